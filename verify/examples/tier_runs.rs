//! Per training run of a scene's co-rotational tier: the full-order run's largest nodal
//! displacement, its largest element rotation, its Newton counters, and the tier's self-check
//! error on it, at a fixed basis size and cubature (ORDER 30, ECSW_TOL 1e-3, MAX_ELEMENTS 600
//! unless given). `--max-rotation DEG` replaces the scene's `max_rotation` (the angle past which
//! a training run is cut), so one scene and one case cache compare limits.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example tier_runs -- SCENE CACHE_DIR \
//!     [ORDER ECSW_TOL MAX_ELEMENTS] [--max-rotation DEG]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::nonlinear::basis::BasisChoice;
use crokf_compile::nonlinear::cases::{self, CaseCache};
use crokf_compile::nonlinear::ecsw::EcswOptions;
use crokf_compile::nonlinear::self_check;
use crokf_compile::nonlinear::tier;
use crokf_compile::nonlinear::training::{deformation, max_nodal, TrainingPlan};
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_verify::nonlinear::TierError;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    crokf_verify::exit(run(&args))
}

const USAGE: &str =
    "usage: tier_runs SCENE CACHE_DIR [ORDER ECSW_TOL MAX_ELEMENTS] [--max-rotation DEG]";

/// The positional argument `k` parsed, or `default` when it is not given.
fn positional<T: std::str::FromStr>(args: &[String], k: usize, default: T) -> Result<T, TierError> {
    match args.get(k) {
        None => Ok(default),
        Some(s) => s.parse().map_err(|_| {
            TierError::Invalid(format!(
                "argument {}: '{s}' is not a number; {USAGE}",
                k + 1
            ))
        }),
    }
}

fn run(args: &[String]) -> Result<(), TierError> {
    let mut args = args.to_vec();
    let mut max_rotation = None;
    if let Some(k) = args.iter().position(|a| a == "--max-rotation") {
        let value = args
            .get(k + 1)
            .and_then(|s| s.parse::<f64>().ok())
            .filter(|a| *a > 0.0 && *a <= 180.0)
            .ok_or_else(|| {
                TierError::Invalid(format!(
                    "--max-rotation needs an angle in (0, 180] degrees; {USAGE}"
                ))
            })?;
        max_rotation = Some(value);
        args.drain(k..k + 2);
    }
    if args.len() < 2 || args.len() > 5 {
        return Err(TierError::Invalid(USAGE.into()));
    }
    let scene = PathBuf::from(&args[0]);
    let cache = CaseCache::open(&PathBuf::from(&args[1])).map_err(TierError::Invalid)?;
    let order: usize = positional(&args, 2, 30)?;
    let tol: f64 = positional(&args, 3, 1e-3)?;
    let max_elements: usize = positional(&args, 4, 600)?;
    let full = FullOrder::build(&scene, &mut StageTimer::default())?;
    let mut plan = TrainingPlan::of_scene(&full)
        .ok_or_else(|| TierError::Invalid("no [reduction.corotational]".into()))?;
    if let Some(angle) = max_rotation {
        plan.max_rotation = angle;
    }
    let training = cases::train_cached(&full, &plan, &cache, &mut |_, _, _| {})
        .map_err(|e| TierError::Invalid(e.to_string()))?;
    for (k, (label, failed)) in training.runs.iter().enumerate() {
        let frames: Vec<&Vec<f64>> = training
            .snapshots
            .iter()
            .zip(&training.run_of)
            .filter(|(_, &r)| r == k)
            .map(|(u, _)| u)
            .collect();
        let umax = frames
            .iter()
            .map(|u| max_nodal(&full.fem, u))
            .fold(0.0, f64::max);
        let worst = frames.iter().map(|u| deformation(&full.fem, u)).fold(
            (f64::INFINITY, 0usize, 0.0f64),
            |a, d| {
                (
                    a.0.min(d.min_det),
                    a.1.max(d.inverted),
                    a.2.max(d.max_rotation),
                )
            },
        );
        let cut = match training.cuts.get(k).and_then(|c| c.as_ref()) {
            Some(c) => format!(
                "cut at t = {} s ({:.3}×, {} of {} snapshots): {}",
                c.time, c.multiple, c.kept, c.of, c.reason
            ),
            None => String::new(),
        };
        println!(
            "run {k:3} {label:60} max|u| {umax:10.4e} m  min det F {:9.3e} inverted {:5} rot {:6.1}°  {}{cut}",
            worst.0, worst.1, worst.2,
            failed.clone().unwrap_or_default()
        );
    }
    let Some(spec) = full.scene.scene.reduction.corotational.as_ref() else {
        return Err(TierError::Invalid("no [reduction.corotational]".into()));
    };
    let newton = self_check::runtime_newton(spec.newton_tolerance, spec.newton_iterations);
    let ecsw = EcswOptions {
        tolerance: tol,
        max_elements,
        ..EcswOptions::default()
    };
    let choice = BasisChoice::pod(order);
    let built = tier::from_training_with(&full, training, &choice, &ecsw)
        .map_err(|e| TierError::Invalid(e.to_string()))?;
    println!(
        "r = {}, sampled {}, pod values {:?}",
        built.model.order(),
        built.model.cubature.elements.len(),
        &built.pod_values[..8.min(built.pod_values.len())]
    );
    let check = self_check::self_check(&full, &plan, &built, newton, 0.05)
        .map_err(|e| TierError::Invalid(e.to_string()))?;
    let (above, checked) = check.above(0.05);
    let out = self_check::out_of_sample(&full, &plan, &built.training, &choice, &ecsw, newton)
        .map_err(|e| TierError::Invalid(e.to_string()))?;
    println!(
        "in sample: median {:.3} %, {above} of {checked} above 5 %; out of sample: {}",
        100.0 * check.median(),
        out.as_ref().map_or("not measured".to_owned(), |o| format!(
            "median {:.3} %, worst {:.3} %",
            100.0 * o.check.median(),
            100.0 * o.check.worst().map_or(f64::NAN, |w| w.error)
        ))
    );
    for c in &check.runs {
        println!(
            "{:60} e {:8.3} %  scale {:10.3e}  unconverged {:4}  {}",
            c.label,
            100.0 * c.error,
            c.scale,
            c.unconverged,
            c.failure.clone().unwrap_or_default()
        );
    }
    Ok(())
}
