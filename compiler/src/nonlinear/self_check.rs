//! The measured self-check of a compiled co-rotational tier (docs/design.md §10, self-check):
//! the reduced model exactly as the runtime steps it (the compiled basis V, the ECSW elements
//! and weights, M_r, and the runtime's Newton settings: [`runtime_newton`]) re-run on every
//! training run's load history and compared with that run's full-order snapshots.
//!
//! Error of training run k over its stored snapshots S_k (the states after every `every`-th
//! step and after the last, the same steps training kept), q_t the reduced state after step t:
//! ```text
//! e_k = ( Σ_{t∈S_k} ‖V q_t − u_t‖²_M  /  Σ_{t∈S_k} ‖u_t‖²_M )^½        (dimensionless)
//! ```
//! with ‖x‖²_M = xᵀ M x (kg·m²): the displacement of the whole body weighted by mass, the inner
//! product the POD basis is built in (for the M-orthonormal V, ‖V q‖_M = ‖q‖, the norm of the
//! runtime's envelope). Not over the displayed nodes: a scene's displays may be one face or
//! none, and a tier can miss a deformation (a twist) that a display happens not to see; the
//! M-norm does not depend on which nodes a scene displays, nor on local mesh refinement.
//!
//! The check is in-sample, hence optimistic: the loads are the training loads themselves and
//! a small error does not say that other histories or load combinations are followed. A large
//! error, though, means the tier cannot reproduce even what it was trained on (the twist hard
//! case of docs/results/tier.md §8), which nothing else in the compile measures. Runs are
//! computed `threads` at a time and gathered by run index: the figures do not depend on the
//! thread count.

use nalgebra::{DMatrix, DVector};

use crate::full_order::FullOrder;

use super::basis::BasisChoice;
use super::ecsw::EcswOptions;
use super::reduced::{ReducedNewton, ReducedStepper, Refresh};
use super::tier::{self as tier_build, Tier};
use super::training::{self, Training, TrainingPlan};
use super::NonlinearError;

/// Relative error e_k above which the compile warns (5 %).
pub const SELF_CHECK_THRESHOLD: f64 = 0.05;

/// Relative error e_k of a held-out run above which the compile warns (2 %): [`out_of_sample`].
pub const OUT_OF_SAMPLE_THRESHOLD: f64 = 0.02;

/// The reduced Newton settings the runtime's tier step equals (runtime/src/tier.rs; tests/
/// tests/tier.rs measures < 1e-9 relative on q): the Taylor predictor, the warped tangent
/// in J, J refreshed when the previous step took more than 4 iterations and once within a
/// step at the 4th, convergence when ‖δ‖ ≤ `tolerance`‖q̂‖, at most `iterations` iterations.
pub fn runtime_newton(tolerance: f64, iterations: usize) -> ReducedNewton {
    ReducedNewton {
        max_iterations: iterations,
        tolerance,
        refresh: Refresh::WhenSlow { iterations: 4 },
        consistent: false,
        predictor: true,
    }
}

/// The self-check of one training run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunCheck {
    /// The training run's label.
    pub label: String,
    /// e_k (module docs); +∞ when the reduced run failed, NaN when the run was not checked
    /// (its training run failed: no snapshots).
    pub error: f64,
    /// The run's displacement scale: RMS of ‖u_t‖_M over its snapshots, kg^½·m (0 when not
    /// checked); e_k is relative to it.
    pub scale: f64,
    /// Snapshots compared.
    pub snapshots: usize,
    /// Reduced steps taken.
    pub steps: usize,
    /// Reduced Newton iterations over the run.
    pub iterations: usize,
    /// Reduced steps that ended unconverged (the runtime refuses such a step).
    pub unconverged: usize,
    /// Why the run was not checked or the reduced run failed.
    pub failure: Option<String>,
    /// Σ_t e_t e_tᵀ over the run's snapshots, e_t = q_t − VᵀM u_t the reduced state's error
    /// against the best the basis can do (r × r, q²; empty when the run was not compared):
    /// the in-basis part of the model error, [`SelfCheck::model_error_covariance`].
    pub error_moment: DMatrix<f64>,
}

impl RunCheck {
    /// Whether the run was compared (its training run completed).
    pub fn checked(&self) -> bool {
        !self.error.is_nan()
    }
}

/// The self-check of a tier: one [`RunCheck`] per training run, in run order.
#[derive(Clone, Debug, PartialEq)]
pub struct SelfCheck {
    /// Per training run.
    pub runs: Vec<RunCheck>,
    /// Warning threshold on e_k.
    pub threshold: f64,
    /// Wall time, s (report only, never in the model file).
    pub seconds: f64,
}

impl SelfCheck {
    /// The checked run with the largest e_k (a failed reduced run counts as +∞).
    pub fn worst(&self) -> Option<&RunCheck> {
        self.runs
            .iter()
            .filter(|r| r.checked())
            .max_by(|a, b| a.error.total_cmp(&b.error))
    }

    /// Median of e_k over the checked runs (mean of the two middle values for an even count);
    /// NaN without a checked run.
    pub fn median(&self) -> f64 {
        let mut e: Vec<f64> = self
            .runs
            .iter()
            .filter(|r| r.checked())
            .map(|r| r.error)
            .collect();
        e.sort_by(f64::total_cmp);
        match e.len() {
            0 => f64::NAN,
            n if n % 2 == 1 => e[n / 2],
            n => 0.5 * (e[n / 2 - 1] + e[n / 2]),
        }
    }

    /// Checked runs with e_k above the threshold (or failed), worst first.
    pub fn flagged(&self) -> Vec<&RunCheck> {
        let mut out: Vec<&RunCheck> = self
            .runs
            .iter()
            .filter(|r| r.checked() && r.error > self.threshold)
            .collect();
        out.sort_by(|a, b| b.error.total_cmp(&a.error));
        out
    }

    /// Whether more than half of the compared runs are above the threshold: the tier fails its
    /// check (the compile refuses to write it unless the scene accepts that).
    pub fn fails_most(&self) -> bool {
        self.fails_most_above(self.threshold)
    }

    /// Whether more than half of the compared runs are above `threshold`.
    pub fn fails_most_above(&self, threshold: f64) -> bool {
        let (above, checked) = self.above(threshold);
        checked > 0 && 2 * above > checked
    }

    /// (runs above `threshold`, runs compared).
    pub fn above(&self, threshold: f64) -> (usize, usize) {
        let checked = self.runs.iter().filter(|r| r.checked());
        let above = checked.clone().filter(|r| r.error > threshold).count();
        (above, checked.count())
    }

    /// The largest run's displacement scale (RMS ‖u‖_M, kg^½·m).
    pub fn largest_scale(&self) -> f64 {
        self.runs.iter().map(|r| r.scale).fold(0.0, f64::max)
    }

    /// The reduced model's own error inside the basis, as a covariance (r × r, q²): the mean
    /// of e_t e_tᵀ over every snapshot of every run that completed (e_t = q_t − VᵀM u_t, the
    /// reduced state after step t against the M-orthogonal projection of the full-order
    /// state). The filter takes it as process noise (docs/design.md §11.9). None when no run
    /// completed.
    pub fn model_error_covariance(&self) -> Option<DMatrix<f64>> {
        let mut sum: Option<DMatrix<f64>> = None;
        let mut count = 0usize;
        for run in self.runs.iter().filter(|r| r.error.is_finite()) {
            if run.error_moment.is_empty() {
                continue;
            }
            count += run.snapshots;
            match sum.as_mut() {
                Some(s) if s.shape() == run.error_moment.shape() => *s += &run.error_moment,
                Some(_) => return None,
                None => sum = Some(run.error_moment.clone()),
            }
        }
        sum.filter(|_| count > 0).map(|s| s / count as f64)
    }

    /// Reduced steps that ended unconverged, over all runs.
    pub fn unconverged(&self) -> usize {
        self.runs.iter().map(|r| r.unconverged).sum()
    }

    /// The report note (deterministic: no timing).
    pub fn note(&self) -> String {
        let checked = self.runs.iter().filter(|r| r.checked()).count();
        let worst = self.worst().map_or_else(
            || "no run checked".to_owned(),
            |w| format!("worst '{}' {}", w.label, percent(w.error)),
        );
        let unconverged = match self.unconverged() {
            0 => String::new(),
            n => format!(
                "; {n} reduced steps ended at newton_iterations without ‖δ‖ ≤ \
                 newton_tolerance·‖q̂‖ (this stepper's test has no floor near rest, the \
                 runtime's has)"
            ),
        };
        format!(
            "co-rotational tier self-check (in-sample, optimistic: the runtime's reduced model \
             re-run on each training run's load history against that run's full-order \
             snapshots; relative L2 error of the displacement in the M-norm over the stored \
             snapshots, docs/design.md §10): {worst}, median {} over {checked} of {} runs \
             (threshold {}){unconverged}",
            percent(self.median()),
            self.runs.len(),
            percent(self.threshold)
        )
    }

    /// The warning when some run is above the threshold (None otherwise).
    pub fn warning(&self) -> Option<String> {
        let flagged = self.flagged();
        let worst = flagged.first()?;
        let more = match flagged.len() {
            1 => String::new(),
            n => format!(
                " (and {} more of the {} runs above it)",
                n - 1,
                self.runs.len()
            ),
        };
        let how = worst
            .failure
            .as_deref()
            .map_or_else(String::new, |f| format!(": {f}"));
        let largest = self.largest_scale();
        let size = if largest > 0.0 && worst.scale > 0.0 {
            format!(
                "; its displacement (RMS ‖u‖_M) is {} of the largest training run's",
                percent(worst.scale / largest)
            )
        } else {
            String::new()
        };
        // Most steps left unconverged at the runtime's iteration bound: its Newton settings
        // first (a few are usual: this stepper's test has no floor near rest).
        let basis = "`order`, set `basis_tolerance` (per-run energy-norm basis, with \
                     `max_order`) or tighten `ecsw_tolerance` in [reduction.corotational]";
        let steps: usize = self.runs.iter().map(|r| r.steps).sum();
        let remedy = match self.unconverged() {
            n if 2 * n <= steps => format!("Raise {basis}"),
            n => format!(
                "{n} of its {steps} reduced steps ended at `newton_iterations` without meeting \
                 `newton_tolerance`: raise `newton_iterations` first (with `newton_tolerance` \
                 near its default 1e-6); then raise {basis}"
            ),
        };
        Some(format!(
            "WARNING: the co-rotational tier does not reproduce its own training: run '{}' is {} \
             off the full-order co-rotational FEM (threshold {}){how}{size}{more}. Loads like it will \
             be as wrong at run time, with the envelope status saying \"inside\". {remedy}",
            worst.label,
            percent(worst.error),
            percent(self.threshold)
        ))
    }
}

/// `0.0123` → `1.23 %` (two significant decimals below 10 %).
pub(crate) fn percent(x: f64) -> String {
    if !x.is_finite() {
        return format!("{x}");
    }
    let p = 100.0 * x;
    if p < 10.0 {
        format!("{p:.2} %")
    } else {
        format!("{p:.1} %")
    }
}

/// Runs the self-check of `tier` built from the training of `plan` (module docs), stepping the
/// reduced model with `newton` ([`runtime_newton`] of the scene for the compiler's check),
/// `plan.threads` runs at a time.
pub fn self_check(
    full: &FullOrder,
    plan: &TrainingPlan,
    tier: &Tier,
    newton: ReducedNewton,
    threshold: f64,
) -> Result<SelfCheck, NonlinearError> {
    let all: Vec<usize> = (0..tier.training.runs.len()).collect();
    check_runs(full, plan, tier, &tier.training, &all, newton, threshold)
}

/// The check of `tier` on the runs `selected` (indices into the plan's runs, in the order
/// given) against their snapshots in `training` (which may hold runs `tier` was not built
/// from: [`out_of_sample`]).
fn check_runs(
    full: &FullOrder,
    plan: &TrainingPlan,
    tier: &Tier,
    training: &Training,
    selected: &[usize],
    newton: ReducedNewton,
    threshold: f64,
) -> Result<SelfCheck, NonlinearError> {
    let started = std::time::Instant::now();
    let runs = plan.runs();
    if training.runs.len() != runs.len() {
        return Err(NonlinearError::Invalid(format!(
            "self-check: the training has {} runs, its plan {}",
            training.runs.len(),
            runs.len()
        )));
    }
    let groups = training::plan_groups(full, plan)?;
    let mut of_run: Vec<Vec<usize>> = vec![Vec::new(); runs.len()];
    for (s, &k) in training.run_of.iter().enumerate() {
        if let Some(list) = of_run.get_mut(k) {
            list.push(s);
        }
    }
    let steps = plan.steps(full.wilson.dt);
    let kept = plan.snapshot_count(full.wilson.dt);
    let check_run = |k: usize| -> RunCheck {
        let run = &runs[k];
        let mut out = RunCheck {
            label: run.label.clone(),
            error: f64::NAN,
            scale: 0.0,
            snapshots: of_run[k].len(),
            steps: 0,
            iterations: 0,
            unconverged: 0,
            failure: None,
            error_moment: DMatrix::zeros(0, 0),
        };
        if let Some(why) = &training.runs[k].1 {
            out.failure = Some(format!("training run failed: {why}"));
            return out;
        }
        // A run cut where it left what the tier is for is replayed only that far.
        let expected = training
            .cuts
            .get(k)
            .and_then(|c| c.as_ref())
            .map_or(kept, |c| c.kept);
        if of_run[k].len() != expected {
            out.error = f64::INFINITY;
            out.failure = Some(format!(
                "{} snapshots stored, the plan keeps {expected}",
                of_run[k].len()
            ));
            return out;
        }
        let unit = DVector::from_vec(training::run_load(full, plan, &groups, run));
        let reduced_unit = tier.basis.vectors.tr_mul(&unit);
        let mut stepper = match ReducedStepper::new(tier.model.clone(), newton) {
            Ok(s) => s,
            Err(e) => {
                out.error = f64::INFINITY;
                out.failure = Some(e.to_string());
                return out;
            }
        };
        let (mut err2, mut ref2) = (0.0, 0.0);
        let r = tier.basis.vectors.ncols();
        let mut moment = DMatrix::<f64>::zeros(r, r);
        let mut snapshot = of_run[k].iter();
        for step in 0..steps {
            let m = run.history.at(step as f64 * full.wilson.dt);
            if let Err(e) = stepper.step(&(&reduced_unit * m)) {
                out.error = f64::INFINITY;
                out.failure = Some(format!("reduced run failed: {e}"));
                break;
            }
            if plan.keeps(step + 1, steps) {
                let Some(&s) = snapshot.next() else { break };
                let u = &training.snapshots[s];
                let q = stepper.coordinates();
                let mut d: Vec<f64> = (&tier.basis.vectors * q).iter().copied().collect();
                d.iter_mut().zip(u).for_each(|(di, ui)| *di -= ui);
                let mu = DVector::from_vec(crate::fem::sparse_mul(&full.fem.mass, u));
                err2 += m_norm2(full, &d);
                ref2 += mu.iter().zip(u).map(|(a, b)| a * b).sum::<f64>();
                let e = q - tier.basis.vectors.tr_mul(&mu);
                moment.ger(1.0, &e, &e, 1.0);
                if snapshot.len() == 0 {
                    break;
                }
            }
        }
        let stats = stepper.stats();
        out.scale = (ref2 / of_run[k].len().max(1) as f64).sqrt();
        out.steps = stats.steps;
        out.iterations = stats.iterations;
        out.unconverged = stats.unconverged;
        if out.failure.is_none() {
            out.error_moment = moment;
            out.error = if ref2 > 0.0 {
                (err2 / ref2).sqrt()
            } else if err2 > 0.0 {
                f64::INFINITY
            } else {
                0.0
            };
        }
        out
    };
    let results = super::training::run_indexed(
        selected.len(),
        plan.threads,
        |i| check_run(selected[i]),
        |_| {},
    );
    let runs = results
        .into_iter()
        .zip(selected.iter().map(|&k| &runs[k]))
        .map(|(c, run)| {
            c.unwrap_or_else(|| RunCheck {
                label: run.label.clone(),
                error: f64::INFINITY,
                scale: 0.0,
                snapshots: 0,
                steps: 0,
                iterations: 0,
                unconverged: 0,
                failure: Some("the check did not finish".to_owned()),
                error_moment: DMatrix::zeros(0, 0),
            })
        })
        .collect();
    Ok(SelfCheck {
        runs,
        threshold,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The training runs held out of the out-of-sample check: every fifth run (index ≡ 2 mod 5),
/// none when the plan has fewer than five. With the default plan (directions × {ramp, step})
/// the held-out runs alternate between ramps and steps and between axes and diagonals.
pub fn held_out_runs(count: usize) -> Vec<usize> {
    if count < 5 {
        return Vec::new();
    }
    (0..count).filter(|k| k % 5 == 2).collect()
}

/// The out-of-sample self-check: a tier built as `choice` and `ecsw` build the compiled one,
/// but from the training without the [`held_out_runs`] (their snapshots are left out of the
/// basis and of the cubature), re-run on the held-out runs' load histories against their
/// full-order snapshots (e_k as in the module docs). It estimates how a tier built this way
/// does on loads of the envelope it was not trained on (the compiled tier, trained on every
/// run, is not itself measured out of sample).
#[derive(Clone, Debug, PartialEq)]
pub struct OutOfSample {
    /// Per held-out run.
    pub check: SelfCheck,
    /// Training runs in all (held out and kept).
    pub runs: usize,
    /// The held-out tier's r.
    pub order: usize,
    /// Sampled elements of the held-out tier.
    pub sampled: usize,
}

/// Builds the held-out tier of `training` and checks it ([`OutOfSample`]); `Ok(None)` when the
/// plan has fewer than five runs or a held-out run failed in training.
pub fn out_of_sample(
    full: &FullOrder,
    plan: &TrainingPlan,
    training: &Training,
    choice: &BasisChoice,
    ecsw: &EcswOptions,
    newton: ReducedNewton,
) -> Result<Option<OutOfSample>, NonlinearError> {
    let held = held_out_runs(training.runs.len());
    if held.is_empty() || held.iter().any(|&k| training.runs[k].1.is_some()) {
        return Ok(None);
    }
    let mut rest = Training {
        runs: training.runs.clone(),
        cuts: training.cuts.clone(),
        envelope: training.envelope.clone(),
        ..Training::default()
    };
    for (u, &k) in training.snapshots.iter().zip(&training.run_of) {
        if !held.contains(&k) {
            rest.snapshots.push(u.clone());
            rest.run_of.push(k);
        }
    }
    let held_tier = tier_build::from_training_with(full, rest, choice, ecsw)?;
    let check = check_runs(
        full,
        plan,
        &held_tier,
        training,
        &held,
        newton,
        OUT_OF_SAMPLE_THRESHOLD,
    )?;
    Ok(Some(OutOfSample {
        check,
        runs: training.runs.len(),
        order: held_tier.model.order(),
        sampled: held_tier.sampling.weights.len(),
    }))
}

impl OutOfSample {
    /// The report note (deterministic: no timing).
    pub fn note(&self) -> String {
        let c = &self.check;
        let worst = c.worst().map_or_else(
            || "no run checked".to_owned(),
            |w| format!("worst '{}' {}", w.label, percent(w.error)),
        );
        format!(
            "co-rotational tier out-of-sample check: {} of the {} training runs held out of a \
             second tier's basis and cubature (r = {}, {} sampled elements), which is re-run on \
             their loads against their full-order snapshots (relative L2 error in the M-norm, \
             docs/design.md §10): {worst}, median {} (threshold {})",
            c.runs.len(),
            self.runs,
            self.order,
            self.sampled,
            percent(c.median()),
            percent(c.threshold)
        )
    }

    /// The warning when a held-out run is above [`OUT_OF_SAMPLE_THRESHOLD`] (None otherwise).
    pub fn warning(&self) -> Option<String> {
        let flagged = self.check.flagged();
        let worst = flagged.first()?;
        Some(format!(
            "WARNING: out of sample, the co-rotational tier is {} off the full-order \
             co-rotational FEM on the held-out training run '{}' (threshold {}; {} of {} \
             held-out runs above it): loads the tier was not trained on can be this far off. \
             Raise `order`, set `basis_tolerance`, or train more directions (the default \
             `directions = \"axes_and_diagonals\"` where the scene says \"axes\") in \
             [reduction.corotational]",
            percent(worst.error),
            worst.label,
            percent(self.check.threshold),
            flagged.len(),
            self.check.runs.len()
        ))
    }
}

/// ‖x‖²_M = xᵀ M x (kg·m² for a displacement x in m).
fn m_norm2(full: &FullOrder, x: &[f64]) -> f64 {
    crate::fem::sparse_mul(&full.fem.mass, x)
        .iter()
        .zip(x)
        .map(|(a, b)| a * b)
        .sum()
}
