//! `crokf-verify identify` is `crokf-compile identify` under another name: on the identify
//! tests' beam (`compiler/tests/support/identify_beam.rs`: a 12×2×2-cell co-rotational beam and
//! a recording of a random-walk tip force, generated here), both commands, run in two copies of
//! the same folder with the same arguments, exit alike, print the same report and write
//! byte-identical identified scenes; a refusal is alike too (status 2, the same report, the same
//! reason after the executable's name, nothing written).
//!
//! `cargo test -p crokf-tests --test identify_alias` (builds the workspace's binaries first, a
//! no-op after `cargo test --workspace`).

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../../compiler/tests/support/identify_beam.rs"]
mod identify_beam;
use identify_beam::{truth, write_beam, write_csv, TRUE_SIGMA};

#[path = "support/tools.rs"]
mod tools;
use tools::tools;

/// The files of the beam's folder.
const FILES: [&str; 5] = [
    "beam.msh",
    "scene.toml",
    "model.crokf",
    "walk.csv",
    "held.csv",
];

/// `TOOL identify scene.toml model.crokf --measurements MEASUREMENTS ARGS…` in `dir`: (exit
/// status, stdout, stderr).
fn identify(tool: &Path, dir: &Path, measurements: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(tool)
        .current_dir(dir)
        .args(["identify", "scene.toml", "model.crokf", "--measurements"])
        .arg(measurements)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

#[test]
fn crokf_verify_identify_prints_and_writes_what_crokf_compile_identify_does() {
    let bin = tools(&["crokf-compile", "crokf-verify"]);
    let root = std::env::temp_dir().join(format!("crokf-identify-alias-{}", std::process::id()));
    let compile_dir = root.join("compile");
    let model = write_beam(&compile_dir);
    write_csv(
        &compile_dir.join("walk.csv"),
        &model,
        &truth(&model, TRUE_SIGMA, 1.0, 11),
    );
    write_csv(
        &compile_dir.join("held.csv"),
        &model,
        &truth(&model, 0.0, 1.0, 12),
    );
    let verify_dir = root.join("verify");
    std::fs::create_dir_all(&verify_dir).unwrap();
    for name in FILES {
        std::fs::copy(compile_dir.join(name), verify_dir.join(name)).unwrap();
    }
    let exe = |name: &str| bin.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    let runs: Vec<(PathBuf, &Path)> = vec![
        (exe("crokf-compile"), compile_dir.as_path()),
        (exe("crokf-verify"), verify_dir.as_path()),
    ];

    // Identified: the same status, report and `wrote` line; the same bytes written.
    let args = ["--lags", "20", "--skip", "100", "-o", "identified.toml"];
    let [compiled, verified] = [0, 1].map(|i| identify(&runs[i].0, runs[i].1, "walk.csv", &args));
    println!("{}", compiled.1);
    assert_eq!(compiled.0, 0, "{}", compiled.2);
    assert!(compiled.1.contains("verdict: IDENTIFIED"), "{}", compiled.1);
    assert!(
        compiled
            .1
            .ends_with("wrote identified.toml (force_noise_std of tip)\n"),
        "{}",
        compiled.1
    );
    assert_eq!(compiled, verified);
    let scene = std::fs::read(compile_dir.join("identified.toml")).unwrap();
    assert_eq!(
        scene,
        std::fs::read(verify_dir.join("identified.toml")).unwrap()
    );
    assert!(String::from_utf8(scene)
        .unwrap()
        .contains("# identified by crokf-compile identify from walk.csv (1500 steps"));

    // Refused (a recording without load changes): status 2, the same report, the same reason.
    let args = ["--lags", "20", "--skip", "100", "-o", "refused.toml"];
    let [compiled, verified] = [0, 1].map(|i| identify(&runs[i].0, runs[i].1, "held.csv", &args));
    assert_eq!(
        (compiled.0, verified.0),
        (2, 2),
        "{}{}",
        compiled.2,
        verified.2
    );
    assert!(
        compiled.1.contains("verdict: NOT IDENTIFIED"),
        "{}",
        compiled.1
    );
    assert_eq!(compiled.1, verified.1);
    let reason = |stderr: &str, name: &str| {
        stderr
            .strip_prefix(&format!("{name}: identify refused: "))
            .unwrap_or_else(|| panic!("{stderr}"))
            .to_owned()
    };
    assert_eq!(
        reason(&compiled.2, "crokf-compile"),
        reason(&verified.2, "crokf-verify")
    );
    assert!(compiled.2.contains("not exciting enough"), "{}", compiled.2);
    assert!(!compile_dir.join("refused.toml").exists());
    assert!(!verify_dir.join("refused.toml").exists());
    let _ = std::fs::remove_dir_all(&root);
}
