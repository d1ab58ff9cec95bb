//! The generated beam shared by the stepper tests (`compiler/tests/stepping.rs`) and the
//! scenario tests (`verify/tests/simulate.rs`, through `#[path]`): one fixture, not two copies.

#![allow(dead_code)]

use std::path::Path;

use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::FemModel;
use crokf_compile::mesh::procedural::{box_mesh, BeamScene};
use crokf_compile::mesh::Mesh;
use crokf_compile::scene::Scene;

/// Beam scene on a generated box mesh: clamp `xmin`, load group `tip` on `xmax`.
pub fn scene(young: f64, poisson: f64, alpha: f64, beta: f64, dt: f64) -> Scene {
    let text = BeamScene {
        mesh_file: "generated.msh".into(),
        young_modulus: young,
        poisson_ratio: poisson,
        alpha,
        beta,
        force_noise_std: None,
        sensors: vec![("tip_centre".into(), [1.0, 0.05, 0.05])],
        sensor_noise_std: 1e-4,
        displays: Vec::new(),
        dt,
        ..BeamScene::default()
    }
    .toml();
    Scene::parse(&text, Path::new("test-scene.toml")).expect("test scene parses")
}

pub fn model(cells: [usize; 3], scene: &Scene) -> (Mesh, FemModel, Operators) {
    let mesh = box_mesh(cells, [1.0, 0.1, 0.1]);
    let fem = FemModel::assemble(&mesh, scene, 1.0).expect("assembles");
    let ops = Operators::build(&mesh, scene, &fem, 1.0).expect("operators");
    (mesh, fem, ops)
}

/// Load vector of a total force `force` (N) on load group 0.
pub fn tip_load(fem: &FemModel, ops: &Operators, force: [f64; 3]) -> Vec<f64> {
    let mut f = vec![0.0; fem.dof_count()];
    for ch in ops.inputs.iter().take(3).enumerate() {
        let (c, ch) = ch;
        for (fi, b) in f.iter_mut().zip(&ch.column) {
            *fi += force[c] * b;
        }
    }
    f
}

/// Euclidean norm.
pub fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

pub fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    norm(&d) / norm(b)
}
