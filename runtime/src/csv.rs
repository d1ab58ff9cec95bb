//! Plain CSV input/output for `crokf-run` (comma-separated, header row, no quoting; blank
//! lines and lines starting with `#` are skipped).
//!
//! Step convention: step k = 1, 2, … is the k-th prediction; the load of step k acts over
//! (t_{k−1}, t_k] and the measurement and estimate of step k are at t_k = k·Δt. The first
//! column of an input or measurement file is `step` (k, an integer) or `t` (t_k in seconds,
//! k = round(t/Δt)).

use crate::{Model, RuntimeError};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One value per input channel (model order) for steps 1, 2, …, n.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTable {
    /// `rows[k − 1]` = inputs of step k.
    pub rows: Vec<Vec<f64>>,
}

/// Measurements by step k; one entry per measurement channel (model order), `None` = missing.
pub type MeasurementTable = BTreeMap<u64, Vec<Option<f64>>>;

struct Lines {
    path: PathBuf,
    /// (1-based line number, cells).
    rows: Vec<(usize, Vec<String>)>,
}

fn read_lines(path: &Path) -> Result<Lines, RuntimeError> {
    let text = std::fs::read_to_string(path).map_err(|source| RuntimeError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let rows = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .map(|(i, l)| (i + 1, l.split(',').map(|c| c.trim().to_string()).collect()))
        .collect();
    Ok(Lines {
        path: path.to_path_buf(),
        rows,
    })
}

impl Lines {
    /// Every data row must have as many cells as the header.
    fn check_widths(&self) -> Result<(), RuntimeError> {
        let width = self.rows.first().map_or(0, |(_, h)| h.len());
        for (line, cells) in self.rows.iter().skip(1) {
            if cells.len() != width {
                return Err(self.err(
                    *line,
                    format!("{} cells, the header has {width}", cells.len()),
                ));
            }
        }
        Ok(())
    }

    fn err(&self, line: usize, message: impl Into<String>) -> RuntimeError {
        RuntimeError::Csv {
            path: self.path.clone(),
            line,
            message: message.into(),
        }
    }

    /// Header → (first column is `t`, column index of each label).
    fn header(
        &self,
        labels: &[String],
        all_required: bool,
    ) -> Result<(bool, Vec<Option<usize>>), RuntimeError> {
        let Some((line, head)) = self.rows.first() else {
            return Err(self.err(1, "empty file: expected a header row"));
        };
        let by_time = match head[0].as_str() {
            "step" => false,
            "t" => true,
            other => {
                return Err(self.err(
                    *line,
                    format!("first column must be `step` or `t`, found `{other}`"),
                ))
            }
        };
        let mut cols = vec![None; labels.len()];
        for (c, name) in head.iter().enumerate().skip(1) {
            let Some(i) = labels.iter().position(|l| l == name) else {
                return Err(self.err(
                    *line,
                    format!(
                        "unknown column `{name}` (the model's are: {})",
                        labels.join(", ")
                    ),
                ));
            };
            if cols[i].is_some() {
                return Err(self.err(*line, format!("column `{name}` appears twice")));
            }
            cols[i] = Some(c);
        }
        if all_required {
            if let Some(i) = cols.iter().position(Option::is_none) {
                return Err(self.err(*line, format!("missing column `{}`", labels[i])));
            }
        }
        Ok((by_time, cols))
    }

    fn step_of(
        &self,
        line: usize,
        cell: &str,
        by_time: bool,
        dt: f64,
    ) -> Result<u64, RuntimeError> {
        if by_time {
            let t: f64 = cell
                .parse()
                .map_err(|_| self.err(line, format!("time `{cell}` is not a number")))?;
            let k = (t / dt).round();
            if !(k >= 1.0 && (t - k * dt).abs() <= 1e-6 * dt.max(t.abs())) || k > 1e15 {
                return Err(self.err(
                    line,
                    format!("time {t} s is not a positive multiple of Δt = {dt} s"),
                ));
            }
            Ok(k as u64)
        } else {
            match cell.parse::<u64>() {
                Ok(k) if k >= 1 => Ok(k),
                _ => Err(self.err(line, format!("step `{cell}` is not an integer ≥ 1"))),
            }
        }
    }

    fn value(
        &self,
        line: usize,
        cells: &[String],
        c: usize,
        label: &str,
    ) -> Result<Option<f64>, RuntimeError> {
        let Some(cell) = cells.get(c) else {
            return Err(self.err(
                line,
                format!("row has {} cells, column `{label}` missing", cells.len()),
            ));
        };
        if cell.is_empty() {
            return Ok(None);
        }
        match cell.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(Some(v)),
            _ => Err(self.err(line, format!("`{label}`: `{cell}` is not a finite number"))),
        }
    }
}

/// Reads `inputs.csv`: first column `step` or `t`, then one column per input label (all
/// required, any order). Rows must be steps 1, 2, 3, … in order.
pub fn read_inputs(path: &Path, model: &Model) -> Result<InputTable, RuntimeError> {
    let lines = read_lines(path)?;
    let labels = model.input_labels();
    let (by_time, cols) = lines.header(&labels, true)?;
    lines.check_widths()?;
    let mut rows = Vec::with_capacity(lines.rows.len().saturating_sub(1));
    for (line, cells) in &lines.rows[1..] {
        let k = lines.step_of(*line, &cells[0], by_time, model.dt)?;
        let expected = rows.len() as u64 + 1;
        if k != expected {
            return Err(lines.err(
                *line,
                format!("step {k}, expected {expected} (rows must be steps 1, 2, 3, … in order)"),
            ));
        }
        let mut row = Vec::with_capacity(labels.len());
        for (label, c) in labels.iter().zip(&cols) {
            let v = lines.value(*line, cells, c.unwrap_or(0), label)?;
            row.push(v.ok_or_else(|| lines.err(*line, format!("input `{label}` is empty")))?);
        }
        rows.push(row);
    }
    Ok(InputTable { rows })
}

/// Reads `measurements.csv`: first column `step` or `t`, then columns named by measurement
/// labels (`sensor.x`; any subset, any order). Empty cell = missing; absent column = always
/// missing. Steps strictly increasing; steps without a row have no measurement.
pub fn read_measurements(path: &Path, model: &Model) -> Result<MeasurementTable, RuntimeError> {
    let lines = read_lines(path)?;
    let labels = model.measurement_labels();
    let (by_time, cols) = lines.header(&labels, false)?;
    lines.check_widths()?;
    let mut table = MeasurementTable::new();
    let mut last = 0;
    for (line, cells) in &lines.rows[1..] {
        let k = lines.step_of(*line, &cells[0], by_time, model.dt)?;
        if k <= last {
            return Err(lines.err(
                *line,
                format!("step {k} after step {last}: steps must increase"),
            ));
        }
        last = k;
        let mut row = Vec::with_capacity(labels.len());
        for (label, c) in labels.iter().zip(&cols) {
            row.push(match c {
                Some(c) => lines.value(*line, cells, *c, label)?,
                None => None,
            });
        }
        table.insert(k, row);
    }
    Ok(table)
}

/// Header of `estimates.csv`: `step,t`, then per sensor `name.x,name.y,name.z`, then per
/// sensor `name.x_std,name.y_std,name.z_std`.
pub fn estimates_header(model: &Model) -> String {
    let mut h = String::from("step,t");
    for suffix in ["", "_std"] {
        for s in &model.sensors {
            for c in ["x", "y", "z"] {
                h.push_str(&format!(",{}.{c}{suffix}", s.name));
            }
        }
    }
    h
}
