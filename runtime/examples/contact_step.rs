//! The contact step's cost (not a test; figures for docs/contact.md): a tool path that presses,
//! slides and lifts, repeated over 10⁶ steps, timed step by step beside the plain step of the
//! same model in the same run.
//!
//! ```text
//! crokf-compile models/meniscus/scene_touch.toml -o /tmp/touch.crokf
//! cargo run --release -p crokf-runtime --example contact_step -- /tmp/touch.crokf [steps]
//! ```

use std::time::Instant;

use crokf_runtime::{load_model, Estimator};

fn main() {
    let mut args = std::env::args().skip(1);
    let Some(path) = args.next() else {
        eprintln!("usage: contact_step MODEL.crokf [steps]");
        std::process::exit(2);
    };
    let steps: usize = match args.next().map(|s| s.parse()) {
        None => 1_000_000,
        Some(Ok(n)) if n > 0 => n,
        Some(_) => {
            eprintln!("steps must be a positive whole number");
            std::process::exit(2);
        }
    };
    let model = match load_model(&path) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("{path}: {e}");
            std::process::exit(1);
        }
    };
    let Some(region) = model.contact.as_ref() else {
        eprintln!("{path}: the model has no contact region");
        std::process::exit(1);
    };
    // The region node nearest the region's centroid, and its outward normal.
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
        .unwrap_or(0);
    let p = [0, 1, 2].map(|c| rest[3 * node + c]);
    let nrm = [0, 1, 2].map(|c| region.normals.data[3 * node + c]);
    let radius = region.tool_radius;
    // A tangent to slide along.
    let t0 = if nrm[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let dot = t0[0] * nrm[0] + t0[1] * nrm[1] + t0[2] * nrm[2];
    let t = [0, 1, 2].map(|c| t0[c] - dot * nrm[c]);
    let tl = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    let t = t.map(|v| v / tl);
    // One cycle of 1000 steps: press to 0.25 R over 200, slide 0.5 R over 500, lift over 200,
    // 100 free.
    let cycle: Vec<[f64; 3]> = (0..1000)
        .map(|k| {
            let depth = 0.25 * radius;
            let (d, s) = match k {
                0..200 => (depth * k as f64 / 200.0, 0.0),
                200..700 => (depth, 0.5 * radius * (k - 200) as f64 / 500.0),
                700..900 => (depth * (900 - k) as f64 / 200.0, 0.5 * radius),
                _ => (-0.1 * radius, 0.5 * radius * (1000 - k) as f64 / 100.0),
            };
            [0, 1, 2].map(|c| p[c] + nrm[c] * (radius - d) + t[c] * s)
        })
        .collect();
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let mut est = Estimator::new(&model).expect("a loaded model builds an estimator");
    let mut times = vec![0u32; steps];
    let mut most = 0;
    for (k, time) in times.iter_mut().enumerate() {
        let c = cycle[k % cycle.len()];
        let start = Instant::now();
        let r = est.step_with_tools(&[c], &inputs, &none);
        *time = start.elapsed().as_nanos().min(u32::MAX as u128) as u32;
        if let Err(e) = r {
            eprintln!("step {k}: {e}");
            std::process::exit(1);
        }
        most = most.max(est.tool_contact(0).map_or(0, |t| t.active));
    }
    let mut plain_est = Estimator::new(&model).expect("estimator");
    let mut plain = vec![0u32; steps.min(200_000)];
    for time in plain.iter_mut() {
        let start = Instant::now();
        let r = plain_est.step(&inputs, &none);
        *time = start.elapsed().as_nanos().min(u32::MAX as u128) as u32;
        if let Err(e) = r {
            eprintln!("plain step: {e}");
            std::process::exit(1);
        }
    }
    times.sort_unstable();
    plain.sort_unstable();
    let q = |v: &[u32], f: f64| v[((v.len() - 1) as f64 * f).round() as usize] as f64 / 1e3;
    println!(
        "{path}: r = {}, {n} region nodes, up to {most} pressing; {steps} contact steps",
        model.state_dim
    );
    println!(
        "contact step: median {:.2} µs, p99 {:.2} µs, p99.99 {:.2} µs, max {:.2} µs",
        q(&times, 0.5),
        q(&times, 0.99),
        q(&times, 0.9999),
        q(&times, 1.0)
    );
    println!(
        "plain step: median {:.2} µs; contact / plain median {:.1}×",
        q(&plain, 0.5),
        q(&times, 0.5) / q(&plain, 0.5)
    );
}
