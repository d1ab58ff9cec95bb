//! A haptic loop to copy (docs/contact.md): a 1 kHz device thread steps the model with the
//! tool's position and renders the force; a 60 Hz render thread draws the deformed surface.
//! They share no lock: the device thread publishes the state and the tool force through a
//! sequence lock made of atomics, and the render thread reads a consistent copy into its own
//! estimator (`set_state`) for the read-outs. A scripted press–slide–lift stands in for the
//! device.
//!
//! ```text
//! crokf-compile models/meniscus/scene_touch.toml -o /tmp/touch.crokf
//! cargo run --release -p crokf-runtime --example haptic_loop -- /tmp/touch.crokf [seconds]
//! ```
//!
//! It prints the device ticks, the ticks that started late by more than a tick (missed), the
//! start jitter, the step time and the frames drawn.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crokf_runtime::{load_model, Estimator};

/// A single-writer sequence lock over f64 values stored as atomic bits.
struct Shared {
    seq: AtomicU64,
    values: Vec<AtomicU64>,
}

impl Shared {
    fn new(n: usize) -> Self {
        Shared {
            seq: AtomicU64::new(0),
            values: (0..n).map(|_| AtomicU64::new(0)).collect(),
        }
    }

    /// The writer: odd sequence while writing, even when done.
    fn publish(&self, v: &[f64]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s + 1, Ordering::Relaxed);
        std::sync::atomic::fence(Ordering::Release);
        for (a, &x) in self.values.iter().zip(v) {
            a.store(x.to_bits(), Ordering::Relaxed);
        }
        self.seq.store(s + 2, Ordering::Release);
    }

    /// A reader: a copy taken while no write happened; false when none could be taken.
    fn read(&self, out: &mut [f64]) -> bool {
        for _ in 0..1000 {
            let before = self.seq.load(Ordering::Acquire);
            if before % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            for (o, a) in out.iter_mut().zip(&self.values) {
                *o = f64::from_bits(a.load(Ordering::Relaxed));
            }
            std::sync::atomic::fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == before {
                return before > 0;
            }
        }
        false
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let Some(path) = args.next() else {
        eprintln!("usage: haptic_loop MODEL.crokf [seconds]");
        std::process::exit(2);
    };
    let seconds: f64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(60.0);
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
    // The scripted device: around the region node nearest its centroid, along its normal.
    let n = region.len();
    let rest = &region.rest_positions.data;
    let centroid = [0, 1, 2].map(|c| (0..n).map(|i| rest[3 * i + c]).sum::<f64>() / n as f64);
    let d2 = |i: usize| {
        (0..3)
            .map(|c| (rest[3 * i + c] - centroid[c]).powi(2))
            .sum::<f64>()
    };
    let node = (0..n).min_by(|&a, &b| d2(a).total_cmp(&d2(b))).unwrap_or(0);
    let p = [0, 1, 2].map(|c| rest[3 * node + c]);
    let nrm = [0, 1, 2].map(|c| region.normals.data[3 * node + c]);
    let radius = region.tool_radius;
    let tangent = {
        let t0 = if nrm[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let d = (0..3).map(|c| t0[c] * nrm[c]).sum::<f64>();
        let t = [0, 1, 2].map(|c| t0[c] - d * nrm[c]);
        let l = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        t.map(|v| v / l)
    };
    let device = move |time: f64| -> [f64; 3] {
        // A 2 s cycle: press 0.25 R, slide 0.5 R and back, lift.
        let s = (time % 2.0) / 2.0;
        let depth = 0.25 * radius * (std::f64::consts::PI * s).sin().max(0.0);
        let slide = 0.5 * radius * (2.0 * std::f64::consts::PI * s).sin();
        [0, 1, 2].map(|c| p[c] + nrm[c] * (radius - depth) + tangent[c] * slide)
    };
    let r = model.state_dim as usize;
    let shared = Arc::new(Shared::new(r + 3));
    let done = Arc::new(AtomicBool::new(false));
    let set = model
        .node_sets
        .iter()
        .position(|s| s.name == "surface")
        .unwrap_or(0);
    let set_len = model.node_sets.get(set).map_or(0, |s| s.node_tags.len());
    let dt = model.dt;
    let mut est = Estimator::new(&model).expect("a loaded model builds an estimator");
    let mut view = est.clone();
    // The render thread: 60 Hz, its own estimator for the read-outs.
    let render = {
        let shared = Arc::clone(&shared);
        let done = Arc::clone(&done);
        std::thread::spawn(move || {
            let mut snapshot = vec![0.0; r + 3];
            let mut positions = vec![0.0; 3 * set_len];
            let (mut frames, mut largest) = (0u64, 0.0f64);
            let frame = Duration::from_secs_f64(1.0 / 60.0);
            let mut next = Instant::now();
            while !done.load(Ordering::Relaxed) {
                next += frame;
                if shared.read(&mut snapshot) && view.set_state(&snapshot[..r]).is_ok() {
                    if set_len > 0 && view.node_positions(set, &mut positions).is_ok() {
                        frames += 1;
                    }
                    let f = &snapshot[r..];
                    largest = largest.max((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt());
                }
                if let Some(wait) = next.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
            }
            (frames, largest)
        })
    };
    // The device thread (here: main): one step per tick, deadlines on an absolute clock.
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let ticks = (seconds / dt).round() as u64;
    let tick = Duration::from_secs_f64(dt);
    let mut lateness = Vec::with_capacity(ticks as usize);
    let mut step_ns = Vec::with_capacity(ticks as usize);
    let mut out = vec![0.0; r + 3];
    let mut missed = 0u64;
    let start = Instant::now();
    for k in 0..ticks {
        let deadline = start + tick * k as u32;
        // Sleep to 200 µs before the tick, then spin.
        if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
            if wait > Duration::from_micros(200) {
                std::thread::sleep(wait - Duration::from_micros(200));
            }
        }
        while Instant::now() < deadline {
            std::hint::spin_loop();
        }
        let began = Instant::now();
        let late = began.duration_since(deadline);
        if late > tick {
            missed += 1;
        }
        lateness.push(late.as_nanos() as u64);
        let tool = device(k as f64 * dt);
        if let Err(e) = est.step_with_tools(&[tool], &inputs, &none) {
            eprintln!("tick {k}: {e}");
            std::process::exit(1);
        }
        let force = est.tool_contact(0).map_or([0.0; 3], |t| t.force);
        // The device renders −force (the tool's push on the body's reaction); here: published.
        out[..r].copy_from_slice(est.state());
        out[r..].copy_from_slice(&force);
        shared.publish(&out);
        step_ns.push(began.elapsed().as_nanos() as u64);
    }
    done.store(true, Ordering::Relaxed);
    let (frames, largest) = render.join().expect("render thread");
    lateness.sort_unstable();
    step_ns.sort_unstable();
    let q = |v: &[u64], f: f64| v[((v.len() - 1) as f64 * f).round() as usize] as f64 / 1e3;
    println!(
        "{path}: {ticks} ticks of {:.3} ms over {:.1} s; missed (started > 1 tick late) {missed}",
        dt * 1e3,
        start.elapsed().as_secs_f64()
    );
    println!(
        "start jitter: median {:.1} µs, p99 {:.1} µs, p99.99 {:.1} µs, max {:.1} µs",
        q(&lateness, 0.5),
        q(&lateness, 0.99),
        q(&lateness, 0.9999),
        q(&lateness, 1.0)
    );
    println!(
        "tick work (contact step + publish): median {:.1} µs, p99.99 {:.1} µs, max {:.1} µs",
        q(&step_ns, 0.5),
        q(&step_ns, 0.9999),
        q(&step_ns, 1.0)
    );
    println!(
        "render: {frames} frames of {set_len} nodes at 60 Hz; largest published force {largest:.4} N"
    );
}
