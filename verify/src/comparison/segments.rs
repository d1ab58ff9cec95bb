//! A filtered run cut at the scenario's load breakpoints, and its N-run consistency per
//! segment (docs/design.md §11.3): a filter can be consistent while a load holds and
//! overconfident while it changes (its force σ too small for how fast the load moves), or the
//! other way round (the model's own error, largest at the largest load, not in σ). The
//! segments tell these apart, for the report's per-segment tables and its advice.
//!
//! Steps: record k (0-based) is the step t_k → t_{k+1}, which holds the input f(t_k), and the
//! statistics after its update. A load history breaks at each of its `times`; a breakpoint t
//! cuts before record ⌊t/Δt⌋ + 1, the first whose input lies past t (the ramp 0 → F over
//! [0, T] changes the input of records 1 … T/Δt). Breakpoints closer than [`MERGE_STEPS`] steps to the one
//! kept before (or to the start or end of the run) are merged into it, so that a step load
//! (two times a few ms apart) is one segment and every segment has enough steps for its
//! fractions to mean something. A segment is *changing* when any load's input differs between
//! two consecutive records in it (or between its first record and the one before; before
//! record 0 the body is at rest, unloaded), else *holding*; a segment whose loads jump in its
//! first [`MERGE_STEPS`] records and then hold is a *step* (changing: the filter's transient
//! after the jump falls in it).

use std::ops::Range;

use crate::scenario::Scenario;

use super::consistency::{SeedEnsemble, StepFractions};

/// Breakpoints closer than this many steps are merged (and a segment has at least this many
/// steps, unless the run itself is shorter).
pub const MERGE_STEPS: usize = 5;

/// What the loads do over a segment, by the norm of all load groups' forces together, |f|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LoadChange {
    /// No load input changes: |f| holds at this value, N.
    Holds(f64),
    /// The loads change and |f| grows from the first to the second value, N.
    Rises(f64, f64),
    /// The loads change and |f| falls from the first to the second value, N.
    Falls(f64, f64),
    /// The loads jump within the segment's first [`MERGE_STEPS`] records (a step load, or a
    /// load present at t = 0 on the body at rest) from the first |f| to the second, N, and
    /// then hold.
    Steps(f64, f64),
    /// The loads change and |f| ends where it started (a reversal, a turn), N.
    Turns(f64),
}

impl LoadChange {
    /// True unless the loads hold.
    pub fn changing(&self) -> bool {
        !matches!(self, LoadChange::Holds(_))
    }

    /// In words: `load holds at 20 N`, `load rises 0 → 20 N`.
    pub fn describe(&self) -> String {
        match *self {
            LoadChange::Holds(f) => format!("load holds at {}", newtons(f)),
            LoadChange::Rises(a, b) => format!("load rises {} → {}", newtons(a), newtons(b)),
            LoadChange::Falls(a, b) => format!("load falls {} → {}", newtons(a), newtons(b)),
            LoadChange::Steps(a, b) => {
                format!("load steps {} → {}, then holds", newtons(a), newtons(b))
            }
            LoadChange::Turns(f) => format!("load turns, |f| {} at both ends", newtons(f)),
        }
    }
}

/// A force with three significant digits: `20 N`, `0.5 N`, `1.25e-3 N`.
fn newtons(f: f64) -> String {
    if f == 0.0 {
        "0 N".into()
    } else if (1e-2..1e4).contains(&f.abs()) {
        // Three significant digits, trailing zeros dropped.
        let digits = (2 - f.abs().log10().floor() as i32).max(0) as usize;
        let s = format!("{f:.digits$}");
        let s = if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_owned()
        } else {
            s
        };
        format!("{s} N")
    } else {
        format!("{f:.2e} N")
    }
}

/// One segment of a run.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Records k of the segment.
    pub steps: Range<usize>,
    /// Its time span, s: from its breakpoint (0 for the first) to the next (the run's end for
    /// the last).
    pub start: f64,
    /// See `start`.
    pub end: f64,
    /// What the loads do in it.
    pub change: LoadChange,
}

/// The segments of `steps` records of Δt = `dt` of `scenario` (module docs); one segment
/// holding for a scenario without loads, none for 0 steps.
pub fn segments(scenario: &Scenario, dt: f64, steps: usize) -> Vec<Segment> {
    if steps == 0 {
        return Vec::new();
    }
    let mut cuts: Vec<usize> = scenario
        .loads
        .iter()
        .flat_map(|l| l.times.iter())
        .filter(|t| t.is_finite() && **t > 0.0)
        // The first record whose input f(t_k) lies past t (1e-9: t a whole number of steps).
        .map(|t| (t / dt + 1e-9).floor() + 1.0)
        .filter(|&k| k < steps as f64)
        .map(|k| k as usize)
        .collect();
    cuts.sort_unstable();
    cuts.dedup();
    let mut kept = vec![0];
    for k in cuts {
        let last = kept[kept.len() - 1];
        if k >= last + MERGE_STEPS && k + MERGE_STEPS <= steps {
            kept.push(k);
        }
    }
    kept.push(steps);
    // The input forces of record k, all groups, and their norm |f|.
    let forces = |k: usize| -> Vec<[f64; 3]> {
        scenario.loads.iter().map(|l| l.at(k as f64 * dt)).collect()
    };
    let norm = |f: &[[f64; 3]]| f.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    // Forces equal to this tolerance hold (the largest |f| of the run × 1e-9).
    let scale = (0..=steps).map(|k| norm(&forces(k))).fold(0.0, f64::max);
    let tolerance = 1e-9 * scale;
    kept.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            // Before record 0 the body is at rest, unloaded.
            let before = match a {
                0 => vec![[0.0; 3]; scenario.loads.len()],
                _ => forces(a - 1),
            };
            let changed: Vec<usize> = (a..b)
                .filter(|&k| {
                    let previous = if k == a {
                        before.clone()
                    } else {
                        forces(k - 1)
                    };
                    forces(k)
                        .iter()
                        .flatten()
                        .zip(previous.iter().flatten())
                        .any(|(x, y)| (x - y).abs() > tolerance)
                })
                .collect();
            let (from, to) = (norm(&before), norm(&forces(b - 1)));
            let change = if changed.is_empty() {
                LoadChange::Holds(to)
            } else if changed.iter().all(|&k| k < a + MERGE_STEPS) && b - a > MERGE_STEPS {
                LoadChange::Steps(from, to)
            } else if to > from + tolerance {
                LoadChange::Rises(from, to)
            } else if to < from - tolerance {
                LoadChange::Falls(from, to)
            } else {
                LoadChange::Turns(to)
            };
            Segment {
                steps: a..b,
                start: a.saturating_sub(1) as f64 * dt,
                end: if b == steps { b } else { b - 1 } as f64 * dt,
                change,
            }
        })
        .collect()
}

/// A segment's N-run figures.
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentFigures {
    /// The segment.
    pub segment: Segment,
    /// Its steps' N-run NIS against their 95 % bounds.
    pub nis: StepFractions,
    /// Its steps' N-run tip NEES against their 95 % bounds (`steps` 0 without a tip).
    pub nees_tip: StepFractions,
    /// 2σ coverage (runtime σ) over its steps and the runs.
    pub coverage: f64,
}

/// The figures of each segment of `segments` over the runs of `ensemble`.
pub fn segment_figures(ensemble: &SeedEnsemble, segments: &[Segment]) -> Vec<SegmentFigures> {
    segments
        .iter()
        .map(|s| SegmentFigures {
            segment: s.clone(),
            nis: ensemble.nis.fractions_in(s.steps.clone()),
            nees_tip: ensemble.nees_tip.fractions_in(s.steps.clone()),
            coverage: ensemble.coverage_in(s.steps.clone()),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::LoadHistory;

    fn scenario(loads: &[(&[f64], &[[f64; 3]])]) -> Scenario {
        Scenario {
            steps: Some(1),
            loads: loads
                .iter()
                .enumerate()
                .map(|(i, (times, forces))| LoadHistory {
                    name: format!("load{i}"),
                    times: times.to_vec(),
                    forces: forces.to_vec(),
                })
                .collect(),
            ..Scenario::default()
        }
    }

    #[test]
    fn a_ramp_and_hold_is_two_segments() {
        // The cantilever's report scenario: 0 → 20 N over 0.5 s, held to 1.5 s (Δt 5 ms).
        let s = scenario(&[(&[0.0, 0.5], &[[0.0; 3], [0.0, 0.0, -20.0]])]);
        let seg = segments(&s, 0.005, 300);
        assert_eq!(seg.len(), 2, "{seg:?}");
        assert_eq!(seg[0].steps, 0..101);
        assert_eq!(seg[1].steps, 101..300);
        assert!((seg[0].end - 0.5).abs() < 1e-12 && (seg[1].start - 0.5).abs() < 1e-12);
        assert!((seg[1].end - 1.5).abs() < 1e-12);
        assert_eq!(seg[1].change, LoadChange::Holds(20.0));
        match seg[0].change {
            LoadChange::Rises(a, b) => assert!(a == 0.0 && (b - 20.0).abs() < 1e-9, "{a} {b}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(seg[0].change.describe(), "load rises 0 N → 20 N");
        assert_eq!(seg[1].change.describe(), "load holds at 20 N");
    }

    #[test]
    fn close_breakpoints_merge_and_a_release_falls() {
        // Rest until 0.1 s, a step to 1 N within 2 ms (merged into one segment), held, a
        // release over 0.2 s from 0.5 s, held at 0; Δt 1 ms, 1000 steps.
        let s = scenario(&[(
            &[0.1, 0.102, 0.5, 0.7],
            &[[0.0; 3], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0; 3]],
        )]);
        let seg = segments(&s, 0.001, 1000);
        let steps: Vec<Range<usize>> = seg.iter().map(|s| s.steps.clone()).collect();
        assert_eq!(steps, vec![0..101, 101..501, 501..701, 701..1000]);
        for (s, (start, end)) in seg
            .iter()
            .zip([(0.0, 0.1), (0.1, 0.5), (0.5, 0.7), (0.7, 1.0)])
        {
            assert!(
                (s.start - start).abs() < 1e-12 && (s.end - end).abs() < 1e-12,
                "{s:?}"
            );
        }
        let changing: Vec<bool> = seg.iter().map(|s| s.change.changing()).collect();
        assert_eq!(changing, vec![false, true, true, false]);
        assert_eq!(seg[0].change, LoadChange::Holds(0.0));
        assert_eq!(seg[1].change, LoadChange::Steps(0.0, 1.0));
        assert_eq!(seg[1].change.describe(), "load steps 0 N → 1 N, then holds");
        assert!(matches!(seg[2].change, LoadChange::Falls(a, _) if a == 1.0));
        assert_eq!(seg[3].change, LoadChange::Holds(0.0));
        // A breakpoint within MERGE_STEPS of the end is merged too; no loads: one segment.
        let seg = segments(&s, 0.001, 503);
        assert_eq!(seg.last().map(|s| s.steps.clone()), Some(101..503));
        let seg = segments(&Scenario::default(), 0.01, 40);
        assert_eq!(seg.len(), 1);
        assert_eq!(seg[0].change, LoadChange::Holds(0.0));
        assert!(segments(&s, 0.001, 0).is_empty());
    }

    #[test]
    fn a_reversal_turns_and_two_loads_share_breakpoints() {
        let s = scenario(&[
            (
                &[0.0, 0.2, 0.4],
                &[[1.0, 0.0, 0.0], [0.0; 3], [-1.0, 0.0, 0.0]],
            ),
            (&[0.3], &[[0.0, 2.0, 0.0]]),
        ]);
        let seg = segments(&s, 0.01, 60);
        let steps: Vec<Range<usize>> = seg.iter().map(|s| s.steps.clone()).collect();
        assert_eq!(steps, vec![0..21, 21..31, 31..41, 41..60]);
        // 0.2 → 0.4 s: the first load goes 0 → −1 N while the second holds 2 N: |f| rises.
        assert!(matches!(seg[1].change, LoadChange::Rises(..)));
        // A reversal from 1 N to −1 N within one segment (its breakpoint merged): it turns.
        let s = scenario(&[(
            &[0.0, 0.2, 0.4],
            &[[1.0, 0.0, 0.0], [0.0; 3], [-1.0, 0.0, 0.0]],
        )]);
        let seg = segments(&s, 0.05, 9);
        assert_eq!(seg.len(), 1, "{seg:?}");
        assert_eq!(seg[0].steps, 0..9);
        // Before record 0 the body is unloaded: 0 N → ... → |−1 N|: |f| rises.
        assert!(matches!(seg[0].change, LoadChange::Rises(a, b) if a == 0.0 && b == 1.0));
        // A load present from t = 0 on the body at rest is a step, then a hold.
        let s = scenario(&[(&[0.0], &[[0.0, 0.0, 3.0]])]);
        let seg = segments(&s, 0.01, 50);
        assert_eq!(seg.len(), 1);
        assert_eq!(seg[0].change, LoadChange::Steps(0.0, 3.0));
        // A reversal after a hold: |f| the same at both ends.
        let s = scenario(&[(
            &[0.1, 0.2, 0.3],
            &[[1.0, 0.0, 0.0], [0.0; 3], [-1.0, 0.0, 0.0]],
        )]);
        let seg = segments(&s, 0.01, 40);
        let steps: Vec<Range<usize>> = seg.iter().map(|s| s.steps.clone()).collect();
        assert_eq!(steps, vec![0..11, 11..21, 21..31, 31..40]);
        assert_eq!(seg[0].change, LoadChange::Steps(0.0, 1.0));
        // A hold at 1 N, then a reversal to −1 N over 0.5 s whose end merges with the run's.
        let s = scenario(&[(
            &[0.0, 0.3, 0.8],
            &[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]],
        )]);
        let seg = segments(&s, 0.05, 20);
        let steps: Vec<Range<usize>> = seg.iter().map(|s| s.steps.clone()).collect();
        assert_eq!(steps, vec![0..7, 7..20]);
        assert!(
            matches!(seg[0].change, LoadChange::Steps(a, b) if a == 0.0 && (b - 1.0).abs() < 1e-12)
        );
        assert!(matches!(seg[1].change, LoadChange::Turns(f) if (f - 1.0).abs() < 1e-12));
    }
}
