//! Co-rotational maps of docs/design.md §5, applied to 3-vectors without heap allocation.
//!
//! With ω ∈ ℝ³ (rad), θ = |ω| and W = `[ω]×` (so W v = ω × v):
//!
//! ```text
//! R(ω)    = I + A₀ W + A₁ W²          A₀ = sin θ / θ,  A₁ = (1 − cos θ)/θ²
//! R̃(ω)   = I + A₁ W + B₁ W²          B₁ = (θ − sin θ)/θ³          (= ∫₀¹ R(sω) ds)
//! R̃(ω)⁻¹ = I − (A₁/D) W + ((A₁² − A₀B₁)/D) W²,   D = A₀² + θ²A₁² = det R̃ = (sin(θ/2)/(θ/2))²
//! ```
//!
//! These are the forms of docs/design.md §5 with n = ω/θ absorbed into W (so no division by
//! θ). The inverse follows because all three are polynomials in W with W³ = −θ²W: on the
//! plane ⊥ ω, W/θ acts as multiplication by i, on ω itself as 0. For θ < 1/2 the coefficients come from
//! their Taylor series (no cancellation); D vanishes only at θ = 2π, 4π, …

/// 3-vector.
pub type Vec3 = [f64; 3];
/// 3×3 matrix, row-major rows.
pub type Mat3 = [[f64; 3]; 3];

/// ω × v.
#[inline]
pub fn cross(a: &Vec3, b: &Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Taylor coefficients (−1)^k / (2k + j)!, k = 0..8, for j = 1, 2, 3.
const SERIES: [[f64; 9]; 3] = [
    [
        1.0,
        -0.16666666666666666,
        0.008333333333333333,
        -0.0001984126984126984,
        2.7557319223985893e-06,
        -2.505210838544172e-08,
        1.6059043836821613e-10,
        -7.647163731819816e-13,
        2.8114572543455206e-15,
    ],
    [
        0.5,
        -0.041666666666666664,
        0.001388888888888889,
        -2.48015873015873e-05,
        2.755731922398589e-07,
        -2.08767569878681e-09,
        1.1470745597729725e-11,
        -4.779477332387385e-14,
        1.5619206968586225e-16,
    ],
    [
        0.16666666666666666,
        -0.008333333333333333,
        0.0001984126984126984,
        -2.7557319223985893e-06,
        2.505210838544172e-08,
        -1.6059043836821613e-10,
        7.647163731819816e-13,
        -2.8114572543455206e-15,
        8.22063524662433e-18,
    ],
];

/// Σ_{k=0..8} (−1)^k t^k / (2k + j)! by Horner, for t = θ² < 1/4 (the first omitted term is
/// below 1e-19 relative).
#[inline]
fn series(t: f64, j: usize) -> f64 {
    SERIES[j - 1].iter().rev().fold(0.0, |acc, &c| acc * t + c)
}

/// (A₀, A₁, B₁) = (sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³) at θ = |ω|.
#[inline]
pub fn coefficients(omega: &Vec3) -> (f64, f64, f64) {
    let t = omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2];
    if t < 0.25 {
        (series(t, 1), series(t, 2), series(t, 3))
    } else {
        let th = t.sqrt();
        let (s, c) = th.sin_cos();
        (s / th, (1.0 - c) / t, (th - s) / (t * th))
    }
}

/// v + a (ω × v) + b (ω × (ω × v)) = (I + aW + bW²) v.
#[inline]
fn poly(omega: &Vec3, a: f64, b: f64, v: &Vec3) -> Vec3 {
    let wv = cross(omega, v);
    let wwv = cross(omega, &wv);
    [
        v[0] + a * wv[0] + b * wwv[0],
        v[1] + a * wv[1] + b * wwv[1],
        v[2] + a * wv[2] + b * wwv[2],
    ]
}

/// The maps of one rotation vector ω, with the coefficients (A₀, A₁, B₁) computed once.
#[derive(Clone, Copy, Debug)]
pub struct Warp {
    omega: Vec3,
    /// θ² = |ω|².
    t: f64,
    a0: f64,
    a1: f64,
    b1: f64,
}

impl Warp {
    /// The maps of ω (rad).
    #[inline]
    pub fn new(omega: &Vec3) -> Self {
        let (a0, a1, b1) = coefficients(omega);
        let t = omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2];
        Warp {
            omega: *omega,
            t,
            a0,
            a1,
            b1,
        }
    }

    /// |ω|, rad.
    pub fn angle(&self) -> f64 {
        self.t.sqrt()
    }

    /// R(ω) v.
    #[inline]
    pub fn rotate(&self, v: &Vec3) -> Vec3 {
        poly(&self.omega, self.a0, self.a1, v)
    }

    /// R(ω)ᵀ v.
    #[inline]
    pub fn rotate_transpose(&self, v: &Vec3) -> Vec3 {
        poly(&self.omega, -self.a0, self.a1, v)
    }

    /// R̃(ω) v.
    #[inline]
    pub fn warp(&self, v: &Vec3) -> Vec3 {
        poly(&self.omega, self.a1, self.b1, v)
    }

    /// det R̃(ω) = A₀² + θ²A₁² = (sin(θ/2)/(θ/2))².
    #[inline]
    pub fn determinant(&self) -> f64 {
        self.a0 * self.a0 + self.t * self.a1 * self.a1
    }

    /// R̃(ω)⁻¹ v, or `None` when det R̃ < 1e-10 (θ near 2π: not invertible).
    #[inline]
    pub fn unwarp(&self, v: &Vec3) -> Option<Vec3> {
        let d = self.determinant();
        if d < 1e-10 || !d.is_finite() {
            return None;
        }
        Some(poly(
            &self.omega,
            -self.a1 / d,
            (self.a1 * self.a1 - self.a0 * self.b1) / d,
            v,
        ))
    }
}

/// R(ω) v: rotation by the angle |ω| about ω/|ω|.
#[inline]
pub fn rotate(omega: &Vec3, v: &Vec3) -> Vec3 {
    Warp::new(omega).rotate(v)
}

/// R(ω)ᵀ v = R(−ω) v: world-frame vector into the local (co-rotated) frame.
#[inline]
pub fn rotate_transpose(omega: &Vec3, v: &Vec3) -> Vec3 {
    Warp::new(omega).rotate_transpose(v)
}

/// R̃(ω) v: local-frame displacement to world-frame displacement (modal warping).
#[inline]
pub fn warp(omega: &Vec3, v: &Vec3) -> Vec3 {
    Warp::new(omega).warp(v)
}

/// R̃(ω)⁻¹ v, or `None` when det R̃ = (sin(θ/2)/(θ/2))² < 1e-10 (θ near 2π: not invertible).
#[inline]
pub fn unwarp(omega: &Vec3, v: &Vec3) -> Option<Vec3> {
    Warp::new(omega).unwarp(v)
}

/// det R̃(ω) = (sin(θ/2)/(θ/2))².
pub fn warp_determinant(omega: &Vec3) -> f64 {
    Warp::new(omega).determinant()
}

fn matrix_of(f: impl Fn(&Vec3) -> Vec3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for j in 0..3 {
        let mut e = [0.0; 3];
        e[j] = 1.0;
        let col = f(&e);
        for i in 0..3 {
            m[i][j] = col[i];
        }
    }
    m
}

/// R(ω) as a matrix.
pub fn rotation_matrix(omega: &Vec3) -> Mat3 {
    matrix_of(|v| rotate(omega, v))
}

/// R̃(ω) as a matrix.
pub fn warp_matrix(omega: &Vec3) -> Mat3 {
    matrix_of(|v| warp(omega, v))
}
