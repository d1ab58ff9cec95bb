//! Open-loop and filtered error of compiled models against the full-order co-rotational FEM on
//! a scenario (docs/design.md §10 item 5, §11.4, docs/results/tier.md): the runtime's
//! `Estimator` on each MODEL file, three runs: open loop (the scenario's loads as inputs),
//! filtered with the loads given, filtered with the loads withheld (every load channel 0: only
//! the markers); filtered runs get the reference's sensor displacements plus Gaussian noise of
//! the model's σ (seed 7; all channels, the runtime uses those active in the step's phase; gate
//! off). Errors are relative L2 over the displayed nodes (and the sensors, and the tip marker)
//! and the whole trajectory, world frame. The filtered runs also give ANIS (ν = y − ŷ⁻ over the
//! phase's active channels, S = H P⁻_p Hᵀ + R from the model's stored covariances: the tier's
//! gain schedule's filter in use at the step), the tip marker's ANEES (posterior P_p), both with
//! their two-sided 95 % χ² bounds, the fraction of displayed-node error components inside ±2σ
//! (runtime σ, `Estimator::node_std`), the count of innovations beyond 5σ of their own variance
//! (docs/design.md §11.3, §11.5), all from `crokf_verify::comparison::ConsistencyAccumulator`,
//! the code of `crokf-verify report`; and the tier's force states at the end. The step time is
//! that of `predict` + `update` only (wall clock).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example nonlinear_filter -- SCENE SCENARIO MODEL...
//! ```
//! MODEL is a model file or `FILE@SCENE2` (FILE's tier with its filter recomputed for SCENE2,
//! see `read_model`).
//! SCENE is the scene of the reference (either tier's scene: same mesh and material).
//!
//! `--seeds N` (N ≥ 2) also repeats each filtered run with the markers' noise drawn from seeds
//! 7, 8, …, 6 + N and prints a second table: the error's mean and range over the N runs, and
//! the N-run consistency test (`crokf_verify::comparison::Ensemble`, docs/design.md §11.3): at
//! each step the N-run average NIS and tip NEES against the 95 % bounds of χ²(N d)/(N d), the
//! fractions of steps below / inside / above them (≈ 95 % inside for a consistent filter), valid
//! where one run's errors are correlated in time, unlike the single-run bounds of the first
//! table; and the 2σ coverage's mean and range.
//!
//! Then, per segment of the scenario (cut at its load times, `crokf_verify::comparison::segments`)
//! and with `--seeds`, the same fractions and the coverage of each filtered run; and one line of
//! advice per problem of each filtered run (`crokf_verify::comparison::advice`, the rules of
//! `crokf-verify report`; with `--noise-scale` ≠ 1 the markers are not drawn with the
//! model's σ and the advice says so).
//!
//! `--imm P` (a measuring prototype, docs/design.md §11.5–11.6): exactly two MODEL arguments,
//! the same tier with two load models (without and with force rates, or two force σ), run as an
//! interacting-multiple-model filter, stay probability P per step (`imm_rows`): the error, the
//! second model's mean weight and the mixture's tip NEES over `--seeds` draws.
//!
//! Measuring aids (flags; an unknown flag is an error): `--runs open,given,withheld` runs only
//! those; `--no-model-error` recomputes a `FILE@SCENE2` filter without the tier's model-error
//! noise (docs/design.md §11.9), `--model-error-scale C` with that noise's measured covariance
//! × C (C replaces SCENE2's `model_error_scale`); `--noise-scale C` scales the markers' noise
//! (0: noise-free, the filter unchanged); `--no-schedule` drops the tier's gain schedule (the
//! filter designed at rest only, docs/design.md §11.5); `--trace` prints ‖q‖, ‖q̇‖, ‖q̈‖ and f
//! before and after every update, and the schedule's filter that made the update, on stderr;
//! `--marker-phase O` makes sparse markers arrive O steps earlier in their period (O
//! predictions at rest first); `--error-trace` prints each step's error and reference norm
//! over the displayed nodes, the phase and the tier's force states on stderr (lines starting
//! `ERR`); `--hold-force-sigma` holds the tier's force σ at its designed level (no levels,
//! docs/design.md §11.10: `Estimator::set_force_adaptation(false)`);
//! `--marker-lost SENSOR:FROM:STEPS` drops that sensor's values (an empty SENSOR: the tip
//! marker's) for those records (a marker lost) and, with `--seeds`, adds a table of the
//! consistency before, during and after the loss; each filtered run that carried its own
//! covariance (a channel missing or gated, docs/design.md §11.11) prints its number of such
//! steps on stderr; `--stored-gains` keeps the stored gains and σ then instead
//! (`Estimator::set_covariance_recursion(false)`).
//!
//! `--reference-cache FILE` keeps the reference run in FILE (written once, read while the step
//! count matches: use one file per scene and scenario).

use std::ops::Range;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::OnceLock;

use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_runtime::{load_model, Estimator};
use crokf_verify::comparison::advice::{self, AdviceFigures, Context, Tier};
use crokf_verify::comparison::segments::{segment_figures, segments, MERGE_STEPS};
use crokf_verify::comparison::{
    segment_table, spread, ChiSquare, Consistency, ConsistencyAccumulator, Ensemble, FilterBlocks,
    Gaussian, SeedEnsemble,
};
use crokf_verify::nonlinear::reference::{displayed, Reference};
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

/// The command line's flags (set once in `run`, read where the runs are made).
static FLAGS: OnceLock<Flags> = OnceLock::new();

/// The flags; their defaults before `run` has parsed them.
fn flags() -> &'static Flags {
    FLAGS.get_or_init(Flags::default)
}

/// The command line's flags: `--seeds`, `--imm` and the measuring aids (see the header).
struct Flags {
    /// `--seeds N`: the filtered runs repeated over N noise seeds (1 without).
    seeds: u64,
    /// `--imm P`: the two models as an IMM filter, stay probability P.
    imm: Option<f64>,
    /// `--runs open,given,withheld`: only the runs named.
    runs: Option<String>,
    /// `--no-model-error`: a `FILE@SCENE2` filter without the tier's model-error noise.
    no_model_error: bool,
    /// `--model-error-scale C`: that noise's covariance × C (replaces SCENE2's factor).
    model_error_scale: Option<f64>,
    /// `--noise-scale C`: the factor on the markers' σ (1 without).
    noise_scale: f64,
    /// `--no-schedule`: the tier's gain schedule dropped.
    no_schedule: bool,
    /// `--trace`: ‖q‖, ‖q̇‖, ‖q̈‖ and f around every update, on stderr.
    trace: bool,
    /// `--marker-phase O`: O predictions at rest before the scenario.
    marker_phase: usize,
    /// `--error-trace`: each step's error on stderr (lines starting `ERR`).
    error_trace: bool,
    /// `--hold-force-sigma`: the tier's force σ held at its designed level.
    hold_force_sigma: bool,
    /// `--marker-lost SENSOR:FROM:STEPS`, as given.
    marker_lost: Option<String>,
    /// `--stored-gains`: the stored gains and σ while a channel is missing.
    stored_gains: bool,
    /// `--reference-cache FILE`: the reference run kept in FILE.
    reference_cache: Option<PathBuf>,
}

impl Default for Flags {
    /// No flag given.
    fn default() -> Self {
        Flags {
            seeds: 1,
            imm: None,
            runs: None,
            no_model_error: false,
            model_error_scale: None,
            noise_scale: 1.0,
            no_schedule: false,
            trace: false,
            marker_phase: 0,
            error_trace: false,
            hold_force_sigma: false,
            marker_lost: None,
            stored_gains: false,
            reference_cache: None,
        }
    }
}

impl Flags {
    /// The flags out of `args`, which keeps the positional arguments; an unknown flag is an
    /// error naming it.
    fn parse(args: &mut Vec<String>) -> Result<Flags, String> {
        let mut flags = Flags::default();
        let mut positional = Vec::new();
        let mut it = std::mem::take(args).into_iter();
        while let Some(arg) = it.next() {
            if !arg.starts_with("--") {
                positional.push(arg);
                continue;
            }
            let mut value = |what: &str| it.next().ok_or_else(|| format!("{arg} needs {what}"));
            match arg.as_str() {
                "--seeds" => {
                    flags.seeds = value("a whole number N ≥ 2")?
                        .parse::<u64>()
                        .ok()
                        .filter(|&n| n >= 2)
                        .ok_or("--seeds needs a whole number N ≥ 2")?
                }
                "--imm" => {
                    flags.imm = Some(
                        value("the probability P of staying in a model per step")?
                            .parse::<f64>()
                            .ok()
                            .filter(|p| *p > 0.0 && *p < 1.0)
                            .ok_or(
                                "--imm needs the probability P of staying in a model per step, 0 < P < 1",
                            )?,
                    )
                }
                "--runs" => flags.runs = Some(value("a list such as open,given,withheld")?),
                "--no-model-error" => flags.no_model_error = true,
                "--model-error-scale" => {
                    let v = value("a factor ≥ 0")?;
                    flags.model_error_scale = Some(
                        v.parse()
                            .ok()
                            .filter(|c: &f64| c.is_finite() && *c >= 0.0)
                            .ok_or_else(|| format!("--model-error-scale {v}: not a factor ≥ 0"))?,
                    )
                }
                "--noise-scale" => {
                    let v = value("a number")?;
                    flags.noise_scale = v
                        .parse()
                        .map_err(|_| format!("--noise-scale {v}: not a number"))?
                }
                "--no-schedule" => flags.no_schedule = true,
                "--trace" => flags.trace = true,
                "--marker-phase" => {
                    let v = value("a whole number of steps")?;
                    flags.marker_phase = v
                        .parse()
                        .map_err(|_| format!("--marker-phase {v}: not a whole number of steps"))?
                }
                "--error-trace" => flags.error_trace = true,
                "--hold-force-sigma" => flags.hold_force_sigma = true,
                "--marker-lost" => flags.marker_lost = Some(value("SENSOR:FROM:STEPS")?),
                "--stored-gains" => flags.stored_gains = true,
                "--reference-cache" => {
                    flags.reference_cache = Some(PathBuf::from(value("a file")?))
                }
                _ => return Err(format!("unknown flag {arg}")),
            }
        }
        *args = positional;
        Ok(flags)
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let parsed = Flags::parse(&mut args)?;
    let (seeds, imm) = (parsed.seeds, parsed.imm);
    if FLAGS.set(parsed).is_err() {
        return Err("the flags were read before they were parsed".into());
    }
    if args.len() < 3 {
        return Err(
            "usage: nonlinear_filter SCENE SCENARIO MODEL... [--seeds N] [--imm P] [flags: see the header]"
                .into(),
        );
    }
    if imm.is_some() && args.len() != 4 {
        return Err("--imm needs exactly two MODEL arguments".into());
    }
    let full = FullOrder::build(&PathBuf::from(&args[0]), &mut StageTimer::default())?;
    let scenario = Scenario::read(&PathBuf::from(&args[1]))?;
    let ops = &full.operators;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let reference = Reference::of(&full, &scenario, steps, flags().reference_cache.as_deref())?;
    let tip = reference.tip_marker(&full);
    println!(
        "tip marker: {} (NEES); loads withheld = every load channel 0, gravity kept\n",
        ops.sensors.get(tip).map_or("—", |s| s.name.as_str())
    );
    if let Some(stay) = imm {
        return imm_rows(&args[2..], stay, seeds, &reference, tip);
    }
    println!(
        "| model | tier | run | nodes | sensors | tip | ANIS [95 % bounds] | tip ANEES [95 % bounds] | 2σ coverage | > 5σ innovations | final f (N) | median step (µs) |\n|---|---|---|---:|---:|---:|---|---|---:|---:|---|---:|"
    );
    let mut ensembles = Vec::new();
    // Every filtered run, for the per-segment table and the advice: (label, tier, its
    // ensemble over the seeds, or of its one run, the model's open-loop error when run).
    let mut advised: Vec<Advised> = Vec::new();
    for path in &args[2..] {
        let mut model = read_model(path)?;
        // --no-schedule (a measuring aid): the tier's filter designed at rest only, as
        // before the gain schedule (docs/design.md §11.5).
        if flags().no_schedule {
            if let Some(t) = model.tier.as_mut() {
                t.scheduled.clear();
            }
        }
        let tier = if model.tier.is_some() {
            "co-rotational"
        } else {
            "warped"
        };
        // --runs open,given,withheld (a measuring aid): only the runs named.
        let only = flags().runs.clone();
        let mut open_loop = None;
        for run in [Run::OpenLoop, Run::Given, Run::Withheld] {
            if only
                .as_deref()
                .is_some_and(|o| !o.split(',').any(|w| run.label().contains(w)))
            {
                continue;
            }
            let out = match run_model(&model, run, &reference, tip, SEED) {
                Ok(out) => out,
                Err(e) => {
                    println!("| {path} | {tier} | {} | refused: {e} |", run.label());
                    continue;
                }
            };
            let label = format!("{path} | {}", run.label());
            let tier_kind = if model.tier.is_some() {
                Tier::Corotational
            } else {
                Tier::Warped
            };
            if run == Run::OpenLoop {
                open_loop = Some(out.nodes);
            } else if seeds > 1 {
                let e = ensemble(&model, run, &reference, tip, seeds);
                if let Ok(e) = &e {
                    if e.nis.runs() > 0 {
                        advised.push((label.clone(), tier_kind, e.clone(), open_loop));
                    }
                }
                ensembles.push((label, e));
            } else if let Some(c) = &out.consistency {
                advised.push((
                    label,
                    tier_kind,
                    SeedEnsemble::of_run(out.nodes, c)?,
                    open_loop,
                ));
            }
            let stat = |c: &Option<ChiSquare>| match c {
                Some(c) if c.dof > 0 => {
                    let (lo, hi) = c.bounds();
                    format!("{:.3} [{lo:.3}, {hi:.3}]", c.mean())
                }
                _ => "—".into(),
            };
            println!(
                "| {path} | {tier} | {} | {:.2} % | {:.2} % | {:.2} % | {} | {} | {} | {} | {} | {:.1} |",
                run.label(),
                100.0 * out.nodes,
                100.0 * out.sensors,
                100.0 * out.tip,
                stat(&out.nis),
                stat(&out.nees),
                out.coverage
                    .map_or("—".into(), |c| format!("{:.1} %", 100.0 * c)),
                out.outliers.map_or("—".into(), |n| n.to_string()),
                if out.forces.is_empty() {
                    "—".into()
                } else {
                    format!(
                        "[{}]",
                        out.forces
                            .iter()
                            .map(|f| format!("{f:.4}"))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                },
                out.median_step * 1e6
            );
        }
    }
    if !ensembles.is_empty() {
        println!(
            "\n{seeds} noise seeds ({SEED}…{}): nodes error, N-run ANIS and tip ANEES per step against χ²(N d)/(N d) (steps below / inside / above the 95 % bounds), 2σ coverage\n",
            SEED + seeds - 1
        );
        println!("| model | run | nodes: mean [min, max] | ANIS: mean, steps below / inside / above | tip ANEES: mean, steps below / inside / above | 2σ coverage: mean [min, max] | refused |\n|---|---|---|---|---|---|---|");
        for (label, e) in &ensembles {
            match e {
                Ok(e) => println!("| {label} | {} |", ensemble_row(e)),
                Err(err) => println!("| {label} | {err} |"),
            }
        }
    }
    let cuts = segments(&scenario, full.wilson.dt, steps);
    if seeds > 1 && !advised.is_empty() {
        println!(
            "\nPer segment (the scenario cut at its load times, breakpoints closer than \
             {MERGE_STEPS} steps merged): steps whose {seeds}-run NIS and tip NEES lie below / \
             inside / above their 95 % bounds, 2σ coverage\n"
        );
        let rows: Vec<(String, Vec<_>)> = advised
            .iter()
            .map(|(label, _, e, _)| (label.clone(), segment_figures(e, &cuts)))
            .collect();
        print!("{}", segment_table("model | run", &rows));
    }
    if let Some((sensor, lost)) = marker_lost(ops.sensors.iter().map(|s| s.name.as_str()), tip)? {
        if seeds > 1 {
            lost_marker_table(&advised, &ops.sensors[sensor].name, lost, seeds);
        }
    }
    print_advice(&advised, &cuts, &scenario, seeds)?;
    Ok(())
}

/// `--marker-lost`: per filtered run, the N-run NIS and tip NEES fractions below / inside /
/// above their bounds and the 2σ coverage over the records before the loss (as many as it
/// lasts), while the marker is lost, and after it (as many again).
fn lost_marker_table(advised: &[Advised], name: &str, lost: Range<usize>, seeds: u64) {
    let n = lost.len();
    let windows = [
        ("before", lost.start.saturating_sub(n)..lost.start),
        ("lost", lost.clone()),
        ("after", lost.end..lost.end + n),
    ];
    println!(
        "\nMarker '{name}' lost for records {} … {} ({n} steps): {seeds}-run NIS and tip NEES \
         below / inside / above their 95 % bounds, 2σ coverage\n",
        lost.start,
        lost.end.saturating_sub(1)
    );
    println!("| model | run | window | steps | NIS % below / inside / above | tip NEES % below / inside / above | 2σ coverage |\n|---|---|---|---:|---|---|---:|");
    for (label, _, e, _) in advised {
        for (what, w) in &windows {
            let nees = e.nees_tip.fractions_in(w.clone());
            println!(
                "| {label} | {what} | {} | {} | {} | {:.1} % |",
                nees.steps,
                e.nis.fractions_in(w.clone()).percentages(),
                nees.percentages(),
                100.0 * e.coverage_in(w.clone())
            );
        }
    }
}

/// A filtered run for the advice: label, tier, its ensemble over the seeds (or of its one run),
/// the model's open-loop error (loads given) when that run was made.
type Advised = (String, Tier, SeedEnsemble, Option<f64>);

/// One line of advice per problem of each filtered run (`crokf_verify::comparison::advice`),
/// from its figures over the seeds (or its one run).
fn print_advice(
    advised: &[Advised],
    cuts: &[crokf_verify::comparison::segments::Segment],
    scenario: &Scenario,
    seeds: u64,
) -> Result<(), Box<dyn std::error::Error>> {
    if advised.is_empty() {
        return Ok(());
    }
    let loads: Vec<String> = scenario
        .loads
        .iter()
        .filter(|l| l.forces.iter().flatten().any(|&f| f != 0.0))
        .map(|l| l.name.clone())
        .collect();
    let markers_from_noise_std = flags().noise_scale == 1.0;
    let mut lines = Vec::new();
    for (label, tier, e, open_loop) in advised {
        let segments = segment_figures(e, cuts);
        let figures = AdviceFigures {
            tier: *tier,
            markers_from_noise_std,
            loads_given: label.ends_with(Run::Given.label()),
            nis: e.nis.fractions(),
            nees_tip: e.nees_tip.fractions(),
            coverage: e.coverage_in(0..e.coverage_steps.len()),
            filtered_error: spread(&e.errors).map_or(f64::NAN, |s| s.0),
            model_error: *open_loop,
            segments: &segments,
            loads: &loads,
            own_covariance: e.own_covariance_fraction(),
        };
        let context = Context::from(&figures);
        for a in advice::advise(&figures) {
            lines.push(format!("{label}: {}", a.line(&context)));
        }
    }
    let over = if seeds > 1 {
        format!("{seeds} seeds")
    } else {
        "one seed (--seeds N for N)".to_owned()
    };
    if lines.is_empty() {
        println!("\nWhat to change ({over}): nothing, every filtered run is within its bounds.");
    } else {
        println!("\nWhat to change ({over}):\n");
        for line in lines {
            println!("- {line}");
        }
    }
    Ok(())
}

/// `--marker-lost SENSOR:FROM:STEPS` (a measuring aid, docs/results/verification.md, a lost
/// marker): the index of sensor SENSOR among `names` (the sensors in the model's order, which
/// is the scene's; an empty SENSOR: `tip`, the run's tip marker) and the records
/// FROM … FROM + STEPS − 1 without its values; None without the flag.
fn marker_lost<'a>(
    mut names: impl Iterator<Item = &'a str>,
    tip: usize,
) -> Result<Option<(usize, Range<usize>)>, String> {
    let Some(v) = flags().marker_lost.as_deref() else {
        return Ok(None);
    };
    let bad = || format!("--marker-lost {v}: expected SENSOR:FROM:STEPS");
    let mut parts = v.split(':');
    let (Some(name), Some(from), Some(count), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(bad());
    };
    let sensor = if name.is_empty() {
        tip
    } else {
        names
            .position(|s| s == name)
            .ok_or_else(|| format!("--marker-lost {v}: the scene has no sensor '{name}'"))?
    };
    let from: usize = from.parse().map_err(|_| bad())?;
    let count: usize = count.parse().map_err(|_| bad())?;
    Ok(Some((sensor, from..from.saturating_add(count))))
}

/// `--imm P` (a measuring prototype, docs/design.md §11.5–11.6): the two MODEL files (the same
/// tier with two load models: without and with force rates, or two force σ) run as an
/// interacting-multiple-model filter (Blom & Bar-Shalom 1988) with fixed gains: each step the
/// two states are mixed with the Markov weights (stay P, switch 1 − P; a state without rates
/// gets ḟ = 0, one with them loses ḟ), both predicted and updated, and the model weights follow
/// the innovations' likelihoods N(ν; 0, S) (S from each filter's stored prior covariance); the
/// estimate is the weighted mean of the displayed nodes. The filters' covariances are not mixed
/// (constant gains); the mixture's tip covariance Σ μ_j (P_j + d_j d_jᵀ) gives its NEES. Over
/// `--seeds` noise draws; a refused step ends the table with its error.
fn imm_rows(
    paths: &[String],
    stay: f64,
    seeds: u64,
    reference: &Reference,
    tip: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let [a, b] = paths else {
        return Err("--imm needs exactly two MODEL arguments".into());
    };
    let models = [read_model(a)?, read_model(b)?];
    println!(
        "\nIMM of {a} and {b}, stay {stay} per step, seeds {SEED}…{}\n",
        SEED + seeds - 1
    );
    println!(
        "| run | nodes error: mean [min, max] | mean weight of the second model | tip NEES of the mixture: mean, steps below / inside / above |\n|---|---|---:|---|"
    );
    for run in [Run::Given, Run::Withheld] {
        let (mut errors, mut weights) = (Vec::new(), Vec::new());
        let mut nees = Ensemble::default();
        for seed in SEED..SEED + seeds {
            let (e, w, steps) = run_imm(&models, stay, run, reference, tip, seed)?;
            errors.push(e);
            weights.push(w);
            nees.add(&steps)?;
        }
        let (m, lo, hi) = spread(&errors).ok_or("no run")?;
        let (w, _, _) = spread(&weights).ok_or("no run")?;
        let f = nees.fractions();
        println!(
            "| {} | {:.2} [{:.2}, {:.2}] % | {w:.3} | {:.3}, {:.1} / {:.1} / {:.1} % of {} |",
            run.label(),
            100.0 * m,
            100.0 * lo,
            100.0 * hi,
            nees.total().mean(),
            100.0 * f.below,
            100.0 * f.inside,
            100.0 * f.above,
            f.steps
        );
    }
    Ok(())
}

/// One IMM run (see [`imm_rows`]): the relative L2 error over the displayed nodes, the second
/// model's mean weight, and per step the tip's NEES against the mixture's covariance
/// Σ μ_j (P_j + d_j d_jᵀ) (d_j = the model's tip estimate − the mixture's).
fn run_imm(
    models: &[crokf_formats::Model; 2],
    stay: f64,
    run: Run,
    reference: &Reference,
    tip: usize,
    seed: u64,
) -> Result<(f64, f64, Vec<ChiSquare>), Box<dyn std::error::Error>> {
    let (sensors_ref, shown_ref) = (&reference.sensors, &reference.shown);
    let steps = reference.inputs.len();
    let mut est = Vec::with_capacity(2);
    for m in models {
        let mut e = Estimator::new(m)?;
        e.set_innovation_gate(None);
        est.push(e);
    }
    let blocks: Vec<FilterBlocks> = models.iter().map(|m| FilterBlocks::new(m, &[])).collect();
    let mut acc: Vec<ConsistencyAccumulator> = models
        .iter()
        .zip(&blocks)
        .map(|(m, b)| ConsistencyAccumulator::new(b, m, None))
        .collect();
    let p = [[stay, 1.0 - stay], [1.0 - stay, stay]];
    let mut mu = [0.5, 0.5];
    let model = &models[0];
    let mut drive = Drive::new(model, reference, run, seed, tip)?;
    let width = shown_ref[0].len();
    let mut parts = vec![vec![0.0; width]; 2];
    let mut sensors = vec![vec![0.0; 3 * model.sensors.len()]; 2];
    let mut nees_steps = Vec::with_capacity(steps);
    let (mut e2, mut r2, mut weight) = (0.0, 0.0, 0.0);
    for k in 0..steps {
        let y = drive.markers(k);
        let u = drive.inputs(k);
        // Mixing: x0_j = Σ_i μ_{i|j} x_i, μ_{i|j} = p_ij μ_i / c_j.
        let c = [
            p[0][0] * mu[0] + p[1][0] * mu[1],
            p[0][1] * mu[0] + p[1][1] * mu[1],
        ];
        let states: Vec<Vec<f64>> = est.iter().map(|e| e.state().to_vec()).collect();
        for (j, e) in est.iter_mut().enumerate() {
            let mut x = vec![0.0; states[j].len()];
            for (i, s) in states.iter().enumerate() {
                let w = p[i][j] * mu[i] / c[j];
                for (t, v) in x.iter_mut().zip(s) {
                    *t += w * v;
                }
            }
            e.set_state(&x)?;
        }
        mu = c;
        let mut ll = [None, None];
        for (j, e) in est.iter_mut().enumerate() {
            e.predict(&u)?;
            acc[j].innovation(e, &y)?;
            ll[j] = acc[j].log_likelihood();
            e.update(&y)?;
        }
        if let [Some(a), Some(b)] = ll {
            let top = a.max(b);
            let w = [mu[0] * (a - top).exp(), mu[1] * (b - top).exp()];
            mu = [w[0] / (w[0] + w[1]), w[1] / (w[0] + w[1])];
        }
        weight += mu[1];
        for (e, part) in est.iter().zip(parts.iter_mut()) {
            displayed(e, model, part)?;
        }
        for i in 0..width {
            let v = mu[0] * parts[0][i] + mu[1] * parts[1][i];
            let t = shown_ref[k][i];
            e2 += (v - t) * (v - t);
            r2 += t * t;
        }
        // The tip's NEES against the mixture's covariance.
        let mut tips = [nalgebra::Vector3::zeros(); 2];
        for j in 0..2 {
            est[j].sensor_displacements(&mut sensors[j])?;
            tips[j] = nalgebra::Vector3::from_fn(|c, _| sensors[j][3 * tip + c]);
        }
        let mix = tips[0] * mu[0] + tips[1] * mu[1];
        let mut cov = nalgebra::Matrix3::zeros();
        for j in 0..2 {
            let d = tips[j] - mix;
            cov += (acc[j].sensor_covariance(&est[j], tip) + d * d.transpose()) * mu[j];
        }
        let truth = nalgebra::Vector3::from_fn(|c, _| sensors_ref[k][3 * tip + c]);
        let e = mix - truth;
        nees_steps.push(match cov.try_inverse() {
            Some(inv) => ChiSquare {
                sum: (e.transpose() * inv * e)[(0, 0)],
                dof: 3,
            },
            None => ChiSquare::default(),
        });
    }
    Ok(((e2 / r2).sqrt(), weight / steps as f64, nees_steps))
}

/// The markers' noise seed of the single runs (and the first of `--seeds`).
const SEED: u64 = 7;

/// The row of the `--seeds` table: error, N-run NIS and tip NEES, coverage, refusals.
fn ensemble_row(e: &SeedEnsemble) -> String {
    let Some((mean, lo, hi)) = spread(&e.errors) else {
        return format!("— | — | — | — | {}", e.refusals());
    };
    let steps = |ens: &Ensemble| {
        let f = ens.fractions();
        format!(
            "{:.3}, {:.1} / {:.1} / {:.1} % of {}",
            ens.total().mean(),
            100.0 * f.below,
            100.0 * f.inside,
            100.0 * f.above,
            f.steps
        )
    };
    let (cov, cov_lo, cov_hi) = spread(&e.coverage).unwrap_or((f64::NAN, f64::NAN, f64::NAN));
    format!(
        "{:.2} [{:.2}, {:.2}] % | {} | {} | {:.1} [{:.1}, {:.1}] % | {}",
        100.0 * mean,
        100.0 * lo,
        100.0 * hi,
        steps(&e.nis),
        steps(&e.nees_tip),
        100.0 * cov,
        100.0 * cov_lo,
        100.0 * cov_hi,
        e.refusals()
    )
}

/// `run` of `model` with the markers' noise from seeds SEED … SEED + seeds − 1.
fn ensemble(
    model: &crokf_formats::Model,
    run: Run,
    reference: &Reference,
    tip: usize,
    seeds: u64,
) -> Result<SeedEnsemble, Box<dyn std::error::Error>> {
    let mut out = SeedEnsemble::default();
    for seed in SEED..SEED + seeds {
        match run_model(model, run, reference, tip, seed) {
            Ok(f) => {
                let c = f
                    .consistency
                    .ok_or("a filtered run without consistency figures")?;
                out.add(f.nodes, &c)?;
            }
            Err(e) => out.refused.push((seed, e.to_string())),
        }
    }
    Ok(out)
}

/// A model file, or `FILE@SCENE`: FILE's co-rotational tier with its filter recomputed for
/// SCENE's sensors and noise model (`crokf_compile::model_file::tier::refilter`: same training,
/// e.g. the scene's 30 Hz or 1 mm variant). FILE may then be a format-v3 or v4 tier file (read
/// past its header; its tier gets the force states of SCENE, and no gain schedule).
fn read_model(arg: &str) -> Result<crokf_formats::Model, Box<dyn std::error::Error>> {
    let Some((file, scene)) = arg.split_once('@') else {
        return Ok(load_model(arg)?);
    };
    let bytes = std::fs::read(file)?;
    let mut model = match crokf_formats::decode(&bytes) {
        Ok(m) => m,
        Err(crokf_formats::FormatError::UnsupportedVersion { found: 3 | 4, .. }) => {
            crokf_formats::decode_payload(&bytes[crokf_formats::HEADER_LEN..])?
        }
        Err(e) => return Err(e.into()),
    };
    let full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    // The scene's noise, its model-error factor replaced (not compounded) when asked.
    let mut spec = full.noise.clone();
    if flags().no_model_error {
        spec.model_error_scale = 0.0;
    }
    if let Some(c) = flags().model_error_scale {
        spec.model_error_scale = c;
    }
    let rho = crokf_compile::model_file::tier::refilter(&full, &mut model, &spec)?;
    eprintln!("{arg}: tier filter recomputed, closed-loop spectral radius {rho:.6}");
    model.validate()?;
    Ok(model)
}

/// Which run of a model.
#[derive(Clone, Copy, PartialEq)]
enum Run {
    /// Predictions only, the scenario's loads as inputs.
    OpenLoop,
    /// Filtered, the loads given.
    Given,
    /// Filtered, every load channel 0 (only the markers).
    Withheld,
}

impl Run {
    fn label(self) -> &'static str {
        match self {
            Run::OpenLoop => "open loop",
            Run::Given => "filtered, loads given",
            Run::Withheld => "filtered, loads withheld",
        }
    }
}

/// Figures of one run (relative L2 errors over the trajectory, world frame).
struct RunFigures {
    nodes: f64,
    sensors: f64,
    tip: f64,
    /// Filtered runs only.
    nis: Option<ChiSquare>,
    nees: Option<ChiSquare>,
    coverage: Option<f64>,
    /// Active innovations beyond 5σ of their own variance (what the 5σ gate would skip with
    /// every channel accepted at its period).
    outliers: Option<usize>,
    /// The tier's force states at the end (N).
    forces: Vec<f64>,
    median_step: f64,
    /// Filtered runs: the whole consistency record (per-step statistics for `--seeds`).
    consistency: Option<Consistency>,
}

/// What one run feeds the estimator at each step: the scenario's inputs (every load channel 0
/// when the run withholds the loads, gravity kept) and the markers, the reference's sensor
/// displacements plus Gaussian noise of each channel's σ (the model's filter's R) times
/// `--noise-scale`, drawn from `seed` one channel after another.
struct Drive<'a> {
    reference: &'a Reference,
    /// Per input channel: zeroed in this run.
    zeroed: Vec<bool>,
    /// Per measurement channel: its index in a step's sensor row (3 per sensor) and noise σ.
    channels: Vec<(usize, f64)>,
    /// `--marker-lost`: the lost sensor and the records without its values.
    lost: Option<(usize, Range<usize>)>,
    rng: Gaussian,
}

impl<'a> Drive<'a> {
    fn new(
        model: &crokf_formats::Model,
        reference: &'a Reference,
        run: Run,
        seed: u64,
        tip: usize,
    ) -> Result<Self, Box<dyn std::error::Error>> {
        // --noise-scale c (a measuring aid): markers with c times the model's σ (0:
        // noise-free), the filter unchanged; separates the noise-driven part of the error.
        let noise_scale = flags().noise_scale;
        let variance = &model
            .tier
            .as_ref()
            .map_or(&model.kalman, |t| &t.kalman)
            .measurement_variance;
        let reference_channels = reference.sensors.first().map_or(0, Vec::len);
        if 3 * model.sensors.len() > reference_channels {
            return Err(format!(
                "the model has {} sensors, the reference scene {}: SCENE must place the model's \
                 sensors (the same [[sensor]] tables)",
                model.sensors.len(),
                reference_channels / 3
            )
            .into());
        }
        Ok(Drive {
            reference,
            zeroed: model
                .inputs
                .iter()
                .map(|i| {
                    run == Run::Withheld && matches!(i.kind, crokf_formats::InputKind::Load { .. })
                })
                .collect(),
            channels: model
                .measurements
                .iter()
                .zip(variance)
                .map(|(m, v)| {
                    (
                        3 * m.sensor as usize + m.component as usize,
                        noise_scale * v.sqrt(),
                    )
                })
                .collect(),
            lost: marker_lost(model.sensors.iter().map(|s| s.name.as_str()), tip)?,
            rng: Gaussian::new(seed),
        })
    }

    /// The inputs of step k.
    fn inputs(&self, k: usize) -> Vec<f64> {
        self.reference.inputs[k]
            .iter()
            .zip(&self.zeroed)
            .map(|(&v, &zero)| if zero { 0.0 } else { v })
            .collect()
    }

    /// The markers of step k (every channel; the runtime uses those of its phase).
    fn markers(&mut self, k: usize) -> Vec<Option<f64>> {
        let row = &self.reference.sensors[k];
        let lost = |at: usize| {
            self.lost
                .as_ref()
                .is_some_and(|(s, when)| at / 3 == *s && when.contains(&k))
        };
        self.channels
            .iter()
            .map(|&(at, sigma)| {
                // Drawn for a lost channel too, so that the other channels' noise is the same.
                let value = row[at] + sigma * self.rng.normal();
                (!lost(at)).then_some(value)
            })
            .collect()
    }
}

fn run_model(
    model: &crokf_formats::Model,
    run: Run,
    reference: &Reference,
    tip: usize,
    seed: u64,
) -> Result<RunFigures, Box<dyn std::error::Error>> {
    let (sensors_ref, shown_ref) = (&reference.sensors, &reference.shown);
    let steps = reference.inputs.len();
    let mut est = Estimator::new(model)?;
    est.set_innovation_gate(None);
    est.set_force_adaptation(!flags().hold_force_sigma);
    est.set_covariance_recursion(!flags().stored_gains);
    // --marker-phase o (a measuring aid): o predictions at rest before the scenario starts,
    // so that sparse markers (period L) arrive at steps k ≡ L − 1 − o (mod L) instead of
    // k ≡ L − 1: the camera's clock is not synchronised with the load's start.
    let pre = flags().marker_phase;
    let error_trace = flags().error_trace;
    let rest_inputs = vec![0.0; model.inputs.len()];
    for _ in 0..pre {
        est.predict(&rest_inputs)?;
    }
    let mut drive = Drive::new(model, reference, run, seed, tip)?;
    let (mut e2, mut r2, mut se2, mut sr2, mut te2, mut tr2) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut shown = vec![0.0; shown_ref[0].len()];
    let mut sens = vec![0.0; 3 * model.sensors.len()];
    let mut times = Vec::with_capacity(steps);
    let tier = model.tier.as_ref();
    let filtered = run != Run::OpenLoop;
    // Consistency (filtered runs): every node of every set in order, as `shown`.
    let display: Vec<(usize, usize)> = model
        .node_sets
        .iter()
        .enumerate()
        .flat_map(|(set, ns)| (0..ns.node_tags.len()).map(move |i| (set, i)))
        .collect();
    let blocks = FilterBlocks::new(model, &display);
    let mut acc = ConsistencyAccumulator::new(&blocks, model, Some(tip));
    // Steps per force-σ level (docs/design.md §11.10), for the run's stderr line.
    let mut levels: std::collections::BTreeMap<usize, (f64, usize)> = Default::default();
    // Steps whose update left the filter on its own covariance (a channel missing or gated, or
    // a lowering of the force-σ level: docs/design.md §11.10–11.11): the stretches of records.
    let mut own: Vec<(usize, usize)> = Vec::new();
    for k in 0..steps {
        let y = drive.markers(k);
        let u = drive.inputs(k);
        let clock = std::time::Instant::now();
        est.predict(&u)?;
        let mut elapsed = clock.elapsed().as_secs_f64();
        if filtered {
            acc.innovation(&est, &y)?;
            let clock = std::time::Instant::now();
            let trace = flags().trace && tier.is_some();
            let norms = |s: &[f64], r: usize| {
                let n = |a: &[f64]| a.iter().map(|x| x * x).sum::<f64>().sqrt();
                format!(
                    "|q| {:.3e} |qd| {:.3e} |qdd| {:.3e} f {:?}",
                    n(&s[..r]),
                    n(&s[r..2 * r]),
                    n(&s[2 * r..3 * r]),
                    s[3 * r..]
                        .iter()
                        .map(|v| (v * 1e4).round() / 1e4)
                        .collect::<Vec<_>>()
                )
            };
            let r = tier.map_or(0, |t| t.order as usize);
            if trace {
                eprintln!(
                    "k {k} phase {} it {} prior  {}",
                    est.phase(),
                    est.tier_status().iterations,
                    norms(est.state(), r)
                );
            }
            est.update(&y)?;
            elapsed += clock.elapsed().as_secs_f64();
            if trace {
                eprintln!(
                    "k {k} filter {:?} post   {}",
                    est.tier_filter(),
                    norms(est.state(), r)
                );
            }
        }
        times.push(elapsed);
        if let Some(l) = est.force_level().filter(|_| filtered) {
            levels.entry(l.level).or_insert((l.factor, 0)).1 += 1;
        }
        if filtered && est.tier_covariance().is_some() {
            match own.last_mut() {
                Some(last) if last.1 + 1 == k => last.1 = k,
                _ => own.push((k, k)),
            }
        }
        displayed(&est, model, &mut shown)?;
        let (mut ke, mut kr) = (0.0, 0.0);
        for (a, b) in shown.iter().zip(&shown_ref[k]) {
            ke += (a - b) * (a - b);
            kr += b * b;
        }
        e2 += ke;
        r2 += kr;
        if error_trace {
            // The tier's force states (none on the warped tier).
            let forces = tier.map_or(&[][..], |t| &est.state()[3 * t.order as usize..]);
            eprintln!(
                "ERR {k} {:.6e} {:.6e} {} {:?}",
                ke.sqrt(),
                kr.sqrt(),
                est.phase(),
                forces
                    .iter()
                    .map(|v| (v * 1e4).round() / 1e4)
                    .collect::<Vec<_>>()
            );
        }
        est.sensor_displacements(&mut sens)?;
        for (i, (a, b)) in sens.iter().zip(&sensors_ref[k]).enumerate() {
            se2 += (a - b) * (a - b);
            sr2 += b * b;
            if i / 3 == tip {
                te2 += (a - b) * (a - b);
                tr2 += b * b;
            }
        }
        if filtered {
            acc.posterior(
                &est,
                (k + 1) as f64 * model.dt,
                &sensors_ref[k][3 * tip..3 * tip + 3],
                &shown,
                &shown_ref[k],
            )?;
        }
    }
    times.sort_by(f64::total_cmp);
    if !levels.is_empty() {
        eprintln!(
            "{} (seed {seed}): steps per force-σ level: {}",
            run.label(),
            levels
                .values()
                .map(|(f, n)| format!("× {f}: {n}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if !own.is_empty() {
        eprintln!(
            "{} (seed {seed}): {} steps on the filter's own covariance (records {})",
            run.label(),
            own.iter().map(|(a, b)| b + 1 - a).sum::<usize>(),
            own.iter()
                .map(|(a, b)| format!("{a} … {b}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let forces = match tier {
        Some(t) => est.state()[3 * t.order as usize..].to_vec(),
        None => Vec::new(),
    };
    let c = acc.finish();
    Ok(RunFigures {
        nodes: (e2 / r2).sqrt(),
        sensors: (se2 / sr2).sqrt(),
        tip: (te2 / tr2).sqrt(),
        nis: filtered.then_some(c.nis),
        nees: filtered.then_some(c.nees_tip),
        coverage: filtered.then_some(c.coverage_runtime),
        outliers: filtered.then_some(c.outliers),
        forces,
        median_step: times[times.len() / 2],
        consistency: filtered.then_some(c),
    })
}
