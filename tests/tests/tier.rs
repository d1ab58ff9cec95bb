//! The co-rotational tier end to end (docs/design.md §10, §11.4): scene switch → compiler
//! training → model file v4 → runtime step and filter (random-walk force states, innovation
//! gate), on a small generated beam (12×2×2 cells, 288 tetrahedra).
//!
//! `cargo test -p crokf-tests --test tier -- --nocapture` prints the figures.

use std::path::PathBuf;
use std::sync::OnceLock;

use crokf_compile::identify::als_noise::identify_noise;
use crokf_compile::identify::filter_run;
use crokf_compile::mesh::procedural::BeamScene;
use crokf_compile::model_file::tier as section;
use crokf_compile::nonlinear::ecsw::EcswOptions;
use crokf_compile::nonlinear::reduced::{
    HyperReducedModel, ReducedNewton, ReducedStepper, Refresh,
};
use crokf_compile::nonlinear::training::{self, TrainingPlan};
use crokf_compile::nonlinear::{filter, tier};
use crokf_compile::report::StageTimer;
use crokf_compile::{compile, CompileOptions, FullOrder};
use crokf_formats::synthetic::SplitMix64;
use crokf_runtime::tier::{Gate, TierModel, TierState};
use crokf_runtime::{Estimator, RuntimeError, TierError, DEFAULT_GATE_SIGMAS};
use nalgebra::DVector;

#[path = "../../runtime/tests/support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::count;

#[path = "support/beam_tier.rs"]
mod beam_tier;
use beam_tier::{tip_beam, write_tier_scene, TIER};

/// Training range of the tip load, N (37.5 N bends this stiff, coarse beam by about 30°).
const RANGE: f64 = 30.0;

/// The scene directory (mesh + tier scene), written once per test process.
fn scene() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("crokf-tier-{}", std::process::id()));
        write_tier_scene(&dir, "scene.toml", &tip_beam())
    })
}

fn options() -> CompileOptions {
    CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    }
}

/// The compiled tier model (bytes), once per process.
fn compiled() -> &'static (Vec<u8>, crokf_formats::Model) {
    static C: OnceLock<(Vec<u8>, crokf_formats::Model)> = OnceLock::new();
    C.get_or_init(|| {
        let c = compile(scene(), &options()).unwrap();
        (c.bytes, c.model)
    })
}

/// The compiler's reduced stepper on `model` with the runtime's predictor and refresh policy,
/// Newton to 1e-12 (a reference the runtime's step is compared with).
fn tight_stepper(model: &HyperReducedModel) -> ReducedStepper {
    ReducedStepper::new(
        model.clone(),
        ReducedNewton {
            max_iterations: 60,
            tolerance: 1e-12,
            refresh: Refresh::WhenSlow { iterations: 4 },
            consistent: false,
            predictor: true,
        },
    )
    .unwrap()
}

/// Tip load history: a ramp to `peak` N along −z over 0.1 s, then held.
fn tip_load(k: usize, peak: f64) -> f64 {
    let t = k as f64 * 0.005;
    -peak * (t / 0.1).min(1.0)
}

#[test]
fn compile_is_deterministic_and_the_file_has_the_tier() {
    let (bytes, model) = compiled();
    let again = compile(scene(), &options()).unwrap();
    assert!(again.bytes == *bytes, "two compiles differ");
    let back = crokf_formats::decode(bytes).unwrap();
    assert_eq!(&back, model);
    let t = model.tier.as_ref().expect("tier section");
    assert_eq!(t.order, 10);
    assert!(
        !t.elements.is_empty() && t.elements.len() < 288,
        "{}",
        t.elements.len()
    );
    assert_eq!(t.envelope.loads[0].name, "tip");
    assert!((t.envelope.loads[0].max_force - 1.25 * RANGE).abs() < 1e-12);
    assert_eq!(t.envelope.runs_completed, 12);
    // The linearised filter is stable.
    assert!(model
        .report
        .notes
        .iter()
        .any(|n| n.contains("co-rotational tier filter")));
    eprintln!(
        "tier: r = {}, {} sampled elements, {} snapshots, file {} bytes",
        t.order,
        t.elements.len(),
        t.envelope.snapshots,
        bytes.len()
    );
}

/// The training case cache (`crokf-compile --cache`): a compile that fills it and one that
/// reads it give the model of a compile without it, byte for byte; after an interruption
/// (cases missing) and with a damaged case file, only those cases run again, the damaged one
/// is named, and every file is whole afterwards.
#[test]
fn a_case_cache_gives_the_same_model_and_resumes_after_an_interruption() {
    use crokf_compile::nonlinear::cases::{self, train_cached, CaseCache, Lookup};
    let (bytes, _) = compiled();
    let dir = scene().parent().unwrap().join("cases");
    let with_cache = CompileOptions {
        training_cache: Some(dir.clone()),
        ..options()
    };
    let filled = compile(scene(), &with_cache).unwrap();
    assert!(
        filled.bytes == *bytes,
        "a compile filling the cache differs"
    );
    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let (plan, list) = cases::scene_cases(&full).unwrap();
    assert_eq!(list.len(), 12);
    let cache = CaseCache::open(&dir).unwrap();
    // An interrupted compile: five cases never stored; one file cut short.
    for case in &list[..5] {
        std::fs::remove_file(cache.path(case)).unwrap();
    }
    let damaged = cache.path(&list[7]);
    let whole = std::fs::read(&damaged).unwrap();
    std::fs::write(&damaged, &whole[..whole.len() / 2]).unwrap();
    let resumed = train_cached(&full, &plan, &cache, &mut |_, _, _| {}).unwrap();
    assert_eq!(
        resumed.cached, 6,
        "only the missing and the damaged case run"
    );
    assert_eq!(resumed.cache_notes.len(), 1, "{:?}", resumed.cache_notes);
    assert!(
        resumed.cache_notes[0].contains(&list[7].id)
            && resumed.cache_notes[0].contains("run again"),
        "{:?}",
        resumed.cache_notes
    );
    let snapshots = plan.snapshot_count(full.wilson.dt);
    for case in &list {
        assert!(matches!(
            cache.lookup(case, full.fem.dof_count(), snapshots),
            Lookup::Found(Ok(_))
        ));
    }
    // The rerun case has the same snapshots (its file differs only in the Newton times).
    let decode = |b: &[u8]| {
        cases::decode(&list[7], full.fem.dof_count(), snapshots, b)
            .unwrap()
            .unwrap()
            .0
    };
    assert!(decode(&std::fs::read(&damaged).unwrap()) == decode(&whole));
    let read = compile(scene(), &with_cache).unwrap();
    assert!(read.bytes == *bytes, "a compile reading the cache differs");
}

#[test]
fn runtime_step_equals_the_compilers_reduced_stepper() {
    let (_, model) = compiled();
    // The compiler's reduced model from the same training (deterministic).
    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let (_, built) = built_tier(&full);
    let r = built.model.order();
    let mut stepper = tight_stepper(&built.model);
    let v = &built.basis.vectors;
    let z = full
        .operators
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let column = DVector::from_column_slice(&full.operators.inputs[z].column);
    let mut est = Estimator::new(model).unwrap();
    assert!(est.is_corotational());
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let mut u = vec![0.0; model.inputs.len()];
    let mut worst: f64 = 0.0;
    let mut tip = [0.0; 3];
    for k in 0..60 {
        let f = tip_load(k, 1.25 * RANGE);
        u[zi] = f;
        est.predict(&u).unwrap();
        stepper.step(&(v.tr_mul(&column) * f)).unwrap();
        let q = stepper.coordinates();
        let size = q.norm();
        let diff = (0..r)
            .map(|i| (est.state()[i] - q[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        worst = worst.max(diff / size);
        est.sensor_displacements(&mut tip).unwrap();
    }
    eprintln!(
        "runtime vs compiler reduced stepper: worst relative difference of q {worst:.2e} over 60 \
         steps; tip ({:.4}, {:.4}, {:.4}) m",
        tip[0], tip[1], tip[2]
    );
    // Both stop Newton at 1e-12 but by different tests: the compiler's stepper when its last
    // increment is ≤ 1e-12‖q̂‖ (error ≈ ρ·1e-12), the runtime when its estimated error
    // η‖δ‖ is (runtime/src/tier.rs), so each step's q̂ may differ by up to ~2e-12 relative;
    // over 60 steps, carried by the Wilson-θ recursion, that stays well under 1e-9.
    assert!(worst < 1e-9, "{worst:e}");
    assert!(
        tip[2] < -0.2 && tip[0] < -0.02,
        "large rotation expected: {tip:?}"
    );
    // The training runs last 0.15 s, a fraction of this beam's first period (~2 s), so the
    // held load carries the state beyond the trained ‖q‖: reported, not refused.
    let status = est.tier_status();
    let max_q = model.tier.as_ref().unwrap().envelope.max_coordinate_norm;
    let norm = est.state()[..r].iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!((status.envelope.state_ratio - norm / max_q).abs() < 1e-12);
    assert_eq!(status.envelope.state_ratio > 1.5, status.envelope.outside());
    eprintln!("envelope after 60 steps: {status:?}");
}

#[test]
fn non_convergence_and_envelope_are_reported_and_leave_the_estimator_unchanged() {
    let (_, model) = compiled();
    let mut m = model.clone();
    m.tier.as_mut().unwrap().newton_iterations = 1;
    m.tier.as_mut().unwrap().newton_tolerance = 1e-15;
    let mut est = Estimator::new(&m).unwrap();
    let zi = m.inputs.iter().position(|c| c.label == "tip.z").unwrap();
    let mut u = vec![0.0; m.inputs.len()];
    u[zi] = -5.0;
    let before = est.state().to_vec();
    match est.predict(&u) {
        Err(RuntimeError::Tier(TierError::NotConverged { iterations, .. })) => {
            assert_eq!(iterations, 1)
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(est.state(), &before[..]);
    assert_eq!(est.step_index(), 0);
    // step() (predict + update) refuses the same way, all or nothing.
    let y = vec![Some(0.0); m.measurements.len()];
    assert!(est.step(&u, &y).is_err());
    assert_eq!(est.state(), &before[..]);
    // A load beyond the training envelope is reported, the step kept.
    let mut est = Estimator::new(model).unwrap();
    u[zi] = -3.0 * RANGE;
    est.predict(&u).unwrap();
    let status = est.tier_status();
    assert!(status.envelope.outside(), "{status:?}");
    assert!((status.envelope.load_ratio - 3.0 / 1.25).abs() < 1e-12);
}

#[test]
fn tier_steps_and_read_outs_do_not_allocate() {
    let (_, model) = compiled();
    let mut est = Estimator::new(model).unwrap();
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let mut u = vec![0.0; model.inputs.len()];
    let y = vec![Some(-0.01); model.measurements.len()];
    let mut sensors = vec![0.0; 3 * model.sensors.len()];
    let mut sigma = vec![0.0; 3 * model.sensors.len()];
    let mut nodes = vec![0.0; 3 * model.node_sets[0].node_tags.len()];
    let mut estimates = vec![0.0; model.measurements.len()];
    est.step(&u, &y).unwrap(); // first step: J factored
    let n = count(|| {
        for k in 0..40 {
            u[zi] = tip_load(k, RANGE);
            est.step(&u, &y).unwrap();
            est.sensor_displacements(&mut sensors).unwrap();
            est.sensor_std(&mut sigma).unwrap();
            est.node_displacements(0, &mut nodes).unwrap();
            est.measurement_estimates(&mut estimates).unwrap();
        }
    });
    assert_eq!(n, 0, "allocations in 40 tier steps");
    assert!(sigma.iter().all(|s| s.is_finite() && *s > 0.0), "{sigma:?}");
}

#[test]
fn scene_fields_are_range_checked_naming_the_field() {
    let dir = scene().parent().unwrap().to_path_buf();
    let base = std::fs::read_to_string(scene()).unwrap();
    for (from, to, field) in [
        (
            "ranges = { tip = 30.0 }",
            "ranges = { nope = 8.0 }",
            "reduction.corotational.ranges",
        ),
        (
            "ranges = { tip = 30.0 }",
            "ranges = { tip = -1.0 }",
            "reduction.corotational.ranges.tip",
        ),
        (
            "duration = 0.15",
            "duration = 0.0",
            "reduction.corotational.duration",
        ),
        ("every = 2", "every = 0", "reduction.corotational.every"),
        ("order = 10", "order = 0", "reduction.corotational.order"),
        (
            "newton_iterations = 60",
            "newton_iterations = 0",
            "reduction.corotational.newton_iterations",
        ),
        (
            "every = 2",
            "every = 2\nmodel_error_scale = -0.5",
            "reduction.corotational.model_error_scale",
        ),
        (
            "every = 2",
            "every = 2\nmodel_error_scale = nan",
            "reduction.corotational.model_error_scale",
        ),
        (
            "every = 2",
            "every = 2\nmax_rotation = 0",
            "reduction.corotational.max_rotation",
        ),
        (
            "every = 2",
            "every = 2\nmax_rotation = -10",
            "reduction.corotational.max_rotation",
        ),
        (
            "every = 2",
            "every = 2\nmax_rotation = 200",
            "reduction.corotational.max_rotation",
        ),
        (
            "every = 2",
            "every = 2\nmax_rotation = nan",
            "reduction.corotational.max_rotation",
        ),
    ] {
        let path = dir.join("bad.toml");
        std::fs::write(&path, base.replace(from, to)).unwrap();
        let err = match compile(&path, &options()) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{to} accepted"),
        };
        assert!(err.contains(field), "{to}: {err}");
    }
    let path = dir.join("bad.toml");
    std::fs::write(
        &path,
        base.replace("[reduction.corotational]", "[reduction.other]"),
    )
    .unwrap();
    assert!(compile(&path, &options()).is_err());
}

/// `model_error_scale` scales the filter's model-error noise, not what the file stores: the
/// same measured S as the default scene's, the process noise's model-error part × the factor
/// (the rest of Q unchanged), and the compile's note names the factor.
#[test]
fn the_scenes_model_error_scale_reaches_the_filter_not_the_stored_error() {
    let with_factor = |c: &str| {
        compiled_variant(&format!("model_error_scale_{c}.toml"), |base| {
            base.replace("every = 2", &format!("every = 2\nmodel_error_scale = {c}"))
        })
        .model
    };
    let scaled = with_factor("0.25");
    let one = &compiled().1;
    let (a, b) = (one.tier.as_ref().unwrap(), scaled.tier.as_ref().unwrap());
    assert!(!a.model_error.data.is_empty());
    assert_eq!(
        a.model_error, b.model_error,
        "the file keeps the measured S"
    );
    assert!(
        scaled
            .report
            .notes
            .iter()
            .any(|n| n.contains("× the scene's model_error_scale = 0.25")),
        "{:?}",
        scaled.report.notes
    );
    // Q(c) = Q(0) + c (Q(1) − Q(0)): only the model error's part scales, and it is not 0.
    let zero = with_factor("0");
    let q = |m: &crokf_formats::Model| m.tier.as_ref().unwrap().kalman.process_noise.data.clone();
    let (q1, q25, q0) = (q(one), q(&scaled), q(&zero));
    let mut largest = 0.0f64;
    for ((x1, x25), x0) in q1.iter().zip(&q25).zip(&q0) {
        let model = x1 - x0;
        largest = largest.max(model.abs());
        assert!(
            (x25 - (x0 + 0.25 * model)).abs() <= 1e-9 * (x1.abs() + x0.abs()) + 1e-300,
            "Q(0.25) = {x25:e}, Q(0) + 0.25 (Q(1) − Q(0)) = {:e}",
            x0 + 0.25 * model
        );
    }
    assert!(largest > 0.0, "the model error is part of Q");
}

/// An order the training snapshots cannot give is refused when the scene is read, naming the
/// order, the snapshot count and the remedy, not a silent cut (and the default order gives no
/// order warning).
#[test]
fn an_order_the_snapshots_cannot_give_is_refused() {
    let base = std::fs::read_to_string(scene()).unwrap();
    let sparse = base.replace("every = 2\norder = 10", "every = 1000\norder = 40");
    assert_ne!(sparse, base);
    let path = scene().parent().unwrap().join("sparse.toml");
    std::fs::write(&path, sparse).unwrap();
    let said = match compile(&path, &options()) {
        Ok(_) => panic!("an order above the snapshot count was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(
        said.contains("every = 1000") || said.contains("order = 40"),
        "{said}"
    );
    let (_, model) = compiled();
    assert!(
        !model.report.notes.iter().any(|n| n.contains("tier order")),
        "{:?}",
        model.report.notes
    );
}

/// A training run is cut at its first snapshot that rotates an element past `max_rotation`
/// (or inverts one): the snapshots it keeps are the uncut run's first ones, bit for bit, the cut
/// is where an independent reading of each snapshot's rotation first passes the limit, the
/// compile's note counts and names the runs cut, and the self-check replays a cut run only as
/// far as it was kept. This beam bends about 30° at its 37.5 N ramp peak, so 15° cuts some of
/// its runs and leaves others whole.
#[test]
fn training_runs_are_cut_where_they_rotate_past_max_rotation() {
    const LIMIT: f64 = 15.0;
    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let mut plan = TrainingPlan::of_scene(&full).expect("a tier scene");
    plan.max_rotation = 180.0;
    let whole = training::train(&full, &plan, &mut |_, _, _| {}).unwrap();
    assert!(whole.cuts.iter().all(Option::is_none), "{:?}", whole.cuts);
    plan.max_rotation = LIMIT;
    let trimmed = training::train(&full, &plan, &mut |_, _, _| {}).unwrap();
    assert_eq!(trimmed.runs.len(), whole.runs.len());
    assert_eq!(trimmed.cuts.len(), whole.runs.len());
    let of_run = |t: &training::Training, k: usize| -> Vec<Vec<f64>> {
        t.snapshots
            .iter()
            .zip(&t.run_of)
            .filter(|(_, &r)| r == k)
            .map(|(u, _)| u.clone())
            .collect()
    };
    let mut cut = Vec::new();
    for k in 0..whole.runs.len() {
        let all = of_run(&whole, k);
        let kept = of_run(&trimmed, k);
        let past = all.iter().position(|u| {
            let d = training::deformation(&full.fem, u);
            d.inverted > 0 || d.max_rotation > LIMIT
        });
        let label = &whole.runs[k].0;
        match past {
            None => {
                assert!(trimmed.cuts[k].is_none(), "{label}");
                assert_eq!(kept, all, "{label}");
            }
            Some(0) => {
                assert!(trimmed.runs[k].1.is_some(), "{label}: no snapshot kept");
                assert!(kept.is_empty(), "{label}");
            }
            Some(j) => {
                let c = trimmed.cuts[k]
                    .as_ref()
                    .unwrap_or_else(|| panic!("{label} not cut"));
                assert_eq!((c.kept, c.of), (j, all.len()), "{label}");
                assert!(c.reason.contains("rotates an element"), "{}", c.reason);
                assert_eq!(kept[..], all[..j], "{label}");
                cut.push((label.clone(), j));
            }
        }
    }
    eprintln!(
        "max_rotation {LIMIT}°: {} of {} runs cut ({cut:?})",
        cut.len(),
        whole.runs.len()
    );
    assert!(!cut.is_empty() && cut.len() < whole.runs.len(), "{cut:?}");
    assert!(
        trimmed.envelope.max_displacement < whole.envelope.max_displacement,
        "the envelope is the kept snapshots'"
    );
    // Uncut, the envelope's forces are the plan's; cut, at most those.
    assert_eq!(whole.envelope.max_multiple, plan.max_multiple());
    for (g, (name, f)) in whole.envelope.max_force.iter().enumerate() {
        assert_eq!(*f, plan.max_force(g), "{name}");
        assert!(trimmed.envelope.max_force[g].1 <= *f, "{name}");
    }

    let compiled = compiled_variant("cut.toml", |base| {
        base.replace("every = 2", &format!("every = 2\nmax_rotation = {LIMIT}"))
    });
    let notes = &compiled.model.report.notes;
    let note = notes
        .iter()
        .find(|n| n.contains("runs were cut"))
        .unwrap_or_else(|| panic!("no note on the cut runs: {notes:?}"));
    assert!(
        note.contains(&format!(
            "{} of {} runs were cut",
            cut.len(),
            whole.runs.len()
        )) && note.contains("max_rotation = 15°")
            && cut.iter().any(|(label, _)| note.contains(label.as_str())),
        "{note}"
    );
    let check = compiled.self_check.as_ref().expect("self-check");
    for (label, kept) in &cut {
        let run = check.runs.iter().find(|r| &r.label == label);
        if let Some(run) = run {
            assert_eq!(run.snapshots, *kept, "{label}");
            assert!(run.failure.is_none(), "{label}: {:?}", run.failure);
        }
    }
}

/// A stated `order` above the snapshots the training kept after its cuts (the scene check
/// passes it: before training the runs hold enough) is a warning with the count, and the basis
/// has no more vectors than those snapshots.
#[test]
fn an_order_above_the_snapshots_kept_after_cuts_is_a_warning() {
    let compiled = compiled_variant("short-cut.toml", |base| {
        base.replace(
            "order = 10\n",
            "order = 100\nmax_rotation = 2\naccept_failed_check = true\n",
        )
    });
    let notes = &compiled.model.report.notes;
    let warning = notes
        .iter()
        .find(|n| n.contains("order = 100 is above the"))
        .unwrap_or_else(|| panic!("no warning: {notes:?}"));
    let kept: usize = warning
        .split("above the ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{warning}"));
    eprintln!("{warning}");
    assert!(kept < 100 && warning.starts_with("WARNING"), "{warning}");
    let tier = compiled.model.tier.as_ref().unwrap();
    assert!(tier.order as usize <= kept, "r = {} of {kept}", tier.order);
    assert_eq!(tier.envelope.snapshots as usize, kept);
}

/// A cubature stopped at its element cap above its tolerance is a warning naming both fields.
#[test]
fn a_cubature_above_its_tolerance_is_a_warning() {
    let notes = compiled_variant("capped.toml", |base| {
        base.replace(
            "ecsw_tolerance = 1e-2",
            // Four elements cannot follow the training: the tier is written only when the
            // scene accepts its failed check.
            "ecsw_tolerance = 1e-6\necsw_max_elements = 4\naccept_failed_check = true",
        )
    })
    .model
    .report
    .notes;
    let warning = notes
        .iter()
        .find(|n| n.starts_with("WARNING: the tier's cubature (ECSW) stopped at"))
        .unwrap_or_else(|| panic!("no cubature warning: {notes:?}"));
    assert!(
        warning.contains("ecsw_max_elements (now 4)") && warning.contains("tolerance 1e-6"),
        "{warning}"
    );
    let (_, model) = compiled();
    assert!(
        !model
            .report
            .notes
            .iter()
            .any(|n| n.contains("cubature (ECSW) stopped")),
        "{:?}",
        model.report.notes
    );
}

/// At rest with no load the round-off residual converges at once (the Newton test's scale is
/// floored at 1e-3 of the training ‖q‖) and the state stays at rest.
#[test]
fn rest_stays_at_rest() {
    let (_, model) = compiled();
    let mut est = Estimator::new(model).unwrap();
    let u = vec![0.0; model.inputs.len()];
    for _ in 0..5 {
        est.predict(&u).unwrap();
        assert!(est.tier_status().iterations <= 2, "{:?}", est.tier_status());
    }
    let max_q = model.tier.as_ref().unwrap().envelope.max_coordinate_norm;
    let worst = est.state().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(worst < 1e-9 * max_q, "{worst:e}");
}

/// σ of the tip force's random walk in the force-state scene, N per 5 ms step.
const FORCE_SIGMA: f64 = 0.05;

/// The beam scene with the tip load as random-walk force states (written once per process).
fn random_walk_scene() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let random_walk = BeamScene {
            force_noise_std: Some(FORCE_SIGMA),
            force_model: Some("random_walk".into()),
            ..tip_beam()
        };
        write_tier_scene(
            scene().parent().unwrap(),
            "scene_random_walk.toml",
            &random_walk,
        )
    })
}

/// The compiled force-state tier model, once per process.
fn compiled_random_walk() -> &'static crokf_formats::Model {
    static C: OnceLock<crokf_formats::Model> = OnceLock::new();
    C.get_or_init(|| compile(random_walk_scene(), &options()).unwrap().model)
}

/// The tier's filter estimates a withheld tip load from the tip marker alone: markers from the
/// same tier model driven by a 20 N downward ramp (open loop, noise-free), the filter given
/// u = 0. Without force states (format v3) the state has no force and the load is lost.
#[test]
fn a_withheld_load_is_recovered_by_the_tier_filter() {
    let model = compiled_random_walk();
    let t = model.tier.as_ref().unwrap();
    let r = t.order as usize;
    assert_eq!(t.force_loads, vec![0]);
    assert_eq!(t.state_dim(), 3 * r + 3);
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let mut truth = Estimator::new(model).unwrap();
    let mut est = Estimator::new(model).unwrap();
    // Without the innovation gate: a 20 N ramp over 0.1 s that nobody tells the filter is a
    // transient far beyond 5σ of the random-walk innovation covariance, and the default gate
    // (now applied on this tier too) locks the markers out (f ≈ (10, 3, −3) N, tip error 1.2
    // with it on). The report comparisons run without the gate for the same reason.
    est.set_innovation_gate(None);
    assert_eq!(est.state().len(), 3 * r + 3);
    let mut u = vec![0.0; model.inputs.len()];
    let zero = vec![0.0; model.inputs.len()];
    let mut y = vec![0.0; model.measurements.len()];
    let (mut tip, mut tip_ref) = ([0.0; 3], [0.0; 3]);
    for k in 0..300 {
        u[zi] = tip_load(k, 20.0);
        truth.predict(&u).unwrap();
        truth.measurement_estimates(&mut y).unwrap();
        let measured: Vec<Option<f64>> = y.iter().map(|&v| Some(v)).collect();
        est.step(&zero, &measured).unwrap();
    }
    truth.sensor_displacements(&mut tip_ref).unwrap();
    est.sensor_displacements(&mut tip).unwrap();
    let f = &est.state()[3 * r..];
    let tip_error = (0..3)
        .map(|c| (tip[c] - tip_ref[c]).powi(2))
        .sum::<f64>()
        .sqrt()
        / (0..3).map(|c| tip_ref[c].powi(2)).sum::<f64>().sqrt();
    eprintln!(
        "withheld 20 N: estimated f = ({:.4}, {:.4}, {:.4}) N after 300 steps, tip error \
         {:.2e}, tip ({:.4}, {:.4}, {:.4}) m",
        f[0], f[1], f[2], tip_error, tip_ref[0], tip_ref[1], tip_ref[2]
    );
    assert!(tip_ref[2] < -0.05, "deflection expected: {tip_ref:?}");
    // The applied component within 1 % (0.2 N); the others, which this stiff beam's single
    // marker sees more weakly (the axial one through 1e4-N/m stretching), within 5 % (1 N).
    assert!((f[2] + 20.0).abs() < 0.2, "f = {f:?}");
    assert!(f[0].abs() < 1.0 && f[1].abs() < 1.0, "f = {f:?}");
    assert!(tip_error < 2e-2, "{tip_error:e}");
}

/// The tier's update gates like the warped tier's (docs/design.md §6): the default 5σ gate
/// skips nothing of 600 marker values with the scene's own noise, skips a 1 m outlier on one
/// channel (the update then equals the update without that value), and without the gate the
/// outlier enters the state.
#[test]
fn the_gate_skips_a_one_metre_outlier_and_none_of_the_scenes_noise() {
    let model = compiled_random_walk();
    let t = model.tier.as_ref().unwrap();
    let tm = TierModel::new(model, t);
    let mut st = TierState::new(&tm, model.loads.len());
    let q = model.measurements.len();
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let every = vec![1u64; q];
    let mut last = vec![0u64; q];
    let mut gated_now = vec![false; q];
    let mut rng = SplitMix64(0x9e37_79b9_7f4a_7c15);
    let sigma: Vec<f64> = t
        .kalman
        .measurement_variance
        .iter()
        .map(|v| v.sqrt())
        .collect();
    let mut u = vec![0.0; model.inputs.len()];
    let mut gated = 0;
    let mut predicted = vec![0.0; q];
    for k in 1..=200u64 {
        u[zi] = tip_load(k as usize, 10.0);
        st.step(&tm, &u, k).unwrap();
        for (j, m) in model.measurements.iter().enumerate() {
            predicted[j] = st.sensor(&tm, m.sensor as usize)[m.component as usize];
        }
        let noise: Vec<f64> = sigma.iter().map(|s| s * rng.normal()).collect();
        let gate = Gate {
            sigmas: Some(DEFAULT_GATE_SIGMAS),
            step: k,
            last_accepted: &last,
            every: &every,
        };
        let used = st.update_gated(
            &tm,
            0,
            &|j| Some(predicted[j] + noise[j]),
            &gate,
            &mut gated_now,
        );
        gated += q - used;
        st.commit_update();
        last.iter_mut().for_each(|l| *l = k);
    }
    assert_eq!(
        gated, 0,
        "the 5σ gate skipped values of the scene's own noise"
    );
    // A 1 m outlier on channel 0.
    let k = 201;
    st.step(&tm, &u, k).unwrap();
    for (j, m) in model.measurements.iter().enumerate() {
        predicted[j] = st.sensor(&tm, m.sensor as usize)[m.component as usize];
    }
    let outlier = |j: usize| Some(predicted[j] + if j == 0 { 1.0 } else { 1e-4 });
    let gate = Gate {
        sigmas: Some(DEFAULT_GATE_SIGMAS),
        step: k,
        last_accepted: &last,
        every: &every,
    };
    let used = st.update_gated(&tm, 0, &outlier, &gate, &mut gated_now);
    assert_eq!(used, q - 1);
    assert!(
        gated_now[0] && gated_now[1..q].iter().all(|g| !g),
        "{gated_now:?}"
    );
    let gated_result = st.pending_update().to_vec();
    st.update(&tm, 0, &|j| if j == 0 { None } else { outlier(j) });
    assert_eq!(st.pending_update(), &gated_result[..]);
    st.update(&tm, 0, &outlier);
    let moved = st
        .pending_update()
        .iter()
        .zip(&gated_result)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        moved > 1e-3,
        "without the gate the outlier moves the state: {moved:e}"
    );

    // The same through the public `Estimator` (the gate on by default): 30 steps with markers
    // at the predicted values gate nothing; a 1 m outlier on channel 0 at step 31 is skipped,
    // counted, and leaves the state as the update without that value would.
    let mut est = Estimator::new(model).unwrap();
    assert_eq!(est.innovation_gate(), Some(DEFAULT_GATE_SIGMAS));
    let mut y_hat = vec![0.0; q];
    let mut without = Estimator::new(model).unwrap();
    for k in 1..=31 {
        u[zi] = tip_load(k, 10.0);
        for e in [&mut est, &mut without] {
            e.predict(&u).unwrap();
        }
        est.measurement_estimates(&mut y_hat).unwrap();
        let y: Vec<Option<f64>> = (0..q)
            .map(|j| Some(y_hat[j] + if k == 31 && j == 0 { 1.0 } else { 0.0 }))
            .collect();
        let y_without: Vec<Option<f64>> = (0..q)
            .map(|j| if k == 31 && j == 0 { None } else { y[j] })
            .collect();
        est.update(&y).unwrap();
        without.update(&y_without).unwrap();
    }
    assert_eq!(est.gated_total(), 1);
    assert_eq!(est.gated_per_channel()[0], 1);
    assert_eq!(est.gated_last_update(), 1);
    assert_eq!(est.state(), without.state());
}

/// A model file of the previous format (v6: no force-σ levels in the tier) is refused with a
/// message that says to recompile.
#[test]
fn a_v6_model_file_is_refused_with_recompile() {
    let (bytes, _) = compiled();
    let mut old = bytes.clone();
    old[8..12].copy_from_slice(&6u32.to_le_bytes());
    let err = crokf_runtime::model_from_bytes(&old)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("model format v6, this runtime reads v7, v9, v10")
            && err.contains("recompile"),
        "{err}"
    );
}

/// The gain schedule (docs/design.md §11.5) of the force-state tier: its operating points are
/// training states picked farthest-first (the first is the training state of largest ‖q‖,
/// which the envelope records independently), each stored filter solves the Riccati equation
/// of the tier linearised at its point (F from `LinearisedTier::transition`, assembled in s
/// coordinates, not the compiler's scaled modal route) and is stable there, the runtime picks
/// each point's own filter at that point and the rest filter at rest, and `section::refilter`
/// recomputes the same schedule from the file.
#[test]
fn the_gain_schedule_solves_the_riccati_equation_at_its_points() {
    let model = compiled_random_walk();
    let t = model.tier.as_ref().unwrap();
    let r = t.order as usize;
    assert!(
        !t.scheduled.is_empty() && t.scheduled.len() <= filter::SCHEDULE_POINTS,
        "{} points",
        t.scheduled.len()
    );
    let norms: Vec<f64> = t
        .scheduled
        .iter()
        .map(|s| s.point.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    let largest = t.envelope.max_coordinate_norm;
    assert!(
        (norms[0] - largest).abs() <= 1e-12 * largest,
        "first point ‖q‖ {} vs training max {largest}",
        norms[0]
    );
    assert!(norms
        .iter()
        .all(|&n| n > 0.0 && n <= largest * (1.0 + 1e-12)));
    let full = FullOrder::build(random_walk_scene(), &mut StageTimer::default()).unwrap();
    let (lin, _, _) = section::linearised_of_file(&full, model, &full.noise).unwrap();
    let reduced = section::reduced_model_of_file(&full, t).unwrap();
    let prepared = TierModel::new(model, t);
    assert_eq!(prepared.filter_count(), 1 + t.scheduled.len());
    assert_eq!(prepared.nearest_filter(&vec![0.0; r]), 0);
    let mut rest_radius_at_points = Vec::new();
    for (i, s) in t.scheduled.iter().enumerate() {
        assert_eq!(prepared.nearest_filter(&s.point), i + 1);
        let q = DVector::from_column_slice(&s.point);
        let (f, h) = lin.at(&reduced, &q).transition().unwrap();
        let phase = &s.kalman.phases[0];
        assert_eq!(s.kalman.period, 1);
        let prior = section::file_matrix(&phase.prior_covariance);
        let posterior = section::file_matrix(&phase.posterior_covariance);
        let q_noise = section::file_matrix(&s.kalman.process_noise);
        let riccati = &f * &posterior * f.transpose() + &q_noise;
        let residual = (&riccati - &prior).norm() / prior.norm();
        assert!(residual < 1e-6, "point {i}: Riccati residual {residual:e}");
        let radius = |gain: &nalgebra::DMatrix<f64>| {
            let n = f.nrows();
            let closed = (nalgebra::DMatrix::identity(n, n) - gain * &h) * &f;
            closed
                .complex_eigenvalues()
                .iter()
                .map(|z| z.norm())
                .fold(0.0, f64::max)
        };
        let own = radius(&section::file_matrix(&phase.gain));
        assert!(own < 1.0, "point {i}: closed-loop spectral radius {own}");
        rest_radius_at_points.push((own, radius(&section::file_matrix(&t.kalman.phases[0].gain))));
    }
    eprintln!(
        "schedule: {} points, ‖q*‖ = {norms:.3?}; closed-loop spectral radius at each point \
         (own gain, rest gain) = {rest_radius_at_points:.4?}",
        t.scheduled.len()
    );
    let mut again = model.clone();
    section::refilter(&full, &mut again, &full.noise).unwrap();
    let again = again.tier.unwrap();
    assert_eq!(again.scheduled.len(), t.scheduled.len());
    for (a, b) in again.scheduled.iter().zip(&t.scheduled) {
        assert_eq!(a.point, b.point);
        let (ga, gb) = (
            section::file_matrix(&a.kalman.phases[0].gain),
            section::file_matrix(&b.kalman.phases[0].gain),
        );
        assert!((&ga - &gb).norm() <= 1e-9 * gb.norm());
    }
}

/// σ of the tip force's rate random walk in the force-rate scene, N/s per 5 ms step.
const RATE_SIGMA: f64 = 20.0;

/// The random-walk beam scene with force-rate states (docs/design.md §11.5), compiled once.
fn compiled_force_rate() -> &'static crokf_formats::Model {
    static C: OnceLock<crokf_formats::Model> = OnceLock::new();
    C.get_or_init(|| {
        let text = std::fs::read_to_string(random_walk_scene())
            .unwrap()
            .replace(
                "force_model = \"random_walk\"",
                &format!("force_model = \"random_walk\"\nforce_rate_noise_std = {RATE_SIGMA:e}"),
            );
        let path = random_walk_scene().with_file_name("scene_force_rate.toml");
        std::fs::write(&path, text).unwrap();
        compile(&path, &options()).unwrap().model
    })
}

/// Runs the withheld-load case of `a_withheld_load_is_recovered_by_the_tier_filter` (20 N
/// ramped in over 20 steps, noise-free markers from the same model, u = 0) on `model`; returns
/// the filter's force states after step 20 (end of the ramp) and after step 300.
fn withheld_ramp(model: &crokf_formats::Model) -> (Vec<f64>, Vec<f64>) {
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let r = model.tier.as_ref().unwrap().order as usize;
    let mut truth = Estimator::new(compiled_random_walk()).unwrap();
    let mut est = Estimator::new(model).unwrap();
    est.set_innovation_gate(None);
    let mut u = vec![0.0; model.inputs.len()];
    let zero = vec![0.0; model.inputs.len()];
    let mut y = vec![0.0; model.measurements.len()];
    let mut at_ramp_end = Vec::new();
    for k in 0..300 {
        u[zi] = tip_load(k, 20.0);
        truth.predict(&u).unwrap();
        truth.measurement_estimates(&mut y).unwrap();
        let measured: Vec<Option<f64>> = y.iter().map(|&v| Some(v)).collect();
        est.step(&zero, &measured).unwrap();
        if k == 19 {
            at_ramp_end = est.state()[3 * r..].to_vec();
        }
    }
    (at_ramp_end, est.state()[3 * r..].to_vec())
}

/// Force-rate states (docs/design.md §11.5): the state grows by 3 rates per group, the rate of
/// a withheld 20 N ramp over 0.1 s (−200 N/s) is estimated during the ramp, the force lags the
/// ramp less than without rates at its end, and both settle on the applied force; a rate σ on
/// a white load or on the warped tier is refused, naming the field.
#[test]
fn force_rate_states_follow_a_withheld_ramp() {
    let model = compiled_force_rate();
    let t = model.tier.as_ref().unwrap();
    let r = t.order as usize;
    assert!(t.force_rates);
    assert_eq!(t.state_dim(), 3 * r + 6);
    assert_eq!(Estimator::new(model).unwrap().state().len(), 3 * r + 6);
    let (ramp_end, settled) = withheld_ramp(model);
    let (ramp_end_rw, settled_rw) = withheld_ramp(compiled_random_walk());
    eprintln!(
        "withheld 20 N ramp: at its end f_z = {:.3} N, ḟ_z = {:.1} N/s with rates; f_z = {:.3} N \
         without; after 300 steps f = {:.3?} (rates), {:.3?} (random walk)",
        ramp_end[2], ramp_end[5], ramp_end_rw[2], settled, settled_rw
    );
    // The applied force at the end of the ramp is −20 N; its rate −200 N/s.
    assert!(
        (ramp_end[2] + 20.0).abs() < (ramp_end_rw[2] + 20.0).abs(),
        "lag with rates {} vs without {}",
        ramp_end[2] + 20.0,
        ramp_end_rw[2] + 20.0
    );
    assert!(
        ramp_end[5] < -50.0,
        "rate at the ramp's end {}",
        ramp_end[5]
    );
    assert!((settled[2] + 20.0).abs() < 0.2, "f = {settled:?}");
    assert!(
        settled[5].abs() < 5.0,
        "rate after 300 steps {}",
        settled[5]
    );
    // Refused: a rate σ without random-walk force states, or on the warped tier.
    let dir = scene().parent().unwrap();
    let base = std::fs::read_to_string(scene()).unwrap();
    for (text, why) in [
        (
            base.replace(
                "force_noise_std = 1e-2",
                "force_noise_std = 1e-2\nforce_rate_noise_std = 1.0",
            ),
            "white load",
        ),
        (
            std::fs::read_to_string(random_walk_scene())
                .unwrap()
                .replace(TIER, "")
                .replace(
                    "force_model = \"random_walk\"",
                    "force_model = \"random_walk\"\nforce_rate_noise_std = 1.0",
                ),
            "warped tier",
        ),
    ] {
        assert!(text.contains("force_rate_noise_std"), "{why}: not inserted");
        let path = dir.join("bad_rate.toml");
        std::fs::write(&path, text).unwrap();
        let err = match compile(&path, &options()) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{why}: accepted"),
        };
        assert!(err.contains("force_rate_noise_std"), "{why}: {err}");
    }
}

/// The iterated scheduled update (docs/design.md §11.5): from rest, markers placed at c times
/// the displacement of the scheduled operating point farthest from rest (c = 1, 10, 50) move the
/// state away from rest; in every case the committed state is s⁻ + K_i ν with ν the innovation
/// and K_i the stored gain of the filter i that the runtime reports, i is the filter nearest
/// to that state (the fixed point the iteration looks for), and for c = 10 and 50 it is not the
/// rest filter that the prior would pick.
#[test]
fn the_update_uses_the_gain_of_the_filter_nearest_to_its_result() {
    let model = compiled_random_walk();
    let t = model.tier.as_ref().unwrap();
    let r = t.order as usize;
    let prepared = TierModel::new(model, t);
    let far = &t.scheduled[0].point;
    let mut switched = 0;
    for c in [1.0, 10.0, 50.0] {
        let mut est = Estimator::new(model).unwrap();
        est.set_innovation_gate(None);
        // The force-σ levels held (docs/design.md §11.10): the large innovations here would
        // raise the level for the next step, and `tier_filter` would name that level's filter.
        est.set_force_adaptation(false);
        est.predict(&vec![0.0; model.inputs.len()]).unwrap();
        assert_eq!(est.tier_filter(), Some(0));
        let prior = est.state().to_vec();
        let mut predicted = vec![0.0; model.measurements.len()];
        est.measurement_estimates(&mut predicted).unwrap();
        // Markers at c times the point's displacement: y = c H V q*.
        let y: Vec<f64> = model
            .measurements
            .iter()
            .map(|m| {
                let rows = &t.sensor_rows[m.sensor as usize];
                let k = m.component as usize;
                c * (0..r).map(|j| rows.data[k * r + j] * far[j]).sum::<f64>()
            })
            .collect();
        let measured: Vec<Option<f64>> = y.iter().map(|&v| Some(v)).collect();
        est.update(&measured).unwrap();
        let used = est.tier_filter().unwrap();
        let posterior = est.state().to_vec();
        assert_eq!(used, prepared.nearest_filter(&posterior[..r]), "c = {c}");
        if c >= 10.0 {
            assert_ne!(used, 0, "c = {c}: the update should leave the rest filter");
        }
        let kalman = if used == 0 {
            &t.kalman
        } else {
            switched += 1;
            &t.scheduled[used - 1].kalman
        };
        let phase = &kalman.phases[est.phase()];
        let nu = DVector::from_iterator(
            phase.measured.len(),
            phase
                .measured
                .iter()
                .map(|&j| y[j as usize] - predicted[j as usize]),
        );
        let expected = DVector::from_column_slice(&prior) + section::file_matrix(&phase.gain) * nu;
        let error = (&expected - DVector::from_column_slice(&posterior)).norm() / expected.norm();
        eprintln!(
            "iterated update, markers × {c}: filter {used} of {}, relative difference {error:.1e}",
            prepared.filter_count()
        );
        assert!(error < 1e-12, "c = {c}: {error:e}");
    }
    assert!(switched > 0, "no update left the rest filter");
}

/// det F of sampled element `e` of the tier at reduced coordinates `q` (r), computed here from
/// the model file's data alone (not the kernel): x_a = X_a + (V_e q)_a, F = Σ_a x_a ⊗ ∇N_a.
fn element_det(t: &crokf_formats::CorotationalTier, e: usize, q: &[f64]) -> f64 {
    let el = &t.elements[e];
    let r = t.order as usize;
    let mut f = [[0.0; 3]; 3];
    for a in 0..4 {
        let x: [f64; 3] = std::array::from_fn(|c| {
            let i = 3 * a + c;
            el.rest[a][c] + (0..r).map(|j| el.rows.data[r * i + j] * q[j]).sum::<f64>()
        });
        for i in 0..3 {
            for j in 0..3 {
                f[i][j] += x[i] * el.gradients[a][j];
            }
        }
    }
    f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0])
        + f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0])
}

/// Hard case: inverted sampled elements. (1) The runtime's force refuses
/// exactly where the model file's own geometry says a sampled element is inverted (det F
/// computed here, not by the kernel): along each basis vector, scaled until elements invert.
/// (2) Through `Estimator`: the beam crushed by a sudden axial tip load within the input
/// plausibility bound (20 and 50 kN end in `NotConverged`, 100 kN inverts sampled element 11 in
/// the first step's Newton iterates); the refusal leaves the estimator exactly as it was (state,
/// step index), read-outs stay finite, and `reset` brings it back.
#[test]
fn inverted_sampled_elements_are_refused_and_leave_the_estimator_unchanged() {
    let (_, model) = compiled();
    let t = model.tier.as_ref().unwrap();
    let r = t.order as usize;
    let tm = TierModel::new(model, t);
    let mut out = vec![0.0; r];
    let mut rotations = vec![[[0.0; 3]; 3]; t.elements.len()];
    let mut scratch = vec![0.0; tm.force_scratch_len()];
    let (mut refused, mut accepted) = (0, 0);
    for j in 0..r {
        for lambda in [
            -100.0, -30.0, -10.0, -3.0, -1.0, 1.0, 3.0, 10.0, 30.0, 100.0,
        ] {
            let mut q = vec![0.0; r];
            q[j] = lambda;
            let dets: Vec<f64> = (0..t.elements.len())
                .map(|e| element_det(t, e, &q))
                .collect();
            let least = dets.iter().cloned().fold(f64::INFINITY, f64::min);
            let result =
                tm.reduced_force(&q, &vec![0.0; r], &mut out, &mut rotations, &mut scratch);
            if least < 0.0 {
                let e = result.expect_err("an inverted element was not refused");
                assert!(
                    dets[e] < 1e-9,
                    "element {e} refused with det F = {}",
                    dets[e]
                );
                refused += 1;
            } else if least > 1e-3 {
                result.expect("no element is inverted, yet the force was refused");
                accepted += 1;
            }
        }
    }
    eprintln!("kernel: {refused} inverted states refused, {accepted} valid states accepted");
    assert!(refused > 0 && accepted > 0, "{refused} {accepted}");

    let xi = model
        .inputs
        .iter()
        .position(|c| c.label == "tip.x")
        .unwrap();
    let mut refusal = None;
    'loads: for load in [2e4, 5e4, 1e5, 2e5, 5e5] {
        let mut est = Estimator::new(model).unwrap();
        let mut u = vec![0.0; model.inputs.len()];
        u[xi] = -load;
        for _ in 0..50 {
            let before = est.state().to_vec();
            let index = est.step_index();
            match est.predict(&u) {
                Ok(()) => {}
                Err(e) => {
                    eprintln!("probe {load}: {e}");
                    if matches!(e, RuntimeError::Tier(TierError::InvertedElement { .. })) {
                        refusal = Some((load, est, before, index, e, u));
                        break 'loads;
                    }
                    continue 'loads;
                }
            }
        }
    }
    let (load, mut est, before, index, error, u) =
        refusal.expect("no axial load up to 5e5 N made the tier refuse a step");
    eprintln!("axial tip load {load} N: {error}");
    assert!(
        matches!(error, RuntimeError::Tier(TierError::InvertedElement { det, .. }) if det <= 0.0),
        "{error:?}"
    );
    assert_eq!(est.state(), &before[..], "a refused step changed the state");
    assert_eq!(est.step_index(), index);
    let mut sensors = vec![0.0; 3 * model.sensors.len()];
    est.sensor_displacements(&mut sensors).unwrap();
    assert!(sensors.iter().all(|v| v.is_finite()));
    // The same step is refused again (nothing half-applied), and a reset recovers.
    assert!(est.predict(&u).is_err());
    assert_eq!(est.state(), &before[..]);
    est.reset();
    est.predict(&vec![0.0; model.inputs.len()]).unwrap();
    assert!(
        est.state().iter().all(|v| v.abs() < 1e-12),
        "rest stays at rest after reset"
    );
}

/// The tier of the beam scene with its scene's settings (the same training as the compile).
fn built_tier(full: &FullOrder) -> (TrainingPlan, tier::Tier) {
    let spec = full.scene.scene.reduction.corotational.clone().unwrap();
    let plan = TrainingPlan::from_scene(&spec, &["tip".to_string()]);
    let built = tier::build(
        full,
        &plan,
        spec.order(),
        &EcswOptions {
            tolerance: spec.ecsw_tolerance(),
            ..EcswOptions::default()
        },
        &mut |_, _, _| {},
    )
    .unwrap();
    (plan, built)
}

/// The self-check (docs/design.md §10) on the beam's r = 10 tier: the bending runs (±y, ±z) are
/// reproduced to ≈ 1 %, the axial runs (±x) are not (6.5 % ramp, 11.4 % step: r = 10 pooled
/// POD vectors, dominated by the large bending snapshots, miss the small axial ones; exact
/// integration instead of ECSW gives the same 11.7 %, r = 14 brings them to 2.9 %), so the
/// compile warns naming an axial step run. The figure of one run equals an independent
/// recomputation: the full-order co-rotational simulator and the reduced stepper driven by
/// hand on the run's load (tip −z, ramp to 1.25 × 30 N over 0.05 s), the error
/// ‖V q − u‖_M / ‖u‖_M summed over the stored steps.
#[test]
fn self_check_is_small_and_equals_an_independent_recomputation() {
    use crokf_compile::nonlinear::self_check::{runtime_newton, self_check, SELF_CHECK_THRESHOLD};
    use crokf_compile::stepping::{CorotationalSimulator, Simulator};
    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let spec = full.scene.scene.reduction.corotational.clone().unwrap();
    let (plan, built) = built_tier(&full);
    let newton = runtime_newton(spec.newton_tolerance, spec.newton_iterations);
    let check = self_check(&full, &plan, &built, newton, SELF_CHECK_THRESHOLD).unwrap();
    let worst = check.worst().unwrap();
    eprintln!(
        "beam self-check (r = 10): worst '{}' {:.3e}, median {:.3e} over {} runs, {} reduced \
         steps in {:.3} s",
        worst.label,
        worst.error,
        check.median(),
        check.runs.len(),
        check.runs.iter().map(|r| r.steps).sum::<usize>(),
        check.seconds
    );
    for r in &check.runs {
        eprintln!("  {:<32} {:.3e}", r.label, r.error);
    }
    assert_eq!(check.runs.len(), 12);
    assert!(check
        .runs
        .iter()
        .all(|r| r.error.is_finite() && r.steps == 30));
    assert_eq!(check.unconverged(), 0);
    for r in &check.runs {
        if r.label.contains("(+0, ") {
            assert!(r.error < 0.015, "bending run {r:?}");
        } else {
            assert!(r.error > 0.05 && r.error < 0.15, "axial run {r:?}");
        }
    }
    assert!(worst.label.contains("+0, +0) step"), "{worst:?}");
    assert!(check.median() < 0.015, "{}", check.median());
    assert_eq!(check.flagged().len(), 4);

    // One run by hand.
    let label = "tip (+0, +0, -1) ramp 1.25×";
    let k = check.runs.iter().position(|r| r.label == label).unwrap();
    let z = full
        .operators
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let column = &full.operators.inputs[z].column;
    let mut sim = CorotationalSimulator::new(&full.fem, full.wilson, plan.newton).unwrap();
    sim.set_modified_newton(plan.modified).unwrap();
    sim.set_sequential();
    let mut stepper = tight_stepper(&built.model);
    let v = &built.basis.vectors;
    let reduced_column = v.tr_mul(&DVector::from_column_slice(column));
    let (mut err2, mut ref2) = (0.0, 0.0);
    let m_norm2 = |x: &[f64]| -> f64 {
        crokf_compile::fem::sparse_mul(&full.fem.mass, x)
            .iter()
            .zip(x)
            .map(|(a, b)| a * b)
            .sum()
    };
    for step in 0..30 {
        let t = step as f64 * 0.005;
        let force = -1.25 * RANGE * (t / 0.05).min(1.0);
        let f: Vec<f64> = column.iter().map(|b| force * b).collect();
        sim.step(&f).unwrap();
        stepper.step(&(&reduced_column * force)).unwrap();
        if (step + 1) % 2 == 0 {
            let u = sim.displacement();
            let d: Vec<f64> = (v * stepper.coordinates())
                .iter()
                .zip(u)
                .map(|(a, b)| a - b)
                .collect();
            err2 += m_norm2(&d);
            ref2 += m_norm2(u);
        }
    }
    let by_hand = (err2 / ref2).sqrt();
    eprintln!(
        "'{label}': self-check {:.6e}, by hand {by_hand:.6e}",
        check.runs[k].error
    );
    assert!(
        (by_hand - check.runs[k].error).abs() < 1e-9,
        "{by_hand:e} vs {:e}",
        check.runs[k].error
    );
    assert!(by_hand > 0.0);

    // The compile's report carries the check and the warning; report.json has every run.
    let compiled = compile(scene(), &options()).unwrap();
    let notes = &compiled.model.report.notes;
    assert!(
        notes.iter().any(|n| n.contains("tier self-check")),
        "{notes:?}"
    );
    let warning = notes.iter().find(|n| n.contains("WARNING")).unwrap();
    assert!(warning.contains(&worst.label), "{warning}");
    let json: serde_json::Value = serde_json::from_str(&compiled.report_json()).unwrap();
    let runs = json["tier_self_check"]["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 12);
    assert_eq!(json["tier_self_check"]["flagged"], 4);
    let worst_json = json["tier_self_check"]["worst"].as_f64().unwrap();
    assert!((worst_json - worst.error).abs() < 1e-15, "{worst_json:e}");
}

/// The out-of-sample check (docs/design.md §10): with 12 runs, runs 2 and 7 are held out of a
/// second tier's basis and cubature and checked against their own full-order snapshots. Their
/// error is measured (finite, small for the beam's r = 10 tier); a tier too small to follow
/// untrained loads (r = 2) is warned about, naming the worst held-out run; the compile's notes
/// carry the check. Held-out runs: every fifth from index 2, none below five runs.
#[test]
fn the_out_of_sample_check_holds_runs_out_and_flags_a_tier_that_misses_them() {
    use crokf_compile::nonlinear::basis::BasisChoice;
    use crokf_compile::nonlinear::self_check::{
        held_out_runs, out_of_sample, runtime_newton, OUT_OF_SAMPLE_THRESHOLD,
    };
    assert_eq!(held_out_runs(20), vec![2, 7, 12, 17]);
    assert_eq!(held_out_runs(12), vec![2, 7]);
    assert!(held_out_runs(4).is_empty());

    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let (plan, built) = built_tier(&full);
    let newton = runtime_newton(1e-12, 60);
    let ecsw = EcswOptions {
        tolerance: 1e-2,
        ..EcswOptions::default()
    };
    let held = out_of_sample(
        &full,
        &plan,
        &built.training,
        &BasisChoice::pod(14),
        &ecsw,
        newton,
    )
    .unwrap()
    .expect("12 runs: an out-of-sample check");
    let labels: Vec<&str> = held.check.runs.iter().map(|r| r.label.as_str()).collect();
    let runs = plan.runs();
    assert_eq!(labels, vec![runs[2].label.as_str(), runs[7].label.as_str()]);
    let worst = held.check.worst().unwrap();
    eprintln!(
        "beam r = 14 out of sample: worst '{}' {:.3e}, median {:.3e} (r = {}, {} elements)",
        worst.label,
        worst.error,
        held.check.median(),
        held.order,
        held.sampled
    );
    assert!(
        worst.error.is_finite() && worst.error < 0.05,
        "{}",
        worst.error
    );
    assert_eq!(held.runs, 12);

    let crippled = out_of_sample(
        &full,
        &plan,
        &built.training,
        &BasisChoice::pod(2),
        &ecsw,
        newton,
    )
    .unwrap()
    .unwrap();
    let w = crippled.warning().expect("r = 2 misses the held-out runs");
    let worst = crippled.check.worst().unwrap();
    assert!(worst.error > OUT_OF_SAMPLE_THRESHOLD, "{}", worst.error);
    assert!(
        w.contains(&worst.label) && w.contains("out of sample"),
        "{w}"
    );

    let (_, model) = compiled();
    assert!(
        model
            .report
            .notes
            .iter()
            .any(|n| n.starts_with("co-rotational tier out-of-sample check: 2 of the 12")),
        "{:?}",
        model.report.notes
    );
}

/// The fidelity rule (docs/design.md §10): on the beam's training, every rung the rule measured
/// carries the worst held-out error that the out-of-sample check gives for that size on its
/// own; the rungs before the chosen one are above the threshold, and the chosen one is within
/// it or, when none is, the most accurate. A scene that states no size compiles with the rule
/// and says so; one that states `order` does not run it.
#[test]
fn the_fidelity_rule_takes_the_first_size_within_the_held_out_threshold() {
    use crokf_compile::nonlinear::fidelity::{self, Fidelity, Rung, LADDER};
    use crokf_compile::nonlinear::self_check::{
        out_of_sample, runtime_newton, OUT_OF_SAMPLE_THRESHOLD,
    };
    let full = FullOrder::build(scene(), &mut StageTimer::default()).unwrap();
    let (plan, built) = built_tier(&full);
    let newton = runtime_newton(1e-12, 60);
    // Each measured rung carries the out-of-sample check's own figure for its size; the
    // rungs before the chosen one are above the threshold.
    let check = |chosen: &Fidelity, ladder: &[Rung]| {
        eprintln!("{}", chosen.note());
        assert!(!chosen.tried.is_empty() && chosen.tried.len() <= ladder.len());
        for (k, (rung, worst)) in chosen.tried.iter().enumerate() {
            assert_eq!(*rung, ladder[k]);
            let direct = out_of_sample(
                &full,
                &plan,
                &built.training,
                &rung.basis(),
                &rung.ecsw(),
                newton,
            )
            .unwrap()
            .unwrap();
            let direct_worst = direct.check.worst().unwrap().error;
            assert_eq!(direct_worst.to_bits(), worst.to_bits(), "{}", rung.label());
            if k + 1 < chosen.tried.len() {
                assert!(
                    *worst > OUT_OF_SAMPLE_THRESHOLD,
                    "{}: {worst}",
                    rung.label()
                );
            }
        }
        chosen
            .out_of_sample
            .as_ref()
            .unwrap()
            .check
            .worst()
            .unwrap()
            .error
    };
    let rung = |order: usize, ecsw_tolerance: f64| Rung {
        order,
        ecsw_tolerance,
        ecsw_max_elements: 200,
    };

    // A first size too small to follow the held-out runs (r = 2): the rule climbs.
    let ladder = [rung(2, 1e-2), LADDER[0]];
    let chosen = fidelity::choose_from(&ladder, &full, &plan, &built.training, newton).unwrap();
    let worst = check(&chosen, &ladder);
    assert_eq!(chosen.tried.len(), 2);
    assert!(chosen.met() && worst <= OUT_OF_SAMPLE_THRESHOLD, "{worst}");
    assert_eq!(chosen.rung, LADDER[0]);
    assert!(!chosen.note().starts_with("WARNING"), "{}", chosen.note());

    // No size within the threshold: the most accurate is taken, with a warning.
    let ladder = [rung(3, 1e-2), rung(2, 1e-2)];
    let chosen = fidelity::choose_from(&ladder, &full, &plan, &built.training, newton).unwrap();
    let worst = check(&chosen, &ladder);
    assert!(!chosen.met() && worst > OUT_OF_SAMPLE_THRESHOLD, "{worst}");
    assert_eq!(chosen.tried.len(), 2);
    assert!(
        chosen.tried.iter().all(|(_, w)| *w >= worst),
        "{:?}",
        chosen.tried
    );
    assert!(
        chosen.note().starts_with("WARNING")
            && chosen.note().contains("is used, the most accurate"),
        "{}",
        chosen.note()
    );

    // The product's ladder on this beam.
    let chosen = fidelity::choose(&full, &plan, &built.training, newton).unwrap();
    check(&chosen, &LADDER);

    let unsized_notes = compiled_variant("unsized.toml", |base| {
        base.replace("order = 10\n", "")
            .replace("ecsw_tolerance = 1e-2\n", "")
    })
    .model
    .report
    .notes;
    assert!(
        unsized_notes
            .iter()
            .any(|n| n.contains("fidelity rule") && n.contains(&chosen.rung.label())),
        "{unsized_notes:?}"
    );
    let (_, model) = compiled();
    assert!(
        !model
            .report
            .notes
            .iter()
            .any(|n| n.contains("fidelity rule")),
        "{:?}",
        model.report.notes
    );
}

/// The beam scene with `order = r`, compiled.
fn compiled_with_order(r: usize) -> crokf_compile::Compiled {
    compiled_variant(&format!("order{r}.toml"), |base| {
        base.replace(
            "order = 10",
            &format!("order = {r}\naccept_failed_check = true"),
        )
    })
}

/// The beam scene edited by `edit`, written as `name` next to it and compiled with
/// [`options`].
fn compiled_variant(name: &str, edit: impl Fn(&str) -> String) -> crokf_compile::Compiled {
    let base = std::fs::read_to_string(scene()).unwrap();
    let path = scene().parent().unwrap().join(name);
    std::fs::write(&path, edit(&base)).unwrap();
    compile(&path, &options()).unwrap()
}

/// With r = 14 the beam's tier passes its self-check (every run < 5 %: the check's remedy
/// "raise `order`" works here); nothing is flagged and no warning is written.
#[test]
fn a_sufficient_tier_passes_the_self_check() {
    let compiled = compiled_with_order(14);
    let check = compiled.self_check.as_ref().unwrap();
    let worst = check.worst().unwrap();
    eprintln!(
        "beam tier r = 14: worst '{}' {:.3e}, median {:.3e}",
        worst.label,
        worst.error,
        check.median()
    );
    assert!(worst.error < 0.05, "{worst:?}");
    assert!(check.median() < 0.01, "{}", check.median());
    assert!(check.warning().is_none());
    assert!(!compiled
        .model
        .report
        .notes
        .iter()
        .any(|n| n.contains("WARNING")));
}

/// A Newton bound the tier cannot step with (one iteration to the tightest tolerance: the
/// runtime would refuse every step): the self-check's reduced steps end unconverged, and what
/// the compile says of the tier (its warning, or its error when no stabilising filter is left)
/// names `newton_iterations` first. With the scene's own bound the remedy does not name it.
#[test]
fn a_newton_bound_the_tier_cannot_step_with_is_named() {
    let dir = scene().parent().unwrap().to_path_buf();
    let base = std::fs::read_to_string(scene()).unwrap();
    let loose = base
        .replace("newton_tolerance = 1e-12", "newton_tolerance = 1e-14")
        .replace("newton_iterations = 60", "newton_iterations = 1");
    assert_ne!(loose, base);
    let path = dir.join("newton1.toml");
    std::fs::write(&path, loose).unwrap();
    let said = match compile(&path, &options()) {
        Ok(c) => c
            .self_check
            .as_ref()
            .and_then(|check| check.warning())
            .expect("a tier this far off its training is flagged"),
        Err(e) => e.to_string(),
    };
    eprintln!("newton_iterations = 1: {said}");
    assert!(said.contains("raise `newton_iterations` first"), "{said}");
    let crippled = compiled_with_order(2);
    let w = crippled.self_check.as_ref().unwrap().warning().unwrap();
    assert!(!w.contains("newton_iterations"), "{w}");
}

/// A crippled tier (r = 2 instead of 10) cannot follow its training: the self-check flags it,
/// naming the worst run, in the report's notes and the JSON report; the model still compiles
/// (a warning, not an error).
#[test]
fn a_crippled_tier_is_flagged_by_the_self_check() {
    let compiled = compiled_with_order(2);
    let check = compiled.self_check.as_ref().unwrap();
    let worst = check.worst().unwrap();
    eprintln!(
        "crippled beam tier (r = 2): worst '{}' {:.3e}, median {:.3e}, {} of {} runs flagged",
        worst.label,
        worst.error,
        check.median(),
        check.flagged().len(),
        check.runs.len()
    );
    assert!(worst.error > 0.5, "{worst:?}");
    assert_eq!(check.flagged().len(), 12);
    let warning = compiled
        .model
        .report
        .notes
        .iter()
        .find(|n| n.contains("WARNING"))
        .expect("a warning note");
    assert!(warning.contains(&worst.label), "{warning}");
    assert!(warning.contains("basis_tolerance") && warning.contains("order"));
    let json: serde_json::Value = serde_json::from_str(&compiled.report_json()).unwrap();
    assert!(json["tier_self_check"]["flagged"].as_u64().unwrap() >= 1);
    assert_eq!(
        json["tier_self_check"]["worst_run"].as_str().unwrap(),
        worst.label
    );
}

/// Noise identification from the tier filter's own innovations (docs/design.md §11.6) against
/// a truth whose noise is known: the tier itself driven open loop by a tip force that is a
/// random walk of σ = 0.5 N per step in each component (10× the filter's σ), markers = its tip
/// plus Gaussian noise of the scene's σ, 1,500 steps (the force reaches 55 N, past the trained
/// 37.5 N, through 4 of the schedule's 9 filters; 4–9 with seeds 11–14). The filter (gain schedule included) runs
/// with the load withheld; ALS on its innovations recovers the truth's σ within 15 % and the
/// markers' σ within 20 % (seeds 11–14: σ_f 0.47–0.53 N, markers' factor 0.96–1.02, model-error factor 0.13–4.4; the
/// linearised filters explain less of the innovations the farther the walk goes: over 4,000
/// steps the markers' factor is 1.05 and σ_f 0.43 N with seed 11).
#[test]
fn identify_noise_recovers_the_random_walk_of_a_known_truth() {
    let model = compiled_random_walk();
    let full = FullOrder::build(random_walk_scene(), &mut StageTimer::default()).unwrap();
    let channels: Vec<usize> = ["tip.x", "tip.y", "tip.z"]
        .iter()
        .map(|l| model.inputs.iter().position(|c| c.label == *l).unwrap())
        .collect();
    let variance = model
        .tier
        .as_ref()
        .unwrap()
        .kalman
        .measurement_variance
        .clone();
    let sigma_true = 10.0 * FORCE_SIGMA;
    let mut rng = SplitMix64(11);
    let mut normal = move || rng.normal();
    // The truth and its markers first (the truth does not depend on the filter).
    let mut truth = Estimator::new(model).unwrap();
    let mut u = vec![0.0; model.inputs.len()];
    let mut y = vec![0.0; variance.len()];
    let mut recording: Vec<Vec<Option<f64>>> = Vec::with_capacity(1500);
    let mut peak = 0.0f64;
    for _ in 0..1500 {
        truth.predict(&u).unwrap();
        truth.measurement_estimates(&mut y).unwrap();
        recording.push(
            y.iter()
                .zip(&variance)
                .map(|(v, s2): (&f64, &f64)| Some(v + s2.sqrt() * normal()))
                .collect(),
        );
        for &c in &channels {
            u[c] += sigma_true * normal();
        }
        peak = peak.max(channels.iter().map(|&c| u[c] * u[c]).sum::<f64>().sqrt());
    }
    // The filter over it with the load withheld.
    let inputs = vec![vec![0.0; model.inputs.len()]; recording.len()];
    let run = filter_run(model, &inputs, &recording).unwrap();
    let (innovations, filters) = (&run.innovations, &run.filters);
    let found = identify_noise(&full, &full.noise, model, innovations, filters, 100, 20).unwrap();
    let load = &found.loads[0];
    let switches = run.switches();
    let used: std::collections::BTreeSet<usize> = filters.iter().map(|f| f.0).collect();
    eprintln!(
        "identified σ_f = {:.4} N (truth {sigma_true}, filter {}), markers' factor {:.4}, \
         filters used {used:?}, {switches} switches, fit residual {:.3}, largest force {peak:.1} N",
        load.force_sigma.1,
        load.force_sigma.0,
        found.measurement_scale,
        found.estimate.relative_residual
    );
    // The tier's measured model error is a parameter too (docs/design.md §11.6); this truth
    // is the tier itself, so what the factor takes up is the linearised filters' mismatch with
    // the nonlinear tier (0.13–4.4 over seeds 11–14), not the tier's error against the full-order FEM.
    eprintln!(
        "model error factor (scene, identified): {:?}",
        found.model_error_scale
    );
    let (scene_factor, factor) = found.model_error_scale.expect("the tier measured S");
    assert_eq!(scene_factor, 1.0);
    assert!(factor.is_finite() && factor >= 0.0, "{factor}");
    assert_eq!(load.force_sigma.0, FORCE_SIGMA);
    assert!(switches > 0, "the run should exercise the gain schedule");
    assert!(
        (load.force_sigma.1 / sigma_true - 1.0).abs() < 0.15,
        "σ_f {} vs {sigma_true}",
        load.force_sigma.1
    );
    assert!(
        (found.measurement_scale - 1.0).abs() < 0.2,
        "markers' factor {}",
        found.measurement_scale
    );
}

/// The meniscus's 30 Hz tier scene (`models/meniscus/scene_corotational_30hz.toml`) compiled
/// as committed: markers every 33rd step of the 1 kHz model, force and force-rate states.
fn meniscus_30hz() -> &'static crokf_formats::Model {
    static M: OnceLock<crokf_formats::Model> = OnceLock::new();
    M.get_or_init(|| {
        let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../models/meniscus/scene_corotational_30hz.toml");
        let options = CompileOptions {
            skip_measured_error: true,
            ..CompileOptions::default()
        };
        compile(&scene, &options).unwrap().model
    })
}

#[test]
fn the_30hz_filter_survives_a_fast_press_it_is_not_told_of() {
    // The meniscus's fast press (models/meniscus/scenario_large.toml: 0.2 N along −z in 20 ms,
    // held until 0.5 s, released in 1 ms), the load withheld, markers at 30 Hz from the tier's
    // own open-loop run plus the scene's 0.2 mm noise. The first marker update sees the whole
    // press at once and moves q far; the step after it started its modified Newton from the
    // stale J and, before the safeguards of runtime/src/tier.rs (full Newton once an increment
    // grows, backtracking from an inverted iterate), diverged into an inverted element and
    // refused the step (step 67 for every seed, and on the full-order reference: README).
    let model = meniscus_30hz();
    let zi = model
        .inputs
        .iter()
        .position(|c| c.label == "probe.z")
        .unwrap();
    let load = |k: usize| {
        let t = (k + 1) as f64 * model.dt;
        if t <= 0.02 {
            -0.2 * t / 0.02
        } else if t <= 0.5 {
            -0.2
        } else {
            (-0.2 * (0.501 - t) / 0.001).min(0.0)
        }
    };
    let steps = 700;
    let mut truth = Estimator::new(model).unwrap();
    let mut u = vec![0.0; model.inputs.len()];
    let mut sensors = Vec::with_capacity(steps);
    let mut s = vec![0.0; 3 * model.sensors.len()];
    for k in 0..steps {
        u[zi] = load(k);
        truth.predict(&u).unwrap();
        truth.sensor_displacements(&mut s).unwrap();
        sensors.push(s.clone());
    }
    let withheld = vec![0.0; model.inputs.len()];
    for seed in 1..4 {
        let mut rng = SplitMix64(seed);
        let mut est = Estimator::new(model).unwrap();
        est.set_innovation_gate(None);
        let (mut e2, mut r2) = (0.0, 0.0);
        let mut estimate = vec![0.0; 3 * model.sensors.len()];
        for k in 0..steps {
            est.predict(&withheld)
                .unwrap_or_else(|e| panic!("seed {seed}, step {}: {e}", k + 1));
            let y: Vec<Option<f64>> = model
                .measurements
                .iter()
                .map(|m| {
                    let truth = sensors[k][3 * m.sensor as usize + m.component as usize];
                    Some(truth + 2e-4 * rng.normal())
                })
                .collect();
            est.update(&y).unwrap();
            if (400..500).contains(&k) {
                est.sensor_displacements(&mut estimate).unwrap();
                for (a, b) in estimate.iter().zip(&sensors[k]) {
                    e2 += (a - b) * (a - b);
                    r2 += b * b;
                }
            }
        }
        let error = (e2 / r2).sqrt();
        let f = &est.state()[3 * model.tier.as_ref().unwrap().order as usize..];
        eprintln!(
            "seed {seed}: markers' error over the hold's last 0.1 s {:.2} %, final force states \
             {f:.3?}",
            100.0 * error
        );
        // 4.7–6.4 % for seeds 1–3 (the markers' own noise is 3 % of their displacement). The
        // scene trains along the axes; with the default diagonals at r = 20 seeds 1–2 gave
        // 6.4 % and 11.3 % (docs/results/tier.md §11).
        assert!(error < 0.1, "seed {seed}: {error}");
        assert!(est.state().iter().all(|v| v.is_finite()));
    }
}
