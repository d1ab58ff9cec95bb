//! The time step's own error: a scene's reduced model against the full-order linear FEM
//! stepped with the same scheme at the scene's Δt (the reduction's error alone, what the
//! compile reports as its measured error) and against the converged full-order response (the
//! error a user sees), per load test: the compile's step and chirp on every load group, and a
//! unit step on each input channel alone.
//!
//! ```text
//! cargo run --release -p crokf-verify --example time_error -- SCENE [--scheme wilson-theta|exact]
//!     [--order R] [--substeps N]
//! ```
//! `--scheme` replaces the scene's `[time] scheme`; `--order` the order rule (else the scene's
//! rule as the compile applies it, measured against the same-scheme reference); the converged
//! reference steps Δt/N (default 16) with the acceleration restarted where the load changes
//! (`accuracy::Stepping::Converged`), and its own error is estimated from the run at Δt/(N/2)
//! (second order: a third of their difference).

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::accuracy::{self, ReferenceResponses, Stepping};
use crokf_compile::reduce::Order;
use crokf_compile::reductor::Reductor;
use crokf_compile::scene::Scheme;
use crokf_compile::timer::StageTimer;
use crokf_compile::FullOrder;

struct Args {
    scene: PathBuf,
    scheme: Option<Scheme>,
    order: Option<usize>,
    substeps: usize,
}

fn parse() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let scene = it.next().ok_or(
        "usage: time_error SCENE [--scheme wilson-theta|exact] [--order R] [--substeps N]",
    )?;
    let mut args = Args {
        scene: scene.into(),
        scheme: None,
        order: None,
        substeps: 16,
    };
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--scheme" => {
                args.scheme = Some(match value.as_str() {
                    "wilson-theta" => Scheme::WilsonTheta,
                    "exact" => Scheme::Exact,
                    _ => return Err(format!("--scheme {value}: wilson-theta or exact")),
                })
            }
            "--order" => {
                args.order = Some(value.parse().map_err(|e| format!("--order {value}: {e}"))?)
            }
            "--substeps" => {
                let n: usize = value
                    .parse()
                    .map_err(|e| format!("--substeps {value}: {e}"))?;
                if n < 2 || !n.is_multiple_of(2) {
                    return Err(format!("--substeps {n}: an even number ≥ 2"));
                }
                args.substeps = n;
            }
            _ => return Err(format!("unknown flag {flag}")),
        }
    }
    Ok(args)
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let mut timer = StageTimer::default();
    let mut full = FullOrder::build(&args.scene, &mut timer)?;
    if let Some(scheme) = args.scheme {
        full.scene.scene.time.scheme = scheme;
    }
    let scheme = full.scene.scene.time.scheme;
    let reductor = Reductor::new(&full, None, &mut timer)?;
    let reduced = match args.order {
        Some(r) => reductor.reduce(Order::Fixed(r))?,
        None => reductor.reduce_by_rule(None, None, true)?.0,
    };
    let (steps, f_high) = reductor.measure_plan();
    let mut tests = accuracy::standard_tests(&full, steps, f_high);
    tests.extend(accuracy::channel_steps(&full, steps));
    let simulate = |stepping| {
        ReferenceResponses::simulate_with(&full, &reductor.rows, tests.clone(), stepping)
    };
    let same = simulate(Stepping::SameScheme)?;
    let converged = simulate(Stepping::Converged {
        substeps: args.substeps,
    })?;
    let coarser = simulate(Stepping::Converged {
        substeps: args.substeps / 2,
    })?;
    let own = converged.relative_difference(&coarser);
    let scheme_error = converged.relative_difference(&same);
    let against_same = same.errors(&reduced);
    let against_converged = converged.errors(&reduced);
    println!(
        "{}: scheme {}, Δt = {} s, r = {}, {steps} steps a test, chirp to {f_high:.1} Hz, \
         converged reference Δt/{}",
        args.scene.display(),
        scheme.name(),
        full.wilson.dt,
        reduced.balanced_order,
        args.substeps
    );
    println!(
        "| test | reduced vs full-order Wilson-θ at Δt | reduced vs converged | full-order Wilson-θ at Δt vs converged | reference's own |"
    );
    println!("|---|---:|---:|---:|---:|");
    for test in &tests {
        let name = &test.name;
        println!(
            "| {name} | {:.2e} | {:.2e} | {:.2e} | {:.1e} |",
            against_same[name],
            against_converged[name],
            scheme_error[name],
            own[name] / 3.0
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("time_error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("time_error: {e}");
            ExitCode::FAILURE
        }
    }
}
