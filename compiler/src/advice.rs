//! Which tier a scene needs (docs/design.md §10): a note from a cheap linear computation set
//! against the measured angle limits of the warped tier.
//!
//! For each load group g, the linear static response to a unit world force along d (|d| = 1),
//! u = K⁻¹ B_g d, gives at every output point p (sensors, load patches, displayed nodes) the
//! linearised rotation ω_p = Ω_p d (rad per N; Ω_p the 3×3 block of the ω rows of
//! [`Reductor::static_outputs`] against the group's x, y, z channels). The largest rotation per
//! newton over directions and points is θ′_g = max_p σ_max(Ω_p) (rad/N), and at the group's
//! range F_g (the load's `range`, or its `[reduction.corotational] ranges` entry, when given) θ_g = F_g θ′_g. No factorisation
//! of its own: the modal stage's K⁻¹B, shared with the force states' static residual.
//!
//! The rule compares θ_g with the rotation up to which the warped tier's open-loop error stayed
//! under 5 % against the full-order co-rotational FEM, measured on the example scenes' report
//! scenarios with the loads scaled (`crokf-verify report --sweep`, docs/results/verification.md "Where the warping
//! approximation breaks down", r = 16): [`WARPED_5_PERCENT_BENDING_DEG`] on the bending
//! cantilever, [`WARPED_5_PERCENT_CLAMPED_DEG`] on the doubly clamped meniscus. Up to the
//! smaller limit both measured bodies were under 5 %; beyond the larger, neither was; between
//! them the outcome depended on the body (bending-dominated or not), which this linear
//! estimate cannot tell. θ_g is a linear estimate: the largest rotation of the co-rotational
//! reference at the same load differs (the cantilever at 20 N: 67° co-rotational, dynamic;
//! θ = PL²/2EI ≈ 69° static linear for an Euler–Bernoulli beam), and the measured limits are
//! in the reference's rotation, so the rule is a guide with its basis stated, not a bound.

use crate::fem::operators::InputKind;
use crate::reductor::Reductor;
use crate::scene::ModelTier;

/// Largest rotation (degrees, co-rotational reference, displayed nodes) at which the warped
/// tier's open-loop error was still under 5 % on the bending cantilever: 4.3 % at 25.9°,
/// 6.3 % at 37.3° (models/cantilever/verification/sweep.md, r = 16).
pub const WARPED_5_PERCENT_BENDING_DEG: f64 = 25.9;

/// The same on the doubly clamped meniscus: 2.2 % at 5.2°, 5.4 % at 12.9°
/// (models/meniscus/verification/sweep.md, r = 16).
pub const WARPED_5_PERCENT_CLAMPED_DEG: f64 = 5.2;

/// The largest linear static rotation of one load group.
#[derive(Clone, Debug, PartialEq)]
pub struct GroupRotation {
    /// Load group name.
    pub name: String,
    /// θ′_g: largest rotation per newton over directions and output points, degrees/N.
    pub per_newton_deg: f64,
    /// The group's range F_g (the load's `range` or its tier `ranges` entry), N, if given.
    pub range: Option<f64>,
}

impl GroupRotation {
    /// θ_g = F_g θ′_g, degrees, when the range is given.
    pub fn at_range_deg(&self) -> Option<f64> {
        self.range.map(|f| f * self.per_newton_deg)
    }
}

/// θ′_g (and θ_g) of every load group with a force input channel; see the module docs.
pub fn linear_rotations(reductor: &Reductor) -> Result<Vec<GroupRotation>, String> {
    let full = reductor.full;
    let ops = &full.operators;
    let statics = reductor.static_outputs();
    let rows = &reductor.rows;
    // ω rows: per sensor after its 3 displacement rows, per load group, per displayed node.
    let mut omega_rows: Vec<usize> = (0..rows.sensors.len())
        .map(|s| rows.sensor_row(s) + 3)
        .collect();
    omega_rows.extend((0..rows.loads.len()).map(|g| rows.load_row(g)));
    for (set, nodes) in rows.node_sets.iter().enumerate() {
        omega_rows.extend((0..nodes.len()).map(|i| rows.node_row(set, i) + 3));
    }
    let scene = &full.scene.scene;
    let mut out = Vec::new();
    for (g, load) in ops.loads.iter().enumerate() {
        let mut columns: [Option<usize>; 3] = [None; 3];
        for (j, ch) in ops.inputs.iter().enumerate() {
            if let InputKind::Load { load, component } = ch.kind {
                if load == g && component < 3 {
                    columns[component] = Some(j);
                }
            }
        }
        if columns.iter().all(Option::is_none) {
            continue;
        }
        let mut largest = 0.0f64;
        for &row in &omega_rows {
            let block = nalgebra::Matrix3::from_fn(|a, c| {
                columns[c].map_or(0.0, |j| statics[(row + a, j)])
            });
            let sigma = block.singular_values().max();
            largest = largest.max(sigma);
        }
        out.push(GroupRotation {
            name: load.name.clone(),
            per_newton_deg: largest.to_degrees(),
            range: scene
                .loads
                .iter()
                .find(|l| l.name == load.name)
                .and_then(|l| scene.load_range(l)),
        });
    }
    Ok(out)
}

/// The compiler's note on which tier the scene needs (one line for report.json's notes and
/// stderr), or why it could not be computed; `None` for a scene without load groups.
pub fn tier_advice(reductor: &Reductor) -> Option<String> {
    let tier = reductor.full.scene.scene.reduction.model;
    let groups = match linear_rotations(reductor) {
        Ok(g) => g,
        Err(why) => return Some(format!("tier advice not computed: {why}")),
    };
    if groups.is_empty() {
        return None;
    }
    let (low, high) = (WARPED_5_PERCENT_CLAMPED_DEG, WARPED_5_PERCENT_BENDING_DEG);
    let mut parts = Vec::new();
    let mut worst: Option<f64> = None;
    for g in &groups {
        let limits = if g.per_newton_deg > 0.0 {
            format!(
                "{low}° at {:.3} N, {high}° at {:.3} N",
                low / g.per_newton_deg,
                high / g.per_newton_deg
            )
        } else {
            "no rotation".to_owned()
        };
        match g.at_range_deg() {
            Some(theta) => {
                worst = Some(worst.map_or(theta, |w: f64| w.max(theta)));
                parts.push(format!(
                    "'{}' {:.3}°/N, {:.1}° at its range {} N ({limits})",
                    g.name,
                    g.per_newton_deg,
                    theta,
                    g.range.unwrap_or(f64::NAN)
                ));
            }
            None => parts.push(format!(
                "'{}' {:.3}°/N ({limits})",
                g.name, g.per_newton_deg
            )),
        }
    }
    let verdict = match worst {
        None => "no load range given: compare your largest load with the forces above".to_owned(),
        Some(theta) if theta <= low => {
            format!("{theta:.1}° ≤ {low}°: within both measured limits, the warped tier suffices")
        }
        Some(theta) if theta <= high => format!(
            "{low}° < {theta:.1}° ≤ {high}°: between the measured limits, the warped tier may \
             do for a bending-dominated body (the cantilever) but did not for a clamped, \
             stretch–bend coupled one (the meniscus); measure it (`crokf-verify report \
             --corotational`) or use the co-rotational tier"
        ),
        Some(theta) => format!(
            "{theta:.1}° > {high}°: beyond both measured limits, the co-rotational tier is \
             needed ([reduction] model = \"corotational\")"
        ),
    };
    let which = match tier {
        ModelTier::Warped => "this is a warped compile",
        ModelTier::Corotational => "this compile has the co-rotational tier (for the record)",
    };
    Some(format!(
        "tier advice ({which}): largest linear static rotation over sensors, load patches and \
         displayed nodes per load group: {}; {verdict}. Basis: the warped tier's open-loop \
         error stayed under 5 % up to {high}° on the bending cantilever and {low}° on the \
         doubly clamped meniscus (docs/verification.md, \"Where the warping approximation breaks down\", \
         r = 16); the angle here is linear, an estimate of the co-rotational one",
        parts.join("; ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::full_order::FullOrder;
    use crate::mesh::procedural::{box_mesh, write_msh22, BeamScene};
    use crate::timer::StageTimer;

    /// A 1 m × 0.1 m × 0.1 m cantilever (12 × 2 × 2 cells, E = 1 MPa), tip load on x = 1,
    /// sensors at the end and mid-span (top face), the end face displayed; `extra` appended.
    fn beam(name: &str, extra: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("crokf-advice-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        write_msh22(
            &box_mesh([12, 2, 2], [1.0, 0.1, 0.1]),
            &dir.join("beam.msh"),
        )
        .expect("mesh");
        let text = BeamScene {
            sensors: vec![
                ("tip".into(), [0.99, 0.05, 0.1]),
                ("mid".into(), [0.5, 0.05, 0.1]),
            ],
            displays: vec![("end".into(), "xmax".into())],
            dt: 0.005,
            ..BeamScene::default()
        }
        .toml()
            + extra;
        let path = dir.join("scene.toml");
        std::fs::write(&path, text).expect("scene");
        path
    }

    #[test]
    fn the_linear_rotation_is_the_beams_end_slope_and_scales_with_the_range() {
        let scene = beam(
            "range",
            "[reduction]\nmodel = \"corotational\"\n[reduction.corotational]\nranges = { tip = 20.0 }\nduration = 0.1\n",
        );
        let mut timer = StageTimer::default();
        let full = FullOrder::build(&scene, &mut timer).expect("front end");
        let reductor = Reductor::new(&full, None, &mut timer).expect("reductor");
        let groups = linear_rotations(&reductor).expect("rotations");
        assert_eq!(groups.len(), 1);
        let g = &groups[0];
        assert_eq!(g.name, "tip");
        assert_eq!(g.range, Some(20.0));
        assert!((g.at_range_deg().expect("range") - 20.0 * g.per_newton_deg).abs() < 1e-12);
        // Independent figure: a cantilever under a tip load has its largest rotation at the free
        // end, θ = P L² / 2EI = (3/2) δ / L with δ = P L³ / 3EI the end deflection (Euler–
        // Bernoulli); δ per newton from the tip sensor's static response (z rows), L = 1 m.
        let statics = reductor.static_outputs();
        let z = reductor
            .full
            .operators
            .inputs
            .iter()
            .position(|c| {
                c.kind
                    == InputKind::Load {
                        load: 0,
                        component: 2,
                    }
            })
            .expect("tip.z channel");
        let deflection = statics[(reductor.rows.sensor_row(0) + 2, z)].abs();
        let slope_deg = (1.5 * deflection / 1.0).to_degrees();
        let ratio = g.per_newton_deg / slope_deg;
        // Shear and the coarse mesh's local rotations at the loaded face: within 20 %.
        assert!(
            (ratio - 1.0).abs() < 0.2,
            "{} °/N vs {slope_deg} °/N",
            g.per_newton_deg
        );
        let note = tier_advice(&reductor).expect("note");
        assert!(
            note.contains("co-rotational tier (for the record)"),
            "{note}"
        );
        assert!(note.contains("at its range 20 N"), "{note}");
    }

    #[test]
    fn the_verdict_follows_the_measured_limits() {
        // Per newton only (no range): the forces at the two measured limits are named.
        let scene = beam("per_newton", "");
        let mut timer = StageTimer::default();
        let full = FullOrder::build(&scene, &mut timer).expect("front end");
        let reductor = Reductor::new(&full, None, &mut timer).expect("reductor");
        let g = linear_rotations(&reductor).expect("rotations").remove(0);
        let note = tier_advice(&reductor).expect("note");
        assert!(note.contains("this is a warped compile"), "{note}");
        assert!(note.contains("no load range given"), "{note}");
        let at_high = format!("{:.3} N", WARPED_5_PERCENT_BENDING_DEG / g.per_newton_deg);
        assert!(note.contains(&at_high), "{note} lacks {at_high}");
    }
}
