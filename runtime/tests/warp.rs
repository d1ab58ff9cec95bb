//! R(ω), R̃(ω), R̃(ω)⁻¹ against independent references: the matrix exponential of [ω]× by
//! Taylor series, and Simpson quadrature of ∫₀¹ exp(s[ω]×) ds.

mod common;
use common::Rng;
use crokf_runtime::warp::*;

type M3 = [[f64; 3]; 3];

fn skew(w: &[f64; 3]) -> M3 {
    [[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]
}

fn mm(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn max_diff(a: &M3, b: &M3) -> f64 {
    (0..9)
        .map(|k| (a[k / 3][k % 3] - b[k / 3][k % 3]).abs())
        .fold(0.0, f64::max)
}

/// exp(s[ω]×) by its Taylor series (|sω| ≤ 3.2 here: 60 terms are plenty).
fn expm(w: &[f64; 3], s: f64) -> M3 {
    let a = skew(&[s * w[0], s * w[1], s * w[2]]);
    let mut term = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut sum = term;
    for k in 1..60 {
        term = mm(&term, &a);
        for row in term.iter_mut() {
            for v in row.iter_mut() {
                *v /= k as f64;
            }
        }
        for i in 0..3 {
            for j in 0..3 {
                sum[i][j] += term[i][j];
            }
        }
    }
    sum
}

/// ∫₀¹ exp(s[ω]×) ds, composite Simpson with 2000 intervals.
fn integral(w: &[f64; 3]) -> M3 {
    let n = 2000;
    let mut sum = [[0.0; 3]; 3];
    for k in 0..=n {
        let weight = if k == 0 || k == n {
            1.0
        } else if k % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let e = expm(w, k as f64 / n as f64);
        for i in 0..3 {
            for j in 0..3 {
                sum[i][j] += weight * e[i][j] / (3.0 * n as f64);
            }
        }
    }
    sum
}

fn det(a: &M3) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

fn random_omegas() -> Vec<[f64; 3]> {
    let mut g = Rng(3);
    let mut out = vec![[0.0; 3]];
    for &theta in &[
        1e-12,
        1e-9,
        1e-4,
        0.1,
        0.49,
        0.499_999_9,
        0.5,
        0.500_000_1,
        0.51,
        1.0,
        2.0,
        3.0,
        3.1,
    ] {
        for _ in 0..4 {
            let v = [g.uniform(), g.uniform(), g.uniform()];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            out.push([theta * v[0] / n, theta * v[1] / n, theta * v[2] / n]);
        }
    }
    out
}

#[test]
fn rotation_is_orthonormal_with_unit_determinant_and_equals_the_exponential() {
    for w in random_omegas() {
        let r = rotation_matrix(&w);
        let rtr = mm(
            &[
                [r[0][0], r[1][0], r[2][0]],
                [r[0][1], r[1][1], r[2][1]],
                [r[0][2], r[1][2], r[2][2]],
            ],
            &r,
        );
        assert!(
            max_diff(&rtr, &expm(&[0.0; 3], 0.0)) < 1e-15,
            "RᵀR ≠ I at ω = {w:?}"
        );
        assert!((det(&r) - 1.0).abs() < 1e-15, "det R at {w:?}");
        assert!(
            max_diff(&r, &expm(&w, 1.0)) < 1e-14,
            "R ≠ exp([ω]×) at {w:?}"
        );
        // Rᵀ v via rotate_transpose.
        let v = [0.3, -1.2, 2.0];
        let rt = rotate_transpose(&w, &v);
        for i in 0..3 {
            let expect: f64 = (0..3).map(|k| r[k][i] * v[k]).sum();
            assert!((rt[i] - expect).abs() < 1e-15);
        }
    }
}

#[test]
fn rotation_by_a_right_angle() {
    // 90° about z maps x to y.
    let w = [0.0, 0.0, std::f64::consts::FRAC_PI_2];
    let v = rotate(&w, &[1.0, 0.0, 0.0]);
    assert!((v[0]).abs() < 1e-15 && (v[1] - 1.0).abs() < 1e-15 && v[2] == 0.0);
    // R̃ maps x to the chord-average: ∫₀¹ (cos sθ, sin sθ) ds = (sin θ/θ, (1 − cos θ)/θ).
    let u = warp(&w, &[1.0, 0.0, 0.0]);
    let th = std::f64::consts::FRAC_PI_2;
    assert!((u[0] - th.sin() / th).abs() < 1e-15 && (u[1] - (1.0 - th.cos()) / th).abs() < 1e-15);
}

#[test]
fn warp_equals_the_integral_of_the_rotation() {
    for w in random_omegas() {
        let rt = warp_matrix(&w);
        let reference = integral(&w);
        assert!(
            max_diff(&rt, &reference) < 1e-12,
            "R̃ ≠ ∫R at ω = {w:?}: {}",
            max_diff(&rt, &reference)
        );
        let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        let sinc = if th == 0.0 {
            1.0
        } else {
            (th / 2.0).sin() / (th / 2.0)
        };
        assert!((det(&rt) - sinc * sinc).abs() < 1e-14);
        assert!((warp_determinant(&w) - sinc * sinc).abs() < 1e-15);
    }
}

#[test]
fn unwarp_inverts_warp() {
    let mut g = Rng(5);
    for w in random_omegas() {
        let v = [g.uniform(), g.uniform(), g.uniform()];
        let back = unwarp(&w, &warp(&w, &v)).unwrap();
        let fwd = warp(&w, &unwarp(&w, &v).unwrap());
        for i in 0..3 {
            assert!((back[i] - v[i]).abs() < 1e-14, "R̃⁻¹R̃ v at {w:?}");
            assert!((fwd[i] - v[i]).abs() < 1e-14, "R̃R̃⁻¹ v at {w:?}");
        }
    }
    // θ = 2π: R̃ is singular.
    assert!(unwarp(&[0.0, 2.0 * std::f64::consts::PI, 0.0], &[1.0, 0.0, 0.0]).is_none());
}

#[test]
fn small_angle_limits() {
    let (a0, a1, b1) = coefficients(&[0.0; 3]);
    assert_eq!((a0, a1, b1), (1.0, 0.5, 1.0 / 6.0));
    // Continuity across the series/closed-form switch at θ = 0.5.
    let lo = coefficients(&[0.5 - 2e-16, 0.0, 0.0]);
    let hi = coefficients(&[0.5 + 2e-16, 0.0, 0.0]);
    assert!(
        (lo.0 - hi.0).abs() < 1e-15 && (lo.1 - hi.1).abs() < 1e-15 && (lo.2 - hi.2).abs() < 1e-15
    );
}
