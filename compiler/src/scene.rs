//! Scene files (TOML): what to simulate, what acts on it, what is measured and what is shown.
//!
//! All lengths in the scene (sensor positions) are in mesh units; `mesh.units` converts them and
//! the mesh coordinates to metres. Material constants, forces and noise are SI (Pa, kg/m³, N, m).
//! Unknown keys are errors.
//!
//! ```toml
//! [mesh]
//! file = "cantilever.msh"       # relative to the scene file
//! units = "m"                   # m, cm or mm
//!
//! [[material]]
//! group = "beam"                # gmsh physical name of a volume group
//! young_modulus = 1.0e6         # E, Pa
//! poisson_ratio = 0.3           # ν
//! density = 1000.0              # ρ, kg/m³
//!
//! [damping]                     # Rayleigh C = αM + βK
//! alpha = 0.5                   # 1/s
//! beta = 1.0e-4                 # s
//!
//! [[fixed]]
//! group = "clamp"               # Dirichlet: all three components of every node fixed
//!
//! [[load]]
//! name = "tip"
//! group = "tip"                 # nodes receiving the force
//! distribution = "area"         # "area" (by surface triangle area) or "uniform" (equal shares)
//! force_noise_std = 0.01        # N per world component, process noise
//! force_model = "white"         # or "random_walk": the filter estimates a persistent force
//!
//! [[sensor]]
//! name = "marker_1"
//! position = [1.0, 0.05, 0.05]  # mesh units, interpolated in the containing tetrahedron
//! components = ["x", "y", "z"]
//! noise_std = 1.0e-4            # m, or per component: [1.0e-4, 1.0e-4, 3.0e-4]
//! every = 1                     # a measurement every k steps
//!
//! [[display]]
//! name = "surface"
//! group = "surface"             # a physical group, or the keyword "surface" (boundary)
//!
//! [time]
//! dt = 0.001                    # s
//! theta = 1.4
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// Errors in reading or checking a scene file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// Scene path.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// TOML syntax or schema error (unknown key, wrong type); the message names the line.
    #[error("{path}: {message}")]
    Parse {
        /// Scene path.
        path: PathBuf,
        /// toml's message, with line and column.
        message: String,
    },
    /// A value is out of its physical range.
    #[error("{path}: {what}")]
    Invalid {
        /// Scene path.
        path: PathBuf,
        /// What is wrong, naming the entry.
        what: String,
    },
}

/// Length unit of the mesh coordinates and scene positions.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LengthUnit {
    /// Metres.
    #[default]
    #[serde(rename = "m")]
    Metre,
    /// Centimetres.
    #[serde(rename = "cm")]
    Centimetre,
    /// Millimetres.
    #[serde(rename = "mm")]
    Millimetre,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn to_metres(self) -> f64 {
        match self {
            LengthUnit::Metre => 1.0,
            LengthUnit::Centimetre => 1e-2,
            LengthUnit::Millimetre => 1e-3,
        }
    }
}

/// The `[mesh]` table.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// Mesh path, relative to the scene file.
    pub file: PathBuf,
    /// Length unit of the mesh coordinates and of scene positions.
    #[serde(default)]
    pub units: LengthUnit,
}

/// Isotropic linear elastic material of one volume physical group.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// gmsh physical name of a 3D group.
    pub group: String,
    /// Young's modulus E, Pa (> 0).
    pub young_modulus: f64,
    /// Poisson's ratio ν, in (-1, 0.5).
    pub poisson_ratio: f64,
    /// Density ρ, kg/m³ (> 0).
    pub density: f64,
}

/// Rayleigh damping C = αM + βK.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Damping {
    /// Mass-proportional coefficient α, 1/s.
    #[serde(default)]
    pub alpha: f64,
    /// Stiffness-proportional coefficient β, s.
    #[serde(default)]
    pub beta: f64,
}

/// Mass matrix options.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MassSpec {
    /// Lumped (row-sum) mass instead of consistent mass.
    #[serde(default)]
    pub lumped: bool,
}

/// A Cartesian component.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[serde(rename_all = "lowercase")]
pub enum Component {
    /// x.
    X,
    /// y.
    Y,
    /// z.
    Z,
}

impl Component {
    /// 0, 1 or 2.
    pub fn index(self) -> usize {
        match self {
            Component::X => 0,
            Component::Y => 1,
            Component::Z => 2,
        }
    }

    /// "x", "y" or "z".
    pub fn label(self) -> &'static str {
        ["x", "y", "z"][self.index()]
    }
}

fn all_components() -> Vec<Component> {
    vec![Component::X, Component::Y, Component::Z]
}

/// A Dirichlet group: the listed components of every node of the group are held at zero.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Fixed {
    /// gmsh physical name (any dimension).
    pub group: String,
    /// Fixed components (default all three).
    #[serde(default = "all_components")]
    pub components: Vec<Component>,
}

/// How a load group's total force is shared among its nodes.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum LoadDistribution {
    /// Consistent with a uniform traction: shares by the area of the group's surface triangles
    /// (needs a 2D group).
    #[default]
    Area,
    /// Equal share per node.
    Uniform,
}

/// A load group: a world-frame force (3 input channels) spread over a group of nodes.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Load {
    /// Input label.
    pub name: String,
    /// gmsh physical name.
    pub group: String,
    /// Distribution of the total force.
    #[serde(default)]
    pub distribution: LoadDistribution,
    /// Standard deviation of the force process noise per world component, N (0: none): of the
    /// force itself (`force_model = "white"`) or of its change per step (`"random_walk"`).
    #[serde(default)]
    pub force_noise_std: f64,
    /// How the Kalman filter models the unknown part of this load.
    #[serde(default)]
    pub force_model: ForceModel,
}

/// Process-noise model of a load group's unknown force.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ForceModel {
    /// White noise: an independent force each step (no memory).
    #[default]
    White,
    /// Random walk: the filter carries the force as 3 extra states, f⁺ = f + w; a persistent
    /// unknown force (or a persistent model error at the load) is then estimated, not lagged.
    RandomWalk,
}

/// A distributed force-noise density over a physical group (process noise only).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForceNoise {
    /// Label.
    pub name: String,
    /// gmsh physical name.
    pub group: String,
    /// Standard deviation of the total force over the group per component, N, spread like a
    /// load with `distribution`.
    pub std: f64,
    /// Distribution.
    #[serde(default)]
    pub distribution: LoadDistribution,
}

/// A point sensor measuring displacement components.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    /// Label.
    pub name: String,
    /// Position in mesh units (rest configuration).
    pub position: [f64; 3],
    /// Measured world displacement components (default all three).
    #[serde(default = "all_components")]
    pub components: Vec<Component>,
    /// Measurement noise standard deviation, m (> 0): one value for all components, or one per
    /// world component `[σx, σy, σz]`.
    pub noise_std: SensorNoise,
    /// A measurement arrives every `every` steps (1: each step).
    #[serde(default = "one")]
    pub every: u32,
}

/// Measurement noise of a sensor: one standard deviation, or one per world component (m).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum SensorNoise {
    /// The same σ for x, y and z.
    Uniform(f64),
    /// σx, σy, σz.
    PerComponent([f64; 3]),
}

impl SensorNoise {
    /// σ of component `c`, m.
    pub fn of(self, c: Component) -> f64 {
        match self {
            SensorNoise::Uniform(s) => s,
            SensorNoise::PerComponent(s) => s[c.index()],
        }
    }
}

fn one() -> u32 {
    1
}

/// A displayed node set.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Display {
    /// Label.
    pub name: String,
    /// gmsh physical name, or `"surface"` for the boundary of the tetrahedral mesh.
    pub group: String,
}

/// Time stepping.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimeSpec {
    /// Time step Δt, s.
    pub dt: f64,
    /// Wilson θ (≥ 1.37).
    #[serde(default = "default_theta")]
    pub theta: f64,
}

fn default_theta() -> f64 {
    1.4
}

/// Reduction settings (all optional; command-line flags override).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReductionSpec {
    /// Balanced truncation order r.
    pub order: Option<usize>,
    /// Relative tolerance on the Hankel singular values σ_i/σ_1 when `order` is absent.
    pub tolerance: Option<f64>,
    /// Number of vibration modes m kept before balancing.
    pub modes: Option<usize>,
}

/// A scene, as written in the file.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Mesh file.
    pub mesh: MeshSpec,
    /// Materials per volume group; every tetrahedron must be covered exactly once.
    #[serde(rename = "material")]
    pub materials: Vec<Material>,
    /// Rayleigh damping.
    #[serde(default)]
    pub damping: Damping,
    /// Mass options.
    #[serde(default)]
    pub mass: MassSpec,
    /// Dirichlet groups.
    #[serde(default)]
    pub fixed: Vec<Fixed>,
    /// Load groups.
    #[serde(default, rename = "load")]
    pub loads: Vec<Load>,
    /// Gravity acceleration vector, m/s² (an input channel when present).
    #[serde(default)]
    pub gravity: Option<[f64; 3]>,
    /// Distributed force-noise channels.
    #[serde(default)]
    pub force_noise: Vec<ForceNoise>,
    /// Sensors.
    #[serde(default, rename = "sensor")]
    pub sensors: Vec<Sensor>,
    /// Displayed node sets.
    #[serde(default)]
    pub display: Vec<Display>,
    /// Time stepping.
    pub time: TimeSpec,
    /// Reduction settings.
    #[serde(default)]
    pub reduction: ReductionSpec,
}

/// A scene with the file it came from.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// Path of the scene file.
    pub path: PathBuf,
    /// Raw bytes of the scene file.
    pub text: String,
    /// Parsed and checked scene.
    pub scene: Scene,
}

impl SceneFile {
    /// Reads, parses and range-checks a scene file.
    pub fn read(path: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.to_owned(),
            source,
        })?;
        let scene = Scene::parse(&text, path)?;
        Ok(SceneFile {
            path: path.to_owned(),
            text,
            scene,
        })
    }

    /// Absolute or working-directory path of the mesh file.
    pub fn mesh_path(&self) -> PathBuf {
        match self.path.parent() {
            Some(dir) => dir.join(&self.scene.mesh.file),
            None => self.scene.mesh.file.clone(),
        }
    }
}

impl Scene {
    /// Parses scene text; `path` is used in messages only.
    pub fn parse(text: &str, path: &Path) -> Result<Self, SceneError> {
        let scene: Scene = toml::from_str(text).map_err(|e| SceneError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        scene.check().map_err(|what| SceneError::Invalid {
            path: path.to_owned(),
            what,
        })?;
        Ok(scene)
    }

    /// Range checks that need no mesh.
    fn check(&self) -> Result<(), String> {
        if self.materials.is_empty() {
            return Err("no [[material]]: every volume group needs E, ν and ρ".into());
        }
        for m in &self.materials {
            let g = &m.group;
            if !(m.young_modulus.is_finite() && m.young_modulus > 0.0) {
                return Err(format!(
                    "material '{g}': young_modulus must be > 0 Pa, got {}",
                    m.young_modulus
                ));
            }
            if !(m.poisson_ratio.is_finite() && m.poisson_ratio > -1.0 && m.poisson_ratio < 0.5) {
                return Err(format!(
                    "material '{g}': poisson_ratio must lie in (-1, 0.5), got {} \
                     (ν = 0.5 is incompressible: linear tetrahedra cannot represent it)",
                    m.poisson_ratio
                ));
            }
            if !(m.density.is_finite() && m.density > 0.0) {
                return Err(format!(
                    "material '{g}': density must be > 0 kg/m³, got {}",
                    m.density
                ));
            }
        }
        let d = self.damping;
        if !(d.alpha.is_finite() && d.alpha >= 0.0 && d.beta.is_finite() && d.beta >= 0.0) {
            return Err(format!(
                "damping: alpha and beta must be finite and ≥ 0, got α = {}, β = {}",
                d.alpha, d.beta
            ));
        }
        let t = self.time;
        if !(t.dt.is_finite() && t.dt > 0.0) {
            return Err(format!("time.dt must be > 0 s, got {}", t.dt));
        }
        if !(t.theta.is_finite() && t.theta >= 1.37) {
            return Err(format!(
                "time.theta must be ≥ 1.37 for unconditional stability, got {}",
                t.theta
            ));
        }
        if let Some(g) = self.gravity {
            if g.iter().any(|v| !v.is_finite()) {
                return Err(format!("gravity must be finite, got {g:?}"));
            }
        }
        let mut names = std::collections::BTreeSet::new();
        for l in &self.loads {
            if !names.insert(l.name.as_str()) {
                return Err(format!("load '{}': name used twice", l.name));
            }
            if !(l.force_noise_std.is_finite() && l.force_noise_std >= 0.0) {
                return Err(format!(
                    "load '{}': force_noise_std must be ≥ 0 N, got {}",
                    l.name, l.force_noise_std
                ));
            }
        }
        for n in &self.force_noise {
            if !names.insert(n.name.as_str()) {
                return Err(format!("force_noise '{}': name used twice", n.name));
            }
            if !(n.std.is_finite() && n.std > 0.0) {
                return Err(format!(
                    "force_noise '{}': std must be > 0 N, got {}",
                    n.name, n.std
                ));
            }
        }
        let mut sensor_names = std::collections::BTreeSet::new();
        for s in &self.sensors {
            if !sensor_names.insert(s.name.as_str()) {
                return Err(format!("sensor '{}': name used twice", s.name));
            }
            if s.position.iter().any(|v| !v.is_finite()) {
                return Err(format!("sensor '{}': position must be finite", s.name));
            }
            if s.components.is_empty() {
                return Err(format!("sensor '{}': no measured components", s.name));
            }
            for &c in &s.components {
                let sigma = s.noise_std.of(c);
                if !(sigma.is_finite() && sigma > 0.0) {
                    return Err(format!(
                        "sensor '{}': noise_std of component {} must be > 0 m (R must be positive \
                         definite), got {sigma}",
                        s.name,
                        c.label()
                    ));
                }
            }
            if s.every == 0 {
                return Err(format!("sensor '{}': every must be ≥ 1", s.name));
            }
        }
        let mut display_names = std::collections::BTreeSet::new();
        for d in &self.display {
            if !display_names.insert(d.name.as_str()) {
                return Err(format!("display '{}': name used twice", d.name));
            }
        }
        if let Some(tol) = self.reduction.tolerance {
            if !(tol > 0.0 && tol < 1.0) {
                return Err(format!("reduction.tolerance must lie in (0, 1), got {tol}"));
            }
        }
        if self.reduction.order == Some(0) {
            return Err("reduction.order must be ≥ 1".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
        [mesh]
        file = "m.msh"
        [[material]]
        group = "body"
        young_modulus = 1e6
        poisson_ratio = 0.3
        density = 1000.0
        [time]
        dt = 0.01
    "#;

    fn parse(text: &str) -> Result<Scene, SceneError> {
        Scene::parse(text, Path::new("scene.toml"))
    }

    #[test]
    fn minimal_scene_defaults() {
        let s = parse(MINIMAL).unwrap();
        assert_eq!(s.time.theta, 1.4);
        assert_eq!(s.mesh.units, LengthUnit::Metre);
        assert!(!s.mass.lumped);
    }

    #[test]
    fn unknown_key_is_an_error_naming_it() {
        let text = format!("{MINIMAL}\n[damping]\nalpah = 1.0\n");
        let e = parse(&text).unwrap_err().to_string();
        assert!(e.contains("alpah"), "{e}");
        assert!(e.contains("scene.toml"), "{e}");
    }

    #[test]
    fn incompressible_and_nonpositive_modulus_are_refused() {
        let e = parse(&MINIMAL.replace("0.3", "0.5"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("poisson_ratio") && e.contains("body"), "{e}");
        let e = parse(&MINIMAL.replace("1e6", "-1.0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("young_modulus"), "{e}");
        let e = parse(&MINIMAL.replace("1e6", "0.0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("young_modulus"), "{e}");
    }

    #[test]
    fn sensor_noise_per_component() {
        let sensor = |noise: &str| {
            format!(
                "{MINIMAL}\n[[sensor]]\nname = \"m\"\nposition = [0.0, 0.0, 0.0]\n\
                 components = [\"x\", \"z\"]\nnoise_std = {noise}\n"
            )
        };
        let s = parse(&sensor("[1e-3, 0.0, 3e-3]")).unwrap();
        assert_eq!(s.sensors[0].noise_std.of(Component::Z), 3e-3);
        assert_eq!(s.sensors[0].noise_std.of(Component::X), 1e-3);
        // σ = 0 on a measured component is refused, on an unmeasured one it is not used.
        let e = parse(&sensor("[0.0, 1e-3, 1e-3]")).unwrap_err().to_string();
        assert!(e.contains("sensor 'm'") && e.contains("component x"), "{e}");
        assert_eq!(
            parse(&sensor("2e-4")).unwrap().sensors[0]
                .noise_std
                .of(Component::Y),
            2e-4
        );
    }

    #[test]
    fn small_theta_is_refused() {
        let e = parse(&MINIMAL.replace("dt = 0.01", "dt = 0.01\ntheta = 1.2"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("theta"), "{e}");
    }
}
