//! Anderson acceleration of a fixed-point iteration `x ← G(x)` (type II,
//! Walker & Ni 2011; applied to projective dynamics with an energy safeguard
//! by Peng et al. 2018, "Anderson acceleration for geometry optimization and
//! physics simulation").
//!
//! One PD iteration (local step, then global solve) is the fixed-point map
//! `G`; it equals `x - K⁻¹ ∇Φ(x)`, a preconditioned gradient step, and
//! converges linearly and slowly on soft, large motions. Anderson mixing
//! keeps the last `m` residuals `f_j = G(x_j) - x_j` and returns
//!
//! `x_{k+1} = G(x_k) - ΔG θ`, `θ = argmin |f_k - ΔF θ|²`,
//!
//! with `ΔF`, `ΔG` the differences of consecutive residuals and map values:
//! a multisecant quasi-Newton step that needs no extra evaluation of `G`.
//! The accelerated point is not guaranteed to lower the objective, so the
//! caller keeps the plain `G(x_k)` as a fallback and [`Self::reset`]s the
//! history when the accelerated point is rejected (Peng et al. Alg. 2).
//!
//! The least-squares problem is solved through its `m x m` normal equations
//! with a small relative Tikhonov term (the columns become nearly dependent
//! as the iteration converges); all sums run sequentially in index order, so
//! the result does not depend on the thread count.

/// Relative Tikhonov regularization of the normal equations.
const REGULARIZATION: f64 = 1e-10;

/// The history of an Anderson-accelerated fixed-point iteration.
#[derive(Debug, Clone)]
pub struct Anderson {
    window: usize,
    /// Last iterate and map value (`x_k`, `G(x_k)`), once one was seen.
    last: Option<(Vec<f64>, Vec<f64>)>,
    /// Columns `ΔF_j`, `ΔG_j`, oldest first (at most `window`).
    df: Vec<Vec<f64>>,
    dg: Vec<Vec<f64>>,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl Anderson {
    /// Mixing over the last `window` residual differences (>= 1).
    pub fn new(window: usize) -> Anderson {
        Anderson {
            window: window.max(1),
            last: None,
            df: Vec::new(),
            dg: Vec::new(),
        }
    }

    /// Forgets the history (the next [`Self::step`] returns `G(x)` itself).
    pub fn reset(&mut self) {
        self.last = None;
        self.df.clear();
        self.dg.clear();
    }

    /// Columns in the history.
    pub fn len(&self) -> usize {
        self.df.len()
    }

    /// True before the history has a column.
    pub fn is_empty(&self) -> bool {
        self.df.is_empty()
    }

    /// Records the pair (`x`, `g = G(x)`) and returns the accelerated next
    /// iterate (`g` itself while the history is empty or the least-squares
    /// problem is degenerate).
    pub fn step(&mut self, x: &[f64], g: &[f64]) -> Vec<f64> {
        let f: Vec<f64> = g.iter().zip(x).map(|(a, b)| a - b).collect();
        if let Some((lx, lg)) = self.last.take() {
            if lx.len() == x.len() {
                let lf = lg.iter().zip(&lx).map(|(a, b)| a - b);
                self.df.push(f.iter().zip(lf).map(|(a, b)| a - b).collect());
                self.dg
                    .push(g.iter().zip(&lg).map(|(a, b)| a - b).collect());
                if self.df.len() > self.window {
                    self.df.remove(0);
                    self.dg.remove(0);
                }
            } else {
                self.df.clear();
                self.dg.clear();
            }
        }
        self.last = Some((x.to_vec(), g.to_vec()));
        let m = self.df.len();
        if m == 0 {
            return g.to_vec();
        }
        let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut rhs = nalgebra::DVector::<f64>::zeros(m);
        for i in 0..m {
            for j in 0..=i {
                let v = dot(&self.df[i], &self.df[j]);
                a[(i, j)] = v;
                a[(j, i)] = v;
            }
            rhs[i] = dot(&self.df[i], &f);
        }
        let scale = (0..m).map(|i| a[(i, i)]).fold(0.0, f64::max);
        if !(scale > 0.0 && scale.is_finite()) {
            return g.to_vec();
        }
        for i in 0..m {
            a[(i, i)] += REGULARIZATION * scale;
        }
        let Some(theta) = a.cholesky().map(|c| c.solve(&rhs)) else {
            return g.to_vec();
        };
        if !theta.iter().all(|t| t.is_finite()) {
            return g.to_vec();
        }
        let mut out = g.to_vec();
        for (j, t) in theta.iter().enumerate() {
            for (o, d) in out.iter_mut().zip(&self.dg[j]) {
                *o -= t * d;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `G(x) = x - P (A x - b)`: gradient descent on a quadratic with a
    /// poor preconditioner converges slowly; Anderson(m) must converge in
    /// far fewer iterations (for a linear map it matches GMRES).
    #[test]
    fn accelerates_a_slow_linear_iteration() {
        let n = 30;
        let diag: Vec<f64> = (0..n).map(|i| 1.0 + 0.1 * i as f64).collect();
        let b: Vec<f64> = (0..n).map(|i| ((i * 7) % 5) as f64 - 2.0).collect();
        let exact: Vec<f64> = b.iter().zip(&diag).map(|(b, d)| b / d).collect();
        let omega = 1.0 / 4.0; // slow: contraction 1 - omega * 1 = 0.75
        let g = |x: &[f64]| -> Vec<f64> {
            x.iter()
                .zip(&diag)
                .zip(&b)
                .map(|((x, d), b)| x - omega * (d * x - b))
                .collect()
        };
        let err = |x: &[f64]| -> f64 {
            x.iter()
                .zip(&exact)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let mut plain = vec![0.0; n];
        let mut acc = vec![0.0; n];
        let mut aa = Anderson::new(6);
        for _ in 0..25 {
            plain = g(&plain);
            let gx = g(&acc);
            acc = aa.step(&acc, &gx);
        }
        assert!(err(&plain) > 1e-4, "plain iteration error {}", err(&plain));
        assert!(
            err(&acc) < 1e-3 * err(&plain),
            "{} vs {}",
            err(&acc),
            err(&plain)
        );
        assert!(aa.len() <= 6);
    }

    #[test]
    fn first_step_and_reset_return_the_map_value() {
        let mut aa = Anderson::new(3);
        let x = vec![1.0, 2.0];
        let g = vec![1.5, 1.0];
        assert_eq!(aa.step(&x, &g), g);
        assert_eq!(aa.len(), 0);
        let x2 = g.clone();
        let g2 = vec![1.6, 0.9];
        let _ = aa.step(&x2, &g2);
        assert_eq!(aa.len(), 1);
        aa.reset();
        assert!(aa.is_empty());
        assert_eq!(aa.step(&x2, &g2), g2);
    }

    #[test]
    fn converged_history_is_not_a_nan() {
        let mut aa = Anderson::new(4);
        let x = vec![1.0; 5];
        for _ in 0..4 {
            let out = aa.step(&x, &x);
            assert!(out.iter().all(|v| v.is_finite()));
            assert_eq!(out, x);
        }
    }
}
