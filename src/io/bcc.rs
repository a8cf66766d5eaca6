//! BCC, Cem Yuksel's binary curve collection. (stub)
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::{UpAxis, Yarns};

/// Default polyline samples per spline span: 1 keeps exactly the C0 control points.
pub const DEFAULT_SPLINE_SAMPLES: usize = 1;

pub fn decode(_data: &[u8], _opts: &ReadOptions) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("bcc: not implemented yet"))
}

pub fn encode(_yarns: &Yarns, _up: UpAxis) -> Result<Vec<u8>, FormatError> {
    Err(FormatError::whole_file("bcc: not implemented yet"))
}
