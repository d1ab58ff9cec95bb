//! Proper orthogonal decomposition in a mass inner product by the method of snapshots
//! (Sirovich 1987): the leading M-orthonormal directions of a set of snapshots.

use faer::sparse::SparseColMat;

use super::sparse::sparse_mul;

/// POD of `snapshots` (each n, m) in the M inner product by the method of snapshots: the
/// eigenpairs (λₖ, ψₖ) of the Gram matrix G = SᵀMS (s × s) give the modes Sψₖ/√λₖ, in
/// decreasing λₖ, up to `max_modes` and down to λₖ ≥ `relative_floor`·λ₁. Returns the modes
/// (n each, M-orthonormal up to round-off) and all eigenvalues λ (m²·kg), descending.
pub fn pod(
    mass: &SparseColMat<usize, f64>,
    snapshots: &[Vec<f64>],
    max_modes: usize,
    relative_floor: f64,
) -> (Vec<(String, Vec<f64>)>, Vec<f64>) {
    let s = snapshots.len();
    if s == 0 {
        return (Vec::new(), Vec::new());
    }
    let n = snapshots[0].len();
    // S (n × s) and MS; G = Sᵀ(MS) and the modes SΨ by blocked products (faer), the
    // eigen-decomposition of G by faer's blocked tridiagonal solver.
    let snap = faer::Mat::from_fn(n, s, |i, j| snapshots[j][i]);
    let mut ms = faer::Mat::<f64>::zeros(n, s);
    for (j, u) in snapshots.iter().enumerate() {
        let m_u = sparse_mul(mass, u);
        ms.col_mut(j)
            .iter_mut()
            .zip(&m_u)
            .for_each(|(d, v)| *d = *v);
    }
    let product = snap.as_ref().transpose() * ms.as_ref();
    drop(ms);
    let gram = faer::Mat::from_fn(s, s, |i, j| 0.5 * (product[(i, j)] + product[(j, i)]));
    // The solver fails only on non-finite entries, and the training keeps no non-finite
    // snapshot (such a run is reported as failed and skipped).
    let Ok(eig) = gram.self_adjoint_eigen(faer::Side::Lower) else {
        return (Vec::new(), Vec::new());
    };
    let eigenvalues = eig.S().column_vector();
    let mut order: Vec<usize> = (0..s).collect();
    order.sort_by(|&a, &b| eigenvalues[b].total_cmp(&eigenvalues[a]));
    let values: Vec<f64> = order.iter().map(|&k| eigenvalues[k]).collect();
    let top = values.first().copied().unwrap_or(0.0);
    let kept: Vec<usize> = order
        .iter()
        .copied()
        .take(max_modes)
        .take_while(|&k| {
            let lambda = eigenvalues[k];
            lambda > 0.0 && lambda >= relative_floor * top
        })
        .collect();
    let psi = faer::Mat::from_fn(s, kept.len(), |c, m| {
        eig.U()[(c, kept[m])] / eigenvalues[kept[m]].sqrt()
    });
    let vectors = &snap * &psi;
    let modes = (0..kept.len())
        .map(|m| {
            (
                format!("pod {}", m + 1),
                vectors.col(m).iter().copied().collect(),
            )
        })
        .collect();
    (modes, values)
}
