// Over 800 lines, one job: the scene's types, each field with its unit, default and range (the schema users read); the checks are in scene/check.rs, 80 lines are tests.
//! Scene files (TOML): what to simulate, what acts on it, what is measured and what is shown.
//!
//! All lengths in the scene (sensor positions, selection shapes) are in mesh units; `mesh.units`
//! converts them and the mesh coordinates to metres. Material constants, forces and noise are SI
//! (Pa, kg/m³, N, m). Unknown keys are errors. A UTF-8 byte-order mark is accepted.
//!
//! Every physical value is range-checked before any numerics (the message names the field and
//! the accepted range): E in [1, 1e13] Pa, ν in (−1, 0.5), ρ in [1e-3, 1e6] kg/m³, α in
//! [0, 1e6] 1/s, β in [0, 1e3] s, |g| ≤ 1e4 m/s², force noise σ in [0, 1e9] N, sensor noise σ in
//! [1e-12, 1e3] m, Δt in [1e-7, 10] s, θ in [1.37, 10], coordinates finite and |x| ≤ 1e9 mesh
//! units (the mesh's own coordinates too, `crate::mesh`). A `[[fixed]]` entry with
//! `components = []` is refused (it would fix nothing). [`Scene::warnings`] lists what is legal but suspect (ν ≥ 0.49 on linear tetrahedra).
//!
//! **Where a group is accepted** (`[[material]]`, `[[fixed]]`, `[[load]]`, `[[force_noise]]`,
//! `[[display]]`), give either `group = "name"` (a gmsh physical name, `"<dim>:<tag>"` for an
//! unnamed gmsh group, `"<array>:<value>"` for an integer cell-data array of a VTK file, e.g.
//! `"MaterialIds:2"`) or `select = [ ... ]`, a union of selectors (each takes exactly one of):
//!
//! ```toml
//! select = [
//!   { box = { min = [0.0, 0.0, 0.0], max = [0.1, 0.1, 0.001] }, nodes = "boundary" },
//!   { sphere = { center = [0.09, 0.0, 0.05], radius = 0.012 }, nodes = "boundary" },
//!   { half_space = { point = [0.0, 0.0, 0.002], normal = [0.0, 0.0, -1.0] }, nodes = "all" },
//!   { node_list = "base_nodes.txt" },   # node tags, relative to the scene file
//!   { group = "clamp" },                # a mesh group, as `group = ...` above
//!   { everything = true, nodes = "all" },
//! ]
//! ```
//!
//! - Shapes are in mesh units, closed (points on the boundary are inside, to 1e-9 of the mesh's
//!   bounding-box diagonal). A half-space holds the points x with (x − point)·normal ≥ 0: the
//!   normal points into the selected side.
//! - `nodes` (required with a shape or `everything` outside `[[material]]`): `"boundary"` takes
//!   only nodes on the boundary of the tetrahedral mesh, `"all"` every node of a tetrahedron.
//! - `node_list`: a text file of node tags (gmsh node tags; 0-based point ids for VTK files),
//!   separated by spaces, commas or newlines; `#` starts a comment; a tag listed more than once
//!   is used once, with a warning naming the tag and its lines.
//! - In `[[material]]` a shape takes the tetrahedra whose centroid lies inside it; `nodes` and
//!   `node_list` do not apply there.
//! - Loads with `distribution = "area"` and displays use the boundary faces whose three nodes
//!   are all selected (a 2-D `group` keeps its own triangles).
//!
//! The compiler reports how many nodes, faces or tetrahedra every selection took and refuses a
//! selector that takes none.
//!
//! ```toml
//! [mesh]
//! file = "cantilever.msh"       # relative to the scene file
//! units = "m"                   # m, cm or mm
//!
//! [[material]]
//! group = "beam"                # gmsh physical name of a volume group (or `select`, above)
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
//! range = 20.0                  # N: the largest total force; the filter estimates the load
//! rise_time = 0.2               # s: the shortest time from 0 to `range` (default 0.2)
//! # force_model = "random_walk" # the default; "white": a load the runtime is always told
//! # force_noise_std = 0.5       # N per step: a stated σ instead of the derived one
//! # force_rate_noise_std = 0.0  # N/s per step: random walk of the force's rate (tier only)
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

mod check;

/// Errors in reading or checking a TOML input file: a scene (here) or a verification scenario
/// (`crokf-verify`, which uses this type as its `ScenarioError`). Each names the file.
#[derive(Debug, thiserror::Error)]
pub enum InputFileError {
    /// The file could not be read.
    #[error("cannot read {kind} file {path}: {source}")]
    Io {
        /// What the file is: "scene" or "scenario".
        kind: &'static str,
        /// The file.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// TOML syntax or schema error (unknown key, wrong type); the message names the line.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// toml's message, with line and column.
        message: String,
    },
    /// A value is out of its physical range or inconsistent, naming the entry.
    #[error("{path}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the entry.
        what: String,
    },
}

/// Errors in reading or checking a scene file.
pub type SceneError = InputFileError;

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
    /// Mesh group name of a volume group (or `select`).
    #[serde(default)]
    pub group: Option<String>,
    /// Union of selectors taking tetrahedra (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
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
    /// Mesh group name (any dimension), or `select`.
    #[serde(default)]
    pub group: Option<String>,
    /// Union of node selectors (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
    /// Fixed components (default all three; an empty list is refused).
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
    /// Mesh group name, or `select`.
    #[serde(default)]
    pub group: Option<String>,
    /// Union of node selectors (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
    /// Distribution of the total force.
    #[serde(default)]
    pub distribution: LoadDistribution,
    /// The largest total force this load reaches, N (> 0): with `rise_time`, what the
    /// compiler derives the estimated force's σ from (docs/design.md §11.8), and the
    /// co-rotational tier's training range unless `[reduction.corotational] ranges` names it.
    #[serde(default)]
    pub range: Option<f64>,
    /// The shortest time in which the load goes from zero to its `range`, s (default
    /// [`DEFAULT_RISE_TIME`]); estimated loads only.
    #[serde(default)]
    pub rise_time: Option<f64>,
    /// Standard deviation of the force process noise per world component, N (0: none): of the
    /// force itself (`force_model = "white"`) or of its change per step (`"random_walk"`,
    /// instead of the σ derived from `range` and `rise_time`).
    #[serde(default)]
    pub force_noise_std: f64,
    /// How the Kalman filter models the unknown part of this load (default
    /// [`ForceModel::RandomWalk`]: the load is estimated); [`Load::force_model`] resolves it.
    #[serde(default, rename = "force_model")]
    pub force_model_stated: Option<ForceModel>,
    /// Co-rotational tier with `force_model = "random_walk"` only: standard deviation of the
    /// change per step of the force's rate, N/s per world component (0: none). The tier's
    /// filter then also carries the rate ḟ, f⁺ = f + Δt ḟ + w, ḟ⁺ = ḟ + w_ḟ (an integrated
    /// random walk: a ramp is extrapolated between markers; docs/design.md §11.5).
    #[serde(default)]
    pub force_rate_noise_std: f64,
}

/// The rise time of a load that states none, s: a load applied by hand or by an instrument
/// (docs/scene.md).
pub const DEFAULT_RISE_TIME: f64 = 0.2;

impl Load {
    /// The force model: the scene's, or [`ForceModel::RandomWalk`] (estimated) by default.
    pub fn force_model(&self) -> ForceModel {
        self.force_model_stated.unwrap_or(ForceModel::RandomWalk)
    }

    /// Whether the filter estimates this load with force states.
    pub fn is_estimated(&self) -> bool {
        self.force_model() == ForceModel::RandomWalk
    }

    /// The rise time, s (the scene's or [`DEFAULT_RISE_TIME`]).
    pub fn rise_time(&self) -> f64 {
        self.rise_time.unwrap_or(DEFAULT_RISE_TIME)
    }
}

/// Process-noise model of a load group's unknown force.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ForceModel {
    /// White noise: an independent force each step (no memory); the runtime is told the load
    /// and `force_noise_std` is the noise on it.
    White,
    /// Random walk (the default): the filter carries the force as 3 extra states, f⁺ = f + w;
    /// a load the runtime is not told (or the part of a given load that the input does not
    /// explain, such as a persistent model error at the load) is estimated, not lagged.
    #[default]
    RandomWalk,
}

/// A distributed force-noise density over a physical group (process noise only).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForceNoise {
    /// Label.
    pub name: String,
    /// Mesh group name, or `select`.
    #[serde(default)]
    pub group: Option<String>,
    /// Union of node selectors (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
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

/// A contact region: the surface nodes a tool may touch, the tool's shape and the force bound
/// (docs/contact.md).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Contact {
    /// Label.
    pub name: String,
    /// Mesh group name, or `select`; only the boundary nodes of the selection take part.
    #[serde(default)]
    pub group: Option<String>,
    /// Union of node selectors (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
    /// The tool: a rigid sphere of this radius, mesh units (> 0), centred at the tool position.
    pub radius: f64,
    /// The largest tool force the runtime returns, N (> 0): the force is clamped to it.
    pub max_force: f64,
    /// Relative eigenvalue of the region's static compliance down to which its directions are
    /// inputs and outputs of the balanced truncation (default
    /// [`DEFAULT_CONTACT_RANK_TOLERANCE`]); the rest is the stored static residual.
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
}

/// Default `rank_tolerance` of a contact region.
pub const DEFAULT_CONTACT_RANK_TOLERANCE: f64 = 1e-2;

impl Contact {
    /// The nodes this region may touch (before taking the boundary).
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }

    /// The rank tolerance (the scene's or [`DEFAULT_CONTACT_RANK_TOLERANCE`]).
    pub fn rank_tolerance(&self) -> f64 {
        self.rank_tolerance
            .unwrap_or(DEFAULT_CONTACT_RANK_TOLERANCE)
    }

    /// Checks of the fields that need no mesh.
    fn check(&self, index: usize) -> Result<(), String> {
        let at = format!("contact[{index}] '{}'", self.name);
        if self.group.is_some() == self.select.is_some() {
            return Err(format!("{at}: give exactly one of `group` and `select`"));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(format!(
                "{at}: radius = {} must be finite and > 0 (mesh units)",
                self.radius
            ));
        }
        if !(self.max_force.is_finite() && self.max_force > 0.0 && self.max_force <= 1e9) {
            return Err(format!(
                "{at}: max_force = {} must be in (0, 1e9] N",
                self.max_force
            ));
        }
        if let Some(t) = self.rank_tolerance {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                return Err(format!("{at}: rank_tolerance = {t} must be in (0, 1)"));
            }
        }
        Ok(())
    }
}

/// A displayed node set.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Display {
    /// Label.
    pub name: String,
    /// Mesh group name, or `"surface"` for the boundary of the tetrahedral mesh (or `select`).
    #[serde(default)]
    pub group: Option<String>,
    /// Union of node selectors (instead of `group`).
    #[serde(default)]
    pub select: Option<Vec<Selector>>,
}

/// Where a scene entry acts: a named mesh group or a union of selectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target<'a> {
    /// A mesh group name (or a keyword such as `"surface"` for displays).
    Group(&'a str),
    /// A union of selectors.
    Select(&'a [Selector]),
}

fn target<'a>(group: &'a Option<String>, select: &'a Option<Vec<Selector>>) -> Target<'a> {
    match (group, select) {
        (Some(g), _) => Target::Group(g),
        (None, Some(s)) => Target::Select(s),
        // Scene::check refuses an entry with neither.
        (None, None) => Target::Select(&[]),
    }
}

impl Material {
    /// The tetrahedra this material covers.
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }
}

impl Fixed {
    /// The nodes this entry fixes.
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }
}

impl Load {
    /// The nodes the force acts on.
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }
}

impl ForceNoise {
    /// The nodes the noise acts on.
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }
}

impl Display {
    /// The displayed nodes.
    pub fn target(&self) -> Target<'_> {
        target(&self.group, &self.select)
    }
}

impl std::fmt::Display for Target<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Target::Group(g) => write!(f, "group '{g}'"),
            Target::Select(s) => write!(f, "select ({} selector(s))", s.len()),
        }
    }
}

/// One selector of a `select = [...]` union; exactly one of `box`, `sphere`, `half_space`,
/// `node_list`, `group`, `everything` is given. Coordinates in mesh units.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Selector {
    /// Axis-aligned box.
    #[serde(rename = "box")]
    pub aabb: Option<BoxRegion>,
    /// Ball.
    pub sphere: Option<Sphere>,
    /// Half-space (x − point)·normal ≥ 0.
    pub half_space: Option<HalfSpace>,
    /// File of node tags, relative to the scene file (resolved by [`Scene::parse`]).
    pub node_list: Option<PathBuf>,
    /// A mesh group by name.
    pub group: Option<String>,
    /// Every tetrahedron, or every node of the given `nodes` kind.
    pub everything: Option<bool>,
    /// Boundary nodes or all nodes (shapes and `everything`, outside materials).
    pub nodes: Option<NodeDomain>,
}

/// An axis-aligned box `min ≤ x ≤ max`, mesh units.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoxRegion {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
}

/// A closed ball `|x − center| ≤ radius`, mesh units.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sphere {
    /// Centre.
    pub center: [f64; 3],
    /// Radius (> 0).
    pub radius: f64,
}

/// A closed half-space `(x − point)·normal ≥ 0`, mesh units (the normal need not be unit).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HalfSpace {
    /// A point on the bounding plane.
    pub point: [f64; 3],
    /// Normal pointing into the selected side (non-zero).
    pub normal: [f64; 3],
}

/// Which nodes a shape selector takes.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum NodeDomain {
    /// Nodes on the boundary of the tetrahedral mesh.
    Boundary,
    /// Every node of a tetrahedron.
    All,
}

impl Selector {
    /// Short description for messages, e.g. `sphere at (0.09, 0, 0.05) r = 0.012`.
    pub fn describe(&self) -> String {
        let on = match self.nodes {
            Some(NodeDomain::Boundary) => " on boundary nodes",
            Some(NodeDomain::All) => " on all nodes",
            None => "",
        };
        let p = |x: [f64; 3]| format!("({}, {}, {})", x[0], x[1], x[2]);
        if let Some(b) = &self.aabb {
            format!("box {} to {}{on}", p(b.min), p(b.max))
        } else if let Some(s) = &self.sphere {
            format!("sphere at {} r = {}{on}", p(s.center), s.radius)
        } else if let Some(h) = &self.half_space {
            format!(
                "half_space through {} normal {}{on}",
                p(h.point),
                p(h.normal)
            )
        } else if let Some(f) = &self.node_list {
            format!("node_list {}", f.display())
        } else if let Some(g) = &self.group {
            format!("group '{g}'")
        } else {
            format!("everything{on}")
        }
    }
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
    /// How the linear (warped) tier's modes are stepped ([`Scheme`]).
    #[serde(default)]
    pub scheme: Scheme,
}

/// The time discretisation of the linear (warped) tier's modal system (docs/design.md §2).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Scheme {
    /// Wilson-θ with the scene's θ (the co-rotational tier and the contact step use it too).
    #[default]
    WilsonTheta,
    /// Each mode's exact response to a load held over the step (zero-order hold).
    Exact,
}

impl Scheme {
    /// The scene's spelling.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::WilsonTheta => "wilson-theta",
            Scheme::Exact => "exact",
        }
    }
}

fn default_theta() -> f64 {
    1.4
}

/// Reduction settings (all optional; command-line flags override).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReductionSpec {
    /// Balanced truncation order r.
    pub order: Option<usize>,
    /// Relative tolerance on the Hankel singular values σ_i/σ_1 when `order` is absent.
    pub tolerance: Option<f64>,
    /// Number of vibration modes m kept before balancing.
    pub modes: Option<usize>,
    /// Highest frequency of the loads (and of the response the model must follow), Hz: the
    /// modal basis keeps every vibration mode up to twice this frequency, without the default
    /// cap of 60 modes, and the measured error's chirp sweeps up to it (docs/design.md §4).
    /// In (0, 1/(4Δt)]; exclusive with `modes`.
    pub max_frequency: Option<f64>,
    // --- The co-rotational tier (docs/design.md §10; compiler/src/nonlinear) ---
    /// Runtime model tier: `"warped"` (default, the warped linear model of §5) or
    /// `"corotational"` (the hyper-reduced co-rotational model of §10, trained by the compiler
    /// on `[reduction.corotational]`).
    #[serde(default)]
    pub model: ModelTier,
    /// Training envelope and sizes of the co-rotational tier (required with
    /// `model = "corotational"`, refused otherwise).
    pub corotational: Option<CorotationalSpec>,
}

/// Which runtime model the compiler writes.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ModelTier {
    /// The warped linear model (docs/design.md §5): the cheapest tier.
    #[default]
    Warped,
    /// The hyper-reduced co-rotational model (docs/design.md §10).
    Corotational,
}

/// `[reduction.corotational]`: what the compiler trains the co-rotational tier on and how big
/// the tier is. Training (docs/design.md §10 item 2): per load group named in `ranges`, each of
/// its `directions` (by default ±x, ±y, ±z and four diagonals) × {a ramp to `ramp_multiple`·F over `ramp_time`, a step to
/// `step_multiple`·F}, F the group's range; full-order co-rotational runs of `duration` s,
/// a snapshot every `every` steps.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CorotationalSpec {
    /// Load range per load group (scene load name → largest total force magnitude, N); by
    /// default every load's `range`. Groups without one are not trained on (and refused by the
    /// runtime's envelope check if loaded).
    #[serde(default)]
    pub ranges: std::collections::BTreeMap<String, f64>,
    /// Length of each training run, s.
    pub duration: f64,
    /// Snapshot every k steps (≥ 1).
    #[serde(default = "default_training_every")]
    pub every: usize,
    /// Final multiple of the range of the ramp runs (0 = no ramp runs).
    #[serde(default = "default_ramp_multiple")]
    pub ramp_multiple: f64,
    /// Ramp time, s (default duration/3).
    pub ramp_time: Option<f64>,
    /// Multiple of the range of the step runs (0 = no step runs).
    #[serde(default = "default_step_multiple")]
    pub step_multiple: f64,
    /// Basis size r (POD vectors of the training snapshots); None: [`CorotationalSpec::order`]
    /// (the fidelity rule's choice, `crate::nonlinear::fidelity`).
    pub order: Option<usize>,
    /// ECSW relative tolerance on the training forces; None: as `order`.
    pub ecsw_tolerance: Option<f64>,
    /// Runtime Newton: converged when ‖δq‖ ≤ tolerance ‖q‖.
    #[serde(default = "default_newton_tolerance")]
    pub newton_tolerance: f64,
    /// Runtime Newton: most iterations per step.
    #[serde(default = "default_newton_iterations")]
    pub newton_iterations: usize,
    /// Also train on every pair of load groups loaded together, in the same and opposite
    /// directions (scenes with two or more groups; e.g. an end torque made of two groups).
    /// Adds 2 × directions × histories runs per pair (docs/results/tier.md §6).
    /// None: true ([`CorotationalSpec::combinations`]). Not with `case`.
    pub combinations: Option<bool>,
    /// The world directions each load group is trained along (None: the six axes and the four
    /// diagonals of a regular tetrahedron, [`TrainingDirections`]). Not with `case`.
    pub directions: Option<TrainingDirections>,
    /// `[[reduction.corotational.case]]`: the training load cases, when the scene states them
    /// (each trained with both signs × the histories), instead of the runs generated from
    /// `directions` and `combinations`: for loads known to act together, e.g. a couple made
    /// of two groups pushed in opposite directions.
    #[serde(default, rename = "case")]
    pub cases: Vec<TrainingCase>,
    /// Per-run basis tolerance ε (optional): after the `order` pooled POD vectors, the basis is
    /// enriched until every training run's relative projection error in the energy norm
    /// (K-norm) is ≤ ε, at most `max_order` vectors (docs/results/tier.md §8). Without
    /// it, r = `order`.
    pub basis_tolerance: Option<f64>,
    /// Largest r with `basis_tolerance` (≥ `order`; default max(order, 60)).
    pub max_order: Option<usize>,
    /// Most ECSW-sampled elements; None: as `order`.
    pub ecsw_max_elements: Option<usize>,
    /// Factor on the tier's measured model error taken as process noise (docs/design.md
    /// §11.9): the filter's model-error covariance is the self-check's S × this factor. None:
    /// 1 (S as measured over the training runs); a value identified from a recording
    /// (`crokf-compile identify`, docs/identify.md) states how large the error is on the loads
    /// that recording saw; 0 turns the term off.
    pub model_error_scale: Option<f64>,
    /// Write the model even when the tier fails its own checks on most runs (more than half
    /// of its training runs, or of the runs held out of it, more than 5 % off the full-order
    /// co-rotational FEM). Default false: such a compile fails
    /// with the reason and the remedy, since the tier would be as far off at run time.
    #[serde(default)]
    pub accept_failed_check: bool,
    /// The largest element rotation a training snapshot may reach, degrees (0 < x ≤ 180).
    /// A training run is cut at its first snapshot past it, or with an inverted element
    /// (det F ≤ 0): the snapshots from there on are left out of the basis, the cubature and
    /// the checks, and the report names the run, the time and the multiple of the range
    /// reached. None: [`DEFAULT_MAX_ROTATION`].
    pub max_rotation: Option<f64>,
}

/// `[[reduction.corotational.case]]`: one training load case, the groups it loads together.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrainingCase {
    /// Name in the training runs' labels (default `case K`, K from 1).
    pub name: Option<String>,
    /// Load group → its force as a multiple of the group's range per world axis, [x, y, z]
    /// (length in (0, 1]): `{ upper = [0, 1, 0], lower = [0, -1, 0] }` is a couple at the
    /// groups' full ranges.
    pub loads: std::collections::BTreeMap<String, [f64; 3]>,
}

/// The length of a training direction or a case's force, [x, y, z] (the scene's check and
/// the training plan normalise by it).
pub fn length3(v: &[f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// `[reduction.corotational] directions`: the world directions of the training loads, a name
/// (`"axes"`, `"axes_and_diagonals"`) or a list of vectors (`[[0, 1, 0], [0, -1, 0]]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum TrainingDirections {
    /// ±x, ±y, ±z: 6 directions (the cheapest; loads off these axes are followed less well,
    /// docs/results/tier.md §11).
    Axes,
    /// ±x, ±y, ±z and the four diagonals (1, 1, 1), (1, −1, −1), (−1, 1, −1), (−1, −1, 1)
    /// (normalised): 10 directions. Axis runs never load two components together, so the
    /// response's coupling between components (quadratic in the load: the xy, xz, yz terms) is
    /// never seen; these four diagonals carry the three couplings with independent signs.
    #[default]
    AxesAndDiagonals,
    /// The scene's own world directions, as written (normalised when the plan is built;
    /// checked: finite, non-zero, no two the same): for loads known to act along a few
    /// directions only, e.g. a couple made of two groups pushed along ±y.
    List(Vec<[f64; 3]>),
}

impl<'de> Deserialize<'de> for TrainingDirections {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = TrainingDirections;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("\"axes\", \"axes_and_diagonals\" or a list of [x, y, z] directions")
            }
            fn visit_str<E: serde::de::Error>(self, name: &str) -> Result<Self::Value, E> {
                match name {
                    "axes" => Ok(TrainingDirections::Axes),
                    "axes_and_diagonals" => Ok(TrainingDirections::AxesAndDiagonals),
                    _ => Err(E::invalid_value(serde::de::Unexpected::Str(name), &self)),
                }
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Self::Value, A::Error> {
                let mut list = Vec::new();
                while let Some(d) = seq.next_element::<[f64; 3]>()? {
                    list.push(d);
                }
                Ok(TrainingDirections::List(list))
            }
        }
        deserializer.deserialize_any(Visitor)
    }
}

/// Most ECSW-sampled elements unless a scene says otherwise (also `EcswOptions::default`'s).
pub const DEFAULT_ECSW_MAX_ELEMENTS: usize = 200;

fn default_training_every() -> usize {
    5
}
fn default_ramp_multiple() -> f64 {
    1.25
}
fn default_step_multiple() -> f64 {
    0.6
}
fn default_newton_tolerance() -> f64 {
    1e-6
}
fn default_newton_iterations() -> usize {
    20
}

/// The tier's basis size unless the scene or the fidelity rule says otherwise.
pub const DEFAULT_TIER_ORDER: usize = 20;

/// The ECSW tolerance unless the scene or the fidelity rule says otherwise.
pub const DEFAULT_ECSW_TOLERANCE: f64 = 5e-3;

/// Default `[reduction.corotational] model_error_scale`: the tier's filter takes its measured
/// model error as it is (docs/design.md §11.9).
pub const DEFAULT_MODEL_ERROR_SCALE: f64 = 1.0;

/// Default `[reduction.corotational] max_rotation`, degrees: the largest element rotation a
/// training snapshot keeps, chosen on the cuts it makes (docs/results/tier.md §12).
pub const DEFAULT_MAX_ROTATION: f64 = 120.0;

impl CorotationalSpec {
    /// The training runs' rotation limit, degrees: as stated, else [`DEFAULT_MAX_ROTATION`].
    pub fn max_rotation(&self) -> f64 {
        self.max_rotation.unwrap_or(DEFAULT_MAX_ROTATION)
    }

    /// The pooled POD size: `order` as stated, else [`DEFAULT_TIER_ORDER`].
    pub fn order(&self) -> usize {
        self.order.unwrap_or(DEFAULT_TIER_ORDER)
    }

    /// The ECSW tolerance: as stated, else [`DEFAULT_ECSW_TOLERANCE`].
    pub fn ecsw_tolerance(&self) -> f64 {
        self.ecsw_tolerance.unwrap_or(DEFAULT_ECSW_TOLERANCE)
    }

    /// The factor on the measured model error: as stated, else [`DEFAULT_MODEL_ERROR_SCALE`].
    pub fn model_error_scale(&self) -> f64 {
        self.model_error_scale.unwrap_or(DEFAULT_MODEL_ERROR_SCALE)
    }

    /// The ECSW element cap: as stated, else [`DEFAULT_ECSW_MAX_ELEMENTS`].
    pub fn ecsw_max_elements(&self) -> usize {
        self.ecsw_max_elements.unwrap_or(DEFAULT_ECSW_MAX_ELEMENTS)
    }

    /// Whether the scene states the tier's size: any of `order`, `basis_tolerance`,
    /// `ecsw_tolerance`, `ecsw_max_elements`. Otherwise the compiler chooses it by the
    /// fidelity rule (`crate::nonlinear::fidelity`).
    pub fn states_size(&self) -> bool {
        self.order.is_some()
            || self.basis_tolerance.is_some()
            || self.ecsw_tolerance.is_some()
            || self.ecsw_max_elements.is_some()
    }

    /// The bound on r: `max_order`, or max(order, 60).
    pub fn largest_order(&self) -> usize {
        self.max_order.unwrap_or(self.order().max(60))
    }

    /// Pair runs: as stated, else true.
    pub fn combinations(&self) -> bool {
        self.combinations.unwrap_or(true)
    }

    /// The training directions: as stated, else the axes and the four diagonals.
    pub fn directions(&self) -> TrainingDirections {
        self.directions.clone().unwrap_or_default()
    }
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
    /// Where a tool may touch the body (at most one region; docs/contact.md).
    #[serde(default, rename = "contact")]
    pub contacts: Vec<Contact>,
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
    /// Reads, parses and range-checks a scene file. A UTF-8 byte-order mark is skipped (and
    /// kept in [`SceneFile::text`], so the digest is that of the file); a `mesh.file` that names
    /// a directory is refused here, naming the field.
    pub fn read(path: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            kind: "scene",
            path: path.to_owned(),
            source,
        })?;
        let scene = Scene::parse(&text, path)?;
        let file = SceneFile {
            path: path.to_owned(),
            text,
            scene,
        };
        let mesh = file.mesh_path();
        if mesh.is_dir() {
            return Err(SceneError::Invalid {
                path: path.to_owned(),
                what: format!(
                    "mesh.file = {:?}: {} is a directory, not a mesh file",
                    file.scene.mesh.file.display().to_string(),
                    mesh.display()
                ),
            });
        }
        Ok(file)
    }

    /// Absolute or working-directory path of the mesh file.
    pub fn mesh_path(&self) -> PathBuf {
        match self.path.parent() {
            Some(dir) => dir.join(&self.scene.mesh.file),
            None => self.scene.mesh.file.clone(),
        }
    }

    /// The files the scene makes a command read besides itself, each with its role: the mesh
    /// (`"mesh"`) and the `node_list` files (`"node_list"`, in scene order). The commands
    /// refuse an output over any of them.
    pub fn input_files(&self) -> Vec<(&'static str, PathBuf)> {
        std::iter::once(("mesh", self.mesh_path()))
            .chain(
                self.scene
                    .node_list_files()
                    .into_iter()
                    .map(|p| ("node_list", p.to_path_buf())),
            )
            .collect()
    }
}

/// Accepted ranges of the physical fields, (min, max) inclusive, SI units.
pub mod limits {
    /// Young's modulus E, Pa (a soft gel is ~1e2 Pa, diamond 1.2e12 Pa).
    pub const YOUNG_MODULUS: (f64, f64) = (1.0, 1e13);
    /// Density ρ, kg/m³ (aerogels ~1, osmium 2.3e4).
    pub const DENSITY: (f64, f64) = (1e-3, 1e6);
    /// Rayleigh α, 1/s.
    pub const ALPHA: (f64, f64) = (0.0, 1e6);
    /// Rayleigh β, s.
    pub const BETA: (f64, f64) = (0.0, 1e3);
    /// Largest gravity component magnitude, m/s².
    pub const GRAVITY: f64 = 1e4;
    /// Force noise standard deviation, N.
    pub const FORCE_NOISE: (f64, f64) = (0.0, 1e9);
    /// Sensor noise standard deviation, m.
    pub const SENSOR_NOISE: (f64, f64) = (1e-12, 1e3);
    /// Time step Δt, s.
    pub const DT: (f64, f64) = (1e-7, 10.0);
    /// Wilson θ.
    pub const THETA: (f64, f64) = (1.37, 10.0);
    /// Largest coordinate magnitude in a scene, mesh units.
    pub const COORDINATE: f64 = 1e9;
    /// Poisson's ratio from which linear tetrahedra lock noticeably (a warning, not an error).
    pub const LOCKING_POISSON: f64 = 0.49;
}

impl Scene {
    /// Why this scene cannot be stepped with `[time] scheme = "exact"`, or None when it can.
    pub fn exact_scheme_refusal(&self) -> Option<&'static str> {
        if !self.contacts.is_empty() {
            return Some(
                "time.scheme = \"exact\" with a [[contact]] region: the contact step enforces \
                 its gap at Wilson-θ's θ-point (docs/contact.md); use the default scheme \
                 \"wilson-theta\" with a contact region",
            );
        }
        if self.reduction.model == ModelTier::Corotational {
            return Some(
                "time.scheme = \"exact\" with [reduction] model = \"corotational\": the \
                 co-rotational tier steps its Newton iterations with Wilson-θ; the exact scheme \
                 is for the linear (warped) tier",
            );
        }
        if self.damping.alpha == 0.0 && self.damping.beta == 0.0 {
            return Some(
                "time.scheme = \"exact\" needs damping (damping.alpha or damping.beta > 0): \
                 undamped modes stepped exactly never decay, and the balanced truncation needs \
                 a stable system",
            );
        }
        None
    }

    /// The range of load `l`, N: its own `range`, else the co-rotational tier's `ranges` entry.
    pub fn load_range(&self, l: &Load) -> Option<f64> {
        l.range.or_else(|| {
            self.reduction
                .corotational
                .as_ref()
                .and_then(|c| c.ranges.get(&l.name).copied())
        })
    }

    /// The co-rotational tier trains on every load that states a `range` unless its
    /// `[reduction.corotational] ranges` names the load already (which must then agree).
    fn resolve_ranges(&mut self) -> Result<(), String> {
        let Some(spec) = self.reduction.corotational.as_mut() else {
            return Ok(());
        };
        for l in &self.loads {
            let Some(range) = l.range else { continue };
            match spec.ranges.get(&l.name) {
                Some(&tier) if tier != range => {
                    return Err(format!(
                        "load '{}': range = {range} N but reduction.corotational.ranges.{} = \
                         {tier} N: state the range once (the load's `range` is enough)",
                        l.name, l.name
                    ))
                }
                Some(_) => {}
                None => {
                    spec.ranges.insert(l.name.clone(), range);
                }
            }
        }
        Ok(())
    }

    /// The `[[contact]]` entries: at most one, each complete and in range, on the warped tier.
    fn check_contacts(&self) -> Result<(), String> {
        if self.contacts.len() > 1 {
            return Err(format!(
                "{} [[contact]] regions: a scene has at most one (give its `select` several \
                 selectors instead)",
                self.contacts.len()
            ));
        }
        for (i, c) in self.contacts.iter().enumerate() {
            c.check(i)?;
            if self.reduction.model == ModelTier::Corotational {
                return Err(format!(
                    "contact[{i}] '{}': contact runs on the warped linear tier only; remove \
                     [reduction] model = \"corotational\" or the [[contact]] entry",
                    c.name
                ));
            }
        }
        Ok(())
    }

    /// Parses scene text; `path` names the file in messages and anchors relative `node_list`
    /// paths. A leading UTF-8 byte-order mark is skipped.
    pub fn parse(text: &str, path: &Path) -> Result<Self, SceneError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut scene: Scene = toml::from_str(text).map_err(|e| SceneError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        scene
            .resolve_ranges()
            .and_then(|()| scene.check())
            .and_then(|()| scene.check_contacts())
            .map_err(|what| SceneError::Invalid {
                path: path.to_owned(),
                what,
            })?;
        if let Some(dir) = path.parent() {
            for sel in scene.selectors_mut() {
                if let Some(f) = &mut sel.node_list {
                    *f = dir.join(&*f);
                }
            }
        }
        Ok(scene)
    }

    /// The `node_list` files the scene's selections name (resolved against the scene's folder),
    /// in scene order, each once.
    pub fn node_list_files(&self) -> Vec<&Path> {
        let m = self.materials.iter().map(|x| &x.select);
        let f = self.fixed.iter().map(|x| &x.select);
        let l = self.loads.iter().map(|x| &x.select);
        let n = self.force_noise.iter().map(|x| &x.select);
        let d = self.display.iter().map(|x| &x.select);
        let c = self.contacts.iter().map(|x| &x.select);
        let mut files: Vec<&Path> = Vec::new();
        for sel in m
            .chain(f)
            .chain(l)
            .chain(n)
            .chain(d)
            .chain(c)
            .flatten()
            .flatten()
        {
            if let Some(file) = sel.node_list.as_deref() {
                if !files.contains(&file) {
                    files.push(file);
                }
            }
        }
        files
    }

    fn selectors_mut(&mut self) -> impl Iterator<Item = &mut Selector> {
        let m = self.materials.iter_mut().map(|x| &mut x.select);
        let f = self.fixed.iter_mut().map(|x| &mut x.select);
        let l = self.loads.iter_mut().map(|x| &mut x.select);
        let n = self.force_noise.iter_mut().map(|x| &mut x.select);
        let d = self.display.iter_mut().map(|x| &mut x.select);
        let c = self.contacts.iter_mut().map(|x| &mut x.select);
        m.chain(f)
            .chain(l)
            .chain(n)
            .chain(d)
            .chain(c)
            .flat_map(|s| s.iter_mut().flatten())
    }

    /// Legal but suspect settings, one sentence each (the wiring prints them as notes):
    /// ν ≥ 0.49 on linear tetrahedra (volumetric locking).
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (i, m) in self.materials.iter().enumerate() {
            if m.poisson_ratio >= limits::LOCKING_POISSON {
                out.push(format!(
                    "material {} ({}): poisson_ratio = {} ≥ {}: linear tetrahedra lock near \
                     incompressibility, so the model is too stiff (docs/design.md §3); expect \
                     displacements well below the true ones",
                    i + 1,
                    m.target(),
                    m.poisson_ratio,
                    limits::LOCKING_POISSON
                ));
            }
        }
        out
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

    /// The files a scene makes a command read: its mesh beside it, then its node lists in
    /// scene order, each once per selector that names it.
    #[test]
    fn input_files_are_the_mesh_and_the_node_lists() {
        let dir = Path::new("/data/body");
        let text = MINIMAL.replace(
            "[time]",
            "[[fixed]]\nselect = [{ node_list = \"base.txt\" }]\n\
             [[load]]\nname = \"push\"\nrange = 1.0\nselect = [{ node_list = \"tip.txt\" }]\n[time]",
        );
        let file = SceneFile {
            path: dir.join("scene.toml"),
            scene: Scene::parse(&text, &dir.join("scene.toml")).unwrap(),
            text,
        };
        assert_eq!(
            file.input_files(),
            [
                ("mesh", dir.join("m.msh")),
                ("node_list", dir.join("base.txt")),
                ("node_list", dir.join("tip.txt")),
            ]
        );
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

    /// `[time] scheme`: the default, both spellings, an unknown one, and the combinations the
    /// exact scheme cannot serve (no damping, a contact region, the co-rotational tier).
    #[test]
    fn the_time_scheme_is_read_and_checked() {
        assert_eq!(parse(MINIMAL).unwrap().time.scheme, Scheme::WilsonTheta);
        let damped = MINIMAL.replace("[time]", "[damping]\nalpha = 1.0\n[time]");
        for (text, scheme) in [
            ("wilson-theta", Scheme::WilsonTheta),
            ("exact", Scheme::Exact),
        ] {
            let scene =
                parse(&damped.replace("dt = 0.01", &format!("dt = 0.01\nscheme = \"{text}\"")))
                    .unwrap();
            assert_eq!(scene.time.scheme, scheme);
            assert_eq!(scheme.name(), text);
        }
        let exact = |text: &str| {
            parse(&text.replace("dt = 0.01", "dt = 0.01\nscheme = \"exact\""))
                .unwrap_err()
                .to_string()
        };
        let e = parse(&MINIMAL.replace("dt = 0.01", "dt = 0.01\nscheme = \"newmark\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("newmark") && e.contains("exact"), "{e}");
        assert!(exact(MINIMAL).contains("needs damping"));
        let e = exact(&damped.replace("[time]", "[reduction]\nmodel = \"corotational\"\n[time]"));
        assert!(e.contains("Newton iterations"), "{e}");
        let e = exact(&damped.replace(
            "[time]",
            "[[contact]]\nname = \"touch\"\nselect = [{ group = \"body\" }]\nradius = 0.001\nmax_force = 3.0\n[time]",
        ));
        assert!(e.contains("θ-point"), "{e}");
    }

    #[test]
    fn small_theta_is_refused() {
        let e = parse(&MINIMAL.replace("dt = 0.01", "dt = 0.01\ntheta = 1.2"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("theta"), "{e}");
    }
}
