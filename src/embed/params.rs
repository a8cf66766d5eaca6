//! The embedding's parameters and errors, shared by its steps.

/// Errors of the embedding stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EmbedError {
    #[error("no yarns to embed")]
    Empty,
    #[error("invalid voxel size {0}: it must be a positive finite length in metres")]
    BadVoxelSize(f64),
    /// `estimate`: the unique voxels found before the walk stopped, or the
    /// voxels one segment alone covers at least.
    #[error("voxel size {h} m makes more than the limit of {limit} voxels (estimate {estimate}; raise --max-voxels or the voxel size)")]
    TooManyVoxels { h: f64, estimate: u64, limit: u64 },
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
            material_density: 1200.0,
        }
    }
}
