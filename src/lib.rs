//! knitvox: yarn-level knitwear to homogenized tetrahedral simulation.
//!
//! Layering (docs/design.md): `geom`, `linalg`, `embed`, `fit`, `sim`, `yarn`,
//! `anim` are pure (no files, no printing, no environment) and never import
//! `io`, `pipeline`, `daemon` or `cli`; `io` converts bytes and types;
//! `pipeline`/`daemon` orchestrate; the `cli` module and `main` own processes
//! and exit codes. No two files import each other, directly or through
//! others (`tests/layering.rs` checks both).
// Guards are written `!(x > 0.0)` on purpose: unlike `x <= 0.0` they also
// reject NaN, which is what a check of a value read from a file or produced
// by a solver must do.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]
pub mod anim;
pub mod cli;
pub mod daemon;
pub mod embed;
pub mod fit;
pub mod geom;
pub mod io;
pub mod linalg;
pub mod pipeline;
pub mod sim;
pub mod yarn;
