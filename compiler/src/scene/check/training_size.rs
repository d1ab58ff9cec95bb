//! The size of the co-rotational tier's training from the scene's values alone: the load
//! groups it trains, its load histories, how many runs it makes and how many steps each run
//! has. The scene's check counts the training's snapshots with them; the training plan is
//! built on the same groups and histories (its run list has as many runs as
//! [`CorotationalSpec::training_run_count`] counts).

use crate::scene::{CorotationalSpec, TrainingDirections};

impl TrainingDirections {
    /// How many training directions: 6 axes, 6 axes and 4 diagonals, or the scene's list.
    pub fn count(&self) -> usize {
        match self {
            TrainingDirections::Axes => 6,
            TrainingDirections::AxesAndDiagonals => 10,
            TrainingDirections::List(list) => list.len(),
        }
    }
}

impl CorotationalSpec {
    /// The trained load groups with their ranges (N), in the order of `load_names` (the
    /// scene's loads): those with a range and, when the scene lists training cases, that a
    /// case loads (a group no case loads is not trained).
    pub fn trained_ranges(&self, load_names: &[String]) -> Vec<(String, f64)> {
        let in_a_case = |n: &String| {
            self.cases.is_empty() || self.cases.iter().any(|c| c.loads.contains_key(n))
        };
        load_names
            .iter()
            .filter(|n| in_a_case(n))
            .filter_map(|n| self.ranges.get(n).map(|&r| (n.clone(), r)))
            .collect()
    }

    /// The ramp runs' final multiple of the range and ramp time, s (default duration/3); None
    /// when `ramp_multiple` is 0 (no ramp runs).
    pub fn training_ramp(&self) -> Option<(f64, f64)> {
        (self.ramp_multiple > 0.0).then(|| {
            (
                self.ramp_multiple,
                self.ramp_time.unwrap_or(self.duration / 3.0),
            )
        })
    }

    /// The step runs' multiple of the range; None when `step_multiple` is 0 (no step runs).
    pub fn training_step(&self) -> Option<f64> {
        (self.step_multiple > 0.0).then_some(self.step_multiple)
    }

    /// How many training runs the scene makes (`load_names` its loads, in order): per case,
    /// both signs × each history; without cases, per trained group each direction × each
    /// history, and with `combinations` per pair of groups each direction × both signs × each
    /// history.
    pub fn training_run_count(&self, load_names: &[String]) -> usize {
        let histories = usize::from(self.training_ramp().is_some())
            + usize::from(self.training_step().is_some());
        if !self.cases.is_empty() {
            return self.cases.len() * 2 * histories;
        }
        let groups = self.trained_ranges(load_names).len();
        let directions = self.directions().count();
        let pairs = if self.combinations() {
            groups * groups.saturating_sub(1) / 2
        } else {
            0
        };
        groups * directions * histories + pairs * directions * 2 * histories
    }

    /// Steps of each training run at the time step `dt` (s): N = round(duration/Δt), at least
    /// 1.
    pub fn training_steps(&self, dt: f64) -> usize {
        ((self.duration / dt).round() as usize).max(1)
    }
}
