//! Full-order time stepping (docs/design.md §2, §7): the static solution, linear Wilson-θ with
//! J factored once ([`LinearSimulator`]) and co-rotational Wilson-θ with per-element polar
//! decomposition and the exact consistent tangent ([`CorotationalSimulator`]).
//!
//! Production needs them (the measured error of a compile, the training runs of the
//! co-rotational tier); verification drives them through scenario files in `crokf-verify`.
//! Loads are world-frame dead loads. Both simulators start at rest (U = U̇ = Ü = 0), like the
//! reduced model's s₀ = 0.

pub mod corotational;
pub mod element;
pub mod linear;
pub mod load_stepping;
mod sparse;

pub use corotational::{CorotationalSimulator, ModifiedNewton, NewtonOptions, NewtonStats};
pub use element::{
    deformation_gradient, element_force, element_tangent, polar_rotation, polar_rotation_svd,
};
pub use linear::{static_solve, LinearSimulator, StaticSolver};

use crate::dynamics::WilsonTheta;
use crate::fem::FemModel;

/// Errors of the full-order steppers.
#[derive(Debug, thiserror::Error)]
pub enum SteppingError {
    /// A matrix that must be symmetric positive definite is not.
    #[error(
        "{what} ({n}×{n}) is not positive definite ({detail}): the model has unconstrained \
         rigid-body modes (add a [[fixed]] group) or inverted elements"
    )]
    NotPositiveDefinite {
        /// Which matrix.
        what: String,
        /// Its size.
        n: usize,
        /// Solver detail.
        detail: String,
    },
    /// Any other sparse-solver failure.
    #[error("sparse solver: {0}")]
    Solver(String),
    /// A vector of the wrong length.
    #[error("{what} has length {got}, expected {expected} (the free DOFs)")]
    Dimension {
        /// Which vector.
        what: &'static str,
        /// n.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// Invalid solver options.
    #[error("{0}")]
    Options(String),
    /// The quasi-static co-rotational Newton solve failed even with tiny load increments.
    #[error(
        "co-rotational static solve did not converge: stuck at load factor {load_factor:.4} \
         after {solves} linear solves (load too large for the structure, or buckling)"
    )]
    StaticDiverged {
        /// Load factor reached, 0..1.
        load_factor: f64,
        /// Linear solves spent.
        solves: usize,
    },
    /// The state became NaN or infinite.
    #[error("the simulation diverged (non-finite displacement) at step {step}, t = {time:.6e} s")]
    NonFinite {
        /// Step.
        step: usize,
        /// Time, s.
        time: f64,
    },
}

/// A full-order time stepper over the free DOFs.
pub trait Simulator {
    /// Advances by Δt with the load f (n, N) held constant over the step.
    fn step(&mut self, f: &[f64]) -> Result<(), SteppingError>;
    /// Displacement U (n, m).
    fn displacement(&self) -> &[f64];
    /// Velocity U̇ (n, m/s).
    fn velocity(&self) -> &[f64];
    /// Acceleration Ü (n, m/s²).
    fn acceleration(&self) -> &[f64];
    /// Simulated time, s.
    fn time(&self) -> f64;
    /// Ü ← the acceleration the equation of motion gives at the current state under a load f
    /// (n, N) that starts now: restarted where the load jumps, Wilson-θ stays second order
    /// across the jump (the converged references sub-step this way).
    fn consistent_acceleration(&mut self, f: &[f64]) -> Result<(), SteppingError>;
}

/// Which full-order model to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Formulation {
    /// Linear FEM, J factored once.
    Linear,
    /// Co-rotational FEM (per-element rotation, exact consistent tangent).
    Corotational,
}

/// Builds the chosen simulator (Newton settings apply to the co-rotational one only).
pub fn simulator<'a>(
    fem: &'a FemModel,
    wilson: WilsonTheta,
    formulation: Formulation,
    newton: NewtonOptions,
) -> Result<Box<dyn Simulator + 'a>, SteppingError> {
    Ok(match formulation {
        Formulation::Linear => Box::new(LinearSimulator::new(fem, wilson)?),
        Formulation::Corotational => Box::new(CorotationalSimulator::new(fem, wilson, newton)?),
    })
}

/// out[i] = g(U[i], U̇[i], Ü[i]) per DOF.
pub(crate) fn map_state(
    u: &[f64],
    v: &[f64],
    a: &[f64],
    out: &mut [f64],
    g: impl Fn(f64, f64, f64) -> f64,
) {
    for (((o, u), v), a) in out.iter_mut().zip(u).zip(v).zip(a) {
        *o = g(*u, *v, *a);
    }
}

/// [`WilsonTheta::advance`] on every DOF, given Û.
pub(crate) fn advance_all(
    w: &WilsonTheta,
    u: &mut [f64],
    v: &mut [f64],
    a: &mut [f64],
    u_hat: &[f64],
) {
    for (((u, v), a), h) in u.iter_mut().zip(v.iter_mut()).zip(a.iter_mut()).zip(u_hat) {
        (*u, *v, *a) = w.advance(*u, *v, *a, *h);
    }
}

/// Euclidean norm.
pub(crate) fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

pub(crate) fn check_len(
    what: &'static str,
    expected: usize,
    got: usize,
) -> Result<(), SteppingError> {
    if expected == got {
        Ok(())
    } else {
        Err(SteppingError::Dimension {
            what,
            expected,
            got,
        })
    }
}
