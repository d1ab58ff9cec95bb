//! Build once, reduce many times (pyMOR's reductor pattern): the full-order model's output
//! layout, its modal basis and modal Wilson-θ system are computed once; balanced truncations
//! of any order r, their Kalman schedules and model files are derived from them
//! (docs/design.md §4, §6).

use std::cell::OnceCell;
use std::collections::BTreeMap;

use faer::linalg::solvers::Solve as _;
use faer::sparse::SparseColMat;
use faer::Mat;

use crate::accuracy::{self, ReferenceResponses};
use crate::error::CompileError;
use crate::full_order::FullOrder;
use crate::kalman::{self, PeriodicSchedule};
use crate::outputs::{columns, stack_rows, Measurements, OutputRows};
use crate::reduce::{self, ModalBasis, ModalSystem, Order};
use crate::reduced::ReducedModel;
use crate::report::StageTimer;
use crate::scene::ForceModel;

/// Default tolerance σ_{r+1}/σ₁ when neither order nor tolerance is given.
pub const DEFAULT_TOLERANCE: f64 = 1e-4;

/// Cap on the number of vibration modes when the scene gives no count. On the 50k-tetrahedron
/// beam, 60 modes instead of 200 cut the modal stage from 61 s to 5 s and left the measured
/// error unchanged (3.1e-4 step, 5.5e-4 chirp): the balanced truncation, not the modal cut,
/// sets the error there.
pub const DEFAULT_MAX_MODES: usize = 60;

/// Longest step/chirp history of the measured error, steps.
pub const MEASURE_MAX_STEPS: usize = 400;

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
    reference: OnceCell<ReferenceResponses>,
    static_outputs: OnceCell<Mat<f64>>,
}

impl<'a> Reductor<'a> {
    /// Builds the output layout, the modal basis (`modes` vibration modes, or every mode up to a
    /// quarter of the sampling frequency capped at [`DEFAULT_MAX_MODES`]) and the modal system.
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
        let outputs: SparseColMat<usize, f64> = stack_rows(&weighted, n);
        let input_columns: Vec<&[f64]> = ops
            .inputs
            .iter()
            .chain(&ops.noise)
            .map(|c| c.column.as_slice())
            .collect();
        let b: Mat<f64> = columns(&input_columns, n);
        let modes = modes.or(full.scene.scene.reduction.modes);
        let modal_options = reduce::ModalOptions {
            modes,
            // Without an explicit count: every mode up to half the Nyquist frequency (Wilson-θ
            // damps the rest numerically), capped; static correction covers the quasi-static
            // rest.
            max_frequency_hz: if modes.is_some() {
                None
            } else {
                Some(0.25 / full.wilson.dt)
            },
            max_modes: modes.unwrap_or(DEFAULT_MAX_MODES).max(1),
            ..reduce::ModalOptions::default()
        };
        let basis = timer
            .stage("modes", || {
                reduce::modal_basis(
                    fem.stiffness.as_ref(),
                    fem.mass.as_ref(),
                    b.as_ref(),
                    &modal_options,
                )
            })
            .map_err(reduce_err)?;
        let system = timer
            .stage("modal_system", || {
                ModalSystem::new(
                    &basis,
                    b.as_ref(),
                    outputs.as_ref(),
                    fem.alpha,
                    fem.beta,
                    full.wilson,
                )
            })
            .map_err(reduce_err)?;
        Ok(Reductor {
            full,
            measurements: Measurements::new(ops),
            rows,
            weights,
            basis,
            system,
            reference: OnceCell::new(),
            static_outputs: OnceCell::new(),
        })
    }

    /// The order rule: an explicit order, else a tolerance, from the arguments, then the scene's
    /// `[reduction]` table, then [`DEFAULT_TOLERANCE`].
    pub fn order(&self, order: Option<usize>, tolerance: Option<f64>) -> Order {
        let spec = self.full.scene.scene.reduction;
        match (order.or(spec.order), tolerance.or(spec.tolerance)) {
            (Some(r), _) => Order::Fixed(r),
            (None, Some(t)) => Order::Tolerance(t),
            (None, None) => Order::Tolerance(DEFAULT_TOLERANCE),
        }
    }

    /// Balanced truncation of the given order, unweighted and sign-normalised, with the force
    /// states of the scene's random-walk load groups appended.
    pub fn reduce(&self, order: Order) -> Result<ReducedModel, CompileError> {
        let truncation =
            self.system
                .balanced_truncation(order)
                .map_err(|source| CompileError::Reduce {
                    path: self.full.scene_path().to_owned(),
                    source,
                })?;
        let ops = &self.full.operators;
        let reduced = ReducedModel::from_truncation(truncation, ops.inputs.len(), &self.weights);
        let random_walk: Vec<(usize, f64)> = self
            .full
            .scene
            .scene
            .loads
            .iter()
            .enumerate()
            .filter(|(_, l)| l.force_model == ForceModel::RandomWalk && l.force_noise_std > 0.0)
            .map(|(i, l)| (i, l.force_noise_std))
            .collect();
        Ok(if random_walk.is_empty() {
            reduced
        } else {
            let exact = self.static_outputs()?;
            reduced.with_force_states(ops, &random_walk, Some(exact))
        })
    }

    /// The full-order static response K⁻¹ b_j of every deterministic input channel j on every
    /// output row (p × m, unweighted, [`OutputRows::weighted`] order; m per channel, or per N
    /// for load channels), computed once (one sparse Cholesky of K) on first use. The force
    /// states' static residual is built from it (docs/design.md §11).
    pub fn static_outputs(&self) -> Result<&Mat<f64>, CompileError> {
        if let Some(s) = self.static_outputs.get() {
            return Ok(s);
        }
        let fem = &self.full.fem;
        let inputs = &self.full.operators.inputs;
        let weighted = self.rows.weighted();
        let n = fem.dof_count();
        let llt =
            fem.stiffness
                .sp_cholesky(faer::Side::Lower)
                .map_err(|e| CompileError::Stepping {
                    path: self.full.scene_path().to_owned(),
                    source: crate::stepping::SteppingError::NotPositiveDefinite {
                        what: "stiffness K (static response of the force states)".into(),
                        n,
                        detail: format!("{e:?}"),
                    },
                })?;
        let mut u = Mat::from_fn(n, inputs.len(), |i, j| inputs[j].column[i]);
        llt.solve_in_place(u.as_mut());
        let mut out = Mat::<f64>::zeros(weighted.len(), inputs.len());
        for j in 0..inputs.len() {
            for (i, (row, _)) in weighted.iter().enumerate() {
                out[(i, j)] = row.iter().map(|&(d, w)| w * u[(d, j)]).sum();
            }
        }
        Ok(self.static_outputs.get_or_init(|| out))
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
        .map_err(|source| CompileError::Kalman {
            path: self.full.scene_path().to_owned(),
            source,
        })
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

    /// The full-order linear responses of the standard tests, simulated on first use.
    fn reference(&self) -> Result<&ReferenceResponses, CompileError> {
        if self.reference.get().is_none() {
            let f1 = self
                .basis
                .frequencies_hz
                .first()
                .copied()
                .unwrap_or(1.0)
                .max(1e-9);
            let dt = self.full.wilson.dt;
            let steps = ((2.0 / (f1 * dt)).ceil() as usize).clamp(100, MEASURE_MAX_STEPS);
            let f_high = (5.0 * f1).min(0.2 / dt);
            let tests = accuracy::standard_tests(self.full, steps, f_high);
            let responses =
                ReferenceResponses::simulate(self.full, &self.rows, tests).map_err(|source| {
                    CompileError::Stepping {
                        path: self.full.scene_path().to_owned(),
                        source,
                    }
                })?;
            // Set once: `get` was empty above and nothing else writes the cell.
            let _ = self.reference.set(responses);
        }
        self.reference.get().ok_or_else(|| CompileError::Stepping {
            path: self.full.scene_path().to_owned(),
            source: crate::stepping::SteppingError::Solver(
                "internal: reference responses not stored".into(),
            ),
        })
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
