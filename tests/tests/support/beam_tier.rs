//! The small co-rotational beam that `tier.rs`, `force_levels.rs`, `covariance_recursion.rs`
//! and crokf-run's `tests/tier.rs` compile (included by `#[path]`): a 12×2×2-cell box of 1 m × 0.1 m × 0.1 m (288 tetrahedra) clamped at x = 0, the
//! tip load on x = 1 m, a `tip` marker, the end face displayed, Δt = 5 ms, and the tier section
//! [`TIER`].

use std::path::{Path, PathBuf};

use crokf_compile::mesh::procedural::{box_mesh, write_msh22, BeamScene};
use crokf_compile::{compile, CompileOptions};
use crokf_formats::Model;

/// Δt of the beam scenes, s.
pub const DT: f64 = 0.005;

/// The beam's tier is trained along the six axes (`directions = "axes"`, 12 runs) to 30 N:
/// the tests were measured on it; the default directions are measured on the held-out bodies
/// (docs/results/tier.md §11) and in `compiler/src/nonlinear/training.rs`'s tests.
pub const TIER: &str = "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\n\
    ranges = { tip = 30.0 }\nduration = 0.15\nevery = 2\norder = 10\necsw_tolerance = 1e-2\n\
    newton_tolerance = 1e-12\nnewton_iterations = 60\ndirections = \"axes\"\n";

/// The beam scene's fields: the tip marker, the end face displayed, Δt = [`DT`]; the rest as
/// [`BeamScene::default`] (a tip load the runtime is told, white force noise).
pub fn tip_beam() -> BeamScene {
    BeamScene {
        sensors: vec![("tip".into(), [0.99, 0.05, 0.1])],
        displays: vec![("end".into(), "xmax".into())],
        dt: DT,
        ..BeamScene::default()
    }
}

/// Writes `dir/beam.msh` (once) and `dir/name` = `scene` with [`TIER`]; returns the scene's
/// path.
pub fn write_tier_scene(dir: &Path, name: &str, scene: &BeamScene) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let mesh = dir.join("beam.msh");
    if !mesh.exists() {
        write_msh22(&box_mesh([12, 2, 2], [1.0, 0.1, 0.1]), &mesh).unwrap();
    }
    let path = dir.join(name);
    std::fs::write(&path, scene.toml() + TIER).unwrap();
    path
}

/// [`tip_beam`] with its tip load estimated and no σ stated (the force σ derived from the
/// tier's range, 30 N, and the default rise time), with a second marker `mid` halfway along
/// when `mid_marker`.
#[allow(dead_code)] // tier.rs compiles its beams with its own settings.
pub fn estimated_load_beam(mid_marker: bool) -> BeamScene {
    let mut scene = BeamScene {
        force_noise_std: None,
        force_model: None,
        ..tip_beam()
    };
    if mid_marker {
        scene.sensors.push(("mid".into(), [0.5, 0.05, 0.1]));
    }
    scene
}

/// `scene` written to `dir/scene.toml` ([`write_tier_scene`]) and compiled at order 8 without
/// the measured error (the quick compile of these tests); the scene's path and the model.
#[allow(dead_code)] // tier.rs compiles its beams with its own settings.
pub fn compile_beam(dir: &Path, scene: &BeamScene) -> (PathBuf, Model) {
    let path = write_tier_scene(dir, "scene.toml", scene);
    let options = CompileOptions {
        order: Some(8),
        skip_measured_error: true,
        ..CompileOptions::default()
    };
    let model = compile(&path, &options).unwrap().model;
    (path, model)
}
