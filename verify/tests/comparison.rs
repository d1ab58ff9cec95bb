//! Speed against error (`crokf_verify::comparison`): the runtime against the full-order
//! references on a small generated beam, and the report's rendering.
//!
//! The beam: 1 m × 0.1 m × 0.1 m, 12 × 2 × 2 cells (288 tetrahedra, 324 free DOFs), E = 1 MPa,
//! clamped at x = 0, tip load on x = 1, sensors `tip` and `mid`, displayed: the whole surface.
//! The release-build figures of the committed report scenarios come from the ignored tests
//! at the end (`cargo test --release -p crokf-verify --test comparison -- --ignored
//! --nocapture`).

use std::path::{Path, PathBuf};

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_verify::comparison::{
    self, breakdown_rotation, rotation_sweep, Comparison, ComparisonError, ComparisonOptions,
    Gaussian, Progress, SweepPoint,
};

/// A fresh directory under the target's temporary directory.
fn case_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("comparison_{name}"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).expect("create test directory");
    dir
}

/// The beam scene with process noise `force_noise_std` (N per component) on the tip load and
/// the end sensor named `tip_name`.
fn scene_text(force_noise_std: f64, tip_name: &str) -> String {
    BeamScene {
        force_noise_std: Some(force_noise_std),
        sensors: vec![
            ("mid".into(), [0.5, 0.05, 0.09]),
            (tip_name.into(), [0.95, 0.05, 0.09]),
        ],
        displays: vec![
            ("surface".into(), "surface".into()),
            ("end".into(), "xmax".into()),
        ],
        dt: 0.005,
        ..BeamScene::default()
    }
    .toml()
}

/// Writes the beam scene and a scenario with a downward tip force `force` (N) ramped in over
/// 0.05 s, `steps` steps of 5 ms; returns (scene, scenario).
fn beam_case(name: &str, force: f64, steps: usize, force_noise_std: f64) -> (PathBuf, PathBuf) {
    beam_case_with(name, force, steps, force_noise_std, "tip")
}

/// [`beam_case`] with the end sensor named `tip_name`.
fn beam_case_with(
    name: &str,
    force: f64,
    steps: usize,
    force_noise_std: f64,
    tip_name: &str,
) -> (PathBuf, PathBuf) {
    let dir = case_dir(name);
    write_msh22(
        &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
        &dir.join("beam.msh"),
    )
    .expect("mesh");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, scene_text(force_noise_std, tip_name)).expect("scene");
    let scenario = dir.join("scenario.toml");
    std::fs::write(
        &scenario,
        format!(
            "steps = {steps}\n[[load]]\nname = \"tip\"\ntimes = [0.0, 0.05]\n\
             forces = [[0.0, 0.0, 0.0], [0.0, 0.0, {}]]\n",
            -force
        ),
    )
    .expect("scenario");
    (scene, scenario)
}

/// Runs a comparison, checking the progress reports (done ≤ total, phases in order).
fn run(scene: &Path, scenario: &Path, options: &ComparisonOptions) -> Comparison {
    let mut phases: Vec<String> = Vec::new();
    let mut progress = |p: Progress| {
        assert!(p.done <= p.total, "{p:?}");
        if phases.last().map(String::as_str) != Some(p.phase) {
            phases.push(p.phase.to_owned());
        }
    };
    let c = comparison::run(scene, scenario, options, None, &mut progress)
        .unwrap_or_else(|e| panic!("comparison failed: {e}"));
    eprintln!("{}", c.markdown());
    // The compiler's notes on the scene reach the report (the beam's static correction note).
    assert!(
        c.notes.iter().any(|n| n.contains("static correction")),
        "{:?}",
        c.notes
    );
    assert!(c.markdown().contains("Compiler notes on the scene"));
    let mut expected = vec![
        "linear FEM".to_owned(),
        "co-rotational FEM".to_owned(),
        "modal system".to_owned(),
    ];
    for r in &options.orders {
        for p in ["compile", "open loop", "filtered", "withheld", "timing"] {
            if p == "withheld" && options.withhold_loads {
                continue;
            }
            expected.push(format!("{p} r = {r}"));
            if (p == "filtered" || p == "withheld") && options.seeds >= 2 {
                expected.push(format!("draws {p} r = {r}"));
            }
        }
    }
    assert_eq!(phases, expected);
    c
}

/// Checks that `svg` is well-formed XML as far as tags go (every element closed, properly
/// nested, attributes quoted) and returns the number of elements with `class="marker"`.
fn check_svg(svg: &str) -> usize {
    let mut stack: Vec<String> = Vec::new();
    let mut markers = 0;
    let mut rest = svg.trim_start();
    assert!(rest.starts_with("<?xml"), "no XML declaration");
    let end = rest.find("?>").expect("unterminated XML declaration");
    rest = &rest[end + 2..];
    let mut roots = 0;
    while let Some(open) = rest.find('<') {
        let text = &rest[..open];
        assert!(
            !text.contains('>') && !text.contains('&')
                || text.contains("&amp;")
                || text.contains("&lt;"),
            "stray markup in text {text:?}"
        );
        let close = rest[open..].find('>').expect("unterminated tag") + open;
        let tag = &rest[open + 1..close];
        assert!(!tag.contains('<'), "'<' inside tag {tag:?}");
        assert_eq!(
            tag.matches('"').count() % 2,
            0,
            "unbalanced quotes in {tag:?}"
        );
        if let Some(name) = tag.strip_prefix('/') {
            let top = stack
                .pop()
                .unwrap_or_else(|| panic!("</{name}> closes nothing"));
            assert_eq!(top, name.trim(), "</{name}> closes <{top}>");
        } else {
            let name: String = tag
                .chars()
                .take_while(|c| !c.is_whitespace() && *c != '/')
                .collect();
            assert!(!name.is_empty(), "empty tag name in {tag:?}");
            if stack.is_empty() {
                roots += 1;
            }
            if tag.contains(r#"class="marker""#) {
                markers += 1;
            }
            if !tag.ends_with('/') {
                stack.push(name);
            }
        }
        rest = &rest[close + 1..];
    }
    assert!(stack.is_empty(), "unclosed elements {stack:?}");
    assert_eq!(roots, 1, "one root element");
    assert!(svg.contains("<svg"), "not an SVG");
    markers
}

/// Rows of the markdown's first table (lines starting with `|`, minus header and separator,
/// up to the first line that does not).
fn markdown_rows(md: &str) -> Vec<&str> {
    md.lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .collect()
}

/// Rows of the markdown's consistency table (the second table).
fn consistency_rows(md: &str) -> Vec<&str> {
    md.lines()
        .skip_while(|l| !l.starts_with("| r | loads"))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .collect()
}

#[test]
fn tiny_load_runtime_error_matches_compile_report_and_linear_reference() {
    // 1 mN: rotations ~1e-3°, so the co-rotational and linear references coincide and the
    // runtime's warping is a no-op; what is left is the reduction error the compiler measures.
    let (scene, scenario) = beam_case("tiny", 1e-3, 60, 0.05);
    let options = ComparisonOptions {
        orders: vec![4, 8],
        measure_compile_error: true,
        seeds: 1,
        ..ComparisonOptions::default()
    };
    let c = run(&scene, &scenario, &options);
    // One noise draw: no N-run table.
    assert!(c
        .reduced
        .iter()
        .all(|r| r.figures.ensemble.is_none() && r.figures.withheld_ensemble.is_none()));
    assert!(!c.markdown().contains("noise draws"));
    assert_eq!((c.dofs, c.tetrahedra, c.steps), (324, 288, 60));
    assert_eq!(c.tip.as_deref(), Some("tip"));
    assert!(
        c.max_rotation_deg > 0.0 && c.max_rotation_deg < 0.01,
        "{}",
        c.max_rotation_deg
    );
    // Geometric nonlinearity is first order in the load: 1 N gives ~5e-3 (sweep test below).
    assert!(
        c.linear.error > 0.0 && c.linear.error < 1e-4,
        "{}",
        c.linear.error
    );
    for row in &c.reduced {
        assert_eq!(row.order, row.requested_order);
        let step = row.compile_measured_errors["step"];
        let ratio = row.figures.runtime.error_vs_linear / step;
        assert!(
            (0.1..10.0).contains(&ratio),
            "r = {}: runtime error vs linear {:.3e}, compiler's step error {step:.3e}",
            row.order,
            row.figures.runtime.error_vs_linear
        );
        // Triangle inequality: the two references differ by c.linear.error (relative).
        assert!(
            (row.figures.runtime.error - row.figures.runtime.error_vs_linear).abs()
                <= 2.0 * c.linear.error + 1e-12,
            "r = {}: {} vs {}",
            row.order,
            row.figures.runtime.error,
            row.figures.runtime.error_vs_linear
        );
        assert!(
            row.figures.runtime.step_s > 0.0 && row.figures.runtime.step_s < 1e-3,
            "{}",
            row.figures.runtime.step_s
        );
        assert!(
            row.figures.runtime.tip_error.is_finite()
                && row.figures.runtime.filtered_error.is_finite()
        );
    }
    assert!(
        c.reduced[1].figures.runtime.error < 0.5 * c.reduced[0].figures.runtime.error,
        "error must fall with r: {} (r = 4) vs {} (r = 8)",
        c.reduced[0].figures.runtime.error,
        c.reduced[1].figures.runtime.error
    );
    assert!(c.corotational.step_s > c.linear.step_s);

    // Rendering: one row per model and order, a well-formed SVG with one marker per point.
    let md = c.markdown();
    let rows = markdown_rows(&md);
    assert_eq!(rows.len(), 2 + 2, "{md}");
    assert!(rows[0].starts_with("| co-rotational FEM"));
    assert!(rows[1].starts_with("| linear FEM"));
    assert!(rows[2].starts_with("| runtime | 4 |") && rows[3].starts_with("| runtime | 8 |"));
    for row in &rows {
        assert_eq!(row.matches('|').count(), 9, "8 columns: {row}");
    }
    // Consistency: one row with the loads given and one withheld per order, 7 columns.
    let rows = consistency_rows(&md);
    assert_eq!(rows.len(), 2 * 2, "{md}");
    for row in &rows {
        assert_eq!(row.matches('|').count(), 8, "7 columns: {row}");
    }
    let csv = c.csv();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 1 + 2 + 2, "{csv}");
    let width = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == width), "{csv}");
    let r8: Vec<&str> = lines[4].split(',').collect();
    assert_eq!(r8[0], "runtime");
    assert_eq!(r8[1], "8");
    let error: f64 = r8[5].parse().expect("error column");
    assert!((error - c.reduced[1].figures.runtime.error).abs() <= 1e-12 * error);
    let svg = c.svg();
    assert_eq!(check_svg(&svg), 2 * 2 + 2, "{svg}");
}

#[test]
fn filter_tracks_a_withheld_load_from_the_measurements() {
    // The filter gets no load input; the 1 N tip force is process noise of 1 N per component
    // to it, and it follows the co-rotational reference through the noisy sensors. The open
    // loop still gets the loads: without inputs or measurements it would stay at rest, an
    // error of exactly 1 flagged "worse than linear FEM" that says nothing of the model.
    // The end sensor is not called `tip`: the report picks the sensor that moves most.
    let (scene, scenario) = beam_case_with("withheld", 1.0, 60, 1.0, "end_marker");
    let options = ComparisonOptions {
        orders: vec![8],
        withhold_loads: true,
        ..ComparisonOptions::default()
    };
    let c = run(&scene, &scenario, &options);
    assert_eq!(c.tip.as_deref(), Some("end_marker"));
    let row = &c.reduced[0];
    let given = comparison::run(
        &scene,
        &scenario,
        &ComparisonOptions {
            withhold_loads: false,
            seeds: 1,
            ..options.clone()
        },
        None,
        &mut |_| {},
    )
    .expect("comparison with the loads given");
    // The same open loop as with the loads given, bit for bit, and the model's (small) error.
    let open = &given.reduced[0].figures.runtime;
    assert_eq!(row.figures.runtime.error, open.error);
    assert_eq!(row.figures.runtime.tip_error, open.tip_error);
    assert!(
        row.figures.runtime.error < 0.05,
        "{}",
        row.figures.runtime.error
    );
    // At this small rotation the linear FEM is closer than the order-8 reduction, and the flag
    // says so (it was on every row, at error 1, before).
    let md = c.markdown();
    assert_eq!(
        md.contains("worse than linear FEM"),
        row.figures.runtime.error > c.linear.error,
        "{md}"
    );
    assert!(!md.contains("| 1.00e0 |"), "{md}");
    assert!(md.contains("the open-loop rows ran with the scenario's loads"));
    assert!(
        row.figures.runtime.filtered_error < 0.3,
        "filtered {}",
        row.figures.runtime.filtered_error
    );
    assert!(
        row.figures.runtime.filtered_tip_error < 0.3,
        "filtered tip {}",
        row.figures.runtime.filtered_tip_error
    );
    // Another seed gives another noise draw but a similar error.
    let other = comparison::run(
        &scene,
        &scenario,
        &ComparisonOptions {
            seed: 7,
            ..options.clone()
        },
        None,
        &mut |_| {},
    )
    .expect("comparison");
    let f2 = other.reduced[0].figures.runtime.filtered_error;
    assert!(
        f2 != row.figures.runtime.filtered_error
            && (f2 / row.figures.runtime.filtered_error - 1.0).abs() < 0.5,
        "{f2}"
    );
}

#[test]
fn nis_and_coverage_hold_when_the_model_is_right_and_fail_when_it_is_not() {
    // 0.01 N on the tip (rotation ≈ 0.05°): the warped reduced model is within its truncation
    // error of the co-rotational reference, so the innovations are what the filter predicts
    // (docs/design.md §11): ANIS inside its 95 % χ² bounds, ≥ 85 % of the displayed-node
    // errors inside ±2σ. At 20 N (the warping error dominates, ~40° here) the same filter is
    // over-confident and the statistics say so.
    let options = ComparisonOptions {
        orders: vec![8],
        timing_samples: 3,
        ..ComparisonOptions::default()
    };
    let (scene, scenario) = beam_case("consistent", 0.01, 200, 0.01);
    let c = run(&scene, &scenario, &options);
    let row = &c.reduced[0];
    let nis = row.figures.consistency.nis;
    let (lo, hi) = nis.bounds();
    eprintln!(
        "small load: ANIS {:.3} [{lo:.3}, {hi:.3}], D = {}, coverage {:.3} / {:.3}, ANEES {:.3}",
        nis.mean(),
        nis.dof,
        row.figures.consistency.coverage_runtime,
        row.figures.consistency.coverage_world,
        row.figures.consistency.nees_tip.mean()
    );
    assert_eq!(nis.dof, 200 * 6, "two sensors × 3 components × 200 steps");
    assert!(nis.inside(), "ANIS {} outside [{lo}, {hi}]", nis.mean());
    assert!(
        (0.85..=1.0).contains(&row.figures.consistency.coverage_world),
        "coverage {}",
        row.figures.consistency.coverage_world
    );
    assert_eq!(row.figures.consistency.tip.len(), 200);
    assert!(row.figures.withheld_consistency.nis.dof > 0);
    // The N-run test over the default 20 noise draws (docs/design.md §11.3) agrees.
    for e in [&row.figures.ensemble, &row.figures.withheld_ensemble] {
        let e = e.as_ref().expect("20 noise draws by default");
        assert_eq!((e.draws(), e.errors.len()), (20, 20));
        let f = e.nis.fractions();
        eprintln!("small load, 20 draws: NIS steps {f:?}");
        assert_eq!(f.steps, 200);
        assert!(f.inside > 0.85, "{f:?}");
        assert_eq!(comparison::verdict(&f), "consistent");
        // Per segment (the ramp to 0.05 s, the hold): the steps and the fractions add up to
        // the whole run's, and the NIS is consistent in each; the coverage is the run's mean.
        assert_eq!(c.segments.len(), 2, "{:?}", c.segments);
        let segments = comparison::segments::segment_figures(e, &c.segments);
        assert_eq!(
            segments.iter().map(|s| s.nis.steps).collect::<Vec<_>>(),
            vec![11, 189]
        );
        for (part, whole) in [
            (segments.iter().map(|s| s.nis).collect::<Vec<_>>(), f),
            (
                segments.iter().map(|s| s.nees_tip).collect(),
                e.nees_tip.fractions(),
            ),
        ] {
            let above: f64 = part.iter().map(|p| p.above * p.steps as f64).sum();
            assert!((above - whole.above * whole.steps as f64).abs() < 1e-9);
        }
        assert!(segments.iter().all(|s| s.nis.inside > 0.8), "{segments:?}");
        let covered: f64 = segments
            .iter()
            .map(|s| s.coverage * s.segment.steps.len() as f64)
            .sum::<f64>()
            / 200.0;
        let mean = comparison::spread(&e.coverage).expect("draws").0;
        assert!((covered - mean).abs() < 1e-12, "{covered} vs {mean}");
    }
    let md = c.markdown();
    // The per-segment table of the row: the ramp and the hold, for both runs.
    for (loads, segment) in [
        ("given", "| 0–0.05 s: load rises 0 N → 0.01 N | 11 |"),
        ("withheld", "| 0.05–1 s: load holds at 0.01 N | 189 |"),
    ] {
        assert!(md.contains(&format!("\n| {loads} {segment}")), "{md}");
    }
    let table: Vec<&str> = md
        .lines()
        .skip_while(|l| !l.contains("noise draws"))
        .filter(|l| l.starts_with("| 8 |"))
        .collect();
    assert_eq!(table.len(), 2, "{md}");
    assert!(
        table.iter().all(|l| l.matches('|').count() == 8),
        "{table:?}"
    );
    let svg = c.tip_svg(0).expect("tip plot");
    assert_eq!(svg.matches(r#"class="band""#).count(), 3, "{svg}");
    assert_eq!(svg.matches(r#"class="error-withheld""#).count(), 3);
    check_svg(&svg);
    let csv = c.csv();
    let header = csv.lines().next().unwrap_or_default().split(',').count();
    assert!(csv.lines().all(|l| l.split(',').count() == header), "{csv}");

    let (scene, scenario) = beam_case("inconsistent", 20.0, 200, 0.01);
    let c = run(&scene, &scenario, &options);
    let nis = c.reduced[0].figures.consistency.nis;
    eprintln!("large load: ANIS {:.3}", nis.mean());
    assert!(nis.mean() > 2.0 * nis.bounds().1, "ANIS {}", nis.mean());
    let f = c.reduced[0]
        .figures
        .ensemble
        .as_ref()
        .expect("draws")
        .nis
        .fractions();
    eprintln!("large load, 20 draws: NIS steps {f:?}");
    assert!(f.above > 0.5, "{f:?}");
    assert_eq!(comparison::verdict(&f), "overconfident");
}

#[test]
fn chi_square_quantiles_match_tables() {
    // χ²(100): 74.22 (2.5 %), 129.56 (97.5 %); χ²(1000): 914.26, 1089.53.
    for (d, lo, hi) in [(100.0, 74.22, 129.56), (1000.0, 914.26, 1089.53)] {
        let q_lo = comparison::chi_square_quantile(d, -1.959_963_984_540_054);
        let q_hi = comparison::chi_square_quantile(d, 1.959_963_984_540_054);
        assert!((q_lo / lo - 1.0).abs() < 2e-3, "{d}: {q_lo} vs {lo}");
        assert!((q_hi / hi - 1.0).abs() < 2e-3, "{d}: {q_hi} vs {hi}");
    }
}

#[test]
fn rotation_sweep_scales_with_the_load() {
    let (scene, scenario) = beam_case("sweep", 1.0, 40, 0.05);
    let scales = [1e-3, 1.0, 30.0];
    let points = rotation_sweep(
        &scene,
        &scenario,
        8,
        &scales,
        &ComparisonOptions::default(),
        None,
        &mut |_| {},
    )
    .expect("sweep");
    eprintln!("{}", comparison::sweep_markdown(&points, 8));
    assert_eq!(points.len(), 3);
    // Small loads: rotation ∝ load, and the linear model's error ∝ load (first order).
    let rot = points[1].max_rotation_deg / points[0].max_rotation_deg;
    assert!((rot / 1e3 - 1.0).abs() < 0.02, "rotation ratio {rot}");
    let lin = points[1].linear_error / points[0].linear_error;
    assert!((lin / 1e3 - 1.0).abs() < 0.05, "linear error ratio {lin}");
    // Large load: the rotation grows, and so does the linear model's error and the warped
    // runtime's error; warping does better than no warping at all.
    assert!(points[2].max_rotation_deg > 10.0 * points[1].max_rotation_deg);
    assert!(points[2].linear_error > 10.0 * points[1].linear_error);
    assert!(points[2].open_loop_error > points[0].open_loop_error);
    assert!(points[2].open_loop_error < points[2].linear_error);
}

#[test]
fn breakdown_rotation_is_the_last_point_under_the_threshold() {
    let p = |max_rotation_deg, open_loop_error| SweepPoint {
        scale: 1.0,
        max_rotation_deg,
        open_loop_error,
        tip_error: 0.0,
        linear_error: 0.0,
        tier: None,
    };
    // Unsorted on purpose; the 40° point fails 5 % but passes 10 %, 60° fails both, and the
    // 80° point back under 5 % must not count (the first failure ends the range).
    let points = [
        p(60.0, 0.2),
        p(10.0, 0.01),
        p(40.0, 0.07),
        p(80.0, 0.01),
        p(25.0, 0.03),
    ];
    assert_eq!(breakdown_rotation(&points, 0.05), Some(25.0));
    assert_eq!(breakdown_rotation(&points, 0.10), Some(40.0));
    assert_eq!(breakdown_rotation(&points, 0.005), None);
    assert_eq!(breakdown_rotation(&[], 0.05), None);
}

#[test]
fn gaussian_samples_have_unit_variance() {
    let mut g = Gaussian::new(42);
    let n = 200_000;
    let samples: Vec<f64> = (0..n).map(|_| g.normal()).collect();
    let mean = samples.iter().sum::<f64>() / n as f64;
    let var = samples.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let within_one = samples.iter().filter(|z| z.abs() < 1.0).count() as f64 / n as f64;
    // σ of the mean estimate 1/√n ≈ 2.2e-3, of the variance √(2/n) ≈ 3.2e-3.
    assert!(mean.abs() < 0.01, "mean {mean}");
    assert!((var - 1.0).abs() < 0.015, "variance {var}");
    assert!(
        (within_one - 0.682_689).abs() < 0.005,
        "P(|z| < 1) = {within_one}"
    );
    // Deterministic per seed; seed 0 is usable.
    let mut a = Gaussian::new(42);
    assert_eq!(a.normal(), samples[0]);
    let mut z = Gaussian::new(0);
    let u = z.uniform();
    assert!(u > 0.0 && u <= 1.0);
}

#[test]
fn a_steady_scenario_and_bad_orders_are_refused() {
    let (scene, scenario) = beam_case("refused", 1.0, 10, 0.05);
    let steady = scenario.with_file_name("steady.toml");
    std::fs::write(
        &steady,
        "steady = { tolerance = 1e-6, max_steps = 100 }\n[[load]]\nname = \"tip\"\n\
         times = [0.0]\nforces = [[0.0, 0.0, -1.0]]\n",
    )
    .expect("scenario");
    let err = comparison::run(
        &scene,
        &steady,
        &ComparisonOptions::default(),
        None,
        &mut |_| {},
    )
    .expect_err("steady scenario");
    let msg = err.to_string();
    assert!(matches!(err, ComparisonError::Invalid { .. }), "{msg}");
    assert!(
        msg.contains("steady.toml") && msg.contains("duration"),
        "{msg}"
    );
    let err = comparison::run(
        &scene,
        &scenario,
        &ComparisonOptions {
            orders: vec![4, 0],
            ..ComparisonOptions::default()
        },
        None,
        &mut |_| {},
    )
    .expect_err("order 0");
    assert!(err.to_string().contains("orders"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Release-build reports of the committed scenarios (slow: run with --release --ignored).

fn models() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    dir.canonicalize().unwrap_or(dir)
}

/// Runs the report, writes `target/tmp/report_<name>.{md,csv,svg}` and prints the markdown.
fn report(name: &str, scene: &Path, scenario: &Path) -> Comparison {
    let mut last = String::new();
    let c = comparison::run(
        scene,
        scenario,
        &ComparisonOptions::default(),
        None,
        &mut |p| {
            if p.phase != last {
                eprintln!("  {} …", p.phase);
                last = p.phase.to_owned();
            }
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    for (ext, text) in [("md", c.markdown()), ("csv", c.csv()), ("svg", c.svg())] {
        let path = dir.join(format!("report_{name}.{ext}"));
        std::fs::write(&path, text).expect("write report");
        eprintln!("wrote {}", path.display());
    }
    println!("{}", c.markdown());
    println!("{}", c.csv());
    assert_eq!(check_svg(&c.svg()), 2 * c.reduced.len() + 2);
    c
}

#[test]
#[ignore = "release-build report: cargo test --release -p crokf-verify --test comparison -- --ignored --nocapture"]
fn report_cantilever() {
    let dir = models().join("cantilever");
    let c = report(
        "cantilever",
        &dir.join("scene.toml"),
        &dir.join("scenario_report.toml"),
    );
    assert!(c.max_rotation_deg >= 60.0, "{}", c.max_rotation_deg);
}

#[test]
#[ignore = "release-build report: cargo test --release -p crokf-verify --test comparison -- --ignored --nocapture"]
fn report_meniscus() {
    let dir = models().join("meniscus");
    report(
        "meniscus",
        &dir.join("scene.toml"),
        &dir.join("scenario_report.toml"),
    );
}

#[test]
#[ignore = "release-build sweep: cargo test --release -p crokf-verify --test comparison -- --ignored --nocapture"]
fn sweep_cantilever() {
    // The report scenario (20 N tip force ramped over 0.5 s, 1.5 s) scaled from 1 N to 20 N.
    let dir = models().join("cantilever");
    let scales = [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0];
    let order = 16;
    let mut last = String::new();
    let points = rotation_sweep(
        &dir.join("scene.toml"),
        &dir.join("scenario_report.toml"),
        order,
        &scales,
        &ComparisonOptions::default(),
        None,
        &mut |p| {
            if p.phase != last {
                eprintln!("  {} …", p.phase);
                last = p.phase.to_owned();
            }
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let md = comparison::sweep_markdown(&points, order);
    println!("{md}");
    std::fs::write(
        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("sweep_cantilever.md"),
        &md,
    )
    .expect("write sweep");
    // The rotation grows with the load, and the warped runtime beats the linear FEM.
    for w in points.windows(2) {
        assert!(w[1].max_rotation_deg > w[0].max_rotation_deg);
    }
    assert!(points.iter().all(|p| p.open_loop_error < p.linear_error));
}

// ---------------------------------------------------------------------------------------------
// The co-rotational tier in the report

/// The tier's training block for the small beam: the tip load trained to 30 N (ramp to
/// 1.25×, step to 0.6×, 0.15 s runs, along the six axes), r = 10, ECSW to 1e-2 (as
/// tests/tests/tier.rs).
const TIER: &str = "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n\
    ranges = { tip = 30.0 }\nduration = 0.15\nevery = 2\norder = 10\necsw_tolerance = 1e-2\n\
    newton_tolerance = 1e-10\nnewton_iterations = 40\ndirections = \"axes\"\n";

/// The beam case `name` at `force` N over `steps` steps, and its tier scene beside it (the
/// same body, white force model, the [`TIER`] block), compiled once.
fn tier_case(name: &str, force: f64, steps: usize) -> (PathBuf, PathBuf, comparison::TierModel) {
    let (scene, scenario) = beam_case(name, force, steps, 0.05);
    let tier_scene = scene.with_file_name("scene_corotational.toml");
    std::fs::write(&tier_scene, scene_text(0.05, "tip") + TIER).expect("tier scene");
    let tier = comparison::compile_tier(&tier_scene, &mut |_| {})
        .unwrap_or_else(|e| panic!("tier compile: {e}"));
    (scene, scenario, tier)
}

#[test]
fn the_tier_is_a_row_and_beats_warping_at_large_rotation() {
    // 30 N ramped in over 0.05 s bends the coarse (stiff, locking) beam by about 14° within the
    // 0.15 s run: the warped row is 5 % off there, the tier stays at its training accuracy.
    let (scene, scenario, tier) = tier_case("tier_row", 30.0, 30);
    let options = ComparisonOptions {
        orders: vec![8],
        timing_samples: 3,
        ..ComparisonOptions::default()
    };
    let c = comparison::run(&scene, &scenario, &options, Some(&tier), &mut |_| {})
        .unwrap_or_else(|e| panic!("comparison: {e}"));
    let md = c.markdown();
    eprintln!("{md}");
    assert!(c.tier_failure.is_none(), "{:?}", c.tier_failure);
    assert!(c.max_rotation_deg > 10.0, "rotation {}", c.max_rotation_deg);
    let t = c.tier.as_ref().expect("tier row");
    let warped = &c.reduced[0];
    assert_eq!(t.basis_order, 10);
    assert!(t.sampled_elements > 0 && t.sampled_elements < c.tetrahedra);
    // The tier against the same reference as the warped row: below it, and below 2 %.
    assert!(
        t.figures.runtime.error < 0.5 * warped.figures.runtime.error
            && t.figures.runtime.error < 0.02,
        "tier {} vs warped {}",
        t.figures.runtime.error,
        warped.figures.runtime.error
    );
    assert!(
        t.figures.runtime.tip_error < warped.figures.runtime.tip_error,
        "{} vs {}",
        t.figures.runtime.tip_error,
        warped.figures.runtime.tip_error
    );
    assert!(t.figures.runtime.error < c.linear.error);
    // Filtered with the loads given: below the warped filter. Withheld: whatever the tier's
    // filter makes of the markers alone (it has no force states in this scene's white force
    // model), but a figure.
    assert!(
        t.figures.runtime.filtered_error < warped.figures.runtime.filtered_error,
        "{} vs {}",
        t.figures.runtime.filtered_error,
        warped.figures.runtime.filtered_error
    );
    assert!(t.figures.runtime.withheld_filtered_error.is_finite());
    assert!(t.figures.runtime.step_s > 0.0 && t.figures.runtime.step_s.is_finite());
    // Inside its envelope: 30 N against 37.5 N trained, and the runtime says so.
    assert!(!t.envelope.outside(), "{:?}", t.envelope);
    assert!(
        (t.envelope.max_load_ratio - 0.8).abs() < 1e-9,
        "{:?}",
        t.envelope
    );
    assert_eq!(t.envelope.steps, 30);
    // Rendering: a row in the table, two in the filter table, one CSV line, two stars.
    let rows = markdown_rows(&md);
    assert_eq!(rows.len(), 2 + 1 + 1, "{md}");
    assert!(
        rows[3].starts_with("| co-rotational tier | 10 POD, "),
        "{}",
        rows[3]
    );
    assert_eq!(rows[3].matches('|').count(), 9);
    let filter_rows = consistency_rows(&md);
    assert_eq!(filter_rows.len(), 2 + 2, "{md}");
    assert!(filter_rows[2].starts_with("| tier 10 POD") && filter_rows[2].contains("| given |"));
    let csv = c.csv();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 1 + 2 + 1 + 1, "{csv}");
    let width = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == width), "{csv}");
    let tier_line: Vec<&str> = lines[4].split(',').collect();
    assert_eq!(tier_line[0], "corotational_tier");
    let error: f64 = tier_line[5].parse().expect("error column");
    assert!((error - t.figures.runtime.error).abs() <= 1e-12 * error);
    let svg = c.svg();
    assert_eq!(check_svg(&svg), 2 + 2 + 2, "{svg}");
    assert!(svg.contains("co-rotational tier, open loop"));

    // `--withhold-loads`: the filters get no loads, the open loops still do, so the open-loop
    // figures and the tier's envelope are those of the run above, not of a body at rest
    // (error 1, "worse than linear FEM", "largest load ratio 0.00").
    let withheld = comparison::run(
        &scene,
        &scenario,
        &ComparisonOptions {
            withhold_loads: true,
            seeds: 1,
            ..options.clone()
        },
        Some(&tier),
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("comparison, loads withheld: {e}"));
    let wt = withheld.tier.as_ref().expect("tier row");
    assert_eq!(wt.figures.runtime.error, t.figures.runtime.error);
    assert_eq!(
        withheld.reduced[0].figures.runtime.error,
        warped.figures.runtime.error
    );
    assert_eq!(wt.envelope, t.envelope);
    assert_eq!(
        wt.figures.runtime.filtered_error,
        t.figures.runtime.withheld_filtered_error
    );
    let wmd = withheld.markdown();
    assert!(wmd.contains("(largest load ratio 0.80, "), "{wmd}");
    assert_eq!(
        wmd.contains("worse than linear FEM"),
        md.contains("worse than linear FEM"),
        "{wmd}"
    );
}

#[test]
fn a_tier_of_another_body_is_refused_before_any_run() {
    let (_, _, tier) = tier_case("tier_other", 1.0, 4);
    // The same beam with its end sensor named differently: not the tier's body.
    let (scene, scenario) = beam_case_with("tier_other_scene", 1.0, 4, 0.05, "end_marker");
    let mut ran = false;
    let err = comparison::run(
        &scene,
        &scenario,
        &ComparisonOptions::default(),
        Some(&tier),
        &mut |_| ran = true,
    )
    .expect_err("another body");
    let msg = err.to_string();
    assert!(!ran, "a reference ran before the check");
    assert!(
        msg.contains("scene_corotational.toml") && msg.contains("end_marker"),
        "{msg}"
    );
}

#[test]
fn the_sweep_table_marks_points_beyond_the_training_envelope() {
    use comparison::{breakdown_rotation_of, EnvelopeSummary, TierPoint};
    let envelope = |load: f64| EnvelopeSummary {
        steps_outside: usize::from(load > 1.0) * 10,
        steps: 10,
        max_load_ratio: load,
        max_state_ratio: load,
        state_margin: 1.5,
        newton_iterations: 20,
    };
    let point = |scale: f64, rotation: f64, tier: f64, load: f64| SweepPoint {
        scale,
        max_rotation_deg: rotation,
        open_loop_error: rotation / 500.0,
        tip_error: rotation / 500.0,
        linear_error: rotation / 100.0,
        tier: Some(TierPoint::Ran {
            open_loop_error: tier,
            tip_error: tier,
            envelope: envelope(load),
        }),
    };
    let points = [
        point(0.5, 10.0, 0.001, 0.4),
        point(1.0, 20.0, 0.015, 0.8),
        point(2.0, 40.0, 0.03, 1.6),
        point(4.0, 60.0, 0.2, 3.2),
    ];
    let tier_error = |p: &SweepPoint| p.tier.as_ref().map_or(f64::NAN, TierPoint::open_loop_error);
    assert_eq!(breakdown_rotation_of(&points, 0.02, tier_error), Some(20.0));
    assert_eq!(breakdown_rotation_of(&points, 0.05, tier_error), Some(40.0));
    let md = comparison::sweep_markdown(&points, 16);
    eprintln!("{md}");
    let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| ")).skip(1).collect();
    assert_eq!(rows.len(), 4);
    assert!(rows[1].contains("| inside (0.80, 0.80) |"), "{}", rows[1]);
    assert!(
        rows[2].contains("**outside** (10 of 10 steps)"),
        "{}",
        rows[2]
    );
    assert!(md.contains("co-rotational tier open-loop error < 2 % up to 20.0° of rotation\n"));
    assert!(md.contains(
        "co-rotational tier open-loop error < 5 % up to 40.0° of rotation (that point lies outside the training envelope)"
    ));
    // The warped runtime's lines are unchanged in form: < 5 % (rotation / 500) up to 20°.
    assert!(md.contains("\nopen-loop error < 5 % up to 20.0° of rotation"));
}

/// The figures of one filtered run of the tier, computed here by hand from the public
/// `Estimator` API and the model file's stored covariances (independently of
/// `comparison::ConsistencyAccumulator`): (Σ NIS, D_NIS, Σ NEES_tip, D_NEES, coverage).
struct HandConsistency {
    nis: f64,
    nis_dof: usize,
    nees: f64,
    nees_dof: usize,
    coverage: f64,
    /// Filters of the gain schedule used (after `predict` or after `update`).
    filters: std::collections::BTreeSet<usize>,
    /// Steps whose update ended on another filter than the prior's.
    switched_in_update: usize,
}

/// C P_qq Dᵀ (3×3, nalgebra) for the 3×r rows `c`, `d` and the leading r×r block of P (n×n).
fn q_block(c: &[f64], d: &[f64], r: usize, p: &crokf_formats::Matrix) -> nalgebra::Matrix3<f64> {
    let n = p.cols as usize;
    nalgebra::Matrix3::from_fn(|i, j| {
        (0..r)
            .flat_map(|k| (0..r).map(move |l| (k, l)))
            .map(|(k, l)| c[i * r + k] * p.data[k * n + l] * d[j * r + l])
            .sum()
    })
}

/// The tier's filtered run on `scene`/`scenario` as `comparison::run` makes it (the same
/// full-order co-rotational reference, the same seeded noise drawn per channel per step, the
/// loads given or withheld), with NIS, tip NEES and 2σ coverage computed by hand:
/// S = H P⁻ Hᵀ + R (m²) of the schedule's filter in use after `predict`, Σ_tip = V_tip P V_tipᵀ
/// of the one in use after `update` (docs/design.md §11.3, §11.5).
fn hand_consistency(
    scene: &Path,
    scenario: &Path,
    model: &crokf_formats::Model,
    seed: u64,
    withhold: bool,
) -> HandConsistency {
    use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
    let full =
        crokf_compile::FullOrder::build(scene, &mut crokf_compile::report::StageTimer::default())
            .expect("full order");
    let sc = crokf_verify::scenario::Scenario::read(scenario).expect("scenario");
    let ops = &full.operators;
    let fem = &full.fem;
    let dt = full.wilson.dt;
    let steps = match sc.horizon(dt) {
        crokf_verify::scenario::Horizon::Steps(k) => k,
        crokf_verify::scenario::Horizon::Steady(_) => panic!("fixed horizon"),
    };
    let tier = model.tier.as_ref().expect("tier");
    let r = tier.order as usize;
    // `Estimator::tier_filter`: level l's filter at schedule point i is l·P + i.
    let per_level = 1 + tier.scheduled.len();
    let kalman = |filter: usize| {
        let (level, point) = (filter / per_level, filter % per_level);
        match (level, point) {
            (0, 0) => &tier.kalman,
            (0, i) => &tier.scheduled[i - 1].kalman,
            (l, 0) => &tier.force_levels[l - 1].kalman,
            (l, i) => &tier.force_levels[l - 1].scheduled[i - 1],
        }
    };
    // Displayed nodes: the union of the node sets, first occurrence first.
    let mut seen = std::collections::HashSet::new();
    let display: Vec<(usize, usize, usize)> = ops
        .node_sets
        .iter()
        .enumerate()
        .flat_map(|(s, set)| set.nodes.iter().enumerate().map(move |(i, &n)| (s, i, n)))
        .filter(|&(_, _, n)| seen.insert(n))
        .collect();
    let tip = ops
        .sensors
        .iter()
        .position(|s| s.name == "tip")
        .expect("tip");
    let mut reference =
        CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default()).expect("sim");
    let mut est = crokf_runtime::Estimator::new(model).expect("estimator");
    est.set_innovation_gate(None);
    let mut rng = Gaussian::new(seed);
    let variance = &tier.kalman.measurement_variance;
    let period = tier.kalman.period.max(1) as usize;
    let nodal = |u: &[f64], node: usize, c: usize| fem.dofs.index[node][c].map_or(0.0, |d| u[d]);
    let mut out = HandConsistency {
        nis: 0.0,
        nis_dof: 0,
        nees: 0.0,
        nees_dof: 0,
        coverage: 0.0,
        filters: Default::default(),
        switched_in_update: 0,
    };
    let (mut inside, mut total) = (0usize, 0usize);
    let mut predicted = vec![0.0; model.measurements.len()];
    let mut sensors = vec![0.0; 3 * model.sensors.len()];
    for k in 0..steps {
        let t = k as f64 * dt;
        reference
            .step(&sc.load_vector(ops, fem.dof_count(), t))
            .expect("reference step");
        let u = reference.displacement();
        let truth: Vec<[f64; 3]> = ops
            .sensors
            .iter()
            .map(|s| {
                std::array::from_fn(|c| s.weights.iter().map(|&(n, w)| w * nodal(u, n, c)).sum())
            })
            .collect();
        // Measurements: one normal per channel per step, the phase's channels kept.
        let noise: Vec<f64> = variance.iter().map(|v| v.sqrt() * rng.normal()).collect();
        let mut y = vec![None; model.measurements.len()];
        for &j in &tier.kalman.phases[(k + 1) % period].measured {
            let ch = model.measurements[j as usize];
            y[j as usize] =
                Some(truth[ch.sensor as usize][ch.component as usize] + noise[j as usize]);
        }
        let mut inputs = sc.inputs_at(ops, t);
        if withhold {
            for (v, ch) in inputs.iter_mut().zip(&model.inputs) {
                if matches!(ch.kind, crokf_formats::InputKind::Load { .. }) {
                    *v = 0.0;
                }
            }
        }
        est.predict(&inputs).expect("predict");
        // NIS with the prior covariance of the filter the runtime's gate reads now.
        est.measurement_estimates(&mut predicted).expect("ŷ⁻");
        let prior_filter = est.tier_filter().expect("tier");
        let phase = &kalman(prior_filter).phases[est.phase()];
        let used: Vec<usize> = phase
            .measured
            .iter()
            .map(|&j| j as usize)
            .filter(|&j| y[j].is_some())
            .collect();
        let m = used.len();
        let s_mat = nalgebra::DMatrix::from_fn(m, m, |a, b| {
            let (ca, cb) = (model.measurements[used[a]], model.measurements[used[b]]);
            let block = q_block(
                &tier.sensor_rows[ca.sensor as usize].data,
                &tier.sensor_rows[cb.sensor as usize].data,
                r,
                &phase.prior_covariance,
            );
            block[(ca.component as usize, cb.component as usize)]
                + if a == b { variance[used[a]] } else { 0.0 }
        });
        let nu = nalgebra::DVector::from_fn(m, |a, _| y[used[a]].unwrap() - predicted[used[a]]);
        if m > 0 {
            out.nis += nu.dot(&(s_mat.try_inverse().expect("S⁻¹") * &nu));
            out.nis_dof += m;
        }
        est.update(&y).expect("update");
        // NEES at the tip and coverage with the posterior of the filter now in use.
        let filter = est.tier_filter().expect("tier");
        out.filters.extend([prior_filter, filter]);
        out.switched_in_update += usize::from(filter != prior_filter);
        let phase = &kalman(filter).phases[est.phase()];
        let rows = &tier.sensor_rows[tip].data;
        let sigma = q_block(rows, rows, r, &phase.posterior_covariance);
        est.sensor_displacements(&mut sensors).expect("sensors");
        let e = nalgebra::Vector3::from_fn(|c, _| sensors[3 * tip + c] - truth[tip][c]);
        out.nees += (e.transpose() * sigma.try_inverse().expect("Σ⁻¹") * e)[(0, 0)];
        out.nees_dof += 3;
        for &(set, i, node) in &display {
            let mut shown = vec![0.0; 3 * ops.node_sets[set].nodes.len()];
            let mut std = shown.clone();
            est.node_displacements(set, &mut shown).expect("nodes");
            est.node_std(set, &mut std).expect("σ");
            for c in 0..3 {
                let error = (shown[3 * i + c] - nodal(u, node, c)).abs();
                inside += usize::from(error <= 2.0 * std[3 * i + c]);
                total += 1;
            }
        }
    }
    out.coverage = inside as f64 / total as f64;
    out
}

#[test]
fn the_tier_rows_carry_consistency_from_the_tiers_own_filters() {
    // The beam at 30 N (≈ 14°) over 0.15 s, its tier with random-walk force states (0.5 N per
    // step) and a gain schedule: the tier's rows of the filter table get ANIS, tip ANEES and
    // 2σ coverage from its own stored filters, equal to a hand computation over the same run.
    let (scene, scenario) = beam_case("tier_consistency", 30.0, 30, 0.05);
    let tier_scene = scene.with_file_name("scene_corotational.toml");
    let text = scene_text(0.5, "tip").replace(
        "force_model = \"white\"\n",
        "force_model = \"random_walk\"\n",
    );
    assert!(text.contains("random_walk"), "{text}");
    std::fs::write(&tier_scene, text + TIER).expect("tier scene");
    let tier = comparison::compile_tier(&tier_scene, &mut |_| {})
        .unwrap_or_else(|e| panic!("tier compile: {e}"));
    let options = ComparisonOptions {
        orders: vec![8],
        timing_samples: 3,
        ..ComparisonOptions::default()
    };
    let c = comparison::run(&scene, &scenario, &options, Some(&tier), &mut |_| {})
        .unwrap_or_else(|e| panic!("comparison: {e}"));
    let md = c.markdown();
    eprintln!("{md}");
    let t = c.tier.as_ref().expect("tier row");
    assert_eq!(t.force_states, 3);
    assert!(t.filters > 1, "a gain schedule: {}", t.filters);
    for (label, ours, withhold) in [
        ("given", &t.figures.consistency, false),
        ("withheld", &t.figures.withheld_consistency, true),
    ] {
        let hand = hand_consistency(&scene, &scenario, &tier.model, options.seed, withhold);
        eprintln!(
            "tier, loads {label}: ANIS {:.6} (hand {:.6}, D = {}), tip ANEES {:.6} (hand {:.6}), \
             coverage {:.4} / {:.4} (hand {:.4}), > 5σ {}; filters used {:?}, {} updates \
             changed filter",
            ours.nis.mean(),
            hand.nis / hand.nis_dof as f64,
            ours.nis.dof,
            ours.nees_tip.mean(),
            hand.nees / hand.nees_dof as f64,
            ours.coverage_runtime,
            ours.coverage_world,
            hand.coverage,
            ours.outliers,
            hand.filters,
            hand.switched_in_update
        );
        // The schedule is exercised: the run goes through several of its filters.
        assert!(hand.filters.len() >= 2, "{:?}", hand.filters);
        // Two sensors × 3 components × 30 steps, all measured; 3 × 30 tip samples.
        assert_eq!((ours.nis.dof, hand.nis_dof), (180, 180));
        assert_eq!((ours.nees_tip.dof, hand.nees_dof), (90, 90));
        assert_eq!(ours.tip.len(), 30);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs();
        assert!(ours.nis.sum.is_finite() && close(ours.nis.sum, hand.nis));
        assert!(ours.nees_tip.sum.is_finite() && close(ours.nees_tip.sum, hand.nees));
        assert!(ours.coverage_runtime > 0.0 && ours.coverage_runtime <= 1.0);
        assert_eq!(ours.coverage_runtime, hand.coverage);
        // World frame: the stored-covariance σ and the runtime's read-out are the same σ.
        assert_eq!(ours.coverage_runtime, ours.coverage_world);
    }
    // Loads given: with the tier's own marker noise and its model error (0.8 % open loop) well
    // under it, the innovations are what its filter predicts: ANIS in [0.7, 1.5] (measured
    // 1.037; its 95 % bounds for D = 180 are [0.80, 1.22]). Withheld: the 30 N ramp over 10
    // steps is 3 N per step, 6× the force states' random-walk σ (0.5 N per step), so the
    // filter lags during the ramp and its innovations say so: ANIS above the upper bound
    // (measured 2.26), but not diverging (< 5).
    let anis = t.figures.consistency.nis.mean();
    assert!((0.7..=1.5).contains(&anis), "ANIS given {anis}");
    let anis = t.figures.withheld_consistency.nis.mean();
    let (_, hi) = t.figures.withheld_consistency.nis.bounds();
    assert!(anis > hi && anis < 5.0, "ANIS withheld {anis}");
    // Rendering: the tier's filter-table rows show the figures, the CSV line carries them,
    // and the tier has its own tip plot.
    let rows = consistency_rows(&md);
    assert_eq!(rows.len(), 2 + 2, "{md}");
    for (row, cons) in rows[2..]
        .iter()
        .zip([&t.figures.consistency, &t.figures.withheld_consistency])
    {
        let (lo, hi) = cons.nis.bounds();
        let anis = format!("| {:.3} [{lo:.3}, {hi:.3}]", cons.nis.mean());
        assert!(
            row.starts_with("| tier 10 POD") && row.contains(&anis),
            "{row}"
        );
        let coverage = format!(
            "{:.1} % / {:.1} % |",
            100.0 * cons.coverage_runtime,
            100.0 * cons.coverage_world
        );
        assert!(row.ends_with(&coverage), "{row}");
    }
    let csv = c.csv();
    let lines: Vec<&str> = csv.lines().collect();
    let header: Vec<&str> = lines[0].split(',').collect();
    let tier_line: Vec<&str> = lines
        .iter()
        .find(|l| l.starts_with("corotational_tier,"))
        .expect("tier line")
        .split(',')
        .collect();
    assert_eq!(tier_line.len(), header.len());
    let field = |name: &str| -> f64 {
        let i = header.iter().position(|h| *h == name).expect(name);
        tier_line[i]
            .parse()
            .unwrap_or_else(|_| panic!("{name}: {}", tier_line[i]))
    };
    assert!((field("anis") - t.figures.consistency.nis.mean()).abs() <= 1e-12 * field("anis"));
    assert!(
        (field("anees_tip") - t.figures.consistency.nees_tip.mean()).abs()
            <= 1e-12 * field("anees_tip")
    );
    assert_eq!(
        field("withheld_coverage_runtime"),
        t.figures.withheld_consistency.coverage_runtime
    );
    let svg = c.tier_tip_svg().expect("tier tip plot");
    check_svg(&svg);
    assert_eq!(svg.matches(r#"class="band""#).count(), 3, "{svg}");
    assert_eq!(svg.matches(r#"class="error-withheld""#).count(), 3);
    assert!(svg.contains("co-rotational tier 10 POD"), "{svg}");
}

/// `substeps`: the references stepped at Δt/N with each step's load held (the response
/// converged in time) show the Wilson-θ runtime's own step error, which the default
/// same-scheme references (Wilson-θ at Δt, the model's scheme) leave out.
#[test]
fn converged_references_show_the_time_steps_error() {
    let (scene, scenario) = beam_case("substeps", 1e-3, 60, 0.05);
    let at = |substeps| {
        let options = ComparisonOptions {
            orders: vec![8],
            seeds: 1,
            substeps,
            ..ComparisonOptions::default()
        };
        run(&scene, &scenario, &options)
    };
    let same = at(None);
    let converged = at(Some(16));
    assert_eq!((same.substeps, converged.substeps), (1, 16));
    assert!(same.markdown().contains("Wilson-θ at Δt: the same scheme"));
    assert!(converged
        .markdown()
        .contains("converged in time: Wilson-θ at Δt/16"));
    let (s, c) = (
        same.reduced[0].figures.runtime.error_vs_linear,
        converged.reduced[0].figures.runtime.error_vs_linear,
    );
    eprintln!("runtime r = 8 against the linear reference: same scheme {s:.3e}, converged {c:.3e}");
    // Measured: 1.26e-2 (the reduction's alone, r = 8) against 3.64e-2 with Wilson-θ's own
    // error at Δt = 5 ms on top; were the sub-steps ignored, both would be equal.
    assert!(c > 2.0 * s, "same scheme {s:.3e}, converged {c:.3e}");
}
