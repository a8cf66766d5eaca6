//! Stiffening tension-only fibres: the strain hardening of knit that the
//! quadratic fibres of [`super::fibre`] lack.
//!
//! A knit stiffens as it is pulled: its loops first straighten and slide
//! (soft), then the yarn itself carries the load (stiff). A uniform material
//! fitted to a stockinette course stretch needs a secant stiffness of 102 Pa
//! at 2% strain, 169 Pa at 10% and 423 Pa at 20% (ratios 1 : 1.66 : 4.15); a
//! quadratic fibre has a constant secant stiffness and cannot follow that.
//!
//! Per tet `e` and family, with a unit rest direction `d` (dimensionless,
//! rest configuration), a small-strain stiffness `k` (Pa, `>= 0`) and a
//! stiffening `β` (dimensionless, `>= 0`):
//!
//! * strain `ε = |y| - 1`, `y = F d` (dimensionless);
//! * `ψ(ε) = k (ε² + (β/2) ε⁴)` for `ε > 0`, `0` for `ε <= 0` (Pa): yarn lines
//!   resist tension and buckle under compression (slack);
//! * `E = V ψ(ε)` (J).
//!
//! Derivatives, with `ŷ = y / |y|`:
//! * `ψ'(ε) = 2 k ε (1 + β ε²)`, `ψ''(ε) = 2 k (1 + 3 β ε²)`;
//! * `∂E/∂F = V ψ'(ε) ŷ dᵀ` (as `∂|y|/∂y = ŷ`, `∂y/∂F = (·) dᵀ`);
//! * `∂²E/∂F²[δF] = V [ψ''(ε) ŷŷᵀ + ψ'(ε)/|y| (I - ŷŷᵀ)] (δF d) dᵀ`
//!   (`∂ŷ/∂y = (I - ŷŷᵀ)/|y|`).
//!
//! Under a uniaxial stretch along `d` of a unit-volume tet the stress is
//! `ψ'(ε)`, so the secant stiffness is `ψ'(ε)/ε = 2 k (1 + β ε²)`: with
//! `β = 80` the ratios at 2%, 10% and 20% are 1 : 1.74 : 4.07, close to the
//! measured ones above. With `β = 0`, `E = k V (|F d| - 1)²` in tension: the
//! energy of [`super::fibre`] with `γ = k`, term for term.
//!
//! # Convexity
//! In tension `ψ' >= 0` and `ψ'' > 0`, and `ψ'` and `ψ''` vanish or are
//! absent when slack. So the 3x3 Hessian in `y` is a sum of two PSD terms
//! (`ψ'' ŷŷᵀ` and `ψ'/|y| (I - ŷŷᵀ)`), and the element Hessian
//! `c cᵀ ⊗ ∂²E/∂y²` (`c_a = ∇N_a · d`, `y = Σ_a c_a x_a`) is PSD everywhere:
//! Newton needs no projection. `E` as a function of `y` is convex: a convex,
//! non-decreasing function (`ψ` extended by 0 below `ε = 0`) of the convex
//! `|y| - 1`. At `ε = 0` the gradient is continuous (`ψ'(0) = 0`) but the
//! Hessian jumps from 0 to `2 k V ŷŷᵀ`, the kink of every tension-only term.
//!
//! # Projective dynamics as quasi-Newton
//! The term is no longer a squared distance to a constraint set, so it has
//! no exact PD projection. Liu, Bouaziz & Kavan 2017 ("Quasi-Newton methods
//! for real-time simulation of hyperelastic materials", §4) read a PD
//! iteration as a quasi-Newton step `x - A⁻¹ ∇E` with the constant PD matrix
//! `A` as the Hessian approximation. Giving the fibre a fixed weight `w` (J)
//! in `A` (block `w c_a c_b`) and the F-space target `w p dᵀ`,
//! `p = y - (∂E/∂y)/w`, the right-hand side `Σ w c p` equals
//! `A x - ∇E` for this term, which is exactly that step
//! ([`knit_fibre_target`]). With `β = 0` and `w = 2 k V`, `p = ŷ = π(y)`: the
//! exact local-global form of [`super::fibre`]. The weight to choose is
//! [`knit_fibre_pd_weight`].
//!
//! # Parameters of a fit
//! At a fixed deformation the energy is linear in `k` and in `k β` (the
//! equilibrium the fit matches is nonlinear in both, and the stiffening
//! matters only through `β ε²`). An adjoint Gauss-Newton fit works in
//! `ln k`, `ln β` so that both stay positive without bounds;
//! [`knit_fibre_param_derivatives`] gives the derivatives of the node
//! gradients (the force) with respect to those logs.

use nalgebra::{Matrix3, Vector3};

use super::element::{node_gradients, Mat12, TetRest, Vec12};
use super::fibre::node_coefficients;
use super::SimError;
use crate::geom::Vec3;

/// One family of stiffening tension-only fibres: per tet a unit rest
/// direction, a small-strain stiffness and a stiffening.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StiffeningFibre {
    /// Unit rest direction per tet (dimensionless, rest configuration).
    pub directions: Vec<[f64; 3]>,
    /// Small-strain stiffness `k` per tet (Pa, finite, `>= 0`; 0: no fibre
    /// in that tet).
    pub k: Vec<f64>,
    /// Stiffening `β` per tet (dimensionless, finite, `>= 0`; 0: the
    /// quadratic fibre of [`super::fibre`]).
    pub beta: Vec<f64>,
}

impl StiffeningFibre {
    /// Checks lengths against `num_tets`, unit directions (to 1e-6),
    /// stiffnesses and stiffenings; `which` names the family in errors.
    pub fn check(&self, num_tets: usize, which: usize) -> Result<(), SimError> {
        if self.directions.len() != num_tets
            || self.k.len() != num_tets
            || self.beta.len() != num_tets
        {
            return Err(SimError::Inconsistent(format!(
                "stiffening fibre family {which}: {num_tets} tets but {} directions, {} \
                 stiffnesses and {} stiffenings",
                self.directions.len(),
                self.k.len(),
                self.beta.len()
            )));
        }
        if let Some((t, d)) = self
            .directions
            .iter()
            .enumerate()
            .find(|(_, d)| !crate::geom::is_unit_vector(d))
        {
            return Err(SimError::Inconsistent(format!(
                "stiffening fibre family {which}: direction of tet {t} is {d:?}; it must be a \
                 unit vector"
            )));
        }
        let bad = |v: &f64| !(v.is_finite() && *v >= 0.0);
        if let Some((t, k)) = self.k.iter().enumerate().find(|(_, k)| bad(k)) {
            return Err(SimError::Inconsistent(format!(
                "stiffening fibre family {which}: stiffness k of tet {t} is {k}; it must be \
                 finite and >= 0"
            )));
        }
        if let Some((t, b)) = self.beta.iter().enumerate().find(|(_, b)| bad(b)) {
            return Err(SimError::Inconsistent(format!(
                "stiffening fibre family {which}: stiffening beta of tet {t} is {b}; it must be \
                 finite and >= 0"
            )));
        }
        Ok(())
    }
}

fn v3(d: &[f64; 3]) -> Vector3<f64> {
    Vector3::new(d[0], d[1], d[2])
}

/// `ψ'(ε) = 2 k ε (1 + β ε²)` (Pa).
fn dpsi(eps: f64, k: f64, beta: f64) -> f64 {
    2.0 * k * eps * (1.0 + beta * eps * eps)
}

/// `ψ''(ε) = 2 k (1 + 3 β ε²)` (Pa).
fn ddpsi(eps: f64, k: f64, beta: f64) -> f64 {
    2.0 * k * (1.0 + 3.0 * beta * eps * eps)
}

/// `y = F d`, `|y|` and the strain `ε = |y| - 1`.
fn stretch(f: &Matrix3<f64>, d: &[f64; 3]) -> (Vector3<f64>, f64, f64) {
    let y = f * v3(d);
    let len = y.norm();
    (y, len, len - 1.0)
}

/// Energy (J) of one tet's fibre: `V k (ε² + (β/2) ε⁴)` in tension, 0 when
/// slack (`ε <= 0`). `volume` in m³, `k` in Pa, `beta` dimensionless.
pub fn knit_fibre_energy(f: &Matrix3<f64>, d: &[f64; 3], volume: f64, k: f64, beta: f64) -> f64 {
    let (_, _, eps) = stretch(f, d);
    if eps <= 0.0 {
        return 0.0;
    }
    let e2 = eps * eps;
    k * volume * (e2 + 0.5 * beta * e2 * e2)
}

/// `∂E/∂y = V ψ'(ε) ŷ` (N · m, J per unit `y`), zero when slack.
fn energy_y_gradient(
    y: &Vector3<f64>,
    len: f64,
    eps: f64,
    volume: f64,
    k: f64,
    beta: f64,
) -> Vector3<f64> {
    if eps <= 0.0 {
        return Vector3::zeros();
    }
    (volume * dpsi(eps, k, beta) / len) * y
}

/// `∂E/∂F = V ψ'(ε) ŷ dᵀ` (J) of one tet's fibre; zero when slack.
pub fn knit_fibre_stress(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
) -> Matrix3<f64> {
    let (y, len, eps) = stretch(f, d);
    energy_y_gradient(&y, len, eps, volume, k, beta) * v3(d).transpose()
}

/// `∂²E/∂y²` (J per unit `y`²): `V [ψ'' ŷŷᵀ + ψ'/|y| (I - ŷŷᵀ)]` in
/// tension, zero when slack; PSD (module doc).
fn energy_y_hessian(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
) -> Matrix3<f64> {
    let (y, len, eps) = stretch(f, d);
    if eps <= 0.0 {
        return Matrix3::zeros();
    }
    let yh = y / len;
    let along = yh * yh.transpose();
    volume
        * (ddpsi(eps, k, beta) * along + (dpsi(eps, k, beta) / len) * (Matrix3::identity() - along))
}

/// `∂²E/∂F²[δF] = V [ψ''(ε) ŷŷᵀ + ψ'(ε)/|y| (I - ŷŷᵀ)] (δF d) dᵀ` (J per
/// unit δF): the derivative of [`knit_fibre_stress`] in the direction `df`;
/// zero when slack.
pub fn knit_fibre_stress_differential(
    f: &Matrix3<f64>,
    df: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
) -> Matrix3<f64> {
    let dv = v3(d);
    energy_y_hessian(f, d, volume, k, beta) * (df * dv) * dv.transpose()
}

/// The 12x12 Hessian (N/m) of one tet's fibre energy with respect to its
/// node positions (node-major, as [`super::fibre::fibre_element_hessian`]):
/// `H_ab = c_a c_b ∂²E/∂y²` with `c = ∇N · d`. PSD everywhere (module doc).
pub fn knit_fibre_element_hessian(
    f: &Matrix3<f64>,
    rest: &TetRest,
    d: &[f64; 3],
    k: f64,
    beta: f64,
) -> Mat12 {
    let mut h = Mat12::zeros();
    let hy = energy_y_hessian(f, d, rest.volume, k, beta);
    if hy == Matrix3::zeros() {
        return h;
    }
    let c = node_coefficients(rest, d);
    for a in 0..4 {
        for b in 0..4 {
            let blk = hy * (c[a] * c[b]);
            h.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
        }
    }
    h
}

/// The quasi-Newton PD target of one tet's fibre in F-space (J) and its
/// energy (J), for the fixed system-matrix weight `weight` (J; the fibre's
/// block in the PD matrix is `w (∇N_a · d)(∇N_b · d)`).
///
/// The target is `w p dᵀ` with `p = y - (∂E/∂y)/w`, computed as
/// `(w y - ∂E/∂y) dᵀ` so that it stays defined for `w = 0`. Summed into the
/// global right-hand side it contributes `A x - ∇E` for this term, so the
/// global solve takes the step `x - A⁻¹ ∇E` of Liu, Bouaziz & Kavan 2017
/// (module doc). With `β = 0` and `w = 2 k V` it is
/// [`super::fibre::fibre_target`]'s `2 k V π(y) dᵀ`; when slack it is
/// `w y dᵀ`: the term then adds no force, only its weight in `A`.
pub fn knit_fibre_target(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
    weight: f64,
) -> (Matrix3<f64>, f64) {
    let (y, len, eps) = stretch(f, d);
    let g = energy_y_gradient(&y, len, eps, volume, k, beta);
    (
        (weight * y - g) * v3(d).transpose(),
        knit_fibre_energy(f, d, volume, k, beta),
    )
}

/// The PD weight (J) of one tet's fibre: the tangent stiffness
/// `V ψ''(ε_ref) = 2 V k (1 + 3 β ε_ref²)` at the reference strain
/// `strain_ref` (dimensionless; values below 0 count as 0, so the weight is
/// at least `2 V k`).
///
/// Why this value: `ψ''` grows with `ε`, and `ψ'(ε)/|y| <= ε ψ''(ε)/(1 + ε)
/// <= ψ''(ε)` (as `ψ'(ε) = ∫₀^ε ψ''`), so for every strain up to `ε_ref` the
/// fibre's Hessian `c cᵀ ⊗ ∂²E/∂y²` is bounded by its PD block
/// `w c cᵀ ⊗ I`. The quadratic model of the quasi-Newton step then majorizes
/// the fibre energy (a majorize-minimize step for this term), so the term
/// cannot make the fixed-point iteration overshoot as long as the strains
/// stay below `ε_ref`; above it, it can. A smaller weight converges faster at
/// small strain but overshoots sooner.
pub fn knit_fibre_pd_weight(volume: f64, k: f64, beta: f64, strain_ref: f64) -> f64 {
    volume * ddpsi(strain_ref.max(0.0), k, beta)
}

/// Derivatives (N) of one tet's fibre node gradients with respect to
/// `ln k` and `ln β` (node-major, as [`super::element::Vec12`]).
///
/// The fit works in logs so the parameters stay positive. `∂/∂ln k = k ∂/∂k`
/// is the node gradient itself (the energy is linear in `k`);
/// `∂/∂ln β = β ∂/∂β` is the node gradient of `V 2 k β ε³ ŷ dᵀ`, which is 0
/// at `β = 0` (a fit must start from `β > 0` to move it).
pub fn knit_fibre_param_derivatives(
    f: &Matrix3<f64>,
    rest: &TetRest,
    d: &[f64; 3],
    k: f64,
    beta: f64,
) -> (Vec12, Vec12) {
    let (y, len, eps) = stretch(f, d);
    let to12 = |m: Matrix3<f64>| {
        let g = node_gradients(&m, &rest.dm_inv);
        Vec12::from_fn(|i, _| g[i / 3][i % 3])
    };
    if eps <= 0.0 {
        return (Vec12::zeros(), Vec12::zeros());
    }
    let dt = v3(d).transpose();
    let yh = y / len;
    let dk = rest.volume * dpsi(eps, k, beta) * yh * dt;
    let db = rest.volume * (2.0 * k * beta * eps * eps * eps) * yh * dt;
    (to12(dk), to12(db))
}

/// Derivatives (J) of one tet's fibre energy with respect to `ln k` and
/// `ln β`: `E` itself and `V k (β/2) ε⁴` (0 when slack or at `β = 0`).
pub fn knit_fibre_energy_param_derivatives(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
) -> (f64, f64) {
    let (_, _, eps) = stretch(f, d);
    if eps <= 0.0 {
        return (0.0, 0.0);
    }
    let e4 = eps.powi(4);
    (
        knit_fibre_energy(f, d, volume, k, beta),
        k * volume * 0.5 * beta * e4,
    )
}

/// `F = Ds Dm⁻¹` of the tet `rest` at positions `x`.
fn deformation_gradient(x: &[Vec3], rest: &TetRest) -> Matrix3<f64> {
    let p = |i: usize| v3(&x[rest.nodes[i]]);
    let x0 = p(0);
    Matrix3::from_columns(&[p(1) - x0, p(2) - x0, p(3) - x0]) * rest.dm_inv
}

/// Total energy (J) of one family over a mesh at node positions `x` (m); a
/// sequential CPU reference. Panics if `fam` does not have one entry per tet
/// or a node index is out of range (call [`StiffeningFibre::check`] first).
pub fn knit_fibre_energy_total(x: &[Vec3], rest: &[TetRest], fam: &StiffeningFibre) -> f64 {
    assert!(fam.directions.len() == rest.len() && fam.k.len() == rest.len());
    assert_eq!(fam.beta.len(), rest.len());
    rest.iter()
        .enumerate()
        .map(|(e, r)| {
            knit_fibre_energy(
                &deformation_gradient(x, r),
                &fam.directions[e],
                r.volume,
                fam.k[e],
                fam.beta[e],
            )
        })
        .sum()
}

/// Node gradients (N) of [`knit_fibre_energy_total`], one per node of `x`;
/// a sequential CPU reference with the same preconditions.
pub fn knit_fibre_gradient(x: &[Vec3], rest: &[TetRest], fam: &StiffeningFibre) -> Vec<Vec3> {
    assert!(fam.directions.len() == rest.len() && fam.k.len() == rest.len());
    assert_eq!(fam.beta.len(), rest.len());
    let mut g = vec![[0.0; 3]; x.len()];
    for (e, r) in rest.iter().enumerate() {
        let p = knit_fibre_stress(
            &deformation_gradient(x, r),
            &fam.directions[e],
            r.volume,
            fam.k[e],
            fam.beta[e],
        );
        for (a, ga) in node_gradients(&p, &r.dm_inv).iter().enumerate() {
            for c in 0..3 {
                g[r.nodes[a]][c] += ga[c];
            }
        }
    }
    g
}

