//! Second derivatives of the VH Eq. 7 element energy (for Newton statics and
//! elasticity fitting, VH §6) and its derivatives with respect to the
//! materials `γs`, `γv`.
//!
//! # What is differentiated
//! The simulator's force is `-∂E/∂x` with
//! `∂E/∂F = P(F) = 2 V_e (γs (F - R(F)) + γv (F - V(F)))`
//! ([`super::energy::element_stress`], the envelope-theorem
//! gradient). Here we differentiate *that* `P` once more, so the Hessian is the
//! exact Jacobian of the force the solvers use — also where the 0.01 floor of
//! Eq. 26 is active (there `P` is the PD force, not the exact gradient of
//! `|F - V(F)|²`, and its Jacobian can be slightly non-symmetric; Newton uses
//! the symmetric PSD projection below, which is all it needs to descend).
//!
//! # How (isotropic form, Smith, de Goes & Kim 2019, "Analytic eigensystems
//! # for isotropic distortion energies", §4-5)
//! With the signed SVD `F = U diag(σ) Vᵀ` ([`super::projection::signed_svd`]),
//! `P = U diag(ψ(σ)) Vᵀ` with `ψ = 2 V_e (γs (σ - 1) + γv (σ - d(σ)))`, where
//! `d` solves Eq. 26 (`R = U Vᵀ`, `V(F) = U diag(d) Vᵀ`). For `δF` write
//! `M = Uᵀ δF V`; then `Uᵀ δP V` has
//! * diagonal `A diag(M)`, `A = ∂ψ/∂σ = 2 V_e (γs I + γv (I - ∂d/∂σ))`;
//! * for each pair `i < j`, with twist part `a = (M_ij - M_ji)/2` and flip part
//!   `b = (M_ij + M_ji)/2`: entries `λ_flip b ± λ_twist a` (Smith et al. Eq. 7.x,
//!   the twist/flip eigenmatrices), `λ_twist = (ψ_i + ψ_j)/(σ_i + σ_j)`,
//!   `λ_flip = (ψ_i - ψ_j)/(σ_i - σ_j)`.
//!
//! For the rotation term these are the classic ARAP values (`λ_flip = 2`,
//! `λ_twist = 2 - 4/(σ_i + σ_j)`). For the volume term `∂d/∂σ` comes from
//! implicit differentiation of the KKT system of Eq. 26 (`d_i - s_i = λ/d_i`
//! for free `i`, `Σ ln d_i = 0`; values held at the floor and clamped inputs
//! have zero derivative), and `(d_i - d_j)/(s_i - s_j) = 1/(1 + λ/(d_i d_j))`
//! exactly when both are free, so `λ_flip` needs no division by a small
//! `σ_i - σ_j`.
//!
//! # PSD projection
//! [`element_hessian`] with `project = true` clamps `λ_flip`, `λ_twist` and the
//! eigenvalues of the symmetrized `A` at zero (Smith et al. §5): the projected
//! 9x9 `∂P/∂F` is PSD, so is `Gᵀ (∂P/∂F) G` (G = ∂F/∂x), and the assembled
//! Newton matrix (plus mass or pin terms) is SPD.

use nalgebra::{Matrix3, Vector3};

use super::element::{node_gradients, Mat12, TetRest, Vec12};
use super::projection::{project_diag_sl3, signed_svd, SINGULAR_VALUE_FLOOR};

/// `∂d/∂s` of Eq. 26 at the clamped input `sc` with solution `d`, multiplier
/// from the KKT system (see the module doc). Rows/columns of values held at the
/// floor, and columns of inputs below the floor, are zero.
fn projection_jacobian(s: [f64; 3], d: [f64; 3]) -> Matrix3<f64> {
    let sc = s.map(|x| x.max(SINGULAR_VALUE_FLOOR));
    let free: [bool; 3] = std::array::from_fn(|i| d[i] > SINGULAR_VALUE_FLOOR * (1.0 + 1e-9));
    // λ = d_i (d_i - s_i) for a free i (the largest d: best conditioned).
    let lambda = (0..3)
        .filter(|&i| free[i])
        .max_by(|&i, &j| d[i].total_cmp(&d[j]))
        .map(|i| d[i] * (d[i] - sc[i]))
        .unwrap_or(0.0);
    let a: [f64; 3] = std::array::from_fn(|i| 1.0 + lambda / (d[i] * d[i]));
    let mut denom = 0.0;
    for i in 0..3 {
        if free[i] {
            denom += 1.0 / (a[i] * d[i] * d[i]);
        }
    }
    let mut j = Matrix3::zeros();
    if denom == 0.0 || !denom.is_finite() {
        return j;
    }
    for r in 0..3 {
        if !free[r] {
            continue;
        }
        for c in 0..3 {
            if !free[c] || !(s[c] > SINGULAR_VALUE_FLOOR) {
                continue;
            }
            let mut v = -(1.0 / (a[r] * d[r])) * (1.0 / (a[c] * d[c])) / denom;
            if r == c {
                v += 1.0 / a[r];
            }
            j[(r, c)] = if v.is_finite() { v } else { 0.0 };
        }
    }
    j
}

/// `∂P/∂F` of one tet as a function applying it to `δF`, in the SVD frame.
struct StressDerivative {
    u: Matrix3<f64>,
    v: Matrix3<f64>,
    a: Matrix3<f64>,
    /// `(λ_flip, λ_twist)` for the pairs (0,1), (0,2), (1,2).
    pairs: [(f64, f64); 3],
}

const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

impl StressDerivative {
    fn new(f: &Matrix3<f64>, volume: f64, gamma_s: f64, gamma_v: f64, project: bool) -> Self {
        let svd = match signed_svd(f) {
            Some(s) => s,
            None => {
                return StressDerivative {
                    u: Matrix3::identity(),
                    v: Matrix3::identity(),
                    a: Matrix3::zeros(),
                    pairs: [(0.0, 0.0); 3],
                }
            }
        };
        let s = [svd.s[0], svd.s[1], svd.s[2]];
        let p = project_diag_sl3(s);
        let d = p.d;
        let w = 2.0 * volume;
        let dd = projection_jacobian(s, d);
        let mut a = w * (gamma_s + gamma_v) * Matrix3::identity() - w * gamma_v * dd;
        // ψ_i (see module doc).
        let psi: [f64; 3] =
            std::array::from_fn(|i| w * (gamma_s * (s[i] - 1.0) + gamma_v * (s[i] - d[i])));
        let sc = s.map(|x| x.max(SINGULAR_VALUE_FLOOR));
        let free: [bool; 3] = std::array::from_fn(|i| {
            d[i] > SINGULAR_VALUE_FLOOR * (1.0 + 1e-9) && s[i] > SINGULAR_VALUE_FLOOR
        });
        let lambda = (0..3)
            .filter(|&i| free[i])
            .max_by(|&i, &j| d[i].total_cmp(&d[j]))
            .map(|i| d[i] * (d[i] - sc[i]));
        let pairs = PAIRS.map(|(i, j)| {
            // Flip: ψ_i - ψ_j over σ_i - σ_j, the volume part without cancellation.
            let q_flip = if free[i] && free[j] && lambda.is_some() {
                1.0 / (1.0 + lambda.unwrap_or(0.0) / (d[i] * d[j]))
            } else if (s[i] - s[j]).abs() > 1e-10 * (s[i].abs() + s[j].abs() + 1e-300) {
                (d[i] - d[j]) / (s[i] - s[j])
            } else {
                dd[(i, i)] - dd[(i, j)]
            };
            let flip = w * (gamma_s + gamma_v * (1.0 - q_flip));
            let sum = s[i] + s[j];
            // The twist eigenvalue is singular where σ_i + σ_j = 0 (the
            // rotation jumps): cap the division.
            let sum = if sum.abs() < 1e-12 {
                1e-12f64.copysign(if sum == 0.0 { 1.0 } else { sum })
            } else {
                sum
            };
            let twist = (psi[i] + psi[j]) / sum;
            (flip, twist)
        });
        let mut pairs = pairs;
        if project {
            let sym = 0.5 * (a + a.transpose());
            let eig = sym.symmetric_eigen();
            let clamped = eig.eigenvalues.map(|l| l.max(0.0));
            a = eig.eigenvectors * Matrix3::from_diagonal(&clamped) * eig.eigenvectors.transpose();
            for p in &mut pairs {
                p.0 = p.0.max(0.0);
                p.1 = p.1.max(0.0);
            }
        }
        StressDerivative {
            u: svd.u,
            v: svd.v,
            a,
            pairs,
        }
    }

    fn apply(&self, df: &Matrix3<f64>) -> Matrix3<f64> {
        let m = self.u.transpose() * df * self.v;
        let diag = self.a * Vector3::new(m[(0, 0)], m[(1, 1)], m[(2, 2)]);
        let mut out = Matrix3::from_diagonal(&diag);
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            let (flip, twist) = self.pairs[k];
            let a = 0.5 * (m[(i, j)] - m[(j, i)]);
            let b = 0.5 * (m[(i, j)] + m[(j, i)]);
            out[(i, j)] = flip * b + twist * a;
            out[(j, i)] = flip * b - twist * a;
        }
        self.u * out * self.v.transpose()
    }
}

/// `∂P/∂F[δF]` (J, Pa · m³ per unit δF) of one tet: the derivative of
/// [`super::energy::element_stress`] in the direction `df`; `project` gives the
/// PSD projection instead (module doc).
pub fn stress_differential(
    f: &Matrix3<f64>,
    df: &Matrix3<f64>,
    volume: f64,
    gamma_s: f64,
    gamma_v: f64,
    project: bool,
) -> Matrix3<f64> {
    StressDerivative::new(f, volume, gamma_s, gamma_v, project).apply(df)
}

/// The 12x12 Jacobian (N/m) of the node gradients of one tet
/// ([`super::element::node_gradients`] of [`super::energy::element_stress`])
/// with respect to its node positions, at deformation gradient `f`; with
/// `project` its PSD projection (symmetric positive semidefinite).
pub fn element_hessian(
    f: &Matrix3<f64>,
    rest: &TetRest,
    gamma_s: f64,
    gamma_v: f64,
    project: bool,
) -> Mat12 {
    let sd = StressDerivative::new(f, rest.volume, gamma_s, gamma_v, project);
    let mut h = Mat12::zeros();
    for a in 0..4 {
        for c in 0..3 {
            // δDs for a unit move of node a along c; δF = δDs Dm⁻¹.
            let mut dds = Matrix3::zeros();
            if a == 0 {
                for col in 0..3 {
                    dds[(c, col)] = -1.0;
                }
            } else {
                dds[(c, a - 1)] = 1.0;
            }
            let dp = sd.apply(&(dds * rest.dm_inv));
            let g = node_gradients(&dp, &rest.dm_inv);
            for b in 0..4 {
                for k in 0..3 {
                    h[(3 * b + k, 3 * a + c)] = g[b][k];
                }
            }
        }
    }
    if project {
        // Symmetric by construction up to rounding; make it exact.
        h = 0.5 * (h + h.transpose());
    }
    h
}

impl super::energy::ElasticModel {
    /// [`element_hessian`] of tet `e` at deformation gradient `f` plus its
    /// fibres' Hessians ([`super::fibre::fibre_element_hessian`], PSD
    /// without projection).
    pub fn tet_hessian(&self, e: usize, f: &Matrix3<f64>, project: bool) -> Mat12 {
        let rest = &self.rest()[e];
        let mut h = element_hessian(f, rest, self.gamma_s()[e], self.gamma_v()[e], project);
        for fam in self.fibres() {
            h += fam.element_hessian(e, f, rest);
        }
        h
    }
}

/// Derivatives (N/Pa) of one tet's node gradients with respect to its `γs`
/// and `γv`: the energy is linear in both, so these are the node gradients of
/// `2 V_e (F - R(F))` and `2 V_e (F - V(F))`.
pub fn element_gamma_derivatives(f: &Matrix3<f64>, rest: &TetRest) -> (Vec12, Vec12) {
    let r = super::projection::project_rotation(f);
    let v = super::projection::project_volume(f);
    let to12 = |m: Matrix3<f64>| {
        let g = node_gradients(&m, &rest.dm_inv);
        Vec12::from_fn(|i, _| g[i / 3][i % 3])
    };
    (
        to12(2.0 * rest.volume * (f - r)),
        to12(2.0 * rest.volume * (f - v)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::energy::element_stress;

    use crate::sim::test_util::{random_rest as rest_of, Rng};

    /// Central FD of the node gradients along every node coordinate vs the
    /// exact Jacobian; returns the relative error.
    fn fd_error(f: &Matrix3<f64>, rest: &TetRest, gs: f64, gv: f64) -> f64 {
        let h_exact = element_hessian(f, rest, gs, gv, false);
        let dm = rest.dm_inv.try_inverse().unwrap();
        let ds = f * dm;
        // Step relative to the tet size (in F units: ~1e-6).
        let eps = 1e-6 * dm.norm();
        let grad = |ds: &Matrix3<f64>| {
            let ff = ds * rest.dm_inv;
            let g = node_gradients(&element_stress(&ff, rest.volume, gs, gv), &rest.dm_inv);
            Vec12::from_fn(|i, _| g[i / 3][i % 3])
        };
        let mut h_fd = Mat12::zeros();
        for a in 0..4 {
            for c in 0..3 {
                let mut d = Matrix3::zeros();
                if a == 0 {
                    for col in 0..3 {
                        d[(c, col)] = -eps;
                    }
                } else {
                    d[(c, a - 1)] = eps;
                }
                let col = (grad(&(ds + d)) - grad(&(ds - d))) / (2.0 * eps);
                h_fd.set_column(3 * a + c, &col);
            }
        }
        (h_exact - h_fd).norm() / h_exact.norm().max(1e-300)
    }

    #[test]
    fn hessian_matches_finite_differences_at_several_scales() {
        let mut rng = Rng(7);
        for &scale in &[1e-3, 1.0, 50.0] {
            for _ in 0..20 {
                let rest = rest_of(scale, &mut rng);
                // Moderate deformations of both signs of stretch.
                let f = rng.rotation() * (Matrix3::identity() + 0.4 * rng.mat());
                if f.determinant() < 0.05 {
                    continue;
                }
                let err = fd_error(&f, &rest, 1e4, 3e4);
                assert!(
                    err < 1e-5,
                    "scale {scale}: relative FD error {err} at F = {f}"
                );
            }
        }
    }

    #[test]
    fn hessian_matches_finite_differences_near_the_floor_and_inverted() {
        let mut rng = Rng(11);
        let mut checked = (0, 0);
        for k in 0..200 {
            let rest = rest_of(0.01, &mut rng);
            let (u, v) = (rng.rotation(), rng.rotation());
            let s = if k % 2 == 0 {
                // Smallest value just above the floor.
                Vector3::new(
                    1.0 + rng.next(),
                    0.5 + 0.3 * rng.next(),
                    0.0105 + 0.005 * rng.next(),
                )
            } else {
                // Inverted: negative third value, well away from the kinks.
                Vector3::new(
                    1.2 + rng.next(),
                    0.6 + 0.3 * rng.next(),
                    -0.2 - 0.3 * rng.next(),
                )
            };
            let f = u * Matrix3::from_diagonal(&s) * v.transpose();
            let err = fd_error(&f, &rest, 2e4, 1e4);
            assert!(err < 1e-4, "s = {s:?}: relative FD error {err}");
            if k % 2 == 0 {
                checked.0 += 1
            } else {
                checked.1 += 1
            }
        }
        assert_eq!(checked, (100, 100));
    }

    #[test]
    fn projected_hessian_is_psd_and_equals_exact_where_convex() {
        let mut rng = Rng(3);
        for k in 0..50 {
            let rest = rest_of(0.02, &mut rng);
            let f = rng.rotation() * (Matrix3::identity() + 0.8 * rng.mat());
            let h = element_hessian(&f, &rest, 1e4, 1e4, true);
            let eig = h.symmetric_eigen();
            let min = eig.eigenvalues.min();
            let max = eig.eigenvalues.max();
            assert!(
                min >= -1e-9 * max,
                "case {k}: min eigenvalue {min} (max {max})"
            );
        }
        // Stretch (all σ > 1): every eigenvalue of the exact form is >= 0, so
        // projection changes nothing.
        let rest = rest_of(0.02, &mut rng);
        let f = rng.rotation() * Matrix3::from_diagonal(&Vector3::new(1.3, 1.2, 1.1));
        let (a, b) = (
            element_hessian(&f, &rest, 1e4, 1e4, false),
            element_hessian(&f, &rest, 1e4, 1e4, true),
        );
        assert!(
            (a - b).norm() < 1e-9 * a.norm(),
            "{}",
            (a - b).norm() / a.norm()
        );
    }

    #[test]
    fn gamma_derivatives_match_finite_differences() {
        let mut rng = Rng(5);
        for _ in 0..20 {
            let rest = rest_of(0.01, &mut rng);
            let f = rng.rotation() * (Matrix3::identity() + 0.5 * rng.mat());
            let (gs, gv) = (1.5e4, 2.5e4);
            let grad = |gs: f64, gv: f64| {
                let g = node_gradients(&element_stress(&f, rest.volume, gs, gv), &rest.dm_inv);
                Vec12::from_fn(|i, _| g[i / 3][i % 3])
            };
            let (ds, dv) = element_gamma_derivatives(&f, &rest);
            let h = 10.0;
            let fd_s = (grad(gs + h, gv) - grad(gs - h, gv)) / (2.0 * h);
            let fd_v = (grad(gs, gv + h) - grad(gs, gv - h)) / (2.0 * h);
            assert!((ds - fd_s).norm() <= 1e-7 * ds.norm().max(1e-300));
            assert!((dv - fd_v).norm() <= 1e-7 * dv.norm().max(1e-300));
            // The gradient is linear in γ: γs ∂/∂γs + γv ∂/∂γv is the gradient.
            assert!((ds * gs + dv * gv - grad(gs, gv)).norm() <= 1e-9 * grad(gs, gv).norm());
        }
    }
}
