//! The exact discretisation of one mass-normalised mode q̈ + c q̇ + k q = f with the load held
//! over the step (zero-order hold; docs/design.md §2): the sampled response of the continuous
//! mode, without the time-stepping error of a scheme.
//!
//! With A = [[0, 1], [−k, −c]] and e^{AΔt} from the augmented matrix exponential
//! ```text
//! exp(Δt [[0, 1, 0], [−k, −c, 1], [0, 0, 0]]) = [[E, g], [0, 1]]
//! [q', q̇'] = E [q, q̇] + g f          q̈' = f − c q̇' − k q'
//! ```
//! so the state s = [q, q̇, q̈] has the same layout as Wilson-θ's ([`crate::wilson`]); Φ's third
//! column is zero (the end-of-step acceleration carries no memory under a held load).

/// Φ (row-major) and Γ of the exact zero-order-hold step of one mode with stiffness k = ω²
/// (1/s²) and damping c (1/s) over Δt (s): s_{k+1} = Φ s_k + Γ f_k, s = [q, q̇, q̈].
pub fn modal_block(dt: f64, k: f64, c: f64) -> ([[f64; 3]; 3], [f64; 3]) {
    let m = [[0.0, dt, 0.0], [-k * dt, -c * dt, dt], [0.0, 0.0, 0.0]];
    let e = expm3(m);
    let phi = [
        [e[0][0], e[0][1], 0.0],
        [e[1][0], e[1][1], 0.0],
        [-k * e[0][0] - c * e[1][0], -k * e[0][1] - c * e[1][1], 0.0],
    ];
    let gamma = [e[0][2], e[1][2], 1.0 - k * e[0][2] - c * e[1][2]];
    (phi, gamma)
}

/// e^M of a 3×3 matrix by scaling and squaring: M/2ˢ with ‖M/2ˢ‖∞ ≤ 1/2, its Taylor series
/// to 18 terms (the remainder below 2⁻⁵³ relative), then s squarings.
fn expm3(m: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let norm = m
        .iter()
        .map(|row| row.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let mut squarings = 0;
    let mut scale = 1.0;
    while norm * scale > 0.5 && squarings < 1100 {
        scale *= 0.5;
        squarings += 1;
    }
    let a = m.map(|row| row.map(|v| v * scale));
    // Horner: I + A(I + A/2(I + A/3(… (I + A/18)))).
    let mut e = identity();
    for j in (1..=18).rev() {
        let ae = mul(a, e);
        e = identity();
        for r in 0..3 {
            for c in 0..3 {
                e[r][c] += ae[r][c] / j as f64;
            }
        }
    }
    for _ in 0..squarings {
        e = mul(e, e);
    }
    e
}

fn identity() -> [[f64; 3]; 3] {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|i| a[r][i] * b[i][c]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wilson::WilsonTheta;

    fn step(block: &([[f64; 3]; 3], [f64; 3]), s: [f64; 3], f: f64) -> [f64; 3] {
        let (p, g) = block;
        [0, 1, 2].map(|r| (0..3).map(|c| p[r][c] * s[c]).sum::<f64>() + g[r] * f)
    }

    /// The step response of an underdamped mode against its closed form
    /// q(t) = f/k (1 − e^{−ζωt}(cos ω_d t + ζω/ω_d sin ω_d t)), at every step of 2,000.
    #[test]
    fn step_response_matches_the_closed_form() {
        let (omega, zeta, dt) = (2.0 * std::f64::consts::PI * 40.0, 0.03, 1e-3);
        let (k, c) = (omega * omega, 2.0 * zeta * omega);
        let block = modal_block(dt, k, c);
        let wd = omega * (1.0 - zeta * zeta).sqrt();
        let mut s = [0.0; 3];
        let mut worst: f64 = 0.0;
        for n in 1..=2000 {
            s = step(&block, s, 1.0);
            let t = n as f64 * dt;
            let q = (1.0
                - (-zeta * omega * t).exp()
                    * ((wd * t).cos() + zeta * omega / wd * (wd * t).sin()))
                / k;
            let v = (-zeta * omega * t).exp() * (wd * t).sin() * omega * omega / wd / k;
            worst = worst
                .max((s[0] - q).abs() * k)
                .max((s[1] - v).abs() * k / omega);
            // The equation of motion holds at the end of the step.
            assert!((s[2] + c * s[1] + k * s[0] - 1.0).abs() < 1e-9);
        }
        assert!(worst < 1e-12, "{worst}");
    }

    /// Overdamped and critically damped modes (a Rayleigh βω² far above 2ω) and a free mass
    /// (k = 0): the response of the exact block to a held load agrees with Wilson-θ at a
    /// step that resolves its fastest rate (acceleration restarted at each load change), which converges to
    /// it.
    #[test]
    fn wilson_theta_converges_to_it() {
        let dt = 2e-3;
        for (k, c) in [
            (1e4, 2e2),
            (1e4, 1e3),
            (1e8, 1e6),
            (0.0, 0.0),
            (0.0, 5.0),
            (3e5, 0.0),
        ] {
            let block = modal_block(dt, k, c);
            // Sub-steps that resolve the fastest rate, max(c, ω)Δt/sub ≤ 0.05.
            let sub = ((20.0 * c.max(k.sqrt()) * dt).ceil() as usize).max(200);
            let w = WilsonTheta {
                dt: dt / sub as f64,
                theta: 1.4,
            };
            let (mut s, mut r) = ([0.0; 3], [0.0; 3]);
            let mut scale: f64 = 0.0;
            let mut worst: f64 = 0.0;
            for n in 0..50 {
                let f = (std::f64::consts::PI * n as f64 / 50.0).sin().powi(2);
                s = step(&block, s, f);
                // The acceleration restarted where the held load changes (else a jump costs
                // Wilson-θ first order).
                r[2] = f - c * r[1] - k * r[0];
                for _ in 0..sub {
                    r = w.modal_step(k, c, r, f);
                }
                scale = scale.max(r[0].abs());
                worst = worst.max((s[0] - r[0]).abs());
            }
            assert!(worst <= 1e-5 * scale, "k {k} c {c}: {worst} of {scale}");
        }
    }

    /// A lightly damped mode far above Nyquist keeps |λ| = e^{−cΔt/2} < 1 (no growth, no
    /// NaN) however large ωΔt.
    #[test]
    fn stiff_modes_stay_bounded() {
        let dt = 1e-3;
        for omega in [1e3, 1e5, 1e7] {
            let k = omega * omega;
            let c = 1e-4 * k;
            let (p, g) = modal_block(dt, k, c);
            assert!(
                p.iter().flatten().chain(&g).all(|v| v.is_finite()),
                "ω {omega}"
            );
            let mut s = [1.0 / k, 0.0, 0.0];
            for _ in 0..1000 {
                s = step(&(p, g), s, 0.0);
            }
            assert!(s[0].abs() <= 1.0 / k, "ω {omega}: {s:?}");
        }
    }
}
