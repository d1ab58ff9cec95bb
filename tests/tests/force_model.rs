//! `force_model = "random_walk"`: the filter carries a load group's force as states, so a
//! persistent force the runtime is not told about is estimated without the lag (bias) of the
//! white-noise model; at low order too, because the force states carry the static residual of
//! the truncation (docs/design.md §11).

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{LinearSimulator, Simulator};
use crokf_compile::{compile, CompileOptions, FullOrder};
use crokf_runtime::Estimator;

fn scene(force_model: &str) -> String {
    scene_with(force_model, vec![("tip".into(), [0.99, 0.05, 0.05])])
}

fn scene_with(force_model: &str, sensors: Vec<(String, [f64; 3])>) -> String {
    BeamScene {
        alpha: 2.0,
        force_model: Some(force_model.into()),
        sensors,
        sensor_noise_std: 1.0e-5,
        displays: vec![("end".into(), "xmax".into())],
        dt: 0.005,
        ..BeamScene::default()
    }
    .toml()
}

/// Final relative tip error of the filter, and the model's state dimension, when the runtime is
/// not told about a constant 0.01 N tip force (exact measurements of a full-order linear run).
fn tip_errors(force_model: &str) -> (f64, usize) {
    let dir =
        std::env::temp_dir().join(format!("crokf-force-{force_model}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, scene(force_model)).unwrap();
    let full = FullOrder::build(&path, &mut StageTimer::default()).unwrap();
    let compiled = compile(
        &path,
        &CompileOptions {
            order: Some(12),
            skip_measured_error: true,
            ..CompileOptions::default()
        },
    )
    .unwrap();
    let model = compiled.model;
    // Full-order linear truth under a constant 0.01 N downward tip force (tiny: no warping).
    let z = full
        .operators
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap();
    let f: Vec<f64> = full.operators.inputs[z]
        .column
        .iter()
        .map(|b| -0.01 * b)
        .collect();
    let mut truth = LinearSimulator::new(&full.fem, full.wilson).unwrap();
    let sensor = &full.operators.sensors[0];
    let mut est = Estimator::new(&model).unwrap();
    let zero = vec![0.0; model.inputs.len()];
    let mut estimate = vec![0.0; 3];
    let mut exact = [0.0; 3];
    for _ in 0..4000 {
        truth.step(&f).unwrap();
        exact = [0.0; 3];
        for &(node, w) in &sensor.weights {
            for (c, e) in exact.iter_mut().enumerate() {
                if let Some(d) = full.fem.dofs.index[node][c] {
                    *e += w * truth.displacement()[d];
                }
            }
        }
        let y: Vec<Option<f64>> = model
            .measurements
            .iter()
            .map(|m| Some(exact[m.component as usize]))
            .collect();
        est.step(&zero, &y).unwrap();
        est.sensor_displacements(&mut estimate).unwrap();
    }
    let error = ((0..3)
        .map(|c| (estimate[c] - exact[c]).powi(2))
        .sum::<f64>()
        / exact.iter().map(|v| v * v).sum::<f64>())
    .sqrt();
    std::fs::remove_dir_all(&dir).ok();
    (error, model.r())
}

#[test]
fn random_walk_force_removes_the_white_noise_bias() {
    let (white, r_white) = tip_errors("white");
    let (walk, r_walk) = tip_errors("random_walk");
    eprintln!("tip error with the force withheld: white {white:.3e} (r = {r_white}), random walk {walk:.3e} (r = {r_walk})");
    assert_eq!(r_walk, r_white + 3);
    assert!(walk < 1e-3, "random walk: {walk}");
    assert!(white > 10.0 * walk, "white {white} vs random walk {walk}");
}

/// A constant tip force with an axial and a downward component, withheld from the runtime, is
/// recovered by the random-walk force states of a low-order model (r = 4 balanced states, where
/// the truncation keeps no axial static response: the force states' static residual makes the
/// axial force observable through 3 markers). Exact marker readings of a full-order linear run.
#[test]
fn withheld_force_is_recovered_at_low_order() {
    let dir = std::env::temp_dir().join(format!("crokf-force-low-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .unwrap();
    let path = dir.join("scene.toml");
    let markers = vec![
        ("tip".into(), [0.99, 0.05, 0.1]),
        ("three_quarter".into(), [0.75, 0.05, 0.1]),
        ("mid".into(), [0.5, 0.05, 0.1]),
    ];
    std::fs::write(&path, scene_with("random_walk", markers)).unwrap();
    let full = FullOrder::build(&path, &mut StageTimer::default()).unwrap();
    let compiled = compile(
        &path,
        &CompileOptions {
            order: Some(4),
            skip_measured_error: true,
            ..CompileOptions::default()
        },
    )
    .unwrap();
    let model = compiled.model;
    let r = model.r();
    assert_eq!(r, 4 + 3);
    // 0.5 N axial (x) and 0.01 N down (−z): axial tip displacement ~5e-5 m, bending ~1e-4 m.
    let force = [0.5, 0.0, -0.01];
    let mut f = vec![0.0; full.fem.dof_count()];
    for (c, label) in ["tip.x", "tip.y", "tip.z"].iter().enumerate() {
        let j = full
            .operators
            .inputs
            .iter()
            .position(|ch| ch.label == *label)
            .unwrap();
        for (fi, b) in f.iter_mut().zip(&full.operators.inputs[j].column) {
            *fi += force[c] * b;
        }
    }
    let mut truth = LinearSimulator::new(&full.fem, full.wilson).unwrap();
    let mut est = Estimator::new(&model).unwrap();
    let zero = vec![0.0; model.inputs.len()];
    for _ in 0..3000 {
        truth.step(&f).unwrap();
        let u = truth.displacement();
        let y: Vec<Option<f64>> = model
            .measurements
            .iter()
            .map(|m| {
                let sensor = &full.operators.sensors[m.sensor as usize];
                let c = m.component as usize;
                Some(
                    sensor
                        .weights
                        .iter()
                        .filter_map(|&(node, w)| full.fem.dofs.index[node][c].map(|d| w * u[d]))
                        .sum(),
                )
            })
            .collect();
        est.step(&zero, &y).unwrap();
    }
    let estimate = &est.state()[r - 3..];
    eprintln!("withheld force {force:?} N, estimated at r = 4: {estimate:?} N");
    std::fs::remove_dir_all(&dir).ok();
    // Axial: within 2 % of 0.5 N; transverse: within 2 % of the 0.01 N downward force.
    assert!(
        (estimate[0] - force[0]).abs() < 0.02 * force[0].abs(),
        "{estimate:?}"
    );
    assert!(estimate[1].abs() < 0.02 * force[2].abs(), "{estimate:?}");
    assert!(
        (estimate[2] - force[2]).abs() < 0.02 * force[2].abs(),
        "{estimate:?}"
    );
}
