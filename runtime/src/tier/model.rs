//! The prepared tier model (docs/design.md §10–11, docs/model-format.md): everything the tier's
//! step and filter read from a model file's tier section, laid out once at load (sampled
//! elements packed for the kernel, gains transposed, read-out σ and the gate's variances per
//! filter of the gain schedule, phase and covariance kind).

use crate::adaptation::Levels;
use crate::covariance::{gate_variances, row_std};
use crokf_formats::{CorotationalTier, InputKind, Model};
use crokf_kernel::{self as kernel, Mat3};

/// The prepared tier model (read-only, from the model file).
#[derive(Clone, Debug)]
pub struct TierModel {
    pub(super) r: usize,
    /// The sampled elements packed by 8 ([`kernel::Blocks`]): the force and the tangent.
    pub(super) blocks: kernel::Blocks,
    /// The kernel path the force and the tangent run on ([`kernel::Isa::best`], detected once
    /// at load rather than at every Newton iteration).
    pub(super) isa: kernel::Isa,
    /// M_r (r × r, row-major, symmetrised at load).
    pub(super) mass: Vec<f64>,
    pub(super) alpha: f64,
    pub(super) beta: f64,
    pub(super) dt: f64,
    pub(super) theta: f64,
    pub(super) tolerance: f64,
    pub(super) max_iterations: usize,
    /// VᵀB, r×m row-major.
    pub(super) input: Vec<f64>,
    pub(super) m: usize,
    /// Per force state (3r + k): its input channel (the group's world component).
    pub(super) force_channels: Vec<usize>,
    /// Whether each force state's rate follows the force states (3r + nf + k, N/s).
    pub(super) force_rates: bool,
    /// Filter state dimension n = 3r + force_channels.len() (twice that many with rates).
    pub(super) n: usize,
    /// Per model load group: max trained force (None: never trained).
    pub(super) max_force: Vec<Option<f64>>,
    /// Per input channel: its load group (None for gravity).
    pub(super) channel_load: Vec<Option<(usize, usize)>>,
    pub(super) max_q: f64,
    pub(super) margin: f64,
    /// Per sensor 3×r rows.
    pub(crate) sensor_rows: Vec<Vec<f64>>,
    /// Per node set 3n×r rows.
    pub(crate) node_rows: Vec<Vec<f64>>,
    /// Per measurement channel: (sensor, component).
    pub(super) channel: Vec<(usize, usize)>,
    /// Per phase: measured channel indices.
    pub(super) measured: Vec<Vec<u32>>,
    /// The gain schedule (docs/design.md §11.5) at each force-σ level (§11.10): filter
    /// l·P + i is level l's filter at point i (P = [`TierModel::filter_count`]); point 0 is
    /// rest (`kalman`), point i ≥ 1 designed at `points[i − 1]`; level 0 is the designed σ,
    /// level l ≥ 1 `force_levels[l − 1]`.
    pub(super) filters: Vec<PointFilter>,
    /// Points per level (1 + scheduled points).
    pub(super) per_level: usize,
    /// The force-σ levels and their statistic (`None`: one level).
    pub(super) levels: Option<Levels>,
    /// Operating points of filters 1.., r each, row-major.
    pub(super) points: Vec<f64>,
    /// Per measurement channel: (H Q Hᵀ)_jj, m² per step (the gate's growth g_j).
    pub(super) variance_growth: Vec<f64>,
    /// Per measurement channel: R_jj, m².
    pub(super) measurement_variance: Vec<f64>,
}

/// One filter of the tier's gain schedule: its gains and what the read-outs and the gate need
/// of its covariances.
#[derive(Clone, Debug)]
pub(super) struct PointFilter {
    /// Per phase: the gain transposed (measured × n, row-major: column a of K_p is
    /// `gains_t[p][a n ..]`), so that K_p ν runs over contiguous columns.
    pub(super) gains_t: Vec<Vec<f64>>,
    /// Per phase, per active channel: the innovation variance (H P⁻ Hᵀ)_jj + R_jj, m² (the
    /// gate's s_j, runtime/src/estimator.rs).
    pub(super) innovation_variance: Vec<Vec<f64>>,
    /// Per kind (prior, posterior) and phase: sensor std (3 per sensor), node std per set.
    pub(super) sensor_std: [Vec<Vec<f64>>; 2],
    pub(super) node_std: [Vec<Vec<Vec<f64>>>; 2],
}

/// Aᵀ (cols × rows, row-major) of A.
fn transposed(a: &crokf_formats::Matrix) -> Vec<f64> {
    let (n, m) = (a.rows as usize, a.cols as usize);
    let mut t = vec![0.0; n * m];
    for i in 0..n {
        for j in 0..m {
            t[j * n + i] = a.data[i * m + j];
        }
    }
    t
}

/// sqrt(diag(C P_qq Cᵀ)) for the rows C (k × r, row-major).
fn std_rows(rows: &[f64], r: usize, p: &crokf_formats::Matrix) -> Vec<f64> {
    let mut out = Vec::with_capacity(rows.len() / r.max(1));
    row_std(rows, r, p, &mut out);
    out
}

impl TierModel {
    /// Prepares the tier of a validated model.
    pub fn new(model: &Model, tier: &CorotationalTier) -> Self {
        let r = tier.order as usize;
        let blocks = kernel::Blocks::new(
            &tier
                .elements
                .iter()
                .map(|e| kernel::Element {
                    weight: e.weight,
                    rest: &e.rest,
                    gradients: &e.gradients,
                    stiffness: &e.stiffness.data,
                    rows: &e.rows.data,
                    cols: &[],
                })
                .collect::<Vec<_>>(),
        );
        let max_force = model
            .loads
            .iter()
            .map(|l| {
                tier.envelope
                    .loads
                    .iter()
                    .find(|e| e.name == l.name)
                    .map(|e| e.max_force)
            })
            .collect();
        let channel_load = model
            .inputs
            .iter()
            .map(|c| match c.kind {
                InputKind::Load { load, component } => Some((load as usize, component as usize)),
                InputKind::Gravity { .. } => None,
            })
            .collect();
        let channel: Vec<(usize, usize)> = model
            .measurements
            .iter()
            .map(|m| (m.sensor as usize, m.component as usize))
            .collect();
        let sensor_rows: Vec<Vec<f64>> = tier.sensor_rows.iter().map(|m| m.data.clone()).collect();
        let node_rows: Vec<Vec<f64>> = tier.node_set_rows.iter().map(|m| m.data.clone()).collect();
        let h_row = |j: usize| {
            let (s, c) = channel[j];
            &sensor_rows[s][c * r..(c + 1) * r]
        };
        let k = &tier.kalman;
        let (_, variance_growth) = gate_variances(k, channel.len(), h_row);
        let filter = |k: &crokf_formats::KalmanGains| {
            let cov = |post: bool| -> (Vec<Vec<f64>>, Vec<Vec<Vec<f64>>>) {
                let mut s_out = Vec::new();
                let mut n_out = Vec::new();
                for ph in &k.phases {
                    let p = if post {
                        &ph.posterior_covariance
                    } else {
                        &ph.prior_covariance
                    };
                    s_out.push(
                        sensor_rows
                            .iter()
                            .flat_map(|rows| std_rows(rows, r, p))
                            .collect(),
                    );
                    n_out.push(node_rows.iter().map(|rows| std_rows(rows, r, p)).collect());
                }
                (s_out, n_out)
            };
            let (s_prior, n_prior) = cov(false);
            let (s_post, n_post) = cov(true);
            PointFilter {
                gains_t: k.phases.iter().map(|p| transposed(&p.gain)).collect(),
                innovation_variance: gate_variances(k, channel.len(), h_row).0,
                sensor_std: [s_prior, s_post],
                node_std: [n_prior, n_post],
            }
        };
        let filters: Vec<PointFilter> = tier.filters().map(filter).collect();
        let points = tier
            .scheduled
            .iter()
            .flat_map(|s| s.point.iter().copied())
            .collect();
        let force_channels: Vec<usize> = tier
            .force_loads
            .iter()
            .flat_map(|&g| {
                (0..3u8).filter_map(move |c| {
                    model.inputs.iter().position(|i| {
                        i.kind
                            == InputKind::Load {
                                load: g,
                                component: c,
                            }
                    })
                })
            })
            .collect();
        TierModel {
            r,
            blocks,
            isa: kernel::Isa::best(),
            // Symmetrised once (the stored M_r is symmetric to round-off; the blocked tangent
            // is symmetric by construction and the Cholesky factor reads the lower triangle).
            mass: {
                let m = &tier.mass.data;
                let mut sym = m.clone();
                for i in 0..r {
                    for j in 0..r {
                        sym[i * r + j] = 0.5 * (m[i * r + j] + m[j * r + i]);
                    }
                }
                sym
            },
            alpha: tier.alpha,
            beta: tier.beta,
            dt: model.dt,
            theta: model.theta,
            tolerance: tier.newton_tolerance,
            max_iterations: tier.newton_iterations as usize,
            input: tier.input.data.clone(),
            m: model.inputs.len(),
            n: 3 * r + force_channels.len() * if tier.force_rates { 2 } else { 1 },
            force_rates: tier.force_rates,
            force_channels,
            max_force,
            channel_load,
            max_q: tier.envelope.max_coordinate_norm,
            margin: tier.envelope.state_margin,
            sensor_rows,
            node_rows,
            channel,
            measured: k.phases.iter().map(|p| p.measured.clone()).collect(),
            filters,
            per_level: 1 + tier.scheduled.len(),
            levels: Levels::new(tier),
            points,
            variance_growth,
            measurement_variance: k.measurement_variance.clone(),
        }
    }

    /// Basis size r.
    pub fn order(&self) -> usize {
        self.r
    }

    /// Number of sampled elements.
    pub fn element_count(&self) -> usize {
        self.blocks.len()
    }

    /// Filter state dimension: 3r + 3 per random-walk load group (s = (q, q̇, q̈, f)).
    pub fn state_dim(&self) -> usize {
        self.n
    }

    /// Number of force states (3 per random-walk load group).
    pub fn force_state_count(&self) -> usize {
        self.force_channels.len()
    }

    /// The measurement channels phase `phase` of the tier's filter updates with, in the order
    /// of its gain's columns.
    pub fn measured(&self, phase: usize) -> &[u32] {
        &self.measured[phase]
    }

    /// Number of filters of the gain schedule (1: the constant gain designed at rest), per
    /// force-σ level.
    pub fn filter_count(&self) -> usize {
        self.per_level
    }

    /// The force-σ levels and their statistic (`None`: one level).
    pub(crate) fn levels(&self) -> Option<&Levels> {
        self.levels.as_ref()
    }

    /// The index of level `level`'s filter at point `point` among all stored filters.
    pub fn filter_index(&self, level: usize, point: usize) -> usize {
        level * self.per_level + point
    }

    /// Per active channel of `phase`: the innovation variance (H P⁻ Hᵀ)_jj + R_jj of stored
    /// filter `filter` ([`TierModel::filter_index`]), m².
    pub(crate) fn innovation_variance(&self, filter: usize, phase: usize) -> &[f64] {
        &self.filters[filter].innovation_variance[phase]
    }

    /// The filter of the gain schedule for the state q (r): 0 (rest) or i ≥ 1 (operating point
    /// i − 1), whichever point is nearest to q in the Euclidean norm of q (the M-norm of the
    /// displacement, docs/design.md §11.5); ties go to the lower index.
    pub fn nearest_filter(&self, q: &[f64]) -> usize {
        let r = self.r;
        let mut best = (0, dot(&q[..r], &q[..r]));
        for (i, p) in self.points.chunks_exact(r).enumerate() {
            let d: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            if d < best.1 {
                best = (i + 1, d);
            }
        }
        best.0
    }

    /// Precomputed std of stored filter `filter` ([`TierModel::filter_index`]), covariance
    /// kind (0 prior, 1 posterior) and phase:
    /// (sensors, 3 each; node sets, 3 per node), m.
    pub(crate) fn std(&self, filter: usize, kind: usize, phase: usize) -> (&[f64], &[Vec<f64>]) {
        let f = &self.filters[filter];
        (&f.sensor_std[kind][phase], &f.node_std[kind][phase])
    }

    /// Whether every estimated load group (3 force states each) has a nonzero input among
    /// `inputs` (false without force states): the runtime is told the load, and its force
    /// states only absorb what the input does not explain.
    pub fn loads_told(&self, inputs: &[f64]) -> bool {
        !self.force_channels.is_empty()
            && self
                .force_channels
                .chunks_exact(3)
                .all(|group| group.iter().any(|&c| inputs[c] != 0.0))
    }

    /// Number of measurement channels of the model.
    pub fn channel_count(&self) -> usize {
        self.channel.len()
    }

    /// Largest number of measured channels in a phase of the tier's filter.
    pub fn max_measured(&self) -> usize {
        self.measured.iter().map(Vec::len).max().unwrap_or(0)
    }

    /// Reduced force f_r,int(q) + β K_t,r(q) q̇ (r) into `out` (module docs); `q`, `velocity`
    /// and `out` of length r. Refuses an inverted sampled element (its index).
    /// `rotations` receives each element's R (length: the number of sampled elements);
    /// `scratch` of length [`TierModel::force_scratch_len`].
    pub fn reduced_force(
        &self,
        q: &[f64],
        velocity: &[f64],
        out: &mut [f64],
        rotations: &mut [Mat3],
        scratch: &mut [f64],
    ) -> Result<(), usize> {
        self.blocks
            .reduced_force(self.isa, q, velocity, self.beta, out, rotations, scratch)
            .map_err(|(e, _)| e)
    }

    /// Length of [`TierModel::reduced_force`]'s scratch.
    pub fn force_scratch_len(&self) -> usize {
        self.blocks.scratch_len()
    }

    /// The sampled elements as the kernel holds them (to run its paths one by one:
    /// [`kernel::Blocks::reduced_force`]).
    pub fn blocks(&self) -> &kernel::Blocks {
        &self.blocks
    }

    /// The stiffness-proportional damping β of the reduced force (s).
    pub fn damping_beta(&self) -> f64 {
        self.beta
    }
}

/// a · b.
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
