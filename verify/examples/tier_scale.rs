//! Training cost and step speed of the co-rotational tier at scale (docs/results/tier.md
//! §6, docs/design.md §10): where the training time goes, and the tier step against the
//! full-order co-rotational step in the same run.
//!
//! ```sh
//! # training only (the scene's [reduction.corotational] plan): runs, steps, Newton solves,
//! # factorisations, time in assembly / factorisation / triangular solves
//! cargo run --release -p crokf-verify --example tier_scale -- train SCENE [--full-newton] [--no-predictor] [--threads N] [--sequential]
//! # the same counters for one run of the plan (index as `crokf-compile SCENE --list-cases`
//! # lists it), optionally shortened to its first S seconds
//! cargo run --release -p crokf-verify --example tier_scale -- train SCENE --case K [--duration S] [--contraction RHO]
//! # step speed: tier step (runtime, MODEL compiled from SCENE) against the full-order
//! # co-rotational step of SCENE's mesh, medians of the same run
//! cargo run --release -p crokf-verify --example tier_scale -- bench SCENE MODEL [--steps N]
//! ```
//!
//! `bench` times three steps (medians of this thread's CPU time, and of wall time; pass
//! `--sequential` so that the full-order factorisations run on the timed thread) under the tier-load ramp of the load channel with the largest
//! range (to 0.8 × the range over the run, z component): the runtime's tier step
//! (`Estimator::predict`), the full-order co-rotational step with one Newton solve (assembly +
//! factorisation + solve: the cheapest full-order step, the one of `crokf-verify bench`), and
//! the full-order step to convergence (Newton to 1e-8, the reference of `crokf-verify`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use crokf_compile::nonlinear::training::{run_case, train, TrainingPlan};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, NewtonStats, Simulator};
use crokf_compile::FullOrder;
use crokf_runtime::{load_model, Estimator};
use crokf_verify::bench::{step_clock_seconds, STEP_CLOCK};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

fn flag_value(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: tier_scale train SCENE [--full-newton] [--no-predictor] [--threads N] | \
                 tier_scale bench SCENE MODEL [--steps N]";
    let (Some(mode), Some(scene)) = (args.first(), args.get(1)) else {
        return Err(usage.into());
    };
    if args.iter().any(|a| a == "--sequential") {
        // faer's sparse Cholesky single-threaded (default: all cores).
        faer::set_global_parallelism(faer::Par::Seq);
    }
    let full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    println!(
        "{scene}: {} tetrahedra, {} free DOFs, Δt = {} s",
        full.fem.elements.len(),
        full.fem.dof_count(),
        full.wilson.dt
    );
    match mode.as_str() {
        "train" => train_cost(&full, &args),
        "bench" => {
            let Some(model) = args.get(2) else {
                return Err(usage.into());
            };
            let steps = flag_value(&args, "--steps")
                .map(|s| s.parse::<usize>())
                .transpose()?
                .unwrap_or(20);
            bench(&full, &PathBuf::from(model), steps)
        }
        _ => Err(usage.into()),
    }
}

fn train_cost(full: &FullOrder, args: &[String]) -> Result<(), Box<dyn std::error::Error>> {
    let Some(mut plan) = TrainingPlan::of_scene(full) else {
        return Err("the scene has no [reduction.corotational] table".into());
    };
    if args.iter().any(|a| a == "--full-newton") {
        plan.modified = None;
    }
    if args.iter().any(|a| a == "--no-predictor") {
        if let Some(m) = plan.modified.as_mut() {
            m.predictor = false;
        }
    }
    if let Some(c) = flag_value(args, "--contraction") {
        if let Some(m) = plan.modified.as_mut() {
            m.contraction = c.parse()?;
        }
    }
    if let Some(t) = flag_value(args, "--threads") {
        plan.threads = t.parse()?;
    }
    if let Some(d) = flag_value(args, "--duration") {
        plan.duration = d.parse()?;
    }
    if let Some(k) = flag_value(args, "--case") {
        let k: usize = k.parse()?;
        let label = plan
            .runs()
            .get(k)
            .map(|r| r.label.clone())
            .unwrap_or_default();
        let started = Instant::now();
        let (frames, s) = run_case(full, &plan, k)??;
        println!(
            "case {k} ({label}): {} snapshots, wall {:.1} s",
            frames.len(),
            started.elapsed().as_secs_f64()
        );
        print_stats(&s);
        return Ok(());
    }
    let mut progress = |k: usize, of: usize, label: &str| {
        eprintln!("run {}/{of}: {label}", k + 1);
    };
    let training = train(full, &plan, &mut progress)?;
    println!(
        "training: {} runs ({} failed), {} snapshots, wall {:.1} s ({} thread(s), {})",
        training.runs.len(),
        training.runs.iter().filter(|r| r.1.is_some()).count(),
        training.snapshots.len(),
        training.seconds,
        plan.threads,
        if plan.modified.is_some() {
            "modified Newton"
        } else {
            "full Newton"
        }
    );
    print_stats(&training.newton);
    Ok(())
}

/// The Newton counters and thread times of `s`, totals and per step.
fn print_stats(s: &NewtonStats) {
    let per_step = |v: f64| v / s.steps.max(1) as f64;
    println!(
        "steps {}, Newton solves {} ({:.2}/step), factorisations {} ({:.2}/step), unconverged \
         {}, fallbacks {}, worst estimated error {:.1e}",
        s.steps,
        s.solves,
        per_step(s.solves as f64),
        s.factorisations,
        per_step(s.factorisations as f64),
        s.unconverged,
        s.fallbacks,
        s.worst_increment
    );
    println!(
        "thread time: assembly {:.1} s, factorisation {:.1} s, solves {:.1} s (per step {:.2} / \
         {:.2} / {:.2} ms)",
        s.assembly_seconds,
        s.factor_seconds,
        s.solve_seconds,
        1e3 * per_step(s.assembly_seconds),
        1e3 * per_step(s.factor_seconds),
        1e3 * per_step(s.solve_seconds)
    );
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn bench(
    full: &FullOrder,
    model_path: &std::path::Path,
    steps: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let model = load_model(model_path)?;
    let mut estimator = Estimator::new(&model)?;
    if !estimator.is_corotational() {
        return Err(format!("{} is not a co-rotational tier model", model_path.display()).into());
    }
    let spec = full
        .scene
        .scene
        .reduction
        .corotational
        .as_ref()
        .ok_or("the scene has no [reduction.corotational] table")?;
    let (load, range) = spec
        .ranges
        .iter()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .ok_or("no load range")?;
    let label = format!("{load}.z");
    let channel = full
        .operators
        .inputs
        .iter()
        .position(|c| c.label == label)
        .ok_or_else(|| format!("no input channel {label}"))?;
    let column = &full.operators.inputs[channel].column;
    let input = model
        .inputs
        .iter()
        .position(|c| c.label == label)
        .ok_or_else(|| format!("the model has no input {label}"))?;
    let force = |k: usize| -0.8 * range * (k as f64 / steps as f64);
    let mut f = vec![0.0; column.len()];
    let mut u = vec![0.0; model.inputs.len()];
    // Both clocks per step: this thread's CPU time (what the step costs on one core; the
    // full-order solves run on this thread with `--sequential`) and wall time.
    let clock = step_clock_seconds;
    // Runtime tier step: 200 × the full-order steps, timed per step.
    let (mut tier, mut tier_wall) = (Vec::new(), Vec::new());
    for k in 1..=200 * steps {
        u[input] = force(k.div_ceil(200));
        let (c0, w0) = (clock(), Instant::now());
        estimator.predict(&u)?;
        tier.push(clock() - c0);
        tier_wall.push(w0.elapsed().as_secs_f64());
    }
    let (mut one_solve, mut one_wall) = (Vec::new(), Vec::new());
    let (mut converged, mut converged_wall) = (Vec::new(), Vec::new());
    let options = NewtonOptions::default();
    let mut single = CorotationalSimulator::new(
        &full.fem,
        full.wilson,
        NewtonOptions {
            max_newton: 1,
            ..options
        },
    )?;
    let mut reference = CorotationalSimulator::new(&full.fem, full.wilson, options)?;
    for k in 1..=steps {
        let m = force(k);
        f.iter_mut().zip(column).for_each(|(fi, b)| *fi = m * b);
        let (c0, w0) = (clock(), Instant::now());
        single.step(&f)?;
        one_solve.push(clock() - c0);
        one_wall.push(w0.elapsed().as_secs_f64());
        let (c0, w0) = (clock(), Instant::now());
        reference.step(&f)?;
        converged.push(clock() - c0);
        converged_wall.push(w0.elapsed().as_secs_f64());
    }
    let (t, s, c) = (median(tier), median(one_solve), median(converged));
    let (tw, sw, cw) = (median(tier_wall), median(one_wall), median(converged_wall));
    let stats = reference.stats();
    println!(
        "medians over {steps} full-order steps and {} tier steps (load to {:.3} N on {label}); \
         thread CPU time ({STEP_CLOCK}) / wall time:",
        200 * steps,
        force(steps)
    );
    println!(
        "  tier step (runtime predict): {:.2} / {:.2} µs",
        1e6 * t,
        1e6 * tw
    );
    println!(
        "  full-order co-rotational step, one Newton solve: {:.1} / {:.1} ms  (ratio {:.2e} CPU, {:.2e} wall)",
        1e3 * s,
        1e3 * sw,
        s / t,
        sw / tw
    );
    println!(
        "  full-order co-rotational step, Newton to 1e-8 ({:.2} solves/step): {:.1} / {:.1} ms  \
         (ratio {:.2e} CPU, {:.2e} wall)",
        stats.solves as f64 / stats.steps.max(1) as f64,
        1e3 * c,
        1e3 * cw,
        c / t,
        cw / tw
    );
    Ok(())
}
