//! Hard cases of the co-rotational tier, on a small generated beam (12×2×2
//! cells, 288 tetrahedra) compiled with `[reduction] model = "corotational"`:
//!
//! - a load reversed mid-run (−z, held, then +z: both directions lie in the training plan's
//!   axis directions), runtime against the full-order co-rotational FEM over the trajectory.
//!   The training runs must span the dynamics: with 0.3 s runs (a sixth of this 1.5 s run) the
//!   same reversal was 22 % off while the envelope status said "inside" (‖q‖ at 0.32 of the
//!   trained maximum); with 1.5 s runs it is 3.0 %;
//! - a twist: opposite y forces on the upper and lower halves of the end face (two load groups,
//!   trained separately), an end torque (ignored: a known miss, see the test);
//! - a load far outside the training envelope: the runtime reports it (status), and either
//!   steps or refuses with a typed error leaving the estimator as it was; never a panic or a
//!   non-finite read-out.
//!
//! Both scenes train along the six axes (`directions = "axes"`), the plan the figures below were
//! measured on.
//!
//! `cargo test -p crokf-tests --test tier_hard_cases -- --nocapture` prints the figures.

use std::path::PathBuf;
use std::sync::OnceLock;

use crokf_compile::fem::operators::Operators;
use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{simulator, Formulation, NewtonOptions, Simulator};
use crokf_compile::{compile, CompileOptions, FullOrder};
use crokf_runtime::Estimator;

/// Training range of the tip load, N.
const RANGE: f64 = 30.0;
const DT: f64 = 0.005;
/// Steps of the reversal run (1.5 s: the beam swings through after the reversal).
const STEPS: usize = 300;

fn scene() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("crokf-tier-hard-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scene folder");
        write_msh22(
            &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
            &dir.join("beam.msh"),
        )
        .expect("mesh");
        let text = BeamScene {
            sensors: vec![("tip".into(), [0.99, 0.05, 0.1])],
            displays: vec![("end".into(), "xmax".into())],
            dt: DT,
            ..BeamScene::default()
        }
        .toml()
            + "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n\
               ranges = { tip = 30.0 }\nduration = 1.5\nevery = 3\norder = 12\n\
               ecsw_tolerance = 5e-3\nnewton_tolerance = 1e-10\nnewton_iterations = 60\n\
               directions = \"axes\"\n";
        let path = dir.join("scene.toml");
        std::fs::write(&path, text).expect("scene");
        path
    })
}

fn model() -> &'static crokf_formats::Model {
    static M: OnceLock<crokf_formats::Model> = OnceLock::new();
    M.get_or_init(|| {
        let options = CompileOptions {
            order: Some(8),
            skip_measured_error: true,
            ..CompileOptions::default()
        };
        compile(scene(), &options).expect("tier compiles").model
    })
}

/// The full-order load column of input channel `label` (N per unit input on the free DOFs).
fn load_column(full: &FullOrder, label: &str) -> Vec<f64> {
    let i = full
        .operators
        .inputs
        .iter()
        .position(|c| c.label == label)
        .expect("load channel");
    full.operators.inputs[i].column.clone()
}

/// The index of input channel `label` in a model file.
fn input_index(model: &crokf_formats::Model, label: &str) -> usize {
    model
        .inputs
        .iter()
        .position(|c| c.label == label)
        .expect("input channel")
}

/// The full-order co-rotational reference simulator and the rows of sensor 0.
fn reference_of(
    full: &FullOrder,
) -> (
    Box<dyn Simulator + '_>,
    [crokf_compile::fem::operators::SparseRow; 3],
) {
    let reference = simulator(
        &full.fem,
        full.wilson,
        Formulation::Corotational,
        NewtonOptions::default(),
    )
    .expect("co-rotational simulator");
    let rows = Operators::sensor_rows(&full.fem, &full.operators.sensors[0]);
    (reference, rows)
}

/// Tip force along z, N: ramp to −P over 0.1 s, hold to 0.2 s, ramp to +P by 0.4 s, hold.
fn reversal(k: usize, peak: f64) -> f64 {
    let t = k as f64 * DT;
    let ramp = |a: f64, b: f64| ((t - a) / (b - a)).clamp(0.0, 1.0);
    -peak * ramp(0.0, 0.1) + 2.0 * peak * ramp(0.2, 0.4)
}

#[test]
fn reversed_load_follows_the_full_order_corotational_fem() {
    let model = model();
    let full = FullOrder::build(scene(), &mut StageTimer::default()).expect("front end");
    let column = load_column(&full, "tip.z");
    let (mut reference, rows) = reference_of(&full);
    let mut est = Estimator::new(model).expect("tier model loads");
    assert!(est.is_corotational());
    let zi = input_index(model, "tip.z");
    let mut u = vec![0.0; model.inputs.len()];
    let peak = 0.8 * RANGE;
    let (mut err2, mut ref2, mut lowest, mut highest) = (0.0, 0.0, 0.0f64, 0.0f64);
    let mut tip = [0.0; 3];
    let mut f = vec![0.0; column.len()];
    for k in 1..=STEPS {
        let force = reversal(k, peak);
        for (fi, b) in f.iter_mut().zip(&column) {
            *fi = force * b;
        }
        reference.step(&f).expect("reference step");
        u[zi] = force;
        est.predict(&u).expect("tier step");
        est.sensor_displacements(&mut tip).expect("read-out");
        let d = reference.displacement();
        for (c, row) in rows.iter().enumerate() {
            let exact: f64 = row.iter().map(|&(j, w)| w * d[j]).sum();
            err2 += (tip[c] - exact).powi(2);
            ref2 += exact.powi(2);
            if c == 2 {
                lowest = lowest.min(exact);
                highest = highest.max(exact);
            }
        }
    }
    let error = (err2 / ref2).sqrt();
    eprintln!(
        "load reversal ±{peak} N: tip z from {lowest:.3} m to {highest:.3} m; runtime tier vs \
         full-order co-rotational FEM, relative L2 of the tip marker over {STEPS} steps: {error:.2e}; \
         envelope {:?}",
        est.tier_status().envelope
    );
    assert!(lowest < -0.1 && highest > 0.1, "the tip must swing through");
    assert!(error < 0.05, "reversal error {error:.3e}");
}

#[test]
fn a_load_far_outside_the_envelope_is_reported_and_never_garbage() {
    let model = model();
    let zi = input_index(model, "tip.z");
    let mut est = Estimator::new(model).expect("tier model loads");
    let mut u = vec![0.0; model.inputs.len()];
    let mut tip = [0.0; 3];
    let (mut stepped, mut refused) = (0, 0);
    for k in 1..=60 {
        u[zi] = -10.0 * RANGE * (k as f64 / 20.0).min(1.0);
        let before = est.state().to_vec();
        match est.predict(&u) {
            Ok(()) => {
                stepped += 1;
                est.sensor_displacements(&mut tip).expect("read-out");
                assert!(tip.iter().all(|v| v.is_finite()));
            }
            Err(e) => {
                refused += 1;
                assert_eq!(
                    est.state(),
                    &before[..],
                    "a refused step changed the state: {e}"
                );
                if refused == 1 {
                    eprintln!("10× the training range: step {k} refused: {e}");
                }
            }
        }
    }
    let status = est.tier_status();
    eprintln!("10× the training range: {stepped} steps taken, {refused} refused; {status:?}");
    assert!(status.envelope.outside(), "{status:?}");
    assert!(status.envelope.load_ratio > 5.0, "{status:?}");
}

/// The training runs give bitwise the same snapshots on one thread and on two (runs are
/// independent and gathered by index), and modified Newton (the training default) stays close
/// to full Newton (the reference's solver) on the twist scene's pair runs: each accepted state
/// is within the Newton tolerance 1e-8 of its root; over the runs the snapshots part by 1.6e-7
/// (asserted below 1e-6).
#[test]
fn training_is_thread_independent_and_modified_newton_matches_full_newton() {
    use crokf_compile::nonlinear::training::{train, TrainingPlan};
    let scene = twist_scene("twist", "");
    let full = FullOrder::build(&scene, &mut StageTimer::default()).expect("front end");
    let mut plan = TrainingPlan::of_scene(&full).expect("tier table");
    plan.duration = 0.1;
    plan.directions = vec![[0.0, 1.0, 0.0]];
    let runs = plan.runs();
    // 2 single-group runs per group (ramp, step) + 2 signs × 2 histories for the pair.
    assert_eq!(runs.len(), 2 * 2 + 4, "{runs:?}");
    assert!(runs
        .iter()
        .any(|r| r.loads == vec![(0, [0.0, 1.0, 0.0]), (1, [0.0, -1.0, 0.0])]));
    plan.modified = Some(crokf_compile::stepping::ModifiedNewton::default());
    plan.threads = 1;
    let one = train(&full, &plan, &mut |_, _, _| {}).expect("training");
    plan.threads = 2;
    let two = train(&full, &plan, &mut |_, _, _| {}).expect("training");
    assert_eq!(
        one.snapshots, two.snapshots,
        "thread count changed the snapshots"
    );
    assert_eq!(one.run_of, two.run_of);
    plan.modified = None;
    let reference = train(&full, &plan, &mut |_, _, _| {}).expect("training");
    let mut worst = 0.0f64;
    for (a, b) in reference.snapshots.iter().zip(&one.snapshots) {
        let d: f64 = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            .sqrt();
        let n: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        worst = worst.max(d / n);
    }
    eprintln!(
        "training: modified vs full Newton, worst relative snapshot difference {worst:.2e}; \
         factorisations {} vs {}, solves {} vs {}",
        one.newton.factorisations,
        reference.newton.factorisations,
        one.newton.solves,
        reference.newton.solves
    );
    assert_eq!(reference.snapshots.len(), one.snapshots.len());
    assert!(
        worst < 1e-6,
        "modified vs full Newton snapshots: {worst:.2e}"
    );
    assert!(one.newton.factorisations * 3 < reference.newton.factorisations);
}

/// Torque group force, N per group (each half of the end face).
const TWIST_RANGE: f64 = 600.0;

/// The twist scene; `extra` is appended to its `[reduction.corotational]` table. Trained along
/// the six axes (`directions = "axes"`: the figures below were measured on that plan), runs of
/// 1 s with a snapshot every third step.
fn twist_scene(name: &str, extra: &str) -> PathBuf {
    twist_scene_trained(name, 1.0, 3, extra)
}

/// The twist scene with training runs of `duration` s and a snapshot every `every` steps.
fn twist_scene_trained(name: &str, duration: f64, every: usize, extra: &str) -> PathBuf {
    twist_scene_with(
        name,
        &format!(
            "ranges = {{ upper = {TWIST_RANGE:e}, lower = {TWIST_RANGE:e} }}\nduration = {duration:?}\n\
             every = {every}\norder = 16\necsw_tolerance = 5e-3\nnewton_tolerance = 1e-10\n\
             newton_iterations = 60\ndirections = \"axes\"\n{extra}"
        ),
    )
}

/// The twist scene with `tier` as its `[reduction.corotational]` table.
fn twist_scene_with(name: &str, tier: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("crokf-tier-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scene folder");
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .expect("mesh");
    let text = format!(
        "[mesh]\nfile = \"beam.msh\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = 1e6\n\
         poisson_ratio = 0.3\ndensity = 1000.0\n[damping]\nalpha = 0.5\nbeta = 1e-3\n\
         [[fixed]]\ngroup = \"xmin\"\n\
         [[load]]\nname = \"upper\"\nselect = [{{ box = {{ min = [0.99, -1, 0.05], max = [1.01, 1, 1] }}, nodes = \"boundary\" }}]\nforce_model = \"white\"\nforce_noise_std = 0.01\n\
         [[load]]\nname = \"lower\"\nselect = [{{ box = {{ min = [0.99, -1, -1], max = [1.01, 1, 0.05] }}, nodes = \"boundary\" }}]\nforce_model = \"white\"\nforce_noise_std = 0.01\n\
         [[sensor]]\nname = \"corner\"\nposition = [1.0, 0.1, 0.1]\nnoise_std = 1e-3\n\
         [[display]]\nname = \"end\"\ngroup = \"xmax\"\n[time]\ndt = {DT:e}\n\
         [reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n{tier}"
    );
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).expect("scene");
    path
}

/// The self-check (docs/design.md §10) notices the twist's known miss at compile time: the
/// default twist tier (pooled POD r = 16, no `basis_tolerance`; the 95 % of
/// [`twist_by_an_end_torque_follows_the_full_order_corotational_fem`]'s doc comment) does not
/// reproduce its own torque-like pair runs (`upper (+0, +1, +0) + lower (+0, -1, +0)`), and
/// the compile warns naming such a run. The failure shows on the training runs themselves, so
/// the in-sample check catches it. The training here is shorter than the other twist tests'
/// (0.5 s runs, a snapshot every sixth step: 816 snapshots instead of 3,216, so that the
/// cubature fit takes seconds instead of minutes); the miss is the same. Measured: worst
/// 108 % (upper −z + lower +z step), median 74 %, all 48 runs above 5 %, the torque pair
/// runs 93–107 %; 4,800 reduced steps in 13 s (debug build). With 1 s runs and every third step:
/// worst 100.2 %, median 89.5 %, all 48 runs above 87 %, the torque pair runs 99.1–99.6 %.
#[test]
fn the_self_check_flags_the_default_twist_tier() {
    let options = CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    };
    // A tier this far off its own training is not written unless the scene accepts it.
    let refused = twist_scene_trained("twist-check-refused", 0.5, 6, "");
    let said = match compile(&refused, &options) {
        Ok(_) => panic!("a tier failing its check on every run was written"),
        Err(e) => e.to_string(),
    };
    assert!(
        said.contains("fails its check")
            && said.contains("not written")
            && said.contains("[[reduction.corotational.case]]")
            && said.contains("accept_failed_check"),
        "{said}"
    );
    let scene = twist_scene_trained("twist-check", 0.5, 6, "accept_failed_check = true\n");
    let compiled = compile(&scene, &options).expect("tier compiles");
    let check = compiled.self_check.as_ref().expect("self-check");
    let worst = check.worst().expect("a checked run");
    let torque = |label: &str| {
        label.contains("(+0, +1, +0) + lower (+0, -1, +0)")
            || label.contains("(+0, -1, +0) + lower (+0, +1, +0)")
    };
    let worst_torque = check
        .runs
        .iter()
        .filter(|r| torque(&r.label))
        .map(|r| r.error)
        .fold(0.0f64, f64::max);
    eprintln!(
        "default twist tier self-check: worst '{}' {:.3e}, median {:.3e}, {} of {} runs above \
         {:.0} %, worst torque pair run {worst_torque:.3e}; {:.2} s for {} reduced steps",
        worst.label,
        worst.error,
        check.median(),
        check.flagged().len(),
        check.runs.len(),
        100.0 * check.threshold,
        check.seconds,
        check.runs.iter().map(|r| r.steps).sum::<usize>()
    );
    for r in check.flagged() {
        eprintln!("  {:<50} {:.3e}", r.label, r.error);
    }
    assert!(worst_torque > check.threshold, "{worst_torque:e}");
    assert!(
        check.flagged().iter().any(|r| torque(&r.label)),
        "the self-check should flag a torque-pair run"
    );
    let warning = compiled
        .model
        .report
        .notes
        .iter()
        .find(|n| n.contains("WARNING"))
        .expect("a warning note");
    assert!(warning.contains(&worst.label), "{warning}");
    let error = compiled
        .model
        .report
        .notes
        .iter()
        .find(|n| n.contains("ERROR: the co-rotational tier fails its check"))
        .expect("an error-level note");
    assert!(error.contains("accept_failed_check = true"), "{error}");
    // The model file says so (format v10), and the runtime reports it on loading.
    let why = compiled
        .model
        .tier_failed_check()
        .expect("the file carries the failed check");
    assert!(
        why.contains("fails its check") && error.contains(why),
        "{why}"
    );
    let bytes = crokf_formats::encode(&compiled.model);
    assert_eq!(bytes[8..12], 10u32.to_le_bytes());
    let loaded = crokf_runtime::model_from_bytes(&bytes).expect("the runtime reads it");
    let prepared = crokf_runtime::PreparedModel::new(loaded).expect("prepared");
    assert_eq!(prepared.tier_failed_check(), Some(why));
    // SAFETY: a live handle from the file's bytes, freed once; the string read while it lives.
    unsafe {
        use crokf_runtime::capi::*;
        let m = crokf_model_from_bytes(bytes.as_ptr(), bytes.len());
        assert!(!m.is_null());
        let said = crokf_model_tier_failed_check(m);
        assert!(!said.is_null());
        assert_eq!(std::ffi::CStr::from_ptr(said).to_str(), Ok(why));
        crokf_model_free(m);
    }
}

/// A couple whose two loads the filter is to estimate (the default random walk, σ derived
/// from the ranges) with one marker at the loaded corner: in the linear static response the
/// corner moves the same for either half's y force, so the markers cannot tell the couple from
/// nothing, and no filter exists. The compile says which force is unseen and what to change,
/// instead of the Riccati solver's eigenvalue.
#[test]
fn a_couple_the_markers_cannot_see_is_named() {
    let scene = twist_scene_with(
        "twist-unseen",
        &format!(
            "ranges = {{ upper = {TWIST_RANGE:e}, lower = {TWIST_RANGE:e} }}\nduration = 0.2\n\
             every = 5\norder = 8\n[[reduction.corotational.case]]\n\
             loads = {{ upper = [0, 1, 0], lower = [0, -1, 0] }}\n"
        ),
    );
    let text = std::fs::read_to_string(&scene).expect("scene");
    std::fs::write(
        &scene,
        text.replace("force_model = \"white\"\nforce_noise_std = 0.01\n", ""),
    )
    .expect("scene");
    let options = CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    };
    let err = match compile(&scene, &options) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a filter that cannot see the couple compiled"),
    };
    eprintln!("{err}");
    assert!(
        err.contains("0.71·upper.y − 0.71·lower.y moves no marker in the static response")
            && err.contains("force_model = \"white\"")
            && err.contains("Add a marker"),
        "{err}"
    );
}

/// The twist through the product (target: the end turned by ≥ 45°, within 2 % of
/// the full-order co-rotational FEM at the corner marker with r ≤ 30 and ≤ 500 sampled
/// elements, the default sizes). The scene declares the couple as its one training load case
/// (`[[reduction.corotational.case]]`: both halves together, opposite ±y: 4 runs) and states no
/// tier size, so the fidelity rule chooses r and the cubature, in-sample (fewer than five
/// runs): r = 30 with ECSW 1e-4, 169 of 288 elements. The end face's section turns by ≈ 50°
/// (the corner by ≈ 31° about the rest axis: the end also moves sideways). What this replaces,
/// measured (docs/results/tier.md §8): trained along the six axes (48 runs, most of them
/// one half face pushed alone by up to 750 N, 37× the beam's buckling load) the pooled POD is
/// 95 % off at r = 16 and an energy-norm basis needs r = 100 (10.8 %); trained on the couple
/// alone the pooled POD is 1.7 % (r = 20) and 0.64 % (r = 30) with every element, and the
/// cubature sets the rest (r = 30: 6.7 % at ECSW 1e-3, 0.55 % at 1e-4).
#[test]
fn twist_by_an_end_torque_follows_the_full_order_corotational_fem() {
    let scene = twist_scene_with(
        "twist-case",
        &format!(
            "ranges = {{ upper = {TWIST_RANGE:e}, lower = {TWIST_RANGE:e} }}\nduration = 1.0\n\
             every = 3\n[[reduction.corotational.case]]\nname = \"twist\"\n\
             loads = {{ upper = [0, 1, 0], lower = [0, -1, 0] }}\n"
        ),
    );
    let options = CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    };
    let model = compile(&scene, &options).expect("tier compiles").model;
    let tier = model.tier.as_ref().expect("a tier");
    let fidelity = model
        .report
        .notes
        .iter()
        .find(|n| n.contains("fidelity rule"))
        .expect("the fidelity rule's note");
    eprintln!("{fidelity}");
    assert!(fidelity.contains("in-sample"), "{fidelity}");
    let full = FullOrder::build(&scene, &mut StageTimer::default()).expect("front end");
    let (up, down) = (load_column(&full, "upper.y"), load_column(&full, "lower.y"));
    let (ui, li) = (
        input_index(&model, "upper.y"),
        input_index(&model, "lower.y"),
    );
    let (mut reference, rows) = reference_of(&full);
    // The end face's corners (1, 0.1, 0.1) and (1, 0, 0): the section's turn about x.
    let node_at = |p: [f64; 3]| {
        full.fem
            .positions
            .iter()
            .position(|q| (0..3).all(|c| (q[c] - p[c]).abs() < 1e-9))
            .expect("a corner node")
    };
    let (a, b) = (node_at([1.0, 0.1, 0.1]), node_at([1.0, 0.0, 0.0]));
    let displaced = |u: &[f64], node: usize, c: usize| {
        full.fem.positions[node][c] + full.fem.dofs.index[node][c].map_or(0.0, |i| u[i])
    };
    let mut est = Estimator::new(&model).expect("tier model loads");
    let mut u = vec![0.0; model.inputs.len()];
    let mut corner = [0.0; 3];
    let mut f = vec![0.0; up.len()];
    let (mut err2, mut ref2, mut turn) = (0.0, 0.0, 0.0f64);
    for k in 1..=200 {
        // Ramp over 0.5 s, then held: +F on the upper half, −F on the lower half.
        let force = 0.8 * TWIST_RANGE * (k as f64 * DT / 0.5).min(1.0);
        for ((fi, a), b) in f.iter_mut().zip(&up).zip(&down) {
            *fi = force * (a - b);
        }
        reference.step(&f).expect("reference step");
        u[ui] = force;
        u[li] = -force;
        est.predict(&u).expect("tier step");
        est.sensor_displacements(&mut corner).expect("read-out");
        let d = reference.displacement();
        let exact: Vec<f64> = rows
            .iter()
            .map(|row| row.iter().map(|&(j, w)| w * d[j]).sum())
            .collect();
        for c in 0..3 {
            err2 += (corner[c] - exact[c]).powi(2);
            ref2 += exact[c].powi(2);
        }
        let (dy, dz) = (
            displaced(d, a, 1) - displaced(d, b, 1),
            displaced(d, a, 2) - displaced(d, b, 2),
        );
        turn = turn.max(
            (dz.atan2(dy) - std::f64::consts::FRAC_PI_4)
                .abs()
                .to_degrees(),
        );
    }
    let error = (err2 / ref2).sqrt();
    eprintln!(
        "twist (±{:.0} N on the end-face halves): the end face turns by up to {turn:.1}°; \
         runtime tier (r = {}, {} sampled elements) vs full-order co-rotational FEM, relative L2 \
         of the corner marker over 200 steps: {error:.2e}; {:?}",
        0.8 * TWIST_RANGE,
        tier.order,
        tier.elements.len(),
        est.tier_status().envelope
    );
    assert!(
        turn >= 45.0,
        "a twist of at least 45° expected, got {turn:.1}°"
    );
    assert!(tier.order <= 30 && tier.elements.len() <= 500);
    assert!(error < 0.02, "twist error {error:.3e}");
}
