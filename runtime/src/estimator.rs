//! The online estimator: periodic steady-state Kalman filter on the reduced model, with the
//! co-rotational maps of docs/design.md §5 at its boundary. Everything is allocated in
//! [`Estimator::new`]; `predict`, `update`, `step` and the read-outs never allocate (except to
//! build an error value).
//!
//! The two tiers are two implementations of one step interface ([`step::TierStep`]):
//! [`warped`] (the warped linear model) and [`corotational`] (the co-rotational tier); this
//! module keeps what both share: the checks of inputs and measurements, the step index and
//! phase, the innovation gate's bookkeeping and the all-or-nothing combined step.

mod corotational;
mod step;
mod warped;

use crate::contact::{ContactPoint, ContactWork, ToolContact, MAX_TOOLS};
use crate::covariance::Gate;
use crate::prepared::PreparedModel;
use crate::RuntimeError;
use crokf_formats::Model;
use std::sync::Arc;

use corotational::CorotationalStep;
use step::{first_non_finite, TierStep, Verdict};
use warped::WarpedStep;

pub use step::CovarianceKind;

/// Default innovation gate, in standard deviations of the innovation (`docs/design.md` §6).
pub const DEFAULT_GATE_SIGMAS: f64 = 5.0;

/// A periodic steady-state Kalman filter over one model (`docs/design.md` §5, §6).
///
/// Step k = 1, 2, …: `predict` forms x⁻_k = F x_{k−1} + G u_lin(k) and selects phase
/// p = k mod period; `update` forms x_k = x⁻_k + K_p (y_lin − H_p x⁻_k) over the channels of
/// phase p. The state starts at rest (x₀ = 0).
///
/// Robustness: inputs and measurements are checked against the model's
/// plausibility bounds ([`PreparedModel`]) before anything changes; an active measurement
/// whose world-frame innovation ν_j exceeds the gate, ν_j² > g² (s_j + n_j g_j) with
/// s_j = (H P⁻ Hᵀ + R)_jj (local frame: equal for small rotations),
/// g_j = (H Q Hᵀ)_jj and n_j the steps channel j went without an accepted value beyond its
/// period, is skipped for that step and counted; a step whose result would not be finite is
/// refused; every failing call leaves the estimator exactly as it was.
///
/// Many estimators can share one [`PreparedModel`] ([`Estimator::from_prepared`]): the
/// matrices exist once, each estimator holds only its state and scratch (O(r + q) numbers).
#[derive(Debug)]
pub struct Estimator {
    shared: Arc<PreparedModel>,
    /// The tier's state, prediction, update and read-outs: the warped linear model, or the
    /// co-rotational tier (docs/design.md §10) when the model has one.
    tier: Box<dyn TierStep>,
    /// What the last update did with each active channel of its phase.
    verdict: Vec<Verdict>,
    /// Number of measurement channels of the model.
    channels: usize,
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
    /// The contact step's scratch and results (a model with a contact region only).
    contact: Option<Box<ContactWork>>,
}

impl Clone for Estimator {
    fn clone(&self) -> Self {
        Estimator {
            shared: Arc::clone(&self.shared),
            tier: self.tier.boxed_clone(),
            verdict: self.verdict.clone(),
            channels: self.channels,
            k: self.k,
            phase: self.phase,
            cov: self.cov,
            awaiting_update: self.awaiting_update,
            gate: self.gate,
            last_accepted: self.last_accepted.clone(),
            gated: self.gated.clone(),
            gated_total: self.gated_total,
            gated_last: self.gated_last,
            contact: self.contact.clone(),
        }
    }
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
        let q = prepared.channel.len();
        let (tier, measured): (Box<dyn TierStep>, usize) = match &prepared.tier {
            Some(t) => (
                Box::new(CorotationalStep::new(t, prepared.model.loads.len())),
                t.max_measured(),
            ),
            None => (Box::new(WarpedStep::new(&prepared)), 0),
        };
        Estimator {
            tier,
            verdict: vec![Verdict::Missing; prepared.max_measured.max(measured)],
            channels: q,
            k: 0,
            phase: 0,
            cov: CovarianceKind::Posterior,
            awaiting_update: false,
            gate: Some(DEFAULT_GATE_SIGMAS),
            last_accepted: vec![0; q],
            gated: vec![0; q],
            gated_total: 0,
            gated_last: 0,
            contact: prepared
                .contact
                .as_ref()
                .map(|c| Box::new(ContactWork::new(prepared.r, c))),
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
        self.tier.reset();
        self.last_accepted.iter_mut().for_each(|v| *v = 0);
        self.gated.iter_mut().for_each(|v| *v = 0);
        self.gated_total = 0;
        self.gated_last = 0;
        if let Some(c) = self.contact.as_mut() {
            c.reset();
        }
        self.k = 0;
        self.phase = 0;
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
    }

    /// True when the model carries the co-rotational tier (docs/design.md §10): the state is
    /// then s = (q, q̇, q̈) (3r, r the tier's basis size) and steps are nonlinear.
    pub fn is_corotational(&self) -> bool {
        self.tier.is_corotational()
    }

    /// The stored filter of the co-rotational tier in use (`None` without a tier): with P
    /// filters per level (1 + `tier.scheduled.len()`), l·P + i is force-σ level l's filter
    /// (docs/design.md §11.10; level 0 the designed σ, `kalman` and `scheduled`; level l ≥ 1
    /// `tier.force_levels[l − 1]`) at schedule point i (0 for the filter designed at rest,
    /// i ≥ 1 for `scheduled[i − 1]`, §11.5). After an update it names the filter the next
    /// update starts from: an update whose innovations change the level leaves its state made
    /// with the previous level's gain.
    pub fn tier_filter(&self) -> Option<usize> {
        self.tier.schedule_filter(&self.shared)
    }

    /// The co-rotational tier's force-σ level in use and its statistic (docs/design.md
    /// §11.10); `None` for a model with one level (no force states, or the warped tier).
    pub fn force_level(&self) -> Option<crate::ForceLevel> {
        self.tier.force_level(&self.shared)
    }

    /// The co-rotational tier filter's own covariance P of s (n × n, row-major, n =
    /// `state().len()`; P⁻ after `predict`, P after `update`) while it carries one: from an
    /// update with an active channel missing or gated until the covariance settles near the
    /// stored filter's (docs/design.md §11.11), and from a lowering of the force-σ level after
    /// an update (§11.10). `None` while the stored filter's covariances are in use (always on the
    /// warped tier); the read-out σ follow the same choice.
    pub fn tier_covariance(&self) -> Option<&[f64]> {
        self.tier.covariance()
    }

    /// Whether the force-σ level follows the innovations (default on). Either way the level
    /// returns to the designed σ (level 0) and the statistic starts afresh; off keeps it there.
    /// Switched on before the first step after `new` or `reset`, the run's first update is made
    /// at the lowest level (§11.10); later, it is not. No effect on a model with one level.
    pub fn set_force_adaptation(&mut self, on: bool) {
        self.tier.set_force_adaptation(on);
    }

    /// Whether the co-rotational tier's filter carries its own covariance while an active channel
    /// is missing or gated and after a lowering of the force-σ level (default on;
    /// docs/design.md §11.10–11.11). Off: the stored gains with a zero innovation for such a
    /// channel, the lower level's stored σ at once, and the stored σ (the recursion, if
    /// running, stops now). It costs about five times a step while it runs; no effect on the warped tier.
    pub fn set_covariance_recursion(&mut self, on: bool) {
        self.tier.set_covariance_recursion(on);
    }

    /// Status of the co-rotational tier's last completed step (Newton iterations, envelope);
    /// the default for the warped tier.
    pub fn tier_status(&self) -> crate::tier::TierStatus {
        self.tier.status()
    }

    /// The state: x (length r) for the warped tier, s = (q, q̇, q̈, f) for the tier (3r + 3 per
    /// random-walk load group, docs/design.md §11.4; s = (q, q̇, q̈, f, ḟ), 6 per group, with
    /// force rates, §11.5).
    pub fn state(&self) -> &[f64] {
        self.tier.state()
    }

    /// Overwrites the state (length of [`Estimator::state`], finite).
    pub fn set_state(&mut self, x: &[f64]) -> Result<(), RuntimeError> {
        check_len("state", self.tier.state().len(), x.len())?;
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFinite {
                what: "state",
                index: i,
                value: x[i],
            });
        }
        self.tier.set_state(&self.shared, x);
        Ok(())
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
        self.tier.active(&self.shared, self.phase)
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
        let sh = &*self.shared;
        check_len("inputs", sh.model.inputs.len(), inputs.len())?;
        let step = self.k + 1;
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

    /// The prediction after the inputs were checked; the tier keeps the previous state for a
    /// rollback.
    fn predict_checked(&mut self, inputs: &[f64]) -> Result<(), RuntimeError> {
        self.tier.predict(&self.shared, inputs, self.k + 1)?;
        let period = self.tier.period(&self.shared);
        self.k += 1;
        self.phase = (self.k % period) as usize;
        self.cov = CovarianceKind::Prior;
        self.awaiting_update = true;
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
        check_len("measurements", self.channels, measurements.len())?;
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
        for i in 0..self.channels {
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

    /// The update after the measurements were checked: the tier's update (which changes nothing
    /// on error), then the gate's bookkeeping from its verdicts.
    fn update_checked(
        &mut self,
        get: &impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        let gate = Gate {
            sigmas: self.gate,
            step: self.k,
            last_accepted: &self.last_accepted,
            every: &self.shared.every,
        };
        let used = self
            .tier
            .update(&self.shared, self.phase, get, &gate, &mut self.verdict)?;
        let mut gated = 0;
        let active = self.tier.active(&self.shared, self.phase);
        for (&j, &verdict) in active.iter().zip(&self.verdict) {
            let j = j as usize;
            match verdict {
                Verdict::Gated => {
                    self.gated[j] += 1;
                    gated += 1;
                }
                Verdict::Accepted => self.last_accepted[j] = self.k,
                Verdict::Missing => {}
            }
        }
        self.gated_total += gated as u64;
        self.gated_last = gated;
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
        Ok(used)
    }

    /// `predict(inputs)` then `update(measurements)`, all or nothing: every input and
    /// measurement is checked before the prediction, and if the update still fails (a
    /// non-invertible R̃, a non-finite result) the prediction is rolled back, so a failed step
    /// leaves the estimator exactly as before. Returns the number of measurements used.
    ///
    /// ```
    /// # let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/cantilever/model.crokf");
    /// use crokf_runtime::{load_model, Estimator};
    /// let model = load_model(path)?;
    /// let mut est = Estimator::new(&model)?;
    /// let tip_z = model.input_labels().iter().position(|l| l == "tip.z").unwrap();
    /// let mut inputs = vec![0.0; model.inputs.len()];
    /// inputs[tip_z] = -5.0; // N
    /// let y = vec![None; model.measurements.len()];
    /// for _ in 0..200 {
    ///     est.step(&inputs, &y)?;
    /// }
    /// let mut u = vec![0.0; 3 * model.sensors.len()];
    /// est.sensor_displacements(&mut u)?;
    /// assert!(u[2] < 0.0); // the tip sensor moved down
    /// // A non-finite input is refused and the estimator is unchanged.
    /// inputs[tip_z] = f64::NAN;
    /// let before = est.state().to_vec();
    /// assert!(est.step(&inputs, &y).is_err());
    /// assert_eq!(est.state(), &before[..]);
    /// # Ok::<(), crokf_runtime::RuntimeError>(())
    /// ```
    pub fn step(
        &mut self,
        inputs: &[f64],
        measurements: &[Option<f64>],
    ) -> Result<usize, RuntimeError> {
        check_len("measurements", self.channels, measurements.len())?;
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
                self.tier.rollback(&self.shared);
                (self.k, self.phase, self.cov, self.awaiting_update) = saved;
                Err(e)
            }
        }
    }

    /// One step with tools on the contact region (docs/contact.md): `predict(inputs)`, then the
    /// contact of each tool (its centre's position this step, m, model frame; at most
    /// [`MAX_TOOLS`]) solved on the predicted state and its forces added to the prediction,
    /// then `update(measurements)`. All or nothing: a non-finite tool position, a model without
    /// a contact region, a co-rotational model, bad inputs or measurements, or a non-finite
    /// result leave the estimator exactly as before. The results are read with
    /// [`Estimator::tool_contact`] and [`Estimator::contact_points`].
    pub fn step_with_tools(
        &mut self,
        tools: &[[f64; 3]],
        inputs: &[f64],
        measurements: &[Option<f64>],
    ) -> Result<usize, RuntimeError> {
        check_len("measurements", self.channels, measurements.len())?;
        self.step_with_tools_with(tools, inputs, |i| measurements[i])
    }

    /// [`Estimator::step_with_tools`] with the measurements given by `get(channel)` (as
    /// [`Estimator::step_with`]).
    pub fn step_with_tools_with(
        &mut self,
        tools: &[[f64; 3]],
        inputs: &[f64],
        get: impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        let step = self.k + 1;
        if self.shared.contact.is_none() {
            return Err(RuntimeError::NoContactRegion);
        }
        if self.tier.is_corotational() {
            return Err(RuntimeError::ContactOnTier);
        }
        if tools.len() > MAX_TOOLS {
            return Err(RuntimeError::TooManyTools {
                given: tools.len(),
                max: MAX_TOOLS,
            });
        }
        for (t, c) in tools.iter().enumerate() {
            if let Some(k) = (0..3).find(|&k| !c[k].is_finite()) {
                return Err(RuntimeError::NonFiniteTool {
                    step,
                    tool: t,
                    component: crokf_formats::component_label(k as u8),
                    value: c[k],
                });
            }
        }
        self.check_inputs(inputs)?;
        self.check_measurements(&get, step)?;
        let saved = (self.k, self.phase, self.cov, self.awaiting_update);
        if let Some(work) = self.contact.as_mut() {
            work.set_previous(self.tier.state());
        }
        self.predict_checked(inputs)?;
        let sh = &*self.shared;
        let (Some(pc), Some(work)) = (sh.contact.as_ref(), self.contact.as_mut()) else {
            unreachable!("a model with a contact region has its scratch");
        };
        work.save();
        let prior = &sh.model.kalman.phases[self.phase].prior_covariance.data;
        let solved = work.solve(
            pc,
            self.tier.state(),
            self.tier.linear_inputs(),
            tools,
            prior,
        ) && self.tier.add_to_state(sh, &work.delta);
        if !solved {
            work.restore();
            self.tier.rollback(sh);
            (self.k, self.phase, self.cov, self.awaiting_update) = saved;
            return Err(RuntimeError::NonFiniteState {
                step,
                stage: "contact",
                index: 0,
            });
        }
        match self.update_checked(&get) {
            Ok(used) => Ok(used),
            Err(e) => {
                if let Some(work) = self.contact.as_mut() {
                    work.restore();
                }
                self.tier.rollback(&self.shared);
                (self.k, self.phase, self.cov, self.awaiting_update) = saved;
                Err(e)
            }
        }
    }

    /// The last contact step's result for tool `t` (`None` without a contact step or past the
    /// tools of the last step).
    pub fn tool_contact(&self, t: usize) -> Option<&ToolContact> {
        let c = self.contact.as_ref()?;
        (t < c.tool_count).then(|| &c.tools[t])
    }

    /// Tool `t` takes hold of the contact-region node nearest its centre (where the last tool
    /// step put it), by the node's present position, among those within 1.25 tool radii: from
    /// the next tool step on the tool holds that node at its centre plus the node's present
    /// offset from it, in all three directions (a bilateral constraint: the tool pulls as well
    /// as pushes, within the region's `max_force`), and pushes nowhere else, until
    /// [`Estimator::release`] or a tool step without tool `t`. Returns the node (index into the
    /// region's nodes). Fails, changing nothing, on a model without a contact region, a tool
    /// that was not in the last tool step, or no node near enough.
    pub fn grasp(&mut self, t: usize) -> Result<usize, RuntimeError> {
        let sh = &*self.shared;
        let (Some(pc), Some(work)) = (sh.contact.as_ref(), self.contact.as_mut()) else {
            return Err(RuntimeError::NoContactRegion);
        };
        if t >= work.tool_count {
            return Err(RuntimeError::NoSuchTool {
                tool: t,
                tools: work.tool_count,
            });
        }
        work.grasp(pc, t, self.tier.state())
            .ok_or(RuntimeError::NothingToGrasp {
                tool: t,
                reach: pc.radius * (1.0 + crate::contact::CANDIDATE_MARGIN),
            })
    }

    /// Tool `t` lets go of the node it holds (nothing happens when it holds none).
    pub fn release(&mut self, t: usize) {
        if let Some(work) = self.contact.as_mut() {
            work.release(t);
        }
    }

    /// The contact-region node tool `t` holds, if any, and where it holds it: the offset of
    /// the held point from the tool's centre, m.
    pub fn grasped(&self, t: usize) -> Option<(usize, [f64; 3])> {
        self.contact.as_ref()?.grasped(t)
    }

    /// The contact points of the last contact step (nodes pressing on a tool).
    pub fn contact_points(&self) -> &[ContactPoint] {
        self.contact
            .as_ref()
            .map_or(&[], |c| &c.points[..c.point_count])
    }

    /// Whether the contact step also computes each tool force's σ from the prediction's
    /// covariance (off by default: it costs about m r² per step for m contacts).
    pub fn set_contact_force_std(&mut self, on: bool) {
        if let Some(c) = self.contact.as_mut() {
            c.with_std = on;
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

    /// World-frame displacement of every sensor, u = R̃(W_s x) C_s x, 3 per sensor (m).
    /// Fails (leaving `out` unspecified) rather than return a non-finite value.
    pub fn sensor_displacements(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        check_len(
            "sensor read-out buffer",
            3 * self.shared.model.sensors.len(),
            out.len(),
        )?;
        for (s, o) in out.chunks_exact_mut(3).enumerate() {
            o.copy_from_slice(&self.tier.sensor_world(&self.shared, s));
        }
        check_finite_readout("sensor displacements", out)
    }

    /// Standard deviation of every sensor's displacement, sqrt(diag(C_s P C_sᵀ)), 3 per sensor
    /// (m), from the stored covariance of the current phase (local frame; P⁻ after `predict`,
    /// P after `update`), or from the co-rotational tier filter's own covariance while it
    /// carries one ([`Estimator::tier_covariance`]). Refused rather than non-finite.
    pub fn sensor_std(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        check_len(
            "sensor std buffer",
            3 * self.shared.model.sensors.len(),
            out.len(),
        )?;
        self.tier
            .sensor_std(&self.shared, self.cov, self.phase, out);
        // The stored σ are finite (validated at load); the tier filter's own covariance
        // (docs/design.md §11.11) is checked here, as every read-out is.
        check_finite_readout("sensor std", out)
    }

    /// Estimated world value of every measurement channel (length q, m).
    pub fn measurement_estimates(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        let channels = &self.shared.channel;
        check_len("measurement read-out buffer", channels.len(), out.len())?;
        // Channels of one sensor are adjacent: evaluate each sensor once.
        let mut current: Option<(usize, crate::warp::Vec3)> = None;
        for (o, &(s, c)) in out.iter_mut().zip(channels) {
            let world = match current {
                Some((cs, w)) if cs == s => w,
                _ => {
                    let w = self.tier.sensor_world(&self.shared, s);
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
        self.tier.node_displacements(&self.shared, set, false, out);
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
        self.tier.node_displacements(&self.shared, set, true, out);
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
        let ns = self.node_set(set)?;
        check_len("node std buffer", 3 * ns.node_tags.len(), out.len())?;
        self.tier
            .node_std(&self.shared, self.cov, self.phase, set, out);
        check_finite_readout("node std", out)
    }
}

/// Refuses a read-out holding NaN or ±∞ (reached only through values near the f64 range).
fn check_finite_readout(what: &'static str, out: &[f64]) -> Result<(), RuntimeError> {
    match first_non_finite(out) {
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
