//! The co-rotational tier's filter design (docs/design.md §11.4–11.5): the reduced model
//! linearised at rest and at training states ([`LinearisedTier`], [`LinearisedTier::at`]),
//! augmented with the force (and rate) states of the noise model ([`crate::noise`]), its DARE
//! solved in scaled modal coordinates ([`filter_of`]), the gain schedule's operating points
//! ([`schedule_points`]) and the checks measured on every compile (static residual of the force
//! channels, the basis's model error at the markers): [`linearised_filter`].

use faer::Mat;
use nalgebra::{DMatrix, DVector};

use crate::algorithms::kalman::{self, PeriodicSchedule};
use crate::full_order::FullOrder;
use crate::observability::{measured_value, static_marker_response};
use crate::outputs::Measurements;

use super::levels::{design_levels, FilterLevel};
use super::reduced::HyperReducedModel;
use super::tier::{point_rows, Tier};
use super::NonlinearError;
use crate::algorithms::kalman::adaptation::Statistic;
use crate::noise::{Derivation, NoiseModel};

/// The tier linearised at rest in reduced coordinates: everything its filter needs, which is
/// also what the model file's tier section stores (so a filter can be recomputed from a model
/// file for other sensors' noise or rates without retraining, [`refilter`](crate::model_file::tier::refilter)).
#[derive(Clone, Debug)]
pub struct LinearisedTier {
    /// M_r (r × r, kg per q²).
    pub mass: DMatrix<f64>,
    /// K_r at rest (r × r): Σ wₑ V_eᵀ Kₑ V_e, N/m per q².
    pub stiffness: DMatrix<f64>,
    /// Rayleigh α (1/s) and β (s).
    pub alpha: f64,
    /// Rayleigh β, s.
    pub beta: f64,
    /// Δt and θ.
    pub wilson: crate::dynamics::WilsonTheta,
    /// VᵀB of each force state's input channel (r each; 3 per random-walk group).
    pub force_columns: Vec<DVector<f64>>,
    /// σ per force state, N per step.
    pub force_sigma: Vec<f64>,
    /// σ of each force state's rate random walk, N/s per step (docs/design.md §11.5); empty:
    /// no rate states.
    pub rate_sigma: Vec<f64>,
    /// VᵀB_w of each white process-noise channel (r each; σ included).
    pub noise_columns: Vec<DVector<f64>>,
    /// H V: the measured channels' rows of V (channels × r).
    pub measured_rows: DMatrix<f64>,
    /// The reduced model's measured error inside the basis, a covariance S (r × r, q²;
    /// [`super::self_check::SelfCheck::model_error_covariance`]), taken as process noise
    /// ([`model_error_noise`], docs/design.md §11.9); None: no such noise.
    pub model_error: Option<DMatrix<f64>>,
    /// The factor on `model_error` ([`NoiseModel::model_error_scale`]): the filter's
    /// model-error covariance is S × this factor.
    pub model_error_scale: f64,
}

impl LinearisedTier {
    /// The same tier linearised at q (r) instead of rest: K_r ← K_N,r(q), the consistent
    /// reduced tangent of `model` (docs/design.md §11.5).
    pub fn at(&self, model: &HyperReducedModel, q: &DVector<f64>) -> LinearisedTier {
        LinearisedTier {
            stiffness: model.tangent(q, 0.0, true),
            ..self.clone()
        }
    }

    /// The linearised step in s = (q, q̇, q̈, f) coordinates (n = 3r + force states):
    /// s_{k+1} = F s_k (+ inputs), F = [[A, Γ_f], [0, I]], and the measured rows
    /// H = [H V, 0, 0, 0] (channels × n). A is the Wilson-θ recursion of
    /// M q̈ + (αM + βK) q̇ + K q = f_r with f_r held over the step (module docs of
    /// `crokf_runtime::tier`): q̂ = J⁻¹ (M(a₀q + (6/τ)q̇ + 2q̈) + C(a₂q + 2q̇ + (τ/2)q̈) + f_r),
    /// J = K + a₂C + a₀M, then [`crate::dynamics::WilsonTheta::advance`] per coordinate.
    pub fn transition(&self) -> Result<(DMatrix<f64>, DMatrix<f64>), NonlinearError> {
        let r = self.mass.nrows();
        let nf = self.force_columns.len();
        let nr = self.rate_sigma.len();
        let n = 3 * r + nf + nr;
        let w = self.wilson;
        let (tau, a0, a2) = (w.tau(), w.mass_coefficient(), w.damping_coefficient());
        let m = &self.mass;
        let c = m * self.alpha + &self.stiffness * self.beta;
        let j = &self.stiffness + &c * a2 + m * a0;
        let chol = j.cholesky().ok_or_else(|| {
            NonlinearError::Invalid("tier transition: J is not positive definite".into())
        })?;
        // q̂ = G s, G = J⁻¹ [M a₀ + C a₂, M 6/τ + 2C, 2M + C τ/2, VᵀB_f].
        let mut rhs = DMatrix::zeros(r, n);
        rhs.view_mut((0, 0), (r, r)).copy_from(&(m * a0 + &c * a2));
        rhs.view_mut((0, r), (r, r))
            .copy_from(&(m * w.velocity_coefficient() + &c * 2.0));
        rhs.view_mut((0, 2 * r), (r, r))
            .copy_from(&(m * 2.0 + &c * (0.5 * tau)));
        for (k, col) in self.force_columns.iter().enumerate() {
            rhs.column_mut(3 * r + k).copy_from(col);
        }
        let g = chol.solve(&rhs);
        // advance(u, v, a, û) is linear: its coefficients from unit arguments.
        let unit = |k: usize| {
            let mut x = [0.0; 4];
            x[k] = 1.0;
            crokf_kernel::wilson::advance(w.dt, w.theta, x[0], x[1], x[2], x[3])
        };
        let coeff: Vec<(f64, f64, f64)> = (0..4).map(unit).collect();
        let mut f = DMatrix::zeros(n, n);
        for blk in 0..3 {
            let pick = |t: (f64, f64, f64)| [t.0, t.1, t.2][blk];
            for i in 0..r {
                for src in 0..3 {
                    f[(blk * r + i, src * r + i)] += pick(coeff[src]);
                }
                for col in 0..n {
                    f[(blk * r + i, col)] += pick(coeff[3]) * g[(i, col)];
                }
            }
        }
        for k in 0..nf {
            f[(3 * r + k, 3 * r + k)] = 1.0;
        }
        for k in 0..nr {
            f[(3 * r + k, 3 * r + nf + k)] = w.dt;
            f[(3 * r + nf + k, 3 * r + nf + k)] = 1.0;
        }
        let mut h = DMatrix::zeros(self.measured_rows.nrows(), n);
        h.view_mut((0, 0), (self.measured_rows.nrows(), r))
            .copy_from(&self.measured_rows);
        Ok((f, h))
    }
}

/// The tier's filter in s = (q, q̇, q̈, f[, ḟ]) coordinates: the one designed at rest and its
/// gain schedule.
#[derive(Clone, Debug)]
pub struct TierFilter {
    /// Periodic steady-state gains (n × measured) and covariances (n × n), n = 3r + 3 per
    /// random-walk load group.
    pub schedule: PeriodicSchedule,
    /// Q_s, n × n: process noise per step of the linearised model.
    pub process_noise: Mat<f64>,
    /// The random-walk load groups (indices into the scene's loads) whose force states follow
    /// the 3r kinematic states, 3 each.
    pub force_loads: Vec<usize>,
    /// Whether the force states' rates follow them (3 more per group, docs/design.md §11.5).
    pub force_rates: bool,
    /// Worst relative static residual of the measured response to a force channel
    /// (`static_residual`; 0 without force states).
    pub static_residual: f64,
    /// The basis's error at the markers over the training snapshots, per measurement channel:
    /// RMS of H(u − V VᵀM u) divided by the channel's σ ([`marker_model_error`]).
    pub marker_model_error: Vec<f64>,
    /// The gain schedule (docs/design.md §11.5): per operating point q* (r), the same filter
    /// on the tier linearised at q* ([`LinearisedTier::at`]) with its process noise (the
    /// model-error term is per mode of that linearisation); `schedule` is the point q = 0.
    pub scheduled: Vec<(DVector<f64>, PeriodicSchedule, Mat<f64>)>,
    /// The model error taken as process noise ([`LinearisedTier::model_error`]).
    pub model_error: Option<DMatrix<f64>>,
    /// The force-σ levels besides the designed one ([`super::levels`], docs/design.md
    /// §11.10); empty without force states.
    pub levels: Vec<FilterLevel>,
    /// The statistic that moves between the levels (present exactly with levels).
    pub adaptation: Option<Statistic>,
    /// Levels left out (their filter could not be designed), for the compile's notes.
    pub level_notes: Vec<String>,
}

/// The tier's filter (docs/design.md §11.4) for the noise model `noise`: the reduced model
/// linearised at rest
/// (K_r = reduced consistent tangent at q = 0, C_r = αM_r + βK_r), stepped by the same Wilson-θ
/// recursion on s = (q, q̇, q̈) (3r), augmented with 3 random-walk force states f per
/// random-walk load group (world force, N; f_{k+1} = f_k + w, w ~ N(0, σ² I₃), σ the load's
/// `force_noise_std`), which enter the step as a load f_r = VᵀB f (the group's nodal
/// distribution, held over the step like an input):
/// ```text
/// s_{k+1} = A s_k + Γ Vᵀ(B u_k + B_f f_k) + Γ Vᵀ B_w w_k,   f_{k+1} = f_k + w_f,k
/// y_k = H V q_k + v_k
/// ```
/// Process noise: the scene's white noise channels projected on V (VᵀB_w), except those of the
/// random-walk groups, which the force increments replace (as on the warped tier,
/// `crate::reduced::ReducedModel::with_force_states`). The force states have no output columns: the static
/// response of the linearised tier to each force channel, H V K_r⁻¹ Vᵀ b, is compared with the
/// full-order H K⁻¹ b and the worst relative residual returned (`static_residual`), so that
/// the choice is measured on every compile.
///
/// With force rates (a load's `force_rate_noise_std` σ_ḟ > 0, docs/design.md §11.5) each force
/// state also has its rate: f_{k+1} = f_k + Δt ḟ_k + w_f,k, ḟ_{k+1} = ḟ_k + w_ḟ,k,
/// w_ḟ ~ N(0, σ_ḟ² I₃) (N/s). Gain schedule (§11.5): the same filter is also designed on the
/// tier linearised at up to [`SCHEDULE_POINTS`] training states ([`schedule_points`],
/// [`LinearisedTier::at`]), returned in `scheduled`.
pub fn linearised_filter(
    full: &FullOrder,
    tier: &Tier,
    noise: &NoiseModel,
    measurements: &Measurements,
    model_error: Option<DMatrix<f64>>,
) -> Result<TierFilter, NonlinearError> {
    let lin = LinearisedTier {
        model_error,
        ..linearise_at_rest(full, tier, noise, measurements)
    };
    let channels = noise.force_channels();
    let residual = static_residual(
        full,
        &tier.basis.vectors,
        &lin.stiffness,
        &lin.measured_rows,
        &channels,
        measurements,
    )?;
    let mut filter = filter_of(&lin, measurements)?;
    filter.force_loads = noise.force_loads();
    filter.static_residual = residual;
    filter.marker_model_error = marker_model_error(full, tier, &lin.measured_rows, measurements);
    let points = schedule_points(&tier.projected, SCHEDULE_POINTS);
    filter.scheduled = scheduled_filters(&lin, &tier.model, &points, measurements);
    add_force_levels(&mut filter, &lin, &tier.model, noise, measurements);
    Ok(filter)
}

/// Designs the force-σ levels of `filter` (designed on `lin`, its schedule's points
/// re-linearised on `model`) and their statistic ([`super::levels`], docs/design.md §11.10):
/// the same filters with every force (and rate) σ of `lin` × each factor; nothing without
/// force states.
pub fn add_force_levels(
    filter: &mut TierFilter,
    lin: &LinearisedTier,
    model: &HyperReducedModel,
    noise: &NoiseModel,
    measurements: &Measurements,
) {
    let rise_time = noise
        .shortest_rise_time()
        .filter(|_| !lin.force_sigma.is_empty());
    let design = |factor: f64| -> Result<FilterLevel, NonlinearError> {
        let scaled = LinearisedTier {
            force_sigma: lin.force_sigma.iter().map(|s| s * factor).collect(),
            rate_sigma: lin.rate_sigma.iter().map(|s| s * factor).collect(),
            ..lin.clone()
        };
        let rest = filter_of(&scaled, measurements)?;
        let scheduled = filter
            .scheduled
            .iter()
            .map(|(q, _, _)| {
                filter_of(&scaled.at(model, q), measurements).map(|f| (f.schedule, f.process_noise))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(FilterLevel {
            factor,
            schedule: rest.schedule,
            process_noise: rest.process_noise,
            scheduled,
        })
    };
    let designed: Vec<&PeriodicSchedule> = std::iter::once(&filter.schedule)
        .chain(filter.scheduled.iter().map(|(_, s, _)| s))
        .collect();
    let (levels, adaptation, notes) = design_levels(
        design,
        &designed,
        &lin.measured_rows,
        measurements,
        rise_time,
        lin.wilson.dt,
    );
    (filter.levels, filter.adaptation, filter.level_notes) = (levels, adaptation, notes);
}

/// The tier linearised at rest with the noise model `noise` (see [`linearised_filter`]).
pub fn linearise_at_rest(
    full: &FullOrder,
    tier: &Tier,
    noise: &NoiseModel,
    measurements: &Measurements,
) -> LinearisedTier {
    let model = &tier.model;
    let r = model.order();
    let v = &tier.basis.vectors;
    let project = |column: &[f64]| v.tr_mul(&DVector::from_column_slice(column));
    let ops = &full.operators;
    LinearisedTier {
        mass: model.mass.clone(),
        stiffness: model.tangent(&DVector::zeros(r), 0.0, true),
        alpha: model.alpha,
        beta: model.beta,
        wilson: full.wilson,
        force_columns: noise
            .force_channels()
            .iter()
            .map(|&ch| project(&ops.inputs[ch].column))
            .collect(),
        force_sigma: noise.force_sigma(),
        rate_sigma: noise.rate_sigma(),
        noise_columns: noise
            .white
            .iter()
            .map(|&j| project(&ops.noise[j].column))
            .collect(),
        measured_rows: measured_rows(measurements, |s| {
            point_rows(full, v, &ops.sensors[s].weights)
        }),
        model_error: None,
        model_error_scale: noise.model_error_scale,
    }
}

/// Fixes the derived force σ of `noise` on the tier linearised at rest `lin` (docs/design.md
/// §11.8): per derived group, the smallest σ whose filter's steady lag on the stated ramp stays
/// within one σ of its force states ([`crate::algorithms::kalman::lag::ramp_lag`], group k's force block
/// 3r + 3k … 3r + 3k + 2). The derivation's filter has no rate states (with rates a ramp has no
/// steady lag); `lin`'s own σ are not used. Returns what was derived (empty when every σ is
/// stated).
pub fn derive_force_sigma(
    lin: &LinearisedTier,
    noise: &mut NoiseModel,
    measurements: &Measurements,
) -> Result<Vec<Derivation>, NonlinearError> {
    let r = lin.mass.nrows();
    noise.derive(lin.wilson.dt, |trial, k, delta| {
        let trial = LinearisedTier {
            force_sigma: trial.force_sigma(),
            rate_sigma: Vec::new(),
            ..lin.clone()
        };
        let filter = filter_of(&trial, measurements)?;
        let (f, h) = trial.transition()?;
        let f = Mat::<f64>::from_fn(f.nrows(), f.ncols(), |i, j| f[(i, j)]);
        let h = Mat::<f64>::from_fn(h.nrows(), h.ncols(), |i, j| h[(i, j)]);
        let block = 3 * r + 3 * k..3 * r + 3 * k + 3;
        kalman::lag::ramp_lag(f.as_ref(), h.as_ref(), &filter.schedule, block, delta)
            .map_err(|e| NonlinearError::Invalid(format!("force σ derivation: {e}")))
    })
}

/// The model error of the tier at the markers that its basis alone makes (docs/design.md
/// §11.5, a check of the noise model against the training runs): per measurement channel j,
/// sqrt(mean over the training snapshots u of (h_j (u − V q))²) / σ_j, q = VᵀM u the snapshot's
/// projection (`tier.projected`), h_j the channel's row of the sensor interpolation (h_j V the
/// row j of `measured_rows`), σ_j its noise.
/// Small against 1: the markers' noise, not the basis, dominates their error budget.
pub fn marker_model_error(
    full: &FullOrder,
    tier: &Tier,
    measured_rows: &DMatrix<f64>,
    measurements: &Measurements,
) -> Vec<f64> {
    let count = tier.training.snapshots.len().max(1) as f64;
    measurements
        .channels
        .iter()
        .zip(&measurements.variance)
        .enumerate()
        .map(|(j, (&channel, &variance))| {
            let row = measured_rows.row(j);
            let sum: f64 = tier
                .training
                .snapshots
                .iter()
                .zip(&tier.projected)
                .map(|(u, q)| {
                    (measured_value(full, channel, |d| u[d]) - row.dot(&q.transpose())).powi(2)
                })
                .sum();
            (sum / count / variance).sqrt()
        })
        .collect()
}

/// Operating points of the tier's gain schedule besides rest (docs/design.md §11.5).
pub const SCHEDULE_POINTS: usize = 8;

/// Up to `count` operating points among the training states `states` (projected snapshots,
/// r each): greedy farthest-point (k-centre) selection in the M-norm of q (= ‖q‖ for an
/// M-orthonormal basis), starting from rest (not returned): each point is the state farthest
/// from rest and the points already chosen; deterministic (the first of equal distances).
/// Fewer when the states run out or coincide with chosen points.
pub fn schedule_points(states: &[DVector<f64>], count: usize) -> Vec<DVector<f64>> {
    let mut distance: Vec<f64> = states.iter().map(|q| q.norm()).collect();
    let mut points: Vec<DVector<f64>> = Vec::with_capacity(count);
    while points.len() < count {
        let Some((far, &d)) = distance.iter().enumerate().fold(
            None,
            |best: Option<(usize, &f64)>, (i, d)| match best {
                Some((_, b)) if *b >= *d => best,
                _ => Some((i, d)),
            },
        ) else {
            break;
        };
        if d.is_nan() || d <= 0.0 {
            break;
        }
        let point = states[far].clone();
        for (dist, q) in distance.iter_mut().zip(states) {
            *dist = dist.min((q - &point).norm());
        }
        points.push(point);
    }
    points
}

/// The filter of `lin` re-linearised at each of `points` ([`LinearisedTier::at`] on `model`);
/// a point whose tangent or DARE fails is left out (the runtime then uses its neighbours).
pub(crate) fn scheduled_filters(
    lin: &LinearisedTier,
    model: &HyperReducedModel,
    points: &[DVector<f64>],
    measurements: &Measurements,
) -> Vec<(DVector<f64>, PeriodicSchedule, Mat<f64>)> {
    points
        .iter()
        .filter_map(|q| {
            filter_of(&lin.at(model, q), measurements)
                .ok()
                .map(|f| (q.clone(), f.schedule, f.process_noise))
        })
        .collect()
}

/// H V (channels × r) from each sensor's 3 × r rows.
pub(crate) fn measured_rows(
    measurements: &Measurements,
    rows_of: impl Fn(usize) -> DMatrix<f64>,
) -> DMatrix<f64> {
    let mut h = DMatrix::zeros(measurements.channels.len(), 0);
    for (row, &(s, c)) in measurements.channels.iter().enumerate() {
        let rows = rows_of(s);
        if h.ncols() == 0 {
            h = DMatrix::zeros(measurements.channels.len(), rows.ncols());
        }
        h.row_mut(row).copy_from(&rows.row(c));
    }
    h
}

/// The augmented model of a [`LinearisedTier`] in scaled modal coordinates x̃ (see
/// [`filter_of`]): x̃⁺ = F x̃ + G w, y = H x̃ + v, w ~ N(0, I), and the map s = T x̃ back to
/// s = (q, q̇, q̈, f, ḟ).
pub(crate) struct ScaledSystem {
    /// F (n × n).
    pub(crate) f: Mat<f64>,
    /// H (channels × n).
    pub(crate) h: Mat<f64>,
    /// G (n × (white + force + rate + model error)): columns of the white channels, then of
    /// the force states, then of their rates, then one per mode of the model error (§11.9;
    /// none without it or with the scene's factor 0), σ included.
    pub(crate) noise: Mat<f64>,
    /// T (n × n) = diag(Φ, Φ, Φ, I) D.
    pub(crate) t: Mat<f64>,
    /// The model error's columns at factor 1 (n × modes; σ of the measured S, whatever the
    /// scene's factor; empty without a measured S): the noise identification fits the factor
    /// on these.
    pub(crate) model_error_unit: Mat<f64>,
}

/// The [`ScaledSystem`] of `lin` for `measurements`.
///
/// Route: mass-normalised modes of (K_r, M_r) (Φ, λ) decouple the recursion into 3×3 blocks
/// ([`crate::dynamics::WilsonTheta::modal_block`]); scaled so that F's entries are O(1).
pub(crate) fn scaled_system(
    lin: &LinearisedTier,
    measurements: &Measurements,
) -> Result<ScaledSystem, NonlinearError> {
    let r = lin.mass.nrows();
    let chol = lin.mass.clone().cholesky().ok_or_else(|| {
        NonlinearError::Invalid("tier filter: reduced mass matrix is not positive definite".into())
    })?;
    let l = chol.l();
    let l_inv = l.clone().try_inverse().ok_or_else(|| {
        NonlinearError::Invalid("tier filter: reduced mass matrix is singular".into())
    })?;
    let kt = &l_inv * &lin.stiffness * l_inv.transpose();
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
    let w = lin.wilson;
    let n3 = 3 * r;
    let nf = lin.force_columns.len();
    let nr = lin.rate_sigma.len();
    let n = n3 + nf + nr;
    let mut f = Mat::<f64>::zeros(n, n);
    let mut gamma = vec![[0.0; 3]; r];
    for i in 0..r {
        let (a, g) = w.modal_block(lambda[i], lin.alpha + lin.beta * lambda[i]);
        for k1 in 0..3 {
            for k2 in 0..3 {
                f[(k1 * r + i, k2 * r + i)] = a[k1][k2];
            }
        }
        gamma[i] = g;
    }
    // Modal image Γ Φᵀ (Vᵀb) of a reduced load column into column `col` of `out`.
    let modal_load = |reduced: &DVector<f64>, out: &mut Mat<f64>, col: usize| {
        let modal = phi.tr_mul(reduced);
        for i in 0..r {
            for k1 in 0..3 {
                out[(k1 * r + i, col)] = gamma[i][k1] * modal[i];
            }
        }
    };
    for (j, column) in lin.force_columns.iter().enumerate() {
        modal_load(column, &mut f, n3 + j);
        f[(n3 + j, n3 + j)] = 1.0;
    }
    // Force rates (§11.5): f⁺ = f + Δt ḟ, ḟ⁺ = ḟ.
    for j in 0..nr {
        f[(n3 + j, n3 + nf + j)] = w.dt;
        f[(n3 + nf + j, n3 + nf + j)] = 1.0;
    }
    let nw = lin.noise_columns.len();
    // The model error's columns at factor 1 (one per mode); G takes them × √c.
    let unit_sigma = match &lin.model_error {
        Some(s) => model_error_noise(&phi, &lin.mass, s, &lambda, w, (lin.alpha, lin.beta)),
        None => Vec::new(),
    };
    let mut unit = Mat::<f64>::zeros(n, unit_sigma.len());
    for (i, &sigma) in unit_sigma.iter().enumerate() {
        for k1 in 0..3 {
            unit[(k1 * r + i, i)] = gamma[i][k1] * sigma;
        }
    }
    let nm = if lin.model_error_scale > 0.0 {
        unit.ncols()
    } else {
        0
    };
    let mut gw = Mat::<f64>::zeros(n, nw + nf + nr + nm);
    for (c, column) in lin.noise_columns.iter().enumerate() {
        modal_load(column, &mut gw, c);
    }
    let c = lin.model_error_scale.sqrt();
    for j in 0..nm {
        for i in 0..n {
            gw[(i, nw + nf + nr + j)] = c * unit[(i, j)];
        }
    }
    for (j, &sigma) in lin.force_sigma.iter().enumerate() {
        gw[(n3 + j, nw + j)] = sigma;
    }
    for (j, &sigma) in lin.rate_sigma.iter().enumerate() {
        gw[(n3 + nf + j, nw + nf + j)] = sigma;
    }
    // Diagonal scaling D (x_m = D x̃) so that F's entries are O(1) and the PBH tests of the
    // DARE are meaningful: (1, ω_i, ω_i²) for mode i's (η, η̇, η̈), and for a force state the
    // force whose static modal response max_i |(Φᵀ Vᵀ b)_i| / λ_i is 1 (in N, f is otherwise
    // seen through responses of 1e-4…1e-1 per N).
    let mut d = vec![1.0; n];
    for i in 0..r {
        let omega = lambda[i].sqrt();
        d[r + i] = omega;
        d[2 * r + i] = omega * omega;
    }
    for (j, column) in lin.force_columns.iter().enumerate() {
        let modal = phi.tr_mul(column);
        let response = (0..r).fold(0.0f64, |m, i| m.max(modal[i].abs() / lambda[i]));
        if response > 0.0 {
            d[n3 + j] = 1.0 / response;
        }
    }
    // A rate's unit: the rate that changes its force by one unit of d in one step.
    for j in 0..nr {
        d[n3 + nf + j] = d[n3 + j] / w.dt;
    }
    let f = Mat::<f64>::from_fn(n, n, |i, j| f[(i, j)] * d[j] / d[i]);
    let gw = Mat::<f64>::from_fn(n, gw.ncols(), |i, j| gw[(i, j)] / d[i]);
    let unit = Mat::<f64>::from_fn(n, unit.ncols(), |i, j| unit[(i, j)] / d[i]);
    let modal_rows = &lin.measured_rows * &phi;
    let h = Mat::<f64>::from_fn(measurements.channels.len(), n, |i, j| {
        if j < r {
            modal_rows[(i, j)] * d[j]
        } else {
            0.0
        }
    });
    // Back to s = (q, q̇, q̈, f): x_s = T D x̃, T = diag(Φ, Φ, Φ, I).
    let mut t = Mat::<f64>::zeros(n, n);
    for blk in 0..3 {
        for i in 0..r {
            for j in 0..r {
                t[(blk * r + i, blk * r + j)] = phi[(i, j)] * d[blk * r + j];
            }
        }
    }
    for j in n3..n {
        t[(j, j)] = d[j];
    }
    Ok(ScaledSystem {
        f,
        h,
        noise: gw,
        t,
        model_error_unit: unit,
    })
}

/// The model error as process noise (docs/design.md §11.9): per mass-normalised mode i of
/// (K_r, M_r) (columns of `phi`, eigenvalues `lambda`), the σ_i of a white modal force, held
/// over the step like a load, whose stationary open-loop variance of the mode's displacement
/// equals the measured one:
/// ```text
/// s_i = (Φᵀ M_r S M_r Φ)_ii,   X_i = A_i X_i A_iᵀ + g_i g_iᵀ,   σ_i² = s_i / (X_i)_00
/// ```
/// with (A_i, g_i) the mode's Wilson-θ block ([`crate::dynamics::WilsonTheta::modal_block`]).
/// σ_i = 0 for a mode without a stationary variance (|eigenvalue of A_i| ≥ 1).
/// Rayleigh damping (α, β) gives mode i the damping α + βλ_i.
pub fn model_error_noise(
    phi: &DMatrix<f64>,
    mass: &DMatrix<f64>,
    s: &DMatrix<f64>,
    lambda: &[f64],
    wilson: crate::dynamics::WilsonTheta,
    (alpha, beta): (f64, f64),
) -> Vec<f64> {
    let projector = phi.transpose() * mass;
    let modal = &projector * s * projector.transpose();
    lambda
        .iter()
        .enumerate()
        .map(|(i, &l)| {
            let (a, g) = wilson.modal_block(l, alpha + beta * l);
            match stationary_displacement_variance(&a, &g) {
                Some(x) if x > 0.0 && modal[(i, i)] > 0.0 => (modal[(i, i)] / x).sqrt(),
                _ => 0.0,
            }
        })
        .collect()
}

/// (X)_00 of the stationary X = A X Aᵀ + g gᵀ (3 × 3), solved as (I − A ⊗ A) vec X = vec g gᵀ;
/// None when A has no stationary covariance (the solve fails or X is not finite and ≥ 0).
fn stationary_displacement_variance(a: &[[f64; 3]; 3], g: &[f64; 3]) -> Option<f64> {
    let am = nalgebra::Matrix3::from_fn(|i, j| a[i][j]);
    let gm = nalgebra::Vector3::from_column_slice(g);
    let kron = nalgebra::SMatrix::<f64, 9, 9>::from_fn(|p, q| {
        let (i, k) = (p / 3, p % 3);
        let (j, l) = (q / 3, q % 3);
        f64::from(u8::from(p == q)) - am[(i, j)] * am[(k, l)]
    });
    let rhs = nalgebra::SVector::<f64, 9>::from_fn(|p, _| gm[p / 3] * gm[p % 3]);
    let x = kron.lu().solve(&rhs)?;
    let eig = am.complex_eigenvalues();
    if eig.iter().any(|e| e.norm() >= 1.0) {
        return None;
    }
    (x[0].is_finite() && x[0] >= 0.0).then_some(x[0])
}

/// The filter of a [`LinearisedTier`] (see [`linearised_filter`]): the DARE of the augmented
/// pair is solved in scaled modal coordinates x̃ (`ScaledSystem`, `kalman::periodic_gains`)
/// and mapped back with T.
pub fn filter_of(
    lin: &LinearisedTier,
    measurements: &Measurements,
) -> Result<TierFilter, NonlinearError> {
    let ScaledSystem { f, h, noise, t, .. } = scaled_system(lin, measurements)?;
    let nr = lin.rate_sigma.len();
    let q = &noise * noise.transpose();
    let schedule = kalman::periodic_gains(
        f.as_ref(),
        h.as_ref(),
        q.as_ref(),
        &measurements.variance,
        &measurements.every,
    )
    .map_err(|e| NonlinearError::Invalid(format!("tier filter: {e}")))?;
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
        force_loads: Vec::new(),
        force_rates: nr > 0,
        static_residual: 0.0,
        marker_model_error: Vec::new(),
        scheduled: Vec::new(),
        model_error: lin.model_error.clone(),
        levels: Vec::new(),
        adaptation: None,
        level_notes: Vec::new(),
    })
}

/// Worst relative static residual of the linearised tier's measured response to the force
/// channels (docs/design.md §11.4): max over channels j of ‖H K⁻¹ b_j − H V K_r⁻¹ Vᵀ b_j‖ /
/// ‖H K⁻¹ b_j‖ (H the measured rows, K the full-order stiffness, K_r the reduced tangent at
/// rest). 0 without force channels.
fn static_residual(
    full: &FullOrder,
    v: &DMatrix<f64>,
    k_r: &DMatrix<f64>,
    h_red: &DMatrix<f64>,
    channels: &[usize],
    measurements: &Measurements,
) -> Result<f64, NonlinearError> {
    if channels.is_empty() {
        return Ok(0.0);
    }
    let exact = static_marker_response(full, measurements, channels)
        .map_err(|e| NonlinearError::Invalid(format!("tier filter: {e}")))?;
    let inputs = &full.operators.inputs;
    let reduced_tangent = k_r.clone().cholesky().ok_or_else(|| {
        NonlinearError::Invalid(
            "tier filter: the reduced tangent at rest is not positive definite".into(),
        )
    })?;
    let mut worst: f64 = 0.0;
    for (j, &ch) in channels.iter().enumerate() {
        let load = v.tr_mul(&DVector::from_column_slice(&inputs[ch].column));
        let reduced = h_red * reduced_tangent.solve(&load);
        let diff = (exact.column(j) - reduced).norm_squared();
        let size = exact.column(j).norm_squared();
        if size > 0.0 {
            worst = worst.max((diff / size).sqrt());
        }
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::WilsonTheta;

    /// The 9 × 9 solve against the recursion X ← A X Aᵀ + g gᵀ iterated to its fixed point, on
    /// a lightly damped slow mode and a stiff one.
    #[test]
    fn stationary_variance_is_the_fixed_point_of_the_recursion() {
        let w = WilsonTheta {
            dt: 2e-3,
            theta: 1.4,
        };
        for (k, c) in [(400.0, 2.0 + 2e-3 * 400.0), (4e6, 2.0 + 2e-3 * 4e6)] {
            let (a, g) = w.modal_block(k, c);
            let solved = stationary_displacement_variance(&a, &g).unwrap();
            let am = nalgebra::Matrix3::from_fn(|i, j| a[i][j]);
            let gm = nalgebra::Vector3::from_column_slice(&g);
            let mut x = nalgebra::Matrix3::<f64>::zeros();
            for _ in 0..200_000 {
                x = am * x * am.transpose() + gm * gm.transpose();
            }
            assert!(
                (solved - x[(0, 0)]).abs() <= 1e-9 * x[(0, 0)],
                "k = {k}: solved {solved:e}, iterated {:e}",
                x[(0, 0)]
            );
        }
        // A growing mode has no stationary variance.
        let a = [[1.01, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]];
        assert!(stationary_displacement_variance(&a, &[1.0, 0.0, 0.0]).is_none());
    }

    /// Each mode's noise reproduces its measured variance: σ_i² X_i,00 = (Φᵀ M S M Φ)_ii, with
    /// a non-identity mass and modes mixing both coordinates; a mode without measured error
    /// gets no noise.
    #[test]
    fn model_error_noise_matches_each_modes_measured_variance() {
        let w = WilsonTheta {
            dt: 1e-3,
            theta: 1.4,
        };
        let mass = DMatrix::from_row_slice(2, 2, &[2.0, 0.0, 0.0, 0.5]);
        let stiffness = DMatrix::from_row_slice(2, 2, &[800.0, -100.0, -100.0, 300.0]);
        // Mass-normalised modes: L⁻¹ K L⁻ᵀ with L = diag(√2, √0.5).
        let l_inv = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![
            1.0 / 2f64.sqrt(),
            1.0 / 0.5f64.sqrt(),
        ]));
        let eig = (&l_inv * &stiffness * &l_inv).symmetric_eigen();
        let phi = &l_inv * &eig.eigenvectors;
        let lambda: Vec<f64> = eig.eigenvalues.iter().copied().collect();
        // S with error only in mode 0: S = σ₀² φ₀ φ₀ᵀ (then Φᵀ M S M Φ = diag(σ₀², 0)).
        let phi0 = phi.column(0).into_owned();
        let s = &phi0 * phi0.transpose() * 4e-6;
        let (alpha, beta) = (1.0, 1e-3);
        let sigma = model_error_noise(&phi, &mass, &s, &lambda, w, (alpha, beta));
        // The modal error variances by construction, not through the function's projection.
        let measured = [4e-6, 0.0];
        for i in 0..2 {
            let (a, g) = w.modal_block(lambda[i], alpha + beta * lambda[i]);
            let x = stationary_displacement_variance(&a, &g).unwrap();
            assert!(
                (sigma[i] * sigma[i] * x - measured[i]).abs() <= 1e-9 * 4e-6,
                "mode {i}: σ² X = {:e}, measured {:e}",
                sigma[i] * sigma[i] * x,
                measured[i]
            );
        }
        assert!(sigma[0] > 0.0 && sigma[1] < 1e-12 * sigma[0], "{sigma:?}");
    }

    /// The scene's `model_error_scale` c multiplies the model error's covariance: its columns
    /// of G (after the force columns) are √c × those of c = 1, the other columns unchanged;
    /// with c = 0 the system has no model-error columns, as without a measured S.
    #[test]
    fn the_model_error_scale_multiplies_its_covariance() {
        let mass = DMatrix::from_row_slice(2, 2, &[2.0, 0.0, 0.0, 0.5]);
        let lin = |scale: f64, error: bool| LinearisedTier {
            mass: mass.clone(),
            stiffness: DMatrix::from_row_slice(2, 2, &[800.0, -100.0, -100.0, 300.0]),
            alpha: 1.0,
            beta: 1e-3,
            wilson: WilsonTheta {
                dt: 1e-3,
                theta: 1.4,
            },
            force_columns: vec![DVector::from_vec(vec![1.0, 0.5])],
            force_sigma: vec![0.1],
            rate_sigma: Vec::new(),
            noise_columns: Vec::new(),
            measured_rows: DMatrix::from_row_slice(1, 2, &[1.0, 0.2]),
            model_error: error.then(|| DMatrix::from_row_slice(2, 2, &[4e-6, 1e-6, 1e-6, 2e-6])),
            model_error_scale: scale,
        };
        let measurements = Measurements {
            channels: vec![(0, 0)],
            variance: vec![1e-6],
            every: vec![1],
        };
        let g = |l: &LinearisedTier| scaled_system(l, &measurements).unwrap().noise;
        let (one, four) = (g(&lin(1.0, true)), g(&lin(4.0, true)));
        assert_eq!(one.ncols(), 1 + 2, "one force column, one per mode");
        assert_eq!(four.ncols(), one.ncols());
        for i in 0..one.nrows() {
            assert_eq!(four[(i, 0)], one[(i, 0)], "the force column is the scene's");
            for j in 1..one.ncols() {
                assert!(
                    (four[(i, j)] - 2.0 * one[(i, j)]).abs() <= 1e-12 * one[(i, j)].abs(),
                    "G[{i}, {j}]: {} against 2 × {}",
                    four[(i, j)],
                    one[(i, j)]
                );
            }
        }
        assert!((1..3).any(|j| (0..one.nrows()).any(|i| one[(i, j)] != 0.0)));
        // The identification's columns at factor 1, whatever the scene's factor.
        for c in [0.0, 4.0] {
            let unit = scaled_system(&lin(c, true), &measurements)
                .unwrap()
                .model_error_unit;
            assert_eq!(unit.ncols(), 2);
            for i in 0..unit.nrows() {
                for j in 0..2 {
                    let want = one[(i, 1 + j)];
                    assert!(
                        (unit[(i, j)] - want).abs() <= 1e-15 * want.abs(),
                        "[{i}, {j}]"
                    );
                }
            }
        }
        let (off, none) = (g(&lin(0.0, true)), g(&lin(1.0, false)));
        assert_eq!(off.ncols(), 1);
        assert_eq!(none.ncols(), 1);
        for i in 0..off.nrows() {
            assert_eq!(off[(i, 0)], none[(i, 0)]);
        }
    }
}
