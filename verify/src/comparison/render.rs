// Over 800 lines, one job: the report's Markdown, CSV and SVG rendering of one comparison; 40 lines are tests.
//! Rendering of a comparison: Markdown table, CSV and an SVG plot of step time against error.

use std::fmt::Write as _;

use crate::bench::STEP_CLOCK;

use super::advice::{self, AdviceFigures, Context, Tier};
use super::segments::{segment_figures, SegmentFigures, MERGE_STEPS};
use super::{
    breakdown_rotation, breakdown_rotation_of, spread, verdict, ChiSquare, Comparison, Consistency,
    Ensemble, RowFigures, RuntimeFigures, SeedEnsemble, SweepPoint, TierPoint,
};

/// The sweep as a markdown table, with the 2 %, 5 % and 10 % breakdown rotations of the warped
/// runtime; with a tier, its open-loop error per scale (marked where the runtime reported the
/// loads or the state outside the training envelope) and its 2 % and 5 % rotations.
pub fn sweep_markdown(points: &[SweepPoint], order: usize) -> String {
    let mut out = String::new();
    let has_tier = points.iter().any(|p| p.tier.is_some());
    let _ = writeln!(
        out,
        "| load scale | max rotation (°) | runtime r = {order} open-loop error | tip error | linear FEM error |{}",
        if has_tier {
            " co-rotational tier open-loop error | tier tip error | training envelope (largest load ratio, state ratio) |"
        } else {
            ""
        }
    );
    let _ = writeln!(
        out,
        "|---:|---:|---:|---:|---:|{}",
        if has_tier { "---:|---:|---|" } else { "" }
    );
    for p in points {
        let tier = match &p.tier {
            None if has_tier => " — | — | — |".to_owned(),
            None => String::new(),
            Some(TierPoint::Failed(why)) => {
                format!(" failed | — | {} |", why.replace('|', "/"))
            }
            Some(TierPoint::Ran {
                open_loop_error,
                tip_error,
                envelope,
            }) => format!(
                " {} | {} | {} ({:.2}, {:.2}) |",
                sci(*open_loop_error),
                sci(*tip_error),
                if envelope.outside() {
                    format!(
                        "**outside** ({} of {} steps)",
                        envelope.steps_outside, envelope.steps
                    )
                } else {
                    "inside".to_owned()
                },
                envelope.max_load_ratio,
                envelope.max_state_ratio
            ),
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |{tier}",
            p.scale,
            degrees(p.max_rotation_deg),
            sci(p.open_loop_error),
            sci(p.tip_error),
            sci(p.linear_error)
        );
    }
    let up_to = |d: Option<f64>| {
        d.map_or("— (not even the smallest load)".to_owned(), |d| {
            format!("{d:.1}° of rotation")
        })
    };
    for t in [0.02, 0.05, 0.10] {
        let _ = writeln!(
            out,
            "\nopen-loop error < {:.0} % up to {}",
            100.0 * t,
            up_to(breakdown_rotation(points, t))
        );
    }
    if has_tier {
        for t in [0.02, 0.05] {
            let tier_error =
                |p: &SweepPoint| p.tier.as_ref().map_or(f64::NAN, |t| t.open_loop_error());
            let reached = breakdown_rotation_of(points, t, tier_error);
            // Whether the last point under the threshold was itself beyond training.
            let beyond = reached.is_some_and(|d| {
                points.iter().any(|p| {
                    p.max_rotation_deg == d
                        && matches!(&p.tier, Some(TierPoint::Ran { envelope, .. }) if envelope.outside())
                })
            });
            let _ = writeln!(
                out,
                "\nco-rotational tier open-loop error < {:.0} % up to {}{}",
                100.0 * t,
                up_to(reached),
                if beyond {
                    " (that point lies outside the training envelope)"
                } else if reached.is_some()
                    && reached
                        == points
                            .iter()
                            .map(|p| p.max_rotation_deg)
                            .max_by(f64::total_cmp)
                {
                    " (the largest rotation of the sweep)"
                } else {
                    ""
                }
            );
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Rendering

/// Seconds with an SI prefix: `1.23 µs`, `45.6 ms`.
pub fn format_seconds(s: f64) -> String {
    if !s.is_finite() {
        return "—".into();
    }
    let (v, unit) = if s < 1e-6 {
        (s * 1e9, "ns")
    } else if s < 1e-3 {
        (s * 1e6, "µs")
    } else if s < 1.0 {
        (s * 1e3, "ms")
    } else {
        (s, "s")
    };
    let digits = if v >= 100.0 {
        0
    } else if v >= 10.0 {
        1
    } else {
        2
    };
    format!("{v:.digits$} {unit}")
}

/// 10^d seconds as a tick label: `1 µs`, `10 µs`, `100 µs`, `1 ms`, … (d from −9 to 2;
/// `1e{d} s` outside).
pub(super) fn decade_seconds(d: i32) -> String {
    let units = ["ns", "µs", "ms", "s"];
    if !(-9..=2).contains(&d) {
        return format!("1e{d} s");
    }
    let k = (d + 9) / 3;
    let mantissa = 10i32.pow(((d + 9) % 3) as u32);
    format!("{mantissa} {}", units[k as usize])
}

/// Degrees with one decimal, or two significant digits below 0.1°.
fn degrees(v: f64) -> String {
    if v.abs() >= 0.1 || v == 0.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.1e}")
    }
}

fn sci(v: f64) -> String {
    if v.is_nan() {
        "—".into()
    } else if v == 0.0 {
        "0".into()
    } else {
        format!("{v:.2e}")
    }
}

fn ratio(a: f64, b: f64) -> String {
    let r = a / b;
    if !r.is_finite() {
        "—".into()
    } else if r >= 100.0 {
        format!("{r:.0}×")
    } else if r >= 1.0 {
        format!("{r:.1}×")
    } else {
        format!("{r:.2}×")
    }
}

/// A fraction as `93.4 %`; `—` when not finite.
fn percent(v: f64) -> String {
    if v.is_finite() {
        format!("{:.1} %", 100.0 * v)
    } else {
        "—".into()
    }
}

/// The 12 consistency fields of a CSV line (the header's `anis` … `withheld_coverage_world`)
/// for the filtered run `given` and the run with the loads withheld `withheld`.
fn csv_consistency(given: &Consistency, withheld: &Consistency) -> String {
    let (nis_lo, nis_hi) = given.nis.bounds();
    let (nees_lo, nees_hi) = given.nees_tip.bounds();
    [
        given.nis.mean(),
        nis_lo,
        nis_hi,
        given.nees_tip.mean(),
        nees_lo,
        nees_hi,
        given.coverage_runtime,
        given.coverage_world,
        withheld.nis.mean(),
        withheld.nees_tip.mean(),
        withheld.coverage_runtime,
        withheld.coverage_world,
    ]
    .map(csv_number)
    .join(",")
}

fn csv_number(v: f64) -> String {
    if v.is_finite() {
        format!("{v:e}")
    } else {
        String::new()
    }
}

impl Comparison {
    /// How the full-order references were stepped, in words.
    fn reference_stepping(&self) -> String {
        match self.substeps {
            0 | 1 => "Wilson-θ at Δt: the same scheme as a Wilson-θ model, so its rows show \
                      the reduction's error and not the time step's (`--substeps 32` for the \
                      response converged in time)"
                .into(),
            n => format!(
                "converged in time: Wilson-θ at Δt/{n}, each step's load held over its \
                 sub-steps and the acceleration restarted at each step"
            ),
        }
    }

    /// The table: one row per full-order model and per runtime order.
    pub fn markdown(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "Scene `{}`, scenario `{}`: {} free DOFs, {} tetrahedra, {} steps of Δt = {} s; \
             largest rotation in the co-rotational reference {:.1}° (t = {:.3} s).",
            self.scene.display(),
            self.scenario.display(),
            self.dofs,
            self.tetrahedra,
            self.steps,
            self.dt,
            self.max_rotation_deg,
            self.max_rotation_time
        );
        let _ = writeln!(
            out,
            "\nErrors: relative L2 over the {} displayed nodes and the whole trajectory, world \
             frame, against the co-rotational full-order reference ({}); tip error at sensor `{}`. \
             Filtered: measurements = reference sensor displacements + Gaussian noise \
             (noise_std, seed {:#x}){}. Runtime step = predict + update, median of batches \
             in {STEP_CLOCK} (the runtime steps on one thread: jobs sharing the machine do not \
             count); full-order step = median wall time over the run (its sparse solver may \
             use several threads).\n",
            self.displayed_nodes,
            self.reference_stepping(),
            self.tip.as_deref().unwrap_or("—"),
            self.seed,
            if self.withheld_loads {
                "; the filter got NO load inputs (loads withheld), the open-loop rows ran with \
                 the scenario's loads (without inputs or measurements the runtime stays at rest)"
            } else {
                ""
            }
        );
        let _ = writeln!(
            out,
            "| model | r | step time (runtime: {STEP_CLOCK}) | speed-up vs co-rotational FEM | speed-up vs linear FEM | relative L2 error | tip error | filtered error |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|");
        let c = self.corotational.step_s;
        let l = self.linear.step_s;
        let _ = writeln!(
            out,
            "| co-rotational FEM (reference) | n = {} | {} | 1× | {} | 0 | 0 | — |",
            self.dofs,
            format_seconds(c),
            ratio(l, c)
        );
        let _ = writeln!(
            out,
            "| linear FEM | n = {} | {} | {} | 1× | {} | {} | — |",
            self.dofs,
            format_seconds(l),
            ratio(c, l),
            sci(self.linear.error),
            sci(self.linear.tip_error)
        );
        for row in &self.reduced {
            let balanced = row.order - row.force_states;
            let r = if balanced == row.requested_order {
                balanced.to_string()
            } else {
                format!("{balanced} (asked {})", row.requested_order)
            };
            let r = if row.force_states > 0 {
                format!("{r} + {} force", row.force_states)
            } else {
                r
            };
            self.speed_row(&mut out, "runtime", &r, &row.figures.runtime);
        }
        for failure in &self.failures {
            let _ = writeln!(
                out,
                "| runtime | {} | failed | — | — | — | — | — |",
                failure.order
            );
        }
        if let Some(t) = &self.tier {
            self.speed_row(
                &mut out,
                "co-rotational tier",
                &tier_order(t),
                &t.figures.runtime,
            );
        } else if self.tier_failure.is_some() {
            let _ = writeln!(
                out,
                "| co-rotational tier | — | failed | — | — | — | — | — |"
            );
        }
        if !self.reduced.is_empty() || self.tier.is_some() {
            let _ = writeln!(
                out,
                "\nFilter with the loads given and withheld (the runtime gets only the markers), \
                 and its consistency (docs/design.md §11): ANIS = Σ NIS / Σ m over the run, \
                 ANEES = Σ NEES / 3N at the tip marker, each with its two-sided 95 % χ² bounds; \
                 2σ coverage = fraction of displayed-node error components inside ±2σ, σ from \
                 the runtime's read-out (local frame on the warped rows) / rotated to the world \
                 frame; the co-rotational tier's from its own stored filters (the gain \
                 schedule's filter in use at each step, world frame: both coverages agree).\n"
            );
            let _ = writeln!(
                out,
                "| r | loads | filtered error | tip error | ANIS [95 % bounds] | ANEES tip [95 % bounds] | 2σ coverage runtime σ / world σ |"
            );
            let _ = writeln!(out, "|---:|---|---:|---:|---:|---:|---:|");
            for row in &self.reduced {
                self.filter_rows(
                    &mut out,
                    &(row.order - row.force_states).to_string(),
                    &row.figures,
                );
            }
            if let Some(t) = &self.tier {
                self.filter_rows(&mut out, &format!("tier {}", tier_order(t)), &t.figures);
            }
            self.ensemble_table(&mut out);
            self.segment_tables(&mut out);
        }
        if let Some(t) = &self.tier {
            let e = &t.envelope;
            let _ = writeln!(
                out,
                "\nCo-rotational tier from `{}`: r = {} POD vectors, {} sampled elements{}, \
                 {}; compiled with its training in {:.0} s. Open loop: {:.2} Newton iterations per \
                 step; training envelope {} (largest load ratio {:.2}, state ratio {:.2} of \
                 margin {:.2}).",
                t.scene.display(),
                t.basis_order,
                t.sampled_elements,
                if t.force_states > 0 {
                    format!(", {} force states", t.force_states)
                } else {
                    String::new()
                },
                if t.filters > 1 {
                    format!("a gain schedule of {} filters", t.filters)
                } else {
                    "one constant-gain filter".to_owned()
                },
                t.compile_s,
                e.iterations_per_step(),
                if e.outside() {
                    format!("LEFT in {} of {} steps", e.steps_outside, e.steps)
                } else {
                    "kept".to_owned()
                },
                e.max_load_ratio,
                e.max_state_ratio,
                e.state_margin
            );
            if let Some(line) = tier_not_faster(
                t.figures.runtime.step_s,
                self.linear.step_s,
                t.sampled_elements,
                self.tetrahedra,
            ) {
                let _ = writeln!(out, "\n{line}");
            }
        }
        if let Some(why) = &self.tier_failure {
            let _ = writeln!(out, "\nThe co-rotational tier failed: {why}");
        }
        for failure in &self.failures {
            let _ = writeln!(
                out,
                "\nOrder r = {} failed: {}",
                failure.order, failure.reason
            );
        }
        if let Some(n) = self.corotational.newton {
            let _ = writeln!(
                out,
                "\nCo-rotational Newton: {} solves in {} steps, {} unconverged, worst final \
                 increment {:.1e}.",
                n.solves, n.steps, n.unconverged, n.worst_increment
            );
        }
        if !self.notes.is_empty() {
            let _ = writeln!(out, "\nCompiler notes on the scene:\n");
            for note in &self.notes {
                let _ = writeln!(out, "- {note}");
            }
        }
        if !self.tier_notes.is_empty() {
            let _ = writeln!(out, "\nCompiler notes on the co-rotational tier's scene:\n");
            for note in &self.tier_notes {
                let _ = writeln!(out, "- {note}");
            }
        }
        self.advice_section(&mut out);
        out
    }

    /// Every filtered run of every row, with its ensemble over the noise draws (or of its one
    /// run below 2 draws). Runs whose ensemble is empty (every draw refused) are left out.
    fn filtered_runs(&self) -> Vec<FilteredRun> {
        let mut rows: Vec<(String, Tier, &RowFigures)> = self
            .reduced
            .iter()
            .map(|row| {
                (
                    format!("r = {}", row.order - row.force_states),
                    Tier::Warped,
                    &row.figures,
                )
            })
            .collect();
        if let Some(t) = &self.tier {
            rows.push((
                format!("co-rotational tier ({})", tier_order(t)),
                Tier::Corotational,
                &t.figures,
            ));
        }
        let mut out = Vec::new();
        for (label, tier, figures) in rows {
            let runs = figures.runtime.filter_runs(self.withheld_loads);
            let single = [&figures.consistency, &figures.withheld_consistency];
            let drawn = [&figures.ensemble, &figures.withheld_ensemble];
            for (((loads, error, _), one), drawn) in runs.into_iter().zip(single).zip(drawn) {
                let ensemble = match drawn {
                    Some(e) => e.clone(),
                    None => match SeedEnsemble::of_run(error, one) {
                        Ok(e) => e,
                        Err(_) => continue,
                    },
                };
                if ensemble.nis.runs() > 0 {
                    out.push(FilteredRun {
                        row: label.clone(),
                        tier,
                        loads,
                        ensemble,
                        open_loop_error: figures.runtime.error,
                    });
                }
            }
        }
        out
    }

    /// The advice of every filtered run ([`advice::advise`]), one line per problem, each
    /// starting with the row and the loads (`r = 16, loads withheld: …`); empty when every run
    /// is within its bounds.
    pub fn advice(&self) -> Vec<String> {
        let mut lines = Vec::new();
        for run in self.filtered_runs() {
            let ensemble = &run.ensemble;
            let segments = segment_figures(ensemble, &self.segments);
            let figures = AdviceFigures {
                tier: run.tier,
                markers_from_noise_std: true,
                loads_given: run.loads == "given",
                nis: ensemble.nis.fractions(),
                nees_tip: ensemble.nees_tip.fractions(),
                coverage: ensemble.coverage_in(0..self.steps),
                filtered_error: spread(&ensemble.errors).map_or(f64::NAN, |s| s.0),
                model_error: Some(run.open_loop_error),
                segments: &segments,
                loads: &self.loads,
                own_covariance: ensemble.own_covariance_fraction(),
            };
            let context = Context::from(&figures);
            for a in advice::advise(&figures) {
                let (row, loads) = (&run.row, run.loads);
                lines.push(format!("{row}, loads {loads}: {}", a.line(&context)));
            }
        }
        lines
    }

    /// The advice section: the rules' thresholds and one line per problem.
    fn advice_section(&self, out: &mut String) {
        if self.reduced.is_empty() && self.tier.is_none() {
            return;
        }
        let lines = self.advice();
        let _ = writeln!(
            out,
            "\nWhat to change: from each filtered run's figures {}, a statistic is off when more than {:.0} % of its steps lie beyond one of its 95 % \
             bounds or the 2σ coverage is outside {:.0}–{:.0} %; tip NEES above is laid to the \
             load's changes or holds by the segments above (a rate {d}× higher in one kind), \
             and not to the model when the filtered error is more than {d}× the row's open-loop \
             error (the model's own, loads given). The markers here are drawn with the scene's \
             noise_std, so R is right by construction.{}",
            if self.seeds >= 2 {
                format!("over its {} noise draws", self.seeds)
            } else {
                "in its one run (per-step bounds of one run)".to_owned()
            },
            100.0 * advice::OUTSIDE_LIMIT,
            100.0 * advice::COVERAGE_LOW,
            100.0 * advice::COVERAGE_HIGH,
            if lines.is_empty() {
                " Every filtered run is within these bounds: nothing to change."
            } else {
                "\n"
            },
            d = advice::DOMINANCE,
        );
        for line in lines {
            let _ = writeln!(out, "- {line}");
        }
    }

    /// The per-segment tables: one per row (a warped order or the tier), its filtered runs'
    /// figures in each segment of the scenario.
    fn segment_tables(&self, out: &mut String) {
        let runs = self.filtered_runs();
        if runs.is_empty() || self.segments.is_empty() {
            return;
        }
        let _ = writeln!(
            out,
            "\nPer segment: the scenario cut at its load times (breakpoints closer than \
             {MERGE_STEPS} steps merged); in each segment, {}, the steps whose NIS and tip NEES \
             lie below / inside / above their 95 % bounds, and the 2σ coverage (runtime σ).",
            if self.seeds >= 2 {
                format!(
                    "over the {} noise draws of the table above (N-run means)",
                    self.seeds
                )
            } else {
                "in the one filtered run (per-step bounds of one run, χ²(d)/d)".to_owned()
            }
        );
        let mut i = 0;
        while i < runs.len() {
            let row = &runs[i].row;
            let rows: Vec<(String, Vec<SegmentFigures>)> = runs[i..]
                .iter()
                .take_while(|r| &r.row == row)
                .map(|r| {
                    (
                        r.loads.to_string(),
                        segment_figures(&r.ensemble, &self.segments),
                    )
                })
                .collect();
            i += rows.len();
            let _ = writeln!(out, "\n{row}:\n");
            out.push_str(&segment_table("loads", &rows));
        }
    }

    /// CSV, one row per model and order; empty fields where a figure does not apply.
    pub fn csv(&self) -> String {
        let mut out = String::from(
            "model,r,step_s,speedup_vs_corotational,speedup_vs_linear,error,tip_error,\
             filtered_error,filtered_tip_error,error_vs_linear,open_loop_step_s,max_rotation_deg,\
             withheld_filtered_error,withheld_filtered_tip_error,anis,anis_low,anis_high,\
             anees_tip,anees_low,anees_high,coverage_runtime,coverage_world,withheld_anis,\
             withheld_anees_tip,withheld_coverage_runtime,withheld_coverage_world\n",
        );
        let c = self.corotational.step_s;
        let l = self.linear.step_s;
        let rot = csv_number(self.max_rotation_deg);
        let _ = writeln!(
            out,
            "corotational_fem,{},{},1,{},0,0,,,,,{rot},,,,,,,,,,,,,,",
            self.dofs,
            csv_number(c),
            csv_number(l / c)
        );
        let _ = writeln!(
            out,
            "linear_fem,{},{},{},1,{},{},,,0,,{rot},,,,,,,,,,,,,,",
            self.dofs,
            csv_number(l),
            csv_number(c / l),
            csv_number(self.linear.error),
            csv_number(self.linear.tip_error)
        );
        for row in &self.reduced {
            let consistency =
                csv_consistency(&row.figures.consistency, &row.figures.withheld_consistency);
            self.csv_row(
                &mut out,
                "runtime",
                row.order,
                &row.figures.runtime,
                &consistency,
            );
        }
        if let Some(t) = &self.tier {
            let consistency =
                csv_consistency(&t.figures.consistency, &t.figures.withheld_consistency);
            self.csv_row(
                &mut out,
                "corotational_tier",
                t.basis_order,
                &t.figures.runtime,
                &consistency,
            );
        }
        out
    }

    /// The filter table's lines of one row (a warped order or the tier, labelled `r`): per
    /// filtered run ([`RuntimeFigures::filter_runs`]) its errors, ANIS and tip ANEES with their
    /// 95 % bounds and the 2σ coverages of `consistency` (given, withheld).
    fn filter_rows(&self, out: &mut String, r: &str, figures: &RowFigures) {
        let runs = figures.runtime.filter_runs(self.withheld_loads);
        let consistency = [&figures.consistency, &figures.withheld_consistency];
        for ((label, e, tip), c) in runs.into_iter().zip(consistency) {
            let _ = writeln!(
                out,
                "| {r} | {label} | {} | {} | {} | {} | {} / {} |",
                sci(e),
                sci(tip),
                chi(&c.nis),
                chi(&c.nees_tip),
                percent(c.coverage_runtime),
                percent(c.coverage_world)
            );
        }
    }

    /// The N-run consistency table (docs/design.md §11.3): one line per filtered run of each
    /// row that was repeated over the noise draws; nothing when none was.
    fn ensemble_table(&self, out: &mut String) {
        let mut rows: Vec<(String, [&Option<SeedEnsemble>; 2])> = self
            .reduced
            .iter()
            .map(|row| {
                (
                    (row.order - row.force_states).to_string(),
                    [&row.figures.ensemble, &row.figures.withheld_ensemble],
                )
            })
            .collect();
        if let Some(t) = &self.tier {
            rows.push((
                format!("tier {}", tier_order(t)),
                [&t.figures.ensemble, &t.figures.withheld_ensemble],
            ));
        }
        if rows.iter().all(|(_, e)| e.iter().all(|e| e.is_none())) {
            return;
        }
        let _ = writeln!(
            out,
            "\nThe filter over {} noise draws (seeds {:#x} + 0 … {}; docs/design.md §11.3). One run's \
             errors are correlated in time, so its single-run bounds above are no verdict; here, \
             at each step, the N-run mean NIS and tip NEES against the 95 % bounds of \
             χ²(N d)/(N d): a consistent filter has ≈ 95 % of the steps inside and ≈ 2.5 % on \
             either side. Verdict: overconfident where more than 10 % of the steps lie above \
             (σ too small), conservative where more than 10 % lie below (σ too large).\n",
            self.seeds,
            self.seed,
            self.seeds.saturating_sub(1)
        );
        let _ = writeln!(
            out,
            "| r | loads | filtered error: mean [min, max] | NIS: mean; steps below / inside / above | tip NEES: mean; steps below / inside / above | 2σ coverage: mean [min, max] | refused draws |"
        );
        let _ = writeln!(out, "|---:|---|---:|---|---|---:|---|");
        let labels: &[&str] = if self.withheld_loads {
            &["withheld"]
        } else {
            &["given", "withheld"]
        };
        for (r, ensembles) in rows {
            for (label, e) in labels.iter().zip(ensembles) {
                let Some(e) = e else { continue };
                let steps = |ens: &Ensemble| {
                    let f = ens.fractions();
                    if f.steps == 0 {
                        return "—".to_string();
                    }
                    format!(
                        "{:.3}; {:.1} / {:.1} / {:.1} % of {}: {}",
                        ens.total().mean(),
                        100.0 * f.below,
                        100.0 * f.inside,
                        100.0 * f.above,
                        f.steps,
                        verdict(&f)
                    )
                };
                let range = |v: &[f64], digits: usize| match spread(v) {
                    Some((mean, lo, hi)) => format!(
                        "{:.digits$} % [{:.digits$}, {:.digits$}]",
                        100.0 * mean,
                        100.0 * lo,
                        100.0 * hi
                    ),
                    None => "—".into(),
                };
                let _ = writeln!(
                    out,
                    "| {r} | {label} | {} | {} | {} | {} | {} |",
                    range(&e.errors, 2),
                    steps(&e.nis),
                    steps(&e.nees_tip),
                    range(&e.coverage, 1),
                    e.refusals()
                );
            }
        }
    }

    /// A runtime row of the speed table: step time, the speed-ups over both full-order models,
    /// open-loop, tip and filtered errors; flagged where it is worse than the linear FEM (the
    /// reduction or the warping costs more there than the co-rotation gains).
    fn speed_row(&self, out: &mut String, model: &str, r: &str, f: &RuntimeFigures) {
        let (c, l) = (self.corotational.step_s, self.linear.step_s);
        let flag = if f.error > self.linear.error {
            " ⚠ worse than linear FEM"
        } else {
            ""
        };
        let _ = writeln!(
            out,
            "| {model} | {r} | {} | {} | {} | {}{flag} | {} | {} |",
            format_seconds(f.step_s),
            ratio(c, f.step_s),
            ratio(l, f.step_s),
            sci(f.error),
            sci(f.tip_error),
            sci(f.filtered_error)
        );
    }

    /// A runtime line of the CSV: the figures of `f` in the header's order, then
    /// `consistency` (the 12 consistency fields, comma-separated, empty where none apply).
    fn csv_row(
        &self,
        out: &mut String,
        model: &str,
        r: usize,
        f: &RuntimeFigures,
        consistency: &str,
    ) {
        let (c, l) = (self.corotational.step_s, self.linear.step_s);
        let _ = writeln!(
            out,
            "{model},{r},{},{},{},{},{},{},{},{},{},{},{},{},{consistency}",
            csv_number(f.step_s),
            csv_number(c / f.step_s),
            csv_number(l / f.step_s),
            csv_number(f.error),
            csv_number(f.tip_error),
            csv_number(f.filtered_error),
            csv_number(f.filtered_tip_error),
            csv_number(f.error_vs_linear),
            csv_number(f.open_loop_step_s),
            csv_number(self.max_rotation_deg),
            csv_number(f.withheld_filtered_error),
            csv_number(f.withheld_filtered_tip_error),
        );
    }
}

/// A filtered run of a row, for the per-segment tables and the advice.
struct FilteredRun {
    /// `r = 16`, `co-rotational tier (…)`.
    row: String,
    tier: Tier,
    /// `given` or `withheld`.
    loads: &'static str,
    /// Over the noise draws, or of the one run.
    ensemble: SeedEnsemble,
    /// The row's open-loop error (the model's own, loads given).
    open_loop_error: f64,
}

impl RuntimeFigures {
    /// The filter table's runs: (loads, filtered error, tip error), "given" and "withheld", or
    /// only "withheld" when the whole comparison withholds the loads (then the filtered run is
    /// the withheld one).
    fn filter_runs(&self, withheld_loads: bool) -> Vec<(&'static str, f64, f64)> {
        if withheld_loads {
            vec![("withheld", self.filtered_error, self.filtered_tip_error)]
        } else {
            vec![
                ("given", self.filtered_error, self.filtered_tip_error),
                (
                    "withheld",
                    self.withheld_filtered_error,
                    self.withheld_filtered_tip_error,
                ),
            ]
        }
    }
}

/// The tier's size in the tables: `20 POD, 169 el.` (+ force states if any).
pub(super) fn tier_order(t: &super::TierRow) -> String {
    let force = if t.force_states > 0 {
        format!(" + {} force", t.force_states)
    } else {
        String::new()
    };
    format!("{} POD, {} el.{force}", t.basis_order, t.sampled_elements)
}

/// `mean [low, high]` of a χ² statistic, with a mark when outside its bounds.
fn chi(c: &ChiSquare) -> String {
    if c.dof == 0 {
        return "—".into();
    }
    let (lo, hi) = c.bounds();
    let flag = if c.inside() { "" } else { " ✗" };
    format!("{:.3} [{:.3}, {:.3}]{flag}", c.mean(), lo, hi)
}

/// A per-segment table ([`super::segments`]): one line per run (`rows`: the run's label, in a
/// first column headed `first` — or several, `first` and the labels split by ` | ` alike — and
/// its segments' figures) and segment: the segment's time
/// span and what the load does, its steps, the fractions of its steps below / inside / above
/// the 95 % bounds of the N-run NIS and tip NEES (%), and its 2σ coverage.
pub fn segment_table(first: &str, rows: &[(String, Vec<SegmentFigures>)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "| {first} | segment | steps | NIS % below / inside / above | tip NEES % below / inside / above | 2σ coverage |"
    );
    // `first` may name several columns (`model | run`).
    let _ = writeln!(
        out,
        "|{}---|---:|---|---|---:|",
        "---|".repeat(first.matches('|').count() + 1)
    );
    for (label, segments) in rows {
        for s in segments {
            let seg = &s.segment;
            let _ = writeln!(
                out,
                "| {label} | {}–{} s: {} | {} | {} | {} | {} |",
                seconds(seg.start),
                seconds(seg.end),
                seg.change.describe(),
                seg.steps.len(),
                s.nis.percentages(),
                s.nees_tip.percentages(),
                percent(s.coverage)
            );
        }
    }
    out
}

/// A warning when the tier's measured step (`tier_s`) is not faster than the full-order
/// linear FEM step of the same run (`linear_s`): on a small mesh, or with many sampled
/// elements, the linear FEM itself is the faster real-time model. None when faster or when a
/// time is missing.
fn tier_not_faster(
    tier_s: f64,
    linear_s: f64,
    sampled: usize,
    tetrahedra: usize,
) -> Option<String> {
    if !(tier_s.is_finite() && linear_s.is_finite() && tier_s >= linear_s) {
        return None;
    }
    Some(format!(
        "WARNING: the co-rotational tier's step ({}) is not faster than the full-order linear \
         FEM step ({}) in this run: it integrates {sampled} of the {tetrahedra} elements. The \
         tier still follows large rotations, which the linear FEM does not; for speed, lower \
         `order` or raise `ecsw_tolerance` in [reduction.corotational] (fewer sampled \
         elements), or run the full-order model on a mesh this small.",
        format_seconds(tier_s),
        format_seconds(linear_s),
    ))
}

/// A time in seconds with at most 4 decimals, trailing zeros dropped: `0`, `0.5`, `1.005`.
fn seconds(t: f64) -> String {
    let s = format!("{t:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comparison::segments::{LoadChange, Segment};
    use crate::comparison::StepFractions;

    #[test]
    fn a_segment_table_has_as_many_columns_in_every_line() {
        let f = StepFractions {
            steps: 100,
            below: 0.01,
            inside: 0.95,
            above: 0.04,
        };
        let figures = SegmentFigures {
            segment: Segment {
                steps: 0..101,
                start: 0.0,
                end: 0.5,
                change: LoadChange::Rises(0.0, 20.0),
            },
            nis: f,
            nees_tip: StepFractions { steps: 0, ..f },
            coverage: 0.9612,
        };
        for (first, label) in [("loads", "given"), ("model | run", "m.crokf | withheld")] {
            let table = segment_table(first, &[(label.to_owned(), vec![figures.clone()])]);
            let pipes: Vec<usize> = table.lines().map(|l| l.matches('|').count()).collect();
            assert_eq!(pipes.len(), 3, "{table}");
            assert!(pipes.iter().all(|&p| p == pipes[0]), "{table}");
            assert!(
                table.ends_with(&format!(
                    "| {label} | 0–0.5 s: load rises 0 N → 20 N | 101 | 1.0 / 95.0 / 4.0 | — | 96.1 % |\n"
                )),
                "{table}"
            );
        }
        assert_eq!(seconds(1.005), "1.005");
    }

    /// The report says so when the tier's step is not faster than the linear FEM's, naming
    /// both times and the sampled share, and says nothing otherwise or without a time.
    #[test]
    fn a_tier_no_faster_than_the_linear_fem_is_a_warning() {
        let w = tier_not_faster(48e-6, 40e-6, 185, 596).expect("a warning");
        assert!(w.starts_with("WARNING"), "{w}");
        assert!(w.contains("185 of the 596 elements"), "{w}");
        assert!(
            w.contains(&format_seconds(48e-6)) && w.contains(&format_seconds(40e-6)),
            "{w}"
        );
        assert!(w.contains("ecsw_tolerance"), "{w}");
        assert_eq!(tier_not_faster(10e-6, 40e-6, 100, 50_000), None);
        assert_eq!(tier_not_faster(f64::NAN, 40e-6, 100, 596), None);
        assert_eq!(tier_not_faster(48e-6, f64::NAN, 100, 596), None);
        assert_eq!(seconds(0.0), "0");
        assert_eq!(seconds(1.5), "1.5");
    }
}
