//! Output of reference simulations: trajectories as CSV, and a ParaView time series of ASCII
//! VTU files (tetrahedra in the rest configuration with point data `displacement`, m) collected
//! by a PVD file.

use std::fmt::Write as _;

use crokf_formats::vtk::{self, DataArray, UnstructuredGrid, Values};

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
    let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
    let (points, displacement) = (flat(points), flat(displacement));
    let connectivity: Vec<u64> = tetrahedra.iter().flatten().map(|&v| v as u64).collect();
    let offsets: Vec<u64> = (1..=tetrahedra.len() as u64).map(|i| 4 * i).collect();
    let types = vec![vtk::VTK_TETRA; tetrahedra.len()];
    UnstructuredGrid {
        points: &points,
        connectivity: &connectivity,
        offsets: &offsets,
        types: &types,
        point_data: &[DataArray {
            name: "displacement",
            components: 3,
            values: Values::F64(&displacement),
        }],
        cell_data: &[],
    }
    .to_xml()
}

/// A PVD collection of (time in s, file path relative to the PVD file).
pub fn pvd(frames: &[(f64, String)]) -> String {
    vtk::collection(frames)
}
