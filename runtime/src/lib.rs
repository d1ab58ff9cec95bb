//! crokf runtime: loads a model file and runs the reduced-order co-rotational Kalman filter
//! online (docs/design.md §1, §5, §6). Dependency-light: no linear-algebra crate, no allocation
//! per step.
//!
//! ```
//! use crokf_runtime::{load_model, Estimator};
//! # let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/cantilever/model.crokf");
//! // path: a model file written by crokf-compile (here the bundled cantilever).
//! let model = load_model(path)?;
//! let mut est = Estimator::new(&model)?;
//! // One step: the inputs (`model.input_labels()`: N per load channel), the measurements
//! // (`model.measurement_labels()`: m per channel, None where a marker has no value).
//! let inputs = vec![0.0; model.inputs.len()];
//! let y = vec![None; model.measurements.len()];
//! est.step(&inputs, &y)?;
//! // The estimate at every sensor: world-frame displacements, 3 per sensor, m.
//! let mut u = vec![0.0; 3 * model.sensors.len()];
//! est.sensor_displacements(&mut u)?;
//! assert!(u.iter().all(|v| v.abs() < 1e-12)); // no load, no measurement: at rest
//! # Ok::<(), crokf_runtime::RuntimeError>(())
//! ```
//!
//! The public API is this crate's root (the model, the estimator, their errors and statuses,
//! the contact results), [`capi`] (the C ABI, `include/crokf.h`) and, with the feature `table`,
//! `table` (the recording's CSV files); `public-api.txt` lists every `pub` declaration of the
//! sources (those of the `internals` modules and of private modules included) and
//! `tests/public_api.rs` checks the sources against it.

mod adaptation;
pub mod capi;
mod contact;
mod covariance;
mod estimator;
mod prepared;
mod simd;
#[cfg(feature = "table")]
pub mod table;
// The tier's step and the warp's algebra: public only with the feature `internals` (the
// project's tests, verification and benchmarks); what a user needs of them is re-exported
// below. Without the feature, the parts only those callers use are unused here.
#[cfg(feature = "internals")]
pub mod tier;
#[cfg(not(feature = "internals"))]
#[allow(dead_code, unused_imports)]
mod tier;
#[cfg(feature = "internals")]
pub mod warp;
#[cfg(not(feature = "internals"))]
#[allow(dead_code)]
mod warp;

pub use adaptation::ForceLevel;
pub use contact::{ContactPoint, ContactStatus, ToolContact, MAX_CONTACTS, MAX_TOOLS};
pub use crokf_formats::{FormatError, Model};
pub use estimator::{CovarianceKind, Estimator, DEFAULT_GATE_SIGMAS};
pub use prepared::{DisplayRowFormat, PreparedModel, COMPACT_ABOVE_BYTES};
pub use tier::{EnvelopeStatus, TierError, TierStatus};

use std::path::{Path, PathBuf};

/// Everything that can go wrong at run time.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// The model file could not be read.
    #[error("cannot read model file {path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The model file is invalid.
    #[error("invalid model file {path}: {source}")]
    ModelFile {
        /// File.
        path: PathBuf,
        /// Cause.
        source: FormatError,
    },
    /// The model (bytes or value) is invalid.
    #[error("invalid model: {0}")]
    Format(#[from] FormatError),
    /// A caller buffer or vector has the wrong length.
    #[error("{what}: expected length {expected}, got {found}")]
    Length {
        /// Which argument.
        what: &'static str,
        /// Required length.
        expected: usize,
        /// Given length.
        found: usize,
    },
    /// A non-finite input value (estimator untouched).
    #[error("step {step}: input '{channel}' is not finite ({value})")]
    NonFiniteInput {
        /// The step k being computed.
        step: u64,
        /// Input label.
        channel: String,
        /// The value.
        value: f64,
    },
    /// An input beyond the model's plausibility bound (estimator untouched).
    #[error("step {step}: input '{channel}' = {value:e} is beyond the model's plausibility bound ±{bound:.3e} (a load that would statically move a point by 10× the body's size)")]
    ImplausibleInput {
        /// The step k being computed.
        step: u64,
        /// Input label.
        channel: String,
        /// The value.
        value: f64,
        /// The bound.
        bound: f64,
    },
    /// A non-finite measurement (estimator untouched).
    #[error("step {step}: measurement '{channel}' is not finite ({value})")]
    NonFiniteMeasurement {
        /// The step k being computed.
        step: u64,
        /// Measurement label `sensor.c`.
        channel: String,
        /// The value.
        value: f64,
    },
    /// A measurement beyond the model's plausibility bound (estimator untouched).
    #[error("step {step}: measurement '{channel}' = {value:e} m is beyond the model's plausibility bound ±{bound:.3e} m (10× the body's size)")]
    ImplausibleMeasurement {
        /// The step k being computed.
        step: u64,
        /// Measurement label `sensor.c`.
        channel: String,
        /// The value, m.
        value: f64,
        /// The bound, m.
        bound: f64,
    },
    /// The step's result would not be finite (estimator untouched).
    #[error("step {step}: the {stage} would make state entry {index} non-finite; step refused")]
    NonFiniteState {
        /// The step k being computed.
        step: u64,
        /// `prediction` or `update`.
        stage: &'static str,
        /// State index.
        index: usize,
    },
    /// The update from the co-rotational tier filter's own covariance (docs/design.md §11.11)
    /// would leave that covariance non-finite or its innovation covariance not positive
    /// definite (estimator untouched).
    #[error(
        "step {step}: the update would make the tier filter's own covariance non-finite or \
         indefinite; step refused"
    )]
    NonFiniteCovariance {
        /// The step k being computed.
        step: u64,
    },
    /// A read-out would hold a non-finite value.
    #[error("{what}: value {index} is not finite")]
    NonFiniteReadout {
        /// Which read-out.
        what: &'static str,
        /// Index into the output buffer.
        index: usize,
    },
    /// A non-finite value elsewhere.
    #[error("{what}[{index}] is not finite ({value})")]
    NonFinite {
        /// Which argument.
        what: &'static str,
        /// Index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// `update` without a preceding `predict`.
    #[error(
        "update called without a preceding predict (each step is predict, then at most one update)"
    )]
    UpdateWithoutPredict,
    /// R̃(ω̄) is not invertible at a sensor (|ω̄| near 2π): the measurement cannot be un-warped.
    #[error("step {step}: sensor '{sensor}': rotation angle {angle} rad makes the warp map singular; step refused")]
    SingularWarp {
        /// The step k being computed.
        step: u64,
        /// Sensor name.
        sensor: String,
        /// |ω̄|, rad.
        angle: f64,
    },
    /// A co-rotational tier step was refused (estimator untouched).
    #[error(transparent)]
    Tier(#[from] crate::tier::TierError),
    /// A tool step on a model without a contact region.
    #[error(
        "the model has no contact region: declare a [[contact]] in the scene and compile again"
    )]
    NoContactRegion,
    /// A tool step on the co-rotational tier.
    #[error(
        "contact runs on the warped linear tier only; this model carries the co-rotational tier"
    )]
    ContactOnTier,
    /// More tools than the contact step takes.
    #[error("{given} tools given; the contact step takes at most {max}")]
    TooManyTools {
        /// Tools given.
        given: usize,
        /// The most.
        max: usize,
    },
    /// A non-finite tool position (estimator untouched).
    #[error("step {step}: tool {tool} position {component} is not finite ({value})")]
    NonFiniteTool {
        /// The step k being computed.
        step: u64,
        /// Tool index.
        tool: usize,
        /// x, y or z.
        component: &'static str,
        /// The value.
        value: f64,
    },
    /// A grasp by a tool that was not in the last tool step.
    #[error(
        "tool {tool} was not in the last tool step ({tools} tools): step with it before it grasps"
    )]
    NoSuchTool {
        /// Tool index.
        tool: usize,
        /// Tools of the last tool step.
        tools: usize,
    },
    /// A grasp with no region node near the tool (estimator untouched).
    #[error("tool {tool}: no contact-region node within {reach} m of its centre to grasp")]
    NothingToGrasp {
        /// Tool index.
        tool: usize,
        /// How near a node must be, m ((1 + 0.25) × the tool radius).
        reach: f64,
    },
    /// Node set index out of range.
    #[error("node set {index} does not exist (the model has {count})")]
    NoSuchNodeSet {
        /// Requested index.
        index: usize,
        /// Number of node sets.
        count: usize,
    },
}

/// Reads and decodes a model file (magic, version, length, hash, structure, shapes).
///
/// ```
/// # let dir = std::env::temp_dir();
/// let err = crokf_runtime::load_model(dir.join("no-such-model.crokf")).unwrap_err();
/// // The error names the file.
/// assert!(err.to_string().contains("no-such-model.crokf"), "{err}");
/// ```
pub fn load_model(path: impl AsRef<Path>) -> Result<Model, RuntimeError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| RuntimeError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    crokf_formats::decode(&bytes).map_err(|source| RuntimeError::ModelFile {
        path: path.to_path_buf(),
        source,
    })
}

/// Decodes a model from the bytes of a model file.
///
/// ```
/// # let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/cantilever/model.crokf");
/// let bytes = std::fs::read(path)?;
/// let model = crokf_runtime::model_from_bytes(&bytes)?;
/// assert_eq!(model.dt, 0.005);
/// // A damaged file is refused with the reason, never read half.
/// let mut damaged = bytes.clone();
/// let last = damaged.len() - 1;
/// damaged[last] ^= 1;
/// let err = crokf_runtime::model_from_bytes(&damaged).unwrap_err();
/// assert!(err.to_string().contains("SHA-256"), "{err}");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn model_from_bytes(bytes: &[u8]) -> Result<Model, RuntimeError> {
    Ok(crokf_formats::decode(bytes)?)
}

/// `Model::load(path)` / `Model::from_bytes(bytes)` for the runtime (Model lives in
/// `crokf-formats`, so these come as an extension trait).
pub trait ModelExt: Sized {
    /// See [`load_model`].
    fn load(path: impl AsRef<Path>) -> Result<Self, RuntimeError>;
    /// See [`model_from_bytes`].
    fn from_bytes(bytes: &[u8]) -> Result<Self, RuntimeError>;
}

impl ModelExt for Model {
    fn load(path: impl AsRef<Path>) -> Result<Self, RuntimeError> {
        load_model(path)
    }
    fn from_bytes(bytes: &[u8]) -> Result<Self, RuntimeError> {
        model_from_bytes(bytes)
    }
}
