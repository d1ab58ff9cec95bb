//! Metrics of the comparison: relative L2 errors accumulated over a trajectory, the rotation
//! angle of a rotation matrix, the breakdown rotation of a sweep, and the seeded Gaussian noise
//! of the synthetic measurements.

use super::SweepPoint;

// ---------------------------------------------------------------------------------------------
// Noise

/// xorshift64* generator with Box–Muller Gaussian samples.
#[derive(Clone, Debug)]
pub struct Gaussian {
    state: u64,
    spare: Option<f64>,
}

impl Gaussian {
    /// A generator from `seed` (0 is replaced by a fixed non-zero value).
    pub fn new(seed: u64) -> Self {
        Gaussian {
            state: if seed == 0 {
                0x9e37_79b9_7f4a_7c15
            } else {
                seed
            },
            spare: None,
        }
    }

    /// Uniform in (0, 1], 53 bits (xorshift64*).
    pub fn uniform(&mut self) -> f64 {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        let v = self.state.wrapping_mul(0x2545_f491_4f6c_dd1d);
        ((v >> 11) + 1) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal sample (Box–Muller: √(−2 ln u₁)·(cos, sin)(2π u₂), both used).
    pub fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let (u1, u2) = (self.uniform(), self.uniform());
        let radius = (-2.0 * u1.ln()).sqrt();
        let angle = 2.0 * std::f64::consts::PI * u2;
        self.spare = Some(radius * angle.sin());
        radius * angle.cos()
    }
}

// ---------------------------------------------------------------------------------------------
// Setup shared by run and rotation_sweep

/// Accumulates Σ|u − u_ref|² and Σ|u_ref|².
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct ErrorSum {
    err2: f64,
    ref2: f64,
}

impl ErrorSum {
    pub(super) fn add(&mut self, approx: &[f64], exact: &[f64]) {
        for (a, e) in approx.iter().zip(exact) {
            self.err2 += (a - e) * (a - e);
            self.ref2 += e * e;
        }
    }

    /// sqrt(Σ|u − u_ref|² / Σ|u_ref|²); NaN when nothing was added.
    pub(super) fn relative(&self) -> f64 {
        if self.ref2 > 0.0 {
            (self.err2 / self.ref2).sqrt()
        } else if self.err2 == 0.0 {
            0.0
        } else {
            f64::NAN
        }
    }
}

/// Relative L2 error ‖a − b‖ / ‖b‖ of two equally long slices (b the reference).
pub fn relative_l2(approx: &[f64], exact: &[f64]) -> f64 {
    let mut s = ErrorSum::default();
    s.add(approx, exact);
    s.relative()
}

/// Angle θ of a rotation matrix, rad: atan2(|vee(R − Rᵀ)|/2, (tr R − 1)/2) (= atan2(sin θ,
/// cos θ), accurate for small angles where acos((tr R − 1)/2) is not).
pub fn rotation_angle(r: &nalgebra::Matrix3<f64>) -> f64 {
    let s = 0.5
        * ((r[(2, 1)] - r[(1, 2)]).powi(2)
            + (r[(0, 2)] - r[(2, 0)]).powi(2)
            + (r[(1, 0)] - r[(0, 1)]).powi(2))
        .sqrt();
    s.atan2(0.5 * (r.trace() - 1.0))
}

/// The largest rotation (degrees) of the sweep up to which the warped runtime's open-loop
/// error stays below `threshold` ([`breakdown_rotation_of`] on `open_loop_error`).
pub fn breakdown_rotation(points: &[SweepPoint], threshold: f64) -> Option<f64> {
    breakdown_rotation_of(points, threshold, |p| p.open_loop_error)
}

/// The largest rotation (degrees) of the sweep up to which `error(point)` stays below
/// `threshold`: points sorted by rotation, the last one before the first that reaches the
/// threshold (a NaN, e.g. a failed or absent run, counts as reaching it). `None` if even the
/// smallest rotation fails it.
pub fn breakdown_rotation_of(
    points: &[SweepPoint],
    threshold: f64,
    error: impl Fn(&SweepPoint) -> f64,
) -> Option<f64> {
    let mut sorted: Vec<&SweepPoint> = points.iter().collect();
    sorted.sort_by(|a, b| a.max_rotation_deg.total_cmp(&b.max_rotation_deg));
    let mut best = None;
    for p in sorted {
        let e = error(p);
        if e.is_nan() || e >= threshold {
            break;
        }
        best = Some(p.max_rotation_deg);
    }
    best
}
