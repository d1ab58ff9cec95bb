//! Model file encoding: round trip, determinism, and corruption of every kind → typed error.

use crokf_formats::synthetic::SplitMix64;
use crokf_formats::*;

#[path = "support/model.rs"]
mod model;
use model::small_model;

#[test]
fn round_trip_and_determinism() {
    let model = small_model();
    model.validate().unwrap();
    let bytes = encode(&model);
    assert_eq!(bytes, encode(&model), "encoding must be deterministic");
    assert_eq!(&bytes[..8], b"CROKF\0\r\n");
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 7);
    let len = u64::from_le_bytes(bytes[12..20].try_into().unwrap());
    assert_eq!(len as usize, bytes.len() - HEADER_LEN);
    assert_eq!(hex(&bytes[20..52]), sha256_hex(&bytes[HEADER_LEN..]));
    let back = decode(&bytes).unwrap();
    assert_eq!(back, model);
    assert_eq!(encode(&back), bytes);
}

#[test]
fn sha256_known_answer() {
    // FIPS 180-2 test vector.
    assert_eq!(
        sha256_hex(b"abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
}

#[test]
fn measurement_matrix_stacks_sensor_rows() {
    let model = small_model();
    let h = model.measurement_matrix();
    assert_eq!((h.rows, h.cols), (4, 4));
    assert_eq!(h.row(1), model.sensors[0].displacement_rows.row(1));
    assert_eq!(h.row(3), model.sensors[1].displacement_rows.row(2));
    assert_eq!(
        model.measurement_labels(),
        ["tip.x", "tip.y", "tip.z", "mid.z"]
    );
}

#[test]
fn every_bit_flip_is_an_error() {
    let bytes = encode(&small_model());
    let mut buf = bytes.clone();
    for i in 0..bytes.len() {
        for bit in 0..8 {
            buf[i] ^= 1 << bit;
            assert!(decode(&buf).is_err(), "flip of byte {i} bit {bit} accepted");
            buf[i] ^= 1 << bit;
        }
    }
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = encode(&small_model());
    for n in 0..bytes.len() {
        let err = decode(&bytes[..n]).unwrap_err();
        if n >= HEADER_LEN {
            assert!(
                matches!(err, FormatError::Truncated { found, .. } if found == (n - HEADER_LEN) as u64),
                "{n}: {err}"
            );
        }
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert_eq!(
        decode(&longer),
        Err(FormatError::TrailingBytes {
            expected: (bytes.len() - HEADER_LEN) as u64,
            extra: 1
        })
    );
}

#[test]
fn other_versions_and_wrong_magic() {
    assert_eq!(FORMAT_VERSION, 7);
    // Version-1 to version-6 files (before the tier's force-σ levels) are refused before
    // their payload is read, with both versions and the remedy in the message.
    // Version 8 (contact before its θ-point rows) likewise.
    for old in [1u32, 2, 3, 4, 5, 6, 8] {
        let mut bytes = encode(&small_model());
        bytes[8..12].copy_from_slice(&old.to_le_bytes());
        let err = decode(&bytes).unwrap_err();
        assert_eq!(
            err,
            FormatError::UnsupportedVersion {
                found: old,
                supported: 10
            }
        );
        assert_eq!(
            err.to_string(),
            format!("model format v{old}, this runtime reads v7, v9, v10: recompile the model with crokf-compile")
        );
    }
    // A model without a contact region is a version 7 file; version 9 must carry one.
    assert_eq!(encode(&small_model())[8..12], 7u32.to_le_bytes());
    let mut bytes = encode(&small_model());
    bytes[8..12].copy_from_slice(&9u32.to_le_bytes());
    let err = decode(&bytes).unwrap_err();
    assert!(
        err.to_string().contains("must carry a contact region"),
        "{err}"
    );
    let mut bytes = encode(&small_model());
    bytes[8..12].copy_from_slice(&11u32.to_le_bytes());
    let err = decode(&bytes).unwrap_err();
    assert!(
        err.to_string()
            .starts_with("model format v11, this runtime reads v7, v9, v10: use a runtime"),
        "{err}"
    );
    // Version 10 must carry a tier that failed its check.
    let mut bytes = encode(&small_model());
    bytes[8..12].copy_from_slice(&10u32.to_le_bytes());
    let err = decode(&bytes).unwrap_err();
    assert!(
        err.to_string()
            .contains("must carry a tier that failed its check"),
        "{err}"
    );
    let mut bytes = encode(&small_model());
    bytes[0] = b'X';
    assert!(matches!(decode(&bytes), Err(FormatError::BadMagic { found }) if found[0] == b'X'));
    assert!(matches!(
        decode(b"PK\x03\x04 not a model"),
        Err(FormatError::BadMagic { .. })
    ));
    assert_eq!(decode(b"CROKF"), Err(FormatError::TooShort { len: 5 }));
}

/// Encodes without validation (as a buggy producer would) and decodes.
fn decode_modified(f: impl FnOnce(&mut Model)) -> FormatError {
    let mut m = small_model();
    f(&mut m);
    decode(&encode(&m)).expect_err("inconsistent model accepted")
}

#[test]
fn inconsistent_shapes_are_named() {
    let e = decode_modified(|m| m.transition = Matrix::zeros(4, 3));
    assert_eq!(
        e,
        FormatError::Shape {
            matrix: "transition".into(),
            expected_rows: 4,
            expected_cols: 4,
            rows: 4,
            cols: 3
        }
    );
    let e = decode_modified(|m| {
        m.transition.data.pop();
    });
    assert!(
        matches!(e, FormatError::DataLength { ref matrix, len: 15, .. } if matrix == "transition"),
        "{e}"
    );
    let e = decode_modified(|m| m.sensors[1].rotation_rows = Matrix::zeros(3, 5));
    assert!(
        e.to_string().contains("sensors[1] 'mid'.rotation_rows"),
        "{e}"
    );
    let e = decode_modified(|m| m.kalman.phases[1].gain = Matrix::zeros(4, 4));
    assert!(e.to_string().contains("kalman.phases[1].gain"), "{e}");
    let e = decode_modified(|m| m.input = Matrix::zeros(4, 3));
    assert!(e.to_string().contains("input:"), "{e}");
    let e = decode_modified(|m| m.node_sets[0].displacement_rows = Matrix::zeros(6, 4));
    assert!(
        e.to_string()
            .contains("node_sets[0] 'surface'.displacement_rows"),
        "{e}"
    );
    let e = decode_modified(|m| m.node_sets[0].triangles.push([0, 1, 3]));
    assert!(e.to_string().contains("triangles[1]"), "{e}");
    let e = decode_modified(|m| m.measurements[3].component = 0);
    assert!(
        e.to_string().contains("does not measure component 0"),
        "{e}"
    );
    let e = decode_modified(|m| m.kalman.phases[0].measured = vec![0, 2, 1, 3]);
    assert!(e.to_string().contains("strictly increasing"), "{e}");
    let e = decode_modified(|m| m.kalman.phases.pop().map(|_| ()).unwrap_or(()));
    assert!(e.to_string().contains("1 phases for period 2"), "{e}");
    let e = decode_modified(|m| {
        m.inputs[1].kind = InputKind::Load {
            load: 0,
            component: 0,
        }
    });
    assert!(e.to_string().contains("two input channels"), "{e}");
    let e = decode_modified(|m| {
        m.inputs[0].kind = InputKind::Load {
            load: 1,
            component: 0,
        }
    });
    assert!(e.to_string().contains("inputs[0] 'push.x'"), "{e}");
    let e = decode_modified(|m| m.kalman.measurement_variance[2] = 0.0);
    assert!(e.to_string().contains("measurement_variance[2]"), "{e}");
    let e = decode_modified(|m| m.sensors[0].components = vec![2, 0, 2]);
    assert!(e.to_string().contains("sensors[0] 'tip'.components"), "{e}");
    let mut m = small_model();
    m.sensors[0].components = vec![2, 0, 1]; // any order is fine
    assert_eq!(decode(&encode(&m)).unwrap(), m);
    let e = decode_modified(|m| m.sensors[0].every = 0);
    assert!(e.to_string().contains("sensors[0] 'tip'.every"), "{e}");
}

#[test]
fn nan_in_a_matrix_is_named_even_with_a_valid_hash() {
    let e = decode_modified(|m| m.sensors[1].rotation_rows.data[5] = f64::NAN);
    assert!(
        matches!(e, FormatError::NonFinite { ref matrix, row: 1, col: 1, .. } if matrix == "sensors[1] 'mid'.rotation_rows"),
        "{e}"
    );
    // Byte-level: overwrite the marker value inside the payload, then re-hash.
    let bytes = encode(&small_model());
    let mut payload = bytes[HEADER_LEN..].to_vec();
    let marker = 12345.678f64.to_le_bytes();
    let at = payload
        .windows(8)
        .position(|w| w == marker)
        .expect("marker present");
    payload[at..at + 8].copy_from_slice(&f64::INFINITY.to_le_bytes());
    let e = decode(&wrap_payload(&payload)).unwrap_err();
    assert!(
        matches!(e, FormatError::NonFinite { ref matrix, row: 2, col: 1, .. } if matrix == "transition"),
        "{e}"
    );
}

#[test]
fn rehashed_garbage_never_panics() {
    let bytes = encode(&small_model());
    let payload = bytes[HEADER_LEN..].to_vec();
    let mut rng = SplitMix64(99);
    let mut accepted = 0;
    for i in 0..payload.len() {
        for v in [0x00u8, 0xff, 0xc1, 0xdb, (rng.next_u64() & 0xff) as u8] {
            let mut p = payload.clone();
            p[i] = v;
            if decode(&wrap_payload(&p)).is_ok() {
                accepted += 1;
            }
        }
    }
    // Some mutations are legitimately valid (a changed matrix entry); most are not.
    assert!(accepted < payload.len() * 5);
    // Extra data after the model inside a correctly hashed payload.
    let mut p = payload.clone();
    p.push(0xc0);
    assert!(matches!(
        decode(&wrap_payload(&p)),
        Err(FormatError::MessagePack(_))
    ));
    // Wrong payload entirely.
    assert!(matches!(
        decode(&wrap_payload(&[0x93, 1, 2, 3])),
        Err(FormatError::MessagePack(_))
    ));
}

#[test]
fn matrix_bytes_not_multiple_of_eight() {
    // {"rows":1,"cols":1,"data":bin(7 bytes)} by hand.
    let mut b = vec![0x83, 0xa4];
    b.extend_from_slice(b"rows");
    b.push(0x01);
    b.push(0xa4);
    b.extend_from_slice(b"cols");
    b.push(0x01);
    b.push(0xa4);
    b.extend_from_slice(b"data");
    b.extend_from_slice(&[0xc4, 7, 0, 0, 0, 0, 0, 0, 0]);
    let r: Result<Matrix, _> = rmp_serde::from_slice(&b);
    assert!(r
        .unwrap_err()
        .to_string()
        .contains("not a whole number of f64"));
    let at = b.len() - 8;
    b[at] = 8;
    b.push(0);
    let m: Matrix = rmp_serde::from_slice(&b).unwrap();
    assert_eq!(
        m,
        Matrix {
            rows: 1,
            cols: 1,
            data: vec![0.0]
        }
    );
}

/// A small synthetic co-rotational tier (r = 2, force states on load group 0: state 3r + 3)
/// for `small_model()`.
fn small_tier(model: &Model) -> CorotationalTier {
    let r = 2usize;
    let n = 3 * r + 3;
    let q = model.measurements.len() as u32;
    let mut g = SplitMix64(7);
    let phase = |measured: Vec<u32>, g: &mut SplitMix64| KalmanPhase {
        gain: g.matrix(n, measured.len(), 1.0),
        measured,
        prior_covariance: Matrix::identity(n as u32),
        posterior_covariance: Matrix::identity(n as u32),
    };
    let phases = vec![
        phase((0..q).collect(), &mut g),
        phase(vec![0, 1, 2], &mut g),
    ];
    CorotationalTier {
        order: r as u32,
        mass: Matrix::identity(r as u32),
        alpha: 0.5,
        beta: 1e-3,
        newton_tolerance: 1e-6,
        newton_iterations: 20,
        input: g.matrix(r, model.inputs.len(), 1.0),
        sensor_rows: model.sensors.iter().map(|_| g.matrix(3, r, 1.0)).collect(),
        node_set_rows: model
            .node_sets
            .iter()
            .map(|s| g.matrix(3 * s.node_tags.len(), r, 1.0))
            .collect(),
        elements: vec![TierElement {
            element: 3,
            weight: 2.5,
            rest: [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            gradients: [[-1.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            stiffness: Matrix::identity(12),
            rows: g.matrix(12, r, 1.0),
        }],
        envelope: TrainingEnvelope {
            loads: vec![EnvelopeLoad {
                name: "push".into(),
                range: 20.0,
                max_force: 25.0,
            }],
            directions: vec![[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]],
            histories: vec![TrainingHistory {
                kind: "ramp".into(),
                multiple: 1.25,
                time: 0.3,
            }],
            duration: 1.0,
            every: 5,
            runs_completed: 2,
            runs_attempted: 2,
            snapshots: 80,
            max_displacement: 0.6,
            max_coordinate_norm: 3.0,
            state_margin: 1.5,
        },
        force_loads: vec![0],
        force_rates: false,
        kalman: KalmanGains {
            period: 2,
            phases: phases.clone(),
            process_noise: Matrix::identity(n as u32),
            measurement_variance: model.kalman.measurement_variance.clone(),
        },
        scheduled: vec![ScheduledFilter {
            point: vec![0.5; r],
            kalman: KalmanGains {
                period: 2,
                phases: phases.clone(),
                process_noise: Matrix::identity(n as u32),
                measurement_variance: model.kalman.measurement_variance.clone(),
            },
        }],
        model_error: Matrix::from_fn(r as u32, r as u32, |i, j| if i == j { 1e-8 } else { 0.0 }),
        force_levels: [4.0, 0.25]
            .into_iter()
            .map(|factor| ForceLevel {
                factor,
                kalman: KalmanGains {
                    period: 2,
                    phases: phases.clone(),
                    process_noise: Matrix::identity(n as u32),
                    measurement_variance: model.kalman.measurement_variance.clone(),
                },
                scheduled: vec![KalmanGains {
                    period: 2,
                    phases: phases.clone(),
                    process_noise: Matrix::identity(n as u32),
                    measurement_variance: model.kalman.measurement_variance.clone(),
                }],
            })
            .collect(),
        adaptation: Some(ForceAdaptation {
            smoothing: vec![0.1; q as usize],
            raise_above: 3.0,
            lower_below: 0.9,
            hold: 50,
        }),
        failed_check: None,
    }
}

#[test]
fn a_tier_that_failed_its_check_is_a_version_10_file_that_says_why() {
    let mut model = small_model();
    model.tier = Some(small_tier(&model));
    let passed = encode(&model);
    assert_eq!(passed[8..12], 7u32.to_le_bytes());
    assert_eq!(model.tier_failed_check(), None);
    assert_eq!(model.tier_failed_check_warning(), None);
    let why = "the co-rotational tier fails its check: 80 of 80 of its own training runs are \
               above 5 % off";
    model.tier.as_mut().unwrap().failed_check = Some(why.into());
    let bytes = encode(&model);
    assert_eq!(bytes[8..12], FAILED_CHECK_FORMAT_VERSION.to_le_bytes());
    assert_eq!(FAILED_CHECK_FORMAT_VERSION, 10);
    let back = decode(&bytes).unwrap();
    assert_eq!(back.tier_failed_check(), Some(why));
    let warning = back.tier_failed_check_warning().unwrap();
    assert!(
        warning.contains("accept_failed_check") && warning.ends_with(why),
        "{warning}"
    );
    // The field changes nothing else in the payload: without it, the passing tier's bytes.
    let mut cleared = back.clone();
    cleared.tier.as_mut().unwrap().failed_check = None;
    assert_eq!(encode(&cleared), passed);
    // The version and the field go together, both ways.
    let mut relabelled = bytes.clone();
    relabelled[8..12].copy_from_slice(&7u32.to_le_bytes());
    let e = decode(&relabelled).unwrap_err().to_string();
    assert!(
        e.contains("tier.failed_check") && e.contains("must not carry a tier that failed"),
        "{e}"
    );
    // An empty reason is refused.
    model.tier.as_mut().unwrap().failed_check = Some("  ".into());
    let e = model.validate().unwrap_err().to_string();
    assert!(
        e.contains("tier.failed_check") && e.contains("empty"),
        "{e}"
    );
}

#[test]
fn tier_section_round_trip_and_validation() {
    let mut model = small_model();
    model.tier = Some(small_tier(&model));
    model.validate().unwrap();
    let bytes = encode(&model);
    assert_eq!(bytes, encode(&model));
    let back = decode(&bytes).unwrap();
    assert_eq!(back, model);
    // Shapes, finiteness and weights of the section are checked, naming the field.
    let bad = |edit: &dyn Fn(&mut CorotationalTier)| {
        let mut m = model.clone();
        edit(m.tier.as_mut().unwrap());
        m.validate().unwrap_err().to_string()
    };
    let e = bad(&|t| t.elements[0].rows = Matrix::zeros(12, 3));
    assert!(
        e.contains("tier.elements[0].rows") && e.contains("12×2"),
        "{e}"
    );
    let e = bad(&|t| t.elements[0].weight = -1.0);
    assert!(e.contains("tier.elements[0].weight"), "{e}");
    let e = bad(&|t| t.elements[0].stiffness.data[1] = 0.5);
    assert!(
        e.contains("tier.elements[0].stiffness") && e.contains("symmetric"),
        "{e}"
    );
    let e = bad(&|t| t.elements[0].rest[2][1] = f64::NAN);
    assert!(
        e.contains("tier.elements[0].rest") && e.contains("(2, 1)"),
        "{e}"
    );
    let e = bad(&|t| t.sensor_rows.truncate(1));
    assert!(e.contains("tier.sensor_rows"), "{e}");
    let e = bad(&|t| t.kalman.phases[0].gain = Matrix::zeros(2, 4));
    assert!(
        e.contains("tier.kalman.phases[0].gain") && e.contains("9×4"),
        "{e}"
    );
    // Force states: the filter's state is 3r + 3 per group; a group must exist and have
    // three load channels.
    let e = bad(&|t| t.force_loads.clear());
    assert!(
        e.contains("tier.kalman.phases[0].gain") && e.contains("6×4"),
        "{e}"
    );
    let e = bad(&|t| t.force_loads = vec![1]);
    assert!(
        e.contains("tier.force_loads") && e.contains("load group 1"),
        "{e}"
    );
    let e = bad(&|t| t.envelope.loads[0].name = "nowhere".into());
    assert!(e.contains("tier.envelope.loads[0] 'nowhere'"), "{e}");
    let e = bad(&|t| t.newton_iterations = 0);
    assert!(e.contains("tier.newton_iterations"), "{e}");
    // The gain schedule (v5): a point of r values, the same phases as `kalman`.
    let e = bad(&|t| t.scheduled[0].point.pop().map_or((), |_| ()));
    assert!(
        e.contains("tier.scheduled[0].point") && e.contains("for r = 2"),
        "{e}"
    );
    let e = bad(&|t| t.scheduled[0].point[1] = f64::INFINITY);
    assert!(e.contains("tier.scheduled[0].point"), "{e}");
    let e = bad(&|t| t.scheduled[0].kalman.phases[1].measured = vec![0, 1]);
    assert!(e.contains("tier.scheduled[0].kalman"), "{e}");
    let e = bad(&|t| t.scheduled[0].kalman.phases[0].gain = Matrix::zeros(2, 4));
    assert!(e.contains("tier.scheduled[0].kalman.phases[0].gain"), "{e}");
    // The model error (v6): r × r or absent, finite, a diagonal ≥ 0.
    let e = bad(&|t| t.model_error = Matrix::zeros(3, 2));
    assert!(e.contains("tier.model_error"), "{e}");
    let e = bad(&|t| t.model_error.data[1] = f64::NAN);
    assert!(e.contains("tier.model_error"), "{e}");
    let e = bad(&|t| t.model_error.data[0] = -1.0);
    assert!(e.contains("tier.model_error") && e.contains("≥ 0"), "{e}");
    // Force-σ levels (v7): distinct factors ≠ 1, one filter per scheduled point shaped as
    // `kalman`, force states, and the statistic present exactly with levels.
    let e = bad(&|t| t.force_levels[1].factor = 4.0);
    assert!(
        e.contains("tier.force_levels[1].factor") && e.contains("repeats"),
        "{e}"
    );
    let e = bad(&|t| t.force_levels[0].factor = 1.0);
    assert!(e.contains("tier.force_levels[0].factor"), "{e}");
    let e = bad(&|t| t.force_levels[0].factor = -2.0);
    assert!(
        e.contains("tier.force_levels[0].factor") && e.contains("> 0"),
        "{e}"
    );
    let e = bad(&|t| t.force_levels[1].scheduled.clear());
    assert!(
        e.contains("tier.force_levels[1].scheduled") && e.contains("0 filters for 1"),
        "{e}"
    );
    let e = bad(&|t| t.force_levels[0].scheduled[0].phases[0].gain = Matrix::zeros(9, 1));
    assert!(
        e.contains("tier.force_levels[0].scheduled[0].phases[0].gain"),
        "{e}"
    );
    let e = bad(&|t| t.force_levels[1].kalman.phases[1].measured = vec![0, 1, 3]);
    assert!(
        e.contains("tier.force_levels[1].kalman") && e.contains("differ"),
        "{e}"
    );
    let e = bad(&|t| t.adaptation = None);
    assert!(
        e.contains("tier.adaptation") && e.contains("missing"),
        "{e}"
    );
    let e = bad(&|t| t.force_levels.clear());
    assert!(
        e.contains("tier.adaptation") && e.contains("without"),
        "{e}"
    );
    let e = bad(&|t| t.adaptation.as_mut().unwrap().smoothing[2] = 0.0);
    assert!(e.contains("tier.adaptation.smoothing[2]"), "{e}");
    let e = bad(&|t| {
        t.adaptation
            .as_mut()
            .unwrap()
            .smoothing
            .pop()
            .map_or((), |_| ())
    });
    assert!(e.contains("tier.adaptation.smoothing"), "{e}");
    let e = bad(&|t| t.adaptation.as_mut().unwrap().raise_above = 0.5);
    assert!(e.contains("tier.adaptation.raise_above"), "{e}");
    let e = bad(&|t| t.adaptation.as_mut().unwrap().hold = 0);
    assert!(e.contains("tier.adaptation.hold"), "{e}");
    // Without levels the section is valid (one level).
    let mut m = model.clone();
    let t = m.tier.as_mut().unwrap();
    (t.force_levels, t.adaptation) = (Vec::new(), None);
    m.validate().unwrap();
}
