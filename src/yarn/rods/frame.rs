//! Frames, parallel transport and the per-hinge bend/twist energy, generic
//! over the scalar type (see `dual`).

use super::dual::Real;
use crate::geom::vec3::{cross, norm, scale};
use crate::geom::Vec3;

pub(crate) type V<R> = [R; 3];

#[inline]
fn vsub<R: Real>(a: V<R>, b: V<R>) -> V<R> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn vadd<R: Real>(a: V<R>, b: V<R>) -> V<R> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
fn vmul<R: Real>(a: V<R>, s: R) -> V<R> {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
fn vdot<R: Real>(a: V<R>, b: V<R>) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn vcross<R: Real>(a: V<R>, b: V<R>) -> V<R> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// Dot product with a constant vector (cheaper than lifting it).
#[inline]
fn cdot<R: Real>(c: Vec3, a: V<R>) -> R {
    a[0].scale(c[0]) + a[1].scale(c[1]) + a[2].scale(c[2])
}
/// `c x a` with a constant `c`.
#[inline]
fn ccross<R: Real>(c: Vec3, a: V<R>) -> V<R> {
    [
        a[2].scale(c[1]) - a[1].scale(c[2]),
        a[0].scale(c[2]) - a[2].scale(c[0]),
        a[1].scale(c[0]) - a[0].scale(c[1]),
    ]
}
/// The rotation taking unit `a` to unit `b` about `a x b` (parallel
/// transport), applied to `u`: with `k = a x b`, `c = a . b`,
/// `P u = c u + k x u + (k . u) k / (1 + c)` (Rodrigues with `|k| = sin`).
/// Undefined for `b = -a`.
#[inline]
pub(crate) fn transport_gen<R: Real>(a: V<R>, b: V<R>, u: V<R>) -> V<R> {
    let c = vdot(a, b);
    let k = vcross(a, b);
    let s = vdot(k, u) / c.add_c(1.0);
    vadd(vadd(vmul(u, c), vcross(k, u)), vmul(k, s))
}

/// [`transport_gen`] from a constant tangent `a` with a constant vector `u`
/// to a variable tangent `b` (the time-parallel transport of a stored
/// reference director).
#[inline]
pub(crate) fn transport_from<R: Real>(a: Vec3, b: V<R>, u: Vec3) -> V<R> {
    let c = cdot(a, b);
    let k = ccross(a, b);
    // k x u with constant u: -(u x k).
    let kxu = ccross(u, k);
    let s = cdot(u, k) / c.add_c(1.0);
    [
        c.scale(u[0]) - kxu[0] + k[0] * s,
        c.scale(u[1]) - kxu[1] + k[1] * s,
        c.scale(u[2]) - kxu[2] + k[2] * s,
    ]
}

/// Plain `f64` parallel transport (see [`transport_gen`]).
pub(crate) fn transport(a: Vec3, b: Vec3, u: Vec3) -> Vec3 {
    transport_gen::<f64>(a, b, u)
}

/// A unit vector perpendicular to the unit vector `t`.
pub(crate) fn perpendicular(t: Vec3) -> Vec3 {
    // Cross with the axis least aligned with t.
    let ax = t.map(f64::abs);
    let axis = if ax[0] <= ax[1] && ax[0] <= ax[2] {
        [1.0, 0.0, 0.0]
    } else if ax[1] <= ax[2] {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let p = cross(t, axis);
    scale(p, 1.0 / norm(p))
}

/// Unit tangent of `e`.
#[inline]
pub(crate) fn unit<R: Real>(e: V<R>) -> (V<R>, R) {
    let l = vdot(e, e).sqrt();
    let inv = R::cst(1.0) / l;
    (vmul(e, inv), l)
}

/// One edge with its frames: edge vector `e`, length `l`, unit tangent `t`,
/// reference frame `(u, v = t x u)`, twist angle `theta` and material frame
/// `m1 = cos(theta) u + sin(theta) v`, `m2 = -sin(theta) u + cos(theta) v`.
#[derive(Clone, Copy)]
pub(crate) struct EdgeFrame<R: Real> {
    pub e: V<R>,
    pub l: R,
    pub t: V<R>,
    pub u: V<R>,
    pub v: V<R>,
    pub theta: R,
    pub m1: V<R>,
    pub m2: V<R>,
}

impl<R: Real> EdgeFrame<R> {
    #[inline]
    pub fn new(e: V<R>, l: R, t: V<R>, u: V<R>, theta: R) -> Self {
        let v = vcross(t, u);
        let (s, c) = theta.sin_cos();
        EdgeFrame {
            e,
            l,
            t,
            u,
            v,
            theta,
            m1: vadd(vmul(u, c), vmul(v, s)),
            m2: vsub(vmul(v, c), vmul(u, s)),
        }
    }

    /// The same frame with every scalar mapped by `f` (changes the dual
    /// number type).
    #[inline]
    pub fn map<S: Real>(&self, f: impl Fn(&R) -> S) -> EdgeFrame<S> {
        let m = |x: &V<R>| [f(&x[0]), f(&x[1]), f(&x[2])];
        EdgeFrame {
            e: m(&self.e),
            l: f(&self.l),
            t: m(&self.t),
            u: m(&self.u),
            v: m(&self.v),
            theta: f(&self.theta),
            m1: m(&self.m1),
            m2: m(&self.m2),
        }
    }
}

/// The frame of edge vector `e` with twist `theta`, its reference director
/// the time-parallel transport of the stored `up` from the stored tangent
/// `tp` to the tangent of `e`.
#[inline]
pub(crate) fn edge_frame<R: Real>(e: V<R>, theta: R, tp: Vec3, up: Vec3) -> EdgeFrame<R> {
    let (t, l) = unit(e);
    let u = transport_from(tp, t, up);
    EdgeFrame::new(e, l, t, u, theta)
}

/// Bergou 2010 material curvatures of the hinge `(k1, k2)` in the frames of
/// edge `i - 1` and edge `i`, `kappa^(j) = (kb . m2^j, -kb . m1^j)` with the
/// curvature binormal `kb = 2 e_{i-1} x e_i / (|e_{i-1}| |e_i| + e_{i-1} .
/// e_i)` (Bergou 2008 Eq. 1), and the raw reference twist in `(-pi, pi]`:
/// the signed angle about `t_i` from the space-parallel transport of `u_{i-1}`
/// to edge `i` to `u_i` (Bergou 2008 §4.2.2 / §6).
#[inline]
pub(crate) fn hinge_terms<R: Real>(f0: &EdgeFrame<R>, f1: &EdgeFrame<R>) -> ([R; 4], R) {
    let den = f0.l * f1.l + vdot(f0.e, f1.e);
    let kb = vmul(vcross(f0.e, f1.e), R::cst(2.0) / den);
    let kappa = [
        vdot(kb, f0.m2),
        -vdot(kb, f0.m1),
        vdot(kb, f1.m2),
        -vdot(kb, f1.m1),
    ];
    let w = transport_gen(f0.t, f1.t, f0.u);
    // Angle from w to u1 about t1: sin = (w x u1) . t1 = -w . v1.
    let ref_twist = (-vdot(w, f1.v)).atan2(vdot(w, f1.u));
    (kappa, ref_twist)
}

/// Per-hinge constants of the bend/twist element.
#[derive(Debug, Clone, Copy)]
pub(crate) struct HingeConst {
    /// Stored tangents of the two edges at the last state update.
    pub tp: [Vec3; 2],
    /// Stored reference directors of the two edges.
    pub up: [Vec3; 2],
    pub kappa_bar: [f64; 4],
    pub m_bar: f64,
    /// Reference twist at the last state update (picks the branch).
    pub ref_prev: f64,
    /// Voronoi length `lbar = (l0_{i-1} + l0_i) / 2` (m).
    pub lbar: f64,
    /// Bending stiffness (N m^2).
    pub bend: f64,
    /// Twist stiffness (N m^2).
    pub twist: f64,
}

/// Unwraps a raw angle to the branch nearest `prev` (the offset is a
/// constant, so derivatives are untouched).
#[inline]
pub(crate) fn unwrap_near<R: Real>(raw: R, prev: f64) -> R {
    let tau = std::f64::consts::TAU;
    let k = ((prev - raw.val()) / tau).round();
    raw.add_c(k * tau)
}

/// The hinge's strains minus their rest values, `d = (kappa^(0) -
/// kappa_bar^(0), kappa^(1) - kappa_bar^(1), m - m_bar)` (four curvature
/// components, then the twist), and the unwrapped reference twist.
#[inline]
pub(crate) fn hinge_strains<R: Real>(
    f0: &EdgeFrame<R>,
    f1: &EdgeFrame<R>,
    c: &HingeConst,
) -> ([R; 5], R) {
    let (kappa, raw) = hinge_terms(f0, f1);
    let reft = unwrap_near(raw, c.ref_prev);
    let m = (f1.theta - f0.theta + reft).add_c(-c.m_bar);
    let d = [
        kappa[0].add_c(-c.kappa_bar[0]),
        kappa[1].add_c(-c.kappa_bar[1]),
        kappa[2].add_c(-c.kappa_bar[2]),
        kappa[3].add_c(-c.kappa_bar[3]),
        m,
    ];
    (d, reft)
}

impl HingeConst {
    /// The weights `w` of `E_b + E_t = sum_k w_k d_k^2` over the strains of
    /// [`hinge_strains`]: `B / (4 lbar)` for the curvatures, `beta / (2
    /// lbar)` for the twist (J per strain^2).
    pub fn strain_weights(&self) -> [f64; 5] {
        let (wb, wt) = (0.25 * self.bend / self.lbar, 0.5 * self.twist / self.lbar);
        [wb, wb, wb, wb, wt]
    }
}

/// Bend and twist energies (J) of one hinge from its two edge frames (edge vectors
/// and twist angles), with the reference directors time-parallel
/// transported from the stored state to the current tangents:
///
/// `E_b = 1/(2 lbar) sum_j 1/2 B |kappa^(j) - kappa_bar^(j)|^2` (Bergou 2010,
/// isotropic B), `E_t = beta (m - m_bar)^2 / (2 lbar)` with
/// `m = theta_i - theta_{i-1} + reference twist` (Bergou 2008 §4.2.2).
/// Also returns the (unwrapped) reference twist.
#[inline]
pub(crate) fn hinge_energy_frames<R: Real>(
    f0: &EdgeFrame<R>,
    f1: &EdgeFrame<R>,
    c: &HingeConst,
) -> (R, R, R) {
    let (d, reft) = hinge_strains(f0, f1, c);
    let (bend, twist) = strain_energies(&d, c);
    (bend, twist, reft)
}

/// Bend and twist energies (J) of the strains `d` of [`hinge_strains`].
#[inline]
pub(crate) fn strain_energies<R: Real>(d: &[R; 5], c: &HingeConst) -> (R, R) {
    let mut sq = R::cst(0.0);
    for dk in &d[..4] {
        sq = sq + *dk * *dk;
    }
    let w = c.strain_weights();
    (sq.scale(w[0]), (d[4] * d[4]).scale(w[4]))
}
