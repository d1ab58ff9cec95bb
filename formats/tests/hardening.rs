//! The shared output writer (`crokf_formats::output`): a folder output replaces its set of files
//! as one transaction (a failure at any file moves everything back), a new folder appears by one
//! rename, the temporaries of this process can all be removed at once (what the interrupt
//! handler does), and those of a process no longer running are swept and named.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use crokf_formats::output::{
    remove_temporaries, sweep_stale_temporaries, AtomicFile, Output, OutputKind, StagedDir,
};

/// `remove_temporaries` removes every temporary of the process: the tests take turns.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("crokf-output-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn is_step(name: &str) -> bool {
    name.starts_with("step_")
}

#[test]
fn a_failed_commit_into_an_existing_folder_moves_everything_back() {
    let _serial = serial();
    let root = scratch("rollback");
    let dir = root.join("out");
    std::fs::create_dir(&dir).unwrap();
    for (name, text) in [
        ("step_1", "old 1"),
        ("step_2", "old 2"),
        ("step_9", "old 9"),
    ] {
        std::fs::write(dir.join(name), text).unwrap();
    }
    std::fs::write(dir.join("keep.txt"), "mine").unwrap();
    // step_3 is a non-empty folder: moving the third file in fails.
    std::fs::create_dir(dir.join("step_3")).unwrap();
    std::fs::write(dir.join("step_3/x"), "x").unwrap();
    let before: Vec<(String, Option<String>)> = listing(&dir)
        .into_iter()
        .map(|n| {
            let text = std::fs::read_to_string(dir.join(&n)).ok();
            (n, text)
        })
        .collect();
    let mut staged = StagedDir::create_owning(&dir, is_step).unwrap();
    for k in 1..=4 {
        staged
            .write(&format!("step_{k}"), format!("new {k}").as_bytes())
            .unwrap();
    }
    let e = staged
        .commit()
        .expect_err("commit through a folder")
        .to_string();
    assert!(e.contains("step_3"), "{e}");
    let after: Vec<(String, Option<String>)> = listing(&dir)
        .into_iter()
        .map(|n| {
            let text = std::fs::read_to_string(dir.join(&n)).ok();
            (n, text)
        })
        .collect();
    assert_eq!(after, before, "the folder is exactly as it was");
    assert_eq!(listing(&root), ["out"]);
}

#[test]
fn a_commit_replaces_the_owned_set_whole_and_leaves_other_files() {
    let _serial = serial();
    let root = scratch("owned");
    let dir = root.join("out");
    std::fs::create_dir(&dir).unwrap();
    for name in ["step_1", "step_2", "step_3", "keep.txt"] {
        std::fs::write(dir.join(name), "old").unwrap();
    }
    let mut staged = StagedDir::create_owning(&dir, is_step).unwrap();
    staged.write("step_1", b"new").unwrap();
    assert!(staged.write(".hidden", b"x").is_err());
    assert!(staged.write("../escape", b"x").is_err());
    staged.commit().unwrap();
    assert_eq!(listing(&dir), ["keep.txt", "step_1"]);
    assert_eq!(std::fs::read_to_string(dir.join("step_1")).unwrap(), "new");
    // Without ownership only the rewritten names change.
    let mut staged = StagedDir::create(&dir).unwrap();
    staged.write("step_7", b"7").unwrap();
    staged.commit().unwrap();
    assert_eq!(listing(&dir), ["keep.txt", "step_1", "step_7"]);
}

#[test]
fn a_new_folder_appears_whole_by_one_rename() {
    let _serial = serial();
    let root = scratch("new");
    let dir = root.join("frames");
    let mut staged = StagedDir::create(&dir).unwrap();
    staged.write("a", b"1").unwrap();
    staged.write("b", b"2").unwrap();
    assert!(!dir.exists());
    staged.commit().unwrap();
    assert_eq!(listing(&dir), ["a", "b"]);
    assert_eq!(listing(&root), ["frames"]);
}

#[test]
fn remove_temporaries_removes_every_unfinished_output_of_this_process() {
    let _serial = serial();
    let root = scratch("interrupt");
    let dir = root.join("out");
    std::fs::create_dir(&dir).unwrap();
    let mut file = AtomicFile::create(&root.join("e.csv")).unwrap();
    file.write_all(b"half").unwrap();
    let mut staged = StagedDir::create(&dir).unwrap();
    staged.write("step_1", b"1").unwrap();
    assert_eq!(listing(&root).len(), 2, "{:?}", listing(&root));
    assert_eq!(listing(&dir).len(), 1);
    let (removed, held) = remove_temporaries();
    drop(held);
    assert!(removed >= 2, "{removed}");
    assert_eq!(listing(&root), ["out"]);
    assert!(listing(&dir).is_empty());
    drop(file);
    drop(staged);
    assert_eq!(listing(&root), ["out"]);
}

#[test]
fn stale_temporaries_of_a_dead_process_are_swept_and_named() {
    let _serial = serial();
    let root = scratch("sweep");
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let out = root.join("e.csv");
    let dir = root.join("vtu");
    std::fs::create_dir(&dir).unwrap();
    let stale_file = root.join(format!(".e.csv.tmp-{dead}-0"));
    std::fs::write(&stale_file, "half").unwrap();
    let stale_dir = dir.join(format!(".vtu.tmp-{dead}-4"));
    std::fs::create_dir(&stale_dir).unwrap();
    std::fs::write(stale_dir.join("step_1"), "half").unwrap();
    // An interrupted commit: kept, and named.
    let interrupted = dir.join(format!(".vtu.tmp-{dead}-5"));
    std::fs::create_dir_all(interrupted.join(".old")).unwrap();
    // Process 1 is running: its temporary stays, unnamed.
    let live = root.join(".e.csv.tmp-1-0");
    std::fs::write(&live, "busy").unwrap();
    let notes = sweep_stale_temporaries(&[
        Output {
            role: "--out",
            path: &out,
            kind: OutputKind::File,
        },
        Output {
            role: "--vtu",
            path: &dir,
            kind: OutputKind::ExistingFolder,
        },
    ]);
    assert!(!stale_file.exists() && !stale_dir.exists());
    assert!(interrupted.exists() && live.exists());
    assert_eq!(notes.len(), 3, "{notes:?}");
    let all = notes.join("\n");
    assert!(
        all.contains(&format!("removed {}", stale_file.display()))
            && all.contains(&format!("removed {}", stale_dir.display()))
            && all.contains(&format!("kept {}", interrupted.display())),
        "{all}"
    );
}
