//! Clearance between yarns: the minimum distance between non-adjacent yarn
//! segments, the quantity the contact model keeps above 2r (Leaf Eq. 9-10:
//! contact acts for distance / 2r < 1).
//!
//! "Non-adjacent" means: on different curves, or on the same curve with more
//! than `exclude_arc` of yarn between them (along the curve, the shorter way
//! round for a closed curve). Segments of one yarn a few vertices apart are
//! always closer than 2r, so they must be excluded; with the default
//! `exclude_arc = pi r` a bend of centre-line radius >= r still counts its
//! two sides as non-adjacent (half a turn of radius r is pi r long).

use std::collections::HashMap;

use crate::geom::{Vec3, Yarns};

/// Result of [`min_segment_distance`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MinDistance {
    /// Smallest centre-line distance (m) between non-adjacent segments, or
    /// `cutoff` when no pair is closer than that.
    pub distance: f64,
    /// `distance / (r_a + r_b)`: 1 means the yarn surfaces touch.
    pub ratio: f64,
    /// The two segments (global indices in `Yarns::segments` order), `None`
    /// when no pair was closer than the cutoff.
    pub segments: Option<[usize; 2]>,
}

/// Minimum distance between non-adjacent segments closer than `cutoff` (m);
/// pairs further apart are not examined. Uses a uniform grid of cell size
/// `cutoff + longest segment`, so every pair within `cutoff` is found.
/// Deterministic: ties go to the lowest segment indices.
pub fn min_segment_distance(yarns: &Yarns, exclude_arc: f64, cutoff: f64) -> MinDistance {
    let nseg = yarns.num_segments();
    let mut seg: Vec<[usize; 2]> = Vec::with_capacity(nseg);
    let mut seg_curve: Vec<usize> = Vec::with_capacity(nseg);
    // Arc length at the start and end of every segment, and per curve its total.
    let mut arc: Vec<[f64; 2]> = Vec::with_capacity(nseg);
    let mut curve_len = Vec::with_capacity(yarns.num_curves());
    for c in 0..yarns.num_curves() {
        let mut s = 0.0;
        for [a, b] in yarns.segments_of(c) {
            let l = crate::geom::dist(yarns.points[a], yarns.points[b]);
            seg.push([a, b]);
            seg_curve.push(c);
            arc.push([s, s + l]);
            s += l;
        }
        curve_len.push(s);
    }
    let max_len = arc.iter().map(|a| a[1] - a[0]).fold(0.0, f64::max);
    let cell = (cutoff + max_len).max(1e-12);
    let key = |p: Vec3| -> [i64; 3] { std::array::from_fn(|k| (p[k] / cell).floor() as i64) };
    let mid = |i: usize| -> Vec3 {
        let (a, b) = (yarns.points[seg[i][0]], yarns.points[seg[i][1]]);
        std::array::from_fn(|k| 0.5 * (a[k] + b[k]))
    };
    // Only looked up, never iterated: the result does not depend on hash order.
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for i in 0..seg.len() {
        grid.entry(key(mid(i))).or_default().push(i);
    }
    let mut best = MinDistance {
        distance: cutoff,
        ratio: f64::INFINITY,
        segments: None,
    };
    let radius_of = |i: usize| yarns.radius_at(seg[i][0]);
    for i in 0..seg.len() {
        let k = key(mid(i));
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &j in list {
                        if j <= i {
                            continue;
                        }
                        if seg_curve[i] == seg_curve[j] {
                            let c = seg_curve[i];
                            let gap = arc[j][0] - arc[i][1];
                            let gap = if yarns.closed[c] {
                                gap.min(curve_len[c] - arc[j][1] + arc[i][0])
                            } else {
                                gap
                            };
                            if gap < exclude_arc {
                                continue;
                            }
                        }
                        let p = &yarns.points;
                        let d = segment_distance(
                            p[seg[i][0]],
                            p[seg[i][1]],
                            p[seg[j][0]],
                            p[seg[j][1]],
                        );
                        if d < best.distance {
                            best = MinDistance {
                                distance: d,
                                ratio: d / (radius_of(i) + radius_of(j)),
                                segments: Some([i, j]),
                            };
                        }
                    }
                }
            }
        }
    }
    if best.segments.is_none() {
        let r = yarns.radius.iter().copied().fold(0.0, f64::max);
        best.ratio = if r > 0.0 {
            cutoff / (2.0 * r)
        } else {
            f64::INFINITY
        };
    }
    best
}

/// Distance between segments p0-p1 and q0-q1 (clamped closest points,
/// Ericson §5.1.9): the yarn simulator's contact routine, so the generator's
/// clearance and the simulator's contact test measure the same thing.
pub fn segment_distance(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> f64 {
    crate::yarn::sim::contact::segment_distance(p0, p1, q0, q1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_distance_cases() {
        // Crossing at right angles 2 apart in z.
        let d = segment_distance(
            [-1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 2.0],
            [0.0, 1.0, 2.0],
        );
        assert!((d - 2.0).abs() < 1e-12);
        // Parallel, offset.
        let d = segment_distance([0.0; 3], [1.0, 0.0, 0.0], [0.5, 3.0, 0.0], [2.0, 3.0, 0.0]);
        assert!((d - 3.0).abs() < 1e-12);
        // Endpoint to endpoint.
        let d = segment_distance([0.0; 3], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0], [3.0, 1.0, 0.0]);
        assert!((d - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn grid_search_matches_brute_force_and_skips_neighbours() {
        // Two parallel lines 0.5 apart and one U-turn curve.
        let mut y = Yarns::new();
        let line = |z: f64| -> Vec<Vec3> { (0..20).map(|i| [i as f64 * 0.3, 0.0, z]).collect() };
        y.push_curve(&line(0.0), false, 0.2);
        y.push_curve(&line(0.5), false, 0.2);
        let u: Vec<Vec3> = (0..40)
            .map(|i| {
                let t = std::f64::consts::PI * i as f64 / 39.0;
                [10.0 + t.sin(), 1.0 - t.cos(), 0.0]
            })
            .collect();
        y.push_curve(&u, false, 0.2);
        let m = min_segment_distance(&y, std::f64::consts::PI * 0.2, 2.0);
        assert!((m.distance - 0.5).abs() < 1e-12, "{m:?}");
        assert!((m.ratio - 1.25).abs() < 1e-12);
        // The U-turn (radius 1) counts its sides (2 apart) only beyond the exclusion.
        let mut only_u = Yarns::new();
        only_u.push_curve(&u, false, 0.2);
        // Excluding 0.5 of arc, the closest counted pair is about 0.5 apart (a chord).
        let m = min_segment_distance(&only_u, 0.5, 5.0);
        assert!(m.distance > 0.45 && m.distance < 0.65, "{m:?}");
        let m = min_segment_distance(&only_u, 10.0, 5.0);
        assert_eq!(m.segments, None);
    }
}
