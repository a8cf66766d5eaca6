//! Sparse LU of square systems that need not be symmetric or definite (the
//! elasticity fit's KKT systems, `K` when its Cholesky factorization fails).

use faer::sparse::{SparseColMat, Triplet};

use super::error::LinalgError;

/// faer's sparse LU of a square `f64` matrix.
pub type SparseLu = faer::sparse::linalg::solvers::Lu<usize, f64>;

/// Sparse LU of the square matrix given by `entries` (duplicates summed).
pub fn sparse_lu(n: usize, entries: &[(usize, usize, f64)]) -> Result<SparseLu, LinalgError> {
    let trip: Vec<Triplet<usize, usize, f64>> = entries
        .iter()
        .map(|&(r, c, v)| Triplet::new(r, c, v))
        .collect();
    let a =
        SparseColMat::try_new_from_triplets(n, n, &trip).map_err(LinalgError::InvalidPattern)?;
    Ok(a.sp_lu()?)
}
