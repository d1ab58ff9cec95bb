//! Benchmark and test support (feature `synthetic`): synthetic models (random matrices of the
//! shapes a compiled model has, no physics), the median timer, and the deterministic generator
//! of test data. One source for `crokf-verify bench` and the runtime's `bench` example, so that
//! both time the same model the same way, and for the tests' and fuzzers' random numbers.

use crate as fmt;
use std::time::Instant;

/// Median wall time of `samples` runs of `f`, s.
pub fn median_seconds(samples: usize, mut f: impl FnMut()) -> f64 {
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

/// SplitMix64 (Steele, Lea & Flood 2014): a small deterministic generator for test data and
/// mutations. One copy for the runtime's test models and benchmarks, the fuzzers and the tests'
/// noise.
#[derive(Clone, Debug)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) (53 random bits).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [-1, 1).
    pub fn uniform(&mut self) -> f64 {
        self.unit() * 2.0 - 1.0
    }

    /// Standard normal (Box–Muller, cosine branch).
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.unit(), self.unit());
        (-2.0 * (1.0 - u1).ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// Uniform index below `n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// One element of a non-empty slice.
    pub fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }

    /// `n` numbers uniform in [-scale, scale).
    pub fn vec(&mut self, n: usize, scale: f64) -> Vec<f64> {
        (0..n).map(|_| scale * self.uniform()).collect()
    }

    /// A rows × cols matrix of numbers uniform in [-scale, scale).
    pub fn matrix(&mut self, rows: usize, cols: usize, scale: f64) -> fmt::Matrix {
        fmt::Matrix::from_fn(rows as u32, cols as u32, |_, _| scale * self.uniform())
    }
}

/// The three input channels of load group `load` named `name`: `name.x`, `name.y`, `name.z`
/// (world force components, N).
pub fn load_inputs(name: &str, load: u32) -> Vec<fmt::InputChannel> {
    (0..3u8)
        .map(|component| fmt::InputChannel {
            label: format!("{name}.{}", fmt::component_label(component)),
            kind: fmt::InputKind::Load { load, component },
        })
        .collect()
}

/// A gravity input channel (`gravity`: a scale of g = (0, 0, −9.81) m/s²).
pub fn gravity_input() -> fmt::InputChannel {
    fmt::InputChannel {
        label: "gravity".into(),
        kind: fmt::InputKind::Gravity {
            acceleration: [0.0, 0.0, -9.81],
        },
    }
}

/// A synthetic model with the runtime benchmark's shapes: r states, `inputs` input channels on
/// two load groups, `measured` measured components (sensors of 3), one node set of `nodes`.
pub fn benchmark_model(r: usize, inputs: usize, measured: usize, nodes: usize) -> fmt::Model {
    let mut rng = SplitMix64(0x9e37_79b9_7f4a_7c15);
    let mut transition = rng.matrix(r, r, 0.3 / (r as f64).sqrt());
    for i in 0..r {
        transition.data[i * r + i] += 0.6;
    }
    let loads = (inputs / 3).max(1);
    let sensors = measured.div_ceil(3);
    let measurements: Vec<fmt::MeasurementChannel> = (0..measured)
        .map(|i| fmt::MeasurementChannel {
            sensor: (i / 3) as u32,
            component: (i % 3) as u8,
        })
        .collect();
    fmt::Model {
        dt: 1e-3,
        theta: 1.4,
        state_dim: r as u32,
        transition,
        input: rng.matrix(r, inputs, 1.0),
        inputs: (0..inputs)
            .map(|j| fmt::InputChannel {
                label: format!("load{}.{}", j / 3, fmt::component_label((j % 3) as u8)),
                kind: fmt::InputKind::Load {
                    load: (j / 3) as u32,
                    component: (j % 3) as u8,
                },
            })
            .collect(),
        loads: (0..loads)
            .map(|g| fmt::LoadGroup {
                name: format!("load{g}"),
                rotation_rows: rng.matrix(3, r, 1e-2),
            })
            .collect(),
        sensors: (0..sensors)
            .map(|s| fmt::SensorInfo {
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
        measurements,
        kalman: fmt::KalmanGains {
            period: 1,
            phases: vec![fmt::KalmanPhase {
                measured: (0..measured as u32).collect(),
                gain: rng.matrix(r, measured, 1e-2),
                prior_covariance: fmt::Matrix::identity(r as u32),
                posterior_covariance: fmt::Matrix::identity(r as u32),
            }],
            process_noise: fmt::Matrix::identity(r as u32),
            measurement_variance: vec![1e-6; measured],
        },
        node_sets: vec![fmt::NodeSet {
            name: "display".into(),
            node_tags: (1..=nodes as u64).collect(),
            rest_positions: rng.matrix(nodes, 3, 1.0),
            triangles: Vec::new(),
            displacement_rows: rng.matrix(3 * nodes, r, 1e-2),
            rotation_rows: rng.matrix(3 * nodes, r, 1e-2),
        }],
        report: fmt::CompileReport::default(),
        inputs_digest: fmt::InputsDigest::default(),
        tier: None,
        contact: None,
    }
}
