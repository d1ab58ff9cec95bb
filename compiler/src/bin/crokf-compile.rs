//! `crokf-compile`: gmsh mesh + scene → hashed, deterministic reduced Kalman model file.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

use crokf_compile::check::{check, CheckOutcome};
use crokf_compile::fem::export::export_matrices;
use crokf_compile::report::StageTimer;
use crokf_compile::{compile, CompileOptions, FullOrder};

/// Compile a scene (TOML) and its gmsh mesh into a crokf model file.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None)]
struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output model file.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Write the compile report as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Balanced truncation order r (overrides the scene).
    #[arg(long)]
    order: Option<usize>,
    /// Relative Hankel singular value tolerance σ_{r+1}/σ₁ (overrides the scene).
    #[arg(long)]
    tolerance: Option<f64>,
    /// Number of vibration modes kept before balancing (overrides the scene).
    #[arg(long)]
    modes: Option<usize>,
    /// Skip the measured error against the full-order linear reference (step and chirp).
    #[arg(long)]
    no_measure: bool,
    /// Write K, M, C, B, H (Matrix Market) and dofs.csv into this directory and stop.
    #[arg(long, value_name = "DIR")]
    export_matrices: Option<PathBuf>,
    /// Check that MODEL was compiled from SCENE's current inputs by this compiler version;
    /// exits non-zero when it is stale (for CI).
    #[arg(long, value_name = "MODEL")]
    check: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(code) => code,
        Err(message) => {
            eprintln!("crokf-compile: error: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<ExitCode, String> {
    if let Some(model) = &args.check {
        return match check(model, &args.scene).map_err(|e| e.to_string())? {
            CheckOutcome::UpToDate => {
                eprintln!(
                    "{}: up to date with {}",
                    model.display(),
                    args.scene.display()
                );
                Ok(ExitCode::SUCCESS)
            }
            CheckOutcome::Stale(why) => {
                eprintln!(
                    "{}: STALE: {why}; rebuild with `crokf-compile {} -o {}`",
                    model.display(),
                    args.scene.display(),
                    model.display()
                );
                Ok(ExitCode::from(2))
            }
        };
    }
    if let Some(dir) = &args.export_matrices {
        let mut timer = StageTimer::default();
        let full = FullOrder::build(&args.scene, &mut timer).map_err(|e| e.to_string())?;
        export_matrices(&full.fem, &full.operators, dir)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        eprintln!(
            "wrote K, M, C ({n}×{n}), B ({n}×{m}), H and dofs.csv to {}",
            dir.display(),
            n = full.fem.dof_count(),
            m = full.operators.inputs.len()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let options = CompileOptions {
        order: args.order,
        tolerance: args.tolerance,
        modes: args.modes,
        skip_measured_error: args.no_measure,
    };
    let compiled = compile(&args.scene, &options).map_err(|e| e.to_string())?;
    eprint!("{}", compiled.summary());
    if let Some(path) = &args.output {
        std::fs::write(path, &compiled.bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        eprintln!("wrote {} ({} bytes)", path.display(), compiled.bytes.len());
    }
    if let Some(path) = &args.report {
        std::fs::write(path, compiled.report_json())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if args.output.is_none() && args.report.is_none() {
        eprintln!("(no -o given: nothing written)");
    }
    Ok(ExitCode::SUCCESS)
}
