//! `crokf-run` end to end: CSV in, CSV and VTU out, compared with the library estimator.

#[path = "../../runtime/tests/common/mod.rs"]
mod common;
use common::*;
use crokf_runtime::Estimator;
use std::process::Command;

fn run(args: &[&std::path::Path]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_crokf-run"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn crokf_run_matches_the_library() {
    let dir = scratch_dir("cli");
    let model = synthetic_model(&Spec {
        rotation: 0.1,
        every2: 2,
        ..Default::default()
    });
    let mp = dir.join("model.crokf");
    std::fs::write(&mp, crokf_formats::encode(&model)).unwrap();
    let mut rng = Rng(41);
    let steps = 8;
    let inputs: Vec<Vec<f64>> = (0..steps).map(|_| rng.vec(4, 1.0)).collect();
    // Columns in a different order than the model's.
    let mut csv = String::from("step,gravity,push.z,push.x,push.y\n");
    for (k, u) in inputs.iter().enumerate() {
        csv += &format!("{},{},{},{},{}\n", k + 1, u[3], u[2], u[0], u[1]);
    }
    let ip = dir.join("inputs.csv");
    std::fs::write(&ip, csv).unwrap();
    // Measurements on steps 2, 3, 6 only; mid.x never given; an empty cell at step 3.
    let meas_csv = "step,tip.x,mid.z,tip.y,tip.z\n# comment\n2,0.01,0.02,0.03,0.04\n3,0.02,,0.01,0.0\n6,-0.01,0.03,0.02,0.01\n";
    let yp = dir.join("measurements.csv");
    std::fs::write(&yp, meas_csv).unwrap();
    let op = dir.join("estimates.csv");
    let vd = dir.join("vtu");
    // --vtu writes into an existing folder (a missing one is refused, tests/hardening.rs).
    std::fs::create_dir_all(&vd).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-run"))
        .arg(&mp)
        .arg("--inputs")
        .arg(&ip)
        .arg("--measurements")
        .arg(&yp)
        .arg("--out")
        .arg(&op)
        .arg("--vtu")
        .arg(&vd)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let text = std::fs::read_to_string(&op).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "step,t,tip.x,tip.y,tip.z,mid.x,mid.y,mid.z,tip.x_std,tip.y_std,tip.z_std,mid.x_std,mid.y_std,mid.z_std"
    );
    let mut est = Estimator::new(&model).unwrap();
    let ys = |k: usize| -> Vec<Option<f64>> {
        // channel order: tip.x tip.y tip.z mid.x mid.z
        match k {
            2 => vec![Some(0.01), Some(0.03), Some(0.04), None, Some(0.02)],
            3 => vec![Some(0.02), Some(0.01), Some(0.0), None, None],
            6 => vec![Some(-0.01), Some(0.02), Some(0.01), None, Some(0.03)],
            _ => vec![None; 5],
        }
    };
    let mut node_u = vec![];
    for (k, line) in (1..=steps).zip(lines) {
        est.step(&inputs[k - 1], &ys(k)).unwrap();
        let (mut d, mut s) = (vec![0.0; 6], vec![0.0; 6]);
        est.sensor_displacements(&mut d).unwrap();
        est.sensor_std(&mut s).unwrap();
        let cells: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        assert_eq!(cells[0], k as f64);
        assert!((cells[1] - k as f64 * 0.01).abs() < 1e-15);
        assert_eq!(&cells[2..8], &d[..], "step {k}");
        assert_eq!(&cells[8..14], &s[..], "step {k}");
        if k == 3 {
            node_u = vec![0.0; 12];
            est.node_displacements(0, &mut node_u).unwrap();
        }
    }
    // VTU: one file per step, a pvd listing them, step 3's displacements.
    let pvd = std::fs::read_to_string(vd.join("estimates.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), steps);
    assert!(pvd.contains("file=\"step_000003.vtu\""));
    let vtu = std::fs::read_to_string(vd.join("step_000003.vtu")).unwrap();
    assert!(
        vtu.contains("<Piece NumberOfPoints=\"5\" NumberOfCells=\"3\">"),
        "{vtu}"
    );
    // The values of the data array `name` (whitespace-separated, any line layout).
    let values = |name: &str| -> Vec<f64> {
        let start = vtu.find(&format!("Name=\"{name}\"")).unwrap();
        let body = &vtu[start..];
        let body = &body[body.find('>').unwrap() + 1..body.find("</DataArray>").unwrap()];
        body.split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect()
    };
    assert_eq!(
        values("connectivity"),
        [0.0, 1.0, 2.0, 0.0, 2.0, 3.0, 4.0],
        "{vtu}"
    );
    assert_eq!(values("types"), [5.0, 5.0, 1.0], "{vtu}");
    let vals = values("displacement");
    assert_eq!(vals.len(), 15);
    assert_eq!(vals[..12], node_u[..]);
}

#[test]
fn crokf_run_errors_name_file_and_line() {
    let dir = scratch_dir("cli-errors");
    let model = synthetic_model(&Spec::default());
    let mp = dir.join("model.crokf");
    std::fs::write(&mp, crokf_formats::encode(&model)).unwrap();
    let op = dir.join("out.csv");
    let check = |name: &str, content: &str, expect: &str| {
        let ip = dir.join(name);
        std::fs::write(&ip, content).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_crokf-run"))
            .arg(&mp)
            .arg("--inputs")
            .arg(&ip)
            .arg("--out")
            .arg(&op)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(expect), "expected `{expect}` in: {err}");
    };
    check(
        "a.csv",
        "step,push.x,push.y,push.z,gravity,bogus\n",
        "a.csv:1: unknown column `bogus`",
    );
    check(
        "b.csv",
        "step,push.x,push.y,push.z\n",
        "b.csv:1: missing column `gravity`",
    );
    check(
        "c.csv",
        "step,push.x,push.y,push.z,gravity\n1,0,0,0,1\n3,0,0,0,1\n",
        "c.csv:3: step 3, expected 2",
    );
    check(
        "d.csv",
        "t,push.x,push.y,push.z,gravity\n0.01,0,0,0,1\n0.02,0,x,0,1\n",
        "d.csv:3: `push.y`: `x` is not a finite number",
    );
    check(
        "e.csv",
        "step,push.x,push.y,push.z,gravity\n1,0,0,0,inf\n",
        "e.csv:2: `gravity`",
    );
    check(
        "f.csv",
        "t,push.x,push.y,push.z,gravity\n0.015,0,0,0,1\n",
        "not a positive multiple",
    );
    // A corrupt model names the model file.
    std::fs::write(&mp, b"nonsense").unwrap();
    let out = run(&[
        &mp,
        std::path::Path::new("--inputs"),
        &dir.join("a.csv"),
        std::path::Path::new("--out"),
        &op,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("model.crokf") && err.contains("not a crokf model file"),
        "{err}"
    );
}
