//! Output of reference simulations: trajectories as CSV, and a ParaView time series of ASCII
//! VTU files (tetrahedra in the rest configuration with point data `displacement`, m) collected
//! by a PVD file.

use std::fmt::Write as _;

use crate::simulate::Trajectories;

/// CSV text: `step,t` then `<label>.ux,<label>.uy,<label>.uz` per recorded point (world
/// displacement, m), one row per recorded step.
pub fn trajectories_csv(t: &Trajectories) -> String {
    let mut out = String::from("step,t");
    for label in &t.labels {
        let _ = write!(out, ",{label}.ux,{label}.uy,{label}.uz");
    }
    out.push('\n');
    for ((step, time), values) in t.steps.iter().zip(&t.times).zip(&t.values) {
        let _ = write!(out, "{step},{time:.9e}");
        for v in values {
            let _ = write!(out, ",{:.9e},{:.9e},{:.9e}", v[0], v[1], v[2]);
        }
        out.push('\n');
    }
    out
}

/// One ASCII VTU UnstructuredGrid: `points` (m, rest configuration), linear tetrahedra
/// (VTK cell type 10) and point data `displacement` (m, one per point).
pub fn vtu(points: &[[f64; 3]], tetrahedra: &[[usize; 4]], displacement: &[[f64; 3]]) -> String {
    let mut s = String::with_capacity(64 * points.len() + 48 * tetrahedra.len());
    s.push_str("<?xml version=\"1.0\"?>\n");
    s.push_str(
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" \
         header_type=\"UInt64\">\n<UnstructuredGrid>\n",
    );
    let _ = writeln!(
        s,
        "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        points.len(),
        tetrahedra.len()
    );
    s.push_str("<PointData Vectors=\"displacement\">\n");
    s.push_str(
        "<DataArray type=\"Float64\" Name=\"displacement\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    for d in displacement {
        let _ = writeln!(s, "{:.9e} {:.9e} {:.9e}", d[0], d[1], d[2]);
    }
    s.push_str("</DataArray>\n</PointData>\n<Points>\n");
    s.push_str("<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for p in points {
        let _ = writeln!(s, "{:.12e} {:.12e} {:.12e}", p[0], p[1], p[2]);
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n");
    s.push_str("<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for t in tetrahedra {
        let _ = writeln!(s, "{} {} {} {}", t[0], t[1], t[2], t[3]);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..tetrahedra.len() {
        let _ = writeln!(s, "{}", 4 * (i + 1));
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in tetrahedra {
        s.push_str("10\n");
    }
    s.push_str("</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    s
}

/// A PVD collection of (time in s, file path relative to the PVD file).
pub fn pvd(frames: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" \
         byte_order=\"LittleEndian\">\n<Collection>\n",
    );
    for (t, file) in frames {
        let _ = writeln!(
            s,
            "<DataSet timestep=\"{t:.9e}\" group=\"\" part=\"0\" file=\"{file}\"/>"
        );
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    s
}
