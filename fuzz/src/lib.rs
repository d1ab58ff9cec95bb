//! Structure-aware mutation fuzzing of the readers a user's files go through:
//! the scene reader (TOML → range checks → group and selection resolution → assembly and
//! operators on a small mesh), the mesh readers (gmsh MSH 1.0 / 2.2 / 4.1 ASCII and binary,
//! legacy VTK, VTU), `crokf-run`'s CSV readers, and VTK files whose claimed sizes
//! are mutated ([`grid`]: binary, zlib, LZ4 and base64 blocks, appended data, legacy counts;
//! a panic a reader catches from a dependency counts as a failure) and node-list files. The model-file decoder has its own long run
//! in `crokf-formats` (`cargo run --release -p crokf-formats --example mutate`).
//!
//! Each target takes bytes and returns [`Outcome::Accepted`] or [`Outcome::Refused`]; an
//! accepted input must satisfy the target's invariants (indices in range, finite values,
//! matching shapes), otherwise the target returns [`Violation`]. A panic is a bug: the driver
//! ([`run`]) catches it, keeps the input and reports it. Mutations are structure-aware:
//! numbers are replaced by boundary values (0, −0, 1e300, NaN, inf, huge integers), names by
//! names the readers know, lines deleted, duplicated, swapped or inserted from a dictionary of
//! scene and mesh keywords, besides byte flips, insertions, deletions and repeats.

pub mod grid;

use crokf_compile::fem::operators::Operators;
use crokf_compile::fem::FemModel;
use crokf_compile::mesh::procedural::{box_mesh, BeamScene};
use crokf_compile::mesh::{read_mesh_bytes, Mesh};

/// The mesh type the scene target resolves against (re-exported for the libFuzzer targets).
pub type MeshFixture = Mesh;
use crokf_compile::scene::Scene;
use crokf_runtime::Model;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a target did with one input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Read and checked: the invariants hold.
    Accepted,
    /// Refused with an error message (the normal fate of a broken input).
    Refused,
}

/// An accepted input that breaks an invariant: a reader bug, like a panic.
#[derive(Debug)]
pub struct Violation(pub String);

/// The fuzzed readers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Target {
    /// Scene text through parsing, range checks, selections, assembly and operators.
    Scene,
    /// Mesh files, every format `read_mesh_bytes` recognises.
    Mesh,
    /// `crokf-run` inputs and measurements CSV.
    Csv,
    /// VTK files (XML and legacy) with mutated claimed sizes ([`grid::case`]).
    Vtu,
    /// Node-list files of a `[[fixed]]` selection.
    NodeList,
}

impl Target {
    /// All targets, in the order the driver runs them.
    pub const ALL: [Target; 5] = [
        Target::Scene,
        Target::Mesh,
        Target::Csv,
        Target::Vtu,
        Target::NodeList,
    ];

    /// Lower-case name (command line, crash file names).
    pub fn name(self) -> &'static str {
        match self {
            Target::Scene => "scene",
            Target::Mesh => "mesh",
            Target::Csv => "csv",
            Target::Vtu => "vtu",
            Target::NodeList => "node_list",
        }
    }
}

/// The generator that picks mutations (SplitMix64, shared with the runtime's tests).
pub use crokf_formats::synthetic::SplitMix64 as Rng;

/// Boundary values that a number token is replaced by.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "0.0",
    "-1",
    "1",
    "2",
    "3",
    "4",
    "1e300",
    "-1e300",
    "1e-300",
    "1e6",
    "0.4999999",
    "0.5",
    "nan",
    "inf",
    "-inf",
    "NaN",
    "2147483648",
    "-2147483649",
    "4294967296",
    "18446744073709551616",
    "9999999999",
    "1.5",
    "-2.5e-3",
    "",
];

/// Names the readers know (groups, keywords, components, selectors).
const NAMES: &[&str] = &[
    "body",
    "xmin",
    "xmax",
    "surface",
    "everything",
    "tip",
    "3:1",
    "2:1",
    "0:0",
    "",
    ".",
    "..",
    "x",
    "y",
    "z",
    "m",
    "mm",
    "cm",
    "area",
    "uniform",
    "white",
    "random_walk",
    "boundary",
    "all",
    "MaterialIds:1",
    "\u{feff}",
    "é",
];

/// Lines inserted into scene texts.
const SCENE_LINES: &[&str] = &[
    "[[sensor]]",
    "name = \"s\"",
    "position = [0.5, 0.05, 0.1]",
    "components = [\"x\"]",
    "noise_std = 1e-3",
    "every = 0",
    "every = 3",
    "[[load]]",
    "name = \"tip\"",
    "group = \"xmax\"",
    "[[fixed]]",
    "group = \"xmin\"",
    "[[display]]",
    "[[material]]",
    "[[force_noise]]",
    "select = [{ box = { min = [0, 0, 0], max = [0.2, 0.1, 0.1] }, nodes = \"boundary\" }]",
    "select = [{ sphere = { center = [1, 0.05, 0.05], radius = 0.1 }, nodes = \"all\" }]",
    "select = [{ half_space = { point = [0.9, 0, 0], normal = [1, 0, 0] }, nodes = \"boundary\" }]",
    "select = [{ everything = true, nodes = \"all\" }]",
    "select = [{ group = \"xmax\" }, { box = { min = [0, 0, 0], max = [1, 1, 1] }, nodes = \"boundary\" }]",
    "nodes = \"boundary\"",
    "gravity = [0, 0, -9.81]",
    "[reduction]",
    "order = 4",
    "tolerance = 1e-3",
    "[time]",
    "dt = 1e-3",
    "theta = 1.4",
    "[damping]",
    "alpha = 0",
    "beta = 0",
    "units = \"mm\"",
    "distribution = \"uniform\"",
    "force_noise_std = 0.5",
    "force_model = \"random_walk\"",
    "young_modulus = 1e6",
    "poisson_ratio = 0.49",
    "density = 1000",
    "[mesh]",
    "file = \"beam.msh\"",
    "# comment",
    "",
];

/// Lines inserted into mesh texts.
const MESH_LINES: &[&str] = &[
    "$MeshFormat",
    "$EndMeshFormat",
    "4.1 0 8",
    "2.2 0 8",
    "$Nodes",
    "$EndNodes",
    "$Elements",
    "$EndElements",
    "$PhysicalNames",
    "$EndPhysicalNames",
    "1 4 1 1 1 2 3 4",
    "3 1 \"body\"",
    "0 0 0 0",
    "CELLS 1 5",
    "CELL_TYPES 1",
    "10",
    "POINTS 4 float",
    "<DataArray type=\"Int32\" Name=\"MaterialIds\" format=\"ascii\">",
    "</DataArray>",
    "</Piece>",
    "",
];

/// A number-token span in `text` starting at a random position, if any.
fn number_span(text: &[u8], rng: &mut Rng) -> Option<(usize, usize)> {
    let is_num = |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E');
    let start = rng.below(text.len().max(1));
    let from = (start..text.len()).find(|&i| text[i].is_ascii_digit())?;
    let mut a = from;
    while a > 0 && is_num(text[a - 1]) {
        a -= 1;
    }
    let mut b = from;
    while b < text.len() && is_num(text[b]) {
        b += 1;
    }
    Some((a, b))
}

/// A quoted-string span (contents only) starting at a random position, if any.
fn string_span(text: &[u8], rng: &mut Rng) -> Option<(usize, usize)> {
    let start = rng.below(text.len().max(1));
    let open = (start..text.len()).find(|&i| text[i] == b'"')?;
    let close = (open + 1..text.len()).find(|&i| text[i] == b'"')?;
    Some((open + 1, close))
}

/// Byte offsets of line starts.
fn line_starts(text: &[u8]) -> Vec<usize> {
    std::iter::once(0)
        .chain(
            text.iter()
                .enumerate()
                .filter(|(_, &b)| b == b'\n')
                .map(|(i, _)| i + 1),
        )
        .filter(|&i| i <= text.len())
        .collect()
}

/// The line containing a random byte: `[start, end)` including its newline.
fn line_span(text: &[u8], rng: &mut Rng) -> (usize, usize) {
    let starts = line_starts(text);
    let k = rng.below(starts.len());
    let end = starts.get(k + 1).copied().unwrap_or(text.len());
    (starts[k], end)
}

/// One structure-aware mutation of `text`, using `lines` as the insertion dictionary.
pub fn mutate(text: &mut Vec<u8>, rng: &mut Rng, lines: &[&str]) {
    match rng.below(12) {
        0..=2 => {
            if let Some((a, b)) = number_span(text, rng) {
                text.splice(a..b, rng.pick(NUMBERS).bytes());
            }
        }
        3 => {
            if let Some((a, b)) = string_span(text, rng) {
                text.splice(a..b, rng.pick(NAMES).bytes());
            }
        }
        4 => {
            let (a, b) = line_span(text, rng);
            text.drain(a..b);
        }
        5 => {
            let (a, b) = line_span(text, rng);
            let line = text[a..b].to_vec();
            text.splice(b..b, line);
        }
        6 => {
            let (a, _) = line_span(text, rng);
            let mut line = rng.pick(lines).as_bytes().to_vec();
            line.push(b'\n');
            text.splice(a..a, line);
        }
        7 => {
            let (a, b) = line_span(text, rng);
            let (c, d) = line_span(text, rng);
            if b <= c {
                let first = text[a..b].to_vec();
                let second = text[c..d].to_vec();
                text.splice(c..d, first);
                text.splice(a..b, second);
            }
        }
        8 if !text.is_empty() => {
            let at = rng.below(text.len());
            text[at] ^= 1 << rng.below(8);
        }
        9 => {
            let at = rng.below(text.len() + 1);
            let byte = (rng.next_u64() & 0xff) as u8;
            text.insert(at, byte);
        }
        10 if !text.is_empty() => {
            let at = rng.below(text.len());
            let len = 1 + rng.below(16);
            text.drain(at..(at + len).min(text.len()));
        }
        _ if !text.is_empty() => {
            let at = rng.below(text.len());
            let end = (at + 1 + rng.below(64)).min(text.len());
            let chunk = text[at..end].to_vec();
            let to = rng.below(text.len() + 1);
            text.splice(to..to, chunk);
        }
        _ => text.push(b'\n'),
    }
}

/// The small mesh every fuzzed scene is resolved against: a 1 m × 0.1 m × 0.1 m box, 4 × 1 × 1
/// cells (24 tetrahedra), groups `body`, `xmin`, `xmax`.
pub fn scene_mesh() -> Mesh {
    box_mesh([4, 1, 1], [1.0, 0.1, 0.1])
}

/// Scene seeds: the benchmark beam scene and variants using selections, gravity, multi-rate
/// sensors, force noise and reduction settings, all valid on [`scene_mesh`].
pub fn scene_seeds() -> Vec<Vec<u8>> {
    let beam = BeamScene::default().toml();
    let with = |extra: &str| format!("{beam}{extra}").into_bytes();
    vec![
        beam.clone().into_bytes(),
        with("[reduction]\norder = 4\n"),
        with("[[force_noise]]\nname = \"bulk\"\nselect = [{ everything = true, nodes = \"all\" }]\nstd = 0.01\n"),
        with(
            "[[sensor]]\nname = \"mid\"\nposition = [0.5, 0.05, 0.1]\ncomponents = [\"z\"]\n\
             noise_std = 1e-3\nevery = 5\n",
        ),
        BeamScene {
            force_model: Some("random_walk".into()),
            displays: vec![("tip".into(), "xmax".into())],
            ..BeamScene::default()
        }
        .toml()
        .into_bytes(),
        beam.replace(
            "group = \"xmax\"",
            "select = [{ half_space = { point = [0.9, 0, 0], normal = [1, 0, 0] }, nodes = \"boundary\" }]",
        )
        .into_bytes(),
        beam.replace(
            "group = \"xmin\"",
            "select = [{ box = { min = [-0.01, -1, -1], max = [0.01, 1, 1] }, nodes = \"all\" }]",
        )
        .into_bytes(),
    ]
}

/// The scene target: parse and range-check, then assemble K, M and the operators on `mesh`.
/// Invariants of an accepted scene: K and M finite, operators' node and element indices in
/// range, every input and sensor with a finite, positive noise where one is given.
pub fn scene(data: &[u8], mesh: &Mesh) -> Result<Outcome, Violation> {
    let Ok(text) = std::str::from_utf8(data) else {
        return Ok(Outcome::Refused);
    };
    let path = Path::new("fuzz/scene.toml");
    if text.contains("node_list") {
        // A mutated node_list path would read arbitrary files of this machine (and a device
        // file would never end): node-list files are covered by compiler/tests/selection.rs.
        return Ok(Outcome::Refused);
    }
    let Ok(scene) = Scene::parse(text, path) else {
        return Ok(Outcome::Refused);
    };
    let unit = scene.mesh.units.to_metres();
    let Ok(fem) = FemModel::assemble(mesh, &scene, unit) else {
        return Ok(Outcome::Refused);
    };
    let Ok(ops) = Operators::build(mesh, &scene, &fem, unit) else {
        return Ok(Outcome::Refused);
    };
    let finite_k = fem.stiffness.val().iter().all(|v| v.is_finite());
    let finite_m = fem.mass.val().iter().all(|v| v.is_finite());
    if !finite_k || !finite_m {
        return Err(Violation(
            "accepted scene assembles a non-finite K or M".into(),
        ));
    }
    let n = mesh.nodes.len();
    for set in &ops.node_sets {
        if set.nodes.iter().any(|&i| i >= n) {
            return Err(Violation(format!(
                "node set {:?}: node out of range",
                set.name
            )));
        }
    }
    for s in &ops.sensors {
        if s.element >= mesh.tetrahedra.len() || s.noise_std.iter().any(|v| !v.is_finite()) {
            return Err(Violation(
                "sensor in no element or with a non-finite σ".into(),
            ));
        }
    }
    Ok(Outcome::Accepted)
}

/// Mesh seeds: the format fixtures of the compiler's tests (MSH 1.0, 2.2, 4.1 ASCII/binary,
/// sparse tags, reversed orientation; VTU ASCII, zlib, appended; legacy VTK ASCII and binary).
pub fn mesh_seeds() -> Vec<(String, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../compiler/tests/fixtures");
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    std::fs::read(e.path()).ok().map(|b| (name, b))
                })
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

/// The mesh target. Invariants of an accepted mesh: at least one tetrahedron, finite
/// coordinates, every element and group index in range, groups' node lists sorted and unique.
pub fn mesh(data: &[u8], name: &str) -> Result<Outcome, Violation> {
    let path = PathBuf::from(format!("fuzz/{name}"));
    let Ok(m) = read_mesh_bytes(data, &path) else {
        return Ok(Outcome::Refused);
    };
    let n = m.nodes.len();
    if m.tetrahedra.is_empty() {
        return Err(Violation("accepted a mesh with no tetrahedra".into()));
    }
    if m.nodes.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Violation("accepted a non-finite coordinate".into()));
    }
    if m.node_tags.len() != n {
        return Err(Violation("node tags and nodes differ in length".into()));
    }
    if m.tetrahedra.iter().any(|t| t.nodes.iter().any(|&i| i >= n))
        || m.triangles.iter().any(|t| t.nodes.iter().any(|&i| i >= n))
    {
        return Err(Violation("an element names a node out of range".into()));
    }
    for g in &m.groups {
        let elements = match g.dim {
            3 => m.tetrahedra.len(),
            2 => m.triangles.len(),
            _ => 0,
        };
        if g.nodes.iter().any(|&i| i >= n)
            || g.elements.iter().any(|&e| e >= elements)
            || g.nodes.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(Violation(format!(
                "group {:?}: index out of range or unsorted",
                g.name
            )));
        }
    }
    Ok(Outcome::Accepted)
}

/// The VTK target: [`mesh`]'s invariants, and no panic caught inside a dependency (a reader's
/// own checks must refuse the file before a third-party parser panics on it).
pub fn vtu(data: &[u8]) -> Result<Outcome, Violation> {
    let before = crokf_compile::mesh::caught_panics();
    let name = if data.starts_with(b"# vtk") {
        "fuzz.vtk"
    } else {
        "fuzz.vtu"
    };
    let outcome = mesh(data, name)?;
    if crokf_compile::mesh::caught_panics() != before {
        return Err(Violation(
            "a third-party parser panicked (caught at the reader's boundary)".into(),
        ));
    }
    Ok(outcome)
}

/// Lines inserted into node lists.
const NODE_LINES: &[&str] = &[
    "1",
    "2, 3",
    "4 5 6",
    "# comment",
    "1 # again",
    "7,8,,9",
    "0",
    "-1",
    "999999",
    "18446744073709551615",
    "18446744073709551616",
    "1e3",
    "0x10",
    "\u{feff}3",
    "\t10\t",
    "",
];

/// Node-list seeds for [`scene_mesh`] (node tags 1 to 20).
pub fn node_list_seeds() -> Vec<Vec<u8>> {
    vec![
        b"1 2 3\n".to_vec(),
        b"# the x = 0 end\n1, 6\n11 16 # last\n".to_vec(),
        "\u{feff}5\n10\n15\n".as_bytes().to_vec(),
        (1..=15)
            .map(|t| t.to_string())
            .collect::<Vec<_>>()
            .join("\n")
            .into_bytes(),
    ]
}

/// The node-list target: the list is written to a file that a `[[fixed]]` selection of the
/// beam scene reads, and the scene is assembled on [`scene_mesh`]. The list is also parsed
/// here, independently (UTF-8, a leading byte-order mark skipped, `#` comments, tags separated
/// by commas or whitespace): an accepted list must fix exactly its tags, each a node of the mesh
/// (a tag listed again counts once); a list that passes the independent parse must be accepted.
pub fn node_list(data: &[u8], mesh: &Mesh) -> Result<Outcome, Violation> {
    use std::sync::OnceLock;
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("crokf-fuzz-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&d);
        d
    });
    let file = dir.join(format!("nodes-{:?}.txt", std::thread::current().id()));
    std::fs::write(&file, data).map_err(|e| Violation(format!("cannot write {file:?}: {e}")))?;
    let beam = BeamScene::default().toml().replace(
        "[[fixed]]\ngroup = \"xmin\"",
        &format!(
            "[[fixed]]\nselect = [{{ node_list = {:?} }}]",
            file.display().to_string()
        ),
    );
    let scene = Scene::parse(&beam, &dir.join("scene.toml"))
        .map_err(|e| Violation(format!("the node-list scene does not parse: {e}")))?;
    let expected = independent_node_list(data, mesh);
    let fem = match FemModel::assemble(mesh, &scene, scene.mesh.units.to_metres()) {
        Ok(fem) => fem,
        // A valid list may still make a scene the assembly refuses (every node fixed): only a
        // refusal of the list itself breaks the invariant.
        Err(e) => {
            let message = e.to_string();
            return match expected {
                Some(tags) if message.contains("node_list") => Err(Violation(format!(
                    "refused a valid node list of {} tags: {message}",
                    tags.len()
                ))),
                _ => Ok(Outcome::Refused),
            };
        }
    };
    let Some(tags) = expected else {
        return Err(Violation("accepted a node list that is not valid".into()));
    };
    let fixed: Vec<u64> = fem
        .dofs
        .index
        .iter()
        .enumerate()
        .filter(|(_, d)| d.iter().all(Option::is_none))
        .map(|(i, _)| mesh.node_tags[i])
        .collect();
    let mut want = tags;
    want.sort_unstable();
    if fixed != want {
        return Err(Violation(format!(
            "fixed nodes {fixed:?}, the list names {want:?}"
        )));
    }
    Ok(Outcome::Accepted)
}

/// The tags of a valid node list (see [`node_list`]), `None` for an invalid one.
fn independent_node_list(data: &[u8], mesh: &Mesh) -> Option<Vec<u64>> {
    let text = std::str::from_utf8(data).ok()?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut tags = Vec::new();
    for line in text.lines() {
        let content = line.split('#').next().unwrap_or("");
        for token in content
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
        {
            let tag: u64 = token.parse().ok()?;
            if !mesh.node_tags.contains(&tag) {
                return None;
            }
            // A tag listed again is used once (the reader warns).
            if !tags.contains(&tag) {
                tags.push(tag);
            }
        }
    }
    (!tags.is_empty()).then_some(tags)
}

/// CSV seeds (inputs, measurements) for the committed cantilever model: its channels are
/// `tip.x,tip.y,tip.z` (inputs) and three markers × three components (measurements).
pub fn csv_seeds(model: &Model) -> (Vec<u8>, Vec<u8>) {
    let input_labels = model.input_labels();
    let measurement_labels = model.measurement_labels();
    let inputs = input_labels.join(",");
    let outputs = measurement_labels.join(",");
    let row = |k: usize, n: usize, scale: f64| {
        (0..n)
            .map(|j| format!("{:e}", scale * (k + j) as f64))
            .collect::<Vec<_>>()
            .join(",")
    };
    let ni = input_labels.len();
    let nm = measurement_labels.len();
    let mut a = format!("step,{inputs}\n");
    let mut b = format!("# markers\nt,{outputs}\n");
    for k in 1..6 {
        a += &format!("{k},{}\n", row(k, ni, 0.1));
        b += &format!("{:e},{}\n", k as f64 * 5e-3, row(k, nm, 1e-4));
    }
    (a.into_bytes(), b.into_bytes())
}

/// The CSV target: inputs and measurements through `crokf-run`'s readers. Invariants of an
/// accepted table: one finite value per channel in every row (measurements may be missing),
/// a source line per row.
pub fn csv(inputs: &[u8], measurements: &[u8], model: &Model) -> Result<Outcome, Violation> {
    use crokf_run::table;
    let mut accepted = false;
    if let Ok(t) = table::parse_inputs(Path::new("inputs.csv"), inputs, model) {
        accepted = true;
        if t.rows.is_empty() || t.rows.len() != t.lines.len() {
            return Err(Violation("accepted inputs without rows or lines".into()));
        }
        if t.rows
            .iter()
            .any(|r| r.len() != model.input_labels().len() || r.iter().any(|v| !v.is_finite()))
        {
            return Err(Violation(
                "accepted an input row of the wrong width or non-finite".into(),
            ));
        }
    }
    if let Ok(t) = table::parse_measurements(Path::new("m.csv"), measurements, model) {
        accepted = true;
        let width = model.measurement_labels().len();
        if t.values()
            .any(|r| r.values.len() != width || r.values.iter().flatten().any(|v| !v.is_finite()))
        {
            return Err(Violation(
                "accepted a measurement row of the wrong width or non-finite".into(),
            ));
        }
    }
    Ok(if accepted {
        Outcome::Accepted
    } else {
        Outcome::Refused
    })
}

/// Counts of one target's run.
#[derive(Clone, Debug, Default)]
pub struct Tally {
    /// Cases run.
    pub cases: u64,
    /// Accepted (invariants held).
    pub accepted: u64,
    /// Refused with an error.
    pub refused: u64,
    /// Panics and invariant violations, with the case number, message and input.
    pub failures: Vec<(u64, String, Vec<u8>)>,
    /// Wall time, s.
    pub seconds: f64,
}

/// Inputs the driver needs once: the scene mesh and the model whose channels the CSV readers
/// check against.
pub struct Fixtures {
    /// [`scene_mesh`].
    pub mesh: Mesh,
    /// The committed cantilever model (`models/cantilever/model.crokf`).
    pub model: Model,
}

impl Fixtures {
    /// Loads the fixtures; the error names the model file.
    pub fn load() -> Result<Self, String> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/cantilever/model.crokf");
        let model =
            crokf_runtime::load_model(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(Fixtures {
            mesh: scene_mesh(),
            model,
        })
    }
}

/// Runs `cases` mutated inputs through `target`, `1 + case % 4` mutations of a seed each.
/// Panics are caught (the default hook is silenced for the run) and recorded with the input.
pub fn run(target: Target, cases: u64, seed: u64, fixtures: &Fixtures) -> Tally {
    let mut rng = Rng(seed ^ (target as u64).wrapping_mul(0x51_7cc1_b727_220a));
    let scenes = scene_seeds();
    let meshes = mesh_seeds();
    let (csv_inputs, csv_measurements) = csv_seeds(&fixtures.model);
    let lists = node_list_seeds();
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let start = Instant::now();
    let mut tally = Tally::default();
    for case in 0..cases {
        let mutations = 1 + (case % 4) as usize;
        let (data, second, name) = match target {
            Target::Scene => (rng.pick(&scenes).clone(), Vec::new(), String::new()),
            Target::Mesh => {
                let (name, bytes) = rng.pick(&meshes).clone();
                (bytes, Vec::new(), name)
            }
            Target::Csv => (csv_inputs.clone(), csv_measurements.clone(), String::new()),
            Target::Vtu => {
                // The generator runs outside the checked call: a panic in it is reported too
                // (the hook is silent during the run).
                match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    grid::case(&mut rng)
                })) {
                    Ok(data) => (data, Vec::new(), String::new()),
                    Err(_) => {
                        tally.cases += 1;
                        tally.failures.push((
                            case,
                            "the VTK case generator panicked".into(),
                            Vec::new(),
                        ));
                        continue;
                    }
                }
            }
            Target::NodeList => (rng.pick(&lists).clone(), Vec::new(), String::new()),
        };
        let (mut data, mut second) = (data, second);
        let lines = match target {
            Target::Scene | Target::Csv => SCENE_LINES,
            Target::Mesh | Target::Vtu => MESH_LINES,
            Target::NodeList => NODE_LINES,
        };
        // The VTK cases carry their own mutations of the claimed sizes; one text mutation on
        // top in a quarter of them.
        let mutations = match target {
            Target::Vtu => usize::from(case % 4 == 0),
            _ => mutations,
        };
        for _ in 0..mutations {
            mutate(&mut data, &mut rng, lines);
            if target == Target::Csv {
                mutate(&mut second, &mut rng, lines);
            }
        }
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match target {
            Target::Scene => scene(&data, &fixtures.mesh),
            Target::Mesh => mesh(&data, &name),
            Target::Csv => csv(&data, &second, &fixtures.model),
            Target::Vtu => vtu(&data),
            Target::NodeList => node_list(&data, &fixtures.mesh),
        }));
        tally.cases += 1;
        match result {
            Ok(Ok(Outcome::Accepted)) => tally.accepted += 1,
            Ok(Ok(Outcome::Refused)) => tally.refused += 1,
            Ok(Err(Violation(what))) => tally.failures.push((case, what, data)),
            Err(payload) => {
                let what = payload
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "panic".into());
                tally.failures.push((case, format!("panic: {what}"), data));
            }
        }
    }
    std::panic::set_hook(hook);
    tally.seconds = start.elapsed().as_secs_f64();
    tally
}
