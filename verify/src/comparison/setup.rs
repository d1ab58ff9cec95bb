//! The scene and scenario of a comparison, ready to run: the full-order model, the horizon,
//! the displayed nodes and the tip.

use std::path::{Path, PathBuf};

use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{deformation_gradient, polar_rotation, SteppingError};
use crokf_compile::FullOrder;

use crate::scenario::{Horizon, Scenario};

use super::metrics::rotation_angle;
use super::ComparisonError;

/// The scene and scenario, ready to run.
pub(super) struct Setup {
    pub(super) scene_path: PathBuf,
    pub(super) scenario_path: PathBuf,
    pub(super) full: FullOrder,
    pub(super) scenario: Scenario,
    pub(super) steps: usize,
    /// Sub-steps of Δt/N per scene step of the full-order references (1: Wilson-θ at Δt, the
    /// same scheme as a Wilson-θ model). By default the reference the compiler measures a
    /// model of the scene's `[time] scheme` against
    /// ([`crokf_compile::accuracy::Stepping::for_scheme`]).
    pub(super) substeps: usize,
    /// Unique displayed nodes: (node set, index in set, mesh node).
    pub(super) display: Vec<(usize, usize, usize)>,
    /// Tip sensor index.
    pub(super) tip: Option<usize>,
    /// Elements around the displayed nodes: per displayed node, (element, volume share).
    pub(super) around: Vec<Vec<(usize, f64)>>,
    /// Elements touching any displayed node.
    pub(super) elements: Vec<usize>,
}

impl Setup {
    pub(super) fn new(scene: &Path, scenario_path: &Path) -> Result<Self, ComparisonError> {
        let mut timer = StageTimer::default();
        let full = FullOrder::build(scene, &mut timer)?;
        let scenario = Scenario::read(scenario_path)?;
        scenario.check_scene(&full.scene.scene, scenario_path)?;
        let invalid = |what: String| ComparisonError::Invalid {
            path: scenario_path.to_owned(),
            what,
        };
        let steps =
            match scenario.horizon(full.wilson.dt) {
                Horizon::Steps(k) => k,
                Horizon::Steady(_) => return Err(invalid(
                    "a comparison needs a fixed horizon: give `duration` or `steps`, not `steady`"
                        .into(),
                )),
            };
        let ops = &full.operators;
        let mut seen = vec![false; full.fem.positions.len()];
        let mut display = Vec::new();
        for (s, set) in ops.node_sets.iter().enumerate() {
            for (i, &node) in set.nodes.iter().enumerate() {
                if !std::mem::replace(&mut seen[node], true) {
                    display.push((s, i, node));
                }
            }
        }
        if display.is_empty() {
            return Err(ComparisonError::Invalid {
                path: scene.to_owned(),
                what: "the scene displays no nodes: add a [[display]] node set to compare on"
                    .into(),
            });
        }
        let tip = ops.sensors.iter().position(|s| s.name == "tip");
        let fem = &full.fem;
        let mut node_elements = vec![Vec::new(); fem.positions.len()];
        for (e, el) in fem.elements.iter().enumerate() {
            for &n in &el.nodes {
                if seen[n] {
                    node_elements[n].push(e);
                }
            }
        }
        let mut touched = vec![false; fem.elements.len()];
        let around = display
            .iter()
            .map(|&(_, _, node)| {
                let list = &node_elements[node];
                let total: f64 = list.iter().map(|&e| fem.elements[e].geometry.volume).sum();
                list.iter()
                    .map(|&e| {
                        touched[e] = true;
                        (e, fem.elements[e].geometry.volume / total)
                    })
                    .collect()
            })
            .collect();
        let elements = (0..fem.elements.len()).filter(|&e| touched[e]).collect();
        let substeps =
            crokf_compile::accuracy::Stepping::for_scheme(full.scene.scene.time.scheme).substeps();
        Ok(Setup {
            scene_path: scene.to_owned(),
            scenario_path: scenario_path.to_owned(),
            full,
            scenario,
            steps,
            substeps,
            display,
            tip,
            around,
            elements,
        })
    }

    pub(super) fn dt(&self) -> f64 {
        self.full.wilson.dt
    }

    /// World displacement (3 per displayed node, m) from free-DOF displacements u.
    pub(super) fn displayed(&self, u: &[f64], out: &mut Vec<f64>) {
        let index = &self.full.fem.dofs.index;
        for &(_, _, node) in &self.display {
            out.extend(index[node].iter().map(|d| d.map_or(0.0, |d| u[d])));
        }
    }

    /// World displacement of every sensor (3 per sensor, m).
    pub(super) fn sensors(&self, u: &[f64], out: &mut Vec<f64>) {
        let fem = &self.full.fem;
        for s in &self.full.operators.sensors {
            let mut d = [0.0; 3];
            for &(node, w) in &s.weights {
                for (c, dc) in d.iter_mut().enumerate() {
                    if let Some(i) = fem.dofs.index[node][c] {
                        *dc += w * u[i];
                    }
                }
            }
            out.extend_from_slice(&d);
        }
    }

    /// Largest rotation angle over displayed nodes, degrees: angle of polar(Σₑ Vₑ Fₑ / Σₑ Vₑ).
    pub(super) fn max_rotation_deg(
        &self,
        u: &[f64],
        f_cache: &mut [nalgebra::Matrix3<f64>],
    ) -> f64 {
        let fem = &self.full.fem;
        for &e in &self.elements {
            let el = &fem.elements[e];
            let x: [[f64; 3]; 4] = std::array::from_fn(|a| {
                let n = el.nodes[a];
                std::array::from_fn(|c| {
                    fem.positions[n][c] + fem.dofs.index[n][c].map_or(0.0, |d| u[d])
                })
            });
            f_cache[e] = deformation_gradient(&el.geometry, &x);
        }
        let mut max = 0.0f64;
        for list in &self.around {
            let mut f = nalgebra::Matrix3::zeros();
            for &(e, share) in list {
                f += f_cache[e] * share;
            }
            max = max.max(rotation_angle(&polar_rotation(&f)).to_degrees());
        }
        max
    }

    /// Without a sensor named `tip`: the sensor whose largest displacement in the reference
    /// run's sensor trace `sensors` (3 per sensor per step) is the largest (the point that
    /// moves most); kept once chosen.
    pub(super) fn choose_tip(&mut self, sensors: &[f64]) {
        let ns = self.full.operators.sensors.len();
        if self.tip.is_some() || ns == 0 {
            return;
        }
        let mut peak = vec![0.0f64; ns];
        for (i, u) in sensors.chunks_exact(3).enumerate() {
            let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
            peak[i % ns] = peak[i % ns].max(norm);
        }
        self.tip = (0..ns).max_by(|&a, &b| peak[a].total_cmp(&peak[b]));
    }

    pub(super) fn reference_error(&self, source: SteppingError) -> ComparisonError {
        ComparisonError::Reference {
            path: self.scenario_path.clone(),
            source,
        }
    }
}

/// Scales the scenario's loads (and gravity factor) by `scale`.
pub(super) fn scaled(scenario: &Scenario, scale: f64, has_gravity: bool) -> Scenario {
    let mut s = scenario.clone();
    for l in &mut s.loads {
        for f in &mut l.forces {
            *f = f.map(|v| v * scale);
        }
    }
    if has_gravity {
        s.gravity = Some(s.gravity.unwrap_or(1.0) * scale);
    }
    s
}
