//! Each input channel on its own, per truncation tolerance: the order rule's evidence
//! (docs/design.md §4.3). For each tolerance the scene's modal system is truncated and printed:
//! r, the compile's joint measured error (worst of the step and chirp on every load group), and
//! per channel its static error (`accuracy::channel_static_errors`) and the error of a unit step
//! on it alone (`accuracy::channel_steps`), both relative to that channel's own response; then
//! the cost of the full-order reference with and without the per-channel steps.
//!
//! ```text
//! cargo run --release -p crokf-verify --example channel_order -- SCENE [TOLERANCES,..]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use crokf_compile::accuracy::{self, ReferenceResponses};
use crokf_compile::reduce::Order;
use crokf_compile::timer::StageTimer;
use crokf_compile::{FullOrder, Reductor};

fn run(scene: &str, tolerances: &[f64]) -> Result<(), Box<dyn std::error::Error>> {
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&PathBuf::from(scene), &mut timer)?;
    let reductor = Reductor::new(&full, None, &mut timer)?;
    let (steps, f_high) = reductor.measure_plan();
    let labels: Vec<String> = full
        .operators
        .inputs
        .iter()
        .map(|c| c.label.clone())
        .collect();
    let standard = accuracy::standard_tests(&full, steps, f_high);
    let started = Instant::now();
    let joint = ReferenceResponses::simulate_with(
        &full,
        &reductor.rows,
        standard.clone(),
        reductor.reference_stepping(),
    )?;
    let joint_s = started.elapsed().as_secs_f64();
    let mut all = standard;
    all.extend(accuracy::channel_steps(&full, steps));
    let started = Instant::now();
    let reference = ReferenceResponses::simulate_with(
        &full,
        &reductor.rows,
        all,
        reductor.reference_stepping(),
    )?;
    let all_s = started.elapsed().as_secs_f64();
    drop(joint);
    println!(
        "{scene}: {} free DOFs, {} input channels ({}), {steps} steps a test; full-order \
         reference {joint_s:.3} s for step + chirp, {all_s:.3} s with a step per channel",
        full.fem.dof_count(),
        labels.len(),
        labels.join(", ")
    );
    println!(
        "| tolerance | r | joint step/chirp worst | worst static (channel) | worst channel step \
         (channel) | static per channel | step per channel | errors s |"
    );
    println!("|---:|---:|---:|---|---|---|---|---:|");
    for &tol in tolerances {
        let reduced = reductor.reduce(Order::Tolerance(tol))?;
        let started = Instant::now();
        let errors = reference.errors(&reduced);
        let errors_s = started.elapsed().as_secs_f64();
        let joint = ["step", "chirp"]
            .iter()
            .filter_map(|k| errors.get(*k))
            .fold(0.0f64, |a, &b| a.max(b));
        let statics = accuracy::channel_static_errors(
            &full,
            &reductor.rows,
            &reduced,
            reductor.static_outputs(),
        )
        .unwrap_or_default();
        let worst_static = statics
            .iter()
            .max_by(|a, b| a.error.total_cmp(&b.error))
            .map_or("-".into(), |c| format!("{:.2e} ({})", c.error, c.label));
        let channel_steps: Vec<(String, f64)> = labels
            .iter()
            .map(|l| (l.clone(), errors[&format!("step.{l}")]))
            .collect();
        let worst_step = channel_steps
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or("-".into(), |(l, e)| format!("{e:.2e} ({l})"));
        println!(
            "| {tol:.0e} | {} | {joint:.2e} | {worst_static} | {worst_step} | {} | {} | {errors_s:.3} |",
            reduced.balanced_order,
            statics
                .iter()
                .map(|c| format!("{:.1e}", c.error))
                .collect::<Vec<_>>()
                .join(" "),
            channel_steps
                .iter()
                .map(|(_, e)| format!("{e:.1e}"))
                .collect::<Vec<_>>()
                .join(" "),
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(scene) = args.first() else {
        eprintln!("usage: channel_order SCENE [TOLERANCES,..]");
        return ExitCode::FAILURE;
    };
    let tolerances: Option<Vec<f64>> = args
        .get(1)
        .map(String::as_str)
        .unwrap_or("1e-3,3e-4,1e-4,3e-5,1e-5,3e-6,1e-6,3e-7,1e-7")
        .split(',')
        .map(|s| s.trim().parse().ok())
        .collect();
    let Some(tolerances) = tolerances else {
        eprintln!("TOLERANCES are comma-separated numbers");
        return ExitCode::FAILURE;
    };
    match run(scene, &tolerances) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("channel_order: {e}");
            ExitCode::FAILURE
        }
    }
}
