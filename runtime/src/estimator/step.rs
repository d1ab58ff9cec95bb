//! The step interface of the estimator's two tiers: the warped linear tier
//! ([`super::warped`], docs/design.md §5) and the co-rotational tier ([`super::corotational`],
//! §10–11) each own their state and scratch and implement [`TierStep`]; the
//! [`Estimator`](super::Estimator) keeps what is common (checks, step index and phase, the
//! gate's bookkeeping, all-or-nothing steps) and calls the interface only.
//!
//! Contract of every implementation: nothing is allocated after construction; `predict` and
//! `update` change nothing on error; a successful `predict` keeps the state before it until
//! the next `predict`, so that `rollback` restores it exactly.

use crate::adaptation::ForceLevel;
use crate::covariance::Gate;
use crate::prepared::PreparedModel;
use crate::tier::TierStatus;
use crate::warp::Vec3;
use crate::RuntimeError;

/// Which covariance the read-out standard deviations come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CovarianceKind {
    /// P⁻ of the phase (after `predict`, before `update`).
    Prior,
    /// P of the phase (after `update`, and initially phase 0).
    Posterior,
}

/// What an update did with an active channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// No value this step.
    Missing,
    /// Skipped by the innovation gate.
    Gated,
    /// Used.
    Accepted,
}

/// One tier's state, prediction, update and read-outs over a [`PreparedModel`].
pub(crate) trait TierStep: std::fmt::Debug + Send + Sync {
    /// A copy behind a new box (the estimator is `Clone`).
    fn boxed_clone(&self) -> Box<dyn TierStep>;

    /// True for the co-rotational tier.
    fn is_corotational(&self) -> bool;

    /// The filter state: x (r) for the warped tier, s = (q, q̇, q̈, f[, ḟ]) for the tier.
    fn state(&self) -> &[f64];

    /// Overwrites the state (length of [`TierStep::state`], finite: checked by the caller).
    fn set_state(&mut self, shared: &PreparedModel, x: &[f64]);

    /// Back to rest.
    fn reset(&mut self);

    /// The period of the filter's phases.
    fn period(&self, shared: &PreparedModel) -> u64;

    /// Measurement channels active in `phase` (indices into the model's measurements).
    fn active<'a>(&self, shared: &'a PreparedModel, phase: usize) -> &'a [u32];

    /// The prediction to step `step` from the checked `inputs`; keeps the state before it for
    /// [`TierStep::rollback`]. Changes nothing on error.
    fn predict(
        &mut self,
        shared: &PreparedModel,
        inputs: &[f64],
        step: u64,
    ) -> Result<(), RuntimeError>;

    /// The update of `phase` at step `step` with the checked measurements `get(j)` and the
    /// innovation gate `gate`: per active channel of the phase its verdict into `verdict`;
    /// returns the number of values used. Changes nothing on error.
    fn update(
        &mut self,
        shared: &PreparedModel,
        phase: usize,
        get: &dyn Fn(usize) -> Option<f64>,
        gate: &Gate<'_>,
        verdict: &mut [Verdict],
    ) -> Result<usize, RuntimeError>;

    /// Restores the state before the last successful [`TierStep::predict`].
    fn rollback(&mut self, shared: &PreparedModel);

    /// World-frame displacement of sensor `s` (m).
    fn sensor_world(&self, shared: &PreparedModel, s: usize) -> Vec3;

    /// The read-out σ of every sensor (3 each, `out`'s length checked by the caller) in
    /// `phase` from covariance `kind`.
    fn sensor_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        out: &mut [f64],
    );

    /// The read-out σ of node set `set` (3 per node, `out`'s length checked by the caller) in
    /// `phase` from covariance `kind`.
    fn node_std(
        &self,
        shared: &PreparedModel,
        kind: CovarianceKind,
        phase: usize,
        set: usize,
        out: &mut [f64],
    );

    /// World displacement of every node of set `set` into `out` (3 per node, length checked
    /// by the caller); `exact`: from the model's f64 rows where the tier has a faster display
    /// read-out.
    fn node_displacements(&self, shared: &PreparedModel, set: usize, exact: bool, out: &mut [f64]);

    /// The stored filter in use (co-rotational tier only): level l's filter at schedule point
    /// i is l·P + i, P the filters per level.
    fn schedule_filter(&self, shared: &PreparedModel) -> Option<usize>;

    /// The status of the last completed step (co-rotational tier; the default otherwise).
    fn status(&self) -> TierStatus;

    /// The force-σ level in use (a tier with levels only; docs/design.md §11.10).
    fn force_level(&self, _shared: &PreparedModel) -> Option<ForceLevel> {
        None
    }

    /// Whether the force-σ level follows the innovations (off: back to the designed σ).
    fn set_force_adaptation(&mut self, _on: bool) {}

    /// Whether the filter may carry its own covariance while channels are missing (the
    /// co-rotational tier; docs/design.md §11.11).
    fn set_covariance_recursion(&mut self, _on: bool) {}

    /// Adds `delta` to the predicted state (a contact force's response, docs/contact.md);
    /// false when the tier takes no contact (the co-rotational tier).
    fn add_to_state(&mut self, _shared: &PreparedModel, _delta: &[f64]) -> bool {
        false
    }

    /// The deterministic inputs of the last prediction as the reduced model's G took them
    /// (local frame; empty for a tier that takes no contact).
    fn linear_inputs(&self) -> &[f64] {
        &[]
    }

    /// The filter's own covariance while it carries one (the co-rotational tier's recursion
    /// while channels are missing, docs/design.md §11.11), else `None`.
    fn covariance(&self) -> Option<&[f64]> {
        None
    }
}

/// The index of the first NaN or ±∞ in `v`, if any. One vectorisable pass first
/// (Σ 0·vᵢ over four lanes is 0 exactly when every vᵢ is finite, NaN otherwise), the search
/// only on failure.
#[inline]
pub(crate) fn first_non_finite(v: &[f64]) -> Option<usize> {
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
