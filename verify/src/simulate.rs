//! `crokf-verify simulate`: drives a full-order stepper of the compiler
//! ([`crokf_compile::stepping`]) through a scenario file and records world displacements at the
//! scene's sensors and the scenario's named points (docs/design.md §7).

use std::path::{Path, PathBuf};
use std::time::Instant;

use crokf_compile::dynamics::WilsonTheta;
use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::FemModel;
use crokf_compile::report::StageTimer;
use crokf_compile::scene::Scene;
use crokf_compile::stepping::{
    CorotationalSimulator, Formulation, LinearSimulator, NewtonOptions, NewtonStats, Simulator,
    SteppingError,
};
use crokf_compile::{CompileError, FullOrder};

use crokf_formats::output::{
    check_paths, write_atomically, Output, OutputError, OutputKind, StagedDir,
};

use crate::scenario::{Horizon, Scenario, ScenarioError};
use crate::vtu;

/// Errors of `crokf-verify simulate`; each names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    /// The full-order stepper failed.
    #[error(transparent)]
    Stepping(#[from] SteppingError),
    /// Scene, mesh or FEM assembly.
    #[error(transparent)]
    Compile(#[from] CompileError),
    /// Scenario file.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// Invalid options.
    #[error("{0}")]
    Options(String),
    /// A steady scenario did not settle.
    #[error(
        "{path}: not steady after {steps} steps: relative change per step {change:.3e} > \
         tolerance {tolerance:.3e} (raise steady.max_steps or damping)"
    )]
    SteadyNotReached {
        /// Scenario path.
        path: PathBuf,
        /// Steps taken.
        steps: usize,
        /// Last relative change.
        change: f64,
        /// Requested tolerance.
        tolerance: f64,
    },
    /// A named point outside the mesh.
    #[error(
        "{path}: point '{name}' at ({:.6}, {:.6}, {:.6}) m lies outside the mesh \
         (nearest node {nearest_tag} at distance {distance:.3e} m)",
        position[0], position[1], position[2]
    )]
    PointOutside {
        /// Scenario path.
        path: PathBuf,
        /// Point name.
        name: String,
        /// Position, m.
        position: [f64; 3],
        /// gmsh tag of the nearest node.
        nearest_tag: u64,
        /// Distance to it, m.
        distance: f64,
    },
    /// An output path refused before any work, or a failed write.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// Output file.
    #[error("{path}: {source}")]
    Io {
        /// File or directory.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
}

/// Settings of [`simulate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimulationOptions {
    /// Full-order formulation.
    pub formulation: Formulation,
    /// Newton settings (co-rotational only).
    pub newton: NewtonOptions,
    /// Record every k-th step (and the first and last), k ≥ 1.
    pub every: usize,
}

impl Default for SimulationOptions {
    fn default() -> Self {
        SimulationOptions {
            formulation: Formulation::Linear,
            newton: NewtonOptions::default(),
            every: 1,
        }
    }
}

/// A recorded point: a scene sensor or a scenario point, with barycentric node weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Probe {
    /// Label.
    pub name: String,
    /// Rest position, m.
    pub position: [f64; 3],
    /// Nodes of the containing tetrahedron and their barycentric weights.
    pub weights: [(usize, f64); 4],
}

impl Probe {
    /// World displacement of the point, Σₐ wₐ uₐ (m), from the free-DOF displacement u.
    pub fn displacement(&self, fem: &FemModel, u: &[f64]) -> [f64; 3] {
        let mut d = [0.0; 3];
        for &(node, w) in &self.weights {
            for (c, dc) in d.iter_mut().enumerate() {
                if let Some(i) = fem.dofs.index[node][c] {
                    *dc += w * u[i];
                }
            }
        }
        d
    }
}

/// Probes: the scene's sensors (in scene order), then the scenario's named points, located in
/// the rest mesh. `unit` converts scenario positions to metres; `path` names the scenario file.
pub fn probes(
    fem: &FemModel,
    ops: &Operators,
    scenario: &Scenario,
    unit: f64,
    path: &Path,
) -> Result<Vec<Probe>, SimulateError> {
    let mut out: Vec<Probe> = ops
        .sensors
        .iter()
        .map(|s| Probe {
            name: s.name.clone(),
            position: s.position,
            weights: s.weights,
        })
        .collect();
    for p in &scenario.points {
        let position = p.position.map(|v| v * unit);
        let weights = locate(fem, position).ok_or_else(|| {
            let (nearest, distance) = fem
                .used_nodes()
                .into_iter()
                .map(|n| (n, distance(fem.positions[n], position)))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            SimulateError::PointOutside {
                path: path.to_owned(),
                name: p.name.clone(),
                position,
                nearest_tag: fem.node_tags.get(nearest).copied().unwrap_or(0),
                distance,
            }
        })?;
        out.push(Probe {
            name: p.name.clone(),
            position,
            weights,
        });
    }
    Ok(out)
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The containing tetrahedron's nodes and barycentric weights (tolerance 1e-9, best element).
fn locate(fem: &FemModel, p: [f64; 3]) -> Option<[(usize, f64); 4]> {
    let mut best: Option<([(usize, f64); 4], f64)> = None;
    for e in &fem.elements {
        let bary = e.geometry.barycentric(fem.positions[e.nodes[0]], p);
        let worst = bary.iter().copied().fold(f64::INFINITY, f64::min);
        if worst >= -1e-9 && best.as_ref().is_none_or(|b| worst > b.1) {
            best = Some((std::array::from_fn(|a| (e.nodes[a], bary[a])), worst));
        }
    }
    best.map(|b| b.0)
}

/// A recorded state handed to the observer of [`simulate`].
pub struct Frame<'a> {
    /// Step index k (0 = initial state).
    pub step: usize,
    /// t = kΔt, s.
    pub time: f64,
    /// Displacement over the free DOFs (n, m).
    pub displacement: &'a [f64],
}

/// Recorded world displacements at the probes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectories {
    /// Probe labels.
    pub labels: Vec<String>,
    /// Recorded step indices.
    pub steps: Vec<usize>,
    /// Their times, s.
    pub times: Vec<f64>,
    /// Per recorded step, per probe: (ux, uy, uz), m.
    pub values: Vec<Vec<[f64; 3]>>,
    /// Steps simulated.
    pub total_steps: usize,
    /// Mean wall time per step, s (excluding setup and recording).
    pub seconds_per_step: f64,
    /// Newton counters (co-rotational model).
    pub newton: Option<NewtonStats>,
}

impl Trajectories {
    /// CSV text: `step,t` then `<label>.ux,<label>.uy,<label>.uz` per recorded point (world
    /// displacement, m), one row per recorded step.
    pub fn csv(&self) -> String {
        use std::fmt::Write as _;
        let t = self;
        let mut out = String::from("step,t");
        for label in &t.labels {
            let _ = write!(out, ",{label}.ux,{label}.uy,{label}.uz");
        }
        out.push('\n');
        for ((step, time), values) in t.steps.iter().zip(&t.times).zip(&t.values) {
            let _ = write!(out, "{step},{time:.9e}");
            for v in values {
                let _ = write!(out, ",{:.9e},{:.9e},{:.9e}", v[0], v[1], v[2]);
            }
            out.push('\n');
        }
        out
    }
}

/// Runs `scenario` on the full-order model: step k → k+1 holds the load f(t_k), t_k = kΔt
/// (Δt, θ from the scene). Records the probes at step 0, every `options.every` steps and at the
/// last step, and calls `observer` with each recorded frame. `path` names the scenario file in
/// messages.
#[allow(clippy::too_many_arguments)]
pub fn simulate(
    fem: &FemModel,
    ops: &Operators,
    scene: &Scene,
    scenario: &Scenario,
    probes: &[Probe],
    options: &SimulationOptions,
    path: &Path,
    observer: &mut dyn FnMut(&Frame) -> Result<(), SimulateError>,
) -> Result<Trajectories, SimulateError> {
    if options.every == 0 {
        return Err(SimulateError::Options("--every must be ≥ 1".into()));
    }
    let n = fem.dof_count();
    let wilson = WilsonTheta::from(&scene.time);
    let dt = wilson.dt;
    let mut corotational = None;
    let mut linear = None;
    let sim: &mut dyn Simulator = match options.formulation {
        Formulation::Linear => linear.insert(LinearSimulator::new(fem, wilson)?),
        Formulation::Corotational => {
            corotational.insert(CorotationalSimulator::new(fem, wilson, options.newton)?)
        }
    };
    let mut out = Trajectories {
        labels: probes.iter().map(|p| p.name.clone()).collect(),
        ..Default::default()
    };
    let mut record = |step: usize, u: &[f64], out: &mut Trajectories| {
        let time = step as f64 * dt;
        out.steps.push(step);
        out.times.push(time);
        out.values
            .push(probes.iter().map(|p| p.displacement(fem, u)).collect());
        observer(&Frame {
            step,
            time,
            displacement: u,
        })
    };
    record(0, sim.displacement(), &mut out)?;
    let horizon = scenario.horizon(dt);
    let (max_steps, steady) = match horizon {
        Horizon::Steps(k) => (k, None),
        Horizon::Steady(s) => (s.max_steps, Some(s)),
    };
    let settle_after = scenario.last_load_time();
    let mut previous = vec![0.0; n];
    let mut elapsed = 0.0;
    let mut change = f64::INFINITY;
    let mut step = 0;
    let mut settled = false;
    while step < max_steps {
        let f = scenario.load_vector(ops, n, step as f64 * dt);
        previous.copy_from_slice(sim.displacement());
        let start = Instant::now();
        sim.step(&f)?;
        elapsed += start.elapsed().as_secs_f64();
        step += 1;
        let u = sim.displacement();
        if u.iter().any(|v| !v.is_finite()) {
            return Err(SteppingError::NonFinite {
                step,
                time: step as f64 * dt,
            }
            .into());
        }
        if let Some(s) = steady {
            let du = u
                .iter()
                .zip(&previous)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            let size = norm(u);
            let measure = du
                .max(dt * norm(sim.velocity()))
                .max(dt * dt * norm(sim.acceleration()));
            change = if measure == 0.0 { 0.0 } else { measure / size };
            if step as f64 * dt >= settle_after && change <= s.tolerance {
                settled = true;
            }
        }
        let last = settled || step == max_steps;
        if step % options.every == 0 || last {
            record(step, u, &mut out)?;
        }
        if settled {
            break;
        }
    }
    if let Some(s) = steady {
        if !settled {
            return Err(SimulateError::SteadyNotReached {
                path: path.to_owned(),
                steps: step,
                change,
                tolerance: s.tolerance,
            });
        }
    }
    out.total_steps = step;
    out.seconds_per_step = elapsed / step.max(1) as f64;
    out.newton = corotational.as_ref().map(|c| c.stats());
    Ok(out)
}

/// Output of [`run`].
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// The trajectories written to `trajectories.csv`.
    pub trajectories: Trajectories,
    /// Free DOFs n.
    pub dofs: usize,
    /// Tetrahedra.
    pub elements: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
    /// What the compiler's front end said about the scene (scene warnings, mesh notes, what
    /// each selection took).
    pub notes: Vec<String>,
}

/// `crokf-verify simulate`: reads the scene, its mesh and the scenario, runs [`simulate`] and
/// writes `out/trajectories.csv`, and with `vtu` also `out/frames/frame_NNNN.vtu` and
/// `out/series.pvd`.
pub fn run(
    scene_path: &Path,
    scenario_path: &Path,
    options: &SimulationOptions,
    out: &Path,
    vtu: bool,
) -> Result<RunSummary, SimulateError> {
    let full = FullOrder::build(scene_path, &mut StageTimer::default())?;
    let (scene, fem, ops) = (&full.scene.scene, &full.fem, &full.operators);
    let unit = scene.mesh.units.to_metres();
    let scenario = Scenario::read(scenario_path)?;
    scenario.check_scene(scene, scenario_path)?;
    let probes = probes(fem, ops, &scenario, unit, scenario_path)?;

    let read = full.scene.input_files();
    let mut inputs: Vec<(&str, &Path)> = vec![("scene", scene_path), ("scenario", scenario_path)];
    inputs.extend(read.iter().map(|(role, p)| (*role, p.as_path())));
    check_paths(
        &inputs,
        &[Output {
            role: "--out",
            path: out,
            kind: OutputKind::Folder,
        }],
    )?;
    // Frames are staged beside `out/frames` and moved in only when the whole run succeeded;
    // a failed run leaves the old files or nothing.
    let frames_dir = out.join("frames");
    let mut staged_frames = None;
    if vtu {
        std::fs::create_dir_all(out).map_err(|source| SimulateError::Io {
            path: out.to_owned(),
            source,
        })?;
        staged_frames = Some(StagedDir::create(&frames_dir)?);
    }
    let tetrahedra: Vec<[usize; 4]> = fem.elements.iter().map(|e| e.nodes).collect();
    let mut files = Vec::new();
    let mut frames: Vec<(f64, String)> = Vec::new();
    let mut observer = |frame: &Frame| -> Result<(), SimulateError> {
        let Some(staged) = staged_frames.as_mut() else {
            return Ok(());
        };
        let name = format!("frame_{:04}.vtu", frames.len());
        let text = vtu::vtu(&fem.positions, &tetrahedra, &fem.nodal(frame.displacement));
        staged.write(&name, text.as_bytes())?;
        frames.push((frame.time, format!("frames/{name}")));
        Ok(())
    };
    let trajectories = simulate(
        fem,
        ops,
        scene,
        &scenario,
        &probes,
        options,
        scenario_path,
        &mut observer,
    )?;
    std::fs::create_dir_all(out).map_err(|source| SimulateError::Io {
        path: out.to_owned(),
        source,
    })?;
    let csv = out.join("trajectories.csv");
    write_atomically(&csv, trajectories.csv().as_bytes())?;
    files.push(csv);
    if let Some(staged) = staged_frames {
        staged.commit()?;
        let pvd = out.join("series.pvd");
        write_atomically(&pvd, vtu::pvd(&frames).as_bytes())?;
        files.push(pvd);
        files.extend(frames.iter().map(|(_, f)| out.join(f)));
    }
    Ok(RunSummary {
        trajectories,
        dofs: fem.dof_count(),
        elements: fem.elements.len(),
        files,
        notes: fem.notes.iter().chain(&ops.notes).cloned().collect(),
    })
}

/// Euclidean norm.
fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}
