//! `knitvox yls SCENE.toml -o FRAMES.h5`: a yarn-level scene.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::yls::{run, YlsError};
use crate::pipeline::yls_scene::YlsScene;

#[derive(Debug, Args)]
pub struct YlsArgs {
    /// Scene file (schemas/yls-scene.md; examples/scenes/yls-*.toml).
    pub scene: PathBuf,
    /// Output knitvox HDF5 file (rest yarns, frames, times, scene, parameters).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print the run's figures as JSON.
    #[arg(long)]
    pub json: bool,
    /// Show a progress bar (on by default when stderr is a terminal).
    #[arg(long, overrides_with = "no_progress")]
    pub progress: bool,
    /// Never show a progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn yls(a: &YlsArgs) -> anyhow::Result<ExitCode> {
    let ext = a.output.extension().and_then(|e| e.to_str()).unwrap_or("");
    if !matches!(ext.to_ascii_lowercase().as_str(), "h5" | "hdf5") {
        return Err(anyhow::Error::new(crate::io::IoError::Unsupported {
            path: a.output.clone(),
            message: "yls writes knitvox HDF5 frames; name the output .h5 or .hdf5".into(),
        }));
    }
    let text = std::fs::read_to_string(&a.scene).map_err(|source| crate::io::IoError::Read {
        path: a.scene.clone(),
        source,
    })?;
    let scene = YlsScene::parse(&text, &a.scene).map_err(YlsError::from)?;
    let show = !a.no_progress && (a.progress || std::io::stderr().is_terminal());
    let result = super::with_frame_progress(show, scene.num_frames(), "yarn-level", |progress| {
        run(&scene, &text, &a.scene, &a.output, progress)
    });
    let r = result?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{}: {} frames of {} vertices ({} curves, {} clamped), {} steps; min distance / 2r {:.3}, max step / r {:.3}; {:.1} ms per frame (median), {:.1} s total",
            r.output.display(),
            r.frames,
            r.vertices,
            r.curves,
            r.handled_vertices,
            r.steps,
            r.min_distance_ratio,
            r.max_displacement_ratio,
            r.ms_per_frame_median,
            r.wall_s
        );
    }
    Ok(ExitCode::Success)
}
