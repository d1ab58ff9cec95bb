//! The co-rotational tier assembled and measured (docs/design.md §10): training → POD basis →
//! ECSW sampling → reduced stepper ([`build`]), its open-loop error and step time against the
//! full-order co-rotational reference in the same run ([`open_loop`]), and the static
//! cantilever against the full-order FEM and the elastica ([`elastica`]).
//!
//! Errors are relative L2 over the displayed nodes and the whole trajectory (steps 1..N),
//! e = sqrt(Σ_k Σ_i |u_i(t_k) − u_ref,i(t_k)|² / Σ_k Σ_i |u_ref,i(t_k)|²), world frame (m), as
//! in the README.

use std::path::Path;
use std::time::Instant;

use nalgebra::{DMatrix, DVector};

use crokf_compile::stepping::{
    static_solve, CorotationalSimulator, NewtonOptions, Simulator, SteppingError,
};
use crokf_compile::FullOrder;

use crate::scenario::{Horizon, Scenario};

use super::floors::displayed_dofs;
use super::training;
use super::TierError;
use crokf_compile::nonlinear::reduced::{
    HyperReducedModel, ReducedNewton, ReducedStats, ReducedStepper,
};

/// The tier built from training: the compiler's (`crokf_compile::nonlinear::tier`).
pub use crokf_compile::nonlinear::tier::{build, from_training, Tier};

/// Open-loop comparison of one scenario.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenLoop {
    /// Steps.
    pub steps: usize,
    /// Relative L2 over displayed nodes and all steps, reduced vs full-order co-rotational.
    pub error: f64,
    /// Same at the sensor named `tip` (None without one).
    pub tip_error: Option<f64>,
    /// Median wall time of a full-order co-rotational step (Newton to 1e-8), s.
    pub full_step: f64,
    /// Median wall time of a reduced step, s.
    pub reduced_step: f64,
    /// Reduced Newton counters.
    pub stats: ReducedStats,
    /// Largest nodal displacement of the reference, m.
    pub max_displacement: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs `scenario` (fixed horizon) on the full-order co-rotational model, then on the tier's
/// reduced stepper once per entry of `newtons`, step k → k+1 holding f(t_k); the reduced load
/// is Vᵀf (computed outside the timed step, as the runtime would apply a stored VᵀB).
pub fn open_loop(
    full: &FullOrder,
    tier: &Tier,
    newtons: &[ReducedNewton],
    scenario: &Scenario,
    path: &Path,
) -> Result<Vec<OpenLoop>, TierError> {
    let dt = full.wilson.dt;
    let steps = match scenario.horizon(dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => {
            return Err(TierError::Invalid(format!(
                "{}: the comparison needs a fixed horizon (`duration` or `steps`)",
                path.display()
            )))
        }
    };
    let fem = &full.fem;
    let n = fem.dof_count();
    let v = &tier.basis.vectors;
    let (_, dofs) = displayed_dofs(full);
    let display_rows = DMatrix::from_fn(dofs.len(), v.ncols(), |i, j| {
        dofs[i].map_or(0.0, |d| v[(d, j)])
    });
    let tip = full.operators.sensors.iter().find(|s| s.name == "tip");
    let tip_dofs: Vec<(usize, usize, f64)> = tip
        .map(|s| {
            s.weights
                .iter()
                .flat_map(|&(node, w)| {
                    (0..3).filter_map(move |c| fem.dofs.index[node][c].map(|d| (c, d, w)))
                })
                .collect()
        })
        .unwrap_or_default();
    let tip_of = |value: &dyn Fn(usize) -> f64| {
        let mut a = [0.0; 3];
        for &(c, d, w) in &tip_dofs {
            a[c] += w * value(d);
        }
        a
    };
    // Reference: displayed DOFs and tip per step, and the reduced loads.
    let mut reference = CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default())?;
    let mut full_times = Vec::with_capacity(steps);
    let mut shown_ref = Vec::with_capacity(steps);
    let mut tip_ref = Vec::with_capacity(steps);
    let mut loads = Vec::with_capacity(steps);
    let mut max_displacement: f64 = 0.0;
    for k in 0..steps {
        let f = scenario.load_vector(&full.operators, n, k as f64 * dt);
        let clock = Instant::now();
        reference.step(&f)?;
        full_times.push(clock.elapsed().as_secs_f64());
        loads.push(v.tr_mul(&DVector::from_column_slice(&f)));
        let u = reference.displacement();
        if u.iter().any(|x| !x.is_finite()) {
            return Err(SteppingError::NonFinite {
                step: k + 1,
                time: (k + 1) as f64 * dt,
            }
            .into());
        }
        max_displacement = max_displacement.max(training::max_nodal(fem, u));
        shown_ref.push(
            dofs.iter()
                .map(|d| d.map_or(0.0, |d| u[d]))
                .collect::<Vec<f64>>(),
        );
        tip_ref.push(tip_of(&|d| u[d]));
    }
    let full_step = median(full_times);
    let ratio = |e: f64, r: f64| if r > 0.0 { (e / r).sqrt() } else { 0.0 };
    let mut out = Vec::new();
    for &newton in newtons {
        let mut reduced = ReducedStepper::new(tier.model.clone(), newton)?;
        let mut reduced_times = Vec::with_capacity(steps);
        let (mut err2, mut ref2, mut tip_err2, mut tip_ref2) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..steps {
            let clock = Instant::now();
            reduced.step(&loads[k])?;
            reduced_times.push(clock.elapsed().as_secs_f64());
            let q = reduced.coordinates();
            let shown = &display_rows * q;
            for (i, exact) in shown_ref[k].iter().enumerate() {
                err2 += (shown[i] - exact).powi(2);
                ref2 += exact * exact;
            }
            let a = tip_of(&|d| (v.row(d) * q)[0]);
            for c in 0..3 {
                tip_err2 += (a[c] - tip_ref[k][c]).powi(2);
                tip_ref2 += tip_ref[k][c] * tip_ref[k][c];
            }
        }
        out.push(OpenLoop {
            steps,
            error: ratio(err2, ref2),
            tip_error: tip.map(|_| ratio(tip_err2, tip_ref2)),
            full_step,
            reduced_step: median(reduced_times),
            stats: reduced.stats(),
            max_displacement,
        });
    }
    Ok(out)
}

/// Median wall times (s) of one reduced force evaluation (with damping) and of one reduced
/// tangent assembly at the reduced state `q`, over `repeats` calls each.
pub fn component_times(model: &HyperReducedModel, q: &DVector<f64>, repeats: usize) -> [f64; 2] {
    let r = model.order();
    let velocity = vec![0.0; r];
    let mut out = vec![0.0; r];
    let mut force = Vec::with_capacity(repeats);
    let mut tangent = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let clock = Instant::now();
        model.force_with_damping(q.as_slice(), &velocity, model.beta, &mut out);
        force.push(clock.elapsed().as_secs_f64());
        std::hint::black_box(&out);
        let clock = Instant::now();
        let t = model.tangent(q, 1.0, true);
        tangent.push(clock.elapsed().as_secs_f64());
        std::hint::black_box(&t);
    }
    [median(force), median(tangent)]
}

/// One row of the static cantilever table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElasticaRow {
    /// α = PL²/EI (EI of the mesh).
    pub alpha: f64,
    /// Tip load P, N.
    pub load: f64,
    /// Inextensible elastica: tip deflection and draw-in, m.
    pub elastica: [f64; 2],
    /// Full-order co-rotational FEM: tip deflection and draw-in, m (load-weighted mean of the
    /// tip face).
    pub full: [f64; 2],
    /// Reduced tier: the same, m.
    pub reduced: [f64; 2],
}

/// The inextensible, shear-free elastica of a cantilever (length 1) under a dead tip load
/// perpendicular to its axis with α = PL²/EI: θ'' = −α cos θ, θ(0) = 0, θ'(1) = 0, by shooting
/// on θ'(0) (bisection, RK4 with 2,000 steps). Returns (deflection, draw-in)/L.
pub fn elastica_tip(alpha: f64) -> [f64; 2] {
    let integrate = |k0: f64| {
        let steps = 2000;
        let h = 1.0 / steps as f64;
        // state: θ, κ, x, y
        let rhs = |s: [f64; 4]| [s[1], -alpha * s[0].cos(), s[0].cos(), s[0].sin()];
        let mut s = [0.0, k0, 0.0, 0.0];
        for _ in 0..steps {
            let k1 = rhs(s);
            let k2 = rhs(std::array::from_fn(|i| s[i] + 0.5 * h * k1[i]));
            let k3 = rhs(std::array::from_fn(|i| s[i] + 0.5 * h * k2[i]));
            let k4 = rhs(std::array::from_fn(|i| s[i] + h * k3[i]));
            s = std::array::from_fn(|i| {
                s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
        }
        s
    };
    // κ(1) decreases with... bisection on the sign of κ(1) between κ0 = 0 (κ(1) < 0) and α.
    let (mut lo, mut hi) = (0.0, alpha);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if integrate(mid)[1] < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let s = integrate(0.5 * (lo + hi));
    [s[3], 1.0 - s[2]]
}

/// Static cantilever: a dead tip load P (on load group `load`, world direction `direction`,
/// perpendicular to the beam axis x) at α = PL²/EI for each of `alphas`, EI = PL³/(3δ) from
/// the mesh's own linear stiffness (δ the linear tip deflection, so locking is factored out).
/// Full-order co-rotational static solve against the tier's reduced static solve.
/// Returns (EI of the mesh N·m², L m, rows).
pub fn elastica(
    full: &FullOrder,
    tier: &Tier,
    load: &str,
    direction: [f64; 3],
    alphas: &[f64],
) -> Result<(f64, f64, Vec<ElasticaRow>), TierError> {
    let fem = &full.fem;
    let ops = &full.operators;
    let n = fem.dof_count();
    let Some(group) = ops.loads.iter().position(|l| l.name == load) else {
        return Err(TierError::Invalid(format!(
            "'{load}' is not a load group of the scene"
        )));
    };
    let unit = |p: f64| {
        let mut f = vec![0.0; n];
        for ch in &ops.inputs {
            if let crokf_compile::fem::operators::InputKind::Load { load: l, component } = ch.kind {
                if l == group {
                    f.iter_mut()
                        .zip(&ch.column)
                        .for_each(|(fi, b)| *fi += p * direction[component] * b);
                }
            }
        }
        f
    };
    let tip = |u: &[f64]| {
        let nodal = fem.nodal(u);
        let mut d = [0.0; 3];
        for &(node, w) in &ops.loads[group].weights {
            for c in 0..3 {
                d[c] += w * nodal[node][c];
            }
        }
        let deflection: f64 = (0..3).map(|c| d[c] * direction[c]).sum();
        [deflection, -d[0]]
    };
    let xs = fem.positions.iter().map(|p| p[0]);
    let length = xs.clone().fold(f64::NEG_INFINITY, f64::max) - xs.fold(f64::INFINITY, f64::min);
    let linear = static_solve(fem, &unit(1.0))?;
    let delta = tip(&linear)[0];
    if delta.is_nan() || delta <= 0.0 {
        return Err(TierError::Invalid(format!(
            "linear tip deflection {delta:e} m under 1 N is not positive"
        )));
    }
    let ei = length.powi(3) / (3.0 * delta);
    let mut simulator = CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default())?;
    let v = &tier.basis.vectors;
    let mut rows = Vec::new();
    for &alpha in alphas {
        let p = alpha * ei / (length * length);
        let f = unit(p);
        let u = simulator.static_solve(&f, 1e-9)?;
        let q = tier
            .model
            .static_solve(&v.tr_mul(&DVector::from_column_slice(&f)), 1e-10)?;
        let ur = v * q;
        let closed = elastica_tip(alpha);
        rows.push(ElasticaRow {
            alpha,
            load: p,
            elastica: closed.map(|x| x * length),
            full: tip(&u),
            reduced: tip(ur.as_slice()),
        });
    }
    Ok((ei, length, rows))
}
