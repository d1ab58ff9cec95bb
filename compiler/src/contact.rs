//! The contact region (docs/contact.md): the surface nodes a tool may touch, their outward
//! normals, the region's full-order static compliance, the directions of it that the balanced
//! truncation keeps as inputs and outputs, and the static residual compliance stored beside the
//! reduced model so that a point force anywhere on the region gets the full-order static
//! response.

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};

use crokf_formats as fmt;

use crate::fem::operators::SparseRow;
use crate::fem::{FemError, FemModel};
use crate::mesh::selection::Selections;
use crate::mesh::Mesh;
use crate::scene::{Scene, Target};

/// Node pairs whose rest distance is at most this multiple of the tool's diameter keep their
/// residual compliance block: two nodes can touch one sphere together only if they lie within
/// its diameter of each other, with room for the deformation between them.
pub const RESIDUAL_RADIUS_FACTOR: f64 = 1.5;

/// Most directions of the region's compliance the truncation takes as inputs and outputs.
pub const MAX_DIRECTIONS: usize = 60;

/// A contact region resolved on the mesh.
#[derive(Clone, Debug)]
pub struct ContactRegion {
    /// The scene's name.
    pub name: String,
    /// Mesh node indices, sorted: the boundary nodes of the selection whose three components
    /// are free.
    pub nodes: Vec<usize>,
    /// Free DOF index of each node's x, y, z (3 per node, node order).
    pub dofs: Vec<usize>,
    /// Unit outward normal at each node (area-weighted mean of its boundary faces).
    pub normals: Vec<[f64; 3]>,
    /// Tool radius, m.
    pub radius: f64,
    /// Force bound, N.
    pub max_force: f64,
    /// The scene's rank tolerance.
    pub rank_tolerance: f64,
    /// What the selection took.
    pub note: String,
}

/// The region's full-order static compliance and its kept directions.
#[derive(Clone, Debug)]
pub struct RegionCompliance {
    /// G = S K⁻¹ Sᵀ, 3n×3n, m/N (S selects the region's DOFs).
    pub matrix: Mat<f64>,
    /// Eigenvalues of G, descending.
    pub eigenvalues: Vec<f64>,
    /// The kept eigenvectors (3n×k): inputs and outputs of the balanced truncation.
    pub directions: Mat<f64>,
}

impl ContactRegion {
    /// The scene's contact region on the mesh, if it declares one. Errors name the entry: a
    /// selection with no boundary node, or whose boundary nodes are all fixed.
    pub fn build(
        mesh: &Mesh,
        scene: &Scene,
        fem: &FemModel,
        unit: f64,
    ) -> Result<Option<Self>, FemError> {
        let Some(c) = scene.contacts.first() else {
            return Ok(None);
        };
        let context = format!("contact '{}'", c.name);
        let mut selections = Selections::new(mesh);
        let surface: Vec<[usize; 3]> = selections.boundary_faces().to_vec();
        let mut on_surface = vec![false; mesh.nodes.len()];
        for f in &surface {
            for &n in f {
                on_surface[n] = true;
            }
        }
        let (selected, what) = match c.target() {
            Target::Group(g) => {
                let group = mesh.find_group(g, &context)?;
                (group.nodes.clone(), format!("group '{g}'"))
            }
            Target::Select(list) => {
                let (s, note) = selections.nodes(list, &context)?;
                (s.nodes, note)
            }
        };
        let taken = selected.len();
        let boundary: Vec<usize> = selected
            .into_iter()
            .filter(|&n| on_surface.get(n).copied().unwrap_or(false))
            .collect();
        if boundary.is_empty() {
            return Err(FemError::Scene(format!(
                "{context}: {what} takes {taken} nodes, none of them on the body's surface: a \
                 tool touches the surface only (select with nodes = \"boundary\" or a surface \
                 group)"
            )));
        }
        let mut nodes = Vec::new();
        let mut dofs = Vec::new();
        let mut fixed = 0;
        for &n in &boundary {
            match fem.dofs.index[n] {
                [Some(x), Some(y), Some(z)] => {
                    nodes.push(n);
                    dofs.extend([x, y, z]);
                }
                _ => fixed += 1,
            }
        }
        if nodes.is_empty() {
            return Err(FemError::Scene(format!(
                "{context}: every one of its {} surface nodes has a fixed component ([[fixed]]): \
                 nothing is left for a tool to move",
                boundary.len()
            )));
        }
        nodes.sort_unstable();
        // Outward normals: area-weighted sums of the boundary faces at each node.
        let mut sum = vec![[0.0f64; 3]; mesh.nodes.len()];
        for f in &surface {
            let [a, b, d] = f.map(|n| fem.positions[n]);
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [d[0] - a[0], d[1] - a[1], d[2] - a[2]];
            let w = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            for &n in f {
                for k in 0..3 {
                    sum[n][k] += w[k];
                }
            }
        }
        let mut normals = Vec::with_capacity(nodes.len());
        let mut order = Vec::with_capacity(3 * nodes.len());
        for &n in &nodes {
            let s = sum[n];
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            if !(len > 0.0 && len.is_finite()) {
                return Err(FemError::Scene(format!(
                    "{context}: node {} has no outward normal (its boundary faces cancel)",
                    fem.node_tags[n]
                )));
            }
            normals.push([s[0] / len, s[1] / len, s[2] / len]);
            let [x, y, z] = fem.dofs.index[n];
            order.extend([x, y, z].map(|d| d.unwrap_or(0)));
        }
        let mut note = format!(
            "{context}: {} surface nodes of the {taken} its {what} takes",
            nodes.len()
        );
        if fixed > 0 {
            note.push_str(&format!(" ({fixed} with a fixed component left out)"));
        }
        Ok(Some(ContactRegion {
            name: c.name.clone(),
            nodes,
            dofs: order,
            normals,
            radius: c.radius * unit,
            max_force: c.max_force,
            rank_tolerance: c.rank_tolerance(),
            note,
        }))
    }

    /// Number of region nodes n.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether the region has no node (never, once built).
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The full-order static compliance of the region (3n solves with K's Cholesky factor) and
    /// its kept directions: every eigenvector whose eigenvalue is at least `rank_tolerance` ×
    /// the largest, at most [`MAX_DIRECTIONS`].
    pub fn compliance(&self, fem: &FemModel) -> Result<RegionCompliance, String> {
        let n = fem.dof_count();
        let m = self.dofs.len();
        let llt = fem
            .stiffness
            .sp_cholesky(Side::Lower)
            .map_err(|e| format!("stiffness K is not positive definite ({e:?})"))?;
        let mut rhs = Mat::<f64>::zeros(n, m);
        for (j, &d) in self.dofs.iter().enumerate() {
            rhs[(d, j)] = 1.0;
        }
        let solved = llt.solve(&rhs);
        let matrix = Mat::from_fn(m, m, |i, j| {
            0.5 * (solved[(self.dofs[i], j)] + solved[(self.dofs[j], i)])
        });
        let eig = matrix
            .self_adjoint_eigen(Side::Lower)
            .map_err(|e| format!("eigen-decomposition of the region's compliance: {e:?}"))?;
        // faer returns ascending eigenvalues.
        let s = eig.S().column_vector();
        let mut order: Vec<usize> = (0..m).collect();
        order.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
        let eigenvalues: Vec<f64> = order.iter().map(|&i| s[i]).collect();
        let top = eigenvalues.first().copied().unwrap_or(0.0);
        if top.is_nan() || top <= 0.0 {
            return Err("the region's static compliance is zero".into());
        }
        let kept = eigenvalues
            .iter()
            .take_while(|&&l| l >= self.rank_tolerance * top)
            .count()
            .clamp(1, MAX_DIRECTIONS.min(m));
        let u = eig.U();
        let directions = Mat::from_fn(m, kept, |i, j| {
            // Sign fixed by the largest entry (a rounding difference must not flip the model).
            let col = order[j];
            let pivot = (0..m)
                .max_by(|&a, &b| u[(a, col)].abs().total_cmp(&u[(b, col)].abs()))
                .map_or(1.0, |p| u[(p, col)].signum());
            pivot * u[(i, col)]
        });
        Ok(RegionCompliance {
            matrix,
            eigenvalues,
            directions,
        })
    }

    /// The kept directions as force patterns on the full DOF vector (one n_dofs-vector each):
    /// inputs of the modal basis and of the balanced truncation.
    pub fn input_columns(&self, compliance: &RegionCompliance, n_dofs: usize) -> Vec<Vec<f64>> {
        (0..compliance.directions.ncols())
            .map(|j| {
                let mut col = vec![0.0; n_dofs];
                for (i, &d) in self.dofs.iter().enumerate() {
                    col[d] = compliance.directions[(i, j)];
                }
                col
            })
            .collect()
    }

    /// The kept directions as output rows (displacement along each direction).
    pub fn output_rows(&self, compliance: &RegionCompliance) -> Vec<SparseRow> {
        (0..compliance.directions.ncols())
            .map(|j| {
                let mut row: SparseRow = self
                    .dofs
                    .iter()
                    .enumerate()
                    .map(|(i, &d)| (d, compliance.directions[(i, j)]))
                    .collect();
                row.sort_by_key(|&(d, _)| d);
                row
            })
            .collect()
    }

    /// Displacement rows of the region's DOFs (3n rows, node order, x y z).
    pub fn displacement_rows(&self) -> Vec<SparseRow> {
        self.dofs.iter().map(|&d| vec![(d, 1.0)]).collect()
    }

    /// The model file's section: the reduced rows `rows` (3n×r), input rows `input_rows`
    /// (3n×r, Bᵀ) and θ-point rows of the full state (force states included), and the residual D = G − C (I −
    /// F)⁻¹ B of the balanced part (r_b states) for the node pairs within the residual radius.
    /// Returns the section and a note on the point compliance.
    pub fn section(
        &self,
        fem: &FemModel,
        compliance: &RegionCompliance,
        reduced: ReducedRegion<'_>,
    ) -> (fmt::ContactRegion, String) {
        let n = self.len();
        let rb = reduced.balanced_order;
        let f = reduced.transition.submatrix(0, 0, rb, rb);
        let c = reduced.rows.subcols(0, rb);
        let b = reduced.input_rows.subcols(0, rb).transpose().to_owned();
        let lu = (Mat::<f64>::identity(rb, rb) - f).partial_piv_lu();
        let steady = lu.solve(&b);
        let reduced_compliance = c * &steady;
        // The θ-point rows' offset from (θ³ − 1) C: zero on a true modal steady state (no
        // velocity, no acceleration), not quite on the truncation's. Its steady response to
        // contact forces and to the inputs is stored as a correction, so that û = u at rest.
        let th3 = reduced.theta.powi(3);
        let offset = Mat::from_fn(3 * n, rb, |i, j| {
            reduced.theta_rows[(i, j)] - (th3 - 1.0) * c[(i, j)]
        });
        let theta_compliance = &offset * &steady;
        let steady_inputs = lu.solve(reduced.input.subrows(0, rb));
        let theta_inputs = &offset * &steady_inputs;
        let residual_radius = 2.0 * self.radius * RESIDUAL_RADIUS_FACTOR;
        let mut pairs = Vec::new();
        let mut blocks = Vec::new();
        let mut theta_blocks = Vec::new();
        let position = |i: usize| fem.positions[self.nodes[i]];
        for i in 0..n {
            let pi = position(i);
            for j in i..n {
                let pj = position(j);
                let d =
                    ((pi[0] - pj[0]).powi(2) + (pi[1] - pj[1]).powi(2) + (pi[2] - pj[2]).powi(2))
                        .sqrt();
                if i != j && d > residual_radius {
                    continue;
                }
                pairs.push([i as u32, j as u32]);
                for a in 0..3 {
                    for bb in 0..3 {
                        let (r, s) = (3 * i + a, 3 * j + bb);
                        let exact = compliance.matrix[(r, s)];
                        // Symmetric: the mean of the two reduced entries.
                        let approx =
                            0.5 * (reduced_compliance[(r, s)] + reduced_compliance[(s, r)]);
                        blocks.push(exact - approx);
                    }
                }
                // D̂_ij = G_ij − (C (I − F)⁻¹ B)_ij + (offset · steady)_ij, then D̂_ji: not
                // symmetrised, so that the steady θ-point displacement is the full order's in
                // every direction (a node's tangential slide sets its normal).
                for (p, q) in [(i, j), (j, i)] {
                    for a in 0..3 {
                        for bb in 0..3 {
                            let (r, s) = (3 * p + a, 3 * q + bb);
                            theta_blocks.push(
                                compliance.matrix[(r, s)] - reduced_compliance[(r, s)]
                                    + theta_compliance[(r, s)],
                            );
                        }
                    }
                }
            }
        }
        // Point compliance of the state-space part alone against the full order, per node.
        let mut errors: Vec<f64> = (0..n)
            .map(|i| {
                let mut num = 0.0;
                let mut den = 0.0;
                for a in 0..3 {
                    for bb in 0..3 {
                        let (r, s) = (3 * i + a, 3 * i + bb);
                        num += (compliance.matrix[(r, s)] - reduced_compliance[(r, s)]).powi(2);
                        den += compliance.matrix[(r, s)].powi(2);
                    }
                }
                (num / den).sqrt()
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        let max = errors[errors.len() - 1];
        let note = format!(
            "contact '{}': {n} nodes, {} compliance directions kept (eigenvalues ≥ {:.0e} of the \
             largest); point compliance of the reduced state alone against the full-order \
             static compliance: median {:.2} %, max {:.2} % — the stored static residual ({} \
             node pairs within {:.3e} m) makes it exact there",
            self.name,
            compliance.directions.ncols(),
            self.rank_tolerance,
            100.0 * median,
            100.0 * max,
            pairs.len(),
            residual_radius
        );
        let section = fmt::ContactRegion {
            name: self.name.clone(),
            tool_radius: self.radius,
            max_force: self.max_force,
            node_tags: self.nodes.iter().map(|&i| fem.node_tags[i]).collect(),
            rest_positions: fmt::Matrix::from_fn(n as u32, 3, |i, c| {
                fem.positions[self.nodes[i]][c]
            }),
            normals: fmt::Matrix::from_fn(n as u32, 3, |i, c| self.normals[i][c]),
            displacement_rows: matrix(reduced.rows),
            input_rows: matrix(reduced.input_rows),
            theta_rows: fmt::Matrix::from_fn(3 * n as u32, reduced.rows.ncols() as u32, |i, j| {
                if j < rb {
                    reduced.theta_rows[(i, j)]
                } else {
                    // Force states hold over the step: their (static) rows are the same at
                    // the θ-point as at its end.
                    (reduced.theta.powi(3) - 1.0) * reduced.rows[(i, j)]
                }
            }),
            theta_input_rows: matrix(theta_inputs.as_ref()),
            residual_pairs: pairs,
            residual_blocks: blocks,
            theta_residual_blocks: theta_blocks,
            residual_radius,
        };
        (section, note)
    }
}

/// A faer matrix as the model file's row-major matrix.
fn matrix(m: faer::MatRef<'_, f64>) -> fmt::Matrix {
    fmt::Matrix::from_fn(m.nrows() as u32, m.ncols() as u32, |i, j| m[(i, j)])
}

/// What [`ContactRegion::section`] reads of a reduced model.
pub struct ReducedRegion<'a> {
    /// F of the whole state.
    pub transition: faer::MatRef<'a, f64>,
    /// Balanced states (the first ones of the state).
    pub balanced_order: usize,
    /// C of the region, 3n × state.
    pub rows: faer::MatRef<'a, f64>,
    /// Bᵀ of the region, 3n × state.
    pub input_rows: faer::MatRef<'a, f64>,
    /// W of the region on the balanced states, 3n × balanced states ([`crate::reduced::RegionRows::theta`]).
    pub theta_rows: faer::MatRef<'a, f64>,
    /// Wilson's θ.
    pub theta: f64,
    /// G of the whole state (state × deterministic inputs).
    pub input: faer::MatRef<'a, f64>,
}
