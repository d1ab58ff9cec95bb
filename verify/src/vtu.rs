//! Output of reference simulations: a ParaView time series of ASCII VTU files (tetrahedra in
//! the rest configuration with point data `displacement`, m) collected by a PVD file.

use crokf_formats::vtk::{self, DataArray, UnstructuredGrid, Values};

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
