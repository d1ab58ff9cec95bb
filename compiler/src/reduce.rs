//! Model reduction (docs/design.md §4): modes with static correction, the modal Wilson-θ system and
//! square-root balanced truncation.
//!
//! ```text
//! (K, M, B, Cout) ──modal_basis──▶ V (n×k): Vᵀ M V = I, Vᵀ K V = diag(ω²)
//!                 ──ModalSystem::new──▶ k blocks (Φᵢ, Γᵢ), bᵢ = (VᵀB)ᵢ, cᵢ = (Cout V)_{:,i}
//!                 ──balanced_truncation──▶ (F, G, H) of order r, Hankel singular values σ
//! ```
//!
//! * [`modal_basis`]: lowest eigenpairs of K φ = ω² M φ by a block shift-invert Krylov–Schur
//!   (thick-restart block Lanczos) in the M-inner product over a sparse Cholesky factor of K,
//!   plus static-correction vectors K⁻¹B, Rayleigh–Ritz on the union. Small models take a dense
//!   path. Rigid-body modes are refused.
//! * [`ModalSystem`]: the block-diagonal discrete system s_{t+1} = Φ s_t + Γ u_t, y_t = C s_t with
//!   sᵢ = [qᵢ, q̇ᵢ, q̈ᵢ].
//! * [`ModalSystem::balanced_truncation`]: Gramians from the 3×3 block Stein equations
//!   (exact, no iteration), square-root balanced truncation, bound ‖G − G_r‖∞ ≤ 2 Σ_{i>r} σᵢ.

// `!(x > 0.0)` deliberately rejects NaN as well; index loops mirror the equations.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod balance;
mod modes;

pub use balance::{BalanceTimings, ModalSystem, ModalSystemTimings, Order, ReducedSystem};
pub use modes::{modal_basis, ModalBasis, ModalOptions, ModalTimings};

/// Errors of the reduction stage. Messages name the DOF, mode or frequency involved.
#[derive(Debug, thiserror::Error)]
pub enum ReduceError {
    /// K is singular: the structure can move without deforming.
    #[error(
        "the model has {count} rigid-body modes (no or too few fixed nodes); fix a group in the scene \
         (lowest ω² = {lowest_omega2:.3e} rad²/s², reference scale {scale:.3e} rad²/s²)"
    )]
    RigidBody {
        /// Number of (near-)zero eigenvalues found (a lower bound when `at_least`).
        count: usize,
        /// Lowest eigenvalue ω² found, rad²/s².
        lowest_omega2: f64,
        /// Reference stiffness/mass scale max Kᵢᵢ/Mᵢᵢ, rad²/s².
        scale: f64,
    },
    /// K has a clearly negative eigenvalue (not an elastic stiffness).
    #[error("the stiffness matrix is not positive semi-definite: eigenvalue ω² = {omega2:.3e} rad²/s² (scale {scale:.3e})")]
    IndefiniteStiffness {
        /// The negative eigenvalue, rad²/s².
        omega2: f64,
        /// Reference scale max Kᵢᵢ/Mᵢᵢ, rad²/s².
        scale: f64,
    },
    /// A mass diagonal entry is not positive (M must be positive definite).
    #[error("mass matrix: diagonal entry of DOF {dof} is {value:e}; M must be positive definite")]
    MassNotPositive {
        /// The DOF (after Dirichlet elimination).
        dof: usize,
        /// The offending value, kg.
        value: f64,
    },
    /// The mass matrix is not positive definite (dense Cholesky failed).
    #[error("mass matrix is not positive definite (Cholesky failed)")]
    MassNotDefinite,
    /// A matrix has a wrong shape.
    #[error("{what}: expected {expected}, got {got}")]
    Dimension {
        /// Which argument.
        what: &'static str,
        /// Expected shape.
        expected: String,
        /// Actual shape.
        got: String,
    },
    /// A NaN or infinity in the named input.
    #[error("non-finite value in {what} at ({row}, {col})")]
    NonFinite {
        /// Which argument.
        what: &'static str,
        /// Row index.
        row: usize,
        /// Column index.
        col: usize,
    },
    /// An option is out of range or options conflict.
    #[error("invalid reduction option: {0}")]
    InvalidOption(String),
    /// The sparse Cholesky factorisation failed for a reason other than rigid-body modes.
    #[error("sparse Cholesky factorisation of {what} failed: {detail}")]
    Factorisation {
        /// Which matrix.
        what: &'static str,
        /// The solver's message.
        detail: String,
    },
    /// A dense decomposition did not converge.
    #[error("dense {what} did not converge")]
    Dense {
        /// Which decomposition.
        what: &'static str,
    },
    /// The eigensolver converged no mode within its restart budget.
    #[error("eigensolver converged no mode within {restarts} restarts ({solves} solves)")]
    NotConverged {
        /// Restarts used.
        restarts: usize,
        /// Factor solves (right-hand sides) used.
        solves: usize,
    },
    /// A modal Wilson-θ block is (numerically) marginally stable: the Gramians do not exist.
    #[error(
        "mode {mode} ({frequency_hz:.6} Hz): Wilson-θ block spectral radius {spectral_radius:.15} ≥ 1 − 1e-12, \
         the Gramians do not exist; add Rayleigh damping (α, β) or increase Δt/θ"
    )]
    MarginallyStable {
        /// Index of the mode in the basis.
        mode: usize,
        /// Its frequency, Hz.
        frequency_hz: f64,
        /// ρ(Φᵢ).
        spectral_radius: f64,
    },
    /// Inputs or outputs see nothing: every Hankel singular value is zero.
    #[error(
        "the inputs and outputs of the scene see no mode (all Hankel singular values are zero)"
    )]
    NothingObservable,
}

impl From<crate::algorithms::krylov::DenseFailure> for ReduceError {
    fn from(failure: crate::algorithms::krylov::DenseFailure) -> Self {
        ReduceError::Dense { what: failure.what }
    }
}
