//! Regularizers of the full stage's log-field `θ = ln γ` (not in VH §6,
//! which fits the loss alone; MAP terms for the directions that few poses
//! leave unobserved):
//!
//! * a Gaussian prior around the stage's start θ0
//!   ([`ElasticFitParams::prior_weight`]): `wp Σ_j (θ_j - θ0_j)²`;
//! * a smoothness term over face-adjacent tets
//!   ([`ElasticFitParams::smooth_weight`]): `ws Σ_(a,b) (θ_a - θ_b)²`, the
//!   γs and γv fields each over the tet-mesh graph of
//!   [`super::harmonic::tet_laplacian`].
//!
//! Both are quadratic in θ, so their θ-Hessians are exact (`2 wp I` and
//! `2 ws L`); in γ, where the Gauss-Newton system is solved, that curvature
//! is `D⁻¹ (·) D⁻¹` with `D = diag(γ)` (the Gauss-Newton form: the term of
//! the θ-gradient times `∂²θ/∂γ²` is left out, as for the loss).

use super::harmonic::tet_laplacian;
use super::types::ElasticFitParams;
use super::types::Evaluated;
use crate::geom::TetMesh;

/// The active regularizers of one stage (both weights zero: inactive).
pub(super) struct Regularizer {
    /// `wp = ρ L0 / m` (m³ per unit `θ²`).
    prior_w: f64,
    theta0: Vec<f64>,
    /// `ws = σ L0 / |E|` (m³ per unit `θ²`).
    smooth_w: f64,
    /// Adjacent parameter pairs `(a, b)`, `a < b`, within each half.
    edges: Vec<(usize, usize)>,
}

impl Regularizer {
    /// The regularizers of `params` around the stage start `start` (loss
    /// `L0`), or none when `active` is false (harmonic stages, linear mode).
    pub(super) fn new(
        params: &ElasticFitParams,
        active: bool,
        mesh: &TetMesh,
        start: &Evaluated,
    ) -> Regularizer {
        let mut r = Regularizer {
            prior_w: 0.0,
            theta0: Vec::new(),
            smooth_w: 0.0,
            edges: Vec::new(),
        };
        if !active {
            return r;
        }
        let m = start.gamma.len().max(1) as f64;
        if params.prior_weight > 0.0 {
            r.prior_w = params.prior_weight * start.loss / m;
            r.theta0 = start.gamma.iter().map(|g| g.ln()).collect();
        }
        if params.smooth_weight > 0.0 {
            r.edges = parameter_edges(mesh, start.gamma.len() / mesh.num_tets().max(1));
            if !r.edges.is_empty() {
                r.smooth_w = params.smooth_weight * start.loss / r.edges.len() as f64;
            }
        }
        r
    }

    /// The regularizers' value at `gamma` (m³).
    pub(super) fn value(&self, gamma: &[f64]) -> f64 {
        let mut v = 0.0;
        if self.prior_w > 0.0 {
            v += self.prior_w
                * gamma
                    .iter()
                    .zip(&self.theta0)
                    .map(|(g, t0)| (g.ln() - t0).powi(2))
                    .sum::<f64>();
        }
        if self.smooth_w > 0.0 {
            v += self.smooth_w
                * self
                    .edges
                    .iter()
                    .map(|&(a, b)| (gamma[a].ln() - gamma[b].ln()).powi(2))
                    .sum::<f64>();
        }
        v
    }

    /// The loss plus the regularizers: what the stage's line search lowers.
    pub(super) fn objective(&self, ev: &Evaluated) -> f64 {
        ev.loss + self.value(&ev.gamma)
    }

    /// Adds the regularizers' gradient with respect to γ (`∂θ/∂γ = 1/γ`).
    pub(super) fn add_gradient(&self, gamma: &[f64], grad: &mut [f64]) {
        if self.prior_w > 0.0 {
            for ((d, g), t0) in grad.iter_mut().zip(gamma).zip(&self.theta0) {
                *d += 2.0 * self.prior_w * (g.ln() - t0) / g;
            }
        }
        if self.smooth_w > 0.0 {
            for &(a, b) in &self.edges {
                let diff = 2.0 * self.smooth_w * (gamma[a].ln() - gamma[b].ln());
                grad[a] += diff / gamma[a];
                grad[b] -= diff / gamma[b];
            }
        }
    }

    /// Adds the regularizers' Gauss-Newton curvature in γ: its diagonal to
    /// `diag`, its off-diagonal entries (both `(a, b)` and `(b, a)`) to
    /// `coupling`.
    pub(super) fn add_hessian(
        &self,
        gamma: &[f64],
        diag: &mut [f64],
        coupling: &mut Vec<(usize, usize, f64)>,
    ) {
        if self.prior_w > 0.0 {
            for (d, g) in diag.iter_mut().zip(gamma) {
                *d += 2.0 * self.prior_w / (g * g);
            }
        }
        if self.smooth_w > 0.0 {
            let w2 = 2.0 * self.smooth_w;
            for &(a, b) in &self.edges {
                diag[a] += w2 / (gamma[a] * gamma[a]);
                diag[b] += w2 / (gamma[b] * gamma[b]);
                let off = -w2 / (gamma[a] * gamma[b]);
                coupling.push((a, b, off));
                coupling.push((b, a, off));
            }
        }
    }
}

/// Face-adjacent tet pairs as parameter pairs of the stacked `[γs; γv;
/// ...]` (every one of the `nf` fields).
fn parameter_edges(mesh: &TetMesh, nf: usize) -> Vec<(usize, usize)> {
    let ne = mesh.num_tets();
    let pairs: Vec<(usize, usize)> = tet_laplacian(mesh)
        .into_iter()
        .filter(|&(a, b, _)| a < b)
        .map(|(a, b, _)| (a, b))
        .collect();
    (0..nf)
        .flat_map(|f| pairs.iter().map(move |&(a, b)| (a + f * ne, b + f * ne)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reg(gamma_len: usize, edges: Vec<(usize, usize)>, wp: f64, ws: f64) -> Regularizer {
        Regularizer {
            prior_w: wp,
            theta0: (0..gamma_len)
                .map(|j| (1.0 + 0.3 * j as f64).ln())
                .collect(),
            smooth_w: ws,
            edges,
        }
    }

    /// Gradient and Gauss-Newton curvature against central differences in
    /// θ, at several scales of γ (the curvature is exact in θ, so
    /// `D H_γ D` must equal the θ-Hessian).
    #[test]
    fn gradient_and_curvature_match_central_differences() {
        let edges = vec![(0, 1), (1, 2), (0, 3), (2, 3), (4, 5)];
        let r = reg(6, edges, 0.7, 1.3);
        for scale in [1e-2, 1.0, 1e4] {
            let gamma: Vec<f64> = (0..6)
                .map(|j| scale * (0.5 + ((j * 7 + 3) % 5) as f64))
                .collect();
            let mut grad = vec![0.0; 6];
            r.add_gradient(&gamma, &mut grad);
            let mut diag = vec![0.0; 6];
            let mut coupling = Vec::new();
            r.add_hessian(&gamma, &mut diag, &mut coupling);
            let mut h = [[0.0; 6]; 6];
            for j in 0..6 {
                h[j][j] = diag[j] * gamma[j] * gamma[j];
            }
            for &(a, b, v) in &coupling {
                h[a][b] += v * gamma[a] * gamma[b];
            }
            let at = |theta: &[f64]| r.value(&theta.iter().map(|t| t.exp()).collect::<Vec<_>>());
            let theta: Vec<f64> = gamma.iter().map(|g| g.ln()).collect();
            let eps = 1e-4;
            for j in 0..6 {
                let mut tp = theta.clone();
                let mut tm = theta.clone();
                tp[j] += eps;
                tm[j] -= eps;
                let fd = (at(&tp) - at(&tm)) / (2.0 * eps);
                // dR/dθ = γ dR/dγ.
                let an = grad[j] * gamma[j];
                assert!(
                    (fd - an).abs() <= 1e-7 * (1.0 + an.abs()),
                    "grad {j}: {fd} vs {an}"
                );
                for k in 0..6 {
                    let mut tpp = theta.clone();
                    tpp[j] += eps;
                    tpp[k] += eps;
                    let mut tpm = theta.clone();
                    tpm[j] += eps;
                    tpm[k] -= eps;
                    let mut tmp = theta.clone();
                    tmp[j] -= eps;
                    tmp[k] += eps;
                    let mut tmm = theta.clone();
                    tmm[j] -= eps;
                    tmm[k] -= eps;
                    let fd2 = (at(&tpp) - at(&tpm) - at(&tmp) + at(&tmm)) / (4.0 * eps * eps);
                    assert!(
                        (fd2 - h[j][k]).abs() <= 1e-5 * (1.0 + h[j][k].abs()),
                        "hessian {j},{k}: {fd2} vs {}",
                        h[j][k]
                    );
                }
            }
        }
    }

    /// The smoothness term is zero for a field constant on each connected
    /// part and grows with its jumps; the prior is zero at its start.
    #[test]
    fn smoothness_vanishes_on_constant_fields_only() {
        let r = reg(4, vec![(0, 1), (1, 2), (2, 3)], 0.0, 1.0);
        assert_eq!(r.value(&[3.0; 4]), 0.0);
        let one = r.value(&[3.0, 3.0, 6.0, 6.0]);
        let two = r.value(&[3.0, 3.0, 12.0, 12.0]);
        assert!(one > 0.0 && (two / one - 4.0).abs() < 1e-12, "{one} {two}");
        let p = reg(3, Vec::new(), 2.0, 0.0);
        let start: Vec<f64> = p.theta0.iter().map(|t| t.exp()).collect();
        assert!(p.value(&start).abs() < 1e-24);
        assert!(p.value(&[1.0, 1.0, 1.0]) > 0.0);
    }

    /// Every field (γs, γv, fibres) of a two-tet mesh sharing a face is
    /// coupled, and nothing else is.
    #[test]
    fn edges_couple_face_neighbours_in_both_fields() {
        let mesh = TetMesh {
            nodes: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [1.0, 1.0, 1.0],
                [5.0, 5.0, 5.0],
                [6.0, 5.0, 5.0],
                [5.0, 6.0, 5.0],
                [5.0, 5.0, 6.0],
            ],
            tets: vec![[0, 1, 2, 3], [1, 2, 3, 4], [5, 6, 7, 8]],
        };
        assert_eq!(parameter_edges(&mesh, 2), vec![(0, 1), (3, 4)]);
        // A fibre family's field is coupled the same way.
        assert_eq!(parameter_edges(&mesh, 3), vec![(0, 1), (3, 4), (6, 7)]);
    }
}
