//! Consistency and coverage of a filtered run (docs/design.md §11): normalised innovation
//! squared (NIS), normalised estimation error squared (NEES) at the tip marker, the fraction of
//! displayed-node errors inside ±2σ, and the tip's error and σ along the trajectory.
//!
//! Covariances come from the model file's stored steady-state (periodic) covariances, P⁻_p and
//! P_p of phase p (local frame, r×r), mapped to an output block by its rows C (3×r):
//! Σ_local = C P Cᵀ; to the world frame by the warp at the current estimate,
//! Σ_world = R̃(ω) Σ_local R̃(ω)ᵀ (first order: the dependence of ω on x is neglected, like the
//! runtime's gate).
//!
//! - NIS_k = ν_kᵀ S_k⁻¹ ν_k with ν_k = y_k − ŷ⁻_k (world frame, active channels of the phase)
//!   and S_k = R̃ (H P⁻_p Hᵀ) R̃ᵀ + R (per-sensor rotation of the 3×3 blocks).
//!   For a consistent filter Σ_k NIS_k ~ χ²(Σ_k m_k).
//! - NEES_k = e_kᵀ Σ_k⁻¹ e_k at the tip marker, e_k = û_tip − u_tip,ref (3 per step),
//!   Σ_k = R̃ C_tip P_p C_tipᵀ R̃ᵀ. For a consistent filter Σ_k NEES_k ~ χ²(3N).
//! - Averages ANIS = Σ NIS / Σ m and ANEES = Σ NEES / 3N with two-sided 95 % bounds
//!   χ²_{0.025}(D)/D, χ²_{0.975}(D)/D (Wilson–Hilferty). The bounds assume independent samples;
//!   a filter whose model error is coloured in time exceeds them even when its σ cover the
//!   error, which is why coverage is reported beside them.

use crokf_formats as fmt;
use crokf_runtime::warp::Warp;
use nalgebra::{DMatrix, Matrix3};

/// A χ² statistic accumulated over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChiSquare {
    /// Σ of the normalised squares.
    pub sum: f64,
    /// Degrees of freedom D (Σ of the sample dimensions).
    pub dof: usize,
}

impl ChiSquare {
    /// Σ / D (1 for a consistent filter); NaN without samples.
    pub fn mean(&self) -> f64 {
        if self.dof == 0 {
            f64::NAN
        } else {
            self.sum / self.dof as f64
        }
    }

    /// Two-sided 95 % bounds of the mean, χ²_{0.025}(D)/D and χ²_{0.975}(D)/D.
    pub fn bounds(&self) -> (f64, f64) {
        let d = self.dof as f64;
        (
            chi_square_quantile(d, -Z_975) / d,
            chi_square_quantile(d, Z_975) / d,
        )
    }

    /// Whether the mean lies inside [`ChiSquare::bounds`].
    pub fn inside(&self) -> bool {
        let (lo, hi) = self.bounds();
        let m = self.mean();
        m >= lo && m <= hi
    }
}

/// Standard normal 97.5 % quantile.
const Z_975: f64 = 1.959_963_984_540_054;

/// Wilson–Hilferty approximation of the χ²(d) quantile at the normal quantile z:
/// d (1 − 2/(9d) + z √(2/(9d)))³ (relative error < 1e-3 from d ≈ 10, and the sums here have
/// d ≥ 100).
pub fn chi_square_quantile(d: f64, z: f64) -> f64 {
    if d <= 0.0 {
        return f64::NAN;
    }
    let c = 2.0 / (9.0 * d);
    d * (1.0 - c + z * c.sqrt()).powi(3).max(0.0)
}

/// One sample of the tip trace: time, world error (estimate − reference) and world σ per
/// component (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TipSample {
    /// t, s.
    pub time: f64,
    /// û − u_ref, m.
    pub error: [f64; 3],
    /// σ, m (posterior, world frame).
    pub sigma: [f64; 3],
}

/// Consistency figures of one filtered run.
#[derive(Clone, Debug, Default)]
pub struct Consistency {
    /// NIS over the run.
    pub nis: ChiSquare,
    /// NEES at the tip marker over the run.
    pub nees_tip: ChiSquare,
    /// Fraction of displayed-node error components with |e| ≤ 2σ, σ the runtime's read-out
    /// (`Estimator::node_std`, local frame).
    pub coverage_runtime: f64,
    /// Same with σ rotated to the world frame, sqrt(diag(R̃ Σ_local R̃ᵀ)).
    pub coverage_world: f64,
    /// The tip trace (empty without a tip sensor).
    pub tip: Vec<TipSample>,
}

/// The model's output covariance blocks per phase, precomputed once per order.
pub(super) struct Blocks {
    /// Per phase: prior 3×3 blocks between sensors, `prior[p][s][t]`.
    prior: Vec<Vec<Vec<Matrix3<f64>>>>,
    /// Per phase: posterior 3×3 block of each sensor.
    sensor_post: Vec<Vec<Matrix3<f64>>>,
    /// Per phase: posterior 3×3 block of each displayed node (in the comparison's display
    /// order).
    node_post: Vec<Vec<Matrix3<f64>>>,
    /// Per displayed node: (set, index) into the model's node sets.
    display: Vec<(usize, usize)>,
}

/// C P (3×r) for the 3 rows of `block` in `m` (row-major 3k×r) and P (r×r row-major).
fn block_times_p(m: &fmt::Matrix, block: usize, p: &[f64], r: usize) -> Vec<[f64; 3]> {
    let mut out = vec![[0.0; 3]; r];
    for (c, row) in (0..3).map(|c| (c, &m.data[(3 * block + c) * r..(3 * block + c + 1) * r])) {
        for (i, &ci) in row.iter().enumerate() {
            if ci == 0.0 {
                continue;
            }
            let prow = &p[i * r..(i + 1) * r];
            for (j, &pij) in prow.iter().enumerate() {
                out[j][c] += ci * pij;
            }
        }
    }
    out
}

/// (C_a P) C_bᵀ as a 3×3 matrix.
fn close(cp: &[[f64; 3]], m: &fmt::Matrix, block: usize, r: usize) -> Matrix3<f64> {
    let mut out = Matrix3::zeros();
    for d in 0..3 {
        let row = &m.data[(3 * block + d) * r..(3 * block + d + 1) * r];
        for (j, &cj) in row.iter().enumerate() {
            if cj == 0.0 {
                continue;
            }
            for c in 0..3 {
                out[(c, d)] += cp[j][c] * cj;
            }
        }
    }
    out
}

impl Blocks {
    /// Blocks of `model` for the displayed nodes `display` ((node set, index in set)).
    pub(super) fn new(model: &fmt::Model, display: &[(usize, usize)]) -> Self {
        let r = model.r();
        let ns = model.sensors.len();
        let mut prior = Vec::new();
        let mut sensor_post = Vec::new();
        let mut node_post = Vec::new();
        for phase in &model.kalman.phases {
            let pp = &phase.prior_covariance.data;
            let po = &phase.posterior_covariance.data;
            let mut blocks = vec![vec![Matrix3::zeros(); ns]; ns];
            let mut post = Vec::with_capacity(ns);
            for (s, sensor) in model.sensors.iter().enumerate() {
                let cp = block_times_p(&sensor.displacement_rows, 0, pp, r);
                for (t, other) in model.sensors.iter().enumerate() {
                    blocks[s][t] = close(&cp, &other.displacement_rows, 0, r);
                }
                let cp = block_times_p(&sensor.displacement_rows, 0, po, r);
                post.push(close(&cp, &sensor.displacement_rows, 0, r));
            }
            prior.push(blocks);
            sensor_post.push(post);
            node_post.push(
                display
                    .iter()
                    .map(|&(set, i)| {
                        let rows = &model.node_sets[set].displacement_rows;
                        close(&block_times_p(rows, i, po, r), rows, i, r)
                    })
                    .collect(),
            );
        }
        Blocks {
            prior,
            sensor_post,
            node_post,
            display: display.to_vec(),
        }
    }
}

/// R̃(ω) as a matrix.
fn warp_matrix(w: &Warp) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for c in 0..3 {
        let mut e = [0.0; 3];
        e[c] = 1.0;
        let col = w.warp(&e);
        for (i, v) in col.iter().enumerate() {
            m[(i, c)] = *v;
        }
    }
    m
}

/// 3 rows of block `block` of `m` times x.
fn rows3(m: &fmt::Matrix, block: usize, x: &[f64]) -> [f64; 3] {
    let r = x.len();
    std::array::from_fn(|c| {
        let row = &m.data[(3 * block + c) * r..(3 * block + c + 1) * r];
        row.iter().zip(x).map(|(a, b)| a * b).sum()
    })
}

/// Accumulates [`Consistency`] step by step.
pub(super) struct Accumulator<'a> {
    blocks: &'a Blocks,
    model: &'a fmt::Model,
    tip: Option<usize>,
    out: Consistency,
    inside_runtime: usize,
    inside_world: usize,
    total: usize,
}

impl<'a> Accumulator<'a> {
    pub(super) fn new(blocks: &'a Blocks, model: &'a fmt::Model, tip: Option<usize>) -> Self {
        Accumulator {
            blocks,
            model,
            tip,
            out: Consistency::default(),
            inside_runtime: 0,
            inside_world: 0,
            total: 0,
        }
    }

    /// After `predict`: the innovation of the active channels `active` (indices into the
    /// model's measurements) of phase `phase`, with predicted world values `predicted` (all
    /// channels) and measurements `y`, at the prior state `x`.
    pub(super) fn innovation(
        &mut self,
        phase: usize,
        active: &[u32],
        predicted: &[f64],
        y: &[Option<f64>],
        x: &[f64],
    ) {
        let used: Vec<usize> = active
            .iter()
            .map(|&j| j as usize)
            .filter(|&j| y[j].is_some())
            .collect();
        if used.is_empty() {
            return;
        }
        let warps: Vec<Matrix3<f64>> = self
            .model
            .sensors
            .iter()
            .map(|s| warp_matrix(&Warp::new(&rows3(&s.rotation_rows, 0, x))))
            .collect();
        let m = used.len();
        let mut s_mat = DMatrix::<f64>::zeros(m, m);
        let mut nu = DMatrix::<f64>::zeros(m, 1);
        for (a, &ja) in used.iter().enumerate() {
            let ch_a = self.model.measurements[ja];
            let (sa, ca) = (ch_a.sensor as usize, ch_a.component as usize);
            nu[(a, 0)] = y[ja].unwrap_or(0.0) - predicted[ja];
            for (b, &jb) in used.iter().enumerate() {
                let ch_b = self.model.measurements[jb];
                let (sb, cb) = (ch_b.sensor as usize, ch_b.component as usize);
                let block = warps[sa] * self.blocks.prior[phase][sa][sb] * warps[sb].transpose();
                s_mat[(a, b)] = block[(ca, cb)];
            }
            s_mat[(a, a)] += self.model.kalman.measurement_variance[ja];
        }
        if let Some(chol) = s_mat.cholesky() {
            let z = chol.solve(&nu);
            self.out.nis.sum += (nu.transpose() * z)[(0, 0)];
            self.out.nis.dof += m;
        }
    }

    /// After `update`: the tip's world estimate `tip_estimate` and reference `tip_reference`,
    /// the displayed nodes' world estimates and references (3 per node) and the runtime's σ
    /// read-out for them, at the posterior state `x` of phase `phase`, time `time`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn posterior(
        &mut self,
        phase: usize,
        time: f64,
        x: &[f64],
        tip_estimate: &[f64],
        tip_reference: &[f64],
        display: &[f64],
        reference: &[f64],
        runtime_std: &[f64],
    ) {
        if let Some(t) = self.tip {
            let w = warp_matrix(&Warp::new(&rows3(
                &self.model.sensors[t].rotation_rows,
                0,
                x,
            )));
            let sigma = w * self.blocks.sensor_post[phase][t] * w.transpose();
            let e = nalgebra::Vector3::from_fn(|c, _| tip_estimate[c] - tip_reference[c]);
            if let Some(inv) = sigma.try_inverse() {
                self.out.nees_tip.sum += (e.transpose() * inv * e)[(0, 0)];
                self.out.nees_tip.dof += 3;
            }
            self.out.tip.push(TipSample {
                time,
                error: [e[0], e[1], e[2]],
                sigma: std::array::from_fn(|c| sigma[(c, c)].max(0.0).sqrt()),
            });
        }
        for (j, &(set, i)) in self.blocks.display.iter().enumerate() {
            let rot = &self.model.node_sets[set].rotation_rows;
            let w = warp_matrix(&Warp::new(&rows3(rot, i, x)));
            let sigma = w * self.blocks.node_post[phase][j] * w.transpose();
            for c in 0..3 {
                let e = (display[3 * j + c] - reference[3 * j + c]).abs();
                self.inside_runtime += (e <= 2.0 * runtime_std[3 * j + c]) as usize;
                self.inside_world += (e <= 2.0 * sigma[(c, c)].max(0.0).sqrt()) as usize;
                self.total += 1;
            }
        }
    }

    pub(super) fn finish(mut self) -> Consistency {
        let total = self.total.max(1) as f64;
        self.out.coverage_runtime = self.inside_runtime as f64 / total;
        self.out.coverage_world = self.inside_world as f64 / total;
        self.out
    }
}
