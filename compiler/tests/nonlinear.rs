//! The co-rotational tier (docs/design.md §10) against the full-order co-rotational reference,
//! invariants and closed forms, on small meshes.
//!
//! `cargo test -p crokf-compile --test nonlinear -- --nocapture` prints the figures.

use std::path::Path;

use crokf_compile::algorithms::nnls::nnls;
use crokf_compile::algorithms::pod::pod;
use crokf_compile::dynamics::WilsonTheta;
use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::{sparse_mul, FemModel};
use crokf_compile::mesh::procedural::box_mesh;
use crokf_compile::nonlinear::basis::{m_orthonormalise, projection_errors};
use crokf_compile::nonlinear::ecsw::{sample_elements, EcswOptions};
use crokf_compile::nonlinear::reduced::{
    HyperReducedModel, ReducedNewton, ReducedStepper, Refresh,
};
use crokf_compile::scene::Scene;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use nalgebra::{DMatrix, DVector, Rotation3, Vector3};

/// Beam scene on a generated box mesh: clamp `xmin` (unless `clamped` is false), load `tip`
/// on `xmax`. E = 1 MPa, ν = 0.3, ρ = 1000 kg/m³, α = 0.5/s, β = 1e-3 s, Δt = 5 ms, θ = 1.4.
fn scene(clamped: bool) -> Scene {
    let fixed = if clamped {
        "[[fixed]]\ngroup = \"xmin\""
    } else {
        ""
    };
    let text = format!(
        r#"
        [mesh]
        file = "generated.msh"
        [[material]]
        group = "body"
        young_modulus = 1e6
        poisson_ratio = 0.3
        density = 1000.0
        [damping]
        alpha = 0.5
        beta = 1e-3
        {fixed}
        [[load]]
        name = "tip"
        group = "xmax"
        force_model = "white"
        [time]
        dt = 5e-3
        theta = 1.4
        "#
    );
    Scene::parse(&text, Path::new("test-scene.toml")).expect("test scene parses")
}

fn model(cells: [usize; 3], clamped: bool) -> (FemModel, Operators, Scene) {
    let scene = scene(clamped);
    let mesh = box_mesh(cells, [1.0, 0.1, 0.1]);
    let fem = FemModel::assemble(&mesh, &scene, 1.0).expect("assembles");
    let ops = Operators::build(&mesh, &scene, &fem, 1.0).expect("operators");
    (fem, ops, scene)
}

/// Load vector of a total force `force` (N) on load group 0.
fn tip_load(fem: &FemModel, ops: &Operators, force: [f64; 3]) -> Vec<f64> {
    let mut f = vec![0.0; fem.dof_count()];
    for (c, ch) in ops.inputs.iter().take(3).enumerate() {
        for (fi, b) in f.iter_mut().zip(&ch.column) {
            *fi += force[c] * b;
        }
    }
    f
}

/// An M-orthonormal basis of the whole free-DOF space (unit vectors, Gram–Schmidt in M).
fn full_basis(fem: &FemModel) -> DMatrix<f64> {
    let n = fem.dof_count();
    let candidates: Vec<(String, Vec<f64>)> = (0..n)
        .map(|i| {
            let mut e = vec![0.0; n];
            e[i] = 1.0;
            (format!("e{i}"), e)
        })
        .collect();
    let b = m_orthonormalise(&fem.mass, &candidates, 1e-10, n);
    assert_eq!(b.len(), n);
    b.vectors
}

fn rel(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    d / b.iter().map(|y| y * y).sum::<f64>().sqrt()
}

#[test]
fn full_basis_with_every_element_reproduces_the_full_order_stepper() {
    let (fem, ops, scene) = model([6, 1, 1], true);
    let v = full_basis(&fem);
    let all: Vec<(usize, f64)> = (0..fem.elements.len()).map(|e| (e, 1.0)).collect();
    let reduced =
        HyperReducedModel::new(&fem, &v, &all, WilsonTheta::from(&scene.time)).expect("model");
    // M_r = VᵀMV = I.
    let eye = DMatrix::<f64>::identity(v.ncols(), v.ncols());
    assert!((&reduced.mass - eye).norm() < 1e-10);
    let newton = ReducedNewton {
        max_iterations: 30,
        tolerance: 1e-12,
        refresh: Refresh::EveryIteration,
        consistent: true,
        predictor: false,
    };
    let mut stepper = ReducedStepper::new(reduced.clone(), newton).expect("stepper");
    let mut predicted = ReducedStepper::new(
        reduced,
        ReducedNewton {
            predictor: true,
            ..newton
        },
    )
    .expect("stepper");
    let mut full = CorotationalSimulator::new(
        &fem,
        WilsonTheta::from(&scene.time),
        NewtonOptions {
            max_newton: 30,
            tolerance: 1e-12,
            consistent: true,
        },
    )
    .expect("full-order");
    let mut worst: f64 = 0.0;
    let mut tip_drop: f64 = 0.0;
    for k in 0..60 {
        // 40 N downward ramped over 20 steps: large rotation of the (stiff, locking) 6-cell beam.
        let scale = (k as f64 / 20.0).min(1.0);
        let f = tip_load(&fem, &ops, [0.0, 0.0, -40.0 * scale]);
        full.step(&f).expect("full step");
        let fr = v.tr_mul(&DVector::from_column_slice(&f));
        stepper.step(&fr).expect("reduced step");
        predicted.step(&fr).expect("reduced step (predictor)");
        let u = &v * stepper.coordinates();
        let up = &v * predicted.coordinates();
        let e = rel(u.as_slice(), full.displacement()).max(rel(up.as_slice(), full.displacement()));
        worst = worst.max(e);
        tip_drop = tip_drop.max(
            full.displacement()
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs())),
        );
    }
    println!("full basis, all elements: worst relative difference {worst:.2e} (largest |u| {tip_drop:.3} m)");
    assert!(
        tip_drop > 0.2,
        "the load must rotate the beam a lot, |u| = {tip_drop}"
    );
    assert!(worst < 1e-9, "reduced with full basis differs by {worst:e}");
}

#[test]
fn rigid_rotation_gives_no_reduced_force() {
    // Unclamped beam: a rigid rotation is representable in the full basis.
    let (fem, _, scene) = model([4, 1, 1], false);
    let v = full_basis(&fem);
    let all: Vec<(usize, f64)> = (0..fem.elements.len()).map(|e| (e, 1.0)).collect();
    let reduced =
        HyperReducedModel::new(&fem, &v, &all, WilsonTheta::from(&scene.time)).expect("model");
    let rot = Rotation3::from_axis_angle(&Vector3::y_axis(), 1.2);
    let mut u = vec![0.0; fem.dof_count()];
    let mut stretch = vec![0.0; fem.dof_count()];
    for (node, x) in fem.positions.iter().enumerate() {
        let y = rot * Vector3::from(*x);
        for c in 0..3 {
            if let Some(d) = fem.dofs.index[node][c] {
                u[d] = y[c] - x[c];
                stretch[d] = if c == 0 { 0.01 * x[0] } else { 0.0 };
            }
        }
    }
    let mu: Vec<f64> = sparse_mul(&fem.mass, &u);
    let q = v.tr_mul(&DVector::from_vec(mu));
    let ms = sparse_mul(&fem.mass, &stretch);
    let q_stretch = v.tr_mul(&DVector::from_vec(ms));
    let r = v.ncols();
    let (mut f, mut d) = (DVector::zeros(r), DVector::zeros(r));
    reduced.internal_force(&q, None, &mut f, &mut d);
    let (mut fs, mut ds) = (DVector::zeros(r), DVector::zeros(r));
    reduced.internal_force(&q_stretch, None, &mut fs, &mut ds);
    println!(
        "rigid rotation 69°: ‖f_r‖ = {:.2e} against {:.2e} for a 1 % stretch",
        f.norm(),
        fs.norm()
    );
    assert!(fs.norm() > 1.0);
    assert!(f.norm() < 1e-9 * fs.norm());
}

#[test]
fn nnls_recovers_a_sparse_non_negative_combination_and_meets_kkt() {
    // Deterministic pseudo-random 30 × 12 matrix.
    let mut seed = 12345u64;
    let mut next = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
    };
    let g = DMatrix::from_fn(30, 12, |_, _| next());
    let mut w_true = DVector::zeros(12);
    w_true[2] = 1.5;
    w_true[7] = 0.25;
    w_true[9] = 3.0;
    let b = &g * &w_true;
    let sol = nnls(&g, &b, 1e-12, 12);
    let mut w = DVector::zeros(12);
    for &(j, x) in &sol.weights {
        w[j] = x;
    }
    println!("NNLS exact case: ‖w − w*‖ = {:.2e}", (&w - &w_true).norm());
    assert!((&w - &w_true).norm() < 1e-10);
    // A target needing negative weights: the solution must satisfy KKT.
    let b2 = &g * DVector::from_fn(12, |i, _| if i % 2 == 0 { 1.0 } else { -1.0 });
    let sol = nnls(&g, &b2, 1e-14, 12);
    let mut w = DVector::zeros(12);
    for &(j, x) in &sol.weights {
        assert!(x > 0.0);
        w[j] = x;
    }
    let gradient = g.tr_mul(&(&b2 - &g * &w));
    let scale = g.norm() * b2.norm();
    for j in 0..12 {
        if w[j] > 0.0 {
            assert!(
                gradient[j].abs() < 1e-9 * scale,
                "active gradient {}",
                gradient[j]
            );
        } else {
            assert!(
                gradient[j] < 1e-9 * scale,
                "inactive gradient {}",
                gradient[j]
            );
        }
    }
    assert!(sol.relative_residual > 0.1);
}

#[test]
fn pod_of_a_rank_two_set_projects_it_exactly() {
    let (fem, ops, _) = model([4, 1, 1], true);
    let a = tip_load(&fem, &ops, [0.0, 0.0, 1.0]);
    let b = tip_load(&fem, &ops, [0.0, 1.0, 0.0]);
    let snapshots: Vec<Vec<f64>> = (0..6)
        .map(|k| {
            let (s, t) = (k as f64, (k * k) as f64 - 3.0);
            a.iter().zip(&b).map(|(x, y)| s * x + t * y).collect()
        })
        .collect();
    let (modes, values) = pod(&fem.mass, &snapshots, 5, 1e-12);
    assert_eq!(modes.len(), 2, "eigenvalues {values:?}");
    let basis = m_orthonormalise(&fem.mass, &modes, 1e-8, 5);
    let errors = projection_errors(&fem.mass, &basis, &snapshots);
    println!("POD rank-2 projection errors by size: {errors:?}");
    assert!((errors[0] - 1.0).abs() < 1e-12);
    assert!(errors[1] > 1e-3);
    assert!(errors[2] < 1e-7);
}

#[test]
fn ecsw_weights_reproduce_the_training_forces_to_the_tolerance() {
    let (fem, ops, scene) = model([8, 1, 1], true);
    // Training: a few static-ish states of the full-order model under tip loads.
    let mut full = CorotationalSimulator::new(
        &fem,
        WilsonTheta::from(&scene.time),
        NewtonOptions::default(),
    )
    .expect("full-order");
    let mut snapshots = Vec::new();
    for k in 0..40 {
        let s = (k as f64 / 10.0).min(1.0);
        full.step(&tip_load(&fem, &ops, [0.0, 0.1 * s, -0.3 * s]))
            .expect("step");
        snapshots.push(full.displacement().to_vec());
    }
    let (modes, _) = pod(&fem.mass, &snapshots, 6, 1e-14);
    let basis = m_orthonormalise(&fem.mass, &modes, 1e-8, 6);
    let options = EcswOptions {
        tolerance: 1e-3,
        max_elements: fem.elements.len(),
        max_snapshots: 40,
    };
    let sol = sample_elements(
        &fem,
        &basis.vectors,
        &basis.mass_vectors,
        &snapshots,
        &options,
    )
    .expect("ecsw");
    println!(
        "ECSW: {} of {} elements, residual {:.2e}",
        sol.weights.len(),
        fem.elements.len(),
        sol.relative_residual
    );
    assert!(sol.relative_residual <= 1e-3);
    assert!(sol.weights.len() < fem.elements.len() / 2);
    // The reduced force of the sampled model at a training state against all elements.
    let all: Vec<(usize, f64)> = (0..fem.elements.len()).map(|e| (e, 1.0)).collect();
    let exact = HyperReducedModel::new(&fem, &basis.vectors, &all, WilsonTheta::from(&scene.time))
        .expect("model");
    let sampled = HyperReducedModel::new(
        &fem,
        &basis.vectors,
        &sol.weights,
        WilsonTheta::from(&scene.time),
    )
    .expect("model");
    let q = basis.project(&snapshots[25]);
    let r = basis.len();
    let (mut fe, mut fs, mut d) = (DVector::zeros(r), DVector::zeros(r), DVector::zeros(r));
    exact.internal_force(&q, None, &mut fe, &mut d);
    sampled.internal_force(&q, None, &mut fs, &mut d);
    let e = (&fe - &fs).norm() / fe.norm();
    println!("ECSW reduced force at a training state: relative error {e:.2e}");
    assert!(e < 1e-2);
}

#[test]
fn per_run_basis_represents_every_run_to_its_tolerance() {
    use crokf_compile::nonlinear::basis::{enrich_per_run, per_run_pod};
    let (fem, ops, _) = model([6, 1, 1], true);
    // Run 0: a large bending motion (metres); run 1: a small axial one (micrometres) that the
    // pooled POD of 2 vectors ranks below both bending shapes.
    let bend_z = tip_load(&fem, &ops, [0.0, 0.0, 1.0]);
    let bend_y = tip_load(&fem, &ops, [0.0, 1.0, 0.0]);
    let axial = tip_load(&fem, &ops, [1.0, 0.0, 0.0]);
    let bend_z = crokf_compile::stepping::static_solve(&fem, &bend_z).expect("static");
    let bend_y = crokf_compile::stepping::static_solve(&fem, &bend_y).expect("static");
    let axial = crokf_compile::stepping::static_solve(&fem, &axial).expect("static");
    let mut snapshots = Vec::new();
    let mut run_of = Vec::new();
    for k in 1..=5 {
        let (s, t) = (k as f64, (k as f64 - 2.5).powi(2));
        snapshots.push(
            bend_z
                .iter()
                .zip(&bend_y)
                .map(|(a, b)| s * a + t * b)
                .collect(),
        );
        run_of.push(0);
        snapshots.push(
            axial
                .iter()
                .map(|a| 1e-3 * k as f64 * a)
                .collect::<Vec<f64>>(),
        );
        run_of.push(1);
    }
    let eps = 1e-6;
    // Independent per-run error of a basis: Σ ‖u − VVᵀMu‖²_M / Σ ‖u‖²_M over the run.
    let run_error = |v: &crokf_compile::nonlinear::basis::Basis, run: usize| {
        let (mut e, mut n) = (0.0, 0.0);
        for (u, _) in snapshots.iter().zip(&run_of).filter(|p| *p.1 == run) {
            let fit = &v.vectors * v.project(u);
            let d: Vec<f64> = u.iter().zip(fit.iter()).map(|(a, b)| a - b).collect();
            e += d
                .iter()
                .zip(sparse_mul(&fem.mass, &d))
                .map(|(a, b)| a * b)
                .sum::<f64>();
            n += u
                .iter()
                .zip(sparse_mul(&fem.mass, u))
                .map(|(a, b)| a * b)
                .sum::<f64>();
        }
        (e / n).sqrt()
    };
    let pooled = per_run_pod(&fem.mass, &snapshots, &run_of, 2, 2, 1.0, 10);
    assert_eq!(pooled.basis.len(), 2);
    assert!(run_error(&pooled.basis, 1) > 0.5, "{:?}", pooled.run_errors);
    let enriched = per_run_pod(&fem.mass, &snapshots, &run_of, 2, 2, eps, 10);
    println!(
        "per-run basis: pooled 2 → r = {}, run errors {:?} (independent: {:.1e}, {:.1e})",
        enriched.basis.len(),
        enriched.run_errors,
        run_error(&enriched.basis, 0),
        run_error(&enriched.basis, 1)
    );
    assert_eq!(enriched.basis.len(), 3, "one axial vector added");
    assert_eq!(enriched.enriched_from, vec![1]);
    for run in 0..2 {
        assert!(run_error(&enriched.basis, run) <= eps);
        // The enrichment's errors come from ‖u‖² − ‖q‖² (cheap, nested): accurate to about
        // √ε_machine ≈ 1e-8 where a run is represented exactly.
        assert!((run_error(&enriched.basis, run) - enriched.run_errors[run]).abs() < 1e-7);
    }
    // M-orthonormal, and the pooled columns are kept as they were.
    let v = &enriched.basis.vectors;
    let gram = v.tr_mul(&enriched.basis.mass_vectors);
    assert!((gram - DMatrix::identity(3, 3)).norm() < 1e-10);
    assert!((v.columns(0, 2) - &pooled.basis.vectors).norm() < 1e-12 * v.norm());
    // The energy-norm variant from the same start reaches the tolerance in K.
    let energy = enrich_per_run(
        &fem.stiffness,
        &snapshots,
        &run_of,
        2,
        m_orthonormalise(&fem.stiffness, &[], 1e-8, 0),
        eps,
        10,
    );
    assert!(energy.worst() <= eps, "{:?}", energy.run_errors);
}

#[test]
fn kernel_polar_matches_the_svd_polar_rotation() {
    use crokf_compile::stepping::{polar_rotation, polar_rotation_svd};
    use nalgebra::Matrix3;
    // The full-order element loop's rotation (the kernel's scaled Newton iteration) against
    // the SVD polar it replaced.
    let mut kernel_worst: f64 = 0.0;
    for k in 0..50 {
        let t = k as f64;
        let rot = Rotation3::from_euler_angles(0.3 * t, 1.1 - 0.05 * t, 0.7 * t.sin());
        // Stretch up to ±40 % with shear, det > 0.
        let s = Matrix3::new(
            1.0 + 0.4 * (0.7 * t).sin(),
            0.2 * (1.3 * t).cos(),
            0.1,
            0.2 * (1.3 * t).cos(),
            1.0 - 0.3 * (0.4 * t).cos(),
            -0.05 * t.sin(),
            0.1,
            -0.05 * t.sin(),
            0.8 + 0.1 * t.cos(),
        );
        let f = rot.matrix() * s;
        kernel_worst = kernel_worst.max((polar_rotation(&f) - polar_rotation_svd(&f)).norm());
    }
    println!("full-order element loop's (kernel) polar vs SVD: worst ‖ΔR‖_F {kernel_worst:.2e}");
    assert!(kernel_worst < 1e-12);
    // An inverted element falls back to the SVD rule: a proper rotation (det R = +1).
    let inverted = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -0.5);
    assert!((polar_rotation(&inverted).determinant() - 1.0).abs() < 1e-12);
}

#[test]
fn reduced_static_solve_with_the_full_basis_matches_the_full_order_static_solve() {
    let (fem, ops, scene) = model([6, 1, 1], true);
    let v = full_basis(&fem);
    let all: Vec<(usize, f64)> = (0..fem.elements.len()).map(|e| (e, 1.0)).collect();
    let reduced =
        HyperReducedModel::new(&fem, &v, &all, WilsonTheta::from(&scene.time)).expect("model");
    let mut full = CorotationalSimulator::new(
        &fem,
        WilsonTheta::from(&scene.time),
        NewtonOptions::default(),
    )
    .expect("full-order");
    let f = tip_load(&fem, &ops, [0.0, 0.0, -40.0]);
    let u = full.static_solve(&f, 1e-11).expect("full static");
    let q = reduced
        .static_solve(&v.tr_mul(&DVector::from_column_slice(&f)), 1e-11)
        .expect("reduced static");
    let ur = &v * q;
    let e = rel(ur.as_slice(), &u);
    println!("static 40 N: reduced (full basis) vs full-order {e:.2e}");
    assert!(e < 1e-9);
}
