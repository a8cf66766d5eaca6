//! The embedding's parameters and errors, shared by its steps.

use crate::geom::excerpt::num;

/// Default memory budget of an embedding (bytes): 4 GiB. The pipeline
/// replaces it with the process's budget (`--max-memory`).
pub const DEFAULT_MAX_MEMORY: u64 = 4 << 30;

/// A byte count in binary units, short.
struct Bytes(u64);

impl std::fmt::Display for Bytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        const UNITS: [&str; 5] = ["bytes", "KiB", "MiB", "GiB", "TiB"];
        let mut v = self.0 as f64;
        let mut u = 0;
        while v >= 1024.0 && u + 1 < UNITS.len() {
            v /= 1024.0;
            u += 1;
        }
        if u == 0 {
            write!(f, "{} bytes", self.0)
        } else {
            write!(f, "{v:.1} {}", UNITS[u])
        }
    }
}

/// Errors of the embedding stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EmbedError {
    #[error("no yarns to embed")]
    Empty,
    #[error("invalid voxel size {}: it must be a positive finite length in metres", num(*.0))]
    BadVoxelSize(f64),
    /// `estimate`: a lower bound of the voxels needed: the unique voxels
    /// found before the walk stopped, or the voxels one curve alone covers
    /// at least (counted from its extent, before any walk).
    #[error("voxel size {} m needs at least {estimate} voxels, more than the limit of {limit} (raise the voxel size, or the limit: --max-voxels, or max_voxels in a manifest's [embed])", num(*h))]
    TooManyVoxels { h: f64, estimate: u64, limit: u64 },
    /// A yarn point `voxels` voxels from the grid origin, beyond the
    /// +-2^30 that grid indices support.
    #[error("voxel size {} m puts a yarn point {} voxels from the grid origin, beyond the supported range of +-2^30 (raise the voxel size)", num(*h), num(voxels.round()))]
    GridTooWide { h: f64, voxels: f64 },
    /// The memory the walk and the yarn pieces would take at `h`, estimated
    /// from the segments before anything is allocated, is beyond the budget.
    #[error("voxel size {} m splits the yarns into up to {pieces} pieces, about {} of memory, more than the budget of {} (raise the voxel size, or the budget: --max-memory)", num(*h), Bytes(*bytes), Bytes(*limit))]
    TooMuchWork {
        h: f64,
        pieces: u64,
        bytes: u64,
        limit: u64,
    },
    #[error("invalid yarns: {0}")]
    Yarns(#[from] crate::geom::GeomError),
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// A broken invariant of the embedding itself (a bug, not bad input).
    #[error("internal embedding error: {0}")]
    Internal(String),
}

/// Parameters of the embedding.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EmbedParams {
    /// Voxel edge length (m). Default: chosen so that the mesh has about
    /// `target_node_ratio` x the yarn vertex count nodes (see [`super::default_voxel_size`]).
    pub voxel_size: Option<f64>,
    /// Target nodes per yarn vertex for the default voxel size. Default 0.5 (VH §4: n_V is about n_Y / 2).
    pub target_node_ratio: f64,
    /// Refuse embeddings with more voxels than this (guards memory). Default 20,000,000.
    pub max_voxels: u64,
    /// Refuse voxel sizes whose walk and yarn pieces would take more memory
    /// than this (bytes), estimated before anything is allocated. A
    /// resource limit, not part of the result, so not recorded.
    #[serde(skip, default = "default_max_memory")]
    pub max_memory: u64,
    /// Yarn material density (kg/m^3) used when the yarns carry no linear density:
    /// linear density = density x pi r^2. Default 1200 (HYLC Table 1, small variants).
    pub material_density: f64,
}

impl Default for EmbedParams {
    fn default() -> Self {
        EmbedParams {
            voxel_size: None,
            target_node_ratio: 0.5,
            max_voxels: 20_000_000,
            max_memory: DEFAULT_MAX_MEMORY,
            material_density: 1200.0,
        }
    }
}

fn default_max_memory() -> u64 {
    DEFAULT_MAX_MEMORY
}
