//! Weft-knit loop geometry for K and P stitches.
//!
//! Every course is one yarn running along +X. In course j the centre line is
//! x = W (t + a sin 2t) / (2 pi), y = j H - b cos t with one wale per 2 pi of
//! t: t = 0 is a sinker loop (bottom, between wales), t = pi the head of the
//! needle loop. With a > 1/2 the legs double back, so each head is wider than
//! the neck of the loop above it, and the loops of course j + 1 pass through
//! the heads of course j.
//!
//! In the x-y projection the head of loop (j, i) crosses the legs of loop
//! (j + 1, i) twice on each side: near its top (at |u| = u_H on the head,
//! u = t - pi, against the *neck* of the loop above at |u| = u_N) and on its
//! side (|u| = u_U against the *lower leg* above, |u| = u_L). The stitch code
//! of (j + 1, i) decides which strand is in front at each crossing (Leaf §4:
//! a knit loop is pulled through the old loop from back to front, a purl
//! from front to back), so z along loop (j, i) is eased (cosine, flat at the
//! knots) through
//!
//! | knot |u|        | 0, u_H | u_U    | u_N   | u_L   | pi (sinker)                |
//! |-----------------|--------|--------|-------|-------|----------------------------|
//! | z / c           | -s'    | +s'    | +s    | -s    | mean of the two -s beside it |
//!
//! with s = +1 for K, -1 for P of stitch (j, i) and s' the same for the
//! stitch above, (j + 1, i). So at every crossing the two strands are 2c
//! apart in z; a purl is a knit mirrored through the fabric plane (z -> -z),
//! and where K meets P in one course (ribs) the sinker passes through the
//! fabric plane between the wales. The crossing parameters are computed from
//! the shape, not tabulated, so any [`KnitShape`] that interlocks works.

use std::f64::consts::PI;

use super::curve::{ease, sample_equal_arclength};
use super::types::{KnitGrid, PatternError, PatternParams, PatternTile, Stitch};
use crate::geom::{Vec3, Yarns};
use crate::yarn::PeriodicTile;

/// The loop shape in metres, with its crossing parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopShape {
    /// Wale width W (m).
    pub w: f64,
    /// Course height H (m).
    pub h: f64,
    /// Bulge a.
    pub a: f64,
    /// Loop half-height b (m).
    pub b: f64,
    /// Crossing depth c (m).
    pub c: f64,
    /// Crossing parameters |u| = t - pi: [u_H, u_U, u_N, u_L].
    pub knots: [f64; 4],
}

impl LoopShape {
    /// The shape of `params` (multiples of r) in metres, with its crossings.
    pub fn new(params: &PatternParams) -> Result<LoopShape, PatternError> {
        let r = params.yarn_radius;
        let k = &params.knit;
        let mut s = LoopShape {
            w: k.wale_width * r,
            h: k.course_height * r,
            a: k.bulge,
            b: k.loop_height * r,
            c: k.depth * r,
            knots: [0.0; 4],
        };
        s.knots = s.crossings()?;
        Ok(s)
    }

    /// Projection (x, y) of the loop curve at parameter t (course 0).
    pub fn xy(&self, t: f64) -> [f64; 2] {
        [
            self.w * (t + self.a * (2.0 * t).sin()) / (2.0 * PI),
            -self.b * t.cos(),
        ]
    }

    /// Finds where the right half of a head (t in [pi, 2 pi]) crosses the
    /// course above in projection: exactly two crossings are needed.
    fn crossings(&self) -> Result<[f64; 4], PatternError> {
        const N: usize = 600;
        let head: Vec<(f64, [f64; 2])> = (0..=N)
            .map(|k| {
                let t = PI + PI * k as f64 / N as f64;
                (t, self.xy(t))
            })
            .collect();
        // Three wales of the course above cover every crossing of the head.
        let above: Vec<(f64, [f64; 2])> = (0..=3 * 2 * N)
            .map(|k| {
                let t = 2.0 * PI * k as f64 / (2 * N) as f64;
                let p = self.xy(t);
                (t, [p[0], p[1] + self.h])
            })
            .collect();
        let mut found: Vec<(f64, f64)> = Vec::new();
        for hw in head.windows(2) {
            let (p, q) = (hw[0].1, hw[1].1);
            for aw in above.windows(2) {
                if let Some((s, u)) = seg_intersect(p, q, aw[0].1, aw[1].1) {
                    let t_head = hw[0].0 + s * (hw[1].0 - hw[0].0);
                    let t_above = aw[0].0 + u * (aw[1].0 - aw[0].0);
                    let u_above = (t_above.rem_euclid(2.0 * PI) - PI).abs();
                    found.push((t_head - PI, u_above));
                }
            }
        }
        found.sort_by(|x, y| x.0.total_cmp(&y.0));
        found.dedup_by(|x, y| (x.0 - y.0).abs() < 1e-9);
        match found.as_slice() {
            [(uh, un), (uu, ul)] if uh < uu && un < ul => Ok([*uh, *uu, *un, *ul]),
            _ => Err(PatternError::BadParameter {
                name: "knit shape",
                value: self.a,
                message: format!(
                    "loops of neighbouring courses cross {} times per half head in projection, \
                     need 2 (course height too large or small for the loop height?)",
                    found.len()
                ),
            }),
        }
    }

    /// z of the loop at |u| (u = t - pi, 0 at the head top) for stitch sign
    /// `s`, the sign of the stitch above `s_up`, and the sinker z `z_sinker`.
    fn z(&self, u_abs: f64, s: f64, s_up: f64, z_sinker: f64) -> f64 {
        let [uh, uu, un, ul] = self.knots;
        let c = self.c;
        let knots = [
            (0.0, -s_up * c),
            (uh, -s_up * c),
            (uu, s_up * c),
            (un, s * c),
            (ul, -s * c),
            (PI, z_sinker),
        ];
        for w in knots.windows(2) {
            let ((u0, z0), (u1, z1)) = (w[0], w[1]);
            if u_abs <= u1 {
                return ease(z0, z1, (u_abs - u0) / (u1 - u0).max(1e-300));
            }
        }
        z_sinker
    }
}

/// Segment intersection in 2D: parameters (s, u) in [0, 1) of both segments.
fn seg_intersect(p: [f64; 2], q: [f64; 2], a: [f64; 2], b: [f64; 2]) -> Option<(f64, f64)> {
    let r = [q[0] - p[0], q[1] - p[1]];
    let d = [b[0] - a[0], b[1] - a[1]];
    let den = r[0] * d[1] - r[1] * d[0];
    if den.abs() < 1e-300 {
        return None;
    }
    let ap = [a[0] - p[0], a[1] - p[1]];
    let s = (ap[0] * d[1] - ap[1] * d[0]) / den;
    let u = (ap[0] * r[1] - ap[1] * r[0]) / den;
    ((0.0..1.0).contains(&s) && (0.0..1.0).contains(&u)).then_some((s, u))
}

/// +1 for a knit, -1 for a purl.
fn sign(st: Stitch) -> f64 {
    match st {
        Stitch::Knit => 1.0,
        Stitch::Purl => -1.0,
    }
}

/// The points of course `j` (row `j mod rows`) over `wales` wales starting at
/// wale 0, the end point (next wale's sinker) excluded. Returns the points
/// and the number of points per wale (nothing for an empty or ragged grid).
pub fn course_points(
    grid: &KnitGrid,
    shape: &LoopShape,
    j: usize,
    wales: usize,
    spacing: f64,
) -> (Vec<Vec3>, Vec<usize>) {
    let rows = grid.rows.len();
    let cols = grid.rows.first().map_or(0, Vec::len);
    if cols == 0 || grid.rows.iter().any(|r| r.len() != cols) {
        return (Vec::new(), Vec::new());
    }
    let code = |jj: usize, i: usize| sign(grid.rows[jj % rows][i % cols]);
    let y0 = j as f64 * shape.h;
    let mut pts = Vec::new();
    let mut per_wale = Vec::with_capacity(wales);
    for i in 0..wales {
        let s = code(j, i);
        let s_up = code(j + 1, i);
        // Sinker z: the mean of the lower-leg z of the two loops it joins.
        let left = 0.5 * (-s - code(j, i + cols - 1)) * shape.c;
        let right = 0.5 * (-s - code(j, i + 1)) * shape.c;
        let x0 = i as f64 * shape.w;
        let f = |t: f64| {
            let [x, y] = shape.xy(t);
            let u = t - PI;
            let zs = if u < 0.0 { left } else { right };
            [x0 + x, y0 + y, shape.z(u.abs(), s, s_up, zs)]
        };
        let (p, _) = sample_equal_arclength(f, 0.0, 2.0 * PI, spacing, 8);
        per_wale.push(p.len());
        pts.extend(p);
    }
    (pts, per_wale)
}

/// One repeat of a knit grid as a periodic tile: one open curve per course,
/// each continuing into itself one tile to the right.
pub fn knit_tile(grid: &KnitGrid, params: &PatternParams) -> Result<PatternTile, PatternError> {
    let shape = LoopShape::new(params)?;
    let rows = grid.rows.len();
    let cols = grid.rows[0].len();
    let spacing = params.spacing * params.yarn_radius;
    let mut yarns = Yarns::new();
    for j in 0..rows {
        let (pts, _) = course_points(grid, &shape, j, cols, spacing);
        yarns.push_curve(&pts, false, params.yarn_radius);
    }
    Ok(PatternTile {
        tile: PeriodicTile {
            yarns,
            lattice: [
                [cols as f64 * shape.w, 0.0, 0.0],
                [0.0, rows as f64 * shape.h, 0.0],
            ],
            next: (0..rows).map(|j| (j, [1, 0])).collect(),
        },
        axis: vec![0; rows],
        lane: (0..rows).collect(),
        repeat: [cols, rows],
        pitch: [shape.w, shape.h],
        radius: params.yarn_radius,
        // The last crossing of a wale (u_L) is about 0.16 W before its sinker.
        seam: 0.15,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::pattern::Stitch;

    #[test]
    fn default_shape_interlocks_with_ordered_crossings() {
        let s = LoopShape::new(&PatternParams::default()).unwrap();
        let [uh, uu, un, ul] = s.knots;
        assert!(
            0.0 < uh && uh < uu && uu < un && un < ul && ul < PI,
            "{:?}",
            s.knots
        );
    }

    #[test]
    fn no_interlock_is_an_error() {
        let mut p = PatternParams::default();
        p.knit.course_height = 30.0; // courses far apart: loops never meet
        assert!(LoopShape::new(&p).is_err());
    }

    #[test]
    fn purl_mirrors_knit_through_the_fabric_plane() {
        let p = PatternParams::default();
        let s = LoopShape::new(&p).unwrap();
        let k = KnitGrid {
            rows: vec![vec![Stitch::Knit]],
        };
        let q = KnitGrid {
            rows: vec![vec![Stitch::Purl]],
        };
        let (a, _) = course_points(&k, &s, 0, 2, p.spacing * p.yarn_radius);
        let (b, _) = course_points(&q, &s, 0, 2, p.spacing * p.yarn_radius);
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert!((x[0] - y[0]).abs() < 1e-12 && (x[1] - y[1]).abs() < 1e-12);
            assert!((x[2] + y[2]).abs() < 1e-12);
        }
        // The neck of a knit loop is in front (+z).
        let neck = s.z(s.knots[2], 1.0, 1.0, -s.c);
        assert!((neck - s.c).abs() < 1e-12);
    }
}
