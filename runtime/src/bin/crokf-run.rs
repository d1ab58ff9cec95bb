//! `crokf-run MODEL --inputs inputs.csv [--measurements m.csv] --out estimates.csv [--vtu DIR]`
//!
//! Runs the estimator over an input history (and optional measurements) and writes the
//! estimated sensor displacements (world frame) and their standard deviations per step.

use clap::Parser;
use crokf_runtime::{csv, load_model, vtu, Estimator, RuntimeError};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Run a crokf model over recorded inputs and measurements.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Model file written by crokf-compile.
    model: PathBuf,
    /// Inputs CSV: `step` (or `t`), then one column per input label; rows are steps 1, 2, ….
    #[arg(long)]
    inputs: PathBuf,
    /// Measurements CSV: `step` (or `t`), then columns `sensor.x|y|z`; empty cell = missing.
    #[arg(long)]
    measurements: Option<PathBuf>,
    /// Output CSV: step, t, estimated sensor displacements, their standard deviations.
    #[arg(long)]
    out: PathBuf,
    /// Also write one .vtu per step and estimates.pvd into this directory.
    #[arg(long)]
    vtu: Option<PathBuf>,
    /// With --vtu: write every N-th step only.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    vtu_every: u64,
}

fn write_err(path: &Path) -> impl Fn(std::io::Error) -> RuntimeError + '_ {
    move |source| RuntimeError::Write {
        path: path.to_path_buf(),
        source,
    }
}

fn run(args: &Args) -> Result<(), RuntimeError> {
    let model = load_model(&args.model)?;
    let inputs = csv::read_inputs(&args.inputs, &model)?;
    let measurements = match &args.measurements {
        Some(p) => csv::read_measurements(p, &model)?,
        None => Default::default(),
    };
    let mut est = Estimator::new(&model)?;
    let q = model.measurements.len();
    let ns = model.sensors.len();
    let none = vec![None; q];
    let mut u = vec![0.0; 3 * ns];
    let mut sd = vec![0.0; 3 * ns];
    let file = std::fs::File::create(&args.out).map_err(write_err(&args.out))?;
    let mut out = std::io::BufWriter::new(file);
    writeln!(out, "{}", csv::estimates_header(&model)).map_err(write_err(&args.out))?;
    if let Some(dir) = &args.vtu {
        std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    }
    let mut pvd = Vec::new();
    for row in &inputs.rows {
        let k = est.step_index() + 1;
        let y = measurements.get(&k).unwrap_or(&none);
        est.step(row, y)?;
        est.sensor_displacements(&mut u)?;
        est.sensor_std(&mut sd)?;
        let mut line = format!("{},{}", k, est.time());
        for v in u.iter().chain(&sd) {
            line.push_str(&format!(",{v:e}"));
        }
        writeln!(out, "{line}").map_err(write_err(&args.out))?;
        if let Some(dir) = &args.vtu {
            if k % args.vtu_every == 0 {
                pvd.push((est.time(), vtu::write_step(dir, &est)?));
            }
        }
    }
    out.flush().map_err(write_err(&args.out))?;
    if let Some(dir) = &args.vtu {
        vtu::write_pvd(dir, &pvd)?;
    }
    if let Some(&last) = measurements.keys().next_back() {
        if last > inputs.rows.len() as u64 {
            eprintln!(
                "warning: measurements after step {} (the last input row) were ignored",
                inputs.rows.len()
            );
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("crokf-run: {e}");
            ExitCode::FAILURE
        }
    }
}
