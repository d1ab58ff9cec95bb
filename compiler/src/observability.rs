//! Whether the markers can tell the estimated loads apart. A load the filter estimates is a
//! random walk: its force states have the eigenvalue 1, and a constant force is seen only
//! through its static response at the markers. So the steady-state filter exists only if the
//! static marker response G (measured channels × estimated force channels, m per N) has full
//! column rank: a force combination c with G c = 0 moves no marker, and no filter can estimate
//! it (the Kalman stage then fails its PBH test, "undetectable"). This module finds that
//! combination and names it, so that the compile's error says which loads and what to change
//! rather than an eigenvalue.

use faer::linalg::solvers::Solve as _;
use nalgebra::DMatrix;

use crate::full_order::FullOrder;
use crate::outputs::Measurements;

/// A combination is unseen when, with every column of G scaled to unit length, its smallest
/// singular value is below this fraction of the largest.
pub const UNSEEN: f64 = 1e-6;

/// The full-order static marker response G: column j is H K⁻¹ b_j for the input channel
/// `channels[j]` (H the measured channels' rows, K the stiffness). Err when K cannot be
/// factored.
pub fn static_marker_response(
    full: &FullOrder,
    measurements: &Measurements,
    channels: &[usize],
) -> Result<DMatrix<f64>, String> {
    let fem = &full.fem;
    let n = fem.dof_count();
    let llt = fem
        .stiffness
        .sp_cholesky(faer::Side::Lower)
        .map_err(|e| format!("the stiffness K is not positive definite ({e:?})"))?;
    let inputs = &full.operators.inputs;
    let mut u = faer::Mat::from_fn(n, channels.len(), |i, j| inputs[channels[j]].column[i]);
    llt.solve_in_place(u.as_mut());
    Ok(DMatrix::from_fn(
        measurements.len(),
        channels.len(),
        |row, j| measured_value(full, measurements.channels[row], |d| u[(d, j)]),
    ))
}

/// The full-order value of measurement channel (sensor, component) `channel` for the
/// displacement `u` (by DOF index): the sensor's barycentric interpolation.
pub fn measured_value(full: &FullOrder, (s, c): (usize, usize), u: impl Fn(usize) -> f64) -> f64 {
    full.operators.sensors[s]
        .weights
        .iter()
        .filter_map(|&(node, w)| full.fem.dofs.index[node][c].map(|d| w * u(d)))
        .sum()
}

/// The force combination the markers do not see (module doc), as text naming the channels by
/// `labels` (one per column of `g`), e.g. `0.71·upper.y + 0.71·lower.y`, and the ratio of
/// its response to the largest; None when every combination is seen.
pub fn unseen_combination(g: &DMatrix<f64>, labels: &[String]) -> Option<(String, f64)> {
    let columns = g.ncols();
    if columns == 0 {
        return None;
    }
    // A channel that moves no marker at all.
    let norms: Vec<f64> = (0..columns).map(|j| g.column(j).norm()).collect();
    let largest = norms.iter().copied().fold(0.0f64, f64::max);
    if let Some(j) = norms
        .iter()
        .position(|&x| x <= UNSEEN * largest || x == 0.0)
    {
        return Some((labels[j].clone(), norms[j] / largest.max(f64::MIN_POSITIVE)));
    }
    let scaled = DMatrix::from_fn(g.nrows(), columns, |i, j| g[(i, j)] / norms[j]);
    if g.nrows() < columns {
        // Fewer marker channels than force channels: a null space exists whatever the layout.
        let svd = scaled.clone().svd(false, true);
        let v_t = svd.v_t?;
        // The rows of V_t (one per marker channel) span G's row space; a null vector of G is
        // orthogonal to them.
        let mut c = nalgebra::DVector::zeros(columns);
        for k in 0..columns {
            let mut e = nalgebra::DVector::zeros(columns);
            e[k] = 1.0;
            let mut x = e.clone();
            for r in 0..v_t.nrows() {
                let row = v_t.row(r).transpose();
                let h = row.dot(&x);
                x -= h * row;
            }
            if x.norm() > 0.5 {
                c = x.normalize();
                break;
            }
        }
        return Some((combination(&c, &norms, labels), 0.0));
    }
    let svd = scaled.svd(false, true);
    let v_t = svd.v_t?;
    let (k, &smallest) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let top = svd.singular_values.max();
    if smallest > UNSEEN * top {
        return None;
    }
    let c = v_t.row(k).transpose();
    Some((combination(&c, &norms, labels), smallest / top))
}

/// `c` (in the unit-column scaling) as a combination of the channels in newtons' proportions,
/// normalised to unit length, terms below 1 % left out, the first term shown positive.
fn combination(c: &nalgebra::DVector<f64>, norms: &[f64], labels: &[String]) -> String {
    let mut w: Vec<f64> = c.iter().zip(norms).map(|(x, n)| x / n).collect();
    let length = w.iter().map(|x| x * x).sum::<f64>().sqrt();
    // The first term shown (weight ≥ 1 % of the length) is made positive.
    let sign = w
        .iter()
        .find(|x| x.abs() >= 0.01 * length)
        .map_or(1.0, |x| x.signum());
    w.iter_mut().for_each(|x| *x *= sign / length);
    let mut text = String::new();
    for (x, label) in w.iter().zip(labels) {
        if x.abs() < 0.01 {
            continue;
        }
        if text.is_empty() {
            text = format!("{x:.2}·{label}");
        } else {
            text.push_str(&format!(
                " {} {:.2}·{label}",
                if *x < 0.0 { "−" } else { "+" },
                x.abs()
            ));
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(n: usize) -> Vec<String> {
        (0..n).map(|j| format!("f{j}")).collect()
    }

    /// Full column rank: nothing unseen. Two columns equal up to scale: their difference in
    /// newtons' proportions is named. A zero column is named alone. More forces than markers:
    /// a null combination is found.
    #[test]
    fn the_unseen_combination_is_named() {
        let g = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        assert!(unseen_combination(&g, &labels(2)).is_none());
        // Column 1 = 2 × column 0: 2·f0 − 1·f1 is unseen (normalised: 0.89, −0.45).
        let g = DMatrix::from_row_slice(3, 2, &[1.0, 2.0, 0.5, 1.0, -1.0, -2.0]);
        let (text, ratio) = unseen_combination(&g, &labels(2)).expect("unseen");
        assert_eq!(text, "0.89·f0 − 0.45·f1", "{text}");
        assert!(ratio < 1e-12, "{ratio}");
        let g = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 2.0, 0.0]);
        assert_eq!(unseen_combination(&g, &labels(2)).expect("unseen").0, "f1");
        let g = DMatrix::from_row_slice(1, 2, &[1.0, 1.0]);
        let (text, _) = unseen_combination(&g, &labels(2)).expect("unseen");
        assert_eq!(text, "0.71·f0 − 0.71·f1", "{text}");
    }
}
