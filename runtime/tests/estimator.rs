//! The estimator against dense direct computations on small synthetic models.

mod common;
use common::*;
use crokf_formats::Model;
use crokf_runtime::{CovarianceKind, Estimator, RuntimeError};

fn rows3(m: &crokf_formats::Matrix, block: usize, x: &[f64]) -> [f64; 3] {
    let a = mat(m);
    let v = matvec(&a[3 * block..3 * block + 3], x);
    [v[0], v[1], v[2]]
}

/// Rodrigues' formula with an explicit axis (independent of the runtime's series).
fn rodrigues(w: &[f64; 3]) -> [[f64; 3]; 3] {
    let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    let n = [w[0] / th, w[1] / th, w[2] / th];
    let k = [[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]];
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let k2: f64 = (0..3).map(|l| k[i][l] * k[l][j]).sum();
            r[i][j] = (i == j) as u8 as f64 + th.sin() * k[i][j] + (1.0 - th.cos()) * k2;
        }
    }
    r
}

/// R̃ with an explicit axis, docs/design.md §5.
fn warp_closed(w: &[f64; 3]) -> [[f64; 3]; 3] {
    let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    let n = [w[0] / th, w[1] / th, w[2] / th];
    let k = [[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]];
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let k2: f64 = (0..3).map(|l| k[i][l] * k[l][j]).sum();
            r[i][j] = (i == j) as u8 as f64
                + (1.0 - th.cos()) / th * k[i][j]
                + (1.0 - th.sin() / th) * k2;
        }
    }
    r
}

fn m3v(a: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| (0..3).map(|j| a[i][j] * v[j]).sum())
}

fn close(a: &[f64], b: &[f64], tol: f64) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1.0f64, |m, v| m.max(v.abs()));
    let err = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / scale;
    assert!(
        err < tol,
        "relative difference {err:e} ≥ {tol:e}\n{a:?}\n{b:?}"
    );
    err
}

#[test]
fn open_loop_equals_dense_recursion() {
    let model = synthetic_model(&Spec::default());
    let mut est = Estimator::new(&model).unwrap();
    let (f, g) = (mat(&model.transition), mat(&model.input));
    let mut x = vec![0.0; model.r()];
    let mut rng = Rng(11);
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let u = rng.vec(4, 10.0);
        est.predict(&u).unwrap();
        x = matvec(&f, &x)
            .iter()
            .zip(matvec(&g, &u))
            .map(|(a, b)| a + b)
            .collect();
        worst = worst.max(close(est.state(), &x, 1e-12));
    }
    assert_eq!(est.step_index(), 200);
    assert!((est.time() - 2.0).abs() < 1e-12);
    // All measurements missing: the update changes nothing (ω = 0 → R̃ = I exactly).
    let none = vec![None; 5];
    est.predict(&[1.0, 2.0, 3.0, 1.0]).unwrap();
    let before = est.state().to_vec();
    assert_eq!(est.update(&none).unwrap(), 0);
    assert_eq!(est.state(), &before[..]);
    eprintln!("open loop worst relative difference {worst:e}");
}

#[test]
fn update_equals_textbook_kalman_update_per_phase() {
    let model = synthetic_model(&Spec {
        every2: 3,
        ..Default::default()
    });
    assert_eq!(model.kalman.period, 3);
    let mut est = Estimator::new(&model).unwrap();
    let h = mat(&model.measurement_matrix());
    let mut rng = Rng(12);
    for k in 1..=9u64 {
        let u = rng.vec(4, 1.0);
        est.predict(&u).unwrap();
        let phase = (k % 3) as usize;
        assert_eq!(est.phase(), phase);
        assert_eq!(est.covariance_kind(), CovarianceKind::Prior);
        let prior = est.state().to_vec();
        let y: Vec<f64> = rng.vec(5, 1.0);
        let ph = &model.kalman.phases[phase];
        // Mid sensor (channels 3, 4) is active only when k mod 3 = 0.
        assert_eq!(ph.measured.len(), if phase == 0 { 5 } else { 3 });
        let innov: Vec<f64> = ph
            .measured
            .iter()
            .map(|&j| y[j as usize] - matvec(&h, &prior)[j as usize])
            .collect();
        let expect: Vec<f64> = prior
            .iter()
            .zip(matvec(&mat(&ph.gain), &innov))
            .map(|(a, b)| a + b)
            .collect();
        let used = est
            .update(&y.iter().map(|&v| Some(v)).collect::<Vec<_>>())
            .unwrap();
        assert_eq!(used, ph.measured.len());
        close(est.state(), &expect, 1e-12);
        assert_eq!(est.covariance_kind(), CovarianceKind::Posterior);
    }
}

#[test]
fn missing_measurement_means_zero_innovation_without_rotation() {
    let model = synthetic_model(&Spec::default());
    let mut est = Estimator::new(&model).unwrap();
    // These values are 5σ outliers for this model: the textbook update needs the gate off.
    est.set_innovation_gate(None);
    est.predict(&[1.0, -1.0, 0.5, 1.0]).unwrap();
    let prior = est.state().to_vec();
    let h = mat(&model.measurement_matrix());
    let hx = matvec(&h, &prior);
    let y = [Some(0.3), None, Some(-0.2), None, Some(0.1)];
    assert_eq!(est.update(&y).unwrap(), 3);
    let innov: Vec<f64> = (0..5).map(|j| y[j].map_or(0.0, |v| v - hx[j])).collect();
    let k = mat(&model.kalman.phases[0].gain);
    let expect: Vec<f64> = prior
        .iter()
        .zip(matvec(&k, &innov))
        .map(|(a, b)| a + b)
        .collect();
    close(est.state(), &expect, 1e-12);
}

#[test]
fn loads_are_rotated_into_the_local_frame() {
    let model = synthetic_model(&Spec {
        rotation: 0.3,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    let mut rng = Rng(13);
    let x0 = rng.vec(model.r(), 1.0);
    est.set_state(&x0).unwrap();
    let u = [2.0, -1.0, 4.0, 0.7];
    est.predict(&u).unwrap();
    let omega = rows3(&model.loads[0].rotation_rows, 0, &x0);
    assert!(
        (omega.iter().map(|v| v * v).sum::<f64>()).sqrt() > 0.1,
        "test needs a real rotation"
    );
    let r = rodrigues(&omega);
    let f_lin: Vec<f64> = (0..3)
        .map(|i| (0..3).map(|k| r[k][i] * u[k]).sum())
        .collect();
    let u_lin = [f_lin[0], f_lin[1], f_lin[2], u[3]];
    let expect: Vec<f64> = matvec(&mat(&model.transition), &x0)
        .iter()
        .zip(matvec(&mat(&model.input), &u_lin))
        .map(|(a, b)| a + b)
        .collect();
    close(est.state(), &expect, 1e-12);
}

#[test]
fn world_measurements_are_unwarped_before_the_update() {
    let model = synthetic_model(&Spec {
        rotation: 0.3,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    let mut rng = Rng(14);
    let x0 = rng.vec(model.r(), 1.0);
    est.set_state(&x0).unwrap();
    est.predict(&[0.0; 4]).unwrap();
    let prior = est.state().to_vec();
    let y = rng.vec(5, 1.0);
    // Tip: all three components measured → y_lin = R̃(ω̄)⁻¹ y_world.
    let tip = &model.sensors[0];
    let w_tip = rows3(&tip.rotation_rows, 0, &prior);
    let y_tip_lin = matvec(&inverse(&warp_closed(&w_tip).map(|r| r.to_vec())), &y[0..3]);
    // Mid: x and z measured, y filled from the prediction R̃ C x⁻.
    let mid = &model.sensors[1];
    let w_mid = rows3(&mid.rotation_rows, 0, &prior);
    let u_mid = rows3(&mid.displacement_rows, 0, &prior);
    let pred_world = m3v(&warp_closed(&w_mid), &u_mid);
    let y_mid_world = [y[3], pred_world[1], y[4]];
    let y_mid_lin = matvec(
        &inverse(&warp_closed(&w_mid).map(|r| r.to_vec())),
        &y_mid_world,
    );
    let u_tip = rows3(&tip.displacement_rows, 0, &prior);
    let innov = [
        y_tip_lin[0] - u_tip[0],
        y_tip_lin[1] - u_tip[1],
        y_tip_lin[2] - u_tip[2],
        y_mid_lin[0] - u_mid[0],
        y_mid_lin[2] - u_mid[2],
    ];
    let expect: Vec<f64> = prior
        .iter()
        .zip(matvec(&mat(&model.kalman.phases[0].gain), &innov))
        .map(|(a, b)| a + b)
        .collect();
    est.update(&y.iter().map(|&v| Some(v)).collect::<Vec<_>>())
        .unwrap();
    close(est.state(), &expect, 1e-12);

    // Consistency: a world measurement equal to the prediction gives a zero innovation.
    est.predict(&[0.0; 4]).unwrap();
    let prior = est.state().to_vec();
    let mut pred = vec![0.0; 5];
    est.measurement_estimates(&mut pred).unwrap();
    est.update(&pred.iter().map(|&v| Some(v)).collect::<Vec<_>>())
        .unwrap();
    close(est.state(), &prior, 1e-13);
}

#[test]
fn readouts_match_dense_formulas() {
    let model = synthetic_model(&Spec {
        rotation: 0.2,
        every2: 2,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    let mut rng = Rng(15);
    let x = rng.vec(model.r(), 1.0);
    est.set_state(&x).unwrap();
    let mut s = vec![0.0; 6];
    est.sensor_displacements(&mut s).unwrap();
    for (i, sensor) in model.sensors.iter().enumerate() {
        let w = rows3(&sensor.rotation_rows, 0, &x);
        let u = m3v(&warp_closed(&w), &rows3(&sensor.displacement_rows, 0, &x));
        close(&s[3 * i..3 * i + 3], &u, 1e-13);
    }
    let mut m = vec![0.0; 5];
    est.measurement_estimates(&mut m).unwrap();
    assert_eq!(m, [s[0], s[1], s[2], s[3], s[5]]);
    let set = &model.node_sets[0];
    let mut u = vec![0.0; 12];
    let mut u32 = vec![0.0; 12];
    let mut p = vec![0.0; 12];
    est.node_displacements_exact(0, &mut u).unwrap();
    est.node_displacements(0, &mut u32).unwrap();
    est.node_positions(0, &mut p).unwrap();
    for i in 0..4 {
        let w = rows3(&set.rotation_rows, i, &x);
        let expect = m3v(&warp_closed(&w), &rows3(&set.displacement_rows, i, &x));
        close(&u[3 * i..3 * i + 3], &expect, 1e-13);
        // Single-precision rows and sums: f32 rounding over r = 6 terms.
        close(&u32[3 * i..3 * i + 3], &expect, 1e-6);
        for c in 0..3 {
            assert!((p[3 * i + c] - set.rest_positions.get(i, c) - u32[3 * i + c]).abs() < 1e-15);
        }
    }
    // Standard deviations: sqrt(diag(C P Cᵀ)) with P = posterior of phase 0, then the prior
    // of phase 1 after a prediction, then the posterior of phase 1 after the update.
    let std_dense = |pm: &crokf_formats::Matrix, rows: &crokf_formats::Matrix| -> Vec<f64> {
        let c = mat(rows);
        let cpc = mul(&mul(&c, &mat(pm)), &transpose(&c));
        (0..c.len()).map(|i| cpc[i][i].sqrt()).collect()
    };
    let check = |est: &Estimator, pm: &crokf_formats::Matrix| {
        let mut sd = vec![0.0; 6];
        est.sensor_std(&mut sd).unwrap();
        close(
            &sd[0..3],
            &std_dense(pm, &model.sensors[0].displacement_rows),
            1e-12,
        );
        close(
            &sd[3..6],
            &std_dense(pm, &model.sensors[1].displacement_rows),
            1e-12,
        );
        let mut nd = vec![0.0; 3];
        est.node_std(1, &mut nd).unwrap();
        close(
            &nd,
            &std_dense(pm, &model.node_sets[1].displacement_rows),
            1e-12,
        );
    };
    check(&est, &model.kalman.phases[0].posterior_covariance);
    est.predict(&[0.0; 4]).unwrap();
    check(&est, &model.kalman.phases[1].prior_covariance);
    est.update(&[None; 5]).unwrap();
    check(&est, &model.kalman.phases[1].posterior_covariance);
    // The measured sensor's posterior std is below its prior std (the filter learns).
    let (mut a, mut b) = (vec![0.0; 6], vec![0.0; 6]);
    est.predict(&[0.0; 4]).unwrap();
    est.sensor_std(&mut a).unwrap();
    est.update(&[None; 5]).unwrap();
    est.sensor_std(&mut b).unwrap();
    assert!(b.iter().zip(&a).all(|(post, prior)| post < prior));
}

#[test]
fn bad_values_are_rejected_without_touching_the_state() {
    let model = synthetic_model(&Spec {
        rotation: 0.2,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    assert!(matches!(
        est.update(&[None; 5]),
        Err(RuntimeError::UpdateWithoutPredict)
    ));
    est.predict(&[1.0, 1.0, 1.0, 1.0]).unwrap();
    let snapshot = est.state().to_vec();
    let k = est.step_index();
    let e = est
        .update(&[Some(1.0), Some(f64::INFINITY), None, None, None])
        .unwrap_err();
    assert!(e.to_string().contains("tip.y"), "{e}");
    let e = est
        .update(&[Some(f64::NAN), None, None, None, None])
        .unwrap_err();
    assert!(matches!(e, RuntimeError::NonFiniteMeasurement { .. }));
    assert!(matches!(
        est.update(&[None; 4]),
        Err(RuntimeError::Length {
            expected: 5,
            found: 4,
            ..
        })
    ));
    assert_eq!(est.state(), &snapshot[..]);
    // step(): measurements checked before the prediction.
    let e = est
        .step(&[0.0; 4], &[None, None, None, None, Some(f64::NAN)])
        .unwrap_err();
    assert!(e.to_string().contains("mid.z"), "{e}");
    let e = est.predict(&[0.0, f64::NAN, 0.0, 0.0]).unwrap_err();
    assert!(e.to_string().contains("push.y"), "{e}");
    assert!(est.predict(&[0.0; 3]).is_err());
    assert_eq!(est.state(), &snapshot[..]);
    assert_eq!(est.step_index(), k);
    // The pending update still works afterwards.
    est.update(&[Some(0.1); 5]).unwrap();
    assert_ne!(est.state(), &snapshot[..]);
    // Read-out buffers of the wrong size, unknown node set.
    assert!(est.sensor_displacements(&mut [0.0; 5]).is_err());
    assert!(matches!(
        est.node_positions(2, &mut [0.0; 3]),
        Err(RuntimeError::NoSuchNodeSet { index: 2, count: 2 })
    ));
    est.reset();
    assert!(est.state().iter().all(|&v| v == 0.0));
    assert_eq!(est.step_index(), 0);
}

#[test]
fn load_and_from_bytes_report_the_path() {
    use crokf_runtime::ModelExt;
    let model = synthetic_model(&Spec::default());
    let bytes = crokf_formats::encode(&model);
    assert_eq!(Model::from_bytes(&bytes).unwrap(), model);
    let dir = scratch_dir("load");
    let path = dir.join("m.crokf");
    std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
    let e = Model::load(&path).unwrap_err();
    assert!(
        e.to_string().contains("m.crokf") && e.to_string().contains("truncated"),
        "{e}"
    );
    let e = Model::load(dir.join("absent.crokf")).unwrap_err();
    assert!(matches!(e, RuntimeError::Io { .. }) && e.to_string().contains("absent.crokf"));
    std::fs::write(&path, &bytes).unwrap();
    assert_eq!(Model::load(&path).unwrap(), model);
}

#[test]
fn filter_error_matches_the_stored_posterior_covariance() {
    // Simulate the model with process noise ~ N(0, Q_r) and measurement noise ~ N(0, R): the
    // filter's mean squared state error must match trace(P) (an invariant of a correct
    // steady-state gain), and beat the open-loop error.
    let model = synthetic_model(&Spec::default());
    let mut est = Estimator::new(&model).unwrap();
    let mut open = Estimator::new(&model).unwrap();
    let (f, g) = (mat(&model.transition), mat(&model.input));
    let h = mat(&model.measurement_matrix());
    let lq = cholesky(&mat(&model.kalman.process_noise));
    let mut rng = Rng(21);
    let mut x = vec![0.0; model.r()];
    let (mut e_kf, mut e_ol) = (0.0, 0.0);
    let (burn, n) = (200, 20_000);
    for k in 0..burn + n {
        let u = rng.vec(4, 1.0);
        let xi: Vec<f64> = (0..model.r()).map(|_| rng.normal()).collect();
        let w = matvec(&lq, &xi);
        x = matvec(&f, &x)
            .iter()
            .zip(matvec(&g, &u))
            .zip(w)
            .map(|((a, b), c)| a + b + c)
            .collect();
        let y: Vec<Option<f64>> = matvec(&h, &x)
            .iter()
            .zip(&model.kalman.measurement_variance)
            .map(|(v, s2)| Some(v + s2.sqrt() * rng.normal()))
            .collect();
        est.step(&u, &y).unwrap();
        open.predict(&u).unwrap();
        if k >= burn {
            e_kf += est
                .state()
                .iter()
                .zip(&x)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
            e_ol += open
                .state()
                .iter()
                .zip(&x)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
        }
    }
    let (e_kf, e_ol) = (e_kf / n as f64, e_ol / n as f64);
    let p = &model.kalman.phases[0].posterior_covariance;
    let trace_p: f64 = (0..model.r()).map(|i| p.get(i, i)).sum();
    eprintln!(
        "mean squared state error: filter {e_kf:.4}, trace(P) {trace_p:.4}, open loop {e_ol:.4}"
    );
    assert!(
        (e_kf / trace_p - 1.0).abs() < 0.05,
        "filter MSE {e_kf} vs trace(P) {trace_p}"
    );
    assert!(e_kf < 0.8 * e_ol);
}
