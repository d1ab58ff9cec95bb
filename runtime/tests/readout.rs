//! What the display read-out costs in accuracy: node displacements from
//! grouped single-precision rows (in the compact format 16-bit fixed-point rotation rows, in
//! the fixed16 format 16-bit displacement rows too), f32 sums and an f32 warp, against the f64
//! path, on the committed example models under their loads and on a synthetic model with
//! rotations beyond the series' range.

mod common;
use common::*;
use crokf_runtime::{load_model, DisplayRowFormat, Estimator, Model, PreparedModel};
use std::sync::Arc;

/// max |a − b| / max |b|.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / scale
}

fn estimator(model: &Model, format: DisplayRowFormat) -> Estimator {
    let prepared = PreparedModel::with_display_format(model.clone(), format).unwrap();
    Estimator::from_prepared(Arc::new(prepared))
}

/// Per column k: the largest |entry| of `rows(set)` over all displayed sets (the scale of the
/// column's 16-bit entries).
fn columns_max(
    model: &Model,
    rows: fn(&crokf_formats::NodeSet) -> &crokf_formats::Matrix,
) -> Vec<f64> {
    let r = model.r();
    let mut m = vec![0.0f64; r];
    for set in &model.node_sets {
        for row in rows(set).data.chunks_exact(r) {
            for (m, v) in m.iter_mut().zip(row) {
                *m = m.max(v.abs());
            }
        }
    }
    m
}

/// The error bound of the 16-bit rows, per node of a set: each entry of column k is off by at
/// most m_k / 32767 (m_k = the column's scale, [`columns_max`]), so a 3-vector of rows times x
/// by at most √3 Σ_k |x_k| m_k / 32767. Rotation rows: |δ(R̃(ω)u)| ≤ ½ |u| |δω| (R̃ = ∫₀¹ R(sω)
/// ds and |∂(R(sω)u)/∂ω| ≤ s|u|); displacement rows (`displacement16`): |δ(R̃u)| ≤ |R̃| |δu|
/// ≤ |δu| (|R̃| ≤ 1). Returns the sum per node, u_i from the f64 path.
fn fixed16_bound(model: &Model, x: &[f64], exact: &[f64], displacement16: bool) -> Vec<f64> {
    let worst = |m: Vec<f64>| {
        3f64.sqrt() * x.iter().zip(&m).map(|(x, m)| x.abs() * m).sum::<f64>() / 32767.0
    };
    let d_omega = worst(columns_max(model, |set| &set.rotation_rows));
    let d_u = if displacement16 {
        worst(columns_max(model, |set| &set.displacement_rows))
    } else {
        0.0
    };
    exact
        .chunks_exact(3)
        .map(|u| 0.5 * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt() * d_omega + d_u)
        .collect()
}

/// Checks the 16-bit read-out of set `s` node by node against [`fixed16_bound`] plus the f32
/// rounding allowance `f32_part` (relative to the largest displacement); returns the largest
/// error relative to the largest displacement.
fn check_compact(
    model: &Model,
    est: &Estimator,
    s: usize,
    f32_part: f64,
    displacement16: bool,
) -> f64 {
    let n = model.node_sets[s].node_tags.len();
    let (mut fast, mut exact) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    est.node_displacements(s, &mut fast).unwrap();
    est.node_displacements_exact(s, &mut exact).unwrap();
    let scale = exact.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let bound = fixed16_bound(model, est.state(), &exact, displacement16);
    for (i, b) in bound.iter().enumerate() {
        let e = (0..3)
            .map(|c| (fast[3 * i + c] - exact[3 * i + c]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            e <= b + f32_part * scale,
            "set {s} node {i}: error {e:e} above the bound {b:e} + {:e}",
            f32_part * scale
        );
    }
    relative(&fast, &exact)
}

#[test]
fn display_rows_cost_below_1e_5_of_the_displacement_on_the_example_models() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    for name in ["cantilever", "meniscus"] {
        let model = load_model(root.join(name).join("model.crokf")).unwrap();
        let u: Vec<f64> = (0..model.inputs.len())
            .map(|j| 0.2 * (1.0 + j as f64))
            .collect();
        let none = vec![None; model.measurements.len()];
        let (mut single, mut compact, mut fixed16) = (
            estimator(&model, DisplayRowFormat::Single),
            estimator(&model, DisplayRowFormat::Compact),
            estimator(&model, DisplayRowFormat::Fixed16),
        );
        // A steady load on every channel, then read out the displayed sets.
        for _ in 0..200 {
            single.step(&u, &none).unwrap();
            compact.step(&u, &none).unwrap();
            fixed16.step(&u, &none).unwrap();
        }
        let (mut worst_single, mut worst_compact, mut worst_fixed16) = (0.0f64, 0.0f64, 0.0f64);
        for (s, set) in model.node_sets.iter().enumerate() {
            let n = set.node_tags.len();
            let (mut fast, mut exact) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            single.node_displacements(s, &mut fast).unwrap();
            single.node_displacements_exact(s, &mut exact).unwrap();
            assert!(exact.iter().any(|v| *v != 0.0));
            worst_single = worst_single.max(relative(&fast, &exact));
            worst_compact = worst_compact.max(check_compact(&model, &compact, s, 1e-5, false));
            worst_fixed16 = worst_fixed16.max(check_compact(&model, &fixed16, s, 1e-5, true));
        }
        println!(
            "{name}: display read-out vs f64, max error / max displacement: single {worst_single:.2e}, compact (16-bit rotation rows) {worst_compact:.2e}, fixed16 (16-bit displacement and rotation rows) {worst_fixed16:.2e}"
        );
        assert!(worst_single < 1e-5, "{name}: {worst_single:e}");
        assert!(worst_compact < 2e-5, "{name}: {worst_compact:e}");
        assert!(worst_fixed16 < 1e-4, "{name}: {worst_fixed16:e}");
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
    let mut single = estimator(&model, DisplayRowFormat::Single);
    let mut compact = estimator(&model, DisplayRowFormat::Compact);
    let mut fixed16 = estimator(&model, DisplayRowFormat::Fixed16);
    let mut angles = vec![];
    let (mut worst_compact, mut worst_fixed16) = (0.0f64, 0.0f64);
    for seed in 0..20 {
        let x = Rng(100 + seed).vec(model.r(), 1.0);
        single.set_state(&x).unwrap();
        compact.set_state(&x).unwrap();
        fixed16.set_state(&x).unwrap();
        for (s, set) in model.node_sets.iter().enumerate() {
            let n = set.node_tags.len();
            let (mut fast, mut exact) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            single.node_displacements(s, &mut fast).unwrap();
            single.node_displacements_exact(s, &mut exact).unwrap();
            let e = relative(&fast, &exact);
            assert!(e < 1e-5, "seed {seed} set {s}: {e:e}");
            worst_compact = worst_compact.max(check_compact(&model, &compact, s, 1e-5, false));
            worst_fixed16 = worst_fixed16.max(check_compact(&model, &fixed16, s, 1e-5, true));
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
    println!("synthetic, |ω| up to {:.2} rad: max error / max displacement: compact read-out {worst_compact:.2e}, fixed16 {worst_fixed16:.2e}",
        angles.iter().fold(0.0f64, |a, &b| a.max(b)));
    assert!(angles.iter().any(|&a| a < 0.5) && angles.iter().any(|&a| a > 0.5));
}

#[test]
fn auto_format_is_fixed16_exactly_above_the_size_threshold() {
    // 6 rows of r f32 per node: the synthetic model's sets are tiny (single precision), the
    // benchmark's 5,000 nodes at r = 40 (4.8 MB) are 16-bit. Observable through the read-out:
    // the 16-bit one differs from the single-precision and the compact ones.
    let model = crokf_formats::synthetic::benchmark_model(40, 6, 30, 5000);
    const { assert!(6 * 40 * 5000 * 4 > crokf_runtime::COMPACT_ABOVE_BYTES) };
    let mut x = vec![0.0; 40];
    x.iter_mut()
        .enumerate()
        .for_each(|(k, v)| *v = ((k * 7) % 11) as f64 - 5.0);
    let read = |format| {
        let mut est = estimator(&model, format);
        est.set_state(&x).unwrap();
        let mut out = vec![0.0; 15000];
        est.node_displacements(0, &mut out).unwrap();
        out
    };
    let (auto, single, compact, fixed16) = (
        read(DisplayRowFormat::Auto),
        read(DisplayRowFormat::Single),
        read(DisplayRowFormat::Compact),
        read(DisplayRowFormat::Fixed16),
    );
    assert_eq!(auto, fixed16);
    assert_ne!(auto, single);
    assert_ne!(auto, compact);
    let small = synthetic_model(&Spec {
        rotation: 0.3,
        ..Default::default()
    });
    let mut a = estimator(&small, DisplayRowFormat::Auto);
    let mut b = estimator(&small, DisplayRowFormat::Single);
    let x = Rng(5).vec(small.r(), 1.0);
    a.set_state(&x).unwrap();
    b.set_state(&x).unwrap();
    let (mut ua, mut ub) = (vec![0.0; 12], vec![0.0; 12]);
    a.node_displacements(0, &mut ua).unwrap();
    b.node_displacements(0, &mut ub).unwrap();
    assert_eq!(ua, ub);
}
