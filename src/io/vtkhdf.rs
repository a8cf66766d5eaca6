//! The homogenized asset as VTKHDF (`.vtkhdf`; schemas/asset-vtkhdf.md). (stub)
use std::path::Path;

use super::IoError;
use crate::geom::Asset;

/// Writes an asset atomically.
pub fn write_asset(path: &Path, _asset: &Asset) -> Result<(), IoError> {
    Err(IoError::Unsupported {
        path: path.to_path_buf(),
        message: "vtkhdf: not implemented yet".into(),
    })
}

/// Reads an asset written by [`write_asset`].
pub fn read_asset(path: &Path) -> Result<Asset, IoError> {
    Err(IoError::Unsupported {
        path: path.to_path_buf(),
        message: "vtkhdf: not implemented yet".into(),
    })
}
