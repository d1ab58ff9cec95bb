//! crokf-verify: verification of CROKF-FEM models against full-order references
//! (docs/design.md §7). Nothing here is needed to compile or run a model.
//!
//! - [`scenario`]: scenario files (load histories, horizons, named points);
//! - [`simulate`]: drives the compiler's full-order steppers through a scenario;
//! - [`vtu`]: ParaView VTU/PVD series of a simulation's frames;
//! - [`comparison`]: speed against error, full-order references vs the runtime at several
//!   orders (one modal system, truncated per order), with Markdown, CSV and SVG output;
//! - [`identify`]: the tier's noise identified from a recording (`crokf-verify identify`);
//! - [`mod@bench`]: structured benchmark meshes and benchmarks (medians, ratios in
//!   one run).

pub mod bench;
pub mod comparison;
pub mod identify;
pub mod nonlinear;
pub mod scenario;
pub mod simulate;
pub mod vtu;

/// The exit of a measuring example (`verify/examples/*`: `fn main() -> ExitCode {
/// crokf_verify::exit(run()) }`): success for `Ok`; for an error, `error: …` in its `Display`
/// form (a `Result`-returning `main` would print its `Debug` form) on stderr and failure.
pub fn exit<E: std::fmt::Display>(result: Result<(), E>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
