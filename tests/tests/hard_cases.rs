//! The hard-case suite of docs/design.md §7, in one place: every case either compiles with a stated
//! accuracy or is refused with a clear error whose text is asserted.
//!
//! Every case uses the same small cantilever: a box mesh 1 m × 0.1 m × 0.1 m, 12 × 2 × 2 cells
//! (288 linear tetrahedra, Kuhn subdivision), written as MSH 2.2 into a temporary directory,
//! clamped on `xmin` and loaded on `xmax`. Accuracy is the compiler's own measured error
//! (relative L2 of the reduced model against the full-order linear Wilson-θ reference over the
//! sensors and displayed nodes, step and chirp load histories, docs/design.md §7); stability is
//! ρ(F) < 1 and ρ((I − K H) F) < 1 with a relative Riccati residual below 1e-10.

use std::path::{Path, PathBuf};

use crokf_compile::mesh::procedural::{box_mesh, write_msh22};
use crokf_compile::mesh::Mesh;
use crokf_compile::{compile, CompileOptions, Compiled};

/// Box cells along x, y, z.
const CELLS: [usize; 3] = [12, 2, 2];
/// Box lengths along x, y, z, m.
const LENGTHS: [f64; 3] = [1.0, 0.1, 0.1];

/// A fresh directory for one case, unique per process.
fn case_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("crokf-hard-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    dir
}

/// Scene parameters varied by the cases; [`Params::default`] is the reference cantilever.
#[derive(Clone, Debug)]
struct Params {
    young_modulus: f64,
    poisson_ratio: f64,
    density: f64,
    alpha: f64,
    beta: f64,
    dt: f64,
    theta: f64,
    fixed: bool,
    mesh_file: String,
    /// `[[sensor]]` tables, verbatim.
    sensors: String,
}

/// A sensor on the top face near the tip, all three components, σ = 1 mm.
const TIP_SENSOR: &str = r#"
[[sensor]]
name = "tip"
position = [0.95, 0.05, 0.1]
components = ["x", "y", "z"]
noise_std = 1.0e-3
"#;

impl Default for Params {
    fn default() -> Self {
        Params {
            young_modulus: 1.0e6,
            poisson_ratio: 0.3,
            density: 1000.0,
            alpha: 0.5,
            beta: 1.0e-3,
            dt: 5.0e-3,
            theta: 1.4,
            fixed: true,
            mesh_file: "box.msh".into(),
            sensors: TIP_SENSOR.into(),
        }
    }
}

impl Params {
    /// The scene file text (schema: `compiler/src/scene.rs`).
    fn scene(&self) -> String {
        let fixed = if self.fixed {
            "[[fixed]]\ngroup = \"xmin\"\n"
        } else {
            ""
        };
        format!(
            r#"[mesh]
file = "{mesh}"
units = "m"

[[material]]
group = "body"
young_modulus = {e:e}
poisson_ratio = {nu}
density = {rho}

[damping]
alpha = {alpha}
beta = {beta:e}

{fixed}
[[load]]
name = "end"
group = "xmax"
distribution = "area"
force_model = "white"
force_noise_std = 0.01
{sensors}
[[display]]
name = "end"
group = "xmax"

[time]
dt = {dt:e}
theta = {theta}
"#,
            mesh = self.mesh_file,
            e = self.young_modulus,
            nu = self.poisson_ratio,
            rho = self.density,
            alpha = self.alpha,
            beta = self.beta,
            sensors = self.sensors,
            dt = self.dt,
            theta = self.theta,
        )
    }
}

/// Writes `mesh` (or the reference box) and the scene into `dir`; returns the scene path.
fn write_case(dir: &Path, params: &Params, mesh: Option<&Mesh>) -> PathBuf {
    let default_mesh;
    let mesh = match mesh {
        Some(m) => m,
        None => {
            default_mesh = box_mesh(CELLS, LENGTHS);
            &default_mesh
        }
    };
    write_msh22(mesh, &dir.join("box.msh")).expect("write mesh");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, params.scene()).expect("write scene");
    scene
}

/// Compiles the case `name` with `params`; the directory is removed afterwards.
fn run(name: &str, params: &Params, mesh: Option<&Mesh>) -> Result<Compiled, String> {
    let dir = case_dir(name);
    let scene = write_case(&dir, params, mesh);
    let out = compile(&scene, &CompileOptions::default()).map_err(|e| e.to_string());
    std::fs::remove_dir_all(&dir).ok();
    out
}

/// The compiled model's figures, for the messages and the README table.
fn figures(c: &Compiled) -> String {
    let r = &c.model.report;
    format!(
        "r = {}, modes = {}, ρ(F) = {:.9}, Riccati residual = {:.2e}, ρ_cl = {:.9}, \
         step = {:.3e}, chirp = {:.3e}, notes = {:?}",
        r.order,
        r.modes,
        r.spectral_radius,
        r.riccati_residual,
        r.closed_loop_spectral_radius,
        r.measured_errors.get("step").copied().unwrap_or(f64::NAN),
        r.measured_errors.get("chirp").copied().unwrap_or(f64::NAN),
        r.notes
    )
}

/// Asserts ρ(F) < 1, ρ_cl < 1, Riccati residual < 1e-10 and both measured errors < `bound`.
fn assert_stable_and_accurate(case: &str, c: &Compiled, bound: f64) {
    let r = &c.model.report;
    let f = figures(c);
    eprintln!("{case}: {f}");
    assert!(r.spectral_radius < 1.0, "{case}: {f}");
    assert!(r.closed_loop_spectral_radius < 1.0, "{case}: {f}");
    assert!(r.riccati_residual < 1e-10, "{case}: {f}");
    for test in ["step", "chirp"] {
        let e = r.measured_errors[test];
        assert!(
            e.is_finite() && e < bound,
            "{case}: {test} error {e:e} ≥ {bound:e}: {f}"
        );
    }
}

/// Signed volume of a tetrahedron, (mesh units)³: det[x₁−x₀, x₂−x₀, x₃−x₀] / 6.
fn signed_volume(x: [[f64; 3]; 4]) -> f64 {
    let e = |a: usize| [x[a][0] - x[0][0], x[a][1] - x[0][1], x[a][2] - x[0][2]];
    let (a, b, c) = (e(1), e(2), e(3));
    (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0]))
        / 6.0
}

/// The reference box with the corner node (lx, 0, 0) moved to (lx, hy (1 − ε), 0), hy = ly/ny.
///
/// That node belongs to exactly two tetrahedra of the corner cell. The one with nodes
/// (0,0,0), (1,0,0), (1,1,0), (1,1,1) (cell-local) has its opposite face in the plane through
/// the z axis and (hx, hy, 0): the move brings the node to ε of its distance from that face, so
/// its volume becomes ε × hx hy hz / 6. The other keeps its volume (the move is parallel to its
/// opposite face). ε = 0 puts the node onto node (1,1,0): zero volume.
fn box_with_sliver(epsilon: f64) -> Mesh {
    let mut mesh = box_mesh(CELLS, LENGTHS);
    let corner = CELLS[0]; // node index of (i, j, k) = (nx, 0, 0)
    assert_eq!(mesh.nodes[corner], [LENGTHS[0], 0.0, 0.0]);
    let hy = LENGTHS[1] / CELLS[1] as f64;
    mesh.nodes[corner][1] = hy * (1.0 - epsilon);
    mesh
}

/// Reads back the written mesh and returns (gmsh tag, volume) of the smallest |volume| element
/// and the mean volume, computed here independently of the compiler.
fn smallest_element(msh: &Path) -> (u64, f64, f64) {
    let mesh = crokf_compile::mesh::read_mesh(msh).expect("read back the mesh");
    let volumes: Vec<(u64, f64)> = mesh
        .tetrahedra
        .iter()
        .map(|t| (t.tag, signed_volume(t.nodes.map(|n| mesh.nodes[n]))))
        .collect();
    let mean = volumes.iter().map(|v| v.1).sum::<f64>() / volumes.len() as f64;
    let (tag, volume) = volumes
        .iter()
        .copied()
        .min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        .expect("tetrahedra");
    (tag, volume, mean)
}

/// Static tip deflection of the FE cantilever under a unit transverse (z) end load, divided by
/// Euler–Bernoulli's δ = F L³ / (3 E I), I = b h³ / 12 (which does not depend on ν).
fn deflection_ratio(poisson_ratio: f64) -> f64 {
    use crokf_compile::fem::operators::InputKind;
    let dir = case_dir(&format!("locking-{poisson_ratio}"));
    let params = Params {
        poisson_ratio,
        ..Params::default()
    };
    let scene = write_case(&dir, &params, None);
    let mut timer = crokf_compile::report::StageTimer::default();
    let full = crokf_compile::FullOrder::build(&scene, &mut timer).expect("build");
    std::fs::remove_dir_all(&dir).ok();
    let column = &full
        .operators
        .inputs
        .iter()
        .find(|c| matches!(c.kind, InputKind::Load { component: 2, .. }))
        .expect("load channel z")
        .column;
    let u = crokf_compile::stepping::static_solve(&full.fem, column).expect("static solve");
    let tip = full.mesh.group("xmax").expect("xmax").nodes.clone();
    let fem = &full.fem;
    let mean_w = tip
        .iter()
        .map(|&n| fem.dofs.index[n][2].map_or(0.0, |d| u[d]))
        .sum::<f64>()
        / tip.len() as f64;
    let [l, b, h] = LENGTHS;
    let i = b * h.powi(3) / 12.0;
    mean_w / (l.powi(3) / (3.0 * params.young_modulus * i))
}

/// Case 1: ν = 0.49: compiles, measured error below 2e-3. Linear tetrahedra lock near
/// incompressibility (docs/design.md §3): the full-order reference locks too, so the measured error
/// (reduced vs full order) does not show it; the static deflection against beam theory does.
#[test]
fn near_incompressible_compiles_accurately_and_locking_is_visible() {
    let c = run(
        "nu049",
        &Params {
            poisson_ratio: 0.49,
            ..Params::default()
        },
        None,
    )
    .expect("ν = 0.49 compiles");
    assert_stable_and_accurate("ν = 0.49", &c, 2e-3);

    let stiff_03 = deflection_ratio(0.3);
    let stiff_049 = deflection_ratio(0.49);
    eprintln!(
        "FE / Euler–Bernoulli tip deflection: ν = 0.3: {stiff_03:.3}, ν = 0.49: {stiff_049:.3}"
    );
    // Locking: two linear tets across the depth already under-predict at ν = 0.3, and
    // markedly more at ν = 0.49 although beam theory does not depend on ν.
    assert!(stiff_03 < 1.0, "{stiff_03}");
    assert!(stiff_049 < 0.5 * stiff_03, "{stiff_049} vs {stiff_03}");
}

/// Case 2: E = 1 kPa, 1 MPa and 200 GPa through the same scene and code path (ρ = 1000 kg/m³, Δt =
/// 5 ms fixed): each compiles with ρ(F) < 1, Riccati residual < 1e-10, ρ_cl < 1 and measured error
/// < 2e-3. The first bending frequency moves from ~0.02 Hz (hundreds of modes below the Nyquist
/// frequency) to ~340 Hz (every mode above it, numerically damped by Wilson-θ), so the Hankel
/// spectra differ physically and are not compared.
#[test]
fn young_modulus_over_eight_decades_in_one_code_path() {
    for e in [1.0e3, 1.0e6, 2.0e11] {
        let c = run(
            &format!("E{e:e}"),
            &Params {
                young_modulus: e,
                ..Params::default()
            },
            None,
        )
        .unwrap_or_else(|err| panic!("E = {e:e} Pa: {err}"));
        assert_stable_and_accurate(&format!("E = {e:e} Pa"), &c, 2e-3);
    }
}

/// Case 3: α = β = 0. With Δt = 5 ms, Wilson-θ's numerical damping keeps every modal block inside
/// the unit circle: it compiles (measured error < 2e-2). With Δt = 0.1 ms the lowest mode's block
/// radius is within 1e-12 of 1: refused, naming the mode and suggesting damping.
#[test]
fn no_physical_damping_compiles_or_is_refused_naming_the_mode() {
    for dt in [5.0e-3, 1.0e-4] {
        let params = Params {
            alpha: 0.0,
            beta: 0.0,
            dt,
            ..Params::default()
        };
        match run(&format!("undamped-{dt:e}"), &params, None) {
            Ok(c) => {
                assert_stable_and_accurate(&format!("α = β = 0, Δt = {dt:e}"), &c, 2e-2);
                assert!(dt > 1e-3, "Δt = {dt:e} was expected to be refused");
            }
            Err(e) => {
                eprintln!("α = β = 0, Δt = {dt:e}: {e}");
                assert!(
                    e.contains("mode 0") && e.contains("Hz") && e.contains("add Rayleigh damping"),
                    "{e}"
                );
                assert!(dt < 1e-3, "Δt = {dt:e} was expected to compile: {e}");
            }
        }
    }
}

/// Case 4: Δt = 0.1 ms (haptics) and Δt = 1/30 s (video) compile with ρ(F) < 1, Riccati residual <
/// 1e-10, ρ_cl < 1; measured errors below 5e-2 and 2e-3 with the default Hankel tolerance. The 0.1
/// ms error is the larger (≈ 2e-2 at r = 34): its 400-step window (40 ms) is shorter than the first
/// period (1.3 s), so the early, wave-dominated response that the truncated states carry weighs
/// heavily. It is the truncation, not the time step: r = 80 gives < 1e-4.
#[test]
fn haptic_and_video_time_steps() {
    for (dt, bound) in [(1.0e-4, 5e-2), (1.0 / 30.0, 2e-3)] {
        let c = run(
            &format!("dt{dt:e}"),
            &Params {
                dt,
                ..Params::default()
            },
            None,
        )
        .unwrap_or_else(|err| panic!("Δt = {dt:e} s: {err}"));
        assert_stable_and_accurate(&format!("Δt = {dt:e} s"), &c, bound);
        assert_eq!(c.model.dt, dt);
    }
    let dir = case_dir("haptic-r80");
    let scene = write_case(
        &dir,
        &Params {
            dt: 1.0e-4,
            ..Params::default()
        },
        None,
    );
    let options = CompileOptions {
        order: Some(80),
        ..CompileOptions::default()
    };
    let c = compile(&scene, &options);
    std::fs::remove_dir_all(&dir).ok();
    let c = c.unwrap_or_else(|err| panic!("Δt = 1e-4 s, r = 80: {err}"));
    assert_eq!(c.model.report.order, 80);
    assert_stable_and_accurate("Δt = 1e-4 s, r = 80", &c, 1e-4);
}

/// Case 5: One sensor measuring only x on the neutral axis at the tip: blind (by the beam's
/// symmetry, up to the mesh's diagonal pattern) to bending. It compiles and the filter is stable;
/// the slowest mode (first bending) is not seen, so the filter cannot speed it up: ρ_cl = ρ(F),
/// whereas a 3-component sensor on the top face pulls ρ_cl below ρ(F).
#[test]
fn sensor_blind_to_bending_gives_a_stable_filter() {
    let blind = run(
        "blind",
        &Params {
            sensors: r#"
[[sensor]]
name = "axis"
position = [0.95, 0.05, 0.05]
components = ["x"]
noise_std = 1.0e-3
"#
            .into(),
            ..Params::default()
        },
        None,
    )
    .expect("blind sensor compiles");
    assert_stable_and_accurate("blind sensor", &blind, 2e-3);
    let seeing = run("seeing", &Params::default(), None).expect("tip sensor compiles");
    assert_stable_and_accurate("3-component tip sensor", &seeing, 2e-3);
    let (b, s) = (&blind.model.report, &seeing.model.report);
    assert!(
        (b.closed_loop_spectral_radius - b.spectral_radius).abs() < 1e-7,
        "blind: ρ_cl = {} vs ρ(F) = {}",
        b.closed_loop_spectral_radius,
        b.spectral_radius
    );
    assert!(
        s.closed_loop_spectral_radius < s.spectral_radius - 1e-4,
        "seeing: ρ_cl = {} vs ρ(F) = {}",
        s.closed_loop_spectral_radius,
        s.spectral_radius
    );
}

/// Case 6: No `[[fixed]]`: K is singular (6 rigid-body modes); refused, suggesting to fix a group.
#[test]
fn no_dirichlet_nodes_is_refused_mentioning_rigid_body_modes() {
    let e = run(
        "free",
        &Params {
            fixed: false,
            ..Params::default()
        },
        None,
    )
    .err()
    .expect("a free body must be refused");
    eprintln!("no [[fixed]]: {e}");
    assert!(
        e.contains("6 rigid-body modes") && e.contains("fix a group"),
        "{e}"
    );
}

/// Case 7: A sliver (volume 1e-6 of the mean, positive) compiles with measured error < 2e-3; a
/// zero-volume tetrahedron is refused with a message naming its gmsh tag.
#[test]
fn sliver_compiles_and_zero_volume_element_is_refused_by_tag() {
    // Sliver.
    let dir = case_dir("sliver");
    let scene = write_case(&dir, &Params::default(), Some(&box_with_sliver(1e-6)));
    let (tag, volume, mean) = smallest_element(&dir.join("box.msh"));
    let ratio = volume / mean;
    eprintln!("sliver: tetrahedron {tag}, volume / mean = {ratio:.3e}");
    assert!(ratio > 0.0 && (ratio - 1e-6).abs() < 0.2e-6, "{ratio:e}");
    let c = compile(&scene, &CompileOptions::default());
    std::fs::remove_dir_all(&dir).ok();
    match c {
        Ok(c) => assert_stable_and_accurate("sliver", &c, 2e-3),
        Err(e) => panic!("sliver refused: {e}"),
    }

    // Zero volume.
    let dir = case_dir("flat");
    let scene = write_case(&dir, &Params::default(), Some(&box_with_sliver(0.0)));
    let (tag, volume, mean) = smallest_element(&dir.join("box.msh"));
    assert!(volume.abs() < 1e-12 * mean, "{volume:e}");
    let e = compile(&scene, &CompileOptions::default())
        .err()
        .expect("a zero-volume element must be refused")
        .to_string();
    std::fs::remove_dir_all(&dir).ok();
    eprintln!("zero volume: {e}");
    assert!(
        e.contains(&format!("tetrahedron {tag} ")) && e.contains("degenerate"),
        "{e}"
    );
}

/// Case 8: Bad scene inputs: each error names the entry (and, where useful, the alternatives).
#[test]
fn bad_scene_inputs_give_errors_naming_the_entry() {
    let refuse = |name: &str, params: Params, needles: &[&str]| {
        let e = run(name, &params, None)
            .err()
            .unwrap_or_else(|| panic!("{name}: expected an error"));
        eprintln!("{name}: {e}");
        for n in needles {
            assert!(e.contains(n), "{name}: '{n}' not in: {e}");
        }
    };
    let with_sensor = |position: &str, noise: &str| Params {
        sensors: format!(
            "[[sensor]]\nname = \"probe\"\nposition = {position}\nnoise_std = {noise}\n"
        ),
        ..Params::default()
    };
    refuse(
        "nu05",
        Params {
            poisson_ratio: 0.5,
            ..Params::default()
        },
        &["material 'body'", "poisson_ratio", "0.5"],
    );
    refuse(
        "nu06",
        Params {
            poisson_ratio: 0.6,
            ..Params::default()
        },
        &["material 'body'", "poisson_ratio", "0.6"],
    );
    refuse(
        "E0",
        Params {
            young_modulus: 0.0,
            ..Params::default()
        },
        &["material 'body'", "young_modulus", "> 0"],
    );
    refuse(
        "Eneg",
        Params {
            young_modulus: -1.0e6,
            ..Params::default()
        },
        &["material 'body'", "young_modulus", "-1000000"],
    );
    refuse(
        "theta",
        Params {
            theta: 1.3,
            ..Params::default()
        },
        &["theta", "1.37", "1.3"],
    );
    refuse(
        "outside",
        with_sensor("[2.0, 0.05, 0.05]", "1.0e-3"),
        &["sensor 'probe'", "outside the mesh", "2.000000"],
    );
    refuse(
        "zero_noise",
        with_sensor("[0.5, 0.05, 0.05]", "0.0"),
        &["sensor 'probe'", "noise_std", "> 0"],
    );
    refuse(
        "missing",
        Params {
            mesh_file: "no_such_mesh.msh".into(),
            ..Params::default()
        },
        &["no_such_mesh.msh", "crokf-hard-missing-"],
    );

    // An unknown physical name in [[material]]: the message lists the names the mesh has.
    let dir = case_dir("unknown-group");
    let scene = write_case(&dir, &Params::default(), None);
    let text = std::fs::read_to_string(&scene).expect("scene");
    std::fs::write(&scene, text.replace("group = \"body\"", "group = \"beam\"")).expect("scene");
    let e = compile(&scene, &CompileOptions::default())
        .err()
        .expect("unknown group must be refused")
        .to_string();
    std::fs::remove_dir_all(&dir).ok();
    eprintln!("unknown group: {e}");
    for n in ["'beam'", "material", "body", "xmin", "xmax"] {
        assert!(e.contains(n), "'{n}' not in: {e}");
    }
}
