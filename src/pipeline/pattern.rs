//! The `knitvox pattern` stage: a named or grid pattern -> periodic tile ->
//! flat swatch or tube -> relaxation into contact (quasi-static, rest
//! lengths scaled, `yarn::fabric::relax_into_contact`) -> clearance check
//! and report. The relaxed yarns carry the rest shape the simulators use.
//!
//! Frame: a flat swatch comes out in the **fabric frame** every pose, scene
//! and test uses (`yarn::poses`): lying in the XZ plane, front face +Y,
//! courses along +X, wales along -Z. The generator itself lays loops out
//! in the x-y plane (front +Z); [`generate`] turns them with
//! [`to_fabric_frame`]. A tube stays as generated (axis along Y).

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::geom::{YarnMaterial, Yarns};
use crate::pipeline::ErrorClass;
use crate::yarn::fabric::{
    relax_into_contact, FabricError, FabricParams, RelaxIntoContactStats, RelaxParams,
};
use crate::yarn::pattern::{
    self, build_tile, character, lay_out, min_segment_distance, Character, Layout, Pattern,
    PatternError, PatternParams,
};
use crate::yarn::sim::YarnSimParams;

/// Where the pattern comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum PatternSource {
    /// A built-in name (`yarn::pattern::BUILTIN_NAMES`).
    Builtin(String),
    /// A grid text file (`schemas/pattern-grid.md`).
    GridFile(PathBuf),
}

/// Everything `knitvox pattern` needs.
#[derive(Debug, Clone)]
pub struct PatternJob {
    pub source: PatternSource,
    pub layout: Layout,
    pub params: PatternParams,
    /// Relax the swatch into contact with these controls (none: the
    /// generated, loose curves without a rest shape).
    pub relax: Option<RelaxParams>,
    /// The yarn material the relaxation runs under, recorded with the rest
    /// shape (default: `FabricParams::default().material()`).
    pub material: YarnMaterial,
}

/// Why the stage failed; [`PatternStageError::class`] classifies it.
#[derive(Debug, thiserror::Error)]
pub enum PatternStageError {
    #[error("{path}: cannot read: {source}", path = path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A grid file is malformed: `path:line:column: message`.
    #[error("{path}:{line}:{column}: {message}", path = path.display())]
    Grid {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// A grid file that is not a regular file or exceeds the memory budget.
    #[error("{0}")]
    Input(crate::io::IoError),
    #[error("{0}")]
    UnknownPattern(PatternError),
    #[error("{0}")]
    Pattern(PatternError),
    /// The relaxation found no equilibrium or was given bad parameters.
    #[error("relaxation: {0}")]
    Relax(FabricError),
}

impl PatternStageError {
    /// An unknown name and bad sizes come from the request (usage); a
    /// malformed grid or a relaxation without equilibrium is bad input; an
    /// unreadable grid file is missing; any other pattern error is a bug.
    pub fn class(&self) -> ErrorClass {
        match self {
            PatternStageError::UnknownPattern(_) => ErrorClass::Usage,
            PatternStageError::Read { source, .. } => match source.kind() {
                std::io::ErrorKind::InvalidData => ErrorClass::BadInput,
                _ => ErrorClass::Missing,
            },
            PatternStageError::Grid { .. } => ErrorClass::BadInput,
            PatternStageError::Input(e) => e.class().into(),
            PatternStageError::Pattern(PatternError::BadParameter { .. }) => ErrorClass::Usage,
            PatternStageError::Pattern(_) => ErrorClass::Internal,
            PatternStageError::Relax(_) => ErrorClass::BadInput,
        }
    }
}

/// What was generated (lengths in metres).
#[derive(Debug, Clone, Serialize)]
pub struct PatternReport {
    /// Built-in name or grid file path.
    pub pattern: String,
    /// "knit" or "woven".
    pub kind: &'static str,
    /// One repeat: [columns, rows] (wales x courses; warps x wefts).
    pub repeat: [usize; 2],
    pub courses: usize,
    pub wales: usize,
    /// Tube radius (m), null for a flat swatch.
    pub tube_radius: Option<f64>,
    /// Tubes: courses joined into one helix (else closed rings).
    pub helix: bool,
    /// Flat swatches: each course a separate yarn (else one yarn knitted
    /// back and forth).
    pub separate_courses: bool,
    /// 2 pi R / (wales * wale width) for tubes, 1 for flat swatches.
    pub circumferential_stretch: f64,
    pub yarn_radius: f64,
    /// Pitch (m): [wale width, course height] (knit) or [spacing, spacing] (woven).
    pub pitch: [f64; 2],
    pub curves: usize,
    pub vertices: usize,
    pub segments: usize,
    /// Vertices per stitch (knit) or per crossing (woven) of the tile.
    pub vertices_per_stitch: f64,
    pub total_length: f64,
    /// Bounding-box size (m).
    pub size: [f64; 3],
    /// Smallest distance between non-adjacent segments / 2r (>= 1: no
    /// interpenetration), searched up to 4r; see `yarn::pattern::distance`.
    pub min_distance_ratio: f64,
    pub min_distance: f64,
    /// Whether the relaxation into contact ran.
    pub relaxed: bool,
    /// Its statistics: rest length scale, Newton iterations, residual (N),
    /// contacts at the end (contacts per vertex, fraction of vertices
    /// touching, minimum distance ratio), size before and after (m).
    pub relaxation: Option<RelaxIntoContactStats>,
    /// The yarn material the relaxation ran under (stored with the rest
    /// shape); null when not relaxed.
    pub material: Option<YarnMaterial>,
    /// Relaxed flat swatches: contacts per vertex at the end of the
    /// relaxation (segment pairs closer than the radii sum, x 2 / vertices)
    /// and the fraction of vertices touching a non-adjacent segment (within
    /// 1.02 x 2r); null when not relaxed.
    pub contacts_per_vertex: Option<f64>,
    pub near_fraction: Option<f64>,
    /// Relaxed flat swatches: size against the generated swatch (width and
    /// height ratios: rib draw-in, garter shortening) and edge curl (mean
    /// rise of each edge band from the centre's plane, m; stockinette: the
    /// sides curl to the back, the top and bottom to the front); see
    /// `yarn::pattern::character`. Null for tubes and unrelaxed swatches.
    pub character: Option<Character>,
    /// Periodic tile figures.
    pub tile_curves: usize,
    pub tile_vertices: usize,
    pub lattice: [[f64; 3]; 2],
    /// Files written (filled in by the caller).
    pub written: Vec<PathBuf>,
}

/// Resolves the pattern of a job (reads the grid file if any).
pub fn load_pattern(source: &PatternSource) -> Result<Pattern, PatternStageError> {
    match source {
        PatternSource::Builtin(name) => {
            pattern::builtin(name).map_err(PatternStageError::UnknownPattern)
        }
        PatternSource::GridFile(path) => {
            let text =
                crate::io::input::read_input_text(path, "pattern grid", crate::io::max_memory())
                    .map_err(|e| match e {
                        crate::io::IoError::Read { path, source } => {
                            PatternStageError::Read { path, source }
                        }
                        other => PatternStageError::Input(other),
                    })?;
            pattern::parse_grid(&text).map_err(|e| grid_error(path, e))
        }
    }
}

fn grid_error(path: &Path, e: PatternError) -> PatternStageError {
    match e {
        PatternError::Grid {
            line,
            column,
            message,
        } => PatternStageError::Grid {
            path: path.to_path_buf(),
            line,
            column,
            message,
        },
        other => PatternStageError::Pattern(other),
    }
}

/// The generator's frame (fabric in x-y, front +Z) into the fabric frame
/// (fabric in XZ, front +Y): `(x, y, z) -> (x, z, -y)`, a proper rotation,
/// the same map as reading a Z-up file.
pub fn to_fabric_frame(p: crate::geom::Vec3) -> crate::geom::Vec3 {
    crate::yarn::fabric::pose::FabricPlane::Xy.to_pose(p)
}

/// Runs the stage: pattern -> tile -> relaxation -> layout -> report. A flat
/// swatch is returned in the fabric frame ([`to_fabric_frame`]).
pub fn generate(job: &PatternJob) -> Result<(Yarns, PatternReport), PatternStageError> {
    let pat = load_pattern(&job.source)?;
    let tile = build_tile(&pat, &job.params).map_err(PatternStageError::Pattern)?;
    let mut yarns = lay_out(&tile, &job.layout).map_err(PatternStageError::Pattern)?;
    let r = job.params.yarn_radius;
    // One density source: the yarn model's density times the cross-section,
    // written with the curves so that `yls`, `embed` and `simulate` weigh
    // the same yarn (kg/m).
    let linear_density = YarnSimParams::default().density * std::f64::consts::PI * r * r;
    yarns.linear_density = Some(vec![linear_density; yarns.num_curves()]);
    let mut shape = None;
    let relaxation = match &job.relax {
        Some(rp) => {
            let fabric = FabricParams::default().with_material(&job.material);
            let (relaxed, stats) =
                relax_into_contact(&yarns, &fabric, rp).map_err(PatternStageError::Relax)?;
            if job.layout.tube_radius.is_none() {
                shape = character(&yarns.points, &relaxed.points, tile.pitch);
            }
            yarns = relaxed;
            Some(stats)
        }
        None => None,
    };
    if job.layout.tube_radius.is_none() {
        yarns.map_points(to_fabric_frame);
        if let Some(rest) = yarns.rest.as_mut() {
            rest.transform(1.0, to_fabric_frame);
        }
    }
    let md = min_segment_distance(&yarns, std::f64::consts::PI * r, 4.0 * r);
    let stitches = (tile.repeat[0] * tile.repeat[1]).max(1) as f64;
    // Woven: a crossing holds one weft and one warp interval.
    let per_stitch = tile.tile.yarns.num_points() as f64 / stitches;
    let report = PatternReport {
        pattern: match &job.source {
            PatternSource::Builtin(n) => n.clone(),
            PatternSource::GridFile(p) => p.display().to_string(),
        },
        kind: pat.kind(),
        repeat: tile.repeat,
        courses: job.layout.courses,
        wales: job.layout.wales,
        tube_radius: job.layout.tube_radius,
        helix: job.layout.helix,
        separate_courses: job.layout.separate_courses,
        circumferential_stretch: job.layout.circumferential_stretch(&tile),
        yarn_radius: r,
        pitch: tile.pitch,
        curves: yarns.num_curves(),
        vertices: yarns.num_points(),
        segments: yarns.num_segments(),
        vertices_per_stitch: per_stitch,
        total_length: yarns.total_length(),
        size: yarns.bounds().map_or([0.0; 3], |b| b.size()),
        min_distance_ratio: md.ratio,
        min_distance: md.distance,
        relaxed: relaxation.is_some(),
        contacts_per_vertex: relaxation.as_ref().map(|r| r.contact.contacts_per_vertex),
        near_fraction: relaxation.as_ref().map(|r| r.contact.near_fraction),
        character: shape,
        material: relaxation.as_ref().map(|_| job.material),
        relaxation,
        tile_curves: tile.tile.yarns.num_curves(),
        tile_vertices: tile.tile.yarns.num_points(),
        lattice: tile.tile.lattice,
        written: Vec::new(),
    };
    Ok((yarns, report))
}

impl crate::pipeline::error::StageFailure for PatternStageError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        PatternStageError::class(self)
    }
    fn file(&self) -> Option<std::path::PathBuf> {
        match self {
            PatternStageError::Read { path, .. } | PatternStageError::Grid { path, .. } => {
                Some(path.clone())
            }
            _ => None,
        }
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<PatternStageError> for crate::pipeline::Error {
    fn from(e: PatternStageError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generate_reports_counts() {
        let job = PatternJob {
            source: PatternSource::Builtin("garter".into()),
            layout: Layout {
                courses: 4,
                wales: 5,
                tube_radius: None,
                helix: false,
                separate_courses: false,
            },
            params: PatternParams::default(),
            relax: None,
            material: FabricParams::default().material(),
        };
        let (y, r) = generate(&job).unwrap();
        // One yarn knitted back and forth, with the model's linear density.
        assert_eq!(r.curves, 1);
        let ld = y.linear_density.as_ref().unwrap()[0];
        assert!(
            (ld - 120.0 * std::f64::consts::PI * 1e-6).abs() < 1e-12,
            "{ld}"
        );
        assert_eq!(r.vertices, y.num_points());
        assert!(!r.relaxed);
        assert!(r.min_distance_ratio >= 0.95, "{}", r.min_distance_ratio);
        assert_eq!(r.repeat, [1, 2]);
    }

    #[test]
    fn grid_errors_carry_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.grid");
        std::fs::write(&p, "K\nZ\n").unwrap();
        let e = load_pattern(&PatternSource::GridFile(p.clone())).unwrap_err();
        assert_eq!(
            e.to_string().split(": ").next().unwrap(),
            format!("{}:2:1", p.display())
        );
    }
}
