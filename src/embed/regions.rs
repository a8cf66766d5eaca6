//! Regions of a garment's tets from labels on its yarn vertices: which
//! material card each tet takes (`embed --card`, per curve, per box, per
//! vertex label). A voxel takes the label most of its yarn vertices carry
//! (ties to the lower label), and its tets with it; a voxel no vertex lies
//! in (a segment crosses it) takes the vote of its neighbourhood, widened
//! until it holds a vertex. [`fabric_area`] measures the fabric a set of
//! voxels holds. Pure: no files, no printing.

use crate::geom::vec3::{dot, norm};
use crate::geom::{Embedding, VoxelGrid};

/// Widest neighbourhood (Chebyshev radius, voxels) searched for a vote;
/// beyond it a voxel keeps label 0.
const MAX_RADIUS: i32 = 6;

/// The label of each tet (`tet_voxel[t]`: its voxel in `grid.voxels`) from
/// the labels of the yarn vertices (`vertex_label[v] < labels`) embedded in
/// it; `fallback` where no vertex lies within reach.
pub fn tet_labels(
    grid: &VoxelGrid,
    tet_voxel: &[u32],
    embedding: &Embedding,
    vertex_label: &[u16],
    labels: usize,
    fallback: u16,
) -> Vec<u16> {
    let nv = grid.voxels.len();
    let labels = labels.max(1);
    let mut votes = vec![0u32; nv * labels];
    for (v, &t) in embedding.tet.iter().enumerate() {
        let (Some(&vox), Some(&l)) = (tet_voxel.get(t as usize), vertex_label.get(v)) else {
            continue;
        };
        if (l as usize) < labels && (vox as usize) < nv {
            votes[vox as usize * labels + l as usize] += 1;
        }
    }
    let winner = |tally: &[u32]| -> Option<u16> {
        let (best, &n) = tally.iter().enumerate().rev().max_by_key(|&(_, n)| *n)?;
        (n > 0).then_some(best as u16)
    };
    let voxel_label: Vec<u16> = (0..nv)
        .map(|i| {
            if let Some(l) = winner(&votes[i * labels..(i + 1) * labels]) {
                return l;
            }
            let c = grid.voxels[i];
            for r in 1..=MAX_RADIUS {
                let mut tally = vec![0u32; labels];
                for dx in -r..=r {
                    for dy in -r..=r {
                        for dz in -r..=r {
                            if let Some(j) = grid.find([c[0] + dx, c[1] + dy, c[2] + dz]) {
                                for (k, t) in tally.iter_mut().enumerate() {
                                    *t += votes[j * labels + k];
                                }
                            }
                        }
                    }
                }
                if let Some(l) = winner(&tally) {
                    return l;
                }
            }
            fallback
        })
        .collect();
    tet_voxel
        .iter()
        .map(|&v| voxel_label.get(v as usize).copied().unwrap_or(0))
        .collect()
}

/// The fabric area (m²) of the voxels of `grid` whose tets have `in_set`,
/// each voxel's fabric normal `normal[t]` taken from its tets: half the
/// voxel set's boundary, each boundary face (edge `h`, axis normal `e`)
/// counted as `h² |n · e|`, its share of the sheet's projection onto its
/// own normal, after closing the set by one voxel. A sheet of voxels any
/// number of layers thick, at any tilt to the grid's axes, counts its area
/// once from each side, so halving gives its area; the sheet's rim (faces
/// across the fabric) adds nothing.
pub fn fabric_area(
    grid: &VoxelGrid,
    tet_voxel: &[u32],
    normal: &[[f64; 3]],
    in_set: &[bool],
) -> f64 {
    let nv = grid.voxels.len();
    let mut member = vec![false; nv];
    let mut n = vec![[0.0f64; 3]; nv];
    for (t, &v) in tet_voxel.iter().enumerate() {
        let v = v as usize;
        if v < nv && in_set.get(t).copied().unwrap_or(false) {
            member[v] = true;
            if let Some(d) = normal.get(t) {
                // Normals are signless: align with the voxel's first.
                let s = if dot(n[v], *d) < 0.0 { -1.0 } else { 1.0 };
                for k in 0..3 {
                    n[v][k] += s * d[k];
                }
            }
        }
    }
    // Closing (dilate, then erode, by one voxel, 26-connected) fills the
    // gaps between loops that a voxel much finer than the fabric's
    // thickness leaves, which would count as boundary; a sheet with no
    // gaps is unchanged.
    let members: std::collections::HashSet<[i32; 3]> = grid
        .voxels
        .iter()
        .enumerate()
        .filter(|&(i, _)| member[i])
        .map(|(_, c)| *c)
        .collect();
    let around = |c: [i32; 3]| {
        (-1..=1).flat_map(move |dx| {
            (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| [c[0] + dx, c[1] + dy, c[2] + dz]))
        })
    };
    let dilated: std::collections::HashSet<[i32; 3]> =
        members.iter().flat_map(|&c| around(c)).collect();
    let closed: std::collections::HashSet<[i32; 3]> = dilated
        .iter()
        .copied()
        .filter(|&c| members.contains(&c) || around(c).all(|d| dilated.contains(&d)))
        .collect();
    // A voxel's normal: its own, else its members' around it.
    let own = |c: [i32; 3]| grid.find(c).filter(|&j| member[j]).map(|j| n[j]);
    let normal_at = |c: [i32; 3]| -> Option<[f64; 3]> {
        let mut m = own(c).unwrap_or_else(|| {
            let mut acc = [0.0; 3];
            for d in around(c) {
                if let Some(v) = own(d) {
                    let s = if dot(acc, v) < 0.0 { -1.0 } else { 1.0 };
                    for k in 0..3 {
                        acc[k] += s * v[k];
                    }
                }
            }
            acc
        });
        let len = norm(m);
        (len > 0.0).then(|| {
            m.iter_mut().for_each(|x| *x /= len);
            m
        })
    };
    let h2 = grid.h * grid.h;
    let mut area = 0.0;
    for &c in &closed {
        let Some(nc) = normal_at(c) else { continue };
        for axis in 0..3 {
            for step in [-1, 1] {
                let mut d = c;
                d[axis] += step;
                if !closed.contains(&d) {
                    area += h2 * nc[axis].abs();
                }
            }
        }
    }
    0.5 * area
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat sheet of `a x b` voxels, `layers` thick, tilted into a
    /// staircase rising one voxel every `rise` voxels along x.
    fn sheet(a: i32, b: i32, layers: i32, rise: i32) -> VoxelGrid {
        let mut voxels = Vec::new();
        for i in 0..a {
            for k in 0..b {
                for l in 0..layers {
                    voxels.push([i, l + if rise > 0 { i / rise } else { 0 }, k]);
                }
            }
        }
        voxels.sort();
        VoxelGrid {
            origin: [0.0; 3],
            h: 0.5,
            voxels,
        }
    }

    #[test]
    fn fabric_area_counts_a_sheet_once_at_any_thickness_and_tilt() {
        for (layers, rise) in [(1, 0), (3, 0), (2, 1), (3, 2)] {
            let g = sheet(40, 30, layers, rise);
            let tet_voxel: Vec<u32> = (0..g.voxels.len() as u32).collect();
            let n = if rise > 0 {
                let t = 1.0 / rise as f64;
                let l = (1.0 + t * t).sqrt();
                [-t / l, 1.0 / l, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let normals = vec![n; g.voxels.len()];
            let area = fabric_area(&g, &tet_voxel, &normals, &vec![true; g.voxels.len()]);
            // The true sheet: 40 x 30 voxels, stretched by the tilt.
            let tilt = if rise > 0 {
                (1.0 + 1.0 / (rise * rise) as f64).sqrt()
            } else {
                1.0
            };
            let want = 0.25 * 40.0 * 30.0 * tilt;
            // The staircase's ends and the rim are the error: a few percent.
            assert!(
                (area / want - 1.0).abs() < 0.06,
                "layers {layers}, rise {rise}: {area} vs {want}"
            );
        }
    }

    #[test]
    fn a_voxel_takes_its_vertices_majority_and_an_empty_one_its_neighbours() {
        let grid = VoxelGrid {
            origin: [0.0; 3],
            h: 1.0,
            voxels: vec![[0, 0, 0], [1, 0, 0], [2, 0, 0], [9, 0, 0]],
        };
        // Two tets per voxel.
        let tet_voxel = vec![0, 0, 1, 1, 2, 2, 3, 3];
        // Voxel 0: labels 1, 1, 0; voxel 1: none; voxel 2: label 0; voxel 3: far, none.
        let embedding = Embedding {
            tet: vec![0, 1, 1, 4],
            weights: vec![[0.25; 4]; 4],
        };
        let labels = tet_labels(&grid, &tet_voxel, &embedding, &[1, 1, 0, 0], 2, 0);
        // Voxel 1's neighbourhood (voxels 0 and 2) votes two 1s and two
        // 0s: a tie goes to the lower label. Voxel 3 finds no vote: 0.
        assert_eq!(labels, vec![1, 1, 0, 0, 0, 0, 0, 0]);
        // Three 1s against one 0: voxel 1 takes 1.
        let labels = tet_labels(&grid, &tet_voxel, &embedding, &[1, 1, 1, 0], 2, 1);
        // ... and voxel 3, out of reach, the fallback.
        assert_eq!(labels, vec![1, 1, 1, 1, 0, 0, 1, 1]);
    }
}
