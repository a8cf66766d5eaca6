//! The built-in demo job: make a small example swatch, write it as the input
//! file, read it back, and convert it into every output format (with a short
//! animated frame sequence); embed it into a homogenized asset, shape-fit and
//! export frames; then simulate two shots of the asset — dropped onto a
//! sphere, and laid on the back of the walking Fox.glb character — and write
//! their caches (asset time series and per-frame yarn curves).

use std::path::{Path, PathBuf};

use crate::geom::{YarnFrames, Yarns};
use crate::io::{self, Format, IoError, ReadOptions, WriteOptions};
use crate::pipeline::simulate::{read_scene, simulate, ShotRequest, SimulateError, SimulateReport};
use crate::yarn::analytic::{knit_swatch, SwatchParams};

use super::inspect::{summarize, YarnReport};

/// Files the demo wrote and what it read back.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DemoReport {
    pub input: PathBuf,
    pub input_report: YarnReport,
    pub outputs: Vec<PathBuf>,
    pub frames: usize,
    /// The homogenized asset built from the swatch, with the fitted frames as its time series.
    pub asset: PathBuf,
    pub embed: crate::embed::EmbedStats,
    pub shapefit: super::asset::ShapefitReport,
    /// Fitted frames exported back to yarn curves (V2Y).
    pub exported: Vec<PathBuf>,
    /// The swatch dropped onto a sphere (examples/drape-sphere.toml).
    pub drape: SimulateReport,
    /// The swatch on the walking fox (examples/fox-walk.toml).
    pub fox: SimulateReport,
    /// The yarn-level stage: a generated 1x1 rib swatch stretched 30% by
    /// the yarn simulator (examples/scenes/yls-demo-rib-stretch.toml).
    pub yls: super::yls::YlsReport,
    /// The fabric stretch test (Sperl 2022 §4) of a small 1x1 rib relaxed
    /// into contact: clamp force and compression at 10% to 50%.
    pub fabric: super::fabric_test::FabricTestReport,
    /// Homogenization: a small rib's material fitted to two yarn-level
    /// training poses and its fidelity on a held-out pose.
    pub fit: FitDemo,
}

/// The demo's fitting stage (VH §6): `fit-demo/job.toml` (embed, train a
/// 10% course stretch and a central bend), a joint fit, then `validate` on
/// a held-out shear.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FitDemo {
    pub job: PathBuf,
    pub fitted: PathBuf,
    pub fit: super::fit::FitJobReport,
    /// The held-out scene and what `validate` measured on it.
    pub held_out: PathBuf,
    pub validate: super::validate::ValidateReport,
    /// Wall time of the whole stage (s).
    pub wall_s: f64,
}

/// The demo's training job: a 4 x 4 rib relaxed into contact, two
/// training poses of two load steps (the fit follows, with its report).
const FIT_JOB: &str = r#"# knitvox demo: fit a small rib to two yarn-level poses (schemas/job.md)
[garment]
yarns = "rib.h5"
[[train]]
kind = "stretch_courses"
amount = 0.1
steps = 2
[[train]]
kind = "bend_central"
amount = 0.3
steps = 2
"#;

/// The held-out motion: a shear, a pose family the fit never saw.
const HELD_OUT_SCENE: &str = r#"# knitvox demo: held-out pose for `validate` (schemas/yls-scene.md)
name = "held-out-shear"
duration = 0.1
frame_rate = 50
gravity = [0.0, 0.0, 0.0]
# the yarn mechanics of the training poses (implicit Euler on the rods)
model = "rods"
[pose]
kind = "shear"
amount = 0.1
ramp = 0.08
"#;

/// The demo scenes and character, compiled in so the demo runs from any
/// folder (they are written next to the demo's outputs).
const DRAPE_SCENE: &str = include_str!("../../examples/drape-sphere.toml");
const FOX_SCENE: &str = include_str!("../../examples/fox-walk.toml");
const FOX_GLB: &[u8] = include_bytes!("../../examples/Fox.glb");
const CREDITS: &str = include_str!("../../examples/CREDITS.md");
const YLS_SCENE: &str = include_str!("../../examples/scenes/yls-demo-rib-stretch.toml");

/// Frames of the demo shots (24 fps): a third of a second each (the fox
/// walks half its cycle after a 0.1 s pre-roll), so that the demo stays
/// quick where the tests run it (debug build, 2 cores).
const DRAPE_FRAMES: std::ops::RangeInclusive<i64> = 1..=8;
const FOX_FRAMES: std::ops::RangeInclusive<i64> = 1..=8;

/// A short analytic animation: the swatch stretched along x by up to 30%
/// while it sags along -y (frames at 24 fps).
pub fn demo_frames(rest: &Yarns, count: usize) -> YarnFrames {
    let mut frames = YarnFrames::new(rest.num_points());
    let x0 = rest.bounds().map_or(0.0, |b| b.min[0]);
    let mut buf = Vec::with_capacity(rest.num_points());
    for f in 0..count {
        let s = f as f64 / (count.max(2) - 1) as f64;
        buf.clear();
        buf.extend(rest.points.iter().map(|p| {
            let u = p[0] - x0;
            [
                x0 + u * (1.0 + 0.3 * s),
                p[1] - 0.002 * s * (u * 40.0).sin().abs(),
                p[2],
            ]
        }));
        frames
            .push_frame(f as f64 / 24.0, &buf)
            .expect("same vertex count");
    }
    frames
}

/// Runs the demo into `out_dir` (created if missing): the yarn-format part,
/// then embed -> shape-fit the frames -> export the fitted frames.
pub fn run(out_dir: &Path, command: &str) -> Result<DemoReport, DemoError> {
    let (input, input_report, outputs, frames) = formats(out_dir)?;
    let asset_path = out_dir.join("swatch.vtkhdf");
    let read = ReadOptions {
        radius: input_report.radius_m.min,
        ..ReadOptions::default()
    };
    let (mut asset, embed) =
        super::asset::build_asset(&input, &read, &Default::default(), command)?;
    let selection: Vec<usize> = (0..frames.num_frames()).collect();
    let shapefit = super::asset::shapefit(
        &mut asset,
        &asset_path,
        &frames,
        &selection,
        &Default::default(),
    )?;
    io::vtkhdf::write_asset(&asset_path, &asset)?;
    let exported = super::asset::export(
        &asset,
        &selection,
        Format::Ply,
        &out_dir.join("fitted"),
        "swatch",
        &WriteOptions::default(),
    )?;
    atomic_write(&out_dir.join("Fox.glb"), FOX_GLB)?;
    atomic_write(&out_dir.join("CREDITS.md"), CREDITS.as_bytes())?;
    // The two shots are independent: run them side by side.
    let (drape, fox) = rayon::join(
        || {
            shot(
                out_dir,
                &asset,
                &asset_path,
                "drape",
                DRAPE_SCENE,
                DRAPE_FRAMES,
                command,
            )
        },
        || {
            shot(
                out_dir,
                &asset,
                &asset_path,
                "fox-walk",
                FOX_SCENE,
                FOX_FRAMES,
                command,
            )
        },
    );
    let (drape, fox) = (drape?, fox?);
    // Yarn level: generate and relax a 1x1 rib swatch, stretch it 30%.
    let scene_path = out_dir.join("yls-rib-stretch.toml");
    atomic_write(&scene_path, YLS_SCENE.as_bytes())?;
    let scene = super::yls_scene::YlsScene::parse(YLS_SCENE, &scene_path)
        .map_err(super::yls::YlsError::from)?;
    let yls = super::yls::run(
        &scene,
        YLS_SCENE,
        &scene_path,
        &out_dir.join("yls-rib-stretch.h5"),
        &mut |_, _| {},
    )?;
    let fabric = fabric_stretch(out_dir)?;
    let fit = fit_demo(&out_dir.join("fit-demo"), command)?;
    Ok(DemoReport {
        fit,
        fabric,
        drape,
        fox,
        yls,
        input,
        input_report,
        outputs,
        frames: frames.num_frames(),
        asset: asset_path,
        embed,
        shapefit,
        exported,
    })
}

/// Relaxes a 3 cm x 4 cm 1x1 rib into contact and stretches it along the
/// courses to 50% in 10% steps (CSV, frames and plot under `fabric-stretch/`).
fn fabric_stretch(out_dir: &Path) -> Result<super::fabric_test::FabricTestReport, DemoError> {
    use super::fabric_test::{run, FabricTest, FabricTestJob, SwatchSource};
    let job = FabricTestJob {
        swatch: SwatchSource::Pattern {
            source: super::pattern::PatternSource::Builtin("rib1x1".into()),
            size: [0.03, 0.04],
        },
        test: FabricTest::Stretch(crate::yarn::fabric::StretchParams {
            max_stretch: 0.5,
            steps: 5,
            ..Default::default()
        }),
        fabric: Default::default(),
        material: Default::default(),
        relax: Default::default(),
        output_dir: Some(out_dir.join("fabric-stretch")),
    };
    Ok(run(&job)?)
}

/// Generates a 4 x 4 rib relaxed into contact (`fit-demo/rib.h5`), runs
/// [`FIT_JOB`] (embed, two training poses, joint fit) and validates the
/// fitted asset on [`HELD_OUT_SCENE`].
fn fit_demo(dir: &Path, command: &str) -> Result<FitDemo, DemoError> {
    use super::pattern::{generate, PatternJob, PatternSource};
    use super::Stage;
    let t = std::time::Instant::now();
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let pattern = PatternJob {
        source: PatternSource::Builtin("rib1x1".into()),
        layout: crate::yarn::pattern::Layout {
            courses: 4,
            wales: 4,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
        params: Default::default(),
        relax: Some(Default::default()),
        material: crate::yarn::fabric::FabricParams::default().material(),
    };
    let (rib, _) = generate(&pattern).map_err(super::Error::from)?;
    io::write_path(&dir.join("rib.h5"), &rib, None, &WriteOptions::default())?;
    let job_path = dir.join("job.toml");
    atomic_write(&job_path, FIT_JOB.as_bytes())?;
    let job = super::job::Job::load(&job_path)?;
    let trained = super::job::run(&job, None, command, &mut super::Quiet)?;
    let poses: Vec<PathBuf> = trained
        .stages
        .iter()
        .filter(|s| s.name.starts_with("train"))
        .flat_map(|s| s.outputs.iter().map(|o| job.output.join(o)))
        .collect();
    let fitted = job.output.join("fitted.vtkhdf");
    let fit = super::fit::FitJob {
        asset: job.output.join("garment.vtkhdf"),
        train: poses,
        read: ReadOptions::default(),
        samples: 1,
        params: crate::fit::elastic::ElasticFitParams {
            harmonic_ranks: vec![1, 10],
            ..Default::default()
        },
        output: Some(fitted.clone()),
        report: Some(dir.join("fit-report")),
        joint: true,
        quasi_static: false,
        fibres: false,
        // VH Eq. 7: the demo's fit stays within seconds; the knit default
        // takes minutes even on this swatch.
        model: super::fit::FitModel::Vh,
        shape_fit_pins: false,
        command: command.into(),
    }
    .run(&mut super::Quiet)?;
    let held_out = dir.join("held-out-shear.toml");
    atomic_write(&held_out, HELD_OUT_SCENE.as_bytes())?;
    let validate = super::validate::ValidateJob {
        asset: fitted.clone(),
        scene: held_out.clone(),
        uniform: true,
        report: Some(dir.join("validate")),
        homogenized: Default::default(),
        truth: None,
        compare_vh: None,
        fit_damping: None,
    }
    .run(&mut super::Quiet)?;
    Ok(FitDemo {
        job: job_path,
        fitted,
        fit,
        held_out,
        validate,
        wall_s: t.elapsed().as_secs_f64(),
    })
}

/// Errors of the demo: a stage's or a shot's.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error(transparent)]
    Stage(#[from] super::asset::StageError),
    #[error(transparent)]
    Shot(#[from] SimulateError),
    #[error(transparent)]
    YarnLevel(#[from] super::yls::YlsError),
    #[error(transparent)]
    Fabric(#[from] super::fabric_test::FabricTestError),
    #[error(transparent)]
    Pipeline(#[from] super::Error),
}

impl From<IoError> for DemoError {
    fn from(e: IoError) -> Self {
        DemoError::Stage(e.into())
    }
}

fn atomic_write(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    io::atomic::write_bytes(path, bytes)
}

/// One demo shot: writes `name.toml` into `out_dir`, simulates the asset
/// under it into `name.vtkhdf` and `name/swatch.####.ply`.
fn shot(
    out_dir: &Path,
    asset: &crate::geom::Asset,
    asset_path: &Path,
    name: &str,
    scene_text: &str,
    frames: std::ops::RangeInclusive<i64>,
    command: &str,
) -> Result<SimulateReport, DemoError> {
    let scene_path = out_dir.join(format!("{name}.toml"));
    atomic_write(&scene_path, scene_text.as_bytes())?;
    let scene = read_scene(&scene_path)?;
    let yarn_dir = out_dir.join(name);
    std::fs::create_dir_all(&yarn_dir).map_err(|source| IoError::Write {
        path: yarn_dir.clone(),
        source,
    })?;
    let req = ShotRequest {
        frames: frames.collect(),
        output: out_dir.join(format!("{name}.vtkhdf")),
        yarns_out: Some(yarn_dir.join("swatch.####.ply")),
        write: WriteOptions::default(),
        command: command.to_string(),
    };
    Ok(simulate(asset, asset_path, &scene, &req, &mut |_, _| {})?)
}

/// The yarn-format part of the demo: example input, inspection, every output format.
fn formats(out_dir: &Path) -> Result<(PathBuf, YarnReport, Vec<PathBuf>, YarnFrames), IoError> {
    std::fs::create_dir_all(out_dir).map_err(|source| IoError::Write {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let swatch = knit_swatch(&SwatchParams::default());
    let input = out_dir.join("example_swatch.bcc");
    io::write_path(&input, &swatch, None, &WriteOptions::default())?;

    let data = io::read_path(
        &input,
        &ReadOptions {
            radius: swatch.radius[0],
            ..ReadOptions::default()
        },
    )?;
    let input_report = summarize(&input.display().to_string(), &data);

    let frames = demo_frames(&data.yarns, 5);
    let mut outputs = Vec::new();
    for format in Format::ALL.into_iter().filter(|f| f.is_writable()) {
        let ext = format.extensions()[0];
        outputs.extend(io::write_path(
            &out_dir.join(format!("swatch.{ext}")),
            &data.yarns,
            None,
            &WriteOptions::default(),
        )?);
        let seq = if format.holds_frames() {
            format!("swatch_frames.{ext}")
        } else {
            format!("swatch_frames.####.{ext}")
        };
        outputs.extend(io::write_path(
            &out_dir.join(seq),
            &data.yarns,
            Some(&frames),
            &WriteOptions::default(),
        )?);
    }
    Ok((input, input_report, outputs, frames))
}
