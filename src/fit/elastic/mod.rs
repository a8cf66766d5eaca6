//! Elasticity fitting (VH 2024 §6, Eq. 9-24): per-element `γs`, `γv` of the
//! Eq. 7 energy learned from target poses of the tet mesh.
//!
//! * [`loss`]: the loss of VH Eq. 10 for one frame (deformation-gradient term
//!   plus the α position term), its gradient and its constant Hessian `G`.
//! * [`adjoint`]: the equilibrium of Eq. 14 per frame ([`crate::sim::statics`])
//!   and the adjoint gradient of the loss (Eq. 16-17).
//! * [`force_loss`]: the clamp-force term a frame's loss may carry (the
//!   wrench each held band holds against the yarn level's).
//! * [`error`]: why a frame's solve or a sample's check failed.
//! * [`jacobian`]: the factor of a frame's force Jacobian `K` that the
//!   adjoint and the Gauss-Newton products solve with (sparse Cholesky
//!   where `K` is symmetric positive definite, its analysis kept per frame;
//!   else sparse LU).
//! * [`gauss_newton`]: the adjoint Gauss-Newton direction (Eq. 19-21, with the
//!   Levenberg-Marquardt `κ I`), line search and the non-negativity
//!   projection / pivoting of §6.3, and the staged optimizer of one sample.
//! * `scale_search`: the stage before them where frames carry external
//!   forces, a search over one common factor of the field.
//! * [`harmonic`]: the harmonic bases of §6.5 (lowest eigenvectors of the
//!   tet-mesh graph Laplacian).
//! * [`samples`]: sample-by-sample fitting with the energy-weighted convex
//!   average of Eq. 22, and the driver [`fit_materials`].
//!
//! Units: positions m, forces N, `γ` Pa, loss m³ (`V_e |F - F̂|²`; the
//! position term is made commensurate by its weights, [`loss::FrameTarget`]).
//! Pure: no files, no printing, no environment.

pub mod adjoint;
pub mod error;
pub mod force_loss;
pub mod gauss_newton;
pub mod harmonic;
pub mod jacobian;
pub mod loss;
mod regularizer;
mod row_lists;
pub mod samples;
mod scale_search;
mod types;

#[cfg(test)]
mod tests;

pub use error::{SampleError, SolveError};
pub use gauss_newton::{fit_sample, StageReport};
pub use loss::{FrameTarget, PositionTerm, TargetError};
pub use samples::{fit_materials, FitInputs, FitReport, SampleReport};
pub use types::{
    CgParams, ElasticFitError, ElasticFitParams, FitProgress, Frame, MaterialFields, Sample,
    KKT_MAX_UNKNOWNS,
};
