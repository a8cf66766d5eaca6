//! Tetrahedral meshes built from voxels, and the embedding of yarns in them.

use super::vec3::{cross, dot, sub};
use super::Vec3;

/// The voxels of an embedding: axis-aligned cubes of edge `h` on the grid
/// `origin + h * (i, j, k)`. Voxel `(i, j, k)` spans `[i, i+1] x [j, j+1] x [k, k+1]`
/// in grid units.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VoxelGrid {
    /// Grid origin (m).
    pub origin: Vec3,
    /// Voxel edge length (m).
    pub h: f64,
    /// Occupied voxels, sorted lexicographically by (i, j, k), no duplicates.
    pub voxels: Vec<[i32; 3]>,
}

impl VoxelGrid {
    /// Grid coordinates of a point (continuous: voxel (i, j, k) holds [i, i+1) etc.).
    pub fn to_grid(&self, p: Vec3) -> Vec3 {
        std::array::from_fn(|k| (p[k] - self.origin[k]) / self.h)
    }
    /// Position (m) of grid corner `c`.
    pub fn corner_position(&self, c: [i32; 3]) -> Vec3 {
        std::array::from_fn(|k| self.origin[k] + self.h * c[k] as f64)
    }
    /// Index of voxel `v` in `voxels`, if occupied.
    pub fn find(&self, v: [i32; 3]) -> Option<usize> {
        self.voxels.binary_search(&v).ok()
    }
}

/// A tetrahedral mesh: rest node positions and tets with positive volume
/// (node order such that `(x1-x0) . ((x2-x0) x (x3-x0)) > 0`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TetMesh {
    /// Rest positions (m).
    pub nodes: Vec<Vec3>,
    /// Node indices of each tet.
    pub tets: Vec<[u32; 4]>,
}

impl TetMesh {
    pub fn num_nodes(&self) -> usize {
        self.nodes.len()
    }
    pub fn num_tets(&self) -> usize {
        self.tets.len()
    }
    /// Signed volume of tet `t` for node positions `x` (m^3).
    pub fn volume_with(&self, x: &[Vec3], t: usize) -> f64 {
        let [a, b, c, d] = self.tets[t].map(|i| x[i as usize]);
        let e1 = sub(b, a);
        let e2 = sub(c, a);
        let e3 = sub(d, a);
        dot(e1, cross(e2, e3)) / 6.0
    }
    /// Signed rest volume of tet `t` (m^3).
    pub fn volume(&self, t: usize) -> f64 {
        self.volume_with(&self.nodes, t)
    }
}

/// Where each yarn vertex sits in the mesh: its tet and barycentric weights
/// (VH Eq. 4: V2Y is `x_yarn = sum_a w_a x_node(a)`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Embedding {
    /// Tet of each yarn vertex.
    pub tet: Vec<u32>,
    /// Barycentric weights of each yarn vertex in its tet (sum to 1).
    pub weights: Vec<[f64; 4]>,
}

impl Embedding {
    pub fn num_vertices(&self) -> usize {
        self.tet.len()
    }

    /// V2Y (VH Eq. 4): yarn vertex positions from mesh node positions.
    pub fn v2y(&self, mesh: &TetMesh, nodes: &[Vec3]) -> Vec<Vec3> {
        self.tet
            .iter()
            .zip(&self.weights)
            .map(|(&t, w)| {
                let ids = mesh.tets[t as usize];
                let mut p = [0.0; 3];
                for a in 0..4 {
                    let x = nodes[ids[a] as usize];
                    for k in 0..3 {
                        p[k] += w[a] * x[k];
                    }
                }
                p
            })
            .collect()
    }
}

/// The part of one yarn segment that lies in one tet: the segment's parameter
/// range `[t0, t1]` (0 at its first vertex, 1 at its second) and its rest length (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YarnPiece {
    /// Index of the segment in `Yarns::segments()` order.
    pub segment: u32,
    /// The tet holding this piece.
    pub tet: u32,
    pub t0: f64,
    pub t1: f64,
    /// Rest length of the piece (m).
    pub length: f64,
}
