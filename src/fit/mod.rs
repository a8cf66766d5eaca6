//! Fitting: Y2V shape fitting (VH §5) now; elasticity fitting (VH §6) later.

pub mod elastic;
pub mod golden;
pub mod shapefit;

pub use shapefit::{FitError, FitStats, ShapeFitParams, ShapeFitter};

#[cfg(test)]
mod y2v_tests;
