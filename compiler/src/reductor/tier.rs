//! The co-rotational tier's reductor (docs/design.md §10–11), beside the linear
//! [`Reductor`](super::Reductor): built once from the scene's `[reduction.corotational]`
//! table, it owns the training runs, the basis, the cubature, the noise model and the filter
//! design, and hands the compile what it found on its way ([`findings`]), its self-check and
//! the model file's tier section; the report's prose is the compile's.
//!
//! ```text
//! training ─▶ basis ─▶ cubature ─▶ reduced model ─▶ filter (noise model, gain schedule)
//!                                        └──▶ self-check         └──▶ model-file section
//! ```

pub mod findings;

use crate::error::CompileError;
use crate::full_order::FullOrder;
use crate::noise::{Derivation, NoiseModel};
use crate::nonlinear::basis::BasisChoice;
use crate::nonlinear::cases::{self, CaseCache};
use crate::nonlinear::ecsw::EcswOptions;
use crate::nonlinear::fidelity;
use crate::nonlinear::filter::{
    derive_force_sigma, linearise_at_rest, linearised_filter, TierFilter,
};
use crate::nonlinear::self_check::{self, percent, OutOfSample, SelfCheck};
use crate::nonlinear::tier::{self, Tier};
use crate::nonlinear::training::{self, TrainingPlan};
use crate::outputs::Measurements;
use crate::progress::Progress;
use crate::scene::CorotationalSpec;
use crate::timer::StageTimer;

use findings::{CacheUse, OrderAboveSnapshots, TierFindings};

/// Factor on the largest training ‖q‖ beyond which the runtime reports the state outside the
/// tier's training envelope.
pub const TIER_STATE_MARGIN: f64 = 1.5;

/// A co-rotational tier trained, reduced and filtered for one scene.
pub struct TierReductor<'a> {
    /// The full-order model.
    pub full: &'a FullOrder,
    /// The scene's `[reduction.corotational]` table.
    pub spec: &'a CorotationalSpec,
    /// The training runs generated from it.
    pub plan: TrainingPlan,
    /// The filter's noise model (force and rate states, white channels), built once, its
    /// derived σ fixed on the tier (docs/design.md §11.8).
    pub noise: NoiseModel,
    /// The force σ derived from the scene's load statements (empty when all are stated).
    pub derived: Vec<Derivation>,
    /// Training, basis, cubature and reduced model.
    pub tier: Tier,
    /// The filter designed on the tier linearised at rest and its gain schedule.
    pub filter: TierFilter,
    /// The compiled tier re-run on its training runs ([`self_check`]); its in-basis error is
    /// the filter's model-error noise.
    pub check: SelfCheck,
    /// A tier built without every fifth training run, re-run on those runs
    /// ([`self_check::out_of_sample`]; None with fewer than five runs).
    pub out_of_sample: Option<OutOfSample>,
    /// The basis and cubature settings the tier was built with: the scene's, or the fidelity
    /// rule's.
    pub size: (BasisChoice, EcswOptions),
    /// The fidelity rule's choice (None when the scene states the tier's size).
    pub fidelity: Option<fidelity::Fidelity>,
    /// Why the tier fails its own check, when the scene accepted it all the same
    /// (`accept_failed_check`); written into the model file (`failed_check`).
    pub failed_check: Option<String>,
    /// What the training found on its way, for the compile report (loads left untrained,
    /// training runs failed or cut, a stated order above the snapshots kept).
    pub findings: TierFindings,
    /// The measurement channels the filter was designed for.
    pub measurements: &'a Measurements,
}

impl<'a> TierReductor<'a> {
    /// Trains on the scene's envelope (progress on stderr), chooses the basis, trains the
    /// cubature and designs the filter for `measurements`; stage costs go to `timer`
    /// ("tier_training", "tier_reduction", "tier_kalman").
    ///
    /// With `cache`, the training runs found in that case cache
    /// ([`crate::nonlinear::cases`]) are read from it and the others stored in it; what
    /// it contributed goes to `on_cache` as soon as the training is done, not into the model
    /// (a model is the same with or without a cache).
    pub fn new(
        full: &'a FullOrder,
        measurements: &'a Measurements,
        cache: Option<&std::path::Path>,
        timer: &mut StageTimer,
        on_cache: &mut dyn FnMut(&CacheUse),
    ) -> Result<Self, CompileError> {
        let fail = |e: &dyn std::fmt::Display| tier_error(full, e);
        let (Some(spec), Some(plan)) = (
            full.scene.scene.reduction.corotational.as_ref(),
            TrainingPlan::of_scene(full),
        ) else {
            return Err(fail(
                &"reduction.model = \"corotational\" needs [reduction.corotational]",
            ));
        };
        let mut noise = full.noise_model().map_err(|e| fail(&e))?;
        // Run k starts when a worker is free: k + 1 − threads runs are done by then.
        let runs = plan.runs().len();
        let mut line = Progress::new(
            &format!("{}: co-rotational training", crate::progress::program()),
            "runs",
            runs,
        );
        let mut progress = |k: usize, _: usize, _: &str| {
            line.update((k + 1).saturating_sub(plan.threads));
        };
        let cache = cache
            .map(CaseCache::open)
            .transpose()
            .map_err(|e| fail(&e))?;
        let training = timer.stage("tier_training", || match &cache {
            Some(cache) => cases::train_cached(full, &plan, cache, &mut progress),
            None => training::train(full, &plan, &mut progress),
        });
        line.finish();
        let training = training.map_err(|e| fail(&e))?;
        if let Some(cache) = &cache {
            on_cache(&CacheUse::of(&training, runs, cache.dir().to_path_buf()));
        }
        let mut findings = TierFindings::of_training(spec, &plan, &training);
        let newton = self_check::runtime_newton(spec.newton_tolerance, spec.newton_iterations);
        // The scene's size, or the fidelity rule's choice measured out of sample.
        let (choice, ecsw, fidelity) = if spec.states_size() {
            let ecsw = EcswOptions {
                tolerance: spec.ecsw_tolerance(),
                max_elements: spec.ecsw_max_elements(),
                ..EcswOptions::default()
            };
            let choice = BasisChoice {
                order: spec.order(),
                tolerance: spec.basis_tolerance,
                max_order: spec.largest_order(),
            };
            findings.order_above_snapshots =
                OrderAboveSnapshots::of(choice.order, spec.order.is_some(), &training);
            (choice, ecsw, None)
        } else {
            let chosen = timer
                .stage("tier_fidelity", || {
                    fidelity::choose(full, &plan, &training, newton)
                })
                .map_err(|e| fail(&e))?;
            (chosen.rung.basis(), chosen.rung.ecsw(), Some(chosen))
        };
        let built = timer
            .stage("tier_reduction", || {
                tier::from_training_with(full, training, &choice, &ecsw)
            })
            .map_err(|e| fail(&e))?;
        let check = timer
            .stage("tier_self_check", || {
                self_check::self_check(
                    full,
                    &plan,
                    &built,
                    newton,
                    self_check::SELF_CHECK_THRESHOLD,
                )
            })
            .map_err(|e| fail(&e))?;
        let out_of_sample = match fidelity.as_ref() {
            Some(f) => f.out_of_sample.clone(),
            None => timer
                .stage("tier_out_of_sample", || {
                    self_check::out_of_sample(full, &plan, &built.training, &choice, &ecsw, newton)
                })
                .map_err(|e| fail(&e))?,
        };
        let failed = failed_check(plan.max_rotation, &built, &check, out_of_sample.as_ref());
        if let Some(why) = &failed {
            if !spec.accept_failed_check {
                return Err(fail(&format!(
                    "{why}. The tier is not written. Remedies, in [reduction.corotational] or \
                     the loads: declare loads that act together as a \
                     [[reduction.corotational.case]] (a couple: `loads = {{ upper = [0, 1, 0], \
                     lower = [0, -1, 0] }}`), which replaces the runs of each group alone; \
                     lower a load's `range` (or `ranges`) to the largest force the body will \
                     see (the training goes to {}× it); raise `order` or set \
                     `basis_tolerance`. `accept_failed_check = true` writes the tier anyway",
                    plan.max_multiple()
                )));
            }
        }
        let model_error = check.model_error_covariance();
        let (derived, filter) = timer
            .stage("tier_kalman", || {
                let rest = linearise_at_rest(full, &built, &noise, measurements);
                let derived = derive_force_sigma(&rest, &mut noise, measurements)?;
                linearised_filter(full, &built, &noise, measurements, model_error)
                    .map(|f| (derived, f))
            })
            .map_err(|e| match check.warning() {
                // The self-check's error is the filter's model-error noise (design.md §11.9):
                // a tier far off its training can leave no stabilising filter. Its cause first.
                Some(w) => fail(&format!("{e} (the tier's self-check, run before: {w})")),
                None => fail(&e),
            })?;
        let reductor = TierReductor {
            full,
            spec,
            plan,
            noise,
            derived,
            tier: built,
            filter,
            check,
            out_of_sample,
            size: (choice, ecsw),
            fidelity,
            failed_check: failed,
            findings,
            measurements,
        };
        Ok(reductor)
    }
}

/// Why the tier fails its own checks (more than half of its training runs above the
/// self-check's threshold, or of the held-out runs above the out-of-sample one), with how
/// many training runs were cut past `plan_rotation` degrees or an inverted element; None when
/// it passes.
fn failed_check(
    plan_rotation: f64,
    built: &Tier,
    check: &SelfCheck,
    out_of_sample: Option<&OutOfSample>,
) -> Option<String> {
    let (what, failing, warning) = if check.fails_most() {
        ("its own training runs", check, check.warning())
    } else {
        match out_of_sample {
            // Held out, a miss between the out-of-sample threshold (2 %) and the self-check's
            // (5 %) stays a warning: the tier is still close on the loads it was not shown.
            Some(o) if o.check.fails_most_above(self_check::SELF_CHECK_THRESHOLD) => {
                ("the training runs held out of it", &o.check, o.warning())
            }
            _ => return None,
        }
    };
    let limit = self_check::SELF_CHECK_THRESHOLD;
    let (above, checked) = failing.above(limit);
    let mut why = format!(
        "the co-rotational tier fails its check: {above} of {checked} of {what} are above {} \
         off the full-order co-rotational FEM (median {})",
        percent(limit),
        percent(failing.median())
    );
    let training = &built.training;
    let cut = training.cuts.iter().flatten().count();
    if cut > 0 {
        why.push_str(&format!(
            "; {cut} of the {} training runs were cut where their load inverted an element or \
             rotated one past max_rotation ({}°), and the largest training displacement kept \
             is {:.3e} m",
            training.runs.len(),
            plan_rotation,
            training.envelope.max_displacement
        ));
    }
    if let Some(w) = warning {
        why.push_str(&format!(" ({})", w.trim_start_matches("WARNING: ")));
    }
    Some(why)
}

/// A tier error of the scene of `full`.
fn tier_error(full: &FullOrder, e: &dyn std::fmt::Display) -> CompileError {
    CompileError::Tier {
        path: full.scene_path().to_path_buf(),
        message: e.to_string(),
    }
}
