//! Tension-only fibre terms: the anisotropy that VH Eq. 7 lacks.
//!
//! Eq. 7 is isotropic per element. A knit is not: a stockinette stretched
//! 10% pulls back with 0.128 N along the wales and 0.042 N along the
//! courses, and it bends about a diagonal far more easily than an isotropic
//! plate of the same stretch stiffness (its in-plane shear is soft). Fitted
//! on one pose at a time the best uniform Eq. 7 material of a stockinette
//! swatch is 2.4x stiffer on a wale stretch than on a course stretch, and on
//! a diagonal bend it stays 10x above the Y2V floor (docs/fidelity.md).
//!
//! A fibre family adds, per tet `e`, a unit rest direction `d_e`
//! (dimensionless, in the rest configuration) and a stiffness `γ_e` (Pa):
//!
//! `E_e = γ_e V_e dist²(F d_e, B)`,  `B` the unit ball,
//!
//! i.e. `γ V (|F d| - 1)²` where the fibre is stretched (`|F d| > 1`) and
//! nothing where it is slack: yarn lines resist tension and buckle under
//! compression. Two families (courses and wales) over a soft Eq. 7 shear
//! make the orthotropic material of woven and knitted sheets.
//!
//! The term has the projective-dynamics form of Eq. 7 (Bouaziz et al. 2014,
//! §4: a distance to a constraint set, here a convex one): with `y = F d`,
//! `π(y)` its projection onto `B`, the selection `y = F d` linear in the node
//! positions, weight `w = 2 γ V`:
//! * energy `γ V |y - π(y)|²`;
//! * `∂E/∂F = 2 γ V (y - π(y)) dᵀ` (envelope theorem, as in [`super::energy`]);
//! * PD target in F-space `2 γ V π(y) dᵀ`, system-matrix block
//!   `2 γ V (∇N_a · d)(∇N_b · d)`;
//! * `∂²E/∂F²[δF] = 2 γ V (I - ∂π/∂y)(δF d) dᵀ` with `∂π/∂y = I` inside `B`
//!   and `(I - ŷŷᵀ)/|y|` outside: PSD everywhere, so Newton needs no
//!   projection.

use nalgebra::{Matrix3, Vector3};

pub use super::element::node_coefficients;
use super::element::{node_gradients, Mat12, TetRest, Vec12};
use super::SimError;

/// Most fibre families per model (the GPU backend packs two per tet).
pub const MAX_FIBRE_FAMILIES: usize = 2;

/// One family of tension-only fibres: per tet a unit rest direction, a
/// stiffness and, for the knit material, a stiffening.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FibreFamily {
    /// Unit rest direction per tet (dimensionless, rest configuration).
    pub directions: Vec<[f64; 3]>,
    /// Stiffness per tet (Pa, finite, `>= 0`; 0: no fibre in that tet): the
    /// small-strain stiffness `k` of a stiffening family.
    pub gamma: Vec<f64>,
    /// Stiffening `β` per tet (dimensionless, finite, `>= 0`;
    /// [`super::knit`]: energy `γ V (ε² + β ε⁴ / 2)` in tension). Empty
    /// (the default): `β = 0` everywhere, the quadratic fibre above, and
    /// `β` is not a fitted field.
    pub beta: Vec<f64>,
}

/// The strain at which a stiffening family's PD weight is its tangent
/// stiffness ([`super::knit::knit_fibre_pd_weight`]): up to it the PD matrix
/// bounds the fibre's Hessian, so the iteration does not overshoot; above
/// it the accelerated iteration's safeguard carries it. 0.2: the middle of
/// the 10-30% strains knits are tested and worn at.
pub const STIFFENING_STRAIN_REF: f64 = 0.2;

impl FibreFamily {
    /// A quadratic family (no stiffening).
    pub fn quadratic(directions: Vec<[f64; 3]>, gamma: Vec<f64>) -> FibreFamily {
        FibreFamily {
            directions,
            gamma,
            beta: Vec::new(),
        }
    }

    /// Whether the family carries a stiffening field (`beta` non-empty).
    pub fn stiffening(&self) -> bool {
        !self.beta.is_empty()
    }

    /// `β` of tet `e` (0 without a stiffening field).
    pub fn beta_at(&self, e: usize) -> f64 {
        self.beta.get(e).copied().unwrap_or(0.0)
    }

    /// Energy (J) of tet `e`'s fibre at `f` (rest volume `volume`).
    pub fn energy(&self, e: usize, f: &Matrix3<f64>, volume: f64) -> f64 {
        match self.beta_at(e) {
            b if b == 0.0 => fibre_energy(f, &self.directions[e], volume, self.gamma[e]),
            b => super::knit::knit_fibre_energy(f, &self.directions[e], volume, self.gamma[e], b),
        }
    }

    /// `∂E/∂F` (J) of tet `e`'s fibre at `f`.
    pub fn stress(&self, e: usize, f: &Matrix3<f64>, volume: f64) -> Matrix3<f64> {
        match self.beta_at(e) {
            b if b == 0.0 => fibre_stress(f, &self.directions[e], volume, self.gamma[e]),
            b => super::knit::knit_fibre_stress(f, &self.directions[e], volume, self.gamma[e], b),
        }
    }

    /// The 12x12 Hessian (N/m) of tet `e`'s fibre (PSD).
    pub fn element_hessian(&self, e: usize, f: &Matrix3<f64>, rest: &TetRest) -> Mat12 {
        match self.beta_at(e) {
            b if b == 0.0 => fibre_element_hessian(f, rest, &self.directions[e], self.gamma[e]),
            b => super::knit::knit_fibre_element_hessian(
                f,
                rest,
                &self.directions[e],
                self.gamma[e],
                b,
            ),
        }
    }

    /// The weight (J) of tet `e`'s fibre in the PD matrix: `2 γ V` (the
    /// exact local-global form), or for a stiffening fibre its tangent
    /// stiffness at [`STIFFENING_STRAIN_REF`].
    pub fn pd_weight(&self, e: usize, volume: f64) -> f64 {
        match self.beta_at(e) {
            b if b == 0.0 => 2.0 * self.gamma[e] * volume,
            b => super::knit::knit_fibre_pd_weight(volume, self.gamma[e], b, STIFFENING_STRAIN_REF),
        }
    }

    /// The PD target in F-space (J) of tet `e`'s fibre and its energy (J),
    /// for the weight [`Self::pd_weight`]: the projection for a quadratic
    /// fibre, the quasi-Newton target of Liu, Bouaziz and Kavan 2017 for a
    /// stiffening one ([`super::knit::knit_fibre_target`]).
    pub fn target(&self, e: usize, f: &Matrix3<f64>, volume: f64) -> (Matrix3<f64>, f64) {
        match self.beta_at(e) {
            b if b == 0.0 => fibre_target(f, &self.directions[e], volume, self.gamma[e]),
            b => super::knit::knit_fibre_target(
                f,
                &self.directions[e],
                volume,
                self.gamma[e],
                b,
                self.pd_weight(e, volume),
            ),
        }
    }

    /// Derivatives (N per Pa, N) of tet `e`'s fibre node gradients with
    /// respect to its `γ` and its `β`: the energy is linear in each at a
    /// fixed deformation, so both are gradients at unit values.
    pub fn param_derivatives(&self, e: usize, f: &Matrix3<f64>, rest: &TetRest) -> (Vec12, Vec12) {
        let d = &self.directions[e];
        let to12 = |m: Matrix3<f64>| {
            let g = node_gradients(&m, &rest.dm_inv);
            Vec12::from_fn(|i, _| g[i / 3][i % 3])
        };
        let b = self.beta_at(e);
        let dk = to12(super::knit::knit_fibre_stress(f, d, rest.volume, 1.0, b));
        let quartic = super::knit::knit_fibre_stress(f, d, rest.volume, self.gamma[e], 1.0)
            - super::knit::knit_fibre_stress(f, d, rest.volume, self.gamma[e], 0.0);
        (dk, to12(quartic))
    }
}

impl FibreFamily {
    /// Checks lengths against `num_tets`, unit directions (to 1e-6),
    /// stiffnesses and stiffenings; `which` names the family in errors.
    pub fn check(&self, num_tets: usize, which: usize) -> Result<(), SimError> {
        if !self.beta.is_empty() && self.beta.len() != num_tets {
            return Err(SimError::Inconsistent(format!(
                "fibre family {which}: {num_tets} tets but {} stiffenings",
                self.beta.len()
            )));
        }
        if let Some((t, b)) = self
            .beta
            .iter()
            .enumerate()
            .find(|(_, b)| !(b.is_finite() && **b >= 0.0))
        {
            return Err(SimError::Inconsistent(format!(
                "fibre family {which}: stiffening of tet {t} is {b}; it must be finite and >= 0"
            )));
        }
        if self.directions.len() != num_tets || self.gamma.len() != num_tets {
            return Err(SimError::Inconsistent(format!(
                "fibre family {which}: {num_tets} tets but {} directions and {} stiffnesses",
                self.directions.len(),
                self.gamma.len()
            )));
        }
        if let Some((t, d)) = self
            .directions
            .iter()
            .enumerate()
            .find(|(_, d)| !crate::geom::is_unit_vector(d))
        {
            return Err(SimError::Inconsistent(format!(
                "fibre family {which}: direction of tet {t} is {d:?}; it must be a unit vector"
            )));
        }
        if let Some((t, g)) = self
            .gamma
            .iter()
            .enumerate()
            .find(|(_, g)| !(g.is_finite() && **g >= 0.0))
        {
            return Err(SimError::Inconsistent(format!(
                "fibre family {which}: stiffness of tet {t} is {g}; it must be finite and >= 0"
            )));
        }
        Ok(())
    }
}

fn v3(d: &[f64; 3]) -> Vector3<f64> {
    Vector3::new(d[0], d[1], d[2])
}

/// `y = F d`, its projection `π(y)` onto the unit ball and `|y - π(y)|²`.
pub fn fibre_projection(f: &Matrix3<f64>, d: &[f64; 3]) -> (Vector3<f64>, Vector3<f64>, f64) {
    let y = f * v3(d);
    let len = y.norm();
    if len > 1.0 {
        (y, y / len, (len - 1.0).powi(2))
    } else {
        (y, y, 0.0)
    }
}

/// Energy (J) of one tet's fibre: `γ V dist²(F d, B)`.
pub fn fibre_energy(f: &Matrix3<f64>, d: &[f64; 3], volume: f64, gamma: f64) -> f64 {
    gamma * volume * fibre_projection(f, d).2
}

/// `∂E/∂F = 2 γ V (y - π(y)) dᵀ` (J) of one tet's fibre.
pub fn fibre_stress(f: &Matrix3<f64>, d: &[f64; 3], volume: f64, gamma: f64) -> Matrix3<f64> {
    let (y, p, _) = fibre_projection(f, d);
    (2.0 * gamma * volume) * (y - p) * v3(d).transpose()
}

/// The PD target of one tet's fibre in F-space, `2 γ V π(F d) dᵀ` (J), and
/// its energy (J).
pub fn fibre_target(
    f: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    gamma: f64,
) -> (Matrix3<f64>, f64) {
    let (_, p, dist2) = fibre_projection(f, d);
    (
        (2.0 * gamma * volume) * p * v3(d).transpose(),
        gamma * volume * dist2,
    )
}

/// `∂²E/∂F²[δF] = 2 γ V (I - ∂π/∂y)(δF d) dᵀ` (J per unit δF): the
/// derivative of [`fibre_stress`] in the direction `df` (PSD, module doc).
pub fn fibre_stress_differential(
    f: &Matrix3<f64>,
    df: &Matrix3<f64>,
    d: &[f64; 3],
    volume: f64,
    gamma: f64,
) -> Matrix3<f64> {
    let dv = v3(d);
    let y = f * dv;
    let len = y.norm();
    if len <= 1.0 {
        return Matrix3::zeros();
    }
    let yh = y / len;
    let dy = df * dv;
    // (I - (I - ŷŷᵀ)/|y|) δy
    let perp = dy - yh * yh.dot(&dy);
    let h = dy - perp / len;
    (2.0 * gamma * volume) * h * dv.transpose()
}

/// The 12x12 Hessian (N/m) of one tet's fibre energy with respect to its
/// node positions (node-major, as [`super::hessian::element_hessian`]).
pub fn fibre_element_hessian(f: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3], gamma: f64) -> Mat12 {
    let mut h = Mat12::zeros();
    let y = f * v3(d);
    let len = y.norm();
    if len <= 1.0 || gamma == 0.0 {
        return h;
    }
    // y = Σ_a c_a x_a with c = ∇N · d, so H = c cᵀ ⊗ ∂²(γ V dist²)/∂y².
    let c = node_coefficients(rest, d);
    let yh = y / len;
    let hy = (2.0 * gamma * rest.volume)
        * (Matrix3::identity() - (Matrix3::identity() - yh * yh.transpose()) / len);
    for a in 0..4 {
        for b in 0..4 {
            let blk = hy * (c[a] * c[b]);
            h.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
        }
    }
    h
}

/// Derivative (N/Pa) of one tet's fibre node gradients with respect to its
/// `γ`: the energy is linear in `γ`.
pub fn fibre_gamma_derivative(f: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3]) -> Vec12 {
    let g = node_gradients(&fibre_stress(f, d, rest.volume, 1.0), &rest.dm_inv);
    Vec12::from_fn(|i, _| g[i / 3][i % 3])
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::sim::test_util::{random_rest as rest_of, Rng};

    /// Node positions of `rest` deformed by `f` (node 0 at the origin).
    fn ds_of(f: &Matrix3<f64>, rest: &TetRest) -> Matrix3<f64> {
        f * rest.dm_inv.try_inverse().unwrap()
    }

    fn energy_at(ds: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3], g: f64) -> f64 {
        fibre_energy(&(ds * rest.dm_inv), d, rest.volume, g)
    }

    fn grad_at(ds: &Matrix3<f64>, rest: &TetRest, d: &[f64; 3], g: f64) -> Vec12 {
        let gr = node_gradients(
            &fibre_stress(&(ds * rest.dm_inv), d, rest.volume, g),
            &rest.dm_inv,
        );
        Vec12::from_fn(|i, _| gr[i / 3][i % 3])
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

    #[test]
    fn gradient_and_hessian_match_finite_differences_at_several_scales() {
        let mut rng = Rng(17);
        let mut stretched = 0;
        for &scale in &[1e-3, 1.0, 50.0] {
            for _ in 0..30 {
                let rest = rest_of(scale, &mut rng);
                let d = rng.unit();
                let f = rng.rotation() * (Matrix3::identity() + 0.6 * rng.mat());
                let ds = ds_of(&f, &rest);
                let g = 3e4;
                let eps = 1e-6 * ds.norm();
                let grad = grad_at(&ds, &rest, &d, g);
                let hess = fibre_element_hessian(&f, &rest, &d, g);
                let (mut gfd, mut hfd) = (Vec12::zeros(), Mat12::zeros());
                for a in 0..4 {
                    for c in 0..3 {
                        let m = node_move(a, c, eps);
                        let (p, q) = (ds + m, ds - m);
                        gfd[3 * a + c] = (energy_at(&p, &rest, &d, g)
                            - energy_at(&q, &rest, &d, g))
                            / (2.0 * eps);
                        hfd.set_column(
                            3 * a + c,
                            &((grad_at(&p, &rest, &d, g) - grad_at(&q, &rest, &d, g))
                                / (2.0 * eps)),
                        );
                    }
                }
                let gs = grad.norm().max(1e-300);
                assert!(
                    (grad - gfd).norm() <= 1e-6 * gs,
                    "gradient: {} vs {}",
                    grad,
                    gfd
                );
                let hs = hess.norm().max(1e-300);
                assert!(
                    (hess - hfd).norm() <= 1e-5 * hs,
                    "hessian error {}",
                    (hess - hfd).norm() / hs
                );
                // The directional differential is the Hessian's action.
                let df = rng.mat();
                let dp = fibre_stress_differential(&f, &df, &d, rest.volume, g);
                let fd = (fibre_stress(&(f + 1e-6 * df), &d, rest.volume, g)
                    - fibre_stress(&(f - 1e-6 * df), &d, rest.volume, g))
                    / 2e-6;
                assert!((dp - fd).norm() <= 1e-5 * dp.norm().max(fd.norm()).max(1e-300));
                stretched += ((f * v3(&d)).norm() > 1.0) as usize;
            }
        }
        // Both regimes are exercised.
        assert!((20..80).contains(&stretched), "{stretched} of 90 stretched");
    }

    #[test]
    fn slack_and_rigid_fibres_cost_nothing_and_stretched_ones_do() {
        let mut rng = Rng(3);
        for _ in 0..20 {
            let d = rng.unit();
            let r = rng.rotation();
            // Rigid motion: |R d| = 1.
            assert!(fibre_energy(&r, &d, 1e-6, 1e4).abs() < 1e-20);
            assert!(fibre_stress(&r, &d, 1e-6, 1e4).norm() < 1e-12);
            // Compressed along the fibre: slack.
            let dv = v3(&d);
            let squash = Matrix3::identity() - 0.3 * dv * dv.transpose();
            assert_eq!(fibre_energy(&(r * squash), &d, 1e-6, 1e4), 0.0);
            // Stretched 20% along it: γ V 0.2².
            let pull = Matrix3::identity() + 0.2 * dv * dv.transpose();
            let e = fibre_energy(&(r * pull), &d, 1e-6, 1e4);
            assert!((e - 1e4 * 1e-6 * 0.04).abs() < 1e-15, "{e}");
            // Stretched across it: nothing.
            let across = Vector3::new(d[1], -d[0], 0.0);
            if across.norm() > 0.1 {
                let a = across.normalize();
                let side = Matrix3::identity() + 0.5 * a * a.transpose();
                assert!(fibre_energy(&(r * side), &d, 1e-6, 1e4) < 1e-20);
            }
        }
    }

    #[test]
    fn hessian_is_psd_and_gamma_derivative_is_linear() {
        let mut rng = Rng(29);
        for _ in 0..40 {
            let rest = rest_of(0.01, &mut rng);
            let d = rng.unit();
            let f = rng.rotation() * (Matrix3::identity() + 0.8 * rng.mat());
            let h = fibre_element_hessian(&f, &rest, &d, 2e4);
            let eig = h.symmetric_eigen().eigenvalues;
            assert!(eig.min() >= -1e-9 * eig.max().max(1e-300), "{eig}");
            assert!((h - h.transpose()).norm() <= 1e-12 * h.norm().max(1e-300));
            let dg = fibre_gamma_derivative(&f, &rest, &d);
            let ds = ds_of(&f, &rest);
            assert!(
                (2e4 * dg - grad_at(&ds, &rest, &d, 2e4)).norm()
                    <= 1e-9 * dg.norm().max(1e-300) * 2e4
            );
        }
    }

    #[test]
    fn families_are_checked() {
        let ok = FibreFamily::quadratic(vec![[1.0, 0.0, 0.0]; 2], vec![1.0, 0.0]);
        assert!(ok.check(2, 0).is_ok());
        assert!(ok.check(3, 0).is_err());
        let mut bad = ok.clone();
        bad.directions[1] = [0.5, 0.0, 0.0];
        assert!(format!("{}", bad.check(2, 1).unwrap_err()).contains("tet 1"));
        let mut bad = ok.clone();
        bad.gamma[0] = -1.0;
        assert!(bad.check(2, 0).is_err());
        let mut bad = ok.clone();
        bad.gamma[0] = f64::NAN;
        assert!(bad.check(2, 0).is_err());
        let mut stiff = ok;
        stiff.beta = vec![80.0, 0.0];
        assert!(stiff.check(2, 0).is_ok());
        stiff.beta[1] = -1.0;
        assert!(format!("{}", stiff.check(2, 0).unwrap_err()).contains("stiffening of tet 1"));
        stiff.beta = vec![f64::NAN, 1.0];
        let m = format!("{}", stiff.check(2, 1).unwrap_err());
        assert!(m.contains("family 1") && m.contains("tet 0"), "{m}");
        stiff.beta = vec![1.0];
        assert!(format!("{}", stiff.check(2, 0).unwrap_err()).contains("1 stiffenings"));
    }

    /// The family's dispatch: a stiffening tet follows `sim::knit`, a
    /// quadratic one this module, and the parameter derivatives are the
    /// force's finite differences in `γ` and `β`.
    #[test]
    fn stiffening_tets_follow_the_knit_energy_and_their_derivatives() {
        let mut rng = Rng(41);
        let rest = rest_of(0.01, &mut rng);
        let d = [1.0, 0.0, 0.0];
        let fam = FibreFamily {
            directions: vec![d; 2],
            gamma: vec![3e3, 3e3],
            beta: vec![80.0, 0.0],
        };
        let f = Matrix3::from_diagonal(&Vector3::new(1.25, 0.97, 1.01));
        let v = rest.volume;
        assert_eq!(
            fam.energy(0, &f, v),
            super::super::knit::knit_fibre_energy(&f, &d, v, 3e3, 80.0)
        );
        assert_eq!(fam.energy(1, &f, v), fibre_energy(&f, &d, v, 3e3));
        assert!(fam.energy(0, &f, v) > fam.energy(1, &f, v));
        assert_eq!(fam.pd_weight(1, v), 2.0 * 3e3 * v);
        assert!(fam.pd_weight(0, v) > fam.pd_weight(1, v));
        // Derivatives in γ and β against central differences of the force.
        let (dk, db) = fam.param_derivatives(0, &f, &rest);
        let force = |g: f64, b: f64| {
            let fam = FibreFamily {
                gamma: vec![g; 2],
                beta: vec![b; 2],
                ..fam.clone()
            };
            let gr = node_gradients(&fam.stress(0, &f, v), &rest.dm_inv);
            Vec12::from_fn(|i, _| gr[i / 3][i % 3])
        };
        let fd_k = (force(3e3 + 1.0, 80.0) - force(3e3 - 1.0, 80.0)) / 2.0;
        let fd_b = (force(3e3, 80.5) - force(3e3, 79.5)) / 1.0;
        assert!((dk - fd_k).norm() <= 1e-7 * dk.norm(), "{dk} {fd_k}");
        assert!((db - fd_b).norm() <= 1e-7 * db.norm(), "{db} {fd_b}");
        assert!(db.norm() > 0.0);
    }
}
