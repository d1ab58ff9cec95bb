//! Rendering of a comparison: Markdown table, CSV and an SVG plot of step time against error.

use std::fmt::Write as _;

use crate::bench::STEP_CLOCK;

use super::{
    breakdown_rotation, breakdown_rotation_of, spread, verdict, ChiSquare, Comparison, Consistency,
    Ensemble, ReducedRow, RowFigures, RuntimeFigures, SeedEnsemble, SweepPoint, TierPoint,
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
fn decade_seconds(d: i32) -> String {
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

/// Plot marker shapes.
#[derive(Clone, Copy, Debug)]
enum Shape {
    Circle,
    Square,
    Triangle,
    Diamond,
    /// Five-pointed star: the co-rotational tier.
    Star,
}

impl Shape {
    /// Appends the marker centred at (x, y) (px) as one SVG element of class `class`.
    fn draw(self, s: &mut String, x: f64, y: f64, colour: &str, class: &str) {
        let points = |p: &[(f64, f64)]| -> String {
            p.iter()
                .map(|(dx, dy)| format!("{:.1},{:.1}", x + dx, y + dy))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let _ = match self {
            Shape::Circle => writeln!(
                s,
                r#"<circle class="{class}" cx="{x:.1}" cy="{y:.1}" r="5" fill="{colour}"/>"#
            ),
            Shape::Square => writeln!(
                s,
                r#"<rect class="{class}" x="{:.1}" y="{:.1}" width="9" height="9" fill="{colour}"/>"#,
                x - 4.5,
                y - 4.5
            ),
            Shape::Triangle => writeln!(
                s,
                r#"<polygon class="{class}" points="{}" fill="{colour}"/>"#,
                points(&[(0.0, -6.0), (-6.0, 5.0), (6.0, 5.0)])
            ),
            Shape::Diamond => writeln!(
                s,
                r#"<polygon class="{class}" points="{}" fill="{colour}"/>"#,
                points(&[(0.0, -7.0), (6.0, 0.0), (0.0, 7.0), (-6.0, 0.0)])
            ),
            Shape::Star => {
                // Ten vertices alternating between radius 7 and 3 px, the first pointing up.
                let star: Vec<(f64, f64)> = (0..10)
                    .map(|i| {
                        let radius = if i % 2 == 0 { 7.0 } else { 3.0 };
                        let angle = std::f64::consts::PI * (i as f64 / 5.0 - 0.5);
                        (radius * angle.cos(), radius * angle.sin())
                    })
                    .collect();
                writeln!(
                    s,
                    r#"<polygon class="{class}" points="{}" fill="{colour}"/>"#,
                    points(&star)
                )
            }
        };
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

impl Comparison {
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
             frame, against the co-rotational full-order reference; tip error at sensor `{}`. \
             Filtered: measurements = reference sensor displacements + Gaussian noise \
             (noise_std, seed {:#x}){}. Runtime step = predict + update, median of batches \
             in {STEP_CLOCK} (the runtime steps on one thread: jobs sharing the machine do not \
             count); full-order step = median wall time over the run (its sparse solver may \
             use several threads).\n",
            self.displayed_nodes,
            self.tip.as_deref().unwrap_or("—"),
            self.seed,
            if self.withheld_loads {
                "; the runtime got NO load inputs (loads withheld)"
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
            self.speed_row(&mut out, "co-rotational tier", &tier_order(t), &t.figures.runtime);
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
                self.filter_rows(
                    &mut out,
                    &format!("tier {}", tier_order(t)),
                    &t.figures,
                );
            }
            self.ensemble_table(&mut out);
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
        out
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
            let consistency = csv_consistency(&row.figures.consistency, &row.figures.withheld_consistency);
            self.csv_row(&mut out, "runtime", row.order, &row.figures.runtime, &consistency);
        }
        if let Some(t) = &self.tier {
            let consistency = csv_consistency(&t.figures.consistency, &t.figures.withheld_consistency);
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

    /// A self-contained SVG plot: step time (log x) against relative L2 error (log y), one
    /// marker (`class="marker"`) per open-loop and filtered runtime point and per full-order
    /// model; the co-rotational reference (error 0) sits on the bottom axis.
    pub fn svg(&self) -> String {
        const W: f64 = 720.0;
        const H: f64 = 480.0;
        const LEFT: f64 = 80.0;
        const RIGHT: f64 = 230.0;
        const TOP: f64 = 50.0;
        const BOTTOM: f64 = 60.0;
        let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);

        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        let mut times = vec![self.corotational.step_s, self.linear.step_s];
        let mut errors = vec![self.linear.error];
        let runtime = self.reduced.iter().map(|r| &r.figures.runtime);
        for f in runtime.chain(self.tier.iter().map(|t| &t.figures.runtime)) {
            times.push(f.step_s);
            errors.push(f.error);
            errors.push(f.filtered_error);
        }
        let decades = |values: &[f64], fallback: (f64, f64)| {
            let v: Vec<f64> = values.iter().copied().filter(|&v| finite_pos(v)).collect();
            if v.is_empty() {
                return fallback;
            }
            let lo = v
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min)
                .log10()
                .floor();
            let hi = v
                .iter()
                .copied()
                .fold(f64::NEG_INFINITY, f64::max)
                .log10()
                .ceil();
            (lo, if hi > lo { hi } else { lo + 1.0 })
        };
        let (x0, x1) = decades(&times, (-6.0, 0.0));
        let (y0, y1) = decades(&errors, (-3.0, 0.0));
        let sx = |t: f64| LEFT + (t.log10() - x0) / (x1 - x0) * pw;
        let sy = |e: f64| TOP + ph - (e.log10() - y0) / (y1 - y0) * ph;
        let y_bottom = TOP + ph;

        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<?xml version="1.0" encoding="UTF-8"?>
<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(
            s,
            r#"<rect x="0" y="0" width="{W}" height="{H}" fill="white"/>"#
        );
        let title = format!(
            "{} — speed against error (max rotation {:.0}°)",
            self.scene.parent().and_then(|p| p.file_name()).map_or_else(
                || self.scene.display().to_string(),
                |n| n.to_string_lossy().into_owned()
            ),
            self.max_rotation_deg
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="28" text-anchor="middle" font-size="15">{}</text>"#,
            LEFT + pw / 2.0,
            xml_escape(&title)
        );
        // Grid, ticks and tick labels.
        let _ = writeln!(s, r##"<g stroke="#dddddd" stroke-width="1">"##);
        for d in (x0 as i32)..=(x1 as i32) {
            let x = LEFT + (d as f64 - x0) / (x1 - x0) * pw;
            let _ = writeln!(
                s,
                r#"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{y_bottom}"/>"#
            );
        }
        for d in (y0 as i32)..=(y1 as i32) {
            let y = TOP + ph - (d as f64 - y0) / (y1 - y0) * ph;
            let _ = writeln!(
                s,
                r#"<line x1="{LEFT}" y1="{y:.1}" x2="{}" y2="{y:.1}"/>"#,
                LEFT + pw
            );
        }
        let _ = writeln!(s, "</g>");
        let _ = writeln!(
            s,
            r#"<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="black"/>"#
        );
        for d in (x0 as i32)..=(x1 as i32) {
            let x = LEFT + (d as f64 - x0) / (x1 - x0) * pw;
            let _ = writeln!(
                s,
                r#"<line x1="{x:.1}" y1="{y_bottom}" x2="{x:.1}" y2="{}" stroke="black"/>"#,
                y_bottom + 5.0
            );
            let _ = writeln!(
                s,
                r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#,
                y_bottom + 19.0,
                decade_seconds(d)
            );
        }
        for d in (y0 as i32)..=(y1 as i32) {
            let y = TOP + ph - (d as f64 - y0) / (y1 - y0) * ph;
            let _ = writeln!(
                s,
                r#"<line x1="{}" y1="{y:.1}" x2="{LEFT}" y2="{y:.1}" stroke="black"/>"#,
                LEFT - 5.0
            );
            let _ = writeln!(
                s,
                r#"<text x="{}" y="{:.1}" text-anchor="end">1e{d}</text>"#,
                LEFT - 8.0,
                y + 4.0
            );
        }
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">step time (log scale; runtime: {STEP_CLOCK}, FEM: wall time)</text>"#,
            LEFT + pw / 2.0,
            H - 18.0
        );
        let _ = writeln!(
            s,
            r#"<text x="20" y="{}" text-anchor="middle" transform="rotate(-90 20 {})">relative L2 error vs co-rotational FEM (log scale)</text>"#,
            TOP + ph / 2.0,
            TOP + ph / 2.0
        );

        // Series: lines through the runtime points, then markers.
        let series = |pick: &dyn Fn(&ReducedRow) -> f64| -> Vec<(f64, f64, usize)> {
            self.reduced
                .iter()
                .filter(|r| finite_pos(r.figures.runtime.step_s) && finite_pos(pick(r)))
                .map(|r| (sx(r.figures.runtime.step_s), sy(pick(r)), r.order))
                .collect()
        };
        let open = series(&|r| r.figures.runtime.error);
        let filtered = series(&|r| r.figures.runtime.filtered_error);
        const OPEN: &str = "#1f77b4";
        const FILTERED: &str = "#ff7f0e";
        const LINEAR: &str = "#2ca02c";
        const COROT: &str = "#000000";
        for (points, colour) in [(&open, OPEN), (&filtered, FILTERED)] {
            if points.len() > 1 {
                let path: Vec<String> = points
                    .iter()
                    .map(|(x, y, _)| format!("{x:.1},{y:.1}"))
                    .collect();
                let _ = writeln!(
                    s,
                    r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="1.5"/>"#,
                    path.join(" ")
                );
            }
        }
        for &(x, y, _) in &open {
            Shape::Circle.draw(&mut s, x, y, OPEN, "marker");
        }
        for &(x, y, _) in &filtered {
            Shape::Square.draw(&mut s, x, y, FILTERED, "marker");
        }
        // Order labels above the upper marker of each order, on top of the markers (white
        // halo); neighbouring orders often sit close together, so the labels take three rows.
        for (i, &(x, y, r)) in open.iter().enumerate() {
            let top = filtered
                .iter()
                .find(|p| p.2 == r && (p.0 - x).abs() < 0.5)
                .map_or(y, |p| p.1.min(y));
            let _ = writeln!(
                s,
                r#"<text x="{x:.1}" y="{:.1}" font-size="10" text-anchor="middle" stroke="white" stroke-width="3" paint-order="stroke">r={r}</text>"#,
                top - 9.0 - 12.0 * (i % 3) as f64
            );
        }
        if finite_pos(self.linear.step_s) && finite_pos(self.linear.error) {
            let (x, y) = (sx(self.linear.step_s), sy(self.linear.error));
            Shape::Triangle.draw(&mut s, x, y, LINEAR, "marker");
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}" font-size="10" text-anchor="end">linear FEM</text>"#,
                x - 8.0,
                y - 6.0
            );
        }
        const TIER_OPEN: &str = "#9467bd";
        const TIER_FILTERED: &str = "#d62728";
        if let Some(t) = &self.tier {
            let mut top = f64::INFINITY;
            let f = &t.figures.runtime;
            for (e, colour) in [(f.error, TIER_OPEN), (f.filtered_error, TIER_FILTERED)] {
                if finite_pos(f.step_s) && finite_pos(e) {
                    let (x, y) = (sx(f.step_s), sy(e));
                    Shape::Star.draw(&mut s, x, y, colour, "marker");
                    top = top.min(y);
                }
            }
            if top.is_finite() {
                let _ = writeln!(
                    s,
                    r#"<text x="{:.1}" y="{:.1}" font-size="10" text-anchor="middle" stroke="white" stroke-width="3" paint-order="stroke">tier r={}</text>"#,
                    sx(f.step_s),
                    top - 10.0,
                    t.basis_order
                );
            }
        }
        if finite_pos(self.corotational.step_s) {
            let x = sx(self.corotational.step_s);
            Shape::Diamond.draw(&mut s, x, y_bottom, COROT, "marker");
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}" font-size="10" text-anchor="end">reference (error 0)</text>"#,
                x - 8.0,
                y_bottom - 8.0
            );
        }
        // Legend.
        let lx = LEFT + pw + 20.0;
        let mut entries = vec![
            ("runtime, open loop", OPEN, Shape::Circle),
            ("runtime, filtered", FILTERED, Shape::Square),
        ];
        if self.tier.is_some() {
            entries.push(("co-rotational tier, open loop", TIER_OPEN, Shape::Star));
            entries.push(("co-rotational tier, filtered", TIER_FILTERED, Shape::Star));
        }
        entries.push(("linear FEM (full order)", LINEAR, Shape::Triangle));
        entries.push(("co-rotational FEM (reference)", COROT, Shape::Diamond));
        let _ = writeln!(s, r#"<g class="legend">"#);
        for (i, (label, colour, draw)) in entries.iter().enumerate() {
            let y = TOP + 14.0 + 22.0 * i as f64;
            draw.draw(&mut s, lx + 6.0, y, colour, "legend-symbol");
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}">{}</text>"#,
                lx + 18.0,
                y + 4.0,
                xml_escape(label)
            );
        }
        let _ = writeln!(s, "</g>");
        let _ = writeln!(s, "</svg>");
        s
    }
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
fn tier_order(t: &super::TierRow) -> String {
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

impl Comparison {
    /// A self-contained SVG of the tip marker's world error and ±2σ along the trajectory for
    /// the runtime row `index` (three panels x, y, z; the filter with the loads given and with
    /// the loads withheld, the ±2σ band of the given-load run), or `None` without a tip trace.
    pub fn tip_svg(&self, index: usize) -> Option<String> {
        let row = self.reduced.get(index)?;
        let label = format!(
            "r = {} + {} force states",
            row.order - row.force_states,
            row.force_states
        );
        self.tip_plot(&label, &row.figures.consistency, &row.figures.withheld_consistency)
    }

    /// The same plot for the co-rotational tier's row ([`Comparison::tip_svg`]; σ from the
    /// tier's own stored filters, world frame), or `None` without a tier or a tip trace.
    pub fn tier_tip_svg(&self) -> Option<String> {
        let t = self.tier.as_ref()?;
        let label = format!("co-rotational tier {}", tier_order(t));
        self.tip_plot(&label, &t.figures.consistency, &t.figures.withheld_consistency)
    }

    /// The tip plot of one row, `label` naming it in the title.
    fn tip_plot(&self, label: &str, given: &Consistency, withheld: &Consistency) -> Option<String> {
        let given = &given.tip[..];
        if given.is_empty() {
            return None;
        }
        let withheld = if self.withheld_loads {
            &[][..]
        } else {
            &withheld.tip[..]
        };
        const W: f64 = 760.0;
        const PANEL: f64 = 180.0;
        const LEFT: f64 = 90.0;
        const RIGHT: f64 = 20.0;
        const TOP: f64 = 50.0;
        const GAP: f64 = 30.0;
        let h = TOP + 3.0 * PANEL + 2.0 * GAP + 70.0;
        let pw = W - LEFT - RIGHT;
        let t0 = given.first().map_or(0.0, |s| s.time);
        let t1 = given.last().map_or(1.0, |s| s.time).max(t0 + 1e-12);
        let sx = |t: f64| LEFT + (t - t0) / (t1 - t0) * pw;
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<?xml version="1.0" encoding="UTF-8"?>
<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="sans-serif" font-size="12">
<rect x="0" y="0" width="{W}" height="{h}" fill="white"/>"#
        );
        let title = format!(
            "tip marker `{}`: error and ±2σ, {label}; inside ±2σ: {:.1} % (loads given) / {:.1} % (withheld)",
            self.tip.as_deref().unwrap_or("—"),
            100.0 * inside_fraction(given),
            100.0 * inside_fraction(withheld),
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="24" text-anchor="middle" font-size="13">{}</text>"#,
            W / 2.0,
            xml_escape(&title)
        );
        for c in 0..3 {
            let top = TOP + c as f64 * (PANEL + GAP);
            let mut ymax = 0.0f64;
            for p in given.iter().chain(withheld) {
                ymax = ymax.max(p.error[c].abs()).max(2.0 * p.sigma[c]);
            }
            let ymax = if ymax > 0.0 { 1.1 * ymax } else { 1.0 };
            let sy = |v: f64| top + PANEL / 2.0 - v / ymax * (PANEL / 2.0);
            let _ = writeln!(
                s,
                r#"<rect x="{LEFT}" y="{top}" width="{pw}" height="{PANEL}" fill="none" stroke="black"/>"#
            );
            let mut band: Vec<String> = given
                .iter()
                .map(|p| format!("{:.1},{:.1}", sx(p.time), sy(2.0 * p.sigma[c])))
                .collect();
            band.extend(
                given
                    .iter()
                    .rev()
                    .map(|p| format!("{:.1},{:.1}", sx(p.time), sy(-2.0 * p.sigma[c]))),
            );
            let _ = writeln!(
                s,
                r##"<polygon class="band" points="{}" fill="#cccccc" stroke="none"/>"##,
                band.join(" ")
            );
            let _ = writeln!(
                s,
                r##"<line x1="{LEFT}" y1="{:.1}" x2="{}" y2="{:.1}" stroke="#888888"/>"##,
                sy(0.0),
                LEFT + pw,
                sy(0.0)
            );
            for (trace, colour, class) in [
                (given, "#1f77b4", "error-given"),
                (withheld, "#d62728", "error-withheld"),
            ] {
                if trace.is_empty() {
                    continue;
                }
                let pts: Vec<String> = trace
                    .iter()
                    .map(|p| format!("{:.1},{:.1}", sx(p.time), sy(p.error[c])))
                    .collect();
                let _ = writeln!(
                    s,
                    r#"<polyline class="{class}" points="{}" fill="none" stroke="{colour}" stroke-width="1.2"/>"#,
                    pts.join(" ")
                );
            }
            let axis = ["x", "y", "z"][c];
            let _ = writeln!(
                s,
                r#"<text x="{}" y="{:.1}" text-anchor="end">{axis}: ±{ymax:.2e} m</text>"#,
                LEFT - 6.0,
                top + 14.0,
            );
        }
        let bottom = TOP + 3.0 * PANEL + 2.0 * GAP;
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{:.1}" text-anchor="middle">t (s), {:.3} … {:.3}</text>"#,
            LEFT + pw / 2.0,
            bottom + 20.0,
            t0,
            t1
        );
        let _ = writeln!(
            s,
            r##"<text x="{LEFT}" y="{:.1}" fill="#1f77b4">— error, loads given</text><text x="{}" y="{:.1}" fill="#d62728">— error, loads withheld</text><text x="{}" y="{:.1}" fill="#777777">■ ±2σ (posterior, world frame)</text>"##,
            bottom + 45.0,
            LEFT + 200.0,
            bottom + 45.0,
            LEFT + 420.0,
            bottom + 45.0
        );
        let _ = writeln!(s, "</svg>");
        Some(s)
    }
}

/// Fraction of (sample, component) pairs of a tip trace with |error| ≤ 2σ; NaN when empty.
fn inside_fraction(trace: &[super::TipSample]) -> f64 {
    if trace.is_empty() {
        return f64::NAN;
    }
    let inside: usize = trace
        .iter()
        .map(|p| {
            (0..3)
                .filter(|&c| p.error[c].abs() <= 2.0 * p.sigma[c])
                .count()
        })
        .sum();
    inside as f64 / (3 * trace.len()) as f64
}
