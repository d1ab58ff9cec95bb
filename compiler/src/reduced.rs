//! One reduced linear system (docs/design.md §4, §6): the balanced truncation of order r in the
//! output layout of [`OutputRows`](crate::outputs::OutputRows), unweighted, with its input
//! channels split into deterministic inputs and process noise, and what the truncation measured.

use faer::linalg::solvers::Solve;
use faer::Mat;

use crate::fem::operators::{InputKind, Operators};
use crate::reduce::ReducedSystem;

/// What the reduced model keeps of a contact region, per region DOF (3n rows, node order).
#[derive(Clone, Debug)]
pub struct RegionRows {
    /// C: the displacement rows (3n × r).
    pub rows: Mat<f64>,
    /// Bᵀ: row 3i + c is the input column of a unit force in direction c on region node i.
    pub input: Mat<f64>,
    /// W (3n × r): Û = θ³ C x⁺ − W x is the region's displacement at the Wilson θ-point
    /// U(t + θΔt) of the step from x to x⁺ ([`WilsonTheta::theta_point_weights`](
    /// crate::dynamics::WilsonTheta::theta_point_weights) on the modal state the truncation
    /// maps x back to).
    pub theta: Mat<f64>,
}

/// The reduced model x⁺ = F x + G u + G_w ξ, y = H x, of order r (plus 3 force states per
/// random-walk load group, docs/design.md §6).
#[derive(Clone, Debug)]
pub struct ReducedModel {
    /// F (r×r).
    pub transition: Mat<f64>,
    /// G (r × deterministic inputs), in the order of [`Operators::inputs`].
    pub input: Mat<f64>,
    /// G_w (r × noise channels), unit-variance channels.
    pub noise_input: Mat<f64>,
    /// All output rows (p×r) in the order of
    /// [`OutputRows::weighted`](crate::outputs::OutputRows::weighted), weights removed, then
    /// (with a contact region) the 3n displacement rows of its nodes.
    pub outputs: Mat<f64>,
    /// Bᵀ of the contact region (3n × r): row 3i + c is the input column of a unit force in
    /// direction c on region node i (0 rows without a region).
    pub contact_input: Mat<f64>,
    /// W_b of the contact region (3n × balanced states): the balanced columns of the θ-point
    /// rows, Û = θ³ C x⁺ − W x (x the state before the step; [`RegionRows::theta`]).
    pub contact_theta: Mat<f64>,
    /// Hankel singular values σ₁ ≥ σ₂ ≥ … of the weighted modal system.
    pub hankel_singular_values: Vec<f64>,
    /// 2 Σ_{i>r} σᵢ ≥ ‖G − G_r‖∞ (weighted outputs).
    pub error_bound: f64,
    /// Balanced states kept (r before any force states).
    pub balanced_order: usize,
    /// ρ(F) of the balanced part.
    pub spectral_radius: f64,
    /// Notes of the truncation (order capped, …).
    pub warnings: Vec<String>,
}

impl ReducedModel {
    /// Splits a balanced truncation of the weighted system into deterministic and noise input
    /// columns (the first `deterministic_inputs` are deterministic, the next `noise_inputs`
    /// noise; columns past them, a contact region's directions, are dropped), keeps the first
    /// `weights.len()` output rows and removes their weights, appends a contact region's
    /// rows `contact` ([`RegionRows`]), then fixes the states' signs.
    pub fn from_truncation(
        system: ReducedSystem,
        deterministic_inputs: usize,
        noise_inputs: usize,
        weights: &[f64],
        contact: Option<RegionRows>,
    ) -> Self {
        let r = system.order;
        let m = deterministic_inputs;
        let noise = noise_inputs;
        let p = weights.len();
        let RegionRows {
            rows: region_rows,
            input: contact_input,
            theta: contact_theta,
        } = contact.unwrap_or_else(|| RegionRows {
            rows: Mat::zeros(0, r),
            input: Mat::zeros(0, r),
            theta: Mat::zeros(0, r),
        });
        let mut outputs = Mat::<f64>::zeros(p + region_rows.nrows(), r);
        for (i, w) in weights.iter().enumerate() {
            for j in 0..r {
                outputs[(i, j)] = system.output[(i, j)] / w;
            }
        }
        outputs
            .submatrix_mut(p, 0, region_rows.nrows(), r)
            .copy_from(&region_rows);
        let mut reduced = ReducedModel {
            transition: system.transition,
            input: system.input.subcols(0, m).to_owned(),
            noise_input: system.input.subcols(m, noise).to_owned(),
            outputs,
            contact_input,
            contact_theta,
            hankel_singular_values: system.hankel_singular_values,
            error_bound: system.error_bound,
            balanced_order: r,
            spectral_radius: system.spectral_radius,
            warnings: system.warnings,
        };
        reduced.normalise_signs();
        reduced
    }

    /// State dimension (balanced states plus force states).
    pub fn state_dim(&self) -> usize {
        self.transition.nrows()
    }

    /// Q = G_w G_wᵀ (r×r), the process-noise covariance per step.
    pub fn process_noise(&self) -> Mat<f64> {
        &self.noise_input * self.noise_input.transpose()
    }

    /// Fixes the sign of each balanced state (a similarity x ↦ S x, S = diag(±1)) so that the
    /// largest-magnitude entry of each output column is positive. Singular vectors are defined
    /// up to sign only, and a rounding difference between machines must not flip the model file.
    pub fn normalise_signs(&mut self) {
        let r = self.transition.nrows();
        for j in 0..r {
            let column = self.outputs.col(j);
            let pivot = (0..column.nrows())
                .max_by(|&a, &b| column[a].abs().total_cmp(&column[b].abs()))
                .map_or(1.0, |i| column[i]);
            if pivot >= 0.0 {
                continue;
            }
            for i in 0..r {
                self.transition[(j, i)] = -self.transition[(j, i)];
                self.transition[(i, j)] = -self.transition[(i, j)];
            }
            self.input.row_mut(j).iter_mut().for_each(|v| *v = -*v);
            self.noise_input
                .row_mut(j)
                .iter_mut()
                .for_each(|v| *v = -*v);
            self.outputs.col_mut(j).iter_mut().for_each(|v| *v = -*v);
            self.contact_input
                .col_mut(j)
                .iter_mut()
                .for_each(|v| *v = -*v);
            self.contact_theta
                .col_mut(j)
                .iter_mut()
                .for_each(|v| *v = -*v);
        }
    }

    /// Augments the state with the (local-frame) force of each random-walk load group
    /// (3 states each): x_aug = [x; f], F_aug = [[F, G_g], [0, I]], G_aug = [G; 0], the group's
    /// white-noise channels replaced by N(0, σ²I) increments of f (docs/design.md §6, §11).
    /// `loads` lists (load group index, σ in N per step).
    ///
    /// Output columns of the force states: with `static_outputs` (p × deterministic inputs,
    /// the full-order static response K⁻¹b_j of each input channel on every output row,
    /// unweighted, in [`OutputRows::weighted`](crate::outputs::OutputRows::weighted) order)
    /// they hold the static residual D_j = y_static,j − C (I − F)⁻¹ G_j, so that the augmented
    /// model's steady response to a constant force, C (I − F)⁻¹ G_j + D_j, is the full-order
    /// one on every output (the mode-acceleration / residual-flexibility correction applied to
    /// the balanced truncation). Without it (`None`) the columns are zero: a load direction the
    /// truncation does not keep (the axial tip force of the cantilever at r ≤ 16: 100 % static
    /// error) is then unobservable through the markers and its random walk drifts.
    pub fn with_force_states(
        self,
        ops: &Operators,
        loads: &[(usize, f64)],
        static_outputs: Option<&Mat<f64>>,
    ) -> Self {
        let r = self.transition.nrows();
        let extra = 3 * loads.len();
        let r2 = r + extra;
        let mut transition = Mat::<f64>::zeros(r2, r2);
        transition
            .submatrix_mut(0, 0, r, r)
            .copy_from(&self.transition);
        let mut input = Mat::<f64>::zeros(r2, self.input.ncols());
        input
            .submatrix_mut(0, 0, r, self.input.ncols())
            .copy_from(&self.input);
        for (k, &(load, _)) in loads.iter().enumerate() {
            for c in 0..3 {
                let channel = load_channel(ops, load, c);
                let state = r + 3 * k + c;
                for i in 0..r {
                    transition[(i, state)] = self.input[(i, channel)];
                }
                transition[(state, state)] = 1.0;
            }
        }
        // White-noise channels of random-walk loads are replaced by the force increments.
        let kept: Vec<usize> = (0..ops.noise.len())
            .filter(|&j| match ops.noise[j].kind {
                InputKind::Noise { load: Some(g) } => !loads.iter().any(|&(l, _)| l == g),
                _ => true,
            })
            .collect();
        let mut noise_input = Mat::<f64>::zeros(r2, kept.len() + extra);
        for (col, &j) in kept.iter().enumerate() {
            for i in 0..r {
                noise_input[(i, col)] = self.noise_input[(i, j)];
            }
        }
        for (k, &(_, sigma)) in loads.iter().enumerate() {
            for c in 0..3 {
                noise_input[(r + 3 * k + c, kept.len() + 3 * k + c)] = sigma;
            }
        }
        let mut contact_input = Mat::<f64>::zeros(self.contact_input.nrows(), r2);
        contact_input
            .submatrix_mut(0, 0, self.contact_input.nrows(), r)
            .copy_from(&self.contact_input);
        let p = self.outputs.nrows();
        let mut outputs = Mat::<f64>::zeros(p, r2);
        outputs.submatrix_mut(0, 0, p, r).copy_from(&self.outputs);
        if let Some(exact) = static_outputs {
            // Steady state of the balanced part per input channel: (I − F)⁻¹ G (r × m). ρ(F) < 1
            // (refused otherwise by the truncation), so I − F is invertible.
            let lu = (Mat::<f64>::identity(r, r) - &self.transition).partial_piv_lu();
            let steady = lu.solve(&self.input);
            let reduced_static = &self.outputs * &steady;
            for (k, &(load, _)) in loads.iter().enumerate() {
                for c in 0..3 {
                    let channel = load_channel(ops, load, c);
                    for i in 0..p {
                        outputs[(i, r + 3 * k + c)] =
                            exact[(i, channel)] - reduced_static[(i, channel)];
                    }
                }
            }
        }
        ReducedModel {
            transition,
            input,
            noise_input,
            outputs,
            contact_input,
            ..self
        }
    }
}

/// The deterministic input channel of component `c` of load group `load`.
///
/// # Panics
/// If the operators have no such channel (every load group has three by construction).
fn load_channel(ops: &Operators, load: usize, c: usize) -> usize {
    ops.inputs
        .iter()
        .position(|ch| ch.kind == InputKind::Load { load, component: c })
        .expect("every load group has three input channels")
}
