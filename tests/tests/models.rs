//! The committed example models stay in step with their scenes, meshes and this compiler, and
//! load and run in the runtime. To refresh one after a change:
//! `cargo run --release --bin crokf-compile -- models/NAME/scene.toml -o models/NAME/model.crokf --report models/NAME/report.json`

use std::path::{Path, PathBuf};

use crokf_compile::check::{check, CheckOutcome};
use crokf_runtime::{load_model, Estimator};

fn models() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("model.crokf").exists())
        .collect();
    dirs.sort();
    dirs
}

#[test]
fn every_committed_model_is_up_to_date() {
    let dirs = models();
    assert!(
        dirs.len() >= 2,
        "expected the cantilever and meniscus models, found {dirs:?}"
    );
    for dir in dirs {
        let outcome = check(&dir.join("model.crokf"), &dir.join("scene.toml")).unwrap();
        assert_eq!(
            outcome,
            CheckOutcome::UpToDate,
            "{}: rebuild it (see this file's header)",
            dir.display()
        );
    }
}

#[test]
fn every_committed_model_loads_and_steps() {
    for dir in models() {
        let model = load_model(dir.join("model.crokf")).unwrap();
        let mut est = Estimator::new(&model).unwrap();
        let u = vec![0.1; model.inputs.len()];
        let y = vec![None; model.measurements.len()];
        for _ in 0..100 {
            est.step(&u, &y).unwrap();
        }
        let mut out = vec![0.0; 3 * model.sensors.len()];
        est.sensor_displacements(&mut out).unwrap();
        assert!(out.iter().all(|v| v.is_finite()) && out.iter().any(|v| *v != 0.0));
    }
}
