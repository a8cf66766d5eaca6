//! How a relaxed flat swatch differs from the generated one: its size
//! (rib draw-in, garter shortening) and how far its edges leave the
//! fabric plane (stockinette curl). Pure geometry on two point sets with
//! the same vertices: the generated points name the regions (edge bands,
//! centre), the relaxed points are measured.
//!
//! Frame as in [`super`]: courses along +X, wales along +Y, +Z the front
//! (knit face). A stockinette swatch curls its side edges (the ends of the
//! courses) to the back and its top and bottom edges to the front; a rib
//! or garter, balanced between the faces, stays flat.

use crate::geom::vec3::{cross, dot, norm, scale, sub};
use crate::geom::Vec3;

/// Size and edge curl of a relaxed swatch against the generated one.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Character {
    /// Bounding-box size of the generated and the relaxed swatch (m).
    pub generated_size: [f64; 3],
    pub relaxed_size: [f64; 3],
    /// Relaxed over generated extent along the courses (x) and the wales
    /// (y): below 1 the swatch drew in (x) or shortened (y).
    pub width_ratio: f64,
    pub height_ratio: f64,
    /// Mean signed distance (m, + to the front) of the vertices in each
    /// edge band from the plane of the swatch's centre: left, right (the
    /// course ends), bottom, top. The bands are one pitch deep and span the
    /// middle third of their edge in the generated layout.
    pub edge_rise_m: [f64; 4],
    /// Mean rise of the left and right edges (m): negative when the course
    /// ends curl to the back (stockinette).
    pub side_curl_m: f64,
    /// Mean rise of the bottom and top edges (m): positive when they curl
    /// to the front (stockinette).
    pub end_curl_m: f64,
}

/// Measures `relaxed` against `generated` (same vertices, same order);
/// `pitch` = [wale width, course height] of the generated layout (m), the
/// edge bands one pitch deep. `None` when the point sets differ in length
/// or the swatch is too small for a centre region of at least 3 vertices.
pub fn character(generated: &[Vec3], relaxed: &[Vec3], pitch: [f64; 2]) -> Option<Character> {
    if generated.len() != relaxed.len() {
        return None;
    }
    let gb = crate::geom::bounds_of(generated)?;
    let rb = crate::geom::bounds_of(relaxed)?;
    let (gs, rs) = (gb.size(), rb.size());
    // Centre: the middle third in both in-plane directions.
    let third = |p: Vec3, k: usize| {
        let f = (p[k] - gb.min[k]) / gs[k].max(1e-300);
        (1.0 / 3.0..=2.0 / 3.0).contains(&f)
    };
    let centre: Vec<Vec3> = generated
        .iter()
        .zip(relaxed)
        .filter(|(g, _)| third(**g, 0) && third(**g, 1))
        .map(|(_, r)| *r)
        .collect();
    let (c, n) = fit_plane(&centre)?;
    // Each band spans only the middle third of its edge, so that a side
    // edge's curl does not enter the top and bottom bands at the corners.
    let bands: [Box<dyn Fn(Vec3) -> bool>; 4] = [
        Box::new(|g: Vec3| g[0] <= gb.min[0] + pitch[0] && third(g, 1)),
        Box::new(|g: Vec3| g[0] >= gb.max[0] - pitch[0] && third(g, 1)),
        Box::new(|g: Vec3| g[1] <= gb.min[1] + pitch[1] && third(g, 0)),
        Box::new(|g: Vec3| g[1] >= gb.max[1] - pitch[1] && third(g, 0)),
    ];
    let mut rise = [0.0; 4];
    for (k, inside) in bands.iter().enumerate() {
        let (sum, count) = generated
            .iter()
            .zip(relaxed)
            .filter(|(g, _)| inside(**g))
            .fold((0.0, 0usize), |(s, m), (_, r)| {
                (s + dot(sub(*r, c), n), m + 1)
            });
        rise[k] = if count > 0 { sum / count as f64 } else { 0.0 };
    }
    Some(Character {
        generated_size: gs,
        relaxed_size: rs,
        width_ratio: rs[0] / gs[0].max(1e-300),
        height_ratio: rs[1] / gs[1].max(1e-300),
        edge_rise_m: rise,
        side_curl_m: 0.5 * (rise[0] + rise[1]),
        end_curl_m: 0.5 * (rise[2] + rise[3]),
    })
}

/// Least-squares plane through `points`: centroid and unit normal with a
/// non-negative z (the front). The normal is the direction of least spread
/// (smallest eigenvector of the scatter matrix, by inverse iteration on the
/// 3x3 matrix); `None` for fewer than 3 points or a degenerate set.
fn fit_plane(points: &[Vec3]) -> Option<(Vec3, Vec3)> {
    if points.len() < 3 {
        return None;
    }
    let m = points.len() as f64;
    let c: Vec3 = std::array::from_fn(|k| points.iter().map(|p| p[k]).sum::<f64>() / m);
    let mut s = [[0.0; 3]; 3];
    for p in points {
        let d = sub(*p, c);
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += d[i] * d[j];
            }
        }
    }
    // The normal minimises n^T S n: inverse iteration n <- S^-1 n.
    let trace = s[0][0] + s[1][1] + s[2][2];
    if !(trace > 0.0) {
        return None;
    }
    // Regularise by a tiny multiple of the trace so that an exactly flat
    // set (smallest eigenvalue 0) still inverts.
    for (i, row) in s.iter_mut().enumerate() {
        row[i] += 1e-12 * trace;
    }
    let inv = invert3(&s)?;
    let mut n = [0.0, 0.0, 1.0];
    for _ in 0..50 {
        let next: Vec3 = std::array::from_fn(|i| dot(inv[i], n));
        let l = norm(next);
        if !(l > 0.0 && l.is_finite()) {
            return None;
        }
        n = scale(next, 1.0 / l);
    }
    if n[2] < 0.0 {
        n = scale(n, -1.0);
    }
    Some((c, n))
}

/// Inverse of a 3x3 matrix by cofactors; `None` when singular.
fn invert3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let cols = [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ];
    // Rows of the inverse are cross products of the columns / det.
    let r0 = cross(cols[1], cols[2]);
    let r1 = cross(cols[2], cols[0]);
    let r2 = cross(cols[0], cols[1]);
    let det = dot(cols[0], r0);
    if !(det.abs() > 0.0 && det.is_finite()) {
        return None;
    }
    Some([
        scale(r0, 1.0 / det),
        scale(r1, 1.0 / det),
        scale(r2, 1.0 / det),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(nx: usize, ny: usize, h: f64) -> Vec<Vec3> {
        let mut p = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                p.push([i as f64 * h, j as f64 * h, 0.0]);
            }
        }
        p
    }

    #[test]
    fn flat_and_rigidly_moved_swatches_do_not_curl() {
        let g = grid(21, 15, 0.001);
        // Tilted about both axes and shifted: a rigid motion.
        let (a, b) = (0.2f64, -0.15f64);
        let r: Vec<Vec3> = g
            .iter()
            .map(|p| {
                let (x, y, z) = (p[0], p[1], p[2]);
                // Rotate about y by a, then about x by b.
                let (x1, z1) = (a.cos() * x + a.sin() * z, -a.sin() * x + a.cos() * z);
                let (y2, z2) = (b.cos() * y - b.sin() * z1, b.sin() * y + b.cos() * z1);
                [x1 + 0.3, y2 - 0.1, z2 + 0.05]
            })
            .collect();
        let c = character(&g, &r, [0.002, 0.002]).unwrap();
        for e in c.edge_rise_m {
            assert!(e.abs() < 1e-12, "{c:?}");
        }
        let c0 = character(&g, &g, [0.002, 0.002]).unwrap();
        assert!((c0.width_ratio - 1.0).abs() < 1e-12 && (c0.height_ratio - 1.0).abs() < 1e-12);
    }

    #[test]
    fn curled_edges_and_shrinkage_are_measured_with_their_signs() {
        let g = grid(21, 15, 0.001);
        // Side edges (x ends) bent to the back, top and bottom to the
        // front, and the swatch narrowed to 80% along x.
        let (xm, ym) = (0.010, 0.007);
        let r: Vec<Vec3> = g
            .iter()
            .map(|p| {
                let (dx, dy) = (p[0] - xm, p[1] - ym);
                [
                    xm + 0.8 * dx,
                    p[1],
                    -50.0 * dx.powi(4) / 1e-6 + 30.0 * dy.powi(4) / 1e-6,
                ]
            })
            .collect();
        let c = character(&g, &r, [0.002, 0.002]).unwrap();
        assert!(c.side_curl_m < -1e-4, "{c:?}");
        assert!(c.end_curl_m > 1e-5, "{c:?}");
        assert!((c.width_ratio - 0.8).abs() < 1e-12, "{c:?}");
        assert!((c.height_ratio - 1.0).abs() < 1e-12, "{c:?}");
        // Mismatched point sets are refused.
        assert!(character(&g, &r[1..], [0.002, 0.002]).is_none());
    }
}
