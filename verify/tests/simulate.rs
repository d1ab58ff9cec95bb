//! `crokf-verify simulate` and scenario files: the full-order steppers driven through scenarios.

use std::path::Path;

#[path = "../../compiler/tests/support/beam.rs"]
mod beam;
use beam::{model, norm, rel_diff, scene, tip_load};

use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::FemModel;
use crokf_compile::scene::Scene;
use crokf_compile::stepping::{static_solve, Formulation, NewtonOptions};
use crokf_verify::scenario::Scenario;
use crokf_verify::simulate::{
    probes, simulate, Frame, SimulateError, SimulationOptions, Trajectories,
};

fn scenario(text: &str) -> Scenario {
    Scenario::parse(text, Path::new("test-scenario.toml")).expect("scenario parses")
}

/// Runs a scenario; returns the trajectories and the final free-DOF displacement.
fn run_scenario(
    fem: &FemModel,
    ops: &Operators,
    sc: &Scene,
    scen: &Scenario,
    options: &SimulationOptions,
) -> (Trajectories, Vec<f64>) {
    let probes = probes(fem, ops, scen, 1.0, Path::new("test-scenario.toml")).unwrap();
    let mut last = Vec::new();
    let mut observer = |frame: &Frame| -> Result<(), SimulateError> {
        last = frame.displacement.to_vec();
        Ok(())
    };
    let t = simulate(
        fem,
        ops,
        sc,
        scen,
        &probes,
        options,
        Path::new("test-scenario.toml"),
        &mut observer,
    )
    .expect("simulation");
    (t, last)
}

/// Damped (α = 5/s, β = 10⁻⁴ s) linear Wilson-θ under a held load settles on K⁻¹f.
#[test]
fn linear_simulator_settles_on_the_static_solution() {
    let sc = scene(1.0e7, 0.3, 5.0, 1e-4, 0.01);
    let (_, fem, ops) = model([8, 1, 1], &sc);
    let scen = scenario(
        r#"
        steady = { tolerance = 1e-11, max_steps = 20000 }
        [[load]]
        name = "tip"
        times = [0.0, 0.2]
        forces = [[0.0, 0.0, 0.0], [0.2, 0.5, -1.0]]
        [[points]]
        name = "middle"
        position = [0.5, 0.05, 0.05]
        "#,
    );
    let (traj, u) = run_scenario(&fem, &ops, &sc, &scen, &SimulationOptions::default());
    let f = tip_load(&fem, &ops, [0.2, 0.5, -1.0]);
    let u_static = static_solve(&fem, &f).unwrap();
    let err = rel_diff(&u, &u_static);
    println!(
        "steady after {} steps ({:.1} s): ‖U − K⁻¹f‖/‖K⁻¹f‖ = {err:.2e}; {:.1} µs per step",
        traj.total_steps,
        traj.times.last().unwrap(),
        1e6 * traj.seconds_per_step
    );
    assert!(err < 1e-8, "steady state off the static solution: {err}");
    assert_eq!(traj.labels, ["tip_centre", "middle"]);
    // The recorded probes are the interpolated static displacement.
    let p = probes(&fem, &ops, &scen, 1.0, Path::new("s")).unwrap();
    for (probe, got) in p.iter().zip(traj.values.last().unwrap()) {
        let want = probe.displacement(&fem, &u_static);
        for c in 0..3 {
            assert!(
                (got[c] - want[c]).abs() < 1e-8 * norm(&want),
                "{}: {got:?} vs {want:?}",
                probe.name
            );
        }
    }
}

/// The same ramped tip load on the linear and co-rotational simulators: their trajectories
/// differ by O(rotation) — proportional to the load.
#[test]
fn corotational_and_linear_agree_for_tiny_loads() {
    let sc = scene(1.0e7, 0.3, 2.0, 1e-4, 0.005);
    let (_, fem, ops) = model([10, 2, 2], &sc);
    let mut diffs = Vec::new();
    for p in [1e-4, 1e-1] {
        let scen = scenario(&format!(
            r#"
            duration = 0.5
            [[load]]
            name = "tip"
            times = [0.0, 0.1]
            forces = [[0.0, 0.0, 0.0], [0.0, {}, {}]]
            "#,
            0.3 * p,
            -p
        ));
        let linear = run_scenario(&fem, &ops, &sc, &scen, &SimulationOptions::default()).0;
        let options = SimulationOptions {
            formulation: Formulation::Corotational,
            newton: NewtonOptions {
                tolerance: 1e-9,
                ..NewtonOptions::default()
            },
            every: 1,
        };
        let corot = run_scenario(&fem, &ops, &sc, &scen, &options).0;
        let flat = |t: &Trajectories| -> Vec<f64> {
            t.values.iter().flatten().flatten().copied().collect()
        };
        let (a, b) = (flat(&corot), flat(&linear));
        let diff = rel_diff(&a, &b);
        let peak = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let newton = corot.newton.unwrap();
        println!(
            "P = {p:.0e} N: peak tip displacement {peak:.3e} m ({:.1e} L), relative trajectory \
             difference {diff:.3e}; Newton {:.2} solves/step, {:.1} ms/step (linear {:.3} ms)",
            peak,
            newton.solves as f64 / newton.steps as f64,
            1e3 * corot.seconds_per_step,
            1e3 * linear.seconds_per_step
        );
        diffs.push((peak, diff));
    }
    let (small, large) = (diffs[0], diffs[1]);
    // Relative difference ~ rotation ~ displacement / L.
    assert!(small.1 < 10.0 * small.0 && small.1 < 1e-4, "{small:?}");
    let ratio = large.1 / small.1;
    assert!(
        ratio > 1e2 && ratio < 1e4,
        "difference does not scale with the load: {ratio}"
    );
}

// ---------------------------------------------------------------------------------------------
// Scenario files

#[test]
fn scenario_loads_are_piecewise_linear_and_held() {
    let s = scenario(
        r#"
        steps = 10
        [[load]]
        name = "tip"
        times = [1.0, 2.0, 4.0]
        forces = [[0, 0, 0], [2, -4, 6], [0, 0, 6]]
        "#,
    );
    let l = &s.loads[0];
    assert_eq!(l.at(0.0), [0.0, 0.0, 0.0]);
    assert_eq!(l.at(1.5), [1.0, -2.0, 3.0]);
    assert_eq!(l.at(2.0), [2.0, -4.0, 6.0]);
    assert_eq!(l.at(3.0), [1.0, -2.0, 6.0]);
    assert_eq!(l.at(9.0), [0.0, 0.0, 6.0]);
    assert_eq!(s.last_load_time(), 4.0);
    let sc = scene(1e7, 0.3, 0.0, 0.0, 0.5);
    let (_, fem, ops) = model([2, 1, 1], &sc);
    assert_eq!(s.inputs_at(&ops, 1.5), vec![1.0, -2.0, 3.0]);
    let f = s.load_vector(&ops, fem.dof_count(), 1.5);
    let sum: [f64; 3] = std::array::from_fn(|c| {
        fem.dofs
            .dofs
            .iter()
            .zip(&f)
            .filter(|((_, k), _)| *k == c)
            .map(|(_, v)| v)
            .sum()
    });
    assert!(
        (sum[0] - 1.0).abs() < 1e-12
            && (sum[1] + 2.0).abs() < 1e-12
            && (sum[2] - 3.0).abs() < 1e-12
    );
    assert_eq!(
        Scenario::parse("duration = 1.0", Path::new("d.toml"))
            .unwrap()
            .horizon(0.3),
        crokf_verify::scenario::Horizon::Steps(3)
    );
}

#[test]
fn scenario_errors_name_the_file_and_the_entry() {
    let err = |text: &str| {
        Scenario::parse(text, Path::new("bad-scenario.toml"))
            .unwrap_err()
            .to_string()
    };
    let e = err("steps = 3\ndurration = 1.0\n");
    assert!(
        e.contains("bad-scenario.toml") && e.contains("durration"),
        "{e}"
    );
    let e = err("steps = 3\nduration = 1.0\n");
    assert!(e.contains("exactly one"), "{e}");
    let e = err(
        "steps = 3\n[[load]]\nname = \"tip\"\ntimes = [0.0, 0.0]\nforces = [[0,0,0],[1,1,1]]\n",
    );
    assert!(e.contains("tip") && e.contains("increase"), "{e}");
    let e = err("steps = 3\n[[load]]\nname = \"tip\"\ntimes = [0.0]\nforces = [[0,0,0],[1,1,1]]\n");
    assert!(e.contains("equal length"), "{e}");
    // Against a scene: unknown load name, point outside the mesh.
    let sc = scene(1e7, 0.3, 0.0, 0.0, 0.5);
    let s = scenario("steps = 1\n[[load]]\nname = \"tipp\"\ntimes = [0.0]\nforces = [[0,0,1]]\n");
    let e = s
        .check_scene(&sc, Path::new("bad-scenario.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bad-scenario.toml") && e.contains("tipp") && e.contains("tip"),
        "{e}"
    );
    let (_, fem, ops) = model([2, 1, 1], &sc);
    let s = scenario("steps = 1\npoints = [{ name = \"far\", position = [2.0, 0.0, 0.0] }]\n");
    let e = probes(&fem, &ops, &s, 1.0, Path::new("bad-scenario.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bad-scenario.toml") && e.contains("far") && e.contains("outside"),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------------
// crokf-verify simulate

/// Checks that every opened XML tag is closed in order; returns the element names seen.
fn xml_elements(text: &str) -> Vec<String> {
    let mut stack: Vec<String> = Vec::new();
    let mut seen = Vec::new();
    let mut rest = text;
    while let Some(open) = rest.find('<') {
        let close = rest[open..].find('>').expect("unterminated tag") + open;
        let tag = &rest[open + 1..close];
        rest = &rest[close + 1..];
        if tag.starts_with('?') {
            continue;
        }
        if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(
                stack.pop().as_deref(),
                Some(name.trim()),
                "mismatched </{name}>"
            );
        } else {
            let name = tag
                .split_whitespace()
                .next()
                .unwrap()
                .trim_end_matches('/')
                .to_owned();
            seen.push(name.clone());
            if !tag.ends_with('/') {
                stack.push(name);
            }
        }
    }
    assert!(stack.is_empty(), "unclosed: {stack:?}");
    seen
}

#[test]
fn crokf_verify_simulate_writes_csv_and_a_vtu_series() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("crokf_verify_simulate");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mesh =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../compiler/tests/fixtures/cube_41_ascii.msh");
    let scene_path = dir.join("scene.toml");
    std::fs::write(
        &scene_path,
        format!(
            r#"
            [mesh]
            file = "{}"
            [[material]]
            group = "body"
            young_modulus = 1e5
            poisson_ratio = 0.3
            density = 1000.0
            [damping]
            alpha = 1.0
            [[fixed]]
            group = "bottom"
            [[load]]
            name = "push"
            group = "top"
            force_model = "white"
            [[sensor]]
            name = "top_centre"
            position = [0.5, 0.5, 1.0]
            noise_std = 1e-4
            [time]
            dt = 0.01
            "#,
            mesh.display()
        ),
    )
    .unwrap();
    let scenario_path = dir.join("scenario.toml");
    std::fs::write(
        &scenario_path,
        r#"
        steps = 10
        points = [{ name = "corner", position = [1.0, 1.0, 1.0] }]
        [[load]]
        name = "push"
        times = [0.0, 0.05]
        forces = [[0, 0, 0], [100, 0, -50]]
        "#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_crokf-verify");
    for model in ["linear", "corotational"] {
        let out = dir.join(model);
        let status = std::process::Command::new(exe)
            .args(["simulate"])
            .arg(&scene_path)
            .arg(&scenario_path)
            .args(["--model", model, "--vtu", "--every", "3", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&status.stdout);
        assert!(
            status.status.success(),
            "{model}: {stdout}\n{}",
            String::from_utf8_lossy(&status.stderr)
        );
        println!("{model}:\n{stdout}");
        let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "step,t,top_centre.ux,top_centre.uy,top_centre.uz,corner.ux,corner.uy,corner.uz"
        );
        let steps: Vec<&str> = lines[1..]
            .iter()
            .map(|l| l.split(',').next().unwrap())
            .collect();
        assert_eq!(steps, ["0", "3", "6", "9", "10"]);
        let last: Vec<f64> = lines[5]
            .split(',')
            .skip(2)
            .map(|v| v.parse().unwrap())
            .collect();
        assert!(
            last[0] > 0.0 && last[2] < 0.0,
            "top pushed +x, −z: {last:?}"
        );
        let pvd = std::fs::read_to_string(out.join("series.pvd")).unwrap();
        let names = xml_elements(&pvd);
        assert_eq!(names.iter().filter(|n| *n == "DataSet").count(), 5);
        let vtu = std::fs::read_to_string(out.join("frames/frame_0004.vtu")).unwrap();
        let names = xml_elements(&vtu);
        assert_eq!(
            names.iter().filter(|n| *n == "DataArray").count(),
            5,
            "{names:?}"
        );
        assert!(vtu.contains("NumberOfPoints=\"8\" NumberOfCells=\"6\""));
        assert!(!out.join("frames/frame_0005.vtu").exists());
    }
    // Errors name the file.
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "steps = 2\nwhen = 3\n").unwrap();
    let status = std::process::Command::new(exe)
        .arg("simulate")
        .arg(&scene_path)
        .arg(&bad)
        .arg("--out")
        .arg(dir.join("bad"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&status.stderr);
    assert!(!status.status.success());
    assert!(
        stderr.contains("bad.toml") && stderr.contains("when"),
        "{stderr}"
    );
}
