//! Open-loop Galerkin runs on a quadratic displacement manifold
//! ([`crokf_compile::nonlinear::manifold`]), every element integrated (no hyper-reduction): a
//! measurement of whether the manifold carries a response a linear basis does not (the twist,
//! docs/corotational-tier.md §8), before anything is built on it.
//!
//! Each step searches the Wilson-θ iterate on the manifold, Û = u(q̂), and solves the full-order
//! step residual projected on the manifold's tangent, P(q̂)ᵀ r(u(q̂)) = 0
//! ([`CorotationalSimulator::step_residual`]), by Newton with a forward-difference Jacobian
//! (r residuals per iteration; fine for the test-sized meshes this measures). The accepted Û
//! advances the full-order Wilson-θ state ([`CorotationalSimulator::accept_step`]), so the
//! history U, U̇, Ü is the full-order one. With W = 0 the search stays in span V, the history
//! too, and the run equals the linear Galerkin stepper (`ReducedStepper` with every element at
//! weight 1) to the Newton tolerance: the check of this driver.

use nalgebra::{DMatrix, DVector};

use crokf_compile::nonlinear::manifold::QuadraticManifold;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use crokf_compile::FullOrder;

use super::TierError;

/// The result of [`galerkin_run`].
#[derive(Clone, Debug, Default)]
pub struct ManifoldRun {
    /// U after every step (n each).
    pub states: Vec<Vec<f64>>,
    /// Newton iterations over all steps.
    pub iterations: usize,
    /// Steps that ended above the tolerance.
    pub unconverged: usize,
}

/// Runs the load history `loads` (n each, held over each step) open loop on `manifold`
/// (module doc); Newton converged when ‖δq‖ ≤ `tolerance` ‖q̂‖, at most `max_iterations`.
pub fn galerkin_run(
    full: &FullOrder,
    manifold: &QuadraticManifold,
    loads: &[Vec<f64>],
    tolerance: f64,
    max_iterations: usize,
) -> Result<ManifoldRun, TierError> {
    let n = full.fem.dof_count();
    let r = manifold.order();
    let mut sim = CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default())?;
    let tau = full.wilson.tau();
    let mut residual = vec![0.0; n];
    let mut run = ManifoldRun::default();
    // g(q) = P(q)ᵀ r(u(q)).
    let mut projected = |sim: &mut CorotationalSimulator,
                         q: &DVector<f64>,
                         f: &[f64]|
     -> Result<DVector<f64>, TierError> {
        let u = manifold.lift(q.as_slice());
        sim.step_residual(u.as_slice(), f, &mut residual)?;
        Ok(manifold
            .tangent(q.as_slice())
            .tr_mul(&DVector::from_column_slice(&residual)))
    };
    for f in loads {
        // Start from the projection of the Taylor predictor U + τU̇ + τ²/2 Ü.
        let predicted: Vec<f64> = (0..n)
            .map(|i| {
                sim.displacement()[i]
                    + tau * sim.velocity()[i]
                    + 0.5 * tau * tau * sim.acceleration()[i]
            })
            .collect();
        let mut q = manifold.project(&predicted);
        let mut converged = false;
        for _ in 0..max_iterations {
            let g = projected(&mut sim, &q, f)?;
            let mut jacobian = DMatrix::zeros(r, r);
            for l in 0..r {
                let h = 1e-7 * manifold.scales[l].max(q[l].abs());
                let mut shifted = q.clone();
                shifted[l] += h;
                let gl = projected(&mut sim, &shifted, f)?;
                jacobian.set_column(l, &((gl - &g) / h));
            }
            let delta = jacobian
                .lu()
                .solve(&(-g))
                .ok_or_else(|| TierError::Invalid("singular reduced Jacobian".into()))?;
            q += &delta;
            run.iterations += 1;
            if !q.iter().all(|x| x.is_finite()) {
                return Err(TierError::Invalid(format!(
                    "non-finite coordinates at step {}",
                    run.states.len() + 1
                )));
            }
            if delta.norm() <= tolerance * q.norm() {
                converged = true;
                break;
            }
        }
        if !converged {
            run.unconverged += 1;
        }
        sim.accept_step(manifold.lift(q.as_slice()).as_slice())?;
        run.states.push(sim.displacement().to_vec());
    }
    Ok(run)
}

/// Quasi-static equilibrium on the manifold, P(q)ᵀ (f − f_int(u(q))) = 0, by Newton with a
/// forward-difference Jacobian over `increments` equal load increments (f: n, N); returns
/// u(q) (n). The static counterpart of [`galerkin_run`]: tells the manifold's equilibrium
/// apart from its dynamics.
pub fn galerkin_static(
    full: &FullOrder,
    manifold: &QuadraticManifold,
    f: &[f64],
    increments: usize,
    tolerance: f64,
) -> Result<Vec<f64>, TierError> {
    let r = manifold.order();
    let mut sim = CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default())?;
    let mut projected = |q: &DVector<f64>, scale: f64| -> Result<DVector<f64>, TierError> {
        let u = manifold.lift(q.as_slice());
        let internal = sim.internal_force(u.as_slice())?;
        let r: Vec<f64> = f
            .iter()
            .zip(&internal)
            .map(|(a, b)| scale * a - b)
            .collect();
        Ok(manifold.tangent(q.as_slice()).tr_mul(&DVector::from_vec(r)))
    };
    let mut q = DVector::zeros(r);
    for k in 1..=increments.max(1) {
        let scale = k as f64 / increments.max(1) as f64;
        let mut converged = false;
        for _ in 0..50 {
            let g = projected(&q, scale)?;
            let mut jacobian = DMatrix::zeros(r, r);
            for l in 0..r {
                let h = 1e-7 * manifold.scales[l].max(q[l].abs());
                let mut shifted = q.clone();
                shifted[l] += h;
                jacobian.set_column(l, &((projected(&shifted, scale)? - &g) / h));
            }
            let delta = jacobian
                .lu()
                .solve(&(-g))
                .ok_or_else(|| TierError::Invalid("singular reduced Jacobian".into()))?;
            q += &delta;
            if !q.iter().all(|x| x.is_finite()) {
                return Err(TierError::Invalid("non-finite static coordinates".into()));
            }
            if delta.norm() <= tolerance * q.norm() {
                converged = true;
                break;
            }
        }
        if !converged {
            return Err(TierError::Invalid(format!(
                "static Galerkin did not converge at load factor {scale}"
            )));
        }
    }
    Ok(manifold.lift(q.as_slice()).iter().copied().collect())
}
