//! Linear tetrahedral FEM: element routines, sparse assembly of K, M, C with Dirichlet
//! elimination, and the scene's input and output operators (loads, gravity, sensors, node sets).

pub mod element;
pub mod export;
pub mod operators;

use std::collections::BTreeSet;

use faer::sparse::{SparseColMat, Triplet};

pub use crate::algorithms::sparse::{sparse_entries, sparse_mul};
pub use element::{ElasticMaterial, TetGeometry};

use crate::mesh::selection::{SelectionError, Selections};
use crate::mesh::{Mesh, UnknownGroup};
use crate::scene::{Scene, Target};

/// Errors in building the finite-element model from a mesh and a scene.
#[derive(Debug, thiserror::Error)]
pub enum FemError {
    /// The scene names a physical group the mesh does not have.
    #[error(transparent)]
    UnknownGroup(#[from] UnknownGroup),
    /// A selection (`select = [...]`) that cannot be resolved or takes nothing (boxed: it is
    /// large and rare).
    #[error(transparent)]
    Selection(Box<SelectionError>),
    /// Tetrahedra with negative (inverted) or near-zero volume: all of them are counted, the
    /// first ten listed, and the first described in full.
    #[error(
        "{count} tetrahedra are inverted or degenerate (first ten, tag: volume m³: {}); \
         tetrahedron {tag} (nodes {nodes:?}) is {kind}: volume {volume:e} m³; \
         fix the mesh (gmsh: Mesh.Optimize = 1) or re-orient the elements",
        listed.iter().map(|(t, v)| format!("{t}: {v:.3e}")).collect::<Vec<_>>().join(", ")
    )]
    DegenerateElement {
        /// Number of inverted or degenerate tetrahedra.
        count: usize,
        /// (gmsh element tag, signed volume in m³) of the first ten.
        listed: Box<[(u64, f64)]>,
        /// gmsh element tag.
        tag: u64,
        /// gmsh node tags.
        nodes: Box<[u64; 4]>,
        /// "inverted" or "degenerate (zero volume)".
        kind: &'static str,
        /// Signed volume.
        volume: f64,
    },
    /// Tetrahedra that no material group covers, or that two groups cover.
    #[error("{0}")]
    Materials(String),
    /// A sensor point not inside any tetrahedron.
    #[error(
        "sensor '{name}' at ({:.6}, {:.6}, {:.6}) m lies outside the mesh \
         (nearest node {nearest_tag} at distance {distance:.3e} m)",
        position[0], position[1], position[2]
    )]
    SensorOutside {
        /// Sensor name.
        name: String,
        /// Position, m.
        position: [f64; 3],
        /// gmsh tag of the nearest node.
        nearest_tag: u64,
        /// Distance to it, m.
        distance: f64,
    },
    /// Any other inconsistency between scene and mesh, described in full.
    #[error("{0}")]
    Scene(String),
}

impl From<SelectionError> for FemError {
    fn from(e: SelectionError) -> Self {
        FemError::Selection(Box::new(e))
    }
}

/// Map between (node, component) and the free (unconstrained) DOF index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DofMap {
    /// For each mesh node and component, the free DOF index, or `None` when the component is
    /// fixed or the node belongs to no tetrahedron.
    pub index: Vec<[Option<usize>; 3]>,
    /// For each free DOF, its (node index, component).
    pub dofs: Vec<(usize, usize)>,
}

impl DofMap {
    /// Number of free DOFs n.
    pub fn len(&self) -> usize {
        self.dofs.len()
    }

    /// True when every DOF is fixed.
    pub fn is_empty(&self) -> bool {
        self.dofs.is_empty()
    }

    /// The 12 free-DOF indices of a tetrahedron's nodes (None where fixed).
    pub fn element(&self, nodes: &[usize; 4]) -> [Option<usize>; 12] {
        std::array::from_fn(|i| self.index[nodes[i / 3]][i % 3])
    }
}

/// One tetrahedron of the model.
#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    /// gmsh element tag.
    pub tag: u64,
    /// Node indices into [`FemModel::positions`].
    pub nodes: [usize; 4],
    /// Index into [`FemModel::materials`].
    pub material: usize,
    /// Rest geometry.
    pub geometry: TetGeometry,
}

/// The assembled full-order model: M ü + C u̇ + K u = f on the free DOFs, C = αM + βK.
#[derive(Clone, Debug)]
pub struct FemModel {
    /// gmsh node tags.
    pub node_tags: Vec<u64>,
    /// Rest positions of all mesh nodes, m.
    pub positions: Vec<[f64; 3]>,
    /// Tetrahedra with their geometry.
    pub elements: Vec<Element>,
    /// Materials, in scene order.
    pub materials: Vec<ElasticMaterial>,
    /// DOF numbering after Dirichlet elimination.
    pub dofs: DofMap,
    /// Stiffness K (n×n, N/m), both triangles stored.
    pub stiffness: SparseColMat<usize, f64>,
    /// Mass M (n×n, kg), consistent or lumped.
    pub mass: SparseColMat<usize, f64>,
    /// Rayleigh α (1/s).
    pub alpha: f64,
    /// Rayleigh β (s).
    pub beta: f64,
    /// What the wiring should tell the user: scene warnings, orphan nodes left out, a mesh
    /// extent that looks like the wrong unit, what each `select` took.
    pub notes: Vec<String>,
}

/// Notes about the mesh that need the scene's unit: nodes left out, an extent that looks like
/// the wrong unit (bounding-box diagonal above 50 m or below 5 mm).
pub fn mesh_notes(mesh: &Mesh, unit: f64) -> Vec<String> {
    let mut notes = Vec::new();
    let orphans = mesh.orphan_nodes();
    if !orphans.is_empty() {
        let tags: Vec<String> = orphans
            .iter()
            .take(10)
            .map(|&i| mesh.node_tags[i].to_string())
            .collect();
        notes.push(format!(
            "{}: {} node(s) belong to no tetrahedron and are left out of the model (first tags: {})",
            mesh.source.display(),
            orphans.len(),
            tags.join(", ")
        ));
    }
    let (lo, hi) = mesh.extent();
    let diag = (0..3).map(|c| (hi[c] - lo[c]).powi(2)).sum::<f64>().sqrt() * unit;
    if diag.is_finite() && diag > 50.0 {
        notes.push(format!(
            "the mesh spans {diag:.3e} m (bounding-box diagonal, mesh.units applied): if its \
             coordinates are millimetres or centimetres, set mesh.units = \"mm\" or \"cm\""
        ));
    } else if diag.is_finite() && diag < 5e-3 {
        notes.push(format!(
            "the mesh spans only {diag:.3e} m (bounding-box diagonal, mesh.units applied): if its \
             coordinates are metres, set mesh.units = \"m\""
        ));
    }
    notes
}

impl FemModel {
    /// Assembles K and M over the free DOFs. `unit` converts mesh coordinates to metres.
    pub fn assemble(mesh: &Mesh, scene: &Scene, unit: f64) -> Result<Self, FemError> {
        let positions: Vec<[f64; 3]> = mesh.nodes.iter().map(|p| p.map(|v| v * unit)).collect();
        let materials: Vec<ElasticMaterial> = scene
            .materials
            .iter()
            .map(|m| ElasticMaterial {
                young_modulus: m.young_modulus,
                poisson_ratio: m.poisson_ratio,
                density: m.density,
            })
            .collect();

        // Material of each tetrahedron: exactly one material group.
        let mut notes = scene.warnings();
        notes.extend(mesh_notes(mesh, unit));
        let mut selections = Selections::new(mesh);
        let mut material_of = vec![None::<usize>; mesh.tetrahedra.len()];
        for (mi, m) in scene.materials.iter().enumerate() {
            let selected;
            let (label, elements): (String, &[usize]) = match m.target() {
                Target::Group(name) => {
                    let group = mesh.find_group(name, "material")?;
                    if group.dim != 3 {
                        return Err(FemError::Scene(format!(
                            "material: physical group '{name}' is {}-dimensional; materials need a volume (3-D) group",
                            group.dim
                        )));
                    }
                    (name.to_owned(), &group.elements)
                }
                Target::Select(list) => {
                    let context = format!("material {}", mi + 1);
                    let (s, note) = selections.tetrahedra(list, &context)?;
                    notes.push(note);
                    selected = s;
                    (context, &selected.tetrahedra)
                }
            };
            for &e in elements {
                if let Some(other) = material_of[e] {
                    let other_label = match scene.materials[other].target() {
                        Target::Group(g) => g.to_owned(),
                        Target::Select(_) => format!("material {}", other + 1),
                    };
                    return Err(FemError::Materials(format!(
                        "tetrahedron {} belongs to two material groups, '{other_label}' and '{label}'",
                        mesh.tetrahedra[e].tag
                    )));
                }
                material_of[e] = Some(mi);
            }
        }
        let uncovered: Vec<u64> = material_of
            .iter()
            .zip(&mesh.tetrahedra)
            .filter(|(m, _)| m.is_none())
            .map(|(_, t)| t.tag)
            .collect();
        if !uncovered.is_empty() {
            return Err(FemError::Materials(format!(
                "{} tetrahedra have no material (first tags: {:?}); give every volume group a [[material]]",
                uncovered.len(),
                &uncovered[..uncovered.len().min(5)]
            )));
        }
        if mesh.tetrahedra.is_empty() {
            return Err(FemError::Scene("the mesh has no tetrahedra".into()));
        }

        // Geometry; reject inverted and degenerate elements.
        let mut elements = Vec::with_capacity(mesh.tetrahedra.len());
        let mut bad: Vec<(usize, &'static str, f64)> = Vec::new();
        for (tet, material) in mesh.tetrahedra.iter().zip(&material_of) {
            let x = tet.nodes.map(|n| positions[n]);
            let geometry = TetGeometry::new(&x);
            let h = (0..4)
                .flat_map(|a| (a + 1..4).map(move |b| (a, b)))
                .map(|(a, b)| {
                    let d = [x[a][0] - x[b][0], x[a][1] - x[b][1], x[a][2] - x[b][2]];
                    element::dot(d, d).sqrt()
                })
                .fold(0.0f64, f64::max);
            let kind = if geometry.volume.is_nan() || geometry.volume.abs() <= 1e-10 * h * h * h {
                Some("degenerate (zero volume)")
            } else if geometry.volume < 0.0 {
                Some("inverted")
            } else {
                None
            };
            if let Some(kind) = kind {
                bad.push((elements.len(), kind, geometry.volume));
            }
            elements.push(Element {
                tag: tet.tag,
                nodes: tet.nodes,
                material: material.unwrap_or(0),
                geometry,
            });
        }

        if let Some(&(first, kind, volume)) = bad.first() {
            let tet = &mesh.tetrahedra[first];
            return Err(FemError::DegenerateElement {
                count: bad.len(),
                listed: bad
                    .iter()
                    .take(10)
                    .map(|&(i, _, v)| (mesh.tetrahedra[i].tag, v))
                    .collect(),
                tag: tet.tag,
                nodes: Box::new(tet.nodes.map(|n| mesh.node_tags[n])),
                kind,
                volume,
            });
        }

        // DOF numbering: nodes in tetrahedra, minus fixed components, node-major.
        let mut used = vec![false; positions.len()];
        for e in &elements {
            for &n in &e.nodes {
                used[n] = true;
            }
        }
        let mut fixed = vec![[false; 3]; positions.len()];
        for (fi, f) in scene.fixed.iter().enumerate() {
            let selected;
            let nodes: &[usize] = match f.target() {
                Target::Group(name) => &mesh.find_group(name, "fixed")?.nodes,
                Target::Select(list) => {
                    let context = format!("fixed {}", fi + 1);
                    let (s, note) = selections.nodes(list, &context)?;
                    notes.push(note);
                    selected = s;
                    &selected.nodes
                }
            };
            for &n in nodes {
                for c in &f.components {
                    fixed[n][c.index()] = true;
                }
            }
        }
        let mut dofs = DofMap {
            index: vec![[None; 3]; positions.len()],
            dofs: Vec::new(),
        };
        for n in 0..positions.len() {
            for c in 0..3 {
                if used[n] && !fixed[n][c] {
                    dofs.index[n][c] = Some(dofs.dofs.len());
                    dofs.dofs.push((n, c));
                }
            }
        }
        if dofs.is_empty() {
            return Err(FemError::Scene(
                "every degree of freedom is fixed: nothing can move".into(),
            ));
        }

        let n = dofs.len();
        let mut k_triplets = Vec::with_capacity(elements.len() * 144);
        let mut m_triplets = Vec::with_capacity(elements.len() * 48);
        for e in &elements {
            let material = &materials[e.material];
            let ke = e.geometry.stiffness(material);
            let me = e.geometry.mass(material.density, scene.mass.lumped);
            let map = dofs.element(&e.nodes);
            for i in 0..12 {
                let Some(row) = map[i] else { continue };
                for j in 0..12 {
                    let Some(col) = map[j] else { continue };
                    k_triplets.push(Triplet::new(row, col, ke[i][j]));
                    if i % 3 == j % 3 && me[i / 3][j / 3] != 0.0 {
                        m_triplets.push(Triplet::new(row, col, me[i / 3][j / 3]));
                    }
                }
            }
        }
        let stiffness = SparseColMat::try_new_from_triplets(n, n, &k_triplets)
            .map_err(|e| FemError::Scene(format!("sparse assembly of K failed: {e:?}")))?;
        let mass = SparseColMat::try_new_from_triplets(n, n, &m_triplets)
            .map_err(|e| FemError::Scene(format!("sparse assembly of M failed: {e:?}")))?;

        Ok(FemModel {
            node_tags: mesh.node_tags.clone(),
            positions,
            elements,
            materials,
            dofs,
            stiffness,
            mass,
            alpha: scene.damping.alpha,
            beta: scene.damping.beta,
            notes,
        })
    }

    /// Number of free DOFs n.
    pub fn dof_count(&self) -> usize {
        self.dofs.len()
    }

    /// Rayleigh damping C = αM + βK (n×n, N·s/m).
    pub fn damping(&self) -> SparseColMat<usize, f64> {
        let mut triplets = Vec::new();
        for (mat, factor) in [(&self.mass, self.alpha), (&self.stiffness, self.beta)] {
            if factor == 0.0 {
                continue;
            }
            for (row, col, v) in sparse_entries(mat) {
                triplets.push(Triplet::new(row, col, factor * v));
            }
        }
        let n = self.dof_count();
        SparseColMat::try_new_from_triplets(n, n, &triplets)
            .expect("the entries come from n×n matrices, so every index is in range")
    }

    /// Element stiffness Kₑ (12×12) of element `e` in its rest configuration.
    pub fn element_stiffness(&self, e: usize) -> [[f64; 12]; 12] {
        let el = &self.elements[e];
        el.geometry.stiffness(&self.materials[el.material])
    }

    /// Nodes that belong to at least one tetrahedron, and so are part of the model.
    pub fn used_nodes(&self) -> BTreeSet<usize> {
        self.elements.iter().flat_map(|e| e.nodes).collect()
    }

    /// Expands a free-DOF vector to per-node displacements (fixed components are zero), m.
    pub fn nodal(&self, u: &[f64]) -> Vec<[f64; 3]> {
        let mut out = vec![[0.0; 3]; self.positions.len()];
        for (&(node, c), &v) in self.dofs.dofs.iter().zip(u) {
            out[node][c] = v;
        }
        out
    }
}
