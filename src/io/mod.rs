//! File formats: bytes <-> geom types. One module per format; no solver code.
//!
//! Every decoder parses from bytes first (`decode`), and the path-level API
//! ([`read_path`], [`write_path`]) is a thin wrapper that adds the file name to
//! errors, resolves external resources (glTF buffers), converts units and up
//! axes, handles frame sequences (`name.####.ext`) and writes atomically.

pub mod atomic;
pub mod bcc;
pub mod bytes;
pub mod character_h5;
pub mod checkpoint;
mod codec;
pub mod confined;
mod error;
pub mod gltf;
pub mod gltf_skin;
pub mod h5;
pub mod input;
pub mod lock;
pub mod obj;
pub mod overwrite;
pub mod plot;
pub mod ply;
pub mod poly;
pub mod pyp;
pub mod sequence;
mod types;
pub mod vtkhdf;

use std::path::{Path, PathBuf};

pub use error::{ErrorClass, FormatError, IoError, Location};

pub use codec::{decode, encode, finish, format_of, read_single};
pub use types::*;

use crate::geom::{YarnFrames, Yarns};

/// Default yarn radius (m) when a file carries none (see [`crate::geom::DEFAULT_RADIUS_M`]).
pub use crate::geom::DEFAULT_RADIUS_M;

/// Reads one yarn file, or a frame sequence when the path holds a `#` run
/// (`name.####.ply`: every existing frame file, in frame order, becomes a frame).
pub fn read_path(path: &Path, opts: &ReadOptions) -> Result<YarnData, IoError> {
    if sequence::is_pattern(path) {
        return sequence::read_sequence(path, opts);
    }
    read_single(path, opts)
}

/// Writes yarns (and frames, if any) to `path` atomically.
///
/// * HDF5: one file with the rest yarns and all frames.
/// * A path with a `#` run (`out.####.ply`): one file per frame (or the rest
///   yarns as frame `first_frame` when there are no frames).
/// * Otherwise: the rest yarns (frames are not written; use a sequence or HDF5).
///
/// Returns the paths written.
pub fn write_path(
    path: &Path,
    yarns: &Yarns,
    frames: Option<&YarnFrames>,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, IoError> {
    let format = format_of(path)?;
    if !format.is_writable() {
        return Err(IoError::Unsupported {
            path: path.to_path_buf(),
            message: format!("knitvox reads {format} but does not write it; write bcc, obj, ply, gltf, glb or h5"),
        });
    }
    if format == Format::Hdf5 {
        if sequence::is_pattern(path) {
            return Err(IoError::Unsupported {
                path: path.to_path_buf(),
                message: "an HDF5 file holds every frame itself; drop the '#' frame pattern".into(),
            });
        }
        h5::write_file(path, yarns, frames)?;
        return Ok(vec![path.to_path_buf()]);
    }
    if sequence::is_pattern(path) {
        return sequence::write_sequence(path, format, yarns, frames, opts);
    }
    let bytes = encode(format, yarns, opts).map_err(|source| IoError::Format {
        path: path.to_path_buf(),
        format,
        source,
    })?;
    atomic::write_bytes(path, &bytes)?;
    Ok(vec![path.to_path_buf()])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_from_extensions() {
        assert_eq!(Format::from_path(Path::new("a/b.BCC")), Some(Format::Bcc));
        assert_eq!(Format::from_path(Path::new("x.hdf5")), Some(Format::Hdf5));
        assert_eq!(
            Format::from_path(Path::new("x.0001.glb")),
            Some(Format::Glb)
        );
        assert_eq!(Format::from_path(Path::new("x.txt")), None);
        assert_eq!(Format::from_path(Path::new("noext")), None);
    }
}
