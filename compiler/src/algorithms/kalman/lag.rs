//! The lag of a steady-state filter on the fastest load its scene states, against the
//! filter's own covariance (docs/design.md §11.8): the criterion from which the random-walk σ
//! of a load's force states is derived.
//!
//! A load that ramps at its stated rate moves its force states by δ per step along a unit
//! direction e, while the filter's model says their increments are zero-mean noise. The
//! persistent mismatch d = δ e (in the force block) drives the mean of the error
//! e_k = x_k − x̂_k through the steady periodic filter:
//! ```text
//! e⁻_{k+1} = F (I − K_p H_p) e⁻_k + d        (phase p = k mod L)
//! ```
//! whose periodic fixed point is the filter's lag. [`ramp_lag`] returns, over the phases and
//! every direction e, the largest Mahalanobis length² of the posterior lag's force block
//! against the posterior covariance's force block, λ = max_p λ_max(B_pᵀ P_ff,p⁻¹ B_p)
//! (B_p: the lag for e = x, y, z as columns). λ ≤ 1: the filter's lag on a stated load stays
//! within its own σ.

use faer::linalg::solvers::Solve as _;
use faer::{Mat, MatRef};

use super::PeriodicSchedule;

/// Why a lag could not be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LagError {
    /// The block of ramped states is not 3 states inside the state.
    #[error("ramped block {start}..{end} is not three states of the {n}-state filter")]
    Block {
        /// First state of the block.
        start: usize,
        /// One past the last.
        end: usize,
        /// State dimension.
        n: usize,
    },
    /// The period's error propagator has an eigenvalue at 1 (the filter does not settle).
    #[error("the filter's error propagator is not stable: no steady lag")]
    Unstable,
    /// The posterior covariance of the ramped block is singular.
    #[error("the posterior covariance of the ramped states is singular")]
    Singular,
}

/// The steady lag of `schedule` (filter of transition `f`, measurement rows `h`) on a ramp of
/// the three states `block` by `delta` per step along every direction; returns λ (module docs).
pub fn ramp_lag(
    f: MatRef<'_, f64>,
    h: MatRef<'_, f64>,
    schedule: &PeriodicSchedule,
    block: std::ops::Range<usize>,
    delta: f64,
) -> Result<f64, LagError> {
    let n = f.nrows();
    if block.len() != 3 || block.end > n {
        return Err(LagError::Block {
            start: block.start,
            end: block.end,
            n,
        });
    }
    let period = schedule.phases.len();
    // Per phase: (I − K_p H_p) (n × n).
    let update: Vec<Mat<f64>> = schedule
        .phases
        .iter()
        .map(|phase| {
            let mut m = Mat::<f64>::identity(n, n);
            for (a, &row) in phase.measured.iter().enumerate() {
                for i in 0..n {
                    let k = phase.gain[(i, a)];
                    if k != 0.0 {
                        for j in 0..n {
                            m[(i, j)] -= k * h[(row, j)];
                        }
                    }
                }
            }
            m
        })
        .collect();
    // One period as an affine map of the prior lag at phase 0, for the three directions at
    // once: e ← A e + c, A = Π F(I − K_p H_p), c the ramps added along the way.
    let mut a = Mat::<f64>::identity(n, n);
    let mut c = Mat::<f64>::zeros(n, 3);
    for u in &update {
        a = f * (u * &a);
        c = f * (u * &c);
        for k in 0..3 {
            c[(block.start + k, k)] += delta;
        }
    }
    let fixed = (Mat::<f64>::identity(n, n) - &a).partial_piv_lu();
    let mut prior = fixed.solve(&c);
    if !prior
        .col_iter()
        .all(|col| col.iter().all(|v| v.is_finite()))
    {
        return Err(LagError::Unstable);
    }
    let mut worst = 0.0f64;
    for (p, u) in update.iter().enumerate() {
        let posterior = u * &prior;
        let cov = &schedule.phases[p].posterior_covariance;
        let pff = Mat::<f64>::from_fn(3, 3, |i, j| cov[(block.start + i, block.start + j)]);
        let b = Mat::<f64>::from_fn(3, 3, |i, j| posterior[(block.start + i, j)]);
        let llt = pff.llt(faer::Side::Lower).map_err(|_| LagError::Singular)?;
        // Bᵀ P_ff⁻¹ B, symmetric 3 × 3; its largest eigenvalue.
        let x = llt.solve(&b);
        let m = b.transpose() * &x;
        let m = Mat::<f64>::from_fn(3, 3, |i, j| 0.5 * (m[(i, j)] + m[(j, i)]));
        let eig = m
            .self_adjoint_eigenvalues(faer::Side::Lower)
            .map_err(|_| LagError::Singular)?;
        let largest = eig.iter().copied().fold(0.0f64, f64::max);
        worst = worst.max(largest);
        if p + 1 < period {
            prior = f * &posterior;
            for k in 0..3 {
                prior[(block.start + k, k)] += delta;
            }
        }
    }
    Ok(worst)
}

/// The smallest σ in [lo, hi] whose filter has `lag(σ)` ≤ 1 (bisection in log σ to a
/// relative 1 %; λ falls as σ grows). `lag` designs the filter of σ and returns its λ
/// ([`ramp_lag`]); an error of the design counts as "not yet" (λ = ∞) below the answer.
/// When the filter of `hi` itself cannot be designed (a σ 10³ × another group's makes Q too
/// ill-scaled for the Riccati solver's checks), the upper end steps down by 10 until one can,
/// and the first error is returned when none above `lo` can. Returns the upper end with its λ
/// when even that lags beyond 1.
pub fn smallest_honest_sigma<E>(
    lo: f64,
    hi: f64,
    mut lag: impl FnMut(f64) -> Result<f64, E>,
) -> Result<(f64, f64), E> {
    let mut hi = hi;
    let mut first_error = None;
    let at_hi = loop {
        match lag(hi) {
            Ok(l) => break l,
            Err(e) => {
                let error = first_error.take().unwrap_or(e);
                if hi / 10.0 <= lo {
                    return Err(error);
                }
                first_error = Some(error);
                hi /= 10.0;
            }
        }
    };
    if at_hi > 1.0 {
        return Ok((hi, at_hi));
    }
    let (mut lo, mut hi, mut best) = (lo, hi, at_hi);
    while hi / lo > 1.01 {
        let mid = (lo * hi).sqrt();
        match lag(mid) {
            Ok(l) if l <= 1.0 => {
                hi = mid;
                best = l;
            }
            _ => lo = mid,
        }
    }
    Ok((hi, best))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::algorithms::kalman::periodic_gains;

    /// A force seen directly (y = f + v, σ_v) with a random walk of σ_f: the scalar steady
    /// filter has K = P⁻/(P⁻ + σ_v²), P⁻ = P + σ_f², and a ramp δ per step lags by
    /// δ(1 − K)/K; the block is three such independent channels.
    fn scalar_case(sigma_f: f64, sigma_v: f64, delta: f64) -> (f64, f64) {
        let n = 3;
        let f = Mat::<f64>::identity(n, n);
        let h = Mat::<f64>::identity(n, n);
        let q = Mat::<f64>::from_fn(n, n, |i, j| if i == j { sigma_f * sigma_f } else { 0.0 });
        let schedule = periodic_gains(
            f.as_ref(),
            h.as_ref(),
            q.as_ref(),
            &[sigma_v * sigma_v; 3],
            &[1; 3],
        )
        .expect("scalar DARE");
        let lag = ramp_lag(f.as_ref(), h.as_ref(), &schedule, 0..3, delta).expect("lag");
        // Closed form.
        let (s2, v2) = (sigma_f * sigma_f, sigma_v * sigma_v);
        let prior = 0.5 * (s2 + (s2 * s2 + 4.0 * s2 * v2).sqrt());
        let k = prior / (prior + v2);
        let post = (1.0 - k) * prior;
        let e = delta * (1.0 - k) / k;
        (lag, e * e / post)
    }

    #[test]
    fn the_lag_of_a_scalar_random_walk_is_the_closed_form() {
        for &(sf, sv, d) in &[(0.1, 1.0, 0.05), (1.0, 1.0, 0.3), (0.01, 2.0, 0.001)] {
            let (lag, exact) = scalar_case(sf, sv, d);
            assert!(
                (lag - exact).abs() <= 1e-8 * exact.max(1e-12),
                "σ_f {sf}, σ_v {sv}, δ {d}: {lag} against {exact}"
            );
        }
    }

    #[test]
    fn the_smallest_honest_sigma_meets_the_closed_form() {
        // λ = δ²σ_v/σ_f³ for σ_f ≪ σ_v: σ_f ≈ (δ²σ_v)^{1/3}.
        let (sv, d) = (10.0, 0.01);
        let (sigma, lag) =
            smallest_honest_sigma(1e-6, 10.0, |s| Ok::<_, LagError>(scalar_case(s, sv, d).0))
                .expect("bisection");
        let approx = (d * d * sv).cbrt();
        assert!(lag <= 1.0);
        assert!(
            (sigma / approx - 1.0).abs() < 0.1,
            "σ {sigma} against the small-σ closed form {approx}"
        );
        // Just below the answer the lag is beyond one σ.
        assert!(scalar_case(sigma / 1.02, sv, d).0 > 1.0);
    }

    /// A design that fails at the top of the range (as an ill-scaled Q does) moves the top down
    /// by decades: the answer is the same as with a range that starts below the failure; a
    /// design that fails everywhere returns the first error.
    #[test]
    fn a_failing_design_at_the_top_steps_down() {
        let (sv, d) = (10.0, 0.01);
        let design = |s: f64| {
            if s > 0.5 {
                Err("no filter")
            } else {
                Ok(scalar_case(s, sv, d).0)
            }
        };
        let (sigma, lag) = smallest_honest_sigma(1e-6, 10.0, design).expect("steps down");
        let (reference, _) = smallest_honest_sigma(1e-6, 0.1, design).expect("in range");
        assert!(lag <= 1.0);
        assert!(
            (sigma / reference - 1.0).abs() < 0.02,
            "{sigma} vs {reference}"
        );
        let none = smallest_honest_sigma(1e-6, 10.0, |_| Err::<f64, _>("no filter"));
        assert_eq!(none, Err("no filter"));
    }

    #[test]
    fn a_block_outside_the_state_is_refused() {
        let f = Mat::<f64>::identity(2, 2);
        let h = Mat::<f64>::identity(2, 2);
        let q = Mat::<f64>::identity(2, 2);
        let s = periodic_gains(f.as_ref(), h.as_ref(), q.as_ref(), &[1.0; 2], &[1; 2]).unwrap();
        assert!(matches!(
            ramp_lag(f.as_ref(), h.as_ref(), &s, 0..3, 1.0),
            Err(LagError::Block { .. })
        ));
    }
}
