//! `embed`, `shapefit`, `export`: the homogenized asset stages.

use std::path::{Path, PathBuf};

use clap::Args;

use super::args::ReadArgs;
use super::exit::ExitCode;
use crate::embed::EmbedParams;
use crate::fit::ShapeFitParams;
use crate::geom::{FrameSpec, Units, UpAxis};
use crate::io::{Format, WriteOptions};
use crate::pipeline::asset as stages;
use crate::pipeline::card_transfer as stages_card;
use crate::pipeline::{Quiet, Stage};

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
    #[arg(long, value_name = "METRES", value_parser = super::parse::parse_positive)]
    pub voxel_size: Option<f64>,
    /// Refuse embeddings with more voxels than this.
    #[arg(long, default_value_t = EmbedParams::default().max_voxels, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_voxels: u64,
    /// Yarn material density (kg/m^3) for yarns without a linear density.
    #[arg(long, default_value_t = EmbedParams::default().material_density, value_parser = super::parse::parse_positive)]
    pub density: f64,
    /// Material card (`knitvox card`) for the garment's tets: `CARD.toml`
    /// for every tet, `CARD.toml@curves=0-3,7` for the yarn vertices of
    /// those curves, `CARD.toml@box=X0,Y0,Z0,X1,Y1,Z1` (m, +Y up) for those
    /// inside the box. Repeatable; a later region card wins where regions
    /// overlap [default: the placeholder material].
    #[arg(long, value_name = "CARD[@REGION]", value_parser = stages_card::CardSpec::parse)]
    pub card: Vec<stages_card::CardSpec>,
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
    #[arg(long, default_value_t = ShapeFitParams::default().alpha, value_parser = super::parse::parse_positive)]
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
    /// Steps to export [default: all]: farm frame numbers for a shot's output asset (the
    /// numbers simulate --yarns-out writes), 0-based step indices for other assets.
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

pub fn embed(a: &EmbedArgs) -> anyhow::Result<ExitCode> {
    let job = stages::EmbedJob {
        yarns: a.yarns.clone(),
        read: a.read.options(),
        params: EmbedParams {
            voxel_size: a.voxel_size,
            max_voxels: a.max_voxels,
            material_density: a.density,
            ..EmbedParams::default()
        },
        output: a.output.clone(),
        command: command_line(),
        cards: a.card.clone(),
    };
    let mut console = super::console::Console::new(false, 0, "");
    let r = job
        .run(&mut console)
        .map_err(|e| voxel_size_usage(e, a.voxel_size))?;
    let stats = &r.stats;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "asset": a.output.display().to_string(),
                "stats": stats,
                "welded_points": r.welded_points,
                "dropped_curves": r.dropped_curves,
                "cards": r.cards,
                "warnings": console.warnings,
            }))?
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
        if let Some(t) = &r.cards {
            for c in &t.cards {
                println!(
                    "  card {} ({}): {} tets, {} yarn vertices, stiffness x {:.3} (mesh {:.2} mm thick \
                     over {:.4} m^2 of fabric): gamma_s {:.4e} Pa, course {:.4e} Pa (beta {:.3e}), wale {:.4e} Pa (beta {:.3e})",
                    c.path.display(),
                    c.name,
                    c.tets,
                    c.yarn_vertices,
                    c.scale.factor,
                    1e3 * c.scale.mesh_thickness_m,
                    c.scale.fabric_area_m2,
                    c.material.gamma_s_pa,
                    c.material.course_pa,
                    c.material.course_beta,
                    c.material.wale_pa,
                    c.material.wale_beta
                );
            }
            println!(
                "  cards carried in {:.2} s; fibre directions from the rest yarns (anisotropy {:.3}){}",
                t.seconds,
                t.fibre_anisotropy,
                if t.uncovered_tets > 0 {
                    format!("; {} tets keep the placeholder", t.uncovered_tets)
                } else {
                    String::new()
                }
            );
        }
    }
    Ok(ExitCode::Success)
}

/// A voxel size given on the command line that needs more voxels or
/// memory than allowed is a usage error naming the flag (exit 2); from a
/// manifest or the default rule it stays bad input.
fn voxel_size_usage(e: crate::pipeline::Error, given: Option<f64>) -> crate::pipeline::Error {
    use crate::embed::EmbedError;
    let Some(h) = given else { return e };
    match e.downcast_stage::<stages::StageError>() {
        Some(stages::StageError::Embed {
            source:
                source @ (EmbedError::TooManyVoxels { .. }
                | EmbedError::TooMuchWork { .. }
                | EmbedError::GridTooWide { .. }),
            ..
        }) => {
            crate::pipeline::Error::Usage(format!("--voxel-size {}: {source}", crate::geom::num(h)))
        }
        _ => e,
    }
}

pub fn shapefit(a: &ShapefitArgs) -> anyhow::Result<ExitCode> {
    let job = stages::ShapefitJob {
        asset: a.asset.clone(),
        frames: a.frames.clone(),
        read: a.read.options(),
        selection: a.frames_spec.clone(),
        output: a.output.clone(),
        params: ShapeFitParams { alpha: a.alpha },
        command: command_line(),
    };
    let report = job.run(&mut Quiet)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{}: fitted {} frames (prepare {:.1} ms, median {:.2} ms per frame); worst RMS yarn error {:.3e} m",
            job.output_path().display(),
            report.frames,
            report.prepare_ms,
            report.fit_ms_per_frame_median,
            report.rms_error_max
        );
    }
    Ok(ExitCode::Success)
}

pub fn export(a: &ExportArgs) -> anyhow::Result<ExitCode> {
    let job = stages::ExportJob {
        asset: a.asset.clone(),
        selection: a.frames_spec.clone(),
        format: Format::from_path(Path::new(&format!("x.{}", a.format))).unwrap_or(Format::Ply),
        output: a.output.clone(),
        name: a.name.clone(),
        write: WriteOptions {
            units: a.out_units,
            up_axis: a.out_up_axis,
            first_frame: 0,
        },
        rest_if_static: false,
    };
    let r = job.run(&mut Quiet)?;
    if a.json {
        let files: Vec<String> = r.written.iter().map(|p| p.display().to_string()).collect();
        println!(
            "{}",
            serde_json::json!({ "steps": r.steps, "written": files })
        );
    } else {
        eprintln!(
            "exported {} step(s) into {} file(s)",
            r.steps,
            r.written.len()
        );
        for p in &r.written {
            println!("{}", p.display());
        }
    }
    Ok(ExitCode::Success)
}
