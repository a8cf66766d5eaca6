//! The default voxel size: about `target_node_ratio` x yarn vertices nodes.

use super::keys::{key_cell, unique_corner_keys};
use super::voxelize::{check_yarns, Prepared};
use super::{EmbedError, EmbedParams};
use crate::geom::{dist, VoxelGrid, Yarns};

/// Evaluations of the node count at most (each is one voxelization).
const MAX_EVALS: usize = 6;
/// Stop once the node count is within this factor (log) of the target (~2 %).
const LOG_TOLERANCE: f64 = 0.02;

/// One evaluated voxel size.
struct Trial {
    h: f64,
    /// Node count (unique voxel corners) at `h`.
    nodes: usize,
    grid: VoxelGrid,
    extra: usize,
}

/// A chosen voxel size with the grid built at it.
pub(crate) struct Chosen {
    pub h: f64,
    pub rule: String,
    pub grid: VoxelGrid,
    pub extra: usize,
}

/// The default voxel size (m) and a description of how it was chosen.
///
/// Rule: VH §4 reports meshes with about half as many nodes as yarn vertices,
/// so the target is `N* = max(8, target_node_ratio x yarn vertices)` nodes
/// (unique voxel corners, default grid origin). Starting from `h0 = 2 x` the
/// mean segment length (4 x the largest radius if every segment has zero
/// length), the node count `n(h)` is evaluated at `h0` and `1.5 h0` (or
/// `h0 / 1.5`, towards the target), then secant steps in log-log
/// (`log h += (log N* - log n) / s` with the slope `s` of the last two
/// evaluations, clamped to `[-3, -0.5]`, each step at most a factor 4) until
/// `n` is within 2 % of `N*` or 6 evaluations are done; the evaluated `h`
/// closest to the target (in `|log(n / N*)|`, first on ties) wins. Sizes with
/// more than `max_voxels` voxels, or whose walk and yarn pieces would take
/// more than `max_memory` (estimated before allocating), count as "too many
/// nodes". Deterministic.
pub fn default_voxel_size(
    yarns: &Yarns,
    params: &EmbedParams,
) -> Result<(f64, String), EmbedError> {
    choose(yarns, params).map(|c| (c.h, c.rule))
}

/// [`default_voxel_size`], also returning the grid at the chosen size.
pub(crate) fn choose(yarns: &Yarns, params: &EmbedParams) -> Result<Chosen, EmbedError> {
    check_yarns(yarns)?;
    let ratio = params.target_node_ratio;
    if !(ratio.is_finite() && ratio > 0.0) {
        return Err(EmbedError::Parameter(format!(
            "target_node_ratio {} must be a positive finite number",
            crate::geom::num(ratio)
        )));
    }
    let target = (ratio * yarns.num_points() as f64).max(8.0);
    let h0 = start_size(yarns);
    let mut trials: Vec<Trial> = Vec::new();
    let mut h = h0;
    // First evaluation; sizes too fine for max_voxels double until one fits.
    for _ in 0..64 {
        match evaluate(yarns, h, params)? {
            Some(t) => {
                trials.push(t);
                break;
            }
            None => h *= 2.0,
        }
    }
    let Some(first) = trials.first() else {
        return Err(EmbedError::TooManyVoxels {
            h,
            estimate: u64::MAX,
            limit: params.max_voxels,
        });
    };
    let mut next = if (first.nodes as f64) < target {
        first.h / 1.5
    } else {
        first.h * 1.5
    };
    while trials.len() < MAX_EVALS {
        let Some(t) = evaluate(yarns, next, params)? else {
            break; // finer than max_voxels allows: keep what we have
        };
        trials.push(t);
        let [p, q] = [&trials[trials.len() - 2], &trials[trials.len() - 1]];
        if miss(q.nodes, target) < LOG_TOLERANCE {
            break;
        }
        let slope = if p.nodes == q.nodes || p.h == q.h {
            -0.5
        } else {
            ((q.nodes as f64).ln() - (p.nodes as f64).ln()) / (q.h.ln() - p.h.ln())
        };
        let slope = slope.clamp(-3.0, -0.5);
        let jump = ((target.ln() - (q.nodes as f64).ln()) / slope).clamp(-4f64.ln(), 4f64.ln());
        next = q.h * jump.exp();
    }
    let evals = trials.len();
    let best = trials
        .into_iter()
        .reduce(|b, t| {
            if miss(t.nodes, target) < miss(b.nodes, target) {
                t
            } else {
                b
            }
        })
        .expect("at least one trial");
    let rule = format!(
        "default: about {ratio} x {} yarn vertices = {target:.0} nodes (VH §4: n_V ~ n_Y/2); \
         log-log secant from 2 x mean segment length ({h0:.6e} m), {evals} evaluations; \
         {} nodes at h = {:.6e} m",
        yarns.num_points(),
        best.nodes,
        best.h
    );
    Ok(Chosen {
        h: best.h,
        rule,
        grid: best.grid,
        extra: best.extra,
    })
}

/// `|log(nodes / target)|`.
fn miss(nodes: usize, target: f64) -> f64 {
    ((nodes as f64).ln() - target.ln()).abs()
}

/// 2 x the mean segment length, or 4 x the largest radius when all segments
/// have zero length.
fn start_size(yarns: &Yarns) -> f64 {
    let (sum, n) = yarns.segments().fold((0.0, 0usize), |(s, n), [a, b]| {
        (s + dist(yarns.points[a], yarns.points[b]), n + 1)
    });
    let mean = if n > 0 { sum / n as f64 } else { 0.0 };
    if mean > 0.0 && mean.is_finite() {
        2.0 * mean
    } else {
        let r = yarns.radius.iter().copied().fold(0.0, f64::max);
        let r = yarns
            .vertex_radius
            .iter()
            .flatten()
            .copied()
            .fold(r, f64::max);
        4.0 * r
    }
}

/// Voxelizes at `h` (default origin) and counts nodes; `None` when there are
/// more than `max_voxels` voxels.
fn evaluate(yarns: &Yarns, h: f64, params: &EmbedParams) -> Result<Option<Trial>, EmbedError> {
    let max_voxels = params.max_voxels;
    let prep = match Prepared::new(yarns, h, None) {
        Ok(p) => p,
        // A grid wider than 2^30 voxels: far too fine, like a bound overflow.
        Err(EmbedError::GridTooWide { .. }) => return Ok(None),
        Err(e) => return Err(e),
    };
    // Too many pieces or walk entries for the memory budget (many yarns
    // over the same voxels): too fine, like too many voxels.
    if prep.work(max_voxels).bytes > params.max_memory {
        return Ok(None);
    }
    let (keys, extra) = match prep.voxels_capped(max_voxels) {
        Ok(v) => v,
        Err(EmbedError::TooManyVoxels { .. }) => return Ok(None),
        Err(e) => return Err(e),
    };
    let voxels: Vec<[i32; 3]> = keys.into_iter().map(key_cell).collect();
    let nodes = unique_corner_keys(&voxels).len();
    Ok(Some(Trial {
        h,
        nodes,
        grid: VoxelGrid {
            voxels,
            ..prep.grid
        },
        extra,
    }))
}
