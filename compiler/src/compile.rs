//! The whole offline pipeline: scene → mesh → FEM → modal + balanced reduction → Kalman →
//! model file. Each stage lives in its own module; this one only wires them and records costs.

use std::path::{Path, PathBuf};

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;

use crokf_formats as fmt;

use crate::accuracy;
use crate::corotation::RotationRows;
use crate::dynamics::WilsonTheta;
use crate::fem::operators::{displacement_rows, InputKind, Operators, SparseRow};
use crate::fem::{FemError, FemModel};
use crate::kalman::{self, KalmanError};
use crate::mesh::{read_mesh_bytes, Mesh, MeshError};
use crate::reduce::{self, ReduceError};
use crate::reference::ReferenceError;
use crate::report::StageTimer;
use crate::scene::{ForceModel, SceneError, SceneFile};

/// The compiler's version string, part of every model's input digest.
pub const COMPILER_VERSION: &str = concat!("crokf-compile ", env!("CARGO_PKG_VERSION"));

/// Any error of the pipeline, by stage.
#[derive(Debug, thiserror::Error)]
pub enum CompileError {
    /// Scene file.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Mesh file.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// FEM assembly and operators.
    #[error("{path}: {source}")]
    Fem {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: FemError,
    },
    /// Reduction.
    #[error("{path}: {source}")]
    Reduce {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: ReduceError,
    },
    /// Kalman gains.
    #[error("{path}: {source}")]
    Kalman {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: KalmanError,
    },
    /// Full-order reference simulation (measured error).
    #[error("{path}: reference simulation: {source}")]
    Reference {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: ReferenceError,
    },
    /// Reading or writing files.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
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

/// Longest step/chirp history of the measured error, steps.
pub const MEASURE_MAX_STEPS: usize = 400;

/// Default tolerance σ_{r+1}/σ₁ when neither order nor tolerance is given.
pub const DEFAULT_TOLERANCE: f64 = 1e-4;

/// Cap on the number of vibration modes when the scene gives no count. On the 50k-tetrahedron
/// beam, 60 modes instead of 200 cut the modal stage from 61 s to 5 s and left the measured
/// error unchanged (3.1e-4 step, 5.5e-4 chirp): the balanced truncation, not the modal cut,
/// sets the error there.
pub const DEFAULT_MAX_MODES: usize = 60;

/// Everything the front end of the pipeline produces: the full-order model with its operators.
pub struct FullOrder {
    /// The scene.
    pub scene: SceneFile,
    /// The mesh.
    pub mesh: Mesh,
    /// Raw mesh bytes (for the digest).
    pub mesh_bytes: Vec<u8>,
    /// Assembled K, M, DOF map.
    pub fem: FemModel,
    /// Loads, sensors, node sets.
    pub operators: Operators,
}

impl FullOrder {
    /// Reads the scene and mesh, assembles K and M and builds the operators.
    pub fn build(scene_path: &Path, timer: &mut StageTimer) -> Result<Self, CompileError> {
        let scene = SceneFile::read(scene_path)?;
        let mesh_path = scene.mesh_path();
        let (mesh, mesh_bytes) = timer.stage("mesh", || -> Result<_, CompileError> {
            let bytes = std::fs::read(&mesh_path).map_err(|source| CompileError::Io {
                path: mesh_path.clone(),
                source,
            })?;
            Ok((read_mesh_bytes(&bytes, &mesh_path)?, bytes))
        })?;
        let unit = scene.scene.mesh.units.to_metres();
        let fem_err = |source| CompileError::Fem {
            path: scene_path.to_owned(),
            source,
        };
        let fem = timer
            .stage("assembly", || FemModel::assemble(&mesh, &scene.scene, unit))
            .map_err(fem_err)?;
        let operators = timer
            .stage("operators", || {
                Operators::build(&mesh, &scene.scene, &fem, unit)
            })
            .map_err(fem_err)?;
        Ok(FullOrder {
            scene,
            mesh,
            mesh_bytes,
            fem,
            operators,
        })
    }

    /// Wilson-θ parameters of the scene.
    pub fn wilson(&self) -> WilsonTheta {
        WilsonTheta {
            dt: self.scene.scene.time.dt,
            theta: self.scene.scene.time.theta,
        }
    }

    /// Digest of the inputs: mesh bytes, scene bytes, compiler version.
    pub fn digest(&self) -> fmt::InputsDigest {
        fmt::InputsDigest {
            mesh_sha256: fmt::sha256_hex(&self.mesh_bytes),
            scene_sha256: fmt::sha256_hex(self.scene.text.as_bytes()),
            compiler_version: COMPILER_VERSION.to_owned(),
        }
    }
}

/// Output rows of the full-order model, grouped as the model file stores them.
pub struct OutputRows {
    /// Per sensor: displacement rows (3) and rotation rows (3).
    pub sensors: Vec<([SparseRow; 3], [SparseRow; 3])>,
    /// Per load group: rotation rows (3).
    pub loads: Vec<[SparseRow; 3]>,
    /// Per node set: per node displacement rows (3) and rotation rows (3).
    pub node_sets: Vec<Vec<([SparseRow; 3], [SparseRow; 3])>>,
    /// Characteristic length (bounding-box diagonal), m: rotation rows are weighted by it in the
    /// balanced truncation so that radians and metres compare.
    pub length_scale: f64,
}

impl OutputRows {
    /// Builds every output row the scene asks for.
    pub fn build(fem: &FemModel, ops: &Operators) -> Self {
        let rot = RotationRows::new(fem);
        let sensors = ops
            .sensors
            .iter()
            .map(|s| {
                (
                    Operators::sensor_rows(fem, s),
                    rot.at_weights(fem, &s.weights),
                )
            })
            .collect();
        let loads = ops
            .loads
            .iter()
            .map(|l| rot.at_weights(fem, &l.weights))
            .collect();
        let node_sets = ops
            .node_sets
            .iter()
            .map(|set| {
                set.nodes
                    .iter()
                    .map(|&n| (displacement_rows(fem, n), rot.at_node(fem, n)))
                    .collect()
            })
            .collect();
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for e in &fem.elements {
            for &n in &e.nodes {
                for c in 0..3 {
                    lo[c] = lo[c].min(fem.positions[n][c]);
                    hi[c] = hi[c].max(fem.positions[n][c]);
                }
            }
        }
        let length_scale = (0..3).map(|c| (hi[c] - lo[c]).powi(2)).sum::<f64>().sqrt();
        OutputRows {
            sensors,
            loads,
            node_sets,
            length_scale,
        }
    }

    /// Row of sensor `s`'s displacement x component in [`OutputRows::weighted`] order; y, z
    /// follow, then its ω rows (x, y, z).
    pub fn sensor_row(&self, s: usize) -> usize {
        6 * s
    }

    /// Row of load group `g`'s ω x component; y, z follow.
    pub fn load_row(&self, g: usize) -> usize {
        6 * self.sensors.len() + 3 * g
    }

    /// Row of node `i` of node set `set`: displacement x, y, z, then ω x, y, z.
    pub fn node_row(&self, set: usize, i: usize) -> usize {
        let before: usize = self.node_sets[..set].iter().map(Vec::len).sum();
        self.load_row(self.loads.len()) + 6 * (before + i)
    }

    /// All rows with their balancing weights, in the order sensors (u, ω), loads (ω), node sets
    /// (u, ω per node). Node-set rows are scaled by 1/√nodes so that a set of many nodes weighs
    /// like one aggregated point; rotation rows by the length scale.
    pub fn weighted(&self) -> Vec<(&SparseRow, f64)> {
        let l = self.length_scale;
        let mut out = Vec::new();
        for (u, w) in &self.sensors {
            out.extend(u.iter().map(|r| (r, 1.0)));
            out.extend(w.iter().map(|r| (r, l)));
        }
        for w in &self.loads {
            out.extend(w.iter().map(|r| (r, l)));
        }
        for set in &self.node_sets {
            let s = 1.0 / (set.len() as f64).sqrt();
            for (u, w) in set {
                out.extend(u.iter().map(|r| (r, s)));
                out.extend(w.iter().map(|r| (r, s * l)));
            }
        }
        out
    }
}

/// Stacks sparse rows (with weights) into a p×n sparse matrix.
pub fn stack_rows(rows: &[(&SparseRow, f64)], n: usize) -> SparseColMat<usize, f64> {
    let triplets: Vec<Triplet<usize, usize, f64>> = rows
        .iter()
        .enumerate()
        .flat_map(|(i, (row, w))| row.iter().map(move |&(j, v)| Triplet::new(i, j, w * v)))
        .collect();
    SparseColMat::try_new_from_triplets(rows.len(), n, &triplets)
        .expect("row indices are in range by construction")
}

/// Dense n×k matrix whose columns are the given vectors.
pub fn columns(cols: &[&[f64]], n: usize) -> Mat<f64> {
    Mat::from_fn(n, cols.len(), |i, j| cols[j][i])
}

/// Converts a faer matrix to the model file's row-major matrix.
pub fn to_matrix(m: faer::MatRef<f64>) -> fmt::Matrix {
    fmt::Matrix::from_fn(m.nrows() as u32, m.ncols() as u32, |i, j| m[(i, j)])
}

/// The reduced linear system in the output layout of [`OutputRows::weighted`], unweighted.
pub struct ReducedParts {
    /// F (r×r).
    pub transition: Mat<f64>,
    /// G (r × deterministic inputs).
    pub input: Mat<f64>,
    /// G_w (r × noise channels), unit-variance channels.
    pub noise_input: Mat<f64>,
    /// All output rows (p×r) in the order of [`OutputRows::weighted`], weights removed.
    pub outputs: Mat<f64>,
}

impl ReducedParts {
    /// Augments the state with the (local-frame) force of each random-walk load group
    /// (3 states each): x_aug = [x; f], F_aug = [[F, G_g], [0, I]], G_aug = [G; 0], the group's
    /// white-noise channels replaced by N(0, σ²I) increments of f, outputs padded with zeros.
    /// `loads` lists (load group index, σ in N per step).
    pub fn with_force_states(self, ops: &Operators, loads: &[(usize, f64)]) -> Self {
        let r = self.transition.nrows();
        let extra = 3 * loads.len();
        let r2 = r + extra;
        let mut transition = Mat::<f64>::zeros(r2, r2);
        transition
            .submatrix_mut(0, 0, r, r)
            .copy_from(&self.transition);
        let mut input = Mat::<f64>::zeros(r2, self.input.ncols());
        input
            .submatrix_mut(0, 0, r, self.input.ncols())
            .copy_from(&self.input);
        for (k, &(load, _)) in loads.iter().enumerate() {
            for c in 0..3 {
                let channel = ops
                    .inputs
                    .iter()
                    .position(|ch| ch.kind == InputKind::Load { load, component: c })
                    .expect("every load group has three input channels");
                let state = r + 3 * k + c;
                for i in 0..r {
                    transition[(i, state)] = self.input[(i, channel)];
                }
                transition[(state, state)] = 1.0;
            }
        }
        // White-noise channels of random-walk loads are replaced by the force increments.
        let replaced: Vec<String> = loads
            .iter()
            .map(|&(load, _)| format!("noise:{}.", ops.loads[load].name))
            .collect();
        let kept: Vec<usize> = (0..ops.noise.len())
            .filter(|&j| {
                !replaced
                    .iter()
                    .any(|p| ops.noise[j].label.starts_with(p.as_str()))
            })
            .collect();
        let mut noise_input = Mat::<f64>::zeros(r2, kept.len() + extra);
        for (col, &j) in kept.iter().enumerate() {
            for i in 0..r {
                noise_input[(i, col)] = self.noise_input[(i, j)];
            }
        }
        for (k, &(_, sigma)) in loads.iter().enumerate() {
            for c in 0..3 {
                noise_input[(r + 3 * k + c, kept.len() + 3 * k + c)] = sigma;
            }
        }
        let mut outputs = Mat::<f64>::zeros(self.outputs.nrows(), r2);
        outputs
            .submatrix_mut(0, 0, self.outputs.nrows(), r)
            .copy_from(&self.outputs);
        ReducedParts {
            transition,
            input,
            noise_input,
            outputs,
        }
    }

    /// Fixes the sign of each balanced state (a similarity x ↦ S x, S = diag(±1)) so that the
    /// largest-magnitude entry of each output column is positive. Singular vectors are defined
    /// up to sign only, and a rounding difference between machines must not flip the model file.
    pub fn normalise_signs(&mut self) {
        let r = self.transition.nrows();
        for j in 0..r {
            let column = self.outputs.col(j);
            let pivot = (0..column.nrows())
                .max_by(|&a, &b| column[a].abs().total_cmp(&column[b].abs()))
                .map_or(1.0, |i| column[i]);
            if pivot >= 0.0 {
                continue;
            }
            for i in 0..r {
                self.transition[(j, i)] = -self.transition[(j, i)];
                self.transition[(i, j)] = -self.transition[(i, j)];
            }
            self.input.row_mut(j).iter_mut().for_each(|v| *v = -*v);
            self.noise_input
                .row_mut(j)
                .iter_mut()
                .for_each(|v| *v = -*v);
            self.outputs.col_mut(j).iter_mut().for_each(|v| *v = -*v);
        }
    }
}

/// Builds the model file's contents from the reduced system and the Kalman schedule.
pub fn assemble_model(
    full: &FullOrder,
    rows: &OutputRows,
    parts: &ReducedParts,
    schedule: &kalman::PeriodicSchedule,
    measurements: &[fmt::MeasurementChannel],
    measurement_variance: Vec<f64>,
    report: fmt::CompileReport,
) -> fmt::Model {
    let r = parts.transition.nrows();
    let ops = &full.operators;
    let fem = &full.fem;
    let out = parts.outputs.as_ref();
    let block = |start: usize, len: usize| to_matrix(out.subrows(start, len));
    let mut sensors = Vec::new();
    for (si, s) in ops.sensors.iter().enumerate() {
        let at = rows.sensor_row(si);
        sensors.push(fmt::SensorInfo {
            name: s.name.clone(),
            position: s.position,
            displacement_rows: block(at, 3),
            rotation_rows: block(at + 3, 3),
            components: s.components.iter().map(|c| c.index() as u8).collect(),
            // The largest σ of the measured components; per-channel values are in
            // `kalman.measurement_variance`.
            noise_std: s
                .components
                .iter()
                .map(|c| s.noise_std[c.index()])
                .fold(0.0, f64::max),
            every: s.every,
        });
    }
    let loads = ops
        .loads
        .iter()
        .enumerate()
        .map(|(g, l)| fmt::LoadGroup {
            name: l.name.clone(),
            rotation_rows: block(rows.load_row(g), 3),
        })
        .collect();
    let mut node_sets = Vec::new();
    for (k, set) in ops.node_sets.iter().enumerate() {
        let n = set.nodes.len();
        let mut disp = Mat::<f64>::zeros(3 * n, r);
        let mut rot = Mat::<f64>::zeros(3 * n, r);
        for i in 0..n {
            let at = rows.node_row(k, i);
            for c in 0..3 {
                for j in 0..r {
                    disp[(3 * i + c, j)] = out[(at + c, j)];
                    rot[(3 * i + c, j)] = out[(at + 3 + c, j)];
                }
            }
        }
        node_sets.push(fmt::NodeSet {
            name: set.name.clone(),
            node_tags: set.nodes.iter().map(|&i| fem.node_tags[i]).collect(),
            rest_positions: fmt::Matrix::from_fn(n as u32, 3, |i, c| {
                fem.positions[set.nodes[i]][c]
            }),
            triangles: set.triangles.clone(),
            displacement_rows: to_matrix(disp.as_ref()),
            rotation_rows: to_matrix(rot.as_ref()),
        });
    }
    let inputs = ops
        .inputs
        .iter()
        .map(|c| fmt::InputChannel {
            label: c.label.clone(),
            kind: match c.kind {
                InputKind::Load { load, component } => fmt::InputKind::Load {
                    load: load as u32,
                    component: component as u8,
                },
                _ => fmt::InputKind::Gravity {
                    acceleration: full.scene.scene.gravity.unwrap_or([0.0; 3]),
                },
            },
        })
        .collect();
    let q = &parts.noise_input * parts.noise_input.transpose();
    let phases = schedule
        .phases
        .iter()
        .map(|p| fmt::KalmanPhase {
            measured: p.measured.iter().map(|&i| i as u32).collect(),
            gain: to_matrix(p.gain.as_ref()),
            prior_covariance: to_matrix(p.prior_covariance.as_ref()),
            posterior_covariance: to_matrix(p.posterior_covariance.as_ref()),
        })
        .collect();
    fmt::Model {
        dt: full.scene.scene.time.dt,
        theta: full.scene.scene.time.theta,
        state_dim: r as u32,
        transition: to_matrix(parts.transition.as_ref()),
        input: to_matrix(parts.input.as_ref()),
        inputs,
        loads,
        sensors,
        measurements: measurements.to_vec(),
        kalman: fmt::KalmanGains {
            period: schedule.period as u32,
            phases,
            process_noise: to_matrix(q.as_ref()),
            measurement_variance,
        },
        node_sets,
        report,
        inputs_digest: full.digest(),
    }
}

/// The measurement channels (sensor, component) in scene order, with variances and rates.
pub fn measurement_channels(ops: &Operators) -> (Vec<fmt::MeasurementChannel>, Vec<f64>, Vec<u32>) {
    let mut channels = Vec::new();
    let mut variance = Vec::new();
    let mut every = Vec::new();
    for (si, s) in ops.sensors.iter().enumerate() {
        let mut comps: Vec<usize> = s.components.iter().map(|c| c.index()).collect();
        comps.sort_unstable();
        comps.dedup();
        for c in comps {
            channels.push(fmt::MeasurementChannel {
                sensor: si as u32,
                component: c as u8,
            });
            variance.push(s.noise_std[c] * s.noise_std[c]);
            every.push(s.every);
        }
    }
    (channels, variance, every)
}

/// A compiled model: the model file's contents, its bytes and the run's costs.
pub struct Compiled {
    /// The model.
    pub model: fmt::Model,
    /// Encoded model file.
    pub bytes: Vec<u8>,
    /// Stage costs.
    pub timer: StageTimer,
    /// Sizes for the summary: (nodes, tetrahedra, free DOFs, inputs, noise channels, outputs).
    pub sizes: Sizes,
}

/// Problem sizes, for the report.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Sizes {
    /// Mesh nodes.
    pub nodes: usize,
    /// Tetrahedra.
    pub tetrahedra: usize,
    /// Free DOFs n.
    pub dofs: usize,
    /// Deterministic input channels.
    pub inputs: usize,
    /// Process-noise channels.
    pub noise_channels: usize,
    /// Output rows seen by the balanced truncation.
    pub outputs: usize,
    /// Measurement channels.
    pub measurements: usize,
}

/// Runs the whole pipeline on a scene file.
pub fn compile(scene_path: &Path, options: &CompileOptions) -> Result<Compiled, CompileError> {
    let mut timer = StageTimer::default();
    let full = FullOrder::build(scene_path, &mut timer)?;
    let reduce_err = |source| CompileError::Reduce {
        path: scene_path.to_owned(),
        source,
    };
    let kalman_err = |source| CompileError::Kalman {
        path: scene_path.to_owned(),
        source,
    };
    let fem = &full.fem;
    let ops = &full.operators;
    let n = fem.dof_count();
    let spec = full.scene.scene.reduction;

    let rows = timer.stage("outputs", || OutputRows::build(fem, ops));
    let weighted = rows.weighted();
    let outputs = stack_rows(&weighted, n);
    let input_columns: Vec<&[f64]> = ops
        .inputs
        .iter()
        .chain(&ops.noise)
        .map(|c| c.column.as_slice())
        .collect();
    let b = columns(&input_columns, n);
    let wilson = full.wilson();

    let modes = options.modes.or(spec.modes);
    let modal_options = reduce::ModalOptions {
        modes,
        // Without an explicit count: every mode up to half the Nyquist frequency (Wilson-θ
        // damps the rest numerically), capped; static correction covers the quasi-static rest.
        max_frequency_hz: if modes.is_some() {
            None
        } else {
            Some(0.25 / wilson.dt)
        },
        max_modes: modes.unwrap_or(DEFAULT_MAX_MODES).max(1),
        ..reduce::ModalOptions::default()
    };
    let basis = timer
        .stage("modes", || {
            reduce::modal_basis(
                fem.stiffness.as_ref(),
                fem.mass.as_ref(),
                b.as_ref(),
                &modal_options,
            )
        })
        .map_err(reduce_err)?;
    let order = match (
        options.order.or(spec.order),
        options.tolerance.or(spec.tolerance),
    ) {
        (Some(r), _) => reduce::Order::Fixed(r),
        (None, Some(t)) => reduce::Order::Tolerance(t),
        (None, None) => reduce::Order::Tolerance(DEFAULT_TOLERANCE),
    };
    let reduced = timer
        .stage("balanced_truncation", || {
            let system = reduce::ModalSystem::new(
                &basis,
                b.as_ref(),
                outputs.as_ref(),
                fem.alpha,
                fem.beta,
                wilson,
            )?;
            system.balanced_truncation(order)
        })
        .map_err(reduce_err)?;

    let r = reduced.order;
    let m = ops.inputs.len();
    let mut out = reduced.output.clone();
    for (i, (_, w)) in weighted.iter().enumerate() {
        for j in 0..r {
            out[(i, j)] /= w;
        }
    }
    let mut parts = ReducedParts {
        transition: reduced.transition.clone(),
        input: reduced.input.subcols(0, m).to_owned(),
        noise_input: reduced.input.subcols(m, ops.noise.len()).to_owned(),
        outputs: out,
    };
    parts.normalise_signs();
    let random_walk = full
        .scene
        .scene
        .loads
        .iter()
        .enumerate()
        .filter(|(_, l)| l.force_model == ForceModel::RandomWalk && l.force_noise_std > 0.0)
        .map(|(i, l)| (i, l.force_noise_std))
        .collect::<Vec<_>>();
    if !random_walk.is_empty() {
        parts = parts.with_force_states(ops, &random_walk);
    }
    let r = parts.transition.nrows();

    let (measurements, variance, every) = measurement_channels(ops);
    let schedule = timer
        .stage("kalman", || {
            let h = Mat::from_fn(measurements.len(), r, |i, j| {
                let ch = measurements[i];
                parts.outputs[(
                    rows.sensor_row(ch.sensor as usize) + ch.component as usize,
                    j,
                )]
            });
            let q = &parts.noise_input * parts.noise_input.transpose();
            kalman::periodic_gains(
                parts.transition.as_ref(),
                h.as_ref(),
                q.as_ref(),
                &variance,
                &every,
            )
        })
        .map_err(kalman_err)?;

    // Scene warnings, mesh notes and what each selection took (fem, operators) come first.
    let mut notes: Vec<String> = full.fem.notes.clone();
    notes.extend(full.operators.notes.iter().cloned());
    notes.extend(basis.warnings.iter().cloned());
    notes.extend(reduced.warnings.iter().cloned());
    if ops.noise.is_empty() {
        notes.push("no process noise declared (force_noise_std / force_noise): Q = 0, so the steady-state gain is zero and measurements are ignored".to_owned());
    }
    let measured_errors = if options.skip_measured_error {
        notes.push("measured error against the full-order reference skipped (--no-measure)".into());
        Default::default()
    } else {
        let f1 = basis
            .frequencies_hz
            .first()
            .copied()
            .unwrap_or(1.0)
            .max(1e-9);
        let steps = ((2.0 / (f1 * wilson.dt)).ceil() as usize).clamp(100, MEASURE_MAX_STEPS);
        let f_high = (5.0 * f1).min(0.2 / wilson.dt);
        let tests = accuracy::standard_tests(&full, steps, f_high);
        timer
            .stage("measured_error", || {
                accuracy::measured_errors(&full, &rows, &parts, &tests)
            })
            .map_err(|source| CompileError::Reference {
                path: scene_path.to_owned(),
                source,
            })?
    };
    let report = fmt::CompileReport {
        hankel_singular_values: reduced.hankel_singular_values.clone(),
        error_bound: reduced.error_bound,
        order: reduced.order as u32,
        modes: basis.n_eigenmodes as u32,
        highest_kept_frequency_hz: basis
            .frequencies_hz
            .iter()
            .zip(&basis.static_correction)
            .filter(|(_, &is_static)| !is_static)
            .map(|(&f, _)| f)
            .fold(0.0, f64::max),
        nyquist_hz: 0.5 / wilson.dt,
        spectral_radius: reduced.spectral_radius,
        riccati_residual: schedule.worst_relative_residual,
        closed_loop_spectral_radius: schedule.closed_loop_spectral_radius,
        measured_errors,
        timings_s: Default::default(),
        notes,
    };
    let model = timer.stage("model_file", || {
        assemble_model(
            &full,
            &rows,
            &parts,
            &schedule,
            &measurements,
            variance.clone(),
            report,
        )
    });
    let bytes = fmt::encode(&model);
    let sizes = Sizes {
        nodes: fem.positions.len(),
        tetrahedra: fem.elements.len(),
        dofs: n,
        inputs: m,
        noise_channels: ops.noise.len(),
        outputs: weighted.len(),
        measurements: measurements.len(),
    };
    Ok(Compiled {
        model,
        bytes,
        timer,
        sizes,
    })
}

impl Compiled {
    /// The JSON report: the model's report, sizes and per-stage costs.
    pub fn report_json(&self) -> String {
        let stages: Vec<serde_json::Value> = self
            .timer
            .order
            .iter()
            .map(|name| {
                let c = &self.timer.stages[name];
                serde_json::json!({
                    "stage": name,
                    "seconds": c.seconds,
                    "peak_memory_mib": json_number(c.peak_memory_mib),
                })
            })
            .collect();
        let r = &self.model.report;
        let value = serde_json::json!({
            "compiler_version": COMPILER_VERSION,
            "inputs_digest": {
                "mesh_sha256": self.model.inputs_digest.mesh_sha256,
                "scene_sha256": self.model.inputs_digest.scene_sha256,
            },
            "sizes": self.sizes,
            "model_file_bytes": self.bytes.len(),
            "reduction": {
                "order": r.order,
                "modes": r.modes,
                "hankel_singular_values": r.hankel_singular_values,
                "error_bound": r.error_bound,
                "relative_error_bound": r.error_bound / r.hankel_singular_values.first().copied().unwrap_or(f64::NAN),
                "highest_kept_frequency_hz": r.highest_kept_frequency_hz,
                "nyquist_hz": r.nyquist_hz,
                "spectral_radius": r.spectral_radius,
            },
            "kalman": {
                "period": self.model.kalman.period,
                "riccati_relative_residual": json_number(r.riccati_residual),
                "closed_loop_spectral_radius": json_number(r.closed_loop_spectral_radius),
            },
            "measured_errors": r.measured_errors,
            "stages": stages,
            "total_seconds": self.timer.total_seconds(),
            "peak_memory_mib": json_number(self.timer.peak_memory_mib()),
            "notes": r.notes,
        });
        serde_json::to_string_pretty(&value).unwrap_or_default() + "\n"
    }

    /// A readable summary for stderr.
    pub fn summary(&self) -> String {
        use std::fmt::Write;
        let r = &self.model.report;
        let s = &self.sizes;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "mesh: {} nodes, {} tetrahedra, {} free DOFs; {} inputs, {} noise channels, {} outputs, {} measurements",
            s.nodes, s.tetrahedra, s.dofs, s.inputs, s.noise_channels, s.outputs, s.measurements
        );
        let _ = writeln!(
            out,
            "modes: {} vibration modes kept (+ static correction), highest {:.3} Hz (Nyquist {:.3} Hz)",
            r.modes, r.highest_kept_frequency_hz, r.nyquist_hz
        );
        let hsv: Vec<String> = r
            .hankel_singular_values
            .iter()
            .take(12)
            .map(|v| format!("{v:.3e}"))
            .collect();
        let _ = writeln!(out, "Hankel singular values: {} …", hsv.join(" "));
        let sigma1 = r
            .hankel_singular_values
            .first()
            .copied()
            .unwrap_or(f64::NAN);
        let _ = writeln!(
            out,
            "balanced truncation: r = {}, bound 2Σσ(i>r) = {:.3e} ({:.2e} of σ₁), ρ(F) = {:.9}",
            r.order,
            r.error_bound,
            r.error_bound / sigma1,
            r.spectral_radius
        );
        let _ = writeln!(
            out,
            "kalman: period {}, Riccati relative residual {:.2e}, ρ((I−KH)F) = {:.9}",
            self.model.kalman.period, r.riccati_residual, r.closed_loop_spectral_radius
        );
        for (name, value) in &r.measured_errors {
            let _ = writeln!(out, "measured error {name}: {value:.3e}");
        }
        for name in &self.timer.order {
            let c = &self.timer.stages[name];
            let _ = writeln!(
                out,
                "  {name:<20} {:>9.3} s  {:>9.1} MiB peak",
                c.seconds, c.peak_memory_mib
            );
        }
        for note in &r.notes {
            let _ = writeln!(out, "note: {note}");
        }
        out
    }
}

fn json_number(v: f64) -> serde_json::Value {
    serde_json::Number::from_f64(v).map_or(serde_json::Value::Null, serde_json::Value::Number)
}

/// Result of `crokf-compile --check`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CheckOutcome {
    /// The model's input digest matches the scene, mesh and compiler version.
    UpToDate,
    /// It does not; the reason names what changed.
    Stale(String),
}

/// Relative tolerance of [`check`]'s numerical comparison of a recompiled model.
pub const CHECK_TOLERANCE: f64 = 1e-6;

/// Checks a committed model file against its scene: the input digest (scene bytes, mesh bytes,
/// compiler version) must match, and recompiling with the model's own order must give the same
/// file — byte for byte, or (another CPU may round differently) every matrix equal to
/// [`CHECK_TOLERANCE`] relative to its largest entry.
pub fn check(model_path: &Path, scene_path: &Path) -> Result<CheckOutcome, CompileError> {
    let bytes = std::fs::read(model_path).map_err(|source| CompileError::Io {
        path: model_path.to_owned(),
        source,
    })?;
    let model = match fmt::decode(&bytes) {
        Ok(m) => m,
        Err(e) => {
            return Ok(CheckOutcome::Stale(format!(
                "the model file does not decode: {e}"
            )))
        }
    };
    let scene = SceneFile::read(scene_path)?;
    let mesh_path = scene.mesh_path();
    let mesh_bytes = std::fs::read(&mesh_path).map_err(|source| CompileError::Io {
        path: mesh_path.clone(),
        source,
    })?;
    let d = &model.inputs_digest;
    let mut why = Vec::new();
    if d.scene_sha256 != fmt::sha256_hex(scene.text.as_bytes()) {
        why.push(format!("{} changed", scene_path.display()));
    }
    if d.mesh_sha256 != fmt::sha256_hex(&mesh_bytes) {
        why.push(format!("{} changed", mesh_path.display()));
    }
    if d.compiler_version != COMPILER_VERSION {
        why.push(format!(
            "compiled by {}, this is {COMPILER_VERSION}",
            d.compiler_version
        ));
    }
    if !why.is_empty() {
        return Ok(CheckOutcome::Stale(why.join("; ")));
    }
    let options = CompileOptions {
        order: Some(model.r()),
        skip_measured_error: model.report.measured_errors.is_empty(),
        ..CompileOptions::default()
    };
    let fresh = compile(scene_path, &options)?;
    if fresh.bytes == bytes {
        return Ok(CheckOutcome::UpToDate);
    }
    Ok(match model_difference(&model, &fresh.model) {
        None => CheckOutcome::UpToDate,
        Some(what) => CheckOutcome::Stale(format!("recompiling gives a different model: {what}")),
    })
}

/// The first difference between two models beyond [`CHECK_TOLERANCE`], if any.
fn model_difference(a: &fmt::Model, b: &fmt::Model) -> Option<String> {
    if a.state_dim != b.state_dim
        || a.inputs != b.inputs
        || a.measurements != b.measurements
        || a.sensors.len() != b.sensors.len()
        || a.node_sets.len() != b.node_sets.len()
        || a.kalman.phases.len() != b.kalman.phases.len()
    {
        return Some("state dimension, channels, sensors, node sets or Kalman phases".into());
    }
    let mut pairs: Vec<(String, &fmt::Matrix, &fmt::Matrix)> = vec![
        ("F".into(), &a.transition, &b.transition),
        ("G".into(), &a.input, &b.input),
        ("Q".into(), &a.kalman.process_noise, &b.kalman.process_noise),
    ];
    for (s, t) in a.sensors.iter().zip(&b.sensors) {
        pairs.push((
            format!("sensor '{}' rows", s.name),
            &s.displacement_rows,
            &t.displacement_rows,
        ));
    }
    for (s, t) in a.node_sets.iter().zip(&b.node_sets) {
        pairs.push((
            format!("node set '{}' rows", s.name),
            &s.displacement_rows,
            &t.displacement_rows,
        ));
    }
    for (i, (p, q)) in a.kalman.phases.iter().zip(&b.kalman.phases).enumerate() {
        pairs.push((format!("Kalman gain of phase {i}"), &p.gain, &q.gain));
    }
    pairs.into_iter().find_map(|(name, x, y)| {
        if x.shape() != y.shape() {
            return Some(format!("{name}: shape {:?} vs {:?}", x.shape(), y.shape()));
        }
        let scale = x
            .data
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
            .max(f64::MIN_POSITIVE);
        let worst = x
            .data
            .iter()
            .zip(&y.data)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        (worst > CHECK_TOLERANCE * scale).then(|| {
            format!(
                "{name} differs by {:.2e} of its largest entry",
                worst / scale
            )
        })
    })
}
