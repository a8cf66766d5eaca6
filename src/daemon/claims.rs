//! Claims on jobs in `work/`, shared by daemons on several hosts without
//! flock (unreliable over NFS; docs/design.md, pipeline conventions).
//!
//! A job being run lives in `work/NAME/`. Ownership is a sequence of claim
//! files `work/NAME/claim.G.json`, each created with `O_EXCL` (atomic on
//! local filesystems and NFSv3+): the highest generation G is the owner.
//! The owner refreshes its file's mtime every heartbeat. Taking over a
//! stale or released claim means creating generation G+1, which only one
//! daemon can do; an owner that sees a newer generation has lost the job
//! and stops working on it. Nothing is ever renamed over another daemon's
//! claim, so two racing takeovers cannot both win.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use serde::{Deserialize, Serialize};

/// Who holds a claim (the content of `claim.G.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Owner {
    pub host: String,
    pub pid: u32,
    /// When the owning daemon started (Unix seconds).
    pub started: f64,
    /// When this claim was made (Unix seconds).
    pub claimed: f64,
    pub generation: u64,
    /// Set when the owner let go on purpose (SIGTERM): anyone may take it at once.
    #[serde(default)]
    pub released: bool,
}

/// The current claim of a job folder.
#[derive(Debug, Clone)]
pub struct Current {
    pub generation: u64,
    /// `None` when the file could not be read (being written right now).
    pub owner: Option<Owner>,
    /// Time since the last heartbeat (the file's mtime).
    pub age: Duration,
}

impl Current {
    /// Whether another daemon may take the job over.
    pub fn takeable(&self, stale_after: Duration) -> bool {
        self.age > stale_after || self.owner.as_ref().is_some_and(|o| o.released)
    }
}

/// A claim this daemon holds.
#[derive(Debug, Clone)]
pub struct Claim {
    pub dir: PathBuf,
    pub owner: Owner,
    file: PathBuf,
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// This machine's host name.
pub use crate::io::lock::host_name;

fn claim_file(dir: &Path, generation: u64) -> PathBuf {
    dir.join(format!("claim.{generation}.json"))
}

fn age_of(mtime: SystemTime) -> Duration {
    SystemTime::now().duration_since(mtime).unwrap_or_default()
}

/// The highest claim generation in `dir` and its file, if any.
fn latest(dir: &Path) -> std::io::Result<Option<(u64, PathBuf)>> {
    let mut best: Option<u64> = None;
    for e in std::fs::read_dir(dir)? {
        let name = e?.file_name();
        let g = name.to_str().and_then(|n| {
            n.strip_prefix("claim.")?
                .strip_suffix(".json")?
                .parse()
                .ok()
        });
        if let Some(g) = g {
            best = Some(best.map_or(g, |b: u64| b.max(g)));
        }
    }
    Ok(best.map(|g| (g, claim_file(dir, g))))
}

/// The current claim of a job folder; `None` when it has none (a daemon
/// died between creating the folder and its first claim).
pub fn current(dir: &Path) -> std::io::Result<Option<Current>> {
    let Some((generation, file)) = latest(dir)? else {
        return Ok(None);
    };
    let meta = match std::fs::metadata(&file) {
        Ok(m) => m,
        // Removed while we looked (the job finished): no claim.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    let owner = std::fs::read_to_string(&file)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    Ok(Some(Current {
        generation,
        owner,
        age: age_of(meta.modified()?),
    }))
}

/// Creates claim file `generation` in `dir` with `O_EXCL`; `None` when
/// another daemon made it first.
fn create(dir: &Path, mut owner: Owner, generation: u64) -> std::io::Result<Option<Claim>> {
    let file = claim_file(dir, generation);
    owner.generation = generation;
    owner.claimed = unix_now();
    owner.released = false;
    let mut f = match OpenOptions::new().write(true).create_new(true).open(&file) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Ok(None),
        Err(e) => return Err(e),
    };
    f.write_all(serde_json::to_string(&owner)?.as_bytes())?;
    f.sync_all()?;
    Ok(Some(Claim {
        dir: dir.to_path_buf(),
        owner,
        file,
    }))
}

/// Claims a new job: creates `work/NAME/` (mkdir, atomic) and generation 0.
/// `None` when the folder exists (another daemon has the job, or a job of
/// that name is still in work/).
pub fn claim_new(work: &Path, name: &str, owner: &Owner) -> std::io::Result<Option<Claim>> {
    let dir = work.join(name);
    match std::fs::create_dir(&dir) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Ok(None),
        Err(e) => return Err(e),
    }
    create(&dir, owner.clone(), 0)
}

/// Takes over the job in `dir` when its claim is stale (no heartbeat for
/// longer than `stale_after`) or released, or when it has none and the
/// folder is older than `stale_after`. Returns the new claim and the
/// previous one.
pub fn take_over(
    dir: &Path,
    owner: &Owner,
    stale_after: Duration,
) -> std::io::Result<Option<(Claim, Option<Current>)>> {
    let cur = current(dir)?;
    let next = match &cur {
        Some(c) if !c.takeable(stale_after) => return Ok(None),
        Some(c) => c.generation + 1,
        None => {
            let age = age_of(std::fs::metadata(dir)?.modified()?);
            if age <= stale_after {
                return Ok(None);
            }
            0
        }
    };
    Ok(create(dir, owner.clone(), next)?.map(|c| (c, cur)))
}

impl Claim {
    /// Refreshes the heartbeat. `Ok(false)` when the claim was lost (a
    /// newer generation exists, or the job folder is gone): stop working.
    pub fn heartbeat(&self) -> std::io::Result<bool> {
        match latest(&self.dir) {
            Ok(Some((g, _))) if g == self.owner.generation => {}
            Ok(_) => return Ok(false),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(e) => return Err(e),
        }
        let f = File::options().write(true).open(&self.file)?;
        f.set_modified(SystemTime::now())?;
        Ok(true)
    }

    /// Whether this daemon still owns the job.
    pub fn held(&self) -> bool {
        matches!(latest(&self.dir), Ok(Some((g, _))) if g == self.owner.generation)
    }

    /// Lets go on purpose (SIGTERM): marks the claim released so another
    /// daemon, or this one restarted, takes the job at once.
    pub fn release(&self) -> std::io::Result<()> {
        let mut o = self.owner.clone();
        o.released = true;
        crate::io::atomic::write_bytes(&self.file, serde_json::to_string(&o)?.as_bytes())
            .map_err(std::io::Error::other)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn owner(pid: u32) -> Owner {
        Owner {
            host: "h".into(),
            pid,
            started: 0.0,
            claimed: 0.0,
            generation: 0,
            released: false,
        }
    }

    fn backdate(file: &Path, secs: u64) {
        let f = File::options().write(true).open(file).unwrap();
        f.set_modified(SystemTime::now() - Duration::from_secs(secs))
            .unwrap();
    }

    #[test]
    fn only_one_daemon_claims_a_new_job() {
        let dir = tempfile::tempdir().unwrap();
        let a = claim_new(dir.path(), "j", &owner(1)).unwrap().unwrap();
        assert!(claim_new(dir.path(), "j", &owner(2)).unwrap().is_none());
        assert!(a.heartbeat().unwrap());
        let c = current(&a.dir).unwrap().unwrap();
        assert_eq!((c.generation, c.owner.unwrap().pid), (0, 1));
    }

    #[test]
    fn a_stale_claim_is_taken_over_once_and_its_owner_learns_it() {
        let dir = tempfile::tempdir().unwrap();
        let a = claim_new(dir.path(), "j", &owner(1)).unwrap().unwrap();
        let stale = Duration::from_secs(10);
        // Fresh: nobody takes it.
        assert!(take_over(&a.dir, &owner(2), stale).unwrap().is_none());
        backdate(&claim_file(&a.dir, 0), 60);
        let (b, prev) = take_over(&a.dir, &owner(2), stale).unwrap().unwrap();
        assert_eq!(b.owner.generation, 1);
        assert_eq!(prev.unwrap().owner.unwrap().pid, 1);
        // A second racer sees the new, fresh generation.
        assert!(take_over(&a.dir, &owner(3), stale).unwrap().is_none());
        // The old owner wakes up: lost.
        assert!(!a.heartbeat().unwrap());
        assert!(!a.held());
        assert!(b.heartbeat().unwrap());
    }

    #[test]
    fn a_released_claim_is_taken_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let a = claim_new(dir.path(), "j", &owner(1)).unwrap().unwrap();
        a.release().unwrap();
        let (b, _) = take_over(&a.dir, &owner(2), Duration::from_secs(3600))
            .unwrap()
            .unwrap();
        assert_eq!(b.owner.generation, 1);
    }

    #[test]
    fn a_folder_without_claim_is_taken_only_when_old() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("j");
        std::fs::create_dir(&d).unwrap();
        let stale = Duration::from_secs(10);
        assert!(take_over(&d, &owner(2), stale).unwrap().is_none());
        let f = File::open(&d).unwrap();
        f.set_modified(SystemTime::now() - Duration::from_secs(60))
            .unwrap();
        let (b, prev) = take_over(&d, &owner(2), stale).unwrap().unwrap();
        assert!(prev.is_none());
        assert_eq!(b.owner.generation, 0);
    }
}
