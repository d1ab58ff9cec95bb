//! `crokf-verify`'s errors carry its own name, and `report` treats the files its scene reads
//! (the mesh) as inputs that no report file may replace.

use std::path::PathBuf;
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("verify_hardening_{name}"));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn verify(args: &[&dyn AsRef<std::ffi::OsStr>]) -> (Option<i32>, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_crokf-verify"));
    for a in args {
        c.arg(a);
    }
    let o = c.output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn errors_are_prefixed_with_crokf_verify() {
    let dir = scratch("prefix");
    let missing = dir.join("missing.toml");
    for sub in ["simulate", "report"] {
        let (code, err) = verify(&[&sub, &missing, &missing, &"--out", &dir.join("out")]);
        assert_eq!(code, Some(1), "{sub}: {err}");
        assert!(
            err.starts_with("crokf-verify: error: ") && err.contains("missing.toml"),
            "{sub}: {err}"
        );
        assert!(!err.contains("crokf-compile"), "{sub}: {err}");
    }
}

#[test]
fn report_refuses_to_overwrite_the_mesh_its_scene_reads() {
    let dir = scratch("mesh_input");
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    let fixture = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../compiler/tests/fixtures/cube_41_ascii.msh");
    std::fs::copy(&fixture, out.join("report.md")).unwrap();
    let mesh_bytes = std::fs::read(out.join("report.md")).unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "[mesh]\nfile = \"out/report.md\"\n[[material]]\ngroup = \"body\"\n\
         young_modulus = 1.0e6\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\n\
         group = \"bottom\"\n[time]\ndt = 0.01\n",
    )
    .unwrap();
    let (code, err) = verify(&[
        &"report",
        &scene,
        &dir.join("scenario.toml"),
        &"--out",
        &out,
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("report.md") && err.contains("mesh") && err.contains("refusing"),
        "{err}"
    );
    assert_eq!(std::fs::read(out.join("report.md")).unwrap(), mesh_bytes);
}
