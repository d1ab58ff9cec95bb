//! What the single-precision display read-out costs (issue 14 item 6): node displacements from
//! f32 rows, f32 sums and an f32 warp against the f64 path, on the committed example models
//! under their loads and on a synthetic model with rotations beyond the series' range.

mod common;
use common::*;
use crokf_runtime::{load_model, Estimator};

/// max |a − b| / max |b|.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / scale
}

#[test]
fn single_precision_display_costs_below_1e_5_of_the_displacement() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    for name in ["cantilever", "meniscus"] {
        let model = load_model(root.join(name).join("model.crokf")).unwrap();
        let mut est = Estimator::new(&model).unwrap();
        // A steady load on every channel, then read out the displayed sets.
        let u: Vec<f64> = (0..model.inputs.len())
            .map(|j| 0.2 * (1.0 + j as f64))
            .collect();
        let none = vec![None; model.measurements.len()];
        let mut worst = 0.0f64;
        for _ in 0..200 {
            est.step(&u, &none).unwrap();
        }
        for (s, set) in model.node_sets.iter().enumerate() {
            let n = set.node_tags.len();
            let (mut fast, mut exact) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            est.node_displacements(s, &mut fast).unwrap();
            est.node_displacements_exact(s, &mut exact).unwrap();
            assert!(exact.iter().any(|v| *v != 0.0));
            worst = worst.max(relative(&fast, &exact));
        }
        println!("{name}: f32 display read-out vs f64, max error / max displacement = {worst:.2e}");
        assert!(worst < 1e-5, "{name}: {worst:e}");
    }
}

#[test]
fn large_rotations_and_partial_groups_match_the_f64_path() {
    // Rotation rows scaled so that |ω| passes 1/2 rad at some nodes (the f64 branch), 4 and 1
    // nodes per set (groups of 8 only partly used).
    let model = synthetic_model(&Spec {
        rotation: 0.8,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    let mut angles = vec![];
    for seed in 0..20 {
        let x = Rng(100 + seed).vec(model.r(), 1.0);
        est.set_state(&x).unwrap();
        for (s, set) in model.node_sets.iter().enumerate() {
            let n = set.node_tags.len();
            let (mut fast, mut exact) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            est.node_displacements(s, &mut fast).unwrap();
            est.node_displacements_exact(s, &mut exact).unwrap();
            let e = relative(&fast, &exact);
            assert!(e < 1e-5, "seed {seed} set {s}: {e:e}");
            for i in 0..n {
                let w: Vec<f64> = (0..3)
                    .map(|c| {
                        set.rotation_rows
                            .row(3 * i + c)
                            .iter()
                            .zip(&x)
                            .map(|(a, b)| a * b)
                            .sum()
                    })
                    .collect();
                angles.push(w.iter().map(|v| v * v).sum::<f64>().sqrt());
            }
        }
    }
    assert!(angles.iter().any(|&a| a < 0.5) && angles.iter().any(|&a| a > 0.5));
}
