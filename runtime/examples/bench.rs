//! Runtime benchmark (a command, not a test; medians on one core, issue 14 item 6):
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
use std::time::Instant;

/// Median wall time of `samples` runs of `f`, s.
fn median_seconds(samples: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..samples.max(1))
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Deterministic numbers in [-1, 1) (xorshift64*).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (v >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
    fn matrix(&mut self, rows: usize, cols: usize, scale: f64) -> Matrix {
        Matrix::from_fn(rows as u32, cols as u32, |_, _| scale * self.next())
    }
}

/// r states, `inputs` load channels (groups of 3), `measured` components (sensors of 3), one
/// node set of `nodes` nodes; F = 0.6 I + noise, P = I.
fn synthetic_model(r: usize, inputs: usize, measured: usize, nodes: usize) -> Model {
    let mut rng = Noise(0x9e37_79b9_7f4a_7c15);
    let mut transition = rng.matrix(r, r, 0.3 / (r as f64).sqrt());
    for i in 0..r {
        transition.data[i * r + i] += 0.6;
    }
    let loads = (inputs / 3).max(1);
    let sensors = measured.div_ceil(3);
    Model {
        dt: 1e-3,
        theta: 1.4,
        state_dim: r as u32,
        transition,
        input: rng.matrix(r, inputs, 1.0),
        inputs: (0..inputs)
            .map(|j| InputChannel {
                label: format!("load{}.{}", j / 3, component_label((j % 3) as u8)),
                kind: InputKind::Load {
                    load: (j / 3) as u32,
                    component: (j % 3) as u8,
                },
            })
            .collect(),
        loads: (0..loads)
            .map(|g| LoadGroup {
                name: format!("load{g}"),
                rotation_rows: rng.matrix(3, r, 1e-2),
            })
            .collect(),
        sensors: (0..sensors)
            .map(|s| SensorInfo {
                name: format!("s{s}"),
                position: [s as f64, 0.0, 0.0],
                displacement_rows: rng.matrix(3, r, 1e-2),
                rotation_rows: rng.matrix(3, r, 1e-2),
                components: (0..3u8)
                    .filter(|c| 3 * s + (*c as usize) < measured)
                    .collect(),
                every: 1,
            })
            .collect(),
        measurements: (0..measured)
            .map(|i| MeasurementChannel {
                sensor: (i / 3) as u32,
                component: (i % 3) as u8,
            })
            .collect(),
        kalman: KalmanGains {
            period: 1,
            phases: vec![KalmanPhase {
                measured: (0..measured as u32).collect(),
                gain: rng.matrix(r, measured, 1e-2),
                prior_covariance: Matrix::identity(r as u32),
                posterior_covariance: Matrix::identity(r as u32),
            }],
            process_noise: Matrix::identity(r as u32),
            measurement_variance: vec![1e-6; measured],
        },
        node_sets: vec![NodeSet {
            name: "display".into(),
            node_tags: (1..=nodes as u64).collect(),
            rest_positions: rng.matrix(nodes, 3, 1.0),
            triangles: Vec::new(),
            displacement_rows: rng.matrix(3 * nodes, r, 1e-2),
            rotation_rows: rng.matrix(3 * nodes, r, 1e-2),
        }],
        report: CompileReport::default(),
        inputs_digest: InputsDigest::default(),
        tier: None,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (inputs, measured, nodes) = (6, 30, 5000);
    // `bench steps R N`: only N steps at order R (for `perf stat` cycle and instruction counts).
    let args: Vec<String> = std::env::args().collect();
    if args.len() == 4 && args[1] == "steps" {
        let (r, n): (usize, usize) = (args[2].parse()?, args[3].parse()?);
        let model = synthetic_model(r, inputs, measured, 8);
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
        let model = synthetic_model(r, inputs, measured, nodes);
        let mut est = Estimator::new(&model)?;
        let u = vec![0.5; inputs];
        let mut rng = Noise(7);
        let y: Vec<Option<f64>> = (0..measured).map(|_| Some(1e-3 * rng.next())).collect();
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
    let model = synthetic_model(r, 6, 30, 5000);
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
