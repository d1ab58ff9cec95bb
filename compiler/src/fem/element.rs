//! Linear 4-node tetrahedron: geometry, strain–displacement B, elasticity D, element K, M and ω.
//!
//! Element DOFs are ordered node-major: `[u0x, u0y, u0z, u1x, …, u3z]` (12 entries).
//! Strains use engineering shear, rows ordered xx, yy, zz, xy, yz, zx (docs/design.md §2).

use crate::mesh::geometry::sub;
/// The 3-vector helpers live with the mesh (the earlier stage); re-exported for element code.
pub use crate::mesh::geometry::{cross, dot};

/// An isotropic linear elastic material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElasticMaterial {
    /// Young's modulus E, Pa.
    pub young_modulus: f64,
    /// Poisson's ratio ν.
    pub poisson_ratio: f64,
    /// Density ρ, kg/m³.
    pub density: f64,
}

impl ElasticMaterial {
    /// Lamé constants (λ, μ) in Pa: λ = Eν/((1+ν)(1−2ν)), μ = E/(2(1+ν)).
    pub fn lame(&self) -> (f64, f64) {
        let (e, nu) = (self.young_modulus, self.poisson_ratio);
        (
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            e / (2.0 * (1.0 + nu)),
        )
    }

    /// The 6×6 elasticity matrix D (Pa) for engineering strains [xx, yy, zz, xy, yz, zx]:
    /// D = E/((1+ν)(1−2ν)) · [[1−ν,ν,ν],[ν,1−ν,ν],[ν,ν,1−ν]] ⊕ diag(μ, μ, μ).
    pub fn elasticity(&self) -> [[f64; 6]; 6] {
        let (lambda, mu) = self.lame();
        let mut d = [[0.0; 6]; 6];
        for (i, row) in d.iter_mut().enumerate().take(3) {
            for (j, v) in row.iter_mut().enumerate().take(3) {
                *v = if i == j { lambda + 2.0 * mu } else { lambda };
            }
        }
        for (i, row) in d.iter_mut().enumerate().skip(3) {
            row[i] = mu;
        }
        d
    }
}

/// Shape-function gradients and signed volume of a linear tetrahedron.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TetGeometry {
    /// Signed volume, m³ (positive for gmsh's orientation).
    pub volume: f64,
    /// ∂Nₐ/∂x_j for node a (row) and direction j (column), 1/m.
    pub gradients: [[f64; 3]; 4],
}

impl TetGeometry {
    /// Geometry of the tetrahedron with vertices `x` (m). The caller checks the volume sign.
    pub fn new(x: &[[f64; 3]; 4]) -> Self {
        let e1 = sub(x[1], x[0]);
        let e2 = sub(x[2], x[0]);
        let e3 = sub(x[3], x[0]);
        let det = dot(e1, cross(e2, e3));
        // Rows of Dm⁻¹, Dm = [e1 e2 e3]: N_i (i = 1..3) = (Dm⁻¹ (x − x0))_i.
        let r1 = cross(e2, e3).map(|v| v / det);
        let r2 = cross(e3, e1).map(|v| v / det);
        let r3 = cross(e1, e2).map(|v| v / det);
        let r0 = [
            -(r1[0] + r2[0] + r3[0]),
            -(r1[1] + r2[1] + r3[1]),
            -(r1[2] + r2[2] + r3[2]),
        ];
        TetGeometry {
            volume: det / 6.0,
            gradients: [r0, r1, r2, r3],
        }
    }

    /// The strain–displacement matrix B (6×12, 1/m): ε = B uₑ, engineering shear,
    /// rows xx, yy, zz, xy, yz, zx.
    pub fn strain_displacement(&self) -> [[f64; 12]; 6] {
        let mut b = [[0.0; 12]; 6];
        for (a, g) in self.gradients.iter().enumerate() {
            let c = 3 * a;
            b[0][c] = g[0];
            b[1][c + 1] = g[1];
            b[2][c + 2] = g[2];
            b[3][c] = g[1];
            b[3][c + 1] = g[0];
            b[4][c + 1] = g[2];
            b[4][c + 2] = g[1];
            b[5][c] = g[2];
            b[5][c + 2] = g[0];
        }
        b
    }

    /// Element stiffness Kₑ = Vₑ Bᵀ D B (12×12, N/m).
    pub fn stiffness(&self, material: &ElasticMaterial) -> [[f64; 12]; 12] {
        let b = self.strain_displacement();
        let d = material.elasticity();
        let mut db = [[0.0; 12]; 6];
        for i in 0..6 {
            for j in 0..12 {
                db[i][j] = (0..6).map(|k| d[i][k] * b[k][j]).sum();
            }
        }
        let v = self.volume.abs();
        let mut k = [[0.0; 12]; 12];
        for i in 0..12 {
            for j in 0..12 {
                k[i][j] = v * (0..6).map(|s| b[s][i] * db[s][j]).sum::<f64>();
            }
        }
        k
    }

    /// Node-pair mass coefficients mₐᵦ (kg): the element mass is mₐᵦ I₃.
    /// Consistent: ρV/20 (1 + δₐᵦ); lumped: ρV/4 δₐᵦ.
    pub fn mass(&self, density: f64, lumped: bool) -> [[f64; 4]; 4] {
        let v = self.volume.abs();
        let mut m = [[0.0; 4]; 4];
        for (a, row) in m.iter_mut().enumerate() {
            for (b, value) in row.iter_mut().enumerate() {
                *value = match (lumped, a == b) {
                    (true, true) => density * v / 4.0,
                    (true, false) => 0.0,
                    (false, true) => density * v / 10.0,
                    (false, false) => density * v / 20.0,
                };
            }
        }
        m
    }

    /// The infinitesimal rotation rows W (3×12): ω = ½ ∇×u = W uₑ (rad per m of displacement).
    pub fn rotation(&self) -> [[f64; 12]; 3] {
        let mut w = [[0.0; 12]; 3];
        for (a, g) in self.gradients.iter().enumerate() {
            let c = 3 * a;
            // ω_x = ½(∂u_z/∂y − ∂u_y/∂z)
            w[0][c + 2] = 0.5 * g[1];
            w[0][c + 1] = -0.5 * g[2];
            // ω_y = ½(∂u_x/∂z − ∂u_z/∂x)
            w[1][c] = 0.5 * g[2];
            w[1][c + 2] = -0.5 * g[0];
            // ω_z = ½(∂u_y/∂x − ∂u_x/∂y)
            w[2][c + 1] = 0.5 * g[0];
            w[2][c] = -0.5 * g[1];
        }
        w
    }

    /// Barycentric coordinates (N₀..N₃) of point `p` given vertex 0 at `x0`.
    pub fn barycentric(&self, x0: [f64; 3], p: [f64; 3]) -> [f64; 4] {
        let d = sub(p, x0);
        let n1 = dot(self.gradients[1], d);
        let n2 = dot(self.gradients[2], d);
        let n3 = dot(self.gradients[3], d);
        [1.0 - n1 - n2 - n3, n1, n2, n3]
    }
}

/// y = A x for a 12×12 matrix.
pub fn mul12(a: &[[f64; 12]; 12], x: &[f64; 12]) -> [f64; 12] {
    let mut y = [0.0; 12];
    for (yi, row) in y.iter_mut().zip(a) {
        *yi = row.iter().zip(x).map(|(r, v)| r * v).sum();
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT: [[f64; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];

    const STEEL_LIKE: ElasticMaterial = ElasticMaterial {
        young_modulus: 2.0e11,
        poisson_ratio: 0.25,
        density: 7800.0,
    };

    #[test]
    fn unit_tet_gradients_and_volume() {
        let g = TetGeometry::new(&UNIT);
        assert!((g.volume - 1.0 / 6.0).abs() < 1e-15);
        assert_eq!(g.gradients[0], [-1.0, -1.0, -1.0]);
        assert_eq!(g.gradients[1], [1.0, 0.0, 0.0]);
        assert_eq!(g.gradients[3], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn lame_constants_are_not_the_papers() {
        let m = ElasticMaterial {
            young_modulus: 10.0,
            poisson_ratio: 0.25,
            density: 1.0,
        };
        let (l, mu) = m.lame();
        assert!((l - 4.0).abs() < 1e-14); // 10·0.25/(1.25·0.5)
        assert!((mu - 4.0).abs() < 1e-14); // 10/2.5
    }

    /// Hand computation for the unit right tetrahedron, E = 1, ν = 0 (λ = 0, μ = ½):
    /// D = diag(1,1,1,½,½,½), V = 1/6. Entry K[0][0] (u0x,u0x) = V·(g0x² + ½g0y² + ½g0z²)
    /// = (1 + ½ + ½)/6 = 1/3; K[0][3] (u0x,u1x) = V·(g0x g1x) = −1/6; K[0][4] (u0x,u1y) =
    /// V·½·g0y g1x = −1/12; K[3][3] (u1x,u1x) = 1/6; K[4][4] (u1y,u1y) = V·½ = 1/12.
    #[test]
    fn single_element_stiffness_by_hand() {
        let m = ElasticMaterial {
            young_modulus: 1.0,
            poisson_ratio: 0.0,
            density: 1.0,
        };
        let k = TetGeometry::new(&UNIT).stiffness(&m);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-15;
        assert!(close(k[0][0], 1.0 / 3.0), "{}", k[0][0]);
        assert!(close(k[0][3], -1.0 / 6.0), "{}", k[0][3]);
        assert!(close(k[0][4], -1.0 / 12.0), "{}", k[0][4]);
        assert!(close(k[3][3], 1.0 / 6.0), "{}", k[3][3]);
        assert!(close(k[4][4], 1.0 / 12.0), "{}", k[4][4]);
        for i in 0..12 {
            for j in 0..12 {
                assert!(close(k[i][j], k[j][i]));
            }
        }
    }

    fn skewed() -> [[f64; 3]; 4] {
        [
            [0.1, -0.2, 0.05],
            [1.3, 0.1, -0.1],
            [0.2, 0.9, 0.3],
            [0.4, 0.3, 1.1],
        ]
    }

    #[test]
    fn rigid_motions_produce_no_force() {
        let x = skewed();
        let k = TetGeometry::new(&x).stiffness(&STEEL_LIKE);
        let scale = k.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        // Translation.
        let t = [0.3, -1.2, 0.7];
        let u: [f64; 12] = std::array::from_fn(|i| t[i % 3]);
        let f = mul12(&k, &u);
        assert!(f.iter().all(|v| v.abs() < 1e-12 * scale), "{f:?}");
        // Infinitesimal rotation u = ω × x.
        let w = [0.2, -0.5, 0.9];
        let mut u = [0.0; 12];
        for a in 0..4 {
            let r = cross(w, x[a]);
            u[3 * a..3 * a + 3].copy_from_slice(&r);
        }
        let f = mul12(&k, &u);
        assert!(f.iter().all(|v| v.abs() < 1e-12 * scale), "{f:?}");
        // ... and its ω rows recover the rotation vector.
        let wr = TetGeometry::new(&x).rotation();
        for i in 0..3 {
            let omega: f64 = (0..12).map(|j| wr[i][j] * u[j]).sum();
            assert!((omega - w[i]).abs() < 1e-13, "{omega} vs {}", w[i]);
        }
    }

    #[test]
    fn mass_sums_to_rho_v() {
        let g = TetGeometry::new(&skewed());
        for lumped in [false, true] {
            let m = g.mass(STEEL_LIKE.density, lumped);
            let total: f64 = m.iter().flatten().sum();
            let expected = STEEL_LIKE.density * g.volume;
            assert!(
                (total - expected).abs() < 1e-12 * expected,
                "{total} vs {expected}"
            );
        }
    }

    /// Patch test: the uniform strain field u = E x reproduces σ = D ε exactly in each element.
    #[test]
    fn uniform_strain_reproduces_exact_stress() {
        let x = skewed();
        let g = TetGeometry::new(&x);
        let grad_u = [
            [1e-3, 2e-4, -3e-4],
            [5e-4, -2e-3, 1e-4],
            [-7e-4, 4e-4, 6e-4],
        ];
        let mut u = [0.0; 12];
        for a in 0..4 {
            for i in 0..3 {
                u[3 * a + i] = (0..3).map(|j| grad_u[i][j] * x[a][j]).sum();
            }
        }
        let b = g.strain_displacement();
        let eps: Vec<f64> = (0..6)
            .map(|s| (0..12).map(|j| b[s][j] * u[j]).sum())
            .collect();
        let exact = [
            grad_u[0][0],
            grad_u[1][1],
            grad_u[2][2],
            grad_u[0][1] + grad_u[1][0],
            grad_u[1][2] + grad_u[2][1],
            grad_u[2][0] + grad_u[0][2],
        ];
        for s in 0..6 {
            assert!((eps[s] - exact[s]).abs() < 1e-15, "strain {s}");
        }
        let (lambda, mu) = STEEL_LIKE.lame();
        let tr = exact[0] + exact[1] + exact[2];
        let d = STEEL_LIKE.elasticity();
        let sigma: Vec<f64> = (0..6)
            .map(|i| (0..6).map(|j| d[i][j] * eps[j]).sum())
            .collect();
        let sigma_exact = [
            lambda * tr + 2.0 * mu * exact[0],
            lambda * tr + 2.0 * mu * exact[1],
            lambda * tr + 2.0 * mu * exact[2],
            mu * exact[3],
            mu * exact[4],
            mu * exact[5],
        ];
        for i in 0..6 {
            assert!(
                (sigma[i] - sigma_exact[i]).abs() < 1e-9 * sigma_exact[0].abs(),
                "stress {i}: {} vs {}",
                sigma[i],
                sigma_exact[i]
            );
        }
    }
}
