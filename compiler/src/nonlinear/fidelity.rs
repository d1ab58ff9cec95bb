//! The tier's fidelity rule (docs/design.md §10, "Fidelity rule"): when a scene states none of
//! `order`, `basis_tolerance`, `ecsw_tolerance` and `ecsw_max_elements`, the compiler chooses
//! the basis size and the cubature's accuracy on measured numbers, as the linear model's order
//! rule chooses r on its measured error.
//!
//! The candidates are the [`LADDER`]'s rungs, from the cheapest. Each rung is measured by the
//! out-of-sample check ([`self_check::out_of_sample`]: a tier built as the rung says from the
//! training without every fifth run, re-run on those runs against their full-order snapshots),
//! and the first rung whose held-out runs are all within [`OUT_OF_SAMPLE_THRESHOLD`] is
//! chosen. When none is, the rung with the smallest worst held-out error is (the first among
//! equals), and the compile warns. A larger basis pays only with a more accurate cubature:
//! ECSW's residual is relative to the whole reduced force, which the leading modes dominate, so
//! at a fixed tolerance the added modes' forces are the least accurate part (measured on the
//! blob of `models/bodies/`: r = 20 / 30 / 40 at ECSW 5e-3 reproduce its own training to
//! 5.0 / 7.0 / 13.5 %, r = 30 at 1e-3 to 1.6 %). Every rung above the first therefore
//! tightens the tolerance with the order.
//!
//! The rule needs the out-of-sample check, hence at least five training runs; with fewer
//! (or a held-out run that failed in training) the first rung is used, as before the rule.
//! The training is run once; each rung costs one ECSW and four to ten reduced runs.

use crate::full_order::FullOrder;

use super::basis::BasisChoice;
use super::ecsw::EcswOptions;
use super::reduced::ReducedNewton;
use super::self_check::{self, percent, OutOfSample, OUT_OF_SAMPLE_THRESHOLD};
use super::training::{Training, TrainingPlan};
use super::NonlinearError;

/// One candidate size of the tier.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rung {
    /// Pooled POD vectors r.
    pub order: usize,
    /// ECSW relative tolerance on the training forces.
    pub ecsw_tolerance: f64,
    /// Most sampled elements.
    pub ecsw_max_elements: usize,
}

/// The rungs, cheapest first: the defaults (r = 20, ECSW 5e-3, ≤ 200 elements), then r × 1.5
/// and × 2 with the tolerance × 1/5 and 20 elements per basis vector at most.
pub const LADDER: [Rung; 3] = [
    Rung {
        order: crate::scene::DEFAULT_TIER_ORDER,
        ecsw_tolerance: crate::scene::DEFAULT_ECSW_TOLERANCE,
        ecsw_max_elements: crate::scene::DEFAULT_ECSW_MAX_ELEMENTS,
    },
    Rung {
        order: 30,
        ecsw_tolerance: 1e-3,
        ecsw_max_elements: 600,
    },
    Rung {
        order: 40,
        ecsw_tolerance: 1e-3,
        ecsw_max_elements: 800,
    },
];

impl Rung {
    /// The pooled POD basis of this size.
    pub fn basis(&self) -> BasisChoice {
        BasisChoice::pod(self.order)
    }

    /// The ECSW options of this rung.
    pub fn ecsw(&self) -> EcswOptions {
        EcswOptions {
            tolerance: self.ecsw_tolerance,
            max_elements: self.ecsw_max_elements,
            ..EcswOptions::default()
        }
    }

    /// `r = 30, ECSW 1e-3 (≤ 600 elements)`.
    pub fn label(&self) -> String {
        format!(
            "r = {}, ECSW {:.0e} (≤ {} elements)",
            self.order, self.ecsw_tolerance, self.ecsw_max_elements
        )
    }
}

/// What the rule chose and measured.
#[derive(Clone, Debug)]
pub struct Fidelity {
    /// The chosen rung.
    pub rung: Rung,
    /// Its out-of-sample check (None: fewer than five training runs, or a held-out run failed
    /// in training; the first rung is then used unmeasured).
    pub out_of_sample: Option<OutOfSample>,
    /// Every rung measured, in ladder order, with its worst held-out error (+∞ for a failed
    /// reduced run).
    pub tried: Vec<(Rung, f64)>,
}

impl Fidelity {
    /// Whether the chosen rung meets the threshold (false when not measured).
    pub fn met(&self) -> bool {
        self.out_of_sample
            .as_ref()
            .is_some_and(|o| o.check.flagged().is_empty())
    }

    /// The report note (deterministic).
    pub fn note(&self) -> String {
        let tried = self
            .tried
            .iter()
            .map(|(rung, worst)| format!("{}: worst held-out {}", rung.label(), percent(*worst)))
            .collect::<Vec<_>>()
            .join("; ");
        match (&self.out_of_sample, self.met()) {
            (None, _) => format!(
                "co-rotational tier fidelity rule (docs/design.md §10): {} used unmeasured, the \
                 out-of-sample check needs five completed training runs",
                self.rung.label()
            ),
            (Some(_), true) => format!(
                "co-rotational tier fidelity rule (docs/design.md §10): {} chosen, the first \
                 size whose held-out training runs are all within {} ({tried})",
                self.rung.label(),
                percent(OUT_OF_SAMPLE_THRESHOLD)
            ),
            (Some(_), false) => format!(
                "WARNING: co-rotational tier fidelity rule (docs/design.md §10): no size meets \
                 {} on the held-out training runs ({tried}); {} is used, the most accurate. \
                 Set `basis_tolerance` (with `max_order`), or `order` with a tighter \
                 `ecsw_tolerance`, in [reduction.corotational]",
                percent(OUT_OF_SAMPLE_THRESHOLD),
                self.rung.label()
            ),
        }
    }
}

/// Measures the [`LADDER`]'s rungs on `training` (module docs) and chooses one.
pub fn choose(
    full: &FullOrder,
    plan: &TrainingPlan,
    training: &Training,
    newton: ReducedNewton,
) -> Result<Fidelity, NonlinearError> {
    choose_from(&LADDER, full, plan, training, newton)
}

/// [`choose`] on the rungs of `ladder`, cheapest first (not empty).
pub fn choose_from(
    ladder: &[Rung],
    full: &FullOrder,
    plan: &TrainingPlan,
    training: &Training,
    newton: ReducedNewton,
) -> Result<Fidelity, NonlinearError> {
    let first = *ladder
        .first()
        .ok_or_else(|| NonlinearError::Invalid("the fidelity rule has no size to try".into()))?;
    let mut tried = Vec::new();
    let mut best: Option<(Rung, OutOfSample, f64)> = None;
    for &rung in ladder {
        let Some(held) =
            self_check::out_of_sample(full, plan, training, &rung.basis(), &rung.ecsw(), newton)?
        else {
            return Ok(Fidelity {
                rung: first,
                out_of_sample: None,
                tried,
            });
        };
        let worst = held.check.worst().map_or(f64::INFINITY, |w| w.error);
        tried.push((rung, worst));
        if held.check.flagged().is_empty() {
            return Ok(Fidelity {
                rung,
                out_of_sample: Some(held),
                tried,
            });
        }
        if best.as_ref().is_none_or(|(_, _, w)| worst < *w) {
            best = Some((rung, held, worst));
        }
    }
    Ok(match best {
        Some((rung, held, _)) => Fidelity {
            rung,
            out_of_sample: Some(held),
            tried,
        },
        None => Fidelity {
            rung: first,
            out_of_sample: None,
            tried,
        },
    })
}
