//! Runtime benchmark (a command, not a test; medians on one core):
//! `cargo run --release -p crokf-runtime --example bench`
//!
//! Synthetic models of the issue's shape (6 inputs on two load groups, 30 measured components
//! on 10 sensors, one displayed set of 5,000 nodes with warping), as in `crokf-verify bench`:
//! - step (predict + update) at r = 10, 20, 40, 80: median over 301 batches of 100 steps
//!   (batches short against a scheduler time slice, so that the median is an undisturbed one);
//! - read-out of the 5,000 node positions (warped): median over 101 calls;
//! - 1,000 estimators at r = 20 sharing one model: steps per second over all of them.
//!
//! `bench steps R N` runs only N steps at order R (for `perf stat -e cycles:u,instructions:u`).

use crokf_formats::*;
use crokf_runtime::Estimator;
use std::hint::black_box;

use crokf_formats::synthetic::median_seconds;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (inputs, measured, nodes) = (6, 30, 5000);
    // `bench steps R N`: only N steps at order R (for `perf stat` cycle and instruction counts).
    let args: Vec<String> = std::env::args().collect();
    if args.len() == 4 && args[1] == "steps" {
        let (r, n): (usize, usize) = (args[2].parse()?, args[3].parse()?);
        let model = crokf_formats::synthetic::benchmark_model(r, inputs, measured, 8);
        let mut est = Estimator::new(&model)?;
        let u = vec![0.5; inputs];
        let y: Vec<Option<f64>> = (0..measured).map(|i| Some(1e-4 * i as f64)).collect();
        for _ in 0..n {
            est.step(black_box(&u), black_box(&y))?;
        }
        println!("{:?}", &est.state()[..2]);
        return Ok(());
    }
    println!("runtime benchmark: {inputs} inputs, {measured} measured components, {nodes} displayed nodes (medians)");
    println!(
        "{:>4} {:>12} {:>22}",
        "r", "step µs", "read-out 5,000 nodes µs"
    );
    for r in [10, 20, 40, 80] {
        let model = crokf_formats::synthetic::benchmark_model(r, inputs, measured, nodes);
        let mut est = Estimator::new(&model)?;
        let u = vec![0.5; inputs];
        let mut rng = crokf_formats::synthetic::SplitMix64(7);
        let y: Vec<Option<f64>> = (0..measured).map(|_| Some(1e-3 * rng.uniform())).collect();
        let batch = 100;
        let mut failed = None;
        let step_s = median_seconds(301, || {
            for _ in 0..batch {
                if let Err(e) = est.step(black_box(&u), black_box(&y)) {
                    failed = Some(e);
                }
            }
        }) / batch as f64;
        if let Some(e) = failed {
            return Err(e.into());
        }
        let mut out = vec![0.0; 3 * nodes];
        let mut failed = None;
        let readout_s = median_seconds(101, || {
            if let Err(e) = est.node_positions(0, black_box(&mut out)) {
                failed = Some(e);
            }
        });
        if let Some(e) = failed {
            return Err(e.into());
        }
        println!("{r:>4} {:>12.3} {:>22.1}", step_s * 1e6, readout_s * 1e6);
    }
    many_instances()?;
    Ok(())
}

/// 1,000 estimators at r = 20 over one model, stepped round-robin.
fn many_instances() -> Result<(), Box<dyn std::error::Error>> {
    let (n, r) = (1000, 20);
    let model = crokf_formats::synthetic::benchmark_model(r, 6, 30, 5000);
    let mut ests = instances(&model, n)?;
    let u = vec![0.5; 6];
    let y: Vec<Option<f64>> = (0..30).map(|i| Some(1e-4 * i as f64)).collect();
    let rounds = 20;
    let mut failed = None;
    let round_s = median_seconds(rounds, || {
        for e in ests.iter_mut() {
            if let Err(err) = e.step(black_box(&u), black_box(&y)) {
                failed = Some(err);
            }
        }
    });
    if let Some(e) = failed {
        return Err(e.into());
    }
    println!(
        "{n} estimators at r = {r}: {:.0} steps/s on one core ({:.3} µs per step)",
        n as f64 / round_s,
        round_s / n as f64 * 1e6
    );
    Ok(())
}

/// `n` estimators sharing one prepared `model` (one copy of the matrices).
fn instances(model: &Model, n: usize) -> Result<Vec<Estimator>, crokf_runtime::RuntimeError> {
    let shared = std::sync::Arc::new(crokf_runtime::PreparedModel::new(model.clone())?);
    Ok((0..n)
        .map(|_| Estimator::from_prepared(std::sync::Arc::clone(&shared)))
        .collect())
}
