//! A state that stays finite: plausibility bounds, the innovation gate, and
//! all-or-nothing steps, on synthetic models with their own noise and on the committed example
//! models.

mod common;
use common::*;
use crokf_formats::Model;
use crokf_runtime::{warp, Estimator, RuntimeError};

/// Lower factor L (Q = L Lᵀ) of a positive semi-definite matrix: pivots below 1e-13 of the
/// largest diagonal entry give a zero column.
fn psd_factor(q: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = q.len();
    let tol = 1e-13 * (0..n).map(|i| q[i][i]).fold(0.0, f64::max);
    let mut l = vec![vec![0.0; n]; n];
    for j in 0..n {
        let d = q[j][j] - (0..j).map(|k| l[j][k] * l[j][k]).sum::<f64>();
        if d <= tol {
            continue;
        }
        l[j][j] = d.sqrt();
        for i in j + 1..n {
            l[i][j] = (q[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>()) / l[j][j];
        }
    }
    l
}

/// The model's own stochastic system: x⁺ = F x + G u + w, w ~ N(0, Q); y = R̃(W_s x) C_s x + v,
/// v ~ N(0, R). Returns per step (inputs, world measurements of every channel).
fn simulate(model: &Model, steps: usize, input: f64, seed: u64) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut rng = Rng(seed);
    let (f, g) = (mat(&model.transition), mat(&model.input));
    let l = psd_factor(&mat(&model.kalman.process_noise));
    let r = model.r();
    let mut x = vec![0.0; r];
    (0..steps)
        .map(|_| {
            let u = vec![input; model.inputs.len()];
            let xi: Vec<f64> = (0..r).map(|_| rng.normal()).collect();
            let w = matvec(&l, &xi);
            let fx = matvec(&f, &x);
            let gu = matvec(&g, &u);
            x = (0..r).map(|i| fx[i] + gu[i] + w[i]).collect();
            let y = model
                .measurements
                .iter()
                .enumerate()
                .map(|(j, ch)| {
                    let s = &model.sensors[ch.sensor as usize];
                    let c: Vec<f64> = (0..3)
                        .map(|k| {
                            s.displacement_rows
                                .row(k)
                                .iter()
                                .zip(&x)
                                .map(|(a, b)| a * b)
                                .sum()
                        })
                        .collect();
                    let om: Vec<f64> = (0..3)
                        .map(|k| {
                            s.rotation_rows
                                .row(k)
                                .iter()
                                .zip(&x)
                                .map(|(a, b)| a * b)
                                .sum()
                        })
                        .collect();
                    let world = warp::warp(&[om[0], om[1], om[2]], &[c[0], c[1], c[2]]);
                    world[ch.component as usize]
                        + model.kalman.measurement_variance[j].sqrt() * rng.normal()
                })
                .collect();
            (u, y)
        })
        .collect()
}

/// Runs `est` over the history; `edit(k, y)` may change step k's measurements (k from 1).
fn run(
    est: &mut Estimator,
    history: &[(Vec<f64>, Vec<f64>)],
    edit: impl Fn(usize, &mut Vec<Option<f64>>),
) -> Vec<Vec<f64>> {
    history
        .iter()
        .enumerate()
        .map(|(i, (u, y))| {
            let mut y: Vec<Option<f64>> = y.iter().map(|&v| Some(v)).collect();
            edit(i + 1, &mut y);
            est.step(u, &y).unwrap();
            est.state().to_vec()
        })
        .collect()
}

fn model() -> Model {
    synthetic_model(&Spec {
        rotation: 0.02,
        ..Default::default()
    })
}

/// An offset that is far beyond the gate and still below the plausibility bound.
fn outlier_offset(est: &Estimator) -> f64 {
    let prepared = est.prepared();
    let offset = 0.5 * prepared.measurement_bound();
    let s_max = prepared
        .innovation_variances()
        .iter()
        .flatten()
        .fold(0.0f64, |a, &v| a.max(v.sqrt()));
    assert!(
        offset > 50.0 * s_max,
        "offset {offset} vs innovation σ {s_max}"
    );
    offset
}

#[test]
fn own_noise_is_never_gated() {
    let model = model();
    let history = simulate(&model, 2000, 0.3, 11);
    let mut est = Estimator::new(&model).unwrap();
    run(&mut est, &history, |_, _| {});
    println!(
        "synthetic model, 2000 steps × 5 channels: gated {}",
        est.gated_total()
    );
    assert_eq!(est.gated_total(), 0);
}

#[test]
fn one_outlier_is_skipped_exactly_like_a_missing_value() {
    let model = model();
    let history = simulate(&model, 120, 0.3, 12);
    let mut reference = Estimator::new(&model).unwrap();
    let expect = run(&mut reference, &history, |k, y| {
        if k == 50 {
            y[0] = None;
        }
    });
    let mut est = Estimator::new(&model).unwrap();
    let offset = outlier_offset(&est);
    let got = run(&mut est, &history, |k, y| {
        if k == 50 {
            y[0] = y[0].map(|v| v + offset);
        }
    });
    assert_eq!(est.gated_total(), 1);
    assert_eq!(est.gated_per_channel(), [1, 0, 0, 0, 0]);
    assert_eq!(
        got, expect,
        "the gated run equals the run with the value missing"
    );
    assert_eq!(reference.gated_total(), 0);
}

#[test]
fn a_burst_is_skipped_and_the_filter_goes_on() {
    let model = model();
    let history = simulate(&model, 200, 0.3, 13);
    let burst = 60..=75;
    let mut reference = Estimator::new(&model).unwrap();
    let expect = run(&mut reference, &history, |k, y| {
        if burst.contains(&k) {
            y[4] = None;
            y[1] = None;
        }
    });
    let mut est = Estimator::new(&model).unwrap();
    let offset = outlier_offset(&est);
    let got = run(&mut est, &history, |k, y| {
        if burst.contains(&k) {
            y[4] = y[4].map(|v| v - offset);
            y[1] = y[1].map(|v| v + 0.3 * offset * (1.5 + (k as f64).sin()));
        }
    });
    assert_eq!(est.gated_per_channel(), [0, 16, 0, 0, 16]);
    assert_eq!(got, expect);
}

#[test]
fn a_marker_lost_for_100_steps_is_taken_back() {
    let model = model();
    let history = simulate(&model, 400, 0.3, 14);
    let mut always = Estimator::new(&model).unwrap();
    let expect = run(&mut always, &history, |_, _| {});
    let lost = 100..200;
    let mut est = Estimator::new(&model).unwrap();
    let got = run(&mut est, &history, |k, y| {
        if lost.contains(&k) {
            y[..3].iter_mut().for_each(|v| *v = None);
        }
    });
    assert_eq!(
        est.gated_total(),
        0,
        "the returning marker must not be gated"
    );
    // 200 steps after its return the estimate is the always-tracked one again.
    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
    let diff: Vec<f64> = got[399]
        .iter()
        .zip(&expect[399])
        .map(|(a, b)| a - b)
        .collect();
    let gap_lost: Vec<f64> = got[199]
        .iter()
        .zip(&expect[199])
        .map(|(a, b)| a - b)
        .collect();
    println!(
        "marker lost 100 steps: state gap {:.2e} at its return, {:.2e} 200 steps later (|x| = {:.2e})",
        norm(&gap_lost),
        norm(&diff),
        norm(&expect[399])
    );
    assert!(norm(&gap_lost) > 0.0);
    assert!(norm(&diff) < 1e-6 * norm(&expect[399]));
}

#[test]
fn implausible_and_non_finite_values_are_refused_before_the_state_changes() {
    let model = model();
    let mut est = Estimator::new(&model).unwrap();
    let y = vec![Some(0.01); 5];
    for _ in 0..3 {
        est.step(&[0.1; 4], &y).unwrap();
    }
    let (x, k, phase) = (est.state().to_vec(), est.step_index(), est.phase());
    let unchanged = |est: &Estimator| {
        assert_eq!(est.state(), &x[..]);
        assert_eq!((est.step_index(), est.phase()), (k, phase));
    };
    let e = est.step(&[0.1, 1e300, 0.1, 0.1], &y).unwrap_err();
    assert!(
        matches!(&e, RuntimeError::ImplausibleInput { step: 4, channel, .. } if channel == "push.y"),
        "{e}"
    );
    assert!(e.to_string().starts_with("step 4: input 'push.y'"), "{e}");
    unchanged(&est);
    let e = est.predict(&[0.1, 0.1, -1e300, 0.1]).unwrap_err();
    assert!(matches!(&e, RuntimeError::ImplausibleInput { channel, .. } if channel == "push.z"));
    unchanged(&est);
    let mut bad = y.clone();
    bad[3] = Some(1e300);
    let e = est.step(&[0.1; 4], &bad).unwrap_err();
    assert!(
        matches!(&e, RuntimeError::ImplausibleMeasurement { step: 4, channel, .. } if channel == "mid.x"),
        "{e}"
    );
    unchanged(&est);
    bad[3] = Some(f64::INFINITY);
    assert!(matches!(
        est.step(&[0.1; 4], &bad),
        Err(RuntimeError::NonFiniteMeasurement { step: 4, .. })
    ));
    unchanged(&est);
    // The bound is stated and sits between the values used above.
    let b = est.prepared().input_bounds()[1];
    assert!(b.is_finite() && b > 1.0 && b < 1e300, "{b}");
    let e = est.step(&[0.1, 2.0 * b, 0.1, 0.1], &y).unwrap_err();
    assert!(matches!(e, RuntimeError::ImplausibleInput { .. }));
    est.step(&[0.1, 0.5 * b, 0.1, 0.1], &y).unwrap();
}

#[test]
fn a_step_failing_in_the_update_is_rolled_back() {
    // Choose x so that the predicted rotation at "tip" is exactly 2π: R̃ is singular there.
    let model = synthetic_model(&Spec {
        rotation: 0.2,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    est.set_innovation_gate(None);
    let z = Rng(5).vec(model.r(), 1.0);
    let fz = matvec(&mat(&model.transition), &z);
    let w = matvec(&mat(&model.sensors[0].rotation_rows), &fz);
    let scale = 2.0 * std::f64::consts::PI / w.iter().map(|a| a * a).sum::<f64>().sqrt();
    let x: Vec<f64> = z.iter().map(|v| v * scale).collect();
    est.set_state(&x).unwrap();
    let e = est
        .step(&[0.0; 4], &[Some(0.0), None, None, None, None])
        .unwrap_err();
    assert!(
        matches!(e, RuntimeError::SingularWarp { step: 1, .. }),
        "{e}"
    );
    assert_eq!(est.state(), &x[..]);
    assert_eq!(est.step_index(), 0);
    // Without the measurement the same step goes through.
    est.step(&[0.0; 4], &[None; 5]).unwrap();
    assert_eq!(est.step_index(), 1);
}

#[test]
fn read_outs_never_return_non_finite_values() {
    let model = model();
    let mut est = Estimator::new(&model).unwrap();
    let x = vec![1e300; model.r()];
    est.set_state(&x).unwrap();
    let mut s = vec![0.0; 6];
    assert!(matches!(
        est.sensor_displacements(&mut s),
        Err(RuntimeError::NonFiniteReadout { .. })
    ));
    let mut n = vec![0.0; 12];
    assert!(est.node_positions(0, &mut n).is_err());
    assert!(est.node_displacements_exact(0, &mut n).is_err());
    let mut q = vec![0.0; 5];
    assert!(est.measurement_estimates(&mut q).is_err());
    // Stepping from such a state is refused, not carried out.
    let e = est.step(&[0.0; 4], &[None; 5]).unwrap_err();
    assert!(
        matches!(e, RuntimeError::NonFiniteState { step: 1, .. }),
        "{e}"
    );
    assert_eq!(est.state(), &x[..]);
}

/// The committed example models, driven by their own process and measurement noise: the
/// default 5σ gate skips nothing. The horizon keeps the force states' random walk inside the
/// load's range, which it leaves after about (F/σ)² steps: the cantilever's derived σ (1.5 N
/// per step against 20 N) allows 180 (beyond, its own noise turns the beam past 90°, where the
/// warp no longer describes it); the meniscus's 5 mN against 0.5 N allows 10⁴.
#[test]
fn example_models_gate_nothing_on_their_own_noise() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    for (name, steps) in [("cantilever", 150), ("meniscus", 1000)] {
        let model = crokf_runtime::load_model(root.join(name).join("model.crokf")).unwrap();
        let history = simulate(&model, steps, 0.0, 21);
        let mut est = Estimator::new(&model).unwrap();
        run(&mut est, &history, |_, _| {});
        println!(
            "{name}: {steps} steps × {} channels with the model's own noise: gated {}",
            model.measurements.len(),
            est.gated_total()
        );
        assert_eq!(est.gated_total(), 0, "{name}");
    }
}
