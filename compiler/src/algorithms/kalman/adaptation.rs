//! The adaptive force σ's statistic (docs/design.md §11.10): the parameters the runtime needs
//! to choose, from its own innovations, among filters designed at several levels of the force
//! states' σ, computed here once so that the runtime does no statistics of its own.
//!
//! Per measurement channel j the runtime keeps an exponentially weighted mean of the whitened
//! innovation z_j = ν_j / √s_j (s_j = (H P⁻ Hᵀ)_jj + R_jj of the filter in use),
//! e_j ← (1 − a_j) e_j + a_j z_j at every update in which j has a value, started at 0 after each
//! change of level. For white innovations of unit variance (the filter's own model holds)
//! e_j is Gaussian with variance v_j(n) = a_j/(2 − a_j) · (1 − (1 − a_j)^{2n}) after n updates,
//! and the statistic
//! ```text
//! T = (1/m) Σ_j e_j² / v_j(n_j)          (m channels)
//! ```
//! has mean 1. If the m whitened channels were independent, m T ~ χ²(m); they are correlated
//! through the state error the channels share (C = D^{-1/2} S D^{-1/2}, D = diag S), and m T is
//! then a sum of χ²₁ weighted by the eigenvalues of C, matched in mean and variance by
//! c χ²(ν) with ν = m² / ‖C‖²_F, c = m / ν (Satterthwaite 1946): T ≈ χ²(ν)/ν. σ is raised one
//! level when T > χ²_{p_raise}(ν)/ν; every W steps since the last change or check T is compared
//! with χ²_{0.5}(ν)/ν, and below it σ is lowered one level (below the designed σ only while
//! every estimated load is told, `crokf_runtime`'s rule).
//!
//! The window W is the smallest stated rise time of the estimated loads in steps (at least
//! [`MIN_WINDOW`]): a ramp's lag is averaged over about its own duration; a channel measured
//! every k steps averages W/k of its updates, a_j = 2 / (W/k + 1) (the EWMA whose centre of
//! mass lies (W/k − 1)/2 updates back, as a moving average over W/k updates).

use faer::Mat;

/// The factors on the designed force σ of the levels stored besides the designed one (factor
/// 1, the tier's own `kalman`): a grid of ratio 4 in σ. The derived σ grows as the stated
/// ramp's increment to the power 2/3 (docs/design.md §11.8), so one level up serves ramps about
/// 8× faster than stated and the two levels down ramps about 8× and 64× slower (a load that
/// nearly holds, or one that is given and leaves the force states only the model's error).
pub const LEVEL_FACTORS: [f64; 3] = [4.0, 0.25, 0.0625];

/// Shortest averaging window, steps (also per channel, in updates).
pub const MIN_WINDOW: usize = 5;

/// Φ⁻¹(0.999): T stays below the raising threshold at one update with probability 0.999 when
/// the filter's model holds (a false raise at most once per 1,000 updates).
const RAISE_NORMAL_QUANTILE: f64 = 3.090_232_306_167_813_5;

/// The χ² quantile of probability p for ν degrees of freedom (ν > 0, real), given z = Φ⁻¹(p):
/// Wilson–Hilferty, χ²_p(ν) ≈ ν (1 − 2/(9ν) + z √(2/(9ν)))³ (at p = 0.999 within 2 % of the
/// tables for ν ≥ 3, 0.5 % at ν = 12; the median within 1 %).
pub fn chi_square_quantile(normal_quantile: f64, dof: f64) -> f64 {
    let h = 2.0 / (9.0 * dof);
    dof * (1.0 - h + normal_quantile * h.sqrt()).max(0.0).powi(3)
}

/// The effective number of independent channels of an innovation covariance S (m × m,
/// symmetric, positive diagonal): ν = m² / ‖C‖²_F with C = D^{-1/2} S D^{-1/2} (module docs);
/// m when the channels are uncorrelated, 1 when they are one signal.
pub fn effective_channels(s: &Mat<f64>) -> f64 {
    let m = s.nrows();
    if m == 0 {
        return 0.0;
    }
    let mut frobenius = 0.0;
    for i in 0..m {
        for j in 0..m {
            let c = s[(i, j)] / (s[(i, i)] * s[(j, j)]).sqrt();
            frobenius += c * c;
        }
    }
    (m * m) as f64 / frobenius
}

/// What the runtime's statistic needs (module docs), for the model file.
#[derive(Clone, Debug, PartialEq)]
pub struct Statistic {
    /// The averaging window W, steps.
    pub window: usize,
    /// Per measurement channel (model order): a_j.
    pub smoothing: Vec<f64>,
    /// ν, the effective number of independent channels the thresholds are set for.
    pub effective_channels: f64,
    /// χ²_{0.999}(ν)/ν: σ is raised one level when T exceeds it.
    pub raise_above: f64,
    /// χ²_{0.5}(ν)/ν: σ is lowered one level when T is below it at a check (every W steps).
    pub lower_below: f64,
}

impl Statistic {
    /// The statistic for the smallest stated rise time `rise_time` (s) of the estimated loads,
    /// time step `dt` (s), the channels measured every `every[j]` steps, and ν = `effective`
    /// (the smallest [`effective_channels`] over the stored filters: the thresholds of the
    /// most correlated filter, the fewest false raises and the most reluctant lowering).
    pub fn new(rise_time: f64, dt: f64, every: &[u32], effective: f64) -> Statistic {
        let window = ((rise_time / dt).round() as usize).max(MIN_WINDOW);
        let smoothing = every
            .iter()
            .map(|&k| {
                let updates = (window as f64 / k.max(1) as f64).max(MIN_WINDOW as f64);
                2.0 / (updates + 1.0)
            })
            .collect();
        let nu = effective.max(1.0);
        Statistic {
            window,
            smoothing,
            effective_channels: nu,
            raise_above: chi_square_quantile(RAISE_NORMAL_QUANTILE, nu) / nu,
            lower_below: chi_square_quantile(0.0, nu) / nu,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Wilson–Hilferty against tabulated quantiles (Abramowitz & Stegun table 26.8).
    #[test]
    fn chi_square_quantiles_match_the_tables() {
        for (dof, p999, p50) in [
            (3.0, 16.266, 2.366),
            (6.0, 22.458, 5.348),
            (12.0, 32.909, 11.340),
            (30.0, 59.703, 29.336),
        ] {
            let q = chi_square_quantile(RAISE_NORMAL_QUANTILE, dof);
            assert!((q / p999 - 1.0).abs() < 0.02, "ν {dof}: {q} vs {p999}");
            let q = chi_square_quantile(0.0, dof);
            assert!((q / p50 - 1.0).abs() < 0.01, "ν {dof}: {q} vs {p50}");
        }
    }

    /// Uncorrelated channels count fully, one signal repeated counts once, and the statistic's
    /// parameters follow the window (a channel every 10 steps averages a tenth of the updates,
    /// not fewer than MIN_WINDOW).
    #[test]
    fn effective_channels_and_window() {
        let diag = Mat::<f64>::from_fn(4, 4, |i, j| if i == j { 2.0 + i as f64 } else { 0.0 });
        assert!((effective_channels(&diag) - 4.0).abs() < 1e-12);
        let one = Mat::<f64>::from_fn(4, 4, |_, _| 3.0);
        assert!((effective_channels(&one) - 1.0).abs() < 1e-12);
        let s = Statistic::new(0.2, 0.002, &[1, 10, 100], 4.0);
        assert_eq!(s.window, 100);
        assert!((s.smoothing[0] - 2.0 / 101.0).abs() < 1e-15);
        assert!((s.smoothing[1] - 2.0 / 11.0).abs() < 1e-15);
        assert!((s.smoothing[2] - 2.0 / 6.0).abs() < 1e-15);
        assert!(
            s.raise_above > 4.0 && s.raise_above < 5.0,
            "{}",
            s.raise_above
        );
        assert!(
            s.lower_below < 1.0 && s.lower_below > 0.8,
            "{}",
            s.lower_below
        );
        assert_eq!(Statistic::new(0.001, 0.002, &[1], 1.0).window, MIN_WINDOW);
    }
}
