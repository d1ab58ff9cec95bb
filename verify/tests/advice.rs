//! The report's per-segment figures and its advice (`crokf_verify::comparison::{segments,
//! advice}`) end to end: a small beam whose scene states a deliberately wrong force σ, run
//! through `comparison::run` like `crokf-verify report`, and the lines it prints.
//!
//! The beam: 1 m × 0.1 m × 0.1 m, 12 × 2 × 2 cells (288 tetrahedra), E = 1 MPa, clamped at
//! x = 0, the tip load on x = 1 and sensors `mid` and `tip`, Δt = 5 ms; a small load (rotation
//! well under 1°: the warped model's own error is negligible), so the force σ is what is off.

use std::path::{Path, PathBuf};

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_verify::comparison::{self, Comparison, ComparisonOptions};

/// Writes the beam with a `random_walk` tip load of force σ `sigma` (N per step) and a scenario
/// of `steps` steps: the tip force ramped 0 → `force` N (downwards) over `ramp` s, then held;
/// returns (scene, scenario).
fn beam(name: &str, sigma: f64, force: f64, ramp: f64, steps: usize) -> (PathBuf, PathBuf) {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("advice_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .expect("mesh");
    let scene = dir.join("scene.toml");
    let text = BeamScene {
        force_noise_std: Some(sigma),
        force_model: Some("random_walk".into()),
        sensors: vec![
            ("mid".into(), [0.5, 0.05, 0.09]),
            ("tip".into(), [0.95, 0.05, 0.09]),
        ],
        displays: vec![("end".into(), "xmax".into())],
        sensor_noise_std: 1e-4,
        dt: 0.005,
        ..BeamScene::default()
    }
    .toml();
    std::fs::write(&scene, text).expect("scene");
    let scenario = dir.join("scenario.toml");
    std::fs::write(
        &scenario,
        format!(
            "steps = {steps}\n[[load]]\nname = \"tip\"\ntimes = [0.0, {ramp}]\n\
             forces = [[0.0, 0.0, 0.0], [0.0, 0.0, {}]]\n",
            -force
        ),
    )
    .expect("scenario");
    (scene, scenario)
}

fn report(scene: &Path, scenario: &Path) -> Comparison {
    let options = ComparisonOptions {
        orders: vec![8],
        withhold_loads: true,
        timing_samples: 3,
        ..ComparisonOptions::default()
    };
    let c = comparison::run(scene, scenario, &options, None, &mut |_| {})
        .unwrap_or_else(|e| panic!("comparison: {e}"));
    eprintln!("{}", c.markdown());
    c
}

/// The per-segment table's row of `segment` (its second column starts with it) for the run
/// `loads`: (steps, NEES % below, inside, above).
fn segment_row(md: &str, loads: &str, segment: &str) -> (usize, [f64; 3]) {
    let row = md
        .lines()
        .find(|l| l.starts_with(&format!("| {loads} | {segment}")))
        .unwrap_or_else(|| panic!("no segment row '{segment}' in\n{md}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let nees: Vec<f64> = cells[5]
        .split('/')
        .map(|v| v.trim().parse().expect("a percentage"))
        .collect();
    (
        cells[3].parse().expect("steps"),
        [nees[0], nees[1], nees[2]],
    )
}

#[test]
fn a_force_sigma_ten_times_too_small_is_told_to_shorten_the_rise_time() {
    // 0.1 mN per step against a load ramped by 1 mN per step (0.05 N over 50 steps): the
    // filter's force state lags the ramp and is still catching up long after, while the
    // warped model itself is within 0.4 % of the reference (open loop with the loads).
    let (scene, scenario) = beam("sigma_small", 1e-4, 0.05, 0.25, 200);
    let c = report(&scene, &scenario);
    assert_eq!(c.segments.len(), 2, "{:?}", c.segments);
    assert_eq!(
        (c.segments[0].steps.clone(), c.segments[1].steps.clone()),
        (0..51, 51..200)
    );
    let md = c.markdown();
    let (ramp_steps, ramp) = segment_row(&md, "withheld", "0–0.25 s: load rises 0 N → 0.05 N");
    let (hold_steps, hold) = segment_row(&md, "withheld", "0.25–1 s: load holds at 0.05 N");
    assert_eq!((ramp_steps, hold_steps), (51, 149));
    // The lag shows in the ramp and stays through the hold.
    assert!(ramp[2] > 30.0 && hold[2] > 90.0, "{ramp:?} {hold:?}");
    let row = &c.reduced[0].figures.runtime;
    assert!(row.error < 0.01, "the model's own error {}", row.error);
    assert!(
        row.filtered_error > 10.0 * row.error,
        "{}",
        row.filtered_error
    );
    let advice = c.advice();
    assert_eq!(advice.len(), 2, "{advice:#?}");
    assert!(
        advice[0].starts_with(
            "r = 8, loads withheld: the force σ is too small for how fast this load changes"
        ),
        "{}",
        advice[0]
    );
    for part in [
        "state a shorter `rise_time` on `[[load]]` 'tip'",
        "`crokf-compile identify SCENE MODEL --measurements M.csv [--inputs I.csv]`",
        "where the load holds; filtered error",
    ] {
        assert!(advice[0].contains(part), "{part}: {}", advice[0]);
    }
    assert!(
        advice[1].starts_with(
            "r = 8, loads withheld: the innovations are larger than the filter predicts"
        ),
        "{}",
        advice[1]
    );
    // The markers are drawn with the scene's noise_std: not "measure the markers' noise".
    assert!(
        !advice[1].contains("measure the markers' noise"),
        "{}",
        advice[1]
    );
    // What `crokf-verify report` prints (stdout and report.md).
    for line in &advice {
        assert!(md.contains(&format!("\n- {line}\n")), "{md}");
    }
}

#[test]
fn a_force_sigma_far_too_large_is_told_to_lengthen_the_rise_time() {
    // 0.1 N per step for the same 0.05 N load: the filter follows the markers alone; its σ
    // away from them covers nearly every error.
    let (scene, scenario) = beam("sigma_large", 0.1, 0.05, 0.25, 200);
    let c = report(&scene, &scenario);
    let e = c.reduced[0].figures.ensemble.as_ref().expect("20 draws");
    let coverage = e.coverage_in(0..c.steps);
    assert!(coverage > 0.98, "coverage {coverage}");
    let advice = c.advice();
    assert_eq!(advice.len(), 1, "{advice:#?}");
    assert!(
        advice[0].starts_with(
            "r = 8, loads withheld: σ away from the markers is larger than the error there"
        ),
        "{}",
        advice[0]
    );
    assert!(
        advice[0].contains(&format!("2σ coverage {:.1} % (> 98.0 %)", 100.0 * coverage))
            && advice[0].ends_with("(longer) `rise_time` or (smaller) `range` on `[[load]]` 'tip'"),
        "{}",
        advice[0]
    );
    assert!(c.markdown().contains(&format!("\n- {}\n", advice[0])));
}
