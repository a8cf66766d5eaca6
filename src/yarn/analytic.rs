//! Analytic knit-like yarn curves for demos, benchmarks and tests.
//!
//! Each course is the classic closed-form loop curve
//! x = w (t + a sin 2t) / (2 pi), y = j h + b cos t, z = c cos 2t
//! (one wale per 2 pi of t). With a > 1/2 the curve doubles back and forms
//! loops that sit over the loops of the neighbouring courses. The curves are
//! *not* relaxed: they are stand-ins until the pattern generator exists.

use std::f64::consts::PI;

use crate::geom::{Vec3, Yarns};

/// Shape of an analytic swatch. Lengths in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct SwatchParams {
    /// Courses (rows), one open yarn each. Default 8.
    pub courses: usize,
    /// Wales (loops per course). Default 8.
    pub wales: usize,
    /// Wale width (m). Default 4 mm.
    pub wale_width: f64,
    /// Course height (m). Default 3 mm.
    pub course_height: f64,
    /// Yarn radius (m). Default 0.4 mm.
    pub radius: f64,
    /// Polyline points per loop. Default 24.
    pub points_per_loop: usize,
    /// Add a closed ring (a course knitted in the round) above the swatch. Default true.
    pub with_ring: bool,
}

impl Default for SwatchParams {
    fn default() -> Self {
        SwatchParams {
            courses: 8,
            wales: 8,
            wale_width: 4e-3,
            course_height: 3e-3,
            radius: 4e-4,
            points_per_loop: 24,
            with_ring: true,
        }
    }
}

/// Builds the swatch: `courses` open curves in the x-y plane (+Y up), and
/// optionally one closed ring lying around it.
pub fn knit_swatch(p: &SwatchParams) -> Yarns {
    let (a, b, c) = (0.8, 0.6 * p.course_height, 0.25 * p.wale_width);
    let n = p.wales * p.points_per_loop.max(4);
    let mut yarns = Yarns::new();
    let mut pts: Vec<Vec3> = Vec::with_capacity(n + 1);
    for j in 0..p.courses {
        pts.clear();
        for i in 0..=n {
            let t = 2.0 * PI * p.wales as f64 * i as f64 / n as f64;
            pts.push([
                p.wale_width * (t + a * (2.0 * t).sin()) / (2.0 * PI),
                j as f64 * p.course_height + b * t.cos(),
                c * (2.0 * t).cos(),
            ]);
        }
        yarns.push_curve(&pts, false, p.radius);
    }
    if p.with_ring {
        let width = p.wales as f64 * p.wale_width;
        let (cx, rr) = (0.5 * width, 0.6 * width);
        let y = p.courses as f64 * p.course_height + 2.0 * p.radius;
        pts.clear();
        for i in 0..n {
            let t = 2.0 * PI * i as f64 / n as f64;
            pts.push([
                cx + rr * t.cos(),
                y + 0.5 * c * (p.wales as f64 * t).sin(),
                rr * t.sin(),
            ]);
        }
        yarns.push_curve(&pts, true, p.radius);
    }
    yarns
}

/// A swatch with about `target_points` points (for benchmarks).
pub fn knit_swatch_with_points(target_points: usize) -> Yarns {
    let per_course = 32 * 24 + 1;
    let courses = (target_points / per_course).max(1);
    knit_swatch(&SwatchParams {
        courses,
        wales: 32,
        with_ring: false,
        ..SwatchParams::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swatch_is_valid_and_sized() {
        let p = SwatchParams::default();
        let y = knit_swatch(&p);
        y.validate().unwrap();
        assert_eq!(y.num_curves(), p.courses + 1);
        assert_eq!(y.num_closed(), 1);
        let b = y.bounds().unwrap();
        // Courses span about wales * wale width along x.
        assert!(
            (b.size()[0] - p.wales as f64 * p.wale_width).abs()
                < 0.6 * 2.0 * p.wales as f64 * p.wale_width
        );
        let big = knit_swatch_with_points(100_000);
        assert!((big.num_points() as f64 - 100_000.0).abs() < 1000.0);
    }
}
