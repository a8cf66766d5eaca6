//! Opening input files: every file knitvox reads (yarn files of every
//! format, characters, scenes, manifests, pattern grids, HDF5 frames and
//! assets) is opened here, as a regular file, within the memory budget.
//!
//! A dropped "file" may be a FIFO (an open or read would block forever), a
//! device (`/dev/zero` never ends), a directory, or a sparse file declaring
//! gigabytes. So an input is
//! * refused at once when its metadata (symlinks followed) is not a regular
//!   file, naming what it is;
//! * opened non-blocking and close-on-exec, and its descriptor checked
//!   again, so a FIFO swapped in after the first check cannot block;
//! * refused before any byte is read when its size exceeds the budget
//!   (bad input, naming the file, its size, the budget and `--max-memory`);
//! * read through `take(budget + 1)`, so a file that grows while it is read
//!   is refused instead of filling memory.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use super::confined::{kind_of, open_nonblocking};
use super::IoError;

fn read_err(path: &Path, source: std::io::Error) -> IoError {
    IoError::Read {
        path: path.to_path_buf(),
        source,
    }
}

fn check_regular(path: &Path, what: &'static str, meta: &std::fs::Metadata) -> Result<(), IoError> {
    if meta.is_file() {
        Ok(())
    } else {
        Err(IoError::NotRegular {
            path: path.to_path_buf(),
            what,
            kind: kind_of(meta),
        })
    }
}

fn too_large(path: &Path, what: &'static str, bytes: u64, budget: u64, grew: bool) -> IoError {
    IoError::TooLarge {
        path: path.to_path_buf(),
        what,
        bytes,
        budget,
        grew,
    }
}

/// Opens the input `path` (a `what`: "yarn file", "scene", ...) as a
/// regular file of at most `max_bytes` bytes (`None`: any size, for HDF5
/// files read dataset by dataset, each dataset checked against the
/// budget). Returns the open file and its length. Nothing is read.
pub fn open_regular(
    path: &Path,
    what: &'static str,
    max_bytes: Option<u64>,
) -> Result<(File, u64), IoError> {
    // The metadata first: a FIFO or device is refused without opening it.
    let meta = std::fs::metadata(path).map_err(|e| read_err(path, e))?;
    check_regular(path, what, &meta)?;
    let file = open_nonblocking(path).map_err(|e| read_err(path, e))?;
    // Again on the descriptor: the path may have been swapped meanwhile.
    let meta = file.metadata().map_err(|e| read_err(path, e))?;
    check_regular(path, what, &meta)?;
    if let Some(max) = max_bytes {
        if meta.len() > max {
            return Err(too_large(path, what, meta.len(), max, false));
        }
    }
    Ok((file, meta.len()))
}

/// Reads the whole input `path` (see [`open_regular`]) when it holds at
/// most `max_bytes` bytes; a larger file is refused before it is read.
pub fn read_input(path: &Path, what: &'static str, max_bytes: u64) -> Result<Vec<u8>, IoError> {
    let (file, len) = open_regular(path, what, Some(max_bytes))?;
    let mut data = Vec::new();
    // The length is within the budget; a failed reservation is still an
    // error, never an abort.
    data.try_reserve_exact(len as usize)
        .map_err(|_| too_large(path, what, len, max_bytes, false))?;
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut data)
        .map_err(|e| read_err(path, e))?;
    if data.len() as u64 > max_bytes {
        return Err(too_large(path, what, data.len() as u64, max_bytes, true));
    }
    Ok(data)
}

/// The first `n` bytes of `path` (fewer when it is shorter), opened as
/// [`read_input`] opens it (a regular file, within `max_bytes`), so that a
/// format's signature is checked before a file of up to the budget is
/// read whole.
pub fn read_prefix(
    path: &Path,
    what: &'static str,
    max_bytes: u64,
    n: usize,
) -> Result<Vec<u8>, IoError> {
    let (file, _) = open_regular(path, what, Some(max_bytes))?;
    let mut data = Vec::with_capacity(n);
    file.take(n as u64)
        .read_to_end(&mut data)
        .map_err(|e| read_err(path, e))?;
    Ok(data)
}

/// [`read_input`] for text files (scenes, manifests, grids): the bytes
/// must be UTF-8 (an error naming the byte otherwise).
pub fn read_input_text(path: &Path, what: &'static str, max_bytes: u64) -> Result<String, IoError> {
    let data = read_input(path, what, max_bytes)?;
    String::from_utf8(data).map_err(|e| {
        read_err(
            path,
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "the {what} is not UTF-8 text (byte {})",
                    e.utf8_error().valid_up_to()
                ),
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_over_the_budget_is_refused_before_it_is_read() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("big.bcc");
        let f = File::create(&p).unwrap();
        f.set_len(1 << 40).unwrap();
        let e = read_input(&p, "yarn file", 1 << 20).unwrap_err();
        assert!(matches!(e, IoError::TooLarge { grew: false, .. }), "{e}");
        let m = e.to_string();
        assert!(
            m.contains("1099511627776 bytes") && m.contains("1048576"),
            "{m}"
        );
        assert!(m.contains("--max-memory") && m.contains("big.bcc"), "{m}");
        assert_eq!(e.class(), super::super::ErrorClass::BadInput);
        std::fs::write(&p, b"0123456789").unwrap();
        assert_eq!(read_input(&p, "yarn file", 10).unwrap(), b"0123456789");
        assert!(read_input(&p, "yarn file", 9).is_err());
    }

    #[test]
    fn fifos_devices_and_directories_are_refused_by_kind() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("f.bcc");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let zero = d.path().join("z.ply");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        for (p, kind) in [
            (fifo, "a FIFO"),
            (zero, "a device"),
            (d.path().to_path_buf(), "a directory"),
        ] {
            let e = read_input(&p, "yarn file", 1 << 20).unwrap_err();
            assert!(e.to_string().contains(kind), "{e}");
            assert_eq!(e.class(), super::super::ErrorClass::BadInput);
        }
        let e = read_input_text(&d.path().join("missing.toml"), "scene", 10).unwrap_err();
        assert_eq!(e.class(), super::super::ErrorClass::MissingInput);
    }
}
