//! `knitvox watch ROOT --status`: the queue, the claims and the counts, read
//! from the folders alone (any host can ask; no daemon needs to run).

use std::path::Path;
use std::time::{Duration, SystemTime};

use serde::Serialize;

use super::claims;
use super::scan::{self, DropKind};
use super::Paths;
use crate::io::IoError;

/// A drop waiting in the inbox.
#[derive(Debug, Clone, Serialize)]
pub struct Queued {
    pub job: String,
    pub kind: DropKind,
    /// Seconds since the newest change to any of its files.
    pub age_s: f64,
    /// Unchanged for at least the settle time (a daemon takes it on its
    /// next two scans); `false`: still being written, or just arrived.
    pub stable: bool,
}

/// A job in work/.
#[derive(Debug, Clone, Serialize)]
pub struct Working {
    pub job: String,
    /// `running`, `stale` (no heartbeat: will be taken over), `released`
    /// (stopped on purpose: will be taken at once), `parked` (could not be
    /// filed away: `parked.json` says why) or `unclaimed`.
    pub state: &'static str,
    pub generation: Option<u64>,
    pub host: Option<String>,
    pub pid: Option<u32>,
    pub heartbeat_age_s: Option<f64>,
    /// The stage the child runs now (its `out/NAME/.knitvox/STAGE.lock`).
    pub stage: Option<String>,
    /// The child's last computed frame, and frames done of how many in
    /// this run (`work/NAME/progress.json`).
    pub frame: Option<i64>,
    pub frames_done: Option<u64>,
    pub frames_total: Option<u64>,
    /// Why a parked job could not be filed.
    pub parked: Option<String>,
}

/// The whole picture.
#[derive(Debug, Clone, Serialize)]
pub struct Status {
    pub inbox: Vec<Queued>,
    pub work: Vec<Working>,
    /// Jobs filed under done/ and failed/ (`NAME.error.json` files).
    pub done: usize,
    pub failed: usize,
}

fn newest_age(path: &Path) -> Option<Duration> {
    let sig = scan::signature(path)?;
    let newest = sig.values().map(|(_, t)| *t).max()?;
    Some(SystemTime::now().duration_since(newest).unwrap_or_default())
}

/// The stage whose lock is held in a job's output folder (the stage
/// `knitvox run` works on), if any.
fn running_stage(out: &Path) -> Option<String> {
    let records = out.join(".knitvox");
    let mut locks: Vec<String> = std::fs::read_dir(records)
        .ok()?
        .flatten()
        .filter_map(|e| {
            e.file_name()
                .to_str()?
                .strip_suffix(".lock")
                .map(String::from)
        })
        .collect();
    locks.sort();
    locks.into_iter().next()
}

fn read_list(dir: &Path) -> Result<Vec<(String, bool)>, IoError> {
    match scan::list(dir) {
        Ok(v) => Ok(v),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(source) => Err(IoError::Read {
            path: dir.to_path_buf(),
            source,
        }),
    }
}

/// Reads ROOT's state. `settle` and `stale_after` as the daemon uses them.
pub fn status(root: &Path, settle: Duration, stale_after: Duration) -> Result<Status, IoError> {
    if !root.is_dir() {
        return Err(IoError::Read {
            path: root.to_path_buf(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        });
    }
    let p = Paths::new(root);
    let entries = read_list(&p.inbox)?;
    let read = |n: &str| std::fs::read_to_string(p.inbox.join(n)).ok();
    let inbox = scan::classify(&entries, read)
        .into_iter()
        .map(|d| {
            let age = d
                .entries()
                .iter()
                .filter_map(|e| newest_age(&p.inbox.join(e)))
                .min()
                .unwrap_or_default();
            Queued {
                job: d.name,
                kind: d.kind,
                age_s: age.as_secs_f64(),
                stable: age >= settle,
            }
        })
        .collect();
    let mut work = Vec::new();
    for (name, is_dir) in read_list(&p.work)? {
        if !is_dir || scan::ignored(&name) {
            continue;
        }
        let cur = claims::current(&p.work.join(&name)).ok().flatten();
        let owner = cur.as_ref().and_then(|c| c.owner.clone());
        let dir = p.work.join(&name);
        let parked = std::fs::read_to_string(dir.join(super::worker::PARKED))
            .ok()
            .map(|t| {
                serde_json::from_str::<serde_json::Value>(&t)
                    .ok()
                    .and_then(|v| v["message"].as_str().map(String::from))
                    .unwrap_or_default()
            });
        let progress = std::fs::read_to_string(dir.join(super::worker::PROGRESS))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
        let stage = running_stage(&p.out.join(&name));
        let state = match &cur {
            _ if parked.is_some() => "parked",
            None => "unclaimed",
            Some(_) if owner.as_ref().is_some_and(|o| o.released) => "released",
            Some(c) if c.age > stale_after => "stale",
            Some(_) => "running",
        };
        work.push(Working {
            job: name,
            state,
            generation: cur.as_ref().map(|c| c.generation),
            host: owner.as_ref().map(|o| o.host.clone()),
            pid: owner.as_ref().map(|o| o.pid),
            heartbeat_age_s: cur.as_ref().map(|c| c.age.as_secs_f64()),
            stage,
            frame: progress.as_ref().and_then(|v| v["frame"].as_i64()),
            frames_done: progress.as_ref().and_then(|v| v["done"].as_u64()),
            frames_total: progress.as_ref().and_then(|v| v["total"].as_u64()),
            parked,
        });
    }
    let mut done_entries = read_list(&p.done)?;
    done_entries.retain(|(n, _)| !n.ends_with(".warnings.json"));
    let done = scan::classify(&done_entries, |n| {
        std::fs::read_to_string(p.done.join(n)).ok()
    })
    .len();
    let failed = read_list(&p.failed)?
        .iter()
        .filter(|(n, _)| n.ends_with(".error.json"))
        .count();
    Ok(Status {
        inbox,
        work,
        done,
        failed,
    })
}
