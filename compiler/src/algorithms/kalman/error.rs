//! Failures of the Kalman stage.

use thiserror::Error;

/// Failures of the Kalman stage. No solution is returned with any of them.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum KalmanError {
    /// Matrix dimensions do not fit together.
    #[error("Kalman: shape mismatch: {0}")]
    Shape(String),
    /// An input entry is NaN or infinite.
    #[error("Kalman: {matrix}[{row},{col}] = {value} is not finite")]
    NonFinite {
        /// Which input ("F", "H", "Q", "R").
        matrix: &'static str,
        /// Row index.
        row: usize,
        /// Column index.
        col: usize,
        /// The offending value.
        value: f64,
    },
    /// A diagonal entry of R (a sensor variance) is zero or negative.
    #[error(
        "Kalman: measurement noise R is not positive definite: R[{index},{index}] = {value:e} \
         (measurement row {index}) must be > 0"
    )]
    RDiagonalNotPositive {
        /// Measurement row.
        index: usize,
        /// Its variance.
        value: f64,
    },
    /// R is not symmetric.
    #[error(
        "Kalman: R is not symmetric: R[{row},{col}] = {upper:e} but R[{col},{row}] = {lower:e}"
    )]
    RNotSymmetric {
        /// Row of the upper entry.
        row: usize,
        /// Column of the upper entry.
        col: usize,
        /// R[row, col].
        upper: f64,
        /// R[col, row].
        lower: f64,
    },
    /// R has a positive diagonal but a non-positive eigenvalue.
    #[error("Kalman: measurement noise R is not positive definite: smallest eigenvalue {eigenvalue:e} <= 0")]
    RNotPositiveDefinite {
        /// Smallest eigenvalue of R.
        eigenvalue: f64,
    },
    /// Q is not symmetric.
    #[error("Kalman: process noise Q is not symmetric: Q[{row},{col}] = {upper:e} but Q[{col},{row}] = {lower:e}")]
    QNotSymmetric {
        /// Row of the upper entry.
        row: usize,
        /// Column of the upper entry.
        col: usize,
        /// Q[row, col].
        upper: f64,
        /// Q[col, row].
        lower: f64,
    },
    /// Q has a clearly negative eigenvalue.
    #[error(
        "Kalman: process noise Q is not positive semidefinite: eigenvalue {eigenvalue:e} \
         (largest {largest:e})"
    )]
    QNotPositiveSemidefinite {
        /// Most negative eigenvalue.
        eigenvalue: f64,
        /// Largest eigenvalue, for scale.
        largest: f64,
    },
    /// An eigenvalue of F with |λ| ≥ 1 is invisible to the sensors (PBH).
    #[error(
        "Kalman: undetectable: F has the eigenvalue {re:.9}{im:+.9}i (|λ| = {modulus:.12}) on or \
         outside the unit circle and the measurements H do not see it (PBH: σ_min[λI − F; H] = \
         {sigma:.3e}); no stabilizing steady-state filter exists"
    )]
    Undetectable {
        /// Re λ.
        re: f64,
        /// Im λ.
        im: f64,
        /// |λ|.
        modulus: f64,
        /// Smallest singular value of the scaled PBH matrix.
        sigma: f64,
    },
    /// An eigenvalue of F with |λ| ≥ 1 is not excited by the process noise (PBH).
    #[error(
        "Kalman: unstabilizable: F has the eigenvalue {re:.9}{im:+.9}i (|λ| = {modulus:.12}) on or \
         outside the unit circle and the process noise Q does not excite it (PBH: \
         σ_min[λ̄I − Fᵀ; Q] = {sigma:.3e}); no stabilizing steady-state filter exists"
    )]
    Unstabilizable {
        /// Re λ.
        re: f64,
        /// Im λ.
        im: f64,
        /// |λ|.
        modulus: f64,
        /// Smallest singular value of the scaled PBH matrix.
        sigma: f64,
    },
    /// The doubling iteration hit its cap (or overflowed).
    #[error(
        "Kalman: the structured doubling algorithm did not converge in {iterations} iterations \
         (last relative change {last_change:e})"
    )]
    NoConvergence {
        /// Iterations done.
        iterations: usize,
        /// Relative change ‖H_k − H_{k−1}‖_F / ‖H_k‖_F of the last one.
        last_change: f64,
    },
    /// The Riccati residual stays too large after polishing.
    #[error(
        "Kalman: relative Riccati residual {residual:e} exceeds {threshold:e} after Newton \
         polishing"
    )]
    ResidualTooLarge {
        /// ‖res‖_F / max(‖P‖_F, ‖Q‖_F).
        residual: f64,
        /// The accepted maximum.
        threshold: f64,
    },
    /// The steady-state filter does not converge. With near-perfect sensors (tiny R) and
    /// more sensors than process-noise channels, H P Hᵀ + R is nearly singular, K is not
    /// determined to working precision and this is how it shows.
    #[error(
        "Kalman: closed-loop spectral radius ρ((I − K H) F) = {radius:.15} >= 1: the filter \
         would diverge (condition number of H P Hᵀ + R: {innovation_condition:.1e}; a huge \
         value means the sensor noise R is too small for K to be computed in double precision)"
    )]
    UnstableClosedLoop {
        /// ρ of the (one-period) closed-loop error propagator.
        radius: f64,
        /// λ_max/λ_min of H₀ P₀ H₀ᵀ + R₀.
        innovation_condition: f64,
    },
    /// A multi-rate divisor is zero.
    #[error("Kalman: measurement row {row}: the update interval `every` must be >= 1 (got 0)")]
    ZeroInterval {
        /// Measurement row.
        row: usize,
    },
    /// lcm(every) too long.
    #[error("Kalman: the multi-rate period lcm(every) = {period} exceeds the limit {limit}")]
    PeriodTooLong {
        /// The period (saturated at u64::MAX).
        period: u64,
        /// [`crate::algorithms::kalman::MAX_PERIOD`].
        limit: usize,
    },
    /// A dense factorisation failed.
    #[error("Kalman: {0}")]
    LinearAlgebra(String),
    /// Noise identification from innovations (autocovariance least squares) cannot run on
    /// the data or filter given.
    #[error("Kalman: noise identification: {0}")]
    Identification(String),
}
