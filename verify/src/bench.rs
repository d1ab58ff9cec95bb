//! Benchmarks (never timed tests): assembly, full-order linear and co-rotational steps, and the
//! runtime's reduced step, measured in the same run so that ratios are meaningful.
//!
//! Structured beams (aspect 10:1:1, [`box_mesh`]) stand in for meshes of a given size; the
//! runtime is timed on synthetic models of the shapes the issues fix (r states, 30 measured
//! components, 6 inputs, 5,000 displayed nodes). Every figure is a median over repetitions.

use std::hint::black_box;
use std::path::Path;

use crokf_formats as fmt;
use crokf_runtime::Estimator;

use crokf_compile::dynamics::WilsonTheta;
use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::FemModel;
use crokf_compile::mesh::Mesh;
use crokf_compile::scene::Scene;
use crokf_compile::stepping::{CorotationalSimulator, LinearSimulator, NewtonOptions, Simulator};

use crokf_compile::mesh::procedural::{box_mesh, BeamScene};

pub use crokf_formats::synthetic::median_seconds;

/// What [`step_clock_seconds`] measures, for the reports' labels.
#[cfg(any(target_os = "linux", target_os = "macos"))]
pub const STEP_CLOCK: &str = "thread CPU time";
/// What [`step_clock_seconds`] measures, for the reports' labels.
#[cfg(not(any(target_os = "linux", target_os = "macos")))]
pub const STEP_CLOCK: &str = "wall time";

/// The clock of the runtime step timers, s: this thread's CPU time
/// (`clock_gettime(CLOCK_THREAD_CPUTIME_ID)`) on Linux and macOS, else wall time. The runtime
/// steps on the calling thread only; on a shared machine its CPU time leaves out the time other
/// jobs hold the core, which wall time counts (the co-rotational tier's step read 1.27 ms of
/// wall time against 55–80 µs of thread CPU time on a loaded machine).
#[cfg(any(target_os = "linux", target_os = "macos"))]
pub fn step_clock_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the call writes only it.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The clock of the runtime step timers, s: wall time since the first call here (no thread
/// CPU clock on this platform; [`STEP_CLOCK`] says so in the reports).
#[cfg(not(any(target_os = "linux", target_os = "macos")))]
pub fn step_clock_seconds() -> f64 {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}

/// Median of `samples` runs of `f` on [`step_clock_seconds`], s.
pub fn median_step_seconds(samples: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..samples.max(1))
        .map(|_| {
            let start = step_clock_seconds();
            f();
            step_clock_seconds() - start
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// A beam mesh of about `tetrahedra` elements (1 m × 0.1 m × 0.1 m, cells k × k in section).
pub fn beam_of_size(tetrahedra: usize) -> Mesh {
    let k = ((tetrahedra as f64 / 60.0).cbrt().floor() as usize).max(1);
    let nx = ((tetrahedra as f64 / (6.0 * (k * k) as f64)).round() as usize).max(1);
    box_mesh([nx, k, k], [1.0, 0.1, 0.1])
}

/// The benchmark beam scene (the shared fixture): 1 MPa, a tip load with 0.01 N force noise,
/// three sensors along the top, the surface displayed, Δt = 1 ms; `mesh_file` is the generated
/// mesh's name.
pub fn beam_scene_text(mesh_file: &str) -> String {
    BeamScene {
        mesh_file: mesh_file.into(),
        sensors: vec![
            ("tip".into(), [0.99, 0.05, 0.1]),
            ("three_quarter".into(), [0.75, 0.05, 0.1]),
            ("mid_span".into(), [0.5, 0.05, 0.1]),
        ],
        ..BeamScene::default()
    }
    .toml()
}

/// [`beam_scene_text`], parsed.
pub fn beam_scene() -> Scene {
    Scene::parse(
        &beam_scene_text("generated"),
        Path::new("<benchmark scene>"),
    )
    .expect("the benchmark scene is valid")
}

/// Full-order figures at one mesh size.
#[derive(Clone, Debug)]
pub struct FullOrderBench {
    /// Tetrahedra.
    pub tetrahedra: usize,
    /// Free DOFs.
    pub dofs: usize,
    /// Assembly of K and M, s (median).
    pub assembly_s: f64,
    /// Linear Wilson-θ step (J factored once), s (median).
    pub linear_step_s: f64,
    /// Co-rotational Wilson-θ step (one linear solve, refactored J), s (median); NaN if skipped.
    pub corotational_step_s: f64,
}

/// Times assembly and (optionally) the full-order steps on a beam of about `tetrahedra` elements.
pub fn full_order(tetrahedra: usize, steps: bool, samples: usize) -> FullOrderBench {
    let mesh = beam_of_size(tetrahedra);
    let scene = beam_scene();
    let mut fem = None;
    let assembly_s = median_seconds(samples, || {
        fem = Some(FemModel::assemble(&mesh, &scene, 1.0).expect("benchmark mesh assembles"));
    });
    let fem = fem.expect("assembled at least once");
    let ops = Operators::build(&mesh, &scene, &fem, 1.0).expect("benchmark operators");
    let wilson = WilsonTheta::from(&scene.time);
    let (mut linear_step_s, mut corotational_step_s) = (f64::NAN, f64::NAN);
    if steps {
        // A tip load of 1 N along z: small enough that one Newton iteration suffices.
        let f: Vec<f64> = ops.inputs[2].column.clone();
        let mut linear = LinearSimulator::new(&fem, wilson).expect("linear simulator");
        linear_step_s = median_seconds(samples.max(5), || {
            linear.step(black_box(&f)).expect("linear step");
        });
        let options = NewtonOptions {
            max_newton: 1,
            ..NewtonOptions::default()
        };
        let mut corotational =
            CorotationalSimulator::new(&fem, wilson, options).expect("co-rotational simulator");
        corotational_step_s = median_seconds(samples.max(3), || {
            corotational
                .step(black_box(&f))
                .expect("co-rotational step");
        });
    }
    FullOrderBench {
        tetrahedra: fem.elements.len(),
        dofs: fem.dof_count(),
        assembly_s,
        linear_step_s,
        corotational_step_s,
    }
}

/// Runtime figures at one order r.
#[derive(Clone, Debug)]
pub struct RuntimeBench {
    /// Reduced order r.
    pub order: usize,
    /// predict + update with all measurements, s (median of batch means).
    pub step_s: f64,
    /// World positions of the displayed node set (with warping), s (median).
    pub readout_s: f64,
    /// Displayed nodes in the read-out.
    pub nodes: usize,
}

/// Times the runtime step and read-out at order r (30 measured components, 6 inputs, 5,000
/// displayed nodes unless told otherwise).
pub fn runtime(r: usize, measured: usize, inputs: usize, nodes: usize) -> RuntimeBench {
    let model = fmt::synthetic::benchmark_model(r, inputs, measured, nodes);
    let mut est = Estimator::new(&model).expect("synthetic model is valid");
    let u = vec![0.5; inputs];
    let mut rng = fmt::synthetic::SplitMix64(7);
    let y: Vec<Option<f64>> = (0..measured).map(|_| Some(1e-3 * rng.uniform())).collect();
    let batch = 1000;
    let step_s = median_seconds(21, || {
        for _ in 0..batch {
            est.step(black_box(&u), black_box(&y)).expect("step");
        }
    }) / batch as f64;
    let mut out = vec![0.0; 3 * nodes];
    let readout_s = median_seconds(51, || {
        est.node_positions(0, black_box(&mut out))
            .expect("read-out");
    });
    RuntimeBench {
        order: r,
        step_s,
        readout_s,
        nodes,
    }
}
