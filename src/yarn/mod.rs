//! Yarn-level curves: analytic example swatches and the periodic tile shared
//! by the stitch-pattern generator and the yarn-level simulator.

pub mod analytic;
pub mod fabric;
pub mod pattern;
pub mod poses;
pub mod rods;
pub mod sim;
pub mod statics;
pub mod tile;

pub use tile::{PeriodicTile, TileError};
