//! Kalman stage (DESIGN.md §6): steady-state gains of the reduced model
//!
//! ```text
//! x⁺ = F x + G u + w,   y = H x + v,   w ~ N(0, Q),  v ~ N(0, R)
//! ```
//!
//! with F (r×r, dimensionless), H (m×r, sensor units per state unit), Q (r×r, PSD, possibly
//! singular or zero) and R (m×m, symmetric positive definite, sensor units²).
//!
//! The a priori (filter) discrete algebraic Riccati equation
//!
//! ```text
//! P = F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q  =  F P (I + Hᵀ R⁻¹ H P)⁻¹ Fᵀ + Q
//! ```
//!
//! is solved by the structured doubling algorithm (SDA) on the dual data
//! (A₀ = Fᵀ, G₀ = Hᵀ R⁻¹ H, H₀ = Q), then polished by Newton (Kleinman/Hewer) steps in
//! residual-correction form where they reduce the residual. Every solution is checked: the
//! relative residual and the closed-loop spectral radius ρ((I − K H) F) < 1.
//!
//! With near-perfect sensors (R ≲ 1e-16 relative to H Q Hᵀ) I + G H in the doubling has
//! condition ~ 1/R and SDA can collapse onto a non-stabilizing solution (residual ~1e-16,
//! ρ > 1). Two fallbacks then run, each followed by the same checks: (2) for Schur-stable F,
//! Hewer's iteration from the stabilizing gain K = 0; (3) the plain Riccati recursion
//! (Joseph form) from the best candidate, within a flop budget. If all fail, the error of
//! route (1) is returned.
//!
//! Multi-rate sensors ([`periodic_gains`]) use the same machinery: each phase of the period
//! is one Riccati map in SDA form, the maps of one period are composed into a single one
//! (the composition of two such maps is again one, the SDA step being the self-composition),
//! and the SDA of the composed map gives the periodic a priori covariance at phase 0.
//!
//! Conventions: the filter gain K = P Hᵀ (H P Hᵀ + R)⁻¹ acts on the innovation,
//! x = x⁻ + K (y − H x⁻); the posterior covariance is the Joseph form
//! (I − K H) P (I − K H)ᵀ + K R Kᵀ (= (I − K H) P for the optimal K, but PSD by construction).

use faer::linalg::solvers::Solve;
use faer::{c64, Mat, MatRef, Side};
use thiserror::Error;

/// Relative Riccati residual above which a solution is refused.
pub const RESIDUAL_THRESHOLD: f64 = 1e-8;
/// Iteration cap of the structured doubling algorithm (each iteration doubles the horizon).
pub const SDA_MAX_ITERATIONS: usize = 100;
/// Longest accepted multi-rate period lcm(every), in base steps.
pub const MAX_PERIOD: usize = 4096;

/// Eigenvalues with |λ| ≥ 1 − this are treated as not asymptotically stable by the PBH test.
const MARGINAL_STABILITY: f64 = 1e-10;
/// PBH rank tolerance: σ_min([λI − F; s·H]) ≤ this · ‖F‖_F counts as rank deficient.
const PBH_TOLERANCE: f64 = 1e-8;
/// Relative SDA change under which the iteration has converged.
const SDA_CHANGE_TOLERANCE: f64 = 1e-15;
/// SDA stops when ‖A_k‖_F² ≤ this: then ‖X − H_k‖ ≤ ‖A_k‖² ‖X‖ is below rounding.
const SDA_A_TOLERANCE: f64 = 1e-16;
/// Largest accepted relative change of the last SDA iteration when the cap is reached.
const SDA_ACCEPT_AT_CAP: f64 = 1e-10;
/// Relative asymmetry accepted in Q and R.
const SYMMETRY_TOLERANCE: f64 = 1e-10;
/// Relative negative eigenvalue accepted in Q (rounding of a PSD projection).
const PSD_TOLERANCE: f64 = 1e-10;
/// Most Newton (Hewer) polish steps; they continue while each halves the residual. One or
/// two usually suffice; with small R (≲ 1e-8 relative to H Q Hᵀ) the SDA iterates lose
/// accuracy (I + G H has condition ~ 1/R) and Newton's quadratic convergence recovers it.
const NEWTON_STEPS: usize = 8;
/// Residual at which Newton stops: rounding level.
const NEWTON_DONE: f64 = 1e-15;
/// Most plain Riccati sweeps tried on a solution that fails the checks.
const RECURSION_MAX_SWEEPS: usize = 2000;
/// Flop budget (≈ sweeps · r³ · L) of those sweeps.
const RECURSION_FLOP_BUDGET: f64 = 2e10;
/// Sweeps between closed-loop checks in that recursion.
const RECURSION_CHECK_EVERY: usize = 10;
/// Most steps of the fallback Hewer iteration from K = 0.
const HEWER_MAX_STEPS: usize = 100;

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
        /// [`MAX_PERIOD`].
        limit: usize,
    },
    /// A dense factorisation failed.
    #[error("Kalman: {0}")]
    LinearAlgebra(String),
}

/// Steady-state (a priori) Kalman filter of one DARE.
#[derive(Clone, Debug)]
pub struct DareSolution {
    /// P∞ (r×r), the stabilizing solution of the filter DARE: a priori error covariance.
    pub prior_covariance: Mat<f64>,
    /// K∞ = P Hᵀ (H P Hᵀ + R)⁻¹ (r×m), the filter gain on the innovation y − H x⁻.
    pub gain: Mat<f64>,
    /// (I − K H) P (I − K H)ᵀ + K R Kᵀ (r×r, Joseph form, symmetric): a posteriori covariance.
    pub posterior_covariance: Mat<f64>,
    /// ‖P − (F P Fᵀ − F P Hᵀ S⁻¹ H P Fᵀ + Q)‖_F / max(‖P‖_F, ‖Q‖_F, tiny), S = H P Hᵀ + R.
    pub relative_residual: f64,
    /// ρ((I − K H) F) < 1, the error propagator of the filter.
    pub closed_loop_spectral_radius: f64,
    /// 2-norm condition number λ_max/λ_min of the innovation covariance S = H P Hᵀ + R
    /// (the matrix inverted for K); 1 when there are no measurements.
    pub condition: f64,
    /// Outer iterations of the route that succeeded: SDA doubling steps (each doubles the
    /// horizon of the Riccati recursion) + Newton steps; on a fallback route, Hewer/Newton
    /// steps + recursion sweeps.
    pub iterations: usize,
}

/// One phase of a periodic (multi-rate) steady-state filter.
#[derive(Clone, Debug)]
pub struct PhaseGain {
    /// Measurement rows (indices into H) updated at this phase, ascending.
    pub measured: Vec<usize>,
    /// Gain (r × measured.len()) on the innovation of those rows; r×0 when predicting only.
    pub gain: Mat<f64>,
    /// A priori covariance at this phase (r×r).
    pub prior_covariance: Mat<f64>,
    /// A posteriori covariance at this phase (r×r, Joseph form).
    pub posterior_covariance: Mat<f64>,
}

/// Periodic steady-state filter for sensors read every `every[i]` base steps.
#[derive(Clone, Debug)]
pub struct PeriodicSchedule {
    /// Period L = lcm(every), base steps.
    pub period: usize,
    /// Phases 0..L; phase p measures the rows i with p % every[i] == 0.
    pub phases: Vec<PhaseGain>,
    /// Worst relative residual over the period: ‖P₀ − Ricc_{L−1}∘…∘Ricc₀(P₀)‖_F /
    /// max(‖P₀‖_F, ‖Q‖_F, tiny) (the per-phase equations hold exactly by construction of
    /// P₁ … P_{L−1} from P₀).
    pub worst_relative_residual: f64,
    /// ρ(Φ) of the one-period error propagator Φ = Π_p F (I − K_p H_p).
    pub closed_loop_spectral_radius: f64,
    /// Outer iterations as in [`DareSolution::iterations`] (SDA on the composed map).
    pub iterations: usize,
}

/// Standard deviations of the outputs z = C x for an error covariance P:
/// sqrt(diag(C P Cᵀ)), computed row by row as Σ_j (C P)_ij C_ij without forming C P Cᵀ.
/// C is q×r, P r×r; returns q values (in output units). Tiny negative rounding is clamped to 0.
///
/// # Panics
/// If C has not as many columns as P has rows, or P is not square (a programming error:
/// both come from the compiler itself, not from user input).
pub fn output_standard_deviations(c: MatRef<f64>, p: MatRef<f64>) -> Vec<f64> {
    assert!(
        p.nrows() == p.ncols() && c.ncols() == p.nrows(),
        "output_standard_deviations: C is {}x{}, P is {}x{}",
        c.nrows(),
        c.ncols(),
        p.nrows(),
        p.ncols()
    );
    let cp = c * p;
    (0..c.nrows())
        .map(|i| {
            let v: f64 = (0..c.ncols()).map(|j| cp[(i, j)] * c[(i, j)]).sum();
            v.max(0.0).sqrt()
        })
        .collect()
}

/// Solves the filter DARE P = F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q for its stabilizing
/// solution and returns the steady-state gain, posterior covariance and accuracy figures.
///
/// Shapes: F r×r, H m×r (m may be 0: P is then the Lyapunov solution), Q r×r symmetric PSD,
/// R m×m symmetric positive definite.
pub fn solve_filter_dare(
    f: MatRef<f64>,
    h: MatRef<f64>,
    q: MatRef<f64>,
    r: MatRef<f64>,
) -> Result<DareSolution, KalmanError> {
    let n = f.nrows();
    let m = h.nrows();
    check_square("F", f)?;
    if n == 0 {
        return Err(KalmanError::Shape(
            "F is 0x0: the model has no states".into(),
        ));
    }
    check_shape("H", h, m, n)?;
    check_shape("Q", q, n, n)?;
    check_shape("R", r, m, m)?;
    for (name, mat) in [("F", f), ("H", h), ("Q", q), ("R", r)] {
        check_finite(name, mat)?;
    }
    let q = validate_q(q)?;
    let r = validate_r(r)?;
    let f = f.to_owned();
    let h = h.to_owned();
    check_detectable_stabilizable(&f, &h, &q)?;
    let phases = vec![PhaseModel::new(h, r, (0..m).collect())?];
    let solved = solve_periodic(&f, &q, &phases)?;
    let phase = solved.phases.into_iter().next().ok_or_else(|| {
        KalmanError::LinearAlgebra("internal: periodic solver returned no phase".into())
    })?;
    Ok(DareSolution {
        prior_covariance: phase.prior_covariance,
        gain: phase.gain,
        posterior_covariance: phase.posterior_covariance,
        relative_residual: solved.worst_relative_residual,
        closed_loop_spectral_radius: solved.closed_loop_spectral_radius,
        condition: solved.condition,
        iterations: solved.iterations,
    })
}

/// Periodic steady-state filter for multi-rate sensors.
///
/// Measurement row i (of H, variance `r_diag[i]` > 0) is available every `every[i]` ≥ 1 base
/// steps; the period is L = lcm(every) and phase p ∈ 0..L measures the rows with
/// p % every[i] == 0 (phase 0 measures all). The per-phase a priori covariances satisfy
/// P_{p+1} = F [(I − K_p H_p) P_p (I − K_p H_p)ᵀ + K_p R_p K_pᵀ] Fᵀ + Q with P_L = P_0,
/// K_p = P_p H_pᵀ (H_p P_p H_pᵀ + R_p)⁻¹. Route: compose the L Riccati maps of one period
/// into one map in SDA form, solve its fixed point P_0 by SDA, polish by Newton on the
/// one-period map, and sweep once through the period. For L = 1 this is
/// [`solve_filter_dare`] with R = diag(r_diag).
pub fn periodic_gains(
    f: MatRef<f64>,
    h: MatRef<f64>,
    q: MatRef<f64>,
    r_diag: &[f64],
    every: &[u32],
) -> Result<PeriodicSchedule, KalmanError> {
    let n = f.nrows();
    let m = h.nrows();
    check_square("F", f)?;
    if n == 0 {
        return Err(KalmanError::Shape(
            "F is 0x0: the model has no states".into(),
        ));
    }
    check_shape("H", h, m, n)?;
    check_shape("Q", q, n, n)?;
    if r_diag.len() != m {
        return Err(KalmanError::Shape(format!(
            "r_diag has {} entries but H has {} measurement rows",
            r_diag.len(),
            m
        )));
    }
    if every.len() != m {
        return Err(KalmanError::Shape(format!(
            "every has {} entries but H has {} measurement rows",
            every.len(),
            m
        )));
    }
    for (name, mat) in [("F", f), ("H", h), ("Q", q)] {
        check_finite(name, mat)?;
    }
    let r_full = Mat::from_fn(m, m, |i, j| if i == j { r_diag[i] } else { 0.0 });
    check_finite("R", r_full.as_ref())?;
    let q = validate_q(q)?;
    validate_r(r_full.as_ref())?;
    let mut period: u64 = 1;
    for (row, &e) in every.iter().enumerate() {
        if e == 0 {
            return Err(KalmanError::ZeroInterval { row });
        }
        let e = e as u64;
        period = (period / gcd(period, e)).saturating_mul(e);
        if period > MAX_PERIOD as u64 {
            return Err(KalmanError::PeriodTooLong {
                period,
                limit: MAX_PERIOD,
            });
        }
    }
    let period = period as usize;
    let f = f.to_owned();
    let h = h.to_owned();
    check_detectable_stabilizable(&f, &h, &q)?;
    let mut phases = Vec::with_capacity(period);
    for p in 0..period {
        let rows: Vec<usize> = (0..m).filter(|&i| p % every[i] as usize == 0).collect();
        let hp = Mat::from_fn(rows.len(), n, |i, j| h[(rows[i], j)]);
        let rp = Mat::from_fn(rows.len(), rows.len(), |i, j| {
            if i == j {
                r_diag[rows[i]]
            } else {
                0.0
            }
        });
        phases.push(PhaseModel::new(hp, rp, rows)?);
    }
    let solved = solve_periodic(&f, &q, &phases)?;
    Ok(PeriodicSchedule {
        period,
        phases: solved.phases,
        worst_relative_residual: solved.worst_relative_residual,
        closed_loop_spectral_radius: solved.closed_loop_spectral_radius,
        iterations: solved.iterations,
    })
}

// ---------------------------------------------------------------------------------------------
// Core: SDA on composed Riccati maps, Newton polish, sweep.

/// Measurement model of one phase: H_p (m_p×r), R_p (m_p×m_p, SPD), G_p = H_pᵀ R_p⁻¹ H_p.
struct PhaseModel {
    h: Mat<f64>,
    r: Mat<f64>,
    g: Mat<f64>,
    measured: Vec<usize>,
}

impl PhaseModel {
    fn new(h: Mat<f64>, r: Mat<f64>, measured: Vec<usize>) -> Result<Self, KalmanError> {
        let n = h.ncols();
        let g = if h.nrows() == 0 {
            Mat::zeros(n, n)
        } else {
            let chol = r
                .llt(Side::Lower)
                .map_err(|e| KalmanError::LinearAlgebra(format!("Cholesky of R failed: {e:?}")))?;
            let rinv_h = chol.solve(&h);
            symmetrise(&(h.transpose() * &rinv_h))
        };
        Ok(Self { h, r, g, measured })
    }
}

/// The Riccati map X ↦ Aᵀ X (I + G X)⁻¹ A + H in SDA form (G, H symmetric PSD).
/// One filter step of phase p is (A, G, H) = (Fᵀ, H_pᵀ R_p⁻¹ H_p, Q).
struct Triple {
    a: Mat<f64>,
    g: Mat<f64>,
    h: Mat<f64>,
}

/// The map "t1 then t2" in SDA form; with W = I + G₂ H₁:
/// A = A₁ W⁻¹ A₂, G = G₁ + A₁ W⁻¹ G₂ A₁ᵀ, H = H₂ + A₂ᵀ H₁ W⁻¹ A₂.
/// compose(t, t) is one SDA step.
fn compose(t1: &Triple, t2: &Triple) -> Triple {
    let n = t1.a.nrows();
    let mut w = Mat::<f64>::identity(n, n);
    w += &t2.g * &t1.h;
    let lu = w.partial_piv_lu();
    let w_a2 = lu.solve(&t2.a);
    let w_g2 = lu.solve(&t2.g);
    let a = &t1.a * &w_a2;
    let g = symmetrise(&(&t1.g + &t1.a * &w_g2 * t1.a.transpose()));
    let h = symmetrise(&(&t2.h + t2.a.transpose() * &t1.h * &w_a2));
    Triple { a, g, h }
}

/// Fixed point X = Aᵀ X (I + G X)⁻¹ A + H of a Riccati map by the structured doubling
/// algorithm. Returns (X, iterations).
fn sda(mut t: Triple) -> Result<(Mat<f64>, usize), KalmanError> {
    let mut change = f64::INFINITY;
    for k in 1..=SDA_MAX_ITERATIONS {
        let next = compose(&t, &t);
        let h_norm = next.h.norm_l2();
        let diff = (&next.h - &t.h).norm_l2();
        change = if h_norm > 0.0 { diff / h_norm } else { diff };
        let a_norm = next.a.norm_l2();
        if !change.is_finite() || !a_norm.is_finite() || !next.g.norm_l2().is_finite() {
            return Err(KalmanError::NoConvergence {
                iterations: k,
                last_change: change,
            });
        }
        t = next;
        if change <= SDA_CHANGE_TOLERANCE || a_norm * a_norm <= SDA_A_TOLERANCE {
            return Ok((t.h, k));
        }
    }
    if change <= SDA_ACCEPT_AT_CAP {
        return Ok((t.h, SDA_MAX_ITERATIONS));
    }
    Err(KalmanError::NoConvergence {
        iterations: SDA_MAX_ITERATIONS,
        last_change: change,
    })
}

/// Solution of the Stein equation X − A X Aᵀ = C (ρ(A) < 1) by doubling:
/// X = Σ_k A^k C A^kᵀ, X_{j+1} = X_j + A_j X_j A_jᵀ, A_{j+1} = A_j². None if it diverges.
fn stein(a: &Mat<f64>, c: &Mat<f64>) -> Option<Mat<f64>> {
    let mut x = c.clone();
    let mut aj = a.clone();
    for _ in 0..SDA_MAX_ITERATIONS {
        let add = symmetrise(&(&aj * &x * aj.transpose()));
        let add_norm = add.norm_l2();
        x += &add;
        aj = &aj * &aj;
        let a_norm = aj.norm_l2();
        if !a_norm.is_finite() || !add_norm.is_finite() {
            return None;
        }
        if a_norm * a_norm <= SDA_A_TOLERANCE || add_norm <= 1e-17 * x.norm_l2() {
            return Some(x);
        }
    }
    None
}

/// Result of a measurement update with the Joseph form.
struct Update {
    gain: Mat<f64>,
    posterior: Mat<f64>,
    innovation_covariance: Mat<f64>,
}

/// K = P Hᵀ S⁻¹, S = H P Hᵀ + R; posterior (I − K H) P (I − K H)ᵀ + K R Kᵀ.
fn measurement_update(p: &Mat<f64>, h: &Mat<f64>, r: &Mat<f64>) -> Update {
    let n = p.nrows();
    let m = h.nrows();
    if m == 0 {
        return Update {
            gain: Mat::zeros(n, 0),
            posterior: p.clone(),
            innovation_covariance: Mat::zeros(0, 0),
        };
    }
    let hp = h * p;
    let s = symmetrise(&(&hp * h.transpose() + r));
    let kt = match s.llt(Side::Lower) {
        Ok(chol) => chol.solve(&hp),
        Err(_) => s.partial_piv_lu().solve(&hp),
    };
    let gain = kt.transpose().to_owned();
    let mut i_kh = Mat::<f64>::identity(n, n);
    i_kh -= &gain * h;
    let posterior = symmetrise(&(&i_kh * p * i_kh.transpose() + &gain * r * gain.transpose()));
    Update {
        gain,
        posterior,
        innovation_covariance: s,
    }
}

/// One sweep through the period from the prior P₀ at phase 0.
#[derive(Clone)]
struct Sweep {
    phases: Vec<PhaseGain>,
    /// P_L − P₀: the fixed-point residual of the one-period map.
    residual: Mat<f64>,
    /// Φ = M_{L−1} ⋯ M₀, M_p = F (I − K_p H_p).
    propagator: Mat<f64>,
    /// S = H₀ P₀ H₀ᵀ + R₀.
    innovation_covariance: Mat<f64>,
}

fn sweep(f: &Mat<f64>, q: &Mat<f64>, phases: &[PhaseModel], p0: &Mat<f64>) -> Sweep {
    let n = f.nrows();
    let mut p = p0.clone();
    let mut phi = Mat::<f64>::identity(n, n);
    let mut out = Vec::with_capacity(phases.len());
    let mut s0 = Mat::zeros(0, 0);
    for (k, ph) in phases.iter().enumerate() {
        let up = measurement_update(&p, &ph.h, &ph.r);
        let mut m = f.clone();
        m -= f * &up.gain * &ph.h;
        phi = &m * &phi;
        let next = symmetrise(&(f * &up.posterior * f.transpose() + q));
        if k == 0 {
            s0 = up.innovation_covariance;
        }
        out.push(PhaseGain {
            measured: ph.measured.clone(),
            gain: up.gain,
            prior_covariance: p,
            posterior_covariance: up.posterior,
        });
        p = next;
    }
    Sweep {
        phases: out,
        residual: symmetrise(&(&p - p0)),
        propagator: phi,
        innovation_covariance: s0,
    }
}

struct Solved {
    phases: Vec<PhaseGain>,
    worst_relative_residual: f64,
    closed_loop_spectral_radius: f64,
    condition: f64,
    iterations: usize,
}

fn relative(res: &Mat<f64>, p: &Mat<f64>, q: &Mat<f64>) -> f64 {
    res.norm_l2() / p.norm_l2().max(q.norm_l2()).max(f64::MIN_POSITIVE)
}

/// A candidate P₀ with its sweep and relative residual.
#[derive(Clone)]
struct Candidate {
    p0: Mat<f64>,
    sw: Sweep,
    res: f64,
}

impl Candidate {
    fn new(f: &Mat<f64>, q: &Mat<f64>, phases: &[PhaseModel], p0: Mat<f64>) -> Self {
        let sw = sweep(f, q, phases, &p0);
        let res = relative(&sw.residual, &p0, q);
        Self { p0, sw, res }
    }
}

/// Newton (Hewer) steps on the one-period map in correction form:
/// P₀ ← P₀ + Δ with Δ − Φ Δ Φᵀ = P_L − P₀, Φ the closed-loop propagator of the current gains
/// (equivalently P₀ ← the periodic Lyapunov solution of the current gains: Hewer's
/// iteration, which stays stabilizing and converges monotonically from a stabilizing start).
///
/// `polish`: keep a step only while it reduces the residual, stop when it no longer halves
/// it. Otherwise (Hewer from a stabilizing start): take every step, stop when the step is at
/// rounding level or the residual has not improved for three steps, return the best iterate.
/// Returns the result and the number of steps taken.
fn newton(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
    start: Candidate,
    max_steps: usize,
    polish: bool,
) -> (Candidate, usize) {
    let mut cur = start;
    let mut best: Option<Candidate> = None;
    let mut since_best = 0;
    let mut steps = 0;
    while steps < max_steps && cur.res > NEWTON_DONE {
        let Some(delta) = stein(&cur.sw.propagator, &cur.sw.residual) else {
            break;
        };
        let cand = Candidate::new(f, q, phases, symmetrise(&(&cur.p0 + &delta)));
        if !cand.res.is_finite() {
            break;
        }
        if polish {
            if cand.res >= cur.res {
                break;
            }
            let halved = cand.res <= 0.5 * cur.res;
            cur = cand;
            steps += 1;
            if !halved {
                break;
            }
        } else {
            let small = delta.norm_l2() <= 1e-14 * cand.p0.norm_l2();
            let prev = std::mem::replace(&mut cur, cand);
            steps += 1;
            match &best {
                Some(b) if b.res <= prev.res => since_best += 1,
                _ => {
                    best = Some(prev);
                    since_best = 0;
                }
            }
            if small || since_best >= 3 {
                break;
            }
        }
    }
    match best {
        Some(b) if b.res < cur.res => (b, steps),
        _ => (cur, steps),
    }
}

/// Route: SDA on the composed one-period map, Newton polish; if that fails (no convergence,
/// residual too large or a closed loop that is not stable — seen with near-perfect sensors,
/// R ≲ 1e-16 relative to H Q Hᵀ, where I + G H has condition ~ 1/R and rounding makes the
/// doubling collapse onto a non-stabilizing solution) and F is Schur-stable, Hewer's
/// iteration from the stabilizing gain K = 0 (P₀ = 0), then the same checks.
fn solve_periodic(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
) -> Result<Solved, KalmanError> {
    let ft = f.transpose().to_owned();
    let triple = |ph: &PhaseModel| Triple {
        a: ft.clone(),
        g: ph.g.clone(),
        h: q.clone(),
    };
    let mut map = triple(&phases[0]);
    for ph in &phases[1..] {
        map = compose(&map, &triple(ph));
    }
    let accept_ref = |c: &Candidate| -> Result<f64, KalmanError> {
        if c.res.is_nan() || c.res > RESIDUAL_THRESHOLD {
            return Err(KalmanError::ResidualTooLarge {
                residual: c.res,
                threshold: RESIDUAL_THRESHOLD,
            });
        }
        let radius = spectral_radius(&c.sw.propagator)?;
        if radius.is_nan() || radius >= 1.0 {
            return Err(KalmanError::UnstableClosedLoop {
                radius,
                innovation_condition: condition_spd(&c.sw.innovation_covariance)?,
            });
        }
        Ok(radius)
    };
    let finish = |c: Candidate, radius: f64, iterations: usize| -> Result<Solved, KalmanError> {
        let condition = condition_spd(&c.sw.innovation_covariance)?;
        Ok(Solved {
            phases: c.sw.phases,
            worst_relative_residual: c.res,
            closed_loop_spectral_radius: radius,
            condition,
            iterations,
        })
    };
    let n = f.nrows();
    let mut failed: Vec<(Candidate, usize)> = Vec::new();
    // Route 1: SDA on the one-period map, Newton polish.
    let first_err = match sda(map) {
        Ok((p0, iterations)) => {
            let start = Candidate::new(f, q, phases, p0);
            let (c, steps) = newton(f, q, phases, start, NEWTON_STEPS, true);
            match accept_ref(&c) {
                Ok(radius) => return finish(c, radius, iterations + steps),
                Err(e) => {
                    failed.push((c, iterations + steps));
                    e
                }
            }
        }
        Err(e) => e,
    };
    // Route 2 (F Schur-stable): Hewer's iteration from the stabilizing gain K = 0.
    if spectral_radius(f)? < 1.0 {
        let start = Candidate::new(f, q, phases, Mat::zeros(n, n));
        let (c, steps) = newton(f, q, phases, start, HEWER_MAX_STEPS, false);
        let (c, more) = newton(f, q, phases, c, NEWTON_STEPS, true);
        match accept_ref(&c) {
            Ok(radius) => return finish(c, radius, steps + more),
            Err(_) => failed.push((c, steps + more)),
        }
    }
    // Route 3: a Newton/SDA iterate carries absolute rounding ~ eps‖P‖ in every direction;
    // when H P Hᵀ + R is ill-conditioned (small R, more sensors than noise channels) that
    // noise is amplified into K and the closed loop can fail the check although a
    // stabilizing filter exists. The plain Riccati recursion P₀ ← P_L (Joseph form) is
    // attracted to the stabilizing solution and keeps the structure that makes K well
    // defined: run it from the best candidate within a flop budget.
    let max_sweeps = (RECURSION_FLOP_BUDGET / (8.0 * (n * n * n * phases.len()) as f64))
        .clamp(1.0, RECURSION_MAX_SWEEPS as f64) as usize;
    let best = failed
        .into_iter()
        .filter(|(c, _)| c.res.is_finite())
        .min_by(|a, b| a.0.res.total_cmp(&b.0.res));
    if let Some((c, iterations)) = best {
        if let Some((c, radius, sweeps)) = settle(f, q, phases, c, max_sweeps, &accept_ref) {
            return finish(c, radius, iterations + sweeps);
        }
    }
    Err(first_err)
}

/// Plain Riccati sweeps P₀ ← P_L from `c` (at most `max_sweeps`): at the first iterate that
/// passes `accept` (checked every [`RECURSION_CHECK_EVERY`] sweeps once the residual is
/// below the threshold), continue while the residual decreases (at most as many sweeps
/// again) and return the last iterate if it still passes, else the first.
fn settle(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
    mut c: Candidate,
    max_sweeps: usize,
    accept: &dyn Fn(&Candidate) -> Result<f64, KalmanError>,
) -> Option<(Candidate, f64, usize)> {
    let next = |c: &Candidate| Candidate::new(f, q, phases, symmetrise(&(&c.p0 + &c.sw.residual)));
    for sweeps in 1..=max_sweeps {
        c = next(&c);
        if !c.res.is_finite() {
            return None;
        }
        if c.res > RESIDUAL_THRESHOLD || sweeps % RECURSION_CHECK_EVERY != 0 {
            continue;
        }
        let Ok(radius) = accept(&c) else {
            continue;
        };
        let first = (c.clone(), radius, sweeps);
        let mut done = sweeps;
        while done < (2 * sweeps).min(max_sweeps) {
            let cand = next(&c);
            if cand.res.is_nan() || cand.res >= c.res {
                break;
            }
            c = cand;
            done += 1;
        }
        if done > sweeps {
            if let Ok(radius) = accept(&c) {
                return Some((c, radius, done));
            }
        }
        return Some(first);
    }
    None
}

// ---------------------------------------------------------------------------------------------
// Input checks.

fn check_square(name: &str, m: MatRef<f64>) -> Result<(), KalmanError> {
    if m.nrows() != m.ncols() {
        return Err(KalmanError::Shape(format!(
            "{name} is {}x{}, must be square",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(())
}

fn check_shape(name: &str, m: MatRef<f64>, rows: usize, cols: usize) -> Result<(), KalmanError> {
    if m.nrows() != rows || m.ncols() != cols {
        return Err(KalmanError::Shape(format!(
            "{name} is {}x{}, expected {rows}x{cols}",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(())
}

fn check_finite(matrix: &'static str, m: MatRef<f64>) -> Result<(), KalmanError> {
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            let value = m[(i, j)];
            if !value.is_finite() {
                return Err(KalmanError::NonFinite {
                    matrix,
                    row: i,
                    col: j,
                    value,
                });
            }
        }
    }
    Ok(())
}

/// First (row, col) with |M_ij − M_ji| > tol · max|M|.
fn asymmetry(m: MatRef<f64>) -> Option<(usize, usize)> {
    let tol = SYMMETRY_TOLERANCE * m.norm_max();
    for j in 0..m.ncols() {
        for i in 0..j {
            if (m[(i, j)] - m[(j, i)]).abs() > tol {
                return Some((i, j));
            }
        }
    }
    None
}

fn validate_q(q: MatRef<f64>) -> Result<Mat<f64>, KalmanError> {
    if let Some((row, col)) = asymmetry(q) {
        return Err(KalmanError::QNotSymmetric {
            row,
            col,
            upper: q[(row, col)],
            lower: q[(col, row)],
        });
    }
    let q = symmetrise(&q.to_owned());
    let ev = q
        .self_adjoint_eigenvalues(Side::Lower)
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of Q: {e:?}")))?;
    if let (Some(&lo), Some(&hi)) = (ev.first(), ev.last()) {
        if lo < -PSD_TOLERANCE * hi.abs().max(f64::MIN_POSITIVE) {
            return Err(KalmanError::QNotPositiveSemidefinite {
                eigenvalue: lo,
                largest: hi,
            });
        }
    }
    Ok(q)
}

fn validate_r(r: MatRef<f64>) -> Result<Mat<f64>, KalmanError> {
    for i in 0..r.nrows() {
        let value = r[(i, i)];
        if value.is_nan() || value <= 0.0 {
            return Err(KalmanError::RDiagonalNotPositive { index: i, value });
        }
    }
    if let Some((row, col)) = asymmetry(r) {
        return Err(KalmanError::RNotSymmetric {
            row,
            col,
            upper: r[(row, col)],
            lower: r[(col, row)],
        });
    }
    let r = symmetrise(&r.to_owned());
    if r.nrows() > 0 {
        let ev = r
            .self_adjoint_eigenvalues(Side::Lower)
            .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of R: {e:?}")))?;
        let lo = ev.first().copied().unwrap_or(0.0);
        if lo.is_nan() || lo <= 0.0 || r.llt(Side::Lower).is_err() {
            return Err(KalmanError::RNotPositiveDefinite { eigenvalue: lo });
        }
    }
    Ok(r)
}

/// PBH tests on the eigenvalues of F with |λ| ≥ 1 − [`MARGINAL_STABILITY`]:
/// detectable ⇔ rank [λI − F; H] = r, stabilizable ⇔ rank [λ̄I − Fᵀ; Q] = r (Q PSD, so
/// wᴴQ = 0 ⇔ wᴴQ^{1/2} = 0). H and Q are scaled to ‖F‖_F so the rank test is scale-free.
fn check_detectable_stabilizable(
    f: &Mat<f64>,
    h: &Mat<f64>,
    q: &Mat<f64>,
) -> Result<(), KalmanError> {
    let n = f.nrows();
    let eig = f
        .eigenvalues()
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of F: {e:?}")))?;
    let f_norm = f.norm_l2().max(f64::MIN_POSITIVE);
    let scale = |x: f64| if x > 0.0 { f_norm / x } else { 0.0 };
    let (sh, sq) = (scale(h.norm_l2()), scale(q.norm_l2()));
    let mut tested: Vec<c64> = Vec::new();
    for lam in eig {
        let modulus = lam.re.hypot(lam.im);
        if modulus < 1.0 - MARGINAL_STABILITY || lam.im < 0.0 {
            continue;
        }
        // A repeated eigenvalue (rigid-body modes) is tested once: the rank test covers its
        // whole eigenspace.
        if tested
            .iter()
            .any(|t| (t.re - lam.re).hypot(t.im - lam.im) <= 1e-9 * modulus)
        {
            continue;
        }
        tested.push(lam);
        let pbh = |top: &dyn Fn(usize, usize) -> c64, bottom: &Mat<f64>, s: f64| {
            let k = bottom.nrows();
            let mat = Mat::<c64>::from_fn(n + k, n, |i, j| {
                if i < n {
                    top(i, j)
                } else {
                    c64::new(s * bottom[(i - n, j)], 0.0)
                }
            });
            mat.singular_values()
                .map(|sv| sv.last().copied().unwrap_or(0.0))
                .map_err(|e| KalmanError::LinearAlgebra(format!("PBH singular values: {e:?}")))
        };
        let diag = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        let sigma = pbh(
            &|i, j| c64::new(lam.re * diag(i, j) - f[(i, j)], lam.im * diag(i, j)),
            h,
            sh,
        )?;
        if sigma <= PBH_TOLERANCE * f_norm {
            return Err(KalmanError::Undetectable {
                re: lam.re,
                im: lam.im,
                modulus,
                sigma,
            });
        }
        let sigma = pbh(
            &|i, j| c64::new(lam.re * diag(i, j) - f[(j, i)], -lam.im * diag(i, j)),
            q,
            sq,
        )?;
        if sigma <= PBH_TOLERANCE * f_norm {
            return Err(KalmanError::Unstabilizable {
                re: lam.re,
                im: lam.im,
                modulus,
                sigma,
            });
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Small helpers.

/// (M + Mᵀ)/2.
fn symmetrise(m: &Mat<f64>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| 0.5 * (m[(i, j)] + m[(j, i)]))
}

/// 2-norm condition λ_max/λ_min of a symmetric positive (semi)definite matrix; 1 if empty,
/// ∞ if singular.
fn condition_spd(s: &Mat<f64>) -> Result<f64, KalmanError> {
    if s.nrows() == 0 {
        return Ok(1.0);
    }
    let ev = s
        .self_adjoint_eigenvalues(Side::Lower)
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of H P Hᵀ + R: {e:?}")))?;
    let lo = ev.first().copied().unwrap_or(1.0);
    let hi = ev.last().copied().unwrap_or(1.0);
    Ok(if lo > 0.0 { hi / lo } else { f64::INFINITY })
}

/// max |λ(M)|.
fn spectral_radius(m: &Mat<f64>) -> Result<f64, KalmanError> {
    let ev = m.eigenvalues().map_err(|e| {
        KalmanError::LinearAlgebra(format!("eigenvalues of the closed loop: {e:?}"))
    })?;
    Ok(ev.iter().map(|l| l.re.hypot(l.im)).fold(0.0, f64::max))
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}
