//! Plain geometric types shared by every stage: yarn curves, yarn frame sequences,
//! units and up axes. Pure: no files, no printing, no environment.
//!
//! Conventions: knitvox works in metres, kilograms and seconds, with **+Y up**
//! (as glTF). Readers convert from a file's unit and up axis into this frame;
//! writers convert back out to the target format's convention.

mod asset;
pub mod bvh;
pub mod card;
mod error;
pub mod excerpt;
mod frame_spec;
mod mesh;
mod plausible;
mod rest;
mod stretch;
mod units;
pub(crate) mod vec3;
mod weld;
mod yarns;

pub use asset::{
    Asset, AssetFibres, InputFile, NodeSteps, Provenance, DEFAULT_GAMMA_S, DEFAULT_GAMMA_V,
};
pub use asset::{
    DampingRecord, DampingRecordError, FitPose, FitRecord, FitRecordError, PoseLosses,
    TrainingFidelity, UniformMaterial, DAMPING_RECORD_KEY, FIT_RECORD_KEY,
};
pub use error::GeomError;
pub use excerpt::{cap_message, excerpt, excerpt_chars, num, MAX_EXCERPT_CHARS, MAX_MESSAGE_BYTES};
pub use frame_spec::{
    check_frame_number, FrameNumberError, FrameSpec, FrameSpecError, MAX_FRAME_NUMBER,
    MAX_SPEC_FRAMES,
};
pub use mesh::{Embedding, TetMesh, VoxelGrid, YarnPiece};
pub use plausible::{garment_size_warning, yarn_radius_warning, GARMENT_DIAGONAL_M, YARN_RADIUS_M};
pub use rest::{MaterialOverrides, RestShape, YarnMaterial};
pub use stretch::{SegmentStretch, StretchSummary};
pub use units::{Units, UnknownUnit, UnknownUpAxis, UpAxis};
pub use weld::{Weld, WELD_TOLERANCE_RADII};
pub use yarns::{bounds_of, dist, is_unit_vector, Bounds, YarnFrames, Yarns, DEFAULT_RADIUS_M};

/// A 3D point or vector in metres.
pub type Vec3 = [f64; 3];
