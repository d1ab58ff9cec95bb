//! `Model::validate`: shapes, indices and finiteness.

use crate::{FormatError, Matrix, Model};
use std::collections::BTreeSet;

fn invalid(path: impl Into<String>, message: impl Into<String>) -> FormatError {
    FormatError::Invalid {
        path: path.into(),
        message: message.into(),
    }
}

/// Checks data length, shape and finiteness of one matrix.
fn check_matrix(path: &str, m: &Matrix, rows: u64, cols: u64) -> Result<(), FormatError> {
    let declared = m.rows as u64 * m.cols as u64;
    if m.data.len() as u64 != declared {
        return Err(FormatError::DataLength {
            matrix: path.to_string(),
            rows: m.rows,
            cols: m.cols,
            len: m.data.len(),
        });
    }
    if m.rows as u64 != rows || m.cols as u64 != cols {
        return Err(FormatError::Shape {
            matrix: path.to_string(),
            expected_rows: rows,
            expected_cols: cols,
            rows: m.rows,
            cols: m.cols,
        });
    }
    check_finite(path, &m.data, m.cols as usize)
}

/// Symmetry of an n × n row-major matrix (finite, checked before): |a_ij − a_ji| ≤ 1e-9 ·
/// max|a|. The tier's element stiffness Kₑ = V Bᵀ D B is symmetric up to round-off; the
/// kernel's force multiplies by Kₑᵀ and the compiler's tangent by Kₑ (crokf-kernel), which
/// agree only for a symmetric Kₑ.
fn check_symmetric(path: &str, data: &[f64], n: usize) -> Result<(), FormatError> {
    let scale = data.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..n {
        for j in i + 1..n {
            let (a, b) = (data[i * n + j], data[j * n + i]);
            if (a - b).abs() > 1e-9 * scale {
                return Err(invalid(
                    path,
                    format!("must be symmetric: ({i}, {j}) = {a:e} but ({j}, {i}) = {b:e}"),
                ));
            }
        }
    }
    Ok(())
}

/// NaN/inf check; `cols` gives the (row, col) of the first offender (0: treat as a vector).
fn check_finite(path: &str, data: &[f64], cols: usize) -> Result<(), FormatError> {
    if let Some((k, &value)) = data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        let (row, col) = match (k.checked_div(cols), k.checked_rem(cols)) {
            (Some(row), Some(col)) => (row, col),
            _ => (0, k),
        };
        return Err(FormatError::NonFinite {
            matrix: path.to_string(),
            row,
            col,
            value,
        });
    }
    Ok(())
}

fn check_positive(path: &str, v: f64) -> Result<(), FormatError> {
    check_finite(path, &[v], 0)?;
    if v > 0.0 {
        Ok(())
    } else {
        Err(invalid(path, format!("must be > 0, got {v}")))
    }
}

fn check_component(path: &str, c: u8) -> Result<(), FormatError> {
    if c < 3 {
        Ok(())
    } else {
        Err(invalid(
            path,
            format!("component {c} is not 0 (x), 1 (y) or 2 (z)"),
        ))
    }
}

fn check_increasing<T: PartialOrd + Copy + std::fmt::Display>(
    path: &str,
    v: &[T],
) -> Result<(), FormatError> {
    for w in v.windows(2) {
        if w[0] >= w[1] {
            return Err(invalid(
                path,
                format!("must be strictly increasing, found {} then {}", w[0], w[1]),
            ));
        }
    }
    Ok(())
}

impl Model {
    /// Checks every shape against r = `state_dim`, m = `inputs.len()`, q =
    /// `measurements.len()`, every index, and that every matrix and numeric parameter is finite.
    /// Errors name the offending field, e.g. `sensors[1] 'tip'.rotation_rows`.
    pub fn validate(&self) -> Result<(), FormatError> {
        let r = self.state_dim as u64;
        let m = self.inputs.len() as u64;
        let q = self.measurements.len();

        check_positive("dt", self.dt)?;
        check_positive("theta", self.theta)?;
        if self.state_dim == 0 {
            return Err(invalid("state_dim", "must be ≥ 1"));
        }
        check_matrix("transition", &self.transition, r, r)?;
        check_matrix("input", &self.input, r, m)?;

        // Inputs: load indices in range, no (load, component) twice.
        let mut seen = BTreeSet::new();
        for (i, ch) in self.inputs.iter().enumerate() {
            let path = format!("inputs[{i}] '{}'", ch.label);
            match &ch.kind {
                crate::InputKind::Load { load, component } => {
                    if *load as usize >= self.loads.len() {
                        return Err(invalid(
                            path,
                            format!(
                                "load {load} out of range ({} load groups)",
                                self.loads.len()
                            ),
                        ));
                    }
                    check_component(&path, *component)?;
                    if !seen.insert((*load, *component)) {
                        return Err(invalid(
                            path,
                            format!("load {load} component {component} has two input channels"),
                        ));
                    }
                }
                crate::InputKind::Gravity { acceleration } => {
                    check_finite(&format!("{path}.acceleration"), acceleration, 0)?;
                }
            }
        }
        for (g, load) in self.loads.iter().enumerate() {
            let path = format!("loads[{g}] '{}'.rotation_rows", load.name);
            check_matrix(&path, &load.rotation_rows, 3, r)?;
        }

        for (s, sensor) in self.sensors.iter().enumerate() {
            let path = format!("sensors[{s}] '{}'", sensor.name);
            check_finite(&format!("{path}.position"), &sensor.position, 0)?;
            check_matrix(
                &format!("{path}.displacement_rows"),
                &sensor.displacement_rows,
                3,
                r,
            )?;
            check_matrix(
                &format!("{path}.rotation_rows"),
                &sensor.rotation_rows,
                3,
                r,
            )?;
            for &c in &sensor.components {
                check_component(&format!("{path}.components"), c)?;
            }
            let mut sorted = sensor.components.clone();
            sorted.sort_unstable();
            check_increasing(&format!("{path}.components (sorted)"), &sorted)?;
            if sensor.every == 0 {
                return Err(invalid(format!("{path}.every"), "must be ≥ 1"));
            }
        }

        let mut seen = BTreeSet::new();
        for (i, ch) in self.measurements.iter().enumerate() {
            let path = format!("measurements[{i}]");
            let Some(sensor) = self.sensors.get(ch.sensor as usize) else {
                return Err(invalid(
                    path,
                    format!(
                        "sensor {} out of range ({} sensors)",
                        ch.sensor,
                        self.sensors.len()
                    ),
                ));
            };
            check_component(&path, ch.component)?;
            if !sensor.components.contains(&ch.component) {
                return Err(invalid(
                    path,
                    format!(
                        "sensor '{}' does not measure component {}",
                        sensor.name, ch.component
                    ),
                ));
            }
            if !seen.insert((ch.sensor, ch.component)) {
                return Err(invalid(
                    path,
                    format!(
                        "sensor '{}' component {} appears twice",
                        sensor.name, ch.component
                    ),
                ));
            }
        }

        check_kalman("kalman", &self.kalman, r, q)?;

        for (s, set) in self.node_sets.iter().enumerate() {
            let path = format!("node_sets[{s}] '{}'", set.name);
            let n = set.node_tags.len() as u64;
            check_matrix(&format!("{path}.rest_positions"), &set.rest_positions, n, 3)?;
            check_matrix(
                &format!("{path}.displacement_rows"),
                &set.displacement_rows,
                3 * n,
                r,
            )?;
            check_matrix(
                &format!("{path}.rotation_rows"),
                &set.rotation_rows,
                3 * n,
                r,
            )?;
            for (t, tri) in set.triangles.iter().enumerate() {
                if let Some(&bad) = tri.iter().find(|&&v| v as u64 >= n) {
                    return Err(invalid(
                        format!("{path}.triangles[{t}]"),
                        format!("node index {bad} out of range ({n} nodes)"),
                    ));
                }
            }
        }
        if let Some(tier) = &self.tier {
            check_tier(self, tier)?;
        }
        if let Some(contact) = &self.contact {
            check_contact(contact, r, m)?;
        }
        Ok(())
    }
}

/// The contact region (format v9) for state dimension r and m deterministic inputs.
fn check_contact(c: &crate::ContactRegion, r: u64, m: u64) -> Result<(), FormatError> {
    let path = format!("contact '{}'", c.name);
    let n = c.node_tags.len() as u64;
    if n == 0 {
        return Err(invalid(format!("{path}.node_tags"), "must list ≥ 1 node"));
    }
    check_positive(&format!("{path}.tool_radius"), c.tool_radius)?;
    check_positive(&format!("{path}.max_force"), c.max_force)?;
    check_matrix(&format!("{path}.rest_positions"), &c.rest_positions, n, 3)?;
    check_matrix(&format!("{path}.normals"), &c.normals, n, 3)?;
    for i in 0..n as usize {
        let v = &c.normals.data[3 * i..3 * i + 3];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if (len - 1.0).abs() > 1e-9 {
            return Err(invalid(
                format!("{path}.normals"),
                format!("row {i} must be a unit vector, its length is {len}"),
            ));
        }
    }
    check_matrix(
        &format!("{path}.displacement_rows"),
        &c.displacement_rows,
        3 * n,
        r,
    )?;
    check_matrix(&format!("{path}.input_rows"), &c.input_rows, 3 * n, r)?;
    check_matrix(&format!("{path}.theta_rows"), &c.theta_rows, 3 * n, r)?;
    check_matrix(
        &format!("{path}.theta_input_rows"),
        &c.theta_input_rows,
        3 * n,
        m,
    )?;
    if c.residual_blocks.len() != 9 * c.residual_pairs.len() {
        return Err(invalid(
            format!("{path}.residual_blocks"),
            format!(
                "holds {} values, expected 9 per pair ({} pairs)",
                c.residual_blocks.len(),
                c.residual_pairs.len()
            ),
        ));
    }
    check_finite(&format!("{path}.residual_blocks"), &c.residual_blocks, 9)?;
    if c.theta_residual_blocks.len() != 18 * c.residual_pairs.len() {
        return Err(invalid(
            format!("{path}.theta_residual_blocks"),
            format!(
                "holds {} values, expected 18 per pair ({} pairs)",
                c.theta_residual_blocks.len(),
                c.residual_pairs.len()
            ),
        ));
    }
    check_finite(
        &format!("{path}.theta_residual_blocks"),
        &c.theta_residual_blocks,
        18,
    )?;
    for (k, w) in c.residual_pairs.windows(2).enumerate() {
        if w[0] >= w[1] {
            return Err(invalid(
                format!("{path}.residual_pairs[{}]", k + 1),
                format!(
                    "must be strictly increasing, found {:?} then {:?}",
                    w[0], w[1]
                ),
            ));
        }
    }
    for (k, p) in c.residual_pairs.iter().enumerate() {
        if p[0] > p[1] || p[1] as u64 >= n {
            return Err(invalid(
                format!("{path}.residual_pairs[{k}]"),
                format!("({}, {}) must have i ≤ j < {n}", p[0], p[1]),
            ));
        }
    }
    let radius = c.residual_radius;
    if !(radius.is_finite() && radius >= 0.0) {
        return Err(invalid(
            format!("{path}.residual_radius"),
            format!("must be finite and ≥ 0, got {radius}"),
        ));
    }
    Ok(())
}

/// The Kalman section `prefix` (`kalman` or `tier.kalman`) for state dimension r and q
/// measurement channels.
fn check_kalman(prefix: &str, k: &crate::KalmanGains, r: u64, q: usize) -> Result<(), FormatError> {
    if k.period == 0 {
        return Err(invalid(format!("{prefix}.period"), "must be ≥ 1"));
    }
    if k.phases.len() != k.period as usize {
        return Err(invalid(
            format!("{prefix}.phases"),
            format!("{} phases for period {}", k.phases.len(), k.period),
        ));
    }
    for (p, phase) in k.phases.iter().enumerate() {
        let path = format!("{prefix}.phases[{p}]");
        if let Some(&bad) = phase.measured.iter().find(|&&j| j as usize >= q) {
            return Err(invalid(
                format!("{path}.measured"),
                format!("measurement index {bad} out of range ({q} measurements)"),
            ));
        }
        check_increasing(&format!("{path}.measured"), &phase.measured)?;
        check_matrix(
            &format!("{path}.gain"),
            &phase.gain,
            r,
            phase.measured.len() as u64,
        )?;
        check_matrix(
            &format!("{path}.prior_covariance"),
            &phase.prior_covariance,
            r,
            r,
        )?;
        check_matrix(
            &format!("{path}.posterior_covariance"),
            &phase.posterior_covariance,
            r,
            r,
        )?;
    }
    check_matrix(&format!("{prefix}.process_noise"), &k.process_noise, r, r)?;
    if k.measurement_variance.len() != q {
        return Err(invalid(
            format!("{prefix}.measurement_variance"),
            format!(
                "{} values for {q} measurements",
                k.measurement_variance.len()
            ),
        ));
    }
    for (i, &v) in k.measurement_variance.iter().enumerate() {
        check_positive(&format!("{prefix}.measurement_variance[{i}]"), v)?;
    }
    Ok(())
}

/// The co-rotational tier section (format v7): shapes against r = `tier.order`, m inputs,
/// the model's sensors and node sets, q measurements; finite values; weights ≥ 0; force
/// states on existing load groups with three load channels, increasing.
fn check_tier(model: &Model, t: &crate::CorotationalTier) -> Result<(), FormatError> {
    let r = t.order as u64;
    if t.order == 0 {
        return Err(invalid("tier.order", "must be ≥ 1"));
    }
    check_matrix("tier.mass", &t.mass, r, r)?;
    check_finite("tier.alpha", &[t.alpha], 0)?;
    check_finite("tier.beta", &[t.beta], 0)?;
    if t.alpha < 0.0 || t.beta < 0.0 {
        return Err(invalid(
            "tier.alpha/beta",
            "Rayleigh coefficients must be ≥ 0",
        ));
    }
    check_positive("tier.newton_tolerance", t.newton_tolerance)?;
    if t.newton_iterations == 0 {
        return Err(invalid("tier.newton_iterations", "must be ≥ 1"));
    }
    check_matrix("tier.input", &t.input, r, model.inputs.len() as u64)?;
    if t.sensor_rows.len() != model.sensors.len() {
        return Err(invalid(
            "tier.sensor_rows",
            format!(
                "{} blocks for {} sensors",
                t.sensor_rows.len(),
                model.sensors.len()
            ),
        ));
    }
    for (s, m) in t.sensor_rows.iter().enumerate() {
        check_matrix(&format!("tier.sensor_rows[{s}]"), m, 3, r)?;
    }
    if t.node_set_rows.len() != model.node_sets.len() {
        return Err(invalid(
            "tier.node_set_rows",
            format!(
                "{} blocks for {} node sets",
                t.node_set_rows.len(),
                model.node_sets.len()
            ),
        ));
    }
    for (s, m) in t.node_set_rows.iter().enumerate() {
        let n = model.node_sets[s].node_tags.len() as u64;
        check_matrix(&format!("tier.node_set_rows[{s}]"), m, 3 * n, r)?;
    }
    if t.elements.is_empty() {
        return Err(invalid("tier.elements", "no sampled element"));
    }
    for (e, el) in t.elements.iter().enumerate() {
        let path = format!("tier.elements[{e}]");
        check_finite(&format!("{path}.weight"), &[el.weight], 0)?;
        if el.weight < 0.0 {
            return Err(invalid(
                format!("{path}.weight"),
                format!("must be ≥ 0, got {}", el.weight),
            ));
        }
        check_finite(&format!("{path}.rest"), el.rest.as_flattened(), 3)?;
        check_finite(&format!("{path}.gradients"), el.gradients.as_flattened(), 3)?;
        check_matrix(&format!("{path}.stiffness"), &el.stiffness, 12, 12)?;
        check_symmetric(&format!("{path}.stiffness"), &el.stiffness.data, 12)?;
        check_matrix(&format!("{path}.rows"), &el.rows, 12, r)?;
    }
    let env = &t.envelope;
    for (g, l) in env.loads.iter().enumerate() {
        let path = format!("tier.envelope.loads[{g}] '{}'", l.name);
        if !model.loads.iter().any(|m| m.name == l.name) {
            return Err(invalid(path, "not a load group of the model"));
        }
        check_positive(&format!("{path}.range"), l.range)?;
        check_positive(&format!("{path}.max_force"), l.max_force)?;
    }
    for (d, dir) in env.directions.iter().enumerate() {
        check_finite(&format!("tier.envelope.directions[{d}]"), dir, 0)?;
    }
    for (h, hist) in env.histories.iter().enumerate() {
        let path = format!("tier.envelope.histories[{h}]");
        check_finite(&path, &[hist.multiple, hist.time], 0)?;
    }
    check_positive("tier.envelope.max_coordinate_norm", env.max_coordinate_norm)?;
    check_finite("tier.envelope.max_displacement", &[env.max_displacement], 0)?;
    check_finite("tier.envelope.duration", &[env.duration], 0)?;
    check_finite("tier.envelope.state_margin", &[env.state_margin], 0)?;
    if env.state_margin < 1.0 {
        return Err(invalid(
            "tier.envelope.state_margin",
            format!("must be ≥ 1, got {}", env.state_margin),
        ));
    }
    if t.model_error.rows != 0 || t.model_error.cols != 0 || !t.model_error.data.is_empty() {
        check_matrix("tier.model_error", &t.model_error, r, r)?;
        check_finite("tier.model_error", &t.model_error.data, t.order as usize)?;
        let n = t.order as usize;
        if (0..n).any(|i| t.model_error.data[i * n + i] < 0.0) {
            return Err(invalid(
                "tier.model_error",
                "a covariance: its diagonal must be ≥ 0",
            ));
        }
    }
    check_increasing("tier.force_loads", &t.force_loads)?;
    if t.force_rates && t.force_loads.is_empty() {
        return Err(invalid(
            "tier.force_rates",
            "force-rate states need force states (force_loads is empty)",
        ));
    }
    for &g in &t.force_loads {
        let channels = model
            .inputs
            .iter()
            .filter(|i| matches!(i.kind, crate::InputKind::Load { load, .. } if load == g))
            .count();
        if g as usize >= model.loads.len() || channels != 3 {
            return Err(invalid(
                "tier.force_loads",
                format!(
                    "load group {g}: not a load group of the model with three load channels ({} groups)",
                    model.loads.len()
                ),
            ));
        }
    }
    check_kalman(
        "tier.kalman",
        &t.kalman,
        t.state_dim() as u64,
        model.measurements.len(),
    )?;
    for (i, s) in t.scheduled.iter().enumerate() {
        let path = format!("tier.scheduled[{i}]");
        if s.point.len() != t.order as usize {
            return Err(invalid(
                format!("{path}.point"),
                format!("{} values for r = {}", s.point.len(), t.order),
            ));
        }
        check_finite(&format!("{path}.point"), &s.point, 0)?;
        check_kalman(
            &format!("{path}.kalman"),
            &s.kalman,
            t.state_dim() as u64,
            model.measurements.len(),
        )?;
        let same_phases = s.kalman.period == t.kalman.period
            && s.kalman
                .phases
                .iter()
                .zip(&t.kalman.phases)
                .all(|(a, b)| a.measured == b.measured);
        if !same_phases {
            return Err(invalid(
                format!("{path}.kalman"),
                "period or measured channels differ from tier.kalman",
            ));
        }
    }
    check_force_levels(model, t)
}

/// The force-σ levels of a tier and their statistic (format v7): each level's filters shaped
/// as the section's (same period and measured channels, one per scheduled point), distinct
/// factors other than 1; the statistic present exactly with levels.
fn check_force_levels(model: &Model, t: &crate::CorotationalTier) -> Result<(), FormatError> {
    let q = model.measurements.len();
    let same_phases = |k: &crate::KalmanGains| {
        k.period == t.kalman.period
            && k.phases
                .iter()
                .zip(&t.kalman.phases)
                .all(|(a, b)| a.measured == b.measured)
    };
    let mut factors = vec![1.0];
    for (l, level) in t.force_levels.iter().enumerate() {
        let path = format!("tier.force_levels[{l}]");
        check_positive(&format!("{path}.factor"), level.factor)?;
        if factors.contains(&level.factor) {
            return Err(invalid(
                format!("{path}.factor"),
                format!(
                    "{} repeats a level (1 is the section's own filter)",
                    level.factor
                ),
            ));
        }
        factors.push(level.factor);
        if t.force_loads.is_empty() {
            return Err(invalid(
                path,
                "force-σ levels need force states (force_loads is empty)",
            ));
        }
        if level.scheduled.len() != t.scheduled.len() {
            return Err(invalid(
                format!("{path}.scheduled"),
                format!(
                    "{} filters for {} scheduled points",
                    level.scheduled.len(),
                    t.scheduled.len()
                ),
            ));
        }
        let filters = std::iter::once((format!("{path}.kalman"), &level.kalman)).chain(
            level
                .scheduled
                .iter()
                .enumerate()
                .map(|(i, k)| (format!("{path}.scheduled[{i}]"), k)),
        );
        for (path, k) in filters {
            check_kalman(&path, k, t.state_dim() as u64, q)?;
            if !same_phases(k) {
                return Err(invalid(
                    path,
                    "period or measured channels differ from tier.kalman",
                ));
            }
        }
    }
    if let Some(why) = &t.failed_check {
        if why.trim().is_empty() {
            return Err(invalid(
                "tier.failed_check",
                "empty: a failed check carries its reason",
            ));
        }
    }
    match (&t.adaptation, t.force_levels.is_empty()) {
        (None, true) => Ok(()),
        (Some(_), true) => Err(invalid("tier.adaptation", "present without force_levels")),
        (None, false) => Err(invalid(
            "tier.adaptation",
            "missing: force_levels need the statistic that chooses among them",
        )),
        (Some(a), false) => {
            if a.smoothing.len() != q {
                return Err(invalid(
                    "tier.adaptation.smoothing",
                    format!("{} values for {q} measurements", a.smoothing.len()),
                ));
            }
            if let Some(j) = a.smoothing.iter().position(|&v| !(v > 0.0 && v <= 1.0)) {
                return Err(invalid(
                    format!("tier.adaptation.smoothing[{j}]"),
                    format!("{} is not in (0, 1]", a.smoothing[j]),
                ));
            }
            check_positive("tier.adaptation.lower_below", a.lower_below)?;
            check_positive("tier.adaptation.raise_above", a.raise_above)?;
            if a.raise_above <= a.lower_below {
                return Err(invalid(
                    "tier.adaptation.raise_above",
                    format!(
                        "{} is not above lower_below {}",
                        a.raise_above, a.lower_below
                    ),
                ));
            }
            if a.hold == 0 {
                return Err(invalid("tier.adaptation.hold", "must be ≥ 1"));
            }
            Ok(())
        }
    }
}
