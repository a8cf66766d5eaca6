//! Sparse and dense linear algebra shared by the solvers: the Y2V shape fit,
//! the PD global step, the Newton statics of the tet mesh and of the yarns,
//! and the adjoint of the elasticity fit.
//!
//! * [`csr`]: CSR matrices for the iterative global-step parts.
//! * [`cholesky`]: sparse SPD factorization (faer), symbolic once per pattern.
//! * [`woodbury`]: low-rank updates of a factored SPD matrix.
//! * [`anderson`]: Anderson acceleration of fixed-point iterations (Peng et
//!   al. 2018).
//! * [`lu`]: sparse LU of square, possibly indefinite systems.
//! * [`error`]: why a matrix could not be built or factored.
//!
//! Pure: no files, no printing, no environment.

pub mod anderson;
pub mod cholesky;
pub mod csr;
pub mod error;
pub mod lu;
pub mod woodbury;

pub use error::LinalgError;
