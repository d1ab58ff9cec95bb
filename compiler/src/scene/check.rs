//! The scene's range checks that need no mesh: every field finite and inside its documented
//! range, every selection well-formed, the load, noise and tier fields consistent with each
//! other (and the tier's size with the snapshots its training stores). Each refusal names the
//! entry and the field.

mod training_size;

use super::*;

/// `Ok` when `v` is finite and in `[lo, hi]`, else a message naming `field`, its unit and range.
fn in_range(field: &str, v: f64, (lo, hi): (f64, f64), unit: &str) -> Result<(), String> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        let lower = if lo > 0.0 { " > 0 and" } else { "" };
        Err(format!(
            "{field} = {v} {unit} is out of range: it must be{lower} within [{lo:e}, {hi:e}] {unit}"
        ))
    }
}

fn check_point(field: &str, p: [f64; 3]) -> Result<(), String> {
    if p.iter()
        .all(|v| v.is_finite() && v.abs() <= limits::COORDINATE)
    {
        Ok(())
    } else {
        Err(format!(
            "{field} = {p:?} is out of range: coordinates must be finite with |x| ≤ {:e} (mesh \
             units)",
            limits::COORDINATE
        ))
    }
}

/// Checks a `group`/`select` pair; `material` when the entry takes tetrahedra.
fn check_target(
    context: &str,
    group: &Option<String>,
    select: &Option<Vec<Selector>>,
    material: bool,
) -> Result<(), String> {
    match (group, select) {
        (Some(_), Some(_)) => {
            return Err(format!(
                "{context}: give either `group` or `select`, not both"
            ))
        }
        (None, None) => {
            return Err(format!(
                "{context}: missing `group = \"name\"` or `select = [...]` (see the scene schema \
                 in compiler/src/scene.rs)"
            ))
        }
        (Some(_), None) => return Ok(()),
        (None, Some(list)) if list.is_empty() => {
            return Err(format!("{context}: `select` is empty"))
        }
        (None, Some(_)) => {}
    }
    for (i, sel) in select.iter().flatten().enumerate() {
        let here = format!("{context}: select[{i}]");
        let given = [
            sel.aabb.is_some(),
            sel.sphere.is_some(),
            sel.half_space.is_some(),
            sel.node_list.is_some(),
            sel.group.is_some(),
            sel.everything.is_some(),
        ]
        .iter()
        .filter(|&&b| b)
        .count();
        if given != 1 {
            return Err(format!(
                "{here}: a selector takes exactly one of box, sphere, half_space, node_list, \
                 group, everything ({given} given)"
            ));
        }
        if sel.everything == Some(false) {
            return Err(format!(
                "{here}: `everything = false` selects nothing; remove it"
            ));
        }
        if let Some(b) = &sel.aabb {
            check_point(&format!("{here}: box.min"), b.min)?;
            check_point(&format!("{here}: box.max"), b.max)?;
            if (0..3).any(|c| b.min[c] > b.max[c]) {
                return Err(format!(
                    "{here}: box.min {:?} must not exceed box.max {:?} in any component",
                    b.min, b.max
                ));
            }
        }
        if let Some(sp) = &sel.sphere {
            check_point(&format!("{here}: sphere.center"), sp.center)?;
            if !(sp.radius.is_finite() && sp.radius > 0.0 && sp.radius <= limits::COORDINATE) {
                return Err(format!(
                    "{here}: sphere.radius = {} is out of range: it must be > 0 and ≤ {:e} (mesh \
                     units)",
                    sp.radius,
                    limits::COORDINATE
                ));
            }
        }
        if let Some(h) = &sel.half_space {
            check_point(&format!("{here}: half_space.point"), h.point)?;
            check_point(&format!("{here}: half_space.normal"), h.normal)?;
            if h.normal.iter().all(|&v| v == 0.0) {
                return Err(format!("{here}: half_space.normal must not be zero"));
            }
        }
        let shape = sel.aabb.is_some()
            || sel.sphere.is_some()
            || sel.half_space.is_some()
            || sel.everything.is_some();
        if material {
            if sel.nodes.is_some() {
                return Err(format!(
                    "{here}: `nodes` does not apply to a material, which takes the tetrahedra \
                     whose centroid lies in the shape; remove it"
                ));
            }
            if sel.node_list.is_some() {
                return Err(format!(
                    "{here}: a material takes tetrahedra, not a node list; use a shape or a group"
                ));
            }
        } else if shape && sel.nodes.is_none() {
            return Err(format!(
                "{here}: state which nodes the {} takes: add nodes = \"boundary\" (nodes on the \
                 mesh boundary) or nodes = \"all\"",
                sel.describe()
            ));
        } else if !shape && sel.nodes.is_some() {
            return Err(format!(
                "{here}: `nodes` applies to shapes and `everything` only; remove it"
            ));
        }
    }
    Ok(())
}

/// Most directions a scene may list (each adds runs per load group and per pair).
const MAX_DIRECTIONS: usize = 26;

/// A listed training direction is finite and non-zero, and no two point the same way.
fn check_directions(field: &str, list: &[[f64; 3]]) -> Result<(), String> {
    if list.is_empty() || list.len() > MAX_DIRECTIONS {
        return Err(format!(
            "{field}: list between 1 and {MAX_DIRECTIONS} directions [x, y, z], got {}",
            list.len()
        ));
    }
    let unit = |d: &[f64; 3]| d.map(|x| x / length3(d));
    for (i, d) in list.iter().enumerate() {
        let norm = length3(d);
        if !norm.is_finite() || norm == 0.0 {
            return Err(format!(
                "{field}[{i}] = {d:?}: a direction must be finite and non-zero"
            ));
        }
        let u = unit(d);
        if let Some(j) = list[..i]
            .iter()
            .position(|e| unit(e).iter().zip(&u).map(|(a, b)| a * b).sum::<f64>() > 1.0 - 1e-9)
        {
            return Err(format!(
                "{field}[{i}] = {d:?} points the same way as {field}[{j}] = {:?}: list each \
                 direction once",
                list[j]
            ));
        }
    }
    Ok(())
}

/// Most training load cases a scene may state.
const MAX_CASES: usize = 64;

impl CorotationalSpec {
    /// `case` entries: each names trained groups (in `ranges`) with finite forces of length in
    /// (0, 1] of the range; names are unique; not together with `directions` or
    /// `combinations` (which generate the runs the cases replace).
    fn check_cases(&self) -> Result<(), String> {
        if self.cases.is_empty() {
            return Ok(());
        }
        let f = |name: &str| format!("reduction.corotational.{name}");
        for (field, stated) in [
            ("directions", self.directions.is_some()),
            ("combinations", self.combinations.is_some()),
        ] {
            if stated {
                return Err(format!(
                    "{}: the scene lists its training cases ([[reduction.corotational.case]]), \
                     which replace the runs `{field}` generates; remove `{field}` or the cases",
                    f(field)
                ));
            }
        }
        if self.cases.len() > MAX_CASES {
            return Err(format!(
                "{}: at most {MAX_CASES} training cases, got {}",
                f("case"),
                self.cases.len()
            ));
        }
        let mut names: Vec<String> = Vec::new();
        for (i, case) in self.cases.iter().enumerate() {
            let here = f(&format!("case[{i}]"));
            if case.loads.is_empty() {
                return Err(format!(
                    "{here}.loads: name at least one load group and its force, e.g. \
                     loads = {{ push = [0, 1, 0] }}"
                ));
            }
            for (group, v) in &case.loads {
                if !self.ranges.contains_key(group) {
                    return Err(format!(
                        "{here}.loads.{group}: not a trained load group (groups with a range: {})",
                        self.ranges.keys().cloned().collect::<Vec<_>>().join(", ")
                    ));
                }
                let length = length3(v);
                if !length.is_finite() || length == 0.0 || length > 1.0 + 1e-12 {
                    return Err(format!(
                        "{here}.loads.{group} = {v:?}: the force is a multiple of the group's \
                         range per axis, of length in (0, 1]; got length {length}"
                    ));
                }
            }
            let name = case
                .name
                .clone()
                .unwrap_or_else(|| format!("case {}", i + 1));
            if names.contains(&name) {
                return Err(format!("{here}.name: '{name}' is used by another case"));
            }
            names.push(name);
        }
        Ok(())
    }

    /// The snapshots the training stores against what the tier needs (`dt` the scene's time
    /// step, s; `loads` its load names, in order): the training's runs
    /// ([`CorotationalSpec::training_run_count`]) each keep ceil(N / every) snapshots,
    /// N = round(duration / dt) steps ([`CorotationalSpec::training_steps`]; every `every`-th
    /// step and the last). Refused: an `every` that keeps
    /// only each run's last step (N > 1, every ≥ N: the training would see no run's motion),
    /// and a pooled POD size above the snapshot count (a POD has at most as many vectors as
    /// snapshots). The pooled size is `order`, whether the basis is the pooled POD alone or is
    /// enriched to `basis_tolerance` (then `order` comes first, and `max_order` only caps the
    /// enrichment, which the snapshots bound as well); when the scene states the tier's size
    /// without `order` ([`CorotationalSpec::states_size`]), the default
    /// [`DEFAULT_TIER_ORDER`] is that size and is checked the same way. Without a stated size
    /// the fidelity rule chooses it from the snapshots there are.
    fn check_snapshots(&self, dt: f64, loads: &[String]) -> Result<(), String> {
        let f = |name: &str| format!("reduction.corotational.{name}");
        let runs = self.training_run_count(loads);
        let steps = self.training_steps(dt);
        let every = self.every.max(1);
        // ceil(steps / every): the multiples of `every` up to N, and N itself.
        let per_run = steps.div_ceil(every);
        let total = runs.saturating_mul(per_run);
        let run = format!(
            "each training run is duration / time.dt = {} s / {dt} s = {steps} steps",
            self.duration
        );
        let with_every = |e: usize| {
            let per = steps.div_ceil(e);
            format!(
                "every = {e} keeps {per} per run, {} in all",
                runs.saturating_mul(per)
            )
        };
        if steps > 1 && every >= steps {
            let hint = if self.every > 5 && steps > 5 {
                format!(" (the default {})", with_every(5))
            } else {
                String::new()
            };
            return Err(format!(
                "{} = {} keeps 1 snapshot per training run, its last step ({run}; a snapshot \
                 every {} steps, and the last), {total} snapshot{} in all from {runs} run{}: the \
                 tier would be trained on end states only, not on the runs' motion; use every \
                 < {steps}{hint}",
                f("every"),
                self.every,
                self.every,
                if total == 1 { "" } else { "s" },
                if runs == 1 { "" } else { "s" },
            ));
        }
        if !self.states_size() {
            return Ok(());
        }
        let order = self.order();
        if order <= total {
            return Ok(());
        }
        let field = match self.order {
            Some(_) => format!("{} = {order}", f("order")),
            None => format!(
                "{} (not stated: the default {order}, the pooled POD size when the scene states \
                 basis_tolerance, ecsw_tolerance or ecsw_max_elements)",
                f("order")
            ),
        };
        let enrich = if self.basis_tolerance.is_some() {
            "; with basis_tolerance the enrichment adds vectors within the same snapshots, so \
             they bound the whole basis too"
        } else {
            ""
        };
        // The largest `every` keeping ceil(order / runs) snapshots per run, if one does.
        let need = order.div_ceil(runs.max(1));
        let more = if need <= steps && need >= 2 {
            let e = (steps.div_ceil(need - 1) - 1).max(1);
            format!(", or keep more snapshots: {}", with_every(e))
        } else if need <= steps {
            String::new()
        } else {
            format!(
                ", or lengthen the runs (duration): even every = 1 keeps only {steps} per run, \
                 {} in all",
                runs.saturating_mul(steps)
            )
        };
        Err(format!(
            "{field} asks for more POD vectors than the training stores snapshots: {runs} \
             run{} × {per_run} snapshot{} per run = {total} ({run}; a snapshot every {} steps, \
             and the last){enrich}; use order ≤ {total}{more}",
            if runs == 1 { "" } else { "s" },
            if per_run == 1 { "" } else { "s" },
            self.every,
        ))
    }

    /// Range checks; `loads` are the scene's load names. Messages name the field.
    fn check(&self, loads: &[&str]) -> Result<(), String> {
        let f = |name: &str| format!("reduction.corotational.{name}");
        if self.ranges.is_empty() {
            return Err(format!(
                "{}: name at least one load group and its force range in N (or state `range` on \
                 the load)",
                f("ranges")
            ));
        }
        for (name, &range) in &self.ranges {
            if !loads.contains(&name.as_str()) {
                return Err(format!(
                    "{}: '{name}' is not a load of the scene (loads: {})",
                    f("ranges"),
                    loads.join(", ")
                ));
            }
            in_range(&format!("{}.{name}", f("ranges")), range, (1e-9, 1e9), "N")?;
            if range <= 0.0 {
                return Err(format!("{}.{name} must be > 0 N", f("ranges")));
            }
        }
        in_range(&f("duration"), self.duration, (1e-6, 1e4), "s")?;
        if self.every == 0 {
            return Err(format!("{} must be ≥ 1", f("every")));
        }
        in_range(&f("ramp_multiple"), self.ramp_multiple, (0.0, 100.0), "")?;
        in_range(&f("step_multiple"), self.step_multiple, (0.0, 100.0), "")?;
        if self.ramp_multiple == 0.0 && self.step_multiple == 0.0 {
            return Err(format!(
                "{} and {} are both 0: no training run",
                f("ramp_multiple"),
                f("step_multiple")
            ));
        }
        if let Some(t) = self.ramp_time {
            in_range(&f("ramp_time"), t, (0.0, self.duration), "s")?;
        }
        if let Some(TrainingDirections::List(list)) = &self.directions {
            check_directions(&f("directions"), list)?;
        }
        self.check_cases()?;
        if let Some(order) = self.order.filter(|r| !(1..=200).contains(r)) {
            return Err(format!(
                "{} = {order} is out of range: it must be within [1, 200]",
                f("order")
            ));
        }
        if let Some(eps) = self.basis_tolerance {
            in_range(&f("basis_tolerance"), eps, (1e-6, 1.0), "")?;
            if eps <= 0.0 {
                return Err(format!("{} must be > 0", f("basis_tolerance")));
            }
        }
        if let Some(max) = self.max_order.filter(|m| !(self.order()..=400).contains(m)) {
            return Err(format!(
                "{} = {max} is out of range: it must be within [order = {}, 400]",
                f("max_order"),
                self.order()
            ));
        }
        if let Some(cap) = self
            .ecsw_max_elements
            .filter(|c| !(1..=100_000).contains(c))
        {
            return Err(format!(
                "{} = {cap} is out of range: it must be within [1, 100000]",
                f("ecsw_max_elements")
            ));
        }
        if let Some(tolerance) = self.ecsw_tolerance {
            in_range(&f("ecsw_tolerance"), tolerance, (1e-8, 0.5), "")?;
            if tolerance <= 0.0 {
                return Err(format!("{} must be > 0", f("ecsw_tolerance")));
            }
        }
        if let Some(c) = self.model_error_scale {
            in_range(&f("model_error_scale"), c, (0.0, 1e6), "")?;
        }
        if let Some(angle) = self.max_rotation {
            in_range(&f("max_rotation"), angle, (0.0, 180.0), "degrees")?;
            if angle <= 0.0 {
                return Err(format!("{} must be > 0 degrees", f("max_rotation")));
            }
        }
        in_range(
            &f("newton_tolerance"),
            self.newton_tolerance,
            (1e-14, 1e-1),
            "",
        )?;
        if !(1..=100).contains(&self.newton_iterations) {
            return Err(format!(
                "{} = {} is out of range: it must be within [1, 100]",
                f("newton_iterations"),
                self.newton_iterations
            ));
        }
        Ok(())
    }
}

impl Scene {
    /// Range checks that need no mesh.
    pub(super) fn check(&self) -> Result<(), String> {
        if self.materials.is_empty() {
            return Err("no [[material]]: every volume group needs E, ν and ρ".into());
        }
        for (i, m) in self.materials.iter().enumerate() {
            let context = match &m.group {
                Some(g) => format!("material '{g}'"),
                None => format!("material {}", i + 1),
            };
            check_target(&context, &m.group, &m.select, true)?;
            let g = &context;
            in_range(
                &format!("{g}: young_modulus"),
                m.young_modulus,
                limits::YOUNG_MODULUS,
                "Pa",
            )?;
            if !(m.poisson_ratio.is_finite() && m.poisson_ratio > -1.0 && m.poisson_ratio < 0.5) {
                return Err(format!(
                    "{g}: poisson_ratio must lie in (-1, 0.5), got {} \
                     (ν = 0.5 is incompressible: linear tetrahedra cannot represent it)",
                    m.poisson_ratio
                ));
            }
            in_range(
                &format!("{g}: density"),
                m.density,
                limits::DENSITY,
                "kg/m³",
            )?;
        }
        let d = self.damping;
        in_range("damping.alpha", d.alpha, limits::ALPHA, "1/s")?;
        in_range("damping.beta", d.beta, limits::BETA, "s")?;
        let t = self.time;
        in_range("time.dt", t.dt, limits::DT, "s")?;
        if !(t.theta.is_finite() && t.theta >= limits::THETA.0 && t.theta <= limits::THETA.1) {
            return Err(format!(
                "time.theta must be ≥ 1.37 for unconditional stability (and ≤ {}), got {}",
                limits::THETA.1,
                t.theta
            ));
        }
        if t.scheme == Scheme::Exact {
            if let Some(why) = self.exact_scheme_refusal() {
                return Err(why.into());
            }
        }
        if let Some(g) = self.gravity {
            if g.iter()
                .any(|v| !(v.is_finite() && v.abs() <= limits::GRAVITY))
            {
                return Err(format!(
                    "gravity = {g:?} m/s² is out of range: every component must be finite with \
                     |g| ≤ {:e} m/s²",
                    limits::GRAVITY
                ));
            }
        }
        for (i, f) in self.fixed.iter().enumerate() {
            let context = match &f.group {
                Some(g) => format!("fixed '{g}'"),
                None => format!("fixed {}", i + 1),
            };
            check_target(&context, &f.group, &f.select, false)?;
            if f.components.is_empty() {
                return Err(format!(
                    "{context}: components = [] fixes nothing; list the fixed components \
                     (e.g. components = [\"z\"]) or leave the key out to fix all three"
                ));
            }
        }
        let mut names = std::collections::BTreeSet::new();
        for l in &self.loads {
            if !names.insert(l.name.as_str()) {
                return Err(format!("load '{}': name used twice", l.name));
            }
            check_target(&format!("load '{}'", l.name), &l.group, &l.select, false)?;
            in_range(
                &format!("load '{}': force_noise_std", l.name),
                l.force_noise_std,
                limits::FORCE_NOISE,
                "N",
            )?;
            in_range(
                &format!("load '{}': force_rate_noise_std", l.name),
                l.force_rate_noise_std,
                limits::FORCE_NOISE,
                "N/s",
            )?;
            if let Some(range) = l.range {
                in_range(
                    &format!("load '{}': range", l.name),
                    range,
                    (1e-9, 1e9),
                    "N",
                )?;
                if range <= 0.0 {
                    return Err(format!("load '{}': range must be > 0 N", l.name));
                }
            }
            if let Some(t) = l.rise_time {
                in_range(
                    &format!("load '{}': rise_time", l.name),
                    t,
                    (1e-6, 1e4),
                    "s",
                )?;
                if t <= 0.0 {
                    return Err(format!("load '{}': rise_time must be > 0 s", l.name));
                }
            }
            if l.force_noise_std > 0.0 && l.force_model_stated.is_none() {
                return Err(format!(
                    "load '{}': force_noise_std without force_model: loads are estimated by \
                     default (force_model = \"random_walk\", force σ derived from `range` and \
                     `rise_time`); write force_model = \"random_walk\" to state the σ of the \
                     force's change per step, or force_model = \"white\" for white noise on a \
                     load the runtime is told",
                    l.name
                ));
            }
            if l.is_estimated() && l.force_noise_std <= 0.0 && self.load_range(l).is_none() {
                return Err(format!(
                    "load '{}': the filter estimates this load (force_model = \"random_walk\", \
                     the default) and needs what it may do: state its range (N, the largest \
                     total force it reaches) and, if not {DEFAULT_RISE_TIME} s, its rise_time (s, \
                     the shortest time from zero to the range), from which the compiler derives \
                     the force σ; or force_noise_std (N per step); or force_model = \"white\" \
                     for a load the runtime is always told",
                    l.name
                ));
            }
            if !l.is_estimated() && l.rise_time.is_some() {
                return Err(format!(
                    "load '{}': rise_time is for estimated loads (force_model = \"random_walk\"); \
                     remove it or the force_model = \"white\"",
                    l.name
                ));
            }
            if l.force_rate_noise_std > 0.0
                && (!l.is_estimated() || self.reduction.model != ModelTier::Corotational)
            {
                return Err(format!(
                    "load '{}': force_rate_noise_std needs force_model = \"random_walk\" (the \
                     default) and reduction.model = \"corotational\" (the rate states are the \
                     co-rotational tier's)",
                    l.name
                ));
            }
        }
        for n in &self.force_noise {
            if !names.insert(n.name.as_str()) {
                return Err(format!("force_noise '{}': name used twice", n.name));
            }
            check_target(
                &format!("force_noise '{}'", n.name),
                &n.group,
                &n.select,
                false,
            )?;
            if !(n.std.is_finite() && n.std > 0.0) {
                return Err(format!(
                    "force_noise '{}': std must be > 0 N, got {}",
                    n.name, n.std
                ));
            }
            in_range(
                &format!("force_noise '{}': std", n.name),
                n.std,
                limits::FORCE_NOISE,
                "N",
            )?;
        }
        let mut sensor_names = std::collections::BTreeSet::new();
        for s in &self.sensors {
            if !sensor_names.insert(s.name.as_str()) {
                return Err(format!("sensor '{}': name used twice", s.name));
            }
            if s.position.iter().any(|v| !v.is_finite()) {
                return Err(format!("sensor '{}': position must be finite", s.name));
            }
            check_point(&format!("sensor '{}': position", s.name), s.position)?;
            if s.components.is_empty() {
                return Err(format!("sensor '{}': no measured components", s.name));
            }
            for &c in &s.components {
                let sigma = s.noise_std.of(c);
                if !(sigma.is_finite() && sigma > 0.0) {
                    return Err(format!(
                        "sensor '{}': noise_std of component {} must be > 0 m (R must be positive \
                         definite), got {sigma}",
                        s.name,
                        c.label()
                    ));
                }
                in_range(
                    &format!("sensor '{}': noise_std of component {}", s.name, c.label()),
                    sigma,
                    limits::SENSOR_NOISE,
                    "m",
                )?;
            }
            if s.every == 0 {
                return Err(format!("sensor '{}': every must be ≥ 1", s.name));
            }
        }
        let mut display_names = std::collections::BTreeSet::new();
        for d in &self.display {
            if !display_names.insert(d.name.as_str()) {
                return Err(format!("display '{}': name used twice", d.name));
            }
            check_target(&format!("display '{}'", d.name), &d.group, &d.select, false)?;
        }
        if let Some(tol) = self.reduction.tolerance {
            if !(tol > 0.0 && tol < 1.0) {
                return Err(format!("reduction.tolerance must lie in (0, 1), got {tol}"));
            }
        }
        if self.reduction.order == Some(0) {
            return Err("reduction.order must be ≥ 1".into());
        }
        if let Some(f) = self.reduction.max_frequency {
            let highest = crokf_kernel::wilson::highest_resolved_hz(self.time.dt);
            if !(f > 0.0 && f <= highest) {
                return Err(format!(
                    "reduction.max_frequency = {f} Hz is out of range: it must be > 0 and at most \
                     1/(4 time.dt) = {highest:.6e} Hz (Wilson-θ damps faster modes numerically)"
                ));
            }
            if self.reduction.modes.is_some() {
                return Err(
                    "reduction: give either modes (a count) or max_frequency (Hz), not both".into(),
                );
            }
        }
        match (self.reduction.model, &self.reduction.corotational) {
            (ModelTier::Corotational, Some(spec)) => {
                let loads: Vec<&str> = self.loads.iter().map(|l| l.name.as_str()).collect();
                spec.check(&loads)?;
                let names: Vec<String> = self.loads.iter().map(|l| l.name.clone()).collect();
                spec.check_snapshots(self.time.dt, &names)?;
            }
            (ModelTier::Corotational, None) => {
                return Err(
                    "reduction.model = \"corotational\" needs a [reduction.corotational] \
                            table (ranges, duration: the training envelope)"
                        .into(),
                )
            }
            (ModelTier::Warped, Some(_)) => {
                return Err(
                    "[reduction.corotational] is only read with reduction.model = \
                            \"corotational\""
                        .into(),
                )
            }
            (ModelTier::Warped, None) => {}
        }
        Ok(())
    }
}
