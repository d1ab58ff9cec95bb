//! Matrix Market export of the assembled operators, so the assembly can be checked with any
//! other FEM code: `K.mtx`, `M.mtx`, `C.mtx` (coordinate real general), `B.mtx` (input load
//! matrix, array real general, n × inputs), `H.mtx` (sensor displacement rows, coordinate,
//! 3·sensors × n), and `dofs.csv` (row → node tag, component).

use std::io::Write;
use std::path::Path;

use faer::sparse::SparseColMat;

use crate::fem::operators::{Operators, SparseRow};
use crate::fem::{sparse_entries, FemModel};

/// Writes the operators into `dir` (created if missing).
pub fn export_matrices(fem: &FemModel, ops: &Operators, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    write_sparse(&dir.join("K.mtx"), &fem.stiffness, "stiffness K, N/m")?;
    write_sparse(&dir.join("M.mtx"), &fem.mass, "mass M, kg")?;
    write_sparse(
        &dir.join("C.mtx"),
        &fem.damping(),
        "Rayleigh damping C = aM + bK, N s/m",
    )?;

    let n = fem.dof_count();
    let mut b = std::io::BufWriter::new(std::fs::File::create(dir.join("B.mtx"))?);
    writeln!(b, "%%MatrixMarket matrix array real general")?;
    let labels: Vec<&str> = ops.inputs.iter().map(|c| c.label.as_str()).collect();
    writeln!(
        b,
        "% input load matrix, N per unit input; columns: {}",
        labels.join(" ")
    )?;
    writeln!(b, "{} {}", n, ops.inputs.len())?;
    for c in &ops.inputs {
        for v in &c.column {
            writeln!(b, "{v:.17e}")?;
        }
    }
    b.flush()?;

    let mut rows: Vec<SparseRow> = Vec::new();
    let mut names = Vec::new();
    for s in &ops.sensors {
        for (c, row) in Operators::sensor_rows(fem, s).into_iter().enumerate() {
            rows.push(row);
            names.push(format!("{}.{}", s.name, ["x", "y", "z"][c]));
        }
    }
    let mut h = std::io::BufWriter::new(std::fs::File::create(dir.join("H.mtx"))?);
    writeln!(h, "%%MatrixMarket matrix coordinate real general")?;
    writeln!(h, "% sensor displacement rows; rows: {}", names.join(" "))?;
    let nnz: usize = rows.iter().map(Vec::len).sum();
    writeln!(h, "{} {} {}", rows.len(), n, nnz)?;
    for (i, row) in rows.iter().enumerate() {
        for &(j, v) in row {
            writeln!(h, "{} {} {v:.17e}", i + 1, j + 1)?;
        }
    }
    h.flush()?;

    let mut d = std::io::BufWriter::new(std::fs::File::create(dir.join("dofs.csv"))?);
    writeln!(d, "row,node_tag,component")?;
    for (i, &(node, c)) in fem.dofs.dofs.iter().enumerate() {
        writeln!(
            d,
            "{},{},{}",
            i + 1,
            fem.node_tags[node],
            ["x", "y", "z"][c]
        )?;
    }
    d.flush()
}

fn write_sparse(path: &Path, mat: &SparseColMat<usize, f64>, what: &str) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "%%MatrixMarket matrix coordinate real general")?;
    writeln!(w, "% {what}; rows and columns numbered as in dofs.csv")?;
    let entries: Vec<_> = sparse_entries(mat).collect();
    writeln!(w, "{} {} {}", mat.nrows(), mat.ncols(), entries.len())?;
    for (i, j, v) in entries {
        writeln!(w, "{} {} {v:.17e}", i + 1, j + 1)?;
    }
    w.flush()
}
