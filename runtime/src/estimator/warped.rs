//! The warped linear tier's step (docs/design.md §5, §6): x⁻ = F x + G u_lin with the load
//! channels rotated into the local frame, the update x = x⁻ + K_p ν over the phase's channels
//! with the measurements un-warped per sensor, and the read-outs R̃(W x) C x.

use crate::covariance::{gate_rejects, Gate};
use crate::prepared::{PhaseStd, PreparedModel};
use crate::simd::{matvec, matvec_t};
use crate::tier::TierStatus;
use crate::warp::{Vec3, Warp};
use crate::RuntimeError;
use crokf_formats::Matrix;

use super::step::{first_non_finite, CovarianceKind, TierStep, Verdict};

/// Three rows (3×r block starting at row `3i`) times x.
#[inline]
fn rows3(m: &Matrix, block: usize, x: &[f64]) -> Vec3 {
    let r = m.cols as usize;
    let base = 3 * block * r;
    let mut out = [0.0; 3];
    matvec(&m.data[base..base + 3 * r], r, x, &mut out, false);
    out
}

/// The warped tier's state x and its scratch (allocated once).
#[derive(Clone, Debug)]
pub(crate) struct WarpedStep {
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
}

impl WarpedStep {
    /// At rest, with every buffer for `prepared`.
    pub(crate) fn new(prepared: &PreparedModel) -> Self {
        let r = prepared.r;
        let ns = prepared.model.sensors.len();
        WarpedStep {
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
        }
    }

    /// x32 ← (x, x_k · 2^(−d_k), x_k · 2^(−e_k)) in single precision (d, e: the exponents of
    /// the 16-bit display displacement and rotation rows).
    fn sync_x32(&mut self, sh: &PreparedModel) {
        let (x32, scaled) = self.x32.split_at_mut(self.r);
        let (displacement, rotation) = scaled.split_at_mut(self.r);
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

    fn current_std(shared: &PreparedModel, kind: CovarianceKind, phase: usize) -> &PhaseStd {
        match kind {
            CovarianceKind::Prior => &shared.std_prior[phase],
            CovarianceKind::Posterior => &shared.std_posterior[phase],
        }
    }
}

impl TierStep for WarpedStep {
    fn boxed_clone(&self) -> Box<dyn TierStep> {
        Box::new(self.clone())
    }

    fn is_corotational(&self) -> bool {
        false
    }

    fn state(&self) -> &[f64] {
        &self.x
    }

    fn set_state(&mut self, shared: &PreparedModel, x: &[f64]) {
        self.x.copy_from_slice(x);
        self.sync_x32(shared);
    }

    fn linear_inputs(&self) -> &[f64] {
        &self.u_lin
    }

    fn add_to_state(&mut self, shared: &PreparedModel, delta: &[f64]) -> bool {
        for (x, d) in self.x.iter_mut().zip(delta) {
            *x += d;
        }
        self.sync_x32(shared);
        true
    }

    fn reset(&mut self) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
        self.x32.iter_mut().for_each(|v| *v = 0.0);
    }

    fn period(&self, shared: &PreparedModel) -> u64 {
        shared.model.kalman.period as u64
    }

    fn active<'a>(&self, shared: &'a PreparedModel, phase: usize) -> &'a [u32] {
        &shared.model.kalman.phases[phase].measured
    }

    /// x⁻ = F x + G u_lin: load channels of group g rotated into the local frame,
    /// f_lin = R(ω_g)ᵀ f_world with ω_g = W_g x (a world component without its own channel
    /// counts as 0 and its local image is dropped).
    fn predict(
        &mut self,
        sh: &PreparedModel,
        inputs: &[f64],
        step: u64,
    ) -> Result<(), RuntimeError> {
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
                step,
                stage: "prediction",
                index,
            });
        }
        std::mem::swap(&mut self.x, &mut self.x_next);
        self.sync_x32(sh);
        Ok(())
    }

    /// Per sensor with an active channel: ω̄ = W_s x⁻, y_world from the accepted measurements
    /// and the prediction R̃(ω̄) C_s x⁻ elsewhere, y_lin = R̃(ω̄)⁻¹ y_world; the gate in the
    /// world frame, channel by channel (`Estimator::update`); x = x⁻ + K_p ν.
    fn update(
        &mut self,
        sh: &PreparedModel,
        p: usize,
        get: &dyn Fn(usize) -> Option<f64>,
        gate: &Gate<'_>,
        verdicts: &mut [Verdict],
    ) -> Result<usize, RuntimeError> {
        let step = gate.step;
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
            .zip(verdicts.iter_mut())
        {
            *verdict = Verdict::Missing;
            let Some(v) = get(ch.channel) else { continue };
            let slot = &mut self.slots[ch.slot];
            let c = ch.component;
            if let Some(sigmas) = gate.sigmas {
                let j = ch.channel;
                let nu = v - slot.pred[c];
                let missed = step
                    .saturating_sub(gate.last_accepted[j])
                    .saturating_sub(ch.every);
                if gate_rejects(nu, sigmas, variance0, missed, ch.variance_growth) {
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
        for ((ch, nu), &verdict) in active.iter().zip(&mut self.innovation).zip(&*verdicts) {
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
        std::mem::swap(&mut self.x, &mut self.x_upd);
        self.sync_x32(sh);
        Ok(used)
    }

    /// predict left the previous state in x_next.
    fn rollback(&mut self, shared: &PreparedModel) {
        std::mem::swap(&mut self.x, &mut self.x_next);
        self.sync_x32(shared);
    }

    /// R̃(W_s x) C_s x.
    fn sensor_world(&self, shared: &PreparedModel, s: usize) -> Vec3 {
        let sensor = &shared.model.sensors[s];
        let u = rows3(&sensor.displacement_rows, 0, &self.x);
        Warp::new(&rows3(&sensor.rotation_rows, 0, &self.x)).warp(&u)
    }

    fn sensor_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        out: &mut [f64],
    ) {
        out.copy_from_slice(&Self::current_std(shared, kind, phase).sensors);
    }

    fn node_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        set: usize,
        out: &mut [f64],
    ) {
        out.copy_from_slice(&Self::current_std(shared, kind, phase).nodes[set]);
    }

    fn node_displacements(&self, shared: &PreparedModel, set: usize, exact: bool, out: &mut [f64]) {
        if !exact {
            crate::simd::display(&shared.display[set], &self.x32, out);
            return;
        }
        let ns = &shared.model.node_sets[set];
        for (i, o) in out.chunks_exact_mut(3).enumerate() {
            let u = rows3(&ns.displacement_rows, i, &self.x);
            let omega = rows3(&ns.rotation_rows, i, &self.x);
            o.copy_from_slice(&Warp::new(&omega).warp(&u));
        }
    }

    fn schedule_filter(&self, _shared: &PreparedModel) -> Option<usize> {
        None
    }

    fn status(&self) -> TierStatus {
        TierStatus::default()
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
