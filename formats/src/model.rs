//! The model: everything the runtime needs, computed offline by `crokf-compile`.
//!
//! Notation (docs/design.md): r = reduced state dimension, m = number of deterministic input
//! channels, q = number of measurement channels. All matrices are row-major [`Matrix`].
//! Lengths in metres, forces in newtons, time in seconds, angles in radians.

use crate::Matrix;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A compiled reduced-order Kalman filter model (one scene).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// Time step Δt, s.
    pub dt: f64,
    /// Wilson θ used to build the recursion.
    pub theta: f64,
    /// Reduced state dimension r.
    pub state_dim: u32,
    /// F, r×r: x⁺ = F x + G u (balanced, reduced Wilson-θ recursion).
    pub transition: Matrix,
    /// G, r×m: deterministic input matrix; column j belongs to `inputs[j]`.
    pub input: Matrix,
    /// The m deterministic input channels, in the column order of G.
    pub inputs: Vec<InputChannel>,
    /// Load groups referenced by [`InputKind::Load`].
    pub loads: Vec<LoadGroup>,
    /// Point sensors.
    pub sensors: Vec<SensorInfo>,
    /// The q measurement channels, in the order of the measurement vector y.
    pub measurements: Vec<MeasurementChannel>,
    /// Steady-state (periodic) Kalman gains and covariances.
    pub kalman: KalmanGains,
    /// Displayed node sets.
    pub node_sets: Vec<NodeSet>,
    /// What the compiler measured and decided.
    pub report: CompileReport,
    /// Hashes of the compiler's inputs.
    pub inputs_digest: InputsDigest,
    /// The co-rotational tier (format v3; `None` for the warped linear tier).
    pub tier: Option<crate::CorotationalTier>,
    /// The contact region a tool may touch (format v8; `None` without `[[contact]]`, and then
    /// not written: such a file is a version 7 file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact: Option<crate::ContactRegion>,
}

/// One deterministic input channel (one column of G).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputChannel {
    /// Label, e.g. `"push.x"` or `"gravity"` (column name in `inputs.csv`).
    pub label: String,
    /// What the channel drives.
    pub kind: InputKind,
}

/// What an input channel drives.
///
/// On disk (rmp-serde's external tagging): `{"Load": {"load": u32, "component": u8}}` or
/// `{"Gravity": {"acceleration": [gx, gy, gz]}}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum InputKind {
    /// World-frame force component `component` (0 = x, 1 = y, 2 = z), N, total over load group
    /// `loads[load]`. At run time the group's world force vector is rotated into the local
    /// frame, f_lin = Rᵀ(ω_g) f_world (docs/design.md §5).
    Load {
        /// Index into [`Model::loads`].
        load: u32,
        /// 0, 1 or 2.
        component: u8,
    },
    /// Gravity: a dimensionless scale factor on the scene's gravity load (1 = the scene's
    /// `acceleration`); not rotated at run time.
    Gravity {
        /// The scene's gravity acceleration, m/s² (informative; already inside G).
        acceleration: [f64; 3],
    },
}

/// A load group: where a world-frame force is applied.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadGroup {
    /// Name (the scene's load name).
    pub name: String,
    /// W_g, 3×r: infinitesimal rotation at the group, ω_g = W_g x, rad (docs/design.md §5).
    pub rotation_rows: Matrix,
}

/// A point sensor measuring world-frame displacement components.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorInfo {
    /// Name (measurement labels are `name.x`, `name.y`, `name.z`).
    pub name: String,
    /// Rest position, m.
    pub position: [f64; 3],
    /// C_s, 3×r: local-frame (linear) displacement at the sensor, u_lin = C_s x, m.
    pub displacement_rows: Matrix,
    /// W_s, 3×r: infinitesimal rotation at the sensor, ω = W_s x, rad.
    pub rotation_rows: Matrix,
    /// Measured components, distinct, each 0 (x), 1 (y) or 2 (z).
    pub components: Vec<u8>,
    /// A measurement arrives at the steps k with k mod `every` = 0 (k = 1, 2, …).
    pub every: u32,
}

/// One entry of the measurement vector y.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasurementChannel {
    /// Index into [`Model::sensors`].
    pub sensor: u32,
    /// 0, 1 or 2; must be one of the sensor's `components`.
    pub component: u8,
}

/// Periodic steady-state Kalman filter.
///
/// Step k = 1, 2, … (the k-th prediction) uses `phases[k mod period]`: x⁻_k = F x_{k−1} + G u,
/// x_k = x⁻_k + K_p (y_p − H_p x⁻_k), where y_p, H_p are the measurement entries / rows of H
/// listed in `phases[p].measured`. With single-rate sensors `period` = 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KalmanGains {
    /// Period of the schedule (≥ 1), steps.
    pub period: u32,
    /// `period` phases.
    pub phases: Vec<KalmanPhase>,
    /// Q_r, r×r: reduced process-noise covariance (per step).
    pub process_noise: Matrix,
    /// Diagonal of R, one per measurement channel, m².
    pub measurement_variance: Vec<f64>,
}

/// One phase of the periodic Kalman filter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KalmanPhase {
    /// Indices into [`Model::measurements`] active in this phase, strictly increasing
    /// (empty: predict only).
    pub measured: Vec<u32>,
    /// K_p, r × len(measured).
    pub gain: Matrix,
    /// P⁻_p, r×r: prior (predicted) state covariance in this phase.
    pub prior_covariance: Matrix,
    /// P_p, r×r: posterior state covariance in this phase.
    pub posterior_covariance: Matrix,
}

/// A displayed node set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeSet {
    /// Name.
    pub name: String,
    /// gmsh node tags, n of them.
    pub node_tags: Vec<u64>,
    /// X, n×3: rest positions, m.
    pub rest_positions: Matrix,
    /// Surface triangles as local node indices (may be empty).
    pub triangles: Vec<[u32; 3]>,
    /// 3n×r: local-frame displacements, rows (3i, 3i+1, 3i+2) belong to node i, m.
    pub displacement_rows: Matrix,
    /// 3n×r: infinitesimal rotations, same row layout, rad.
    pub rotation_rows: Matrix,
}

/// The compiler's report (named fields; f64 values may be NaN when not computed).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompileReport {
    /// Hankel singular values σ_i of the balanced realisation, descending.
    pub hankel_singular_values: Vec<f64>,
    /// ‖G − G_r‖∞ ≤ 2 Σ_{i>r} σ_i.
    pub error_bound: f64,
    /// Reduced order r.
    pub order: u32,
    /// Number of vibration modes kept before balancing.
    pub modes: u32,
    /// Highest kept modal frequency, Hz.
    pub highest_kept_frequency_hz: f64,
    /// 1 / (2Δt), Hz.
    pub nyquist_hz: f64,
    /// ρ(F).
    pub spectral_radius: f64,
    /// Relative residual of the Riccati equation.
    pub riccati_residual: f64,
    /// ρ((I − K H) F) (largest over the phases of a periodic filter, of the monodromy).
    pub closed_loop_spectral_radius: f64,
    /// Measured errors against references, by name (relative unless the name says otherwise).
    pub measured_errors: BTreeMap<String, f64>,
    /// Wall-clock times of the compiler's stages, s.
    pub timings_s: BTreeMap<String, f64>,
    /// Free-form notes and warnings.
    pub notes: Vec<String>,
}

/// Hashes of what produced the model.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputsDigest {
    /// SHA-256 of the mesh file, lowercase hex.
    pub mesh_sha256: String,
    /// SHA-256 of the scene file, lowercase hex.
    pub scene_sha256: String,
    /// Compiler version string.
    pub compiler_version: String,
}

/// "x", "y" or "z" for a component index (anything else → "?").
pub fn component_label(c: u8) -> &'static str {
    match c {
        0 => "x",
        1 => "y",
        2 => "z",
        _ => "?",
    }
}

impl Model {
    /// Reduced state dimension r.
    pub fn r(&self) -> usize {
        self.state_dim as usize
    }

    /// Why the co-rotational tier failed the compiler's own check, when the scene accepted it
    /// all the same (format v10, `CorotationalTier::failed_check`). None: the tier passed, or
    /// the model has none.
    pub fn tier_failed_check(&self) -> Option<&str> {
        self.tier.as_ref()?.failed_check.as_deref()
    }

    /// The warning a program prints on loading a model whose tier failed its check (None when
    /// [`Self::tier_failed_check`] is None): one wording for `crokf-run`, the viewer and the
    /// bindings.
    pub fn tier_failed_check_warning(&self) -> Option<String> {
        self.tier_failed_check().map(|why| {
            format!(
                "this model's co-rotational tier failed the compiler's own check and was written \
                 all the same (accept_failed_check = true); estimates for loads like its training \
                 runs can be this far off: {why}"
            )
        })
    }

    /// Labels of the measurement channels, `"<sensor>.<x|y|z>"`, in the order of y.
    pub fn measurement_labels(&self) -> Vec<String> {
        self.measurements
            .iter()
            .map(|m| {
                let name = self
                    .sensors
                    .get(m.sensor as usize)
                    .map_or("?", |s| s.name.as_str());
                format!("{name}.{}", component_label(m.component))
            })
            .collect()
    }

    /// Labels of the input channels, in the column order of G.
    pub fn input_labels(&self) -> Vec<String> {
        self.inputs.iter().map(|i| i.label.clone()).collect()
    }

    /// H, q×r: row i is row `measurements[i].component` of
    /// `sensors[measurements[i].sensor].displacement_rows` (local frame).
    /// Requires a validated model.
    pub fn measurement_matrix(&self) -> Matrix {
        let r = self.r();
        let mut h = Matrix::zeros(self.measurements.len() as u32, self.state_dim);
        for (i, m) in self.measurements.iter().enumerate() {
            let s = &self.sensors[m.sensor as usize];
            h.data[i * r..(i + 1) * r]
                .copy_from_slice(s.displacement_rows.row(m.component as usize));
        }
        h
    }
}
