//! The contact step (docs/contact.md): a rigid spherical tool on the model's contact region.
//!
//! Each step, after the prediction x⁻ = F x + G u without contact, the region nodes near each
//! tool are found on the body's *current* surface at the step's Wilson θ-point
//! (p̂_i = X_i + θ³ C_i x⁻ − W_i x + E_i u; a fresh search every step, never a frozen set), and
//! unilateral frictionless (Signorini) contact is solved there on the reduced model's θ-point
//! compliance of those nodes:
//!
//! ```text
//! gap_a = g_a + Σ_b A_ab λ_b ≥ 0,   λ_a ≥ 0,   λ_a · gap_a = 0,
//! g_a = n_aᵀ (p̂_a − c) − R,  A_ab = n_aᵀ (θ³ C_a B_bᵀ + D̂_ab) n_b
//! ```
//!
//! (λ_a the normal force on node a, N; B_b the node's input rows, D̂_ab the stored θ-point
//! residual) by an active-set method (principal pivoting with an iteration cap, warm-started
//! from the last step's contacts). The normals n_a point from the tool's centre to the solved
//! positions: the problem is solved again with them until they stay (at most
//! [`MAX_NORMAL_PASSES`] a step, carried to the next step), and a node the solved forces push
//! into the tool joins it. Enforced at the end of the step instead, with the force held over
//! it, the contact would oscillate with period two. The forces λ_a n_a enter the prediction as
//! inputs, x⁻ += Σ_a λ_a B_aᵀ n_a, before the markers' update. The tool receives −Σ_a λ_a n_a,
//! bounded by the region's `max_force`; its stiffness is N A⁻¹ Nᵀ over the active contacts
//! (N/m, the one-step stiffness for a device loop faster than the model), and its σ comes
//! from the prediction's covariance, Cov(F) = N A⁻¹ Hₙ P⁻ Hₙᵀ A⁻ᵀ Nᵀ.
//!
//! A tool that grasps ([`crate::Estimator::grasp`]) holds one region node at its centre plus a
//! fixed offset instead: three bilateral constraints along the axes in the same problem (their
//! forces of either sign), and it pushes nowhere else.
//!
//! The search keeps a list of the nodes within half a tool radius of the near zone of each
//! tool (a Verlet list), searched again from the grid only once the tools or the body may have
//! moved by that much; within it, a node whose cached position, less how far it can have moved,
//! is clear of the tool is not evaluated again.
//!
//! Everything is allocated when the estimator is built: the step allocates nothing.

use crokf_formats::ContactRegion;

/// Most tools at once (a probe and a grasper).
pub const MAX_TOOLS: usize = 2;

/// Most region nodes in one contact problem, over all tools; further candidates are left out
/// and the step's status says so.
pub const MAX_CONTACTS: usize = 48;

/// The search around each tool: region nodes whose free θ-point gap is below this fraction
/// of the tool radius are checked against the solved forces (a node the neighbours' forces
/// push into the tool joins the problem); farther nodes are taken to stay clear this step.
pub(crate) const CANDIDATE_MARGIN: f64 = 0.25;

/// The skin of the list of nodes near the tools, in tool radii: the list is searched again
/// once the tools or the body may have moved by this much since it was made.
const LIST_SKIN: f64 = 0.5;

/// Cap on the active-set iterations of one contact problem.
const MAX_PIVOTS: usize = 4 * MAX_CONTACTS;

/// Most contact solves of one step while the normals move to the solved positions.
const MAX_NORMAL_PASSES: usize = 6;

/// The normals are settled when no component moves by more than this.
const NORMAL_TOLERANCE: f64 = 1e-9;

/// What the last contact step did for a tool.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ContactStatus {
    /// No region node touches the tool.
    #[default]
    Free,
    /// In contact, every constraint met.
    Touching,
    /// Holding its grasped point where the tool puts it ([`crate::Estimator::grasp`]).
    Grasping,
    /// The force was above `max_force` and was scaled down to it: the tool went deeper than the
    /// model can push back within its bound (a tool pressed too far, started inside the body,
    /// or jumped).
    Clamped,
    /// More candidate nodes than [`MAX_CONTACTS`]: the nearest ones were solved, the rest left
    /// out.
    Overflow,
    /// The active-set iterations reached their cap: the last iterate's non-negative part was
    /// used.
    NotConverged,
}

/// The result of the last contact step for one tool (world = the model's frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolContact {
    /// Force of the body on the tool, N.
    pub force: [f64; 3],
    /// Torque of the body on the tool about its centre, N·m.
    pub torque: [f64; 3],
    /// ∂(−force)/∂(position), 3×3 row-major, N/m: the tool force changes by −K δc for a small
    /// move δc at the current contacts.
    pub stiffness: [f64; 9],
    /// Number of region nodes pressing on the tool (λ > 0).
    pub active: usize,
    /// Deepest penetration of the free prediction into the tool, m (0 when free).
    pub depth: f64,
    /// σ of `force` per component, N, from the prediction's covariance (computed when
    /// [`crate::Estimator::set_contact_force_std`] is on, else 0).
    pub force_std: [f64; 3],
    /// What happened.
    pub status: ContactStatus,
}

/// One contact point of the last step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContactPoint {
    /// The tool it touches.
    pub tool: usize,
    /// Index of the node in the region (`model.contact.node_tags`).
    pub node: usize,
    /// Position of the node after the step (with the contact force), m.
    pub position: [f64; 3],
    /// Force of the tool on the body at the node, N.
    pub force: [f64; 3],
}

/// The region's data arranged for the step, derived once per model.
#[derive(Clone, Debug)]
pub(crate) struct PreparedContact {
    pub(crate) radius: f64,
    pub(crate) max_force: f64,
    /// Rest positions, 3 per node.
    rest: Vec<f64>,
    /// Rest normals, 3 per node.
    normals: Vec<f64>,
    /// C (3n × r) and Bᵀ (3n × r), row-major.
    rows: Vec<f64>,
    input_rows: Vec<f64>,
    /// Per node i, its three θ-point rows over [x⁺; x] (2r each, row-major): [θ³ C_i | −W_i],
    /// and E (3n × m): û = θ³ C x⁺ − W x + E u.
    theta_rows: Vec<f64>,
    theta_input_rows: Vec<f64>,
    /// Per node: the Frobenius norm of its 3×r displacement block C_i, of its θ-point block
    /// [θ³C_i | −W_i] and of E_i.
    row_norm: Vec<f64>,
    theta_norm: Vec<f64>,
    input_norm: Vec<f64>,
    /// θ³.
    theta_cubed: f64,
    /// Over the nodes: the largest of `row_norm`, `theta_norm` and `input_norm` (the
    /// searches' displacement bounds).
    row_norm_max: f64,
    theta_norm_max: f64,
    input_norm_max: f64,
    /// The largest Frobenius norm of a θ-point residual block D̂_ij, m/N.
    residual_norm_max: f64,
    /// The largest Frobenius norm of an end-of-step residual block D_ij, m/N.
    residual_end_norm_max: f64,
    /// Residual blocks: per node i, its neighbours j with the block D_ij (row-major 3×3),
    /// CSR-like: `neighbours[start[i]..start[i + 1]]`.
    start: Vec<usize>,
    neighbours: Vec<(u32, Residual)>,
    /// The search grid over rest positions.
    grid: Grid,
}

/// The residual blocks of a node pair (i, j), row-major 3×3: D_ij for the end of the step,
/// D̂_ij for the θ-point.
#[derive(Clone, Copy, Debug)]
struct Residual {
    end: [f64; 9],
    theta: [f64; 9],
}

/// A uniform grid over the region's rest positions (CSR of node indices per cell).
#[derive(Clone, Debug)]
struct Grid {
    origin: [f64; 3],
    cell: f64,
    dims: [usize; 3],
    start: Vec<usize>,
    nodes: Vec<u32>,
}

impl Grid {
    fn new(rest: &[f64], cell: f64) -> Self {
        let n = rest.len() / 3;
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in rest.chunks_exact(3) {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        // At most 64 cells a side: a coarser cell only costs more candidates.
        let extent = (0..3).map(|c| hi[c] - lo[c]).fold(0.0, f64::max);
        let cell = cell.max(extent / 64.0).max(f64::MIN_POSITIVE);
        let dims = [0, 1, 2].map(|c| (((hi[c] - lo[c]) / cell).floor() as usize + 1).max(1));
        let cells = dims[0] * dims[1] * dims[2];
        let index = |p: &[f64]| -> usize {
            let i = [0, 1, 2].map(|c| (((p[c] - lo[c]) / cell) as usize).min(dims[c] - 1));
            (i[2] * dims[1] + i[1]) * dims[0] + i[0]
        };
        let mut count = vec![0usize; cells + 1];
        for p in rest.chunks_exact(3) {
            count[index(p) + 1] += 1;
        }
        for k in 0..cells {
            count[k + 1] += count[k];
        }
        let mut fill = count.clone();
        let mut nodes = vec![0u32; n];
        for (i, p) in rest.chunks_exact(3).enumerate() {
            let k = index(p);
            nodes[fill[k]] = i as u32;
            fill[k] += 1;
        }
        Grid {
            origin: lo,
            cell,
            dims,
            start: count,
            nodes,
        }
    }

    /// Calls `f(node)` for every node in the cells that meet the ball (c, reach).
    fn visit(&self, c: &[f64; 3], reach: f64, mut f: impl FnMut(usize)) {
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        for k in 0..3 {
            let a = ((c[k] - reach - self.origin[k]) / self.cell).floor();
            let b = ((c[k] + reach - self.origin[k]) / self.cell).floor();
            if b < 0.0 || a > (self.dims[k] - 1) as f64 {
                return;
            }
            lo[k] = a.max(0.0) as usize;
            hi[k] = (b as usize).min(self.dims[k] - 1);
        }
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let k = (z * self.dims[1] + y) * self.dims[0] + x;
                    for &node in &self.nodes[self.start[k]..self.start[k + 1]] {
                        f(node as usize);
                    }
                }
            }
        }
    }
}

impl PreparedContact {
    /// The region of a model stepped with Wilson's `theta`.
    pub(crate) fn new(c: &ContactRegion, theta: f64) -> Self {
        let n = c.len();
        let r = c.displacement_rows.cols as usize;
        let rows = c.displacement_rows.data.clone();
        let theta_rows: Vec<f64> = (0..3 * n)
            .flat_map(|row| {
                let c_row = &rows[row * r..(row + 1) * r];
                let w_row = &c.theta_rows.data[row * r..(row + 1) * r];
                c_row
                    .iter()
                    .map(|v| theta * theta * theta * v)
                    .chain(w_row.iter().map(|v| -v))
                    .collect::<Vec<_>>()
            })
            .collect();
        let row_norm = block_norms(&rows, n);
        let theta_norm = block_norms(&theta_rows, n);
        let input_norm = block_norms(&c.theta_input_rows.data, n);
        let mut lists: Vec<Vec<(u32, Residual)>> = vec![Vec::new(); n];
        let block = |v: &[f64]| -> [f64; 9] { std::array::from_fn(|m| v[m]) };
        for (k, p) in c.residual_pairs.iter().enumerate() {
            let (i, j) = (p[0] as usize, p[1] as usize);
            let end = block(&c.residual_blocks[9 * k..]);
            let theta = &c.theta_residual_blocks[18 * k..18 * k + 18];
            lists[i].push((
                j as u32,
                Residual {
                    end,
                    theta: block(theta),
                },
            ));
            if i != j {
                lists[j].push((
                    i as u32,
                    Residual {
                        end: [0, 3, 6, 1, 4, 7, 2, 5, 8].map(|m| end[m]),
                        theta: block(&theta[9..]),
                    },
                ));
            }
        }
        let mut start = Vec::with_capacity(n + 1);
        let mut neighbours = Vec::new();
        start.push(0);
        for mut l in lists {
            l.sort_by_key(|e| e.0);
            neighbours.extend(l);
            start.push(neighbours.len());
        }
        PreparedContact {
            radius: c.tool_radius,
            max_force: c.max_force,
            rest: c.rest_positions.data.clone(),
            normals: c.normals.data.clone(),
            rows,
            input_rows: c.input_rows.data.clone(),
            row_norm_max: row_norm.iter().copied().fold(0.0, f64::max),
            theta_norm_max: theta_norm.iter().copied().fold(0.0, f64::max),
            theta_norm,
            input_norm_max: input_norm.iter().copied().fold(0.0, f64::max),
            input_norm,
            theta_rows,
            row_norm,
            theta_input_rows: c.theta_input_rows.data.clone(),
            theta_cubed: theta * theta * theta,
            residual_end_norm_max: c
                .residual_blocks
                .chunks_exact(9)
                .map(|b| b.iter().map(|v| v * v).sum::<f64>().sqrt())
                .fold(0.0, f64::max),
            residual_norm_max: c
                .theta_residual_blocks
                .chunks_exact(9)
                .map(|b| b.iter().map(|v| v * v).sum::<f64>().sqrt())
                .fold(0.0, f64::max),
            start,
            neighbours,
            grid: Grid::new(&c.rest_positions.data, 2.0 * c.tool_radius),
        }
    }

    /// Number of region nodes.
    pub(crate) fn len(&self) -> usize {
        self.rest.len() / 3
    }

    /// Node i's position at the θ-point of the step from x to the prediction x⁺ with inputs
    /// `u` (no contact force): X_i + θ³ C_i x⁺ − W_i x + E_i u, `joint` = [x⁺; x].
    #[inline]
    fn theta_point(&self, i: usize, joint: &[f64], u: &[f64]) -> [f64; 3] {
        let r2 = joint.len();
        let m = u.len();
        let d = crate::simd::rows3(&self.theta_rows[3 * i * r2..3 * (i + 1) * r2], r2, joint);
        let e = &self.theta_input_rows[3 * i * m..3 * (i + 1) * m];
        [0, 1, 2].map(|k| self.rest[3 * i + k] + d[k] + dot(&e[k * m..(k + 1) * m], u))
    }

    fn residual(&self, i: usize, j: usize) -> Option<&Residual> {
        self.residual_index(i, j).map(|k| &self.neighbours[k].1)
    }

    /// Where the residual block of the pair (i, j) is in `neighbours`.
    fn residual_index(&self, i: usize, j: usize) -> Option<usize> {
        let list = &self.neighbours[self.start[i]..self.start[i + 1]];
        list.binary_search_by_key(&(j as u32), |e| e.0)
            .ok()
            .map(|k| self.start[i] + k)
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let ca = a.chunks_exact(4);
    let cb = b.chunks_exact(4);
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// The contact step's state and scratch (allocated once per estimator).
#[derive(Clone, Debug)]
pub(crate) struct ContactWork {
    r: usize,
    /// Candidates of this step (`candidates` of them): (tool, node), their free gap, normal
    /// and free position.
    candidates: usize,
    cand: Vec<(usize, usize)>,
    gap: Vec<f64>,
    normal: Vec<[f64; 3]>,
    position: Vec<[f64; 3]>,
    /// The normals at the solved positions of the last pass.
    next_normal: Vec<[f64; 3]>,
    /// The region nodes near the tools this step: (tool, node, free θ-point position, free
    /// gap), at most n per tool.
    visited: Vec<(usize, usize, [f64; 3], f64)>,
    /// [x⁺; x] of this step (2r: the prediction, then the state before it, set by
    /// [`ContactWork::set_previous`]), of the last step, and the last step's inputs (m).
    joint: Vec<f64>,
    last_joint: Vec<f64>,
    last_inputs: Vec<f64>,
    /// The path length of [x⁺; x] and of u over all steps so far.
    path: (f64, f64),
    /// Per region node: its θ-point position when last evaluated and `path` then (infinite
    /// before the first evaluation): a node whose cached position, less how far it can have
    /// moved since, is clear of every tool is not evaluated again.
    cache: Vec<[f64; 3]>,
    stamp: Vec<(f64, f64)>,
    /// Per candidate: h_a = C_aᵀ n_a and b_a = B_a n_a (r each).
    h: Vec<f64>,
    b: Vec<f64>,
    /// A (MAX_CONTACTS²), the active-set scratch.
    a: Vec<f64>,
    /// Per candidate pair (a, c) of the pass: where their residual block is in the region's
    /// `neighbours` (u32::MAX: none stored), found once a pass.
    pair: Vec<u32>,
    lambda: Vec<f64>,
    active: Vec<bool>,
    lu: Vec<f64>,
    piv: Vec<usize>,
    rhs: Vec<f64>,
    /// State increment Σ λ_a b_a.
    pub(crate) delta: Vec<f64>,
    /// Nodes active last step (region node index, tool), for the warm start.
    was_active: Vec<(usize, usize, [f64; 3])>,
    was_count: usize,
    /// Results of the last step.
    pub(crate) tools: [ToolContact; MAX_TOOLS],
    pub(crate) tool_count: usize,
    pub(crate) tool_position: [[f64; 3]; MAX_TOOLS],
    pub(crate) points: Vec<ContactPoint>,
    pub(crate) point_count: usize,
    /// Candidates of the last step that pressed (indices into `cand`), for the force σ.
    pressed: Vec<usize>,
    pressed_count: usize,
    scratch: Vec<f64>,
    /// Whether the step computes each tool's force σ.
    pub(crate) with_std: bool,
    /// The (tool, node) pairs that may be near a pushing tool ([`ContactWork::rebuild_list`]),
    /// and what they were found for: the paths, the tools' centres and which tools pushed.
    list: Vec<(u32, u32)>,
    list_count: usize,
    list_valid: bool,
    list_path: (f64, f64),
    list_tools: [[f64; 3]; MAX_TOOLS],
    list_tool_count: usize,
    list_pushing: [bool; MAX_TOOLS],
    /// Per tool: the point it holds, when grasping.
    grasp: [Option<Grasp>; MAX_TOOLS],
    /// Per candidate: a grasp's constraint (bilateral, along a fixed axis) rather than a push.
    bilateral: Vec<bool>,
    /// The results and warm start before the last step, for a rollback.
    saved: Saved,
}

/// A grasp: the region node a tool holds, kept at the tool's centre plus `offset` (m).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Grasp {
    node: usize,
    offset: [f64; 3],
}

/// What a rollback restores (preallocated).
#[derive(Clone, Debug)]
struct Saved {
    was_active: Vec<(usize, usize, [f64; 3])>,
    was_count: usize,
    tools: [ToolContact; MAX_TOOLS],
    tool_count: usize,
    tool_position: [[f64; 3]; MAX_TOOLS],
    points: Vec<ContactPoint>,
    point_count: usize,
    grasp: [Option<Grasp>; MAX_TOOLS],
}

impl ContactWork {
    /// Scratch for a model of r states with the region `pc`.
    pub(crate) fn new(r: usize, pc: &PreparedContact) -> Self {
        let n = pc.len();
        let inputs = pc.theta_input_rows.len() / (3 * n).max(1);
        let m = MAX_CONTACTS;
        ContactWork {
            r,
            candidates: 0,
            cand: vec![(0, 0); m],
            gap: vec![0.0; m],
            normal: vec![[0.0; 3]; m],
            position: vec![[0.0; 3]; m],
            next_normal: vec![[0.0; 3]; m],
            visited: vec![(0, 0, [0.0; 3], 0.0); n * MAX_TOOLS],
            joint: vec![0.0; 2 * r],
            last_joint: vec![0.0; 2 * r],
            last_inputs: vec![0.0; inputs],
            path: (0.0, 0.0),
            cache: vec![[0.0; 3]; n],
            stamp: vec![(f64::INFINITY, f64::INFINITY); n],
            h: vec![0.0; m * r],
            b: vec![0.0; m * r],
            a: vec![0.0; m * m],
            pair: vec![u32::MAX; m * m],
            lambda: vec![0.0; m],
            active: vec![false; m],
            lu: vec![0.0; m * m],
            piv: vec![0; m],
            rhs: vec![0.0; m],
            delta: vec![0.0; r],
            was_active: vec![(0, 0, [0.0; 3]); m],
            was_count: 0,
            tools: [ToolContact::default(); MAX_TOOLS],
            tool_count: 0,
            tool_position: [[0.0; 3]; MAX_TOOLS],
            points: vec![ContactPoint::default(); m],
            point_count: 0,
            pressed: vec![0; m],
            pressed_count: 0,
            scratch: vec![0.0; m * r.max(m)],
            with_std: false,
            list: vec![(0, 0); n * MAX_TOOLS],
            list_count: 0,
            list_valid: false,
            list_path: (0.0, 0.0),
            list_tools: [[0.0; 3]; MAX_TOOLS],
            list_tool_count: 0,
            list_pushing: [false; MAX_TOOLS],
            grasp: [None; MAX_TOOLS],
            bilateral: vec![false; m],
            saved: Saved {
                was_active: vec![(0, 0, [0.0; 3]); m],
                was_count: 0,
                tools: [ToolContact::default(); MAX_TOOLS],
                tool_count: 0,
                tool_position: [[0.0; 3]; MAX_TOOLS],
                points: vec![ContactPoint::default(); m],
                point_count: 0,
                grasp: [None; MAX_TOOLS],
            },
        }
    }

    /// The state before this step's prediction (r), kept for the θ-point.
    pub(crate) fn set_previous(&mut self, x: &[f64]) {
        self.joint[self.r..].copy_from_slice(x);
    }

    /// Keeps the results and the warm start for [`ContactWork::restore`] (no allocation).
    pub(crate) fn save(&mut self) {
        let s = &mut self.saved;
        s.was_active.copy_from_slice(&self.was_active);
        s.was_count = self.was_count;
        s.tools = self.tools;
        s.tool_count = self.tool_count;
        s.tool_position = self.tool_position;
        s.points.copy_from_slice(&self.points);
        s.point_count = self.point_count;
        s.grasp = self.grasp;
    }

    /// Back to what [`ContactWork::save`] kept.
    pub(crate) fn restore(&mut self) {
        let s = &self.saved;
        self.was_active.copy_from_slice(&s.was_active);
        self.was_count = s.was_count;
        self.tools = s.tools;
        self.tool_count = s.tool_count;
        self.tool_position = s.tool_position;
        self.points.copy_from_slice(&s.points);
        self.point_count = s.point_count;
        self.grasp = s.grasp;
    }

    /// Back to no contact (an estimator reset).
    pub(crate) fn reset(&mut self) {
        self.stamp
            .iter_mut()
            .for_each(|s| *s = (f64::INFINITY, f64::INFINITY));
        self.was_count = 0;
        self.tool_count = 0;
        self.point_count = 0;
        self.pressed_count = 0;
        self.tools = [ToolContact::default(); MAX_TOOLS];
        self.grasp = [None; MAX_TOOLS];
        self.list_valid = false;
    }

    /// Tool `t` of the last step takes hold of the region node nearest its centre, by the
    /// node's position after that step (state `x`), among those within
    /// (1 + [`CANDIDATE_MARGIN`]) R of it: from the next step on the node is held at the
    /// tool's centre plus its present offset, in all three directions, until
    /// [`ContactWork::release`]. Returns the node, or `None` when no region node is that near
    /// (nothing changes then). The caller checks that tool `t` was in the last step.
    pub(crate) fn grasp(&mut self, pc: &PreparedContact, t: usize, x: &[f64]) -> Option<usize> {
        let c = self.tool_position[t];
        let near = pc.radius * (1.0 + CANDIDATE_MARGIN);
        // How far a node can be from rest: its rows times the state, and the residual of the
        // last step's contact forces.
        let pushed: f64 = self.points[..self.point_count]
            .iter()
            .map(|p| norm(p.force))
            .sum();
        let reach = near + pc.row_norm_max * dot(x, x).sqrt() + pc.residual_end_norm_max * pushed;
        let mut best: Option<(usize, f64, [f64; 3])> = None;
        pc.grid.visit(&c, reach, |i| {
            let p = self.end_position(pc, i, x);
            let d = distance(p, &c);
            if d <= near && best.is_none_or(|(_, bd, _)| d < bd) {
                best = Some((i, d, p));
            }
        });
        let (node, _, p) = best?;
        self.grasp[t] = Some(Grasp {
            node,
            offset: [0, 1, 2].map(|k| p[k] - c[k]),
        });
        Some(node)
    }

    /// Tool `t` lets go of what it holds (nothing when it holds nothing).
    pub(crate) fn release(&mut self, t: usize) {
        if let Some(g) = self.grasp.get_mut(t) {
            *g = None;
        }
    }

    /// The region node tool `t` holds and the held point's offset from the tool's centre.
    pub(crate) fn grasped(&self, t: usize) -> Option<(usize, [f64; 3])> {
        self.grasp
            .get(t)
            .copied()
            .flatten()
            .map(|g| (g.node, g.offset))
    }

    /// Region node i's position after the last step with state `x`: X_i + C_i x plus the
    /// residual of the last step's contact forces.
    fn end_position(&self, pc: &PreparedContact, i: usize, x: &[f64]) -> [f64; 3] {
        let r = self.r;
        let u = crate::simd::rows3(&pc.rows[3 * i * r..3 * (i + 1) * r], r, x);
        let mut p = [0, 1, 2].map(|k| pc.rest[3 * i + k] + u[k]);
        for point in &self.points[..self.point_count] {
            if let Some(d) = pc.residual(i, point.node).map(|d| &d.end) {
                for (a, pa) in p.iter_mut().enumerate() {
                    *pa += (0..3).map(|b| d[3 * a + b] * point.force[b]).sum::<f64>();
                }
            }
        }
        p
    }

    /// Solves the contact of `tools` on the free prediction `x` (r, the whole state, with the
    /// deterministic inputs `inputs` as G took them) from the state before the step
    /// ([`ContactWork::set_previous`], by the caller), and leaves the state increment in
    /// [`ContactWork::delta`] and the results in `tools`, `points`. The gap is enforced at the
    /// step's θ-point (free position p̂ = X + θ³ C x − W x_prev + E u), with the normals taken at the
    /// solved positions (a fixed point over at most [`MAX_NORMAL_PASSES`] solves). Changes
    /// nothing outside the scratch; returns false when the result is not finite (the caller
    /// then refuses the step).
    pub(crate) fn solve(
        &mut self,
        pc: &PreparedContact,
        x: &[f64],
        inputs: &[f64],
        tools: &[[f64; 3]],
        prior: &[f64],
    ) -> bool {
        let r = self.r;
        if inputs.len() != self.last_inputs.len() {
            return false;
        }
        self.joint[..r].copy_from_slice(x);
        let radius = pc.radius;
        let th3 = pc.theta_cubed;
        let joint_norm = dot(&self.joint, &self.joint).sqrt();
        let input_norm = dot(inputs, inputs).sqrt();
        // 1. The region nodes near each tool at the θ-point of the free step, then the
        // contact problem's candidates: the penetrating ones and last step's pressing ones.
        let near = radius * (1.0 + CANDIDATE_MARGIN);
        // The path length of [x⁺; x] and of u over the steps, for the cached positions.
        let step_joint = self
            .joint
            .iter()
            .zip(&self.last_joint)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        let step_inputs = inputs
            .iter()
            .zip(&self.last_inputs)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        self.path = (self.path.0 + step_joint, self.path.1 + step_inputs);
        self.last_joint.copy_from_slice(&self.joint);
        self.last_inputs.copy_from_slice(inputs);
        let path = self.path;
        // A tool absent from this step lets go; one that holds a point does not push: its
        // neighbourhood is not searched.
        for g in self.grasp.iter_mut().skip(tools.len()) {
            *g = None;
        }
        let grasp = self.grasp;
        // The nodes that may be near a tool: the list of those within the skin, rebuilt by a
        // search of the grid once the tools or the body may have moved by the skin since.
        let since = pc.theta_norm_max * (path.0 - self.list_path.0)
            + pc.input_norm_max * (path.1 - self.list_path.1)
            + tools
                .iter()
                .zip(&self.list_tools)
                .map(|(c, c0)| distance(*c, c0))
                .fold(0.0, f64::max);
        let pushing: [bool; MAX_TOOLS] =
            std::array::from_fn(|t| t < tools.len() && grasp[t].is_none());
        if !self.list_valid
            || tools.len() != self.list_tool_count
            || pushing != self.list_pushing
            || !since.is_finite()
            || since >= pc.radius * LIST_SKIN
        {
            self.rebuild_list(pc, tools, pushing, joint_norm, input_norm);
        }
        let joint = &self.joint;
        let mut seen = 0usize;
        for &(t, i) in &self.list[..self.list_count] {
            let (t, i) = (t as usize, i as usize);
            let c = &tools[t];
            // Its last evaluated position, with how far it can have moved since
            // (‖[θ³C_i | −W_i]‖ times the path of [x⁺; x], ‖E_i‖ times that of u).
            let (sj, su) = self.stamp[i];
            let moved = pc.theta_norm[i] * (path.0 - sj) + pc.input_norm[i] * (path.1 - su);
            let slack = 1e-12 * (1.0 + path.0 + path.1);
            let clear = near + moved + slack;
            if sj.is_finite() && distance_squared(self.cache[i], c) > clear * clear {
                continue;
            }
            let p = pc.theta_point(i, joint, inputs);
            self.cache[i] = p;
            self.stamp[i] = path;
            let g = distance(p, c) - radius;
            self.visited[seen] = (t, i, p, g);
            seen += 1;
        }
        let mut m = 0usize;
        // A grasp first: three bilateral constraints on its node along the axes, the gap the
        // node's offset from where the tool holds it.
        for (t, c) in tools.iter().enumerate() {
            let Some(g) = grasp[t] else { continue };
            let p = pc.theta_point(g.node, &self.joint, inputs);
            for axis in 0..3 {
                let mut n = [0.0; 3];
                n[axis] = 1.0;
                self.cand[m] = (t, g.node);
                self.gap[m] = p[axis] - c[axis] - g.offset[axis];
                self.normal[m] = n;
                self.next_normal[m] = n;
                self.position[m] = p;
                self.bilateral[m] = true;
                m += 1;
            }
        }
        let grasped = |i: usize| grasp.iter().flatten().any(|g| g.node == i);
        let mut overflow = [false; MAX_TOOLS];
        let mut depth = [0.0f64; MAX_TOOLS];
        for v in 0..seen {
            let (t, i, p, g) = self.visited[v];
            if grasped(i) {
                continue;
            }
            depth[t] = depth[t].max(-g);
            let was = self.was_active[..self.was_count]
                .iter()
                .find(|&&(wi, wt, _)| wi == i && wt == t)
                .map(|w| w.2);
            if g < 0.0 || was.is_some() {
                // The normal from last step's solve (the fixed point goes on over the steps).
                let n = was.unwrap_or_else(|| toward(p, &tools[t], &pc.normals[3 * i..3 * i + 3]));
                self.add_candidate(&mut m, (t, i), p, g, n, &mut overflow);
            }
        }
        for k in 0..m {
            self.active[k] = true;
        }
        let mut converged = false;
        for pass in 0..MAX_NORMAL_PASSES {
            // 2. Gaps along the current normals, h_a = C_aᵀ n_a, b_a = B_a n_a and
            // A_ac = n_aᵀ (θ³ C_a B_cᵀ + D_ac) n_c.
            for k in 0..m {
                let (t, i) = self.cand[k];
                let n = self.normal[k];
                let c = tools[t];
                let p = self.position[k];
                self.gap[k] = match (self.bilateral[k], grasp[t]) {
                    (true, Some(g)) => (0..3).map(|q| (p[q] - c[q] - g.offset[q]) * n[q]).sum(),
                    _ => (0..3).map(|q| (p[q] - c[q]) * n[q]).sum::<f64>() - radius,
                };
                let rows = &pc.rows[3 * i * r..3 * (i + 1) * r];
                let inputs = &pc.input_rows[3 * i * r..3 * (i + 1) * r];
                let h = &mut self.h[k * r..(k + 1) * r];
                let b = &mut self.b[k * r..(k + 1) * r];
                for j in 0..r {
                    h[j] = n[0] * rows[j] + n[1] * rows[r + j] + n[2] * rows[2 * r + j];
                    b[j] = n[0] * inputs[j] + n[1] * inputs[r + j] + n[2] * inputs[2 * r + j];
                }
            }
            for a in 0..m {
                for c in 0..m {
                    let mut v = th3 * dot(&self.h[a * r..(a + 1) * r], &self.b[c * r..(c + 1) * r]);
                    let pair = pc.residual_index(self.cand[a].1, self.cand[c].1);
                    self.pair[a * m + c] = pair.map_or(u32::MAX, |k| k as u32);
                    if let Some(d) = pair.map(|k| &pc.neighbours[k].1.theta) {
                        let (na, nc) = (self.normal[a], self.normal[c]);
                        for p in 0..3 {
                            for q in 0..3 {
                                v += na[p] * d[3 * p + q] * nc[q];
                            }
                        }
                    }
                    self.a[a * m + c] = v;
                }
            }
            // 3. The LCP by principal pivoting, warm-started.
            let Some(pivoted) = self.principal_pivoting(m, radius) else {
                return false;
            };
            // 4. Normals at the solved θ-point positions; done when they stay.
            self.accumulate_delta(m);
            let mut moved = 0.0f64;
            for k in 0..m {
                if self.bilateral[k] {
                    self.next_normal[k] = self.normal[k];
                    continue;
                }
                let (t, i) = self.cand[k];
                let q = self.candidate_position(pc, k, m);
                let n = toward(q, &tools[t], &pc.normals[3 * i..3 * i + 3]);
                moved = moved.max(
                    (0..3)
                        .map(|c| (n[c] - self.normal[k][c]).abs())
                        .fold(0.0, f64::max),
                );
                self.next_normal[k] = n;
            }
            // Nodes left out that the solved forces push into a tool join the problem: only
            // those whose free gap is below the largest displacement the forces can cause.
            // Checked once the normals have settled (or on the last pass).
            let last_pass = pass + 1 == MAX_NORMAL_PASSES;
            let mut added = false;
            if moved >= NORMAL_TOLERANCE && !last_pass {
                self.normal[..m].copy_from_slice(&self.next_normal[..m]);
                for k in 0..m {
                    self.active[k] = self.bilateral[k] || self.lambda[k] > 0.0;
                }
                continue;
            }
            let lsum: f64 = self.lambda[..m].iter().map(|l| l.abs()).sum();
            let delta_norm = th3 * dot(&self.delta, &self.delta).sqrt();
            let residual_push = pc.residual_norm_max * lsum;
            for v in 0..seen {
                let (t, i, p, g) = self.visited[v];
                if grasped(i)
                    || g >= delta_norm * pc.row_norm[i] + residual_push
                    || self.cand[..m].iter().any(|&(_, ci)| ci == i)
                {
                    continue;
                }
                let q = self.solved_position(pc, i, p, m);
                let c = tools[t];
                if distance(q, &c) < radius * (1.0 - 1e-12) {
                    let n = toward(q, &c, &pc.normals[3 * i..3 * i + 3]);
                    if let Some(k) = self.add_candidate(&mut m, (t, i), p, g, n, &mut overflow) {
                        self.next_normal[k] = n;
                        self.lambda[k] = 0.0;
                        added = true;
                    }
                }
            }
            self.candidates = m;
            if !added || last_pass {
                converged = pivoted && !added;
                break;
            }
            self.normal[..m].copy_from_slice(&self.next_normal[..m]);
            for k in 0..m {
                self.active[k] = self.bilateral[k] || self.lambda[k] > 0.0;
            }
        }
        // 5. Tool forces, the bound, the stiffness.
        let ntools = tools.len();
        let mut clamped = [false; MAX_TOOLS];
        for t in 0..ntools {
            let mut f = [0.0; 3];
            for k in (0..m).filter(|&k| self.cand[k].0 == t) {
                for c in 0..3 {
                    f[c] -= self.lambda[k] * self.normal[k][c];
                }
            }
            let mag = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            if mag > pc.max_force {
                let s = pc.max_force / mag;
                for k in (0..m).filter(|&k| self.cand[k].0 == t) {
                    self.lambda[k] *= s;
                }
                clamped[t] = true;
            }
        }
        let pressed = self.accumulate_delta(m);
        if self.delta.iter().any(|v| !v.is_finite()) {
            return false;
        }
        self.pressed_count = pressed;
        self.stiffness_and_points(pc, x, tools, &clamped, &overflow, &depth, converged);
        if self.with_std {
            for t in 0..tools.len() {
                let std = self.force_std(t, prior);
                if std.iter().any(|v| !v.is_finite()) {
                    return false;
                }
                self.tools[t].force_std = std;
            }
        }
        // The warm start of the next step.
        self.was_count = 0;
        for &k in self.pressed[..pressed]
            .iter()
            .filter(|&&k| !self.bilateral[k])
        {
            self.was_active[self.was_count] = (self.cand[k].1, self.cand[k].0, self.next_normal[k]);
            self.was_count += 1;
        }
        true
    }

    /// The list of (tool, node) that may come within `near` of a pushing tool before the tools
    /// or the body move by the skin: every node whose distance from the tool's centre, less
    /// how far it can be from where it was last evaluated (or from rest), is within near + skin.
    /// A node left out is more than near + skin away; it can come nearer only by the tool's
    /// movement and its own since (bounded by the largest row norms times the paths).
    fn rebuild_list(
        &mut self,
        pc: &PreparedContact,
        tools: &[[f64; 3]],
        pushing: [bool; MAX_TOOLS],
        joint_norm: f64,
        input_norm: f64,
    ) {
        let near = pc.radius * (1.0 + CANDIDATE_MARGIN);
        let skin = pc.radius * LIST_SKIN;
        let path = self.path;
        let bound = pc.theta_norm_max * joint_norm + pc.input_norm_max * input_norm;
        let within = near + skin;
        let mut count = 0;
        for (t, c) in tools.iter().enumerate() {
            if !pushing[t] {
                continue;
            }
            let (list, cache, stamp) = (&mut self.list, &self.cache, &self.stamp);
            pc.grid.visit(c, within + bound, |i| {
                let from_rest = pc.theta_norm[i] * joint_norm + pc.input_norm[i] * input_norm;
                let rest = [0, 1, 2].map(|k| pc.rest[3 * i + k]);
                let mut lower = distance(rest, c) - from_rest;
                let (sj, su) = stamp[i];
                if sj.is_finite() {
                    let moved = pc.theta_norm[i] * (path.0 - sj) + pc.input_norm[i] * (path.1 - su);
                    let slack = 1e-12 * (1.0 + path.0 + path.1);
                    lower = lower.max(distance(cache[i], c) - moved - slack);
                }
                if lower <= within {
                    list[count] = (t as u32, i as u32);
                    count += 1;
                }
            });
        }
        self.list_count = count;
        self.list_path = path;
        self.list_tool_count = tools.len();
        self.list_pushing = pushing;
        for (t, c) in tools.iter().enumerate() {
            self.list_tools[t] = *c;
        }
        self.list_valid = true;
    }

    /// Node i's θ-point position under the solved forces: its free position `free` plus
    /// θ³ C_i δ and the residual of the m candidates' forces.
    fn solved_position(
        &self,
        pc: &PreparedContact,
        i: usize,
        free: [f64; 3],
        m: usize,
    ) -> [f64; 3] {
        let r = self.r;
        let th3 = pc.theta_cubed;
        let u = crate::simd::rows3(&pc.rows[3 * i * r..3 * (i + 1) * r], r, &self.delta);
        let mut q = [0, 1, 2].map(|c| free[c] + th3 * u[c]);
        for k in 0..m {
            let l = self.lambda[k];
            if l != 0.0 {
                if let Some(d) = pc.residual(i, self.cand[k].1).map(|d| &d.theta) {
                    let n = self.normal[k];
                    for (c, qc) in q.iter_mut().enumerate() {
                        *qc += l * (0..3).map(|s| d[3 * c + s] * n[s]).sum::<f64>();
                    }
                }
            }
        }
        q
    }

    /// [`ContactWork::solved_position`] of candidate `a` of the m of this pass, its residual
    /// blocks from the pass's pair table.
    fn candidate_position(&self, pc: &PreparedContact, a: usize, m: usize) -> [f64; 3] {
        let r = self.r;
        let i = self.cand[a].1;
        let free = self.position[a];
        let th3 = pc.theta_cubed;
        let u = crate::simd::rows3(&pc.rows[3 * i * r..3 * (i + 1) * r], r, &self.delta);
        let mut q = [0, 1, 2].map(|c| free[c] + th3 * u[c]);
        for k in 0..m {
            let l = self.lambda[k];
            let pair = self.pair[a * m + k];
            if l != 0.0 && pair != u32::MAX {
                let d = &pc.neighbours[pair as usize].1.theta;
                let n = self.normal[k];
                for (c, qc) in q.iter_mut().enumerate() {
                    *qc += l * (0..3).map(|s| d[3 * c + s] * n[s]).sum::<f64>();
                }
            }
        }
        q
    }

    /// Adds node `node` = (tool, region node) to the contact problem with its free position,
    /// free gap and normal: a node already taken by the other tool keeps the deeper of the
    /// two; when the problem is full the shallowest candidate gives way to a deeper one (and
    /// the tool's status says so). Returns the slot it took.
    fn add_candidate(
        &mut self,
        m: &mut usize,
        node: (usize, usize),
        p: [f64; 3],
        g: f64,
        n: [f64; 3],
        overflow: &mut [bool; MAX_TOOLS],
    ) -> Option<usize> {
        let pushes = |k: &usize| !self.bilateral[*k];
        let slot = if let Some(k) = (0..*m).filter(pushes).find(|&k| self.cand[k].1 == node.1) {
            if g >= self.gap[k] {
                return None;
            }
            k
        } else if *m == MAX_CONTACTS {
            overflow[node.0] = true;
            // The shallowest push gives way (a grasp's constraints stay).
            let k = (0..*m)
                .filter(pushes)
                .max_by(|&a, &b| self.gap[a].total_cmp(&self.gap[b]))?;
            if g >= self.gap[k] {
                return None;
            }
            k
        } else {
            *m += 1;
            *m - 1
        };
        self.cand[slot] = node;
        self.gap[slot] = g;
        self.normal[slot] = n;
        self.position[slot] = p;
        self.active[slot] = true;
        self.bilateral[slot] = false;
        Some(slot)
    }

    /// The state increment δ = Σ λ_a b_a of the pressing candidates (listed in `pressed`);
    /// returns how many press.
    fn accumulate_delta(&mut self, m: usize) -> usize {
        let r = self.r;
        self.delta.iter_mut().for_each(|v| *v = 0.0);
        let mut pressed = 0;
        for k in 0..m {
            let l = self.lambda[k];
            if l != 0.0 || self.bilateral[k] {
                let b = &self.b[k * r..(k + 1) * r];
                for (d, &bv) in self.delta.iter_mut().zip(b) {
                    *d += l * bv;
                }
                self.pressed[pressed] = k;
                pressed += 1;
            }
        }
        pressed
    }

    /// The LCP gap = g + A λ ≥ 0, λ ≥ 0, λ·gap = 0 over the m candidates by principal pivoting
    /// from the active set in `active`: λ in `lambda` (0 off the active set). `None` when a
    /// solve fails; `Some(false)` when the pivot cap is reached.
    fn principal_pivoting(&mut self, m: usize, radius: f64) -> Option<bool> {
        let mut converged = false;
        for _ in 0..MAX_PIVOTS {
            if !self.solve_active(m) {
                return None;
            }
            // A negative force leaves the active set (the most negative first).
            let worst = (0..m)
                .filter(|&k| self.active[k] && !self.bilateral[k] && self.lambda[k] < 0.0)
                .min_by(|&a, &b| self.lambda[a].total_cmp(&self.lambda[b]));
            if let Some(k) = worst {
                self.active[k] = false;
                continue;
            }
            // A penetrating inactive node joins (the deepest first).
            let tol = 1e-12 * radius.max(1e-9);
            let mut deepest: Option<(usize, f64)> = None;
            for k in 0..m {
                if self.active[k] {
                    continue;
                }
                let w = self.gap[k]
                    + (0..m)
                        .filter(|&c| self.active[c])
                        .map(|c| self.a[k * m + c] * self.lambda[c])
                        .sum::<f64>();
                if w < -tol && deepest.is_none_or(|(_, d)| w < d) {
                    deepest = Some((k, w));
                }
            }
            match deepest {
                Some((k, _)) => self.active[k] = true,
                None => {
                    converged = true;
                    break;
                }
            }
        }
        for k in 0..m {
            if !self.bilateral[k] && (!self.active[k] || self.lambda[k] < 0.0) {
                self.lambda[k] = 0.0;
            }
        }
        Some(converged)
    }

    /// σ of tool `t`'s force (N, per world component) from the prediction's covariance `p`
    /// (r×r row-major, P⁻ of the step): Cov(F) = N A⁻¹ (Hₙ P Hₙᵀ) A⁻ᵀ Nᵀ over the tool's
    /// pressed contacts (hₐ = C_aᵀ n_a the rows Hₙ). Zero when the tool touches nothing.
    fn force_std(&mut self, t: usize, p: &[f64]) -> [f64; 3] {
        let r = self.r;
        let total = self.candidates;
        let mut s = 0;
        for q in 0..self.pressed_count {
            let k = self.pressed[q];
            if self.cand[k].0 == t {
                self.piv[s] = k;
                s += 1;
            }
        }
        if s == 0 {
            return [0.0; 3];
        }
        // M = A_SS⁻ᵀ Nᵀ (s×3): then Cov(F) = Mᵀ (Hₙ P Hₙᵀ) M.
        let mut m3 = [[0.0f64; 3]; MAX_CONTACTS];
        for col in 0..3 {
            for i in 0..s {
                for j in 0..s {
                    // Transposed: A_SSᵀ.
                    self.lu[i * s + j] = self.a[self.piv[j] * total + self.piv[i]];
                }
                self.rhs[i] = self.normal[self.piv[i]][col];
            }
            if !gauss(&mut self.lu[..s * s], &mut self.rhs[..s], s) {
                return [f64::NAN; 3];
            }
            for i in 0..s {
                m3[i][col] = self.rhs[i];
            }
        }
        // V = Hₙ P (s×r) into scratch, then S = V Hₙᵀ (s×s) into lu.
        for i in 0..s {
            let h = &self.h[self.piv[i] * r..(self.piv[i] + 1) * r];
            for j in 0..r {
                let col_sum: f64 = (0..r).map(|k| h[k] * p[k * r + j]).sum();
                self.scratch[i * r + j] = col_sum;
            }
        }
        for i in 0..s {
            for j in 0..s {
                let hj = &self.h[self.piv[j] * r..(self.piv[j] + 1) * r];
                self.lu[i * s + j] = dot(&self.scratch[i * r..(i + 1) * r], hj);
            }
        }
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            let mut v = 0.0;
            for i in 0..s {
                for j in 0..s {
                    v += m3[i][c] * self.lu[i * s + j] * m3[j][c];
                }
            }
            *o = v.max(0.0).sqrt();
        }
        out
    }

    /// λ over the active set: A_SS λ_S = −g_S (Gaussian elimination with partial pivoting);
    /// false when the system is singular or not finite.
    fn solve_active(&mut self, m: usize) -> bool {
        let mut s = 0;
        for k in 0..m {
            if self.active[k] {
                self.piv[s] = k;
                s += 1;
            }
        }
        for k in 0..m {
            self.lambda[k] = 0.0;
        }
        if s == 0 {
            return true;
        }
        for i in 0..s {
            for j in 0..s {
                self.lu[i * s + j] = self.a[self.piv[i] * m + self.piv[j]];
            }
            self.rhs[i] = -self.gap[self.piv[i]];
        }
        if !gauss(&mut self.lu[..s * s], &mut self.rhs[..s], s) {
            return false;
        }
        for i in 0..s {
            self.lambda[self.piv[i]] = self.rhs[i];
        }
        true
    }

    #[allow(clippy::too_many_arguments)]
    fn stiffness_and_points(
        &mut self,
        pc: &PreparedContact,
        x: &[f64],
        tools: &[[f64; 3]],
        clamped: &[bool; MAX_TOOLS],
        overflow: &[bool; MAX_TOOLS],
        depth: &[f64; MAX_TOOLS],
        converged: bool,
    ) {
        let r = self.r;
        let m_all = self.pressed_count;
        self.tool_count = tools.len();
        self.point_count = 0;
        for (t, c) in tools.iter().enumerate() {
            self.tool_position[t] = *c;
            let mut tc = ToolContact {
                depth: depth[t],
                ..ToolContact::default()
            };
            // The pressed contacts of this tool: their A block, inverted column by column
            // against the normals (K = N A⁻¹ Nᵀ).
            let mut s = 0;
            for q in 0..m_all {
                let k = self.pressed[q];
                if self.cand[k].0 == t {
                    self.piv[s] = k;
                    s += 1;
                }
            }
            for i in 0..s {
                let k = self.piv[i];
                let l = self.lambda[k];
                let n = self.normal[k];
                let f_body = [l * n[0], l * n[1], l * n[2]];
                // Position after the step: free position + the contact's displacement there.
                let i_node = self.cand[k].1;
                let rows = &pc.rows[3 * i_node * r..3 * (i_node + 1) * r];
                let mut p = [0.0; 3];
                for (comp, pv) in p.iter_mut().enumerate() {
                    let row = &rows[comp * r..(comp + 1) * r];
                    *pv = pc.rest[3 * i_node + comp] + dot(row, x) + dot(row, &self.delta);
                }
                for q in 0..s {
                    let kq = self.piv[q];
                    if let Some(d) = pc.residual(i_node, self.cand[kq].1).map(|d| &d.end) {
                        let lq = self.lambda[kq];
                        let nq = self.normal[kq];
                        for a in 0..3 {
                            p[a] += (0..3).map(|b| d[3 * a + b] * lq * nq[b]).sum::<f64>();
                        }
                    }
                }
                for comp in 0..3 {
                    tc.force[comp] -= f_body[comp];
                }
                let arm = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                let ft = [-f_body[0], -f_body[1], -f_body[2]];
                tc.torque[0] += arm[1] * ft[2] - arm[2] * ft[1];
                tc.torque[1] += arm[2] * ft[0] - arm[0] * ft[2];
                tc.torque[2] += arm[0] * ft[1] - arm[1] * ft[0];
                // A grasp's three constraints act on one node: one point.
                let last = self.point_count.checked_sub(1).map(|q| self.points[q]);
                match last {
                    Some(lp) if lp.tool == t && lp.node == i_node => {
                        let q = self.point_count - 1;
                        for comp in 0..3 {
                            self.points[q].force[comp] += f_body[comp];
                        }
                    }
                    _ if self.point_count < self.points.len() => {
                        self.points[self.point_count] = ContactPoint {
                            tool: t,
                            node: i_node,
                            position: p,
                            force: f_body,
                        };
                        self.point_count += 1;
                        tc.active += 1;
                    }
                    _ => {}
                }
            }
            if s > 0 {
                // A_SS of the pressed set, then K = N A⁻¹ Nᵀ by three solves.
                let total = self.candidates;
                let lu = &mut self.scratch[..s * s];
                for i in 0..s {
                    for j in 0..s {
                        lu[i * s + j] = self.a[self.piv[i] * total + self.piv[j]];
                    }
                }
                let mut k3 = [0.0; 9];
                for col in 0..3 {
                    for i in 0..s {
                        self.rhs[i] = self.normal[self.piv[i]][col];
                    }
                    let lu = &mut self.lu[..s * s];
                    lu.copy_from_slice(&self.scratch[..s * s]);
                    if !gauss(lu, &mut self.rhs[..s], s) {
                        break;
                    }
                    for row in 0..3 {
                        k3[3 * row + col] = (0..s)
                            .map(|i| self.normal[self.piv[i]][row] * self.rhs[i])
                            .sum();
                    }
                }
                tc.stiffness = k3;
            }
            tc.status = if clamped[t] {
                ContactStatus::Clamped
            } else if overflow[t] {
                ContactStatus::Overflow
            } else if !converged {
                ContactStatus::NotConverged
            } else if self.grasp[t].is_some() {
                ContactStatus::Grasping
            } else if s > 0 {
                ContactStatus::Touching
            } else {
                ContactStatus::Free
            };
            self.tools[t] = tc;
        }
    }
}

/// The Frobenius norm of each of the n blocks of 3 consecutive rows of `m` (row-major, 3n
/// rows).
fn block_norms(m: &[f64], n: usize) -> Vec<f64> {
    let width = m.len() / (3 * n).max(1);
    (0..n)
        .map(|i| {
            m[3 * i * width..3 * (i + 1) * width]
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt()
        })
        .collect()
}

/// |v|.
#[inline]
fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// |p − c|².
#[inline]
fn distance_squared(p: [f64; 3], c: &[f64; 3]) -> f64 {
    (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)
}

/// |p − c|.
#[inline]
fn distance(p: [f64; 3], c: &[f64; 3]) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
}

/// The unit vector from the tool's centre c to p, or the rest normal when p is at c.
#[inline]
fn toward(p: [f64; 3], c: &[f64; 3], rest_normal: &[f64]) -> [f64; 3] {
    let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
    unit(d, distance(p, c), rest_normal)
}

/// The unit vector d/|d|, or the rest normal when the node sits at the tool's centre.
#[inline]
fn unit(d: [f64; 3], dist: f64, rest_normal: &[f64]) -> [f64; 3] {
    if dist > 1e-300 {
        [d[0] / dist, d[1] / dist, d[2] / dist]
    } else {
        [rest_normal[0], rest_normal[1], rest_normal[2]]
    }
}

/// Solves a (s×s, row-major, overwritten) x = b in place in b by Gaussian elimination with
/// partial pivoting; false when singular or not finite.
fn gauss(a: &mut [f64], b: &mut [f64], s: usize) -> bool {
    for col in 0..s {
        let mut p = col;
        for row in col + 1..s {
            if a[row * s + col].abs() > a[p * s + col].abs() {
                p = row;
            }
        }
        let pivot = a[p * s + col];
        if pivot == 0.0 || !pivot.is_finite() {
            return false;
        }
        if p != col {
            for j in 0..s {
                a.swap(col * s + j, p * s + j);
            }
            b.swap(col, p);
        }
        for row in col + 1..s {
            let f = a[row * s + col] / pivot;
            if f != 0.0 {
                for j in col..s {
                    a[row * s + j] -= f * a[col * s + j];
                }
                b[row] -= f * b[col];
            }
        }
    }
    for col in (0..s).rev() {
        let mut v = b[col];
        for j in col + 1..s {
            v -= a[col * s + j] * b[j];
        }
        b[col] = v / a[col * s + col];
        if !b[col].is_finite() {
            return false;
        }
    }
    true
}
