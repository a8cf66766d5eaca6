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
//! matters only through `β ε²`). The adjoint's derivatives of the node
//! gradients with respect to `k` and `β` are
//! [`super::fibre::FibreFamily::param_derivatives`], tested against finite
//! differences there.

use nalgebra::{Matrix3, Vector3};

use super::element::{node_coefficients, Mat12, TetRest};

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
///
/// The pull is capped at `w ε` (the target never passes the fibre's rest
/// length, `p = y / |y|` at the cap): above `√3 ε_ref` the stiffening
/// force outgrows the weight of [`knit_fibre_pd_weight`], and the uncapped
/// step overshoots past rest and grows from iteration to iteration
/// (measured: a knit stockinette field, `β` 5e4, diverged at 4,100 m/s in
/// a held-out 30% wale stretch). Beyond the cap the PD fixed point follows
/// the fibre with the weight's slope instead of its full stiffening.
pub fn knit_fibre_target(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    k: f64,
    beta: f64,
    weight: f64,
) -> (Matrix3<f64>, f64) {
    let (y, len, eps) = stretch(f, d);
    let mut g = energy_y_gradient(&y, len, eps, volume, k, beta);
    if eps > 0.0 {
        // |g| = V ψ'(ε); the cap w ε keeps y - g / w at or beyond rest.
        let cap = weight * eps;
        let pull = g.norm();
        if pull > cap {
            g *= cap / pull;
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Vec3;
    use crate::sim::element::{node_gradients, Vec12};
    use crate::sim::fibre::{
        fibre_element_hessian, fibre_energy, fibre_stress, fibre_stress_differential, fibre_target,
    };

    use crate::sim::test_util::{random_rest as rest_of, Rng};

    /// The stiffening of the course fit (module doc).
    const BETA: f64 = 80.0;
    /// A knit-like small-strain stiffness (Pa).
    const K: f64 = 150.0;

    fn to12(g: [Vector3<f64>; 4]) -> Vec12 {
        Vec12::from_fn(|i, _| g[i / 3][i % 3])
    }

    /// Node positions of `rest` deformed by `f` (node 0 at the origin).
    fn ds_of(f: &Matrix3<f64>, rest: &TetRest) -> Matrix3<f64> {
        f * rest.dm_inv.try_inverse().unwrap()
    }

    fn grad_of(f: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3], k: f64, beta: f64) -> Vec12 {
        to12(node_gradients(
            &knit_fibre_stress(f, d, rest.volume, k, beta),
            &rest.dm_inv,
        ))
    }

    /// δDs for a move `eps` of node a along c.
    fn node_move(a: usize, c: usize, eps: f64) -> Matrix3<f64> {
        let mut m = Matrix3::zeros();
        if a == 0 {
            for col in 0..3 {
                m[(c, col)] = -eps;
            }
        } else {
            m[(c, a - 1)] = eps;
        }
        m
    }

    /// `f0` changed along `d` so that `|F d| = 1 + strain` exactly (up to
    /// rounding): `F = f0 + ((1 + strain) - |y0|) ŷ0 dᵀ`.
    fn with_strain(f0: &Matrix3<f64>, d: &[f64; 3], strain: f64) -> Matrix3<f64> {
        let y0 = f0 * v3(d);
        let len = y0.norm();
        f0 + ((1.0 + strain - len) / len) * y0 * v3(d).transpose()
    }

    /// Relative errors of the node gradients against central differences of
    /// the energy, of the Hessian against central differences of the node
    /// gradients, and of the stress differential against central differences
    /// of the stress, at deformation `f`.
    ///
    /// The node step is `h_f / |Dm⁻¹|`, so a node move changes `F` by at most
    /// `√3 h_f` and `|F d|` by as much. With `h_f = 1e-6` the truncation
    /// error is `~h_f² E'''/E'`, which is below 1e-8 relative even at the
    /// strain 1e-4 (where `E'''/E' ~ 1/ε`), and the rounding error is
    /// `~u ε / h_f < 1e-9`: 1e-6 and 1e-5 leave a wide margin.
    fn fd_errors(f: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3], k: f64, beta: f64) -> [f64; 3] {
        let h_f = 1e-6;
        let eps = h_f / rest.dm_inv.norm();
        let ds = ds_of(f, rest);
        let at = |m: &Matrix3<f64>| (ds + m) * rest.dm_inv;
        let grad = grad_of(f, rest, d, k, beta);
        let hess = knit_fibre_element_hessian(f, rest, d, k, beta);
        let (mut gfd, mut hfd) = (Vec12::zeros(), Mat12::zeros());
        for a in 0..4 {
            for c in 0..3 {
                let m = node_move(a, c, eps);
                let (p, q) = (at(&m), at(&-m));
                gfd[3 * a + c] = (knit_fibre_energy(&p, d, rest.volume, k, beta)
                    - knit_fibre_energy(&q, d, rest.volume, k, beta))
                    / (2.0 * eps);
                hfd.set_column(
                    3 * a + c,
                    &((grad_of(&p, rest, d, k, beta) - grad_of(&q, rest, d, k, beta))
                        / (2.0 * eps)),
                );
            }
        }
        // A unit-norm direction in F.
        let mut rng = Rng(f.norm().to_bits());
        let df = rng.mat().normalize();
        let dp = knit_fibre_stress_differential(f, &df, d, rest.volume, k, beta);
        let fd = (knit_fibre_stress(&(f + h_f * df), d, rest.volume, k, beta)
            - knit_fibre_stress(&(f - h_f * df), d, rest.volume, k, beta))
            / (2.0 * h_f);
        [
            (grad - gfd).norm() / grad.norm().max(1e-300),
            (hess - hfd).norm() / hess.norm().max(1e-300),
            (dp - fd).norm() / dp.norm().max(fd.norm()).max(1e-300),
        ]
    }

    fn assert_fd(errs: [f64; 3], what: &str) {
        assert!(errs[0] <= 1e-6, "{what}: gradient error {}", errs[0]);
        assert!(errs[1] <= 1e-5, "{what}: hessian error {}", errs[1]);
        assert!(errs[2] <= 1e-5, "{what}: differential error {}", errs[2]);
    }

    #[test]
    fn derivatives_match_finite_differences_at_several_strains_and_scales() {
        let mut rng = Rng(41);
        for &scale in &[1e-3, 1.0, 50.0] {
            for &strain in &[1e-4, 0.02, 0.1, 0.2, 0.3, 0.5] {
                for _ in 0..6 {
                    let rest = rest_of(scale, &mut rng);
                    let d = rng.unit();
                    let f0 = rng.rotation() * (Matrix3::identity() + 0.4 * rng.mat());
                    let f = with_strain(&f0, &d, strain);
                    let got = (f * v3(&d)).norm() - 1.0;
                    assert!((got - strain).abs() < 1e-12, "{got} vs {strain}");
                    for &beta in &[0.0, BETA] {
                        let what = format!("scale {scale}, strain {strain}, beta {beta}");
                        let errs = fd_errors(&f, &rest, &d, K, beta);
                        assert_fd(errs, &what);
                        // Not vacuous: the fibre is stretched.
                        assert!(grad_of(&f, &rest, &d, K, beta).norm() > 0.0, "{what}");
                    }
                }
            }
        }
    }

    #[test]
    fn derivatives_match_finite_differences_near_the_floor_and_inverted() {
        let mut rng = Rng(13);
        let (mut stretched, mut slack, mut inverted) = (0, 0, 0);
        for n in 0..300 {
            let rest = rest_of(0.01, &mut rng);
            let d = rng.unit();
            let (u, v) = (rng.rotation(), rng.rotation());
            let f = if n % 2 == 0 {
                // Crushed: the smallest singular value near the 0.01 floor.
                let s = Vector3::new(
                    0.8 + rng.next(),
                    0.4 + 0.4 * rng.next(),
                    0.0105 + 0.005 * rng.next(),
                );
                u * Matrix3::from_diagonal(&s) * v.transpose()
            } else {
                // Inverted, then stretched along d.
                let s = Vector3::new(
                    1.2 + rng.next(),
                    0.6 + 0.3 * rng.next(),
                    -0.2 - 0.3 * rng.next(),
                );
                let f0 = u * Matrix3::from_diagonal(&s) * v.transpose();
                let f = with_strain(&f0, &d, [0.02, 0.1, 0.3][n % 3]);
                if f.determinant() >= -1e-3 {
                    continue;
                }
                inverted += 1;
                f
            };
            let eps = (f * v3(&d)).norm() - 1.0;
            // The central differences must not straddle the kink at ε = 0.
            if eps.abs() < 1e-3 {
                continue;
            }
            if n % 2 == 0 {
                if eps > 0.0 {
                    stretched += 1
                } else {
                    slack += 1
                }
            }
            assert_fd(fd_errors(&f, &rest, &d, K, BETA), &format!("F = {f}"));
        }
        // Every regime is exercised.
        assert!(
            stretched >= 20 && slack >= 20,
            "{stretched} stretched, {slack} slack"
        );
        assert!(inverted >= 50, "{inverted} inverted");
    }

    #[test]
    fn slack_and_rigid_fibres_cost_nothing() {
        let mut rng = Rng(3);
        for _ in 0..20 {
            let rest = rest_of(0.01, &mut rng);
            let d = rng.unit();
            let dv = v3(&d);
            let r = rng.rotation();
            // Rigid motion: |R d| = 1 up to rounding.
            assert!(knit_fibre_energy(&r, &d, 1e-6, 1e4, BETA).abs() < 1e-20);
            assert!(knit_fibre_stress(&r, &d, 1e-6, 1e4, BETA).norm() < 1e-12);
            // Compressed along the fibre, or crushed: slack, exactly nothing.
            let squash = Matrix3::identity() - 0.3 * dv * dv.transpose();
            for f in [r * squash, 0.5 * r, Matrix3::zeros()] {
                let df = rng.mat();
                assert_eq!(knit_fibre_energy(&f, &d, 1e-6, 1e4, BETA), 0.0);
                assert_eq!(knit_fibre_stress(&f, &d, 1e-6, 1e4, BETA), Matrix3::zeros());
                assert_eq!(
                    knit_fibre_stress_differential(&f, &df, &d, 1e-6, 1e4, BETA),
                    Matrix3::zeros()
                );
                assert_eq!(
                    knit_fibre_element_hessian(&f, &rest, &d, 1e4, BETA),
                    Mat12::zeros()
                );
                // The target is the current y: no force.
                let (t, e) = knit_fibre_target(&f, &d, 1e-6, 1e4, BETA, 3.0);
                assert_eq!(e, 0.0);
                assert!((t - 3.0 * f * dv * dv.transpose()).norm() <= 1e-15);
            }
            // Stretched across the fibre: nothing either.
            let across = Vector3::new(d[1], -d[0], 0.0);
            if across.norm() > 0.1 {
                let a = across.normalize();
                let side = Matrix3::identity() + 0.5 * a * a.transpose();
                assert!(knit_fibre_energy(&(r * side), &d, 1e-6, 1e4, BETA) < 1e-20);
            }
            // Stretched 20% along it: V k (ε² + β/2 ε⁴).
            let pull = Matrix3::identity() + 0.2 * dv * dv.transpose();
            let e = knit_fibre_energy(&(r * pull), &d, 1e-6, 1e4, BETA);
            let want = 1e4 * 1e-6 * (0.04 + 40.0 * 0.0016);
            assert!((e - want).abs() < 1e-12 * want, "{e} vs {want}");
        }
    }

    #[test]
    fn secant_stiffness_follows_the_course_fit() {
        let d = {
            let v = Vector3::new(0.3, -0.5, 0.8).normalize();
            [v[0], v[1], v[2]]
        };
        let dv = v3(&d);
        let mut secant = Vec::new();
        for &strain in &[0.02, 0.1, 0.2] {
            // Uniaxial stretch along d of a unit-volume tet.
            let f = Matrix3::identity() + strain * dv * dv.transpose();
            let p = knit_fibre_stress(&f, &d, 1.0, K, BETA);
            let s = p.norm() / strain;
            let want = 2.0 * K * (1.0 + BETA * strain * strain);
            assert!((s - want).abs() <= 1e-9 * want, "{strain}: {s} vs {want}");
            // The stress pulls along d.
            assert!((p * dv).dot(&dv) > 0.0);
            secant.push(s);
        }
        // Within 6% of the measured 1 : 1.66 : 4.15.
        for (r, m) in [(secant[1] / secant[0], 1.66), (secant[2] / secant[0], 4.15)] {
            assert!((r / m - 1.0).abs() < 0.06, "ratio {r} vs {m}");
        }
    }

    #[test]
    fn hessian_is_psd_and_symmetric() {
        let mut rng = Rng(29);
        let mut stretched = 0;
        for n in 0..80 {
            let rest = rest_of(0.01, &mut rng);
            let d = rng.unit();
            let mut f = rng.rotation() * (Matrix3::identity() + 0.8 * rng.mat());
            if n % 2 == 0 {
                f = with_strain(&f, &d, 0.6 * rng.next());
            }
            let h = knit_fibre_element_hessian(&f, &rest, &d, K, BETA);
            let eig = h.symmetric_eigen().eigenvalues;
            assert!(eig.min() >= -1e-9 * eig.max().max(1e-300), "{eig}");
            assert!((h - h.transpose()).norm() <= 1e-12 * h.norm().max(1e-300));
            stretched += (eig.max() > 0.0) as usize;
        }
        assert!(stretched >= 40, "{stretched} of 80 stretched");
    }

    #[test]
    fn zero_beta_is_the_quadratic_fibre() {
        let mut rng = Rng(31);
        let mut stretched = 0;
        for _ in 0..60 {
            let rest = rest_of(0.05, &mut rng);
            let d = rng.unit();
            let f = rng.rotation() * (Matrix3::identity() + 0.6 * rng.mat());
            let v = rest.volume;
            let eps = (f * v3(&d)).norm() - 1.0;
            // The energies are computed the same way: equal to the last bit.
            let (e, e0) = (
                knit_fibre_energy(&f, &d, v, K, 0.0),
                fibre_energy(&f, &d, v, K),
            );
            assert_eq!(e, e0);
            // The stresses and Hessians differ in rounding only, but
            // fibre.rs forms `y - y/|y|` and `1 - 1/|y|`, which cancel to a
            // relative error of a few ulp over ε at small strains.
            let tol = 1e-14 * (1.0 + 1.0 / eps.abs());
            let (p, p0) = (
                knit_fibre_stress(&f, &d, v, K, 0.0),
                fibre_stress(&f, &d, v, K),
            );
            assert!((p - p0).norm() <= tol * p0.norm(), "{p} vs {p0}");
            let df = rng.mat();
            let (q, q0) = (
                knit_fibre_stress_differential(&f, &df, &d, v, K, 0.0),
                fibre_stress_differential(&f, &df, &d, v, K),
            );
            assert!((q - q0).norm() <= tol * q0.norm(), "{q} vs {q0}");
            let (h, h0) = (
                knit_fibre_element_hessian(&f, &rest, &d, K, 0.0),
                fibre_element_hessian(&f, &rest, &d, K),
            );
            assert!((h - h0).norm() <= tol * h0.norm(), "{h} vs {h0}");
            // The exact local-global form: w = 2 k V.
            let w = knit_fibre_pd_weight(v, K, 0.0, 0.3);
            assert!((w - 2.0 * K * v).abs() <= 1e-15 * w);
            let ((t, et), (t0, et0)) = (
                knit_fibre_target(&f, &d, v, K, 0.0, w),
                fibre_target(&f, &d, v, K),
            );
            assert!((t - t0).norm() <= 1e-13 * t0.norm(), "{t} vs {t0}");
            assert_eq!(et, et0);
            stretched += (e0 > 0.0) as usize;
        }
        assert!((15..50).contains(&stretched), "{stretched} of 60 stretched");
    }

    #[test]
    fn pd_target_gives_the_quasi_newton_right_hand_side() {
        let mut rng = Rng(37);
        for n in 0..40 {
            let rest = rest_of(0.02, &mut rng);
            let d = rng.unit();
            let f0 = rng.rotation() * (Matrix3::identity() + 0.4 * rng.mat());
            let f = with_strain(&f0, &d, [-0.1, 0.05, 0.2, 0.4][n % 4]);
            let w = knit_fibre_pd_weight(rest.volume, K, BETA, 0.4);
            let (t, e) = knit_fibre_target(&f, &d, rest.volume, K, BETA, w);
            assert_eq!(e, knit_fibre_energy(&f, &d, rest.volume, K, BETA));
            // Node-space right-hand side of the target vs A x - ∇E of the term:
            // (A x)_a = w c_a y.
            let rhs = to12(node_gradients(&t, &rest.dm_inv));
            let c = node_coefficients(&rest, &d);
            let y = f * v3(&d);
            let ax = Vec12::from_fn(|i, _| w * c[i / 3] * y[i % 3]);
            let want = ax - grad_of(&f, &rest, &d, K, BETA);
            assert!((rhs - want).norm() <= 1e-12 * ax.norm(), "{rhs} vs {want}");
        }
    }

    /// The target's pull is the fibre force up to `√3 ε_ref` and capped
    /// above it so that the target `p = t / w` never passes rest: a step
    /// toward it cannot overshoot, whatever the stiffening.
    #[test]
    fn pd_target_never_passes_the_rest_length() {
        let mut rng = Rng(53);
        let strain_ref = 0.2;
        let cap_strain = 3f64.sqrt() * strain_ref;
        for n in 0..40 {
            let rest = rest_of(0.02, &mut rng);
            let d = rng.unit();
            let f0 = rng.rotation() * (Matrix3::identity() + 0.4 * rng.mat());
            let eps = [0.1, 0.3, 0.4, 0.8, 2.0][n % 5];
            let f = with_strain(&f0, &d, eps);
            let beta = [BETA, 5e4][n % 2];
            let w = knit_fibre_pd_weight(rest.volume, K, beta, strain_ref);
            let (t, _) = knit_fibre_target(&f, &d, rest.volume, K, beta, w);
            let y = f * v3(&d);
            let p = t * v3(&d) / w;
            let force = knit_fibre_stress(&f, &d, rest.volume, K, beta) * v3(&d);
            if eps < cap_strain {
                // Uncapped: w p = w y - V ψ'(ε) ŷ.
                assert!((w * p - (w * y - force)).norm() <= 1e-10 * w * y.norm());
            } else {
                assert!(
                    (p.norm() - 1.0).abs() <= 1e-12,
                    "eps {eps}: |p| {}",
                    p.norm()
                );
                assert!((p - y.normalize()).norm() <= 1e-12);
            }
            assert!(p.norm() >= 1.0 - 1e-12, "eps {eps}: |p| {}", p.norm());
        }
    }

    #[test]
    fn pd_weight_bounds_the_hessian_up_to_the_reference_strain() {
        let mut rng = Rng(43);
        let strain_ref = 0.3;
        for _ in 0..40 {
            let rest = rest_of(0.02, &mut rng);
            let d = rng.unit();
            let f0 = rng.rotation() * (Matrix3::identity() + 0.4 * rng.mat());
            let w = knit_fibre_pd_weight(rest.volume, K, BETA, strain_ref);
            assert!(w >= 2.0 * rest.volume * K);
            let c = node_coefficients(&rest, &d);
            let block = Mat12::from_fn(|i, j| {
                if i % 3 == j % 3 {
                    w * c[i / 3] * c[j / 3]
                } else {
                    0.0
                }
            });
            let check = |strain: f64| {
                let f = with_strain(&f0, &d, strain);
                let h = knit_fibre_element_hessian(&f, &rest, &d, K, BETA);
                (block - h).symmetric_eigen().eigenvalues.min() / block.norm()
            };
            // The PD block dominates the Hessian up to ε_ref, not beyond.
            for &s in &[1e-4, 0.1, 0.2, strain_ref * (1.0 - 1e-9)] {
                assert!(check(s) >= -1e-9, "strain {s}: {}", check(s));
            }
            assert!(check(1.2 * strain_ref) < -1e-3);
        }
        // Negative reference strains count as 0.
        assert_eq!(knit_fibre_pd_weight(2.0, K, BETA, -0.5), 4.0 * K);
    }

    #[test]
    fn model_gradient_matches_finite_differences_of_the_total() {
        let mut rng = Rng(47);
        // Three tets sharing nodes: 0-1-2-3, 1-2-3-4, 0-2-3-5.
        let x: Vec<Vec3> = (0..6)
            .map(|_| [rng.sym() * 0.01, rng.sym() * 0.01, rng.sym() * 0.01])
            .collect();
        let tets = [[0, 1, 2, 3], [1, 2, 3, 4], [0, 2, 3, 5]];
        let rest: Vec<TetRest> = tets
            .iter()
            .map(|&nodes| {
                let p = |i: usize| v3(&x[nodes[i]]);
                let mut dm = Matrix3::from_columns(&[p(1) - p(0), p(2) - p(0), p(3) - p(0)]);
                let mut nodes = nodes;
                if dm.determinant() < 0.0 {
                    nodes.swap(1, 2);
                    dm.swap_columns(0, 1);
                }
                TetRest {
                    nodes,
                    dm_inv: dm.try_inverse().unwrap(),
                    volume: dm.determinant() / 6.0,
                }
            })
            .collect();
        // One family: per tet a direction, k and β.
        let fam: Vec<([f64; 3], f64, f64)> = vec![
            (rng.unit(), K, BETA),
            (rng.unit(), 2.0 * K, 0.0),
            (rng.unit(), 0.5 * K, 20.0),
        ];
        let def_grad = |x: &[Vec3], r: &TetRest| {
            let p = |i: usize| v3(&x[r.nodes[i]]);
            Matrix3::from_columns(&[p(1) - p(0), p(2) - p(0), p(3) - p(0)]) * r.dm_inv
        };
        type Family = [([f64; 3], f64, f64)];
        let knit_fibre_energy_total = |x: &[Vec3], rest: &[TetRest], fam: &Family| -> f64 {
            rest.iter()
                .zip(fam)
                .map(|(r, (d, k, b))| knit_fibre_energy(&def_grad(x, r), d, r.volume, *k, *b))
                .sum()
        };
        let knit_fibre_gradient = |x: &[Vec3], rest: &[TetRest], fam: &Family| {
            let mut g = vec![[0.0; 3]; x.len()];
            for (r, (d, k, b)) in rest.iter().zip(fam) {
                let p = knit_fibre_stress(&def_grad(x, r), d, r.volume, *k, *b);
                for (a, ga) in node_gradients(&p, &r.dm_inv).iter().enumerate() {
                    for c in 0..3 {
                        g[r.nodes[a]][c] += ga[c];
                    }
                }
            }
            g
        };
        // Deformed: stretched by 30% plus noise.
        let y: Vec<Vec3> = x
            .iter()
            .map(|p| {
                let q = 1.3 * v3(p);
                [q[0] + 1e-3 * rng.sym(), q[1] + 1e-3 * rng.sym(), q[2]]
            })
            .collect();
        let e = knit_fibre_energy_total(&y, &rest, &fam);
        assert!(e > 0.0);
        let g = knit_fibre_gradient(&y, &rest, &fam);
        assert_eq!(g.len(), 6);
        let h = 1e-9;
        let gmax = g.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        for n in 0..6 {
            for c in 0..3 {
                let (mut p, mut q) = (y.clone(), y.clone());
                p[n][c] += h;
                q[n][c] -= h;
                let fd = (knit_fibre_energy_total(&p, &rest, &fam)
                    - knit_fibre_energy_total(&q, &rest, &fam))
                    / (2.0 * h);
                assert!(
                    (g[n][c] - fd).abs() <= 1e-6 * gmax,
                    "node {n} coord {c}: {} vs {fd}",
                    g[n][c]
                );
            }
        }
        // Translations cost nothing: the gradient sums to zero.
        for c in 0..3 {
            let s: f64 = g.iter().map(|v| v[c]).sum();
            assert!(s.abs() <= 1e-12 * gmax);
        }
    }
    mod props {
        use super::*;
        use nalgebra::Rotation3;
        use proptest::prelude::*;

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(256))]

            #[test]
            fn energy_is_non_negative_and_frame_indifferent(
                m in proptest::array::uniform9(-2.0f64..2.0),
                axis in proptest::array::uniform3(-3.0f64..3.0),
                dir in proptest::array::uniform3(-1.0f64..1.0),
                k in 0.0f64..1e5,
                beta in 0.0f64..200.0,
                volume in 1e-9f64..1.0,
            ) {
                let dn = v3(&dir).norm();
                prop_assume!(dn > 0.1);
                let d = [dir[0] / dn, dir[1] / dn, dir[2] / dn];
                let f = Matrix3::from_row_slice(&m);
                let r = Rotation3::new(v3(&axis)).into_inner();
                let e = knit_fibre_energy(&f, &d, volume, k, beta);
                let er = knit_fibre_energy(&(r * f), &d, volume, k, beta);
                prop_assert!(e >= 0.0 && e.is_finite());
                // |R y| and |y| differ by a few ulp of |y|; E changes by the
                // stress times that (and by V k ulp² across the kink).
                let len = (f * v3(&d)).norm();
                let p = knit_fibre_stress(&f, &d, volume, k, beta).norm()
                    + knit_fibre_stress(&(r * f), &d, volume, k, beta).norm();
                let tol = 1e-12 * e.max(er)
                    + 1e-14 * p * (1.0 + len)
                    + 1e-28 * k * volume * (1.0 + len).powi(2);
                prop_assert!((e - er).abs() <= tol, "{} vs {}", e, er);
            }
        }
    }
}
