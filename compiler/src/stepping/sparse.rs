//! A fixed symmetric sparsity pattern over the free DOFs (the node-adjacency pattern of the
//! tetrahedral mesh), filled element by element, with a sparse Cholesky whose symbolic analysis
//! is done once and reused for every numeric refactorisation.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky};
use faer::sparse::linalg::solvers::Llt;
use faer::sparse::{SparseColMat, SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};

use crate::fem::{sparse_entries, FemModel};

use super::SteppingError;

/// Both triangles of the symmetric pattern: column j holds every free DOF of every node that
/// shares a tetrahedron with DOF j's node, rows sorted.
pub(crate) struct Pattern {
    /// n, the number of free DOFs.
    pub n: usize,
    symbolic: SymbolicSparseColMat<usize>,
    llt: Arc<SymbolicCholesky<usize>>,
    /// Parallelism of the numeric factorisations and solves (faer's global setting unless
    /// [`Pattern::set_sequential`]).
    par: Par,
}

impl Pattern {
    /// Builds the pattern of `fem` and its symbolic Cholesky (lower triangle).
    pub fn new(fem: &FemModel) -> Result<Self, SteppingError> {
        let n = fem.dof_count();
        let mut adjacent: Vec<Vec<usize>> = vec![Vec::new(); fem.positions.len()];
        for e in &fem.elements {
            for &a in &e.nodes {
                adjacent[a].extend_from_slice(&e.nodes);
            }
        }
        for list in &mut adjacent {
            list.sort_unstable();
            list.dedup();
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for &(node, _) in &fem.dofs.dofs {
            let start = row_idx.len();
            for &m in &adjacent[node] {
                row_idx.extend(fem.dofs.index[m].iter().flatten());
            }
            row_idx[start..].sort_unstable();
            col_ptr.push(row_idx.len());
        }
        let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let llt = factorize_symbolic_cholesky(
            symbolic.as_ref(),
            Side::Lower,
            Default::default(),
            Default::default(),
        )
        .map_err(|e| {
            SteppingError::Solver(format!("symbolic Cholesky of the {n}×{n} pattern: {e:?}"))
        })?;
        Ok(Pattern {
            n,
            symbolic,
            llt: Arc::new(llt),
            par: faer::get_global_parallelism(),
        })
    }

    /// Factorisations and solves on the calling thread only (for simulators run several at a
    /// time, e.g. the training runs: no thread pool shared between them).
    pub fn set_sequential(&mut self) {
        self.par = Par::Seq;
    }

    /// Number of stored entries.
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// Position of entry (row, col) in the value array.
    #[inline]
    pub fn slot(&self, row: usize, col: usize) -> usize {
        let ptr = self.symbolic.col_ptr();
        let rows = &self.symbolic.row_idx()[ptr[col]..ptr[col + 1]];
        match rows.binary_search(&row) {
            Ok(i) => ptr[col] + i,
            Err(_) => unreachable!("entry ({row}, {col}) outside the mesh pattern"),
        }
    }

    /// Scatters a sparse matrix with a sub-pattern (K or M of the same mesh) into values.
    pub fn scatter(&self, mat: &SparseColMat<usize, f64>) -> Vec<f64> {
        let mut values = vec![0.0; self.nnz()];
        for (i, j, v) in sparse_entries(mat) {
            values[self.slot(i, j)] += v;
        }
        values
    }

    /// y = A x for the values `a` on this pattern.
    pub fn mul(&self, a: &[f64], x: &[f64], y: &mut [f64]) {
        let ptr = self.symbolic.col_ptr();
        let rows = self.symbolic.row_idx();
        y.iter_mut().for_each(|v| *v = 0.0);
        for (j, &xj) in x.iter().enumerate() {
            if xj == 0.0 {
                continue;
            }
            for p in ptr[j]..ptr[j + 1] {
                y[rows[p]] += a[p] * xj;
            }
        }
    }

    /// Numeric Cholesky of the matrix with values `a` (symbolic analysis reused).
    pub fn factor(&self, a: &[f64], what: &str) -> Result<Factor, SteppingError> {
        let mat = SparseColMatRef::new(self.symbolic.as_ref(), a);
        let mut values = vec![0.0; self.llt.len_val()];
        let mut scratch = MemBuffer::try_new(
            self.llt
                .factorize_numeric_llt_scratch::<f64>(self.par, Default::default()),
        )
        .map_err(|e| SteppingError::Solver(format!("{what}: workspace: {e:?}")))?;
        self.llt
            .factorize_numeric_llt::<f64>(
                &mut values,
                mat,
                Side::Lower,
                Default::default(),
                self.par,
                MemStack::new(&mut scratch),
                Default::default(),
            )
            .map_err(|e| SteppingError::NotPositiveDefinite {
                what: what.to_owned(),
                n: self.n,
                detail: format!("{e:?}"),
            })?;
        Ok(Factor::OnPattern {
            symbolic: Arc::clone(&self.llt),
            values,
            par: self.par,
        })
    }
}

/// A numeric sparse Cholesky factorisation.
pub(crate) enum Factor {
    /// Of a stand-alone matrix.
    Whole(Llt<usize, f64>),
    /// Of values on a [`Pattern`], with the pattern's parallelism.
    OnPattern {
        symbolic: Arc<SymbolicCholesky<usize>>,
        values: Vec<f64>,
        par: Par,
    },
}

impl Factor {
    /// Cholesky of a stand-alone symmetric positive definite matrix (both triangles stored).
    pub fn of(mat: &SparseColMat<usize, f64>, what: &str) -> Result<Self, SteppingError> {
        mat.sp_cholesky(Side::Lower)
            .map(Factor::Whole)
            .map_err(|e| not_positive_definite(what, mat.nrows(), e))
    }

    /// Overwrites `b` with A⁻¹ b.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        self.solve_in_place_with(b, None);
    }

    /// Overwrites `b` with A⁻¹ b, on the calling thread only when `par` is `Some(Par::Seq)`
    /// (for solves run several at a time), else with the factor's own parallelism.
    pub fn solve_in_place_with(&self, b: &mut [f64], par: Option<Par>) {
        let n = b.len();
        let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
        match self {
            Factor::Whole(llt) => llt.solve_in_place(rhs),
            Factor::OnPattern {
                symbolic,
                values,
                par: own,
            } => {
                let par = par.unwrap_or(*own);
                let mut scratch = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, par));
                LltRef::new(symbolic, values).solve_in_place_with_conj(
                    Conj::No,
                    rhs,
                    par,
                    MemStack::new(&mut scratch),
                );
            }
        }
    }
}

fn not_positive_definite(what: &str, n: usize, e: faer::sparse::linalg::LltError) -> SteppingError {
    SteppingError::NotPositiveDefinite {
        what: what.to_owned(),
        n,
        detail: format!("{e:?}"),
    }
}
