//! ASCII VTK XML output: one `.vtu` per step (each displayed node set a piece: its rest
//! positions as points, its triangles as cells — vertices if it has none — with point data
//! `displacement` (world, m) and `displacement_std` (m)), and a `.pvd` collection over time.
//! In ParaView, "Warp By Vector" on `displacement` shows the deformed surface.

use crate::{Estimator, RuntimeError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn write_err(path: &Path, source: std::io::Error) -> RuntimeError {
    RuntimeError::Write {
        path: path.to_path_buf(),
        source,
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Renders the current estimate of every node set as a VTU document.
pub fn render_vtu(est: &Estimator) -> Result<String, RuntimeError> {
    let model = est.model();
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n<UnstructuredGrid>\n");
    for (set_index, set) in model.node_sets.iter().enumerate() {
        let n = set.node_tags.len();
        let mut u = vec![0.0; 3 * n];
        let mut sd = vec![0.0; 3 * n];
        est.node_displacements(set_index, &mut u)?;
        est.node_std(set_index, &mut sd)?;
        let (ncells, conn, offsets, types): (usize, Vec<u32>, Vec<usize>, u8) =
            if set.triangles.is_empty() {
                (n, (0..n as u32).collect(), (1..=n).collect(), 1)
            } else {
                let t = set.triangles.len();
                (
                    t,
                    set.triangles.iter().flatten().copied().collect(),
                    (1..=t).map(|i| 3 * i).collect(),
                    5,
                )
            };
        let _ = writeln!(
            s,
            "<Piece Name=\"{}\" NumberOfPoints=\"{n}\" NumberOfCells=\"{ncells}\">",
            xml_escape(&set.name)
        );
        s.push_str("<PointData Vectors=\"displacement\">\n");
        for (name, data) in [("displacement", &u), ("displacement_std", &sd)] {
            let _ = writeln!(
                s,
                "<DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"3\" format=\"ascii\">"
            );
            for v in data.iter() {
                let _ = write!(s, "{v:e} ");
            }
            s.push_str("\n</DataArray>\n");
        }
        s.push_str("<DataArray type=\"UInt64\" Name=\"node_tag\" format=\"ascii\">\n");
        for t in &set.node_tags {
            let _ = write!(s, "{t} ");
        }
        s.push_str("\n</DataArray>\n</PointData>\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
        for v in &set.rest_positions.data {
            let _ = write!(s, "{v:e} ");
        }
        s.push_str("\n</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"UInt32\" Name=\"connectivity\" format=\"ascii\">\n");
        for v in &conn {
            let _ = write!(s, "{v} ");
        }
        s.push_str(
            "\n</DataArray>\n<DataArray type=\"UInt64\" Name=\"offsets\" format=\"ascii\">\n",
        );
        for v in &offsets {
            let _ = write!(s, "{v} ");
        }
        s.push_str("\n</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
        for _ in 0..ncells {
            let _ = write!(s, "{types} ");
        }
        s.push_str("\n</DataArray>\n</Cells>\n</Piece>\n");
    }
    s.push_str("</UnstructuredGrid>\n</VTKFile>\n");
    Ok(s)
}

/// Writes `dir/step_{k:06}.vtu` for the estimator's current step k; returns the file name.
pub fn write_step(dir: &Path, est: &Estimator) -> Result<String, RuntimeError> {
    let name = format!("step_{:06}.vtu", est.step_index());
    let path = dir.join(&name);
    std::fs::write(&path, render_vtu(est)?).map_err(|e| write_err(&path, e))?;
    Ok(name)
}

/// Writes `dir/estimates.pvd` listing `(time s, file name)` pairs.
pub fn write_pvd(dir: &Path, entries: &[(f64, String)]) -> Result<PathBuf, RuntimeError> {
    let mut s = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n<Collection>\n");
    for (t, file) in entries {
        let _ = writeln!(
            s,
            "<DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{}\"/>",
            xml_escape(file)
        );
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    let path = dir.join("estimates.pvd");
    std::fs::write(&path, s).map_err(|e| write_err(&path, e))?;
    Ok(path)
}
