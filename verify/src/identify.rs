//! `crokf-verify identify`: the co-rotational tier's noise identified from a recording
//! (autocovariance least squares, docs/design.md §11.6), with an uncertainty, refusals, and
//! the identified σ written into a copy of the scene for the next compile.
//!
//! The tier of a model file, its filters (gain schedule included) recomputed for the scene's
//! noise, runs from rest over a recording (inputs and markers in `crokf-run`'s CSV formats);
//! its innovations after the first `skip` steps give the sample autocovariances and
//! `crokf_compile::nonlinear::identify::identify_noise` the σ that explain them: each
//! estimated load's force σ_f (and rate σ_ḟ with rate states), the tier's model error as a
//! factor on its measured covariance (the scene's `model_error_scale`, written into the copy
//! when the recording disagrees with it) and the markers' σ as a factor on the scene's.
//!
//! Uncertainty: the recording after `skip` is cut into [`BLOCKS`] disjoint blocks of equal
//! length; each block is identified alone (the filter still runs over the whole recording from
//! rest; a block's autocovariances use only pairs of its own steps), and the uncertainty of
//! the whole recording's value is the standard error of the block values, s/√K (s their
//! sample standard deviation, K = [`BLOCKS`]: batch means).
//!
//! Refusals ([`IdentifyError`]): a recording shorter than [`MIN_STEPS_PER_LAG`] × lags steps
//! after `skip` or with fewer than [`MIN_MARKER_UPDATES`] marker updates there; a model
//! without a co-rotational tier or without estimated loads; a recording that does not excite
//! any force parameter (each within two uncertainties of 0: the markers' noise alone explains
//! the innovations); a markers' factor outside [`MARKER_FACTOR_RANGE`] (the markers' noise is
//! known, so the linearised filters do not explain the innovations).

use std::path::{Path, PathBuf};

use crokf_compile::full_order::FullOrder;
use crokf_compile::noise::{ForceSigma, NoiseSpec};
use crokf_compile::nonlinear::identify::IdentifiedNoise;
use crokf_compile::scene::{ForceModel, Scene, SceneFile};
use crokf_formats::output::{check_paths, write_atomically, Output, OutputKind};
use crokf_formats::Model;

use crate::nonlinear::identify::filter_run;

/// The recording after `skip` is cut into this many disjoint blocks for the uncertainty.
pub const BLOCKS: usize = 4;
/// A recording needs at least this many steps per lag after `skip`.
pub const MIN_STEPS_PER_LAG: usize = 10;
/// A recording needs at least this many steps with a marker value after `skip`.
pub const MIN_MARKER_UPDATES: usize = 100;
/// The markers' factor outside which the linearised filters do not explain the innovations
/// (docs/design.md §11.6: 1.00–1.15 where the tier recovers a known truth, 1.26 past it).
pub const MARKER_FACTOR_RANGE: (f64, f64) = (0.8, 1.25);
/// A force parameter is excited when its value exceeds this many uncertainties.
pub const EXCITED_UNCERTAINTIES: f64 = 2.0;
/// `fixed_point` iterations at most.
pub const MAX_ITERATIONS: usize = 10;
/// `fixed_point` stops when no σ changes by more than this fraction.
pub const FIXED_POINT_TOLERANCE: f64 = 0.01;

/// Why nothing was identified or written. Every variant is a refusal: the command exits 2
/// and writes nothing.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    /// The recording is too short for the lags, or has too few marker updates.
    #[error("the recording is too short: {0}")]
    TooShort(String),
    /// No force parameter is excited: the markers' noise alone explains the innovations.
    #[error(
        "the recording is not exciting enough: {0}; record a history in which the load \
         changes (or give fewer --lags)"
    )]
    NotExcited(String),
    /// The markers' identified factor is outside [`MARKER_FACTOR_RANGE`].
    #[error("the linearised filters do not explain the innovations: {0}")]
    Unexplained(String),
    /// The model has no co-rotational tier or no estimated load.
    #[error("{0}")]
    Model(String),
    /// A CSV file of the recording (file, line and column in the message).
    #[error(transparent)]
    Table(#[from] crokf_run::RunError),
    /// The options or the output path.
    #[error("{0}")]
    Usage(String),
    /// Reading the scene or the model, running the filter or the identification.
    #[error("{0}")]
    Failed(String),
}

/// The identification's settings.
#[derive(Clone, Debug)]
pub struct IdentifyOptions {
    /// Lags 0 … lags − 1 of the autocovariances.
    pub lags: usize,
    /// Steps left out of the statistics at the start (the filter's transient from rest).
    pub skip: usize,
    /// Repeat with the filters of the σ just identified until they agree to 1 %.
    pub fixed_point: bool,
    /// Run the gain schedule (false: the filter at rest only).
    pub schedule: bool,
    /// The filters' σ_f of every estimated load instead of the scene's (N per step).
    pub filter_sigma: Option<f64>,
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        IdentifyOptions {
            lags: 30,
            skip: 50,
            fixed_point: false,
            schedule: true,
            filter_sigma: None,
        }
    }
}

/// Inputs and markers per step (one row per step 1, 2, …, model order; `None`: missing).
#[derive(Clone, Debug)]
pub struct Recording {
    /// Inputs per step.
    pub inputs: Vec<Vec<f64>>,
    /// Markers per step.
    pub measurements: Vec<Vec<Option<f64>>>,
    /// What the recording is (a file name), for the output and the scene's comment.
    pub name: String,
    /// Whether the loads were given (an inputs file) or withheld (every input 0).
    pub loads_given: bool,
}

impl Recording {
    /// A user's recording in `crokf-run`'s CSV formats (`run/src/table.rs`): steps 1 … n (n:
    /// the inputs' rows, else the last measured step); without an inputs file every input is
    /// 0 (the loads withheld).
    pub fn read(
        model: &Model,
        measurements: &Path,
        inputs: Option<&Path>,
    ) -> Result<Recording, IdentifyError> {
        let table = crokf_run::table::read_measurements(measurements, model)?;
        let rows = match inputs {
            Some(path) => crokf_run::table::read_inputs(path, model)?.rows,
            None => {
                let last = table.keys().next_back().copied().unwrap_or(0) as usize;
                vec![vec![0.0; model.inputs.len()]; last]
            }
        };
        if let Some((&k, row)) = table.iter().find(|(&k, _)| k as usize > rows.len()) {
            return Err(IdentifyError::Usage(format!(
                "{}:{}: step {k} is beyond the inputs' {} steps",
                measurements.display(),
                row.line,
                rows.len()
            )));
        }
        let none = vec![None; model.measurements.len()];
        let values = (1..=rows.len() as u64)
            .map(|k| {
                table
                    .get(&k)
                    .map_or_else(|| none.clone(), |r| r.values.clone())
            })
            .collect();
        let name = measurements.file_name().map_or_else(
            || measurements.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Ok(Recording {
            inputs: rows,
            measurements: values,
            name,
            loads_given: inputs.is_some(),
        })
    }

    /// Steps.
    pub fn steps(&self) -> usize {
        self.inputs.len()
    }
}

/// A value identified from the whole recording and from each block.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// From the whole recording after `skip`.
    pub value: f64,
    /// s/√K over the blocks (module docs).
    pub uncertainty: f64,
    /// From each block alone, in time order.
    pub blocks: Vec<f64>,
}

impl Estimate {
    fn new(value: f64, blocks: Vec<f64>) -> Estimate {
        let k = blocks.len() as f64;
        let mean = blocks.iter().sum::<f64>() / k;
        let s2 = blocks.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (k - 1.0).max(1.0);
        Estimate {
            value,
            uncertainty: (s2 / k).sqrt(),
            blocks,
        }
    }

    /// Whether the value exceeds [`EXCITED_UNCERTAINTIES`] uncertainties (and 0).
    pub fn excited(&self) -> bool {
        self.value > 0.0 && self.value > EXCITED_UNCERTAINTIES * self.uncertainty
    }
}

/// One estimated load's identified σ.
#[derive(Clone, Debug)]
pub struct LoadSigma {
    /// Index into the scene's loads.
    pub load: usize,
    /// The load's name.
    pub name: String,
    /// The scene's σ_f, N per step (stated, or derived from `range` and `rise_time`).
    pub scene_sigma: f64,
    /// Whether the scene states σ_f (`force_noise_std`) rather than the compiler deriving it.
    pub stated: bool,
    /// The σ_f of the filters that ran (the scene's unless `filter_sigma` or `fixed_point`).
    pub filter_sigma: f64,
    /// σ_f identified, N per step.
    pub force: Estimate,
    /// With rate states: the scene's σ_ḟ (N/s per step) and the identified.
    pub rate: Option<(f64, Estimate)>,
}

/// The tier's model-error factor: the scene's, the filters', the identified.
#[derive(Clone, Debug)]
pub struct ModelErrorFactor {
    /// The scene's `model_error_scale` (1 unless stated).
    pub scene: f64,
    /// The factor of the filters that ran (the scene's unless `fixed_point`).
    pub filter: f64,
    /// Identified.
    pub factor: Estimate,
}

/// What `fixed_point` did.
#[derive(Clone, Debug)]
pub struct FixedPoint {
    /// Identification runs.
    pub iterations: usize,
    /// Whether the σ agreed to [`FIXED_POINT_TOLERANCE`].
    pub converged: bool,
    /// The largest relative change of the last iteration.
    pub last_change: f64,
    /// Why it stopped early, if it did (a σ identified as 0).
    pub stopped: Option<String>,
}

/// The identification of a recording.
#[derive(Clone, Debug)]
pub struct Identification {
    /// Per estimated load, scene order.
    pub loads: Vec<LoadSigma>,
    /// The factor on the σ of the white process-noise channels (None without any).
    pub white: Option<Estimate>,
    /// The tier's model error (docs/design.md §11.9) as a factor on its measured S (None when
    /// the tier has no measured S).
    pub model_error: Option<ModelErrorFactor>,
    /// The factor on the markers' σ: the check.
    pub markers: Estimate,
    /// The recording's name.
    pub recording: String,
    /// Steps of the recording.
    pub steps: usize,
    /// Whether the loads were given.
    pub loads_given: bool,
    /// Innovations in the statistics of the whole recording.
    pub samples: usize,
    /// ‖C(θ) − Ĉ‖ / ‖Ĉ‖ of the whole recording's fit.
    pub relative_residual: f64,
    /// The options.
    pub lags: usize,
    /// The options.
    pub skip: usize,
    /// Filters of the run (1 + scheduled points) and changes between steps.
    pub filters: usize,
    /// Changes of the schedule's filter between steps.
    pub switches: usize,
    /// The first step (0-based) of each block and the end of the last.
    pub block_bounds: Vec<usize>,
    /// `fixed_point`'s course.
    pub fixed_point: Option<FixedPoint>,
}

/// One run of the identification over the whole recording with the σ of one [`NoiseSpec`].
struct Run {
    /// The σ of the run's filters.
    spec: NoiseSpec,
    model: Model,
    innovations: Vec<Vec<f64>>,
    filters: Vec<(usize, usize)>,
    switches: usize,
}

/// Runs the tier's filter, recomputed for the noise `spec` on the scene `full`, over
/// `recording`.
fn filter_over(
    full: &FullOrder,
    spec: &NoiseSpec,
    base: &Model,
    recording: &Recording,
    schedule: bool,
) -> Result<Run, IdentifyError> {
    let mut model = base.clone();
    if let Some(t) = model.tier.as_mut() {
        if !schedule {
            t.scheduled.clear();
        }
    }
    let failed = |e: &dyn std::fmt::Display| IdentifyError::Failed(e.to_string());
    crokf_compile::model_file::tier::refilter(full, &mut model, spec).map_err(|e| failed(&e))?;
    model.validate().map_err(|e| failed(&e))?;
    let run =
        filter_run(&model, &recording.inputs, &recording.measurements).map_err(|e| failed(&e))?;
    Ok(Run {
        spec: spec.clone(),
        switches: run.switches(),
        model,
        innovations: run.innovations,
        filters: run.filters,
    })
}

impl Run {
    /// The noise of steps `from .. to` (0-based; the filter's covariance is propagated from
    /// step 0).
    fn identify(
        &self,
        full: &FullOrder,
        from: usize,
        to: usize,
        lags: usize,
    ) -> Result<IdentifiedNoise, IdentifyError> {
        crokf_compile::nonlinear::identify::identify_noise(
            full,
            &self.spec,
            &self.model,
            &self.innovations[..to],
            &self.filters[..to],
            from,
            lags,
        )
        .map_err(|e| IdentifyError::Failed(format!("the identification failed: {e}")))
    }
}

/// Refuses a recording too short for `options` (module docs) and a model the identification
/// cannot use.
fn check_inputs(
    full: &FullOrder,
    model: &Model,
    recording: &Recording,
    options: &IdentifyOptions,
) -> Result<(), IdentifyError> {
    let Some(tier) = model.tier.as_ref() else {
        return Err(IdentifyError::Model(
            "the model has no co-rotational tier: identify runs the tier's filters; compile \
             the scene with [reduction] model = \"corotational\""
                .into(),
        ));
    };
    if full.noise.forces.is_empty() || tier.force_loads.is_empty() {
        return Err(IdentifyError::Model(
            "the model estimates no load (no load with force_model = \"random_walk\" and a \
             range or force_noise_std): there is no force σ to identify"
                .into(),
        ));
    }
    if options.lags < 2 {
        return Err(IdentifyError::Usage(format!(
            "--lags {}: at least 2",
            options.lags
        )));
    }
    let steps = recording.steps();
    let after = steps.saturating_sub(options.skip);
    let needed = MIN_STEPS_PER_LAG * options.lags;
    if after < needed {
        return Err(IdentifyError::TooShort(format!(
            "{} has {steps} steps, {after} after --skip {}; --lags {} needs at least \
             {needed} ({MIN_STEPS_PER_LAG} × lags)",
            recording.name, options.skip, options.lags
        )));
    }
    let updates = recording.measurements[options.skip..]
        .iter()
        .filter(|row| row.iter().any(Option::is_some))
        .count();
    if updates < MIN_MARKER_UPDATES {
        return Err(IdentifyError::TooShort(format!(
            "{} has {updates} steps with a marker value after --skip {}, fewer than \
             {MIN_MARKER_UPDATES}",
            recording.name, options.skip
        )));
    }
    Ok(())
}

/// Identifies the noise of `model`'s tier from `recording` (module docs). `full` is the scene
/// the model was compiled from; the filters start from its noise (`full.noise`), and the
/// fixed point varies a copy of it. The verdict is [`Identification::check`].
pub fn identify(
    full: &FullOrder,
    model: &Model,
    recording: &Recording,
    options: &IdentifyOptions,
) -> Result<Identification, IdentifyError> {
    check_inputs(full, model, recording, options)?;
    // The scene's σ (stated or derived on the file's linearisation, as the compile did)
    // before any filter σ replaces them.
    let (_, _, noise) =
        crokf_compile::model_file::tier::linearised_of_file(full, model, &full.noise)
            .map_err(|e| IdentifyError::Failed(e.to_string()))?;
    // (load, stated, σ_f, σ_ḟ) of each estimated load.
    let scene_sigmas: Vec<(usize, bool, f64, f64)> = noise
        .groups
        .iter()
        .map(|g| {
            let stated = matches!(g.statement, crokf_compile::noise::ForceSigma::Stated(_));
            (g.load, stated, g.sigma, g.rate_sigma)
        })
        .collect();
    let mut spec = full.noise.clone();
    if let Some(sigma) = options.filter_sigma {
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(IdentifyError::Usage(format!(
                "filter σ {sigma}: must be > 0 (N per step)"
            )));
        }
        spec = spec.with_force_sigma(sigma);
    }
    let scene_factor = full.noise.model_error_scale;
    let (steps, skip, lags) = (recording.steps(), options.skip, options.lags);
    let mut run = filter_over(full, &spec, model, recording, options.schedule)?;
    let mut whole = run.identify(full, skip, steps, lags)?;
    let mut fixed = None;
    if options.fixed_point {
        let mut course = FixedPoint {
            iterations: 1,
            converged: false,
            last_change: f64::INFINITY,
            stopped: None,
        };
        while course.iterations < MAX_ITERATIONS {
            let mut change = 0.0f64;
            let mut next = Vec::new();
            for l in &whole.loads {
                let name = &full.scene.scene.loads[l.load].name;
                let mut pairs = vec![(l.force_sigma, false)];
                if let Some(rate) = l.rate_sigma {
                    pairs.push((rate, true));
                }
                for ((old, new), is_rate) in pairs {
                    if new <= 0.0 {
                        course.stopped = Some(format!(
                            "σ{} of load '{name}' identified as 0: no filter of that σ (the \
                             filter needs σ > 0); the values are those of the last filter",
                            if is_rate { "_ḟ" } else { "_f" }
                        ));
                    }
                    change = change.max((new / old - 1.0).abs());
                    next.push((l.load, is_rate, new));
                }
            }
            if let Some((old, new)) = whole.model_error_scale {
                // A factor may be 0 (the filters then run without the term).
                if old != new {
                    change = change.max((new - old).abs() / old.max(new));
                }
            }
            course.last_change = change;
            if course.stopped.is_some() {
                break;
            }
            if change < FIXED_POINT_TOLERANCE {
                course.converged = true;
                break;
            }
            for (g, is_rate, new) in next {
                let Some(force) = spec.force_mut(g) else {
                    return Err(IdentifyError::Failed(format!(
                        "load group {g} identified but not estimated by the scene"
                    )));
                };
                if is_rate {
                    force.rate_sigma = new;
                } else {
                    force.sigma = ForceSigma::Stated(new);
                }
            }
            if let Some((_, new)) = whole.model_error_scale {
                spec.model_error_scale = new;
            }
            run = filter_over(full, &spec, model, recording, options.schedule)?;
            whole = run.identify(full, skip, steps, lags)?;
            course.iterations += 1;
        }
        fixed = Some(course);
    }
    // The blocks, with the last run's filters.
    let bounds: Vec<usize> = (0..=BLOCKS)
        .map(|b| skip + b * (steps - skip) / BLOCKS)
        .collect();
    let blocks: Vec<IdentifiedNoise> = bounds
        .windows(2)
        .map(|w| run.identify(full, w[0], w[1], lags))
        .collect::<Result<_, _>>()?;
    let loads = whole
        .loads
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let (stated, scene_sigma, scene_rate) = scene_sigmas
                .iter()
                .find(|(g, ..)| *g == l.load)
                .map_or((false, l.force_sigma.0, 0.0), |&(_, s, f, r)| (s, f, r));
            let force = Estimate::new(
                l.force_sigma.1,
                blocks.iter().map(|b| b.loads[i].force_sigma.1).collect(),
            );
            let rate = l.rate_sigma.map(|(_, value)| {
                (
                    scene_rate,
                    Estimate::new(
                        value,
                        blocks
                            .iter()
                            .map(|b| b.loads[i].rate_sigma.map_or(0.0, |r| r.1))
                            .collect(),
                    ),
                )
            });
            LoadSigma {
                load: l.load,
                name: full.scene.scene.loads[l.load].name.clone(),
                scene_sigma,
                stated,
                filter_sigma: l.force_sigma.0,
                force,
                rate,
            }
        })
        .collect();
    let white = whole.white_scale.map(|w| {
        Estimate::new(
            w,
            blocks
                .iter()
                .map(|b| b.white_scale.unwrap_or(0.0))
                .collect(),
        )
    });
    let model_error = whole
        .model_error_scale
        .map(|(filter, value)| ModelErrorFactor {
            scene: scene_factor,
            filter,
            factor: Estimate::new(
                value,
                blocks
                    .iter()
                    .map(|b| b.model_error_scale.map_or(0.0, |m| m.1))
                    .collect(),
            ),
        });
    let markers = Estimate::new(
        whole.measurement_scale,
        blocks.iter().map(|b| b.measurement_scale).collect(),
    );
    Ok(Identification {
        loads,
        white,
        model_error,
        markers,
        recording: recording.name.clone(),
        steps,
        loads_given: recording.loads_given,
        samples: whole.estimate.samples,
        relative_residual: whole.estimate.relative_residual,
        lags,
        skip,
        filters: 1 + if options.schedule {
            model.tier.as_ref().map_or(0, |t| t.scheduled.len())
        } else {
            0
        },
        switches: run.switches,
        block_bounds: bounds,
        fixed_point: fixed,
    })
}

impl Identification {
    /// The loads whose σ_f the recording excites (written by [`identified_scene`]).
    pub fn excited_loads(&self) -> impl Iterator<Item = &LoadSigma> {
        self.loads.iter().filter(|l| l.force.excited())
    }

    /// The model error's identified factor when it differs from the scene's by more than
    /// [`EXCITED_UNCERTAINTIES`] uncertainties (written by [`identified_scene`]); None when the
    /// recording agrees with the scene's factor or the filter has no such term.
    pub fn model_error_changed(&self) -> Option<&Estimate> {
        self.model_error
            .as_ref()
            .filter(|m| {
                (m.factor.value - m.scene).abs() > EXCITED_UNCERTAINTIES * m.factor.uncertainty
            })
            .map(|m| &m.factor)
    }

    /// The verdict: `Ok` when the markers' factor is within [`MARKER_FACTOR_RANGE`] and at
    /// least one force parameter is excited; the refusal otherwise.
    pub fn check(&self) -> Result<(), IdentifyError> {
        let (lo, hi) = MARKER_FACTOR_RANGE;
        let m = &self.markers;
        if !(lo..=hi).contains(&m.value) {
            return Err(IdentifyError::Unexplained(format!(
                "the markers' factor {:.3} ± {:.3} is outside [{lo}, {hi}] (the markers' σ \
                 is known); a recording nearer the trained states, or the loads given \
                 (--inputs), may be explained",
                m.value, m.uncertainty
            )));
        }
        let excited = self
            .loads
            .iter()
            .any(|l| l.force.excited() || l.rate.as_ref().is_some_and(|(_, r)| r.excited()));
        if !excited {
            let list: Vec<String> = self
                .loads
                .iter()
                .map(|l| {
                    format!(
                        "σ_f of '{}' {:.3e} ± {:.3e} N",
                        l.name, l.force.value, l.force.uncertainty
                    )
                })
                .collect();
            let model_error = self
                .model_error
                .as_ref()
                .map(|m| {
                    format!(
                        "; the model error's factor {:.3} ± {:.3} (scene {:.3}) is not \
                         written from a recording that excites no force",
                        m.factor.value, m.factor.uncertainty, m.scene
                    )
                })
                .unwrap_or_default();
            return Err(IdentifyError::NotExcited(format!(
                "every force σ is within {EXCITED_UNCERTAINTIES} uncertainties of 0 ({}): the \
                 markers' noise alone explains the innovations{model_error}",
                list.join(", ")
            )));
        }
        Ok(())
    }

    /// The method's line, the table and the verdict (Markdown), as the command prints them.
    pub fn report(&self) -> String {
        let mut s = format!(
            "{}: {} steps ({} innovations after --skip {}), loads {}, lags {}, {} filter(s), \
             {} switches; fit: relative residual {:.3}\n",
            self.recording,
            self.steps,
            self.samples,
            self.skip,
            if self.loads_given {
                "given (--inputs)"
            } else {
                "withheld"
            },
            self.lags,
            self.filters,
            self.switches,
            self.relative_residual
        );
        if let Some(f) = &self.fixed_point {
            s.push_str(&format!(
                "fixed point: {} after {} run(s) (last change {:.2} %){}\n",
                if f.converged {
                    "reached"
                } else {
                    "not reached"
                },
                f.iterations,
                100.0 * f.last_change,
                f.stopped
                    .as_ref()
                    .map(|w| format!("; {w}"))
                    .unwrap_or_default()
            ));
        }
        let bounds: Vec<String> = self
            .block_bounds
            .windows(2)
            .map(|w| format!("{}–{}", w[0] + 1, w[1]))
            .collect();
        s.push_str(&format!(
            "uncertainty (±): standard error over {BLOCKS} disjoint blocks of the recording \
             after --skip (steps {}), each identified alone: s/√{BLOCKS}, s the standard \
             deviation of the block values\n\n",
            bounds.join(", ")
        ));
        s.push_str(
            "| parameter | scene | filter | identified | ± | per block |\n\
             |---|---:|---:|---:|---:|---|\n",
        );
        let blocks = |e: &Estimate| {
            e.blocks
                .iter()
                .map(|b| format!("{b:.3e}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for l in &self.loads {
            s.push_str(&format!(
                "| σ_f of '{}' (N per step; scene: {}) | {:.4e} | {:.4e} | {:.4e} | {:.2e} | {} |\n",
                l.name,
                if l.stated { "stated" } else { "derived" },
                l.scene_sigma,
                l.filter_sigma,
                l.force.value,
                l.force.uncertainty,
                blocks(&l.force)
            ));
            if let Some((scene, rate)) = &l.rate {
                s.push_str(&format!(
                    "| σ_ḟ of '{}' (N/s per step) | {scene:.4e} | {scene:.4e} | {:.4e} | {:.2e} | {} |\n",
                    l.name,
                    rate.value,
                    rate.uncertainty,
                    blocks(rate)
                ));
            }
        }
        if let Some(w) = &self.white {
            s.push_str(&format!(
                "| white process noise (factor) | 1 | 1 | {:.4} | {:.2e} | {} |\n",
                w.value,
                w.uncertainty,
                blocks(w)
            ));
        }
        if let Some(m) = &self.model_error {
            s.push_str(&format!(
                "| the tier's model error (factor on its measured S) | {:.4} | {:.4} | {:.4} | \
                 {:.2e} | {} |\n",
                m.scene,
                m.filter,
                m.factor.value,
                m.factor.uncertainty,
                blocks(&m.factor)
            ));
        }
        s.push_str(&format!(
            "| markers (factor on the scene's σ; the check) | 1 | 1 | {:.4} | {:.2e} | {} |\n",
            self.markers.value,
            self.markers.uncertainty,
            blocks(&self.markers)
        ));
        s.push('\n');
        s.push_str(&self.verdict());
        s.push('\n');
        s
    }

    /// One line: identified (which σ, the markers' factor) or why not.
    pub fn verdict(&self) -> String {
        match self.check() {
            Err(e) => format!("verdict: NOT IDENTIFIED: {e}"),
            Ok(()) => {
                let (lo, hi) = MARKER_FACTOR_RANGE;
                let mut parts: Vec<String> = self
                    .excited_loads()
                    .map(|l| {
                        format!(
                            "σ_f of '{}' = {:.3e} ± {:.1e} N per step (scene {:.3e})",
                            l.name, l.force.value, l.force.uncertainty, l.scene_sigma
                        )
                    })
                    .collect();
                for l in self.loads.iter().filter(|l| !l.force.excited()) {
                    parts.push(format!(
                        "σ_f of '{}' not excited ({:.1e} ± {:.1e}; the scene's kept)",
                        l.name, l.force.value, l.force.uncertainty
                    ));
                }
                if let Some(m) = &self.model_error {
                    let (value, u, scene) = (m.factor.value, m.factor.uncertainty, m.scene);
                    parts.push(if self.model_error_changed().is_some() {
                        format!("the model error's factor = {value:.3} ± {u:.3} (scene {scene:.3})")
                    } else {
                        format!(
                            "the model error's factor {value:.3} ± {u:.3} agrees with the \
                             scene's {scene:.3} (kept)"
                        )
                    });
                }
                format!(
                    "verdict: IDENTIFIED: {}; markers' factor {:.3} ± {:.3} within [{lo}, {hi}]",
                    parts.join("; "),
                    self.markers.value,
                    self.markers.uncertainty
                )
            }
        }
    }
}

/// The text of `scene` with each excited load's `force_noise_std` set to its identified σ_f
/// (rounded to 4 significant digits), `force_model = "random_walk"` made explicit, and a
/// comment line above the value naming this command, the recording and the uncertainty;
/// every other byte as in the file. The loads must be `[[load]]` tables. The result is
/// parsed back and compared with the scene (refused unless only those fields changed).
pub fn identified_scene(
    scene: &SceneFile,
    found: &Identification,
) -> Result<String, IdentifyError> {
    let values: Vec<(usize, f64, String)> = found
        .excited_loads()
        .map(|l| {
            let value: f64 = format!("{:.3e}", l.force.value)
                .parse()
                .unwrap_or(l.force.value);
            let comment = format!(
                "identified by crokf-verify identify from {} ({} steps, lags {}, skip {}): \
                 {:.3e} ± {:.1e} N per step (standard error over {BLOCKS} blocks); the scene's \
                 was {:.3e} ({})",
                found.recording,
                found.steps,
                found.lags,
                found.skip,
                l.force.value,
                l.force.uncertainty,
                l.scene_sigma,
                if l.stated {
                    "stated"
                } else {
                    "derived from range and rise_time"
                }
            );
            (l.load, value, comment)
        })
        .collect();
    let mut text = set_force_sigmas(&scene.text, &values)
        .map_err(|e| IdentifyError::Failed(format!("{}: {e}", scene.path.display())))?;
    let scale = found.model_error_changed().map(|m| {
        let value: f64 = format!("{:.3e}", m.value).parse().unwrap_or(m.value);
        let comment = format!(
            "identified by crokf-verify identify from {} ({} steps, lags {}, skip {}): {:.3} ± \
             {:.1e} (standard error over {BLOCKS} blocks); the scene's was {}",
            found.recording,
            found.steps,
            found.lags,
            found.skip,
            m.value,
            m.uncertainty,
            found.model_error.as_ref().map_or(1.0, |m| m.scene)
        );
        (value, comment)
    });
    if let Some((value, comment)) = &scale {
        text = set_model_error_scale(&text, *value, comment)
            .map_err(|e| IdentifyError::Failed(format!("{}: {e}", scene.path.display())))?;
    }
    // Only the stated fields changed: the parsed copy equals the scene with them set.
    let written = Scene::parse(&text, &scene.path)
        .map_err(|e| IdentifyError::Failed(format!("the edited scene does not parse: {e}")))?;
    let mut expected =
        Scene::parse(&scene.text, &scene.path).map_err(|e| IdentifyError::Failed(e.to_string()))?;
    for &(g, value, _) in &values {
        expected.loads[g].force_noise_std = value;
        expected.loads[g].force_model_stated = Some(ForceModel::RandomWalk);
    }
    if let (Some((value, _)), Some(spec)) = (&scale, expected.reduction.corotational.as_mut()) {
        spec.model_error_scale = Some(*value);
    }
    if written != expected {
        return Err(IdentifyError::Failed(format!(
            "{}: editing the scene changed more than its force σ and model-error factor; \
             write the loads as [[load]] tables and [reduction.corotational] as a table, with \
             one key per line",
            scene.path.display()
        )));
    }
    Ok(text)
}

/// A table's values as the TOML parser sees them (byte spans into the text).
type SpannedTable = std::collections::BTreeMap<String, toml::Spanned<toml::Value>>;

/// The `[[load]]` tables and `[reduction.corotational]` as the TOML parser sees them.
#[derive(serde::Deserialize)]
struct SpannedScene {
    #[serde(default)]
    load: Vec<SpannedTable>,
    reduction: Option<SpannedReduction>,
}

/// `[reduction]`'s `corotational` table.
#[derive(serde::Deserialize)]
struct SpannedReduction {
    corotational: Option<SpannedTable>,
}

/// The last table header before byte `at` of `body`, without spaces and comment
/// (`[[load]]`, `[reduction.corotational]`).
fn header_before(body: &str, at: usize) -> Option<String> {
    body[..at]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .map(|h| h.split('#').next().unwrap_or("").replace([' ', '\t'], ""))
}

/// A scene's text parsed with byte spans, for edits that keep every other byte (a byte-order
/// mark and CRLF line ends included).
struct SceneText<'a> {
    text: &'a str,
    /// Bytes of a leading byte-order mark (0 or 3).
    bom: usize,
    parsed: SpannedScene,
    newline: &'static str,
}

impl<'a> SceneText<'a> {
    fn parse(text: &'a str) -> Result<Self, String> {
        let bom = if text.starts_with('\u{feff}') { 3 } else { 0 };
        let parsed = toml::from_str(&text[bom..]).map_err(|e| e.to_string())?;
        let newline = if text.contains("\r\n") { "\r\n" } else { "\n" };
        Ok(SceneText {
            text,
            bom,
            parsed,
            newline,
        })
    }

    /// The text after the byte-order mark (the spans' reference).
    fn body(&self) -> &'a str {
        &self.text[self.bom..]
    }

    fn line_start(&self, at: usize) -> usize {
        self.body()[..at].rfind('\n').map_or(0, |i| i + 1)
    }

    fn line_end(&self, at: usize) -> usize {
        let body = self.body();
        body[at..].find('\n').map_or(body.len(), |i| at + i + 1)
    }

    /// The spaces and tabs that start the line at `line_start`.
    fn indent(&self, line_start: usize) -> String {
        self.body()[line_start..]
            .chars()
            .take_while(|c| *c == ' ' || *c == '\t')
            .collect()
    }

    /// The text with `edits` (byte ranges of the body, new text) applied from the end.
    fn edited(&self, mut edits: Vec<(std::ops::Range<usize>, String)>) -> String {
        edits.sort_by(|a, b| b.0.start.cmp(&a.0.start).then(b.0.end.cmp(&a.0.end)));
        let mut out = self.body().to_owned();
        for (range, new) in edits {
            out.replace_range(range, &new);
        }
        format!("{}{out}", &self.text[..self.bom])
    }
}

/// `text` with load `g`'s `force_noise_std` = value (and `force_model = "random_walk"`) for
/// each `(g, value, comment)`, the comment on a line of its own above the value.
fn set_force_sigmas(text: &str, values: &[(usize, f64, String)]) -> Result<String, String> {
    let scene = SceneText::parse(text)?;
    let (body, newline) = (scene.body(), scene.newline);
    let mut edits: Vec<(std::ops::Range<usize>, String)> = Vec::new();
    for (g, value, comment) in values {
        let table = scene
            .parsed
            .load
            .get(*g)
            .ok_or_else(|| format!("load {g} is not in the file"))?;
        let name = table
            .get("name")
            .ok_or_else(|| format!("load {g} has no name"))?;
        let start = scene.line_start(name.span().start);
        // The table must be a `[[load]]` table: its header is the last table header before
        // its name.
        if header_before(body, start).as_deref() != Some("[[load]]") {
            return Err(format!(
                "load '{}' is not a [[load]] table with one key per line: write it so to \
                 have its force σ written",
                name.get_ref().as_str().unwrap_or("?")
            ));
        }
        let indent = scene.indent(start);
        let comment_line = format!("{indent}# {comment}{newline}");
        let model_line = match table.get("force_model") {
            Some(_) => String::new(),
            None => format!("{indent}force_model = \"random_walk\"{newline}"),
        };
        let number = format!("{value:e}");
        match table.get("force_noise_std") {
            Some(old) => {
                let at = scene.line_start(old.span().start);
                edits.push((old.span(), number));
                edits.push((at..at, format!("{model_line}{comment_line}")));
            }
            None => {
                let last = table.values().map(|v| v.span().end).max().unwrap_or(0);
                let at = scene.line_end(last);
                let lead = if at == body.len() && !body.ends_with('\n') {
                    newline
                } else {
                    ""
                };
                edits.push((
                    at..at,
                    format!(
                        "{lead}{model_line}{comment_line}{indent}force_noise_std = {number}{newline}"
                    ),
                ));
            }
        }
    }
    Ok(scene.edited(edits))
}

/// `text` with `[reduction.corotational] model_error_scale = value`, the comment on a line of
/// its own above it: the key's line replaced where the table states it, else the key added
/// above the table's first key. The table must be written as a `[reduction.corotational]`
/// header with one key per line.
fn set_model_error_scale(text: &str, value: f64, comment: &str) -> Result<String, String> {
    let scene = SceneText::parse(text)?;
    let table = scene
        .parsed
        .reduction
        .as_ref()
        .and_then(|r| r.corotational.as_ref())
        .ok_or("no [reduction.corotational] table to write model_error_scale in")?;
    let first = table
        .values()
        .map(|v| scene.line_start(v.span().start))
        .min()
        .ok_or("[reduction.corotational] has no keys")?;
    if header_before(scene.body(), first).as_deref() != Some("[reduction.corotational]") {
        return Err(
            "[reduction.corotational] is not written as a table with one key per \
                    line: write it so to have model_error_scale written"
                .into(),
        );
    }
    let (range, indent) = match table.get("model_error_scale") {
        Some(old) => {
            let at = scene.line_start(old.span().start);
            (at..scene.line_end(old.span().end), scene.indent(at))
        }
        None => (first..first, String::new()),
    };
    let newline = scene.newline;
    let line =
        format!("{indent}# {comment}{newline}{indent}model_error_scale = {value:e}{newline}");
    Ok(scene.edited(vec![(range, line)]))
}

/// Writes `text` (from [`identified_scene`]) to `out`, atomically. Refused: `out` equal to
/// one of `inputs`, or in another folder than the scene's (its relative paths, the mesh and
/// node lists, resolve from the scene's folder).
pub fn write_scene(
    scene: &Path,
    out: &Path,
    inputs: &[(&str, &Path)],
    text: &str,
) -> Result<(), IdentifyError> {
    check_output(scene, out, inputs)?;
    write_atomically(out, text.as_bytes()).map_err(|e| IdentifyError::Failed(e.to_string()))
}

/// The checks of [`write_scene`], before any work.
pub fn check_output(
    scene: &Path,
    out: &Path,
    inputs: &[(&str, &Path)],
) -> Result<(), IdentifyError> {
    let outputs = [Output {
        role: "-o",
        path: out,
        kind: OutputKind::File,
    }];
    check_paths(inputs, &outputs).map_err(|e| IdentifyError::Usage(e.to_string()))?;
    let folder = |p: &Path| {
        crokf_formats::output::canonical(p).and_then(|c| c.parent().map(Path::to_path_buf))
    };
    let (a, b): (Option<PathBuf>, Option<PathBuf>) = (folder(scene), folder(out));
    if a.is_none() || a != b {
        return Err(IdentifyError::Usage(format!(
            "-o {}: write the identified scene into the scene's folder ({}): its relative \
             paths (mesh file, node lists) resolve from there",
            out.display(),
            scene
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .display()
        )));
    }
    Ok(())
}

/// The files of one identification (the command's arguments).
#[derive(Clone, Debug)]
pub struct Files<'a> {
    /// The scene the model was compiled from.
    pub scene: &'a Path,
    /// The model file, with a co-rotational tier.
    pub model: &'a Path,
    /// The recorded markers (`crokf-run`'s measurements CSV).
    pub measurements: &'a Path,
    /// The recorded inputs (`crokf-run`'s inputs CSV); `None`: every input 0.
    pub inputs: Option<&'a Path>,
    /// Where the scene with the identified σ goes (the scene's folder).
    pub out: Option<&'a Path>,
}

/// A refusal, with the identification when there was one (its report says why).
#[derive(Debug)]
pub struct Refusal {
    /// Why.
    pub error: IdentifyError,
    /// The identification refused by its verdict (not excited, markers unexplained).
    pub found: Option<Box<Identification>>,
}

impl From<IdentifyError> for Refusal {
    fn from(error: IdentifyError) -> Refusal {
        Refusal { error, found: None }
    }
}

/// `crokf-verify identify` (and `crokf.identify`): reads the files, refuses an output over an
/// input or outside the scene's folder before any work, identifies, checks the verdict and
/// writes the scene with the identified σ to `files.out` (nothing written on a refusal).
pub fn identify_files(
    files: &Files<'_>,
    options: &IdentifyOptions,
) -> Result<Identification, Refusal> {
    let failed = |e: &dyn std::fmt::Display| IdentifyError::Failed(e.to_string());
    let scene = SceneFile::read(files.scene).map_err(|e| failed(&e))?;
    let read = scene.input_files();
    let mut inputs: Vec<(&str, &Path)> = vec![
        ("scene", files.scene),
        ("model", files.model),
        ("--measurements", files.measurements),
    ];
    if let Some(i) = files.inputs {
        inputs.push(("--inputs", i));
    }
    inputs.extend(read.iter().map(|(role, p)| (*role, p.as_path())));
    if let Some(out) = files.out {
        check_output(files.scene, out, &inputs)?;
    }
    let model = crokf_runtime::load_model(files.model).map_err(|e| failed(&e))?;
    let recording = Recording::read(&model, files.measurements, files.inputs)?;
    let full = FullOrder::build(
        files.scene,
        &mut crokf_compile::report::StageTimer::default(),
    )
    .map_err(|e| failed(&e))?;
    let found = identify(&full, &model, &recording, options)?;
    if let Err(error) = found.check() {
        return Err(Refusal {
            error,
            found: Some(Box::new(found)),
        });
    }
    if let Some(out) = files.out {
        let text = identified_scene(&full.scene, &found)?;
        write_scene(files.scene, out, &inputs, &text)?;
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = "# a scene\n[mesh]\nfile = \"m.msh\"\n\n[[load]]\nname = \"tip\"\n\
        group = \"tip\"   # the end\nrange = 20.0\n\n[[load]]\n  name = \"side\"\n  \
        force_model = \"random_walk\"\n  force_noise_std = 0.5 # old\n  rise_time = 0.1\n\n\
        [time]\ndt = 0.001\n";

    /// A stated σ is replaced in place; a load without one gets `force_model` and the value
    /// after its last key; every other byte is kept.
    #[test]
    fn force_sigmas_are_set_and_the_rest_is_kept() {
        let out =
            set_force_sigmas(SCENE, &[(0, 0.25, "c0".into()), (1, 1.5e-3, "c1".into())]).unwrap();
        let expected = "# a scene\n[mesh]\nfile = \"m.msh\"\n\n[[load]]\nname = \"tip\"\n\
        group = \"tip\"   # the end\nrange = 20.0\nforce_model = \"random_walk\"\n# c0\n\
        force_noise_std = 2.5e-1\n\n[[load]]\n  name = \"side\"\n  \
        force_model = \"random_walk\"\n  # c1\n  force_noise_std = 1.5e-3 # old\n  rise_time = 0.1\n\n\
        [time]\ndt = 0.001\n";
        assert_eq!(out, expected);
        // CRLF line ends stay CRLF, a byte-order mark stays.
        let crlf = format!("\u{feff}{}", SCENE.replace('\n', "\r\n"));
        let out = set_force_sigmas(&crlf, &[(0, 0.25, "c0".into())]).unwrap();
        assert!(out.starts_with('\u{feff}'));
        assert!(out.contains(
            "range = 20.0\r\nforce_model = \"random_walk\"\r\n# c0\r\nforce_noise_std = 2.5e-1\r\n"
        ));
        assert_eq!(out.matches('\n').count(), out.matches("\r\n").count());
    }

    /// A load written as an inline table is refused, naming it.
    #[test]
    fn inline_loads_are_refused() {
        let text = "load = [{ name = \"tip\", range = 1.0 }]\n";
        let e = set_force_sigmas(text, &[(0, 0.25, "c".into())]).unwrap_err();
        assert!(e.contains("'tip'") && e.contains("[[load]]"), "{e}");
    }

    /// The tier's `model_error_scale`: replaced in place where `[reduction.corotational]`
    /// states it (its indent kept), else added as the table's first key; CRLF kept; a scene
    /// without that table header is refused.
    #[test]
    fn the_model_error_scale_is_set_in_its_table() {
        let text = "[reduction]\nmodel = \"corotational\"\n\n[reduction.corotational]\n\
            duration = 1.0\n  model_error_scale = 1.0 # was\n\n[time]\ndt = 0.001\n";
        let out = set_model_error_scale(text, 0.25, "c").unwrap();
        assert_eq!(
            out,
            "[reduction]\nmodel = \"corotational\"\n\n[reduction.corotational]\n\
            duration = 1.0\n  # c\n  model_error_scale = 2.5e-1\n\n[time]\ndt = 0.001\n"
        );
        let without = text.replace("  model_error_scale = 1.0 # was\n", "");
        let out = set_model_error_scale(&without, 0.25, "c").unwrap();
        assert!(
            out.contains("[reduction.corotational]\n# c\nmodel_error_scale = 2.5e-1\nduration"),
            "{out}"
        );
        // The key of another table is not taken for it.
        let other = without.replace("dt = 0.001", "dt = 0.001\nmodel_error_scale = 3.0");
        let out = set_model_error_scale(&other, 0.25, "c").unwrap();
        assert!(out.contains("model_error_scale = 3.0") && out.contains("= 2.5e-1\nduration"));
        let crlf = text.replace('\n', "\r\n");
        let out = set_model_error_scale(&crlf, 0.25, "c").unwrap();
        assert!(
            out.contains("  # c\r\n  model_error_scale = 2.5e-1\r\n"),
            "{out}"
        );
        assert_eq!(out.matches('\n').count(), out.matches("\r\n").count());
        let e = set_model_error_scale("[time]\ndt = 0.001\n", 0.25, "c").unwrap_err();
        assert!(e.contains("[reduction.corotational]"), "{e}");
    }

    /// The uncertainty is s/√K of the block values.
    #[test]
    fn the_uncertainty_is_the_standard_error_of_the_blocks() {
        let e = Estimate::new(2.0, vec![1.0, 2.0, 3.0, 2.0]);
        // s² = (1 + 0 + 1 + 0) / 3, u = √(s²/4).
        assert!((e.uncertainty - (2.0f64 / 3.0 / 4.0).sqrt()).abs() < 1e-15);
        assert!(e.excited());
        assert!(!Estimate::new(0.5, vec![0.0, 1.0, 0.0, 1.0]).excited());
        assert!(!Estimate::new(0.0, vec![0.0; 4]).excited());
    }
}
