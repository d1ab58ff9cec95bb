//! `crokf-compile`'s outputs: every file the scene reads (mesh, node lists) is an input that no
//! output may replace, `--export-matrices` replaces its set of files whole or not at all in a
//! folder that must exist, and temporaries left by a killed run are removed and named.

use std::process::Command;

#[path = "support/hardening.rs"]
mod support;
use support::{case_dir, compile, fixture, listing, scene_for};

#[test]
fn every_file_the_scene_reads_is_an_input() {
    let dir = case_dir("inputs");
    let scene = scene_for(&dir, "cube.msh");
    let text = std::fs::read_to_string(&scene).expect("scene").replace(
        "select = [{ box = { min = [-1, -1, -0.01], max = [2, 2, 0.01] }, nodes = \"all\" }]",
        "select = [{ node_list = \"NODES.txt\" }]",
    );
    std::fs::write(&scene, text).expect("scene");
    let nodes = dir.join("NODES.txt");
    std::fs::write(&nodes, "1 2 3 4\n").expect("list");
    for flag in ["-o", "--report"] {
        let (code, err) = compile(&[&scene, &flag, &nodes]);
        assert_eq!(code, Some(1), "{flag}: {err}");
        assert!(
            err.contains("node_list") && err.contains("NODES.txt") && err.contains("refusing"),
            "{flag}: {err}"
        );
        assert_eq!(std::fs::read_to_string(&nodes).expect("list"), "1 2 3 4\n");
    }
    // --export-matrices into a folder holding the mesh under a name the export writes.
    let sub = dir.join("export");
    std::fs::create_dir(&sub).expect("mkdir");
    std::fs::copy(fixture("cube_41_ascii.msh"), sub.join("M.mtx")).expect("copy");
    let mesh_bytes = std::fs::read(sub.join("M.mtx")).expect("mesh");
    let scene2 = sub.join("scene.toml");
    std::fs::write(
        &scene2,
        std::fs::read_to_string(&scene)
            .expect("scene")
            .replace("cube.msh", "M.mtx")
            .replace("NODES.txt", "../NODES.txt"),
    )
    .expect("scene");
    let (code, err) = compile(&[&scene2, &"--export-matrices", &sub]);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("mesh") && err.contains("M.mtx") && err.contains("refusing"),
        "{err}"
    );
    assert_eq!(std::fs::read(sub.join("M.mtx")).expect("mesh"), mesh_bytes);
    assert_eq!(listing(&sub), ["M.mtx", "scene.toml"]);
}

#[test]
fn exported_matrices_replace_the_old_set_whole_or_not_at_all() {
    let dir = case_dir("export");
    let scene = scene_for(&dir, "cube.msh");
    let out = dir.join("matrices");
    // A folder that does not exist is refused (the README: a missing folder is refused).
    let (code, err) = compile(&[&scene, &"--export-matrices", &out]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("does not exist") && !out.exists(), "{err}");
    std::fs::create_dir(&out).expect("mkdir");
    for name in ["K.mtx", "M.mtx", "keep.txt"] {
        std::fs::write(out.join(name), "old").expect("old file");
    }
    // A folder named C.mtx in the way: refused before anything is written.
    std::fs::create_dir(out.join("C.mtx")).expect("mkdir");
    std::fs::write(out.join("C.mtx/x"), "x").expect("x");
    let (code, err) = compile(&[&scene, &"--export-matrices", &out]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("C.mtx"), "{err}");
    assert_eq!(listing(&out), ["C.mtx", "K.mtx", "M.mtx", "keep.txt"]);
    assert_eq!(
        std::fs::read_to_string(out.join("K.mtx")).expect("K"),
        "old"
    );
    std::fs::remove_dir_all(out.join("C.mtx")).expect("rm");
    let (code, err) = compile(&[&scene, &"--export-matrices", &out]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(
        listing(&out),
        ["B.mtx", "C.mtx", "H.mtx", "K.mtx", "M.mtx", "dofs.csv", "keep.txt"]
    );
    assert!(std::fs::read_to_string(out.join("K.mtx"))
        .expect("K")
        .starts_with("%%MatrixMarket"));
    assert_eq!(
        std::fs::read_to_string(out.join("keep.txt")).expect("keep"),
        "old"
    );
}

#[test]
fn stale_temporaries_of_a_dead_process_are_removed_and_named() {
    let dir = case_dir("stale");
    let scene = scene_for(&dir, "cube.msh");
    let out = dir.join("matrices");
    std::fs::create_dir(&out).expect("mkdir");
    // A process that has exited: its id names the leftovers.
    let mut child = Command::new("true").spawn().expect("spawn");
    let pid = child.id();
    child.wait().expect("wait");
    let file = dir.join(format!(".model.crokf.tmp-{pid}-0"));
    std::fs::write(&file, "half").expect("stale file");
    let folder = out.join(format!(".matrices.tmp-{pid}-3"));
    std::fs::create_dir(&folder).expect("stale folder");
    std::fs::write(folder.join("K.mtx"), "half").expect("stale");
    // Not a temporary of ours: left alone.
    let other = dir.join(".model.crokf.tmp-notapid-0");
    std::fs::write(&other, "x").expect("other");
    let (code, err) = compile(&[&scene, &"--export-matrices", &out]);
    assert_eq!(code, Some(0), "{err}");
    // Only the temporaries of this command's outputs are swept.
    assert!(!folder.exists() && file.exists() && other.exists(), "{err}");
    assert!(
        err.contains(&format!("removed {}", folder.display())) && err.contains(&pid.to_string()),
        "{err}"
    );
    let model = dir.join("model.crokf");
    let (code, err) = compile(&[&scene, &"-o", &model, &"--export-matrices", &out]);
    assert_eq!(code, Some(0), "{err}");
    assert!(!file.exists() && other.exists(), "{err}");
    assert!(
        err.contains(&format!("removed {}", file.display())) && err.contains("no longer running"),
        "{err}"
    );
}
