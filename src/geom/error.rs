//! The error of malformed geometry, shared by the yarn and rest-shape checks.

use super::Vec3;

/// Why a set of yarns or frames is not well formed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeomError {
    #[error("curve {curve} has {points} point(s); an open yarn needs at least 2, a closed one 3")]
    TooFewPoints {
        curve: usize,
        points: usize,
        closed: bool,
    },
    #[error("curve {curve}, point {point}: coordinate is not finite ({value:?})")]
    NonFinitePoint {
        curve: usize,
        point: usize,
        value: Vec3,
    },
    #[error("curve {curve}: radius {value} is not a positive finite number")]
    BadRadius { curve: usize, value: f64 },
    #[error("vertex {vertex}: radius {value} is not a positive finite number")]
    BadVertexRadius { vertex: usize, value: f64 },
    #[error("curve {curve}: linear density {value} is not a non-negative finite number")]
    BadLinearDensity { curve: usize, value: f64 },
    #[error("inconsistent layout: {0}")]
    Layout(String),
    #[error("frame {frame}: {message}")]
    Frame { frame: usize, message: String },
}
