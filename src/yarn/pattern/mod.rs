//! Stitch patterns to yarn curves (Leaf et al. 2018 §4): knit grids of stitch
//! codes (K, P) and woven 0/1 matrices become a [`PeriodicTile`] of yarn
//! curves, which is tiled into flat swatches of N courses x M wales or wrapped
//! into tubes knitted in the round.
//!
//! The curves are an *unrelaxed* starting state: topologically right (every
//! loop is pulled through the loop below it from the side its stitch code
//! says), smooth, sampled at a documented vertex spacing, and free of
//! interpenetration: non-adjacent segments are at least about 2r apart (the
//! tests check >= 0.95 * 2r for every built-in, see [`distance`]). Like Leaf's
//! generated curves they hold more yarn than the relaxed fabric (the loops are
//! looser than a relaxed knit); the yarn-level relaxation (Leaf §5-6, HYLC §5)
//! pulls them tight.
//!
//! Frame: metres, +Y up. Courses (and weft yarns) run along +X, the fabric
//! grows along +Y, and +Z is the fabric's front (the knit face of a K stitch).

pub mod builtin;
pub mod character;
mod curve;
pub mod distance;
pub mod grid;
pub mod knit;
mod types;
pub mod woven;

use std::f64::consts::PI;

use crate::geom::{GeomError, Vec3, Yarns};

use super::PeriodicTile;

pub use builtin::{builtin, BUILTIN_NAMES};
pub use character::{character, Character};
pub(crate) use curve::ease;
pub use distance::{min_segment_distance, MinDistance};
pub use grid::parse_grid;
pub use types::{
    KnitGrid, KnitShape, Pattern, PatternError, PatternParams, PatternTile, Stitch, WeaveMatrix,
    WovenShape,
};

/// Builds the periodic tile of one repeat of `pattern`.
pub fn build_tile(pattern: &Pattern, params: &PatternParams) -> Result<PatternTile, PatternError> {
    params.check()?;
    pattern.check_rectangular()?;
    let tile = match pattern {
        Pattern::Knit(g) => knit::knit_tile(g, params)?,
        Pattern::Woven(w) => woven::woven_tile(w, params),
    };
    tile.tile.yarns.validate()?;
    tile.tile
        .validate()
        .map_err(|e| PatternError::Geometry(GeomError::Layout(e.to_string())))?;
    Ok(tile)
}

/// How a tile is laid out: a flat swatch, or a tube knitted in the round.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layout {
    /// Courses (knit) or wefts (woven): the count along +Y.
    pub courses: usize,
    /// Wales (knit) or warps (woven): the count along +X (around a tube).
    pub wales: usize,
    /// Tube radius (m) of the fabric's mid-surface; `None` for a flat swatch.
    pub tube_radius: Option<f64>,
    /// Tubes only: join the courses (wefts) into one helix, as knitting in
    /// the round does, instead of closing each into a ring.
    pub helix: bool,
    /// Flat swatches only: keep every course (weft) a separate open yarn.
    /// By default (false) the courses are one yarn, as flat knitting (and
    /// weaving) makes it: course after course, alternately left to right and
    /// right to left, joined by a turn at the edge, so the swatch cannot
    /// come apart course by course.
    pub separate_courses: bool,
}

/// Largest swatch side accepted (courses and wales), against runaway memory.
pub const MAX_STITCHES: usize = 100_000;

/// Most stitches (courses x wales) in one swatch: about 32 million vertices,
/// some 800 MB of points.
pub const MAX_TOTAL_STITCHES: usize = 1_000_000;

/// Lays out `tile` as a swatch.
///
/// Flat: the tile is repeated and cut to `wales * pitch[0]` by `courses *
/// pitch[1]`; every course (weft, warp) is one open yarn whose ends are the
/// cut.
///
/// Tube (`tube_radius = Some(R)`, `wales` a multiple of the repeat's
/// columns): a flat point (x, y, z) maps to angle theta = 2 pi x / X
/// (X = wales * pitch[0], the course length) around the tube axis (+Y) at
/// distance R + z, so the front face (+Z) is outside. When 2 pi R differs from
/// X the fabric is stretched around the tube by 2 pi R / X (reported by
/// [`Layout::circumferential_stretch`]). By default every course (weft) closes
/// into a ring. With `helix`, the courses are joined into one yarn that rises
/// one course per turn (height y + pitch[1] theta / 2 pi), as knitting in the
/// round makes it; where consecutive courses start with different stitches
/// (garter, seed, weaves) the helix has a jog at the seam (theta = 0), eased
/// over `PatternTile::seam`. Warps stay open yarns along the axis.
pub fn lay_out(tile: &PatternTile, layout: &Layout) -> Result<Yarns, PatternError> {
    for (name, v) in [("courses", layout.courses), ("wales", layout.wales)] {
        if v == 0 || v > MAX_STITCHES {
            return Err(PatternError::BadParameter {
                name,
                value: v as f64,
                message: format!("must be between 1 and {MAX_STITCHES}"),
            });
        }
    }
    let total = layout.courses.saturating_mul(layout.wales);
    if total > MAX_TOTAL_STITCHES {
        return Err(PatternError::BadParameter {
            name: "courses x wales",
            value: total as f64,
            message: format!("at most {MAX_TOTAL_STITCHES} stitches per swatch"),
        });
    }
    if let Some(r) = layout.tube_radius {
        if layout.wales % tile.repeat[0] != 0 {
            return Err(PatternError::BadParameter {
                name: "wales",
                value: layout.wales as f64,
                message: format!(
                    "a tube must hold whole repeats: use a multiple of {} wales",
                    tile.repeat[0]
                ),
            });
        }
        if !(r.is_finite() && r > 0.0) {
            return Err(PatternError::BadParameter {
                name: "tube_radius",
                value: r,
                message: "must be a positive length (m)".into(),
            });
        }
    }
    let counts = [layout.wales, layout.courses];
    let extent = [
        counts[0] as f64 * tile.pitch[0],
        counts[1] as f64 * tile.pitch[1],
    ];
    // Chains per axis, in lane order: Vec<(lane, points)>.
    let mut chains: [Vec<(usize, Vec<Vec3>)>; 2] = [Vec::new(), Vec::new()];
    let t = &tile.tile;
    let n_curves = t.yarns.num_curves();
    for c in 0..n_curves {
        let ax = tile.axis[c] as usize;
        let other = 1 - ax;
        let copies_across = counts[other].div_ceil(tile.repeat[other]);
        for k in 0..copies_across {
            let lane = k * tile.repeat[other] + tile.lane[c];
            if lane >= counts[other] {
                continue;
            }
            let mut copy = [0i64; 2];
            copy[other] = k as i64;
            chains[ax].push((lane, follow_chain(t, c, copy, ax, extent[ax])));
        }
    }
    for ch in &mut chains {
        ch.sort_by_key(|(lane, _)| *lane);
    }
    let r = tile.radius;
    let mut yarns = Yarns::new();
    match layout.tube_radius {
        None if layout.separate_courses => {
            for (_, pts) in chains.iter().flatten() {
                yarns.push_curve(pts, false, r);
            }
        }
        None => {
            let spacing = mean_segment_length(&t.yarns);
            let joined = join_back_and_forth(&chains[0], extent[0], spacing, r);
            if joined.len() >= 2 {
                yarns.push_curve(&joined, false, r);
            }
            for (_, pts) in &chains[1] {
                yarns.push_curve(pts, false, r);
            }
        }
        Some(radius) if !layout.helix => {
            let wrap = |p: Vec3| {
                let theta = 2.0 * PI * p[0] / extent[0];
                let rho = radius + p[2];
                [rho * theta.sin(), p[1], rho * theta.cos()]
            };
            // Each course's end point is its start one turn on: drop it and close.
            for (_, pts) in &chains[0] {
                let ring: Vec<Vec3> = pts[..pts.len().saturating_sub(1)]
                    .iter()
                    .map(|&p| wrap(p))
                    .collect();
                yarns.push_curve(&ring, true, r);
            }
            for (_, pts) in &chains[1] {
                let w: Vec<Vec3> = pts.iter().map(|&p| wrap(p)).collect();
                yarns.push_curve(&w, false, r);
            }
        }
        Some(radius) => {
            let wrap = |p: Vec3| {
                let s = p[0] / extent[0];
                let theta = 2.0 * PI * s;
                let rho = radius + p[2];
                [
                    rho * theta.sin(),
                    p[1] + tile.pitch[1] * s,
                    rho * theta.cos(),
                ]
            };
            // One helix: each course ends where the next begins (one turn
            // up), so its end point is dropped; the last course's too, since
            // it would sit on the first wale of a course that is not there
            // (for a weave, on the end of warp 0).
            // Where one turn runs into the next, the flat course would end at
            // the z of its own next wale, but the helix goes on into the next
            // course, whose first stitch may differ (garter, seed, a weave):
            // the z difference is eased in over the last `seam * pitch[0]`.
            let mut helix: Vec<Vec3> = Vec::new();
            let seam = tile.seam * tile.pitch[0];
            let n_chains = chains[0].len();
            for (i, (_, pts)) in chains[0].iter().enumerate() {
                // Index of the last point before the seam region (loops double
                // back, so search from the end).
                let before_seam = pts
                    .iter()
                    .rposition(|p| p[0] <= extent[0] - seam + 1e-9 * extent[0])
                    .map_or(0, |k| k + 1);
                // The last turn stops short of the seam: past it, it would run
                // into the ends of the warps (or wales) where the next course
                // would start.
                let keep = if i + 1 == n_chains {
                    before_seam
                } else {
                    pts.len().saturating_sub(1)
                };
                let dz = match (pts.last(), chains[0].get(i + 1).and_then(|c| c.1.first())) {
                    (Some(end), Some(next)) => next[2] - end[2],
                    _ => 0.0,
                };
                helix.extend(pts[..keep].iter().enumerate().map(|(k, &p)| {
                    let z = if k >= before_seam {
                        let f = (p[0] - (extent[0] - seam)) / seam.max(1e-300);
                        p[2] + dz * ease(0.0, 1.0, f)
                    } else {
                        p[2]
                    };
                    wrap([p[0], p[1], z])
                }));
            }
            if helix.len() >= 2 {
                yarns.push_curve(&helix, false, r);
            }
            for (_, pts) in &chains[1] {
                let w: Vec<Vec3> = pts.iter().map(|&p| wrap(p)).collect();
                yarns.push_curve(&w, false, r);
            }
        }
    }
    yarns.validate()?;
    Ok(yarns)
}

/// Mean segment length of a set of yarns (m), 0 without segments.
fn mean_segment_length(y: &Yarns) -> f64 {
    let n = y.num_segments();
    if n == 0 {
        return 0.0;
    }
    y.segments()
        .map(|[a, b]| crate::geom::dist(y.points[a], y.points[b]))
        .sum::<f64>()
        / n as f64
}

/// Joins courses (bottom first, each running from x = 0 to x = `width`) into
/// one flat-knitted yarn: even courses left to right, odd ones right to left,
/// each turn a half ellipse outside the edge (x beyond 0 or `width`) from the
/// end of one course to the start of the next, sampled at `spacing`.
///
/// The turn bulges out by at least 2r so that it clears the edge stitches'
/// legs (which stay within the edge sinkers in x), and eases z between the
/// two courses' end heights.
fn join_back_and_forth(
    courses: &[(usize, Vec<Vec3>)],
    width: f64,
    spacing: f64,
    r: f64,
) -> Vec<Vec3> {
    let mut out: Vec<Vec3> = Vec::new();
    for (k, (_, pts)) in courses.iter().enumerate() {
        let forward = k % 2 == 0;
        let course: Vec<Vec3> = if forward {
            pts.clone()
        } else {
            pts.iter().rev().copied().collect()
        };
        if let (Some(&p), Some(&q)) = (out.last(), course.first()) {
            // A backward course starts at the right edge, a forward one at the left.
            let side = if forward { -1.0 } else { 1.0 };
            let edge_x = if forward { 0.0 } else { width };
            let dy = q[1] - p[1];
            let bulge = (0.5 * dy.abs()).max(2.0 * r);
            // Half-ellipse arc length (Ramanujan), for the sample count.
            let (a, b) = (bulge, 0.5 * dy.abs());
            let h = ((a - b) / (a + b).max(1e-300)).powi(2);
            let arc = 0.5 * PI * (a + b) * (1.0 + 3.0 * h / (10.0 + (4.0 - 3.0 * h).sqrt()));
            let n = ((arc / spacing.max(1e-300)).ceil() as usize).max(3);
            for i in 1..n {
                let th = PI * i as f64 / n as f64;
                let f = 0.5 - 0.5 * th.cos();
                out.push([
                    edge_x
                        + side * bulge * th.sin()
                        + (1.0 - f) * (p[0] - edge_x)
                        + f * (q[0] - edge_x),
                    p[1] + dy * f,
                    ease(p[2], q[2], f),
                ]);
            }
        }
        out.extend(course);
    }
    out
}

impl Layout {
    /// How much a tube stretches the fabric around its circumference:
    /// 2 pi R / (wales * pitch); 1 for a flat swatch.
    pub fn circumferential_stretch(&self, tile: &PatternTile) -> f64 {
        match self.tube_radius {
            Some(r) => 2.0 * PI * r / (self.wales as f64 * tile.pitch[0]),
            None => 1.0,
        }
    }
}

/// The points of the yarn that starts as curve `c` in tile copy `copy`,
/// followed through its continuations, up to coordinate `axis` = `extent`
/// (inclusive, within a relative 1e-9).
fn follow_chain(t: &PeriodicTile, c: usize, copy: [i64; 2], axis: usize, extent: f64) -> Vec<Vec3> {
    let tol = 1e-9 * extent.abs().max(1e-12);
    let mut out = Vec::new();
    let (mut cur, mut copy) = (c, copy);
    // Every step advances along `axis` by at least one lattice step for the
    // tiles this module builds; the bound only guards against a malformed tile.
    let max_steps = 4 + (extent / t.lattice[axis][axis].abs().max(1e-300)).ceil() as usize * 2;
    for _ in 0..max_steps.min(10_000_000) {
        let shift: Vec3 = std::array::from_fn(|k| {
            copy[0] as f64 * t.lattice[0][k] + copy[1] as f64 * t.lattice[1][k]
        });
        for p in t.yarns.curve(cur) {
            let q = [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]];
            if q[axis] > extent + tol {
                return out;
            }
            out.push(q);
        }
        let (next, d) = t.next[cur];
        cur = next;
        copy = [copy[0] + d[0] as i64, copy[1] + d[1] as i64];
    }
    out
}

/// Repeats a periodic tile `n[0] x n[1]` times and joins curves through their
/// continuations into continuous yarns (open, or closed where a chain returns
/// to where it started). Used to check tiles (3x3) and by the relaxation stage.
pub fn tile_periodic(t: &PeriodicTile, n: [usize; 2]) -> Result<Yarns, PatternError> {
    t.validate()
        .map_err(|e| PatternError::Geometry(GeomError::Layout(e.to_string())))?;
    let nc = t.yarns.num_curves();
    let inside =
        |i: [i64; 2]| i[0] >= 0 && i[1] >= 0 && (i[0] as usize) < n[0] && (i[1] as usize) < n[1];
    let mut pred = vec![None; nc];
    for (c, &(to, d)) in t.next.iter().enumerate() {
        pred[to] = Some((c, d));
    }
    let idx = |c: usize, i: [i64; 2]| (i[1] as usize * n[0] + i[0] as usize) * nc + c;
    let mut used = vec![false; nc * n[0] * n[1]];
    let radius = t
        .yarns
        .radius
        .first()
        .copied()
        .unwrap_or(crate::geom::DEFAULT_RADIUS_M);
    let mut yarns = Yarns::new();
    // Starts first (chains entering from outside), then what is left is closed loops.
    for pass in 0..2 {
        for i1 in 0..n[1] as i64 {
            for i0 in 0..n[0] as i64 {
                for c in 0..nc {
                    let start = [i0, i1];
                    if used[idx(c, start)] {
                        continue;
                    }
                    let is_start = match pred[c] {
                        Some((_, d)) => !inside([i0 - d[0] as i64, i1 - d[1] as i64]),
                        None => true,
                    };
                    if pass == 0 && !is_start {
                        continue;
                    }
                    let (mut cur, mut copy) = (c, start);
                    let mut pts = Vec::new();
                    let mut closed = false;
                    while inside(copy) {
                        if used[idx(cur, copy)] {
                            closed = true;
                            break;
                        }
                        used[idx(cur, copy)] = true;
                        let shift: Vec3 = std::array::from_fn(|k| {
                            copy[0] as f64 * t.lattice[0][k] + copy[1] as f64 * t.lattice[1][k]
                        });
                        pts.extend(
                            t.yarns
                                .curve(cur)
                                .iter()
                                .map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]),
                        );
                        let (next, d) = t.next[cur];
                        cur = next;
                        copy = [copy[0] + d[0] as i64, copy[1] + d[1] as i64];
                    }
                    yarns.push_curve(&pts, closed, radius);
                }
            }
        }
    }
    yarns.validate()?;
    Ok(yarns)
}

#[cfg(test)]
mod tests {
    use super::curve::sample_equal_arclength;
    use super::*;

    #[test]
    fn sampling_is_even_and_excludes_end() {
        let (pts, len) = sample_equal_arclength(|t| [t.cos(), t.sin(), 0.0], 0.0, 2.0 * PI, 0.1, 4);
        assert!((len - 2.0 * PI).abs() < 1e-3);
        assert_eq!(pts.len(), 63);
        let d: Vec<f64> = pts
            .windows(2)
            .map(|w| crate::geom::dist(w[0], w[1]))
            .collect();
        let (lo, hi) = d
            .iter()
            .fold((f64::MAX, 0.0f64), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(hi - lo < 1e-3, "{lo} {hi}");
        assert!(crate::geom::dist(pts[0], [1.0, 0.0, 0.0]) < 1e-12);
    }

    #[test]
    fn ease_is_monotone_and_clamped() {
        assert_eq!(ease(1.0, 3.0, 0.0), 1.0);
        assert_eq!(ease(1.0, 3.0, 1.0), 3.0);
        assert_eq!(ease(1.0, 3.0, 2.0), 3.0);
        assert!((ease(1.0, 3.0, 0.5) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn tiling_follows_continuations_and_closes_loops() {
        // Curve 0 continues into curve 1 in the same copy, curve 1 into curve 0
        // one copy to the right; curve 2 into itself in the same copy (a loop).
        let mut y = Yarns::new();
        y.push_curve(&[[0.0, 0.0, 0.0], [0.25, 0.0, 0.0]], false, 0.01);
        y.push_curve(&[[0.5, 0.0, 0.0], [0.75, 0.0, 0.0]], false, 0.01);
        y.push_curve(
            &[[0.5, 0.5, 0.0], [0.6, 0.6, 0.0], [0.4, 0.6, 0.0]],
            false,
            0.01,
        );
        let t = PeriodicTile {
            yarns: y,
            lattice: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            next: vec![(1, [0, 0]), (0, [1, 0]), (2, [0, 0])],
        };
        let tiled = tile_periodic(&t, [3, 2]).unwrap();
        // Per row: one open yarn through 3 copies, and 3 closed loops.
        assert_eq!(tiled.num_curves(), 2 * (1 + 3));
        assert_eq!(tiled.num_closed(), 6);
        let open: Vec<usize> = (0..tiled.num_curves())
            .filter(|&c| !tiled.closed[c])
            .collect();
        assert_eq!(open.len(), 2);
        let row0 = tiled.curve(open[0]);
        assert_eq!(row0.len(), 12);
        for w in row0.windows(2) {
            assert!((crate::geom::dist(w[0], w[1]) - 0.25).abs() < 1e-12);
        }
    }

    #[test]
    fn bad_parameters_are_rejected() {
        let p = PatternParams {
            yarn_radius: -1.0,
            ..Default::default()
        };
        let e = build_tile(&builtin("stockinette").unwrap(), &p).unwrap_err();
        assert!(matches!(
            e,
            PatternError::BadParameter {
                name: "yarn_radius",
                ..
            }
        ));
        let t = build_tile(&builtin("stockinette").unwrap(), &PatternParams::default()).unwrap();
        let e = lay_out(
            &t,
            &Layout {
                courses: 0,
                wales: 3,
                tube_radius: None,
                helix: false,
                separate_courses: false,
            },
        )
        .unwrap_err();
        assert!(matches!(
            e,
            PatternError::BadParameter {
                name: "courses",
                ..
            }
        ));
    }
}
