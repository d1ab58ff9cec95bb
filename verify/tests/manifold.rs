//! The manifold Galerkin driver (`crokf_verify::nonlinear::manifold`) against independent
//! steppers on small beams swung by a tip load:
//!
//! - on the whole space (V = every DOF, W = 0) it is the full-order co-rotational Wilson-θ
//!   step (`CorotationalSimulator::step`, full Newton);
//! - on a linear basis (W = 0) it is the reduced Galerkin stepper on every element at weight 1
//!   (`ReducedStepper`);
//! - on a quadratic manifold fitted to the run's own states over the same basis it is closer
//!   to the full-order run than the linear Galerkin run (measured: 6.6e-4 against 3.8e-3 at
//!   r = 4).

use std::path::PathBuf;

use nalgebra::{DMatrix, DVector};

use crokf_compile::algorithms::pod::pod;
use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::nonlinear::basis::m_orthonormalise;
use crokf_compile::nonlinear::manifold::{product_count, QuadraticManifold};
use crokf_compile::nonlinear::reduced::{
    HyperReducedModel, ReducedNewton, ReducedStepper, Refresh,
};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use crokf_compile::FullOrder;
use crokf_verify::nonlinear::manifold::{galerkin_run, History};

/// A cells × 1 × 1 beam of length 0.1 m per cell, its scene built once per call.
fn beam(cells: usize, name: &str) -> FullOrder {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("crokf-manifold-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_msh22(
        &box_mesh([cells, 1, 1], [0.1 * cells as f64, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .unwrap();
    let length = 0.1 * cells as f64;
    let text = BeamScene {
        sensors: vec![("tip".into(), [length, 0.05, 0.1])],
        displays: Vec::new(),
        dt: 5e-3,
        ..BeamScene::default()
    }
    .toml();
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    FullOrder::build(&dir.join("scene.toml"), &mut StageTimer::default()).unwrap()
}

/// The tip −z load ramped to `peak` N over 40 steps, then held: `steps` load vectors.
fn loads(full: &FullOrder, peak: f64, steps: usize) -> Vec<Vec<f64>> {
    let n = full.fem.dof_count();
    let column = &full.operators.inputs[2].column;
    assert_eq!(column.len(), n);
    (1..=steps)
        .map(|k| {
            let m = -peak * (k as f64 / 40.0).min(1.0);
            column.iter().map(|c| m * c).collect()
        })
        .collect()
}

fn linear(basis: &crokf_compile::nonlinear::basis::Basis) -> QuadraticManifold {
    let (n, r) = (basis.vectors.nrows(), basis.len());
    QuadraticManifold {
        vectors: basis.vectors.clone(),
        mass_vectors: basis.mass_vectors.clone(),
        quadratic: DMatrix::zeros(n, product_count(r)),
        scales: vec![1e-3; r],
    }
}

fn relative(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let (mut e, mut s) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for (p, q) in x.iter().zip(y) {
            e += (p - q).powi(2);
            s += q * q;
        }
    }
    (e / s).sqrt()
}

#[test]
fn on_the_whole_space_it_is_the_full_order_step() {
    let full = beam(2, "whole");
    let n = full.fem.dof_count();
    let f = loads(&full, 300.0, 50);
    let mut sim = CorotationalSimulator::new(
        &full.fem,
        full.wilson,
        NewtonOptions {
            tolerance: 1e-13,
            ..NewtonOptions::default()
        },
    )
    .unwrap();
    let mut exact = Vec::new();
    for fk in &f {
        sim.step(fk).unwrap();
        exact.push(sim.displacement().to_vec());
    }
    let unit: Vec<(String, Vec<f64>)> = (0..n)
        .map(|i| {
            let mut e = vec![0.0; n];
            e[i] = 1.0;
            (format!("e{i}"), e)
        })
        .collect();
    let whole = m_orthonormalise(&full.fem.mass, &unit, 1e-12, n);
    assert_eq!(whole.len(), n);
    let tip = exact
        .last()
        .unwrap()
        .iter()
        .fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(tip > 0.02, "a large swing expected, {tip}");
    for history in [History::FullOrder, History::Coordinates] {
        let run = galerkin_run(&full, &linear(&whole), &f, 1e-13, 30, history).unwrap();
        let gap = relative(&run.states, &exact);
        eprintln!("whole space, {history:?}: gap {gap:.2e} (largest displacement {tip:.3} m)");
        assert!(gap < 1e-9, "{history:?}: {gap:e}");
    }
}

#[test]
fn on_a_linear_basis_it_is_the_reduced_galerkin_stepper_and_a_fitted_manifold_does_better() {
    let full = beam(4, "basis");
    let f = loads(&full, 200.0, 80);
    let mut sim =
        CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default()).unwrap();
    let mut exact = Vec::new();
    for fk in &f {
        sim.step(fk).unwrap();
        exact.push(sim.displacement().to_vec());
    }
    let (modes, _) = pod(&full.fem.mass, &exact, 4, 1e-14);
    let basis = m_orthonormalise(&full.fem.mass, &modes, 1e-10, 4);
    let r = basis.len();
    assert_eq!(r, 4);
    // The reduced stepper on every element at weight 1.
    let all: Vec<(usize, f64)> = (0..full.fem.elements.len()).map(|e| (e, 1.0)).collect();
    let model = HyperReducedModel::new(&full.fem, &basis.vectors, &all, full.wilson).unwrap();
    let mut stepper = ReducedStepper::new(
        model,
        ReducedNewton {
            max_iterations: 60,
            tolerance: 1e-12,
            refresh: Refresh::WhenSlow { iterations: 4 },
            consistent: true,
            predictor: true,
        },
    )
    .unwrap();
    let mut reduced = Vec::new();
    for fk in &f {
        let load = basis.vectors.tr_mul(&DVector::from_column_slice(fk));
        stepper.step(&load).unwrap();
        reduced.push(
            (&basis.vectors * stepper.coordinates())
                .iter()
                .copied()
                .collect(),
        );
    }
    let linear_error = relative(&reduced, &exact);
    assert!(
        linear_error > 1e-3,
        "the linear basis should miss: {linear_error:e}"
    );
    // The manifold fitted to the run's own states.
    let manifold = QuadraticManifold::fit(&basis, &exact, 1e-8).unwrap();
    for history in [History::FullOrder, History::Coordinates] {
        let on_basis = galerkin_run(&full, &linear(&basis), &f, 1e-12, 30, history).unwrap();
        let gap = relative(&on_basis.states, &reduced);
        let curved = galerkin_run(&full, &manifold, &f, 1e-12, 30, history).unwrap();
        let curved_error = relative(&curved.states, &exact);
        eprintln!(
            "r = {r}, {history:?}: driver against the reduced stepper {gap:.2e}; error against \
             the full order: linear {linear_error:.2e}, quadratic {curved_error:.2e}"
        );
        assert!(gap < 1e-8, "{history:?}: {gap:e}");
        assert!(
            curved_error < 0.5 * linear_error,
            "{history:?}: {curved_error:e}"
        );
    }
}
