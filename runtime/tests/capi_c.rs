//! Compiles `runtime/examples/c/example.c` with the system C compiler against the built
//! cdylib, runs it on a synthetic model and compares its output with the Rust estimator.

mod common;
use common::*;
use crokf_runtime::Estimator;
use std::path::Path;
use std::process::Command;

fn parse_line(line: &str) -> (usize, Vec<f64>, Vec<f64>) {
    // "step K used N: d d d ... | std: s s s ..."
    let (head, rest) = line.split_once(':').unwrap();
    let used = head.split_whitespace().nth(3).unwrap().parse().unwrap();
    let (d, s) = rest.split_once("| std:").unwrap();
    let nums = |t: &str| {
        t.split_whitespace()
            .map(|v| v.parse::<f64>().unwrap())
            .collect::<Vec<_>>()
    };
    (used, nums(d), nums(s))
}

#[test]
fn c_example_matches_rust() {
    let dir = scratch_dir("capi");
    let model = synthetic_model(&Spec {
        rotation: 0.1,
        every2: 2,
        ..Default::default()
    });
    let model_path = dir.join("model.crokf");
    std::fs::write(&model_path, crokf_formats::encode(&model)).unwrap();
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = dir.join("example");
    compile_c(&manifest.join("examples/c/example.c"), &exe);
    let run = Command::new(&exe)
        .arg(&model_path)
        .arg("6")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "example failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        stdout.starts_with("model: r=6 inputs=4 measurements=5 sensors=2 dt=0.01"),
        "{stdout}"
    );
    assert!(
        stdout.contains("expected error: sensor read-out buffer: expected length 6, got 7"),
        "{stdout}"
    );
    assert!(
        stdout.contains(
            "refused step: step 7: input 'push.x' = 1e300 is beyond the model's plausibility bound"
        ),
        "{stdout}"
    );
    // The example's zero measurements at step 2 lie beyond 5σ of one channel's innovation.
    assert!(
        stdout.contains("after the refused step: step 6, read-outs unchanged, gated 1"),
        "{stdout}"
    );

    // The same protocol in Rust.
    let mut est = Estimator::new(&model).unwrap();
    let lines: Vec<&str> = stdout.lines().filter(|l| l.starts_with("step ")).collect();
    assert_eq!(lines.len(), 6);
    for (k, line) in (1..=6).zip(lines) {
        let y = if k == 2 {
            vec![Some(0.0); 5]
        } else {
            vec![None; 5]
        };
        let used = est.step(&[1.0; 4], &y).unwrap();
        let (mut d, mut s) = (vec![0.0; 6], vec![0.0; 6]);
        est.sensor_displacements(&mut d).unwrap();
        est.sensor_std(&mut s).unwrap();
        let (c_used, c_d, c_s) = parse_line(line);
        assert_eq!(c_used, used, "step {k}");
        assert_eq!(c_d, d, "step {k} displacements");
        assert_eq!(c_s, s, "step {k} std");
    }
    // A broken model file: a clean error, exit status 1.
    std::fs::write(&model_path, b"CROKF\0\r\n garbage").unwrap();
    let run = Command::new(&exe).arg(&model_path).output().unwrap();
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("model.crokf") && err.contains("too short"),
        "{err}"
    );
}

#[test]
fn c_api_rejects_null_and_bad_input_without_panicking() {
    use crokf_runtime::capi::*;
    use std::ffi::CStr;
    unsafe {
        assert!(crokf_model_load(std::ptr::null()).is_null());
        assert_eq!(
            CStr::from_ptr(crokf_last_error()).to_str().unwrap(),
            "model path is NULL"
        );
        assert!(crokf_estimator_new(std::ptr::null()).is_null());
        assert_eq!(
            crokf_step(
                std::ptr::null_mut(),
                std::ptr::null(),
                0,
                std::ptr::null(),
                std::ptr::null(),
                0
            ),
            -1
        );
        let model = synthetic_model(&Spec::default());
        let bytes = crokf_formats::encode(&model);
        let m = crokf_model_from_bytes(bytes.as_ptr(), bytes.len());
        assert!(!m.is_null());
        assert_eq!(crokf_model_num_measurements(m), 5);
        assert_eq!(
            CStr::from_ptr(crokf_model_measurement_label(m, 4))
                .to_str()
                .unwrap(),
            "mid.z"
        );
        assert!(crokf_model_input_label(m, 4).is_null());
        // No tier, no failed check (a tier that failed it: tests/tests/tier_hard_cases.rs).
        assert!(crokf_model_tier_failed_check(m).is_null());
        assert!(crokf_model_tier_failed_check(std::ptr::null()).is_null());
        let e = crokf_estimator_new(m);
        crokf_model_free(m);
        let u = [1.0; 4];
        let y = [0.5, f64::NAN, 0.1, 0.2, 0.3];
        let present = [1u8, 0, 1, 1, 1];
        // NaN marked missing: fine. NaN present: error, state untouched.
        assert_eq!(
            crokf_step(e, u.as_ptr(), 4, y.as_ptr(), present.as_ptr(), 5),
            4
        );
        let mut before = [0.0; 6];
        assert_eq!(crokf_state(e, before.as_mut_ptr(), 6), 0);
        assert_eq!(
            crokf_step(e, u.as_ptr(), 4, y.as_ptr(), std::ptr::null(), 5),
            -1
        );
        assert!(CStr::from_ptr(crokf_last_error())
            .to_str()
            .unwrap()
            .contains("not finite"));
        let mut after = [0.0; 6];
        crokf_state(e, after.as_mut_ptr(), 6);
        assert_eq!(before, after);
        assert_eq!(crokf_step_index(e), 1);
        assert_eq!(crokf_node_positions(e, 7, after.as_mut_ptr(), 3), -1);
        crokf_estimator_free(e);
    }
}
