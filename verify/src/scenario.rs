//! Scenario files (TOML): the load history a reference simulation applies, how long it runs and
//! which extra points it records. Unknown keys are errors.
//!
//! ```toml
//! duration = 2.0                # s; or `steps = 2000`; or the `steady` table below
//! # steady = { tolerance = 1e-6, max_steps = 100000 }
//! gravity = 1.0                 # factor on the scene's gravity (default 1 when it declares one)
//!
//! [[load]]                      # one per scene load group that is not zero
//! name = "tip"                  # a scene [[load]] name
//! times = [0.0, 0.5, 2.0]       # s, strictly increasing
//! forces = [[0, 0, 0], [0, 0, -1], [0, 0, -1]]   # world-frame total force, N, per time
//!
//! [[points]]                    # or points = [{ name = "tip", position = [1.0, 0.05, 0.05] }]
//! name = "tip"
//! position = [1.0, 0.05, 0.05]  # mesh units, rest configuration
//! ```
//!
//! Forces are piecewise linear in time and held at the first and last value outside `times`.
//! The step from t_k to t_{k+1} holds f(t_k) (the input f_k of s_{k+1} = Φ s_k + Γ f_k).
//! Loads the scenario does not name are zero.

use std::path::Path;

use serde::Deserialize;

use crokf_compile::fem::operators::{InputKind, Operators};
use crokf_compile::scene::Scene;

/// Errors in reading or checking a scenario file: the same type as a scene file's.
pub type ScenarioError = crokf_compile::scene::InputFileError;

/// Run until the state settles.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Steady {
    /// Stop once t ≥ the last load time and
    /// max(‖U_{k+1} − U_k‖, Δt‖U̇_{k+1}‖, Δt²‖Ü_{k+1}‖) ≤ tolerance · ‖U_{k+1}‖.
    pub tolerance: f64,
    /// Give up (an error) after this many steps.
    pub max_steps: usize,
}

/// The force history of one scene load group.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LoadHistory {
    /// Scene load name.
    pub name: String,
    /// Sample times, s, strictly increasing.
    pub times: Vec<f64>,
    /// World-frame total force on the group at each time, N.
    pub forces: Vec<[f64; 3]>,
}

impl LoadHistory {
    /// The force at time t (N): piecewise-linear, constant outside the samples.
    pub fn at(&self, t: f64) -> [f64; 3] {
        let (times, forces) = (&self.times, &self.forces);
        if t <= times[0] {
            return forces[0];
        }
        let last = times.len() - 1;
        if t >= times[last] {
            return forces[last];
        }
        let k = times.partition_point(|&s| s <= t) - 1;
        let w = (t - times[k]) / (times[k + 1] - times[k]);
        std::array::from_fn(|c| (1.0 - w) * forces[k][c] + w * forces[k + 1][c])
    }
}

/// A named point to record, interpolated like a sensor.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NamedPoint {
    /// Label (unique among sensors and points).
    pub name: String,
    /// Position in mesh units (rest configuration).
    pub position: [f64; 3],
}

/// A scenario as written in the file.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Simulated time, s (rounded to whole steps).
    pub duration: Option<f64>,
    /// Number of steps.
    pub steps: Option<usize>,
    /// Run until steady instead.
    pub steady: Option<Steady>,
    /// Factor on the scene's gravity vector (default 1 when the scene declares gravity).
    pub gravity: Option<f64>,
    /// Load histories.
    #[serde(default, rename = "load")]
    pub loads: Vec<LoadHistory>,
    /// Extra recorded points.
    #[serde(default)]
    pub points: Vec<NamedPoint>,
}

/// How long a scenario runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Horizon {
    /// A fixed number of steps.
    Steps(usize),
    /// Until steady.
    Steady(Steady),
}

impl Scenario {
    /// Reads and checks a scenario file.
    pub fn read(path: &Path) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io {
            kind: "scenario",
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and checks scenario text; `path` appears in messages only.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ScenarioError> {
        let scenario: Scenario = toml::from_str(text).map_err(|e| ScenarioError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        scenario.check().map_err(|what| ScenarioError::Invalid {
            path: path.to_owned(),
            what,
        })?;
        Ok(scenario)
    }

    fn check(&self) -> Result<(), String> {
        let given = [
            self.duration.is_some(),
            self.steps.is_some(),
            self.steady.is_some(),
        ];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err("give exactly one of `duration` (s), `steps` or `steady`".into());
        }
        if let Some(d) = self.duration {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!("duration must be > 0 s, got {d}"));
            }
        }
        if self.steps == Some(0) {
            return Err("steps must be ≥ 1".into());
        }
        if let Some(s) = self.steady {
            if !(s.tolerance.is_finite() && s.tolerance > 0.0) {
                return Err(format!("steady.tolerance must be > 0, got {}", s.tolerance));
            }
            if s.max_steps == 0 {
                return Err("steady.max_steps must be ≥ 1".into());
            }
        }
        if let Some(g) = self.gravity {
            if !g.is_finite() {
                return Err(format!("gravity factor must be finite, got {g}"));
            }
        }
        let mut names = std::collections::BTreeSet::new();
        for l in &self.loads {
            let name = &l.name;
            if !names.insert(name.as_str()) {
                return Err(format!("load '{name}': given twice"));
            }
            if l.times.is_empty() || l.times.len() != l.forces.len() {
                return Err(format!(
                    "load '{name}': times and forces must be non-empty and of equal length, \
                     got {} times and {} forces",
                    l.times.len(),
                    l.forces.len()
                ));
            }
            if l.times.iter().any(|t| !t.is_finite())
                || l.forces.iter().flatten().any(|f| !f.is_finite())
            {
                return Err(format!("load '{name}': times and forces must be finite"));
            }
            if let Some(k) = l.times.windows(2).position(|w| w[1] <= w[0]) {
                return Err(format!(
                    "load '{name}': times must increase strictly, but times[{}] = {} follows {}",
                    k + 1,
                    l.times[k + 1],
                    l.times[k]
                ));
            }
        }
        let mut points = std::collections::BTreeSet::new();
        for p in &self.points {
            if !points.insert(p.name.as_str()) {
                return Err(format!("point '{}': name used twice", p.name));
            }
            if p.position.iter().any(|v| !v.is_finite()) {
                return Err(format!("point '{}': position must be finite", p.name));
            }
        }
        Ok(())
    }

    /// Checks the scenario against a scene: load names exist, point names do not clash with
    /// sensor names, gravity is only scaled when declared. `path` names the scenario file.
    pub fn check_scene(&self, scene: &Scene, path: &Path) -> Result<(), ScenarioError> {
        let invalid = |what: String| ScenarioError::Invalid {
            path: path.to_owned(),
            what,
        };
        for l in &self.loads {
            if !scene.loads.iter().any(|s| s.name == l.name) {
                let known: Vec<&str> = scene.loads.iter().map(|s| s.name.as_str()).collect();
                return Err(invalid(format!(
                    "load '{}': the scene has no [[load]] of that name; it has: {}",
                    l.name,
                    known.join(", ")
                )));
            }
        }
        for p in &self.points {
            if scene.sensors.iter().any(|s| s.name == p.name) {
                return Err(invalid(format!(
                    "point '{}': a sensor of the scene has the same name",
                    p.name
                )));
            }
        }
        if self.gravity.is_some_and(|g| g != 0.0) && scene.gravity.is_none() {
            return Err(invalid(
                "gravity: the scene declares no gravity vector to scale".into(),
            ));
        }
        Ok(())
    }

    /// The horizon for time step `dt` (s): `duration` becomes round(duration/Δt) ≥ 1 steps.
    pub fn horizon(&self, dt: f64) -> Horizon {
        match (self.steps, self.duration, self.steady) {
            (Some(n), _, _) => Horizon::Steps(n),
            (_, Some(d), _) => Horizon::Steps(((d / dt).round() as usize).max(1)),
            (_, _, Some(s)) => Horizon::Steady(s),
            _ => Horizon::Steps(1),
        }
    }

    /// Time after which the loads are constant, s.
    pub fn last_load_time(&self) -> f64 {
        self.loads
            .iter()
            .filter_map(|l| l.times.last().copied())
            .fold(0.0, f64::max)
    }

    /// The input vector at time t in the order of [`Operators::inputs`]: per scene load
    /// (x, y, z force, N), then the gravity factor if the scene declares gravity.
    pub fn inputs_at(&self, ops: &Operators, t: f64) -> Vec<f64> {
        ops.inputs
            .iter()
            .map(|channel| match channel.kind {
                InputKind::Load { load, component } => self
                    .loads
                    .iter()
                    .find(|l| l.name == ops.loads[load].name)
                    .map_or(0.0, |l| l.at(t)[component]),
                InputKind::Gravity => self.gravity.unwrap_or(1.0),
                InputKind::Noise { .. } => 0.0,
            })
            .collect()
    }

    /// The load vector f(t) = Σ inputs · columns over the free DOFs (n, N).
    pub fn load_vector(&self, ops: &Operators, n: usize, t: f64) -> Vec<f64> {
        let mut f = vec![0.0; n];
        for (value, channel) in self.inputs_at(ops, t).iter().zip(&ops.inputs) {
            if *value != 0.0 {
                f.iter_mut()
                    .zip(&channel.column)
                    .for_each(|(f, c)| *f += value * c);
            }
        }
        f
    }
}
