//! Y2V shape fitting (VH §5, Eq. 5-6): the tet mesh pose that best matches a
//! yarn pose.
//!
//! 1. Per yarn segment, a deformation gradient
//!    `F^Y = [x1 - x0, n1, n2] [x̄1 - x̄0, n̄1, n̄2]^-1` (VH §5). The rest
//!    normals n̄1, n̄2 are parallel-transported along each yarn (consistent
//!    along the yarn, no flips). The deformed normals come from a *local
//!    affine fit*: the map A minimising `sum_k w_k |A (X_k - X̄) - (x_k - x̄)|^2`
//!    over the yarn vertices k (of any yarn) within a radius r of the segment
//!    midpoint, with weights `w_k = (1 - d_k^2 / r^2)^2` and weighted centroids
//!    X̄, x̄ (found with a uniform grid of cell h). Then `n_i = A n̂_i`: A is
//!    linear in the deformed positions, so each normal is a fixed stencil
//!    `n_i = sum_k c_ik (x_k - x0)` computed once at rest (coefficients in
//!    f32), and the rest frame uses the same stencil applied to the rest pose,
//!    `n̂_i = sum_k c_ik (X_k - X0)` (≈ n̄_i). Hence for any affine map
//!    x -> A x + b of the yarns every segment gets `F^Y = A` to rounding,
//!    whatever the stencil's precision, and with it a stretch *across* the
//!    yarns (which a single yarn cannot see) reaches the mesh. r starts at
//!    1.5 h (h the voxel size) and grows by 1.5x up to 5 h until the weighted
//!    covariance of the neighbourhood spans 3D (smallest eigenvalue at least
//!    1% of the largest, i.e. the thinnest extent at least 10% of the
//!    widest). Where it never does (an isolated yarn, a straight strand) and
//!    where the affine F^Y is not orientation preserving (det <= 0, a guard
//!    against tangled yarn-level poses), the segment falls back to the rest
//!    normals *rotated* by the best-fit rotation (Kabsch) of its up to 4
//!    neighbouring vertices along the yarn. Both variants give F = R exactly
//!    for any rigid motion.
//! 2. Per tet, Eq. 5: F = exp(mean Ω) mean S over the yarn pieces in the tet,
//!    weighted by piece length, where F^Y = R S (polar decomposition) and
//!    R = exp(Ω). Tets without yarn take their voxel's average; voxels without
//!    yarn (corner contacts) take the average of their face neighbours.
//! 3. Eq. 6, solved per coordinate with one sparse SPD matrix:
//!    `min sum_e V_e |F_e(x) - F*_e|^2 + alpha sum_i w_i |(N x)_i - x^Y_i|^2`.
//!    Reading of the printed mass term: the weights are the yarn vertex
//!    masses made dimensionless, `w_i = (m_i / M) (V / h^2)` (M total yarn
//!    mass, V total mesh volume, h the voxel size), so that a position misfit
//!    of d weighs like a deformation-gradient misfit of d/h whatever the units.
//!    The weights (and so the scale of the mass term) are unchanged by the
//!    affine fit of step 1: with exact F targets the position term only
//!    fixes the translation (and anything F cannot see), so alpha matters
//!    less than it did with rotation-only normals.
//!    The matrix depends on the rest mesh only: its symbolic and numeric
//!    Cholesky factorizations are computed once per mesh; every frame is
//!    three triangular solves.
//! 4. Per frame, the deformation gradient of every fitted tet is checked:
//!    [`FitStats::inverted_tets`] counts those with det F <= 0 and
//!    [`FitStats::min_det_f`] is the smallest det F.

use std::collections::HashMap;
use std::time::Instant;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use nalgebra::{Matrix3, Rotation3, Vector3};
use rayon::prelude::*;

use crate::geom::{Embedding, TetMesh, Vec3, VoxelGrid, YarnFrames, YarnPiece, Yarns};
use crate::linalg::cholesky::SparseCholesky;

/// Errors of shape fitting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("inconsistent inputs: {0}")]
    Inconsistent(String),
    #[error("the shape-fit matrix is not positive definite ({0}); is every mesh component reached by a yarn?")]
    NotPositiveDefinite(String),
    #[error("frame {frame}: {message}")]
    Frame { frame: usize, message: String },
}

/// Parameters of the shape fit.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShapeFitParams {
    /// Weight of the position term of VH Eq. 6 (dimensionless). Default 0.1 (VH §5).
    pub alpha: f64,
}

impl Default for ShapeFitParams {
    fn default() -> Self {
        ShapeFitParams { alpha: 0.1 }
    }
}

/// What one fitted frame looks like.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct FitStats {
    /// RMS over yarn vertices of |V2Y(x) - x^Y| (m).
    pub rms_error: f64,
    /// Largest |V2Y(x) - x^Y| (m).
    pub max_error: f64,
    /// Time of this frame's fit (ms).
    pub ms: f64,
    /// Fitted tets whose deformation gradient F (rest mesh to fitted nodes,
    /// the D operator of Eq. 6) has det F <= 0: inverted or flattened. 0 for
    /// a sound fit; the elasticity fit and the simulator cannot use a pose
    /// with inverted tets.
    pub inverted_tets: usize,
    /// Smallest det F over the fitted tets (the smallest volume ratio; 1 at
    /// rest, <= 0 when some tet is inverted). 0 for a mesh without tets.
    pub min_det_f: f64,
}

/// Timings of the one-off preparation.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct PrepareStats {
    pub assemble_ms: f64,
    pub symbolic_ms: f64,
    pub numeric_ms: f64,
    pub nonzeros: usize,
    /// Yarn segments.
    pub segments: usize,
    /// Segments whose deformed normals come from the local affine fit (the
    /// others, whose neighbourhood never spans 3D, only rotate theirs).
    pub affine_segments: usize,
    /// Stencil entries over all segments (12 bytes each, and about 6 flops
    /// each per frame).
    pub stencil_taps: usize,
}

/// Per-segment rest data.
#[derive(Debug, Clone)]
struct RestSegment {
    a: usize,
    b: usize,
    /// Neighbourhood vertex indices used for the rotation fit (first `window_len` valid).
    window: [usize; 4],
    window_len: usize,
    /// Inverse of [x̄1 - x̄0, n̄1, n̄2].
    rest_inv: Matrix3<f64>,
    n1: Vector3<f64>,
    n2: Vector3<f64>,
    /// Range of this segment's affine stencil in `ShapeFitter::taps`; empty
    /// when the neighbourhood does not span 3D (rotation-only normals).
    taps: (usize, usize),
    /// Inverse of [x̄1 - x̄0, n̂1, n̂2], n̂ the stencil applied to the rest pose.
    affine_inv: Matrix3<f64>,
}

/// Radii of the local affine fit, in voxel sizes, tried in turn until the
/// neighbourhood spans 3D.
const STENCIL_RADII: [f64; 4] = [1.5, 2.25, 3.375, 5.0];
/// A neighbourhood spans 3D when the smallest eigenvalue of its weighted
/// covariance is at least this fraction of the largest.
const MIN_SPREAD: f64 = 1e-2;

/// Uniform grid over the rest yarn vertices, for radius queries (cell: the
/// first stencil radius, so a first query visits at most 27 cells).
struct PointGrid {
    cell: f64,
    /// Vertex indices sorted by (cell, index).
    order: Vec<u32>,
    /// Range of each occupied cell in `order`.
    cells: HashMap<[i32; 3], (usize, usize)>,
}

impl PointGrid {
    fn key(&self, p: &Vector3<f64>) -> [i32; 3] {
        std::array::from_fn(|k| (p[k] / self.cell).floor() as i32)
    }

    fn new(points: &[Vec3], cell: f64) -> PointGrid {
        let mut g = PointGrid {
            cell,
            order: Vec::new(),
            cells: HashMap::new(),
        };
        let mut keyed: Vec<([i32; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (g.key(&v3(*p)), i as u32))
            .collect();
        keyed.sort_unstable();
        let mut s = 0;
        while s < keyed.len() {
            let mut e = s + 1;
            while e < keyed.len() && keyed[e].0 == keyed[s].0 {
                e += 1;
            }
            g.cells.insert(keyed[s].0, (s, e));
            s = e;
        }
        g.order = keyed.into_iter().map(|(_, i)| i).collect();
        g
    }

    /// The vertices within distance `r` of `c`, sorted by index, into `out`.
    fn within(&self, points: &[Vec3], c: &Vector3<f64>, r: f64, out: &mut Vec<u32>) {
        out.clear();
        let lo = self.key(&c.add_scalar(-r));
        let hi = self.key(&c.add_scalar(r));
        for i in lo[0]..=hi[0] {
            for j in lo[1]..=hi[1] {
                for k in lo[2]..=hi[2] {
                    if let Some(&(s, e)) = self.cells.get(&[i, j, k]) {
                        out.extend(
                            self.order[s..e]
                                .iter()
                                .filter(|&&v| (v3(points[v as usize]) - c).norm_squared() < r * r),
                        );
                    }
                }
            }
        }
        out.sort_unstable();
    }
}

/// A segment's stencil taps (vertex, coefficients of n1 and n2) and the
/// inverse of its rest frame [x̄1 - x̄0, n̂1, n̂2].
type Stencil = (Vec<(u32, [f32; 2])>, Matrix3<f64>);

/// Local affine stencil of one segment: the coefficients of n1, n2 on
/// (x_k - x0) and the inverse rest frame, or None when no radius of
/// [`STENCIL_RADII`] gives a neighbourhood that spans 3D.
fn affine_stencil(
    points: &[Vec3],
    grid: &PointGrid,
    s: &RestSegment,
    h: f64,
    buf: &mut Vec<u32>,
) -> Option<Stencil> {
    let (x0, x1) = (v3(points[s.a]), v3(points[s.b]));
    let mid = 0.5 * (x0 + x1);
    for f in STENCIL_RADII {
        let r = f * h;
        grid.within(points, &mid, r, buf);
        if buf.len() < 4 {
            continue;
        }
        let w: Vec<f64> = buf
            .iter()
            .map(|&v| {
                let q2 = (v3(points[v as usize]) - mid).norm_squared() / (r * r);
                (1.0 - q2) * (1.0 - q2)
            })
            .collect();
        let wsum: f64 = w.iter().sum();
        if wsum <= 0.0 || wsum.is_nan() {
            continue;
        }
        let centre = buf
            .iter()
            .zip(&w)
            .map(|(&v, &wk)| (v3(points[v as usize]) - mid) * wk)
            .sum::<Vector3<f64>>()
            / wsum;
        let mut cov = Matrix3::zeros();
        for (&v, &wk) in buf.iter().zip(&w) {
            let d = v3(points[v as usize]) - mid - centre;
            cov += d * d.transpose() * wk;
        }
        let eig = cov.symmetric_eigen();
        let (lmin, lmax) = (eig.eigenvalues.min(), eig.eigenvalues.max());
        if lmax <= 0.0 || lmax.is_nan() || lmin < MIN_SPREAD * lmax {
            continue;
        }
        let cinv = eig.eigenvectors
            * Matrix3::from_diagonal(&eig.eigenvalues.map(|l| 1.0 / l))
            * eig.eigenvectors.transpose();
        let taps: Vec<(u32, [f32; 2])> = buf
            .iter()
            .zip(&w)
            .map(|(&v, &wk)| {
                let g = cinv * (v3(points[v as usize]) - mid - centre) * wk;
                (v, [g.dot(&s.n1) as f32, g.dot(&s.n2) as f32])
            })
            .collect();
        let (m1, m2) = apply_stencil(points, &taps, &x0);
        if let Some(inv) = Matrix3::from_columns(&[x1 - x0, m1, m2]).try_inverse() {
            if inv.iter().all(|x| x.is_finite()) {
                return Some((taps, inv));
            }
        }
    }
    None
}

/// `sum_k c_ik (x_k - x0)` for i = 1, 2.
fn apply_stencil(
    x: &[Vec3],
    taps: &[(u32, [f32; 2])],
    x0: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let (mut m1, mut m2) = (Vector3::zeros(), Vector3::zeros());
    for &(v, c) in taps {
        let d = v3(x[v as usize]) - x0;
        m1 += d * c[0] as f64;
        m2 += d * c[1] as f64;
    }
    (m1, m2)
}

/// Y2V prepared for one mesh and embedding: factorized once, applied per frame.
pub struct ShapeFitter {
    mesh: TetMesh,
    embedding: Embedding,
    /// Rest yarn vertex positions (m).
    rest: Vec<Vec3>,
    segments: Vec<RestSegment>,
    /// Affine stencils of all segments (see `RestSegment::taps`).
    taps: Vec<(u32, [f32; 2])>,
    /// Pieces grouped by tet: (segment, length).
    tet_pieces: Vec<Vec<(u32, f64)>>,
    /// For tets without pieces: the tets whose pieces stand in (its voxel, or neighbouring voxels).
    tet_fallback: Vec<Vec<u32>>,
    /// Shape function gradients of each tet (rows = nodes).
    grads: Vec<[Vector3<f64>; 4]>,
    volumes: Vec<f64>,
    /// Position-term weight of each yarn vertex (alpha w_i).
    weights: Vec<f64>,
    /// Cholesky factor of the Eq. 6 matrix.
    factor: SparseCholesky,
    pub prepare: PrepareStats,
}

fn v3(p: Vec3) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// Polar decomposition F = R S with R a rotation (det +1) and S symmetric.
pub fn polar(f: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let svd = f.svd(true, true);
    let (mut u, s, v_t) = (svd.u.unwrap(), svd.singular_values, svd.v_t.unwrap());
    let mut sig = s;
    if (u * v_t).determinant() < 0.0 {
        // Flip the direction of the smallest singular value.
        let k = (0..3).min_by(|&i, &j| s[i].total_cmp(&s[j])).unwrap_or(2);
        for r in 0..3 {
            u[(r, k)] = -u[(r, k)];
        }
        sig[k] = -sig[k];
    }
    let r = u * v_t;
    let s_mat = v_t.transpose() * Matrix3::from_diagonal(&sig) * v_t;
    (r, s_mat)
}

/// Matrix logarithm of a rotation as an axis-angle vector (the vee of Ω in
/// R = exp(Ω)). Robust near the identity, where acos((tr R - 1) / 2) is not.
pub fn log_rotation(r: &Matrix3<f64>) -> Vector3<f64> {
    let w = 0.5
        * Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        );
    let s = w.norm();
    let c = 0.5 * (r.trace() - 1.0);
    let angle = s.atan2(c);
    if s < 1e-12 {
        if c > 0.0 {
            return w; // first order: angle = s, axis = w / s
        }
        // Half turn: the axis is the column of R + I with the largest norm.
        let m = r + Matrix3::identity();
        let k = (0..3)
            .max_by(|&i, &j| m.column(i).norm().total_cmp(&m.column(j).norm()))
            .unwrap_or(0);
        return m.column(k).normalize() * std::f64::consts::PI;
    }
    w * (angle / s)
}

/// Best rotation R with R (p̄_k - c̄) ≈ (p_k - c) (Kabsch); None when the
/// points do not determine a rotation (fewer than 2 independent directions).
fn kabsch(rest: &[Vector3<f64>], cur: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
    let n = rest.len() as f64;
    let c0 = rest.iter().sum::<Vector3<f64>>() / n;
    let c1 = cur.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (p, q) in rest.iter().zip(cur) {
        h += (q - c1) * (p - c0).transpose();
    }
    let svd = h.svd(true, true);
    let s = svd.singular_values;
    let mut sorted = [s[0], s[1], s[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted[0] <= 0.0 || sorted[0].is_nan() || sorted[1] <= 1e-9 * sorted[0] {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        let k = (0..3).min_by(|&i, &j| s[i].total_cmp(&s[j])).unwrap_or(2);
        d[(k, k)] = -1.0;
    }
    Some(u * d * v_t)
}

/// The rotation taking unit vector a to unit vector b with the smallest angle.
fn minimal_rotation(a: &Vector3<f64>, b: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::rotation_between(a, b)
        .unwrap_or_else(|| {
            // Opposite vectors: half-turn about any axis perpendicular to a.
            let axis = a.cross(&perpendicular(a)).normalize();
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), std::f64::consts::PI)
        })
        .into_inner()
}

fn perpendicular(t: &Vector3<f64>) -> Vector3<f64> {
    let k = (0..3)
        .min_by(|&i, &j| t[i].abs().total_cmp(&t[j].abs()))
        .unwrap_or(0);
    let mut e = Vector3::zeros();
    e[k] = 1.0;
    t.cross(&e).normalize()
}

impl ShapeFitter {
    /// Prepares Y2V for `mesh` with rest yarns `yarns` embedded by `embedding`.
    /// `pieces` are the yarn segments split at tet boundaries; `tet_voxel`
    /// and `grid` give each tet's voxel; `linear_density` is per curve (kg/m).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        yarns: &Yarns,
        mesh: &TetMesh,
        grid: &VoxelGrid,
        tet_voxel: &[u32],
        embedding: &Embedding,
        pieces: &[YarnPiece],
        linear_density: &[f64],
        params: &ShapeFitParams,
    ) -> Result<ShapeFitter, FitError> {
        let t_start = Instant::now();
        let nv = mesh.num_nodes();
        let nt = mesh.num_tets();
        if embedding.num_vertices() != yarns.num_points()
            || tet_voxel.len() != nt
            || linear_density.len() != yarns.num_curves()
        {
            return Err(FitError::Inconsistent(format!(
                "{} embedded vertices for {} yarn points, {} tet voxels for {} tets, {} densities for {} curves",
                embedding.num_vertices(),
                yarns.num_points(),
                tet_voxel.len(),
                nt,
                linear_density.len(),
                yarns.num_curves()
            )));
        }
        let mut segments = rest_segments(yarns);
        let taps = attach_stencils(&yarns.points, &mut segments, grid.h);
        let mut tet_pieces = vec![Vec::new(); nt];
        for p in pieces {
            if p.tet as usize >= nt || p.segment as usize >= segments.len() {
                return Err(FitError::Inconsistent(format!(
                    "piece {p:?} refers past the mesh or the segments"
                )));
            }
            tet_pieces[p.tet as usize].push((p.segment, p.length));
        }
        let tet_fallback = fallbacks(grid, tet_voxel, &tet_pieces);

        // Shape-function gradients and volumes.
        let mut grads = Vec::with_capacity(nt);
        let mut volumes = Vec::with_capacity(nt);
        for t in 0..nt {
            let x = mesh.tets[t].map(|i| v3(mesh.nodes[i as usize]));
            let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
            let inv = dm
                .try_inverse()
                .ok_or_else(|| FitError::Inconsistent(format!("tet {t} is degenerate")))?;
            let g1 = inv.row(0).transpose();
            let g2 = inv.row(1).transpose();
            let g3 = inv.row(2).transpose();
            grads.push([-(g1 + g2 + g3), g1, g2, g3]);
            volumes.push(dm.determinant() / 6.0);
        }

        // Position-term weights from the yarn vertex masses.
        let mut vertex_mass = vec![0.0; yarns.num_points()];
        for (c, &density) in linear_density.iter().enumerate() {
            for [a, b] in yarns.segments_of(c) {
                let m = density * crate::geom::dist(yarns.points[a], yarns.points[b]);
                vertex_mass[a] += 0.5 * m;
                vertex_mass[b] += 0.5 * m;
            }
        }
        let total_mass: f64 = vertex_mass.iter().sum();
        let total_volume: f64 = volumes.iter().sum();
        let h2 = (6.0 * total_volume / nt.max(1) as f64).powf(2.0 / 3.0);
        let scale = if total_mass > 0.0 {
            params.alpha * total_volume / (h2 * total_mass)
        } else {
            0.0
        };
        let weights: Vec<f64> = vertex_mass.iter().map(|m| m * scale).collect();

        // Assemble K + N^T W N (lower triangle is enough for the Cholesky, but faer wants the full matrix
        // on the side it reads; we give the lower side).
        let mut trip: Vec<Triplet<usize, usize, f64>> =
            Vec::with_capacity(nt * 10 + embedding.num_vertices() * 10);
        for t in 0..nt {
            let ids = mesh.tets[t];
            for a in 0..4 {
                for b in 0..4 {
                    let (i, j) = (ids[a] as usize, ids[b] as usize);
                    if i >= j {
                        trip.push(Triplet::new(
                            i,
                            j,
                            volumes[t] * grads[t][a].dot(&grads[t][b]),
                        ));
                    }
                }
            }
        }
        for (v, (&t, w)) in embedding.tet.iter().zip(&embedding.weights).enumerate() {
            let ids = mesh.tets[t as usize];
            for a in 0..4 {
                for b in 0..4 {
                    let (i, j) = (ids[a] as usize, ids[b] as usize);
                    if i >= j {
                        trip.push(Triplet::new(i, j, weights[v] * w[a] * w[b]));
                    }
                }
            }
        }
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(nv, nv, &trip)
            .map_err(|e| FitError::Inconsistent(format!("assembling the matrix: {e:?}")))?;
        let assemble_ms = t_start.elapsed().as_secs_f64() * 1e3;
        let t_sym = Instant::now();
        let symbolic = SparseCholesky::symbolic(a.as_ref())
            .map_err(|e| FitError::NotPositiveDefinite(e.to_string()))?;
        let symbolic_ms = t_sym.elapsed().as_secs_f64() * 1e3;
        let t_num = Instant::now();
        let factor = SparseCholesky::numeric(symbolic, a.as_ref())
            .map_err(|e| FitError::NotPositiveDefinite(e.to_string()))?;
        let numeric_ms = t_num.elapsed().as_secs_f64() * 1e3;
        let num_segments = segments.len();
        let affine_segments = segments.iter().filter(|s| s.taps.0 < s.taps.1).count();
        let stencil_taps = taps.len();
        Ok(ShapeFitter {
            mesh: mesh.clone(),
            embedding: embedding.clone(),
            rest: yarns.points.clone(),
            segments,
            taps,
            tet_pieces,
            tet_fallback,
            grads,
            volumes,
            weights,
            factor,
            prepare: PrepareStats {
                assemble_ms,
                symbolic_ms,
                numeric_ms,
                nonzeros: a.compute_nnz(),
                segments: num_segments,
                affine_segments,
                stencil_taps,
            },
        })
    }

    /// Per-segment deformation gradients F^Y for a yarn pose, as (Ω, S) pairs.
    fn segment_gradients(&self, x: &[Vec3]) -> Vec<(Vector3<f64>, Matrix3<f64>)> {
        let rest = &self.rest;
        self.segments
            .par_iter()
            .map(|s| {
                let e = v3(x[s.b]) - v3(x[s.a]);
                if s.taps.0 < s.taps.1 {
                    let (m1, m2) = apply_stencil(x, &self.taps[s.taps.0..s.taps.1], &v3(x[s.a]));
                    let f = Matrix3::from_columns(&[e, m1, m2]) * s.affine_inv;
                    let det = f.determinant();
                    if det > 0.0 && det.is_finite() {
                        let (rot, stretch) = polar(&f);
                        return (log_rotation(&rot), stretch);
                    }
                }
                let w = &s.window[..s.window_len];
                let rest_pts: [Vector3<f64>; 4] =
                    std::array::from_fn(|k| v3(rest[w[k.min(w.len() - 1)]]));
                let cur_pts: [Vector3<f64>; 4] =
                    std::array::from_fn(|k| v3(x[w[k.min(w.len() - 1)]]));
                let r = kabsch(&rest_pts[..w.len()], &cur_pts[..w.len()]).unwrap_or_else(|| {
                    let e0 = (v3(rest[s.b]) - v3(rest[s.a])).normalize();
                    let e1 = if e.norm() > 0.0 { e.normalize() } else { e0 };
                    minimal_rotation(&e0, &e1)
                });
                let f = Matrix3::from_columns(&[e, r * s.n1, r * s.n2]) * s.rest_inv;
                let (rot, stretch) = polar(&f);
                let omega = log_rotation(&rot);
                (omega, stretch)
            })
            .collect()
    }

    /// Target F*_e of every tet (VH Eq. 5).
    fn targets(&self, seg: &[(Vector3<f64>, Matrix3<f64>)]) -> Vec<Matrix3<f64>> {
        let average = |list: &mut dyn Iterator<Item = (u32, f64)>| {
            let (mut om, mut st, mut wsum) = (Vector3::zeros(), Matrix3::zeros(), 0.0);
            for (s, w) in list {
                om += seg[s as usize].0 * w;
                st += seg[s as usize].1 * w;
                wsum += w;
            }
            (om, st, wsum)
        };
        (0..self.mesh.num_tets())
            .into_par_iter()
            .map(|t| {
                let (mut om, mut st, mut w) = average(&mut self.tet_pieces[t].iter().copied());
                if w <= 0.0 {
                    let mut it = self.tet_fallback[t]
                        .iter()
                        .flat_map(|&u| self.tet_pieces[u as usize].iter().copied());
                    (om, st, w) = average(&mut it);
                }
                if w <= 0.0 {
                    return Matrix3::identity();
                }
                Rotation3::new(om / w).into_inner() * (st / w)
            })
            .collect()
    }

    /// Prepares Y2V for the output of the embedding stage.
    pub fn from_embedded(
        yarns: &Yarns,
        e: &crate::embed::Embedded,
        params: &ShapeFitParams,
    ) -> Result<ShapeFitter, FitError> {
        ShapeFitter::new(
            yarns,
            &e.mesh,
            &e.grid,
            &e.tet_voxel,
            &e.embedding,
            &e.pieces,
            &e.linear_density,
            params,
        )
    }

    /// Y2V of one yarn pose (m): the fitted node positions and the fit error.
    pub fn fit(&self, yarn_points: &[Vec3]) -> Result<(Vec<Vec3>, FitStats), FitError> {
        let start = Instant::now();
        if yarn_points.len() != self.embedding.num_vertices() {
            return Err(FitError::Inconsistent(format!(
                "{} yarn positions for {} embedded vertices",
                yarn_points.len(),
                self.embedding.num_vertices()
            )));
        }
        if let Some(v) = yarn_points
            .iter()
            .position(|p| !p.iter().all(|x| x.is_finite()))
        {
            return Err(FitError::Inconsistent(format!(
                "yarn vertex {v} is not finite"
            )));
        }
        let seg = self.segment_gradients(yarn_points);
        let targets = self.targets(&seg);
        let nv = self.mesh.num_nodes();
        let mut rhs = Mat::<f64>::zeros(nv, 3);
        for (t, f) in targets.iter().enumerate() {
            let ids = self.mesh.tets[t];
            for a in 0..4 {
                let g = f * self.grads[t][a] * self.volumes[t];
                for c in 0..3 {
                    rhs[(ids[a] as usize, c)] += g[c];
                }
            }
        }
        for (v, (&t, w)) in self
            .embedding
            .tet
            .iter()
            .zip(&self.embedding.weights)
            .enumerate()
        {
            let ids = self.mesh.tets[t as usize];
            for a in 0..4 {
                for c in 0..3 {
                    rhs[(ids[a] as usize, c)] += self.weights[v] * w[a] * yarn_points[v][c];
                }
            }
        }
        // Sequential triangular solves (frames already run in parallel; faer's
        // parallel sparse solve was several times slower at these sizes).
        let mut sol = rhs;
        self.factor.solve_in_place(sol.as_mut());
        let nodes: Vec<Vec3> = (0..nv)
            .map(|i| [sol[(i, 0)], sol[(i, 1)], sol[(i, 2)]])
            .collect();
        if let Some(i) = nodes.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
            return Err(FitError::NotPositiveDefinite(format!(
                "node {i} came out non-finite"
            )));
        }
        let back = self.embedding.v2y(&self.mesh, &nodes);
        let (mut sum2, mut max) = (0.0, 0.0f64);
        for (p, q) in back.iter().zip(yarn_points) {
            let d = crate::geom::dist(*p, *q);
            sum2 += d * d;
            max = max.max(d);
        }
        let rms = (sum2 / back.len().max(1) as f64).sqrt();
        let (inverted_tets, min_det_f) = self.det_stats(&nodes);
        Ok((
            nodes,
            FitStats {
                rms_error: rms,
                max_error: max,
                ms: start.elapsed().as_secs_f64() * 1e3,
                inverted_tets,
                min_det_f,
            },
        ))
    }

    /// (tets with det F <= 0, smallest det F) of fitted node positions.
    fn det_stats(&self, nodes: &[Vec3]) -> (usize, f64) {
        if self.mesh.num_tets() == 0 {
            return (0, 0.0);
        }
        (0..self.mesh.num_tets())
            .into_par_iter()
            .map(|t| {
                let ids = self.mesh.tets[t];
                let mut f = Matrix3::zeros();
                for a in 0..4 {
                    f += v3(nodes[ids[a] as usize]) * self.grads[t][a].transpose();
                }
                let d = f.determinant();
                (usize::from(d <= 0.0 || d.is_nan()), d)
            })
            .reduce(
                || (0, f64::INFINITY),
                |a, b| (a.0 + b.0, if b.1 < a.1 || b.1.is_nan() { b.1 } else { a.1 }),
            )
    }

    /// Y2V of every frame, frames in parallel (results in frame order).
    pub fn fit_frames(&self, frames: &YarnFrames) -> Result<Vec<(Vec<Vec3>, FitStats)>, FitError> {
        (0..frames.num_frames())
            .into_par_iter()
            .map(|f| {
                self.fit(frames.frame(f)).map_err(|e| FitError::Frame {
                    frame: f,
                    message: e.to_string(),
                })
            })
            .collect()
    }

    /// Tet volumes (m^3).
    pub fn volumes(&self) -> &[f64] {
        &self.volumes
    }
}

/// Rest segment frames: parallel-transported normals along each yarn.
fn rest_segments(yarns: &Yarns) -> Vec<RestSegment> {
    let mut out = Vec::with_capacity(yarns.num_segments());
    for c in 0..yarns.num_curves() {
        let range = yarns.curve_range(c);
        let n = range.len();
        let closed = yarns.closed[c];
        let segs: Vec<[usize; 2]> = yarns.segments_of(c).collect();
        let mut normal: Option<Vector3<f64>> = None;
        let mut prev_t: Option<Vector3<f64>> = None;
        for (k, &[a, b]) in segs.iter().enumerate() {
            let e = v3(yarns.points[b]) - v3(yarns.points[a]);
            let len = e.norm();
            let t = if len > 0.0 {
                e / len
            } else {
                prev_t.unwrap_or_else(Vector3::x)
            };
            let n1 = match (normal, prev_t) {
                (Some(nprev), Some(tp)) => {
                    let m = minimal_rotation(&tp, &t) * nprev;
                    // Re-orthogonalise against drift.
                    let m = m - t * t.dot(&m);
                    if m.norm() > 1e-12 {
                        m.normalize()
                    } else {
                        perpendicular(&t)
                    }
                }
                _ => perpendicular(&t),
            };
            let n2 = t.cross(&n1);
            normal = Some(n1);
            prev_t = Some(t);
            // Neighbourhood window: vertices k-1 .. k+2 along the curve.
            let local = |j: isize| -> Option<usize> {
                if closed {
                    Some(range.start + j.rem_euclid(n as isize) as usize)
                } else if j >= 0 && (j as usize) < n {
                    Some(range.start + j as usize)
                } else {
                    None
                }
            };
            let mut window = [0usize; 4];
            let mut window_len = 0;
            for v in (-1..=2).filter_map(|d| local(k as isize + d)) {
                // Short closed curves wrap onto themselves: keep each vertex once.
                if !window[..window_len].contains(&v) {
                    window[window_len] = v;
                    window_len += 1;
                }
            }
            let rest = Matrix3::from_columns(&[e, n1, n2]);
            let rest_inv = rest.try_inverse().unwrap_or_else(Matrix3::identity);
            out.push(RestSegment {
                a,
                b,
                window,
                window_len,
                rest_inv,
                n1,
                n2,
                taps: (0, 0),
                affine_inv: Matrix3::identity(),
            });
        }
    }
    out
}

/// Builds every segment's affine stencil (in parallel, deterministic) and
/// returns the concatenated taps; segments without one keep an empty range.
fn attach_stencils(points: &[Vec3], segments: &mut [RestSegment], h: f64) -> Vec<(u32, [f32; 2])> {
    if h <= 0.0 || h.is_nan() || segments.is_empty() {
        return Vec::new();
    }
    let grid = PointGrid::new(points, STENCIL_RADII[0] * h);
    let stencils: Vec<Option<Stencil>> = segments
        .par_iter()
        .map_init(Vec::new, |buf, s| affine_stencil(points, &grid, s, h, buf))
        .collect();
    let mut taps = Vec::with_capacity(stencils.iter().flatten().map(|s| s.0.len()).sum());
    for (s, st) in segments.iter_mut().zip(stencils) {
        if let Some((list, inv)) = st {
            s.taps = (taps.len(), taps.len() + list.len());
            s.affine_inv = inv;
            taps.extend(list);
        }
    }
    taps
}

/// For tets without yarn pieces: the tets of their voxel that have pieces, or
/// failing that, the tets of the nearest voxels (face neighbours, grown ring by
/// ring) that have pieces.
fn fallbacks(grid: &VoxelGrid, tet_voxel: &[u32], tet_pieces: &[Vec<(u32, f64)>]) -> Vec<Vec<u32>> {
    let nvox = grid.voxels.len();
    let mut voxel_tets: Vec<Vec<u32>> = vec![Vec::new(); nvox];
    for (t, &v) in tet_voxel.iter().enumerate() {
        if let Some(list) = voxel_tets.get_mut(v as usize) {
            list.push(t as u32);
        }
    }
    let has_yarn = |v: usize| {
        voxel_tets[v]
            .iter()
            .any(|&t| !tet_pieces[t as usize].is_empty())
    };
    // Voxel-level source lists, grown from yarn voxels into empty ones.
    let mut source: Vec<Option<Vec<u32>>> = (0..nvox)
        .map(|v| {
            has_yarn(v).then(|| {
                voxel_tets[v]
                    .iter()
                    .copied()
                    .filter(|&t| !tet_pieces[t as usize].is_empty())
                    .collect()
            })
        })
        .collect();
    const FACES: [[i32; 3]; 6] = [
        [1, 0, 0],
        [-1, 0, 0],
        [0, 1, 0],
        [0, -1, 0],
        [0, 0, 1],
        [0, 0, -1],
    ];
    for _ in 0..64 {
        let missing: Vec<usize> = (0..nvox).filter(|&v| source[v].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        let mut updates = Vec::new();
        for v in missing {
            let c = grid.voxels[v];
            let mut list = Vec::new();
            for d in FACES {
                if let Some(u) = grid.find([c[0] + d[0], c[1] + d[1], c[2] + d[2]]) {
                    if let Some(s) = &source[u] {
                        list.extend_from_slice(s);
                    }
                }
            }
            if !list.is_empty() {
                list.sort_unstable();
                list.dedup();
                updates.push((v, list));
            }
        }
        if updates.is_empty() {
            break;
        }
        for (v, list) in updates {
            source[v] = Some(list);
        }
    }
    tet_voxel
        .iter()
        .enumerate()
        .map(|(t, &v)| {
            if !tet_pieces[t].is_empty() {
                Vec::new()
            } else {
                source
                    .get(v as usize)
                    .cloned()
                    .flatten()
                    .unwrap_or_default()
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polar_is_rotation_times_symmetric() {
        let f = Matrix3::new(1.2, 0.3, -0.1, 0.05, 0.9, 0.2, -0.3, 0.1, 1.1);
        let (r, s) = polar(&f);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        assert!((s - s.transpose()).norm() < 1e-12);
        assert!((r * s - f).norm() < 1e-12);
        // A reflection still gives a proper rotation.
        let m = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let (r, s) = polar(&m);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((r * s - m).norm() < 1e-12);
    }

    #[test]
    fn log_rotation_inverts_exp() {
        for v in [
            Vector3::new(0.3, -0.5, 0.8),
            Vector3::new(1e-9, 0.0, 0.0),
            Vector3::zeros(),
            Vector3::new(0.0, 3.0, 0.0),
        ] {
            let r = Rotation3::new(v).into_inner();
            assert!((log_rotation(&r) - v).norm() < 1e-9, "{v:?}");
        }
        // Slightly non-orthogonal identity (polar output) must not give NaN.
        let mut r = Matrix3::identity();
        r[(0, 0)] = 1.0 + 1e-15;
        assert!(log_rotation(&r).iter().all(|x| x.is_finite()));
        let half = Rotation3::new(Vector3::new(0.0, 0.0, std::f64::consts::PI)).into_inner();
        assert!((log_rotation(&half).norm() - std::f64::consts::PI).abs() < 1e-9);
    }

    #[test]
    fn kabsch_recovers_rotation() {
        let rot = Rotation3::new(Vector3::new(0.3, -0.5, 0.8)).into_inner();
        let pts = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.1, 0.0),
            Vector3::new(2.0, -0.3, 0.4),
            Vector3::new(2.5, 0.5, 1.0),
        ];
        let moved: Vec<_> = pts
            .iter()
            .map(|p| rot * p + Vector3::new(3.0, 2.0, 1.0))
            .collect();
        let r = kabsch(&pts, &moved).unwrap();
        assert!((r - rot).norm() < 1e-12);
        let line = [Vector3::zeros(), Vector3::x(), Vector3::x() * 2.0];
        assert!(kabsch(&line, &line).is_none());
    }
}
