//! `knitvox run JOB.toml`: a job manifest's stages, cached (schemas/job.md).

use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::job::{self, Job};

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Job manifest (TOML; schemas/job.md).
    pub job: PathBuf,
    /// Run this stage and the stages it needs (embed, shot, export) [default: all].
    #[arg(long, value_name = "NAME")]
    pub stage: Option<String>,
    /// Print one JSON line per computed frame and the report as the last line (errors as JSON too).
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: &RunArgs) -> anyhow::Result<ExitCode> {
    let job = Job::load(&a.job)?;
    let r = job::run(
        &job,
        a.stage.as_deref(),
        &super::asset::command_line(),
        &mut super::Console::with_mode(super::ProgressMode::of(a.json), 0, "run"),
    )?;
    if a.json {
        super::print_json_report(&r, &[])?;
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
