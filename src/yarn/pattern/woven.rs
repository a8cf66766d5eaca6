//! Single-layer wovens from a weave matrix (Leaf §4).
//!
//! Weft i runs along +X at y = i S, warp j along +Y at x = j S (S the yarn
//! spacing). At the crossing of weft i and warp j the upper yarn sits at
//! z = +A and the lower at z = -A (A the crimp amplitude): weft on top where
//! `rows[i][j]` is true. Between crossings z is cosine-eased, so each yarn is
//! a smooth sinusoid-like crimp wave, flat at the crossings, and a vertex sits
//! exactly on every crossing so that the polyline keeps the full 2A clearance.

use super::curve::ease;
use super::types::{PatternParams, PatternTile, WeaveMatrix};
use crate::geom::{Vec3, Yarns};
use crate::yarn::PeriodicTile;

/// One repeat of a weave as a periodic tile: wefts first (curves
/// `0..rows`), then warps (`rows..rows + cols`).
pub fn woven_tile(m: &WeaveMatrix, params: &PatternParams) -> PatternTile {
    let r = params.yarn_radius;
    let s = params.woven.spacing * r;
    let amp = params.woven.crimp * r;
    let rows = m.rows.len();
    let cols = m.rows[0].len();
    // Vertices per spacing interval; at least 2 so the crimp has a middle point.
    let per = ((params.woven.spacing / params.spacing).ceil() as usize).max(2);
    let mut yarns = Yarns::new();
    let wave = |zs: &[f64], k: usize| -> f64 {
        let (i, f) = (k / per, (k % per) as f64 / per as f64);
        ease(zs[i % zs.len()], zs[(i + 1) % zs.len()], f)
    };
    for (i, row) in m.rows.iter().enumerate() {
        let zs: Vec<f64> = row
            .iter()
            .map(|&over| if over { amp } else { -amp })
            .collect();
        let pts: Vec<Vec3> = (0..cols * per)
            .map(|k| [k as f64 * s / per as f64, i as f64 * s, wave(&zs, k)])
            .collect();
        yarns.push_curve(&pts, false, r);
    }
    for j in 0..cols {
        let zs: Vec<f64> = m
            .rows
            .iter()
            .map(|row| if row[j] { -amp } else { amp })
            .collect();
        let pts: Vec<Vec3> = (0..rows * per)
            .map(|k| [j as f64 * s, k as f64 * s / per as f64, wave(&zs, k)])
            .collect();
        yarns.push_curve(&pts, false, r);
    }
    let next = (0..rows)
        .map(|i| (i, [1, 0]))
        .chain((0..cols).map(|j| (rows + j, [0, 1])))
        .collect();
    PatternTile {
        tile: PeriodicTile {
            yarns,
            lattice: [[cols as f64 * s, 0.0, 0.0], [0.0, rows as f64 * s, 0.0]],
            next,
        },
        axis: std::iter::repeat_n(0u8, rows)
            .chain(std::iter::repeat_n(1u8, cols))
            .collect(),
        lane: (0..rows).chain(0..cols).collect(),
        repeat: [cols, rows],
        pitch: [s, s],
        radius: r,
        seam: 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_weave_alternates() {
        let m = WeaveMatrix {
            rows: vec![vec![true, false], vec![false, true]],
        };
        let p = PatternParams::default();
        let t = woven_tile(&m, &p);
        t.tile.validate().unwrap();
        let a = p.woven.crimp * p.yarn_radius;
        let per = t.tile.yarns.curve(0).len() / 2;
        // Weft 0 is over warp 0 and under warp 1; warp 0 is under weft 0.
        assert_eq!(t.tile.yarns.curve(0)[0][2], a);
        assert_eq!(t.tile.yarns.curve(0)[per][2], -a);
        assert_eq!(t.tile.yarns.curve(2)[0][2], -a);
    }
}
