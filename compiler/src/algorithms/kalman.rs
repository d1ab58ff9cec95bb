//! Kalman stage (docs/design.md §6): steady-state gains of the reduced model
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

use faer::{c64, Mat, MatRef, Side};

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

pub mod adaptation;
pub mod als;
mod checks;
mod error;
pub mod lag;
mod sda;

use checks::*;
pub use error::KalmanError;
use sda::*;

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
    /// Phases 0..L; phase p measures the rows i with p % every\[i\] == 0.
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

/// Checks the shapes and values shared by both Riccati entry points: F square with at least
/// one state, H m×n, Q n×n, all finite. Returns m, the number of measurement rows.
fn check_system(f: MatRef<f64>, h: MatRef<f64>, q: MatRef<f64>) -> Result<usize, KalmanError> {
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
    for (name, mat) in [("F", f), ("H", h), ("Q", q)] {
        check_finite(name, mat)?;
    }
    Ok(m)
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
    let m = check_system(f, h, q)?;
    check_shape("R", r, m, m)?;
    check_finite("R", r)?;
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
/// p % every\[i\] == 0 (phase 0 measures all). The per-phase a priori covariances satisfy
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
    let m = check_system(f, h, q)?;
    let n = f.nrows();
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
