//! Products with faer's compressed-column sparse matrices, entry by entry in storage order (the
//! order fixes the rounding, and with it the model file's bytes).

use faer::sparse::SparseColMat;

/// (row, col, value) of every stored entry, column by column.
pub fn sparse_entries(
    mat: &SparseColMat<usize, f64>,
) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
    let m = mat.as_ref();
    (0..m.ncols()).flat_map(move |j| {
        m.row_idx_of_col_raw(j)
            .iter()
            .zip(m.val_of_col(j))
            .map(move |(&i, &v)| (i, j, v))
    })
}

/// y = A x for a sparse A.
pub fn sparse_mul(mat: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; mat.nrows()];
    for (i, j, v) in sparse_entries(mat) {
        y[i] += v * x[j];
    }
    y
}
