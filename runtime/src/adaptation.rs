//! Adaptive force σ (docs/design.md §11.10): the tier's filter is stored at several levels of
//! the force states' σ (`crokf_formats::CorotationalTier::force_levels`), and the level in use
//! follows the innovations. Per measurement channel j an exponentially weighted mean of the
//! whitened innovation z_j = ν_j / √s_j (s_j of the filter that made the update, the gate's
//! variance; clipped to ±[`Z_CLIP`]),
//! ```text
//! e_j ← (1 − a_j) e_j + a_j z_j,   v_j ← (1 − a_j)² v_j   (e = 0, v = 1 after a change)
//! T = (1/m) Σ_j e_j² (2 − a_j) / (a_j (1 − v_j))          (channels updated at least once)
//! ```
//! (T has mean 1 while the filter's model holds, for any number of updates since the change).
//! σ goes one level up when T > `raise_above`. Every `hold` steps since the last change or
//! check, T is compared with `lower_below`, and below it σ goes one level down: below the
//! designed σ only while every estimated load is told (a load that is given leaves the force
//! states only the model's error; one that is withheld and slower than stated would lag a
//! lower σ before T could show it). The start of a run, with every channel measured every step
//! ([`AdaptationState::start_move`]): the first update after a reset is made at the lowest
//! level (at rest a zero input may be a told zero or a withheld load, and an update at a larger
//! σ would let the markers' noise into the force states, which a random walk of low σ sheds
//! only slowly); at the next prediction the level stays there when every estimated load is
//! told and goes to the designed σ when not; a later first told prediction goes to the lowest
//! level at once, before its update, while the level has not moved since. With sparser markers
//! the model runs alone between them, and the lowest σ did not cover its error there
//! (docs/design.md §11.10): such a tier starts at the designed σ. After a change e restarts at
//! 0. The compiler chose a_j and the thresholds; the runtime only counts. The state is
//! allocated once and changed only after a successful update or, at the start, a successful
//! prediction (which a failed step rolls back with it).

use crokf_formats::{CorotationalTier, ForceAdaptation};

/// Bound on a whitened innovation in the statistic (the default innovation gate, σ): one
/// outlier moves e_j by at most a_j · 5.
pub(crate) const Z_CLIP: f64 = 5.0;

/// The levels of a model and the statistic's parameters (read-only, from the model file).
#[derive(Clone, Debug)]
pub(crate) struct Levels {
    /// Factor on the designed σ per level (level 0 = 1, the model's `kalman`).
    factors: Vec<f64>,
    /// Per level: the next larger and the next smaller factor's level.
    up: Vec<Option<usize>>,
    down: Vec<Option<usize>>,
    /// The level of the smallest factor.
    lowest: usize,
    /// Whether every measurement channel is measured every step (the tier's `kalman.period`
    /// is 1): only then do told loads start at the lowest level (module docs).
    every_step: bool,
    /// Per measurement channel: a_j.
    smoothing: Vec<f64>,
    raise_above: f64,
    lower_below: f64,
    hold: u64,
}

impl Levels {
    /// The levels of a validated tier section: level 0 the designed σ (`kalman`, `scheduled`),
    /// level l ≥ 1 `force_levels[l − 1]`; `None` when the tier has one level.
    pub(crate) fn new(tier: &CorotationalTier) -> Option<Levels> {
        let a = tier.adaptation.as_ref()?;
        if tier.force_levels.is_empty() {
            return None;
        }
        let factors: Vec<f64> = std::iter::once(1.0)
            .chain(tier.force_levels.iter().map(|l| l.factor))
            .collect();
        Some(Levels::from_parts(factors, a, tier.kalman.period == 1))
    }

    /// The levels of the factors `factors` (level 0 first) and the statistic `a`.
    fn from_parts(factors: Vec<f64>, a: &ForceAdaptation, every_step: bool) -> Levels {
        let neighbour = |larger: bool| -> Vec<Option<usize>> {
            (0..factors.len())
                .map(|l| {
                    (0..factors.len())
                        .filter(|&k| {
                            if larger {
                                factors[k] > factors[l]
                            } else {
                                factors[k] < factors[l]
                            }
                        })
                        .min_by(|&a, &b| {
                            (factors[a] - factors[l])
                                .abs()
                                .total_cmp(&(factors[b] - factors[l]).abs())
                        })
                })
                .collect()
        };
        let lowest = (0..factors.len())
            .min_by(|&a, &b| factors[a].total_cmp(&factors[b]))
            .unwrap_or(0);
        Levels {
            lowest,
            every_step,
            up: neighbour(true),
            down: neighbour(false),
            smoothing: a.smoothing.clone(),
            raise_above: a.raise_above,
            lower_below: a.lower_below,
            hold: a.hold as u64,
            factors,
        }
    }

    /// The factor on the designed σ of `level`.
    pub(crate) fn factor(&self, level: usize) -> f64 {
        self.factors[level]
    }
}

/// What [`crate::Estimator::force_level`] reports: the level in use and the statistic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceLevel {
    /// The level (0: the designed σ; l ≥ 1: the tier's `force_levels[l − 1]`).
    pub level: usize,
    /// Its factor on the designed force σ.
    pub factor: f64,
    /// The statistic T after the last update (module docs; 0 right after a change).
    pub statistic: f64,
    /// Whether the level follows the statistic ([`crate::Estimator::set_force_adaptation`]).
    pub adapting: bool,
}

/// Where a run is in its start ([`AdaptationState::start_move`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Start {
    /// Reset; no prediction yet.
    Fresh,
    /// The first update is made at the lowest level.
    Quiet,
    /// Past the first update.
    Open,
}

/// A move of the start ([`AdaptationState::start_move`]): the level, the start's next phase,
/// whether the statistic restarts and whether it counts as the level having moved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct StartMove {
    /// The level after the move.
    pub(crate) level: usize,
    next: Start,
    restart: bool,
    moved: bool,
}

/// The adaptation's statistic (the level it moves is the tier state's, `TierState::level`).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct AdaptationState {
    /// Per channel: e_j and (1 − a_j)^{2n_j} (1 before any update since the change).
    mean: Vec<f64>,
    decay: Vec<f64>,
    /// T after the last update (0 after a change).
    statistic: f64,
    /// The step of the last change or of the last check against `lower_below`.
    settled_since: u64,
    /// Whether the level has moved since the last reset other than by the start.
    moved: bool,
    /// Where the run is in its start (module docs).
    start: Start,
    /// Whether the level follows the statistic (else it stays where it is).
    enabled: bool,
}

impl AdaptationState {
    /// Cleared, for `channels` measurement channels.
    pub(crate) fn new(channels: usize) -> AdaptationState {
        AdaptationState {
            mean: vec![0.0; channels],
            decay: vec![1.0; channels],
            statistic: 0.0,
            settled_since: 0,
            moved: false,
            start: Start::Fresh,
            enabled: true,
        }
    }

    /// The statistic cleared (keeps `enabled`); the level goes back to 0 with it, and the next
    /// prediction starts a run.
    pub(crate) fn reset(&mut self) {
        self.restart(0);
        self.moved = false;
        self.start = Start::Fresh;
    }

    fn restart(&mut self, step: u64) {
        self.mean.iter_mut().for_each(|e| *e = 0.0);
        self.decay.iter_mut().for_each(|v| *v = 1.0);
        self.statistic = 0.0;
        self.settled_since = step;
    }

    /// The report of [`crate::Estimator::force_level`] at level `level`.
    pub(crate) fn report(&self, levels: &Levels, level: usize) -> ForceLevel {
        ForceLevel {
            level,
            factor: levels.factor(level),
            statistic: self.statistic,
            adapting: self.enabled,
        }
    }

    /// Turns the adaptation on or off: either way the statistic starts afresh and the level
    /// goes back to 0 (the designed σ); off, [`AdaptationState::observe`] keeps it there.
    /// After a prediction since the last reset the run is not started again: a told load goes
    /// to the lowest level at its next prediction, a withheld one stays at the designed σ.
    pub(crate) fn set_enabled(&mut self, on: bool) {
        let fresh = self.start == Start::Fresh;
        self.enabled = on;
        self.reset();
        if !fresh {
            self.start = Start::Open;
        }
    }

    /// Whether a prediction has been made since the last reset (and kept: a failed step rolls
    /// it back).
    pub(crate) fn started(&self) -> bool {
        self.start != Start::Fresh
    }

    /// At level `level`, after a successful prediction and before its update, with every
    /// estimated load `told` a nonzero input or not: the level this prediction moves to (module
    /// docs), `Some` also when only the start advanced; None when nothing changed
    /// ([`AdaptationState::start_move`], then [`AdaptationState::take`]; the tests' shorthand).
    #[cfg(test)]
    pub(crate) fn at_prediction(
        &mut self,
        levels: &Levels,
        level: usize,
        told: bool,
        step: u64,
    ) -> Option<usize> {
        let m = self.start_move(levels, level, told)?;
        Some(self.take(m, step))
    }

    /// What the start does at this prediction, changing nothing (None: nothing changes, so
    /// that a caller keeps the state for a rollback only when something will). Only with every
    /// channel measured every step: the first prediction after a reset goes to the lowest
    /// level; the next stays there when told and goes to the designed σ when not (from a level
    /// below it); later, the first told prediction goes to the lowest level while the level has
    /// not moved since the reset.
    pub(crate) fn start_move(
        &self,
        levels: &Levels,
        level: usize,
        told: bool,
    ) -> Option<StartMove> {
        if !self.enabled || !levels.every_step {
            return None;
        }
        let to = |level, next, restart, moved| StartMove {
            level,
            next,
            restart,
            moved,
        };
        match self.start {
            Start::Fresh => Some(to(levels.lowest, Start::Quiet, true, false)),
            Start::Quiet if told => Some(to(level, Start::Open, false, true)),
            Start::Quiet if levels.factors[level] < 1.0 => Some(to(0, Start::Open, true, false)),
            Start::Quiet => Some(to(level, Start::Open, false, false)),
            Start::Open => (told && !self.moved && level != levels.lowest)
                .then(|| to(levels.lowest, Start::Open, true, true)),
        }
    }

    /// Carries out `m` ([`AdaptationState::start_move`]) at step `step`; returns its level.
    pub(crate) fn take(&mut self, m: StartMove, step: u64) -> usize {
        self.start = m.next;
        self.moved |= m.moved;
        if m.restart {
            self.restart(step);
        }
        m.level
    }

    /// `self` becomes a copy of `other` (same channel count) without allocating.
    pub(crate) fn copy_from(&mut self, other: &AdaptationState) {
        self.mean.copy_from_slice(&other.mean);
        self.decay.copy_from_slice(&other.decay);
        self.statistic = other.statistic;
        self.settled_since = other.settled_since;
        self.moved = other.moved;
        self.start = other.start;
        self.enabled = other.enabled;
    }

    /// After a successful update at step `step` made at level `level`: the whitened
    /// innovations `z[a]` of the phase's active channels `active[a]` (NaN: no value) enter the
    /// statistic, and the level moves (module docs): up or down one level, below the designed
    /// σ only when `told` (every estimated load was given a value this step). Returns the level
    /// for the next step.
    pub(crate) fn observe(
        &mut self,
        levels: &Levels,
        level: usize,
        step: u64,
        active: &[u32],
        z: &[f64],
        told: bool,
    ) -> usize {
        if !self.enabled {
            return level;
        }
        let mut seen = false;
        for (&j, &z) in active.iter().zip(z) {
            if z.is_nan() {
                continue;
            }
            let j = j as usize;
            let a = levels.smoothing[j];
            let keep = 1.0 - a;
            self.mean[j] = keep * self.mean[j] + a * z.clamp(-Z_CLIP, Z_CLIP);
            self.decay[j] *= keep * keep;
            seen = true;
        }
        if !seen {
            return level;
        }
        let (mut sum, mut count) = (0.0, 0usize);
        for ((&e, &v), &a) in self.mean.iter().zip(&self.decay).zip(&levels.smoothing) {
            if v < 1.0 {
                sum += e * e * (2.0 - a) / (a * (1.0 - v));
                count += 1;
            }
        }
        self.statistic = sum / count.max(1) as f64;
        let next = if self.statistic > levels.raise_above {
            levels.up[level]
        } else if step.saturating_sub(self.settled_since) >= levels.hold {
            // One window since the last change or check: T now summarises it.
            self.settled_since = step;
            if self.statistic < levels.lower_below {
                levels.down[level].filter(|&l| told || levels.factors[l] >= 1.0)
            } else {
                None
            }
        } else {
            None
        };
        match next {
            Some(next) => {
                self.restart(step);
                self.moved = true;
                next
            }
            None => level,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crokf_formats::synthetic::SplitMix64;

    fn levels(hold: u32) -> Levels {
        levels_at(hold, true)
    }

    /// `every_step`: every channel measured every step.
    fn levels_at(hold: u32, every_step: bool) -> Levels {
        Levels::from_parts(
            vec![1.0, 4.0, 0.25, 0.0625],
            &ForceAdaptation {
                smoothing: vec![2.0 / 21.0; 3],
                raise_above: 5.0,
                lower_below: 0.8,
                hold,
            },
            every_step,
        )
    }

    /// The factors are ordered by size whatever their storage order.
    #[test]
    fn neighbours_follow_the_factors() {
        let l = levels(20);
        assert_eq!(l.up, vec![Some(1), None, Some(0), Some(2)]);
        assert_eq!(l.down, vec![Some(2), Some(0), Some(3), None]);
    }

    /// White unit innovations: T averages 1 from the first update on (the transient is
    /// normalised); a bias of 0.5 σ on every channel raises within a few window lengths; not
    /// told, zero innovations lower nothing below the designed σ and come down one level per
    /// `hold` steps from above it; off keeps level 0.
    #[test]
    fn the_statistic_is_unbiased_and_moves_one_level_at_a_time() {
        let l = levels(20);
        let active = [0u32, 1, 2];
        let mut rng = SplitMix64(3);
        let (mut sum, mut n) = (0.0, 0);
        for run in 0..400 {
            let mut s = AdaptationState::new(3);
            for k in 1..=10u64 {
                let z: Vec<f64> = (0..3).map(|_| rng.normal()).collect();
                s.observe(&l, 0, k + 1000 * run, &active, &z, false);
                if k == 3 {
                    sum += s.statistic;
                    n += 1;
                }
            }
        }
        let mean = sum / n as f64;
        assert!((mean - 1.0).abs() < 0.1, "mean T after 3 updates {mean}");

        let mut s = AdaptationState::new(3);
        let mut raised = None;
        for k in 1..200u64 {
            let z: Vec<f64> = (0..3).map(|_| 0.5 + rng.normal()).collect();
            if s.observe(&l, 0, k, &active, &z, false) == 1 {
                raised = Some(k);
                break;
            }
        }
        let k = raised.expect("a 0.5 σ bias raises σ");
        assert!(k < 60, "raised at step {k}");
        assert_eq!(s.statistic, 0.0);

        // Not told: the calm steps lower nothing below the designed σ; from above it, one.
        let mut s = AdaptationState::new(3);
        for k in 1..=100u64 {
            assert_eq!(s.observe(&l, 0, k, &active, &[0.0; 3], false), 0);
        }
        let mut s = AdaptationState::new(3);
        let mut level = s.observe(&l, 0, 1, &active, &[9.0; 3], false);
        assert_eq!(level, 1);
        for k in 2..=100u64 {
            let next = s.observe(&l, level, k, &active, &[0.0; 3], false);
            if next != level {
                assert_eq!(k % 20, 1, "a change after exactly `hold` calm steps");
            }
            level = next;
        }
        assert_eq!(level, 0);

        let mut s = AdaptationState::new(3);
        s.set_enabled(false);
        for k in 1..100u64 {
            assert_eq!(s.observe(&l, 0, k, &active, &[9.0; 3], true), 0);
        }
        // Missing values change nothing.
        let mut s = AdaptationState::new(3);
        let before = s.clone();
        s.observe(&l, 0, 1, &active, &[f64::NAN; 3], true);
        assert_eq!(s, before);
    }

    /// Every channel measured every step: the first update after a reset at the lowest level;
    /// at the next prediction told loads stay there and withheld ones go to the designed σ,
    /// where a later first told prediction goes to the lowest level at once; after the level
    /// has moved, nothing; a bias still raises, and calm checks come down one level each. With
    /// sparser markers, the designed σ from the start and told loads come down one level per
    /// `hold` calm steps.
    #[test]
    fn runs_start_at_the_lowest_level_with_markers_every_step() {
        let l = levels(20);
        let active = [0u32, 1, 2];
        // Not told: the lowest level for the first update, then the designed σ.
        let mut s = AdaptationState::new(3);
        assert_eq!(s.at_prediction(&l, 0, false, 1), Some(3));
        assert_eq!(s.observe(&l, 3, 1, &active, &[0.0; 3], false), 3);
        assert_eq!(s.at_prediction(&l, 3, false, 2), Some(0));
        assert_eq!(s.observe(&l, 0, 2, &active, &[0.0; 3], false), 0);
        assert_eq!(s.at_prediction(&l, 0, false, 3), None);
        // Told later: the lowest level at once, once.
        assert_eq!(s.at_prediction(&l, 0, true, 4), Some(3));
        assert_eq!(s.at_prediction(&l, 3, true, 5), None);
        // Told from the start: the lowest level throughout the start.
        let mut s = AdaptationState::new(3);
        assert_eq!(s.at_prediction(&l, 0, true, 1), Some(3));
        assert_eq!(s.observe(&l, 3, 1, &active, &[0.0; 3], true), 3);
        assert_eq!(s.at_prediction(&l, 3, true, 2), Some(3));
        assert_eq!(s.at_prediction(&l, 3, true, 3), None);
        let mut level = 3;
        for k in 2..=100u64 {
            level = s.observe(&l, level, k, &active, &[0.0; 3], true);
            assert_eq!(level, 3, "step {k}");
        }
        // Raised twice by a bias (3 → 2 → 0), then calm: down one level per `hold`.
        let mut path = vec![level];
        let mut k = 100;
        while level != 0 {
            k += 1;
            level = s.observe(&l, level, k, &active, &[9.0; 3], true);
            if level != *path.last().unwrap() {
                path.push(level);
            }
            assert!(k < 200, "a 9 σ bias raises");
        }
        let raised_at = k;
        for k in raised_at + 1..=raised_at + 60 {
            let next = s.observe(&l, level, k, &active, &[0.0; 3], true);
            if next != level {
                assert_eq!(
                    (k - raised_at) % 20,
                    0,
                    "a change after exactly `hold` calm steps"
                );
                path.push(next);
            }
            level = next;
        }
        assert_eq!(path, vec![3, 2, 0, 2, 3]);
        // A copy restores everything, here of a state moved and with a nonzero statistic.
        s.observe(&l, level, k + 61, &active, &[1.0, -2.0, 0.5], true);
        let mut copy = AdaptationState::new(3);
        copy.copy_from(&s);
        assert_eq!(copy, s);
        // Moved since the reset: told predictions leave the level to the statistic.
        assert_eq!(s.at_prediction(&l, 2, true, k + 62), None);
        // Switched off and on mid-run: no new start, a told load goes to the lowest level.
        s.set_enabled(false);
        assert_eq!(s.at_prediction(&l, 0, true, k + 63), None);
        s.set_enabled(true);
        assert_eq!(s.at_prediction(&l, 0, true, k + 64), Some(3));
        // reset: a new start; adaptation off: never.
        s.reset();
        assert_eq!(s.at_prediction(&l, 0, false, 1), Some(3));
        s.set_enabled(false);
        assert_eq!(s.at_prediction(&l, 0, true, 1), None);

        // Sparser markers: one level per `hold` calm steps, from the designed σ.
        let l = levels_at(20, false);
        let mut s = AdaptationState::new(3);
        assert_eq!(s.at_prediction(&l, 0, true, 1), None);
        let mut path = vec![0];
        for k in 1..=100u64 {
            let level = s.observe(&l, *path.last().unwrap(), k, &active, &[0.0; 3], true);
            if level != *path.last().unwrap() {
                path.push(level);
                assert_eq!(k % 20, 0, "a change after exactly `hold` calm steps");
            }
        }
        assert_eq!(path, vec![0, 2, 3]);
    }
}
