//! Matrix Market export of the assembled operators, so the assembly can be checked with any
//! other FEM code: `K.mtx`, `M.mtx`, `C.mtx` (coordinate real general), `B.mtx` (input load
//! matrix, array real general, n × inputs), `H.mtx` (sensor displacement rows, coordinate,
//! 3·sensors × n), and `dofs.csv` (row → node tag, component), written together through a
//! staging folder ([`FILES`]).

use std::fmt::Write as _;
use std::path::Path;

use crokf_formats::output::{OutputError, StagedDir};

use faer::sparse::SparseColMat;

use crate::fem::operators::{Operators, SparseRow};
use crate::fem::{sparse_entries, FemModel};

/// The files [`export_matrices`] writes, in order.
pub const FILES: [&str; 6] = ["K.mtx", "M.mtx", "C.mtx", "B.mtx", "H.mtx", "dofs.csv"];

/// Writes the operators into `dir` through a staging folder: the six files replace their old
/// versions together when all are written, and a failure at any of them leaves `dir` as it was
/// (`crokf_formats::output::StagedDir`).
pub fn export_matrices(fem: &FemModel, ops: &Operators, dir: &Path) -> Result<(), OutputError> {
    let mut staged = StagedDir::create_owning(dir, |name| FILES.contains(&name))?;
    staged.write("K.mtx", &sparse_file(&fem.stiffness, "stiffness K, N/m"))?;
    staged.write("M.mtx", &sparse_file(&fem.mass, "mass M, kg"))?;
    staged.write(
        "C.mtx",
        &sparse_file(&fem.damping(), "Rayleigh damping C = aM + bK, N s/m"),
    )?;

    let n = fem.dof_count();
    let mut b = String::new();
    let labels: Vec<&str> = ops.inputs.iter().map(|c| c.label.as_str()).collect();
    let _ = writeln!(b, "%%MatrixMarket matrix array real general");
    let _ = writeln!(
        b,
        "% input load matrix, N per unit input; columns: {}",
        labels.join(" ")
    );
    let _ = writeln!(b, "{} {}", n, ops.inputs.len());
    for c in &ops.inputs {
        for v in &c.column {
            let _ = writeln!(b, "{v:.17e}");
        }
    }
    staged.write("B.mtx", b.as_bytes())?;

    let mut rows: Vec<SparseRow> = Vec::new();
    let mut names = Vec::new();
    for s in &ops.sensors {
        for (c, row) in Operators::sensor_rows(fem, s).into_iter().enumerate() {
            rows.push(row);
            names.push(format!("{}.{}", s.name, ["x", "y", "z"][c]));
        }
    }
    let mut h = String::new();
    let _ = writeln!(h, "%%MatrixMarket matrix coordinate real general");
    let _ = writeln!(h, "% sensor displacement rows; rows: {}", names.join(" "));
    let nnz: usize = rows.iter().map(Vec::len).sum();
    let _ = writeln!(h, "{} {} {}", rows.len(), n, nnz);
    for (i, row) in rows.iter().enumerate() {
        for &(j, v) in row {
            let _ = writeln!(h, "{} {} {v:.17e}", i + 1, j + 1);
        }
    }
    staged.write("H.mtx", h.as_bytes())?;

    let mut d = String::from("row,node_tag,component\n");
    for (i, &(node, c)) in fem.dofs.dofs.iter().enumerate() {
        let _ = writeln!(
            d,
            "{},{},{}",
            i + 1,
            fem.node_tags[node],
            ["x", "y", "z"][c]
        );
    }
    staged.write("dofs.csv", d.as_bytes())?;
    staged.commit()
}

/// One sparse matrix as a Matrix Market coordinate file (1-based indices).
fn sparse_file(mat: &SparseColMat<usize, f64>, what: &str) -> Vec<u8> {
    let mut w = String::new();
    let _ = writeln!(w, "%%MatrixMarket matrix coordinate real general");
    let _ = writeln!(w, "% {what}; rows and columns numbered as in dofs.csv");
    let entries: Vec<_> = sparse_entries(mat).collect();
    let _ = writeln!(w, "{} {} {}", mat.nrows(), mat.ncols(), entries.len());
    for (i, j, v) in entries {
        let _ = writeln!(w, "{} {} {v:.17e}", i + 1, j + 1);
    }
    w.into_bytes()
}
