//! `crokf-verify`: verification tools for CROKF-FEM models.
//!
//! ```text
//! crokf-verify simulate SCENE SCENARIO --model linear|corotational --out DIR [--vtu] [--every k]
//! ```
//! runs the full-order reference (linear or co-rotational Wilson-θ) through a scenario and
//! writes `DIR/trajectories.csv` and, with `--vtu`, `DIR/frames/frame_NNNN.vtu` + `DIR/series.pvd`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};
use crokf_compile::reference::{self, Model, NewtonOptions, SimulationOptions};

#[derive(Parser)]
#[command(
    name = "crokf-verify",
    version,
    about = "Verification tools for CROKF-FEM models"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a full-order reference simulation of a scene through a scenario.
    Simulate(SimulateArgs),
}

#[derive(Clone, Copy, ValueEnum)]
enum ModelArg {
    /// Linear FEM, Wilson-θ matrix factored once.
    Linear,
    /// Co-rotational FEM (per-element polar decomposition, warped stiffness).
    Corotational,
}

#[derive(Args)]
struct SimulateArgs {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Scenario file (TOML): load histories, duration or steady, named points.
    scenario: PathBuf,
    /// Full-order model.
    #[arg(long, value_enum, default_value = "linear")]
    model: ModelArg,
    /// Output directory (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Also write a VTU time series (frames/frame_NNNN.vtu and series.pvd).
    #[arg(long)]
    vtu: bool,
    /// Record every k-th step (the first and last are always recorded).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Co-rotational: most Newton solves per step (1 = one linearised solve).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    max_newton: u64,
    /// Co-rotational: Newton tolerance on ‖δ‖/‖Û‖.
    #[arg(long, default_value_t = 1e-8)]
    tolerance: f64,
    /// Co-rotational: Newton matrix from the warped stiffness R K Rᵀ (classic stiffness
    /// warping) instead of the consistent tangent.
    #[arg(long)]
    warped: bool,
}

fn simulate(args: &SimulateArgs) -> Result<(), reference::ReferenceError> {
    let options = SimulationOptions {
        model: match args.model {
            ModelArg::Linear => Model::Linear,
            ModelArg::Corotational => Model::Corotational,
        },
        newton: NewtonOptions {
            max_newton: args.max_newton as usize,
            tolerance: args.tolerance,
            consistent: !args.warped,
        },
        every: args.every as usize,
    };
    let summary = reference::run(&args.scene, &args.scenario, &options, &args.out, args.vtu)?;
    let t = &summary.trajectories;
    println!(
        "{} DOFs, {} tetrahedra; {} steps to t = {:.6} s, {:.3} ms per step",
        summary.dofs,
        summary.elements,
        t.total_steps,
        t.times.last().copied().unwrap_or(0.0),
        1e3 * t.seconds_per_step
    );
    if let Some(n) = t.newton {
        println!(
            "Newton: {} solves in {} steps, {} steps unconverged, {} warped fallbacks, \
             worst final increment {:.2e}",
            n.solves, n.steps, n.unconverged, n.fallbacks, n.worst_increment
        );
    }
    if let Some(last) = t.values.last() {
        for (label, u) in t.labels.iter().zip(last) {
            println!(
                "  {label}: u = ({:.6e}, {:.6e}, {:.6e}) m",
                u[0], u[1], u[2]
            );
        }
    }
    let shown = summary.files.len().min(3);
    for f in &summary.files[..shown] {
        println!("wrote {}", f.display());
    }
    if summary.files.len() > shown {
        println!("  ... and {} more files", summary.files.len() - shown);
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Simulate(args) => simulate(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
