//! Stanford PLY polylines. (stub)
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::Yarns;

pub fn decode(_data: &[u8], _opts: &ReadOptions) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("ply: not implemented yet"))
}

pub fn encode(_yarns: &Yarns) -> Result<Vec<u8>, FormatError> {
    Err(FormatError::whole_file("ply: not implemented yet"))
}
