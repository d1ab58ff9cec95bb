//! Training runs of the co-rotational tier (docs/design.md §10, item 2): full-order
//! co-rotational Wilson-θ runs over the scene's load groups, generated deterministically from a
//! [`TrainingPlan`], recorded as displacement snapshots.
//!
//! Run list, in this order: for each load group g, each direction d of `directions` and each
//! history h of `histories`, one run with only group g loaded by the world-frame dead load
//! f(t) = h(t)·F_g·d, F_g the group's load range (N). Histories: a ramp from 0 to a·F_g over
//! t_r then held, or a step to a·F_g at t = 0 (a the history's multiple of the range).

use std::path::Path;

use crokf_compile::stepping::{Formulation, NewtonOptions};
use crokf_compile::FullOrder;

use crate::scenario::{LoadHistory, Scenario};
use crate::simulate::{simulate, Frame, SimulateError, SimulationOptions};

use super::TierError;

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
}

impl TrainingPlan {
    /// The default plan: the six axis directions ±x, ±y, ±z; a ramp to 1.25× the range over
    /// `duration`/3 and a step to 0.6× the range; snapshots every `every` steps.
    pub fn axes(ranges: Vec<(String, f64)>, duration: f64, every: usize) -> Self {
        let mut directions = Vec::new();
        for c in 0..3 {
            for s in [1.0, -1.0] {
                let mut d = [0.0; 3];
                d[c] = s;
                directions.push(d);
            }
        }
        TrainingPlan {
            ranges,
            directions,
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
        }
    }

    /// The scenario of every run, labelled, in run order.
    pub fn scenarios(&self) -> Vec<(String, Scenario)> {
        let mut out = Vec::new();
        for (name, range) in &self.ranges {
            for d in &self.directions {
                for h in &self.histories {
                    let force = |m: f64| d.map(|c| c * m * range);
                    let (times, forces, label) = match *h {
                        History::Ramp { multiple, time } => (
                            vec![0.0, time],
                            vec![[0.0; 3], force(multiple)],
                            format!("ramp {multiple}×"),
                        ),
                        History::Step { multiple } => (
                            vec![0.0],
                            vec![force(multiple)],
                            format!("step {multiple}×"),
                        ),
                    };
                    out.push((
                        format!("{name} ({:+.0}, {:+.0}, {:+.0}) {label}", d[0], d[1], d[2]),
                        Scenario {
                            duration: Some(self.duration),
                            loads: vec![LoadHistory {
                                name: name.clone(),
                                times,
                                forces,
                            }],
                            ..Default::default()
                        },
                    ));
                }
            }
        }
        out
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

/// Snapshots of the training runs and what they cover.
#[derive(Clone, Debug, Default)]
pub struct Training {
    /// Displacement snapshots (n each, m).
    pub snapshots: Vec<Vec<f64>>,
    /// Per snapshot: its run index.
    pub run_of: Vec<usize>,
    /// Run labels and, for a run that failed, why (the run is then skipped).
    pub runs: Vec<(String, Option<String>)>,
    /// The envelope.
    pub envelope: TrainingEnvelope,
    /// Wall time of all runs, s.
    pub seconds: f64,
}

/// Runs every training scenario of `plan` on the full-order co-rotational model, keeping a
/// snapshot every `plan.every` steps (step 0 excluded). A run that fails (non-finite state,
/// Newton failure) is reported in [`Training::runs`] and skipped. `progress` receives
/// (run index, run count, label) before each run.
pub fn train(
    full: &FullOrder,
    plan: &TrainingPlan,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Training, TierError> {
    if plan.every == 0 || plan.duration.is_nan() || plan.duration <= 0.0 {
        return Err(TierError::Invalid(format!(
            "training plan: every must be ≥ 1 and duration > 0 s, got {} and {}",
            plan.every, plan.duration
        )));
    }
    for (name, range) in &plan.ranges {
        if !full.operators.loads.iter().any(|l| &l.name == name) {
            return Err(TierError::Invalid(format!(
                "training plan: '{name}' is not a load group of the scene"
            )));
        }
        if !(range.is_finite() && *range > 0.0) {
            return Err(TierError::Invalid(format!(
                "training plan: load range of '{name}' must be > 0 N, got {range}"
            )));
        }
    }
    let started = std::time::Instant::now();
    let scenarios = plan.scenarios();
    let mut out = Training::default();
    let options = SimulationOptions {
        formulation: Formulation::Corotational,
        newton: plan.newton,
        every: plan.every,
    };
    let fem = &full.fem;
    for (k, (label, scenario)) in scenarios.iter().enumerate() {
        progress(k, scenarios.len(), label);
        let mut frames: Vec<Vec<f64>> = Vec::new();
        let mut observer = |frame: &Frame| -> Result<(), SimulateError> {
            if frame.step > 0 {
                frames.push(frame.displacement.to_vec());
            }
            Ok(())
        };
        let result = simulate(
            fem,
            &full.operators,
            &full.scene.scene,
            scenario,
            &[],
            &options,
            Path::new(label),
            &mut observer,
        );
        match result {
            Ok(_) => {
                for u in frames {
                    out.envelope.max_displacement =
                        out.envelope.max_displacement.max(max_nodal(fem, &u));
                    out.snapshots.push(u);
                    out.run_of.push(k);
                }
                out.runs.push((label.clone(), None));
            }
            Err(e) => out.runs.push((label.clone(), Some(e.to_string()))),
        }
    }
    let top = plan
        .histories
        .iter()
        .map(History::multiple)
        .fold(0.0f64, f64::max);
    out.envelope.max_multiple = top;
    out.envelope.max_force = plan
        .ranges
        .iter()
        .map(|(n, r)| (n.clone(), r * top))
        .collect();
    out.envelope.runs = (
        out.runs.iter().filter(|r| r.1.is_none()).count(),
        out.runs.len(),
    );
    out.envelope.snapshots = out.snapshots.len();
    out.seconds = started.elapsed().as_secs_f64();
    Ok(out)
}

/// Largest nodal displacement magnitude of u (free DOFs, m).
pub fn max_nodal(fem: &crokf_compile::fem::FemModel, u: &[f64]) -> f64 {
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
