//! The co-rotational tier section of a model file (format v7; docs/model-format.md,
//! docs/design.md §10): a hyper-reduced co-rotational model on the reduced coordinates q (r)
//! with u ≈ V q (world-frame displacements of the free DOFs, m per unit q).
//!
//! Per step (Wilson-θ, τ = θΔt, a₀ = 6/τ², a₂ = 3/τ, load f_r = Vᵀ B u held over the step):
//! ```text
//! f_r,int(q) = Σ_e wₑ V_eᵀ Rₑ Kₑ (Rₑᵀ xₑ − Xₑ),  xₑ = Xₑ + V_e q   (R from F = R S)
//! q̈_θ = a₀Δq̂ − (6/τ)q̇ − 2q̈,   q̇_θ = a₂Δq̂ − 2q̇ − (τ/2)q̈
//! res(q̂) = f_r − M_r(q̈_θ + α q̇_θ) − f_r,int(q̂) − β Σ_e wₑ V_eᵀ Rₑ Kₑ Rₑᵀ V_e q̇_θ
//! J = K_t,r(q̂)(1 + a₂β) + (a₀ + a₂α) M_r,   q̂ ← q̂ + J⁻¹ res
//! ```
//! then the Wilson-θ update of (q, q̇, q̈). The filter (extended Kalman filter with gains from
//! the DARE of the model linearised at rest and, as a gain schedule, at training states,
//! docs/design.md §11.4–11.5) has the state s = (q, q̇, q̈, f[, ḟ]) (3r + 3·`force_loads.len()`,
//! twice the force states with `force_rates`) and the linear measurement map y = H V q.
//! f holds the world force of each random-walk load group (3 components, N, f_{k+1} = f_k + w);
//! it enters the step as an input: f_r = VᵀB (u + f) (a load channel's column of `input`).

use crate::{KalmanGains, Matrix};
use serde::{Deserialize, Serialize};

/// The co-rotational tier of a model (present when the scene selected
/// `[reduction] model = "corotational"`; the runtime then steps this model, not F, G).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorotationalTier {
    /// Basis size r.
    pub order: u32,
    /// M_r = VᵀMV, r×r (kg per q²; the identity up to round-off for an M-orthonormal V).
    pub mass: Matrix,
    /// Rayleigh α, 1/s (C = αM + βK_t).
    pub alpha: f64,
    /// Rayleigh β, s.
    pub beta: f64,
    /// Runtime Newton: converged when ‖δq‖ ≤ `newton_tolerance` ‖q̂‖.
    pub newton_tolerance: f64,
    /// Runtime Newton: most iterations per step (≥ 1); a step that does not converge in as
    /// many is refused (estimator unchanged).
    pub newton_iterations: u32,
    /// VᵀB, r×m: reduced load per input channel (columns in the order of `Model::inputs`; a
    /// load channel is a world-frame dead force, N; gravity a scale factor).
    pub input: Matrix,
    /// Per sensor (order of `Model::sensors`): 3×r rows of V at the sensor, world-frame
    /// displacement u_s = V_s q, m.
    pub sensor_rows: Vec<Matrix>,
    /// Per displayed node set (order of `Model::node_sets`): 3n×r rows of V, world-frame
    /// displacement of node i in rows 3i..3i+3, m.
    pub node_set_rows: Vec<Matrix>,
    /// The sampled elements of the hyper-reduction (ECSW).
    pub elements: Vec<TierElement>,
    /// What the compiler trained on.
    pub envelope: TrainingEnvelope,
    /// Load groups (indices into `Model::loads`, increasing) whose force is estimated by
    /// random-walk states (format v4; docs/design.md §11.4): group `force_loads[k]`'s world
    /// force (x, y, z, N) is state 3r + 3k + c, added to the group's input channels (so the
    /// group needs all three load channels). Empty (or absent, as in a v3 payload): white
    /// force model, s = (q, q̇, q̈).
    #[serde(default)]
    pub force_loads: Vec<u32>,
    /// Force-rate states (format v5; docs/design.md §11.5): when true each force state also has
    /// its rate ḟ (N/s), state 3r + 3g + 3k + c for group `force_loads[k]` (g groups), and the
    /// prediction carries f⁺ = f + Δt ḟ, ḟ⁺ = ḟ (an integrated random walk).
    #[serde(default)]
    pub force_rates: bool,
    /// The filter on s = (q, q̇, q̈, f[, ḟ]) (state dimension [`Self::state_dim`]) designed on
    /// the model linearised at rest: gains (state × measured), prior/posterior covariances and
    /// process noise (state × state); `measurement_variance` as `Model::kalman`. Used near rest,
    /// and everywhere when `scheduled` is empty.
    pub kalman: KalmanGains,
    /// Gain schedule (format v5; docs/design.md §11.5): the same filter designed on the tier
    /// linearised at deformed states q* (consistent reduced tangent K_N,r(q*)), picked by the
    /// runtime when q is nearer to q* than to rest and to every other point. Empty: the
    /// constant gain `kalman` everywhere (as v4).
    #[serde(default)]
    pub scheduled: Vec<ScheduledFilter>,
    /// The reduced model's measured error inside its basis (format v6; docs/design.md §11.9):
    /// a covariance S (r × r, q²) that the filter takes as process noise, kept so that a
    /// filter recomputed from the file (other sensors, identified σ) keeps it. 0 × 0: none.
    #[serde(default)]
    pub model_error: Matrix,
    /// Force-σ levels (format v7; docs/design.md §11.10): the same filter and gain schedule
    /// designed with every force state's σ (and rate σ) scaled by `factor`, one entry per
    /// level other than the designed one (`kalman`, `scheduled`: factor 1). Empty: one level.
    #[serde(default)]
    pub force_levels: Vec<ForceLevel>,
    /// How the runtime moves between the levels (format v7; present exactly when
    /// `force_levels` is not empty).
    #[serde(default)]
    pub adaptation: Option<ForceAdaptation>,
    /// Why the compiler's own check of the tier failed (format v10, [`FAILED_CHECK_FORMAT_VERSION`]):
    /// more than half of its training runs, or of the runs held out of it, off the full-order
    /// co-rotational FEM by more than the check's threshold. The compiler refuses such a tier
    /// unless the scene sets `[reduction.corotational] accept_failed_check = true`; then it is
    /// written with this reason, which the runtime, `crokf-run` and the bindings report on
    /// loading. None (absent from the payload): the tier passed.
    ///
    /// [`FAILED_CHECK_FORMAT_VERSION`]: crate::FAILED_CHECK_FORMAT_VERSION
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed_check: Option<String>,
}

/// One level of the force states' σ (format v7): the filter at rest and at every point of the
/// gain schedule, designed with the force σ times `factor`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceLevel {
    /// Factor on the designed force σ (> 0, ≠ 1, distinct across levels).
    pub factor: f64,
    /// The filter at rest (as the section's `kalman`).
    pub kalman: KalmanGains,
    /// The filter at each operating point of the section's `scheduled`, in its order.
    pub scheduled: Vec<KalmanGains>,
}

/// The innovation statistic that chooses the force-σ level at run time (format v7;
/// docs/design.md §11.10). Per measurement channel j an exponentially weighted mean of the
/// whitened innovation, e_j ← (1 − a_j) e_j + a_j z_j (z_j clipped to ±5); T is the mean over
/// the updated channels of e_j² normalised to unit mean. σ goes one level up when
/// T > `raise_above`; every `hold` steps since the last change or check, one level down when
/// T < `lower_below` (below the designed σ only while every estimated load is told).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceAdaptation {
    /// a_j per measurement channel (model order), in (0, 1].
    pub smoothing: Vec<f64>,
    /// Threshold above which σ is raised one level (> `lower_below`).
    pub raise_above: f64,
    /// Threshold below which T, checked every `hold` steps, lowers σ one level (> 0).
    pub lower_below: f64,
    /// Steps between two checks against `lower_below` (≥ 1).
    pub hold: u32,
}

/// One operating point of the tier's gain schedule (format v5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduledFilter {
    /// The operating point q* (r reduced coordinates).
    pub point: Vec<f64>,
    /// The filter linearised at q*: same period, phases, measured channels and measurement
    /// variance as the tier's `kalman`; its own gains, covariances and process noise (the
    /// model-error term, format v6, is per mode of this linearisation).
    pub kalman: KalmanGains,
}

impl CorotationalTier {
    /// Every stored filter, level by level (the designed σ, then `force_levels` in order), and
    /// within a level at rest then at each `scheduled` point: level l's filter at point i is
    /// the (l·(1 + `scheduled.len()`) + i)-th (the numbering of the runtime's `tier_filter`).
    pub fn filters(&self) -> impl Iterator<Item = &KalmanGains> {
        std::iter::once(&self.kalman)
            .chain(self.scheduled.iter().map(|s| &s.kalman))
            .chain(
                self.force_levels
                    .iter()
                    .flat_map(|l| std::iter::once(&l.kalman).chain(&l.scheduled)),
            )
    }

    /// Dimension of the filter's state s = (q, q̇, q̈, f[, ḟ]): 3r + 3·`force_loads.len()`,
    /// twice that many force states with `force_rates`.
    pub fn state_dim(&self) -> usize {
        let per_group = if self.force_rates { 6 } else { 3 };
        3 * self.order as usize + per_group * self.force_loads.len()
    }
}

/// One sampled element: f contributes wₑ V_eᵀ fₑ(Xₑ + V_e q).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TierElement {
    /// Index of the element in the compiler's mesh (informative).
    pub element: u32,
    /// ECSW weight wₑ ≥ 0.
    pub weight: f64,
    /// Rest vertex positions Xₑ, m (4 vertices).
    pub rest: [[f64; 3]; 4],
    /// Shape-function gradients ∇Nₐ at rest, 1/m (F = Σₐ xₐ ⊗ ∇Nₐ).
    pub gradients: [[f64; 3]; 4],
    /// Rest stiffness Kₑ, 12×12, N/m, node-major (row 3a + c: node a, component c).
    pub stiffness: Matrix,
    /// V_e, 12×r: the rows of V at the element's DOFs (zero rows at fixed DOFs).
    pub rows: Matrix,
}

/// One training history (docs/design.md §10 item 2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingHistory {
    /// `"ramp"` (0 → multiple over `time` s, then held) or `"step"` (multiple from t = 0).
    pub kind: String,
    /// Multiple of the group's range.
    pub multiple: f64,
    /// Ramp time, s (0 for a step).
    pub time: f64,
}

/// Per trained load group.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvelopeLoad {
    /// Load group name (`Model::loads`).
    pub name: String,
    /// The scene's load range F, N.
    pub range: f64,
    /// Largest trained force magnitude (range × largest multiple), N; the runtime reports a
    /// step whose force on this group exceeds it.
    pub max_force: f64,
}

/// The training envelope: what the tier was trained on and the state it covered.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingEnvelope {
    /// Trained load groups (a group not listed was never loaded in training).
    pub loads: Vec<EnvelopeLoad>,
    /// Unit world directions of the training loads.
    pub directions: Vec<[f64; 3]>,
    /// Load histories of the runs.
    pub histories: Vec<TrainingHistory>,
    /// Length of each run, s.
    pub duration: f64,
    /// Snapshot every k steps.
    pub every: u32,
    /// Runs that completed.
    pub runs_completed: u32,
    /// Runs attempted.
    pub runs_attempted: u32,
    /// Snapshots kept.
    pub snapshots: u32,
    /// Largest nodal displacement magnitude in any snapshot, m.
    pub max_displacement: f64,
    /// Largest ‖q‖ (= ‖u‖_M for an M-orthonormal V) of a snapshot's projection; the runtime
    /// reports a state with ‖q‖ above `state_margin` × this.
    pub max_coordinate_norm: f64,
    /// Factor on `max_coordinate_norm` beyond which the state is outside the envelope (≥ 1).
    pub state_margin: f64,
}
