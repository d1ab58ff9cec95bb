//! The simulation thread: steps the estimator in real time and publishes frames.
//!
//! Real time: with t₀ the wall-clock instant stepping (re)started and k₀ steps done since,
//! the thread performs every step k with t₀ + k Δt ≤ now (docs/design.md §5 for one step), so
//! the simulated time follows the wall clock at 1/Δt steps per second. When it falls more than
//! [`MAX_CATCH_UP`] steps behind (a stalled machine), it drops the backlog and counts the
//! dropped steps instead of running faster than real time afterwards. Read-outs for the page
//! happen on a second thread from a copy of the state, so they never delay a step.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use base64::Engine;
use crokf_formats::{InputKind, Model};
use crokf_runtime::{Estimator, ToolContact};

use crate::ServeOptions;

/// Largest backlog of steps run at once before the rest is dropped, steps.
const MAX_CATCH_UP: u64 = 250;

/// Figures of the running viewer (all measured, none configured).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Stats {
    /// Steps since the start or the last reset.
    pub steps: u64,
    /// Simulated time, s.
    pub sim_time: f64,
    /// Steps per wall-clock second over the last window (≈ 1 s), Hz.
    pub step_rate_hz: f64,
    /// Median wall-clock time of one estimator step (predict + update) over the last 1,000
    /// steps, µs.
    pub step_time_median_us: f64,
    /// Median time to read out one frame (node positions, σ, markers), µs.
    pub readout_time_median_us: f64,
    /// Frames published per wall-clock second over the last window, Hz.
    pub frame_rate_hz: f64,
    /// Frames published in total.
    pub frames: u64,
    /// Steps dropped because the stepping thread fell more than 250 steps behind real time
    /// (the machine stalled it for longer than that).
    pub dropped_steps: u64,
    /// Whether stepping is running.
    pub playing: bool,
}

/// What the page controls.
#[derive(Clone, Debug)]
pub(crate) struct Controls {
    /// World-frame force per load group, N.
    pub forces: Vec<[f64; 3]>,
    /// Gravity scale (1 = the scene's gravity).
    pub gravity: f64,
    pub playing: bool,
    pub reset: bool,
    /// Centre of the spherical tool, m (model frame); `None`: no tool (plain steps). Only set
    /// on a model with a contact region.
    pub tool: Option<[f64; 3]>,
}

struct SharedState {
    frame: Arc<String>,
    generation: u64,
    controls: Controls,
    stats: Stats,
}

/// State shared by the simulation thread and the HTTP handlers.
pub(crate) struct Shared {
    load_names: Vec<String>,
    /// Per load group and world component: the plausibility bound of its input channel (N;
    /// ∞ when the model has no channel for that component).
    force_bounds: Vec<[f64; 3]>,
    /// The plausibility bound of the gravity scale, `None` without a gravity input.
    gravity_bound: Option<f64>,
    /// Whether the model has a contact region (a tool may be set).
    has_contact: bool,
    state: Mutex<SharedState>,
    new_frame: Condvar,
}

impl Shared {
    /// `input_bounds`: per input channel of `model`, the runtime's plausibility bound
    /// (`PreparedModel::input_bounds`).
    pub fn new(model: &Model, playing: bool, input_bounds: &[f64]) -> Self {
        let mut force_bounds = vec![[f64::INFINITY; 3]; model.loads.len()];
        let mut gravity_bound: Option<f64> = None;
        for (ch, &bound) in model.inputs.iter().zip(input_bounds) {
            match ch.kind {
                InputKind::Load { load, component } => {
                    if let Some(b) = force_bounds.get_mut(load as usize) {
                        b[(component as usize).min(2)] = bound;
                    }
                }
                InputKind::Gravity { .. } => {
                    gravity_bound = Some(gravity_bound.map_or(bound, |g| g.min(bound)));
                }
            }
        }
        let gravity = if gravity_bound.is_some() { 1.0 } else { 0.0 };
        Self {
            load_names: model.loads.iter().map(|l| l.name.clone()).collect(),
            force_bounds,
            gravity_bound,
            has_contact: model.contact.is_some(),
            state: Mutex::new(SharedState {
                frame: Arc::new(String::new()),
                generation: 0,
                controls: Controls {
                    forces: vec![[0.0; 3]; model.loads.len()],
                    gravity,
                    playing,
                    reset: false,
                    tool: None,
                },
                stats: Stats::default(),
            }),
            new_frame: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, SharedState> {
        // A poisoned lock only means another thread panicked mid-update of plain data.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Load group names, in model order.
    pub fn load_names(&self) -> &[String] {
        &self.load_names
    }

    /// Per load group, the plausibility bound of each world force component, N.
    pub fn force_bounds(&self) -> &[[f64; 3]] {
        &self.force_bounds
    }

    /// The plausibility bound of the gravity scale, `None` when the model has no gravity input.
    pub fn gravity_bound(&self) -> Option<f64> {
        self.gravity_bound
    }

    /// Whether the model has a contact region, so that the page may set a tool.
    pub fn has_contact(&self) -> bool {
        self.has_contact
    }

    pub fn stats(&self) -> Stats {
        self.lock().stats.clone()
    }

    /// Applies `f` to the controls.
    pub fn with_controls<R>(&self, f: impl FnOnce(&mut Controls) -> R) -> R {
        f(&mut self.lock().controls)
    }

    /// Waits (at most `timeout`) for a frame newer than `seen`; returns it and its generation.
    pub fn next_frame(&self, seen: u64, timeout: Duration) -> Option<(u64, Arc<String>)> {
        let guard = self.lock();
        let (guard, _) = self
            .new_frame
            .wait_timeout_while(guard, timeout, |s| s.generation == seen)
            .unwrap_or_else(|p| p.into_inner());
        (guard.generation != seen).then(|| (guard.generation, guard.frame.clone()))
    }

    pub fn wake_all(&self) {
        self.new_frame.notify_all();
    }

    fn publish(&self, frame: String, stats: Stats) {
        let mut s = self.lock();
        s.frame = Arc::new(frame);
        s.generation += 1;
        s.stats = stats;
        drop(s);
        self.new_frame.notify_all();
    }
}

/// Ring of recent durations, for medians.
struct Recent {
    values: Vec<f64>,
    next: usize,
    cap: usize,
}

impl Recent {
    fn new(cap: usize) -> Self {
        Self {
            values: Vec::with_capacity(cap),
            next: 0,
            cap,
        }
    }
    fn push(&mut self, v: f64) {
        if self.values.len() < self.cap {
            self.values.push(v);
        } else {
            self.values[self.next] = v;
        }
        self.next = (self.next + 1) % self.cap;
    }
    fn median(&self) -> f64 {
        if self.values.is_empty() {
            return 0.0;
        }
        let mut v = self.values.clone();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    }
}

/// The latest stepped state, handed from the stepping thread to the frame thread.
#[derive(Clone, Default)]
struct Snapshot {
    generation: u64,
    x: Vec<f64>,
    step: u64,
    time: f64,
    stats: Stats,
    forces: Vec<[f64; 3]>,
    gravity: f64,
    /// The tool as set by the page, with the result of the last contact step since it was set
    /// (`None` before the first one).
    tool: Option<([f64; 3], Option<ToolContact>)>,
    error: Option<String>,
}

/// Stepping thread → frame thread hand-over (the stepping thread never waits on a read-out).
#[derive(Default)]
pub(crate) struct Handover {
    latest: Mutex<Snapshot>,
    fresh: Condvar,
}

impl Handover {
    fn lock(&self) -> MutexGuard<'_, Snapshot> {
        self.latest.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn wake_all(&self) {
        self.fresh.notify_all();
    }
}

/// The stepping thread: the estimator and the input buffers.
pub(crate) struct Simulation {
    est: Estimator,
    frame_interval: Duration,
    inputs: Vec<f64>,
    no_measurements: Vec<Option<f64>>,
    /// The result of the last contact step since the tool was set (cleared when the page takes
    /// the tool away and on a reset).
    tool_result: Option<ToolContact>,
}

impl Simulation {
    pub fn new(est: Estimator, frame_interval: Duration) -> Self {
        let model = est.model();
        let m = model.inputs.len();
        let q = model.measurements.len();
        Self {
            est,
            frame_interval,
            inputs: vec![0.0; m],
            no_measurements: vec![None; q],
            tool_result: None,
        }
    }

    /// Input vector from the controls: load channel (g, c) gets forces[g][c] (N), gravity
    /// channels the gravity scale.
    fn set_inputs(&mut self, controls: &Controls) {
        for (u, ch) in self.inputs.iter_mut().zip(&self.est.model().inputs) {
            *u = match ch.kind {
                InputKind::Load { load, component } => controls
                    .forces
                    .get(load as usize)
                    .map_or(0.0, |f| f[(component as usize).min(2)]),
                InputKind::Gravity { .. } => controls.gravity,
            };
        }
    }

    /// Steps in real time until `stop` is set; hands the state to the frame thread at the
    /// frame rate.
    pub fn run(mut self, shared: &Shared, handover: &Handover, stop: &AtomicBool) {
        let dt = Duration::from_secs_f64(self.est.model().dt);
        let mut origin = Instant::now();
        let mut done_since_origin: u64 = 0;
        let mut was_playing = false;
        let mut next_frame = Instant::now();
        let mut step_times = Recent::new(1000);
        let mut stats = Stats::default();
        let mut window_start = Instant::now();
        let mut window_steps = 0u64;
        let mut error: Option<String> = None;
        let mut generation = 0;
        while !stop.load(Ordering::SeqCst) {
            let controls = shared.with_controls(|c| {
                let snapshot = c.clone();
                c.reset = false;
                snapshot
            });
            if controls.reset {
                self.est.reset();
                self.tool_result = None;
                error = None;
                origin = Instant::now();
                done_since_origin = 0;
            }
            self.set_inputs(&controls);
            if controls.tool.is_none() {
                self.tool_result = None;
            }
            let now = Instant::now();
            if controls.playing && !was_playing {
                origin = now;
                done_since_origin = 0;
            }
            was_playing = controls.playing;
            if controls.playing && error.is_none() {
                let due = (now.duration_since(origin).as_secs_f64() / dt.as_secs_f64()) as u64;
                let mut behind = due.saturating_sub(done_since_origin);
                if behind > MAX_CATCH_UP {
                    stats.dropped_steps += behind - MAX_CATCH_UP;
                    done_since_origin += behind - MAX_CATCH_UP;
                    behind = MAX_CATCH_UP;
                }
                let mut succeeded = 0;
                for _ in 0..behind {
                    let t0 = Instant::now();
                    let stepped = match controls.tool {
                        None => self
                            .est
                            .step(&self.inputs, &self.no_measurements)
                            .map_err(|e| e.to_string()),
                        Some(c) => self
                            .est
                            .step_with_tools(&[c], &self.inputs, &self.no_measurements)
                            .map_err(|e| {
                                format!(
                                    "contact step with the tool at [{}, {}, {}] m: {e}",
                                    c[0], c[1], c[2]
                                )
                            }),
                    };
                    if let Err(e) = stepped {
                        // A plain step fails only on a singular warp (|ω̄| near 2π), a contact
                        // step also on a non-finite contact solve: stop stepping and show the
                        // runtime's message until the page resets (the estimator is left as
                        // it was before the failed step).
                        error = Some(e);
                        break;
                    }
                    step_times.push(t0.elapsed().as_secs_f64() * 1e6);
                    done_since_origin += 1;
                    window_steps += 1;
                    succeeded += 1;
                }
                // The frame shows the last successful contact step's result.
                if controls.tool.is_some() && succeeded > 0 {
                    self.tool_result = self.est.tool_contact(0).copied();
                }
            }
            let now = Instant::now();
            if now >= next_frame {
                let window = now.duration_since(window_start).as_secs_f64();
                if window >= 1.0 {
                    stats.step_rate_hz = window_steps as f64 / window;
                    window_start = now;
                    window_steps = 0;
                }
                stats.steps = self.est.step_index();
                stats.sim_time = self.est.time();
                stats.step_time_median_us = step_times.median();
                stats.playing = controls.playing;
                generation += 1;
                {
                    let mut h = handover.lock();
                    h.generation = generation;
                    h.x.clear();
                    h.x.extend_from_slice(self.est.state());
                    h.step = self.est.step_index();
                    h.time = self.est.time();
                    h.stats.clone_from(&stats);
                    h.forces.clone_from(&controls.forces);
                    h.gravity = controls.gravity;
                    h.tool = controls.tool.map(|c| (c, self.tool_result));
                    h.error.clone_from(&error);
                }
                handover.fresh.notify_all();
                next_frame += self.frame_interval;
                if next_frame < now {
                    next_frame = now + self.frame_interval;
                }
            }
            // Sleep until the next step or frame is due (at most 5 ms).
            let next_step = if controls.playing {
                origin + dt.mul_f64((done_since_origin + 1) as f64)
            } else {
                next_frame
            };
            let wake = next_step.min(next_frame);
            let now = Instant::now();
            if wake > now {
                std::thread::sleep((wake - now).min(Duration::from_millis(5)));
            }
        }
    }
}

/// The frame thread: a copy of the estimator whose state is set from each snapshot, the node
/// set drawn and the read-out buffers.
pub(crate) struct Framer {
    view: Estimator,
    set: usize,
    positions: Vec<f64>,
    std: Vec<f64>,
    markers: Vec<f64>,
    bytes: Vec<u8>,
}

impl Framer {
    pub fn new(view: Estimator, set: usize) -> Self {
        let model = view.model();
        let n = model.node_sets[set].node_tags.len();
        let s = model.sensors.len();
        Self {
            view,
            set,
            positions: vec![0.0; 3 * n],
            std: vec![0.0; 3 * n],
            markers: vec![0.0; 3 * s],
            bytes: Vec::with_capacity(12 * n),
        }
    }

    /// Turns each new snapshot into a published frame until `stop` is set.
    pub fn run(mut self, shared: &Shared, handover: &Handover, stop: &AtomicBool) {
        let mut seen = 0;
        let mut readout_times = Recent::new(60);
        let mut frames = 0u64;
        let mut window_start = Instant::now();
        let mut window_frames = 0u64;
        let mut frame_rate_hz = 0.0;
        while !stop.load(Ordering::SeqCst) {
            let snapshot = {
                let guard = handover.lock();
                let (guard, _) = handover
                    .fresh
                    .wait_timeout_while(guard, Duration::from_millis(200), |s| {
                        s.generation == seen && !stop.load(Ordering::SeqCst)
                    })
                    .unwrap_or_else(|p| p.into_inner());
                if guard.generation == seen {
                    continue;
                }
                guard.clone()
            };
            seen = snapshot.generation;
            let t0 = Instant::now();
            let mut stats = snapshot.stats.clone();
            frames += 1;
            window_frames += 1;
            let window = t0.duration_since(window_start).as_secs_f64();
            if window >= 1.0 {
                frame_rate_hz = window_frames as f64 / window;
                window_start = t0;
                window_frames = 0;
            }
            stats.frames = frames;
            stats.frame_rate_hz = frame_rate_hz;
            stats.readout_time_median_us = readout_times.median();
            let frame = self.frame(&snapshot, &stats);
            readout_times.push(t0.elapsed().as_secs_f64() * 1e6);
            shared.publish(frame, stats);
        }
    }

    /// One frame as the JSON text of a server-sent event: positions (n×3 float32, base64, m),
    /// per-node σ magnitude sqrt(σx² + σy² + σz²) (n float32, base64, m; the filter's steady
    /// state, phase 0 of a periodic one), marker positions (sensor rest position + world
    /// displacement, m), forces and stats.
    fn frame(&mut self, snap: &Snapshot, stats: &Stats) -> String {
        let mut failure = snap.error.clone();
        if let Err(e) = self.view.set_state(&snap.x) {
            failure.get_or_insert(e.to_string());
        }
        if let Err(e) = self.view.node_positions(self.set, &mut self.positions) {
            failure.get_or_insert(e.to_string());
        }
        if let Err(e) = self.view.node_std(self.set, &mut self.std) {
            failure.get_or_insert(e.to_string());
        }
        if let Err(e) = self.view.sensor_displacements(&mut self.markers) {
            failure.get_or_insert(e.to_string());
        }
        for (m, s) in self
            .markers
            .chunks_exact_mut(3)
            .zip(&self.view.model().sensors)
        {
            for c in 0..3 {
                m[c] += s.position[c];
            }
        }
        let engine = base64::engine::general_purpose::STANDARD;
        self.bytes.clear();
        for v in &self.positions {
            self.bytes.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        let positions = engine.encode(&self.bytes);
        self.bytes.clear();
        for s in self.std.chunks_exact(3) {
            let mag = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            self.bytes.extend_from_slice(&(mag as f32).to_le_bytes());
        }
        let std = engine.encode(&self.bytes);
        serde_json::json!({
            "step": snap.step,
            "time": snap.time,
            "positions": positions,
            "std": std,
            "markers": self.markers,
            "forces": snap.forces,
            "gravity": snap.gravity,
            "tool": snap.tool.as_ref().map(|(position, result)| tool_json(position, result.as_ref())),
            "stats": stats,
            "error": failure,
        })
        .to_string()
    }
}

/// The tool in a frame: its centre as the page set it (m, model frame) and the result of the
/// last contact step since it was set: the force of the body on the tool (N, model frame), its
/// magnitude, the torque about the centre (N·m), the pressing nodes, the deepest penetration
/// of the free prediction (m) and the status. Before the first contact step (set while
/// paused): zero force, status "Free", `stepped` false.
fn tool_json(position: &[f64; 3], result: Option<&ToolContact>) -> serde_json::Value {
    let c = result.copied().unwrap_or_default();
    let magnitude =
        (c.force[0] * c.force[0] + c.force[1] * c.force[1] + c.force[2] * c.force[2]).sqrt();
    serde_json::json!({
        "position": position,
        "force": c.force,
        "force_magnitude": magnitude,
        "torque": c.torque,
        "active": c.active,
        "depth": c.depth,
        "status": format!("{:?}", c.status),
        "stepped": result.is_some(),
    })
}

/// The static description of the scene the page loads once (`GET /model.json`): rest
/// positions (m) and triangles of the drawn node set, sensors, load groups, Δt.
pub(crate) fn model_json(model: &Model, set: usize, options: &ServeOptions) -> String {
    let ns = &model.node_sets[set];
    let rest: Vec<f32> = ns.rest_positions.data.iter().map(|&v| v as f32).collect();
    let triangles: Vec<u32> = ns.triangles.iter().flatten().copied().collect();
    let sensors: Vec<serde_json::Value> = model
        .sensors
        .iter()
        .map(|s| serde_json::json!({"name": s.name, "position": s.position}))
        .collect();
    let loads: Vec<serde_json::Value> = model
        .loads
        .iter()
        .enumerate()
        .map(|(g, l)| {
            let components: Vec<u8> = model
                .inputs
                .iter()
                .filter_map(|i| match i.kind {
                    InputKind::Load { load, component } if load as usize == g => Some(component),
                    _ => None,
                })
                .collect();
            serde_json::json!({"name": l.name, "components": components})
        })
        .collect();
    let gravity = model
        .inputs
        .iter()
        .any(|i| matches!(i.kind, InputKind::Gravity { .. }));
    // The contact region, where the page's tool may press: the tool radius (m), the force
    // bound (N), the region's name and its nodes' rest positions and outward normals (m, 3 per
    // node) for placing the tool.
    let contact = model.contact.as_ref().map(|c| {
        serde_json::json!({
            "radius": c.tool_radius,
            "max_force": c.max_force,
            "region": c.name,
            "positions": c.rest_positions.data,
            "normals": c.normals.data,
        })
    });
    serde_json::json!({
        "title": options.title,
        "dt": model.dt,
        "order": model.r(),
        "node_set": ns.name,
        "rest_positions": rest,
        "triangles": triangles,
        "sensors": sensors,
        "loads": loads,
        "gravity": gravity,
        "contact": contact,
        "force_range": options.force_range,
        "frame_rate": options.frame_rate,
    })
    .to_string()
}
