//! Measured error of a reduced model against the full-order linear reference (docs/design.md §7).
//!
//! Both are driven by the same input history u_k (one value per deterministic input channel);
//! the full-order model by f_k = B u_k through [`LinearSimulator`], the reduced one by
//! x_{k+1} = F x_k + G u_k. The error is the relative L2 norm over the displayed nodes (and the
//! sensors) and the whole trajectory, ‖u − u_ref‖ / ‖u_ref‖, in the linear (unwarped) frame.

use std::collections::BTreeMap;

use faer::Mat;

use crate::fem::operators::{InputKind, SparseRow};
use crate::full_order::FullOrder;
use crate::outputs::OutputRows;
use crate::reduced::ReducedModel;
use crate::scene::Scheme;
use crate::stepping::{LinearSimulator, Simulator, SteppingError};

/// A named input history: `inputs[k][j]` is channel j at step k.
#[derive(Clone, Debug)]
pub struct LoadTest {
    /// "step" or "chirp".
    pub name: String,
    /// Per step, one value per deterministic input channel.
    pub inputs: Vec<Vec<f64>>,
}

/// The two standard histories: a unit step and a linear chirp, both on every load group along
/// the unit direction (1, 1, 1)/√3 (gravity channel at 1 when there is no load group).
/// The chirp sweeps 0 → `f_high` Hz over the run; `steps` steps each.
pub fn standard_tests(full: &FullOrder, steps: usize, f_high: f64) -> Vec<LoadTest> {
    let dt = full.wilson.dt;
    let has_loads = !full.operators.loads.is_empty();
    let direction: Vec<f64> = full
        .operators
        .inputs
        .iter()
        .map(|c| match c.kind {
            InputKind::Load { .. } => 1.0 / 3f64.sqrt(),
            InputKind::Gravity if !has_loads => 1.0,
            _ => 0.0,
        })
        .collect();
    let duration = steps as f64 * dt;
    let step = (0..steps).map(|_| direction.clone()).collect();
    let chirp = (0..steps)
        .map(|k| {
            let t = k as f64 * dt;
            // Phase of a linear sweep from 0 to f_high over the duration.
            let phase = std::f64::consts::PI * f_high * t * t / duration;
            direction.iter().map(|d| d * phase.sin()).collect()
        })
        .collect();
    vec![
        LoadTest {
            name: "step".into(),
            inputs: step,
        },
        LoadTest {
            name: "chirp".into(),
            inputs: chirp,
        },
    ]
}

/// A unit step on each deterministic input channel alone (`step.<label>`, e.g. `step.tip.x`),
/// `steps` steps each: a weak channel's error shows on its own instead of inside the others'.
pub fn channel_steps(full: &FullOrder, steps: usize) -> Vec<LoadTest> {
    let m = full.operators.inputs.len();
    full.operators
        .inputs
        .iter()
        .enumerate()
        .map(|(j, c)| LoadTest {
            name: format!("step.{}", c.label),
            inputs: (0..steps)
                .map(|_| (0..m).map(|i| if i == j { 1.0 } else { 0.0 }).collect())
                .collect(),
        })
        .collect()
}

/// Sub-steps per scene step of the converged full-order reference of an exactly stepped
/// model: at Δt/32 the reference's own error (a third of its difference from Δt/16, second
/// order) is 5e-4 on the meniscus chirp, ≤ 1e-4 on the cantilever, tentacle, kidney and arch
/// (`cargo run --release -p crokf-verify --example time_error -- SCENE --substeps 32`).
pub const CONVERGED_SUBSTEPS: usize = 32;

/// How the full-order reference is stepped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stepping {
    /// Wilson-θ at the scene's Δt: the same scheme as a Wilson-θ reduced model, so the error
    /// is the reduction's alone.
    SameScheme,
    /// Wilson-θ at Δt / `substeps` with the load of each scene step held over its sub-steps
    /// and the acceleration restarted where it changes
    /// ([`LinearSimulator::consistent_acceleration`]): second order in the sub-step, the
    /// continuous-time response of the full-order model to the held loads as `substeps`
    /// grows.
    Converged {
        /// Sub-steps per scene step (≥ 1).
        substeps: usize,
    },
}

impl Stepping {
    /// The reference a model stepped by `scheme` is measured against: a Wilson-θ model
    /// against the full-order Wilson-θ at Δt (the error is then the reduction's alone), an
    /// exactly stepped one against the full-order response converged in time at
    /// Δt/[`CONVERGED_SUBSTEPS`] (there is no full-order exact step to compare with).
    pub fn for_scheme(scheme: Scheme) -> Self {
        match scheme {
            Scheme::WilsonTheta => Stepping::SameScheme,
            Scheme::Exact => Stepping::Converged {
                substeps: CONVERGED_SUBSTEPS,
            },
        }
    }

    /// Sub-steps of the reference per scene step (1 for the same scheme).
    pub fn substeps(self) -> usize {
        match self {
            Stepping::SameScheme => 1,
            Stepping::Converged { substeps } => substeps.max(1),
        }
    }
}

/// Displacement rows the error is measured on: sensors and displayed nodes, with their row
/// indices in [`OutputRows::weighted`] order.
pub(crate) fn measured_rows(rows: &OutputRows) -> Vec<(usize, &SparseRow)> {
    let sensors = rows.sensors.iter().enumerate().flat_map(|(s, (u, _))| {
        u.iter()
            .enumerate()
            .map(move |(c, r)| (rows.sensor_row(s) + c, r))
    });
    let nodes = rows.node_sets.iter().enumerate().flat_map(|(k, set)| {
        set.iter().enumerate().flat_map(move |(i, (u, _))| {
            u.iter()
                .enumerate()
                .map(move |(c, r)| (rows.node_row(k, i) + c, r))
        })
    });
    sensors.chain(nodes).collect()
}

/// The full-order linear responses of a set of load tests on the measured rows, simulated once
/// and compared with any number of reduced models (one per order r).
pub struct ReferenceResponses {
    tests: Vec<LoadTest>,
    /// (row index in [`OutputRows::weighted`] order, exact value per step), per test:
    /// `values[t][k * rows + i]`.
    values: Vec<Vec<f64>>,
    rows: Vec<usize>,
    sensor_rows: usize,
}

impl ReferenceResponses {
    /// Runs the full-order linear Wilson-θ reference through every test and records the
    /// displacement rows of the sensors and displayed nodes. The tests are stepped together,
    /// one column each, on one factor of J ([`LinearSimulator::batch`]); a test shorter than
    /// the longest is stepped on at zero load and no longer recorded.
    pub fn simulate(
        full: &FullOrder,
        rows: &OutputRows,
        tests: Vec<LoadTest>,
    ) -> Result<Self, SteppingError> {
        Self::simulate_with(full, rows, tests, Stepping::SameScheme)
    }

    /// [`ReferenceResponses::simulate`] with the reference stepped as `stepping` says.
    pub fn simulate_with(
        full: &FullOrder,
        rows: &OutputRows,
        tests: Vec<LoadTest>,
        stepping: Stepping,
    ) -> Result<Self, SteppingError> {
        let substeps = stepping.substeps();
        let wilson = crate::dynamics::WilsonTheta {
            dt: full.wilson.dt / substeps as f64,
            theta: full.wilson.theta,
        };
        let fem = &full.fem;
        let n = fem.dof_count();
        let measured = measured_rows(rows);
        let mut values: Vec<Vec<f64>> = tests
            .iter()
            .map(|t| Vec::with_capacity(t.inputs.len() * measured.len()))
            .collect();
        let steps = tests.iter().map(|t| t.inputs.len()).max().unwrap_or(0);
        // n > 0: the modal stage refuses a model without free DOFs before this runs.
        if steps > 0 && n > 0 {
            let mut reference = LinearSimulator::batch(fem, wilson, tests.len())?;
            let mut f = vec![0.0; n * tests.len()];
            for k in 0..steps {
                for (test, f) in tests.iter().zip(f.chunks_exact_mut(n)) {
                    f.iter_mut().for_each(|v| *v = 0.0);
                    let Some(u) = test.inputs.get(k) else {
                        continue;
                    };
                    for (channel, &value) in full.operators.inputs.iter().zip(u) {
                        if value != 0.0 {
                            f.iter_mut()
                                .zip(&channel.column)
                                .for_each(|(fi, b)| *fi += value * b);
                        }
                    }
                }
                if matches!(stepping, Stepping::Converged { .. }) {
                    reference.consistent_acceleration(&f)?;
                }
                for _ in 0..substeps {
                    reference.step(&f)?;
                }
                let all = reference.displacement();
                for ((test, recorded), full_u) in
                    tests.iter().zip(&mut values).zip(all.chunks_exact(n))
                {
                    if k < test.inputs.len() {
                        recorded.extend(
                            measured.iter().map(|(_, row)| {
                                row.iter().map(|&(d, w)| w * full_u[d]).sum::<f64>()
                            }),
                        );
                    }
                }
            }
        }
        Ok(ReferenceResponses {
            tests,
            values,
            rows: measured.iter().map(|&(i, _)| i).collect(),
            sensor_rows: 3 * rows.sensors.len(),
        })
    }

    /// Relative L2 difference of `other` from these responses per test (same tests and rows):
    /// `"<test>"` over displayed nodes and sensors, ‖other − self‖ / ‖self‖.
    pub fn relative_difference(&self, other: &ReferenceResponses) -> BTreeMap<String, f64> {
        self.tests
            .iter()
            .zip(self.values.iter().zip(&other.values))
            .map(|(test, (a, b))| {
                let (err, norm) = a.iter().zip(b).fold((0.0, 0.0), |(e, n), (a, b)| {
                    (e + (b - a) * (b - a), n + a * a)
                });
                (test.name.clone(), (err / norm).sqrt())
            })
            .collect()
    }

    /// Relative L2 errors of the reduced model per test: `"<test>"` over displayed nodes and
    /// sensors, `"<test>.sensors"` over the sensors only.
    pub fn errors(&self, reduced: &ReducedModel) -> BTreeMap<String, f64> {
        use faer::linalg::matmul::matmul;
        use faer::{Accum, Par};
        let r = reduced.state_dim();
        let p = self.rows.len();
        // The measured rows of the reduced model's outputs, read once (p × r).
        let c = Mat::from_fn(p, r, |i, j| reduced.outputs[(self.rows[i], j)]);
        let mut errors = BTreeMap::new();
        for (test, exact_values) in self.tests.iter().zip(&self.values) {
            let steps = test.inputs.len();
            // The states after each step (r × steps), then every measured row at once.
            let mut states = Mat::<f64>::zeros(r, steps);
            let mut x = Mat::<f64>::zeros(r, 1);
            for (k, u) in test.inputs.iter().enumerate() {
                let u_in = Mat::from_fn(u.len(), 1, |i, _| u[i]);
                let mut next = Mat::<f64>::zeros(r, 1);
                matmul(
                    next.as_mut(),
                    Accum::Replace,
                    reduced.transition.as_ref(),
                    x.as_ref(),
                    1.0,
                    Par::Seq,
                );
                matmul(
                    next.as_mut(),
                    Accum::Add,
                    reduced.input.as_ref(),
                    u_in.as_ref(),
                    1.0,
                    Par::Seq,
                );
                x = next;
                states.col_mut(k).copy_from(x.col(0));
            }
            let mut approx = Mat::<f64>::zeros(p, steps);
            matmul(
                approx.as_mut(),
                Accum::Replace,
                c.as_ref(),
                states.as_ref(),
                1.0,
                Par::Seq,
            );
            let (mut err, mut norm, mut err_s, mut norm_s) = (0.0, 0.0, 0.0, 0.0);
            for k in 0..steps {
                for i in 0..p {
                    let exact = exact_values[k * p + i];
                    let e2 = (approx[(i, k)] - exact).powi(2);
                    err += e2;
                    norm += exact * exact;
                    if i < self.sensor_rows {
                        err_s += e2;
                        norm_s += exact * exact;
                    }
                }
            }
            errors.insert(test.name.clone(), (err / norm).sqrt());
            if self.sensor_rows > 0 {
                errors.insert(format!("{}.sensors", test.name), (err_s / norm_s).sqrt());
            }
        }
        errors
    }

    /// Per test: the RMS over the run of the reduced model's error at each sensor displacement
    /// row (3 per sensor, x, y, z, sensor order) against the full-order linear reference, m per
    /// unit input (the tests drive each load group with a unit-magnitude force). A check of the
    /// process noise from the model (docs/design.md §11.3): the truncation's own error per
    /// marker channel, to compare with the markers' σ and the filter's innovation σ.
    pub fn sensor_rms_errors(&self, reduced: &ReducedModel) -> BTreeMap<String, Vec<f64>> {
        let r = reduced.state_dim();
        let p = self.rows.len();
        let mut out = BTreeMap::new();
        for (test, exact_values) in self.tests.iter().zip(&self.values) {
            let mut x = Mat::<f64>::zeros(r, 1);
            let mut sum = vec![0.0; self.sensor_rows];
            for (k, u) in test.inputs.iter().enumerate() {
                let u_in = Mat::from_fn(u.len(), 1, |i, _| u[i]);
                x = &reduced.transition * &x + &reduced.input * &u_in;
                for (i, s) in sum.iter_mut().enumerate() {
                    let row_index = self.rows[i];
                    let approx: f64 = (0..r)
                        .map(|j| reduced.outputs[(row_index, j)] * x[(j, 0)])
                        .sum();
                    *s += (approx - exact_values[k * p + i]).powi(2);
                }
            }
            let n = test.inputs.len().max(1) as f64;
            out.insert(
                test.name.clone(),
                sum.into_iter().map(|s| (s / n).sqrt()).collect(),
            );
        }
        out
    }
}

/// The static error of one input channel: the reduced model's steady state under a constant
/// unit input on that channel against the full-order static response K⁻¹ b_j.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelStaticError {
    /// The channel's label (`tip.x`, `gravity`).
    pub label: String,
    /// ‖y_r − y‖ / ‖y‖ over the sensors' and displayed nodes' displacement rows.
    pub error: f64,
    /// ‖y‖ of this channel over the largest ‖y‖ of the load channels (None for gravity, whose
    /// unit is not a newton).
    pub relative_size: Option<f64>,
}

/// Every deterministic input channel's static error ([`ChannelStaticError`]): the balanced
/// part of `reduced` (its force states, a pure integrator, left out) at its steady state
/// x = (I − F)⁻¹ G e_j, read on the measured rows of `rows`, against `static_outputs` (p × m,
/// [`OutputRows::weighted`] order, [`Reductor::static_outputs`]). The standard tests load every
/// channel of a group together, so a channel whose static gain is far below the others' can be
/// off without the measured error showing it. None when I − F is singular (a mode with no
/// stiffness).
///
/// [`Reductor::static_outputs`]: crate::Reductor::static_outputs
pub fn channel_static_errors(
    full: &FullOrder,
    rows: &OutputRows,
    reduced: &ReducedModel,
    static_outputs: &Mat<f64>,
) -> Option<Vec<ChannelStaticError>> {
    use faer::linalg::solvers::Solve;
    let rb = reduced.balanced_order;
    let m = reduced.input.ncols();
    if static_outputs.ncols() != m || m == 0 {
        return None;
    }
    let a = Mat::from_fn(rb, rb, |i, j| {
        f64::from(u8::from(i == j)) - reduced.transition[(i, j)]
    });
    let g = Mat::from_fn(rb, m, |i, j| reduced.input[(i, j)]);
    let x = a.partial_piv_lu().solve(&g);
    if x.col_iter().flat_map(|c| c.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    let measured = measured_rows(rows);
    let mut out = Vec::with_capacity(m);
    let mut norms = Vec::with_capacity(m);
    for j in 0..m {
        let (mut err, mut norm) = (0.0, 0.0);
        for &(i, _) in &measured {
            let approx: f64 = (0..rb).map(|k| reduced.outputs[(i, k)] * x[(k, j)]).sum();
            let exact = static_outputs[(i, j)];
            err += (approx - exact).powi(2);
            norm += exact * exact;
        }
        norms.push(norm.sqrt());
        out.push(ChannelStaticError {
            label: full.operators.inputs[j].label.clone(),
            error: if norm > 0.0 { (err / norm).sqrt() } else { 0.0 },
            relative_size: None,
        });
    }
    let is_load = |j: usize| matches!(full.operators.inputs[j].kind, InputKind::Load { .. });
    let largest = (0..m)
        .filter(|&j| is_load(j))
        .map(|j| norms[j])
        .fold(0.0f64, f64::max);
    for (j, c) in out.iter_mut().enumerate() {
        if is_load(j) && largest > 0.0 {
            c.relative_size = Some(norms[j] / largest);
        }
    }
    Some(out)
}

/// The static error above which a channel is named in the compile report.
pub const CHANNEL_STATIC_NOTE_ABOVE: f64 = 0.02;

/// The compile note naming the channels whose static error is above
/// [`CHANNEL_STATIC_NOTE_ABOVE`] (None when none is), largest first.
pub fn channel_static_note(errors: &[ChannelStaticError], order: usize) -> Option<String> {
    let mut above: Vec<&ChannelStaticError> = errors
        .iter()
        .filter(|c| c.error > CHANNEL_STATIC_NOTE_ABOVE)
        .collect();
    if above.is_empty() {
        return None;
    }
    above.sort_by(|a, b| b.error.total_cmp(&a.error));
    let listed: Vec<String> = above
        .iter()
        .map(|c| {
            let size = c.relative_size.map_or(String::new(), |s| {
                format!(
                    " (its static response {:.2e} of the largest load channel's)",
                    s
                )
            });
            format!("'{}' {:.1} %{size}", c.label, 100.0 * c.error)
        })
        .collect();
    Some(format!(
        "static error per input channel above {:.0} % at r = {order} (the reduced model's steady \
         state under a constant unit input against the full-order K⁻¹b, sensors and displayed \
         nodes): {}; the measured error loads the channels of a group together and does not \
         show it; the default order rule counts each channel's static error (not when \
         reduction.order or reduction.tolerance is stated); a larger order follows such a \
         channel",
        100.0 * CHANNEL_STATIC_NOTE_ABOVE,
        listed.join(", ")
    ))
}
