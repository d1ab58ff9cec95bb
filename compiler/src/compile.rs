//! The pipeline's wiring: scene → mesh → FEM → modal + balanced reduction → Kalman → model
//! file (docs/design.md §1). Each stage lives in its own module; this one only calls them in
//! order and records their costs.

pub mod tier_notes;

use std::path::Path;

use crokf_formats as fmt;

use crate::error::CompileError;
use crate::full_order::FullOrder;
use crate::model_file::assemble_model;
use crate::nonlinear::self_check::SelfCheck;
use crate::reductor::tier::TierReductor;
use crate::reductor::Reductor;
use crate::report::{self, Sizes};
use crate::scene::ModelTier;
use crate::timer::StageTimer;

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
    /// The co-rotational tier's training case cache (`nonlinear::cases`): cases found there
    /// are read, the others run and stored. The model does not depend on it.
    pub training_cache: Option<std::path::PathBuf>,
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
    notes.extend(
        crate::accuracy::channel_static_errors(
            full,
            &reductor.rows,
            &reduced,
            reductor.static_outputs(),
        )
        .and_then(|e| crate::accuracy::channel_static_note(&e, reduced.balanced_order)),
    );
    if full.scene.scene.time.scheme == crate::scene::Scheme::Exact {
        notes.push(format!(
            "time scheme exact: each mode's response to the load held over the step \
             (zero-order hold); the measured error and the order rule compare with the full-order \
             response converged in time (Wilson-θ at Δt/{})",
            crate::reductor::CONVERGED_SUBSTEPS
        ));
    }
    if !options.skip_measured_error {
        let step_errors = timer.stage("step_error", || reductor.step_errors())?;
        notes.extend(crate::step_error::note(
            &step_errors,
            full.wilson.dt,
            crate::step_error::NOTE_ABOVE,
            full.scene.scene.exact_scheme_refusal().is_none(),
        ));
    }
    notes.extend(crate::advice::tier_advice(reductor));
    // Force states come from the loads (estimated by default), white channels from `force_noise`.
    let estimated_loads = full.noise_model().is_ok_and(|n| !n.groups.is_empty());
    if ops.noise.is_empty() && !estimated_loads {
        notes.push("no process noise: no load is estimated (every load is force_model = \"white\" without force_noise_std) and no [[force_noise]] channel, so Q = 0, the steady-state gain is zero and measurements are ignored".to_owned());
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
            reductor.contact.as_ref(),
            report,
        )
    });
    let mut model = model;
    let mut self_check = None;
    if full.scene.scene.reduction.model == ModelTier::Corotational {
        let tier = TierReductor::new(
            full,
            &reductor.measurements,
            options.training_cache.as_deref(),
            &mut timer,
            // The case cache's use, as soon as the training is done.
            &mut |cache| {
                for line in tier_notes::cache_lines(cache) {
                    eprintln!("{}: {line}", crate::progress::program());
                }
            },
        )?;
        let program = crate::progress::program();
        // The self-check ([`TierReductor::new`] ran it, its cost in the stage
        // "tier_self_check"): its summary and any warning on the terminal, then in the report.
        let check = tier.check.clone();
        let steps: usize = check.runs.iter().map(|r| r.steps).sum();
        eprintln!(
            "{program}: {} ({steps} reduced steps in {:.2} s)",
            check.note(),
            check.seconds
        );
        if let Some(warning) = check.warning() {
            eprintln!("{program}: {warning}");
        }
        if let Some(held) = &tier.out_of_sample {
            eprintln!("{program}: {}", held.note());
            if let Some(warning) = held.warning() {
                eprintln!("{program}: {warning}");
            }
        }
        let notes = &mut model.report.notes;
        notes.extend(tier_notes::tier_notes(&tier));
        notes.push(check.note());
        notes.extend(check.warning());
        if let Some(held) = &tier.out_of_sample {
            notes.push(held.note());
            notes.extend(held.warning());
        }
        model.tier = Some(tier_section(&tier));
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

/// The model file's tier section of a co-rotational tier's reductor: the file's writer
/// ([`crate::model_file::tier::tier_section`]) on what the reductor built, the runtime's Newton
/// settings from the scene with [`TIER_STATE_MARGIN`], and the failed check it was accepted
/// with, if any.
///
/// [`TIER_STATE_MARGIN`]: crate::reductor::tier::TIER_STATE_MARGIN
fn tier_section(tier: &TierReductor) -> fmt::CorotationalTier {
    let newton = crate::model_file::tier::RuntimeNewton {
        tolerance: tier.spec.newton_tolerance,
        iterations: tier.spec.newton_iterations,
        state_margin: crate::reductor::tier::TIER_STATE_MARGIN,
    };
    fmt::CorotationalTier {
        failed_check: tier.failed_check.clone(),
        ..crate::model_file::tier::tier_section(
            tier.full,
            &tier.tier,
            &tier.plan,
            &tier.filter,
            tier.measurements,
            newton,
        )
    }
}
