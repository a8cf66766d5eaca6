//! Projective dynamics of the homogenized tet mesh (VH §7; DESIGN.md method
//! map rows "energy", "local step", "global step").
//!
//! * [`anderson`]: Anderson acceleration of the PD iterations (Peng et al.
//!   2018).
//! * [`energy`]: the element energy of VH Eq. 7-8, its gradient, totals.
//! * [`fibre`]: tension-only fibre families, the anisotropy Eq. 7 lacks.
//! * [`hessian`]: its force Jacobian (exact and PSD-projected) and the
//!   derivatives of the force with respect to `γs`, `γv`.
//! * [`statics`]: Newton equilibrium of the tet mesh (VH Eq. 13-14).
//! * [`local`]: the PD local step (VH §7.1, Eq. 26): closest rotation and
//!   closest volume-preserving matrix per tet.
//! * [`collide`]: planes, spheres and posed triangle meshes as colliders.
//! * [`contact`]: the collider interface of the time loop (projection
//!   constraints).
//! * [`csr`]: CSR matrices for the iterative global-step parts.
//! * [`cpu`]: CPU implementations of the [`backend`] traits.
//! * [`jacobi`]: Chebyshev-accelerated Jacobi (Wang 2015).
//! * [`partition`]: domains and boundary nodes for the decomposition.
//! * [`dd`]: the domain-decomposed (CMS) global solve (VH §7.2).
//! * [`gpu`]: the wgpu backend (WGSL kernels of the local step, Chebyshev-
//!   Jacobi and collider projection).
//! * [`pd`]: the global step (direct or domain-decomposed, VH Eq. 27-34),
//!   contacts as projection constraints, and the implicit-Euler time loop
//!   (VH Eq. 25).
//!
//! Pure: no files, no printing, no environment.

pub mod anderson;
pub mod backend;
pub mod cholesky;
pub mod collide;
pub mod contact;
pub mod cpu;
pub mod csr;
pub mod dd;
pub mod energy;
pub mod fibre;
pub mod gpu;
pub mod hessian;
pub mod jacobi;
pub mod local;
pub mod partition;
pub mod pd;
pub mod shot;
pub mod statics;
#[cfg(test)]
mod test_util;
pub mod woodbury;

pub use energy::{gradient, total_energy, ElasticModel, TetRest};
pub use local::{
    local_step, project_diag_sl3, project_rotation, project_volume, DiagProjection, LocalStats,
    TetTargets,
};

/// Errors of the simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// Inputs that do not fit together (lengths, indices, non-positive rest
    /// volumes, negative or non-finite stiffnesses).
    #[error("inconsistent inputs: {0}")]
    Inconsistent(String),
    /// The simulation diverged at time step `step` (1-based count of steps
    /// taken by the solver): non-finite positions, a speed above the guard or
    /// an energy blow-up; `node` is the worst node.
    #[error("simulation diverged at step {step}, node {node}: {reason}")]
    Diverged {
        step: u64,
        node: usize,
        reason: String,
    },
}
