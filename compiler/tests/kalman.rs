//! Kalman stage: DARE against closed forms and independent recursions, hard cases, a filtered
//! simulation with a consistency (NIS) check, and multi-rate periodic gains against brute force.

use crokf_compile::algorithms::kalman::{
    output_standard_deviations, periodic_gains, solve_filter_dare, DareSolution, KalmanError,
};
use crokf_compile::dynamics::WilsonTheta;
use faer::linalg::solvers::Solve;
use faer::{Mat, MatRef, Side};

// ----------------------------------------------------------------------------------------------
// Helpers (independent of the code under test).

/// xorshift64* with Box–Muller normals.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(seed.max(1))
    }
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in (0, 1).
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
    fn matrix(&mut self, rows: usize, cols: usize) -> Mat<f64> {
        Mat::from_fn(rows, cols, |_, _| self.normal())
    }
}

fn from_rows(rows: &[&[f64]]) -> Mat<f64> {
    Mat::from_fn(rows.len(), rows[0].len(), |i, j| rows[i][j])
}

fn diag(d: &[f64]) -> Mat<f64> {
    Mat::from_fn(d.len(), d.len(), |i, j| if i == j { d[i] } else { 0.0 })
}

fn spectral_radius(m: MatRef<f64>) -> f64 {
    m.eigenvalues()
        .unwrap()
        .iter()
        .map(|l| l.re.hypot(l.im))
        .fold(0.0, f64::max)
}

/// Random F with spectral radius exactly `rho`.
fn random_stable(rng: &mut Rng, n: usize, rho: f64) -> Mat<f64> {
    let a = rng.matrix(n, n);
    let s = rho / spectral_radius(a.as_ref());
    Mat::from_fn(n, n, |i, j| s * a[(i, j)])
}

/// Random PSD of rank k: B Bᵀ, B n×k.
fn random_psd(rng: &mut Rng, n: usize, k: usize) -> Mat<f64> {
    let b = rng.matrix(n, k);
    &b * b.transpose()
}

fn rel_diff(a: MatRef<f64>, b: MatRef<f64>) -> f64 {
    let d = Mat::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)] - b[(i, j)]);
    d.norm_l2() / a.norm_l2().max(b.norm_l2()).max(f64::MIN_POSITIVE)
}

/// The DARE residual in the textbook form, computed here from scratch:
/// ‖F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q − P‖_F / max(‖P‖_F, ‖Q‖_F).
fn dare_residual(f: &Mat<f64>, h: &Mat<f64>, q: &Mat<f64>, r: &Mat<f64>, p: &Mat<f64>) -> f64 {
    let fp = f * p;
    let s = h * p * h.transpose() + r;
    let hpft = h * fp.transpose();
    let corr = fp.as_ref() * h.transpose() * s.partial_piv_lu().solve(&hpft);
    let res = &fp * f.transpose() - corr + q - p;
    res.norm_l2() / p.norm_l2().max(q.norm_l2()).max(f64::MIN_POSITIVE)
}

/// Checks the relations between the returned fields, independently recomputed.
fn check_consistency(sol: &DareSolution, f: &Mat<f64>, h: &Mat<f64>, r: &Mat<f64>, tol: f64) {
    let p = &sol.prior_covariance;
    let n = p.nrows();
    let s = h * p * h.transpose() + r;
    let k = (s.partial_piv_lu().solve(h * p)).transpose().to_owned();
    assert!(rel_diff(k.as_ref(), sol.gain.as_ref()) < tol, "gain");
    let post = (Mat::<f64>::identity(n, n) - &k * h) * p;
    assert!(
        rel_diff(post.as_ref(), sol.posterior_covariance.as_ref()) < tol,
        "posterior {}",
        rel_diff(post.as_ref(), sol.posterior_covariance.as_ref())
    );
    let closed = (Mat::<f64>::identity(n, n) - &k * h) * f;
    let rho = spectral_radius(closed.as_ref());
    assert!(
        (rho - sol.closed_loop_spectral_radius).abs() < 1e-8,
        "ρ {rho} vs {}",
        sol.closed_loop_spectral_radius
    );
    assert!(rho < 1.0);
    // Symmetry.
    for i in 0..n {
        for j in 0..n {
            assert_eq!(p[(i, j)], p[(j, i)]);
        }
    }
}

/// Scalar DARE closed form: h² P² + (r(1 − f²) − q h²) P − q r = 0, the non-negative root,
/// evaluated without cancellation.
fn scalar_dare(f: f64, h: f64, q: f64, r: f64) -> f64 {
    // 1 − f² as (1 − f)(1 + f): exact for f near 1.
    let b = r * ((1.0 - f) * (1.0 + f)) - q * h * h;
    let disc = (b * b + 4.0 * h * h * q * r).sqrt();
    if b > 0.0 {
        2.0 * q * r / (b + disc)
    } else {
        (-b + disc) / (2.0 * h * h)
    }
}

fn scalar(v: f64) -> Mat<f64> {
    Mat::from_fn(1, 1, |_, _| v)
}

// ----------------------------------------------------------------------------------------------
// Closed forms and independent computations.

#[test]
fn scalar_dare_matches_quadratic_formula() {
    let cases = [
        (0.5, 1.0, 1.0, 1.0),
        (-0.9, 2.0, 0.3, 5.0),
        (0.999999, 1.0, 1e-4, 1e-2),
        (0.999999, 0.1, 1e-10, 1.0),
        (0.999999, 1.0, 1.0, 1e-16),
        (0.2, 3.0, 1e6, 1e-3),
        (1.5, 1.0, 1.0, 1.0), // unstable but detectable and stabilizable
        (-1.2, 0.5, 2.0, 0.1),
    ];
    for (f, h, q, r) in cases {
        let sol = solve_filter_dare(
            scalar(f).as_ref(),
            scalar(h).as_ref(),
            scalar(q).as_ref(),
            scalar(r).as_ref(),
        )
        .unwrap_or_else(|e| panic!("({f}, {h}, {q}, {r}): {e}"));
        let p = scalar_dare(f, h, q, r);
        let k = p * h / (h * h * p + r);
        let post = p * r / (h * h * p + r);
        // Forward error bound: rounding of f (relative 1e-16) moves 1 − f² by 1e-16/(1 − |f|)
        // relative, so a backward-stable solver is accurate to about that near |f| = 1.
        let tol = 1e-12f64.max(4e-16 / (1.0 - f.abs()).abs());
        let got = sol.prior_covariance[(0, 0)];
        let err = (got - p).abs() / p;
        assert!(
            err <= tol,
            "({f},{h},{q},{r}): P {got} vs {p}: {err:e} > {tol:e}"
        );
        assert!((sol.gain[(0, 0)] - k).abs() <= 10.0 * tol * k.abs(), "K");
        let gpost = sol.posterior_covariance[(0, 0)];
        assert!(
            (gpost - post).abs() <= 100.0 * tol * post,
            "P+ {gpost} vs {post}"
        );
        let rho = (f * (1.0 - k * h)).abs();
        assert!((sol.closed_loop_spectral_radius - rho).abs() < 1e-12);
        assert!(sol.relative_residual <= 1e-13, "{}", sol.relative_residual);
        assert!(sol.iterations >= 1 && sol.iterations < 100);
    }
}

#[test]
fn scalar_without_sensors_is_the_lyapunov_solution() {
    let (f, q) = (0.999999, 3e-3);
    let sol = solve_filter_dare(
        scalar(f).as_ref(),
        Mat::<f64>::zeros(0, 1).as_ref(),
        scalar(q).as_ref(),
        Mat::<f64>::zeros(0, 0).as_ref(),
    )
    .unwrap();
    let p = q / (1.0 - f * f);
    assert!((sol.prior_covariance[(0, 0)] - p).abs() <= 1e-9 * p);
    assert_eq!(sol.gain.ncols(), 0);
    assert_eq!(sol.condition, 1.0);
    assert!((sol.closed_loop_spectral_radius - f).abs() < 1e-15);
}

/// Runs P ← F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q on explicit 2×2 arrays until it stops
/// changing: an independent reference for small systems.
fn iterate_riccati_2x2(f: [[f64; 2]; 2], h: [f64; 2], q: [[f64; 2]; 2], r: f64) -> [[f64; 2]; 2] {
    let mut p = q;
    for _ in 0..1_000_000 {
        // PHᵀ, S = H P Hᵀ + r, posterior = P − PHᵀ HP / S.
        let ph = [
            p[0][0] * h[0] + p[0][1] * h[1],
            p[1][0] * h[0] + p[1][1] * h[1],
        ];
        let s = h[0] * ph[0] + h[1] * ph[1] + r;
        let mut post = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                post[i][j] = p[i][j] - ph[i] * ph[j] / s;
            }
        }
        let mut next = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                let mut acc = q[i][j];
                for k in 0..2 {
                    for l in 0..2 {
                        acc += f[i][k] * post[k][l] * f[j][l];
                    }
                }
                next[i][j] = acc;
            }
        }
        let change: f64 = (0..4)
            .map(|t| (next[t / 2][t % 2] - p[t / 2][t % 2]).abs())
            .sum();
        p = next;
        if change <= 1e-17 * p.iter().flatten().map(|v| v.abs()).sum::<f64>() {
            break;
        }
    }
    p
}

#[test]
fn two_state_dare_matches_iterated_recursion() {
    // A damped oscillator sampled at Δt = 0.05 s (ω = 2π, ζ = 0.1) measured in position, and
    // an unstable (|λ| > 1) detectable and stabilizable case.
    let cases = [
        (
            [[0.9516, 0.0473], [-1.8671, 0.8918]],
            [1.0, 0.0],
            [[1e-4, 2e-5], [2e-5, 4e-3]],
            1e-3,
        ),
        (
            [[1.05, 0.1], [0.0, 0.7]],
            [0.3, 1.0],
            [[0.5, 0.0], [0.0, 0.0]],
            0.2,
        ),
    ];
    for (f, h, q, r) in cases {
        let reference = iterate_riccati_2x2(f, h, q, r);
        let fm = from_rows(&[&f[0], &f[1]]);
        let hm = from_rows(&[&h]);
        let qm = from_rows(&[&q[0], &q[1]]);
        let rm = scalar(r);
        let sol = solve_filter_dare(fm.as_ref(), hm.as_ref(), qm.as_ref(), rm.as_ref()).unwrap();
        let refm = from_rows(&[&reference[0], &reference[1]]);
        let d = rel_diff(refm.as_ref(), sol.prior_covariance.as_ref());
        assert!(d < 1e-12, "P differs from the iterated recursion by {d}");
        assert!(dare_residual(&fm, &hm, &qm, &rm, &sol.prior_covariance) < 1e-13);
        check_consistency(&sol, &fm, &hm, &rm, 1e-12);
    }
}

#[test]
fn random_stable_twenty_state_systems() {
    let mut rng = Rng::new(20);
    for (trial, (rho, m, rank_q)) in [(0.95, 5, 3), (0.5, 2, 20), (0.999, 8, 1), (0.99, 1, 4)]
        .into_iter()
        .enumerate()
    {
        let n = 20;
        let f = random_stable(&mut rng, n, rho);
        let h = rng.matrix(m, n);
        let q = random_psd(&mut rng, n, rank_q);
        let r = diag(&(0..m).map(|_| 0.1 + rng.uniform()).collect::<Vec<_>>());
        let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref()).unwrap();
        let res = dare_residual(&f, &h, &q, &r, &sol.prior_covariance);
        assert!(res <= 1e-10, "trial {trial}: residual {res}");
        assert!(sol.relative_residual <= 1e-10);
        assert!(sol.closed_loop_spectral_radius < 1.0);
        check_consistency(&sol, &f, &h, &r, 1e-9);
        // P is PSD and at most the open-loop (no sensor) covariance along any direction.
        let ev = sol
            .prior_covariance
            .self_adjoint_eigenvalues(Side::Lower)
            .unwrap();
        assert!(
            ev[0] >= -1e-10 * ev[n - 1],
            "trial {trial}: λ_min(P) = {}",
            ev[0]
        );
        assert!(sol.condition >= 1.0 && sol.condition.is_finite());
    }
}

// ----------------------------------------------------------------------------------------------
// Hard cases.

/// Block-diagonal F of damped rotations ρ_i [[cos θ_i, −sin θ_i], [sin θ_i, cos θ_i]].
fn rotation_blocks(blocks: &[(f64, f64)]) -> Mat<f64> {
    let n = 2 * blocks.len();
    Mat::from_fn(n, n, |i, j| {
        if i / 2 != j / 2 {
            return 0.0;
        }
        let (rho, th) = blocks[i / 2];
        let (c, s) = (th.cos(), th.sin());
        rho * match (i % 2, j % 2) {
            (0, 0) | (1, 1) => c,
            (0, 1) => -s,
            _ => s,
        }
    })
}

#[test]
fn eigenvalues_within_1e6_of_unit_circle_and_unobservable_mode() {
    // Δt = 1e-4 s, light damping: |λ| = 1 − 1e-6 … 1 − 4e-6. Block 3 is seen by no sensor:
    // its P is the open-loop Lyapunov solution q/(1 − ρ²) I (rotations preserve I).
    let blocks = [
        (1.0 - 1e-6, 2.0 * std::f64::consts::PI * 10.0 * 1e-4),
        (1.0 - 2e-6, 2.0 * std::f64::consts::PI * 37.0 * 1e-4),
        (1.0 - 4e-6, 2.0 * std::f64::consts::PI * 55.0 * 1e-4),
    ];
    let f = rotation_blocks(&blocks);
    let h = from_rows(&[
        &[1.0, 0.0, 0.5, 0.0, 0.0, 0.0],
        &[0.0, 0.0, 1.0, 0.2, 0.0, 0.0],
    ]);
    let qd = [1e-6, 1e-6, 2e-6, 2e-6, 3e-6, 3e-6];
    let q = diag(&qd);
    let r = diag(&[1e-4, 4e-4]);
    let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref()).unwrap();
    let res = dare_residual(&f, &h, &q, &r, &sol.prior_covariance);
    assert!(res <= 1e-10, "residual {res}");
    let rho3 = blocks[2].0;
    let lyap = qd[4] / (1.0 - rho3 * rho3);
    let p = &sol.prior_covariance;
    for (i, j, want) in [
        (4, 4, lyap),
        (5, 5, lyap),
        (4, 5, 0.0),
        (0, 4, 0.0),
        (2, 5, 0.0),
    ] {
        assert!(
            (p[(i, j)] - want).abs() <= 1e-9 * lyap,
            "P[{i},{j}] = {} vs {want}",
            p[(i, j)]
        );
    }
    // The unobservable mode keeps its open-loop radius in the closed loop.
    assert!((sol.closed_loop_spectral_radius - rho3).abs() < 1e-9);
    // The observed blocks are genuinely filtered: far below their open-loop variance.
    let open = qd[0] / (1.0 - blocks[0].0 * blocks[0].0);
    assert!(p[(0, 0)] < 0.01 * open, "{} vs {open}", p[(0, 0)]);
    check_consistency(&sol, &f, &h, &r, 1e-8);
}

#[test]
fn tiny_and_huge_measurement_noise() {
    let mut rng = Rng::new(7);
    let n = 6;
    let f = random_stable(&mut rng, n, 0.98);
    let h = rng.matrix(2, n);
    let q = random_psd(&mut rng, n, n);
    for (sigma2, tol) in [(1e-16, 1e-10), (1e6, 1e-10)] {
        let r = diag(&[sigma2, sigma2]);
        let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref())
            .unwrap_or_else(|e| panic!("R = {sigma2}: {e}"));
        let res = dare_residual(&f, &h, &q, &r, &sol.prior_covariance);
        assert!(res <= tol, "R = {sigma2} I: residual {res}");
        assert!(sol.closed_loop_spectral_radius < 1.0);
        let post = &sol.posterior_covariance;
        if sigma2 < 1.0 {
            // Near-perfect sensors: the measured combinations are known after the update,
            // H P⁺ Hᵀ ≈ R, and the gain is a right inverse of H on the innovations: H K ≈ I.
            let hph = &h * post * h.transpose();
            assert!(hph.norm_l2() < 1e-12 * q.norm_l2(), "{}", hph.norm_l2());
            let hk = &h * &sol.gain;
            assert!(rel_diff(hk.as_ref(), Mat::<f64>::identity(2, 2).as_ref()) < 1e-8);
        } else {
            // Useless sensors: P approaches the open-loop Lyapunov solution X = F X Fᵀ + Q,
            // here from the Kronecker form (I − F ⊗ F) vec X = vec Q, with a deviation and a
            // gain that shrink like 1/R (first-order perturbation).
            let nn = n * n;
            let kron = Mat::from_fn(nn, nn, |a, b| {
                let (i, j, k, l) = (a / n, a % n, b / n, b % n);
                f64::from(u8::from(a == b)) - f[(i, k)] * f[(j, l)]
            });
            let vq = Mat::from_fn(nn, 1, |a, _| q[(a / n, a % n)]);
            let vx = kron.partial_piv_lu().solve(&vq);
            let x = Mat::from_fn(n, n, |i, j| vx[(i * n + j, 0)]);
            let no_sensor = solve_filter_dare(
                f.as_ref(),
                Mat::<f64>::zeros(0, n).as_ref(),
                q.as_ref(),
                Mat::<f64>::zeros(0, 0).as_ref(),
            )
            .unwrap();
            assert!(rel_diff(x.as_ref(), no_sensor.prior_covariance.as_ref()) < 1e-12);
            let d6 = rel_diff(x.as_ref(), sol.prior_covariance.as_ref());
            let r7 = diag(&[10.0 * sigma2, 10.0 * sigma2]);
            let sol7 = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r7.as_ref()).unwrap();
            let d7 = rel_diff(x.as_ref(), sol7.prior_covariance.as_ref());
            assert!(
                (d6 / d7 - 10.0).abs() < 0.5,
                "deviation {d6:e} at R, {d7:e} at 10 R"
            );
            let k_ratio = sol.gain.norm_l2() / sol7.gain.norm_l2();
            assert!((k_ratio - 10.0).abs() < 0.5, "‖K(R)‖/‖K(10R)‖ = {k_ratio}");
        }
    }
}

#[test]
fn near_perfect_sensors_on_twenty_states() {
    // R = 1e-16 I with as many sensors as noise channels (Q of rank 5): I + G H in the
    // doubling has condition ~ 1e16 and plain SDA lands on a non-stabilizing solution; the
    // solver must still return the stabilizing one (via its fallback routes).
    let mut rng = Rng::new(42);
    let n = 20;
    for rho in [0.95, 0.999999] {
        let f = random_stable(&mut rng, n, rho);
        let h = rng.matrix(5, n);
        let q = random_psd(&mut rng, n, 5);
        let r = diag(&[1e-16; 5]);
        let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref())
            .unwrap_or_else(|e| panic!("ρ(F) = {rho}: {e}"));
        let res = dare_residual(&f, &h, &q, &r, &sol.prior_covariance);
        assert!(res <= 1e-10, "ρ(F) = {rho}: residual {res}");
        let closed = (Mat::<f64>::identity(n, n) - &sol.gain * &h) * &f;
        let rho_cl = spectral_radius(closed.as_ref());
        assert!(rho_cl < 1.0, "ρ(F) = {rho}: closed loop {rho_cl}");
    }
}

#[test]
fn zero_process_noise_gives_zero_covariance_and_gain() {
    let mut rng = Rng::new(3);
    let n = 5;
    let f = random_stable(&mut rng, n, 0.9);
    let h = rng.matrix(2, n);
    let sol = solve_filter_dare(
        f.as_ref(),
        h.as_ref(),
        Mat::<f64>::zeros(n, n).as_ref(),
        diag(&[1.0, 2.0]).as_ref(),
    )
    .unwrap();
    assert_eq!(sol.prior_covariance.norm_max(), 0.0);
    assert_eq!(sol.gain.norm_max(), 0.0);
    assert_eq!(sol.posterior_covariance.norm_max(), 0.0);
    assert_eq!(sol.relative_residual, 0.0);
    assert!((sol.closed_loop_spectral_radius - 0.9).abs() < 1e-12);
}

fn expect_err(f: &Mat<f64>, h: &Mat<f64>, q: &Mat<f64>, r: &Mat<f64>) -> (KalmanError, String) {
    match solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref()) {
        Ok(sol) => panic!(
            "expected an error, got P = {:?}",
            sol.prior_covariance.as_ref()
        ),
        Err(e) => {
            let msg = e.to_string();
            (e, msg)
        }
    }
}

#[test]
fn unobservable_unstable_mode_is_refused() {
    // Mode 2 (λ = 1.01) is invisible to the sensor.
    let f = from_rows(&[&[0.5, 0.1, 0.0], &[0.0, 0.3, 0.0], &[0.0, 0.0, 1.01]]);
    let h = from_rows(&[&[1.0, 1.0, 0.0]]);
    let q = diag(&[1.0, 1.0, 1.0]);
    let (e, msg) = expect_err(&f, &h, &q, &scalar(0.1));
    assert!(matches!(e, KalmanError::Undetectable { .. }), "{msg}");
    assert!(
        msg.contains("undetectable") && msg.contains("1.01"),
        "{msg}"
    );
    // An undetectable mode exactly on the unit circle (a rigid-body mode) too.
    let f = from_rows(&[&[1.0, 0.0], &[0.0, 0.5]]);
    let h = from_rows(&[&[0.0, 1.0]]);
    let (e, msg) = expect_err(&f, &h, &diag(&[1.0, 1.0]), &scalar(0.1));
    assert!(matches!(e, KalmanError::Undetectable { .. }), "{msg}");
}

/// Two modes (frequencies in Hz, ζ = 2 %) in Wilson-θ form (θ = 1.4, step `dt` s): the
/// transition F (6×6, state [q, q̇, q̈] per mode) and the force input Γ (6×2, one force per mode).
fn two_modes(dt: f64, hz: [f64; 2]) -> (Mat<f64>, Mat<f64>) {
    let wt = WilsonTheta { dt, theta: 1.4 };
    let mut f = Mat::<f64>::zeros(6, 6);
    let mut gam = Mat::<f64>::zeros(6, 2);
    for (mode, hz) in hz.into_iter().enumerate() {
        let w = 2.0 * std::f64::consts::PI * hz;
        let (phi, g) = wt.modal_block(w * w, 2.0 * 0.02 * w);
        for i in 0..3 {
            for j in 0..3 {
                f[(3 * mode + i, 3 * mode + j)] = phi[i][j];
            }
            gam[(3 * mode + i, mode)] = g[i];
        }
    }
    (f, gam)
}

#[test]
fn rigid_body_mode_needs_a_position_sensor() {
    // No Dirichlet nodes: a rigid-body mode (k = c = 0, eigenvalue 1 of Wilson-θ, defective)
    // next to a 13 Hz mode, force noise on both. A position sensor makes the data detectable;
    // a velocity-only sensor cannot see the position drift (eigenvector [1, 0, 0]).
    let (f, gam) = two_modes(1e-3, [0.0, 13.0]);
    let q = &gam * gam.transpose();
    let r = diag(&[1e-8]);
    let h = from_rows(&[&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]]);
    let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref()).unwrap();
    assert!(dare_residual(&f, &h, &q, &r, &sol.prior_covariance) < 1e-12);
    check_consistency(&sol, &f, &h, &r, 1e-9);
    let h = from_rows(&[&[0.0, 1.0, 0.0, 1.0, 0.0, 0.0]]);
    let (e, msg) = expect_err(&f, &h, &q, &r);
    assert!(matches!(e, KalmanError::Undetectable { .. }), "{msg}");
    assert!(msg.contains("|λ| = 1.000000000000"), "{msg}");
}

#[test]
fn unexcited_unstable_mode_is_refused() {
    // Seen but never excited: λ = 1.2 with Q zero on that mode.
    let f = from_rows(&[&[1.2, 0.0], &[0.0, 0.5]]);
    let h = from_rows(&[&[1.0, 1.0]]);
    let (e, msg) = expect_err(&f, &h, &diag(&[0.0, 1.0]), &scalar(0.1));
    assert!(matches!(e, KalmanError::Unstabilizable { .. }), "{msg}");
    assert!(
        msg.contains("unstabilizable") && msg.contains("process noise"),
        "{msg}"
    );
}

#[test]
fn bad_measurement_noise_is_refused_with_its_row() {
    let f = diag(&[0.5, 0.6]);
    let h = diag(&[1.0, 1.0]);
    let q = diag(&[1.0, 1.0]);
    for bad in [0.0, -1e-3] {
        let (e, msg) = expect_err(&f, &h, &q, &diag(&[1.0, bad]));
        assert!(
            matches!(e, KalmanError::RDiagonalNotPositive { index: 1, .. }),
            "{msg}"
        );
        assert!(
            msg.contains("R[1,1]") && msg.contains("measurement row 1"),
            "{msg}"
        );
    }
    // Positive diagonal, indefinite matrix.
    let (e, msg) = expect_err(&f, &h, &q, &from_rows(&[&[1.0, 2.0], &[2.0, 1.0]]));
    assert!(
        matches!(e, KalmanError::RNotPositiveDefinite { .. }),
        "{msg}"
    );
    assert!(msg.contains("smallest eigenvalue -1"), "{msg}");
    // Asymmetric R.
    let (_, msg) = expect_err(&f, &h, &q, &from_rows(&[&[1.0, 0.1], &[0.0, 1.0]]));
    assert!(msg.contains("R is not symmetric"), "{msg}");
}

#[test]
fn malformed_inputs_are_refused() {
    let f = diag(&[0.5, 0.6]);
    let h = diag(&[1.0, 1.0]);
    let q = diag(&[1.0, 1.0]);
    let r = diag(&[1.0, 1.0]);
    let mut fnan = f.clone();
    fnan[(1, 0)] = f64::NAN;
    let (_, msg) = expect_err(&fnan, &h, &q, &r);
    assert!(msg.contains("F[1,0] = NaN is not finite"), "{msg}");
    let (_, msg) = expect_err(&f, &h, &q, &diag(&[1.0]));
    assert!(msg.contains("R is 1x1, expected 2x2"), "{msg}");
    let (e, msg) = expect_err(&f, &h, &diag(&[1.0, -1.0]), &r);
    assert!(
        matches!(e, KalmanError::QNotPositiveSemidefinite { .. }),
        "{msg}"
    );
}

// ----------------------------------------------------------------------------------------------
// A filtered run.

#[test]
fn filtered_run_beats_open_loop_and_innovations_are_consistent() {
    // Two lightly damped modes (5 Hz, 13 Hz, ζ = 2 %) in Wilson-θ form, state [q, q̇, q̈] per
    // mode, Δt = 2 ms, force noise on each mode (Q singular: rank 2), two position sensors.
    let (f, gam) = two_modes(2e-3, [5.0, 13.0]);
    let n = f.nrows();
    let sigma_force = [3.0f64, 5.0];
    let q = &gam * diag(&[sigma_force[0].powi(2), sigma_force[1].powi(2)]) * gam.transpose();
    let h = from_rows(&[
        &[1.0, 0.0, 0.0, 0.5, 0.0, 0.0],
        &[0.3, 0.0, 0.0, -1.0, 0.0, 0.0],
    ]);
    let sigma_meas = [2e-4f64, 3e-4];
    let r = diag(&[sigma_meas[0].powi(2), sigma_meas[1].powi(2)]);
    let sol = solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), r.as_ref()).unwrap();
    assert!(sol.closed_loop_spectral_radius < 1.0);
    assert!(dare_residual(&f, &h, &q, &r, &sol.prior_covariance) < 1e-10);
    let s = &h * &sol.prior_covariance * h.transpose() + &r;
    let s_inv = s.partial_piv_lu().solve(Mat::<f64>::identity(2, 2));

    // Four independent runs (seeds 1..=4), each with a burn-in of 1000 steps (ρ_cl ≈ 0.86:
    // the initial error has decayed to 1e-65), pooled: 24 000 steps, 48 000 degrees of
    // freedom, so the 95 % band on the mean NIS is ±1.3 %.
    let (burn_in, steps_per_run, runs) = (1000, 6000, 4);
    let steps = steps_per_run * runs;
    let (mut nis_sum, mut err_filter, mut err_open, mut err_post) = (0.0, 0.0, 0.0, 0.0);
    for run in 0..runs {
        let mut rng = Rng::new(run as u64 + 1);
        let mut x = Mat::<f64>::zeros(n, 1);
        let mut xf = Mat::<f64>::zeros(n, 1); // filter a priori estimate
        let mut xo = Mat::<f64>::zeros(n, 1); // open-loop prediction
        for step in 0..burn_in + steps_per_run {
            let v = Mat::from_fn(2, 1, |i, _| sigma_meas[i] * rng.normal());
            let y = &h * &x + v;
            let innov = &y - &h * &xf;
            let xpost = &xf + &sol.gain * &innov;
            if step >= burn_in {
                nis_sum += (innov.transpose() * &s_inv * &innov)[(0, 0)];
                // Displacement errors (states 0 and 3), a priori and a posteriori.
                for i in [0, 3] {
                    err_filter += (x[(i, 0)] - xf[(i, 0)]).powi(2);
                    err_open += (x[(i, 0)] - xo[(i, 0)]).powi(2);
                    err_post += (x[(i, 0)] - xpost[(i, 0)]).powi(2);
                }
            }
            let xi = Mat::from_fn(2, 1, |i, _| sigma_force[i] * rng.normal());
            x = &f * &x + &gam * xi;
            xf = &f * &xpost;
            xo = &f * &xo;
        }
    }
    assert!(
        err_filter < 0.1 * err_open,
        "filter MSE {err_filter} vs open loop {err_open}"
    );
    assert!(err_post < err_filter);
    // The a posteriori displacement MSE agrees with the predicted covariance.
    let predicted =
        (sol.posterior_covariance[(0, 0)] + sol.posterior_covariance[(3, 3)]) * steps as f64;
    assert!(
        (err_post / predicted - 1.0).abs() < 0.15,
        "MSE {err_post} vs trace P⁺ {predicted}"
    );
    // NIS: Σ eᵀ S⁻¹ e ~ χ²(N m); two-sided 95 % by the normal approximation.
    let dof = (steps * 2) as f64;
    let half = 1.96 * (2.0 * dof).sqrt();
    assert!(
        (nis_sum - dof).abs() < half,
        "NIS sum {nis_sum} outside {dof} ± {half}"
    );
}

// ----------------------------------------------------------------------------------------------
// Multi-rate.

/// Brute force: iterate the time-varying Riccati recursion (textbook form, not Joseph) for
/// `periods` periods and return the priors, gains and posteriors of the last period.
#[allow(clippy::type_complexity)]
fn brute_force_periodic(
    f: &Mat<f64>,
    h: &Mat<f64>,
    q: &Mat<f64>,
    r_diag: &[f64],
    every: &[u32],
    period: usize,
    periods: usize,
) -> Vec<(Mat<f64>, Mat<f64>, Mat<f64>)> {
    let n = f.nrows();
    let mut p = q.clone();
    let mut last = Vec::new();
    for k in 0..periods * period {
        let phase = k % period;
        let rows: Vec<usize> = (0..h.nrows())
            .filter(|&i| phase.is_multiple_of(every[i] as usize))
            .collect();
        let hp = Mat::from_fn(rows.len(), n, |i, j| h[(rows[i], j)]);
        let rp = diag(&rows.iter().map(|&i| r_diag[i]).collect::<Vec<_>>());
        let (gain, post) = if rows.is_empty() {
            (Mat::zeros(n, 0), p.clone())
        } else {
            let s = &hp * &p * hp.transpose() + &rp;
            let k = s.partial_piv_lu().solve(&hp * &p).transpose().to_owned();
            let post = &p - &k * &hp * &p;
            (k, post)
        };
        if k >= (periods - 1) * period {
            last.push((p.clone(), gain, post.clone()));
        }
        p = f * &post * f.transpose() + q;
    }
    last
}

#[test]
fn periodic_gains_match_brute_force_recursion() {
    let mut rng = Rng::new(11);
    let n = 4;
    let f = random_stable(&mut rng, n, 0.9);
    let h = rng.matrix(3, n);
    let q = random_psd(&mut rng, n, 2);
    let r_diag = [0.5, 0.05, 2.0];
    for every in [vec![1u32, 2, 3], vec![2, 2, 4], vec![1, 5, 1]] {
        let sched = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &r_diag, &every).unwrap();
        let period = sched.period;
        let want_period = match every.as_slice() {
            [1, 2, 3] => 6,
            [2, 2, 4] => 4,
            _ => 5,
        };
        assert_eq!(period, want_period);
        assert_eq!(sched.phases.len(), period);
        assert!(sched.worst_relative_residual < 1e-12);
        assert!(sched.closed_loop_spectral_radius < 1.0);
        let brute = brute_force_periodic(&f, &h, &q, &r_diag, &every, period, 400);
        for (p, (phase, (prior, gain, post))) in sched.phases.iter().zip(&brute).enumerate() {
            let expected: Vec<usize> = (0..3)
                .filter(|&i| (p as u32).is_multiple_of(every[i]))
                .collect();
            assert_eq!(phase.measured, expected, "phase {p}");
            assert_eq!(phase.gain.ncols(), expected.len());
            let d = rel_diff(prior.as_ref(), phase.prior_covariance.as_ref());
            assert!(d < 1e-9, "{every:?} phase {p}: prior differs by {d}");
            let d = rel_diff(post.as_ref(), phase.posterior_covariance.as_ref());
            assert!(d < 1e-9, "{every:?} phase {p}: posterior differs by {d}");
            if !expected.is_empty() {
                let d = rel_diff(gain.as_ref(), phase.gain.as_ref());
                assert!(d < 1e-9, "{every:?} phase {p}: gain differs by {d}");
            }
        }
    }
}

#[test]
fn periodic_with_period_one_is_the_dare() {
    let mut rng = Rng::new(5);
    let n = 8;
    let f = random_stable(&mut rng, n, 0.97);
    let h = rng.matrix(3, n);
    let q = random_psd(&mut rng, n, 3);
    let r_diag = [0.1, 0.2, 0.3];
    let sched = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &r_diag, &[1, 1, 1]).unwrap();
    let sol =
        solve_filter_dare(f.as_ref(), h.as_ref(), q.as_ref(), diag(&r_diag).as_ref()).unwrap();
    assert_eq!(sched.period, 1);
    let ph = &sched.phases[0];
    assert_eq!(ph.measured, vec![0, 1, 2]);
    assert!(rel_diff(ph.prior_covariance.as_ref(), sol.prior_covariance.as_ref()) < 1e-14);
    assert!(rel_diff(ph.gain.as_ref(), sol.gain.as_ref()) < 1e-14);
    assert!(
        rel_diff(
            ph.posterior_covariance.as_ref(),
            sol.posterior_covariance.as_ref()
        ) < 1e-14
    );
    assert!((sched.closed_loop_spectral_radius - sol.closed_loop_spectral_radius).abs() < 1e-14);
}

#[test]
fn periodic_gains_with_slow_unobserved_mode() {
    // Three damped rotation blocks near the unit circle; sensors every 3 and 4 steps
    // (L = 12, phases without any measurement); block 3 is seen by no sensor, so at every
    // phase its prior covariance is the open-loop q/(1 − ρ²) I. Brute force would need ~1e6
    // periods here, so the observed part is checked through the per-phase recursion instead.
    let blocks = [(1.0 - 1e-4, 0.05), (1.0 - 2e-4, 0.13), (1.0 - 1e-6, 0.021)];
    let f = rotation_blocks(&blocks);
    let h = from_rows(&[
        &[1.0, 0.0, 0.5, 0.0, 0.0, 0.0],
        &[0.0, 0.0, 1.0, 0.2, 0.0, 0.0],
    ]);
    let qd = [1e-6, 1e-6, 2e-6, 2e-6, 3e-6, 3e-6];
    let q = diag(&qd);
    let r_diag = [1e-4, 4e-4];
    let sched = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &r_diag, &[3, 4]).unwrap();
    assert_eq!(sched.period, 12);
    assert!(sched.worst_relative_residual < 1e-10);
    assert!(sched.closed_loop_spectral_radius < 1.0);
    let lyap = qd[4] / (1.0 - blocks[2].0 * blocks[2].0);
    let n = 6;
    for (p, ph) in sched.phases.iter().enumerate() {
        let want: Vec<usize> = [3u32, 4]
            .iter()
            .enumerate()
            .filter(|(_, &e)| (p as u32).is_multiple_of(e))
            .map(|(i, _)| i)
            .collect();
        assert_eq!(ph.measured, want, "phase {p}");
        let pr = &ph.prior_covariance;
        assert!(
            (pr[(4, 4)] - lyap).abs() <= 1e-9 * lyap,
            "phase {p}: {}",
            pr[(4, 4)]
        );
        assert!(pr[(0, 5)].abs() <= 1e-9 * lyap);
        // P_{p+1} = F P⁺_p Fᵀ + Q with P⁺_p = (I − K_p H_p) P_p, wrapping at L.
        let rows = Mat::from_fn(want.len(), n, |i, j| h[(want[i], j)]);
        let post = (Mat::<f64>::identity(n, n) - &ph.gain * &rows) * pr;
        assert!(rel_diff(post.as_ref(), ph.posterior_covariance.as_ref()) < 1e-10);
        let next = &f * &post * f.transpose() + &q;
        let following = &sched.phases[(p + 1) % sched.period].prior_covariance;
        let d = rel_diff(next.as_ref(), following.as_ref());
        assert!(d < 1e-10, "phase {p} → {}: {d}", (p + 1) % sched.period);
    }
    // Measured phases shrink the covariance of the observed block below the predict-only ones.
    assert!(
        sched.phases[0].posterior_covariance[(0, 0)] < sched.phases[1].prior_covariance[(0, 0)]
    );
}

#[test]
fn periodic_input_errors() {
    let f = diag(&[0.5, 0.6]);
    let h = diag(&[1.0, 1.0]);
    let q = diag(&[1.0, 1.0]);
    let err = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &[1.0, 1.0], &[1, 0]).unwrap_err();
    assert!(err.to_string().contains("measurement row 1"), "{err}");
    let err =
        periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &[1.0, -1.0], &[1, 1]).unwrap_err();
    assert!(err.to_string().contains("R[1,1]"), "{err}");
    let err = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &[1.0], &[1, 1]).unwrap_err();
    assert!(err.to_string().contains("r_diag has 1 entries"), "{err}");
    let err = periodic_gains(
        f.as_ref(),
        h.as_ref(),
        q.as_ref(),
        &[1.0, 1.0],
        &[4093, 4091],
    )
    .unwrap_err();
    assert!(matches!(err, KalmanError::PeriodTooLong { .. }), "{err}");
}

// ----------------------------------------------------------------------------------------------
// Output standard deviations.

#[test]
fn output_standard_deviations_match_dense_product() {
    let mut rng = Rng::new(9);
    let (n, k) = (7, 4);
    let p = random_psd(&mut rng, n, n);
    let c = rng.matrix(k, n);
    let dense = &c * &p * c.transpose();
    let sd = output_standard_deviations(c.as_ref(), p.as_ref());
    assert_eq!(sd.len(), k);
    for (i, s) in sd.iter().enumerate() {
        let want = dense[(i, i)].sqrt();
        assert!((s - want).abs() <= 1e-13 * want, "row {i}: {s} vs {want}");
    }
    // A row in the null space of P has zero deviation.
    let p2 = diag(&[1.0, 0.0]);
    let c2 = from_rows(&[&[0.0, 3.0], &[2.0, 0.0]]);
    assert_eq!(
        output_standard_deviations(c2.as_ref(), p2.as_ref()),
        vec![0.0, 2.0]
    );
}
