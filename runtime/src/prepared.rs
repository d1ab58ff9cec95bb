//! Everything the estimator derives from a model once, at load, shared read-only by any number
//! of estimators (`Arc<PreparedModel>`, no copy of the matrices per instance).
//!
//! - read-out standard deviations sqrt(diag(C P Cᵀ)) per phase (`docs/design.md` §6);
//! - the innovation gate's variances: per phase and active channel j,
//!   s_j = (H P⁻_p Hᵀ)_jj + R_jj (m²), and the per-step growth g_j = (H Q Hᵀ)_jj (m²) used while
//!   channel j goes without an accepted value (§6);
//! - plausibility bounds (stated in `docs/model-format.md` §4): a length scale L (m), the
//!   bounding-box diagonal of the sensors' and displayed nodes' rest positions (at least
//!   1000 σ_max when the model has no extent); every measurement |y| ≤ 10 L; input channel j
//!   bounded by |u_j| ≤ 10 L / d_j, where d_j is the largest displacement any sensor or displayed
//!   node reaches per unit of input j in the linear step response after 2²⁰ steps,
//!   d_j = max_rows |c · Σ_{i<2²⁰} Fⁱ G e_j| (an input that would statically move a point by ten
//!   times the body's size is not physical; d_j = 0 leaves only the finiteness check);
//! - the displayed node rows grouped by 8 nodes so that one state entry multiplies 3 × 8
//!   contiguous values per row kind (no horizontal sums; the warp runs on 8 nodes at once):
//!   displacement rows in single precision, rotation rows in single precision or, for large
//!   sets, 16-bit fixed point ([`DisplayRowFormat`]): 1/2 or 3/8 of the bytes of f64 rows.

use crate::covariance::{gate_variances, row_std};
use crate::simd;
use crate::RuntimeError;
use crokf_formats::{InputKind, Matrix, Model};

/// sqrt(diag(C P Cᵀ)) for every read-out row C, for one phase and one covariance.
#[derive(Clone, Debug)]
pub(crate) struct PhaseStd {
    /// 3 per sensor, m.
    pub(crate) sensors: Vec<f64>,
    /// 3n per node set, m.
    pub(crate) nodes: Vec<Vec<f64>>,
}

/// An active measurement channel of a phase.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ActiveChannel {
    /// Index into the model's measurement channels.
    pub(crate) channel: usize,
    /// Position of its sensor in the phase's `phase_sensors`.
    pub(crate) slot: usize,
    /// x, y or z (0, 1, 2).
    pub(crate) component: usize,
    /// The sensor's `every`.
    pub(crate) every: u64,
    /// g_j = (H Q Hᵀ)_jj, m² per step.
    pub(crate) variance_growth: f64,
}

/// A validated model plus everything derived from it at load (see the module docs).
#[derive(Clone, Debug)]
pub struct PreparedModel {
    pub(crate) model: Model,
    pub(crate) r: usize,
    /// Per load group: the input channel of each world component.
    pub(crate) load_channels: Vec<[Option<usize>; 3]>,
    /// Per measurement channel: (sensor, component).
    pub(crate) channel: Vec<(usize, usize)>,
    /// Per measurement channel: its sensor's `every` (base steps between markers).
    pub(crate) every: Vec<u64>,
    /// Per phase: sensors with at least one active channel (a sensor's slot is its position
    /// here).
    pub(crate) phase_sensors: Vec<Vec<usize>>,
    /// Per phase, in the order of `kalman.phases[p].measured`: each active channel with its
    /// sensor slot and component.
    pub(crate) active: Vec<Vec<ActiveChannel>>,
    /// Per phase: the rows [C_s; W_s] (6 per sensor of `phase_sensors[p]`, r columns), stacked
    /// and transposed (r × 6·sensors) so that the update evaluates them in one product.
    pub(crate) phase_rows_t: Vec<simd::Columns>,
    /// The load groups' rotation rows W_g stacked (3 per group), by columns.
    pub(crate) load_rows_t: simd::Columns,
    /// F (r × r), G (r × m) and per phase K_p (r × active channels), by columns, for
    /// [`simd::matvec_t`].
    pub(crate) transition_t: simd::Columns,
    pub(crate) input_t: simd::Columns,
    pub(crate) gain_t: Vec<simd::Columns>,
    /// Largest number of active channels in a phase.
    pub(crate) max_measured: usize,
    pub(crate) std_prior: Vec<PhaseStd>,
    pub(crate) std_posterior: Vec<PhaseStd>,
    /// Per phase, per active channel: (H P⁻ Hᵀ)_jj + R_jj, m².
    pub(crate) innovation_variance: Vec<Vec<f64>>,
    /// Length scale L, m.
    pub(crate) length_scale: f64,
    /// Per input channel: the largest plausible |u_j| (N, or a scale for gravity; may be ∞).
    pub(crate) input_bound: Vec<f64>,
    /// The largest plausible |y|, m.
    pub(crate) measurement_bound: f64,
    pub(crate) display: Vec<simd::DisplayRows>,
    /// Per state index k: 2^(−e_k), the scale of the 16-bit display displacement rows
    /// ([`simd::fixed16_exponents`]), exact in f32.
    pub(crate) displacement_scale: Vec<f32>,
    /// The same for the 16-bit display rotation rows.
    pub(crate) rotation_scale: Vec<f32>,
    /// The co-rotational tier (docs/design.md §10), when the model has one.
    pub(crate) tier: Option<crate::tier::TierModel>,
    /// The contact region arranged for the contact step (docs/contact.md).
    pub(crate) contact: Option<crate::contact::PreparedContact>,
}

/// Dense row-major n×n product.
fn square_product(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            if aik != 0.0 {
                for j in 0..n {
                    c[i * n + j] += aik * b[k * n + j];
                }
            }
        }
    }
    c
}

/// Σ_{i<2^20} Fⁱ G (r×m, row-major) by doubling: X ← X + A X, A ← A², twenty times.
fn step_response_sum(f: &Matrix, g: &Matrix) -> Vec<f64> {
    let (r, m) = (f.rows as usize, g.cols as usize);
    let mut x = g.data.clone();
    let mut a = f.data.clone();
    for _ in 0..20 {
        let mut ax = vec![0.0; r * m];
        for i in 0..r {
            for k in 0..r {
                let aik = a[i * r + k];
                if aik != 0.0 {
                    for j in 0..m {
                        ax[i * m + j] += aik * x[k * m + j];
                    }
                }
            }
        }
        x.iter_mut().zip(&ax).for_each(|(v, d)| *v += d);
        a = square_product(&a, &a, r);
        if !x.iter().all(|v| v.is_finite()) {
            break;
        }
    }
    x
}

/// Single-precision display rows above this size (bytes) are stored in 16 bits under
/// [`DisplayRowFormat::Auto`]: half of a 2 MiB L2 cache, beyond which the read-out streams its
/// rows from L3 or memory and is bound by bandwidth.
pub const COMPACT_ABOVE_BYTES: usize = 1 << 20;

/// How the display read-out ([`crate::Estimator::node_displacements`]) stores a node set's
/// rows, chosen at load.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DisplayRowFormat {
    /// [`DisplayRowFormat::Fixed16`] for sets whose single-precision rows (24·r bytes per
    /// node) exceed [`COMPACT_ABOVE_BYTES`], [`DisplayRowFormat::Single`] otherwise.
    #[default]
    Auto,
    /// Displacement and rotation rows in single precision (24·r bytes per node; error a few
    /// 1e-7 of the largest displacement, measured in `tests/readout.rs`).
    Single,
    /// Rotation rows in 16-bit fixed point with a power-of-two scale per state index (18·r
    /// bytes per node). Each entry is off by at most max_i |W_ik| / 32767, so ω by at most
    /// Σ_k |x_k| max_i |W_ik| / 32767 and the displacement by about half that times |u|
    /// (docs/design.md §5: δ(R̃u) ≈ ½ δω × u for small rotations); measured in
    /// `tests/readout.rs`. Displacement rows in single precision.
    Compact,
    /// Displacement rows in 16-bit fixed point too (12·r bytes per node): each entry off by
    /// at most max_i |C_ik| / 32767 (the column's largest over all displayed sets), so a node's
    /// u by at most √3 Σ_k |x_k| max_i |C_ik| / 32767, plus the rotation rows' part above;
    /// measured in `tests/readout.rs`.
    Fixed16,
}

impl PreparedModel {
    /// Validates `model` and derives the shared data (see the module docs), with
    /// [`DisplayRowFormat::Auto`].
    pub fn new(model: Model) -> Result<PreparedModel, RuntimeError> {
        Self::with_display_format(model, DisplayRowFormat::Auto)
    }

    /// [`PreparedModel::new`] with the display rows stored as `display_format` says.
    pub fn with_display_format(
        model: Model,
        display_format: DisplayRowFormat,
    ) -> Result<PreparedModel, RuntimeError> {
        model.validate()?;
        let r = model.r();
        let mut load_channels = vec![[None; 3]; model.loads.len()];
        for (j, ch) in model.inputs.iter().enumerate() {
            if let InputKind::Load { load, component } = ch.kind {
                load_channels[load as usize][component as usize] = Some(j);
            }
        }
        let channel: Vec<(usize, usize)> = model
            .measurements
            .iter()
            .map(|c| (c.sensor as usize, c.component as usize))
            .collect();
        let every: Vec<u64> = channel
            .iter()
            .map(|&(s, _)| model.sensors[s].every as u64)
            .collect();
        let phase_sensors: Vec<Vec<usize>> = model
            .kalman
            .phases
            .iter()
            .map(|ph| {
                let mut s: Vec<usize> =
                    ph.measured.iter().map(|&j| channel[j as usize].0).collect();
                s.sort_unstable();
                s.dedup();
                s
            })
            .collect();
        let phase_rows_t: Vec<simd::Columns> = phase_sensors
            .iter()
            .map(|sensors: &Vec<usize>| {
                let mut rows = Vec::with_capacity(6 * r * sensors.len());
                for &s in sensors {
                    rows.extend_from_slice(&model.sensors[s].displacement_rows.data);
                    rows.extend_from_slice(&model.sensors[s].rotation_rows.data);
                }
                simd::Columns::from_row_major(&rows, 6 * sensors.len(), r)
            })
            .collect();
        let load_rows: Vec<f64> = model
            .loads
            .iter()
            .flat_map(|g| g.rotation_rows.data.iter().copied())
            .collect();
        let load_rows_t = simd::Columns::from_row_major(&load_rows, 3 * model.loads.len(), r);
        let transition_t = simd::Columns::from_row_major(&model.transition.data, r, r);
        let input_t = simd::Columns::from_row_major(&model.input.data, r, model.inputs.len());
        let gain_t = model
            .kalman
            .phases
            .iter()
            .map(|ph| simd::Columns::from_row_major(&ph.gain.data, r, ph.measured.len()))
            .collect();
        let max_measured = model
            .kalman
            .phases
            .iter()
            .map(|p| p.measured.len())
            .max()
            .unwrap_or(0);
        let std_of = |p: &Matrix| {
            let mut sensors = Vec::with_capacity(3 * model.sensors.len());
            for s in &model.sensors {
                row_std(&s.displacement_rows.data, r, p, &mut sensors);
            }
            let nodes = model
                .node_sets
                .iter()
                .map(|set| {
                    let mut v = Vec::with_capacity(set.displacement_rows.rows as usize);
                    row_std(&set.displacement_rows.data, r, p, &mut v);
                    v
                })
                .collect();
            PhaseStd { sensors, nodes }
        };
        let std_prior = model
            .kalman
            .phases
            .iter()
            .map(|ph| std_of(&ph.prior_covariance))
            .collect();
        let std_posterior = model
            .kalman
            .phases
            .iter()
            .map(|ph| std_of(&ph.posterior_covariance))
            .collect();
        let h_row = |j: usize| {
            let (s, c) = channel[j];
            model.sensors[s].displacement_rows.row(c)
        };
        let (innovation_variance, variance_growth) =
            gate_variances(&model.kalman, channel.len(), h_row);

        let active = model
            .kalman
            .phases
            .iter()
            .zip(&phase_sensors)
            .map(|(ph, sensors)| {
                ph.measured
                    .iter()
                    .map(|&j| {
                        let (s, c) = channel[j as usize];
                        ActiveChannel {
                            channel: j as usize,
                            slot: sensors.partition_point(|&t| t < s),
                            component: c,
                            every: every[j as usize],
                            variance_growth: variance_growth[j as usize],
                        }
                    })
                    .collect()
            })
            .collect();

        // Plausibility bounds.
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut extend = |p: &[f64]| {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        };
        for s in &model.sensors {
            extend(&s.position);
        }
        for set in &model.node_sets {
            for p in set.rest_positions.data.chunks_exact(3) {
                extend(p);
            }
        }
        let diagonal = (0..3).map(|c| (hi[c] - lo[c]).powi(2)).sum::<f64>().sqrt();
        let sigma_max = model
            .kalman
            .measurement_variance
            .iter()
            .fold(0.0f64, |a, &v| a.max(v.sqrt()));
        let length_scale = if diagonal.is_finite() {
            diagonal.max(1e3 * sigma_max)
        } else {
            1e3 * sigma_max
        };
        let measurement_bound = if length_scale > 0.0 {
            10.0 * length_scale
        } else {
            f64::INFINITY
        };
        let response = step_response_sum(&model.transition, &model.input);
        let m = model.inputs.len();
        let mut reach = vec![0.0f64; m];
        let mut col = vec![0.0; r];
        for (j, d) in reach.iter_mut().enumerate() {
            for (i, c) in col.iter_mut().enumerate() {
                *c = response[i * m + j];
            }
            let rows = model
                .sensors
                .iter()
                .map(|s| &s.displacement_rows)
                .chain(model.node_sets.iter().map(|n| &n.displacement_rows));
            for mat in rows {
                for i in 0..mat.rows as usize {
                    let v: f64 = mat.row(i).iter().zip(&col).map(|(a, b)| a * b).sum();
                    *d = d.max(v.abs());
                }
            }
        }
        let input_bound = reach
            .iter()
            .map(|&d| {
                let b = 10.0 * length_scale / d;
                if d > 0.0 && b.is_finite() && b > 0.0 {
                    b
                } else {
                    f64::INFINITY
                }
            })
            .collect();

        // Per column and row kind: the largest |entry| over the displayed sets, for the 16-bit
        // rows' exponents.
        let columns_max = |rows: fn(&crokf_formats::NodeSet) -> &Matrix| {
            let mut m = vec![0.0f64; r];
            for set in &model.node_sets {
                for row in rows(set).data.chunks_exact(r.max(1)) {
                    for (m, v) in m.iter_mut().zip(row) {
                        *m = m.max(v.abs());
                    }
                }
            }
            simd::fixed16_exponents(&m)
        };
        let displacement_exponents = columns_max(|set| &set.displacement_rows);
        let rotation_exponents = columns_max(|set| &set.rotation_rows);
        let scale = |e: &[i32]| e.iter().map(|&e| 2f32.powi(-e)).collect::<Vec<f32>>();
        let (displacement_scale, rotation_scale) =
            (scale(&displacement_exponents), scale(&rotation_exponents));
        let display = model
            .node_sets
            .iter()
            .map(|set| {
                let n = set.node_tags.len();
                let large = 6 * r * n * 4 > COMPACT_ABOVE_BYTES;
                let (displacement16, rotation16) = match display_format {
                    DisplayRowFormat::Single => (false, false),
                    DisplayRowFormat::Compact => (false, true),
                    DisplayRowFormat::Fixed16 => (true, true),
                    DisplayRowFormat::Auto => (large, large),
                };
                simd::DisplayRows::new(
                    n,
                    r,
                    |i| set.displacement_rows.row(i),
                    |i| set.rotation_rows.row(i),
                    set.rotation_rows.data.iter().any(|&v| v != 0.0),
                    simd::Fixed16 {
                        displacement: displacement16.then_some(&displacement_exponents[..]),
                        rotation: rotation16.then_some(&rotation_exponents[..]),
                    },
                )
            })
            .collect();

        let tier = model
            .tier
            .as_ref()
            .map(|t| crate::tier::TierModel::new(&model, t));
        Ok(PreparedModel {
            tier,
            contact: model
                .contact
                .as_ref()
                .map(|c| crate::contact::PreparedContact::new(c, model.theta)),
            r,
            load_channels,
            channel,
            every,
            phase_sensors,
            active,
            phase_rows_t,
            load_rows_t,
            transition_t,
            input_t,
            gain_t,
            max_measured,
            std_prior,
            std_posterior,
            innovation_variance,
            length_scale,
            input_bound,
            measurement_bound,
            display,
            displacement_scale,
            rotation_scale,
            model,
        })
    }

    /// The co-rotational tier, when the model has one (docs/design.md §10; feature
    /// `internals`).
    #[cfg(feature = "internals")]
    pub fn tier(&self) -> Option<&crate::tier::TierModel> {
        self.tier.as_ref()
    }

    /// Why the co-rotational tier failed the compiler's own check, when the scene accepted it
    /// all the same (format v10, `CorotationalTier::failed_check`): its estimates can be as far
    /// off as the reason says. None when the tier passed or the model has none.
    pub fn tier_failed_check(&self) -> Option<&str> {
        self.model.tier_failed_check()
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Length scale L of the plausibility bounds, m.
    pub fn length_scale(&self) -> f64 {
        self.length_scale
    }

    /// Largest plausible |u_j| per input channel (N, or a scale for gravity; ∞ = finiteness
    /// only).
    pub fn input_bounds(&self) -> &[f64] {
        &self.input_bound
    }

    /// Per phase, per active channel (in the order of `kalman.phases[p].measured`): the
    /// innovation variance (H P⁻ Hᵀ + R)_jj the gate compares with, m².
    pub fn innovation_variances(&self) -> &[Vec<f64>] {
        &self.innovation_variance
    }

    /// Largest plausible |y| of a measurement, m.
    pub fn measurement_bound(&self) -> f64 {
        self.measurement_bound
    }
}
