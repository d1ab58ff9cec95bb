//! The outputs the balanced truncation keeps (docs/design.md §4–§5): displacement and rotation
//! rows at the sensors, rotation rows at the load groups, displacement and rotation rows at the
//! displayed nodes, in one fixed layout with their balancing weights.

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;

use crate::corotation::RotationRows;
use crate::fem::operators::{displacement_rows, Operators, SparseRow};
use crate::fem::FemModel;

/// Output rows of the full-order model, grouped as the model file stores them.
pub struct OutputRows {
    /// Per sensor: displacement rows (3) and rotation rows (3).
    pub sensors: Vec<([SparseRow; 3], [SparseRow; 3])>,
    /// Per load group: rotation rows (3).
    pub loads: Vec<[SparseRow; 3]>,
    /// Per node set: per node displacement rows (3) and rotation rows (3).
    pub node_sets: Vec<Vec<([SparseRow; 3], [SparseRow; 3])>>,
    /// Characteristic length (bounding-box diagonal), m: rotation rows are weighted by it in the
    /// balanced truncation so that radians and metres compare.
    pub length_scale: f64,
}

impl OutputRows {
    /// Builds every output row the scene asks for.
    pub fn build(fem: &FemModel, ops: &Operators) -> Self {
        let rot = RotationRows::new(fem);
        let sensors = ops
            .sensors
            .iter()
            .map(|s| {
                (
                    Operators::sensor_rows(fem, s),
                    rot.at_weights(fem, &s.weights),
                )
            })
            .collect();
        let loads = ops
            .loads
            .iter()
            .map(|l| rot.at_weights(fem, &l.weights))
            .collect();
        let node_sets = ops
            .node_sets
            .iter()
            .map(|set| {
                set.nodes
                    .iter()
                    .map(|&n| (displacement_rows(fem, n), rot.at_node(fem, n)))
                    .collect()
            })
            .collect();
        // Over the nodes of the tetrahedra (orphan nodes do not count).
        let length_scale = crate::mesh::bounding_diagonal(
            fem.elements
                .iter()
                .flat_map(|e| e.nodes.iter().map(|&n| &fem.positions[n])),
        );
        OutputRows {
            sensors,
            loads,
            node_sets,
            length_scale,
        }
    }

    /// Row of sensor `s`'s displacement x component in [`OutputRows::weighted`] order; y, z
    /// follow, then its ω rows (x, y, z).
    pub fn sensor_row(&self, s: usize) -> usize {
        6 * s
    }

    /// Row of load group `g`'s ω x component; y, z follow.
    pub fn load_row(&self, g: usize) -> usize {
        6 * self.sensors.len() + 3 * g
    }

    /// Row of node `i` of node set `set`: displacement x, y, z, then ω x, y, z.
    pub fn node_row(&self, set: usize, i: usize) -> usize {
        let before: usize = self.node_sets[..set].iter().map(Vec::len).sum();
        self.load_row(self.loads.len()) + 6 * (before + i)
    }

    /// All rows with their balancing weights, in the order sensors (u, ω), loads (ω), node sets
    /// (u, ω per node). Node-set rows are scaled by 1/√nodes so that a set of many nodes weighs
    /// like one aggregated point; rotation rows by the length scale.
    pub fn weighted(&self) -> Vec<(&SparseRow, f64)> {
        let l = self.length_scale;
        let mut out = Vec::new();
        for (u, w) in &self.sensors {
            out.extend(u.iter().map(|r| (r, 1.0)));
            out.extend(w.iter().map(|r| (r, l)));
        }
        for w in &self.loads {
            out.extend(w.iter().map(|r| (r, l)));
        }
        for set in &self.node_sets {
            let s = 1.0 / (set.len() as f64).sqrt();
            for (u, w) in set {
                out.extend(u.iter().map(|r| (r, s)));
                out.extend(w.iter().map(|r| (r, s * l)));
            }
        }
        out
    }
}

/// Stacks sparse rows (with weights) into a p×n sparse matrix.
pub fn stack_rows(rows: &[(&SparseRow, f64)], n: usize) -> SparseColMat<usize, f64> {
    let triplets: Vec<Triplet<usize, usize, f64>> = rows
        .iter()
        .enumerate()
        .flat_map(|(i, (row, w))| row.iter().map(move |&(j, v)| Triplet::new(i, j, w * v)))
        .collect();
    SparseColMat::try_new_from_triplets(rows.len(), n, &triplets)
        .expect("row indices are in range by construction")
}

/// Dense n×k matrix whose columns are the given vectors.
pub fn columns(cols: &[&[f64]], n: usize) -> Mat<f64> {
    Mat::from_fn(n, cols.len(), |i, j| cols[j][i])
}

/// The measurement vector y: one channel per measured (sensor, component), in scene order,
/// with its noise variance σ² (m²) and its rate (a measurement at steps k ≡ 0 mod `every`).
/// Built once; the Kalman stage, the model file and the measured error all read it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Measurements {
    /// (sensor index into [`Operators::sensors`], component 0..3) per channel.
    pub channels: Vec<(usize, usize)>,
    /// σ² per channel, m².
    pub variance: Vec<f64>,
    /// Rate divisor per channel (≥ 1).
    pub every: Vec<u32>,
}

impl Measurements {
    /// The channels of the scene's sensors: each sensor's distinct components in x, y, z order.
    pub fn new(ops: &Operators) -> Self {
        let mut out = Measurements::default();
        for (si, s) in ops.sensors.iter().enumerate() {
            let mut comps: Vec<usize> = s.components.iter().map(|c| c.index()).collect();
            comps.sort_unstable();
            comps.dedup();
            for c in comps {
                out.channels.push((si, c));
                out.variance.push(s.noise_std[c] * s.noise_std[c]);
                out.every.push(s.every);
            }
        }
        out
    }

    /// Number of channels q.
    pub fn len(&self) -> usize {
        self.channels.len()
    }

    /// Whether there are no measurements.
    pub fn is_empty(&self) -> bool {
        self.channels.is_empty()
    }

    /// H (q×r): the measured rows of a reduced output matrix laid out as
    /// [`OutputRows::weighted`].
    pub fn rows_of(&self, rows: &OutputRows, outputs: faer::MatRef<'_, f64>) -> Mat<f64> {
        Mat::from_fn(self.len(), outputs.ncols(), |i, j| {
            let (s, c) = self.channels[i];
            outputs[(rows.sensor_row(s) + c, j)]
        })
    }
}
