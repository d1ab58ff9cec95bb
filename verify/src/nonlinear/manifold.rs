//! Open-loop Galerkin runs on a quadratic displacement manifold
//! ([`crokf_compile::nonlinear::manifold`]), every element integrated (no hyper-reduction): a
//! measurement of whether the manifold carries a response a linear basis does not (the twist,
//! docs/results/tier.md §8), before anything is built on it.
//!
//! Each step searches the Wilson-θ iterate on the manifold, Û = u(q̂), and solves the full-order
//! equation of motion projected on the manifold's tangent, P(q̂)ᵀ r = 0, by Newton with a
//! forward-difference Jacobian (r residuals per iteration; fine for the test-sized meshes this
//! measures). Two ways to keep the Wilson-θ history ([`History`]):
//!
//! - full order: r is the full-order step residual at Û
//!   ([`CorotationalSimulator::step_residual`]) and the accepted Û advances U, U̇, Ü
//!   ([`CorotationalSimulator::accept_step`]);
//! - in the coordinates: Wilson-θ on q, the rates lifted by the manifold
//!   ([`CorotationalSimulator::dynamic_residual`] at u(q̂), P q̇_θ, P q̈_θ + 2 W k(q̇_θ)).
//!
//! With W = 0 both stay in span V and equal the linear Galerkin stepper (`ReducedStepper` with
//! every element at weight 1) to the Newton tolerance: the check of this driver.

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

/// Where the run keeps its Wilson-θ history (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum History {
    /// U, U̇, Ü at full order, advanced from the accepted Û = u(q̂): the history leaves the
    /// manifold between steps (its Wilson-θ interpolation is linear in Û).
    FullOrder,
    /// q, q̇, q̈ (r each), advanced by Wilson-θ in q; the full-order motion is u(q),
    /// u̇ = P(q) q̇, ü = P(q) q̈ + 2 W k(q̇) (the manifold's own acceleration: for a quadratic k,
    /// d²k/dt² = k'(q) q̈ + 2 k(q̇)). What a reduced runtime would carry.
    Coordinates,
}

/// g(q): the projected residual (r) at the coordinates q (r).
type ReducedResidual<'a> = dyn FnMut(&DVector<f64>) -> Result<DVector<f64>, TierError> + 'a;

/// Newton on g(q) = 0 from `q` with a forward-difference Jacobian (steps 1e-7 × the larger of
/// the coordinate's scale and its value); true when ‖δ‖ ≤ `tolerance` ‖q‖ within
/// `max_iterations`. Counts iterations into `iterations`.
fn newton(
    q: &mut DVector<f64>,
    scales: &[f64],
    tolerance: f64,
    max_iterations: usize,
    iterations: &mut usize,
    g: &mut ReducedResidual<'_>,
) -> Result<bool, TierError> {
    let r = q.len();
    for _ in 0..max_iterations {
        let g0 = g(q)?;
        let mut jacobian = DMatrix::zeros(r, r);
        for l in 0..r {
            let h = 1e-7 * scales[l].max(q[l].abs());
            let mut shifted = q.clone();
            shifted[l] += h;
            jacobian.set_column(l, &((g(&shifted)? - &g0) / h));
        }
        let delta = jacobian
            .lu()
            .solve(&(-g0))
            .ok_or_else(|| TierError::Invalid("singular reduced Jacobian".into()))?;
        *q += &delta;
        *iterations += 1;
        if !q.iter().all(|x| x.is_finite()) {
            return Err(TierError::Invalid("non-finite reduced coordinates".into()));
        }
        if delta.norm() <= tolerance * q.norm() {
            return Ok(true);
        }
    }
    Ok(false)
}

/// Runs the load history `loads` (n each, held over each step) open loop on `manifold`
/// (module doc) with its history kept as `history`; Newton converged when
/// ‖δq‖ ≤ `tolerance` ‖q̂‖, at most `max_iterations`.
pub fn galerkin_run(
    full: &FullOrder,
    manifold: &QuadraticManifold,
    loads: &[Vec<f64>],
    tolerance: f64,
    max_iterations: usize,
    history: History,
) -> Result<ManifoldRun, TierError> {
    let n = full.fem.dof_count();
    let r = manifold.order();
    let wilson = full.wilson;
    let mut sim = CorotationalSimulator::new(&full.fem, wilson, NewtonOptions::default())?;
    let tau = wilson.tau();
    let (a0, a1, a2) = (
        wilson.mass_coefficient(),
        wilson.velocity_coefficient(),
        wilson.damping_coefficient(),
    );
    let mut residual = vec![0.0; n];
    let mut run = ManifoldRun::default();
    // Reduced history (History::Coordinates).
    let (mut q, mut qd, mut qdd) = (
        DVector::<f64>::zeros(r),
        DVector::<f64>::zeros(r),
        DVector::<f64>::zeros(r),
    );
    for f in loads {
        let mut q_hat = match history {
            // The projection of the full-order Taylor predictor U + τU̇ + τ²/2 Ü.
            History::FullOrder => {
                let predicted: Vec<f64> = (0..n)
                    .map(|i| {
                        sim.displacement()[i]
                            + tau * sim.velocity()[i]
                            + 0.5 * tau * tau * sim.acceleration()[i]
                    })
                    .collect();
                manifold.project(&predicted)
            }
            History::Coordinates => &q + tau * &qd + 0.5 * tau * tau * &qdd,
        };
        let (q0, qd0, qdd0) = (&q, &qd, &qdd);
        let (sim_ref, residual_ref) = (&mut sim, &mut residual);
        let mut g: Box<ReducedResidual<'_>> = match history {
            History::FullOrder => Box::new(move |x: &DVector<f64>| {
                let u = manifold.lift(x.as_slice());
                sim_ref.step_residual(u.as_slice(), f, residual_ref)?;
                Ok(manifold
                    .tangent(x.as_slice())
                    .tr_mul(&DVector::from_column_slice(residual_ref)))
            }),
            History::Coordinates => Box::new(move |x: &DVector<f64>| {
                // Wilson-θ rates at t + τ in q, lifted with the manifold's tangent.
                let dq = x - q0;
                let acc = a0 * &dq - a1 * qd0 - 2.0 * qdd0;
                let vel = a2 * &dq - 2.0 * qd0 - 0.5 * tau * qdd0;
                let p = manifold.tangent(x.as_slice());
                let u = manifold.lift(x.as_slice());
                let u_vel = &p * &vel;
                let u_acc = &p * &acc + 2.0 * manifold.quadratic_part(vel.as_slice());
                sim_ref.dynamic_residual(
                    u.as_slice(),
                    u_vel.as_slice(),
                    u_acc.as_slice(),
                    f,
                    residual_ref,
                )?;
                Ok(p.tr_mul(&DVector::from_column_slice(residual_ref)))
            }),
        };
        let converged = newton(
            &mut q_hat,
            &manifold.scales,
            tolerance,
            max_iterations,
            &mut run.iterations,
            &mut *g,
        )?;
        drop(g);
        if !converged {
            run.unconverged += 1;
        }
        match history {
            History::FullOrder => {
                sim.accept_step(manifold.lift(q_hat.as_slice()).as_slice())?;
                run.states.push(sim.displacement().to_vec());
            }
            History::Coordinates => {
                for i in 0..r {
                    (q[i], qd[i], qdd[i]) = wilson.advance(q[i], qd[i], qdd[i], q_hat[i]);
                }
                run.states
                    .push(manifold.lift(q.as_slice()).iter().copied().collect());
            }
        }
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
    let mut q = DVector::zeros(r);
    let mut iterations = 0;
    for k in 1..=increments.max(1) {
        let scale = k as f64 / increments.max(1) as f64;
        let converged = newton(
            &mut q,
            &manifold.scales,
            tolerance,
            50,
            &mut iterations,
            &mut |x| {
                let u = manifold.lift(x.as_slice());
                let internal = sim.internal_force(u.as_slice())?;
                let r: Vec<f64> = f
                    .iter()
                    .zip(&internal)
                    .map(|(a, b)| scale * a - b)
                    .collect();
                Ok(manifold.tangent(x.as_slice()).tr_mul(&DVector::from_vec(r)))
            },
        )?;
        if !converged {
            return Err(TierError::Invalid(format!(
                "static Galerkin did not converge at load factor {scale}"
            )));
        }
    }
    Ok(manifold.lift(q.as_slice()).iter().copied().collect())
}
