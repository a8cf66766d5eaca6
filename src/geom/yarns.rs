//! Yarn curves (`Yarns`) and time sequences of their vertex positions (`YarnFrames`).

use super::vec3::{norm, sub};
use super::{GeomError, RestShape, Units, UpAxis, Vec3};

/// Default yarn radius (m) when a file carries none: 1 mm, the HYLC papers' yarn radius.
pub const DEFAULT_RADIUS_M: f64 = 1.0e-3;

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Bounds {
    pub min: Vec3,
    pub max: Vec3,
}

impl Bounds {
    pub fn size(&self) -> Vec3 {
        [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ]
    }
    pub fn diagonal(&self) -> f64 {
        norm(self.size())
    }
}

/// A collection of yarn polylines stored flat.
///
/// Curve `c` owns `points[offsets[c]..offsets[c + 1]]`. A closed curve has an
/// implicit segment from its last point back to its first (the first point is
/// **not** repeated). Units: metres, +Y up.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Yarns {
    /// Vertex positions (m).
    pub points: Vec<Vec3>,
    /// `num_curves + 1` monotone offsets into `points`, starting at 0.
    pub offsets: Vec<usize>,
    /// Per curve: whether the curve is a closed loop.
    pub closed: Vec<bool>,
    /// Per curve yarn radius (m).
    pub radius: Vec<f64>,
    /// Optional per-vertex radius (m); overrides `radius` where present.
    pub vertex_radius: Option<Vec<f64>>,
    /// Optional per-curve linear density (kg/m). When absent, later stages
    /// derive it from the radius and a material density.
    pub linear_density: Option<Vec<f64>>,
    /// Optional rest shape of the yarn-level rod model (rest lengths,
    /// curvatures, material frames); only the knitvox HDF5 format keeps it.
    pub rest: Option<RestShape>,
}

impl Yarns {
    /// An empty collection.
    pub fn new() -> Yarns {
        Yarns {
            offsets: vec![0],
            ..Default::default()
        }
    }

    /// Appends one curve with a per-curve radius (m).
    pub fn push_curve(&mut self, points: &[Vec3], closed: bool, radius: f64) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.points.extend_from_slice(points);
        self.offsets.push(self.points.len());
        self.closed.push(closed);
        self.radius.push(radius);
    }

    pub fn num_curves(&self) -> usize {
        self.closed.len()
    }

    pub fn num_points(&self) -> usize {
        self.points.len()
    }

    pub fn num_closed(&self) -> usize {
        self.closed.iter().filter(|c| **c).count()
    }

    /// Index range of curve `c` in `points`.
    pub fn curve_range(&self, c: usize) -> std::ops::Range<usize> {
        self.offsets[c]..self.offsets[c + 1]
    }

    /// The points of curve `c`.
    pub fn curve(&self, c: usize) -> &[Vec3] {
        &self.points[self.curve_range(c)]
    }

    /// Number of segments of curve `c` (closed curves have one more).
    pub fn curve_segments(&self, c: usize) -> usize {
        let n = self.offsets[c + 1] - self.offsets[c];
        if self.closed[c] {
            n
        } else {
            n.saturating_sub(1)
        }
    }

    /// Total number of segments.
    pub fn num_segments(&self) -> usize {
        (0..self.num_curves()).map(|c| self.curve_segments(c)).sum()
    }

    /// Every segment as a pair of global vertex indices, curve by curve.
    pub fn segments(&self) -> impl Iterator<Item = [usize; 2]> + '_ {
        (0..self.num_curves()).flat_map(move |c| self.segments_of(c))
    }

    /// Radius (m) at global vertex `v`.
    pub fn radius_at(&self, v: usize) -> f64 {
        if let Some(vr) = &self.vertex_radius {
            return vr[v];
        }
        let c = self.offsets.partition_point(|&o| o <= v) - 1;
        self.radius[c]
    }

    /// Length of curve `c` (m), including the closing segment of a loop.
    pub fn curve_length(&self, c: usize) -> f64 {
        self.segments_of(c)
            .map(|[a, b]| dist(self.points[a], self.points[b]))
            .sum()
    }

    /// The segments of curve `c` as global vertex index pairs.
    pub fn segments_of(&self, c: usize) -> impl Iterator<Item = [usize; 2]> + '_ {
        let r = self.curve_range(c);
        let closed = self.closed[c];
        (r.start..r.end.saturating_sub(1))
            .map(|i| [i, i + 1])
            .chain((closed && r.len() >= 2).then_some([r.end - 1, r.start]))
    }

    /// Total yarn length (m).
    pub fn total_length(&self) -> f64 {
        (0..self.num_curves()).map(|c| self.curve_length(c)).sum()
    }

    /// Longest segment length (m), 0 for no segments.
    pub fn max_segment_length(&self) -> f64 {
        self.segments()
            .map(|[a, b]| dist(self.points[a], self.points[b]))
            .fold(0.0, f64::max)
    }

    /// Bounding box of all points, `None` when there are none.
    pub fn bounds(&self) -> Option<Bounds> {
        bounds_of(&self.points)
    }

    /// Checks the invariants every stage relies on: consistent layout, at
    /// least 2 points per curve, finite coordinates, positive finite radii.
    pub fn validate(&self) -> Result<(), GeomError> {
        let n = self.num_curves();
        if self.offsets.len() != n + 1 || self.radius.len() != n {
            return Err(GeomError::Layout(format!(
                "{} curves but {} offsets and {} radii",
                n,
                self.offsets.len(),
                self.radius.len()
            )));
        }
        if self.offsets[0] != 0 || self.offsets[n] != self.points.len() {
            return Err(GeomError::Layout(
                "offsets must start at 0 and end at the point count".into(),
            ));
        }
        for c in 0..n {
            let (a, b) = (self.offsets[c], self.offsets[c + 1]);
            if b < a {
                return Err(GeomError::Layout(format!("offsets decrease at curve {c}")));
            }
            if b - a < 2 || (self.closed[c] && b - a < 3) {
                return Err(GeomError::TooFewPoints {
                    curve: c,
                    points: b - a,
                    closed: self.closed[c],
                });
            }
            for (i, p) in self.points[a..b].iter().enumerate() {
                if !p.iter().all(|x| x.is_finite()) {
                    return Err(GeomError::NonFinitePoint {
                        curve: c,
                        point: i,
                        value: *p,
                    });
                }
            }
            let r = self.radius[c];
            if !(r.is_finite() && r > 0.0) {
                return Err(GeomError::BadRadius { curve: c, value: r });
            }
        }
        if let Some(vr) = &self.vertex_radius {
            if vr.len() != self.points.len() {
                return Err(GeomError::Layout(format!(
                    "{} vertex radii for {} points",
                    vr.len(),
                    self.points.len()
                )));
            }
            if let Some((v, &r)) = vr
                .iter()
                .enumerate()
                .find(|(_, r)| !(r.is_finite() && **r > 0.0))
            {
                return Err(GeomError::BadVertexRadius {
                    vertex: v,
                    value: r,
                });
            }
        }
        if let Some(ld) = &self.linear_density {
            if ld.len() != n {
                return Err(GeomError::Layout(format!(
                    "{} linear densities for {n} curves",
                    ld.len()
                )));
            }
            if let Some((c, &d)) = ld
                .iter()
                .enumerate()
                .find(|(_, d)| !(d.is_finite() && **d >= 0.0))
            {
                return Err(GeomError::BadLinearDensity { curve: c, value: d });
            }
        }
        if let Some(rest) = &self.rest {
            rest.validate(self.num_segments(), self.points.len())?;
        }
        Ok(())
    }

    /// Applies `f` to every point (and leaves radii alone).
    pub fn map_points(&mut self, f: impl Fn(Vec3) -> Vec3) {
        for p in &mut self.points {
            *p = f(*p);
        }
    }

    /// Converts from a file frame (unit, up axis) into knitvox's metres, +Y up.
    /// Radii and linear densities are scaled with the length unit.
    pub fn file_to_internal(&mut self, units: Units, up: UpAxis) {
        let s = units.metres_per_unit;
        self.map_points(|p| up.to_internal([p[0] * s, p[1] * s, p[2] * s]));
        self.scale_attributes(s);
        if let Some(rest) = &mut self.rest {
            rest.transform(s, |d| up.to_internal(d));
        }
    }

    /// Converts from knitvox's metres, +Y up into a file frame (unit, up axis).
    pub fn internal_to_file(&mut self, units: Units, up: UpAxis) {
        let s = 1.0 / units.metres_per_unit;
        self.map_points(|p| {
            let q = up.from_internal(p);
            [q[0] * s, q[1] * s, q[2] * s]
        });
        self.scale_attributes(s);
        if let Some(rest) = &mut self.rest {
            rest.transform(s, |d| up.from_internal(d));
        }
    }

    fn scale_attributes(&mut self, s: f64) {
        self.radius.iter_mut().for_each(|r| *r *= s);
        if let Some(vr) = &mut self.vertex_radius {
            vr.iter_mut().for_each(|r| *r *= s);
        }
        // kg/m: a file unit s times longer holds s times the mass per unit.
        if let Some(ld) = &mut self.linear_density {
            ld.iter_mut().for_each(|d| *d /= s);
        }
    }

    /// The same curves with other vertex positions (e.g. one frame of a sequence).
    pub fn with_points(&self, points: &[Vec3]) -> Result<Yarns, GeomError> {
        if points.len() != self.points.len() {
            return Err(GeomError::Layout(format!(
                "{} positions for {} yarn vertices",
                points.len(),
                self.points.len()
            )));
        }
        Ok(Yarns {
            points: points.to_vec(),
            ..self.clone()
        })
    }

    /// The curves where `keep[c]` holds, with every per-curve, per-vertex
    /// and per-segment datum (radii, linear density, rest shape) that goes
    /// with them.
    pub fn select_curves(&self, keep: &[bool]) -> Yarns {
        let mut out = Yarns::new();
        let mut vertex_radius = Vec::new();
        let mut density = Vec::new();
        let mut rest = self.rest.as_ref().map(|r| RestShape {
            material: r.material,
            ..RestShape::default()
        });
        let mut seg0 = 0;
        for c in 0..self.num_curves() {
            let range = self.curve_range(c);
            let segs = seg0..seg0 + self.curve_segments(c);
            seg0 = segs.end;
            if !keep.get(c).copied().unwrap_or(false) {
                continue;
            }
            out.push_curve(&self.points[range.clone()], self.closed[c], self.radius[c]);
            if let Some(vr) = &self.vertex_radius {
                vertex_radius.extend_from_slice(&vr[range.clone()]);
            }
            if let Some(ld) = &self.linear_density {
                density.push(ld[c]);
            }
            if let (Some(r), Some(src)) = (rest.as_mut(), &self.rest) {
                r.lengths.extend_from_slice(&src.lengths[segs.clone()]);
                r.directors.extend_from_slice(&src.directors[segs]);
                r.curvature.extend_from_slice(&src.curvature[range.clone()]);
                r.twist.extend_from_slice(&src.twist[range]);
            }
        }
        out.vertex_radius = self.vertex_radius.as_ref().map(|_| vertex_radius);
        out.linear_density = self.linear_density.as_ref().map(|_| density);
        out.rest = rest;
        out
    }

    /// True when `other` has the same curve structure (counts, offsets, closed flags).
    pub fn same_topology(&self, other: &Yarns) -> bool {
        self.offsets == other.offsets && self.closed == other.closed
    }
}

/// A sequence of frames of vertex positions for one fixed set of yarns,
/// stored flat: frame `f` owns `points[f * num_vertices..(f + 1) * num_vertices]`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct YarnFrames {
    /// Vertices per frame (equals the rest yarns' point count).
    pub num_vertices: usize,
    /// Time of each frame (s).
    pub times: Vec<f64>,
    /// Positions (m), frame-major.
    pub points: Vec<Vec3>,
}

impl YarnFrames {
    pub fn new(num_vertices: usize) -> YarnFrames {
        YarnFrames {
            num_vertices,
            ..Default::default()
        }
    }

    pub fn num_frames(&self) -> usize {
        self.times.len()
    }

    /// Appends a frame at time `time` (s).
    pub fn push_frame(&mut self, time: f64, points: &[Vec3]) -> Result<(), GeomError> {
        let frame = self.num_frames();
        if points.len() != self.num_vertices {
            return Err(GeomError::Frame {
                frame,
                message: format!("{} positions, expected {}", points.len(), self.num_vertices),
            });
        }
        if !time.is_finite() {
            return Err(GeomError::Frame {
                frame,
                message: format!("time {time} is not finite"),
            });
        }
        self.times.push(time);
        self.points.extend_from_slice(points);
        Ok(())
    }

    /// Positions of frame `f`.
    pub fn frame(&self, f: usize) -> &[Vec3] {
        &self.points[f * self.num_vertices..(f + 1) * self.num_vertices]
    }

    /// Checks layout and finiteness.
    pub fn validate(&self) -> Result<(), GeomError> {
        if self.points.len() != self.num_vertices * self.num_frames() {
            return Err(GeomError::Layout(format!(
                "{} positions for {} frames of {} vertices",
                self.points.len(),
                self.num_frames(),
                self.num_vertices
            )));
        }
        for f in 0..self.num_frames() {
            if !self.times[f].is_finite() {
                return Err(GeomError::Frame {
                    frame: f,
                    message: format!("time {} is not finite", self.times[f]),
                });
            }
            if let Some(v) = self
                .frame(f)
                .iter()
                .position(|p| !p.iter().all(|x| x.is_finite()))
            {
                return Err(GeomError::Frame {
                    frame: f,
                    message: format!("vertex {v} is not finite"),
                });
            }
        }
        Ok(())
    }

    /// Converts every frame from a file frame into metres, +Y up.
    pub fn file_to_internal(&mut self, units: Units, up: UpAxis) {
        let s = units.metres_per_unit;
        for p in &mut self.points {
            *p = up.to_internal([p[0] * s, p[1] * s, p[2] * s]);
        }
    }

    /// Converts every frame from metres, +Y up into a file frame.
    pub fn internal_to_file(&mut self, units: Units, up: UpAxis) {
        let s = 1.0 / units.metres_per_unit;
        for p in &mut self.points {
            let q = up.from_internal(*p);
            *p = [q[0] * s, q[1] * s, q[2] * s];
        }
    }
}

/// Euclidean distance between two points.
pub fn dist(a: Vec3, b: Vec3) -> f64 {
    norm(sub(a, b))
}

/// Whether `v` is a unit vector: finite, its squared norm within 2e-6 of 1
/// (the tolerance of stored fibre directions).
pub fn is_unit_vector(v: &Vec3) -> bool {
    let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    n2.is_finite() && (n2 - 1.0).abs() <= 2e-6
}

/// The bounding box of `points` (None when empty).
pub fn bounds_of(points: &[Vec3]) -> Option<Bounds> {
    let first = *points.first()?;
    let mut b = Bounds {
        min: first,
        max: first,
    };
    for p in points {
        b.min = std::array::from_fn(|k| b.min[k].min(p[k]));
        b.max = std::array::from_fn(|k| b.max[k].max(p[k]));
    }
    Some(b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::YarnMaterial;

    fn square(closed: bool) -> Yarns {
        let mut y = Yarns::new();
        y.push_curve(
            &[
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            closed,
            0.1,
        );
        y
    }

    #[test]
    fn lengths_and_segments() {
        assert_eq!(square(false).total_length(), 3.0);
        assert_eq!(square(true).total_length(), 4.0);
        assert_eq!(
            square(true).segments().collect::<Vec<_>>(),
            vec![[0, 1], [1, 2], [2, 3], [3, 0]]
        );
        assert_eq!(square(false).num_segments(), 3);
    }

    #[test]
    fn validate_catches_problems() {
        let mut y = square(false);
        assert!(y.validate().is_ok());
        y.points[2][1] = f64::NAN;
        assert!(matches!(
            y.validate(),
            Err(GeomError::NonFinitePoint {
                curve: 0,
                point: 2,
                ..
            })
        ));
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3]], false, 0.1);
        assert_eq!(
            y.validate(),
            Err(GeomError::TooFewPoints {
                curve: 0,
                points: 1,
                closed: false
            })
        );
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1.0; 3]], true, 0.1);
        assert!(y.validate().is_err(), "a closed curve needs 3 points");
        let mut y = square(true);
        y.radius[0] = 0.0;
        assert!(matches!(y.validate(), Err(GeomError::BadRadius { .. })));
    }

    #[test]
    fn unit_conversion_round_trip() {
        let mut y = square(true);
        y.linear_density = Some(vec![0.002]);
        let orig = y.clone();
        y.file_to_internal(Units::CENTIMETRES, UpAxis::Z);
        assert!((y.radius[0] - 0.001).abs() < 1e-15);
        assert!((y.total_length() - 0.04).abs() < 1e-15);
        y.internal_to_file(Units::CENTIMETRES, UpAxis::Z);
        for (a, b) in y.points.iter().zip(&orig.points) {
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-12);
            }
        }
        assert!((y.linear_density.as_ref().unwrap()[0] - 0.002).abs() < 1e-15);
    }

    #[test]
    fn rest_shape_converts_with_units_and_axis() {
        let mut y = square(false);
        let ns = y.num_segments();
        let nv = y.num_points();
        y.rest = Some(RestShape {
            lengths: vec![2.0; ns],
            directors: vec![[0.0, 0.0, 1.0]; ns],
            curvature: vec![[0.5, -0.25, 0.5, -0.25]; nv],
            twist: vec![0.0; nv],
            material: None,
        });
        y.validate().unwrap();
        // A Z-up file in centimetres: lengths scale to metres, the director
        // +Z (file up) becomes +Y, curvatures stay.
        y.file_to_internal(Units::CENTIMETRES, UpAxis::Z);
        let r = y.rest.as_ref().unwrap();
        assert!(r.lengths.iter().all(|l| (l - 0.02).abs() < 1e-15));
        assert!(r.directors.iter().all(|d| d == &[0.0, 1.0, 0.0]));
        assert_eq!(r.curvature[0], [0.5, -0.25, 0.5, -0.25]);
        y.internal_to_file(Units::CENTIMETRES, UpAxis::Z);
        let r = y.rest.as_ref().unwrap();
        assert!(r.lengths.iter().all(|l| (l - 2.0).abs() < 1e-12));
        assert!(r.directors.iter().all(|d| (d[2] - 1.0).abs() < 1e-15));
        // Sizes and values are checked.
        y.rest.as_mut().unwrap().lengths[0] = 0.0;
        assert!(y.validate().is_err());
        y.rest.as_mut().unwrap().lengths.pop();
        assert!(matches!(y.validate(), Err(GeomError::Layout(_))));
    }

    #[test]
    fn selected_curves_keep_their_rest_shape_and_radii() {
        // Curves: open square (4 vertices, 3 segments), closed square (4, 4),
        // open pair (2, 1); each with distinct per-segment and per-vertex data.
        let mut y = square(false);
        let closed = square(true);
        y.push_curve(&closed.points, true, 0.2);
        y.push_curve(&[[5.0; 3], [6.0; 3]], false, 0.3);
        let (ns, nv) = (y.num_segments(), y.num_points());
        assert_eq!((ns, nv), (8, 10));
        y.vertex_radius = Some((0..nv).map(|v| 0.01 * v as f64).collect());
        y.linear_density = Some(vec![1.0, 2.0, 3.0]);
        y.rest = Some(RestShape {
            lengths: (0..ns).map(|i| 1.0 + i as f64).collect(),
            directors: (0..ns).map(|i| [0.0, 0.0, i as f64]).collect(),
            curvature: (0..nv).map(|v| [v as f64; 4]).collect(),
            twist: (0..nv).map(|v| -(v as f64)).collect(),
            material: Some(YarnMaterial::from_values([1e6, 4e5, 0.5, 30.0])),
        });
        // (Synthetic rest data: only where each datum goes is checked.)
        let s = y.select_curves(&[false, true, true]);
        assert_eq!(s.offsets, [0, 4, 6]);
        assert_eq!(s.closed, [true, false]);
        assert_eq!(s.radius, [0.2, 0.3]);
        assert_eq!(s.linear_density.as_deref(), Some(&[2.0, 3.0][..]));
        assert_eq!(s.vertex_radius.as_ref().unwrap()[0], 0.04);
        let r = s.rest.as_ref().unwrap();
        // Segments 3..7 are the closed square's, 7 the pair's.
        assert_eq!(r.lengths, [4.0, 5.0, 6.0, 7.0, 8.0]);
        assert_eq!(r.directors[4], [0.0, 0.0, 7.0]);
        assert_eq!(r.curvature[0], [4.0; 4]);
        assert_eq!(r.twist[5], -9.0);
        assert_eq!(r.material, y.rest.as_ref().unwrap().material);
        assert_eq!(y.select_curves(&[true, true, true]), y);
        assert_eq!(y.select_curves(&[false; 3]).num_curves(), 0);
    }

    #[test]
    fn radius_lookup_per_curve() {
        let mut y = square(false);
        y.push_curve(&[[0.0; 3], [1.0; 3]], false, 0.5);
        assert_eq!(y.radius_at(3), 0.1);
        assert_eq!(y.radius_at(4), 0.5);
    }
}
