//! Energy-conserving sampling and weighting (ECSW; Farhat, Avery, Chapman, Cortial 2014) of the
//! co-rotational element forces (docs/design.md §10, item 3).
//!
//! For training states u_s ≈ V q_s (s = 1..S, q_s = VᵀM u_s) the projected element forces
//! g_{e,s} = V_eᵀ fₑ(Xₑ + V_e q_s) (r each) form the columns of G (rS × E, block s scaled by
//! 1/‖b_s‖), with b = G·1 the exact reduced forces. ECSW finds sparse weights w ≥ 0 with
//! ‖G w − b‖ ≤ τ ‖b‖ by the Lawson–Hanson active-set non-negative least squares, stopped as
//! soon as the tolerance τ is met (so the active set, the sampled elements, stays small).

use nalgebra::{DMatrix, DVector};

use crate::fem::FemModel;
use crate::stepping::element_force;

use super::NonlinearError;

/// Result of [`nnls`].
#[derive(Clone, Debug, PartialEq)]
pub struct NnlsSolution {
    /// Non-zero weights (column index, weight > 0), by column index.
    pub weights: Vec<(usize, f64)>,
    /// ‖G w − b‖ / ‖b‖ at exit.
    pub relative_residual: f64,
    /// Outer iterations (columns added).
    pub iterations: usize,
}

/// Lawson–Hanson NNLS min ‖G w − b‖ over w ≥ 0, stopped when ‖G w − b‖ ≤ `tolerance`‖b‖, when
/// `max_active` columns are active, or when no column can lower the residual. The
/// least-squares subproblems use the normal equations of the active columns (Cholesky; a
/// column that makes them singular is skipped), adequate for the 1e-2…1e-4 tolerances of ECSW.
pub fn nnls(g: &DMatrix<f64>, b: &DVector<f64>, tolerance: f64, max_active: usize) -> NnlsSolution {
    let (m, n) = g.shape();
    let bnorm = b.norm();
    let mut w = DVector::<f64>::zeros(n);
    let mut active: Vec<usize> = Vec::new();
    let mut excluded = vec![false; n];
    let mut residual = b.clone();
    let mut iterations = 0;
    if bnorm == 0.0 || m == 0 {
        return NnlsSolution {
            weights: Vec::new(),
            relative_residual: 0.0,
            iterations,
        };
    }
    let gtb = g.tr_mul(b);
    let mut gram = Gram::new(n);
    while residual.norm() > tolerance * bnorm && active.len() < max_active.min(n) {
        let gradient = g.tr_mul(&residual);
        let mut best = None;
        for j in 0..n {
            if excluded[j] || active.contains(&j) {
                continue;
            }
            if gradient[j] > 0.0 && best.is_none_or(|(_, v)| gradient[j] > v) {
                best = Some((j, gradient[j]));
            }
        }
        let Some((j, _)) = best else { break };
        active.push(j);
        iterations += 1;
        gram.admit(g, j);
        loop {
            let k = active.len();
            let normal = DMatrix::from_fn(k, k, |a, b| gram.get(active[a], active[b]));
            let rhs = DVector::from_fn(k, |c, _| gtb[active[c]]);
            let Some(ch) = normal.cholesky() else {
                // The new column is dependent on the active ones: drop it for good.
                if let Some(last) = active.pop() {
                    excluded[last] = true;
                }
                break;
            };
            let z = ch.solve(&rhs);
            if z.iter().all(|&v| v > 0.0) {
                for (c, &col) in active.iter().enumerate() {
                    w[col] = z[c];
                }
                break;
            }
            // Step from w towards z until the first active weight reaches zero.
            let mut step = 1.0f64;
            let mut blocking = None;
            for (c, &col) in active.iter().enumerate() {
                if z[c] <= 0.0 {
                    let denom = w[col] - z[c];
                    if denom > 0.0 && w[col] / denom <= step {
                        step = w[col] / denom;
                        blocking = Some(col);
                    }
                }
            }
            for (c, &col) in active.iter().enumerate() {
                w[col] += step * (z[c] - w[col]);
            }
            if let Some(col) = blocking {
                w[col] = 0.0;
            }
            let largest = active.iter().map(|&col| w[col]).fold(0.0f64, f64::max);
            active.retain(|&col| w[col] > 1e-12 * largest);
            for col in 0..n {
                if !active.contains(&col) {
                    w[col] = 0.0;
                }
            }
            if active.is_empty() {
                break;
            }
        }
        residual = b - g * &w;
    }
    let mut weights: Vec<(usize, f64)> =
        (0..n).filter(|&j| w[j] > 0.0).map(|j| (j, w[j])).collect();
    weights.sort_by_key(|p| p.0);
    NnlsSolution {
        weights,
        relative_residual: residual.norm() / bnorm,
        iterations,
    }
}

/// The inner products of the columns of G that have been active, each computed once when its
/// column first enters the active set: the normal equations of an active set are gathered
/// from it instead of formed again (m k² per inner iteration) from the columns.
struct Gram {
    /// Slot of each column (`usize::MAX`: never active).
    slot: Vec<usize>,
    /// Column of each slot.
    columns: Vec<usize>,
    /// `products[s][t]` = ⟨g_columns[s], g_columns[t]⟩ for t ≤ s.
    products: Vec<Vec<f64>>,
}

impl Gram {
    fn new(n: usize) -> Self {
        Gram {
            slot: vec![usize::MAX; n],
            columns: Vec::new(),
            products: Vec::new(),
        }
    }

    /// Gives column `j` a slot with its products against every slotted column.
    fn admit(&mut self, g: &DMatrix<f64>, j: usize) {
        if self.slot[j] != usize::MAX {
            return;
        }
        let column = g.column(j);
        let mut row: Vec<f64> = self
            .columns
            .iter()
            .map(|&c| column.dot(&g.column(c)))
            .collect();
        row.push(column.dot(&column));
        self.slot[j] = self.columns.len();
        self.columns.push(j);
        self.products.push(row);
    }

    /// ⟨g_a, g_b⟩ for two admitted columns.
    fn get(&self, a: usize, b: usize) -> f64 {
        let (s, t) = (self.slot[a], self.slot[b]);
        if s >= t {
            self.products[s][t]
        } else {
            self.products[t][s]
        }
    }
}

/// Options of [`sample_elements`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EcswOptions {
    /// Relative tolerance τ on the training forces.
    pub tolerance: f64,
    /// Most sampled elements.
    pub max_elements: usize,
    /// Most training snapshots used (evenly subsampled).
    pub max_snapshots: usize,
}

impl Default for EcswOptions {
    fn default() -> Self {
        EcswOptions {
            tolerance: 1e-2,
            max_elements: crate::scene::DEFAULT_ECSW_MAX_ELEMENTS,
            max_snapshots: 80,
        }
    }
}

/// ECSW sampling (module docs) of `fem`'s elements for the basis `v` (n × r, M-orthonormal:
/// q_s = VᵀM u_s via `mass_v` = M V, n × r) from training displacements `snapshots`.
pub fn sample_elements(
    fem: &FemModel,
    v: &DMatrix<f64>,
    mass_v: &DMatrix<f64>,
    snapshots: &[Vec<f64>],
    options: &EcswOptions,
) -> Result<NnlsSolution, NonlinearError> {
    let r = v.ncols();
    let n = fem.dof_count();
    if v.nrows() != n || mass_v.shape() != v.shape() {
        return Err(NonlinearError::Invalid(format!(
            "ECSW: basis is {}×{} and M·V {}×{}, expected {n} rows each",
            v.nrows(),
            r,
            mass_v.nrows(),
            mass_v.ncols()
        )));
    }
    let count = snapshots.len().min(options.max_snapshots.max(1));
    let picked: Vec<&Vec<f64>> = (0..count)
        .map(|k| &snapshots[(k * snapshots.len()) / count])
        .collect();
    let elements = fem.elements.len();
    let mut g = DMatrix::zeros(r * picked.len(), elements);
    let rows: Vec<DMatrix<f64>> = fem
        .elements
        .iter()
        .map(|el| {
            let dofs = fem.dofs.element(&el.nodes);
            DMatrix::from_fn(12, r, |i, j| dofs[i].map_or(0.0, |d| v[(d, j)]))
        })
        .collect();
    let stiffness: Vec<[[f64; 12]; 12]> = (0..elements).map(|e| fem.element_stiffness(e)).collect();
    for (s, u) in picked.iter().enumerate() {
        if u.len() != n {
            return Err(NonlinearError::Invalid(format!(
                "ECSW: snapshot {s} has length {}, expected {n}",
                u.len()
            )));
        }
        let q = mass_v.tr_mul(&DVector::from_column_slice(u));
        for (e, el) in fem.elements.iter().enumerate() {
            let ue = &rows[e] * &q;
            let rest = el.nodes.map(|node| fem.positions[node]);
            let current: [[f64; 3]; 4] =
                std::array::from_fn(|a| std::array::from_fn(|c| rest[a][c] + ue[3 * a + c]));
            let (f, _) = element_force(&el.geometry, &stiffness[e], &rest, &current);
            let ge = rows[e].tr_mul(&DVector::from_column_slice(&f));
            g.view_mut((s * r, e), (r, 1)).copy_from(&ge);
        }
        let block_norm = g.rows(s * r, r).column_sum().norm();
        if block_norm > 0.0 {
            g.rows_mut(s * r, r).scale_mut(1.0 / block_norm);
        }
    }
    let b = g.column_sum();
    Ok(nnls(&g, &b, options.tolerance, options.max_elements))
}
