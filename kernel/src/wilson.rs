//! The Wilson-θ scheme (docs/design.md §2): one definition of its derived constants, its
//! advance and its per-mode recursion, for the compiler's steppers and filter design
//! (`crokf_compile::dynamics`), the runtime's tier step and the verification floors.
//!
//! With τ = θΔt and the load f held constant over the step, s = [U; U̇; Ü]:
//! ```text
//! J  = K + (6/τ²) M + (3/τ) C
//! Û  = J⁻¹ [ f + M(6/τ² U + 6/τ U̇ + 2Ü) + C(3/τ U + 2U̇ + τ/2 Ü) ]
//! Ü' = 6/(θ³Δt²)(Û − U) − 6/(θ²Δt) U̇ + (1 − 3/θ) Ü
//! U̇' = U̇ + Δt/2 (Ü' + Ü)
//! U' = U + Δt U̇ + Δt²/6 (Ü' + 2Ü)
//! ```
//! Full-order solvers use [`WilsonTheta::mass_rhs`], [`WilsonTheta::damping_rhs`] and
//! [`WilsonTheta::advance`]; the reduced model uses the 3×3 per-mode blocks of
//! [`WilsonTheta::modal_block`]; the Newton steps of the co-rotational tier use the
//! acceleration and velocity at t + τ, a₀ΔÛ − (6/τ)U̇ − 2Ü and a₂ΔÛ − 2U̇ − (τ/2)Ü
//! (a₀ = [`WilsonTheta::mass_coefficient`], a₂ = [`WilsonTheta::damping_coefficient`],
//! 6/τ = [`WilsonTheta::velocity_coefficient`]).

/// Wilson-θ parameters: time step Δt (s) and θ (≥ 1.37 for unconditional stability).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WilsonTheta {
    /// Time step Δt, s.
    pub dt: f64,
    /// θ, dimensionless.
    pub theta: f64,
}

/// The highest frequency a step of `dt` seconds resolves, Hz: 0.25/Δt, four steps per period
/// (the modal reduction keeps modes up to it; the scene check warns about loads above it).
pub fn highest_resolved_hz(dt: f64) -> f64 {
    0.25 / dt
}

/// The largest time step that resolves a frequency of `hz`, s: 0.25/f (the inverse of
/// [`highest_resolved_hz`]).
pub fn resolving_dt(hz: f64) -> f64 {
    0.25 / hz
}

impl WilsonTheta {
    /// τ = θΔt, s.
    pub fn tau(&self) -> f64 {
        self.theta * self.dt
    }

    /// Coefficient of M in J, a₀ = 6/τ², 1/s².
    pub fn mass_coefficient(&self) -> f64 {
        6.0 / (self.tau() * self.tau())
    }

    /// Coefficient of C in J, a₂ = 3/τ, 1/s.
    pub fn damping_coefficient(&self) -> f64 {
        3.0 / self.tau()
    }

    /// Coefficient of U̇ in M's right-hand side and in the acceleration at t + τ: 6/τ, 1/s.
    pub fn velocity_coefficient(&self) -> f64 {
        6.0 / self.tau()
    }

    /// The highest frequency the step resolves, Hz ([`highest_resolved_hz`]).
    pub fn highest_resolved_hz(&self) -> f64 {
        highest_resolved_hz(self.dt)
    }

    /// The vector multiplied by M on the right-hand side, per DOF:
    /// 6/τ² U + 6/τ U̇ + 2Ü.
    pub fn mass_rhs(&self, u: f64, v: f64, a: f64) -> f64 {
        self.mass_coefficient() * u + self.velocity_coefficient() * v + 2.0 * a
    }

    /// The vector multiplied by C on the right-hand side, per DOF:
    /// 3/τ U + 2U̇ + τ/2 Ü.
    pub fn damping_rhs(&self, u: f64, v: f64, a: f64) -> f64 {
        let tau = self.tau();
        self.damping_coefficient() * u + 2.0 * v + 0.5 * tau * a
    }

    /// Advances one DOF from (U, U̇, Ü) at t to t + Δt given Û = U(t + θΔt) ([`advance`]).
    #[inline]
    pub fn advance(&self, u: f64, v: f64, a: f64, u_hat: f64) -> (f64, f64, f64) {
        advance(self.dt, self.theta, u, v, a, u_hat)
    }

    /// The weights w of Û = θ³ U' − w · [U, U̇, Ü]: the θ-point displacement Û = U(t + θΔt)
    /// from the end-of-step one U' and the state at t ([`advance`] solved for Û), so a model
    /// that knows U' and the state before the step knows the θ-point (the contact step enforces
    /// its gap there: enforced at the end of the step with the force held over it, the
    /// contact oscillates with period two). w = [θ³ − 1, Δt θ (θ² − 1), Δt² θ² (θ − 1) / 2].
    pub fn theta_point_weights(&self) -> [f64; 3] {
        let (th, dt) = (self.theta, self.dt);
        [
            th * th * th - 1.0,
            dt * th * (th * th - 1.0),
            0.5 * dt * dt * th * th * (th - 1.0),
        ]
    }

    /// One step of a single mass-normalised mode q̈ + c q̇ + k q = f with (q, q̇, q̈) state.
    pub fn modal_step(&self, k: f64, c: f64, s: [f64; 3], f: f64) -> [f64; 3] {
        let j = k + self.mass_coefficient() + self.damping_coefficient() * c;
        let [u, v, a] = s;
        let u_hat = (f + self.mass_rhs(u, v, a) + c * self.damping_rhs(u, v, a)) / j;
        let (u, v, a) = self.advance(u, v, a, u_hat);
        [u, v, a]
    }

    /// The discrete blocks (Φ, Γ) of one mass-normalised mode with stiffness k = ω² (1/s²) and
    /// damping c = α + βω² (1/s): s_{k+1} = Φ s_k + Γ f_k, s = [q, q̇, q̈], Φ row-major.
    pub fn modal_block(&self, k: f64, c: f64) -> ([[f64; 3]; 3], [f64; 3]) {
        let mut phi = [[0.0; 3]; 3];
        for col in 0..3 {
            let mut e = [0.0; 3];
            e[col] = 1.0;
            let s = self.modal_step(k, c, e, 0.0);
            for row in 0..3 {
                phi[row][col] = s[row];
            }
        }
        let gamma = self.modal_step(k, c, [0.0; 3], 1.0);
        (phi, gamma)
    }
}

/// Advances one DOF from (U, U̇, Ü) at t to t + Δt given Û = U(t + θΔt) (Δt in s, θ ≥ 1.37):
/// ```text
/// Ü' = 6/(θ³Δt²)(Û − U) − 6/(θ²Δt) U̇ + (1 − 3/θ) Ü
/// U̇' = U̇ + Δt/2 (Ü' + Ü)
/// U' = U + Δt U̇ + Δt²/6 (Ü' + 2Ü)
/// ```
/// Returns (U', U̇', Ü').
#[inline]
pub fn advance(dt: f64, theta: f64, u: f64, v: f64, a: f64, u_hat: f64) -> (f64, f64, f64) {
    let th = theta;
    let a_new = 6.0 / (th * th * th * dt * dt) * (u_hat - u) - 6.0 / (th * th * dt) * v
        + (1.0 - 3.0 / th) * a;
    let v_new = v + 0.5 * dt * (a_new + a);
    let u_new = u + dt * v + dt * dt / 6.0 * (a_new + 2.0 * a);
    (u_new, v_new, a_new)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A free mass (no force, Û from constant velocity) keeps its velocity exactly.
    #[test]
    fn constant_velocity_is_kept() {
        let (dt, theta) = (1e-3, 1.4);
        let (u, v) = (0.2, 3.0);
        let u_hat = u + theta * dt * v;
        let (u1, v1, a1) = advance(dt, theta, u, v, 0.0, u_hat);
        assert!((u1 - (u + dt * v)).abs() < 1e-15);
        assert!((v1 - v).abs() < 1e-12 && a1.abs() < 1e-9);
    }

    /// The θ-point weights recover Û from U' and the state before the step.
    #[test]
    fn theta_point_from_the_end_of_the_step() {
        let w = WilsonTheta {
            dt: 2e-3,
            theta: 1.4,
        };
        let (u, v, a, u_hat) = (0.3, -2.0, 50.0, 0.29);
        let (u1, _, _) = w.advance(u, v, a, u_hat);
        let c = w.theta_point_weights();
        let th3 = w.theta.powi(3);
        let back = th3 * u1 - (c[0] * u + c[1] * v + c[2] * a);
        assert!((back - u_hat).abs() < 1e-12, "{back} against {u_hat}");
    }

    /// ρ(Φ) ≈ ‖Φ^(2^20)‖^(2^-20) by repeated squaring with rescaling (Gelfand's formula).
    fn spectral_radius_3x3(p: [[f64; 3]; 3]) -> f64 {
        let mut m = p;
        let mut log_scale = 0.0;
        let squarings = 20;
        for _ in 0..squarings {
            let mut sq = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    sq[i][j] = (0..3).map(|k| m[i][k] * m[k][j]).sum();
                }
            }
            let norm = sq.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
            log_scale = 2.0 * log_scale + norm.ln();
            m = sq.map(|row| row.map(|v| v / norm));
        }
        (log_scale / f64::powi(2.0, squarings)).exp()
    }

    /// A contact held by its force over the step (docs/contact.md): one mode pressed by a
    /// bilateral constraint that holds its displacement at 0. Enforced on the end-of-step
    /// displacement, the closed loop's spectral radius is 2 + √3 ≈ 3.73 (a period-2
    /// oscillation that grows), whatever the mode; enforced at the θ-point Û it is about 0.78.
    #[test]
    fn contact_at_the_theta_point_is_stable_and_at_the_end_of_the_step_is_not() {
        let w = WilsonTheta {
            dt: 1e-3,
            theta: 1.4,
        };
        for omega in [1.0, 1e2, 1e3, 1e4, 1e5] {
            for zeta in [0.0, 0.2] {
                let (k, c) = (omega * omega, 2.0 * zeta * omega);
                let (phi, gamma) = w.modal_block(k, c);
                let j = k + w.mass_coefficient() + w.damping_coefficient() * c;
                let h: [f64; 3] = std::array::from_fn(|i| {
                    let mut e = [0.0; 3];
                    e[i] = 1.0;
                    (w.mass_rhs(e[0], e[1], e[2]) + c * w.damping_rhs(e[0], e[1], e[2])) / j
                });
                // Û = h·s + f/j = 0: f = −j h·s.
                let theta = std::array::from_fn(|r| {
                    std::array::from_fn(|col| phi[r][col] - gamma[r] * j * h[col])
                });
                // U' = Φ₀·s + Γ₀ f = 0: f = −Φ₀·s / Γ₀.
                let end = std::array::from_fn(|r| {
                    std::array::from_fn(|col| phi[r][col] - gamma[r] * phi[0][col] / gamma[0])
                });
                let (rho_theta, rho_end) = (spectral_radius_3x3(theta), spectral_radius_3x3(end));
                assert!(
                    rho_theta < 0.8,
                    "ω {omega}, ζ {zeta}: θ-point ρ = {rho_theta}"
                );
                assert!(
                    rho_end > 3.7,
                    "ω {omega}, ζ {zeta}: end-of-step ρ = {rho_end}"
                );
            }
        }
    }

    #[test]
    fn static_load_converges_to_static_deflection() {
        let w = WilsonTheta {
            dt: 0.01,
            theta: 1.4,
        };
        let (k, c) = (400.0, 2.0);
        let mut s = [0.0; 3];
        for _ in 0..5000 {
            s = w.modal_step(k, c, s, 2.0);
        }
        assert!((s[0] - 2.0 / 400.0).abs() < 1e-12, "{s:?}");
    }

    #[test]
    fn undamped_step_far_above_period_does_not_grow() {
        // Δt = 100 × the period of the mode: Wilson-θ (θ = 1.4) must stay bounded.
        let w = WilsonTheta {
            dt: 1.0,
            theta: 1.4,
        };
        let omega = 2.0 * std::f64::consts::PI * 100.0;
        let mut s = [1.0, 0.0, -omega * omega];
        // The first steps carry a non-normal transient; afterwards the amplitude only decays.
        let (mut early, mut late): (f64, f64) = (0.0, 0.0);
        for step in 0..100_000 {
            s = w.modal_step(omega * omega, 0.0, s, 0.0);
            let size = s[0].abs() + s[1].abs() * w.dt + s[2].abs() * w.dt * w.dt;
            if step < 1000 {
                early = early.max(size);
            } else if step >= 99_000 {
                late = late.max(size);
            }
            assert!(size.is_finite());
        }
        assert!(
            late <= early,
            "grew: first 1000 steps {early}, last 1000 steps {late}"
        );
        let (phi, _) = w.modal_block(omega * omega, 0.0);
        let rho = spectral_radius_3x3(phi);
        assert!(rho < 1.0, "spectral radius {rho}");
    }
}
