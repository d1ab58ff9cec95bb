//! Full-order linear references: the static solution K u = f and Wilson-θ time stepping with
//! J = K + a₀M + a₂C factored once (a₀ = 6/τ², a₂ = 3/τ, τ = θΔt; docs/design.md §2).

use crate::dynamics::WilsonTheta;
use crate::fem::FemModel;

use faer::Par;

use super::sparse::{Factor, Pattern};
use super::{advance_all, check_len, map_state, Simulator, SteppingError};

/// The static displacement u (n, m) of K u = f (f: n, N) by sparse Cholesky of K.
///
/// Fails with [`SteppingError::NotPositiveDefinite`] when K is singular (no Dirichlet nodes:
/// rigid-body modes).
pub fn static_solve(fem: &FemModel, f: &[f64]) -> Result<Vec<f64>, SteppingError> {
    check_len("load vector f", fem.dof_count(), f.len())?;
    let mut u = f.to_vec();
    StaticSolver::new(fem)?.solve_in_place(&mut u);
    Ok(u)
}

/// K factored once, for many static solves K u = f (a quasi-static contact reference).
pub struct StaticSolver {
    factor: Factor,
    n: usize,
}

impl StaticSolver {
    /// Sparse Cholesky of K; fails as [`static_solve`] does.
    pub fn new(fem: &FemModel) -> Result<Self, SteppingError> {
        Ok(StaticSolver {
            factor: Factor::of(&fem.stiffness, "stiffness K (static solve)")?,
            n: fem.dof_count(),
        })
    }

    /// b ← K⁻¹ b (b: n, N in, m out).
    pub fn solve_in_place(&self, b: &mut [f64]) {
        debug_assert_eq!(b.len(), self.n);
        self.factor.solve_in_place(b);
    }
}

/// Full-order linear Wilson-θ: M Ü + C U̇ + K U = f on the free DOFs, C = αM + βK, state
/// (U, U̇, Ü) starting at rest; J = K + a₀M + a₂C is factored once.
///
/// Each [`step`](Simulator::step) holds f (n, N) constant over [t, t + Δt] and solves
/// `J Û = f + M(a₀U + 6/τ U̇ + 2Ü) + C(a₂U + 2U̇ + τ/2 Ü)`, then advances with
/// [`WilsonTheta::advance`].
///
/// [`LinearSimulator::batch`] runs k independent load histories on the one factor of J: f and
/// the state are then n × k, column-major, and each step works on the k columns side by side,
/// one thread per core, each solving on its own thread with the shared factor.
pub struct LinearSimulator {
    system: WilsonSystem,
    u: Vec<f64>,
    v: Vec<f64>,
    a: Vec<f64>,
    time: f64,
    /// M's factor, made on the first [`LinearSimulator::consistent_acceleration`].
    mass_factor: Option<Factor>,
    /// k, the number of histories stepped together.
    columns: usize,
    /// Threads a step of k > 1 columns uses (≤ k, ≤ the cores).
    threads: usize,
    work: [Vec<f64>; 3],
}

/// What every column of a [`LinearSimulator`] shares: the matrices on one pattern and J's factor.
struct WilsonSystem {
    wilson: WilsonTheta,
    alpha: f64,
    beta: f64,
    pattern: Pattern,
    stiffness: Vec<f64>,
    mass: Vec<f64>,
    jacobian: Factor,
}

impl WilsonSystem {
    /// Û of one column, left in `rhs`: rhs = f + M(a₀U + 6/τ U̇ + 2Ü) + C(a₂U + 2U̇ + τ/2 Ü),
    /// then J⁻¹ rhs (`par`: see [`Factor::solve_in_place_with`]).
    fn solve_column(
        &self,
        (u, v, a): (&[f64], &[f64], &[f64]),
        f: &[f64],
        rhs: &mut [f64],
        x: &mut [f64],
        y: &mut [f64],
        par: Option<Par>,
    ) {
        let w = self.wilson;
        // rhs = f + M·(a₀U + 6/τ U̇ + 2Ü)
        map_state(u, v, a, x, |u, v, a| w.mass_rhs(u, v, a));
        self.pattern.mul(&self.mass, x, rhs);
        rhs.iter_mut().zip(f).for_each(|(r, f)| *r += f);
        // + C·(a₂U + 2U̇ + τ/2 Ü), C = αM + βK
        if self.alpha != 0.0 || self.beta != 0.0 {
            map_state(u, v, a, x, |u, v, a| w.damping_rhs(u, v, a));
            if self.alpha != 0.0 {
                self.pattern.mul(&self.mass, x, y);
                rhs.iter_mut()
                    .zip(y.iter())
                    .for_each(|(r, v)| *r += self.alpha * v);
            }
            if self.beta != 0.0 {
                self.pattern.mul(&self.stiffness, x, y);
                rhs.iter_mut()
                    .zip(y.iter())
                    .for_each(|(r, v)| *r += self.beta * v);
            }
        }
        self.jacobian.solve_in_place_with(rhs, par);
    }
}

impl LinearSimulator {
    /// Factors J for the model and time step; the state starts at rest (U = U̇ = Ü = 0).
    pub fn new(fem: &FemModel, wilson: WilsonTheta) -> Result<Self, SteppingError> {
        Self::batch(fem, wilson, 1)
    }

    /// The simulator of `columns` ≥ 1 independent histories sharing one factor of J: every
    /// vector (f, U, U̇, Ü) is n × `columns`, column-major. Column j steps as a one-column
    /// simulator would.
    pub fn batch(
        fem: &FemModel,
        wilson: WilsonTheta,
        columns: usize,
    ) -> Result<Self, SteppingError> {
        if columns == 0 {
            return Err(SteppingError::Solver(
                "a batch of linear simulations needs at least one column".into(),
            ));
        }
        let pattern = Pattern::new(fem)?;
        let stiffness = pattern.scatter(&fem.stiffness);
        let mass = pattern.scatter(&fem.mass);
        let a0 = wilson.mass_coefficient();
        let a2 = wilson.damping_coefficient();
        let (alpha, beta) = (fem.alpha, fem.beta);
        let j: Vec<f64> = stiffness
            .iter()
            .zip(&mass)
            .map(|(k, m)| k * (1.0 + a2 * beta) + m * (a0 + a2 * alpha))
            .collect();
        let jacobian = pattern.factor(&j, "Wilson-θ matrix J = K + a₀M + a₂C")?;
        let n = pattern.n * columns;
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        Ok(LinearSimulator {
            system: WilsonSystem {
                wilson,
                alpha,
                beta,
                pattern,
                stiffness,
                mass,
                jacobian,
            },
            u: vec![0.0; n],
            v: vec![0.0; n],
            a: vec![0.0; n],
            time: 0.0,
            mass_factor: None,
            columns,
            threads: columns.min(cores),
            work: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        })
    }
}

impl LinearSimulator {
    /// The displacement at the θ-point t + θΔt of a step with load f (n, N) held over it,
    /// Û = J⁻¹ (f + M(…) + C(…)), into `out` (n), the state unchanged (one column only): where
    /// a contact solve enforces its gap before it commits (docs/contact.md).
    pub fn theta_displacement(&mut self, f: &[f64], out: &mut [f64]) -> Result<(), SteppingError> {
        let n = self.system.pattern.n;
        if self.columns != 1 {
            return Err(SteppingError::Solver(
                "theta_displacement works on a one-column simulator".into(),
            ));
        }
        check_len("load vector f", n, f.len())?;
        check_len("displacement out", n, out.len())?;
        let [rhs, x, y] = &mut self.work;
        self.system
            .solve_column((&self.u, &self.v, &self.a), f, rhs, x, y, None);
        out.copy_from_slice(rhs);
        Ok(())
    }

    /// b ← J⁻¹ b: the θ-point displacement per unit load b held over the step.
    pub fn theta_compliance(&self, b: &mut [f64]) {
        self.system.jacobian.solve_in_place(b);
    }

    /// Ü ← M⁻¹ (f − K U − C U̇) in every column (f: n × columns): the acceleration the
    /// equation of motion gives under a load f that starts now. Wilson-θ assumes the
    /// acceleration linear over a step, so a load that jumps at a step's start costs it first
    /// order in Δt; restarting the acceleration where the load changes keeps it second order
    /// (the converged reference of [`crate::accuracy`] sub-steps this way).
    pub fn consistent_acceleration(&mut self, f: &[f64]) -> Result<(), SteppingError> {
        let n = self.system.pattern.n;
        check_len("load vector f", n * self.columns, f.len())?;
        if self.mass_factor.is_none() {
            let factor = self
                .system
                .pattern
                .factor(&self.system.mass, "mass matrix M")?;
            self.mass_factor = Some(factor);
        }
        let system = &self.system;
        let [rhs, x, y] = &mut self.work;
        let (rhs, x, y) = (&mut rhs[..n], &mut x[..n], &mut y[..n]);
        for (((a, u), v), f) in self
            .a
            .chunks_exact_mut(n)
            .zip(self.u.chunks_exact(n))
            .zip(self.v.chunks_exact(n))
            .zip(f.chunks_exact(n))
        {
            // K U + C U̇ = K (U + β U̇) + α M U̇.
            x.iter_mut()
                .zip(u.iter().zip(v))
                .for_each(|(x, (u, v))| *x = u + system.beta * v);
            system.pattern.mul(&system.stiffness, x, rhs);
            if system.alpha != 0.0 {
                system.pattern.mul(&system.mass, v, y);
                rhs.iter_mut()
                    .zip(y.iter())
                    .for_each(|(r, y)| *r += system.alpha * y);
            }
            a.iter_mut()
                .zip(f)
                .zip(rhs.iter())
                .for_each(|((a, f), r)| *a = f - r);
            if let Some(m) = &self.mass_factor {
                m.solve_in_place(a);
            }
        }
        Ok(())
    }
}

impl Simulator for LinearSimulator {
    fn step(&mut self, f: &[f64]) -> Result<(), SteppingError> {
        let n = self.system.pattern.n;
        check_len("load vector f", n * self.columns, f.len())?;
        let system = &self.system;
        let [rhs, x, y] = &mut self.work;
        let columns = self
            .u
            .chunks_exact(n)
            .zip(self.v.chunks_exact(n))
            .zip(self.a.chunks_exact(n))
            .zip(f.chunks_exact(n))
            .zip(rhs.chunks_exact_mut(n))
            .zip(x.chunks_exact_mut(n))
            .zip(y.chunks_exact_mut(n));
        // A batch solves every column on one thread, however many the machine has: its
        // results do not depend on the core count.
        let par = (self.columns > 1).then_some(Par::Seq);
        if self.threads <= 1 {
            for ((((((u, v), a), f), rhs), x), y) in columns {
                system.solve_column((u, v, a), f, rhs, x, y, par);
            }
        } else {
            // Columns dealt round-robin to the threads.
            let mut shares: Vec<Vec<_>> = (0..self.threads).map(|_| Vec::new()).collect();
            for (c, column) in columns.enumerate() {
                shares[c % self.threads].push(column);
            }
            std::thread::scope(|scope| {
                for share in shares {
                    scope.spawn(move || {
                        for ((((((u, v), a), f), rhs), x), y) in share {
                            system.solve_column((u, v, a), f, rhs, x, y, par);
                        }
                    });
                }
            });
        }
        let w = system.wilson;
        advance_all(&w, &mut self.u, &mut self.v, &mut self.a, rhs);
        self.time += w.dt;
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
        LinearSimulator::consistent_acceleration(self, f)
    }
}
