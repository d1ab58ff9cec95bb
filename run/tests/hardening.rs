//! `crokf-run --vtu`: the folder must exist (the README: a missing folder is refused), a series
//! replaces an older one whole or not at all, SIGINT and SIGTERM remove the temporaries, and the
//! temporaries of a run killed by SIGKILL are removed (and named) by the next run.

#[path = "../../runtime/tests/common/mod.rs"]
mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

struct Case {
    dir: PathBuf,
    model: PathBuf,
}

impl Case {
    fn new(name: &str) -> Case {
        let dir = scratch_dir(name);
        let model = dir.join("model.crokf");
        std::fs::write(
            &model,
            crokf_formats::encode(&synthetic_model(&Spec::default())),
        )
        .unwrap();
        Case { dir, model }
    }

    /// An inputs file of `rows` steps; the load grows with the number of rows, so that runs
    /// of different lengths write different files.
    fn inputs(&self, name: &str, rows: usize) -> PathBuf {
        let path = self.dir.join(name);
        let mut csv = String::from("step,push.x,push.y,push.z,gravity\n");
        let f = 0.1 * (1 + rows % 7) as f64;
        for k in 1..=rows {
            csv += &format!("{k},{f},0.2,0.3,1\n");
        }
        std::fs::write(&path, csv).unwrap();
        path
    }

    fn command(&self, inputs: &Path, out: &Path, vtu: &Path) -> Command {
        let mut c = Command::new(env!("CARGO_BIN_EXE_crokf-run"));
        c.arg(&self.model)
            .arg("--inputs")
            .arg(inputs)
            .arg("--out")
            .arg(out)
            .arg("--vtu")
            .arg(vtu);
        c
    }

    fn run(&self, inputs: &Path, out: &Path, vtu: &Path) -> Output {
        self.command(inputs, out, vtu).output().unwrap()
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn series(steps: usize) -> Vec<String> {
    let mut v: Vec<String> = (1..=steps).map(|k| format!("step_{k:06}.vtu")).collect();
    v.push("estimates.pvd".into());
    v.sort();
    v
}

#[test]
fn a_missing_vtu_folder_is_refused() {
    let c = Case::new("vtu-missing");
    let inputs = c.inputs("inputs.csv", 3);
    let vtu = c.dir.join("new");
    let o = c.run(&inputs, &c.dir.join("e.csv"), &vtu);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).starts_with("crokf-run: error: ")
            && stderr(&o).contains("--vtu")
            && stderr(&o).contains("does not exist"),
        "{}",
        stderr(&o)
    );
    assert!(!vtu.exists() && !c.dir.join("e.csv").exists());
}

#[test]
fn a_series_replaces_an_older_longer_one_whole() {
    let c = Case::new("vtu-replace");
    let vtu = c.dir.join("vtu");
    std::fs::create_dir(&vtu).unwrap();
    std::fs::write(vtu.join("notes.txt"), "mine").unwrap();
    let out = c.dir.join("e.csv");
    let o = c.run(&c.inputs("nine.csv", 9), &out, &vtu);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut want = series(9);
    want.push("notes.txt".into());
    want.sort();
    assert_eq!(listing(&vtu), want);
    // A shorter run: steps 5..9 of the old series go, the user's file stays.
    let o = c.run(&c.inputs("four.csv", 4), &out, &vtu);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut want = series(4);
    want.push("notes.txt".into());
    want.sort();
    assert_eq!(listing(&vtu), want);
    assert_eq!(
        std::fs::read_to_string(vtu.join("notes.txt")).unwrap(),
        "mine"
    );
    let pvd = std::fs::read_to_string(vtu.join("estimates.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 4, "{pvd}");
}

#[test]
fn a_commit_that_fails_midway_leaves_the_old_series() {
    let c = Case::new("vtu-midway");
    let vtu = c.dir.join("vtu");
    std::fs::create_dir(&vtu).unwrap();
    let out = c.dir.join("e.csv");
    let o = c.run(&c.inputs("two.csv", 2), &out, &vtu);
    assert!(o.status.success(), "{}", stderr(&o));
    let old: Vec<(String, Vec<u8>)> = listing(&vtu)
        .into_iter()
        .map(|n| (n.clone(), std::fs::read(vtu.join(&n)).unwrap()))
        .collect();
    let old_out = std::fs::read(&out).unwrap();
    // A folder where the third step's file goes: the commit fails after two files.
    std::fs::create_dir(vtu.join("step_000003.vtu")).unwrap();
    std::fs::write(vtu.join("step_000003.vtu/x"), "x").unwrap();
    let o = c.run(&c.inputs("five.csv", 5), &out, &vtu);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("step_000003.vtu"), "{}", stderr(&o));
    for (name, bytes) in &old {
        assert_eq!(&std::fs::read(vtu.join(name)).unwrap(), bytes, "{name}");
    }
    let mut want: Vec<String> = old.iter().map(|(n, _)| n.clone()).collect();
    want.push("step_000003.vtu".into());
    want.sort();
    assert_eq!(listing(&vtu), want, "old series only, no temporary");
    assert_eq!(std::fs::read(&out).unwrap(), old_out);
    assert!(listing(&c.dir).iter().all(|n| !n.starts_with('.')));
}

/// Starts a long `--vtu` run and waits until its staging folder inside `vtu` holds files; the
/// caller signals and waits for the child.
#[allow(clippy::zombie_processes)]
fn start_long_run(c: &Case, vtu: &Path, out: &Path) -> Child {
    let inputs = c.inputs("long.csv", 400_000);
    let mut child = c
        .command(&inputs, out, vtu)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        // The staging folder (inside the existing folder; next to it, where older versions
        // put it).
        let staged = [vtu, &c.dir]
            .iter()
            .flat_map(|d| listing(d).into_iter().map(move |n| d.join(n)))
            .find(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with(".vtu.tmp-"))
            })
            .map(|p| listing(&p).len())
            .unwrap_or(0);
        if staged >= 20 {
            return child;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("no staging folder in {}", vtu.display());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn signal(child: &Child, name: &str) {
    let status = Command::new("kill")
        .arg(format!("-{name}"))
        .arg(child.id().to_string())
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn sigint_and_sigterm_remove_the_temporaries() {
    for (name, code) in [("INT", 130), ("TERM", 143)] {
        let c = Case::new(&format!("vtu-sig{name}"));
        let vtu = c.dir.join("vtu");
        std::fs::create_dir(&vtu).unwrap();
        std::fs::write(vtu.join("notes.txt"), "mine").unwrap();
        let out = c.dir.join("e.csv");
        let child = start_long_run(&c, &vtu, &out);
        signal(&child, name);
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(code), "SIG{name}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("interrupted (SIG{name})")),
            "{}",
            stderr(&o)
        );
        assert_eq!(listing(&vtu), ["notes.txt"], "SIG{name}");
        assert_eq!(
            listing(&c.dir),
            ["long.csv", "model.crokf", "vtu"],
            "SIG{name}"
        );
    }
}

#[test]
fn temporaries_of_a_killed_run_are_removed_by_the_next() {
    let c = Case::new("vtu-killed");
    let vtu = c.dir.join("vtu");
    std::fs::create_dir(&vtu).unwrap();
    let out = c.dir.join("e.csv");
    let child = start_long_run(&c, &vtu, &out);
    let pid = child.id();
    signal(&child, "KILL");
    child.wait_with_output().unwrap();
    // SIGKILL cannot be caught: the staging folder and the CSV's temporary stay.
    let staging = format!(".vtu.tmp-{pid}-");
    let csv_tmp = format!(".e.csv.tmp-{pid}-");
    assert!(listing(&vtu).iter().any(|n| n.starts_with(&staging)));
    assert!(listing(&c.dir).iter().any(|n| n.starts_with(&csv_tmp)));
    let o = c.run(&c.inputs("three.csv", 3), &out, &vtu);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains(&staging) && e.contains(&csv_tmp) && e.contains("no longer running"),
        "{e}"
    );
    assert_eq!(listing(&vtu), series(3));
    assert_eq!(
        listing(&c.dir),
        ["e.csv", "long.csv", "model.crokf", "three.csv", "vtu"]
    );
}
