//! `crokf-compile` never destroys its inputs or leaves a half-written result: outputs that are
//! inputs, two outputs on one path and outputs into a missing folder are refused before any
//! work, with a message naming both paths.

use std::path::{Path, PathBuf};
use std::process::Command;

fn case_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("compile_cli_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    dir
}

/// Copies the cube fixture and a scene for it into `dir`; returns the scene path.
fn scene_in(dir: &Path) -> PathBuf {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    std::fs::copy(fixtures.join("cube_41_ascii.msh"), dir.join("cube.msh")).expect("copy mesh");
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "[mesh]\nfile = \"cube.msh\"\n[[material]]\ngroup = \"body\"\nyoung_modulus = 1.0e6\n\
         poisson_ratio = 0.3\ndensity = 1000.0\n[[fixed]]\ngroup = \"bottom\"\n[time]\ndt = 0.01\n",
    )
    .expect("write scene");
    scene
}

fn compile(args: &[&Path]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .args(args)
        .output()
        .expect("run crokf-compile");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn outputs_that_are_inputs_or_collide_are_refused_before_any_work() {
    let dir = case_dir("refusals");
    let scene = scene_in(&dir);
    let mesh = dir.join("cube.msh");
    let scene_bytes = std::fs::read(&scene).expect("scene");
    let mesh_bytes = std::fs::read(&mesh).expect("mesh");
    let o = Path::new("-o");
    let report = Path::new("--report");

    let (ok, err) = compile(&[&scene, o, &scene]);
    assert!(
        !ok && err.contains("scene") && err.contains("refusing"),
        "{err}"
    );
    let (ok, err) = compile(&[&scene, o, &mesh]);
    assert!(
        !ok && err.contains("mesh") && err.contains("refusing"),
        "{err}"
    );
    let model = dir.join("model.crokf");
    let (ok, err) = compile(&[&scene, o, &model, report, &model]);
    assert!(!ok && err.contains("same file"), "{err}");
    let missing = dir.join("no/such/folder/report.json");
    let (ok, err) = compile(&[&scene, o, &model, report, &missing]);
    assert!(!ok && err.contains("does not exist"), "{err}");

    assert_eq!(std::fs::read(&scene).expect("scene"), scene_bytes);
    assert_eq!(std::fs::read(&mesh).expect("mesh"), mesh_bytes);
    assert!(
        !model.exists(),
        "no model is written when the command is refused"
    );
    let strays: Vec<_> = std::fs::read_dir(&dir)
        .expect("list")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(strays.is_empty(), "stray temporary files: {strays:?}");
}

/// A node-list file is part of the model's input digest: `--check` reports the model stale
/// when the list changes, and up to date when it is restored.
#[test]
fn check_sees_a_changed_node_list() {
    let dir = case_dir("node_list_digest");
    let scene = scene_in(&dir);
    let mut text = std::fs::read_to_string(&scene).expect("scene");
    text.push_str(
        "[[load]]\nname = \"push\"\ngroup = \"body\"\ndistribution = \"uniform\"\n\
         force_model = \"white\"\n\
         [[display]]\nname = \"few\"\nselect = [{ node_list = \"few.txt\" }]\n",
    );
    std::fs::write(&scene, text).expect("write scene");
    let list = dir.join("few.txt");
    std::fs::write(&list, "1 2 3\n").expect("write list");
    let model = dir.join("model.crokf");
    let (ok, err) = compile(&[&scene, Path::new("-o"), &model]);
    assert!(ok, "{err}");
    let check = |expect_ok: bool| {
        let (ok, err) = compile(&[Path::new("--check"), &model, &scene]);
        assert_eq!(ok, expect_ok, "{err}");
        err
    };
    check(true);
    std::fs::write(&list, "1 2 3 4\n").expect("change list");
    let err = check(false);
    assert!(err.contains("STALE") && err.contains("few.txt"), "{err}");
    std::fs::write(&list, "1 2 3\n").expect("restore list");
    check(true);
}

/// A 288-tetrahedron beam with a co-rotational tier of 12 short training runs (six axes,
/// ramp and step); returns the scene path.
fn tier_scene_in(dir: &Path) -> PathBuf {
    use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .expect("mesh");
    let text = BeamScene {
        sensors: vec![("tip".into(), [0.99, 0.05, 0.1])],
        dt: 0.005,
        ..BeamScene::default()
    }
    .toml()
        + "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n\
           ranges = { tip = 30.0 }\nduration = 0.05\nevery = 2\norder = 6\n\
           directions = \"axes\"\n";
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, text).expect("write scene");
    scene
}

/// `--list-cases` prints one line per training run (index, 64-digit identity, label);
/// `--run-case K --cache DIR` writes exactly that case's file and reuses it when run again;
/// an index past the plan, `--run-case` without `--cache`, a cache path that is a file and a
/// scene without a tier are refused with a message naming them.
#[test]
fn training_cases_are_listed_and_run_one_at_a_time() {
    let dir = case_dir("cases");
    let scene = tier_scene_in(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg(&scene)
        .arg("--list-cases")
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let listing = String::from_utf8(out.stdout).expect("utf-8");
    let lines: Vec<Vec<&str>> = listing.lines().map(|l| l.split('\t').collect()).collect();
    assert_eq!(lines.len(), 12, "{listing}");
    for (k, fields) in lines.iter().enumerate() {
        assert_eq!(fields.len(), 3, "{fields:?}");
        assert_eq!(fields[0], k.to_string());
        assert!(fields[1].len() == 64 && fields[1].bytes().all(|b| b.is_ascii_hexdigit()));
    }
    assert_eq!(lines[0][2], "tip (+1, +0, +0) ramp 1.25×");
    let mut ids: Vec<&str> = lines.iter().map(|f| f[1]).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), 12, "identities are distinct");

    let cache = dir.join("cache");
    let run = |k: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
            .arg(&scene)
            .args(["--run-case", k, "--cache"])
            .arg(&cache)
            .output()
            .expect("run");
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, err) = run("3");
    assert!(
        ok && err.contains("case 3 of 12") && err.contains("wrote"),
        "{err}"
    );
    let files: Vec<_> = std::fs::read_dir(&cache)
        .expect("cache")
        .flatten()
        .collect();
    assert_eq!(files.len(), 1);
    assert_eq!(
        files[0].file_name().to_string_lossy(),
        format!("{}.case", lines[3][1])
    );
    let (ok, err) = run("3");
    assert!(ok && err.contains("already in the cache"), "{err}");
    let (ok, err) = run("12");
    assert!(!ok && err.contains("12 cases (0 to 11)"), "{err}");

    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg(&scene)
        .args(["--run-case", "0"])
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--cache"), "{err}");
    let file = dir.join("a_file");
    std::fs::write(&file, "x").expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg(&scene)
        .args(["--run-case", "0", "--cache"])
        .arg(&file)
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is a file"), "{err}");

    let plain = scene_in(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .arg(&plain)
        .arg("--list-cases")
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("[reduction.corotational]"),
        "{err}"
    );
}

/// A first argument `identify` selects `crokf-compile identify` (its own usage on a missing
/// argument); a scene file of that name is compiled as `./identify`.
#[test]
fn a_first_argument_identify_selects_the_subcommand() {
    let dir = case_dir("identify");
    let scene = scene_in(&dir);
    let mut text = std::fs::read_to_string(&scene).expect("scene");
    text.push_str(
        "[[load]]\nname = \"push\"\ngroup = \"body\"\ndistribution = \"uniform\"\n\
         force_model = \"white\"\n",
    );
    std::fs::write(dir.join("identify"), text).expect("write the scene");
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
            .current_dir(&dir)
            .args(args)
            .output()
            .expect("run crokf-compile")
    };
    let out = run(&["identify", "-o", "model.crokf"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("Usage: crokf-compile identify") && err.contains("--measurements"),
        "{err}"
    );
    assert!(!dir.join("model.crokf").exists());
    let out = run(&["./identify", "-o", "model.crokf", "--no-measure"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(dir.join("model.crokf").is_file());
}
