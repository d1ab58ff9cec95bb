//! The modal Wilson-θ system and square-root balanced truncation (docs/design.md §4.2–4.3).
//!
//! Modal system, block i (state sᵢ = [qᵢ, q̇ᵢ, q̈ᵢ]): sᵢ' = Φᵢ sᵢ + Γᵢ bᵢᵀ u, y = Σᵢ cᵢ qᵢ, with
//! (Φᵢ, Γᵢ) = `WilsonTheta::modal_block(ωᵢ², α + βωᵢ²)`, bᵢ = (VᵀB)ᵢ, cᵢ = (Cout V)_{:,i}.
//!
//! Gramians: Φ X Φᵀ − X + ΓΓᵀ = 0 and Φᵀ Y Φ − Y + CᵀC = 0 decouple into the 3×3 block Stein
//! equations Φᵢ Xᵢⱼ Φⱼᵀ − Xᵢⱼ + γᵢ (bᵢ·bⱼ) γⱼᵀ = 0 and Φᵢᵀ Yᵢⱼ Φⱼ − Yᵢⱼ + (cᵢ·cⱼ) e₁e₁ᵀ = 0,
//! each a 9×9 Kronecker solve. Numerically the blocks are first scaled to
//! zᵢ = tᵢ [qᵢ, q̇ᵢ/νᵢ, q̈ᵢ/νᵢ²] with νᵢ = min(ωᵢ, 1/Δt) and tᵢ = (‖Yᵢᵢ‖/‖Xᵢᵢ‖)^{1/4}
//! (a similarity transform: the Hankel singular values are unchanged, and a change of physical
//! scale E → sE, Δt → Δt/√s leaves the scaled blocks unchanged), and B, C are normalised.
//!
//! Square-root balanced truncation: X = Lc Lcᵀ, Y = Lo Loᵀ (eigen-decompositions, negative
//! round-off eigenvalues clipped), Loᵀ Lc = U Σ Wᵀ, T = Lc W_r Σ_r^{-1/2},
//! S = Lo U_r Σ_r^{-1/2}, F = Sᵀ Φ T, G = Sᵀ Γ, H = C T; ‖G − G_r‖∞ ≤ 2 Σ_{i>r} σᵢ.

use super::modes::ModalBasis;
use super::ReduceError;
use crate::dynamics::WilsonTheta;
use crate::scene::Scheme;
use faer::linalg::matmul::matmul;
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::sparse::SparseColMatRef;
use faer::{Accum, Mat, MatRef, Side};
use std::time::Instant;

/// Modal blocks with ρ(Φᵢ) at or above this are refused (the Gramians would not exist).
const MARGINAL: f64 = 1.0 - 1e-12;
/// Hankel singular values below this fraction of σ₁ are numerically zero (order cap).
const RANK_RATIO: f64 = 1e-11;

/// How the reduced order r is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Order {
    /// r states (capped at the numerical rank).
    Fixed(usize),
    /// The smallest r with σ_{r+1}/σ₁ ≤ tol.
    Tolerance(f64),
}

/// Wall-clock seconds of [`ModalSystem::new`].
#[derive(Clone, Debug, Default)]
pub struct ModalSystemTimings {
    /// VᵀB and Cout V.
    pub projection: f64,
    /// Wilson-θ blocks and their spectral radii.
    pub blocks: f64,
}

/// Wall-clock seconds of [`ModalSystem::balanced_truncation`].
#[derive(Clone, Debug, Default)]
pub struct BalanceTimings {
    /// Block Stein solves.
    pub gramians: f64,
    /// Eigen-decompositions of the Gramians (square-root factors).
    pub factors: f64,
    /// SVD of Loᵀ Lc.
    pub svd: f64,
    /// Projection to (F, G, H) and ρ(F).
    pub projection: f64,
    /// Whole call.
    pub total: f64,
}

/// The block-diagonal discrete modal system, 3k states.
#[derive(Clone, Debug)]
pub struct ModalSystem {
    /// Time discretisation.
    pub wilson: WilsonTheta,
    /// Rayleigh mass coefficient α, 1/s.
    pub alpha: f64,
    /// Rayleigh stiffness coefficient β, s.
    pub beta: f64,
    /// ωᵢ², rad²/s².
    pub omega2: Vec<f64>,
    /// ωᵢ/(2π), Hz.
    pub frequencies_hz: Vec<f64>,
    /// Φᵢ (row-major), state [q, q̇, q̈].
    pub phi: Vec<[[f64; 3]; 3]>,
    /// Γᵢ (response of [q, q̇, q̈] to a unit modal force held over one step).
    pub gamma: Vec<[f64; 3]>,
    /// ρ(Φᵢ).
    pub spectral_radii: Vec<f64>,
    /// VᵀB, k×m: row i is bᵢ.
    pub modal_inputs: Mat<f64>,
    /// Cout V, p×k: column i is cᵢ.
    pub modal_outputs: Mat<f64>,
    basis: Mat<f64>,
    /// Stage timings, s.
    pub timings: ModalSystemTimings,
}

/// The balanced reduced discrete system x' = F x + G u, y = H x (zero feed-through).
#[derive(Clone, Debug)]
pub struct ReducedSystem {
    /// F, r×r.
    pub transition: Mat<f64>,
    /// G, r×m.
    pub input: Mat<f64>,
    /// H, p×r.
    pub output: Mat<f64>,
    /// All Hankel singular values σ₁ ≥ σ₂ ≥ … (units of output/input).
    pub hankel_singular_values: Vec<f64>,
    /// 2 Σ_{i>r} σᵢ ≥ ‖G − G_r‖∞.
    pub error_bound: f64,
    /// r.
    pub order: usize,
    /// ρ(F).
    pub spectral_radius: f64,
    /// Maps a modal state [q₁, q̇₁, q̈₁, …] (3k) to the reduced state: r×3k (Sᵀ).
    pub modal_to_reduced: Mat<f64>,
    /// Maps the reduced state back to an approximate modal state: 3k×r (T).
    pub reduced_to_modal: Mat<f64>,
    /// u ≈ D x: nodal displacement (n) from the reduced state, n×r (V T_q).
    displacement_map: Mat<f64>,
    /// The reduced input of a unit modal force held over one step, r×k: G = this · Vᵀ B.
    input_map: Mat<f64>,
    /// Notes (order capped, ρ(F) ≥ 1, …).
    pub warnings: Vec<String>,
    /// Stage timings, s.
    pub timings: BalanceTimings,
}

/// Per-mode blocks (Φᵢ, Γᵢ) of the scheme at `wilson`'s Δt and their spectral radii, measured
/// on the blocks scaled by Eᵢ = diag(1, 1/νᵢ, 1/νᵢ²), νᵢ = min(ωᵢ, 1/Δt).
#[allow(clippy::type_complexity)]
fn discrete_blocks(
    omega2: &[f64],
    alpha: f64,
    beta: f64,
    wilson: WilsonTheta,
    scheme: Scheme,
) -> Result<(Vec<[[f64; 3]; 3]>, Vec<[f64; 3]>, Vec<f64>), ReduceError> {
    let k = omega2.len();
    let mut phi = Vec::with_capacity(k);
    let mut gamma = Vec::with_capacity(k);
    let mut spectral_radii = Vec::with_capacity(k);
    for &w2 in omega2 {
        let (p, g) = match scheme {
            Scheme::WilsonTheta => wilson.modal_block(w2, alpha + beta * w2),
            Scheme::Exact => crokf_kernel::exact::modal_block(wilson.dt, w2, alpha + beta * w2),
        };
        let nu = if w2 > 0.0 {
            w2.sqrt().min(1.0 / wilson.dt)
        } else {
            1.0 / wilson.dt
        };
        let e = [1.0, 1.0 / nu, 1.0 / (nu * nu)];
        let scaled = Mat::from_fn(3, 3, |r, c| p[r][c] * e[r] / e[c]);
        spectral_radii.push(spectral_radius(scaled.as_ref())?);
        phi.push(p);
        gamma.push(g);
    }
    Ok((phi, gamma, spectral_radii))
}

fn spectral_radius(a: MatRef<'_, f64>) -> Result<f64, ReduceError> {
    if a.nrows() == 0 {
        return Ok(0.0);
    }
    let ev = a.eigenvalues().map_err(|_| ReduceError::Dense {
        what: "eigenvalues",
    })?;
    Ok(ev.iter().map(|z| z.norm()).fold(0.0, f64::max))
}

/// Solves Z − A Z Bᵀ = Q (3×3) through the 9×9 Kronecker system (I − B ⊗ A) vec Z = vec Q
/// (column-major vec) by Gaussian elimination with partial pivoting.
fn stein_block(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3], q: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0f64; 10]; 9];
    for c in 0..3 {
        for r in 0..3 {
            let p = r + 3 * c;
            for c2 in 0..3 {
                for r2 in 0..3 {
                    let p2 = r2 + 3 * c2;
                    m[p][p2] = if p == p2 { 1.0 } else { 0.0 } - a[r][r2] * b[c][c2];
                }
            }
            m[p][9] = q[r][c];
        }
    }
    for col in 0..9 {
        let piv = (col..9)
            .max_by(|&x, &y| m[x][col].abs().total_cmp(&m[y][col].abs()))
            .unwrap_or(col);
        m.swap(col, piv);
        let d = m[col][col];
        for row in col + 1..9 {
            let f = m[row][col] / d;
            if f != 0.0 {
                for k in col..10 {
                    m[row][k] -= f * m[col][k];
                }
            }
        }
    }
    let mut x = [0.0f64; 9];
    for row in (0..9).rev() {
        let s: f64 = (row + 1..9).map(|k| m[row][k] * x[k]).sum();
        x[row] = (m[row][9] - s) / m[row][row];
    }
    let mut z = [[0.0; 3]; 3];
    for c in 0..3 {
        for r in 0..3 {
            z[r][c] = x[r + 3 * c];
        }
    }
    z
}

fn transpose3(a: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut t = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            t[c][r] = a[r][c];
        }
    }
    t
}

fn frobenius3(a: &[[f64; 3]; 3]) -> f64 {
    a.iter().flatten().map(|v| v * v).sum::<f64>().sqrt()
}

/// Symmetric PSD square-root factor L (rows × rank) with A ≈ L Lᵀ, negative eigenvalues clipped.
fn psd_factor(a: &Mat<f64>) -> Result<Mat<f64>, ReduceError> {
    let n = a.nrows();
    let sym = Mat::from_fn(n, n, |i, j| 0.5 * (a[(i, j)] + a[(j, i)]));
    let evd = sym
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| ReduceError::Dense {
            what: "Gramian eigen-decomposition",
        })?;
    let s = evd.S().column_vector();
    let u = evd.U();
    let keep: Vec<usize> = (0..n).rev().filter(|&j| s[j] > 0.0).collect();
    Ok(Mat::from_fn(n, keep.len(), |i, c| {
        u[(i, keep[c])] * s[keep[c]].sqrt()
    }))
}

/// (Φ̃ᵢ, Γ̃ᵢ, νᵢ) of every mode.
type ScaledBlocks = (Vec<[[f64; 3]; 3]>, Vec<[f64; 3]>, Vec<f64>);

/// Gramians in the scaled coordinates zᵢ = tᵢ Eᵢ sᵢ over the active modes.
struct ScaledGramians {
    /// Active (controllable and observable) modes.
    active: Vec<usize>,
    /// Scaled blocks Φ̃ᵢ = Eᵢ Φᵢ Eᵢ⁻¹ (all modes).
    phi: Vec<[[f64; 3]; 3]>,
    /// Scaled Γ̃ᵢ = Eᵢ Γᵢ (all modes).
    gamma: Vec<[f64; 3]>,
    /// νᵢ.
    nu: Vec<f64>,
    /// tᵢ (all modes; 1 for inactive ones).
    t: Vec<f64>,
    /// Input normalisation: X_phys-scale = beta_s X̂.
    beta_s: f64,
    /// Output normalisation: Y_phys-scale = gamma_s Ŷ.
    gamma_s: f64,
    x: Mat<f64>,
    y: Mat<f64>,
}

impl ModalSystem {
    /// Builds the modal system from the basis, B (n×m), sparse Cout (p×n), Rayleigh damping
    /// C = αM + βK and the Wilson-θ scheme.
    pub fn new(
        basis: &ModalBasis,
        inputs: MatRef<'_, f64>,
        outputs: SparseColMatRef<'_, usize, f64>,
        alpha: f64,
        beta: f64,
        wilson: WilsonTheta,
    ) -> Result<Self, ReduceError> {
        Self::with_scheme(
            basis,
            inputs,
            outputs,
            alpha,
            beta,
            wilson,
            Scheme::WilsonTheta,
        )
    }

    /// [`ModalSystem::new`] with the modes stepped by `scheme`: Wilson-θ's blocks
    /// ([`WilsonTheta::modal_block`]) or the exact zero-order-hold ones
    /// ([`crokf_kernel::exact::modal_block`]) over `wilson.dt`.
    pub fn with_scheme(
        basis: &ModalBasis,
        inputs: MatRef<'_, f64>,
        outputs: SparseColMatRef<'_, usize, f64>,
        alpha: f64,
        beta: f64,
        wilson: WilsonTheta,
        scheme: Scheme,
    ) -> Result<Self, ReduceError> {
        let v = &basis.vectors;
        let (n, k) = (v.nrows(), v.ncols());
        if inputs.nrows() != n {
            return Err(ReduceError::Dimension {
                what: "input matrix B",
                expected: format!("{n}×m"),
                got: format!("{}×{}", inputs.nrows(), inputs.ncols()),
            });
        }
        if outputs.ncols() != n {
            return Err(ReduceError::Dimension {
                what: "output matrix Cout",
                expected: format!("p×{n}"),
                got: format!("{}×{}", outputs.nrows(), outputs.ncols()),
            });
        }
        if !(alpha.is_finite() && alpha >= 0.0 && beta.is_finite() && beta >= 0.0) {
            return Err(ReduceError::InvalidOption(format!(
                "Rayleigh damping α = {alpha}, β = {beta} must be finite and ≥ 0"
            )));
        }
        if !(wilson.dt.is_finite()
            && wilson.dt > 0.0
            && wilson.theta.is_finite()
            && wilson.theta >= 1.0)
        {
            return Err(ReduceError::InvalidOption(format!(
                "Wilson-θ: Δt = {} s must be > 0 and θ = {} ≥ 1",
                wilson.dt, wilson.theta
            )));
        }
        let par = faer::get_global_parallelism();
        let t = Instant::now();
        let mut modal_inputs = Mat::zeros(k, inputs.ncols());
        matmul(
            modal_inputs.as_mut(),
            Accum::Replace,
            v.transpose(),
            inputs,
            1.0,
            par,
        );
        let mut modal_outputs = Mat::zeros(outputs.nrows(), k);
        sparse_dense_matmul(
            modal_outputs.as_mut(),
            Accum::Replace,
            outputs,
            v.as_ref(),
            1.0,
            par,
        );
        let projection = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (phi, gamma, spectral_radii) =
            discrete_blocks(&basis.omega2, alpha, beta, wilson, scheme)?;
        let blocks = t.elapsed().as_secs_f64();
        Ok(Self {
            wilson,
            alpha,
            beta,
            omega2: basis.omega2.clone(),
            frequencies_hz: basis.frequencies_hz.clone(),
            phi,
            gamma,
            spectral_radii,
            modal_inputs,
            modal_outputs,
            basis: v.clone(),
            timings: ModalSystemTimings { projection, blocks },
        })
    }

    /// Number of modes k.
    pub fn n_modes(&self) -> usize {
        self.omega2.len()
    }

    /// Number of states 3k.
    pub fn n_states(&self) -> usize {
        3 * self.omega2.len()
    }

    /// The same modes, inputs and outputs discretised with another step or scheme (the
    /// projections are kept, only the per-mode blocks are made again).
    pub fn rediscretised(&self, wilson: WilsonTheta, scheme: Scheme) -> Result<Self, ReduceError> {
        let t = Instant::now();
        let (phi, gamma, spectral_radii) =
            discrete_blocks(&self.omega2, self.alpha, self.beta, wilson, scheme)?;
        Ok(Self {
            wilson,
            phi,
            gamma,
            spectral_radii,
            timings: ModalSystemTimings {
                projection: 0.0,
                blocks: t.elapsed().as_secs_f64(),
            },
            ..self.clone()
        })
    }

    /// Output response y_t = Σᵢ cᵢ qᵢ(t) (p×T) to inputs u (m×T) from rest;
    /// s(t+1) = Φ s(t) + Γ u(t), so y_0 = 0.
    pub fn simulate(&self, inputs: MatRef<'_, f64>) -> Mat<f64> {
        let (k, steps) = (self.n_modes(), inputs.ncols());
        let mut q = Mat::zeros(k, steps);
        let mut f = Mat::zeros(k, steps);
        matmul(
            f.as_mut(),
            Accum::Replace,
            self.modal_inputs.as_ref(),
            inputs,
            1.0,
            faer::Par::Seq,
        );
        for i in 0..k {
            let mut s = [0.0; 3];
            for step in 0..steps {
                q[(i, step)] = s[0];
                let (p, g) = (&self.phi[i], &self.gamma[i]);
                let fi = f[(i, step)];
                s = [0, 1, 2].map(|r| p[r][0] * s[0] + p[r][1] * s[1] + p[r][2] * s[2] + g[r] * fi);
            }
        }
        &self.modal_outputs * &q
    }

    /// Refuses marginally stable blocks (ρ(Φᵢ) ≥ 1 − 1e-12), naming the mode.
    pub fn check_stability(&self) -> Result<(), ReduceError> {
        for (i, &rho) in self.spectral_radii.iter().enumerate() {
            if !(rho < MARGINAL) {
                return Err(ReduceError::MarginallyStable {
                    mode: i,
                    frequency_hz: self.frequencies_hz[i],
                    spectral_radius: rho,
                });
            }
        }
        Ok(())
    }

    /// Scaled blocks Φ̃ᵢ = Eᵢ Φᵢ Eᵢ⁻¹, Γ̃ᵢ = Eᵢ Γᵢ with Eᵢ = diag(1, 1/νᵢ, 1/νᵢ²), νᵢ = min(ωᵢ, 1/Δt).
    fn scaled_blocks(&self) -> ScaledBlocks {
        let k = self.n_modes();
        let dt = self.wilson.dt;
        let mut nu = Vec::with_capacity(k);
        let mut phi = Vec::with_capacity(k);
        let mut gamma = Vec::with_capacity(k);
        for i in 0..k {
            let w2 = self.omega2[i];
            let v = if w2 > 0.0 {
                w2.sqrt().min(1.0 / dt)
            } else {
                1.0 / dt
            };
            let e = [1.0, 1.0 / v, 1.0 / (v * v)];
            let p = &self.phi[i];
            phi.push([0, 1, 2].map(|r| [0, 1, 2].map(|c| p[r][c] * e[r] / e[c])));
            gamma.push([0, 1, 2].map(|r| self.gamma[i][r] * e[r]));
            nu.push(v);
        }
        (phi, gamma, nu)
    }

    fn scaled_gramians(&self) -> Result<ScaledGramians, ReduceError> {
        self.check_stability()?;
        let k = self.n_modes();
        let (phi, gamma, nu) = self.scaled_blocks();
        let b = &self.modal_inputs;
        let c = &self.modal_outputs;
        let wb = b * b.transpose();
        let wc = c.transpose() * c;
        let beta_s = (0..k).map(|i| wb[(i, i)]).fold(0.0, f64::max);
        let gamma_s = (0..k).map(|i| wc[(i, i)]).fold(0.0, f64::max);
        if !(beta_s > 0.0 && gamma_s > 0.0) {
            return Err(ReduceError::NothingObservable);
        }
        let e1 = [[1.0, 0.0, 0.0], [0.0; 3], [0.0; 3]];
        let phit: Vec<[[f64; 3]; 3]> = phi.iter().map(transpose3).collect();
        let outer =
            |i: usize, j: usize| [0, 1, 2].map(|r| [0, 1, 2].map(|s| gamma[i][r] * gamma[j][s]));
        let xblock = |i: usize, j: usize| {
            let w = wb[(i, j)] / beta_s;
            if w == 0.0 {
                [[0.0; 3]; 3]
            } else {
                stein_block(&phi[i], &phi[j], &outer(i, j)).map(|row| row.map(|v| v * w))
            }
        };
        let yblock = |i: usize, j: usize| {
            let w = wc[(i, j)] / gamma_s;
            if w == 0.0 {
                [[0.0; 3]; 3]
            } else {
                stein_block(&phit[i], &phit[j], &e1).map(|row| row.map(|v| v * w))
            }
        };
        // Diagonal blocks first: activity and the balancing scalars tᵢ.
        let xd: Vec<f64> = (0..k).map(|i| frobenius3(&xblock(i, i))).collect();
        let yd: Vec<f64> = (0..k).map(|i| frobenius3(&yblock(i, i))).collect();
        let top = (0..k).map(|i| xd[i] * yd[i]).fold(0.0, f64::max);
        if !(top > 0.0) {
            return Err(ReduceError::NothingObservable);
        }
        let active: Vec<usize> = (0..k).filter(|&i| xd[i] * yd[i] > 1e-30 * top).collect();
        let mut t = vec![1.0; k];
        for &i in &active {
            t[i] = (yd[i] / xd[i]).powf(0.25);
        }
        let ka = active.len();
        let mut x = Mat::zeros(3 * ka, 3 * ka);
        let mut y = Mat::zeros(3 * ka, 3 * ka);
        for (a, &i) in active.iter().enumerate() {
            for (bb, &j) in active.iter().enumerate().skip(a) {
                let tt = t[i] * t[j];
                let xb = xblock(i, j);
                let yb = yblock(i, j);
                for r in 0..3 {
                    for s in 0..3 {
                        x[(3 * a + r, 3 * bb + s)] = xb[r][s] * tt;
                        x[(3 * bb + s, 3 * a + r)] = xb[r][s] * tt;
                        y[(3 * a + r, 3 * bb + s)] = yb[r][s] / tt;
                        y[(3 * bb + s, 3 * a + r)] = yb[r][s] / tt;
                    }
                }
            }
        }
        Ok(ScaledGramians {
            active,
            phi,
            gamma,
            nu,
            t,
            beta_s,
            gamma_s,
            x,
            y,
        })
    }

    /// The controllability and observability Gramians (X, Y), 3k×3k, in the physical modal
    /// state [q₁, q̇₁, q̈₁, …]: Φ X Φᵀ − X + ΓΓᵀ = 0, Φᵀ Y Φ − Y + CᵀC = 0, from the 3×3 block
    /// Stein equations in the scaled coordinates (X = E⁻¹ X̃ E⁻¹, Y = E Ỹ E).
    pub fn gramians(&self) -> Result<(Mat<f64>, Mat<f64>), ReduceError> {
        self.check_stability()?;
        let k = self.n_modes();
        let (phi, gamma, nu) = self.scaled_blocks();
        let phit: Vec<[[f64; 3]; 3]> = phi.iter().map(transpose3).collect();
        let wb = &self.modal_inputs * self.modal_inputs.transpose();
        let wc = self.modal_outputs.transpose() * &self.modal_outputs;
        let e1 = [[1.0, 0.0, 0.0], [0.0; 3], [0.0; 3]];
        let einv = |i: usize, r: usize| [1.0, nu[i], nu[i] * nu[i]][r];
        let mut x = Mat::zeros(3 * k, 3 * k);
        let mut y = Mat::zeros(3 * k, 3 * k);
        for i in 0..k {
            for j in 0..k {
                let q = [0, 1, 2].map(|r| [0, 1, 2].map(|s| gamma[i][r] * gamma[j][s]));
                let xb = stein_block(&phi[i], &phi[j], &q);
                let yb = stein_block(&phit[i], &phit[j], &e1);
                for r in 0..3 {
                    for s in 0..3 {
                        x[(3 * i + r, 3 * j + s)] = wb[(i, j)] * einv(i, r) * xb[r][s] * einv(j, s);
                        y[(3 * i + r, 3 * j + s)] =
                            wc[(i, j)] * yb[r][s] / (einv(i, r) * einv(j, s));
                    }
                }
            }
        }
        Ok((x, y))
    }

    /// Square-root balanced truncation to the order chosen by `order`.
    pub fn balanced_truncation(&self, order: Order) -> Result<ReducedSystem, ReduceError> {
        let started = Instant::now();
        let par = faer::get_global_parallelism();
        let mut timings = BalanceTimings::default();
        let mut warnings = Vec::new();
        match order {
            Order::Fixed(0) => return Err(ReduceError::InvalidOption("order r = 0".into())),
            Order::Tolerance(tol) if !(tol.is_finite() && tol > 0.0 && tol < 1.0) => {
                return Err(ReduceError::InvalidOption(format!(
                    "order tolerance {tol} must be in (0, 1)"
                )))
            }
            _ => {}
        }
        if let Some((i, rho)) = self
            .spectral_radii
            .iter()
            .copied()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|&(_, rho)| rho > 1.0 - 1e-8)
        {
            warnings.push(format!(
                "mode {i} ({:.4} Hz) is nearly undamped: 1 − ρ(Φ) = {:.1e}; the Gramians and Hankel singular \
                 values are accurate only to about 1e-16/(1 − ρ) relative",
                self.frequencies_hz[i],
                1.0 - rho
            ));
        }
        let t = Instant::now();
        let g = self.scaled_gramians()?;
        timings.gramians = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let lc = psd_factor(&g.x)?;
        let lo = psd_factor(&g.y)?;
        timings.factors = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let prod = lo.transpose() * &lc;
        let svd = prod.thin_svd().map_err(|_| ReduceError::Dense {
            what: "SVD of Loᵀ Lc",
        })?;
        timings.svd = t.elapsed().as_secs_f64();
        let sigma_n: Vec<f64> = svd.S().column_vector().iter().copied().collect();
        let physical = (g.beta_s * g.gamma_s).sqrt();
        let hsv: Vec<f64> = sigma_n.iter().map(|s| s * physical).collect();
        if hsv.is_empty() || !(hsv[0] > 0.0) {
            return Err(ReduceError::NothingObservable);
        }
        let rank = hsv.iter().filter(|&&s| s > RANK_RATIO * hsv[0]).count();
        let r = match order {
            Order::Fixed(r) => {
                if r > rank {
                    warnings.push(format!(
                        "order {r} capped at the numerical rank {rank} (σ > {RANK_RATIO:e} σ₁)"
                    ));
                }
                r.min(rank)
            }
            Order::Tolerance(tol) => (1..=rank)
                .find(|&r| hsv.get(r).is_none_or(|&s| s <= tol * hsv[0]))
                .unwrap_or(rank),
        };
        let error_bound = 2.0 * hsv[r..].iter().sum::<f64>();

        let t = Instant::now();
        let ka = g.active.len();
        let kappa = (g.beta_s / g.gamma_s).powf(0.25);
        // T = κ Lc W_r Σ^{-1/2}, S = κ⁻¹ Lo U_r Σ^{-1/2} (scaled coordinates, physical scale).
        let tr = &lc
            * svd.V().subcols(0, r)
            * Mat::from_fn(r, r, |i, j| {
                if i == j {
                    kappa / sigma_n[i].sqrt()
                } else {
                    0.0
                }
            });
        let sr = &lo
            * svd.U().subcols(0, r)
            * Mat::from_fn(r, r, |i, j| {
                if i == j {
                    1.0 / (kappa * sigma_n[i].sqrt())
                } else {
                    0.0
                }
            });
        // Φ̂ T blockwise (scalar tᵢ cancels inside a block).
        let mut phit = Mat::<f64>::zeros(3 * ka, r);
        for (a, &i) in g.active.iter().enumerate() {
            for row in 0..3 {
                for col in 0..r {
                    phit[(3 * a + row, col)] = (0..3)
                        .map(|s| g.phi[i][row][s] * tr[(3 * a + s, col)])
                        .sum();
                }
            }
        }
        let transition = sr.transpose() * &phit;
        // Γ̂ (3ka×m): block a = tᵢ γ̃ᵢ bᵢᵀ.
        let m = self.modal_inputs.ncols();
        let gam = Mat::from_fn(3 * ka, m, |p, col| {
            let i = g.active[p / 3];
            g.t[i] * g.gamma[i][p % 3] * self.modal_inputs[(i, col)]
        });
        let input = sr.transpose() * &gam;
        // The same projection for a unit modal force on mode i (column i; inactive modes 0).
        let mut input_map = Mat::<f64>::zeros(r, self.n_modes());
        for (a, &i) in g.active.iter().enumerate() {
            for row in 0..r {
                input_map[(row, i)] = (0..3)
                    .map(|s| sr[(3 * a + s, row)] * g.t[i] * g.gamma[i][s])
                    .sum();
            }
        }
        // q = z₁/tᵢ: T_q (k×r), physical reduced_to_modal and modal_to_reduced.
        let k = self.n_modes();
        let mut tq = Mat::zeros(k, r);
        let mut reduced_to_modal = Mat::zeros(3 * k, r);
        let mut modal_to_reduced = Mat::zeros(r, 3 * k);
        for (a, &i) in g.active.iter().enumerate() {
            let v = g.nu[i];
            let einv = [1.0, v, v * v];
            for col in 0..r {
                tq[(i, col)] = tr[(3 * a, col)] / g.t[i];
                for s in 0..3 {
                    reduced_to_modal[(3 * i + s, col)] = einv[s] * tr[(3 * a + s, col)] / g.t[i];
                    modal_to_reduced[(col, 3 * i + s)] = g.t[i] * sr[(3 * a + s, col)] / einv[s];
                }
            }
        }
        let output = &self.modal_outputs * &tq;
        let mut displacement_map = Mat::zeros(self.basis.nrows(), r);
        matmul(
            displacement_map.as_mut(),
            Accum::Replace,
            self.basis.as_ref(),
            tq.as_ref(),
            1.0,
            par,
        );
        let spectral_radius = spectral_radius(transition.as_ref())?;
        if !(spectral_radius < 1.0) {
            warnings.push(format!(
                "the reduced model is not asymptotically stable: ρ(F) = {spectral_radius}; lower the order"
            ));
        }
        timings.projection = t.elapsed().as_secs_f64();
        timings.total = started.elapsed().as_secs_f64();
        Ok(ReducedSystem {
            transition,
            input,
            output,
            hankel_singular_values: hsv,
            error_bound,
            order: r,
            spectral_radius,
            modal_to_reduced,
            reduced_to_modal,
            displacement_map,
            input_map,
            warnings,
            timings,
        })
    }
}

impl ReducedSystem {
    /// Rows of further outputs (sparse q×n over the DOFs, e.g. displayed nodes or rotation rows
    /// ω) mapped to the reduced state: q×r, y = rows · u ≈ (rows · V T_q) x.
    pub fn project_outputs(
        &self,
        rows: SparseColMatRef<'_, usize, f64>,
    ) -> Result<Mat<f64>, ReduceError> {
        let n = self.displacement_map.nrows();
        if rows.ncols() != n {
            return Err(ReduceError::Dimension {
                what: "output rows",
                expected: format!("q×{n}"),
                got: format!("{}×{}", rows.nrows(), rows.ncols()),
            });
        }
        let mut out = Mat::zeros(rows.nrows(), self.order);
        sparse_dense_matmul(
            out.as_mut(),
            Accum::Replace,
            rows,
            self.displacement_map.as_ref(),
            1.0,
            faer::get_global_parallelism(),
        );
        Ok(out)
    }

    /// The r×k map from a modal force (Vᵀ b, k) to the reduced input column of b: G = this · Vᵀ B
    /// for any force pattern b, seen by the truncation or not.
    pub fn input_map(&self) -> MatRef<'_, f64> {
        self.input_map.as_ref()
    }

    /// u ≈ D x: the n×r map from the reduced state to the nodal displacements.
    pub fn displacement_map(&self) -> MatRef<'_, f64> {
        self.displacement_map.as_ref()
    }

    /// Output response (p×T) to inputs u (m×T) from rest: x' = F x + G u, y = H x (y₀ = 0).
    pub fn simulate(&self, inputs: MatRef<'_, f64>) -> Mat<f64> {
        let steps = inputs.ncols();
        let mut x = Mat::<f64>::zeros(self.order, 1);
        let mut states = Mat::zeros(self.order, steps);
        for step in 0..steps {
            states.col_mut(step).copy_from(x.col(0));
            x = &self.transition * &x + &self.input * inputs.subcols(step, 1);
        }
        &self.output * &states
    }
}
