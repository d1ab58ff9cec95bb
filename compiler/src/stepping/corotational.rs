//! Full-order co-rotational reference (stiffness warping): per element, the rotation Rₑ of the
//! polar decomposition Fₑ = Rₑ Sₑ of the deformation gradient, the internal force
//! fₑ = Rₑ Kₑ (Rₑᵀ xₑ − Xₑ) and the warped tangent Rₑ Kₑ Rₑᵀ (docs/design.md §7 (b)).
//!
//! External loads are world-frame dead loads: a force on a load group keeps its world direction
//! while the body rotates (it is not a follower load).

use nalgebra::Vector3;

use crate::dynamics::WilsonTheta;
use crate::fem::{FemModel, TetGeometry};

use super::element::{corotated_forces, warped_forces, Kinematics};
use super::load_stepping::{load_steps, LoadStepError};
use super::sparse::Pattern;
use super::{advance_all, check_len, norm, Simulator, SteppingError};

/// Newton settings of the co-rotational solvers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NewtonOptions {
    /// Most linear solves per time step (≥ 1; 1 = one linearised solve per step).
    pub max_newton: usize,
    /// Converged when the Newton increment ‖δ‖ ≤ tolerance · ‖Û‖ (or below the round-off
    /// floor 16 ε × the mesh's bounding-box diagonal).
    pub tolerance: f64,
    /// Newton matrix from the consistent tangent (exact derivative of f_int, quadratic
    /// convergence) instead of the warped stiffness R K Rᵀ (classic stiffness warping; converges
    /// only linearly, and stalls near large rotations under load). Damping always uses the warped
    /// stiffness. Where the consistent matrix is not positive definite the warped one is used.
    pub consistent: bool,
}

impl Default for NewtonOptions {
    fn default() -> Self {
        NewtonOptions {
            max_newton: 10,
            tolerance: 1e-8,
            consistent: true,
        }
    }
}

/// Counters of the Newton iterations so far.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NewtonStats {
    /// Time steps taken.
    pub steps: usize,
    /// Linear solves (numeric Cholesky factorisations) in all steps.
    pub solves: usize,
    /// Steps that stopped at `max_newton` without meeting the tolerance.
    pub unconverged: usize,
    /// Solves that fell back to the warped matrix (consistent one not positive definite).
    pub fallbacks: usize,
    /// Largest final relative increment ‖δ‖/‖Û‖ of any step (with [`ModifiedNewton`]: the
    /// estimated error η‖δ‖/‖Û‖ of the accepted iterate).
    pub worst_increment: f64,
    /// Numeric Cholesky factorisations of the Newton matrix (= `solves` with full Newton).
    pub factorisations: usize,
    /// Wall time in element loops (internal force, tangents), s.
    pub assembly_seconds: f64,
    /// Wall time in numeric factorisations, s.
    pub factor_seconds: f64,
    /// Wall time in triangular solves, s.
    pub solve_seconds: f64,
}

/// Modified Newton for the dynamic step (docs/design.md §10, training cost): the factorised
/// Newton matrix J_t is kept across iterations and time steps while the iteration contracts,
/// and refactored at the current iterate when it stalls. Iteration k solves J_t* δₖ = r(Ûₖ)
/// with the stale J_t*; ρₖ = ‖δₖ‖/‖δₖ₋₁‖ estimates the contraction, and the iterate is accepted
/// when its estimated error η‖δₖ‖ ≤ tolerance·‖Û‖ (Hairer & Wanner, *Solving ODEs II*, §IV.8):
/// η = ρ/(1−ρ) with ρ measured in this step on this factorisation (from the second iteration
/// after a factorisation), else η = max(ρ/(1−ρ), 1) with the ρ carried from before, so that a
/// first iterate is accepted only when its increment itself meets the tolerance. A
/// factorisation is redone when ρₖ > `contraction`, when ρₖ ≥ 1, or after `iterations`
/// iterations without acceptance. The accepted state is within the tolerance of the root (to
/// the accuracy of the η estimate; full Newton's test bounds its last increment instead); the
/// path is an option of [`CorotationalSimulator`], off by default (the full-order reference
/// keeps full Newton).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModifiedNewton {
    /// Refactor when the measured contraction ρ exceeds this (0 < contraction < 1).
    pub contraction: f64,
    /// Iterations with one factorisation before it is redone (≥ 1).
    pub iterations: usize,
    /// Start each step from the Taylor predictor Û₀ = U + τU̇ + (τ²/2)Ü (τ = θΔt; the
    /// runtime tier's predictor) instead of Û₀ = U. The iteration and its tolerance are
    /// unchanged; a start nearer the root needs fewer iterations.
    pub predictor: bool,
}

impl Default for ModifiedNewton {
    fn default() -> Self {
        ModifiedNewton {
            contraction: 0.25,
            iterations: 8,
            predictor: true,
        }
    }
}

/// Per-element data kept between steps: what every force evaluation reads (the element
/// matrices the tangents need are kept apart in [`ElementMatrices`], so that the force loop
/// streams about 350 bytes per element instead of 2 kB).
struct ElementData {
    nodes: [usize; 4],
    dofs: [Option<usize>; 12],
    geometry: TetGeometry,
    /// (Vλ, Vμ): volume times the Lamé constants, N·m (the closed-form force of
    /// [`corotated_forces`]).
    lame: [f64; 2],
}

/// Per-element data of the tangent assembly.
struct ElementMatrices {
    ke: [[f64; 12]; 12],
    /// Value slot of entry (i, j) of the element matrix in the pattern (row-major, 12×12),
    /// `u32::MAX` where a DOF is fixed.
    slots: [u32; 144],
}

impl ElementData {
    /// Co-rotated kinematics at the free-DOF displacement u (m): the rest positions of the
    /// element's vertices (from `rest`, all nodes) plus u at its free DOFs.
    fn kinematics(&self, ke: &[[f64; 12]; 12], rest: &[[f64; 3]], u: &[f64]) -> Kinematics {
        let current = self.current(rest, u);
        Kinematics::new(&self.geometry, ke, &self.nodes.map(|n| rest[n]), &current)
    }

    /// The current vertex positions (m): rest positions from `rest` (all nodes) plus u at the
    /// free DOFs.
    fn current(&self, rest: &[[f64; 3]], u: &[f64]) -> [[f64; 3]; 4] {
        let mut current = self.nodes.map(|n| rest[n]);
        for (k, dof) in self.dofs.iter().enumerate() {
            if let Some(d) = dof {
                current[k / 3][k % 3] += u[*d];
            }
        }
        current
    }

    /// The element's nodal values of a free-DOF vector (0 at fixed DOFs).
    fn nodal(&self, v: &[f64]) -> [[f64; 3]; 4] {
        std::array::from_fn(|a| std::array::from_fn(|i| self.dofs[3 * a + i].map_or(0.0, |d| v[d])))
    }

    /// Adds the world-frame node forces `force(a)` (a = 0..3, N) into `out` at the element's
    /// free DOFs.
    fn scatter(&self, out: &mut [f64], force: impl Fn(usize) -> Vector3<f64>) {
        for a in 0..4 {
            let fa = force(a);
            for i in 0..3 {
                if let Some(d) = self.dofs[3 * a + i] {
                    out[d] += fa[i];
                }
            }
        }
    }
}

/// Full-order co-rotational Wilson-θ: M Ü + C U̇ + f_int(U) = f with
/// f_int = Σₑ Rₑ Kₑ (Rₑᵀ xₑ − Xₑ), C = αM + β K_t, K_t = Σₑ Rₑ Kₑ Rₑᵀ (warped).
///
/// Per step (τ = θΔt, a₀ = 6/τ², a₂ = 3/τ, ΔÛ = Û − U, load f held over the step):
/// ```text
/// Ü_θ = a₀ ΔÛ − (6/τ) U̇ − 2Ü,   U̇_θ = a₂ ΔÛ − 2U̇ − (τ/2) Ü
/// r(Û) = f − M Ü_θ − C U̇_θ − f_int(Û),   J_t = K_N + a₀M + a₂C,   Û ← Û + J_t⁻¹ r
/// ```
/// from Û = U, at least once and up to `max_newton` times (symbolic Cholesky reused, numeric
/// refactored each time), then [`WilsonTheta::advance`] per DOF. K_N is the consistent tangent
/// or K_t ([`NewtonOptions::consistent`]).
pub struct CorotationalSimulator {
    wilson: WilsonTheta,
    alpha: f64,
    beta: f64,
    options: NewtonOptions,
    rest: Vec<[f64; 3]>,
    elements: Vec<ElementData>,
    /// The elements' matrices, in the order of `elements`.
    matrices: Vec<ElementMatrices>,
    pattern: Pattern,
    mass: Vec<f64>,
    /// Warped stiffness K_t values.
    warped: Vec<f64>,
    /// Consistent tangent values (when `options.consistent`).
    consistent: Vec<f64>,
    jacobian: Vec<f64>,
    internal: Vec<f64>,
    u: Vec<f64>,
    v: Vec<f64>,
    a: Vec<f64>,
    time: f64,
    stats: NewtonStats,
    /// Modified Newton settings (None: full Newton, J_t refactored every iteration).
    modified: Option<ModifiedNewton>,
    /// The kept factorisation of J_t (modified Newton only).
    kept: Option<super::sparse::Factor>,
    /// Last measured contraction ρ (modified Newton only).
    contraction: f64,
    /// β K_t U̇_θ, element by element (modified Newton only), N.
    damping_force: Vec<f64>,
    /// Round-off floor of a Newton increment, m: 16 ε × the diagonal of the mesh's bounding box
    /// (f_int carries ~ε·h relative noise even at rest).
    floor: f64,
    /// M's factor, made on the first [`CorotationalSimulator::consistent_acceleration`].
    mass_factor: Option<super::sparse::Factor>,
}

impl CorotationalSimulator {
    /// Builds the simulator at rest; checks `options`.
    pub fn new(
        fem: &FemModel,
        wilson: WilsonTheta,
        options: NewtonOptions,
    ) -> Result<Self, SteppingError> {
        if options.max_newton == 0 || options.tolerance.is_nan() || options.tolerance <= 0.0 {
            return Err(SteppingError::Options(format!(
                "Newton: max_newton must be ≥ 1 and tolerance > 0, got {} and {}",
                options.max_newton, options.tolerance
            )));
        }
        let pattern = Pattern::new(fem)?;
        let mass = pattern.scatter(&fem.mass);
        let elements = fem
            .elements
            .iter()
            .map(|el| ElementData {
                nodes: el.nodes,
                dofs: fem.dofs.element(&el.nodes),
                geometry: el.geometry,
                lame: {
                    let (lambda, mu) = fem.materials[el.material].lame();
                    let v = el.geometry.volume.abs();
                    [v * lambda, v * mu]
                },
            })
            .collect::<Vec<_>>();
        if pattern.nnz() >= u32::MAX as usize {
            return Err(SteppingError::Solver(format!(
                "{} stored entries exceed the 32-bit slot index",
                pattern.nnz()
            )));
        }
        let matrices = elements
            .iter()
            .enumerate()
            .map(|(e, el)| ElementMatrices {
                ke: fem.element_stiffness(e),
                slots: std::array::from_fn(|k| match (el.dofs[k / 12], el.dofs[k % 12]) {
                    (Some(r), Some(c)) => pattern.slot(r, c) as u32,
                    _ => u32::MAX,
                }),
            })
            .collect();
        let n = pattern.n;
        let nnz = pattern.nnz();
        Ok(CorotationalSimulator {
            wilson,
            alpha: fem.alpha,
            beta: fem.beta,
            options,
            rest: fem.positions.clone(),
            elements,
            matrices,
            pattern,
            mass,
            warped: vec![0.0; nnz],
            consistent: if options.consistent {
                vec![0.0; nnz]
            } else {
                Vec::new()
            },
            jacobian: vec![0.0; nnz],
            internal: vec![0.0; n],
            u: vec![0.0; n],
            v: vec![0.0; n],
            a: vec![0.0; n],
            time: 0.0,
            stats: NewtonStats::default(),
            modified: None,
            kept: None,
            contraction: 0.0,
            damping_force: Vec::new(),
            floor: 16.0 * f64::EPSILON * crate::mesh::bounding_diagonal(&fem.positions),
            mass_factor: None,
        })
    }

    /// Newton counters so far.
    pub fn stats(&self) -> NewtonStats {
        self.stats
    }

    /// Factorisations and triangular solves on the calling thread only (faer's thread pool
    /// otherwise): for simulators run several at a time, e.g. the training runs. Results are
    /// those of a sequential factorisation.
    pub fn set_sequential(&mut self) {
        self.pattern.set_sequential();
    }

    /// Selects modified Newton for [`Simulator::step`] (None: full Newton, the default); checks
    /// the settings. The tolerance stays [`NewtonOptions::tolerance`].
    pub fn set_modified_newton(
        &mut self,
        modified: Option<ModifiedNewton>,
    ) -> Result<(), SteppingError> {
        if let Some(m) = modified {
            if !(m.contraction > 0.0 && m.contraction < 1.0) || m.iterations == 0 {
                return Err(SteppingError::Options(format!(
                    "modified Newton: contraction must lie in (0, 1) and iterations be ≥ 1, got                      {} and {}",
                    m.contraction, m.iterations
                )));
            }
            self.damping_force = vec![0.0; self.pattern.n];
        }
        self.modified = modified;
        self.kept = None;
        Ok(())
    }

    /// Internal force f_int(u) into `self.internal` and, with `velocity` = Some(v), the damping
    /// stiffness force K_t v = Σₑ Rₑ Kₑ Rₑᵀ vₑ into `self.damping_force` (element by element,
    /// no matrix assembled), at the free-DOF displacement u (m).
    fn assemble_force(&mut self, u: &[f64], velocity: Option<&[f64]>) {
        let started = std::time::Instant::now();
        self.internal.iter_mut().for_each(|v| *v = 0.0);
        self.damping_force.iter_mut().for_each(|v| *v = 0.0);
        for el in &self.elements {
            let (r, force) = corotated_forces(&el.geometry, el.lame, &el.current(&self.rest, u));
            el.scatter(&mut self.internal, |a| force[a]);
            if let Some(vel) = velocity {
                let damping = warped_forces(&el.geometry, el.lame, &r, &el.nodal(vel));
                el.scatter(&mut self.damping_force, |a| damping[a]);
            }
        }
        self.stats.assembly_seconds += started.elapsed().as_secs_f64();
    }

    /// Internal force f_int(u) (n, N), warped stiffness and (if enabled) consistent tangent
    /// (pattern values) at the free-DOF displacement u (m).
    fn assemble(&mut self, u: &[f64]) {
        let started = std::time::Instant::now();
        let consistent = self.options.consistent;
        self.internal.iter_mut().for_each(|v| *v = 0.0);
        self.warped.iter_mut().for_each(|v| *v = 0.0);
        self.consistent.iter_mut().for_each(|v| *v = 0.0);
        let (warped, consistent_values) = (&mut self.warped, &mut self.consistent);
        for (el, mats) in self.elements.iter().zip(&self.matrices) {
            let kin = el.kinematics(&mats.ke, &self.rest, u);
            el.scatter(&mut self.internal, |a| kin.force(a));
            kin.tangents(&el.geometry, &mats.ke, consistent, |a, b, kw, kc| {
                for i in 0..3 {
                    for j in 0..3 {
                        let slot = mats.slots[12 * (3 * a + i) + 3 * b + j];
                        if slot == u32::MAX {
                            continue;
                        }
                        let slot = slot as usize;
                        warped[slot] += kw[(i, j)];
                        if consistent {
                            consistent_values[slot] += kc[(i, j)];
                        }
                    }
                }
            });
        }
        self.stats.assembly_seconds += started.elapsed().as_secs_f64();
    }

    /// Internal force f_int(u) (n, N) at the free-DOF displacement u (n, m).
    pub fn internal_force(&mut self, u: &[f64]) -> Result<Vec<f64>, SteppingError> {
        check_len("displacement u", self.pattern.n, u.len())?;
        self.assemble(u);
        Ok(self.internal.clone())
    }

    /// The Newton residual of one Wilson-θ step from the current state under the load f (n, N)
    /// at the trial Û (n, m), into `out` (n): [`CorotationalSimulator::dynamic_residual`] at Û
    /// with the Wilson-θ rates U̇_θ, Ü_θ of Û, zero at the step's solution. For a solver that
    /// searches Û elsewhere than in the whole space (a reduced manifold); the state is
    /// unchanged until [`CorotationalSimulator::accept_step`].
    pub fn step_residual(
        &mut self,
        u_hat: &[f64],
        f: &[f64],
        out: &mut [f64],
    ) -> Result<(), SteppingError> {
        let n = self.pattern.n;
        check_len("trial displacement", n, u_hat.len())?;
        check_len("load vector f", n, f.len())?;
        check_len("residual", n, out.len())?;
        let mut vel = vec![0.0; n];
        let mut y = vec![0.0; n];
        self.theta_rates(u_hat, &mut vel, &mut y);
        self.assemble(u_hat);
        let mut scratch = vec![0.0; n];
        self.assembled_residual(&vel, &y, f, out, &mut scratch);
        Ok(())
    }

    /// The equation of motion's residual at a displacement u, velocity u̇ and acceleration ü
    /// (n each) under the load f (n, N), into `out` (n):
    /// r = f − f_int(u) − M (ü + α u̇) − β K_t(u) u̇. The state is unchanged.
    pub fn dynamic_residual(
        &mut self,
        u: &[f64],
        velocity: &[f64],
        acceleration: &[f64],
        f: &[f64],
        out: &mut [f64],
    ) -> Result<(), SteppingError> {
        let n = self.pattern.n;
        check_len("displacement", n, u.len())?;
        check_len("velocity", n, velocity.len())?;
        check_len("acceleration", n, acceleration.len())?;
        check_len("load vector f", n, f.len())?;
        check_len("residual", n, out.len())?;
        self.assemble(u);
        let y: Vec<f64> = acceleration
            .iter()
            .zip(velocity)
            .map(|(a, v)| a + self.alpha * v)
            .collect();
        let mut scratch = vec![0.0; n];
        self.assembled_residual(velocity, &y, f, out, &mut scratch);
        Ok(())
    }

    /// r = f − f_int − M y − β K_t u̇ at the last assembly (f_int and K_t of its displacement),
    /// y = ü + α u̇, into `out` (n each; `scratch` n): the equation of motion's residual, the
    /// full Newton's and [`CorotationalSimulator::dynamic_residual`]'s.
    fn assembled_residual(
        &self,
        velocity: &[f64],
        y: &[f64],
        f: &[f64],
        out: &mut [f64],
        scratch: &mut [f64],
    ) {
        for ((r, fi), int) in out.iter_mut().zip(f).zip(&self.internal) {
            *r = fi - int;
        }
        self.pattern.mul(&self.mass, y, scratch);
        out.iter_mut().zip(&*scratch).for_each(|(r, v)| *r -= v);
        if self.beta != 0.0 {
            self.pattern.mul(&self.warped, velocity, scratch);
            out.iter_mut()
                .zip(&*scratch)
                .for_each(|(r, v)| *r -= self.beta * v);
        }
    }

    /// Ü ← M⁻¹ (f − f_int(U) − αM U̇ − β K_t(U) U̇): the acceleration the equation of motion
    /// gives at the current state under a load f (n, N) that starts now (U, U̇ and the time
    /// unchanged). Wilson-θ assumes the acceleration linear over a step, so a load that jumps
    /// at a step's start costs it first order in Δt; restarting the acceleration where the
    /// load changes keeps it second order, as
    /// [`LinearSimulator::consistent_acceleration`](super::LinearSimulator::consistent_acceleration)
    /// does for the linear model (the converged reference of [`crate::nonlinear::time_error`]).
    pub fn consistent_acceleration(&mut self, f: &[f64]) -> Result<(), SteppingError> {
        let n = self.pattern.n;
        check_len("load vector f", n, f.len())?;
        if self.mass_factor.is_none() {
            self.mass_factor = Some(self.pattern.factor(&self.mass, "mass matrix M")?);
        }
        let (u, v) = (self.u.clone(), self.v.clone());
        let mut r = vec![0.0; n];
        self.dynamic_residual(&u, &v, &vec![0.0; n], f, &mut r)?;
        if let Some(m) = &self.mass_factor {
            m.solve_in_place(&mut r);
        }
        self.a = r;
        Ok(())
    }

    /// Accepts Û (n, m) as the solution of the current step (found by the caller, e.g. on
    /// [`CorotationalSimulator::step_residual`]): advances U, U̇, Ü by Wilson-θ and the time.
    pub fn accept_step(&mut self, u_hat: &[f64]) -> Result<(), SteppingError> {
        check_len("accepted displacement", self.pattern.n, u_hat.len())?;
        advance_all(&self.wilson, &mut self.u, &mut self.v, &mut self.a, u_hat);
        self.time += self.wilson.dt;
        self.stats.steps += 1;
        Ok(())
    }

    /// Factors J = c_k K_N + c_w K_t + c_m M, K_N the consistent tangent (if enabled, else K_t),
    /// falling back to K_N = K_t when that matrix is not positive definite.
    fn factor_newton(
        &mut self,
        c_k: f64,
        c_w: f64,
        c_m: f64,
        what: &str,
    ) -> Result<super::sparse::Factor, SteppingError> {
        let mut use_consistent = self.options.consistent;
        loop {
            let tangent = if use_consistent {
                &self.consistent
            } else {
                &self.warped
            };
            for (((j, k), w), m) in self
                .jacobian
                .iter_mut()
                .zip(tangent)
                .zip(&self.warped)
                .zip(&self.mass)
            {
                *j = c_k * k + c_w * w + c_m * m;
            }
            let started = std::time::Instant::now();
            let factored = self.pattern.factor(&self.jacobian, what);
            self.stats.factor_seconds += started.elapsed().as_secs_f64();
            self.stats.factorisations += 1;
            match factored {
                Ok(factor) => return Ok(factor),
                Err(SteppingError::NotPositiveDefinite { .. }) if use_consistent => {
                    self.stats.fallbacks += 1;
                    use_consistent = false;
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Quasi-static equilibrium f_int(u) = f (f: n, N, world-frame dead load) by Newton with
    /// adaptive load stepping ([`load_steps`], λ from 0 to 1; an increment that does not converge in 30 solves
    /// is halved, one that converges in ≤ 6 lets the next grow by 1.5). Converged when
    /// ‖δ‖ ≤ `tolerance` ‖u‖. The dynamic state is left unchanged.
    pub fn static_solve(&mut self, f: &[f64], tolerance: f64) -> Result<Vec<f64>, SteppingError> {
        let n = self.pattern.n;
        check_len("load vector f", n, f.len())?;
        const MAX_SOLVES: usize = 30;
        let mut total_solves = 0;
        let mut r = vec![0.0; n];
        let solve =
            |u: &Vec<f64>, target: f64| -> Result<Option<(Vec<f64>, usize)>, SteppingError> {
                let mut trial = u.clone();
                let mut first = f64::INFINITY;
                for it in 1..=MAX_SOLVES {
                    self.assemble(&trial);
                    for i in 0..n {
                        r[i] = target * f[i] - self.internal[i];
                    }
                    let factor =
                        self.factor_newton(1.0, 0.0, 0.0, "tangent stiffness (static solve)")?;
                    timed_solve(&mut self.stats, &factor, &mut r);
                    total_solves += 1;
                    trial.iter_mut().zip(&r).for_each(|(t, d)| *t += d);
                    let step = norm(&r);
                    if it == 1 {
                        first = step;
                    }
                    if !step.is_finite() || step > 10.0 * first {
                        break;
                    }
                    if step <= tolerance * norm(&trial) || step <= self.floor {
                        return Ok(Some((trial, it)));
                    }
                }
                Ok(None)
            };
        match load_steps(vec![0.0; n], solve) {
            Ok(u) => Ok(u),
            Err(LoadStepError::Stuck { load_factor }) => Err(SteppingError::StaticDiverged {
                load_factor,
                solves: total_solves,
            }),
            Err(LoadStepError::Solve(e)) => Err(e),
        }
    }
}

/// b ← A⁻¹ b with the time counted in `stats.solve_seconds`.
fn timed_solve(stats: &mut NewtonStats, factor: &super::sparse::Factor, b: &mut [f64]) {
    let started = std::time::Instant::now();
    factor.solve_in_place(b);
    stats.solve_seconds += started.elapsed().as_secs_f64();
}

impl CorotationalSimulator {
    /// The Wilson-θ rates at the iterate Û (docs/design.md §4.2): U̇_θ into `vel` and
    /// Ü_θ + α U̇_θ into `y` (the vector M multiplies in the residual), from U, U̇, Ü.
    fn theta_rates(&self, u_hat: &[f64], vel: &mut [f64], y: &mut [f64]) {
        let w = self.wilson;
        let tau = w.tau();
        let (a0, a1, a2) = (
            w.mass_coefficient(),
            w.velocity_coefficient(),
            w.damping_coefficient(),
        );
        for i in 0..u_hat.len() {
            let du = u_hat[i] - self.u[i];
            let acc = a0 * du - a1 * self.v[i] - 2.0 * self.a[i];
            vel[i] = a2 * du - 2.0 * self.v[i] - 0.5 * tau * self.a[i];
            y[i] = acc + self.alpha * vel[i];
        }
    }

    /// Books a finished Newton iteration (`iterations` solves, last error estimate `error`)
    /// and advances U, U̇, Ü from the converged Û by Wilson-θ.
    fn finish_step(&mut self, u_hat: &[f64], iterations: usize, error: f64) {
        self.stats.steps += 1;
        self.stats.solves += iterations;
        if error > self.options.tolerance {
            self.stats.unconverged += 1;
        }
        self.stats.worst_increment = self.stats.worst_increment.max(error);
        advance_all(&self.wilson, &mut self.u, &mut self.v, &mut self.a, u_hat);
        self.time += self.wilson.dt;
    }

    /// One Wilson-θ step by [`ModifiedNewton`]: the residual r(Û) of [`CorotationalSimulator`]
    /// with β K_t U̇_θ evaluated element by element, J_t refactored only when needed.
    fn step_modified(&mut self, f: &[f64], m: ModifiedNewton) -> Result<(), SteppingError> {
        let n = self.pattern.n;
        let w = self.wilson;
        let (a0, a2) = (w.mass_coefficient(), w.damping_coefficient());
        let (alpha, beta) = (self.alpha, self.beta);
        let mut u_hat = self.u.clone();
        if m.predictor {
            let tau = w.tau();
            for ((x, v), a) in u_hat.iter_mut().zip(&self.v).zip(&self.a) {
                *x += tau * v + 0.5 * tau * tau * a;
            }
        }
        let mut vel = vec![0.0; n];
        let mut r = vec![0.0; n];
        let mut y = vec![0.0; n];
        let mut my = vec![0.0; n];
        let limit = self.options.max_newton.max(4 * m.iterations);
        let mut estimate = f64::INFINITY;
        let mut previous = f64::INFINITY;
        let mut since_factor = 0;
        let mut iterations = 0;
        let mut refactor = self.kept.is_none();
        while iterations < limit {
            self.theta_rates(&u_hat, &mut vel, &mut y);
            if refactor {
                // Tangents at Û, the new J_t; the damping force from the assembled K_t.
                self.assemble(&u_hat);
                if beta != 0.0 {
                    self.pattern
                        .mul(&self.warped, &vel, &mut self.damping_force);
                }
                self.kept = None;
                let factor = self.factor_newton(
                    1.0,
                    a2 * beta,
                    a0 + a2 * alpha,
                    "co-rotational Wilson-θ matrix J_t",
                )?;
                self.kept = Some(factor);
                since_factor = 0;
                previous = f64::INFINITY;
                refactor = false;
            } else {
                self.assemble_force(&u_hat, (beta != 0.0).then_some(&vel[..]));
            }
            for i in 0..n {
                r[i] = f[i] - self.internal[i] - beta * self.damping_force[i];
            }
            self.pattern.mul(&self.mass, &y, &mut my);
            r.iter_mut().zip(&my).for_each(|(r, v)| *r -= v);
            let Some(factor) = self.kept.as_ref() else {
                unreachable!("a factorisation is kept before it is used");
            };
            timed_solve(&mut self.stats, factor, &mut r);
            u_hat.iter_mut().zip(&r).for_each(|(x, d)| *x += d);
            iterations += 1;
            since_factor += 1;
            let step = norm(&r);
            if !step.is_finite() {
                return Err(SteppingError::NonFinite {
                    step: self.stats.steps + 1,
                    time: self.time + w.dt,
                });
            }
            if since_factor >= 2 {
                self.contraction = step / previous;
            }
            previous = step;
            // ρ measured in this step on this factorisation: the accepted iterate is within
            // ρ/(1−ρ)‖δ‖ of the root. Otherwise (first iteration on a factorisation, ρ carried
            // from before) the increment itself must meet the tolerance (η ≥ 1).
            let rho = self.contraction;
            let eta = if rho >= 1.0 {
                f64::INFINITY
            } else if since_factor >= 2 {
                rho / (1.0 - rho)
            } else {
                (rho / (1.0 - rho)).max(1.0)
            };
            estimate = if step <= self.floor {
                0.0
            } else {
                eta * step / norm(&u_hat)
            };
            if estimate <= self.options.tolerance {
                break;
            }
            if (since_factor >= 2 && self.contraction > m.contraction)
                || since_factor >= m.iterations
            {
                refactor = true;
            }
        }
        self.finish_step(&u_hat, iterations, estimate);
        Ok(())
    }
}

impl Simulator for CorotationalSimulator {
    fn step(&mut self, f: &[f64]) -> Result<(), SteppingError> {
        let n = self.pattern.n;
        check_len("load vector f", n, f.len())?;
        if let Some(m) = self.modified {
            return self.step_modified(f, m);
        }
        let w = self.wilson;
        let (a0, a2) = (w.mass_coefficient(), w.damping_coefficient());
        let (alpha, beta) = (self.alpha, self.beta);
        let mut u_hat = self.u.clone();
        let mut vel = vec![0.0; n];
        let mut r = vec![0.0; n];
        let mut y = vec![0.0; n];
        let mut my = vec![0.0; n];
        let mut relative = f64::INFINITY;
        let mut iterations = 0;
        while iterations < self.options.max_newton {
            self.assemble(&u_hat);
            self.theta_rates(&u_hat, &mut vel, &mut y);
            // r = f − f_int − M (Ü_θ + α U̇_θ) − β K_t U̇_θ
            self.assembled_residual(&vel, &y, f, &mut r, &mut my);
            let factor = self.factor_newton(
                1.0,
                a2 * beta,
                a0 + a2 * alpha,
                "co-rotational Wilson-θ matrix J_t",
            )?;
            timed_solve(&mut self.stats, &factor, &mut r);
            u_hat.iter_mut().zip(&r).for_each(|(x, d)| *x += d);
            iterations += 1;
            let step = norm(&r);
            relative = if step <= self.floor {
                0.0
            } else {
                step / norm(&u_hat)
            };
            if relative <= self.options.tolerance {
                break;
            }
        }
        self.finish_step(&u_hat, iterations, relative);
        Ok(())
    }

    fn displacement(&self) -> &[f64] {
        &self.u
    }

    fn velocity(&self) -> &[f64] {
        &self.v
    }

    fn acceleration(&self) -> &[f64] {
        &self.a
    }

    fn time(&self) -> f64 {
        self.time
    }
    fn consistent_acceleration(&mut self, f: &[f64]) -> Result<(), SteppingError> {
        CorotationalSimulator::consistent_acceleration(self, f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::operators::Operators;
    use crate::mesh::procedural::{box_mesh, BeamScene};
    use crate::scene::Scene;

    /// Modified Newton (the training runs' path) against full Newton (the reference) on a
    /// 6×1×1 beam swung by a tip load ramped to a large rotation: the same trajectory to within
    /// what the Newton tolerance allows, with fewer factorisations than steps. Each accepted
    /// state is within the tolerance of its root (estimated); the swing carries each step's
    /// error into the velocity and acceleration, so the trajectories part by about 10³ × the
    /// tolerance over the 120 steps, and the gap shrinks with the tolerance.
    #[test]
    fn modified_newton_follows_full_newton_with_fewer_factorisations() {
        let dt = 5e-3;
        let text = BeamScene {
            mesh_file: "generated.msh".into(),
            displays: Vec::new(),
            dt,
            ..BeamScene::default()
        }
        .toml();
        let scene = Scene::parse(&text, std::path::Path::new("test.toml")).expect("scene");
        let mesh = box_mesh([6, 1, 1], [1.0, 0.1, 0.1]);
        let fem = FemModel::assemble(&mesh, &scene, 1.0).expect("assembles");
        let ops = Operators::build(&mesh, &scene, &fem, 1.0).expect("operators");
        let column = &ops.inputs[2].column;
        let wilson = WilsonTheta::from(&scene.time);
        let options = NewtonOptions::default();
        // Worst relative gap over the run, and the two simulators' counters, for the modified
        // Newton at `tolerance` (full Newton at the default 1e-8).
        let run = |tolerance: f64| {
            let mut full = CorotationalSimulator::new(&fem, wilson, options).expect("simulator");
            let mut modified = CorotationalSimulator::new(
                &fem,
                wilson,
                NewtonOptions {
                    tolerance,
                    ..options
                },
            )
            .expect("simulator");
            modified
                .set_modified_newton(Some(ModifiedNewton::default()))
                .expect("settings");
            let (mut worst, mut largest) = (0.0f64, 0.0f64);
            for k in 1..=120 {
                // −z tip force ramped to 60 N over 60 steps, then held.
                let m = -60.0 * (k as f64 / 60.0).min(1.0);
                let f: Vec<f64> = column.iter().map(|b| m * b).collect();
                full.step(&f).expect("full Newton step");
                modified.step(&f).expect("modified Newton step");
                let (a, b) = (full.displacement(), modified.displacement());
                let diff = norm(&a.iter().zip(b).map(|(x, y)| x - y).collect::<Vec<_>>());
                worst = worst.max(diff / norm(a));
                largest = largest.max(a.iter().fold(0.0f64, |m, v| m.max(v.abs())));
            }
            assert!(
                largest > 0.3,
                "a large deflection expected, got {largest} m"
            );
            (worst, full.stats(), modified.stats())
        };
        let (worst, sf, sm) = run(1e-8);
        let (tighter, _, _) = run(1e-10);
        println!("modified vs full Newton: {worst:.2e} at 1e-8, {tighter:.2e} at 1e-10");
        assert!(worst < 1e-4, "modified vs full Newton: {worst:.2e}");
        assert!(tighter < 1e-6 && tighter < 0.1 * worst, "{tighter:.2e}");
        assert_eq!(sm.unconverged, 0, "{sm:?}");
        assert_eq!(sf.factorisations, sf.solves, "{sf:?}");
        assert!(
            sm.factorisations * 4 < sf.factorisations,
            "full {sf:?}, modified {sm:?}"
        );
        assert!(set_check(&fem, wilson).is_err());
    }

    fn set_check(fem: &FemModel, wilson: WilsonTheta) -> Result<(), SteppingError> {
        let mut sim = CorotationalSimulator::new(fem, wilson, NewtonOptions::default())?;
        sim.set_modified_newton(Some(ModifiedNewton {
            contraction: 1.5,
            iterations: 4,
            predictor: true,
        }))
    }
}
