//! The recording's CSV files (inputs, measurements, tool paths) and the headers of
//! `estimates.csv`, read with the `csv` crate: comma-separated, a header row, RFC 4180 quoting,
//! CRLF or LF line ends, a UTF-8 byte-order mark ignored, cells trimmed; blank lines and lines
//! starting with `#` are skipped. Only with the `table` feature (off by default: without it
//! the runtime library and its cdylib do not depend on `csv`); used by `crokf-run` (the
//! replay) and by `crokf-compile identify` (the recording), which must not depend on the
//! replay tool.
//!
//! Step convention (`docs/design.md` §6, `docs/model-format.md` §2): step k = 1, 2, … is the
//! k-th prediction; the load of step k acts over (t_{k−1}, t_k] and the measurement and
//! estimate of step k are at t_k = k·Δt. The first column of an input or measurement file is
//! `step` (k, an integer) or `t` (t_k in seconds, k = round(t/Δt)).

use crate::Model;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A CSV file that cannot be read or is malformed; messages name the file and the line.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The file is malformed.
    #[error("{path}:{line}: {message}")]
    Csv {
        /// File.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// One value per input channel (model order) for steps 1, 2, …, n.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTable {
    /// `rows[k − 1]` = inputs of step k (N for load channels, a scale for gravity).
    pub rows: Vec<Vec<f64>>,
    /// `lines[k − 1]` = 1-based line of step k's row in the file.
    pub lines: Vec<usize>,
}

/// One step's measurements: one entry per measurement channel (model order), `None` =
/// missing, and the 1-based line of the row.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasurementRow {
    /// World-frame values, m.
    pub values: Vec<Option<f64>>,
    /// 1-based line in the file.
    pub line: usize,
}

/// Measurements by step k.
pub type MeasurementTable = BTreeMap<u64, MeasurementRow>;

/// The non-blank, non-comment records of a CSV text with their 1-based line numbers.
struct Records {
    path: PathBuf,
    /// (1-based line, trimmed cells).
    rows: Vec<(usize, Vec<String>)>,
}

impl Records {
    /// Parses `text` (the content of `path`).
    fn parse(path: &Path, text: &[u8]) -> Result<Records, TableError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            .from_reader(text);
        let mut rows = Vec::new();
        let mut record = csv::StringRecord::new();
        loop {
            let line = reader.position().line() as usize;
            match reader.read_record(&mut record) {
                Ok(false) => break,
                Ok(true) => {
                    let line = record.position().map_or(line, |p| p.line() as usize);
                    if record.iter().all(str::is_empty) {
                        continue; // a line of blanks
                    }
                    rows.push((line, record.iter().map(str::to_owned).collect()));
                }
                Err(e) => {
                    let line = e.position().map_or(line, |p| p.line() as usize);
                    let message = match e.kind() {
                        csv::ErrorKind::Utf8 { .. } => "not valid UTF-8".to_owned(),
                        _ => e.to_string(),
                    };
                    return Err(TableError::Csv {
                        path: path.to_path_buf(),
                        line,
                        message,
                    });
                }
            }
        }
        Ok(Records {
            path: path.to_path_buf(),
            rows,
        })
    }

    fn read(path: &Path) -> Result<Records, TableError> {
        let text = std::fs::read(path).map_err(|source| TableError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Records::parse(path, &text)
    }

    /// Every data row must have as many cells as the header.
    fn check_widths(&self) -> Result<(), TableError> {
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

    fn err(&self, line: usize, message: impl Into<String>) -> TableError {
        TableError::Csv {
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
    ) -> Result<(bool, Vec<Option<usize>>), TableError> {
        let Some((line, head)) = self.rows.first() else {
            return Err(self.err(1, "empty file: expected a header row"));
        };
        let by_time = match head.first().map(String::as_str) {
            Some("step") => false,
            Some("t") => true,
            other => {
                return Err(self.err(
                    *line,
                    format!(
                        "first column must be `step` or `t`, found `{}`",
                        other.unwrap_or("")
                    ),
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

    /// The row's step must be `expected` (rows are steps 1, 2, 3, … in order).
    fn expect_step(
        &self,
        line: usize,
        cell: &str,
        by_time: bool,
        dt: f64,
        expected: u64,
    ) -> Result<(), TableError> {
        let k = self.step_of(line, cell, by_time, dt)?;
        if k != expected {
            return Err(self.err(
                line,
                format!("step {k}, expected {expected} (rows must be steps 1, 2, 3, … in order)"),
            ));
        }
        Ok(())
    }

    fn step_of(&self, line: usize, cell: &str, by_time: bool, dt: f64) -> Result<u64, TableError> {
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
    ) -> Result<Option<f64>, TableError> {
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

/// Parses the text of an inputs file (`path` only names it in errors): first column `step` or
/// `t`, then one column per input label (all required, any order). Rows must be steps
/// 1, 2, 3, … in order; a file with a header and no rows is an error.
pub fn parse_inputs(path: &Path, text: &[u8], model: &Model) -> Result<InputTable, TableError> {
    inputs_from(Records::parse(path, text)?, model)
}

/// Reads `inputs.csv` (see [`parse_inputs`]).
pub fn read_inputs(path: &Path, model: &Model) -> Result<InputTable, TableError> {
    inputs_from(Records::read(path)?, model)
}

fn inputs_from(records: Records, model: &Model) -> Result<InputTable, TableError> {
    let labels = model.input_labels();
    let (by_time, cols) = records.header(&labels, true)?;
    records.check_widths()?;
    let mut rows = Vec::with_capacity(records.rows.len().saturating_sub(1));
    let mut lines = Vec::with_capacity(rows.capacity());
    for (line, cells) in &records.rows[1..] {
        records.expect_step(*line, &cells[0], by_time, model.dt, rows.len() as u64 + 1)?;
        let mut row = Vec::with_capacity(labels.len());
        for (label, c) in labels.iter().zip(&cols) {
            let v = records.value(*line, cells, c.unwrap_or(0), label)?;
            row.push(v.ok_or_else(|| records.err(*line, format!("input `{label}` is empty")))?);
        }
        rows.push(row);
        lines.push(*line);
    }
    if rows.is_empty() {
        let line = records.rows.first().map_or(1, |(l, _)| *l);
        return Err(records.err(line, "header only: no input rows, nothing to run"));
    }
    Ok(InputTable { rows, lines })
}

/// Parses the text of a measurements file (`path` only names it in errors): first column
/// `step` or `t`, then columns named by measurement labels (`sensor.x`; any subset, any order).
/// Empty cell = missing; absent column = always missing. Steps strictly increasing; steps
/// without a row have no measurement.
pub fn parse_measurements(
    path: &Path,
    text: &[u8],
    model: &Model,
) -> Result<MeasurementTable, TableError> {
    measurements_from(Records::parse(path, text)?, model)
}

/// A `measurements.csv` of `rows` (one per step from step 1, one cell per
/// [`Model::measurement_labels`] entry, empty where `None`) that [`parse_measurements`] reads
/// back: `step`, then the labels; values in Rust's shortest round-trip `e` notation.
pub fn measurements_text(model: &Model, rows: &[Vec<Option<f64>>]) -> String {
    let mut text = format!("step,{}\n", model.measurement_labels().join(","));
    for (k, row) in rows.iter().enumerate() {
        text.push_str(&(k + 1).to_string());
        for v in row {
            text.push(',');
            if let Some(v) = v {
                text.push_str(&format!("{v:e}"));
            }
        }
        text.push('\n');
    }
    text
}

/// Reads `measurements.csv` (see [`parse_measurements`]).
pub fn read_measurements(path: &Path, model: &Model) -> Result<MeasurementTable, TableError> {
    measurements_from(Records::read(path)?, model)
}

fn measurements_from(records: Records, model: &Model) -> Result<MeasurementTable, TableError> {
    let labels = model.measurement_labels();
    let (by_time, cols) = records.header(&labels, false)?;
    records.check_widths()?;
    let mut table = MeasurementTable::new();
    let mut last = 0;
    for (line, cells) in &records.rows[1..] {
        let k = records.step_of(*line, &cells[0], by_time, model.dt)?;
        if k <= last {
            return Err(records.err(
                *line,
                format!("step {k} after step {last}: steps must increase"),
            ));
        }
        last = k;
        let mut values = Vec::with_capacity(labels.len());
        for (label, c) in labels.iter().zip(&cols) {
            values.push(match c {
                Some(c) => records.value(*line, cells, *c, label)?,
                None => None,
            });
        }
        table.insert(
            k,
            MeasurementRow {
                values,
                line: *line,
            },
        );
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

/// A tool path: the centre of each tool (1 or 2) for steps 1, 2, …, n (m, the model's frame),
/// and whether it holds what it grasped.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolTable {
    /// `rows[k − 1][t]` = tool t's centre at step k.
    pub rows: Vec<Vec<[f64; 3]>>,
    /// `grasp[k − 1][t]`: tool t holds a grasped node during step k (the `toolT.grasp` column,
    /// 0 or 1; all false without it).
    pub grasp: Vec<Vec<bool>>,
    /// `lines[k − 1]` = 1-based line of step k's row in the file.
    pub lines: Vec<usize>,
}

/// Parses the text of a tool file (`path` only names it in errors): first column `step` or
/// `t`, then `tool0.x,tool0.y,tool0.z` and optionally `tool1.x,tool1.y,tool1.z` (any order),
/// and for each tool optionally `toolT.grasp` (0 or 1: the tool grasps the region node nearest
/// it where the column turns 1 and lets go where it turns 0). Rows must be steps 1, 2, 3, … in
/// order, every value given.
pub fn parse_tools(path: &Path, text: &[u8], model: &Model) -> Result<ToolTable, TableError> {
    tools_from(Records::parse(path, text)?, model)
}

/// Reads `tool.csv` (see [`parse_tools`]).
pub fn read_tools(path: &Path, model: &Model) -> Result<ToolTable, TableError> {
    tools_from(Records::read(path)?, model)
}

fn tools_from(records: Records, model: &Model) -> Result<ToolTable, TableError> {
    let tools_max = crate::MAX_TOOLS;
    let labels: Vec<String> = (0..tools_max)
        .flat_map(|t| ["x", "y", "z"].map(|c| format!("tool{t}.{c}")))
        .chain((0..tools_max).map(|t| format!("tool{t}.grasp")))
        .collect();
    let (by_time, cols) = records.header(&labels, false)?;
    let head_line = records.rows.first().map_or(1, |(l, _)| *l);
    let mut tools = 0;
    for t in 0..crate::MAX_TOOLS {
        let given = (0..3).filter(|&c| cols[3 * t + c].is_some()).count();
        match given {
            0 => {}
            3 if t == tools => tools += 1,
            3 => {
                return Err(records.err(
                    head_line,
                    format!("tool{t} without tool{}: number the tools from 0", t - 1),
                ))
            }
            _ => {
                let missing = (0..3)
                    .find(|&c| cols[3 * t + c].is_none())
                    .map_or(String::new(), |c| labels[3 * t + c].clone());
                return Err(records.err(head_line, format!("missing column `{missing}`")));
            }
        }
    }
    if tools == 0 {
        return Err(records.err(head_line, "missing columns `tool0.x`, `tool0.y`, `tool0.z`"));
    }
    if let Some(t) = (tools..tools_max).find(|&t| cols[3 * tools_max + t].is_some()) {
        return Err(records.err(
            head_line,
            format!("`tool{t}.grasp` without the columns `tool{t}.x`, `tool{t}.y`, `tool{t}.z`"),
        ));
    }
    records.check_widths()?;
    let mut rows = Vec::with_capacity(records.rows.len().saturating_sub(1));
    let mut lines = Vec::with_capacity(rows.capacity());
    let mut grasp = Vec::with_capacity(rows.capacity());
    for (line, cells) in &records.rows[1..] {
        records.expect_step(*line, &cells[0], by_time, model.dt, rows.len() as u64 + 1)?;
        let mut row = Vec::with_capacity(tools);
        for t in 0..tools {
            let mut centre = [0.0; 3];
            for (c, v) in centre.iter_mut().enumerate() {
                let label = &labels[3 * t + c];
                *v = records
                    .value(*line, cells, cols[3 * t + c].unwrap_or(0), label)?
                    .ok_or_else(|| records.err(*line, format!("`{label}` is empty")))?;
            }
            row.push(centre);
        }
        let mut holds = vec![false; tools];
        for (t, h) in holds.iter_mut().enumerate() {
            let label = &labels[3 * tools_max + t];
            if let Some(c) = cols[3 * tools_max + t] {
                *h = match records.value(*line, cells, c, label)? {
                    Some(0.0) => false,
                    Some(1.0) => true,
                    Some(v) => {
                        return Err(records.err(*line, format!("`{label}`: {v} is not 0 or 1")))
                    }
                    None => return Err(records.err(*line, format!("`{label}` is empty"))),
                };
            }
        }
        grasp.push(holds);
        rows.push(row);
        lines.push(*line);
    }
    if rows.is_empty() {
        return Err(records.err(head_line, "header only: no tool rows"));
    }
    Ok(ToolTable { rows, grasp, lines })
}

/// The tool columns `estimates.csv` gains with `--tool`: per tool `toolT.fx,toolT.fy,toolT.fz`
/// (N, the body on the tool), `toolT.nodes` (pressing nodes) and `toolT.status`.
pub fn tool_header(tools: usize) -> String {
    (0..tools)
        .map(|t| format!(",tool{t}.fx,tool{t}.fy,tool{t}.fz,tool{t}.nodes,tool{t}.status"))
        .collect()
}
