//! The co-rotational tier's force-σ levels (docs/design.md §11.10) end to end, on the small
//! generated beam of `tier.rs` (12×2×2 cells, 288 tetrahedra) with its tip load estimated and
//! its force σ derived from the load's range: the compiler stores the filter at each level,
//! the runtime moves between them on its innovations, and off is the one-level filter exactly.
//!
//! `cargo test -p crokf-tests --test force_levels -- --nocapture` prints the figures.

use std::sync::OnceLock;

use crokf_formats::synthetic::SplitMix64;
use crokf_formats::Model;
use crokf_runtime::Estimator;

#[path = "../../runtime/tests/support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::count;

#[path = "support/beam_tier.rs"]
mod beam_tier;
use beam_tier::{compile_beam, estimated_load_beam, DT};

fn compiled() -> &'static Model {
    static C: OnceLock<Model> = OnceLock::new();
    C.get_or_init(|| {
        // The tip load states no σ: its force σ is derived from the tier's range (30 N) and
        // the default rise time (0.2 s).
        let dir = std::env::temp_dir().join(format!("crokf-levels-{}", std::process::id()));
        let (_, model) = compile_beam(&dir, &estimated_load_beam(false));
        let _ = std::fs::remove_dir_all(&dir);
        model
    })
}

/// The model with its levels removed: the one-level filter of the same compile.
fn one_level(model: &Model) -> Model {
    let mut m = model.clone();
    let t = m.tier.as_mut().unwrap();
    (t.force_levels, t.adaptation) = (Vec::new(), None);
    m
}

/// The tip load's z input channel.
fn tip_z(model: &Model) -> usize {
    model
        .inputs
        .iter()
        .position(|c| c.label == "tip.z")
        .unwrap()
}

/// The markers of `truth` after its prediction with inputs `u`, plus the tier's stated noise
/// (σ per channel `sigma`).
fn noisy_markers(
    truth: &mut Estimator,
    u: &[f64],
    sigma: &[f64],
    rng: &mut SplitMix64,
) -> Vec<Option<f64>> {
    let mut y = vec![0.0; sigma.len()];
    truth.predict(u).unwrap();
    truth.measurement_estimates(&mut y).unwrap();
    y.iter()
        .zip(sigma)
        .map(|(&v, s)| Some(v + s * rng.normal()))
        .collect()
}

/// The markers' σ the tier's filter states, per measurement channel.
fn marker_sigma(model: &Model) -> Vec<f64> {
    model
        .tier
        .as_ref()
        .unwrap()
        .kalman
        .measurement_variance
        .iter()
        .map(|v| v.sqrt())
        .collect()
}

/// Largest |a − b| / max|b| over two matrices' entries.
fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

/// Each level is the designed filter with the force σ scaled: its process noise equals the
/// designed one's with the force block times factor² (and nothing else changed), its force
/// states' posterior variance and gains grow with the factor, and the statistic averages over
/// the rise time in steps.
#[test]
fn each_level_is_the_designed_filter_with_the_force_sigma_scaled() {
    let model = compiled();
    let t = model.tier.as_ref().unwrap();
    let n = t.state_dim();
    let r3 = 3 * t.order as usize;
    assert_eq!(t.force_loads, vec![0]);
    let factors: Vec<f64> = t.force_levels.iter().map(|l| l.factor).collect();
    assert_eq!(factors, vec![4.0, 0.25, 0.0625]);
    let q0 = &t.kalman.process_noise.data;
    let force_variance = |k: &crokf_formats::KalmanGains| {
        let p = &k.phases[0].posterior_covariance.data;
        (r3..n).map(|i| p[i * n + i]).sum::<f64>()
    };
    let force_gain = |k: &crokf_formats::KalmanGains| {
        let g = &k.phases[0].gain;
        (r3 * g.cols as usize..g.data.len())
            .map(|i| g.data[i].abs())
            .sum::<f64>()
    };
    let mut by_factor: Vec<(f64, f64, f64)> =
        vec![(1.0, force_variance(&t.kalman), force_gain(&t.kalman))];
    for level in &t.force_levels {
        let f2 = level.factor * level.factor;
        let expected: Vec<f64> = (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                if i >= r3 && j >= r3 {
                    q0[k] * f2
                } else {
                    q0[k]
                }
            })
            .collect();
        let d = relative_difference(&level.kalman.process_noise.data, &expected);
        assert!(d < 1e-12, "level × {}: Q differs by {d:e}", level.factor);
        assert_eq!(level.scheduled.len(), t.scheduled.len());
        for (s, base) in level.scheduled.iter().zip(&t.scheduled) {
            let q = &base.kalman.process_noise.data;
            let forces_only = (0..n * n).all(|k| {
                let (i, j) = (k / n, k % n);
                let e = if i >= r3 && j >= r3 { q[k] * f2 } else { q[k] };
                (s.process_noise.data[k] - e).abs()
                    <= 1e-12 * q.iter().fold(0.0f64, |m, v| m.max(v.abs()))
            });
            assert!(
                forces_only,
                "level × {}: a scheduled Q differs",
                level.factor
            );
        }
        by_factor.push((
            level.factor,
            force_variance(&level.kalman),
            force_gain(&level.kalman),
        ));
    }
    by_factor.sort_by(|a, b| a.0.total_cmp(&b.0));
    eprintln!("factor, force-state posterior variance (N²), force gain: {by_factor:?}");
    for w in by_factor.windows(2) {
        assert!(w[1].1 > w[0].1 && w[1].2 > w[0].2, "{by_factor:?}");
    }
    let a = t.adaptation.as_ref().unwrap();
    assert_eq!(a.hold, (0.2 / DT).round() as u32);
    assert!(a.smoothing.iter().all(|&s| (s - 2.0 / 41.0).abs() < 1e-15));
    assert!(
        a.raise_above > 1.0 && a.lower_below < 1.0 && a.lower_below > 0.3,
        "{a:?}"
    );
}

/// Tip load history: a ramp to `peak` N along −z over 0.1 s starting at step `start`, held.
fn ramp(k: usize, start: usize, peak: f64) -> f64 {
    let t = k.saturating_sub(start) as f64 * DT;
    -peak * (t / 0.1).min(1.0)
}

/// One filtered run against the tier's own open-loop trajectory under the load `load(k)`
/// (markers: the truth plus the scene's noise, seed `seed`), the load given to the filter or
/// withheld, the adaptation on or off: per step the tip error (m) and the level's factor.
fn run(
    model: &Model,
    steps: usize,
    load: impl Fn(usize) -> f64,
    given: bool,
    adapt: bool,
    seed: u64,
) -> (Vec<f64>, Vec<f64>) {
    let zi = tip_z(model);
    let sigma = marker_sigma(model);
    let mut truth = Estimator::new(model).unwrap();
    let mut est = Estimator::new(model).unwrap();
    est.set_innovation_gate(None);
    est.set_force_adaptation(adapt);
    let mut rng = SplitMix64(seed);
    let mut u = vec![0.0; model.inputs.len()];
    let zero = vec![0.0; model.inputs.len()];
    let (mut tip, mut tip_ref) = ([0.0; 3], [0.0; 3]);
    let (mut errors, mut factors) = (Vec::new(), Vec::new());
    for k in 0..steps {
        u[zi] = load(k);
        let measured = noisy_markers(&mut truth, &u, &sigma, &mut rng);
        est.step(if given { &u } else { &zero }, &measured).unwrap();
        truth.sensor_displacements(&mut tip_ref).unwrap();
        est.sensor_displacements(&mut tip).unwrap();
        errors.push(
            (0..3)
                .map(|c| (tip[c] - tip_ref[c]).powi(2))
                .sum::<f64>()
                .sqrt(),
        );
        factors.push(est.force_level().map_or(1.0, |l| l.factor));
    }
    (errors, factors)
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// With the load given, the force states only absorb what the input does not explain: every
/// run makes its first update at the smallest σ (markers every step), the load told from the
/// next prediction on keeps it there, and the innovations, white and small, leave it there (at
/// least 3/4 of the steps: a raise comes back down one `hold` later); the tip follows the truth
/// closer than with the designed σ alone (the markers' noise lets less in). With the load
/// withheld, the level is at or above the designed σ from the second step on.
#[test]
fn the_level_falls_while_the_load_is_given_and_not_below_the_designed_sigma_when_withheld() {
    let model = compiled();
    let hold = model
        .tier
        .as_ref()
        .unwrap()
        .adaptation
        .as_ref()
        .unwrap()
        .hold as usize;
    let steps = 400;
    let load = |k| ramp(k, 0, 20.0);
    let (mut adaptive, mut designed) = (Vec::new(), Vec::new());
    for seed in 1..=4 {
        let (e, f) = run(model, steps, load, true, true, seed);
        assert_eq!(f.last(), Some(&0.0625), "seed {seed}: levels {f:?}");
        // The first update is made at the smallest level (steps count from 1; step 1 holds
        // u = 0), and the ramp, told from step 2 on, keeps it there to the end.
        let first_low = 1 + f.iter().position(|&x| x == 0.0625).unwrap();
        eprintln!("seed {seed}, load given: smallest level from step {first_low}");
        assert_eq!(first_low, 1, "seed {seed}: levels {f:?}");
        // A raise by the statistic (one seed has one) comes back down after a `hold`.
        let low = f.iter().filter(|&&x| x == 0.0625).count();
        assert!(
            low >= 3 * steps / 4,
            "seed {seed}: {low} of {steps} steps at the smallest level (hold {hold})"
        );
        adaptive.push(rms(&e[steps / 2..]));
        designed.push(rms(
            &run(model, steps, load, true, false, seed).0[steps / 2..]
        ));
    }
    eprintln!(
        "loads given, tip error RMS over the second half (m): adaptive {adaptive:?}, designed \
         σ {designed:?}"
    );
    for (a, d) in adaptive.iter().zip(&designed) {
        assert!(a < &(0.7 * d), "adaptive {a:e} vs designed {d:e}");
    }

    // Withheld: nothing for 150 steps, then a 20 N ramp nobody tells the filter of. After the
    // first update (at the smallest level, as every run's) the level never goes below the
    // designed σ (a lower σ would lag a withheld load before the statistic could show it); the
    // estimate is as close as the designed σ's.
    let start = 150;
    let load = |k| ramp(k, start, 20.0);
    for seed in 1..=4 {
        let (e, f) = run(model, 450, load, false, true, seed);
        let (d, _) = run(model, 450, load, false, false, seed);
        assert_eq!(f[0], 0.0625, "seed {seed}");
        let lowest = f[1..].iter().fold(f64::INFINITY, |m, &x| m.min(x));
        let highest = f.iter().fold(0.0f64, |m, &x| m.max(x));
        eprintln!(
            "seed {seed}, withheld ramp at step {start}: levels × {lowest} … × {highest}; tip \
             error RMS over the ramp and hold {:.3e} m (designed σ {:.3e} m)",
            rms(&e[start..]),
            rms(&d[start..])
        );
        assert!(
            lowest >= 1.0,
            "seed {seed}: × {lowest} with the load withheld"
        );
        assert!(rms(&e[start..]) <= 1.05 * rms(&d[start..]), "seed {seed}");
    }
}

/// Off, the estimator is the one-level filter of the same compile bit for bit; a failing step
/// leaves the level and its statistic as they were, also one whose prediction moved the level.
#[test]
fn off_is_the_one_level_filter_and_a_failed_step_changes_no_level() {
    let model = compiled();
    let plain = one_level(model);
    let mut off = Estimator::new(model).unwrap();
    off.set_force_adaptation(false);
    let mut single = Estimator::new(&plain).unwrap();
    assert_eq!(single.force_level(), None);
    let mut on = Estimator::new(model).unwrap();
    let zi = tip_z(model);
    let mut rng = SplitMix64(5);
    let mut u = vec![0.0; model.inputs.len()];
    let q = model.measurements.len();
    for k in 0..200 {
        u[zi] = ramp(k, 50, 10.0);
        let y: Vec<Option<f64>> = (0..q).map(|_| Some(1e-3 * rng.normal())).collect();
        off.step(&u, &y).unwrap();
        single.step(&u, &y).unwrap();
        on.step(&u, &y).unwrap();
        let bits = |e: &Estimator| e.state().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&off), bits(&single), "step {k}");
        assert_eq!(off.tier_filter(), single.tier_filter());
        let level = off.force_level().unwrap();
        assert_eq!((level.level, level.factor, level.adapting), (0, 1.0, false));
    }
    let before = on.force_level().unwrap();
    assert!(before.adapting);
    let state: Vec<u64> = on.state().iter().map(|v| v.to_bits()).collect();
    let mut bad: Vec<Option<f64>> = vec![Some(0.0); q];
    bad[0] = Some(f64::NAN);
    assert!(on.step(&u, &bad).is_err());
    assert_eq!(on.force_level(), Some(before));
    assert_eq!(
        on.state().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        state
    );
    // A told prediction moves a fresh estimator to the lowest level before its update; when
    // that update fails (here its gains, edited to 1e308, overflow), the step is rolled back
    // with its level.
    let mut overflowing = model.clone();
    let lowest = overflowing
        .tier
        .as_mut()
        .unwrap()
        .force_levels
        .last_mut()
        .unwrap();
    assert_eq!(lowest.factor, 0.0625);
    for k in std::iter::once(&mut lowest.kalman).chain(lowest.scheduled.iter_mut()) {
        for phase in &mut k.phases {
            phase.gain.data.iter_mut().for_each(|g| *g = 1e308);
        }
    }
    // (The stored gains: with the covariance recursion on, the lowering would carry the
    // transition's covariance and its own gain instead, docs/design.md §11.10.)
    let mut fresh = Estimator::new(&overflowing).unwrap();
    fresh.set_innovation_gate(None);
    fresh.set_covariance_recursion(false);
    let untouched = fresh.force_level();
    u[zi] = 5.0;
    let e = fresh.step(&u, &vec![Some(5.0); q]).unwrap_err();
    assert!(e.to_string().contains("update"), "{e}");
    assert_eq!(fresh.force_level(), untouched);
    assert!(fresh.state().iter().all(|v| v.to_bits() == 0));
    fresh.step(&u, &vec![Some(0.0); q]).unwrap();
    assert_eq!(fresh.force_level().unwrap().factor, 0.0625);
    // The C ABI: the level of a new estimator (the designed σ), pinned or not; a model with
    // one level reports none; a NULL handle -1.
    use crokf_runtime::capi::*;
    for (m, expected) in [(model, 1), (&plain, 0)] {
        let bytes = crokf_formats::encode(m);
        unsafe {
            let handle = crokf_model_from_bytes(bytes.as_ptr(), bytes.len());
            assert!(!handle.is_null());
            let e = crokf_estimator_new(handle);
            let (mut level, mut factor, mut statistic) = (usize::MAX, 0.0, -1.0);
            assert_eq!(crokf_set_force_adaptation(e, 0), 0);
            let has = crokf_force_level(e, &mut level, &mut factor, &mut statistic);
            assert_eq!(has, expected);
            if expected == 1 {
                assert_eq!((level, factor, statistic), (0, 1.0, 0.0));
            } else {
                assert_eq!((level, factor, statistic), (usize::MAX, 0.0, -1.0));
            }
            assert_eq!(
                crokf_force_level(std::ptr::null(), &mut level, &mut factor, &mut statistic),
                -1
            );
            assert_eq!(crokf_set_force_adaptation(std::ptr::null_mut(), 1), -1);
            crokf_estimator_free(e);
            crokf_model_free(handle);
        }
    }
}

/// Steps with the levels moving (down while the load is given, up on a large innovation)
/// allocate nothing.
#[test]
fn steps_that_change_the_level_do_not_allocate() {
    let model = compiled();
    let mut est = Estimator::new(model).unwrap();
    est.set_innovation_gate(None);
    let zi = tip_z(model);
    let mut u = vec![0.0; model.inputs.len()];
    let q = model.measurements.len();
    let mut sigma = vec![0.0; 3 * model.sensors.len()];
    let mut predicted = vec![0.0; q];
    let mut y = vec![None; q];
    est.step(&u, &y).unwrap();
    let mut factors = Vec::with_capacity(170);
    let n = count(|| {
        for k in 0..170 {
            u[zi] = -1.0;
            est.predict(&u).unwrap();
            est.measurement_estimates(&mut predicted).unwrap();
            // Calm markers, then a 5 mm (5σ) offset on every channel from step 150.
            let jump = if k >= 150 { 0.005 } else { 0.0 };
            for (v, p) in y.iter_mut().zip(&predicted) {
                *v = Some(p + jump);
            }
            est.update(&y).unwrap();
            est.sensor_std(&mut sigma).unwrap();
            factors.push(est.force_level().unwrap().factor);
        }
    });
    assert_eq!(n, 0, "allocations in 170 steps");
    assert_eq!(factors[149], 0.0625, "{factors:?}");
    assert!(factors[150..].iter().any(|&f| f > 0.0625), "{factors:?}");
}

/// A lowering carries the covariance of its transition (docs/design.md §11.10, the recursion
/// of §11.11). At a check: the load is given, 10 N, but at step 100 the body gets 15 N more
/// than it is told; the lag raises the level from the lowest, and once the force states have
/// caught up a check lowers it again; from that update on the estimator runs on its own
/// covariance, started at the posterior the update left (the higher level's) and propagated
/// with the lower level's Q. Up to that update it is bit for bit the estimator with the
/// recursion off; after it, its tip σ starts above the lower level's stored σ (what the
/// read-out stated at once before), falls towards it, and the stored filter takes over within
/// the run. At a told start: none when the load is told from the run's first update on (made
/// at the lowest level), the recursion from the designed level's prior when updates at the
/// designed σ came before.
#[test]
fn a_lowering_carries_the_covariance_of_its_transition() {
    let model = compiled();
    let zi = tip_z(model);
    let tip = model.sensors.iter().position(|s| s.name == "tip").unwrap();
    let tip_sigma = |e: &Estimator| {
        let mut s = vec![0.0; 3 * model.sensors.len()];
        e.sensor_std(&mut s).unwrap();
        s[3 * tip + 2]
    };
    let sigma = marker_sigma(model);

    // Told from step 2: the run's first update is at the lowest level and the told load keeps
    // it there, nothing runs. Told from step 5 only: the designed σ from step 2, and the told
    // start lowers the level before step 5's update, which starts the recursion from the
    // designed level's prior: its tip σ above the lowest level's stored one.
    for (from, runs) in [(0, false), (3, true)] {
        let mut told = Estimator::new(model).unwrap();
        let mut stored = Estimator::new(model).unwrap();
        stored.set_covariance_recursion(false);
        for e in [&mut told, &mut stored] {
            e.set_innovation_gate(None);
        }
        let mut truth = Estimator::new(model).unwrap();
        let mut rng = SplitMix64(5);
        let mut u = vec![0.0; model.inputs.len()];
        for k in 0..8 {
            u[zi] = ramp(k, from, 20.0);
            let y = noisy_markers(&mut truth, &u, &sigma, &mut rng);
            told.step(&u, &y).unwrap();
            stored.step(&u, &y).unwrap();
            let factor = told.force_level().unwrap().factor;
            let told_now = k > from;
            assert_eq!(
                factor,
                if k == 0 || told_now { 0.0625 } else { 1.0 },
                "from {from}, step {k}"
            );
            assert_eq!(
                told.tier_covariance().is_some(),
                runs && told_now,
                "from {from}, step {k}"
            );
            if runs && told_now {
                let ratio = tip_sigma(&told) / tip_sigma(&stored);
                assert!(ratio > 1.05, "from {from}, step {k}: {ratio}");
            }
        }
    }
    let mut carried = Estimator::new(model).unwrap();
    let mut stored = Estimator::new(model).unwrap();
    stored.set_covariance_recursion(false);
    for e in [&mut carried, &mut stored] {
        e.set_innovation_gate(None);
    }
    let mut truth = Estimator::new(model).unwrap();
    let mut rng = SplitMix64(3);
    let (mut raised, mut lowered_at) = (false, None);
    let (mut ratios, mut settled) = (Vec::new(), None);
    let mut given = vec![0.0; model.inputs.len()];
    let mut u = vec![0.0; model.inputs.len()];
    for k in 0..400 {
        given[zi] = ramp(k, 0, 10.0);
        u[zi] = given[zi] - if k >= 100 { 15.0 } else { 0.0 };
        let y = noisy_markers(&mut truth, &u, &sigma, &mut rng);
        let before = carried.force_level().unwrap().factor;
        carried.step(&given, &y).unwrap();
        stored.step(&given, &y).unwrap();
        assert!(stored.tier_covariance().is_none(), "step {k}");
        let (level, level_stored) = (
            carried.force_level().unwrap().factor,
            stored.force_level().unwrap().factor,
        );
        raised |= level > before;
        if lowered_at.is_none() {
            assert_eq!(carried.state(), stored.state(), "step {k}");
            if level < before && raised {
                lowered_at = Some(k);
            } else {
                assert!(carried.tier_covariance().is_none(), "step {k}");
                continue;
            }
        }
        if carried.tier_covariance().is_none() {
            settled = Some(k);
            break;
        }
        if level != level_stored {
            break;
        }
        ratios.push(tip_sigma(&carried) / tip_sigma(&stored));
    }
    let lowered_at =
        lowered_at.expect("the untold step raises the level and a later check lowers it");
    eprintln!(
        "lowered at step {lowered_at}: tip σ / the lower level's stored σ over {} steps: first \
         {:.3}, last {:.3}; stored filter back at step {settled:?}",
        ratios.len(),
        ratios[0],
        ratios[ratios.len() - 1]
    );
    // The higher level's posterior is the larger; the ratio falls as the transition settles.
    assert!(ratios[0] > 1.05, "{ratios:?}");
    assert!(ratios[ratios.len() - 1] < ratios[0], "{ratios:?}");
    assert!(ratios.iter().all(|r| *r > 0.9), "{ratios:?}");
    let settled = settled.expect("the stored filter takes over within the run");
    assert!(settled > lowered_at, "{settled}");
}
