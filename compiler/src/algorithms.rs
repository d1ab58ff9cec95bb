//! Algorithms that know no physics: each takes matrices, vectors and tolerances and returns
//! numbers, and imports nothing else of the crate (`tests/tests/imports.rs` checks it). The
//! reductors wire them to the models (pyMOR's split of models, reductors and algorithms).
//!
//! - [`krylov`]: block shift-invert Krylov–Schur (thick-restart block Lanczos) for the lowest
//!   eigenpairs of K φ = λ M φ, used by [`crate::reduce::modal_basis`];
//! - [`pod`]: proper orthogonal decomposition in the M inner product (the co-rotational tier's
//!   basis, [`crate::nonlinear::basis`]);
//! - [`nnls`]: Lawson–Hanson non-negative least squares with an early stop (ECSW's element
//!   sampling, [`crate::nonlinear::ecsw`]);
//! - [`kalman`]: the steady-state and periodic Kalman filter (DARE by the structure-preserving
//!   doubling algorithm, Stein equations), its consistency checks, ramp lag, innovation
//!   statistics and autocovariance least squares (the filter design of
//!   [`crate::noise`] and [`crate::nonlinear::filter`], identification's noise fit);
//! - [`sparse`]: entry-order products with compressed-column sparse matrices.

pub mod kalman;
pub mod krylov;
pub mod nnls;
pub mod pod;
pub mod sparse;
