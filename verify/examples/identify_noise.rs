//! The co-rotational tier's noise identified from its own innovations (autocovariance least
//! squares, docs/design.md §11.6): the tier of MODEL, its filter recomputed at rest for SCENE's
//! noise (no gain schedule: the ALS model is the filter at rest), runs through SCENARIO with
//! the loads withheld (`--given`: given) on markers = the full-order co-rotational reference +
//! Gaussian noise of the scene's σ (seed 7, every marker at every step); its innovations
//! ν = y − ŷ⁻ after the first SKIP steps give the sample autocovariances, and
//! `crokf_compile::nonlinear::tier::identify_noise` the σ that explain them: each random-walk
//! load's force σ_f (and rate σ_ḟ), the markers' σ as a factor on the scene's (a check: 1 when
//! the markers' noise is what the scene says).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example identify_noise -- SCENE SCENARIO MODEL \
//!     [--given] [--lags L] [--skip S]
//! ```
//! Defaults: L = 30 lags, S = 50 steps. `CROKF_REFERENCE_CACHE=FILE` as in `nonlinear_filter`.

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_runtime::{load_model, Estimator};
use crokf_verify::comparison::Gaussian;
use crokf_verify::nonlinear::reference::Reference;
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

const USAGE: &str =
    "usage: identify_noise SCENE SCENARIO MODEL [--given] [--lags L] [--skip S] [--force-sigma S]";

/// The markers' factor outside which the identification is flagged (module docs).
const MARKER_FACTOR_RANGE: (f64, f64) = (0.8, 1.25);

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut positional = Vec::new();
    let (mut given, mut lags, mut skip) = (false, 30usize, 50usize);
    let mut force_sigma: Option<f64> = None;
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
        let mut number = |flag: &str| -> Result<usize, Box<dyn std::error::Error>> {
            let v = args
                .next()
                .ok_or(format!("{flag} needs a value; {USAGE}"))?;
            v.parse()
                .map_err(|_| format!("{flag} {v}: not a whole number; {USAGE}").into())
        };
        match a.as_str() {
            "--given" => given = true,
            "--lags" => lags = number("--lags")?,
            "--skip" => skip = number("--skip")?,
            _ if a.starts_with("--") => return Err(format!("unknown flag {a}; {USAGE}").into()),
            _ => positional.push(a),
        }
    }
    let [scene, scenario, model_path] = positional.as_slice() else {
        return Err(USAGE.into());
    };
    let mut full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    if let Some(sigma) = force_sigma {
        let loads: Vec<usize> = full.random_walk_loads().iter().map(|&(g, _)| g).collect();
        if loads.is_empty() {
            return Err(format!("--force-sigma: {scene} has no random-walk load").into());
        }
        for g in loads {
            full.scene.scene.loads[g].force_noise_std = sigma;
        }
    }
    let scenario = Scenario::read(&PathBuf::from(scenario))?;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    if steps <= skip {
        return Err(format!("the scenario has {steps} steps, fewer than --skip {skip}").into());
    }
    let cache = std::env::var_os("CROKF_REFERENCE_CACHE").map(PathBuf::from);
    let reference = Reference::of(&full, &scenario, steps, cache.as_deref())?;

    let mut model = load_model(model_path)?;
    let Some(tier) = model.tier.as_mut() else {
        return Err(format!("{model_path} has no co-rotational tier").into());
    };
    tier.scheduled.clear();
    crokf_compile::nonlinear::tier::refilter(&full, &mut model)?;
    model.validate()?;

    let mut est = Estimator::new(&model)?;
    est.set_innovation_gate(None);
    let variance = model
        .tier
        .as_ref()
        .map(|t| t.kalman.measurement_variance.clone())
        .unwrap_or_default();
    let is_load: Vec<bool> = model
        .inputs
        .iter()
        .map(|i| matches!(i.kind, crokf_formats::InputKind::Load { .. }))
        .collect();
    let mut rng = Gaussian::new(7);
    let mut predicted = vec![0.0; model.measurements.len()];
    let mut innovations = Vec::with_capacity(steps - skip);
    for k in 0..steps {
        let y: Vec<Option<f64>> = model
            .measurements
            .iter()
            .zip(&variance)
            .map(|(m, v)| {
                Some(
                    reference.sensors[k][3 * m.sensor as usize + m.component as usize]
                        + v.sqrt() * rng.normal(),
                )
            })
            .collect();
        let u: Vec<f64> = reference.inputs[k]
            .iter()
            .zip(&is_load)
            .map(|(&v, &load)| if load && !given { 0.0 } else { v })
            .collect();
        est.predict(&u)?;
        est.measurement_estimates(&mut predicted)?;
        if k >= skip {
            innovations.push(
                y.iter()
                    .zip(&predicted)
                    .map(|(y, p)| y.unwrap_or(0.0) - p)
                    .collect(),
            );
        }
        est.update(&y)?;
    }
    let found = crokf_compile::nonlinear::tier::identify_noise(&full, &model, &innovations, lags)?;
    println!(
        "{} steps ({} innovations after {skip}), lags {lags}, loads {}; fit: relative residual {:.3}\n",
        steps,
        found.estimate.samples,
        if given { "given" } else { "withheld" },
        found.estimate.relative_residual
    );
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
    let (lo, hi) = MARKER_FACTOR_RANGE;
    if !(lo..=hi).contains(&found.measurement_scale) {
        println!(
            "\nNOT IDENTIFIED: the markers' factor {:.2} is outside [{lo}, {hi}]: the filter at \
             rest does not explain these innovations (a recording far from rest run with a \
             strong gain); try a smaller --force-sigma or a recording nearer rest.",
            found.measurement_scale
        );
    }
    Ok(())
}
