//! The cubature of the co-rotational tier's reduced internal force (docs/design.md §10, item 3):
//! the sampled elements with their ECSW weights and what each needs to evaluate its force in
//! the basis (rest geometry, rest stiffness, its rows of V). One object: the reduced model
//! evaluates its forces over it ([`super::reduced::HyperReducedModel`]), ECSW trains it
//! ([`Cubature::train`], [`super::ecsw`]) and the model file's tier section stores and reads it
//! back (`crate::model_file::tier`).

use nalgebra::DMatrix;

use crate::fem::{FemModel, TetGeometry};

use super::basis::Basis;
use super::ecsw::{self, EcswOptions};
use super::NonlinearError;
use crate::algorithms::nnls::NnlsSolution;

/// One sampled element: rest geometry, rest stiffness, its basis rows and weight.
#[derive(Clone, Debug)]
pub struct SampledElement {
    /// Index into the full model's elements.
    pub element: usize,
    /// ECSW weight wₑ ≥ 0.
    pub weight: f64,
    /// Rest geometry (shape-function gradients, volume).
    pub geometry: TetGeometry,
    /// Rest stiffness Kₑ (12 × 12, N/m, node-major).
    pub stiffness: [[f64; 12]; 12],
    /// Rest vertex positions Xₑ, m.
    pub rest: [[f64; 3]; 4],
    /// V_e: the 12 rows of V at the element's DOFs (12 × r; zero rows where fixed).
    pub rows: DMatrix<f64>,
    /// The same rows flattened row-major (12·r), for the allocation-free force loop.
    pub flat: Vec<f64>,
    /// V_eᵀ flattened row-major (r·12) ([`crokf_kernel::Element::cols`]).
    pub flat_t: Vec<f64>,
}

/// The sampled elements of the reduced force, Σ_S wₑ V_eᵀ fₑ, in the order ECSW chose them
/// (by element index).
#[derive(Clone, Debug)]
pub struct Cubature {
    /// The sampled elements with their weights.
    pub elements: Vec<SampledElement>,
}

impl Cubature {
    /// The cubature of `fem` on the basis `v` (n × r) with the sampled elements
    /// `(element, weight)`: each element's rest geometry, stiffness and rows of `v`.
    pub fn new(
        fem: &FemModel,
        v: &DMatrix<f64>,
        sampled: &[(usize, f64)],
    ) -> Result<Self, NonlinearError> {
        let n = fem.dof_count();
        if v.nrows() != n {
            return Err(NonlinearError::Invalid(format!(
                "basis has {} rows, the model {} free DOFs",
                v.nrows(),
                n
            )));
        }
        let r = v.ncols();
        let mut elements = Vec::with_capacity(sampled.len());
        for &(e, weight) in sampled {
            let Some(el) = fem.elements.get(e) else {
                return Err(NonlinearError::Invalid(format!(
                    "sampled element {e} does not exist ({} elements)",
                    fem.elements.len()
                )));
            };
            if !(weight.is_finite() && weight >= 0.0) {
                return Err(NonlinearError::Invalid(format!(
                    "sampled element {e} (tag {}): weight {weight} is not ≥ 0",
                    el.tag
                )));
            }
            let dofs = fem.dofs.element(&el.nodes);
            let rows = DMatrix::from_fn(12, r, |i, j| dofs[i].map_or(0.0, |d| v[(d, j)]));
            let flat: Vec<f64> = (0..12)
                .flat_map(|i| (0..r).map(move |j| (i, j)))
                .map(|(i, j)| rows[(i, j)])
                .collect();
            let flat_t = crokf_kernel::transpose_rows(&flat);
            elements.push(SampledElement {
                flat,
                flat_t,
                element: e,
                weight,
                geometry: el.geometry,
                stiffness: fem.element_stiffness(e),
                rest: el.nodes.map(|node| fem.positions[node]),
                rows,
            });
        }
        Ok(Cubature { elements })
    }

    /// ECSW on the training displacements `snapshots` for `basis` ([`ecsw::sample_elements`]):
    /// the cubature and the NNLS solution (weights, relative residual) it came from.
    pub fn train(
        fem: &FemModel,
        basis: &Basis,
        snapshots: &[Vec<f64>],
        options: &EcswOptions,
    ) -> Result<(Self, NnlsSolution), NonlinearError> {
        let sampling =
            ecsw::sample_elements(fem, &basis.vectors, &basis.mass_vectors, snapshots, options)?;
        let cubature = Cubature::new(fem, &basis.vectors, &sampling.weights)?;
        Ok((cubature, sampling))
    }

    /// Number of sampled elements.
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    /// True with no sampled element.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }
}
