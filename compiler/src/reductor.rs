//! Build once, reduce many times (pyMOR's reductor pattern): the full-order model's output
//! layout, its modal basis and modal Wilson-θ system are computed once; balanced truncations
//! of any order r, their Kalman schedules and model files are derived from them
//! (docs/design.md §4, §6). The co-rotational tier's reductor is [`tier::TierReductor`].

pub mod tier;

use std::cell::OnceCell;
use std::collections::BTreeMap;

use faer::sparse::SparseColMat;
use faer::Mat;

use crokf_kernel::wilson;

use crate::accuracy::{self, ReferenceResponses};
use crate::algorithms::kalman::{self, KalmanError, PeriodicSchedule};
use crate::contact::{ContactRegion, RegionCompliance};
use crate::error::CompileError;
use crate::full_order::FullOrder;
use crate::noise::NoiseModel;
use crate::observability;
use crate::outputs::{columns, stack_rows, Measurements, OutputRows};
use crate::reduce::{self, ModalBasis, ModalSystem, Order};
use crate::reduced::{ReducedModel, RegionRows};
use crate::scene::Scheme;
use crate::step_error::{self, StepError};
use crate::timer::StageTimer;

/// Tolerance σ_{r+1}/σ₁ when neither order nor tolerance is given and no measured error is
/// computed (`--no-measure`).
pub const DEFAULT_TOLERANCE: f64 = 1e-4;

/// The default order rule (neither order nor tolerance given): the loosest tolerance of
/// [`DEFAULT_TOLERANCE_LADDER`] whose reduced model's measured error (worst of the step and
/// chirp on every load group together, docs/design.md §7) is at most this, and whose every input
/// channel's own static error is at most [`DEFAULT_CHANNEL_STATIC_TARGET`]. Chosen from the error
/// it costs (`cargo run --release -p crokf-verify --example mode_budget -- SCENE`): a fixed
/// tolerance of 1e-3 gives r = 22 / 16 / 24 on the cantilever / meniscus / tentacle at 4.9e-4 /
/// 3.2e-3 / 1.2e-3, but 3.0e-2 on an undamped beam (r = 4) and 7.8e-2 at Δt = 1e-4 s
/// (tests/tests/hard_cases.rs); a fixed 1e-4 spends r = 38 on the cantilever for 1.5e-4.
/// Measuring the error per scene keeps it at 1e-3, an order below the runtime's 2–5 % targets,
/// with no more states than needed.
pub const DEFAULT_ERROR_TARGET: f64 = 1e-3;

/// The default order rule's bound on each input channel's own static error
/// ([`accuracy::channel_static_errors`]: the reduced model's steady state under a unit input on
/// that channel alone against the full-order K⁻¹b_j, relative to that channel's response), the
/// measured-error target's: the joint tests load every channel of a group together, so a
/// channel whose static gain is far below the others' (the cantilever's axial tip.x, 3.5e-3 of
/// the bending channels') is off unseen (15.1 % at the joint rule's r = 22; 4.9e-4 at r = 47).
/// The static error, not a step per channel, because the order controls it exactly (the modal
/// basis holds K⁻¹B, so it falls to ~1e-5 as r grows) while a per-channel step also carries the
/// modal cut, which no order removes (the arch's push.x step stays at 1.3e-3 up to r = 39,
/// static 1.1e-5), and because it costs one r × r solve per candidate where the steps double the
/// full-order reference (cantilever 0.32 → 0.67 s); on the cantilever, meniscus, tentacle, arch
/// and horn a channel whose step exceeded 1e-3 always had its static error above it too
/// (`cargo run --release -p crokf-verify --example channel_order -- SCENE`).
pub const DEFAULT_CHANNEL_STATIC_TARGET: f64 = DEFAULT_ERROR_TARGET;

/// Tolerances the default order rule tries, loosest first.
pub const DEFAULT_TOLERANCE_LADDER: [f64; 6] = [1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6];

/// `[reduction] max_frequency = f`: the modal basis keeps every mode up to this multiple of f.
pub const MAX_FREQUENCY_MODE_FACTOR: f64 = 2.0;

/// Cap on the number of modes under `max_frequency` (a guard against a mesh with thousands of
/// modes below the scene's frequency; the report says when it bites).
pub const MAX_FREQUENCY_MODE_CAP: usize = 400;

/// Cap on the number of vibration modes when the scene gives no count. On the 50k-tetrahedron
/// beam, 60 modes instead of 200 cut the modal stage from 61 s to 5 s and left the measured
/// error unchanged (3.1e-4 step, 5.5e-4 chirp): the balanced truncation, not the modal cut,
/// sets the error there.
pub const DEFAULT_MAX_MODES: usize = 60;

/// Longest step/chirp history of the measured error, steps.
pub const MEASURE_MAX_STEPS: usize = 400;
pub use crate::accuracy::CONVERGED_SUBSTEPS;

/// The modal system of a full-order model with everything an order-r model is derived from.
pub struct Reductor<'a> {
    /// The full-order model.
    pub full: &'a FullOrder,
    /// Output layout (sensors, loads, displayed nodes).
    pub rows: OutputRows,
    /// Balancing weight of each output row, in [`OutputRows::weighted`] order.
    pub weights: Vec<f64>,
    /// The measurement channels.
    pub measurements: Measurements,
    /// Modes + static correction.
    pub basis: ModalBasis,
    /// The modal Wilson-θ system with weighted outputs.
    pub system: ModalSystem,
    /// The scene's contact region with its full-order static compliance (docs/contact.md).
    pub contact: Option<(ContactRegion, RegionCompliance)>,
    reference: OnceCell<ReferenceResponses>,
    static_outputs: Mat<f64>,
}

impl<'a> Reductor<'a> {
    /// Builds the output layout, the modal basis (`modes` vibration modes; else every mode up to
    /// twice the scene's `max_frequency`; else every mode up to a quarter of the sampling
    /// frequency capped at [`DEFAULT_MAX_MODES`]) and the modal system.
    /// Stage costs go to `timer` ("outputs", "modes", "modal_system").
    pub fn new(
        full: &'a FullOrder,
        modes: Option<usize>,
        timer: &mut StageTimer,
    ) -> Result<Self, CompileError> {
        let reduce_err = |source| CompileError::Reduce {
            path: full.scene_path().to_owned(),
            source,
        };
        let fem = &full.fem;
        let ops = &full.operators;
        let n = fem.dof_count();
        let rows = timer.stage("outputs", || OutputRows::build(fem, ops));
        let weighted = rows.weighted();
        let weights: Vec<f64> = weighted.iter().map(|(_, w)| *w).collect();
        let contact = timer.stage("contact", || Self::contact_region(full))?;
        // A contact region's kept compliance directions are inputs and outputs of the modal
        // basis and the truncation too (after the scene's own), so the reduced model keeps what
        // a force on the region excites and shows there.
        let (contact_columns, contact_rows) = match &contact {
            Some((region, compliance)) => (
                region.input_columns(compliance, n),
                region.output_rows(compliance),
            ),
            None => (Vec::new(), Vec::new()),
        };
        let mut truncation_rows = weighted.clone();
        truncation_rows.extend(contact_rows.iter().map(|r| (r, 1.0)));
        let outputs: SparseColMat<usize, f64> = stack_rows(&truncation_rows, n);
        let input_columns: Vec<&[f64]> = ops
            .inputs
            .iter()
            .chain(&ops.noise)
            .map(|c| c.column.as_slice())
            .chain(contact_columns.iter().map(Vec::as_slice))
            .collect();
        let b: Mat<f64> = columns(&input_columns, n);
        let spec = &full.scene.scene.reduction;
        let modes = modes.or(spec.modes);
        let resolved = full.wilson.highest_resolved_hz();
        let (max_frequency_hz, max_modes) = match (modes, spec.max_frequency) {
            // An explicit count: exactly that many.
            (Some(m), _) => (None, m.max(1)),
            // The scene's load spectrum: every mode up to twice its highest frequency.
            (None, Some(f)) => (
                Some((MAX_FREQUENCY_MODE_FACTOR * f).min(resolved)),
                MAX_FREQUENCY_MODE_CAP,
            ),
            // Otherwise every mode up to half the Nyquist frequency (Wilson-θ damps the rest
            // numerically), capped; static correction covers the quasi-static rest.
            (None, None) => (Some(resolved), DEFAULT_MAX_MODES),
        };
        // The default makes the static correction: its K⁻¹B gives `static_outputs` below.
        let modal_options = reduce::ModalOptions {
            modes,
            max_frequency_hz,
            max_modes,
            ..reduce::ModalOptions::default()
        };
        let mut basis = timer
            .stage("modes", || {
                reduce::modal_basis(
                    fem.stiffness.as_ref(),
                    fem.mass.as_ref(),
                    b.as_ref(),
                    &modal_options,
                )
            })
            .map_err(reduce_err)?;
        if let Some(note) = unresolved_modes_note(&basis, full.wilson.dt) {
            basis.warnings.push(note);
        }
        let system = timer
            .stage("modal_system", || {
                ModalSystem::with_scheme(
                    &basis,
                    b.as_ref(),
                    outputs.as_ref(),
                    fem.alpha,
                    fem.beta,
                    full.wilson,
                    full.scene.scene.time.scheme,
                )
            })
            .map_err(reduce_err)?;
        // K⁻¹b_j of the deterministic inputs (B's first columns) on every output row.
        // With a contact region, its nodes' rows follow (region DOFs of K⁻¹B).
        let solved = basis.static_response.subcols(0, ops.inputs.len());
        let p = weighted.len();
        let region_dofs: &[usize] = contact.as_ref().map_or(&[], |(c, _)| &c.dofs);
        let static_outputs = Mat::from_fn(p + region_dofs.len(), ops.inputs.len(), |i, j| {
            if i < p {
                weighted[i].0.iter().map(|&(d, w)| w * solved[(d, j)]).sum()
            } else {
                solved[(region_dofs[i - p], j)]
            }
        });
        Ok(Reductor {
            full,
            contact,
            measurements: Measurements::new(ops),
            rows,
            weights,
            basis,
            system,
            reference: OnceCell::new(),
            static_outputs,
        })
    }

    /// The scene's contact region and its full-order static compliance, if it declares one.
    fn contact_region(
        full: &FullOrder,
    ) -> Result<Option<(ContactRegion, RegionCompliance)>, CompileError> {
        let fem = &full.fem;
        let unit = full.scene.scene.mesh.units.to_metres();
        let region =
            ContactRegion::build(&full.mesh, &full.scene.scene, fem, unit).map_err(|source| {
                CompileError::Fem {
                    path: full.scene_path().to_owned(),
                    source,
                }
            })?;
        let Some(region) = region else {
            return Ok(None);
        };
        let compliance = region.compliance(fem).map_err(|what| CompileError::Fem {
            path: full.scene_path().to_owned(),
            source: crate::fem::FemError::Scene(format!("contact '{}': {what}", region.name)),
        })?;
        Ok(Some((region, compliance)))
    }

    /// The order rule without measurement: an explicit order, else a tolerance, from the
    /// arguments, then the scene's `[reduction]` table, then [`DEFAULT_TOLERANCE`].
    pub fn order(&self, order: Option<usize>, tolerance: Option<f64>) -> Order {
        let spec = &self.full.scene.scene.reduction;
        match (order.or(spec.order), tolerance.or(spec.tolerance)) {
            (Some(r), _) => Order::Fixed(r),
            (None, Some(t)) => Order::Tolerance(t),
            (None, None) => Order::Tolerance(DEFAULT_TOLERANCE),
        }
    }

    /// Balanced truncation of the given order, unweighted and sign-normalised, with the force
    /// states of the scene's estimated load groups appended ([`NoiseModel`]); a derived force σ
    /// is fixed on this truncation's filter (docs/design.md §11.8) and noted in `warnings`.
    pub fn reduce(&self, order: Order) -> Result<ReducedModel, CompileError> {
        let truncation = self.balanced_truncation(order)?;
        let ops = &self.full.operators;
        let contact = self.contact.as_ref().map(|(region, _)| {
            let rows = stack_rows(
                &region
                    .displacement_rows()
                    .iter()
                    .map(|r| (r, 1.0))
                    .collect::<Vec<_>>(),
                self.full.fem.dof_count(),
            );
            let region_rows = truncation
                .project_outputs(rows.as_ref())
                .expect("the region's rows span the model's DOFs");
            let v = &self.basis.vectors;
            let map = truncation.input_map();
            let contact_input = Mat::from_fn(region.dofs.len(), map.nrows(), |i, j| {
                let d = region.dofs[i];
                (0..v.ncols()).map(|k| v[(d, k)] * map[(j, k)]).sum()
            });
            // W = θ³Λ T on the region's DOFs: Σ_k V[d, k] Σ_s w_s T[3k + s, j].
            let w = self.full.wilson.theta_point_weights();
            let t = &truncation.reduced_to_modal;
            let theta = Mat::from_fn(region.dofs.len(), t.ncols(), |i, j| {
                let d = region.dofs[i];
                (0..v.ncols())
                    .map(|k| {
                        v[(d, k)]
                            * (w[0] * t[(3 * k, j)]
                                + w[1] * t[(3 * k + 1, j)]
                                + w[2] * t[(3 * k + 2, j)])
                    })
                    .sum()
            });
            RegionRows {
                rows: region_rows,
                input: contact_input,
                theta,
            }
        });
        let reduced = ReducedModel::from_truncation(
            truncation,
            ops.inputs.len(),
            ops.noise.len(),
            &self.weights,
            contact,
        );
        let mut noise = self.full.noise_model().map_err(|e| self.noise_error(e))?;
        if noise.groups.is_empty() {
            return Ok(reduced);
        }
        let exact = self.static_outputs();
        let r = reduced.transition.nrows();
        let with_forces = |noise: &NoiseModel| {
            let loads: Vec<(usize, f64)> = noise.groups.iter().map(|g| (g.load, g.sigma)).collect();
            reduced.clone().with_force_states(ops, &loads, Some(exact))
        };
        let derived = noise.derive(self.full.wilson.dt, |trial, k, delta| {
            let augmented = with_forces(trial);
            let schedule = self.kalman(&augmented)?;
            let h = self
                .measurements
                .rows_of(&self.rows, augmented.outputs.as_ref());
            let block = r + 3 * k..r + 3 * k + 3;
            kalman::lag::ramp_lag(
                augmented.transition.as_ref(),
                h.as_ref(),
                &schedule,
                block,
                delta,
            )
            .map_err(|e| self.noise_error(e))
        })?;
        let mut augmented = with_forces(&noise);
        augmented.warnings.extend(
            derived
                .iter()
                .map(|d| d.note(&self.full.scene.scene.loads[d.load].name)),
        );
        Ok(augmented)
    }

    /// A noise-model error of this scene.
    fn noise_error(&self, e: impl std::fmt::Display) -> CompileError {
        CompileError::Reduce {
            path: self.full.scene_path().to_owned(),
            source: reduce::ReduceError::InvalidOption(format!("force states: {e}")),
        }
    }

    /// The reduced model by the scene's order rule (docs/design.md §4.3): an explicit order,
    /// else a tolerance, from the arguments, then the scene's `[reduction]` table; else, when
    /// `measure` allows the measured error, the loosest tolerance of
    /// [`DEFAULT_TOLERANCE_LADDER`] whose measured error meets [`DEFAULT_ERROR_TARGET`] and whose
    /// every input channel's static error meets [`DEFAULT_CHANNEL_STATIC_TARGET`] (when none
    /// does, the last tried, with a note naming what is not met); else [`DEFAULT_TOLERANCE`].
    /// Returns the model and a note on how r was chosen (default rule only).
    pub fn reduce_by_rule(
        &self,
        order: Option<usize>,
        tolerance: Option<f64>,
        measure: bool,
    ) -> Result<(ReducedModel, Option<String>), CompileError> {
        let spec = &self.full.scene.scene.reduction;
        if order.or(spec.order).is_some() || tolerance.or(spec.tolerance).is_some() || !measure {
            return Ok((self.reduce(self.order(order, tolerance))?, None));
        }
        let worst = |errors: &BTreeMap<String, f64>| {
            ["step", "chirp"]
                .iter()
                .filter_map(|k| errors.get(*k))
                .fold(0.0f64, |a, &b| a.max(b))
        };
        let mut tried: Vec<RuleCandidate> = Vec::new();
        for tol in DEFAULT_TOLERANCE_LADDER {
            // The candidate without force states: they start at zero and have no input, so its
            // measured and static errors are the full model's; the force σ is derived once, for
            // the order chosen.
            let candidate = self.truncate(Order::Tolerance(tol))?;
            if tried
                .last()
                .is_some_and(|c| c.order == candidate.balanced_order)
            {
                continue;
            }
            let joint = worst(&self.measured_errors(&candidate)?);
            let channel = accuracy::channel_static_errors(
                self.full,
                &self.rows,
                &candidate,
                self.static_outputs(),
            )
            .and_then(|errors| {
                errors
                    .into_iter()
                    .max_by(|a, b| a.error.total_cmp(&b.error))
                    .map(|c| (c.label, c.error))
            });
            let c = RuleCandidate {
                tolerance: tol,
                order: candidate.balanced_order,
                joint,
                channel,
            };
            let met = c.met();
            tried.push(c);
            if met {
                break;
            }
        }
        let Some(chosen) = tried.last() else {
            return Err(CompileError::Reduce {
                path: self.full.scene_path().to_owned(),
                source: reduce::ReduceError::InvalidOption("empty tolerance ladder".into()),
            });
        };
        let reduced = self.reduce(Order::Tolerance(chosen.tolerance))?;
        Ok((reduced, Some(rule_note(&tried))))
    }

    /// The modal system's balanced truncation of the given order, its error naming the scene.
    fn balanced_truncation(&self, order: Order) -> Result<reduce::ReducedSystem, CompileError> {
        self.system
            .balanced_truncation(order)
            .map_err(|source| CompileError::Reduce {
                path: self.full.scene_path().to_owned(),
                source,
            })
    }

    /// The balanced truncation of the given order without force states or a contact region's
    /// rows (unweighted, sign-normalised): what the default order rule measures per candidate.
    fn truncate(&self, order: Order) -> Result<ReducedModel, CompileError> {
        let truncation = self.balanced_truncation(order)?;
        let ops = &self.full.operators;
        Ok(ReducedModel::from_truncation(
            truncation,
            ops.inputs.len(),
            ops.noise.len(),
            &self.weights,
            None,
        ))
    }

    /// The full-order static response K⁻¹ b_j of every deterministic input channel j on every
    /// output row (p × m, unweighted, [`OutputRows::weighted`] order; m per channel, or per N
    /// for load channels), from the modal stage's K⁻¹B: no factorisation of its own. The force
    /// states' static residual is built from it (docs/design.md §11).
    pub fn static_outputs(&self) -> &Mat<f64> {
        &self.static_outputs
    }

    /// The steady-state (periodic) Kalman schedule of a reduced model (docs/design.md §6).
    pub fn kalman(&self, reduced: &ReducedModel) -> Result<PeriodicSchedule, CompileError> {
        let h = self
            .measurements
            .rows_of(&self.rows, reduced.outputs.as_ref());
        let q = reduced.process_noise();
        kalman::periodic_gains(
            reduced.transition.as_ref(),
            h.as_ref(),
            q.as_ref(),
            &self.measurements.variance,
            &self.measurements.every,
        )
        .map_err(|source| {
            let path = self.full.scene_path().to_owned();
            match &source {
                KalmanError::Undetectable { .. } => match self.unseen_loads() {
                    Some(what) => CompileError::Unobservable { path, what },
                    None => CompileError::Kalman { path, source },
                },
                _ => CompileError::Kalman { path, source },
            }
        })
    }

    /// When the markers cannot tell the estimated loads apart in the full-order model
    /// ([`crate::observability`]): what is unseen and what to change.
    fn unseen_loads(&self) -> Option<String> {
        let noise = self.full.noise_model().ok()?;
        let channels = noise.force_channels();
        let g =
            observability::static_marker_response(self.full, &self.measurements, &channels).ok()?;
        let labels: Vec<String> = channels
            .iter()
            .map(|&ch| self.full.operators.inputs[ch].label.clone())
            .collect();
        let (combination, _) = observability::unseen_combination(&g, &labels)?;
        Some(format!(
            "the markers cannot tell the estimated loads apart: the force {combination} moves \
             no marker in the static response ({} estimated force channels, {} marker \
             channels), so no filter can estimate it. Add a marker where that force moves the \
             body, or state force_model = \"white\" on a load the runtime is always told (then \
             it is not estimated)",
            channels.len(),
            self.measurements.len()
        ))
    }

    /// Relative L2 errors of a reduced model against the full-order linear reference on a unit
    /// step and a chirp (docs/design.md §7). The reference runs once per reductor, on first use.
    pub fn measured_errors(
        &self,
        reduced: &ReducedModel,
    ) -> Result<BTreeMap<String, f64>, CompileError> {
        Ok(self.reference()?.errors(reduced))
    }

    /// Per test, the RMS error of each sensor displacement row against the full-order linear
    /// reference (m per unit load; [`ReferenceResponses::sensor_rms_errors`], docs/design.md
    /// §11.3).
    pub fn sensor_rms_errors(
        &self,
        reduced: &ReducedModel,
    ) -> Result<BTreeMap<String, Vec<f64>>, CompileError> {
        Ok(self.reference()?.sensor_rms_errors(reduced))
    }

    /// How the measured error's full-order reference is stepped: with the model's own
    /// Wilson-θ at Δt (the error is then the reduction's alone), or, for a model stepped
    /// exactly (`[time] scheme = "exact"`), converged in time at Δt/[`CONVERGED_SUBSTEPS`]
    /// (there is no full-order exact step to compare with).
    pub fn reference_stepping(&self) -> accuracy::Stepping {
        accuracy::Stepping::for_scheme(self.full.scene.scene.time.scheme)
    }

    /// The Wilson-θ step's own error, estimated on the modal system ([`crate::step_error`]),
    /// for the measured error's step and chirp and a unit step on each input channel; empty
    /// for an exactly stepped model (its measured error is against the converged reference).
    pub fn step_errors(&self) -> Result<Vec<StepError>, CompileError> {
        if self.full.scene.scene.time.scheme == Scheme::Exact {
            return Ok(Vec::new());
        }
        let (steps, f_high) = self.measure_plan();
        let mut tests = accuracy::standard_tests(self.full, steps, f_high);
        tests.extend(accuracy::channel_steps(self.full, steps));
        let rows: Vec<(usize, f64)> = accuracy::measured_rows(&self.rows)
            .iter()
            .map(|&(i, _)| (i, self.weights[i]))
            .collect();
        step_error::estimate(&self.system, &rows, &tests).map_err(|source| CompileError::Reduce {
            path: self.full.scene_path().to_owned(),
            source,
        })
    }

    /// The measured error's load tests (docs/design.md §7): steps per test (two periods of the
    /// lowest mode, 100 to [`MEASURE_MAX_STEPS`]) and the chirp's top frequency, Hz (the
    /// scene's `max_frequency`, else 5 f₁ capped at 0.2/Δt).
    pub fn measure_plan(&self) -> (usize, f64) {
        let f1 = self
            .basis
            .frequencies_hz
            .first()
            .copied()
            .unwrap_or(1.0)
            .max(1e-9);
        let dt = self.full.wilson.dt;
        let steps = ((2.0 / (f1 * dt)).ceil() as usize).clamp(100, MEASURE_MAX_STEPS);
        let f_high = match self.full.scene.scene.reduction.max_frequency {
            Some(f) => f,
            None => (5.0 * f1).min(0.2 / dt),
        };
        (steps, f_high)
    }

    /// The full-order linear responses the measured error compares against (docs/design.md §7),
    /// simulated on first use and kept.
    pub fn reference(&self) -> Result<&ReferenceResponses, CompileError> {
        if let Some(reference) = self.reference.get() {
            return Ok(reference);
        }
        {
            let (steps, f_high) = self.measure_plan();
            let tests = accuracy::standard_tests(self.full, steps, f_high);
            let responses = ReferenceResponses::simulate_with(
                self.full,
                &self.rows,
                tests,
                self.reference_stepping(),
            )
            .map_err(|source| CompileError::Stepping {
                path: self.full.scene_path().to_owned(),
                source,
            })?;
            Ok(self.reference.get_or_init(|| responses))
        }
    }

    /// Highest kept vibration frequency (static-correction vectors excluded), Hz.
    pub fn highest_kept_frequency_hz(&self) -> f64 {
        self.basis
            .frequencies_hz
            .iter()
            .zip(&self.basis.static_correction)
            .filter(|(_, &is_static)| !is_static)
            .map(|(&f, _)| f)
            .fold(0.0, f64::max)
    }
}

/// One order the default rule measured.
#[derive(Clone, Debug, PartialEq)]
pub struct RuleCandidate {
    /// Its tolerance on σ_{r+1}/σ₁.
    pub tolerance: f64,
    /// Its balanced order r.
    pub order: usize,
    /// Worst of the step and chirp on every load group together.
    pub joint: f64,
    /// The input channel with the largest static error, and that error (None when the model has
    /// no steady state or no input channel).
    pub channel: Option<(String, f64)>,
}

impl RuleCandidate {
    /// Whether the joint error meets [`DEFAULT_ERROR_TARGET`] and every channel's static error
    /// [`DEFAULT_CHANNEL_STATIC_TARGET`].
    pub fn met(&self) -> bool {
        self.joint <= DEFAULT_ERROR_TARGET && self.channel_met()
    }

    fn channel_met(&self) -> bool {
        self.channel
            .as_ref()
            .is_none_or(|(_, e)| *e <= DEFAULT_CHANNEL_STATIC_TARGET)
    }
}

/// The default order rule's note on `tried` (in ladder order; the last is the one built): the
/// tolerance chosen, why, and every candidate with its joint error and worst channel. When the
/// last candidate misses a target, the note says which (the joint error, or the channel named
/// with its static error) at the largest order tried.
pub fn rule_note(tried: &[RuleCandidate]) -> String {
    let Some(last) = tried.last() else {
        return "order rule: no candidate".into();
    };
    let tol = last.tolerance;
    let verdict = if last.met() {
        format!(
            "the loosest tolerance meeting the measured-error target {DEFAULT_ERROR_TARGET:.0e} \
             and every input channel's static error ≤ {DEFAULT_CHANNEL_STATIC_TARGET:.0e}"
        )
    } else {
        let mut missed = Vec::new();
        if last.joint > DEFAULT_ERROR_TARGET {
            missed.push(format!(
                "the measured-error target {DEFAULT_ERROR_TARGET:.0e} is NOT met (worst {:.2e})",
                last.joint
            ));
        }
        if let (false, Some((label, e))) = (last.channel_met(), &last.channel) {
            missed.push(format!(
                "input channel '{label}' is NOT brought under the static-error target \
                 {DEFAULT_CHANNEL_STATIC_TARGET:.0e} ({e:.2e})"
            ));
        }
        format!(
            "{} down to tolerance {tol:.0e}, the ladder's last (r = {}, the largest order \
             tried); set reduction.order or reduction.tolerance",
            missed.join(" and "),
            last.order
        )
    };
    let list: Vec<String> = tried
        .iter()
        .map(|c| {
            let channel = c
                .channel
                .as_ref()
                .map_or(String::new(), |(l, e)| format!(", static '{l}' {e:.2e}"));
            format!(
                "{:.0e}: r = {}, {:.2e}{channel}",
                c.tolerance, c.order, c.joint
            )
        })
        .collect();
    format!(
        "order rule: tolerance {tol:.0e}, {verdict} (tried {})",
        list.join("; ")
    )
}

/// A warning when Δt resolves none of the kept vibration modes: the lowest kept mode's period
/// spans fewer than 4 steps (f > 1/(4Δt), the default cut-off of the modal basis), so
/// Wilson-θ damps every kept mode numerically and the model is quasi-static at best.
fn unresolved_modes_note(basis: &reduce::ModalBasis, dt: f64) -> Option<String> {
    let lowest = *basis.frequencies_hz[..basis.n_eigenmodes].first()?;
    let resolved = wilson::highest_resolved_hz(dt);
    (lowest > resolved).then(|| {
        format!(
            "time.dt = {dt:e} s resolves none of the kept vibration modes: the lowest is \
             {lowest:.4} Hz, above 1/(4Δt) = {resolved:.4e} Hz, so Wilson-θ damps every kept mode \
             numerically; for dynamics choose dt ≤ {:.3e} s",
            wilson::resolving_dt(lowest)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(tolerance: f64, order: usize, joint: f64, weak: f64) -> RuleCandidate {
        RuleCandidate {
            tolerance,
            order,
            joint,
            channel: Some(("weak.x".into(), weak)),
        }
    }

    /// Two channels, one 300× weaker (the cantilever's axial tip.x against bending): the joint
    /// error meets the target at the first rung, the weak channel's static error does not; a
    /// candidate passes only when both do, and the note names the weak channel per rung.
    #[test]
    fn a_weak_channel_holds_the_rule_until_it_is_under_the_target() {
        let first = candidate(1e-3, 22, 4.85e-4, 1.51e-1);
        assert!(!first.met(), "the joint error alone would pass it");
        let met = candidate(3e-6, 47, 5.25e-6, 4.90e-4);
        assert!(met.met());
        let note = rule_note(&[first.clone(), met]);
        assert!(
            note.starts_with("order rule: tolerance 3e-6, the loosest tolerance meeting")
                && note.contains("1e-3: r = 22, 4.85e-4, static 'weak.x' 1.51e-1")
                && note.contains("3e-6: r = 47, 5.25e-6, static 'weak.x' 4.90e-4"),
            "{note}"
        );
        // At the ladder's end with the weak channel still above: the compile goes on and the
        // note names the channel and the largest order tried.
        let last = candidate(3e-6, 30, 4e-4, 2.0e-2);
        let note = rule_note(&[first, last]);
        assert!(
            note.contains("input channel 'weak.x' is NOT brought under the static-error target 1e-3 (2.00e-2)")
                && note.contains("r = 30, the largest order tried")
                && !note.contains("measured-error target 1e-3 is NOT met"),
            "{note}"
        );
        // Both missed.
        let note = rule_note(&[candidate(3e-6, 88, 6.27e-3, 2.0e-2)]);
        assert!(
            note.contains(
                "measured-error target 1e-3 is NOT met (worst 6.27e-3) and input channel 'weak.x'"
            ),
            "{note}"
        );
        // No channel figure (no steady state): the joint error decides.
        let none = RuleCandidate {
            channel: None,
            ..candidate(1e-3, 10, 1e-4, 0.0)
        };
        assert!(none.met());
    }
}
