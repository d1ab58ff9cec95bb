//! What the co-rotational tier's build finds on its way, as typed values for the compile's
//! report: loads with a range that no training run loads, training runs that failed or were
//! cut, a stated tier size whose order is above the snapshots the training kept, and what a
//! case cache contributed. The report's prose on them is the compile's
//! (`compile::tier_notes`).

use std::path::PathBuf;

use crate::nonlinear::training::{Cut, Training, TrainingPlan};
use crate::scene::CorotationalSpec;

/// What the tier's training found, for the compile report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TierFindings {
    /// Loads with a range that no training run loads (no `[[reduction.corotational.case]]`
    /// names them), by name in the order of the scene's `ranges`: the tier is not trained on
    /// them.
    pub untrained_loads: Vec<String>,
    /// Training runs that failed and were skipped, in run order.
    pub failed_runs: Vec<FailedRun>,
    /// Training runs cut where their load drove the body past what the tier is for, in run
    /// order.
    pub cut_runs: Vec<CutRun>,
    /// Training runs in all (failed and cut ones included).
    pub runs: usize,
    /// The largest element rotation a kept snapshot may reach, degrees (the plan's
    /// `max_rotation`, past which a run is cut).
    pub max_rotation: f64,
    /// The scene's stated tier size asks for an order above the snapshots the training kept
    /// (None: it does not, or the fidelity rule chose the size).
    pub order_above_snapshots: Option<OrderAboveSnapshots>,
}

/// A training run that failed and was skipped.
#[derive(Clone, Debug, PartialEq)]
pub struct FailedRun {
    /// The run's label.
    pub label: String,
    /// Why it failed.
    pub reason: String,
}

/// A training run cut at its first snapshot past what the tier is for.
#[derive(Clone, Debug, PartialEq)]
pub struct CutRun {
    /// The run's label.
    pub label: String,
    /// Where and why it was cut.
    pub cut: Cut,
}

/// A tier order above the snapshots the training kept: the basis has at most `kept` vectors.
#[derive(Clone, Debug, PartialEq)]
pub struct OrderAboveSnapshots {
    /// The tier's order.
    pub order: usize,
    /// Whether the scene states it (`[reduction.corotational] order`); else it is the default.
    pub stated: bool,
    /// Snapshots the training kept.
    pub kept: usize,
    /// Training runs cut or failed.
    pub cut_or_failed: usize,
    /// Training runs in all.
    pub runs: usize,
}

/// What a case cache contributed to the training.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheUse {
    /// Case files that could not be used or stored (their runs were computed all the same).
    pub unusable: Vec<String>,
    /// Training runs read from the cache.
    pub cached: usize,
    /// Training runs in all.
    pub runs: usize,
    /// The cache's folder.
    pub dir: PathBuf,
}

impl TierFindings {
    /// The findings of `training`, run on `plan` from the scene's `spec`: untrained loads,
    /// failed and cut runs (no order check: [`OrderAboveSnapshots::of`]).
    pub fn of_training(spec: &CorotationalSpec, plan: &TrainingPlan, training: &Training) -> Self {
        let untrained_loads = spec
            .ranges
            .keys()
            .filter(|name| !plan.ranges.iter().any(|(n, _)| n == *name))
            .cloned()
            .collect();
        let failed_runs = training
            .runs
            .iter()
            .filter_map(|(label, failed)| {
                failed.as_ref().map(|reason| FailedRun {
                    label: label.clone(),
                    reason: reason.clone(),
                })
            })
            .collect();
        let cut_runs = training
            .runs
            .iter()
            .zip(&training.cuts)
            .filter_map(|((label, _), cut)| {
                cut.as_ref().map(|cut| CutRun {
                    label: label.clone(),
                    cut: cut.clone(),
                })
            })
            .collect();
        TierFindings {
            untrained_loads,
            failed_runs,
            cut_runs,
            runs: training.runs.len(),
            max_rotation: plan.max_rotation,
            order_above_snapshots: None,
        }
    }
}

impl OrderAboveSnapshots {
    /// The tier order `order` (`stated` in the scene, or the default) against the snapshots
    /// `training` kept; None when they are enough.
    pub fn of(order: usize, stated: bool, training: &Training) -> Option<Self> {
        let kept = training.snapshots.len();
        (order > kept).then(|| OrderAboveSnapshots {
            order,
            stated,
            kept,
            cut_or_failed: training
                .cuts
                .iter()
                .zip(&training.runs)
                .filter(|(c, (_, failed))| c.is_some() || failed.is_some())
                .count(),
            runs: training.runs.len(),
        })
    }
}

impl CacheUse {
    /// What the cache at `dir` contributed to `training` of `runs` runs.
    pub fn of(training: &Training, runs: usize, dir: PathBuf) -> Self {
        CacheUse {
            unusable: training.cache_notes.clone(),
            cached: training.cached,
            runs,
            dir,
        }
    }
}
