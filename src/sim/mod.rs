//! Projective dynamics of the homogenized tet mesh (VH §7; DESIGN.md method
//! map rows "energy", "local step", "global step").
//!
//! * [`energy`]: the element energy of VH Eq. 7-8, its gradient, totals.
//! * [`local`]: the PD local step (VH §7.1, Eq. 26): closest rotation and
//!   closest volume-preserving matrix per tet.
//!
//! Pure: no files, no printing, no environment.

pub mod energy;
pub mod local;

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
}
