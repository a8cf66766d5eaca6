//! `knitvox yls SCENE.toml -o FRAMES.h5`: a yarn-level scene.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::yls::YlsJob;
use crate::pipeline::Stage;

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
    let job = YlsJob {
        scene: a.scene.clone(),
        output: a.output.clone(),
    };
    let show = !a.no_progress && (a.progress || std::io::stderr().is_terminal());
    let mut console = super::Console::new(show, 0, "yarn-level");
    let result = job.run(&mut console);
    drop(console);
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
