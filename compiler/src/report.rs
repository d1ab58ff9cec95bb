//! The compile report: what each stage decided and measured, with timings and peak memory.
//!
//! Written as JSON (`--report FILE.json`) and summarised on stderr. Wall-clock figures live here
//! only, never in the model file, so that the model file stays byte-identical across builds.

use crokf_formats as fmt;

use crate::nonlinear::self_check::SelfCheck;
pub use crate::timer::{StageCost, StageTimer};

/// Problem sizes, for the report.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Sizes {
    /// Mesh nodes.
    pub nodes: usize,
    /// Tetrahedra.
    pub tetrahedra: usize,
    /// Free DOFs n.
    pub dofs: usize,
    /// Deterministic input channels.
    pub inputs: usize,
    /// Process-noise channels.
    pub noise_channels: usize,
    /// Output rows seen by the balanced truncation.
    pub outputs: usize,
    /// Measurement channels.
    pub measurements: usize,
}

/// The JSON report of a compile: the model's report, sizes, per-stage costs and, for a
/// co-rotational tier, its self-check per training run (`tier_self_check`: threshold, worst,
/// median, runs with their error e_k, docs/design.md §10; a failed reduced run's error is null).
pub fn json(
    model: &fmt::Model,
    sizes: &Sizes,
    timer: &StageTimer,
    model_file_bytes: usize,
    self_check: Option<&SelfCheck>,
) -> String {
    let stages: Vec<serde_json::Value> = timer
        .order
        .iter()
        .map(|name| {
            let c = &timer.stages[name];
            serde_json::json!({
                "stage": name,
                "seconds": c.seconds,
                "peak_memory_mib": json_number(c.peak_memory_mib),
            })
        })
        .collect();
    let r = &model.report;
    let tier_self_check = self_check.map(|c| {
        serde_json::json!({
            "definition": "relative L2 error of the displacement in the M-norm over each training run's stored snapshots, the compiled reduced model (runtime Newton settings) re-run on the run's load history; in-sample",
            "threshold": c.threshold,
            "worst_run": c.worst().map(|w| w.label.clone()),
            "worst": c.worst().map(|w| json_number(w.error)),
            "median": json_number(c.median()),
            "flagged": c.flagged().len(),
            "unconverged_steps": c.unconverged(),
            "seconds": c.seconds,
            "runs": c.runs.iter().map(|run| serde_json::json!({
                "label": run.label,
                "error": json_number(run.error),
                "scale_m_norm": run.scale,
                "snapshots": run.snapshots,
                "steps": run.steps,
                "iterations": run.iterations,
                "unconverged": run.unconverged,
                "failure": run.failure,
            })).collect::<Vec<_>>(),
        })
    });
    let value = serde_json::json!({
        "compiler_version": model.inputs_digest.compiler_version,
        "inputs_digest": {
            "mesh_sha256": model.inputs_digest.mesh_sha256,
            "scene_sha256": model.inputs_digest.scene_sha256,
        },
        "sizes": sizes,
        "model_file_bytes": model_file_bytes,
        "reduction": {
            "order": r.order,
            "modes": r.modes,
            "hankel_singular_values": r.hankel_singular_values,
            "error_bound": r.error_bound,
            "relative_error_bound": r.error_bound / r.hankel_singular_values.first().copied().unwrap_or(f64::NAN),
            "highest_kept_frequency_hz": r.highest_kept_frequency_hz,
            "nyquist_hz": r.nyquist_hz,
            "spectral_radius": r.spectral_radius,
        },
        "kalman": {
            "period": model.kalman.period,
            "riccati_relative_residual": json_number(r.riccati_residual),
            "closed_loop_spectral_radius": json_number(r.closed_loop_spectral_radius),
        },
        "measured_errors": r.measured_errors,
        "stages": stages,
        "total_seconds": timer.total_seconds(),
        "peak_memory_mib": json_number(timer.peak_memory_mib()),
        "notes": r.notes,
        "tier_self_check": tier_self_check,
    });
    serde_json::to_string_pretty(&value).unwrap_or_default() + "\n"
}

/// A readable summary of a compile, for stderr.
pub fn summary(model: &fmt::Model, sizes: &Sizes, timer: &StageTimer) -> String {
    use std::fmt::Write;
    let r = &model.report;
    let s = &sizes;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "mesh: {} nodes, {} tetrahedra, {} free DOFs; {} inputs, {} noise channels, {} outputs, {} measurements",
        s.nodes, s.tetrahedra, s.dofs, s.inputs, s.noise_channels, s.outputs, s.measurements
    );
    let _ = writeln!(
        out,
        "modes: {} vibration modes kept (+ static correction), highest {:.3} Hz (Nyquist {:.3} Hz)",
        r.modes, r.highest_kept_frequency_hz, r.nyquist_hz
    );
    let hsv: Vec<String> = r
        .hankel_singular_values
        .iter()
        .take(12)
        .map(|v| format!("{v:.3e}"))
        .collect();
    let _ = writeln!(out, "Hankel singular values: {} …", hsv.join(" "));
    let sigma1 = r
        .hankel_singular_values
        .first()
        .copied()
        .unwrap_or(f64::NAN);
    let _ = writeln!(
        out,
        "balanced truncation: r = {}, bound 2Σσ(i>r) = {:.3e} ({:.2e} of σ₁), ρ(F) = {:.9}",
        r.order,
        r.error_bound,
        r.error_bound / sigma1,
        r.spectral_radius
    );
    let _ = writeln!(
        out,
        "kalman: period {}, Riccati relative residual {:.2e}, ρ((I−KH)F) = {:.9}",
        model.kalman.period, r.riccati_residual, r.closed_loop_spectral_radius
    );
    for (name, value) in &r.measured_errors {
        let _ = writeln!(out, "measured error {name}: {value:.3e}");
    }
    for name in &timer.order {
        let c = &timer.stages[name];
        let _ = writeln!(
            out,
            "  {name:<20} {:>9.3} s  {:>9.1} MiB peak",
            c.seconds, c.peak_memory_mib
        );
    }
    // Notes are diagnostics: they name the running binary like its warnings and errors
    // (`crokf-compile: note: …`); the lines above are the summary itself.
    let program = crate::progress::program();
    for note in &r.notes {
        let _ = writeln!(out, "{program}: note: {note}");
    }
    out
}

fn json_number(v: f64) -> serde_json::Value {
    serde_json::Number::from_f64(v).map_or(serde_json::Value::Null, serde_json::Value::Number)
}
