//! The factor of a frame's force Jacobian `K` (VH Eq. 17, 20), which the
//! adjoint and every Gauss-Newton product solve with.
//!
//! `K` is the exact Jacobian of the PD force ([`crate::sim::hessian`]): it
//! is symmetric wherever the 0.01 floor of Eq. 26 is inactive, and positive
//! definite at a stable equilibrium with pinned nodes. There it is factored
//! by sparse Cholesky ([`SparseCholesky`]): the symbolic analysis (AMD) once
//! per frame ([`KPattern`]), the lower triangle gathered from the assembled
//! entries in a precomputed order (no sort), and `K⁻¹` and `K⁻ᵀ` are one
//! and the same solve with half the factor of an LU. Anywhere else (an
//! element block asymmetric beyond [`SYMMETRY_TOLERANCE`], or a Cholesky
//! that meets a non-positive pivot) it is faer's sparse LU with partial
//! pivoting, which solves with `Kᵀ` exactly.

use faer::linalg::solvers::SolveCore;
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::sparse::{Argsort, CreationError, FaerError, Pair, SparseColMat, SymbolicSparseColMat};
use faer::{Conj, MatMut};
use std::sync::{Arc, OnceLock};

use crate::linalg::cholesky::SparseCholesky;
use crate::linalg::lu::{sparse_lu, SparseLu};
use crate::linalg::LinalgError;

/// Why a frame's force Jacobian could not be set up or factored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum JacobianError {
    /// faer could not build the lower-triangle pattern from the entries.
    #[error("force Jacobian pattern: {0:?}")]
    Pattern(CreationError),
    /// faer could not place the values on the pattern.
    #[error("force Jacobian: {0:?}")]
    Values(FaerError),
    /// The assembly has another number of entries than the pattern was
    /// made from.
    #[error("force Jacobian: {got} entries for a pattern of {expected}")]
    EntryCount { got: usize, expected: usize },
    /// The symbolic analysis or the LU factorization failed.
    #[error(transparent)]
    Factor(#[from] LinalgError),
}

/// Largest asymmetry `max |H - Hᵀ|` of an element block, relative to its
/// largest entry, for which `K` is factored as symmetric (its symmetric
/// part; the solves then differ from exact ones by about this much). Blocks
/// of a floored tet are asymmetric far beyond it; rounding stays near 1e-16.
pub const SYMMETRY_TOLERANCE: f64 = 1e-10;

/// The lower-triangle pattern of one frame's `K` and its symbolic Cholesky:
/// fixed by the mesh and the frame's free DOFs, so computed once per frame
/// and reused for every linearization of a fit.
pub struct KPattern {
    n: usize,
    /// Entries of the assembly it was made for (the same order every time).
    entries: usize,
    lower: SymbolicSparseColMat<usize>,
    argsort: Argsort<usize>,
    symbolic: Arc<SymbolicCholesky<usize>>,
}

impl KPattern {
    /// The pattern of the `n x n` matrix given by `k` (row, col, value;
    /// duplicates summed, both triangles).
    pub fn new(n: usize, k: &[(usize, usize, f64)]) -> Result<KPattern, JacobianError> {
        let pairs: Vec<Pair<usize, usize>> = k
            .iter()
            .map(|&(r, c, _)| Pair::new(r.max(c), r.min(c)))
            .collect();
        let (lower, argsort) = SymbolicSparseColMat::try_new_from_indices(n, n, &pairs)
            .map_err(JacobianError::Pattern)?;
        let matrix = symmetric_lower(&lower, &argsort, k)?;
        let symbolic = SparseCholesky::symbolic(matrix.as_ref())?;
        Ok(KPattern {
            n,
            entries: k.len(),
            lower,
            argsort,
            symbolic: Arc::new(symbolic),
        })
    }

    /// The lower triangle of `(K + Kᵀ) / 2` for entries `k` in the order
    /// the pattern was made from.
    fn lower_matrix(
        &self,
        k: &[(usize, usize, f64)],
    ) -> Result<SparseColMat<usize, f64>, JacobianError> {
        if k.len() != self.entries {
            return Err(JacobianError::EntryCount {
                got: k.len(),
                expected: self.entries,
            });
        }
        symmetric_lower(&self.lower, &self.argsort, k)
    }
}

/// The lower triangle of `(K + Kᵀ) / 2` on the pattern `lower` made (with
/// `argsort`) from the lower slots of `k`'s entries.
fn symmetric_lower(
    lower: &SymbolicSparseColMat<usize>,
    argsort: &Argsort<usize>,
    k: &[(usize, usize, f64)],
) -> Result<SparseColMat<usize, f64>, JacobianError> {
    // Each off-diagonal entry lands in the lower slot of its pair with half
    // its value, so the slot holds the symmetric part.
    let vals: Vec<f64> = k
        .iter()
        .map(|&(r, c, v)| if r == c { v } else { 0.5 * v })
        .collect();
    SparseColMat::new_from_argsort(lower.clone(), argsort, &vals).map_err(JacobianError::Values)
}

/// A frame's [`KPattern`], made at its first symmetric factorization
/// (`None` inside when the analysis failed: that frame then uses LU).
#[derive(Default)]
pub struct KPatternCache(OnceLock<Option<KPattern>>);

impl KPatternCache {
    fn get_or_make(&self, n: usize, k: &[(usize, usize, f64)]) -> Option<&KPattern> {
        self.0.get_or_init(|| KPattern::new(n, k).ok()).as_ref()
    }
}

/// A factored force Jacobian.
pub enum KFactor {
    /// Cholesky of the symmetric part (`K` symmetric to [`SYMMETRY_TOLERANCE`]).
    Cholesky(SparseCholesky<Arc<SymbolicCholesky<usize>>>),
    /// LU with partial pivoting of `K` itself (boxed: the larger one).
    Lu(Box<SparseLu>),
}

impl KFactor {
    /// Factors the `n x n` matrix `k` (row, col, value; duplicates summed):
    /// Cholesky on the frame's cached pattern when `symmetric` (what the
    /// assembly found) and positive definite, else LU.
    pub fn new(
        n: usize,
        k: &[(usize, usize, f64)],
        symmetric: bool,
        cache: &KPatternCache,
    ) -> Result<KFactor, JacobianError> {
        if let Some(p) = symmetric.then(|| cache.get_or_make(n, k)).flatten() {
            if p.n == n {
                let lower = p.lower_matrix(k)?;
                // A non-positive pivot (an unstable equilibrium) is not an
                // error: the LU below takes any non-singular K.
                if let Ok(c) = SparseCholesky::numeric(p.symbolic.clone(), lower.as_ref()) {
                    return Ok(KFactor::Cholesky(c));
                }
            }
        }
        Ok(KFactor::Lu(Box::new(sparse_lu(n, k)?)))
    }

    /// Solves `K X = B` in place for every column of `rhs`.
    pub fn solve_in_place(&self, rhs: MatMut<'_, f64>) {
        match self {
            KFactor::Cholesky(c) => c.solve_in_place(rhs),
            KFactor::Lu(lu) => lu.solve_in_place_with_conj(Conj::No, rhs),
        }
    }

    /// Solves `Kᵀ X = B` in place for every column of `rhs`.
    pub fn solve_transpose_in_place(&self, rhs: MatMut<'_, f64>) {
        match self {
            KFactor::Cholesky(c) => c.solve_in_place(rhs),
            KFactor::Lu(lu) => lu.solve_transpose_in_place_with_conj(Conj::No, rhs),
        }
    }

    /// Whether this is the Cholesky factor.
    pub fn is_cholesky(&self) -> bool {
        matches!(self, KFactor::Cholesky(_))
    }
}
