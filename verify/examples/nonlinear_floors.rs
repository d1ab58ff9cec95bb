//! Prints the error floors of the co-rotational tier (docs/design.md §10) for
//! one scene and scenario: projection error against basis size per candidate basis, and the
//! best fit of the warped linear read-out.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example nonlinear_floors -- \
//!     SCENE SCENARIO LOAD=RANGE_N TRAINING_DURATION_S [SNAPSHOT_EVERY]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_verify::nonlinear::floors::{floors, FloorOptions};
use crokf_verify::nonlinear::training::TrainingPlan;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        eprintln!("usage: nonlinear_floors SCENE SCENARIO LOAD=RANGE_N TRAINING_DURATION_S [SNAPSHOT_EVERY]");
        return ExitCode::FAILURE;
    }
    let Some((load, range)) = args[2].split_once('=') else {
        eprintln!("expected LOAD=RANGE_N, got '{}'", args[2]);
        return ExitCode::FAILURE;
    };
    let (Ok(range), Ok(duration)) = (range.parse::<f64>(), args[3].parse::<f64>()) else {
        eprintln!("RANGE_N and TRAINING_DURATION_S must be numbers");
        return ExitCode::FAILURE;
    };
    let every = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(5);
    let options = FloorOptions {
        plan: TrainingPlan::axes(vec![(load.to_owned(), range)], duration, every),
        sizes: vec![3, 5, 10, 15, 20, 25, 30, 40, 60],
        derivative_modes: 4,
        warped_every: 5,
    };
    let started = std::time::Instant::now();
    let result = floors(
        &PathBuf::from(&args[0]),
        &PathBuf::from(&args[1]),
        &options,
        &mut |line| eprintln!("[{:7.1} s] {line}", started.elapsed().as_secs_f64()),
    );
    match result {
        Ok(table) => {
            println!("{}", table.markdown());
            for (label, failure) in &table.training.runs {
                if let Some(why) = failure {
                    println!("training run '{label}' failed: {why}");
                }
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
