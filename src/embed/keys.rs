//! Integer grid cells as sortable keys.
//!
//! A cell `(i, j, k)` (voxel or corner) packs into a `u128` whose unsigned
//! order is the lexicographic `(i, j, k)` order (each `i32` with its sign bit
//! flipped takes 32 bits), so sorting keys sorts cells the way [`VoxelGrid`]
//! requires, for any `i32` indices.
//!
//! [`VoxelGrid`]: crate::geom::VoxelGrid

use rayon::prelude::*;

const SIGN: u32 = 0x8000_0000;

/// Order-preserving key of cell `c`.
pub(crate) fn corner_key(c: [i32; 3]) -> u128 {
    let u = c.map(|x| (x as u32 ^ SIGN) as u128);
    (u[0] << 64) | (u[1] << 32) | u[2]
}

/// Inverse of [`corner_key`].
pub(crate) fn key_cell(key: u128) -> [i32; 3] {
    let part = |s: u32| ((key >> s) as u32 ^ SIGN) as i32;
    [part(64), part(32), part(0)]
}

/// Sorts keys and removes duplicates (parallel sort; the result is the same
/// for any thread count because equal keys are identical).
pub(crate) fn sort_dedup(keys: &mut Vec<u128>) {
    keys.par_sort_unstable();
    keys.dedup();
}

/// Keys of the 8 corners of each voxel, unique and sorted.
pub(crate) fn unique_corner_keys(voxels: &[[i32; 3]]) -> Vec<u128> {
    let mut keys: Vec<u128> = voxels
        .par_iter()
        .flat_map_iter(|&v| {
            (0..8).map(move |c| {
                corner_key([v[0] + (c & 1), v[1] + ((c >> 1) & 1), v[2] + ((c >> 2) & 1)])
            })
        })
        .collect();
    sort_dedup(&mut keys);
    keys
}

/// The unique corners of the voxels, sorted by `(i, j, k)`.
pub(crate) fn unique_corners(voxels: &[[i32; 3]]) -> Vec<[i32; 3]> {
    unique_corner_keys(voxels)
        .into_iter()
        .map(key_cell)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_preserve_lexicographic_order() {
        let mut cells = vec![
            [0, 0, 0],
            [-1, 5, 2],
            [i32::MIN, 0, 0],
            [i32::MAX - 1, -3, 7],
            [0, -1, 0],
            [0, 0, -1],
            [3, 3, 3],
        ];
        let mut keys: Vec<u128> = cells.iter().map(|&c| corner_key(c)).collect();
        keys.sort();
        cells.sort();
        let back: Vec<[i32; 3]> = keys.iter().map(|&k| key_cell(k)).collect();
        assert_eq!(back, cells);
    }

    #[test]
    fn two_voxels_share_four_corners() {
        let c = unique_corners(&[[0, 0, 0], [1, 0, 0]]);
        assert_eq!(c.len(), 12);
        assert!(c.windows(2).all(|w| w[0] < w[1]));
    }
}
