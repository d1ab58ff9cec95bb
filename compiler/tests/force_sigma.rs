//! Loads are estimated by default and their force σ is derived from what the scene states of
//! them (docs/design.md §11.8): the scene's rules for `range`, `rise_time`, `force_model` and
//! `force_noise_std`, and the derived σ of a compiled beam against the criterion it is derived
//! from (the lag on the fastest stated ramp within one σ) and against the scalar law
//! σ ∝ δ^(2/3) (δ the ramp's increment per step).

use std::path::Path;

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::scene::Scene;
use crokf_compile::{compile, CompileOptions};

/// The benchmark beam's scene with the tip load's lines replaced by `load_lines`.
fn beam_scene(load_lines: &str) -> String {
    let text = BeamScene {
        alpha: 2.0,
        force_noise_std: None,
        force_model: None,
        displays: vec![("end".into(), "xmax".into())],
        dt: 0.005,
        ..BeamScene::default()
    }
    .toml();
    text.replace(
        "[[load]]\nname = \"tip\"\ngroup = \"xmax\"\n",
        &format!("[[load]]\nname = \"tip\"\ngroup = \"xmax\"\n{load_lines}"),
    )
}

fn parse(text: &str) -> Result<Scene, String> {
    Scene::parse(text, Path::new("scene.toml")).map_err(|e| e.to_string())
}

#[test]
fn an_estimated_load_states_a_range_or_a_sigma() {
    // Nothing stated: the load is estimated by default and needs its range.
    let e = parse(&beam_scene("")).unwrap_err();
    assert!(
        e.contains("load 'tip'") && e.contains("range") && e.contains("rise_time"),
        "{e}"
    );
    // A range (rise time by default), a stated σ, or a told (white) load are all accepted.
    let s = parse(&beam_scene("range = 2.0\n")).unwrap();
    assert!(s.loads[0].is_estimated());
    assert_eq!(s.loads[0].rise_time(), 0.2);
    parse(&beam_scene(
        "force_model = \"random_walk\"\nforce_noise_std = 0.1\n",
    ))
    .unwrap();
    let s = parse(&beam_scene("force_model = \"white\"\n")).unwrap();
    assert!(!s.loads[0].is_estimated());
}

#[test]
fn the_former_white_default_is_not_reinterpreted_silently() {
    // force_noise_std without force_model meant white noise before: refused, naming both ways.
    let e = parse(&beam_scene("force_noise_std = 0.01\n")).unwrap_err();
    assert!(
        e.contains("force_noise_std without force_model")
            && e.contains("force_model = \"white\"")
            && e.contains("force_model = \"random_walk\""),
        "{e}"
    );
}

#[test]
fn range_and_rise_time_are_checked() {
    for (lines, what) in [
        ("range = 0.0\n", "range"),
        ("range = -1.0\n", "range"),
        ("range = 1e12\n", "range"),
        ("range = 1.0\nrise_time = 0.0\n", "rise_time"),
        ("range = 1.0\nrise_time = nan\n", "rise_time"),
        (
            "force_model = \"white\"\nrange = 1.0\nrise_time = 0.1\n",
            "rise_time is for estimated loads",
        ),
    ] {
        let e = parse(&beam_scene(lines)).unwrap_err();
        assert!(e.contains("load 'tip'") && e.contains(what), "{lines}: {e}");
    }
}

#[test]
fn the_tier_trains_on_the_loads_range_and_refuses_a_second_one() {
    let tier =
        "\n[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\nduration = 0.1\n";
    let s = parse(&(beam_scene("range = 3.0\n") + tier)).unwrap();
    let spec = s.reduction.corotational.as_ref().unwrap();
    assert_eq!(spec.ranges.get("tip"), Some(&3.0));
    // The same range twice is fine, two different ones are refused naming both.
    let twice = tier.replace("duration", "ranges = { tip = 3.0 }\nduration");
    parse(&(beam_scene("range = 3.0\n") + &twice)).unwrap();
    let differ = tier.replace("duration", "ranges = { tip = 4.0 }\nduration");
    let e = parse(&(beam_scene("range = 3.0\n") + &differ)).unwrap_err();
    assert!(
        e.contains("range = 3 N") && e.contains("ranges.tip = 4 N"),
        "{e}"
    );
    // The tier's range alone also states the load's range for the derivation.
    let only_tier = tier.replace("duration", "ranges = { tip = 4.0 }\nduration");
    let s = parse(&(beam_scene("") + &only_tier)).unwrap();
    assert_eq!(s.load_range(&s.loads[0]), Some(4.0));
}

/// Compiles the beam with `load_lines`; returns the compile notes' force-σ note's σ and lag.
fn derived(dir: &Path, load_lines: &str) -> (f64, f64) {
    let path = dir.join(format!("scene-{}.toml", load_lines.len()));
    std::fs::write(&path, beam_scene(load_lines)).unwrap();
    let compiled = compile(
        &path,
        &CompileOptions {
            order: Some(10),
            skip_measured_error: true,
            ..CompileOptions::default()
        },
    )
    .unwrap();
    let note = compiled
        .model
        .report
        .notes
        .iter()
        .find(|n| n.contains("load 'tip': force σ"))
        .unwrap_or_else(|| panic!("no force σ note: {:?}", compiled.model.report.notes))
        .clone();
    // "load 'tip': force σ S N per step, derived … the filter's steady lag on it is L of its own σ"
    let number = |after: &str| -> f64 {
        let rest = &note[note.find(after).unwrap() + after.len()..];
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    (number("force σ "), number("lag on it is "))
}

#[test]
fn the_derived_sigma_keeps_the_lag_within_one_sigma_and_scales_as_the_scalar_law() {
    let dir = std::env::temp_dir().join(format!("crokf-force-sigma-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .unwrap();
    let (s1, lag1) = derived(&dir, "range = 1.0\nrise_time = 0.2\n");
    let (s8, lag8) = derived(&dir, "range = 8.0\nrise_time = 0.2\n");
    let (s_slow, _) = derived(&dir, "range = 1.0\nrise_time = 1.6\n");
    for lag in [lag1, lag8] {
        assert!(lag <= 1.0 && lag > 0.9, "lag {lag} of its own σ");
    }
    // A linear filter's lag scales with the ramp: 8 × the range is 8 × δ, a σ 8^(2/3) = 4 ×
    // larger in the scalar law (λ = δ²σ_v/σ³); and δ depends on range / rise time only.
    assert!((s8 / s1 / 4.0 - 1.0).abs() < 0.25, "σ ratio {}", s8 / s1);
    assert!(
        (s1 / s_slow / 4.0 - 1.0).abs() < 0.25,
        "σ ratio {}",
        s1 / s_slow
    );
    let _ = std::fs::remove_dir_all(&dir);
}
