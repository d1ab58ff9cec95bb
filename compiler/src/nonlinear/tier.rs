//! The co-rotational tier assembled from training (docs/design.md §10): training → POD basis →
//! ECSW sampling → reduced model ([`from_training`], [`build`]); its constant-gain filter from
//! the DARE of the model linearised at rest ([`linearised_filter`]); and the model file's tier
//! section ([`tier_section`], docs/model-format.md).

use faer::Mat;
use nalgebra::{DMatrix, DVector};

use crokf_formats as fmt;

use crate::full_order::FullOrder;
use crate::kalman::{self, PeriodicSchedule};
use crate::outputs::Measurements;

use super::basis::{self, Basis};
use super::ecsw::{self, EcswOptions, NnlsSolution};
use super::reduced::ReducedModel;
use super::training::{self, History, Training, TrainingPlan};
use super::NonlinearError;

/// A built co-rotational tier.
#[derive(Clone, Debug)]
pub struct Tier {
    /// The basis V (n × r, M-orthonormal): POD of the training snapshots, each column's
    /// largest-magnitude entry positive (deterministic signs).
    pub basis: Basis,
    /// POD eigenvalues of the training snapshots (m²·kg), descending.
    pub pod_values: Vec<f64>,
    /// ECSW sampling.
    pub sampling: NnlsSolution,
    /// The reduced model.
    pub model: ReducedModel,
    /// Training runs and envelope (snapshots kept).
    pub training: Training,
    /// Largest ‖q‖ = ‖VᵀM u‖ over the training snapshots.
    pub max_coordinate_norm: f64,
    /// Wall time of the POD and of the ECSW, s.
    pub seconds: [f64; 2],
}

/// Builds the tier from training snapshots: the first `order` POD vectors of the snapshots in
/// the M inner product, ECSW on the snapshots with `ecsw`.
pub fn from_training(
    full: &FullOrder,
    training: Training,
    order: usize,
    ecsw_options: &EcswOptions,
) -> Result<Tier, NonlinearError> {
    if training.snapshots.is_empty() {
        return Err(NonlinearError::Invalid(
            "no training snapshot: every training run failed".into(),
        ));
    }
    let clock = std::time::Instant::now();
    let (mut modes, pod_values) = basis::pod(&full.fem.mass, &training.snapshots, order, 1e-14);
    for (_, v) in &mut modes {
        let top = v
            .iter()
            .copied()
            .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        if top < 0.0 {
            v.iter_mut().for_each(|x| *x = -*x);
        }
    }
    let basis = basis::m_orthonormalise(&full.fem.mass, &modes, 1e-8, order);
    let t_pod = clock.elapsed().as_secs_f64();
    let clock = std::time::Instant::now();
    let sampling = ecsw::sample_elements(
        &full.fem,
        &basis.vectors,
        &basis.mass_vectors,
        &training.snapshots,
        ecsw_options,
    )?;
    let t_ecsw = clock.elapsed().as_secs_f64();
    let model = ReducedModel::new(&full.fem, &basis.vectors, &sampling.weights, full.wilson)?;
    let max_coordinate_norm = training
        .snapshots
        .iter()
        .map(|u| basis.project(u).norm())
        .fold(0.0, f64::max);
    Ok(Tier {
        basis,
        pod_values,
        sampling,
        model,
        training,
        max_coordinate_norm,
        seconds: [t_pod, t_ecsw],
    })
}

/// Trains on `plan` (full-order co-rotational runs) and builds the tier.
pub fn build(
    full: &FullOrder,
    plan: &TrainingPlan,
    order: usize,
    ecsw_options: &EcswOptions,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Tier, NonlinearError> {
    let training = training::train(full, plan, progress)?;
    from_training(full, training, order, ecsw_options)
}

/// Rows of V (3 × r) at a point with barycentric node weights (world-frame displacement, m).
pub fn point_rows(full: &FullOrder, v: &DMatrix<f64>, weights: &[(usize, f64)]) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(3, v.ncols());
    for &(node, w) in weights {
        for c in 0..3 {
            if let Some(d) = full.fem.dofs.index[node][c] {
                for j in 0..v.ncols() {
                    out[(c, j)] += w * v[(d, j)];
                }
            }
        }
    }
    out
}

/// The tier's filter: the reduced model linearised at rest (K_r = reduced consistent tangent
/// at q = 0, C_r = αM_r + βK_r), stepped by the same Wilson-θ recursion on s = (q, q̇, q̈)
/// (3r), process noise from the scene's noise channels projected on V (VᵀB_w), measurement
/// map y = H V q; the periodic steady-state gains of `kalman::periodic_gains`.
///
/// Route: mass-normalised modes of (K_r, M_r) (Φ, λ) decouple the recursion into 3×3 blocks
/// ([`crate::dynamics::WilsonTheta::modal_block`]); the DARE is solved in modal coordinates
/// and mapped back with T = diag(Φ, Φ, Φ).
pub fn linearised_filter(
    full: &FullOrder,
    tier: &Tier,
    measurements: &Measurements,
) -> Result<TierFilter, NonlinearError> {
    let model = &tier.model;
    let r = model.order();
    let v = &tier.basis.vectors;
    let k = model.tangent(&DVector::zeros(r), 0.0, true);
    let m = &model.mass;
    let chol = m.clone().cholesky().ok_or_else(|| {
        NonlinearError::Invalid("tier filter: reduced mass matrix is not positive definite".into())
    })?;
    let l = chol.l();
    let l_inv = l.clone().try_inverse().ok_or_else(|| {
        NonlinearError::Invalid("tier filter: reduced mass matrix is singular".into())
    })?;
    let kt = &l_inv * &k * l_inv.transpose();
    let kt = (&kt + kt.transpose()) * 0.5;
    let eig = kt.symmetric_eigen();
    let mut order: Vec<usize> = (0..r).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // Φ = L⁻ᵀ Φ̃ (ΦᵀMΦ = I), columns in ascending λ.
    let phi_t = DMatrix::from_fn(r, r, |i, j| eig.eigenvectors[(i, order[j])]);
    let phi = l_inv.transpose() * phi_t;
    let lambda: Vec<f64> = order.iter().map(|&j| eig.eigenvalues[j]).collect();
    if let Some(bad) = lambda.iter().find(|&&x| !(x.is_finite() && x > 0.0)) {
        return Err(NonlinearError::Invalid(format!(
            "tier filter: the reduced stiffness at rest is not positive definite (eigenvalue {bad:e})"
        )));
    }
    let w = full.wilson;
    let n3 = 3 * r;
    let mut f = Mat::<f64>::zeros(n3, n3);
    let mut gamma = vec![[0.0; 3]; r];
    for i in 0..r {
        let (a, g) = w.modal_block(lambda[i], model.alpha + model.beta * lambda[i]);
        for k1 in 0..3 {
            for k2 in 0..3 {
                f[(k1 * r + i, k2 * r + i)] = a[k1][k2];
            }
        }
        gamma[i] = g;
    }
    // Noise: modal load Φᵀ Vᵀ b_w per channel.
    let noise = &full.operators.noise;
    let mut gw = Mat::<f64>::zeros(n3, noise.len());
    for (c, ch) in noise.iter().enumerate() {
        let reduced = v.tr_mul(&DVector::from_column_slice(&ch.column));
        let modal = phi.tr_mul(&reduced);
        for i in 0..r {
            for k1 in 0..3 {
                gw[(k1 * r + i, c)] = gamma[i][k1] * modal[i];
            }
        }
    }
    let q = &gw * gw.transpose();
    let ops = &full.operators;
    let channels = &measurements.channels;
    let mut h = Mat::<f64>::zeros(channels.len(), n3);
    for (row, &(s, c)) in channels.iter().enumerate() {
        let rows = point_rows(full, v, &ops.sensors[s].weights) * &phi;
        for i in 0..r {
            h[(row, i)] = rows[(c, i)];
        }
    }
    let schedule = kalman::periodic_gains(
        f.as_ref(),
        h.as_ref(),
        q.as_ref(),
        &measurements.variance,
        &measurements.every,
    )
    .map_err(|e| NonlinearError::Invalid(format!("tier filter: {e}")))?;
    // Back to s = (q, q̇, q̈): x_s = T x_m, T = diag(Φ, Φ, Φ).
    let mut t = Mat::<f64>::zeros(n3, n3);
    for blk in 0..3 {
        for i in 0..r {
            for j in 0..r {
                t[(blk * r + i, blk * r + j)] = phi[(i, j)];
            }
        }
    }
    let back = |p: &Mat<f64>| &t * p * t.transpose();
    let mut schedule = schedule;
    for phase in &mut schedule.phases {
        phase.gain = &t * &phase.gain;
        phase.prior_covariance = back(&phase.prior_covariance);
        phase.posterior_covariance = back(&phase.posterior_covariance);
    }
    Ok(TierFilter {
        process_noise: back(&q),
        schedule,
    })
}

/// The tier's constant-gain filter in s = (q, q̇, q̈) coordinates.
#[derive(Clone, Debug)]
pub struct TierFilter {
    /// Periodic steady-state gains (3r × measured) and covariances (3r × 3r).
    pub schedule: PeriodicSchedule,
    /// Q_s, 3r × 3r: process noise per step of the linearised model.
    pub process_noise: Mat<f64>,
}

fn to_matrix(m: &DMatrix<f64>) -> fmt::Matrix {
    fmt::Matrix::from_fn(m.nrows() as u32, m.ncols() as u32, |i, j| m[(i, j)])
}

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
/// `filter` of [`linearised_filter`].
pub fn tier_section(
    full: &FullOrder,
    tier: &Tier,
    plan: &TrainingPlan,
    filter: &TierFilter,
    measurements: &Measurements,
    newton: RuntimeNewton,
) -> fmt::CorotationalTier {
    let schedule = &filter.schedule;
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
        .map(|s| to_matrix(&point_rows(full, v, &s.weights)))
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
            to_matrix(&m)
        })
        .collect();
    let elements = tier
        .model
        .elements
        .iter()
        .map(|e| fmt::TierElement {
            element: e.element as u32,
            weight: e.weight,
            rest: e.rest,
            gradients: e.geometry.gradients,
            stiffness: fmt::Matrix::from_fn(12, 12, |i, j| e.stiffness[i][j]),
            rows: to_matrix(&e.rows),
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
    let phases = schedule
        .phases
        .iter()
        .map(|p| fmt::KalmanPhase {
            measured: p.measured.iter().map(|&i| i as u32).collect(),
            gain: crate::model_file::to_matrix(p.gain.as_ref()),
            prior_covariance: crate::model_file::to_matrix(p.prior_covariance.as_ref()),
            posterior_covariance: crate::model_file::to_matrix(p.posterior_covariance.as_ref()),
        })
        .collect();
    fmt::CorotationalTier {
        order: r as u32,
        mass: to_matrix(&tier.model.mass),
        alpha: tier.model.alpha,
        beta: tier.model.beta,
        newton_tolerance: newton.tolerance,
        newton_iterations: newton.iterations as u32,
        input: to_matrix(&input),
        sensor_rows,
        node_set_rows,
        elements,
        envelope: fmt::TrainingEnvelope {
            loads: plan
                .ranges
                .iter()
                .map(|(name, range)| fmt::EnvelopeLoad {
                    name: name.clone(),
                    range: *range,
                    max_force: range * plan.max_multiple(),
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
        kalman: fmt::KalmanGains {
            period: schedule.period as u32,
            phases,
            process_noise: crate::model_file::to_matrix(filter.process_noise.as_ref()),
            measurement_variance: measurements.variance.clone(),
        },
    }
}
