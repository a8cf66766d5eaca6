//! Curve helpers shared by the knit and woven tile builders.

use std::f64::consts::PI;

use crate::geom::Vec3;

/// Samples a smooth curve `f(t)`, `t` in `[t0, t1)`, at (nearly) equal arc
/// length with segments of at most `spacing` (end point excluded, so the next
/// piece starts there). Returns the points and the arc length.
pub(crate) fn sample_equal_arclength(
    f: impl Fn(f64) -> Vec3,
    t0: f64,
    t1: f64,
    spacing: f64,
    min_points: usize,
) -> (Vec<Vec3>, f64) {
    const DENSE: usize = 512;
    let mut ts = Vec::with_capacity(DENSE + 1);
    let mut cum = Vec::with_capacity(DENSE + 1);
    let mut prev = f(t0);
    let mut len = 0.0;
    for k in 0..=DENSE {
        let t = t0 + (t1 - t0) * k as f64 / DENSE as f64;
        let p = f(t);
        len += crate::geom::dist(prev, p);
        prev = p;
        ts.push(t);
        cum.push(len);
    }
    let n = ((len / spacing).ceil() as usize).max(min_points);
    let mut out = Vec::with_capacity(n);
    let mut seg = 0;
    for k in 0..n {
        let target = len * k as f64 / n as f64;
        while seg + 1 < DENSE && cum[seg + 1] < target {
            seg += 1;
        }
        let (a, b) = (cum[seg], cum[seg + 1]);
        let w = if b > a { (target - a) / (b - a) } else { 0.0 };
        out.push(f(ts[seg] + w * (ts[seg + 1] - ts[seg])));
    }
    (out, len)
}

/// Cosine easing from `z0` (at f = 0) to `z1` (at f = 1), flat at both ends.
pub(crate) fn ease(z0: f64, z1: f64, f: f64) -> f64 {
    let f = f.clamp(0.0, 1.0);
    z0 + (z1 - z0) * (0.5 - 0.5 * (PI * f).cos())
}
