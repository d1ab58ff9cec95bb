//! Verification drivers of the co-rotational tier (docs/design.md §10; the tier's model is
//! `crokf_compile::nonlinear`): training runs over generated load histories, the error floors
//! of candidate bases on reference trajectories, and the open-loop and elastica comparisons of
//! the hyper-reduced model against the full-order co-rotational FEM.
//!
//! `cargo run --release -p crokf-verify --example nonlinear_floors -- …` and
//! `--example nonlinear_tier -- …` print the tables of `docs/results/tier.md`.

pub mod floors;
pub mod manifold;
pub mod reference;
pub mod sampling;
pub mod tier;
pub mod training;

use crokf_compile::nonlinear::NonlinearError;
use crokf_compile::stepping::SteppingError;
use crokf_compile::CompileError;

use crate::scenario::ScenarioError;
use crate::simulate::SimulateError;

/// Errors of the tier's verification drivers.
#[derive(Debug, thiserror::Error)]
pub enum TierError {
    /// The reduced model or its basis.
    #[error(transparent)]
    Nonlinear(#[from] NonlinearError),
    /// Modal basis.
    #[error(transparent)]
    Reduce(#[from] crokf_compile::reduce::ReduceError),
    /// A full-order run.
    #[error(transparent)]
    Stepping(#[from] SteppingError),
    /// A scenario-driven full-order run.
    #[error(transparent)]
    Simulate(#[from] Box<SimulateError>),
    /// Scenario file.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// Scene, mesh or assembly.
    #[error(transparent)]
    Compile(#[from] Box<CompileError>),
    /// The runtime (an oracle run through the model's `Estimator`).
    #[error(transparent)]
    Runtime(#[from] crokf_runtime::RuntimeError),
    /// Inconsistent arguments (what is wrong, naming the offending item).
    #[error("{0}")]
    Invalid(String),
}

impl From<SimulateError> for TierError {
    fn from(e: SimulateError) -> Self {
        TierError::Simulate(Box::new(e))
    }
}

impl From<CompileError> for TierError {
    fn from(e: CompileError) -> Self {
        TierError::Compile(Box::new(e))
    }
}
