//! The homogenized asset as VTKHDF (`.vtkhdf`; the layout is documented in
//! schemas/asset-vtkhdf.md).
//!
//! The file is an HDF5 file that ParaView / VTK's `vtkHDFReader` opens with no
//! plugin: `/VTKHDF` holds a VTKHDF 2.2 `UnstructuredGrid` of linear tets with
//! the per-tet stiffnesses and domains as cell data and the lumped node masses
//! as point data; an asset with a time series of node positions carries a
//! `/VTKHDF/Steps` group with a fixed topology. Everything else knitvox needs
//! (rest nodes, voxel grid, embedding, rest yarns, parameters, provenance,
//! per-step fit error) lives beside it in `/knitvox`, which VTK ignores.
//!
//! Fixed-topology time series, as checked against vtkHDFReader (VTK 9.7.2,
//! tests/io_vtkhdf.rs): `NumberOfPoints`, `NumberOfCells` and
//! `NumberOfConnectivityIds` hold one value per step, `Steps/NumberOfParts` is
//! 1 per step, `Steps/PartOffsets` and every topology and data offset are
//! zero, and only `Steps/PointOffsets = step * nPoints` moves. Observed
//! alternatives: single `NumberOf*` values without `NumberOfParts` make the
//! reader fail at step 0; single values with `PartOffsets = step` (VTK's own
//! example) show step 0's points at every step. The node masses are stored
//! once (`Steps/PointDataOffsets/mass` all zero), which the reader replays at
//! every step.
//!
//! Reading validates every dataset's rank, shape and type, bounds every count
//! by [`MAX_ELEMENTS`] and by the bytes the file really stores before
//! allocating, and reports problems as [`IoError::Format`] naming the dataset
//! (`/VTKHDF/Connectivity: ...`). A file another process is writing is
//! [`IoError::Busy`], as in `io::h5`.

use std::path::Path;

use hdf5::Group;

use super::h5::{self, Ds, Kind};
use super::{FormatError, IoError, ReadOptions};
use crate::geom::{
    is_unit_vector, Asset, AssetFibres, Embedding, GeomError, NodeSteps, Provenance, TetMesh, Vec3,
    VoxelGrid,
};

/// Value of the `/knitvox` attribute `knitvox_format` in an asset file.
pub const FORMAT_NAME: &str = "asset";
/// Layout version written in `/knitvox@knitvox_format_version`; readers refuse
/// files with a larger version.
pub const FORMAT_VERSION: i64 = 1;
/// The VTKHDF version written in `/VTKHDF@Version`.
pub const VTKHDF_VERSION: [i64; 2] = [2, 2];
/// VTK's cell type id of a linear tetrahedron.
pub const VTK_TETRA: u8 = 10;
/// Most elements the reader accepts in any one count: nodes, tets, voxels,
/// steps, nodes x steps, connectivity ids (2^31, as `io::DEFAULT_MAX_POINTS`).
pub const MAX_ELEMENTS: u64 = super::DEFAULT_MAX_POINTS;
/// Largest JSON text (`/knitvox/parameters`, `/knitvox/provenance`) the reader accepts.
pub const MAX_JSON_BYTES: usize = 64 << 20;

const VTK: &str = "/VTKHDF";
const STEPS: &str = "/VTKHDF/Steps";
const KV: &str = "/knitvox";

// ---------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------

/// Writes an asset atomically (libhdf5 writes a dot-prefixed temporary file in
/// the target's directory, which is fsynced and renamed onto `path`). An
/// inconsistent asset (lengths that do not match, indices out of range,
/// non-finite values) is refused with [`IoError::Write`] before anything is written.
pub fn write_asset(path: &Path, asset: &Asset) -> Result<(), IoError> {
    let refuse = |m: String| {
        h5::write_err(
            path,
            h5::invalid_input(format!("refusing to write an invalid asset: {m}")),
        )
    };
    check_asset(asset).map_err(|e| refuse(e.to_string()))?;
    let parameters = serde_json::to_vec(&asset.parameters)
        .map_err(|e| refuse(format!("parameters cannot be written as JSON: {e}")))?;
    let provenance = serde_json::to_vec(&asset.provenance)
        .map_err(|e| refuse(format!("provenance cannot be written as JSON: {e}")))?;
    super::atomic::write_with(path, |tmp| {
        let file = h5::create_h5(tmp)?;
        write_vtk(&file, asset)?;
        write_knitvox(&file, asset, &parameters, &provenance)?;
        file.close()?;
        Ok(())
    })
}

fn all_finite(v: &[f64]) -> Option<usize> {
    v.iter().position(|x| !x.is_finite())
}

/// Why an asset cannot be written: what the reader would refuse.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum AssetCheckError {
    /// A rest node coordinate is not finite.
    #[error("rest node {node}: coordinate is not finite")]
    NonFiniteNode { node: usize },
    /// A tet names a node the mesh does not have.
    #[error("tet {tet} {nodes:?}: node index out of range ({count} nodes)")]
    TetNode {
        tet: usize,
        nodes: [u32; 4],
        count: usize,
    },
    /// An array without one entry per tet, node, step or yarn vertex.
    #[error("{what} has {got} entries, expected {want} (one per {per})")]
    Length {
        what: &'static str,
        got: usize,
        want: usize,
        per: &'static str,
    },
    /// A tet names a voxel the grid does not have.
    #[error("tet {tet}: voxel {voxel} out of range ({voxels} voxels)")]
    TetVoxel {
        tet: usize,
        voxel: u32,
        voxels: usize,
    },
    /// A node mass (kg) is negative or not finite.
    #[error("node {node}: mass {mass} is not a non-negative finite number")]
    NodeMass { node: usize, mass: f64 },
    /// A stiffness (Pa) outside `[0, MAX_STIFFNESS_PA]`.
    #[error(
        "tet {tet}: {name} {value:e} Pa is not a finite value in [0, {MAX_STIFFNESS_PA:e}] Pa"
    )]
    Stiffness {
        tet: usize,
        name: &'static str,
        value: f64,
    },
    /// A fibre array without one entry per tet.
    #[error("{name} has {got} entries for {tets} tets")]
    FibreLength {
        name: &'static str,
        got: usize,
        tets: usize,
    },
    /// A fibre direction that is not a unit vector.
    #[error("tet {tet}: {name} {direction:?} is not a unit vector")]
    FibreDirection {
        tet: usize,
        name: &'static str,
        direction: Vec3,
    },
    /// The voxel grid's origin or size is not finite.
    #[error("voxel grid origin or size is not finite")]
    GridNotFinite,
    /// The voxel size (m) of a grid with voxels is not positive.
    #[error("voxel size {h} is not positive")]
    VoxelSize { h: f64 },
    /// The rest yarns are not well formed.
    #[error("rest yarns: {0}")]
    RestYarns(#[source] GeomError),
    /// A yarn vertex is embedded in a tet the mesh does not have.
    #[error("yarn vertex {vertex}: tet {tet} out of range ({tets} tets)")]
    EmbeddingTet {
        vertex: usize,
        tet: u32,
        tets: usize,
    },
    /// A yarn vertex's embedding weight is not finite.
    #[error("yarn vertex {vertex}: weight is not finite")]
    EmbeddingWeight { vertex: usize },
    /// A step time is not finite.
    #[error("step {step}: time is not finite")]
    StepTime { step: usize },
    /// The number of step positions overflows.
    #[error("{steps} steps x {nodes} nodes overflows")]
    StepOverflow { steps: usize, nodes: usize },
    /// The steps hold another number of positions than steps x nodes.
    #[error("steps hold {got} positions, expected {steps} steps x {nodes} nodes = {want}")]
    StepPositions {
        got: usize,
        steps: usize,
        nodes: usize,
        want: usize,
    },
    /// A step position is not finite.
    #[error("step {step}, node {node}: position is not finite")]
    StepPosition { step: usize, node: usize },
    /// A step's fit error is not finite.
    #[error("step {step}: fit_error is not finite")]
    StepFitError { step: usize },
}

/// Everything the reader will check, so that a written file always reads back.
fn check_asset(a: &Asset) -> Result<(), AssetCheckError> {
    let n = a.mesh.nodes.len();
    let t = a.mesh.tets.len();
    let nv = a.grid.voxels.len();
    if let Some(i) = all_finite(a.mesh.nodes.as_flattened()) {
        return Err(AssetCheckError::NonFiniteNode { node: i / 3 });
    }
    if let Some((i, tet)) = a
        .mesh
        .tets
        .iter()
        .enumerate()
        .find(|(_, tet)| tet.iter().any(|&v| v as usize >= n))
    {
        return Err(AssetCheckError::TetNode {
            tet: i,
            nodes: *tet,
            count: n,
        });
    }
    let len = |what: &'static str, got: usize, want: usize, per: &'static str| {
        if got == want {
            Ok(())
        } else {
            Err(AssetCheckError::Length {
                what,
                got,
                want,
                per,
            })
        }
    };
    len("tet_voxel", a.tet_voxel.len(), t, "tet")?;
    if let Some((i, &v)) = a
        .tet_voxel
        .iter()
        .enumerate()
        .find(|(_, &v)| v as usize >= nv)
    {
        return Err(AssetCheckError::TetVoxel {
            tet: i,
            voxel: v,
            voxels: nv,
        });
    }
    len("node_mass", a.node_mass.len(), n, "node")?;
    if let Some(i) = a
        .node_mass
        .iter()
        .position(|m| !(m.is_finite() && *m >= 0.0))
    {
        return Err(AssetCheckError::NodeMass {
            node: i,
            mass: a.node_mass[i],
        });
    }
    len("gamma_s", a.gamma_s.len(), t, "tet")?;
    len("gamma_v", a.gamma_v.len(), t, "tet")?;
    len("domain", a.domain.len(), t, "tet")?;
    check_stiffness("gamma_s", &a.gamma_s)?;
    check_stiffness("gamma_v", &a.gamma_v)?;
    if let Some(f) = &a.fibres {
        check_fibres(f, t)?;
    }
    if all_finite(&a.grid.origin).is_some() || !a.grid.h.is_finite() {
        return Err(AssetCheckError::GridNotFinite);
    }
    if nv > 0 && a.grid.h <= 0.0 {
        return Err(AssetCheckError::VoxelSize { h: a.grid.h });
    }
    a.rest_yarns
        .validate()
        .map_err(AssetCheckError::RestYarns)?;
    let m = a.rest_yarns.num_points();
    len(
        "embedding.tet",
        a.embedding.tet.len(),
        m,
        "rest yarn vertex",
    )?;
    len(
        "embedding.weights",
        a.embedding.weights.len(),
        m,
        "rest yarn vertex",
    )?;
    if let Some((i, &v)) = a
        .embedding
        .tet
        .iter()
        .enumerate()
        .find(|(_, &v)| v as usize >= t)
    {
        return Err(AssetCheckError::EmbeddingTet {
            vertex: i,
            tet: v,
            tets: t,
        });
    }
    if let Some(i) = all_finite(a.embedding.weights.as_flattened()) {
        return Err(AssetCheckError::EmbeddingWeight { vertex: i / 4 });
    }
    let s = a.steps.num_steps();
    if let Some(i) = all_finite(&a.steps.times) {
        return Err(AssetCheckError::StepTime { step: i });
    }
    let want = s
        .checked_mul(n)
        .ok_or(AssetCheckError::StepOverflow { steps: s, nodes: n })?;
    if a.steps.positions.len() != want {
        return Err(AssetCheckError::StepPositions {
            got: a.steps.positions.len(),
            steps: s,
            nodes: n,
            want,
        });
    }
    if let Some(i) = all_finite(a.steps.positions.as_flattened()) {
        let k = i / 3;
        return Err(AssetCheckError::StepPosition {
            step: k / n.max(1),
            node: k % n.max(1),
        });
    }
    if !a.steps.fit_error.is_empty() {
        len("steps.fit_error", a.steps.fit_error.len(), s, "step")?;
        if let Some(i) = all_finite(&a.steps.fit_error) {
            return Err(AssetCheckError::StepFitError { step: i });
        }
    }
    Ok(())
}

/// A 2-D dataset of `data.len() / cols` rows of `cols` values.
fn write_2d<T: hdf5::H5Type>(
    g: &Group,
    name: &str,
    data: &[T],
    cols: usize,
    units: Option<&str>,
) -> hdf5::Result<()> {
    let ds = g
        .new_dataset::<T>()
        .shape([data.len() / cols, cols])
        .create(name)?;
    if !data.is_empty() {
        ds.write_raw(data)?;
    }
    if let Some(u) = units {
        h5::write_str_attr(&ds, "units", u)?;
    }
    Ok(())
}

fn i64_of(x: usize) -> i64 {
    // Counts of in-memory vectors always fit (isize::MAX <= i64::MAX).
    x as i64
}

/// `/VTKHDF`: what VTK reads.
fn write_vtk(file: &hdf5::File, a: &Asset) -> hdf5::Result<()> {
    let g = h5::new_group(file, "VTKHDF")?;
    g.new_attr::<i64>()
        .shape([2])
        .create("Version")?
        .write_raw(&VTKHDF_VERSION)?;
    h5::write_str_attr(&g, "Type", "UnstructuredGrid")?;
    let n = a.mesh.nodes.len();
    let t = a.mesh.tets.len();
    let s = a.steps.num_steps();
    // One entry per step (see the module doc); a static grid has one part.
    let parts = s.max(1);
    h5::write_1d(&g, "NumberOfPoints", &vec![i64_of(n); parts], None)?;
    h5::write_1d(&g, "NumberOfCells", &vec![i64_of(t); parts], None)?;
    h5::write_1d(
        &g,
        "NumberOfConnectivityIds",
        &vec![i64_of(4 * t); parts],
        None,
    )?;
    let points: &[Vec3] = if s > 0 {
        &a.steps.positions
    } else {
        &a.mesh.nodes
    };
    write_2d(&g, "Points", points.as_flattened(), 3, Some("m"))?;
    let conn: Vec<i64> = a
        .mesh
        .tets
        .iter()
        .flat_map(|tet| tet.map(i64::from))
        .collect();
    h5::write_1d(&g, "Connectivity", &conn, None)?;
    let offsets: Vec<i64> = (0..=t).map(|i| i64_of(4 * i)).collect();
    h5::write_1d(&g, "Offsets", &offsets, None)?;
    h5::write_1d(&g, "Types", &vec![VTK_TETRA; t], None)?;
    let cd = h5::new_group(&g, "CellData")?;
    h5::write_1d(&cd, "gamma_s", &a.gamma_s, Some("Pa"))?;
    h5::write_1d(&cd, "gamma_v", &a.gamma_v, Some("Pa"))?;
    h5::write_1d(&cd, "domain", &a.domain, None)?;
    if let Some(f) = &a.fibres {
        write_2d(&cd, "course_direction", f.course.as_flattened(), 3, None)?;
        write_2d(&cd, "wale_direction", f.wale.as_flattened(), 3, None)?;
        h5::write_1d(&cd, "gamma_course", &f.gamma_course, Some("Pa"))?;
        h5::write_1d(&cd, "gamma_wale", &f.gamma_wale, Some("Pa"))?;
        if !f.beta_course.is_empty() {
            h5::write_1d(&cd, "beta_course", &f.beta_course, None)?;
            h5::write_1d(&cd, "beta_wale", &f.beta_wale, None)?;
        }
    }
    let pd = h5::new_group(&g, "PointData")?;
    h5::write_1d(&pd, "mass", &a.node_mass, Some("kg"))?;
    if s > 0 {
        let st = h5::new_group(&g, "Steps")?;
        st.new_attr::<i64>()
            .shape(())
            .create("NSteps")?
            .write_scalar(&i64_of(s))?;
        h5::write_1d(&st, "Values", &a.steps.times, Some("s"))?;
        let zeros = vec![0i64; s];
        let point_offsets: Vec<i64> = (0..s).map(|k| i64_of(k * n)).collect();
        h5::write_1d(&st, "PointOffsets", &point_offsets, None)?;
        h5::write_1d(&st, "PartOffsets", &zeros, None)?;
        h5::write_1d(&st, "NumberOfParts", &vec![1i64; s], None)?;
        write_2d(&st, "CellOffsets", &zeros, 1, None)?;
        write_2d(&st, "ConnectivityIdOffsets", &zeros, 1, None)?;
        let cdo = h5::new_group(&st, "CellDataOffsets")?;
        let fibre_names: &[&str] = match &a.fibres {
            Some(f) if !f.beta_course.is_empty() => &FIBRE_CELL_DATA_STIFFENING,
            Some(_) => &FIBRE_CELL_DATA,
            None => &[],
        };
        for name in ["gamma_s", "gamma_v", "domain"].iter().chain(fibre_names) {
            h5::write_1d(&cdo, name, &zeros, None)?;
        }
        let pdo = h5::new_group(&st, "PointDataOffsets")?;
        h5::write_1d(&pdo, "mass", &zeros, None)?;
    }
    Ok(())
}

/// `/knitvox`: what only knitvox reads.
fn write_knitvox(
    file: &hdf5::File,
    a: &Asset,
    parameters: &[u8],
    provenance: &[u8],
) -> hdf5::Result<()> {
    let g = h5::new_group(file, "knitvox")?;
    h5::write_str_attr(&g, "knitvox_format", FORMAT_NAME)?;
    g.new_attr::<i64>()
        .shape(())
        .create("knitvox_format_version")?
        .write_scalar(&FORMAT_VERSION)?;
    h5::write_str_attr(&g, "units", "m")?;
    h5::write_str_attr(&g, "up_axis", "y")?;
    h5::write_str_attr(
        &g,
        "generator",
        &format!("knitvox {}", env!("CARGO_PKG_VERSION")),
    )?;
    write_2d(&g, "rest_nodes", a.mesh.nodes.as_flattened(), 3, Some("m"))?;
    h5::write_1d(&g, "tet_voxel", &a.tet_voxel, None)?;
    let grid = h5::new_group(&g, "grid")?;
    h5::write_1d(&grid, "origin", &a.grid.origin, Some("m"))?;
    let h = grid.new_dataset::<f64>().shape(()).create("h")?;
    h.write_scalar(&a.grid.h)?;
    h5::write_str_attr(&h, "units", "m")?;
    write_2d(&grid, "voxels", a.grid.voxels.as_flattened(), 3, None)?;
    let emb = h5::new_group(&g, "embedding")?;
    h5::write_1d(&emb, "tet", &a.embedding.tet, None)?;
    write_2d(&emb, "weights", a.embedding.weights.as_flattened(), 4, None)?;
    h5::write_yarns_group(&h5::new_group(&g, "rest_yarns")?, &a.rest_yarns)?;
    for (name, json) in [("parameters", parameters), ("provenance", provenance)] {
        h5::write_1d(&g, name, json, None)?;
        let ds = g.dataset(name)?;
        h5::write_str_attr(&ds, "content_type", "application/json")?;
    }
    if !a.steps.fit_error.is_empty() {
        h5::write_1d(&g, "fit_error", &a.steps.fit_error, Some("m"))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------

/// Reads an asset written by [`write_asset`], every value bit for bit.
pub fn read_asset(path: &Path) -> Result<Asset, IoError> {
    let file = h5::open_path(path)?;
    let _budget = h5::whole_file_budget(super::max_memory());
    let layout = Layout::open(&file).map_err(|e| h5::format_err(path, e))?;
    read_contents(&layout, true).map_err(|e| h5::format_err(path, e))
}

/// Reads the node positions (m) of step `s` (0-based) without loading the other steps.
pub fn read_step(path: &Path, s: usize) -> Result<Vec<Vec3>, IoError> {
    let file = h5::open_path(path)?;
    read_step_of(&file, s).map_err(|e| h5::format_err(path, e))
}

/// What `knitvox inspect asset.vtkhdf` shows; read without the per-step positions.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AssetSummary {
    /// `/knitvox@knitvox_format_version`.
    pub format_version: i64,
    /// Tet mesh nodes.
    pub nodes: usize,
    /// Tets.
    pub tets: usize,
    /// Occupied voxels.
    pub voxels: usize,
    /// Voxel edge length (m).
    pub voxel_size: f64,
    /// Voxel grid origin (m).
    pub grid_origin: Vec3,
    /// Bounding box of the rest nodes (m), `[min, max]`; `None` without nodes.
    pub rest_bounds: Option<[Vec3; 2]>,
    /// Steps of the node time series (0: a static asset).
    pub steps: usize,
    /// First and last step time (s).
    pub time_range: Option<[f64; 2]>,
    /// Smallest and largest per-step fit error (m), when the file has them.
    pub fit_error_range: Option<[f64; 2]>,
    /// Rest yarn curves.
    pub yarn_curves: usize,
    /// Rest yarn vertices (each embedded in one tet).
    pub yarn_points: usize,
    /// Sum of the lumped node masses (kg).
    pub total_mass: f64,
    /// The lumped node masses' rotational inertia over the rest yarns'
    /// about each of the yarns' principal axes, smallest moment first
    /// (1: a spin of the mesh has the yarns' inertia; VH §5, the mass is
    /// lumped up to a voxel from the yarns); `None` without yarns or for a
    /// degenerate (straight) set.
    pub lumped_inertia_ratio: Option<[f64; 3]>,
    /// Smallest and largest gamma_s (Pa).
    pub gamma_s_range: Option<[f64; 2]>,
    /// Smallest and largest gamma_v (Pa).
    pub gamma_v_range: Option<[f64; 2]>,
    /// Smallest and largest fibre stiffness along the course and the wale
    /// (Pa); `None` for an asset without fibres.
    pub gamma_course_range: Option<[f64; 2]>,
    pub gamma_wale_range: Option<[f64; 2]>,
    /// Smallest and largest knit-material stiffening along the course and
    /// the wale (dimensionless); `None` for quadratic fibres or none.
    pub beta_course_range: Option<[f64; 2]>,
    pub beta_wale_range: Option<[f64; 2]>,
    /// Number of distinct domain ids.
    pub domains: usize,
    pub provenance: Provenance,
    pub parameters: serde_json::Value,
}

fn range(v: &[f64]) -> Option<[f64; 2]> {
    let first = *v.first()?;
    Some(
        v.iter()
            .fold([first, first], |[lo, hi], &x| [lo.min(x), hi.max(x)]),
    )
}

/// [`AssetSummary::lumped_inertia_ratio`]: the yarns' line density as the
/// embedding made it (the parameters' material density, 1200 kg/m³ when
/// they hold none; the ratio is per unit mass, so only its variation along
/// the yarns matters).
fn lumped_inertia_ratio(a: &Asset) -> Option<[f64; 3]> {
    let density = a.parameters["embed"]["material_density"]
        .as_f64()
        .unwrap_or(crate::embed::EmbedParams::default().material_density);
    let lambda = crate::embed::segment_linear_densities(&a.rest_yarns, density);
    crate::embed::compare_inertia(&a.rest_yarns, &lambda, &a.mesh.nodes, &a.node_mass)
        .map(|c| c.ratios())
}

/// A summary of an asset file for `knitvox inspect` (reads everything but the
/// per-step node positions).
pub fn summary(path: &Path) -> Result<AssetSummary, IoError> {
    let file = h5::open_path(path)?;
    let layout = Layout::open(&file).map_err(|e| h5::format_err(path, e))?;
    let a = read_contents(&layout, false).map_err(|e| h5::format_err(path, e))?;
    let rest_bounds = a.mesh.nodes.first().map(|&p0| {
        a.mesh.nodes.iter().fold([p0, p0], |[lo, hi], p| {
            [
                std::array::from_fn(|k| lo[k].min(p[k])),
                std::array::from_fn(|k| hi[k].max(p[k])),
            ]
        })
    });
    let mut domains = a.domain.clone();
    domains.sort_unstable();
    domains.dedup();
    Ok(AssetSummary {
        format_version: layout.version,
        nodes: a.mesh.num_nodes(),
        tets: a.mesh.num_tets(),
        voxels: a.grid.voxels.len(),
        voxel_size: a.grid.h,
        grid_origin: a.grid.origin,
        rest_bounds,
        steps: a.steps.num_steps(),
        time_range: a
            .steps
            .times
            .first()
            .zip(a.steps.times.last())
            .map(|(&t0, &t1)| [t0, t1]),
        fit_error_range: range(&a.steps.fit_error),
        yarn_curves: a.rest_yarns.num_curves(),
        yarn_points: a.rest_yarns.num_points(),
        total_mass: a.node_mass.iter().sum(),
        lumped_inertia_ratio: lumped_inertia_ratio(&a),
        gamma_s_range: range(&a.gamma_s),
        gamma_v_range: range(&a.gamma_v),
        gamma_course_range: a.fibres.as_ref().and_then(|f| range(&f.gamma_course)),
        gamma_wale_range: a.fibres.as_ref().and_then(|f| range(&f.gamma_wale)),
        beta_course_range: a.fibres.as_ref().and_then(|f| range(&f.beta_course)),
        beta_wale_range: a.fibres.as_ref().and_then(|f| range(&f.beta_wale)),
        domains: domains.len(),
        provenance: a.provenance,
        parameters: a.parameters,
    })
}

/// CellData arrays of the fibre families: all four or none.
const FIBRE_CELL_DATA: [&str; 4] = [
    "course_direction",
    "wale_direction",
    "gamma_course",
    "gamma_wale",
];

/// [`FIBRE_CELL_DATA`] with the knit material's stiffenings (both or none).
const FIBRE_CELL_DATA_STIFFENING: [&str; 6] = [
    "course_direction",
    "wale_direction",
    "gamma_course",
    "gamma_wale",
    "beta_course",
    "beta_wale",
];

/// Unit directions (to 1e-6) and finite stiffnesses `>= 0`, one per tet.
fn check_fibres(f: &AssetFibres, t: usize) -> Result<(), AssetCheckError> {
    if !(f.beta_course.is_empty() && f.beta_wale.is_empty()) {
        for (name, n) in [
            ("beta_course", f.beta_course.len()),
            ("beta_wale", f.beta_wale.len()),
        ] {
            if n != t {
                return Err(AssetCheckError::FibreLength {
                    name,
                    got: n,
                    tets: t,
                });
            }
        }
        check_stiffness("beta_course", &f.beta_course)?;
        check_stiffness("beta_wale", &f.beta_wale)?;
    }
    for (name, n) in [
        ("course_direction", f.course.len()),
        ("wale_direction", f.wale.len()),
        ("gamma_course", f.gamma_course.len()),
        ("gamma_wale", f.gamma_wale.len()),
    ] {
        if n != t {
            return Err(AssetCheckError::FibreLength {
                name,
                got: n,
                tets: t,
            });
        }
    }
    for (name, d) in [("course_direction", &f.course), ("wale_direction", &f.wale)] {
        if let Some(i) = d.iter().position(|v| !is_unit_vector(v)) {
            return Err(AssetCheckError::FibreDirection {
                tet: i,
                name,
                direction: d[i],
            });
        }
    }
    check_stiffness("gamma_course", &f.gamma_course)?;
    check_stiffness("gamma_wale", &f.gamma_wale)
}

/// Largest stiffness an asset may carry (Pa), about diamond's Young's
/// modulus: knit materials lie around 1e1-1e6 Pa, so a value beyond this is
/// corruption, and it would overflow the simulator's matrices (a `γv` of
/// 1e300 made `K` lose positive definiteness, reported against the scene).
pub const MAX_STIFFNESS_PA: f64 = 1e12;

fn stiffness_in_range(v: f64) -> bool {
    (0.0..=MAX_STIFFNESS_PA).contains(&v)
}

/// Every stiffness of `name` (Pa) finite and in `[0, MAX_STIFFNESS_PA]`.
fn check_stiffness(name: &'static str, g: &[f64]) -> Result<(), AssetCheckError> {
    match g.iter().position(|v| !stiffness_in_range(*v)) {
        Some(i) => Err(AssetCheckError::Stiffness {
            tet: i,
            name,
            value: g[i],
        }),
        None => Ok(()),
    }
}

/// The fibre families of `CellData`, if it has them (all four arrays or
/// none; unit directions, stiffnesses finite and `>= 0`).
fn read_fibres(cd: &Group, cdp: &str, t: usize) -> Result<Option<AssetFibres>, FormatError> {
    let present: Vec<bool> = FIBRE_CELL_DATA.iter().map(|n| cd.link_exists(n)).collect();
    if !present.iter().any(|&p| p) {
        return Ok(None);
    }
    if let Some(k) = present.iter().position(|&p| !p) {
        return Err(FormatError::at_path(
            format!("{cdp}/{}", FIBRE_CELL_DATA[k]),
            "missing: fibre data needs course_direction, wale_direction, gamma_course and gamma_wale",
        ));
    }
    let per_tet = format!("[{t}] (one per tet)");
    let dirs = |name: &str| -> Result<Vec<Vec3>, FormatError> {
        let ds = required(cd, cdp, name)?;
        let v = read_floats(&ds, &[t, 3], &format!("[{t}, 3] (one unit vector per tet)"))?;
        let d: Vec<Vec3> = v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        if let Some(i) = d.iter().position(|v| !is_unit_vector(v)) {
            return Err(ds.err(format!("entry {i}: {:?} is not a unit vector", d[i])));
        }
        Ok(d)
    };
    let gammas = |name: &str| read_stiffness(&required(cd, cdp, name)?, t, &per_tet);
    // The knit material's stiffenings: both or neither.
    let (beta_course, beta_wale) =
        match (cd.link_exists("beta_course"), cd.link_exists("beta_wale")) {
            (false, false) => (Vec::new(), Vec::new()),
            (true, true) => (gammas("beta_course")?, gammas("beta_wale")?),
            (c, _) => {
                let missing = if c { "beta_wale" } else { "beta_course" };
                return Err(FormatError::at_path(
                    format!("{cdp}/{missing}"),
                    "missing: stiffening fibres need both beta_course and beta_wale",
                ));
            }
        };
    Ok(Some(AssetFibres {
        course: dirs("course_direction")?,
        wale: dirs("wale_direction")?,
        gamma_course: gammas("gamma_course")?,
        gamma_wale: gammas("gamma_wale")?,
        beta_course,
        beta_wale,
    }))
}

fn required(g: &Group, gp: &str, name: &str) -> Result<Ds, FormatError> {
    Ds::open(g, gp, name, true)?
        .ok_or_else(|| FormatError::at_path(format!("{gp}/{name}"), "required dataset is missing"))
}

fn required_group(parent: &Group, gp: &str, name: &str) -> Result<Group, FormatError> {
    let loc = format!("{gp}/{name}");
    h5::open_group(parent, name, &loc)?
        .ok_or_else(|| FormatError::at_path(&loc, "required group is missing"))
}

/// Checks that `count` fits [`MAX_ELEMENTS`].
fn limit(ds: &Ds, count: usize, what: &str) -> Result<(), FormatError> {
    if count as u64 > MAX_ELEMENTS {
        Err(ds.err(format!(
            "{count} {what} exceeds the limit of {MAX_ELEMENTS}"
        )))
    } else {
        Ok(())
    }
}

/// Reads a float dataset of exactly `shape` (rows x cols or a 1-D length) as f64.
fn read_floats(ds: &Ds, shape: &[usize], what: &str) -> Result<Vec<f64>, FormatError> {
    let expected: Vec<Option<usize>> = shape.iter().map(|&d| Some(d)).collect();
    ds.expect_shape(&expected, what)?;
    ds.expect_float()?;
    let elems = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| ds.err("size overflows"))?;
    let v = ds.read_f64(elems)?;
    if let Some(i) = all_finite(&v) {
        let row = if shape.len() == 2 { i / shape[1] } else { i };
        return Err(ds.err(format!("entry {row}: value {} is not finite", v[i])));
    }
    Ok(v)
}

/// A per-tet stiffness dataset (Pa), each value in `[0, MAX_STIFFNESS_PA]`.
fn read_stiffness(ds: &Ds, t: usize, what: &str) -> Result<Vec<f64>, FormatError> {
    let g = read_floats(ds, &[t], what)?;
    match g.iter().position(|v| !stiffness_in_range(*v)) {
        Some(i) => Err(ds.err(format!(
            "entry {i}: stiffness {:e} Pa is outside [0, {MAX_STIFFNESS_PA:e}] Pa",
            g[i]
        ))),
        None => Ok(g),
    }
}

fn expect_int(ds: &Ds) -> Result<(), FormatError> {
    match ds.ty.kind {
        Kind::Int { .. } => Ok(()),
        _ => Err(ds.err(format!("type {}, expected integers", ds.ty.describe()))),
    }
}

/// Reads an integer dataset of exactly `shape` as non-negative values below `bound`.
fn read_indices(ds: &Ds, shape: &[usize], bound: u64, what: &str) -> Result<Vec<u64>, FormatError> {
    let expected: Vec<Option<usize>> = shape.iter().map(|&d| Some(d)).collect();
    ds.expect_shape(&expected, what)?;
    expect_int(ds)?;
    let elems = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| ds.err("size overflows"))?;
    let v = ds.read_index(elems)?;
    if let Some((i, x)) = v.iter().enumerate().find(|(_, &x)| x >= bound) {
        return Err(ds.err(format!(
            "entry {i}: {x} is out of range (must be below {bound})"
        )));
    }
    Ok(v)
}

/// Reads a signed integer dataset of exactly `shape` as i32.
fn read_i32(ds: &Ds, shape: &[usize], what: &str) -> Result<Vec<i32>, FormatError> {
    let expected: Vec<Option<usize>> = shape.iter().map(|&d| Some(d)).collect();
    ds.expect_shape(&expected, what)?;
    expect_int(ds)?;
    let elems = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| ds.err("size overflows"))?;
    if elems == 0 {
        return Ok(Vec::new());
    }
    ds.guard_storage(elems)?;
    let v: Vec<i64> = ds
        .ds
        .read_raw()
        .map_err(|e| ds.err(format!("libhdf5 cannot read it: {}", h5::h5_message(&e))))?;
    v.into_iter()
        .enumerate()
        .map(|(i, x)| {
            i32::try_from(x).map_err(|_| ds.err(format!("entry {i}: {x} does not fit in int32")))
        })
        .collect()
}

/// Every entry of an integer dataset of `len` entries (rank 1, or rank 2 with
/// one column) must equal `want(i)`.
fn check_offsets(
    g: &Group,
    name: &str,
    len: usize,
    two_d: bool,
    want: impl Fn(usize) -> u64,
    why: &str,
) -> Result<(), FormatError> {
    let ds = required(g, STEPS, name)?;
    let ok_shape = ds.shape == [len] || (two_d && ds.shape == [len, 1]);
    if !ok_shape {
        return Err(ds.err(format!(
            "shape {:?}, expected [{len}]{} (one entry per step)",
            ds.shape,
            if two_d {
                format!(" or [{len}, 1]")
            } else {
                String::new()
            }
        )));
    }
    expect_int(&ds)?;
    let v = ds.read_index(len)?;
    if let Some((i, x)) = v.iter().enumerate().find(|(i, &x)| x != want(*i)) {
        return Err(ds.err(format!("step {i}: {x}, expected {} ({why})", want(i))));
    }
    Ok(())
}

/// The opened groups and the counts every other check depends on.
struct Layout {
    vtk: Group,
    kv: Group,
    /// `/VTKHDF/Steps` when the asset has a time series.
    steps: Option<Group>,
    version: i64,
    /// Nodes.
    n: usize,
    /// Tets.
    t: usize,
    /// Steps (0: static).
    s: usize,
    points: Ds,
    rest_nodes: Ds,
    connectivity: Ds,
}

fn read_version_attr(vtk: &Group) -> Result<[i64; 2], FormatError> {
    let loc = format!("{VTK}@Version");
    let names = vtk
        .attr_names()
        .map_err(|e| FormatError::at_path(VTK, h5::h5_message(&e)))?;
    if !names.iter().any(|n| n == "Version") {
        return Err(FormatError::at_path(&loc, "required attribute is missing"));
    }
    let attr = vtk
        .attr("Version")
        .map_err(|e| FormatError::at_path(&loc, h5::h5_message(&e)))?;
    let ty = h5::type_info(
        &attr
            .dtype()
            .map_err(|e| FormatError::at_path(&loc, h5::h5_message(&e)))?,
    );
    if attr.shape() != [2] || !matches!(ty.kind, Kind::Int { .. }) {
        return Err(FormatError::at_path(
            &loc,
            format!(
                "expected 2 integers [major, minor], found {} of shape {:?}",
                ty.describe(),
                attr.shape()
            ),
        ));
    }
    let v: Vec<i64> = attr
        .read_raw()
        .map_err(|e| FormatError::at_path(&loc, h5::h5_message(&e)))?;
    match v[..] {
        [a, b] => Ok([a, b]),
        _ => Err(FormatError::at_path(&loc, "expected 2 integers")),
    }
}

impl Layout {
    fn open(file: &hdf5::File) -> Result<Layout, FormatError> {
        let root: &Group = file;
        let vtk = h5::open_group(root, "VTKHDF", VTK)?.ok_or_else(|| {
            FormatError::whole_file(format!(
                "not a VTKHDF file: there is no /VTKHDF group ({})",
                h5::describe_top_level(root)
            ))
        })?;
        let kv = h5::open_group(root, "knitvox", KV)?.ok_or_else(|| {
            FormatError::whole_file(format!(
                "a VTKHDF file but not a knitvox asset: there is no /knitvox group ({})",
                h5::describe_top_level(root)
            ))
        })?;
        match h5::read_str_attr(&kv, KV, "knitvox_format")? {
            Some(k) if k == FORMAT_NAME => {}
            Some(k) => {
                return Err(FormatError::at_path(
                    h5::attr_loc(KV, "knitvox_format"),
                    format!(
                        "this is a knitvox '{}' file, not an '{FORMAT_NAME}' file",
                        crate::geom::excerpt(&k)
                    ),
                ))
            }
            None => {
                return Err(FormatError::at_path(
                    h5::attr_loc(KV, "knitvox_format"),
                    "required attribute is missing",
                ))
            }
        }
        let version = h5::read_int_attr(&kv, KV, "knitvox_format_version")?.ok_or_else(|| {
            FormatError::at_path(
                h5::attr_loc(KV, "knitvox_format_version"),
                "required attribute is missing",
            )
        })?;
        if !(1..=FORMAT_VERSION).contains(&version) {
            return Err(FormatError::at_path(
                h5::attr_loc(KV, "knitvox_format_version"),
                format!(
                    "asset format version {version} is not supported (this build reads versions 1 to {FORMAT_VERSION})"
                ),
            ));
        }
        let [major, minor] = read_version_attr(&vtk)?;
        if major != VTKHDF_VERSION[0] {
            return Err(FormatError::at_path(
                format!("{VTK}@Version"),
                format!("VTKHDF version {major}.{minor}; this build reads version 2.x"),
            ));
        }
        match h5::read_str_attr(&vtk, VTK, "Type")? {
            Some(k) if k == "UnstructuredGrid" => {}
            Some(k) => {
                return Err(FormatError::at_path(
                    h5::attr_loc(VTK, "Type"),
                    format!(
                        "VTK type '{}', expected 'UnstructuredGrid'",
                        crate::geom::excerpt(&k)
                    ),
                ))
            }
            None => {
                return Err(FormatError::at_path(
                    h5::attr_loc(VTK, "Type"),
                    "required attribute is missing",
                ))
            }
        }

        let rest_nodes = required(&kv, KV, "rest_nodes")?;
        rest_nodes.expect_shape(&[None, Some(3)], "N x 3 (nodes x xyz)")?;
        rest_nodes.expect_float()?;
        let n = rest_nodes.shape[0];
        limit(&rest_nodes, n, "nodes")?;

        let connectivity = required(&vtk, VTK, "Connectivity")?;
        connectivity.expect_shape(&[None], "[4 x tets] (node ids)")?;
        expect_int(&connectivity)?;
        let ids = connectivity.len();
        limit(&connectivity, ids, "connectivity ids")?;
        if ids % 4 != 0 {
            return Err(connectivity.err(format!(
                "{ids} node ids is not a whole number of tets (4 ids each)"
            )));
        }
        let t = ids / 4;

        let steps = h5::open_group(&vtk, "Steps", STEPS)?;
        let s = match &steps {
            None => 0,
            Some(st) => {
                let nsteps = h5::read_int_attr(st, STEPS, "NSteps")?.ok_or_else(|| {
                    FormatError::at_path(
                        h5::attr_loc(STEPS, "NSteps"),
                        "required attribute is missing",
                    )
                })?;
                let s = usize::try_from(nsteps)
                    .ok()
                    .filter(|&s| s >= 1 && s as u64 <= MAX_ELEMENTS)
                    .ok_or_else(|| {
                        FormatError::at_path(
                            h5::attr_loc(STEPS, "NSteps"),
                            format!("{nsteps} steps: expected 1 to {MAX_ELEMENTS}"),
                        )
                    })?;
                s
            }
        };

        let points = required(&vtk, VTK, "Points")?;
        points.expect_shape(&[None, Some(3)], "P x 3 (points x xyz)")?;
        points.expect_float()?;
        let rows = s
            .max(1)
            .checked_mul(n)
            .filter(|&r| r as u64 <= MAX_ELEMENTS)
            .ok_or_else(|| {
                points.err(format!(
                    "{s} steps x {n} nodes exceeds the limit of {MAX_ELEMENTS} positions"
                ))
            })?;
        if points.shape[0] != rows {
            return Err(points.err(if s > 0 {
                format!(
                    "{} points, expected {s} steps x {n} nodes = {rows}",
                    points.shape[0]
                )
            } else {
                format!(
                    "{} points, expected the {n} nodes of /knitvox/rest_nodes",
                    points.shape[0]
                )
            }));
        }
        let parts = s.max(1);
        for (name, want) in [
            ("NumberOfPoints", n),
            ("NumberOfCells", t),
            ("NumberOfConnectivityIds", ids),
        ] {
            let ds = required(&vtk, VTK, name)?;
            let v = read_indices(
                &ds,
                &[parts],
                u64::MAX,
                &format!("[{parts}] (one entry per step)"),
            )?;
            if let Some((i, x)) = v.iter().enumerate().find(|(_, &x)| x != want as u64) {
                return Err(ds.err(format!("entry {i}: {x}, expected {want}")));
            }
        }
        Ok(Layout {
            vtk,
            kv,
            steps,
            version,
            n,
            t,
            s,
            points,
            rest_nodes,
            connectivity,
        })
    }

    /// Checks `/VTKHDF/Steps` (fixed topology) and returns the step times.
    fn read_steps(&self) -> Result<Vec<f64>, FormatError> {
        let Some(st) = &self.steps else {
            return Ok(Vec::new());
        };
        let (s, n) = (self.s, self.n);
        let values = required(st, STEPS, "Values")?;
        let times = read_floats(&values, &[s], &format!("[{s}] (NSteps times)"))?;
        let fixed = "knitvox assets have a fixed topology";
        check_offsets(
            st,
            "PointOffsets",
            s,
            false,
            |k| (k * n) as u64,
            "step x nodes",
        )?;
        check_offsets(st, "PartOffsets", s, false, |_| 0, fixed)?;
        if st.link_exists("NumberOfParts") {
            check_offsets(st, "NumberOfParts", s, false, |_| 1, "one part per step")?;
        }
        check_offsets(st, "CellOffsets", s, true, |_| 0, fixed)?;
        check_offsets(st, "ConnectivityIdOffsets", s, true, |_| 0, fixed)?;
        for (group, names) in [
            (
                "CellDataOffsets",
                &[
                    "gamma_s",
                    "gamma_v",
                    "domain",
                    FIBRE_CELL_DATA[0],
                    FIBRE_CELL_DATA[1],
                    FIBRE_CELL_DATA[2],
                    FIBRE_CELL_DATA[3],
                ][..],
            ),
            ("PointDataOffsets", &["mass"][..]),
        ] {
            if let Some(g) = h5::open_group(st, group, &format!("{STEPS}/{group}"))? {
                for name in names {
                    if g.link_exists(name) {
                        let ds = required(&g, &format!("{STEPS}/{group}"), name)?;
                        let v = read_indices(&ds, &[s], u64::MAX, &format!("[{s}]"))?;
                        if let Some((i, x)) = v.iter().enumerate().find(|(_, &x)| x != 0) {
                            return Err(ds.err(format!(
                                "step {i}: {x}, expected 0 (the data is stored once for all steps)"
                            )));
                        }
                    }
                }
            }
        }
        Ok(times)
    }
}

fn parse_json<T: serde::de::DeserializeOwned>(kv: &Group, name: &str) -> Result<T, FormatError> {
    let ds = required(kv, KV, name)?;
    ds.expect_shape(&[None], "[bytes] (UTF-8 JSON text)")?;
    if !matches!(ds.ty.kind, Kind::Int { .. }) || ds.ty.size != 1 {
        return Err(ds.err(format!(
            "type {}, expected uint8 (UTF-8 JSON text)",
            ds.ty.describe()
        )));
    }
    let len = ds.len();
    if len > MAX_JSON_BYTES {
        return Err(ds.err(format!(
            "{len} bytes of JSON exceeds the limit of {MAX_JSON_BYTES}"
        )));
    }
    let bytes: Vec<u8> = if len == 0 {
        Vec::new()
    } else {
        ds.guard_storage(len)?;
        ds.ds
            .read_raw()
            .map_err(|e| ds.err(format!("libhdf5 cannot read it: {}", h5::h5_message(&e))))?
    };
    serde_json::from_slice(&bytes).map_err(|e| ds.err(format!("invalid JSON: {e}")))
}

/// Refuses an asset whose arrays together would exceed the memory budget
/// (each dataset is also checked alone when read): per node the rest
/// position and mass (32 bytes), per tet its ids, offset, type, moduli,
/// domain and voxel (48 bytes as read), per stored position 24 bytes.
fn check_budget(l: &Layout, positions: bool) -> Result<(), FormatError> {
    let stored = if positions {
        l.s.saturating_mul(l.n)
    } else {
        0
    };
    // The largest datasets alone first: that error names the dataset.
    l.rest_nodes.guard_declared(l.n.saturating_mul(3))?;
    l.connectivity.guard_declared(l.t.saturating_mul(4))?;
    l.points.guard_declared(stored.saturating_mul(3))?;
    let bytes = (l.n as u64)
        .saturating_mul(32)
        .saturating_add((l.t as u64).saturating_mul(48))
        .saturating_add((stored as u64).saturating_mul(24));
    let budget = super::max_memory();
    if bytes > budget {
        return Err(FormatError::whole_file(format!(
            "the asset declares {} nodes, {} tets and {} steps: about {bytes} bytes in memory, more than the memory budget of {budget} bytes (--max-memory)",
            l.n, l.t, l.s
        )));
    }
    // Within the budget together: the compression-bomb rules last.
    l.rest_nodes.guard_storage(l.n.saturating_mul(3))?;
    l.connectivity.guard_storage(l.t.saturating_mul(4))?;
    l.points.guard_storage(stored.saturating_mul(3))
}

/// Reads everything; the per-step positions only when `positions` is set.
fn read_contents(l: &Layout, positions: bool) -> Result<Asset, FormatError> {
    check_budget(l, positions)?;
    let (n, t, s) = (l.n, l.t, l.s);

    let nodes = read_floats(&l.rest_nodes, &[n, 3], "N x 3")?;
    let nodes: Vec<Vec3> = nodes.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    let conn = read_indices(&l.connectivity, &[4 * t], n as u64, "[4 x tets]")?;
    // Every entry < n <= MAX_ELEMENTS < 2^32, so the casts below are exact.
    let tets: Vec<[u32; 4]> = conn
        .chunks_exact(4)
        .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32, c[3] as u32])
        .collect();
    let offsets = required(&l.vtk, VTK, "Offsets")?;
    let off = read_indices(
        &offsets,
        &[t + 1],
        u64::MAX,
        &format!("[{}] (tets + 1)", t + 1),
    )?;
    if let Some((i, x)) = off.iter().enumerate().find(|(i, &x)| x != 4 * *i as u64) {
        return Err(offsets.err(format!(
            "entry {i}: {x}, expected {} (every cell is a tet with 4 nodes)",
            4 * i
        )));
    }
    let types = required(&l.vtk, VTK, "Types")?;
    let ty = read_indices(&types, &[t], u64::MAX, &format!("[{t}] (one per tet)"))?;
    if let Some((i, x)) = ty
        .iter()
        .enumerate()
        .find(|(_, &x)| x != u64::from(VTK_TETRA))
    {
        return Err(types.err(format!(
            "cell {i}: type {x}, expected {VTK_TETRA} (VTK_TETRA)"
        )));
    }

    let cd = required_group(&l.vtk, VTK, "CellData")?;
    let cdp = format!("{VTK}/CellData");
    let per_tet = format!("[{t}] (one per tet)");
    let gamma_s = read_stiffness(&required(&cd, &cdp, "gamma_s")?, t, &per_tet)?;
    let gamma_v = read_stiffness(&required(&cd, &cdp, "gamma_v")?, t, &per_tet)?;
    let domain = read_i32(&required(&cd, &cdp, "domain")?, &[t], &per_tet)?;
    let fibres = read_fibres(&cd, &cdp, t)?;
    let pd = required_group(&l.vtk, VTK, "PointData")?;
    let mass_ds = required(&pd, &format!("{VTK}/PointData"), "mass")?;
    let node_mass = read_floats(&mass_ds, &[n], &format!("[{n}] (one per node)"))?;
    if let Some(i) = node_mass.iter().position(|&m| m < 0.0) {
        return Err(mass_ds.err(format!("node {i}: mass {} is negative", node_mass[i])));
    }

    // Voxel grid.
    let gp = format!("{KV}/grid");
    let grid_g = required_group(&l.kv, KV, "grid")?;
    let origin = read_floats(&required(&grid_g, &gp, "origin")?, &[3], "[3] (xyz)")?;
    let h_ds = required(&grid_g, &gp, "h")?;
    let h = read_floats(&h_ds, &[], "a scalar")?[0];
    let vox_ds = required(&grid_g, &gp, "voxels")?;
    vox_ds.expect_shape(&[None, Some(3)], "V x 3 (voxels x ijk)")?;
    let nv = vox_ds.shape[0];
    limit(&vox_ds, nv, "voxels")?;
    if nv > 0 && h <= 0.0 {
        return Err(h_ds.err(format!("voxel size {h} is not positive")));
    }
    let vox = read_i32(&vox_ds, &[nv, 3], "V x 3")?;
    let voxels: Vec<[i32; 3]> = vox.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let tv = read_indices(
        &required(&l.kv, KV, "tet_voxel")?,
        &[t],
        nv as u64,
        &per_tet,
    )?;
    let tet_voxel: Vec<u32> = tv.into_iter().map(|v| v as u32).collect(); // < nv <= MAX_ELEMENTS

    // Rest yarns and their embedding.
    let yp = format!("{KV}/rest_yarns");
    let yg = required_group(&l.kv, KV, "rest_yarns")?;
    let opts = ReadOptions {
        max_points: MAX_ELEMENTS,
        ..ReadOptions::default()
    };
    let (rest_yarns, radius_in_file) = h5::read_yarns_group(&yg, &yp, &opts)?;
    if !radius_in_file {
        return Err(FormatError::at_path(
            format!("{yp}/radius"),
            "required dataset is missing",
        ));
    }
    let m = rest_yarns.num_points();
    let ep = format!("{KV}/embedding");
    let eg = required_group(&l.kv, KV, "embedding")?;
    let per_vertex = format!("[{m}] (one per rest yarn vertex)");
    let et = read_indices(&required(&eg, &ep, "tet")?, &[m], t as u64, &per_vertex)?;
    let w = read_floats(
        &required(&eg, &ep, "weights")?,
        &[m, 4],
        &format!("{m} x 4 (one row of barycentric weights per rest yarn vertex)"),
    )?;
    let embedding = Embedding {
        tet: et.into_iter().map(|v| v as u32).collect(), // < t <= MAX_ELEMENTS / 4
        weights: w
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
    };

    let parameters: serde_json::Value = parse_json(&l.kv, "parameters")?;
    let provenance: Provenance = parse_json(&l.kv, "provenance")?;

    // Time series.
    let times = l.read_steps()?;
    let fit_error = match Ds::open(&l.kv, KV, "fit_error", false)? {
        Some(ds) if s > 0 => read_floats(&ds, &[s], &format!("[{s}] (one per step)"))?,
        Some(ds) => return Err(ds.err("the asset has no steps (no /VTKHDF/Steps) but a fit error")),
        None => Vec::new(),
    };
    let step_positions = if s > 0 && positions {
        let p = read_floats(&l.points, &[s * n, 3], "steps x nodes x 3")?;
        p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    } else {
        Vec::new()
    };

    Ok(Asset {
        grid: VoxelGrid {
            origin: [origin[0], origin[1], origin[2]],
            h,
            voxels,
        },
        mesh: TetMesh { nodes, tets },
        tet_voxel,
        node_mass,
        gamma_s,
        gamma_v,
        domain,
        fibres,
        embedding,
        rest_yarns,
        parameters,
        provenance,
        steps: NodeSteps {
            times,
            positions: step_positions,
            fit_error,
        },
    })
}

fn read_step_of(file: &hdf5::File, s: usize) -> Result<Vec<Vec3>, FormatError> {
    let l = Layout::open(file)?;
    let Some(st) = &l.steps else {
        return Err(FormatError::at_path(
            STEPS,
            format!("step {s} requested but the asset is static (no time steps)"),
        ));
    };
    if s >= l.s {
        return Err(FormatError::at_path(
            STEPS,
            format!("step {s} requested but the asset holds {} step(s)", l.s),
        ));
    }
    let n = l.n;
    check_offsets(
        st,
        "PointOffsets",
        l.s,
        false,
        |k| (k * n) as u64,
        "step x nodes",
    )?;
    let (a, b) = (s * n, (s + 1) * n); // <= s * n checked by Layout::open
    if n == 0 {
        return Ok(Vec::new());
    }
    // The rows up to this step must be stored (contiguous storage: the whole dataset).
    l.points.guard_storage(b.saturating_mul(3))?;
    let arr = l
        .points
        .ds
        .read_slice::<f64, _, ndarray::Ix2>(ndarray::s![a..b, ..])
        .map_err(|e| {
            l.points
                .err(format!("libhdf5 cannot read it: {}", h5::h5_message(&e)))
        })?;
    let flat = arr.as_standard_layout();
    let flat = flat
        .as_slice()
        .ok_or_else(|| l.points.err("internal error: step not contiguous"))?;
    let mut out = Vec::with_capacity(n);
    for (v, p) in flat.chunks_exact(3).enumerate() {
        if !p.iter().all(|x| x.is_finite()) {
            return Err(l.points.err(format!(
                "step {s}, node {v}: coordinate {p:?} is not finite"
            )));
        }
        out.push([p[0], p[1], p[2]]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Yarns;

    /// One unit cube split into 6 tets around the diagonal 0-6.
    pub(crate) fn cube_asset(steps: usize) -> Asset {
        let nodes: Vec<Vec3> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        let tets = vec![
            [0, 1, 3, 7],
            [0, 3, 2, 7],
            [0, 2, 6, 7],
            [0, 6, 4, 7],
            [0, 4, 5, 7],
            [0, 5, 1, 7],
        ];
        let mut y = Yarns::new();
        y.push_curve(
            &[[0.1, 0.2, 0.3], [0.5, 0.5, 0.5], [0.9, 0.1, 0.2]],
            false,
            1e-3,
        );
        let mut steps_ = NodeSteps::default();
        for k in 0..steps {
            steps_.times.push(k as f64 * 0.25);
            steps_
                .positions
                .extend(nodes.iter().map(|p| [p[0] + 0.1 * k as f64, p[1], p[2]]));
        }
        Asset {
            grid: VoxelGrid {
                origin: [0.0; 3],
                h: 1.0,
                voxels: vec![[0, 0, 0]],
            },
            mesh: TetMesh { nodes, tets },
            tet_voxel: vec![0; 6],
            node_mass: vec![0.125; 8],
            gamma_s: vec![1e4; 6],
            gamma_v: vec![2e4; 6],
            domain: vec![0; 6],
            fibres: None,
            embedding: Embedding {
                tet: vec![0, 1, 5],
                weights: vec![[0.25; 4], [0.1, 0.2, 0.3, 0.4], [1.0, 0.0, 0.0, 0.0]],
            },
            rest_yarns: y,
            parameters: serde_json::json!({"h": 1.0}),
            provenance: Provenance::default(),
            steps: steps_,
        }
    }

    #[test]
    fn round_trip_static_and_with_steps() {
        let dir = tempfile::tempdir().unwrap();
        for steps in [0, 3] {
            let p = dir.path().join(format!("a{steps}.vtkhdf"));
            let a = cube_asset(steps);
            write_asset(&p, &a).unwrap();
            assert_eq!(read_asset(&p).unwrap(), a);
            for k in 0..steps {
                assert_eq!(read_step(&p, k).unwrap(), a.steps.step(k, 8));
            }
            assert!(read_step(&p, steps).is_err());
        }
    }

    #[test]
    fn inconsistent_assets_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.vtkhdf");
        let mut a = cube_asset(2);
        a.mesh.tets[3][2] = 8;
        let e = write_asset(&p, &a).unwrap_err();
        assert!(e.to_string().contains("tet 3"), "{e}");
        let mut a = cube_asset(2);
        a.steps.positions.pop();
        assert!(write_asset(&p, &a).is_err());
        let mut a = cube_asset(0);
        a.gamma_v[0] = f64::NAN;
        assert!(write_asset(&p, &a).is_err());
        let mut a = cube_asset(0);
        a.gamma_s[1] = 2.0 * MAX_STIFFNESS_PA;
        let e = write_asset(&p, &a).unwrap_err();
        assert!(e.to_string().contains("tet 1: gamma_s 2e12 Pa"), "{e}");
        assert!(!p.exists());
    }

    #[test]
    fn range_of_values() {
        assert_eq!(range(&[]), None);
        assert_eq!(range(&[3.0, -1.0, 2.0]), Some([-1.0, 3.0]));
    }
}
