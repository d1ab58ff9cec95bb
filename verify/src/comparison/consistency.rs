// Over 800 lines, one job: the consistency statistics of a filtered run (100 lines are its tests).
//! Consistency and coverage of a filtered run (docs/design.md §11.3): normalised innovation
//! squared (NIS), normalised estimation error squared (NEES) at the tip marker, the fraction of
//! displayed-node errors inside ±2σ, and the tip's error and σ along the trajectory. One
//! implementation for both tiers: the warped rows of `crokf-verify report`, the co-rotational
//! tier's row, and the `nonlinear_filter` example all go through [`ConsistencyAccumulator`].
//!
//! Covariances come from the model file's stored steady-state (periodic) covariances, P⁻_p and
//! P_p of phase p, of the filter the runtime uses at that step ([`FilterBlocks`]), mapped to an
//! output block by its rows C (3×r): Σ = C P_qq Cᵀ (P_qq the r×r block of P on the coordinates
//! the rows read).
//! - Warped tier (docs/design.md §5–6): one filter, P on the balanced state x (r×r); Σ is in the
//!   local frame and is rotated to the world frame by the warp at the current estimate,
//!   Σ_world = R̃(ω) Σ R̃(ω)ᵀ, ω = W x (first order: the dependence of ω on x is neglected,
//!   like the runtime's gate).
//! - Co-rotational tier (docs/design.md §10, §11.4–11.5): P on s = (q, q̇, q̈, f[, ḟ]) (n×n),
//!   C the world-frame rows V_s of q, so Σ is already in the world frame (R̃ = I). The filter
//!   is the one of the gain schedule in use ([`Estimator::tier_filter`]): after `predict` the
//!   one nearest to the prior q⁻ (whose P⁻ the runtime's gate reads as the innovation
//!   variance), after `update` the one whose gain gave the posterior (whose P the runtime's σ
//!   read-outs use). While the tier filter carries its own covariance (an active channel
//!   missing or gated, docs/design.md §11.11; `Estimator::tier_covariance`), that P⁻ and P
//!   instead, as the runtime's gate and read-outs use them.
//!
//! Statistics:
//! - NIS_k = ν_kᵀ S_k⁻¹ ν_k with ν_k = y_k − ŷ⁻_k (world frame, the present measurements of
//!   the phase's active channels), S_k = R̃ (H P⁻_p Hᵀ) R̃ᵀ + R (per-sensor rotation of the
//!   3×3 blocks). For a consistent filter Σ_k NIS_k ~ χ²(Σ_k m_k).
//! - NEES_k = e_kᵀ Σ_k⁻¹ e_k at the tip marker, e_k = û_tip − u_tip,ref (m, 3 per step),
//!   Σ_k = R̃ C_tip P_p C_tipᵀ R̃ᵀ. For a consistent filter Σ_k NEES_k ~ χ²(3N).
//! - Averages ANIS = Σ NIS / Σ m and ANEES = Σ NEES / 3N with two-sided 95 % bounds
//!   χ²_{0.025}(D)/D, χ²_{0.975}(D)/D (Wilson–Hilferty). The bounds assume independent samples;
//!   a filter whose model error is coloured in time exceeds them even when its σ cover the
//!   error, which is why coverage is reported beside them.
//! - Outliers: active innovations with ν_j² > 25 S_jj (beyond 5σ of their own variance: what
//!   the runtime's 5σ gate would skip with every channel accepted at its period).
//! - Over N independent runs (Monte Carlo: the same scenario, independent marker noise),
//!   [`Ensemble`]: at each step k the N-run average of NIS_k or NEES_k, which for a consistent
//!   filter is χ²(N d_k)/N (d_k the dimension of one run's sample), with its two-sided 95 %
//!   bounds; the fraction of steps inside them is ≈ 95 % for a consistent filter, and below /
//!   above tells a conservative from an overconfident one (Bar-Shalom, Li & Kirubarajan 2001,
//!   §5.4.2). The runs are independent of each other even where one run's samples are
//!   correlated in time, so these bounds hold where the single-run ones above do not.

use crokf_formats as fmt;
use crokf_runtime::warp::Warp;
use crokf_runtime::{Estimator, RuntimeError};
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

    /// Adds another sample's sum and degrees of freedom.
    pub fn add(&mut self, other: ChiSquare) {
        self.sum += other.sum;
        self.dof += other.dof;
    }
}

/// A per-step χ² statistic (NIS_k or NEES_k) summed over N independent runs of one scenario
/// (module docs, Bar-Shalom, Li & Kirubarajan 2001, §5.4.2): step k holds Σ_i ε_{i,k} with
/// N d_k degrees of freedom, so its mean is the N-run average per degree of freedom and its
/// [`ChiSquare::bounds`] are the 95 % bounds of χ²(N d_k)/(N d_k).
#[derive(Clone, Debug, Default)]
pub struct Ensemble {
    steps: Vec<ChiSquare>,
    runs: usize,
}

/// Where the steps of an [`Ensemble`] lie against their 95 % bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFractions {
    /// Steps with a sample (d_k > 0).
    pub steps: usize,
    /// Fractions below the lower bound (σ too large), inside, above the upper bound (σ too
    /// small); they sum to 1 (NaN without steps).
    pub below: f64,
    /// See `below`.
    pub inside: f64,
    /// See `below`.
    pub above: f64,
}

impl StepFractions {
    /// `below / inside / above` in percent with one decimal (`4.0 / 94.2 / 1.8`), `—` without
    /// steps: the table cell of the per-segment tables.
    pub fn percentages(&self) -> String {
        if self.steps == 0 {
            "—".to_owned()
        } else {
            format!(
                "{:.1} / {:.1} / {:.1}",
                100.0 * self.below,
                100.0 * self.inside,
                100.0 * self.above
            )
        }
    }
}

/// Runs of unequal length given to [`Ensemble::add`].
#[derive(Debug, thiserror::Error)]
#[error("ensemble of runs with {expected} steps: a run with {found} steps")]
pub struct RunLengthMismatch {
    /// Steps of the runs added before.
    pub expected: usize,
    /// Steps of the run refused.
    pub found: usize,
}

impl Ensemble {
    /// Adds one run's per-step statistics (`Consistency::nis_steps` or `nees_tip_steps`); every
    /// run of an ensemble has the same steps.
    pub fn add(&mut self, run: &[ChiSquare]) -> Result<(), RunLengthMismatch> {
        if self.runs == 0 {
            self.steps = vec![ChiSquare::default(); run.len()];
        } else if run.len() != self.steps.len() {
            return Err(RunLengthMismatch {
                expected: self.steps.len(),
                found: run.len(),
            });
        }
        for (acc, &step) in self.steps.iter_mut().zip(run) {
            acc.add(step);
        }
        self.runs += 1;
        Ok(())
    }

    /// Runs added.
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// Steps of each run (0 before the first run).
    pub fn steps(&self) -> usize {
        self.steps.len()
    }

    /// Σ over runs and steps (its mean is the ensemble's average NIS or NEES; its single-run
    /// style bounds assume samples independent in time and are not used for a verdict).
    pub fn total(&self) -> ChiSquare {
        self.steps.iter().fold(ChiSquare::default(), |mut t, &s| {
            t.add(s);
            t
        })
    }

    /// Where the steps' N-run averages lie against their 95 % bounds.
    pub fn fractions(&self) -> StepFractions {
        self.fractions_in(0..self.steps.len())
    }

    /// [`Ensemble::fractions`] over the steps `steps` only (a segment of the run; clipped to
    /// the run's steps).
    pub fn fractions_in(&self, steps: std::ops::Range<usize>) -> StepFractions {
        let end = steps.end.min(self.steps.len());
        let start = steps.start.min(end);
        let (mut below, mut inside, mut above) = (0usize, 0usize, 0usize);
        for s in self.steps[start..end].iter().filter(|s| s.dof > 0) {
            let (lo, hi) = s.bounds();
            let m = s.mean();
            if m < lo {
                below += 1;
            } else if m > hi {
                above += 1;
            } else {
                inside += 1;
            }
        }
        let steps = below + inside + above;
        let n = steps as f64;
        StepFractions {
            steps,
            below: below as f64 / n,
            inside: inside as f64 / n,
            above: above as f64 / n,
        }
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

/// The 2σ coverage of one step: displayed-node error components inside ±2σ (runtime σ) out of
/// all of them; summed over steps or runs by [`CoverageCount::add`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CoverageCount {
    /// Components with |e| ≤ 2σ.
    pub inside: usize,
    /// Components counted.
    pub total: usize,
}

impl CoverageCount {
    /// inside / total; NaN without components.
    pub fn fraction(&self) -> f64 {
        if self.total == 0 {
            f64::NAN
        } else {
            self.inside as f64 / self.total as f64
        }
    }

    /// Adds another count.
    pub fn add(&mut self, other: CoverageCount) {
        self.inside += other.inside;
        self.total += other.total;
    }
}

/// Consistency figures of one filtered run.
#[derive(Clone, Debug, Default)]
pub struct Consistency {
    /// NIS over the run.
    pub nis: ChiSquare,
    /// NEES at the tip marker over the run.
    pub nees_tip: ChiSquare,
    /// Fraction of displayed-node error components with |e| ≤ 2σ, σ the runtime's read-out
    /// (`Estimator::node_std`: local frame on the warped tier, world frame on the
    /// co-rotational tier).
    pub coverage_runtime: f64,
    /// Same with σ = sqrt(diag(R̃ Σ R̃ᵀ)) in the world frame (on the co-rotational tier R̃ = I
    /// and this equals `coverage_runtime`).
    pub coverage_world: f64,
    /// Active innovations beyond 5σ of their own variance, ν_j² > 25 S_jj, over the run.
    pub outliers: usize,
    /// NIS_k of each step (one entry per [`ConsistencyAccumulator::innovation`]; dof 0 where
    /// the step had no measurement), for [`Ensemble`].
    pub nis_steps: Vec<ChiSquare>,
    /// NEES_k at the tip of each step (one entry per [`ConsistencyAccumulator::posterior`];
    /// dof 0 without a tip), for [`Ensemble`].
    pub nees_tip_steps: Vec<ChiSquare>,
    /// The 2σ coverage (runtime σ) of each step (one entry per
    /// [`ConsistencyAccumulator::posterior`]), for the per-segment figures.
    pub coverage_steps: Vec<CoverageCount>,
    /// The tip trace (empty without a tip sensor).
    pub tip: Vec<TipSample>,
    /// Updates after which the filter carried its own covariance
    /// (`Estimator::tier_covariance`; docs/design.md §11.11), from the run's first update with
    /// an active channel missing or gated on (a lowering of the force σ alone also starts it,
    /// §11.10: not counted, no channel was lost).
    pub own_covariance: usize,
}

/// The output covariance blocks of one stored filter, per phase (m²).
#[derive(Clone, Debug)]
struct Filter {
    /// Per phase: prior 3×3 blocks C_s P⁻_p C_tᵀ between sensors, `prior[p][s][t]`.
    prior: Vec<Vec<Vec<Matrix3<f64>>>>,
    /// Per phase: posterior 3×3 block C_s P_p C_sᵀ of each sensor.
    sensor_post: Vec<Vec<Matrix3<f64>>>,
    /// Per phase: posterior 3×3 block of each displayed node (in the display order).
    node_post: Vec<Vec<Matrix3<f64>>>,
    /// R_jj per measurement channel, m².
    measurement_variance: Vec<f64>,
}

/// A model's stored filters seen through its output rows, precomputed once per model
/// (docs/design.md §11.3): what [`ConsistencyAccumulator`] needs of the covariances of each
/// filter and phase. For a warped model one filter (`Model::kalman`), local frame; for a
/// co-rotational tier the gain schedule, filter 0 = `tier.kalman` (rest) and filter i ≥ 1 =
/// `tier.scheduled[i − 1].kalman` (the numbering of [`Estimator::tier_filter`]), world frame.
#[derive(Clone, Debug)]
pub struct FilterBlocks {
    filters: Vec<Filter>,
    /// Per displayed node: (node set, index in set).
    display: Vec<(usize, usize)>,
    /// True for the co-rotational tier (covariances already in the world frame).
    world: bool,
    /// State dimension the blocks were built for (checked against the estimator's).
    state_dim: usize,
}

/// C P (3×r) for the 3 rows of `block` in `m` (row-major 3k×r) and the leading r×r block of P
/// (row-major, `p.cols` columns: r for the warped tier, n ≥ 3r for the co-rotational tier).
fn block_times_p(m: &fmt::Matrix, block: usize, p: &fmt::Matrix) -> Vec<[f64; 3]> {
    block_times(m, block, &p.data, p.cols as usize)
}

/// [`block_times_p`] for P given as its row-major values with `stride` columns.
fn block_times(m: &fmt::Matrix, block: usize, p: &[f64], stride: usize) -> Vec<[f64; 3]> {
    let r = m.cols as usize;
    let mut out = vec![[0.0; 3]; r];
    for c in 0..3 {
        let row = &m.data[(3 * block + c) * r..(3 * block + c + 1) * r];
        for (i, &ci) in row.iter().enumerate() {
            if ci == 0.0 {
                continue;
            }
            let prow = &p[i * stride..i * stride + r];
            for (j, &pij) in prow.iter().enumerate() {
                out[j][c] += ci * pij;
            }
        }
    }
    out
}

/// (C_a P) C_bᵀ as a 3×3 matrix.
fn close(cp: &[[f64; 3]], m: &fmt::Matrix, block: usize) -> Matrix3<f64> {
    let r = m.cols as usize;
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

/// The 3×3 block C_a P C_bᵀ of the tier filter's own covariance P (`Estimator::tier_covariance`,
/// n × n) for rows `a` (block `ia`) and `b` (block `ib`).
fn live_block(
    a: &fmt::Matrix,
    ia: usize,
    b: &fmt::Matrix,
    ib: usize,
    p: &[f64],
    n: usize,
) -> Matrix3<f64> {
    close(&block_times(a, ia, p, n), b, ib)
}

impl Filter {
    /// The blocks of `kalman` through the sensor rows `sensors` (3×r each) and the node sets'
    /// rows `sets` (3n×r each) for the displayed nodes `display`.
    fn new(
        kalman: &fmt::KalmanGains,
        sensors: &[&fmt::Matrix],
        sets: &[&fmt::Matrix],
        display: &[(usize, usize)],
    ) -> Self {
        let ns = sensors.len();
        let mut prior = Vec::new();
        let mut sensor_post = Vec::new();
        let mut node_post = Vec::new();
        for phase in &kalman.phases {
            let pp = &phase.prior_covariance;
            let po = &phase.posterior_covariance;
            let mut blocks = vec![vec![Matrix3::zeros(); ns]; ns];
            let mut post = Vec::with_capacity(ns);
            for (s, rows) in sensors.iter().enumerate() {
                let cp = block_times_p(rows, 0, pp);
                for (t, other) in sensors.iter().enumerate() {
                    blocks[s][t] = close(&cp, other, 0);
                }
                post.push(close(&block_times_p(rows, 0, po), rows, 0));
            }
            prior.push(blocks);
            sensor_post.push(post);
            node_post.push(
                display
                    .iter()
                    .map(|&(set, i)| close(&block_times_p(sets[set], i, po), sets[set], i))
                    .collect(),
            );
        }
        Filter {
            prior,
            sensor_post,
            node_post,
            measurement_variance: kalman.measurement_variance.clone(),
        }
    }
}

impl FilterBlocks {
    /// Blocks of `model`'s filters (its tier's gain schedule when it has a tier) for the
    /// displayed nodes `display` ((node set, index in set), the order in which
    /// [`ConsistencyAccumulator::posterior`] gets their values).
    pub fn new(model: &fmt::Model, display: &[(usize, usize)]) -> Self {
        match &model.tier {
            None => {
                let sensors: Vec<&fmt::Matrix> =
                    model.sensors.iter().map(|s| &s.displacement_rows).collect();
                let sets: Vec<&fmt::Matrix> = model
                    .node_sets
                    .iter()
                    .map(|s| &s.displacement_rows)
                    .collect();
                FilterBlocks {
                    filters: vec![Filter::new(&model.kalman, &sensors, &sets, display)],
                    display: display.to_vec(),
                    world: false,
                    state_dim: model.r(),
                }
            }
            Some(tier) => {
                let sensors: Vec<&fmt::Matrix> = tier.sensor_rows.iter().collect();
                let sets: Vec<&fmt::Matrix> = tier.node_set_rows.iter().collect();
                FilterBlocks {
                    // In the order of `Estimator::tier_filter`.
                    filters: tier
                        .filters()
                        .map(|k| Filter::new(k, &sensors, &sets, display))
                        .collect(),
                    display: display.to_vec(),
                    world: true,
                    state_dim: tier.state_dim(),
                }
            }
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

/// Accumulates [`Consistency`] over a filtered run, step by step: after each
/// [`Estimator::predict`] call [`ConsistencyAccumulator::innovation`] with the step's
/// measurements, after each [`Estimator::update`] [`ConsistencyAccumulator::posterior`] with
/// the references; then [`ConsistencyAccumulator::finish`].
pub struct ConsistencyAccumulator<'a> {
    blocks: &'a FilterBlocks,
    tip: Option<usize>,
    out: Consistency,
    inside_runtime: usize,
    inside_world: usize,
    total: usize,
    /// ln N(ν; 0, S) of the last innovation (see [`ConsistencyAccumulator::log_likelihood`]).
    log_likelihood: Option<f64>,
    /// Whether an update of this run had an active channel missing or gated.
    channels_lost: bool,
    /// Scratch: ŷ⁻ per measurement channel, sensor displacements, σ per node set.
    predicted: Vec<f64>,
    sensors: Vec<f64>,
    std: Vec<Vec<f64>>,
}

impl<'a> ConsistencyAccumulator<'a> {
    /// An accumulator for runs of `model` (the one `blocks` was built from), NEES at sensor
    /// `tip` (none without).
    pub fn new(blocks: &'a FilterBlocks, model: &fmt::Model, tip: Option<usize>) -> Self {
        ConsistencyAccumulator {
            blocks,
            tip,
            out: Consistency::default(),
            inside_runtime: 0,
            inside_world: 0,
            total: 0,
            log_likelihood: None,
            channels_lost: false,
            predicted: vec![0.0; model.measurements.len()],
            sensors: vec![0.0; 3 * model.sensors.len()],
            std: model
                .node_sets
                .iter()
                .map(|s| vec![0.0; 3 * s.node_tags.len()])
                .collect(),
        }
    }

    /// The stored filter `est` uses now (0 on the warped tier).
    fn filter(&self, est: &Estimator) -> &'a Filter {
        &self.blocks.filters[est.tier_filter().unwrap_or(0)]
    }

    /// The 3×3 rotation taking sensor `s`'s covariance block to the world frame at the state
    /// `x`: R̃(W_s x) on the warped tier, I on the co-rotational tier.
    fn sensor_warp(&self, model: &fmt::Model, s: usize, x: &[f64]) -> Matrix3<f64> {
        if self.blocks.world {
            Matrix3::identity()
        } else {
            warp_matrix(&Warp::new(&rows3(&model.sensors[s].rotation_rows, 0, x)))
        }
    }

    /// After `est.predict`, before `est.update(y)`: NIS of the present measurements `y` on the
    /// phase's active channels, ν = y − ŷ⁻ and S = R̃ (H P⁻_p Hᵀ) R̃ᵀ + R of the filter in use
    /// (module docs).
    pub fn innovation(&mut self, est: &Estimator, y: &[Option<f64>]) -> Result<(), RuntimeError> {
        let model = est.model();
        debug_assert_eq!(est.state().len(), self.blocks.state_dim);
        debug_assert_eq!(est.is_corotational(), self.blocks.world);
        // The phase's channels with a value: (channel, value).
        let used: Vec<(usize, f64)> = est
            .active_measurements()
            .iter()
            .filter_map(|&j| y[j as usize].map(|v| (j as usize, v)))
            .collect();
        self.out.nis_steps.push(ChiSquare::default());
        self.log_likelihood = None;
        self.channels_lost |= used.len() < est.active_measurements().len();
        if used.is_empty() {
            return Ok(());
        }
        est.measurement_estimates(&mut self.predicted)?;
        let filter = self.filter(est);
        let phase = est.phase();
        let x = est.state();
        let live = est.tier_covariance();
        let n = x.len();
        let warps: Vec<Matrix3<f64>> = (0..model.sensors.len())
            .map(|s| self.sensor_warp(model, s, x))
            .collect();
        let m = used.len();
        let mut s_mat = DMatrix::<f64>::zeros(m, m);
        let mut nu = DMatrix::<f64>::zeros(m, 1);
        for (a, &(ja, value)) in used.iter().enumerate() {
            let ch_a = model.measurements[ja];
            let (sa, ca) = (ch_a.sensor as usize, ch_a.component as usize);
            nu[(a, 0)] = value - self.predicted[ja];
            for (b, &(jb, _)) in used.iter().enumerate() {
                let ch_b = model.measurements[jb];
                let (sb, cb) = (ch_b.sensor as usize, ch_b.component as usize);
                let prior = match (live, &model.tier) {
                    (Some(p), Some(t)) => {
                        live_block(&t.sensor_rows[sa], 0, &t.sensor_rows[sb], 0, p, n)
                    }
                    _ => filter.prior[phase][sa][sb],
                };
                let block = warps[sa] * prior * warps[sb].transpose();
                s_mat[(a, b)] = block[(ca, cb)];
            }
            s_mat[(a, a)] += filter.measurement_variance[ja];
            if nu[(a, 0)] * nu[(a, 0)] > 25.0 * s_mat[(a, a)] {
                self.out.outliers += 1;
            }
        }
        if let Some(chol) = s_mat.cholesky() {
            let z = chol.solve(&nu);
            let step = ChiSquare {
                sum: (nu.transpose() * z)[(0, 0)],
                dof: m,
            };
            self.out.nis.add(step);
            if let Some(last) = self.out.nis_steps.last_mut() {
                *last = step;
            }
            let log_det: f64 = (0..m).map(|i| 2.0 * chol.l_dirty()[(i, i)].ln()).sum();
            self.log_likelihood =
                Some(-0.5 * (step.sum + log_det + m as f64 * (2.0 * std::f64::consts::PI).ln()));
        }
        Ok(())
    }

    /// The posterior covariance of sensor `s`'s world displacement after `est.update` (m², the
    /// stored P_p of the filter in use mapped by the sensor's rows, rotated to the world frame
    /// on the warped tier; module docs).
    pub fn sensor_covariance(&self, est: &Estimator, s: usize) -> Matrix3<f64> {
        let w = self.sensor_warp(est.model(), s, est.state());
        w * self.sensor_posterior(est, s) * w.transpose()
    }

    /// Sensor `s`'s posterior block in the filter's frame: from the tier filter's own
    /// covariance while it carries one, else the stored filter's.
    fn sensor_posterior(&self, est: &Estimator, s: usize) -> Matrix3<f64> {
        match (est.tier_covariance(), &est.model().tier) {
            (Some(p), Some(t)) => {
                let rows = &t.sensor_rows[s];
                live_block(rows, 0, rows, 0, p, est.state().len())
            }
            _ => self.filter(est).sensor_post[est.phase()][s],
        }
    }

    /// ln N(ν; 0, S) of the innovation of the last [`ConsistencyAccumulator::innovation`]: the
    /// likelihood of the measurements under the filter's prior (`None` when the step had no
    /// measurement or S was not positive definite). For comparing filters on one recording
    /// (an interacting-multiple-model weight).
    pub fn log_likelihood(&self) -> Option<f64> {
        self.log_likelihood
    }

    /// After `est.update`: at time `time` (s), the tip's NEES and trace against its world
    /// reference `tip_reference` (3, m; ignored without a tip), and the 2σ coverage of the
    /// displayed nodes' world estimates `display` against `reference` (3 per displayed node in
    /// the order given to [`FilterBlocks::new`], m), with the runtime's σ read-out and with the
    /// filter's posterior P_p (module docs).
    pub fn posterior(
        &mut self,
        est: &Estimator,
        time: f64,
        tip_reference: &[f64],
        display: &[f64],
        reference: &[f64],
    ) -> Result<(), RuntimeError> {
        let model = est.model();
        let filter = self.filter(est);
        let phase = est.phase();
        let x = est.state();
        self.out.nees_tip_steps.push(ChiSquare::default());
        self.channels_lost |= est.gated_last_update() > 0;
        self.out.own_covariance +=
            usize::from(self.channels_lost && est.tier_covariance().is_some());
        if let Some(t) = self.tip {
            est.sensor_displacements(&mut self.sensors)?;
            let w = self.sensor_warp(model, t, x);
            let sigma = w * self.sensor_posterior(est, t) * w.transpose();
            let e = nalgebra::Vector3::from_fn(|c, _| self.sensors[3 * t + c] - tip_reference[c]);
            if let Some(inv) = sigma.try_inverse() {
                let step = ChiSquare {
                    sum: (e.transpose() * inv * e)[(0, 0)],
                    dof: 3,
                };
                self.out.nees_tip.add(step);
                if let Some(last) = self.out.nees_tip_steps.last_mut() {
                    *last = step;
                }
            }
            self.out.tip.push(TipSample {
                time,
                error: [e[0], e[1], e[2]],
                sigma: std::array::from_fn(|c| sigma[(c, c)].max(0.0).sqrt()),
            });
        }
        for (set, buf) in self.std.iter_mut().enumerate() {
            est.node_std(set, buf)?;
        }
        let mut step = CoverageCount::default();
        for (j, &(set, i)) in self.blocks.display.iter().enumerate() {
            let w = if self.blocks.world {
                Matrix3::identity()
            } else {
                let rot = &model.node_sets[set].rotation_rows;
                warp_matrix(&Warp::new(&rows3(rot, i, x)))
            };
            let post = match (est.tier_covariance(), &model.tier) {
                (Some(p), Some(t)) => {
                    let rows = &t.node_set_rows[set];
                    live_block(rows, i, rows, i, p, x.len())
                }
                _ => filter.node_post[phase][j],
            };
            let sigma = w * post * w.transpose();
            for c in 0..3 {
                let e = (display[3 * j + c] - reference[3 * j + c]).abs();
                step.inside += (e <= 2.0 * self.std[set][3 * i + c]) as usize;
                self.inside_world += (e <= 2.0 * sigma[(c, c)].max(0.0).sqrt()) as usize;
                step.total += 1;
            }
        }
        self.inside_runtime += step.inside;
        self.total += step.total;
        self.out.coverage_steps.push(step);
        Ok(())
    }

    /// The figures of the run (coverage NaN-free: 0 without displayed nodes).
    pub fn finish(mut self) -> Consistency {
        let total = self.total.max(1) as f64;
        self.out.coverage_runtime = self.inside_runtime as f64 / total;
        self.out.coverage_world = self.inside_world as f64 / total;
        self.out
    }
}

/// One filtered run repeated over N noise draws (docs/design.md §11.3): the N-run consistency
/// test ([`Ensemble`] of the per-step NIS and tip NEES) and the spread of the error and of the
/// 2σ coverage over the draws.
#[derive(Clone, Debug, Default)]
pub struct SeedEnsemble {
    /// Relative L2 error over the displayed nodes of each completed run.
    pub errors: Vec<f64>,
    /// 2σ coverage (runtime σ) of each completed run.
    pub coverage: Vec<f64>,
    /// Per-step NIS over the completed runs.
    pub nis: Ensemble,
    /// Per-step tip NEES over the completed runs.
    pub nees_tip: Ensemble,
    /// Per-step 2σ coverage (runtime σ) summed over the completed runs.
    pub coverage_steps: Vec<CoverageCount>,
    /// Draws whose run the runtime refused: seed and reason (the figures are over the others).
    pub refused: Vec<(u64, String)>,
    /// Updates after which the filter carried its own covariance, over the completed runs.
    pub own_covariance: usize,
}

/// Mean, smallest and largest value (`None` when empty).
pub fn spread(values: &[f64]) -> Option<(f64, f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    Some((values.iter().sum::<f64>() / values.len() as f64, lo, hi))
}

impl SeedEnsemble {
    /// Adds a completed run: its error and its consistency record.
    pub fn add(&mut self, error: f64, run: &Consistency) -> Result<(), RunLengthMismatch> {
        // All checked before any is changed: the ensembles hold the same runs.
        let first = self.nis.runs() == 0;
        for (expected, found) in [
            (self.nis.steps(), run.nis_steps.len()),
            (self.nees_tip.steps(), run.nees_tip_steps.len()),
            (self.coverage_steps.len(), run.coverage_steps.len()),
        ] {
            if !first && expected != found {
                return Err(RunLengthMismatch { expected, found });
            }
        }
        self.nis.add(&run.nis_steps)?;
        self.nees_tip.add(&run.nees_tip_steps)?;
        if first {
            self.coverage_steps = run.coverage_steps.clone();
        } else {
            for (acc, &step) in self.coverage_steps.iter_mut().zip(&run.coverage_steps) {
                acc.add(step);
            }
        }
        self.errors.push(error);
        self.coverage.push(run.coverage_runtime);
        self.own_covariance += run.own_covariance;
        Ok(())
    }

    /// Fraction of the completed runs' updates after which the filter carried its own
    /// covariance (0 without runs).
    pub fn own_covariance_fraction(&self) -> f64 {
        let updates = self.nees_tip.steps() * self.nees_tip.runs();
        if updates == 0 {
            0.0
        } else {
            self.own_covariance as f64 / updates as f64
        }
    }

    /// The ensemble of the one run `run` of relative error `error` (the per-step bounds of
    /// one run, χ²(d)/d, are those of N = 1: valid step by step).
    pub fn of_run(error: f64, run: &Consistency) -> Result<Self, RunLengthMismatch> {
        let mut e = SeedEnsemble::default();
        e.add(error, run)?;
        Ok(e)
    }

    /// The 2σ coverage over the steps `steps` (clipped to the run's) and all completed runs;
    /// NaN without displayed nodes or steps.
    pub fn coverage_in(&self, steps: std::ops::Range<usize>) -> f64 {
        let end = steps.end.min(self.coverage_steps.len());
        let start = steps.start.min(end);
        self.coverage_steps[start..end]
            .iter()
            .fold(CoverageCount::default(), |mut t, &c| {
                t.add(c);
                t
            })
            .fraction()
    }

    /// Draws made (completed and refused).
    pub fn draws(&self) -> usize {
        self.errors.len() + self.refused.len()
    }

    /// The refused draws in words: `0`, or `k of N: seed s: reason; …`.
    pub fn refusals(&self) -> String {
        if self.refused.is_empty() {
            return "0".into();
        }
        let reasons: Vec<String> = self
            .refused
            .iter()
            .map(|(seed, why)| format!("seed {seed}: {why}"))
            .collect();
        format!(
            "{} of {}: {}",
            self.refused.len(),
            self.draws(),
            reasons.join("; ")
        )
    }
}

/// The word for where an [`Ensemble`]'s steps lie: "overconfident" when more than 10 % of them
/// lie above their bounds (σ too small), else "conservative" when more than 10 % lie below
/// (σ too large), else "consistent" (≈ 2.5 % on either side expected).
pub fn verdict(f: &StepFractions) -> &'static str {
    if f.above > 0.1 {
        "overconfident"
    } else if f.below > 0.1 {
        "conservative"
    } else {
        "consistent"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comparison::Gaussian;

    /// N runs of K steps of a 3-component error that is an AR(1) process in time (correlation
    /// `rho` per step, stationary variance `scale` per component) against a filter that claims
    /// the identity: per-step NEES and the runs' single-run averages.
    fn runs(n: usize, k: usize, rho: f64, scale: f64, seed: u64) -> (Ensemble, Vec<ChiSquare>) {
        let mut rng = Gaussian::new(seed);
        let mut ensemble = Ensemble::default();
        let mut singles = Vec::new();
        for _ in 0..n {
            let mut e: [f64; 3] = std::array::from_fn(|_| rng.normal());
            let mut steps = Vec::with_capacity(k);
            let mut single = ChiSquare::default();
            for _ in 0..k {
                for c in &mut e {
                    *c = rho * *c + (1.0 - rho * rho).sqrt() * rng.normal();
                }
                let step = ChiSquare {
                    sum: scale * e.iter().map(|c| c * c).sum::<f64>(),
                    dof: 3,
                };
                single.add(step);
                steps.push(step);
            }
            ensemble.add(&steps).expect("equal lengths");
            singles.push(single);
        }
        (ensemble, singles)
    }

    #[test]
    fn ensemble_bounds_hold_for_errors_correlated_in_time() {
        // A consistent filter whose errors are strongly correlated in time (ρ = 0.98: about
        // 4 independent samples in 400 steps): the single-run bounds reject most runs, the
        // per-step N-run bounds accept ≈ 95 % of the steps.
        let (ensemble, singles) = runs(20, 400, 0.98, 1.0, 3);
        let f = ensemble.fractions();
        assert_eq!(f.steps, 400);
        assert!(f.inside > 0.88 && f.inside < 0.995, "{f:?}");
        assert!((f.below + f.inside + f.above - 1.0).abs() < 1e-12);
        let rejected = singles.iter().filter(|s| !s.inside()).count();
        assert!(
            rejected >= 10,
            "single-run bounds rejected {rejected} of 20"
        );
        let total = ensemble.total();
        assert_eq!(total.dof, 20 * 400 * 3);
        assert!((total.mean() - 1.0).abs() < 0.15, "{}", total.mean());
        // Independent samples: both kinds of bounds accept.
        let (ensemble, singles) = runs(20, 400, 0.0, 1.0, 4);
        let f = ensemble.fractions();
        assert!(f.inside > 0.9 && f.inside < 0.99, "{f:?}");
        assert!(singles.iter().filter(|s| !s.inside()).count() <= 4);
    }

    #[test]
    fn ensemble_tells_conservative_from_overconfident() {
        // χ²(60)/60 bounds are [0.69, 1.39]: errors of 0.4× the claimed variance lie below at
        // almost every step, of 2.5× above.
        let (conservative, _) = runs(20, 300, 0.5, 0.4, 5);
        let f = conservative.fractions();
        assert!(f.below > 0.9 && f.above == 0.0, "{f:?}");
        let (overconfident, _) = runs(20, 300, 0.5, 2.5, 6);
        let f = overconfident.fractions();
        assert!(f.above > 0.9 && f.below == 0.0, "{f:?}");
    }

    #[test]
    fn seed_ensemble_keeps_its_two_ensembles_over_the_same_runs() {
        let step = ChiSquare { sum: 3.0, dof: 3 };
        let run = |n: usize, m: usize| Consistency {
            nis_steps: vec![step; n],
            nees_tip_steps: vec![step; m],
            coverage_runtime: 0.95,
            ..Consistency::default()
        };
        let mut e = SeedEnsemble::default();
        e.add(0.01, &run(4, 4)).expect("first run");
        // A run whose NEES record is short changes neither ensemble.
        assert!(e.add(0.02, &run(4, 3)).is_err());
        assert_eq!((e.nis.runs(), e.nees_tip.runs(), e.errors.len()), (1, 1, 1));
        e.refused.push((9, "step 3: refused".into()));
        assert_eq!(e.draws(), 2);
        assert_eq!(e.refusals(), "1 of 2: seed 9: step 3: refused");
        assert_eq!(spread(&[1.0, 3.0, 2.0]), Some((2.0, 1.0, 3.0)));
        assert_eq!(spread(&[]), None);
    }

    #[test]
    fn fractions_and_coverage_over_a_range_of_steps() {
        // 10 steps of 3 runs: the first 4 overconfident (NEES 5 per dof), the rest consistent;
        // coverage 1 of 2 components inside on the first 4 steps, 2 of 2 after.
        let mut e = SeedEnsemble::default();
        for _ in 0..3 {
            let nees: Vec<ChiSquare> = (0..10)
                .map(|k| ChiSquare {
                    sum: if k < 4 { 15.0 } else { 3.0 },
                    dof: 3,
                })
                .collect();
            let coverage: Vec<CoverageCount> = (0..10)
                .map(|k| CoverageCount {
                    inside: if k < 4 { 1 } else { 2 },
                    total: 2,
                })
                .collect();
            let run = Consistency {
                nis_steps: nees.clone(),
                nees_tip_steps: nees,
                coverage_steps: coverage,
                ..Consistency::default()
            };
            e.add(0.01, &run).expect("equal lengths");
        }
        let f = e.nees_tip.fractions_in(0..4);
        assert_eq!((f.steps, f.above, f.inside), (4, 1.0, 0.0));
        let f = e.nees_tip.fractions_in(4..10);
        assert_eq!((f.steps, f.above, f.inside), (6, 0.0, 1.0));
        assert_eq!(e.nees_tip.fractions().above, 0.4);
        // Ranges are clipped to the run.
        assert_eq!(e.nees_tip.fractions_in(8..40).steps, 2);
        assert_eq!(e.nees_tip.fractions_in(20..40).steps, 0);
        assert_eq!(e.coverage_in(0..4), 0.5);
        assert_eq!(e.coverage_in(4..10), 1.0);
        assert_eq!(e.coverage_in(0..10), (12.0 + 36.0) / 60.0);
        assert!(e.coverage_in(10..12).is_nan());
        // A run whose coverage record is short changes nothing.
        let short = Consistency {
            nis_steps: vec![ChiSquare { sum: 3.0, dof: 3 }; 10],
            nees_tip_steps: vec![ChiSquare { sum: 3.0, dof: 3 }; 10],
            coverage_steps: vec![CoverageCount::default(); 9],
            ..Consistency::default()
        };
        assert!(e.add(0.01, &short).is_err());
        assert_eq!((e.nis.runs(), e.errors.len()), (3, 3));
        // One run alone is an ensemble of one.
        let one = SeedEnsemble::of_run(0.02, &short).expect("one run");
        assert_eq!((one.nis.runs(), one.coverage_steps.len()), (1, 9));
    }

    #[test]
    fn ensemble_refuses_runs_of_another_length() {
        let mut e = Ensemble::default();
        let step = ChiSquare { sum: 3.0, dof: 3 };
        e.add(&[step; 5]).expect("first run");
        let err = e.add(&[step; 4]).expect_err("shorter run");
        assert_eq!((err.expected, err.found), (5, 4));
        assert_eq!(e.runs(), 1);
        // Steps without a sample are not counted.
        let mut e = Ensemble::default();
        e.add(&[ChiSquare::default(), step]).expect("run");
        assert_eq!(e.fractions().steps, 1);
    }
}
