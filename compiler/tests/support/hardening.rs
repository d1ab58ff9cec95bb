//! Helpers of the hardening tests: fixtures, scratch folders, a scene for a mesh, running
//! `crokf-compile`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

pub fn case_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("hardening_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    dir
}

/// Copies the cube fixture as `cube.msh` and writes a scene for it reading `mesh`.
pub fn scene_for(dir: &Path, mesh: &str) -> PathBuf {
    std::fs::copy(fixture("cube_41_ascii.msh"), dir.join("cube.msh")).expect("copy mesh");
    let scene = dir.join("scene.toml");
    let group = if mesh.ends_with(".msh") {
        "body"
    } else {
        "MaterialIds:1"
    };
    std::fs::write(
        &scene,
        format!(
            "[mesh]\nfile = \"{mesh}\"\n[[material]]\ngroup = \"{group}\"\n\
             young_modulus = 1.0e6\npoisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\n\
             select = [{{ box = {{ min = [-1, -1, -0.01], max = [2, 2, 0.01] }}, nodes = \"all\" }}]\n\
             [time]\ndt = 0.01\n"
        ),
    )
    .expect("write scene");
    scene
}

pub fn compile(args: &[&dyn AsRef<std::ffi::OsStr>]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .args(args.iter().map(|a| a.as_ref()))
        .output()
        .expect("run crokf-compile");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// No panic message, no path into a dependency's source.
pub fn assert_no_panic_text(msg: &str) {
    for bad in [
        "panicked",
        "registry",
        ".cargo",
        "RUST_BACKTRACE",
        "memory allocation",
    ] {
        assert!(!msg.contains(bad), "{bad:?} in: {msg}");
    }
}

pub fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("list")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}
