//! The co-rotational tier's step (docs/design.md §10–11): the nonlinear Wilson-θ step of
//! [`TierState`] as the prediction, the constant-gain extended update ν = y − V_s q (world
//! frame, linear) with the gain schedule, and the read-outs V q.

use crate::adaptation::{AdaptationState, ForceLevel};
use crate::covariance::Gate;
use crate::prepared::PreparedModel;
use crate::tier::recursion::Recursion;
use crate::tier::{TierModel, TierState, TierStatus};
use crate::warp::Vec3;
use crate::RuntimeError;

use super::step::{first_non_finite, CovarianceKind, TierStep, Verdict};

/// The tier's state with the update's per-channel gate flags and the force-σ adaptation
/// (allocated once).
#[derive(Clone, Debug)]
pub(crate) struct CorotationalStep {
    state: TierState,
    /// Status of the last completed step.
    status: TierStatus,
    /// Per active channel of the current phase: gated in this update.
    gated: Vec<bool>,
    /// The force-σ level's statistic (a tier with levels only; docs/design.md §11.10).
    adaptation: Option<AdaptationState>,
    /// Per active channel: the whitened innovation of the last update (NaN: not used).
    whitened: Vec<f64>,
    /// Whether every estimated load had a nonzero input at the last prediction.
    told: bool,
    /// The level and the statistic before the last prediction, when that prediction moved the
    /// level or the run's start ([`AdaptationState::start_move`]; restored by `rollback`).
    before_prediction: Option<(usize, AdaptationState)>,
    /// Whether the last prediction moved the level.
    prediction_moved: bool,
    /// The stored filter of the level before a lowering at a prediction after an update: the
    /// next update starts the covariance recursion from its prior (docs/design.md §11.10).
    transition: Option<usize>,
    /// The covariance recursion while channels are missing (docs/design.md §11.11), and
    /// whether it may run.
    recursion: Recursion,
    recursion_on: bool,
}

impl CorotationalStep {
    /// At rest, at the designed force σ.
    pub(crate) fn new(tier: &TierModel, loads: usize) -> Self {
        CorotationalStep {
            state: TierState::new(tier, loads),
            status: TierStatus::default(),
            gated: vec![false; tier.max_measured()],
            adaptation: tier
                .levels()
                .map(|_| AdaptationState::new(tier.channel_count())),
            whitened: vec![f64::NAN; tier.max_measured()],
            told: false,
            before_prediction: tier
                .levels()
                .map(|_| (0, AdaptationState::new(tier.channel_count()))),
            prediction_moved: false,
            transition: None,
            recursion: Recursion::new(tier),
            recursion_on: true,
        }
    }

    /// After a committed update of `phase` at `step` (whose prior used stored filter
    /// `filter`): the accepted channels' whitened innovations ν_a / √s_a enter the statistic,
    /// which sets the level of the next step.
    #[allow(clippy::too_many_arguments)]
    fn adapt(
        &mut self,
        tm: &TierModel,
        section: &crokf_formats::CorotationalTier,
        phase: usize,
        filter: usize,
        live: bool,
        step: u64,
        verdicts: &[Verdict],
    ) {
        let (Some(levels), Some(adaptation)) = (tm.levels(), self.adaptation.as_mut()) else {
            return;
        };
        let measured = tm.measured(phase);
        let variance = if live {
            self.recursion.variance(measured.len())
        } else {
            tm.innovation_variance(filter, phase)
        };
        for (a, z) in self.whitened[..measured.len()].iter_mut().enumerate() {
            *z = if verdicts[a] == Verdict::Accepted {
                self.state.innovation[a] / variance[a].sqrt()
            } else {
                f64::NAN
            };
        }
        let before = self.state.level;
        self.state.level = adaptation.observe(
            levels,
            self.state.level,
            step,
            measured,
            &self.whitened[..measured.len()],
            self.told,
        );
        // Lowered: the covariance of the transition (`crate::tier::recursion`).
        if self.recursion_on && levels.factor(self.state.level) < levels.factor(before) {
            self.recursion.start_at_posterior(
                section,
                tm.filter_index(before, self.state.filter_upd),
                phase,
            );
        }
    }
}

/// The stored covariances' index of `kind` (0 prior, 1 posterior).
fn kind_index(kind: CovarianceKind) -> usize {
    match kind {
        CovarianceKind::Prior => 0,
        CovarianceKind::Posterior => 1,
    }
}

/// The model file's tier section (present whenever this step is).
fn section(shared: &PreparedModel) -> &crokf_formats::CorotationalTier {
    shared
        .model
        .tier
        .as_ref()
        .expect("a co-rotational step exists only for a model with a tier")
}

/// The prepared model's tier (present whenever this step is).
fn tier(shared: &PreparedModel) -> &TierModel {
    shared
        .tier
        .as_ref()
        .expect("a co-rotational step exists only for a model with a tier")
}

impl TierStep for CorotationalStep {
    fn boxed_clone(&self) -> Box<dyn TierStep> {
        Box::new(self.clone())
    }

    fn is_corotational(&self) -> bool {
        true
    }

    fn state(&self) -> &[f64] {
        &self.state.s
    }

    fn set_state(&mut self, _shared: &PreparedModel, x: &[f64]) {
        self.state.s.copy_from_slice(x);
    }

    fn reset(&mut self) {
        self.state.reset();
        self.status = TierStatus::default();
        if let Some(a) = self.adaptation.as_mut() {
            a.reset();
        }
        self.prediction_moved = false;
        self.transition = None;
        self.recursion.reset();
    }

    fn period(&self, shared: &PreparedModel) -> u64 {
        shared.model.tier.as_ref().map_or(1, |t| t.kalman.period) as u64
    }

    fn active<'a>(&self, shared: &'a PreparedModel, phase: usize) -> &'a [u32] {
        tier(shared).measured(phase)
    }

    /// The tier's step leaves s unchanged on error and its previous value in s_prev.
    fn predict(
        &mut self,
        shared: &PreparedModel,
        inputs: &[f64],
        step: u64,
    ) -> Result<(), RuntimeError> {
        let tm = tier(shared);
        self.status = self.state.step(tm, inputs, step)?;
        self.told = tm.loads_told(inputs);
        self.prediction_moved = false;
        if let (Some(levels), Some(adaptation), Some(before)) = (
            tm.levels(),
            self.adaptation.as_mut(),
            self.before_prediction.as_mut(),
        ) {
            if let Some(m) = adaptation.start_move(levels, self.state.level, self.told) {
                // Kept for a rollback only when the start changes something.
                before.0 = self.state.level;
                before.1.copy_from(adaptation);
                let updated = adaptation.started();
                let level = adaptation.take(m, step);
                // Lowered after an update (a told start): the next update starts the recursion
                // from the prior of the level before, unless switched off.
                if self.recursion_on && updated && levels.factor(level) < levels.factor(before.0) {
                    self.transition = Some(tm.filter_index(before.0, self.state.filter));
                }
                self.state.level = level;
                self.prediction_moved = true;
            }
        }
        self.recursion.predict(tm, section(shared), &self.state);
        Ok(())
    }

    /// Constant-gain extended filter: ν = y − V_s q (world frame, linear), s += K_p ν, with the
    /// same innovation gate as the warped tier (docs/design.md §6, §11.4).
    fn update(
        &mut self,
        shared: &PreparedModel,
        phase: usize,
        get: &dyn Fn(usize) -> Option<f64>,
        gate: &Gate<'_>,
        verdicts: &mut [Verdict],
    ) -> Result<usize, RuntimeError> {
        let tm = tier(shared);
        let prior_filter = tm.filter_index(self.state.level, self.state.filter);
        let nm = tm.measured(phase).len();
        // The gate tests against the recursion's innovation variance while it runs.
        let transition = self.transition.take();
        let variance = match self.recursion.prior_variance(tm, phase) {
            Some(v) => v,
            None => tm.innovation_variance(transition.unwrap_or(prior_filter), phase),
        };
        let used = self
            .state
            .innovations(tm, phase, &get, gate, &mut self.gated, variance);
        // A channel missing or gated: the update from the recursion's covariance (module
        // docs of `crate::tier::recursion`), which then runs until it settles.
        let live =
            self.recursion.active() || (self.recursion_on && (used < nm || transition.is_some()));
        if live {
            let updated =
                self.recursion
                    .update(tm, section(shared), &mut self.state, phase, transition);
            if updated.is_err() || first_non_finite(self.recursion.pending()).is_some() {
                return Err(RuntimeError::NonFiniteCovariance { step: gate.step });
            }
        } else {
            self.state.apply_stored_gain(tm, phase);
        }
        if let Some(index) = first_non_finite(&self.state.s_upd) {
            return Err(RuntimeError::NonFiniteState {
                step: gate.step,
                stage: "update",
                index,
            });
        }
        self.state.commit_update();
        if live {
            self.recursion.commit();
        }
        // What `innovations` found per channel: gated, used, or without a value.
        for ((&rejected, &present), verdict) in self.gated[..nm]
            .iter()
            .zip(&self.state.present[..nm])
            .zip(verdicts.iter_mut())
        {
            *verdict = if rejected {
                Verdict::Gated
            } else if present {
                Verdict::Accepted
            } else {
                Verdict::Missing
            };
        }
        self.adapt(
            tm,
            section(shared),
            phase,
            prior_filter,
            live,
            gate.step,
            verdicts,
        );
        Ok(used)
    }

    fn rollback(&mut self, _shared: &PreparedModel) {
        self.state.rollback();
        self.recursion.rollback();
        self.transition = None;
        if self.prediction_moved {
            if let (Some(adaptation), Some((level, before))) =
                (self.adaptation.as_mut(), self.before_prediction.as_ref())
            {
                adaptation.copy_from(before);
                self.state.level = *level;
            }
            self.prediction_moved = false;
        }
    }

    /// V_s q.
    fn sensor_world(&self, shared: &PreparedModel, s: usize) -> Vec3 {
        self.state.sensor(tier(shared), s)
    }

    /// The recursion's σ while it runs (computed now), else the stored filter's.
    fn sensor_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        out: &mut [f64],
    ) {
        let tm = tier(shared);
        if self.recursion.active() {
            for (rows, o) in tm.sensor_rows.iter().zip(out.chunks_exact_mut(3)) {
                self.recursion.std_of_rows(tm, rows, o);
            }
        } else {
            let filter = tm.filter_index(self.state.level, self.state.filter);
            out.copy_from_slice(tm.std(filter, kind_index(kind), phase).0);
        }
    }

    fn node_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        set: usize,
        out: &mut [f64],
    ) {
        let tm = tier(shared);
        if self.recursion.active() {
            self.recursion.std_of_rows(tm, &tm.node_rows[set], out);
        } else {
            let filter = tm.filter_index(self.state.level, self.state.filter);
            out.copy_from_slice(&tm.std(filter, kind_index(kind), phase).1[set]);
        }
    }

    /// V q at the set's nodes (the tier has one read-out, in f64).
    fn node_displacements(
        &self,
        shared: &PreparedModel,
        set: usize,
        _exact: bool,
        out: &mut [f64],
    ) {
        self.state.nodes(tier(shared), set, out);
    }

    /// The stored filter in use: level l's filter at point i is l·P + i (P filters per level).
    fn schedule_filter(&self, shared: &PreparedModel) -> Option<usize> {
        Some(tier(shared).filter_index(self.state.level, self.state.filter()))
    }

    fn status(&self) -> TierStatus {
        self.status
    }

    fn force_level(&self, shared: &PreparedModel) -> Option<ForceLevel> {
        let levels = tier(shared).levels()?;
        Some(self.adaptation.as_ref()?.report(levels, self.state.level))
    }

    fn covariance(&self) -> Option<&[f64]> {
        self.recursion.covariance()
    }

    fn set_covariance_recursion(&mut self, on: bool) {
        self.recursion_on = on;
        if !on {
            self.recursion.reset();
        }
    }

    fn set_force_adaptation(&mut self, on: bool) {
        if let Some(a) = self.adaptation.as_mut() {
            a.set_enabled(on);
            self.state.level = 0;
            self.prediction_moved = false;
        }
    }
}
