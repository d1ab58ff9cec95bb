//! What the co-rotational tier's filter states about its load estimate (docs/design.md §11.7):
//! for the filter at rest and each filter of the gain schedule (§11.5), the standard deviations
//! of the force states f (N) and, with force rates, ḟ (N/s) that its stored covariances give
//! before (P⁻) and after (P) the update of the first phase that measures (with markers every
//! L steps: the marker step), per world component of each estimated load group.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example tier_force_sigma -- MODEL
//! ```
//! MODEL: a tier model file with force states (`force_model = "random_walk"`).

use crokf_formats::{KalmanGains, Matrix};
use std::process::ExitCode;

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [file] = args.as_slice() else {
        return Err("usage: tier_force_sigma MODEL".into());
    };
    let model = crokf_runtime::load_model(file)?;
    let tier = model
        .tier
        .as_ref()
        .ok_or_else(|| format!("{file}: no co-rotational tier"))?;
    if tier.force_loads.is_empty() {
        return Err(format!("{file}: the tier has no force states (a white force model)").into());
    }
    let r = tier.order as usize;
    let n = tier.state_dim();
    let Some(phase) = tier
        .kalman
        .phases
        .iter()
        .position(|p| !p.measured.is_empty())
    else {
        return Err(format!("{file}: no phase measures").into());
    };
    let names: Vec<String> = (3 * r..n)
        .map(|i| {
            let k = i - 3 * r;
            let groups = 3 * tier.force_loads.len();
            let (rate, k) = if k >= groups {
                ("ḟ", k - groups)
            } else {
                ("f", k)
            };
            let group = tier.force_loads[k / 3] as usize;
            let load = model.loads.get(group).map_or("?", |l| l.name.as_str());
            format!("{rate} {load}.{}", ["x", "y", "z"][k % 3])
        })
        .collect();
    println!(
        "phase {phase} of {} (the first that measures); σ in N (f) and N/s (ḟ), prior → posterior\n",
        tier.kalman.period
    );
    println!("| filter | ‖q*‖ | {} |", names.join(" | "));
    println!("|---|---:|{}", "---:|".repeat(names.len()));
    let sigma = |m: &Matrix, i: usize| m.data[i * n + i].max(0.0).sqrt();
    let row = |label: String, norm: f64, k: &KalmanGains| {
        let p = &k.phases[phase];
        let cells: Vec<String> = (3 * r..n)
            .map(|i| {
                format!(
                    "{:.3} → {:.3}",
                    sigma(&p.prior_covariance, i),
                    sigma(&p.posterior_covariance, i)
                )
            })
            .collect();
        println!("| {label} | {norm:.3e} | {} |", cells.join(" | "));
    };
    row("rest".into(), 0.0, &tier.kalman);
    for (i, s) in tier.scheduled.iter().enumerate() {
        let norm = s.point.iter().map(|v| v * v).sum::<f64>().sqrt();
        row(format!("{}", i + 1), norm, &s.kalman);
    }
    Ok(())
}
