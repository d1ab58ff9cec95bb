//! crokf-compile: the offline half of CROKF-FEM (docs/design.md).
//!
//! Data flows one way, one pipeline stage per module:
//!
//! ```text
//! scene ─▶ mesh ─▶ fem ─▶ dynamics ─▶ reduce ─▶ noise (the filters' noise; DARE in algorithms) ─▶ model_file
//!                   │        (corotation: rotation rows for warping, outputs: the kept rows)
//!                   ├──▶ stepping (full-order linear and co-rotational Wilson-θ)
//!                   └──▶ nonlinear (the co-rotational tier: training, basis, cubature)
//! ```
//!
//! Below every stage, [`algorithms`] holds what knows no physics (Krylov–Schur, POD, NNLS, the
//! Kalman filter's DARE and Stein solvers) and imports nothing else of the crate.
//! Beside the stages: [`full_order`] (the front end, built once), [`reductor`] (build once,
//! reduce at many orders), [`reduced`] (one reduced system), [`accuracy`] (measured error
//! against the full-order reference), [`timer`] (stage costs), [`report`], [`check`] (`--check`), and [`compile()`], which
//! only wires them. Stages never import the wiring; [`error`] holds the boundary error type.
//! After the compile, [`identify`] (`crokf-compile identify`) fits a compiled tier's noise to
//! a recording and writes it into a copy of the scene.
//! Verification (scenarios, comparison reports, benchmarks) lives in the `crokf-verify` crate.

pub mod scene;

pub mod mesh;

pub mod fem;

pub mod corotation;
pub mod dynamics;
pub mod outputs;

pub mod reduce;
pub mod reduced;

pub mod contact;

pub mod noise;
pub mod observability;

pub mod model_file;

pub mod nonlinear;

pub mod stepping;

pub mod accuracy;
pub mod advice;
pub mod algorithms;
pub mod check;
pub mod compile;
pub mod error;
pub mod full_order;
pub mod identify;
pub mod progress;
pub mod reductor;
pub mod report;
pub mod step_error;
pub mod timer;

pub use compile::{compile, CompileOptions, Compiled};
pub use error::CompileError;
pub use full_order::{FullOrder, COMPILER_VERSION};
pub use reductor::Reductor;
