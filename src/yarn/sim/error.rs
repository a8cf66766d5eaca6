//! Errors of the yarn-level simulator.

use super::handles::HandleError;
use crate::geom::GeomError;
use crate::yarn::tile::TileError;

/// Errors of the yarn-level simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum YarnSimError {
    /// The yarns are not well formed.
    #[error("invalid yarns: {0}")]
    Geom(#[from] GeomError),
    /// The periodic tile is not well formed.
    #[error("invalid periodic tile: {0}")]
    Tile(#[from] TileError),
    /// A parameter or input value out of range.
    #[error("invalid {name}: {message}")]
    Param { name: &'static str, message: String },
    /// A handle description that does not fit the yarns.
    #[error("invalid handle: {0}")]
    Handle(#[from] HandleError),
    /// The simulation diverged at time step `step` (1-based, counted over the
    /// simulator's life) at simulated time `time`; `vertex` is the worst vertex.
    #[error(
        "yarn simulation diverged at step {step} (t = {time} s), worst vertex {vertex}: {reason}"
    )]
    Diverged {
        step: u64,
        time: f64,
        vertex: usize,
        reason: String,
    },
}
