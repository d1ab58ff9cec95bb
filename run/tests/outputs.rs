//! `crokf-run` loses nothing and half-writes nothing: outputs that are
//! inputs or collide are refused before any work, a failed run leaves the old files and no
//! stray temporary, the gate's summary line, and CSV details the csv crate handles.

#[path = "../../runtime/tests/common/mod.rs"]
mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

struct Case {
    dir: PathBuf,
    model: PathBuf,
    inputs: PathBuf,
}

fn case(name: &str, rows: usize) -> Case {
    let dir = scratch_dir(name);
    let model = dir.join("model.crokf");
    std::fs::write(
        &model,
        crokf_formats::encode(&synthetic_model(&Spec::default())),
    )
    .unwrap();
    let inputs = dir.join("inputs.csv");
    let mut csv = String::from("step,push.x,push.y,push.z,gravity\n");
    for k in 1..=rows {
        csv += &format!("{k},0.1,0.2,0.3,1\n");
    }
    std::fs::write(&inputs, csv).unwrap();
    Case { dir, model, inputs }
}

fn crokf_run(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_crokf-run"));
    for a in args {
        c.arg(a);
    }
    c.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Names of the entries of `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn an_output_that_is_an_input_is_refused_before_any_work() {
    let c = case("out-is-input", 3);
    let model_bytes = std::fs::read(&c.model).unwrap();
    let inputs_text = std::fs::read(&c.inputs).unwrap();
    for (target, role) in [(&c.model, "model"), (&c.inputs, "--inputs")] {
        let o = crokf_run(&[&c.model, &"--inputs", &c.inputs, &"--out", target]);
        assert_eq!(o.status.code(), Some(1));
        let e = stderr(&o);
        assert!(
            e.contains(&format!("is the {role}")) && e.contains("refusing"),
            "{e}"
        );
    }
    // Through another spelling of the same path.
    let other = c.dir.join(".").join("inputs.csv");
    let o = crokf_run(&[&c.model, &"--inputs", &c.inputs, &"--out", &other]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(std::fs::read(&c.model).unwrap(), model_bytes);
    assert_eq!(std::fs::read(&c.inputs).unwrap(), inputs_text);
    // --out inside --vtu under a series name, and a --vtu that is a file.
    let vtu = c.dir.join("vtu");
    std::fs::create_dir(&vtu).unwrap();
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--out",
        &vtu.join("estimates.pvd"),
        &"--vtu",
        &vtu,
    ]);
    assert!(stderr(&o).contains("are the same file"), "{}", stderr(&o));
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--out",
        &c.dir.join("e.csv"),
        &"--vtu",
        &c.inputs,
    ]);
    assert!(
        stderr(&o).contains("exists and is not a folder"),
        "{}",
        stderr(&o)
    );
    // An output folder that does not exist.
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--out",
        &c.dir.join("no/such/e.csv"),
    ]);
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));
    assert_eq!(listing(&c.dir), ["inputs.csv", "model.crokf", "vtu"]);
}

#[test]
fn a_failed_run_leaves_the_old_files_and_nothing_else() {
    let c = case("failed-run", 8);
    let out = c.dir.join("estimates.csv");
    let vtu = c.dir.join("vtu");
    std::fs::create_dir(&vtu).unwrap();
    let ok = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--out",
        &out,
        &"--vtu",
        &vtu,
    ]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let old_csv = std::fs::read(&out).unwrap();
    assert_eq!(String::from_utf8_lossy(&old_csv).lines().count(), 9);
    let old_vtu = listing(&vtu);
    assert_eq!(old_vtu.len(), 9);
    // Step 5 has an implausible load: the run fails there.
    let mut text = std::fs::read_to_string(&c.inputs).unwrap();
    text = text.replace("5,0.1,0.2,0.3,1", "5,0.1,1e300,0.3,1");
    let bad = c.dir.join("bad.csv");
    std::fs::write(&bad, text).unwrap();
    let o = crokf_run(&[&c.model, &"--inputs", &bad, &"--out", &out, &"--vtu", &vtu]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("step 5 (") && e.contains("bad.csv:6") && e.contains("push.y"),
        "{e}"
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        old_csv,
        "old estimates untouched"
    );
    assert_eq!(listing(&vtu), old_vtu);
    assert_eq!(
        listing(&c.dir),
        [
            "bad.csv",
            "estimates.csv",
            "inputs.csv",
            "model.crokf",
            "vtu"
        ]
    );
    // A failed first run leaves nothing.
    let fresh = c.dir.join("fresh.csv");
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &bad,
        &"--out",
        &fresh,
        &"--vtu",
        &c.dir.join("v2"),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!fresh.exists() && !c.dir.join("v2").exists());
    assert_eq!(listing(&c.dir).len(), 5);
}

#[test]
fn the_gate_is_reported_and_configurable() {
    let c = case("gate", 40);
    let meas = c.dir.join("m.csv");
    // tip.x far off at step 1 (an outlier, below the plausibility bound); the rest absent.
    std::fs::write(&meas, "step,tip.x\n1,8.0\n").unwrap();
    let out = c.dir.join("e.csv");
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--measurements",
        &meas,
        &"--out",
        &out,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("innovation gate 5σ: skipped 1 of 1 measurements (tip.x 1)"),
        "{}",
        stderr(&o)
    );
    let o = crokf_run(&[
        &c.model,
        &"--inputs",
        &c.inputs,
        &"--measurements",
        &meas,
        &"--out",
        &out,
        &"--gate",
        &"0",
    ]);
    assert!(
        stderr(&o).contains("innovation gate off: 1 measurements used"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn csv_byte_order_mark_quotes_and_crlf_are_read() {
    let c = case("bom", 0);
    let out = c.dir.join("e.csv");
    let text = "\u{feff}step,\"push.x\",push.y,push.z,gravity\r\n1,0.1,0.2,0.3,1\r\n# a comment\r\n\r\n2,0.1,0.2,0.3,1\r\n";
    std::fs::write(&c.inputs, text).unwrap();
    let o = crokf_run(&[&c.model, &"--inputs", &c.inputs, &"--out", &out]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&out).unwrap().lines().count(), 3);
    // Header only: refused, naming the line.
    std::fs::write(&c.inputs, "step,push.x,push.y,push.z,gravity\n").unwrap();
    let o = crokf_run(&[&c.model, &"--inputs", &c.inputs, &"--out", &out]);
    assert!(
        stderr(&o).contains("inputs.csv:1: header only"),
        "{}",
        stderr(&o)
    );
}
