//! `crokf-run`: replays a recorded input history (and optional measurements) through a crokf
//! model and writes the estimates (`docs/model-format.md` §6). The estimator itself is
//! `crokf-runtime`, and so are the CSV readers (`crokf_runtime::table`, feature `table`,
//! re-exported here); this crate adds the CSV and VTU files around it, written through
//! temporary files and renames (`crokf_formats::output`), so that a failed run leaves the old
//! files or nothing.

pub mod vtu;

/// The CSV files of a recording and the headers of `estimates.csv`: the runtime's readers
/// (feature `table`), shared with `crokf-compile identify`.
pub use crokf_runtime::table;

use crokf_formats::output::OutputError;
use crokf_runtime::table::TableError;
use crokf_runtime::RuntimeError;

/// Everything `crokf-run` can fail on; messages name the file, line, step and channel.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The command line asks for something impossible.
    #[error("{0}")]
    Usage(String),
    /// An input file could not be read, or a CSV file is malformed (file and line).
    #[error(transparent)]
    Table(#[from] TableError),
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
