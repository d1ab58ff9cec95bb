//! Rotation rows for the run-time warping of docs/design.md §5.
//!
//! For a linear tetrahedron the infinitesimal rotation ωₑ = ½ ∇×u is constant and linear in the
//! nodal displacements ([`TetGeometry::rotation`](crate::fem::TetGeometry::rotation)). A node's ω
//! is the volume-weighted mean of ωₑ over the elements around it, so ω at any node (or any point,
//! by interpolation) is a fixed row block W over the free DOFs; the compiler projects W onto the
//! reduced state and the runtime evaluates R(ω), R̃(ω) from it.

use crate::fem::operators::{interpolate_rows, merge, SparseRow};
use crate::fem::FemModel;

/// Nodal rotation rows W (3 rows per node, rad per m of displacement) for a [`FemModel`].
pub struct RotationRows {
    /// For each mesh node: the elements around it and their volumes.
    around: Vec<Vec<usize>>,
}

impl RotationRows {
    /// Builds the node → element adjacency.
    pub fn new(fem: &FemModel) -> Self {
        let mut around = vec![Vec::new(); fem.positions.len()];
        for (e, el) in fem.elements.iter().enumerate() {
            for &n in &el.nodes {
                around[n].push(e);
            }
        }
        RotationRows { around }
    }

    /// ω rows at node `node`: Σₑ Vₑ Wₑ uₑ / Σₑ Vₑ over the elements around the node.
    pub fn at_node(&self, fem: &FemModel, node: usize) -> [SparseRow; 3] {
        let mut rows: [SparseRow; 3] = Default::default();
        let total: f64 = self.around[node]
            .iter()
            .map(|&e| fem.elements[e].geometry.volume)
            .sum();
        for &e in &self.around[node] {
            let el = &fem.elements[e];
            let w = el.geometry.rotation();
            let share = el.geometry.volume / total;
            let map = fem.dofs.element(&el.nodes);
            for c in 0..3 {
                for (j, dof) in map.iter().enumerate() {
                    if let Some(d) = dof {
                        if w[c][j] != 0.0 {
                            rows[c].push((*d, share * w[c][j]));
                        }
                    }
                }
            }
        }
        rows.map(merge)
    }

    /// ω rows at a weighted set of nodes (a sensor's barycentric weights, a load group's shares).
    pub fn at_weights(&self, fem: &FemModel, weights: &[(usize, f64)]) -> [SparseRow; 3] {
        interpolate_rows(weights, |node| self.at_node(fem, node))
    }
}
