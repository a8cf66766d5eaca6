//! Farm submission of a job manifest's stages (`knitvox run JOB --submit`).
//!
//! A job's stages become one farm job each, chained by dependencies, each
//! running `knitvox run JOB --stage NAME` on a node: the stage's upstream
//! stages are then cached (their records in `OUT/.knitvox`), so a node only
//! verifies their keys and runs its own stage. [`Plan`] is the scheduler-
//! neutral description (`knitvox run JOB --plan --json` prints it for the
//! Deadline and OpenCue submitters in `pipelines/`); [`submit_slurm`]
//! submits it to Slurm with `sbatch`.
//!
//! Exit classes (`pipeline::ErrorClass`) decide what a failed stage does on
//! the farm, through the batch script ([`slurm_script`]):
//! * `Retry::Later` (exit 75, transient): the job requeues itself, up to
//!   `max_retries` times (Slurm delays a requeued job by about two minutes).
//! * `Retry::AfterFix` (66 missing input, 74 output) and `Retry::Elsewhere`
//!   (69, e.g. no GPU on the node): the job requeues itself *held*; its
//!   dependents wait until a person fixes the cause (or moves the job to
//!   another partition) and releases it (`scontrol release JOBID`).
//! * `Retry::No` (2, 65, 70): the job fails and its dependents are
//!   cancelled (`--kill-on-invalid-dep=yes`).

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::Serialize;

use super::error::{ErrorClass, Retry};
use super::job::Job;
use super::Error;

/// One farm job of a plan: a stage of the manifest.
#[derive(Debug, Clone, Serialize)]
pub struct PlanStage {
    /// The stage's name (`embed`, `shot`, `export`).
    pub name: String,
    /// Stages that must finish successfully first.
    pub after: Vec<String>,
    /// Independent tasks of the stage (an array job); 1 for a single task.
    pub tasks: usize,
    /// The command a node runs (absolute paths).
    pub argv: Vec<String>,
}

/// A job's stages as farm jobs, scheduler-neutral.
#[derive(Debug, Clone, Serialize)]
pub struct Plan {
    /// The manifest (absolute).
    pub job: PathBuf,
    /// A short name for the farm (the manifest's stem).
    pub name: String,
    /// The job's output folder (absolute); scripts and logs go under
    /// `OUT/.knitvox/submit/`.
    pub output: PathBuf,
    /// The stages in run order.
    pub stages: Vec<PlanStage>,
}

/// Errors of planning or submitting.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    /// The scheduler's command is not installed here.
    #[error("cannot run '{program}': {source} (is the scheduler's client installed and on PATH?)")]
    NoScheduler {
        program: String,
        source: std::io::Error,
    },
    /// The scheduler refused the submission.
    #[error("'{program}' refused stage '{stage}' (exit {code}): {stderr}")]
    Refused {
        program: String,
        stage: String,
        code: i32,
        stderr: String,
    },
    /// The scheduler answered something that is not a job id.
    #[error("'{program}' answered '{answer}' for stage '{stage}', not a job id")]
    Answer {
        program: String,
        stage: String,
        answer: String,
    },
    /// A path cannot be made absolute.
    #[error("{path}: {source}")]
    Path {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A name that would go into a farm script holds a control character
    /// (or is not UTF-8): it could start a new shell line or directive.
    #[error(
        "{what} {value} holds a control character or is not UTF-8 (farm scripts \
         take names without bytes below 0x20, 0x7f or invalid UTF-8; see \
         docs/guides/jobs-and-farm.md)"
    )]
    UnsafeName {
        /// What the value is: `the manifest's 'output' key in JOB`, ...
        what: String,
        /// The value, escaped and capped.
        value: String,
        /// Bad input for what a file says, usage for a command-line flag.
        class: ErrorClass,
    },
    /// Slurm drops every backslash of an `--output` path (and its
    /// patterns with it), so a log under this folder cannot be named.
    #[error(
        "the 'output' key of {job} names the folder {value}, which holds a backslash: \
         Slurm's --output cannot name a log file there; name the folder without one"
    )]
    SlurmBackslash { job: PathBuf, value: String },
}

impl SubmitError {
    /// No client is `Unavailable` (run elsewhere); a refusal or a strange
    /// answer is `Transient` (a controller restarting), a path `Missing`.
    pub fn class(&self) -> ErrorClass {
        match self {
            SubmitError::NoScheduler { .. } => ErrorClass::Unavailable,
            SubmitError::Refused { .. } | SubmitError::Answer { .. } => ErrorClass::Transient,
            SubmitError::Path { .. } => ErrorClass::Missing,
            SubmitError::UnsafeName { class, .. } => *class,
            SubmitError::SlurmBackslash { .. } => ErrorClass::BadInput,
        }
    }
}

fn absolute(p: &Path) -> Result<PathBuf, SubmitError> {
    p.canonicalize().map_err(|source| SubmitError::Path {
        path: p.to_path_buf(),
        source,
    })
}

/// Longest escaped value an [`SubmitError::UnsafeName`] shows (characters).
const MAX_SHOWN: usize = 120;

/// `s` as a Rust string literal (control bytes escaped), capped.
fn escaped(s: &str) -> String {
    let quoted = format!("{s:?}");
    if quoted.chars().count() <= MAX_SHOWN {
        return quoted;
    }
    let mut cut: String = quoted.chars().take(MAX_SHOWN).collect();
    cut.push_str("…");
    cut
}

/// A control byte: one a shell or a `#SBATCH` line reads as a line break,
/// a carriage return that hides what follows, or a terminal escape.
fn is_control(c: char) -> bool {
    (c as u32) < 0x20 || c == '\u{7f}'
}

/// `p` as UTF-8 without control bytes, or the error naming `what`.
fn safe_text(p: &Path, what: &str, class: ErrorClass) -> Result<String, SubmitError> {
    let refuse = |value: String| SubmitError::UnsafeName {
        what: what.to_string(),
        value,
        class,
    };
    let Some(s) = p.to_str() else {
        return Err(refuse(escaped(&p.to_string_lossy())));
    };
    if s.chars().any(is_control) {
        return Err(refuse(escaped(s)));
    }
    Ok(s.to_string())
}

/// The farm's job name from a manifest stem: `[A-Za-z0-9._-]` only (a
/// scheduler's name field and a `#SBATCH` line take it verbatim), other
/// characters as `_`, never empty.
fn job_name(stem: &str) -> String {
    let name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        "job".into()
    } else {
        name
    }
}

/// Checks every text a farm script or submitter gets from `plan`: the
/// manifest's path, its `output` key, the executable and the stage names
/// (one place, applied when the plan is built).
fn check_plan(plan: &Plan, job: &Job) -> Result<(), SubmitError> {
    let manifest = job.path.display();
    safe_text(&plan.job, "the job manifest's path", ErrorClass::BadInput)?;
    safe_text(
        &plan.output,
        &format!("the 'output' key of {manifest} (the job's output folder)"),
        ErrorClass::BadInput,
    )?;
    for stage in &plan.stages {
        safe_text(Path::new(&stage.name), "a stage name", ErrorClass::Internal)?;
        if let Some(exe) = stage.argv.first() {
            safe_text(
                Path::new(exe),
                "the knitvox executable (--knitvox)",
                ErrorClass::Usage,
            )?;
        }
    }
    Ok(())
}

/// The plan of `job`: one farm job per stage, each after the one before,
/// running `knitvox` at `exe` (a path valid on the farm's nodes). Refused
/// ([`SubmitError::UnsafeName`]) when a path or name it would pass to a
/// farm script holds a control byte or is not UTF-8.
pub fn plan(job: &Job, exe: &Path) -> Result<Plan, Error> {
    // The name as given first: canonicalizing it must not be what reveals it.
    safe_text(&job.path, "the job manifest's path", ErrorClass::BadInput)?;
    safe_text(
        &job.output,
        &format!(
            "the 'output' key of {} (the job's output folder)",
            job.path.display()
        ),
        ErrorClass::BadInput,
    )?;
    let manifest = absolute(&job.path).map_err(Error::from)?;
    // The output folder may not exist yet: make its parent absolute.
    let output = if job.output.is_absolute() {
        job.output.clone()
    } else {
        std::env::current_dir()
            .map_err(|source| SubmitError::Path {
                path: job.output.clone(),
                source,
            })?
            .join(&job.output)
    };
    let name = job_name(
        &manifest
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    );
    let mut stages: Vec<PlanStage> = Vec::new();
    for s in job.stages() {
        let after = stages
            .last()
            .map(|p| vec![p.name.clone()])
            .unwrap_or_default();
        stages.push(PlanStage {
            name: s.to_string(),
            after,
            tasks: job.tasks(s),
            argv: [
                exe.display().to_string(),
                "run".into(),
                manifest.display().to_string(),
                "--stage".into(),
                s.to_string(),
                "--json".into(),
            ]
            .into_iter()
            // A node reads from the same folders as this run.
            .chain(
                job.allowed_roots()
                    .iter()
                    .flat_map(|r| ["--allow-root".to_string(), r.display().to_string()]),
            )
            .collect(),
        });
    }
    let plan = Plan {
        job: manifest,
        name,
        output,
        stages,
    };
    check_plan(&plan, job)?;
    Ok(plan)
}

/// How to submit to Slurm.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// The `sbatch` program [default `sbatch` from PATH].
    pub sbatch: PathBuf,
    /// Requeues of a stage after transient failures (exit 75) [default 3].
    pub max_retries: u32,
    /// Extra `sbatch` arguments for every stage (`--partition=sim`,
    /// `--account=show`, `--time=2:00:00`, ...).
    pub extra_args: Vec<String>,
    /// Write the scripts and print the commands, submit nothing.
    pub dry_run: bool,
}

impl Default for SlurmOptions {
    fn default() -> Self {
        SlurmOptions {
            sbatch: PathBuf::from("sbatch"),
            max_retries: 3,
            extra_args: Vec::new(),
            dry_run: false,
        }
    }
}

/// One submitted stage.
#[derive(Debug, Clone, Serialize)]
pub struct Submitted {
    pub stage: String,
    /// The scheduler's job id (`None` on a dry run).
    pub job_id: Option<String>,
    /// The batch script written for the stage.
    pub script: PathBuf,
    /// The `sbatch` command line (script last).
    pub command: Vec<String>,
}

/// What a submission did.
#[derive(Debug, Clone, Serialize)]
pub struct SubmitReport {
    pub scheduler: &'static str,
    pub job: PathBuf,
    pub dry_run: bool,
    pub stages: Vec<Submitted>,
}

/// Shell single-quoting (a path with spaces or quotes stays one word; the
/// plan holds no control byte, so no value spans lines).
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// `s` with every control byte as `?`: for a comment line of a script.
fn one_line(s: &str) -> String {
    s.chars()
        .map(|c| if is_control(c) { '?' } else { c })
        .collect()
}

/// A `#SBATCH` value: sbatch splits a directive at white space and ends it
/// at an unquoted `#`, and honours double quotes and backslashes (not the
/// shell's rules), so the value goes in double quotes with `\` and `"`
/// escaped. [`plan`] refuses control bytes; one in a plan built by hand
/// becomes `?` (`#SBATCH` values cannot hold a line break).
fn sbatch_value(s: &str) -> String {
    let mut out = String::from("\"");
    for c in one_line(s).chars() {
        if matches!(c, '\\' | '"') {
            out.push('\\');
        }
        out.push(c);
    }
    out.push('"');
    out
}

/// The folder of a plan's scripts and logs.
pub fn submit_dir(plan: &Plan, scheduler: &str) -> PathBuf {
    plan.output.join(".knitvox").join("submit").join(scheduler)
}

/// The class policy as a shell `case` over the stage's exit code (see the
/// module comment); generated from [`ErrorClass::retry`] so the scripts
/// follow the one table.
fn exit_policy(max_retries: u32, requeue_id: &str) -> String {
    let codes = |r: Retry| {
        ErrorClass::ALL
            .iter()
            .filter(|c| c.retry() == r)
            .map(|c| c.exit_code().to_string())
            .collect::<Vec<_>>()
            .join("|")
    };
    let hold = format!("{}|{}", codes(Retry::AfterFix), codes(Retry::Elsewhere));
    format!(
        r#"case "$rc" in
  0) ;;
  {later})
    if [ "${{SLURM_RESTART_COUNT:-0}}" -lt {max_retries} ]; then
      echo "knitvox: transient failure (exit $rc): requeueing (restart ${{SLURM_RESTART_COUNT:-0}} of {max_retries})" >&2
      scontrol requeue "{requeue_id}"
      sleep 600  # the requeue ends this script
    fi ;;
  {hold})
    echo "knitvox: exit $rc needs a fix (missing input, output folder, or a node that can run it): holding {requeue_id}; fix, then 'scontrol release {requeue_id}'" >&2
    scontrol requeuehold "{requeue_id}"
    sleep 600 ;;
  *)
    echo "knitvox: exit $rc: not retryable; dependent stages are cancelled" >&2 ;;
esac"#,
        later = codes(Retry::Later),
    )
}

/// The batch script of one stage.
pub fn slurm_script(plan: &Plan, stage: &PlanStage, opts: &SlurmOptions) -> String {
    // `%` in the folder is literal (`%%`); the file name's `%A`, `%a`, `%j`
    // are Slurm's patterns.
    let dir = submit_dir(plan, "slurm")
        .display()
        .to_string()
        .replace('%', "%%");
    let (log, requeue_id) = if stage.tasks > 1 {
        (
            format!("{dir}/{}-%A_%a.log", stage.name),
            "${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}",
        )
    } else {
        (format!("{dir}/{}-%j.log", stage.name), "$SLURM_JOB_ID")
    };
    let command = stage
        .argv
        .iter()
        .map(|a| quote(a))
        .collect::<Vec<_>>()
        .join(" ");
    let task = if stage.tasks > 1 {
        " --task \"$SLURM_ARRAY_TASK_ID\""
    } else {
        ""
    };
    format!(
        "#!/bin/bash\n\
         # knitvox {version}: stage '{stage}' of {job}\n\
         # Exit classes and what they do here: schemas/job.md, \"Farm submission\".\n\
         #SBATCH --job-name={name}\n\
         #SBATCH --output={log}\n\
         #SBATCH --open-mode=append\n\
         #SBATCH --requeue\n\
         #SBATCH --chdir={chdir}\n\
         {command}{task}\n\
         rc=$?\n\
         {policy}\n\
         exit \"$rc\"\n",
        version = env!("CARGO_PKG_VERSION"),
        stage = one_line(&stage.name),
        job = one_line(&plan.job.display().to_string()),
        name = sbatch_value(&format!("{}:{}", job_name(&plan.name), stage.name)),
        log = sbatch_value(&log),
        chdir = sbatch_value(
            &plan
                .job
                .parent()
                .unwrap_or(Path::new("/"))
                .display()
                .to_string()
        ),
        policy = exit_policy(opts.max_retries, requeue_id),
    )
}

/// Writes every stage's script and submits them in order with `sbatch
/// --parsable`, each `--dependency=afterok:` its upstream jobs.
pub fn submit_slurm(plan: &Plan, opts: &SlurmOptions) -> Result<SubmitReport, Error> {
    let dir = submit_dir(plan, "slurm");
    if dir.to_string_lossy().contains('\\') {
        return Err(SubmitError::SlurmBackslash {
            job: plan.job.clone(),
            value: escaped(&plan.output.to_string_lossy()),
        }
        .into());
    }
    std::fs::create_dir_all(&dir).map_err(|source| crate::io::IoError::Write {
        path: dir.clone(),
        source,
    })?;
    let mut out: Vec<Submitted> = Vec::new();
    for stage in &plan.stages {
        let script = dir.join(format!("{}.sbatch", stage.name));
        crate::io::atomic::write_bytes(&script, slurm_script(plan, stage, opts).as_bytes())?;
        let mut args: Vec<String> = vec!["--parsable".into(), "--kill-on-invalid-dep=yes".into()];
        // A dry run names the upstream stage where its id would be.
        let deps: Vec<String> = stage
            .after
            .iter()
            .filter_map(|a| out.iter().find(|s| &s.stage == a))
            .map(|s| s.job_id.clone().unwrap_or_else(|| format!("<{}>", s.stage)))
            .collect();
        if !deps.is_empty() {
            args.push(format!("--dependency=afterok:{}", deps.join(":")));
        }
        if stage.tasks > 1 {
            args.push(format!("--array=0-{}", stage.tasks - 1));
        }
        args.extend(opts.extra_args.iter().cloned());
        args.push(script.display().to_string());
        let mut command = vec![opts.sbatch.display().to_string()];
        command.extend(args.iter().cloned());
        let job_id = if opts.dry_run {
            None
        } else {
            Some(sbatch(&opts.sbatch, &args, &stage.name)?)
        };
        out.push(Submitted {
            stage: stage.name.clone(),
            job_id,
            script,
            command,
        });
    }
    Ok(SubmitReport {
        scheduler: "slurm",
        job: plan.job.clone(),
        dry_run: opts.dry_run,
        stages: out,
    })
}

/// Runs `sbatch --parsable ...` and returns the job id it prints
/// (`ID` or `ID;CLUSTER`).
fn sbatch(program: &Path, args: &[String], stage: &str) -> Result<String, SubmitError> {
    let name = program.display().to_string();
    let o = Command::new(program)
        .args(args)
        .output()
        .map_err(|source| SubmitError::NoScheduler {
            program: name.clone(),
            source,
        })?;
    if !o.status.success() {
        return Err(SubmitError::Refused {
            program: name,
            stage: stage.into(),
            code: o.status.code().unwrap_or(-1),
            stderr: String::from_utf8_lossy(&o.stderr).trim().to_string(),
        });
    }
    let answer = String::from_utf8_lossy(&o.stdout).trim().to_string();
    let id = answer.split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        return Err(SubmitError::Answer {
            program: name,
            stage: stage.into(),
            answer: crate::geom::excerpt(&answer).to_string(),
        });
    }
    Ok(id)
}

impl crate::pipeline::error::StageFailure for SubmitError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        SubmitError::class(self)
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<SubmitError> for crate::pipeline::Error {
    fn from(e: SubmitError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_stage_plan() -> Plan {
        let stage = |name: &str, after: &[&str], tasks| PlanStage {
            name: name.into(),
            after: after.iter().map(|s| s.to_string()).collect(),
            tasks,
            argv: vec![
                "/opt/knit vox".into(),
                "run".into(),
                "/jobs/it's.toml".into(),
            ],
        };
        Plan {
            job: "/jobs/it's.toml".into(),
            name: "its".into(),
            output: "/jobs/out".into(),
            stages: vec![stage("embed", &[], 1), stage("train", &["embed"], 4)],
        }
    }

    #[test]
    fn scripts_quote_paths_and_follow_the_exit_classes() {
        let p = two_stage_plan();
        let s = slurm_script(&p, &p.stages[0], &SlurmOptions::default());
        assert!(
            s.contains(r#"'/opt/knit vox' 'run' '/jobs/it'\''s.toml'"#),
            "{s}"
        );
        assert!(s.contains("  75)\n"), "{s}");
        assert!(s.contains("scontrol requeue \"$SLURM_JOB_ID\""), "{s}");
        assert!(s.contains("  66|74|69)\n"), "{s}");
        assert!(s.contains("-lt 3 ]"), "{s}");
        assert!(
            s.contains("#SBATCH --output=\"/jobs/out/.knitvox/submit/slurm/embed-%j.log\"\n"),
            "{s}"
        );
        assert!(s.contains("#SBATCH --job-name=\"its:embed\"\n"), "{s}");
        assert!(s.contains("#SBATCH --chdir=\"/jobs\"\n"), "{s}");
        let a = slurm_script(&p, &p.stages[1], &SlurmOptions::default());
        assert!(a.contains("--task \"$SLURM_ARRAY_TASK_ID\""), "{a}");
        assert!(a.contains("train-%A_%a.log"), "{a}");
        assert!(
            a.contains("${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}"),
            "{a}"
        );
    }

    #[test]
    fn sbatch_values_stay_one_argument_and_job_names_are_plain() {
        assert_eq!(sbatch_value(r#"/a b/#c"d\e"#), r#""/a b/#c\"d\\e""#);
        assert_eq!(sbatch_value("a\nb\rc\u{7f}"), "\"a?b?c?\"");
        assert_eq!(job_name("shot 01 $(id)`x`'\"\n"), "shot_01___id__x____");
        assert_eq!(job_name(""), "job");
        assert_eq!(job_name("a.b_c-D9"), "a.b_c-D9");
        let mut p = two_stage_plan();
        p.output = "/jobs/50%/out".into();
        let s = slurm_script(&p, &p.stages[0], &SlurmOptions::default());
        assert!(
            s.contains("/jobs/50%%/out/.knitvox/submit/slurm/embed-%j.log"),
            "{s}"
        );
    }

    #[test]
    fn escaped_values_are_one_line_and_capped() {
        assert_eq!(escaped("o\ntouch X"), r#""o\ntouch X""#);
        let long = escaped(&"\n".repeat(500));
        assert!(
            long.chars().count() <= MAX_SHOWN + 1 && !long.contains('\n'),
            "{long}"
        );
    }

    #[test]
    fn a_missing_sbatch_is_unavailable_and_a_bad_answer_transient() {
        let e = sbatch(Path::new("/nonexistent/sbatch"), &[], "embed").unwrap_err();
        assert_eq!(e.class(), ErrorClass::Unavailable);
        let e = sbatch(Path::new("echo"), &["not-an-id".into()], "embed").unwrap_err();
        assert!(matches!(e, SubmitError::Answer { .. }), "{e}");
        assert_eq!(e.class(), ErrorClass::Transient);
        assert_eq!(
            sbatch(Path::new("echo"), &["42;farm".into()], "embed").unwrap(),
            "42"
        );
        let e = sbatch(Path::new("false"), &[], "shot").unwrap_err();
        assert!(e.to_string().contains("stage 'shot'"), "{e}");
    }
}
