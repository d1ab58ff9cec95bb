//! The runs of a comparison: the full-order references, the runtime open loop, filtered
//! (loads given and withheld, over noise draws) and timed, and the compiles at each order.

use std::hint::black_box;
use std::time::Instant;

use crokf_formats as fmt;
use crokf_runtime::Estimator;

use crokf_compile::compile::compile_reduced;
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{
    CorotationalSimulator, LinearSimulator, NewtonOptions, NewtonStats, Simulator,
};
use crokf_compile::{CompileOptions, Reductor};

use crate::bench::{median_step_seconds, step_clock_seconds};
use crate::scenario::Scenario;

use super::consistency::{
    Consistency, ConsistencyAccumulator, FilterBlocks, RunLengthMismatch, SeedEnsemble,
};
use super::metrics::{ErrorSum, Gaussian};
use super::setup::Setup;
use super::{ComparisonError, ComparisonOptions, EnvelopeSummary, Progress};

/// A recorded full-order run.
pub(super) struct ReferenceRun {
    /// Per step 1..=N: displayed-node displacements (3D each, flattened).
    pub(super) display: Vec<f64>,
    /// Per step 1..=N: sensor displacements (3S each, flattened).
    pub(super) sensors: Vec<f64>,
    pub(super) step_s: f64,
    pub(super) max_rotation_deg: f64,
    pub(super) max_rotation_step: usize,
    pub(super) newton: Option<NewtonStats>,
}

pub(super) fn run_reference(
    setup: &Setup,
    scenario: &Scenario,
    corotational: Option<NewtonOptions>,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<ReferenceRun, ComparisonError> {
    let full = &setup.full;
    let fem = &full.fem;
    let n = fem.dof_count();
    let err = |e| setup.reference_error(e);
    // Sub-stepped (the converged reference, `Setup::substeps` > 1): Wilson-θ at Δt/N with
    // each scene step's load held over its N sub-steps and the acceleration restarted from the
    // equation of motion at each scene step, as the compiler's converged reference
    // (`crokf_compile::accuracy::Stepping::Converged`).
    let substeps = setup.substeps.max(1);
    let wilson = crokf_compile::dynamics::WilsonTheta {
        dt: full.wilson.dt / substeps as f64,
        theta: full.wilson.theta,
    };
    let mut linear = None;
    let mut corot = None;
    let sim: &mut dyn Simulator = match corotational {
        None => linear.insert(LinearSimulator::new(fem, wilson).map_err(err)?),
        Some(newton) => corot.insert(CorotationalSimulator::new(fem, wilson, newton).map_err(err)?),
    };
    let steps = setup.steps;
    let dt = setup.dt();
    let mut out = ReferenceRun {
        display: Vec::with_capacity(steps * 3 * setup.display.len()),
        sensors: Vec::with_capacity(steps * 3 * full.operators.sensors.len()),
        step_s: 0.0,
        max_rotation_deg: 0.0,
        max_rotation_step: 0,
        newton: None,
    };
    let mut f_cache = vec![nalgebra::Matrix3::zeros(); fem.elements.len()];
    let mut times = Vec::with_capacity(steps);
    let report_every = (steps / 100).max(1);
    progress(Progress {
        phase,
        done: 0,
        total: steps,
    });
    for k in 0..steps {
        let f = scenario.load_vector(&full.operators, n, k as f64 * dt);
        let start = Instant::now();
        if substeps > 1 {
            sim.consistent_acceleration(&f).map_err(err)?;
        }
        for _ in 0..substeps {
            sim.step(&f).map_err(err)?;
        }
        // Per sub-step: the cost of one full-order step (at Δt/N, the same work as at Δt).
        times.push(start.elapsed().as_secs_f64() / substeps as f64);
        let u = sim.displacement();
        if let Some(i) = u.iter().position(|v| !v.is_finite()) {
            return Err(ComparisonError::Invalid {
                path: setup.scenario_path.clone(),
                what: format!(
                    "{phase}: non-finite displacement at DOF {i}, step {}, t = {:.6} s",
                    k + 1,
                    (k + 1) as f64 * dt
                ),
            });
        }
        setup.displayed(u, &mut out.display);
        setup.sensors(u, &mut out.sensors);
        if corotational.is_some() {
            let angle = setup.max_rotation_deg(u, &mut f_cache);
            if angle > out.max_rotation_deg {
                out.max_rotation_deg = angle;
                out.max_rotation_step = k + 1;
            }
        }
        if (k + 1) % report_every == 0 || k + 1 == steps {
            progress(Progress {
                phase,
                done: k + 1,
                total: steps,
            });
        }
    }
    times.sort_by(f64::total_cmp);
    out.step_s = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
    out.newton = corot.as_ref().map(|c| c.stats());
    Ok(out)
}

/// Errors of one runtime run.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RunErrors {
    pub(super) display: ErrorSum,
    pub(super) tip: ErrorSum,
    pub(super) display_vs_linear: ErrorSum,
    /// The co-rotational tier's envelope status over the run (default for the warped tier).
    pub(super) envelope: EnvelopeSummary,
}

/// Drives the estimator through precomputed inputs and measurements (per step), accumulating
/// errors against the references.
#[allow(clippy::too_many_arguments)]
pub(super) fn run_runtime(
    setup: &Setup,
    est: &mut Estimator,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    corot: &ReferenceRun,
    linear: Option<&ReferenceRun>,
    mut consistency: Option<&mut ConsistencyAccumulator>,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<RunErrors, ComparisonError> {
    est.reset();
    let model_order = est.model().r();
    let nd = 3 * setup.display.len();
    let ns = 3 * setup.full.operators.sensors.len();
    let sets = &setup.full.operators.node_sets;
    let mut set_buffers: Vec<Vec<f64>> =
        sets.iter().map(|s| vec![0.0; 3 * s.nodes.len()]).collect();
    let mut display = vec![0.0; nd];
    let mut sensors = vec![0.0; ns];
    let mut errors = RunErrors::default();
    let steps = setup.steps;
    let report_every = (steps / 20).max(1);
    let runtime_err = |step: usize, source| ComparisonError::Runtime {
        path: setup.scene_path.clone(),
        order: model_order,
        step,
        source,
    };
    for k in 0..steps {
        if let Some(acc) = consistency.as_deref_mut() {
            est.predict(&inputs[k]).map_err(|e| runtime_err(k + 1, e))?;
            acc.innovation(est, &measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
            est.update(&measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
        } else {
            est.step(&inputs[k], &measurements[k])
                .map_err(|e| runtime_err(k + 1, e))?;
        }
        if est.is_corotational() {
            errors.envelope.record(&est.tier_status());
        }
        for (s, buf) in set_buffers.iter_mut().enumerate() {
            est.node_displacements(s, buf)
                .map_err(|e| runtime_err(k + 1, e))?;
        }
        for (j, &(s, i, _)) in setup.display.iter().enumerate() {
            display[3 * j..3 * j + 3].copy_from_slice(&set_buffers[s][3 * i..3 * i + 3]);
        }
        errors
            .display
            .add(&display, &corot.display[k * nd..(k + 1) * nd]);
        if let Some(lin) = linear {
            errors
                .display_vs_linear
                .add(&display, &lin.display[k * nd..(k + 1) * nd]);
        }
        if let Some(t) = setup.tip {
            est.sensor_displacements(&mut sensors)
                .map_err(|e| runtime_err(k + 1, e))?;
            errors.tip.add(
                &sensors[3 * t..3 * t + 3],
                &corot.sensors[k * ns + 3 * t..k * ns + 3 * t + 3],
            );
        }
        if let Some(acc) = consistency.as_deref_mut() {
            let tip_ref = match setup.tip {
                Some(t) => &corot.sensors[k * ns + 3 * t..k * ns + 3 * t + 3],
                None => &[][..],
            };
            acc.posterior(
                est,
                (k + 1) as f64 * setup.dt(),
                tip_ref,
                &display,
                &corot.display[k * nd..(k + 1) * nd],
            )
            .map_err(|e| runtime_err(k + 1, e))?;
        }
        if (k + 1) % report_every == 0 || k + 1 == steps {
            progress(Progress {
                phase,
                done: k + 1,
                total: steps,
            });
        }
    }
    Ok(errors)
}

/// Input sequences of a row: (open loop, filter). The open-loop run always gets the scenario's
/// loads (without inputs and measurements the runtime stays at rest); the filter gets none
/// when `withhold_loads`.
pub(super) type RowInputs = (Vec<Vec<f64>>, Vec<Vec<f64>>);

/// [`RowInputs`] of `model` on the setup's scenario.
pub(super) fn row_inputs(
    setup: &Setup,
    model: &fmt::Model,
    withhold_loads: bool,
) -> Result<RowInputs, ComparisonError> {
    let given = runtime_inputs(setup, &setup.scenario, model, false)?;
    let filter = if withhold_loads {
        runtime_inputs(setup, &setup.scenario, model, true)?
    } else {
        given.clone()
    };
    Ok((given, filter))
}

/// The row's timed steps (progress `phase`, 0/1): the median runtime step of the filter, on its
/// (inputs, measurements), and of the open loop, on its (inputs, no measurements), s.
pub(super) fn time_row(
    est: &mut Estimator,
    filter: (&[Vec<f64>], &[Vec<Option<f64>>]),
    open: (&[Vec<f64>], &[Vec<Option<f64>>]),
    samples: usize,
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> (f64, f64) {
    progress(Progress {
        phase,
        done: 0,
        total: 1,
    });
    let step_s = time_runtime(est, filter.0, filter.1, samples);
    let open_loop_step_s = time_runtime(est, open.0, open.1, samples);
    progress(Progress {
        phase,
        done: 1,
        total: 1,
    });
    (step_s, open_loop_step_s)
}

/// Median time of one `est.step` over the precomputed sequence, s, in this thread's CPU time
/// ([`step_clock_seconds`]): batches of consecutive steps (each batch ≥ ~2 ms, wrapping to the
/// start with a reset), `samples` batches.
pub(super) fn time_runtime(
    est: &mut Estimator,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    samples: usize,
) -> f64 {
    let steps = inputs.len();
    if steps == 0 {
        return f64::NAN;
    }
    est.reset();
    let mut k = 0;
    let mut run = |est: &mut Estimator, count: usize| {
        for _ in 0..count {
            if k == steps {
                est.reset();
                k = 0;
            }
            // A step can only fail on a non-invertible warp or (tier) a refused Newton step,
            // both already ruled out by the runs over the same sequence.
            let _ = black_box(est.step(black_box(&inputs[k]), black_box(&measurements[k])));
            k += 1;
        }
    };
    // Calibrate the batch so one sample lasts about 2 ms.
    let mut batch = 16;
    loop {
        let start = step_clock_seconds();
        run(est, batch);
        let t = step_clock_seconds() - start;
        // NaN (no clock) ends the calibration too.
        if t.is_nan() || t >= 2e-3 || batch >= 1 << 22 {
            break;
        }
        batch *= 2;
    }
    median_step_seconds(samples, || run(est, batch)) / batch as f64
}

/// Inputs per step k = 0..N (the step k → k+1 holds u(t_k)), in `model.inputs` order.
pub(super) fn runtime_inputs(
    setup: &Setup,
    scenario: &Scenario,
    model: &fmt::Model,
    withhold_loads: bool,
) -> Result<Vec<Vec<f64>>, ComparisonError> {
    let ops = &setup.full.operators;
    if model.inputs.len() != ops.inputs.len() {
        return Err(ComparisonError::Invalid {
            path: setup.scene_path.clone(),
            what: format!(
                "the compiled model has {} input channels, the scene {}",
                model.inputs.len(),
                ops.inputs.len()
            ),
        });
    }
    let dt = setup.dt();
    Ok((0..setup.steps)
        .map(|k| {
            let mut u = scenario.inputs_at(ops, k as f64 * dt);
            if withhold_loads {
                for (v, ch) in u.iter_mut().zip(&model.inputs) {
                    if matches!(ch.kind, fmt::InputKind::Load { .. }) {
                        *v = 0.0;
                    }
                }
            }
            u
        })
        .collect())
}

/// Synthetic measurements per step k = 0..N (the update after the step k → k+1): the
/// co-rotational reference's world sensor displacement at step k+1 plus N(0, σ_s²), on the
/// channels that the schedule's phase (k+1) mod period measures; others `None`. One sample is
/// drawn per channel per step whether used or not, so the noise does not depend on `every`.
pub(super) fn synthetic_measurements(
    model: &fmt::Model,
    corot: &ReferenceRun,
    steps: usize,
    seed: u64,
) -> Vec<Vec<Option<f64>>> {
    let mut rng = Gaussian::new(seed);
    let ns = 3 * model.sensors.len();
    // The filter the estimator runs: the tier's own when the model has one.
    let kalman = model.tier.as_ref().map_or(&model.kalman, |t| &t.kalman);
    let period = kalman.period.max(1) as usize;
    (0..steps)
        .map(|k| {
            let phase = &kalman.phases[(k + 1) % period];
            let mut y = vec![None; model.measurements.len()];
            let noise: Vec<f64> = kalman
                .measurement_variance
                .iter()
                .map(|variance| variance.sqrt() * rng.normal())
                .collect();
            for &j in &phase.measured {
                let ch = model.measurements[j as usize];
                let exact = corot.sensors[k * ns + 3 * ch.sensor as usize + ch.component as usize];
                y[j as usize] = Some(exact + noise[j as usize]);
            }
            y
        })
        .collect()
}

/// Reduces the prepared modal system at order r (truncation, Kalman, model file; the front end
/// and the modes are built once per report) and returns the model and the wall time.
pub(super) fn compile_at(
    reductor: &Reductor,
    order: usize,
    measure: bool,
) -> Result<(fmt::Model, f64), ComparisonError> {
    let start = Instant::now();
    let compiled = compile_reduced(
        reductor,
        &CompileOptions {
            order: Some(order),
            skip_measured_error: !measure,
            ..CompileOptions::default()
        },
        StageTimer::default(),
    )?;
    Ok((compiled.model, start.elapsed().as_secs_f64()))
}

/// The filtered runs of one row (a warped order or the tier) and their consistency.
pub(super) struct FilteredRuns {
    pub(super) given: RunErrors,
    pub(super) given_consistency: Consistency,
    pub(super) given_ensemble: Option<SeedEnsemble>,
    pub(super) withheld: RunErrors,
    pub(super) withheld_consistency: Consistency,
    pub(super) withheld_ensemble: Option<SeedEnsemble>,
}

/// A row's filtered runs through [`run_runtime`]: with `inputs` (the loads given, or withheld
/// when the whole comparison withholds them) and, unless `options.withhold_loads`, with the
/// loads withheld (the headline case: the runtime gets no load input, only the markers), each
/// with the same [`ConsistencyAccumulator`] over the model's own stored filters
/// ([`FilterBlocks`]: the warped model's, or the tier's gain schedule); then each repeated over
/// `options.seeds` noise draws ([`seed_ensemble`]). Progress phases `filtered {label}`,
/// `withheld {label}`, and `draws filtered {label}` / `draws withheld {label}` with the draws.
#[allow(clippy::too_many_arguments)]
pub(super) fn filtered_runs(
    setup: &Setup,
    est: &mut Estimator,
    model: &fmt::Model,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
    corot: &ReferenceRun,
    options: &ComparisonOptions,
    label: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<FilteredRuns, ComparisonError> {
    let display: Vec<(usize, usize)> = setup.display.iter().map(|&(s, i, _)| (s, i)).collect();
    let blocks = FilterBlocks::new(model, &display);
    let mut acc = ConsistencyAccumulator::new(&blocks, model, setup.tip);
    let given = run_runtime(
        setup,
        est,
        inputs,
        measurements,
        corot,
        None,
        Some(&mut acc),
        &format!("filtered {label}"),
        progress,
    )?;
    let given_consistency = acc.finish();
    let given_ensemble = seed_ensemble(
        setup,
        est,
        model,
        &blocks,
        inputs,
        corot,
        options,
        (&given, &given_consistency),
        &format!("draws filtered {label}"),
        progress,
    )?;
    if options.withhold_loads {
        return Ok(FilteredRuns {
            given,
            withheld: given,
            withheld_consistency: given_consistency.clone(),
            given_consistency,
            withheld_ensemble: given_ensemble.clone(),
            given_ensemble,
        });
    }
    let blind = runtime_inputs(setup, &setup.scenario, model, true)?;
    let mut acc = ConsistencyAccumulator::new(&blocks, model, setup.tip);
    let withheld = run_runtime(
        setup,
        est,
        &blind,
        measurements,
        corot,
        None,
        Some(&mut acc),
        &format!("withheld {label}"),
        progress,
    )?;
    let withheld_consistency = acc.finish();
    let withheld_ensemble = seed_ensemble(
        setup,
        est,
        model,
        &blocks,
        &blind,
        corot,
        options,
        (&withheld, &withheld_consistency),
        &format!("draws withheld {label}"),
        progress,
    )?;
    Ok(FilteredRuns {
        given,
        given_consistency,
        given_ensemble,
        withheld,
        withheld_consistency,
        withheld_ensemble,
    })
}

/// A filtered run over the noise draws `options.seed + i`, i = 0 … `options.seeds` − 1 (the
/// N-run consistency test, docs/design.md §11.3); `first` is the run of draw 0, already made.
/// A draw the runtime refuses is recorded with its reason. `None` below 2 draws. Progress
/// phase `phase`.
#[allow(clippy::too_many_arguments)]
pub(super) fn seed_ensemble(
    setup: &Setup,
    est: &mut Estimator,
    model: &fmt::Model,
    blocks: &FilterBlocks,
    inputs: &[Vec<f64>],
    corot: &ReferenceRun,
    options: &ComparisonOptions,
    first: (&RunErrors, &Consistency),
    phase: &str,
    progress: &mut dyn FnMut(Progress),
) -> Result<Option<SeedEnsemble>, ComparisonError> {
    if options.seeds < 2 {
        return Ok(None);
    }
    let invalid = |e: RunLengthMismatch| ComparisonError::Invalid {
        path: setup.scene_path.clone(),
        what: format!("{phase}: {e}"),
    };
    let mut ensemble = SeedEnsemble::default();
    ensemble
        .add(first.0.display.relative(), first.1)
        .map_err(invalid)?;
    for i in 1..options.seeds as u64 {
        let seed = options.seed.wrapping_add(i);
        let measurements = synthetic_measurements(model, corot, setup.steps, seed);
        let mut acc = ConsistencyAccumulator::new(blocks, model, setup.tip);
        match run_runtime(
            setup,
            est,
            inputs,
            &measurements,
            corot,
            None,
            Some(&mut acc),
            phase,
            progress,
        ) {
            Ok(errors) => ensemble
                .add(errors.display.relative(), &acc.finish())
                .map_err(invalid)?,
            Err(e) => ensemble.refused.push((seed, e.to_string())),
        }
    }
    Ok(Some(ensemble))
}
