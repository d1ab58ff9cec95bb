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

        let k = &self.kalman;
        if k.period == 0 {
            return Err(invalid("kalman.period", "must be ≥ 1"));
        }
        if k.phases.len() != k.period as usize {
            return Err(invalid(
                "kalman.phases",
                format!("{} phases for period {}", k.phases.len(), k.period),
            ));
        }
        for (p, phase) in k.phases.iter().enumerate() {
            let path = format!("kalman.phases[{p}]");
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
        check_matrix("kalman.process_noise", &k.process_noise, r, r)?;
        if k.measurement_variance.len() != q {
            return Err(invalid(
                "kalman.measurement_variance",
                format!(
                    "{} values for {q} measurements",
                    k.measurement_variance.len()
                ),
            ));
        }
        for (i, &v) in k.measurement_variance.iter().enumerate() {
            check_positive(&format!("kalman.measurement_variance[{i}]"), v)?;
        }

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
        Ok(())
    }
}
