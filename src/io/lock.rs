//! An advisory lock on an output folder for one process at a time (`knitvox
//! run` on a job): an `O_EXCL` file naming the holder's host and pid, not
//! flock (unreliable over NFS; docs/design.md, pipeline conventions). A lock
//! whose holder is a dead process on this host is taken over (after
//! `kill -9`); a live holder, or one on another host (whose liveness cannot
//! be checked from here), makes the caller wait: [`IoError::Busy`], exit 75.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::IoError;

/// Who holds a lock (the lock file's content).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Holder {
    pub host: String,
    pub pid: u32,
}

/// A held lock; dropping it removes the file.
#[derive(Debug)]
pub struct Lock {
    path: PathBuf,
}

/// This machine's host name ("unknown" when the system will not say).
pub fn host_name() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most buf.len() bytes into buf.
    let rc = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    if rc != 0 {
        return "unknown".into();
    }
    let end = buf.iter().position(|b| *b == 0).unwrap_or(buf.len());
    String::from_utf8_lossy(&buf[..end]).into_owned()
}

/// Whether process `pid` of this host is alive (a zombie counts as dead).
fn alive(pid: u32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    let exists = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0
        || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
    exists
        && std::fs::read_to_string(format!("/proc/{pid}/stat")).map_or(true, |s| {
            s.rsplit(')')
                .next()
                .and_then(|r| r.split_whitespace().next())
                != Some("Z")
        })
}

/// The holder named by the lock file at `path` (None: no file, or not a
/// holder's JSON, e.g. half written).
fn read_holder(path: &Path) -> Option<Holder> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
}

impl Lock {
    /// Takes the lock at `path` (its folder must exist).
    pub fn acquire(path: &Path) -> Result<Lock, IoError> {
        let me = Holder {
            host: host_name(),
            pid: std::process::id(),
        };
        let write_err = |source| IoError::Write {
            path: path.to_path_buf(),
            source,
        };
        // Two tries: the second after removing a dead holder's file.
        for _ in 0..2 {
            match OpenOptions::new().write(true).create_new(true).open(path) {
                Ok(mut f) => {
                    let text = serde_json::to_string(&me).expect("a holder serializes");
                    f.write_all(text.as_bytes()).map_err(write_err)?;
                    return Ok(Lock {
                        path: path.to_path_buf(),
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
                Err(e) => return Err(write_err(e)),
            }
            match read_holder(path) {
                Some(h) if h.host == me.host && !alive(h.pid) => {
                    // Its holder was killed: nobody else is working here.
                    let _ = std::fs::remove_file(path);
                }
                Some(h) => {
                    return Err(IoError::Busy {
                        path: path.to_path_buf(),
                        message: format!(
                            "held by process {} on {}; retry when it is done (if that process is gone, remove the file)",
                            h.pid, h.host
                        ),
                    })
                }
                None => {
                    return Err(IoError::Busy {
                        path: path.to_path_buf(),
                        message: "being taken by another process; retry".into(),
                    })
                }
            }
        }
        Err(IoError::Busy {
            path: path.to_path_buf(),
            message: "taken by another process meanwhile; retry".into(),
        })
    }
}

/// Removes the lock file at `path` if its holder is a dead process of this
/// host: a run killed between finishing its work and dropping its lock
/// leaves the file behind, and a later run that finds the work done (so
/// takes no lock) would otherwise leave it there for good. A live holder,
/// one on another host or an unreadable file is left alone. Returns whether
/// a file was removed.
pub fn remove_if_orphaned(path: &Path) -> bool {
    match read_holder(path) {
        Some(h) if h.host == host_name() && !alive(h.pid) => std::fs::remove_file(path).is_ok(),
        _ => false,
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_taker_waits_and_a_dead_holder_is_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lock");
        let held = Lock::acquire(&p).unwrap();
        // Ourselves, alive: busy (exit 75).
        let e = Lock::acquire(&p).unwrap_err();
        assert!(matches!(e, IoError::Busy { .. }), "{e}");
        assert!(
            e.to_string().contains(&std::process::id().to_string()),
            "{e}"
        );
        drop(held);
        assert!(!p.exists());
        // A dead process of this host: taken over.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let text = serde_json::to_string(&Holder {
            host: host_name(),
            pid: dead,
        })
        .unwrap();
        std::fs::write(&p, text).unwrap();
        let taken = Lock::acquire(&p).unwrap();
        let h: Holder = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert_eq!(h.pid, std::process::id());
        drop(taken);
        // Another host: its liveness is unknown, so busy.
        let text = serde_json::to_string(&Holder {
            host: "elsewhere-host".into(),
            pid: dead,
        })
        .unwrap();
        std::fs::write(&p, text).unwrap();
        let e = Lock::acquire(&p).unwrap_err();
        assert!(e.to_string().contains("elsewhere-host"), "{e}");
    }

    #[test]
    fn only_a_dead_local_holders_file_is_swept() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lock");
        assert!(!remove_if_orphaned(&p), "no file");
        let held = Lock::acquire(&p).unwrap();
        assert!(!remove_if_orphaned(&p), "a live holder keeps its lock");
        assert!(p.exists());
        drop(held);
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        for (host, swept) in [("elsewhere-host".to_string(), false), (host_name(), true)] {
            let text = serde_json::to_string(&Holder { host, pid: dead }).unwrap();
            std::fs::write(&p, text).unwrap();
            assert_eq!(remove_if_orphaned(&p), swept);
            assert_eq!(p.exists(), !swept);
        }
        std::fs::write(&p, "not json").unwrap();
        assert!(!remove_if_orphaned(&p), "an unreadable lock is left alone");
    }
}
