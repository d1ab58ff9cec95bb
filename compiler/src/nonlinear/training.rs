//! Training runs of the co-rotational tier (docs/design.md §10, item 2): full-order
//! co-rotational Wilson-θ runs over the scene's load groups, generated deterministically from a
//! [`TrainingPlan`], recorded as displacement snapshots. The compiler runs them itself when the
//! scene selects `[reduction] model = "corotational"` (its `[corotational]` table is the plan,
//! [`TrainingPlan::from_scene`]); `crokf-verify` reuses the same driver.
//!
//! Run list, in this order: for each load group g, each direction d of `directions` (the six
//! axes, and by default four diagonals: [`directions_of`]) and each
//! history h of `histories`, one run with only group g loaded by the world-frame dead load
//! f(t) = h(t)·F_g·d, F_g the group's load range (N). Histories: a ramp from 0 to a·F_g over
//! t_r then held, or a step to a·F_g at t = 0 (a the history's multiple of the range). Then,
//! with `combinations` and at least two groups, for each pair of groups g < g′, each d and each
//! sign s = +1, −1 and each h: one run with both loaded, f(t) = h(t)(F_g d b_g + s F_g′ d b_g′)
//! (same and opposite directions: e.g. an end torque made of two opposite forces). A scene that
//! lists its own load cases (`[[reduction.corotational.case]]`) gets those instead: for each
//! case, each sign s = +1, −1 and each h, one run with f(t) = s h(t) Σ_g F_g v_g b_g (v_g the
//! case's force on group g as a multiple of its range). Step k
//! (k = 0 … N−1, N = round(duration/Δt)) holds f(kΔt); a snapshot is kept after every
//! `every`-th step and after the last.
//!
//! Cost (docs/design.md §10, training; docs/results/tier.md §6): the runs use
//! [`ModifiedNewton`] (a factorised Newton matrix kept while the iteration contracts; the same
//! tolerance 1e-8 as the full-order reference, which keeps full Newton) and are computed
//! `threads` at a time, each with sequential factorisations; each run is independent and its
//! results are gathered by run index, so the snapshots (and the model file) do not depend on the
//! thread count or scheduling.

use crate::fem::operators::InputKind;
use crate::fem::FemModel;
use crate::full_order::FullOrder;
use crate::scene::{length3, CorotationalSpec, TrainingDirections};
use crate::stepping::{
    CorotationalSimulator, ModifiedNewton, NewtonOptions, NewtonStats, Simulator, SteppingError,
};

use super::NonlinearError;

/// The time history of one training run's load, as a multiple of the group's range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum History {
    /// 0 at t = 0, `multiple` at t = `time` (s), then held.
    Ramp {
        /// Final multiple of the range.
        multiple: f64,
        /// Ramp time, s.
        time: f64,
    },
    /// `multiple` from t = 0 on (a suddenly applied load: dynamic overshoot).
    Step {
        /// Multiple of the range.
        multiple: f64,
    },
}

impl History {
    /// Largest multiple of the range this history reaches.
    pub fn multiple(&self) -> f64 {
        match *self {
            History::Ramp { multiple, .. } | History::Step { multiple } => multiple,
        }
    }

    /// Multiple of the range at time t (s): linear ramp then held, or the step.
    pub fn at(&self, t: f64) -> f64 {
        match *self {
            History::Ramp { multiple, time } => {
                if time <= 0.0 || t >= time {
                    multiple
                } else {
                    multiple * (t / time).max(0.0)
                }
            }
            History::Step { multiple } => multiple,
        }
    }

    /// Short label, e.g. `ramp 1.25×`.
    pub fn label(&self) -> String {
        match *self {
            History::Ramp { multiple, .. } => format!("ramp {multiple}×"),
            History::Step { multiple } => format!("step {multiple}×"),
        }
    }
}

/// What the compiler trains on.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingPlan {
    /// Per load group (scene load name): its load range, the largest total force magnitude the
    /// model is meant for, N.
    pub ranges: Vec<(String, f64)>,
    /// Unit world directions of the training loads.
    pub directions: Vec<[f64; 3]>,
    /// Load histories.
    pub histories: Vec<History>,
    /// Length of each run, s.
    pub duration: f64,
    /// Keep every k-th step as a snapshot (k ≥ 1; the last step always).
    pub every: usize,
    /// Newton settings of the full-order runs.
    pub newton: NewtonOptions,
    /// Modified Newton in the runs (the default; None: full Newton, J refactored every
    /// iteration, as the full-order reference).
    pub modified: Option<ModifiedNewton>,
    /// Pair runs: every pair of groups loaded together, same and opposite directions.
    pub combinations: bool,
    /// The scene's own training load cases. When not empty they are the runs, each with both
    /// signs × `histories`, instead of those of `directions` and `combinations`.
    pub cases: Vec<LoadCase>,
    /// Runs computed at a time (≥ 1; results do not depend on it).
    pub threads: usize,
    /// The largest element rotation a kept snapshot may reach, degrees: a run is cut at its
    /// first snapshot past it or with an inverted element ([`Cut`]).
    pub max_rotation: f64,
}

/// A training load case of the plan: groups loaded together.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadCase {
    /// Name in the run labels.
    pub name: String,
    /// Per loaded group: its index into the plan's `ranges` and its force as a multiple of the
    /// range per world axis (length ≤ 1), in group order.
    pub loads: Vec<(usize, [f64; 3])>,
}

/// One training run: the loaded groups (index into [`TrainingPlan::ranges`]) with their unit
/// world directions, and the history of the multiple of each group's range.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingRun {
    /// Label, e.g. `tip (+0, +0, -1) ramp 1.25×`.
    pub label: String,
    /// (group, unit direction) of every loaded group.
    pub loads: Vec<(usize, [f64; 3])>,
    /// Load history.
    pub history: History,
}

/// Runs computed at a time by default: two (the training runs are independent; more threads
/// than cores only add memory), or one on a single-core machine.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().min(2))
}

/// The six axis directions ±x, ±y, ±z, in that order.
pub fn axis_directions() -> Vec<[f64; 3]> {
    let mut directions = Vec::new();
    for c in 0..3 {
        for s in [1.0, -1.0] {
            let mut d = [0.0; 3];
            d[c] = s;
            directions.push(d);
        }
    }
    directions
}

/// The four diagonals of a regular tetrahedron, (1, 1, 1), (1, −1, −1), (−1, 1, −1),
/// (−1, −1, 1), normalised: loaded along them a body shows the couplings between load
/// components (xy, xz, yz) that axis runs never excite ([`TrainingDirections`]).
pub fn tetrahedral_diagonals() -> Vec<[f64; 3]> {
    let s = 1.0 / 3f64.sqrt();
    vec![[s, s, s], [s, -s, -s], [-s, s, -s], [-s, -s, s]]
}

/// The unit directions of a scene's `directions` setting: the named sets axes first, a
/// list normalised in its order (checked non-zero by the scene).
pub fn directions_of(choice: &TrainingDirections) -> Vec<[f64; 3]> {
    match choice {
        TrainingDirections::Axes => axis_directions(),
        TrainingDirections::AxesAndDiagonals => {
            let mut directions = axis_directions();
            directions.extend(tetrahedral_diagonals());
            directions
        }
        TrainingDirections::List(list) => list.iter().map(|d| d.map(|x| x / length3(d))).collect(),
    }
}

impl TrainingPlan {
    /// The default plan: the six axis directions ±x, ±y, ±z; a ramp to 1.25× the range over
    /// `duration`/3 and a step to 0.6× the range; snapshots every `every` steps.
    pub fn axes(ranges: Vec<(String, f64)>, duration: f64, every: usize) -> Self {
        TrainingPlan {
            ranges,
            directions: axis_directions(),
            histories: vec![
                History::Ramp {
                    multiple: 1.25,
                    time: duration / 3.0,
                },
                History::Step { multiple: 0.6 },
            ],
            duration,
            every,
            newton: NewtonOptions::default(),
            modified: Some(ModifiedNewton::default()),
            combinations: true,
            cases: Vec::new(),
            threads: default_threads(),
            max_rotation: crate::scene::DEFAULT_MAX_ROTATION,
        }
    }

    /// The plan of a scene's `[corotational]` table: its `ranges` (in the scene's load order),
    /// its `case` list or else its `directions` ([`directions_of`]), a ramp to `ramp_multiple` × range over `ramp_time` (default
    /// duration/3) and a step to `step_multiple` × range.
    pub fn from_scene(spec: &CorotationalSpec, load_names: &[String]) -> Self {
        // With cases, a group no case loads is not trained: it leaves the plan (and the
        // envelope, so the runtime reports it outside when it is loaded).
        let ranges = spec.trained_ranges(load_names);
        let mut histories = Vec::new();
        if let Some((multiple, time)) = spec.training_ramp() {
            histories.push(History::Ramp { multiple, time });
        }
        if let Some(multiple) = spec.training_step() {
            histories.push(History::Step { multiple });
        }
        let cases: Vec<LoadCase> = spec
            .cases
            .iter()
            .enumerate()
            .map(|(i, case)| {
                let mut loads: Vec<(usize, [f64; 3])> = case
                    .loads
                    .iter()
                    .filter_map(|(name, v)| {
                        ranges.iter().position(|(n, _)| n == name).map(|g| (g, *v))
                    })
                    .collect();
                loads.sort_by_key(|&(g, _)| g);
                let name = case
                    .name
                    .clone()
                    .unwrap_or_else(|| format!("case {}", i + 1));
                LoadCase { name, loads }
            })
            .collect();
        // With cases, the envelope's directions are those the cases load along (both signs).
        let directions = if cases.is_empty() {
            directions_of(&spec.directions())
        } else {
            let mut unit: Vec<[f64; 3]> = Vec::new();
            for case in &cases {
                for (_, v) in &case.loads {
                    let length = length3(v);
                    for sign in [1.0, -1.0] {
                        let d = v.map(|x| sign * x / length + 0.0);
                        if !unit.contains(&d) {
                            unit.push(d);
                        }
                    }
                }
            }
            unit
        };
        TrainingPlan {
            ranges,
            directions,
            histories,
            duration: spec.duration,
            every: spec.every,
            newton: NewtonOptions::default(),
            modified: Some(ModifiedNewton::default()),
            combinations: spec.combinations(),
            cases,
            threads: default_threads(),
            max_rotation: spec.max_rotation(),
        }
    }

    /// [`TrainingPlan::from_scene`] for the scene `full` was built from: its
    /// `[reduction.corotational]` table and its load groups' names; `None` without the table.
    pub fn of_scene(full: &FullOrder) -> Option<Self> {
        let spec = full.scene.scene.reduction.corotational.as_ref()?;
        let names: Vec<String> = full
            .operators
            .loads
            .iter()
            .map(|l| l.name.clone())
            .collect();
        Some(Self::from_scene(spec, &names))
    }

    /// Every run, in run order (module doc).
    pub fn runs(&self) -> Vec<TrainingRun> {
        // The built-in directions and their negations by their signs, e.g. "(+1, -1, -1)";
        // any other to 2 decimals.
        let named: Vec<[f64; 3]> = axis_directions()
            .into_iter()
            .chain(tetrahedral_diagonals())
            .collect();
        let direction = |d: &[f64; 3]| {
            let negated = d.map(|x| -x + 0.0);
            if named.contains(d) || named.contains(&negated) {
                format!("({:+.0}, {:+.0}, {:+.0})", d[0], d[1], d[2])
            } else {
                format!("({:+.2}, {:+.2}, {:+.2})", d[0], d[1], d[2])
            }
        };
        let mut out = Vec::new();
        if !self.cases.is_empty() {
            for case in &self.cases {
                for (sign, mark) in [(1.0, "+"), (-1.0, "−")] {
                    for h in &self.histories {
                        out.push(TrainingRun {
                            label: format!("{} {mark} {}", case.name, h.label()),
                            loads: case
                                .loads
                                .iter()
                                .map(|&(g, v)| (g, v.map(|x| sign * x + 0.0)))
                                .collect(),
                            history: *h,
                        });
                    }
                }
            }
            return out;
        }
        for (g, (name, _)) in self.ranges.iter().enumerate() {
            for d in &self.directions {
                for h in &self.histories {
                    out.push(TrainingRun {
                        label: format!("{name} {} {}", direction(d), h.label()),
                        loads: vec![(g, *d)],
                        history: *h,
                    });
                }
            }
        }
        if self.combinations {
            for (g, (first, _)) in self.ranges.iter().enumerate() {
                for (g2, (second, _)) in self.ranges.iter().enumerate().skip(g + 1) {
                    for d in &self.directions {
                        for sign in [1.0, -1.0] {
                            // + 0.0 turns −0 into +0 (labels).
                            let d2 = d.map(|c| sign * c + 0.0);
                            for h in &self.histories {
                                out.push(TrainingRun {
                                    label: format!(
                                        "{first} {} + {second} {} {}",
                                        direction(d),
                                        direction(&d2),
                                        h.label()
                                    ),
                                    loads: vec![(g, *d), (g2, d2)],
                                    history: *h,
                                });
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// The largest force the training puts on group `g` (index into `ranges`), N: its range ×
    /// [`TrainingPlan::max_multiple`], × the longest force a case gives it when the plan has
    /// cases.
    pub fn max_force(&self, g: usize) -> f64 {
        let share = if self.cases.is_empty() {
            1.0
        } else {
            self.cases
                .iter()
                .flat_map(|c| c.loads.iter().filter(|(h, _)| *h == g))
                .map(|(_, v)| length3(v))
                .fold(0.0, f64::max)
        };
        self.ranges[g].1 * share * self.max_multiple()
    }

    /// Largest multiple of a range any history reaches.
    pub fn max_multiple(&self) -> f64 {
        self.histories
            .iter()
            .map(History::multiple)
            .fold(0.0f64, f64::max)
    }
}

/// The region of load space and state space the training covered (stored with the model so the
/// runtime can say when it leaves it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainingEnvelope {
    /// Per load group: the largest training force magnitude, N.
    pub max_force: Vec<(String, f64)>,
    /// Largest multiple of a group's range trained on.
    pub max_multiple: f64,
    /// Largest nodal displacement magnitude in any snapshot, m.
    pub max_displacement: f64,
    /// Runs completed / attempted.
    pub runs: (usize, usize),
    /// Snapshots kept.
    pub snapshots: usize,
}

/// Where a training run was cut: its first snapshot with an inverted element (det F ≤ 0) or an
/// element rotated past the plan's `max_rotation`. That snapshot and the later ones are left
/// out (the load history past that point drives the body past anything the tier is for); the
/// run keeps `kept` snapshots, the checks replay it only that far, and the envelope's forces
/// count its load only up to its last kept snapshot.
#[derive(Clone, Debug, PartialEq)]
pub struct Cut {
    /// Snapshots kept (those before the first one past the limit; ≥ 1).
    pub kept: usize,
    /// Snapshots the run computed.
    pub of: usize,
    /// Time of the first snapshot left out, s.
    pub time: f64,
    /// Multiple of the group's range the load history had reached there.
    pub multiple: f64,
    /// What that snapshot does, e.g. `inverts 3 elements` or `rotates an element 131°`.
    pub reason: String,
}

/// Snapshots of the training runs and what they cover.
#[derive(Clone, Debug, Default)]
pub struct Training {
    /// Displacement snapshots (n each, m).
    pub snapshots: Vec<Vec<f64>>,
    /// Per snapshot: its run index.
    pub run_of: Vec<usize>,
    /// Run labels and, for a run that failed, why (the run is then skipped).
    pub runs: Vec<(String, Option<String>)>,
    /// Per run (as `runs`): where it was cut, when its load drove the body past what the tier
    /// is for ([`Cut`]); its snapshots from there on are not in `snapshots`.
    pub cuts: Vec<Option<Cut>>,
    /// The envelope.
    pub envelope: TrainingEnvelope,
    /// Wall time of all runs, s.
    pub seconds: f64,
    /// Newton counters and times summed over the runs (times are thread time: with two
    /// threads they add up to about twice the wall time).
    pub newton: NewtonStats,
    /// Runs read from a case cache ([`cases::train_cached`](super::cases::train_cached)).
    pub cached: usize,
    /// Case files that could not be used or stored (the runs were computed all the same).
    pub cache_notes: Vec<String>,
}

/// The load vector (n, N) of a unit world force `direction` (N) on load group `group` (index
/// into the scene's loads): Σ_c d_c b_{g,c}.
pub fn group_load(full: &FullOrder, group: usize, direction: [f64; 3], scale: f64) -> Vec<f64> {
    let mut f = vec![0.0; full.fem.dof_count()];
    for ch in &full.operators.inputs {
        if let InputKind::Load { load, component } = ch.kind {
            let value = scale * direction[component];
            if load == group && value != 0.0 {
                f.iter_mut()
                    .zip(&ch.column)
                    .for_each(|(fi, b)| *fi += value * b);
            }
        }
    }
    f
}

/// The scene load group (index into `full.operators.loads`) of each of `plan.ranges`, checked:
/// every name is a load group and every range is finite and > 0 N.
pub fn plan_groups(full: &FullOrder, plan: &TrainingPlan) -> Result<Vec<usize>, NonlinearError> {
    let mut groups = Vec::with_capacity(plan.ranges.len());
    for (name, range) in &plan.ranges {
        let Some(g) = full.operators.loads.iter().position(|l| &l.name == name) else {
            return Err(NonlinearError::Invalid(format!(
                "training plan: '{name}' is not a load group of the scene"
            )));
        };
        if !(range.is_finite() && *range > 0.0) {
            return Err(NonlinearError::Invalid(format!(
                "training plan: load range of '{name}' must be > 0 N, got {range}"
            )));
        }
        groups.push(g);
    }
    Ok(groups)
}

/// The load vector of `run` at multiple 1 of its history (n, N): Σ over its loaded groups of
/// F_g Σ_c d_c b_{g,c} ([`group_load`] with the group's range F_g); step k of the run holds
/// `run.history.at(kΔt)` times it. `groups` from [`plan_groups`].
pub fn run_load(
    full: &FullOrder,
    plan: &TrainingPlan,
    groups: &[usize],
    run: &TrainingRun,
) -> Vec<f64> {
    let mut f = vec![0.0; full.fem.dof_count()];
    for &(g, d) in &run.loads {
        let column = group_load(full, groups[g], d, plan.ranges[g].1);
        f.iter_mut().zip(&column).for_each(|(fi, c)| *fi += c);
    }
    f
}

impl TrainingPlan {
    /// Steps of each run: N = round(duration/Δt), at least 1 (Δt in s).
    pub fn steps(&self, dt: f64) -> usize {
        ((self.duration / dt).round() as usize).max(1)
    }

    /// Snapshots one run keeps ([`TrainingPlan::keeps`] over its steps).
    pub fn snapshot_count(&self, dt: f64) -> usize {
        let steps = self.steps(dt);
        (1..=steps).filter(|&k| self.keeps(k, steps)).count()
    }

    /// Whether the state after step `step` (1-based, of `steps`) is kept as a snapshot: every
    /// `every`-th step and the last.
    pub fn keeps(&self, step: usize, steps: usize) -> bool {
        step.is_multiple_of(self.every.max(1)) || step == steps
    }
}

/// Runs every training run of `plan` on the full-order co-rotational model, keeping a
/// snapshot every `plan.every` steps (step 0 excluded). A run that fails (non-finite state,
/// Newton failure) is reported in [`Training::runs`] and skipped. `progress` receives
/// (run index, run count, label) before each run. (With a case cache:
/// [`cases::train_cached`](super::cases::train_cached).)
pub fn train(
    full: &FullOrder,
    plan: &TrainingPlan,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Training, NonlinearError> {
    train_each(full, plan, progress, |_, compute| (compute(), ())).map(|(training, _)| training)
}

/// The skeleton of [`train`] and [`cases::train_cached`](super::cases::train_cached): the plan
/// checked, its runs made on `plan.threads` threads and gathered. Run k's result is what
/// `each(k, compute)` returns, `compute()` being the run itself (a caller may return a result
/// it has from elsewhere instead), with a value of the caller's per run (None for a run that
/// did not finish).
pub(crate) fn train_each<T: Send>(
    full: &FullOrder,
    plan: &TrainingPlan,
    progress: &mut dyn FnMut(usize, usize, &str),
    each: impl Fn(usize, &dyn Fn() -> RunResult) -> (RunResult, T) + Sync,
) -> Result<(Training, Vec<Option<T>>), NonlinearError> {
    check_plan(plan)?;
    let groups = plan_groups(full, plan)?;
    let started = std::time::Instant::now();
    let runs = plan.runs();
    let outcomes = run_indexed(
        runs.len(),
        plan.threads,
        |k| each(k, &|| run_one(full, plan, &groups, &runs[k])),
        |k| progress(k, runs.len(), &runs[k].label),
    );
    let (results, extra): (Vec<Option<RunResult>>, Vec<Option<T>>) = outcomes
        .into_iter()
        .map(|o| match o {
            Some((result, value)) => (Some(result), Some(value)),
            None => (None, None),
        })
        .unzip();
    Ok((gather(full, plan, &runs, results, started), extra))
}

/// The result of one training run: its snapshots (each n, m) and Newton counters, or why it
/// failed.
pub type RunResult = Result<(Vec<Vec<f64>>, NewtonStats), String>;

/// Refuses a plan that cannot run: `every` 0, a duration not > 0 s, 0 threads.
pub(crate) fn check_plan(plan: &TrainingPlan) -> Result<(), NonlinearError> {
    if plan.every == 0 || plan.duration.is_nan() || plan.duration <= 0.0 {
        return Err(NonlinearError::Invalid(format!(
            "training plan: every must be ≥ 1 and duration > 0 s, got {} and {}",
            plan.every, plan.duration
        )));
    }
    if plan.threads == 0 {
        return Err(NonlinearError::Invalid(
            "training plan: threads must be ≥ 1".to_owned(),
        ));
    }
    Ok(())
}

/// `run` of `plan` (`groups` from [`plan_groups`]).
pub(crate) fn run_one(
    full: &FullOrder,
    plan: &TrainingPlan,
    groups: &[usize],
    run: &TrainingRun,
) -> RunResult {
    training_run(full, plan, &run_load(full, plan, groups, run), &run.history)
        .map_err(|e| e.to_string())
}

/// Runs run `index` of `plan` alone (a job array's task, a Dask task): its result, as
/// [`train`] computes it for that run.
pub fn run_case(
    full: &FullOrder,
    plan: &TrainingPlan,
    index: usize,
) -> Result<RunResult, NonlinearError> {
    check_plan(plan)?;
    let groups = plan_groups(full, plan)?;
    let runs = plan.runs();
    let Some(run) = runs.get(index) else {
        return Err(NonlinearError::Invalid(format!(
            "training case {index}: the scene has {} cases (0 to {})",
            runs.len(),
            runs.len().saturating_sub(1)
        )));
    };
    Ok(run_one(full, plan, &groups, run))
}

/// The [`Training`] of `runs` from their results by index (None: the run did not finish);
/// `started`: when the runs began (its wall time).
pub(crate) fn gather(
    full: &FullOrder,
    plan: &TrainingPlan,
    runs: &[TrainingRun],
    results: Vec<Option<RunResult>>,
    started: std::time::Instant,
) -> Training {
    let cut_at = run_indexed(
        runs.len(),
        plan.threads,
        |k| match &results[k] {
            Some(Ok((frames, _))) => first_past_limit(full, plan, frames),
            _ => None,
        },
        |_| {},
    );
    let dt = full.wilson.dt;
    let steps = plan.steps(dt);
    let kept_steps: Vec<usize> = (1..=steps).filter(|&k| plan.keeps(k, steps)).collect();
    let mut out = Training::default();
    // Per group (as `plan.ranges`): the largest force a kept snapshot's load history reached.
    let mut max_force = vec![0.0f64; plan.ranges.len()];
    let mut max_multiple = 0.0f64;
    for (k, ((run, result), cut_at)) in runs.iter().zip(results).zip(cut_at).enumerate() {
        let mut cut = None;
        match result {
            Some(Ok((mut frames, stats))) => {
                if let Some((j, reason)) = cut_at.flatten() {
                    let step = kept_steps.get(j).copied().unwrap_or(steps);
                    let time = step as f64 * dt;
                    let multiple = run.history.at((step - 1) as f64 * dt);
                    if j == 0 {
                        out.runs.push((
                            run.label.clone(),
                            Some(format!(
                                "its first snapshot (t = {time} s, {multiple:.3}× the range) \
                                 already {reason}: no snapshot kept"
                            )),
                        ));
                        out.cuts.push(None);
                        continue;
                    }
                    cut = Some(Cut {
                        kept: j,
                        of: frames.len(),
                        time,
                        multiple,
                        reason,
                    });
                    frames.truncate(j);
                }
                // The multiple the load reached up to the last kept snapshot.
                let reached = match &cut {
                    None => run.history.multiple(),
                    Some(c) => {
                        let last = kept_steps.get(c.kept - 1).copied().unwrap_or(steps);
                        (0..last)
                            .map(|s| run.history.at(s as f64 * dt).abs())
                            .fold(0.0, f64::max)
                    }
                };
                max_multiple = max_multiple.max(reached);
                for &(g, v) in &run.loads {
                    if let Some(f) = max_force.get_mut(g) {
                        *f = f.max(plan.ranges[g].1 * length3(&v) * reached);
                    }
                }
                for u in frames {
                    out.envelope.max_displacement =
                        out.envelope.max_displacement.max(max_nodal(&full.fem, &u));
                    out.snapshots.push(u);
                    out.run_of.push(k);
                }
                add_stats(&mut out.newton, &stats);
                out.runs.push((run.label.clone(), None));
            }
            Some(Err(e)) => out.runs.push((run.label.clone(), Some(e))),
            None => out
                .runs
                .push((run.label.clone(), Some("the run did not finish".to_owned()))),
        }
        out.cuts.push(cut);
    }
    out.envelope.max_multiple = max_multiple;
    out.envelope.max_force = plan
        .ranges
        .iter()
        .zip(max_force)
        .map(|((n, _), f)| (n.clone(), f))
        .collect();
    out.envelope.runs = (
        out.runs.iter().filter(|r| r.1.is_none()).count(),
        out.runs.len(),
    );
    out.envelope.snapshots = out.snapshots.len();
    out.seconds = started.elapsed().as_secs_f64();
    out
}

/// The first of a run's snapshots past what the tier is for, and why: an inverted element
/// (det F ≤ 0) or an element rotated more than `plan.max_rotation` degrees. None: all within.
fn first_past_limit(
    full: &FullOrder,
    plan: &TrainingPlan,
    frames: &[Vec<f64>],
) -> Option<(usize, String)> {
    frames.iter().enumerate().find_map(|(j, u)| {
        let d = deformation(&full.fem, u);
        if d.inverted > 0 {
            let s = if d.inverted == 1 { "" } else { "s" };
            Some((
                j,
                format!(
                    "inverts {} element{s} (det F {:.3} at element tag {})",
                    d.inverted, d.min_det, full.fem.elements[d.worst_element].tag
                ),
            ))
        } else if d.max_rotation > plan.max_rotation {
            Some((
                j,
                format!(
                    "rotates an element {:.0}° (max_rotation {}°)",
                    d.max_rotation, plan.max_rotation
                ),
            ))
        } else {
            None
        }
    })
}

/// One training run: the full-order co-rotational simulator from rest under f(t) =
/// `history`(t)·`unit`, its snapshots (every `plan.every` steps and the last) and Newton counters.
fn training_run(
    full: &FullOrder,
    plan: &TrainingPlan,
    unit: &[f64],
    history: &History,
) -> Result<(Vec<Vec<f64>>, NewtonStats), SteppingError> {
    let dt = full.wilson.dt;
    let steps = plan.steps(dt);
    let mut sim = CorotationalSimulator::new(&full.fem, full.wilson, plan.newton)?;
    sim.set_modified_newton(plan.modified)?;
    sim.set_sequential();
    let mut frames = Vec::new();
    let mut f = vec![0.0; unit.len()];
    for step in 0..steps {
        let m = history.at(step as f64 * dt);
        f.iter_mut().zip(unit).for_each(|(fi, u)| *fi = m * u);
        sim.step(&f)?;
        let u = sim.displacement();
        if u.iter().any(|v| !v.is_finite()) {
            return Err(SteppingError::NonFinite {
                step: step + 1,
                time: (step + 1) as f64 * dt,
            });
        }
        if plan.keeps(step + 1, steps) {
            frames.push(u.to_vec());
        }
    }
    Ok((frames, sim.stats()))
}

/// Sums the counters and times of `b` into `a` (worst increment: the larger).
fn add_stats(a: &mut NewtonStats, b: &NewtonStats) {
    a.steps += b.steps;
    a.solves += b.solves;
    a.unconverged += b.unconverged;
    a.fallbacks += b.fallbacks;
    a.worst_increment = a.worst_increment.max(b.worst_increment);
    a.factorisations += b.factorisations;
    a.assembly_seconds += b.assembly_seconds;
    a.factor_seconds += b.factor_seconds;
    a.solve_seconds += b.solve_seconds;
}

/// Largest nodal displacement magnitude of u (free DOFs, m).
pub fn max_nodal(fem: &FemModel, u: &[f64]) -> f64 {
    fem.dofs
        .index
        .iter()
        .map(|d| {
            d.iter()
                .map(|i| i.map_or(0.0, |i| u[i] * u[i]))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// How far a displacement state is from what an elastic body can mean: its elements'
/// smallest det F (≤ 0: inverted), how many are inverted, and the largest element rotation
/// (the polar decomposition's angle, degrees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deformation {
    /// Smallest det F over the elements.
    pub min_det: f64,
    /// Elements with det F ≤ 0.
    pub inverted: usize,
    /// Index of the element with the smallest det F.
    pub worst_element: usize,
    /// Largest element rotation, degrees.
    pub max_rotation: f64,
}

/// [`Deformation`] of the free-DOF displacement `u` (m) of `fem`.
pub fn deformation(fem: &FemModel, u: &[f64]) -> Deformation {
    let at = |node: usize| -> [f64; 3] {
        let mut x = fem.positions[node];
        for (c, xc) in x.iter_mut().enumerate() {
            if let Some(i) = fem.dofs.index[node][c] {
                *xc += u[i];
            }
        }
        x
    };
    let mut out = Deformation {
        min_det: f64::INFINITY,
        inverted: 0,
        worst_element: 0,
        max_rotation: 0.0,
    };
    for (e, element) in fem.elements.iter().enumerate() {
        let x = element.nodes.map(at);
        let f = crate::stepping::element::deformation_gradient(&element.geometry, &x);
        let det = f.determinant();
        if det.is_nan() || det <= 0.0 {
            out.inverted += 1;
        }
        if det.is_nan() || det < out.min_det {
            out.min_det = det;
            out.worst_element = e;
        }
        let r = crate::stepping::element::polar_rotation(&f);
        let cos = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
        out.max_rotation = out.max_rotation.max(cos.acos().to_degrees());
    }
    out
}

/// `work(k)` for k = 0 … `count` − 1 on up to `threads` scoped threads (at least one), each
/// taking the next k; `started(k)` runs on the calling thread as each k begins (progress).
/// The results by index, independent of the thread count and the order of completion.
pub(crate) fn run_indexed<T: Send>(
    count: usize,
    threads: usize,
    work: impl Fn(usize) -> T + Sync,
    mut started: impl FnMut(usize),
) -> Vec<Option<T>> {
    let mut results: Vec<Option<T>> = (0..count).map(|_| None).collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let (sender, receiver) = std::sync::mpsc::channel::<(usize, Option<T>)>();
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, count.max(1)) {
            let sender = sender.clone();
            let (next, work) = (&next, &work);
            scope.spawn(move || loop {
                let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if k >= count {
                    break;
                }
                // The receiver lives until every sender is dropped: sends cannot fail.
                let _ = sender.send((k, None));
                let result = work(k);
                let _ = sender.send((k, Some(result)));
            });
        }
        drop(sender);
        for (k, message) in receiver {
            match message {
                None => started(k),
                Some(result) => results[k] = Some(result),
            }
        }
    });
    results
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default plan trains each load group along the six axes and four tetrahedral
    /// diagonals (unit vectors; every pair of the three components loaded together, with both
    /// signs of its product); `directions = "axes"` keeps the six axes alone.
    #[test]
    fn default_directions_are_the_axes_and_four_diagonals() {
        let spec: CorotationalSpec = toml::from_str("duration = 0.1").unwrap();
        assert_eq!(spec.directions(), TrainingDirections::AxesAndDiagonals);
        let plan = TrainingPlan::from_scene(&spec, &[]);
        assert_eq!(plan.directions.len(), 10);
        assert_eq!(plan.directions[..6], axis_directions()[..]);
        for d in &plan.directions {
            let norm = d.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!((norm - 1.0).abs() < 1e-15, "{d:?}");
        }
        // Each coupling (xy, xz, yz) appears with both signs over the diagonals.
        for (i, j) in [(0, 1), (0, 2), (1, 2)] {
            let signs: Vec<f64> = plan.directions[6..]
                .iter()
                .map(|d| (d[i] * d[j]).signum())
                .collect();
            assert!(
                signs.contains(&1.0) && signs.contains(&-1.0),
                "{i}{j}: {signs:?}"
            );
        }
        let mut ranges = std::collections::BTreeMap::new();
        ranges.insert("push".to_string(), 1.0);
        let spec = CorotationalSpec { ranges, ..spec };
        let runs = TrainingPlan::from_scene(&spec, &["push".to_string()]).runs();
        assert_eq!(runs.len(), 20);
        assert_eq!(runs[12].label, "push (+1, +1, +1) ramp 1.25×");

        let axes: CorotationalSpec =
            toml::from_str("duration = 0.1\ndirections = \"axes\"").unwrap();
        assert_eq!(
            TrainingPlan::from_scene(&axes, &[]).directions,
            axis_directions()
        );
        let bad = toml::from_str::<CorotationalSpec>("duration = 0.1\ndirections = \"all\"")
            .unwrap_err()
            .to_string();
        assert!(bad.contains("axes_and_diagonals"), "{bad}");
    }

    /// Listed load cases are the runs (each sign × each history), in the scene's group order,
    /// labelled by the case's name; their directions (both signs, unit) are the envelope's, the
    /// trained force per group is the longest a case gives it, and a group with a range that no
    /// case loads leaves the plan.
    #[test]
    fn listed_cases_replace_the_generated_runs() {
        let spec: CorotationalSpec = toml::from_str(
            "duration = 0.1\nranges = { lower = 2.0, upper = 3.0 }\n\
             [[case]]\nname = \"twist\"\nloads = { upper = [0, 1, 0], lower = [0, -1, 0] }\n\
             [[case]]\nloads = { lower = [0, 0, 0.5] }\n",
        )
        .unwrap();
        let names = ["upper".to_string(), "lower".to_string()];
        let plan = TrainingPlan::from_scene(&spec, &names);
        let runs = plan.runs();
        let labels: Vec<&str> = runs.iter().map(|r| r.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "twist + ramp 1.25×",
                "twist + step 0.6×",
                "twist − ramp 1.25×",
                "twist − step 0.6×",
                "case 2 + ramp 1.25×",
                "case 2 + step 0.6×",
                "case 2 − ramp 1.25×",
                "case 2 − step 0.6×",
            ]
        );
        // upper is group 0 (the scene's order), lower group 1.
        assert_eq!(
            runs[0].loads,
            vec![(0, [0.0, 1.0, 0.0]), (1, [0.0, -1.0, 0.0])]
        );
        assert_eq!(
            runs[2].loads,
            vec![(0, [0.0, -1.0, 0.0]), (1, [0.0, 1.0, 0.0])]
        );
        assert_eq!(runs[6].loads, vec![(1, [0.0, 0.0, -0.5])]);
        // The trained force per group: upper at its full range, lower at its full range (the
        // couple) × the ramp's 1.25.
        assert_eq!(plan.max_force(0), 3.0 * 1.25);
        assert_eq!(plan.max_force(1), 2.0 * 1.25);
        assert_eq!(
            plan.directions,
            vec![
                [0.0, 1.0, 0.0],
                [0.0, -1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, 0.0, -1.0]
            ]
        );
        // A group no case loads is not in the plan.
        let spec = CorotationalSpec {
            cases: spec.cases[1..].to_vec(),
            ..spec
        };
        let plan = TrainingPlan::from_scene(&spec, &names);
        assert_eq!(plan.ranges, vec![("lower".to_string(), 2.0)]);
        assert_eq!(plan.runs()[0].loads, vec![(0, [0.0, 0.0, 0.5])]);
        assert_eq!(plan.max_force(0), 2.0 * 0.5 * 1.25);
    }

    /// A case naming a group without a range, a zero or too long force, a repeated name, no
    /// load, or cases together with `directions` / `combinations` are refused naming the entry.
    #[test]
    fn case_errors_name_the_entry() {
        for (table, entry) in [
            (
                "[[reduction.corotational.case]]\nloads = { nope = [0, 1, 0] }",
                "case[0].loads.nope",
            ),
            (
                "[[reduction.corotational.case]]\nloads = { push = [0, 0, 0] }",
                "case[0].loads.push",
            ),
            (
                "[[reduction.corotational.case]]\nloads = { push = [0, 1, 1] }",
                "case[0].loads.push",
            ),
            (
                "[[reduction.corotational.case]]\nloads = {}",
                "case[0].loads",
            ),
            (
                "[[reduction.corotational.case]]\nname = \"a\"\nloads = { push = [0, 1, 0] }\n\
                 [[reduction.corotational.case]]\nname = \"a\"\nloads = { push = [1, 0, 0] }",
                "case[1].name",
            ),
            (
                "[[reduction.corotational.case]]\nloads = { push = [0, 1, 0] }",
                "reduction.corotational.directions",
            ),
        ] {
            let directions = if entry.ends_with("directions") {
                "directions = \"axes\"\n"
            } else {
                ""
            };
            let text = format!(
                "[mesh]\nfile = \"m.msh\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = 1e6\n\
                 poisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\n\
                 name = \"push\"\ngroup = \"xmax\"\n[[load]]\nname = \"nope\"\ngroup = \"xmax\"\nforce_model = \"white\"\n\
                 [time]\ndt = 1e-3\n[reduction]\nmodel = \"corotational\"\n\
                 [reduction.corotational]\nranges = {{ push = 1.0 }}\nduration = 0.1\n{directions}{table}\n"
            );
            let err = crate::scene::Scene::parse(&text, std::path::Path::new("s.toml"))
                .expect_err(table)
                .to_string();
            let entry = if entry.starts_with("reduction") {
                entry.to_string()
            } else {
                format!("reduction.corotational.{entry}")
            };
            assert!(err.contains(&entry), "{table}: {err}");
        }
    }

    /// A listed set of directions is trained as written, normalised, with labels that tell
    /// the directions apart; a zero, a non-finite or a repeated direction is refused by the
    /// scene check naming the entry.
    #[test]
    fn listed_directions_are_normalised_and_checked() {
        let spec: CorotationalSpec =
            toml::from_str("duration = 0.1\ndirections = [[0, 2, 0], [0, -1, 0], [1, 1, 0]]")
                .unwrap();
        let s = 0.5f64.sqrt();
        let plan = TrainingPlan::from_scene(&spec, &[]);
        let expected = [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [s, s, 0.0]];
        assert_eq!(plan.directions.len(), 3);
        for (d, e) in plan.directions.iter().zip(&expected) {
            assert!(d.iter().zip(e).all(|(a, b)| (a - b).abs() < 1e-15), "{d:?}");
        }
        let mut ranges = std::collections::BTreeMap::new();
        ranges.insert("push".to_string(), 1.0);
        let spec = CorotationalSpec { ranges, ..spec };
        let runs = TrainingPlan::from_scene(&spec, &["push".to_string()]).runs();
        assert_eq!(runs.len(), 6);
        assert_eq!(runs[0].label, "push (+0, +1, +0) ramp 1.25×");
        assert_eq!(runs[4].label, "push (+0.71, +0.71, +0.00) ramp 1.25×");
        for (list, entry) in [
            ("[[0, 0, 0]]", "directions[0]"),
            ("[[0, 1, 0], [1, 0, 0], [0, 3, 0]]", "directions[2]"),
            ("[]", "directions: list between 1"),
            ("[[1, 0, nan]]", "directions[0]"),
        ] {
            let text = format!(
                "[mesh]\nfile = \"m.msh\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = 1e6\n\
                 poisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\n\
                 name = \"push\"\ngroup = \"xmax\"\n[time]\ndt = 1e-3\n[reduction]\n\
                 model = \"corotational\"\n[reduction.corotational]\nranges = {{ push = 1.0 }}\n\
                 duration = 0.1\ndirections = {list}\n"
            );
            let err = crate::scene::Scene::parse(&text, std::path::Path::new("s.toml"))
                .expect_err(list)
                .to_string();
            assert!(
                err.contains(&format!("reduction.corotational.{entry}")),
                "{list}: {err}"
            );
        }
    }

    /// The scene's count of the training (its check's snapshot count) is the plan's: as many
    /// runs as [`TrainingPlan::runs`] lists, as many steps per run, and as many directions as
    /// [`directions_of`] gives, over directions, histories, combinations, cases and loads
    /// without a range.
    #[test]
    fn the_scenes_training_count_is_the_plans() {
        let names: Vec<String> = ["upper", "lower", "mid", "free"].map(String::from).to_vec();
        for (k, text) in [
            "duration = 0.1",
            "duration = 0.1\nranges = { upper = 2.0 }",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0, mid = 1.0 }",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0 }\ncombinations = false",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0 }\ndirections = \"axes\"",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0 }\n\
             directions = [[0, 1, 0], [0, -1, 0], [1, 0, 0]]",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0 }\nramp_multiple = 0",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0 }\nstep_multiple = 0",
            "duration = 0.3\nranges = { upper = 2.0 }\nramp_multiple = 0\nstep_multiple = 0",
            "duration = 0.1\nranges = { upper = 2.0, lower = 3.0, mid = 1.0 }\n\
             [[case]]\nname = \"twist\"\nloads = { upper = [0, 1, 0], lower = [0, -1, 0] }\n\
             [[case]]\nloads = { lower = [0, 0, 0.5] }\n",
        ]
        .into_iter()
        .enumerate()
        {
            let spec: CorotationalSpec = toml::from_str(text).unwrap();
            let plan = TrainingPlan::from_scene(&spec, &names);
            assert_eq!(
                spec.training_run_count(&names),
                plan.runs().len(),
                "{k}: {text}"
            );
            assert_eq!(
                spec.directions().count(),
                directions_of(&spec.directions()).len(),
                "{k}"
            );
            assert_eq!(spec.trained_ranges(&names), plan.ranges, "{k}");
            for dt in [1e-3, 0.007, 0.05, 1.0] {
                assert_eq!(spec.training_steps(dt), plan.steps(dt), "{k}: dt {dt}");
            }
        }
    }
}
