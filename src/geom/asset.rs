//! The homogenized asset: tet mesh, materials, embedding, rest yarns,
//! parameters, provenance and a time series of node positions. Stored as
//! VTKHDF by `io::vtkhdf` (layout in schemas/asset-vtkhdf.md).

use super::{Embedding, TetMesh, Vec3, VoxelGrid, Yarns};

/// Default per-tet shape stiffness gamma_s (VH Eq. 7) before fitting (Pa).
pub const DEFAULT_GAMMA_S: f64 = 1.0e4;
/// Default per-tet volume stiffness gamma_v (VH Eq. 7) before fitting (Pa).
pub const DEFAULT_GAMMA_V: f64 = 1.0e4;

/// Where an asset came from.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Provenance {
    /// knitvox version that wrote it.
    pub knitvox_version: String,
    /// The command line that made it.
    pub command: String,
    /// Input files and their SHA-256 (hex).
    pub inputs: Vec<InputFile>,
}

#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct InputFile {
    pub path: String,
    pub sha256: String,
}

/// A time series of node positions (fixed topology).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NodeSteps {
    /// Time of each step (s).
    pub times: Vec<f64>,
    /// Node positions (m), step-major: step `s` owns `positions[s * n .. (s + 1) * n]`.
    pub positions: Vec<Vec3>,
    /// Optional per-step fit error (e.g. Y2V RMS yarn error, m); empty when unknown.
    pub fit_error: Vec<f64>,
}

impl NodeSteps {
    pub fn num_steps(&self) -> usize {
        self.times.len()
    }
    pub fn step(&self, s: usize, num_nodes: usize) -> &[Vec3] {
        &self.positions[s * num_nodes..(s + 1) * num_nodes]
    }
}

/// A homogenized asset.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Asset {
    /// Voxels the mesh was built from.
    pub grid: VoxelGrid,
    /// Rest tet mesh (m).
    pub mesh: TetMesh,
    /// Voxel (index into `grid.voxels`) of each tet.
    pub tet_voxel: Vec<u32>,
    /// Lumped node masses (kg), VH Eq. 1-3.
    pub node_mass: Vec<f64>,
    /// Per-tet shape stiffness gamma_s (Pa).
    pub gamma_s: Vec<f64>,
    /// Per-tet volume stiffness gamma_v (Pa).
    pub gamma_v: Vec<f64>,
    /// Per-tet domain id (for domain-decomposed solvers); 0 by default.
    pub domain: Vec<i32>,
    /// Yarn vertices in the mesh (V2Y).
    pub embedding: Embedding,
    /// Rest yarns (m, +Y up).
    pub rest_yarns: Yarns,
    /// Every parameter used to build and fit the asset, as a JSON object.
    pub parameters: serde_json::Value,
    pub provenance: Provenance,
    /// Node positions over time.
    pub steps: NodeSteps,
}
