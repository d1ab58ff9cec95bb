//! C ABI (header `runtime/include/crokf.h`). Opaque handles, `0` / non-NULL on success,
//! `-1` / NULL on failure with the message in [`crokf_last_error`] (thread-local). No panic
//! crosses the boundary (every entry point runs under `catch_unwind`).

use crate::{load_model, model_from_bytes, Estimator, Model, PreparedModel};
use std::cell::RefCell;
use std::ffi::{c_char, c_int, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::ptr;
use std::sync::Arc;

/// A loaded, prepared model plus C strings of its labels. Estimators made from it share its
/// matrices (an `Arc`), so freeing the handle early is safe.
pub struct CrokfModel {
    prepared: Arc<PreparedModel>,
    input_labels: Vec<CString>,
    measurement_labels: Vec<CString>,
    sensor_names: Vec<CString>,
    node_set_names: Vec<CString>,
    failed_check: Option<CString>,
}

/// An estimator over a model (shares the model's matrices).
pub struct CrokfEstimator {
    est: Estimator,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: &str) {
    let c = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// Runs `f`, turning `Err` and panics into `on_error` plus the thread-local message.
fn guard<T>(on_error: T, f: impl FnOnce() -> Result<T, String>) -> T {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => v,
        Ok(Err(msg)) => {
            set_error(&msg);
            on_error
        }
        Err(_) => {
            set_error("internal error (panic caught at the C boundary)");
            on_error
        }
    }
}

fn cstrings(v: impl IntoIterator<Item = String>) -> Vec<CString> {
    v.into_iter()
        .map(|s| CString::new(s.replace('\0', " ")).unwrap_or_default())
        .collect()
}

fn wrap_model(model: Model) -> Result<*mut CrokfModel, String> {
    let m = CrokfModel {
        input_labels: cstrings(model.input_labels()),
        measurement_labels: cstrings(model.measurement_labels()),
        sensor_names: cstrings(model.sensors.iter().map(|s| s.name.clone())),
        node_set_names: cstrings(model.node_sets.iter().map(|s| s.name.clone())),
        failed_check: model
            .tier_failed_check()
            .map(|why| CString::new(why.replace('\0', " ")).unwrap_or_default()),
        prepared: Arc::new(PreparedModel::new(model).map_err(|e| e.to_string())?),
    };
    Ok(Box::into_raw(Box::new(m)))
}

unsafe fn model_ref<'a>(m: *const CrokfModel) -> Result<&'a CrokfModel, String> {
    m.as_ref().ok_or_else(|| "model handle is NULL".to_string())
}

unsafe fn est_ref<'a>(e: *const CrokfEstimator) -> Result<&'a CrokfEstimator, String> {
    e.as_ref()
        .ok_or_else(|| "estimator handle is NULL".to_string())
}

unsafe fn est_mut<'a>(e: *mut CrokfEstimator) -> Result<&'a mut CrokfEstimator, String> {
    e.as_mut()
        .ok_or_else(|| "estimator handle is NULL".to_string())
}

unsafe fn slice<'a, T>(p: *const T, n: usize, what: &str) -> Result<&'a [T], String> {
    if n == 0 {
        Ok(&[])
    } else if p.is_null() {
        Err(format!("{what} is NULL but its length is {n}"))
    } else {
        Ok(std::slice::from_raw_parts(p, n))
    }
}

unsafe fn slice_mut<'a>(p: *mut f64, n: usize, what: &str) -> Result<&'a mut [f64], String> {
    if n == 0 {
        Ok(&mut [])
    } else if p.is_null() {
        Err(format!("{what} is NULL but its length is {n}"))
    } else {
        Ok(std::slice::from_raw_parts_mut(p, n))
    }
}

/// The measurements of a step as `crokf_step` takes them: `y` NULL for none, else `n` = q
/// values with `present[i] == 0` marking value i missing (`present` NULL: all present).
unsafe fn measurement_getter<'a>(
    est: &Estimator,
    y: *const f64,
    present: *const u8,
    n: usize,
) -> Result<impl Fn(usize) -> Option<f64> + 'a, String> {
    let values = if y.is_null() {
        None
    } else {
        let q = est.model().measurements.len();
        if n != q {
            return Err(format!("measurements: expected length {q}, got {n}"));
        }
        let ys = slice(y, n, "measurements")?;
        let present = if present.is_null() {
            None
        } else {
            Some(slice(present, n, "present")?)
        };
        Some((ys, present))
    };
    Ok(move |i: usize| match values {
        None => None,
        Some((_, Some(p))) if p[i] == 0 => None,
        Some((ys, _)) => Some(ys[i]),
    })
}

/// The message of the last failed call on this thread ("" if none). Valid until the next
/// failing call on the same thread.
#[no_mangle]
pub extern "C" fn crokf_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Loads a model file; NULL on error.
///
/// # Safety
/// `path` must be NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_load(path: *const c_char) -> *mut CrokfModel {
    guard(ptr::null_mut(), || {
        if path.is_null() {
            return Err("model path is NULL".into());
        }
        let p = CStr::from_ptr(path)
            .to_str()
            .map_err(|_| "model path is not UTF-8".to_string())?;
        wrap_model(load_model(p).map_err(|e| e.to_string())?)
    })
}

/// Decodes a model from the `len` bytes of a model file; NULL on error.
///
/// # Safety
/// `bytes` must point to `len` readable bytes (or be NULL with `len` = 0).
#[no_mangle]
pub unsafe extern "C" fn crokf_model_from_bytes(bytes: *const u8, len: usize) -> *mut CrokfModel {
    guard(ptr::null_mut(), || {
        let b = slice(bytes, len, "bytes")?;
        wrap_model(model_from_bytes(b).map_err(|e| e.to_string())?)
    })
}

/// Frees a model (NULL is a no-op). Estimators made from it stay valid.
///
/// # Safety
/// `m` must be NULL or a handle from `crokf_model_load`/`crokf_model_from_bytes`, freed once.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_free(m: *mut CrokfModel) {
    if !m.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| drop(Box::from_raw(m))));
    }
}

macro_rules! model_count {
    ($(#[$doc:meta])* $name:ident, |$m:ident| $e:expr) => {
        $(#[$doc])*
        ///
        /// # Safety
        /// `m` must be NULL (returns 0) or a live model handle.
        #[no_mangle]
        pub unsafe extern "C" fn $name(m: *const CrokfModel) -> usize {
            guard(0, || {
                let $m = model_ref(m)?.prepared.model();
                Ok($e)
            })
        }
    };
}

model_count!(
    /// Number of input channels m.
    crokf_model_num_inputs, |m| m.inputs.len());
model_count!(
    /// Number of measurement channels q.
    crokf_model_num_measurements, |m| m.measurements.len());
model_count!(
    /// Number of sensors (sensor read-outs have 3 values per sensor).
    crokf_model_num_sensors, |m| m.sensors.len());
model_count!(
    /// State length (of `crokf_state`): r for the warped tier; 3·r_tier + 3 per random-walk
    /// load group, s = (q, q̇, q̈, f), for the co-rotational tier (6 per group with force rates,
    /// s = (q, q̇, q̈, f, ḟ); docs/design.md §10, §11.4, §11.5).
    crokf_model_state_dim, |m| m.tier.as_ref().map_or(m.r(), |t| t.state_dim()));
model_count!(
    /// 1 when the model carries the co-rotational tier (docs/design.md §10), else 0.
    crokf_model_is_corotational, |m| m.tier.is_some() as usize);
model_count!(
    /// Number of displayed node sets.
    crokf_model_num_node_sets, |m| m.node_sets.len());

/// Number of nodes in node set `set` (0 if out of range or NULL handle).
///
/// # Safety
/// `m` must be NULL or a live model handle.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_node_set_len(m: *const CrokfModel, set: usize) -> usize {
    guard(0, || {
        let m = model_ref(m)?.prepared.model();
        m.node_sets
            .get(set)
            .map(|s| s.node_tags.len())
            .ok_or_else(|| format!("node set {set} does not exist"))
    })
}

/// Time step Δt in seconds (NaN on a NULL handle).
///
/// # Safety
/// `m` must be NULL or a live model handle.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_dt(m: *const CrokfModel) -> f64 {
    guard(f64::NAN, || Ok(model_ref(m)?.prepared.model().dt))
}

macro_rules! model_label {
    ($(#[$doc:meta])* $name:ident, $field:ident) => {
        $(#[$doc])*
        /// NULL if out of range. The string lives as long as the model handle.
        ///
        /// # Safety
        /// `m` must be NULL or a live model handle.
        #[no_mangle]
        pub unsafe extern "C" fn $name(m: *const CrokfModel, i: usize) -> *const c_char {
            guard(ptr::null(), || {
                let v = &model_ref(m)?.$field;
                v.get(i)
                    .map(|s| s.as_ptr())
                    .ok_or_else(|| format!("index {i} out of range ({} entries)", v.len()))
            })
        }
    };
}

model_label!(
    /// Label of input channel i.
    crokf_model_input_label, input_labels);
model_label!(
    /// Label of measurement channel i (`sensor.x`).
    crokf_model_measurement_label, measurement_labels);
model_label!(
    /// Name of sensor i.
    crokf_model_sensor_name, sensor_names);
model_label!(
    /// Name of node set i.
    crokf_model_node_set_name, node_set_names);

/// A new estimator at rest over the model (which may be freed afterwards; the estimator shares
/// the model's matrices, so many estimators cost O(r + q) each); NULL on error.
///
/// # Safety
/// `m` must be NULL or a live model handle.
#[no_mangle]
pub unsafe extern "C" fn crokf_estimator_new(m: *const CrokfModel) -> *mut CrokfEstimator {
    guard(ptr::null_mut(), || {
        let est = Estimator::from_prepared(Arc::clone(&model_ref(m)?.prepared));
        Ok(Box::into_raw(Box::new(CrokfEstimator { est })))
    })
}

/// Frees an estimator (NULL is a no-op).
///
/// # Safety
/// `e` must be NULL or a handle from `crokf_estimator_new`, freed once.
#[no_mangle]
pub unsafe extern "C" fn crokf_estimator_free(e: *mut CrokfEstimator) {
    if !e.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| drop(Box::from_raw(e))));
    }
}

/// Prediction with `n_inputs` world-frame inputs (one per input channel).
///
/// # Safety
/// `e` live estimator; `inputs` points to `n_inputs` doubles.
#[no_mangle]
pub unsafe extern "C" fn crokf_predict(
    e: *mut CrokfEstimator,
    inputs: *const f64,
    n_inputs: usize,
) -> c_int {
    guard(-1, || {
        let e = est_mut(e)?;
        let u = slice(inputs, n_inputs, "inputs")?;
        e.est.predict(u).map(|_| 0).map_err(|e| e.to_string())
    })
}

unsafe fn do_update(
    est: &mut Estimator,
    y: *const f64,
    present: *const u8,
    n: usize,
) -> Result<c_int, String> {
    let q = est.model().measurements.len();
    if y.is_null() {
        // No measurements at all this step.
        return est
            .update_with(|_| None)
            .map(|k| k as c_int)
            .map_err(|e| e.to_string());
    }
    if n != q {
        return Err(format!("measurements: expected length {q}, got {n}"));
    }
    let y = slice(y, n, "measurements")?;
    let present = if present.is_null() {
        None
    } else {
        Some(slice(present, n, "present")?)
    };
    est.update_with(|i| match present {
        Some(p) if p[i] == 0 => None,
        _ => Some(y[i]),
    })
    .map(|k| k as c_int)
    .map_err(|e| e.to_string())
}

/// Measurement update of the current phase. `y[i]` is channel i's world value; `present[i]`
/// = 0 marks it missing (`present` NULL: all present; `y` NULL: none). Returns the number of
/// values used (≥ 0) or -1. A non-finite present value is an error and leaves the state as is.
///
/// # Safety
/// `e` live estimator; `y` and `present` NULL or pointing to `n` elements.
#[no_mangle]
pub unsafe extern "C" fn crokf_update(
    e: *mut CrokfEstimator,
    y: *const f64,
    present: *const u8,
    n: usize,
) -> c_int {
    guard(-1, || do_update(&mut est_mut(e)?.est, y, present, n))
}

/// `crokf_predict` then `crokf_update`, all or nothing: returns the number of measurements
/// used, or -1 with the estimator exactly as before the call.
///
/// # Safety
/// As for `crokf_predict` and `crokf_update`.
#[no_mangle]
pub unsafe extern "C" fn crokf_step(
    e: *mut CrokfEstimator,
    inputs: *const f64,
    n_inputs: usize,
    y: *const f64,
    present: *const u8,
    n: usize,
) -> c_int {
    guard(-1, || {
        let est = &mut est_mut(e)?.est;
        let u = slice(inputs, n_inputs, "inputs")?;
        let get = measurement_getter(est, y, present, n)?;
        est.step_with(u, get)
            .map(|k| k as c_int)
            .map_err(|e| e.to_string())
    })
}

/// Sets the innovation gate to `sigmas` standard deviations of the innovation (default 5); a
/// value that is not finite and > 0 turns the gate off. Returns 0 or -1 (NULL handle).
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_set_innovation_gate(e: *mut CrokfEstimator, sigmas: f64) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.set_innovation_gate(Some(sigmas));
        Ok(0)
    })
}

/// Measurements skipped by the innovation gate since creation/reset; 0 on a NULL handle.
///
/// # Safety
/// `e` NULL or a live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_gated_count(e: *const CrokfEstimator) -> u64 {
    guard(0, || Ok(est_ref(e)?.est.gated_total()))
}

/// Back to rest (x = 0, step 0).
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_reset(e: *mut CrokfEstimator) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.reset();
        Ok(0)
    })
}

/// Step index k (number of predictions since creation/reset); 0 on a NULL handle.
///
/// # Safety
/// `e` NULL or a live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_step_index(e: *const CrokfEstimator) -> u64 {
    guard(0, || Ok(est_ref(e)?.est.step_index()))
}

/// Status of the co-rotational tier's last completed step (docs/design.md §10): Newton
/// iterations, the largest load ratio |f_g|/max_force_g and the state ratio ‖q‖/max training
/// ‖q‖ are written where the pointers are not NULL. Returns 1 when that step left the
/// training envelope, 0 when inside (and for the warped tier, with zeros), -1 on a NULL handle.
///
/// # Safety
/// `e` live estimator; each pointer NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn crokf_tier_status(
    e: *const CrokfEstimator,
    iterations: *mut usize,
    load_ratio: *mut f64,
    state_ratio: *mut f64,
) -> c_int {
    guard(-1, || {
        let status = est_ref(e)?.est.tier_status();
        // SAFETY: the caller passes NULL or writable pointers.
        unsafe {
            if !iterations.is_null() {
                *iterations = status.iterations;
            }
            if !load_ratio.is_null() {
                *load_ratio = status.envelope.load_ratio;
            }
            if !state_ratio.is_null() {
                *state_ratio = status.envelope.state_ratio;
            }
        }
        Ok(status.envelope.outside() as c_int)
    })
}

/// The co-rotational tier's force-σ level in use (docs/design.md §11.10): the level (0: the
/// designed σ), its factor on the designed σ and the innovation statistic T are written where
/// the pointers are not NULL. Returns 1 when the model has levels, 0 when it has one (nothing
/// written), -1 on a NULL handle.
///
/// # Safety
/// `e` live estimator; each pointer NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn crokf_force_level(
    e: *const CrokfEstimator,
    level: *mut usize,
    factor: *mut f64,
    statistic: *mut f64,
) -> c_int {
    guard(-1, || {
        let Some(l) = est_ref(e)?.est.force_level() else {
            return Ok(0);
        };
        // SAFETY: the caller passes NULL or writable pointers.
        unsafe {
            if !level.is_null() {
                *level = l.level;
            }
            if !factor.is_null() {
                *factor = l.factor;
            }
            if !statistic.is_null() {
                *statistic = l.statistic;
            }
        }
        Ok(1)
    })
}

/// Whether the force-σ level follows the innovations (`on` ≠ 0, the default) or stays at the
/// designed σ (`on` = 0); on before the first step after creation or reset, the run's first
/// update is made at the lowest level (docs/design.md §11.10). Returns 0, or -1 on a NULL
/// handle.
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_set_force_adaptation(e: *mut CrokfEstimator, on: c_int) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.set_force_adaptation(on != 0);
        Ok(0)
    })
}

/// Whether the co-rotational tier's filter carries its own covariance while an active channel
/// is missing or gated and after a lowering of the force-σ level (`on` ≠ 0, the default;
/// docs/design.md §11.10–11.11) or keeps the stored gains and σ (`on` = 0). Returns 0, or -1
/// on a NULL handle.
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_set_covariance_recursion(
    e: *mut CrokfEstimator,
    on: c_int,
) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.set_covariance_recursion(on != 0);
        Ok(0)
    })
}

/// Copies the co-rotational tier filter's own covariance P (n × n row-major, n =
/// `crokf_model_state_dim`; `len` = n²) while it carries one (docs/design.md §11.11). Returns
/// 1 when written, 0 when the stored filter's covariances are in use (nothing written), -1
/// (wrong length, NULL).
///
/// # Safety
/// `e` live estimator; `out` points to `len` writable doubles.
#[no_mangle]
pub unsafe extern "C" fn crokf_tier_covariance(
    e: *const CrokfEstimator,
    out: *mut f64,
    len: usize,
) -> c_int {
    guard(-1, || {
        let est = &est_ref(e)?.est;
        let out = slice_mut(out, len, "out")?;
        let n = est.state().len();
        if out.len() != n * n {
            return Err(format!(
                "tier covariance: expected length {}, got {len}",
                n * n
            ));
        }
        match est.tier_covariance() {
            Some(p) => {
                out.copy_from_slice(p);
                Ok(1)
            }
            None => Ok(0),
        }
    })
}

macro_rules! readout {
    ($(#[$doc:meta])* $name:ident, $method:ident) => {
        $(#[$doc])*
        /// Returns 0 or -1 (wrong length, NULL).
        ///
        /// # Safety
        /// `e` live estimator; `out` points to `len` writable doubles.
        #[no_mangle]
        pub unsafe extern "C" fn $name(e: *const CrokfEstimator, out: *mut f64, len: usize) -> c_int {
            guard(-1, || {
                let est = &est_ref(e)?.est;
                let out = slice_mut(out, len, "out")?;
                est.$method(out).map(|_| 0).map_err(|e| e.to_string())
            })
        }
    };
}

macro_rules! node_readout {
    ($(#[$doc:meta])* $name:ident, $method:ident) => {
        $(#[$doc])*
        /// `len` = 3 × nodes in the set. Returns 0 or -1.
        ///
        /// # Safety
        /// `e` live estimator; `out` points to `len` writable doubles.
        #[no_mangle]
        pub unsafe extern "C" fn $name(
            e: *const CrokfEstimator,
            set: usize,
            out: *mut f64,
            len: usize,
        ) -> c_int {
            guard(-1, || {
                let est = &est_ref(e)?.est;
                let out = slice_mut(out, len, "out")?;
                est.$method(set, out).map(|_| 0).map_err(|e| e.to_string())
            })
        }
    };
}

readout!(
    /// World displacement of every sensor, 3 per sensor (m); `len` = 3 × sensors.
    crokf_sensor_displacements, sensor_displacements);
readout!(
    /// Standard deviation of every sensor displacement, 3 per sensor (m).
    crokf_sensor_std, sensor_std);
readout!(
    /// Estimated world value of every measurement channel; `len` = q.
    crokf_measurement_estimates, measurement_estimates);
node_readout!(
    /// World displacements of node set `set`, 3 per node (m).
    crokf_node_displacements, node_displacements);
node_readout!(
    /// World positions X + u of node set `set`, 3 per node (m).
    crokf_node_positions, node_positions);
node_readout!(
    /// Standard deviations of node set `set`'s displacements, 3 per node (m).
    crokf_node_std, node_std);

/// Copies the state (length `crokf_model_state_dim`: x for the warped tier, (q, q̇, q̈, f) for
/// the co-rotational tier). Returns 0 or -1.
///
/// # Safety
/// `e` live estimator; `out` points to `len` writable doubles.
#[no_mangle]
pub unsafe extern "C" fn crokf_state(e: *const CrokfEstimator, out: *mut f64, len: usize) -> c_int {
    guard(-1, || {
        let est = &est_ref(e)?.est;
        let out = slice_mut(out, len, "out")?;
        if out.len() != est.state().len() {
            return Err(format!(
                "state: expected length {}, got {len}",
                est.state().len()
            ));
        }
        out.copy_from_slice(est.state());
        Ok(0)
    })
}

/// What [`crokf_tool_contact`] writes (header `CrokfToolContact`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct CrokfToolContact {
    /// Force of the body on the tool, N.
    pub force: [f64; 3],
    /// Torque of the body on the tool about its centre, N·m.
    pub torque: [f64; 3],
    /// The tool's 3×3 contact stiffness, row-major, N/m.
    pub stiffness: [f64; 9],
    /// σ of `force` per component, N (with `crokf_set_contact_force_std` on, else 0).
    pub force_std: [f64; 3],
    /// Deepest penetration of the free prediction into the tool, m.
    pub depth: f64,
    /// Region nodes pressing on the tool.
    pub active: u32,
    /// 0 free, 1 touching, 2 clamped at the force bound, 3 overflow, 4 not converged,
    /// 5 grasping.
    pub status: i32,
}

/// 1 when the model has a contact region (docs/contact.md), 0 when not or on a NULL handle.
///
/// # Safety
/// `m` NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_has_contact(m: *const CrokfModel) -> usize {
    guard(0, || {
        Ok(usize::from(
            model_ref(m)?.prepared.model().contact.is_some(),
        ))
    })
}

/// Why the model's co-rotational tier failed the compiler's own check (it was written all the
/// same: the scene set `accept_failed_check = true`; format v10, docs/model-format.md), or NULL
/// when the tier passed, the model has no tier, or the handle is NULL. The string lives as long
/// as the model handle.
///
/// # Safety
/// `m` NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn crokf_model_tier_failed_check(m: *const CrokfModel) -> *const c_char {
    guard(ptr::null(), || {
        Ok(model_ref(m)?
            .failed_check
            .as_ref()
            .map_or(ptr::null(), |s| s.as_ptr()))
    })
}

/// One step with `n_tools` (≤ 2) tools whose centres are `tools` (3 per tool, m, the model's
/// frame): prediction, contact, update, all or nothing as `crokf_step`. Returns the number of
/// measurements used, or -1 with the estimator exactly as before the call.
///
/// # Safety
/// As for `crokf_step`; `tools` holds 3 × `n_tools` doubles (or is NULL with `n_tools` 0).
#[no_mangle]
pub unsafe extern "C" fn crokf_step_with_tools(
    e: *mut CrokfEstimator,
    tools: *const f64,
    n_tools: usize,
    inputs: *const f64,
    n_inputs: usize,
    y: *const f64,
    present: *const u8,
    n: usize,
) -> c_int {
    guard(-1, || {
        let est = &mut est_mut(e)?.est;
        if n_tools > crate::MAX_TOOLS {
            return Err(format!(
                "{n_tools} tools given, the contact step takes at most {}",
                crate::MAX_TOOLS
            ));
        }
        let flat = slice(tools, 3 * n_tools, "tools")?;
        let mut centres = [[0.0; 3]; crate::MAX_TOOLS];
        for (t, c) in centres.iter_mut().take(n_tools).enumerate() {
            c.copy_from_slice(&flat[3 * t..3 * t + 3]);
        }
        let u = slice(inputs, n_inputs, "inputs")?;
        let get = measurement_getter(est, y, present, n)?;
        est.step_with_tools_with(&centres[..n_tools], u, get)
            .map(|k| k as c_int)
            .map_err(|e| e.to_string())
    })
}

/// The last contact step's result for tool `tool` into `out`. Returns 0, or -1 (NULL handle
/// or `out`, no contact step yet, or `tool` past the last step's tools).
///
/// # Safety
/// `e` live estimator; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn crokf_tool_contact(
    e: *const CrokfEstimator,
    tool: usize,
    out: *mut CrokfToolContact,
) -> c_int {
    guard(-1, || {
        let est = &est_ref(e)?.est;
        let out = out.as_mut().ok_or_else(|| "out is NULL".to_string())?;
        let t = est.tool_contact(tool).ok_or_else(|| {
            format!("no tool {tool} in the last contact step (crokf_step_with_tools)")
        })?;
        *out = CrokfToolContact {
            force: t.force,
            torque: t.torque,
            stiffness: t.stiffness,
            force_std: t.force_std,
            depth: t.depth,
            active: t.active as u32,
            status: match t.status {
                crate::ContactStatus::Free => 0,
                crate::ContactStatus::Touching => 1,
                crate::ContactStatus::Clamped => 2,
                crate::ContactStatus::Overflow => 3,
                crate::ContactStatus::NotConverged => 4,
                crate::ContactStatus::Grasping => 5,
            },
        };
        Ok(0)
    })
}

/// Tool `tool` (of the last tool step) grasps the contact-region node nearest its centre
/// (`Estimator::grasp`): writes the node's index into `node` and returns 0, or returns -1 and
/// changes nothing (NULL handle, no contact region, no such tool, no node near enough).
///
/// # Safety
/// `e` live estimator; `node` NULL or valid for one write.
#[no_mangle]
pub unsafe extern "C" fn crokf_grasp(
    e: *mut CrokfEstimator,
    tool: usize,
    node: *mut usize,
) -> c_int {
    guard(-1, || {
        let est = est_mut(e)?;
        let n = est.est.grasp(tool).map_err(|err| err.to_string())?;
        if !node.is_null() {
            *node = n;
        }
        Ok(0)
    })
}

/// Tool `tool` lets go of what it holds. Returns 0, or -1 on a NULL handle.
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_release(e: *mut CrokfEstimator, tool: usize) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.release(tool);
        Ok(0)
    })
}

/// Whether the contact step also computes each tool force's σ (`on` ≠ 0). Returns 0 or -1.
///
/// # Safety
/// `e` live estimator.
#[no_mangle]
pub unsafe extern "C" fn crokf_set_contact_force_std(e: *mut CrokfEstimator, on: c_int) -> c_int {
    guard(-1, || {
        est_mut(e)?.est.set_contact_force_std(on != 0);
        Ok(0)
    })
}
