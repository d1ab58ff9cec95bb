//! The co-rotational tier at run time (docs/design.md §10, docs/model-format.md "tier"): the
//! reduced co-rotational Wilson-θ step on q with a bounded Newton iteration, and the
//! constant-gain filter on s = (q, q̇, q̈, f) (docs/design.md §11.4): f holds the world force of
//! each random-walk load group (3 per group, N), carried unchanged by the prediction (random
//! walk) and corrected by the update; it adds to the group's inputs, f_r = VᵀB (u + f). With
//! force rates (`force_rates`, §11.5) s = (q, q̇, q̈, f, ḟ) and the prediction carries
//! f⁺ = f + Δt ḟ after the step (f held over it), ḟ⁺ = ḟ.
//!
//! Per step (τ = θΔt, a₀ = 6/τ², a₂ = 3/τ, f_r = VᵀB (u + f) held over the step; the equations
//! of `crokf_formats::CorotationalTier`):
//! ```text
//! q̂ ← q + τq̇ + (τ²/2)q̈;  repeat ≤ newton_iterations:
//!   Δ = q̂ − q,  q̈_θ = a₀Δ − (6/τ)q̇ − 2q̈,  q̇_θ = a₂Δ − 2q̇ − (τ/2)q̈
//!   res = f_r − M_r(q̈_θ + α q̇_θ) − Σ_e wₑ V_eᵀ Rₑ Kₑ(yₑ + β Rₑᵀ V_e q̇_θ)
//!   J = (1 + a₂β) K_t,r(q̂) + (a₀ + a₂α) M_r   (refreshed as below; dense Cholesky)
//!   δ = J⁻¹ res, q̂ ← q̂ + δ;  converged when η‖δ‖ ≤ tol max(‖q̂‖, 1e-3 max‖q‖_training)
//! (q, q̇, q̈) ← Wilson-θ advance with q̂
//! ```
//! The Newton test bounds the error of the accepted iterate, not its last increment (the
//! simplified-Newton stopping rule of Hairer & Wanner, Solving ODEs II §IV.8, as in RADAU5):
//! the (modified) Newton iteration contracts, ‖δₖ₊₁‖ ≤ ρ‖δₖ‖ with ρ < 1, so the distance of
//! q̂ₖ to the root is ≤ Σⱼ₊ₖ‖δⱼ‖ ≤ ρ/(1 − ρ)‖δₖ‖ = η‖δₖ‖. From the second iteration of a step
//! ρ is this step's ‖δₖ‖/‖δₖ₋₁‖; at the first, η is the last measured one (same J unless
//! refreshed), grown as η ← η^0.8 after each step accepted at its first iteration (so that a
//! run of one-iteration steps soon measures ρ again). η is
//! capped at 1 (ρ ≥ ½ or no estimate yet: η = 1, the plain test ‖δ‖ ≤ tol …, never stricter
//! than that). With the frozen J converged to a few ‰ the first increment is usually
//! accepted, which saves the confirming force evaluation; the accepted q̂ is then within
//! tol·‖q̂‖ of the root (estimated) where the plain test left it within ρ·tol·‖q̂‖.

//! J (warped tangent K_t,r = Σ wₑ V_eᵀ Rₑ Kₑ Rₑᵀ V_e) is refreshed at the first step, at the
//! first iteration of a step after a step that needed more than [`SLOW_ITERATIONS`]
//! iterations or after an update that moved q to another operating point of the gain schedule
//! (docs/design.md §11.5), at every iteration of a step after its first increment that did not
//! shrink (‖δₖ‖ ≥ ‖δₖ₋₁‖: the frozen J no longer contracts, and a J refreshed only once
//! went stale again within the step: full Newton from there on), and once within a step at
//! iteration [`SLOW_ITERATIONS`]: a modified Newton iteration converging to the same root.
//! Backtracking: an iterate whose residual meets an inverted sampled element is not refused at
//! once; it is moved halfway back to the last iterate of the step whose residual was admissible
//! (q itself before the first), J is refreshed there, up to [`BACKTRACK_HALVINGS`] times per
//! step (a damped Newton step; the step is refused only when the halvings run out), and the
//! Newton test is the plain one (η = 1) until a contraction is measured again. Both
//! safeguards act only where the plain iteration fails: after a sparse marker update that
//! moved q far (docs/design.md §11.5, the meniscus's 30 Hz filter) the stale J made the
//! increments grow into an inverted element. Nothing allocates per step.
//!
//! Filter (docs/design.md §11.4–11.5): the gains of the filter of the schedule whose operating
//! point is nearest to q ([`TierModel::nearest_filter`]; filter 0 is the one designed at rest),
//! chosen after each step; an update s⁺ = s⁻ + K_i ν is iterated to the filter i nearest to
//! its own result s⁺ (at most one pass per filter).

mod model;
pub(crate) mod recursion;

use crate::covariance::gate_rejects;
pub use crate::covariance::Gate;
use crokf_kernel::wilson::WilsonTheta;
use crokf_kernel::{self as kernel, Mat3, PolarError};
use model::dot;
pub use model::TierModel;
pub use recursion::{linearised_step, SETTLED, SETTLING_RATE};

/// Iterations after which J is refreshed (within a step, and at the next step).
pub const SLOW_ITERATIONS: usize = 4;

/// Halvings per step of an iterate whose residual met an inverted element (module docs): 12
/// bring it within 2⁻¹² of the last admissible iterate.
pub const BACKTRACK_HALVINGS: usize = 12;

/// Floor of the Newton test's scale, as a fraction of the largest training ‖q‖: converged
/// when ‖δq‖ ≤ tol · max(‖q̂‖, QUIET · max‖q‖_training).
pub const QUIET: f64 = 1e-3;

/// Why a tier step was refused (the estimator is unchanged).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TierError {
    /// Newton did not converge within the model's iteration bound.
    #[error(
        "co-rotational step {step}: Newton did not converge in {iterations} iterations \
         (last relative increment {increment:.3e}, tolerance {tolerance:.1e}); step refused"
    )]
    NotConverged {
        /// Step k being computed.
        step: u64,
        /// Iterations done.
        iterations: usize,
        /// ‖δq‖/‖q̂‖ of the last iteration.
        increment: f64,
        /// The model's tolerance.
        tolerance: f64,
    },
    /// A sampled element is inverted or degenerate at the Newton iterate.
    #[error(
        "co-rotational step {step}: sampled element {element} is inverted (det F = {det:.3e}); \
         step refused"
    )]
    InvertedElement {
        /// Step k being computed.
        step: u64,
        /// Index into the model's sampled elements.
        element: usize,
        /// det F.
        det: f64,
    },
    /// The Newton matrix is not positive definite.
    #[error("co-rotational step {step}: the Newton matrix is not positive definite at pivot {pivot}; step refused")]
    NotPositiveDefinite {
        /// Step k being computed.
        step: u64,
        /// Failing pivot.
        pivot: usize,
    },
    /// The iterate became non-finite.
    #[error("co-rotational step {step}: non-finite reduced state; step refused")]
    NonFinite {
        /// Step k being computed.
        step: u64,
    },
}

/// Where a completed step left the training envelope (reported, the step is kept).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvelopeStatus {
    /// Largest ratio |f_g| / max_force_g over the load groups this step (> 1: a load beyond
    /// training; +∞ for a load on a group never trained).
    pub load_ratio: f64,
    /// ‖q‖ / max training ‖q‖ after the step (> `state_margin`: outside).
    pub state_ratio: f64,
    /// The model's state margin.
    pub state_margin: f64,
}

impl EnvelopeStatus {
    /// True when a load or the state is outside the training envelope.
    pub fn outside(&self) -> bool {
        self.load_ratio > 1.0 + 1e-9 || self.state_ratio > self.state_margin
    }
}

/// What a completed tier step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TierStatus {
    /// Newton iterations (force evaluations).
    pub iterations: usize,
    /// Whether J was refreshed (reduced tangent + Cholesky).
    pub refreshed: bool,
    /// The envelope check.
    pub envelope: EnvelopeStatus,
}

/// The tier's stepper and filter state with all scratch (allocated once).
#[derive(Clone, Debug)]
pub struct TierState {
    /// s = (q, q̇, q̈, f), n = 3r + force states.
    pub(crate) s: Vec<f64>,
    /// Previous s (rollback of a step) and the update's scratch.
    pub(crate) s_prev: Vec<f64>,
    q_hat: Vec<f64>,
    acc: Vec<f64>,
    vel: Vec<f64>,
    force: Vec<f64>,
    res: Vec<f64>,
    load: Vec<f64>,
    jac: Vec<f64>,
    /// J before its factorisation (the covariance recursion's linearised step,
    /// [`recursion`]).
    newton: Vec<f64>,
    has_factor: bool,
    slow: bool,
    /// Error factor η of the Newton test (module docs), carried across steps.
    eta: f64,
    rotations: Vec<Mat3>,
    /// The tangent's per-lane sums ([`kernel::Blocks::tangent_scratch_len`]).
    scratch: Vec<f64>,
    /// The force evaluation's per-lane sums ([`kernel::Blocks::scratch_len`]).
    force_scratch: Vec<f64>,
    group_force: Vec<[f64; 3]>,
    /// The filter of the gain schedule in use ([`TierModel::nearest_filter`] of the last
    /// step's q).
    pub(crate) filter: usize,
    /// `filter` before the last step (restored with `s_prev` by [`TierState::rollback`]).
    filter_prev: usize,
    /// The filter whose gain gave `s_upd` (committed with it).
    pub(crate) filter_upd: usize,
    /// The force-σ level in use (docs/design.md §11.10; 0: the designed σ).
    pub(crate) level: usize,
    /// Innovation scratch.
    pub(crate) innovation: Vec<f64>,
    /// Per active channel of the last update: whether its value was used (present, not gated).
    pub(crate) present: Vec<bool>,
    /// The update's result before it is committed.
    pub(crate) s_upd: Vec<f64>,
}

impl TierState {
    /// At rest.
    pub fn new(model: &TierModel, loads: usize) -> Self {
        let r = model.r;
        let q = model.channel.len();
        TierState {
            s: vec![0.0; model.n],
            s_prev: vec![0.0; model.n],
            q_hat: vec![0.0; r],
            acc: vec![0.0; r],
            vel: vec![0.0; r],
            force: vec![0.0; r],
            res: vec![0.0; r],
            load: vec![0.0; r],
            jac: vec![0.0; r * r],
            newton: vec![0.0; r * r],
            has_factor: false,
            slow: true,
            eta: 1.0,
            rotations: vec![kernel::IDENTITY; model.blocks.len()],
            scratch: vec![0.0; model.blocks.tangent_scratch_len()],
            force_scratch: vec![0.0; model.force_scratch_len()],
            group_force: vec![[0.0; 3]; loads],
            filter: 0,
            filter_prev: 0,
            filter_upd: 0,
            level: 0,
            innovation: vec![0.0; q],
            present: vec![false; q],
            s_upd: vec![0.0; model.n],
        }
    }

    /// Back to rest (the cached Newton matrix is kept).
    pub fn reset(&mut self) {
        self.s.iter_mut().for_each(|v| *v = 0.0);
        self.filter = 0;
        self.filter_prev = 0;
        self.level = 0;
        self.slow = true;
        self.eta = 1.0;
    }

    /// q (r).
    pub fn coordinates<'a>(&'a self, model: &TierModel) -> &'a [f64] {
        &self.s[..model.r]
    }

    /// The estimated forces f (3 per random-walk load group, world frame, N; empty without
    /// force states), in the order of the tier's `force_loads`.
    pub fn forces<'a>(&'a self, model: &TierModel) -> &'a [f64] {
        &self.s[3 * model.r..3 * model.r + model.force_channels.len()]
    }

    /// Residual and rotations at q̂ (`self.force` ← f_int + β K_t q̇_θ, then `self.res`).
    fn residual(&mut self, model: &TierModel, step: u64) -> Result<(), TierError> {
        let r = model.r;
        let w = wilson(model);
        let (q, v, a) = (&self.s[..r], &self.s[r..2 * r], &self.s[2 * r..]);
        for i in 0..r {
            let du = self.q_hat[i] - q[i];
            self.acc[i] = w.a0 * du - w.a1 * v[i] - 2.0 * a[i];
            self.vel[i] = w.a2 * du - 2.0 * v[i] - 0.5 * w.tau * a[i];
        }
        match model.blocks.reduced_force(
            model.isa,
            &self.q_hat,
            &self.vel,
            model.beta,
            &mut self.force,
            &mut self.rotations,
            &mut self.force_scratch,
        ) {
            Ok(()) => {}
            Err((e, PolarError::Inverted(det))) => {
                return Err(TierError::InvertedElement {
                    step,
                    element: e,
                    det,
                })
            }
            Err((_, PolarError::NoConvergence)) => return Err(TierError::NonFinite { step }),
        }
        for i in 0..r {
            let mut m = 0.0;
            for j in 0..r {
                m += model.mass[i * r + j] * (self.acc[j] + model.alpha * self.vel[j]);
            }
            self.res[i] = self.load[i] - self.force[i] - m;
        }
        Ok(())
    }

    /// J at the rotations of the last residual, factored in `self.jac`.
    fn refresh(&mut self, model: &TierModel, step: u64) -> Result<(), TierError> {
        let r = model.r;
        let w = wilson(model);
        self.has_factor = false;
        let c_m = w.a0 + w.a2 * model.alpha;
        for i in 0..r * r {
            self.jac[i] = c_m * model.mass[i];
        }
        let scale = 1.0 + w.a2 * model.beta;
        model.blocks.add_warped_tangent(
            model.isa,
            &self.rotations,
            scale,
            &mut self.jac,
            &mut self.scratch,
        );
        self.newton.copy_from_slice(&self.jac);
        kernel::cholesky(&mut self.jac, r)
            .map_err(|pivot| TierError::NotPositiveDefinite { step, pivot })?;
        self.has_factor = true;
        Ok(())
    }

    /// One step with inputs `u` (m, `Model::inputs` order) plus the estimated forces f on their
    /// channels; `step` is the step index being computed (for messages). f is carried
    /// unchanged (random walk). On error s is unchanged.
    pub fn step(
        &mut self,
        model: &TierModel,
        u: &[f64],
        step: u64,
    ) -> Result<TierStatus, TierError> {
        let r = model.r;
        let forces = &self.s[3 * r..];
        // f_r = VᵀB (u + f) and the per-group world force.
        for i in 0..r {
            let row = &model.input[i * model.m..(i + 1) * model.m];
            let mut v: f64 = row.iter().zip(u).map(|(a, b)| a * b).sum();
            for (&ch, &fk) in model.force_channels.iter().zip(forces) {
                v += row[ch] * fk;
            }
            self.load[i] = v;
        }
        self.group_force.iter_mut().for_each(|g| *g = [0.0; 3]);
        for (j, ch) in model.channel_load.iter().enumerate() {
            if let Some((g, c)) = *ch {
                self.group_force[g][c] += u[j];
            }
        }
        for (&ch, &fk) in model.force_channels.iter().zip(forces) {
            if let Some((g, c)) = model.channel_load[ch] {
                self.group_force[g][c] += fk;
            }
        }
        let mut load_ratio: f64 = 0.0;
        for (g, f) in self.group_force.iter().enumerate() {
            let size = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            if size > 0.0 {
                load_ratio = load_ratio.max(match model.max_force[g] {
                    Some(max) => size / max,
                    None => f64::INFINITY,
                });
            }
        }
        // Taylor predictor q̂₀ = q + τq̇ + (τ²/2)q̈ (the compiler's `ReducedNewton::predictor`);
        // `res` holds the last step taken towards q̂ (here q̂₀ − q), which a backtracking halving
        // undoes by halves (module docs).
        let tau = wilson(model).tau;
        for i in 0..r {
            self.q_hat[i] = self.s[i] + tau * self.s[r + i] + 0.5 * tau * tau * self.s[2 * r + i];
            self.res[i] = self.q_hat[i] - self.s[i];
        }
        let mut refreshed = false;
        let mut iterations = 0;
        let mut increment = f64::INFINITY;
        let mut converged = false;
        let mut previous = f64::INFINITY;
        // An increment grew (ρ ≥ 1) or an iterate was backtracked: J is refreshed at every
        // remaining iteration of the step.
        let mut growing = false;
        let mut halvings = 0;
        // The iterate was just backtracked: no contraction is measured across it.
        let mut backtracked = false;
        while iterations < model.max_iterations {
            match self.residual(model, step) {
                Ok(()) => {}
                Err(TierError::InvertedElement { .. }) if halvings < BACKTRACK_HALVINGS => {
                    // Backtracking (module docs): halfway back to the last admissible iterate,
                    // J refreshed there. The residual failed before writing `res`: it still
                    // holds the step into this iterate.
                    for (q, d) in self.q_hat.iter_mut().zip(self.res.iter_mut()) {
                        *d *= 0.5;
                        *q -= *d;
                    }
                    halvings += 1;
                    growing = true;
                    backtracked = true;
                    // The plain test until a contraction is measured again.
                    self.eta = 1.0;
                    continue;
                }
                Err(e) => return Err(e),
            }
            let refresh_now = !self.has_factor
                || (iterations == 0 && self.slow)
                || iterations == SLOW_ITERATIONS
                || growing;
            if refresh_now {
                self.refresh(model, step)?;
                refreshed = true;
            }
            kernel::cholesky_solve(&self.jac, r, &mut self.res);
            let (mut dn, mut qn) = (0.0, 0.0);
            for i in 0..r {
                self.q_hat[i] += self.res[i];
                dn += self.res[i] * self.res[i];
                qn += self.q_hat[i] * self.q_hat[i];
            }
            iterations += 1;
            if !qn.is_finite() {
                return Err(TierError::NonFinite { step });
            }
            // Relative to ‖q̂‖, floored at 1e-3 of the largest training ‖q‖: near rest the
            // increments of a round-off residual are not measured against a vanishing q̂.
            let (dn, qn) = (dn.sqrt(), qn.sqrt().max(QUIET * model.max_q));
            increment = if qn > 0.0 { dn / qn } else { 0.0 };
            // Contraction estimate: this step's ratio of increments from the second iteration
            // on, the previous steps' (grown by ^0.8) at the first (docs: `error_factor`).
            let measured = iterations > 1 && !backtracked;
            if measured {
                let rho = dn / previous;
                self.eta = if rho < 0.5 { rho / (1.0 - rho) } else { 1.0 };
            }
            // Once an increment grew, J is refreshed at every remaining iteration of the step
            // (full Newton).
            growing = growing || (measured && dn >= previous);
            backtracked = false;
            previous = dn;
            if self.eta * dn <= model.tolerance * qn {
                converged = true;
                if iterations == 1 {
                    // No ρ measured in this step: the next step's estimate grows.
                    self.eta = self.eta.max(f64::EPSILON).powf(0.8);
                }
                break;
            }
        }
        self.slow = iterations > SLOW_ITERATIONS || !converged;
        if !converged {
            return Err(TierError::NotConverged {
                step,
                iterations,
                increment,
                tolerance: model.tolerance,
            });
        }
        // Commit: Wilson-θ advance.
        self.s_prev.copy_from_slice(&self.s);
        let w = wilson(model);
        let mut qn = 0.0;
        for i in 0..r {
            let (q, v, a) = (self.s[i], self.s[r + i], self.s[2 * r + i]);
            let (q1, v1, a1) = w.advance(q, v, a, self.q_hat[i]);
            self.s[i] = q1;
            self.s[r + i] = v1;
            self.s[2 * r + i] = a1;
            qn += q1 * q1;
        }
        // Force rates (docs/design.md §11.5): f⁺ = f + Δt ḟ (f was held over the step).
        if model.force_rates {
            let nf = model.force_channels.len();
            for k in 0..nf {
                self.s[3 * r + k] += model.dt * self.s[3 * r + nf + k];
            }
        }
        self.filter_prev = self.filter;
        self.filter = model.nearest_filter(&self.s[..r]);
        Ok(TierStatus {
            iterations,
            refreshed,
            envelope: EnvelopeStatus {
                load_ratio,
                state_ratio: qn.sqrt() / model.max_q,
                state_margin: model.margin,
            },
        })
    }

    /// World displacement of sensor s: V_s q (3, m).
    pub fn sensor(&self, model: &TierModel, s: usize) -> [f64; 3] {
        let r = model.r;
        let rows = &model.sensor_rows[s];
        std::array::from_fn(|c| dot(&rows[c * r..(c + 1) * r], &self.s[..r]))
    }

    /// World displacements of node set `set` (3n, m) into `out`.
    pub fn nodes(&self, model: &TierModel, set: usize, out: &mut [f64]) {
        let r = model.r;
        for (o, row) in out.iter_mut().zip(model.node_rows[set].chunks_exact(r)) {
            *o = dot(row, &self.s[..r]);
        }
    }

    /// Innovations of phase p's channels (measurement `get(j)`, missing → 0 innovation) and
    /// `s_upd` ← s + K_p ν (not committed); returns the number of values used. No gate
    /// ([`TierState::update_gated`] with `gate = None`).
    pub fn update(
        &mut self,
        model: &TierModel,
        phase: usize,
        get: &impl Fn(usize) -> Option<f64>,
    ) -> usize {
        self.update_gated(model, phase, get, &Gate::OFF, &mut [])
    }

    /// Undoes the last step (s ← its value before the step, the filter of the schedule with
    /// it); what the estimator does when the update of a combined step fails.
    pub(crate) fn rollback(&mut self) {
        std::mem::swap(&mut self.s, &mut self.s_prev);
        self.filter = self.filter_prev;
    }

    /// The filter of the gain schedule in use (0: the one designed at rest; docs/design.md
    /// §11.5).
    pub fn filter(&self) -> usize {
        self.filter
    }

    /// Commits the last [`TierState::update`] / [`TierState::update_gated`]: s ← `s_upd`
    /// (what the estimator does after its checks).
    pub fn commit_update(&mut self) {
        std::mem::swap(&mut self.s, &mut self.s_upd);
        if self.filter_upd != self.filter {
            // The update moved q to another operating point of the schedule: the Newton matrix
            // of the previous state is refreshed at the next step's first iteration.
            self.slow = true;
        }
        self.filter = self.filter_upd;
    }

    /// The filter state s = (q, q̇, q̈, f) (length [`TierModel::state_dim`]).
    pub fn state(&self) -> &[f64] {
        &self.s
    }

    /// The last update's uncommitted result (length [`TierModel::state_dim`]).
    pub fn pending_update(&self) -> &[f64] {
        &self.s_upd
    }

    /// [`TierState::update`] with the innovation gate of the warped tier (runtime/src/
    /// estimator.rs, docs/design.md §6): an active channel j whose innovation
    /// ν_j = y_j − (V_s q⁻)_c exceeds it, ν_j² > g² (s_j + n_j g_j) with s_j = (H P⁻ Hᵀ + R)_jj,
    /// g_j = (H Q Hᵀ)_jj and n_j = `gate.missed(j)`, is treated as missing and flagged in
    /// `gated_now[a]` (a: its position among the phase's active channels; `gated_now` at least
    /// that long when the gate is on). Returns the number of values used (present, not gated).
    /// Nothing is committed: `s_upd` holds the result.
    pub fn update_gated(
        &mut self,
        model: &TierModel,
        phase: usize,
        get: &impl Fn(usize) -> Option<f64>,
        gate: &Gate<'_>,
        gated_now: &mut [bool],
    ) -> usize {
        let variance =
            model.innovation_variance(model.filter_index(self.level, self.filter), phase);
        let used = self.innovations(model, phase, get, gate, gated_now, variance);
        self.apply_stored_gain(model, phase);
        used
    }

    /// The innovations of phase p's active channels into `innovation` (0 for a channel
    /// missing or gated) and their use into `present`; the gate tests channel a against the
    /// innovation variance `variance[a]` (see [`TierState::update_gated`]). Returns the number
    /// of values used.
    pub(crate) fn innovations(
        &mut self,
        model: &TierModel,
        phase: usize,
        get: &impl Fn(usize) -> Option<f64>,
        gate: &Gate<'_>,
        gated_now: &mut [bool],
        variance: &[f64],
    ) -> usize {
        let measured = &model.measured[phase];
        let mut used = 0;
        for (a, &j) in measured.iter().enumerate() {
            let j = j as usize;
            let (s, c) = model.channel[j];
            // (V_s q)_c: the one row this channel needs (what `sensor` gives for component c).
            let r = model.r;
            let row = &model.sensor_rows[s][c * r..(c + 1) * r];
            let nu = get(j).map(|y| y - dot(row, &self.s[..r]));
            let rejected = match (nu, gate.sigmas) {
                (Some(nu), Some(g)) => {
                    gate_rejects(nu, g, variance[a], gate.missed(j), model.variance_growth[j])
                }
                _ => false,
            };
            if let Some(flag) = gated_now.get_mut(a) {
                *flag = rejected;
            }
            self.present[a] = nu.is_some() && !rejected;
            self.innovation[a] = match nu {
                Some(nu) if !rejected => {
                    used += 1;
                    nu
                }
                _ => 0.0,
            };
        }
        used
    }

    /// `s_upd` ← s + K_p ν with the stored gains and the innovations of
    /// [`TierState::innovations`].
    pub(crate) fn apply_stored_gain(&mut self, model: &TierModel, phase: usize) {
        let nm = model.measured[phase].len();
        // Iterated scheduled update (docs/design.md §11.5): the gain of the filter whose point
        // is nearest to the result, starting from the prior's; at most one pass per filter.
        // s_upd = s + K_p ν as Σ_a ν_a K_p[·, a] (contiguous columns: vector operations), each
        // entry summed over a in order, so s_i + (K_p ν)_i as the row-by-row product has it.
        let n = self.s_upd.len();
        let mut filter = self.filter;
        let passes = model.filter_count();
        for pass in 0..passes {
            let gain_t = &model.filters[model.filter_index(self.level, filter)].gains_t[phase];
            self.s_upd.iter_mut().for_each(|v| *v = 0.0);
            for (column, &nu) in gain_t.chunks_exact(n).zip(&self.innovation[..nm]) {
                for (o, g) in self.s_upd.iter_mut().zip(column) {
                    *o += g * nu;
                }
            }
            for (o, si) in self.s_upd.iter_mut().zip(&self.s) {
                *o += si;
            }
            let next = model.nearest_filter(&self.s_upd[..model.r]);
            // The last pass keeps its filter: `filter_upd` names the gain s_upd was made with.
            if next == filter || pass + 1 == passes {
                break;
            }
            filter = next;
        }
        self.filter_upd = filter;
    }
}

/// The tier's Wilson-θ scheme ([`crokf_kernel::wilson`]) with its constants evaluated once per
/// call site: τ, a₀ = 6/τ², a₁ = 6/τ, a₂ = 3/τ.
#[derive(Clone, Copy)]
struct Wilson {
    scheme: WilsonTheta,
    tau: f64,
    a0: f64,
    a1: f64,
    a2: f64,
}

impl Wilson {
    /// (U, U̇, Ü) at t + Δt from Û = U(t + θΔt) ([`WilsonTheta::advance`]).
    fn advance(&self, u: f64, v: f64, a: f64, u_hat: f64) -> (f64, f64, f64) {
        self.scheme.advance(u, v, a, u_hat)
    }
}

fn wilson(model: &TierModel) -> Wilson {
    let scheme = WilsonTheta {
        dt: model.dt,
        theta: model.theta,
    };
    Wilson {
        scheme,
        tau: scheme.tau(),
        a0: scheme.mass_coefficient(),
        a1: scheme.velocity_coefficient(),
        a2: scheme.damping_coefficient(),
    }
}
