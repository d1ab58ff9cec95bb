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
//! The rule measures out of sample with at least five training runs. With fewer (a scene that
//! lists one or two load cases: 4 or 8 runs) no run can be held out, and each rung is measured
//! in-sample instead: a tier built as the rung says from all the runs, re-run on every run
//! ([`self_check::self_check`] at the same threshold). In-sample is optimistic, so a rung that
//! fails it fails out of sample too. With a training run that failed (a held-out one, or any
//! when measuring in-sample), the first rung is used unmeasured. The training is run once; each rung costs one ECSW and four to ten reduced runs.

use crate::full_order::FullOrder;

use super::basis::BasisChoice;
use super::ecsw::EcswOptions;
use super::reduced::ReducedNewton;
use super::self_check::{self, percent, OutOfSample, SelfCheck, OUT_OF_SAMPLE_THRESHOLD};
use super::tier as tier_build;
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
/// and × 2 with the tolerance × 1/5 and 20 elements per basis vector at most, then r × 1.5 with
/// the tolerance × 1/50: where the cubature, not the basis, is what misses (the twist of
/// `models/twist/`, a couple pressed into six nodes per half face: r = 30 is 6.7 % off at
/// ECSW 1e-3 and 0.55 % at 1e-4, docs/results/tier.md §8).
pub const LADDER: [Rung; 4] = [
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
    Rung {
        order: 30,
        ecsw_tolerance: 1e-4,
        ecsw_max_elements: 600,
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
    /// in training).
    pub out_of_sample: Option<OutOfSample>,
    /// With fewer than five training runs: its in-sample check (module doc). When both are
    /// None the first rung is used unmeasured.
    pub in_sample: Option<SelfCheck>,
    /// Every rung measured, in ladder order, with its worst held-out error (+∞ for a failed
    /// reduced run).
    pub tried: Vec<(Rung, f64)>,
    /// When a rung's order was above the snapshots the training kept (runs cut, or a short
    /// training): that count, the order it was capped at ([`capped_ladder`]).
    pub snapshot_cap: Option<usize>,
}

/// The rungs of `ladder` with each order capped at the `kept` training snapshots (a POD has at
/// most as many vectors as snapshots, so a larger rung would be measured and reported as a
/// size the tier cannot have), a rung equal to an earlier one after the cap left out; and
/// whether any order was capped. The out-of-sample check builds its tier from about four fifths
/// of the runs, so a rung near the cap can still have fewer vectors there than its order.
pub fn capped_ladder(ladder: &[Rung], kept: usize) -> (Vec<Rung>, bool) {
    let mut rungs: Vec<Rung> = Vec::with_capacity(ladder.len());
    let mut capped = false;
    for rung in ladder {
        let order = rung.order.min(kept.max(1));
        capped |= order < rung.order;
        let rung = Rung { order, ..*rung };
        if !rungs.contains(&rung) {
            rungs.push(rung);
        }
    }
    (rungs, capped)
}

impl Fidelity {
    /// Whether the chosen rung meets the threshold (false when not measured).
    pub fn met(&self) -> bool {
        self.out_of_sample
            .as_ref()
            .map(|o| &o.check)
            .or(self.in_sample.as_ref())
            .is_some_and(|c| c.flagged().is_empty())
    }

    /// The report note (deterministic).
    pub fn note(&self) -> String {
        match self.snapshot_cap {
            Some(kept) => format!(
                "{}; its sizes are capped at the {kept} snapshots the training kept (a basis has \
                 at most as many vectors as snapshots: cut runs, or lengthen the runs or lower \
                 `every` for more)",
                self.rule_note()
            ),
            None => self.rule_note(),
        }
    }

    fn rule_note(&self) -> String {
        let tried = self
            .tried
            .iter()
            .map(|(rung, worst)| {
                let how = if self.in_sample.is_some() {
                    "in-sample"
                } else {
                    "held-out"
                };
                format!("{}: worst {how} {}", rung.label(), percent(*worst))
            })
            .collect::<Vec<_>>()
            .join("; ");
        if self.in_sample.is_some() {
            return if self.met() {
                format!(
                    "co-rotational tier fidelity rule (docs/design.md §10): {} chosen, the first \
                     size whose training runs are all within {} measured in-sample (fewer than \
                     five training runs: none can be held out; {tried})",
                    self.rung.label(),
                    percent(OUT_OF_SAMPLE_THRESHOLD)
                )
            } else {
                format!(
                    "WARNING: co-rotational tier fidelity rule (docs/design.md §10): no size \
                     reproduces its own training runs within {} ({tried}; in-sample: fewer than \
                     five training runs); {} is used, the most accurate. Set `basis_tolerance` \
                     (with `max_order`), or `order` with a tighter `ecsw_tolerance`, in \
                     [reduction.corotational]",
                    percent(OUT_OF_SAMPLE_THRESHOLD),
                    self.rung.label()
                )
            };
        }
        match (&self.out_of_sample, self.met()) {
            (None, _) => format!(
                "co-rotational tier fidelity rule (docs/design.md §10): {} used unmeasured, the \
                 training has a failed run",
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
    let kept = training.snapshots.len();
    let (ladder, capped) = capped_ladder(ladder, kept);
    let snapshot_cap = capped.then_some(kept);
    let first = *ladder
        .first()
        .ok_or_else(|| NonlinearError::Invalid("the fidelity rule has no size to try".into()))?;
    let unmeasured = |tried| Fidelity {
        rung: first,
        out_of_sample: None,
        in_sample: None,
        tried,
        snapshot_cap,
    };
    let in_sample = self_check::held_out_runs(training.runs.len()).is_empty();
    if in_sample && training.runs.iter().any(|(_, failed)| failed.is_some()) {
        return Ok(unmeasured(Vec::new()));
    }
    let mut tried = Vec::new();
    let mut best: Option<(Fidelity, f64)> = None;
    for &rung in &ladder {
        let measured = if in_sample {
            let tier = tier_build::from_training_with(
                full,
                training.clone(),
                &rung.basis(),
                &rung.ecsw(),
            )?;
            let check = self_check::self_check(full, plan, &tier, newton, OUT_OF_SAMPLE_THRESHOLD)?;
            Fidelity {
                rung,
                out_of_sample: None,
                in_sample: Some(check),
                tried: Vec::new(),
                snapshot_cap,
            }
        } else {
            let Some(held) = self_check::out_of_sample(
                full,
                plan,
                training,
                &rung.basis(),
                &rung.ecsw(),
                newton,
            )?
            else {
                return Ok(unmeasured(tried));
            };
            Fidelity {
                rung,
                out_of_sample: Some(held),
                in_sample: None,
                tried: Vec::new(),
                snapshot_cap,
            }
        };
        let check = measured
            .out_of_sample
            .as_ref()
            .map(|o| &o.check)
            .or(measured.in_sample.as_ref());
        let worst = check
            .and_then(|c| c.worst())
            .map_or(f64::INFINITY, |w| w.error);
        tried.push((rung, worst));
        if measured.met() {
            return Ok(Fidelity { tried, ..measured });
        }
        if best.as_ref().is_none_or(|(_, w)| worst < *w) {
            best = Some((measured, worst));
        }
    }
    Ok(match best {
        Some((measured, _)) => Fidelity { tried, ..measured },
        None => unmeasured(tried),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rungs_above_the_kept_snapshots_are_capped_and_not_measured_twice() {
        // Enough snapshots: the ladder as it is.
        let (rungs, capped) = capped_ladder(&LADDER, 10_000);
        assert_eq!(rungs, LADDER.to_vec());
        assert!(!capped);
        // 25 snapshots: r = 20 stays, r = 30 and 40 become 25; the three r = 25 rungs differ
        // in their cubature (1e-3 with 600 and 800 elements, 1e-4 with 600), so all are kept.
        let (rungs, capped) = capped_ladder(&LADDER, 25);
        assert!(capped);
        let orders: Vec<usize> = rungs.iter().map(|r| r.order).collect();
        assert_eq!(orders, [20, 25, 25, 25]);
        // 12 snapshots: every rung at r = 12, each distinct cubature once.
        let (rungs, _) = capped_ladder(&LADDER, 12);
        assert!(rungs.iter().all(|r| r.order == 12));
        let same = Rung {
            order: 12,
            ..LADDER[1]
        };
        assert_eq!(rungs.iter().filter(|r| **r == same).count(), 1);
        // Two rungs equal after the cap: one is measured.
        let twins = [
            Rung {
                order: 30,
                ..LADDER[1]
            },
            Rung {
                order: 40,
                ..LADDER[1]
            },
        ];
        let (rungs, capped) = capped_ladder(&twins, 20);
        assert!(capped);
        assert_eq!(
            rungs,
            vec![Rung {
                order: 20,
                ..LADDER[1]
            }]
        );
    }
}
