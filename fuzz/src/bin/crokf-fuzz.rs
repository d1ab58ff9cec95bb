//! `crokf-fuzz [--target all|scene|mesh|csv|vtu|node_list] [--cases N] [--seed S] [--crashes DIR]`: the long
//! structure-aware mutation run of crokf's readers. Prints, per target, the
//! cases, how many were accepted and refused, the time and the rate; every panic or invariant
//! violation is written to DIR (default: the current folder) as `crash-<target>-<case>.bin` and
//! makes the exit status non-zero (written through a temporary file and a rename, like every
//! output of the tools). The model-file decoder's run is
//! `cargo run --release -p crokf-formats --example mutate`.

use clap::Parser;
use crokf_fuzz::{run, Fixtures, Target};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    about = "Structure-aware mutation fuzzing of the scene, mesh, CSV, VTK (claimed sizes) and node-list readers"
)]
struct Args {
    /// `all`, `scene`, `mesh`, `csv`, `vtu` (VTK files with mutated claimed sizes) or
    /// `node_list`.
    #[arg(long, default_value = "all")]
    target: String,
    /// Cases per target.
    #[arg(long, default_value_t = 1_000_000)]
    cases: u64,
    /// Seed of the mutation sequence.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Folder for the inputs that crashed.
    #[arg(long, default_value = ".")]
    crashes: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let targets: Vec<Target> = match args.target.as_str() {
        "all" => Target::ALL.to_vec(),
        name => match Target::ALL.iter().find(|t| t.name() == name) {
            Some(t) => vec![*t],
            None => {
                eprintln!(
                    "error: --target {name:?}: expected all, scene, mesh, csv, vtu or node_list"
                );
                return ExitCode::from(2);
            }
        },
    };
    if !args.crashes.is_dir() {
        eprintln!("error: --crashes {}: not a folder", args.crashes.display());
        return ExitCode::from(2);
    }
    let fixtures = match Fixtures::load() {
        Ok(f) => f,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let mut failed = false;
    for target in targets {
        let t = run(target, args.cases, args.seed, &fixtures);
        println!(
            "{:>5}: {} cases in {:.1} s ({:.0}/s): {} accepted, {} refused, {} failures",
            target.name(),
            t.cases,
            t.seconds,
            t.cases as f64 / t.seconds.max(1e-9),
            t.accepted,
            t.refused,
            t.failures.len()
        );
        for (case, what, data) in &t.failures {
            failed = true;
            let path = args
                .crashes
                .join(format!("crash-{}-{case}.bin", target.name()));
            match crokf_formats::output::write_atomically(&path, data) {
                Ok(()) => println!("  case {case}: {what} (input: {})", path.display()),
                Err(e) => println!("  case {case}: {what} (input not written: {e})"),
            }
        }
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
