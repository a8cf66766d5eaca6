//! glTF 2.0 (.gltf / .glb) line primitives. (stub)
use super::{Decoded, FormatError, ReadOptions, Resources};
use crate::geom::Yarns;

pub fn decode(
    _data: &[u8],
    _opts: &ReadOptions,
    _res: &dyn Resources,
) -> Result<Decoded, FormatError> {
    Err(FormatError::whole_file("gltf: not implemented yet"))
}

pub fn encode(_yarns: &Yarns, _binary: bool) -> Result<Vec<u8>, FormatError> {
    Err(FormatError::whole_file("gltf: not implemented yet"))
}
