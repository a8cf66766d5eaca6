//! The test rig's geometry: a stretch axis in the swatch plane, clamp bands
//! at both ends, the gauge section between them.

use crate::geom::Vec3;

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

impl std::str::FromStr for Direction {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "weft" => Ok(Direction::Weft),
            "warp" => Ok(Direction::Warp),
            "bias" => Ok(Direction::Bias),
            _ => Err(format!("unknown direction {s:?} (weft, warp, bias)")),
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
