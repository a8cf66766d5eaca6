//! One job's life in `work/NAME/`: take the drop in, derive its manifest,
//! run it in a child process, file the drop under done/ or failed/.
//!
//! Every step can be interrupted by `kill -9` and redone by the daemon that
//! takes the claim over: the drop is recorded (`drop.json`) before it is
//! moved, the outcome (`result.json`) before the drop leaves work/, and the
//! child is `knitvox run`, whose stage records make a rerun skip the stages
//! that finished (schemas/job.md, "Caching").

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use serde::{Deserialize, Serialize};

use super::scan::{Drop, DropKind, Signature};
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
    /// The run's warnings (`warning: ...` lines of the child).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// How a job ended (`work/NAME/result.json` while it is being filed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Outcome {
    Done {
        stages: Vec<StageLine>,
        /// The run's warnings (kept as `done/NAME.warnings.json`).
        #[serde(default)]
        warnings: Vec<String>,
    },
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
    Done(Vec<StageLine>, Vec<String>),
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
        warnings: Vec::new(),
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
/// `Ok(false)`: none of the drop is in the inbox or in `input/` (another
/// daemon took it under another name first): nothing to run.
pub fn take_in(paths: &Paths, dir: &Path, drop: &Drop) -> Result<bool, IoError> {
    let input = dir.join("input");
    let here = |e: &String| {
        std::fs::symlink_metadata(paths.inbox.join(e)).is_ok()
            || std::fs::symlink_metadata(input.join(e)).is_ok()
    };
    if !drop.entries().iter().any(here) {
        return Ok(false);
    }
    write_json(&dir.join("drop.json"), drop)?;
    std::fs::create_dir_all(&input).map_err(|e| write_err(&input, e))?;
    for e in drop.entries() {
        let (from, to) = (paths.inbox.join(&e), input.join(&e));
        match std::fs::rename(&from, &to) {
            Ok(()) => {}
            Err(err)
                if err.kind() == std::io::ErrorKind::NotFound
                    && std::fs::symlink_metadata(&to).is_ok() => {}
            Err(err) => return Err(read_err(&from, err)),
        }
    }
    Ok(true)
}

/// Refuses a drop that is a symlink, or a folder drop holding a symlink
/// that leads outside it, before anything of it is read: a bad-input
/// failure naming the entry.
pub fn check_links(paths: &Paths, dir: &Path, drop: &Drop) -> Result<(), Failure> {
    let input = dir.join("input");
    for e in drop.entries() {
        let mut base = &paths.inbox;
        if std::fs::symlink_metadata(base.join(&e)).is_err() {
            base = &input; // moved in already by a previous owner
        }
        let path = base.join(&e);
        if let Some(link) = super::scan::link_outside(&path) {
            let shown = link
                .strip_prefix(base)
                .unwrap_or(&link)
                .display()
                .to_string();
            let what = if link == path {
                "the drop is a symlink"
            } else {
                "a symlink in the drop leads outside it"
            };
            return Err(failure(
                &drop.name,
                ErrorClass::BadInput,
                format!("{shown}: refusing: {what}; drop files, not links to them"),
                Some(shown),
            ));
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

/// The input paths a manifest names, with their keys.
fn named_paths(m: &Manifest) -> Vec<(&'static str, PathBuf)> {
    let mut v = vec![("garment.yarns", m.garment.yarns.clone())];
    if let Some(s) = m.shot.as_ref().and_then(|s| s.scene.clone()) {
        v.push(("shot.scene", s));
    }
    if let Some(c) = &m.character {
        v.push(("character.file", c.file.clone()));
    }
    v
}

/// What a job's child may read besides its own folder.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Reads {
    /// A path of a top-level manifest or sidecar names a file in the inbox.
    pub inbox: bool,
}

/// Writes `work/NAME/job.toml`: the drop's manifest (or the default job of
/// a bare yarn file) with its paths rebased onto `work/NAME/` and its
/// output set to `out/NAME/`. Paths are relative where the files moved
/// with the drop, so the child's provenance (and so its output bytes) does
/// not depend on where ROOT is.
///
/// Every input path the manifest names must resolve (symlinks followed)
/// inside the job's folder, the inbox for a top-level manifest or sidecar
/// (whose relative paths mean the inbox), or one of `allow` (the
/// operator's `--allow-root`s); else the job fails as bad input naming the
/// dropped file, the key and the path as written, and nothing is read.
pub fn derive_manifest(
    paths: &Paths,
    dir: &Path,
    drop: &Drop,
    allow: &[PathBuf],
) -> Result<Reads, Failure> {
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
    // (the file shown in errors, the paths as written, whether relative paths mean the inbox)
    let shown: String;
    let written: Vec<(&'static str, PathBuf)>;
    let mut top_level = true;
    let mut m = match &drop.kind {
        DropKind::Yarns { file, sidecar } => {
            let mut m = match sidecar {
                Some(s) => parse_manifest(job, &input.join(s), s, Some(file))?,
                None => Manifest::for_yarns(file.into()),
            };
            shown = sidecar.clone().unwrap_or_else(|| file.clone());
            written = named_paths(&m);
            m.map_paths(&from_inbox);
            m.garment.yarns = Path::new("input").join(file);
            m
        }
        DropKind::Manifest { file } => {
            let mut m = parse_manifest(job, &input.join(file), file, None)?;
            shown = file.clone();
            written = named_paths(&m);
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
            shown = format!("{d}/{name}");
            let mut m = parse_manifest(job, &folder.join(&name), &shown, None)?;
            written = named_paths(&m);
            top_level = false;
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
    let mut roots = vec![dir.to_path_buf()];
    if top_level {
        roots.push(paths.inbox.clone());
    }
    roots.extend(allow.iter().cloned());
    let canon = |p: &Path| std::fs::canonicalize(p).ok();
    let own_dir = canon(dir);
    let allowed: Vec<PathBuf> = allow.iter().filter_map(|p| canon(p)).collect();
    let mut reads = Reads::default();
    for ((key, path), (_, as_written)) in named_paths(&m).into_iter().zip(written) {
        let full = if path.is_absolute() {
            path
        } else {
            dir.join(path)
        };
        let refuse = |class, e: &dyn std::fmt::Display| {
            failure(
                job,
                class,
                format!("{shown}: {key} = \"{}\": {e}", as_written.display()),
                Some(shown.clone()),
            )
        };
        match crate::io::confined::resolve_inside(&full, &roots) {
            Ok(r) => {
                // Neither in the job's folder nor an allowed root: in the inbox.
                let in_dir = own_dir.as_ref().is_some_and(|d| r.starts_with(d));
                if !in_dir && !allowed.iter().any(|a| r.starts_with(a)) {
                    reads.inbox = true;
                }
            }
            Err(e @ crate::io::confined::ConfinedError::OutsideRoots { .. }) => {
                return Err(refuse(ErrorClass::BadInput, &e))
            }
            Err(e) => return Err(refuse(ErrorClass::Missing, &e)),
        }
    }
    // Outputs always go to out/NAME (a dropped `output` key is replaced).
    m.output = Some(Path::new("../..").join("out").join(job));
    let text = m
        .to_toml()
        .map_err(|e| failure(job, ErrorClass::Internal, e.to_string(), None))?;
    let path = dir.join("job.toml");
    crate::io::atomic::write_bytes(&path, text.as_bytes())
        .map_err(|e| failure(job, ErrorClass::Output, e.to_string(), None))?;
    Ok(reads)
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
pub fn spawn(
    exe: &Path,
    dir: &Path,
    extra: &[std::ffi::OsString],
) -> std::io::Result<std::process::Child> {
    let mut cmd = Command::new(exe);
    cmd.args(["run", "job.toml", "--json"])
        .args(extra)
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
    let warnings = warnings_of(&stdout, &stderr);
    if out.status.success() {
        // `run --json` prints a line per computed frame, the report last.
        let stages = stdout
            .lines()
            .rev()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .find_map(|v| serde_json::from_value::<Vec<StageLine>>(v["stages"].clone()).ok())
            .unwrap_or_default();
        return RunResult::Done(stages, warnings);
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
    let mut f = failure(job, class, message, file);
    f.warnings = warnings;
    RunResult::Failed(f)
}

/// The child's warnings: its `warning: ...` stderr lines, and the
/// `warnings` of its JSON report where it carries them (each once, in
/// order), with the work folder's `input/` stripped from file names.
fn warnings_of(stdout: &str, stderr: &str) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    let report = stdout
        .lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|v| v["event"] == "report");
    let from_report = report
        .as_ref()
        .and_then(|r| r["warnings"].as_array().cloned())
        .unwrap_or_default();
    let lines = stderr.lines().filter_map(|l| l.strip_prefix("warning: "));
    for w in from_report
        .iter()
        .filter_map(|w| w.as_str())
        .chain(lines)
        .map(|w| w.trim().replace("input/", ""))
    {
        // Kept short and few: a record must not grow with a hostile input.
        let w = crate::geom::cap_message(&w, crate::geom::MAX_MESSAGE_BYTES).into_owned();
        if v.len() == MAX_WARNINGS {
            v.push("further warnings left out".into());
            break;
        }
        if !w.is_empty() && !v.contains(&w) {
            v.push(w);
        }
    }
    v
}

/// The most warnings a job's record keeps.
const MAX_WARNINGS: usize = 100;

/// The name an entry of job `job` is filed under with suffix `n`: itself
/// for 0, else `.N` after the job name (`coll.1`, `dup.1.bcc`,
/// `dup.1.job.toml`, `dup.1.error.json`), or at the end for an entry that
/// does not start with it.
pub fn filed_name(entry: &str, job: &str, n: u32) -> String {
    if n == 0 {
        return entry.to_string();
    }
    if entry == job {
        return format!("{job}.{n}");
    }
    match entry.strip_prefix(job).and_then(|r| r.strip_prefix('.')) {
        Some(rest) => format!("{job}.{n}.{rest}"),
        None => format!("{entry}.{n}"),
    }
}

/// The smallest suffix under which none of `names` (nor the job's error
/// and warnings files) exists in `dest`: filing never replaces anything.
fn free_suffix(dest: &Path, job: &str, names: &[String]) -> u32 {
    let records = [format!("{job}.error.json"), format!("{job}.warnings.json")];
    let taken = |n: u32| {
        names
            .iter()
            .chain(records.iter())
            .any(|e| std::fs::symlink_metadata(dest.join(filed_name(e, job, n))).is_ok())
    };
    (0..u32::MAX).find(|&n| !taken(n)).unwrap_or(u32::MAX)
}

/// Files the job's drop (everything in `work/NAME/input/`) under `dest`
/// (done/ or failed/) with suffix `n`.
pub fn file_away(dir: &Path, dest: &Path, job: &str, n: u32) -> Result<(), IoError> {
    let input = dir.join("input");
    let entries = match std::fs::read_dir(&input) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(read_err(&input, e)),
    };
    for e in entries {
        let e = e.map_err(|err| read_err(&input, err))?;
        let name = e.file_name().to_string_lossy().into_owned();
        let to = dest.join(filed_name(&name, job, n));
        if std::fs::symlink_metadata(&to).is_ok() {
            // Taken since the suffix was chosen: never replaced.
            return Err(write_err(
                &to,
                std::io::Error::from(std::io::ErrorKind::AlreadyExists),
            ));
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

/// Records the outcome, files the drop (under a suffixed name where its
/// names are taken, [`filed_name`]), removes `work/NAME/`. Returns the
/// suffix (0: none).
pub fn finish(paths: &Paths, dir: &Path, job: &str, outcome: &Outcome) -> Result<u32, IoError> {
    let result = dir.join("result.json");
    if !result.exists() {
        write_json(&result, outcome)?;
    }
    let (dest, warnings) = match outcome {
        Outcome::Done { warnings, .. } => (&paths.done, warnings),
        Outcome::Failed(f) => (&paths.failed, &f.warnings),
    };
    // The suffix is recorded before anything moves, so a new owner that
    // finishes the filing uses the same one.
    let filing = dir.join("filing.json");
    let n = match std::fs::read_to_string(&filing)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v["suffix"].as_u64())
    {
        Some(n) => n as u32,
        None => {
            let input = dir.join("input");
            let names: Vec<String> = std::fs::read_dir(&input)
                .map(|r| {
                    r.flatten()
                        .map(|e| e.file_name().to_string_lossy().into_owned())
                        .collect()
                })
                .unwrap_or_default();
            let n = free_suffix(dest, job, &names);
            write_json(&filing, &serde_json::json!({ "suffix": n }))?;
            n
        }
    };
    if let Outcome::Failed(f) = outcome {
        // A second guard: whatever the child said, a record stays short.
        let cap =
            |s: &str| crate::geom::cap_message(s, crate::geom::MAX_MESSAGE_BYTES).into_owned();
        let mut f = f.clone();
        f.message = cap(&f.message);
        f.file = f.file.as_deref().map(cap);
        f.place = f.place.as_deref().map(cap);
        write_json(
            &dest.join(filed_name(&format!("{job}.error.json"), job, n)),
            &f,
        )?;
    }
    if !warnings.is_empty() {
        let w = serde_json::json!({ "job": job, "warnings": warnings });
        write_json(
            &dest.join(filed_name(&format!("{job}.warnings.json"), job, n)),
            &w,
        )?;
    }
    file_away(dir, dest, job, n)?;
    if matches!(outcome, Outcome::Failed(_)) {
        // A job that failed before writing anything leaves no empty out/NAME.
        let _ = std::fs::remove_dir(paths.out.join(job));
    }
    remove_tree(dir)?;
    Ok(n)
}

/// The outcome recorded by a previous owner that died while filing.
pub fn recorded_outcome(dir: &Path) -> Option<Outcome> {
    let text = std::fs::read_to_string(dir.join("result.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// `work/NAME/parked.json`: a job that could not be filed away (removing
/// the file lets a daemon take it again).
pub const PARKED: &str = "parked.json";

/// `work/NAME/progress.json`: the running child's last frame.
pub const PROGRESS: &str = "progress.json";

/// Records why a job is parked.
pub fn park(dir: &Path, job: &str, message: &str) -> Result<(), IoError> {
    let v = serde_json::json!({ "job": job, "message": message, "t": super::claims::unix_now() });
    write_json(&dir.join(PARKED), &v)
}

/// Reads the child's stdout to its end (returned), writing each `frame`
/// event to `progress` as it comes (for `--status`).
pub fn read_progress(out: impl std::io::Read, progress: &Path, attempt: u32) -> Vec<u8> {
    use std::io::BufRead;
    let mut all = Vec::new();
    let mut r = std::io::BufReader::new(out);
    let mut line = Vec::new();
    while matches!(r.read_until(b'\n', &mut line), Ok(n) if n > 0) {
        if let Ok(v) = serde_json::from_slice::<serde_json::Value>(&line) {
            if v["event"] == "frame" {
                let p = serde_json::json!({
                    "attempt": attempt,
                    "frame": v["frame"],
                    "done": v["done"],
                    "total": v["total"],
                    "t": super::claims::unix_now(),
                });
                let _ = write_json(progress, &p);
            }
        }
        all.append(&mut line);
    }
    all
}

/// The signatures of a job's entries in `work/NAME/input/`.
fn input_signature(dir: &Path, drop: &Drop) -> BTreeMap<String, Signature> {
    let input = dir.join("input");
    drop.entries()
        .into_iter()
        .filter_map(|e| {
            let mut s = super::scan::signature(&input.join(&e))?;
            // A moved folder's own mtime may change with the move.
            if input.join(&e).is_dir() {
                s.remove(Path::new(""));
            }
            Some((e, s))
        })
        .collect()
}

fn without_folder_times(
    mut sig: BTreeMap<String, Signature>,
    dir: &Path,
) -> BTreeMap<String, Signature> {
    for (e, s) in sig.iter_mut() {
        if dir.join("input").join(e).is_dir() {
            s.remove(Path::new(""));
        }
    }
    sig
}

fn newest_age(sig: &BTreeMap<String, Signature>) -> Duration {
    let newest = sig.values().flat_map(|s| s.values().map(|(_, t)| *t)).max();
    newest.map_or(Duration::MAX, |t| {
        SystemTime::now().duration_since(t).unwrap_or_default()
    })
}

/// Whether a job's files changed since they were claimed (`claimed`),
/// changed less than `settle` ago, or change within the next `settle`
/// (watched unless `stop`): a parse failure may then be a copy still
/// under way.
pub fn still_changing(
    dir: &Path,
    drop: &Drop,
    claimed: Option<&BTreeMap<String, Signature>>,
    settle: Duration,
    stop: impl Fn() -> bool,
) -> bool {
    let now = input_signature(dir, drop);
    let changed = claimed.is_some_and(|c| without_folder_times(c.clone(), dir) != now);
    if changed || newest_age(&now) < settle {
        return true;
    }
    // A copy pausing between writes: the next write comes soon.
    let end = Instant::now() + settle;
    while Instant::now() < end && !stop() {
        sleep_unless(Duration::from_millis(100).min(settle), &stop);
        if input_signature(dir, drop) != now {
            return true;
        }
    }
    false
}

/// Waits until a job's files held still for `settle` (looking at least
/// every 100 ms; at most 10 minutes, or until `stop`); their signature.
pub fn wait_still(
    dir: &Path,
    drop: &Drop,
    settle: Duration,
    stop: impl Fn() -> bool,
) -> BTreeMap<String, Signature> {
    let end = Instant::now() + Duration::from_secs(600);
    let step = settle.clamp(Duration::from_millis(100), Duration::from_secs(5));
    let mut last = input_signature(dir, drop);
    let mut since = Instant::now();
    while Instant::now() < end && !stop() {
        sleep_unless(step, &stop);
        let now = input_signature(dir, drop);
        if now != last {
            (last, since) = (now, Instant::now());
        } else if since.elapsed() >= settle && newest_age(&now) >= settle {
            break;
        }
    }
    last
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
    fn filed_names_put_the_suffix_after_the_job_name() {
        assert_eq!(filed_name("coll", "coll", 0), "coll");
        assert_eq!(filed_name("coll", "coll", 1), "coll.1");
        assert_eq!(filed_name("dup.bcc", "dup", 2), "dup.2.bcc");
        assert_eq!(filed_name("dup.job.toml", "dup", 1), "dup.1.job.toml");
        assert_eq!(filed_name("dup.error.json", "dup", 1), "dup.1.error.json");
        assert_eq!(filed_name("dup.obj", "dup.obj", 1), "dup.obj.1");
        assert_eq!(filed_name("other", "dup", 1), "other.1");
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("a.bcc"), b"").unwrap();
        assert_eq!(free_suffix(d.path(), "a", &["a.bcc".into()]), 1);
        std::fs::write(d.path().join("a.1.error.json"), b"").unwrap();
        assert_eq!(free_suffix(d.path(), "a", &["a.bcc".into()]), 2);
        assert_eq!(free_suffix(d.path(), "b", &["b.bcc".into()]), 0);
    }

    /// An absolute yarns path of a top-level manifest: refused outside the
    /// job's folder and the inbox, unless an allowed root holds it; an
    /// inbox file is read with the inbox allowed.
    #[test]
    fn manifest_paths_must_lie_in_the_job_the_inbox_or_an_allowed_root() {
        let d = tempfile::tempdir().unwrap();
        let paths = Paths::new(&d.path().join("root"));
        paths.create().unwrap();
        let outside = d.path().join("outside");
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(outside.join("x.bcc"), b"never read").unwrap();
        std::fs::write(paths.inbox.join("y.bcc"), b"").unwrap();
        let job = |name: &str, text: &str| {
            let dir = paths.work.join(name);
            std::fs::create_dir_all(dir.join("input")).unwrap();
            let file = format!("{name}.toml");
            std::fs::write(dir.join("input").join(&file), text).unwrap();
            let drop = Drop {
                name: name.into(),
                kind: DropKind::Manifest { file },
            };
            (dir, drop)
        };
        let abs = format!(
            "[garment]\nyarns = \"{}\"\n",
            outside.join("x.bcc").display()
        );
        let (dir, drop) = job("abs", &abs);
        let f = derive_manifest(&paths, &dir, &drop, &[]).unwrap_err();
        assert_eq!(f.class, ErrorClass::BadInput);
        assert_eq!(f.file.as_deref(), Some("abs.toml"));
        assert!(f.message.contains("garment.yarns"), "{}", f.message);
        assert!(!f.message.contains("never read"), "{}", f.message);
        assert!(!dir.join("job.toml").exists());
        let reads = derive_manifest(&paths, &dir, &drop, &[outside.clone()]).unwrap();
        assert_eq!(reads, Reads { inbox: false });
        assert!(dir.join("job.toml").is_file());
        let (dir, drop) = job("inb", "[garment]\nyarns = \"y.bcc\"\n");
        let reads = derive_manifest(&paths, &dir, &drop, &[]).unwrap();
        assert_eq!(reads, Reads { inbox: true });
        let (dir, drop) = job("gone", "[garment]\nyarns = \"nothere.bcc\"\n");
        let f = derive_manifest(&paths, &dir, &drop, &[]).unwrap_err();
        assert_eq!(f.class, ErrorClass::Missing, "{}", f.message);
    }

    /// A sidecar's `[garment]` read options reach the job the child runs
    /// (the yarn file set to the drop's).
    #[test]
    fn a_sidecars_read_options_reach_the_job() {
        let d = tempfile::tempdir().unwrap();
        let paths = Paths::new(&d.path().join("root"));
        paths.create().unwrap();
        let dir = paths.work.join("glove");
        std::fs::create_dir_all(dir.join("input")).unwrap();
        std::fs::write(dir.join("input/glove.bcc"), b"").unwrap();
        std::fs::write(
            dir.join("input/glove.job.toml"),
            "[garment]\nunits = \"cm\"\nradius = 0.00025\ntile = [1, 1]\n",
        )
        .unwrap();
        let drop = Drop {
            name: "glove".into(),
            kind: DropKind::Yarns {
                file: "glove.bcc".into(),
                sidecar: Some("glove.job.toml".into()),
            },
        };
        derive_manifest(&paths, &dir, &drop, &[]).unwrap();
        let job = crate::pipeline::job::Job::load(&dir.join("job.toml")).unwrap();
        let g = &job.manifest.garment;
        assert_eq!(g.yarns, Path::new("input/glove.bcc"));
        assert_eq!(g.units.as_deref(), Some("cm"));
        assert_eq!(g.radius, Some(0.00025));
        assert_eq!(g.tile, Some(crate::pipeline::job::Tile::Pair(vec![1, 1])));
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
        let RunResult::Done(s, _) = result_of("c", &ok, false) else {
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
