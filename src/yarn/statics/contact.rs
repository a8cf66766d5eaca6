//! Yarn-yarn contact for the quasi-static solver: exactly the Kaldor
//! potential of the explicit simulator (`yarn::sim::contact`; Leaf 2018 Eq.
//! 9-10, f(d) = 1/d^2 + d^2 - 2 for d = dist / (rA + rB) < 1, Simpson
//! samples over the rest arclength of both segments), with its gradient
//! and a PSD Hessian.
//!
//! Hessian: per sample pair with `u = pA - pB`, `phi(|u|) = k w f(|u|/R)`
//! has `d2phi/du2 = phi'' n n^T + (phi'/|u|) (I - n n^T)`. `f'' > 0`
//! everywhere, but `f' < 0` inside contact, so the transverse part is
//! negative: it is dropped (clamped at zero), leaving `phi'' n n^T`, mapped
//! to the four segment vertices through the sample weights
//! `(1 - s, s, -(1 - t), -t)`.
//!
//! Candidate pairs come from the simulator's spatial hash (same exclusion of
//! near neighbours along a yarn), rebuilt at every Newton iteration with a
//! skin at least the solver's displacement cap, so no pair can enter
//! contact unseen within an iteration.

use rayon::prelude::*;

use super::term::{EnergyTerm, Triplets};
use crate::geom::vec3::{dot, sub};
use crate::geom::{Vec3, Yarns};
use crate::yarn::sim::contact::{simpson, ContactSet};
use crate::yarn::sim::model::Model;
use crate::yarn::sim::{YarnSimError, YarnSimParams};

/// Kaldor contact over the position coordinates of `q`.
#[derive(Debug, Clone)]
pub struct ContactTerm {
    model: Model,
    set: ContactSet,
    /// Contact stiffness k_contact (J/m^2 = kg/s^2). Default from
    /// [`YarnSimParams`] (HYLC Table 1: 60).
    pub stiffness: f64,
    weights: Vec<f64>,
    samples: Vec<f64>,
    /// The position coordinates the candidate set was last built at (a
    /// rebuild at the same positions would find the same pairs).
    built_at: Vec<f64>,
}

/// Contact figures at a state.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ContactStats {
    /// Segment pairs closer than the sum of their radii.
    pub active_pairs: usize,
    /// `2 * active_pairs / vertices`.
    pub contacts_per_vertex: f64,
    /// Smallest closest distance / (rA + rB) over the candidate pairs.
    pub min_distance_ratio: f64,
    /// That pair's closest distance (m) and radius sum `rA + rB` (m), so
    /// a caller can say which radius would fit (not in reports, which
    /// give the ratio).
    #[serde(skip)]
    pub min_distance_m: f64,
    #[serde(skip)]
    pub min_distance_radius_sum_m: f64,
    /// Fraction of vertices within [`NEAR_FACTOR`] x (rA + rB) of a segment
    /// that is not their neighbour along the yarn (a relaxed knit's yarns
    /// lie against each other; the loose generated rib has ~3%).
    pub near_fraction: f64,
}

/// Fraction of a candidate pair's distance each of its vertices may move in
/// one solver iteration.
const MOVE_FRACTION: f64 = 0.45;

/// The "touching" tolerance of [`ContactStats::near_fraction`].
pub const NEAR_FACTOR: f64 = 1.02;

fn point_segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f64 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    let t = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let c = [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]];
    let d = sub(p, c);
    dot(d, d).sqrt()
}

fn points_of(q: &[f64], n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|v| [q[3 * v], q[3 * v + 1], q[3 * v + 2]])
        .collect()
}

impl ContactTerm {
    /// Contact between the segments of `yarns` (rest arclengths from its
    /// points), candidate pairs found within the radii plus `2 skin` (m).
    pub fn new(
        yarns: &Yarns,
        params: &YarnSimParams,
        skin: f64,
    ) -> Result<ContactTerm, YarnSimError> {
        let model = Model::from_yarns(yarns, params, None)?;
        let ns = model.n_samples;
        let mut set = ContactSet {
            skin: skin.max(params.contact_skin * model.r_min),
            ..ContactSet::default()
        };
        set.build(&model, &yarns.points);
        Ok(ContactTerm {
            stiffness: params.contact_stiffness,
            weights: simpson(ns),
            samples: (0..ns).map(|k| k as f64 / (ns - 1) as f64).collect(),
            built_at: yarns.points.iter().flatten().copied().collect(),
            model,
            set,
        })
    }

    /// Integrates over the given rest lengths (m) of the yarn segments
    /// `edges` (vertex pairs, in the yarns' segment order) instead of the
    /// lengths the term was built with, so the contact energy follows the
    /// rods' rest state (Leaf Eq. 9 integrates over rest arclength).
    pub fn set_rest_lengths(
        &mut self,
        edges: &[[usize; 2]],
        lengths: &[f64],
    ) -> Result<(), YarnSimError> {
        let bad = |message: String| YarnSimError::Param {
            name: "rest lengths",
            message,
        };
        if edges.len() != lengths.len() {
            return Err(bad(format!(
                "{} lengths for {} segments",
                lengths.len(),
                edges.len()
            )));
        }
        for c in self.model.csegs.iter_mut().filter(|c| c.real) {
            let s = c.base as usize;
            let same = edges
                .get(s)
                .is_some_and(|e| e[0] == c.v[0] as usize && e[1] == c.v[1] as usize);
            if !same || !(lengths[s] > 0.0 && lengths[s].is_finite()) {
                return Err(bad(format!(
                    "segment {s} does not match the contact segment {:?} or has length {}",
                    c.v,
                    lengths.get(s).copied().unwrap_or(f64::NAN)
                )));
            }
            c.l0 = lengths[s];
        }
        Ok(())
    }

    /// Active pairs, contacts per vertex and the minimum distance ratio at `q`.
    pub fn stats(&self, q: &[f64]) -> ContactStats {
        let n = self.model.n_real;
        let x = points_of(q, n);
        let cs = &self.model.csegs;
        let mut near = vec![false; n];
        let mut active = 0usize;
        let mut min_ratio = f64::INFINITY;
        let (mut min_d, mut min_rsum) = (f64::INFINITY, 0.0);
        for p in &self.set.pairs {
            let (a, b) = (&cs[p.a as usize], &cs[p.b as usize]);
            let [a0, a1] = [a.v[0] as usize, a.v[1] as usize];
            let [b0, b1] = [b.v[0] as usize, b.v[1] as usize];
            let rsum = a.radius + b.radius;
            let d = crate::yarn::sim::contact::segment_distance(x[a0], x[a1], x[b0], x[b1]);
            active += usize::from(d < rsum);
            if d / rsum < min_ratio {
                (min_ratio, min_d, min_rsum) = (d / rsum, d, rsum);
            }
            if d < NEAR_FACTOR * rsum {
                for (v, (s0, s1)) in [
                    (a0, (b0, b1)),
                    (a1, (b0, b1)),
                    (b0, (a0, a1)),
                    (b1, (a0, a1)),
                ] {
                    if v < n && point_segment_distance(x[v], x[s0], x[s1]) < NEAR_FACTOR * rsum {
                        near[v] = true;
                    }
                }
            }
        }
        ContactStats {
            active_pairs: active,
            contacts_per_vertex: 2.0 * active as f64 / n.max(1) as f64,
            min_distance_ratio: min_ratio,
            min_distance_m: min_d,
            min_distance_radius_sum_m: min_rsum,
            near_fraction: near.iter().filter(|&&b| b).count() as f64 / n.max(1) as f64,
        }
    }

    /// The pairs in contact at `q` (the candidate set as last built): their
    /// four vertices `(a0, a1, b0, b1)` and the contact gradient on them
    /// (`dE/dx`, 12 entries; the force on segment A is minus the sum of the
    /// first two 3-vectors). For the friction term's lagged normal forces.
    pub fn active_pair_gradients(&self, q: &[f64]) -> Vec<([usize; 4], [f64; 12])> {
        let x = points_of(q, self.model.n_real);
        (0..self.set.pairs.len())
            .filter_map(|i| self.pair(i, &x, None))
            .filter(|(_, ids, _)| ids.iter().all(|&v| v < self.model.n_real))
            .map(|(_, ids, g)| (ids, g))
            .collect()
    }

    /// Whether pair `pi` is in contact at `x` (what [`Self::pair`] tests first).
    fn touching(&self, pi: usize, x: &[Vec3]) -> bool {
        let p = self.set.pairs[pi];
        let cs = &self.model.csegs;
        let (a, b) = (&cs[p.a as usize], &cs[p.b as usize]);
        let v = [a.v[0], a.v[1], b.v[0], b.v[1]].map(|v| x[v as usize]);
        crate::yarn::sim::contact::segment_distance(v[0], v[1], v[2], v[3]) < a.radius + b.radius
    }

    /// Energy and the 12 gradient entries of one pair in contact (`None`
    /// when it is not), and with `h` its 12x12 PSD Hessian (row-major,
    /// overwritten).
    fn pair(
        &self,
        pi: usize,
        x: &[Vec3],
        mut h: Option<&mut [f64; 144]>,
    ) -> Option<(f64, [usize; 4], [f64; 12])> {
        let p = self.set.pairs[pi];
        let cs = &self.model.csegs;
        let (a, b) = (&cs[p.a as usize], &cs[p.b as usize]);
        let ids = [
            a.v[0] as usize,
            a.v[1] as usize,
            b.v[0] as usize,
            b.v[1] as usize,
        ];
        let (a0, a1, b0, b1) = (x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]]);
        let rsum = a.radius + b.radius;
        if crate::yarn::sim::contact::segment_distance(a0, a1, b0, b1) >= rsum {
            return None;
        }
        let (da, db) = (sub(a1, a0), sub(b1, b0));
        let inv_r = 1.0 / rsum;
        let cw = self.stiffness * p.w * a.l0 * b.l0;
        let mut e = 0.0;
        let mut g = [0.0; 12];
        if let Some(h) = h.as_deref_mut() {
            h.fill(0.0);
        }
        for (k, &sk) in self.samples.iter().enumerate() {
            let pa = [a0[0] + sk * da[0], a0[1] + sk * da[1], a0[2] + sk * da[2]];
            for (m, &tm) in self.samples.iter().enumerate() {
                let pb = [b0[0] + tm * db[0], b0[1] + tm * db[1], b0[2] + tm * db[2]];
                let u = sub(pa, pb);
                let d2 = dot(u, u) * inv_r * inv_r;
                if d2 >= 1.0 {
                    continue;
                }
                let d = d2.sqrt();
                let ww = cw * self.weights[k] * self.weights[m];
                e += ww * (1.0 / d2 + d2 - 2.0);
                // dphi/du = ww f'(d) / R * n, n = u / |u|.
                let fp = -2.0 / (d2 * d) + 2.0 * d;
                let fpp = 6.0 / (d2 * d2) + 2.0;
                let dist = d * rsum;
                let nrm = [u[0] / dist, u[1] / dist, u[2] / dist];
                let gu = ww * fp * inv_r;
                let hu = ww * fpp * inv_r * inv_r;
                let sh = [1.0 - sk, sk, -(1.0 - tm), -tm];
                for (j, &s) in sh.iter().enumerate() {
                    for c in 0..3 {
                        g[3 * j + c] += s * gu * nrm[c];
                    }
                }
                if let Some(h) = h.as_deref_mut() {
                    for (j1, &s1) in sh.iter().enumerate() {
                        for (j2, &s2) in sh.iter().enumerate() {
                            let f = s1 * s2 * hu;
                            for c1 in 0..3 {
                                for c2 in 0..3 {
                                    h[(3 * j1 + c1) * 12 + 3 * j2 + c2] += f * nrm[c1] * nrm[c2];
                                }
                            }
                        }
                    }
                }
            }
        }
        Some((e, ids, g))
    }
}

impl EnergyTerm for ContactTerm {
    fn name(&self) -> &'static str {
        "contact"
    }

    fn eval(&self, q: &[f64], grad: &mut [f64], hess: Option<&mut Triplets>) -> f64 {
        let x = points_of(q, self.model.n_real);
        // Per pair in pair order (collect keeps it), then summed in order:
        // the same result for any thread count.
        let outs: Vec<_> = match hess {
            None => (0..self.set.pairs.len())
                .into_par_iter()
                .with_min_len(256)
                .filter_map(|i| self.pair(i, &x, None))
                .collect(),
            Some(t) => {
                // The pairs in contact first, then their Hessian blocks
                // straight into their places in `t` (144 entries each).
                let active: Vec<usize> = (0..self.set.pairs.len())
                    .into_par_iter()
                    .with_min_len(256)
                    .filter(|&i| self.touching(i, &x))
                    .collect();
                let mut sink = t.reserve_sink(144 * active.len());
                let parts: Vec<_> = active
                    .chunks(256)
                    .map(|c| (c, sink.split_off_front(144 * c.len())))
                    .collect();
                let chunks: Vec<Vec<_>> = parts
                    .into_par_iter()
                    .map(|(c, mut part)| {
                        let mut h = [0.0; 144];
                        c.iter()
                            .map(|&i| {
                                let out = self.pair(i, &x, Some(&mut h));
                                let (_, ids, _) = out.expect("a touching pair is in contact");
                                let dofs: [usize; 12] =
                                    std::array::from_fn(|k| 3 * ids[k / 3] + k % 3);
                                part.block(&dofs, &h);
                                out.expect("checked above")
                            })
                            .collect()
                    })
                    .collect();
                chunks.concat()
            }
        };
        let mut e = 0.0;
        for (pe, ids, g) in &outs {
            e += pe;
            for (j, &v) in ids.iter().enumerate() {
                for c in 0..3 {
                    grad[3 * v + c] += g[3 * j + c];
                }
            }
        }
        e
    }

    fn begin_iteration(&mut self, q: &[f64]) {
        let n = 3 * self.model.n_real;
        if q[..n] == self.built_at[..] {
            return;
        }
        let x = points_of(q, self.model.n_real);
        self.set.build(&self.model, &x);
        self.built_at.clear();
        self.built_at.extend_from_slice(&q[..n]);
    }

    /// Each vertex of a candidate pair moves less than 0.45 of the pair's
    /// distance, so the two segments stay more than 0.1 of it apart along
    /// the whole step (distance is 1-Lipschitz in the vertex moves): no yarn
    /// passes through another. Pairs outside the candidate set are farther
    /// than the radii plus two skins, which the solver's global cap (at most
    /// the skin) keeps out of contact.
    fn limit_vertex_moves(&self, q: &[f64], caps: &mut [f64]) {
        let n = self.model.n_real.min(caps.len());
        let x = points_of(q, self.model.n_real);
        let cs = &self.model.csegs;
        for p in &self.set.pairs {
            let (a, b) = (&cs[p.a as usize], &cs[p.b as usize]);
            let ids = [a.v[0], a.v[1], b.v[0], b.v[1]].map(|v| v as usize);
            let d = crate::yarn::sim::contact::segment_distance(
                x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]],
            );
            for v in ids.into_iter().filter(|&v| v < n) {
                caps[v] = caps[v].min(MOVE_FRACTION * d);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 3 x 3 grids of straight yarns crossing at right angles, the
    /// upper layer pressed `overlap` (fraction of 2r) into the lower one.
    fn pressed_grid(overlap: f64) -> Yarns {
        let r = 1e-3;
        let mut y = Yarns::new();
        for layer in 0..2 {
            for k in 0..3 {
                let pts: Vec<Vec3> = (0..25)
                    .map(|i| {
                        let s = (i as f64 - 12.0) * 0.5 * r;
                        let o = (k as f64 - 1.0) * 4.0 * r;
                        let z = layer as f64 * 2.0 * r * (1.0 - overlap);
                        if layer == 0 {
                            [s, o, z]
                        } else {
                            [o, s + 0.1 * r, z]
                        }
                    })
                    .collect();
                y.push_curve(&pts, false, r);
            }
        }
        y
    }

    /// The Hessian path (blocks written straight into the triplets) gives
    /// the gradient-only path's energy and gradient bit for bit, and a
    /// symmetric PSD matrix supported exactly on the touching pairs' vertices.
    #[test]
    fn hessian_blocks_land_on_the_touching_pairs() {
        let y = pressed_grid(0.1);
        let term = ContactTerm::new(&y, &YarnSimParams::default(), 0.5e-3).unwrap();
        let q: Vec<f64> = y.points.iter().flatten().copied().collect();
        let n = q.len();
        let (mut g0, mut g1) = (vec![0.0; n], vec![0.0; n]);
        let e0 = term.eval(&q, &mut g0, None);
        let mut t = Triplets::new();
        let e1 = term.eval(&q, &mut g1, Some(&mut t));
        assert!(e0 > 0.0);
        assert_eq!(e0.to_bits(), e1.to_bits());
        assert_eq!(g0, g1);
        let touching = term.active_pair_gradients(&q);
        assert!(touching.len() >= 9, "{} pairs touch", touching.len());
        assert_eq!(t.len(), 144 * touching.len());
        let mut h = vec![vec![0.0; n]; n];
        for ((&r, &c), &v) in t.rows.iter().zip(&t.cols).zip(&t.vals) {
            h[r as usize][c as usize] += v;
        }
        let mut in_contact = vec![false; n / 3];
        for (ids, _) in &touching {
            for &v in ids {
                in_contact[v] = true;
            }
        }
        for i in 0..n {
            for j in 0..n {
                assert!((h[i][j] - h[j][i]).abs() <= 1e-9 * h[i][i].abs().max(1.0));
                if !(in_contact[i / 3] && in_contact[j / 3]) {
                    assert_eq!(h[i][j], 0.0, "entry ({i}, {j}) off the touching pairs");
                }
            }
            if in_contact[i / 3] {
                assert!(h[i][i] >= 0.0);
            }
        }
        // PSD: x^T H x >= 0 for the gradient and a few pseudo-random vectors.
        let mut seed = 3u64;
        let mut dirs = vec![g0.clone()];
        for _ in 0..8 {
            dirs.push(
                (0..n)
                    .map(|_| {
                        seed = seed
                            .wrapping_mul(6364136223846793005)
                            .wrapping_add(1442695040888963407);
                        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                    })
                    .collect(),
            );
        }
        for x in &dirs {
            let xhx: f64 = (0..n)
                .map(|i| x[i] * (0..n).map(|j| h[i][j] * x[j]).sum::<f64>())
                .sum();
            let scale: f64 = (0..n).map(|i| h[i][i] * x[i] * x[i]).sum();
            assert!(xhx >= -1e-9 * scale.abs(), "x^T H x = {xhx}");
        }
        // The Hessian sees the contact: along the gradient it is positive.
        let ghg: f64 = (0..n)
            .map(|i| g0[i] * (0..n).map(|j| h[i][j] * g0[j]).sum::<f64>())
            .sum();
        assert!(ghg > 0.0);
    }
}
