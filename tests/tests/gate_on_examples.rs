//! The runtime's guards on the committed example models: the plausibility
//! bounds derived at load time, and the default innovation gate (5σ) on the models' own
//! measurement noise — at rest, markers = N(0, σ²) of the scene's σ per channel for 1,000
//! steps — which must gate nothing.
//!
//! `cargo test -p crokf-tests --test gate_on_examples -- --nocapture` prints the figures.

use std::path::Path;

use crokf_formats::synthetic::SplitMix64;
use crokf_runtime::{load_model, Estimator, DEFAULT_GATE_SIGMAS};

#[test]
fn own_noise_is_never_gated_on_the_example_models() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for name in ["cantilever", "meniscus", "tentacle"] {
        let path = root.join("models").join(name).join("model.crokf");
        let model = load_model(&path).expect("committed model loads");
        let mut est = Estimator::new(&model).expect("estimator");
        assert_eq!(est.innovation_gate(), Some(DEFAULT_GATE_SIGMAS));
        let bounds = est.prepared().input_bounds().to_vec();
        let labels = model.input_labels();
        let per_input: Vec<String> = labels
            .iter()
            .zip(&bounds)
            .map(|(l, b)| format!("|{l}| ≤ {b:.3e}"))
            .collect();
        eprintln!(
            "{name}: plausibility bounds {} N, |y| ≤ {:.3e} m",
            per_input.join(", "),
            est.prepared().measurement_bound()
        );
        assert!(bounds.iter().all(|b| *b > 0.0));
        let sigma: Vec<f64> = model
            .kalman
            .measurement_variance
            .iter()
            .map(|v| v.sqrt())
            .collect();
        let u = vec![0.0; model.inputs.len()];
        let mut noise = SplitMix64(0x5eed);
        let mut y = vec![None; model.measurements.len()];
        for _ in 0..1000 {
            for (yj, s) in y.iter_mut().zip(&sigma) {
                *yj = Some(s * noise.normal());
            }
            est.step(&u, &y).expect("step");
        }
        eprintln!(
            "{name}: {} channels × 1,000 steps of its own noise: {} gated",
            y.len(),
            est.gated_total()
        );
        assert_eq!(est.gated_total(), 0, "{name}");
    }
}
