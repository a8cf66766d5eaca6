//! Why one frame's solve or one sample's check failed: the messages a
//! fitted sample reports ([`super::ElasticFitError::Sample`]) and that
//! `validate` and `fit` show for a frame without equilibrium.

use super::jacobian::JacobianError;
use super::loss::TargetError;
use crate::linalg::LinalgError;
use crate::sim::SimError;

/// Why an equilibrium, a linearization or a Gauss-Newton step of the
/// elasticity fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// The simulator refused the model or the positions (a bad material,
    /// pins out of range, inverted tets).
    #[error(transparent)]
    Model(#[from] SimError),
    /// The static solve from the frame's start failed.
    #[error("no equilibrium: {0}")]
    NoEquilibrium(SimError),
    /// The static solve stalled, and a second one to the looser
    /// `tolerance` failed too.
    #[error("no equilibrium: {first}; to {tolerance:e}: {second}")]
    Stalled {
        first: SimError,
        tolerance: f64,
        second: SimError,
    },
    /// The relative residual stayed above the tolerance after the exact
    /// Newton polish, or the positions are not finite.
    #[error("no equilibrium: relative residual {residual:e} > {tolerance:e}")]
    NotConverged { residual: f64, tolerance: f64 },
    /// The residual of the static equations is not finite.
    #[error("non-finite residual")]
    NonFiniteResidual,
    /// A sparse factorization of the polish or the adjoint failed.
    #[error(transparent)]
    Linalg(#[from] LinalgError),
    /// The anchor of a continuation was made for another mesh or material
    /// layout.
    #[error("continuation anchor does not match the mesh")]
    AnchorMismatch,
    /// A continuation gave up `fraction` (0 to 1) of the way along its path
    /// in `ln γ`; `error` is the last failed solve.
    #[error("{error} (the continuation stopped {:.0}% of the way in ln γ)", 100.0 * .fraction)]
    Continuation {
        error: Box<SolveError>,
        fraction: f64,
    },
    /// The force Jacobian `K` could not be factored.
    #[error("force Jacobian: {0}")]
    Jacobian(#[from] JacobianError),
    /// The adjoint state came out non-finite: `K` is singular.
    #[error("the force Jacobian is singular (adjoint not finite)")]
    SingularAdjoint,
    /// The loss of a frame's equilibrium is not finite.
    #[error("the loss is not finite")]
    NonFiniteLoss,
    /// A parameter coupling was given with a harmonic basis.
    #[error("a parameter coupling needs the full basis")]
    CouplingNeedsFullBasis,
    /// The sparse LU of the Gauss-Newton system (Eq. 21) failed.
    #[error("Gauss-Newton system: {0}")]
    GaussNewtonSystem(LinalgError),
    /// The dense Gauss-Newton matrix of a harmonic subspace is singular.
    #[error("Gauss-Newton system: the subspace matrix is singular")]
    SingularSubspace,
    /// The Gauss-Newton direction has a non-finite component.
    #[error("Gauss-Newton direction is not finite")]
    NonFiniteDirection,
    /// Conjugate gradients on the Gauss-Newton system took no step or
    /// ended with a non-finite direction.
    #[error("Gauss-Newton direction: conjugate gradients failed (relative residual {residual:e})")]
    ConjugateGradients { residual: f64 },
    /// A sparse entry lies outside the `rows` rows, or its column does not
    /// fit in `u32`.
    #[error("entry ({row}, {col}) outside {rows} rows of u32 columns")]
    RowEntryOutOfRange { row: usize, col: usize, rows: usize },
}

/// Why a sample does not fit the mesh it is to be fitted on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SampleError {
    /// The sample has no frames.
    #[error("the sample has no frames")]
    NoFrames,
    /// The sample's energy weight is not a positive finite number.
    #[error("energy weight {weight} must be > 0 and finite")]
    EnergyWeight { weight: f64 },
    /// The node masses do not match the mesh.
    #[error("{masses} masses for {nodes} nodes")]
    MassCount { masses: usize, nodes: usize },
    /// A frame's start positions or forces do not match the mesh.
    #[error("{starts} start positions and {forces} forces for {nodes} nodes")]
    FrameLengths {
        starts: usize,
        forces: usize,
        nodes: usize,
    },
    /// A frame pins a node the mesh does not have.
    #[error("pinned node {node} but the mesh has {nodes} nodes")]
    PinnedOutOfRange { node: usize, nodes: usize },
    /// A frame's start position or force is not finite.
    #[error("non-finite start position or force")]
    NonFinite,
    /// A frame's targets do not fit the model.
    #[error(transparent)]
    Target(#[from] TargetError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_continuation_names_how_far_it_came() {
        let e = SolveError::Continuation {
            error: Box::new(SolveError::NonFiniteResidual),
            fraction: 0.375,
        };
        assert_eq!(
            e.to_string(),
            "non-finite residual (the continuation stopped 38% of the way in ln γ)"
        );
        let e = SolveError::NotConverged {
            residual: 2.5e-7,
            tolerance: 1e-8,
        };
        assert_eq!(
            e.to_string(),
            "no equilibrium: relative residual 2.5e-7 > 1e-8"
        );
    }
}
