//! What the estimator reads from a filter's stored covariances, shared by the warped and the
//! co-rotational tier: read-out standard deviations sqrt(diag(C P Cᵀ)), the innovation gate's
//! variances (computed once, at load) and the gate's test per update (docs/design.md §6).

use crokf_formats::Matrix;

/// c P cᵀ for a row c of length k ≤ n and the leading k×k block of the n×n P (the whole P when
/// k = n; the displacement block P_qq of the co-rotational tier's (q, q̇, q̈, f) covariance):
/// Σ_i c_i (Σ_j P_ij c_j). Used at load only (read-out σ, the gate's variances).
fn quadratic(c: &[f64], p: &Matrix) -> f64 {
    let n = p.cols as usize;
    c.iter()
        .zip(p.data.chunks_exact(n.max(1)))
        .map(|(ci, row)| ci * row.iter().zip(c).map(|(a, b)| a * b).sum::<f64>())
        .sum()
}

/// sqrt(diag(C P Cᵀ)) for the rows C (row-major, `c.len()` = k·rows, k ≤ n) and the leading
/// k×k block of P (see [`quadratic`]), appended to `out`.
pub(crate) fn row_std(rows: &[f64], k: usize, p: &Matrix, out: &mut Vec<f64>) {
    out.extend(
        rows.chunks_exact(k.max(1))
            .map(|c| quadratic(c, p).max(0.0).sqrt()),
    );
}

/// The innovation gate's variances of a Kalman section (docs/design.md §6), h_j = `h_row(j)`
/// the row of measurement channel j (over the leading block of P and Q): per phase and active
/// channel j, s_j = h_j P⁻_p h_jᵀ + R_jj (m²), and per channel (all `channels`) the growth per
/// step without an accepted value, g_j = max(h_j Q h_jᵀ, 0) (m²).
pub(crate) fn gate_variances<'a>(
    kalman: &crokf_formats::KalmanGains,
    channels: usize,
    h_row: impl Fn(usize) -> &'a [f64],
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let innovation_variance = kalman
        .phases
        .iter()
        .map(|ph| {
            ph.measured
                .iter()
                .map(|&j| {
                    let j = j as usize;
                    quadratic(h_row(j), &ph.prior_covariance) + kalman.measurement_variance[j]
                })
                .collect()
        })
        .collect();
    let variance_growth = (0..channels)
        .map(|j| quadratic(h_row(j), &kalman.process_noise).max(0.0))
        .collect();
    (innovation_variance, variance_growth)
}

/// The innovation gate's configuration for one update (docs/design.md §6): `sigmas` g (None:
/// off) and, per measurement channel, the steps it went without an accepted value beyond its
/// period (n_j, from the caller's bookkeeping).
#[derive(Clone, Copy, Debug)]
pub struct Gate<'a> {
    /// g, in standard deviations of the innovation; `None`: off.
    pub sigmas: Option<f64>,
    /// The step k being updated.
    pub step: u64,
    /// Per measurement channel: the step of its last accepted value (0: none yet).
    pub last_accepted: &'a [u64],
    /// Per measurement channel: its sensor's `every`.
    pub every: &'a [u64],
}

impl Gate<'_> {
    /// The gate off.
    #[cfg_attr(not(feature = "internals"), allow(dead_code))]
    pub const OFF: Gate<'static> = Gate {
        sigmas: None,
        step: 0,
        last_accepted: &[],
        every: &[],
    };

    /// n_j = max(0, k − last accepted step − every_j).
    pub(crate) fn missed(&self, j: usize) -> u64 {
        match (self.last_accepted.get(j), self.every.get(j)) {
            (Some(&last), Some(&every)) => self.step.saturating_sub(last).saturating_sub(every),
            _ => 0,
        }
    }
}

/// The gate's test (docs/design.md §6): true when ν² > g² (s + n·growth).
pub(crate) fn gate_rejects(nu: f64, sigmas: f64, variance: f64, missed: u64, growth: f64) -> bool {
    nu * nu > sigmas * sigmas * (variance + missed as f64 * growth)
}
