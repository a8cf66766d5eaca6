//! One job's life in `work/NAME/`: take the drop in, derive its manifest,
//! run it in a child process, file the drop under done/ or failed/.
//!
//! Every step can be interrupted by `kill -9` and redone by the daemon that
//! takes the claim over: the drop is recorded (`drop.json`) before it is
//! moved, the outcome (`result.json`) before the drop leaves work/, and the
//! child is `knitvox run`, whose stage records make a rerun skip the stages
//! that finished (schemas/job.md, "Caching").

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::scan::{Drop, DropKind};
use super::Paths;
use crate::io::IoError;
use crate::pipeline::job::Manifest;
use crate::pipeline::ErrorClass;

/// Why a job did not finish (the content of `failed/NAME.error.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Failure {
    pub job: String,
    #[serde(deserialize_with = "class_by_name")]
    pub class: ErrorClass,
    /// The exit code `knitvox run` gave (or would give) for the class.
    pub exit_code: u8,
    pub message: String,
    /// The file the error is about, as dropped (inbox-relative) where known.
    pub file: Option<String>,
    /// Where in the file (`line 3, column 7`) where the message says.
    pub place: Option<String>,
    /// Runs made (transient failures are retried).
    pub attempts: u32,
}

/// How a job ended (`work/NAME/result.json` while it is being filed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Outcome {
    Done { stages: Vec<StageLine> },
    Failed(Failure),
}

/// One stage of the child's report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageLine {
    pub name: String,
    pub status: String,
    pub ms: f64,
}

/// What one run of the child gave.
#[derive(Debug)]
pub enum RunResult {
    Done(Vec<StageLine>),
    Failed(Failure),
    /// Killed by a signal this daemon sent (stop, lost claim).
    Signalled,
}

/// An [`ErrorClass`] by its serialized name (`bad_input`).
fn class_by_name<'de, D: serde::Deserializer<'de>>(d: D) -> Result<ErrorClass, D::Error> {
    let name = String::deserialize(d)?;
    ErrorClass::ALL
        .into_iter()
        .find(|c| {
            serde_json::to_value(c)
                .ok()
                .and_then(|v| v.as_str().map(|s| s == name))
                == Some(true)
        })
        .ok_or_else(|| serde::de::Error::custom(format!("unknown error class '{name}'")))
}

/// The class of an exit code (the inverse of [`ErrorClass::exit_code`]).
pub fn class_of_exit_code(code: i32) -> Option<ErrorClass> {
    ErrorClass::ALL
        .into_iter()
        .find(|c| i32::from(c.exit_code()) == code)
}

pub(super) fn failure(
    job: &str,
    class: ErrorClass,
    message: String,
    file: Option<String>,
) -> Failure {
    Failure {
        job: job.into(),
        class,
        exit_code: class.exit_code(),
        place: place_of(&message),
        message,
        file,
        attempts: 0,
    }
}

/// `line N[, column M]` from a message, where it names one.
fn place_of(message: &str) -> Option<String> {
    let i = message.find("line ")?;
    let rest = &message[i + 5..];
    let digits = rest.chars().take_while(|c| c.is_ascii_digit()).count();
    if digits == 0 {
        return None;
    }
    let mut place = format!("line {}", &rest[..digits]);
    if let Some(col) = rest[digits..].strip_prefix(", column ") {
        let d = col.chars().take_while(|c| c.is_ascii_digit()).count();
        if d > 0 {
            place.push_str(&format!(", column {}", &col[..d]));
        }
    }
    Some(place)
}

fn read_err(path: &Path, source: std::io::Error) -> IoError {
    IoError::Read {
        path: path.to_path_buf(),
        source,
    }
}

fn write_err(path: &Path, source: std::io::Error) -> IoError {
    IoError::Write {
        path: path.to_path_buf(),
        source,
    }
}

fn write_json(path: &Path, v: &impl Serialize) -> Result<(), IoError> {
    let text = serde_json::to_string_pretty(v).map_err(|e| write_err(path, e.into()))?;
    crate::io::atomic::write_bytes(path, text.as_bytes())
}

/// Records the drop, then moves its entries from the inbox into
/// `work/NAME/input/` (entries already moved by a previous owner are kept).
pub fn take_in(paths: &Paths, dir: &Path, drop: &Drop) -> Result<(), IoError> {
    write_json(&dir.join("drop.json"), drop)?;
    let input = dir.join("input");
    std::fs::create_dir_all(&input).map_err(|e| write_err(&input, e))?;
    for e in drop.entries() {
        let (from, to) = (paths.inbox.join(&e), input.join(&e));
        match std::fs::rename(&from, &to) {
            Ok(()) => {}
            Err(err) if err.kind() == std::io::ErrorKind::NotFound && to.exists() => {}
            Err(err) => return Err(read_err(&from, err)),
        }
    }
    Ok(())
}

/// The drop recorded in a job folder (`None`: the daemon died before
/// recording it, so nothing left the inbox).
pub fn recorded_drop(dir: &Path) -> Option<Drop> {
    let text = std::fs::read_to_string(dir.join("drop.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// A manifest file's contents, with a bad-input failure naming the file
/// (as dropped) and the line.
fn parse_manifest(
    job: &str,
    path: &Path,
    shown: &str,
    yarns: Option<&str>,
) -> Result<Manifest, Failure> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        failure(
            job,
            ErrorClass::Missing,
            format!("{shown}: cannot read: {e}"),
            Some(shown.into()),
        )
    })?;
    let bad = |m: String| {
        failure(
            job,
            ErrorClass::BadInput,
            format!("{shown}: {m}"),
            Some(shown.into()),
        )
    };
    let Some(yarns) = yarns else {
        // Checked again by `knitvox run`; here so the error names the dropped file.
        return toml::from_str::<Manifest>(&text)
            .map_err(|e| bad(crate::pipeline::sim_scene::toml_error_line(&e, &text)));
    };
    // A sidecar: its yarn file is the drop's.
    let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
        bad(crate::pipeline::sim_scene::toml_error_line(&e, &text))
    })?;
    let garment = table
        .entry("garment")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let Some(garment) = garment.as_table_mut() else {
        return Err(bad("key 'garment' must be a table".into()));
    };
    garment.insert("yarns".into(), toml::Value::String(yarns.into()));
    toml::Value::Table(table)
        .try_into::<Manifest>()
        .map_err(|e| bad(e.message().trim().to_string()))
}

/// Writes `work/NAME/job.toml`: the drop's manifest (or the default job of
/// a bare yarn file) with its paths rebased onto `work/NAME/` and its
/// output set to `out/NAME/`. Paths are relative where the files moved
/// with the drop, so the child's provenance (and so its output bytes) does
/// not depend on where ROOT is.
pub fn derive_manifest(paths: &Paths, dir: &Path, drop: &Drop) -> Result<(), Failure> {
    let job = drop.name.as_str();
    let input = dir.join("input");
    // Top-level drops: relative paths mean the inbox, where they were dropped.
    let inbox = paths.inbox.clone();
    let from_inbox = move |p: &Path| {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            inbox.join(p)
        }
    };
    let mut m = match &drop.kind {
        DropKind::Yarns { file, sidecar } => {
            let mut m = match sidecar {
                Some(s) => parse_manifest(job, &input.join(s), s, Some(file))?,
                None => Manifest::for_yarns(file.into()),
            };
            m.map_paths(&from_inbox);
            m.garment.yarns = Path::new("input").join(file);
            m
        }
        DropKind::Manifest { file } => {
            let mut m = parse_manifest(job, &input.join(file), file, None)?;
            m.map_paths(&from_inbox);
            m
        }
        DropKind::Folder { dir: d } => {
            let folder = input.join(d);
            let name = manifest_in_folder(&folder).ok_or_else(|| {
                failure(
                    job,
                    ErrorClass::BadInput,
                    format!("{d}/: a job folder needs a job.toml (or one NAME.job.toml)"),
                    Some(format!("{d}/")),
                )
            })?;
            let shown = format!("{d}/{name}");
            let mut m = parse_manifest(job, &folder.join(&name), &shown, None)?;
            let base = Path::new("input").join(d);
            m.map_paths(|p| if p.is_absolute() { p.to_path_buf() } else { base.join(p) });
            m
        }
        DropKind::Unknown { file } | DropKind::Sidecar { file } => {
            return Err(failure(
                job,
                ErrorClass::BadInput,
                format!(
                    "{file}: not a job manifest (.toml), a job folder or a yarn file (bcc, obj, poly, pyp, gltf, glb, ply, h5)"
                ),
                Some(file.clone()),
            ))
        }
    };
    // Outputs always go to out/NAME (a dropped `output` key is replaced).
    m.output = Some(Path::new("../..").join("out").join(job));
    let text = m
        .to_toml()
        .map_err(|e| failure(job, ErrorClass::Internal, e.to_string(), None))?;
    let path = dir.join("job.toml");
    crate::io::atomic::write_bytes(&path, text.as_bytes())
        .map_err(|e| failure(job, ErrorClass::Output, e.to_string(), None))
}

fn manifest_in_folder(folder: &Path) -> Option<String> {
    if folder.join("job.toml").is_file() {
        return Some("job.toml".into());
    }
    let mut found: Vec<String> = std::fs::read_dir(folder)
        .ok()?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".job.toml"))
        .collect();
    (found.len() == 1).then(|| found.remove(0))
}

/// Starts `EXE run job.toml --json` in `dir`. The child gets SIGTERM when
/// the thread that started it dies (PR_SET_PDEATHSIG; workers live as long
/// as the daemon), so a killed daemon leaves nobody writing outputs; it has
/// its own process group, so a terminal's Ctrl-C reaches only the daemon,
/// which decides what the children get.
pub fn spawn(exe: &Path, dir: &Path) -> std::io::Result<std::process::Child> {
    let mut cmd = Command::new(exe);
    cmd.args(["run", "job.toml", "--json"])
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        let parent = std::process::id() as libc::pid_t;
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            cmd.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0
                    || libc::setpgid(0, 0) != 0
                {
                    return Err(std::io::Error::last_os_error());
                }
                // The daemon died before prctl: do not run orphaned.
                if libc::getppid() != parent {
                    return Err(std::io::Error::other("the daemon is gone"));
                }
                Ok(())
            });
        }
    }
    cmd.spawn()
}

/// Reads a finished child's result. `signalled`: this daemon sent it a
/// signal (a death by signal is then not the input's fault).
pub fn result_of(job: &str, out: &std::process::Output, signalled: bool) -> RunResult {
    use std::os::unix::process::ExitStatusExt;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Whatever a child this daemon signalled says (a checkpointing shot
    // exits 75), the job is interrupted, not failed.
    if signalled && !out.status.success() {
        return RunResult::Signalled;
    }
    if out.status.success() {
        // `run --json` prints a line per computed frame, the report last.
        let stages = stdout
            .lines()
            .rev()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .find_map(|v| serde_json::from_value::<Vec<StageLine>>(v["stages"].clone()).ok())
            .unwrap_or_default();
        return RunResult::Done(stages);
    }
    let class = out
        .status
        .code()
        .and_then(class_of_exit_code)
        .unwrap_or(ErrorClass::Internal);
    // `run --json` prints its error as a JSON object on stdout
    // (`{"event":"error","message","file",..}`; older: `{"error":{..}}`).
    let json = stdout
        .lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|v| v.get("error").is_some() || v["event"] == "error");
    let (mut message, mut file) = match &json {
        Some(v) => {
            let e = if v["event"] == "error" {
                v
            } else {
                &v["error"]
            };
            let msg = e
                .get("message")
                .and_then(|m| m.as_str())
                .or_else(|| e.as_str())
                .unwrap_or_default()
                .to_string();
            let file = e.get("file").and_then(|f| f.as_str()).map(String::from);
            (msg, file)
        }
        None => (String::new(), None),
    };
    if message.is_empty() {
        message = stderr
            .lines()
            .rev()
            .find(|l| l.starts_with("error: "))
            .or_else(|| stderr.lines().rev().find(|l| !l.trim().is_empty()))
            .map(|l| l.trim_start_matches("error: ").to_string())
            .unwrap_or_else(|| match out.status.signal() {
                Some(s) => format!("knitvox run died of signal {s}"),
                None => format!("knitvox run exited with {}", out.status),
            });
    }
    // Name files as dropped: strip the work folder's `input/`.
    message = message.replace("input/", "");
    if file.is_none() {
        file = message
            .split_once(": ")
            .map(|(f, _)| f.to_string())
            .filter(|f| !f.contains(' ') && f != "error");
    }
    let file = file.map(|f| f.trim_start_matches("input/").to_string());
    RunResult::Failed(failure(job, class, message, file))
}

/// Files the job's drop (everything in `work/NAME/input/`) under `dest`
/// (done/ or failed/), replacing an earlier drop of the same name.
pub fn file_away(dir: &Path, dest: &Path) -> Result<(), IoError> {
    let input = dir.join("input");
    let entries = match std::fs::read_dir(&input) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(read_err(&input, e)),
    };
    for e in entries {
        let e = e.map_err(|err| read_err(&input, err))?;
        let to = dest.join(e.file_name());
        if to.is_dir() {
            remove_tree(&to)?;
        }
        std::fs::rename(e.path(), &to).map_err(|err| write_err(&to, err))?;
    }
    Ok(())
}

/// Removes a folder: renamed to a hidden name first, so a half-removed
/// folder is never taken for a job.
pub fn remove_tree(dir: &Path) -> Result<(), IoError> {
    let name = dir.file_name().unwrap_or_default().to_string_lossy();
    let hidden = dir.with_file_name(format!(".{name}.removing.{}", std::process::id()));
    match std::fs::rename(dir, &hidden) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(write_err(dir, e)),
    }
    std::fs::remove_dir_all(&hidden).map_err(|e| write_err(&hidden, e))
}

/// Records the outcome, files the drop, removes `work/NAME/`.
pub fn finish(paths: &Paths, dir: &Path, job: &str, outcome: &Outcome) -> Result<(), IoError> {
    let result = dir.join("result.json");
    if !result.exists() {
        write_json(&result, outcome)?;
    }
    let dest = match outcome {
        Outcome::Done { .. } => &paths.done,
        Outcome::Failed(f) => {
            write_json(&paths.failed.join(format!("{job}.error.json")), f)?;
            &paths.failed
        }
    };
    file_away(dir, dest)?;
    if matches!(outcome, Outcome::Failed(_)) {
        // A job that failed before writing anything leaves no empty out/NAME.
        let _ = std::fs::remove_dir(paths.out.join(job));
    }
    remove_tree(dir)
}

/// The outcome recorded by a previous owner that died while filing.
pub fn recorded_outcome(dir: &Path) -> Option<Outcome> {
    let text = std::fs::read_to_string(dir.join("result.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// Waits `d`, waking early when `stop` says so.
pub fn sleep_unless(d: Duration, stop: impl Fn() -> bool) {
    let end = Instant::now() + d;
    while Instant::now() < end && !stop() {
        std::thread::sleep(Duration::from_millis(50).min(end - Instant::now()));
    }
}

/// The path of a job's folder.
pub fn job_dir(paths: &Paths, job: &str) -> PathBuf {
    paths.work.join(job)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_place_is_read_from_the_message() {
        assert_eq!(
            place_of("a.toml: line 4, column 1: unknown field").as_deref(),
            Some("line 4, column 1")
        );
        assert_eq!(
            place_of("a.bcc: line 12: bad count").as_deref(),
            Some("line 12")
        );
        assert_eq!(place_of("a.bcc: no such file"), None);
        assert_eq!(place_of("inline 3"), Some("line 3".into()));
    }

    #[test]
    fn exit_codes_map_back_to_classes() {
        for c in ErrorClass::ALL {
            assert_eq!(class_of_exit_code(i32::from(c.exit_code())), Some(c));
        }
        assert_eq!(class_of_exit_code(1), None);
    }

    fn output(code: i32, stdout: &str, stderr: &str) -> std::process::Output {
        use std::os::unix::process::ExitStatusExt;
        std::process::Output {
            status: std::process::ExitStatus::from_raw(code << 8),
            stdout: stdout.as_bytes().to_vec(),
            stderr: stderr.as_bytes().to_vec(),
        }
    }

    #[test]
    fn a_failed_child_gives_class_file_and_place() {
        let out = output(65, "", "error: input/a.bcc: line 3: expected a count\n");
        let RunResult::Failed(f) = result_of("a", &out, false) else {
            panic!("not a failure")
        };
        assert_eq!(f.class, ErrorClass::BadInput);
        assert_eq!(f.exit_code, 65);
        assert_eq!(f.message, "a.bcc: line 3: expected a count");
        assert_eq!(f.file.as_deref(), Some("a.bcc"));
        assert_eq!(f.place.as_deref(), Some("line 3"));
        // A JSON error on stdout wins over stderr: as `run --json` prints it
        // after its frame lines, and the older nested form.
        let json = concat!(
            r#"{"event":"frame","frame":1,"done":1,"total":2,"ms":2.0}"#,
            "\n",
            r#"{"event":"error","class":"transient","exit_code":75,"message":"input/c.h5: busy","file":"input/c.h5"}"#,
        );
        let RunResult::Failed(f) = result_of("c", &output(75, json, "noise"), false) else {
            panic!("not a failure")
        };
        assert_eq!(
            (f.message.as_str(), f.file.as_deref()),
            ("c.h5: busy", Some("c.h5"))
        );
        let json = r#"{"error":{"message":"input/b.ply: truncated","file":"input/b.ply"}}"#;
        let RunResult::Failed(f) = result_of("b", &output(75, json, "noise"), false) else {
            panic!("not a failure")
        };
        assert_eq!(f.class, ErrorClass::Transient);
        assert_eq!(
            (f.message.as_str(), f.file.as_deref()),
            ("b.ply: truncated", Some("b.ply"))
        );
        // A child this daemon signalled was interrupted, whatever it exits with.
        assert!(matches!(
            result_of("b", &output(75, "", ""), true),
            RunResult::Signalled
        ));
        let ok = output(
            0,
            concat!(
                r#"{"event":"frame","frame":1,"done":1,"total":1,"ms":2.0}"#,
                "\n",
                r#"{"event":"report","stages":[{"name":"embed","status":"ran","key":"k","outputs":[],"ms":5.0}],"ran":1}"#,
                "\n"
            ),
            "",
        );
        let RunResult::Done(s) = result_of("c", &ok, false) else {
            panic!("not done")
        };
        assert_eq!(
            s,
            vec![StageLine {
                name: "embed".into(),
                status: "ran".into(),
                ms: 5.0
            }]
        );
    }
}
