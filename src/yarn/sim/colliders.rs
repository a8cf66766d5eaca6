//! Point colliders: vertices are kept at least their yarn radius outside.
//! A triangle-mesh collider (sim::collide) plugs in through [`PointCollider`].

use crate::geom::Vec3;

/// A collider queried per vertex.
pub trait PointCollider: Send + Sync + std::fmt::Debug {
    /// Signed distance (m, positive outside) of `p` from the surface at time
    /// `t`, and the outward unit normal of the closest surface point.
    fn signed_distance(&self, p: Vec3, t: f64) -> (f64, Vec3);
    /// Velocity of the surface near `p` at time `t` (m/s). Default: at rest.
    fn velocity(&self, _p: Vec3, _t: f64) -> Vec3 {
        [0.0; 3]
    }
    /// Coulomb friction coefficient mu (dimensionless, >= 0) between the
    /// surface and a yarn vertex: on contact the tangential relative
    /// velocity is removed when it is within `mu` times the normal velocity
    /// change (stick), else reduced by that much (slide; Bridson et al.
    /// 2002 §7.2). Default 0: frictionless.
    fn friction(&self) -> f64 {
        0.0
    }
}

/// An infinite plane through `point` with outward `normal`.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneCollider {
    pub point: Vec3,
    /// Outward normal (normalized on use).
    pub normal: Vec3,
    /// Coulomb coefficient mu, see [`PointCollider::friction`]. Default 0.
    pub friction: f64,
}

impl PointCollider for PlaneCollider {
    fn signed_distance(&self, p: Vec3, _t: f64) -> (f64, Vec3) {
        let n = self.normal;
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-300);
        let n = [n[0] / l, n[1] / l, n[2] / l];
        let d = (p[0] - self.point[0]) * n[0]
            + (p[1] - self.point[1]) * n[1]
            + (p[2] - self.point[2]) * n[2];
        (d, n)
    }
    fn friction(&self) -> f64 {
        self.friction
    }
}

/// A sphere whose centre moves at constant `velocity` from `center` at t = 0.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereCollider {
    pub center: Vec3,
    /// Radius (m).
    pub radius: f64,
    /// Centre velocity (m/s). Default 0.
    pub velocity: Vec3,
    /// Coulomb coefficient mu, see [`PointCollider::friction`]. Default 0.
    pub friction: f64,
}

impl PointCollider for SphereCollider {
    fn signed_distance(&self, p: Vec3, t: f64) -> (f64, Vec3) {
        let c = [
            self.center[0] + t * self.velocity[0],
            self.center[1] + t * self.velocity[1],
            self.center[2] + t * self.velocity[2],
        ];
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if l > 0.0 {
            (l - self.radius, [d[0] / l, d[1] / l, d[2] / l])
        } else {
            (-self.radius, [0.0, 1.0, 0.0])
        }
    }
    fn velocity(&self, _p: Vec3, _t: f64) -> Vec3 {
        self.velocity
    }
    fn friction(&self) -> f64 {
        self.friction
    }
}

/// Pushes a vertex of radius `r` out of the collider, removes the inward
/// normal relative velocity and applies Coulomb friction with the
/// collider's `mu` as a velocity-level impulse cap (Bridson et al. 2002
/// §7.2): with `dvn` the normal velocity removed, a tangential relative
/// velocity `vt` with `|vt| <= mu dvn` is removed (stick), a larger one
/// shortened by `mu dvn` (slide). The position, just advanced by `dt` with
/// the old velocity, is corrected by `dt` times the tangential change, so
/// that it moved with the new velocity (a sticking vertex does not creep).
/// Returns whether the vertex was in contact.
pub(crate) fn resolve(
    c: &dyn PointCollider,
    x: &mut Vec3,
    v: &mut Vec3,
    r: f64,
    t: f64,
    dt: f64,
) -> bool {
    let (sd, n) = c.signed_distance(*x, t);
    if !(sd < r) {
        return false;
    }
    let push = r - sd;
    for i in 0..3 {
        x[i] += push * n[i];
    }
    let vc = c.velocity(*x, t);
    let rel = [v[0] - vc[0], v[1] - vc[1], v[2] - vc[2]];
    let vn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2];
    let dvn = -vn.min(0.0);
    let tan = [rel[0] - vn * n[0], rel[1] - vn * n[1], rel[2] - vn * n[2]];
    let vt = (tan[0] * tan[0] + tan[1] * tan[1] + tan[2] * tan[2]).sqrt();
    let cap = c.friction().max(0.0) * dvn;
    // Fraction of the tangential velocity kept.
    let keep = if vt <= cap { 0.0 } else { 1.0 - cap / vt };
    for i in 0..3 {
        let dvt = (keep - 1.0) * tan[i];
        v[i] = vc[i] + keep * tan[i] + (vn + dvn) * n[i];
        x[i] += dt * dvt;
    }
    true
}
