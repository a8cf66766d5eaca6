//! pyp reader. (stub)
use super::{Decoded, FormatError, ReadOptions};

pub fn decode(_data: &[u8], _opts: &ReadOptions) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("pyp: not implemented yet"))
}
