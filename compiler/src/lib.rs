//! crokf-compile: the offline half of CROKF-FEM.
//!
//! Data flows one way, one pipeline stage per module:
//!
//! ```text
//! scene ─▶ mesh ─▶ fem ─▶ dynamics ─▶ reduce ─▶ kalman ─▶ corotation ─▶ model file
//!                     └──▶ reference (full-order simulators, for verification)
//! ```
//!
//! See `DESIGN.md` in the shared notes for the equations each module implements.

pub mod comparison;
pub mod compile;
pub mod accuracy;
pub mod bench;
pub mod corotation;
pub mod dynamics;
pub mod fem;
pub mod generate;
pub mod kalman;
pub mod mesh;
pub mod reduce;
pub mod reference;
pub mod report;
pub mod scene;
