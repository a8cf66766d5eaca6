//! The test rig's geometry: a stretch axis in the swatch plane, clamp bands
//! at both ends, the gauge section between them.

use super::model::FabricError;
use crate::geom::{Vec3, Yarns};

/// Which way a swatch is pulled: along the courses (weft, x), along the
/// wales (warp, y) or at 45 degrees between them (bias).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    Weft,
    Warp,
    Bias,
}

impl Direction {
    pub fn name(self) -> &'static str {
        match self {
            Direction::Weft => "weft",
            Direction::Warp => "warp",
            Direction::Bias => "bias",
        }
    }

    /// Unit stretch axis and the in-plane transverse axis (swatch in xy).
    pub fn axes(self) -> (Vec3, Vec3) {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        match self {
            Direction::Weft => ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            Direction::Warp => ([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]),
            Direction::Bias => ([h, h, 0.0], [-h, h, 0.0]),
        }
    }
}

/// A direction name other than `weft`, `warp` and `bias`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown direction {name:?} (weft, warp, bias)")]
pub struct UnknownDirection {
    /// The name as given.
    pub name: String,
}

impl std::str::FromStr for Direction {
    type Err = UnknownDirection;
    fn from_str(s: &str) -> Result<Self, UnknownDirection> {
        match s {
            "weft" => Ok(Direction::Weft),
            "warp" => Ok(Direction::Warp),
            "bias" => Ok(Direction::Bias),
            _ => Err(UnknownDirection {
                name: s.to_string(),
            }),
        }
    }
}

pub(crate) fn along(p: Vec3, a: Vec3) -> f64 {
    p[0] * a[0] + p[1] * a[1] + p[2] * a[2]
}

/// Clamp bands and gauge of a swatch along an axis.
#[derive(Debug, Clone)]
pub struct Rig {
    pub axis: Vec3,
    pub transverse: Vec3,
    /// Coordinates along the axis of the swatch's ends (m).
    pub s_min: f64,
    pub s_max: f64,
    /// Depth of each clamp (m).
    pub clamp_depth: f64,
    /// Vertices held by the fixed (low) and the moving (high) clamp.
    pub low: Vec<bool>,
    pub high: Vec<bool>,
}

impl Rig {
    /// Clamps `depth` deep at both ends of `points` along `axis`.
    pub fn new(points: &[Vec3], axis: Vec3, transverse: Vec3, depth: f64) -> Rig {
        let s: Vec<f64> = points.iter().map(|&p| along(p, axis)).collect();
        let s_min = s.iter().copied().fold(f64::INFINITY, f64::min);
        let s_max = s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Rig {
            axis,
            transverse,
            s_min,
            s_max,
            clamp_depth: depth,
            low: s.iter().map(|&v| v <= s_min + depth).collect(),
            high: s.iter().map(|&v| v >= s_max - depth).collect(),
        }
    }

    /// Free length between the clamps at rest (m).
    pub fn gauge(&self) -> f64 {
        self.s_max - self.s_min - 2.0 * self.clamp_depth
    }

    /// Transverse extent of the vertices in the middle fifth of the gauge.
    pub fn mid_width(&self, points: &[Vec3], offset: f64) -> f64 {
        let mid = 0.5 * (self.s_min + self.s_max + offset);
        let half = 0.1 * (self.gauge() + offset);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &p in points {
            if (along(p, self.axis) - mid).abs() <= half {
                let t = along(p, self.transverse);
                lo = lo.min(t);
                hi = hi.max(t);
            }
        }
        (hi - lo).max(0.0)
    }

    pub fn any_clamped(&self) -> Vec<bool> {
        self.low
            .iter()
            .zip(&self.high)
            .map(|(a, b)| *a || *b)
            .collect()
    }
}

/// The test piece of a bias test (Sperl 2022 §4.3: swatches cut at 45
/// degrees to the courses): the part of `yarns` inside the rectangle
/// `length` along `axis` by `width` along `transverse` (m) centred on the
/// yarns' bounding box. Yarns are cut where they leave it, as scissors cut
/// a swatch from the fabric: the cut ends are free and only contact holds
/// them (the clamps hold the ends' at the clamped edges). Pieces of fewer
/// than `min_points` vertices (corner fragments not held by any loop) are
/// left out. For generated yarns, before relaxation: a stored rest shape
/// cannot be cut and is refused.
pub fn cut_rectangle(
    yarns: &Yarns,
    axis: Vec3,
    transverse: Vec3,
    length: f64,
    width: f64,
    min_points: usize,
) -> Result<Yarns, FabricError> {
    if yarns.rest.is_some() {
        return Err(FabricError::Setup(
            "a yarn set with a stored rest shape cannot be cut to a test piece".into(),
        ));
    }
    let b = crate::geom::bounds_of(&yarns.points)
        .ok_or_else(|| FabricError::Setup("no yarn points to cut a test piece from".into()))?;
    let c = [
        0.5 * (b.min[0] + b.max[0]),
        0.5 * (b.min[1] + b.max[1]),
        0.5 * (b.min[2] + b.max[2]),
    ];
    let inside = |p: Vec3| {
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        along(d, axis).abs() <= 0.5 * length && along(d, transverse).abs() <= 0.5 * width
    };
    let mut out = Yarns::new();
    let mut density = Vec::new();
    let mut vertex_radius = Vec::new();
    for k in 0..yarns.num_curves() {
        let range = yarns.curve_range(k);
        let idx: Vec<usize> = range.clone().collect();
        let keep: Vec<bool> = idx.iter().map(|&v| inside(yarns.points[v])).collect();
        if yarns.closed[k] && keep.iter().all(|&x| x) {
            push_piece(
                yarns,
                k,
                &idx,
                true,
                &mut out,
                &mut density,
                &mut vertex_radius,
            );
            continue;
        }
        // A closed curve is opened at a vertex outside, so that its runs
        // inside are contiguous.
        let start = if yarns.closed[k] {
            keep.iter().position(|&x| !x).unwrap_or(0)
        } else {
            0
        };
        let order: Vec<usize> = (0..idx.len()).map(|i| (start + i) % idx.len()).collect();
        let mut run: Vec<usize> = Vec::new();
        for &i in order.iter().chain(std::iter::once(&usize::MAX)) {
            if i != usize::MAX && keep[i] {
                run.push(idx[i]);
                continue;
            }
            if run.len() >= min_points.max(2) {
                push_piece(
                    yarns,
                    k,
                    &run,
                    false,
                    &mut out,
                    &mut density,
                    &mut vertex_radius,
                );
            }
            run.clear();
        }
    }
    if out.num_curves() == 0 {
        return Err(FabricError::Setup(format!(
            "no yarn of at least {min_points} vertices inside the {length:.4} x {width:.4} m test piece"
        )));
    }
    if yarns.linear_density.is_some() {
        out.linear_density = Some(density);
    }
    if yarns.vertex_radius.is_some() {
        out.vertex_radius = Some(vertex_radius);
    }
    Ok(out)
}

/// Appends the vertices `run` of curve `k` as one curve, with its radius,
/// linear density and per-vertex radii.
fn push_piece(
    yarns: &Yarns,
    k: usize,
    run: &[usize],
    closed: bool,
    out: &mut Yarns,
    density: &mut Vec<f64>,
    vertex_radius: &mut Vec<f64>,
) {
    let pts: Vec<Vec3> = run.iter().map(|&v| yarns.points[v]).collect();
    out.push_curve(&pts, closed, yarns.radius[k]);
    if let Some(ld) = &yarns.linear_density {
        density.push(ld[k]);
    }
    if let Some(vr) = &yarns.vertex_radius {
        vertex_radius.extend(run.iter().map(|&v| vr[v]));
    }
}

/// The pieces of a cut swatch that hang together: the curves of the
/// largest group (by vertex count) linked by contact, two curves being
/// linked where segments of theirs come within `touch` x the sum of their
/// radii. A bias cut leaves corner fragments that no loop holds; after the
/// relaxation they lie apart from the piece, and a clamp band that caught
/// only them would hold nothing (as scissors' offcuts fall away).
pub fn held_together(yarns: &Yarns, touch: f64) -> Vec<bool> {
    use std::collections::HashMap;
    let nc = yarns.num_curves();
    let mut parent: Vec<usize> = (0..nc).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut seg: Vec<([usize; 2], usize)> = Vec::with_capacity(yarns.num_segments());
    for c in 0..nc {
        seg.extend(yarns.segments_of(c).map(|s| (s, c)));
    }
    let r_max = (0..yarns.num_points())
        .map(|v| yarns.radius_at(v))
        .fold(0.0, f64::max);
    let reach = 2.0 * r_max * touch + yarns.max_segment_length();
    let cell = reach.max(1e-12);
    let mid = |s: [usize; 2]| -> Vec3 {
        let (a, b) = (yarns.points[s[0]], yarns.points[s[1]]);
        std::array::from_fn(|k| 0.5 * (a[k] + b[k]))
    };
    let key = |p: Vec3| -> [i64; 3] { std::array::from_fn(|k| (p[k] / cell).floor() as i64) };
    // Only looked up, never iterated: the result does not depend on hash order.
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, (s, _)) in seg.iter().enumerate() {
        grid.entry(key(mid(*s))).or_default().push(i);
    }
    for (i, &(s, c)) in seg.iter().enumerate() {
        let k = key(mid(s));
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(cands) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &j in cands {
                        let (t, d) = seg[j];
                        if j <= i || d == c || root(&mut parent, c) == root(&mut parent, d) {
                            continue;
                        }
                        let gap = crate::yarn::pattern::distance::segment_distance(
                            yarns.points[s[0]],
                            yarns.points[s[1]],
                            yarns.points[t[0]],
                            yarns.points[t[1]],
                        );
                        let limit = touch * (yarns.radius_at(s[0]) + yarns.radius_at(t[0]));
                        if gap <= limit {
                            let (a, b) = (root(&mut parent, c), root(&mut parent, d));
                            parent[a.max(b)] = a.min(b);
                        }
                    }
                }
            }
        }
    }
    let mut size = vec![0usize; nc];
    for c in 0..nc {
        let r = root(&mut parent, c);
        size[r] += yarns.curve_range(c).len();
    }
    // Ties go to the group of the lowest curve index (deterministic).
    let best = (0..nc).fold(0, |b, r| if size[r] > size[b] { r } else { b });
    (0..nc).map(|c| root(&mut parent, c) == best).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offcuts_that_touch_nothing_are_not_held() {
        let r = 0.001;
        let mut y = Yarns::new();
        // Two parallel yarns touching (axes 2r apart) and a third crossing
        // the second just above it: one piece. A fragment 1 cm away, and a
        // pair touching each other but not the piece.
        y.push_curve(
            &[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0]],
            false,
            r,
        );
        y.push_curve(&[[0.0, 0.002, 0.0], [0.02, 0.002, 0.0]], false, r);
        y.push_curve(&[[0.01, 0.0041, -0.01], [0.01, 0.0041, 0.01]], false, r);
        y.push_curve(&[[0.0, 0.012, 0.0], [0.005, 0.012, 0.0]], false, r);
        y.push_curve(&[[0.05, 0.0, 0.0], [0.06, 0.0, 0.0]], false, r);
        y.push_curve(&[[0.05, 0.0021, 0.0], [0.06, 0.0021, 0.0]], false, r);
        assert_eq!(
            held_together(&y, 1.1),
            [true, true, true, false, false, false]
        );
        // A tighter contact threshold drops the crossing yarn 2.1r away.
        assert!(!held_together(&y, 1.0)[2]);
    }
}
