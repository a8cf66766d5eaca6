//! `knitvox yls SCENE.toml -o FRAMES.h5`: a yarn-level scene.

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
    /// Print one JSON line per frame and the run's figures as the last line (errors as JSON too).
    #[arg(long)]
    pub json: bool,
    /// Show a progress bar (on by default when stderr is a terminal).
    #[arg(long, overrides_with = "no_progress")]
    pub progress: bool,
    /// Never show progress (without it and without a terminal: a plain line per frame on stderr).
    #[arg(long)]
    pub no_progress: bool,
}

pub fn yls(a: &YlsArgs) -> anyhow::Result<ExitCode> {
    let job = YlsJob {
        scene: a.scene.clone(),
        output: a.output.clone(),
    };
    use super::console::ProgressMode;
    let mode = if a.json {
        ProgressMode::Json
    } else {
        ProgressMode::on_stderr(a.progress, a.no_progress)
    };
    let mut console = super::console::Console::with_mode(mode, 0, "yarn-level");
    let result = job.run(&mut console);
    drop(console);
    let r = result?;
    if a.json {
        super::console::print_json_report(&r, &[])?;
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
