//! A filter run as the noise identification needs it (docs/design.md §11.6,
//! [`identify_noise`](super::als_noise::identify_noise)): the innovations of every
//! step and the gain-schedule filter and phase that updated it, from rest, the innovation gate
//! off, through the runtime's [`Estimator`].

use crokf_runtime::{Estimator, Model, RuntimeError};

/// What one run of a model's filter over a recording gives the identification.
#[derive(Clone, Debug, Default)]
pub struct FilterRun {
    /// Per step: y − ŷ⁻ per measurement channel (model order), m; NaN for a channel the step's
    /// phase does not measure or the recording does not have.
    pub innovations: Vec<Vec<f64>>,
    /// Per step: (the schedule's filter that updated it, its phase); filter 0 on the warped tier.
    pub filters: Vec<(usize, usize)>,
}

impl FilterRun {
    /// Changes of the schedule's filter between consecutive steps.
    pub fn switches(&self) -> usize {
        self.filters.windows(2).filter(|w| w[0].0 != w[1].0).count()
    }
}

/// Runs `model`'s filter from rest over `inputs` (one row per step, model input order) and
/// `measurements` (one row per step, model measurement order; `None`: missing), the innovation
/// gate off, the force σ held at its designed level and the stored gains kept where a value is
/// missing (the identification reads the gains of the designed filter), and records what
/// [`FilterRun`] holds. Both have one row per step, as
/// many rows.
pub fn filter_run(
    model: &Model,
    inputs: &[Vec<f64>],
    measurements: &[Vec<Option<f64>>],
) -> Result<FilterRun, RuntimeError> {
    let mut est = Estimator::new(model)?;
    est.set_innovation_gate(None);
    est.set_force_adaptation(false);
    // The stored gains also where the recording misses a value: the identification models
    // the innovations through the stored filters (docs/design.md §11.11 would change them).
    est.set_covariance_recursion(false);
    let m = model.measurements.len();
    let mut predicted = vec![0.0; m];
    let mut run = FilterRun {
        innovations: Vec::with_capacity(inputs.len()),
        filters: Vec::with_capacity(inputs.len()),
    };
    for (u, y) in inputs.iter().zip(measurements) {
        est.predict(u)?;
        est.measurement_estimates(&mut predicted)?;
        let mut nu = vec![f64::NAN; m];
        for &j in est.active_measurements() {
            let j = j as usize;
            if let Some(value) = y.get(j).copied().flatten() {
                nu[j] = value - predicted[j];
            }
        }
        let phase = est.phase();
        est.update(y)?;
        run.innovations.push(nu);
        run.filters.push((est.tier_filter().unwrap_or(0), phase));
    }
    Ok(run)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crokf_formats::synthetic::{benchmark_model, SplitMix64};

    /// The run's innovations are y − ŷ⁻ of an estimator stepped the same way, NaN exactly where
    /// the recording has no value, and every step's phase is recorded (on this warped model the
    /// filter is always 0; the tier's filter sequence is exercised by tests/tests/tier.rs,
    /// `identify_noise_recovers_the_random_walk_of_a_known_truth`).
    #[test]
    fn innovations_and_filters_of_a_recording() {
        let model = benchmark_model(8, 3, 6, 10);
        let (n_in, m) = (model.inputs.len(), model.measurements.len());
        let mut rng = SplitMix64(5);
        let inputs: Vec<Vec<f64>> = (0..40)
            .map(|_| (0..n_in).map(|_| rng.uniform()).collect())
            .collect();
        let measurements: Vec<Vec<Option<f64>>> = (0..40)
            .map(|k| {
                (0..m)
                    .map(|j| ((k + j) % 5 != 0).then(|| 1e-3 * rng.uniform()))
                    .collect()
            })
            .collect();
        let run = filter_run(&model, &inputs, &measurements).unwrap();
        assert_eq!(run.innovations.len(), 40);
        assert_eq!(run.filters.len(), 40);
        let mut est = Estimator::new(&model).unwrap();
        est.set_innovation_gate(None);
        let mut predicted = vec![0.0; m];
        for (k, (u, y)) in inputs.iter().zip(&measurements).enumerate() {
            est.predict(u).unwrap();
            est.measurement_estimates(&mut predicted).unwrap();
            let active: Vec<usize> = est
                .active_measurements()
                .iter()
                .map(|&j| j as usize)
                .collect();
            for j in 0..m {
                let nu = run.innovations[k][j];
                match y[j] {
                    Some(v) if active.contains(&j) => assert_eq!(nu, v - predicted[j]),
                    _ => assert!(nu.is_nan(), "step {k} channel {j}: {nu}"),
                }
            }
            assert_eq!(run.filters[k], (0, est.phase()));
            est.update(y).unwrap();
        }
        assert_eq!(run.switches(), 0);
    }
}
