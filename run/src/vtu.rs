//! ASCII VTK XML output: one `.vtu` per step (the displayed node sets one after the other: rest
//! positions as points, triangles as cells — vertices for a set without triangles — with point
//! data `displacement` (world, m), `displacement_std` (m), `node_tag`, `node_set`), and a
//! `.pvd` collection over time.
//! In ParaView, "Warp By Vector" on `displacement` shows the deformed surface.

use crokf_formats::output::{OutputError, StagedDir};
use crokf_formats::vtk::{self, DataArray, UnstructuredGrid, Values};
use crokf_runtime::{Estimator, RuntimeError};

/// Renders the current estimate of every node set as a VTU document: a single piece with the
/// node sets one after the other (point and cell data `node_set` give the set index).
pub fn render_vtu(est: &Estimator) -> Result<String, RuntimeError> {
    let model = est.model();
    let (mut u, mut sd, mut points, mut tags, mut set_of_point) =
        (vec![], vec![], vec![], vec![], vec![]);
    let (mut conn, mut offsets, mut types, mut set_of_cell) = (vec![], vec![], vec![], vec![]);
    for (set_index, set) in model.node_sets.iter().enumerate() {
        let n = set.node_tags.len();
        let base = tags.len() as u64;
        let mut buf = vec![0.0; 3 * n];
        est.node_displacements(set_index, &mut buf)?;
        u.extend_from_slice(&buf);
        est.node_std(set_index, &mut buf)?;
        sd.extend_from_slice(&buf);
        points.extend_from_slice(&set.rest_positions.data);
        tags.extend_from_slice(&set.node_tags);
        set_of_point.extend(std::iter::repeat_n(set_index as u32, n));
        if set.triangles.is_empty() {
            for i in 0..n as u64 {
                conn.push(base + i);
                offsets.push(conn.len() as u64);
                types.push(vtk::VTK_VERTEX);
                set_of_cell.push(set_index as u32);
            }
        } else {
            for t in &set.triangles {
                conn.extend(t.iter().map(|&v| base + v as u64));
                offsets.push(conn.len() as u64);
                types.push(vtk::VTK_TRIANGLE);
                set_of_cell.push(set_index as u32);
            }
        }
    }
    let array = |name, components, values| DataArray {
        name,
        components,
        values,
    };
    Ok(UnstructuredGrid {
        points: &points,
        connectivity: &conn,
        offsets: &offsets,
        types: &types,
        point_data: &[
            array("displacement", 3, Values::F64(&u)),
            array("displacement_std", 3, Values::F64(&sd)),
            array("node_tag", 1, Values::U64(&tags)),
            array("node_set", 1, Values::U32(&set_of_point)),
        ],
        cell_data: &[array("node_set", 1, Values::U32(&set_of_cell))],
    }
    .to_xml())
}

/// Writes `step_{k:06}.vtu` for the estimator's current step k into the staged folder;
/// returns the file name.
pub fn write_step(dir: &mut StagedDir, est: &Estimator) -> Result<String, crate::RunError> {
    let name = step_file_name(est.step_index());
    dir.write(&name, render_vtu(est)?.as_bytes())?;
    Ok(name)
}

/// `step_{k:06}.vtu`.
pub fn step_file_name(k: u64) -> String {
    format!("step_{k:06}.vtu")
}

/// Whether `name` is one of the files a VTU series writes (`step_*.vtu`, `estimates.pvd`).
pub fn is_series_file_name(name: &str) -> bool {
    name == PVD_NAME || (name.starts_with("step_") && name.ends_with(".vtu"))
}

/// The collection file's name.
pub const PVD_NAME: &str = "estimates.pvd";

/// Writes `estimates.pvd` listing `(time s, file name)` pairs into the staged folder.
pub fn write_pvd(dir: &mut StagedDir, entries: &[(f64, String)]) -> Result<(), OutputError> {
    dir.write(PVD_NAME, vtk::collection(entries).as_bytes())
}
