//! The co-rotational tier assembled from training (docs/design.md §10): training → POD basis
//! ([`super::basis::BasisChoice`]) → ECSW cubature ([`super::cubature`]) → reduced model
//! ([`from_training`], [`build`]). Its filter is designed in [`super::filter`], its model-file
//! section written and read in `crate::model_file::tier`, and the whole wired for a compile by
//! `crate::reductor::tier::TierReductor`.

use nalgebra::{DMatrix, DVector};

use crate::full_order::FullOrder;

use super::basis::{Basis, BasisChoice, ChosenBasis};
use super::cubature::Cubature;
use super::ecsw::EcswOptions;
use super::reduced::HyperReducedModel;
use super::training::{self, Training, TrainingPlan};
use super::NonlinearError;
use crate::algorithms::nnls::NnlsSolution;

/// A built co-rotational tier.
#[derive(Clone, Debug)]
pub struct Tier {
    /// The basis V (n × r, M-orthonormal): POD of the training snapshots, each column's
    /// largest-magnitude entry positive (deterministic signs).
    pub basis: Basis,
    /// POD eigenvalues of the training snapshots (m²·kg), descending.
    pub pod_values: Vec<f64>,
    /// ECSW sampling.
    pub sampling: NnlsSolution,
    /// The reduced model.
    pub model: HyperReducedModel,
    /// Training runs and envelope (snapshots kept).
    pub training: Training,
    /// The training snapshots' reduced coordinates q = VᵀM u (r each, in the snapshots' order).
    pub projected: Vec<DVector<f64>>,
    /// Largest ‖q‖ over `projected`.
    pub max_coordinate_norm: f64,
    /// Wall time of the POD and of the ECSW, s.
    pub seconds: [f64; 2],
    /// With a per-run basis tolerance ([`BasisChoice::tolerance`]): the vectors added after the
    /// pooled POD and the worst per-run relative error in the energy norm reached (above the
    /// tolerance when `max_order` stopped the enrichment).
    pub enrichment: Option<(usize, f64)>,
}

/// Builds the tier from training snapshots: the first `order` POD vectors of the snapshots in
/// the M inner product, ECSW on the snapshots with `ecsw`.
pub fn from_training(
    full: &FullOrder,
    training: Training,
    order: usize,
    ecsw_options: &EcswOptions,
) -> Result<Tier, NonlinearError> {
    from_training_with(full, training, &BasisChoice::pod(order), ecsw_options)
}

/// [`from_training`] with the basis of `choice` ([`BasisChoice::choose`]: the pooled POD and,
/// with a tolerance, the per-run enrichment in the energy norm), then ECSW on the snapshots
/// ([`Cubature::train`]) and the reduced model on both.
pub fn from_training_with(
    full: &FullOrder,
    training: Training,
    choice: &BasisChoice,
    ecsw_options: &EcswOptions,
) -> Result<Tier, NonlinearError> {
    if training.snapshots.is_empty() {
        return Err(NonlinearError::Invalid(
            "no training snapshot: every training run failed".into(),
        ));
    }
    let clock = std::time::Instant::now();
    let ChosenBasis {
        basis,
        pod_values,
        enrichment,
    } = choice.choose(&full.fem, &training);
    let t_pod = clock.elapsed().as_secs_f64();
    let clock = std::time::Instant::now();
    let (cubature, sampling) =
        Cubature::train(&full.fem, &basis, &training.snapshots, ecsw_options)?;
    let t_ecsw = clock.elapsed().as_secs_f64();
    let model = HyperReducedModel::with_cubature(&full.fem, &basis.vectors, cubature, full.wilson);
    let projected: Vec<DVector<f64>> = training
        .snapshots
        .iter()
        .map(|u| basis.project(u))
        .collect();
    let max_coordinate_norm = projected.iter().map(|q| q.norm()).fold(0.0, f64::max);
    Ok(Tier {
        basis,
        pod_values,
        sampling,
        model,
        training,
        projected,
        max_coordinate_norm,
        seconds: [t_pod, t_ecsw],
        enrichment,
    })
}

/// Trains on `plan` (full-order co-rotational runs) and builds the tier.
pub fn build(
    full: &FullOrder,
    plan: &TrainingPlan,
    order: usize,
    ecsw_options: &EcswOptions,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Tier, NonlinearError> {
    let training = training::train(full, plan, progress)?;
    from_training(full, training, order, ecsw_options)
}

/// Rows of V (3 × r) at a point with barycentric node weights (world-frame displacement, m).
pub fn point_rows(full: &FullOrder, v: &DMatrix<f64>, weights: &[(usize, f64)]) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(3, v.ncols());
    for &(node, w) in weights {
        for c in 0..3 {
            if let Some(d) = full.fem.dofs.index[node][c] {
                for j in 0..v.ncols() {
                    out[(c, j)] += w * v[(d, j)];
                }
            }
        }
    }
    out
}
