//! Fabric-level tests on yarn-level swatches (Sperl et al. 2022 §4): the
//! clamped stretch test, the pear-loop bending test and hanging, run
//! quasi-statically (or with implicit Euler) by the Newton solver of
//! [`crate::yarn::statics`]; and the relaxation of a generated pattern into a
//! rest state held by contact (Leaf 2018 §6).
//!
//! Pure: no files, no printing, no environment.

pub mod inertia;

pub use inertia::InertiaTerm;
