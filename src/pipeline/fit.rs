//! The `fit` stage (VH 2024 §6): yarn-level training poses -> per-element
//! `γs`, `γv` of the asset's Eq. 7 energy.
//!
//! Each pose file becomes one sample of VH §6.4: `--samples` frames chosen
//! evenly (the last, most loaded frame always among them), each turned into
//! a [`Frame`]:
//!
//! * the loss targets from the Y2V shape fit `x̂` of the yarn frame (VH Eq.
//!   5-6, [`ShapeFitter`]) and [`FrameTarget::from_nodes`] (α = 0.1);
//! * Dirichlet nodes: the four nodes of every tet that holds a *held* yarn
//!   vertex, kept at `x̂`. Held vertices are the rows of
//!   `/frames/reaction_forces` that are non-zero (schemas/yarns-hdf5.md),
//!   with the clamped bands of the pose record `/metadata/pose_json` of
//!   `knitvox train` when present (inside a band that moves rigidly a
//!   clamped vertex can have an exactly zero reaction);
//!   without that dataset, the clamped bands of the yls scene stored in
//!   `/metadata/scene_toml`; without either, the left and right bands of a
//!   `stretch_courses` pose (a warning says which);
//! * external node forces `Nᵀ f` from `/frames/external_forces` (gravity of
//!   the yarn-level run), else the scene's gravity on the node masses, else
//!   none (warned);
//! * the Eq. 22 weight: the pose's `/frames/elastic_energy` over the chosen
//!   frames, else the Eq. 7 energy of `x̂` under the asset's material (warned).
//!
//! The fit runs twice through [`fit_materials`]: the uniform material (the
//! r = 1 harmonic stage alone, from the asset's material) that `validate`
//! compares against, then the harmonic stages and the full field from that
//! uniform material. Frames are quasi-static (Eq. 14 without the inertia
//! term of Eq. 13).
//!
//! The scale of γ: Eq. 7 is linear in γ, so a pose held only by Dirichlet
//! nodes (no external force) has the same equilibrium under `s γ` for every
//! `s > 0`, and its loss cannot see the scale. The recorded clamp reactions
//! can: [`force_scale`] matches the homogenized clamp forces of the held
//! bands to the yarn-level ones (resultant force and moment per band) and
//! scales the uniform material, and again the fitted field, by the
//! least-squares factor. Poses with external forces (gravity) see the scale
//! in their loss; when any frame has them the final field is not rescaled.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::fit::elastic::adjoint::{equilibrium, equilibrium_continued, Anchor};
use crate::fit::elastic::force_loss::{wrench, BandForce, ForceTarget};
use crate::fit::elastic::{
    fit_materials, ElasticFitError, ElasticFitParams, FitInputs, FitReport, Frame, FrameTarget,
    MaterialFields, Sample, SolveError,
};
use crate::fit::{ShapeFitParams, ShapeFitter};
use crate::geom::{
    Asset, Embedding, FitPose, FitRecord, PoseLosses, TetMesh, TrainingFidelity, UniformMaterial,
    Vec3,
};
use crate::io::{self, plot, IoError, ReadOptions};
use crate::pipeline::asset::{
    asset_materials, check_asset_ext, re_embed, set_asset_materials, yarn_distances, StageError,
};
use crate::pipeline::clamp_drive::ClampDrive;
use crate::pipeline::util::{held_nodes, rms_max, sha256_file};
use crate::pipeline::yls_scene::YlsScene;
use crate::pipeline::{Error, Observer, Stage};
use crate::sim::energy::ElasticModel;
use crate::yarn::fabric::pose::FabricPlane;
use crate::yarn::poses::{PoseDriver, PoseKind, PoseParams};

/// Frames fitted per pose when `--samples` is not given.
pub const DEFAULT_SAMPLES: usize = 2;
/// Most frames fitted per pose (`--samples`, a manifest's `[fit] samples`):
/// each is a shape fit and an equilibrium solve per iteration, so more
/// would run for days; far beyond the frames a training pose holds.
pub const MAX_SAMPLES: usize = 10_000;
/// Most gradient-descent or Gauss-Newton iterations per stage
/// (`--gd-iterations`, `--gn-iterations`; VH §6.3 uses 10 to 30).
pub const MAX_ITERATIONS: u32 = 10_000;
/// Weight α of the loss's position term (VH §5, Eq. 6 and 10).
pub const LOSS_ALPHA: f64 = 0.1;

/// The `fit` stage.
#[derive(Debug, Clone)]
pub struct FitJob {
    /// The asset (.vtkhdf).
    pub asset: PathBuf,
    /// Training poses: yarn frames with the asset's rest-yarn topology, any
    /// yarn format (knitvox HDF5 carries forces and energies).
    pub train: Vec<PathBuf>,
    /// How to read the poses.
    pub read: ReadOptions,
    /// Frames fitted per pose (>= 1). Default [`DEFAULT_SAMPLES`].
    pub samples: usize,
    /// Fitting parameters (harmonic ranks, iterations, ...).
    pub params: ElasticFitParams,
    /// The fitted asset [default: [`default_output`] of `asset`]; never the input.
    pub output: Option<PathBuf>,
    /// Folder for `fit.json` and the PNG plots.
    pub report: Option<PathBuf>,
    /// Fit every pose's frames together (VH Eq. 9) instead of pose by pose
    /// with the energy-weighted fold of Eq. 22. Default false.
    pub joint: bool,
    /// Treat the frames of yls runs (files storing their scene,
    /// `/metadata/scene_toml`; `train` output stores none) as equilibria,
    /// without the inertia and damping forces of VH Eq. 13-14. Default
    /// false.
    pub quasi_static: bool,
    /// Fit tension-only fibres along the courses and wales
    /// ([`crate::sim::fibre`]) next to VH Eq. 7: their directions from the
    /// rest yarns ([`crate::embed::orientation`]) unless the asset has
    /// them, their stiffnesses starting at the asset's `γs`. An asset with
    /// fibres refits them either way. Default false.
    pub fibres: bool,
    /// The material model fitted: VH Eq. 7 (with `fibres`, plus quadratic
    /// fibres), or the knit material (Eq. 7 under stiffening course and
    /// wale fibres, [`crate::sim::knit`]). Default [`FitModel::Knit`].
    pub model: FitModel,
    /// Hold the pinned tet nodes of every frame at its shape fit (Y2V)
    /// instead of where the pose's bands put them, as the homogenized runs
    /// drive them ([`super::clamp_drive`]). Default false.
    pub shape_fit_pins: bool,
    /// The command line, for provenance.
    pub command: String,
}

/// `NAME.vtkhdf` -> `NAME.fit.vtkhdf` beside it.
pub fn default_output(asset: &Path) -> PathBuf {
    let stem = asset
        .file_stem()
        .map_or("asset".into(), |s| s.to_string_lossy().into_owned());
    asset.with_file_name(format!("{stem}.fit.vtkhdf"))
}

impl FitJob {
    /// The asset written.
    pub fn output_path(&self) -> PathBuf {
        self.output
            .clone()
            .unwrap_or_else(|| default_output(&self.asset))
    }
}

/// The material model `fit` fits (`fit --model`).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum FitModel {
    /// VH Eq. 7 per element (isotropic `γs`, `γv`), the reference.
    Vh,
    /// The knit material, the default: Eq. 7 (the soft shear and bending)
    /// under course and wale fibres that stiffen with stretch,
    /// `γ V (ε² + β ε⁴ / 2)` in tension ([`crate::sim::knit`]): per element
    /// `γs`, `γv`, and per family a stiffness and a stiffening, fitted to
    /// the positions and the clamp forces together.
    #[default]
    Knit,
}

/// The stiffening `β` a knit fit starts from where the asset has none: a
/// secant stiffness 1.4x its small-strain value at 20% strain.
pub const KNIT_BETA_START: f64 = 10.0;

/// Where a pose's boundary conditions and weight came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// The pose file's mechanics (`/frames/reaction_forces`, ...).
    File,
    /// The yls scene stored in the pose file.
    Scene,
    /// knitvox's fallback (stretch_courses bands, no force, material energy).
    Assumed,
}

/// What one training pose contributed.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PoseSummary {
    pub path: PathBuf,
    pub sha256: String,
    pub frames_in_file: usize,
    /// 0-based frames fitted.
    pub frames: Vec<usize>,
    /// The pose's amount at each fitted frame (a `knitvox train` record;
    /// null for other frames).
    pub amounts: Vec<Option<f64>>,
    /// [`TrainingFidelity`] of each fitted frame, in the order of
    /// `frames` (filled in after the fit): the error per amplitude.
    pub training_per_frame: Vec<TrainingFidelity>,
    /// Held yarn vertices and Dirichlet tet nodes (largest over its frames).
    pub held_vertices: usize,
    pub held_nodes: usize,
    pub held_source: Source,
    pub forces_source: Source,
    /// Eq. 22 weight (J) and where it came from.
    pub energy: f64,
    pub energy_source: Source,
    /// Largest Y2V RMS yarn error over its frames (m) and smallest det F.
    pub y2v_rms_max: f64,
    pub y2v_min_det_f: f64,
    /// Dynamic frames (a yls run): each carries the inertia and damping
    /// forces of VH Eq. 13-14 from the shape fits of it and the two frames
    /// before ([`inertia_forces`]).
    pub dynamic: bool,
    /// Where the pinned tet nodes are held: `band` (where the pose's bands
    /// put them, as `validate` drives them) or `shape_fit` (each frame's
    /// Y2V: `--shape-fit-pins`, or a pose whose bands are not known).
    pub pins: &'static str,
    /// Largest distance (m) between a pinned node's band position and its
    /// shape fit over the fitted frames (0 with `shape_fit` pins).
    pub pin_offset_m: f64,
    /// How close the mesh's equilibria carry the yarns on this pose's
    /// fitted frames (filled in after the fit).
    pub training: Option<TrainingFidelity>,
}

/// Distances (yarn diameters) of every vertex of every frame between the
/// yarns `yarns[i]` and V2Y of the node positions `nodes[i]`.
fn frame_distances<'a>(
    asset: &Asset,
    yarns: &[Vec<Vec3>],
    nodes: impl Iterator<Item = &'a [Vec3]>,
) -> Vec<f64> {
    nodes
        .zip(yarns)
        .flat_map(|(x, y)| yarn_distances(asset, x, y))
        .collect()
}

/// [`TrainingFidelity`] of each pose (`yarns[k]`: the yarns of its fitted
/// frames, `samples[k]` their shape fits, `equilibria[k]` the mesh under
/// the earlier, uniform and fitted material), then pooled over all poses.
fn training_fidelity_of_poses(
    asset: &Asset,
    yarns: &[Vec<Vec<Vec3>>],
    samples: &[Sample],
    equilibria: &[[Vec<Vec<Vec3>>; 3]],
) -> (Vec<TrainingFidelity>, TrainingFidelity) {
    // Per pose: the floor's distances, then each material's.
    let per_pose: Vec<[Vec<f64>; 4]> = (0..samples.len())
        .map(|k| {
            let starts = samples[k].frames.iter().map(|f| f.start.as_slice());
            let states = |m: usize| equilibria[k][m].iter().map(Vec::as_slice);
            [
                frame_distances(asset, &yarns[k], starts),
                frame_distances(asset, &yarns[k], states(0)),
                frame_distances(asset, &yarns[k], states(1)),
                frame_distances(asset, &yarns[k], states(2)),
            ]
        })
        .collect();
    let fidelity = |d: [&[f64]; 4]| fidelity_of(d);
    let pooled: [Vec<f64>; 4] =
        std::array::from_fn(|m| per_pose.iter().flat_map(|p| p[m].iter().copied()).collect());
    (
        per_pose
            .iter()
            .map(|p| fidelity(std::array::from_fn(|m| p[m].as_slice())))
            .collect(),
        fidelity(std::array::from_fn(|m| pooled[m].as_slice())),
    )
}

fn fidelity_of(d: [&[f64]; 4]) -> TrainingFidelity {
    TrainingFidelity {
        y2v_floor_rms_yarn_diameters: rms_max(d[0]).0,
        before_rms_yarn_diameters: rms_max(d[1]).0,
        uniform_rms_yarn_diameters: rms_max(d[2]).0,
        fitted_rms_yarn_diameters: rms_max(d[3]).0,
    }
}

/// [`TrainingFidelity`] of each fitted frame of each pose (arguments as
/// [`training_fidelity_of_poses`]).
fn training_fidelity_per_frame(
    asset: &Asset,
    yarns: &[Vec<Vec<Vec3>>],
    samples: &[Sample],
    equilibria: &[[Vec<Vec<Vec3>>; 3]],
) -> Vec<Vec<TrainingFidelity>> {
    (0..samples.len())
        .map(|k| {
            (0..samples[k].frames.len())
                .map(|j| {
                    let y = &yarns[k][j];
                    let d0 = yarn_distances(asset, &samples[k].frames[j].start, y);
                    let d: [Vec<f64>; 3] =
                        std::array::from_fn(|m| yarn_distances(asset, &equilibria[k][m][j], y));
                    fidelity_of([&d0, &d[0], &d[1], &d[2]])
                })
                .collect()
        })
        .collect()
}

/// What `fit` did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FitJobReport {
    pub output: PathBuf,
    pub nodes: usize,
    pub tets: usize,
    pub poses: Vec<PoseSummary>,
    /// Loss (m³) summed over poses at the asset's material, the uniform
    /// material and the fitted field.
    pub loss_before: f64,
    pub loss_uniform: f64,
    pub loss_fitted: f64,
    /// [`TrainingFidelity`] pooled over every pose's fitted frames (each
    /// pose's in `poses[].training`).
    pub training: TrainingFidelity,
    /// The best uniform material (r = 1).
    pub uniform: UniformMaterial,
    /// The reaction-matched γ scale applied to the uniform material and to
    /// the fitted field ([`force_scale`]; null where not applied).
    pub uniform_force_scale: Option<ForceScale>,
    pub field_force_scale: Option<ForceScale>,
    /// `--model knit`: the stiffening set from the clamp forces on the
    /// fitted field and on the uniform material
    /// ([`stiffening_from_forces`]; null where not run).
    pub field_stiffening: Option<StiffeningFit>,
    pub uniform_stiffening: Option<StiffeningFit>,
    /// `--model knit` with clamp forces: the field fitted to the positions
    /// and the forces together ([`ForceFit`]; null where not).
    pub field_forces: Option<ForceFit>,
    pub gamma_s_range: [f64; 2],
    pub gamma_v_range: [f64; 2],
    /// Fitted fibre stiffnesses along the course and the wale (Pa), with
    /// fibres.
    pub gamma_course_range: Option<[f64; 2]>,
    pub gamma_wale_range: Option<[f64; 2]>,
    /// The model fitted, and the fitted stiffenings along the course and
    /// the wale (dimensionless; `--model knit`).
    pub model: FitModel,
    pub beta_course_range: Option<[f64; 2]>,
    pub beta_wale_range: Option<[f64; 2]>,
    /// Mean chord anisotropy of the fibre directions found for this fit
    /// ([`crate::embed::orientation::CourseWale::mean_anisotropy`]); null
    /// when the asset brought its own or the fit has none.
    pub fibre_anisotropy: Option<f64>,
    /// The fitter's reports: the uniform stage, then the field.
    pub uniform_fit: FitReport,
    pub fit: FitReport,
    /// Files of `--report`.
    pub report_files: Vec<PathBuf>,
    pub wall_s: f64,
}

/// `n` frames of `f` chosen evenly, the last always included: frame
/// `ceil((k + 1) f / n) - 1` for `k < n` (all of them when `n >= f`).
pub fn choose_frames(f: usize, n: usize) -> Vec<usize> {
    let n = n.min(f);
    (0..n).map(|k| ((k + 1) * f).div_ceil(n) - 1).collect()
}

/// Yarn-vertex forces (N) as node forces `Nᵀ f` (VH Eq. 4 transposed):
/// the total force and its moment about any point are kept.
pub fn node_forces(mesh: &TetMesh, embedding: &Embedding, f: &[Vec3]) -> Vec<Vec3> {
    let mut out = vec![[0.0; 3]; mesh.num_nodes()];
    for (v, fv) in f.iter().enumerate() {
        let ids = mesh.tets[embedding.tet[v] as usize];
        for a in 0..4 {
            for k in 0..3 {
                out[ids[a] as usize][k] += embedding.weights[v][a] * fv[k];
            }
        }
    }
    out
}

/// `/frames/<name>` of a knitvox HDF5 pose as `[F][N]` vectors (+Y up),
/// None when the file is not HDF5 or lacks it.
fn mechanics(
    path: &Path,
    name: &str,
    nf: usize,
    weld: &crate::geom::Weld,
    up: crate::geom::UpAxis,
) -> Result<Option<Vec<Vec<Vec3>>>, IoError> {
    // Stored per point of the file: welded points carry their run's sum.
    let n = weld.input_points();
    if io::format_of(path)? != io::Format::Hdf5 {
        return Ok(None);
    }
    let loc = format!("/frames/{name}");
    if !io::h5::list_datasets(path)?.iter().any(|d| d.path == loc) {
        return Ok(None);
    }
    let (shape, v) = io::h5::read_dataset_f64(path, &loc)?;
    if shape != [nf, n, 3] || v.iter().any(|x| !x.is_finite()) {
        return Err(IoError::Unsupported {
            path: path.to_path_buf(),
            message: format!(
                "{loc}: shape {shape:?} or values do not fit {nf} frames of {n} vertices (finite, F x N x 3)"
            ),
        });
    }
    Ok(Some(
        v.chunks_exact(3 * n.max(1))
            .map(|fr| {
                let f: Vec<Vec3> = fr
                    .chunks_exact(3)
                    .map(|c| up.to_internal([c[0], c[1], c[2]]))
                    .collect();
                if weld.is_identity() {
                    f
                } else {
                    weld.sum(&f)
                }
            })
            .collect(),
    ))
}

/// `/frames/elastic_energy` (J per frame) of a knitvox HDF5 pose, if any.
fn energies_of(path: &Path, nf: usize) -> Result<Option<Vec<f64>>, IoError> {
    const LOC: &str = "/frames/elastic_energy";
    if io::format_of(path)? != io::Format::Hdf5
        || !io::h5::list_datasets(path)?.iter().any(|d| d.path == LOC)
    {
        return Ok(None);
    }
    let (shape, v) = io::h5::read_dataset_f64(path, LOC)?;
    if shape != [nf] || v.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
        return Err(IoError::Unsupported {
            path: path.to_path_buf(),
            message: format!("{LOC}: shape {shape:?}, expected [{nf}] finite energies >= 0 J"),
        });
    }
    Ok(Some(v))
}

/// Everything shared by the poses of one fit.
struct Context<'a> {
    asset: &'a Asset,
    asset_path: &'a Path,
    fitter: ShapeFitter,
    model: ElasticModel,
    samples: usize,
    quasi_static: bool,
    shape_fit_pins: bool,
}

/// The forces of VH Eq. 13-14 that turn a dynamic frame into a static
/// problem: `-m_i (a_i + c v_i)` per node, with the acceleration and
/// velocity differenced from the shape fits of frames `f - 2`, `f - 1`, `f`
/// (positions fitted first, differenced afterwards: VH §5), `dt` the frame
/// interval (s) and `c` the mass-proportional damping (1/s) of the run.
pub fn inertia_forces(mass: &[f64], x: [&[Vec3]; 3], dt: f64, damping: f64) -> Vec<Vec3> {
    let [x0, x1, x2] = x;
    (0..mass.len())
        .map(|i| {
            std::array::from_fn(|k| {
                let a = (x2[i][k] - 2.0 * x1[i][k] + x0[i][k]) / (dt * dt);
                let v = (x2[i][k] - x1[i][k]) / dt;
                -mass[i] * (a + damping * v)
            })
        })
        .collect()
}

fn invalid(path: &Path, message: String) -> Error {
    StageError::Invalid {
        path: path.to_path_buf(),
        message,
    }
    .into()
}

/// A pose's frame times must be finite and never decrease: the fit takes
/// its frames in time order, and the inertia of Eq. 13 differences them.
fn check_times(path: &Path, times: &[f64]) -> Result<(), Error> {
    let at = |i: usize, what: String| {
        invalid(
            path,
            format!("/frames/times: frame {i}: {what}: a pose's frame times must increase"),
        )
    };
    let num = crate::geom::num;
    for (i, &t) in times.iter().enumerate() {
        if !t.is_finite() {
            return Err(at(i, format!("time {} s is not finite", num(t))));
        }
        if i > 0 && t < times[i - 1] {
            return Err(at(
                i,
                format!(
                    "time {} s is before frame {}'s {} s",
                    num(t),
                    i - 1,
                    num(times[i - 1])
                ),
            ));
        }
    }
    Ok(())
}

/// One training pose as `fit` uses it.
struct PoseInput {
    sample: Sample,
    summary: PoseSummary,
    /// Clamp reactions per fitted frame, on the mesh nodes (None: not
    /// recorded).
    reactions: Vec<Option<Vec<Vec3>>>,
    /// The yarn positions of each fitted frame (m), for the training
    /// fidelity.
    yarns: Vec<Vec<Vec3>>,
}

/// Reads one pose file into a sample (see the module documentation).
fn read_pose(
    cx: &Context<'_>,
    path: &Path,
    read: &ReadOptions,
    observer: &mut dyn Observer,
) -> Result<PoseInput, Error> {
    let asset = cx.asset;
    let data = io::read_path(path, read)?;
    let rest = &asset.rest_yarns;
    if data.yarns.offsets != rest.offsets || data.yarns.closed != rest.closed {
        return Err(invalid(
            path,
            format!(
                "its yarns ({} curves, {} vertices) do not have the topology of the asset's rest yarns ({} curves, {} vertices; {})",
                data.yarns.num_curves(),
                data.yarns.num_points(),
                rest.num_curves(),
                rest.num_points(),
                cx.asset_path.display()
            ),
        ));
    }
    let Some(frames) = data.frames else {
        return Err(invalid(path, "holds no frames: a training pose is a knitvox HDF5 file with /frames or a name.####.ext sequence".into()));
    };
    let nf = frames.num_frames();
    let n = rest.num_points();
    if nf == 0 {
        return Err(invalid(path, "holds no frames".into()));
    }
    check_times(path, &frames.times)?;
    let pose_record = recorded_pose(path)?;
    // A pose trained at a list of amplitudes is fitted at each of them.
    let chosen = match &pose_record {
        Some(r) if !r.stop_frames.is_empty() && r.frame_amounts.len() == nf => {
            r.stop_frames.clone()
        }
        _ => choose_frames(nf, cx.samples),
    };
    let up = data.up_axis.0;
    let reactions = mechanics(path, "reaction_forces", nf, &data.weld, up)?;
    let external = mechanics(path, "external_forces", nf, &data.weld, up)?;
    let energies = energies_of(path, nf)?;
    let scene = if reactions.is_none() || external.is_none() {
        scene_of(path)?
    } else {
        None
    };
    let name = path.display().to_string();
    // Held vertices: per frame from the reactions, else one set.
    let (fixed_held, held_source): (Vec<bool>, Source) = match (&reactions, &scene) {
        (Some(_), _) => (Vec::new(), Source::File),
        (None, scene) => {
            let params = scene.as_ref().map_or_else(
                || PoseParams::new(PoseKind::StretchCourses, 0.0),
                |s| s.pose_params(),
            );
            // An assumed pose clamps the bands of the swatch turned into the
            // pose frame (as `train` turns it); a yls scene's run in the
            // frame the swatch has.
            let points: Vec<Vec3> = match scene {
                Some(_) => rest.points.clone(),
                None => {
                    let plane = FabricPlane::of(&rest.points);
                    rest.points.iter().map(|p| plane.to_pose(*p)).collect()
                }
            };
            let driver = PoseDriver::new(&points, params)
                .map_err(|e| invalid(path, format!("its clamped bands: {e}")))?;
            let mut h = vec![false; n];
            for &v in driver.pinned() {
                h[v] = true;
            }
            let src = if scene.is_some() {
                observer.warning(&format!("{name}: no /frames/reaction_forces: held vertices are the clamped bands of its yls scene"));
                Source::Scene
            } else {
                observer.warning(&format!("{name}: no /frames/reaction_forces and no yls scene: assuming the left and right bands (6% of the width along X) are held, as in stretch_courses"));
                Source::Assumed
            };
            (h, src)
        }
    };
    // A clamped vertex whose neighbours are clamped too can have an exactly
    // zero reaction (its band moves rigidly): the pose record's bands
    // (`knitvox train`) count as held with the non-zero rows.
    let record = if reactions.is_some() || !cx.shape_fit_pins {
        pose_record.clone()
    } else {
        None
    };
    let recorded = match (&reactions, &record) {
        (Some(_), Some(r)) => Some(recorded_bands(path, r.params, &rest.points)?),
        _ => None,
    };
    let held_at = |f: usize| -> Vec<bool> {
        match &reactions {
            Some(r) => r[f]
                .iter()
                .enumerate()
                .map(|(v, x)| {
                    x.iter().any(|c| *c != 0.0) || recorded.as_ref().is_some_and(|b| b[v])
                })
                .collect(),
            None => fixed_held.clone(),
        }
    };
    let forces_source = match (&external, &scene) {
        (Some(_), _) => Source::File,
        (None, Some(_)) => {
            observer.warning(&format!(
                "{name}: no /frames/external_forces: using the yls scene's gravity on the node masses"
            ));
            Source::Scene
        }
        (None, None) => {
            observer.warning(&format!(
                "{name}: no /frames/external_forces and no yls scene: no external force (gravity ignored)"
            ));
            Source::Assumed
        }
    };
    // A yls run (the only writer of /metadata/scene_toml; `train` output
    // stores its pose instead) is dynamic: its frames are not equilibria
    // without their inertia.
    let damping = match &scene {
        Some(s) if !cx.quasi_static => Some(super::yls::scene_params(s, path)?.global_damping),
        _ => None,
    };
    let drive = clamp_drive(cx, path, scene.as_ref(), record.as_ref(), &frames, observer)?;
    let mut pin_offset = 0.0f64;
    let mut out = Vec::with_capacity(chosen.len());
    let mut node_reactions = Vec::with_capacity(chosen.len());
    let (mut energy, mut y2v_rms, mut min_det, mut held_v, mut held_n) =
        (0.0, 0.0f64, f64::INFINITY, 0usize, 0usize);
    let mut used = Vec::with_capacity(chosen.len());
    let mut yarns = Vec::with_capacity(chosen.len());
    for &want in &chosen {
        // A frame whose shape fit inverts tets cannot be a target: the
        // nearest earlier frame after the previous choice replaces it.
        let lowest = used.last().map_or(usize::from(nf > 1), |&u: &usize| u + 1);
        let mut f = want;
        let (x_hat, st) = loop {
            let (x, st) = cx
                .fitter
                .fit(frames.frame(f))
                .map_err(|e| invalid(path, format!("frame {f}: shape fit: {e}")))?;
            if st.inverted_tets == 0 {
                break (x, st);
            }
            if f <= lowest {
                return Err(invalid(path, format!(
                    "frame {want}: its shape fit inverts {} tets (smallest det F {:.3e}), and so do the frames before it down to {f}: the homogenized mesh cannot be asked to reach them",
                    st.inverted_tets, st.min_det_f
                )));
            }
            f -= 1;
        };
        if f != want {
            observer.warning(&format!(
                "{name}: frame {want}'s shape fit inverts tets: fitting frame {f} instead"
            ));
        }
        used.push(f);
        yarns.push(frames.frame(f).to_vec());
        let held_f = held_at(f);
        y2v_rms = y2v_rms.max(st.rms_error);
        min_det = min_det.min(st.min_det_f);
        let target = FrameTarget::from_nodes(
            &cx.model,
            &x_hat,
            &asset.node_mass,
            LOSS_ALPHA,
            asset.grid.h,
        )
        .map_err(|e| invalid(path, format!("frame {f}: loss targets: {e}")))?;
        let pinned = held_nodes(&asset.mesh, &asset.embedding, &held_f);
        if pinned.is_empty() {
            return Err(invalid(path, format!("frame {f}: no held vertex (all reaction forces are zero): the pose has no boundary condition to fit under")));
        }
        held_v = held_v.max(held_f.iter().filter(|h| **h).count());
        held_n = held_n.max(pinned.len());
        let mut f_ext = match (&external, &scene) {
            (Some(e), _) => node_forces(&asset.mesh, &asset.embedding, &e[f]),
            (None, Some(s)) => asset
                .node_mass
                .iter()
                .map(|m| s.gravity.map(|g| m * g))
                .collect(),
            (None, None) => vec![[0.0; 3]; asset.mesh.num_nodes()],
        };
        if let Some(c) = damping {
            let inertia = dynamic_forces(cx, path, &frames, f, &x_hat, c)?;
            for (fe, fi) in f_ext.iter_mut().zip(&inertia) {
                for k in 0..3 {
                    fe[k] += fi[k];
                }
            }
        }
        energy += match &energies {
            Some(e) => e[f],
            None => cx
                .model
                .energy(&x_hat)
                .map_err(|e| invalid(path, format!("frame {f}: energy of its shape fit: {e}")))?,
        };
        node_reactions.push(
            reactions
                .as_ref()
                .map(|r| node_forces(&asset.mesh, &asset.embedding, &r[f])),
        );
        let mut start = x_hat;
        if let Some(d) = &drive {
            let at = d
                .targets(f, &asset.mesh.nodes, &pinned)
                .map_err(|e| invalid(path, format!("frame {f}: its bands: {e}")))?;
            for (&i, p) in pinned.iter().zip(at) {
                if let Some(p) = p {
                    pin_offset = pin_offset
                        .max(crate::geom::vec3::norm(crate::geom::vec3::sub(p, start[i])));
                    start[i] = p;
                }
            }
        }
        out.push(Frame {
            target,
            pinned,
            start,
            f_ext,
            forces: None,
        });
    }
    let energy_source = if energies.is_some() {
        Source::File
    } else {
        observer.warning(&format!("{name}: no /frames/elastic_energy: its Eq. 22 weight is the Eq. 7 energy of its shape fit under the asset's material"));
        Source::Assumed
    };
    if !(energy > 0.0 && energy.is_finite()) {
        return Err(invalid(path, format!(
            "its chosen frames {used:?} store no elastic energy ({energy:e} J): is the pose deformed?"
        )));
    }
    let amounts = used
        .iter()
        .map(|&f| {
            pose_record
                .as_ref()
                .filter(|r| r.frame_amounts.len() == nf)
                .map(|r| r.frame_amounts[f])
        })
        .collect();
    let summary = PoseSummary {
        path: path.to_path_buf(),
        sha256: sha256_file(path)?,
        frames_in_file: nf,
        frames: used,
        amounts,
        training_per_frame: Vec::new(),
        held_vertices: held_v,
        held_nodes: held_n,
        held_source,
        forces_source,
        energy,
        energy_source,
        y2v_rms_max: y2v_rms,
        y2v_min_det_f: min_det,
        dynamic: damping.is_some(),
        pins: if drive.is_some() { "band" } else { "shape_fit" },
        pin_offset_m: pin_offset,
        training: None,
    };
    Ok(PoseInput {
        sample: Sample {
            name,
            frames: out,
            energy,
        },
        summary,
        reactions: node_reactions,
        yarns,
    })
}

/// [`inertia_forces`] of frame `f` (shape fit `x_hat`) of a dynamic pose:
/// the two frames before it are shape-fitted too and must be as far apart
/// in time as it is from the one before.
fn dynamic_forces(
    cx: &Context<'_>,
    path: &Path,
    frames: &crate::geom::YarnFrames,
    f: usize,
    x_hat: &[Vec3],
    damping: f64,
) -> Result<Vec<Vec3>, Error> {
    if f < 2 {
        return Err(invalid(path, format!(
            "frame {f}: a dynamic frame needs the two frames before it (Eq. 13): fit later frames, or pass --quasi-static"
        )));
    }
    let t = &frames.times;
    let (dt, dt0) = (t[f] - t[f - 1], t[f - 1] - t[f - 2]);
    if !(dt > 0.0 && (dt - dt0).abs() <= 1e-6 * dt) {
        return Err(invalid(path, format!(
            "frames {}..={f}: times {:?} are not evenly spaced: no Eq. 13 inertia (pass --quasi-static to fit them as equilibria)",
            f - 2,
            &t[f - 2..=f]
        )));
    }
    let fit = |k: usize| {
        cx.fitter
            .fit(frames.frame(k))
            .map(|(x, _)| x)
            .map_err(|e| invalid(path, format!("frame {k}: shape fit: {e}")))
    };
    let (x0, x1) = (fit(f - 2)?, fit(f - 1)?);
    Ok(inertia_forces(
        &cx.asset.node_mass,
        [&x0, &x1, x_hat],
        dt,
        damping,
    ))
}

/// The clamped vertices of the pose `params` a `knitvox train` file
/// records ([`recorded_pose`]), found on the rest yarns turned into the
/// pose frame as the run did.
fn recorded_bands(path: &Path, params: PoseParams, rest: &[Vec3]) -> Result<Vec<bool>, Error> {
    let bad = |m: String| invalid(path, format!("its /metadata/pose_json: {m}"));
    let plane = FabricPlane::of(rest);
    let posed: Vec<Vec3> = rest.iter().map(|p| plane.to_pose(*p)).collect();
    let driver = PoseDriver::new(&posed, params).map_err(|e| bad(format!("its bands: {e}")))?;
    let mut held = vec![false; rest.len()];
    driver.pinned().iter().for_each(|&i| held[i] = true);
    Ok(held)
}

/// Where the homogenized runs would hold this pose's pinned nodes
/// ([`super::clamp_drive`]): from its yls scene or its `knitvox train`
/// `record` ([`recorded_pose`]); None with `--shape-fit-pins`, when neither
/// is known, or when they do not describe every frame (warned).
fn clamp_drive(
    cx: &Context<'_>,
    path: &Path,
    scene: Option<&YlsScene>,
    record: Option<&RecordedPose>,
    frames: &crate::geom::YarnFrames,
    observer: &mut dyn Observer,
) -> Result<Option<ClampDrive>, Error> {
    if cx.shape_fit_pins {
        return Ok(None);
    }
    let bad = |e: crate::yarn::poses::PoseError| invalid(path, format!("its clamped bands: {e}"));
    let drive = match (scene, record) {
        (Some(s), _) => Some(
            ClampDrive::from_scene(cx.asset, s.pose_params(), frames.times.clone()).map_err(bad)?,
        ),
        (None, Some(r)) => Some(
            ClampDrive::from_record(cx.asset, r.params, r.frame_amounts.clone()).map_err(bad)?,
        ),
        (None, None) => None,
    };
    match &drive {
        // Another simulator's frames: the shape fits are all there is
        // (the report's `pins` says so).
        None => Ok(None),
        Some(d) if d.covers(frames.num_frames()) => Ok(drive),
        Some(_) => {
            observer.warning(&format!(
                "{}: its pose record or scene does not describe each of its frames: its pinned nodes are held at each frame's shape fit",
                path.display()
            ));
            Ok(None)
        }
    }
}

/// A `knitvox train` file's pose record.
#[derive(Debug, Clone)]
struct RecordedPose {
    /// The pose at its full (last) amount.
    params: PoseParams,
    /// The amount at each frame (`frame_amounts`; records without it: load
    /// step `f + 1` of `steps` at `(f + 1) / steps` of the amount).
    frame_amounts: Vec<f64>,
    /// The frames of the listed amplitudes when the record lists more than
    /// one (`stop_frames`); empty otherwise.
    stop_frames: Vec<usize>,
}

/// The pose a `knitvox train` file records (`/metadata/pose_json`: kind,
/// amount, mirror, folds, band, steps, and for a list of amplitudes the
/// amount of each frame); None without a record.
fn recorded_pose(path: &Path) -> Result<Option<RecordedPose>, Error> {
    if io::format_of(path)? != io::Format::Hdf5 {
        return Ok(None);
    }
    let Some(text) = io::h5::read_text(path, "pose_json")? else {
        return Ok(None);
    };
    let bad = |m: String| invalid(path, format!("its /metadata/pose_json: {m}"));
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
    let kind = v["kind"]
        .as_str()
        .ok_or_else(|| bad("no kind".into()))
        .and_then(|k| super::util::parse_kind(k).map_err(|e| bad(e.to_string())))?;
    let mut params = PoseParams::new(kind, v["amount"].as_f64().unwrap_or(0.0));
    params.mirror = v["mirror"].as_bool().unwrap_or(false);
    if let Some(f) = v["folds"].as_u64() {
        params.folds = f as u32;
    }
    if let Some(b) = v["band"].as_f64() {
        params.band = b;
    }
    let steps = v["steps"].as_u64().map_or(1, |s| s.max(1) as usize);
    let numbers = |key: &str| -> Result<Option<Vec<f64>>, Error> {
        match v.get(key) {
            None => Ok(None),
            Some(a) => a
                .as_array()
                .and_then(|a| {
                    a.iter()
                        .map(|x| x.as_f64().filter(|x| x.is_finite()))
                        .collect()
                })
                .map(Some)
                .ok_or_else(|| bad(format!("{key} is not a list of finite numbers"))),
        }
    };
    let frame_amounts = match numbers("frame_amounts")? {
        Some(a) if a.len() <= crate::yarn::fabric::pose::MAX_LOAD_STEPS => a,
        Some(a) => return Err(bad(format!("frame_amounts lists {} frames", a.len()))),
        None => {
            let steps = steps.min(crate::yarn::fabric::pose::MAX_LOAD_STEPS);
            (1..=steps)
                .map(|f| params.amount * f as f64 / steps as f64)
                .collect()
        }
    };
    let stop_frames: Vec<usize> = match numbers("stop_frames")? {
        Some(f) => f
            .iter()
            .map(|x| {
                (x.fract() == 0.0 && *x >= 0.0 && (*x as usize) < frame_amounts.len())
                    .then_some(*x as usize)
                    .ok_or_else(|| bad(format!("stop frame {x} is not one of its frames")))
            })
            .collect::<Result<_, _>>()?,
        None => Vec::new(),
    };
    Ok(Some(RecordedPose {
        params,
        frame_amounts,
        stop_frames: if stop_frames.len() > 1 {
            stop_frames
        } else {
            Vec::new()
        },
    }))
}

/// The yls scene a pose file stores (`/metadata/scene_toml`), if any.
fn scene_of(path: &Path) -> Result<Option<YlsScene>, Error> {
    if io::format_of(path)? != io::Format::Hdf5 {
        return Ok(None);
    }
    let Some(text) = io::h5::read_text(path, "scene_toml")? else {
        return Ok(None);
    };
    YlsScene::parse(&text, path)
        .map(Some)
        .map_err(|e| invalid(path, format!("its /metadata/scene_toml: {e}")))
}

/// Per sample and frame, the fit's equilibrium under the field it fitted
/// ([`SampleReport::anchors`](crate::fit::elastic::SampleReport); a joint
/// fit's one merged sample split back into the samples it joined).
pub fn anchors_of(report: &FitReport, samples: &[Sample], joint: bool) -> Vec<Vec<Anchor>> {
    if joint {
        let mut all = report
            .samples
            .first()
            .map(|s| s.anchors.clone())
            .unwrap_or_default()
            .into_iter();
        samples
            .iter()
            .map(|s| all.by_ref().take(s.frames.len()).collect())
            .collect()
    } else {
        report.samples.iter().map(|s| s.anchors.clone()).collect()
    }
}

/// Why a frame has no equilibrium under a material.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum SettleError {
    /// Newton from the frame's start failed, and there was no equilibrium
    /// of the fit to continue from.
    #[error(transparent)]
    Newton(SolveError),
    /// The continuation from the fit's equilibrium failed, and so did
    /// Newton from the frame's start.
    #[error("{newton}; from the fit's equilibrium: {continued}")]
    Both {
        newton: SolveError,
        continued: SolveError,
    },
}

/// Equilibrium of `frame` under `model` (material `gamma`): by continuation
/// from the fit's `anchor` when there is one (the equilibrium the fit itself
/// reached, so losses agree with the fit's), else, or when that fails, by
/// Newton from the frame's start.
fn settle(
    mesh: &TetMesh,
    model: &ElasticModel,
    gamma: &MaterialFields,
    mass: &[f64],
    frame: &Frame,
    anchor: Option<&Anchor>,
    params: &ElasticFitParams,
) -> Result<Vec<Vec3>, SettleError> {
    let mut via_anchor = None;
    if let Some(a) = anchor {
        match equilibrium_continued(mesh, mass, frame, gamma, a, &params.statics()) {
            Ok((x, _)) => return Ok(x),
            Err(e) => via_anchor = Some(e),
        }
    }
    equilibrium(model, mass, frame, &frame.start, &params.statics())
        .map(|(x, _)| x)
        .map_err(|newton| match via_anchor {
            Some(continued) => SettleError::Both { newton, continued },
            None => SettleError::Newton(newton),
        })
}

/// The model of a material and the equilibria under it, per sample and frame.
type SettledSamples = (ElasticModel, Vec<Vec<Vec<Vec3>>>);

/// Every frame of `samples` brought to equilibrium under `gamma`
/// ([`settle`]; `anchors[s][f]` where known, may be empty): positions per
/// sample and frame, and the model of `gamma`.
fn settle_samples(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<SettledSamples, ElasticFitError> {
    let model = gamma
        .model(mesh)
        .map_err(|e| ElasticFitError::Inconsistent(e.to_string()))?;
    let xs = samples
        .iter()
        .enumerate()
        .map(|(k, s)| {
            s.frames
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let anchor = anchors.get(k).and_then(|a| a.get(i));
                    settle(mesh, &model, gamma, mass, f, anchor, params).map_err(|e| {
                        ElasticFitError::Sample {
                            sample: s.name.clone(),
                            frame: i,
                            message: e.to_string(),
                        }
                    })
                })
                .collect::<Result<Vec<_>, _>>()
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((model, xs))
}

/// Loss (m³) of each sample at material `gamma`, and the equilibria it
/// measures, per sample and frame ([`settle_samples`]).
pub fn sample_equilibria(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<(Vec<f64>, Vec<Vec<Vec<Vec3>>>), ElasticFitError> {
    let (model, xs) = settle_samples(mesh, mass, samples, gamma, anchors, params)?;
    let losses = samples
        .iter()
        .zip(&xs)
        .map(|(s, xs)| {
            s.frames
                .iter()
                .zip(xs)
                .map(|(f, x)| f.target.loss(&model, x))
                .sum()
        })
        .collect();
    Ok((losses, xs))
}

/// The uniform γ scale that the clamp reactions call for.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ForceScale {
    /// Least-squares factor `s` (dimensionless) applied to γ.
    pub scale: f64,
    /// Held bands matched (over all frames with reactions).
    pub bands: usize,
    /// `|s C - R| / |R|` over the stacked band resultants after scaling.
    pub relative_misfit: f64,
}

/// Connected groups of `pinned` nodes (joined by the tets they share).
fn bands_of(mesh: &TetMesh, pinned: &[usize]) -> Vec<Vec<usize>> {
    let n = mesh.num_nodes();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut is = vec![false; n];
    pinned.iter().for_each(|&i| is[i] = true);
    for t in &mesh.tets {
        let held: Vec<usize> = t.iter().map(|&i| i as usize).filter(|&i| is[i]).collect();
        for w in held.windows(2) {
            let (a, b) = (root(&mut parent, w[0]), root(&mut parent, w[1]));
            parent[a.max(b)] = a.min(b);
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for &i in pinned {
        let r = root(&mut parent, i);
        groups.entry(r).or_default().push(i);
    }
    groups.into_values().collect()
}

/// The mesh's size (m), the length that makes a wrench's moment a force.
fn wrench_length(mesh: &TetMesh) -> f64 {
    crate::geom::bounds_of(&mesh.nodes).map_or(1.0, |b| {
        crate::geom::dist(b.min, b.max).max(f64::MIN_POSITIVE)
    })
}

/// Per held band: the homogenized clamp wrench and the yarn level's.
type BandWrenches = Vec<([f64; 6], [f64; 6])>;

/// Per held band of `frame`, the homogenized clamp wrench at its
/// equilibrium under `model` (clamp force on a held node: `∂E/∂x - f_ext`;
/// the free nodes are at rest) and the wrench of the yarn-level reactions
/// `r`. The inner error: no equilibrium was found.
#[allow(clippy::too_many_arguments)]
fn band_wrenches(
    mesh: &TetMesh,
    model: &ElasticModel,
    gamma: &MaterialFields,
    mass: &[f64],
    frame: &Frame,
    anchor: Option<&Anchor>,
    r: &[Vec3],
    params: &ElasticFitParams,
) -> Result<Result<BandWrenches, SettleError>, ElasticFitError> {
    let x = match settle(mesh, model, gamma, mass, frame, anchor, params) {
        Ok(x) => x,
        Err(e) => return Ok(Err(e)),
    };
    let g = model
        .gradient(&x)
        .map_err(|e| ElasticFitError::Inconsistent(e.to_string()))?;
    let clamp: Vec<Vec3> = g
        .iter()
        .zip(&frame.f_ext)
        .map(|(a, b)| std::array::from_fn(|d| a[d] - b[d]))
        .collect();
    let length = wrench_length(mesh);
    Ok(Ok(bands_of(mesh, &frame.pinned)
        .iter()
        .map(|band| {
            (
                wrench(band, &x, &clamp, length),
                wrench(band, &x, r, length),
            )
        })
        .collect()))
}

/// The least-squares γ scale matching the homogenized clamp forces to the
/// yarn-level reactions (module documentation). `reactions[s][f]` are the
/// node reactions `Nᵀ r` of frame `f` of sample `s` (None without them);
/// frames with a free-node external force are skipped (their held
/// equilibrium depends on the scale). None when no frame qualifies or the
/// factor is not positive.
pub fn force_scale(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    reactions: &[Vec<Option<Vec<Vec3>>>],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<Option<ForceScale>, ElasticFitError> {
    let model = gamma
        .model(mesh)
        .map_err(|e| ElasticFitError::Inconsistent(e.to_string()))?;
    let (mut cc, mut cr, mut rr, mut bands) = (0.0, 0.0, 0.0, 0usize);
    let mut pairs = Vec::new();
    for (k, (s, rs)) in samples.iter().zip(reactions).enumerate() {
        for (i, (f, r)) in s.frames.iter().zip(rs).enumerate() {
            let Some(r) = r else { continue };
            let mut pinned = vec![false; mesh.num_nodes()];
            f.pinned.iter().for_each(|&p| pinned[p] = true);
            let loaded = f
                .f_ext
                .iter()
                .enumerate()
                .any(|(k, v)| !pinned[k] && v.iter().any(|c| *c != 0.0));
            if loaded {
                continue;
            }
            let anchor = anchors.get(k).and_then(|a| a.get(i));
            let frame_pairs = band_wrenches(mesh, &model, gamma, mass, f, anchor, r, params)?
                .map_err(|e| ElasticFitError::Sample {
                    sample: s.name.clone(),
                    frame: i,
                    message: e.to_string(),
                })?;
            for (c, y) in frame_pairs {
                cc += c.iter().map(|v| v * v).sum::<f64>();
                cr += c.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>();
                rr += y.iter().map(|v| v * v).sum::<f64>();
                pairs.push((c, y));
                bands += 1;
            }
        }
    }
    if !(cc > 0.0 && rr > 0.0) {
        return Ok(None);
    }
    let scale = cr / cc;
    if !(scale > 0.0 && scale.is_finite()) {
        return Ok(None);
    }
    let misfit: f64 = pairs
        .iter()
        .map(|(c, y)| (0..6).map(|d| (scale * c[d] - y[d]).powi(2)).sum::<f64>())
        .sum();
    Ok(Some(ForceScale {
        scale,
        bands,
        relative_misfit: (misfit / rr).sqrt(),
    }))
}

/// What [`stiffening_from_forces`] found.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StiffeningFit {
    /// The stiffening set on every tet, along the course and the wale
    /// (dimensionless, [`crate::sim::knit`]).
    pub beta_course: f64,
    pub beta_wale: f64,
    /// The relative clamp-force misfit ([`force_misfit`]) before and after.
    pub force_misfit_before: f64,
    pub force_misfit_after: f64,
    /// Whether the field was set to `beta_course`, `beta_wale`: only when
    /// that lowers the misfit; else the fit's own stiffening field stays.
    pub applied: bool,
    /// Frames and clamped bands compared, misfit evaluations, wall time (s).
    pub frames: usize,
    pub bands: usize,
    pub evaluations: usize,
    pub seconds: f64,
}

/// Largest stiffening [`stiffening_from_forces`] searches (dimensionless):
/// at 20% strain `β = 1e6` multiplies the fibre's secant stiffness by 4e4,
/// beyond what a knit's course reaches as its yarns straighten (measured:
/// a stockinette's course asks for about 5e4).
pub const MAX_SEARCHED_BETA: f64 = 1e6;

/// Golden-section evaluations per family and sweep of
/// [`stiffening_from_forces`]: the bracket `ln(1 + β)` in `[0, 13.8]`
/// narrows to about 0.02 (2% in `β`).
const STIFFENING_EVALUATIONS: usize = 16;

/// The relative misfit of the homogenized clamp forces against the
/// yarn-level reactions over every frame that has them (loaded frames
/// too: each is brought to equilibrium under `gamma`):
/// `sqrt(Σ |C_b - R_b|² / Σ |R_b|²)` over the held bands' wrenches
/// (resultant force and moment about the band's centroid over the mesh's
/// size, as [`force_scale`]), with `C = ∂E/∂x - f_ext` on the held nodes.
/// Returns the misfit and the frames and bands compared; None when no
/// frame has reactions or a frame finds no equilibrium.
pub fn force_misfit(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    reactions: &[Vec<Option<Vec<Vec3>>>],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<Option<(f64, usize, usize)>, ElasticFitError> {
    let model = gamma
        .model(mesh)
        .map_err(|e| ElasticFitError::Inconsistent(e.to_string()))?;
    let (mut num, mut den, mut frames, mut bands) = (0.0, 0.0, 0usize, 0usize);
    for (k, (s, rs)) in samples.iter().zip(reactions).enumerate() {
        for (i, (f, r)) in s.frames.iter().zip(rs).enumerate() {
            let Some(r) = r else { continue };
            let anchor = anchors.get(k).and_then(|a| a.get(i));
            let Ok(frame_pairs) = band_wrenches(mesh, &model, gamma, mass, f, anchor, r, params)?
            else {
                return Ok(None);
            };
            frames += 1;
            for (c, y) in frame_pairs {
                num += c.iter().zip(&y).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
                den += y.iter().map(|v| v * v).sum::<f64>();
                bands += 1;
            }
        }
    }
    Ok((den > 0.0).then(|| ((num / den).sqrt(), frames, bands)))
}

/// `gamma` with the stiffening of every tet set to `beta[0]` along the
/// course and `beta[1]` along the wale (stiffening families only).
fn with_stiffening(gamma: &MaterialFields, beta: [f64; 2]) -> MaterialFields {
    let mut g = gamma.clone();
    for (f, b) in g.fibres.iter_mut().zip(beta) {
        if f.stiffening() {
            f.beta.iter_mut().for_each(|v| *v = b);
        }
    }
    g
}

/// The knit material's stiffening from the clamp forces. A pose driven by
/// clamps has nearly the same shape under a material that stiffens and one
/// that does not, so the position loss leaves `β` where it starts
/// (measured on a 6 x 6 rib trained at 2/10/20% wale stretch: `β_wale`
/// 0.001, while the yarn level's clamp force grows 2.8 / 28.8 / 112.6 mN);
/// the clamp forces see it. One `β` per family, uniform over the mesh (the
/// positions identify no field of it), by golden-section search on
/// `ln(1 + β)` in `[0, ln(1 + MAX_SEARCHED_BETA)]`, course then wale, two
/// sweeps, each evaluation the equilibria of every frame with reactions
/// ([`force_misfit`]). Kept only where it lowers the misfit. None when
/// `gamma` has no stiffening family or no frame has reactions.
#[allow(clippy::too_many_arguments)]
pub fn stiffening_from_forces(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    reactions: &[Vec<Option<Vec<Vec3>>>],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
    progress: Option<&dyn Fn(&crate::fit::elastic::FitProgress)>,
) -> Result<Option<StiffeningFit>, ElasticFitError> {
    let families: Vec<usize> = (0..gamma.fibres.len().min(2))
        .filter(|&f| gamma.fibres[f].stiffening())
        .collect();
    if families.is_empty() || !reactions.iter().flatten().any(Option::is_some) {
        return Ok(None);
    }
    let t0 = Instant::now();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let mut beta = [0.0f64; 2];
    for (f, b) in gamma.fibres.iter().take(2).zip(beta.iter_mut()) {
        *b = mean(&f.beta);
    }
    let mut evaluations = 0usize;
    let mut misfit = |b: [f64; 2]| -> Result<f64, ElasticFitError> {
        evaluations += 1;
        let g = with_stiffening(gamma, b);
        let m = force_misfit(mesh, mass, samples, reactions, &g, anchors, params)?
            .map_or(f64::INFINITY, |m| m.0);
        if let Some(p) = progress {
            p(&crate::fit::elastic::FitProgress {
                sample: "clamp forces".into(),
                stage: "stiffening".into(),
                iteration: evaluations as u32,
                method: format!("beta {:.4e} / {:.4e}", b[0], b[1]),
                loss: m,
                ms: t0.elapsed().as_secs_f64() * 1e3,
                direction_ms: 0.0,
                halvings: 0,
            });
        }
        Ok(m)
    };
    let Some((before, frames, bands)) =
        force_misfit(mesh, mass, samples, reactions, gamma, anchors, params)?
    else {
        return Ok(None);
    };
    let (mut best_b, mut best) = (beta, misfit(beta)?);
    for _sweep in 0..2 {
        for &fam in &families {
            let at = |t: f64| {
                let mut b = best_b;
                b[fam] = t.exp_m1();
                b
            };
            let (t, ft) = crate::fit::golden::golden_section(
                (0.0, MAX_SEARCHED_BETA.ln_1p()),
                STIFFENING_EVALUATIONS - 2,
                true,
                |t| misfit(at(t)),
            )?;
            if ft < best {
                best = ft;
                best_b = at(t);
            }
        }
    }
    let keep = best < before;
    Ok(Some(StiffeningFit {
        beta_course: best_b[0],
        beta_wale: best_b[1],
        applied: keep,
        force_misfit_before: before,
        force_misfit_after: if keep { best } else { before },
        frames,
        bands,
        evaluations,
        seconds: t0.elapsed().as_secs_f64(),
    }))
}

fn range(v: &[f64]) -> [f64; 2] {
    v.iter()
        .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], x| {
            [lo.min(*x), hi.max(*x)]
        })
}

/// `g` scaled by `s`, every γ kept at or above `floor` (the fit's
/// non-negativity projection, VH §6.3): a γ that a fit drove to the floor
/// (measured: the demo's uniform `γv` at 0.035 Pa next to `γs` 15 kPa) stays
/// there when the reactions scale the material down.
fn scaled_above(g: &MaterialFields, s: f64, floor: f64) -> MaterialFields {
    g.with_stacked(
        &g.stacked()
            .iter()
            .map(|v| (v * s).max(floor))
            .collect::<Vec<_>>(),
    )
}

/// Whether the training loss at `to` is at most that at `from` (both
/// started from `anchors`, the equilibria under `from`; `to` by Newton from
/// there, without continuation, so a far material costs one solve per
/// frame); a material whose frames find no equilibrium so does not lower it. Loaded frames (weights,
/// external forces) see the material's scale in the loss, so there the loss,
/// not the clamp reactions, decides it: measured on a stretch + bend +
/// cantilever joint fit, the uniform stage reached 2.15e-5 m³ and the
/// reactions' scale (set by the unloaded stretch and bend) took it to 5.7e-4.
fn lowers_loss(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    (from, to): (&MaterialFields, &MaterialFields),
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<bool, ElasticFitError> {
    let before: f64 = sample_equilibria(mesh, mass, samples, from, anchors, params)?
        .0
        .iter()
        .sum();
    let model = to
        .model(mesh)
        .map_err(|e| ElasticFitError::Inconsistent(e.to_string()))?;
    let mut after = 0.0;
    for (k, s) in samples.iter().enumerate() {
        for (i, f) in s.frames.iter().enumerate() {
            let start = anchors
                .get(k)
                .and_then(|a| a.get(i))
                .map_or(&f.start, |a| &a.x);
            match equilibrium(&model, mass, f, start, &params.statics()) {
                Ok((x, _)) => after += f.target.loss(&model, &x),
                Err(_) => return Ok(false),
            }
        }
    }
    Ok(after <= before)
}

/// `samples` with every frame's start replaced by its equilibrium under
/// `gamma` ([`settle_samples`]: by continuation from `anchors[s][f]`, the
/// equilibria under a nearby material, when given); the pinned nodes keep
/// their places, so the frames pose the same problems.
fn warm_samples(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<Vec<Sample>, ElasticFitError> {
    let (_, xs) = settle_samples(mesh, mass, samples, gamma, anchors, params)?;
    Ok(samples
        .iter()
        .zip(xs)
        .map(|(s, xs)| Sample {
            frames: s
                .frames
                .iter()
                .zip(xs)
                .map(|(f, x)| Frame {
                    start: x,
                    ..f.clone()
                })
                .collect(),
            ..s.clone()
        })
        .collect())
}

/// What [`fit_samples`] found.
#[derive(Debug, Clone)]
pub struct Fitted {
    pub gamma: MaterialFields,
    pub uniform: UniformMaterial,
    pub uniform_fit: FitReport,
    pub fit: FitReport,
    /// Per sample: loss before, at the uniform material, fitted.
    pub losses: Vec<[f64; 3]>,
    /// Per sample and frame: the mesh's equilibrium (node positions, m)
    /// before, at the uniform material and fitted, the states `losses`
    /// measure.
    pub equilibria: Vec<[Vec<Vec<Vec3>>; 3]>,
    /// The reaction-matched scale applied to the uniform material, then to
    /// the fitted field (None: no reactions, or not applied).
    pub uniform_force_scale: Option<ForceScale>,
    pub field_force_scale: Option<ForceScale>,
    /// The knit material's stiffening set from the clamp forces, for the
    /// field and the uniform material ([`stiffening_from_forces`]; None
    /// without stiffening families or reactions).
    pub field_stiffening: Option<StiffeningFit>,
    pub uniform_stiffening: Option<StiffeningFit>,
    /// The field fitted to the positions and the clamp forces together
    /// (None: positions only).
    pub field_forces: Option<ForceFit>,
}

/// All samples as one (the loss of VH Eq. 9 summed over every frame),
/// named after them, weighted by their total energy.
pub fn joint_sample(samples: &[Sample]) -> Sample {
    Sample {
        name: samples
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(" + "),
        frames: samples.iter().flat_map(|s| s.frames.clone()).collect(),
        energy: samples.iter().map(|s| s.energy).sum(),
    }
}

/// The in-memory core of `fit`: the uniform (r = 1) material from `init`,
/// scaled to the clamp reactions ([`force_scale`]; `reactions[s][f]` per
/// sample and frame, may be empty), then the field from it
/// (`params.harmonic_ranks`, full stage), rescaled the same way when no
/// frame carries an external force; either sample by sample with the Eq.
/// 22 fold or, with `joint`, all samples as one ([`joint_sample`]). Losses
/// are reported per sample either way, "before" at `earlier` (the asset's
/// material; `init` adds the fibre families a fit with fibres starts from).
#[allow(clippy::too_many_arguments)]
pub fn fit_samples(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    reactions: &[Vec<Option<Vec<Vec3>>>],
    joint: bool,
    earlier: &MaterialFields,
    init: &MaterialFields,
    params: &ElasticFitParams,
    progress: Option<&dyn Fn(&crate::fit::elastic::FitProgress)>,
) -> Result<Fitted, ElasticFitError> {
    let uniform_params = ElasticFitParams {
        harmonic_ranks: vec![1],
        full_stage: false,
        ..params.clone()
    };
    let merged = [joint_sample(samples)];
    let inputs = FitInputs {
        mesh,
        mass,
        samples: if joint { &merged } else { samples },
        init,
        progress,
    };
    // Frames with external forces see the scale in the loss itself, so the
    // field is not rescaled when any frame has them, and the uniform
    // material only where the rescale lowers the loss ([`lowers_loss`]).
    // (Rescaling regardless stalls the r = 1 stage: 1.08e-3 -> 1.06e-3 m³
    // where stalled equilibria fail its line searches; with the stall
    // retried it reaches 2.15e-5.)
    let loaded = samples
        .iter()
        .any(crate::fit::elastic::gauss_newton::loaded);
    let (mut u, uniform_fit) = fit_materials(&inputs, &uniform_params)?;
    let at_uniform = anchors_of(&uniform_fit, samples, joint);
    let mut uniform_force_scale =
        force_scale(mesh, mass, samples, reactions, &u, &at_uniform, params)?;
    if let Some(fs) = uniform_force_scale {
        let rescaled = scaled_above(&u, fs.scale, params.gamma_floor);
        if !loaded || lowers_loss(mesh, mass, samples, (&u, &rescaled), &at_uniform, params)? {
            u = rescaled;
        } else {
            uniform_force_scale = None;
        }
    }
    // Where one sample (or the joint one) is fitted and the uniform material
    // kept, the field's start is already the optimum of the r = 1 subspace:
    // that stage could only spend line searches there (measured: 9 halvings
    // per ~45 s iteration on a joint stretch + bend + cantilever fit), and
    // so could the scale stage.
    // The knit material with clamp forces: the uniform material's
    // stiffening from the forces first, then the field fitted to the
    // positions and the forces together, so that its stiffnesses settle
    // under the stiffening the forces ask for (set after a positions-only
    // fit, that stiffening raised the rib's training position loss by 59%).
    let uniform_stiffening = stiffening_from_forces(
        mesh,
        mass,
        samples,
        reactions,
        &u,
        &at_uniform,
        params,
        progress,
    )?;
    if let Some(s) = uniform_stiffening.filter(|s| s.applied) {
        u = with_stiffening(&u, [s.beta_course, s.beta_wale]);
    }
    let forced = if uniform_stiffening.is_some() && params.force_weight > 0.0 {
        with_force_targets(mesh, mass, samples, reactions, &u, &at_uniform, params)?
    } else {
        None
    };
    let samples_field: &[Sample] = forced.as_deref().unwrap_or(samples);
    let merged_field = [joint_sample(samples_field)];
    let inputs = FitInputs {
        samples: if joint { &merged_field } else { samples_field },
        ..inputs
    };
    let start_optimal =
        forced.is_none() && uniform_force_scale.is_none() && (joint || samples.len() == 1);
    let field_params = ElasticFitParams {
        scale_search: params.scale_search && !start_optimal,
        harmonic_ranks: params
            .harmonic_ranks
            .iter()
            .copied()
            .filter(|&r| !(start_optimal && r == 1))
            .collect(),
        ..params.clone()
    };
    let params = &field_params;
    let (mut gamma, fit) = match fit_materials(&FitInputs { init: &u, ..inputs }, params) {
        // Newton from a frame's own start can fail under the uniform
        // material (measured: a cantilever frame under gravity in a joint
        // fit, after 7 minutes of the uniform stage, rescaled or not)
        // although the uniform fit reached its equilibrium through warm
        // starts: start the field's fit from the equilibria that
        // continuation from the uniform fit's finds.
        Err(ElasticFitError::Sample { .. }) => {
            let warm = warm_samples(mesh, mass, samples_field, &u, &at_uniform, params)?;
            let merged_warm = [joint_sample(&warm)];
            let field_inputs = FitInputs {
                init: &u,
                samples: if joint { &merged_warm } else { &warm },
                ..inputs
            };
            fit_materials(&field_inputs, params)?
        }
        other => other?,
    };
    let at_field = anchors_of(&fit, samples, joint);
    let field_force_scale = if loaded || forced.is_some() {
        None
    } else {
        force_scale(mesh, mass, samples, reactions, &gamma, &at_field, params)?
    };
    if let Some(fs) = field_force_scale {
        gamma = scaled_above(&gamma, fs.scale, params.gamma_floor);
    }
    // Without the force term (`force_weight` 0) the field's stiffening,
    // which the positions do not see, is set from the forces afterwards.
    let field_stiffening = if forced.is_some() {
        None
    } else {
        stiffening_from_forces(
            mesh, mass, samples, reactions, &gamma, &at_field, params, progress,
        )?
    };
    if let Some(s) = field_stiffening.filter(|s| s.applied) {
        gamma = with_stiffening(&gamma, [s.beta_course, s.beta_wale]);
    }
    let field_forces = match &forced {
        None => None,
        Some(_) => force_misfit(mesh, mass, samples, reactions, &gamma, &at_field, params)?.map(
            |(after, frames, bands)| ForceFit {
                weight: params.force_weight,
                force_misfit_start: uniform_stiffening.map_or(f64::NAN, |s| s.force_misfit_after),
                force_misfit_after: after,
                frames,
                bands,
            },
        ),
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let uniform = UniformMaterial {
        gamma_s: mean(&u.gamma_s),
        gamma_v: mean(&u.gamma_v),
        gamma_course: u.fibres.first().map(|f| mean(&f.gamma)),
        gamma_wale: u.fibres.get(1).map(|f| mean(&f.gamma)),
        beta_course: u
            .fibres
            .first()
            .filter(|f| f.stiffening())
            .map(|f| mean(&f.beta)),
        beta_wale: u
            .fibres
            .get(1)
            .filter(|f| f.stiffening())
            .map(|f| mean(&f.beta)),
    };
    let (before, x_before) = sample_equilibria(mesh, mass, samples, earlier, &[], params)?;
    let (at_u, x_u) = sample_equilibria(mesh, mass, samples, &u, &at_uniform, params)?;
    let (after, x_after) = sample_equilibria(mesh, mass, samples, &gamma, &at_field, params)?;
    let losses = (0..samples.len())
        .map(|k| [before[k], at_u[k], after[k]])
        .collect();
    let equilibria = x_before
        .into_iter()
        .zip(x_u)
        .zip(x_after)
        .map(|((b, u), a)| [b, u, a])
        .collect();
    Ok(Fitted {
        gamma,
        uniform,
        uniform_fit,
        fit,
        losses,
        equilibria,
        uniform_force_scale,
        field_force_scale,
        field_stiffening,
        uniform_stiffening,
        field_forces,
    })
}

/// What the field's fit to the clamp forces reached ([`with_force_targets`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ForceFit {
    /// The term's weight ρ ([`ElasticFitParams::force_weight`]).
    pub weight: f64,
    /// The relative clamp-force misfit ([`force_misfit`]) of the uniform
    /// material the field starts from, and of the fitted field.
    pub force_misfit_start: f64,
    pub force_misfit_after: f64,
    /// Frames and clamped bands compared.
    pub frames: usize,
    pub bands: usize,
}

/// `samples` with the clamp-force term on every frame that has yarn-level
/// reactions ([`crate::fit::elastic::force_loss`]): per held band the
/// wrench of the reactions, per sample the weight `ρ L0 / Σ |R|²`
/// ([`ElasticFitParams::force_weight`]; `L0` the sample's position loss
/// under `gamma`, the uniform material the field starts from). None when
/// no frame has reactions.
fn with_force_targets(
    mesh: &TetMesh,
    mass: &[f64],
    samples: &[Sample],
    reactions: &[Vec<Option<Vec<Vec3>>>],
    gamma: &MaterialFields,
    anchors: &[Vec<Anchor>],
    params: &ElasticFitParams,
) -> Result<Option<Vec<Sample>>, ElasticFitError> {
    if !reactions.iter().flatten().any(Option::is_some) {
        return Ok(None);
    }
    let (losses, _) = sample_equilibria(mesh, mass, samples, gamma, anchors, params)?;
    let length = wrench_length(mesh);
    let mut out = samples.to_vec();
    for ((s, rs), l0) in out.iter_mut().zip(reactions).zip(losses) {
        let targets: Vec<Option<Vec<BandForce>>> = s
            .frames
            .iter()
            .zip(rs.iter().chain(std::iter::repeat(&None)))
            .map(|(f, r)| {
                r.as_ref().map(|r| {
                    bands_of(mesh, &f.pinned)
                        .into_iter()
                        .map(|band| BandForce {
                            target: wrench(&band, &f.start, r, length),
                            nodes: band,
                        })
                        .collect()
                })
            })
            .collect();
        let norm2: f64 = targets
            .iter()
            .flatten()
            .flatten()
            .flat_map(|b| b.target)
            .map(|v| v * v)
            .sum();
        if !(norm2 > 0.0 && l0 > 0.0 && l0.is_finite()) {
            continue;
        }
        let weight = params.force_weight * l0 / norm2;
        for (f, t) in s.frames.iter_mut().zip(targets) {
            f.forces = t.map(|bands| ForceTarget {
                bands,
                length,
                weight,
            });
        }
    }
    Ok(Some(out))
}

/// The material a fit starts from: the asset's own (`earlier`), plus course
/// and wale fibres with stiffnesses at its `γs` when `fibres` asks for them
/// and it has none, their directions from its rest yarns; and the mean
/// chord anisotropy of directions found here.
fn fit_start(
    asset: &Asset,
    earlier: &MaterialFields,
    fibres: bool,
    model: FitModel,
) -> Result<(MaterialFields, Option<f64>), crate::embed::EmbedError> {
    let knit = model == FitModel::Knit;
    let stiffen = |mut m: MaterialFields| {
        if knit {
            for f in m.fibres.iter_mut().filter(|f| !f.stiffening()) {
                f.beta = vec![KNIT_BETA_START; f.gamma.len()];
            }
        }
        m
    };
    if !(fibres || knit) || !earlier.fibres.is_empty() {
        return Ok((stiffen(earlier.clone()), None));
    }
    let cw = crate::embed::orientation::course_and_wale(
        &asset.rest_yarns,
        &asset.grid,
        &asset.tet_voxel,
        &Default::default(),
    )?;
    let family = |directions: Vec<Vec3>| crate::sim::fibre::FibreFamily {
        directions,
        beta: Vec::new(),
        gamma: earlier.gamma_s.clone(),
    };
    let mut init = earlier.clone();
    init.fibres = vec![family(cw.course), family(cw.wale)];
    Ok((stiffen(init), Some(cw.mean_anisotropy)))
}

/// Where the material a fit starts from lies below the fit's floor, as a
/// message naming the dataset and the tet: every `γ` of a fit stays at or
/// above the floor (VH §6.3's projection), its start included.
fn below_floor(m: &MaterialFields, floor: f64) -> Option<String> {
    let fibres = ["CellData/gamma_course", "CellData/gamma_wale"];
    [
        ("CellData/gamma_s", &m.gamma_s),
        ("CellData/gamma_v", &m.gamma_v),
    ]
    .into_iter()
    .chain(fibres.into_iter().zip(m.fibres.iter().map(|f| &f.gamma)))
    .chain(
        ["CellData/beta_course", "CellData/beta_wale"]
            .into_iter()
            .zip(m.fibres.iter().map(|f| &f.beta)),
    )
    .find_map(|(name, g)| {
        let i = g.iter().position(|v| *v < floor)?;
        Some(format!(
            "{name} of tet {i} is {:e} Pa, below the fit's floor of {floor} Pa \
                 (a fit starts from the asset's material)",
            g[i]
        ))
    })
}

fn fit_error(poses: &[PathBuf], e: ElasticFitError) -> Error {
    match &e {
        ElasticFitError::Sample { sample, .. } => {
            let path = poses
                .iter()
                .find(|p| p.display().to_string() == *sample)
                .or_else(|| poses.first().filter(|_| poses.len() == 1))
                .cloned()
                .unwrap_or_else(|| PathBuf::from(sample));
            invalid(&path, format!("cannot be fitted: {e}"))
        }
        _ => Error::Internal(format!("elasticity fit: {e}")),
    }
}

impl Stage for FitJob {
    type Report = FitJobReport;
    const NAME: &'static str = "fit";
    fn run(&self, observer: &mut dyn Observer) -> Result<FitJobReport, Error> {
        let t0 = Instant::now();
        check_asset_ext(&self.asset)?;
        let output = self.output_path();
        check_asset_ext(&output)?;
        if self.train.is_empty() {
            return Err(Error::Usage("fit needs at least one --train pose".into()));
        }
        if self.samples == 0 {
            return Err(Error::Usage("--samples must be at least 1".into()));
        }
        if self.samples > MAX_SAMPLES {
            return Err(Error::Usage(format!(
                "samples {} is more than the limit of {MAX_SAMPLES} frames per pose",
                self.samples
            )));
        }
        for (name, n) in [
            ("gd_iterations", self.params.gd_iterations),
            ("gn_iterations", self.params.gn_iterations),
        ] {
            if n > MAX_ITERATIONS {
                return Err(Error::Usage(format!(
                    "{name} {n} is more than the limit of {MAX_ITERATIONS}"
                )));
            }
        }
        let mut inputs: Vec<&Path> = vec![&self.asset];
        inputs.extend(self.train.iter().map(PathBuf::as_path));
        let mut outs: Vec<&Path> = vec![&output];
        if let Some(r) = &self.report {
            outs.push(r);
        }
        io::overwrite::refuse_inputs(&outs, &inputs)?;
        let mut asset = io::vtkhdf::read_asset(&self.asset)?;
        let e = re_embed(&asset, &self.asset)?;
        let fitter = ShapeFitter::from_embedded(&asset.rest_yarns, &e, &ShapeFitParams::default())
            .map_err(|source| StageError::Fit {
                path: self.asset.clone(),
                source,
            })?;
        let model = ElasticModel::new(&asset.mesh, &asset.gamma_s, &asset.gamma_v)
            .map_err(|e| invalid(&self.asset, format!("its material: {e}")))?;
        let cx = Context {
            asset: &asset,
            asset_path: &self.asset,
            fitter,
            model,
            samples: self.samples,
            quasi_static: self.quasi_static,
            shape_fit_pins: self.shape_fit_pins,
        };
        let mut samples = Vec::new();
        let mut poses = Vec::new();
        let mut reactions = Vec::new();
        let mut pose_yarns = Vec::new();
        for p in &self.train {
            let pose = read_pose(&cx, p, &self.read, observer)?;
            samples.push(pose.sample);
            poses.push(pose.summary);
            reactions.push(pose.reactions);
            pose_yarns.push(pose.yarns);
        }
        let earlier = asset_materials(&asset);
        let (init, fibre_anisotropy) = fit_start(&asset, &earlier, self.fibres, self.model)
            .map_err(|e| invalid(&self.asset, format!("fibre directions: {e}")))?;
        if let Some(m) = below_floor(&init, self.params.gamma_floor) {
            return Err(invalid(&self.asset, m));
        }
        let fitted = {
            let cell = std::cell::RefCell::new(&mut *observer);
            let progress = |p: &crate::fit::elastic::FitProgress| cell.borrow_mut().iteration(p);
            fit_samples(
                &asset.mesh,
                &asset.node_mass,
                &samples,
                &reactions,
                self.joint,
                &earlier,
                &init,
                &self.params,
                Some(&progress),
            )
        }
        .map_err(|e| fit_error(&self.train, e))?;
        let (per_pose, training) =
            training_fidelity_of_poses(&asset, &pose_yarns, &samples, &fitted.equilibria);
        let per_frame =
            training_fidelity_per_frame(&asset, &pose_yarns, &samples, &fitted.equilibria);
        for ((p, t), f) in poses.iter_mut().zip(per_pose).zip(per_frame) {
            p.training = Some(t);
            p.training_per_frame = f;
        }
        let loaded = samples
            .iter()
            .flat_map(|s| &s.frames)
            .any(|f| f.f_ext.iter().flatten().any(|c| *c != 0.0));
        if fitted.uniform_force_scale.is_none() && !loaded {
            observer.warning(
                "no clamp reactions set the material scale (a loss without external forces does not see it)",
            );
        }
        let record = FitRecord {
            knitvox_version: env!("CARGO_PKG_VERSION").to_string(),
            poses: poses
                .iter()
                .map(|p| FitPose {
                    path: p.path.display().to_string(),
                    sha256: p.sha256.clone(),
                    frames: p.frames.clone(),
                    energy: p.energy,
                })
                .collect(),
            samples_per_pose: self.samples,
            harmonic_ranks: self.params.harmonic_ranks.clone(),
            joint: self.joint,
            uniform: fitted.uniform,
            losses: poses
                .iter()
                .zip(&fitted.losses)
                .enumerate()
                .map(|(k, (p, l))| {
                    (
                        p,
                        l,
                        &fitted.fit.samples[k.min(fitted.fit.samples.len() - 1)],
                    )
                })
                .map(|(p, l, s)| PoseLosses {
                    pose: p.path.display().to_string(),
                    before: l[0],
                    uniform: l[1],
                    fitted: l[2],
                    training: p.training,
                    stages: s
                        .stages
                        .iter()
                        .map(|st| {
                            (
                                st.name.clone(),
                                st.losses.last().copied().unwrap_or(f64::NAN),
                            )
                        })
                        .collect(),
                })
                .collect(),
            params: serde_json::to_value(&self.params)
                .map_err(|e| Error::Internal(e.to_string()))?,
        };
        set_asset_materials(&mut asset, &fitted.gamma)
            .map_err(|e| Error::Internal(e.to_string()))?;
        asset.set_fit_record(&record);
        for p in &self.train {
            asset.provenance.inputs.push(crate::geom::InputFile {
                path: p.display().to_string(),
                sha256: poses
                    .iter()
                    .find(|s| &s.path == p)
                    .map_or(String::new(), |s| s.sha256.clone()),
            });
        }
        asset.provenance.command = format!("{} && {}", asset.provenance.command, self.command);
        let sum = |k: usize| fitted.losses.iter().map(|l| l[k]).sum::<f64>();
        let mut report = FitJobReport {
            output: output.clone(),
            nodes: asset.mesh.num_nodes(),
            tets: asset.mesh.num_tets(),
            poses,
            loss_before: sum(0),
            loss_uniform: sum(1),
            loss_fitted: sum(2),
            training,
            uniform: fitted.uniform,
            uniform_force_scale: fitted.uniform_force_scale,
            field_force_scale: fitted.field_force_scale,
            field_stiffening: fitted.field_stiffening,
            uniform_stiffening: fitted.uniform_stiffening,
            field_forces: fitted.field_forces,
            gamma_s_range: range(&fitted.gamma.gamma_s),
            gamma_v_range: range(&fitted.gamma.gamma_v),
            gamma_course_range: fitted.gamma.fibres.first().map(|f| range(&f.gamma)),
            gamma_wale_range: fitted.gamma.fibres.get(1).map(|f| range(&f.gamma)),
            model: self.model,
            beta_course_range: fitted
                .gamma
                .fibres
                .first()
                .filter(|f| f.stiffening())
                .map(|f| range(&f.beta)),
            beta_wale_range: fitted
                .gamma
                .fibres
                .get(1)
                .filter(|f| f.stiffening())
                .map(|f| range(&f.beta)),
            fibre_anisotropy,
            uniform_fit: fitted.uniform_fit,
            fit: fitted.fit,
            report_files: Vec::new(),
            wall_s: 0.0,
        };
        io::atomic::all_or_nothing(|| -> Result<(), Error> {
            io::vtkhdf::write_asset(&output, &asset)?;
            if let Some(dir) = &self.report {
                report.report_files = write_report(dir, &asset, &report)?;
            }
            Ok(())
        })?;
        report.wall_s = t0.elapsed().as_secs_f64();
        Ok(report)
    }
}

/// The mid-plane slice of a per-tet field: voxels of the layer at the
/// middle of the thinnest axis, each the mean of its tets, over the other
/// two axes.
pub fn mid_plane_slice(asset: &Asset, field: &[f64], name: &str) -> plot::FieldSlice {
    let vox = &asset.grid.voxels;
    let lo = |k: usize| vox.iter().map(|v| v[k]).min().unwrap_or(0);
    let hi = |k: usize| vox.iter().map(|v| v[k]).max().unwrap_or(0);
    let ext: [i64; 3] = std::array::from_fn(|k| (hi(k) - lo(k)) as i64 + 1);
    let thin = (0..3).min_by_key(|&k| (ext[k], k)).unwrap_or(1);
    let (a, b) = match thin {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let mid = lo(thin) + ((ext[thin] - 1) / 2) as i32;
    let (nx, ny) = (ext[a] as usize, ext[b] as usize);
    let mut sum = vec![(0.0, 0usize); nx * ny];
    for (t, &v) in asset.tet_voxel.iter().enumerate() {
        let p = vox[v as usize];
        if p[thin] == mid {
            let c = (p[b] - lo(b)) as usize * nx + (p[a] - lo(a)) as usize;
            sum[c].0 += field[t];
            sum[c].1 += 1;
        }
    }
    let axis = ["x", "y", "z"];
    plot::FieldSlice {
        title: format!("{name}, voxel layer {} = {mid} (mid-plane)", axis[thin]),
        x_label: format!("{} (voxels)", axis[a]),
        y_label: format!("{} (voxels)", axis[b]),
        nx,
        ny,
        values: sum
            .iter()
            .map(|&(s, c)| (c > 0).then(|| s / c as f64))
            .collect(),
        unit: "Pa".into(),
    }
}

fn plot_err(path: &Path, e: plot::PlotError) -> Error {
    Error::Internal(format!("{}: {e}", path.display()))
}

/// `fit.json`, `loss.png`, `gamma_hist.png`, `gamma_s_slice.png`,
/// `gamma_v_slice.png` in `dir`.
fn write_report(dir: &Path, asset: &Asset, r: &FitJobReport) -> Result<Vec<PathBuf>, Error> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    let mut put = |name: &str, bytes: &[u8]| -> Result<(), Error> {
        let p = dir.join(name);
        io::atomic::write_bytes(&p, bytes)?;
        files.push(p);
        Ok(())
    };
    let json = serde_json::to_vec_pretty(r).map_err(|e| Error::Internal(e.to_string()))?;
    put("fit.json", &json)?;
    // Loss per accepted iteration, across the stages, per pose, relative to
    // its start (log10: 0 at the start, -k after a 10^k decrease).
    let series = r
        .fit
        .samples
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let losses: Vec<f64> = s
                .stages
                .iter()
                .enumerate()
                .flat_map(|(i, st)| st.losses.iter().skip(usize::from(i > 0)).copied())
                .collect();
            plot::Series {
                label: Path::new(&s.name)
                    .file_name()
                    .map_or(s.name.clone(), |n| n.to_string_lossy().into_owned()),
                points: losses
                    .iter()
                    .enumerate()
                    .map(|(i, l)| {
                        let l0 = losses[0].max(1e-300);
                        [i as f64, (l / l0).max(1e-300).log10()]
                    })
                    .collect(),
                color: plot::PALETTE[k % plot::PALETTE.len()],
            }
        })
        .collect();
    let fig = plot::Figure {
        title: "elasticity fit: loss per iteration (all stages)".into(),
        panels: vec![plot::Panel {
            x_label: "iteration".into(),
            y_label: "log10(loss / loss at the start)".into(),
            series,
        }],
        size: (900, 500),
    };
    let loss_png = dir.join("loss.png");
    put(
        "loss.png",
        &plot::render_png(&fig).map_err(|e| plot_err(&loss_png, e))?,
    )?;
    let hist = |label: &str, v: &[f64], c: usize| {
        plot::histogram_series(label, v, 40, plot::PALETTE[c]).map(|s| plot::Panel {
            x_label: format!("{label} (Pa)"),
            y_label: "tets".into(),
            series: vec![s],
        })
    };
    let hist_png = dir.join("gamma_hist.png");
    let fig = plot::Figure {
        title: "fitted materials".into(),
        panels: vec![
            hist("gamma_s", &asset.gamma_s, 0).map_err(|e| plot_err(&hist_png, e))?,
            hist("gamma_v", &asset.gamma_v, 1).map_err(|e| plot_err(&hist_png, e))?,
        ],
        size: (900, 700),
    };
    put(
        "gamma_hist.png",
        &plot::render_png(&fig).map_err(|e| plot_err(&hist_png, e))?,
    )?;
    for (name, field) in [("gamma_s", &asset.gamma_s), ("gamma_v", &asset.gamma_v)] {
        let file = format!("{name}_slice.png");
        let slice = mid_plane_slice(asset, field, name);
        let png = plot::render_field_png(&slice, (900, 600))
            .map_err(|e| plot_err(&dir.join(&file), e))?;
        put(&file, &png)?;
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `g` scaled by `s > 0` (every γ here is positive: no floor bites).
    fn scaled(g: &MaterialFields, s: f64) -> MaterialFields {
        scaled_above(g, s, 0.0)
    }

    #[test]
    fn inertia_forces_cancel_gravity_in_free_fall_and_add_damping() {
        // Shape fits of a free fall x(t) = x0 + u t + g t²/2 sampled every
        // dt: the second difference is exactly g dt², so the Eq. 13 force
        // balances each node's weight, whatever the step; damping adds
        // -c m v with v the backward difference.
        let (g, u, dt) = ([0.0, -9.81, 0.0], [0.3, 0.1, -0.2], 1.0 / 30.0);
        let mass = vec![2e-4, 5e-5, 1e-3];
        let x0s: Vec<Vec3> = vec![[0.0, 0.0, 0.0], [0.01, 0.02, -0.03], [1.0, 2.0, 3.0]];
        let at = |t: f64| -> Vec<Vec3> {
            x0s.iter()
                .map(|p| std::array::from_fn(|k| p[k] + u[k] * t + 0.5 * g[k] * t * t))
                .collect()
        };
        let t2 = 0.4;
        let (a, b, c) = (at(t2 - 2.0 * dt), at(t2 - dt), at(t2));
        let f = inertia_forces(&mass, [&a, &b, &c], dt, 0.0);
        for (fi, m) in f.iter().zip(&mass) {
            for k in 0..3 {
                assert!((fi[k] + m * g[k]).abs() <= 1e-9 * m * 9.81, "{fi:?}");
            }
        }
        let damping = 2.0;
        let fd = inertia_forces(&mass, [&a, &b, &c], dt, damping);
        for i in 0..3 {
            for k in 0..3 {
                let v = (c[i][k] - b[i][k]) / dt;
                let want = -mass[i] * (g[k] + damping * v);
                assert!(
                    (fd[i][k] - want).abs() <= 1e-9 * mass[i] * 10.0,
                    "{:?}",
                    fd[i]
                );
            }
        }
    }

    #[test]
    fn frames_are_chosen_evenly_with_the_last() {
        assert_eq!(choose_frames(11, 2), vec![5, 10]);
        assert_eq!(choose_frames(11, 1), vec![10]);
        assert_eq!(choose_frames(3, 5), vec![0, 1, 2]);
        assert_eq!(choose_frames(10, 4), vec![2, 4, 7, 9]);
        assert_eq!(choose_frames(1, 1), vec![0]);
    }

    /// A joint fit's anchors (one merged sample) go back to the samples it
    /// joined, frame by frame in order; a pose-by-pose fit's stay as they are.
    #[test]
    fn joint_anchors_split_back_into_their_samples() {
        let anchor = |v: f64| Anchor {
            gamma: std::sync::Arc::new(vec![v]),
            x: vec![[v, 0.0, 0.0]],
        };
        let frame = || Frame {
            target: FrameTarget {
                f_target: Vec::new(),
                alpha: 0.0,
                positions: Vec::new(),
            },
            pinned: Vec::new(),
            start: Vec::new(),
            f_ext: Vec::new(),
            forces: None,
        };
        let sample = |n: usize| Sample {
            name: format!("{n} frames"),
            frames: (0..n).map(|_| frame()).collect(),
            energy: 1.0,
        };
        let samples = [sample(2), sample(1)];
        let report = |groups: Vec<Vec<f64>>| FitReport {
            samples: groups
                .into_iter()
                .map(|g| crate::fit::elastic::SampleReport {
                    anchors: g.into_iter().map(anchor).collect(),
                    ..Default::default()
                })
                .collect(),
            ..Default::default()
        };
        let firsts = |a: Vec<Vec<Anchor>>| -> Vec<Vec<f64>> {
            a.iter()
                .map(|s| s.iter().map(|a| a.x[0][0]).collect())
                .collect()
        };
        let joint = anchors_of(&report(vec![vec![1.0, 2.0, 3.0]]), &samples, true);
        assert_eq!(firsts(joint), vec![vec![1.0, 2.0], vec![3.0]]);
        let apart = anchors_of(&report(vec![vec![1.0, 2.0], vec![3.0]]), &samples, false);
        assert_eq!(firsts(apart), vec![vec![1.0, 2.0], vec![3.0]]);
    }

    /// The reactions' scale keeps a γ the fit drove to the floor there (the
    /// demo's uniform γv sat at 0.035-0.13 Pa and a 0.026 scale took it
    /// below the 1e-3 floor, which the next stage refused), and scales the
    /// rest exactly.
    #[test]
    fn the_reaction_scale_keeps_the_material_above_the_floor() {
        let g = MaterialFields {
            gamma_s: vec![15e3, 2e3],
            gamma_v: vec![0.035, 1e-3],
            fibres: Vec::new(),
        };
        let s = scaled_above(&g, 0.026, 1e-3);
        assert_eq!(s.gamma_s, vec![15e3 * 0.026, 2e3 * 0.026]);
        assert_eq!(s.gamma_v, vec![1e-3, 1e-3]);
        let up = scaled_above(&g, 10.0, 1e-3);
        assert_eq!(up.gamma_s, vec![15e3 * 10.0, 2e3 * 10.0]);
        assert_eq!(up.gamma_v, vec![0.035 * 10.0, 1e-3 * 10.0]);
    }

    /// A slab held at both ends and stretched 20 %: the clamp forces at a
    /// true material γ* are the "reactions"; from γ*/7 the force scale is 7
    /// (the held equilibrium does not depend on the scale).
    #[test]
    fn force_scale_recovers_the_material_scale_from_reactions() {
        let h = 0.01;
        let (mesh, mass) = crate::embed::box_mesh([6, 2, 2], h, 120.0);
        let nt = mesh.num_tets();
        let truth = MaterialFields {
            gamma_s: vec![2e4; nt],
            gamma_v: vec![5e4; nt],
            fibres: Vec::new(),
        };
        let lx = 6.0 * h;
        let mut pinned = Vec::new();
        let mut start = mesh.nodes.clone();
        for (i, p) in mesh.nodes.iter().enumerate() {
            if p[0] < 1e-9 || p[0] > lx - 1e-9 {
                pinned.push(i);
                start[i][0] *= 1.2;
            }
        }
        let model = ElasticModel::new(&mesh, &truth.gamma_s, &truth.gamma_v).unwrap();
        let frame = Frame {
            target: FrameTarget::from_nodes(&model, &start, &mass, LOSS_ALPHA, h).unwrap(),
            pinned: pinned.clone(),
            start: start.clone(),
            f_ext: vec![[0.0; 3]; mesh.num_nodes()],
            forces: None,
        };
        let params = ElasticFitParams::default();
        let (x, _) = equilibrium(&model, &mass, &frame, &start, &params.statics()).unwrap();
        let g = model.gradient(&x).unwrap();
        let mut r = vec![[0.0; 3]; g.len()];
        for &i in &pinned {
            r[i] = g[i];
        }
        let samples = [Sample {
            name: "stretch".into(),
            frames: vec![frame],
            energy: 1.0,
        }];
        let reactions = vec![vec![Some(r)]];
        let fs = force_scale(
            &mesh,
            &mass,
            &samples,
            &reactions,
            &scaled(&truth, 1.0 / 7.0),
            &[],
            &params,
        )
        .unwrap()
        .unwrap();
        assert_eq!(fs.bands, 2);
        assert!((fs.scale - 7.0).abs() < 1e-4 * 7.0, "{fs:?}");
        assert!(fs.relative_misfit < 1e-4, "{fs:?}");
        // Without reactions there is nothing to match.
        let none =
            force_scale(&mesh, &mass, &samples, &[vec![None]], &truth, &[], &params).unwrap();
        assert!(none.is_none());
    }

    /// The nodes of a bar's two ends (x = 0 and x = `lx`), and the nodes
    /// with those ends pulled apart by `strain`.
    fn clamped_stretch(mesh: &TetMesh, lx: f64, strain: f64) -> (Vec<usize>, Vec<Vec3>) {
        let mut pinned = Vec::new();
        let mut start = mesh.nodes.clone();
        for (i, p) in mesh.nodes.iter().enumerate() {
            if p[0] < 1e-9 || p[0] > lx - 1e-9 {
                pinned.push(i);
                start[i][0] *= 1.0 + strain;
            }
        }
        (pinned, start)
    }

    #[test]
    fn the_stiffening_is_found_from_the_clamp_forces() {
        let h = 0.01;
        let (mesh, mass) = crate::embed::box_mesh([6, 2, 2], h, 120.0);
        let nt = mesh.num_tets();
        let with_beta = |beta: f64| MaterialFields {
            gamma_s: vec![2e3; nt],
            gamma_v: vec![6e3; nt],
            fibres: vec![crate::sim::fibre::FibreFamily {
                directions: vec![[1.0, 0.0, 0.0]; nt],
                gamma: vec![2e4; nt],
                beta: vec![beta; nt],
            }],
        };
        let truth = with_beta(60.0);
        let model = truth.model(&mesh).unwrap();
        let params = ElasticFitParams::default();
        let lx = 6.0 * h;
        // Stretches of 5% and 20% between clamped ends, reactions from the
        // truth's equilibria.
        let (mut frames, mut reactions) = (Vec::new(), Vec::new());
        for strain in [0.05, 0.2] {
            let (pinned, start) = clamped_stretch(&mesh, lx, strain);
            let frame = Frame {
                target: FrameTarget::from_nodes(&model, &start, &mass, LOSS_ALPHA, h).unwrap(),
                pinned: pinned.clone(),
                start: start.clone(),
                f_ext: vec![[0.0; 3]; mesh.num_nodes()],
                forces: None,
            };
            let (x, _) = equilibrium(&model, &mass, &frame, &start, &params.statics()).unwrap();
            let g = model.gradient(&x).unwrap();
            let mut r = vec![[0.0; 3]; g.len()];
            for &i in &pinned {
                r[i] = g[i];
            }
            frames.push(frame);
            reactions.push(Some(r));
        }
        let samples = [Sample {
            name: "stretch".into(),
            frames,
            energy: 1.0,
        }];
        let reactions = vec![reactions];
        let found = stiffening_from_forces(
            &mesh,
            &mass,
            &samples,
            &reactions,
            &with_beta(1.0),
            &[],
            &params,
            None,
        )
        .unwrap()
        .unwrap();
        eprintln!("{found:?}");
        assert_eq!((found.frames, found.bands), (2, 4));
        assert!(found.applied, "{found:?}");
        assert!((found.beta_course - 60.0).abs() < 0.05 * 60.0, "{found:?}");
        assert!(
            found.force_misfit_after < 0.02 * found.force_misfit_before,
            "{found:?}"
        );
        // The truth itself is kept: no search lowers its misfit of 0.
        let kept = stiffening_from_forces(
            &mesh,
            &mass,
            &samples,
            &reactions,
            &truth,
            &[],
            &params,
            None,
        )
        .unwrap()
        .unwrap();
        assert!(!kept.applied, "{kept:?}");
        assert_eq!(kept.force_misfit_after, kept.force_misfit_before);
        // A material without stiffening, or frames without reactions: no search.
        let mut quadratic = with_beta(1.0);
        quadratic.fibres[0].beta.clear();
        let none = |g: &MaterialFields, r: &[Vec<Option<Vec<Vec3>>>]| {
            stiffening_from_forces(&mesh, &mass, &samples, r, g, &[], &params, None).unwrap()
        };
        assert!(none(&quadratic, &reactions).is_none());
        assert!(none(&with_beta(1.0), &[vec![None, None]]).is_none());
    }

    /// A knit fit with clamp forces fits the field to the positions and the
    /// forces together: on a bar stretched 5% and 20% between clamps, whose
    /// stiffening fibre is 4x stiffer in one half, the field fitted so
    /// matches both the positions and the clamp forces better than a
    /// positions-only fit whose stiffening is set from the forces after
    /// (`force_weight` 0), which trades positions for forces.
    #[test]
    fn the_knit_field_is_fitted_to_the_positions_and_the_clamp_forces_together() {
        let h = 0.01;
        let (mesh, mass) = crate::embed::box_mesh([6, 2, 2], h, 120.0);
        let nt = mesh.num_tets();
        let lx = 6.0 * h;
        let half: Vec<bool> = (0..nt)
            .map(|e| {
                let cx: f64 = mesh.tets[e]
                    .iter()
                    .map(|&i| mesh.nodes[i as usize][0])
                    .sum::<f64>()
                    / 4.0;
                cx > 0.5 * lx
            })
            .collect();
        let truth = MaterialFields {
            gamma_s: vec![2e3; nt],
            gamma_v: vec![6e3; nt],
            fibres: vec![crate::sim::fibre::FibreFamily {
                directions: vec![[1.0, 0.0, 0.0]; nt],
                gamma: half.iter().map(|&b| if b { 8e4 } else { 2e4 }).collect(),
                beta: vec![60.0; nt],
            }],
        };
        let model = truth.model(&mesh).unwrap();
        let params = ElasticFitParams {
            harmonic_ranks: vec![1, 10],
            full_stage: false,
            gn_iterations: 20,
            ..Default::default()
        };
        let (mut frames, mut reactions) = (Vec::new(), Vec::new());
        for strain in [0.05, 0.2] {
            let (pinned, start) = clamped_stretch(&mesh, lx, strain);
            let probe = Frame {
                target: FrameTarget::from_nodes(&model, &start, &mass, LOSS_ALPHA, h).unwrap(),
                pinned: pinned.clone(),
                start: start.clone(),
                f_ext: vec![[0.0; 3]; mesh.num_nodes()],
                forces: None,
            };
            let (x, _) = equilibrium(&model, &mass, &probe, &start, &params.statics()).unwrap();
            let g = model.gradient(&x).unwrap();
            let mut r = vec![[0.0; 3]; g.len()];
            for &i in &pinned {
                r[i] = g[i];
            }
            frames.push(Frame {
                target: FrameTarget::from_nodes(&model, &x, &mass, LOSS_ALPHA, h).unwrap(),
                ..probe
            });
            reactions.push(Some(r));
        }
        let samples = [Sample {
            name: "stretch".into(),
            frames,
            energy: 1.0,
        }];
        let reactions = vec![reactions];
        let init = MaterialFields {
            fibres: vec![crate::sim::fibre::FibreFamily {
                gamma: vec![4e4; nt],
                beta: vec![KNIT_BETA_START; nt],
                ..truth.fibres[0].clone()
            }],
            ..truth.clone()
        };
        let fit = |force_weight: f64| {
            let p = ElasticFitParams {
                force_weight,
                ..params.clone()
            };
            fit_samples(
                &mesh, &mass, &samples, &reactions, true, &init, &init, &p, None,
            )
            .unwrap()
        };
        let joint = fit(1.0);
        let f = joint
            .field_forces
            .expect("the field was fitted to the forces");
        assert_eq!((f.frames, f.bands), (2, 4));
        assert!(joint.field_stiffening.is_none());
        let [_, uniform, fitted] = joint.losses[0];
        // Positions only, the stiffening set afterwards from the forces.
        let after = fit(0.0);
        assert!(after.field_forces.is_none());
        let s = after.field_stiffening.expect("the stiffening set after");
        let [_, _, fitted_after] = after.losses[0];
        eprintln!(
            "together: force misfit {:.4} -> {:.4}, position loss {uniform:.3e} -> {fitted:.3e}; \
             after: force misfit {:.4}, position loss {fitted_after:.3e}",
            f.force_misfit_start, f.force_misfit_after, s.force_misfit_after
        );
        assert!(
            fitted < 0.5 * uniform,
            "position loss {uniform:e} -> {fitted:e}"
        );
        // Measured: 0.0150 against 0.0218, 1.30e-8 against 6.67e-8 m³.
        assert!(
            f.force_misfit_after < s.force_misfit_after,
            "force misfit together {} against after {}",
            f.force_misfit_after,
            s.force_misfit_after
        );
        assert!(
            fitted < 0.5 * fitted_after,
            "position loss together {fitted:e} against after {fitted_after:e}"
        );
    }

    /// A slab held at its x = 0 end under its weight, with a uniform
    /// material of `gamma` (Pa): the mesh, its masses, and a frame whose
    /// target is the flat rest shape.
    fn sagging_slab(gamma: f64) -> (TetMesh, Vec<f64>, MaterialFields, Frame) {
        let h = 0.01;
        let (mesh, mass) = crate::embed::box_mesh([6, 1, 2], h, 120.0);
        let nt = mesh.num_tets();
        let pinned: Vec<usize> = (0..mesh.num_nodes())
            .filter(|&i| mesh.nodes[i][0] < 1e-9)
            .collect();
        let weight: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
        let material = MaterialFields::uniform(nt, gamma, gamma);
        let model = ElasticModel::new(&mesh, &material.gamma_s, &material.gamma_v).unwrap();
        let frame = Frame {
            target: FrameTarget::from_nodes(&model, &mesh.nodes, &mass, LOSS_ALPHA, h).unwrap(),
            pinned,
            start: mesh.nodes.clone(),
            f_ext: weight,
            forces: None,
        };
        (mesh, mass, material, frame)
    }

    /// `warm_samples` puts every frame's start at its equilibrium under the
    /// given material, also by continuation from an anchor at another one:
    /// a slab held at one end and sagging under its weight.
    #[test]
    fn warm_samples_start_at_the_equilibrium_of_the_material() {
        let (mesh, mass, stiff, frame) = sagging_slab(2e4);
        let pinned = frame.pinned.clone();
        let soft = scaled(&stiff, 0.1);
        let model = ElasticModel::new(&mesh, &stiff.gamma_s, &stiff.gamma_v).unwrap();
        let samples = [Sample {
            name: "sag".into(),
            frames: vec![frame.clone()],
            energy: 1.0,
        }];
        let params = ElasticFitParams::default();
        let soft_model = ElasticModel::new(&mesh, &soft.gamma_s, &soft.gamma_v).unwrap();
        let (cold, _) =
            equilibrium(&soft_model, &mass, &frame, &frame.start, &params.statics()).unwrap();
        let (at_stiff, _) =
            equilibrium(&model, &mass, &frame, &frame.start, &params.statics()).unwrap();
        let anchor = Anchor {
            gamma: std::sync::Arc::new(stiff.stacked()),
            x: at_stiff,
        };
        let lowest = |x: &[Vec3]| x.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
        let sag = -lowest(&cold);
        assert!(sag > 1e-4, "the soft slab sags only {sag} m");
        for anchors in [vec![], vec![vec![anchor]]] {
            let warm = warm_samples(&mesh, &mass, &samples, &soft, &anchors, &params).unwrap();
            let x = &warm[0].frames[0].start;
            for &p in &pinned {
                assert_eq!(x[p], frame.start[p], "pinned node {p} moved");
            }
            let d = x
                .iter()
                .zip(&cold)
                .map(|(a, b)| crate::geom::dist(*a, *b))
                .fold(0.0, f64::max);
            assert!(
                d < 1e-3 * sag,
                "{} anchors: {d} m from the equilibrium",
                anchors.len()
            );
        }
    }

    /// The sagging slab of 2e3 Pa as a one-frame sample whose target is its
    /// own equilibrium under that material.
    fn sagged_sample(
        params: &ElasticFitParams,
    ) -> (TetMesh, Vec<f64>, MaterialFields, [Sample; 1]) {
        let (mesh, mass, truth, mut frame) = sagging_slab(2e3);
        let model = ElasticModel::new(&mesh, &truth.gamma_s, &truth.gamma_v).unwrap();
        let (sagged, _) =
            equilibrium(&model, &mass, &frame, &frame.start, &params.statics()).unwrap();
        frame.target = FrameTarget::from_nodes(&model, &sagged, &mass, LOSS_ALPHA, 0.01).unwrap();
        let samples = [Sample {
            name: "sag".into(),
            frames: vec![frame],
            energy: 1.0,
        }];
        (mesh, mass, truth, samples)
    }

    /// With a loaded frame the loss sees the material's scale: moving toward
    /// the material that made the frame lowers it, moving away does not.
    #[test]
    fn lowers_loss_sees_the_scale_of_a_loaded_frame() {
        let params = ElasticFitParams::default();
        let (mesh, mass, truth, samples) = sagged_sample(&params);
        let stiff = scaled(&truth, 7.0);
        assert!(lowers_loss(&mesh, &mass, &samples, (&stiff, &truth), &[], &params).unwrap());
        assert!(!lowers_loss(&mesh, &mass, &samples, (&truth, &stiff), &[], &params).unwrap());
    }

    /// A joint fit of a loaded frame from a material 100x too stiff: the
    /// uniform fit's scale stage finds the truth's scale, and the field fit,
    /// starting from that optimum, runs neither the scale nor the r = 1
    /// stage again.
    #[test]
    fn joint_loaded_fit_finds_the_scale_and_skips_what_its_start_optimizes() {
        let params = ElasticFitParams {
            harmonic_ranks: vec![1, 3],
            full_stage: false,
            ..Default::default()
        };
        let (mesh, mass, truth, samples) = sagged_sample(&params);
        let init = scaled(&truth, 100.0);
        let fitted = fit_samples(
            &mesh,
            &mass,
            &samples,
            &[],
            true,
            &init,
            &init,
            &params,
            None,
        )
        .unwrap();
        let names = |r: &crate::fit::elastic::FitReport| -> Vec<String> {
            r.samples[0].stages.iter().map(|s| s.name.clone()).collect()
        };
        assert_eq!(names(&fitted.uniform_fit), ["scale", "harmonic r=1"]);
        assert_eq!(names(&fitted.fit), ["harmonic r=3"]);
        assert!(fitted.uniform_force_scale.is_none());
        let c = fitted.uniform.gamma_s / truth.gamma_s[0];
        assert!((c - 1.0).abs() < 0.05, "uniform at {c} of the truth");
    }

    /// The pose record's bands: a stretch_courses file gives its left and
    /// right bands (both ends of the swatch along X), whatever its reactions.
    #[test]
    fn recorded_bands_are_the_clamped_bands_of_the_pose() {
        let n = 40;
        let points: Vec<Vec3> = (0..n)
            .map(|i| [0.001 * i as f64, 0.0, 0.0005 * (i % 4) as f64])
            .collect();
        let mut yarns = crate::geom::Yarns::new();
        yarns.push_curve(&points, false, 0.0005);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pose.h5");
        let mut w = io::h5::FrameWriter::create(&path, &yarns).unwrap();
        w.add_text(
            "pose_json",
            r#"{"kind":"stretch_courses","amount":0.1,"mirror":false,"folds":3,"band":0.1}"#,
        )
        .unwrap();
        w.push(0.1, &points).unwrap();
        w.finish().unwrap();
        let r = recorded_pose(&path).unwrap().unwrap();
        // An old record (no frame amounts, no steps): one load step.
        assert_eq!(r.frame_amounts, [0.1]);
        assert!(r.stop_frames.is_empty());
        let held = recorded_bands(&path, r.params, &points).unwrap();
        let lx = 0.001 * (n - 1) as f64;
        for (v, p) in points.iter().enumerate() {
            let edge = p[0] <= 0.1 * lx + 1e-12 || p[0] >= 0.9 * lx - 1e-12;
            assert_eq!(held[v], edge, "vertex {v} at x = {}", p[0]);
        }
        // No record: None; a broken record: an error naming the file.
        let bare = dir.path().join("bare.h5");
        io::h5::write_file(&bare, &yarns, None).unwrap();
        assert!(recorded_pose(&bare).unwrap().is_none());
        let broken = dir.path().join("broken.h5");
        let mut w = io::h5::FrameWriter::create(&broken, &yarns).unwrap();
        w.add_text("pose_json", r#"{"kind":"sideways"}"#).unwrap();
        w.push(0.1, &points).unwrap();
        w.finish().unwrap();
        let e = recorded_pose(&broken).unwrap_err().to_string();
        assert!(e.contains("broken.h5") && e.contains("pose_json"), "{e}");
        // A list of amplitudes: the amount of every frame and the stops;
        // a stop that is not one of its frames is refused.
        let listed = dir.path().join("listed.h5");
        let record = |stops: &str| {
            format!(
                r#"{{"kind":"stretch_courses","amount":0.2,"steps":2,"amounts":[0.1,0.2],
                "frame_amounts":[0.05,0.1,0.15,0.2],"stop_frames":{stops}}}"#
            )
        };
        let mut w = io::h5::FrameWriter::create(&listed, &yarns).unwrap();
        w.add_text("pose_json", &record("[1,3]")).unwrap();
        w.push(0.1, &points).unwrap();
        w.finish().unwrap();
        let r = recorded_pose(&listed).unwrap().unwrap();
        assert_eq!(r.frame_amounts, [0.05, 0.1, 0.15, 0.2]);
        assert_eq!(r.stop_frames, [1, 3]);
        let mut w = io::h5::FrameWriter::create(&listed, &yarns).unwrap();
        w.add_text("pose_json", &record("[1,7]")).unwrap();
        w.push(0.1, &points).unwrap();
        w.finish().unwrap();
        let e = recorded_pose(&listed).unwrap_err().to_string();
        assert!(e.contains("stop frame 7"), "{e}");
    }

    #[test]
    fn default_output_sits_beside_the_input() {
        assert_eq!(
            default_output(Path::new("/a/rib.vtkhdf")),
            PathBuf::from("/a/rib.fit.vtkhdf")
        );
    }
}
