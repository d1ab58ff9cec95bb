//! `crokf._crokf`: the Python extension behind the `crokf` package.
//!
//! Wraps the compiler library (`crokf_compile::compile::compile`), the model file loader
//! (`crokf_runtime::load_model`, with the runtime's verification) and the runtime's
//! [`crokf_runtime::Estimator`] (docs/design.md §5, §6: predict x⁻ = F x + G Rᵀ(ω_g) f_world,
//! update x = x⁻ + K_p (y_lin − H_p x⁻), warped read-outs u_world = R̃(ω) C x).
//!
//! Units are the model's: metres, newtons, seconds, radians. Arrays are float64, row-major:
//! inputs (T, m), measurements (T, q), sensor read-outs (S, 3), node read-outs (n, 3).
//! Read-outs are written by the runtime into a buffer that becomes the NumPy array's memory
//! without a further copy.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use crokf_formats::Model as FormatModel;
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{
    AllowTypeChange, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayLike1, PyArrayLike2,
};
use pyo3::exceptions::{PyException, PyKeyError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBytes, PyComplex, PyDict, PyString, PyTuple, PyType};

pyo3::create_exception!(
    crokf,
    CrokfError,
    PyException,
    "Base class of every crokf error."
);
pyo3::create_exception!(
    crokf,
    CompileError,
    CrokfError,
    "The compiler refused a scene (message names the file, group, element or stage)."
);
pyo3::create_exception!(
    crokf,
    ModelFileError,
    CrokfError,
    "A model file could not be read or failed verification (magic, version, hash, shapes)."
);
pyo3::create_exception!(
    crokf,
    EstimatorError,
    CrokfError,
    "The runtime refused a call (wrong length, non-finite value, update without predict, ...)."
);

pyo3::create_exception!(
    crokf,
    IdentifyError,
    CrokfError,
    "`identify` refused: the recording too short or not exciting enough, the markers' factor \
     outside [0.8, 1.25], a model without estimated loads, a CSV error (file, line, column), \
     or an output over an input or outside the scene's folder. Nothing was written."
);

/// `ChannelError(CrokfError, KeyError)` and `InputError(CrokfError, TypeError)`: crokf errors
/// that existing `except KeyError` / `except TypeError` code still catches. Created once, in
/// Python (a class with two bases), and raised from here.
static CHANNEL_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static INPUT_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

fn two_base_error(
    py: Python<'_>,
    cell: &'static PyOnceLock<Py<PyType>>,
    name: &str,
    second: Bound<'_, PyType>,
    doc: &str,
) -> PyResult<Py<PyType>> {
    cell.get_or_try_init(py, || {
        let namespace = PyDict::new(py);
        namespace.set_item("__doc__", doc)?;
        namespace.set_item("__module__", "crokf")?;
        // The message as given (KeyError's own __str__ would print its repr, quotes escaped).
        namespace.set_item(
            "__str__",
            py.get_type::<pyo3::exceptions::PyBaseException>()
                .getattr("__str__")?,
        )?;
        let bases = PyTuple::new(py, [py.get_type::<CrokfError>(), second])?;
        py.get_type::<PyType>()
            .call1((name, bases, namespace))?
            .cast_into::<PyType>()
            .map(Bound::unbind)
            .map_err(PyErr::from)
    })
    .map(|t| t.clone_ref(py))
}

fn channel_error_type(py: Python<'_>) -> PyResult<Py<PyType>> {
    two_base_error(
        py,
        &CHANNEL_ERROR,
        "ChannelError",
        py.get_type::<PyKeyError>(),
        "A channel, sensor, node set or phase the model does not have (also a KeyError).",
    )
}

fn input_error_type(py: Python<'_>) -> PyResult<Py<PyType>> {
    two_base_error(
        py,
        &INPUT_ERROR,
        "InputError",
        py.get_type::<PyTypeError>(),
        "A value that is not a real number: complex, a string, a boolean (also a TypeError).",
    )
}

/// A `ChannelError` with `message`.
fn channel_error(message: String) -> PyErr {
    Python::attach(|py| match channel_error_type(py) {
        Ok(t) => PyErr::from_type(t.into_bound(py), message),
        Err(e) => e,
    })
}

/// An `InputError` with `message`.
fn input_error(message: String) -> PyErr {
    Python::attach(|py| match input_error_type(py) {
        Ok(t) => PyErr::from_type(t.into_bound(py), message),
        Err(e) => e,
    })
}

/// What a NumPy dtype kind holds, for messages.
fn kind_name(kind: &str) -> &'static str {
    match kind {
        "c" => "complex numbers",
        "U" | "S" => "strings",
        "b" => "booleans",
        "O" => "Python objects",
        "M" | "m" => "dates or durations",
        "V" => "raw bytes",
        _ => "values that are not real numbers",
    }
}

/// Whether one Python value is a real number (int, float or a NumPy real scalar; not bool,
/// str, bytes or complex).
fn is_real(v: &Bound<'_, PyAny>) -> bool {
    if v.is_instance_of::<PyString>()
        || v.is_instance_of::<PyBytes>()
        || v.is_instance_of::<PyComplex>()
        || v.is_instance_of::<pyo3::types::PyBool>()
    {
        return false;
    }
    match v.getattr("dtype").and_then(|d| d.getattr("kind")) {
        Ok(kind) => kind
            .extract::<String>()
            .is_ok_and(|k| matches!(k.as_str(), "f" | "i" | "u")),
        Err(_) => v.extract::<f64>().is_ok(),
    }
}

/// `obj` as a float64 NumPy array of real numbers: refuses complex numbers, strings,
/// booleans and other objects (`InputError`, naming `what` and the element), and `None`
/// elements unless `none_allowed` (they become NaN, "missing").
fn real_array<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    none_allowed: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let array = np
        .call_method1("asarray", (obj,))
        .map_err(|e| input_error(format!("{what}: not an array of numbers ({e})")))?;
    let dtype = array.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    match kind.as_str() {
        "f" | "i" | "u" => {}
        "O" => {
            let flat = array.call_method0("ravel")?;
            for (i, v) in flat.try_iter()?.enumerate() {
                let v = v?;
                if (none_allowed && v.is_none()) || is_real(&v) {
                    continue;
                }
                let shown = v.repr().map_or_else(|_| "?".into(), |r| r.to_string());
                return Err(input_error(format!(
                    "{what}: element {i} is {shown}, not a real number{}",
                    if none_allowed { " or None" } else { "" }
                )));
            }
        }
        other => {
            return Err(input_error(format!(
                "{what}: expected real numbers (float or int), got an array of {} (dtype {})",
                kind_name(other),
                dtype
            )))
        }
    }
    np.call_method1("asarray", (array, "float64"))
}

fn runtime_err(e: crokf_runtime::RuntimeError) -> PyErr {
    use crokf_runtime::RuntimeError as E;
    match e {
        E::Io { .. } | E::ModelFile { .. } | E::Format(_) => ModelFileError::new_err(e.to_string()),
        _ => EstimatorError::new_err(e.to_string()),
    }
}

/// Parses JSON text into Python objects with the standard library's `json` module.
fn json_to_py<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

fn to_array2<'py>(
    py: Python<'py>,
    rows: usize,
    cols: usize,
    data: Vec<f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    Array2::from_shape_vec((rows, cols), data)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyValueError::new_err(format!("internal shape error: {e}")))
}

fn to_array3<'py>(
    py: Python<'py>,
    shape: (usize, usize, usize),
    data: Vec<f64>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    Array3::from_shape_vec(shape, data)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyValueError::new_err(format!("internal shape error: {e}")))
}

fn matrix<'py>(py: Python<'py>, m: &crokf_formats::Matrix) -> PyResult<Bound<'py, PyArray2<f64>>> {
    to_array2(py, m.rows as usize, m.cols as usize, m.data.clone())
}

/// A compiled model (the contents of a `.crokf` file).
///
/// Attributes name what the model has: `inputs` (input channel labels, the columns of the
/// inputs array, N or a dimensionless gravity scale), `measurement_channels` (labels
/// `sensor.x|y|z`, the columns of the measurements array, m), `sensors`, `loads`,
/// `node_sets`.
#[pyclass(module = "crokf", frozen)]
struct Model {
    model: Arc<FormatModel>,
    /// The encoded model file (what `save` writes).
    bytes: Arc<Vec<u8>>,
}

impl Model {
    fn from_bytes_checked(
        py: Python<'_>,
        bytes: Vec<u8>,
        origin: Option<PathBuf>,
    ) -> PyResult<Self> {
        let decoded = match origin {
            Some(path) => crokf_formats::decode(&bytes)
                .map_err(|source| crokf_runtime::RuntimeError::ModelFile { path, source }),
            None => crokf_runtime::model_from_bytes(&bytes),
        }
        .map_err(runtime_err)?;
        decoded
            .validate()
            .map_err(|e| ModelFileError::new_err(format!("invalid model: {e}")))?;
        if let Some(warning) = decoded.tier_failed_check_warning() {
            let message = std::ffi::CString::new(warning.replace('\0', " ")).unwrap_or_default();
            let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
            PyErr::warn(py, category.as_any(), &message, 1)?;
        }
        Ok(Self {
            model: Arc::new(decoded),
            bytes: Arc::new(bytes),
        })
    }

    fn node_set_index(&self, set: &Bound<'_, PyAny>) -> PyResult<usize> {
        node_set_index(&self.model, set)
    }
}

fn node_set_index(model: &FormatModel, set: &Bound<'_, PyAny>) -> PyResult<usize> {
    if let Ok(name) = set.extract::<String>() {
        return model
            .node_sets
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = model.node_sets.iter().map(|s| s.name.as_str()).collect();
                channel_error(format!(
                    "node set '{name}' does not exist; the model has {names:?}"
                ))
            });
    }
    let index = set.extract::<usize>().map_err(|_| {
        PyValueError::new_err("a node set is given by its name (str) or its index (int)")
    })?;
    if index < model.node_sets.len() {
        Ok(index)
    } else {
        Err(channel_error(format!(
            "node set {index} does not exist (the model has {})",
            model.node_sets.len()
        )))
    }
}

#[pymethods]
impl Model {
    /// Reads a model file and verifies it like the runtime does (magic, version, length,
    /// SHA-256, structure, shapes). Raises `ModelFileError` naming the file.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let bytes = std::fs::read(&path).map_err(|source| {
            runtime_err(crokf_runtime::RuntimeError::Io {
                path: path.clone(),
                source,
            })
        })?;
        Self::from_bytes_checked(py, bytes, Some(path))
    }

    /// Decodes a model from the bytes of a model file (same verification as `load`).
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<Self> {
        Self::from_bytes_checked(py, data.to_vec(), None)
    }

    /// Writes the model file (byte-identical to what `crokf-compile` writes).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        // A temporary sibling renamed over the target: an interrupted save leaves the old file.
        crokf_formats::output::write_atomically(&path, self.bytes.as_slice())
            .map_err(|e| CrokfError::new_err(format!("cannot write {}: {e}", path.display())))
    }

    /// The encoded model file.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.bytes)
    }

    /// Time step Δt, s.
    #[getter]
    fn dt(&self) -> f64 {
        self.model.dt
    }

    /// Wilson θ of the recursion.
    #[getter]
    fn theta(&self) -> f64 {
        self.model.theta
    }

    /// Reduced state dimension r.
    #[getter]
    fn order(&self) -> usize {
        self.model.r()
    }

    /// Model tier: "corotational" when the model file carries the co-rotational tier
    /// (docs/design.md §10: a reduced co-rotational model stepped by Newton, with its own
    /// filter; `reduction.model = "corotational"` in the scene), else "warped_linear" (the
    /// reduced linear model with co-rotational warping of the read-outs, §5).
    #[getter]
    fn tier(&self) -> &'static str {
        if self.model.tier.is_some() {
            "corotational"
        } else {
            "warped_linear"
        }
    }

    /// Why the co-rotational tier failed the compiler's own check, when the scene accepted it
    /// all the same (`accept_failed_check = true`; loading such a model also raises a
    /// `UserWarning`), else None.
    #[getter]
    fn tier_failed_check(&self) -> Option<String> {
        self.model.tier_failed_check().map(str::to_owned)
    }

    /// Input channel labels, the columns of the inputs array (`"probe.x"`, `"gravity"`, ...).
    #[getter]
    fn inputs(&self) -> Vec<String> {
        self.model.input_labels()
    }

    /// Measurement channel labels `"sensor.x|y|z"`, the columns of the measurements array.
    #[getter]
    fn measurement_channels(&self) -> Vec<String> {
        self.model.measurement_labels()
    }

    /// Measurement noise variances, one per measurement channel, m².
    #[getter]
    fn measurement_variance<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from(self.model.kalman.measurement_variance.clone()).into_pyarray(py)
    }

    /// Sensor names, in the order of the sensor read-outs.
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.model.sensors.iter().map(|s| s.name.clone()).collect()
    }

    /// Rest positions of the sensors, (S, 3), m.
    #[getter]
    fn sensor_positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let data = self.model.sensors.iter().flat_map(|s| s.position).collect();
        to_array2(py, self.model.sensors.len(), 3, data)
    }

    /// Load group names.
    #[getter]
    fn loads(&self) -> Vec<String> {
        self.model.loads.iter().map(|l| l.name.clone()).collect()
    }

    /// Displayed node set names.
    #[getter]
    fn node_sets(&self) -> Vec<String> {
        self.model
            .node_sets
            .iter()
            .map(|s| s.name.clone())
            .collect()
    }

    /// One displayed node set by name or index, as a dict: `name`, `node_tags` (n,) uint64
    /// gmsh tags, `rest_positions` (n, 3) m, `triangles` (t, 3) uint32 local node indices.
    fn node_set<'py>(
        &self,
        py: Python<'py>,
        set: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let ns = &self.model.node_sets[self.node_set_index(set)?];
        let d = PyDict::new(py);
        d.set_item("name", &ns.name)?;
        d.set_item(
            "node_tags",
            Array1::from(ns.node_tags.clone()).into_pyarray(py),
        )?;
        d.set_item("rest_positions", matrix(py, &ns.rest_positions)?)?;
        let tri: Vec<u32> = ns.triangles.iter().flatten().copied().collect();
        let tri = Array2::from_shape_vec((ns.triangles.len(), 3), tri)
            .map_err(|e| PyValueError::new_err(format!("internal shape error: {e}")))?;
        d.set_item("triangles", tri.into_pyarray(py))?;
        Ok(d)
    }

    /// F, (r, r): x⁺ = F x + G u (docs/design.md §3).
    #[getter]
    fn transition<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        matrix(py, &self.model.transition)
    }

    /// G, (r, m): input matrix, column j belongs to `inputs[j]` (local frame).
    #[getter]
    fn input_matrix<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        matrix(py, &self.model.input)
    }

    /// H, (q, r): local-frame measurement matrix.
    #[getter]
    fn measurement_matrix<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        matrix(py, &self.model.measurement_matrix())
    }

    /// Period of the Kalman schedule (1 with single-rate sensors).
    #[getter]
    fn kalman_period(&self) -> u32 {
        self.model.kalman.period
    }

    /// Phase p of the periodic Kalman filter as a dict: `measured` (indices of the active
    /// measurement channels), `gain` K_p (r, len(measured)), `prior_covariance` P⁻_p and
    /// `posterior_covariance` P_p (r, r). Step k uses phase k mod period (docs/design.md §6).
    fn kalman_phase<'py>(&self, py: Python<'py>, phase: usize) -> PyResult<Bound<'py, PyDict>> {
        let p = self.model.kalman.phases.get(phase).ok_or_else(|| {
            channel_error(format!(
                "phase {phase} does not exist (the period is {})",
                self.model.kalman.period
            ))
        })?;
        let d = PyDict::new(py);
        d.set_item("measured", p.measured.clone())?;
        d.set_item("gain", matrix(py, &p.gain)?)?;
        d.set_item("prior_covariance", matrix(py, &p.prior_covariance)?)?;
        d.set_item("posterior_covariance", matrix(py, &p.posterior_covariance)?)?;
        Ok(d)
    }

    /// Sensor `name`'s rows as a dict: `displacement_rows` C_s (3, r) m and `rotation_rows`
    /// W_s (3, r) rad, local frame (u_lin = C_s x, ω = W_s x).
    fn sensor_rows<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyDict>> {
        let s = self
            .model
            .sensors
            .iter()
            .find(|s| s.name == name)
            .ok_or_else(|| {
                channel_error(format!(
                    "sensor '{name}' does not exist; the model has {:?}",
                    self.sensors()
                ))
            })?;
        let d = PyDict::new(py);
        d.set_item("displacement_rows", matrix(py, &s.displacement_rows)?)?;
        d.set_item("rotation_rows", matrix(py, &s.rotation_rows)?)?;
        Ok(d)
    }

    /// The compiler's report stored in the model (Hankel singular values, bound, ρ(F),
    /// Riccati residual, measured errors, ...), as a dict.
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let text = serde_json::to_string(&self.model.report)
            .map_err(|e| CrokfError::new_err(format!("cannot convert the report: {e}")))?;
        json_to_py(py, &text)
    }

    fn __repr__(&self) -> String {
        format!(
            "crokf.Model(order={}, dt={} s, inputs={}, measurement_channels={}, node_sets={:?})",
            self.model.r(),
            self.model.dt,
            self.model.inputs.len(),
            self.model.measurements.len(),
            self.node_sets()
        )
    }
}

/// Compiles a scene file (TOML) into a model, in process (the compiler library, not a
/// subprocess); the GIL is released while it runs.
///
/// `order` fixes the balanced truncation order r, `tolerance` the relative Hankel singular value
/// cut σ_{r+1}/σ₁ (default: the scene's `[reduction]`, then 1e-4), `modes` the number of
/// vibration modes. `report=False` skips the measured error against the full-order linear
/// reference (faster; the report then has no `measured_errors`). Returns `(model, report)`, the
/// report as the dict `crokf-compile --report` writes. `cache`: the co-rotational tier's
/// training case cache (`crokf-compile --cache`): cases found there are read, the others run
/// and stored; the model is the same without it. Raises `CompileError`.
#[pyfunction]
#[pyo3(signature = (scene_path, order=None, tolerance=None, report=true, modes=None, cache=None))]
fn compile<'py>(
    py: Python<'py>,
    scene_path: PathBuf,
    order: Option<usize>,
    tolerance: Option<f64>,
    report: bool,
    modes: Option<usize>,
    cache: Option<PathBuf>,
) -> PyResult<Bound<'py, PyTuple>> {
    let options = crokf_compile::compile::CompileOptions {
        order,
        tolerance,
        modes,
        skip_measured_error: !report,
        training_cache: cache,
    };
    let result = py.detach(|| {
        crokf_compile::compile::compile(&scene_path, &options)
            .map(|c| (c.report_json(), c.model, c.bytes))
            .map_err(|e| e.to_string())
    });
    let (report_json, model, bytes) = result.map_err(CompileError::new_err)?;
    let model = Model {
        model: Arc::new(model),
        bytes: Arc::new(bytes),
    };
    let report = json_to_py(py, &report_json)?;
    PyTuple::new(py, [Py::new(py, model)?.into_any(), report.unbind()])
}

/// The co-rotational tier's training cases of a scene (`crokf-compile SCENE --list-cases`):
/// a list of `(index, identity, label)`; the identity names the case's file in a cache
/// (`<identity>.case`). Raises `CompileError` (also for a scene without a tier).
#[pyfunction]
fn training_cases(py: Python<'_>, scene_path: PathBuf) -> PyResult<Vec<(usize, String, String)>> {
    py.detach(|| -> Result<Vec<(usize, String, String)>, String> {
        let full = shared_full_order(&scene_path)?;
        let (_, cases) = crokf_compile::nonlinear::cases::scene_cases(&full)?;
        Ok(cases
            .into_iter()
            .map(|c| (c.index, c.id, c.label))
            .collect())
    })
    .map_err(CompileError::new_err)
}

/// Each training case of a scene against a case cache folder: `(index, identity, None)` when
/// its file is there and usable (its identity, checksum and sizes are the scene's), else
/// `(index, identity, why)` — `"missing"`, or why the file cannot be used (damaged, from
/// another build or scene). `crokf.distributed` runs the cases that are not usable again on the
/// cluster before compiling. Raises `CompileError` for a bad scene or cache folder.
#[pyfunction]
fn training_case_status(
    py: Python<'_>,
    scene_path: PathBuf,
    cache: PathBuf,
) -> PyResult<Vec<(usize, String, Option<String>)>> {
    py.detach(|| -> Result<Vec<(usize, String, Option<String>)>, String> {
        use crokf_compile::nonlinear::cases::{self, CaseCache, Lookup};
        let full = shared_full_order(&scene_path)?;
        let (plan, list) = cases::scene_cases(&full)?;
        let store = CaseCache::open(&cache)?;
        let snapshots = plan.snapshot_count(full.wilson.dt);
        let dofs = full.fem.dof_count();
        Ok(list
            .iter()
            .map(|case| {
                let why = match store.lookup(case, dofs, snapshots) {
                    Lookup::Found(_) => None,
                    Lookup::Missing => Some("missing".to_owned()),
                    Lookup::Unusable(why) => Some(why),
                };
                (case.index, case.id.clone(), why)
            })
            .collect())
    })
    .map_err(CompileError::new_err)
}

/// The full-order model of the last scene this process built, with the identity of the inputs
/// it was built from (`shared_full_order`).
type SharedFullOrder = (String, Arc<crokf_compile::FullOrder>);
static FULL_ORDER: std::sync::Mutex<Option<SharedFullOrder>> = std::sync::Mutex::new(None);

/// The full-order model of `scene_path`, built once per process and reused while the scene's
/// inputs are the same: a Dask worker runs many training cases of one scene, and building the
/// model (mesh, K, M, operators) is most of a case's set-up. The identity is the canonical
/// path with the SHA-256 of the scene text and of every file it reads (mesh, node lists), so
/// an edited scene or mesh is built again; one model is kept (the last; `forget_full_order`
/// drops it).
fn shared_full_order(
    scene_path: &std::path::Path,
) -> Result<Arc<crokf_compile::FullOrder>, String> {
    let identity = inputs_identity(scene_path)?;
    {
        let kept = FULL_ORDER.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((id, full)) = kept.as_ref() {
            if *id == identity {
                return Ok(Arc::clone(full));
            }
        }
    }
    let mut timer = crokf_compile::report::StageTimer::default();
    let full = Arc::new(
        crokf_compile::FullOrder::build(scene_path, &mut timer).map_err(|e| e.to_string())?,
    );
    // Kept only when no input changed while it was built (the build read them again).
    if inputs_identity(scene_path)? == identity {
        *FULL_ORDER.lock().unwrap_or_else(|e| e.into_inner()) = Some((identity, Arc::clone(&full)));
    }
    Ok(full)
}

/// Drops the full-order model this process keeps (`shared_full_order`), so its memory is
/// freed: `crokf.distributed` calls it in the client when a compile is done (the workers keep
/// theirs for their next cases).
#[pyfunction]
fn forget_full_order() {
    *FULL_ORDER.lock().unwrap_or_else(|e| e.into_inner()) = None;
}

/// The identity of a scene's inputs: its canonical path, then per file read (the scene, its
/// mesh, its node lists) its role and the SHA-256 of its bytes. Errors name the file.
fn inputs_identity(scene_path: &std::path::Path) -> Result<String, String> {
    let scene = crokf_compile::scene::SceneFile::read(scene_path).map_err(|e| e.to_string())?;
    let canonical =
        std::fs::canonicalize(scene_path).map_err(|e| format!("{}: {e}", scene_path.display()))?;
    let mut identity = format!(
        "{}\0scene {}",
        canonical.display(),
        crokf_formats::sha256_hex(scene.text.as_bytes())
    );
    for (role, path) in scene.input_files() {
        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        identity.push_str(&format!("\0{role} {}", crokf_formats::sha256_hex(&bytes)));
    }
    Ok(identity)
}

/// Runs training case `index` of a scene in process (the GIL released; the scene's full-order
/// model built once per process and reused, `shared_full_order`) and returns its case file's
/// bytes, to be written as `<identity>.case` into the cache a compile reads
/// (`crokf.distributed` does). A run that fails is a result too (stored as failed, as the
/// compile would). Raises `CompileError` for a bad scene or index.
#[pyfunction]
fn run_training_case<'py>(
    py: Python<'py>,
    scene_path: PathBuf,
    index: usize,
) -> PyResult<Bound<'py, PyBytes>> {
    let bytes = py
        .detach(|| -> Result<Vec<u8>, String> {
            use crokf_compile::nonlinear::{cases, training};
            let full = shared_full_order(&scene_path)?;
            let (plan, list) = cases::scene_cases(&full)?;
            let result = training::run_case(&full, &plan, index).map_err(|e| e.to_string())?;
            Ok(cases::encode(&list[index], &result))
        })
        .map_err(CompileError::new_err)?;
    Ok(PyBytes::new(py, &bytes))
}

/// `{"value", "uncertainty", "blocks"}` of an identified parameter.
fn estimate_dict<'py>(
    py: Python<'py>,
    e: &crokf_compile::identify::Estimate,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("value", e.value)?;
    d.set_item("uncertainty", e.uncertainty)?;
    d.set_item("blocks", e.blocks.clone())?;
    Ok(d)
}

/// Identifies the force σ of a co-rotational model's estimated loads from a recording
/// (`crokf-compile identify`; autocovariance least squares on the tier filter's innovations).
///
/// `scene`: the scene the model was compiled from; `model`: the `.crokf` file; `measurements`
/// and `inputs`: `crokf-run`'s CSV files (no inputs: the loads withheld); `out`: a copy of the
/// scene with each identified load's `force_noise_std` and, where the recording disagrees with
/// the scene's, the tier's `model_error_scale` (in the scene's folder). Options:
/// `lags` (30), `skip` (50), `fixed_point` (False). Uncertainties are standard errors over 4
/// disjoint blocks of the recording after `skip`. Returns a dict (`loads`,
/// `model_error_factor`, `markers_factor`,
/// …, `report`: the command's text, `written`). Raises `IdentifyError` on a refusal (nothing
/// written); the GIL is released while it runs.
#[pyfunction]
#[pyo3(signature = (scene, model, measurements, inputs=None, out=None, *, lags=30, skip=50, fixed_point=false))]
#[allow(clippy::too_many_arguments)]
fn identify<'py>(
    py: Python<'py>,
    scene: PathBuf,
    model: PathBuf,
    measurements: PathBuf,
    inputs: Option<PathBuf>,
    out: Option<PathBuf>,
    lags: usize,
    skip: usize,
    fixed_point: bool,
) -> PyResult<Bound<'py, PyDict>> {
    use crokf_compile::identify as id;
    let options = id::IdentifyOptions {
        lags,
        skip,
        fixed_point,
        ..id::IdentifyOptions::default()
    };
    let files = id::Files {
        scene: &scene,
        model: &model,
        measurements: &measurements,
        inputs: inputs.as_deref(),
        out: out.as_deref(),
    };
    let result = py.detach(|| {
        id::identify_files(&files, &options).map_err(|r| match r.found {
            Some(found) => format!("{}\n\n{}", r.error, found.report()),
            None => r.error.to_string(),
        })
    });
    let found = result.map_err(IdentifyError::new_err)?;
    let d = PyDict::new(py);
    let mut loads = Vec::new();
    for l in &found.loads {
        let load = estimate_dict(py, &l.force)?;
        load.set_item("name", &l.name)?;
        load.set_item("scene_sigma", l.scene_sigma)?;
        load.set_item("stated", l.stated)?;
        load.set_item("filter_sigma", l.filter_sigma)?;
        load.set_item("excited", l.force.excited())?;
        match &l.rate {
            Some((scene_rate, rate)) => {
                let r = estimate_dict(py, rate)?;
                r.set_item("scene_sigma", *scene_rate)?;
                load.set_item("rate", r)?;
            }
            None => load.set_item("rate", py.None())?,
        }
        loads.push(load);
    }
    d.set_item("loads", loads)?;
    d.set_item("markers_factor", estimate_dict(py, &found.markers)?)?;
    match &found.white {
        Some(w) => d.set_item("white_factor", estimate_dict(py, w)?)?,
        None => d.set_item("white_factor", py.None())?,
    }
    match &found.model_error {
        Some(m) => {
            let e = estimate_dict(py, &m.factor)?;
            e.set_item("scene_factor", m.scene)?;
            e.set_item("filter_factor", m.filter)?;
            e.set_item("changed", found.model_error_changed().is_some())?;
            d.set_item("model_error_factor", e)?;
        }
        None => d.set_item("model_error_factor", py.None())?,
    }
    d.set_item("steps", found.steps)?;
    d.set_item("samples", found.samples)?;
    d.set_item("lags", found.lags)?;
    d.set_item("skip", found.skip)?;
    d.set_item("blocks", id::BLOCKS)?;
    d.set_item("block_bounds", found.block_bounds.clone())?;
    d.set_item("relative_residual", found.relative_residual)?;
    d.set_item("switches", found.switches)?;
    d.set_item("report", found.report())?;
    d.set_item("written", out.as_ref().map(|p| p.display().to_string()))?;
    Ok(d)
}

/// The runtime's steady-state (periodic) Kalman filter over one model.
///
/// Each step is `predict(inputs)` then at most one `update(measurements)` (or `step`, both).
/// Inputs are world-frame load forces (N) and gravity scales, by channel (`Model.inputs`):
/// a sequence of length m, or a dict `{label: value}` (absent labels are 0). Measurements are
/// world-frame displacements (m) by channel (`Model.measurement_channels`): a sequence of
/// length q with `None` or NaN where missing, a dict `{label: value}` (absent = missing), or
/// `None` (all missing).
#[pyclass(module = "crokf")]
struct Estimator {
    inner: crokf_runtime::Estimator,
    model: Arc<FormatModel>,
    input_index: HashMap<String, usize>,
    channel_index: HashMap<String, usize>,
}

/// A step's inputs and measurements (`None`: zero inputs, no measurement).
fn step_vectors(
    est: &Estimator,
    inputs: Option<&Bound<'_, PyAny>>,
    measurements: Option<&Bound<'_, PyAny>>,
) -> PyResult<(Vec<f64>, Vec<Option<f64>>)> {
    let u = match inputs {
        Some(obj) => input_vector(est, obj)?,
        None => vec![0.0; est.model.inputs.len()],
    };
    let y = match measurements {
        Some(obj) => measurement_vector(est, obj)?,
        None => vec![None; est.model.measurements.len()],
    };
    Ok((u, y))
}

fn input_vector(est: &Estimator, obj: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let m = est.model.inputs.len();
    if obj.is_none() {
        return Ok(vec![0.0; m]);
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut u = vec![0.0; m];
        for (k, v) in d.iter() {
            let label: String = k.extract()?;
            let j = *est.input_index.get(&label).ok_or_else(|| {
                channel_error(format!(
                    "no input channel '{label}'; the model's inputs are {:?}",
                    est.model.input_labels()
                ))
            })?;
            if !is_real(&v) {
                return Err(input_error(format!(
                    "input '{label}': {} is not a real number",
                    v.repr().map_or_else(|_| "?".into(), |r| r.to_string())
                )));
            }
            u[j] = v.extract()?;
        }
        return Ok(u);
    }
    let a: PyArrayLike1<f64, AllowTypeChange> = real_array(obj, "inputs", false)?.extract()?;
    Ok(a.as_array().to_vec())
}

fn measurement_vector(est: &Estimator, obj: &Bound<'_, PyAny>) -> PyResult<Vec<Option<f64>>> {
    let q = est.model.measurements.len();
    if obj.is_none() {
        return Ok(vec![None; q]);
    }
    let present = |v: f64| if v.is_nan() { None } else { Some(v) };
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut y = vec![None; q];
        for (k, v) in d.iter() {
            let label: String = k.extract()?;
            let j = *est.channel_index.get(&label).ok_or_else(|| {
                channel_error(format!(
                    "no measurement channel '{label}'; the model's channels are {:?}",
                    est.model.measurement_labels()
                ))
            })?;
            if !(v.is_none() || is_real(&v)) {
                return Err(input_error(format!(
                    "measurement '{label}': {} is not a real number or None",
                    v.repr().map_or_else(|_| "?".into(), |r| r.to_string())
                )));
            }
            y[j] = v.extract::<Option<f64>>()?.and_then(present);
        }
        return Ok(y);
    }
    let a: PyArrayLike1<f64, AllowTypeChange> = real_array(obj, "measurements", true)?.extract()?;
    Ok(a.as_array().iter().map(|&v| present(v)).collect())
}

impl Estimator {
    fn set_index(&self, set: &Bound<'_, PyAny>) -> PyResult<(usize, usize)> {
        let i = node_set_index(&self.model, set)?;
        Ok((i, self.model.node_sets[i].node_tags.len()))
    }

    /// One per-node read-out of a node set as an (n, 3) array: `read(estimator, set, out)`
    /// fills the 3n values.
    fn node_array<'py>(
        &self,
        py: Python<'py>,
        set: &Bound<'py, PyAny>,
        read: fn(
            &crokf_runtime::Estimator,
            usize,
            &mut [f64],
        ) -> Result<(), crokf_runtime::RuntimeError>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (i, n) = self.set_index(set)?;
        let mut out = vec![0.0; 3 * n];
        read(&self.inner, i, &mut out).map_err(runtime_err)?;
        to_array2(py, n, 3, out)
    }
}

#[pymethods]
impl Estimator {
    /// Validates the model and allocates the filter; the state starts at rest (x₀ = 0).
    #[new]
    fn new(model: &Model) -> PyResult<Self> {
        let inner = crokf_runtime::Estimator::new(&model.model).map_err(runtime_err)?;
        let input_index = model
            .model
            .input_labels()
            .into_iter()
            .enumerate()
            .map(|(i, l)| (l, i))
            .collect();
        let channel_index = model
            .model
            .measurement_labels()
            .into_iter()
            .enumerate()
            .map(|(i, l)| (l, i))
            .collect();
        Ok(Self {
            inner,
            model: model.model.clone(),
            input_index,
            channel_index,
        })
    }

    /// x⁻ = F x + G Rᵀ(ω_g) f_world (docs/design.md §5); inputs as described on the class.
    #[pyo3(signature = (inputs=None))]
    fn predict(&mut self, inputs: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let u = match inputs {
            Some(obj) => input_vector(self, obj)?,
            None => vec![0.0; self.model.inputs.len()],
        };
        self.inner.predict(&u).map_err(runtime_err)
    }

    /// x = x⁻ + K_p (y_lin − H_p x⁻) over the channels active in this step's phase
    /// (docs/design.md §6). Returns the number of measurement values used.
    #[pyo3(signature = (measurements=None))]
    fn update(&mut self, measurements: Option<&Bound<'_, PyAny>>) -> PyResult<usize> {
        let y = match measurements {
            Some(obj) => measurement_vector(self, obj)?,
            None => vec![None; self.model.measurements.len()],
        };
        self.inner.update(&y).map_err(runtime_err)
    }

    /// `predict(inputs)` then `update(measurements)`; returns the number of values used.
    #[pyo3(signature = (inputs=None, measurements=None))]
    fn step(
        &mut self,
        inputs: Option<&Bound<'_, PyAny>>,
        measurements: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<usize> {
        let (u, y) = step_vectors(self, inputs, measurements)?;
        self.inner.step(&u, &y).map_err(runtime_err)
    }

    /// One step with tools on the model's contact region (docs/contact.md): `tools` the
    /// centres of 1 or 2 spherical tools this step, (3,) or (n, 3), m, the model's frame; then
    /// as `step`. All or nothing: a refused step (a non-finite tool, more than two tools, a
    /// model without a contact region) raises `EstimatorError` and changes nothing. Read the
    /// result with `tool_contact`.
    #[pyo3(signature = (tools, inputs=None, measurements=None))]
    fn step_with_tools(
        &mut self,
        tools: &Bound<'_, PyAny>,
        inputs: Option<&Bound<'_, PyAny>>,
        measurements: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<usize> {
        let a: PyArrayLike1<f64, AllowTypeChange> = real_array(tools, "tools", false)?
            .call_method1("reshape", (-1,))?
            .extract()?;
        let flat = a.as_array().to_vec();
        if !flat.len().is_multiple_of(3) || flat.is_empty() {
            return Err(input_error(format!(
                "tools: {} values, expected 3 per tool ((3,) or (n, 3))",
                flat.len()
            )));
        }
        let centres: Vec<[f64; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let (u, y) = step_vectors(self, inputs, measurements)?;
        self.inner
            .step_with_tools(&centres, &u, &y)
            .map_err(runtime_err)
    }

    /// The last contact step's result for tool `tool` (0-based), or None without one: a dict
    /// with `force` (3,) N (the body on the tool), `torque` (3,) N·m about its centre,
    /// `stiffness` (3, 3) N/m, `force_std` (3,) N (with `contact_force_std` on), `depth` m,
    /// `nodes` (pressing or held region nodes) and `status` ("Free", "Touching", "Grasping",
    /// "Clamped", "Overflow", "NotConverged").
    #[pyo3(signature = (tool=0))]
    fn tool_contact<'py>(
        &self,
        py: Python<'py>,
        tool: usize,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(t) = self.inner.tool_contact(tool) else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("force", Array1::from(t.force.to_vec()).into_pyarray(py))?;
        d.set_item("torque", Array1::from(t.torque.to_vec()).into_pyarray(py))?;
        let k = Array2::from_shape_vec((3, 3), t.stiffness.to_vec())
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        d.set_item("stiffness", k.into_pyarray(py))?;
        d.set_item(
            "force_std",
            Array1::from(t.force_std.to_vec()).into_pyarray(py),
        )?;
        d.set_item("depth", t.depth)?;
        d.set_item("nodes", t.active)?;
        d.set_item("status", format!("{:?}", t.status))?;
        Ok(Some(d))
    }

    /// Tool `tool` (of the last `step_with_tools`) grasps the contact-region node nearest its
    /// centre (within 1.25 tool radii) and, from the next tool step on, holds it at its centre
    /// plus the node's present offset, pulling as well as pushing, until `release(tool)` or a
    /// tool step without it. Returns the node's index in the region. Raises `EstimatorError`
    /// (nothing changed) without a contact region, a tool not in the last step, or no node
    /// near enough.
    #[pyo3(signature = (tool=0))]
    fn grasp(&mut self, tool: usize) -> PyResult<usize> {
        self.inner.grasp(tool).map_err(runtime_err)
    }

    /// Tool `tool` lets go of what it holds.
    #[pyo3(signature = (tool=0))]
    fn release(&mut self, tool: usize) {
        self.inner.release(tool);
    }

    /// The region node tool `tool` holds and the held point's offset from the tool's centre
    /// ((3,) m), or None.
    #[pyo3(signature = (tool=0))]
    fn grasped<'py>(
        &self,
        py: Python<'py>,
        tool: usize,
    ) -> Option<(usize, Bound<'py, PyArray1<f64>>)> {
        self.inner
            .grasped(tool)
            .map(|(node, offset)| (node, Array1::from(offset.to_vec()).into_pyarray(py)))
    }

    /// Whether the contact step also computes each tool force's σ (off by default).
    #[setter]
    fn set_contact_force_std(&mut self, on: bool) {
        self.inner.set_contact_force_std(on);
    }

    /// Runs a whole history in one call (no Python loop; the GIL is released).
    ///
    /// `inputs`: (T, m) world-frame inputs per step. `measurements`: (T, q) with NaN (or None)
    /// where missing, or None (open loop). Real numbers only: complex values, strings and
    /// booleans raise `InputError`. `node_set`: optionally a node set (name or index) whose
    /// world positions are recorded every step. Returns a dict of arrays: `time` (T,) s,
    /// `measurements` (T, q) estimated measurement channels, `sensors` (T, S, 3) world
    /// displacements and `sensor_std` (T, S, 3) their standard deviations (m), and with
    /// `node_set` also `node_positions` (T, n, 3) m.
    ///
    /// All or nothing, like `step`: the estimator keeps the final state of a run that
    /// succeeds; when row k fails, `EstimatorError` names row k (0-based) with the runtime's
    /// reason, and the estimator is exactly as it was before the call (no row is taken).
    #[pyo3(signature = (inputs, measurements=None, node_set=None))]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        inputs: &Bound<'py, PyAny>,
        measurements: Option<&Bound<'py, PyAny>>,
        node_set: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let m = self.model.inputs.len();
        let q = self.model.measurements.len();
        let s = self.model.sensors.len();
        let inputs: PyArrayLike2<'py, f64, AllowTypeChange> =
            real_array(inputs, "inputs", false)?.extract()?;
        let measurements: Option<PyArrayLike2<'py, f64, AllowTypeChange>> = match measurements {
            Some(obj) if !obj.is_none() => Some(real_array(obj, "measurements", true)?.extract()?),
            _ => None,
        };
        let u = inputs.as_array();
        let steps = u.nrows();
        if u.ncols() != m {
            return Err(PyValueError::new_err(format!(
                "inputs: expected shape (T, {m}) for the input channels {:?}, got {:?}",
                self.model.input_labels(),
                u.shape()
            )));
        }
        let u: Vec<f64> = u.iter().copied().collect();
        let y: Option<Vec<f64>> = match &measurements {
            Some(a) => {
                let a = a.as_array();
                if a.nrows() != steps || a.ncols() != q {
                    return Err(PyValueError::new_err(format!(
                        "measurements: expected shape ({steps}, {q}) for the channels {:?}, got {:?}",
                        self.model.measurement_labels(),
                        a.shape()
                    )));
                }
                Some(a.iter().copied().collect())
            }
            None => None,
        };
        let set = match node_set {
            Some(obj) => Some(self.set_index(obj)?),
            None => None,
        };
        let dt = self.model.dt;
        // All or nothing: a failing row puts the estimator back as it was (the prepared model
        // is shared, so the copy is the state and its scratch, O(r + q)).
        let before = self.inner.clone();
        let inner = &mut self.inner;
        let out = py.detach(move || -> Result<RunOutput, String> {
            let mut out = RunOutput {
                time: Vec::with_capacity(steps),
                meas: vec![0.0; steps * q],
                sensors: vec![0.0; steps * 3 * s],
                std: vec![0.0; steps * 3 * s],
                nodes: vec![0.0; set.map_or(0, |(_, n)| steps * 3 * n)],
            };
            let mut yk = vec![None; q];
            for k in 0..steps {
                if let Some(y) = &y {
                    for (o, &v) in yk.iter_mut().zip(&y[k * q..(k + 1) * q]) {
                        *o = if v.is_nan() { None } else { Some(v) };
                    }
                }
                let at = |e: crokf_runtime::RuntimeError| format!("row {k} of {steps}: {e}");
                inner.step(&u[k * m..(k + 1) * m], &yk).map_err(at)?;
                out.time.push(inner.step_index() as f64 * dt);
                inner
                    .measurement_estimates(&mut out.meas[k * q..(k + 1) * q])
                    .map_err(at)?;
                inner
                    .sensor_displacements(&mut out.sensors[k * 3 * s..(k + 1) * 3 * s])
                    .map_err(at)?;
                inner
                    .sensor_std(&mut out.std[k * 3 * s..(k + 1) * 3 * s])
                    .map_err(at)?;
                if let Some((i, n)) = set {
                    inner
                        .node_positions(i, &mut out.nodes[k * 3 * n..(k + 1) * 3 * n])
                        .map_err(at)?;
                }
            }
            Ok(out)
        });
        let out = match out {
            Ok(out) => out,
            Err(message) => {
                self.inner = before;
                return Err(EstimatorError::new_err(format!(
                    "{message}; Estimator.run took no row: the estimator is as it was before \
                     the call"
                )));
            }
        };
        let d = PyDict::new(py);
        d.set_item("time", Array1::from(out.time).into_pyarray(py))?;
        d.set_item("measurements", to_array2(py, steps, q, out.meas)?)?;
        d.set_item("sensors", to_array3(py, (steps, s, 3), out.sensors)?)?;
        d.set_item("sensor_std", to_array3(py, (steps, s, 3), out.std)?)?;
        if let Some((_, n)) = set {
            d.set_item("node_positions", to_array3(py, (steps, n, 3), out.nodes)?)?;
        }
        Ok(d)
    }

    /// Back to rest (x = 0, step 0).
    fn reset(&mut self) {
        self.inner.reset();
    }

    /// The co-rotational tier's force-σ level in use (docs/design.md §11.10): a dict with
    /// `level` (0: the designed σ), `factor` (on the designed σ), `statistic` (the innovation
    /// statistic T, mean 1 while the filter's model holds) and `adapting`; None for a model
    /// with one level (no estimated loads, or the warped linear tier).
    #[getter]
    fn force_level<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(l) = self.inner.force_level() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("level", l.level)?;
        d.set_item("factor", l.factor)?;
        d.set_item("statistic", l.statistic)?;
        d.set_item("adapting", l.adapting)?;
        Ok(Some(d))
    }

    /// Whether the force-σ level follows the innovations (True, the default) or stays at the
    /// designed σ (False). Either way the level returns to the designed σ and its statistic
    /// starts afresh; on before the first step after construction or `reset`, the run's first
    /// update is made at the lowest level (markers every step, docs/design.md §11.10). No
    /// effect on a model with one level.
    fn set_force_adaptation(&mut self, on: bool) {
        self.inner.set_force_adaptation(on);
    }

    /// The co-rotational tier filter's own covariance P of the state (n × n, a copy) while it
    /// carries one: from an update with an active channel missing or gated, or from a lowering
    /// of the force-σ level after an update, until it settles near the stored filter's
    /// (docs/design.md §11.10–11.11); None while the stored covariances are
    /// in use (always on the warped tier). `sensor_std` and `node_std` follow the same choice.
    #[getter]
    fn tier_covariance<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let n = self.inner.state().len();
        self.inner
            .tier_covariance()
            .map(|p| Array2::from_shape_fn((n, n), |(i, j)| p[i * n + j]).into_pyarray(py))
    }

    /// Whether the co-rotational tier's filter carries its own covariance while channels are
    /// missing or gated (True, the default) or keeps the stored gains and σ (False; it then
    /// costs nothing extra). docs/design.md §11.11.
    fn set_covariance_recursion(&mut self, on: bool) {
        self.inner.set_covariance_recursion(on);
    }

    /// Number of predictions since construction or `reset`.
    #[getter]
    fn step_index(&self) -> u64 {
        self.inner.step_index()
    }

    /// Time of the current state, s (step_index × Δt).
    #[getter]
    fn time(&self) -> f64 {
        self.inner.time()
    }

    /// The reduced state x, (r,) (a copy).
    #[getter]
    fn state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from(self.inner.state().to_vec()).into_pyarray(py)
    }

    /// Sets the state (length of `state`: r, or the co-rotational tier's state). Refused
    /// (`EstimatorError`, the estimator unchanged) when an entry is not finite, or when the
    /// state is not one the filter can go on from: a sensor or displayed node displaced beyond
    /// the runtime's plausibility bound of a measurement (10 × the body's size: no measurement
    /// could be accepted from it), or a next prediction that would not be finite. Real numbers
    /// only (`InputError` otherwise).
    #[setter]
    fn set_state(&mut self, x: &Bound<'_, PyAny>) -> PyResult<()> {
        let x: PyArrayLike1<'_, f64, AllowTypeChange> = real_array(x, "state", false)?.extract()?;
        let x: Vec<f64> = x.as_array().to_vec();
        let mut trial = self.inner.clone();
        trial.set_state(&x).map_err(runtime_err)?;
        check_state(&trial)
            .map_err(|m| EstimatorError::new_err(format!("state: {m}; state unchanged")))?;
        self.inner = trial;
        Ok(())
    }

    /// World-frame displacement of every sensor, u = R̃(W_s x) C_s x, (S, 3), m.
    fn sensor_displacements<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let s = self.model.sensors.len();
        let mut out = vec![0.0; 3 * s];
        self.inner
            .sensor_displacements(&mut out)
            .map_err(runtime_err)?;
        to_array2(py, s, 3, out)
    }

    /// Standard deviation of every sensor displacement, sqrt(diag(C_s P C_sᵀ)), (S, 3), m.
    fn sensor_std<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let s = self.model.sensors.len();
        let mut out = vec![0.0; 3 * s];
        self.inner.sensor_std(&mut out).map_err(runtime_err)?;
        to_array2(py, s, 3, out)
    }

    /// Estimated world value of every measurement channel, (q,), m.
    fn measurement_estimates<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let mut out = vec![0.0; self.model.measurements.len()];
        self.inner
            .measurement_estimates(&mut out)
            .map_err(runtime_err)?;
        Ok(Array1::from(out).into_pyarray(py))
    }

    /// World displacement u_i = R̃(ω_i) u_lin,i of every node of a node set, (n, 3), m.
    fn node_displacements<'py>(
        &self,
        py: Python<'py>,
        set: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.node_array(py, set, crokf_runtime::Estimator::node_displacements)
    }

    /// World position X + u of every node of a node set, (n, 3), m.
    fn node_positions<'py>(
        &self,
        py: Python<'py>,
        set: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.node_array(py, set, crokf_runtime::Estimator::node_positions)
    }

    /// Standard deviation of every node displacement of a node set, (n, 3), m.
    fn node_std<'py>(
        &self,
        py: Python<'py>,
        set: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.node_array(py, set, crokf_runtime::Estimator::node_std)
    }

    fn __repr__(&self) -> String {
        format!(
            "crokf.Estimator(step_index={}, time={} s, order={})",
            self.inner.step_index(),
            self.inner.time(),
            self.model.r()
        )
    }
}

/// Whether the filter can go on from `est`'s state: every sensor and displayed node within the
/// plausibility bound of a measurement (`PreparedModel::measurement_bound`, 10 × the body's
/// size) and finite read-outs, and a next prediction (inputs 0) with a finite result. The
/// runtime documents no range for a state and the C ABI sets none, so this is the boundary's
/// check (docs/limits.md); the message names the first read-out out of range.
fn check_state(est: &crokf_runtime::Estimator) -> Result<(), String> {
    let model = est.model();
    let bound = est.prepared().measurement_bound();
    let mut u = vec![0.0; 3 * model.sensors.len()];
    let unreadable = |e: crokf_runtime::RuntimeError| format!("its read-outs are not finite ({e})");
    est.sensor_displacements(&mut u).map_err(unreadable)?;
    for (i, v) in u.chunks_exact(3).enumerate() {
        if let Some(c) = v.iter().position(|c| !c.is_finite() || c.abs() > bound) {
            return Err(format!(
                "it displaces sensor '{}' by {:e} m along {}, beyond the plausibility bound \
                 ±{bound:.3e} m (10 × the body's size)",
                model.sensors[i].name,
                v[c],
                ["x", "y", "z"][c]
            ));
        }
    }
    for (set, ns) in model.node_sets.iter().enumerate() {
        let mut d = vec![0.0; 3 * ns.node_tags.len()];
        est.node_displacements(set, &mut d).map_err(unreadable)?;
        if let Some(i) = d.iter().position(|c| !c.is_finite() || c.abs() > bound) {
            return Err(format!(
                "it displaces node {} of node set '{}' by {:e} m, beyond the plausibility bound \
                 ±{bound:.3e} m (10 × the body's size)",
                ns.node_tags[i / 3],
                ns.name,
                d[i]
            ));
        }
    }
    let mut next = est.clone();
    next.predict(&vec![0.0; model.inputs.len()])
        .map_err(|e| format!("the next prediction from it fails ({e})"))?;
    Ok(())
}

/// Buffers filled by `Estimator.run` with the GIL released.
struct RunOutput {
    time: Vec<f64>,
    meas: Vec<f64>,
    sensors: Vec<f64>,
    std: Vec<f64>,
    nodes: Vec<f64>,
}

/// The extension module `crokf._crokf` (re-exported by the `crokf` package).
#[pymodule]
fn _crokf(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Model>()?;
    m.add_class::<Estimator>()?;
    m.add_function(wrap_pyfunction!(compile, m)?)?;
    m.add_function(wrap_pyfunction!(identify, m)?)?;
    m.add_function(wrap_pyfunction!(training_cases, m)?)?;
    m.add_function(wrap_pyfunction!(run_training_case, m)?)?;
    m.add_function(wrap_pyfunction!(training_case_status, m)?)?;
    m.add_function(wrap_pyfunction!(forget_full_order, m)?)?;
    m.add("CrokfError", py.get_type::<CrokfError>())?;
    m.add("CompileError", py.get_type::<CompileError>())?;
    m.add("ModelFileError", py.get_type::<ModelFileError>())?;
    m.add("EstimatorError", py.get_type::<EstimatorError>())?;
    m.add("IdentifyError", py.get_type::<IdentifyError>())?;
    m.add("ChannelError", channel_error_type(py)?)?;
    m.add("InputError", input_error_type(py)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
