//! crokf-compile: the offline half of CROKF-FEM.
//!
//! Data flows one way, one pipeline stage per module:
//!
//! ```text
//! scene ─▶ mesh ─▶ fem ─▶ dynamics ─▶ reduce ─▶ kalman ─▶ corotation ─▶ model file
//!                     └──▶ reference (full-order simulators, for verification)
//! ```
//!
//! `compile` wires the stages; `accuracy` measures the reduced model against the full-order
//! reference, `comparison` produces the speed-against-error report, `report` records stage
//! costs, `bench` and `generate` serve the benchmarks. See `DESIGN.md` in the shared notes for
//! the equations each module implements.

pub mod accuracy;
pub mod bench;
pub mod comparison;
pub mod compile;
pub mod corotation;
pub mod dynamics;
pub mod fem;
pub mod generate;
pub mod kalman;
pub mod mesh;
pub mod nonlinear;
pub mod reduce;
pub mod reference;
pub mod report;
pub mod scene;
