//! Voxelization (VH §4): the exact 3D supercover of the yarn segments.
//!
//! A voxel is kept when its CLOSED cube meets a yarn segment. Each segment is
//! walked in grid coordinates like a 3D DDA (Amanatides-Woo): the crossings of
//! the planes `x = n`, `y = n`, `z = n` are sorted by their parameter `t`, and
//! the "open" voxel holding each piece between crossings steps by one index on
//! the crossed axis, so every yarn's voxels are face-connected by construction.
//! At every crossing point (the crossed coordinate set exactly to its integer,
//! so a segment through an edge or corner gives exactly equal `t` values and
//! exact integers) and at both endpoints, every voxel whose closed cube holds
//! the point is added too: on each axis where the coordinate is an integer both
//! neighbours, else the floor. This adds the voxels VH §4 includes "where the
//! thread passes through a voxel corner" (and edge or face): the 4 voxels
//! around an edge, the 8 around a corner, both sides of a face a segment runs
//! along. Their number beyond the open-voxel walk is reported as the extra
//! voxels.

use super::keys::{corner_key, key_cell, sort_dedup};
use super::EmbedError;
use crate::geom::{Vec3, VoxelGrid, Yarns};
use rayon::prelude::*;

/// Grid indices must stay within this magnitude so corner indices (`+1`) and
/// neighbour searches never overflow `i32`.
const MAX_INDEX: f64 = (1u64 << 30) as f64;

/// Segments per parallel work item (the output is concatenated in segment
/// order, so results do not depend on the thread count).
const CHUNK: usize = 2048;

/// The default grid origin for voxel size `h`: the yarn bounding-box minimum
/// minus half a voxel on each axis (deterministic, and keeps the lowest yarn
/// point off a grid plane).
pub fn default_origin(yarns: &Yarns, h: f64) -> Option<Vec3> {
    let b = yarns.bounds()?;
    Some(b.min.map(|m| m - 0.5 * h))
}

/// Voxelizes the yarns (m) with voxel size `h` (m): the exact closed-cube
/// supercover of every segment (closed curves include their closing segment).
/// `origin` defaults to [`default_origin`]. Returns the grid and the number of
/// extra voxels (kept only for closed-cube contacts at edges, corners or faces).
///
/// Errors: `Empty` (no curves or points), `Yarns` (invalid yarns),
/// `BadVoxelSize` (`h` not positive and finite), `Parameter` (non-finite
/// origin, or a grid wider than 2^30 voxels), `TooManyVoxels` when the
/// supercover has more than `max_voxels` unique voxels (counted in bounded
/// memory, see [`Prepared::voxels_capped`]).
pub fn voxelize(
    yarns: &Yarns,
    h: f64,
    origin: Option<Vec3>,
    max_voxels: u64,
) -> Result<(VoxelGrid, usize), EmbedError> {
    let prep = Prepared::new(yarns, h, origin)?;
    let (voxels, extra) = prep.voxels_capped(max_voxels)?;
    let grid = VoxelGrid {
        voxels: voxels.into_iter().map(key_cell).collect(),
        ..prep.grid
    };
    Ok((grid, extra))
}

/// Validated input of a voxelization: the (empty) grid frame, the yarn points
/// in grid coordinates and the segments.
pub(crate) struct Prepared {
    pub grid: VoxelGrid,
    pub g: Vec<Vec3>,
    pub segments: Vec<[usize; 2]>,
    /// A lower bound of the unique voxels: the most any one curve needs (see
    /// [`curve_min_voxels`]), counted from the points alone.
    pub min_voxels: f64,
}

/// Walk entries per batch at most when the whole walk does not fit at once:
/// keeps the walk's scratch memory bounded whatever the segments.
const BATCH_ENTRIES: u64 = 1 << 24;

/// Bytes of one walk entry while a batch is walked, sorted and merged (the
/// key, its copy in the concatenated batch, and the merge output).
const WALK_ENTRY_BYTES: u64 = 48;

/// Bytes of one yarn piece while the segments are split: the piece with its
/// weights (64) and spare vector capacity (measured: 200K segments cut into
/// 28M pieces peak at 2.0 GB in all, about 70 bytes a piece).
const PIECE_BYTES: u64 = 128;

/// What an embedding at this voxel size will cost, estimated from the
/// segments before anything is allocated.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Work {
    /// Yarn pieces at most (every segment split at every tet boundary).
    pub pieces: u64,
    /// Peak memory (bytes) of the walk or of the pieces, whichever is larger.
    pub bytes: u64,
}

impl Prepared {
    /// Validates the inputs and maps the points to grid coordinates.
    pub fn new(yarns: &Yarns, h: f64, origin: Option<Vec3>) -> Result<Prepared, EmbedError> {
        check_yarns(yarns)?;
        if !(h.is_finite() && h > 0.0) {
            return Err(EmbedError::BadVoxelSize(h));
        }
        let origin = match origin {
            Some(o) => o,
            None => default_origin(yarns, h).ok_or(EmbedError::Empty)?,
        };
        if !origin.iter().all(|x| x.is_finite()) {
            return Err(EmbedError::Parameter(format!(
                "grid origin {origin:?} is not finite"
            )));
        }
        let grid = VoxelGrid {
            origin,
            h,
            voxels: Vec::new(),
        };
        let g: Vec<Vec3> = yarns.points.par_iter().map(|&p| grid.to_grid(p)).collect();
        if let Some(bad) = g.iter().find(|p| !p.iter().all(|x| x.abs() < MAX_INDEX)) {
            let far = bad.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            return Err(EmbedError::GridTooWide { h, voxels: far });
        }
        let segments = yarns.segments().collect();
        let min_voxels = curve_min_voxels(yarns, &g);
        Ok(Prepared {
            grid,
            g,
            segments,
            min_voxels,
        })
    }

    /// The work of embedding at this size: an upper bound of the yarn
    /// pieces (per segment one plus the integers strictly between its ends
    /// on each of the six Kuhn forms, as `mass::split_segments` cuts) and
    /// the peak memory of the walk or the pieces. Counts only, saturating.
    pub fn work(&self, max_voxels: u64) -> Work {
        let (pieces, biggest) = self
            .segments
            .par_iter()
            .map(|&[a, b]| (self.segment_pieces(a, b), self.segment_bound(a, b)))
            .reduce(|| (0, 0), |x, y| (x.0.saturating_add(y.0), x.1.max(y.1)));
        let total = self.voxel_bound();
        let batch = if total <= max_voxels {
            total
        } else {
            BATCH_ENTRIES.max(biggest).min(total)
        };
        // The running set of unique voxels is bounded by `max_voxels`, the
        // limit of its own that the mesh built from it needs anyway.
        let walk = batch.saturating_mul(WALK_ENTRY_BYTES);
        Work {
            pieces,
            bytes: walk.max(pieces.saturating_mul(PIECE_BYTES)),
        }
    }

    fn segment_pieces(&self, a: usize, b: usize) -> u64 {
        let dot = |f: [f64; 3], p: Vec3| f[0] * p[0] + f[1] * p[1] + f[2] * p[2];
        super::mass::FORMS
            .iter()
            .map(|&f| {
                let (x, y) = (dot(f, self.g[a]), dot(f, self.g[b]));
                let (lo, hi) = if x < y { (x, y) } else { (y, x) };
                // One more than the integers strictly between lo and hi.
                (hi.ceil() - lo.floor()).max(1.0) as u64
            })
            .fold(1u64, u64::saturating_add)
    }

    /// Upper bound of the voxel entries the walk produces: per segment
    /// `8 (C + 2)` with `C <= sum over axes of ceil(|delta|)` plane crossings
    /// (saturating, so the sum is the same in any order). Loose for dense
    /// garments (neighbouring segments share voxels), so it only selects the
    /// fast path; the limit itself is checked on the unique voxels.
    pub fn voxel_bound(&self) -> u64 {
        self.segments
            .par_iter()
            .map(|&[a, b]| self.segment_bound(a, b))
            .reduce(|| 0, u64::saturating_add)
    }

    fn segment_bound(&self, a: usize, b: usize) -> u64 {
        let c: u64 = (0..3)
            .map(|k| (self.g[b][k] - self.g[a][k]).abs().ceil() as u64)
            .fold(0u64, u64::saturating_add);
        c.saturating_add(2).saturating_mul(8)
    }

    /// The sorted unique voxel keys of the supercover and the count of extra
    /// (contact-only) voxels, or `TooManyVoxels` as soon as more than
    /// `max_voxels` unique voxels are found.
    ///
    /// When the per-segment bound fits, every chunk is walked at once (the
    /// entries cannot exceed the bound). Otherwise segments are walked in
    /// batches whose deduplicated keys are merged into the running set, and
    /// the walk stops once the set passes `max_voxels`: memory stays within a
    /// few times `max_voxels` keys whatever the garment size (a 1.5M-vertex garment at 4 mm has a 56.9M bound but 414K voxels).
    pub fn voxels_capped(&self, max_voxels: u64) -> Result<(Vec<u128>, usize), EmbedError> {
        let too_many = |estimate: u64| EmbedError::TooManyVoxels {
            h: self.grid.h,
            estimate,
            limit: max_voxels,
        };
        // One curve alone needs more voxels than allowed: no walk needed.
        if self.min_voxels > max_voxels as f64 {
            return Err(too_many(self.min_voxels.min(u64::MAX as f64) as u64));
        }
        let walk = |chunk: &[[usize; 2]]| {
            let mut out = Walk::default();
            for &[a, b] in chunk {
                out.segment(self.g[a], self.g[b]);
            }
            let mut open = out.open;
            let mut all = out.contact;
            all.extend_from_slice(&open);
            open.sort_unstable();
            open.dedup();
            all.sort_unstable();
            all.dedup();
            (open, all)
        };
        let batches = if self.voxel_bound() <= max_voxels {
            vec![0..self.segments.len()]
        } else {
            // Batches of at most BATCH_ENTRIES walk entries (a longer
            // segment alone is its own batch): enough to keep every thread
            // busy, few so the linear merges stay cheap, and the walk's
            // scratch stays bounded however many entries the segments make.
            let mut out = Vec::new();
            let (mut start, mut entries) = (0, 0u64);
            for (i, &[a, b]) in self.segments.iter().enumerate() {
                let e = self.segment_bound(a, b);
                if i > start && entries.saturating_add(e) > BATCH_ENTRIES {
                    out.push(start..i);
                    (start, entries) = (i, 0);
                }
                entries = entries.saturating_add(e);
            }
            out.push(start..self.segments.len());
            out
        };
        let mut open: Vec<u128> = Vec::new();
        let mut all: Vec<u128> = Vec::new();
        for range in batches {
            let segs = &self.segments[range];
            let parts: Vec<(Vec<u128>, Vec<u128>)> = segs.par_chunks(CHUNK).map(walk).collect();
            let mut bo: Vec<u128> = parts.iter().flat_map(|p| p.0.iter().copied()).collect();
            let mut ba: Vec<u128> = parts.into_iter().flat_map(|p| p.1).collect();
            sort_dedup(&mut bo);
            sort_dedup(&mut ba);
            open = merge_dedup(&open, &bo);
            all = merge_dedup(&all, &ba);
            if all.len() as u64 > max_voxels {
                return Err(too_many(all.len() as u64));
            }
        }
        let extra = all.len() - open.len();
        Ok((all, extra))
    }
}

/// The sorted union of two sorted, duplicate-free key lists.
fn merge_dedup(a: &[u128], b: &[u128]) -> Vec<u128> {
    if a.is_empty() {
        return b.to_vec();
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => {
                out.push(a[i]);
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                out.push(b[j]);
                j += 1;
            }
            std::cmp::Ordering::Equal => {
                out.push(a[i]);
                i += 1;
                j += 1;
            }
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// A lower bound of the unique voxels of the supercover: the most any one
/// curve needs. A curve's voxels are face-connected (the walk steps one axis
/// at a time, and the closed-cube contacts at a shared vertex join the
/// voxels of the two segments), so a curve whose voxels span `n_k + 1`
/// indices on axis `k` has at least `1 + n_0 + n_1 + n_2` voxels. Every
/// vertex is a segment end, whose closed-cube contacts include voxel
/// `ceil(x) - 1` and voxel `floor(x)` on each axis, so points from `lo` to
/// `hi` span at least `floor(hi) - ceil(lo) + 1` index steps. Counted from
/// the points before any walk, so an absurdly fine voxel size is refused at
/// once.
fn curve_min_voxels(yarns: &Yarns, g: &[Vec3]) -> f64 {
    (0..yarns.num_curves())
        .into_par_iter()
        .map(|c| {
            let pts = &g[yarns.curve_range(c)];
            let Some(first) = pts.first() else {
                return 0.0;
            };
            let (lo, hi) = pts.iter().fold((*first, *first), |(lo, hi), p| {
                (
                    std::array::from_fn(|k| lo[k].min(p[k])),
                    std::array::from_fn(|k| hi[k].max(p[k])),
                )
            });
            1.0 + (0..3)
                .map(|k| (hi[k].floor() - lo[k].ceil() + 1.0).max(0.0))
                .sum::<f64>()
        })
        .reduce(|| 0.0, f64::max)
}

/// `Empty` for no curves or no points, else the yarns' own validation.
pub(crate) fn check_yarns(yarns: &Yarns) -> Result<(), EmbedError> {
    if yarns.num_curves() == 0 || yarns.points.is_empty() {
        return Err(EmbedError::Empty);
    }
    yarns.validate()?;
    Ok(())
}

/// Voxel keys produced by walking segments.
#[derive(Default)]
struct Walk {
    /// Voxels holding a positive-length piece of a segment (the DDA walk).
    open: Vec<u128>,
    /// Voxels whose closed cube holds a crossing point or an endpoint.
    contact: Vec<u128>,
    /// Scratch: crossings `(t, axis, plane)` of the current segment.
    crossings: Vec<(f64, usize, f64)>,
}

impl Walk {
    /// Walks the segment `a -> b` (grid coordinates).
    fn segment(&mut self, a: Vec3, b: Vec3) {
        let d: Vec3 = std::array::from_fn(|k| b[k] - a[k]);
        let mut cur = [0i32; 3];
        let mut step = [0i32; 3];
        self.crossings.clear();
        for k in 0..3 {
            let (start, first, last, s) = axis_walk(a[k], b[k]);
            cur[k] = start;
            step[k] = s;
            let mut n = first;
            while s != 0 && (n - last) * s as f64 <= 0.0 {
                let t = ((n - a[k]) / d[k]).clamp(0.0, 1.0);
                self.crossings.push((t, k, n));
                n += s as f64;
            }
        }
        self.crossings
            .sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        self.contact_box(a);
        self.contact_box(b);
        let mut prev_t = 0.0;
        let mut i = 0;
        while i < self.crossings.len() {
            let t = self.crossings[i].0;
            if t > prev_t {
                self.open.push(corner_key(cur));
            }
            // Every crossing at exactly this t is one crossing point (an edge
            // or corner when there are several).
            let mut p: Vec3 = std::array::from_fn(|k| a[k] + t * d[k]);
            let group = i;
            while i < self.crossings.len() && self.crossings[i].0 == t {
                let (_, k, n) = self.crossings[i];
                p[k] = n;
                cur[k] += step[k];
                i += 1;
            }
            // A plain face crossing (one plane, the other coordinates off
            // the grid planes) touches only the voxels before and after it,
            // which the walk lists; only edge and corner points add voxels.
            let k = self.crossings[group].1;
            let plain = i == group + 1 && (0..3).all(|j| j == k || p[j].floor() != p[j]);
            if !plain {
                self.contact_box(p);
            }
            prev_t = t;
        }
        if prev_t < 1.0 {
            self.open.push(corner_key(cur));
        }
    }

    /// Adds every voxel whose closed cube holds grid point `p`.
    fn contact_box(&mut self, p: Vec3) {
        let mut lo = [0i32; 3];
        let mut n = [1i32; 3];
        for k in 0..3 {
            let f = p[k].floor();
            if f == p[k] {
                lo[k] = f as i32 - 1;
                n[k] = 2;
            } else {
                lo[k] = f as i32;
            }
        }
        for i in 0..n[0] {
            for j in 0..n[1] {
                for k in 0..n[2] {
                    self.contact
                        .push(corner_key([lo[0] + i, lo[1] + j, lo[2] + k]));
                }
            }
        }
    }
}

/// For one axis of a segment from coordinate `a` to `b`: the index of the
/// first open voxel, the first and last plane crossed strictly between `a`
/// and `b`, and the step direction (0 when the segment does not move on it).
fn axis_walk(a: f64, b: f64) -> (i32, f64, f64, i32) {
    if b > a {
        (a.floor() as i32, a.floor() + 1.0, b.ceil() - 1.0, 1)
    } else if b < a {
        (a.ceil() as i32 - 1, a.ceil() - 1.0, b.floor() + 1.0, -1)
    } else {
        (a.floor() as i32, 0.0, 0.0, 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk(a: Vec3, b: Vec3) -> (Vec<[i32; 3]>, Vec<[i32; 3]>) {
        let mut w = Walk::default();
        w.segment(a, b);
        let mut open = w.open.clone();
        let mut all = w.contact.clone();
        all.extend_from_slice(&w.open);
        sort_dedup(&mut open);
        sort_dedup(&mut all);
        (
            open.into_iter().map(key_cell).collect(),
            all.into_iter().map(key_cell).collect(),
        )
    }

    #[test]
    fn straight_segment_inside_rows() {
        let (open, all) = walk([0.5, 0.5, 0.5], [3.5, 0.5, 0.5]);
        assert_eq!(open, vec![[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]);
        assert_eq!(all, open);
    }

    #[test]
    fn diagonal_through_a_corner_takes_all_eight() {
        let (open, all) = walk([0.5, 0.5, 0.5], [1.5, 1.5, 1.5]);
        assert_eq!(open, vec![[0, 0, 0], [1, 1, 1]]);
        assert_eq!(all.len(), 8);
    }

    #[test]
    fn segment_along_an_edge_takes_four_per_step() {
        let (_, all) = walk([0.5, 1.0, 1.0], [2.5, 1.0, 1.0]);
        assert_eq!(all.len(), 12);
        for v in &all {
            assert!((0..3).contains(&v[0]) && (0..2).contains(&v[1]) && (0..2).contains(&v[2]));
        }
    }

    #[test]
    fn negative_direction_and_integer_endpoints() {
        let (open, all) = walk([2.0, 0.5, 0.5], [0.0, 0.5, 0.5]);
        assert_eq!(open, vec![[0, 0, 0], [1, 0, 0]]);
        // Closed cubes at the endpoints x = 0 and x = 2 add voxels -1 and 2.
        assert_eq!(all, vec![[-1, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]]);
    }

    /// The counts taken before the walk bound what the walk and the split
    /// really make: the voxels from below, the pieces from above.
    #[test]
    fn counts_before_the_walk_bound_the_real_voxels_and_pieces() {
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for trial in 0..40 {
            let mut y = Yarns::new();
            for _ in 0..1 + trial % 4 {
                let n = 3 + (next() * 12.0) as usize;
                let step = 0.002 + 0.02 * next();
                let mut p = [next(), next(), next()].map(|x| 0.1 * x);
                let mut pts = Vec::new();
                for _ in 0..n {
                    pts.push(p);
                    p = p.map(|x| x + step * (next() - 0.5));
                }
                y.push_curve(&pts, trial % 3 == 0, 0.001);
            }
            let h = 0.001 + 0.01 * next();
            let prep = Prepared::new(&y, h, None).unwrap();
            let (voxels, _) = prep.voxels_capped(u64::MAX).unwrap();
            assert!(prep.min_voxels <= voxels.len() as f64, "trial {trial}");
            let e = crate::embed::embed(
                &y,
                &crate::embed::EmbedParams {
                    voxel_size: Some(h),
                    ..Default::default()
                },
            )
            .unwrap();
            assert!(
                prep.work(u64::MAX).pieces >= e.pieces.len() as u64,
                "trial {trial}"
            );
        }
    }

    #[test]
    fn zero_length_segment_is_its_point() {
        let (_, all) = walk([0.25, 1.0, 0.5], [0.25, 1.0, 0.5]);
        assert_eq!(all, vec![[0, 0, 0], [0, 1, 0]]);
    }
}
