//! Tetrahedral meshes read from gmsh files (MSH 4.1 ASCII/binary through mshio, MSH 2.2 ASCII).
//!
//! Coordinates are stored as read (mesh units); the scene's unit factor is applied by the caller.

use std::path::PathBuf;

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

    /// Names of all physical groups, for error messages.
    pub fn group_names(&self) -> Vec<String> {
        self.groups.iter().map(|g| g.name.clone()).collect()
    }
}
