//! The report's notes and terminal lines on a co-rotational tier, built by the compile from
//! the values [`TierReductor`] returns (the reductor builds and measures; it writes no prose
//! of its own beyond its refusals).

use crokf_formats as fmt;

use crate::nonlinear::filter::SCHEDULE_POINTS;
use crate::reductor::tier::findings::{CacheUse, CutRun, OrderAboveSnapshots, TierFindings};
use crate::reductor::tier::TierReductor;

/// The lines on what a case cache contributed to the training, for the terminal: a
/// `warning: …` per case file that could not be used or stored, then a `note: …` on the runs
/// read from it.
pub fn cache_lines(cache: &CacheUse) -> Vec<String> {
    let mut lines: Vec<String> = cache
        .unusable
        .iter()
        .map(|note| format!("warning: {note}"))
        .collect();
    lines.push(format!(
        "note: co-rotational training: {} of {} cases read from the cache {}",
        cache.cached,
        cache.runs,
        cache.dir.display()
    ));
    lines
}

/// The report's notes on the tier: what its training found, the fidelity rule's choice and
/// an accepted failed check first, then its basis, cubature and filter, from what the
/// reductor built and measured.
pub(super) fn tier_notes(t: &TierReductor) -> Vec<String> {
    let (full, spec, plan, built, filter) = (t.full, t.spec, &t.plan, &t.tier, &t.filter);
    let (choice, ecsw) = &t.size;
    let mut notes = training_notes(&t.findings);
    notes.extend(t.fidelity.as_ref().map(|f| f.note()));
    notes.extend(t.failed_check.as_deref().map(accepted_failed_check_note));
    let env = &built.training.envelope;
    let r = built.model.order();
    if let (Some(eps), Some((added, worst))) = (spec.basis_tolerance, built.enrichment) {
        notes.push(format!(
            "co-rotational tier basis: {} pooled POD vectors + {added} added for the per-run \
             tolerance {eps:e} in the energy norm; worst training run {worst:.2e}{} (r ≤ {})",
            r - added,
            if worst > eps {
                ", NOT reached: max_order stopped the enrichment"
            } else {
                ""
            },
            spec.largest_order()
        ));
    }
    if choice.tolerance.is_none() && r < choice.order {
        notes.push(format!(
            "WARNING: co-rotational tier order {} asked, r = {r} given: the {} training \
             snapshots span only {r} independent directions. More snapshots (a smaller \
             [reduction.corotational] every = {}, or longer training) or a smaller order \
             remove this warning",
            choice.order, env.snapshots, spec.every
        ));
    }
    notes.push(format!(
        "co-rotational tier: r = {r} POD vectors of {} training snapshots ({} of {} runs), {} \
         sampled elements of {} (ECSW residual {:.2e}, tolerance {:.0e}); envelope: {}",
        env.snapshots,
        env.runs.0,
        env.runs.1,
        built.model.cubature.len(),
        full.fem.elements.len(),
        built.sampling.relative_residual,
        ecsw.tolerance,
        plan.ranges
            .iter()
            .enumerate()
            .map(|(g, (n, _))| format!("{n} ≤ {:.4} N", plan.max_force(g)))
            .collect::<Vec<_>>()
            .join(", ")
    ));
    let (residual, sampled) = (built.sampling.relative_residual, built.model.cubature.len());
    if residual > ecsw.tolerance {
        notes.push(format!(
            "WARNING: the tier's cubature (ECSW) stopped at {sampled} sampled elements with \
             a relative residual {residual:.2e} above its tolerance {:.0e}: the reduced \
             forces are less accurate than asked. Raise [reduction.corotational] \
             ecsw_max_elements (now {}) or loosen ecsw_tolerance",
            ecsw.tolerance, ecsw.max_elements
        ));
    }
    notes.push(format!(
        "co-rotational tier filter (linearised at rest, state (q, q̇, q̈, f[, ḟ]) = {}, {} force \
         (and rate) states): closed-loop spectral radius {:.6}, Riccati residual {:.1e}, static residual \
         of the force channels at the markers {:.1e}; gain schedule: {} of {} operating points \
         (training states, ‖q*‖ {:.3e} … {:.3e})",
        filter.schedule.phases[0].gain.nrows(),
        filter.schedule.phases[0].gain.nrows() - 3 * r,
        filter.schedule.closed_loop_spectral_radius,
        filter.schedule.worst_relative_residual,
        filter.static_residual,
        filter.scheduled.len(),
        SCHEDULE_POINTS,
        filter
            .scheduled
            .iter()
            .map(|(q, _, _)| q.norm())
            .fold(f64::INFINITY, f64::min),
        filter
            .scheduled
            .iter()
            .map(|(q, _, _)| q.norm())
            .fold(0.0, f64::max)
    ));
    notes.extend(t.derived.iter().map(|d| {
        format!(
            "co-rotational tier: {}",
            d.note(&full.scene.scene.loads[d.load].name)
        )
    }));
    if let Some(a) = &filter.adaptation {
        let mut factors: Vec<f64> = std::iter::once(1.0)
            .chain(filter.levels.iter().map(|l| l.factor))
            .collect();
        factors.sort_by(|a, b| b.total_cmp(a));
        notes.push(format!(
            "co-rotational tier force σ levels (docs/design.md §11.10): × {} the designed \
             σ, chosen at run time from the whitened innovations averaged over {} steps \
             (the shortest rise time): one level up when the statistic exceeds {:.2}; \
             checked every {} steps, one down when it is below {:.2}, below the designed σ \
             only while every estimated load is told ({:.1} effective channels)",
            factors
                .iter()
                .map(|f| format!("{f}"))
                .collect::<Vec<_>>()
                .join(", "),
            a.window,
            a.raise_above,
            a.window,
            a.lower_below,
            a.effective_channels
        ));
    }
    notes.extend(
        filter
            .level_notes
            .iter()
            .map(|n| format!("WARNING: co-rotational tier: {n}")),
    );
    if let Some(s) = &filter.model_error {
        let largest = t.check.largest_scale();
        notes.push(format!(
            "co-rotational tier model error as process noise (docs/design.md §11.9): the \
             reduced model's error inside its basis over the training runs, RMS ‖q − VᵀMu‖ \
             {:.3e} kg^½·m{}, per mode as a white modal force whose open-loop variance \
             equals the measured one{}",
            s.trace().max(0.0).sqrt(),
            if largest > 0.0 {
                format!(
                    " ({:.2} % of the largest run's RMS ‖u‖_M)",
                    100.0 * s.trace().max(0.0).sqrt() / largest
                )
            } else {
                String::new()
            },
            {
                let c = t.full.noise.model_error_scale;
                if c == 0.0 {
                    "; the scene's model_error_scale = 0 leaves it out of the filter".into()
                } else if c != crate::scene::DEFAULT_MODEL_ERROR_SCALE {
                    format!(", × the scene's model_error_scale = {c}")
                } else {
                    String::new()
                }
            }
        ));
    }
    notes.push(format!(
        "co-rotational tier model error at the markers (basis projection of the training \
         snapshots, RMS per channel in units of the channel's σ): largest {:.2e}, median {:.2e} \
         (not added to R: against the markers' own noise it is negligible below ≈ 0.1)",
        filter
            .marker_model_error
            .iter()
            .copied()
            .fold(0.0, f64::max),
        {
            let mut e = filter.marker_model_error.clone();
            e.sort_by(f64::total_cmp);
            e.get(e.len() / 2).copied().unwrap_or(0.0)
        }
    ));
    notes
}

/// The report's notes on what the tier's training found: loads with a range that no run
/// loads, failed runs, cut runs, and a stated order above the snapshots kept, in that order.
fn training_notes(findings: &TierFindings) -> Vec<String> {
    let mut notes: Vec<String> = findings
        .untrained_loads
        .iter()
        .map(|name| {
            format!(
                "co-rotational tier: load '{name}' has a range but no training case loads \
                 it: the tier is not trained on it, and the runtime reports it outside the \
                 envelope when it is loaded (add it to a [[reduction.corotational.case]])"
            )
        })
        .collect();
    notes.extend(findings.failed_runs.iter().map(|run| {
        format!(
            "co-rotational training run '{}' failed and was skipped: {}",
            run.label, run.reason
        )
    }));
    notes.extend(cut_note(
        &findings.cut_runs,
        findings.runs,
        findings.max_rotation,
    ));
    notes.extend(
        findings
            .order_above_snapshots
            .as_ref()
            .map(order_above_snapshots_note),
    );
    notes
}

/// The report's note on the training runs cut where their load drove the body past what the
/// tier is for (an inverted element, or an element rotated past `max_rotation` degrees): how
/// many of the `runs`, and the ones cut at the smallest multiple of their range first. None:
/// no run was cut.
fn cut_note(cut_runs: &[CutRun], runs: usize, max_rotation: f64) -> Option<String> {
    if cut_runs.is_empty() {
        return None;
    }
    let mut cut: Vec<&CutRun> = cut_runs.iter().collect();
    cut.sort_by(|a, b| a.cut.multiple.total_cmp(&b.cut.multiple));
    const LISTED: usize = 3;
    let listed: Vec<String> = cut
        .iter()
        .take(LISTED)
        .map(|CutRun { label, cut: c }| {
            format!(
                "'{label}' at t = {} s ({:.3}× its range): {}, {} of {} snapshots kept",
                c.time, c.multiple, c.reason, c.kept, c.of
            )
        })
        .collect();
    let more = match cut.len().saturating_sub(LISTED) {
        0 => String::new(),
        n => format!("; and {n} more"),
    };
    Some(format!(
        "co-rotational training: {} of {runs} runs were cut at their first snapshot that inverts \
         an element or rotates one past max_rotation = {max_rotation}°, and the tier is not \
         trained on their loads past that point: {}{more}",
        cut.len(),
        listed.join("; ")
    ))
}

/// The report's warning on a tier order above the snapshots the training kept.
fn order_above_snapshots_note(o: &OrderAboveSnapshots) -> String {
    let stated = if o.stated {
        format!("[reduction.corotational] order = {}", o.order)
    } else {
        format!("the tier's order {} (not stated: the default)", o.order)
    };
    format!(
        "WARNING: {stated} is above the {} snapshots the training kept ({} of its {} runs cut \
         or failed): the basis has at most {} vectors. Lengthen the runs (duration) or lower \
         `every` for more snapshots, or lower `order`",
        o.kept, o.cut_or_failed, o.runs, o.kept
    )
}

/// The report's error note on a tier written although it fails its own check, `why`
/// (`[reduction.corotational] accept_failed_check = true`).
fn accepted_failed_check_note(why: &str) -> String {
    format!(
        "ERROR: {why}; written all the same because [reduction.corotational] \
         accept_failed_check = true: loads like its training runs will be this far off \
         at run time; the model file says so (format v{}), and the runtime and \
         crokf-run report it on loading",
        fmt::FAILED_CHECK_FORMAT_VERSION
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonlinear::training::Cut;
    use crate::reductor::tier::findings::FailedRun;

    fn cut(label: &str, multiple: f64, time: f64) -> CutRun {
        CutRun {
            label: label.into(),
            cut: Cut {
                kept: 3,
                of: 10,
                time,
                multiple,
                reason: "inverts 1 element".into(),
            },
        }
    }

    /// The training notes in their order (untrained loads, failed runs, cut runs, the order
    /// above the snapshots), the cut runs listed at the smallest multiple first, three of them
    /// and a count of the rest.
    #[test]
    fn training_notes_name_each_finding_in_order() {
        let findings = TierFindings {
            untrained_loads: vec!["mid".into()],
            failed_runs: vec![FailedRun {
                label: "push (+1, +0, +0) step 0.6×".into(),
                reason: "Newton did not converge".into(),
            }],
            cut_runs: vec![
                cut("a", 0.9, 0.3),
                cut("b", 0.5, 0.1),
                cut("c", 1.1, 0.4),
                cut("d", 0.75, 0.2),
            ],
            runs: 10,
            max_rotation: 60.0,
            order_above_snapshots: Some(OrderAboveSnapshots {
                order: 40,
                stated: false,
                kept: 12,
                cut_or_failed: 5,
                runs: 10,
            }),
        };
        assert_eq!(
            training_notes(&findings),
            [
                "co-rotational tier: load 'mid' has a range but no training case loads it: the \
                 tier is not trained on it, and the runtime reports it outside the envelope when \
                 it is loaded (add it to a [[reduction.corotational.case]])",
                "co-rotational training run 'push (+1, +0, +0) step 0.6×' failed and was \
                 skipped: Newton did not converge",
                "co-rotational training: 4 of 10 runs were cut at their first snapshot that \
                 inverts an element or rotates one past max_rotation = 60°, and the tier is not \
                 trained on their loads past that point: 'b' at t = 0.1 s (0.500× its range): \
                 inverts 1 element, 3 of 10 snapshots kept; 'd' at t = 0.2 s (0.750× its \
                 range): inverts 1 element, 3 of 10 snapshots kept; 'a' at t = 0.3 s (0.900× \
                 its range): inverts 1 element, 3 of 10 snapshots kept; and 1 more",
                "WARNING: the tier's order 40 (not stated: the default) is above the 12 \
                 snapshots the training kept (5 of its 10 runs cut or failed): the basis has at \
                 most 12 vectors. Lengthen the runs (duration) or lower `every` for more \
                 snapshots, or lower `order`",
            ]
        );
        assert!(training_notes(&TierFindings::default()).is_empty());
    }

    /// A stated order is named as the scene's field.
    #[test]
    fn a_stated_order_is_named_as_the_field() {
        let note = order_above_snapshots_note(&OrderAboveSnapshots {
            order: 100,
            stated: true,
            kept: 2,
            cut_or_failed: 4,
            runs: 4,
        });
        assert!(
            note.starts_with("WARNING: [reduction.corotational] order = 100 is above the 2 "),
            "{note}"
        );
    }

    /// The cache's lines: a warning per unusable case file, then the count read.
    #[test]
    fn cache_lines_warn_then_count() {
        let lines = cache_lines(&CacheUse {
            unusable: vec!["case file x: unreadable".into()],
            cached: 3,
            runs: 8,
            dir: "/tmp/cases".into(),
        });
        assert_eq!(
            lines,
            [
                "warning: case file x: unreadable",
                "note: co-rotational training: 3 of 8 cases read from the cache /tmp/cases",
            ]
        );
    }
}
