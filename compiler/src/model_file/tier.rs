//! The model file's co-rotational tier section (docs/model-format.md), written and read back:
//! [`tier_section`] writes a compiled tier (basis rows at the sensors and displayed nodes, the
//! cubature's sampled elements, M_r, VᵀB, the training envelope, the filter and its gain
//! schedule); [`reduced_model_of_file`] and [`linearised_of_file`] read a file's tier back for a
//! scene (the reduced model, the linearised tier its filter is designed on), and [`refilter`]
//! redesigns a file's filter for another scene's sensors and noise without retraining.

use nalgebra::{DMatrix, DVector};

use crokf_formats as fmt;

use crate::fem::operators::InputKind;
use crate::full_order::FullOrder;
use crate::noise::{load_channel, NoiseModel, NoiseSpec};
use crate::nonlinear::cubature::{Cubature, SampledElement};
use crate::nonlinear::filter::{
    add_force_levels, derive_force_sigma, filter_of, measured_rows, scheduled_filters,
    LinearisedTier, TierFilter,
};
use crate::nonlinear::reduced::HyperReducedModel;
use crate::nonlinear::tier::{point_rows, Tier};
use crate::nonlinear::training::{History, TrainingPlan};
use crate::nonlinear::NonlinearError;
use crate::outputs::Measurements;

use super::kalman_gains;

/// How the runtime steps the tier (stored in the model file).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RuntimeNewton {
    /// Converged when ‖δq‖ ≤ tolerance ‖q̂‖.
    pub tolerance: f64,
    /// Most iterations per step.
    pub iterations: usize,
    /// Factor on the largest training ‖q‖ beyond which the state is outside the envelope.
    pub state_margin: f64,
}

/// The model file's tier section (docs/model-format.md): basis rows at the sensors and the
/// displayed nodes, the sampled elements, M_r, VᵀB, the envelope and the filter `schedule`
/// `filter` of [`linearised_filter`](crate::nonlinear::filter::linearised_filter).
pub fn tier_section(
    full: &FullOrder,
    tier: &Tier,
    plan: &TrainingPlan,
    filter: &TierFilter,
    measurements: &Measurements,
    newton: RuntimeNewton,
) -> fmt::CorotationalTier {
    let v = &tier.basis.vectors;
    let fem = &full.fem;
    let ops = &full.operators;
    let r = v.ncols();
    let input = DMatrix::from_fn(r, ops.inputs.len(), |i, j| {
        (0..v.nrows())
            .map(|d| v[(d, i)] * ops.inputs[j].column[d])
            .sum()
    });
    let sensor_rows = ops
        .sensors
        .iter()
        .map(|s| dense_matrix(&point_rows(full, v, &s.weights)))
        .collect();
    let node_set_rows = ops
        .node_sets
        .iter()
        .map(|set| {
            let mut m = DMatrix::zeros(3 * set.nodes.len(), r);
            for (i, &node) in set.nodes.iter().enumerate() {
                for c in 0..3 {
                    if let Some(d) = fem.dofs.index[node][c] {
                        for j in 0..r {
                            m[(3 * i + c, j)] = v[(d, j)];
                        }
                    }
                }
            }
            dense_matrix(&m)
        })
        .collect();
    let elements = tier
        .model
        .cubature
        .elements
        .iter()
        .map(|e| fmt::TierElement {
            element: e.element as u32,
            weight: e.weight,
            rest: e.rest,
            gradients: e.geometry.gradients,
            stiffness: fmt::Matrix::from_fn(12, 12, |i, j| e.stiffness[i][j]),
            rows: dense_matrix(&e.rows),
        })
        .collect();
    let env = &tier.training.envelope;
    let histories = plan
        .histories
        .iter()
        .map(|h| match *h {
            History::Ramp { multiple, time } => fmt::TrainingHistory {
                kind: "ramp".into(),
                multiple,
                time,
            },
            History::Step { multiple } => fmt::TrainingHistory {
                kind: "step".into(),
                multiple,
                time: 0.0,
            },
        })
        .collect();
    fmt::CorotationalTier {
        order: r as u32,
        mass: dense_matrix(&tier.model.mass),
        alpha: tier.model.alpha,
        beta: tier.model.beta,
        newton_tolerance: newton.tolerance,
        newton_iterations: newton.iterations as u32,
        input: dense_matrix(&input),
        sensor_rows,
        node_set_rows,
        elements,
        envelope: fmt::TrainingEnvelope {
            loads: plan
                .ranges
                .iter()
                .enumerate()
                .map(|(g, (name, range))| fmt::EnvelopeLoad {
                    name: name.clone(),
                    range: *range,
                    max_force: plan.max_force(g),
                })
                .collect(),
            directions: plan.directions.clone(),
            histories,
            duration: plan.duration,
            every: plan.every as u32,
            runs_completed: env.runs.0 as u32,
            runs_attempted: env.runs.1 as u32,
            snapshots: env.snapshots as u32,
            max_displacement: env.max_displacement,
            max_coordinate_norm: tier.max_coordinate_norm,
            state_margin: newton.state_margin,
        },
        force_loads: filter.force_loads.iter().map(|&g| g as u32).collect(),
        force_rates: filter.force_rates,
        kalman: kalman_gains(&filter.schedule, &filter.process_noise, measurements),
        scheduled: scheduled_section(filter, measurements),
        model_error: filter
            .model_error
            .as_ref()
            .map_or_else(fmt::Matrix::default, dense_matrix),
        force_levels: levels_section(filter, measurements),
        adaptation: adaptation_section(filter),
        // Set by the compile when the scene accepts a tier that failed its check.
        failed_check: None,
    }
}

/// The section's `force_levels` of a filter (docs/design.md §11.10).
fn levels_section(filter: &TierFilter, measurements: &Measurements) -> Vec<fmt::ForceLevel> {
    filter
        .levels
        .iter()
        .map(|l| fmt::ForceLevel {
            factor: l.factor,
            kalman: kalman_gains(&l.schedule, &l.process_noise, measurements),
            scheduled: l
                .scheduled
                .iter()
                .map(|(schedule, q)| kalman_gains(schedule, q, measurements))
                .collect(),
        })
        .collect()
}

/// The section's `adaptation` of a filter (present exactly with levels).
fn adaptation_section(filter: &TierFilter) -> Option<fmt::ForceAdaptation> {
    let a = filter.adaptation.as_ref()?;
    (!filter.levels.is_empty()).then(|| fmt::ForceAdaptation {
        smoothing: a.smoothing.clone(),
        raise_above: a.raise_above,
        lower_below: a.lower_below,
        hold: a.window as u32,
    })
}

/// The section's `scheduled` of a filter.
fn scheduled_section(
    filter: &TierFilter,
    measurements: &Measurements,
) -> Vec<fmt::ScheduledFilter> {
    filter
        .scheduled
        .iter()
        .map(|(q, schedule, process_noise)| fmt::ScheduledFilter {
            point: q.iter().copied().collect(),
            kalman: kalman_gains(schedule, process_noise, measurements),
        })
        .collect()
}

/// A dense matrix as the model file's row-major matrix.
fn dense_matrix(m: &DMatrix<f64>) -> fmt::Matrix {
    fmt::Matrix::from_fn(m.nrows() as u32, m.ncols() as u32, |i, j| m[(i, j)])
}

/// The [`LinearisedTier`] of a model file's tier at rest for the scene `full` (same mesh and
/// loads; the scene gives the sensors' noise and rates) with the noise `spec` (the scene's own
/// is `full.noise`), and the scene's [`Measurements`]: K_r at rest = Σ wₑ V_eᵀ Kₑ V_e over the
/// sampled elements, M_r, VᵀB and the sensor rows from the file, the noise model of `spec`
/// with its derived σ fixed on this linearisation ([`derive_force_sigma`], as the compile
/// did). The scene's distributed force noise is not in the file (no VᵀB_w): refused.
pub fn linearised_of_file(
    full: &FullOrder,
    model: &fmt::Model,
    spec: &NoiseSpec,
) -> Result<(LinearisedTier, Measurements, NoiseModel), NonlinearError> {
    let mut noise = NoiseModel::new(spec, &full.operators, full.wilson.dt)?;
    let (mut lin, measurements) = linearised_of_file_with(full, model, &noise)?;
    derive_force_sigma(&lin, &mut noise, &measurements)?;
    lin.force_sigma = noise.force_sigma();
    Ok((lin, measurements, noise))
}

/// [`linearised_of_file`] with the noise model `noise` (e.g. `FullOrder::noise_model`).
pub fn linearised_of_file_with(
    full: &FullOrder,
    model: &fmt::Model,
    noise: &NoiseModel,
) -> Result<(LinearisedTier, Measurements), NonlinearError> {
    let measurements = Measurements::new(&full.operators);
    let inputs = &full.operators.inputs;
    if model.inputs.len() != inputs.len()
        || model.measurements.len() != measurements.channels.len()
        || (model.dt - full.wilson.dt).abs() > 1e-15 * full.wilson.dt
    {
        return Err(NonlinearError::Invalid(
            "refilter: the scene's inputs, measurements or Δt differ from the model's".into(),
        ));
    }
    let Some(t) = model.tier.as_ref() else {
        return Err(NonlinearError::Invalid(
            "refilter: the model has no tier".into(),
        ));
    };
    let r = t.order as usize;
    let mut stiffness = DMatrix::<f64>::zeros(r, r);
    for e in &t.elements {
        let rows = file_matrix(&e.rows);
        stiffness += e.weight * rows.transpose() * file_matrix(&e.stiffness) * &rows;
    }
    let input = file_matrix(&t.input);
    let mut noise_columns = Vec::with_capacity(noise.white.len());
    for &j in &noise.white {
        // A load's white noise channel is σ times its load channel (fem::operators), whose VᵀB
        // the file holds; distributed noise is not in the file.
        let ch = &full.operators.noise[j];
        let column = match ch.kind {
            InputKind::Noise { load: Some(g) } => (0..3)
                .find(|&c| ch.label.ends_with(["x", "y", "z"][c]))
                .and_then(|c| load_channel(&full.operators, g, c))
                .map(|k| {
                    DVector::from(input.column(k)) * full.scene.scene.loads[g].force_noise_std
                }),
            _ => None,
        };
        noise_columns.push(column.ok_or_else(|| {
            NonlinearError::Invalid(format!(
                "refilter: noise channel '{}' is not in the model file: recompile",
                ch.label
            ))
        })?);
    }
    let lin = LinearisedTier {
        mass: file_matrix(&t.mass),
        stiffness,
        alpha: t.alpha,
        beta: t.beta,
        wilson: full.wilson,
        force_columns: noise
            .force_channels()
            .iter()
            .map(|&ch| input.column(ch).into())
            .collect(),
        force_sigma: noise.force_sigma(),
        rate_sigma: noise.rate_sigma(),
        noise_columns,
        measured_rows: measured_rows(&measurements, |s| file_matrix(&t.sensor_rows[s])),
        model_error: (t.model_error.rows > 0).then(|| file_matrix(&t.model_error)),
        model_error_scale: noise.model_error_scale,
    };
    Ok((lin, measurements))
}

/// A model file's matrix as a DMatrix.
pub fn file_matrix(m: &fmt::Matrix) -> DMatrix<f64> {
    DMatrix::from_fn(m.rows as usize, m.cols as usize, |i, j| {
        m.data[i * m.cols as usize + j]
    })
}

/// The reduced co-rotational model of a model file's tier on the scene's mesh `full` (the
/// sampled elements' rest geometry, Kₑ, weights and basis rows from the file, their shape
/// gradients from the mesh): what the compiler's [`HyperReducedModel`] was when the file was written,
/// for the consistent tangent K_N,r(q) of [`LinearisedTier::at`].
pub fn reduced_model_of_file(
    full: &FullOrder,
    t: &fmt::CorotationalTier,
) -> Result<HyperReducedModel, NonlinearError> {
    let fem = &full.fem;
    let mut elements = Vec::with_capacity(t.elements.len());
    for e in &t.elements {
        let index = e.element as usize;
        let Some(el) = fem.elements.get(index) else {
            return Err(NonlinearError::Invalid(format!(
                "tier element {index} is not in the scene's mesh ({} elements)",
                fem.elements.len()
            )));
        };
        let rows = file_matrix(&e.rows);
        let flat = e.rows.data.clone();
        elements.push(SampledElement {
            element: index,
            weight: e.weight,
            geometry: el.geometry,
            stiffness: std::array::from_fn(|i| {
                std::array::from_fn(|j| e.stiffness.data[12 * i + j])
            }),
            rest: e.rest,
            flat_t: crokf_kernel::transpose_rows(&flat),
            flat,
            rows,
        });
    }
    Ok(HyperReducedModel {
        cubature: Cubature { elements },
        mass: file_matrix(&t.mass),
        alpha: t.alpha,
        beta: t.beta,
        wilson: full.wilson,
    })
}

/// Recomputes the tier filter of a model file for the scene `full` (same mesh, loads and
/// training; other sensors' noise or rates) with the noise `spec` (force σ, model-error
/// factor; the scene's own is `full.noise`): the [`LinearisedTier`] is read from the file's
/// tier section (M_r, K_r at rest = Σ wₑ V_eᵀ Kₑ V_e over the sampled elements, VᵀB, the
/// sensor rows), and the section's `force_loads` and `kalman` are replaced. The scene's
/// distributed force noise is not in the file (no VᵀB_w): refused. Returns the new filter's
/// closed-loop spectral radius.
pub fn refilter(
    full: &FullOrder,
    model: &mut fmt::Model,
    spec: &NoiseSpec,
) -> Result<f64, NonlinearError> {
    let (lin, measurements, noise) = linearised_of_file(full, model, spec)?;
    let Some(t) = model.tier.as_mut() else {
        return Err(NonlinearError::Invalid(
            "refilter: the model has no tier".into(),
        ));
    };
    let mut filter = filter_of(&lin, &measurements)?;
    filter.force_loads = noise.force_loads();
    let points: Vec<DVector<f64>> = t
        .scheduled
        .iter()
        .map(|s| DVector::from_column_slice(&s.point))
        .collect();
    let reduced = reduced_model_of_file(full, t)?;
    if !points.is_empty() {
        filter.scheduled = scheduled_filters(&lin, &reduced, &points, &measurements);
    }
    add_force_levels(&mut filter, &lin, &reduced, &noise, &measurements);
    t.force_loads = filter.force_loads.iter().map(|&g| g as u32).collect();
    t.force_rates = filter.force_rates;
    t.kalman = kalman_gains(&filter.schedule, &filter.process_noise, &measurements);
    t.scheduled = scheduled_section(&filter, &measurements);
    t.force_levels = levels_section(&filter, &measurements);
    t.adaptation = adaptation_section(&filter);
    Ok(filter.schedule.closed_loop_spectral_radius)
}
