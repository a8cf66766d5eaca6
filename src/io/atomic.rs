//! Atomic file output: write to a dot-prefixed temporary file in the target's
//! directory, fsync it, rename it over the target, fsync the directory. A
//! reader (or a crash) never sees a half-written file.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicPtr, Ordering};

use super::IoError;

/// Temporary files in flight, for [`remove_temporaries_on_signal`]: a fixed
/// table of leaked C strings so the signal handler needs no allocation or
/// lock (async-signal-safe: atomic loads and `unlink`).
const MAX_TEMPS: usize = 64;
static TEMPS: [AtomicPtr<libc::c_char>; MAX_TEMPS] =
    [const { AtomicPtr::new(std::ptr::null_mut()) }; MAX_TEMPS];

/// A temporary path registered for removal on SIGINT/SIGTERM; unregistered
/// (and its C string freed) when dropped.
pub struct TempGuard(Option<usize>);

impl TempGuard {
    /// Registers `path` (best effort: a full table or a path with a NUL byte
    /// is simply not registered).
    pub fn register(path: &Path) -> TempGuard {
        #[cfg(unix)]
        {
            use std::os::unix::ffi::OsStrExt;
            let Ok(c) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
                return TempGuard(None);
            };
            let raw = c.into_raw();
            for (i, slot) in TEMPS.iter().enumerate() {
                if slot
                    .compare_exchange(
                        std::ptr::null_mut(),
                        raw,
                        Ordering::AcqRel,
                        Ordering::Acquire,
                    )
                    .is_ok()
                {
                    return TempGuard(Some(i));
                }
            }
            // SAFETY: `raw` came from CString::into_raw above and was not stored.
            drop(unsafe { std::ffi::CString::from_raw(raw) });
        }
        TempGuard(None)
    }
}

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(i) = self.0 {
            let raw = TEMPS[i].swap(std::ptr::null_mut(), Ordering::AcqRel);
            if !raw.is_null() {
                // SAFETY: only TempGuard::register stores pointers, from CString::into_raw.
                drop(unsafe { std::ffi::CString::from_raw(raw) });
            }
        }
    }
}

/// Signal handler body for SIGINT/SIGTERM: removes every registered
/// temporary file, then re-raises the signal with its default action (so
/// the exit status still says "killed by signal"). Installed by the binary.
/// Async-signal-safe: atomic loads, `unlink`, `signal`, `raise`.
#[cfg(unix)]
pub extern "C" fn remove_temporaries_on_signal(sig: libc::c_int) {
    for slot in &TEMPS {
        let p = slot.load(Ordering::Acquire);
        if !p.is_null() {
            // SAFETY: p is a NUL-terminated string from CString::into_raw.
            unsafe { libc::unlink(p) };
        }
    }
    // SAFETY: resetting to the default action and re-raising is the usual
    // way to end with the signal's status; both are async-signal-safe.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
        libc::raise(sig);
    }
}

fn write_err(path: &Path, source: std::io::Error) -> IoError {
    IoError::Write {
        path: path.to_path_buf(),
        source,
    }
}

fn dir_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_with(path, |tmp| {
        let mut f = File::create(tmp)?;
        f.write_all(bytes)?;
        f.flush()
    })
}

/// Lets `produce` write a complete file at a temporary path (dot-prefixed,
/// same directory), then fsyncs and renames it onto `path`. On failure the
/// temporary file is removed and `path` is untouched. Used directly by
/// writers that need a path of their own (libhdf5).
pub fn write_with(
    path: &Path,
    produce: impl FnOnce(&Path) -> std::io::Result<()>,
) -> Result<(), IoError> {
    let dir = dir_of(path);
    let name = path.file_name().ok_or_else(|| {
        write_err(
            path,
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "output path has no file name",
            ),
        )
    })?;
    // tempfile picks a unique name and removes it if we bail out early.
    let mut builder = tempfile::Builder::new();
    // Outputs are for other users too (renderers, farm accounts): the mode a plain
    // File::create gives (0o666 less the umask), not tempfile's private 0o600.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let tmp = builder
        .prefix(&format!(".{}.", name.to_string_lossy()))
        .suffix(".tmp")
        .tempfile_in(&dir)
        .map_err(|e| write_err(path, e))?;
    let tmp_path = tmp.path().to_path_buf();
    let _registered = TempGuard::register(&tmp_path);
    produce(&tmp_path).map_err(|e| write_err(path, e))?;
    File::open(&tmp_path)
        .and_then(|f| f.sync_all())
        .map_err(|e| write_err(path, e))?;
    tmp.persist(path).map_err(|e| write_err(path, e.error))?;
    // fsync the directory so the rename itself is durable.
    if let Ok(d) = File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_without_leftovers() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.bin");
        write_bytes(&p, b"first").unwrap();
        write_bytes(&p, b"second").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "temporary files left behind: {names:?}");
    }

    #[cfg(unix)]
    #[test]
    fn outputs_get_the_usual_file_mode() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let reference = dir.path().join("plain");
        File::create(&reference).unwrap();
        let p = dir.path().join("atomic");
        write_bytes(&p, b"x").unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&p), mode(&reference));
    }

    #[test]
    fn failed_producer_leaves_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("keep.bin");
        write_bytes(&p, b"keep").unwrap();
        let r = write_with(&p, |_| Err(std::io::Error::other("disk on fire")));
        assert!(matches!(r, Err(IoError::Write { .. })));
        assert_eq!(std::fs::read(&p).unwrap(), b"keep");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn missing_directory_is_write_error() {
        let r = write_bytes(Path::new("/nonexistent-knitvox-dir/x.ply"), b"x");
        assert!(matches!(r, Err(IoError::Write { .. })));
    }
}
