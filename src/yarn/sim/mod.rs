//! The reference yarn-level simulator (YLS): polyline rods with stretching
//! and bending with rest curvature (HYLC §5.1), Kaldor yarn-yarn contact
//! (Leaf Eq. 9-10) with contact and global damping (Leaf Eq. 11-12),
//! gravity, pins and scripted handles, plane and sphere colliders (any
//! [`PointCollider`]), periodic tiles (Leaf §5), relaxation with local
//! rest-length scaling and the radius similarity transform (Leaf §6).
//!
//! Time integration is symplectic Euler with an adaptive step that bounds
//! every vertex's motion to `eps * r` per step (Leaf Eq. 2), so yarns cannot
//! pass through each other; see [`integrate`] for why.
//!
//! Pure: no files, no printing, no environment.

pub mod bench_scenes;
pub mod colliders;
pub mod contact;
pub mod damping;
mod error;
pub mod handles;
pub mod integrate;
pub(crate) mod model;
pub mod params;
pub mod periodic;
pub mod rod;

pub use colliders::{PlaneCollider, PointCollider, SphereCollider};
pub use handles::{Handle, HandleError, HandleMotion};
pub use integrate::{EnergyTerms, FrameStats, Timings, YarnSim};
pub use params::YarnSimParams;
pub use periodic::{relax, relax_periodic, tile_yarns, RelaxOptions, RelaxStats};

pub use bench_scenes::{
    bench, bench_yarns, plain_weave_swatch, stretch_scene, BenchGeometry, BenchOptions,
    BenchReport, BENCH_FRAME,
};
pub use error::YarnSimError;
