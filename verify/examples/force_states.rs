//! Diagnosis of the random-walk force states at low order (docs/design.md §11):
//! per balanced order r, the static (DC) response of the truncated model to each load channel
//! against the full-order static solve, per output group (sensor displacement and rotation,
//! load rotation, displayed-node displacement and rotation), the observability of a constant
//! force through the markers (singular values of the σ-scaled sensor DC gain) and the
//! steady-state filter's force uncertainty and slowest closed-loop pole.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example force_states -- SCENE [r1,r2,…]
//! ```

use std::path::PathBuf;

use crokf_compile::fem::operators::InputKind;
use crokf_compile::reduce::Order;
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::static_solve;
use crokf_compile::{FullOrder, Reductor};
use faer::linalg::solvers::Solve;
use faer::Mat;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let scene = PathBuf::from(args.next().ok_or("usage: force_states SCENE [r1,r2,…]")?);
    let orders: Vec<usize> = args
        .next()
        .unwrap_or_else(|| "4,8,11,16,19,24,35".into())
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&scene, &mut timer)?;
    let reductor = Reductor::new(&full, None, &mut timer)?;
    let ops = &full.operators;
    let weighted = reductor.rows.weighted();
    let p = weighted.len();
    // Output groups in weighted order.
    let ns = reductor.rows.sensors.len();
    let nl = reductor.rows.loads.len();
    let mut group = vec![""; p];
    for (i, g) in group.iter_mut().enumerate() {
        *g = if i < 6 * ns {
            if i % 6 < 3 {
                "sensor u"
            } else {
                "sensor ω"
            }
        } else if i < 6 * ns + 3 * nl {
            "load ω"
        } else if (i - 6 * ns - 3 * nl) % 6 < 3 {
            "node u"
        } else {
            "node ω"
        };
    }
    let groups = ["sensor u", "sensor ω", "load ω", "node u", "node ω"];
    let load_channels: Vec<usize> = (0..ops.inputs.len())
        .filter(|&j| matches!(ops.inputs[j].kind, InputKind::Load { .. }))
        .collect();
    // Full-order static responses per load channel, on every output row (unweighted).
    let exact: Vec<Vec<f64>> = load_channels
        .iter()
        .map(|&j| {
            let u = static_solve(&full.fem, &ops.inputs[j].column)?;
            Ok(weighted
                .iter()
                .map(|(row, _)| row.iter().map(|&(d, w)| w * u[d]).sum())
                .collect())
        })
        .collect::<Result<_, crokf_compile::stepping::SteppingError>>()?;
    let sigma: Vec<f64> = reductor
        .measurements
        .variance
        .iter()
        .map(|v| v.sqrt())
        .collect();
    println!(
        "scene {}: {} DOFs; load channels {:?}",
        scene.display(),
        full.fem.dof_count(),
        load_channels
            .iter()
            .map(|&j| ops.inputs[j].label.clone())
            .collect::<Vec<_>>()
    );
    println!(
        "| r | DC error {} (per load channel x,y,z) | σ_min/σ_max of σ-scaled marker DC gain | singular values of σ-scaled one-step H G (1/N) | σ(f) posterior (N) | ρ closed loop | slowest pole τ (steps) | meas. err step |",
        groups.join(" / ")
    );
    for &r in &orders {
        let reduced = reductor.reduce(Order::Fixed(r))?;
        let r0 = reduced.balanced_order;
        let f0 = reduced.transition.submatrix(0, 0, r0, r0).to_owned();
        let i_minus_f = Mat::<f64>::identity(r0, r0) - &f0;
        let lu = i_minus_f.partial_piv_lu();
        let mut per_group = Vec::new();
        let mut h_dc = Mat::<f64>::zeros(reductor.measurements.len(), load_channels.len());
        for (c, &j) in load_channels.iter().enumerate() {
            let g = reduced.input.submatrix(0, j, r0, 1).to_owned();
            let x = lu.solve(&g);
            let mut y = reduced.outputs.submatrix(0, 0, p, r0) * &x;
            // Force state of this channel (one load group: states r0 + c), its static residual.
            if reduced.state_dim() > r0 + c {
                for i in 0..p {
                    y[(i, 0)] += reduced.outputs[(i, r0 + c)];
                }
            }
            let mut errs = Vec::new();
            for name in groups {
                let (mut e2, mut n2) = (0.0, 0.0);
                for i in 0..p {
                    if group[i] == name {
                        e2 += (y[(i, 0)] - exact[c][i]).powi(2);
                        n2 += exact[c][i].powi(2);
                    }
                }
                errs.push(if n2 > 0.0 { (e2 / n2).sqrt() } else { f64::NAN });
            }
            per_group.push(errs);
            for (m, &(s, comp)) in reductor.measurements.channels.iter().enumerate() {
                h_dc[(m, c)] = y[(reductor.rows.sensor_row(s) + comp, 0)] / sigma[m];
            }
        }
        // One-step input gain H G (σ-scaled): Gillijns–De Moor's unbiased input estimator needs
        // rank(H G) = inputs and amplifies the noise by its inverse.
        let mut hg = Mat::<f64>::zeros(reductor.measurements.len(), load_channels.len());
        for (c, &j) in load_channels.iter().enumerate() {
            for (m, &(s, comp)) in reductor.measurements.channels.iter().enumerate() {
                let row = reductor.rows.sensor_row(s) + comp;
                hg[(m, c)] = (0..r0)
                    .map(|i| reduced.outputs[(row, i)] * reduced.input[(i, j)])
                    .sum::<f64>()
                    / sigma[m];
            }
        }
        let hg_sv = hg.singular_values().map_err(|e| format!("{e:?}"))?;
        let sv = h_dc.singular_values().map_err(|e| format!("{e:?}"))?;
        let cond = sv.last().copied().unwrap_or(0.0) / sv.first().copied().unwrap_or(1.0);
        let dc: Vec<String> = groups
            .iter()
            .enumerate()
            .map(|(k, _)| {
                per_group
                    .iter()
                    .map(|e| format!("{:.1e}", e[k]))
                    .collect::<Vec<_>>()
                    .join(",")
            })
            .collect();
        let (force_std, rho, tau) = match reductor.kalman(&reduced) {
            Ok(schedule) => {
                let phase = &schedule.phases[0];
                let rt = reduced.state_dim();
                let fs: Vec<String> = (r0..rt)
                    .map(|i| format!("{:.2e}", phase.posterior_covariance[(i, i)].sqrt()))
                    .collect();
                let rho = schedule.closed_loop_spectral_radius;
                let tau = -1.0 / rho.ln();
                (fs.join(","), format!("{rho:.5}"), format!("{tau:.1}"))
            }
            Err(e) => (format!("DARE failed: {e}"), "—".into(), "—".into()),
        };
        let measured = reductor.measured_errors(&reduced)?;
        // Process-noise check (docs/design.md §11.3): the truncation's own error per marker
        // channel (RMS over the unit step / chirp, m per N) against the marker σ.
        let rms = reductor.sensor_rms_errors(&reduced)?;
        let worst = |name: &str| {
            rms.get(name).map_or(f64::NAN, |v| {
                reductor
                    .measurements
                    .channels
                    .iter()
                    .zip(&sigma)
                    .map(|(&(s, c), sg)| v[3 * s + c] / sg)
                    .fold(0.0, f64::max)
            })
        };
        println!(
            "  r = {r0}: largest truncation error per marker channel / marker σ, per N of load: step {:.1e}, chirp {:.1e}",
            worst("step"),
            worst("chirp")
        );
        println!(
            "| {r0} | {} | {:.2e} (σ {}) | {} | {force_std} | {rho} | {tau} | {:.1e} |",
            dc.join(" / "),
            cond,
            sv.iter()
                .map(|v| format!("{v:.1e}"))
                .collect::<Vec<_>>()
                .join(","),
            hg_sv
                .iter()
                .map(|v| format!("{v:.1e}"))
                .collect::<Vec<_>>()
                .join(","),
            measured.get("step").copied().unwrap_or(f64::NAN),
        );
    }
    Ok(())
}
