//! `crokf-compile identify` end to end on a small co-rotational beam (12×2×2 cells, the tier
//! of tests/tests/tier.rs): a recording whose force is a random walk of known σ, the command's
//! numbers and uncertainty, each refusal (exit 2, nothing written), and the written scene.
//!
//! `cargo test -p crokf-compile --test identify -- --nocapture` prints the figures.

use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;

use crokf_compile::identify::{identify, IdentifyError, IdentifyOptions, Recording, BLOCKS};
use crokf_compile::report::StageTimer;
use crokf_compile::scene::{ForceModel, SceneFile};
use crokf_compile::{compile, FullOrder};

#[path = "support/identify_beam.rs"]
mod identify_beam;
use identify_beam::{options, truth, write_beam, write_csv, FILTER_SIGMA, STEPS, TRUE_SIGMA};

/// The folder: beam.msh, scene.toml (σ_f stated, a comment line first), model.crokf, the
/// recordings; written once per test process.
fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("crokf-identify-{}", std::process::id()));
        let model = write_beam(&dir);
        // The recordings: a random-walk force of σ 0.5 N per step (seed 11), markers with the
        // scene's noise; the same with no force; the same force with twice the markers' noise.
        let model = &model;
        write_csv(
            &dir.join("walk.csv"),
            model,
            &truth(model, TRUE_SIGMA, 1.0, 11),
        );
        write_csv(&dir.join("held.csv"), model, &truth(model, 0.0, 1.0, 12));
        write_csv(
            &dir.join("noisy.csv"),
            model,
            &truth(model, TRUE_SIGMA, 2.0, 11),
        );
        dir
    })
}

fn model() -> crokf_formats::Model {
    crokf_runtime::load_model(dir().join("model.crokf")).unwrap()
}

fn full() -> FullOrder {
    FullOrder::build(&dir().join("scene.toml"), &mut StageTimer::default()).unwrap()
}

/// The test's options: 20 lags, the first 100 steps left out (the tier test's).
fn test_options() -> IdentifyOptions {
    IdentifyOptions {
        lags: 20,
        skip: 100,
        ..IdentifyOptions::default()
    }
}

/// `crokf-compile identify scene.toml model.crokf --measurements FILE ARGS…` in the folder:
/// (exit code, stdout, stderr).
fn command(measurements: &str, args: &[&str]) -> (i32, String, String) {
    let dir = dir();
    let out = Command::new(env!("CARGO_BIN_EXE_crokf-compile"))
        .current_dir(dir)
        .args(["identify", "scene.toml", "model.crokf", "--measurements"])
        .arg(measurements)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The truth's σ_f is recovered within twice the stated uncertainty (the standard error over
/// 4 blocks), and the uncertainty is informative (under 20 % of σ_f); the markers' factor
/// is within 20 % of 1; the scene's σ and the filter's are the stated 0.05 N; the blocks
/// cover the steps after --skip without overlap.
#[test]
fn a_known_random_walk_is_recovered_within_its_uncertainty() {
    let model = model();
    let recording = Recording::read(&model, &dir().join("walk.csv"), None).unwrap();
    assert_eq!(recording.steps(), STEPS);
    let found = identify(&full(), &model, &recording, &test_options()).unwrap();
    print!("{}", found.report());
    let load = &found.loads[0];
    assert_eq!(load.name, "tip");
    assert!(load.stated);
    assert_eq!(load.scene_sigma, FILTER_SIGMA);
    assert_eq!(load.filter_sigma, FILTER_SIGMA);
    assert!(load.rate.is_none());
    let f = &load.force;
    assert_eq!(f.blocks.len(), BLOCKS);
    assert!(
        (f.value - TRUE_SIGMA).abs() <= 2.0 * f.uncertainty,
        "σ_f {} ± {} vs {TRUE_SIGMA}",
        f.value,
        f.uncertainty
    );
    assert!(
        f.uncertainty > 0.0 && f.uncertainty < 0.2 * TRUE_SIGMA,
        "{}",
        f.uncertainty
    );
    assert!(
        (found.markers.value - 1.0).abs() < 0.2,
        "{}",
        found.markers.value
    );
    assert_eq!(found.block_bounds, vec![100, 450, 800, 1150, 1500]);
    found.check().unwrap();
}

/// The command writes the scene with the identified σ_f: only the value and one comment line
/// differ from the scene; the written scene compiles and its σ_f is the one printed.
#[test]
fn the_written_scene_keeps_the_rest_and_compiles_with_the_identified_sigma() {
    let dir = dir();
    let out = dir.join("identified.toml");
    let _ = std::fs::remove_file(&out);
    let (code, stdout, stderr) = command(
        "walk.csv",
        &["--lags", "20", "--skip", "100", "-o", "identified.toml"],
    );
    println!("{stdout}{stderr}");
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("verdict: IDENTIFIED"), "{stdout}");
    assert!(stdout.contains("standard error over 4 disjoint blocks"));
    let original = std::fs::read_to_string(dir.join("scene.toml")).unwrap();
    let written = std::fs::read_to_string(&out).unwrap();
    // Byte for byte the scene but for the value and the comment above it.
    let (mut kept, mut comments, mut values) = (Vec::new(), 0, Vec::new());
    for line in written.split_inclusive('\n') {
        if line.starts_with("# identified by crokf-compile identify from walk.csv (1500 steps") {
            comments += 1;
            assert!(line.contains("standard error over 4 blocks"), "{line}");
        } else if let Some(v) = line.strip_prefix("force_noise_std = ") {
            values.push(v.trim().parse::<f64>().unwrap());
            kept.push(format!("force_noise_std = {FILTER_SIGMA:e}\n"));
        } else {
            kept.push(line.to_owned());
        }
    }
    assert_eq!((comments, values.len()), (1, 1));
    assert_eq!(kept.concat(), original);
    // The value is the identified σ to 4 digits.
    let model = model();
    let recording = Recording::read(&model, &dir.join("walk.csv"), None).unwrap();
    let found = identify(&full(), &model, &recording, &test_options()).unwrap();
    let sigma = found.loads[0].force.value;
    assert!(
        (values[0] / sigma - 1.0).abs() < 5e-4,
        "{} vs {sigma}",
        values[0]
    );
    assert!(stdout.contains(&format!("{sigma:.4e}")), "{stdout}");
    // It compiles, stating that σ.
    let scene = SceneFile::read(&out).unwrap();
    assert_eq!(scene.scene.loads[0].force_noise_std, values[0]);
    assert_eq!(
        scene.scene.loads[0].force_model_stated,
        Some(ForceModel::RandomWalk)
    );
    let c = compile(&out, &options()).unwrap();
    assert_eq!(c.model.tier.as_ref().unwrap().force_loads, vec![0]);
    let full = FullOrder::build(&out, &mut StageTimer::default()).unwrap();
    let (_, _, noise) =
        crokf_compile::model_file::tier::linearised_of_file(&full, &c.model, &full.noise).unwrap();
    assert_eq!(noise.groups[0].sigma, values[0]);
}

/// Refusals exit 2 with a message and write nothing (an output named after the recording:
/// the tests run in parallel).
fn refused(measurements: &str, args: &[&str], message: &str) {
    let name = format!("refused_{measurements}.toml");
    let out = dir().join(&name);
    let _ = std::fs::remove_file(&out);
    let mut all = args.to_vec();
    all.extend(["-o", &name]);
    let (code, stdout, stderr) = command(measurements, &all);
    println!("{stdout}{stderr}");
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert!(stderr.contains(message), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn a_recording_too_short_for_the_lags_is_refused() {
    // 1500 − 1250 = 250 steps after --skip, 30 lags need 300.
    refused(
        "walk.csv",
        &["--skip", "1250"],
        "too short: walk.csv has 1500 steps, 250 after --skip 1250; --lags 30 needs at least 300",
    );
    // Enough with 20 lags (200), but markers in fewer than 100 of them: a file with markers
    // every 4th step of the last 250.
    let text = std::fs::read_to_string(dir().join("walk.csv")).unwrap();
    let sparse: String = text
        .lines()
        .enumerate()
        .filter(|(i, _)| *i == 0 || *i <= 1250 || (i % 4 == 0) || *i == 1500)
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    std::fs::write(dir().join("sparse.csv"), sparse).unwrap();
    refused(
        "sparse.csv",
        &["--skip", "1250", "--lags", "20"],
        "sparse.csv has 63 steps with a marker value after --skip 1250, fewer than 100",
    );
}

#[test]
fn a_recording_without_load_changes_is_not_exciting_enough() {
    refused(
        "held.csv",
        &["--lags", "20", "--skip", "100"],
        "not exciting enough: every force σ is within 2 uncertainties of 0",
    );
}

#[test]
fn markers_noisier_than_the_scene_says_are_not_explained() {
    refused(
        "noisy.csv",
        &["--lags", "20", "--skip", "100"],
        "the linearised filters do not explain the innovations: the markers' factor",
    );
}

#[test]
fn a_scene_without_estimated_loads_is_refused() {
    let text = std::fs::read_to_string(dir().join("scene.toml"))
        .unwrap()
        .replace("force_model = \"random_walk\"", "force_model = \"white\"");
    let path = dir().join("white.toml");
    std::fs::write(&path, text).unwrap();
    let full = FullOrder::build(&path, &mut StageTimer::default()).unwrap();
    let model = model();
    let recording = Recording::read(&model, &dir().join("walk.csv"), None).unwrap();
    let e = identify(&full, &model, &recording, &test_options()).unwrap_err();
    assert!(matches!(e, IdentifyError::Model(_)), "{e:?}");
    assert!(e.to_string().contains("estimates no load"), "{e}");
}

#[test]
fn csv_errors_name_the_file_line_and_column() {
    let text = std::fs::read_to_string(dir().join("walk.csv")).unwrap();
    let bad: String = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 4 {
                let mut cells: Vec<&str> = l.split(',').collect();
                cells[2] = "abc";
                format!("{}\n", cells.join(","))
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    std::fs::write(dir().join("bad.csv"), bad).unwrap();
    refused(
        "bad.csv",
        &[],
        "bad.csv:5: `tip.y`: `abc` is not a finite number",
    );
}

#[test]
fn outputs_over_an_input_or_in_another_folder_are_refused() {
    let (code, _, stderr) = command("walk.csv", &["-o", "scene.toml"]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains("refusing to overwrite an input"),
        "{stderr}"
    );
    let other = std::env::temp_dir().join(format!("crokf-identify-other-{}", std::process::id()));
    std::fs::create_dir_all(&other).unwrap();
    let out = other.join("identified.toml");
    let (code, _, stderr) = command("walk.csv", &["-o", out.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(stderr.contains("into the scene's folder"), "{stderr}");
    assert!(!out.exists());
}

/// `--fixed-point`: the filters of the σ just identified until they agree to 1 %; the fixed
/// point's filter σ is its identified σ, still within twice the uncertainty of the truth.
#[test]
fn the_fixed_point_confirms_its_own_sigma() {
    let model = model();
    let recording = Recording::read(&model, &dir().join("walk.csv"), None).unwrap();
    let options = IdentifyOptions {
        fixed_point: true,
        ..test_options()
    };
    let full = full();
    let found = identify(&full, &model, &recording, &options).unwrap();
    print!("{}", found.report());
    let course = found.fixed_point.as_ref().unwrap();
    assert!(course.converged, "{course:?}");
    assert!(
        course.iterations > 1 && course.last_change < 0.01,
        "{course:?}"
    );
    let load = &found.loads[0];
    assert_eq!(load.scene_sigma, FILTER_SIGMA);
    assert!(
        (load.filter_sigma / load.force.value - 1.0).abs() < 0.01,
        "{load:?}"
    );
    assert!(
        (load.force.value - TRUE_SIGMA).abs() <= 2.0 * load.force.uncertainty,
        "{load:?}"
    );
    found.check().unwrap();
    // The fixed point varied a copy of the scene's noise: the scene's own is as it was.
    assert_eq!(full.scene.scene.loads[0].force_noise_std, FILTER_SIGMA);
    assert_eq!(
        full.noise.forces[0].sigma,
        crokf_compile::noise::ForceSigma::Stated(FILTER_SIGMA)
    );
}
