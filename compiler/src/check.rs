//! `crokf-compile --check`: is a committed model file current with its scene, mesh and
//! compiler? The scene and mesh are read once; the recompile reuses that front end.

use std::path::Path;

use crokf_formats as fmt;

use crate::compile::{compile_reduced, CompileOptions};
use crate::error::CompileError;
use crate::full_order::{FullOrder, COMPILER_VERSION};
use crate::reductor::Reductor;
use crate::timer::StageTimer;

/// Result of `crokf-compile --check`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CheckOutcome {
    /// The model's input digest matches the scene, mesh and compiler version.
    UpToDate,
    /// It does not; the reason names what changed.
    Stale(String),
}

/// Relative tolerance of [`check`]'s numerical comparison of a recompiled model.
pub const CHECK_TOLERANCE: f64 = 1e-6;

/// Checks a committed model file against its scene: the input digest (scene bytes, mesh bytes,
/// compiler version) must match, and recompiling with the model's own order must give the same
/// file — byte for byte, or (another CPU may round differently) every matrix equal to
/// [`CHECK_TOLERANCE`] relative to its largest entry.
pub fn check(model_path: &Path, scene_path: &Path) -> Result<CheckOutcome, CompileError> {
    let bytes = std::fs::read(model_path).map_err(|source| CompileError::Io {
        path: model_path.to_owned(),
        source,
    })?;
    let model = match fmt::decode(&bytes) {
        Ok(m) => m,
        Err(e) => {
            return Ok(CheckOutcome::Stale(format!(
                "the model file does not decode: {e}"
            )))
        }
    };
    let mut timer = StageTimer::default();
    let full = FullOrder::build(scene_path, &mut timer)?;
    let d = &model.inputs_digest;
    let fresh_digest = full.digest();
    let mut why = Vec::new();
    if d.scene_sha256 != fresh_digest.scene_sha256 {
        let lists: Vec<String> = full
            .node_lists
            .iter()
            .map(|(p, _)| p.display().to_string())
            .collect();
        why.push(if lists.is_empty() {
            format!("{} changed", scene_path.display())
        } else {
            format!(
                "{} or its node lists ({}) changed",
                scene_path.display(),
                lists.join(", ")
            )
        });
    }
    if d.mesh_sha256 != fresh_digest.mesh_sha256 {
        why.push(format!("{} changed", full.scene.mesh_path().display()));
    }
    if d.compiler_version != COMPILER_VERSION {
        why.push(format!(
            "compiled by {}, this is {COMPILER_VERSION}",
            d.compiler_version
        ));
    }
    if !why.is_empty() {
        return Ok(CheckOutcome::Stale(why.join("; ")));
    }
    let options = CompileOptions {
        // The balanced order: r() also counts the random-walk force states appended after
        // the truncation (docs/design.md §11).
        order: Some(model.report.order as usize),
        skip_measured_error: model.report.measured_errors.is_empty(),
        ..CompileOptions::default()
    };
    let reductor = Reductor::new(&full, options.modes, &mut timer)?;
    let fresh = compile_reduced(&reductor, &options, timer)?;
    if fresh.bytes == bytes {
        return Ok(CheckOutcome::UpToDate);
    }
    Ok(match model_difference(&model, &fresh.model) {
        None => CheckOutcome::UpToDate,
        Some(what) => CheckOutcome::Stale(format!("recompiling gives a different model: {what}")),
    })
}

/// The first difference between two models beyond [`CHECK_TOLERANCE`], if any.
fn model_difference(a: &fmt::Model, b: &fmt::Model) -> Option<String> {
    if a.state_dim != b.state_dim
        || a.inputs != b.inputs
        || a.measurements != b.measurements
        || a.sensors.len() != b.sensors.len()
        || a.node_sets.len() != b.node_sets.len()
        || a.kalman.phases.len() != b.kalman.phases.len()
    {
        return Some("state dimension, channels, sensors, node sets or Kalman phases".into());
    }
    let mut pairs: Vec<(String, &fmt::Matrix, &fmt::Matrix)> = vec![
        ("F".into(), &a.transition, &b.transition),
        ("G".into(), &a.input, &b.input),
        ("Q".into(), &a.kalman.process_noise, &b.kalman.process_noise),
    ];
    for (s, t) in a.sensors.iter().zip(&b.sensors) {
        pairs.push((
            format!("sensor '{}' rows", s.name),
            &s.displacement_rows,
            &t.displacement_rows,
        ));
    }
    for (s, t) in a.node_sets.iter().zip(&b.node_sets) {
        pairs.push((
            format!("node set '{}' rows", s.name),
            &s.displacement_rows,
            &t.displacement_rows,
        ));
    }
    for (i, (p, q)) in a.kalman.phases.iter().zip(&b.kalman.phases).enumerate() {
        pairs.push((format!("Kalman gain of phase {i}"), &p.gain, &q.gain));
    }
    pairs.into_iter().find_map(|(name, x, y)| {
        if x.shape() != y.shape() {
            return Some(format!("{name}: shape {:?} vs {:?}", x.shape(), y.shape()));
        }
        let scale = x
            .data
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
            .max(f64::MIN_POSITIVE);
        let worst = x
            .data
            .iter()
            .zip(&y.data)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        (worst > CHECK_TOLERANCE * scale).then(|| {
            format!(
                "{name} differs by {:.2e} of its largest entry",
                worst / scale
            )
        })
    })
}
