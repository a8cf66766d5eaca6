//! The built-in demo job: make a small example swatch, write it as the input
//! file, read it back, and convert it into every output format (with a short
//! animated frame sequence). Later issues grow this into the full pipeline.

use std::path::{Path, PathBuf};

use crate::geom::{YarnFrames, Yarns};
use crate::io::{self, Format, IoError, ReadOptions, WriteOptions};
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
}

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
pub fn run(out_dir: &Path, command: &str) -> Result<DemoReport, super::asset::StageError> {
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
    Ok(DemoReport {
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
