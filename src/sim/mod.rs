//! Projective dynamics of the homogenized tet mesh (VH §7; docs/design.md method
//! map rows "energy", "local step", "global step").
//!
//! * [`energy`]: the element energy of VH Eq. 7-8, its gradient, totals.
//! * [`fibre`]: tension-only fibre families, the anisotropy Eq. 7 lacks.
//! * [`hessian`]: its force Jacobian (exact and PSD-projected) and the
//!   derivatives of the force with respect to `γs`, `γv`.
//! * [`statics`]: Newton equilibrium of the tet mesh (VH Eq. 13-14).
//! * [`element`]: one tet's rest data and node-gradient map, shared by the
//!   energy, its Hessian and the fibres.
//! * [`projection`]: the signed SVD and the closest rotation and closest
//!   volume-preserving matrix (VH §7.1, Eq. 26).
//! * [`local`]: the PD local step: those projections for every tet.
//! * [`collide`]: planes, spheres and posed triangle meshes as colliders.
//! * [`contact`]: the collider interface of the time loop (projection
//!   constraints).
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

pub mod backend;
pub mod collide;
pub mod contact;
pub mod cpu;
pub mod dd;
pub mod element;
pub mod energy;
pub mod fibre;
pub mod gpu;
pub mod hessian;
pub mod jacobi;
pub mod knit;
pub mod local;
pub mod partition;
pub mod pd;
pub mod projection;
pub mod shot;
pub mod statics;
#[cfg(test)]
mod test_util;

pub use element::TetRest;
pub use energy::{gradient, total_energy, ElasticModel};
pub use local::{local_step, LocalStats, TetTargets};
pub use projection::{project_diag_sl3, project_rotation, project_volume, DiagProjection};

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
