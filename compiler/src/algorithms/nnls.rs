//! Non-negative least squares by Lawson–Hanson's active-set method (Lawson & Hanson, *Solving
//! Least Squares Problems*, 1974, ch. 23), stopped at a relative residual: the solver behind
//! ECSW's element sampling ([`crate::nonlinear::ecsw`]), where an early stop keeps the active
//! set (the sampled elements) small.

use nalgebra::{DMatrix, DVector};

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
