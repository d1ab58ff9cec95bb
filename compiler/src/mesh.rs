// Over 800 lines, one job: the mesh type, its errors with their hints, and what every reader shares (header sniffing, element kinds, assembly of the raw mesh); each format's reader is its own module (msh1, msh2, msh41, vtk, vtu).
//! Tetrahedral meshes read from gmsh and VTK files.
//!
//! Coordinates are stored as read (mesh units); the scene's unit factor is applied by the caller.
//!
//! [`read_mesh`] recognises the format from the file's content, not its name (a UTF-8 byte-order
//! mark is skipped):
//! - `$MeshFormat` 4.1, ASCII or binary: parsed by `mshio`; physical tags come from `$Entities`,
//!   names from `$PhysicalNames` (read here: mshio skips it; it is ASCII even in binary files).
//!   mshio drops node tags when they are contiguous; they are then read back from the `$Nodes`
//!   section here.
//! - `$MeshFormat` 2.0–2.2, ASCII: a small reader in this module; the first element tag is the
//!   physical tag, the second the elementary entity. gmsh writes an element once per physical
//!   group it belongs to (with a new element number); such copies (same type, entity and nodes)
//!   are merged and keep the first number.
//! - `$NOD` (MSH 1.0, ASCII): [`msh1`]; `reg-phys` is the physical tag (there are no names).
//! - `<?xml`/`<VTKFile` (VTU: ASCII, base64 binary or appended data, zlib or LZ4 compressed) and
//!   `# vtk DataFile` (legacy VTK, ASCII or binary) unstructured grids: [`vtk`], through
//!   `vtkio`. Node and element tags are the 0-based point and cell ids (as ParaView shows them);
//!   every integer cell-data array becomes volume groups named `"<array>:<value>"`
//!   (e.g. `"MaterialIds:2"`).
//!
//! Element types 4 (tet4) and 2 (tri3) are kept; 15 (point) and 1 (line2) only contribute nodes
//! to their groups. Any other type is an error naming it. Node coordinates must be finite with
//! |x| ≤ 1e9 mesh units ([`limits::COORDINATE`]); every size a file claims is checked before it
//! is allocated ([`limits`], docs/limits.md), and a panic inside a third-party parser is caught
//! without its message ([`caught_panics`] counts them).
//! Nodes that belong to no tetrahedron ([`Mesh::orphan_nodes`]) stay in the mesh but not in the
//! model (the FEM numbers only the nodes of tetrahedra).

mod blocks;
pub mod geometry;
mod guard;
pub mod limits;
pub mod msh1;
mod msh2;
mod msh41;
mod msh_text;
pub mod procedural;
pub mod selection;
pub mod vtk;
mod vtu;

pub use guard::caught_panics;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use geometry::{cross, det3, dot, sub};

/// A linear 4-node tetrahedron (gmsh element type 4).
#[derive(Clone, Debug, PartialEq)]
pub struct Tetrahedron {
    /// gmsh element tag.
    pub tag: u64,
    /// Indices into [`Mesh::nodes`], in gmsh order.
    pub nodes: [usize; 4],
}

/// A linear 3-node triangle (gmsh element type 2), kept for display and surface groups.
#[derive(Clone, Debug, PartialEq)]
pub struct Triangle {
    /// gmsh element tag.
    pub tag: u64,
    /// Indices into [`Mesh::nodes`].
    pub nodes: [usize; 3],
}

/// A gmsh physical group with the mesh entities it contains.
#[derive(Clone, Debug, PartialEq)]
pub struct PhysicalGroup {
    /// Dimension: 0 points, 1 curves, 2 surfaces, 3 volumes.
    pub dim: u8,
    /// gmsh physical tag.
    pub tag: i32,
    /// Name from `$PhysicalNames`; groups without a name get `"<dim>:<tag>"`.
    pub name: String,
    /// Node indices (into [`Mesh::nodes`]) of every element in the group, sorted, unique.
    pub nodes: Vec<usize>,
    /// For dim 3: indices into [`Mesh::tetrahedra`]; for dim 2: into [`Mesh::triangles`];
    /// empty for dims 0 and 1.
    pub elements: Vec<usize>,
}

/// A tetrahedral mesh with its physical groups.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// File the mesh was read from.
    pub source: PathBuf,
    /// gmsh node tag of each node.
    pub node_tags: Vec<u64>,
    /// Node coordinates in mesh units, `[x, y, z]`.
    pub nodes: Vec<[f64; 3]>,
    /// Linear tetrahedra.
    pub tetrahedra: Vec<Tetrahedron>,
    /// Surface triangles as given in the file (boundary or interface).
    pub triangles: Vec<Triangle>,
    /// Physical groups, sorted by (dim, tag).
    pub groups: Vec<PhysicalGroup>,
}

impl Mesh {
    /// The physical group called `name`, if any.
    pub fn group(&self, name: &str) -> Option<&PhysicalGroup> {
        self.groups.iter().find(|g| g.name == name)
    }

    /// The physical group `name`, or an error listing the groups that exist with their sizes
    /// and, when the mesh has no physical names, how to name them or select nodes instead;
    /// `context` says where the name appeared (e.g. "material", "fixed", "load 'tip'").
    pub fn find_group(&self, name: &str, context: &str) -> Result<&PhysicalGroup, UnknownGroup> {
        self.group(name).ok_or_else(|| {
            let available: Vec<String> = self
                .groups
                .iter()
                .map(|g| {
                    let size = match g.dim {
                        3 => format!("{} tetrahedra", g.elements.len()),
                        2 => format!("{} triangles", g.elements.len()),
                        _ => format!("{} nodes", g.nodes.len()),
                    };
                    format!("'{}' ({}-D, {size})", g.name, g.dim)
                })
                .collect();
            UnknownGroup {
                context: context.to_owned(),
                name: name.to_owned(),
                available,
            }
        })
    }

    /// Names of all physical groups, for error messages.
    pub fn group_names(&self) -> Vec<String> {
        self.groups.iter().map(|g| g.name.clone()).collect()
    }

    /// Indices of the nodes that belong to no tetrahedron (left out of the model), sorted.
    pub fn orphan_nodes(&self) -> Vec<usize> {
        let mut used = vec![false; self.nodes.len()];
        for t in &self.tetrahedra {
            for &n in &t.nodes {
                if let Some(u) = used.get_mut(n) {
                    *u = true;
                }
            }
        }
        (0..self.nodes.len()).filter(|&i| !used[i]).collect()
    }

    /// Axis-aligned bounding box `(min, max)` of the nodes of the tetrahedra, mesh units.
    pub fn extent(&self) -> ([f64; 3], [f64; 3]) {
        bounding_box(
            self.tetrahedra
                .iter()
                .flat_map(|t| t.nodes.iter().filter_map(|&n| self.nodes.get(n))),
        )
    }

    /// Signed volume of tetrahedron `i` (mesh units³):
    /// V = det[x₁ − x₀, x₂ − x₀, x₃ − x₀] / 6, positive for gmsh's orientation.
    ///
    /// Panics if `i` is out of range.
    pub fn signed_volume(&self, i: usize) -> f64 {
        let [a, b, c, d] = self.tetrahedra[i].nodes.map(|n| self.nodes[n]);
        det3(sub(b, a), sub(c, a), sub(d, a)) / 6.0
    }

    /// Boundary faces of the tetrahedral mesh: the faces that belong to exactly one tetrahedron,
    /// as node-index triples oriented outward (right-hand normal pointing away from the
    /// tetrahedron's fourth node, whatever the tetrahedron's own orientation).
    ///
    /// Each triple is rotated (orientation kept) to start at its smallest index; the list is
    /// sorted lexicographically, so the result depends only on the mesh, not on hashing.
    pub fn surface_triangles(&self) -> Vec<[usize; 3]> {
        // (opposite vertex, face) for the 4 faces of a tet (0,1,2,3); outward if positive.
        const FACES: [(usize, [usize; 3]); 4] = [
            (3, [0, 2, 1]),
            (2, [0, 1, 3]),
            (1, [0, 3, 2]),
            (0, [1, 2, 3]),
        ];
        // sorted face -> (number of tets using it, outward face of the first one)
        let mut faces: HashMap<[usize; 3], (u32, [usize; 3])> =
            HashMap::with_capacity(2 * self.tetrahedra.len());
        for t in &self.tetrahedra {
            for (opposite, f) in FACES {
                let mut face = f.map(|i| t.nodes[i]);
                let [p0, p1, p2] = face.map(|n| self.nodes[n]);
                let normal = cross(sub(p1, p0), sub(p2, p0));
                let away = sub(self.nodes[t.nodes[opposite]], p0);
                if dot(normal, away) > 0.0 {
                    face.swap(1, 2);
                }
                let mut key = face;
                key.sort_unstable();
                faces
                    .entry(key)
                    .and_modify(|e| e.0 += 1)
                    .or_insert((1, face));
            }
        }
        let mut out: Vec<[usize; 3]> = faces
            .into_values()
            .filter(|&(count, _)| count == 1)
            .map(|(_, f)| {
                let k = (0..3).min_by_key(|&k| f[k]).unwrap_or(0);
                [f[k], f[(k + 1) % 3], f[(k + 2) % 3]]
            })
            .collect();
        out.sort_unstable();
        out
    }
}

/// A group name the mesh does not have (from a scene's `group = ...` fields).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{context}: the mesh has no physical group named '{name}'; it has: {}{}",
    available.join(", "), group_hint(available))]
pub struct UnknownGroup {
    /// Where the name appeared (e.g. "material", "fixed", "load 'tip'").
    pub context: String,
    /// The unknown name.
    pub name: String,
    /// Names that exist, each quoted, with its dimension and size: `'body' (3-D, 12
    /// tetrahedra)`.
    pub available: Vec<String>,
}

/// What to do about an unknown group, from the list of groups the mesh has (entries as in
/// [`UnknownGroup`]): with no groups, use a selection; with unnamed groups only
/// (names `"dim:tag"`), use those names, name the groups in gmsh, or select by geometry.
fn group_hint(available: &[String]) -> String {
    let unnamed = |entry: &String| {
        let name = entry.split('\'').nth(1).unwrap_or("");
        let mut parts = name.splitn(2, ':');
        let dim = parts.next().unwrap_or("");
        let tag = parts.next().unwrap_or("");
        dim.len() == 1 && dim.parse::<u8>().is_ok() && tag.parse::<i64>().is_ok()
    };
    if available.is_empty() {
        "(no groups at all); use a selection instead, e.g. `select = [{ everything = true }]` \
         for a material or `select = [{ box = { min = [..], max = [..] }, nodes = \"boundary\" }]` \
         for nodes (schema in compiler/src/scene.rs)"
            .to_owned()
    } else if available.iter().all(unnamed) {
        "; the mesh has no physical names: refer to a group as \"dim:tag\" as listed \
         (e.g. group = \"3:1\"), name the groups in gmsh (Physical Volume(\"body\") = {1};), \
         or select nodes by geometry (`select = [{ box = { min = [..], max = [..] }, \
         nodes = \"boundary\" }]`, schema in compiler/src/scene.rs)"
            .to_owned()
    } else {
        String::new()
    }
}

/// How to get a file crokf can read, for a format it does not recognise (checked: meshio 5.3
/// converts an Abaqus .inp file with this command).
const CONVERT_HINT: &str = "crokf reads gmsh MSH 4.1 (ASCII or binary), 2.2 and 1.0 (ASCII), \
     VTK XML unstructured grids (.vtu) and legacy VTK unstructured grids; for another format \
     that meshio reads, convert it with `meshio convert FILE out.vtu` (`pip install meshio`)";

/// How to convert another MSH version (checked with gmsh 4.15 on MSH 4.0 ASCII, 3.0 ASCII and
/// 2.2 binary files).
const MSH_VERSION_HINT: &str = "convert it to MSH 4.1 with gmsh: \
     `gmsh FILE -save -format msh41 -o out.msh` (`pip install gmsh` provides the command)";

/// How to get linear tetrahedra.
const TET4_HINT: &str =
    "crokf needs linear tetrahedra (type 4; types 2, 1 and 15 are accepted for groups): \
     re-mesh with `gmsh model.geo -3 -order 1 -format msh41 -o out.msh` \
     (hexahedra or prisms: mesh the volume with tetrahedra)";

fn hint(path: &Path) -> String {
    CONVERT_HINT.replace("FILE", &path.display().to_string())
}

fn version_hint(path: &Path) -> String {
    MSH_VERSION_HINT.replace("FILE", &path.display().to_string())
}

/// Errors in reading a gmsh mesh file. Every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be read (missing, unreadable).
    #[error("cannot read mesh file {}: {source}", .path.display())]
    Io {
        /// Mesh path.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file is in none of the formats crokf reads.
    #[error("{}: not a mesh format crokf recognises (expected `$MeshFormat`, `$NOD`, `<?xml` or \
        `# vtk DataFile` at the start, found {found:?}); {}", .path.display(), hint(.path))]
    NotGmsh {
        /// Mesh path.
        path: PathBuf,
        /// Start of the first line.
        found: String,
    },
    /// A gmsh format version or encoding this reader does not handle.
    #[error("{}: MSH version {version} {encoding} is not supported (crokf reads MSH 4.1 ASCII or \
        binary, 2.2 ASCII and 1.0); {}", .path.display(), version_hint(.path))]
    UnsupportedVersion {
        /// Mesh path.
        path: PathBuf,
        /// Version string as found in the header.
        version: String,
        /// "ASCII" or "binary".
        encoding: &'static str,
    },
    /// Malformed or truncated content.
    #[error("{}: {location}: {message}", .path.display())]
    Syntax {
        /// Mesh path.
        path: PathBuf,
        /// "line N" (ASCII) or "byte N" (binary).
        location: String,
        /// What is wrong.
        message: String,
    },
    /// Elements of types other than 4, 2, 1 and 15.
    #[error("{}: unsupported elements: {}; {TET4_HINT}", .path.display(), describe_types(.found))]
    UnsupportedElements {
        /// Mesh path.
        path: PathBuf,
        /// (gmsh element type number, count), sorted by type.
        found: Vec<(u32, usize)>,
    },
    /// A node coordinate that is NaN or infinite.
    #[error("{}: node {node} has a non-finite coordinate ({:?}, {:?}, {:?}); every coordinate \
        must be a finite number", .path.display(), .position[0], .position[1], .position[2])]
    NonFiniteNode {
        /// Mesh path.
        path: PathBuf,
        /// Node tag (gmsh tag, or 0-based VTK point id).
        node: u64,
        /// Coordinates as read.
        position: [f64; 3],
    },
    /// A node coordinate beyond the documented range |x| ≤ 1e9 mesh units.
    #[error("{}: node {node} has a coordinate out of range ({:?}, {:?}, {:?}); coordinates must \
        be finite with |x| ≤ {:e} mesh units (docs/limits.md)", .path.display(), .position[0],
        .position[1], .position[2], limits::COORDINATE)]
    NodeOutOfRange {
        /// Mesh path.
        path: PathBuf,
        /// Node tag (gmsh tag, or 0-based VTK point id).
        node: u64,
        /// Coordinates as read.
        position: [f64; 3],
    },
    /// A VTK file that is not a serial unstructured grid, or that cannot be parsed.
    #[error("{}: {message}", .path.display())]
    Vtk {
        /// Mesh path.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An element references a node tag that `$Nodes` does not define.
    #[error("{}: element {element} references node {node}, which is not defined in $Nodes",
        .path.display())]
    UnknownNode {
        /// Mesh path.
        path: PathBuf,
        /// gmsh element tag.
        element: u64,
        /// Missing gmsh node tag.
        node: u64,
    },
    /// A node tag defined twice.
    #[error("{}: node {node} is defined twice in $Nodes", .path.display())]
    DuplicateNode {
        /// Mesh path.
        path: PathBuf,
        /// gmsh node tag.
        node: u64,
    },
    /// No tetrahedra at all (a surface mesh, or a mesh saved without its volume).
    #[error("{}: the mesh has no linear tetrahedra (gmsh type 4); {TET4_HINT}; if the volume \
        has physical groups, make sure the volume itself is in one (`Physical Volume`)",
        .path.display())]
    NoTetrahedra {
        /// Mesh path.
        path: PathBuf,
    },
}

/// Short and long name of a gmsh element type.
pub fn element_type_name(t: u32) -> &'static str {
    match t {
        1 => "line2, 2-node line",
        2 => "tri3, 3-node triangle",
        3 => "quad4, 4-node quadrangle",
        4 => "tet4, 4-node tetrahedron",
        5 => "hex8, 8-node hexahedron",
        6 => "prism6, 6-node prism",
        7 => "pyramid5, 5-node pyramid",
        8 => "line3, 3-node second-order line",
        9 => "tri6, 6-node second-order triangle",
        10 => "quad9, 9-node second-order quadrangle",
        11 => "tet10, 10-node second-order tetrahedron",
        12 => "hex27, 27-node second-order hexahedron",
        13 => "prism18, 18-node second-order prism",
        14 => "pyramid14, 14-node second-order pyramid",
        15 => "point, 1-node point",
        16 => "quad8, 8-node second-order quadrangle",
        17 => "hex20, 20-node second-order hexahedron",
        18 => "prism15, 15-node second-order prism",
        19 => "pyramid13, 13-node second-order pyramid",
        20 => "tri9, 9-node third-order triangle",
        21 => "tri10, 10-node third-order triangle",
        26 => "line4, 4-node third-order line",
        29 => "tet20, 20-node third-order tetrahedron",
        _ => "higher-order or special element",
    }
}

fn describe_types(found: &[(u32, usize)]) -> String {
    found
        .iter()
        .map(|&(t, n)| format!("{n} element(s) of type {t} ({})", element_type_name(t)))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Reads a gmsh mesh: MSH 4.1 (ASCII or binary) or MSH 2.2 (ASCII), chosen by the
/// `$MeshFormat` header.
pub fn read_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_mesh_bytes(&bytes, path)
}

/// Reads a gmsh mesh from its bytes; `path` is recorded in [`Mesh::source`] and in messages.
pub fn read_mesh_bytes(bytes: &[u8], path: &Path) -> Result<Mesh, MeshError> {
    let body = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let start = body
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .map_or(&body[body.len()..], |i| &body[i..]);
    if start.starts_with(b"$NOD") || start.starts_with(b"$NOE") {
        return assemble(msh1::read(body, path)?, path);
    }
    if start.starts_with(b"<?xml") || start.starts_with(b"<VTKFile") {
        return assemble(vtk::read_xml(bytes, bytes.len() - start.len(), path)?, path);
    }
    if start.starts_with(b"# vtk DataFile") {
        return assemble(vtk::read_legacy(start, path)?, path);
    }
    let bytes = body;
    let header = parse_header(bytes, path)?;
    let encoding = if header.binary { "binary" } else { "ASCII" };
    let unsupported = || MeshError::UnsupportedVersion {
        path: path.to_owned(),
        version: header.version.clone(),
        encoding,
    };
    let version: f64 = header.version.parse().map_err(|_| unsupported())?;
    let raw = if version == 4.1 {
        msh41::read_msh41(bytes, &header, path)?
    } else if (2.0..3.0).contains(&version) && !header.binary {
        msh2::read_msh2(bytes, path)?
    } else {
        return Err(unsupported());
    };
    assemble(raw, path)
}

// ---------------------------------------------------------------------------------------------
// Header

/// The `$MeshFormat` line: `version file-type data-size`.
struct Header {
    version: String,
    binary: bool,
    /// Bytes per `size_t` (4 or 8).
    data_size: usize,
    /// Binary files: byte order detected from the integer 1 after the header line.
    big_endian: bool,
}

fn syntax(path: &Path, location: String, message: impl Into<String>) -> MeshError {
    MeshError::Syntax {
        path: path.to_owned(),
        location,
        message: message.into(),
    }
}

fn parse_header(bytes: &[u8], path: &Path) -> Result<Header, MeshError> {
    let bom = if bytes.starts_with(b"\xEF\xBB\xBF") {
        3
    } else {
        0
    };
    // (line number, start offset, trimmed content) of successive lines.
    let mut pos = bom;
    let mut line_no = 0;
    let mut next_line = || -> Option<(usize, &[u8], usize)> {
        if pos >= bytes.len() {
            return None;
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |p| pos + p);
        let line = bytes[pos..end].trim_ascii();
        pos = (end + 1).min(bytes.len());
        line_no += 1;
        Some((line_no, line, pos))
    };
    let first = loop {
        match next_line() {
            Some((_, [], _)) => {}
            Some((_, l, _)) => break l,
            None => return Err(not_gmsh(path, b"")),
        }
    };
    if first != b"$MeshFormat" {
        if first == b"$NOD" || first == b"$NOE" {
            return Err(MeshError::UnsupportedVersion {
                path: path.to_owned(),
                version: "1.0".into(),
                encoding: "ASCII",
            });
        }
        return Err(not_gmsh(path, first));
    }
    let Some((line, content, after)) = next_line() else {
        return Err(syntax(
            path,
            format!("line {}", line_of(bytes, bytes.len()) + 1),
            "file ends after `$MeshFormat` (expected `version file-type data-size`)",
        ));
    };
    let text = String::from_utf8_lossy(content).into_owned();
    let fields: Vec<&str> = text.split_ascii_whitespace().collect();
    let bad = || {
        syntax(
            path,
            format!("line {line}"),
            format!("`$MeshFormat` header {text:?} is not `version file-type data-size`"),
        )
    };
    if fields.len() != 3 {
        return Err(bad());
    }
    let binary = match fields[1] {
        "0" => false,
        "1" => true,
        _ => return Err(bad()),
    };
    let data_size: usize = fields[2].parse().map_err(|_| bad())?;
    if data_size != 4 && data_size != 8 {
        return Err(syntax(
            path,
            format!("line {line}"),
            format!("data size {data_size} is not supported (gmsh writes 8)"),
        ));
    }
    let mut big_endian = false;
    if binary {
        // The integer 1 in the file's byte order follows the header line.
        big_endian = match bytes.get(after..after + 4) {
            Some([1, 0, 0, 0]) => false,
            Some([0, 0, 0, 1]) => true,
            _ => {
                return Err(syntax(
                    path,
                    format!("line {}", line + 1),
                    "binary MSH file: the integer 1 that marks the byte order is missing",
                ))
            }
        };
    }
    Ok(Header {
        version: fields[0].to_owned(),
        binary,
        data_size,
        big_endian,
    })
}

fn not_gmsh(path: &Path, first: &[u8]) -> MeshError {
    let shown: String = String::from_utf8_lossy(&first[..first.len().min(60)])
        .chars()
        .map(|c| if c.is_control() { '?' } else { c })
        .collect();
    MeshError::NotGmsh {
        path: path.to_owned(),
        found: shown,
    }
}

// ---------------------------------------------------------------------------------------------
// Format-independent assembly

/// An element as read from either format.
struct RawElement {
    tag: u64,
    /// gmsh element type number.
    kind: u32,
    /// Physical tags of the element (2.2: the first tag; 4.1: those of its entity).
    physical: Vec<i32>,
    /// gmsh node tags.
    nodes: Vec<u64>,
}

#[derive(Default)]
struct RawMesh {
    node_tags: Vec<u64>,
    nodes: Vec<[f64; 3]>,
    elements: Vec<RawElement>,
    names: BTreeMap<(u8, i32), String>,
}

/// Dimension of the kept element types.
fn kept_dim(kind: u32) -> Option<u8> {
    match kind {
        15 => Some(0),
        1 => Some(1),
        2 => Some(2),
        4 => Some(3),
        _ => None,
    }
}

fn assemble(raw: RawMesh, path: &Path) -> Result<Mesh, MeshError> {
    let mut unsupported: BTreeMap<u32, usize> = BTreeMap::new();
    for e in &raw.elements {
        if kept_dim(e.kind).is_none() {
            *unsupported.entry(e.kind).or_default() += 1;
        }
    }
    if !unsupported.is_empty() {
        return Err(MeshError::UnsupportedElements {
            path: path.to_owned(),
            found: unsupported.into_iter().collect(),
        });
    }

    if let Some((&node, &position)) = raw
        .node_tags
        .iter()
        .zip(&raw.nodes)
        .find(|(_, p)| p.iter().any(|v| !v.is_finite()))
    {
        return Err(MeshError::NonFiniteNode {
            path: path.to_owned(),
            node,
            position,
        });
    }
    if let Some((&node, &position)) = raw
        .node_tags
        .iter()
        .zip(&raw.nodes)
        .find(|(_, p)| p.iter().any(|v| v.abs() > limits::COORDINATE))
    {
        return Err(MeshError::NodeOutOfRange {
            path: path.to_owned(),
            node,
            position,
        });
    }
    let mut index: HashMap<u64, usize> = HashMap::with_capacity(raw.node_tags.len());
    for (i, &t) in raw.node_tags.iter().enumerate() {
        if index.insert(t, i).is_some() {
            return Err(MeshError::DuplicateNode {
                path: path.to_owned(),
                node: t,
            });
        }
    }

    #[derive(Default)]
    struct Acc {
        nodes: Vec<usize>,
        elements: Vec<usize>,
    }
    let mut groups: BTreeMap<(u8, i32), Acc> = BTreeMap::new();
    for &key in raw.names.keys() {
        groups.entry(key).or_default();
    }
    let mut tetrahedra = Vec::new();
    let mut triangles = Vec::new();
    let mut nodes = Vec::with_capacity(4);
    for e in &raw.elements {
        nodes.clear();
        for &n in &e.nodes {
            let i = *index.get(&n).ok_or(MeshError::UnknownNode {
                path: path.to_owned(),
                element: e.tag,
                node: n,
            })?;
            nodes.push(i);
        }
        let dim = kept_dim(e.kind).unwrap_or(0);
        let element = match (e.kind, nodes.as_slice()) {
            (4, &[a, b, c, d]) => {
                tetrahedra.push(Tetrahedron {
                    tag: e.tag,
                    nodes: [a, b, c, d],
                });
                Some(tetrahedra.len() - 1)
            }
            (2, &[a, b, c]) => {
                triangles.push(Triangle {
                    tag: e.tag,
                    nodes: [a, b, c],
                });
                Some(triangles.len() - 1)
            }
            (1, &[_, _]) | (15, &[_]) => None,
            _ => {
                return Err(syntax(
                    path,
                    "$Elements".into(),
                    format!(
                        "element {} of type {} ({}) has {} nodes",
                        e.tag,
                        e.kind,
                        element_type_name(e.kind),
                        nodes.len()
                    ),
                ))
            }
        };
        for &p in &e.physical {
            let acc = groups.entry((dim, p)).or_default();
            acc.nodes.extend_from_slice(&nodes);
            if let Some(i) = element {
                acc.elements.push(i);
            }
        }
    }
    if tetrahedra.is_empty() {
        return Err(MeshError::NoTetrahedra {
            path: path.to_owned(),
        });
    }
    let groups = groups
        .into_iter()
        .map(|((dim, tag), mut acc)| {
            acc.nodes.sort_unstable();
            acc.nodes.dedup();
            acc.elements.sort_unstable();
            acc.elements.dedup();
            PhysicalGroup {
                dim,
                tag,
                name: raw
                    .names
                    .get(&(dim, tag))
                    .cloned()
                    .unwrap_or_else(|| format!("{dim}:{tag}")),
                nodes: acc.nodes,
                elements: acc.elements,
            }
        })
        .collect();
    Ok(Mesh {
        source: path.to_owned(),
        node_tags: raw.node_tags,
        nodes: raw.nodes,
        tetrahedra,
        triangles,
        groups,
    })
}

// ---------------------------------------------------------------------------------------------
// Line-oriented ASCII reading (MSH 2.2, and `$PhysicalNames` in every format)

/// Lines of an ASCII region with 1-based line numbers.
struct Lines<'a> {
    path: &'a Path,
    iter: std::iter::Enumerate<std::str::Lines<'a>>,
    /// Line number of the first line of the region, minus one.
    base: usize,
    /// Last line number returned.
    last: usize,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str, base: usize, path: &'a Path) -> Self {
        Lines {
            path,
            iter: text.lines().enumerate(),
            base,
            last: base,
        }
    }

    /// Next line (trimmed) or None at the end.
    fn next_opt(&mut self) -> Option<(usize, &'a str)> {
        let (i, l) = self.iter.next()?;
        self.last = self.base + i + 1;
        Some((self.last, l.trim()))
    }

    /// Next line (trimmed); an error naming `what` at the end of the file.
    fn next(&mut self, what: &str) -> Result<(usize, &'a str), MeshError> {
        self.next_opt().ok_or_else(|| {
            syntax(
                self.path,
                format!("line {}", self.last + 1),
                format!("unexpected end of file while reading {what} (file truncated?)"),
            )
        })
    }

    fn error(&self, line: usize, message: impl Into<String>) -> MeshError {
        syntax(self.path, format!("line {line}"), message)
    }

    /// A count line: a single non-negative integer.
    fn count(&mut self, section: &str) -> Result<usize, MeshError> {
        let (no, l) = self.next(&format!("the {section} count"))?;
        l.parse()
            .map_err(|_| self.error(no, format!("expected the number of {section}, found {l:?}")))
    }

    /// Expects the `$End...` line of a section.
    fn end(&mut self, end: &str) -> Result<(), MeshError> {
        let (no, l) = self.next(end)?;
        if l == end {
            Ok(())
        } else {
            Err(self.error(no, format!("expected {end}, found {l:?}")))
        }
    }

    /// Skips an unknown section up to and including `end`.
    fn skip_to(&mut self, end: &str) -> Result<(), MeshError> {
        loop {
            let (_, l) = self.next(end)?;
            if l == end {
                return Ok(());
            }
        }
    }
}

fn parse_num<T: std::str::FromStr>(
    lines: &Lines<'_>,
    no: usize,
    tok: Option<&str>,
    what: &str,
) -> Result<T, MeshError> {
    match tok {
        Some(t) => t
            .parse()
            .map_err(|_| lines.error(no, format!("{what}: {t:?} is not a valid number"))),
        None => Err(lines.error(no, format!("{what} missing"))),
    }
}

/// Body of `$PhysicalNames` (after the opening line), through `$EndPhysicalNames`.
fn parse_physical_names(
    lines: &mut Lines<'_>,
    names: &mut BTreeMap<(u8, i32), String>,
) -> Result<(), MeshError> {
    let n = lines.count("physical names")?;
    for _ in 0..n {
        let (no, l) = lines.next("$PhysicalNames")?;
        let mut parts = l.splitn(3, char::is_whitespace);
        let dim: u8 = parse_num(lines, no, parts.next(), "physical group dimension")?;
        let tag: i32 = parse_num(lines, no, parts.next(), "physical group tag")?;
        if dim > 3 {
            return Err(lines.error(no, format!("physical group dimension {dim} is not 0..3")));
        }
        let rest = parts.next().unwrap_or("").trim();
        let name = rest
            .strip_prefix('"')
            .and_then(|r| r.strip_suffix('"'))
            .ok_or_else(|| {
                lines.error(
                    no,
                    format!("physical group {dim}:{tag}: name {rest:?} is not in double quotes"),
                )
            })?;
        names.insert((dim, tag), name.to_owned());
    }
    lines.end("$EndPhysicalNames")
}

/// Offset of the line following a line that is exactly `marker` (ignoring `\r`), searching
/// from the start of the file.
fn find_section(bytes: &[u8], marker: &[u8]) -> Option<usize> {
    let mut start = 0;
    while start < bytes.len() {
        let end = bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |p| start + p);
        if bytes[start..end].trim_ascii_end() == marker {
            return Some((end + 1).min(bytes.len()));
        }
        start = end + 1;
    }
    None
}

fn line_of(bytes: &[u8], offset: usize) -> usize {
    1 + bytes[..offset.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}

/// Axis-aligned bounding box `(min, max)` of `points` (infinite bounds for no points).
pub fn bounding_box<'a>(points: impl IntoIterator<Item = &'a [f64; 3]>) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    (lo, hi)
}

/// Length of the diagonal of the axis-aligned bounding box of `points` (same unit as the points;
/// 0 for no points). The one place the model's characteristic length is computed: the balancing
/// weight of rotation rows, the co-rotational Newton floor, the floors of the tier.
pub fn bounding_diagonal<'a>(points: impl IntoIterator<Item = &'a [f64; 3]>) -> f64 {
    let (lo, hi) = bounding_box(points);
    (0..3)
        .map(|c| (hi[c] - lo[c]).max(0.0).powi(2))
        .sum::<f64>()
        .sqrt()
}
