//! The reduced co-rotational model and its Wilson-θ stepper (docs/design.md §10, item 4).
//!
//! Unknowns q (r) with u ≈ V q (V: n × r, m per unit q). On the sampled elements e ∈ S with
//! weights wₑ ≥ 0 ([`super::ecsw`]), V_e the 12 rows of V at the element's DOFs (zero where a
//! DOF is fixed), xₑ = Xₑ + V_e q:
//! ```text
//! f_r(q)   = Σ_S wₑ V_eᵀ Rₑ Kₑ (Rₑᵀ xₑ − Xₑ)                  reduced internal force (N·m/q)
//! K_t,r(q) = Σ_S wₑ V_eᵀ Rₑ Kₑ Rₑᵀ V_e                          reduced warped stiffness
//! K_N,r(q) = Σ_S wₑ V_eᵀ K_eᶜ V_e                               reduced consistent tangent
//! M_r = VᵀMV (= I for an M-orthonormal V),  C_r(q) = α M_r + β K_t,r(q)
//! ```
//! Per step (τ = θΔt, a₀ = 6/τ², a₂ = 3/τ, Δq̂ = q̂ − q, load f_r = Vᵀf held over the step),
//! exactly the full-order scheme of `stepping::corotational` projected on V:
//! ```text
//! q̈_θ = a₀Δq̂ − (6/τ)q̇ − 2q̈,   q̇_θ = a₂Δq̂ − 2q̇ − (τ/2)q̈
//! res(q̂) = f_r − M_r(q̈_θ + α q̇_θ) − β K_t,r(q̂) q̇_θ − f_r,int(q̂)
//! J = K_N,r + a₂β K_t,r + (a₀ + a₂α) M_r,   q̂ ← q̂ + J⁻¹ res   (dense r × r Cholesky)
//! ```
//! then [`WilsonTheta::advance`] per component. β K_t,r q̇_θ is evaluated per element as
//! V_eᵀ Rₑ Kₑ Rₑᵀ (V_e q̇_θ) (no matrix). J is refreshed per [`Refresh`]; with a frozen J the
//! iteration is a modified Newton converging to the same tolerance.

use nalgebra::{DMatrix, DVector};

use crate::dynamics::WilsonTheta;
use crate::fem::FemModel;
use std::convert::Infallible;

use crate::stepping::load_stepping::{load_steps, LoadStepError};
use crate::stepping::{element_force, element_tangent};

use super::cubature::Cubature;
use super::NonlinearError;

/// The hyper-reduced co-rotational model (basis V, ECSW cubature, reduced mass and damping):
/// what the model file's tier section stores besides the basis rows of the read-out and the
/// training envelope. The linear tier's reduced system is [`crate::reduced::ReducedModel`].
#[derive(Clone, Debug)]
pub struct HyperReducedModel {
    /// The sampled elements and their weights.
    pub cubature: Cubature,
    /// M_r = VᵀMV (r × r, kg per q²).
    pub mass: DMatrix<f64>,
    /// Rayleigh α (1/s).
    pub alpha: f64,
    /// Rayleigh β (s).
    pub beta: f64,
    /// Time stepping.
    pub wilson: WilsonTheta,
}

impl HyperReducedModel {
    /// Builds the model of `fem` on the basis `v` (n × r) with the sampled elements
    /// `(element, weight)`; M_r = vᵀ M v.
    pub fn new(
        fem: &FemModel,
        v: &DMatrix<f64>,
        sampled: &[(usize, f64)],
        wilson: WilsonTheta,
    ) -> Result<Self, NonlinearError> {
        let cubature = Cubature::new(fem, v, sampled)?;
        Ok(Self::with_cubature(fem, v, cubature, wilson))
    }

    /// The model of `fem` on the basis `v` (n × r, the rows of `cubature`'s elements):
    /// M_r = vᵀ M v, Rayleigh damping from `fem`.
    pub fn with_cubature(
        fem: &FemModel,
        v: &DMatrix<f64>,
        cubature: Cubature,
        wilson: WilsonTheta,
    ) -> Self {
        let r = v.ncols();
        let mv = DMatrix::from_columns(
            &(0..r)
                .map(|j| {
                    let col: Vec<f64> = v.column(j).iter().copied().collect();
                    DVector::from_vec(crate::fem::sparse_mul(&fem.mass, &col))
                })
                .collect::<Vec<_>>(),
        );
        let mass = if r == 0 {
            DMatrix::zeros(0, 0)
        } else {
            v.tr_mul(&mv)
        };
        HyperReducedModel {
            cubature,
            mass,
            alpha: fem.alpha,
            beta: fem.beta,
            wilson,
        }
    }

    /// Order r.
    pub fn order(&self) -> usize {
        self.mass.nrows()
    }

    /// Reduced internal force f_r,int(q) (r) and, with `velocity` = Some(ẏ), the damping
    /// stiffness term K_t,r(q) ẏ (r); `force` and `damping` are overwritten.
    pub fn internal_force(
        &self,
        q: &DVector<f64>,
        velocity: Option<&DVector<f64>>,
        force: &mut DVector<f64>,
        damping: &mut DVector<f64>,
    ) {
        force.fill(0.0);
        damping.fill(0.0);
        for el in &self.cubature.elements {
            let u = &el.rows * q;
            let current = current_positions(&el.rest, &u);
            let (f, rot) = element_force(&el.geometry, &el.stiffness, &el.rest, &current);
            let g = DVector::from_column_slice(&f) * el.weight;
            if let Some(v) = velocity {
                let ve = &el.rows * v;
                // R K Rᵀ vₑ
                let mut local = [0.0; 12];
                for a in 0..4 {
                    let va = nalgebra::Vector3::new(ve[3 * a], ve[3 * a + 1], ve[3 * a + 2]);
                    let la = rot.tr_mul(&va);
                    local[3 * a..3 * a + 3].copy_from_slice(la.as_slice());
                }
                let kl = crate::fem::element::mul12(&el.stiffness, &local);
                let mut d = DVector::zeros(12);
                for a in 0..4 {
                    let da = rot * nalgebra::Vector3::new(kl[3 * a], kl[3 * a + 1], kl[3 * a + 2]);
                    d.rows_mut(3 * a, 3).copy_from(&da);
                }
                damping.gemv_tr(el.weight, &el.rows, &d, 1.0);
            }
            force.gemv_tr(1.0, &el.rows, &g, 1.0);
        }
    }

    /// Allocation-free reduced force for the stepper: `out` = f_r,int(q) + β K_t,r(q) ẏ
    /// (r; the sum of the internal force and the stiffness-proportional damping force of
    /// the module docs), per element by the shared kernel ([`crokf_kernel::gather`],
    /// [`crokf_kernel::scatter`], [`crokf_kernel::polar_rotation`]: the runtime's), with the
    /// SVD polar decomposition of the full-order reference as the fallback for inverted
    /// elements (where the runtime refuses the step).
    pub fn force_with_damping(&self, q: &[f64], velocity: &[f64], beta: f64, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        for el in &self.cubature.elements {
            let e = crokf_kernel::Element {
                weight: el.weight,
                rest: &el.rest,
                gradients: &el.geometry.gradients,
                stiffness: el.stiffness.as_flattened(),
                rows: &el.flat,
                cols: &el.flat_t,
            };
            let g = crokf_kernel::gather(&e, q, velocity);
            // Where the kernel refuses (inverted or degenerate), the SVD rule directly
            // (`stepping::polar_rotation` would run the same kernel iteration first).
            let rot = crokf_kernel::polar_rotation(&g.f).unwrap_or_else(|_| {
                let m = crate::stepping::polar_rotation_svd(&nalgebra::Matrix3::from_fn(|i, j| {
                    g.f[i][j]
                }));
                std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
            });
            crokf_kernel::scatter(&e, &g, &rot, beta, out);
        }
    }

    /// Reduced tangents at q: K_N,r + c_w K_t,r (r × r); the consistent element tangent where
    /// `consistent`, else the warped one for both terms.
    pub fn tangent(&self, q: &DVector<f64>, c_w: f64, consistent: bool) -> DMatrix<f64> {
        let r = self.order();
        let mut out = DMatrix::zeros(r, r);
        for el in &self.cubature.elements {
            let u = &el.rows * q;
            let current = current_positions(&el.rest, &u);
            let kw = element_tangent(&el.geometry, &el.stiffness, &el.rest, &current, false);
            let kc = if consistent {
                element_tangent(&el.geometry, &el.stiffness, &el.rest, &current, true)
            } else {
                kw
            };
            let ke = DMatrix::from_fn(12, 12, |i, j| kc[i][j] + c_w * kw[i][j]);
            let kv = ke * &el.rows;
            out.gemm_tr(el.weight, &el.rows, &kv, 1.0);
        }
        (&out + out.transpose()) * 0.5
    }
}

impl HyperReducedModel {
    /// Reduced quasi-static equilibrium f_r,int(q) = `load` (r) by Newton on K_N,r with
    /// adaptive load stepping ([`load_steps`]: an increment that does not converge in 30
    /// iterations is halved, one that converges in ≤ 6 lets the next grow by 1.5), as the
    /// full-order `CorotationalSimulator::static_solve`. Converged when ‖δ‖ ≤ `tolerance`‖q‖.
    pub fn static_solve(
        &self,
        load: &DVector<f64>,
        tolerance: f64,
    ) -> Result<DVector<f64>, NonlinearError> {
        let r = self.order();
        if load.len() != r {
            return Err(NonlinearError::Invalid(format!(
                "reduced load has length {}, expected r = {r}",
                load.len()
            )));
        }
        let (mut force, mut unused) = (DVector::zeros(r), DVector::zeros(r));
        let solve = |q: &DVector<f64>, target: f64| {
            let mut trial = q.clone();
            for it in 1..=30 {
                self.internal_force(&trial, None, &mut force, &mut unused);
                let res = load * target - &force;
                let tangent = self.tangent(&trial, 0.0, true);
                let delta = match tangent.clone().cholesky() {
                    Some(ch) => ch.solve(&res),
                    None => match self.tangent(&trial, 0.0, false).cholesky() {
                        Some(ch) => ch.solve(&res),
                        None => break,
                    },
                };
                trial += &delta;
                if !trial.norm().is_finite() {
                    break;
                }
                if delta.norm() <= tolerance * trial.norm() {
                    return Ok::<_, Infallible>(Some((trial, it)));
                }
            }
            Ok(None)
        };
        match load_steps(DVector::zeros(r), solve) {
            Ok(q) => Ok(q),
            Err(LoadStepError::Stuck { load_factor }) => Err(NonlinearError::Invalid(format!(
                "reduced static solve stuck at load factor {load_factor:.4}"
            ))),
            Err(LoadStepError::Solve(never)) => match never {},
        }
    }
}

/// xₑ = Xₑ + uₑ (uₑ: 12, node-major).
fn current_positions(rest: &[[f64; 3]; 4], u: &DVector<f64>) -> [[f64; 3]; 4] {
    std::array::from_fn(|a| std::array::from_fn(|c| rest[a][c] + u[3 * a + c]))
}

/// When the reduced Newton matrix J is recomputed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refresh {
    /// At every Newton iteration (full Newton, as the full-order reference).
    EveryIteration,
    /// At the first iteration of every step.
    EveryStep,
    /// Only when the previous step needed more than `iterations` Newton iterations (and at
    /// the first step), and once within a step that reaches `iterations` unconverged:
    /// modified Newton.
    WhenSlow {
        /// Iteration count that triggers a refresh.
        iterations: usize,
    },
}

/// Newton settings of the reduced stepper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReducedNewton {
    /// Most iterations per step (bounded, ≥ 1).
    pub max_iterations: usize,
    /// Converged when ‖δ‖ ≤ tolerance ‖q̂‖.
    pub tolerance: f64,
    /// Tangent refresh policy.
    pub refresh: Refresh,
    /// Consistent element tangent (true) or warped R K Rᵀ.
    pub consistent: bool,
    /// Start Newton from the Taylor predictor q̂₀ = q + τq̇ + (τ²/2)q̈ instead of q̂₀ = q
    /// (the full-order reference starts from Û = U).
    pub predictor: bool,
}

impl Default for ReducedNewton {
    fn default() -> Self {
        ReducedNewton {
            max_iterations: 30,
            tolerance: 1e-8,
            refresh: Refresh::WhenSlow { iterations: 4 },
            consistent: true,
            predictor: false,
        }
    }
}

/// Counters of the reduced stepper.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReducedStats {
    /// Steps.
    pub steps: usize,
    /// Newton iterations (force evaluations).
    pub iterations: usize,
    /// Tangent refreshes (reduced tangent assemblies + Cholesky).
    pub refreshes: usize,
    /// Steps that ended at `max_iterations` unconverged.
    pub unconverged: usize,
}

/// Reduced co-rotational Wilson-θ stepper on q (module docs).
pub struct ReducedStepper {
    model: HyperReducedModel,
    newton: ReducedNewton,
    q: DVector<f64>,
    v: DVector<f64>,
    a: DVector<f64>,
    time: f64,
    stats: ReducedStats,
    factor: Option<nalgebra::Cholesky<f64, nalgebra::Dyn>>,
    slow: bool,
    force: DVector<f64>,
}

impl ReducedStepper {
    /// At rest.
    pub fn new(model: HyperReducedModel, newton: ReducedNewton) -> Result<Self, NonlinearError> {
        if newton.max_iterations == 0 || newton.tolerance.is_nan() || newton.tolerance <= 0.0 {
            return Err(NonlinearError::Invalid(format!(
                "reduced Newton: max_iterations must be ≥ 1 and tolerance > 0, got {} and {}",
                newton.max_iterations, newton.tolerance
            )));
        }
        let r = model.order();
        Ok(ReducedStepper {
            model,
            newton,
            q: DVector::zeros(r),
            v: DVector::zeros(r),
            a: DVector::zeros(r),
            time: 0.0,
            stats: ReducedStats::default(),
            factor: None,
            slow: true,
            force: DVector::zeros(r),
        })
    }

    /// The model.
    pub fn model(&self) -> &HyperReducedModel {
        &self.model
    }

    /// q (r).
    pub fn coordinates(&self) -> &DVector<f64> {
        &self.q
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Counters.
    pub fn stats(&self) -> ReducedStats {
        self.stats
    }

    fn refresh(&mut self, q_hat: &DVector<f64>) -> Result<(), NonlinearError> {
        let w = self.model.wilson;
        let (a0, a2) = (w.mass_coefficient(), w.damping_coefficient());
        let mut consistent = self.newton.consistent;
        loop {
            let mut j = self.model.tangent(q_hat, a2 * self.model.beta, consistent);
            j += &self.model.mass * (a0 + a2 * self.model.alpha);
            match j.cholesky() {
                Some(f) => {
                    self.factor = Some(f);
                    self.stats.refreshes += 1;
                    return Ok(());
                }
                None if consistent => consistent = false,
                None => {
                    return Err(NonlinearError::NotPositiveDefinite {
                        step: self.stats.steps + 1,
                        time: self.time,
                        order: self.model.order(),
                        pivot: 0,
                    })
                }
            }
        }
    }

    /// Advances by Δt with the reduced load f_r = Vᵀf (r, N per q) held over the step.
    pub fn step(&mut self, load: &DVector<f64>) -> Result<(), NonlinearError> {
        let r = self.model.order();
        if load.len() != r {
            return Err(NonlinearError::Invalid(format!(
                "reduced load has length {}, expected r = {r}",
                load.len()
            )));
        }
        let w = self.model.wilson;
        let tau = w.tau();
        let (a0, a1, a2) = (
            w.mass_coefficient(),
            w.velocity_coefficient(),
            w.damping_coefficient(),
        );
        let (alpha, beta) = (self.model.alpha, self.model.beta);
        let mut q_hat = self.q.clone();
        if self.newton.predictor {
            q_hat += &self.v * tau + &self.a * (0.5 * tau * tau);
        }
        let refresh_step = match self.newton.refresh {
            Refresh::EveryIteration | Refresh::EveryStep => true,
            Refresh::WhenSlow { .. } => self.slow || self.factor.is_none(),
        };
        let mut iterations = 0;
        let mut converged = false;
        let mut force = std::mem::replace(&mut self.force, DVector::zeros(0));
        while iterations < self.newton.max_iterations {
            let du = &q_hat - &self.q;
            let acc = &du * a0 - &self.v * a1 - &self.a * 2.0;
            let vel = &du * a2 - &self.v * 2.0 - &self.a * (0.5 * tau);
            self.model.force_with_damping(
                q_hat.as_slice(),
                vel.as_slice(),
                beta,
                force.as_mut_slice(),
            );
            let mut res = load - &force;
            res -= &self.model.mass * (&acc + &vel * alpha);
            // With a frozen J, a step still unconverged after the policy's iteration count
            // refreshes J once within the step.
            let stalled = matches!(
                self.newton.refresh,
                Refresh::WhenSlow { iterations: limit } if iterations == limit.max(1)
            );
            let refresh_now = self.newton.refresh == Refresh::EveryIteration
                || (iterations == 0 && refresh_step)
                || stalled
                || self.factor.is_none();
            if refresh_now {
                self.refresh(&q_hat)?;
            }
            let Some(factor) = &self.factor else {
                return Err(NonlinearError::NotPositiveDefinite {
                    step: self.stats.steps + 1,
                    time: self.time,
                    order: r,
                    pivot: 0,
                });
            };
            let delta = factor.solve(&res);
            q_hat += &delta;
            iterations += 1;
            let size = q_hat.norm();
            if !size.is_finite() {
                return Err(NonlinearError::NonFinite {
                    step: self.stats.steps + 1,
                    time: self.time,
                });
            }
            if delta.norm() <= self.newton.tolerance * size || size == 0.0 {
                converged = true;
                break;
            }
        }
        self.force = force;
        self.stats.steps += 1;
        self.stats.iterations += iterations;
        if !converged {
            self.stats.unconverged += 1;
        }
        if let Refresh::WhenSlow { iterations: limit } = self.newton.refresh {
            self.slow = iterations > limit || !converged;
        }
        for i in 0..r {
            let (q, v, a) = w.advance(self.q[i], self.v[i], self.a[i], q_hat[i]);
            self.q[i] = q;
            self.v[i] = v;
            self.a[i] = a;
        }
        self.time += w.dt;
        Ok(())
    }
}
