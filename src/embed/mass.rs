//! Yarn pieces (segments split at tet boundaries) and lumped node masses
//! (VH Eq. 1-3).
//!
//! VH Eq. 2 lumps `m_i = sum_j L_j int_0^1 N_i(x_j(t)) rho_j dt` over the yarn
//! segments `j` in a tet. The shape functions `N_i` are linear inside one tet,
//! so on a straight piece lying in one tet the integral is exact with the
//! trapezoid rule: `lambda L_piece (N_i(start) + N_i(end)) / 2`. Splitting each
//! segment at every tet boundary crossed (the planes `x`, `y`, `z`, `x - y`,
//! `y - z`, `x - z` = integer in grid units for the Kuhn split) makes every piece
//! lie in one tet. Since `sum_i N_i = 1`, the node masses add up to the yarn
//! mass `sum_j lambda_j L_j`.

use super::tetrahedralize::{kuhn_weights, locate_nearest};
use super::EmbedError;
use crate::geom::vec3::dot;
use crate::geom::{Vec3, VoxelGrid, YarnPiece};
use rayon::prelude::*;

/// The linear forms whose integer level sets bound the Kuhn tets.
pub(crate) const FORMS: [[f64; 3]; 6] = [
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, -1.0, 0.0],
    [0.0, 1.0, -1.0],
    [1.0, 0.0, -1.0],
];

/// Segments per parallel work item (output concatenated in order).
const CHUNK: usize = 2048;

/// A yarn piece with the mean of its two end weights in its tet (stored node
/// order): `N_i` averaged over the piece, VH Eq. 2 by the trapezoid rule.
pub(crate) struct Piece {
    pub piece: YarnPiece,
    pub mean_weights: [f64; 4],
}

/// Splits every segment (`g`: points in grid coordinates, `lengths`: segment
/// lengths in metres) into pieces, each in one tet of `grid`'s mesh.
pub(crate) fn split_segments(
    grid: &VoxelGrid,
    g: &[Vec3],
    segments: &[[usize; 2]],
    lengths: &[f64],
) -> Result<Vec<Piece>, EmbedError> {
    let parts: Vec<Result<Vec<Piece>, EmbedError>> = segments
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut out = Vec::with_capacity(chunk.len() * 4);
            let mut ts = Vec::new();
            for (i, &[a, b]) in chunk.iter().enumerate() {
                let s = c * CHUNK + i;
                split_one(grid, s, g[a], g[b], lengths[s], &mut ts, &mut out)?;
            }
            Ok(out)
        })
        .collect();
    let mut pieces = Vec::new();
    for p in parts {
        pieces.extend(p?);
    }
    Ok(pieces)
}

/// Splits segment `s` from `a` to `b` (grid coordinates), `length` metres long.
fn split_one(
    grid: &VoxelGrid,
    s: usize,
    a: Vec3,
    b: Vec3,
    length: f64,
    ts: &mut Vec<f64>,
    out: &mut Vec<Piece>,
) -> Result<(), EmbedError> {
    ts.clear();
    ts.extend([0.0, 1.0]);
    for form in FORMS {
        let ga = dot(form, a);
        let gb = dot(form, b);
        let (lo, hi) = if ga < gb { (ga, gb) } else { (gb, ga) };
        // Integers strictly between the two ends (none when equal).
        let mut n = lo.floor() + 1.0;
        while n < hi {
            ts.push(((n - ga) / (gb - ga)).clamp(0.0, 1.0));
            n += 1.0;
        }
    }
    ts.sort_unstable_by(f64::total_cmp);
    ts.dedup();
    let at = |t: f64| -> Vec3 { std::array::from_fn(|k| a[k] + t * (b[k] - a[k])) };
    // `ts` holds 0 and 1, so a zero-length segment still gets one (empty)
    // piece, with a tet.
    for w in ts.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        let mid = at(0.5 * (t0 + t1));
        let loc = locate_nearest(grid, mid).ok_or_else(|| {
            EmbedError::Internal(format!(
                "piece [{t0}, {t1}] of segment {s} (grid point {mid:?}) lies in no voxel"
            ))
        })?;
        let v = grid.voxels[loc.tet as usize / 6];
        let q = loc.tet as usize % 6;
        let w0 = clamped_weights(q, v, at(t0));
        let w1 = clamped_weights(q, v, at(t1));
        out.push(Piece {
            piece: YarnPiece {
                segment: s as u32,
                tet: loc.tet,
                t0,
                t1,
                length: (t1 - t0) * length,
            },
            mean_weights: std::array::from_fn(|i| 0.5 * (w0[i] + w1[i])),
        });
    }
    Ok(())
}

/// Weights of grid point `p` in tet `q` of voxel `v`, with rounding noise
/// (a piece end on a tet face can come out at -1e-17) clamped to 0 and the
/// weights renormalized, so lumped masses are never negative.
fn clamped_weights(q: usize, v: [i32; 3], p: Vec3) -> [f64; 4] {
    let f: Vec3 = std::array::from_fn(|k| p[k] - v[k] as f64);
    let w = kuhn_weights(q, f).map(|x| x.clamp(0.0, 1.0));
    let sum: f64 = w.iter().sum();
    if sum > 0.0 {
        w.map(|x| x / sum)
    } else {
        [0.25; 4]
    }
}

/// Lumped node masses (VH Eq. 2): `m_i = sum over pieces of lambda L_piece
/// mean N_i`, accumulated in piece order (deterministic). `lambda[s]` is the
/// linear density (kg/m) of segment `s`.
pub(crate) fn lump_masses(
    tets: &[[u32; 4]],
    num_nodes: usize,
    pieces: &[Piece],
    lambda: &[f64],
) -> Vec<f64> {
    let mut mass = vec![0.0; num_nodes];
    for p in pieces {
        let m = lambda[p.piece.segment as usize] * p.piece.length;
        let ids = tets[p.piece.tet as usize];
        for a in 0..4 {
            mass[ids[a] as usize] += m * p.mean_weights[a];
        }
    }
    mass
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_row(n: i32) -> VoxelGrid {
        VoxelGrid {
            origin: [0.0; 3],
            h: 1.0,
            voxels: (0..n).map(|i| [i, 0, 0]).collect(),
        }
    }

    #[test]
    fn straight_segment_splits_at_every_tet_boundary() {
        let grid = grid_row(2);
        let (a, b) = ([0.1, 0.5, 0.3], [1.9, 0.6, 0.35]);
        let mut ts = Vec::new();
        let mut out = Vec::new();
        split_one(&grid, 0, a, b, 2.0, &mut ts, &mut out).unwrap();
        // x crosses 1; x - y crosses 0 and 1; x - z crosses 0 and 1.
        assert_eq!(out.len(), 6);
        assert_eq!(out[0].piece.t0, 0.0);
        assert_eq!(out.last().unwrap().piece.t1, 1.0);
        for w in out.windows(2) {
            assert_eq!(w[0].piece.t1, w[1].piece.t0);
            assert_ne!(w[0].piece.tet, w[1].piece.tet);
        }
        let total: f64 = out.iter().map(|p| p.piece.length).sum();
        assert!((total - 2.0).abs() < 1e-14);
    }

    #[test]
    fn masses_sum_to_yarn_mass() {
        let grid = grid_row(2);
        let mut ts = Vec::new();
        let mut out = Vec::new();
        split_one(
            &grid,
            0,
            [0.2, 0.7, 0.1],
            [1.8, 0.2, 0.9],
            3.0,
            &mut ts,
            &mut out,
        )
        .unwrap();
        let (mesh, _) = super::super::tetrahedralize(&grid);
        let m = lump_masses(&mesh.tets, mesh.num_nodes(), &out, &[0.5]);
        let total: f64 = m.iter().sum();
        assert!((total - 1.5).abs() < 1e-14, "{total}");
        assert!(m.iter().all(|&x| x >= 0.0));
    }
}
