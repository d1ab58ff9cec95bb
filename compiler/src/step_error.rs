//! The time step's own error, estimated on the model's modal system (its retained modes and
//! static correction) without a full-order run.
//!
//! The exact zero-order-hold step of a mode ([`crokf_kernel::exact`]) is that mode's exact
//! response to a load held over each step, so stepping the same modal system once with
//! Wilson-θ at Δt and once exactly, through the same load histories, separates the step's error
//! from the reduction's: ‖y_W − y_E‖ / ‖y_E‖ on the measured rows (sensors and displayed nodes,
//! unweighted). Stepping Wilson-θ at Δt/2 with each load held over two sub-steps gives the
//! error's order, and from it the Δt that would meet a tolerance. The modes cut from the basis
//! are missing from both responses; the full-order figures of `time_error` (the converged
//! reference) agree within a few per cent on the example scenes.

use std::collections::BTreeMap;

use faer::Mat;

use crate::accuracy::LoadTest;
use crate::dynamics::WilsonTheta;
use crate::reduce::ModalSystem;
use crate::reduce::ReduceError;
use crate::scene::Scheme;

/// The step's own error above which the compile says so, and the tolerance its Δt advice
/// meets: 1 %.
pub const NOTE_ABOVE: f64 = 0.01;

/// The estimate for one load history.
#[derive(Clone, Debug, PartialEq)]
pub struct StepError {
    /// The history's name (`step`, `chirp`, `step.<channel>`).
    pub test: String,
    /// Wilson-θ at Δt against the exact step, relative L2.
    pub error: f64,
    /// Wilson-θ at Δt/2 (load held over both sub-steps) against the exact step.
    pub half_step_error: f64,
}

impl StepError {
    /// The measured order of the error, log₂(error at Δt / error at Δt/2).
    pub fn order(&self) -> f64 {
        (self.error / self.half_step_error).log2()
    }

    /// The Δt (s) at which this error would meet `tolerance`, extrapolated from `dt` with the
    /// measured order ([`StepError::order`], or 1 when that is not a positive finite number:
    /// the smaller Δt, the safer). `dt` itself when it already meets it.
    pub fn dt_for(&self, dt: f64, tolerance: f64) -> f64 {
        if self.error <= tolerance {
            return dt;
        }
        let order = match self.order() {
            p if p.is_finite() && p > 0.0 => p,
            _ => 1.0,
        };
        dt * (tolerance / self.error).powf(1.0 / order)
    }
}

/// Outputs of `system` on `rows` (indices of its output rows, with the weight each was scaled
/// by) per scene step of `test`, each input held over `substeps` steps of the system: `rows ×
/// steps` values, step-major.
fn response(
    system: &ModalSystem,
    rows: &[(usize, f64)],
    test: &LoadTest,
    substeps: usize,
) -> Vec<f64> {
    let m = system.modal_inputs.ncols();
    let steps = test.inputs.len();
    let inputs = Mat::from_fn(m, steps * substeps, |i, k| {
        test.inputs[k / substeps].get(i).copied().unwrap_or(0.0)
    });
    // Column t is the state after t system steps (y_0 = 0): read at each scene step's start,
    // the state after k scene steps, the same in every response compared.
    let y = system.simulate(inputs.as_ref());
    let mut out = Vec::with_capacity(steps * rows.len());
    for k in 0..steps {
        let col = k * substeps;
        out.extend(rows.iter().map(|&(i, w)| y[(i, col)] / w));
    }
    out
}

fn relative_l2(reference: &[f64], other: &[f64]) -> f64 {
    let (err, norm) = reference
        .iter()
        .zip(other)
        .fold((0.0, 0.0), |(e, n), (a, b)| {
            (e + (b - a) * (b - a), n + a * a)
        });
    if norm > 0.0 {
        (err / norm).sqrt()
    } else {
        0.0
    }
}

/// The step's own error of Wilson-θ at `system`'s Δt (a Wilson-θ modal system) on each test,
/// against the exact step of the same modes.
pub fn estimate(
    system: &ModalSystem,
    rows: &[(usize, f64)],
    tests: &[LoadTest],
) -> Result<Vec<StepError>, ReduceError> {
    let wilson = system.wilson;
    let wilson_system = system.rediscretised(wilson, Scheme::WilsonTheta)?;
    let exact = system.rediscretised(wilson, Scheme::Exact)?;
    let half = system.rediscretised(
        WilsonTheta {
            dt: wilson.dt / 2.0,
            theta: wilson.theta,
        },
        Scheme::WilsonTheta,
    )?;
    Ok(tests
        .iter()
        .map(|test| {
            let reference = response(&exact, rows, test, 1);
            StepError {
                test: test.name.clone(),
                error: relative_l2(&reference, &response(&wilson_system, rows, test, 1)),
                half_step_error: relative_l2(&reference, &response(&half, rows, test, 2)),
            }
        })
        .collect())
}

/// The compile note of a Wilson-θ model: the step's own error on the joint step and chirp and
/// the worst single channel, the Δt that would meet `tolerance` on all of them, and the exact
/// scheme; None when every figure is within `tolerance`.
pub fn note(errors: &[StepError], dt: f64, tolerance: f64, exact_allowed: bool) -> Option<String> {
    let worst = errors.iter().max_by(|a, b| a.error.total_cmp(&b.error))?;
    if worst.error <= tolerance {
        return None;
    }
    let named: BTreeMap<&str, f64> = errors.iter().map(|e| (e.test.as_str(), e.error)).collect();
    let joint = ["step", "chirp"]
        .iter()
        .filter_map(|t| named.get(t).map(|e| format!("{e:.2e} ({t})")))
        .collect::<Vec<_>>()
        .join(", ");
    let channel = errors
        .iter()
        .filter(|e| e.test.starts_with("step."))
        .max_by(|a, b| a.error.total_cmp(&b.error))
        .map(|e| {
            format!(
                "; worst single channel '{}' {:.2e}",
                e.test.trim_start_matches("step."),
                e.error
            )
        })
        .unwrap_or_default();
    let dt_needed = errors
        .iter()
        .map(|e| e.dt_for(dt, tolerance))
        .fold(dt, f64::min);
    let remedy = if exact_allowed {
        "; or `[time] scheme = \"exact\"`, whose step is exact for the modes at this Δt"
    } else {
        ""
    };
    Some(format!(
        "time step: Wilson-θ at Δt = {} s is {joint} off the exact response of the model's own \
         modes{channel} (estimated on the modal system; the measured error, against the \
         full-order Wilson-θ at the same Δt, is the reduction's alone and does not contain it). \
         Δt ≈ {:.2e} s would bring every figure within {:.0} %{remedy}",
        dt,
        dt_needed,
        100.0 * tolerance
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_and_dt_for() {
        let e = StepError {
            test: "step".into(),
            error: 0.04,
            half_step_error: 0.01,
        };
        assert!((e.order() - 2.0).abs() < 1e-12);
        assert!((e.dt_for(1e-3, 0.01) - 0.5e-3).abs() < 1e-15);
        assert_eq!(e.dt_for(1e-3, 0.05), 1e-3);
        let first = StepError {
            half_step_error: 0.02,
            ..e.clone()
        };
        assert!((first.dt_for(1e-3, 0.01) - 0.25e-3).abs() < 1e-15);
    }

    #[test]
    fn the_note_names_the_worst_channel_and_is_silent_within_the_tolerance() {
        let errors = vec![
            StepError {
                test: "step".into(),
                error: 0.05,
                half_step_error: 0.025,
            },
            StepError {
                test: "chirp".into(),
                error: 0.15,
                half_step_error: 0.04,
            },
            StepError {
                test: "step.tip.x".into(),
                error: 0.2,
                half_step_error: 0.1,
            },
        ];
        let text = note(&errors, 1e-3, 0.01, true).expect("a note");
        assert!(text.contains("'tip.x' 2.00e-1"), "{text}");
        assert!(text.contains("1.50e-1 (chirp)"), "{text}");
        assert!(text.contains("scheme = \"exact\""), "{text}");
        // First order on tip.x: Δt/20.
        assert!(text.contains("5.00e-5 s"), "{text}");
        assert!(note(&errors, 1e-3, 0.5, true).is_none());
        assert!(!note(&errors, 1e-3, 0.01, false)
            .expect("a note")
            .contains("scheme = \"exact\""));
    }
}
