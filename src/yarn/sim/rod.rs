//! Intrinsic rod energies on polyline yarns: stretching and bending with rest
//! curvature (HYLC §5.1, Eq. 23: DER-style discrete rods, Bergou et al.
//! 2008; twist is not modelled).
//!
//! * Stretch per segment: `E_s = 1/2 E A l0 (|e| / l0 - 1)^2`.
//! * Bending per hinge: `E_b = 1/2 gamma E I (kappa - kappa0)^2 / lbar` with
//!   the discrete curvature `kappa = 2 tan(phi / 2)` (|kappa b| of Bergou
//!   2008), `phi` the turning angle, `lbar` half the sum of the adjacent rest
//!   lengths. The unsigned rest curvature keeps the energy frame-free (no
//!   twist variables), as Kaldor's unsigned curvature (Leaf Eq. 7) does; its
//!   gradient is continuous except where a rest-curved hinge is exactly
//!   straight (a set of measure zero, where we take the zero subgradient).

use super::model::{Hinge, Seg};
use crate::geom::vec3::{cross, dot, norm, scale, sub};
use crate::geom::Vec3;

/// Stretch energy and the forces `-dE/dx` on the two ends.
#[inline]
pub(crate) fn stretch(s: &Seg, x: &[Vec3]) -> (f64, [Vec3; 2]) {
    let e = sub(x[s.v[1] as usize], x[s.v[0] as usize]);
    let l = norm(e);
    let strain = l / s.l0 - 1.0;
    let energy = 0.5 * s.ks * s.l0 * strain * strain;
    // dE/dx1 = ks * strain * e / l.
    let g = if l > 0.0 {
        scale(e, s.ks * strain / l)
    } else {
        [0.0; 3]
    };
    (energy, [g, scale(g, -1.0)])
}

/// Bending energy and the forces `-dE/dx` on the three hinge vertices.
#[inline]
pub(crate) fn bend(h: &Hinge, x: &[Vec3]) -> (f64, [Vec3; 3]) {
    let (x0, x1, x2) = (x[h.v[0] as usize], x[h.v[1] as usize], x[h.v[2] as usize]);
    let e0 = sub(x1, x0);
    let e1 = sub(x2, x1);
    let (n0, n1) = (norm(e0), norm(e1));
    if !(n0 > 0.0 && n1 > 0.0) {
        return (0.0, [[0.0; 3]; 3]);
    }
    let t0 = scale(e0, 1.0 / n0);
    let t1 = scale(e1, 1.0 / n1);
    let c = dot(t0, t1);
    let sn = norm(cross(t0, t1));
    let kappa = 2.0 * sn / (1.0 + c);
    let d = kappa - h.kappa0;
    let energy = h.coef * d * d;
    // dE/dphi = 2 coef (kappa - kappa0) dkappa/dphi, dkappa/dphi = 1 + kappa^2/4.
    let de_dphi = 2.0 * h.coef * d * (1.0 + 0.25 * kappa * kappa);
    // Unit vectors u0 = (t1 - c t0)/sin, u1 = (t0 - c t1)/sin.
    let u0 = sub(t1, scale(t0, c));
    let u1 = sub(t0, scale(t1, c));
    let nu = norm(u0);
    if !(nu > 1e-14) || de_dphi == 0.0 {
        return (energy, [[0.0; 3]; 3]);
    }
    // dphi/de0 = -u0 / (n0 sin), dphi/de1 = -u1 / (n1 sin); |u0| = |u1| = sin.
    let g_e0 = scale(u0, -de_dphi / (n0 * nu));
    let g_e1 = scale(u1, -de_dphi / (n1 * nu));
    // x0: -dE/de0; x1: dE/de0 - dE/de1; x2: dE/de1. Forces are the negatives.
    let f0 = g_e0;
    let f1 = sub(g_e1, g_e0);
    let f2 = scale(g_e1, -1.0);
    (energy, [f0, f1, f2])
}
