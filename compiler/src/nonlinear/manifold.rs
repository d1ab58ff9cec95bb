//! A quadratic displacement manifold u(q) = V q + W k(q) over an M-orthonormal basis V
//! (n × r), k(q) the r(r+1)/2 products q̃ᵢq̃ⱼ (i ≤ j) of the scaled coordinates q̃ᵢ = qᵢ/sᵢ, fitted
//! to snapshots by regularised least squares (the data-driven quadratic manifold of Geelen,
//! Wright & Willcox 2023; Jain et al. 2017 derive W from modal derivatives instead). A
//! candidate for loads whose response turns a part of the body far (the twist,
//! docs/results/tier.md §8): a linear basis holds a rotation only to first order.
//!
//! Fit: q_t = VᵀM u_t, R = U − VQ (the part of every snapshot outside span V), K = k(Q)
//! (p × s), W = R Kᵀ (K Kᵀ + γ tr(K Kᵀ)/p I)⁻¹. Each row of W solves its own least-squares
//! problem, so the fit is the same in any inner product; W's columns are combinations of R's,
//! hence M-orthogonal to V, and VᵀM u(q) = q: the projection q = VᵀMu is the manifold's
//! left inverse. sᵢ is the RMS of qᵢ over the snapshots (the products of coordinates that
//! differ by orders of magnitude stay comparable for the regulariser).

use nalgebra::{DMatrix, DVector};

use super::basis::Basis;

/// u(q) = V q + W k(q/s) (module doc).
#[derive(Clone, Debug)]
pub struct QuadraticManifold {
    /// V, n × r, M-orthonormal.
    pub vectors: DMatrix<f64>,
    /// M V, n × r (the projection q = (MV)ᵀu).
    pub mass_vectors: DMatrix<f64>,
    /// W, n × r(r+1)/2, columns in the order (0,0), (0,1), …, (0,r−1), (1,1), …
    pub quadratic: DMatrix<f64>,
    /// sᵢ, r: the scale of each coordinate in k.
    pub scales: Vec<f64>,
}

/// Number of products q̃ᵢq̃ⱼ, i ≤ j, of r coordinates.
pub fn product_count(r: usize) -> usize {
    r * (r + 1) / 2
}

/// The products q̃ᵢq̃ⱼ (i ≤ j) into `out` (r(r+1)/2).
fn products(q: &[f64], scales: &[f64], out: &mut [f64]) {
    let mut k = 0;
    for i in 0..q.len() {
        let qi = q[i] / scales[i];
        for j in i..q.len() {
            out[k] = qi * q[j] / scales[j];
            k += 1;
        }
    }
}

impl QuadraticManifold {
    /// Fits W to `snapshots` (each n) over the basis `basis`, regularised by `regularisation` γ
    /// (relative to the mean diagonal of K Kᵀ; γ > 0). None when the snapshots give no
    /// scale (all zero) or the regularised normal matrix is not positive definite.
    pub fn fit(basis: &Basis, snapshots: &[Vec<f64>], regularisation: f64) -> Option<Self> {
        let (n, r) = (basis.vectors.nrows(), basis.len());
        let p = product_count(r);
        let s = snapshots.len();
        if s == 0 || r == 0 {
            return None;
        }
        let u = DMatrix::from_fn(n, s, |i, t| snapshots[t][i]);
        let q = basis.mass_vectors.tr_mul(&u);
        let residual = &u - &basis.vectors * &q;
        let scales: Vec<f64> = (0..r)
            .map(|i| (q.row(i).norm_squared() / s as f64).sqrt())
            .collect();
        if scales.iter().any(|&x| x == 0.0 || !x.is_finite()) {
            return None;
        }
        let mut k = DMatrix::zeros(p, s);
        let mut column = vec![0.0; p];
        for t in 0..s {
            let qt: Vec<f64> = q.column(t).iter().copied().collect();
            products(&qt, &scales, &mut column);
            k.column_mut(t).copy_from_slice(&column);
        }
        let mut normal = &k * k.transpose();
        let shift = regularisation * normal.trace() / p as f64;
        for i in 0..p {
            normal[(i, i)] += shift;
        }
        let rhs = &k * residual.transpose();
        let solved = normal.cholesky()?.solve(&rhs);
        Some(QuadraticManifold {
            vectors: basis.vectors.clone(),
            mass_vectors: basis.mass_vectors.clone(),
            quadratic: solved.transpose(),
            scales,
        })
    }

    /// r.
    pub fn order(&self) -> usize {
        self.vectors.ncols()
    }

    /// q = VᵀMu (r) of a displacement u (n).
    pub fn project(&self, u: &[f64]) -> DVector<f64> {
        self.mass_vectors.tr_mul(&DVector::from_column_slice(u))
    }

    /// u(q) (n).
    pub fn lift(&self, q: &[f64]) -> DVector<f64> {
        &self.vectors * DVector::from_column_slice(q) + self.quadratic_part(q)
    }

    /// W k(q) (n): the manifold's quadratic part alone (with [`QuadraticManifold::tangent`],
    /// the acceleration of a motion on it: ü = P(q) q̈ + 2 W k(q̇)).
    pub fn quadratic_part(&self, q: &[f64]) -> DVector<f64> {
        let mut k = vec![0.0; product_count(q.len())];
        products(q, &self.scales, &mut k);
        &self.quadratic * DVector::from_column_slice(&k)
    }

    /// The tangent ∂u/∂q = V + W ∂k/∂q at q (n × r).
    pub fn tangent(&self, q: &[f64]) -> DMatrix<f64> {
        let r = q.len();
        // ∂k_(i,j)/∂q_l = (δ_il q̃_j + δ_jl q̃_i) / s_l.
        let mut dk = DMatrix::zeros(product_count(r), r);
        let mut c = 0;
        for i in 0..r {
            let qi = q[i] / self.scales[i];
            for j in i..r {
                let qj = q[j] / self.scales[j];
                dk[(c, i)] += qj / self.scales[i];
                dk[(c, j)] += qi / self.scales[j];
                c += 1;
            }
        }
        &self.vectors + &self.quadratic * dk
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonlinear::basis::m_orthonormalise;

    /// Snapshots that lie on a quadratic manifold (a random quadratic part outside span V)
    /// are reproduced by the fit to round-off; the fitted W is M-orthogonal to V; the tangent
    /// equals the central difference of the lift.
    #[test]
    fn a_quadratic_manifold_is_recovered_and_its_tangent_is_the_derivative() {
        let (n, r) = (12, 3);
        // A diagonal SPD mass and a deterministic pseudo-random sequence.
        let mass = faer::sparse::SparseColMat::<usize, f64>::try_new_from_triplets(
            n,
            n,
            &(0..n)
                .map(|i| faer::sparse::Triplet::new(i, i, 1.0 + 0.1 * i as f64))
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let candidates: Vec<(String, Vec<f64>)> = (0..r)
            .map(|j| (format!("v{j}"), (0..n).map(|_| next()).collect()))
            .collect();
        let basis = m_orthonormalise(&mass, &candidates, 1e-10, r);
        // A W outside span V: random columns with their V part removed.
        let p = product_count(r);
        let mut w = DMatrix::from_fn(n, p, |_, _| next());
        for c in 0..p {
            let col: Vec<f64> = w.column(c).iter().copied().collect();
            let coeff = basis.project(&col);
            let inside = &basis.vectors * coeff;
            let mut column = w.column_mut(c);
            column -= inside;
        }
        let scales = vec![1.0; r];
        let truth = QuadraticManifold {
            vectors: basis.vectors.clone(),
            mass_vectors: basis.mass_vectors.clone(),
            quadratic: w.clone(),
            scales,
        };
        let snapshots: Vec<Vec<f64>> = (0..40)
            .map(|_| {
                let q: Vec<f64> = (0..r).map(|_| 2.0 * next()).collect();
                truth.lift(&q).iter().copied().collect()
            })
            .collect();
        let fitted = QuadraticManifold::fit(&basis, &snapshots, 1e-14).expect("fit");
        for u in &snapshots {
            let q = fitted.project(u);
            let back = fitted.lift(q.as_slice());
            let e = (back - DVector::from_column_slice(u)).norm();
            assert!(
                e < 1e-9 * (1.0 + DVector::from_column_slice(u).norm()),
                "{e:e}"
            );
        }
        // W ⟂_M V.
        let vw = fitted.mass_vectors.tr_mul(&fitted.quadratic);
        assert!(vw.amax() < 1e-12, "{:e}", vw.amax());
        // Tangent against central differences.
        let q = [0.3, -0.7, 0.2];
        let tangent = fitted.tangent(&q);
        let h = 1e-6;
        for l in 0..r {
            let (mut up, mut down) = (q, q);
            up[l] += h;
            down[l] -= h;
            let fd = (fitted.lift(&up) - fitted.lift(&down)) / (2.0 * h);
            let e = (fd - tangent.column(l)).amax();
            assert!(e < 1e-8, "column {l}: {e:e}");
        }
    }
}
