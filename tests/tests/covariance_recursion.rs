//! The tier filter's covariance recursion while channels are missing (docs/design.md §11.11),
//! on the small generated beam of `tier.rs` (288 tetrahedra) with two markers (`tip` at the
//! load, `mid` halfway) and its tip load estimated (force σ derived from the load's range):
//! its linearised step is the compiler's, an update with a marker lost is the Kalman update of
//! the markers present from the recursion's prior (dense reference), the lost marker's σ
//! grows, the stored filter takes over again after the marker returns, and a failed step
//! restores the recursion with the state, allocation-free.
//!
//! `cargo test -p crokf-tests --test covariance_recursion -- --nocapture` prints the figures.

use std::path::PathBuf;
use std::sync::OnceLock;

use crokf_compile::model_file::tier as section;
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_formats::synthetic::SplitMix64;
use crokf_formats::Model;
use crokf_runtime::tier::{linearised_step, TierModel, TierState, SETTLED};
use crokf_runtime::Estimator;
use nalgebra::{DMatrix, DVector};

#[path = "../../runtime/tests/support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::count;

#[path = "support/beam_tier.rs"]
mod beam_tier;
use beam_tier::{compile_beam, estimated_load_beam};

/// The scene's path and its compiled model, once per process.
fn compiled() -> &'static (PathBuf, Model) {
    static C: OnceLock<(PathBuf, Model)> = OnceLock::new();
    C.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("crokf-recursion-{}", std::process::id()));
        compile_beam(&dir, &estimated_load_beam(true))
    })
}

/// The index of input channel `label`.
fn input(model: &Model, label: &str) -> usize {
    model.inputs.iter().position(|c| c.label == label).unwrap()
}

/// max |a − b| / max |b|.
fn relative(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    (a - b).amax() / b.amax()
}

/// The runtime's step linearised at rest (after one unloaded step, its Newton matrix is the
/// tangent at rest) is the compiler's `LinearisedTier::transition` of the file's tier, which
/// assembles F densely from K_r at rest: the recursion's structured F = D + E G is the same
/// matrix.
#[test]
fn the_linearised_step_is_the_compilers_transition() {
    let (path, model) = compiled();
    let t = model.tier.as_ref().unwrap();
    let full = FullOrder::build(path, &mut StageTimer::default()).unwrap();
    let (lin, _, _) = section::linearised_of_file(&full, model, &full.noise).unwrap();
    let (expected, _) = lin.transition().unwrap();
    let tm = TierModel::new(model, t);
    let mut st = TierState::new(&tm, model.loads.len());
    assert!(linearised_step(&tm, &st).is_none());
    st.step(&tm, &vec![0.0; model.inputs.len()], 1).unwrap();
    let n = tm.state_dim();
    let f = DMatrix::from_row_slice(n, n, &linearised_step(&tm, &st).unwrap());
    let difference = relative(&f, &expected);
    eprintln!("runtime F vs compiler F at rest: max relative difference {difference:.2e}");
    assert!(difference < 1e-9, "{difference:e}");
}

/// The stored filter's covariance `kind` (prior or posterior) of phase `phase` for the filter
/// the estimator uses now.
fn stored(model: &Model, est: &Estimator, prior: bool) -> DMatrix<f64> {
    let t = model.tier.as_ref().unwrap();
    let k = t.filters().nth(est.tier_filter().unwrap()).unwrap();
    let ph = &k.phases[est.phase()];
    section::file_matrix(if prior {
        &ph.prior_covariance
    } else {
        &ph.posterior_covariance
    })
}

/// The estimator's covariance now: its own while the recursion runs, else the stored one.
fn covariance(model: &Model, est: &Estimator, prior: bool) -> DMatrix<f64> {
    let n = est.state().len();
    match est.tier_covariance() {
        Some(p) => DMatrix::from_row_slice(n, n, p),
        None => stored(model, est, prior),
    }
}

/// H of channels `channels` over s (rows V_s of q, zeros elsewhere).
fn h_rows(model: &Model, channels: &[usize]) -> DMatrix<f64> {
    let t = model.tier.as_ref().unwrap();
    let (r, n) = (t.order as usize, t.state_dim());
    DMatrix::from_fn(channels.len(), n, |a, i| {
        let m = model.measurements[channels[a]];
        let rows = &t.sensor_rows[m.sensor as usize];
        if i < r {
            rows.data[m.component as usize * r + i]
        } else {
            0.0
        }
    })
}

/// With the tip marker lost, each update is the Kalman update of the mid marker alone from
/// the recursion's prior, s⁺ = s⁻ + P⁻Hᵀ S⁻¹ ν, P = P⁻ − P⁻Hᵀ S⁻¹ H P⁻ (nalgebra, dense), and
/// each prediction P⁻ = F P Fᵀ + Q with the compiler's F at rest (the load is small: the step
/// is linear to round-off); the lost marker's read-out σ grows step by step and is
/// sqrt(diag(V P Vᵀ)); after it returns the stored filter takes over, with a prior within
/// SETTLED of the stored one.
#[test]
fn a_lost_marker_updates_from_the_recursions_covariance() {
    let (path, model) = compiled();
    let t = model.tier.as_ref().unwrap();
    let n = t.state_dim();
    let full = FullOrder::build(path, &mut StageTimer::default()).unwrap();
    let (lin, _, _) = section::linearised_of_file(&full, model, &full.noise).unwrap();
    let (f, _) = lin.transition().unwrap();
    let q_noise = |est: &Estimator| {
        section::file_matrix(
            &t.filters()
                .nth(est.tier_filter().unwrap())
                .unwrap()
                .process_noise,
        )
    };
    let mut est = Estimator::new(model).unwrap();
    est.set_innovation_gate(None);
    let u = vec![0.0; model.inputs.len()];
    let q = model.measurements.len();
    let mid: Vec<usize> = (0..q)
        .filter(|&j| model.sensors[model.measurements[j].sensor as usize].name == "mid")
        .collect();
    let tip = model.sensors.iter().position(|s| s.name == "tip").unwrap();
    // Marker values of a few nm: the body stays where its step is linear to round-off (the
    // covariances checked here do not depend on the values).
    let mut rng = SplitMix64(11);
    let mut marker = move || 1e-9 * rng.normal();
    let mut y: Vec<Option<f64>> = vec![None; q];
    for _ in 0..60 {
        for v in y.iter_mut() {
            *v = Some(marker());
        }
        est.step(&u, &y).unwrap();
    }
    assert!(est.tier_covariance().is_none(), "every marker present");
    let mut tip_sigma = Vec::new();
    let mut posterior_prev = covariance(model, &est, false);
    let mut worst: (f64, f64, f64) = (0.0, 0.0, 0.0);
    let mut std = vec![0.0; 3 * model.sensors.len()];
    for k in 60..100 {
        est.predict(&u).unwrap();
        let prior = covariance(model, &est, true);
        if k > 60 {
            let expected = &f * &posterior_prev * f.transpose() + q_noise(&est);
            worst.0 = worst.0.max(relative(&prior, &expected));
        }
        let s_prior = DVector::from_column_slice(est.state());
        for (j, v) in y.iter_mut().enumerate() {
            *v = mid.contains(&j).then(&mut marker);
        }
        let h = h_rows(model, &mid);
        let r = DMatrix::from_diagonal(&DVector::from_iterator(
            mid.len(),
            mid.iter().map(|&j| t.kalman.measurement_variance[j]),
        ));
        let nu =
            DVector::from_iterator(mid.len(), mid.iter().map(|&j| y[j].unwrap())) - &h * &s_prior;
        let pht = &prior * h.transpose();
        let s = &h * &pht + r;
        let gain = &pht * s.clone().try_inverse().unwrap();
        let s_expected = &s_prior + &gain * nu;
        let p_expected = &prior - &gain * pht.transpose();
        assert_eq!(est.update(&y).unwrap(), mid.len());
        let p = covariance(model, &est, false);
        assert!(est.tier_covariance().is_some(), "step {k}");
        let s_after = DVector::from_column_slice(est.state());
        worst.1 = worst
            .1
            .max((&s_after - &s_expected).amax() / s_expected.amax());
        worst.2 = worst.2.max(relative(&p, &p_expected));
        est.sensor_std(&mut std).unwrap();
        let v = h_rows(
            model,
            &(0..q)
                .filter(|&j| model.measurements[j].sensor as usize == tip)
                .collect::<Vec<_>>(),
        );
        let read_out = (&v * &p * v.transpose()).map_diagonal(|d| d.sqrt());
        for (c, &j) in (0..q)
            .filter(|&j| model.measurements[j].sensor as usize == tip)
            .collect::<Vec<_>>()
            .iter()
            .enumerate()
        {
            let comp = model.measurements[j].component as usize;
            let d = (std[3 * tip + comp] - read_out[c]).abs();
            assert!(
                d <= 1e-12 * read_out[c],
                "step {k}: σ {} vs {}",
                std[3 * tip + comp],
                read_out[c]
            );
        }
        tip_sigma.push(read_out.amax());
        posterior_prev = p;
    }
    eprintln!(
        "tip lost for 40 steps: prior vs F P Fᵀ + Q {:.2e}, state vs dense update {:.2e}, P vs \
         dense update {:.2e}; tip σ {:.3e} → {:.3e} m",
        worst.0,
        worst.1,
        worst.2,
        tip_sigma[0],
        tip_sigma[tip_sigma.len() - 1]
    );
    assert!(
        worst.0 < 1e-6 && worst.1 < 1e-9 && worst.2 < 1e-9,
        "{worst:?}"
    );
    assert!(
        tip_sigma.windows(2).all(|w| w[1] > w[0]),
        "the lost marker's σ grows: {tip_sigma:?}"
    );
    // Back: every marker present; the stored filter takes over once the prior settled.
    let mut back = None;
    let mut last_prior = None;
    for k in 100..700 {
        for v in y.iter_mut() {
            *v = Some(marker());
        }
        est.predict(&u).unwrap();
        let live = est.tier_covariance().is_some();
        if live {
            last_prior = Some(covariance(model, &est, true));
        }
        est.update(&y).unwrap();
        if est.tier_covariance().is_none() {
            back = Some(k);
            break;
        }
    }
    let back = back.expect("the recursion settles within 600 steps");
    let prior = last_prior.unwrap();
    let stored_prior = stored(model, &est, true);
    let force: Vec<f64> = (3 * t.order as usize..n)
        .map(|i| prior[(i, i)] / stored_prior[(i, i)])
        .collect();
    eprintln!(
        "back to the stored filter {} steps after the marker returned; force variance ratio \
         {force:.3?}",
        back - 99
    );
    assert!(force.iter().all(|&x| x <= 1.0 + SETTLED), "{force:?}");
}

/// Every stored filter of `model`'s tier, to edit.
fn broken_filters(model: &mut Model) -> impl Iterator<Item = &mut crokf_formats::KalmanGains> {
    let t = model.tier.as_mut().unwrap();
    std::iter::once(&mut t.kalman)
        .chain(t.scheduled.iter_mut().map(|s| &mut s.kalman))
        .chain(
            t.force_levels
                .iter_mut()
                .flat_map(|l| std::iter::once(&mut l.kalman).chain(&mut l.scheduled)),
        )
}

/// Steps with a marker missing allocate nothing (read-outs included), switched off the
/// recursion does not run, and a step whose update
/// fails while the recursion runs (here its process noise, edited negative, makes S
/// indefinite) is rolled back with the recursion: state, covariance and σ bit for bit.
#[test]
fn recursion_steps_allocate_nothing_and_a_failed_step_restores_them() {
    let (_, model) = compiled();
    let zi = input(model, "tip.z");
    let q = model.measurements.len();
    let mut u = vec![0.0; model.inputs.len()];
    u[zi] = -1.0;
    let mut est = Estimator::new(model).unwrap();
    est.set_innovation_gate(None);
    let mut std = vec![0.0; 3 * model.sensors.len()];
    let mut nodes = vec![0.0; 3 * model.node_sets[0].node_tags.len()];
    let mut y: Vec<Option<f64>> = vec![Some(0.0); q];
    y[0] = None;
    est.step(&u, &y).unwrap();
    let n = count(|| {
        for _ in 0..50 {
            est.step(&u, &y).unwrap();
            est.sensor_std(&mut std).unwrap();
            est.node_std(0, &mut nodes).unwrap();
        }
    });
    assert_eq!(n, 0, "allocations in 50 steps with a channel missing");
    assert!(est.tier_covariance().is_some());
    // Off: the stored gains and σ with the channel missing; the recursion stops at once.
    let mut stored_gains = Estimator::new(model).unwrap();
    stored_gains.set_innovation_gate(None);
    stored_gains.set_covariance_recursion(false);
    stored_gains.step(&u, &y).unwrap();
    assert!(stored_gains.tier_covariance().is_none());
    est.set_covariance_recursion(false);
    assert!(est.tier_covariance().is_none());
    // The C ABI: P while the filter carries it (1), nothing otherwise (0), -1 on a wrong length
    // or NULL; the switch.
    use crokf_runtime::capi::*;
    let bytes = crokf_formats::encode(model);
    let n = model.tier.as_ref().unwrap().state_dim();
    unsafe {
        let handle = crokf_model_from_bytes(bytes.as_ptr(), bytes.len());
        assert!(!handle.is_null());
        let e = crokf_estimator_new(handle);
        let present: Vec<u8> = y.iter().map(|v| u8::from(v.is_some())).collect();
        let values: Vec<f64> = y.iter().map(|v| v.unwrap_or(0.0)).collect();
        let mut p = vec![f64::NAN; n * n];
        assert_eq!(crokf_tier_covariance(e, p.as_mut_ptr(), p.len()), 0);
        assert!(p.iter().all(|v| v.is_nan()));
        assert_eq!(crokf_set_innovation_gate(e, 0.0), 0);
        let step = |e| crokf_step(e, u.as_ptr(), u.len(), values.as_ptr(), present.as_ptr(), q);
        assert_eq!(step(e), (q - 1) as i32);
        assert_eq!(crokf_tier_covariance(e, p.as_mut_ptr(), p.len()), 1);
        assert!(p.iter().all(|v| v.is_finite()));
        assert_eq!(crokf_tier_covariance(e, p.as_mut_ptr(), p.len() - 1), -1);
        assert_eq!(
            crokf_tier_covariance(std::ptr::null(), p.as_mut_ptr(), p.len()),
            -1
        );
        assert_eq!(crokf_set_covariance_recursion(e, 0), 0);
        assert_eq!(crokf_tier_covariance(e, p.as_mut_ptr(), p.len()), 0);
        assert_eq!(crokf_set_covariance_recursion(std::ptr::null_mut(), 1), -1);
        crokf_estimator_free(e);
        crokf_model_free(handle);
    }

    let mut broken = model.clone();
    for k in broken_filters(&mut broken) {
        let n = k.process_noise.rows as usize;
        for i in 0..n {
            k.process_noise.data[i * n + i] = -1e3;
        }
    }
    let mut est = Estimator::new(&broken).unwrap();
    est.set_innovation_gate(None);
    est.step(&u, &y).unwrap();
    assert!(est.tier_covariance().is_some());
    let bits = |e: &Estimator| -> (Vec<u64>, Vec<u64>) {
        (
            e.state().iter().map(|v| v.to_bits()).collect(),
            e.tier_covariance()
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect(),
        )
    };
    let before = bits(&est);
    let mut std_before = vec![0.0; std.len()];
    est.sensor_std(&mut std_before).unwrap();
    let e = est.step(&u, &y).unwrap_err();
    assert!(e.to_string().contains("update"), "{e}");
    assert_eq!(bits(&est), before);
    est.sensor_std(&mut std).unwrap();
    assert_eq!(std, std_before);

    // A process noise near the f64 range: the recursion's prior overflows; its σ read-outs
    // are refused rather than returned as ±∞, and the update that follows fails and changes
    // nothing.
    for k in broken_filters(&mut broken) {
        let n = k.process_noise.rows as usize;
        for i in 0..n {
            k.process_noise.data[i * n + i] = 1e308;
        }
    }
    let mut est = Estimator::new(&broken).unwrap();
    est.set_innovation_gate(None);
    est.step(&u, &y).unwrap();
    est.predict(&u).unwrap();
    let e = est.sensor_std(&mut std).unwrap_err();
    assert!(e.to_string().contains("sensor std"), "{e}");
    assert!(est.node_std(0, &mut nodes).is_err());
    let state: Vec<u64> = est.state().iter().map(|v| v.to_bits()).collect();
    assert!(est.update(&y).is_err());
    assert_eq!(
        est.state().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        state
    );
}
