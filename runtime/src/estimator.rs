//! The online estimator: periodic steady-state Kalman filter on the reduced model, with the
//! co-rotational maps of docs/design.md §5 at its boundary. Everything is allocated in
//! [`Estimator::new`]; `predict`, `update`, `step` and the read-outs never allocate (except to
//! build an error value).

use crate::prepared::PreparedModel;
use crate::simd::{matvec, matvec_t};
use crate::warp::{Vec3, Warp};
use crate::RuntimeError;
use crokf_formats::{Matrix, Model};
use std::sync::Arc;

/// Which covariance the read-out standard deviations come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CovarianceKind {
    /// P⁻ of the phase (after `predict`, before `update`).
    Prior,
    /// P of the phase (after `update`, and initially phase 0).
    Posterior,
}

/// Default innovation gate, in standard deviations of the innovation (`docs/design.md` §6).
pub const DEFAULT_GATE_SIGMAS: f64 = 5.0;

/// Three rows (3×r block starting at row `3i`) times x.
#[inline]
fn rows3(m: &Matrix, block: usize, x: &[f64]) -> Vec3 {
    let r = m.cols as usize;
    let base = 3 * block * r;
    let mut out = [0.0; 3];
    matvec(&m.data[base..base + 3 * r], r, x, &mut out, false);
    out
}

/// A periodic steady-state Kalman filter over one model (`docs/design.md` §5, §6).
///
/// Step k = 1, 2, …: `predict` forms x⁻_k = F x_{k−1} + G u_lin(k) and selects phase
/// p = k mod period; `update` forms x_k = x⁻_k + K_p (y_lin − H_p x⁻_k) over the channels of
/// phase p. The state starts at rest (x₀ = 0).
///
/// Robustness (issue 14 item 2): inputs and measurements are checked against the model's
/// plausibility bounds ([`PreparedModel`]) before anything changes; an active measurement
/// whose world-frame innovation ν_j exceeds the gate, ν_j² > g² (s_j + n_j g_j) with
/// s_j = (H P⁻ Hᵀ + R)_jj (local frame: equal for small rotations),
/// g_j = (H Q Hᵀ)_jj and n_j the steps channel j went without an accepted value beyond its
/// period, is skipped for that step and counted; a step whose result would not be finite is
/// refused; every failing call leaves the estimator exactly as it was.
///
/// Many estimators can share one [`PreparedModel`] ([`Estimator::from_prepared`]): the
/// matrices exist once, each estimator holds only its state and scratch (O(r + q) numbers).
#[derive(Clone, Debug)]
pub struct Estimator {
    shared: Arc<PreparedModel>,
    r: usize,
    /// Current state x (posterior after `update`, prior after `predict`).
    x: Vec<f64>,
    /// The display read-out's operand (3r): x in single precision, then x_k · 2^(−d_k) and
    /// x_k · 2^(−e_k) for 16-bit displacement and rotation rows
    /// (`PreparedModel::displacement_scale`, `rotation_scale`).
    x32: Vec<f32>,
    /// Scratch for F x + G u, and the state before the last prediction (for a rollback).
    x_next: Vec<f64>,
    /// Scratch for x⁻ + K ν.
    x_upd: Vec<f64>,
    /// Inputs after rotating load channels into the local frame (m).
    u_lin: Vec<f64>,
    /// Per sensor slot of the current phase (`PreparedModel::phase_sensors`): the update's
    /// per-sensor scratch.
    slots: Vec<SensorSlot>,
    /// [C_s x; W_s x] of the current phase's sensors (6 each), and W_g x of the load groups.
    sensor_vals: Vec<f64>,
    load_vals: Vec<f64>,
    /// Innovation per active channel of the current phase.
    innovation: Vec<f64>,
    /// What the last update did with each active channel of its phase.
    verdict: Vec<Verdict>,
    /// Per active channel of the tier's current phase: gated in this update.
    tier_gated: Vec<bool>,
    k: u64,
    phase: usize,
    cov: CovarianceKind,
    awaiting_update: bool,
    /// Gate in σ of the innovation; `None` = off.
    gate: Option<f64>,
    /// Per measurement channel: the step of its last accepted value (0 = none yet).
    last_accepted: Vec<u64>,
    /// Per measurement channel: values skipped by the gate.
    gated: Vec<u64>,
    gated_total: u64,
    gated_last: usize,
    /// The co-rotational tier's state (docs/design.md §10), when the model has a tier: then
    /// prediction, update and read-outs use it instead of x.
    tier: Option<Box<crate::tier::TierState>>,
    /// Status of the tier's last completed step.
    tier_status: crate::tier::TierStatus,
}

impl Estimator {
    /// Validates the model, copies it into a new [`PreparedModel`] and allocates every buffer.
    pub fn new(model: &Model) -> Result<Self, RuntimeError> {
        Ok(Self::from_prepared(Arc::new(PreparedModel::new(
            model.clone(),
        )?)))
    }

    /// An estimator at rest sharing `prepared` (no copy of the model's matrices).
    pub fn from_prepared(prepared: Arc<PreparedModel>) -> Self {
        let r = prepared.r;
        let ns = prepared.model.sensors.len();
        let q = prepared.channel.len();
        Estimator {
            r,
            x: vec![0.0; r],
            x32: vec![0.0; 3 * r],
            x_next: vec![0.0; r],
            x_upd: vec![0.0; r],
            u_lin: vec![0.0; prepared.model.inputs.len()],
            slots: vec![SensorSlot::default(); ns],
            sensor_vals: vec![0.0; 6 * ns],
            load_vals: vec![0.0; 3 * prepared.model.loads.len()],
            innovation: vec![0.0; prepared.max_measured],
            verdict: vec![Verdict::Missing; prepared.max_measured],
            tier_gated: vec![false; prepared.tier.as_ref().map_or(0, |t| t.max_measured())],
            k: 0,
            phase: 0,
            cov: CovarianceKind::Posterior,
            awaiting_update: false,
            gate: Some(DEFAULT_GATE_SIGMAS),
            last_accepted: vec![0; q],
            gated: vec![0; q],
            gated_total: 0,
            gated_last: 0,
            tier: prepared
                .tier
                .as_ref()
                .map(|t| Box::new(crate::tier::TierState::new(t, prepared.model.loads.len()))),
            tier_status: Default::default(),
            shared: prepared,
        }
    }

    /// The shared, prepared model (clone the `Arc` to make more estimators over it).
    pub fn prepared(&self) -> &Arc<PreparedModel> {
        &self.shared
    }

    /// The innovation gate in standard deviations of the innovation (`None`: off).
    pub fn innovation_gate(&self) -> Option<f64> {
        self.gate
    }

    /// Sets the innovation gate: `Some(g)` skips an active measurement whose innovation exceeds
    /// g standard deviations (g > 0, finite); `None` (or a g that is not finite and > 0) turns
    /// it off. Default [`DEFAULT_GATE_SIGMAS`].
    pub fn set_innovation_gate(&mut self, sigmas: Option<f64>) {
        self.gate = sigmas.filter(|g| g.is_finite() && *g > 0.0);
    }

    /// Measurements skipped by the gate since construction or `reset`, per channel (model
    /// order).
    pub fn gated_per_channel(&self) -> &[u64] {
        &self.gated
    }

    /// Measurements skipped by the gate since construction or `reset`.
    pub fn gated_total(&self) -> u64 {
        self.gated_total
    }

    /// Measurements skipped by the gate in the last update.
    pub fn gated_last_update(&self) -> usize {
        self.gated_last
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.shared.model
    }

    /// Back to rest: x = 0, k = 0, phase 0.
    pub fn reset(&mut self) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
        self.x32.iter_mut().for_each(|v| *v = 0.0);
        self.last_accepted.iter_mut().for_each(|v| *v = 0);
        self.gated.iter_mut().for_each(|v| *v = 0);
        self.gated_total = 0;
        self.gated_last = 0;
        self.k = 0;
        self.phase = 0;
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
        if let Some(t) = &mut self.tier {
            t.reset();
        }
        self.tier_status = Default::default();
    }

    /// True when the model carries the co-rotational tier (docs/design.md §10): the state is
    /// then s = (q, q̇, q̈) (3r, r the tier's basis size) and steps are nonlinear.
    pub fn is_corotational(&self) -> bool {
        self.tier.is_some()
    }

    /// The filter of the co-rotational tier's gain schedule in use: 0 for the filter designed
    /// at rest, i ≥ 1 for `tier.scheduled[i − 1]` (docs/design.md §11.5); `None` without a tier.
    pub fn tier_filter(&self) -> Option<usize> {
        self.tier.as_ref().map(|t| t.filter())
    }

    /// Status of the co-rotational tier's last completed step (Newton iterations, envelope);
    /// the default for the warped tier.
    pub fn tier_status(&self) -> crate::tier::TierStatus {
        self.tier_status
    }

    /// The state: x (length r) for the warped tier, s = (q, q̇, q̈, f) for the tier (3r + 3 per
    /// random-walk load group, docs/design.md §11.4; s = (q, q̇, q̈, f, ḟ), 6 per group, with
    /// force rates, §11.5).
    pub fn state(&self) -> &[f64] {
        match &self.tier {
            Some(t) => &t.s,
            None => &self.x,
        }
    }

    /// Overwrites the state (length of [`Estimator::state`], finite).
    pub fn set_state(&mut self, x: &[f64]) -> Result<(), RuntimeError> {
        if let Some(t) = &mut self.tier {
            check_len("state", t.s.len(), x.len())?;
            if let Some(i) = x.iter().position(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFinite {
                    what: "state",
                    index: i,
                    value: x[i],
                });
            }
            t.s.copy_from_slice(x);
            return Ok(());
        }
        check_len("state", self.r, x.len())?;
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFinite {
                what: "state",
                index: i,
                value: x[i],
            });
        }
        self.x.copy_from_slice(x);
        self.sync_x32();
        Ok(())
    }

    /// x32 ← (x, x_k · 2^(−d_k), x_k · 2^(−e_k)) in single precision (d, e: the exponents of
    /// the 16-bit display displacement and rotation rows).
    fn sync_x32(&mut self) {
        let (x32, scaled) = self.x32.split_at_mut(self.r);
        let (displacement, rotation) = scaled.split_at_mut(self.r);
        let sh = &*self.shared;
        for ((((a, d), w), b), (&sd, &sw)) in x32
            .iter_mut()
            .zip(displacement)
            .zip(rotation)
            .zip(&self.x)
            .zip(sh.displacement_scale.iter().zip(&sh.rotation_scale))
        {
            *a = *b as f32;
            *d = *a * sd;
            *w = *a * sw;
        }
    }

    /// Number of predictions since construction or `reset` (the step index k).
    pub fn step_index(&self) -> u64 {
        self.k
    }

    /// Time of the current estimate, k·Δt (s).
    pub fn time(&self) -> f64 {
        self.k as f64 * self.shared.model.dt
    }

    /// Phase of the current step, k mod period.
    pub fn phase(&self) -> usize {
        self.phase
    }

    /// Whether the read-out standard deviations currently come from P⁻ or P.
    pub fn covariance_kind(&self) -> CovarianceKind {
        self.cov
    }

    /// Measurement channels active in the current phase (indices into `model().measurements`).
    pub fn active_measurements(&self) -> &[u32] {
        match &self.shared.model.tier {
            Some(t) => &t.kalman.phases[self.phase].measured,
            None => &self.shared.model.kalman.phases[self.phase].measured,
        }
    }

    /// x⁻ = F x + G u_lin, then k += 1 and the phase becomes k mod period.
    ///
    /// `inputs`: one world-frame value per input channel (`model().inputs`), N for load
    /// channels, a dimensionless scale for gravity. Load channels of group g are rotated into
    /// the local frame, f_lin = R(ω_g)ᵀ f_world with ω_g = W_g x (the current state; a world
    /// component without its own channel counts as 0 and its local image is dropped).
    /// Non-finite inputs, inputs beyond the plausibility bound
    /// ([`PreparedModel::input_bounds`]) and a non-finite result are refused, naming the step
    /// and channel, and leave the estimator unchanged.
    pub fn predict(&mut self, inputs: &[f64]) -> Result<(), RuntimeError> {
        self.check_inputs(inputs)?;
        self.predict_checked(inputs)
    }

    fn check_inputs(&self, inputs: &[f64]) -> Result<(), RuntimeError> {
        check_len("inputs", self.u_lin.len(), inputs.len())?;
        let step = self.k + 1;
        let sh = &*self.shared;
        for (i, (&value, &bound)) in inputs.iter().zip(&sh.input_bound).enumerate() {
            if !value.is_finite() {
                return Err(RuntimeError::NonFiniteInput {
                    step,
                    channel: sh.model.inputs[i].label.clone(),
                    value,
                });
            }
            if value.abs() > bound {
                return Err(RuntimeError::ImplausibleInput {
                    step,
                    channel: sh.model.inputs[i].label.clone(),
                    value,
                    bound,
                });
            }
        }
        Ok(())
    }

    /// The prediction after the inputs were checked; keeps the previous state in `x_next`.
    fn predict_checked(&mut self, inputs: &[f64]) -> Result<(), RuntimeError> {
        if let (Some(t), Some(tm)) = (&mut self.tier, &self.shared.tier) {
            // The tier's step leaves s unchanged on error and its previous value in s_prev.
            self.tier_status = t.step(tm, inputs, self.k + 1)?;
            let period = self
                .shared
                .model
                .tier
                .as_ref()
                .map_or(1, |t| t.kalman.period) as u64;
            self.k += 1;
            self.phase = (self.k % period) as usize;
            self.cov = CovarianceKind::Prior;
            self.awaiting_update = true;
            return Ok(());
        }
        let sh: &PreparedModel = &self.shared;
        let model = &sh.model;
        self.u_lin.copy_from_slice(inputs);
        matvec_t(&sh.load_rows_t, &self.x, &mut self.load_vals, false);
        for (g, chans) in sh.load_channels.iter().enumerate() {
            if chans.iter().all(Option::is_none) {
                continue;
            }
            let f_world: Vec3 = [0, 1, 2].map(|c| chans[c].map_or(0.0, |j| inputs[j]));
            let omega = [0, 1, 2].map(|c| self.load_vals[3 * g + c]);
            let f_lin = Warp::new(&omega).rotate_transpose(&f_world);
            for c in 0..3 {
                if let Some(j) = chans[c] {
                    self.u_lin[j] = f_lin[c];
                }
            }
        }
        matvec_t(&sh.transition_t, &self.x, &mut self.x_next, false);
        matvec_t(&sh.input_t, &self.u_lin, &mut self.x_next, true);
        if let Some(index) = first_non_finite(&self.x_next) {
            return Err(RuntimeError::NonFiniteState {
                step: self.k + 1,
                stage: "prediction",
                index,
            });
        }
        let period = model.kalman.period as u64;
        std::mem::swap(&mut self.x, &mut self.x_next);
        self.k += 1;
        self.phase = (self.k % period) as usize;
        self.cov = CovarianceKind::Prior;
        self.awaiting_update = true;
        self.sync_x32();
        Ok(())
    }

    /// Measurement update of the current phase; `measurements[i]` is the world-frame value of
    /// channel i (`model().measurements`, m), `None` when missing. Returns the number of values
    /// used (present, active and not gated).
    ///
    /// Only channels active in the phase are used (others are ignored). For each sensor with
    /// an active channel: ω̄ = W_s x⁻; the world displacement y_world is the measured
    /// components, with every other component (unmeasured, inactive, missing or gated) filled
    /// from the prediction R̃(ω̄) C_s x⁻; then y_lin = R̃(ω̄)⁻¹ y_world and the innovation of an
    /// active channel is `y_lin[c] − (C_s x⁻)[c]`; a sensor without an accepted value has zero
    /// innovation. A channel whose world-frame innovation y_world\[c\] − (R̃(ω̄) C_s x⁻)\[c\] fails
    /// the gate (see [`Estimator`]) is treated as missing.
    /// x = x⁻ + K_p · innovation. Errors — wrong length, a non-finite or implausible value,
    /// `update` without a preceding `predict`, a non-invertible R̃, a non-finite result — leave
    /// the estimator untouched.
    pub fn update(&mut self, measurements: &[Option<f64>]) -> Result<usize, RuntimeError> {
        check_len(
            "measurements",
            self.shared.channel.len(),
            measurements.len(),
        )?;
        self.update_with(|i| measurements[i])
    }

    /// [`Estimator::update`] with measurement i given by `get(i)` (i < number of channels).
    pub fn update_with(
        &mut self,
        get: impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        if !self.awaiting_update {
            return Err(RuntimeError::UpdateWithoutPredict);
        }
        self.check_measurements(&get, self.k)?;
        self.update_checked(&get)
    }

    fn check_measurements(
        &self,
        get: &impl Fn(usize) -> Option<f64>,
        step: u64,
    ) -> Result<(), RuntimeError> {
        let bound = self.shared.measurement_bound;
        for i in 0..self.shared.channel.len() {
            if let Some(value) = get(i) {
                if !value.is_finite() {
                    return Err(RuntimeError::NonFiniteMeasurement {
                        step,
                        channel: self.channel_label(i),
                        value,
                    });
                }
                if value.abs() > bound {
                    return Err(RuntimeError::ImplausibleMeasurement {
                        step,
                        channel: self.channel_label(i),
                        value,
                        bound,
                    });
                }
            }
        }
        Ok(())
    }

    /// The update after the measurements were checked. Changes nothing on error.
    fn update_checked(
        &mut self,
        get: &impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        if let (Some(t), Some(tm)) = (&mut self.tier, &self.shared.tier) {
            // Constant-gain extended filter: ν = y − V_s q (world frame, linear), s += K_p ν,
            // with the same innovation gate as the warped tier (docs/design.md §6, §11.4).
            let gate = crate::covariance::Gate {
                sigmas: self.gate,
                step: self.k,
                last_accepted: &self.last_accepted,
                every: &self.shared.every,
            };
            let used = t.update_gated(tm, self.phase, get, &gate, &mut self.tier_gated);
            if let Some(index) = t.s_upd.iter().position(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFiniteState {
                    step: self.k,
                    stage: "update",
                    index,
                });
            }
            t.commit_update();
            let mut gated = 0;
            for (&j, &rejected) in tm.measured(self.phase).iter().zip(&self.tier_gated) {
                let j = j as usize;
                if rejected {
                    self.gated[j] += 1;
                    gated += 1;
                } else if get(j).is_some() {
                    self.last_accepted[j] = self.k;
                }
            }
            self.gated_total += gated as u64;
            self.gated_last = gated;
            self.cov = CovarianceKind::Posterior;
            self.awaiting_update = false;
            return Ok(used);
        }
        let sh: &PreparedModel = &self.shared;
        let p = self.phase;
        let step = self.k;
        let active = &sh.active[p];
        let slots = sh.phase_sensors[p].len();
        // Per sensor slot of the phase: [C_s x⁻; W_s x⁻], the warp at ω̄ = W_s x⁻ and the
        // predicted world displacement R̃(ω̄) C_s x⁻, which y_world starts from.
        let vals = &mut self.sensor_vals[..6 * slots];
        matvec_t(&sh.phase_rows_t[p], &self.x, vals, false);
        for (v, slot) in vals.chunks_exact(6).zip(&mut self.slots) {
            slot.u = [v[0], v[1], v[2]];
            slot.warp = Warp::new(&[v[3], v[4], v[5]]);
            slot.pred = slot.warp.warp(&slot.u);
            slot.y = slot.pred;
            slot.accepted = 0;
        }
        // Gate in the world frame, channel by channel: ν_j = y_world − (R̃(ω̄) C_s x⁻)_c, so an
        // outlier cannot leak into its sensor's other components through the un-warp.
        for ((ch, &variance0), verdict) in active
            .iter()
            .zip(&sh.innovation_variance[p])
            .zip(&mut self.verdict)
        {
            *verdict = Verdict::Missing;
            let Some(v) = get(ch.channel) else { continue };
            let slot = &mut self.slots[ch.slot];
            let c = ch.component;
            if let Some(sigmas) = self.gate {
                let j = ch.channel;
                let nu = v - slot.pred[c];
                let missed = step
                    .saturating_sub(self.last_accepted[j])
                    .saturating_sub(ch.every);
                if crate::covariance::gate_rejects(nu, sigmas, variance0, missed, ch.variance_growth) {
                    *verdict = Verdict::Gated;
                    continue;
                }
            }
            *verdict = Verdict::Accepted;
            slot.y[c] = v;
            slot.accepted += 1;
        }
        // Un-warp: y_lin = R̃(ω̄)⁻¹ y_world, unmeasured components from the prediction; a sensor
        // without an accepted value has y_lin = C_s x⁻ (zero innovation).
        for (index, slot) in self.slots[..slots].iter_mut().enumerate() {
            if slot.accepted == 0 {
                slot.y_lin = slot.u;
                continue;
            }
            match slot.warp.unwarp(&slot.y) {
                Some(v) => slot.y_lin = v,
                None => {
                    return Err(RuntimeError::SingularWarp {
                        step,
                        sensor: sh.model.sensors[sh.phase_sensors[p][index]].name.clone(),
                        angle: slot.warp.angle(),
                    })
                }
            }
        }
        let nm = active.len();
        let mut used = 0;
        for ((ch, nu), &verdict) in active.iter().zip(&mut self.innovation).zip(&self.verdict) {
            let slot = &self.slots[ch.slot];
            *nu = slot.y_lin[ch.component] - slot.u[ch.component];
            used += (verdict == Verdict::Accepted) as usize;
        }
        self.x_upd.copy_from_slice(&self.x);
        matvec_t(&sh.gain_t[p], &self.innovation[..nm], &mut self.x_upd, true);
        if let Some(index) = first_non_finite(&self.x_upd) {
            return Err(RuntimeError::NonFiniteState {
                step,
                stage: "update",
                index,
            });
        }
        // Commit.
        let mut gated = 0;
        for (ch, &verdict) in active.iter().zip(&self.verdict) {
            match verdict {
                Verdict::Gated => {
                    self.gated[ch.channel] += 1;
                    gated += 1;
                }
                Verdict::Accepted => self.last_accepted[ch.channel] = step,
                Verdict::Missing => {}
            }
        }
        self.gated_total += gated as u64;
        self.gated_last = gated;
        std::mem::swap(&mut self.x, &mut self.x_upd);
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
        self.sync_x32();
        Ok(used)
    }

    /// `predict(inputs)` then `update(measurements)`, all or nothing: every input and
    /// measurement is checked before the prediction, and if the update still fails (a
    /// non-invertible R̃, a non-finite result) the prediction is rolled back, so a failed step
    /// leaves the estimator exactly as before.
    pub fn step(
        &mut self,
        inputs: &[f64],
        measurements: &[Option<f64>],
    ) -> Result<usize, RuntimeError> {
        check_len(
            "measurements",
            self.shared.channel.len(),
            measurements.len(),
        )?;
        self.step_with(inputs, |i| measurements[i])
    }

    /// [`Estimator::step`] with measurement i given by `get(i)` (i < number of channels).
    pub fn step_with(
        &mut self,
        inputs: &[f64],
        get: impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        self.check_inputs(inputs)?;
        self.check_measurements(&get, self.k + 1)?;
        let saved = (self.k, self.phase, self.cov, self.awaiting_update);
        self.predict_checked(inputs)?;
        match self.update_checked(&get) {
            Ok(used) => Ok(used),
            Err(e) => {
                // predict_checked left the previous state in x_next (s_prev for the tier).
                if let Some(t) = &mut self.tier {
                    t.rollback();
                }
                std::mem::swap(&mut self.x, &mut self.x_next);
                (self.k, self.phase, self.cov, self.awaiting_update) = saved;
                self.sync_x32();
                Err(e)
            }
        }
    }

    fn channel_label(&self, i: usize) -> String {
        let (s, c) = self.shared.channel[i];
        format!(
            "{}.{}",
            self.shared.model.sensors[s].name,
            crokf_formats::component_label(c as u8)
        )
    }

    /// The tier's precomputed std of the current phase: (sensors, node sets).
    fn tier_std(&self) -> Option<(&[f64], &[Vec<f64>])> {
        let tm = self.shared.tier.as_ref()?;
        let filter = self.tier.as_ref().map_or(0, |t| t.filter);
        let kind = match self.cov {
            CovarianceKind::Prior => 0,
            CovarianceKind::Posterior => 1,
        };
        Some(tm.std(filter, kind, self.phase))
    }

    fn current_std(&self) -> &crate::prepared::PhaseStd {
        match self.cov {
            CovarianceKind::Prior => &self.shared.std_prior[self.phase],
            CovarianceKind::Posterior => &self.shared.std_posterior[self.phase],
        }
    }

    /// World-frame displacement of every sensor, u = R̃(W_s x) C_s x, 3 per sensor (m).
    /// Fails (leaving `out` unspecified) rather than return a non-finite value.
    pub fn sensor_displacements(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        check_len(
            "sensor read-out buffer",
            3 * self.shared.model.sensors.len(),
            out.len(),
        )?;
        for (s, o) in out.chunks_exact_mut(3).enumerate() {
            o.copy_from_slice(&self.sensor_world(s));
        }
        check_finite_readout("sensor displacements", out)
    }

    /// World-frame displacement of sensor `s`, R̃(W_s x) C_s x (m).
    fn sensor_world(&self, s: usize) -> Vec3 {
        if let (Some(t), Some(tm)) = (&self.tier, &self.shared.tier) {
            return t.sensor(tm, s);
        }
        let sensor = &self.shared.model.sensors[s];
        let u = rows3(&sensor.displacement_rows, 0, &self.x);
        Warp::new(&rows3(&sensor.rotation_rows, 0, &self.x)).warp(&u)
    }

    /// Standard deviation of every sensor's displacement, sqrt(diag(C_s P C_sᵀ)), 3 per sensor
    /// (m), from the stored covariance of the current phase (local frame; P⁻ after `predict`,
    /// P after `update`).
    pub fn sensor_std(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        let std = match self.tier_std() {
            Some((s, _)) => s,
            None => &self.current_std().sensors,
        };
        check_len("sensor std buffer", std.len(), out.len())?;
        out.copy_from_slice(std);
        Ok(())
    }

    /// Estimated world value of every measurement channel (length q, m).
    pub fn measurement_estimates(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        let channels = &self.shared.channel;
        check_len("measurement read-out buffer", channels.len(), out.len())?;
        // Channels of one sensor are adjacent: evaluate each sensor once.
        let mut current: Option<(usize, Vec3)> = None;
        for (o, &(s, c)) in out.iter_mut().zip(channels) {
            let world = match current {
                Some((cs, w)) if cs == s => w,
                _ => {
                    let w = self.sensor_world(s);
                    current = Some((s, w));
                    w
                }
            };
            *o = world[c];
        }
        check_finite_readout("measurement estimates", out)
    }

    fn node_set(&self, set: usize) -> Result<&crokf_formats::NodeSet, RuntimeError> {
        let sets = &self.shared.model.node_sets;
        sets.get(set).ok_or(RuntimeError::NoSuchNodeSet {
            index: set,
            count: sets.len(),
        })
    }

    /// World displacement of every node of node set `set`, u_i = R̃(ω_i) u_lin,i, 3 per node
    /// (m), with u_lin,i and ω_i from the set's displacement and rotation rows stored in single
    /// precision (both in 16-bit fixed point for large sets: [`crate::DisplayRowFormat`]), dot
    /// products and the warp in f32 (`docs/design.md` §5). It differs from
    /// [`Estimator::node_displacements_exact`] by a few 1e-7 of the largest displacement with
    /// single-precision rows and by about 3e-5 (examples) to 1e-4 (a synthetic model at
    /// 2.4 rad) with 16-bit rows (measured in `tests/readout.rs`). Rotation rows that are all
    /// zero skip the warp.
    pub fn node_displacements(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        let ns = self.node_set(set)?;
        check_len("node read-out buffer", 3 * ns.node_tags.len(), out.len())?;
        if let (Some(t), Some(tm)) = (&self.tier, &self.shared.tier) {
            t.nodes(tm, set, out);
            return check_finite_readout("node displacements", out);
        }
        let rows = &self.shared.display[set];
        crate::simd::display(rows, &self.x32, out);
        check_finite_readout("node displacements", out)
    }

    /// [`Estimator::node_displacements`] from the model's f64 rows (the reference the single-
    /// precision read-out is measured against; twice the bytes).
    pub fn node_displacements_exact(
        &self,
        set: usize,
        out: &mut [f64],
    ) -> Result<(), RuntimeError> {
        let ns = self.node_set(set)?;
        check_len("node read-out buffer", 3 * ns.node_tags.len(), out.len())?;
        if let (Some(t), Some(tm)) = (&self.tier, &self.shared.tier) {
            t.nodes(tm, set, out);
            return check_finite_readout("node displacements", out);
        }
        for (i, o) in out.chunks_exact_mut(3).enumerate() {
            let u = rows3(&ns.displacement_rows, i, &self.x);
            let omega = rows3(&ns.rotation_rows, i, &self.x);
            o.copy_from_slice(&Warp::new(&omega).warp(&u));
        }
        check_finite_readout("node displacements", out)
    }

    /// World position X + u of every node of node set `set`, 3 per node (m), u from
    /// [`Estimator::node_displacements`].
    pub fn node_positions(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        self.node_displacements(set, out)?;
        let ns = &self.shared.model.node_sets[set];
        for (o, x) in out.iter_mut().zip(&ns.rest_positions.data) {
            *o += x;
        }
        Ok(())
    }

    /// Standard deviation of every node displacement of set `set` (local frame, like
    /// [`Estimator::sensor_std`]), 3 per node (m).
    pub fn node_std(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        self.node_set(set)?;
        let std = match self.tier_std() {
            Some((_, nodes)) => &nodes[set],
            None => &self.current_std().nodes[set],
        };
        check_len("node std buffer", std.len(), out.len())?;
        out.copy_from_slice(std);
        Ok(())
    }
}

/// The update's scratch for one sensor with an active channel.
#[derive(Clone, Copy, Debug)]
struct SensorSlot {
    /// u_lin predicted, C_s x⁻ (m).
    u: Vec3,
    /// The maps of ω̄ = W_s x⁻.
    warp: Warp,
    /// The predicted world displacement R̃(ω̄) C_s x⁻ (m).
    pred: Vec3,
    /// y_world: the accepted measurements, other components from `pred` (m).
    y: Vec3,
    /// y_lin = R̃(ω̄)⁻¹ y_world (m).
    y_lin: Vec3,
    /// Number of accepted components.
    accepted: u8,
}

impl Default for SensorSlot {
    fn default() -> Self {
        SensorSlot {
            u: [0.0; 3],
            warp: Warp::new(&[0.0; 3]),
            pred: [0.0; 3],
            y: [0.0; 3],
            y_lin: [0.0; 3],
            accepted: 0,
        }
    }
}

/// What an update did with an active channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Verdict {
    /// No value this step.
    Missing,
    /// Skipped by the innovation gate.
    Gated,
    /// Used.
    Accepted,
}

/// The index of the first NaN or ±∞ in `v`, if any. One vectorisable pass first
/// (Σ 0·vᵢ over four lanes is 0 exactly when every vᵢ is finite, NaN otherwise), the search
/// only on failure.
#[inline]
fn first_non_finite(v: &[f64]) -> Option<usize> {
    let mut lanes = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder().iter().fold(0.0, |acc, x| acc + 0.0 * x);
    for c in chunks {
        for l in 0..4 {
            lanes[l] += 0.0 * c[l];
        }
    }
    if (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + tail == 0.0 {
        None
    } else {
        v.iter().position(|x| !x.is_finite())
    }
}

/// Refuses a read-out holding NaN or ±∞ (reached only through values near the f64 range).
fn check_finite_readout(what: &'static str, out: &[f64]) -> Result<(), RuntimeError> {
    match out.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(RuntimeError::NonFiniteReadout { what, index }),
    }
}

fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), RuntimeError> {
    if expected == found {
        Ok(())
    } else {
        Err(RuntimeError::Length {
            what,
            expected,
            found,
        })
    }
}
