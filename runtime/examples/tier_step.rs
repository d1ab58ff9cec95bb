//! Cost per step of the co-rotational tier (docs/design.md §10) on a compiled model file (not a
//! test; numbers for docs/results/tier.md):
//!
//! `cargo run --release -p crokf-runtime --example tier_step -- MODEL.crokf INPUT PEAK RAMP STEPS`
//!
//! Drives input channel INPUT (label, e.g. `tip.z`) with a ramp to PEAK (N) over RAMP steps,
//! then held, for STEPS steps; times every `predict` (the tier's nonlinear step: Newton on q)
//! and every `step` (predict + constant-gain update, measurements = the open-loop estimates,
//! i.e. zero innovation) separately, the same `step` with the first sensor's values missing (the
//! filter on its own covariance, docs/design.md §11.11) timed alternately with it, and prints
//! medians, Newton iterations per step, the slowest step and the median of the steps that
//! refreshed the tangent, and the envelope status; then one reduced force evaluation and one warped tangent at the final state on each
//! kernel path this CPU has (`crokf_kernel::Isa::available`: portable, AVX2 + FMA, AVX-512),
//! in alternating rounds so that the paths share clock and cache. Times are this thread's CPU
//! time (the machine is shared).

use crokf_formats::synthetic::SplitMix64;
use crokf_runtime::{load_model, Estimator};

/// This thread's CPU time, s (Linux `clock_gettime(CLOCK_THREAD_CPUTIME_ID)`): on a shared
/// machine, wall time counts the time other jobs hold the core, CPU time does not.
#[repr(C)]
struct Timespec {
    sec: i64,
    nsec: i64,
}
extern "C" {
    fn clock_gettime(clock: i32, ts: *mut Timespec) -> i32;
}
const CLOCK_THREAD_CPUTIME_ID: i32 = 3;

#[derive(Clone, Copy)]
struct Instant(f64);
impl Instant {
    fn now() -> Self {
        let mut ts = Timespec { sec: 0, nsec: 0 };
        // SAFETY: a valid out-pointer; the call only writes it.
        unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        Instant(ts.sec as f64 + ts.nsec as f64 * 1e-9)
    }
    fn elapsed(&self) -> Elapsed {
        Elapsed(Instant::now().0 - self.0)
    }
}
struct Elapsed(f64);
impl Elapsed {
    fn as_secs_f64(&self) -> f64 {
        self.0
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 6 {
        return Err("usage: tier_step MODEL.crokf INPUT PEAK RAMP STEPS".into());
    }
    let model = load_model(&args[1])?;
    let Some(tier) = model.tier.as_ref() else {
        return Err(format!("{}: no co-rotational tier in this model", args[1]).into());
    };
    let input = model
        .inputs
        .iter()
        .position(|c| c.label == args[2])
        .ok_or_else(|| format!("no input channel '{}'", args[2]))?;
    let peak: f64 = args[3].parse()?;
    let ramp: usize = args[4].parse()?;
    let steps: usize = args[5].parse()?;
    println!(
        "model {}: r = {}, {} sampled elements, {} measurement channels",
        args[1],
        tier.order,
        tier.elements.len(),
        model.measurements.len()
    );
    let load = |k: usize| peak * ((k + 1) as f64 / ramp.max(1) as f64).min(1.0);
    let mut u = vec![0.0; model.inputs.len()];
    // Open loop: predict only.
    let mut est = Estimator::new(&model)?;
    let mut times = Vec::with_capacity(steps);
    let (mut iterations, mut refreshes, mut outside) = (0usize, 0usize, 0usize);
    let mut refresh_times = Vec::new();
    for k in 0..steps {
        u[input] = load(k);
        let clock = Instant::now();
        est.predict(&u)?;
        let t = clock.elapsed().as_secs_f64();
        times.push(t);
        let s = est.tier_status();
        iterations += s.iterations;
        refreshes += s.refreshed as usize;
        outside += s.envelope.outside() as usize;
        if s.refreshed {
            refresh_times.push(t);
        }
    }
    let slowest = times.iter().fold(0.0f64, |m, &t| m.max(t));
    let predict = median(times);
    let mut tip = vec![0.0; 3 * model.sensors.len()];
    est.sensor_displacements(&mut tip)?;
    // Filter: predict + update with the open-loop estimates as measurements, the force-σ
    // levels (docs/design.md §11.10) adapting and held at the designed σ, timed alternately in
    // the same loop.
    let mut est2 = Estimator::new(&model)?;
    let mut held = Estimator::new(&model)?;
    held.set_force_adaptation(false);
    // The first sensor lost: its channels without values, the filter on its own covariance
    // (docs/design.md §11.11).
    let mut lost = Estimator::new(&model)?;
    let mut lost_times = Vec::with_capacity(steps);
    let mut y_lost = vec![None; model.measurements.len()];
    let mut y = vec![None; model.measurements.len()];
    let mut estimates = vec![0.0; model.measurements.len()];
    let (mut times, mut held_times) = (Vec::with_capacity(steps), Vec::with_capacity(steps));
    let mut reference = Estimator::new(&model)?;
    for k in 0..steps {
        u[input] = load(k);
        reference.predict(&u)?;
        reference.measurement_estimates(&mut estimates)?;
        for (yi, e) in y.iter_mut().zip(&estimates) {
            *yi = Some(*e);
        }
        let clock = Instant::now();
        est2.step(&u, &y)?;
        times.push(clock.elapsed().as_secs_f64());
        let clock = Instant::now();
        held.step(&u, &y)?;
        held_times.push(clock.elapsed().as_secs_f64());
        for ((yl, yi), m) in y_lost.iter_mut().zip(&y).zip(&model.measurements) {
            *yl = if m.sensor == 0 { None } else { *yi };
        }
        let clock = Instant::now();
        lost.step(&u, &y_lost)?;
        lost_times.push(clock.elapsed().as_secs_f64());
    }
    let step = median(times);
    let lost_step = median(lost_times);
    // The report's case: markers = the open-loop estimates + Gaussian noise of the model's R
    // (a fixed draw), so that every update moves the state; median and mean per step (the
    // mean counts the tangent refreshes at their rate, as `crokf-verify report` does).
    let mut noisy = Estimator::new(&model)?;
    let mut reference = Estimator::new(&model)?;
    let mut rng = SplitMix64(0x5eed);
    let (mut noisy_times, mut noisy_iterations, mut noisy_refreshes) =
        (Vec::with_capacity(steps), 0usize, 0usize);
    for k in 0..steps {
        u[input] = load(k);
        reference.predict(&u)?;
        reference.measurement_estimates(&mut estimates)?;
        for ((yi, e), v) in y
            .iter_mut()
            .zip(&estimates)
            .zip(&model.kalman.measurement_variance)
        {
            *yi = Some(*e + v.sqrt() * rng.normal());
        }
        let clock = Instant::now();
        noisy.step(&u, &y)?;
        noisy_times.push(clock.elapsed().as_secs_f64());
        let status = noisy.tier_status();
        noisy_iterations += status.iterations;
        noisy_refreshes += status.refreshed as usize;
    }
    let noisy_mean = noisy_times.iter().sum::<f64>() / steps as f64;
    println!(
        "predict + update with noisy markers (R of the model): median {:.1} µs, mean {:.1} µs; \
         {:.2} Newton iterations per step, {noisy_refreshes} tangent refreshes in {steps} steps",
        median(noisy_times) * 1e6,
        noisy_mean * 1e6,
        noisy_iterations as f64 / steps as f64
    );
    let held_step = median(held_times);
    println!(
        "predict (nonlinear step) median {:.1} µs; predict + update median {:.1} µs; \
         {:.2} Newton iterations per step, {refreshes} tangent refreshes in {steps} steps, \
         {outside} steps outside the envelope",
        predict * 1e6,
        step * 1e6,
        iterations as f64 / steps as f64
    );
    if let Some(level) = est2.force_level() {
        println!(
            "force-σ levels: predict + update median {:.1} µs adapting (level × {} at the end), \
             {:.1} µs held at the designed σ: ratio {:.3}",
            step * 1e6,
            level.factor,
            held_step * 1e6,
            step / held_step
        );
    }
    println!(
        "sensor '{}' lost (the filter's own covariance, n = {}): predict + update median {:.1} µs, \
         ratio {:.2} to every marker present",
        model.sensors.first().map_or("", |s| s.name.as_str()),
        lost.state().len(),
        lost_step * 1e6,
        lost_step / step
    );
    println!(
        "slowest predict {:.1} µs; steps with a tangent refresh: median {:.1} µs",
        slowest * 1e6,
        if refresh_times.is_empty() {
            0.0
        } else {
            median(refresh_times) * 1e6
        }
    );
    println!("first sensor at the end: {:?} m", &tip[..3]);
    // One reduced force evaluation at the final state: median of 200 batches of 20 calls.
    let tm = est.prepared().tier().ok_or("no tier")?;
    let r = tm.order();
    let s = est.state();
    let mut out = vec![0.0; r];
    let mut rotations = vec![[[0.0; 3]; 3]; tm.element_count()];
    let mut scratch = vec![0.0; tm.force_scratch_len()];
    let mut batches = Vec::with_capacity(200);
    for _ in 0..200 {
        let clock = Instant::now();
        for _ in 0..20 {
            tm.reduced_force(
                &s[..r],
                &s[r..2 * r],
                std::hint::black_box(&mut out),
                &mut rotations,
                &mut scratch,
            )
            .map_err(|e| format!("inverted element {e}"))?;
        }
        batches.push(clock.elapsed().as_secs_f64() / 20.0);
    }
    let force = median(batches);
    println!(
        "one reduced force evaluation: median {:.1} µs ({:.3} µs per sampled element)",
        force * 1e6,
        force * 1e6 / tm.element_count() as f64
    );
    // Each instruction-set path of the kernel on this CPU, at the same state, in alternating
    // rounds (same clock, same cache state): force evaluation and warped tangent.
    let isas = crokf_kernel::Isa::available();
    let blocks = tm.blocks();
    let beta = tm.damping_beta();
    let mut tangent = vec![0.0; r * r];
    let mut tangent_scratch = vec![0.0; blocks.tangent_scratch_len()];
    let mut force_times = vec![Vec::with_capacity(200); isas.len()];
    let mut tangent_times = vec![Vec::with_capacity(200); isas.len()];
    for _ in 0..200 {
        for (i, &isa) in isas.iter().enumerate() {
            let clock = Instant::now();
            for _ in 0..20 {
                blocks
                    .reduced_force(
                        isa,
                        &s[..r],
                        &s[r..2 * r],
                        beta,
                        std::hint::black_box(&mut out),
                        &mut rotations,
                        &mut scratch,
                    )
                    .map_err(|(e, _)| format!("inverted element {e}"))?;
            }
            force_times[i].push(clock.elapsed().as_secs_f64() / 20.0);
            let clock = Instant::now();
            for _ in 0..5 {
                blocks.add_warped_tangent(
                    isa,
                    &rotations,
                    1.0,
                    std::hint::black_box(&mut tangent),
                    &mut tangent_scratch,
                );
            }
            tangent_times[i].push(clock.elapsed().as_secs_f64() / 5.0);
        }
    }
    let per_element = 1e9 / tm.element_count() as f64;
    let fastest = force_times.len() - 1;
    let (best_force, best_tangent) = (
        median(force_times[fastest].clone()),
        median(tangent_times[fastest].clone()),
    );
    for ((isa, f), t) in isas.iter().zip(force_times).zip(tangent_times) {
        let (f, t) = (median(f), median(t));
        println!(
            "kernel path {:>8}: force {:.2} µs ({:.1} ns per element, {:.2}× the fastest), \
             tangent {:.1} µs ({:.2}×)",
            isa.name(),
            f * 1e6,
            f * per_element,
            f / best_force,
            t * 1e6,
            t / best_tangent
        );
    }
    Ok(())
}
