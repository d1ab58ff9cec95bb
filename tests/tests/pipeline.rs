//! End-to-end: scene → model file → runtime, on the bundled cantilever.

use std::path::{Path, PathBuf};

use crokf_compile::check::{check, CheckOutcome};
use crokf_compile::{compile, CompileOptions};
use crokf_runtime::Estimator;

fn cantilever() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/cantilever/scene.toml")
}

fn options(order: usize) -> CompileOptions {
    CompileOptions {
        order: Some(order),
        ..CompileOptions::default()
    }
}

#[test]
fn compiling_twice_gives_byte_identical_files_that_decode() {
    let a = compile(&cantilever(), &options(12)).unwrap();
    let b = compile(&cantilever(), &options(12)).unwrap();
    assert_eq!(a.bytes, b.bytes);
    let model = crokf_formats::decode(&a.bytes).unwrap();
    assert_eq!(model, a.model);
    // 12 balanced states + 3 random-walk force states of the tip load (scene.toml).
    assert_eq!(model.state_dim, 12 + 3);
    assert_eq!(model.report.order, 12);
}

#[test]
fn error_falls_as_the_order_grows_and_stays_small() {
    let mut last = f64::INFINITY;
    let mut figures = Vec::new();
    for r in [4, 8, 16, 32] {
        let c = compile(&cantilever(), &options(r)).unwrap();
        let report = &c.model.report;
        let step = report.measured_errors["step"];
        let chirp = report.measured_errors["chirp"];
        figures.push((r, step, chirp, report.error_bound));
        let worst = step.max(chirp);
        assert!(worst < last * 1.05, "error grew at r = {r}: {figures:?}");
        last = worst;
        assert!(report.spectral_radius < 1.0);
        assert!(
            report.riccati_residual < 1e-10,
            "{}",
            report.riccati_residual
        );
        assert!(report.closed_loop_spectral_radius < 1.0);
    }
    eprintln!("r, step error, chirp error, Hankel bound: {figures:?}");
    assert!(last < 1e-2, "{figures:?}");
}

#[test]
fn check_detects_a_changed_scene() {
    let dir = std::env::temp_dir().join(format!("crokf-check-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let src = cantilever();
    let scene_text = std::fs::read_to_string(&src).unwrap();
    let mesh = src.parent().unwrap().join("cantilever.msh");
    std::fs::copy(&mesh, dir.join("cantilever.msh")).unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, &scene_text).unwrap();
    let compiled = compile(&scene, &options(6)).unwrap();
    let model = dir.join("model.crokf");
    std::fs::write(&model, &compiled.bytes).unwrap();
    assert_eq!(check(&model, &scene).unwrap(), CheckOutcome::UpToDate);
    std::fs::write(&scene, scene_text.replace("alpha = 0.5", "alpha = 0.6")).unwrap();
    match check(&model, &scene).unwrap() {
        CheckOutcome::Stale(why) => assert!(why.contains("scene.toml"), "{why}"),
        other => panic!("{other:?}"),
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The runtime's open-loop trajectory under a tiny load (rotations ~1e-9 rad, so the warping
/// is the identity to round-off) equals the compiler's reduced recursion x⁺ = F x + G u.
#[test]
fn runtime_open_loop_equals_the_reduced_recursion() {
    let c = compile(&cantilever(), &options(16)).unwrap();
    let model = crokf_runtime::Model::clone(&c.model);
    let mut est = Estimator::new(&model).unwrap();
    let r = model.r();
    let m = model.inputs.len();
    let mut x = vec![0.0; r];
    let none = vec![None; model.measurements.len()];
    let mut worst: f64 = 0.0;
    let mut scale: f64 = 0.0;
    for k in 0..200 {
        let u: Vec<f64> = (0..m)
            .map(|j| 1e-9 * ((k + j) as f64 * 0.1).sin())
            .collect();
        est.step(&u, &none).unwrap();
        let f = &model.transition;
        let g = &model.input;
        x = (0..r)
            .map(|i| {
                (0..r).map(|j| f.get(i, j) * x[j]).sum::<f64>()
                    + (0..m).map(|j| g.get(i, j) * u[j]).sum::<f64>()
            })
            .collect();
        for (a, b) in est.state().iter().zip(&x) {
            worst = worst.max((a - b).abs());
            scale = scale.max(b.abs());
        }
    }
    assert!(worst <= 1e-9 * scale, "worst {worst:e}, scale {scale:e}");
}
