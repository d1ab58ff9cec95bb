//! The co-rotational tier (docs/design.md §10): a small nonlinear reduced model that evaluates
//! the same co-rotational element forces as the full-order reference
//! ([`crate::stepping::corotational`]) in a displacement basis V, on a few weighted elements.
//! One module per job, data flowing down the list:
//!
//! - [`training`]: the compiler's training runs (full-order co-rotational, generated from the
//!   scene's `[reduction.corotational]` envelope);
//! - [`cases`]: the training runs as independent cases with content identities, their results
//!   as files in a cache folder (resumable, computed anywhere);
//! - [`basis`]: candidate bases (modes + static correction, static modal derivatives, POD of
//!   co-rotational snapshots), M-orthonormalisation, projection errors and the tier's choice
//!   ([`basis::BasisChoice`]: pooled POD, per-run enrichment in the energy norm);
//! - [`manifold`]: a quadratic manifold u = Vq + W k(q) fitted to snapshots (measured on the
//!   twist, not in the product);
//! - [`ecsw`]: element sampling and non-negative weights (ECSW, Lawson–Hanson NNLS);
//! - [`cubature`]: the sampled elements and their weights as one object (trained by ECSW,
//!   evaluated by the reduced model, stored by the model file);
//! - [`reduced`]: the reduced co-rotational Wilson-θ stepper on q with Newton on the reduced
//!   tangent;
//! - [`tier`]: training → basis → cubature → reduced model;
//! - [`filter`]: the filter design (linearisation at rest and at training states, DARE in
//!   scaled modal coordinates, gain schedule);
//! - [`levels`]: the same filter at several levels of the force σ and the innovation statistic
//!   the runtime moves between them with;
//! - [`self_check`]: the compiled tier re-run on its own training loads against the training
//!   snapshots (in-sample error per run, a warning above 5 %), and a tier built without some
//!   runs re-run on those (out of sample);
//! - [`fidelity`]: the basis size and cubature accuracy chosen on the out-of-sample error when
//!   the scene does not state them.
//!
//! The model file's tier section lives with the other sections (`crate::model_file::tier`),
//! the identification of its noise from a recording in `crate::identify` (`als_noise`);
//! `crate::reductor::tier::TierReductor` wires the tier into a compile. The floors of candidate
//! bases and the scenario-driven open-loop comparisons live in `crokf-verify`
//! (`crokf_verify::nonlinear`), which reuses [`training`] and [`tier`].

pub mod basis;
pub mod cases;
pub mod cubature;
pub mod ecsw;
pub mod fidelity;
pub mod filter;
pub mod levels;
pub mod manifold;
pub mod reduced;
pub mod self_check;
pub mod tier;
pub mod time_error;
pub mod training;

use crate::error::CompileError;
use crate::reduce::ReduceError;
use crate::stepping::SteppingError;

/// Errors of the co-rotational tier.
#[derive(Debug, thiserror::Error)]
pub enum NonlinearError {
    /// Full-order stepping (training or reference run).
    #[error(transparent)]
    Stepping(#[from] SteppingError),
    /// Reading the scene or assembling the full-order model.
    #[error(transparent)]
    Compile(#[from] Box<CompileError>),
    /// Modal basis.
    #[error(transparent)]
    Reduce(#[from] ReduceError),
    /// The scene's noise model.
    #[error("tier filter: {0}")]
    Noise(#[from] crate::noise::NoiseError),
    /// Inconsistent arguments (what is wrong, naming the offending item).
    #[error("{0}")]
    Invalid(String),
    /// The reduced Newton matrix is not positive definite.
    #[error(
        "reduced co-rotational step {step} (t = {time:.6e} s): the reduced Newton matrix \
         ({order}×{order}) is not positive definite at pivot {pivot}"
    )]
    NotPositiveDefinite {
        /// Step index (1-based).
        step: usize,
        /// Time at the start of the step, s.
        time: f64,
        /// r.
        order: usize,
        /// Failing pivot.
        pivot: usize,
    },
    /// The reduced state became non-finite.
    #[error("reduced co-rotational step {step} (t = {time:.6e} s): non-finite reduced state")]
    NonFinite {
        /// Step index (1-based).
        step: usize,
        /// Time at the start of the step, s.
        time: f64,
    },
}

impl From<CompileError> for NonlinearError {
    fn from(e: CompileError) -> Self {
        NonlinearError::Compile(Box::new(e))
    }
}
