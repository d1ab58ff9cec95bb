//! `crokf-run --tool`: a tool path replayed through a model with a contact region (the
//! meniscus's `scene_touch.toml`), its forces in the estimates equal to the library's, and the
//! tool file's errors named by file and line.

use std::path::{Path, PathBuf};
use std::process::Command;

use crokf_compile::compile::{compile, CompileOptions};
use crokf_runtime::Estimator;

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("crokf-run-tool-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    dir
}

fn run(args: &[&Path]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_crokf-run"))
        .args(args)
        .output()
        .expect("crokf-run runs")
}

/// The touch model, an all-zero inputs file of `steps` rows and a tool path pressing 0.8 mm
/// along the normal of the region's first node.
fn setup(dir: &Path, steps: usize) -> (crokf_formats::Model, Vec<[f64; 3]>) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/scene_touch.toml");
    let compiled = compile(&scene, &CompileOptions::default()).expect("compile");
    std::fs::write(dir.join("touch.crokf"), &compiled.bytes).expect("write model");
    let model = compiled.model;
    let labels = model.input_labels();
    let mut inputs = format!("step,{}\n", labels.join(","));
    for k in 1..=steps {
        inputs.push_str(&format!("{k}{}\n", ",0".repeat(labels.len())));
    }
    std::fs::write(dir.join("inputs.csv"), inputs).expect("write inputs");
    let region = model.contact.as_ref().expect("contact region");
    let p = &region.rest_positions.data[0..3];
    let n = &region.normals.data[0..3];
    let radius = region.tool_radius;
    let path: Vec<[f64; 3]> = (1..=steps)
        .map(|k| {
            let d = 8e-4 * k as f64 / steps as f64;
            [0, 1, 2].map(|i| p[i] + n[i] * (radius - d))
        })
        .collect();
    let mut tool = String::from("step,tool0.x,tool0.y,tool0.z\n");
    for (k, c) in path.iter().enumerate() {
        tool.push_str(&format!("{},{:e},{:e},{:e}\n", k + 1, c[0], c[1], c[2]));
    }
    std::fs::write(dir.join("tool.csv"), tool).expect("write tool");
    (model, path)
}

/// `crokf-run` over the folder's model, inputs and `tool.csv`: the estimates' text (the
/// folder is removed).
fn replay(dir: &Path) -> String {
    let out = run(&[
        &dir.join("touch.crokf"),
        Path::new("--inputs"),
        &dir.join("inputs.csv"),
        Path::new("--tool"),
        &dir.join("tool.csv"),
        Path::new("--out"),
        &dir.join("estimates.csv"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.join("estimates.csv")).expect("estimates");
    std::fs::remove_dir_all(dir).ok();
    text
}

#[test]
fn a_tool_path_gives_the_librarys_forces() {
    let dir = scratch("forces");
    let steps = 40;
    let (model, path) = setup(&dir, steps);
    let text = replay(&dir);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let fx = header
        .iter()
        .position(|&h| h == "tool0.fx")
        .expect("tool0.fx column");
    assert_eq!(header[fx + 3], "tool0.nodes");
    assert_eq!(header[fx + 4], "tool0.status");
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let mut touching = 0;
    for c in &path {
        est.step_with_tools(&[*c], &inputs, &none).expect("step");
        let t = est.tool_contact(0).expect("tool");
        let cells: Vec<&str> = lines.next().expect("a row per step").split(',').collect();
        for k in 0..3 {
            let v: f64 = cells[fx + k].parse().expect("number");
            assert_eq!(v.to_bits(), t.force[k].to_bits(), "{cells:?}");
        }
        assert_eq!(cells[fx + 3], t.active.to_string());
        assert_eq!(cells[fx + 4], format!("{:?}", t.status));
        touching += usize::from(t.active > 0);
    }
    assert!(touching > steps / 2, "the path presses ({touching} steps)");
}

#[test]
fn bad_tool_files_are_refused_naming_file_and_line() {
    let dir = scratch("bad");
    let (_, _) = setup(&dir, 5);
    let tool = dir.join("bad.csv");
    let cases: [(&str, &str); 9] = [
        (
            "step,tool0.x,tool0.y,tool0.z,tool0.grasp\n1,0,0,0,0\n2,0,0,0,1\n3,0,0,0,1\n4,0,0,0,1\n5,0,0,0,1\n",
            "bad.csv:3",
        ),
        (
            "step,tool0.x,tool0.y,tool0.z,tool0.grasp\n1,0,0,0,2\n",
            "`tool0.grasp`: 2 is not 0 or 1",
        ),
        (
            "step,tool0.x,tool0.y,tool0.z,tool1.grasp\n1,0,0,0,0\n",
            "`tool1.grasp` without the columns",
        ),
        (
            "step,tool0.x,tool0.y,tool0.z,tool0.grasp\n1,0,0,0,\n",
            "`tool0.grasp` is empty",
        ),
        ("step,tool0.x,tool0.y\n1,0,0\n", "missing column `tool0.z`"),
        ("step,tool0.x,tool0.y,tool0.z\n1,0,0,nan\n", "bad.csv:2"),
        (
            "step,tool0.x,tool0.y,tool0.z,extra\n1,0,0,0,0\n",
            "unknown column `extra`",
        ),
        (
            "step,tool0.x,tool0.y,tool0.z\n1,0,0,0\n",
            "one tool row per step",
        ),
        (
            "step,tool1.x,tool1.y,tool1.z\n1,0,0,0\n",
            "number the tools from 0",
        ),
    ];
    for (text, expected) in cases {
        std::fs::write(&tool, text).expect("write");
        let out = run(&[
            &dir.join("touch.crokf"),
            Path::new("--inputs"),
            &dir.join("inputs.csv"),
            Path::new("--tool"),
            &tool,
            Path::new("--out"),
            &dir.join("estimates.csv"),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{text:?} accepted");
        assert!(err.contains(expected), "{text:?}: {err}");
        assert!(
            !dir.join("estimates.csv").exists(),
            "nothing written for {text:?}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A `tool0.grasp` column: the tool presses, grasps the node under it where the column turns
/// 1, pulls it back out, lets go where it turns 0; the estimates equal the library's with the
/// same grasp and release.
#[test]
fn a_grasp_column_grasps_and_lets_go_as_the_library_does() {
    let dir = scratch("grasp");
    let steps = 40;
    let (model, press) = setup(&dir, 3 * steps);
    // Steps 1..=40 press (the first 40 of the setup's path), 41..=80 pull back out holding,
    // 81..=120 stay out, let go.
    let path: Vec<[f64; 3]> = (0..3 * steps)
        .map(|k| match k {
            k if k < steps => press[k],
            k if k < 2 * steps => press[2 * steps - 1 - k],
            _ => press[0],
        })
        .collect();
    let holds = |k: usize| (steps..2 * steps).contains(&k);
    let mut tool = String::from("step,tool0.x,tool0.y,tool0.z,tool0.grasp\n");
    for (k, c) in path.iter().enumerate() {
        tool.push_str(&format!(
            "{},{:e},{:e},{:e},{}\n",
            k + 1,
            c[0],
            c[1],
            c[2],
            u8::from(holds(k))
        ));
    }
    std::fs::write(dir.join("tool.csv"), tool).expect("write tool");
    let text = replay(&dir);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let fx = header
        .iter()
        .position(|&h| h == "tool0.fx")
        .expect("tool0.fx column");
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let mut grasping = 0;
    for (k, c) in path.iter().enumerate() {
        if holds(k) && est.grasped(0).is_none() {
            est.grasp(0).expect("grasp");
        } else if !holds(k) {
            est.release(0);
        }
        est.step_with_tools(&[*c], &inputs, &none).expect("step");
        let t = est.tool_contact(0).expect("tool");
        let cells: Vec<&str> = lines.next().expect("a row per step").split(',').collect();
        for q in 0..3 {
            let v: f64 = cells[fx + q].parse().expect("number");
            assert_eq!(
                v.to_bits(),
                t.force[q].to_bits(),
                "step {}: {cells:?}",
                k + 1
            );
        }
        assert_eq!(cells[fx + 4], format!("{:?}", t.status));
        grasping += usize::from(cells[fx + 4] == "Grasping");
    }
    assert_eq!(grasping, steps, "held while the column is 1");
}
