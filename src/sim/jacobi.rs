//! Chebyshev semi-iterative Jacobi on the CPU (Wang 2015, "A Chebyshev
//! semi-iterative approach for accelerating projective and position-based
//! dynamics"; VH §7.2 uses it after the subspace solve): [`CpuJacobi`]
//! implements [`JacobiSolve`] for a sparse SPD matrix `A` (the free block of
//! the PD matrix `K`) and an optional extra diagonal `W` (contact weights).
//!
//! # Iteration
//! With `D` the diagonal of `A + W` and the damped Jacobi update
//! `y = x_k + γ D⁻¹ (b - (A + W) x_k)`, the Chebyshev iterate is
//! `x_{k+1} = ω_{k+1} (y - x_{k-1}) + x_{k-1}`, `ω_1 = 1`,
//! `ω_2 = 2 / (2 - ρ²)`, `ω_{k+1} = 4 / (4 - ρ² ω_k)`, where `ρ` is the
//! spectral radius of the damped Jacobi iteration matrix `I - γ D⁻¹ A`.
//!
//! # Spectral estimate
//! `ρ` and the damping `γ` come from the extreme eigenvalues of `D⁻¹ A`
//! (equal to those of the symmetric `D^-½ A D^-½`), estimated once per matrix
//! by [`LANCZOS_STEPS`] Lanczos steps from a fixed start vector. Ritz values
//! lie inside the spectrum and the extreme ones converge first, so the
//! estimate of `λmax` is slightly low and that of `λmin` slightly high; both
//! are widened by safety margins ([`JacobiParams::lambda_min_margin`],
//! [`JacobiParams::lambda_max_margin`]) because Chebyshev acceleration with
//! an underestimated `ρ` can diverge while an overestimated one only slows it
//! down. Unless [`JacobiParams::relaxation`] fixes it, `γ = 2 / (λmin +
//! λmax)`, which centres the spectrum of `I - γ D⁻¹ A` on 0 so that
//! `ρ = (λmax - λmin) / (λmax + λmin)` (the symmetric interval Chebyshev
//! acceleration assumes).
//!
//! # Extra diagonal
//! For `A + W` with `W >= 0` diagonal the generalized Rayleigh quotient
//! `xᵀ(A + W)x / xᵀ(D_A + W)x` is a weighted mean of `xᵀAx / xᵀD_A x` and
//! `xᵀWx / xᵀWx = 1`, and `1` lies in `[λmin, λmax]` (the mean eigenvalue of
//! `D⁻¹A` is 1). So the spectrum of `(D_A + W)⁻¹ (A + W)` stays inside the
//! estimated interval and the same `γ`, `ρ` remain valid (conservative) for
//! any contact weights: no re-estimation when the active set changes.
//!
//! # Determinism
//! Rows are updated in parallel (each row only reads the previous iterate),
//! norms are summed per fixed-size chunk and then in chunk order, so the
//! result does not depend on the thread count.

// `!(a > b)` is deliberate: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use rayon::prelude::*;

use super::backend::{check_jacobi_inputs, IterStats, JacobiSolve};
use super::SimError;
use crate::linalg::csr::CsrMatrix;

/// Lanczos steps of the spectral estimate (the extreme Ritz values of a
/// 3D stiffness matrix are accurate to a few percent after ~60 steps).
pub const LANCZOS_STEPS: usize = 60;

/// Rows per chunk of the deterministic norm reductions.
const ROW_CHUNK: usize = 1024;

/// Fewest rows per rayon task of a sweep: below this, waking threads costs
/// more than the rows (small systems then run on one thread).
pub(crate) const MIN_ROWS_PER_TASK: usize = 512;

/// Parameters of [`CpuJacobi`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JacobiParams {
    /// Damping `γ` of the Jacobi update (dimensionless, in (0, 1]), or `None`
    /// for the optimal `2 / (λmin + λmax)` from the spectral estimate
    /// (module doc). Wang 2015 uses an under-relaxation of about 0.9 with a
    /// hand-tuned `ρ`. Default `None`.
    pub relaxation: Option<f64>,
    /// The estimated `λmin` of `D⁻¹A` is multiplied by this (< 1). Default
    /// 0.8: Lanczos approaches `λmin` from above and converges slowest there.
    pub lambda_min_margin: f64,
    /// The estimated `λmax` is multiplied by this (> 1). Default 1.02.
    pub lambda_max_margin: f64,
    /// Residual check every this many iterations (the check costs one more
    /// reduction; 1 checks every iteration). Default 4.
    pub check_every: u32,
    /// Divergence: the relative residual exceeding this factor times the
    /// initial one is an error. Default 1e3.
    pub divergence_factor: f64,
}

impl Default for JacobiParams {
    fn default() -> Self {
        JacobiParams {
            relaxation: None,
            lambda_min_margin: 0.8,
            lambda_max_margin: 1.02,
            check_every: 4,
            divergence_factor: 1e3,
        }
    }
}

/// Chebyshev-Jacobi solver of `(A + W) x = b` on the CPU.
#[derive(Debug, Clone)]
pub struct CpuJacobi {
    a: CsrMatrix,
    diag: Vec<f64>,
    params: JacobiParams,
    /// Estimated extreme eigenvalues of `D⁻¹A` (with the margins).
    lambda: (f64, f64),
    gamma: f64,
    rho: f64,
    /// Scratch buffers (n x 3).
    prev: Vec<f64>,
    next: Vec<f64>,
}

/// `Σ v²` over chunks of rows, summed in chunk order (deterministic).
fn sum_sq(v: &[f64]) -> f64 {
    let parts: Vec<f64> = v
        .par_chunks(ROW_CHUNK * 3)
        .map(|c| c.iter().map(|x| x * x).sum::<f64>())
        .collect();
    parts.iter().sum()
}

/// `r = b - (A + W) x` (n x 3), returning `|r|²`.
fn residual(a: &CsrMatrix, w: Option<&[f64]>, b: &[f64], x: &[f64], r: &mut [f64]) -> f64 {
    r.par_chunks_mut(3)
        .enumerate()
        .with_min_len(MIN_ROWS_PER_TASK)
        .for_each(|(i, ri)| {
            let mut s = [b[3 * i], b[3 * i + 1], b[3 * i + 2]];
            for e in a.row_ptr[i]..a.row_ptr[i + 1] {
                let (c, v) = (a.col[e], a.val[e]);
                for k in 0..3 {
                    s[k] -= v * x[3 * c + k];
                }
            }
            if let Some(w) = w {
                for k in 0..3 {
                    s[k] -= w[i] * x[3 * i + k];
                }
            }
            ri.copy_from_slice(&s);
        });
    sum_sq(r)
}

impl CpuJacobi {
    /// Prepares the solver for `a` (square, symmetric with both triangles
    /// stored, positive diagonal) and estimates its spectrum (module doc).
    pub fn new(a: CsrMatrix, params: JacobiParams) -> Result<CpuJacobi, SimError> {
        if a.row_ptr.len() != a.n + 1 || a.col.len() != a.val.len() {
            return Err(SimError::Inconsistent("malformed CSR matrix".into()));
        }
        if let Some(&c) = a.col.iter().find(|&&c| c >= a.n) {
            return Err(SimError::Inconsistent(format!(
                "CSR column {c} outside a {} x {} matrix",
                a.n, a.n
            )));
        }
        let diag = a.diagonal();
        if let Some(i) = diag.iter().position(|d| !(*d > 0.0 && d.is_finite())) {
            return Err(SimError::Inconsistent(format!(
                "Jacobi needs a positive diagonal; row {i} has {}",
                diag[i]
            )));
        }
        let margins_ok = params.lambda_min_margin > 0.0
            && params.lambda_min_margin <= 1.0
            && params.lambda_max_margin >= 1.0
            && params.lambda_max_margin.is_finite();
        if !margins_ok
            || params.check_every == 0
            || !(params.divergence_factor > 1.0)
            || params.relaxation.is_some_and(|g| !(g > 0.0 && g <= 1.0))
        {
            return Err(SimError::Inconsistent(format!(
                "bad Jacobi parameters {params:?}"
            )));
        }
        let (lmin, lmax) = lanczos_extremes(&a, &diag, LANCZOS_STEPS);
        let lmin = (lmin * params.lambda_min_margin).max(1e-12);
        let lmax = lmax * params.lambda_max_margin;
        let gamma = params.relaxation.unwrap_or(2.0 / (lmin + lmax));
        let rho = (1.0 - gamma * lmin).abs().max((gamma * lmax - 1.0).abs());
        if !(rho < 1.0) {
            return Err(SimError::Inconsistent(format!(
                "damped Jacobi does not converge on this matrix (spectral radius \
                 estimate {rho:.4}, λ(D⁻¹A) in [{lmin:.3e}, {lmax:.3e}], damping {gamma})"
            )));
        }
        let n = a.n;
        Ok(CpuJacobi {
            a,
            diag,
            params,
            lambda: (lmin, lmax),
            gamma,
            rho,
            prev: vec![0.0; 3 * n],
            next: vec![0.0; 3 * n],
        })
    }

    /// The spectral radius `ρ` used by the Chebyshev weights.
    pub fn rho(&self) -> f64 {
        self.rho
    }
    /// The damping `γ` of the Jacobi update.
    pub fn relaxation(&self) -> f64 {
        self.gamma
    }
    /// The estimated (and widened) `[λmin, λmax]` of `D⁻¹A`.
    pub fn spectrum(&self) -> (f64, f64) {
        self.lambda
    }
    /// The matrix `A`.
    pub fn matrix(&self) -> &CsrMatrix {
        &self.a
    }
}

/// Extreme eigenvalues of `D^-½ A D^-½` by `steps` Lanczos steps (full
/// reorthogonalization: `steps` is small) from a fixed start vector.
fn lanczos_extremes(a: &CsrMatrix, diag: &[f64], steps: usize) -> (f64, f64) {
    let n = a.n;
    if n == 0 {
        return (1.0, 1.0);
    }
    let steps = steps.min(n);
    let dis: Vec<f64> = diag.iter().map(|d| 1.0 / d.sqrt()).collect();
    // Deterministic, non-smooth start vector (a smooth one would miss the
    // high end of the spectrum).
    let mut q: Vec<f64> = (0..n)
        .map(|i| 1.0 + 0.5 * (((i as u64).wrapping_mul(2654435761) % 1000) as f64 / 1000.0))
        .collect();
    let nq = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.iter_mut().for_each(|v| *v /= nq);
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(steps);
    let mut alpha = Vec::with_capacity(steps);
    let mut beta: Vec<f64> = Vec::with_capacity(steps);
    let mut tmp = vec![0.0; n];
    let mut w = vec![0.0; n];
    for _ in 0..steps {
        // w = D^-½ A D^-½ q
        for i in 0..n {
            tmp[i] = dis[i] * q[i];
        }
        a.mul_rows(&tmp, 1, &mut w);
        for i in 0..n {
            w[i] *= dis[i];
        }
        let al: f64 = w.iter().zip(&q).map(|(x, y)| x * y).sum();
        alpha.push(al);
        basis.push(q.clone());
        for b in &basis {
            let c: f64 = w.iter().zip(b).map(|(x, y)| x * y).sum();
            w.iter_mut().zip(b).for_each(|(x, y)| *x -= c * y);
        }
        let be = w.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(be > 1e-12 * al.abs().max(1e-300)) || basis.len() == steps {
            break;
        }
        beta.push(be);
        q.iter_mut().zip(&w).for_each(|(x, y)| *x = y / be);
    }
    let m = alpha.len();
    let t = nalgebra::DMatrix::from_fn(m, m, |i, j| {
        if i == j {
            alpha[i]
        } else if i + 1 == j {
            beta[i]
        } else if j + 1 == i {
            beta[j]
        } else {
            0.0
        }
    });
    let ev = t.symmetric_eigenvalues();
    let lmin = ev.iter().cloned().fold(f64::INFINITY, f64::min);
    let lmax = ev.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    (lmin, lmax)
}

impl JacobiSolve for CpuJacobi {
    fn solve(
        &mut self,
        b: &[f64],
        extra_diag: Option<&[f64]>,
        x: &mut [f64],
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<IterStats, SimError> {
        let n = self.a.n;
        check_jacobi_inputs("Jacobi solve", n, b, extra_diag, x)?;
        let bnorm = sum_sq(b).sqrt();
        if bnorm == 0.0 {
            x.iter_mut().for_each(|v| *v = 0.0);
            return Ok(IterStats::default());
        }
        let (a, diag, gamma, rho) = (&self.a, &self.diag, self.gamma, self.rho);
        let w = extra_diag;
        let r0 = {
            let mut r = std::mem::take(&mut self.next);
            let rr = residual(a, w, b, x, &mut r).sqrt() / bnorm;
            self.next = r;
            rr
        };
        if !r0.is_finite() {
            return Err(diverged(x, 0, "initial residual not finite"));
        }
        if r0 <= tolerance {
            return Ok(IterStats {
                iterations: 0,
                relative_residual: r0,
            });
        }
        // Three rotating buffers (x_{k-1}, x_k, scratch / x_{k+1}); `x` is
        // written once at the end.
        let mut cur = x.to_vec();
        let mut prev = std::mem::take(&mut self.prev);
        let mut next = std::mem::take(&mut self.next);
        prev.copy_from_slice(x);
        let mut omega = 1.0;
        let mut rel = r0;
        let mut it = 0u32;
        let mut failure = None;
        while it < max_iterations {
            it += 1;
            omega = match it {
                1 => 1.0,
                2 => 2.0 / (2.0 - rho * rho),
                _ => 4.0 / (4.0 - rho * rho * omega),
            };
            let (xk, xp) = (&cur, &prev);
            next.par_chunks_mut(3)
                .enumerate()
                .with_min_len(MIN_ROWS_PER_TASK)
                .for_each(|(i, out)| {
                    let mut s = [b[3 * i], b[3 * i + 1], b[3 * i + 2]];
                    for e in a.row_ptr[i]..a.row_ptr[i + 1] {
                        let (c, v) = (a.col[e], a.val[e]);
                        for k in 0..3 {
                            s[k] -= v * xk[3 * c + k];
                        }
                    }
                    let wi = w.map_or(0.0, |w| w[i]);
                    let d = diag[i] + wi;
                    for k in 0..3 {
                        let xi = xk[3 * i + k];
                        let y = xi + gamma * (s[k] - wi * xi) / d;
                        out[k] = omega * (y - xp[3 * i + k]) + xp[3 * i + k];
                    }
                });
            // Rotate: prev <- x_k, cur <- x_{k+1}, next <- scratch.
            std::mem::swap(&mut prev, &mut cur);
            std::mem::swap(&mut cur, &mut next);
            if it % self.params.check_every == 0 || it == max_iterations {
                rel = residual(a, w, b, &cur, &mut next).sqrt() / bnorm;
                if !rel.is_finite() {
                    failure = Some("residual not finite".to_string());
                    break;
                }
                if rel > self.params.divergence_factor * r0 {
                    failure = Some(format!("relative residual grew from {r0:.3e} to {rel:.3e}"));
                    break;
                }
                if rel <= tolerance {
                    break;
                }
            }
        }
        x.copy_from_slice(&cur);
        self.prev = prev;
        self.next = next;
        if let Some(why) = failure {
            return Err(diverged(x, it, &why));
        }
        Ok(IterStats {
            iterations: it,
            relative_residual: rel,
        })
    }

    fn name(&self) -> &'static str {
        "cpu"
    }
}

/// A divergence error naming the row with the largest (or a non-finite) entry.
fn diverged(x: &[f64], it: u32, why: &str) -> SimError {
    let mut node = 0;
    let mut best = f64::NEG_INFINITY;
    for (i, c) in x.chunks(3).enumerate() {
        let m = c.iter().map(|v| v.abs()).fold(0.0, f64::max);
        if c.iter().any(|v| !v.is_finite()) {
            node = i;
            break;
        }
        if m > best {
            best = m;
            node = i;
        }
    }
    SimError::Diverged {
        step: 0,
        node,
        reason: format!("Chebyshev-Jacobi iteration {it}: {why}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 1D Laplacian plus a mass shift, on `n` rows.
    fn laplace(n: usize, shift: f64) -> CsrMatrix {
        CsrMatrix::from_triplets(n, &crate::linalg::csr::tridiagonal_triplets(n, 2.0 + shift))
            .unwrap()
    }

    #[test]
    fn converges_and_estimates_spectrum() {
        let n = 50;
        let a = laplace(n, 0.05);
        let mut j = CpuJacobi::new(a.clone(), JacobiParams::default()).unwrap();
        // Exact extremes of D⁻¹A: (2 + s - 2 cos(kπ/(n+1))) / (2 + s).
        let d = 2.05;
        let lmin = (d - 2.0 * (std::f64::consts::PI / 51.0).cos()) / d;
        let lmax = (d + 2.0 * (std::f64::consts::PI / 51.0).cos()) / d;
        let (emin, emax) = j.spectrum();
        assert!(emin <= lmin && emin > 0.5 * lmin, "{emin} vs {lmin}");
        assert!(emax >= lmax && emax < 1.1 * lmax, "{emax} vs {lmax}");
        let b: Vec<f64> = (0..3 * n).map(|i| ((i * 7) % 11) as f64 - 5.0).collect();
        let mut x = vec![0.0; 3 * n];
        let st = j.solve(&b, None, &mut x, 1e-10, 10_000).unwrap();
        assert!(st.relative_residual <= 1e-10, "{st:?}");
        let mut ax = vec![0.0; 3 * n];
        a.mul_rows(&x, 3, &mut ax);
        let err: f64 = ax
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).powi(2))
            .sum::<f64>()
            .sqrt();
        let bn: f64 = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(err / bn <= 1e-10 * 1.0001);
        // Chebyshev beats plain damped Jacobi by far: ~sqrt(κ) vs κ.
        assert!(st.iterations < 400, "{st:?}");
        // With an extra diagonal.
        let w: Vec<f64> = (0..n)
            .map(|i| if i % 5 == 0 { 100.0 } else { 0.0 })
            .collect();
        let mut x2 = vec![0.0; 3 * n];
        let st2 = j.solve(&b, Some(&w), &mut x2, 1e-10, 10_000).unwrap();
        assert!(st2.relative_residual <= 1e-10);
        let mut ax2 = vec![0.0; 3 * n];
        a.mul_rows(&x2, 3, &mut ax2);
        for i in 0..n {
            for k in 0..3 {
                let r = b[3 * i + k] - ax2[3 * i + k] - w[i] * x2[3 * i + k];
                assert!(r.abs() < 1e-8 * bn, "{r}");
            }
        }
    }

    #[test]
    fn too_large_damping_diverges_with_an_error() {
        let n = 40;
        let a = laplace(n, 0.01);
        let mut j = CpuJacobi::new(a, JacobiParams::default()).unwrap();
        // Sabotage the damping: γ λmax > 2 makes the Jacobi update diverge.
        j.gamma = 2.5 / j.lambda.1;
        let b = vec![1.0; 3 * n];
        let mut x = vec![0.0; 3 * n];
        let r = j.solve(&b, None, &mut x, 1e-12, 100_000);
        assert!(matches!(r, Err(SimError::Diverged { .. })), "{r:?}");
        assert!(CpuJacobi::new(laplace(3, -3.0), JacobiParams::default()).is_err());
    }
}
