//! `crokf-run`: replays a recorded input history (and optional measurements) through a crokf
//! model and writes the estimates (`docs/model-format.md` §6). The estimator itself is
//! `crokf-runtime`; this crate adds the CSV and VTU files around it, written through temporary
//! files and renames (`crokf_formats::output`), so that a failed run leaves the old files or
//! nothing.

pub mod table;
pub mod vtu;

use crokf_formats::output::OutputError;
use crokf_runtime::RuntimeError;
use std::path::PathBuf;

/// Everything `crokf-run` can fail on; messages name the file, line, step and channel.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The command line asks for something impossible.
    #[error("{0}")]
    Usage(String),
    /// An input file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A CSV file is malformed.
    #[error("{path}:{line}: {message}")]
    Csv {
        /// File.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// Loading the model or building the estimator failed.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    /// A step was refused; the estimator is unchanged and nothing has been written.
    #[error("step {step} ({location}): {source}")]
    Step {
        /// Step k.
        step: u64,
        /// `inputs.csv:LINE` and, if the step has a measurement row, `measurements.csv:LINE`.
        location: String,
        /// Cause.
        source: RuntimeError,
    },
    /// An output path is refused, or writing it failed.
    #[error(transparent)]
    Output(#[from] OutputError),
}
