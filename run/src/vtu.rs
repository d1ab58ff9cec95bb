//! ASCII VTK XML output: one `.vtu` per step (the displayed node sets one after the other: rest
//! positions as points, triangles as cells — vertices for a set without triangles — with point
//! data `displacement` (world, m), `displacement_std` (m), `node_tag`, `node_set`), and a
//! `.pvd` collection over time.
//! In ParaView, "Warp By Vector" on `displacement` shows the deformed surface.

use crokf_formats::output::{OutputError, StagedDir};
use crokf_runtime::{Estimator, RuntimeError};
use std::fmt::Write as _;

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

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
        set_of_point.extend(std::iter::repeat_n(set_index, n));
        if set.triangles.is_empty() {
            for i in 0..n as u64 {
                conn.push(base + i);
                offsets.push(conn.len());
                types.push(1u8); // VTK_VERTEX
                set_of_cell.push(set_index);
            }
        } else {
            for t in &set.triangles {
                conn.extend(t.iter().map(|&v| base + v as u64));
                offsets.push(conn.len());
                types.push(5u8); // VTK_TRIANGLE
                set_of_cell.push(set_index);
            }
        }
    }
    fn array<T: std::fmt::Display>(s: &mut String, head: &str, values: &[T]) {
        s.push_str(head);
        s.push('\n');
        for v in values {
            let _ = write!(s, "{v} ");
        }
        s.push_str("\n</DataArray>\n");
    }
    // LowerExp is only implemented for numbers; format f64 arrays through this wrapper.
    struct E(f64);
    impl std::fmt::Display for E {
        fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "{:e}", self.0)
        }
    }
    let f = |v: &[f64]| v.iter().map(|&x| E(x)).collect::<Vec<_>>();
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n");
    let _ = writeln!(
        s,
        "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        tags.len(),
        types.len()
    );
    s.push_str("<PointData Vectors=\"displacement\">\n");
    array(&mut s, "<DataArray type=\"Float64\" Name=\"displacement\" NumberOfComponents=\"3\" format=\"ascii\">", &f(&u));
    array(&mut s, "<DataArray type=\"Float64\" Name=\"displacement_std\" NumberOfComponents=\"3\" format=\"ascii\">", &f(&sd));
    array(
        &mut s,
        "<DataArray type=\"UInt64\" Name=\"node_tag\" format=\"ascii\">",
        &tags,
    );
    array(
        &mut s,
        "<DataArray type=\"UInt32\" Name=\"node_set\" format=\"ascii\">",
        &set_of_point,
    );
    s.push_str("</PointData>\n<CellData>\n");
    array(
        &mut s,
        "<DataArray type=\"UInt32\" Name=\"node_set\" format=\"ascii\">",
        &set_of_cell,
    );
    s.push_str("</CellData>\n<Points>\n");
    array(
        &mut s,
        "<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">",
        &f(&points),
    );
    s.push_str("</Points>\n<Cells>\n");
    array(
        &mut s,
        "<DataArray type=\"UInt64\" Name=\"connectivity\" format=\"ascii\">",
        &conn,
    );
    array(
        &mut s,
        "<DataArray type=\"UInt64\" Name=\"offsets\" format=\"ascii\">",
        &offsets,
    );
    array(
        &mut s,
        "<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">",
        &types,
    );
    s.push_str("</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    Ok(s)
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
    let mut s = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n<Collection>\n");
    for (t, file) in entries {
        let _ = writeln!(
            s,
            "<DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{}\"/>",
            xml_escape(file)
        );
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    dir.write(PVD_NAME, s.as_bytes())
}
