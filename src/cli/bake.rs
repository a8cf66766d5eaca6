//! `knitvox bake`: a glTF character's animation as an HDF5 character cache.

use std::path::PathBuf;

use clap::Args;

use super::exit::ExitCode;
use crate::pipeline::bake::BakeJob;
use crate::pipeline::{Quiet, Stage};

#[derive(Debug, Args)]
pub struct BakeArgs {
    /// The character (glTF/GLB with a skin and animations).
    pub character: PathBuf,
    /// Animation to bake [default: the file's first].
    #[arg(long)]
    pub animation: Option<String>,
    /// Samples per second.
    #[arg(long, default_value_t = 24.0)]
    pub fps: f64,
    /// The cache to write (.h5; schemas/character-hdf5.md).
    #[arg(short, long, value_name = "CHAR.h5")]
    pub output: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn bake(a: &BakeArgs) -> anyhow::Result<ExitCode> {
    let job = BakeJob {
        character: a.character.clone(),
        animation: a.animation.clone(),
        fps: a.fps,
        output: a.output.clone(),
    };
    let r = job.run(&mut Quiet)?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        println!(
            "baked {} ({}): {} frames over {:.3} s, {} vertices, {} triangles -> {}",
            a.character.display(),
            r.animation.as_deref().unwrap_or("bind pose"),
            r.frames,
            r.duration_s,
            r.vertices,
            r.triangles,
            r.output.display()
        );
    }
    Ok(ExitCode::Success)
}
