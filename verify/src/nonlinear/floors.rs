//! Error floors of the co-rotational tier (docs/design.md §10): before any
//! reduced model is built, how well can a basis or a read-out represent the full-order
//! co-rotational trajectory at all?
//!
//! - Projection floor of a basis V (M-orthonormal, n × r): min_q ‖V_k q − u_t‖_M over the
//!   whole trajectory, relative, for nested sizes k ([`crokf_compile::nonlinear::basis::projection_errors`]); also
//!   the same M-projection measured as relative L2 over the displayed nodes (the README's
//!   error norm).
//! - Warped floor: the best fit of the warped linear read-out of §5,
//!   min_x Σ_i |R̃(W_i Φ x) Φ_i x − u_i|² per step over the displayed nodes i (Φ the whole modal
//!   basis with static correction, W_i the nodal rotation rows), by Levenberg–Marquardt; the
//!   figure is the relative L2 error over displayed nodes and the recorded steps.

use std::path::Path;

use faer::Mat;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crokf_compile::corotation::RotationRows;
use crokf_compile::reduce::{self, ModalBasis};
use crokf_compile::stepping::{CorotationalSimulator, Formulation, NewtonOptions};
use crokf_compile::FullOrder;

use crate::scenario::Scenario;
use crate::simulate::{simulate, Frame, SimulateError, SimulationOptions};
use crokf_compile::report::StageTimer;

use super::training::{self, Training, TrainingPlan};
use super::TierError;
use crokf_compile::algorithms::pod::pod;
use crokf_compile::nonlinear::basis::{self, Basis};

/// Modes kept by default, as in `crokf-compile` (every mode up to a quarter of the sampling
/// frequency, at most this many).
const MAX_MODES: usize = 60;

/// Options of [`floors`].
#[derive(Clone, Debug)]
pub struct FloorOptions {
    /// Training plan for the POD candidates (its runs must differ from the scenario).
    pub plan: TrainingPlan,
    /// Basis sizes to tabulate.
    pub sizes: Vec<usize>,
    /// Lowest eigenmodes that generate modal derivatives (with every static-correction vector).
    pub derivative_modes: usize,
    /// Fit the warped read-out every k-th reference step (k ≥ 1).
    pub warped_every: usize,
}

/// One candidate basis' floors.
#[derive(Clone, Debug, PartialEq)]
pub struct FloorRow {
    /// Candidate name.
    pub name: String,
    /// Its number of independent columns.
    pub columns: usize,
    /// Per tabulated size: relative M-norm projection error (NaN beyond `columns`).
    pub m_norm: Vec<f64>,
    /// Per tabulated size: the same projection, relative L2 over the displayed nodes.
    pub displayed: Vec<f64>,
}

/// The floor table of one scene and scenario.
#[derive(Clone, Debug)]
pub struct FloorTable {
    /// Tabulated sizes.
    pub sizes: Vec<usize>,
    /// Candidates.
    pub rows: Vec<FloorRow>,
    /// Best-fit warped read-out error, relative L2 over displayed nodes.
    pub warped: f64,
    /// Linear basis size used for the warped fit.
    pub warped_order: usize,
    /// Reference steps.
    pub steps: usize,
    /// Free DOFs.
    pub dofs: usize,
    /// Training summary.
    pub training: Training,
    /// Wall times: reference, training, bases, warped fit (s).
    pub seconds: [f64; 4],
}

impl FloorTable {
    /// The table as Markdown.
    pub fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "n = {} free DOFs, {} reference steps; training: {}/{} runs, {} snapshots, envelope ≤ {:.2}× range (max |u| {:.4} m)",
            self.dofs,
            self.steps,
            self.training.envelope.runs.0,
            self.training.envelope.runs.1,
            self.training.envelope.snapshots,
            self.training.envelope.max_multiple,
            self.training.envelope.max_displacement
        );
        let _ = writeln!(
            s,
            "\nBest-fit warped read-out (linear basis of {} vectors): {:.4} relative L2 over displayed nodes\n",
            self.warped_order, self.warped
        );
        let _ = write!(s, "| basis (M-norm / displayed L2) | columns |");
        for k in &self.sizes {
            let _ = write!(s, " r = {k} |");
        }
        let _ = write!(s, "\n|---|---:|");
        for _ in &self.sizes {
            let _ = write!(s, "---:|");
        }
        s.push('\n');
        for row in &self.rows {
            let _ = write!(s, "| {} | {} |", row.name, row.columns);
            for (m, d) in row.m_norm.iter().zip(&row.displayed) {
                if m.is_nan() {
                    let _ = write!(s, " — |");
                } else {
                    let _ = write!(s, " {m:.2e} / {d:.2e} |");
                }
            }
            s.push('\n');
        }
        let _ = writeln!(
            s,
            "\nwall time: reference {:.1} s, training {:.1} s, bases {:.1} s, warped fit {:.1} s",
            self.seconds[0], self.seconds[1], self.seconds[2], self.seconds[3]
        );
        s
    }
}

/// Runs the full-order co-rotational reference of `scenario` and returns every state after step
/// 0 (n each, m).
pub fn reference_trajectory(
    full: &FullOrder,
    scenario: &Scenario,
    path: &Path,
) -> Result<Vec<Vec<f64>>, TierError> {
    let mut frames = Vec::new();
    let mut observer = |frame: &Frame| -> Result<(), SimulateError> {
        if frame.step > 0 {
            frames.push(frame.displacement.to_vec());
        }
        Ok(())
    };
    let options = SimulationOptions {
        formulation: Formulation::Corotational,
        newton: NewtonOptions::default(),
        every: 1,
    };
    simulate(
        &full.fem,
        &full.operators,
        &full.scene.scene,
        scenario,
        &[],
        &options,
        path,
        &mut observer,
    )?;
    Ok(frames)
}

/// The linear basis of `crokf-compile`: eigenmodes of (K, M) up to a quarter of the sampling
/// frequency (at most 60) plus static corrections K⁻¹B for every input channel, M-orthonormal.
pub fn linear_basis(full: &FullOrder) -> Result<ModalBasis, TierError> {
    let fem = &full.fem;
    let ops = &full.operators;
    let n = fem.dof_count();
    let cols: Vec<&[f64]> = ops
        .inputs
        .iter()
        .chain(&ops.noise)
        .map(|c| c.column.as_slice())
        .collect();
    let b = Mat::from_fn(n, cols.len(), |i, j| cols[j][i]);
    let options = reduce::ModalOptions {
        max_frequency_hz: Some(full.wilson.highest_resolved_hz()),
        max_modes: MAX_MODES,
        ..reduce::ModalOptions::default()
    };
    Ok(reduce::modal_basis(
        fem.stiffness.as_ref(),
        fem.mass.as_ref(),
        b.as_ref(),
        &options,
    )?)
}

/// The linear basis' columns labelled and ordered static corrections first, then eigenmodes by
/// ascending frequency.
pub fn linear_candidates(modal: &ModalBasis) -> Vec<(String, Vec<f64>)> {
    let n = modal.vectors.nrows();
    let col = |j: usize| (0..n).map(|i| modal.vectors[(i, j)]).collect::<Vec<f64>>();
    let mut out = Vec::new();
    for j in 0..modal.len() {
        if modal.static_correction.get(j).copied().unwrap_or(false) {
            out.push((format!("static {}", out.len() + 1), col(j)));
        }
    }
    let mut k = 0;
    for j in 0..modal.len() {
        if !modal.static_correction.get(j).copied().unwrap_or(false) {
            k += 1;
            out.push((format!("mode {k}"), col(j)));
        }
    }
    out
}

/// The displayed nodes (union of the scene's node sets, first occurrence order) and their free
/// DOF indices (3 per node, `None` where fixed).
pub fn displayed_dofs(full: &FullOrder) -> (Vec<usize>, Vec<Option<usize>>) {
    let mut seen = vec![false; full.fem.positions.len()];
    let mut nodes = Vec::new();
    for set in &full.operators.node_sets {
        for &node in &set.nodes {
            if !std::mem::replace(&mut seen[node], true) {
                nodes.push(node);
            }
        }
    }
    let dofs = nodes
        .iter()
        .flat_map(|&node| full.fem.dofs.index[node])
        .collect();
    (nodes, dofs)
}

/// Relative L2 error over the displayed DOFs of the M-projection on the first k columns, for
/// each k of `sizes` (NaN where k exceeds the basis).
pub fn displayed_projection_errors(
    basis: &Basis,
    trajectory: &[Vec<f64>],
    dofs: &[Option<usize>],
    sizes: &[usize],
) -> Vec<f64> {
    let rows = DMatrix::from_fn(dofs.len(), basis.len(), |i, j| {
        dofs[i].map_or(0.0, |d| basis.vectors[(d, j)])
    });
    let mut err = vec![0.0; sizes.len()];
    let mut total = 0.0;
    let coefficients: Vec<DVector<f64>> = trajectory.iter().map(|u| basis.project(u)).collect();
    for (u, q) in trajectory.iter().zip(&coefficients) {
        total += dofs
            .iter()
            .map(|d| d.map_or(0.0, |d| u[d] * u[d]))
            .sum::<f64>();
        for (s, &k) in sizes.iter().enumerate() {
            if k > basis.len() {
                continue;
            }
            let fit = rows.columns(0, k) * q.rows(0, k);
            err[s] += dofs
                .iter()
                .zip(fit.iter())
                .map(|(d, f)| d.map_or(0.0, |d| (u[d] - f).powi(2)))
                .sum::<f64>();
        }
    }
    sizes
        .iter()
        .zip(&err)
        .map(|(&k, e)| {
            if k > basis.len() || total == 0.0 {
                f64::NAN
            } else {
                (e / total).sqrt()
            }
        })
        .collect()
}

fn row(
    name: &str,
    full: &FullOrder,
    candidates: &[(String, Vec<f64>)],
    trajectory: &[Vec<f64>],
    dofs: &[Option<usize>],
    sizes: &[usize],
) -> FloorRow {
    let largest = sizes.iter().copied().max().unwrap_or(0);
    let v = basis::m_orthonormalise(&full.fem.mass, candidates, 1e-6, largest);
    let all = basis::projection_errors(&full.fem.mass, &v, trajectory);
    FloorRow {
        name: name.to_owned(),
        columns: v.len(),
        m_norm: sizes
            .iter()
            .map(|&k| all.get(k).copied().unwrap_or(f64::NAN))
            .collect(),
        displayed: displayed_projection_errors(&v, trajectory, dofs, sizes),
    }
}

/// The floor table of `scenario` on `scene`: the full-order co-rotational
/// reference trajectory, the training runs of `options.plan`, the candidate bases
/// (modes + static correction; + static modal derivatives; POD of the training snapshots;
/// static correction + modes + training POD; POD of the reference itself, a tautological lower
/// bound) and the warped floor. `progress` receives one line per stage.
pub fn floors(
    scene: &Path,
    scenario_path: &Path,
    options: &FloorOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<FloorTable, TierError> {
    let full = FullOrder::build(scene, &mut StageTimer::default())?;
    let scenario = Scenario::read(scenario_path)?;
    scenario.check_scene(&full.scene.scene, scenario_path)?;
    let clock = std::time::Instant::now();
    progress("full-order co-rotational reference");
    let trajectory = reference_trajectory(&full, &scenario, scenario_path)?;
    let t_reference = clock.elapsed().as_secs_f64();

    let clock = std::time::Instant::now();
    let training = training::train(&full, &options.plan, &mut |k, of, label| {
        progress(&format!("training run {}/{of}: {label}", k + 1))
    })?;
    let t_training = clock.elapsed().as_secs_f64();

    let clock = std::time::Instant::now();
    progress("bases");
    let modal = linear_basis(&full)?;
    let linear = linear_candidates(&modal);
    let statics = linear.iter().filter(|c| c.0.starts_with("static")).count();
    let generators: Vec<_> = linear
        .iter()
        .take(statics + options.derivative_modes)
        .cloned()
        .collect();
    let mut simulator =
        CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default())?;
    let size = crokf_compile::mesh::bounding_diagonal(&full.fem.positions);
    let derivatives =
        basis::modal_derivatives(&full.fem, &mut simulator, &generators, 1e-3 * size)?;
    let largest = options.sizes.iter().copied().max().unwrap_or(0);
    let (training_pod, _) = pod(&full.fem.mass, &training.snapshots, largest, 1e-14);
    let (reference_pod, _) = pod(&full.fem.mass, &trajectory, largest, 1e-14);
    let (_, dofs) = displayed_dofs(&full);
    let sizes = &options.sizes;
    let with_derivatives: Vec<_> = generators
        .iter()
        .chain(&derivatives)
        .chain(linear.iter().skip(generators.len()))
        .cloned()
        .collect();
    let with_pod: Vec<_> = generators.iter().chain(&training_pod).cloned().collect();
    let derivatives_pod: Vec<_> = generators
        .iter()
        .chain(&derivatives)
        .chain(&training_pod)
        .cloned()
        .collect();
    let rows = vec![
        row("static + modes", &full, &linear, &trajectory, &dofs, sizes),
        row(
            &format!(
                "static + {} modes + {} modal derivatives (+ further modes)",
                options.derivative_modes,
                derivatives.len()
            ),
            &full,
            &with_derivatives,
            &trajectory,
            &dofs,
            sizes,
        ),
        row(
            "POD of training",
            &full,
            &training_pod,
            &trajectory,
            &dofs,
            sizes,
        ),
        row(
            &format!(
                "static + {} modes + POD of training",
                options.derivative_modes
            ),
            &full,
            &with_pod,
            &trajectory,
            &dofs,
            sizes,
        ),
        row(
            &format!(
                "static + {} modes + derivatives + POD of training",
                options.derivative_modes
            ),
            &full,
            &derivatives_pod,
            &trajectory,
            &dofs,
            sizes,
        ),
        row(
            "POD of the reference itself (tautology)",
            &full,
            &reference_pod,
            &trajectory,
            &dofs,
            sizes,
        ),
    ];
    let t_bases = clock.elapsed().as_secs_f64();

    let clock = std::time::Instant::now();
    progress("warped floor");
    let phi = basis::m_orthonormalise(&full.fem.mass, &linear, 1e-6, usize::MAX);
    let warped = warped_floor(&full, &phi, &trajectory, options.warped_every.max(1));
    let t_warped = clock.elapsed().as_secs_f64();
    Ok(FloorTable {
        sizes: sizes.clone(),
        rows,
        warped,
        warped_order: phi.len(),
        steps: trajectory.len(),
        dofs: full.fem.dof_count(),
        training,
        seconds: [t_reference, t_training, t_bases, t_warped],
    })
}

/// R̃(ω) v of docs/design.md §5 (the runtime's warp).
fn warp(omega: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    let w = crokf_runtime::warp::warp(&[omega[0], omega[1], omega[2]], &[v[0], v[1], v[2]]);
    Vector3::new(w[0], w[1], w[2])
}

/// Best fit of the warped read-out (module docs) to every `every`-th state of `trajectory`:
/// relative L2 error over the displayed nodes and those steps. Φ = `phi` (n × m).
pub fn warped_floor(full: &FullOrder, phi: &Basis, trajectory: &[Vec<f64>], every: usize) -> f64 {
    let fem = &full.fem;
    let m = phi.len();
    let (nodes, dofs) = displayed_dofs(full);
    let rot = RotationRows::new(fem);
    // Per displayed node: A (3 × m) displacement rows, B (3 × m) rotation rows of Φ.
    let a: Vec<DMatrix<f64>> = (0..nodes.len())
        .map(|i| {
            DMatrix::from_fn(3, m, |c, j| {
                dofs[3 * i + c].map_or(0.0, |d| phi.vectors[(d, j)])
            })
        })
        .collect();
    let b: Vec<DMatrix<f64>> = nodes
        .iter()
        .map(|&node| {
            let rows = rot.at_node(fem, node);
            DMatrix::from_fn(3, m, |c, j| {
                rows[c]
                    .iter()
                    .map(|&(d, w)| w * phi.vectors[(d, j)])
                    .sum::<f64>()
            })
        })
        .collect();
    let stacked_a = DMatrix::from_fn(3 * nodes.len(), m, |r, j| a[r / 3][(r % 3, j)]);
    let mut x = DVector::zeros(m);
    let (mut err2, mut ref2) = (0.0, 0.0);
    let residual = |x: &DVector<f64>, target: &DVector<f64>| -> DVector<f64> {
        let mut out = DVector::zeros(3 * nodes.len());
        for i in 0..nodes.len() {
            let v = &a[i] * x;
            let w = &b[i] * x;
            let fit = warp(
                &Vector3::new(w[0], w[1], w[2]),
                &Vector3::new(v[0], v[1], v[2]),
            );
            for c in 0..3 {
                out[3 * i + c] = fit[c] - target[3 * i + c];
            }
        }
        out
    };
    let mut first = true;
    for (t, u) in trajectory.iter().enumerate() {
        if (t + 1) % every != 0 && t + 1 != trajectory.len() {
            continue;
        }
        let target =
            DVector::from_iterator(dofs.len(), dofs.iter().map(|d| d.map_or(0.0, |d| u[d])));
        if first {
            // Start from the unwarped least-squares fit.
            let ata = stacked_a.tr_mul(&stacked_a);
            let atb = stacked_a.tr_mul(&target);
            if let Some(ch) = ata.cholesky() {
                x = ch.solve(&atb);
            }
            first = false;
        }
        let mut res = residual(&x, &target);
        let mut cost = res.norm_squared();
        let mut mu = 1e-3;
        for _ in 0..50 {
            let mut jac = DMatrix::zeros(3 * nodes.len(), m);
            for i in 0..nodes.len() {
                let v = &a[i] * &x;
                let w = &b[i] * &x;
                let (v, w) = (
                    Vector3::new(v[0], v[1], v[2]),
                    Vector3::new(w[0], w[1], w[2]),
                );
                // d(R̃(ω) v)/dω by central differences, 3 × 3.
                let h = 1e-7;
                let mut dw = Matrix3::zeros();
                for k in 0..3 {
                    let mut e = Vector3::zeros();
                    e[k] = h;
                    let diff = (warp(&(w + e), &v) - warp(&(w - e), &v)) / (2.0 * h);
                    dw.set_column(k, &diff);
                }
                let r = crokf_runtime::warp::warp_matrix(&[w[0], w[1], w[2]]);
                let r = Matrix3::from_fn(|p, q| r[p][q]);
                let block = DMatrix::from_fn(3, 3, |p, q| r[(p, q)]) * &a[i]
                    + DMatrix::from_fn(3, 3, |p, q| dw[(p, q)]) * &b[i];
                jac.view_mut((3 * i, 0), (3, m)).copy_from(&block);
            }
            let jtj = jac.tr_mul(&jac);
            let jtr = jac.tr_mul(&res);
            let mut improved = false;
            for _ in 0..10 {
                let mut lhs = jtj.clone();
                for k in 0..m {
                    lhs[(k, k)] += mu * jtj[(k, k)].max(1e-300);
                }
                let Some(ch) = lhs.cholesky() else {
                    mu *= 10.0;
                    continue;
                };
                let step = -ch.solve(&jtr);
                let trial = &x + &step;
                let trial_res = residual(&trial, &target);
                let trial_cost = trial_res.norm_squared();
                if trial_cost < cost {
                    let gain = cost - trial_cost;
                    x = trial;
                    res = trial_res;
                    let old = cost;
                    cost = trial_cost;
                    mu = (mu / 3.0).max(1e-12);
                    improved = gain > 1e-12 * old;
                    break;
                }
                mu *= 10.0;
            }
            if !improved {
                break;
            }
        }
        err2 += cost;
        ref2 += target.norm_squared();
    }
    if ref2 > 0.0 {
        (err2 / ref2).sqrt()
    } else {
        0.0
    }
}
