//! Atomic file output: write to a dot-prefixed temporary file in the target's
//! directory, fsync it, rename it over the target, fsync the directory. A
//! reader (or a crash) never sees a half-written file.

use std::cell::RefCell;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI32, AtomicPtr, AtomicUsize, Ordering};

use tempfile::TempPath;

use super::IoError;

/// Temporary files in flight, for [`remove_temporaries_on_signal`]: a fixed
/// table of leaked C strings so the signal handler needs no allocation or
/// lock (async-signal-safe: atomic loads and `unlink`).
/// Room for every frame of a staged sequence (see [`all_or_nothing`]):
/// 512 KiB of zeroed static memory, touched only as far as it is used.
const MAX_TEMPS: usize = 1 << 16;
static TEMPS: [AtomicPtr<libc::c_char>; MAX_TEMPS] =
    [const { AtomicPtr::new(std::ptr::null_mut()) }; MAX_TEMPS];
/// Where [`TempGuard::register`] starts looking for a free slot, so that
/// registering many files stays linear.
static NEXT_SLOT: AtomicUsize = AtomicUsize::new(0);

/// Non-zero while some thread is in [`hold_signals`] (creating and
/// registering a temporary, or [`commit`] renaming several files into
/// place): a signal then waits in [`PENDING_SIGNAL`], so that no temporary
/// exists unregistered and the outputs are all or nothing.
static HELD: AtomicUsize = AtomicUsize::new(0);
static PENDING_SIGNAL: AtomicI32 = AtomicI32::new(0);

/// Runs `f` with SIGINT/SIGTERM held back (handled when the last holder
/// returns).
pub(crate) fn hold_signals<T>(f: impl FnOnce() -> T) -> T {
    HELD.fetch_add(1, Ordering::AcqRel);
    let r = f();
    if HELD.fetch_sub(1, Ordering::AcqRel) == 1 {
        #[cfg(unix)]
        match PENDING_SIGNAL.swap(0, Ordering::AcqRel) {
            0 => {}
            sig => remove_temporaries_on_signal(sig),
        }
    }
    r
}

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
            let start = NEXT_SLOT.load(Ordering::Relaxed);
            for i in (start..MAX_TEMPS).chain(0..start) {
                if TEMPS[i]
                    .compare_exchange(
                        std::ptr::null_mut(),
                        raw,
                        Ordering::AcqRel,
                        Ordering::Acquire,
                    )
                    .is_ok()
                {
                    NEXT_SLOT.store((i + 1) % MAX_TEMPS, Ordering::Relaxed);
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
    // Mid-commit the temporaries are becoming the outputs: finish first
    // (see `commit`), which calls back here.
    if HELD.load(Ordering::Acquire) > 0 {
        PENDING_SIGNAL.store(sig, Ordering::Release);
        return;
    }
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
    let prefix = format!(".{}.", name.to_string_lossy());
    let (tmp, registered) = hold_signals(|| {
        let tmp = builder.prefix(&prefix).suffix(".tmp").tempfile_in(&dir)?;
        let registered = TempGuard::register(tmp.path());
        Ok((tmp, registered))
    })
    .map_err(|e| write_err(path, e))?;
    let tmp_path = tmp.path().to_path_buf();
    produce(&tmp_path).map_err(|e| write_err(path, e))?;
    finish_temp(tmp.into_temp_path(), registered, path)
}

/// A complete temporary file waiting for its final name.
struct Staged {
    tmp: TempPath,
    target: PathBuf,
    _registered: TempGuard,
}

thread_local! {
    /// The files staged by the enclosing [`all_or_nothing`] on this thread;
    /// `None` outside one (files get their names at once).
    static STAGE: RefCell<Option<Vec<Staged>>> = const { RefCell::new(None) };
}

/// Gives the complete temporary file `tmp` its final name `path` (fsync,
/// rename, fsync of the folder): at once, or when the enclosing
/// [`all_or_nothing`] succeeds. Used by [`write_with`] and by writers that
/// build their temporary file themselves (`h5::FrameWriter`).
pub fn finish_temp(tmp: TempPath, registered: TempGuard, path: &Path) -> Result<(), IoError> {
    File::open(&tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| write_err(path, e))?;
    let staged = Staged {
        tmp,
        target: path.to_path_buf(),
        _registered: registered,
    };
    let now = STAGE.with(|s| match s.borrow_mut().as_mut() {
        Some(list) => {
            list.push(staged);
            None
        }
        None => Some(staged),
    });
    match now {
        Some(s) => commit(vec![s]),
        None => Ok(()),
    }
}

/// Runs `job` so that the files it writes (on this thread, through this
/// module) appear under their final names only if it succeeds: until `job` returns each stays a registered temporary file,
/// removed on an error, a panic or SIGINT/SIGTERM; then all are renamed
/// into place, and a rename that fails puts back what the earlier ones
/// replaced. A nested call joins the outermost one.
pub fn all_or_nothing<T, E: From<IoError>>(job: impl FnOnce() -> Result<T, E>) -> Result<T, E> {
    if STAGE.with(|s| s.borrow().is_some()) {
        return job();
    }
    /// Ends the stage on every way out; dropping its files removes them.
    struct Reset;
    impl Drop for Reset {
        fn drop(&mut self) {
            let _ = STAGE.try_with(|s| s.borrow_mut().take());
        }
    }
    STAGE.with(|s| *s.borrow_mut() = Some(Vec::new()));
    let reset = Reset;
    let out = job()?;
    let staged = STAGE.with(|s| s.borrow_mut().take()).unwrap_or_default();
    drop(reset);
    commit(staged)?;
    Ok(out)
}

/// Renames every staged file onto its target. One file needs no undo (a
/// rename is atomic); several are renamed with SIGINT/SIGTERM held back
/// (the handler would remove the rest), each replaced file first moved
/// aside so that a failed rename can restore them all.
fn commit(staged: Vec<Staged>) -> Result<(), IoError> {
    let dirs: Vec<PathBuf> = staged.iter().map(|s| dir_of(&s.target)).collect();
    let result = if staged.len() <= 1 {
        staged.into_iter().try_for_each(|s| {
            s.tmp
                .persist(&s.target)
                .map_err(|e| write_err(&s.target, e.error))
        })
    } else {
        hold_signals(|| place_all(staged))
    };
    // fsync the folders so the renames themselves are durable.
    for d in dirs {
        if let Ok(f) = File::open(&d) {
            let _ = f.sync_all();
        }
    }
    result
}

/// [`place`]s every file, or none: a failure restores the earlier ones.
fn place_all(staged: Vec<Staged>) -> Result<(), IoError> {
    let mut placed: Vec<(PathBuf, Option<TempPath>)> = Vec::with_capacity(staged.len());
    for s in staged {
        match place(s) {
            Ok(p) => placed.push(p),
            Err(e) => {
                for (target, old) in placed.into_iter().rev() {
                    restore(&target, old);
                }
                return Err(e);
            }
        }
    }
    // Dropping `placed` removes the files moved aside.
    Ok(())
}

/// Moves the file at the target (if any) aside, then renames the staged
/// file onto the target. Returns the target and what it replaced.
fn place(s: Staged) -> Result<(PathBuf, Option<TempPath>), IoError> {
    let Staged { tmp, target, .. } = s;
    let old = match std::fs::symlink_metadata(&target) {
        Ok(m) if !m.is_dir() => Some(move_aside(&target).map_err(|e| write_err(&target, e))?),
        _ => None,
    };
    match tmp.persist(&target) {
        Ok(()) => Ok((target, old)),
        Err(e) => {
            if let Some(old) = old {
                let _ = old.persist(&target);
            }
            Err(write_err(&target, e.error))
        }
    }
}

/// Renames `target` to a fresh dot-prefixed name in its folder.
fn move_aside(target: &Path) -> std::io::Result<TempPath> {
    let name = target.file_name().unwrap_or_default().to_string_lossy();
    let aside = tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".old")
        .tempfile_in(dir_of(target))?
        .into_temp_path();
    std::fs::rename(target, &aside)?;
    Ok(aside)
}

/// Undoes [`place`]: the replaced file back, or the new file removed.
fn restore(target: &Path, old: Option<TempPath>) {
    match old {
        Some(old) => {
            let _ = old.persist(target);
        }
        None => {
            let _ = std::fs::remove_file(target);
        }
    }
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
    fn staged_writes_appear_only_when_all_succeed() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
        write_bytes(&a, b"old a").unwrap();
        let r: Result<(), IoError> = all_or_nothing(|| {
            write_bytes(&a, b"new a")?;
            assert_eq!(std::fs::read(&a).unwrap(), b"old a", "renamed too early");
            write_bytes(&b, b"new b")?;
            Err(write_err(&b, std::io::Error::other("later failure")))
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read(&a).unwrap(), b"old a");
        assert!(!b.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        all_or_nothing(|| {
            write_bytes(&a, b"new a")?;
            write_bytes(&b, b"new b")
        })
        .unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), b"new a");
        assert_eq!(std::fs::read(&b).unwrap(), b"new b");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn failed_rename_puts_back_earlier_files() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
        write_bytes(&a, b"old a").unwrap();
        // A folder under b's name: b's temporary writes fine, its rename fails.
        std::fs::create_dir(&b).unwrap();
        let r = all_or_nothing(|| {
            write_bytes(&a, b"new a")?;
            write_bytes(&b, b"new b")
        });
        assert!(matches!(r, Err(IoError::Write { .. })), "{r:?}");
        assert_eq!(std::fs::read(&a).unwrap(), b"old a");
        assert!(b.is_dir());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn missing_directory_is_write_error() {
        let r = write_bytes(Path::new("/nonexistent-knitvox-dir/x.ply"), b"x");
        assert!(matches!(r, Err(IoError::Write { .. })));
    }
}
