//! Constant external forces as energy terms.

use super::term::{EnergyTerm, Triplets};
use crate::geom::Vec3;

/// Gravity: `E = -sum_i m_i g . x_i` (J); no Hessian.
#[derive(Debug, Clone)]
pub struct GravityTerm {
    /// Lumped mass per vertex (kg).
    pub mass: Vec<f64>,
    /// Acceleration (m/s^2), e.g. [0, -9.81, 0].
    pub g: Vec3,
}

impl EnergyTerm for GravityTerm {
    fn name(&self) -> &'static str {
        "gravity"
    }

    fn eval(&self, q: &[f64], grad: &mut [f64], _hess: Option<&mut Triplets>) -> f64 {
        let mut e = 0.0;
        for (v, &m) in self.mass.iter().enumerate() {
            for c in 0..3 {
                e -= m * self.g[c] * q[3 * v + c];
                grad[3 * v + c] -= m * self.g[c];
            }
        }
        e
    }
}
