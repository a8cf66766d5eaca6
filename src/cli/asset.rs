//! `embed`, `shapefit`, `export`: the homogenized asset stages.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;

use super::{ExitCode, ReadArgs};
use crate::embed::EmbedParams;
use crate::fit::ShapeFitParams;
use crate::geom::{FrameSpec, Units, UpAxis};
use crate::io::{self, vtkhdf, Format, WriteOptions};
use crate::pipeline::asset as stages;

/// The command line as typed, for provenance.
pub fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

#[derive(Debug, Args)]
pub struct EmbedArgs {
    /// Yarn file (any readable format).
    pub yarns: PathBuf,
    /// Output asset (.vtkhdf).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Voxel edge length in metres [default: about 0.5 mesh nodes per yarn vertex, VH §4].
    #[arg(long, value_name = "METRES", value_parser = super::guard::parse_positive)]
    pub voxel_size: Option<f64>,
    /// Refuse embeddings with more voxels than this.
    #[arg(long, default_value_t = EmbedParams::default().max_voxels, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_voxels: u64,
    /// Yarn material density (kg/m^3) for yarns without a linear density.
    #[arg(long, default_value_t = EmbedParams::default().material_density, value_parser = super::guard::parse_positive)]
    pub density: f64,
    #[command(flatten)]
    pub read: ReadArgs,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ShapefitArgs {
    /// The asset (.vtkhdf); its time series is replaced by the fitted frames.
    pub asset: PathBuf,
    /// Yarn frames: knitvox HDF5 (.h5) or a `name.####.ext` sequence, same vertices as the asset's yarns.
    pub frames: PathBuf,
    /// Frames to fit, as 0-based indices into the frame file: `0-99`, `0-99x5`, `0,5,7-20` [default: all].
    #[arg(long = "frames", value_name = "SPEC")]
    pub frames_spec: Option<FrameSpec>,
    /// Write the fitted asset here instead of updating ASSET in place.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Weight of the position term of VH Eq. 6.
    #[arg(long, default_value_t = ShapeFitParams::default().alpha, value_parser = super::guard::parse_positive)]
    pub alpha: f64,
    #[command(flatten)]
    pub read: ReadArgs,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// The asset (.vtkhdf).
    pub asset: PathBuf,
    /// Steps to export, as 0-based indices into the asset's time series [default: all].
    #[arg(long = "frames", value_name = "SPEC")]
    pub frames_spec: Option<FrameSpec>,
    /// Output format.
    #[arg(long, value_parser = ["ply", "bcc", "obj", "gltf", "glb", "h5"], default_value = "ply")]
    pub format: String,
    /// Output folder (files `NAME.####.EXT`, or `NAME.h5`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Base name of the files [default: the asset's file stem].
    #[arg(long)]
    pub name: Option<String>,
    /// Unit of the written coordinates for bcc, obj, ply.
    #[arg(long, value_name = "mm|cm|m|SCALE", default_value = "m")]
    pub out_units: Units,
    /// Up axis of the written coordinates for bcc, obj, ply.
    #[arg(long, value_name = "y|z", default_value = "y")]
    pub out_up_axis: UpAxis,
    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

fn check_asset_ext(path: &Path) -> anyhow::Result<()> {
    if path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
        != Some("vtkhdf")
    {
        return Err(anyhow::Error::new(io::IoError::Unsupported {
            path: path.to_path_buf(),
            message: "an asset file must have the .vtkhdf extension".into(),
        }));
    }
    Ok(())
}

/// Resolves `--frames` against `n` available frames: 0-based indices, all
/// in range. One out of range is a usage error (exit 2) naming the option:
/// the file is fine, the option asks for what it does not hold.
fn select(
    spec: &Option<FrameSpec>,
    n: usize,
    what: &str,
    path: &Path,
) -> anyhow::Result<Vec<usize>> {
    let frames = spec.clone().unwrap_or_else(|| FrameSpec::all(n)).frames();
    frames
        .into_iter()
        .map(|f| {
            usize::try_from(f).ok().filter(|&i| i < n).ok_or_else(|| {
                super::guard::UsageError(format!(
                    "--frames {}: {what} {f} does not exist: {} has {n} {what}s (0..{})",
                    spec.as_ref().map_or(String::new(), |s| s.to_string()),
                    path.display(),
                    n.saturating_sub(1)
                ))
                .into()
            })
        })
        .collect()
}

pub fn embed(a: &EmbedArgs) -> anyhow::Result<ExitCode> {
    check_asset_ext(&a.output)?;
    let params = EmbedParams {
        voxel_size: a.voxel_size,
        max_voxels: a.max_voxels,
        material_density: a.density,
        ..EmbedParams::default()
    };
    let (asset, stats) =
        stages::build_asset(&a.yarns, &a.read.options(), &params, &command_line())?;
    let warnings = super::warn_all(
        stages::size_warning(&asset)
            .map(|w| format!("{}: {w}", a.yarns.display()))
            .into_iter()
            .collect(),
    );
    vtkhdf::write_asset(&a.output, &asset)?;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "asset": a.output.display().to_string(), "stats": stats, "warnings": warnings })
            )?
        );
    } else {
        println!(
            "{}: {} yarn vertices -> {} voxels (h = {:.4e} m, {}), {} nodes, {} tets, n_V/n_Y = {:.3}, yarn mass {:.4e} kg",
            a.output.display(),
            stats.yarn_vertices,
            stats.voxels,
            stats.voxel_size,
            stats.voxel_size_rule,
            stats.nodes,
            stats.tets,
            stats.nodes as f64 / stats.yarn_vertices.max(1) as f64,
            stats.total_yarn_mass
        );
    }
    Ok(ExitCode::Success)
}

pub fn shapefit(a: &ShapefitArgs) -> anyhow::Result<ExitCode> {
    check_asset_ext(&a.asset)?;
    let mut asset = vtkhdf::read_asset(&a.asset)?;
    let data = io::read_path(&a.frames, &a.read.options())?;
    let Some(frames) = data.frames else {
        return Err(anyhow::Error::new(io::IoError::Unsupported {
            path: a.frames.clone(),
            message:
                "holds no frames: give a knitvox HDF5 file with /frames or a name.####.ext sequence"
                    .into(),
        }));
    };
    let selection = select(&a.frames_spec, frames.num_frames(), "frame", &a.frames)?;
    let report = stages::shapefit(
        &mut asset,
        &a.asset,
        &frames,
        &selection,
        &ShapeFitParams { alpha: a.alpha },
    )?;
    asset.provenance.inputs.push(crate::geom::InputFile {
        path: a.frames.display().to_string(),
        sha256: if a.frames.is_file() {
            stages::sha256_file(&a.frames)?
        } else {
            String::new()
        },
    });
    asset.provenance.command = format!("{} && {}", asset.provenance.command, command_line());
    let out = a.output.clone().unwrap_or_else(|| a.asset.clone());
    vtkhdf::write_asset(&out, &asset).with_context(|| "writing the fitted asset")?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{}: fitted {} frames (prepare {:.1} ms, median {:.2} ms per frame); worst RMS yarn error {:.3e} m",
            out.display(),
            report.frames,
            report.prepare_ms,
            report.fit_ms_per_frame_median,
            report.rms_error_max
        );
    }
    Ok(ExitCode::Success)
}

pub fn export(a: &ExportArgs) -> anyhow::Result<ExitCode> {
    check_asset_ext(&a.asset)?;
    let asset = vtkhdf::read_asset(&a.asset)?;
    if asset.steps.num_steps() == 0 {
        return Err(anyhow::Error::new(io::IoError::Unsupported {
            path: a.asset.clone(),
            message: "the asset has no steps to export: fill it with `knitvox shapefit` or `knitvox simulate` first".into(),
        }));
    }
    let steps = select(&a.frames_spec, asset.steps.num_steps(), "step", &a.asset)?;
    let format = Format::from_path(Path::new(&format!("x.{}", a.format))).unwrap_or(Format::Ply);
    let name = a.name.clone().unwrap_or_else(|| {
        a.asset
            .file_stem()
            .map_or("asset".into(), |s| s.to_string_lossy().into_owned())
    });
    let opts = WriteOptions {
        units: a.out_units,
        up_axis: a.out_up_axis,
        first_frame: 0,
    };
    let written = stages::export(&asset, &steps, format, &a.output, &name, &opts)?;
    if a.json {
        let files: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        println!(
            "{}",
            serde_json::json!({ "steps": steps.len(), "written": files })
        );
    } else {
        eprintln!(
            "exported {} step(s) into {} file(s)",
            steps.len(),
            written.len()
        );
        for p in &written {
            println!("{}", p.display());
        }
    }
    Ok(ExitCode::Success)
}
