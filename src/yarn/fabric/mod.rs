//! Fabric-level tests on yarn-level swatches (Sperl et al. 2022 §4): the
//! clamped stretch test and hanging, run quasi-statically (or with implicit
//! Euler) by the Newton solver of [`crate::yarn::statics`]; and the
//! relaxation of a generated pattern into a rest state held by contact
//! (Leaf 2018 §6).
//!
//! Pure: no files, no printing, no environment.

pub mod bend;
pub mod dynamics;
pub mod hang;
pub mod inertia;
pub mod model;
pub mod pose;
pub mod relax;
pub mod rig;
pub mod stretch;

pub use dynamics::{RodAdvanceStats, RodDynamics, RodDynamicsParams};
pub use hang::{hang_test, HangParams, HangResult};
pub use inertia::InertiaTerm;
pub use model::{
    lumped_masses, Fabric, FabricError, FabricParams, MaterialChoice, Settle, SettleStats,
};
pub use relax::{relax_into_contact, RelaxIntoContactStats, RelaxParams};
pub use rig::{Direction, Rig};
pub use stretch::{stretch_test, RigFrame, StretchParams, StretchPoint, StretchResult};
