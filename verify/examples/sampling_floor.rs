//! The sampling floor of sparse markers on a scenario (docs/design.md §11.7,
//! `crokf_verify::nonlinear::sampling`): for each marker offset, the error of an oracle that is
//! exact from the first marker that sees the load (onset) and of oracles that are given the
//! model's exact state and the exact loads at every marker and extrapolate the loads between
//! markers with factor α times a rate (0: held, the random-walk force model's prediction; 1: the
//! rate carried on, the force-rate states'), the rate being the loads' exact last change (first
//! table) or their change between the last two markers (second table: all that noise-free
//! markers tell), against the full-order co-rotational reference, relative L2 over the displayed
//! nodes (as `nonlinear_filter` scores its runs).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example sampling_floor -- SCENE SCENARIO MODEL \
//!     [--period L] [--offsets 0,4,8] [--alphas 0,0.5,1]
//! ```
//! MODEL is a compiled model file (either tier); L defaults to the model's marker period (the
//! phases of its filter), the offsets to 0, 4, 8, … < L, the α to 0, 0.1, …, 1. Offset o means
//! markers at steps k ≡ L − 1 − o (mod L), as `--marker-phase o` of `nonlinear_filter`.
//! `--reference-cache FILE` keeps the reference run in FILE (as the other drivers).

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_verify::nonlinear::reference::Reference;
use crokf_verify::nonlinear::sampling::{MarkerSteps, OpenLoop};
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

/// Removes `--name VALUE` from `args` and parses VALUE as a comma-separated list.
fn list<T: std::str::FromStr>(
    args: &mut Vec<String>,
    name: &str,
) -> Result<Option<Vec<T>>, String> {
    let Some(i) = args.iter().position(|a| a == name) else {
        return Ok(None);
    };
    let value = args
        .get(i + 1)
        .cloned()
        .ok_or_else(|| format!("{name} needs a value"))?;
    args.drain(i..i + 2);
    value
        .split(',')
        .map(|v| {
            v.trim()
                .parse()
                .map_err(|_| format!("{name} {value}: '{v}' is not a number"))
        })
        .collect::<Result<Vec<T>, String>>()
        .map(Some)
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let period = list::<usize>(&mut args, "--period")?;
    let offsets = list::<usize>(&mut args, "--offsets")?;
    let cache = match args.iter().position(|a| a == "--reference-cache") {
        Some(i) => {
            let file = args
                .get(i + 1)
                .cloned()
                .ok_or("--reference-cache needs a file")?;
            args.drain(i..i + 2);
            Some(PathBuf::from(file))
        }
        None => None,
    };
    let alphas = list::<f64>(&mut args, "--alphas")?
        .unwrap_or_else(|| (0..=10).map(|i| 0.1 * i as f64).collect());
    if args.len() != 3 {
        return Err("usage: sampling_floor SCENE SCENARIO MODEL [--period L] [--offsets O,…] [--alphas A,…] [--reference-cache FILE]".into());
    }
    let model = crokf_runtime::load_model(&args[2])?;
    let phases = model
        .tier
        .as_ref()
        .map_or(&model.kalman, |t| &t.kalman)
        .phases
        .len();
    let period = match period.as_deref() {
        Some([p]) => *p,
        Some(_) => return Err("--period takes one number".into()),
        None => phases,
    };
    let offsets = offsets.unwrap_or_else(|| (0..period).step_by(4).collect());
    let markers = offsets
        .iter()
        .map(|&o| MarkerSteps::new(period, o))
        .collect::<Result<Vec<_>, _>>()?;

    let full = FullOrder::build(&PathBuf::from(&args[0]), &mut StageTimer::default())?;
    let scenario = Scenario::read(&PathBuf::from(&args[1]))?;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let reference = Reference::of(&full, &scenario, steps, cache.as_deref())?;

    println!(
        "markers every {period} steps ({:.1} Hz at Δt = {} s); errors relative L2 over the displayed nodes\n",
        1.0 / (period as f64 * model.dt),
        model.dt
    );
    let heads: Vec<String> = alphas.iter().map(|a| format!("α = {a:.2}")).collect();
    let open_loop = OpenLoop::run(&model, &reference.inputs, &reference.shown)?;
    for (span, what) in [
        (1, "the exact last change of the loads"),
        (period, "the loads' change between the last two markers"),
    ] {
        println!(
            "rate from {what} (d = {span} step{}):\n",
            if span == 1 { "" } else { "s" }
        );
        println!(
            "| offset | first marker seeing the load | onset | {} | best α (error) |",
            heads.join(" | ")
        );
        println!("|---:|---:|---:|{}---|", "---:|".repeat(alphas.len()));
        for (o, &m) in offsets.iter().zip(&markers) {
            let floor = open_loop.floor(m, &alphas, span)?;
            let cells: Vec<String> = floor
                .extrapolated
                .iter()
                .map(|(_, e)| format!("{:.2} %", 100.0 * e))
                .collect();
            let (best_alpha, best) = floor.best().unwrap_or((f64::NAN, f64::NAN));
            println!(
                "| {o} | {} | {:.2} % | {} | {best_alpha:.2} ({:.2} %) |",
                floor
                    .first_marker
                    .map_or("none".to_string(), |k| k.to_string()),
                100.0 * floor.onset,
                cells.join(" | "),
                100.0 * best
            );
        }
        println!();
        if period == 1 {
            break;
        }
    }
    println!(
        "the model open loop, loads given: {:.3} %",
        100.0 * open_loop.error()
    );
    Ok(())
}
