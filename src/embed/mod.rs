//! Voxel embedding of yarns in a tetrahedral mesh (VH §4): voxelize (3D
//! supercover), tetrahedralize (6 tets per voxel, conforming), lumped masses
//! (VH Eq. 1-3), and the V2Y embedding (VH Eq. 4). Pure: no files, no printing.

mod inertia;
mod keys;
mod mass;
pub mod orientation;
mod params;
pub mod regions;
mod size;
mod tetrahedralize;
mod voxelize;

pub use inertia::{compare_inertia, InertiaComparison};
pub use params::{EmbedError, EmbedParams};
pub use size::default_voxel_size;
pub use tetrahedralize::{kuhn_tet, kuhn_weights, locate, tetrahedralize, Location, PERMS};
pub use voxelize::{default_origin, voxelize};

use crate::geom::{dist, Embedding, TetMesh, VoxelGrid, YarnPiece, Yarns};
use rayon::prelude::*;
use std::time::Instant;

/// A box of `n[0] x n[1] x n[2]` voxels of edge `h` (m) at the origin (y up),
/// six Kuhn tets per voxel (all around the main diagonal, so neighbouring
/// voxels' faces match), and lumped node masses (kg) at density `rho`
/// (kg/m³): a quarter of each tet's mass to each of its nodes. The
/// benchmarks' slab and the solvers' tests are built from it.
pub fn box_mesh(n: [usize; 3], h: f64, rho: f64) -> (TetMesh, Vec<f64>) {
    // Voxels sorted by (i, j, k), as `tetrahedralize` requires.
    let mut voxels = Vec::with_capacity(n[0] * n[1] * n[2]);
    for i in 0..n[0] as i32 {
        for j in 0..n[1] as i32 {
            for k in 0..n[2] as i32 {
                voxels.push([i, j, k]);
            }
        }
    }
    let grid = crate::geom::VoxelGrid {
        origin: [0.0; 3],
        h,
        voxels,
    };
    let (mesh, _) = tetrahedralize(&grid);
    let mut mass = vec![0.0; mesh.num_nodes()];
    for t in 0..mesh.num_tets() {
        let m = rho * mesh.volume(t) / 4.0;
        for &a in &mesh.tets[t] {
            mass[a as usize] += m;
        }
    }
    (mesh, mass)
}

/// Statistics and timings of an embedding.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct EmbedStats {
    /// Voxel size used (m) and how it was chosen.
    pub voxel_size: f64,
    pub voxel_size_rule: String,
    pub voxels: usize,
    /// Voxels added beyond the open-cube supercover to keep yarns face-connected.
    pub extra_voxels: usize,
    pub nodes: usize,
    pub tets: usize,
    pub yarn_vertices: usize,
    /// Yarn pieces (segments split at tet boundaries).
    pub pieces: usize,
    /// Sum of linear density x segment length (kg); equals the total node mass.
    pub total_yarn_mass: f64,
    pub voxelize_ms: f64,
    pub tetrahedralize_ms: f64,
    pub mass_ms: f64,
    pub embedding_ms: f64,
}

/// Everything the embedding stage produces.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Embedded {
    pub grid: VoxelGrid,
    pub mesh: TetMesh,
    /// Voxel (index into `grid.voxels`) of each tet.
    pub tet_voxel: Vec<u32>,
    /// Lumped node masses (kg).
    pub node_mass: Vec<f64>,
    /// Per-curve linear density used (kg/m). With per-vertex radii it is the
    /// curve's mass over its length (see `segment_linear_density`).
    pub linear_density: Vec<f64>,
    /// Linear density (kg/m) of each segment in `Yarns::segments()` order.
    pub segment_linear_density: Vec<f64>,
    pub embedding: Embedding,
    /// Every yarn segment split at tet boundaries.
    pub pieces: Vec<YarnPiece>,
    pub stats: EmbedStats,
}

/// Embeds yarns (m) in a voxel tet mesh (VH §4-5):
///
/// 1. voxel size: `params.voxel_size`, else [`default_voxel_size`];
/// 2. [`voxelize`]: closed-cube supercover of every segment (default origin);
/// 3. [`tetrahedralize`]: 6 Kuhn tets per voxel, conforming;
/// 4. every segment split at the tet boundaries into [`YarnPiece`]s, and the
///    lumped node masses of VH Eq. 1-3 (exact line integrals of the linear
///    shape functions times the linear density);
/// 5. the V2Y embedding of VH Eq. 4: each yarn vertex's tet and barycentric
///    weights ([`locate`]).
///
/// Linear density: `yarns.linear_density` per curve when present, else
/// `material_density x pi r^2` with `r` the curve radius, or per segment the
/// mean of its two vertex radii when the yarns carry per-vertex radii.
/// Deterministic: the same input gives bit-identical output for any thread count.
pub fn embed(yarns: &Yarns, params: &EmbedParams) -> Result<Embedded, EmbedError> {
    voxelize::check_yarns(yarns)?;
    check_params(params)?;
    let start = Instant::now();
    let (grid, extra, rule) = match params.voxel_size {
        Some(h) => {
            // Refused from the counts alone, before the walk allocates.
            let prep = voxelize::Prepared::new(yarns, h, None)?;
            if prep.min_voxels > params.max_voxels as f64 {
                return Err(EmbedError::TooManyVoxels {
                    h,
                    estimate: prep.min_voxels.min(u64::MAX as f64) as u64,
                    limit: params.max_voxels,
                });
            }
            let work = prep.work(params.max_voxels);
            if work.bytes > params.max_memory {
                return Err(EmbedError::TooMuchWork {
                    h,
                    pieces: work.pieces,
                    bytes: work.bytes,
                    limit: params.max_memory,
                });
            }
            let (keys, extra) = prep.voxels_capped(params.max_voxels)?;
            let grid = VoxelGrid {
                voxels: keys.into_iter().map(keys::key_cell).collect(),
                ..prep.grid
            };
            (grid, extra, format!("given: {h} m"))
        }
        None => {
            let c = size::choose(yarns, params)?;
            (c.grid, c.extra, c.rule)
        }
    };
    let voxelize_ms = ms_since(start);

    let start = Instant::now();
    let (mesh, tet_voxel) = tetrahedralize(&grid);
    let tetrahedralize_ms = ms_since(start);

    let start = Instant::now();
    let g: Vec<_> = yarns.points.par_iter().map(|&p| grid.to_grid(p)).collect();
    let segments: Vec<[usize; 2]> = yarns.segments().collect();
    let lengths: Vec<f64> = segments
        .iter()
        .map(|&[a, b]| dist(yarns.points[a], yarns.points[b]))
        .collect();
    let (segment_linear_density, linear_density) =
        linear_densities(yarns, params.material_density, &lengths);
    let split = mass::split_segments(&grid, &g, &segments, &lengths)?;
    let node_mass = mass::lump_masses(
        &mesh.tets,
        mesh.num_nodes(),
        &split,
        &segment_linear_density,
    );
    let pieces: Vec<YarnPiece> = split.into_iter().map(|p| p.piece).collect();
    let total_yarn_mass = lengths
        .iter()
        .zip(&segment_linear_density)
        .map(|(l, d)| l * d)
        .sum();
    let mass_ms = ms_since(start);

    let start = Instant::now();
    let embedding = embed_vertices(&grid, &g)?;
    let embedding_ms = ms_since(start);

    let stats = EmbedStats {
        voxel_size: grid.h,
        voxel_size_rule: rule,
        voxels: grid.voxels.len(),
        extra_voxels: extra,
        nodes: mesh.num_nodes(),
        tets: mesh.num_tets(),
        yarn_vertices: yarns.num_points(),
        pieces: pieces.len(),
        total_yarn_mass,
        voxelize_ms,
        tetrahedralize_ms,
        mass_ms,
        embedding_ms,
    };
    Ok(Embedded {
        grid,
        mesh,
        tet_voxel,
        node_mass,
        linear_density,
        segment_linear_density,
        embedding,
        pieces,
        stats,
    })
}

impl Embedded {
    /// The V2Y matrix `N` of VH Eq. 4 (yarn vertices x mesh nodes, 4 entries a
    /// row: the barycentric weights of the vertex in its tet), so that
    /// `x_yarn = N x_nodes` coordinate by coordinate.
    pub fn v2y_matrix(&self) -> Result<faer::sparse::SparseColMat<usize, f64>, EmbedError> {
        v2y_matrix(&self.embedding, &self.mesh)
    }
}

/// The V2Y matrix (VH Eq. 4) of an embedding in `mesh`; see [`Embedded::v2y_matrix`].
pub fn v2y_matrix(
    embedding: &Embedding,
    mesh: &TetMesh,
) -> Result<faer::sparse::SparseColMat<usize, f64>, EmbedError> {
    use faer::sparse::{SparseColMat, Triplet};
    let mut triplets = Vec::with_capacity(4 * embedding.num_vertices());
    for (row, (&t, w)) in embedding.tet.iter().zip(&embedding.weights).enumerate() {
        let ids = mesh.tets.get(t as usize).ok_or_else(|| {
            EmbedError::Parameter(format!("vertex {row} refers to tet {t}, beyond the mesh"))
        })?;
        for a in 0..4 {
            triplets.push(Triplet::new(row, ids[a] as usize, w[a]));
        }
    }
    SparseColMat::try_new_from_triplets(embedding.num_vertices(), mesh.num_nodes(), &triplets)
        .map_err(|e| EmbedError::Parameter(format!("V2Y matrix: {e:?}")))
}

/// Checks the parameters that do not depend on the yarns.
fn check_params(params: &EmbedParams) -> Result<(), EmbedError> {
    if let Some(h) = params.voxel_size {
        if !(h.is_finite() && h > 0.0) {
            return Err(EmbedError::BadVoxelSize(h));
        }
    }
    let r = params.target_node_ratio;
    if !(r.is_finite() && r > 0.0) {
        return Err(EmbedError::Parameter(format!(
            "target_node_ratio {} must be a positive finite number",
            crate::geom::num(r)
        )));
    }
    let d = params.material_density;
    if !(d.is_finite() && d > 0.0) {
        return Err(EmbedError::Parameter(format!(
            "material_density {} kg/m^3 must be a positive finite number",
            crate::geom::num(d)
        )));
    }
    Ok(())
}

/// Per segment (in `yarns.segments()` order) the linear density (kg/m) an
/// embedding gives it: the yarn's own, else `density` (kg/m³) times the
/// cross-section of its radius, as [`embed`] lumps it.
pub fn segment_linear_densities(yarns: &Yarns, density: f64) -> Vec<f64> {
    let lengths: Vec<f64> = yarns
        .segments()
        .map(|[a, b]| dist(yarns.points[a], yarns.points[b]))
        .collect();
    linear_densities(yarns, density, &lengths).0
}

/// Linear densities (kg/m): per segment (in `Yarns::segments()` order) and per
/// curve (the curve's mass over its length when radii vary per vertex).
fn linear_densities(yarns: &Yarns, density: f64, lengths: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let area = |r: f64| density * std::f64::consts::PI * r * r;
    let mut per_segment = Vec::with_capacity(lengths.len());
    let mut per_curve = Vec::with_capacity(yarns.num_curves());
    for c in 0..yarns.num_curves() {
        let first = per_segment.len();
        for [a, b] in yarns.segments_of(c) {
            per_segment.push(match (&yarns.linear_density, &yarns.vertex_radius) {
                (Some(ld), _) => ld[c],
                (None, Some(vr)) => area(0.5 * (vr[a] + vr[b])),
                (None, None) => area(yarns.radius[c]),
            });
        }
        let seg = first..per_segment.len();
        let len: f64 = lengths[seg.clone()].iter().sum();
        per_curve.push(match &yarns.linear_density {
            Some(ld) => ld[c],
            None if yarns.vertex_radius.is_some() && len > 0.0 => {
                let m: f64 = per_segment[seg.clone()]
                    .iter()
                    .zip(&lengths[seg])
                    .map(|(d, l)| d * l)
                    .sum();
                m / len
            }
            None => area(yarns.radius[c]),
        });
    }
    (per_segment, per_curve)
}

/// The V2Y embedding (VH Eq. 4) of every yarn vertex (grid coordinates `g`).
fn embed_vertices(grid: &VoxelGrid, g: &[crate::geom::Vec3]) -> Result<Embedding, EmbedError> {
    let locs: Vec<Option<Location>> = g
        .par_iter()
        .map(|&p| tetrahedralize::locate_grid(grid, p))
        .collect();
    let mut embedding = Embedding {
        tet: Vec::with_capacity(g.len()),
        weights: Vec::with_capacity(g.len()),
    };
    for (v, l) in locs.into_iter().enumerate() {
        // The supercover keeps every voxel whose closed cube holds a vertex.
        let l = l.ok_or_else(|| {
            EmbedError::Internal(format!("yarn vertex {v} lies in no voxel of the grid"))
        })?;
        embedding.tet.push(l.tet);
        embedding.weights.push(l.weights);
    }
    Ok(embedding)
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
