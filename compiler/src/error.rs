//! The compiler's error type at its boundary: each stage keeps its own error enum, and this one
//! says which stage failed and for which scene.

use std::path::PathBuf;

use crate::algorithms::kalman::KalmanError;
use crate::fem::FemError;
use crate::mesh::MeshError;
use crate::reduce::ReduceError;
use crate::scene::SceneError;
use crate::stepping::SteppingError;

/// Any error of the pipeline, by stage.
#[derive(Debug, thiserror::Error)]
pub enum CompileError {
    /// Scene file.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Mesh file.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// FEM assembly and operators.
    #[error("{path}: {source}")]
    Fem {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: FemError,
    },
    /// Reduction.
    #[error("{path}: {source}")]
    Reduce {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: ReduceError,
    },
    /// Kalman gains.
    #[error("{path}: {source}")]
    Kalman {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: KalmanError,
    },
    /// The markers cannot tell the estimated loads apart ([`crate::observability`]).
    #[error("{path}: {what}")]
    Unobservable {
        /// Scene path.
        path: PathBuf,
        /// The unseen force combination and what to change.
        what: String,
    },
    /// Full-order simulation (measured error).
    #[error("{path}: full-order simulation: {source}")]
    Stepping {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        source: SteppingError,
    },
    /// The co-rotational tier (training, hyper-reduction, its filter; docs/design.md §10).
    #[error("{path}: co-rotational tier: {message}")]
    Tier {
        /// Scene path.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// Reading or writing files.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
}
