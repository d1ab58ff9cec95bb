//! Block shift-invert Krylov–Schur (thick-restart block Lanczos) in the M-inner product.
//!
//! Operator A = (K − σM)⁻¹ M, self-adjoint in ⟨x, y⟩_M = xᵀ M y, eigenvalues θ = 1/(λ − σ)
//! for K φ = λ M φ. With an M-orthonormal basis Q (n×d) built by block expansion with full
//! re-orthogonalisation, A Q = Q T + Q₊ R Eᵀ with T = Qᵀ M A Q (d×d, filled from the
//! orthogonalisation coefficients) and Q₊ the next block. Ritz pairs (θ, Q y) of T have
//! residual ‖A x − θ x‖_M = ‖R E ᵀ y‖₂, so convergence costs no extra solve. Converged pairs
//! are locked (deflated); the wanted unconverged Ritz vectors and Q₊ restart the basis
//! (thick restart keeps the Krylov relation exact). The block size b > 1 finds eigenvalues of
//! multiplicity ≤ b (paired bending modes of square sections) that a single-vector Lanczos
//! misses or finds only after many restarts.

use faer::linalg::matmul::matmul;
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::sparse::SparseColMatRef;
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};

/// A dense decomposition inside the iteration did not converge (non-finite input).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DenseFailure {
    /// Which decomposition.
    pub what: &'static str,
}

/// Tuning of [`block_krylov_schur`].
pub(crate) struct KrylovOptions {
    /// Block size b (≥ the largest expected eigenvalue multiplicity).
    pub block: usize,
    /// Relative residual ‖A x − θ x‖_M / θ at which a Ritz pair is locked.
    pub tolerance: f64,
    /// Restart budget.
    pub max_restarts: usize,
}

/// Converged eigenpairs of A, in locking order.
pub(crate) struct KrylovOutcome {
    /// θ = 1/(λ − σ) of each locked pair.
    pub theta: Vec<f64>,
    /// Locked vectors, n × l, M-orthonormal.
    pub vectors: Mat<f64>,
    /// Restarts used.
    pub restarts: usize,
    /// Right-hand sides solved with the factor.
    pub solves: usize,
    /// Whether the target count was reached within the budget.
    pub complete: bool,
}

/// y = M x for sparse M (n×n) and dense x (n×c).
pub(crate) fn mass_mul(
    mass: SparseColMatRef<'_, usize, f64>,
    x: MatRef<'_, f64>,
    par: Par,
) -> Mat<f64> {
    let mut y = Mat::zeros(mass.nrows(), x.ncols());
    sparse_dense_matmul(y.as_mut(), Accum::Replace, mass, x, 1.0, par);
    y
}

/// Deterministic pseudo-random block (SplitMix64), entries uniform in [−½, ½).
pub(crate) fn random_block(n: usize, c: usize, state: &mut u64) -> Mat<f64> {
    Mat::from_fn(n, c, |_, _| {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    })
}

/// w ← w − S (Sᵀ M w) for an M-orthonormal S; returns the coefficients Sᵀ M w.
fn project_out(
    w: &mut Mat<f64>,
    set: MatRef<'_, f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    par: Par,
) -> Mat<f64> {
    let mut h = Mat::zeros(set.ncols(), w.ncols());
    if set.ncols() == 0 || w.ncols() == 0 {
        return h;
    }
    let mw = mass_mul(mass, w.as_ref(), par);
    matmul(
        h.as_mut(),
        Accum::Replace,
        set.transpose(),
        mw.as_ref(),
        1.0,
        par,
    );
    matmul(w.as_mut(), Accum::Add, set, h.as_ref(), -1.0, par);
    h
}

/// M-orthonormalises the columns of w within themselves by an eigen-decomposition of the Gram
/// matrix G = wᵀ M w = U Λ Uᵀ: Q = w U₊ Λ₊^{-1/2}, R = Λ₊^{1/2} U₊ᵀ (so w ≈ Q R), keeping the
/// directions with Λ > `drop_below` (absolute, M-norm²). Also returns the smallest kept Λ.
fn gram_orthonormalize(
    w: &Mat<f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    drop_below: f64,
    par: Par,
) -> Result<(Mat<f64>, Mat<f64>, f64), DenseFailure> {
    let c = w.ncols();
    let mw = mass_mul(mass, w.as_ref(), par);
    let mut g = Mat::zeros(c, c);
    matmul(
        g.as_mut(),
        Accum::Replace,
        w.transpose(),
        mw.as_ref(),
        1.0,
        par,
    );
    let g = Mat::from_fn(c, c, |i, j| 0.5 * (g[(i, j)] + g[(j, i)]));
    let evd = g
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| DenseFailure {
            what: "Gram eigen-decomposition",
        })?;
    let s = evd.S().column_vector();
    let u = evd.U();
    // Largest first.
    let keep: Vec<usize> = (0..c)
        .rev()
        .filter(|&j| s[j] > drop_below && s[j] > 0.0)
        .collect();
    let r = keep.len();
    let uk = Mat::from_fn(c, r, |i, j| u[(i, keep[j])] / s[keep[j]].sqrt());
    let mut q = Mat::zeros(w.nrows(), r);
    matmul(
        q.as_mut(),
        Accum::Replace,
        w.as_ref(),
        uk.as_ref(),
        1.0,
        par,
    );
    let rr = Mat::from_fn(r, c, |i, j| s[keep[i]].sqrt() * u[(j, keep[i])]);
    let smallest = keep.last().map_or(0.0, |&j| s[j]);
    Ok((q, rr, smallest))
}

/// (Q, R, C) of [`m_orthonormalize`].
pub(crate) type Orthonormalized = (Mat<f64>, Mat<f64>, Mat<f64>);

/// M-orthonormalises the columns of w against the M-orthonormal columns of `locked` and
/// `basis` (two passes of classical Gram–Schmidt) and within themselves, dropping directions
/// whose M-norm is below `rank_tol` × the largest input column M-norm.
///
/// Returns (Q n×r, R r×c, C basis.ncols()×c) with w = basis·C + Q·R + locked·(·) + dropped.
pub(crate) fn m_orthonormalize(
    w: Mat<f64>,
    locked: MatRef<'_, f64>,
    basis: MatRef<'_, f64>,
    mass: SparseColMatRef<'_, usize, f64>,
    rank_tol: f64,
    par: Par,
) -> Result<Orthonormalized, DenseFailure> {
    let (n, c) = (w.nrows(), w.ncols());
    let mut w = w;
    let mw = mass_mul(mass, w.as_ref(), par);
    let reference = (0..c)
        .map(|j| w.col(j).transpose() * mw.col(j))
        .fold(0.0f64, f64::max);
    let mut coef = Mat::zeros(basis.ncols(), c);
    for _ in 0..2 {
        project_out(&mut w, locked, mass, par);
        coef += project_out(&mut w, basis, mass, par);
    }
    // Also true for a NaN reference.
    if reference.is_nan() || reference <= 0.0 {
        return Ok((Mat::zeros(n, 0), Mat::zeros(0, c), coef));
    }
    let (mut q, r1, smallest) =
        gram_orthonormalize(&w, mass, rank_tol * rank_tol * reference, par)?;
    // Λ^{-1/2} amplifies the traces (~ε) of the basis left in w by sqrt(reference/Λ_min).
    if q.ncols() == 0 || smallest >= 1e-4 * reference {
        return Ok((q, r1, coef));
    }
    // Second round: q may carry amplified traces of the basis after the Λ^{-1/2} scaling.
    project_out(&mut q, locked, mass, par);
    let h = project_out(&mut q, basis, mass, par);
    coef += &h * &r1;
    let (q2, r2, _) = gram_orthonormalize(&q, mass, 1e-24, par)?;
    let r = &r2 * &r1;
    Ok((q2, r, coef))
}

/// Ensures `basis` (n × capacity) and `t` (capacity²) hold at least `want` columns, keeping
/// the first `used`.
fn grow(basis: &mut Mat<f64>, t: &mut Mat<f64>, used: usize, want: usize) {
    if basis.ncols() >= want {
        return;
    }
    let mut nb = Mat::zeros(basis.nrows(), want);
    nb.subcols_mut(0, used).copy_from(basis.subcols(0, used));
    *basis = nb;
    let mut nt = Mat::zeros(want, want);
    nt.submatrix_mut(0, 0, used, used)
        .copy_from(t.submatrix(0, 0, used, used));
    *t = nt;
}

/// Lowest eigenpairs of (K, M) seen through A = (K − σM)⁻¹ M: the largest θ.
///
/// `solve` overwrites its argument X with (K − σM)⁻¹ X. `target` receives the θ locked so far
/// and returns how many pairs are wanted (it may grow, e.g. for a frequency cut-off).
pub(crate) fn block_krylov_schur(
    mass: SparseColMatRef<'_, usize, f64>,
    solve: &mut dyn FnMut(MatMut<'_, f64>),
    target: &mut dyn FnMut(&[f64]) -> usize,
    options: &KrylovOptions,
    par: Par,
) -> Result<KrylovOutcome, DenseFailure> {
    let n = mass.nrows();
    let b = options.block.clamp(1, n.max(1));
    let mut seed = 0x00C0_FFEE_u64;
    let mut locked = Mat::<f64>::zeros(n, 0);
    let mut theta_locked: Vec<f64> = Vec::new();
    let (mut solves, mut restarts) = (0usize, 0usize);

    let start = random_block(n, b, &mut seed);
    let (q0, _, _) = m_orthonormalize(
        start,
        locked.as_ref(),
        Mat::zeros(n, 0).as_ref(),
        mass,
        1e-12,
        par,
    )?;
    // Columns 0..d of `basis` (capacity ≥ d) are the basis; the frontier block is fstart..d.
    let mut d = q0.ncols();
    let mut basis = q0;
    let mut t = Mat::<f64>::zeros(d, d);
    let mut fstart = 0usize;
    let mut theta_top = 0.0f64;
    let mut complete = false;

    loop {
        let nl = theta_locked.len();
        let nev = target(&theta_locked).min(n);
        if nl >= nev {
            complete = true;
            break;
        }
        if d == fstart {
            // Empty frontier: the Krylov space is invariant. Inject a fresh random block.
            let w = random_block(n, b, &mut seed);
            let (q, _, _) =
                m_orthonormalize(w, locked.as_ref(), basis.subcols(0, d), mass, 1e-10, par)?;
            if q.ncols() == 0 {
                break; // the whole space is spanned
            }
            grow(&mut basis, &mut t, d, d + q.ncols());
            basis.subcols_mut(d, q.ncols()).copy_from(&q);
            d += q.ncols();
        }
        let rem = nev - nl;
        let dmax = (2 * rem + 4 * b).min(n - nl).max(d);
        grow(&mut basis, &mut t, d, dmax);

        // Expansion: Q₊ R = (I − Q Qᵀ M) A Q_F, T[:, F] = Qᵀ M A Q_F.
        let (qn, rn) = loop {
            let fw = d - fstart;
            let mut w = mass_mul(mass, basis.subcols(fstart, fw), par);
            solve(w.as_mut());
            solves += fw;
            let (qn, rn, cn) =
                m_orthonormalize(w, locked.as_ref(), basis.subcols(0, d), mass, 1e-12, par)?;
            t.submatrix_mut(0, fstart, d, fw).copy_from(&cn);
            let wn = qn.ncols();
            if wn == 0 || d + wn > dmax {
                break (qn, rn);
            }
            basis.subcols_mut(d, wn).copy_from(&qn);
            t.submatrix_mut(d, fstart, wn, fw).copy_from(&rn);
            t.submatrix_mut(0, d, d + wn, wn).fill(0.0);
            fstart = d;
            d += wn;
        };
        let fw = d - fstart;
        let wn = qn.ncols();

        // Rayleigh–Ritz on T (symmetrised), θ descending.
        let ts = Mat::from_fn(d, d, |i, j| 0.5 * (t[(i, j)] + t[(j, i)]));
        let evd = ts
            .self_adjoint_eigen(Side::Lower)
            .map_err(|_| DenseFailure {
                what: "Krylov projected eigenproblem",
            })?;
        let s = evd.S().column_vector();
        let y = evd.U();
        let order: Vec<usize> = (0..d).rev().collect();
        theta_top = theta_top.max(s[order[0]].abs());
        // Residuals ‖R y_F‖₂ of all Ritz pairs.
        let mut ry = Mat::zeros(wn, d);
        if wn > 0 {
            matmul(
                ry.as_mut(),
                Accum::Replace,
                rn.as_ref(),
                y.subrows(fstart, fw),
                1.0,
                par,
            );
        }
        let floor = 64.0 * f64::EPSILON * theta_top;
        let mut lock = Vec::new();
        let mut keep = Vec::new();
        for (rank, &j) in order.iter().enumerate() {
            let residual = ry.col(j).norm_l2();
            let converged = s[j] > 0.0 && residual <= options.tolerance * s[j] + floor;
            if rank < rem && converged {
                lock.push(j);
            } else {
                keep.push(j);
            }
        }
        // Lock.
        if !lock.is_empty() {
            let sel = Mat::from_fn(d, lock.len(), |i, c| y[(i, lock[c])]);
            let mut x = Mat::zeros(n, nl + lock.len());
            x.subcols_mut(0, nl).copy_from(&locked);
            matmul(
                x.subcols_mut(nl, lock.len()),
                Accum::Replace,
                basis.subcols(0, d),
                sel.as_ref(),
                1.0,
                par,
            );
            locked = x;
            theta_locked.extend(lock.iter().map(|&j| s[j]));
        }
        let nl2 = theta_locked.len();
        let nev2 = target(&theta_locked).min(n);
        if nl2 >= nev2 {
            complete = true;
            break;
        }
        if restarts >= options.max_restarts {
            break;
        }
        restarts += 1;
        // Thick restart: U = Q Y_keep, then Q₊; T = [[Θ, ·], [R Y_F,keep, ·]].
        let rem2 = nev2 - nl2;
        let dmax2 = (2 * rem2 + 4 * b).min(n - nl2);
        let kkeep = (rem2 + b)
            .max(dmax2 / 2)
            .min(dmax2.saturating_sub(wn))
            .min(keep.len())
            .max(rem2.min(keep.len()));
        let sel = Mat::from_fn(d, kkeep, |i, c| y[(i, keep[c])]);
        let capacity = (kkeep + wn).max(dmax2);
        let mut nb = Mat::zeros(n, capacity);
        matmul(
            nb.subcols_mut(0, kkeep),
            Accum::Replace,
            basis.subcols(0, d),
            sel.as_ref(),
            1.0,
            par,
        );
        nb.subcols_mut(kkeep, wn).copy_from(&qn);
        basis = nb;
        let mut tn = Mat::zeros(capacity, capacity);
        for c in 0..kkeep {
            tn[(c, c)] = s[keep[c]];
            for r in 0..wn {
                tn[(kkeep + r, c)] = ry[(r, keep[c])];
            }
        }
        t = tn;
        d = kkeep + wn;
        fstart = kkeep;
    }
    Ok(KrylovOutcome {
        theta: theta_locked,
        vectors: locked,
        restarts,
        solves,
        complete,
    })
}
