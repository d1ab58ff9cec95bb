//! The identify tests' beam (`compiler/tests/identify.rs`, and through `#[path]`
//! `tests/tests/identify_alias.rs`): a 12×2×2-cell co-rotational beam whose scene states the
//! tip load's σ_f, its compiled model, and recordings of a random-walk tip force.

#![allow(dead_code)]

use std::path::Path;

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::{compile, CompileOptions};
use crokf_formats::synthetic::SplitMix64;
use crokf_runtime::Estimator;

/// The filter's σ_f in the scene, N per step.
pub const FILTER_SIGMA: f64 = 0.05;
/// The truth's σ_f: 10× the filter's (docs/design.md §11.6, the tier test).
pub const TRUE_SIGMA: f64 = 0.5;
/// Steps of the recordings.
pub const STEPS: usize = 1500;

/// The tier section of the scene.
pub const TIER: &str = "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n\
    ranges = { tip = 30.0 }\nduration = 0.15\nevery = 2\norder = 10\necsw_tolerance = 1e-2\n\
    newton_tolerance = 1e-12\nnewton_iterations = 60\n";

/// Writes `dir/beam.msh`, `dir/scene.toml` (σ_f stated, a comment line first) and
/// `dir/model.crokf` (compiled with [`options`]); returns the model.
pub fn write_beam(dir: &Path) -> crokf_formats::Model {
    std::fs::create_dir_all(dir).unwrap();
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .unwrap();
    let text = "# the identify test's beam\n".to_owned()
        + &BeamScene {
            sensors: vec![("tip".into(), [0.99, 0.05, 0.1])],
            displays: vec![("end".into(), "xmax".into())],
            dt: 0.005,
            force_noise_std: Some(FILTER_SIGMA),
            force_model: Some("random_walk".into()),
            ..BeamScene::default()
        }
        .toml()
        + TIER;
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let c = compile(&dir.join("scene.toml"), &options()).unwrap();
    std::fs::write(dir.join("model.crokf"), &c.bytes).unwrap();
    c.model
}

pub fn options() -> CompileOptions {
    CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    }
}

/// Markers per step of the tier itself driven open loop by a tip force that is a random walk
/// of σ `sigma` per step in each component, plus Gaussian noise of `noise` × the scene's σ.
pub fn truth(
    model: &crokf_formats::Model,
    sigma: f64,
    noise: f64,
    seed: u64,
) -> Vec<Vec<Option<f64>>> {
    let channels: Vec<usize> = ["tip.x", "tip.y", "tip.z"]
        .iter()
        .map(|l| model.inputs.iter().position(|c| c.label == *l).unwrap())
        .collect();
    let variance = &model.tier.as_ref().unwrap().kalman.measurement_variance;
    let mut rng = SplitMix64(seed);
    let mut truth = Estimator::new(model).unwrap();
    let mut u = vec![0.0; model.inputs.len()];
    let mut y = vec![0.0; variance.len()];
    (0..STEPS)
        .map(|_| {
            truth.predict(&u).unwrap();
            truth.measurement_estimates(&mut y).unwrap();
            let row = y
                .iter()
                .zip(variance)
                .map(|(v, s2)| Some(v + noise * s2.sqrt() * rng.normal()))
                .collect();
            for &c in &channels {
                u[c] += sigma * rng.normal();
            }
            row
        })
        .collect()
}

/// A `crokf-run` measurements file: `step`, then the model's labels.
pub fn write_csv(path: &Path, model: &crokf_formats::Model, rows: &[Vec<Option<f64>>]) {
    std::fs::write(path, crokf_runtime::table::measurements_text(model, rows)).unwrap();
}
