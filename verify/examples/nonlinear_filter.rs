//! Open-loop and filtered error of compiled models against the full-order co-rotational FEM on
//! a scenario (docs/design.md §10 item 5, docs/corotational-tier.md): the runtime's
//! `Estimator` on each MODEL file, given the scenario's loads as inputs and, for the filtered
//! run, the reference's sensor displacements plus Gaussian noise of the scene's σ (seed 7).
//! Errors are relative L2 over the displayed nodes and the whole trajectory, world frame.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example nonlinear_filter -- SCENE SCENARIO MODEL...
//! ```
//! SCENE is the scene of the reference (either tier's scene: same mesh and material).

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use crokf_compile::FullOrder;
use crokf_runtime::{load_model, Estimator};
use crokf_verify::comparison::Gaussian;
use crokf_verify::scenario::{Horizon, Scenario};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: nonlinear_filter SCENE SCENARIO MODEL...".into());
    }
    let full = FullOrder::build(&PathBuf::from(&args[0]), &mut StageTimer::default())?;
    let scenario = Scenario::read(&PathBuf::from(&args[1]))?;
    let fem = &full.fem;
    let ops = &full.operators;
    let dt = full.wilson.dt;
    let steps = match scenario.horizon(dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let n = fem.dof_count();
    // Reference: displayed nodes (node sets in order, world displacement) and sensors.
    let mut reference = CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default())?;
    let mut shown_ref: Vec<Vec<f64>> = Vec::with_capacity(steps);
    let mut sensors_ref: Vec<Vec<f64>> = Vec::with_capacity(steps);
    let mut inputs = Vec::with_capacity(steps);
    let nodal = |u: &[f64], node: usize, c: usize| fem.dofs.index[node][c].map_or(0.0, |d| u[d]);
    for k in 0..steps {
        let t = k as f64 * dt;
        let f = scenario.load_vector(ops, n, t);
        inputs.push(scenario.inputs_at(ops, t));
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
        shown_ref.push(shown);
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
        sensors_ref.push(s);
    }
    println!(
        "| model | tier | open loop | filtered | sensors, filtered | median step (µs) |\n|---|---|---:|---:|---:|---:|"
    );
    for path in &args[2..] {
        let model = load_model(path)?;
        let tier = if model.tier.is_some() {
            "co-rotational"
        } else {
            "warped"
        };
        let mut row = Vec::new();
        let mut sensor_err = f64::NAN;
        let mut median_step = f64::NAN;
        for filtered in [false, true] {
            let mut est = Estimator::new(&model)?;
            est.set_innovation_gate(None);
            let mut rng = Gaussian::new(7);
            let (mut e2, mut r2, mut se2, mut sr2) = (0.0, 0.0, 0.0, 0.0);
            let mut shown = vec![0.0; shown_ref[0].len()];
            let mut sens = vec![0.0; 3 * model.sensors.len()];
            let mut times = Vec::with_capacity(steps);
            for k in 0..steps {
                let y: Vec<Option<f64>> = model
                    .measurements
                    .iter()
                    .enumerate()
                    .map(|(j, m)| {
                        let sigma = model.kalman.measurement_variance[j].sqrt();
                        Some(
                            sensors_ref[k][3 * m.sensor as usize + m.component as usize]
                                + sigma * rng.normal(),
                        )
                    })
                    .collect();
                let clock = std::time::Instant::now();
                if filtered {
                    est.step(&inputs[k], &y)?;
                } else {
                    est.predict(&inputs[k])?;
                }
                times.push(clock.elapsed().as_secs_f64());
                let mut at = 0;
                for set in 0..model.node_sets.len() {
                    let len = 3 * model.node_sets[set].node_tags.len();
                    est.node_displacements_exact(set, &mut shown[at..at + len])?;
                    at += len;
                }
                for (a, b) in shown.iter().zip(&shown_ref[k]) {
                    e2 += (a - b) * (a - b);
                    r2 += b * b;
                }
                est.sensor_displacements(&mut sens)?;
                for (a, b) in sens.iter().zip(&sensors_ref[k]) {
                    se2 += (a - b) * (a - b);
                    sr2 += b * b;
                }
            }
            row.push((e2 / r2).sqrt());
            if filtered {
                sensor_err = (se2 / sr2).sqrt();
                times.sort_by(f64::total_cmp);
                median_step = times[times.len() / 2];
            }
        }
        println!(
            "| {path} | {tier} | {:.2} % | {:.2} % | {:.2} % | {:.1} |",
            100.0 * row[0],
            100.0 * row[1],
            100.0 * sensor_err,
            median_step * 1e6
        );
    }
    Ok(())
}
