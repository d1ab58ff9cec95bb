//! The levels of the tier's force σ (docs/design.md §11.10): the tier's filter and its gain
//! schedule designed again with every force (and rate) σ scaled by each factor of
//! [`LEVEL_FACTORS`], and the parameters of the innovation statistic with which the runtime
//! moves between them ([`Statistic`]). One σ cannot serve a load that ramps as fast as the scene
//! states and one that holds or is given: the levels let the runtime use the σ the innovations
//! ask for, with the gains still computed here.

use faer::Mat;
use nalgebra::{DMatrix, DVector};

use crate::algorithms::kalman::adaptation::{effective_channels, Statistic, LEVEL_FACTORS};
use crate::algorithms::kalman::PeriodicSchedule;
use crate::outputs::Measurements;

/// One level of the force σ: the filter at rest and at each operating point of the gain
/// schedule (in the order of the tier filter's `scheduled`), designed with the force σ ×
/// `factor`.
#[derive(Clone, Debug)]
pub struct FilterLevel {
    /// Factor on the designed force (and rate) σ.
    pub factor: f64,
    /// The filter at rest and its process noise.
    pub schedule: PeriodicSchedule,
    pub process_noise: Mat<f64>,
    /// Per scheduled point: the filter there and its process noise.
    pub scheduled: Vec<(PeriodicSchedule, Mat<f64>)>,
}

/// The levels of [`LEVEL_FACTORS`] designed by `design` (the filter at rest and at every
/// scheduled point with the force σ × the factor) and the statistic that moves between them:
/// its window from the shortest stated rise time `rise_time` (s) at time step `dt` (s), its
/// thresholds from the smallest effective channel count over the designed filters `designed`
/// and the levels (innovation covariances through the measured rows `rows`, channels × r, and
/// the markers' variance). Nothing without a rise time (no force states). A level `design`
/// fails for is left out, named in the returned notes.
pub fn design_levels<E: std::fmt::Display>(
    design: impl Fn(f64) -> Result<FilterLevel, E>,
    designed: &[&PeriodicSchedule],
    rows: &DMatrix<f64>,
    measurements: &Measurements,
    rise_time: Option<f64>,
    dt: f64,
) -> (Vec<FilterLevel>, Option<Statistic>, Vec<String>) {
    let Some(rise_time) = rise_time else {
        return (Vec::new(), None, Vec::new());
    };
    let mut levels = Vec::new();
    let mut notes = Vec::new();
    for factor in LEVEL_FACTORS {
        match design(factor) {
            Ok(level) => levels.push(level),
            Err(e) => notes.push(format!(
                "force σ level × {factor}: left out, its filter could not be designed ({e}); \
                 the run-time filter has no such level, so when the load changes faster (or \
                 slower) than the σ of the levels it has, its estimate lags (or is noisier) \
                 with no level to move to"
            )),
        }
    }
    if levels.is_empty() {
        return (levels, None, notes);
    }
    let schedules = designed.iter().copied().chain(
        levels
            .iter()
            .flat_map(|l| std::iter::once(&l.schedule).chain(l.scheduled.iter().map(|(s, _)| s))),
    );
    let effective = schedules
        .flat_map(|s| &s.phases)
        .filter(|p| !p.measured.is_empty())
        .map(|p| {
            effective_channels(&innovation_covariance(
                rows,
                &p.prior_covariance,
                &p.measured,
                &measurements.variance,
            ))
        })
        .fold(f64::INFINITY, f64::min);
    let statistic = Statistic::new(
        rise_time,
        dt,
        &measurements.every,
        if effective.is_finite() {
            effective
        } else {
            1.0
        },
    );
    (levels, Some(statistic), notes)
}

/// S = H P⁻_qq Hᵀ + R over the channels `measured` (rows of `rows`, channels × r; P⁻ of the
/// filter state, its leading r × r block the coordinates q).
fn innovation_covariance(
    rows: &DMatrix<f64>,
    prior: &Mat<f64>,
    measured: &[usize],
    variance: &[f64],
) -> Mat<f64> {
    let r = rows.ncols();
    let hp: Vec<DVector<f64>> = measured
        .iter()
        .map(|&j| DVector::from_fn(r, |c, _| (0..r).map(|i| rows[(j, i)] * prior[(i, c)]).sum()))
        .collect();
    Mat::from_fn(measured.len(), measured.len(), |a, b| {
        let jb = measured[b];
        let s: f64 = (0..r).map(|c| hp[a][c] * rows[(jb, c)]).sum();
        if a == b {
            s + variance[jb]
        } else {
            s
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// S of two channels that read the same coordinate is one signal plus independent noise:
    /// its effective count lies between 1 and 2, and equals 2 when P⁻ vanishes.
    #[test]
    fn innovation_covariance_of_shared_and_independent_channels() {
        let rows = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 1.0, 0.0]);
        let prior = Mat::from_fn(2, 2, |i, j| if i == j { 4.0 } else { 0.0 });
        let s = innovation_covariance(&rows, &prior, &[0, 1], &[1.0, 1.0]);
        assert_eq!((s[(0, 0)], s[(0, 1)], s[(1, 1)]), (5.0, 4.0, 5.0));
        let nu = effective_channels(&s);
        assert!(nu > 1.0 && nu < 2.0, "{nu}");
        let zero = Mat::zeros(2, 2);
        let s = innovation_covariance(&rows, &zero, &[0, 1], &[1.0, 3.0]);
        assert!((effective_channels(&s) - 2.0).abs() < 1e-12);
    }

    /// A level whose filter cannot be designed is left out with a note naming its factor, the
    /// design's error and what the run-time filter then lacks; with none designed there is no
    /// statistic to move between levels.
    #[test]
    fn a_level_that_cannot_be_designed_is_named() {
        let measurements = Measurements {
            channels: vec![(0, 0)],
            variance: vec![1e-6],
            every: vec![1],
        };
        let (levels, statistic, notes) = design_levels(
            |factor| Err::<FilterLevel, _>(format!("Riccati residual at × {factor}")),
            &[],
            &DMatrix::zeros(1, 2),
            &measurements,
            Some(0.2),
            1e-3,
        );
        assert!(levels.is_empty() && statistic.is_none());
        assert_eq!(notes.len(), LEVEL_FACTORS.len());
        for (note, factor) in notes.iter().zip(LEVEL_FACTORS) {
            assert!(
                note.contains(&format!("force σ level × {factor}: left out"))
                    && note.contains(&format!("Riccati residual at × {factor}"))
                    && note.contains("no such level"),
                "{note}"
            );
        }
    }
}
