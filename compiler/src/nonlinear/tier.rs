//! The co-rotational tier assembled from training (docs/design.md §10): training → POD basis →
//! ECSW sampling → reduced model ([`from_training`], [`build`]); its filter from the DARE of
//! the model linearised at rest and at training states, a gain schedule ([`linearised_filter`],
//! docs/design.md §11.4–11.5); and the model file's tier section ([`tier_section`],
//! docs/model-format.md).

use faer::linalg::solvers::Solve as _;
use faer::Mat;
use nalgebra::{DMatrix, DVector};

use crokf_formats as fmt;

use crate::fem::operators::InputKind;
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
    /// The training snapshots' reduced coordinates q = VᵀM u (r each, in the snapshots' order).
    pub projected: Vec<DVector<f64>>,
    /// Largest ‖q‖ over `projected`.
    pub max_coordinate_norm: f64,
    /// Wall time of the POD and of the ECSW, s.
    pub seconds: [f64; 2],
    /// With a per-run basis tolerance ([`BasisChoice::tolerance`]): the vectors added after the
    /// pooled POD and the worst per-run relative error in the energy norm reached (above the
    /// tolerance when `max_order` stopped the enrichment).
    pub enrichment: Option<(usize, f64)>,
}

/// Builds the tier from training snapshots: the first `order` POD vectors of the snapshots in
/// the M inner product, ECSW on the snapshots with `ecsw`.
pub fn from_training(
    full: &FullOrder,
    training: Training,
    order: usize,
    ecsw_options: &EcswOptions,
) -> Result<Tier, NonlinearError> {
    from_training_with(full, training, &BasisChoice::pod(order), ecsw_options)
}

/// How the tier's basis is chosen from the training snapshots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasisChoice {
    /// Pooled POD vectors (M inner product), first.
    pub order: usize,
    /// Per-run tolerance ε in the energy norm, enrichment up to `max_order` columns
    /// ([`basis::enrich_per_run`] with K; docs/corotational-tier.md §8); None: r = `order`.
    pub tolerance: Option<f64>,
    /// Largest r with a tolerance.
    pub max_order: usize,
}

impl BasisChoice {
    /// The first `order` pooled POD vectors only.
    pub fn pod(order: usize) -> Self {
        BasisChoice {
            order,
            tolerance: None,
            max_order: order,
        }
    }
}

/// [`from_training`] with the basis of `choice`: the pooled POD (M inner product, signs
/// normalised) and, with a tolerance ε, the per-run enrichment in the energy norm: while some
/// training run k has e_k = (Σ_t ‖(I − P_K) u_t‖²_K / Σ_t ‖u_t‖²_K)^½ > ε (P_K the K-orthogonal
/// projector on V), the leading K-POD vector of the worst run's residuals is appended; the
/// result is M-orthonormalised (same span). The energy norm because the Galerkin step solves
/// for the K-orthogonal projection, not the M-orthogonal one: on the twist hard case a basis
/// that fits the trajectory to 1–3 % in M left the linear static Galerkin solution 87 % off
/// (docs/corotational-tier.md §8).
pub fn from_training_with(
    full: &FullOrder,
    training: Training,
    choice: &BasisChoice,
    ecsw_options: &EcswOptions,
) -> Result<Tier, NonlinearError> {
    if training.snapshots.is_empty() {
        return Err(NonlinearError::Invalid(
            "no training snapshot: every training run failed".into(),
        ));
    }
    let clock = std::time::Instant::now();
    let order = choice.order;
    let (mut modes, pod_values) = basis::pod(&full.fem.mass, &training.snapshots, order, 1e-14);
    basis::normalise_signs(&mut modes);
    let mut basis = basis::m_orthonormalise(&full.fem.mass, &modes, 1e-8, order);
    let mut enrichment = None;
    if let Some(tolerance) = choice.tolerance {
        let stiffness = &full.fem.stiffness;
        let energy = basis::m_orthonormalise(stiffness, &modes, 1e-8, order);
        let enriched = basis::enrich_per_run(
            stiffness,
            &training.snapshots,
            &training.run_of,
            training.runs.len(),
            energy,
            tolerance,
            choice.max_order.max(order),
        );
        let columns: Vec<(String, Vec<f64>)> = enriched.basis.columns();
        // The pooled columns first, unchanged (same M-orthonormal vectors as without the
        // tolerance), then the enrichment M-orthogonalised against them.
        let mut all: Vec<(String, Vec<f64>)> = basis.columns();
        all.extend(columns.into_iter().skip(enriched.pooled));
        enrichment = Some((enriched.enriched_from.len(), enriched.worst()));
        basis = basis::m_orthonormalise(&full.fem.mass, &all, 1e-10, all.len());
    }
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
    let projected: Vec<DVector<f64>> = training
        .snapshots
        .iter()
        .map(|u| basis.project(u))
        .collect();
    let max_coordinate_norm = projected.iter().map(|q| q.norm()).fold(0.0, f64::max);
    Ok(Tier {
        basis,
        pod_values,
        sampling,
        model,
        training,
        projected,
        max_coordinate_norm,
        seconds: [t_pod, t_ecsw],
        enrichment,
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

/// The deterministic input channel of component `c` of load group `load`, if any.
fn load_channel(full: &FullOrder, load: usize, c: usize) -> Option<usize> {
    full.operators
        .inputs
        .iter()
        .position(|ch| ch.kind == InputKind::Load { load, component: c })
}

/// The tier linearised at rest in reduced coordinates: everything its filter needs, which is
/// also what the model file's tier section stores (so a filter can be recomputed from a model
/// file for other sensors' noise or rates without retraining, [`refilter`]).
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
}

/// The scene's noise model on the tier: random-walk force states and the white noise channels
/// they do not replace.
struct NoiseModel {
    /// Per force state: (input channel index into `full.operators.inputs`, σ in N per step).
    force: Vec<(usize, f64)>,
    /// White noise channels (indices into `full.operators.noise`).
    white: Vec<usize>,
    /// Per force state: σ of its rate's random walk, N/s per step; empty without rate states.
    rate: Vec<f64>,
}

/// The scene's [`NoiseModel`] (docs/design.md §11.4).
fn noise_model(full: &FullOrder) -> Result<NoiseModel, NonlinearError> {
    let force_loads = full.random_walk_loads();
    let mut force = Vec::with_capacity(3 * force_loads.len());
    for &(g, sigma) in &force_loads {
        for c in 0..3 {
            let ch = load_channel(full, g, c).ok_or_else(|| {
                NonlinearError::Invalid(format!(
                    "tier filter: load group {g} has no input channel for component {c}"
                ))
            })?;
            force.push((ch, sigma));
        }
    }
    let rates = full.force_rate_sigmas();
    let rate = if rates.iter().all(|&r| r == 0.0) {
        Vec::new()
    } else if rates.iter().all(|&r| r > 0.0) {
        rates.iter().flat_map(|&r| [r; 3]).collect()
    } else {
        return Err(NonlinearError::Invalid(
            "tier filter: force_rate_noise_std must be set on every random-walk load or on none"
                .into(),
        ));
    };
    let white = (0..full.operators.noise.len())
        .filter(|&j| match full.operators.noise[j].kind {
            InputKind::Noise { load: Some(g) } => !force_loads.iter().any(|&(l, _)| l == g),
            _ => true,
        })
        .collect();
    Ok(NoiseModel { force, white, rate })
}

/// The tier's filter (docs/design.md §11.4): the reduced model linearised at rest
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
/// `ReducedModel::with_force_states`). The force states have no output columns: the static
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
    measurements: &Measurements,
) -> Result<TierFilter, NonlinearError> {
    let model = &tier.model;
    let r = model.order();
    let v = &tier.basis.vectors;
    let NoiseModel { force, white, rate } = noise_model(full)?;
    let project = |column: &[f64]| v.tr_mul(&DVector::from_column_slice(column));
    let ops = &full.operators;
    let lin = LinearisedTier {
        mass: model.mass.clone(),
        stiffness: model.tangent(&DVector::zeros(r), 0.0, true),
        alpha: model.alpha,
        beta: model.beta,
        wilson: full.wilson,
        force_columns: force
            .iter()
            .map(|&(ch, _)| project(&ops.inputs[ch].column))
            .collect(),
        force_sigma: force.iter().map(|&(_, s)| s).collect(),
        rate_sigma: rate,
        noise_columns: white
            .iter()
            .map(|&j| project(&ops.noise[j].column))
            .collect(),
        measured_rows: measured_rows(measurements, |s| {
            point_rows(full, v, &ops.sensors[s].weights)
        }),
    };
    let channels: Vec<usize> = force.iter().map(|&(ch, _)| ch).collect();
    let residual = static_residual(
        full,
        v,
        &lin.stiffness,
        &lin.measured_rows,
        &channels,
        measurements,
    )?;
    let mut filter = filter_of(&lin, measurements)?;
    filter.force_loads = full.random_walk_loads().iter().map(|&(g, _)| g).collect();
    filter.static_residual = residual;
    filter.marker_model_error = marker_model_error(full, tier, &lin.measured_rows, measurements);
    let points = schedule_points(&tier.projected, SCHEDULE_POINTS);
    filter.scheduled = scheduled_filters(&lin, model, &points, measurements);
    Ok(filter)
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

/// The full-order value of measurement channel (sensor, component) `channel` for the
/// displacement `u` (by DOF index): the sensor's barycentric interpolation.
fn measured_value(full: &FullOrder, (s, c): (usize, usize), u: impl Fn(usize) -> f64) -> f64 {
    full.operators.sensors[s]
        .weights
        .iter()
        .filter_map(|&(node, w)| full.fem.dofs.index[node][c].map(|d| w * u(d)))
        .sum()
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
fn scheduled_filters(
    lin: &LinearisedTier,
    model: &ReducedModel,
    points: &[DVector<f64>],
    measurements: &Measurements,
) -> Vec<(DVector<f64>, PeriodicSchedule)> {
    points
        .iter()
        .filter_map(|q| {
            filter_of(&lin.at(model, q), measurements)
                .ok()
                .map(|f| (q.clone(), f.schedule))
        })
        .collect()
}

/// H V (channels × r) from each sensor's 3 × r rows.
fn measured_rows(
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
struct ScaledSystem {
    /// F (n × n).
    f: Mat<f64>,
    /// H (channels × n).
    h: Mat<f64>,
    /// G (n × (white + force + rate)): columns of the white channels, then of the force
    /// states, then of their rates, σ included.
    noise: Mat<f64>,
    /// T (n × n) = diag(Φ, Φ, Φ, I) D.
    t: Mat<f64>,
}

/// The [`ScaledSystem`] of `lin` for `measurements`.
///
/// Route: mass-normalised modes of (K_r, M_r) (Φ, λ) decouple the recursion into 3×3 blocks
/// ([`crate::dynamics::WilsonTheta::modal_block`]); scaled so that F's entries are O(1).
fn scaled_system(
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
    let mut gw = Mat::<f64>::zeros(n, nw + nf + nr);
    for (c, column) in lin.noise_columns.iter().enumerate() {
        modal_load(column, &mut gw, c);
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
    Ok(ScaledSystem { f, h, noise: gw, t })
}

/// The filter of a [`LinearisedTier`] (see [`linearised_filter`]): the DARE of the augmented
/// pair is solved in scaled modal coordinates x̃ (`ScaledSystem`, `kalman::periodic_gains`)
/// and mapped back with T.
pub fn filter_of(
    lin: &LinearisedTier,
    measurements: &Measurements,
) -> Result<TierFilter, NonlinearError> {
    let ScaledSystem { f, h, noise, t } = scaled_system(lin, measurements)?;
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
    })
}

/// The [`LinearisedTier`] of a model file's tier at rest for the scene `full` (same mesh and
/// loads; the scene gives the sensors' noise and rates and the force-noise σ) and the scene's
/// [`Measurements`]: K_r at rest = Σ wₑ V_eᵀ Kₑ V_e over the sampled elements, M_r, VᵀB and the
/// sensor rows from the file, the noise model from the scene. The scene's distributed force
/// noise is not in the file (no VᵀB_w): refused.
pub fn linearised_of_file(
    full: &FullOrder,
    model: &fmt::Model,
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
    let NoiseModel { force, white, rate } = noise_model(full)?;
    let mut noise_columns = Vec::with_capacity(white.len());
    for &j in &white {
        // A load's white noise channel is σ times its load channel (fem::operators), whose VᵀB
        // the file holds; distributed noise is not in the file.
        let ch = &full.operators.noise[j];
        let column = match ch.kind {
            InputKind::Noise { load: Some(g) } => (0..3)
                .find(|&c| ch.label.ends_with(["x", "y", "z"][c]))
                .and_then(|c| load_channel(full, g, c))
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
        force_columns: force
            .iter()
            .map(|&(ch, _)| input.column(ch).into())
            .collect(),
        force_sigma: force.iter().map(|&(_, s)| s).collect(),
        rate_sigma: rate,
        noise_columns,
        measured_rows: measured_rows(&measurements, |s| file_matrix(&t.sensor_rows[s])),
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
/// gradients from the mesh): what the compiler's [`ReducedModel`] was when the file was written,
/// for the consistent tangent K_N,r(q) of [`LinearisedTier::at`].
pub fn reduced_model_of_file(
    full: &FullOrder,
    t: &fmt::CorotationalTier,
) -> Result<ReducedModel, NonlinearError> {
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
        elements.push(super::reduced::SampledElement {
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
    Ok(ReducedModel {
        elements,
        mass: file_matrix(&t.mass),
        alpha: t.alpha,
        beta: t.beta,
        wilson: full.wilson,
    })
}

impl LinearisedTier {
    /// The same tier linearised at q (r) instead of rest: K_r ← K_N,r(q), the consistent
    /// reduced tangent of `model` (docs/design.md §11.5).
    pub fn at(&self, model: &ReducedModel, q: &DVector<f64>) -> LinearisedTier {
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

/// Recomputes the tier filter of a model file for the scene `full` (same mesh, loads and
/// training; other sensors' noise, rates or force-noise σ): the [`LinearisedTier`] is read
/// from the file's tier section (M_r, K_r at rest = Σ wₑ V_eᵀ Kₑ V_e over the sampled
/// elements, VᵀB, the sensor rows), the noise model from the scene, and the section's
/// `force_loads` and `kalman` are replaced. The scene's distributed force noise is not in the
/// file (no VᵀB_w): refused. Returns the new filter's closed-loop spectral radius.
pub fn refilter(full: &FullOrder, model: &mut fmt::Model) -> Result<f64, NonlinearError> {
    let (lin, measurements) = linearised_of_file(full, model)?;
    let Some(t) = model.tier.as_mut() else {
        return Err(NonlinearError::Invalid(
            "refilter: the model has no tier".into(),
        ));
    };
    let mut filter = filter_of(&lin, &measurements)?;
    filter.force_loads = full.random_walk_loads().iter().map(|&(g, _)| g).collect();
    let points: Vec<DVector<f64>> = t
        .scheduled
        .iter()
        .map(|s| DVector::from_column_slice(&s.point))
        .collect();
    if !points.is_empty() {
        let reduced = reduced_model_of_file(full, t)?;
        filter.scheduled = scheduled_filters(&lin, &reduced, &points, &measurements);
    }
    t.force_loads = filter.force_loads.iter().map(|&g| g as u32).collect();
    t.force_rates = filter.force_rates;
    t.kalman = kalman_section(&filter.schedule, &filter.process_noise, &measurements);
    t.scheduled = scheduled_section(&filter, &measurements);
    Ok(filter.schedule.closed_loop_spectral_radius)
}

/// What [`identify_noise`] found for one random-walk load group: σ in the scene and σ
/// identified, for the force (N per step) and, with rate states, its rate (N/s per step).
#[derive(Clone, Debug)]
pub struct IdentifiedLoad {
    /// The load group (index into the scene's loads).
    pub load: usize,
    /// σ_f of the scene and identified.
    pub force_sigma: (f64, f64),
    /// σ_ḟ of the scene and identified (rate states only).
    pub rate_sigma: Option<(f64, f64)>,
}

/// The tier filter's noise identified from its innovations ([`identify_noise`]).
#[derive(Clone, Debug)]
pub struct IdentifiedNoise {
    /// Per random-walk load group.
    pub loads: Vec<IdentifiedLoad>,
    /// The factor on the σ of the white process-noise channels (None without any).
    pub white_scale: Option<f64>,
    /// The factor on the markers' σ.
    pub measurement_scale: f64,
    /// The least-squares fit (θ per parameter: white, then per load force and rate, then R).
    pub estimate: kalman::als::AlsEstimate,
}

/// The noise of a model file's tier filter identified by autocovariance least squares
/// (docs/design.md §11.6, [`kalman::als`]) from the innovations of a run of that filter, gain
/// schedule included, from rest: `innovations[k]` = y_k − H V q⁻_k at every step k (in the
/// model's measurement order, NaN for a channel the step's phase does not measure), `filters[k]`
/// = (the schedule's filter that updated step k, the step's phase) (`Estimator::tier_filter`
/// after the update: 0 rest, i ≥ 1 `scheduled[i − 1]`; `Estimator::phase`), the innovation gate
/// off; the first `skip` steps are left out of the statistics. The gains are
/// the model file's (those the run used); the transitions are the tier linearised at rest and
/// at each scheduled point, all mapped into the rest filter's scaled coordinates. Parameters:
/// a factor on the variance of the white channels, of each random-walk load group's force
/// increments and rate increments, and of the markers' variance; each is σ² × θ, θ ≥ 0, σ those
/// of the scene `full` (the noise model's shape: same loads and markers as the model's).
/// Approximation: a white channel's process noise enters through the modal load of the rest
/// linearisation at every point (the force, rate and marker parameters are exact; the example
/// scenes have no white channel on the tier). Lags 0 … `lags`−1.
pub fn identify_noise(
    full: &FullOrder,
    model: &fmt::Model,
    innovations: &[Vec<f64>],
    filters: &[(usize, usize)],
    skip: usize,
    lags: usize,
) -> Result<IdentifiedNoise, NonlinearError> {
    let (lin, measurements) = linearised_of_file(full, model)?;
    let Some(t) = model.tier.as_ref() else {
        return Err(NonlinearError::Invalid("the model has no tier".into()));
    };
    let sys = scaled_system(&lin, &measurements)?;
    let (n, m) = (sys.f.nrows(), measurements.channels.len());
    let t0 = sys.t.partial_piv_lu();
    let period = t.kalman.period as usize;
    // The file's gains of a filter per phase (s coordinates, the phase's channels) as
    // K̂ = T₀⁻¹ K_s with a zero column for each channel the phase does not measure.
    let gains_of = |k: &fmt::KalmanGains, which: usize| -> Result<Vec<Mat<f64>>, NonlinearError> {
        if k.phases.len() != period {
            return Err(NonlinearError::Invalid(format!(
                "noise identification: filter {which} has {} phases, the tier {period}",
                k.phases.len()
            )));
        }
        k.phases
            .iter()
            .map(|phase| {
                let cols = phase.measured.len();
                if phase.gain.rows as usize != n
                    || phase.gain.cols as usize != cols
                    || phase.measured.iter().any(|&j| j as usize >= m)
                {
                    return Err(NonlinearError::Invalid(format!(
                        "noise identification: filter {which}'s gain does not fit its channels"
                    )));
                }
                let mut gain = Mat::<f64>::zeros(n, m);
                for (a, &j) in phase.measured.iter().enumerate() {
                    for i in 0..n {
                        gain[(i, j as usize)] = phase.gain.data[i * cols + a];
                    }
                }
                Ok(t0.solve(&gain))
            })
            .collect()
    };
    let mut transitions = vec![sys.f.clone()];
    let mut gains = vec![gains_of(&t.kalman, 0)?];
    if !t.scheduled.is_empty() {
        let reduced = reduced_model_of_file(full, t)?;
        for (i, point) in t.scheduled.iter().enumerate() {
            let at = lin.at(&reduced, &DVector::from_column_slice(&point.point));
            let sys_i = scaled_system(&at, &measurements)?;
            // x̂ = T₀⁻¹ s = X x̃_i, X = T₀⁻¹ T_i: F̂ = X F̃_i X⁻¹.
            let x = t0.solve(&sys_i.t);
            let xf = &x * &sys_i.f;
            let f_hat = x
                .transpose()
                .partial_piv_lu()
                .solve(xf.transpose())
                .transpose()
                .to_owned();
            transitions.push(f_hat);
            gains.push(gains_of(&point.kalman, i + 1)?);
        }
    }
    // One (F̂, K̂) per filter and phase, indexed filter · period + phase.
    let (transitions, gains): (Vec<Mat<f64>>, Vec<Mat<f64>>) = transitions
        .iter()
        .zip(&gains)
        .flat_map(|(f, per_phase)| per_phase.iter().map(move |k| (f.clone(), k.clone())))
        .unzip();
    if let Some(k) = filters.iter().position(|&(i, p)| {
        p >= period
            || i.checked_mul(period)
                .and_then(|x| x.checked_add(p))
                .is_none_or(|x| x >= gains.len())
    }) {
        return Err(NonlinearError::Invalid(format!(
            "noise identification: step {k} names filter {} phase {}, the model has {} filters \
             of {period} phases",
            filters[k].0,
            filters[k].1,
            gains.len() / period.max(1)
        )));
    }
    let sequence: Vec<usize> = filters.iter().map(|&(i, p)| i * period + p).collect();
    let (nw, nf, nr) = (
        lin.noise_columns.len(),
        lin.force_columns.len(),
        lin.rate_sigma.len(),
    );
    let part = |name: String, columns: std::ops::Range<usize>| {
        let g = sys.noise.subcols(columns.start, columns.len());
        kalman::als::NoiseParameter {
            name,
            process: g * g.transpose(),
            measurement: vec![0.0; m],
        }
    };
    let loads = full.random_walk_loads();
    let mut parameters = Vec::new();
    if nw > 0 {
        parameters.push(part("white process noise".into(), 0..nw));
    }
    for (i, &(g, _)) in loads.iter().enumerate() {
        let name = &full.scene.scene.loads[g].name;
        parameters.push(part(
            format!("force of load '{name}'"),
            nw + 3 * i..nw + 3 * i + 3,
        ));
        if nr > 0 {
            parameters.push(part(
                format!("force rate of load '{name}'"),
                nw + nf + 3 * i..nw + nf + 3 * i + 3,
            ));
        }
    }
    parameters.push(kalman::als::NoiseParameter {
        name: "markers".into(),
        process: Mat::zeros(n, n),
        measurement: measurements.variance.clone(),
    });
    let estimate = kalman::als::scheduled_autocovariance_least_squares(
        sys.h.as_ref(),
        kalman::als::GainSchedule {
            transitions: &transitions,
            gains: &gains,
            sequence: &sequence,
        },
        &parameters,
        innovations,
        skip,
        lags,
    )
    .map_err(|e| NonlinearError::Invalid(e.to_string()))?;
    let theta = &estimate.theta;
    let mut at = usize::from(nw > 0);
    let mut identified = Vec::with_capacity(loads.len());
    for (i, &(g, sigma)) in loads.iter().enumerate() {
        let force_sigma = (sigma, sigma * theta[at].sqrt());
        at += 1;
        let rate_sigma = (nr > 0).then(|| {
            let scene = lin.rate_sigma[3 * i];
            at += 1;
            (scene, scene * theta[at - 1].sqrt())
        });
        identified.push(IdentifiedLoad {
            load: g,
            force_sigma,
            rate_sigma,
        });
    }
    Ok(IdentifiedNoise {
        loads: identified,
        white_scale: (nw > 0).then(|| theta[0].sqrt()),
        measurement_scale: theta[at].sqrt(),
        estimate,
    })
}

/// The section's `kalman` of a periodic schedule with process noise `process_noise`.
fn kalman_section(
    schedule: &PeriodicSchedule,
    process_noise: &Mat<f64>,
    measurements: &Measurements,
) -> fmt::KalmanGains {
    fmt::KalmanGains {
        period: schedule.period as u32,
        phases: schedule
            .phases
            .iter()
            .map(|p| fmt::KalmanPhase {
                measured: p.measured.iter().map(|&i| i as u32).collect(),
                gain: crate::model_file::to_matrix(p.gain.as_ref()),
                prior_covariance: crate::model_file::to_matrix(p.prior_covariance.as_ref()),
                posterior_covariance: crate::model_file::to_matrix(p.posterior_covariance.as_ref()),
            })
            .collect(),
        process_noise: crate::model_file::to_matrix(process_noise.as_ref()),
        measurement_variance: measurements.variance.clone(),
    }
}

/// The section's `scheduled` of a filter.
fn scheduled_section(
    filter: &TierFilter,
    measurements: &Measurements,
) -> Vec<fmt::ScheduledFilter> {
    filter
        .scheduled
        .iter()
        .map(|(q, schedule)| fmt::ScheduledFilter {
            point: q.iter().copied().collect(),
            kalman: kalman_section(schedule, &filter.process_noise, measurements),
        })
        .collect()
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
    let fem = &full.fem;
    let n = fem.dof_count();
    let llt = fem.stiffness.sp_cholesky(faer::Side::Lower).map_err(|e| {
        NonlinearError::Invalid(format!(
            "tier filter: the stiffness K is not positive definite ({e:?})"
        ))
    })?;
    let inputs = &full.operators.inputs;
    let mut u = Mat::from_fn(n, channels.len(), |i, j| inputs[channels[j]].column[i]);
    llt.solve_in_place(u.as_mut());
    let reduced_tangent = k_r.clone().cholesky().ok_or_else(|| {
        NonlinearError::Invalid(
            "tier filter: the reduced tangent at rest is not positive definite".into(),
        )
    })?;
    let mut worst: f64 = 0.0;
    for (j, &ch) in channels.iter().enumerate() {
        let load = v.tr_mul(&DVector::from_column_slice(&inputs[ch].column));
        let reduced = h_red * reduced_tangent.solve(&load);
        let (mut diff, mut size) = (0.0, 0.0);
        for (row, &channel) in measurements.channels.iter().enumerate() {
            let exact = measured_value(full, channel, |d| u[(d, j)]);
            diff += (exact - reduced[row]).powi(2);
            size += exact * exact;
        }
        if size > 0.0 {
            worst = worst.max((diff / size).sqrt());
        }
    }
    Ok(worst)
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
    /// on the tier linearised at q* ([`LinearisedTier::at`]); `schedule` is the point q = 0.
    pub scheduled: Vec<(DVector<f64>, PeriodicSchedule)>,
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
        force_loads: filter.force_loads.iter().map(|&g| g as u32).collect(),
        force_rates: filter.force_rates,
        kalman: kalman_section(&filter.schedule, &filter.process_noise, measurements),
        scheduled: scheduled_section(filter, measurements),
    }
}
