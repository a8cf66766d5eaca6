//! Summaries of yarn files for `knitvox inspect`.

use serde::Serialize;

use crate::geom::{Bounds, YarnMaterial};
use crate::io::{Provenance, YarnData};

/// What `knitvox inspect` reports about one yarn file (lengths in metres,
/// in knitvox's +Y-up frame).
#[derive(Debug, Clone, Serialize)]
pub struct YarnReport {
    pub path: String,
    pub format: String,
    pub curves: usize,
    pub open_curves: usize,
    pub closed_curves: usize,
    pub points: usize,
    pub segments: usize,
    pub points_per_curve: MinMax<usize>,
    pub total_length_m: f64,
    pub segment_length_m: MinMax<f64>,
    pub bbox_m: Option<Bounds>,
    pub bbox_size_m: Option<[f64; 3]>,
    pub radius_m: MinMax<f64>,
    pub radius_source: Provenance,
    pub per_vertex_radius: bool,
    pub linear_density: bool,
    /// Whether the yarns carry a rest shape (knitvox HDF5 only) and the
    /// yarn material it was relaxed under, when recorded.
    pub rest_shape: bool,
    pub rest_material: Option<YarnMaterial>,
    pub units: String,
    pub units_source: Provenance,
    pub up_axis: String,
    pub up_axis_source: Provenance,
    pub frames: usize,
    pub frame_times_s: Option<MinMax<f64>>,
    /// Repeated points welded on read, and curves dropped for it
    /// ([`crate::geom::Yarns::weld`]); the counts above are after it.
    pub welded_points: usize,
    pub dropped_curves: usize,
    pub notes: Vec<String>,
    /// An implausible garment size with an assumed unit, an implausible
    /// yarn radius: each with the option that would fix it.
    pub warnings: Vec<String>,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct MinMax<T> {
    pub min: T,
    pub max: T,
}

fn min_max<T: PartialOrd + Copy>(it: impl IntoIterator<Item = T>, empty: T) -> MinMax<T> {
    let mut it = it.into_iter();
    let Some(first) = it.next() else {
        return MinMax {
            min: empty,
            max: empty,
        };
    };
    it.fold(
        MinMax {
            min: first,
            max: first,
        },
        |m, x| MinMax {
            min: if x < m.min { x } else { m.min },
            max: if x > m.max { x } else { m.max },
        },
    )
}

/// Summarises yarns read from `path`.
pub fn summarize(path: &str, d: &YarnData) -> YarnReport {
    let y = &d.yarns;
    let radii: Vec<f64> = match &y.vertex_radius {
        Some(v) => v.clone(),
        None => y.radius.clone(),
    };
    let bbox = y.bounds();
    YarnReport {
        path: path.to_string(),
        format: d.format.name().to_string(),
        curves: y.num_curves(),
        open_curves: y.num_curves() - y.num_closed(),
        closed_curves: y.num_closed(),
        points: y.num_points(),
        segments: y.num_segments(),
        points_per_curve: min_max((0..y.num_curves()).map(|c| y.curve_range(c).len()), 0),
        total_length_m: y.total_length(),
        segment_length_m: min_max(
            y.segments()
                .map(|[a, b]| crate::geom::dist(y.points[a], y.points[b])),
            0.0,
        ),
        bbox_m: bbox,
        bbox_size_m: bbox.map(|b| b.size()),
        radius_m: min_max(radii.iter().copied(), 0.0),
        radius_source: d.radius,
        per_vertex_radius: y.vertex_radius.is_some(),
        linear_density: y.linear_density.is_some(),
        rest_shape: y.rest.is_some(),
        rest_material: y.rest.as_ref().and_then(|r| r.material),
        units: d.units.0.name(),
        units_source: d.units.1,
        up_axis: d.up_axis.0.name().to_string(),
        up_axis_source: d.up_axis.1,
        frames: d.frames.as_ref().map_or(0, |f| f.num_frames()),
        frame_times_s: d
            .frames
            .as_ref()
            .filter(|f| f.num_frames() > 0)
            .map(|f| min_max(f.times.iter().copied(), 0.0)),
        welded_points: d.weld.welded_points,
        dropped_curves: d.weld.dropped_curves.len(),
        notes: d.notes.clone(),
        warnings: d.warnings(),
    }
}

impl YarnReport {
    /// Human-readable multi-line text.
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let src = |p: Provenance| match p {
            Provenance::Option => "from the command line",
            Provenance::File => "declared by the file",
            Provenance::Assumed => "ASSUMED: the file does not say",
        };
        let mut s = String::new();
        let _ = writeln!(s, "{}", self.path);
        let _ = writeln!(s, "  format        {}", self.format);
        let _ = writeln!(
            s,
            "  curves        {} ({} open, {} closed)",
            self.curves, self.open_curves, self.closed_curves
        );
        let _ = writeln!(
            s,
            "  points        {} ({} segments; {}..{} points per curve)",
            self.points, self.segments, self.points_per_curve.min, self.points_per_curve.max
        );
        let _ = writeln!(
            s,
            "  length        {:.6} m total; segments {:.3e}..{:.3e} m",
            self.total_length_m, self.segment_length_m.min, self.segment_length_m.max
        );
        if let Some(b) = &self.bbox_m {
            let z = b.size();
            let _ = writeln!(
                s,
                "  bbox          min [{:.6}, {:.6}, {:.6}] max [{:.6}, {:.6}, {:.6}] m (size {:.6} x {:.6} x {:.6})",
                b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], z[0], z[1], z[2]
            );
        }
        let _ = writeln!(
            s,
            "  radius        {:.4e}..{:.4e} m{} ({})",
            self.radius_m.min,
            self.radius_m.max,
            if self.per_vertex_radius {
                " per vertex"
            } else {
                ""
            },
            src(self.radius_source)
        );
        if self.rest_shape {
            let m = self
                .rest_material
                .map_or("no material recorded".into(), |m| {
                    format!("relaxed under {m}")
                });
            let _ = writeln!(s, "  rest shape    stored ({m})");
        }
        let _ = writeln!(
            s,
            "  file units    {} ({})",
            self.units,
            src(self.units_source)
        );
        let _ = writeln!(
            s,
            "  file up axis  +{} ({}); shown here in knitvox's metres, +Y up",
            self.up_axis,
            src(self.up_axis_source)
        );
        if self.frames > 0 {
            let t = self.frame_times_s.unwrap_or(MinMax { min: 0.0, max: 0.0 });
            let _ = writeln!(
                s,
                "  frames        {} (t = {} .. {} s)",
                self.frames, t.min, t.max
            );
        }
        for n in &self.notes {
            let _ = writeln!(s, "  note          {n}");
        }
        for w in &self.warnings {
            let _ = writeln!(s, "  warning       {w}");
        }
        s
    }
}
