//! Welding repeated points of yarn curves.
//!
//! Real files repeat points: Cem Yuksel's glove BCC holds 8 consecutive
//! duplicates, each a segment of length 0, which the rods model refuses
//! ("edge has length 0") and which carry no shape. Readers weld them
//! ([`Yarns::weld`]) and keep the map ([`Weld`]) so that everything aligned
//! with the file's points (per-vertex radii, the frames of a sequence or an
//! HDF5 file, per-vertex forces) follows the same numbering.

use super::vec3::{norm, sub};
use super::{Vec3, YarnFrames, Yarns};

/// Consecutive points of a curve closer than this many yarn radii, or
/// this fraction of the curve's mean segment length where that is
/// shorter, are one point. Exact duplicates always weld; the tolerance
/// also catches copies that went through float32 (a BCC stores float32:
/// one unit in the last place of a coordinate 1 m from the origin is 6e-8
/// m, 2.4e-4 radii of a 0.25 mm yarn), and it is far below any sampling
/// that carries shape (64 samples per BCC span, the most a reader makes,
/// are still about 1/64 of a radius apart). The segment bound keeps a
/// radius too large for the file (a wrong `--units`, a default radius on
/// a tiny curve) from welding real points.
pub const WELD_TOLERANCE_RADII: f64 = 1e-3;

/// What [`Yarns::weld`] did, as a map from the input points to the welded
/// ones.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Weld {
    /// Per welded point: the input point it is (the first of its run).
    pub kept: Vec<usize>,
    /// Per input point: the welded point it became (`None`: its curve was
    /// dropped).
    pub target: Vec<Option<usize>>,
    /// The input's curve structure, to recognise data of the input's
    /// numbering (`offsets`, `closed` of the yarns before welding).
    pub input_offsets: Vec<usize>,
    pub input_closed: Vec<bool>,
    /// Input points merged into the point before them.
    pub welded_points: usize,
    /// Input curves dropped because welding left them too few points (2
    /// for an open curve, 3 for a closed one).
    pub dropped_curves: Vec<usize>,
}

impl Weld {
    /// The map of yarns that needed no welding.
    pub fn identity(yarns: &Yarns) -> Weld {
        let n = yarns.num_points();
        Weld {
            kept: (0..n).collect(),
            target: (0..n).map(Some).collect(),
            input_offsets: yarns.offsets.clone(),
            input_closed: yarns.closed.clone(),
            welded_points: 0,
            dropped_curves: Vec::new(),
        }
    }

    /// Whether the welded points are the input points.
    pub fn is_identity(&self) -> bool {
        self.welded_points == 0 && self.dropped_curves.is_empty()
    }

    /// Number of points before welding.
    pub fn input_points(&self) -> usize {
        self.target.len()
    }

    /// Whether `yarns` have the curve structure of this weld's input.
    pub fn is_input_topology(&self, yarns: &Yarns) -> bool {
        yarns.offsets == self.input_offsets && yarns.closed == self.input_closed
    }

    /// Per-point values of the input (positions, radii) at the welded
    /// points: each welded point keeps its run's first value.
    pub fn pick<T: Copy>(&self, values: &[T]) -> Vec<T> {
        self.kept.iter().map(|&i| values[i]).collect()
    }

    /// Per-point vectors of the input that add up (forces) summed onto the
    /// welded points: a run's forces all act on the one point it became.
    pub fn sum(&self, values: &[Vec3]) -> Vec<Vec3> {
        let mut out = vec![[0.0; 3]; self.kept.len()];
        for (v, t) in values.iter().zip(&self.target) {
            if let Some(t) = *t {
                for k in 0..3 {
                    out[t][k] += v[k];
                }
            }
        }
        out
    }

    /// The frames of the input's points at the welded points.
    pub fn frames(&self, frames: &YarnFrames) -> YarnFrames {
        let mut out = YarnFrames::new(self.kept.len());
        out.times = frames.times.clone();
        out.points.reserve(self.kept.len() * frames.num_frames());
        for f in 0..frames.num_frames() {
            let fr = frames.frame(f);
            out.points.extend(self.kept.iter().map(|&i| fr[i]));
        }
        out
    }
}

impl Yarns {
    /// The yarns with consecutive points closer than
    /// [`WELD_TOLERANCE_RADII`] yarn radii merged into the first of their
    /// run (the closing pair of a closed curve too), and the map. A curve
    /// that welding leaves too few points (2 open, 3 closed) is dropped;
    /// one that had too few already is kept for [`Yarns::validate`] to
    /// refuse. A rest shape's per-segment data no longer line up with
    /// welded segments, so welded yarns lose it (their rest state then
    /// comes from the positions, as for every format but HDF5).
    pub fn weld(&self) -> (Yarns, Weld) {
        let n = self.num_points();
        let mut target: Vec<Option<usize>> = vec![None; n];
        let mut kept: Vec<usize> = Vec::with_capacity(n);
        let mut out = Yarns::new();
        let mut vertex_radius = Vec::new();
        let mut density = Vec::new();
        let mut welded_points = 0;
        let mut dropped_curves = Vec::new();
        for c in 0..self.num_curves() {
            let range = self.curve_range(c);
            let closed = self.closed[c];
            let segments = self.curve_segments(c);
            let mean = if segments > 0 {
                self.curve_length(c) / segments as f64
            } else {
                0.0
            };
            let tol_of = |r: f64| {
                if r.is_finite() && r > 0.0 && mean.is_finite() {
                    WELD_TOLERANCE_RADII * r.min(mean)
                } else {
                    0.0
                }
            };
            let tol = tol_of(self.radius[c]);
            let tol_at = |v: usize| match &self.vertex_radius {
                Some(vr) => tol_of(vr[v]),
                None => tol,
            };
            // Runs of the curve: each point joins the run of the point
            // before it when they are within the tolerance.
            let mut run_of: Vec<usize> = Vec::with_capacity(range.len());
            let mut firsts: Vec<usize> = Vec::new();
            for v in range.clone() {
                let joins = firsts.last().is_some_and(|_| {
                    norm(sub(self.points[v], self.points[v - 1])) <= tol_at(v - 1).max(tol_at(v))
                });
                if !joins {
                    firsts.push(v);
                }
                run_of.push(firsts.len() - 1);
            }
            // The closing pair: a last run that repeats the first point
            // joins the first run.
            if closed && firsts.len() > 1 {
                let (a, b) = (range.start, range.end - 1);
                if norm(sub(self.points[b], self.points[a])) <= tol_at(a).max(tol_at(b)) {
                    let last = firsts.len() - 1;
                    run_of
                        .iter_mut()
                        .filter(|r| **r == last)
                        .for_each(|r| *r = 0);
                    firsts.pop();
                }
            }
            let merged = range.len() - firsts.len();
            let min = if closed { 3 } else { 2 };
            if merged > 0 && firsts.len() < min {
                dropped_curves.push(c);
                continue;
            }
            welded_points += merged;
            let base = kept.len();
            for (i, v) in range.clone().enumerate() {
                target[v] = Some(base + run_of[i]);
            }
            kept.extend_from_slice(&firsts);
            let pts: Vec<Vec3> = firsts.iter().map(|&v| self.points[v]).collect();
            out.push_curve(&pts, closed, self.radius[c]);
            if let Some(vr) = &self.vertex_radius {
                vertex_radius.extend(firsts.iter().map(|&v| vr[v]));
            }
            if let Some(ld) = &self.linear_density {
                density.push(ld[c]);
            }
        }
        let weld = Weld {
            kept,
            target,
            input_offsets: self.offsets.clone(),
            input_closed: self.closed.clone(),
            welded_points,
            dropped_curves,
        };
        if weld.is_identity() {
            return (self.clone(), weld);
        }
        out.vertex_radius = self.vertex_radius.as_ref().map(|_| vertex_radius);
        out.linear_density = self.linear_density.as_ref().map(|_| density);
        out.rest = None;
        (out, weld)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(points: &[Vec3], closed: bool) -> Yarns {
        let mut y = Yarns::new();
        y.push_curve(points, closed, 1e-3);
        y
    }

    #[test]
    fn exact_duplicates_weld_into_the_first_of_their_run() {
        let p = [
            [0.0; 3],
            [1e-2, 0.0, 0.0],
            [1e-2, 0.0, 0.0],
            [2e-2, 0.0, 0.0],
        ];
        let mut y = curve(&p, false);
        y.push_curve(&[[0.0, 1.0, 0.0], [0.0, 1.01, 0.0]], false, 1e-3);
        y.vertex_radius = Some(vec![1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3]);
        let (w, map) = y.weld();
        assert_eq!(map.welded_points, 1);
        assert_eq!(w.offsets, [0, 3, 5]);
        assert_eq!(w.points[1], [1e-2, 0.0, 0.0]);
        assert_eq!(map.kept, [0, 1, 3, 4, 5]);
        assert_eq!(
            map.target,
            [Some(0), Some(1), Some(1), Some(2), Some(3), Some(4)]
        );
        // Per-vertex radii follow the kept points.
        assert_eq!(
            w.vertex_radius.as_deref(),
            Some(&[1e-3, 2e-3, 4e-3, 5e-3, 6e-3][..])
        );
        assert!(w.validate().is_ok());
        // Forces of a run add up on its point.
        let f = map.sum(&[[1.0; 3], [2.0; 3], [3.0; 3], [4.0; 3], [0.0; 3], [0.0; 3]]);
        assert_eq!(f[1], [5.0; 3]);
        assert!(map.is_input_topology(&y) && !map.is_input_topology(&w));
    }

    #[test]
    fn the_tolerance_is_a_fraction_of_the_radius() {
        let r = 1e-3;
        let near = WELD_TOLERANCE_RADII * r * 0.5;
        let far = WELD_TOLERANCE_RADII * r * 2.0;
        let (_, m) = curve(&[[0.0; 3], [near, 0.0, 0.0], [1e-2, 0.0, 0.0]], false).weld();
        assert_eq!(m.welded_points, 1);
        let (w, m) = curve(&[[0.0; 3], [far, 0.0, 0.0], [1e-2, 0.0, 0.0]], false).weld();
        assert!(m.is_identity());
        assert_eq!(w.num_points(), 3);
    }

    #[test]
    fn a_radius_too_large_for_the_curve_does_not_weld_its_points() {
        // 1 µm segments under a 1 mm radius (a file in m read as mm): the
        // radius tolerance (1 µm) would weld them all; the segment one
        // (1 nm) keeps them, and still welds an exact repeat.
        let p: Vec<Vec3> = (0..10).map(|i| [i as f64 * 1e-6, 0.0, 0.0]).collect();
        let (w, m) = curve(&p, false).weld();
        assert!(m.is_identity() && w.num_points() == 10);
        let mut q = p.clone();
        q.insert(4, p[4]);
        let (w, m) = curve(&q, false).weld();
        assert_eq!((m.welded_points, w.num_points()), (1, 10));
    }

    #[test]
    fn a_closed_curve_repeating_its_first_point_loses_the_repeat() {
        let p = [[0.0; 3], [1e-2, 0.0, 0.0], [1e-2, 1e-2, 0.0], [0.0; 3]];
        let (w, m) = curve(&p, true).weld();
        assert_eq!(m.welded_points, 1);
        assert_eq!(w.num_points(), 3);
        assert_eq!(w.num_segments(), 3);
        assert_eq!(m.target[3], Some(0));
        assert!(w.segments().all(|[a, b]| w.points[a] != w.points[b]));
    }

    #[test]
    fn a_curve_that_collapses_is_dropped_and_one_already_short_is_kept() {
        let mut y = curve(&[[0.0; 3], [0.0; 3], [0.0; 3]], false);
        y.push_curve(&[[1.0; 3], [1.01, 1.0, 1.0]], false, 1e-3);
        y.linear_density = Some(vec![1.0, 2.0]);
        let (w, m) = y.weld();
        assert_eq!(m.dropped_curves, [0]);
        assert_eq!(w.num_curves(), 1);
        assert_eq!(w.linear_density.as_deref(), Some(&[2.0][..]));
        assert_eq!(m.target[..3], [None, None, None]);
        assert_eq!(m.target[3], Some(0));
        // One point from the start: left to validate to refuse.
        let (w, m) = curve(&[[0.0; 3]], false).weld();
        assert!(m.is_identity() && w.validate().is_err());
    }

    #[test]
    fn frames_follow_the_rest_map_even_where_they_separate_the_repeats() {
        let y = curve(&[[0.0; 3], [0.0; 3], [1e-2, 0.0, 0.0]], false);
        let (_, m) = y.weld();
        let mut f = YarnFrames::new(3);
        f.push_frame(0.0, &y.points).unwrap();
        f.push_frame(1.0, &[[0.0; 3], [5e-3, 0.0, 0.0], [1e-2, 0.0, 0.0]])
            .unwrap();
        let g = m.frames(&f);
        assert_eq!(g.num_vertices, 2);
        assert_eq!(g.frame(1), [[0.0; 3], [1e-2, 0.0, 0.0]]);
        assert!(g.validate().is_ok());
    }
}
