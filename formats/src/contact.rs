//! The contact region (format v9): where a tool may touch the body, with what the runtime's
//! contact step needs (docs/contact.md): the region's surface nodes, their rest positions and
//! outward normals, the reduced model's input columns and displacement rows at every region
//! node, and the static residual compliance that the balanced truncation does not keep.

use crate::Matrix;
use serde::{Deserialize, Serialize};

/// A contact region of the body (docs/contact.md).
///
/// For region node i (n nodes), the displacement in the local (linear) frame at the end of a
/// step is u_i = C_i x⁺ + Σ_j D_ij f_j, with x⁺ = F x + G u + Σ_j B_j f_j the prediction and
/// f_j the contact force (N, body frame) on region node j during the step. C_i and B_j are 3×r
/// blocks of [`ContactRegion::displacement_rows`] and [`ContactRegion::input_rows`]; D_ij the
/// 3×3 blocks of the residual compliance listed in [`ContactRegion::residual_pairs`].
///
/// Contact is enforced at the Wilson θ-point of the step, where the displacement is
/// û_i = θ³ C_i x⁺ − W_i x + E_i u + Σ_j D̂_ij f_j (x the state before the step, u the step's
/// deterministic inputs; W_i, E_i the 3×r and 3×m blocks of [`ContactRegion::theta_rows`] and
/// [`ContactRegion::theta_input_rows`], D̂_ij those of
/// [`ContactRegion::theta_residual_blocks`]); at a steady state û_i = u_i.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactRegion {
    /// The scene's contact name.
    pub name: String,
    /// Radius of the spherical tool that touches it, m (> 0).
    pub tool_radius: f64,
    /// The largest tool force magnitude the runtime returns, N (> 0).
    pub max_force: f64,
    /// gmsh node tags of the region's surface nodes, n of them.
    pub node_tags: Vec<u64>,
    /// X, n×3: rest positions, m.
    pub rest_positions: Matrix,
    /// n×3: unit outward surface normals at rest.
    pub normals: Matrix,
    /// C, 3n×r: local-frame displacement of region node i in rows 3i..3i+3, m.
    pub displacement_rows: Matrix,
    /// Bᵀ, 3n×r: row 3i + c is the reduced input column of a unit force (1 N) in direction c on
    /// region node i (the state's response over one step).
    pub input_rows: Matrix,
    /// W, 3n×r: û = θ³ C x⁺ − W x is the displacement at the θ-point t + θΔt of the step
    /// from x to x⁺, m.
    pub theta_rows: Matrix,
    /// E, 3n×m: the θ-point's static correction for the deterministic inputs (the truncation's
    /// state does not rest exactly at a steady state), m/input unit.
    pub theta_input_rows: Matrix,
    /// Pairs (i, j), i ≤ j, whose residual compliance block D_ij is stored, sorted; D_ji = D_ijᵀ.
    pub residual_pairs: Vec<[u32; 2]>,
    /// The blocks D_ij of `residual_pairs`, 9 values each (row-major 3×3), m/N.
    pub residual_blocks: Vec<f64>,
    /// The θ-point's residual blocks D̂_ij then D̂_ji of each of `residual_pairs` (18 values
    /// per pair, row-major 3×3 each; not symmetric), m/N.
    pub theta_residual_blocks: Vec<f64>,
    /// Rest distance (m) within which node pairs keep their residual block; pairs farther apart
    /// use D_ij = 0.
    pub residual_radius: f64,
}

impl ContactRegion {
    /// Number of region nodes n.
    pub fn len(&self) -> usize {
        self.node_tags.len()
    }

    /// Whether the region has no node.
    pub fn is_empty(&self) -> bool {
        self.node_tags.is_empty()
    }
}
