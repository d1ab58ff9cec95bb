//! The co-rotational tier's row of a comparison: compiled once from its own scene
//! ([`compile_tier`], training included), checked against the comparison's scene and driven
//! through the runtime like the warped rows.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crokf_formats as fmt;
use crokf_runtime::Estimator;

use crokf_compile::compile::compile;
use crokf_compile::CompileOptions;

use super::runs::{
    filtered_runs, row_inputs, run_runtime, synthetic_measurements, time_row, ReferenceRun,
};
use super::setup::Setup;
use super::{ComparisonError, ComparisonOptions, Progress, RowFigures, RuntimeFigures, TierRow};

/// The co-rotational tier compiled from its scene (training included), once per report.
#[derive(Clone, Debug)]
pub struct TierModel {
    /// The tier's scene file.
    pub scene: PathBuf,
    /// The compiled model (format v3 with the tier section).
    pub model: fmt::Model,
    /// Compile wall time, training included, s.
    pub compile_s: f64,
}

/// Compiles the co-rotational tier of `scene` (`[reduction] model = "corotational"`), the whole
/// pipeline with its training runs (progress of the training on stderr, from the compiler);
/// the balanced part of the file is compiled at the scene's default order without its measured
/// error (the report measures the tier itself). Refuses a scene without the tier.
pub fn compile_tier(
    scene: &Path,
    progress: &mut dyn FnMut(Progress),
) -> Result<TierModel, ComparisonError> {
    let phase = "compile co-rotational tier";
    progress(Progress {
        phase,
        done: 0,
        total: 1,
    });
    let start = Instant::now();
    let compiled = compile(
        scene,
        &CompileOptions {
            skip_measured_error: true,
            ..CompileOptions::default()
        },
    )?;
    let compile_s = start.elapsed().as_secs_f64();
    if compiled.model.tier.is_none() {
        return Err(ComparisonError::Invalid {
            path: scene.to_owned(),
            what: "this scene has no co-rotational tier: give a scene with [reduction] model = \"corotational\" and [reduction.corotational]".into(),
        });
    }
    progress(Progress {
        phase,
        done: 1,
        total: 1,
    });
    Ok(TierModel {
        scene: scene.to_owned(),
        model: compiled.model,
        compile_s,
    })
}

impl TierModel {
    /// POD basis size r of the tier.
    pub fn basis_order(&self) -> usize {
        self.model.tier.as_ref().map_or(0, |t| t.order as usize)
    }

    /// Sampled (ECSW) elements.
    pub fn sampled_elements(&self) -> usize {
        self.model.tier.as_ref().map_or(0, |t| t.elements.len())
    }

    /// The compiler's notes on the tier's compile (training, sampling, its filter, advice).
    pub fn notes(&self) -> &[String] {
        &self.model.report.notes
    }
}

/// Refuses a tier whose scene is not the comparison's body: the inputs, the sensors and the
/// displayed node sets (names, sizes and rest positions) must agree, since the tier's read-outs
/// are compared node by node with the comparison scene's references.
pub(super) fn check_tier_matches(setup: &Setup, tier: &TierModel) -> Result<(), ComparisonError> {
    let model = &tier.model;
    let ops = &setup.full.operators;
    let fail = |what: String| ComparisonError::Invalid {
        path: tier.scene.clone(),
        what: format!(
            "the co-rotational tier's scene does not match {}: {what}",
            setup.scene_path.display()
        ),
    };
    let inputs: Vec<&str> = model.inputs.iter().map(|c| c.label.as_str()).collect();
    let expected: Vec<&str> = ops.inputs.iter().map(|c| c.label.as_str()).collect();
    if inputs != expected {
        return Err(fail(format!("inputs {inputs:?}, expected {expected:?}")));
    }
    let sensors: Vec<&str> = model.sensors.iter().map(|s| s.name.as_str()).collect();
    let expected: Vec<&str> = ops.sensors.iter().map(|s| s.name.as_str()).collect();
    if sensors != expected {
        return Err(fail(format!("sensors {sensors:?}, expected {expected:?}")));
    }
    if model.node_sets.len() != ops.node_sets.len() {
        return Err(fail(format!(
            "{} node sets, expected {}",
            model.node_sets.len(),
            ops.node_sets.len()
        )));
    }
    let positions = &setup.full.fem.positions;
    let scale = positions
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for (set, ours) in model.node_sets.iter().zip(&ops.node_sets) {
        if set.name != ours.name || set.node_tags.len() != ours.nodes.len() {
            return Err(fail(format!(
                "node set '{}' ({} nodes), expected '{}' ({} nodes)",
                set.name,
                set.node_tags.len(),
                ours.name,
                ours.nodes.len()
            )));
        }
        for (i, &node) in ours.nodes.iter().enumerate() {
            let rest = &set.rest_positions.data[3 * i..3 * i + 3];
            if (0..3).any(|c| (rest[c] - positions[node][c]).abs() > 1e-9 * scale) {
                return Err(fail(format!(
                    "node {i} of set '{}' rests at {rest:?}, expected {:?}",
                    set.name, positions[node]
                )));
            }
        }
    }
    Ok(())
}

/// The tier's row: open loop (the loads given), filtered with the loads given and withheld,
/// and the timed step, through the same [`run_runtime`], inputs and synthetic measurements as
/// the warped rows.
pub(super) fn run_tier(
    setup: &Setup,
    tier: &TierModel,
    corot: &ReferenceRun,
    linear: &ReferenceRun,
    options: &ComparisonOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<TierRow, ComparisonError> {
    let model = &tier.model;
    let r = tier.basis_order();
    let mut est = Estimator::new(model).map_err(|source| ComparisonError::Runtime {
        path: tier.scene.clone(),
        order: r,
        step: 0,
        source,
    })?;
    // As for the warped rows: the filter itself, not the outlier gate.
    est.set_innovation_gate(None);
    let force_states = est.state().len().saturating_sub(3 * r);
    let (given, inputs) = row_inputs(setup, model, options.withhold_loads)?;
    let none = vec![vec![None; model.measurements.len()]; setup.steps];
    let open = run_runtime(
        setup,
        &mut est,
        &given,
        &none,
        corot,
        Some(linear),
        None,
        "open loop tier",
        progress,
    )?;
    let measurements = synthetic_measurements(model, corot, setup.steps, options.seed);
    let filter = filtered_runs(
        setup,
        &mut est,
        model,
        &inputs,
        &measurements,
        corot,
        options,
        "tier",
        progress,
    )?;
    let times = time_row(
        &mut est,
        (&inputs, &measurements),
        (&given, &none),
        options.timing_samples,
        "timing tier",
        progress,
    );
    Ok(TierRow {
        scene: tier.scene.clone(),
        basis_order: r,
        sampled_elements: tier.sampled_elements(),
        force_states,
        compile_s: tier.compile_s,
        figures: RowFigures::new(
            RuntimeFigures::new(times, &open, &filter.given, &filter.withheld),
            filter,
        ),
        filters: model.tier.as_ref().map_or(1, |t| 1 + t.scheduled.len()),
        envelope: open.envelope,
    })
}
