//! crokf-verify: verification of CROKF-FEM models against full-order references
//! (docs/design.md §7). Nothing here is needed to compile or run a model.
//!
//! - [`scenario`]: scenario files (load histories, horizons, named points);
//! - [`simulate`]: drives the compiler's full-order steppers through a scenario;
//! - [`vtu`]: ParaView VTU/PVD series of a simulation's frames;
//! - [`comparison`]: speed against error, full-order references vs the runtime at several
//!   orders (one modal system, truncated per order), with Markdown, CSV and SVG output;
//! - [`mod@bench`]: structured benchmark meshes and benchmarks (medians, ratios in
//!   one run).

pub mod bench;
pub mod comparison;
pub mod contact;
pub mod nonlinear;
pub mod scenario;
pub mod simulate;
pub mod vtu;

/// The exit of a measuring example (`verify/examples/*`: `fn main() -> ExitCode {
/// crokf_verify::exit(run()) }`): success for `Ok`; for an error, `NAME: error: …` in its
/// `Display` form (a `Result`-returning `main` would print its `Debug` form) on stderr and
/// failure, NAME being the example's executable (`tier_scale`, …) as the crokf binaries name
/// themselves (`crokf-compile: error: …`).
pub fn exit<E: std::fmt::Display>(result: Result<(), E>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{}", error_line(&executable_name(), &e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The running executable's file stem (`tier_scale` for `target/release/examples/tier_scale`),
/// `crokf-verify` when the OS gives none.
fn executable_name() -> String {
    crokf_compile::progress::executable_stem().unwrap_or_else(|| "crokf-verify".to_owned())
}

/// `NAME: error: MESSAGE`, the error line of every crokf executable.
fn error_line(name: &str, error: &dyn std::fmt::Display) -> String {
    format!("{name}: error: {error}")
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_example_error_line_names_the_example() {
        // The test harness's executable is `crokf_verify-HASH`.
        assert!(super::executable_name().starts_with("crokf_verify-"));
        assert_eq!(
            super::error_line("tier_scale", &"scene.toml: no such file"),
            "tier_scale: error: scene.toml: no such file"
        );
    }
}
