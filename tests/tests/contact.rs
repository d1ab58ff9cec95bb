//! The contact step against the full-order contact reference (docs/contact.md): a 2 mm sphere
//! pressed into the meniscus's femoral surface, held, and lifted off, open loop; the reduced
//! model's tool force against the full-order linear FEM with the same tool and contact law.

use std::path::Path;

use crokf_compile::compile::{compile, CompileOptions};
use crokf_compile::full_order::FullOrder;
use crokf_compile::timer::StageTimer;
use crokf_runtime::{ContactStatus, Estimator, RuntimeError};
use crokf_verify::contact::ContactReference;

fn scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/scene_touch.toml")
}

/// The accuracy target (2 % of the full-order force at every depth) is not met yet: the
/// full-order reference chatters (hard node contact with the body's inertia at 1 kHz: the node
/// bounces off between presses) while the reduced step, whose residual compliance is
/// quasi-static, stays in contact; run with `--ignored` to see the figures.
#[test]
#[ignore = "accuracy target not met yet (docs/contact.md)"]
fn a_pressed_sphere_gets_the_full_order_force() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let region = model
        .contact
        .as_ref()
        .expect("the scene declares a contact region");
    let mut full_timer = StageTimer::default();
    let full = FullOrder::build(&scene(), &mut full_timer).expect("full order");
    let mut reference = ContactReference::new(&full).expect("reference");
    // The region node nearest (20, 0, top) mm: the tool comes down along its normal.
    let target = [0.020, 0.0, 0.00427];
    let (node, _) = (0..region.len())
        .map(|i| {
            let p = &region.rest_positions.data[3 * i..3 * i + 3];
            let d: f64 = (0..3).map(|c| (p[c] - target[c]).powi(2)).sum();
            (i, d)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("nodes");
    let p = &region.rest_positions.data[3 * node..3 * node + 3];
    let n = &region.normals.data[3 * node..3 * node + 3];
    let radius = region.tool_radius;
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let f_ext = vec![0.0; full.fem.dof_count()];
    // 0.6 mm deep over 300 steps, held 200 steps, lifted in one step.
    let depth = |k: usize| -> f64 {
        if k < 300 {
            6e-4 * k as f64 / 300.0
        } else if k < 500 {
            6e-4
        } else {
            -1e-3
        }
    };
    let mut worst = 0.0f64;
    let mut largest = 0.0f64;
    for k in 0..501 {
        let d = depth(k);
        let c = [0, 1, 2].map(|i| p[i] + n[i] * (radius - d));
        est.step_with_tools(&[c], &inputs, &none).expect("step");
        let got = est.tool_contact(0).expect("tool").force;
        let want = reference.step(c, &f_ext).expect("reference step").force;
        if k % 100 == 50 {
            let t = est.tool_contact(0).unwrap();
            eprintln!(
                "k {k}: got {got:?} ({:?}, {} active) want {want:?}",
                t.status, t.active
            );
        }
        let mag = want.iter().map(|v| v * v).sum::<f64>().sqrt();
        largest = largest.max(mag);
        if mag > 0.05 {
            let err = (0..3)
                .map(|i| (got[i] - want[i]).powi(2))
                .sum::<f64>()
                .sqrt()
                / mag;
            worst = worst.max(err);
        }
    }
    eprintln!("largest reference force {largest:.4} N; worst relative force error {worst:.4}");
    assert!(
        worst < 0.02,
        "force within 2 % of the full order (measured {worst})"
    );
}

#[test]
fn a_press_pushes_back_within_its_bound_and_leaving_gives_zero_at_once() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let region = model.contact.as_ref().expect("contact region");
    let p = &region.rest_positions.data[0..3];
    let n = &region.normals.data[0..3];
    let radius = region.tool_radius;
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let at = |d: f64| [0, 1, 2].map(|i| p[i] + n[i] * (radius - d));
    for k in 1..=200 {
        est.step_with_tools(&[at(5e-4 * k as f64 / 200.0)], &inputs, &none)
            .expect("step");
        let t = est.tool_contact(0).expect("tool");
        let mag = t.force.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(mag.is_finite() && mag <= region.max_force * (1.0 + 1e-12));
    }
    let t = *est.tool_contact(0).expect("tool");
    // Pressed along the outward normal: the body pushes the tool outward.
    let along: f64 = (0..3).map(|i| t.force[i] * n[i]).sum();
    assert!(along > 0.0, "the force pushes the tool out ({:?})", t.force);
    assert!(t.active >= 1 && t.status != ContactStatus::Free);
    // Far away at once: no force at once.
    est.step_with_tools(&[at(-0.01)], &inputs, &none)
        .expect("step");
    let t = est.tool_contact(0).expect("tool");
    assert_eq!(t.force, [0.0; 3]);
    assert_eq!(t.status, ContactStatus::Free);
    assert!(est.contact_points().is_empty());
}

#[test]
fn bad_tools_are_refused_and_change_nothing() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let mut est = Estimator::new(&compiled.model).expect("estimator");
    let inputs = vec![0.0; compiled.model.inputs.len()];
    let none = vec![None; compiled.model.measurements.len()];
    let before = est.state().to_vec();
    let err = est
        .step_with_tools(&[[f64::NAN, 0.0, 0.0]], &inputs, &none)
        .unwrap_err();
    assert!(
        matches!(err, RuntimeError::NonFiniteTool { tool: 0, .. }),
        "{err}"
    );
    let err = est
        .step_with_tools(&[[0.0; 3]; 3], &inputs, &none)
        .unwrap_err();
    assert!(
        matches!(err, RuntimeError::TooManyTools { given: 3, .. }),
        "{err}"
    );
    assert_eq!(est.state(), &before[..]);
    assert_eq!(est.step_index(), 0);
}
