//! Wavefront OBJ `v` / `l` polylines. (stub)
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::{Units, UpAxis, Yarns};

pub fn decode(_data: &[u8], _opts: &ReadOptions) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("obj: not implemented yet"))
}

pub fn encode(_yarns: &Yarns, _units: Units, _up: UpAxis) -> Result<Vec<u8>, FormatError> {
    Err(FormatError::whole_file("obj: not implemented yet"))
}
