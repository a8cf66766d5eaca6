//! knitvox HDF5 yarns and frames (schemas/yarns-hdf5.md). (stub)
use std::path::Path;

use super::{Decoded, FormatError, IoError, ReadOptions};
use crate::geom::{YarnFrames, Yarns};

pub fn decode(_data: &[u8], _opts: &ReadOptions) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("hdf5: not implemented yet"))
}

pub fn read_file(path: &Path, _opts: &ReadOptions) -> Result<Decoded, IoError> {
    Err(IoError::Unsupported {
        path: path.to_path_buf(),
        message: "hdf5: not implemented yet".into(),
    })
}

pub fn write_file(
    path: &Path,
    _yarns: &Yarns,
    _frames: Option<&YarnFrames>,
) -> Result<(), IoError> {
    Err(IoError::Unsupported {
        path: path.to_path_buf(),
        message: "hdf5: not implemented yet".into(),
    })
}
