//! Contact with external bodies as PD projection constraints (VH §8.5,
//! Bouaziz et al. 2014 §5): a node `i` at `p` that is not admissible (inside a
//! collider, or closer to it than the collider's thickness) gets the
//! constraint energy `½ w_i |x_i - P(p)|²`, where `P(p)` is the closest
//! admissible position. The solver re-projects every PD iteration.
//!
//! This module holds only the interface shared by the colliders
//! (`sim::collide`) and the time loop (`sim::pd`).

use crate::geom::Vec3;

/// Something the free nodes must stay out of during one time step (a set of
/// colliders posed at the step's end time).
pub trait NodeProjector: Sync {
    /// The closest admissible position (m) for node `node` at `p` (m), or
    /// `None` when `p` is already admissible. Must be cheap and thread-safe:
    /// the solver calls it for every free node in every PD iteration.
    fn project(&self, node: usize, p: Vec3) -> Option<Vec3>;
}

/// No colliders.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoContact;

impl NodeProjector for NoContact {
    fn project(&self, _node: usize, _p: Vec3) -> Option<Vec3> {
        None
    }
}
