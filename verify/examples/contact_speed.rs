//! The contact step against the full-order contact step, timed in the same run (not a test;
//! figures for docs/contact.md): a scene with a `[[contact]]` region, a 2000-step path that
//! presses the tool 0.25 R into the region node nearest the region's centroid along its normal,
//! slides it 0.5 R and lifts it, stepped by the reduced model (`Estimator::step_with_tools`)
//! and by the full-order FEM with the same tool and contact law (`ContactReference::step`,
//! Wilson-θ on the full mesh), each step timed; the medians, their ratio, and the largest
//! difference of the tool forces along the path.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example contact_speed -- models/meniscus/scene_touch.toml
//! ```

use std::path::Path;
use std::time::Instant;

use crokf_compile::compile::{compile, CompileOptions};
use crokf_compile::full_order::FullOrder;
use crokf_compile::timer::StageTimer;
use crokf_runtime::Estimator;
use crokf_verify::contact::ContactReference;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run(scene: &Path) -> Result<(), String> {
    let model = compile(scene, &CompileOptions::default())
        .map_err(|e| e.to_string())?
        .model;
    let region = model
        .contact
        .as_ref()
        .ok_or("the scene declares no [[contact]] region")?;
    let n = region.len();
    let rest = &region.rest_positions.data;
    let centroid = [0, 1, 2].map(|c| (0..n).map(|i| rest[3 * i + c]).sum::<f64>() / n as f64);
    let node = (0..n)
        .min_by(|&a, &b| {
            let d = |i: usize| {
                (0..3)
                    .map(|c| (rest[3 * i + c] - centroid[c]).powi(2))
                    .sum::<f64>()
            };
            d(a).total_cmp(&d(b))
        })
        .ok_or("empty region")?;
    let p = [0, 1, 2].map(|c| rest[3 * node + c]);
    let nrm = [0, 1, 2].map(|c| region.normals.data[3 * node + c]);
    let radius = region.tool_radius;
    let t0 = if nrm[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let along: f64 = (0..3).map(|c| t0[c] * nrm[c]).sum();
    let t = [0, 1, 2].map(|c| t0[c] - along * nrm[c]);
    let tl = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    let path: Vec<[f64; 3]> = (0..2000)
        .map(|k| {
            let depth = 0.25 * radius;
            let (d, s) = match k {
                0..400 => (depth * k as f64 / 400.0, 0.0),
                400..1400 => (depth, 0.5 * radius * (k - 400) as f64 / 1000.0),
                _ => (depth * (2000 - k) as f64 / 600.0, 0.5 * radius),
            };
            [0, 1, 2].map(|c| p[c] + nrm[c] * (radius - d) + t[c] / tl * s)
        })
        .collect();
    let full = FullOrder::build(scene, &mut StageTimer::default()).map_err(|e| e.to_string())?;
    let mut reference = ContactReference::new(&full)?;
    let f = vec![0.0; full.fem.dof_count()];
    let mut est = Estimator::new(&model).map_err(|e| e.to_string())?;
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    // Each model over the whole path in its own loop (interleaved, each would evict the
    // other's data from the caches).
    let (mut reduced, mut fem) = (Vec::new(), Vec::new());
    let mut got = Vec::new();
    for c in &path {
        let start = Instant::now();
        est.step_with_tools(&[*c], &inputs, &none)
            .map_err(|e| e.to_string())?;
        reduced.push(start.elapsed().as_secs_f64());
        got.push(est.tool_contact(0).ok_or("no tool result")?.force);
    }
    let (mut worst, mut peak) = (0.0f64, 0.0f64);
    for (c, got) in path.iter().zip(&got) {
        let start = Instant::now();
        let want = reference.step(*c, &f).map_err(|e| e.to_string())?;
        fem.push(start.elapsed().as_secs_f64());
        let diff = (0..3)
            .map(|k| (got[k] - want.force[k]).powi(2))
            .sum::<f64>();
        worst = worst.max(diff.sqrt());
        peak = peak.max(want.force.iter().map(|v| v * v).sum::<f64>().sqrt());
    }
    let (r, fo) = (median(&mut reduced), median(&mut fem));
    println!(
        "{}: {} DOFs, r = {}, {n} region nodes; {} steps along press-slide-lift",
        scene.display(),
        full.fem.dof_count(),
        model.state_dim,
        path.len()
    );
    println!(
        "reduced contact step median {:.2} µs, full-order contact step median {:.1} µs: {:.0}× faster",
        r * 1e6,
        fo * 1e6,
        fo / r
    );
    println!(
        "tool force, reduced against full order over the path: largest difference {:.2e} of the peak {peak:.4} N",
        worst / peak.max(1e-300)
    );
    Ok(())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.is_empty() {
        eprintln!("usage: contact_speed SCENE.toml [SCENE.toml ...]");
        std::process::exit(2);
    }
    for a in &args {
        if let Err(e) = run(Path::new(a)) {
            eprintln!("{a}: {e}");
            std::process::exit(1);
        }
    }
}
