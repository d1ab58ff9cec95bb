//! The sampling floor of sparse markers (docs/design.md §11.7): how close to the truth can an
//! estimator be that is told about a withheld load only at the markers' steps?
//!
//! Markers every L steps (offset o: they arrive at the steps k ≡ L − 1 − o (mod L), the
//! convention of `nonlinear_filter`'s `--marker-phase`) are all the estimator learns of a
//! withheld load. Two oracles, each given far more than noisy markers of a few points can tell,
//! show what the samples alone would allow on a recording; both step the model's own runtime
//! ([`Estimator`]), so the model's open-loop error is in both, and both are scored as the filter
//! drivers score a run (relative L2 over the displayed nodes and the whole trajectory):
//!
//! - **onset**: at rest (the loads withheld) until the first marker step m₁ at which a load
//!   channel is nonzero, exact from m₁ on (the model's open-loop run, future loads included).
//!   An estimator that shows rest while nothing has been seen (one that is right when no load
//!   comes) cannot do better: e_onset² = (Σ_{k<m₁} ‖u_rest,k − u_ref,k‖² +
//!   Σ_{k≥m₁} ‖u_open,k − u_ref,k‖²) / Σ_k ‖u_ref,k‖².
//! - **extrapolating** with factor α: at every marker step m it is given the exact state s_m of
//!   the model's open-loop run (set after its prediction) and the loads' values u(m) and their
//!   rate over a span of d steps, u̇ = (u(m) − u(m − d))/d (u = 0 before the run; d = 1: the
//!   exact last change; d = L: the change between the last two markers, all that noise-free
//!   markers tell of a rate); between markers it steps the model with u(m) + α (k − m) u̇ on
//!   the load channels (other inputs, gravity, as given).
//!   α = 0 holds the load, the prediction of the random-walk force model (§11.4); α = 1
//!   carries the load's rate on, the prediction of the force-rate states (§11.5). Before the
//!   first marker it is the onset oracle's rest. For a rule that does not know when a load stops
//!   (a constant α), a load that ramps and then holds makes the trade-off explicit: α = 1 is
//!   exact inside the ramp and overshoots after its end, α = 0 lags the ramp and is exact in the
//!   hold. A filter with these predictions, which also has to estimate u(m), its rate and the
//!   state from noisy markers of a few points, is not expected to beat the best α of the family
//!   with d = L (not a theorem: a filter's rate may by chance fit a recording better).

use crokf_formats::{InputKind, Model};
use crokf_runtime::Estimator;

use super::reference::displayed;
use super::TierError;

/// When the markers arrive: every `period` steps, at the steps k ≡ period − 1 − offset
/// (mod period).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MarkerSteps {
    period: usize,
    offset: usize,
}

impl MarkerSteps {
    /// Markers every `period` ≥ 1 steps, `offset` < `period` steps earlier in their period
    /// (0: at steps period − 1, 2 period − 1, …, the runtime's phase 0 from rest).
    pub fn new(period: usize, offset: usize) -> Result<Self, TierError> {
        if period == 0 || offset >= period {
            return Err(TierError::Invalid(format!(
                "markers every {period} steps at offset {offset}: need period ≥ 1 and offset < period"
            )));
        }
        Ok(MarkerSteps { period, offset })
    }

    /// Whether a marker arrives at step k (0-based: after the (k + 1)-th prediction).
    pub fn at(&self, k: usize) -> bool {
        (k + 1 + self.offset).is_multiple_of(self.period)
    }
}

/// The floors of one recording and one marker schedule (relative L2 errors over the displayed
/// nodes and the whole trajectory).
#[derive(Clone, Debug, PartialEq)]
pub struct SamplingFloor {
    /// The model open loop with the loads given (the model's own error).
    pub open_loop: f64,
    /// The first marker step with a nonzero load channel (`None`: no marker sees a load).
    pub first_marker: Option<usize>,
    /// The onset oracle's error.
    pub onset: f64,
    /// Per requested α: the extrapolating oracle's error.
    pub extrapolated: Vec<(f64, f64)>,
}

impl SamplingFloor {
    /// The α of the grid with the smallest extrapolating error, and that error.
    pub fn best(&self) -> Option<(f64, f64)> {
        self.extrapolated
            .iter()
            .copied()
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }
}

/// Σ_i (u_i − u_ref,i)² and Σ_i u_ref,i² of one step.
fn squared(approx: &[f64], exact: &[f64]) -> (f64, f64) {
    approx.iter().zip(exact).fold((0.0, 0.0), |(e, r), (a, b)| {
        (e + (a - b) * (a - b), r + b * b)
    })
}

/// The model's open-loop run on a recording (loads given), built once per recording and shared
/// by every marker schedule, rate span and α ([`OpenLoop::floor`]): the state after each
/// prediction (what the oracles are given at a marker) and each step's squared error.
pub struct OpenLoop<'a> {
    model: &'a Model,
    inputs: &'a [Vec<f64>],
    shown: &'a [Vec<f64>],
    /// Per input channel: a load (withheld before the first marker, extrapolated after).
    load: Vec<bool>,
    /// The state after the prediction of step k.
    states: Vec<Vec<f64>>,
    /// Per step: Σ (u − u_ref)² over the displayed nodes.
    error2: Vec<f64>,
    /// Σ_k Σ u_ref² (the denominator of every relative error here).
    reference2: f64,
}

impl<'a> OpenLoop<'a> {
    /// Runs `model` open loop on `inputs` (one row per step, the model's input order; the loads
    /// given) against `shown` (the reference's displayed nodes per step, node sets in order,
    /// world frame, m: `Reference::shown`).
    pub fn run(
        model: &'a Model,
        inputs: &'a [Vec<f64>],
        shown: &'a [Vec<f64>],
    ) -> Result<Self, TierError> {
        let steps = inputs.len();
        if steps == 0 || shown.len() != steps {
            return Err(TierError::Invalid(format!(
                "sampling floor: {steps} input rows and {} reference rows (need as many, at least one)",
                shown.len()
            )));
        }
        let load: Vec<bool> = model
            .inputs
            .iter()
            .map(|i| matches!(i.kind, InputKind::Load { .. }))
            .collect();
        if let Some(k) = inputs.iter().position(|u| u.len() != load.len()) {
            return Err(TierError::Invalid(format!(
                "sampling floor: input row {k} has {} values, the model {} input channels",
                inputs[k].len(),
                load.len()
            )));
        }
        let width: usize = model.node_sets.iter().map(|s| 3 * s.node_tags.len()).sum();
        if let Some(k) = shown.iter().position(|r| r.len() != width) {
            return Err(TierError::Invalid(format!(
                "sampling floor: reference row {k} has {} values, the model displays {width} (3 per node of its node sets): not the model of this scene?",
                shown[k].len()
            )));
        }
        let mut est = Estimator::new(model)?;
        let mut row = vec![0.0; width];
        let mut states = Vec::with_capacity(steps);
        let mut error2 = Vec::with_capacity(steps);
        let mut reference2 = 0.0;
        for (u, exact) in inputs.iter().zip(shown) {
            est.predict(u)?;
            states.push(est.state().to_vec());
            displayed(&est, model, &mut row)?;
            let (e, r) = squared(&row, exact);
            error2.push(e);
            reference2 += r;
        }
        Ok(OpenLoop {
            model,
            inputs,
            shown,
            load,
            states,
            error2,
            reference2,
        })
    }

    /// The model's open-loop error (relative L2 over the displayed nodes and the run).
    pub fn error(&self) -> f64 {
        (self.error2.iter().sum::<f64>() / self.reference2).sqrt()
    }

    /// Step k's inputs with every load channel 0.
    fn withheld(&self, k: usize) -> Vec<f64> {
        self.inputs[k]
            .iter()
            .zip(&self.load)
            .map(|(&v, &is_load)| if is_load { 0.0 } else { v })
            .collect()
    }

    /// The onset and extrapolating oracles for markers at `markers`: one extrapolating run per
    /// α in `alphas`, the rate over `rate_span` ≥ 1 steps, (u(m) − u(m − rate_span)) /
    /// rate_span (1: the exact last change; the marker period: the change between the last two
    /// markers, what noise-free markers tell).
    pub fn floor(
        &self,
        markers: MarkerSteps,
        alphas: &[f64],
        rate_span: usize,
    ) -> Result<SamplingFloor, TierError> {
        if rate_span == 0 {
            return Err(TierError::Invalid(
                "sampling floor: the rate's span must be at least one step".into(),
            ));
        }
        let (model, inputs, load) = (self.model, self.inputs, &self.load);
        let span = rate_span as f64;
        let mut row = vec![0.0; self.shown[0].len()];
        let first_marker = (0..inputs.len())
            .find(|&k| markers.at(k) && inputs[k].iter().zip(load).any(|(&v, &l)| l && v != 0.0));

        // Onset: at rest until m₁, the open loop from m₁ on.
        let mut est = Estimator::new(model)?;
        let mut onset = 0.0;
        for (k, exact) in self.shown.iter().enumerate() {
            if first_marker.is_some_and(|m| k >= m) {
                onset += self.error2[k];
            } else {
                est.predict(&self.withheld(k))?;
                displayed(&est, model, &mut row)?;
                onset += squared(&row, exact).0;
            }
        }

        let mut extrapolated = Vec::with_capacity(alphas.len());
        for &alpha in alphas {
            let mut est = Estimator::new(model)?;
            let mut total = 0.0;
            let mut last: Option<usize> = None;
            for (k, exact) in self.shown.iter().enumerate() {
                let u = match last {
                    None => self.withheld(k),
                    Some(m) => {
                        let ahead = (k - m) as f64;
                        inputs[k]
                            .iter()
                            .enumerate()
                            .map(|(c, &given)| {
                                if !load[c] {
                                    return given;
                                }
                                let before = m.checked_sub(rate_span).map_or(0.0, |j| inputs[j][c]);
                                inputs[m][c] + alpha * ahead * (inputs[m][c] - before) / span
                            })
                            .collect()
                    }
                };
                est.predict(&u)?;
                if markers.at(k) {
                    est.set_state(&self.states[k])?;
                    last = Some(k);
                }
                displayed(&est, model, &mut row)?;
                total += squared(&row, exact).0;
            }
            extrapolated.push((alpha, (total / self.reference2).sqrt()));
        }
        Ok(SamplingFloor {
            open_loop: self.error(),
            first_marker,
            onset: (onset / self.reference2).sqrt(),
            extrapolated,
        })
    }
}

/// [`OpenLoop::run`] then [`OpenLoop::floor`]: the oracles of one marker schedule on a
/// recording (for several schedules, run the open loop once and call `floor` for each).
pub fn sampling_floor(
    model: &Model,
    inputs: &[Vec<f64>],
    shown: &[Vec<f64>],
    markers: MarkerSteps,
    alphas: &[f64],
    rate_span: usize,
) -> Result<SamplingFloor, TierError> {
    OpenLoop::run(model, inputs, shown)?.floor(markers, alphas, rate_span)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crokf_formats::synthetic::benchmark_model;

    /// The model's own open-loop run as the reference, and inputs that ramp on every load
    /// channel from step `start` (and hold from step `end`, if given).
    fn recording(
        model: &Model,
        start: usize,
        end: Option<usize>,
    ) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let steps: usize = 120;
        let inputs: Vec<Vec<f64>> = (0..steps)
            .map(|k: usize| {
                let t = k
                    .saturating_sub(start)
                    .min(end.map_or(usize::MAX, |e| e - start));
                (0..model.inputs.len())
                    .map(|c| 0.01 * (c + 1) as f64 * t as f64)
                    .collect()
            })
            .collect();
        let mut est = Estimator::new(model).unwrap();
        let width: usize = model.node_sets.iter().map(|s| 3 * s.node_tags.len()).sum();
        let shown = inputs
            .iter()
            .map(|u| {
                est.predict(u).unwrap();
                let mut row = vec![0.0; width];
                displayed(&est, model, &mut row).unwrap();
                row
            })
            .collect();
        (inputs, shown)
    }

    #[test]
    fn marker_steps_follow_the_runtime_phase_convention() {
        let m = MarkerSteps::new(33, 0).unwrap();
        let at: Vec<usize> = (0..100).filter(|&k| m.at(k)).collect();
        assert_eq!(at, vec![32, 65, 98]);
        let m = MarkerSteps::new(33, 28).unwrap();
        assert_eq!(
            (0..40).filter(|&k| m.at(k)).collect::<Vec<_>>(),
            vec![4, 37]
        );
        assert!(MarkerSteps::new(0, 0).is_err());
        assert!(MarkerSteps::new(5, 5).is_err());
    }

    /// Markers at every step: every oracle is the model's open loop, here exact.
    #[test]
    fn markers_at_every_step_leave_the_open_loop_error() {
        let model = benchmark_model(8, 3, 6, 10);
        let (inputs, shown) = recording(&model, 10, Some(60));
        let floor = sampling_floor(
            &model,
            &inputs,
            &shown,
            MarkerSteps::new(1, 0).unwrap(),
            &[0.0, 1.0],
            1,
        )
        .unwrap();
        assert_eq!(floor.first_marker, Some(11));
        assert!(floor.open_loop < 1e-14, "{}", floor.open_loop);
        // Before step 11 the loads are still 0 (step 10 is the ramp's first, zero, value).
        assert!(floor.onset < 1e-14, "{}", floor.onset);
        for (alpha, e) in &floor.extrapolated {
            assert!(*e < 1e-12, "α = {alpha}: {e}");
        }
    }

    /// A ramp that never ends: carrying the rate on (α = 1) is exact after the first marker,
    /// so it equals the onset floor; holding the load (α = 0) lags, and half the rate lags less.
    #[test]
    fn an_endless_ramp_is_extrapolated_exactly_and_held_with_a_lag() {
        let model = benchmark_model(8, 3, 6, 10);
        let (inputs, shown) = recording(&model, 5, None);
        let markers = MarkerSteps::new(7, 2).unwrap();
        let floor = sampling_floor(&model, &inputs, &shown, markers, &[0.0, 0.5, 1.0], 1).unwrap();
        assert_eq!(floor.first_marker, Some(11)); // 4, 11, 18, …; step 11 is the first load ≠ 0
        assert!(floor.onset > 1e-4, "{}", floor.onset);
        let e = |a: f64| floor.extrapolated.iter().find(|p| p.0 == a).unwrap().1;
        assert!(
            (e(1.0) - floor.onset).abs() < 1e-9 * floor.onset,
            "{} {}",
            e(1.0),
            floor.onset
        );
        assert!(
            e(0.0) > e(0.5) && e(0.5) > 1.01 * e(1.0),
            "{:?}",
            floor.extrapolated
        );
        assert_eq!(floor.best(), Some((1.0, e(1.0))));
    }

    /// The rate between the last two markers (d = L) is exact from the second marker after
    /// the ramp's start on, short at the first (the ramp began after the marker before): above
    /// the exact rate's floor, below holding the load.
    #[test]
    fn the_rate_between_two_markers_lags_only_at_the_start() {
        let model = benchmark_model(8, 3, 6, 10);
        let (inputs, shown) = recording(&model, 5, None);
        let markers = MarkerSteps::new(7, 2).unwrap();
        let exact = sampling_floor(&model, &inputs, &shown, markers, &[0.0, 1.0], 1).unwrap();
        let two = sampling_floor(&model, &inputs, &shown, markers, &[0.0, 1.0], 7).unwrap();
        // Holding the load does not use the rate.
        assert_eq!(exact.extrapolated[0], two.extrapolated[0]);
        let (e_exact, e_two, e_hold) = (
            exact.extrapolated[1].1,
            two.extrapolated[1].1,
            two.extrapolated[0].1,
        );
        assert!(
            e_two > 1.01 * e_exact && e_two < 0.9 * e_hold,
            "{e_exact} {e_two} {e_hold}"
        );
    }

    /// A ramp that stops between markers: carrying the rate on overshoots after its end, so
    /// α = 1 is above the onset floor; and the best α lies strictly inside (0, 1].
    #[test]
    fn a_ramp_that_stops_is_overshot_by_its_rate() {
        let model = benchmark_model(8, 3, 6, 10);
        let (inputs, shown) = recording(&model, 5, Some(50));
        let markers = MarkerSteps::new(7, 2).unwrap();
        let alphas: Vec<f64> = (0..=10).map(|i| 0.1 * i as f64).collect();
        let floor = sampling_floor(&model, &inputs, &shown, markers, &alphas, 1).unwrap();
        let e = |a: usize| floor.extrapolated[a].1;
        assert!(e(10) > 1.01 * floor.onset, "{} {}", e(10), floor.onset);
        let (best, _) = floor.best().unwrap();
        assert!(best > 0.0, "{:?}", floor.extrapolated);
        assert!(floor.extrapolated.iter().all(|&(_, v)| v >= floor.onset));
    }

    #[test]
    fn mismatched_rows_are_refused() {
        let model = benchmark_model(8, 3, 6, 10);
        let (inputs, shown) = recording(&model, 5, None);
        let m = MarkerSteps::new(7, 0).unwrap();
        assert!(sampling_floor(&model, &inputs[..10], &shown, m, &[0.0], 1).is_err());
        assert!(sampling_floor(&model, &inputs, &shown, m, &[0.0], 0).is_err());
        let mut short = inputs.clone();
        short[3].pop();
        let err = sampling_floor(&model, &short, &shown, m, &[0.0], 1).unwrap_err();
        assert!(err.to_string().contains("input row 3"), "{err}");
        let mut narrow = shown.clone();
        narrow[7].pop();
        let err = sampling_floor(&model, &inputs, &narrow, m, &[0.0], 1).unwrap_err();
        assert!(err.to_string().contains("reference row 7"), "{err}");
    }
}
