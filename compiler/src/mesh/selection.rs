//! Geometric and list selections of nodes, boundary faces and tetrahedra (the scene's
//! `select = [...]`, schema in `crate::scene`).
//!
//! All tests are in mesh units and closed: a point is inside a shape when it is within
//! `tol = 1e-9 × (bounding-box diagonal)` of it, so nodes lying exactly on a box face or on a
//! half-space's plane are taken.
//! - box: `min − tol ≤ x ≤ max + tol` componentwise;
//! - sphere: `|x − c| ≤ r + tol`;
//! - half-space: `(x − p)·n / |n| ≥ −tol`.
//!
//! Nodes are the nodes of tetrahedra (orphans never), all of them or the boundary ones (nodes of
//! faces that belong to exactly one tetrahedron). Faces are the boundary faces whose three nodes
//! are all selected, oriented outward ([`Mesh::surface_triangles`]), or a 2-D group's own
//! triangles. Tetrahedra are those whose centroid is inside the shape.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use super::{Mesh, PhysicalGroup};
use crate::scene::{NodeDomain, Selector};

/// What a selection took (indices into the mesh's arrays).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Selected {
    /// Node indices, sorted, unique.
    pub nodes: Vec<usize>,
    /// Faces as node-index triples: a 2-D group's triangles in file order, then boundary faces
    /// in [`Mesh::surface_triangles`] order; no face twice.
    pub faces: Vec<[usize; 3]>,
    /// Tetrahedron indices, sorted, unique.
    pub tetrahedra: Vec<usize>,
}

/// Errors in resolving a selection; every message names the scene entry and the selector.
#[derive(Debug, thiserror::Error)]
pub enum SelectionError {
    /// A selector that takes nothing.
    #[error("{context}: select[{index}] ({what}) takes no {kind}; the mesh's tetrahedra span x \
        [{:.6e}, {:.6e}], y [{:.6e}, {:.6e}], z [{:.6e}, {:.6e}] (mesh units)",
        .extent.0[0], .extent.1[0], .extent.0[1], .extent.1[1], .extent.0[2], .extent.1[2])]
    Empty {
        /// Scene entry.
        context: String,
        /// Selector index in the union.
        index: usize,
        /// Selector description.
        what: String,
        /// "nodes" or "tetrahedra".
        kind: &'static str,
        /// Bounding box of the mesh, (min, max), mesh units.
        extent: ([f64; 3], [f64; 3]),
    },
    /// A node-list file that cannot be read or holds a bad entry.
    #[error("{context}: node_list {}: {message}", .path.display())]
    NodeList {
        /// Scene entry.
        context: String,
        /// The list file.
        path: PathBuf,
        /// What is wrong (with the line).
        message: String,
    },
    /// A group selector naming a group the mesh lacks.
    #[error("{context}: select[{index}]: {message}")]
    Group {
        /// Scene entry.
        context: String,
        /// Selector index.
        index: usize,
        /// The unknown-group message, listing the groups the mesh has.
        message: String,
    },
}

/// Resolves selections against one mesh; boundary faces are computed once, on first use.
pub struct Selections<'m> {
    mesh: &'m Mesh,
    boundary: Option<Vec<[usize; 3]>>,
    used: Vec<bool>,
    tolerance: f64,
    extent: ([f64; 3], [f64; 3]),
}

impl<'m> Selections<'m> {
    /// Prepares selections on `mesh`.
    pub fn new(mesh: &'m Mesh) -> Self {
        let mut used = vec![false; mesh.nodes.len()];
        for t in &mesh.tetrahedra {
            for &n in &t.nodes {
                if let Some(u) = used.get_mut(n) {
                    *u = true;
                }
            }
        }
        let extent = mesh.extent();
        let diag = (0..3)
            .map(|c| (extent.1[c] - extent.0[c]).powi(2))
            .sum::<f64>()
            .sqrt();
        Selections {
            mesh,
            boundary: None,
            used,
            tolerance: if diag.is_finite() { 1e-9 * diag } else { 0.0 },
            extent,
        }
    }

    /// Boundary faces of the tetrahedral mesh, outward ([`Mesh::surface_triangles`]).
    pub fn boundary_faces(&mut self) -> &[[usize; 3]] {
        let mesh = self.mesh;
        self.boundary
            .get_or_insert_with(|| mesh.surface_triangles())
    }

    fn inside(&self, sel: &Selector, x: [f64; 3]) -> bool {
        let tol = self.tolerance;
        if let Some(b) = &sel.aabb {
            (0..3).all(|c| x[c] >= b.min[c] - tol && x[c] <= b.max[c] + tol)
        } else if let Some(s) = &sel.sphere {
            let d2: f64 = (0..3).map(|c| (x[c] - s.center[c]).powi(2)).sum();
            d2.sqrt() <= s.radius + tol
        } else if let Some(h) = &sel.half_space {
            let norm = h.normal.iter().map(|v| v * v).sum::<f64>().sqrt();
            let d: f64 = (0..3).map(|c| (x[c] - h.point[c]) * h.normal[c]).sum();
            norm > 0.0 && d / norm >= -tol
        } else {
            sel.everything == Some(true)
        }
    }

    /// Nodes and faces of a union of selectors (fixed, load, force noise, display).
    /// `group` selectors name mesh groups (an unknown name lists the groups the mesh has).
    /// Returns what was taken and one note per selector with its counts.
    pub fn nodes(
        &mut self,
        selectors: &[Selector],
        context: &str,
    ) -> Result<(Selected, String), SelectionError> {
        let mut nodes = BTreeSet::new();
        let mut faces: Vec<[usize; 3]> = Vec::new();
        let mut seen_faces = BTreeSet::new();
        let mut parts = Vec::new();
        let mut warnings = Vec::new();
        for (index, sel) in selectors.iter().enumerate() {
            let (n, f) = self.one_node_selector(sel, index, context, &mut warnings)?;
            if n.is_empty() {
                return Err(self.empty(context, index, sel, "nodes"));
            }
            parts.push(format!(
                "{}: {} nodes, {} faces",
                sel.describe(),
                n.len(),
                f.len()
            ));
            nodes.extend(n);
            for face in f {
                let mut key = face;
                key.sort_unstable();
                if seen_faces.insert(key) {
                    faces.push(face);
                }
            }
        }
        let selected = Selected {
            nodes: nodes.into_iter().collect(),
            faces,
            tetrahedra: Vec::new(),
        };
        let mut note = format!(
            "{context}: selection took {} nodes and {} faces ({})",
            selected.nodes.len(),
            selected.faces.len(),
            parts.join("; ")
        );
        for w in warnings {
            note.push_str("; warning: ");
            note.push_str(&w);
        }
        Ok((selected, note))
    }

    fn one_node_selector(
        &mut self,
        sel: &Selector,
        index: usize,
        context: &str,
        warnings: &mut Vec<String>,
    ) -> Result<(Vec<usize>, Vec<[usize; 3]>), SelectionError> {
        let mesh = self.mesh;
        let nodes: Vec<usize> = if let Some(name) = &sel.group {
            let group = self
                .group(name, context)
                .map_err(|message| SelectionError::Group {
                    context: context.to_owned(),
                    index,
                    message,
                })?;
            let nodes: Vec<usize> = group
                .nodes
                .iter()
                .copied()
                .filter(|&n| self.used.get(n).copied().unwrap_or(false))
                .collect();
            if group.dim == 2 {
                let faces = group
                    .elements
                    .iter()
                    .filter_map(|&t| mesh.triangles.get(t).map(|t| t.nodes))
                    .collect();
                return Ok((nodes, faces));
            }
            nodes
        } else if let Some(file) = &sel.node_list {
            let (nodes, repeated) = self.node_list(file, context)?;
            warnings.extend(repeated);
            nodes
        } else {
            let candidates: Vec<usize> = match sel.nodes {
                Some(NodeDomain::Boundary) => {
                    let set: BTreeSet<usize> =
                        self.boundary_faces().iter().flatten().copied().collect();
                    set.into_iter().collect()
                }
                _ => (0..mesh.nodes.len()).filter(|&n| self.used[n]).collect(),
            };
            candidates
                .into_iter()
                .filter(|&n| self.inside(sel, mesh.nodes[n]))
                .collect()
        };
        let mut taken = vec![false; mesh.nodes.len()];
        for &n in &nodes {
            taken[n] = true;
        }
        let faces = self
            .boundary_faces()
            .iter()
            .filter(|f| f.iter().all(|&n| taken[n]))
            .copied()
            .collect();
        Ok((nodes, faces))
    }

    /// Tetrahedra of a union of selectors (materials): a shape takes the tetrahedra whose
    /// centroid is inside; a group its volume elements.
    pub fn tetrahedra(
        &mut self,
        selectors: &[Selector],
        context: &str,
    ) -> Result<(Selected, String), SelectionError> {
        let mesh = self.mesh;
        let mut tets = BTreeSet::new();
        let mut parts = Vec::new();
        for (index, sel) in selectors.iter().enumerate() {
            let taken: Vec<usize> = if let Some(name) = &sel.group {
                let group = self
                    .group(name, context)
                    .map_err(|message| SelectionError::Group {
                        context: context.to_owned(),
                        index,
                        message,
                    })?;
                if group.dim == 3 {
                    group.elements.clone()
                } else {
                    Vec::new()
                }
            } else {
                mesh.tetrahedra
                    .iter()
                    .enumerate()
                    .filter(|(_, t)| {
                        let mut c = [0.0; 3];
                        for &n in &t.nodes {
                            for (k, ck) in c.iter_mut().enumerate() {
                                *ck += 0.25 * mesh.nodes[n][k];
                            }
                        }
                        self.inside(sel, c)
                    })
                    .map(|(i, _)| i)
                    .collect()
            };
            if taken.is_empty() {
                return Err(self.empty(context, index, sel, "tetrahedra"));
            }
            parts.push(format!("{}: {} tetrahedra", sel.describe(), taken.len()));
            tets.extend(taken);
        }
        let selected = Selected {
            nodes: Vec::new(),
            faces: Vec::new(),
            tetrahedra: tets.into_iter().collect(),
        };
        let note = format!(
            "{context}: selection took {} tetrahedra ({})",
            selected.tetrahedra.len(),
            parts.join("; ")
        );
        Ok((selected, note))
    }

    fn group(&self, name: &str, context: &str) -> Result<&'m PhysicalGroup, String> {
        self.mesh
            .find_group(name, context)
            .map_err(|e| e.to_string())
    }

    fn empty(
        &self,
        context: &str,
        index: usize,
        sel: &Selector,
        kind: &'static str,
    ) -> SelectionError {
        SelectionError::Empty {
            context: context.to_owned(),
            index,
            what: sel.describe(),
            kind,
            extent: self.extent,
        }
    }

    /// Node indices of the tags listed in `file`, each once, and a warning naming the tags
    /// listed more than once (exports often repeat the nodes that elements share).
    fn node_list(
        &self,
        file: &Path,
        context: &str,
    ) -> Result<(Vec<usize>, Option<String>), SelectionError> {
        let err = |message: String| SelectionError::NodeList {
            context: context.to_owned(),
            path: file.to_owned(),
            message,
        };
        let text =
            std::fs::read_to_string(file).map_err(|e| err(format!("cannot read it: {e}")))?;
        let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
        let index: BTreeMap<u64, usize> = self
            .mesh
            .node_tags
            .iter()
            .enumerate()
            .map(|(i, &t)| (t, i))
            .collect();
        let mut out = BTreeSet::new();
        // Tag → the lines that list it, in order: a tag listed again is used once.
        let mut lines_of: BTreeMap<u64, Vec<usize>> = BTreeMap::new();
        for (line_no, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("");
            for token in line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|t| !t.is_empty())
            {
                let tag: u64 = token.parse().map_err(|_| {
                    err(format!(
                        "line {}: {token:?} is not a node tag (a non-negative integer)",
                        line_no + 1
                    ))
                })?;
                let lines = lines_of.entry(tag).or_default();
                lines.push(line_no + 1);
                if lines.len() > 1 {
                    continue;
                }
                let &i = index.get(&tag).ok_or_else(|| {
                    err(format!(
                        "line {}: node {tag} is not in the mesh (tags run from {} to {})",
                        line_no + 1,
                        self.mesh.node_tags.iter().min().copied().unwrap_or(0),
                        self.mesh.node_tags.iter().max().copied().unwrap_or(0)
                    ))
                })?;
                if !self.used[i] {
                    return Err(err(format!(
                        "line {}: node {tag} belongs to no tetrahedron (it is not in the model)",
                        line_no + 1
                    )));
                }
                out.insert(i);
            }
        }
        Ok((out.into_iter().collect(), repeated_tags(file, &lines_of)))
    }
}

/// Tags shown by name in the warning on repeated tags; the rest are counted.
const REPEATS_SHOWN: usize = 5;

/// The warning on the tags of a node list that are listed more than once (`lines_of`: per
/// tag, the lines that list it), or `None` when every tag is listed once.
fn repeated_tags(file: &Path, lines_of: &BTreeMap<u64, Vec<usize>>) -> Option<String> {
    let repeated: Vec<(u64, &Vec<usize>)> = lines_of
        .iter()
        .filter(|(_, lines)| lines.len() > 1)
        .map(|(&tag, lines)| (tag, lines))
        .collect();
    if repeated.is_empty() {
        return None;
    }
    let extra: usize = repeated.iter().map(|(_, lines)| lines.len() - 1).sum();
    // "node 2 (3 times: lines 1, 3 and 4)", each line once, at most four.
    let where_ = |tag: u64, l: &[usize]| {
        let mut distinct: Vec<usize> = l.to_vec();
        distinct.dedup();
        let shown: Vec<String> = distinct.iter().take(4).map(usize::to_string).collect();
        let lines = match shown.as_slice() {
            [one] => format!("line {one}"),
            [init @ .., last] if distinct.len() <= 4 => {
                format!("lines {} and {last}", init.join(", "))
            }
            _ => format!("lines {}, …", shown.join(", ")),
        };
        format!("node {tag} ({} times: {lines})", l.len())
    };
    let mut listed: Vec<String> = repeated
        .iter()
        .take(REPEATS_SHOWN)
        .map(|&(tag, l)| where_(tag, l))
        .collect();
    if repeated.len() > REPEATS_SHOWN {
        listed.push(format!("{} more nodes", repeated.len() - REPEATS_SHOWN));
    }
    Some(format!(
        "node_list {} lists {} node{} more than once ({}): {extra} duplicate entr{} ignored, each \
         node is used once",
        file.display(),
        repeated.len(),
        if repeated.len() == 1 { "" } else { "s" },
        listed.join("; "),
        if extra == 1 { "y" } else { "ies" }
    ))
}
