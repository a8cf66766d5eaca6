//! Damping (Leaf Eq. 11-12).
//!
//! * Global, mass-proportional damping (Leaf Eq. 11, lumped): force
//!   `-c m v` per vertex. It is integrated implicitly,
//!   `v <- (v + dt a) / (1 + c dt)`, so it never limits the time step and
//!   only ever shrinks the step's displacement (the Leaf Eq. 2 bound holds).
//! * Contact damping (Leaf Eq. 12) lives in the contact kernel
//!   ([`super::contact`]) because it shares the sample-pair loop: for sample
//!   pairs closer than the contact distance,
//!   `F_A = 2 w w' (k_dt dv - (k_dt - k_dn) n (n . dv))`, `dv = v_B - v_A`,
//!   the negative velocity gradient of Leaf's dissipation D as printed.
//!   It is explicit; its coefficient enters the step bound.

use crate::geom::Vec3;

/// Implicit global damping update of one velocity: `(v + dt a) / (1 + c dt)`.
#[inline]
pub(crate) fn damped_velocity(v: Vec3, a: Vec3, dt: f64, c: f64) -> Vec3 {
    let s = 1.0 / (1.0 + c * dt);
    [
        (v[0] + dt * a[0]) * s,
        (v[1] + dt * a[1]) * s,
        (v[2] + dt * a[2]) * s,
    ]
}

/// Largest explicit step for a vertex of mass `m` with contact damping
/// coefficient `c` (kg/s): symplectic Euler on `m v' = -c v` is stable for
/// `dt < 2 m / c`.
#[inline]
pub(crate) fn damping_dt_limit(m: f64, c: f64) -> f64 {
    if c > 0.0 {
        2.0 * m / c
    } else {
        f64::INFINITY
    }
}
