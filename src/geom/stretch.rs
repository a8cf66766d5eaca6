//! How far deformed yarns stretch: the distribution of `|l / l0 - 1|` over
//! the yarn segments of a run of frames, against the rest yarns' segment
//! lengths `l0`.
//!
//! A shot's yarns are the V2Y image of the tet nodes, so they stretch as
//! the homogenized fabric does. Knit yarns themselves barely stretch: a
//! shot whose yarn segments stretch by much says the material is too soft
//! for it. The distribution is kept as a histogram, so the cost per frame
//! is one pass over the segments and the memory does not grow with the
//! frames.

use super::vec3::{norm, sub};
use super::{Vec3, Yarns};

/// Histogram bins per decade of `|l / l0 - 1|`: a percentile is given to
/// within one bin, 10^(1/200) - 1 = 1.2% of its value.
const BINS_PER_DECADE: f64 = 200.0;
/// The smallest stretch the histogram tells apart (smaller ones share the
/// first bin), and the number of decades above it it spans.
const SMALLEST: f64 = 1e-8;
const DECADES: f64 = 10.0;

/// The stretch of yarn segments over frames ([`SegmentStretch::add_frame`]).
#[derive(Debug, Clone)]
pub struct SegmentStretch {
    segments: Vec<[usize; 2]>,
    rest: Vec<f64>,
    bins: Vec<u64>,
    count: u64,
    frames: usize,
    max: f64,
    max_frame: i64,
    max_segment: usize,
}

/// What [`SegmentStretch`] found.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StretchSummary {
    /// 99th percentile of `|l / l0 - 1|` over every segment of every
    /// frame (to within 1.2%, never below the true value).
    pub p99: f64,
    /// Largest `|l / l0 - 1|`, the frame (as numbered by the caller) and
    /// the segment (in [`Yarns::segments`] order) where it is.
    pub max: f64,
    pub max_frame: i64,
    pub max_segment: usize,
    /// Frames and segments per frame measured.
    pub frames: usize,
    pub segments: usize,
}

impl SegmentStretch {
    /// Stretch against the segment lengths of `rest`; segments of length
    /// 0 at rest (which welding removes from files read now) are left out.
    pub fn new(rest: &Yarns) -> SegmentStretch {
        let (segments, rest_len): (Vec<[usize; 2]>, Vec<f64>) = rest
            .segments()
            .map(|[a, b]| ([a, b], norm(sub(rest.points[a], rest.points[b]))))
            .filter(|(_, l)| *l > 0.0 && l.is_finite())
            .unzip();
        SegmentStretch {
            segments,
            rest: rest_len,
            bins: vec![0; (BINS_PER_DECADE * DECADES) as usize + 1],
            count: 0,
            frames: 0,
            max: 0.0,
            max_frame: 0,
            max_segment: 0,
        }
    }

    /// Adds frame `frame` with yarn positions `points` (the rest yarns'
    /// numbering).
    pub fn add_frame(&mut self, frame: i64, points: &[Vec3]) {
        let last = self.bins.len() - 1;
        for (s, ([a, b], l0)) in self.segments.iter().zip(&self.rest).enumerate() {
            let e = (norm(sub(points[*a], points[*b])) / l0 - 1.0).abs();
            if !e.is_finite() {
                continue;
            }
            let bin = if e <= SMALLEST {
                0
            } else {
                ((e / SMALLEST).log10() * BINS_PER_DECADE)
                    .ceil()
                    .min(last as f64) as usize
            };
            self.bins[bin] += 1;
            self.count += 1;
            if e > self.max || self.frames == 0 && s == 0 {
                (self.max, self.max_frame, self.max_segment) = (e, frame, s);
            }
        }
        self.frames += 1;
    }

    /// The figures so far; None before any segment of any frame.
    pub fn summary(&self) -> Option<StretchSummary> {
        if self.count == 0 {
            return None;
        }
        let need = (0.99 * self.count as f64).ceil() as u64;
        let mut seen = 0;
        let bin = self
            .bins
            .iter()
            .position(|&n| {
                seen += n;
                seen >= need
            })
            .unwrap_or(self.bins.len() - 1);
        // The bin's upper edge: the percentile lies in the bin.
        let edge = SMALLEST * 10f64.powf(bin as f64 / BINS_PER_DECADE);
        Some(StretchSummary {
            p99: edge.min(self.max),
            max: self.max,
            max_frame: self.max_frame,
            max_segment: self.max_segment,
            frames: self.frames,
            segments: self.segments.len(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize) -> Yarns {
        let mut y = Yarns::new();
        let p: Vec<Vec3> = (0..=n).map(|i| [i as f64 * 1e-3, 0.0, 0.0]).collect();
        y.push_curve(&p, false, 1e-4);
        y
    }

    #[test]
    fn rest_positions_do_not_stretch() {
        let y = line(10);
        let mut s = SegmentStretch::new(&y);
        assert!(s.summary().is_none());
        s.add_frame(1, &y.points);
        let r = s.summary().unwrap();
        assert!(r.p99 <= 1e-8 && r.max <= 1e-12, "{r:?}");
        assert_eq!((r.frames, r.segments), (1, 10));
    }

    #[test]
    fn percentile_and_max_name_the_frame() {
        // 200 segments: frame 3 stretches every one by 2%, frame 7 one
        // segment by 30% (1 in 400 over both frames: above the 99th
        // percentile).
        let y = line(200);
        let mut s = SegmentStretch::new(&y);
        let stretched: Vec<Vec3> = y.points.iter().map(|p| [p[0] * 1.02, 0.0, 0.0]).collect();
        s.add_frame(3, &stretched);
        let mut one = y.points.clone();
        for p in one.iter_mut().skip(101) {
            p[0] += 0.3e-3;
        }
        s.add_frame(7, &one);
        let r = s.summary().unwrap();
        assert!((r.max - 0.3).abs() < 1e-9, "{r:?}");
        assert_eq!((r.max_frame, r.max_segment), (7, 100));
        assert!(
            r.p99 >= 0.02 * (1.0 - 1e-9) && r.p99 <= 0.02 * 1.012,
            "{r:?}"
        );
        assert_eq!(r.frames, 2);
    }

    #[test]
    fn compression_counts_as_much_as_stretch() {
        let y = line(4);
        let mut s = SegmentStretch::new(&y);
        let squeezed: Vec<Vec3> = y.points.iter().map(|p| [p[0] * 0.9, 0.0, 0.0]).collect();
        s.add_frame(0, &squeezed);
        assert!((s.summary().unwrap().max - 0.1).abs() < 1e-9);
    }
}
