//! Speed against error (docs/design.md §7): full-order references and the reduced runtime on one
//! scene and one scenario, in the same run.
//!
//! [`run`] drives, through the same scenario (world-frame dead loads; step k → k+1 holds
//! f(t_k), t_k = kΔt):
//! 1. the full-order linear FEM ([`LinearSimulator`], J factored once) and the full-order
//!    co-rotational FEM ([`CorotationalSimulator`], Newton to a tolerance), timing each step;
//! 2. for each order r: the model reduced at r from one [`Reductor`] (front end and modes built
//!    once), run through the runtime
//!    [`Estimator`] (warping included) open loop (no measurements) and filtered on synthetic
//!    measurements: the co-rotational reference's world sensor displacements plus Gaussian
//!    noise N(0, σ_s²) (σ_s the sensor's `noise_std`, fixed seed), on the channels the model's
//!    multi-rate schedule measures at each step (`every`).
//!
//! Errors are relative L2 norms over the whole trajectory (steps 1..N),
//! e = ‖u − u_ref‖ / ‖u_ref‖ = sqrt(Σ_k Σ_i |u_i(t_k) − u_ref,i(t_k)|² / Σ_k Σ_i |u_ref,i(t_k)|²),
//! against the co-rotational reference, world-frame displacements (m):
//! - `error`: over the displayed nodes, the union of all node sets of the scene (a node in two
//!   sets counts once);
//! - `tip_error`: at the tip, the sensor named `tip` if the scene has one, else the sensor
//!   with the largest displacement in the co-rotational reference (the point that moves most);
//! - the linear FEM's error shows what the co-rotational correction is worth; the runtime's
//!   error shows what reduction + warping cost.
//!
//! The largest rotation reached is the angle of the polar rotation of the volume-weighted mean
//! deformation gradient around each displayed node, max over nodes and steps (degrees).
//!
//! [`rotation_sweep`] repeats the open-loop comparison with the scenario's loads scaled, to find
//! where the warping approximation breaks down.
//!
//! The co-rotational tier (docs/design.md §10), compiled once from its own scene by
//! [`compile_tier`] (training included), joins both as one more row / one more column: it is
//! driven through the same public [`Estimator`] API, inputs and synthetic measurements as the
//! warped rows (open loop, filtered with the loads given and withheld, timed the same way), so
//! its figures are whatever the runtime's tier does. Its scene must describe the same body as the
//! comparison's scene (same inputs, sensors and displayed node sets, checked); the references
//! are the comparison scene's. The runtime's envelope status ([`crokf_runtime::TierStatus`]) is
//! recorded per run: a sweep point whose loads or state leave the training envelope is marked.

use std::path::{Path, PathBuf};

use crokf_runtime::{Estimator, RuntimeError};

use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{NewtonOptions, NewtonStats, SteppingError};
use crokf_compile::{CompileError, Reductor};

pub mod advice;
mod consistency;
mod metrics;
mod render;
mod runs;
pub mod segments;
mod setup;
mod svg;
mod tier;

use crate::scenario::ScenarioError;
pub use consistency::{
    chi_square_quantile, spread, verdict, ChiSquare, Consistency, ConsistencyAccumulator,
    CoverageCount, Ensemble, FilterBlocks, RunLengthMismatch, SeedEnsemble, StepFractions,
    TipSample,
};
use metrics::ErrorSum;
pub use metrics::{
    breakdown_rotation, breakdown_rotation_of, relative_l2, rotation_angle, Gaussian,
};
pub use render::{format_seconds, segment_table, sweep_markdown};
use runs::{
    compile_at, filtered_runs, row_inputs, run_reference, run_runtime, runtime_inputs,
    synthetic_measurements, time_row, FilteredRuns, ReferenceRun, RunErrors,
};
use segments::Segment;
use setup::{scaled, Setup};
use tier::{check_tier_matches, run_tier};
pub use tier::{compile_tier, TierModel};

/// Errors of a comparison; each names the file, order or step concerned.
#[derive(Debug, thiserror::Error)]
pub enum ComparisonError {
    /// Scene, mesh, FEM or compile failure.
    #[error(transparent)]
    Compile(#[from] CompileError),
    /// Full-order reference failure.
    #[error("{path}: {source}")]
    Reference {
        /// Scenario path.
        path: PathBuf,
        /// What went wrong.
        source: SteppingError,
    },
    /// Scenario file.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The runtime refused a step.
    #[error("{path}: runtime at order r = {order}, step {step}: {source}")]
    Runtime {
        /// Scene path.
        path: PathBuf,
        /// Reduced order.
        order: usize,
        /// Step index (1-based).
        step: usize,
        /// What went wrong.
        source: RuntimeError,
    },
    /// Inconsistent or unsupported inputs.
    #[error("{path}: {what}")]
    Invalid {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Settings of [`run`] and [`rotation_sweep`].
#[derive(Clone, Debug)]
pub struct ComparisonOptions {
    /// Balanced truncation orders r to compile and run.
    pub orders: Vec<usize>,
    /// Newton settings of the co-rotational reference.
    pub newton: NewtonOptions,
    /// Seed of the measurement noise (xorshift64*; 0 is replaced by a fixed non-zero value).
    pub seed: u64,
    /// Also compute the compiler's measured error (step/chirp against the linear reference)
    /// for each order (costs a full-order linear run per test).
    pub measure_compile_error: bool,
    /// Give the filter no load inputs: the force is unknown to the estimator, only the
    /// measurements carry it (the filtered run with the loads given is then not made). The
    /// references and the open-loop runs still get the loads: without inputs and without
    /// measurements the runtime stays at rest, an error of 1 that says nothing of the model.
    pub withhold_loads: bool,
    /// Timing samples (batches) of the runtime step.
    pub timing_samples: usize,
    /// Noise draws of the N-run consistency test (seeds `seed`, `seed + 1`, …; docs/design.md
    /// §11.3): every filtered run is repeated with each; below 2 only the single run.
    pub seeds: usize,
    /// Sub-steps N of the full-order references: Wilson-θ at Δt/N with each scene step's load
    /// held and the acceleration restarted at each scene step, the continuous-time response
    /// as N grows (1: Wilson-θ at Δt, the same scheme as a Wilson-θ model, whose error is
    /// then the reduction's alone). `None`: the reference the compiler measures the scene's
    /// `[time] scheme` against (1 for Wilson-θ, 32 for exact).
    pub substeps: Option<usize>,
}

impl Default for ComparisonOptions {
    fn default() -> Self {
        ComparisonOptions {
            orders: vec![4, 8, 16, 32, 64],
            newton: NewtonOptions::default(),
            seed: 0x5eed_c0ff_ee00_0001,
            measure_compile_error: false,
            withhold_loads: false,
            timing_samples: 31,
            seeds: 20,
            substeps: None,
        }
    }
}

/// Progress report: `done` of `total` units of `phase` (steps, or 0/1 for a compile).
#[derive(Clone, Copy, Debug)]
pub struct Progress<'a> {
    /// Phase name, e.g. `co-rotational FEM`, `compile r = 8`, `runtime r = 8`.
    pub phase: &'a str,
    /// Units done.
    pub done: usize,
    /// Units in the phase.
    pub total: usize,
}

/// A full-order model's figures.
#[derive(Clone, Debug)]
pub struct FullOrderRow {
    /// Median wall time of one step, s.
    pub step_s: f64,
    /// Relative L2 error over displayed nodes against the co-rotational reference (0 for it).
    pub error: f64,
    /// Relative L2 error at the tip.
    pub tip_error: f64,
    /// Newton counters (co-rotational only).
    pub newton: Option<NewtonStats>,
}

/// The runtime's step times and errors in one row (a warped order or the co-rotational tier):
/// open loop, filtered with the loads given and withheld, against the co-rotational reference.
#[derive(Clone, Debug)]
pub struct RuntimeFigures {
    /// Median runtime step, predict + update with the measurements, s (batched; thread CPU
    /// time, [`crate::bench::step_clock_seconds`]).
    pub step_s: f64,
    /// Median runtime step without measurements (predict + empty update) on the open-loop
    /// run's inputs, s (batched; thread CPU time).
    pub open_loop_step_s: f64,
    /// Open loop (with the scenario's loads, also when the comparison withholds them from the
    /// filter): relative L2 error over displayed nodes vs the co-rotational reference.
    pub error: f64,
    /// Open loop: relative L2 error at the tip vs the co-rotational reference.
    pub tip_error: f64,
    /// Filtered (loads given, or withheld when the whole comparison withholds them): relative
    /// L2 error over displayed nodes vs the co-rotational reference.
    pub filtered_error: f64,
    /// Filtered: relative L2 error at the tip vs the co-rotational reference.
    pub filtered_tip_error: f64,
    /// Filtered with the loads withheld from the runtime (only the markers carry the force):
    /// relative L2 error over displayed nodes vs the co-rotational reference. Equal to
    /// `filtered_error` when the whole comparison withholds the loads.
    pub withheld_filtered_error: f64,
    /// Same at the tip.
    pub withheld_filtered_tip_error: f64,
    /// Open loop: relative L2 error over displayed nodes vs the LINEAR full-order reference.
    pub error_vs_linear: f64,
}

impl RuntimeFigures {
    /// The figures of a row from its timed steps and its open-loop, filtered and withheld runs.
    fn new(
        (step_s, open_loop_step_s): (f64, f64),
        open: &RunErrors,
        filtered: &RunErrors,
        withheld: &RunErrors,
    ) -> Self {
        RuntimeFigures {
            step_s,
            open_loop_step_s,
            error: open.display.relative(),
            tip_error: open.tip.relative(),
            filtered_error: filtered.display.relative(),
            filtered_tip_error: filtered.tip.relative(),
            withheld_filtered_error: withheld.display.relative(),
            withheld_filtered_tip_error: withheld.tip.relative(),
            error_vs_linear: open.display_vs_linear.relative(),
        }
    }
}

/// The runtime's figures at one order.
#[derive(Clone, Debug)]
pub struct ReducedRow {
    /// Order asked for.
    pub requested_order: usize,
    /// State dimension of the compiled model: balanced order (capped at the numerical rank by
    /// the compiler) plus `force_states`.
    pub order: usize,
    /// Random-walk force states appended to the balanced ones (3 per such load group).
    pub force_states: usize,
    /// Step times, errors and the filtered runs' consistency.
    pub figures: RowFigures,
    /// The compiler's measured errors (empty unless `measure_compile_error`).
    pub compile_measured_errors: std::collections::BTreeMap<String, f64>,
    /// Compile wall time, s.
    pub compile_s: f64,
}

/// The runtime's figures of one row (a warped order or the co-rotational tier): its open-loop
/// and filtered runs, their consistency and the noise draws.
#[derive(Clone, Debug)]
pub struct RowFigures {
    /// Step times and errors.
    pub runtime: RuntimeFigures,
    /// NIS, NEES, 2σ coverage and the tip trace of the filtered run (docs/design.md §11).
    pub consistency: Consistency,
    /// The same for the run with the loads withheld.
    pub withheld_consistency: Consistency,
    /// The filtered run over the options' noise draws (`None` below 2 draws).
    pub ensemble: Option<SeedEnsemble>,
    /// The same for the run with the loads withheld.
    pub withheld_ensemble: Option<SeedEnsemble>,
}

impl RowFigures {
    /// The row's figures from its step times and errors and its filtered runs.
    fn new(runtime: RuntimeFigures, filter: FilteredRuns) -> Self {
        RowFigures {
            runtime,
            consistency: filter.given_consistency,
            withheld_consistency: filter.withheld_consistency,
            ensemble: filter.given_ensemble,
            withheld_ensemble: filter.withheld_ensemble,
        }
    }
}

/// Result of [`run`]: one scene, one scenario, full-order references and the runtime at
/// several orders.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// Scene file.
    pub scene: PathBuf,
    /// Scenario file.
    pub scenario: PathBuf,
    /// Free DOFs n.
    pub dofs: usize,
    /// Tetrahedra.
    pub tetrahedra: usize,
    /// Displayed nodes (union of the node sets).
    pub displayed_nodes: usize,
    /// Steps N.
    pub steps: usize,
    /// Δt, s.
    pub dt: f64,
    /// Tip sensor: the one named `tip`, else the one that moves most in the co-rotational
    /// reference; `None` when the scene has no sensor.
    pub tip: Option<String>,
    /// Largest rotation in the co-rotational reference over displayed nodes, degrees.
    pub max_rotation_deg: f64,
    /// Time of that rotation, s.
    pub max_rotation_time: f64,
    /// Sub-steps of Δt/N per scene step of the full-order references
    /// ([`ComparisonOptions::substeps`]; 1: Wilson-θ at Δt).
    pub substeps: usize,
    /// Co-rotational full-order reference.
    pub corotational: FullOrderRow,
    /// Linear full-order model.
    pub linear: FullOrderRow,
    /// Runtime rows, in the order of `options.orders` (orders that failed are left out).
    pub reduced: Vec<ReducedRow>,
    /// Orders whose compile or run failed, with the reason.
    pub failures: Vec<ReducedFailure>,
    /// The co-rotational tier's row, when one was given and its runs completed.
    pub tier: Option<TierRow>,
    /// Why the tier's row is missing, when one was given and a run failed.
    pub tier_failure: Option<String>,
    /// The compiler's notes on the tier's compile (empty without a tier).
    pub tier_notes: Vec<String>,
    /// Noise seed used.
    pub seed: u64,
    /// Noise draws of the N-run consistency test (`ComparisonOptions::seeds`).
    pub seeds: usize,
    /// Whether the filter got the loads (the open-loop runs always get them).
    pub withheld_loads: bool,
    /// The scenario cut at its load breakpoints ([`segments::segments`]), for the per-segment
    /// consistency and the advice.
    pub segments: Vec<Segment>,
    /// The scenario's loads that are not zero throughout (scene `[[load]]` names).
    pub loads: Vec<String>,
    /// What the compiler said about the scene, once for all orders: scene warnings, mesh
    /// notes, what each selection took, the modal basis' warnings.
    pub notes: Vec<String>,
}

/// An order the comparison could not complete.
#[derive(Clone, Debug)]
pub struct ReducedFailure {
    /// Requested order r.
    pub order: usize,
    /// What went wrong (the compiler's or the runtime's message, with the step).
    pub reason: String,
}

/// One point of [`rotation_sweep`].
#[derive(Clone, Debug)]
pub struct SweepPoint {
    /// Factor on the scenario's loads.
    pub scale: f64,
    /// Largest rotation in the co-rotational reference, degrees.
    pub max_rotation_deg: f64,
    /// Runtime open-loop relative L2 error over displayed nodes vs the co-rotational reference.
    pub open_loop_error: f64,
    /// Same at the tip.
    pub tip_error: f64,
    /// Linear full-order error vs the co-rotational reference (what no warping would give).
    pub linear_error: f64,
    /// The co-rotational tier's open loop at this scale, when the sweep has a tier.
    pub tier: Option<TierPoint>,
}

/// The co-rotational tier at one sweep scale.
#[derive(Clone, Debug)]
pub enum TierPoint {
    /// The run completed.
    Ran {
        /// Open-loop relative L2 error over displayed nodes vs the co-rotational reference.
        open_loop_error: f64,
        /// Same at the tip.
        tip_error: f64,
        /// What the runtime said about the training envelope along the run.
        envelope: EnvelopeSummary,
    },
    /// The runtime refused a step (e.g. Newton did not converge): the reason, with the step.
    Failed(String),
}

impl TierPoint {
    /// Open-loop error; NaN for a failed run.
    pub fn open_loop_error(&self) -> f64 {
        match self {
            TierPoint::Ran {
                open_loop_error, ..
            } => *open_loop_error,
            TierPoint::Failed(_) => f64::NAN,
        }
    }
}

/// The runtime's training-envelope status ([`crokf_runtime::EnvelopeStatus`]) over one run of
/// the co-rotational tier, and its Newton work.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvelopeSummary {
    /// Steps after which the runtime reported the load or the state outside the envelope.
    pub steps_outside: usize,
    /// Steps run.
    pub steps: usize,
    /// Largest |f_g| / trained max force over the run (> 1: a load beyond training).
    pub max_load_ratio: f64,
    /// Largest ‖q‖ / trained max ‖q‖ over the run.
    pub max_state_ratio: f64,
    /// The model's margin on the state ratio.
    pub state_margin: f64,
    /// Newton iterations (force evaluations) summed over the run.
    pub newton_iterations: usize,
}

impl EnvelopeSummary {
    /// True when any step left the envelope.
    pub fn outside(&self) -> bool {
        self.steps_outside > 0
    }

    /// Mean Newton iterations per step.
    pub fn iterations_per_step(&self) -> f64 {
        self.newton_iterations as f64 / self.steps.max(1) as f64
    }

    fn record(&mut self, status: &crokf_runtime::TierStatus) {
        let e = &status.envelope;
        self.steps += 1;
        self.steps_outside += usize::from(e.outside());
        self.max_load_ratio = self.max_load_ratio.max(e.load_ratio);
        self.max_state_ratio = self.max_state_ratio.max(e.state_ratio);
        self.state_margin = e.state_margin;
        self.newton_iterations += status.iterations;
    }
}

/// The co-rotational tier's figures in [`run`].
#[derive(Clone, Debug)]
pub struct TierRow {
    /// The tier's scene file.
    pub scene: PathBuf,
    /// POD basis size r.
    pub basis_order: usize,
    /// Sampled elements.
    pub sampled_elements: usize,
    /// State entries beyond (q, q̇, q̈): the filter's force states, if the runtime has any.
    pub force_states: usize,
    /// Compile wall time with training, s.
    pub compile_s: f64,
    /// Step times, errors and the filtered runs' consistency, as for the warped rows; the
    /// consistency from the tier's own stored filters (the gain schedule's filter in use at
    /// each step; docs/design.md §11.3, §11.5), by the same [`ConsistencyAccumulator`].
    pub figures: RowFigures,
    /// Filters of the tier's gain schedule (1: the constant gain designed at rest).
    pub filters: usize,
    /// Envelope and Newton work of the open-loop run.
    pub envelope: EnvelopeSummary,
}

/// Runs the comparison of one scene and one scenario (see the module docs), with the
/// co-rotational tier as one more row when `tier` is given (compiled by [`compile_tier`]).
///
/// Phases reported through `progress`: `linear FEM`, `co-rotational FEM` (steps), `modal
/// system` (0/1: front end and modes, once), then per order `compile r = R` (0/1), `open loop
/// r = R`, `filtered r = R`, `withheld r = R` (steps; each followed by `draws filtered r = R` /
/// `draws withheld r = R` with `options.seeds` ≥ 2) and `timing r = R` (0/1); with a tier the
/// same phases labelled `tier`.
pub fn run(
    scene: &Path,
    scenario: &Path,
    options: &ComparisonOptions,
    tier: Option<&TierModel>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Comparison, ComparisonError> {
    if options.orders.is_empty() || options.orders.contains(&0) {
        return Err(ComparisonError::Invalid {
            path: scene.to_owned(),
            what: format!("orders must be ≥ 1 and not empty, got {:?}", options.orders),
        });
    }
    let mut setup = Setup::new(scene, scenario)?;
    if let Some(n) = options.substeps {
        if n == 0 {
            return Err(ComparisonError::Invalid {
                path: scene.to_owned(),
                what: "substeps must be ≥ 1".into(),
            });
        }
        setup.substeps = n;
    }
    if let Some(t) = tier {
        check_tier_matches(&setup, t)?;
    }
    let linear = run_reference(&setup, &setup.scenario, None, "linear FEM", progress)?;
    let corot = run_reference(
        &setup,
        &setup.scenario,
        Some(options.newton),
        "co-rotational FEM",
        progress,
    )?;
    setup.choose_tip(&corot.sensors);
    let ns = 3 * setup.full.operators.sensors.len();
    let tip_error = |run: &ReferenceRun| match setup.tip {
        Some(t) => {
            let mut s = ErrorSum::default();
            for k in 0..setup.steps {
                let at = k * ns + 3 * t;
                s.add(&run.sensors[at..at + 3], &corot.sensors[at..at + 3]);
            }
            s.relative()
        }
        None => f64::NAN,
    };
    let linear_row = FullOrderRow {
        step_s: linear.step_s,
        error: relative_l2(&linear.display, &corot.display),
        tip_error: tip_error(&linear),
        newton: None,
    };
    let corot_row = FullOrderRow {
        step_s: corot.step_s,
        error: 0.0,
        tip_error: 0.0,
        newton: corot.newton,
    };

    progress(Progress {
        phase: "modal system",
        done: 0,
        total: 1,
    });
    let reductor = Reductor::new(&setup.full, None, &mut StageTimer::default())?;
    progress(Progress {
        phase: "modal system",
        done: 1,
        total: 1,
    });
    let mut reduced = Vec::new();
    let mut failures = Vec::new();
    for &order in &options.orders {
        // One order's failure (a refused compile, a runtime that leaves its envelope) is
        // recorded with its reason and the report goes on with the next order.
        let one = |progress: &mut dyn FnMut(Progress)| -> Result<ReducedRow, ComparisonError> {
            let phase = format!("compile r = {order}");
            progress(Progress {
                phase: &phase,
                done: 0,
                total: 1,
            });
            let (model, compile_s) = compile_at(&reductor, order, options.measure_compile_error)?;
            progress(Progress {
                phase: &phase,
                done: 1,
                total: 1,
            });
            let r = model.r();
            let mut est = Estimator::new(&model).map_err(|source| ComparisonError::Runtime {
                path: setup.scene_path.clone(),
                order: r,
                step: 0,
                source,
            })?;
            // The comparison measures the filter itself, not the outlier gate: with model error
            // of 10 % and more at large rotation the 5σ gate would skip true measurements and the
            // figures would mix two effects (the README's tables were made without a gate).
            est.set_innovation_gate(None);
            let (given, inputs) = row_inputs(&setup, &model, options.withhold_loads)?;
            let none = vec![vec![None; model.measurements.len()]; setup.steps];
            let open = run_runtime(
                &setup,
                &mut est,
                &given,
                &none,
                &corot,
                Some(&linear),
                None,
                &format!("open loop r = {order}"),
                progress,
            )?;
            let measurements = synthetic_measurements(&model, &corot, setup.steps, options.seed);
            let filter = filtered_runs(
                &setup,
                &mut est,
                &model,
                &inputs,
                &measurements,
                &corot,
                options,
                &format!("r = {order}"),
                progress,
            )?;
            let times = time_row(
                &mut est,
                (&inputs, &measurements),
                (&given, &none),
                options.timing_samples,
                &format!("timing r = {order}"),
                progress,
            );
            Ok(ReducedRow {
                requested_order: order,
                order: r,
                force_states: r.saturating_sub(model.report.order as usize),
                figures: RowFigures::new(
                    RuntimeFigures::new(times, &open, &filter.given, &filter.withheld),
                    filter,
                ),
                compile_measured_errors: model.report.measured_errors.clone(),
                compile_s,
            })
        };
        match one(progress) {
            Ok(row) => reduced.push(row),
            Err(e) => failures.push(ReducedFailure {
                order,
                reason: e.to_string(),
            }),
        }
    }
    // The tier: a scene describing another body is an error of the inputs; a refused runtime
    // step is recorded with its reason like a failed order.
    let (tier_row, tier_failure) = match tier {
        None => (None, None),
        Some(t) => match run_tier(&setup, t, &corot, &linear, options, progress) {
            Ok(row) => (Some(row), None),
            Err(e) => (None, Some(e.to_string())),
        },
    };
    Ok(Comparison {
        scene: setup.scene_path.clone(),
        scenario: setup.scenario_path.clone(),
        dofs: setup.full.fem.dof_count(),
        tetrahedra: setup.full.fem.elements.len(),
        displayed_nodes: setup.display.len(),
        steps: setup.steps,
        dt: setup.dt(),
        tip: setup
            .tip
            .map(|t| setup.full.operators.sensors[t].name.clone()),
        max_rotation_deg: corot.max_rotation_deg,
        max_rotation_time: corot.max_rotation_step as f64 * setup.dt(),
        substeps: setup.substeps,
        corotational: corot_row,
        linear: linear_row,
        reduced,
        failures,
        tier: tier_row,
        tier_failure,
        tier_notes: tier.map(|t| t.notes().to_vec()).unwrap_or_default(),
        seed: options.seed,
        seeds: options.seeds,
        withheld_loads: options.withhold_loads,
        segments: segments::segments(&setup.scenario, setup.dt(), setup.steps),
        loads: setup
            .scenario
            .loads
            .iter()
            .filter(|l| l.forces.iter().flatten().any(|&f| f != 0.0))
            .map(|l| l.name.clone())
            .collect(),
        notes: setup
            .full
            .fem
            .notes
            .iter()
            .chain(&setup.full.operators.notes)
            .chain(&reductor.basis.warnings)
            .cloned()
            .collect(),
    })
}

/// "Where the warping approximation breaks down": for each factor in `scales`, the scenario's
/// loads (and gravity factor) are multiplied by it and the whole scenario is re-run
/// dynamically (same time history, same Δt) on the co-rotational reference, the linear
/// full-order model, and the runtime at order `order` open loop (compiled once), and the
/// co-rotational `tier` open loop when given (its envelope status recorded per scale; a refused
/// step is recorded as [`TierPoint::Failed`] and the sweep goes on). Returns one point per
/// scale, in the given order. Use [`breakdown_rotation`] / [`breakdown_rotation_of`] on the
/// result.
pub fn rotation_sweep(
    scene: &Path,
    scenario: &Path,
    order: usize,
    scales: &[f64],
    options: &ComparisonOptions,
    tier: Option<&TierModel>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Vec<SweepPoint>, ComparisonError> {
    if order == 0 {
        return Err(ComparisonError::Invalid {
            path: scene.to_owned(),
            what: "order must be ≥ 1".into(),
        });
    }
    if let Some(s) = scales.iter().find(|s| !s.is_finite()) {
        return Err(ComparisonError::Invalid {
            path: scenario.to_owned(),
            what: format!("load scale factors must be finite, got {s}"),
        });
    }
    let mut setup = Setup::new(scene, scenario)?;
    let (model, _) = compile_at(
        &Reductor::new(&setup.full, None, &mut StageTimer::default())?,
        order,
        false,
    )?;
    let mut est = Estimator::new(&model).map_err(|source| ComparisonError::Runtime {
        path: setup.scene_path.clone(),
        order: model.r(),
        step: 0,
        source,
    })?;
    let mut tier_est = match tier {
        None => None,
        Some(t) => {
            check_tier_matches(&setup, t)?;
            let mut est = Estimator::new(&t.model).map_err(|source| ComparisonError::Runtime {
                path: t.scene.clone(),
                order: t.basis_order(),
                step: 0,
                source,
            })?;
            est.set_innovation_gate(None);
            Some((t, est))
        }
    };
    let has_gravity = setup.full.scene.scene.gravity.is_some();
    let none = vec![vec![None; model.measurements.len()]; setup.steps];
    let mut points = Vec::with_capacity(scales.len());
    for &scale in scales {
        let scenario = scaled(&setup.scenario, scale, has_gravity);
        let lin = run_reference(
            &setup,
            &scenario,
            None,
            &format!("linear FEM ×{scale}"),
            progress,
        )?;
        let corot = run_reference(
            &setup,
            &scenario,
            Some(options.newton),
            &format!("co-rotational FEM ×{scale}"),
            progress,
        )?;
        setup.choose_tip(&corot.sensors);
        let inputs = runtime_inputs(&setup, &scenario, &model, false)?;
        let open = run_runtime(
            &setup,
            &mut est,
            &inputs,
            &none,
            &corot,
            None,
            None,
            &format!("open loop ×{scale}"),
            progress,
        )?;
        let tier = match &mut tier_est {
            None => None,
            Some((t, est)) => {
                let inputs = runtime_inputs(&setup, &scenario, &t.model, false)?;
                let none = vec![vec![None; t.model.measurements.len()]; setup.steps];
                let run = run_runtime(
                    &setup,
                    est,
                    &inputs,
                    &none,
                    &corot,
                    None,
                    None,
                    &format!("open loop tier ×{scale}"),
                    progress,
                );
                Some(match run {
                    Ok(e) => TierPoint::Ran {
                        open_loop_error: e.display.relative(),
                        tip_error: e.tip.relative(),
                        envelope: e.envelope,
                    },
                    Err(e) => TierPoint::Failed(e.to_string()),
                })
            }
        };
        points.push(SweepPoint {
            scale,
            max_rotation_deg: corot.max_rotation_deg,
            open_loop_error: open.display.relative(),
            tip_error: open.tip.relative(),
            linear_error: relative_l2(&lin.display, &corot.display),
            tier,
        });
    }
    Ok(points)
}
