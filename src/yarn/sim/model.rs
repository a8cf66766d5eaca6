//! The discrete model shared by the free simulator and the periodic tile:
//! real vertices (integrated), ghost vertices (rigid lattice copies of real
//! ones, Leaf §5 "virtual" points), stretch segments, bending hinges, contact
//! segments and the along-yarn contact exclusion lists.
//!
//! Every element is listed once per tile (or once, without periodicity), so
//! `-dE/dx_real` with ghosts folded onto their real vertices is exactly the
//! force of the infinite tiling.

use crate::geom::vec3::{norm, sub};
use std::collections::BTreeMap;

use super::params::YarnSimParams;
use super::YarnSimError;
use crate::geom::{Vec3, Yarns};
use crate::yarn::PeriodicTile;

/// A vertex named by its real vertex and its lattice shift.
pub(crate) type VRef = (u32, [i32; 2]);

/// A stretch segment between two extended vertices.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Seg {
    pub v: [u32; 2],
    /// Rest length (m).
    pub l0: f64,
    /// Axial stiffness E A (N).
    pub ks: f64,
}

/// A bending hinge at `v[1]` between segments (v0, v1) and (v1, v2).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hinge {
    pub v: [u32; 3],
    /// Rest discrete curvature 2 tan(phi0 / 2).
    pub kappa0: f64,
    /// `0.5 * bend_scale * E * I / lbar` (J).
    pub coef: f64,
}

/// A segment taking part in contact (a base segment or a ghost copy).
#[derive(Debug, Clone, Copy)]
pub(crate) struct CSeg {
    pub v: [u32; 2],
    pub radius: f64,
    pub l0: f64,
    pub base: u32,
    pub shift: [i32; 2],
    pub real: bool,
}

/// Compressed rows: `idx[start[i]..start[i + 1]]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Csr {
    pub start: Vec<u32>,
    pub idx: Vec<u32>,
}

impl Csr {
    /// Builds rows from (row, value) entries by a counting sort; values keep
    /// their input order within a row.
    pub fn build(rows: usize, entries: Vec<(u32, u32)>) -> Csr {
        let mut start = vec![0u32; rows + 1];
        for &(r, _) in &entries {
            start[r as usize + 1] += 1;
        }
        for i in 0..rows {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut idx = vec![0u32; entries.len()];
        for (r, v) in entries {
            idx[fill[r as usize] as usize] = v;
            fill[r as usize] += 1;
        }
        Csr { start, idx }
    }
    #[inline]
    pub fn row(&self, i: usize) -> &[u32] {
        &self.idx[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

/// The discrete yarn model.
#[derive(Debug, Clone)]
pub(crate) struct Model {
    pub n_real: usize,
    /// Ghost `k` (extended index `n_real + k`): (real vertex, lattice offset).
    pub ghosts: Vec<(u32, Vec3)>,
    pub lattice: Option<[Vec3; 2]>,
    /// Lumped mass per real vertex (kg).
    pub mass: Vec<f64>,
    /// Radius per real vertex (m).
    pub radius: Vec<f64>,
    pub segs: Vec<Seg>,
    pub hinges: Vec<Hinge>,
    pub csegs: Vec<CSeg>,
    /// Per base segment: sorted (base segment, relative shift) pairs excluded from contact.
    pub excl: Vec<Vec<VRef>>,
    /// Real vertex -> slots `2 * seg + end` of the stretch output.
    pub seg_inc: Csr,
    /// Real vertex -> slots `3 * hinge + k` of the bending output.
    pub hinge_inc: Csr,
    /// Static Gershgorin bound of the rod stiffness per real vertex (N/m).
    pub rod_stiffness: Vec<f64>,
    /// Contact quadrature samples per segment (odd, >= 3).
    pub n_samples: usize,
    /// Smallest radius (m).
    pub r_min: f64,
}

/// What the two builders hand to [`finish`].
struct Topo {
    rest: Vec<Vec3>,
    radius: Vec<f64>,
    lin_density: Vec<Option<f64>>,
    lattice: Option<[Vec3; 2]>,
    base: Vec<[VRef; 2]>,
    hinges: Vec<[VRef; 3]>,
    succ: Vec<Option<(u32, [i32; 2])>>,
    pred: Vec<Option<(u32, [i32; 2])>>,
    shifts: Vec<[i32; 2]>,
    /// Per vertex: rest curvature magnitude `|kb|` from a stored rest shape
    /// (none: from the rest positions).
    rest_curvature: Option<Vec<f64>>,
}

fn add2(a: [i32; 2], b: [i32; 2]) -> [i32; 2] {
    [a[0] + b[0], a[1] + b[1]]
}

impl Model {
    /// Model of free (non-periodic) yarns.
    pub fn from_yarns(
        y: &Yarns,
        params: &YarnSimParams,
        length_scale: Option<&[f64]>,
    ) -> Result<Model, YarnSimError> {
        y.validate()?;
        let n = y.num_points();
        let mut t = Topo {
            rest: y.points.clone(),
            radius: (0..n).map(|v| y.radius_at(v)).collect(),
            lin_density: vec![None; n],
            lattice: None,
            base: Vec::new(),
            hinges: Vec::new(),
            succ: Vec::new(),
            pred: Vec::new(),
            shifts: vec![[0, 0]],
            rest_curvature: None,
        };
        for c in 0..y.num_curves() {
            let r = y.curve_range(c);
            let (o, m) = (r.start as u32, r.len() as u32);
            let closed = y.closed[c];
            let ld = y.linear_density.as_ref().map(|d| d[c]);
            for v in r.clone() {
                t.lin_density[v] = ld;
            }
            let nseg = if closed { m } else { m - 1 };
            let first = t.base.len() as u32;
            for k in 0..nseg {
                let s = first + k;
                t.base.push([(o + k, [0, 0]), (o + (k + 1) % m, [0, 0])]);
                t.succ.push(if k + 1 < nseg {
                    Some((s + 1, [0, 0]))
                } else if closed {
                    Some((first, [0, 0]))
                } else {
                    None
                });
                t.pred.push(if k > 0 {
                    Some((s - 1, [0, 0]))
                } else if closed {
                    Some((first + nseg - 1, [0, 0]))
                } else {
                    None
                });
            }
            let hinge_range = if closed { 0..m } else { 1..m - 1 };
            for k in hinge_range {
                t.hinges.push([
                    (o + (k + m - 1) % m, [0, 0]),
                    (o + k, [0, 0]),
                    (o + (k + 1) % m, [0, 0]),
                ]);
            }
        }
        // A stored rest shape (a relaxed swatch's scaled lengths and
        // curvatures) is the rest state; the positions are only the start.
        let from_rest;
        let length_scale = match (&y.rest, length_scale) {
            (Some(rest), None) => {
                rest.validate(t.base.len(), n)?;
                t.rest_curvature = Some(
                    rest.curvature
                        .iter()
                        .map(|k| 0.5 * (k[0].hypot(k[1]) + k[2].hypot(k[3])))
                        .collect(),
                );
                from_rest = t
                    .base
                    .iter()
                    .zip(&rest.lengths)
                    .map(|(&[a, b], &l0)| {
                        l0 / norm(sub(y.points[b.0 as usize], y.points[a.0 as usize]))
                    })
                    .collect::<Vec<f64>>();
                Some(from_rest.as_slice())
            }
            (_, given) => given,
        };
        finish(t, params, length_scale)
    }

    /// Model of a periodic tile (Leaf §5): ghosts for the 8 neighbouring
    /// copies of every segment, elements owned by the tile.
    pub fn from_tile(
        tile: &PeriodicTile,
        params: &YarnSimParams,
        length_scale: Option<&[f64]>,
    ) -> Result<Model, YarnSimError> {
        tile.validate().map_err(YarnSimError::Tile)?;
        let y = &tile.yarns;
        y.validate()?;
        let n = y.num_points();
        let nc = y.num_curves();
        let mut t = Topo {
            rest: y.points.clone(),
            radius: (0..n).map(|v| y.radius_at(v)).collect(),
            lin_density: vec![None; n],
            lattice: Some(tile.lattice),
            base: Vec::new(),
            hinges: Vec::new(),
            succ: Vec::new(),
            pred: Vec::new(),
            shifts: Vec::new(),
            rest_curvature: None,
        };
        for i in -1..=1 {
            for j in -1..=1 {
                t.shifts.push([i, j]);
            }
        }
        // prev[c]: the curve continuing into c and its shift (c's copy at 0
        // follows curve p's copy at -shift).
        let mut prev = vec![(0usize, [0i32; 2]); nc];
        for (p, &(c, s)) in tile.next.iter().enumerate() {
            prev[c] = (p, s);
        }
        // Per curve: its segments are the internal ones plus the connector
        // from its last point to the next curve's first point.
        let mut first_seg = vec![0u32; nc];
        let mut n_seg_total = 0u32;
        for c in 0..nc {
            first_seg[c] = n_seg_total;
            n_seg_total += y.curve_range(c).len() as u32;
        }
        for c in 0..nc {
            let r = y.curve_range(c);
            let (o, m) = (r.start as u32, r.len() as u32);
            let ld = y.linear_density.as_ref().map(|d| d[c]);
            for v in r.clone() {
                t.lin_density[v] = ld;
            }
            let (nx, ns) = tile.next[c];
            let (pv, ps) = prev[c];
            let nx_first = y.offsets[nx] as u32;
            let pv_last = y.offsets[pv + 1] as u32 - 1;
            for k in 0..m {
                let s = first_seg[c] + k;
                if k + 1 < m {
                    t.base.push([(o + k, [0, 0]), (o + k + 1, [0, 0])]);
                    t.succ.push(Some((s + 1, [0, 0])));
                } else {
                    t.base.push([(o + k, [0, 0]), (nx_first, ns)]);
                    t.succ.push(Some((first_seg[nx], ns)));
                }
                t.pred.push(if k > 0 {
                    Some((s - 1, [0, 0]))
                } else {
                    Some((
                        first_seg[pv] + y.curve_range(pv).len() as u32 - 1,
                        [-ps[0], -ps[1]],
                    ))
                });
                let before = if k > 0 {
                    (o + k - 1, [0, 0])
                } else {
                    (pv_last, [-ps[0], -ps[1]])
                };
                let after = if k + 1 < m {
                    (o + k + 1, [0, 0])
                } else {
                    (nx_first, ns)
                };
                t.hinges.push([before, (o + k, [0, 0]), after]);
            }
        }
        finish(t, params, length_scale)
    }

    /// Extended index -> real vertex.
    #[inline]
    pub fn real_of(&self, e: u32) -> usize {
        let e = e as usize;
        if e < self.n_real {
            e
        } else {
            self.ghosts[e - self.n_real].0 as usize
        }
    }

    pub fn n_ext(&self) -> usize {
        self.n_real + self.ghosts.len()
    }

    /// Overwrites ghost positions from their real vertices (Leaf Algorithm 2).
    pub fn update_ghosts(&self, x: &mut [Vec3]) {
        let n = self.n_real;
        for (k, &(r, off)) in self.ghosts.iter().enumerate() {
            let p = x[r as usize];
            x[n + k] = [p[0] + off[0], p[1] + off[1], p[2] + off[2]];
        }
    }

    /// Ghost velocities equal their real vertices' (Leaf Algorithm 2).
    pub fn update_ghost_velocities(&self, v: &mut [Vec3]) {
        let n = self.n_real;
        for (k, &(r, _)) in self.ghosts.iter().enumerate() {
            v[n + k] = v[r as usize];
        }
    }

    /// Whether base segments `a` (shift `sa`) and `b` (shift `sb`) are too
    /// close along the yarn to interact by contact.
    #[inline]
    pub fn excluded(&self, a: &CSeg, b: &CSeg) -> bool {
        let rel = [b.shift[0] - a.shift[0], b.shift[1] - a.shift[1]];
        self.excl[a.base as usize]
            .binary_search(&(b.base, rel))
            .is_ok()
    }
}

fn finish(
    t: Topo,
    params: &YarnSimParams,
    length_scale: Option<&[f64]>,
) -> Result<Model, YarnSimError> {
    params.validate()?;
    let n = t.rest.len();
    if let Some(s) = length_scale {
        if s.len() != t.base.len() {
            return Err(YarnSimError::Param {
                name: "rest_length_scale",
                message: format!("{} values for {} segments", s.len(), t.base.len()),
            });
        }
        if let Some((i, v)) = s
            .iter()
            .enumerate()
            .find(|(_, v)| !(v.is_finite() && **v > 0.0))
        {
            return Err(YarnSimError::Param {
                name: "rest_length_scale",
                message: format!("segment {i}: {v} is not a positive finite number"),
            });
        }
    }
    let lattice = t.lattice;
    let offset = |s: [i32; 2]| -> Vec3 {
        match lattice {
            Some([a, b]) => {
                let (i, j) = (s[0] as f64, s[1] as f64);
                [
                    i * a[0] + j * b[0],
                    i * a[1] + j * b[1],
                    i * a[2] + j * b[2],
                ]
            }
            None => [0.0; 3],
        }
    };
    let mut ghost_ids: BTreeMap<VRef, u32> = BTreeMap::new();
    let mut ghosts: Vec<(u32, Vec3)> = Vec::new();
    let mut ext = |r: VRef| -> u32 {
        if r.1 == [0, 0] {
            return r.0;
        }
        *ghost_ids.entry(r).or_insert_with(|| {
            ghosts.push((r.0, offset(r.1)));
            (n + ghosts.len() - 1) as u32
        })
    };
    let pos = |r: VRef| -> Vec3 {
        let p = t.rest[r.0 as usize];
        let o = offset(r.1);
        [p[0] + o[0], p[1] + o[1], p[2] + o[2]]
    };
    let e_mod = params.youngs_modulus;
    let pi = std::f64::consts::PI;
    let mut segs = Vec::with_capacity(t.base.len());
    let mut mass = vec![0.0; n];
    let mut seg_entries = Vec::with_capacity(2 * t.base.len());
    let mut seg_radius = Vec::with_capacity(t.base.len());
    for (s, &[a, b]) in t.base.iter().enumerate() {
        let l = norm(sub(pos(b), pos(a))) * length_scale.map_or(1.0, |x| x[s]);
        if !(l > 0.0) {
            return Err(YarnSimError::Param {
                name: "yarns",
                message: format!(
                    "segment {s} (vertices {} and {}) has zero rest length",
                    a.0, b.0
                ),
            });
        }
        let r = 0.5 * (t.radius[a.0 as usize] + t.radius[b.0 as usize]);
        let mu = t.lin_density[a.0 as usize].unwrap_or(params.density * pi * r * r);
        mass[a.0 as usize] += 0.5 * mu * l;
        mass[b.0 as usize] += 0.5 * mu * l;
        segs.push(Seg {
            v: [ext(a), ext(b)],
            l0: l,
            ks: e_mod * pi * r * r,
        });
        seg_entries.push((a.0, 2 * s as u32));
        seg_entries.push((b.0, 2 * s as u32 + 1));
        seg_radius.push(r);
    }
    if let Some(v) = mass.iter().position(|m| !(*m > 0.0)) {
        return Err(YarnSimError::Param {
            name: "yarns",
            message: format!("vertex {v} has no mass (linear density zero or no segment)"),
        });
    }
    // Bending hinges: lbar = half the sum of the adjacent rest lengths.
    let mut hinges = Vec::with_capacity(t.hinges.len());
    let mut hinge_entries = Vec::with_capacity(3 * t.hinges.len());
    let mut rod_stiffness = vec![0.0; n];
    for (s, &[a, b]) in segs.iter().zip(&t.base) {
        let k = 2.0 * s.ks / s.l0;
        // Ghost ends fold onto their real vertex in the static bound too.
        rod_stiffness[a.0 as usize] += k;
        rod_stiffness[b.0 as usize] += k;
    }
    // Rest lengths of a hinge's segments come from the rest positions and the
    // factor of the base segment starting at the same real vertex.
    let mut seg_of_start: BTreeMap<VRef, usize> = BTreeMap::new();
    for (s, &[a, _]) in t.base.iter().enumerate() {
        seg_of_start.insert(a, s);
    }
    for (h, &[a, b, c]) in t.hinges.iter().enumerate() {
        let (pa, pb, pc) = (pos(a), pos(b), pos(c));
        let e0 = sub(pb, pa);
        let e1 = sub(pc, pb);
        let kappa0 = match &t.rest_curvature {
            Some(k) => k[b.0 as usize],
            None => discrete_curvature(e0, e1),
        };
        // Rest lengths of the two segments, with any local scaling.
        let scale_of = |start: VRef| -> f64 {
            let key = (start.0, [0, 0]);
            let s = seg_of_start.get(&key).copied();
            match (s, length_scale) {
                (Some(s), Some(x)) => x[s],
                _ => 1.0,
            }
        };
        let l0 = norm(e0) * scale_of(a);
        let l1 = norm(e1) * scale_of(b);
        let lbar = 0.5 * (l0 + l1);
        let r = t.radius[b.0 as usize];
        let ei = params.bend_scale * e_mod * pi * r.powi(4) / 4.0;
        let coef = 0.5 * ei / lbar;
        hinges.push(Hinge {
            v: [ext(a), ext(b), ext(c)],
            kappa0,
            coef,
        });
        for (k, vr) in [a, b, c].iter().enumerate() {
            hinge_entries.push((vr.0, 3 * h as u32 + k as u32));
        }
        let lmin = l0.min(l1);
        let kb = 32.0 * coef / (lmin * lmin);
        for vr in [a, b, c] {
            rod_stiffness[vr.0 as usize] += kb;
        }
    }
    // Contact segments: base segments, then ghost copies for each shift.
    let mut csegs = Vec::new();
    for &sh in &t.shifts {
        for (s, &[a, b]) in t.base.iter().enumerate() {
            let real = sh == [0, 0];
            csegs.push(CSeg {
                v: [ext((a.0, add2(a.1, sh))), ext((b.0, add2(b.1, sh)))],
                radius: seg_radius[s],
                l0: segs[s].l0,
                base: s as u32,
                shift: sh,
                real,
            });
        }
    }
    // Real segments first (the pair builder relies on it only for speed).
    csegs.sort_by_key(|c| !c.real);
    // Along-yarn exclusion lists.
    let mut excl = Vec::with_capacity(t.base.len());
    for s in 0..t.base.len() {
        let limit = params.contact_exclusion * 2.0 * seg_radius[s];
        let mut list: Vec<VRef> = vec![(s as u32, [0, 0])];
        for dir in [&t.succ, &t.pred] {
            let (mut cur, mut shift, mut gap) = (s as u32, [0i32, 0i32], 0.0);
            for _ in 0..t.base.len() + 1 {
                let Some((nb, ds)) = dir[cur as usize] else {
                    break;
                };
                if gap >= limit {
                    break;
                }
                shift = add2(shift, ds);
                if nb as usize == s && shift == [0, 0] {
                    break;
                }
                list.push((nb, shift));
                gap += segs[nb as usize].l0;
                cur = nb;
            }
        }
        list.sort();
        list.dedup();
        excl.push(list);
    }
    let r_min = t.radius.iter().cloned().fold(f64::INFINITY, f64::min);
    let l_max = segs.iter().map(|s| s.l0).fold(0.0, f64::max);
    let mut ns = ((l_max / (params.contact_sample_spacing * r_min)).ceil() as usize + 1).max(3);
    if ns % 2 == 0 {
        ns += 1;
    }
    if ns > 63 {
        return Err(YarnSimError::Param {
            name: "yarns",
            message: format!(
                "segments up to {l_max} m long need {ns} contact samples at radius {r_min} m; resample the yarns"
            ),
        });
    }
    Ok(Model {
        n_real: n,
        ghosts,
        lattice,
        mass,
        radius: t.radius,
        segs,
        hinges,
        csegs,
        excl,
        seg_inc: Csr::build(n, seg_entries),
        hinge_inc: Csr::build(n, hinge_entries),
        rod_stiffness,
        n_samples: ns,
        r_min,
    })
}

/// Discrete curvature 2 tan(phi / 2) at a hinge with incoming edge `e0` and
/// outgoing edge `e1` (Bergou et al. 2008, |kappa b|).
pub(crate) fn discrete_curvature(e0: Vec3, e1: Vec3) -> f64 {
    let c = [
        e0[1] * e1[2] - e0[2] * e1[1],
        e0[2] * e1[0] - e0[0] * e1[2],
        e0[0] * e1[1] - e0[1] * e1[0],
    ];
    let d = e0[0] * e1[0] + e0[1] * e1[1] + e0[2] * e1[2];
    2.0 * norm(c) / (norm(e0) * norm(e1) + d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::rods::{RodRest, RodTopology};

    /// A stored rest shape is the explicit model's rest state: its lengths
    /// and curvature magnitudes, not the positions'.
    #[test]
    fn stored_rest_shape_sets_rest_lengths_and_curvatures() {
        let rest_pts: Vec<Vec3> = (0..9)
            .map(|i| {
                let a = 0.3 * i as f64;
                [0.01 * a.cos(), 0.01 * a.sin(), 0.001 * i as f64]
            })
            .collect();
        let mut y = Yarns::new();
        y.push_curve(&rest_pts, false, 1e-3);
        let topo = RodTopology::new(&y).unwrap();
        let mut rest = RodRest::from_positions(&topo, &rest_pts).unwrap();
        rest.l0.iter_mut().for_each(|l| *l *= 0.8);
        // Start from a straightened, longer copy of the curve.
        let mut moved = y.clone();
        moved.points = (0..9).map(|i| [0.004 * i as f64, 0.0, 0.0]).collect();
        moved.rest = Some(rest.to_shape(&topo));
        let p = YarnSimParams::default();
        let m = Model::from_yarns(&moved, &p, None).unwrap();
        for (s, seg) in m.segs.iter().enumerate() {
            assert!((seg.l0 - rest.l0[s]).abs() < 1e-15, "segment {s}");
        }
        let plain = Model::from_yarns(&y, &p, None).unwrap();
        assert_eq!(m.hinges.len(), plain.hinges.len());
        for (h, (a, b)) in m.hinges.iter().zip(&plain.hinges).enumerate() {
            // Same curvature as the rest curve (not the straight start).
            assert!(a.kappa0 > 0.1, "hinge {h}: {}", a.kappa0);
            assert!((a.kappa0 - b.kappa0).abs() < 1e-9, "hinge {h}");
        }
    }
}
