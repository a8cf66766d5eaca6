//! The inertia term of implicit Euler as an energy term, so the quasi-static
//! Newton solver also integrates dynamics (Martin et al. 2011, "Example-based
//! elastic materials"; Gast et al. 2015 "Optimization integrator"): one step
//! of size h from (x, v) minimizes
//! `sum_i m_i / (2 h^2) |x_i' - x~_i|^2 + E(x')`, `x~ = x + h v`,
//! and v' = (x' - x) / h. External constant forces (gravity) belong to E.

use crate::yarn::statics::{EnergyTerm, Triplets};

/// `sum_i m_i / (2 h^2) |x_i - target_i|^2` over the position DOFs.
#[derive(Debug, Clone)]
pub struct InertiaTerm {
    /// Lumped mass per vertex (kg).
    pub mass: Vec<f64>,
    /// Predicted positions `x + h v` (m), 3 per vertex.
    pub target: Vec<f64>,
    /// Time step h (s).
    pub dt: f64,
    /// Name in the solver's statistics.
    pub label: &'static str,
}

impl InertiaTerm {
    /// A term for `mass.len()` vertices predicting `target` with step `dt`.
    pub fn new(mass: Vec<f64>, target: Vec<f64>, dt: f64) -> InertiaTerm {
        debug_assert_eq!(3 * mass.len(), target.len());
        InertiaTerm {
            mass,
            target,
            dt,
            label: "inertia",
        }
    }

    /// Rayleigh mass damping `gamma m v` (gamma in 1/s) over a step of
    /// `dt` from `start`: with `v = (x - start) / dt` its potential is
    /// `sum_i gamma m_i / (2 dt) |x_i - start_i|^2`, the inertia form with
    /// step `sqrt(dt / gamma)`. `gamma` must be > 0.
    pub fn damping(mass: Vec<f64>, start: Vec<f64>, dt: f64, gamma: f64) -> InertiaTerm {
        InertiaTerm {
            label: "damping",
            ..InertiaTerm::new(mass, start, (dt / gamma).sqrt())
        }
    }
}

impl EnergyTerm for InertiaTerm {
    fn name(&self) -> &'static str {
        self.label
    }

    fn eval(&self, q: &[f64], grad: &mut [f64], hess: Option<&mut Triplets>) -> f64 {
        let inv_h2 = 1.0 / (self.dt * self.dt);
        let mut e = 0.0;
        for (v, &m) in self.mass.iter().enumerate() {
            let k = m * inv_h2;
            for c in 0..3 {
                let i = 3 * v + c;
                let d = q[i] - self.target[i];
                e += 0.5 * k * d * d;
                grad[i] += k * d;
            }
        }
        if let Some(h) = hess {
            for (v, &m) in self.mass.iter().enumerate() {
                for c in 0..3 {
                    h.push(3 * v + c, 3 * v + c, m * inv_h2);
                }
            }
        }
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences_and_hessian_is_diagonal_mass() {
        let t = InertiaTerm::new(vec![2.0, 0.5], vec![0.1, 0.2, 0.3, -0.1, 0.0, 0.4], 0.01);
        let q = vec![0.12, 0.18, 0.35, -0.2, 0.05, 0.41];
        let mut g = vec![0.0; 6];
        let mut h = Triplets::new();
        t.eval(&q, &mut g, Some(&mut h));
        for i in 0..6 {
            let eps = 1e-6;
            let (mut qp, mut qm) = (q.clone(), q.clone());
            qp[i] += eps;
            qm[i] -= eps;
            let mut sink = vec![0.0; 6];
            let fd = (t.eval(&qp, &mut sink, None) - t.eval(&qm, &mut sink, None)) / (2.0 * eps);
            assert!(
                (fd - g[i]).abs() <= 1e-6 * g[i].abs().max(1.0),
                "{i}: {fd} vs {}",
                g[i]
            );
        }
        assert_eq!(h.len(), 6);
        assert_eq!(h.vals[0], 2.0 / 1e-4);
        assert_eq!(h.vals[5], 0.5 / 1e-4);
    }
}
