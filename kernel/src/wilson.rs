//! The Wilson-θ advance (docs/design.md §2), one copy for the compiler's steppers
//! (`crokf_compile::dynamics::WilsonTheta::advance`) and the runtime's tier step.

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
    /// A free mass (no force, Û from constant velocity) keeps its velocity exactly.
    #[test]
    fn constant_velocity_is_kept() {
        let (dt, theta) = (1e-3, 1.4);
        let (u, v) = (0.2, 3.0);
        let u_hat = u + theta * dt * v;
        let (u1, v1, a1) = super::advance(dt, theta, u, v, 0.0, u_hat);
        assert!((u1 - (u + dt * v)).abs() < 1e-15);
        assert!((v1 - v).abs() < 1e-12 && a1.abs() < 1e-9);
    }
}
