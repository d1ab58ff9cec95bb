//! The formats tests' fixture model, shared by `tests/format.rs`, `tests/mutate.rs` and
//! `examples/mutate.rs`; its random entries from `crokf_formats::synthetic::SplitMix64`.

use crokf_formats::synthetic::SplitMix64;
use crokf_formats::*;
use std::collections::BTreeMap;

/// r = 4, loads: one group (3 channels) + gravity, 2 sensors (3 + 1 components, the second
/// every 2 steps → period 2), one displayed node set of 3 nodes.
pub fn small_model() -> Model {
    let mut g = SplitMix64(7);
    let r = 4usize;
    let sensors = vec![
        SensorInfo {
            name: "tip".into(),
            position: [1.0, 0.0, 0.5],
            displacement_rows: g.matrix(3, r, 1.0),
            rotation_rows: g.matrix(3, r, 1.0),
            components: vec![0, 1, 2],
            every: 1,
        },
        SensorInfo {
            name: "mid".into(),
            position: [0.5, 0.0, 0.5],
            displacement_rows: g.matrix(3, r, 1.0),
            rotation_rows: g.matrix(3, r, 1.0),
            components: vec![2],
            every: 2,
        },
    ];
    let measurements = vec![
        MeasurementChannel {
            sensor: 0,
            component: 0,
        },
        MeasurementChannel {
            sensor: 0,
            component: 1,
        },
        MeasurementChannel {
            sensor: 0,
            component: 2,
        },
        MeasurementChannel {
            sensor: 1,
            component: 2,
        },
    ];
    let phase = |measured: Vec<u32>, g: &mut SplitMix64| KalmanPhase {
        gain: g.matrix(r, measured.len(), 1.0),
        measured,
        prior_covariance: Matrix::identity(r as u32),
        posterior_covariance: Matrix::identity(r as u32),
    };
    let phases = vec![
        phase(vec![0, 1, 2, 3], &mut g),
        phase(vec![0, 1, 2], &mut g),
    ];
    let mut transition = g.matrix(r, r, 1.0);
    transition.data[2 * 4 + 1] = 12345.678; // a marker the corruption test looks for
    Model {
        dt: 1e-3,
        theta: 1.4,
        state_dim: r as u32,
        transition,
        input: g.matrix(r, 4, 1.0),
        inputs: [
            crokf_formats::synthetic::load_inputs("push", 0),
            vec![crokf_formats::synthetic::gravity_input()],
        ]
        .concat(),
        loads: vec![LoadGroup {
            name: "push".into(),
            rotation_rows: g.matrix(3, r, 1.0),
        }],
        sensors,
        measurements,
        kalman: KalmanGains {
            period: 2,
            phases,
            process_noise: Matrix::identity(r as u32),
            measurement_variance: vec![1e-6, 1e-6, 1e-6, 4e-6],
        },
        node_sets: vec![NodeSet {
            name: "surface".into(),
            node_tags: vec![10, 11, 12],
            rest_positions: g.matrix(3, 3, 1.0),
            triangles: vec![[0, 1, 2]],
            displacement_rows: g.matrix(9, r, 1.0),
            rotation_rows: g.matrix(9, r, 1.0),
        }],
        report: CompileReport {
            hankel_singular_values: vec![3.0, 2.0, 1.0, 0.5, 0.1],
            error_bound: 0.2,
            order: r as u32,
            modes: 6,
            highest_kept_frequency_hz: 120.0,
            nyquist_hz: 500.0,
            spectral_radius: 0.99,
            riccati_residual: 1e-14,
            closed_loop_spectral_radius: 0.9,
            measured_errors: BTreeMap::from([("tip".to_string(), 0.01)]),
            timings_s: BTreeMap::from([("total".to_string(), 1.5), ("dare".to_string(), 0.1)]),
            notes: vec!["synthetic".into()],
        },
        inputs_digest: InputsDigest {
            mesh_sha256: sha256_hex(b"mesh"),
            scene_sha256: sha256_hex(b"scene"),
            compiler_version: "test".into(),
        },
        tier: None,
        contact: None,
    }
}
