//! Six tets per voxel (VH §4) with the Kuhn/Freudenthal split, and point location.
//!
//! Every voxel is cut along its `(0,0,0)-(1,1,1)` diagonal into the six tets
//! `{ f[pi0] >= f[pi1] >= f[pi2] }` of the axis permutations `pi` (`f` = the
//! fractional grid coordinate inside the voxel). The tet of `pi` has the corners
//! `v0 = 0`, `v1 = e_pi0`, `v2 = e_pi0 + e_pi1`, `v3 = (1,1,1)`. Because the same
//! split is used in every voxel, the two triangles of a shared voxel face are
//! the same on both sides (the face diagonal runs from the face's lowest to its
//! highest corner in both voxels), so the mesh is conforming with no hanging
//! nodes.
//!
//! Barycentric weights of a point with fractional coordinates `f` in the tet of
//! `pi` (solve `f = w1 v1 + w2 v2 + w3 v3`, `w0 = 1 - w1 - w2 - w3`):
//! `w = (1 - f[pi0], f[pi0] - f[pi1], f[pi1] - f[pi2], f[pi2])` for `(v0, v1, v2, v3)`.
//! The signed volume of `(v0, v1, v2, v3)` is `sign(pi) h^3 / 6`, so tets of odd
//! permutations are stored as `(v0, v2, v1, v3)` (and their weights swapped alike).

use super::keys::{corner_key, unique_corners};
use crate::geom::{TetMesh, Vec3, VoxelGrid};
use rayon::prelude::*;

/// The six axis permutations, in the fixed order of the tets of a voxel
/// (voxel `v` owns tets `6 v + q`, `q` indexing this table).
pub const PERMS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// Whether `PERMS[q]` is an odd permutation (its tet is stored as `(v0, v2, v1, v3)`).
const ODD: [bool; 6] = [false, true, true, false, false, true];

/// Local corner index `dx + 2 dy + 4 dz` of each stored node of tet `q`.
pub(crate) fn tet_corners(q: usize) -> [usize; 4] {
    let [a, b, _] = PERMS[q];
    let v1 = 1 << a;
    let v2 = v1 | (1 << b);
    if ODD[q] {
        [0, v2, v1, 7]
    } else {
        [0, v1, v2, 7]
    }
}

/// Barycentric weights, in stored node order, of the point with fractional
/// coordinates `f` (relative to the voxel's lowest corner, grid units) with
/// respect to tet `q` of that voxel. They sum to 1 and reproduce the point for
/// any `f`; they are all in `[0, 1]` exactly when the point lies in the tet.
pub fn kuhn_weights(q: usize, f: Vec3) -> [f64; 4] {
    let [a, b, c] = PERMS[q];
    let w = [1.0 - f[a], f[a] - f[b], f[b] - f[c], f[c]];
    if ODD[q] {
        [w[0], w[2], w[1], w[3]]
    } else {
        w
    }
}

/// The tet (index into [`PERMS`]) of a voxel holding fractional coordinates `f`:
/// the permutation sorting `f` descending, ties broken by the lower axis first
/// (any tie choice is a tet containing the point, on its boundary).
pub fn kuhn_tet(f: Vec3) -> usize {
    let mut order = [0usize, 1, 2];
    // Stable sort: equal coordinates keep ascending axis order.
    order.sort_by(|&x, &y| f[y].total_cmp(&f[x]));
    PERMS
        .iter()
        .position(|p| *p == order)
        .expect("every permutation of 3 axes is in PERMS")
}

/// Builds the tet mesh of a voxel grid (VH §4): nodes are the unique voxel
/// corners sorted by `(i, j, k)`, each voxel gives 6 positive tets of volume
/// `h^3 / 6` (voxel `v` -> tets `6v..6v+6`, in [`PERMS`] order). Returns the
/// mesh and the voxel of every tet.
pub fn tetrahedralize(grid: &VoxelGrid) -> (TetMesh, Vec<u32>) {
    let corners = unique_corners(&grid.voxels);
    let nodes: Vec<Vec3> = corners
        .par_iter()
        .map(|&c| grid.corner_position(c))
        .collect();
    let keys: Vec<u128> = corners.iter().map(|&c| corner_key(c)).collect();
    let tets: Vec<[u32; 4]> = grid
        .voxels
        .par_iter()
        .flat_map_iter(|&v| {
            let ids = voxel_corner_nodes(&keys, v);
            (0..6).map(move |q| tet_corners(q).map(|c| ids[c]))
        })
        .collect();
    let tet_voxel = (0..grid.voxels.len() as u32)
        .flat_map(|v| std::iter::repeat_n(v, 6))
        .collect();
    (TetMesh { nodes, tets }, tet_voxel)
}

/// Node indices of the 8 corners of voxel `v` (local corner `dx + 2 dy + 4 dz`),
/// looked up in the sorted corner keys.
fn voxel_corner_nodes(keys: &[u128], v: [i32; 3]) -> [u32; 8] {
    std::array::from_fn(|c| {
        let corner = [
            v[0] + (c & 1) as i32,
            v[1] + ((c >> 1) & 1) as i32,
            v[2] + ((c >> 2) & 1) as i32,
        ];
        // Every corner of every voxel was inserted by `unique_corners`.
        keys.binary_search(&corner_key(corner))
            .expect("voxel corner is a node") as u32
    })
}

/// Where a point sits in the mesh of `grid`: its tet (`6 * voxel + q`) and
/// barycentric weights in stored node order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Location {
    /// Tet index (`6 * voxel index + q`, `q` into [`PERMS`]).
    pub tet: u32,
    /// Barycentric weights in the tet's stored node order (sum to 1).
    pub weights: [f64; 4],
}

/// Locates point `p` (m): the voxel is the floor of its grid coordinate (a
/// point on a voxel boundary goes to the voxel above it on each axis), the tet
/// follows [`kuhn_tet`]. `None` when that voxel is not in the grid. Every yarn
/// vertex of the grid's own yarns is found (its closed-cube voxels are all in
/// the grid, see [`super::voxelize`]).
pub fn locate(grid: &VoxelGrid, p: Vec3) -> Option<Location> {
    locate_grid(grid, grid.to_grid(p))
}

/// [`locate`] with the point already in grid coordinates.
pub(crate) fn locate_grid(grid: &VoxelGrid, g: Vec3) -> Option<Location> {
    let v = floor_voxel(g)?;
    let vi = grid.find(v)?;
    Some(location_in(vi, v, g))
}

/// Location of grid point `g` in voxel `v` (index `vi`), tet chosen from `g`'s
/// fractional coordinates clamped to the voxel.
fn location_in(vi: usize, v: [i32; 3], g: Vec3) -> Location {
    let f: Vec3 = std::array::from_fn(|k| g[k] - v[k] as f64);
    let q = kuhn_tet(std::array::from_fn(|k| f[k].clamp(0.0, 1.0)));
    Location {
        tet: (6 * vi + q) as u32,
        weights: kuhn_weights(q, f),
    }
}

/// Like [`locate_grid`], but when rounding puts `g` just outside the grid's
/// voxels (a tiny yarn piece next to a voxel face), falls back to the nearest
/// occupied voxel among the 27 around the floor voxel (L1 distance to the
/// cube; ties: first in (i, j, k) order). Used for yarn-piece midpoints.
pub(crate) fn locate_nearest(grid: &VoxelGrid, g: Vec3) -> Option<Location> {
    if let Some(l) = locate_grid(grid, g) {
        return Some(l);
    }
    let v = floor_voxel(g)?;
    let mut best: Option<(f64, usize, [i32; 3])> = None;
    for di in -1..=1 {
        for dj in -1..=1 {
            for dk in -1..=1 {
                let n = [v[0] + di, v[1] + dj, v[2] + dk];
                let Some(ni) = grid.find(n) else { continue };
                let d: f64 = (0..3)
                    .map(|k| {
                        let lo = n[k] as f64;
                        (lo - g[k]).max(0.0) + (g[k] - lo - 1.0).max(0.0)
                    })
                    .sum();
                if best.is_none_or(|(bd, _, _)| d < bd) {
                    best = Some((d, ni, n));
                }
            }
        }
    }
    best.map(|(_, ni, n)| location_in(ni, n, g))
}

/// The voxel `floor(g)`, `None` when outside the `i32` range (or NaN).
pub(crate) fn floor_voxel(g: Vec3) -> Option<[i32; 3]> {
    let mut v = [0i32; 3];
    for k in 0..3 {
        let f = g[k].floor();
        if !(f >= i32::MIN as f64 && f <= i32::MAX as f64) {
            return None;
        }
        v[k] = f as i32;
    }
    Some(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::TetMesh;

    fn unit_corner(c: usize) -> Vec3 {
        [(c & 1) as f64, ((c >> 1) & 1) as f64, ((c >> 2) & 1) as f64]
    }

    #[test]
    fn every_kuhn_tet_is_positive_with_volume_one_sixth() {
        let nodes: Vec<Vec3> = (0..8).map(unit_corner).collect();
        let tets = (0..6).map(|q| tet_corners(q).map(|c| c as u32)).collect();
        let mesh = TetMesh { nodes, tets };
        let mut total = 0.0;
        for t in 0..6 {
            let v = mesh.volume(t);
            assert!((v - 1.0 / 6.0).abs() < 1e-15, "tet {t}: volume {v}");
            total += v;
        }
        assert!((total - 1.0).abs() < 1e-14);
    }

    #[test]
    fn weights_reproduce_points_and_select_the_containing_tet() {
        let pts = [
            [0.7, 0.2, 0.4],
            [0.1, 0.9, 0.5],
            [0.3, 0.3, 0.8],
            [0.5, 0.5, 0.5],
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.25, 0.75, 0.75],
        ];
        for f in pts {
            let q = kuhn_tet(f);
            let w = kuhn_weights(q, f);
            let c = tet_corners(q);
            let mut p = [0.0; 3];
            for a in 0..4 {
                let x = unit_corner(c[a]);
                for k in 0..3 {
                    p[k] += w[a] * x[k];
                }
            }
            for k in 0..3 {
                assert!((p[k] - f[k]).abs() < 1e-15, "{f:?} -> {p:?}");
            }
            assert!(w.iter().all(|&x| (0.0..=1.0).contains(&x)), "{f:?}: {w:?}");
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            // Points strictly inside one tet are outside the others.
            if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] && f.iter().all(|x| *x > 0.0) {
                for o in (0..6).filter(|&o| o != q) {
                    assert!(kuhn_weights(o, f).iter().any(|&x| x < 0.0));
                }
            }
        }
    }

    #[test]
    fn tetrahedralize_one_voxel() {
        let grid = VoxelGrid {
            origin: [1.0, 2.0, 3.0],
            h: 0.5,
            voxels: vec![[0, 0, 0]],
        };
        let (mesh, tv) = tetrahedralize(&grid);
        assert_eq!(mesh.num_nodes(), 8);
        assert_eq!(mesh.num_tets(), 6);
        assert_eq!(tv, vec![0; 6]);
        assert_eq!(mesh.nodes[0], [1.0, 2.0, 3.0]);
        assert_eq!(mesh.nodes[7], [1.5, 2.5, 3.5]);
        for t in 0..6 {
            assert!((mesh.volume(t) - 0.125 / 6.0).abs() < 1e-15);
        }
    }

    #[test]
    fn locate_misses_absent_voxels_and_nearest_recovers() {
        let grid = VoxelGrid {
            origin: [0.0; 3],
            h: 1.0,
            voxels: vec![[0, 0, 0]],
        };
        assert!(locate(&grid, [1.0, 0.5, 0.5]).is_none());
        let l = locate_nearest(&grid, [1.0, 0.5, 0.5]).unwrap();
        assert_eq!(l.tet / 6, 0);
        assert!(l.weights.iter().all(|&w| w >= 0.0));
        assert!(locate(&grid, [f64::NAN, 0.0, 0.0]).is_none());
    }
}
