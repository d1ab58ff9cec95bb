//! Measures the estimator's cost per step on random models (not a test; numbers for the
//! report): `cargo run --release -p crokf-runtime --example step_time`.

use crokf_formats::*;
use crokf_runtime::Estimator;
use std::time::Instant;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
    fn matrix(&mut self, rows: usize, cols: usize, scale: f64) -> Matrix {
        Matrix::from_fn(rows as u32, cols as u32, |_, _| scale * self.next())
    }
}

/// r states, 2 load groups (6 inputs), 3 sensors (9 channels), one node set of n nodes.
fn model(r: usize, n: usize) -> Model {
    let mut g = Rng(0x2545_F491_4F6C_DD1D);
    let mut f = g.matrix(r, r, 1.0);
    let norm = f.data.iter().map(|v| v * v).sum::<f64>().sqrt();
    f.data.iter_mut().for_each(|v| *v *= 0.9 / norm);
    let sensors: Vec<SensorInfo> = (0..3)
        .map(|s| SensorInfo {
            name: format!("s{s}"),
            position: [0.0; 3],
            displacement_rows: g.matrix(3, r, 1.0),
            rotation_rows: g.matrix(3, r, 0.01),
            components: vec![0, 1, 2],
            every: 1,
        })
        .collect();
    let measurements: Vec<MeasurementChannel> = (0..9)
        .map(|i| MeasurementChannel {
            sensor: i / 3,
            component: (i % 3) as u8,
        })
        .collect();
    Model {
        dt: 1e-3,
        theta: 1.4,
        state_dim: r as u32,
        transition: f,
        input: g.matrix(r, 6, 1.0),
        inputs: (0..6)
            .map(|j| InputChannel {
                label: format!("l{}.{}", j / 3, component_label((j % 3) as u8)),
                kind: InputKind::Load {
                    load: (j / 3) as u32,
                    component: (j % 3) as u8,
                },
            })
            .collect(),
        loads: (0..2)
            .map(|i| LoadGroup {
                name: format!("l{i}"),
                rotation_rows: g.matrix(3, r, 0.01),
            })
            .collect(),
        sensors,
        measurements,
        kalman: KalmanGains {
            period: 1,
            phases: vec![KalmanPhase {
                measured: (0..9).collect(),
                gain: g.matrix(r, 9, 0.01),
                prior_covariance: Matrix::identity(r as u32),
                posterior_covariance: Matrix::identity(r as u32),
            }],
            process_noise: Matrix::identity(r as u32),
            measurement_variance: vec![1e-6; 9],
        },
        node_sets: vec![NodeSet {
            name: "surface".into(),
            node_tags: (0..n as u64).collect(),
            rest_positions: g.matrix(n, 3, 1.0),
            triangles: vec![],
            displacement_rows: g.matrix(3 * n, r, 1.0),
            rotation_rows: g.matrix(3 * n, r, 0.01),
        }],
        report: CompileReport::default(),
        inputs_digest: InputsDigest::default(),
        tier: None,
        contact: None,
    }
}

fn main() {
    println!(
        "{:>5} {:>6} {:>14} {:>20} {:>14}",
        "r", "nodes", "step+sensors µs", "node positions µs", "per node ns"
    );
    for &(r, n) in &[(10, 100), (20, 1000), (50, 1000), (100, 1000), (50, 10000)] {
        let m = model(r, n);
        let mut est = Estimator::new(&m).unwrap();
        let u = [0.1; 6];
        let y = [Some(0.0); 9];
        let mut s = vec![0.0; 9];
        let mut p = vec![0.0; 3 * n];
        let steps = 20_000;
        let t = Instant::now();
        for _ in 0..steps {
            est.step(&u, &y).unwrap();
            est.sensor_displacements(&mut s).unwrap();
        }
        let step_us = t.elapsed().as_secs_f64() / steps as f64 * 1e6;
        let reps = (2_000_000 / (n * r)).max(10);
        let t = Instant::now();
        for _ in 0..reps {
            est.node_positions(0, &mut p).unwrap();
        }
        let node_us = t.elapsed().as_secs_f64() / reps as f64 * 1e6;
        std::hint::black_box((&s, &p));
        println!(
            "{r:>5} {n:>6} {step_us:>14.2} {node_us:>20.1} {:>14.1}",
            node_us * 1e3 / n as f64
        );
    }
}
