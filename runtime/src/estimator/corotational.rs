//! The co-rotational tier's step (docs/design.md §10–11): the nonlinear Wilson-θ step of
//! [`TierState`] as the prediction, the constant-gain extended update ν = y − V_s q (world
//! frame, linear) with the gain schedule, and the read-outs V q.

use crate::adaptation::{AdaptationState, ForceLevel};
use crate::covariance::Gate;
use crate::prepared::PreparedModel;
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
    /// level ([`AdaptationState::told_start`]; restored by `rollback`).
    before_prediction: Option<(usize, AdaptationState)>,
    /// Whether the last prediction moved the level.
    prediction_moved: bool,
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
        }
    }

    /// After a committed update of `phase` at `step` (whose prior used stored filter
    /// `filter`): the accepted channels' whitened innovations ν_a / √s_a enter the statistic,
    /// which sets the level of the next step.
    fn adapt(
        &mut self,
        tm: &TierModel,
        phase: usize,
        filter: usize,
        step: u64,
        verdicts: &[Verdict],
    ) {
        let (Some(levels), Some(adaptation)) = (tm.levels(), self.adaptation.as_mut()) else {
            return;
        };
        let measured = tm.measured(phase);
        let variance = tm.innovation_variance(filter, phase);
        for (a, z) in self.whitened[..measured.len()].iter_mut().enumerate() {
            *z = if verdicts[a] == Verdict::Accepted {
                self.state.innovation[a] / variance[a].sqrt()
            } else {
                f64::NAN
            };
        }
        self.state.level = adaptation.observe(
            levels,
            self.state.level,
            step,
            measured,
            &self.whitened[..measured.len()],
            self.told,
        );
    }
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
            if let Some(level) = adaptation.told_start(levels, self.state.level, self.told) {
                before.0 = self.state.level;
                before.1.copy_from(adaptation);
                adaptation.moved_at(step);
                self.state.level = level;
                self.prediction_moved = true;
            }
        }
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
        let used = self
            .state
            .update_gated(tm, phase, &get, gate, &mut self.gated);
        if let Some(index) = first_non_finite(&self.state.s_upd) {
            return Err(RuntimeError::NonFiniteState {
                step: gate.step,
                stage: "update",
                index,
            });
        }
        self.state.commit_update();
        for ((&j, &rejected), verdict) in tm
            .measured(phase)
            .iter()
            .zip(&self.gated)
            .zip(verdicts.iter_mut())
        {
            *verdict = if rejected {
                Verdict::Gated
            } else if get(j as usize).is_some() {
                Verdict::Accepted
            } else {
                Verdict::Missing
            };
        }
        self.adapt(tm, phase, prior_filter, gate.step, verdicts);
        Ok(used)
    }

    fn rollback(&mut self, _shared: &PreparedModel) {
        self.state.rollback();
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

    fn std<'a>(
        &self,
        shared: &'a PreparedModel,
        kind: CovarianceKind,
        phase: usize,
    ) -> (&'a [f64], &'a [Vec<f64>]) {
        let kind = match kind {
            CovarianceKind::Prior => 0,
            CovarianceKind::Posterior => 1,
        };
        let tm = tier(shared);
        tm.std(
            tm.filter_index(self.state.level, self.state.filter),
            kind,
            phase,
        )
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

    fn set_force_adaptation(&mut self, on: bool) {
        if let Some(a) = self.adaptation.as_mut() {
            a.set_enabled(on);
            self.state.level = 0;
            self.prediction_moved = false;
        }
    }
}
