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
use crate::algorithms::nnls::{nnls, NnlsSolution};

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
