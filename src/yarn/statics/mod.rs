//! Quasi-static yarn mechanics: the total potential over generalized
//! coordinates, split into terms (rods, contact, friction, gravity, ...), and
//! the Newton solver that brings it to equilibrium (issue: knit ground truth).
//!
//! Coordinates `q` (SI units): `3 * n_vertices` positions (m) first, vertex
//! `v` at `q[3v..3v + 3]`, then one twist angle (rad) per rod edge where the
//! model carries material frames. Every term sees the whole `q`.
//!
//! Pure: no files, no printing, no environment.

pub mod assemble;
pub mod collider;
pub mod contact;
pub mod external;
pub mod friction;
pub mod solver;
pub mod term;

pub use collider::ColliderTerm;
pub use contact::{ContactStats, ContactTerm, NEAR_FACTOR};
pub use external::GravityTerm;
pub use friction::{Carry, FrictionContact, FrictionParams, FrictionTerm};
pub use solver::{
    evaluate, reaction_forces, solve_static, StaticError, StaticStats, SymbolicCache,
    YarnStaticParams,
};
pub use term::{EnergyTerm, Triplets};
