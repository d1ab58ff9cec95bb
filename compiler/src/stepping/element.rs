//! The co-rotational element (docs/design.md §7 (b)): the rotation Rₑ of the polar
//! decomposition Fₑ = Rₑ Sₑ of the deformation gradient, the internal force
//! fₑ = Rₑ Kₑ (Rₑᵀ xₑ − Xₑ) and the warped and consistent tangents; shared by the full-order
//! stepper ([`super::corotational`]), ECSW and the reduced model.

use nalgebra::{Matrix3, Vector3};

use crate::fem::TetGeometry;

/// The rotation R (det R = +1) of the polar decomposition F = R S: the runtime kernel's
/// scaled Newton iteration ([`crokf_kernel::polar_rotation`], converged to round-off) where
/// det F > 0, else [`polar_rotation_svd`] (robust to inverted elements). The two agree to
/// round-off where both apply (test `kernel_polar_matches_the_svd_polar_rotation`); the kernel's is 3–4 Newton
/// steps with one 3×3 inverse each instead of a Jacobi SVD.
pub fn polar_rotation(f: &Matrix3<f64>) -> Matrix3<f64> {
    let m: crokf_kernel::Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| f[(i, j)]));
    match crokf_kernel::polar_rotation(&m) {
        Ok(r) => Matrix3::from_fn(|i, j| r[i][j]),
        Err(_) => polar_rotation_svd(f),
    }
}

/// The rotation R (det R = +1) of the polar decomposition F = R S, robust to inverted elements
/// (det F ≤ 0): SVD F = U Σ Vᵀ, and where det U or det V is negative the column belonging to the
/// smallest singular value is negated (Irving, Teran and Fedkiw 2004), then R = U Vᵀ.
pub fn polar_rotation_svd(f: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = f.svd(true, true);
    let (Some(mut u), Some(mut v_t)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    let s = svd.singular_values;
    let k = if s[0] <= s[1] && s[0] <= s[2] {
        0
    } else if s[1] <= s[2] {
        1
    } else {
        2
    };
    if u.determinant() < 0.0 {
        u.column_mut(k).neg_mut();
    }
    if v_t.determinant() < 0.0 {
        v_t.row_mut(k).neg_mut();
    }
    u * v_t
}

/// Deformation gradient F = Σₐ xₐ ⊗ ∇Nₐ (= Ds Dm⁻¹) of a linear tetrahedron with rest
/// geometry `geometry` and current vertex positions `x` (m).
pub fn deformation_gradient(geometry: &TetGeometry, x: &[[f64; 3]; 4]) -> Matrix3<f64> {
    let mut f = Matrix3::zeros();
    for (xa, g) in x.iter().zip(&geometry.gradients) {
        for i in 0..3 {
            for j in 0..3 {
                f[(i, j)] += xa[i] * g[j];
            }
        }
    }
    f
}

/// The element-frame nodal forces zₐ = V σ(H) ∇Nₐ (a = 0..3, N) of a displacement gradient
/// H: σ = λ tr(ε) I + 2μ ε, ε = ½(H + Hᵀ). With the isotropic element stiffness
/// Kₑ = V Bᵀ D B this is Kₑ y for any nodal vector y with Σₐ yₐ ⊗ ∇Nₐ = H (B y is the
/// engineering strain of H, Bᵀσ at node a is σ ∇Nₐ), at a fraction of the 12 × 12 product.
/// `lame` = (Vλ, Vμ) of the element (N·m).
#[inline]
pub(super) fn stress_forces(
    geometry: &TetGeometry,
    lame: [f64; 2],
    h: &Matrix3<f64>,
) -> [Vector3<f64>; 4] {
    let [vl, vm] = lame;
    let eps = (h + h.transpose()) * 0.5;
    let sigma = eps * (2.0 * vm) + Matrix3::identity() * (vl * eps.trace());
    std::array::from_fn(|a| sigma * Vector3::from(geometry.gradients[a]))
}

/// The co-rotational force of one element in closed form ([`stress_forces`]): its rotation R
/// and the world-frame nodal forces R zₐ, zₐ = Kₑ (Rᵀ(xₐ − x₀) − (Xₐ − X₀)) as [`Kinematics`]
/// computes them (the displacement gradient of that nodal vector is RᵀF − I = S − I). F is
/// formed from the positions relative to vertex 0 (exact since Σₐ ∇Nₐ = 0), so a tiny strain
/// keeps its digits.
#[inline]
pub(super) fn corotated_forces(
    geometry: &TetGeometry,
    lame: [f64; 2],
    current: &[[f64; 3]; 4],
) -> (Matrix3<f64>, [Vector3<f64>; 4]) {
    let relative = current.map(|xa| std::array::from_fn(|i| xa[i] - current[0][i]));
    let f = deformation_gradient(geometry, &relative);
    let r = polar_rotation(&f);
    let h = r.tr_mul(&f) - Matrix3::identity();
    let z = stress_forces(geometry, lame, &h);
    (r, z.map(|za| r * za))
}

/// The warped stiffness force R Kₑ Rᵀ vₑ of one element in closed form ([`stress_forces`]
/// of H = Rᵀ Σₐ vₐ ⊗ ∇Nₐ), world frame, N; `velocity` the nodal vectors vₐ.
#[inline]
pub(super) fn warped_forces(
    geometry: &TetGeometry,
    lame: [f64; 2],
    r: &Matrix3<f64>,
    velocity: &[[f64; 3]; 4],
) -> [Vector3<f64>; 4] {
    let l = deformation_gradient(geometry, velocity);
    let z = stress_forces(geometry, lame, &r.tr_mul(&l));
    z.map(|za| r * za)
}

/// Co-rotated kinematics of one element: R and S = RᵀF of F = R S, the unrotated relative
/// positions pₐ = Rᵀ(xₐ − x₀) and the element-frame forces z = Kₑ (p − (X − X₀)).
pub(super) struct Kinematics {
    pub(super) r: Matrix3<f64>,
    pub(super) s: Matrix3<f64>,
    pub(super) p: [Vector3<f64>; 4],
    pub(super) z: [Vector3<f64>; 4],
}

impl Kinematics {
    pub(super) fn new(
        geometry: &TetGeometry,
        ke: &[[f64; 12]; 12],
        rest: &[[f64; 3]; 4],
        current: &[[f64; 3]; 4],
    ) -> Self {
        let f = deformation_gradient(geometry, current);
        let r = polar_rotation(&f);
        let s = r.tr_mul(&f);
        let p: [Vector3<f64>; 4] = std::array::from_fn(|a| {
            r.tr_mul(&Vector3::from_fn(|i, _| current[a][i] - current[0][i]))
        });
        let mut y = [0.0; 12];
        for a in 0..4 {
            for i in 0..3 {
                y[3 * a + i] = p[a][i] - (rest[a][i] - rest[0][i]);
            }
        }
        let z = crate::fem::element::mul12(ke, &y);
        let z = std::array::from_fn(|a| Vector3::new(z[3 * a], z[3 * a + 1], z[3 * a + 2]));
        Kinematics { r, s, p, z }
    }

    /// World-frame force on node a: R zₐ.
    pub(super) fn force(&self, a: usize) -> Vector3<f64> {
        self.r * self.z[a]
    }

    /// Calls `out(a, b, warped, consistent)` with the 3×3 tangent blocks ∂fₐ/∂x_b:
    /// warped R Kₐᵦ Rᵀ, and (if `consistent`) the exact derivative
    /// R Kₐᵦ Rᵀ + R (Σ_c Kₐ_c [p_c]× − [zₐ]×)(tr S·I − S)⁻¹ [∇N_b]× Rᵀ
    /// (from δR = R[w]×, (tr S·I − S) w = Σ_b ∇N_b × Rᵀδx_b), else a copy of the warped one.
    pub(super) fn tangents(
        &self,
        geometry: &TetGeometry,
        ke: &[[f64; 12]; 12],
        consistent: bool,
        mut out: impl FnMut(usize, usize, &Matrix3<f64>, &Matrix3<f64>),
    ) {
        let block = |a: usize, b: usize| Matrix3::from_fn(|i, j| ke[3 * a + i][3 * b + j]);
        let rt = self.r.transpose();
        let spin = (Matrix3::identity() * self.s.trace() - self.s).try_inverse();
        let (left, right) = match (consistent, spin) {
            (true, Some(spin_inv)) => {
                let left: [Matrix3<f64>; 4] = std::array::from_fn(|a| {
                    let mut h = -self.z[a].cross_matrix();
                    for c in 0..4 {
                        h += block(a, c) * self.p[c].cross_matrix();
                    }
                    self.r * h * spin_inv
                });
                let right: [Matrix3<f64>; 4] = std::array::from_fn(|b| {
                    Vector3::from(geometry.gradients[b]).cross_matrix() * rt
                });
                (Some(left), Some(right))
            }
            _ => (None, None),
        };
        for a in 0..4 {
            for b in 0..4 {
                let warped = self.r * block(a, b) * rt;
                match (&left, &right) {
                    (Some(l), Some(r)) => out(a, b, &warped, &(warped + l[a] * r[b])),
                    _ => out(a, b, &warped, &warped),
                }
            }
        }
    }
}

/// Co-rotational internal force of one element, fₑ = R Kₑ (Rᵀ xₑ − Xₑ) (12, N, node-major),
/// and its rotation R. `ke` is the rest stiffness (12×12, N/m), `rest` and `current` the vertex
/// positions Xₑ and xₑ (m). Positions enter relative to vertex 0, which Kₑ (translation-free)
/// does not see but which keeps the difference Rᵀxₑ − Xₑ accurate for tiny displacements.
pub fn element_force(
    geometry: &TetGeometry,
    ke: &[[f64; 12]; 12],
    rest: &[[f64; 3]; 4],
    current: &[[f64; 3]; 4],
) -> ([f64; 12], Matrix3<f64>) {
    let kin = Kinematics::new(geometry, ke, rest, current);
    let mut f = [0.0; 12];
    for a in 0..4 {
        f[3 * a..3 * a + 3].copy_from_slice(kin.force(a).as_slice());
    }
    (f, kin.r)
}

/// Element tangent ∂fₑ/∂xₑ (12×12, N/m): the warped stiffness R Kₑ Rᵀ, or with `consistent`
/// the exact derivative of [`element_force`] including the change of R (symmetric for the
/// isotropic material: fₑ is the gradient of Vₑ[λ/2 tr²(S − I) + μ‖S − I‖²]).
pub fn element_tangent(
    geometry: &TetGeometry,
    ke: &[[f64; 12]; 12],
    rest: &[[f64; 3]; 4],
    current: &[[f64; 3]; 4],
    consistent: bool,
) -> [[f64; 12]; 12] {
    let kin = Kinematics::new(geometry, ke, rest, current);
    let mut t = [[0.0; 12]; 12];
    kin.tangents(geometry, ke, consistent, |a, b, _, k| {
        for i in 0..3 {
            for j in 0..3 {
                t[3 * a + i][3 * b + j] = k[(i, j)];
            }
        }
    });
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::element::{mul12, ElasticMaterial};
    use nalgebra::Rotation3;

    /// The closed-form forces against the 12 × 12 products they replace, on elements rotated
    /// up to ~170°, stretched by up to ±40 % and sheared, down to a strain of 1e-9: equal to
    /// within the round-off of the strain's digits, and the damping force to 1e-12.
    #[test]
    fn closed_form_forces_match_the_element_stiffness_products() {
        let material = ElasticMaterial {
            young_modulus: 3.0e5,
            poisson_ratio: 0.45,
            density: 1000.0,
        };
        let (lambda, mu) = material.lame();
        let rest = [
            [0.10, 0.20, 0.05],
            [0.13, 0.21, 0.05],
            [0.11, 0.24, 0.06],
            [0.10, 0.21, 0.09],
        ];
        let geometry = TetGeometry::new(&rest);
        let ke = geometry.stiffness(&material);
        let lame = [geometry.volume * lambda, geometry.volume * mu];
        let mut worst: f64 = 0.0;
        for k in 0..40 {
            let t = k as f64;
            let rot = Rotation3::from_euler_angles(0.3 * t, 1.1 - 0.05 * t, 0.7 * t.sin());
            let size = [1e-9, 1e-5, 1e-2, 0.4][k % 4];
            let s = Matrix3::new(
                1.0 + size * (0.7 * t).sin(),
                0.5 * size * (1.3 * t).cos(),
                0.2 * size,
                0.5 * size * (1.3 * t).cos(),
                1.0 - 0.7 * size * (0.4 * t).cos(),
                -0.1 * size * t.sin(),
                0.2 * size,
                -0.1 * size * t.sin(),
                1.0 + 0.3 * size * t.cos(),
            );
            let map = rot.matrix() * s;
            let shift = Vector3::new(0.01 * t, -0.02, 0.3);
            let current: [[f64; 3]; 4] = std::array::from_fn(|a| {
                let x = map * Vector3::from(rest[a]) + shift;
                [x[0], x[1], x[2]]
            });
            let (f_ref, r_ref) = element_force(&geometry, &ke, &rest, &current);
            let (r, force) = corotated_forces(&geometry, lame, &current);
            let scale = f_ref.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut error: f64 = 0.0;
            for a in 0..4 {
                for i in 0..3 {
                    error = error.max((force[a][i] - f_ref[3 * a + i]).abs() / scale);
                }
            }
            // Both lose the digits of a small strain to round-off: a few ε over the strain.
            assert!(
                error < 64.0 * f64::EPSILON / size,
                "strain {size:e}: {error:.2e}"
            );
            worst = worst.max(error * size / f64::EPSILON);
            assert!((r - r_ref).norm() < 1e-13);
            // R Kₑ Rᵀ v against the product.
            let velocity: [[f64; 3]; 4] =
                std::array::from_fn(|a| [0.3 * a as f64 - t.cos(), 0.1 * t, -0.2 + a as f64]);
            let mut local = [0.0; 12];
            for a in 0..4 {
                let v = r.tr_mul(&Vector3::from(velocity[a]));
                local[3 * a..3 * a + 3].copy_from_slice(v.as_slice());
            }
            let product = mul12(&ke, &local);
            let damping = warped_forces(&geometry, lame, &r, &velocity);
            let dscale = product.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for a in 0..4 {
                let expected =
                    r * Vector3::new(product[3 * a], product[3 * a + 1], product[3 * a + 2]);
                assert!((damping[a] - expected).norm() < 1e-12 * dscale);
            }
        }
        println!(
            "closed-form element force vs Kₑ product: worst {worst:.1} ε / strain of the largest"
        );
    }
}
