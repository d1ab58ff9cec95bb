//! The report's notes on a co-rotational tier, built by the compile from the values
//! [`TierReductor`] returns (the reductor builds and measures; it writes no prose of its own
//! beyond its refusals and the notes on its training and size).

use crate::nonlinear::filter::SCHEDULE_POINTS;
use crate::reductor::tier::TierReductor;

/// The report's notes on the tier's basis, cubature and filter, from what the reductor built
/// and measured (after the reductor's own notes on its training and size).
pub(super) fn tier_notes(t: &TierReductor) -> Vec<String> {
    let (full, spec, plan, built, filter) = (t.full, t.spec, &t.plan, &t.tier, &t.filter);
    let (choice, ecsw) = &t.size;
    let mut notes = Vec::new();
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
