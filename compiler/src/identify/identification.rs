//! The identification of a recording: the tier's filters, recomputed for a [`NoiseSpec`], run
//! over it ([`filter_run`]), their innovations fitted by [`identify_noise`] on the whole
//! recording and on each of [`BLOCKS`] blocks, `--fixed-point`'s iteration, the verdict
//! ([`Identification::check`]) and the report ([`Identification::report`]). Module docs of
//! [`crate::identify`]: the method, the uncertainty and the refusals.

use std::path::Path;

use crokf_formats::Model;

use super::als_noise::{identify_noise, IdentifiedNoise};
use crate::full_order::FullOrder;
use crate::noise::{ForceSigma, NoiseSpec};

use super::filter_run::filter_run;

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
    Table(#[from] crokf_runtime::table::TableError),
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
    /// A user's recording in `crokf-run`'s CSV formats (`crokf_runtime::table`): steps 1 … n (n:
    /// the inputs' rows, else the last measured step); without an inputs file every input is
    /// 0 (the loads withheld).
    pub fn read(
        model: &Model,
        measurements: &Path,
        inputs: Option<&Path>,
    ) -> Result<Recording, IdentifyError> {
        let table = crokf_runtime::table::read_measurements(measurements, model)?;
        let rows = match inputs {
            Some(path) => crokf_runtime::table::read_inputs(path, model)?.rows,
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
    crate::model_file::tier::refilter(full, &mut model, spec).map_err(|e| failed(&e))?;
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
        identify_noise(
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
    let (_, _, noise) = crate::model_file::tier::linearised_of_file(full, model, &full.noise)
        .map_err(|e| IdentifyError::Failed(e.to_string()))?;
    // (load, stated, σ_f, σ_ḟ) of each estimated load.
    let scene_sigmas: Vec<(usize, bool, f64, f64)> = noise
        .groups
        .iter()
        .map(|g| {
            let stated = matches!(g.statement, ForceSigma::Stated(_));
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
    /// The loads whose σ_f the recording excites (written by
    /// [`identified_scene`](super::scene_edit::identified_scene)).
    pub fn excited_loads(&self) -> impl Iterator<Item = &LoadSigma> {
        self.loads.iter().filter(|l| l.force.excited())
    }

    /// The model error's identified factor when it differs from the scene's by more than
    /// [`EXCITED_UNCERTAINTIES`] uncertainties (written by
    /// [`identified_scene`](super::scene_edit::identified_scene)); None when the recording
    /// agrees with the scene's factor or the filter has no such term.
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

#[cfg(test)]
mod tests {
    use super::*;

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
