//! Per-step cost of the filter with and without the random-walk force states
//! (docs/design.md §11): for each scene, the model at the scene's order with its force model
//! (`random_walk`, the default: r + 3 states) and the same scene with every load's `force_model
//! = "white"` (r states),
//! timed back to back in alternation, predict + update with every marker, median of batches.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example filter_step -- models/cantilever/scene.toml models/meniscus/scene.toml models/meniscus/scene_30hz.toml
//! ```

use std::hint::black_box;
use std::path::{Path, PathBuf};

use crokf_compile::{compile, CompileOptions};
use crokf_runtime::Estimator;
use crokf_verify::bench::median_seconds;

/// Median seconds per `est.step` over batches of `batch` steps with all markers at zero.
fn step_time(model: &crokf_formats::Model, batch: usize, samples: usize) -> f64 {
    let mut est = match Estimator::new(model) {
        Ok(e) => e,
        Err(e) => panic!("model refused: {e}"),
    };
    est.set_innovation_gate(None);
    let u = vec![0.0; model.inputs.len()];
    let y = vec![Some(0.0); model.measurements.len()];
    median_seconds(samples, || {
        for _ in 0..batch {
            let _ = black_box(est.step(black_box(&u), black_box(&y)));
        }
    }) / batch as f64
}

/// The scene with every load told (`force_model = "white"`; the estimated loads' `rise_time`
/// and `force_rate_noise_std` dropped, which a white load refuses), next to it.
fn white_copy(scene: &Path) -> Result<PathBuf, Box<dyn std::error::Error>> {
    let mut table: toml::Table = std::fs::read_to_string(scene)?.parse()?;
    if let Some(toml::Value::Array(loads)) = table.get_mut("load") {
        for load in loads.iter_mut().filter_map(toml::Value::as_table_mut) {
            load.insert("force_model".into(), "white".into());
            load.remove("rise_time");
            load.remove("force_rate_noise_std");
        }
    }
    let white = toml::to_string(&table)?;
    let dir = scene.parent().ok_or("scene without a folder")?;
    let path = dir.join(format!(".filter_step_white_{}.toml", std::process::id()));
    std::fs::write(&path, white)?;
    Ok(path)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!(
        "| scene | Δt | states (white / random walk) | step white | step random walk | ratio |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for scene in std::env::args().skip(1).map(PathBuf::from) {
        let options = CompileOptions {
            skip_measured_error: true,
            ..CompileOptions::default()
        };
        let walk = compile(&scene, &options)?.model;
        let white_path = white_copy(&scene)?;
        let white = compile(
            &white_path,
            &CompileOptions {
                order: Some(walk.report.order as usize),
                ..options
            },
        );
        std::fs::remove_file(&white_path).ok();
        let white = white?.model;
        let (mut tw, mut tr) = (Vec::new(), Vec::new());
        for _ in 0..5 {
            tw.push(step_time(&white, 200, 101));
            tr.push(step_time(&walk, 200, 101));
        }
        tw.sort_by(f64::total_cmp);
        tr.sort_by(f64::total_cmp);
        let (w, r) = (tw[2], tr[2]);
        println!(
            "| {} | {} s | {} / {} | {:.0} ns | {:.0} ns | {:.2} |",
            scene.display(),
            walk.dt,
            white.r(),
            walk.r(),
            w * 1e9,
            r * 1e9,
            r / w
        );
    }
    Ok(())
}
