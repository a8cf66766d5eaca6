//! Course and wale directions per tet, from the embedded rest yarns: the rest
//! directions of the fibre families ([`crate::sim::fibre`]).
//!
//! Within a stitch a knitted yarn turns every way (legs along the wales,
//! heads and sinkers along the course, through the fabric where loops
//! interlock), so its tangent alone does not say where the course runs. Its
//! chord over a window of arc length `W` longer than a loop does: the loops'
//! back-and-forth cancels and what remains points along the course (up to
//! sign: a flat swatch's yarn turns at each edge). Per voxel we sum, over
//! the yarn vertices in it and its neighbours,
//! * the chord tensor `Σ ĉ ĉᵀ` (`ĉ` the unit chord over `W` centred on the
//!   vertex): its principal eigenvector is the course;
//! * the covariance of the vertex positions: the fabric is a sheet a few
//!   yarns thick, so its least eigenvector is the fabric's normal `n` (the
//!   classic point-cloud normal; the yarns' tangents point through the
//!   fabric too often where loops interlock to say it as well).
//!
//! The wale is `n × course` and the course is made orthogonal to both. Tets
//! take their voxel's frame; a voxel whose neighbourhood holds no yarn
//! vertex widens it until it does (every voxel of an embedding holds yarn).
//! Pure: no files, no printing.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::EmbedError;
use crate::geom::{VoxelGrid, Yarns};

/// Parameters of [`course_and_wale`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OrientationParams {
    /// Chord window `W` in voxel edges (arc length of yarn, dimensionless).
    /// Default 20: about two stitches' yarn at the default 2.6 voxels per
    /// stitch width (a stitch takes about 3.5 widths of yarn).
    pub window_voxels: f64,
    /// Neighbourhood radius in voxels (Chebyshev distance) over which
    /// tensors are summed. Default 1.
    pub radius_voxels: i32,
}

impl Default for OrientationParams {
    fn default() -> Self {
        OrientationParams {
            window_voxels: 10.0,
            radius_voxels: 1,
        }
    }
}

/// Unit course and wale directions (rest configuration) per tet.
#[derive(Debug, Clone, PartialEq)]
pub struct CourseWale {
    pub course: Vec<[f64; 3]>,
    pub wale: Vec<[f64; 3]>,
    /// Mean over tets of the chord tensor's anisotropy `1 - λ2/λ1`
    /// (0: no preferred direction, 1: every chord along the course).
    pub mean_anisotropy: f64,
}

fn v3(p: &[f64; 3]) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// Per vertex of each curve: the unit chord over the arc-length window `w`
/// centred on it (clamped at open ends, wrapped on closed curves); `None`
/// where the curve has no extent.
fn chords(yarns: &Yarns, w: f64) -> Vec<Option<Vector3<f64>>> {
    let mut out = vec![None; yarns.points.len()];
    for c in 0..yarns.offsets.len().saturating_sub(1) {
        let (a, b) = (yarns.offsets[c], yarns.offsets[c + 1]);
        let n = b - a;
        if n < 2 {
            continue;
        }
        let closed = yarns.closed.get(c).copied().unwrap_or(false);
        let p = |i: usize| v3(&yarns.points[a + i]);
        // Cumulative arc length, one extra entry for the closing segment.
        let mut s = vec![0.0; n + 1];
        for i in 1..=n {
            let j = if i == n { 0 } else { i };
            s[i] = s[i - 1]
                + if i < n || closed {
                    (p(j) - p(i - 1)).norm()
                } else {
                    0.0
                };
        }
        let total = s[n];
        // Point at arc length t along the curve (t clamped or wrapped).
        let at = |t: f64| -> Vector3<f64> {
            let t = if closed {
                t.rem_euclid(total.max(f64::MIN_POSITIVE))
            } else {
                t.clamp(0.0, s[n - 1])
            };
            let k = s.partition_point(|&x| x <= t).clamp(1, n);
            let (i0, i1) = (k - 1, if k == n { 0 } else { k });
            let len = s[k] - s[k - 1];
            let f = if len > 0.0 { (t - s[k - 1]) / len } else { 0.0 };
            p(i0) + f * (p(i1) - p(i0))
        };
        for i in 0..n {
            let chord = at(s[i] + 0.5 * w) - at(s[i] - 0.5 * w);
            if chord.norm() > 0.0 {
                out[a + i] = Some(chord.normalize());
            }
        }
    }
    out
}

/// Course and wale directions of every tet of an embedding: `grid` and
/// `tet_voxel` (voxel index of each tet) as the asset stores them, `yarns`
/// the rest yarns it embeds.
pub fn course_and_wale(
    yarns: &Yarns,
    grid: &VoxelGrid,
    tet_voxel: &[u32],
    params: &OrientationParams,
) -> Result<CourseWale, EmbedError> {
    if !(params.window_voxels.is_finite()
        && params.window_voxels > 0.0
        && params.radius_voxels >= 0)
    {
        return Err(EmbedError::Parameter(format!(
            "orientation window {} voxels and radius {}: both must be positive",
            params.window_voxels, params.radius_voxels
        )));
    }
    let nv = grid.voxels.len();
    if let Some(t) = tet_voxel.iter().position(|&v| v as usize >= nv) {
        return Err(EmbedError::Internal(format!(
            "tet {t} names voxel {} of {nv}",
            tet_voxel[t]
        )));
    }
    let index = |k: [i32; 3]| grid.voxels.binary_search(&k).ok();
    // Per voxel: chord and tangent tensors of its own vertices.
    let mut own = vec![Acc::default(); nv];
    let w = params.window_voxels * grid.h;
    for (p, ct) in yarns.points.iter().zip(chords(yarns, w)) {
        let Some(c) = ct else { continue };
        let g = grid.to_grid(*p);
        let k = [
            g[0].floor() as i32,
            g[1].floor() as i32,
            g[2].floor() as i32,
        ];
        if let Some(v) = index(k) {
            // Positions relative to the voxel's grid origin, in voxels:
            // well scaled whatever the asset's placement.
            own[v].add(&c, &Vector3::new(g[0], g[1], g[2]));
        }
    }
    let global = own.iter().fold(Acc::default(), |mut a, o| {
        a.merge(o);
        a
    });
    if global.n == 0 {
        return Err(EmbedError::Parameter(
            "no yarn vertex lies in the asset's voxels".into(),
        ));
    }
    let frames: Vec<LocalFrame> = (0..nv)
        .map(|v| {
            // Widen until there are enough points for a covariance with a
            // clear least direction.
            let sum = (params.radius_voxels..=params.radius_voxels + 5)
                .map(|r| neighbourhood(grid, &own, v, r))
                .find(|acc| acc.n >= 8)
                .unwrap_or_else(|| global.clone());
            frame_of(&sum.chords, &sum.covariance())
        })
        .collect();
    let mut out = CourseWale {
        course: Vec::with_capacity(tet_voxel.len()),
        wale: Vec::with_capacity(tet_voxel.len()),
        mean_anisotropy: 0.0,
    };
    for &v in tet_voxel {
        let (c, wl, an) = frames[v as usize];
        out.course.push([c[0], c[1], c[2]]);
        out.wale.push([wl[0], wl[1], wl[2]]);
        out.mean_anisotropy += an;
    }
    out.mean_anisotropy /= tet_voxel.len().max(1) as f64;
    Ok(out)
}

/// Course, wale (unit) and the chord anisotropy of one voxel.
type LocalFrame = (Vector3<f64>, Vector3<f64>, f64);

/// Sums over yarn vertices: chord tensor, count, positions and their
/// second moments (grid units).
#[derive(Debug, Clone, Default)]
struct Acc {
    chords: Matrix3<f64>,
    n: usize,
    sum: Vector3<f64>,
    second: Matrix3<f64>,
}

impl Acc {
    fn add(&mut self, chord: &Vector3<f64>, p: &Vector3<f64>) {
        self.chords += chord * chord.transpose();
        self.n += 1;
        self.sum += p;
        self.second += p * p.transpose();
    }
    fn merge(&mut self, o: &Acc) {
        self.chords += o.chords;
        self.n += o.n;
        self.sum += o.sum;
        self.second += o.second;
    }
    fn covariance(&self) -> Matrix3<f64> {
        let n = self.n.max(1) as f64;
        let mean = self.sum / n;
        self.second / n - mean * mean.transpose()
    }
}

/// The sums of voxel `v` and its neighbours within Chebyshev distance `r`.
fn neighbourhood(grid: &VoxelGrid, own: &[Acc], v: usize, r: i32) -> Acc {
    let mut acc = Acc::default();
    let c = grid.voxels[v];
    for di in -r..=r {
        for dj in -r..=r {
            for dk in -r..=r {
                if let Ok(u) = grid
                    .voxels
                    .binary_search(&[c[0] + di, c[1] + dj, c[2] + dk])
                {
                    acc.merge(&own[u]);
                }
            }
        }
    }
    acc
}

/// Course, wale and the chord anisotropy from the chord tensor and the
/// positions' covariance.
fn frame_of(chords: &Matrix3<f64>, covariance: &Matrix3<f64>) -> LocalFrame {
    let ce = SymmetricEigen::new(*chords);
    let order = |e: &SymmetricEigen<f64, nalgebra::U3>| {
        let mut i = [0usize, 1, 2];
        i.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
        i
    };
    let ci = order(&ce);
    let course0 = ce.eigenvectors.column(ci[0]).into_owned();
    let l1 = ce.eigenvalues[ci[0]].max(f64::MIN_POSITIVE);
    let anisotropy = (1.0 - ce.eigenvalues[ci[1]] / l1).clamp(0.0, 1.0);
    let te = SymmetricEigen::new(*covariance);
    let ti = order(&te);
    let mut normal = te.eigenvectors.column(ti[2]).into_owned();
    // The normal must not lie along the course (a degenerate tensor): then
    // take the chords' least direction.
    if normal.cross(&course0).norm() < 0.5 {
        normal = ce.eigenvectors.column(ci[2]).into_owned();
    }
    let wale = normal.cross(&course0).normalize();
    let course = wale.cross(&normal).normalize();
    // A deterministic sign: the largest component positive.
    let signed = |v: Vector3<f64>| {
        let k = v.iamax();
        if v[k] < 0.0 {
            -v
        } else {
            v
        }
    };
    (signed(course), signed(wale), anisotropy)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embed::{default_origin, tetrahedralize, voxelize};
    use crate::yarn::pattern::{build_tile, builtin, lay_out, Layout, PatternParams};

    fn swatch(pattern: &str) -> Yarns {
        let tile = build_tile(&builtin(pattern).unwrap(), &PatternParams::default()).unwrap();
        lay_out(
            &tile,
            &Layout {
                courses: 16,
                wales: 16,
                tube_radius: None,
                helix: false,
                separate_courses: false,
            },
        )
        .unwrap()
    }

    fn grid_of(y: &Yarns, h: f64) -> (VoxelGrid, Vec<u32>) {
        let (grid, _) = voxelize(y, h, default_origin(y, h), 10_000_000).unwrap();
        let (_, tet_voxel) = tetrahedralize(&grid);
        (grid, tet_voxel)
    }

    /// 16 x 16 stitches: the edge voxels, where the yarn turns and the
    /// neighbourhood is one-sided, are the 5-10% that deviate.
    #[test]
    fn a_flat_swatch_runs_its_courses_along_x_and_wales_along_y() {
        for pattern in ["stockinette", "rib1x1", "garter"] {
            let y = swatch(pattern);
            let (grid, tet_voxel) = grid_of(&y, 0.0032);
            let cw = course_and_wale(&y, &grid, &tet_voxel, &OrientationParams::default()).unwrap();
            let along = |d: &[[f64; 3]], k: usize| {
                d.iter().filter(|v| v[k].abs() > 0.9).count() as f64 / d.len() as f64
            };
            let (cx, wy) = (along(&cw.course, 0), along(&cw.wale, 1));
            eprintln!(
                "{pattern}: course along x {cx:.3}, wale along y {wy:.3}, anisotropy {:.3}",
                cw.mean_anisotropy
            );
            assert!(cx > 0.9 && wy > 0.9, "{pattern}: {cx} {wy}");
            for (c, w) in cw.course.iter().zip(&cw.wale) {
                let (c, w) = (v3(c), v3(w));
                assert!((c.norm() - 1.0).abs() < 1e-9 && (w.norm() - 1.0).abs() < 1e-9);
                assert!(c.dot(&w).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn a_rotated_swatch_rotates_its_directions() {
        let y = swatch("stockinette");
        let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.6);
        let mut r = y.clone();
        for p in r.points.iter_mut() {
            let q = rot * v3(p);
            *p = [q[0], q[1], q[2]];
        }
        let (grid, tet_voxel) = grid_of(&r, 0.0032);
        let cw = course_and_wale(&r, &grid, &tet_voxel, &OrientationParams::default()).unwrap();
        let want = rot * Vector3::x();
        let close = cw
            .course
            .iter()
            .filter(|c| v3(c).dot(&want).abs() > 0.9)
            .count() as f64
            / cw.course.len() as f64;
        assert!(close > 0.9, "{close}");
        assert!(course_and_wale(
            &r,
            &grid,
            &tet_voxel,
            &OrientationParams {
                window_voxels: 0.0,
                radius_voxels: 1
            }
        )
        .is_err());
    }
}
