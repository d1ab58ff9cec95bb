//! The mode budget from the scene: `[reduction] max_frequency = f` keeps
//! every vibration mode up to 2f — more than the default cap of 60 when the spectrum asks for
//! it — and no mode above; the field is range-checked against Δt and exclusive with `modes`.

use std::path::{Path, PathBuf};

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::report::StageTimer;
use crokf_compile::scene::Scene;
use crokf_compile::{FullOrder, Reductor};

fn beam_dir(name: &str, extra: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("mode_budget_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    write_msh22(
        &box_mesh([12, 1, 1], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .expect("mesh");
    let text = BeamScene {
        dt: 1e-5,
        ..BeamScene::default()
    }
    .toml();
    std::fs::write(dir.join("scene.toml"), format!("{text}{extra}")).expect("scene");
    dir.join("scene.toml")
}

#[test]
fn max_frequency_keeps_every_mode_up_to_twice_it_beyond_the_default_cap() {
    // The spectrum, from an explicit count of every mode the check needs.
    let scene = beam_dir("spectrum", "");
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&scene, &mut timer).expect("front end");
    let all = Reductor::new(&full, Some(90), &mut timer).expect("modes");
    let f: Vec<f64> = all.basis.frequencies_hz[..all.basis.n_eigenmodes].to_vec();
    assert_eq!(f.len(), 90);
    // Halfway between modes 70 and 71 (1-based) at 2f: 70 modes expected, above the cap of 60.
    let max_frequency = 0.25 * (f[69] + f[70]);
    let scene = beam_dir(
        "budget",
        &format!("[reduction]\nmax_frequency = {max_frequency:e}\n"),
    );
    let full = FullOrder::build(&scene, &mut timer).expect("front end");
    let reductor = Reductor::new(&full, None, &mut timer).expect("modes");
    let kept = &reductor.basis.frequencies_hz[..reductor.basis.n_eigenmodes];
    println!(
        "max_frequency {max_frequency:.1} Hz: {} modes kept, highest {:.1} Hz (2f = {:.1} Hz)",
        kept.len(),
        kept[kept.len() - 1],
        2.0 * max_frequency
    );
    assert_eq!(kept.len(), 70);
    assert!(kept.iter().all(|&k| k <= 2.0 * max_frequency));
    for (a, b) in kept.iter().zip(&f) {
        assert!((a - b).abs() <= 1e-6 * b, "{a} vs {b}");
    }
}

#[test]
fn max_frequency_is_range_checked_and_exclusive_with_modes() {
    let base = BeamScene {
        dt: 1e-3,
        ..BeamScene::default()
    }
    .toml();
    let parse = |extra: &str| Scene::parse(&format!("{base}{extra}"), Path::new("s.toml"));
    assert!(parse("[reduction]\nmax_frequency = 250.0\n").is_ok());
    let err = parse("[reduction]\nmax_frequency = 251.0\n").expect_err("above 1/(4Δt)");
    assert!(err.to_string().contains("reduction.max_frequency"), "{err}");
    let err = parse("[reduction]\nmax_frequency = 0.0\n").expect_err("zero");
    assert!(err.to_string().contains("reduction.max_frequency"), "{err}");
    let err = parse("[reduction]\nmax_frequency = 10.0\nmodes = 5\n").expect_err("both");
    assert!(err.to_string().contains("not both"), "{err}");
}
