//! The co-rotational tier's time-discretisation error, per training run of
//! the scene's tier: the tier against the full-order co-rotational FEM stepped with the same
//! scheme at the scene's Δt (the reduction's error, what the tier's self-check measures), the
//! tier against the converged full-order response (the error a user sees), the full-order
//! Wilson-θ at Δt (and Δt/2) against the converged response (the step's own error), and the
//! converged reference's own error and order (`crokf_compile::nonlinear::time_error`).
//!
//! ```text
//! cargo run --release -p crokf-verify --example tier_time_error -- SCENE [--substeps N]
//!     [--runs all|I,J,…] [--cache DIR]
//! ```
//! The tier is built as `crokf-compile` builds it (training, basis, cubature, self-check,
//! filter; `--cache` reads and fills a training case cache as `crokf-compile --cache` does).
//! `--runs` picks training runs by index (as `crokf-compile SCENE --list-cases` numbers them,
//! from 0; default all); `--substeps` is N of the converged reference (a multiple of 4,
//! default 16): the full-order model at Δt/N with each scene step's load held and the
//! acceleration restarted where the load changes, its own error a third of its difference from
//! Δt/(N/2), its order the ratio of the Δt/(N/4)–Δt/(N/2) and Δt/(N/2)–Δt/N differences.
//! Every figure: relative L2 over the sensors and displayed nodes and every step of the run.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use crokf_compile::nonlinear::self_check::runtime_newton;
use crokf_compile::nonlinear::time_error::{self, RunTimeError};
use crokf_compile::outputs::Measurements;
use crokf_compile::reductor::tier::TierReductor;
use crokf_compile::timer::StageTimer;
use crokf_compile::FullOrder;

const USAGE: &str = "usage: tier_time_error SCENE [--substeps N] [--runs all|I,J,…] [--cache DIR]";

struct Args {
    scene: PathBuf,
    substeps: usize,
    runs: Option<Vec<usize>>,
    cache: Option<PathBuf>,
}

fn parse() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let scene = it.next().ok_or(USAGE)?;
    if scene.starts_with("--") {
        return Err(USAGE.into());
    }
    let mut args = Args {
        scene: scene.into(),
        substeps: 16,
        runs: None,
        cache: None,
    };
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--substeps" => {
                let n: usize = value
                    .parse()
                    .map_err(|e| format!("--substeps {value}: {e}"))?;
                if n < 4 || !n.is_multiple_of(4) {
                    return Err(format!("--substeps {n}: a multiple of 4 (≥ 4)"));
                }
                args.substeps = n;
            }
            "--runs" => {
                args.runs = if value == "all" {
                    None
                } else {
                    Some(
                        value
                            .split(',')
                            .map(|s| {
                                s.trim()
                                    .parse::<usize>()
                                    .map_err(|e| format!("--runs {value}: '{s}': {e}"))
                            })
                            .collect::<Result<_, _>>()?,
                    )
                }
            }
            "--cache" => args.cache = Some(value.into()),
            _ => return Err(format!("unknown flag {flag}\n{USAGE}")),
        }
    }
    Ok(args)
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&args.scene, &mut timer)?;
    let measurements = Measurements::new(&full.operators);
    let started = Instant::now();
    let reductor = TierReductor::new(
        &full,
        &measurements,
        args.cache.as_deref(),
        &mut timer,
        &mut |cache| {
            for line in crokf_compile::compile::tier_notes::cache_lines(cache) {
                eprintln!("tier_time_error: {line}");
            }
        },
    )?;
    let build_seconds = started.elapsed().as_secs_f64();
    let plan = &reductor.plan;
    let runs = plan.runs();
    let selected: Vec<usize> = match &args.runs {
        None => (0..runs.len()).collect(),
        Some(list) => {
            if let Some(&bad) = list.iter().find(|&&k| k >= runs.len()) {
                return Err(format!(
                    "--runs: no run {bad}, the plan has {} (0 … {})",
                    runs.len(),
                    runs.len().saturating_sub(1)
                )
                .into());
            }
            list.clone()
        }
    };
    let newton = runtime_newton(
        reductor.spec.newton_tolerance,
        reductor.spec.newton_iterations,
    );
    let dt = full.wilson.dt;
    println!(
        "{}: Δt = {dt} s, θ = {}, tier r = {}, {} sampled elements (built in {build_seconds:.1} s), \
         {} steps a run, converged reference Δt/{}",
        args.scene.display(),
        full.wilson.theta,
        reductor.tier.model.order(),
        reductor.tier.sampling.weights.len(),
        plan.steps(dt),
        args.substeps
    );
    println!(
        "| run | tier vs full-order Wilson-θ at Δt | tier vs converged | full-order Wilson-θ at Δt vs converged | at Δt/2 vs converged (order) | at Δt restarted vs converged | reference's own | reference's ratio | Δt for 1 % | s |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut measured: Vec<RunTimeError> = Vec::new();
    for &k in &selected {
        let clock = Instant::now();
        let e =
            time_error::measure_run(&full, plan, &reductor.tier, newton, &runs[k], args.substeps)?;
        println!(
            "| {k} {} | {:.2e} | {:.2e} | {:.2e} | {:.2e} ({:.2}) | {:.2e} | {:.1e} | {:.2} | {:.2e} s | {:.0} |",
            e.label,
            e.reduction,
            e.against_converged,
            e.step,
            e.step_half,
            e.step_order(),
            e.step_restarted,
            e.reference_error,
            e.reference_ratio,
            e.dt_for(dt, 0.01),
            clock.elapsed().as_secs_f64()
        );
        measured.push(e);
    }
    let worst = |f: fn(&RunTimeError) -> f64| measured.iter().map(f).fold(0.0, f64::max);
    let (step, reduction) = (worst(|e| e.step), worst(|e| e.reduction));
    let step_dominates = measured.iter().filter(|e| e.step > e.reduction).count();
    println!(
        "worst: step {step:.2e}, reduction {reduction:.2e}, tier vs converged {:.2e}; the step's \
         own error is the larger in {step_dominates} of {} runs; Δt for 1 % on every run: {:.2e} s",
        worst(|e| e.against_converged),
        measured.len(),
        measured
            .iter()
            .map(|e| e.dt_for(dt, 0.01))
            .fold(dt, f64::min)
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("tier_time_error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tier_time_error: {e}");
            ExitCode::FAILURE
        }
    }
}
