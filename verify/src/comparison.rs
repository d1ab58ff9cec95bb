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

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crokf_formats as fmt;
use crokf_runtime::{Estimator, RuntimeError};

use crokf_compile::compile::{compile, compile_reduced};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{
    deformation_gradient, polar_rotation, CorotationalSimulator, LinearSimulator, NewtonOptions,
    NewtonStats, Simulator, SteppingError,
};
use crokf_compile::{CompileError, CompileOptions, FullOrder, Reductor};

use crate::bench::{median_step_seconds, step_clock_seconds};

mod consistency;
mod metrics;
mod render;

use crate::scenario::{Horizon, Scenario, ScenarioError};
pub use consistency::{
    chi_square_quantile, spread, verdict, ChiSquare, Consistency, ConsistencyAccumulator, Ensemble,
    FilterBlocks, RunLengthMismatch, SeedEnsemble, StepFractions, TipSample,
};
use metrics::ErrorSum;
pub use metrics::{
    breakdown_rotation, breakdown_rotation_of, relative_l2, rotation_angle, Gaussian,
};
pub use render::{format_seconds, sweep_markdown};

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
    /// Give the runtime no load inputs (open loop and filter): the force is unknown to the
    /// estimator, only the measurements carry it. The references still get the loads.
    pub withhold_loads: bool,
    /// Timing samples (batches) of the runtime step.
    pub timing_samples: usize,
    /// Noise draws of the N-run consistency test (seeds `seed`, `seed + 1`, …; docs/design.md
    /// §11.3): every filtered run is repeated with each; below 2 only the single run.
    pub seeds: usize,
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
    /// Median runtime step without measurements (predict + empty update), s (batched; thread
    /// CPU time).
    pub open_loop_step_s: f64,
    /// Open loop: relative L2 error over displayed nodes vs the co-rotational reference.
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
    /// Whether the runtime got the loads.
    pub withheld_loads: bool,
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

/// The co-rotational tier compiled from its scene (training included), once per report.
#[derive(Clone, Debug)]
pub struct TierModel {
    /// The tier's scene file.
    pub scene: PathBuf,
    /// The compiled model (format v3 with the tier section).
    pub model: fmt::Model,
    /// Compile wall time, training included, s.
    pub compile_s: f64,
}

/// Compiles the co-rotational tier of `scene` (`[reduction] model = "corotational"`), the whole
/// pipeline with its training runs (progress of the training on stderr, from the compiler);
/// the balanced part of the file is compiled at the scene's default order without its measured
/// error (the report measures the tier itself). Refuses a scene without the tier.
pub fn compile_tier(
    scene: &Path,
    progress: &mut dyn FnMut(Progress),
) -> Result<TierModel, ComparisonError> {
    let phase = "compile co-rotational tier";
    progress(Progress {
        phase,
        done: 0,
        total: 1,
    });
    let start = Instant::now();
    let compiled = compile(
        scene,
        &CompileOptions {
            skip_measured_error: true,
            ..CompileOptions::default()
        },
    )?;
    let compile_s = start.elapsed().as_secs_f64();
    if compiled.model.tier.is_none() {
        return Err(ComparisonError::Invalid {
            path: scene.to_owned(),
            what: "this scene has no co-rotational tier: give a scene with [reduction] model = \"corotational\" and [reduction.corotational]".into(),
        });
    }
    progress(Progress {
        phase,
        done: 1,
        total: 1,
    });
    Ok(TierModel {
        scene: scene.to_owned(),
        model: compiled.model,
        compile_s,
    })
}

impl TierModel {
    /// POD basis size r of the tier.
    pub fn basis_order(&self) -> usize {
        self.model.tier.as_ref().map_or(0, |t| t.order as usize)
    }

    /// Sampled (ECSW) elements.
    pub fn sampled_elements(&self) -> usize {
        self.model.tier.as_ref().map_or(0, |t| t.elements.len())
    }

    /// The compiler's notes on the tier's compile (training, sampling, its filter, advice).
    pub fn notes(&self) -> &[String] {
        &self.model.report.notes
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

/// The scene and scenario, ready to run.
struct Setup {
    scene_path: PathBuf,
    scenario_path: PathBuf,
    full: FullOrder,
    scenario: Scenario,
    steps: usize,
    /// Unique displayed nodes: (node set, index in set, mesh node).
    display: Vec<(usize, usize, usize)>,
    /// Tip sensor index.
    tip: Option<usize>,
    /// Elements around the displayed nodes: per displayed node, (element, volume share).
    around: Vec<Vec<(usize, f64)>>,
    /// Elements touching any displayed node.
    elements: Vec<usize>,
}

impl Setup {
    fn new(scene: &Path, scenario_path: &Path) -> Result<Self, ComparisonError> {
        let mut timer = StageTimer::default();
        let full = FullOrder::build(scene, &mut timer)?;
        let scenario = Scenario::read(scenario_path)?;
        scenario.check_scene(&full.scene.scene, scenario_path)?;
        let invalid = |what: String| ComparisonError::Invalid {
            path: scenario_path.to_owned(),
            what,
        };
        let steps =
            match scenario.horizon(full.wilson.dt) {
                Horizon::Steps(k) => k,
                Horizon::Steady(_) => return Err(invalid(
                    "a comparison needs a fixed horizon: give `duration` or `steps`, not `steady`"
                        .into(),
                )),
            };
        let ops = &full.operators;
        let mut seen = vec![false; full.fem.positions.len()];
        let mut display = Vec::new();
        for (s, set) in ops.node_sets.iter().enumerate() {
            for (i, &node) in set.nodes.iter().enumerate() {
                if !std::mem::replace(&mut seen[node], true) {
                    display.push((s, i, node));
                }
            }
        }
        if display.is_empty() {
            return Err(ComparisonError::Invalid {
                path: scene.to_owned(),
                what: "the scene displays no nodes: add a [[display]] node set to compare on"
                    .into(),
            });
        }
        let tip = ops.sensors.iter().position(|s| s.name == "tip");
        let fem = &full.fem;
        let mut node_elements = vec![Vec::new(); fem.positions.len()];
        for (e, el) in fem.elements.iter().enumerate() {
            for &n in &el.nodes {
                if seen[n] {
                    node_elements[n].push(e);
                }
            }
        }
        let mut touched = vec![false; fem.elements.len()];
        let around = display
            .iter()
            .map(|&(_, _, node)| {
                let list = &node_elements[node];
                let total: f64 = list.iter().map(|&e| fem.elements[e].geometry.volume).sum();
                list.iter()
                    .map(|&e| {
                        touched[e] = true;
                        (e, fem.elements[e].geometry.volume / total)
                    })
                    .collect()
            })
            .collect();
        let elements = (0..fem.elements.len()).filter(|&e| touched[e]).collect();
        Ok(Setup {
            scene_path: scene.to_owned(),
            scenario_path: scenario_path.to_owned(),
            full,
            scenario,
            steps,
            display,
            tip,
            around,
            elements,
        })
    }

    fn dt(&self) -> f64 {
        self.full.wilson.dt
    }

    /// World displacement (3 per displayed node, m) from free-DOF displacements u.
    fn displayed(&self, u: &[f64], out: &mut Vec<f64>) {
        let index = &self.full.fem.dofs.index;
        for &(_, _, node) in &self.display {
            out.extend(index[node].iter().map(|d| d.map_or(0.0, |d| u[d])));
        }
    }

    /// World displacement of every sensor (3 per sensor, m).
    fn sensors(&self, u: &[f64], out: &mut Vec<f64>) {
        let fem = &self.full.fem;
        for s in &self.full.operators.sensors {
            let mut d = [0.0; 3];
            for &(node, w) in &s.weights {
                for (c, dc) in d.iter_mut().enumerate() {
                    if let Some(i) = fem.dofs.index[node][c] {
                        *dc += w * u[i];
                    }
                }
            }
            out.extend_from_slice(&d);
        }
    }

    /// Largest rotation angle over displayed nodes, degrees: angle of polar(Σₑ Vₑ Fₑ / Σₑ Vₑ).
    fn max_rotation_deg(&self, u: &[f64], f_cache: &mut [nalgebra::Matrix3<f64>]) -> f64 {
        let fem = &self.full.fem;
        for &e in &self.elements {
            let el = &fem.elements[e];
            let x: [[f64; 3]; 4] = std::array::from_fn(|a| {
                let n = el.nodes[a];
                std::array::from_fn(|c| {
                    fem.positions[n][c] + fem.dofs.index[n][c].map_or(0.0, |d| u[d])
                })
            });
            f_cache[e] = deformation_gradient(&el.geometry, &x);
        }
        let mut max = 0.0f64;
        for list in &self.around {
            let mut f = nalgebra::Matrix3::zeros();
            for &(e, share) in list {
                f += f_cache[e] * share;
            }
            max = max.max(rotation_angle(&polar_rotation(&f)).to_degrees());
        }
        max
    }

    /// Without a sensor named `tip`: the sensor whose largest displacement in `corot` is the
    /// largest (the point that moves most); kept once chosen.
    fn choose_tip(&mut self, corot: &ReferenceRun) {
        let ns = self.full.operators.sensors.len();
        if self.tip.is_some() || ns == 0 {
            return;
        }
        let mut peak = vec![0.0f64; ns];
        for (i, u) in corot.sensors.chunks_exact(3).enumerate() {
            let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
            peak[i % ns] = peak[i % ns].max(norm);
        }
        self.tip = (0..ns).max_by(|&a, &b| peak[a].total_cmp(&peak[b]));
    }

    fn reference_error(&self, source: SteppingError) -> ComparisonError {
        ComparisonError::Reference {
            path: self.scenario_path.clone(),
            source,
        }
    }
}

/// Scales the scenario's loads (and gravity factor) by `scale`.
fn scaled(scenario: &Scenario, scale: f64, has_gravity: bool) -> Scenario {
    let mut s = scenario.clone();
    for l in &mut s.loads {
        for f in &mut l.forces {
            *f = f.map(|v| v * scale);
        }
    }
    if has_gravity {
        s.gravity = Some(s.gravity.unwrap_or(1.0) * scale);
    }
    s
}

/// A recorded full-order run.
struct ReferenceRun {
    /// Per step 1..=N: displayed-node displacements (3D each, flattened).
    display: Vec<f64>,
    /// Per step 1..=N: sensor displacements (3S each, flattened).
    sensors: Vec<f64>,
    step_s: f64,
    max_rotation_deg: f64,
    max_rotation_step: usize,
    newton: Option<NewtonStats>,
}

fn run_reference(
    setup: &Setup,
    scenario: &Scenario,
    corotational: Option<NewtonOptions>,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<ReferenceRun, ComparisonError> {
    let full = &setup.full;
    let fem = &full.fem;
    let n = fem.dof_count();
    let err = |e| setup.reference_error(e);
    let mut linear = None;
    let mut corot = None;
    let sim: &mut dyn Simulator = match corotational {
        None => linear.insert(LinearSimulator::new(fem, full.wilson).map_err(err)?),
        Some(newton) => {
            corot.insert(CorotationalSimulator::new(fem, full.wilson, newton).map_err(err)?)
        }
    };
    let steps = setup.steps;
    let dt = setup.dt();
    let mut out = ReferenceRun {
        display: Vec::with_capacity(steps * 3 * setup.display.len()),
        sensors: Vec::with_capacity(steps * 3 * full.operators.sensors.len()),
        step_s: 0.0,
        max_rotation_deg: 0.0,
        max_rotation_step: 0,
        newton: None,
    };
    let mut f_cache = vec![nalgebra::Matrix3::zeros(); fem.elements.len()];
    let mut times = Vec::with_capacity(steps);
    let report_every = (steps / 100).max(1);
    progress(Progress {
        phase,
        done: 0,
        total: steps,
    });
    for k in 0..steps {
        let f = scenario.load_vector(&full.operators, n, k as f64 * dt);
        let start = Instant::now();
        sim.step(&f).map_err(err)?;
        times.push(start.elapsed().as_secs_f64());
        let u = sim.displacement();
        if let Some(i) = u.iter().position(|v| !v.is_finite()) {
            return Err(ComparisonError::Invalid {
                path: setup.scenario_path.clone(),
                what: format!(
                    "{phase}: non-finite displacement at DOF {i}, step {}, t = {:.6} s",
                    k + 1,
                    (k + 1) as f64 * dt
                ),
            });
        }
        setup.displayed(u, &mut out.display);
        setup.sensors(u, &mut out.sensors);
        if corotational.is_some() {
            let angle = setup.max_rotation_deg(u, &mut f_cache);
            if angle > out.max_rotation_deg {
                out.max_rotation_deg = angle;
                out.max_rotation_step = k + 1;
            }
        }
        if (k + 1) % report_every == 0 || k + 1 == steps {
            progress(Progress {
                phase,
                done: k + 1,
                total: steps,
            });
        }
    }
    times.sort_by(f64::total_cmp);
    out.step_s = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
    out.newton = corot.as_ref().map(|c| c.stats());
    Ok(out)
}

/// Errors of one runtime run.
#[derive(Clone, Copy, Debug, Default)]
struct RunErrors {
    display: ErrorSum,
    tip: ErrorSum,
    display_vs_linear: ErrorSum,
    /// The co-rotational tier's envelope status over the run (default for the warped tier).
    envelope: EnvelopeSummary,
}

/// Drives the estimator through precomputed inputs and measurements (per step), accumulating
/// errors against the references.
#[allow(clippy::too_many_arguments)]
fn run_runtime(
    setup: &Setup,
    est: &mut Estimator,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    corot: &ReferenceRun,
    linear: Option<&ReferenceRun>,
    mut consistency: Option<&mut ConsistencyAccumulator>,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<RunErrors, ComparisonError> {
    est.reset();
    let model_order = est.model().r();
    let nd = 3 * setup.display.len();
    let ns = 3 * setup.full.operators.sensors.len();
    let sets = &setup.full.operators.node_sets;
    let mut set_buffers: Vec<Vec<f64>> =
        sets.iter().map(|s| vec![0.0; 3 * s.nodes.len()]).collect();
    let mut display = vec![0.0; nd];
    let mut sensors = vec![0.0; ns];
    let mut errors = RunErrors::default();
    let steps = setup.steps;
    let report_every = (steps / 20).max(1);
    let runtime_err = |step: usize, source| ComparisonError::Runtime {
        path: setup.scene_path.clone(),
        order: model_order,
        step,
        source,
    };
    for k in 0..steps {
        if let Some(acc) = consistency.as_deref_mut() {
            est.predict(&inputs[k]).map_err(|e| runtime_err(k + 1, e))?;
            acc.innovation(est, &measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
            est.update(&measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
        } else {
            est.step(&inputs[k], &measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
        }
        if est.is_corotational() {
            errors.envelope.record(&est.tier_status());
        }
        for (s, buf) in set_buffers.iter_mut().enumerate() {
            est.node_displacements(s, buf)
                .map_err(|e| runtime_err(k + 1, e))?;
        }
        for (j, &(s, i, _)) in setup.display.iter().enumerate() {
            display[3 * j..3 * j + 3].copy_from_slice(&set_buffers[s][3 * i..3 * i + 3]);
        }
        errors
            .display
            .add(&display, &corot.display[k * nd..(k + 1) * nd]);
        if let Some(lin) = linear {
            errors
                .display_vs_linear
                .add(&display, &lin.display[k * nd..(k + 1) * nd]);
        }
        if let Some(t) = setup.tip {
            est.sensor_displacements(&mut sensors)
                .map_err(|e| runtime_err(k + 1, e))?;
            errors.tip.add(
                &sensors[3 * t..3 * t + 3],
                &corot.sensors[k * ns + 3 * t..k * ns + 3 * t + 3],
            );
        }
        if let Some(acc) = consistency.as_deref_mut() {
            let tip_ref = match setup.tip {
                Some(t) => &corot.sensors[k * ns + 3 * t..k * ns + 3 * t + 3],
                None => &[][..],
            };
            acc.posterior(
                est,
                (k + 1) as f64 * setup.dt(),
                tip_ref,
                &display,
                &corot.display[k * nd..(k + 1) * nd],
            )
            .map_err(|e| runtime_err(k + 1, e))?;
        }
        if (k + 1) % report_every == 0 || k + 1 == steps {
            progress(Progress {
                phase,
                done: k + 1,
                total: steps,
            });
        }
    }
    Ok(errors)
}

/// The row's timed steps (progress `phase`, 0/1): the median runtime step with the
/// measurements and without (open loop), s.
fn time_row(
    est: &mut Estimator,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    none: &[Vec<Option<f64>>],
    samples: usize,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> (f64, f64) {
    progress(Progress {
        phase,
        done: 0,
        total: 1,
    });
    let step_s = time_runtime(est, inputs, measurements, samples);
    let open_loop_step_s = time_runtime(est, inputs, none, samples);
    progress(Progress {
        phase,
        done: 1,
        total: 1,
    });
    (step_s, open_loop_step_s)
}

/// Median time of one `est.step` over the precomputed sequence, s, in this thread's CPU time
/// ([`step_clock_seconds`]): batches of consecutive steps (each batch ≥ ~2 ms, wrapping to the
/// start with a reset), `samples` batches.
fn time_runtime(
    est: &mut Estimator,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    samples: usize,
) -> f64 {
    let steps = inputs.len();
    if steps == 0 {
        return f64::NAN;
    }
    est.reset();
    let mut k = 0;
    let mut run = |est: &mut Estimator, count: usize| {
        for _ in 0..count {
            if k == steps {
                est.reset();
                k = 0;
            }
            // A step can only fail on a non-invertible warp or (tier) a refused Newton step,
            // both already ruled out by the runs over the same sequence.
            let _ = black_box(est.step(black_box(&inputs[k]), black_box(&measurements[k])));
            k += 1;
        }
    };
    // Calibrate the batch so one sample lasts about 2 ms.
    let mut batch = 16;
    loop {
        let start = step_clock_seconds();
        run(est, batch);
        let t = step_clock_seconds() - start;
        // NaN (no clock) ends the calibration too.
        if t.is_nan() || t >= 2e-3 || batch >= 1 << 22 {
            break;
        }
        batch *= 2;
    }
    median_step_seconds(samples, || run(est, batch)) / batch as f64
}

/// Inputs per step k = 0..N (the step k → k+1 holds u(t_k)), in `model.inputs` order.
fn runtime_inputs(
    setup: &Setup,
    scenario: &Scenario,
    model: &fmt::Model,
    withhold_loads: bool,
) -> Result<Vec<Vec<f64>>, ComparisonError> {
    let ops = &setup.full.operators;
    if model.inputs.len() != ops.inputs.len() {
        return Err(ComparisonError::Invalid {
            path: setup.scene_path.clone(),
            what: format!(
                "the compiled model has {} input channels, the scene {}",
                model.inputs.len(),
                ops.inputs.len()
            ),
        });
    }
    let dt = setup.dt();
    Ok((0..setup.steps)
        .map(|k| {
            let mut u = scenario.inputs_at(ops, k as f64 * dt);
            if withhold_loads {
                for (v, ch) in u.iter_mut().zip(&model.inputs) {
                    if matches!(ch.kind, fmt::InputKind::Load { .. }) {
                        *v = 0.0;
                    }
                }
            }
            u
        })
        .collect())
}

/// Synthetic measurements per step k = 0..N (the update after the step k → k+1): the
/// co-rotational reference's world sensor displacement at step k+1 plus N(0, σ_s²), on the
/// channels that the schedule's phase (k+1) mod period measures; others `None`. One sample is
/// drawn per channel per step whether used or not, so the noise does not depend on `every`.
fn synthetic_measurements(
    model: &fmt::Model,
    corot: &ReferenceRun,
    steps: usize,
    seed: u64,
) -> Vec<Vec<Option<f64>>> {
    let mut rng = Gaussian::new(seed);
    let ns = 3 * model.sensors.len();
    // The filter the estimator runs: the tier's own when the model has one.
    let kalman = model.tier.as_ref().map_or(&model.kalman, |t| &t.kalman);
    let period = kalman.period.max(1) as usize;
    (0..steps)
        .map(|k| {
            let phase = &kalman.phases[(k + 1) % period];
            let mut y = vec![None; model.measurements.len()];
            let noise: Vec<f64> = kalman
                .measurement_variance
                .iter()
                .map(|variance| variance.sqrt() * rng.normal())
                .collect();
            for &j in &phase.measured {
                let ch = model.measurements[j as usize];
                let exact = corot.sensors[k * ns + 3 * ch.sensor as usize + ch.component as usize];
                y[j as usize] = Some(exact + noise[j as usize]);
            }
            y
        })
        .collect()
}

/// Reduces the prepared modal system at order r (truncation, Kalman, model file; the front end
/// and the modes are built once per report) and returns the model and the wall time.
fn compile_at(
    reductor: &Reductor,
    order: usize,
    measure: bool,
) -> Result<(fmt::Model, f64), ComparisonError> {
    let start = Instant::now();
    let compiled = compile_reduced(
        reductor,
        &CompileOptions {
            order: Some(order),
            skip_measured_error: !measure,
            ..CompileOptions::default()
        },
        StageTimer::default(),
    )?;
    Ok((compiled.model, start.elapsed().as_secs_f64()))
}

/// Refuses a tier whose scene is not the comparison's body: the inputs, the sensors and the
/// displayed node sets (names, sizes and rest positions) must agree, since the tier's read-outs
/// are compared node by node with the comparison scene's references.
fn check_tier_matches(setup: &Setup, tier: &TierModel) -> Result<(), ComparisonError> {
    let model = &tier.model;
    let ops = &setup.full.operators;
    let fail = |what: String| ComparisonError::Invalid {
        path: tier.scene.clone(),
        what: format!(
            "the co-rotational tier's scene does not match {}: {what}",
            setup.scene_path.display()
        ),
    };
    let inputs: Vec<&str> = model.inputs.iter().map(|c| c.label.as_str()).collect();
    let expected: Vec<&str> = ops.inputs.iter().map(|c| c.label.as_str()).collect();
    if inputs != expected {
        return Err(fail(format!("inputs {inputs:?}, expected {expected:?}")));
    }
    let sensors: Vec<&str> = model.sensors.iter().map(|s| s.name.as_str()).collect();
    let expected: Vec<&str> = ops.sensors.iter().map(|s| s.name.as_str()).collect();
    if sensors != expected {
        return Err(fail(format!("sensors {sensors:?}, expected {expected:?}")));
    }
    if model.node_sets.len() != ops.node_sets.len() {
        return Err(fail(format!(
            "{} node sets, expected {}",
            model.node_sets.len(),
            ops.node_sets.len()
        )));
    }
    let positions = &setup.full.fem.positions;
    let scale = positions
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for (set, ours) in model.node_sets.iter().zip(&ops.node_sets) {
        if set.name != ours.name || set.node_tags.len() != ours.nodes.len() {
            return Err(fail(format!(
                "node set '{}' ({} nodes), expected '{}' ({} nodes)",
                set.name,
                set.node_tags.len(),
                ours.name,
                ours.nodes.len()
            )));
        }
        for (i, &node) in ours.nodes.iter().enumerate() {
            let rest = &set.rest_positions.data[3 * i..3 * i + 3];
            if (0..3).any(|c| (rest[c] - positions[node][c]).abs() > 1e-9 * scale) {
                return Err(fail(format!(
                    "node {i} of set '{}' rests at {rest:?}, expected {:?}",
                    set.name, positions[node]
                )));
            }
        }
    }
    Ok(())
}

/// The tier's row: open loop, filtered with the loads given and withheld, and the timed step,
/// through the same [`run_runtime`], inputs and synthetic measurements as the warped rows.
fn run_tier(
    setup: &Setup,
    tier: &TierModel,
    corot: &ReferenceRun,
    linear: &ReferenceRun,
    options: &ComparisonOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<TierRow, ComparisonError> {
    let model = &tier.model;
    let r = tier.basis_order();
    let mut est = Estimator::new(model).map_err(|source| ComparisonError::Runtime {
        path: tier.scene.clone(),
        order: r,
        step: 0,
        source,
    })?;
    // As for the warped rows: the filter itself, not the outlier gate.
    est.set_innovation_gate(None);
    let force_states = est.state().len().saturating_sub(3 * r);
    let inputs = runtime_inputs(setup, &setup.scenario, model, options.withhold_loads)?;
    let none = vec![vec![None; model.measurements.len()]; setup.steps];
    let open = run_runtime(
        setup,
        &mut est,
        &inputs,
        &none,
        corot,
        Some(linear),
        None,
        "open loop tier",
        progress,
    )?;
    let measurements = synthetic_measurements(model, corot, setup.steps, options.seed);
    let filter = filtered_runs(
        setup,
        &mut est,
        model,
        &inputs,
        &measurements,
        corot,
        options,
        "tier",
        progress,
    )?;
    let times = time_row(
        &mut est,
        &inputs,
        &measurements,
        &none,
        options.timing_samples,
        "timing tier",
        progress,
    );
    Ok(TierRow {
        scene: tier.scene.clone(),
        basis_order: r,
        sampled_elements: tier.sampled_elements(),
        force_states,
        compile_s: tier.compile_s,
        figures: RowFigures::new(
            RuntimeFigures::new(times, &open, &filter.given, &filter.withheld),
            filter,
        ),
        filters: model.tier.as_ref().map_or(1, |t| 1 + t.scheduled.len()),
        envelope: open.envelope,
    })
}

/// The filtered runs of one row (a warped order or the tier) and their consistency.
struct FilteredRuns {
    given: RunErrors,
    given_consistency: Consistency,
    given_ensemble: Option<SeedEnsemble>,
    withheld: RunErrors,
    withheld_consistency: Consistency,
    withheld_ensemble: Option<SeedEnsemble>,
}

/// A row's filtered runs through [`run_runtime`]: with `inputs` (the loads given, or withheld
/// when the whole comparison withholds them) and, unless `options.withhold_loads`, with the
/// loads withheld (the headline case: the runtime gets no load input, only the markers), each
/// with the same [`ConsistencyAccumulator`] over the model's own stored filters
/// ([`FilterBlocks`]: the warped model's, or the tier's gain schedule); then each repeated over
/// `options.seeds` noise draws ([`seed_ensemble`]). Progress phases `filtered {label}`,
/// `withheld {label}`, and `draws filtered {label}` / `draws withheld {label}` with the draws.
#[allow(clippy::too_many_arguments)]
fn filtered_runs(
    setup: &Setup,
    est: &mut Estimator,
    model: &fmt::Model,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    corot: &ReferenceRun,
    options: &ComparisonOptions,
    label: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<FilteredRuns, ComparisonError> {
    let display: Vec<(usize, usize)> = setup.display.iter().map(|&(s, i, _)| (s, i)).collect();
    let blocks = FilterBlocks::new(model, &display);
    let mut acc = ConsistencyAccumulator::new(&blocks, model, setup.tip);
    let given = run_runtime(
        setup,
        est,
        inputs,
        measurements,
        corot,
        None,
        Some(&mut acc),
        &format!("filtered {label}"),
        progress,
    )?;
    let given_consistency = acc.finish();
    let given_ensemble = seed_ensemble(
        setup,
        est,
        model,
        &blocks,
        inputs,
        corot,
        options,
        (&given, &given_consistency),
        &format!("draws filtered {label}"),
        progress,
    )?;
    if options.withhold_loads {
        return Ok(FilteredRuns {
            given,
            withheld: given,
            withheld_consistency: given_consistency.clone(),
            given_consistency,
            withheld_ensemble: given_ensemble.clone(),
            given_ensemble,
        });
    }
    let blind = runtime_inputs(setup, &setup.scenario, model, true)?;
    let mut acc = ConsistencyAccumulator::new(&blocks, model, setup.tip);
    let withheld = run_runtime(
        setup,
        est,
        &blind,
        measurements,
        corot,
        None,
        Some(&mut acc),
        &format!("withheld {label}"),
        progress,
    )?;
    let withheld_consistency = acc.finish();
    let withheld_ensemble = seed_ensemble(
        setup,
        est,
        model,
        &blocks,
        &blind,
        corot,
        options,
        (&withheld, &withheld_consistency),
        &format!("draws withheld {label}"),
        progress,
    )?;
    Ok(FilteredRuns {
        given,
        given_consistency,
        given_ensemble,
        withheld,
        withheld_consistency,
        withheld_ensemble,
    })
}

/// A filtered run over the noise draws `options.seed + i`, i = 0 … `options.seeds` − 1 (the
/// N-run consistency test, docs/design.md §11.3); `first` is the run of draw 0, already made.
/// A draw the runtime refuses is recorded with its reason. `None` below 2 draws. Progress
/// phase `phase`.
#[allow(clippy::too_many_arguments)]
fn seed_ensemble(
    setup: &Setup,
    est: &mut Estimator,
    model: &fmt::Model,
    blocks: &FilterBlocks,
    inputs: &[Vec<f64>],
    corot: &ReferenceRun,
    options: &ComparisonOptions,
    first: (&RunErrors, &Consistency),
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<Option<SeedEnsemble>, ComparisonError> {
    if options.seeds < 2 {
        return Ok(None);
    }
    let invalid = |e: RunLengthMismatch| ComparisonError::Invalid {
        path: setup.scene_path.clone(),
        what: format!("{phase}: {e}"),
    };
    let mut ensemble = SeedEnsemble::default();
    ensemble
        .add(first.0.display.relative(), first.1)
        .map_err(invalid)?;
    for i in 1..options.seeds as u64 {
        let seed = options.seed.wrapping_add(i);
        let measurements = synthetic_measurements(model, corot, setup.steps, seed);
        let mut acc = ConsistencyAccumulator::new(blocks, model, setup.tip);
        match run_runtime(
            setup,
            est,
            inputs,
            &measurements,
            corot,
            None,
            Some(&mut acc),
            phase,
            progress,
        ) {
            Ok(errors) => ensemble
                .add(errors.display.relative(), &acc.finish())
                .map_err(invalid)?,
            Err(e) => ensemble.refused.push((seed, e.to_string())),
        }
    }
    Ok(Some(ensemble))
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
    setup.choose_tip(&corot);
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
            let inputs = runtime_inputs(&setup, &setup.scenario, &model, options.withhold_loads)?;
            let none = vec![vec![None; model.measurements.len()]; setup.steps];
            let open = run_runtime(
                &setup,
                &mut est,
                &inputs,
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
                &inputs,
                &measurements,
                &none,
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
        setup.choose_tip(&corot);
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
