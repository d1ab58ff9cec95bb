//! Modal basis with static correction (docs/design.md §4.1).
//!
//! Lowest eigenpairs of K φ = ω² M φ, plus static-correction vectors K⁻¹B for every input
//! channel, M-orthogonalised against the modes and rank revealed; Rayleigh–Ritz on the union
//! gives V (n×k) with Vᵀ M V = I and Vᵀ K V = diag(ω²).

use super::ReduceError;
use crate::algorithms::krylov::{block_krylov_schur, m_orthonormalize, mass_mul, KrylovOptions};
use faer::linalg::matmul::matmul;
use faer::linalg::solvers::Solve;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, SparseColMatRef, Triplet};
use faer::{Accum, Mat, MatRef, Par, Side};
use std::cell::Cell;
use std::f64::consts::PI;
use std::time::{Duration, Instant};

use crate::progress::Progress;

/// An eigenvalue ω² ≤ `RIGID_RATIO` × (stiffness/mass scale) is a rigid-body mode.
const RIGID_RATIO: f64 = 1e-12;
/// Static-correction directions whose M-norm after orthogonalisation against the modes is below
/// this fraction of the (M-normalised) static vector are dependent and dropped.
const STATIC_RANK_TOL: f64 = 1e-8;

/// Options of [`modal_basis`]. At least one of `modes` and `max_frequency_hz` must be set; with
/// both, the modes kept are the lowest `modes` that are also ≤ `max_frequency_hz`.
#[derive(Clone, Debug)]
pub struct ModalOptions {
    /// Number of eigenmodes wanted.
    pub modes: Option<usize>,
    /// Keep every eigenmode up to this frequency, Hz (e.g. a multiple of 1/(2Δt)).
    pub max_frequency_hz: Option<f64>,
    /// Hard cap on the number of eigenmodes.
    pub max_modes: usize,
    /// Restart budget of the eigensolver.
    pub max_restarts: usize,
    /// Relative residual ‖A x − θ x‖_M / θ at which an eigenpair counts as converged.
    pub tolerance: f64,
    /// Block size of the Krylov eigensolver (≥ the largest eigenvalue multiplicity expected).
    pub block_size: usize,
    /// Models with at most this many DOFs use the dense generalized eigensolver.
    pub dense_threshold: usize,
    /// Add the static-correction vectors K⁻¹B.
    pub static_correction: bool,
}

impl Default for ModalOptions {
    fn default() -> Self {
        Self {
            modes: None,
            max_frequency_hz: None,
            max_modes: 400,
            max_restarts: 60,
            tolerance: 1e-10,
            block_size: 6,
            dense_threshold: 600,
            static_correction: true,
        }
    }
}

/// Wall-clock seconds of each stage of [`modal_basis`].
#[derive(Clone, Debug, Default)]
pub struct ModalTimings {
    /// Sparse Cholesky of K (symbolic + numeric).
    pub factorisation: f64,
    /// Eigensolver (Krylov or dense).
    pub eigensolve: f64,
    /// K⁻¹B and its M-orthogonalisation.
    pub static_correction: f64,
    /// Rayleigh–Ritz on the union and residuals.
    pub rayleigh_ritz: f64,
    /// Whole call.
    pub total: f64,
}

/// The reduction basis V (n×k): Vᵀ M V = I, Vᵀ K V = diag(ω²), columns by ascending ω².
#[derive(Clone, Debug)]
pub struct ModalBasis {
    /// V, n×k, M-orthonormal, K-orthogonal.
    pub vectors: Mat<f64>,
    /// ω² of each column, rad²/s² (ascending).
    pub omega2: Vec<f64>,
    /// ω/(2π) of each column, Hz.
    pub frequencies_hz: Vec<f64>,
    /// Whether column j is a static-correction (pseudo-)mode rather than an eigenmode.
    pub static_correction: Vec<bool>,
    /// Number of eigenmodes (columns not flagged static).
    pub n_eigenmodes: usize,
    /// K⁻¹B, n × m, every input column solved with the stage's factor of K before the static
    /// correction orthogonalises it (n × 0 without static correction): the full-order static
    /// response, reused by whoever needs it instead of factoring K again.
    pub static_response: Mat<f64>,
    /// Relative residual ‖K v − ω² M v‖₂ / (ω² ‖M v‖₂) of each column (not small for the
    /// static-correction columns: they are not eigenvectors).
    pub residuals: Vec<f64>,
    /// False when the eigensolver's restart budget ran out before the requested modes converged.
    pub complete: bool,
    /// True when the dense eigensolver was used.
    pub dense: bool,
    /// Eigensolver restarts used.
    pub restarts: usize,
    /// Right-hand sides solved with the Cholesky factor by the eigensolver.
    pub solves: usize,
    /// Human-readable notes (incomplete convergence, dropped static vectors, …).
    pub warnings: Vec<String>,
    /// Stage timings, s.
    pub timings: ModalTimings,
}

impl ModalBasis {
    /// Number of basis vectors k.
    pub fn len(&self) -> usize {
        self.omega2.len()
    }

    /// Whether the basis is empty.
    pub fn is_empty(&self) -> bool {
        self.omega2.is_empty()
    }
}

fn dimension(what: &'static str, expected: (usize, usize), got: (usize, usize)) -> ReduceError {
    ReduceError::Dimension {
        what,
        expected: format!("{}×{}", expected.0, expected.1),
        got: format!("{}×{}", got.0, got.1),
    }
}

fn check_sparse(
    what: &'static str,
    a: SparseColMatRef<'_, usize, f64>,
    n: usize,
) -> Result<Vec<f64>, ReduceError> {
    if a.nrows() != n || a.ncols() != n {
        return Err(dimension(what, (n, n), (a.nrows(), a.ncols())));
    }
    let mut diag = vec![0.0; n];
    let (row_idx, val) = (a.row_idx(), a.val());
    for j in 0..n {
        for p in a.col_range(j) {
            let (i, v) = (row_idx[p], val[p]);
            if !v.is_finite() {
                return Err(ReduceError::NonFinite {
                    what,
                    row: i,
                    col: j,
                });
            }
            if i == j {
                diag[j] += v;
            }
        }
    }
    Ok(diag)
}

fn factor(
    a: SparseColMatRef<'_, usize, f64>,
) -> Result<Llt<usize, f64>, faer::sparse::linalg::LltError> {
    let symbolic = SymbolicLlt::try_new(a.symbolic(), Side::Lower)?;
    Llt::try_new_with_symbolic(symbolic, a, Side::Lower)
}

/// Dense (K, M): M = L Lᵀ, L⁻¹ K L⁻ᵀ = Y Λ Yᵀ, X = L⁻ᵀ Y. Eigenvalues ascending.
fn dense_generalized(
    stiffness: SparseColMatRef<'_, usize, f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    par: Par,
) -> Result<(Vec<f64>, Mat<f64>), ReduceError> {
    let n = stiffness.nrows();
    let kd = stiffness.to_dense();
    let md = mass.to_dense();
    let md = Mat::from_fn(n, n, |i, j| 0.5 * (md[(i, j)] + md[(j, i)]));
    let llt = md
        .llt(Side::Lower)
        .map_err(|_| ReduceError::MassNotDefinite)?;
    let l = llt.L();
    let mut c = Mat::from_fn(n, n, |i, j| 0.5 * (kd[(i, j)] + kd[(j, i)]));
    solve_lower_triangular_in_place(l, c.as_mut(), par); // L⁻¹ K
    let mut c = c.transpose().to_owned();
    solve_lower_triangular_in_place(l, c.as_mut(), par); // L⁻¹ (L⁻¹ K)ᵀ = L⁻¹ K L⁻ᵀ
    let c = Mat::from_fn(n, n, |i, j| 0.5 * (c[(i, j)] + c[(j, i)]));
    let evd = c
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| ReduceError::Dense {
            what: "generalized eigen-decomposition of (K, M)",
        })?;
    let lambda: Vec<f64> = evd.S().column_vector().iter().copied().collect();
    let mut x = evd.U().to_owned();
    solve_upper_triangular_in_place(l.transpose(), x.as_mut(), par);
    Ok((lambda, x))
}

/// Rigid-body analysis after the Cholesky factorisation of K failed: factor K + sM (s > 0),
/// compute the lowest eigenpairs and count the (near-)zero ones.
fn rigid_body_error(
    stiffness: SparseColMatRef<'_, usize, f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    scale: f64,
    options: &ModalOptions,
    detail: String,
    par: Par,
) -> ReduceError {
    let n = stiffness.nrows();
    let shift = 1e-6 * scale;
    let mut triplets = Vec::with_capacity(stiffness.compute_nnz() + mass.compute_nnz());
    for (a, f) in [(stiffness, 1.0), (mass, shift)] {
        for j in 0..n {
            for p in a.col_range(j) {
                triplets.push(Triplet::new(a.row_idx()[p], j, f * a.val()[p]));
            }
        }
    }
    let shifted = match SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &triplets) {
        Ok(s) => s,
        Err(e) => {
            return ReduceError::Factorisation {
                what: "K + sM",
                detail: format!("{e:?}"),
            }
        }
    };
    let llt = match factor(shifted.as_ref()) {
        Ok(l) => l,
        Err(_) => {
            return ReduceError::IndefiniteStiffness {
                omega2: -shift,
                scale,
            };
        }
    };
    let wanted = 12.min(n);
    let outcome = block_krylov_schur(
        mass,
        &mut |x| llt.solve_in_place(x),
        &mut |_| wanted,
        &KrylovOptions {
            block: options.block_size.max(6),
            tolerance: 1e-8,
            max_restarts: options.max_restarts,
        },
        par,
    );
    let outcome = match outcome {
        Ok(o) => o,
        Err(e) => return e.into(),
    };
    // Rayleigh quotients xᵀKx / xᵀMx: accurate to ~ε·max Kᵢᵢ/Mᵢᵢ.
    let x = outcome.vectors;
    let mut kx = Mat::zeros(n, x.ncols());
    sparse_dense_matmul(kx.as_mut(), Accum::Replace, stiffness, x.as_ref(), 1.0, par);
    let mx = mass_mul(mass, x.as_ref(), par);
    let lambda: Vec<f64> = (0..x.ncols())
        .map(|j| (x.col(j).transpose() * kx.col(j)) / (x.col(j).transpose() * mx.col(j)))
        .collect();
    let lowest = lambda.iter().copied().fold(f64::INFINITY, f64::min);
    let count = lambda.iter().filter(|&&l| l <= RIGID_RATIO * scale).count();
    if lowest < -1e-8 * scale {
        return ReduceError::IndefiniteStiffness {
            omega2: lowest,
            scale,
        };
    }
    if count == 0 {
        return ReduceError::Factorisation { what: "K", detail };
    }
    ReduceError::RigidBody {
        count,
        lowest_omega2: lowest,
        scale,
    }
}

/// An eigen-solve shorter than this prints no progress line.
const EIGEN_PROGRESS_AFTER: Duration = Duration::from_secs(3);

/// The eigen-solve's progress line on stderr (a terminal only, after
/// [`EIGEN_PROGRESS_AFTER`]): `crokf-compile: eigen-solve, n DOFs[, modes ≤ f Hz]: done/wanted
/// modes done, …`, the estimate linear in converged modes, timed since the wanted count last
/// grew.
fn eigen_progress(n: usize, max_frequency_hz: Option<f64>, wanted: usize) -> Progress {
    Progress::new(
        &eigen_label(&crate::progress::program(), n, max_frequency_hz),
        "modes",
        wanted,
    )
    .after(EIGEN_PROGRESS_AFTER)
}

/// `PROGRAM: eigen-solve, n DOFs[, modes ≤ f Hz]`.
fn eigen_label(program: &str, n: usize, max_frequency_hz: Option<f64>) -> String {
    match max_frequency_hz {
        Some(f) => format!("{program}: eigen-solve, {n} DOFs, modes ≤ {f:.0} Hz"),
        None => format!("{program}: eigen-solve, {n} DOFs"),
    }
}

fn cap_note(limit: usize, below: usize, highest: f64) -> String {
    let more = if below > limit {
        format!("{below}")
    } else {
        "more".to_string()
    };
    format!(
        "the frequency cut-off is not reached: {more} modes lie below it, capped at max_modes = {limit} \
         (highest kept {:.4} Hz)",
        highest.sqrt() / (2.0 * PI)
    )
}

/// The modal basis of (K, M) with static correction for the input channels B (n×m).
///
/// `stiffness` and `mass` are the n×n matrices after Dirichlet elimination with both triangles
/// stored (N/m and kg, or any consistent units). Returns V with Vᵀ M V = I,
/// Vᵀ K V = diag(ω²), the lowest eigenmodes first (by ascending ω²) then the static-correction
/// pseudo-modes. Refuses K with rigid-body modes.
pub fn modal_basis(
    stiffness: SparseColMatRef<'_, usize, f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    inputs: MatRef<'_, f64>,
    options: &ModalOptions,
) -> Result<ModalBasis, ReduceError> {
    let started = Instant::now();
    let par = faer::get_global_parallelism();
    let n = stiffness.nrows();
    let kdiag = check_sparse("stiffness matrix K", stiffness, n)?;
    let mdiag = check_sparse("mass matrix M", mass, n)?;
    if inputs.nrows() != n {
        return Err(dimension(
            "input matrix B",
            (n, inputs.ncols()),
            (inputs.nrows(), inputs.ncols()),
        ));
    }
    for j in 0..inputs.ncols() {
        for i in 0..n {
            if !inputs[(i, j)].is_finite() {
                return Err(ReduceError::NonFinite {
                    what: "input matrix B",
                    row: i,
                    col: j,
                });
            }
        }
    }
    if n == 0 {
        return Err(ReduceError::InvalidOption(
            "the model has no free DOF".into(),
        ));
    }
    match (options.modes, options.max_frequency_hz) {
        (None, None) => {
            return Err(ReduceError::InvalidOption(
                "set the number of modes or a maximum frequency".into(),
            ))
        }
        (Some(0), _) => return Err(ReduceError::InvalidOption("modes = 0".into())),
        (_, Some(f)) if !(f.is_finite() && f > 0.0) => {
            return Err(ReduceError::InvalidOption(format!(
                "max_frequency_hz = {f} must be positive"
            )))
        }
        _ => {}
    }
    if !(options.tolerance > 0.0 && options.tolerance <= 1e-3) {
        return Err(ReduceError::InvalidOption(format!(
            "tolerance = {} must be in (0, 1e-3]",
            options.tolerance
        )));
    }
    if options.max_modes == 0 || options.block_size == 0 {
        return Err(ReduceError::InvalidOption(
            "max_modes and block_size must be ≥ 1".into(),
        ));
    }
    for (i, &m) in mdiag.iter().enumerate() {
        if !(m > 0.0) {
            return Err(ReduceError::MassNotPositive { dof: i, value: m });
        }
    }
    // Stiffness/mass scale, rad²/s²: the order of the highest eigenvalue.
    let scale = kdiag
        .iter()
        .zip(&mdiag)
        .map(|(k, m)| k / m)
        .fold(0.0f64, f64::max);
    if !(scale > 0.0) {
        return Err(ReduceError::RigidBody {
            count: n,
            lowest_omega2: 0.0,
            scale,
        });
    }
    let cap = options.max_modes.min(n);
    let limit = options.modes.unwrap_or(cap).min(cap);
    let lambda_cut = options.max_frequency_hz.map(|f| (2.0 * PI * f).powi(2));
    let mut warnings = Vec::new();
    if let Some(asked) = options.modes.filter(|&m| m > n) {
        warnings.push(format!(
            "modes = {asked} asks for more vibration modes than the mesh has free DOFs ({n}): \
             capped at {limit}{}",
            if limit == n {
                " (every mode: a dense eigensolve of the whole model)"
            } else {
                ""
            }
        ));
    }
    let mut timings = ModalTimings::default();

    let dense = n <= options.dense_threshold || 2 * limit + 4 * options.block_size >= n;
    let (mut restarts, mut solves, mut complete) = (0, 0, true);
    let (llt, lambda, modes) = if dense {
        let t = Instant::now();
        let (lambda_all, x_all) = dense_generalized(stiffness, mass, par)?;
        timings.eigensolve = t.elapsed().as_secs_f64();
        let reference = scale.max(lambda_all[n - 1]);
        if lambda_all[0] < -1e-8 * reference {
            return Err(ReduceError::IndefiniteStiffness {
                omega2: lambda_all[0],
                scale: reference,
            });
        }
        let rigid = lambda_all
            .iter()
            .filter(|&&l| l <= RIGID_RATIO * reference)
            .count();
        if rigid > 0 {
            return Err(ReduceError::RigidBody {
                count: rigid,
                lowest_omega2: lambda_all[0],
                scale: reference,
            });
        }
        let below = lambda_cut.map_or(n, |cut| lambda_all.iter().filter(|&&l| l <= cut).count());
        let keep = limit.min(below).max(1);
        if lambda_cut.is_some() && options.modes.is_none() && below > limit {
            warnings.push(cap_note(limit, below, lambda_all[keep - 1]));
        }
        let t = Instant::now();
        let llt = factor(stiffness).map_err(|e| ReduceError::Factorisation {
            what: "K",
            detail: format!("{e:?}"),
        })?;
        timings.factorisation = t.elapsed().as_secs_f64();
        (
            llt,
            lambda_all[..keep].to_vec(),
            x_all.subcols(0, keep).to_owned(),
        )
    } else {
        let t = Instant::now();
        let llt = match factor(stiffness) {
            Ok(l) => l,
            Err(faer::sparse::linalg::LltError::Numeric(e)) => {
                return Err(rigid_body_error(
                    stiffness,
                    mass,
                    scale,
                    options,
                    format!("{e:?}"),
                    par,
                ));
            }
            Err(e) => {
                return Err(ReduceError::Factorisation {
                    what: "K",
                    detail: format!("{e:?}"),
                })
            }
        };
        timings.factorisation = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut wanted = match lambda_cut {
            Some(_) => limit.min(16),
            None => limit,
        };
        // Converged modes of the wanted count; the count may still grow while it is below
        // `limit` and every converged mode is below the cut-off.
        let converged = Cell::new((0usize, wanted, lambda_cut.is_some() && wanted < limit));
        let mut line = eigen_progress(n, options.max_frequency_hz, wanted);
        let outcome = block_krylov_schur(
            mass,
            &mut |x| {
                llt.solve_in_place(x);
                let (done, total, open) = converged.get();
                line.set_total(total, open, done);
                line.update(done);
            },
            &mut |theta: &[f64]| {
                let mut open = false;
                if let Some(cut) = lambda_cut {
                    // θ = 1/λ: grow the target while every locked mode is below the cut-off.
                    let all_below = theta.iter().all(|&th| 1.0 / th <= cut);
                    if theta.len() >= wanted && all_below && wanted < limit {
                        wanted = (2 * wanted).min(limit);
                    }
                    open = all_below && wanted < limit;
                }
                converged.set((theta.len(), wanted, open));
                wanted
            },
            &KrylovOptions {
                block: options.block_size,
                tolerance: options.tolerance,
                max_restarts: options.max_restarts,
            },
            par,
        )?;
        let (done, total, _) = converged.get();
        line.set_total(total, false, done);
        line.finish_at(done);
        timings.eigensolve = t.elapsed().as_secs_f64();
        restarts = outcome.restarts;
        solves = outcome.solves;
        complete = outcome.complete;
        if outcome.theta.is_empty() {
            return Err(ReduceError::NotConverged { restarts, solves });
        }
        let mut order: Vec<usize> = (0..outcome.theta.len()).collect();
        order.sort_by(|&a, &b| outcome.theta[b].total_cmp(&outcome.theta[a]));
        let mut lambda: Vec<f64> = order.iter().map(|&j| 1.0 / outcome.theta[j]).collect();
        let rigid = lambda.iter().filter(|&&l| l <= RIGID_RATIO * scale).count();
        if rigid > 0 {
            return Err(ReduceError::RigidBody {
                count: rigid,
                lowest_omega2: lambda[0],
                scale,
            });
        }
        let mut keep = lambda.len();
        if let Some(cut) = lambda_cut {
            keep = lambda.iter().filter(|&&l| l <= cut).count().max(1);
        }
        keep = keep.min(limit);
        if let Some(cut) = lambda_cut {
            if options.modes.is_none() && keep == limit && lambda.iter().all(|&l| l <= cut) {
                warnings.push(cap_note(limit, limit + 1, lambda[keep - 1]));
            }
        }
        lambda.truncate(keep);
        let modes = Mat::from_fn(n, keep, |i, j| outcome.vectors[(i, order[j])]);
        if !complete {
            warnings.push(format!(
                "eigensolver stopped after {restarts} restarts ({solves} solves) with {} converged modes; \
                 the highest converged is {:.4} Hz",
                outcome.theta.len(),
                lambda[keep - 1].sqrt() / (2.0 * PI)
            ));
        }
        (llt, lambda, modes)
    };
    let n_modes = modes.ncols();
    let _ = lambda;

    // Static correction K⁻¹B, M-orthogonalised against the modes, rank revealed.
    let t = Instant::now();
    let mut statics = Mat::zeros(n, 0);
    let mut static_response = Mat::zeros(n, 0);
    if options.static_correction && inputs.ncols() > 0 {
        let mut s = inputs.to_owned();
        llt.solve_in_place(s.as_mut());
        static_response = s.clone();
        let ms = mass_mul(mass, s.as_ref(), par);
        let norms: Vec<f64> = (0..s.ncols())
            .map(|j| (s.col(j).transpose() * ms.col(j)).max(0.0).sqrt())
            .collect();
        let cols: Vec<usize> = (0..s.ncols()).filter(|&j| norms[j] > 0.0).collect();
        let unit = Mat::from_fn(n, cols.len(), |i, c| s[(i, cols[c])] / norms[cols[c]]);
        let (q, _, _) = m_orthonormalize(
            unit,
            modes.as_ref(),
            Mat::zeros(n, 0).as_ref(),
            mass,
            STATIC_RANK_TOL,
            par,
        )?;
        if q.ncols() < inputs.ncols() {
            warnings.push(format!(
                "static correction: {} independent directions from {} input channels (the rest lie in \
                 the span of the modes or of other channels)",
                q.ncols(),
                inputs.ncols()
            ));
        }
        statics = q;
    }
    timings.static_correction = t.elapsed().as_secs_f64();

    // Rayleigh–Ritz on Z = [modes, statics]: (Zᵀ K Z) y = ω² (Zᵀ M Z) y.
    let t = Instant::now();
    let k = n_modes + statics.ncols();
    let mut z = Mat::zeros(n, k);
    z.subcols_mut(0, n_modes).copy_from(&modes);
    z.subcols_mut(n_modes, statics.ncols()).copy_from(&statics);
    let mut kz = Mat::zeros(n, k);
    sparse_dense_matmul(kz.as_mut(), Accum::Replace, stiffness, z.as_ref(), 1.0, par);
    let mz = mass_mul(mass, z.as_ref(), par);
    let mut kr = Mat::zeros(k, k);
    matmul(
        kr.as_mut(),
        Accum::Replace,
        z.transpose(),
        kz.as_ref(),
        1.0,
        par,
    );
    let mut mr = Mat::zeros(k, k);
    matmul(
        mr.as_mut(),
        Accum::Replace,
        z.transpose(),
        mz.as_ref(),
        1.0,
        par,
    );
    let mr = Mat::from_fn(k, k, |i, j| 0.5 * (mr[(i, j)] + mr[(j, i)]));
    let llt_r = mr
        .llt(Side::Lower)
        .map_err(|_| ReduceError::MassNotDefinite)?;
    let l = llt_r.L();
    let mut c = Mat::from_fn(k, k, |i, j| 0.5 * (kr[(i, j)] + kr[(j, i)]));
    solve_lower_triangular_in_place(l, c.as_mut(), par);
    let mut c = c.transpose().to_owned();
    solve_lower_triangular_in_place(l, c.as_mut(), par);
    let c = Mat::from_fn(k, k, |i, j| 0.5 * (c[(i, j)] + c[(j, i)]));
    let evd = c
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| ReduceError::Dense {
            what: "Rayleigh–Ritz eigen-decomposition",
        })?;
    let omega2: Vec<f64> = evd.S().column_vector().iter().copied().collect();
    let mut coef = evd.U().to_owned();
    solve_upper_triangular_in_place(l.transpose(), coef.as_mut(), par);
    let mut vectors = Mat::zeros(n, k);
    matmul(
        vectors.as_mut(),
        Accum::Replace,
        z.as_ref(),
        coef.as_ref(),
        1.0,
        par,
    );
    // Weight of each Ritz vector on the eigenmode part (Z is M-orthonormal): > ½ → eigenmode.
    let static_correction: Vec<bool> = (0..k)
        .map(|j| {
            (0..n_modes)
                .map(|i| coef[(i, j)] * coef[(i, j)])
                .sum::<f64>()
                < 0.5
        })
        .collect();
    let mut kv = Mat::zeros(n, k);
    sparse_dense_matmul(
        kv.as_mut(),
        Accum::Replace,
        stiffness,
        vectors.as_ref(),
        1.0,
        par,
    );
    let mv = mass_mul(mass, vectors.as_ref(), par);
    let residuals: Vec<f64> = (0..k)
        .map(|j| {
            let r = kv.col(j) - mv.col(j) * omega2[j];
            r.norm_l2() / (omega2[j].abs() * mv.col(j).norm_l2())
        })
        .collect();
    timings.rayleigh_ritz = t.elapsed().as_secs_f64();
    timings.total = started.elapsed().as_secs_f64();
    let frequencies_hz = omega2
        .iter()
        .map(|&w| w.max(0.0).sqrt() / (2.0 * PI))
        .collect();
    Ok(ModalBasis {
        vectors,
        n_eigenmodes: static_correction.iter().filter(|&&s| !s).count(),
        static_response,
        omega2,
        frequencies_hz,
        static_correction,
        residuals,
        complete,
        dense,
        restarts,
        solves,
        warnings,
        timings,
    })
}
