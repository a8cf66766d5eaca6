//! Yarn-yarn contact (Leaf Eq. 9-10, Kaldor et al. 2008) on linear segments,
//! with contact damping (Leaf Eq. 12) and a spatial hash whose candidate
//! pairs are reused while the accumulated motion stays under the skin.
//!
//! Energy of a segment pair (A, B):
//! `E = k_c * sum_k sum_m wA_k wB_m f(|pA_k - pB_m| / (rA + rB))`,
//! `f(d) = 1/d^2 + d^2 - 2` for d < 1, else 0, with Simpson weights over the
//! rest arclength (the quadrature of Leaf Eq. 9 with N_S odd, §3.1).
//! The quadrature *is* the discrete energy, so forces are its exact gradient.

use rayon::prelude::*;

use super::model::{CSeg, Model};
use crate::geom::vec3::{axpy, dot, norm, scale, sub};
use crate::geom::Vec3;

/// One candidate pair of contact segments with its weight (1 for two real
/// segments, 1/2 for a real-ghost pair, which the tile also sees mirrored).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pair {
    pub a: u32,
    pub b: u32,
    pub w: f64,
}

/// Per-pair results of one evaluation (kept only for pairs in contact).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PairOut {
    /// Index of the pair in `ContactSet::pairs`.
    pub pair: u32,
    pub f: [Vec3; 4],
    pub energy: f64,
    /// Gershgorin row sums of the contact stiffness for the 4 vertices (N/m).
    pub stiff: [f64; 4],
    /// Row sums of the contact damping matrix for the 4 vertices (kg/s).
    pub damp: [f64; 4],
    /// Closest distance / (rA + rB).
    pub ratio: f64,
}

/// The candidate pair list and its reuse bookkeeping.
#[derive(Debug, Clone, Default)]
pub(crate) struct ContactSet {
    pub pairs: Vec<Pair>,
    /// Results of the pairs in contact at the last evaluation, in pair order.
    pub active: Vec<PairOut>,
    /// Minimum closest distance / (rA + rB) over all candidate pairs at the
    /// last evaluation (a lower bound where above 1).
    pub min_ratio: f64,
    /// Accumulated maximum vertex motion since the last build (m).
    pub acc_motion: f64,
    /// Skin (m): pairs are found within `rA + rB + 2 skin`.
    pub skin: f64,
    pub builds: u64,
    pub valid: bool,
}

/// Closest distance between segments [p0, p1] and [q0, q1] (Ericson 2005, §5.1.9).
pub fn segment_distance(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> f64 {
    let (s, t) = segment_closest_params(p0, p1, q0, q1);
    let (d1, d2) = (sub(p1, p0), sub(q1, q0));
    let cp = [p0[0] + d1[0] * s, p0[1] + d1[1] * s, p0[2] + d1[2] * s];
    let cq = [q0[0] + d2[0] * t, q0[1] + d2[1] * t, q0[2] + d2[2] * t];
    norm(sub(cp, cq))
}

/// Parameters `(s, t)` in [0, 1] of the closest points `p0 + s (p1 - p0)`
/// and `q0 + t (q1 - q0)` of two segments (Ericson 2005, §5.1.9; parallel
/// segments get `s = 0` or an end clamp).
#[inline]
pub fn segment_closest_params(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> (f64, f64) {
    let d1 = sub(p1, p0);
    let d2 = sub(q1, q0);
    let r = sub(p0, q0);
    let a = dot(d1, d1);
    let e = dot(d2, d2);
    let f = dot(d2, r);
    if a <= 1e-300 && e <= 1e-300 {
        return (0.0, 0.0);
    }
    if a <= 1e-300 {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = dot(d1, r);
    if e <= 1e-300 {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = dot(d1, d2);
    let denom = a * e - b * b;
    let mut s0 = if denom > 1e-14 * a * e {
        ((b * f - c * e) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut t0 = (b * s0 + f) / e;
    if t0 < 0.0 {
        t0 = 0.0;
        s0 = (-c / a).clamp(0.0, 1.0);
    } else if t0 > 1.0 {
        t0 = 1.0;
        s0 = ((b - c) / a).clamp(0.0, 1.0);
    }
    (s0, t0)
}

/// Simpson weights on [0, 1] for `n` (odd) samples.
pub(crate) fn simpson(n: usize) -> Vec<f64> {
    let h = 1.0 / (n - 1) as f64;
    (0..n)
        .map(|k| {
            let m = if k == 0 || k == n - 1 {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            };
            m * h / 3.0
        })
        .collect()
}

const CELL_BITS: u32 = 21;
const CELL_BIAS: i64 = 1 << 20;

#[inline]
fn cell_key(c: [i64; 3]) -> u64 {
    let m = (1i64 << CELL_BITS) - 1;
    let f = |v: i64| ((v + CELL_BIAS).clamp(0, m)) as u64;
    (f(c[0]) << (2 * CELL_BITS)) | (f(c[1]) << CELL_BITS) | f(c[2])
}

impl ContactSet {
    /// Rebuilds the candidate pairs from the current extended positions.
    pub fn build(&mut self, model: &Model, x: &[Vec3]) {
        let cs = &model.csegs;
        let mut r_max: f64 = 0.0;
        let mut l_max: f64 = 0.0;
        for c in cs {
            r_max = r_max.max(c.radius);
        }
        let mids: Vec<(Vec3, f64)> = cs
            .iter()
            .map(|c| {
                let (a, b) = (x[c.v[0] as usize], x[c.v[1] as usize]);
                let l = norm(sub(b, a));
                (
                    [
                        0.5 * (a[0] + b[0]),
                        0.5 * (a[1] + b[1]),
                        0.5 * (a[2] + b[2]),
                    ],
                    l,
                )
            })
            .collect();
        for m in &mids {
            l_max = l_max.max(m.1);
        }
        // Two segments closer than D have midpoints closer than D + l_max.
        let reach = 2.0 * r_max + 2.0 * self.skin;
        let h = reach + l_max;
        let cell_of = |p: Vec3| -> [i64; 3] {
            [
                (p[0] / h).floor() as i64,
                (p[1] / h).floor() as i64,
                (p[2] / h).floor() as i64,
            ]
        };
        let mut keys: Vec<(u64, u32)> = mids
            .iter()
            .enumerate()
            .map(|(i, m)| (cell_key(cell_of(m.0)), i as u32))
            .collect();
        keys.par_sort_unstable();
        // Occupied cells (runs of one key) and, once per cell, the key
        // ranges of its 3 x 3 neighbour columns (the three z-neighbours are
        // contiguous in key order): every segment of a cell shares them.
        let mut cell_start: Vec<usize> = Vec::new();
        let mut seg_cell = vec![0u32; keys.len()];
        for (k, &(key, seg)) in keys.iter().enumerate() {
            if k == 0 || key != keys[k - 1].0 {
                cell_start.push(k);
            }
            seg_cell[seg as usize] = (cell_start.len() - 1) as u32;
        }
        let neighbour_ranges: Vec<[(usize, usize); 9]> = cell_start
            .par_iter()
            .map(|&k| {
                let c = cell_of(mids[keys[k].1 as usize].0);
                let mut out = [(0, 0); 9];
                for (slot, (dx, dy)) in (-1..=1)
                    .flat_map(|dx| (-1..=1).map(move |dy| (dx, dy)))
                    .enumerate()
                {
                    let k0 = cell_key([c[0] + dx, c[1] + dy, c[2] - 1]);
                    let k1 = cell_key([c[0] + dx, c[1] + dy, c[2] + 1]);
                    let start = keys.partition_point(|e| e.0 < k0);
                    let end = start + keys[start..].partition_point(|e| e.0 <= k1);
                    out[slot] = (start, end);
                }
                out
            })
            .collect();
        let skin = self.skin;
        let n_real_segs = cs.iter().take_while(|c| c.real).count();
        let lists: Vec<Vec<Pair>> = (0..n_real_segs)
            .into_par_iter()
            .map(|i| {
                let ci = &cs[i];
                let mut out = Vec::new();
                for &(start, end) in &neighbour_ranges[seg_cell[i] as usize] {
                    for &(_, j) in &keys[start..end] {
                        let cj = &cs[j as usize];
                        if cj.real && j as usize <= i {
                            continue;
                        }
                        // Midpoints farther than the reach plus the half
                        // lengths: the segments are farther than the reach.
                        let (mi, mj) = (&mids[i], &mids[j as usize]);
                        let lim = ci.radius + cj.radius + 2.0 * skin + 0.5 * (mi.1 + mj.1);
                        let dm = sub(mi.0, mj.0);
                        if dot(dm, dm) >= lim * lim {
                            continue;
                        }
                        if model.excluded(ci, cj) {
                            continue;
                        }
                        let d = segment_distance(
                            x[ci.v[0] as usize],
                            x[ci.v[1] as usize],
                            x[cj.v[0] as usize],
                            x[cj.v[1] as usize],
                        );
                        if d < ci.radius + cj.radius + 2.0 * skin {
                            out.push(Pair {
                                a: i as u32,
                                b: j,
                                w: if cj.real { 1.0 } else { 0.5 },
                            });
                        }
                    }
                }
                // Deterministic order independent of the cell visiting order.
                out.sort_by_key(|p| p.b);
                out
            })
            .collect();
        self.pairs = lists.concat();
        self.acc_motion = 0.0;
        self.builds += 1;
        self.valid = true;
    }

    /// Evaluates every pair (energy, forces, damping, stiffness bound, distance).
    pub fn eval(
        &mut self,
        model: &Model,
        x: &[Vec3],
        v: Option<&[Vec3]>,
        k_contact: f64,
        k_dn: f64,
        k_dt: f64,
    ) {
        let cs = &model.csegs;
        let ns = model.n_samples;
        let w = simpson(ns);
        let s: Vec<f64> = (0..ns).map(|k| k as f64 / (ns - 1) as f64).collect();
        // Only pairs in contact carry forces: keep those (in pair order, so
        // the result does not depend on how rayon splits the work).
        let (active, min_ratio) = self
            .pairs
            .par_iter()
            .enumerate()
            .with_min_len(256)
            .fold(
                || (Vec::new(), f64::INFINITY),
                |(mut acc, m), (i, p)| {
                    let mut o = pair_eval(
                        &cs[p.a as usize],
                        &cs[p.b as usize],
                        p.w,
                        x,
                        v,
                        &w,
                        &s,
                        k_contact,
                        k_dn,
                        k_dt,
                    );
                    let m = m.min(o.ratio);
                    if o.ratio < 1.0 {
                        o.pair = i as u32;
                        acc.push(o);
                    }
                    (acc, m)
                },
            )
            .reduce(
                || (Vec::new(), f64::INFINITY),
                |(mut a, ma), (mut b, mb)| {
                    a.append(&mut b);
                    (a, ma.min(mb))
                },
            );
        self.active = active;
        self.min_ratio = min_ratio;
    }
}

#[allow(clippy::too_many_arguments)]
#[inline]
fn pair_eval(
    a: &CSeg,
    b: &CSeg,
    pw: f64,
    x: &[Vec3],
    v: Option<&[Vec3]>,
    w: &[f64],
    s: &[f64],
    kc: f64,
    k_dn: f64,
    k_dt: f64,
) -> PairOut {
    let (a0, a1) = (x[a.v[0] as usize], x[a.v[1] as usize]);
    let (b0, b1) = (x[b.v[0] as usize], x[b.v[1] as usize]);
    let rsum = a.radius + b.radius;
    // Cheap rejection: midpoint distance minus half lengths bounds the
    // segment distance from below.
    let da = sub(a1, a0);
    let db = sub(b1, b0);
    let mid = [
        0.5 * (a0[0] + a1[0] - b0[0] - b1[0]),
        0.5 * (a0[1] + a1[1] - b0[1] - b1[1]),
        0.5 * (a0[2] + a1[2] - b0[2] - b1[2]),
    ];
    let reach = rsum + 0.5 * (norm(da) + norm(db));
    let m2 = dot(mid, mid);
    if m2 >= reach * reach {
        let lower = m2.sqrt() - 0.5 * (norm(da) + norm(db));
        return PairOut {
            ratio: lower / rsum,
            ..PairOut::default()
        };
    }
    let dist = segment_distance(a0, a1, b0, b1);
    let mut o = PairOut {
        ratio: dist / rsum,
        ..PairOut::default()
    };
    if dist >= rsum {
        return o;
    }
    let ns = s.len();
    let inv_r = 1.0 / rsum;
    let mut e = 0.0;
    let mut stiff = [0.0; 4];
    let mut damp = [0.0; 4];
    let (mut fa0, mut fa1, mut fb0, mut fb1) = ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]);
    let vel = v.map(|v| {
        (
            v[a.v[0] as usize],
            v[a.v[1] as usize],
            v[b.v[0] as usize],
            v[b.v[1] as usize],
        )
    });
    let cw = pw * a.l0 * b.l0;
    for k in 0..ns {
        let sk = s[k];
        let pa = [a0[0] + sk * da[0], a0[1] + sk * da[1], a0[2] + sk * da[2]];
        // Skip samples of A farther than rsum from the whole segment B.
        for m in 0..ns {
            let tm = s[m];
            let pb = [b0[0] + tm * db[0], b0[1] + tm * db[1], b0[2] + tm * db[2]];
            let dvec = sub(pa, pb);
            let d2 = dot(dvec, dvec) * inv_r * inv_r;
            if d2 >= 1.0 {
                continue;
            }
            let d = d2.sqrt();
            let ww = cw * w[k] * w[m];
            let inv_d2 = 1.0 / d2;
            e += ww * (inv_d2 + d2 - 2.0);
            // f'(d) = -2/d^3 + 2d; force on pa = -k ww f'(d) / rsum * dvec/|dvec|.
            let fp = -2.0 * inv_d2 / d + 2.0 * d;
            let dn = d * rsum;
            let nhat = scale(dvec, 1.0 / dn);
            let fmag = -kc * ww * fp * inv_r;
            // Force on A sample along +nhat (pushes A away from B).
            let mut fs = scale(nhat, fmag);
            // Hessian norm of f(|pa - pb| / R) is at most f''/R^2 (f'' >= |f'|/d);
            // the sample pair couples 4 vertices with weights summing to 2.
            let ks = 2.0 * kc * ww * (6.0 * inv_d2 * inv_d2 + 2.0) * inv_r * inv_r;
            let shares = [1.0 - sk, sk, 1.0 - tm, tm];
            for q in 0..4 {
                stiff[q] += shares[q] * ks;
            }
            if let Some((va0, va1, vb0, vb1)) = vel {
                // Leaf Eq. 12: F_A = 2 ww (k_dt dv - (k_dt - k_dn) n (n . dv)), dv = vB - vA.
                let mut dv = [0.0; 3];
                for c in 0..3 {
                    dv[c] = (1.0 - tm) * vb0[c] + tm * vb1[c] - (1.0 - sk) * va0[c] - sk * va1[c];
                }
                let nd = dot(nhat, dv);
                let mut fd = scale(dv, 2.0 * ww * k_dt);
                axpy(&mut fd, -2.0 * ww * (k_dt - k_dn) * nd, nhat);
                fs[0] += fd[0];
                fs[1] += fd[1];
                fs[2] += fd[2];
                let cd = 2.0 * 2.0 * ww * k_dn.max(k_dt);
                for q in 0..4 {
                    damp[q] += shares[q] * cd;
                }
            }
            axpy(&mut fa0, 1.0 - sk, fs);
            axpy(&mut fa1, sk, fs);
            axpy(&mut fb0, -(1.0 - tm), fs);
            axpy(&mut fb1, -tm, fs);
        }
    }
    o.energy = kc * e;
    o.f = [fa0, fa1, fb0, fb1];
    o.stiff = stiff;
    o.damp = damp;
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_distance_matches_sampling() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for _ in 0..200 {
            let p: Vec<Vec3> = (0..4).map(|_| [rnd(), rnd(), rnd()]).collect();
            let d = segment_distance(p[0], p[1], p[2], p[3]);
            let mut best = f64::INFINITY;
            let n = 200;
            for i in 0..=n {
                let s = i as f64 / n as f64;
                let a = [
                    p[0][0] + s * (p[1][0] - p[0][0]),
                    p[0][1] + s * (p[1][1] - p[0][1]),
                    p[0][2] + s * (p[1][2] - p[0][2]),
                ];
                for j in 0..=n {
                    let t = j as f64 / n as f64;
                    let b = [
                        p[2][0] + t * (p[3][0] - p[2][0]),
                        p[2][1] + t * (p[3][1] - p[2][1]),
                        p[2][2] + t * (p[3][2] - p[2][2]),
                    ];
                    best = best.min(norm(sub(a, b)));
                }
            }
            assert!(d <= best + 1e-12, "{d} > sampled {best}");
            assert!(best - d < 1e-2, "{d} vs sampled {best}");
        }
        // Parallel segments.
        let d = segment_distance([0.0; 3], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [2.0, 1.0, 0.0]);
        assert!((d - 1.0).abs() < 1e-15);
    }

    #[test]
    fn simpson_weights_integrate_cubics() {
        for n in [3, 5, 9] {
            let w = simpson(n);
            let s: f64 = w.iter().sum();
            assert!((s - 1.0).abs() < 1e-14);
            let c: f64 = w
                .iter()
                .enumerate()
                .map(|(k, w)| w * (k as f64 / (n - 1) as f64).powi(3))
                .sum();
            assert!((c - 0.25).abs() < 1e-14);
        }
    }
}
