//! The full-order co-rotational reference of a scenario as the filter drivers use it
//! (`--example nonlinear_filter`, `--example identify_noise`): displayed nodes, sensors and the
//! scenario's inputs per step, optionally cached in a file (a measuring aid); [`displayed`], an
//! estimator's read-out in the same layout.

use std::path::Path;

use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use crokf_compile::FullOrder;
use crokf_runtime::{Estimator, Model, RuntimeError};

use super::TierError;
use crate::scenario::Scenario;

/// A reference trajectory, one row per step: displayed nodes (node sets in order, world
/// displacement, m), sensors (3 per sensor, m) and the scenario's inputs.
#[derive(Clone, Debug, Default)]
pub struct Reference {
    /// Displayed nodes per step (3 per node).
    pub shown: Vec<Vec<f64>>,
    /// Sensors per step (3 per sensor).
    pub sensors: Vec<Vec<f64>>,
    /// The scenario's inputs per step (`Scenario::inputs_at`).
    pub inputs: Vec<Vec<f64>>,
}

impl Reference {
    /// The full-order co-rotational run of `scenario` over `steps` steps (Newton to the default
    /// tolerance); with `cache` a file that holds it (written after computing, read while its
    /// step count and its displayed-node and sensor counts match: one file per scene and
    /// scenario).
    pub fn of(
        full: &FullOrder,
        scenario: &Scenario,
        steps: usize,
        cache: Option<&Path>,
    ) -> Result<Reference, TierError> {
        let ops = &full.operators;
        let shape = (
            ops.node_sets
                .iter()
                .map(|s| 3 * s.nodes.len())
                .sum::<usize>(),
            3 * ops.sensors.len(),
        );
        if let Some(path) = cache {
            if let Some(cached) = read_cache(path, steps, shape) {
                eprintln!("reference read from {}", path.display());
                return Ok(cached);
            }
        }
        let computed = run(full, scenario, steps)?;
        if let Some(path) = cache {
            write_cache(path, &computed).map_err(|e| {
                TierError::Invalid(format!("reference cache {}: {e}", path.display()))
            })?;
        }
        Ok(computed)
    }

    /// The tip marker: the sensor named `tip`, else the one with the largest peak displacement
    /// (as `crokf-verify report`); 0 without sensors.
    pub fn tip_marker(&self, full: &FullOrder) -> usize {
        let sensors = &full.operators.sensors;
        let peak = |s: usize| {
            self.sensors
                .iter()
                .map(|y| (y[3 * s].powi(2) + y[3 * s + 1].powi(2) + y[3 * s + 2].powi(2)).sqrt())
                .fold(0.0, f64::max)
        };
        sensors
            .iter()
            .position(|s| s.name == "tip")
            .or_else(|| (0..sensors.len()).max_by(|&a, &b| peak(a).total_cmp(&peak(b))))
            .unwrap_or(0)
    }
}

/// The estimator's displayed nodes in the layout of [`Reference::shown`]: every node set of
/// `model` in order, 3 world-frame displacements per node (m), exact rotations
/// (`Estimator::node_displacements_exact`). `out` has 3 × (the node sets' total count).
pub fn displayed(est: &Estimator, model: &Model, out: &mut [f64]) -> Result<(), RuntimeError> {
    let found = out.len();
    let mut at = 0;
    for (set, nodes) in model.node_sets.iter().enumerate() {
        let len = 3 * nodes.node_tags.len();
        let rows = out.get_mut(at..at + len).ok_or(RuntimeError::Length {
            what: "displayed nodes",
            expected: at + len,
            found,
        })?;
        est.node_displacements_exact(set, rows)?;
        at += len;
    }
    Ok(())
}

fn run(full: &FullOrder, scenario: &Scenario, steps: usize) -> Result<Reference, TierError> {
    let fem = &full.fem;
    let ops = &full.operators;
    let dt = full.wilson.dt;
    let n = fem.dof_count();
    let mut reference = CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default())?;
    let mut out = Reference {
        shown: Vec::with_capacity(steps),
        sensors: Vec::with_capacity(steps),
        inputs: Vec::with_capacity(steps),
    };
    let nodal = |u: &[f64], node: usize, c: usize| fem.dofs.index[node][c].map_or(0.0, |d| u[d]);
    for k in 0..steps {
        let t = k as f64 * dt;
        let f = scenario.load_vector(ops, n, t);
        out.inputs.push(scenario.inputs_at(ops, t));
        reference.step(&f)?;
        let u = reference.displacement();
        let mut shown = Vec::new();
        for set in &ops.node_sets {
            for &node in &set.nodes {
                for c in 0..3 {
                    shown.push(nodal(u, node, c));
                }
            }
        }
        out.shown.push(shown);
        let mut s = Vec::new();
        for sensor in &ops.sensors {
            for c in 0..3 {
                s.push(
                    sensor
                        .weights
                        .iter()
                        .map(|&(node, w)| w * nodal(u, node, c))
                        .sum::<f64>(),
                );
            }
        }
        out.sensors.push(s);
    }
    Ok(out)
}

/// The reference as little-endian f64 rows: per part its row count, column count and rows.
fn write_cache(path: &Path, r: &Reference) -> Result<(), crokf_formats::output::OutputError> {
    let mut bytes = Vec::new();
    for part in [&r.shown, &r.sensors, &r.inputs] {
        bytes.extend_from_slice(&(part.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&(part.first().map_or(0, Vec::len) as u64).to_le_bytes());
        for row in part {
            for v in row {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    crokf_formats::output::write_atomically(path, &bytes)
}

/// The cached reference if it has `steps` rows and `shape` = (displayed values, sensor values)
/// per row.
fn read_cache(path: &Path, steps: usize, shape: (usize, usize)) -> Option<Reference> {
    let bytes = std::fs::read(path).ok()?;
    let mut at = 0;
    let mut word = || -> Option<[u8; 8]> {
        let w = bytes.get(at..at + 8)?.try_into().ok()?;
        at += 8;
        Some(w)
    };
    let mut part = || -> Option<Vec<Vec<f64>>> {
        let rows = u64::from_le_bytes(word()?) as usize;
        let cols = u64::from_le_bytes(word()?) as usize;
        (0..rows)
            .map(|_| (0..cols).map(|_| word().map(f64::from_le_bytes)).collect())
            .collect()
    };
    let out = Reference {
        shown: part()?,
        sensors: part()?,
        inputs: part()?,
    };
    let fits = |rows: &[Vec<f64>], width: usize| {
        rows.len() == steps && rows.iter().all(|r| r.len() == width)
    };
    (fits(&out.shown, shape.0) && fits(&out.sensors, shape.1)).then_some(out)
}
