//! The command line of `crokf-compile identify` (`crokf-verify identify` is the same command):
//! its arguments ([`IdentifyArgs`]) and [`run`], which prints the report on stdout, a refusal
//! on stderr, and gives the exit status.

use std::path::PathBuf;
use std::process::ExitCode;

use super::files::{identify_files, Files};
use super::identification::{IdentifyError, IdentifyOptions};

/// The command's one-paragraph description (`--help`).
pub const ABOUT: &str = "Identify the force σ of a co-rotational model's estimated loads from a \
    recording (autocovariance least squares on the filter's innovations), with an uncertainty \
    over 4 disjoint blocks; -o writes a copy of the scene with the identified force_noise_std. \
    A refusal exits with status 2 and writes nothing.";

/// The exit status of a refusal (every [`IdentifyError`]).
pub const REFUSED: u8 = 2;

/// `identify SCENE MODEL --measurements M.csv [--inputs I.csv] [-o IDENTIFIED.toml]
/// [--fixed-point] [--lags L] [--skip S]`.
#[derive(clap::Args, Clone, Debug)]
pub struct IdentifyArgs {
    /// Scene file (TOML) the model was compiled from.
    pub scene: PathBuf,
    /// Model file (.crokf) with a co-rotational tier.
    pub model: PathBuf,
    /// Recorded markers (crokf-run's measurements CSV: `step` or `t`, then `sensor.x`, …).
    #[arg(long)]
    pub measurements: PathBuf,
    /// Recorded inputs (crokf-run's inputs CSV); without it every input is 0 (loads withheld).
    #[arg(long)]
    pub inputs: Option<PathBuf>,
    /// Write a copy of SCENE with each identified load's force_noise_std (same folder as
    /// SCENE).
    #[arg(short = 'o', long = "out", value_name = "IDENTIFIED.toml")]
    pub out: Option<PathBuf>,
    /// Repeat with the filters of the σ just identified until they agree to 1 % (at most 10
    /// runs).
    #[arg(long)]
    pub fixed_point: bool,
    /// Lags of the innovations' autocovariances.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(2..=10_000))]
    pub lags: u64,
    /// Steps left out at the start (the filter's transient from rest).
    #[arg(long, default_value_t = 50)]
    pub skip: u64,
}

/// Runs the command: the report on stdout (also for a refusal by the verdict), then `wrote
/// OUT (…)` when `-o` was written; a refusal as `PROGRAM: identify refused: …` on stderr and
/// exit status [`REFUSED`], nothing written. `program` names the executable in that line.
pub fn run(args: &IdentifyArgs, program: &str) -> ExitCode {
    match identify(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{program}: identify refused: {e}");
            ExitCode::from(REFUSED)
        }
    }
}

/// [`run`] up to its exit status.
fn identify(args: &IdentifyArgs) -> Result<(), IdentifyError> {
    let files = Files {
        scene: &args.scene,
        model: &args.model,
        measurements: &args.measurements,
        inputs: args.inputs.as_deref(),
        out: args.out.as_deref(),
    };
    let options = IdentifyOptions {
        lags: usize::try_from(args.lags)
            .map_err(|_| IdentifyError::Usage(format!("--lags {}: too large", args.lags)))?,
        skip: usize::try_from(args.skip)
            .map_err(|_| IdentifyError::Usage(format!("--skip {}: too large", args.skip)))?,
        fixed_point: args.fixed_point,
        ..IdentifyOptions::default()
    };
    match identify_files(&files, &options) {
        Ok(found) => {
            print!("{}", found.report());
            if let Some(out) = &args.out {
                let mut written: Vec<String> = found
                    .excited_loads()
                    .map(|l| format!("force_noise_std of {}", l.name))
                    .collect();
                if found.model_error_changed().is_some() {
                    written.push("[reduction.corotational] model_error_scale".into());
                }
                println!("wrote {} ({})", out.display(), written.join(", "));
            }
            Ok(())
        }
        Err(refusal) => {
            if let Some(found) = &refusal.found {
                print!("{}", found.report());
            }
            Err(refusal.error)
        }
    }
}
