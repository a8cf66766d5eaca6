//! Why a sparse matrix could not be built or factored.
//!
//! The messages are faer's own `Debug` text of its errors (a symbolic
//! failure reads `IndexOverflow`, a Cholesky pivot
//! `NonPositivePivot { index: 3 }`), so the callers' messages
//! read as they always have.

use faer::linalg::cholesky::llt::factor::LltError;
use faer::sparse::linalg::LuError;
use faer::sparse::{CreationError, FaerError};

/// Why a sparse matrix could not be built or factored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LinalgError {
    /// An entry `(row, col)` lies outside the `n x n` matrix.
    #[error("entry ({row}, {col}) outside a {n} x {n} matrix")]
    EntryOutOfRange { row: usize, col: usize, n: usize },
    /// faer could not build the matrix from its entries (an entry out of
    /// bounds, an index overflow or no memory).
    #[error("{0:?}")]
    InvalidPattern(CreationError),
    /// The symbolic analysis of the sparsity pattern failed (an index
    /// overflow or no memory).
    #[error("{0:?}")]
    Symbolic(FaerError),
    /// The Cholesky factorization met a non-positive pivot: the matrix is
    /// not positive definite.
    #[error("NonPositivePivot {{ index: {pivot} }}")]
    NotPositiveDefinite { pivot: usize },
    /// The LU factorization found no pivot at step `pivot`: the matrix is
    /// structurally singular.
    #[error("sparse LU: SymbolicSingular {{ index: {pivot} }}")]
    SingularLu { pivot: usize },
    /// The LU factorization ran out of memory or index range.
    #[error("sparse LU: Generic({0:?})")]
    Lu(FaerError),
}

impl From<LltError> for LinalgError {
    fn from(e: LltError) -> Self {
        let LltError::NonPositivePivot { index } = e;
        LinalgError::NotPositiveDefinite { pivot: index }
    }
}

impl From<LuError> for LinalgError {
    fn from(e: LuError) -> Self {
        match e {
            LuError::SymbolicSingular { index } => LinalgError::SingularLu { pivot: index },
            LuError::Generic(g) => LinalgError::Lu(g),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The messages are faer's Debug text, as the callers always showed.
    #[test]
    fn messages_are_faers_debug_text() {
        let e = LltError::NonPositivePivot { index: 7 };
        assert_eq!(LinalgError::from(e).to_string(), format!("{e:?}"));
        for e in [
            LuError::SymbolicSingular { index: 3 },
            LuError::Generic(FaerError::IndexOverflow),
        ] {
            assert_eq!(
                LinalgError::from(e).to_string(),
                format!("sparse LU: {e:?}")
            );
        }
        let c = CreationError::OutOfBounds { row: 1, col: 2 };
        assert_eq!(LinalgError::InvalidPattern(c).to_string(), format!("{c:?}"));
        let s = FaerError::IndexOverflow;
        assert_eq!(LinalgError::Symbolic(s).to_string(), format!("{s:?}"));
        assert_eq!(
            LinalgError::EntryOutOfRange {
                row: 3,
                col: 0,
                n: 2
            }
            .to_string(),
            "entry (3, 0) outside a 2 x 2 matrix"
        );
    }
}
