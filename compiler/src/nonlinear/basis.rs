//! Candidate displacement bases of the co-rotational tier and their projection errors
//! (docs/design.md §10, item 1).
//!
//! Every basis is M-orthonormal, VᵀMV = I (V: n × r over the free DOFs, M the consistent mass,
//! kg), so the best fit of a displacement u (n, m) in the M-norm is q = VᵀMu and
//! min_q ‖Vq − u‖²_M = ‖u‖²_M − ‖VᵀMu‖² (nested in r: the error of the first k columns needs
//! only the first k coefficients).

use faer::sparse::SparseColMat;
use nalgebra::{DMatrix, DVector};

use crate::fem::{sparse_mul, FemModel};
use crate::stepping::{static_solve, CorotationalSimulator};

use super::training::Training;
use super::NonlinearError;
use crate::algorithms::pod::pod;

/// An M-orthonormal basis (n × r, columns in the order they were accepted) with a label per
/// column saying where it came from.
#[derive(Clone, Debug)]
pub struct Basis {
    /// V, n × r, VᵀMV = I.
    pub vectors: DMatrix<f64>,
    /// M V, n × r (kept for projections q = (MV)ᵀu).
    pub mass_vectors: DMatrix<f64>,
    /// Per column: its source ("static", "mode 3", "derivative 1,2", "pod 4").
    pub labels: Vec<String>,
}

impl Basis {
    /// Number of columns r.
    pub fn len(&self) -> usize {
        self.vectors.ncols()
    }

    /// True with no column.
    pub fn is_empty(&self) -> bool {
        self.vectors.ncols() == 0
    }

    /// (label, column) of every vector, in order: the input of an orthonormalisation in another
    /// inner product or of an enrichment.
    pub fn columns(&self) -> Vec<(String, Vec<f64>)> {
        (0..self.len())
            .map(|j| {
                (
                    self.labels[j].clone(),
                    self.vectors.column(j).iter().copied().collect(),
                )
            })
            .collect()
    }

    /// Coefficients q = VᵀMu (r) of the M-orthogonal projection of u (n, m).
    pub fn project(&self, u: &[f64]) -> DVector<f64> {
        self.mass_vectors.tr_mul(&DVector::from_column_slice(u))
    }

    /// The first `r` columns.
    pub fn truncated(&self, r: usize) -> Basis {
        let r = r.min(self.len());
        Basis {
            vectors: self.vectors.columns(0, r).into_owned(),
            mass_vectors: self.mass_vectors.columns(0, r).into_owned(),
            labels: self.labels[..r].to_vec(),
        }
    }
}

/// M-orthonormalises `candidates` (each n) in order by modified Gram–Schmidt, twice per vector
/// (re-orthogonalisation), dropping a candidate whose M-norm after orthogonalisation is below
/// `drop_tolerance` × its M-norm before (linearly dependent). Stops at `max_columns`.
pub fn m_orthonormalise(
    mass: &SparseColMat<usize, f64>,
    candidates: &[(String, Vec<f64>)],
    drop_tolerance: f64,
    max_columns: usize,
) -> Basis {
    let mut columns: Vec<Vec<f64>> = Vec::new();
    let mut mass_columns: Vec<Vec<f64>> = Vec::new();
    let mut labels = Vec::new();
    let n = mass.nrows();
    for (label, v) in candidates {
        if columns.len() >= max_columns {
            break;
        }
        if v.len() != n {
            continue;
        }
        let mut x = v.clone();
        let mx = sparse_mul(mass, &x);
        let before = dot(&x, &mx).max(0.0).sqrt();
        if before == 0.0 || !before.is_finite() {
            continue;
        }
        for _ in 0..2 {
            for (c, mc) in columns.iter().zip(&mass_columns) {
                let h = dot(&x, mc);
                x.iter_mut().zip(c).for_each(|(xi, ci)| *xi -= h * ci);
            }
        }
        let mx = sparse_mul(mass, &x);
        let after = dot(&x, &mx).max(0.0).sqrt();
        if after <= drop_tolerance * before {
            continue;
        }
        columns.push(x.iter().map(|v| v / after).collect());
        mass_columns.push(mx.iter().map(|v| v / after).collect());
        labels.push(label.clone());
    }
    let r = columns.len();
    Basis {
        vectors: DMatrix::from_fn(n, r, |i, j| columns[j][i]),
        mass_vectors: DMatrix::from_fn(n, r, |i, j| mass_columns[j][i]),
        labels,
    }
}

/// Euclidean dot product.
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Static modal derivatives θᵢⱼ = −K⁻¹ (∂²f_int/∂qᵢ∂qⱼ at rest) of the co-rotational internal
/// force for every pair i ≤ j of `generators` (each n, m per unit q), by the central second
/// difference
/// `[f(h(φᵢ+φⱼ)) − f(h(φᵢ−φⱼ)) − f(h(−φᵢ+φⱼ)) + f(−h(φᵢ+φⱼ))] / (4h²)`
/// with h chosen per pair so that the largest nodal displacement of hφ is `amplitude` (m).
/// Truncation error O((amplitude/L)²), round-off O(ε L/amplitude) relative; amplitude =
/// 1e-3 × the body's size balances both far below the 1e-3 accuracy a basis vector needs.
pub fn modal_derivatives(
    fem: &FemModel,
    simulator: &mut CorotationalSimulator,
    generators: &[(String, Vec<f64>)],
    amplitude: f64,
) -> Result<Vec<(String, Vec<f64>)>, NonlinearError> {
    let n = fem.dof_count();
    let mut out = Vec::new();
    let largest = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    for i in 0..generators.len() {
        for j in i..generators.len() {
            let (li, gi) = (&generators[i].0, &generators[i].1);
            let (lj, gj) = (&generators[j].0, &generators[j].1);
            let (si, sj) = (largest(gi), largest(gj));
            if si == 0.0 || sj == 0.0 {
                continue;
            }
            // Scale each generator to unit largest entry so h means metres.
            let a: Vec<f64> = gi.iter().map(|v| v / si).collect();
            let b: Vec<f64> = gj.iter().map(|v| v / sj).collect();
            let h = amplitude;
            let mut d = vec![0.0; n];
            for (sa, sb, sign) in [
                (1.0, 1.0, 1.0),
                (1.0, -1.0, -1.0),
                (-1.0, 1.0, -1.0),
                (-1.0, -1.0, 1.0),
            ] {
                let u: Vec<f64> = a
                    .iter()
                    .zip(&b)
                    .map(|(x, y)| h * (sa * x + sb * y))
                    .collect();
                let f = simulator.internal_force(&u)?;
                d.iter_mut()
                    .zip(&f)
                    .for_each(|(di, fi)| *di += sign * fi / (4.0 * h * h));
            }
            let theta = static_solve(fem, &d)?;
            out.push((
                format!("derivative {li} × {lj}"),
                theta.iter().map(|v| -v).collect(),
            ));
        }
    }
    Ok(out)
}

/// Relative projection error of a trajectory on the first k columns of `basis`, for every
/// k = 0..=r: e_k = sqrt(Σ_t min_q ‖V_k q − u_t‖²_M / Σ_t ‖u_t‖²_M) (entry k of the result);
/// `mass` is M (n × n, kg), `trajectory` the displacements u_t (n each, m).
pub fn projection_errors(
    mass: &SparseColMat<usize, f64>,
    basis: &Basis,
    trajectory: &[Vec<f64>],
) -> Vec<f64> {
    let r = basis.len();
    let mut residual = vec![0.0; r + 1];
    let mut total = 0.0;
    for u in trajectory {
        let q = basis.project(u);
        let norm2 = dot(u, &sparse_mul(mass, u));
        total += norm2;
        let mut left = norm2;
        residual[0] += left;
        for k in 0..r {
            left -= q[k] * q[k];
            residual[k + 1] += left.max(0.0);
        }
    }
    residual
        .iter()
        .map(|e| if total > 0.0 { (e / total).sqrt() } else { 0.0 })
        .collect()
}

/// Flips the sign of each vector so that its largest-magnitude entry is positive
/// (deterministic signs for POD vectors, whose eigenvector signs are arbitrary).
pub fn normalise_signs(vectors: &mut [(String, Vec<f64>)]) {
    for (_, v) in vectors {
        let top = v
            .iter()
            .copied()
            .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        if top < 0.0 {
            v.iter_mut().for_each(|x| *x = -*x);
        }
    }
}

/// A basis whose every training run is represented to a relative tolerance, from
/// [`per_run_pod`].
#[derive(Clone, Debug)]
pub struct PerRunBasis {
    /// V (n × r, VᵀMV = I): the pooled POD vectors first, then the enrichment.
    pub basis: Basis,
    /// Columns that came from the pooled POD.
    pub pooled: usize,
    /// Per run: its relative projection error e_k on the final basis (module docs of
    /// [`per_run_pod`]); 0 for a run with no snapshot or only zero snapshots.
    pub run_errors: Vec<f64>,
    /// Per added column: the run it was taken from.
    pub enriched_from: Vec<usize>,
}

impl PerRunBasis {
    /// The largest per-run relative projection error.
    pub fn worst(&self) -> f64 {
        self.run_errors.iter().copied().fold(0.0, f64::max)
    }
}

/// A POD basis in which every training run, not only the pooled snapshot energy, is
/// represented to the relative tolerance ε = `tolerance` (docs/design.md §10 item 1;
/// docs/results/tier.md §8).
///
/// With u_t the snapshots (n each, m), run k's snapshots T_k and P = V Vᵀ M the M-orthogonal
/// projector on V, run k's relative projection error is
/// ```text
/// e_k = sqrt( Σ_{t∈T_k} ‖u_t − P u_t‖²_M / Σ_{t∈T_k} ‖u_t‖²_M ).
/// ```
/// V starts with the first `pooled` POD vectors of all snapshots (the energy-optimal basis of
/// the pool, [`pod`](crate::algorithms::pod::pod)); then, while the worst run has e_k > ε and r < `max_columns`, the leading
/// POD vector of that run's residuals (I − P)u_t, t ∈ T_k (M-orthogonal to V by construction,
/// re-orthogonalised twice) is appended. Each added vector removes the largest share of the worst
/// run's residual energy, so e_k of that run strictly decreases; r is set by ε, bounded by
/// `max_columns`. The pooled POD comes first so that a run that dominates the pool (a large
/// bending motion) keeps the vectors it had; runs that the pool ranks last (a stiff torsion
/// or an axial pull, millimetres next to metres) are added until they are represented too.
/// `run_of[t]` is snapshot t's run (< `runs`). Cost: O(S n r) for S snapshots. e_k is
/// evaluated as (‖u‖² − ‖q‖²)^½ per snapshot (nested in r, no residual vectors kept), so it is
/// accurate to about √ε_machine ≈ 1e-8 relative: tolerances below 1e-6 are not meaningful.
pub fn per_run_pod(
    mass: &SparseColMat<usize, f64>,
    snapshots: &[Vec<f64>],
    run_of: &[usize],
    runs: usize,
    pooled: usize,
    tolerance: f64,
    max_columns: usize,
) -> PerRunBasis {
    let (mut modes, _) = pod(mass, snapshots, pooled.min(max_columns), 1e-14);
    normalise_signs(&mut modes);
    let start = m_orthonormalise(mass, &modes, 1e-8, pooled.min(max_columns));
    enrich_per_run(mass, snapshots, run_of, runs, start, tolerance, max_columns)
}

/// The enrichment of [`per_run_pod`] from a given M-orthonormal `start` basis (e.g. the pooled
/// POD, computed once for several tolerances): appends the leading POD vector of the worst
/// run's residuals while that run's e_k > `tolerance` and r < `max_columns`.
pub fn enrich_per_run(
    mass: &SparseColMat<usize, f64>,
    snapshots: &[Vec<f64>],
    run_of: &[usize],
    runs: usize,
    start: Basis,
    tolerance: f64,
    max_columns: usize,
) -> PerRunBasis {
    let mut basis = start;
    let pooled = basis.len();
    let norms2: Vec<f64> = snapshots
        .iter()
        .map(|u| dot(u, &sparse_mul(mass, u)))
        .collect();
    // Coefficients q_t = (MV)ᵀ u_t, one row per column of V.
    let mut coefficients: Vec<Vec<f64>> = (0..basis.len())
        .map(|j| {
            let mv = basis.mass_vectors.column(j);
            snapshots
                .iter()
                .map(|u| mv.iter().zip(u).map(|(a, b)| a * b).sum())
                .collect()
        })
        .collect();
    let errors = |coefficients: &[Vec<f64>]| -> Vec<f64> {
        let mut left = vec![0.0; runs];
        let mut total = vec![0.0; runs];
        for (t, &k) in run_of.iter().enumerate() {
            let kept: f64 = coefficients.iter().map(|row| row[t] * row[t]).sum();
            left[k] += (norms2[t] - kept).max(0.0);
            total[k] += norms2[t];
        }
        left.iter()
            .zip(&total)
            .map(|(l, t)| if *t > 0.0 { (l / t).sqrt() } else { 0.0 })
            .collect()
    };
    let mut run_errors = errors(&coefficients);
    let mut enriched_from = Vec::new();
    let mut columns: Vec<(String, Vec<f64>)> = basis.columns();
    while basis.len() < max_columns {
        let Some((worst, &e)) = run_errors
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
        else {
            break;
        };
        if e <= tolerance {
            break;
        }
        let residuals: Vec<Vec<f64>> = run_of
            .iter()
            .enumerate()
            .filter(|&(_, &k)| k == worst)
            .map(|(t, _)| {
                let mut r = snapshots[t].clone();
                for (j, row) in coefficients.iter().enumerate() {
                    let c = row[t];
                    r.iter_mut()
                        .zip(basis.vectors.column(j).iter())
                        .for_each(|(x, v)| *x -= c * v);
                }
                r
            })
            .collect();
        let (mut lead, _) = pod(mass, &residuals, 1, 0.0);
        normalise_signs(&mut lead);
        let Some((_, v)) = lead.pop() else { break };
        columns.push((format!("run {worst} residual"), v));
        let next = m_orthonormalise(mass, &columns, 1e-8, basis.len() + 1);
        if next.len() == basis.len() {
            break; // numerically dependent: the run cannot be improved further
        }
        basis = next;
        let j = basis.len() - 1;
        let mv = basis.mass_vectors.column(j);
        coefficients.push(
            snapshots
                .iter()
                .map(|u| mv.iter().zip(u).map(|(a, b)| a * b).sum())
                .collect(),
        );
        enriched_from.push(worst);
        run_errors = errors(&coefficients);
    }
    PerRunBasis {
        basis,
        pooled,
        run_errors,
        enriched_from,
    }
}

/// How the tier's basis is chosen from the training snapshots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasisChoice {
    /// Pooled POD vectors (M inner product), first.
    pub order: usize,
    /// Per-run tolerance ε in the energy norm, enrichment up to `max_order` columns
    /// ([`enrich_per_run`] with K; docs/results/tier.md §8); None: r = `order`.
    pub tolerance: Option<f64>,
    /// Largest r with a tolerance.
    pub max_order: usize,
}

impl BasisChoice {
    /// The first `order` pooled POD vectors only.
    pub fn pod(order: usize) -> Self {
        BasisChoice {
            order,
            tolerance: None,
            max_order: order,
        }
    }
}

/// The tier's basis chosen from training snapshots ([`BasisChoice::choose`]).
#[derive(Clone, Debug)]
pub struct ChosenBasis {
    /// V (n × r, M-orthonormal), each pooled column's largest-magnitude entry positive.
    pub basis: Basis,
    /// POD eigenvalues of the snapshots (m²·kg), descending.
    pub pod_values: Vec<f64>,
    /// With a per-run tolerance: the vectors added after the pooled POD and the worst per-run
    /// relative error in the energy norm reached.
    pub enrichment: Option<(usize, f64)>,
}

impl BasisChoice {
    /// The basis of the training snapshots `training`: the pooled POD (M inner product, signs
    /// normalised) and, with a tolerance ε, the per-run enrichment in the energy norm: while
    /// some training run k has e_k = (Σ_t ‖(I − P_K) u_t‖²_K / Σ_t ‖u_t‖²_K)^½ > ε (P_K the
    /// K-orthogonal projector on V), the leading K-POD vector of the worst run's residuals is
    /// appended; the result is M-orthonormalised (same span). The energy norm because the
    /// Galerkin step solves for the K-orthogonal projection, not the M-orthogonal one: on the
    /// twist hard case a basis that fits the trajectory to 1–3 % in M left the linear static
    /// Galerkin solution 87 % off (docs/results/tier.md §8).
    pub fn choose(&self, fem: &FemModel, training: &Training) -> ChosenBasis {
        let order = self.order;
        let (mut modes, pod_values) = pod(&fem.mass, &training.snapshots, order, 1e-14);
        normalise_signs(&mut modes);
        let mut basis = m_orthonormalise(&fem.mass, &modes, 1e-8, order);
        let mut enrichment = None;
        if let Some(tolerance) = self.tolerance {
            let stiffness = &fem.stiffness;
            let energy = m_orthonormalise(stiffness, &modes, 1e-8, order);
            let enriched = enrich_per_run(
                stiffness,
                &training.snapshots,
                &training.run_of,
                training.runs.len(),
                energy,
                tolerance,
                self.max_order.max(order),
            );
            let columns: Vec<(String, Vec<f64>)> = enriched.basis.columns();
            // The pooled columns first, unchanged (same M-orthonormal vectors as without the
            // tolerance), then the enrichment M-orthogonalised against them.
            let mut all: Vec<(String, Vec<f64>)> = basis.columns();
            all.extend(columns.into_iter().skip(enriched.pooled));
            enrichment = Some((enriched.enriched_from.len(), enriched.worst()));
            basis = m_orthonormalise(&fem.mass, &all, 1e-10, all.len());
        }
        ChosenBasis {
            basis,
            pod_values,
            enrichment,
        }
    }
}
