//! Builds the co-rotational tier (training → POD basis → ECSW → reduced Wilson-θ stepper,
//! docs/design.md §10) for one scene and prints its open-loop error against the full-order
//! co-rotational reference on a scenario, the per-step medians of both in the same run, and
//! optionally the static cantilever table against the full-order FEM and the elastica.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example nonlinear_tier -- \
//!     SCENE SCENARIO LOAD=RANGE_N TRAINING_DURATION_S SNAPSHOT_EVERY ORDER ECSW_TOL MAX_ELEMENTS \
//!     [ALPHAS, e.g. 0.5,1,2,3,5]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::nonlinear::ecsw::EcswOptions;
use crokf_compile::nonlinear::reduced::{ReducedNewton, Refresh};
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_verify::nonlinear::tier;
use crokf_verify::nonlinear::training::{self, TrainingPlan};
use crokf_verify::nonlinear::TierError;
use crokf_verify::scenario::Scenario;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    crokf_verify::exit(run(&args))
}

fn number<T: std::str::FromStr>(args: &[String], i: usize, what: &str) -> Result<T, TierError> {
    args.get(i)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| TierError::Invalid(format!("argument {}: expected {what}", i + 1)))
}

fn run(args: &[String]) -> Result<(), TierError> {
    if args.len() < 8 {
        return Err(TierError::Invalid(
            "usage: nonlinear_tier SCENE SCENARIO LOAD=RANGE_N TRAINING_DURATION_S SNAPSHOT_EVERY ORDER ECSW_TOL MAX_ELEMENTS [ALPHAS]".into(),
        ));
    }
    let scene = PathBuf::from(&args[0]);
    let scenario_path = PathBuf::from(&args[1]);
    let (load, range) = args[2]
        .split_once('=')
        .and_then(|(l, r)| r.parse::<f64>().ok().map(|r| (l.to_owned(), r)))
        .ok_or_else(|| TierError::Invalid(format!("expected LOAD=RANGE_N, got '{}'", args[2])))?;
    let duration: f64 = number(args, 3, "training duration, s")?;
    let every: usize = number(args, 4, "snapshot stride")?;
    let order: usize = number(args, 5, "order r")?;
    let tolerances: Vec<f64> = args[6]
        .split(',')
        .map(|a| a.parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| TierError::Invalid(format!("ECSW_TOL: {e}")))?;
    let max_elements: usize = number(args, 7, "most sampled elements")?;
    let alphas: Vec<f64> = match args.get(8) {
        Some(s) => s
            .split(',')
            .map(|a| a.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| TierError::Invalid(format!("ALPHAS: {e}")))?,
        None => Vec::new(),
    };
    let started = std::time::Instant::now();
    let full = FullOrder::build(&scene, &mut StageTimer::default())?;
    let scenario = Scenario::read(&scenario_path)?;
    let plan = TrainingPlan::axes(vec![(load.clone(), range)], duration, every);
    let training = training::train(&full, &plan, &mut |k, of, label| {
        eprintln!(
            "[{:7.1} s] training run {}/{of}: {label}",
            started.elapsed().as_secs_f64(),
            k + 1
        )
    })?;
    for (index, &tolerance) in tolerances.iter().enumerate() {
        let ecsw = EcswOptions {
            tolerance,
            max_elements,
            ..EcswOptions::default()
        };
        let built = tier::from_training(&full, training.clone(), order, &ecsw)?;
        report(
            &full,
            &built,
            &plan,
            &scene,
            &scenario,
            &scenario_path,
            &load,
            range,
            tolerance,
        )?;
        if index == 0 && !alphas.is_empty() {
            elastica(&full, &built, &load, &alphas)?;
        }
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn report(
    full: &FullOrder,
    built: &tier::Tier,
    plan: &TrainingPlan,
    scene: &std::path::Path,
    scenario: &Scenario,
    scenario_path: &std::path::Path,
    load: &str,
    range: f64,
    tolerance: f64,
) -> Result<(), TierError> {
    let env = &built.training.envelope;
    println!(
        "scene {}: n = {} free DOFs, {} tetrahedra",
        scene.display(),
        full.fem.dof_count(),
        full.fem.elements.len()
    );
    println!(
        "training: {}/{} runs ({} directions × {:?}), {} snapshots, {:.1} s; envelope: '{load}' ≤ {:.3} N ({:.2}× range {range} N), max |u| {:.4} m",
        env.runs.0,
        env.runs.1,
        plan.directions.len(),
        plan.histories,
        env.snapshots,
        built.training.seconds,
        range * env.max_multiple,
        env.max_multiple,
        env.max_displacement
    );
    for (label, failure) in &built.training.runs {
        if let Some(why) = failure {
            println!("  training run '{label}' failed: {why}");
        }
    }
    println!(
        "basis: r = {} POD vectors (λ_r/λ_1 = {:.2e}), {:.1} s; ECSW: {} of {} elements, training-force residual {:.2e} (tolerance {tolerance:e}), {:.1} s",
        built.basis.len(),
        built.pod_values.get(built.basis.len().saturating_sub(1)).copied().unwrap_or(0.0)
            / built.pod_values.first().copied().unwrap_or(1.0),
        built.seconds[0],
        built.sampling.weights.len(),
        full.fem.elements.len(),
        built.sampling.relative_residual,
        built.seconds[1]
    );
    let policies = [
        (
            "Newton to 1e-8, tangent refreshed after a step of > 4 iterations",
            ReducedNewton::default(),
        ),
        (
            "Newton to 1e-6, tangent refreshed after a step of > 4 iterations",
            ReducedNewton {
                tolerance: 1e-6,
                ..ReducedNewton::default()
            },
        ),
        (
            "Newton to 1e-6 from the Taylor predictor, tangent refreshed after a step of > 4 iterations",
            ReducedNewton {
                tolerance: 1e-6,
                predictor: true,
                ..ReducedNewton::default()
            },
        ),
        (
            "Newton to 1e-4, tangent refreshed after a step of > 6 iterations",
            ReducedNewton {
                tolerance: 1e-4,
                refresh: Refresh::WhenSlow { iterations: 6 },
                ..ReducedNewton::default()
            },
        ),
        (
            "Newton to 1e-6, tangent refreshed every step",
            ReducedNewton {
                tolerance: 1e-6,
                refresh: Refresh::EveryStep,
                ..ReducedNewton::default()
            },
        ),
    ];
    let newtons: Vec<ReducedNewton> = policies.iter().map(|p| p.1).collect();
    let results = tier::open_loop(full, built, &newtons, scenario, scenario_path)?;
    if let Some(first) = results.first() {
        println!(
            "open loop on {} ({} steps, max |u| {:.4} m); full-order co-rotational step median {:.3} ms (Newton to 1e-8)",
            scenario_path.display(),
            first.steps,
            first.max_displacement,
            first.full_step * 1e3
        );
    }
    println!("\n| reduced stepper | error (displayed) | tip error | step median | speed-up | iterations / refreshes / unconverged in {} steps |", results.first().map_or(0, |r| r.steps));
    println!("|---|---:|---:|---:|---:|---:|");
    for ((label, _), result) in policies.iter().zip(&results) {
        println!(
            "| {label} | {:.4} | {:.4} | {:.1} µs | {:.0}× | {} / {} / {} |",
            result.error,
            result.tip_error.unwrap_or(f64::NAN),
            result.reduced_step * 1e6,
            result.full_step / result.reduced_step,
            result.stats.iterations,
            result.stats.refreshes,
            result.stats.unconverged
        );
    }
    let q = built.basis.project(
        built
            .training
            .snapshots
            .last()
            .map_or(&[][..], |s| s.as_slice()),
    );
    let [force, tangent] = tier::component_times(&built.model, &q, 200);
    println!(
        "\ncomponents (median of 200, at the last training state): reduced force {:.1} µs, reduced tangent {:.1} µs ({} elements, r = {})",
        force * 1e6,
        tangent * 1e6,
        built.model.cubature.len(),
        built.model.order()
    );
    Ok(())
}

fn elastica(
    full: &FullOrder,
    built: &tier::Tier,
    load: &str,
    alphas: &[f64],
) -> Result<(), TierError> {
    {
        let (ei, length, rows) = tier::elastica(full, built, load, [0.0, 0.0, -1.0], alphas)?;
        println!("\nstatic cantilever, EI of the mesh {ei:.4} N·m², L = {length} m (deflection / draw-in, m)\n");
        println!("| α = PL²/EI | P (N) | elastica | full-order co-rot. FEM | reduced tier | tier vs FEM: deflection, draw-in |");
        println!("|---:|---:|---:|---:|---:|---:|");
        for r in rows {
            let rel = |a: f64, b: f64| (a - b) / b;
            println!(
                "| {} | {:.3} | {:.4} / {:.4} | {:.4} / {:.4} | {:.4} / {:.4} | {:+.2} % / {:+.2} % |",
                r.alpha,
                r.load,
                r.elastica[0],
                r.elastica[1],
                r.full[0],
                r.full[1],
                r.reduced[0],
                r.reduced[1],
                100.0 * rel(r.reduced[0], r.full[0]),
                100.0 * rel(r.reduced[1], r.full[1])
            );
        }
    }
    Ok(())
}
