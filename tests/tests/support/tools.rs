//! The workspace's binaries of this build, for the tests that run them as a user would
//! (`quickstart.rs`, `identify_alias.rs`; included by `#[path]`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository root.
pub fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The folder of this build's binaries, with the `names` built (cargo's own freshness check:
/// nothing is rebuilt when they are up to date). Every binary of the
/// workspace is built, as `cargo test --workspace` builds them: the same packages and so the
/// same features, so that after that command this build is a no-op (the dev-dependencies add
/// no feature to a normal dependency; a `--bin` build of two packages alone resolves fewer
/// features and compiled both crates again).
pub fn tools(names: &[&str]) -> PathBuf {
    // target/<profile>/deps/<test>-<hash> → target/<profile>
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>/deps")
        .to_path_buf();
    let profile = match dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => "dev".to_owned(),
        Some(other) => other.to_owned(),
        None => panic!("no profile folder above {}", exe.display()),
    };
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| env!("CARGO").into());
    let out = Command::new(cargo)
        .current_dir(repository())
        .args([
            "build",
            "--locked",
            "--workspace",
            "--bins",
            "--profile",
            &profile,
        ])
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo build of the tools failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for tool in names {
        let path = dir.join(format!("{tool}{}", std::env::consts::EXE_SUFFIX));
        assert!(path.is_file(), "{} was not built", path.display());
    }
    dir
}
