//! Confined reads of files that another file refers to (glTF buffer URIs,
//! for the yarn reader and the character reader alike).
//!
//! A referenced file is attacker-controlled text in a dropped file, so the
//! URI is percent-decoded first (RFC 3986; `%2Fetc%2Fpasswd` is an absolute
//! path once decoded) and then refused when it
//! * has a scheme (`file:`, `http:`) or is absolute,
//! * resolves outside the referring file's folder (`..`, or a symlink that
//!   leads out: the path is canonicalized and its prefix checked),
//! * is not a regular file (FIFO, device, directory: checked on the metadata
//!   before opening, and again on the opened descriptor, which is opened
//!   non-blocking so a FIFO swapped in between cannot hang the read),
//! * holds fewer bytes than declared; at most the declared bytes are read.

use std::ffi::OsString;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Why a confined read was refused or failed; `uri` is the URI as given
/// and `path` the file it names, both cut to an excerpt.
#[derive(Debug, thiserror::Error)]
pub enum ConfinedError {
    /// The URI has a scheme (`file:`, `http:`, a drive letter).
    #[error("refusing URI '{uri}': only relative paths are followed (it has a scheme)")]
    Scheme { uri: String },
    /// The URI holds a NUL byte once percent-decoded.
    #[error("refusing URI '{uri}': it holds a NUL byte once decoded")]
    NulByte { uri: String },
    /// The URI names no path.
    #[error("refusing URI '{uri}': empty path")]
    EmptyPath { uri: String },
    /// The URI names an absolute path.
    #[error("refusing URI '{uri}': it names the absolute path '{path}'; only paths inside the file's folder are followed")]
    Absolute { uri: String, path: String },
    /// The folder of the referring file cannot be resolved.
    #[error("cannot resolve the folder '{}': {source}", folder.display())]
    Folder {
        folder: PathBuf,
        source: std::io::Error,
    },
    /// The file cannot be resolved, inspected or read.
    #[error("cannot read '{path}': {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    /// The file cannot be opened.
    #[error("cannot open '{path}': {source}")]
    Open {
        path: String,
        source: std::io::Error,
    },
    /// The URI resolves outside the referring file's folder.
    #[error("refusing URI '{uri}': it resolves to '{path}', outside the file's folder '{}'", folder.display())]
    Outside {
        uri: String,
        path: String,
        folder: PathBuf,
    },
    /// The URI names a directory, FIFO, device or socket.
    #[error("refusing URI '{uri}': '{path}' is not a regular file ({kind})")]
    NotRegular {
        uri: String,
        path: String,
        kind: &'static str,
    },
    /// A path a job, scene or manifest names resolves (symlinks followed)
    /// outside every folder it may read from.
    #[error("refusing '{path}': it resolves to '{resolved}', outside {roots}; a job reads only files inside its own folder (an operator can allow more folders)")]
    OutsideRoots {
        path: String,
        resolved: String,
        roots: String,
    },
    /// The file holds fewer bytes than declared.
    #[error("'{path}' holds {bytes} bytes, fewer than the {declared} declared")]
    TooShort {
        path: String,
        bytes: u64,
        declared: u64,
    },
}

/// Percent-decodes a URI path (invalid escapes are kept as they are).
pub fn percent_decode_bytes(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            let hex = std::str::from_utf8(&b[i + 1..i + 3])
                .ok()
                .and_then(|h| u8::from_str_radix(h, 16).ok());
            if let Some(v) = hex {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    out
}

/// A path built from a URI, cut for messages like the URI itself.
fn shown_path(p: &Path) -> String {
    crate::geom::excerpt(&p.display().to_string())
}

/// The relative path a URI names, or why it may not be followed.
pub fn relative_path(uri: &str) -> Result<PathBuf, ConfinedError> {
    let shown = crate::geom::excerpt(uri);
    // A scheme (`file:`, `http:`, a Windows drive `C:`) comes before any '/'.
    let head = uri.split(['/', '?', '#']).next().unwrap_or("");
    if head.contains(':') {
        return Err(ConfinedError::Scheme { uri: shown });
    }
    let bytes = percent_decode_bytes(uri);
    if bytes.contains(&0) {
        return Err(ConfinedError::NulByte { uri: shown });
    }
    #[cfg(unix)]
    let path = {
        use std::os::unix::ffi::OsStringExt;
        PathBuf::from(OsString::from_vec(bytes.clone()))
    };
    #[cfg(not(unix))]
    let path = PathBuf::from(OsString::from(String::from_utf8_lossy(&bytes).into_owned()));
    if path.as_os_str().is_empty() {
        return Err(ConfinedError::EmptyPath { uri: shown });
    }
    if path.is_absolute()
        || path.has_root()
        || path
            .components()
            .any(|c| matches!(c, Component::Prefix(_) | Component::RootDir))
        || bytes.starts_with(b"\\")
    {
        return Err(ConfinedError::Absolute {
            uri: shown,
            path: crate::geom::excerpt(&path.display().to_string()),
        });
    }
    Ok(path)
}

/// Reads the file `uri` names inside `dir`: at most `max_bytes` bytes, and an
/// error if the file holds fewer than `min_bytes`.
pub fn read_confined(
    dir: &Path,
    uri: &str,
    min_bytes: u64,
    max_bytes: u64,
) -> Result<Vec<u8>, ConfinedError> {
    let rel = relative_path(uri)?;
    let shown = crate::geom::excerpt(uri);
    let base_dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let base = std::fs::canonicalize(base_dir).map_err(|source| ConfinedError::Folder {
        folder: base_dir.to_path_buf(),
        source,
    })?;
    let joined = base.join(&rel);
    let target = std::fs::canonicalize(&joined).map_err(|source| ConfinedError::Read {
        path: shown_path(&joined),
        source,
    })?;
    if !target.starts_with(&base) {
        return Err(ConfinedError::Outside {
            uri: shown,
            path: shown_path(&target),
            folder: base,
        });
    }
    let read_error = |source| ConfinedError::Read {
        path: shown_path(&target),
        source,
    };
    let not_regular = |meta: &std::fs::Metadata| ConfinedError::NotRegular {
        uri: shown.clone(),
        path: shown_path(&target),
        kind: kind_of(meta),
    };
    let too_short = |bytes: u64| ConfinedError::TooShort {
        path: shown_path(&target),
        bytes,
        declared: min_bytes,
    };
    let meta = std::fs::metadata(&target).map_err(read_error)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    if meta.len() < min_bytes {
        return Err(too_short(meta.len()));
    }
    let file = open_nonblocking(&target).map_err(|source| ConfinedError::Open {
        path: shown_path(&target),
        source,
    })?;
    let meta = file.metadata().map_err(read_error)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    let mut data = Vec::new();
    file.take(max_bytes)
        .read_to_end(&mut data)
        .map_err(read_error)?;
    if (data.len() as u64) < min_bytes {
        return Err(too_short(data.len() as u64));
    }
    Ok(data)
}

/// Resolves `path` (symlinks followed, `..` applied) and checks that it
/// lies inside one of `roots` (themselves resolved). Returns the resolved
/// path; nothing is opened or read, so a refused file's contents never
/// reach a message. A path that does not exist is an error naming it.
pub fn resolve_inside(path: &Path, roots: &[PathBuf]) -> Result<PathBuf, ConfinedError> {
    let resolved = std::fs::canonicalize(path).map_err(|source| ConfinedError::Read {
        path: shown_path(path),
        source,
    })?;
    let mut shown_roots = Vec::new();
    for root in roots {
        match std::fs::canonicalize(root) {
            Ok(r) if resolved.starts_with(&r) => return Ok(resolved),
            Ok(r) => shown_roots.push(shown_path(&r)),
            Err(_) => shown_roots.push(shown_path(root)),
        }
    }
    let roots = match shown_roots.len() {
        0 => "every allowed folder (none is allowed)".to_string(),
        1 => format!("'{}'", shown_roots[0]),
        _ => format!("the allowed folders '{}'", shown_roots.join("', '")),
    };
    Err(ConfinedError::OutsideRoots {
        path: shown_path(path),
        resolved: shown_path(&resolved),
        roots,
    })
}

/// Opens `path` read-only, non-blocking and close-on-exec: a FIFO swapped in
/// after a metadata check cannot block the open, and no child inherits it.
/// The caller checks the opened file's metadata (it may still be a FIFO).
pub(crate) fn open_nonblocking(path: &Path) -> std::io::Result<std::fs::File> {
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.custom_flags(libc::O_NONBLOCK | libc::O_CLOEXEC);
    }
    opts.open(path)
}

/// What a file that is not a regular file is, for messages ("a FIFO").
pub(crate) fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    let ft = meta.file_type();
    if ft.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO";
        }
        if ft.is_char_device() || ft.is_block_device() {
            return "a device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    "not a plain file"
}

#[cfg(test)]
mod tests {
    #[test]
    fn resolve_inside_refuses_dotdot_absolute_and_symlinks_that_leave() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().join("job");
        let outside = d.path().join("secret.bcc");
        std::fs::create_dir(&root).unwrap();
        std::fs::write(&outside, b"secret").unwrap();
        std::fs::write(root.join("ok.bcc"), b"x").unwrap();
        std::os::unix::fs::symlink(&outside, root.join("link.bcc")).unwrap();
        std::os::unix::fs::symlink(root.join("ok.bcc"), root.join("inner.bcc")).unwrap();
        let roots = [root.clone()];
        assert!(super::resolve_inside(&root.join("ok.bcc"), &roots).is_ok());
        assert!(super::resolve_inside(&root.join("inner.bcc"), &roots).is_ok());
        for bad in [
            root.join("../secret.bcc"),
            outside.clone(),
            root.join("link.bcc"),
        ] {
            let e = super::resolve_inside(&bad, &roots).unwrap_err().to_string();
            assert!(e.contains("outside"), "{e}");
            assert!(!e.contains("secret\""), "{e}");
        }
        // A second allowed root lets the outside file through.
        assert!(super::resolve_inside(&outside, &[root.clone(), d.path().to_path_buf()]).is_ok());
    }

    use super::*;

    #[test]
    fn decoding_and_refusals() {
        assert_eq!(percent_decode_bytes("a%20b.bin"), b"a b.bin");
        assert_eq!(percent_decode_bytes("100%"), b"100%");
        assert_eq!(percent_decode_bytes("%zz"), b"%zz");
        assert_eq!(percent_decode_bytes("x%2"), b"x%2");
        assert_eq!(
            relative_path("a%20b.bin").unwrap(),
            PathBuf::from("a b.bin")
        );
        for bad in [
            "%2Fetc%2Fpasswd",
            "/etc/passwd",
            "file:///etc/passwd",
            "C:x",
            "a%00b",
            "",
        ] {
            assert!(relative_path(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn reads_stay_in_the_folder() {
        let root = std::env::temp_dir().join(format!("knitvox-confined-{}", std::process::id()));
        let dir = root.join("in");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(root.join("secret.bin"), b"SECRET").unwrap();
        std::fs::write(dir.join("ok.bin"), b"0123456789").unwrap();
        assert_eq!(read_confined(&dir, "ok.bin", 4, 4).unwrap(), b"0123");
        let e = read_confined(&dir, "ok.bin", 11, 11)
            .unwrap_err()
            .to_string();
        assert!(e.contains("fewer than the 11 declared"), "{e}");
        let e = read_confined(&dir, "../secret.bin", 1, 6)
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside the file's folder"), "{e}");
        let e = read_confined(&dir, "..%2Fsecret.bin", 1, 6)
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside the file's folder"), "{e}");
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(root.join("secret.bin"), dir.join("link.bin")).unwrap();
            let e = read_confined(&dir, "link.bin", 1, 6)
                .unwrap_err()
                .to_string();
            assert!(e.contains("outside the file's folder"), "{e}");
            let e = read_confined(&dir, "/dev/zero", 1, 6)
                .unwrap_err()
                .to_string();
            assert!(e.contains("absolute"), "{e}");
        }
        let e = read_confined(&dir, ".", 1, 6).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
