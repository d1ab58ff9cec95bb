// Over 800 lines, one job: the advice rules and their wording (500 lines); the rest is their tests, one per rule.
//! What to change when a filtered run is not consistent: a small table of rules from the N-run
//! figures ([`super::SeedEnsemble`], per segment [`super::segments`]) to one line of advice per
//! problem, naming the parameter that is off, its direction, the scene field or command that
//! fixes it, and the figure that triggered it. [`advise`] is a pure function of
//! [`AdviceFigures`]; [`table_markdown`] renders the table itself.
//!
//! What each statistic can tell (docs/design.md §11.3):
//! - NIS compares the innovations with S = H P⁻ Hᵀ + R, what the filter predicts of the markers.
//!   Above its bounds: R or P⁻ too small (markers noisier than `noise_std`, or process noise —
//!   the force σ, the model error — too small); below: R or P⁻ too large. It cannot tell R from
//!   P⁻; where the markers are drawn with the scene's own `noise_std` (the report's synthetic
//!   markers) R is right by construction and only P⁻ is left.
//! - Tip NEES compares the posterior error at the tip marker with P. Above while the NIS is
//!   inside: the error lies where the markers do not see it well. Where it lies in time tells
//!   the cause: above while the load changes (a ramp, a step, a release) and not while it
//!   holds is the estimate lagging the load (force σ too small for its rate); above while the
//!   load holds (the largest deflection), or anywhere when the filter is given the loads
//!   (its estimate cannot lag them), is the model's own error — unless the model's own
//!   error, measured open loop with the loads given, is far below the filter's: then what σ
//!   misses is the estimate of the load (a force σ too small leaves it lagging long after the
//!   load stopped changing), not the model.
//! - 2σ coverage tests σ over every displayed node, mostly far from the markers. Below 90 %
//!   with the NIS inside: the model's error in the shape away from the markers is not in σ
//!   (with the same exception). Above 98 %: σ larger than the error there.
//!
//! Thresholds: a statistic is off when more than [`OUTSIDE_LIMIT`] of its steps lie beyond one
//! of its 95 % bounds (a consistent filter: ≈ 2.5 % on each side); the 2σ coverage's target is
//! [`COVERAGE_LOW`]–[`COVERAGE_HIGH`] (a Gaussian's: 95.4 %); NEES above is laid to the load's
//! changes or holds when its rate (steps above / steps) in one kind of segment is at least
//! [`DOMINANCE`] times that in the other, else to both; the model is cleared when the filtered
//! error is more than [`DOMINANCE`] times its own.

use std::fmt::Write as _;

use super::consistency::StepFractions;
use super::segments::SegmentFigures;

/// Largest fraction of steps beyond one 95 % bound of a consistent statistic (≈ 2.5 %
/// expected).
pub const OUTSIDE_LIMIT: f64 = 0.05;

/// Lowest acceptable 2σ coverage.
pub const COVERAGE_LOW: f64 = 0.90;

/// Highest acceptable 2σ coverage.
pub const COVERAGE_HIGH: f64 = 0.98;

/// Ratio of NEES-above rates (where the load changes / where it holds, or the reverse) that
/// lays the excess to one kind of segment.
pub const DOMINANCE: f64 = 2.0;

/// The command that identifies σ from a recording.
pub const IDENTIFY: &str =
    "crokf-compile identify SCENE MODEL --measurements M.csv [--inputs I.csv]";

/// The model tier of the row advised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tier {
    /// The warped linear model.
    Warped,
    /// The co-rotational tier.
    Corotational,
}

/// The figures of one filtered run (over N noise draws) that the rules read.
#[derive(Clone, Debug)]
pub struct AdviceFigures<'a> {
    /// The row's tier.
    pub tier: Tier,
    /// True when the markers were drawn with the scene's own `noise_std` (the report's
    /// synthetic markers): R is then right by construction.
    pub markers_from_noise_std: bool,
    /// True when the filter got the scenario's loads as inputs (exactly): its estimate cannot
    /// lag them, and what σ misses is the model's error.
    pub loads_given: bool,
    /// N-run NIS over the whole run.
    pub nis: StepFractions,
    /// N-run tip NEES over the whole run (`steps` 0 without a tip).
    pub nees_tip: StepFractions,
    /// Mean 2σ coverage (runtime σ) over the runs; NaN without displayed nodes.
    pub coverage: f64,
    /// Mean relative L2 error of the filtered runs over the displayed nodes.
    pub filtered_error: f64,
    /// The model's own error, when known: the open-loop run's relative L2 error with the loads
    /// given, against the same reference.
    pub model_error: Option<f64>,
    /// The same per segment of the scenario.
    pub segments: &'a [SegmentFigures],
    /// The scenario's loads (names of the scene's `[[load]]`), for the fixes' text.
    pub loads: &'a [String],
    /// Fraction of the steps after whose update the filter carried its own covariance (an
    /// active channel missing or gated, docs/design.md §11.11; `Estimator::tier_covariance`).
    pub own_covariance: f64,
}

/// A row of the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    /// Tip NEES above, mostly where the load changes.
    ForceSigmaTooSmallForChanges,
    /// Tip NEES above mostly where the load holds, or coverage low with the NIS not above.
    ModelErrorNotInSigma,
    /// Tip NEES above where the load changes and holds alike.
    SigmaTooSmallThroughout,
    /// NIS above.
    InnovationsLargerThanPredicted,
    /// NIS below.
    Conservative,
    /// Coverage high with the NIS not below.
    ConservativeAwayFromMarkers,
    /// Channels missing or gated: the filter ran on its own covariance for part of the run.
    ChannelsMissing,
}

/// One line of advice: the rule and the figures that triggered it.
#[derive(Clone, Debug, PartialEq)]
pub struct Advice {
    /// The rule.
    pub rule: Rule,
    /// The figures, in words (e.g. `tip NEES above its bound on 12.3 % of the steps (> 5 %)`).
    pub trigger: String,
}

/// A percentage with one decimal.
fn pc(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

/// Steps above the bound and steps, over the segments whose loads change (`changing`) or hold.
fn nees_above(segments: &[SegmentFigures], changing: bool) -> (f64, usize) {
    segments
        .iter()
        .filter(|s| s.segment.change.changing() == changing)
        .fold((0.0, 0), |(above, steps), s| {
            (
                above + s.nees_tip.above * s.nees_tip.steps as f64,
                steps + s.nees_tip.steps,
            )
        })
}

/// The advice for one filtered run: one item per problem, in the table's order (module docs).
pub fn advise(f: &AdviceFigures) -> Vec<Advice> {
    let mut out: Vec<Advice> = Vec::new();
    // First, as the context of the others: their figures include these steps.
    if f.own_covariance > 0.0 {
        out.push(Advice {
            rule: Rule::ChannelsMissing,
            trigger: format!(
                "the filter carried its own covariance after {} of the updates",
                pc(f.own_covariance)
            ),
        });
    }
    let nis_steps = f.nis.steps > 0;
    let nees_steps = f.nees_tip.steps > 0;
    let nis_above = nis_steps && f.nis.above > OUTSIDE_LIMIT;
    let nis_below = nis_steps && f.nis.below > OUTSIDE_LIMIT;
    // The filtered error far above the model's own: what σ misses is the estimate of the
    // load, not the model.
    let not_the_model = f
        .model_error
        .filter(|&m| f.filtered_error > DOMINANCE * m)
        .map(|m| {
            format!(
                "filtered error {} > {DOMINANCE}× the model's own {} (open loop with the loads)",
                pc(f.filtered_error),
                pc(m)
            )
        });
    // Tip NEES above: laid to the load's changes, its holds, or both.
    if nees_steps && f.nees_tip.above > OUTSIDE_LIMIT {
        let (ca, cs) = nees_above(f.segments, true);
        let (ha, hs) = nees_above(f.segments, false);
        let rate = |a: f64, s: usize| (s > 0).then(|| a / s as f64);
        let (changing, holding) = (rate(ca, cs), rate(ha, hs));
        let mut trigger = format!(
            "tip NEES above its bound on {} of the steps (> {})",
            pc(f.nees_tip.above),
            pc(OUTSIDE_LIMIT)
        );
        let part = |r: Option<f64>, s: usize, where_: &str| {
            r.map(|r| format!("{} of the {s} steps where the load {where_}", pc(r)))
        };
        let parts: Vec<String> = [part(changing, cs, "changes"), part(holding, hs, "holds")]
            .into_iter()
            .flatten()
            .collect();
        if !parts.is_empty() {
            let _ = write!(trigger, ": {}", parts.join(", "));
        }
        let rule = if let Some(why) = &not_the_model {
            let _ = write!(trigger, "; {why}");
            Rule::ForceSigmaTooSmallForChanges
        } else if f.loads_given {
            trigger.push_str("; the filter is given the loads, its estimate cannot lag them");
            Rule::ModelErrorNotInSigma
        } else {
            match (changing, holding) {
                (Some(_), None) => Rule::ForceSigmaTooSmallForChanges,
                (None, Some(_)) => Rule::ModelErrorNotInSigma,
                (Some(c), Some(h)) if c >= DOMINANCE * h => Rule::ForceSigmaTooSmallForChanges,
                (Some(c), Some(h)) if h >= DOMINANCE * c => Rule::ModelErrorNotInSigma,
                _ => Rule::SigmaTooSmallThroughout,
            }
        };
        out.push(Advice { rule, trigger });
    }
    // Coverage low while the markers' innovations are not too large: the model's error away
    // from the markers, unless the model's own error is far below the filter's.
    if f.coverage < COVERAGE_LOW && nis_steps && !nis_above {
        let mut trigger = format!(
            "2σ coverage {} (< {}) with NIS above its bound on only {} of the steps",
            pc(f.coverage),
            pc(COVERAGE_LOW),
            pc(f.nis.above)
        );
        let rule = match &not_the_model {
            Some(why) => {
                if !out.iter().any(|a| a.trigger.contains(why.as_str())) {
                    let _ = write!(trigger, "; {why}");
                }
                Rule::ForceSigmaTooSmallForChanges
            }
            None => Rule::ModelErrorNotInSigma,
        };
        match out.iter_mut().find(|a| a.rule == rule) {
            Some(a) => {
                let _ = write!(a.trigger, "; {trigger}");
            }
            None => out.push(Advice { rule, trigger }),
        }
    }
    if nis_above {
        out.push(Advice {
            rule: Rule::InnovationsLargerThanPredicted,
            trigger: format!(
                "NIS above its bound on {} of the steps (> {})",
                pc(f.nis.above),
                pc(OUTSIDE_LIMIT)
            ),
        });
    }
    if nis_below {
        let mut trigger = format!(
            "NIS below its bound on {} of the steps (> {})",
            pc(f.nis.below),
            pc(OUTSIDE_LIMIT)
        );
        if nees_steps && f.nees_tip.below > OUTSIDE_LIMIT {
            let _ = write!(trigger, ", tip NEES below on {}", pc(f.nees_tip.below));
        }
        if f.coverage > COVERAGE_HIGH {
            let _ = write!(trigger, ", 2σ coverage {}", pc(f.coverage));
        }
        out.push(Advice {
            rule: Rule::Conservative,
            trigger,
        });
    } else if f.coverage > COVERAGE_HIGH {
        out.push(Advice {
            rule: Rule::ConservativeAwayFromMarkers,
            trigger: format!(
                "2σ coverage {} (> {}){}",
                pc(f.coverage),
                pc(COVERAGE_HIGH),
                if nis_steps {
                    format!(" with NIS below its bound on only {}", pc(f.nis.below))
                } else {
                    String::new()
                }
            ),
        });
    }
    out
}

/// What the texts of a rule are written for: a run's tier and markers and the scenario's loads,
/// or (for the table) any.
#[derive(Clone, Copy, Debug)]
pub struct Context<'a> {
    /// The row's tier; `None`: both fixes.
    pub tier: Option<Tier>,
    /// The markers were drawn with the scene's `noise_std`.
    pub markers_from_noise_std: bool,
    /// The filter was given the loads.
    pub loads_given: bool,
    /// Load names for the fixes (empty: "the `[[load]]`").
    pub loads: &'a [String],
}

impl<'a> From<&AdviceFigures<'a>> for Context<'a> {
    fn from(f: &AdviceFigures<'a>) -> Self {
        Context {
            tier: Some(f.tier),
            markers_from_noise_std: f.markers_from_noise_std,
            loads_given: f.loads_given,
            loads: f.loads,
        }
    }
}

impl Context<'_> {
    /// `` `[[load]]` 'tip' `` or `` the `[[load]]` ``.
    fn load(&self) -> String {
        if self.loads.is_empty() {
            "the `[[load]]`".into()
        } else {
            let names: Vec<String> = self.loads.iter().map(|n| format!("'{n}'")).collect();
            format!("`[[load]]` {}", names.join(", "))
        }
    }

    /// The fix of a lagging force σ.
    fn shorter_rise_time(&self) -> String {
        format!(
            "state a shorter `rise_time` on {} (the compiler derives the force σ from `range` \
             and `rise_time`), or identify σ from a recording: `{IDENTIFY}`",
            self.load()
        )
    }

    /// The fix of a model error not in σ, for the tier.
    fn model_fix(&self) -> String {
        let corotational = "raise the tier's `order` or set its `basis_tolerance` \
             (`[reduction.corotational]`), or train it on the loads the body meets \
             (`[reduction.corotational] directions`, or `[[reduction.corotational.case]]` for \
             loads that act together)";
        let warped = "use the co-rotational tier (`[reduction] model = \"corotational\"`: the \
             warped model's error grows with the rotation) or raise `[reduction] order`";
        match self.tier {
            Some(Tier::Corotational) => corotational.into(),
            Some(Tier::Warped) => warped.into(),
            None => format!("co-rotational tier: {corotational}; warped tier: {warped}"),
        }
    }
}

impl Rule {
    /// Every rule, in the table's order.
    pub const ALL: [Rule; 7] = [
        Rule::ForceSigmaTooSmallForChanges,
        Rule::ModelErrorNotInSigma,
        Rule::SigmaTooSmallThroughout,
        Rule::InnovationsLargerThanPredicted,
        Rule::Conservative,
        Rule::ConservativeAwayFromMarkers,
        Rule::ChannelsMissing,
    ];

    /// When the rule fires, in words (the table's first column).
    pub fn when(self) -> String {
        let limit = pc(OUTSIDE_LIMIT);
        match self {
            Rule::ForceSigmaTooSmallForChanges => format!(
                "tip NEES above its bound on > {limit} of the steps, at a rate ≥ {DOMINANCE}× \
                 higher where the load changes than where it holds (loads withheld from the \
                 filter), or anywhere with the filtered \
                 error > {DOMINANCE}× the model's own (open loop with the loads); or 2σ coverage \
                 < {} with NIS above on ≤ {limit} and that filtered error",
                pc(COVERAGE_LOW)
            ),
            Rule::ModelErrorNotInSigma => format!(
                "tip NEES above on > {limit} of the steps, at a rate ≥ {DOMINANCE}× higher where \
                 the load holds, or anywhere with the loads given to the filter; or 2σ coverage \
                 < {} with NIS above on ≤ {limit} (in all cases unless the filtered error is > \
                 {DOMINANCE}× the model's own)",
                pc(COVERAGE_LOW)
            ),
            Rule::SigmaTooSmallThroughout => format!(
                "tip NEES above on > {limit} of the steps, where the load changes and where it \
                 holds alike (loads withheld, the filtered error not > {DOMINANCE}× the model's \
                 own)"
            ),
            Rule::InnovationsLargerThanPredicted => {
                format!("NIS above its bound on > {limit} of the steps")
            }
            Rule::Conservative => format!(
                "NIS below its bound on > {limit} of the steps (often with tip NEES below, or \
                 2σ coverage > {})",
                pc(COVERAGE_HIGH)
            ),
            Rule::ConservativeAwayFromMarkers => format!(
                "2σ coverage > {} with NIS below on ≤ {limit}",
                pc(COVERAGE_HIGH)
            ),
            Rule::ChannelsMissing => "any update with an active channel missing or gated (the \
                 co-rotational tier)"
                .into(),
        }
    }

    /// What the figures say is off, and in which direction.
    pub fn finding(self, c: &Context) -> String {
        match self {
            Rule::ForceSigmaTooSmallForChanges => {
                "the force σ is too small for how fast this load changes: the estimate lags the \
                 load"
                    .into()
            }
            Rule::ModelErrorNotInSigma => "the reduced model's own error is not in σ".into(),
            Rule::SigmaTooSmallThroughout => {
                "σ is too small where the load changes and where it holds: the force σ, the \
                 model's own error, or both"
                    .into()
            }
            Rule::InnovationsLargerThanPredicted if c.markers_from_noise_std && c.loads_given => {
                "the innovations are larger than the filter predicts; the markers here are drawn \
                 with the scene's `noise_std` and the filter is given the loads, so the model's \
                 own error is not in σ"
                    .into()
            }
            Rule::InnovationsLargerThanPredicted if c.markers_from_noise_std => {
                "the innovations are larger than the filter predicts; the markers here are drawn \
                 with the scene's `noise_std`, so the predicted σ at the markers is too small: \
                 the force σ or the model's own error (the tip NEES line tells which)"
                    .into()
            }
            Rule::InnovationsLargerThanPredicted => {
                "the innovations are larger than the filter predicts: the markers are noisier \
                 than the scene's `noise_std` says, or the force σ is too small"
                    .into()
            }
            Rule::Conservative | Rule::ConservativeAwayFromMarkers if c.loads_given => {
                "conservative: the force states still carry what the given input might not \
                 explain (on the co-rotational tier at its lowest force σ, docs/design.md \
                 §11.10), and the inputs given here are exact"
                    .into()
            }
            Rule::Conservative if c.markers_from_noise_std => {
                "conservative; the markers here are drawn with the scene's `noise_std`, so the \
                 force σ is larger than this load needs (`rise_time` shorter or `range` larger \
                 than the load's)"
                    .into()
            }
            Rule::Conservative => {
                "conservative: `noise_std` is larger than the markers' real noise, or the force \
                 σ larger than this load needs (`rise_time` shorter or `range` larger than the \
                 load's)"
                    .into()
            }
            Rule::ConservativeAwayFromMarkers => {
                "σ away from the markers is larger than the error there: the force σ is larger \
                 than this load needs"
                    .into()
            }
            Rule::ChannelsMissing => {
                "markers were missing or gated: from such an update until its covariance settles \
                 the filter carries its own (docs/design.md §11.11), whose σ grow while a marker \
                 that sees a load is away, so the other lines' figures include steps that are \
                 conservative by design"
                    .into()
            }
        }
    }

    /// The command or scene field that fixes it.
    pub fn fix(self, c: &Context) -> String {
        match self {
            Rule::ForceSigmaTooSmallForChanges => c.shorter_rise_time(),
            Rule::ModelErrorNotInSigma => c.model_fix(),
            Rule::SigmaTooSmallThroughout => format!(
                "first the force σ: {}; if tip NEES stays above where the load holds, the model: \
                 {}",
                c.shorter_rise_time(),
                c.model_fix()
            ),
            Rule::InnovationsLargerThanPredicted if c.markers_from_noise_std && c.loads_given => {
                c.model_fix()
            }
            Rule::InnovationsLargerThanPredicted if c.markers_from_noise_std => {
                c.shorter_rise_time()
            }
            Rule::InnovationsLargerThanPredicted => format!(
                "measure the markers' noise and state it as `noise_std` on each `[[sensor]]`, or \
                 identify σ from a recording: `{IDENTIFY}`"
            ),
            Rule::Conservative | Rule::ConservativeAwayFromMarkers if c.loads_given => format!(
                "where the runtime is always told {} exactly (a measured force), declare it \
                 `force_model = \"white\"`: no force states; else nothing: a `rise_time` or \
                 `range` changed for this also changes the σ of the load withheld",
                c.load()
            ),
            Rule::Conservative if c.markers_from_noise_std => format!(
                "state the load's real (longer) `rise_time` or (smaller) `range` on {}",
                c.load()
            ),
            Rule::Conservative => format!(
                "state the markers' measured noise as `noise_std` on each `[[sensor]]` and the \
                 load's real `rise_time` and `range` on {}, or identify σ from a recording: \
                 `{IDENTIFY}`",
                c.load()
            ),
            Rule::ConservativeAwayFromMarkers => format!(
                "state the load's real (longer) `rise_time` or (smaller) `range` on {}",
                c.load()
            ),
            Rule::ChannelsMissing => format!(
                "judge σ on a recording without losses; where one marker alone sees {}, a \
                 second marker near it keeps the load observable when one is lost",
                c.load()
            ),
        }
    }
}

impl Advice {
    /// The advice in one line: `finding (trigger) → fix`.
    pub fn line(&self, c: &Context) -> String {
        format!(
            "{} ({}) → {}",
            self.rule.finding(c),
            self.trigger,
            self.rule.fix(c)
        )
    }
}

/// The table of rules as Markdown (user-facing; markers as recorded, both tiers' fixes).
pub fn table_markdown() -> String {
    let c = Context {
        tier: None,
        markers_from_noise_std: false,
        loads_given: false,
        loads: &[],
    };
    let mut out =
        String::from("| when (N-run figures) | what is off | what to change |\n|---|---|---|\n");
    for rule in Rule::ALL {
        let _ = writeln!(
            out,
            "| {} | {} | {} |",
            rule.when(),
            rule.finding(&c),
            rule.fix(&c).replace('|', "\\|")
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comparison::segments::{LoadChange, Segment};

    fn fractions(below: f64, above: f64, steps: usize) -> StepFractions {
        StepFractions {
            steps,
            below,
            inside: 1.0 - below - above,
            above,
        }
    }

    /// A ramp of `ramp` steps then a hold of `hold` steps, with the tip NEES fractions above of
    /// each (NIS and coverage consistent in both).
    fn ramp_hold(ramp: (usize, f64), hold: (usize, f64)) -> Vec<SegmentFigures> {
        let seg = |steps: std::ops::Range<usize>, change, above| SegmentFigures {
            segment: Segment {
                start: steps.start as f64 * 0.01,
                end: steps.end as f64 * 0.01,
                steps: steps.clone(),
                change,
            },
            nis: fractions(0.02, 0.02, steps.len()),
            nees_tip: fractions(0.02, above, steps.len()),
            coverage: 0.95,
        };
        vec![
            seg(0..ramp.0, LoadChange::Rises(0.0, 1.0), ramp.1),
            seg(ramp.0..ramp.0 + hold.0, LoadChange::Holds(1.0), hold.1),
        ]
    }

    fn figures<'a>(
        nis: StepFractions,
        nees: StepFractions,
        coverage: f64,
        segments: &'a [SegmentFigures],
        loads: &'a [String],
    ) -> AdviceFigures<'a> {
        AdviceFigures {
            tier: Tier::Corotational,
            markers_from_noise_std: false,
            loads_given: false,
            nis,
            nees_tip: nees,
            coverage,
            filtered_error: 0.02,
            model_error: Some(0.015),
            segments,
            loads,
            own_covariance: 0.0,
        }
    }

    fn rules(advice: &[Advice]) -> Vec<Rule> {
        advice.iter().map(|a| a.rule).collect()
    }

    #[test]
    fn a_consistent_run_gets_no_advice() {
        let seg = ramp_hold((100, 0.03), (200, 0.02));
        let f = figures(
            fractions(0.03, 0.02, 300),
            fractions(0.04, 0.0233, 300),
            0.955,
            &seg,
            &[],
        );
        assert!(advise(&f).is_empty(), "{:?}", advise(&f));
        // At the limits exactly: still no advice.
        let f = figures(
            fractions(0.05, 0.05, 300),
            fractions(0.05, 0.05, 300),
            0.90,
            &seg,
            &[],
        );
        assert!(advise(&f).is_empty());
        let f = AdviceFigures {
            coverage: 0.98,
            ..f
        };
        assert!(advise(&f).is_empty());
    }

    #[test]
    fn nees_above_where_the_load_changes_asks_for_a_shorter_rise_time() {
        // 100 ramp steps 30 % above, 200 hold steps 1 % above: 32 of 300 = 10.7 %.
        let seg = ramp_hold((100, 0.30), (200, 0.01));
        let loads = vec!["tip".to_owned()];
        let f = figures(
            fractions(0.02, 0.03, 300),
            fractions(0.0, 32.0 / 300.0, 300),
            0.94,
            &seg,
            &loads,
        );
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::ForceSigmaTooSmallForChanges]);
        assert_eq!(
            advice[0].trigger,
            "tip NEES above its bound on 10.7 % of the steps (> 5.0 %): 30.0 % of the 100 steps \
             where the load changes, 1.0 % of the 200 steps where the load holds"
        );
        let line = advice[0].line(&(&f).into());
        assert!(line.starts_with("the force σ is too small for how fast this load changes"));
        assert!(
            line.contains("a shorter `rise_time` on `[[load]]` 'tip'"),
            "{line}"
        );
        assert!(line.contains(IDENTIFY), "{line}");
        // No hold segment at all: the same rule.
        let f = AdviceFigures {
            segments: &seg[..1],
            ..f
        };
        assert_eq!(rules(&advise(&f)), vec![Rule::ForceSigmaTooSmallForChanges]);
    }

    #[test]
    fn nees_above_where_the_load_holds_or_low_coverage_is_the_models_error() {
        let seg = ramp_hold((100, 0.02), (200, 0.40));
        let f = figures(
            fractions(0.02, 0.04, 300),
            fractions(0.0, 82.0 / 300.0, 300),
            0.93,
            &seg,
            &[],
        );
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::ModelErrorNotInSigma]);
        let line = advice[0].line(&(&f).into());
        assert!(line.contains("raise the tier's `order`"), "{line}");
        assert!(line.contains("`basis_tolerance`"), "{line}");
        // The warped tier's fix is the co-rotational tier.
        let warped = AdviceFigures {
            tier: Tier::Warped,
            ..f.clone()
        };
        let line = advise(&warped)[0].line(&(&warped).into());
        assert!(
            line.contains("`[reduction] model = \"corotational\"`"),
            "{line}"
        );
        // Coverage below 90 % with the NIS inside adds to the same line.
        let low = AdviceFigures {
            coverage: 0.62,
            ..f.clone()
        };
        let advice = advise(&low);
        assert_eq!(rules(&advice), vec![Rule::ModelErrorNotInSigma]);
        assert!(
            advice[0]
                .trigger
                .ends_with("; 2σ coverage 62.0 % (< 90.0 %) with NIS above its bound on only 4.0 % of the steps"),
            "{}",
            advice[0].trigger
        );
        // Coverage alone (NEES inside) fires it too; with the NIS above it does not (rule 4).
        let consistent = ramp_hold((100, 0.02), (200, 0.02));
        let alone = figures(
            fractions(0.02, 0.04, 300),
            fractions(0.0, 0.02, 300),
            0.80,
            &consistent,
            &[],
        );
        assert_eq!(rules(&advise(&alone)), vec![Rule::ModelErrorNotInSigma]);
        let nis_above = AdviceFigures {
            nis: fractions(0.0, 0.30, 300),
            ..alone
        };
        assert_eq!(
            rules(&advise(&nis_above)),
            vec![Rule::InnovationsLargerThanPredicted]
        );
    }

    #[test]
    fn a_filtered_error_far_above_the_models_own_clears_the_model() {
        // NEES above where the load holds, coverage low: the model's error, unless the model is
        // far more accurate than the filter (the estimate of the load still lags).
        let seg = ramp_hold((100, 0.02), (200, 0.40));
        let f = AdviceFigures {
            filtered_error: 0.36,
            model_error: Some(0.012),
            ..figures(
                fractions(0.02, 0.04, 300),
                fractions(0.0, 82.0 / 300.0, 300),
                0.81,
                &seg,
                &[],
            )
        };
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::ForceSigmaTooSmallForChanges]);
        assert_eq!(
            advice[0].trigger,
            "tip NEES above its bound on 27.3 % of the steps (> 5.0 %): 2.0 % of the 100 steps \
             where the load changes, 40.0 % of the 200 steps where the load holds; filtered \
             error 36.0 % > 2× the model's own 1.2 % (open loop with the loads); 2σ coverage \
             81.0 % (< 90.0 %) with NIS above its bound on only 4.0 % of the steps"
        );
        // Coverage alone, the same.
        let consistent = ramp_hold((100, 0.02), (200, 0.02));
        let alone = AdviceFigures {
            nees_tip: fractions(0.0, 0.02, 300),
            segments: &consistent,
            ..f.clone()
        };
        let advice = advise(&alone);
        assert_eq!(rules(&advice), vec![Rule::ForceSigmaTooSmallForChanges]);
        assert!(
            advice[0].trigger.ends_with("(open loop with the loads)"),
            "{advice:?}"
        );
        // The model's error unknown, or within 2× of the filter's: the segments decide.
        for model_error in [None, Some(0.18)] {
            let f = AdviceFigures {
                model_error,
                ..f.clone()
            };
            assert_eq!(rules(&advise(&f)), vec![Rule::ModelErrorNotInSigma]);
        }
    }

    #[test]
    fn nees_above_everywhere_names_both_causes() {
        let seg = ramp_hold((100, 0.50), (200, 0.40));
        let f = figures(
            fractions(0.02, 0.04, 300),
            fractions(0.0, 130.0 / 300.0, 300),
            0.93,
            &seg,
            &[],
        );
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::SigmaTooSmallThroughout]);
        let line = advice[0].line(&(&f).into());
        assert!(
            line.contains("first the force σ") && line.contains("the model: raise"),
            "{line}"
        );
        // With the loads given the estimate cannot lag them: the model's error, wherever.
        for seg in [seg.clone(), ramp_hold((100, 0.60), (200, 0.01))] {
            let given = AdviceFigures {
                loads_given: true,
                segments: &seg,
                ..f.clone()
            };
            let advice = advise(&given);
            assert_eq!(rules(&advice), vec![Rule::ModelErrorNotInSigma]);
            assert!(
                advice[0]
                    .trigger
                    .ends_with("; the filter is given the loads, its estimate cannot lag them"),
                "{advice:?}"
            );
        }
    }

    #[test]
    fn nis_above_blames_the_markers_or_the_force_sigma() {
        let seg = ramp_hold((100, 0.02), (200, 0.02));
        let f = figures(
            fractions(0.0, 0.12, 300),
            fractions(0.0, 0.02, 300),
            0.93,
            &seg,
            &[],
        );
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::InnovationsLargerThanPredicted]);
        assert_eq!(
            advice[0].trigger,
            "NIS above its bound on 12.0 % of the steps (> 5.0 %)"
        );
        let line = advice[0].line(&(&f).into());
        assert!(
            line.contains("noisier than the scene's `noise_std`"),
            "{line}"
        );
        assert!(line.contains("measure the markers' noise"), "{line}");
        // Markers drawn with the scene's noise_std: R is right, the prior σ is not.
        let synthetic = AdviceFigures {
            markers_from_noise_std: true,
            ..f
        };
        let line = advise(&synthetic)[0].line(&(&synthetic).into());
        assert!(!line.contains("measure the markers' noise"), "{line}");
        assert!(line.contains("shorter `rise_time`"), "{line}");
        // ... and with the loads given as well, only the model's error is left.
        let given = AdviceFigures {
            loads_given: true,
            ..synthetic
        };
        let line = advise(&given)[0].line(&(&given).into());
        assert!(line.contains("the model's own error is not in σ"), "{line}");
        assert!(line.contains("raise the tier's `order`"), "{line}");
        assert!(!line.contains("rise_time"), "{line}");
    }

    #[test]
    fn nis_below_is_conservative() {
        let seg = ramp_hold((100, 0.0), (200, 0.0));
        let f = figures(
            fractions(0.40, 0.0, 300),
            fractions(0.35, 0.0, 300),
            0.995,
            &seg,
            &[],
        );
        let advice = advise(&f);
        assert_eq!(rules(&advice), vec![Rule::Conservative]);
        assert_eq!(
            advice[0].trigger,
            "NIS below its bound on 40.0 % of the steps (> 5.0 %), tip NEES below on 35.0 %, \
             2σ coverage 99.5 %"
        );
        let line = advice[0].line(&(&f).into());
        assert!(line.contains("`noise_std` is larger than the markers' real noise"));
        // Synthetic markers: only the force σ is left.
        let synthetic = AdviceFigures {
            markers_from_noise_std: true,
            ..f.clone()
        };
        let line = advise(&synthetic)[0].line(&(&synthetic).into());
        assert!(!line.contains("`noise_std` is larger"), "{line}");
        assert!(line.contains("longer) `rise_time`"), "{line}");
        // Coverage above 98 % with the NIS inside: σ too large away from the markers.
        let high = AdviceFigures {
            nis: fractions(0.02, 0.02, 300),
            ..f
        };
        let advice = advise(&high);
        assert_eq!(rules(&advice), vec![Rule::ConservativeAwayFromMarkers]);
        assert_eq!(
            advice[0].trigger,
            "2σ coverage 99.5 % (> 98.0 %) with NIS below its bound on only 2.0 %"
        );
        // The same with the loads given: not the load's statement (that would also move the σ
        // of the load withheld) but, for a load always told exactly, no force states.
        let loads = ["push".to_string()];
        let given = AdviceFigures {
            loads_given: true,
            markers_from_noise_std: true,
            loads: &loads,
            ..high
        };
        let advice = advise(&given);
        assert_eq!(rules(&advice), vec![Rule::ConservativeAwayFromMarkers]);
        let line = advice[0].line(&(&given).into());
        assert!(
            line.contains("what the given input might not explain"),
            "{line}"
        );
        assert!(
            line.contains("always told `[[load]]` 'push' exactly")
                && line.contains("`force_model = \"white\"`"),
            "{line}"
        );
        assert!(!line.contains("(longer) `rise_time`"), "{line}");
    }

    #[test]
    fn overconfident_everywhere_gets_one_line_per_problem() {
        // The warped rows at large rotation: NEES above in hold, NIS above, coverage low.
        let seg = ramp_hold((100, 0.10), (200, 0.95));
        let f = AdviceFigures {
            tier: Tier::Warped,
            ..figures(
                fractions(0.0, 0.80, 300),
                fractions(0.0, 200.0 / 300.0, 300),
                0.45,
                &seg,
                &[],
            )
        };
        let advice = advise(&f);
        assert_eq!(
            rules(&advice),
            vec![
                Rule::ModelErrorNotInSigma,
                Rule::InnovationsLargerThanPredicted
            ]
        );
        // The coverage is not added to the model line: the NIS is above (its own line).
        assert!(!advice[0].trigger.contains("coverage"), "{:?}", advice);
        // No tip: no NEES rule.
        let f = AdviceFigures {
            nees_tip: fractions(f64::NAN, f64::NAN, 0),
            ..f
        };
        assert_eq!(
            rules(&advise(&f)),
            vec![Rule::InnovationsLargerThanPredicted]
        );
    }

    #[test]
    fn missing_channels_come_first_as_the_others_context() {
        let seg = ramp_hold((100, 0.03), (200, 0.02));
        let loads = vec!["tip".to_owned()];
        let f = AdviceFigures {
            own_covariance: 0.25,
            ..figures(
                fractions(0.10, 0.02, 300),
                fractions(0.40, 0.0, 300),
                0.99,
                &seg,
                &loads,
            )
        };
        let advice = advise(&f);
        assert_eq!(
            rules(&advice),
            vec![Rule::ChannelsMissing, Rule::Conservative]
        );
        assert_eq!(
            advice[0].trigger,
            "the filter carried its own covariance after 25.0 % of the updates"
        );
        let line = advice[0].line(&(&f).into());
        assert!(
            line.contains("§11.11") && line.contains("a second marker near it"),
            "{line}"
        );
        // None missing: no such line.
        let f = AdviceFigures {
            own_covariance: 0.0,
            ..f
        };
        assert_eq!(rules(&advise(&f)), vec![Rule::Conservative]);
    }

    #[test]
    fn the_table_has_a_row_per_rule() {
        let table = table_markdown();
        // `cargo test -p crokf-verify --lib the_table -- --nocapture` prints it.
        eprintln!("{table}");
        assert_eq!(table.lines().count(), 2 + Rule::ALL.len(), "{table}");
        for rule in Rule::ALL {
            assert!(table.contains(&rule.when()), "{rule:?}");
        }
        assert!(table.contains("co-rotational tier: raise"));
        assert!(table.contains("warped tier: use the co-rotational tier"));
    }
}
