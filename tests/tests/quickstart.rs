//! The README's "Bring your own mesh" quickstart, run as written: the `sh` block under that
//! heading is taken from README.md and run by `sh -eu` in a temporary folder holding a copy of
//! `models/quickstart/`, with `crokf-compile` and `crokf-run` of this build first on the PATH.
//! The test fails when a command of the block fails, and checks what the commands wrote against
//! the scene and the recording: the model's compile report, `estimates.csv` (header, one row per
//! input row, t = kΔt, estimates that follow the markers to within their noise while the push
//! that nobody told the runtime bends the finger by many σ, the filter's σ below the markers'),
//! and the VTU series.
//!
//! `cargo test -p crokf-tests --test quickstart -- --nocapture` prints the figures. The tools
//! are built first (`cargo build --bin crokf-compile --bin crokf-run`, a no-op when they are
//! fresh) so that the block never runs stale binaries.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use crokf_compile::scene::SceneFile;

#[path = "support/tools.rs"]
mod tools;
use tools::{repository, tools};

/// The heading of the README section whose first `sh` block is the quickstart.
const HEADING: &str = "## Bring your own mesh";

/// The first ```` ```sh ```` block after [`HEADING`], without its fences.
fn quickstart_block(readme: &str) -> Result<String, String> {
    let section = readme
        .split_once(&format!("\n{HEADING}\n"))
        .ok_or(format!("README.md has no heading `{HEADING}`"))?
        .1;
    let section = section.split("\n## ").next().unwrap_or(section);
    let body = section
        .split_once("```sh\n")
        .ok_or(format!("README.md: no ```sh block under `{HEADING}`"))?
        .1;
    let (block, _) = body.split_once("\n```").ok_or(format!(
        "README.md: the ```sh block under `{HEADING}` is not closed"
    ))?;
    Ok(block.to_owned() + "\n")
}

#[test]
fn the_quickstart_block_is_found() {
    let text = "x\n## Bring your own mesh\n\ntext\n```sh\na b\nc\n```\nmore\n```sh\nd\n```\n";
    assert_eq!(quickstart_block(text).unwrap(), "a b\nc\n");
    // A block in a later section is not the quickstart's.
    let later = "## Bring your own mesh\ntext\n## Next\n```sh\nd\n```\n";
    assert!(quickstart_block(later).is_err());
}

/// A temporary folder removed when dropped.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The non-comment rows of a CSV file written by crokf or the generator: header, then rows of
/// cells (empty cells kept as `None`).
struct Table {
    header: Vec<String>,
    rows: Vec<Vec<Option<f64>>>,
}

impl Table {
    fn read(path: &Path) -> Table {
        let text =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut lines = text
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with('#'));
        let header: Vec<String> = lines
            .next()
            .unwrap_or_else(|| panic!("{}: no header", path.display()))
            .split(',')
            .map(str::to_owned)
            .collect();
        let rows = lines
            .map(|l| {
                l.split(',')
                    .map(|c| {
                        (!c.is_empty()).then(|| {
                            c.parse::<f64>()
                                .unwrap_or_else(|_| panic!("{}: `{c}`", path.display()))
                        })
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        Table { header, rows }
    }

    fn column(&self, name: &str) -> usize {
        self.header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.header))
    }
}

#[test]
fn the_readme_quickstart_runs_as_written() {
    let root = repository();
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let block = quickstart_block(&readme).unwrap_or_else(|e| panic!("{e}"));
    let tools = tools(&["crokf-compile", "crokf-run"]);

    // A temporary folder with a copy of models/quickstart/, as in a checkout.
    let tmp =
        TempDir(std::env::temp_dir().join(format!("crokf-quickstart-{}", std::process::id())));
    let _ = std::fs::remove_dir_all(&tmp.0);
    let copy = tmp.0.join("models").join("quickstart");
    std::fs::create_dir_all(&copy).expect("temporary folder");
    for entry in std::fs::read_dir(root.join("models").join("quickstart")).expect("quickstart") {
        let entry = entry.expect("entry");
        if entry.file_type().expect("file type").is_file() {
            std::fs::copy(entry.path(), copy.join(entry.file_name())).expect("copy");
        }
    }

    let path = std::env::join_paths(std::iter::once(tools.clone()).chain(std::env::split_paths(
        &std::env::var_os("PATH").unwrap_or_default(),
    )))
    .expect("PATH");
    let out = Command::new("sh")
        .arg("-euc")
        .arg(&block)
        .current_dir(&tmp.0)
        .env("PATH", path)
        .output()
        .expect("sh runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{stderr}");
    assert!(
        out.status.success(),
        "the README's quickstart failed:\n{block}\n--- stderr:\n{stderr}"
    );

    // The block copies the example to my-body/ and works there.
    let body = tmp.0.join("my-body");
    let scene = SceneFile::read(&body.join("scene.toml")).expect("scene");
    let scene = &scene.scene;
    let dt = scene.time.dt;

    // The compile: the order rule met its 1e-3 target; the push's σ was derived from its range.
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(body.join("report.json")).expect("report.json"),
    )
    .expect("report JSON");
    let order = report["reduction"]["order"].as_u64().expect("order");
    let step = report["measured_errors"]["step"]
        .as_f64()
        .expect("step error");
    let chirp = report["measured_errors"]["chirp"]
        .as_f64()
        .expect("chirp error");
    eprintln!("compile: r = {order}, measured error step {step:.2e}, chirp {chirp:.2e}");
    assert!(order >= 1 && step <= 1e-3 && chirp <= 1e-3, "{report}");
    let notes = report["notes"].to_string();
    assert!(
        notes.contains("load 'push': force σ") && notes.contains("derived from its range"),
        "{notes}"
    );
    // On stderr the notes name the binary, as its warnings and errors do.
    assert!(
        stderr
            .lines()
            .any(|l| l.starts_with("crokf-compile: note: load 'push': force σ")),
        "{stderr}"
    );
    assert!(!stderr.lines().any(|l| l.starts_with("note: ")), "{stderr}");
    assert!(body.join("body.crokf").is_file());

    // estimates.csv: the header docs/csv.md states, one row per input row, t = kΔt.
    let inputs = Table::read(&body.join("inputs.csv"));
    let measured = Table::read(&body.join("measurements.csv"));
    let estimates = Table::read(&body.join("estimates.csv"));
    let mut header = vec!["step".to_owned(), "t".to_owned()];
    for suffix in ["", "_std"] {
        for s in &scene.sensors {
            for c in ["x", "y", "z"] {
                header.push(format!("{}.{c}{suffix}", s.name));
            }
        }
    }
    assert_eq!(estimates.header, header);
    assert_eq!(estimates.rows.len(), inputs.rows.len());
    for (i, row) in estimates.rows.iter().enumerate() {
        let k = (i + 1) as f64;
        assert_eq!(row[0], Some(k));
        let t = row[1].expect("t");
        assert!((t - k * dt).abs() <= 1e-9 * k * dt, "row {i}: t = {t}");
        assert!(row.iter().all(|v| v.is_some_and(f64::is_finite)), "row {i}");
    }

    // The filter follows the markers: its estimate stays within the markers' noise of them
    // (RMS of estimate − marker below 1.5σ per channel), while the push bends the finger by
    // many σ (a filter that ignored the markers would sit many σ away).
    let by_step: BTreeMap<u64, &Vec<Option<f64>>> = measured
        .rows
        .iter()
        .map(|r| (r[0].expect("step") as u64, r))
        .collect();
    let mut worst_ratio: f64 = 0.0;
    let mut largest_motion: f64 = 0.0;
    for s in &scene.sensors {
        for &c in &s.components {
            let label = format!("{}.{}", s.name, c.label());
            let (m, e) = (measured.column(&label), estimates.column(&label));
            let sigma = s.noise_std.of(c);
            let (mut sum, mut n) = (0.0, 0usize);
            for row in &estimates.rows {
                let k = row[0].expect("step") as u64;
                if let Some(y) = by_step.get(&k).and_then(|r| r[m]) {
                    sum += (row[e].expect("estimate") - y).powi(2);
                    n += 1;
                    largest_motion = largest_motion.max(y.abs() / sigma);
                }
            }
            assert!(n > 0, "{label}: no measurement");
            let ratio = (sum / n as f64).sqrt() / sigma;
            eprintln!("{label}: RMS(estimate − marker) = {ratio:.3} σ over {n} steps");
            worst_ratio = worst_ratio.max(ratio);

            // At the last step the filter's σ of a measured component lies below the marker's.
            let last = estimates.rows.last().expect("rows");
            let std = last[estimates.column(&format!("{label}_std"))].expect("std");
            assert!(std > 0.0 && std < sigma, "{label}: σ {std} against {sigma}");
        }
    }
    eprintln!(
        "largest marker displacement {largest_motion:.1} σ; worst RMS ratio {worst_ratio:.3}"
    );
    assert!(largest_motion > 20.0, "the push hardly moved the markers");
    assert!(worst_ratio < 1.5, "the estimates do not follow the markers");

    // The VTU series: one file per step and the collection.
    let vtu: Vec<_> = std::fs::read_dir(body.join("vtu"))
        .expect("vtu folder")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    let steps = vtu
        .iter()
        .filter(|n| n.starts_with("step_") && n.ends_with(".vtu"));
    assert_eq!(steps.count(), inputs.rows.len());
    assert!(vtu.iter().any(|n| n == "estimates.pvd"), "{vtu:?}");
}
