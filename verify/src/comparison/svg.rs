//! SVG plots of a comparison: step time against error over the orders, and the tip marker's
//! error with its ±2σ band along the trajectory.

use std::fmt::Write as _;

use crate::bench::STEP_CLOCK;

use super::render::{decade_seconds, tier_order};
use super::{Comparison, Consistency, ReducedRow};

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
        self.tip_plot(
            &label,
            &row.figures.consistency,
            &row.figures.withheld_consistency,
        )
    }

    /// The same plot for the co-rotational tier's row ([`Comparison::tip_svg`]; σ from the
    /// tier's own stored filters, world frame), or `None` without a tier or a tip trace.
    pub fn tier_tip_svg(&self) -> Option<String> {
        let t = self.tier.as_ref()?;
        let label = format!("co-rotational tier {}", tier_order(t));
        self.tip_plot(
            &label,
            &t.figures.consistency,
            &t.figures.withheld_consistency,
        )
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
