//! `knitvox run JOB.toml`: a job manifest's stages, cached (schemas/job.md).

use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::job::{self, Job};
use crate::pipeline::submit::{self, SlurmOptions};

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Job manifest (TOML; schemas/job.md).
    pub job: PathBuf,
    /// Run this stage and the stages it needs (embed, train, fit, shot, export) [default: all].
    #[arg(long, value_name = "NAME")]
    pub stage: Option<String>,
    /// With --stage: only this task of the stage (0-based; `train` has one
    /// task per [[train]] pose), as a farm array task runs it.
    #[arg(long, value_name = "N", requires = "stage")]
    pub task: Option<usize>,
    /// Print one JSON line per computed frame and the report as the last line (errors as JSON too).
    #[arg(long)]
    pub json: bool,
    /// Submit the stages to a farm scheduler instead of running them here:
    /// one batch job per stage, chained by dependencies (schemas/job.md,
    /// "Farm submission").
    #[arg(long, value_name = "SCHEDULER", value_parser = ["slurm"], conflicts_with = "stage")]
    pub submit: Option<String>,
    /// Print the stages as farm jobs (scheduler-neutral; the Deadline and
    /// OpenCue submitters in pipelines/ read it with --json) and run nothing.
    #[arg(long, conflicts_with_all = ["submit", "stage"])]
    pub plan: bool,
    /// With --submit: write the batch scripts and print the submit commands, submit nothing.
    #[arg(long, requires = "submit")]
    pub dry_run: bool,
    /// With --submit slurm: an extra sbatch argument for every stage (repeatable:
    /// --sbatch-arg=--partition=sim --sbatch-arg=--time=2:00:00).
    #[arg(
        long,
        value_name = "ARG",
        allow_hyphen_values = true,
        requires = "submit"
    )]
    pub sbatch_arg: Vec<String>,
    /// With --submit: requeues of a stage after a transient failure (exit 75).
    #[arg(long, value_name = "N", default_value_t = SlurmOptions::default().max_retries)]
    pub max_retries: u32,
    /// The knitvox executable the farm's nodes run [default: this one].
    #[arg(long, value_name = "PATH")]
    pub knitvox: Option<PathBuf>,
    /// A folder the job may also read from (repeatable; absolute, or
    /// relative to the working folder). Without it every file the manifest
    /// and its scene name must resolve, symlinks followed, inside the
    /// manifest's folder.
    #[arg(long, value_name = "DIR")]
    pub allow_root: Vec<PathBuf>,
    /// A checkpoint in OUT/checkpoints/ that the shot stage cannot use (damaged, truncated, of
    /// another version or shot) is skipped with a warning instead of failing (exit 65): the shot
    /// then continues from an older checkpoint or starts from rest.
    #[arg(long, conflicts_with_all = ["submit", "plan"])]
    pub resume_or_restart: bool,
}

fn node_executable(a: &RunArgs) -> anyhow::Result<PathBuf> {
    match &a.knitvox {
        Some(p) => Ok(p.clone()),
        None => Ok(std::env::current_exe()?),
    }
}

/// `--plan` and `--submit`: the stages as farm jobs.
fn farm(a: &RunArgs, job: &Job) -> anyhow::Result<ExitCode> {
    let plan = submit::plan(job, &node_executable(a)?)?;
    if a.plan {
        if a.json {
            println!("{}", serde_json::to_string(&plan)?);
        } else {
            for s in &plan.stages {
                let after = if s.after.is_empty() {
                    String::new()
                } else {
                    format!(" (after {})", s.after.join(", "))
                };
                println!("{}{after}: {}", s.name, s.argv.join(" "));
            }
        }
        return Ok(ExitCode::Success);
    }
    let opts = SlurmOptions {
        max_retries: a.max_retries,
        extra_args: a.sbatch_arg.clone(),
        dry_run: a.dry_run,
        ..SlurmOptions::default()
    };
    let r = submit::submit_slurm(&plan, &opts)?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        for s in &r.stages {
            match &s.job_id {
                Some(id) => println!("{}: slurm job {id} ({})", s.stage, s.script.display()),
                None => println!("{}: {}", s.stage, s.command.join(" ")),
            }
        }
    }
    Ok(ExitCode::Success)
}

pub fn run(a: &RunArgs) -> anyhow::Result<ExitCode> {
    let mut job = Job::load_allowing(&a.job, &a.allow_root)?;
    if a.plan || a.submit.is_some() {
        return farm(a, &job);
    }
    job.interrupt = Some(super::console::relay_sigterm());
    job.resume_or_restart = a.resume_or_restart;
    let mut console =
        super::console::Console::with_mode(super::console::ProgressMode::of(a.json), 0, "run");
    let r = job::run_tasks(
        &job,
        a.stage.as_deref(),
        a.task,
        &super::asset::command_line(),
        &mut console,
    )?;
    if a.json {
        let warnings = std::mem::take(&mut console.warnings);
        super::console::print_json_report(&r, &[("warnings", warnings.into())])?;
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
