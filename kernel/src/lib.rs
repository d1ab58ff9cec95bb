//! The co-rotational element kernel of the hyper-reduced tier (docs/design.md §10), without
//! dependencies, shared by `crokf-compile` (its reduced stepper) and `crokf-runtime` (the
//! tier's step), so that there is one copy of the reduced element force; and the Wilson-θ
//! advance both use ([`wilson`]).
//!
//! One linear tetrahedron e with rest vertex positions Xₑ (m), shape-function gradients ∇Nₐ
//! (1/m), rest stiffness Kₑ (12×12, N/m, node-major, row-major) and basis rows V_e (12×r,
//! row-major; zero rows at fixed DOFs). With xₑ = Xₑ + V_e q, F = Σₐ xₐ ⊗ ∇Nₐ = R S (polar):
//! ```text
//! yₑ = Rᵀ(xₑ − x₀) − (Xₑ − X₀)                  (vertex-0-relative, per node)
//! fₑ = R Kₑ (yₑ + β Rᵀ V_e q̇)                    (internal + stiffness-proportional damping)
//! out += wₑ V_eᵀ fₑ                                (r)
//! K_t += wₑ V_eᵀ R Kₑ Rᵀ V_e                      (warped tangent, r×r)
//! ```

pub mod block;
pub mod exact;
mod lanes;
mod simd;
pub mod wilson;

pub use block::{Blocks, Isa};

/// 3×3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// Identity.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

#[cfg(test)]
fn det(m: &Mat3) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// X⁻ᵀ of an invertible 3×3 matrix (cofactor matrix / det), or `None` if det = 0.
#[cfg(test)]
fn inverse_transpose(m: &Mat3) -> Option<Mat3> {
    let d = det(m);
    if d == 0.0 || !d.is_finite() {
        return None;
    }
    let inv = 1.0 / d;
    // Cofactor matrix / det = (M⁻¹)ᵀ.
    Some([
        [
            (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
            (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
            (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
        ],
        [
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
        ],
        [
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv,
        ],
    ])
}

/// Why an element has no rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PolarError {
    /// det F ≤ 1e-12‖F‖³: the element is inverted or degenerate (det F given).
    Inverted(f64),
    /// Non-finite F or no convergence in 30 iterations.
    NoConvergence,
}

/// The rotation R of the polar decomposition F = R S by Newton's iteration
/// X ← ½(γX + (γX)⁻ᵀ): scaled by γ = (‖X⁻¹‖_F/‖X‖_F)^½ (Higham) while X is far from
/// orthogonal (‖ΔX‖_F > 1e-2), unscaled (γ = 1) near it, where the iteration converges
/// quadratically; stops when ‖ΔX‖_F ≤ 1e-8, when the next change would be ~1e-16 (3–4
/// iterations for an element strained by a few %). Refuses inverted or degenerate elements
/// (det F ≤ 1e-12‖F‖³_F). One copy of the iteration: the kernel's lane-wise polar with one
/// lane (which [`Blocks`] runs on 8 elements at once, bit-for-bit the same per lane).
#[inline(always)]
pub fn polar_rotation(f: &Mat3) -> Result<Mat3, PolarError> {
    let mut x = *f;
    let [result, ..] = lanes::polar_rotations::<f64>(&mut x);
    result.map(|()| x)
}

/// One sampled element's data (borrowed from the caller's flat storage).
#[derive(Clone, Copy, Debug)]
pub struct Element<'a> {
    /// ECSW weight wₑ ≥ 0.
    pub weight: f64,
    /// Rest vertex positions Xₑ, m.
    pub rest: &'a [[f64; 3]; 4],
    /// ∇Nₐ, 1/m.
    pub gradients: &'a [[f64; 3]; 4],
    /// Kₑ, 144 values row-major, N/m; symmetric (the linear-elastic element stiffness).
    pub stiffness: &'a [f64],
    /// V_e, 12·r values row-major.
    pub rows: &'a [f64],
    /// V_eᵀ, r·12 values row-major (the same numbers transposed: `cols[12 j + i]` =
    /// `rows[r i + j]`), so that the gather V_e q runs 12 lanes wide.
    pub cols: &'a [f64],
}

/// V_eᵀ (r × 12, row-major) of V_e (12 × r, row-major).
pub fn transpose_rows(rows: &[f64]) -> Vec<f64> {
    let r = rows.len() / 12;
    let mut cols = vec![0.0; rows.len()];
    for i in 0..12 {
        for j in 0..r {
            cols[12 * j + i] = rows[r * i + j];
        }
    }
    cols
}

/// The element's state at q: current vertex positions xₑ = Xₑ + V_e q (m), V_e q̇ (12, m/s)
/// and the deformation gradient F = Σₐ xₐ ⊗ ∇Nₐ.
#[derive(Clone, Copy, Debug)]
pub struct Gathered {
    /// xₑ, m.
    pub x: [[f64; 3]; 4],
    /// V_e q̇, node-major.
    pub velocity: [f64; 12],
    /// F.
    pub f: Mat3,
}

/// Gathers the element's state at `q`, `velocity` (r each; r = `cols.len() / 12`).
///
/// V_e q and V_e q̇ accumulate column by column in three 4-lane blocks each (12 = 3 × 4), a
/// shape LLVM turns into full-width vector multiply–adds (with AVX2: six per column, no
/// shuffles); each entry is still summed over j in order, so the result is the plain loop's.
#[inline(always)]
pub fn gather(e: &Element, q: &[f64], velocity: &[f64]) -> Gathered {
    debug_assert_eq!(
        e.cols.len(),
        e.rows.len(),
        "gather needs V_eᵀ (Element::cols)"
    );
    let mut u = [[0.0f64; 4]; 3];
    let mut v = [[0.0f64; 4]; 3];
    for (col, (&qj, &vj)) in e.cols.chunks_exact(12).zip(q.iter().zip(velocity)) {
        for b in 0..3 {
            for l in 0..4 {
                u[b][l] += col[4 * b + l] * qj;
                v[b][l] += col[4 * b + l] * vj;
            }
        }
    }
    let mut x = [[0.0; 3]; 4];
    let mut ve = [0.0; 12];
    for i in 0..12 {
        x[i / 3][i % 3] = e.rest[i / 3][i % 3] + u[i / 4][i % 4];
        ve[i] = v[i / 4][i % 4];
    }
    let mut f = [[0.0; 3]; 3];
    for (xa, g) in x.iter().zip(e.gradients) {
        for i in 0..3 {
            for j in 0..3 {
                f[i][j] += xa[i] * g[j];
            }
        }
    }
    Gathered { x, velocity: ve, f }
}

/// Adds wₑ V_eᵀ R Kₑ (yₑ + β Rᵀ V_e q̇) to `out` (r) for the gathered state and its rotation.
#[inline(always)]
pub fn scatter(e: &Element, g: &Gathered, rot: &Mat3, beta: f64, out: &mut [f64]) {
    let r = out.len();
    let (x, ve) = (&g.x, &g.velocity);
    // local = Rᵀ(xₐ − x₀) − (Xₐ − X₀) + β Rᵀ vₐ
    let mut local = [0.0; 12];
    for a in 0..4 {
        let d = [x[a][0] - x[0][0], x[a][1] - x[0][1], x[a][2] - x[0][2]];
        let v = [ve[3 * a], ve[3 * a + 1], ve[3 * a + 2]];
        for c in 0..3 {
            let p = rot[0][c] * d[0] + rot[1][c] * d[1] + rot[2][c] * d[2];
            let lv = rot[0][c] * v[0] + rot[1][c] * v[1] + rot[2][c] * v[2];
            local[3 * a + c] = (p - (e.rest[a][c] - e.rest[0][c])) + beta * lv;
        }
    }
    // z = Kₑ local as Σ_j local_j Kₑ[j, ·] (Kₑ symmetric): 12-wide updates, no reduction.
    let mut z = [0.0; 12];
    for (j, row) in e.stiffness.chunks_exact(12).enumerate() {
        let lj = local[j];
        for i in 0..12 {
            z[i] += row[i] * lj;
        }
    }
    let mut force = [0.0; 12];
    for a in 0..4 {
        for c in 0..3 {
            force[3 * a + c] = e.weight
                * (rot[c][0] * z[3 * a] + rot[c][1] * z[3 * a + 1] + rot[c][2] * z[3 * a + 2]);
        }
    }
    for i in 0..12 {
        if force[i] == 0.0 {
            continue;
        }
        let row = &e.rows[i * r..(i + 1) * r];
        for j in 0..r {
            out[j] += row[j] * force[i];
        }
    }
}

/// Adds wₑ V_eᵀ R Kₑ (yₑ + β Rᵀ V_e q̇) to `out` (r) at the reduced state `q` (r) and velocity
/// `velocity` (r) (module docs) and returns the element's rotation R ([`gather`],
/// [`polar_rotation`] (inverted elements refused), [`scatter`]).
#[inline(always)]
pub fn add_reduced_force(
    e: &Element,
    q: &[f64],
    velocity: &[f64],
    beta: f64,
    out: &mut [f64],
) -> Result<Mat3, PolarError> {
    let g = gather(e, q, velocity);
    let rot = polar_rotation(&g.f)?;
    scatter(e, &g, &rot, beta, out);
    Ok(rot)
}

/// Adds `scale` · wₑ V_eᵀ R Kₑ Rᵀ V_e to `out` (r×r row-major) for the element rotation `rot`;
/// `scratch` holds 2·12·r values. The reference of [`Blocks::add_warped_tangent`] (what the
/// runtime runs), kept for its test.
#[cfg(test)]
pub(crate) fn add_warped_tangent(
    e: &Element,
    rot: &Mat3,
    scale: f64,
    scratch: &mut [f64],
    out: &mut [f64],
) {
    let r = e.rows.len() / 12;
    let (a_buf, b_buf) = scratch.split_at_mut(12 * r);
    // A = Rᵀ V_e (per node block), B = Kₑ A, then B ← R B; out += w Vᵀ B.
    for n in 0..4 {
        for c in 0..3 {
            let dst = &mut a_buf[(3 * n + c) * r..(3 * n + c + 1) * r];
            dst.iter_mut().for_each(|v| *v = 0.0);
            for k in 0..3 {
                let s = rot[k][c];
                let src = &e.rows[(3 * n + k) * r..(3 * n + k + 1) * r];
                for j in 0..r {
                    dst[j] += s * src[j];
                }
            }
        }
    }
    for i in 0..12 {
        let dst = &mut b_buf[i * r..(i + 1) * r];
        dst.iter_mut().for_each(|v| *v = 0.0);
        for k in 0..12 {
            let s = e.stiffness[12 * i + k];
            if s == 0.0 {
                continue;
            }
            let src = &a_buf[k * r..(k + 1) * r];
            for j in 0..r {
                dst[j] += s * src[j];
            }
        }
    }
    // a_buf ← R B (per node block)
    for n in 0..4 {
        for c in 0..3 {
            let (rc0, rc1, rc2) = (rot[c][0], rot[c][1], rot[c][2]);
            for j in 0..r {
                a_buf[(3 * n + c) * r + j] = rc0 * b_buf[(3 * n) * r + j]
                    + rc1 * b_buf[(3 * n + 1) * r + j]
                    + rc2 * b_buf[(3 * n + 2) * r + j];
            }
        }
    }
    let w = scale * e.weight;
    for i in 0..12 {
        let vrow = &e.rows[i * r..(i + 1) * r];
        let brow = &a_buf[i * r..(i + 1) * r];
        for (p, &vp) in vrow.iter().enumerate() {
            if vp == 0.0 {
                continue;
            }
            let s = w * vp;
            let orow = &mut out[p * r..(p + 1) * r];
            for j in 0..r {
                orow[j] += s * brow[j];
            }
        }
    }
}

/// In-place Cholesky factor L (lower, row-major n×n, upper part left untouched) of a symmetric
/// positive definite matrix; `Err(pivot)` at the first non-positive pivot.
pub fn cholesky(a: &mut [f64], n: usize) -> Result<(), usize> {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return Err(j);
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    Ok(())
}

/// Solves L Lᵀ x = b in place (`b` ← x) with the factor of [`cholesky`].
pub fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polar_of_rotated_stretch() {
        // F = R S with R about z by 0.7 rad, S = diag(1.1, 0.9, 1.0).
        let (c, s) = (0.7f64.cos(), 0.7f64.sin());
        let r = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        let st = [1.1, 0.9, 1.0];
        let f: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| r[i][j] * st[j]));
        let got = polar_rotation(&f).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                assert!((got[i][j] - r[i][j]).abs() < 1e-13);
            }
        }
        let inverted = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(matches!(
            polar_rotation(&inverted),
            Err(PolarError::Inverted(_))
        ));
    }

    /// A rigid rotation of an element (any angle) gives no force: Rᵀ(x − x₀) = X − X₀.
    #[test]
    fn rigid_rotation_gives_no_force() {
        let rest = [
            [0.1, 0.2, 0.0],
            [1.1, 0.2, 0.1],
            [0.0, 1.3, 0.2],
            [0.2, 0.1, 0.9],
        ];
        // Gradients of the barycentric coordinates (Dm⁻¹ rows) of this tetrahedron.
        let d: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| rest[j + 1][i] - rest[0][i]));
        let it = inverse_transpose(&d).unwrap(); // (Dm⁻¹)ᵀ
        let mut gradients = [[0.0; 3]; 4];
        for a in 1..4 {
            for c in 0..3 {
                gradients[a][c] = it[c][a - 1];
                gradients[0][c] -= it[c][a - 1];
            }
        }
        let stiffness: Vec<f64> = (0..144)
            .map(|k| {
                if k % 13 == 0 {
                    1e6
                } else {
                    1e5 / (1.0 + (k % 7) as f64)
                }
            })
            .collect();
        let stiffness: Vec<f64> = (0..144)
            .map(|k| 0.5 * (stiffness[k] + stiffness[(k % 12) * 12 + k / 12]))
            .collect();
        // r = 12, V_e = I: q is the nodal displacement.
        let rows: Vec<f64> = (0..144)
            .map(|k| if k % 13 == 0 { 1.0 } else { 0.0 })
            .collect();
        let cols = transpose_rows(&rows);
        let e = Element {
            weight: 1.0,
            rest: &rest,
            gradients: &gradients,
            stiffness: &stiffness,
            rows: &rows,
            cols: &cols,
        };
        let axis = [0.3f64, -0.5, 0.8];
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        let k = axis.map(|v| v / n);
        for angle in [0.3f64, 1.5, 3.0] {
            let (s, c) = angle.sin_cos();
            // Rodrigues.
            let rot: Mat3 = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    let kk = k[i] * k[j] * (1.0 - c);
                    let cross = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]][i][j];
                    kk + if i == j { c } else { 0.0 } + s * cross
                })
            });
            let mut q = [0.0; 12];
            for a in 0..4 {
                for i in 0..3 {
                    let x: f64 = (0..3).map(|j| rot[i][j] * rest[a][j]).sum::<f64>() + 0.7;
                    q[3 * a + i] = x - rest[a][i];
                }
            }
            let mut out = [0.0; 12];
            let got = add_reduced_force(&e, &q, &[0.0; 12], 0.0, &mut out).unwrap();
            let worst = out.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            // Scale: Kₑ · (1 m) = 1e6 N.
            assert!(worst < 1e-8, "angle {angle}: force {worst:e} N");
            for i in 0..3 {
                for j in 0..3 {
                    assert!((got[i][j] - rot[i][j]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn cholesky_solves() {
        let mut a = vec![4.0, 2.0, 0.6, 2.0, 5.0, 1.0, 0.6, 1.0, 3.0];
        let orig = a.clone();
        cholesky(&mut a, 3).unwrap();
        let mut b = vec![1.0, -2.0, 0.5];
        let rhs = b.clone();
        cholesky_solve(&a, 3, &mut b);
        for i in 0..3 {
            let s: f64 = (0..3).map(|j| orig[i * 3 + j] * b[j]).sum();
            assert!((s - rhs[i]).abs() < 1e-14);
        }
        let mut bad = vec![1.0, 2.0, 2.0, 1.0];
        assert_eq!(cholesky(&mut bad, 2), Err(1));
    }
}
