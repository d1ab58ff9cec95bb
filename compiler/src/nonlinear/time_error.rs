//! The co-rotational tier's time-discretisation error: the tier and the
//! full-order co-rotational FEM at the scene's Δt against a converged finer step of the same
//! full-order model, per training run, measured as the linear model's is
//! ([`crate::accuracy::Stepping::Converged`]).
//!
//! The converged reference steps the full-order co-rotational Wilson-θ
//! ([`CorotationalSimulator`], the training's Newton settings) at Δt/N with the load of each
//! scene step held over its N sub-steps and the acceleration restarted where the load changes
//! ([`CorotationalSimulator::consistent_acceleration`]): the continuous-time response of the
//! full-order model to the held loads as N grows. Its own error is estimated from the run at
//! Δt/(N/2) (second order: a third of their difference) and its order measured with a third
//! run at Δt/(N/4) (the ratio of the two differences, 4 for second order).
//!
//! Each figure is a relative L2 difference over the sensors' and displayed nodes' displacement
//! rows and every scene step of the run, ‖y − y_ref‖ / ‖y_ref‖, the rows of the linear
//! model's measured error ([`crate::accuracy`]).

use nalgebra::{DMatrix, DVector};

use crate::dynamics::WilsonTheta;
use crate::fem::operators::SparseRow;
use crate::full_order::FullOrder;
use crate::outputs::OutputRows;
use crate::stepping::{CorotationalSimulator, Simulator, SteppingError};

use super::reduced::{ReducedNewton, ReducedStepper};
use super::tier::Tier;
use super::training::{self, History, TrainingPlan, TrainingRun};
use super::NonlinearError;

/// How the full-order co-rotational model is stepped through a run's scene steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Substepping {
    /// Sub-steps of Δt/`substeps` per scene step, the scene step's load held over them (≥ 1).
    pub substeps: usize,
    /// Restart the acceleration where the load changes (at a scene step's start).
    pub restart: bool,
}

impl Substepping {
    /// Wilson-θ at the scene's Δt, no restart: the training runs' and the self-check's
    /// reference, the tier's own scheme.
    pub const SAME_SCHEME: Substepping = Substepping {
        substeps: 1,
        restart: false,
    };

    /// The converged reference at Δt/`substeps` with the acceleration restarted.
    pub fn converged(substeps: usize) -> Self {
        Substepping {
            substeps,
            restart: true,
        }
    }
}

/// The displacement rows measured (sensors, then displayed nodes; each a weighted sum of
/// free DOFs), as the linear model's measured error takes them.
pub fn measured_rows(full: &FullOrder) -> Vec<SparseRow> {
    let rows = OutputRows::build(&full.fem, &full.operators);
    crate::accuracy::measured_rows(&rows)
        .into_iter()
        .map(|(_, row)| row.clone())
        .collect()
}

fn record(rows: &[SparseRow], u: &[f64], out: &mut Vec<f64>) {
    out.extend(
        rows.iter()
            .map(|row| row.iter().map(|&(d, w)| w * u[d]).sum::<f64>()),
    );
}

/// The full-order co-rotational response on `rows` after each of `steps` scene steps of Δt
/// (the scene's), step k holding the load `history`(kΔt)·`unit` (n, N), stepped as
/// `stepping` says with `plan`'s Newton settings (the training's): `steps × rows` values,
/// step-major.
pub fn full_order_response(
    full: &FullOrder,
    plan: &TrainingPlan,
    unit: &[f64],
    history: &History,
    steps: usize,
    stepping: Substepping,
    rows: &[SparseRow],
) -> Result<Vec<f64>, SteppingError> {
    let dt = full.wilson.dt;
    let substeps = stepping.substeps.max(1);
    let wilson = WilsonTheta {
        dt: dt / substeps as f64,
        theta: full.wilson.theta,
    };
    let mut sim = CorotationalSimulator::new(&full.fem, wilson, plan.newton)?;
    sim.set_modified_newton(plan.modified)?;
    sim.set_sequential();
    let mut f = vec![0.0; unit.len()];
    let mut previous = 0.0;
    let mut out = Vec::with_capacity(steps * rows.len());
    for k in 0..steps {
        let m = history.at(k as f64 * dt);
        f.iter_mut().zip(unit).for_each(|(fi, u)| *fi = m * u);
        if stepping.restart && m != previous {
            sim.consistent_acceleration(&f)?;
        }
        previous = m;
        for _ in 0..substeps {
            sim.step(&f)?;
        }
        let u = sim.displacement();
        if u.iter().any(|v| !v.is_finite()) {
            return Err(SteppingError::NonFinite {
                step: k + 1,
                time: (k + 1) as f64 * dt,
            });
        }
        record(rows, u, &mut out);
    }
    Ok(out)
}

/// The tier's response on `rows` (V q after each scene step) to the same loads as
/// [`full_order_response`], stepped by the reduced Wilson-θ with `newton` (the runtime's:
/// [`super::self_check::runtime_newton`]).
pub fn tier_response(
    tier: &Tier,
    newton: ReducedNewton,
    unit: &[f64],
    history: &History,
    steps: usize,
    rows: &[SparseRow],
) -> Result<Vec<f64>, NonlinearError> {
    let v = &tier.basis.vectors;
    let dt = tier.model.wilson.dt;
    // P = rows · V (p × r): the rows read off q directly.
    let p = DMatrix::from_fn(rows.len(), v.ncols(), |i, j| {
        rows[i].iter().map(|&(d, w)| w * v[(d, j)]).sum()
    });
    let reduced_unit = v.tr_mul(&DVector::from_column_slice(unit));
    let mut stepper = ReducedStepper::new(tier.model.clone(), newton)?;
    let mut out = Vec::with_capacity(steps * rows.len());
    for k in 0..steps {
        let m = history.at(k as f64 * dt);
        stepper.step(&(&reduced_unit * m))?;
        out.extend((&p * stepper.coordinates()).iter());
    }
    Ok(out)
}

/// ‖other − reference‖ / ‖reference‖ (Euclidean over all values; 0 when both are zero, +∞
/// when only the reference is).
pub fn relative_l2(reference: &[f64], other: &[f64]) -> f64 {
    let (err, norm) = reference
        .iter()
        .zip(other)
        .fold((0.0, 0.0), |(e, n), (a, b)| {
            (e + (b - a) * (b - a), n + a * a)
        });
    if norm > 0.0 {
        (err / norm).sqrt()
    } else if err > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// The time-discretisation figures of one run (module docs), each a relative L2 difference.
#[derive(Clone, Debug, PartialEq)]
pub struct RunTimeError {
    /// The run's label.
    pub label: String,
    /// Tier against the full-order model at Δt (same scheme): the reduction's error.
    pub reduction: f64,
    /// Tier against the converged reference: what a user sees.
    pub against_converged: f64,
    /// Full-order Wilson-θ at Δt against the converged reference: the step's own error.
    pub step: f64,
    /// Full-order Wilson-θ at Δt/2 (load held per scene step, no restart) against the
    /// converged reference: with [`RunTimeError::step`], the step error's order.
    pub step_half: f64,
    /// Full-order Wilson-θ at Δt with the acceleration restarted where the load changes
    /// (what a restart alone, without a finer step, would give) against the converged
    /// reference (+∞ when that run diverged).
    pub step_restarted: f64,
    /// The reference's own error estimate: a third of its difference from the run at Δt/(N/2).
    pub reference_error: f64,
    /// Convergence ratio of the reference: ‖y(Δt/(N/4)) − y(Δt/(N/2))‖ over
    /// ‖y(Δt/(N/2)) − y(Δt/N)‖ (4 for second order).
    pub reference_ratio: f64,
    /// Sub-steps N of the converged reference.
    pub substeps: usize,
}

impl RunTimeError {
    /// The measured order of the step's own error, log₂(step / step_half).
    pub fn step_order(&self) -> f64 {
        (self.step / self.step_half).log2()
    }

    /// The Δt (s) at which the full-order Wilson-θ step's own error would meet `tolerance`
    /// (relative), extrapolated from `dt` with the measured order ([`Self::step_order`], or 2
    /// when that is not a positive finite number). `dt` itself when it already meets it.
    pub fn dt_for(&self, dt: f64, tolerance: f64) -> f64 {
        if self.step <= tolerance {
            return dt;
        }
        let order = match self.step_order() {
            p if p.is_finite() && p > 0.0 => p,
            _ => 2.0,
        };
        dt * (tolerance / self.step).powf(1.0 / order)
    }
}

/// Measures [`RunTimeError`] on `run` of `plan` (the tier's training plan, its steps
/// `plan.steps(Δt)`): the tier stepped with `newton`, the full-order model at Δt (without and
/// with the restart), at Δt/2 and the
/// reference at Δt/N, Δt/(N/2), Δt/(N/4) (`substeps` = N, a multiple of 4). Cost: about
/// 1.75 N + 4 training runs of the full-order model.
pub fn measure_run(
    full: &FullOrder,
    plan: &TrainingPlan,
    tier: &Tier,
    newton: ReducedNewton,
    run: &TrainingRun,
    substeps: usize,
) -> Result<RunTimeError, NonlinearError> {
    if substeps < 4 || !substeps.is_multiple_of(4) {
        return Err(NonlinearError::Invalid(format!(
            "converged reference: {substeps} sub-steps, a multiple of 4 (≥ 4) expected"
        )));
    }
    let groups = training::plan_groups(full, plan)?;
    let unit = training::run_load(full, plan, &groups, run);
    let steps = plan.steps(full.wilson.dt);
    let rows = measured_rows(full);
    let full_order =
        |stepping| full_order_response(full, plan, &unit, &run.history, steps, stepping, &rows);
    let same = full_order(Substepping::SAME_SCHEME)?;
    let half = full_order(Substepping {
        substeps: 2,
        restart: false,
    })?;
    // Restarting every scene step at Δt is not Wilson-θ's unconditionally stable scheme any
    // more: it can diverge (measured), which is a figure here, not a failure.
    let restarted = full_order(Substepping::converged(1)).ok();
    let converged = full_order(Substepping::converged(substeps))?;
    let coarser = full_order(Substepping::converged(substeps / 2))?;
    let coarsest = full_order(Substepping::converged(substeps / 4))?;
    let reduced = tier_response(tier, newton, &unit, &run.history, steps, &rows)?;
    let fine_gap = relative_l2(&converged, &coarser);
    // ‖y(N/4) − y(N/2)‖ / ‖y(N/2) − y(N)‖, both relative to the reference's norm.
    let coarse_step = relative_l2(&coarser, &coarsest) * norm(&coarser) / norm(&converged);
    Ok(RunTimeError {
        label: run.label.clone(),
        reduction: relative_l2(&same, &reduced),
        against_converged: relative_l2(&converged, &reduced),
        step: relative_l2(&converged, &same),
        step_half: relative_l2(&converged, &half),
        step_restarted: restarted.map_or(f64::INFINITY, |r| relative_l2(&converged, &r)),
        reference_error: fine_gap / 3.0,
        reference_ratio: coarse_step / fine_gap,
        substeps,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_l2_and_dt_for() {
        assert_eq!(relative_l2(&[3.0, 4.0], &[3.0, 4.0]), 0.0);
        assert!((relative_l2(&[3.0, 4.0], &[3.0, 4.5]) - 0.1).abs() < 1e-15);
        assert_eq!(relative_l2(&[0.0], &[0.0]), 0.0);
        assert_eq!(relative_l2(&[0.0], &[1.0]), f64::INFINITY);
        let e = RunTimeError {
            label: "x".into(),
            reduction: 0.0,
            against_converged: 0.0,
            step: 0.04,
            step_half: 0.01,
            step_restarted: 0.0,
            reference_error: 0.0,
            reference_ratio: 4.0,
            substeps: 16,
        };
        assert!((e.step_order() - 2.0).abs() < 1e-12);
        // Second order: a quarter of the error at half the step.
        assert!((e.dt_for(1e-3, 0.01) - 0.5e-3).abs() < 1e-15);
        assert_eq!(e.dt_for(1e-3, 0.05), 1e-3);
    }
}
