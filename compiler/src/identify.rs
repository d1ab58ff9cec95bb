//! `crokf-compile identify` (docs/identify.md): the co-rotational tier's noise identified from
//! a recording (autocovariance least squares, docs/design.md §11.6), with an uncertainty,
//! refusals, and the identified σ written into a copy of the scene for the next compile.
//!
//! The tier of a model file, its filters (gain schedule included) recomputed for the scene's
//! noise, runs from rest over a recording (inputs and markers in `crokf-run`'s CSV formats);
//! its innovations after the first `skip` steps give the sample autocovariances and
//! [`identify_noise`](als_noise::identify_noise) the σ that explain them: each
//! estimated load's force σ_f (and rate σ_ḟ with rate states), the tier's model error as a
//! factor on its measured covariance (the scene's `model_error_scale`, written into the copy
//! when the recording disagrees with it) and the markers' σ as a factor on the scene's.
//!
//! Uncertainty: the recording after `skip` is cut into [`BLOCKS`] disjoint blocks of equal
//! length; each block is identified alone (the filter still runs over the whole recording from
//! rest; a block's autocovariances use only pairs of its own steps), and the uncertainty of
//! the whole recording's value is the standard error of the block values, s/√K (s their
//! sample standard deviation, K = [`BLOCKS`]: batch means).
//!
//! Refusals ([`IdentifyError`]): a recording shorter than [`MIN_STEPS_PER_LAG`] × lags steps
//! after `skip` or with fewer than [`MIN_MARKER_UPDATES`] marker updates there; a model
//! without a co-rotational tier or without estimated loads; a recording that does not excite
//! any force parameter (each within two uncertainties of 0: the markers' noise alone explains
//! the innovations); a markers' factor outside [`MARKER_FACTOR_RANGE`] (the markers' noise is
//! known, so the linearised filters do not explain the innovations).
//!
//! The algorithm is [`als_noise`]; the rest of this module is the layer around it, one
//! way: [`filter_run`](mod@filter_run) (the runtime's filter over a recording) ← [`identification`] (the loop
//! over noise specs, the blocks, the verdict and the report) ← [`scene_edit`] (the identified
//! scene's text) ← [`files`] (reading the files, checking and writing the output) ←
//! [`command`] (the command line of `crokf-compile identify`, also `crokf-verify identify`).

pub mod als_noise;
pub mod command;
pub mod files;
pub mod filter_run;
pub mod identification;
pub mod scene_edit;

pub use files::{check_output, identify_files, write_scene, Files, Refusal};
pub use filter_run::{filter_run, FilterRun};
pub use identification::{
    identify, Estimate, FixedPoint, Identification, IdentifyError, IdentifyOptions, LoadSigma,
    ModelErrorFactor, Recording, BLOCKS, EXCITED_UNCERTAINTIES, FIXED_POINT_TOLERANCE,
    MARKER_FACTOR_RANGE, MAX_ITERATIONS, MIN_MARKER_UPDATES, MIN_STEPS_PER_LAG,
};
pub use scene_edit::identified_scene;
