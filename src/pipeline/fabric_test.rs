//! `knitvox fabric-test`: the physical tests of Sperl 2022 §4 on a yarn
//! swatch (a built-in or grid pattern sized to the test, or a yarn file),
//! relaxed into contact first unless the yarns carry a rest shape. Writes
//! the curve as CSV and PNG plot and the equilibrium frames (positions,
//! elastic energy, clamp reactions, external forces) as knitvox HDF5.
//! A bias swatch of a pattern is laid out larger and cut to the test
//! piece at 45 degrees to the courses before relaxation.
//!
//! Frames: the rigs work in the pattern generator's frame (fabric in x-y,
//! courses along X, a hang hanging it under -Y). A yarn file is turned into
//! it from whatever coordinate plane it lies in (`knitvox pattern` writes
//! the fabric frame, XZ), and the written frames are turned back into the
//! file's coordinates; a generated swatch's frames are written in the
//! fabric frame, as `knitvox pattern` would write that swatch.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::geom::{MaterialOverrides, Vec3, Yarns};
use crate::io::plot::{self, Figure, Panel, Series, PALETTE};
use crate::io::{self, h5::FrameWriter, IoError};
use crate::pipeline::pattern::{load_pattern, PatternSource, PatternStageError};
use crate::yarn::fabric::bend::{bend_test, BendParams, BendResult};
use crate::yarn::fabric::pose::FabricPlane;
use crate::yarn::fabric::rig::{cut_rectangle, held_together};
use crate::yarn::fabric::{
    hang_test, relax_into_contact, stretch_test, Direction, FabricError, FabricParams, HangParams,
    HangResult, MaterialChoice, RelaxIntoContactStats, RelaxParams, RigFrame, StretchParams,
    StretchResult,
};
use crate::yarn::pattern::{build_tile, lay_out, Layout, PatternParams};

/// Where the swatch comes from.
#[derive(Debug, Clone)]
pub enum SwatchSource {
    /// A pattern laid out to `size` = [width across the test axis, length
    /// along it] (m), after the relaxation's shrinkage estimate.
    Pattern {
        source: PatternSource,
        size: [f64; 2],
    },
    /// A yarn file (relaxed first when it carries no rest shape).
    Yarns(PathBuf),
}

/// Which test.
#[derive(Debug, Clone)]
pub enum FabricTest {
    Stretch(StretchParams),
    Bend(BendParams),
    Hang(HangParams),
}

impl FabricTest {
    pub fn name(&self) -> &'static str {
        match self {
            FabricTest::Stretch(_) => "stretch",
            FabricTest::Bend(_) => "bend",
            FabricTest::Hang(_) => "hang",
        }
    }
    /// Along which axis the swatch's `size[1]` (length) is laid out.
    fn direction(&self) -> Direction {
        match self {
            FabricTest::Stretch(p) => p.direction,
            FabricTest::Bend(p) => p.direction,
            FabricTest::Hang(_) => Direction::Warp,
        }
    }

    /// The files `-o DIR` gets besides `TEST.h5`: the curve as CSV and its
    /// plot.
    fn curve_files(&self) -> &'static [&'static str] {
        match self {
            FabricTest::Stretch(_) => &["stretch.csv", "stretch.png"],
            FabricTest::Bend(_) => &["bend.csv", "bend.png"],
            FabricTest::Hang(_) => &[],
        }
    }
}

/// Everything one run needs.
#[derive(Debug, Clone)]
pub struct FabricTestJob {
    pub swatch: SwatchSource,
    pub test: FabricTest,
    /// Friction, density and solver controls; its material applies where
    /// the yarns record none (a generated pattern, a file without a rest
    /// shape's material).
    pub fabric: FabricParams,
    /// Material fields that replace the yarns' recorded (or `fabric`'s) ones.
    pub material: MaterialOverrides,
    pub relax: RelaxParams,
    /// Output folder for the CSV and the frames (none: figures only).
    pub output_dir: Option<PathBuf>,
}

/// Errors, each naming its input.
#[derive(Debug, thiserror::Error)]
pub enum FabricTestError {
    #[error("pattern: {0}")]
    Pattern(#[from] PatternStageError),
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{what}: {source}")]
    Fabric {
        what: String,
        #[source]
        source: FabricError,
    },
    #[error("{}: {message}", path.display())]
    Output { path: PathBuf, message: String },
}

impl FabricTestError {
    /// Exit-code class; parameter errors (`FabricError::Setup`) are
    /// usage errors, which the CLI checks with [`Self::is_usage`].
    pub fn class(&self) -> io::ErrorClass {
        match self {
            FabricTestError::Io(e) => e.class(),
            FabricTestError::Pattern(PatternStageError::Read { .. }) => {
                io::ErrorClass::MissingInput
            }
            FabricTestError::Output { .. } => io::ErrorClass::Output,
            _ => io::ErrorClass::BadInput,
        }
    }
}

impl FabricTestError {
    pub fn is_usage(&self) -> bool {
        matches!(
            self,
            FabricTestError::Fabric {
                source: FabricError::Setup(_),
                ..
            }
        ) || self.class() == io::ErrorClass::Usage
    }
}

/// The test's outcome.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum TestFigures {
    Stretch(StretchResult),
    Bend(BendResult),
    Hang(HangResult),
}

/// What a run did (`--json` prints it).
#[derive(Debug, Clone, Serialize)]
pub struct FabricTestReport {
    pub test: &'static str,
    pub swatch: String,
    pub vertices: usize,
    /// The relaxation into contact (none when the yarns carried a rest shape).
    pub relaxation: Option<RelaxIntoContactStats>,
    /// Pieces of a bias cut left out after the relaxation because no
    /// contact held them to the test piece (`rig::held_together`).
    pub offcuts: usize,
    /// The yarn material the test ran under and where it came from.
    pub material: MaterialChoice,
    /// Warnings also printed on stderr.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    #[serde(flatten)]
    pub figures: TestFigures,
    pub written: Vec<PathBuf>,
}

fn fabric_err(what: &str) -> impl FnOnce(FabricError) -> FabricTestError + '_ {
    move |source| FabricTestError::Fabric {
        what: what.to_string(),
        source,
    }
}

/// Courses x wales of a pattern so that, shrunk by the relaxation's rest
/// length scale, the swatch measures about `size` ([across, along] the
/// test direction).
fn layout_for(
    pitch: [f64; 2],
    repeat: [usize; 2],
    size: [f64; 2],
    dir: Direction,
    scale: f64,
) -> Layout {
    let (along_x, along_y) = match dir {
        Direction::Weft => (size[1], size[0]),
        Direction::Warp => (size[0], size[1]),
        // A square holding the test piece turned by 45 degrees, with a
        // margin so the cut runs through whole stitches.
        Direction::Bias => {
            let d = 1.1 * (size[0] + size[1]) * std::f64::consts::FRAC_1_SQRT_2;
            (d, d)
        }
    };
    let count = |len: f64, p: f64, rep: usize| {
        let n = (len / (p * scale)).round().max(1.0) as usize;
        n.div_ceil(rep.max(1)) * rep.max(1)
    };
    Layout {
        courses: count(along_y, pitch[1], repeat[1]),
        wales: count(along_x, pitch[0], repeat[0]),
        tube_radius: None,
        helix: false,
        separate_courses: false,
    }
}

/// Fewest vertices of a yarn piece kept by the bias cut: shorter corner
/// fragments are not held by any loop.
const MIN_PIECE: usize = 8;

/// Two yarns touch, for [`held_together`], within this multiple of the sum
/// of their radii (relaxed contacts sit at 0.98-1.02).
const TOUCH: f64 = 1.1;

/// The turn between a swatch's own frame and the rigs' frame (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RigTurn {
    /// The plane the swatch lies in, in its own frame.
    pub plane: FabricPlane,
}

impl RigTurn {
    /// From the swatch's frame into the rigs'.
    pub fn to_rig(&self, p: Vec3) -> Vec3 {
        FabricPlane::Xy.from_pose(self.plane.to_pose(p))
    }
    /// From the rigs' frame back into the swatch's (the inverse of
    /// [`Self::to_rig`]; both are proper rotations, so vectors turn alike).
    pub fn from_rig(&self, p: Vec3) -> Vec3 {
        self.plane.from_pose(FabricPlane::Xy.to_pose(p))
    }
    fn turn_yarns(y: &mut Yarns, f: impl Fn(Vec3) -> Vec3 + Copy) {
        y.map_points(f);
        if let Some(rest) = y.rest.as_mut() {
            rest.transform(1.0, f);
        }
    }
}

/// A loaded or generated swatch, ready for its test.
pub struct Swatch {
    /// In the rigs' frame.
    pub yarns: Yarns,
    /// How the written frames turn back into the swatch's own frame.
    pub turn: RigTurn,
    pub name: String,
    /// The relaxation into contact (none when the yarns carried a rest shape).
    pub relaxation: Option<RelaxIntoContactStats>,
    /// Bias-cut pieces dropped after the relaxation.
    pub offcuts: usize,
    /// The job's parameters with the material chosen for these yarns.
    pub fabric: FabricParams,
    pub material: MaterialChoice,
}

/// Loads or generates the swatch, relaxing it when it has no rest shape; a
/// bias-cut piece then loses the offcuts no contact holds to it.
pub fn swatch(job: &FabricTestJob) -> Result<Swatch, FabricTestError> {
    let mut cut = false;
    let mut turn = RigTurn {
        plane: FabricPlane::Xz,
    };
    let (yarns, name) = match &job.swatch {
        SwatchSource::Yarns(path) => {
            let mut d = io::read_path(path, &Default::default())?;
            turn.plane = FabricPlane::of(&d.yarns.points);
            RigTurn::turn_yarns(&mut d.yarns, |p| turn.to_rig(p));
            (d.yarns, path.display().to_string())
        }
        SwatchSource::Pattern { source, size } => {
            let pat = load_pattern(source)?;
            let params = PatternParams::default();
            let tile = build_tile(&pat, &params).map_err(PatternStageError::Pattern)?;
            let layout = layout_for(
                tile.pitch,
                tile.repeat,
                *size,
                job.test.direction(),
                job.relax.length_scale,
            );
            let mut y = lay_out(&tile, &layout).map_err(PatternStageError::Pattern)?;
            let dir = job.test.direction();
            if dir == Direction::Bias {
                let (axis, transverse) = dir.axes();
                let s = job.relax.length_scale;
                y = cut_rectangle(&y, axis, transverse, size[1] / s, size[0] / s, MIN_PIECE)
                    .map_err(fabric_err("bias cut"))?;
                cut = true;
            }
            let name = match source {
                PatternSource::Builtin(n) => n.clone(),
                PatternSource::GridFile(p) => p.display().to_string(),
            };
            (y, format!("{name} {}x{}", layout.courses, layout.wales))
        }
    };
    let (fabric, material) = job.fabric.for_yarns(&yarns, &job.material);
    if yarns.rest.is_some() {
        return Ok(Swatch {
            yarns,
            turn,
            name,
            relaxation: None,
            offcuts: 0,
            fabric,
            material,
        });
    }
    let (mut relaxed, stats) = relax_into_contact(&yarns, &fabric, &job.relax)
        .map_err(fabric_err(&format!("{name}: relaxation")))?;
    let mut offcuts = 0;
    if cut {
        let keep = held_together(&relaxed, TOUCH);
        offcuts = keep.iter().filter(|k| !**k).count();
        if offcuts > 0 {
            relaxed = relaxed.select_curves(&keep);
        }
    }
    Ok(Swatch {
        yarns: relaxed,
        turn,
        name,
        relaxation: Some(stats),
        offcuts,
        fabric,
        material,
    })
}

/// Runs the job: swatch, test, outputs.
pub fn run(job: &FabricTestJob) -> Result<FabricTestReport, FabricTestError> {
    run_observed(job, &mut super::Quiet)
}

/// [`run`], telling `observer` its warnings as soon as the swatch is ready,
/// before the test (a stretch of a large swatch runs for minutes); the
/// report keeps them too.
pub fn run_observed(
    job: &FabricTestJob,
    observer: &mut dyn super::Observer,
) -> Result<FabricTestReport, FabricTestError> {
    match &job.test {
        FabricTest::Stretch(p) => p.check(),
        FabricTest::Bend(p) => p.check(),
        FabricTest::Hang(p) => p.check(),
    }
    .and_then(|_| job.relax.check())
    .map_err(fabric_err("parameters"))?;
    refuse_input_overwrite(job)?;
    let Swatch {
        yarns,
        turn,
        name,
        relaxation,
        offcuts,
        fabric,
        material,
    } = swatch(job)?;
    let warnings: Vec<String> = material.warning(&name).into_iter().collect();
    warnings.iter().for_each(|w| observer.warning(w));
    let mut written = Vec::new();
    let mut writer = match &job.output_dir {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| FabricTestError::Output {
                path: dir.clone(),
                message: e.to_string(),
            })?;
            let target = dir.join(format!("{}.h5", job.test.name()));
            let mut own = yarns.clone();
            RigTurn::turn_yarns(&mut own, |p| turn.from_rig(p));
            let mut w = FrameWriter::create(&target, &own)?;
            w.add_text(
                "fabric_parameters_json",
                &serde_json::to_string(&fabric).unwrap_or_default(),
            )?;
            Some(w)
        }
        None => None,
    };
    let mut io_error: Option<IoError> = None;
    // Progress counts the frames handed on (from 0; a stretch's
    // conditioning cycles are not among them).
    let total = match &job.test {
        FabricTest::Stretch(p) => p.steps + p.release_steps,
        FabricTest::Bend(p) => p.steps,
        FabricTest::Hang(p) => p.watch_steps(),
    };
    let mut last_frame = std::time::Instant::now();
    let mut on_frame = |f: &RigFrame| -> Result<(), FabricError> {
        observer.frame(&super::FrameProgress::of_rig(
            f.index,
            total,
            &mut last_frame,
        ));
        if let Some(w) = writer.as_mut() {
            let back = |v: &[Vec3]| v.iter().map(|p| turn.from_rig(*p)).collect::<Vec<_>>();
            let r = w
                .push(f.parameter, &back(f.points))
                .and_then(|_| w.push_mechanics(f.energy, &back(&f.reactions), &back(&f.external)));
            if let Err(e) = r {
                let msg = e.to_string();
                io_error = Some(e);
                return Err(FabricError::Setup(format!(
                    "writing frame {}: {msg}",
                    f.index
                )));
            }
        }
        Ok(())
    };
    let figures = match &job.test {
        FabricTest::Stretch(p) => {
            stretch_test(&yarns, &fabric, p, &mut on_frame).map(TestFigures::Stretch)
        }
        FabricTest::Bend(p) => bend_test(&yarns, &fabric, p, &mut on_frame).map(TestFigures::Bend),
        FabricTest::Hang(p) => hang_test(&yarns, &fabric, p, &mut on_frame).map(TestFigures::Hang),
    };
    if let Some(e) = io_error {
        return Err(e.into());
    }
    // The swatch is named: a yarn file's errors name the file.
    let figures = figures.map_err(fabric_err(&format!("{name}: {}", job.test.name())))?;
    if let (Some(dir), Some(w)) = (&job.output_dir, writer) {
        // Every file or none.
        io::atomic::all_or_nothing(|| {
            written.push(w.finish()?);
            let curve = match &figures {
                TestFigures::Stretch(s) => Some((stretch_csv(s), stretch_figure(s))),
                TestFigures::Bend(b) => Some((bend_csv(b), bend_figure(b))),
                TestFigures::Hang(_) => None,
            };
            if let Some((csv, fig)) = curve {
                let [csv_name, png_name] = job.test.curve_files() else {
                    unreachable!("curve tests name a CSV and a PNG")
                };
                let png_path = dir.join(png_name);
                let png = plot::render_png(&fig).map_err(|e| FabricTestError::Output {
                    path: png_path.clone(),
                    message: e.to_string(),
                })?;
                for (name, bytes) in [(csv_name, csv.as_bytes()), (png_name, &png[..])] {
                    let path = dir.join(name);
                    write_file(&path, bytes)?;
                    written.push(path);
                }
            }
            Ok::<_, FabricTestError>(())
        })?;
    }
    Ok(FabricTestReport {
        test: job.test.name(),
        swatch: name,
        vertices: yarns.num_points(),
        relaxation,
        offcuts,
        material,
        warnings,
        figures,
        written,
    })
}

/// Refuses an output folder whose files would replace the input yarn or
/// grid file (exit 2), before any work.
fn refuse_input_overwrite(job: &FabricTestJob) -> Result<(), FabricTestError> {
    let Some(dir) = &job.output_dir else {
        return Ok(());
    };
    let input = match &job.swatch {
        SwatchSource::Yarns(p) => p,
        SwatchSource::Pattern {
            source: PatternSource::GridFile(p),
            ..
        } => p,
        SwatchSource::Pattern { .. } => return Ok(()),
    };
    let mut outputs = vec![dir.join(format!("{}.h5", job.test.name()))];
    outputs.extend(job.test.curve_files().iter().map(|f| dir.join(f)));
    let outputs: Vec<&Path> = outputs.iter().map(|p| p.as_path()).collect();
    Ok(io::overwrite::refuse_inputs(&outputs, &[input])?)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), FabricTestError> {
    io::atomic::write_bytes(path, bytes).map_err(|e| FabricTestError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn stretch_csv(s: &StretchResult) -> String {
    let mut text = String::from("stretch,force_n,compression,energy_j,newton_iterations,residual_n,contacts_per_vertex,min_distance_ratio,phase\n");
    let phases = s
        .conditioning
        .iter()
        .enumerate()
        .flat_map(|(i, c)| {
            c.iter()
                .map(move |p| (p, format!("conditioning {}", i + 1)))
        })
        .chain(s.points.iter().map(|p| (p, "load".to_string())))
        .chain(s.release.iter().map(|p| (p, "release".to_string())));
    for (p, phase) in phases {
        text.push_str(&format!(
            "{},{},{},{},{},{},{},{},{}\n",
            p.stretch,
            p.force_n,
            p.compression,
            p.energy_j,
            p.newton_iterations,
            p.residual_n,
            p.contacts_per_vertex,
            p.min_distance_ratio,
            phase
        ));
    }
    text
}

fn bend_csv(b: &BendResult) -> String {
    let mut text = String::from(
        "clamp_distance_m,height_m,width_m,aspect_ratio,low_clamp_axial_n,low_clamp_up_n,\
         high_clamp_axial_n,high_clamp_up_n,energy_j,newton_iterations,residual_n,\
         contacts_per_vertex,min_distance_ratio\n",
    );
    for p in &b.points {
        text.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            p.clamp_distance_m,
            p.height_m,
            p.width_m,
            p.aspect_ratio,
            p.low_clamp_force_n[0],
            p.low_clamp_force_n[1],
            p.high_clamp_force_n[0],
            p.high_clamp_force_n[1],
            p.energy_j,
            p.newton_iterations,
            p.residual_n,
            p.contacts_per_vertex,
            p.min_distance_ratio
        ));
    }
    text
}

/// Force and orthogonal compression against stretch (Sperl 2022 §4.3).
fn stretch_figure(s: &StretchResult) -> Figure {
    type Point = crate::yarn::fabric::StretchPoint;
    let curve = |label: &str, pts: &[Point], f: &dyn Fn(&Point) -> f64, c| Series {
        label: label.into(),
        points: pts.iter().map(|p| [p.stretch, f(p)]).collect(),
        color: c,
    };
    // The conditioning cycles (when run), the measured loading drawn over
    // them, then the unloading, in their own colours.
    let series = |f: &dyn Fn(&Point) -> f64, what: &str, colour| {
        let mut v: Vec<Series> = s
            .conditioning
            .iter()
            .enumerate()
            .map(|(i, c)| curve(&format!("conditioning {}", i + 1), c, f, PALETTE[2]))
            .collect();
        v.push(curve(what, &s.points, f, colour));
        if !s.release.is_empty() {
            // From the top of the loading, so the loop closes.
            let from_top: Vec<Point> = s
                .points
                .last()
                .into_iter()
                .chain(&s.release)
                .copied()
                .collect();
            v.push(curve("release", &from_top, f, PALETTE[3]));
        }
        v
    };
    Figure {
        title: format!(
            "stretch test, {}: {:.0} x {:.0} mm, gauge {:.0} mm",
            s.direction.name(),
            1e3 * s.width_m,
            1e3 * s.length_m,
            1e3 * s.gauge_m
        ),
        panels: vec![
            Panel {
                x_label: "stretch l/l0 - 1".into(),
                y_label: "clamp force (N)".into(),
                series: series(&|p| p.force_n, "force", PALETTE[0]),
            },
            Panel {
                x_label: "stretch l/l0 - 1".into(),
                y_label: "orthogonal compression 1 - w/w0".into(),
                series: series(&|p| p.compression, "compression", PALETTE[1]),
            },
        ],
        size: (800, 900),
    }
}

/// Loop aspect ratio against clamp distance (Sperl 2022 §4.3, Fig. 8).
fn bend_figure(b: &BendResult) -> Figure {
    Figure {
        title: format!(
            "pear-loop test, {}: {:.0} x {:.0} mm, gauge {:.0} mm",
            b.direction.name(),
            1e3 * b.width_m,
            1e3 * b.length_m,
            1e3 * b.gauge_m
        ),
        panels: vec![Panel {
            x_label: "clamp distance d (cm)".into(),
            y_label: "aspect ratio h/p".into(),
            series: vec![Series {
                label: "h/p".into(),
                points: b
                    .points
                    .iter()
                    .map(|p| [100.0 * p.clamp_distance_m, p.aspect_ratio])
                    .collect(),
                color: PALETTE[0],
            }],
        }],
        size: (800, 500),
    }
}

/// A fabric test's class: its swatch's pattern errors keep theirs, its
/// parameter errors are usage errors.
impl crate::pipeline::error::StageFailure for FabricTestError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        match self {
            FabricTestError::Pattern(p) => p.class(),
            _ if self.is_usage() => crate::pipeline::ErrorClass::Usage,
            _ => FabricTestError::class(self).into(),
        }
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<FabricTestError> for crate::pipeline::Error {
    fn from(e: FabricTestError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}
