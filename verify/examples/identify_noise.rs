//! The co-rotational tier's noise identified from its own innovations (autocovariance least
//! squares, docs/design.md §11.6). The tier of MODEL, its filters (gain schedule included)
//! recomputed for SCENE's noise, runs from rest over a recording; its innovations ν = y − ŷ⁻
//! after the first SKIP steps give the sample autocovariances, the schedule's filter and phase
//! in use at each step give the model's, and `crokf_compile::nonlinear::identify::identify_noise`
//! the σ that explain them: each random-walk load's force σ_f (and rate σ_ḟ), and the markers'
//! σ as a factor on the scene's.
//!
//! The recording is either
//! - simulated, `SCENE SCENARIO MODEL`: the full-order co-rotational reference of SCENARIO,
//!   markers = reference + Gaussian noise of the scene's σ (`--seed N`, default 7; every
//!   marker at every step), the loads withheld (every load channel 0; `--given`: given);
//!   `--write-recording FILE` also writes these markers as a `crokf-run` measurements file; or
//! - a user's, `SCENE MODEL --recording MEASUREMENTS.csv [--inputs INPUTS.csv]`, in
//!   `crokf-run`'s CSV formats (`run/src/table.rs`; without an inputs file every input is 0:
//!   the loads are withheld).
//!
//! The markers' factor is the check of the result: the markers' noise is known (a tracking
//! system's specification; the scene's by construction when simulated), so a factor outside
//! [0.8, 1.25] says that the linearised filters do not explain the innovations, and the σ are
//! printed as not identified.
//!
//! Flags: `--force-sigma S` runs the filters of σ_f = S (N per step) on every random-walk load
//! instead of the scene's (ALS needs stable filters, not optimal ones); `--no-schedule` the
//! filter at rest only; `--fixed-point` repeats the identification with the filters of the σ
//! just identified until they agree to 1 % (at most 10 runs, the same recording): the σ that,
//! used in the filter, its own innovations confirm; `--lags L` (30), `--skip S` (50 steps).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example identify_noise -- SCENE SCENARIO MODEL \
//!     [--given] [--seed N] [--write-recording FILE] [--no-schedule] [--fixed-point] \
//!     [--force-sigma S] [--lags L] [--skip S]
//! cargo run --release -p crokf-verify --example identify_noise -- SCENE MODEL \
//!     --recording MEASUREMENTS.csv [--inputs INPUTS.csv] [--fixed-point] …
//! ```
//! `CROKF_REFERENCE_CACHE=FILE` as in `nonlinear_filter`.

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::nonlinear::identify::IdentifiedNoise;
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_runtime::load_model;
use crokf_verify::comparison::Gaussian;
use crokf_verify::nonlinear::identify::filter_run;
use crokf_verify::nonlinear::reference::Reference;
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

const USAGE: &str =
    "usage: identify_noise SCENE SCENARIO MODEL [--given] [--seed N] [--write-recording FILE] | \
     SCENE MODEL --recording \
     MEASUREMENTS.csv [--inputs INPUTS.csv]; and [--no-schedule] [--fixed-point] [--lags L] \
     [--skip S] [--force-sigma S]";

/// The markers' factor outside which the identification is flagged (module docs).
const MARKER_FACTOR_RANGE: (f64, f64) = (0.8, 1.25);

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut positional = Vec::new();
    let (mut given, mut schedule, mut fixed_point) = (false, true, false);
    let (mut lags, mut skip) = (30usize, 50usize);
    let mut force_sigma: Option<f64> = None;
    let (mut recording, mut inputs_file): (Option<PathBuf>, Option<PathBuf>) = (None, None);
    let (mut seed, mut write_recording): (u64, Option<PathBuf>) = (7, None);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--force-sigma" {
            let v = args
                .next()
                .ok_or(format!("--force-sigma needs a value; {USAGE}"))?;
            let sigma: f64 = v
                .parse()
                .map_err(|_| format!("--force-sigma {v}: not a number; {USAGE}"))?;
            if !(sigma.is_finite() && sigma > 0.0) {
                return Err(format!("--force-sigma {v}: must be > 0 (N per step)").into());
            }
            force_sigma = Some(sigma);
            continue;
        }
        if a == "--recording" || a == "--inputs" || a == "--write-recording" {
            let v = args.next().ok_or(format!("{a} needs a file; {USAGE}"))?;
            let path = Some(PathBuf::from(v));
            match a.as_str() {
                "--recording" => recording = path,
                "--inputs" => inputs_file = path,
                _ => write_recording = path,
            }
            continue;
        }
        let mut number = |flag: &str| -> Result<usize, Box<dyn std::error::Error>> {
            let v = args
                .next()
                .ok_or(format!("{flag} needs a value; {USAGE}"))?;
            v.parse()
                .map_err(|_| format!("{flag} {v}: not a whole number; {USAGE}").into())
        };
        match a.as_str() {
            "--given" => given = true,
            "--no-schedule" => schedule = false,
            "--fixed-point" => fixed_point = true,
            "--lags" => lags = number("--lags")?,
            "--skip" => skip = number("--skip")?,
            "--seed" => seed = number("--seed")? as u64,
            _ if a.starts_with("--") => return Err(format!("unknown flag {a}; {USAGE}").into()),
            _ => positional.push(a),
        }
    }
    let (scene, scenario, model_path) = match (positional.as_slice(), &recording) {
        ([scene, scenario, model], None) => (scene, Some(scenario), model),
        ([scene, model], Some(_)) => (scene, None, model),
        _ => return Err(USAGE.into()),
    };
    if recording.is_none() && inputs_file.is_some() {
        return Err(format!("--inputs goes with --recording; {USAGE}").into());
    }
    if recording.is_some() && (write_recording.is_some() || seed != 7) {
        return Err(
            format!("--seed and --write-recording are for a simulated recording; {USAGE}").into(),
        );
    }
    if recording.is_some() && given {
        return Err(format!(
            "--given is for a simulated recording (the inputs file gives a \
                            recording's loads); {USAGE}"
        )
        .into());
    }
    let base = load_model(model_path)?;
    let Some(tier) = base.tier.as_ref() else {
        return Err(format!("{model_path} has no co-rotational tier").into());
    };
    let mut full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    if let Some(sigma) = force_sigma {
        let loads: Vec<usize> = full.force_statements().iter().map(|s| s.load).collect();
        if loads.is_empty() {
            return Err(format!("--force-sigma: {scene} has no random-walk load").into());
        }
        for g in loads {
            full.scene.scene.loads[g].force_noise_std = sigma;
        }
    }
    let (inputs, measurements) = match (scenario, &recording) {
        (Some(scenario), _) => {
            let simulated = simulated(&full, &base, &PathBuf::from(scenario), given, seed)?;
            if let Some(path) = &write_recording {
                write_measurements(path, &base, &simulated.1)?;
                eprintln!("markers written to {}", path.display());
            }
            simulated
        }
        (None, Some(path)) => recorded(&base, path, inputs_file.as_deref())?,
        (None, None) => return Err(USAGE.into()),
    };
    let steps = inputs.len();
    if steps <= skip {
        return Err(format!("the recording has {steps} steps, fewer than --skip {skip}").into());
    }
    let points = if schedule { tier.scheduled.len() } else { 0 };
    let run = Run {
        inputs: &inputs,
        measurements: &measurements,
        schedule,
        skip,
        lags,
    };
    for iteration in 1..=if fixed_point { MAX_ITERATIONS } else { 1 } {
        let found = run.identify(&full, &base)?;
        println!(
            "{}{steps} steps ({} innovations after {skip}), lags {lags}, loads {}, {} filter(s), \
             {} switches; fit: relative residual {:.3}\n",
            if fixed_point {
                format!("iteration {iteration}: ")
            } else {
                String::new()
            },
            found.noise.estimate.samples,
            match (&recording, given) {
                (Some(_), _) => "as recorded",
                (None, true) => "given",
                (None, false) => "withheld",
            },
            1 + points,
            found.switches,
            found.noise.estimate.relative_residual
        );
        print_table(&full, &found.noise);
        let (lo, hi) = MARKER_FACTOR_RANGE;
        if !(lo..=hi).contains(&found.noise.measurement_scale) {
            println!(
                "\nNOT IDENTIFIED: the markers' factor {:.2} is outside [{lo}, {hi}]: the \
                 linearised filters do not explain these innovations; try another \
                 --force-sigma, or a recording nearer the trained states.",
                found.noise.measurement_scale
            );
            break;
        }
        if !fixed_point {
            break;
        }
        // The fixed point: the filter's σ := the identified σ, until they agree to 1 %.
        let mut change = 0.0f64;
        for l in &found.noise.loads {
            let load = &mut full.scene.scene.loads[l.load];
            let mut next = vec![(l.force_sigma, &mut load.force_noise_std)];
            if let Some(rate) = l.rate_sigma {
                next.push((rate, &mut load.force_rate_noise_std));
            }
            for ((old, new), field) in next {
                if new <= 0.0 {
                    println!(
                        "\nσ → 0 for load '{}': a held load; no fixed point (the filter needs \
                         σ > 0)",
                        load.name
                    );
                    return Ok(());
                }
                change = change.max((new / old - 1.0).abs());
                *field = new;
            }
        }
        println!();
        if change < FIXED_POINT_TOLERANCE {
            println!(
                "fixed point: the identified σ agree with the filter's to {:.2} %",
                100.0 * change
            );
            break;
        }
        if iteration == MAX_ITERATIONS {
            println!("no fixed point in {MAX_ITERATIONS} iterations (last change {change:.3})");
        }
    }
    Ok(())
}

/// Iterations of `--fixed-point` at most.
const MAX_ITERATIONS: usize = 10;
/// `--fixed-point` stops when no σ changes by more than this fraction.
const FIXED_POINT_TOLERANCE: f64 = 0.01;

/// One identification run's settings: the recording (one row per step, model order) and the
/// identification's.
struct Run<'a> {
    inputs: &'a [Vec<f64>],
    measurements: &'a [Vec<Option<f64>>],
    schedule: bool,
    skip: usize,
    lags: usize,
}

/// What one run identified.
struct Found {
    noise: IdentifiedNoise,
    /// Changes of the schedule's filter between steps.
    switches: usize,
}

impl Run<'_> {
    /// The tier of `base` with its filters recomputed for `full`'s noise, run over the
    /// recording, and the noise its innovations identify.
    fn identify(
        &self,
        full: &FullOrder,
        base: &crokf_formats::Model,
    ) -> Result<Found, Box<dyn std::error::Error>> {
        let mut model = base.clone();
        if let Some(t) = model.tier.as_mut() {
            if !self.schedule {
                t.scheduled.clear();
            }
        }
        crokf_compile::model_file::tier::refilter(full, &mut model)?;
        model.validate()?;
        let run = filter_run(&model, self.inputs, self.measurements)?;
        let noise = crokf_compile::nonlinear::identify::identify_noise(
            full,
            &model,
            &run.innovations,
            &run.filters,
            self.skip,
            self.lags,
        )?;
        Ok(Found {
            noise,
            switches: run.switches(),
        })
    }
}

/// Inputs and markers per step of the simulated recording: the full-order co-rotational
/// reference of `scenario`, markers = reference + Gaussian noise of the scene's σ (seed 7; the
/// scene's measurement channels are the model's, `refilter` checks it), every load channel 0
/// unless `given`.
fn simulated(
    full: &FullOrder,
    model: &crokf_formats::Model,
    scenario: &std::path::Path,
    given: bool,
    seed: u64,
) -> Result<Recording, Box<dyn std::error::Error>> {
    let scenario = Scenario::read(scenario)?;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let cache = std::env::var_os("CROKF_REFERENCE_CACHE").map(PathBuf::from);
    let reference = Reference::of(full, &scenario, steps, cache.as_deref())?;
    let variance = crokf_compile::outputs::Measurements::new(&full.operators).variance;
    let mut rng = Gaussian::new(seed);
    let measurements = reference
        .sensors
        .iter()
        .map(|row| {
            model
                .measurements
                .iter()
                .zip(&variance)
                .map(|(m, v)| {
                    Some(
                        row[3 * m.sensor as usize + m.component as usize] + v.sqrt() * rng.normal(),
                    )
                })
                .collect()
        })
        .collect();
    let inputs = reference
        .inputs
        .iter()
        .map(|row| {
            row.iter()
                .zip(&model.inputs)
                .map(|(&v, input)| match input.kind {
                    crokf_formats::InputKind::Load { .. } if !given => 0.0,
                    _ => v,
                })
                .collect()
        })
        .collect();
    Ok((inputs, measurements))
}

/// Inputs and markers per step of a user's recording in `crokf-run`'s CSV formats: steps
/// 1 … n (n: the inputs' rows, else the last measured step); without an inputs file every
/// input is 0.
fn recorded(
    model: &crokf_formats::Model,
    measurements: &std::path::Path,
    inputs: Option<&std::path::Path>,
) -> Result<Recording, Box<dyn std::error::Error>> {
    let table = crokf_run::table::read_measurements(measurements, model)?;
    let rows = match inputs {
        Some(path) => crokf_run::table::read_inputs(path, model)?.rows,
        None => {
            let last = table.keys().next_back().copied().unwrap_or(0) as usize;
            vec![vec![0.0; model.inputs.len()]; last]
        }
    };
    if let Some((&k, row)) = table.iter().find(|(&k, _)| k as usize > rows.len()) {
        return Err(format!(
            "{}: line {}: step {k} is beyond the inputs' {} steps",
            measurements.display(),
            row.line,
            rows.len()
        )
        .into());
    }
    let none = vec![None; model.measurements.len()];
    let values = (1..=rows.len() as u64)
        .map(|k| {
            table
                .get(&k)
                .map_or_else(|| none.clone(), |r| r.values.clone())
        })
        .collect();
    Ok((rows, values))
}

/// Writes `measurements` (one row per step, steps 1, 2, …) as a `crokf-run` measurements file
/// (`step`, then the model's measurement labels; an empty cell for a missing value), atomically.
fn write_measurements(
    path: &std::path::Path,
    model: &crokf_formats::Model,
    measurements: &[Vec<Option<f64>>],
) -> Result<(), Box<dyn std::error::Error>> {
    let mut text = format!("step,{}\n", model.measurement_labels().join(","));
    for (k, row) in measurements.iter().enumerate() {
        text.push_str(&(k + 1).to_string());
        for v in row {
            text.push(',');
            if let Some(v) = v {
                text.push_str(&format!("{v:e}"));
            }
        }
        text.push('\n');
    }
    crokf_formats::output::write_atomically(path, text.as_bytes())?;
    Ok(())
}

/// Inputs and measurements (`None`: missing) per step, model order.
type Recording = (Vec<Vec<f64>>, Vec<Vec<Option<f64>>>);

/// The identified σ against those of the filter run, as a Markdown table.
fn print_table(full: &FullOrder, found: &IdentifiedNoise) {
    println!("| parameter | σ of the filter run | identified σ |\n|---|---:|---:|");
    for l in &found.loads {
        let name = &full.scene.scene.loads[l.load].name;
        println!(
            "| force of '{name}' (N per step) | {:.4e} | {:.4e} |",
            l.force_sigma.0, l.force_sigma.1
        );
        if let Some((scene, identified)) = l.rate_sigma {
            println!("| force rate of '{name}' (N/s per step) | {scene:.4e} | {identified:.4e} |");
        }
    }
    if let Some(w) = found.white_scale {
        println!("| white process noise (factor) | 1 | {w:.4} |");
    }
    println!(
        "| markers (factor on the scene's σ) | 1 | {:.4} |",
        found.measurement_scale
    );
}
