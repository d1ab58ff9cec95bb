//! The co-rotational tier's noise identified from its own innovations (autocovariance least
//! squares, docs/design.md §11.6). The tier of MODEL, its filters (gain schedule included)
//! recomputed for SCENE's noise, runs from rest over a recording; its innovations ν = y − ŷ⁻
//! after the first SKIP steps give the sample autocovariances, the schedule's filter and phase
//! in use at each step give the model's, and `crokf_compile::identify::als_noise::identify_noise`
//! the σ that explain them: each random-walk load's force σ_f (and rate σ_ḟ), and the markers'
//! σ as a factor on the scene's.
//!
//! The recording is either
//! - simulated, `SCENE SCENARIO MODEL`: the full-order co-rotational reference of SCENARIO,
//!   markers = reference + Gaussian noise of the scene's σ (`--seed N`, default 7; every
//!   marker at every step), the loads withheld (every load channel 0; `--given`: given);
//!   `--write-recording FILE` also writes these markers as a `crokf-run` measurements file; or
//! - a user's, `SCENE MODEL --recording MEASUREMENTS.csv [--inputs INPUTS.csv]`, in
//!   `crokf-run`'s CSV formats (`runtime/src/table.rs`; without an inputs file every input is 0:
//!   the loads are withheld).
//!
//! The identification, its uncertainty over disjoint blocks and its verdict are
//! `crokf_compile::identify` (the product command is `crokf-compile identify`, for a user's
//! recording); this example adds the simulated recording and the filter flags below. The
//! markers' factor is the check of the result: the markers' noise is known (a tracking
//! system's specification; the scene's by construction when simulated), so a factor outside
//! [0.8, 1.25] says that the linearised filters do not explain the innovations, and the σ are
//! printed as not identified.
//!
//! Flags: `--force-sigma S` runs the filters of σ_f = S (N per step) on every random-walk load
//! instead of the scene's (ALS needs stable filters, not optimal ones); `--no-schedule` the
//! filter at rest only; `--fixed-point` repeats the identification with the filters of the σ
//! just identified until they agree to 1 % (at most 10 runs, the same recording): the σ that,
//! used in the filter, its own innovations confirm; `--lags L` (30), `--skip S` (50 steps);
//! `-o IDENTIFIED.toml` writes the scene with what was identified, as `crokf-compile identify
//! -o` does (in the scene's folder; nothing when the verdict refuses).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example identify_noise -- SCENE SCENARIO MODEL \
//!     [--given] [--seed N] [--write-recording FILE] [--no-schedule] [--fixed-point] \
//!     [--force-sigma S] [--lags L] [--skip S]
//! cargo run --release -p crokf-verify --example identify_noise -- SCENE MODEL \
//!     --recording MEASUREMENTS.csv [--inputs INPUTS.csv] [--fixed-point] …
//! ```
//! `--reference-cache FILE` keeps the reference run in FILE, as in `nonlinear_filter`.

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::identify::{
    identified_scene, identify, write_scene, IdentifyOptions, Recording,
};
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_runtime::load_model;
use crokf_verify::comparison::Gaussian;
use crokf_verify::nonlinear::reference::Reference;
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

const USAGE: &str =
    "usage: identify_noise SCENE SCENARIO MODEL [--given] [--seed N] [--write-recording FILE] | \
     SCENE MODEL --recording \
     MEASUREMENTS.csv [--inputs INPUTS.csv]; and [--no-schedule] [--fixed-point] [--lags L] \
     [--skip S] [--force-sigma S] [--reference-cache FILE] [-o IDENTIFIED.toml]";

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut positional = Vec::new();
    let (mut given, mut schedule, mut fixed_point) = (false, true, false);
    let (mut lags, mut skip) = (30usize, 50usize);
    let mut force_sigma: Option<f64> = None;
    let (mut recording, mut inputs_file): (Option<PathBuf>, Option<PathBuf>) = (None, None);
    let (mut seed, mut write_recording): (u64, Option<PathBuf>) = (7, None);
    let mut out: Option<PathBuf> = None;
    let mut cache: Option<PathBuf> = None;
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
        if a == "--recording"
            || a == "--inputs"
            || a == "--write-recording"
            || a == "--reference-cache"
            || a == "-o"
        {
            let v = args.next().ok_or(format!("{a} needs a file; {USAGE}"))?;
            let path = Some(PathBuf::from(v));
            match a.as_str() {
                "--recording" => recording = path,
                "--inputs" => inputs_file = path,
                "-o" => out = path,
                "--reference-cache" => cache = path,
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
    if base.tier.is_none() {
        return Err(format!("{model_path} has no co-rotational tier").into());
    }
    let full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    let recording = match (scenario, &recording) {
        (Some(scenario), _) => {
            let (inputs, measurements) = simulated(
                &full,
                &base,
                &PathBuf::from(scenario),
                given,
                seed,
                cache.as_deref(),
            )?;
            if let Some(path) = &write_recording {
                write_measurements(path, &base, &measurements)?;
                eprintln!("markers written to {}", path.display());
            }
            Recording {
                inputs,
                measurements,
                name: format!("{scenario} (simulated, seed {seed})"),
                loads_given: given,
            }
        }
        (None, Some(path)) => Recording::read(&base, path, inputs_file.as_deref())?,
        (None, None) => return Err(USAGE.into()),
    };
    let options = IdentifyOptions {
        lags,
        skip,
        fixed_point,
        schedule,
        filter_sigma: force_sigma,
    };
    let found = identify(&full, &base, &recording, &options)?;
    print!("{}", found.report());
    if let Some(out) = &out {
        found.check()?;
        let scene_path = PathBuf::from(scene);
        let text = identified_scene(&full.scene, &found)?;
        write_scene(&scene_path, out, &[("scene", &scene_path)], &text)?;
        eprintln!("identified scene written to {}", out.display());
    }
    Ok(())
}

/// Inputs and markers per step of the simulated recording: the full-order co-rotational
/// reference of `scenario`, markers = reference + Gaussian noise of the scene's σ (seed 7; the
/// scene's measurement channels are the model's, `refilter` checks it), every load channel 0
/// unless `given`; the reference kept in `cache` when given.
fn simulated(
    full: &FullOrder,
    model: &crokf_formats::Model,
    scenario: &std::path::Path,
    given: bool,
    seed: u64,
    cache: Option<&std::path::Path>,
) -> Result<Simulated, Box<dyn std::error::Error>> {
    let scenario = Scenario::read(scenario)?;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let reference = Reference::of(full, &scenario, steps, cache)?;
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

/// Writes `measurements` (one row per step, steps 1, 2, …) as a `crokf-run` measurements file
/// (`step`, then the model's measurement labels; an empty cell for a missing value), atomically.
fn write_measurements(
    path: &std::path::Path,
    model: &crokf_formats::Model,
    measurements: &[Vec<Option<f64>>],
) -> Result<(), Box<dyn std::error::Error>> {
    let text = crokf_runtime::table::measurements_text(model, measurements);
    crokf_formats::output::write_atomically(path, text.as_bytes())?;
    Ok(())
}

/// Inputs and measurements (`None`: missing) per step, model order.
type Simulated = (Vec<Vec<f64>>, Vec<Vec<Option<f64>>>);
