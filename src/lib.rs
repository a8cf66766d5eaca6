//! knitvox: yarn-level knitwear to homogenized tetrahedral simulation.
//!
//! Layering (see DESIGN.md): `geom`, `embed`, `fit`, `sim`, `yarn`, `anim` are pure
//! (no files, no printing, no environment); `io` converts bytes and types;
//! `pipeline`/`daemon` orchestrate; the `cli` module and `main` own processes and exit codes.
pub mod anim;
pub mod cli;
pub mod daemon;
pub mod embed;
pub mod fit;
pub mod geom;
pub mod io;
pub mod pipeline;
pub mod sim;
pub mod yarn;
