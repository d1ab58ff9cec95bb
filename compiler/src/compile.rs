//! The pipeline's wiring: scene → mesh → FEM → modal + balanced reduction → Kalman → model
//! file (docs/design.md §1). Each stage lives in its own module; this one only calls them in
//! order and records their costs.

use std::path::Path;

use crokf_formats as fmt;

use crate::error::CompileError;
use crate::full_order::FullOrder;
use crate::model_file::assemble_model;
use crate::nonlinear::ecsw::EcswOptions;
use crate::nonlinear::self_check::{self, SelfCheck};
use crate::nonlinear::tier::{self, RuntimeNewton};
use crate::nonlinear::training::TrainingPlan;
use crate::outputs::Measurements;
use crate::reductor::Reductor;
use crate::report::{self, Sizes};
use crate::timer::StageTimer;
use crate::scene::ModelTier;

/// Factor on the largest training ‖q‖ beyond which the runtime reports the state outside the
/// tier's training envelope.
pub const TIER_STATE_MARGIN: f64 = 1.5;

/// The co-rotational tier of `[reduction] model = "corotational"` (docs/design.md §10):
/// training runs generated from `[reduction.corotational]` (progress on stderr), POD basis,
/// ECSW, the linearised filter, the model file's tier section and the self-check of the
/// compiled tier on its training runs ([`self_check`]: summary and any warning on stderr and in
/// the report's notes); figures go into `report`.
fn corotational_tier(
    full: &FullOrder,
    measurements: &Measurements,
    timer: &mut StageTimer,
    report: &mut fmt::CompileReport,
) -> Result<(fmt::CorotationalTier, SelfCheck), CompileError> {
    let path = full.scene_path().to_path_buf();
    let fail = |e: &dyn std::fmt::Display| CompileError::Tier {
        path: path.clone(),
        message: e.to_string(),
    };
    let (Some(spec), Some(plan)) = (
        full.scene.scene.reduction.corotational.as_ref(),
        TrainingPlan::of_scene(full),
    ) else {
        return Err(fail(
            &"reduction.model = \"corotational\" needs [reduction.corotational]",
        ));
    };
    let mut progress = |k: usize, of: usize, label: &str| {
        eprintln!(
            "crokf-compile: co-rotational training run {}/{of}: {label}",
            k + 1
        );
    };
    let training = timer
        .stage("tier_training", || {
            crate::nonlinear::training::train(full, &plan, &mut progress)
        })
        .map_err(|e| fail(&e))?;
    for (label, failed) in &training.runs {
        if let Some(why) = failed {
            report.notes.push(format!(
                "co-rotational training run '{label}' failed and was skipped: {why}"
            ));
        }
    }
    let ecsw = EcswOptions {
        tolerance: spec.ecsw_tolerance,
        max_elements: spec.ecsw_max_elements,
        ..EcswOptions::default()
    };
    let choice = tier::BasisChoice {
        order: spec.order,
        tolerance: spec.basis_tolerance,
        max_order: spec.largest_order(),
    };
    let built = timer
        .stage("tier_reduction", || {
            tier::from_training_with(full, training, &choice, &ecsw)
        })
        .map_err(|e| fail(&e))?;
    let filter = timer
        .stage("tier_kalman", || {
            tier::linearised_filter(full, &built, measurements)
        })
        .map_err(|e| fail(&e))?;
    let env = &built.training.envelope;
    let r = built.model.order();
    if let (Some(eps), Some((added, worst))) = (spec.basis_tolerance, built.enrichment) {
        report.notes.push(format!(
            "co-rotational tier basis: {} pooled POD vectors + {added} added for the per-run \
             tolerance {eps:e} in the energy norm; worst training run {worst:.2e}{} (r ≤ {})",
            r - added,
            if worst > eps {
                ", NOT reached: max_order stopped the enrichment"
            } else {
                ""
            },
            spec.largest_order()
        ));
    }
    report.notes.push(format!(
        "co-rotational tier: r = {r} POD vectors of {} training snapshots ({} of {} runs), {} \
         sampled elements of {} (ECSW residual {:.2e}, tolerance {:.0e}); envelope: {}",
        env.snapshots,
        env.runs.0,
        env.runs.1,
        built.model.elements.len(),
        full.fem.elements.len(),
        built.sampling.relative_residual,
        spec.ecsw_tolerance,
        plan.ranges
            .iter()
            .map(|(n, f)| format!("{n} ≤ {:.4} N", f * plan.max_multiple()))
            .collect::<Vec<_>>()
            .join(", ")
    ));
    report.notes.push(format!(
        "co-rotational tier filter (linearised at rest, state (q, q̇, q̈, f[, ḟ]) = {}, {} force \
         (and rate) states): closed-loop spectral radius {:.6}, Riccati residual {:.1e}, static residual \
         of the force channels at the markers {:.1e}; gain schedule: {} of {} operating points \
         (training states, ‖q*‖ {:.3e} … {:.3e})",
        filter.schedule.phases[0].gain.nrows(),
        filter.schedule.phases[0].gain.nrows() - 3 * r,
        filter.schedule.closed_loop_spectral_radius,
        filter.schedule.worst_relative_residual,
        filter.static_residual,
        filter.scheduled.len(),
        tier::SCHEDULE_POINTS,
        filter
            .scheduled
            .iter()
            .map(|(q, _)| q.norm())
            .fold(f64::INFINITY, f64::min),
        filter
            .scheduled
            .iter()
            .map(|(q, _)| q.norm())
            .fold(0.0, f64::max)
    ));
    report.notes.push(format!(
        "co-rotational tier model error at the markers (basis projection of the training \
         snapshots, RMS per channel in units of the channel's σ): largest {:.2e}, median {:.2e} \
         (not added to R: against the markers' own noise it is negligible below ≈ 0.1)",
        filter
            .marker_model_error
            .iter()
            .copied()
            .fold(0.0, f64::max),
        {
            let mut e = filter.marker_model_error.clone();
            e.sort_by(f64::total_cmp);
            e.get(e.len() / 2).copied().unwrap_or(0.0)
        }
    ));
    let newton = self_check::runtime_newton(spec.newton_tolerance, spec.newton_iterations);
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
    let steps: usize = check.runs.iter().map(|r| r.steps).sum();
    eprintln!(
        "crokf-compile: {} ({steps} reduced steps in {:.2} s)",
        check.note(),
        check.seconds
    );
    report.notes.push(check.note());
    if let Some(warning) = check.warning() {
        eprintln!("crokf-compile: {warning}");
        report.notes.push(warning);
    }
    let section = tier::tier_section(
        full,
        &built,
        &plan,
        &filter,
        measurements,
        RuntimeNewton {
            tolerance: spec.newton_tolerance,
            iterations: spec.newton_iterations,
            state_margin: TIER_STATE_MARGIN,
        },
    );
    Ok((section, check))
}

/// Options of a compile run; `None` falls back to the scene's `[reduction]` table, then defaults.
#[derive(Clone, Debug, Default)]
pub struct CompileOptions {
    /// Balanced truncation order r.
    pub order: Option<usize>,
    /// Relative Hankel singular value tolerance.
    pub tolerance: Option<f64>,
    /// Number of vibration modes m before balancing.
    pub modes: Option<usize>,
    /// Skip the measured error against the full-order linear reference.
    pub skip_measured_error: bool,
}

/// A compiled model: the model file's contents, its bytes and the run's costs.
pub struct Compiled {
    /// The model.
    pub model: fmt::Model,
    /// Encoded model file.
    pub bytes: Vec<u8>,
    /// Stage costs.
    pub timer: StageTimer,
    /// Problem sizes.
    pub sizes: Sizes,
    /// The co-rotational tier's self-check (per training run; None without a tier).
    pub self_check: Option<SelfCheck>,
}

impl Compiled {
    /// The JSON report: the model's report, sizes and per-stage costs.
    pub fn report_json(&self) -> String {
        report::json(
            &self.model,
            &self.sizes,
            &self.timer,
            self.bytes.len(),
            self.self_check.as_ref(),
        )
    }

    /// A readable summary for stderr.
    pub fn summary(&self) -> String {
        report::summary(&self.model, &self.sizes, &self.timer)
    }
}

/// Runs the whole pipeline on a scene file.
pub fn compile(scene_path: &Path, options: &CompileOptions) -> Result<Compiled, CompileError> {
    let mut timer = StageTimer::default();
    let full = FullOrder::build(scene_path, &mut timer)?;
    let reductor = Reductor::new(&full, options.modes, &mut timer)?;
    compile_reduced(&reductor, options, timer)
}

/// The order-dependent rest of the pipeline on a prepared [`Reductor`]: balanced truncation,
/// Kalman schedule, measured error, model file. Called once per order by `crokf-verify report`
/// and by [`check`](crate::check::check), which build the reductor once.
pub fn compile_reduced(
    reductor: &Reductor,
    options: &CompileOptions,
    mut timer: StageTimer,
) -> Result<Compiled, CompileError> {
    let full = reductor.full;
    let ops = &full.operators;
    if !options.skip_measured_error {
        // The full-order reference first: the default order rule measures candidate orders.
        timer.stage("full_order_reference", || reductor.reference().map(|_| ()))?;
    }
    let (reduced, order_note) = timer.stage("balanced_truncation", || {
        reductor.reduce_by_rule(
            options.order,
            options.tolerance,
            !options.skip_measured_error,
        )
    })?;
    let schedule = timer.stage("kalman", || reductor.kalman(&reduced))?;

    // Scene warnings, mesh notes and what each selection took (fem, operators) come first.
    let mut notes: Vec<String> = full.fem.notes.clone();
    notes.extend(full.operators.notes.iter().cloned());
    notes.extend(reductor.basis.warnings.iter().cloned());
    notes.extend(reduced.warnings.iter().cloned());
    notes.extend(order_note);
    notes.extend(crate::advice::tier_advice(reductor));
    if ops.noise.is_empty() {
        notes.push("no process noise declared (force_noise_std / force_noise): Q = 0, so the steady-state gain is zero and measurements are ignored".to_owned());
    }
    let measured_errors = if options.skip_measured_error {
        notes.push("measured error against the full-order reference skipped (--no-measure)".into());
        Default::default()
    } else {
        timer.stage("measured_error", || reductor.measured_errors(&reduced))?
    };
    let report = fmt::CompileReport {
        hankel_singular_values: reduced.hankel_singular_values.clone(),
        error_bound: reduced.error_bound,
        order: reduced.balanced_order as u32,
        modes: reductor.basis.n_eigenmodes as u32,
        highest_kept_frequency_hz: reductor.highest_kept_frequency_hz(),
        nyquist_hz: 0.5 / full.wilson.dt,
        spectral_radius: reduced.spectral_radius,
        riccati_residual: schedule.worst_relative_residual,
        closed_loop_spectral_radius: schedule.closed_loop_spectral_radius,
        measured_errors,
        timings_s: Default::default(),
        notes,
    };
    let model = timer.stage("model_file", || {
        assemble_model(
            full,
            &reductor.rows,
            &reduced,
            &schedule,
            &reductor.measurements,
            report,
        )
    });
    let mut model = model;
    let mut self_check = None;
    if full.scene.scene.reduction.model == ModelTier::Corotational {
        let (section, check) =
            corotational_tier(full, &reductor.measurements, &mut timer, &mut model.report)?;
        model.tier = Some(section);
        self_check = Some(check);
        model.validate().map_err(|e| CompileError::Tier {
            path: full.scene_path().to_path_buf(),
            message: format!("model file section: {e}"),
        })?;
    }
    let bytes = fmt::encode(&model);
    let fem = &full.fem;
    let sizes = Sizes {
        nodes: fem.positions.len(),
        tetrahedra: fem.elements.len(),
        dofs: fem.dof_count(),
        inputs: ops.inputs.len(),
        noise_channels: ops.noise.len(),
        outputs: reductor.weights.len(),
        measurements: reductor.measurements.len(),
    };
    Ok(Compiled {
        model,
        bytes,
        timer,
        sizes,
        self_check,
    })
}
