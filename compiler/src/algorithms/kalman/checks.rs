//! Input checks of the Kalman stage: shapes, finiteness, symmetry, definiteness,
//! detectability and stabilizability (PBH test).

use faer::{Mat, MatRef};

use super::*;

// ---------------------------------------------------------------------------------------------
// Input checks.

pub(super) fn check_square(name: &str, m: MatRef<f64>) -> Result<(), KalmanError> {
    if m.nrows() != m.ncols() {
        return Err(KalmanError::Shape(format!(
            "{name} is {}x{}, must be square",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(())
}

pub(super) fn check_shape(
    name: &str,
    m: MatRef<f64>,
    rows: usize,
    cols: usize,
) -> Result<(), KalmanError> {
    if m.nrows() != rows || m.ncols() != cols {
        return Err(KalmanError::Shape(format!(
            "{name} is {}x{}, expected {rows}x{cols}",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(())
}

pub(super) fn check_finite(matrix: &'static str, m: MatRef<f64>) -> Result<(), KalmanError> {
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            let value = m[(i, j)];
            if !value.is_finite() {
                return Err(KalmanError::NonFinite {
                    matrix,
                    row: i,
                    col: j,
                    value,
                });
            }
        }
    }
    Ok(())
}

/// First (row, col) with |M_ij − M_ji| > tol · max|M|.
pub(super) fn asymmetry(m: MatRef<f64>) -> Option<(usize, usize)> {
    let tol = SYMMETRY_TOLERANCE * m.norm_max();
    for j in 0..m.ncols() {
        for i in 0..j {
            if (m[(i, j)] - m[(j, i)]).abs() > tol {
                return Some((i, j));
            }
        }
    }
    None
}

pub(super) fn validate_q(q: MatRef<f64>) -> Result<Mat<f64>, KalmanError> {
    if let Some((row, col)) = asymmetry(q) {
        return Err(KalmanError::QNotSymmetric {
            row,
            col,
            upper: q[(row, col)],
            lower: q[(col, row)],
        });
    }
    let q = symmetrise(&q.to_owned());
    let ev = q
        .self_adjoint_eigenvalues(Side::Lower)
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of Q: {e:?}")))?;
    if let (Some(&lo), Some(&hi)) = (ev.first(), ev.last()) {
        if lo < -PSD_TOLERANCE * hi.abs().max(f64::MIN_POSITIVE) {
            return Err(KalmanError::QNotPositiveSemidefinite {
                eigenvalue: lo,
                largest: hi,
            });
        }
    }
    Ok(q)
}

pub(super) fn validate_r(r: MatRef<f64>) -> Result<Mat<f64>, KalmanError> {
    for i in 0..r.nrows() {
        let value = r[(i, i)];
        if value.is_nan() || value <= 0.0 {
            return Err(KalmanError::RDiagonalNotPositive { index: i, value });
        }
    }
    if let Some((row, col)) = asymmetry(r) {
        return Err(KalmanError::RNotSymmetric {
            row,
            col,
            upper: r[(row, col)],
            lower: r[(col, row)],
        });
    }
    let r = symmetrise(&r.to_owned());
    if r.nrows() > 0 {
        let ev = r
            .self_adjoint_eigenvalues(Side::Lower)
            .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of R: {e:?}")))?;
        let lo = ev.first().copied().unwrap_or(0.0);
        if lo.is_nan() || lo <= 0.0 || r.llt(Side::Lower).is_err() {
            return Err(KalmanError::RNotPositiveDefinite { eigenvalue: lo });
        }
    }
    Ok(r)
}

/// PBH tests on the eigenvalues of F with |λ| ≥ 1 − [`MARGINAL_STABILITY`]:
/// detectable ⇔ rank [λI − F; H] = r, stabilizable ⇔ rank [λ̄I − Fᵀ; Q] = r (Q PSD, so
/// wᴴQ = 0 ⇔ wᴴQ^{1/2} = 0). H and Q are scaled to ‖F‖_F so the rank test is scale-free.
pub(super) fn check_detectable_stabilizable(
    f: &Mat<f64>,
    h: &Mat<f64>,
    q: &Mat<f64>,
) -> Result<(), KalmanError> {
    let n = f.nrows();
    let eig = f
        .eigenvalues()
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of F: {e:?}")))?;
    let f_norm = f.norm_l2().max(f64::MIN_POSITIVE);
    let scale = |x: f64| if x > 0.0 { f_norm / x } else { 0.0 };
    let (sh, sq) = (scale(h.norm_l2()), scale(q.norm_l2()));
    let mut tested: Vec<c64> = Vec::new();
    for lam in eig {
        let modulus = lam.re.hypot(lam.im);
        if modulus < 1.0 - MARGINAL_STABILITY || lam.im < 0.0 {
            continue;
        }
        // A repeated eigenvalue (rigid-body modes) is tested once: the rank test covers its
        // whole eigenspace.
        if tested
            .iter()
            .any(|t| (t.re - lam.re).hypot(t.im - lam.im) <= 1e-9 * modulus)
        {
            continue;
        }
        tested.push(lam);
        let pbh = |top: &dyn Fn(usize, usize) -> c64, bottom: &Mat<f64>, s: f64| {
            let k = bottom.nrows();
            let mat = Mat::<c64>::from_fn(n + k, n, |i, j| {
                if i < n {
                    top(i, j)
                } else {
                    c64::new(s * bottom[(i - n, j)], 0.0)
                }
            });
            mat.singular_values()
                .map(|sv| sv.last().copied().unwrap_or(0.0))
                .map_err(|e| KalmanError::LinearAlgebra(format!("PBH singular values: {e:?}")))
        };
        let diag = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        let sigma = pbh(
            &|i, j| c64::new(lam.re * diag(i, j) - f[(i, j)], lam.im * diag(i, j)),
            h,
            sh,
        )?;
        if sigma <= PBH_TOLERANCE * f_norm {
            return Err(KalmanError::Undetectable {
                re: lam.re,
                im: lam.im,
                modulus,
                sigma,
            });
        }
        let sigma = pbh(
            &|i, j| c64::new(lam.re * diag(i, j) - f[(j, i)], -lam.im * diag(i, j)),
            q,
            sq,
        )?;
        if sigma <= PBH_TOLERANCE * f_norm {
            return Err(KalmanError::Unstabilizable {
                re: lam.re,
                im: lam.im,
                modulus,
                sigma,
            });
        }
    }
    Ok(())
}
