//! `knitvox run JOB.toml`: a job manifest's stages, cached (schemas/job.md).

use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::job::{self, Job};
use crate::pipeline::Quiet;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Job manifest (TOML; schemas/job.md).
    pub job: PathBuf,
    /// Run this stage and the stages it needs (embed, shot, export) [default: all].
    #[arg(long, value_name = "NAME")]
    pub stage: Option<String>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: &RunArgs) -> anyhow::Result<ExitCode> {
    let job = Job::load(&a.job)?;
    let r = job::run(
        &job,
        a.stage.as_deref(),
        &super::asset::command_line(),
        &mut Quiet,
    )?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(ExitCode::Success);
    }
    for s in &r.stages {
        if s.status == "cached" {
            println!("{}: cached (key {}..)", s.name, &s.key[..8]);
        } else {
            println!("{}: ran in {:.0} ms", s.name, s.ms);
        }
    }
    if r.ran == 0 {
        println!(
            "nothing to do: every stage is cached in {}",
            job.output.display()
        );
    }
    Ok(ExitCode::Success)
}
