//! Full-order steppers against closed forms, invariants and each other.
//!
//! `cargo test -p crokf-compile --test stepping -- --nocapture` prints the figures.

#[path = "support/beam.rs"]
mod beam;
use beam::{model, norm, rel_diff, scene, tip_load};

use crokf_compile::dynamics::WilsonTheta;
use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::{FemModel, TetGeometry};
use crokf_compile::stepping::{
    element_force, element_tangent, polar_rotation, static_solve, CorotationalSimulator,
    LinearSimulator, NewtonOptions, Simulator,
};
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

/// Load-weighted mean displacement of the tip face (work-conjugate to a uniform tip force).
fn tip_mean(fem: &FemModel, ops: &Operators, u: &[f64]) -> [f64; 3] {
    let nodal = fem.nodal(u);
    let mut d = [0.0; 3];
    for &(node, w) in &ops.loads[0].weights {
        for c in 0..3 {
            d[c] += w * nodal[node][c];
        }
    }
    d
}

// ---------------------------------------------------------------------------------------------
// Co-rotational element invariants

fn skewed_tet() -> [[f64; 3]; 4] {
    [
        [0.1, -0.2, 0.05],
        [1.3, 0.1, -0.1],
        [0.2, 0.9, 0.3],
        [0.4, 0.3, 1.1],
    ]
}

fn stiffness(x: &[[f64; 3]; 4]) -> (TetGeometry, [[f64; 12]; 12]) {
    let g = TetGeometry::new(x);
    let m = crokf_compile::fem::ElasticMaterial {
        young_modulus: 1e6,
        poisson_ratio: 0.3,
        density: 1000.0,
    };
    let k = g.stiffness(&m);
    (g, k)
}

fn rotate(q: &Matrix3<f64>, p: [f64; 3]) -> [f64; 3] {
    let v = q * Vector3::from(p);
    [v[0], v[1], v[2]]
}

#[test]
fn corotational_force_rotates_with_the_element_and_vanishes_for_rigid_motion() {
    let rest = skewed_tet();
    let (g, ke) = stiffness(&rest);
    let scale = ke.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    // 90° about a skew axis, plus a translation.
    let q = *Rotation3::from_axis_angle(
        &Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
        0.5 * std::f64::consts::PI,
    )
    .matrix();
    let t = [0.7, -1.1, 2.3];
    // A deformed element: 3 % stretch along x, shear, and a node pulled off.
    let grad = Matrix3::new(0.03, 0.01, 0.0, -0.02, 0.0, 0.015, 0.005, 0.0, -0.01);
    let mut x = rest;
    for a in 0..4 {
        let d = grad * Vector3::from(rest[a]);
        for i in 0..3 {
            x[a][i] += d[i];
        }
    }
    x[2][1] += 0.02;
    let (f, _) = element_force(&g, &ke, &rest, &x);
    let fnorm = norm(&f);
    assert!(
        fnorm > 1e-3 * scale,
        "deformed element has a force: {fnorm}"
    );
    let xq = x.map(|p| {
        let r = rotate(&q, p);
        [r[0] + t[0], r[1] + t[1], r[2] + t[2]]
    });
    let (fq, _) = element_force(&g, &ke, &rest, &xq);
    let mut err: f64 = 0.0;
    for a in 0..4 {
        let expected = rotate(&q, [f[3 * a], f[3 * a + 1], f[3 * a + 2]]);
        for i in 0..3 {
            err = err.max((fq[3 * a + i] - expected[i]).abs());
        }
    }
    println!("f(Qx + t) − Q f(x): max {err:.2e} N, ‖f‖ = {fnorm:.3e} N");
    assert!(err < 1e-10 * fnorm, "f(Qx) ≠ Q f(x): {err}");
    // The linear force K(x − X) of the rotated element is far from Q f(x): the test can fail.
    let u: [f64; 12] = std::array::from_fn(|k| xq[k / 3][k % 3] - rest[k / 3][k % 3] - t[k % 3]);
    let lin = crokf_compile::fem::element::mul12(&ke, &u);
    assert!(rel_diff(&lin, &fq) > 0.5);

    // Rigidly rotated undeformed element: no force.
    let xr = rest.map(|p| {
        let r = rotate(&q, p);
        [r[0] + t[0], r[1] + t[1], r[2] + t[2]]
    });
    let (fr, r) = element_force(&g, &ke, &rest, &xr);
    let worst = fr.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!("rigid 90° rotation: max |f| = {worst:.2e} N (K scale {scale:.2e} N/m)");
    assert!(
        worst < 1e-12 * scale,
        "rigid rotation makes a force: {worst}"
    );
    assert!((r - q).norm() < 1e-12, "recovered rotation {r} vs {q}");
}

#[test]
fn polar_rotation_is_proper_even_for_inverted_elements() {
    let q = *Rotation3::from_euler_angles(0.3, -1.2, 2.0).matrix();
    let s = Matrix3::new(1.2, 0.1, 0.0, 0.1, 0.8, -0.05, 0.0, -0.05, 1.05);
    let r = polar_rotation(&(q * s));
    assert!((r - q).norm() < 1e-12, "F = Q S: R = {r}, Q = {q}");
    // Inverted: reflect one axis (det F < 0).
    let inverted = q * Matrix3::new(-0.2, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.9);
    let r = polar_rotation(&inverted);
    assert!(
        (r.determinant() - 1.0).abs() < 1e-12,
        "det R = {}",
        r.determinant()
    );
    assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
    // The inverted axis is the one flipped (smallest singular value): R = Q.
    assert!((r - q).norm() < 1e-12, "R = {r}, Q = {q}");
    // Flat element (rank 2).
    let flat = q * Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
    let r = polar_rotation(&flat);
    assert!((r.determinant() - 1.0).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Static cantilever against Euler–Bernoulli + Timoshenko shear

/// Tip load P = 1 N (area-weighted over `xmax`) on a clamped 1 × 0.1 × 0.1 m beam, E = 10 MPa,
/// ν = 0.3: the load-weighted mean tip deflection approaches PL³/(3EI) + PL/(κGA), κ = 5/6, from
/// below (linear tets are stiff in bending).
#[test]
fn cantilever_tip_deflection_converges_to_beam_theory() {
    let (young, poisson) = (1.0e7, 0.3);
    let (l, a): (f64, f64) = (1.0, 0.1);
    let p = 1.0; // N, along −z
    let inertia = a.powi(4) / 12.0;
    let area = a * a;
    let shear = young / (2.0 * (1.0 + poisson));
    let bending = p * l.powi(3) / (3.0 * young * inertia);
    let shear_term = p * l / (5.0 / 6.0 * shear * area);
    let exact = bending + shear_term;
    println!(
        "cantilever 1 × 0.1 × 0.1 m, E = {young:e} Pa, ν = {poisson}, P = {p} N: \
         PL³/(3EI) = {bending:.6e} m, PL/(κGA) = {shear_term:.6e} m, total {exact:.6e} m"
    );
    let sc = scene(young, poisson, 0.0, 0.0, 1e-3);
    let mut errors = Vec::new();
    for cells in [[10, 1, 1], [20, 2, 2], [40, 4, 4], [80, 8, 8]] {
        let start = std::time::Instant::now();
        let (_, fem, ops) = model(cells, &sc);
        let f = tip_load(&fem, &ops, [0.0, 0.0, -p]);
        let u = static_solve(&fem, &f).expect("static solve");
        let tip = -tip_mean(&fem, &ops, &u)[2];
        let err = (tip - exact) / exact;
        println!(
            "  {:>2}×{}×{} cells, {:>6} tets, {:>6} DOFs: tip {tip:.6e} m, error {:+.2} % ({:.2} s)",
            cells[0],
            cells[1],
            cells[2],
            fem.elements.len(),
            fem.dof_count(),
            100.0 * err,
            start.elapsed().as_secs_f64()
        );
        errors.push(err.abs());
    }
    for w in errors.windows(2) {
        assert!(
            w[1] < w[0],
            "error does not decrease under refinement: {errors:?}"
        );
    }
    // Linear tets lock in bending: 80×8×8 is still 7 % stiff.
    assert!(
        errors[3] < 0.08,
        "finest mesh off by {:.2} %",
        100.0 * errors[3]
    );
}

// ---------------------------------------------------------------------------------------------
// End moment: the co-rotational cantilever bends into a circular arc

/// Nodal forces of a linearly varying axial traction on the `xmax` face, σ_xx ∝ −(z − z_c), scaled
/// to the end moment `moment` (N·m, about +y in the rest configuration, bending the tip to +z).
fn end_couple(fem: &FemModel, ops: &Operators, moment: f64) -> Vec<f64> {
    let zc = 0.05;
    let mut f = vec![0.0; fem.dof_count()];
    let mut m0 = 0.0;
    for &(node, w) in &ops.loads[0].weights {
        let z = fem.positions[node][2] - zc;
        let fx = -w * z;
        m0 += z * fx; // M_y = z F_x − x F_z
        if let Some(d) = fem.dofs.index[node][0] {
            f[d] += fx;
        }
    }
    // m0 < 0: compressing the top fibres turns the end towards +z (M_y < 0 in this frame).
    let scale = moment / m0.abs();
    f.iter_mut().for_each(|v| *v *= scale);
    f
}

/// Current moment about y of the x-forces `f` on the tip face, Σ z_i F_x,i (N·m).
fn current_moment(fem: &FemModel, ops: &Operators, f: &[f64], u: &[f64]) -> f64 {
    let nodal = fem.nodal(u);
    let mut m = 0.0;
    for &(node, _) in &ops.loads[0].weights {
        if let Some(d) = fem.dofs.index[node][0] {
            m += (fem.positions[node][2] + nodal[node][2]) * f[d];
        }
    }
    m.abs()
}

/// A 80×8×8-cell beam (30 720 tets, 19 440 DOFs; the static solve takes ~3 s in the dev
/// profile) under a dead end couple M₀ = 2.2 EI/L. Because the forces keep their world direction,
/// the couple's current moment M = Σ zᵢ F_x,i shrinks as the end turns (≈ M₀ cos φ); every
/// section carries the same M, so beam theory predicts an arc of radius ρ = EI/M, tip at
/// (ρ sin(L/ρ), ρ(1 − cos(L/ρ))). Linear tets lock in bending: this mesh is 7 % too stiff
/// (effective EI from a small linear end moment, ML²/(2 w_tip)), so the arc is checked with the
/// nominal EI (tolerance 5 % of L, measured 3.7 %) and with the mesh's own EI (0.5 %, measured
/// 0.15 %).
#[test]
fn corotational_end_moment_bends_into_a_circular_arc() {
    let (young, poisson) = (1.0e7, 0.3);
    let ei = young * 0.1f64.powi(4) / 12.0;
    let l = 1.0;
    let sc = scene(young, poisson, 0.0, 0.0, 1e-3);
    let (_, fem, ops) = model([80, 8, 8], &sc);
    let small = 1e-3 * ei / l;
    let u_small = static_solve(&fem, &end_couple(&fem, &ops, small)).expect("linear");
    let ei_mesh = small * l * l / (2.0 * tip_mean(&fem, &ops, &u_small)[2]);
    println!(
        "end moment, 80×8×8 cells: EI = {ei:.4e} N·m², mesh EI = {ei_mesh:.4e} N·m² (×{:.3})",
        ei_mesh / ei
    );
    let m0 = 2.2 * ei / l;
    let f = end_couple(&fem, &ops, m0);
    let wilson = WilsonTheta {
        dt: 1e-3,
        theta: 1.4,
    };
    let mut corot = CorotationalSimulator::new(&fem, wilson, NewtonOptions::default()).unwrap();
    let start = std::time::Instant::now();
    let u = corot.static_solve(&f, 1e-9).expect("co-rotational static");
    let secs = start.elapsed().as_secs_f64();
    let tip = tip_mean(&fem, &ops, &u);
    let m = current_moment(&fem, &ops, &f, &u);
    let arc_error = |stiffness: f64, tip: [f64; 3]| {
        let rho = stiffness / m;
        let phi = l / rho;
        let arc = [rho * phi.sin() - l, rho * (1.0 - phi.cos())];
        let err = ((tip[0] - arc[0]).powi(2) + (tip[2] - arc[1]).powi(2)).sqrt() / l;
        (err, phi, arc)
    };
    for (label, stiffness) in [("nominal EI", ei), ("mesh EI", ei_mesh)] {
        let (err, phi, arc) = arc_error(stiffness, tip);
        println!(
            "  {label}: M = {m:.4e} N·m (M₀ = {m0:.4e}), φ = {:.1}°: arc tip u = ({:+.4}, {:+.4}) m, \
             co-rotational ({:+.4}, {:+.4}) m, error {:.2} % of L ({secs:.1} s)",
            phi.to_degrees(),
            arc[0],
            arc[1],
            tip[0],
            tip[2],
            100.0 * err
        );
    }
    let (nominal, _, _) = arc_error(ei, tip);
    let (calibrated, phi, _) = arc_error(ei_mesh, tip);
    assert!(
        nominal < 0.05,
        "co-rotational tip {:.2} % of L off the arc",
        100.0 * nominal
    );
    assert!(
        calibrated < 0.005,
        "{:.3} % of L off the mesh-EI arc",
        100.0 * calibrated
    );
    assert!(
        phi.to_degrees() > 55.0 && phi.to_degrees() < 90.0,
        "end rotation {phi}"
    );
    // The tip moves sideways too (it shortens along x) ...
    assert!(
        tip[0] < -0.15 * l,
        "co-rotational tip does not shorten: {tip:?}"
    );
    // ... which the linear model cannot do; it is far off the arc.
    let lin = tip_mean(&fem, &ops, &static_solve(&fem, &f).unwrap());
    let (linear_error, _, _) = arc_error(ei, lin);
    println!(
        "  linear: tip u = ({:+.4}, {:+.4}) m, error {:.1} % of L",
        lin[0],
        lin[2],
        100.0 * linear_error
    );
    assert!(lin[0].abs() < 0.01 * l, "linear tip moved along x: {lin:?}");
    assert!(
        linear_error > 0.3,
        "linear model close to the arc: {linear_error}"
    );
}

#[test]
fn consistent_tangent_matches_finite_differences_and_warped_does_not() {
    let rest = skewed_tet();
    let (g, ke) = stiffness(&rest);
    let q = *Rotation3::from_euler_angles(0.4, 1.1, -0.7).matrix();
    let mut x = rest.map(|p| rotate(&q, p));
    x[1][0] += 0.08;
    x[3][2] -= 0.05;
    x[2][1] += 0.03;
    let analytic = element_tangent(&g, &ke, &rest, &x, true);
    let warped = element_tangent(&g, &ke, &rest, &x, false);
    let h = 1e-6;
    let mut fd = [[0.0; 12]; 12];
    for j in 0..12 {
        let mut xp = x;
        let mut xm = x;
        xp[j / 3][j % 3] += h;
        xm[j / 3][j % 3] -= h;
        let (fp, _) = element_force(&g, &ke, &rest, &xp);
        let (fm, _) = element_force(&g, &ke, &rest, &xm);
        for i in 0..12 {
            fd[i][j] = (fp[i] - fm[i]) / (2.0 * h);
        }
    }
    let diff = |a: &[[f64; 12]; 12]| {
        let d: f64 = (0..144)
            .map(|k| (a[k / 12][k % 12] - fd[k / 12][k % 12]).powi(2))
            .sum();
        let s: f64 = (0..144).map(|k| fd[k / 12][k % 12].powi(2)).sum();
        (d / s).sqrt()
    };
    let asym: f64 = (0..144)
        .map(|k| (analytic[k / 12][k % 12] - analytic[k % 12][k / 12]).abs())
        .fold(0.0, f64::max);
    let scale = ke.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    println!(
        "tangent vs central differences: consistent {:.2e}, warped {:.2e}; asymmetry {:.2e}",
        diff(&analytic),
        diff(&warped),
        asym / scale
    );
    assert!(
        diff(&analytic) < 1e-6,
        "consistent tangent is off: {}",
        diff(&analytic)
    );
    assert!(diff(&warped) > 1e-2, "warped tangent unexpectedly exact");
    assert!(
        asym < 1e-9 * scale,
        "consistent tangent not symmetric: {asym}"
    );
}

// ---------------------------------------------------------------------------------------------
// Dynamics

/// Dense n×n copy of a sparse matrix.
fn dense(mat: &faer::sparse::SparseColMat<usize, f64>) -> nalgebra::DMatrix<f64> {
    let mut d = nalgebra::DMatrix::zeros(mat.nrows(), mat.ncols());
    for (i, j, v) in crokf_compile::fem::sparse_entries(mat) {
        d[(i, j)] += v;
    }
    d
}

/// Largest ω (rad/s) of K φ = ω² M φ, dense.
fn highest_frequency(fem: &FemModel) -> f64 {
    let k = dense(&fem.stiffness);
    let m = dense(&fem.mass);
    let l = m.cholesky().expect("M SPD").l();
    let l_inv = l.try_inverse().unwrap();
    let a = &l_inv * k * l_inv.transpose();
    let a = (&a + a.transpose()) * 0.5;
    a.symmetric_eigenvalues().max().sqrt()
}

/// ½ U̇ᵀMU̇ + ½ UᵀKU, J.
fn energy(fem: &FemModel, sim: &dyn Simulator) -> f64 {
    let (u, v) = (sim.displacement(), sim.velocity());
    let ku = crokf_compile::fem::sparse_mul(&fem.stiffness, u);
    let mv = crokf_compile::fem::sparse_mul(&fem.mass, v);
    0.5 * (u.iter().zip(&ku).map(|(a, b)| a * b).sum::<f64>()
        + v.iter().zip(&mv).map(|(a, b)| a * b).sum::<f64>())
}

/// Undamped, θ = 1.4, Δt = 100 × the shortest period of a 6-tet mesh: a load pulse, then 10⁵
/// free steps; the energy at the end does not exceed its largest value early on. The same run
/// with θ = 1 (conditionally stable) blows up, so the check has teeth.
#[test]
fn undamped_wilson_theta_does_not_grow_far_above_the_highest_period() {
    let sc = scene(1.0e7, 0.3, 0.0, 0.0, 1.0);
    let (_, fem, ops) = model([1, 1, 1], &sc);
    let omega = highest_frequency(&fem);
    let dt = 100.0 * 2.0 * std::f64::consts::PI / omega;
    println!(
        "{} DOFs, ω_max = {omega:.4e} rad/s, Δt = {dt:.4e} s = 100 periods",
        fem.dof_count()
    );
    let pulse = tip_load(&fem, &ops, [0.0, 0.3, -1.0]);
    let zero = vec![0.0; fem.dof_count()];
    // Energies after the first free step, the largest in the first 1000, the largest in the
    // last 1000 (of `steps`), and the final one.
    let run = |theta: f64, steps: usize| -> [f64; 4] {
        let mut sim = LinearSimulator::new(&fem, WilsonTheta { dt, theta }).unwrap();
        sim.step(&pulse).unwrap();
        let mut e = [0.0; 4];
        for k in 0..steps {
            sim.step(&zero).unwrap();
            let energy = energy(&fem, &sim);
            assert!(!energy.is_nan());
            if k == 0 {
                e[0] = energy;
            }
            if k < 1000 {
                e[1] = e[1].max(energy);
            }
            if k + 1000 >= steps {
                e[2] = e[2].max(energy);
            }
            e[3] = energy;
        }
        e
    };
    let e = run(1.4, 100_000);
    println!(
        "θ = 1.4: energy after the pulse {:.3e} J, max in steps 1..1000 {:.3e} J, max in the \
         last 1000 {:.3e} J",
        e[0], e[1], e[2]
    );
    assert!(
        e[0] > 0.0 && e[2].is_finite() && e[2] <= e[1],
        "energy grew: {e:?}"
    );
    let e = run(1.0, 100);
    println!(
        "θ = 1.0: {:.3e} J after the pulse, {:.3e} J 100 steps later",
        e[0], e[3]
    );
    assert!(
        e[3] > 1e10 * e[0],
        "θ = 1 should be unstable at this Δt: {e:?}"
    );
}

/// A batch of three histories on one factor of J (a step, a sine, zero) steps each column as a
/// one-column simulator does, to rounding (the blocked solve may order sums differently), with
/// damping on so that every term of the right-hand side is exercised; the zero column stays
/// exactly at rest. A batch of zero columns is refused.
#[test]
fn a_batch_of_histories_matches_one_simulator_per_history() {
    let sc = scene(1.0e6, 0.3, 0.5, 1e-3, 0.005);
    let (_, fem, ops) = model([6, 2, 2], &sc);
    let wilson = WilsonTheta {
        dt: 0.005,
        theta: 1.4,
    };
    let n = fem.dof_count();
    let step = tip_load(&fem, &ops, [0.0, 0.3, -1.0]);
    let load = |column: usize, k: usize| -> Vec<f64> {
        match column {
            0 => step.clone(),
            1 => {
                let s = (0.07 * k as f64).sin();
                tip_load(&fem, &ops, [s, -0.5 * s, 0.2 * s])
            }
            _ => vec![0.0; n],
        }
    };
    let columns = 3;
    let mut batch = LinearSimulator::batch(&fem, wilson, columns).unwrap();
    let mut single: Vec<LinearSimulator> = (0..columns)
        .map(|_| LinearSimulator::new(&fem, wilson).unwrap())
        .collect();
    let mut worst = 0.0f64;
    for k in 0..200 {
        let f: Vec<f64> = (0..columns).flat_map(|c| load(c, k)).collect();
        batch.step(&f).unwrap();
        for (c, sim) in single.iter_mut().enumerate() {
            sim.step(&load(c, k)).unwrap();
            let got = &batch.displacement()[c * n..(c + 1) * n];
            if c == 2 {
                assert!(got.iter().all(|&v| v == 0.0), "the zero history moved");
            } else {
                worst = worst.max(rel_diff(got, sim.displacement()));
            }
        }
    }
    println!("batch of {columns} vs one simulator each: worst relative difference {worst:.2e}");
    assert!(worst < 1e-12, "{worst:e}");
    assert!(norm(&batch.displacement()[..n]) > 0.0);
    assert!(
        batch.step(&vec![0.0; n]).is_err(),
        "a one-column load was taken"
    );
    assert!(LinearSimulator::batch(&fem, wilson, 0).is_err());
}
