//! The `validate` stage: one yls scene run at yarn level
//! ([`super::yls::run`]) and on the homogenized asset, compared frame by
//! frame through V2Y (VH Eq. 4).
//!
//! The yarn-level run uses the asset's rest yarns: a scene without
//! `[swatch]` gets them injected (written to a temporary knitvox HDF5 file),
//! a scene with one must produce the same topology and rest positions (to a
//! yarn radius). The homogenized run drives the mesh by the same pose: the
//! four nodes of every tet that holds a clamped yarn vertex follow that
//! vertex's band map ([`PoseDriver::group_target`] applied to the node's rest
//! position), gravity acts on the node masses (VH Eq. 2: the asset's mass
//! must be the yarn-level mass; a difference over 1% is warned), and each
//! frame is the implicit (backward-Euler) equilibrium of VH Eq. 13-14 at the
//! frame interval, solved by Newton ([`StaticSolver`], symbolic factorization
//! once). The scene's colliders (plane, sphere, character; the same objects
//! as the yarn-level run, at the frame's time) act on the homogenized mesh
//! through its yarn vertices: each V2Y yarn vertex is kept its yarn radius
//! outside by a penalty ([`ContactPenalty`], stiffness
//! [`CONTACT_STIFFNESS_FACTOR`] x the stiffest tet's `(γs + γv) h`).
//!
//! Distances are in yarn diameters (`|V2Y(x) - y| / 2 r` per vertex), over
//! frames 1.. (frame 0 is the rest state on both sides). The report also
//! gives the Y2V floor: the distance of `V2Y(Y2V(y))` from each yarn frame
//! `y` (VH Eq. 5-6), which no material can beat.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::fit::elastic::MaterialFields;
use crate::geom::{Asset, Vec3, YarnFrames, DEFAULT_GAMMA_S, DEFAULT_GAMMA_V};
use crate::io::{self, plot, IoError, WriteOptions};
use crate::pipeline::asset::{asset_materials, check_asset_ext, uniform_material, yarn_distances};
use crate::pipeline::frames::{FrameSink, YarnFrameWriter};
use crate::pipeline::sim_scene::{BackendChoice, SolverChoice};
use crate::pipeline::util::held_nodes;
use crate::pipeline::util::rms_max;
use crate::pipeline::validate_forces::{self, ForceMatch};
use crate::pipeline::validate_motion::{self, MotionReport, MotionScene};
use crate::pipeline::validate_pd::{HomogenizedRun, HomogenizedRunError};
use crate::pipeline::yls::{self, YlsError};
use crate::pipeline::yls_scene::{YarnModel, YlsScene};
use crate::pipeline::{Error, Observer, Stage};
use crate::sim::SimError;
use std::sync::Arc;

use crate::fit::{ShapeFitParams, ShapeFitter};
use crate::pipeline::asset::re_embed;
use crate::sim::statics::{
    ContactPenalty, EmbeddedPoint, Inertia, SignedDistance, StaticParams, StaticSolver,
};
use crate::yarn::poses::PoseDriver;
use crate::yarn::sim::PointCollider;

/// Collider penalty stiffness per yarn vertex, in units of the stiffest
/// tet's `(γs + γv) h` (N/m): 100 keeps the penetration about 1% of the
/// elastic deflection pressing the mesh into the collider.
pub const CONTACT_STIFFNESS_FACTOR: f64 = 100.0;

/// The `validate` stage.
#[derive(Debug, Clone)]
pub struct ValidateJob {
    /// The asset (.vtkhdf), usually fitted by `knitvox fit`.
    pub asset: PathBuf,
    /// The yls scene (schemas/yls-scene.md).
    pub scene: PathBuf,
    /// Require the uniform-material comparison (fails without a fit record).
    /// Without it the comparison runs when the asset records a fit.
    pub uniform: bool,
    /// Folder for `validate.json`, `error.png` and both yarn sequences (PLY).
    pub report: Option<PathBuf>,
    /// How the homogenized runs are integrated (PD by default, as
    /// `simulate`).
    pub homogenized: HomogenizedRunParams,
    /// A yarn-level run of the same scene to reuse instead of running it
    /// again (`knitvox yls` output, or `yarn_level.h5` of a `--report`):
    /// its scene (`/metadata/scene_toml`, `[swatch]` aside), rest yarns
    /// and frame times must match; its recorded wall time is reported as
    /// the yarn level's.
    pub truth: Option<PathBuf>,
    /// A second asset of the same mesh and rest yarns whose material is the
    /// reference to beat (VH Eq. 7 fitted on the same poses): run on the
    /// same scene, its distance is reported beside the asset's.
    pub compare_vh: Option<PathBuf>,
    /// Fit the stiffness-proportional damping on this scene
    /// (`knitvox fit-damping`) and write the asset with it to this path;
    /// the report then describes the run with the fitted damping.
    pub fit_damping: Option<PathBuf>,
}

/// Range of the damping search (s): `log10 β` in [-6, -1], plus `β = 0`.
/// The swing of a 6 x 6 stockinette or rib follows best at about 1e-2 s
/// (co-rotated, 1/600 s steps); 0.1 s damps every mode a swatch shows.
pub const DAMPING_SEARCH_LOG10: (f64, f64) = (-6.0, -1.0);

/// Golden-section refinements of the damping search after its first two
/// points: the bracket of `log10 β` shrinks to 5 x 0.618^12 = 0.016 decades.
pub const DAMPING_SEARCH_REFINEMENTS: usize = 12;

/// `beta` to 6 significant digits, the damping search's points: a decimal
/// that short reads back as the same f64 from any JSON parser (the record
/// is JSON), so a run with the recorded damping repeats the search's bit
/// for bit. The search's bracket is 0.016 decades; 6 digits change `β` by
/// at most 5e-6 of itself.
fn damping_digits(beta: f64) -> f64 {
    format!("{beta:.5e}").parse().unwrap_or(beta)
}

/// What `knitvox fit-damping` found (`ValidateReport::damping_fit`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct DampingFitReport {
    /// The asset written, with its damping record.
    pub output: PathBuf,
    /// The damping found (s) and the RMS (yarn diameters) with it and
    /// without damping, on the scene fitted.
    pub stiffness_damping_s: f64,
    pub rms_yarn_diameters: f64,
    pub undamped_rms_yarn_diameters: f64,
    /// Every `[β (s), RMS (yarn diameters)]` tried, in order.
    pub evaluations: Vec<[f64; 2]>,
    /// Wall time of the search (s).
    pub search_s: f64,
}

/// Error of one frame (yarn diameters).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct FrameError {
    pub frame: usize,
    pub time: f64,
    pub rms: f64,
    pub max: f64,
    pub uniform_rms: Option<f64>,
    /// RMS distance of `V2Y(Y2V(y))` from this yarn frame.
    pub y2v_floor_rms: f64,
    /// The clamp force on the band where the yarn level's force peaks,
    /// along the peak's direction (N): yarn level, the asset's material
    /// (None without yarn-level clamp forces; `validate_forces`).
    pub clamp_force_n: Option<f64>,
    pub asset_clamp_force_n: Option<f64>,
}

/// What `validate` measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ValidateReport {
    pub frames: usize,
    pub rms_yarn_diameters: f64,
    pub max_yarn_diameters: f64,
    pub uniform_rms_yarn_diameters: Option<f64>,
    pub uniform_max_yarn_diameters: Option<f64>,
    /// The same for the reference asset of `--compare-vh` (VH Eq. 7 fitted
    /// on the same poses), and that asset.
    pub vh_rms_yarn_diameters: Option<f64>,
    pub vh_max_yarn_diameters: Option<f64>,
    pub vh_asset: Option<PathBuf>,
    /// The same for the placeholder material every asset starts with
    /// (`DEFAULT_GAMMA_S`, `DEFAULT_GAMMA_V`), when the asset's differs.
    pub placeholder_rms_yarn_diameters: Option<f64>,
    /// Wall time of the yarn-level run and of the homogenized run with the
    /// asset's material (s), and their ratio.
    pub yarn_level_s: f64,
    pub homogenized_s: f64,
    pub speedup: f64,
    pub nodes: usize,
    pub tets: usize,
    pub yarn_vertices: usize,
    pub held_nodes: usize,
    /// The homogenized runs' integrator.
    pub solver: HomogenizedSolver,
    /// Newton iterations (solver `newton`) or PD iterations (`pd`) of the
    /// homogenized run with the asset's material, and its implicit-Euler
    /// steps.
    pub solver_iterations: u64,
    pub solver_steps: u64,
    /// Where the PD run with the asset's material spent its time (s): local
    /// steps and global solves (the rest of `homogenized_s` is contact
    /// targets, V2Y of the collider thickness and bookkeeping), and the
    /// contact CG iterations of its global solves and the numeric
    /// refactorizations of `K + W` for new contact sets (direct solver);
    /// 0 for Newton.
    pub pd_local_s: f64,
    pub pd_global_s: f64,
    pub pd_contact_cg_iterations: u64,
    pub pd_contact_refactors: u64,
    /// PD only: local steps evaluated (one per iteration, one more per step
    /// for its last iterate, one per rejected Anderson iterate) and the
    /// Anderson iterates rejected by the safeguard.
    pub pd_local_steps: u64,
    pub pd_accelerations_rejected: u64,
    /// PD only: the iteration cap per step, the steps of the run with the
    /// asset's material that reached it without meeting the tolerance (a
    /// warning says so), and its largest end-of-step residual (N: the
    /// largest `|∇Φ|` over free nodes) and that residual over the mean
    /// node weight (`m̄ · 9.81 m/s²`; 1: a node's weight left unbalanced).
    pub pd_iteration_cap: u32,
    pub pd_capped_steps: u64,
    pub pd_max_residual_n: f64,
    pub pd_max_residual_over_weight: f64,
    /// PD only (else 0): the tolerance of the steps and the largest
    /// end-of-step convergence measure (dimensionless, `PdParams::tolerance`:
    /// at most the tolerance unless a step was capped).
    pub pd_tolerance: f64,
    pub pd_convergence_max: f64,
    /// PD only: the local step's backend ("cpu", "gpu") and the global
    /// solver ("direct", "dd") that ran; "" for Newton.
    pub pd_backend: &'static str,
    pub pd_global_solver: &'static str,
    /// Colliders acting on both runs.
    pub colliders: usize,
    /// PD only: what the colliders act on in the homogenized runs
    /// ("yarns": the V2Y yarn vertices; "nodes": the tet nodes); "" for
    /// Newton (yarn vertices, by its own contact term).
    pub pd_contact: &'static str,
    /// PD only (else 0): the stiffness-proportional damping `β` (s) of the
    /// homogenized runs (`validate --stiffness-damping`, else the asset's
    /// damping record, else 0).
    pub pd_stiffness_damping_s: f64,
    /// PD only (else 0): the largest step of the homogenized runs (s;
    /// `--dt`, else [`default_pd_step`]).
    pub pd_max_dt_s: f64,
    /// Deepest collider penetration of a homogenized yarn vertex (m) and the
    /// most contacts in one frame ([`HomogenizedRun::max_contacts`]).
    pub max_penetration_m: f64,
    pub max_contacts: usize,
    /// Most implicit-Euler steps a homogenized frame took: PD splits every
    /// frame into steps of at most `pd_max_dt_s`; Newton takes one unless its solve
    /// fails, then retries in 2, 4, .. 16.
    pub max_substeps: usize,
    /// Total node mass of the asset and the yarn-level mass (kg).
    pub mesh_mass_kg: f64,
    pub yarn_mass_kg: f64,
    /// The Y2V floor: RMS and max distance of `V2Y(Y2V(y))` from the yarn
    /// frames (yarn diameters); no material gets closer on average.
    pub y2v_floor_rms_yarn_diameters: f64,
    pub y2v_floor_max_yarn_diameters: f64,
    /// The clamp forces (module `validate_forces`): the yarn level's
    /// largest force on one band (N), and how the asset's, the uniform
    /// material's and the `--compare-vh` reference's match it. None when
    /// the yarn level recorded none (the explicit model, or a `--truth`
    /// file made before clamp forces were recorded).
    pub clamp_force_n: Option<f64>,
    pub clamp_force: Option<ForceMatch>,
    pub uniform_clamp_force: Option<ForceMatch>,
    pub vh_clamp_force: Option<ForceMatch>,
    pub per_frame: Vec<FrameError>,
    /// The motion of both levels (module `validate_motion`): kinetic
    /// energy, centre-of-mass path, support force and slip along the
    /// colliders, per frame and in total, for the asset's material and the
    /// uniform one.
    pub motion: MotionReport,
    /// The yarn-level frames reused (`--truth`); `yarn_level_s` is then
    /// the wall time that file records, measured when it was made.
    pub truth_file: Option<PathBuf>,
    pub report_files: Vec<PathBuf>,
    /// `knitvox fit-damping`: the damping search and the asset written;
    /// the figures above are then those of the fitted damping.
    pub damping_fit: Option<DampingFitReport>,
    /// One line in words: the held-out distance, against the uniform
    /// material, and whether the fitted material is better, the same or
    /// worse ([`verdict`]).
    pub verdict: String,
}

/// Ratios within this factor of 1 read as "the same".
pub const SAME_WITHIN: f64 = 1.05;

/// `ours` against `theirs` (both distances): "better", "the same" or
/// "worse", with the ratio `theirs / ours` in words.
fn compare(ours: f64, theirs: f64, whose: &str) -> String {
    if !(ours > 0.0 && theirs > 0.0) {
        return format!("{whose} moves {}", crate::geom::num(theirs));
    }
    let r = theirs / ours;
    let word = if r > SAME_WITHIN {
        format!("the asset's is {r:.2}x closer: better")
    } else if r < 1.0 / SAME_WITHIN {
        format!("the asset's is {:.2}x farther: worse", 1.0 / r)
    } else {
        format!("within {:.0}%: the same", 100.0 * (SAME_WITHIN - 1.0))
    };
    format!("{whose} moves {theirs:.3}, so {word}")
}

/// The verdict line of a report: the fitted material's RMS and largest
/// distance from the yarn level in yarn diameters, the mesh's floor, and
/// the comparison with the uniform material when there is one.
pub fn verdict(r: &ValidateReport) -> String {
    let mut line = format!(
        "verdict: the asset's material moves {:.3} yarn diameters RMS (largest {:.2}) from the \
         yarn level over {} frames (the mesh alone could reach {:.3})",
        r.rms_yarn_diameters, r.max_yarn_diameters, r.frames, r.y2v_floor_rms_yarn_diameters
    );
    match r.uniform_rms_yarn_diameters {
        Some(u) => {
            line.push_str("; ");
            line.push_str(&compare(
                r.rms_yarn_diameters,
                u,
                "the best uniform material",
            ));
        }
        None => line.push_str("; no fit record, so no uniform material to compare with"),
    }
    if let Some(v) = r.vh_rms_yarn_diameters {
        line.push_str("; ");
        line.push_str(&compare(r.rms_yarn_diameters, v, "the VH Eq. 7 reference"));
    }
    if let (Some(n), Some(m)) = (r.clamp_force_n, r.clamp_force) {
        line.push_str(&format!(
            "; at the clamps' peak of {} the asset's material holds {:.2}x the yarn level's force",
            force_words(n),
            m.peak_ratio
        ));
        let others: Vec<String> = [
            ("the uniform one", r.uniform_clamp_force),
            ("VH Eq. 7's", r.vh_clamp_force),
        ]
        .iter()
        .filter_map(|(who, f)| f.map(|f| format!("{who} {:.2}x", f.peak_ratio)))
        .collect();
        if !others.is_empty() {
            line.push_str(&format!(" ({})", others.join(", ")));
        }
    }
    line
}

/// The damping search of `knitvox fit-damping` in words.
pub fn damping_words(d: &DampingFitReport) -> String {
    let how = if d.stiffness_damping_s > 0.0 {
        format!(
            "stiffness damping {:.3e} s brings the RMS from {:.3} (undamped) to {:.3} yarn diameters",
            d.stiffness_damping_s, d.undamped_rms_yarn_diameters, d.rms_yarn_diameters
        )
    } else {
        format!(
            "no damping in {:.0e}-{:.0e} s comes closer than none ({:.3} yarn diameters RMS)",
            10f64.powf(DAMPING_SEARCH_LOG10.0),
            10f64.powf(DAMPING_SEARCH_LOG10.1),
            d.undamped_rms_yarn_diameters
        )
    };
    format!(
        "damping: {how} in {} runs ({:.1} s); written to {}",
        d.evaluations.len(),
        d.search_s,
        d.output.display()
    )
}

/// A force in words at a readable scale (`12.3 mN`).
fn force_words(n: f64) -> String {
    let a = n.abs();
    if a >= 1.0 {
        format!("{n:.3} N")
    } else if a >= 1e-3 {
        format!("{:.3} mN", n * 1e3)
    } else {
        format!("{:.3} µN", n * 1e6)
    }
}

impl ValidateReport {
    /// The one-line summary `validate` prints.
    pub fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "frames": self.frames,
            "rms_yarn_diameters": self.rms_yarn_diameters,
            "max_yarn_diameters": self.max_yarn_diameters,
            "uniform_rms_yarn_diameters": self.uniform_rms_yarn_diameters,
            "vh_rms_yarn_diameters": self.vh_rms_yarn_diameters,
            "yarn_level_s": self.yarn_level_s,
            "homogenized_s": self.homogenized_s,
            "speedup": self.speedup,
            "y2v_floor_rms_yarn_diameters": self.y2v_floor_rms_yarn_diameters,
            "placeholder_rms_yarn_diameters": self.placeholder_rms_yarn_diameters,
            "clamp_force_n": self.clamp_force_n,
            "clamp_force_ratio": self.clamp_force.map(|m| m.peak_ratio),
            "clamp_force_error": self.clamp_force.map(|m| m.relative_error),
            "uniform_clamp_force_ratio": self.uniform_clamp_force.map(|m| m.peak_ratio),
            "vh_clamp_force_ratio": self.vh_clamp_force.map(|m| m.peak_ratio),
            "vh_clamp_force_error": self.vh_clamp_force.map(|m| m.relative_error),
            "com_travel_m": self.motion.yarn_level.com_travel_m,
            "com_travel_ratio": self.motion.homogenized_match.com_travel_ratio,
            "com_path_error": self.motion.homogenized_match.com_path_error,
            "slip_m": self.motion.yarn_level.slip_m,
            "slip_ratio": self.motion.homogenized_match.slip_ratio,
            "peak_kinetic_ratio": self.motion.homogenized_match.peak_kinetic_ratio,
            "verdict": self.verdict,
        })
    }
}

fn setup(path: &Path, message: String) -> Error {
    YlsError::Setup {
        file: path.to_path_buf(),
        message,
    }
    .into()
}

/// A yarn-level collider queried at one time.
struct AtTime {
    collider: Arc<dyn PointCollider>,
    t: f64,
}

impl SignedDistance for AtTime {
    fn signed_distance(&self, p: Vec3) -> (f64, Vec3) {
        self.collider.signed_distance(p, self.t)
    }
}

/// The integrator of `validate`'s homogenized runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum HomogenizedSolver {
    /// Projective dynamics, as `simulate` runs shots ([`super::validate_pd`]).
    #[default]
    Pd,
    /// One backward-Euler Newton solve per frame interval ([`homogenized_frames`]):
    /// the exact implicit step, a reference for PD.
    Newton,
}

/// How `validate` integrates its homogenized runs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HomogenizedRunParams {
    /// The integrator. Default PD.
    pub solver: HomogenizedSolver,
    /// Largest PD time step (s). None: `PdRunParams::default()` (1/150 s);
    /// `validate` passes [`default_pd_step`].
    pub max_dt: Option<f64>,
    /// Most PD iterations per step. None: `PdRunParams::default()` (100, the cap on the tolerance).
    pub pd_iterations: Option<u32>,
    /// PD: where the local step runs (default `Auto`, as `simulate`) and the
    /// global solver (default direct).
    pub backend: BackendChoice,
    pub global: SolverChoice,
    /// PD: what the colliders act on (default the yarn vertices).
    pub contact: super::validate_pd::ContactAt,
    /// PD: stiffness-proportional damping `β` (s) of the homogenized
    /// runs. None (default): the asset's damping record
    /// ([`crate::geom::DampingRecord`]), else 0.
    pub stiffness_damping: Option<f64>,
}

/// The homogenized runs' PD step for `scene` when none is given: the yarn
/// level's own step where it has a fixed one (`model = "rods"`: `[rods]
/// max_dt`, default 1/600 s), so that the comparison measures the
/// homogenization and not two time steps (implicit Euler's own
/// dissipation grows with the step: a 20 degree slide with friction keeps
/// 0.77x the yarn level's slip at 1/150 s and 0.97x at the yarn level's
/// 1/600 s, docs/fidelity.md, the time step); else PD's default (1/150 s;
/// the explicit yarn model's adaptive steps are far shorter).
pub fn default_pd_step(scene: &YlsScene) -> f64 {
    match scene.model {
        YarnModel::Rods => scene
            .rods
            .as_ref()
            .and_then(|r| r.max_dt)
            .unwrap_or(crate::yarn::fabric::RodDynamicsParams::default().max_dt),
        YarnModel::Explicit => super::validate_pd::PdRunParams::default().max_dt,
    }
}

/// What the Newton reference ([`homogenized_frames`]) leaves out of a scene
/// that PD and the yarn level model: collider friction and the
/// mass-proportional damping `damping` (1/s). None when the scene has
/// neither, so that the two runs differ only by the integrator.
pub fn newton_omissions(colliders: &[Arc<dyn PointCollider>], damping: f64) -> Option<String> {
    let mu = colliders.iter().map(|c| c.friction()).fold(0.0, f64::max);
    let mut left = Vec::new();
    if mu > 0.0 {
        left.push(format!("collider friction (mu up to {mu})"));
    }
    if damping > 0.0 {
        left.push(format!("the scene's damping ({damping} 1/s)"));
    }
    (!left.is_empty()).then(|| {
        format!(
            "ignores {}: its frames can part from the yarn level's for that reason alone",
            left.join(" and ")
        )
    })
}

/// The homogenized frames of `validate` by `solver` (see
/// [`homogenized_frames`] and [`super::validate_pd::pd_frames`]); `damping`
/// is the mass-proportional damping (1/s) of the PD run. Pure.
#[allow(clippy::too_many_arguments)]
pub fn homogenized_run(
    how: &HomogenizedRunParams,
    asset: &Asset,
    gamma: &MaterialFields,
    driver: &PoseDriver,
    gravity: Vec3,
    damping: f64,
    times: &[f64],
    colliders: &[Arc<dyn PointCollider>],
) -> Result<HomogenizedRun, HomogenizedRunError> {
    match how.solver {
        HomogenizedSolver::Newton => {
            homogenized_frames(asset, gamma, driver, gravity, times, colliders)
        }
        HomogenizedSolver::Pd => {
            let group = super::clamp_drive::node_groups(asset, driver);
            let pinned: Vec<usize> = (0..group.len()).filter(|&i| group[i].is_some()).collect();
            let nodes = &asset.mesh.nodes;
            let target = |i: usize, t: f64| driver.group_target(group[i].unwrap_or(0), nodes[i], t);
            let d = super::validate_pd::PdRunParams::default();
            let params = super::validate_pd::PdRunParams {
                mass_damping: damping,
                max_dt: how.max_dt.unwrap_or(d.max_dt),
                iterations: how.pd_iterations.unwrap_or(d.iterations),
                backend: how.backend,
                global: how.global,
                contact: how.contact,
                stiffness_damping: how.stiffness_damping.unwrap_or(0.0),
            };
            super::validate_pd::pd_frames(
                asset, gamma, &pinned, &target, gravity, times, colliders, &params,
            )
        }
    }
}

/// One frame interval `(t0, t1)` in `sub` backward-Euler steps from
/// positions `x` and velocities `v`: pinned node `i` at `target(i, t)`,
/// colliders from `contact_at(t)`. Returns the end positions and
/// velocities, the Newton iterations, and the most contacts and deepest
/// penetration (m) seen.
#[allow(clippy::too_many_arguments)]
fn frame_steps(
    solver: &mut StaticSolver,
    x: &[Vec3],
    v: &[Vec3],
    (t0, t1, sub): (f64, f64, usize),
    target: &dyn Fn(usize, f64) -> Vec3,
    pinned: &[usize],
    f_ext: &[Vec3],
    params: &StaticParams,
    contact_at: &dyn Fn(f64) -> Option<ContactPenalty>,
) -> Result<(Vec<Vec3>, Vec<Vec3>, u64, (usize, f64)), SimError> {
    let dt = (t1 - t0) / sub as f64;
    let (mut x, mut v) = (x.to_vec(), v.to_vec());
    let (mut iterations, mut contacts, mut depth) = (0u64, 0usize, 0.0f64);
    for j in 1..=sub {
        let t = t0 + dt * j as f64;
        let mut x0 = x.clone();
        for &i in pinned {
            x0[i] = target(i, t);
        }
        solver.set_contact(contact_at(t))?;
        // Eq. 13's x̃ = 2 x_prev - x_prevprev with x_prevprev = x - v Δt.
        let back: Vec<Vec3> = x
            .iter()
            .zip(&v)
            .map(|(p, w)| std::array::from_fn(|c| p[c] - w[c] * dt))
            .collect();
        let inertia = (dt > 0.0).then_some(Inertia {
            x_prev: &x,
            x_prevprev: &back,
            dt,
        });
        let (xn, st) = solver.solve(&x0, f_ext, inertia, params)?;
        iterations += st.iterations as u64;
        if let Some(c) = solver.contact() {
            let (count, d) = c.penetration(&xn);
            contacts = contacts.max(count);
            depth = depth.max(d);
        }
        if dt > 0.0 {
            v = xn
                .iter()
                .zip(&x)
                .map(|(a, b)| std::array::from_fn(|c| (a[c] - b[c]) / dt))
                .collect();
        }
        x = xn;
    }
    Ok((x, v, iterations, (contacts, depth)))
}

/// Homogenized frames at `times` (s; `times[0]` is the rest state) under
/// `gravity` (m/s²) and `colliders` (acting on the V2Y yarn vertices, see
/// the module documentation). Pure.
pub fn homogenized_frames(
    asset: &Asset,
    gamma: &MaterialFields,
    driver: &PoseDriver,
    gravity: Vec3,
    times: &[f64],
    colliders: &[Arc<dyn PointCollider>],
) -> Result<HomogenizedRun, HomogenizedRunError> {
    let mesh = &asset.mesh;
    let n = mesh.num_nodes();
    let group = super::clamp_drive::node_groups(asset, driver);
    let pinned: Vec<usize> = (0..n).filter(|&i| group[i].is_some()).collect();
    let model = gamma.model(mesh)?;
    let mut solver = StaticSolver::new(model, &asset.node_mass, &pinned)?;
    let stiffest = (0..mesh.num_tets())
        .map(|e| {
            gamma.gamma_s[e]
                + gamma.gamma_v[e]
                + gamma.fibres.iter().map(|f| f.gamma[e]).sum::<f64>()
        })
        .fold(0.0, f64::max);
    let stiffness = CONTACT_STIFFNESS_FACTOR * stiffest * asset.grid.h;
    let points: Vec<EmbeddedPoint> = (0..asset.embedding.num_vertices())
        .map(|v| EmbeddedPoint {
            nodes: mesh.tets[asset.embedding.tet[v] as usize].map(|i| i as usize),
            weights: asset.embedding.weights[v],
            thickness: asset.rest_yarns.radius_at(v),
        })
        .collect();
    let f_ext: Vec<Vec3> = asset
        .node_mass
        .iter()
        .map(|m| gravity.map(|g| m * g))
        .collect();
    let params = StaticParams::default();
    let mut run = HomogenizedRun::at_rest(&mesh.nodes);
    let contact_at = |t: f64| -> Option<ContactPenalty> {
        (!colliders.is_empty()).then(|| ContactPenalty {
            points: points.clone(),
            colliders: colliders
                .iter()
                .map(|c| {
                    Box::new(AtTime {
                        collider: c.clone(),
                        t,
                    }) as Box<dyn SignedDistance>
                })
                .collect(),
            stiffness,
        })
    };
    // State: positions and velocity (m/s). A frame whose Newton solve fails
    // is retried in 2, 4, ... 16 backward-Euler substeps (pins and colliders
    // at the substep times): contact active sets and large motions
    // converge in smaller steps.
    let mut x_p = mesh.nodes.clone();
    let mut v = vec![[0.0; 3]; n];
    for k in 1..times.len() {
        let (t0, t1) = (times[k - 1], times[k]);
        let mut sub = 1usize;
        let (x, vel, iterations, contacts) = loop {
            match frame_steps(
                &mut solver,
                &x_p,
                &v,
                (t0, t1, sub),
                &|i, t| driver.group_target(group[i].unwrap_or(0), mesh.nodes[i], t),
                &pinned,
                &f_ext,
                &params,
                &contact_at,
            ) {
                Ok(r) => break r,
                Err(source) if sub >= 16 => {
                    return Err(HomogenizedRunError::NewtonFrame {
                        frame: k,
                        time: t1,
                        substeps: sub,
                        source,
                    })
                }
                Err(_) => sub *= 2,
            }
        };
        run.iterations += iterations;
        run.max_contacts = run.max_contacts.max(contacts.0);
        run.max_penetration_m = run.max_penetration_m.max(contacts.1);
        run.substeps = run.substeps.max(sub);
        run.steps += sub as u64;
        v = vel;
        x_p = x.clone();
        run.frames.push(x);
    }
    Ok(run)
}

/// Yarn mass (kg) as the yarn-level simulator lumps it: per curve its
/// linear density when the yarns carry one, else `density π r²`, times
/// the segment lengths.
pub fn yarn_mass(yarns: &crate::geom::Yarns, density: f64) -> f64 {
    (0..yarns.num_curves())
        .map(|c| {
            yarns
                .segments_of(c)
                .map(|[a, b]| {
                    let ld = yarns.linear_density.as_ref().map_or_else(
                        || density * std::f64::consts::PI * yarns.radius_at(a).powi(2),
                        |d| d[c],
                    );
                    ld * crate::geom::dist(yarns.points[a], yarns.points[b])
                })
                .sum::<f64>()
        })
        .sum()
}

/// The scene table without `[swatch]` (the rest yarns are compared
/// separately, point by point).
fn scene_without_swatch(text: &str, file: &Path) -> Result<toml::Table, Error> {
    let mut table: toml::Table = text
        .parse()
        .map_err(|e| setup(file, format!("not a TOML scene: {e}")))?;
    table.remove("swatch");
    Ok(table)
}

/// Checks that `truth` ran `text` (the scene `file`, `[swatch]` aside) and
/// returns the wall time it records (s).
fn check_truth(truth: &Path, text: &str, file: &Path) -> Result<f64, Error> {
    let bad = |m: String| setup(truth, format!("--truth: {m}"));
    let recorded = io::h5::read_text(truth, "scene_toml")?.ok_or_else(|| {
        bad("records no scene (/metadata/scene_toml); make it with `knitvox yls` or `validate --report`".into())
    })?;
    let theirs = scene_without_swatch(&recorded, truth)?;
    let ours = scene_without_swatch(text, file)?;
    if theirs != ours {
        let differ: Vec<&str> = ours
            .keys()
            .chain(theirs.keys())
            .filter(|k| ours.get(*k) != theirs.get(*k))
            .map(String::as_str)
            .collect();
        return Err(bad(format!(
            "ran another scene than {} (keys differ: {}); run it again without --truth",
            file.display(),
            differ.join(", ")
        )));
    }
    let run = io::h5::read_text(truth, "run_json")?
        .ok_or_else(|| bad("records no run time (/metadata/run_json)".into()))?;
    let wall_s = serde_json::from_str::<serde_json::Value>(&run)
        .ok()
        .and_then(|v| v.get("wall_s").and_then(|w| w.as_f64()))
        .filter(|w| w.is_finite() && *w >= 0.0)
        .ok_or_else(|| bad(format!("/metadata/run_json: no valid `wall_s` in {run:?}")))?;
    Ok(wall_s)
}

/// The reused frames must be the scene's frames: one per `1 / frame_rate`
/// from 0 (the rest state) to `duration`.
fn check_truth_times(truth: &Path, times: &[f64], scene: &YlsScene) -> Result<(), Error> {
    let n = scene.num_frames();
    let dt = 1.0 / scene.frame_rate;
    let ok = times.len() == n + 1
        && times
            .iter()
            .enumerate()
            .all(|(k, t)| (t - k as f64 * dt).abs() <= 1e-9 * (1.0 + t.abs()));
    if ok {
        return Ok(());
    }
    Err(setup(
        truth,
        format!(
            "--truth: {} frames at times {:?}..; the scene asks for {} frames every {dt} s",
            times.len(),
            times.iter().take(3).collect::<Vec<_>>(),
            n + 1
        ),
    ))
}

/// The scene's text with `[swatch]` naming `swatch_file` when it has none.
fn with_swatch(text: &str, scene: &Path, swatch_file: &Path) -> Result<(String, bool), Error> {
    let table: toml::Table = text
        .parse()
        .map_err(|e| setup(scene, format!("not a TOML scene: {e}")))?;
    if table.contains_key("swatch") {
        return Ok((text.to_string(), false));
    }
    let p = swatch_file.display().to_string();
    if p.contains('\'') || p.contains('\n') {
        return Err(Error::Internal(format!(
            "temporary path {p} cannot be quoted"
        )));
    }
    Ok((format!("{text}\n[swatch]\nfile = '{p}'\n"), true))
}

/// The scene a damping search runs (`ValidateJob::fit_damping`).
struct DampingScene<'a> {
    driver: &'a PoseDriver,
    /// The scene's mass damping (1/s), as the yarn level's.
    damping: f64,
    frames: &'a YarnFrames,
    colliders: &'a [Arc<dyn PointCollider>],
}

impl ValidateJob {
    /// Searches the stiffness-proportional damping that brings the asset's
    /// homogenized run closest (RMS over the frames) to the yarn level on
    /// `scene`: `β = 0`, then a golden-section search of `log10 β` over
    /// [`DAMPING_SEARCH_LOG10`]; keeps 0 unless a damping is closer. Writes
    /// the asset with its [`crate::geom::DampingRecord`] to `out` and
    /// returns the damping and the report.
    #[allow(clippy::too_many_arguments)]
    fn fit_damping(
        &self,
        out: &Path,
        asset: &Asset,
        gamma: &MaterialFields,
        how: HomogenizedRunParams,
        scene: &YlsScene,
        ds: &DampingScene<'_>,
        observer: &mut dyn Observer,
    ) -> Result<(f64, DampingFitReport), Error> {
        if how.solver != HomogenizedSolver::Pd {
            return Err(Error::Usage(
                "fit-damping fits the damping of PD runs: --solver newton has none".into(),
            ));
        }
        let ts = Instant::now();
        let nf = ds.frames.num_frames();
        let sample = self.scene.display().to_string();
        let mut evaluations: Vec<[f64; 2]> = Vec::new();
        let mut rms_at = |beta: f64| -> Result<f64, Error> {
            let beta = damping_digits(beta);
            let t = Instant::now();
            let params = HomogenizedRunParams {
                stiffness_damping: Some(beta),
                ..how
            };
            let hr = homogenized_run(
                &params,
                asset,
                gamma,
                ds.driver,
                scene.gravity,
                ds.damping,
                &ds.frames.times,
                ds.colliders,
            )
            .map_err(|m| {
                setup(
                    &self.scene,
                    format!("homogenized run with damping {beta:e} s: {m}"),
                )
            })?;
            let d: Vec<f64> = (1..nf)
                .flat_map(|k| yarn_distances(asset, &hr.frames[k], ds.frames.frame(k)))
                .collect();
            let rms = rms_max(&d).0;
            evaluations.push([beta, rms]);
            observer.iteration(&crate::fit::elastic::FitProgress {
                sample: sample.clone(),
                stage: "damping".into(),
                iteration: evaluations.len() as u32,
                method: format!("beta {beta:.3e} s"),
                loss: rms,
                ms: t.elapsed().as_secs_f64() * 1e3,
                direction_ms: 0.0,
                halvings: 0,
            });
            Ok(rms)
        };
        let undamped = rms_at(0.0)?;
        let (u, best) = crate::fit::golden::golden_section(
            DAMPING_SEARCH_LOG10,
            DAMPING_SEARCH_REFINEMENTS,
            true,
            |u| rms_at(10f64.powf(u)),
        )?;
        let (beta, rms) = if best < undamped {
            (damping_digits(10f64.powf(u)), best)
        } else {
            (0.0, undamped)
        };
        let mut fitted = asset.clone();
        let scene_input = crate::pipeline::asset::input_record(&self.scene)?;
        let scene_sha256 = scene_input.sha256.clone();
        fitted.set_damping_record(&crate::geom::DampingRecord {
            knitvox_version: env!("CARGO_PKG_VERSION").to_string(),
            stiffness_damping_s: beta,
            scene: self.scene.display().to_string(),
            scene_sha256,
            rms_yarn_diameters: rms,
            undamped_rms_yarn_diameters: undamped,
            evaluations: evaluations.clone(),
            dt_s: how.max_dt,
            corotated: true,
        });
        fitted.provenance.inputs.push(scene_input);
        fitted.provenance.command = format!(
            "{} && knitvox fit-damping {} --scene {} -o {}",
            fitted.provenance.command,
            self.asset.display(),
            self.scene.display(),
            out.display()
        );
        io::vtkhdf::write_asset(out, &fitted)?;
        Ok((
            beta,
            DampingFitReport {
                output: out.to_path_buf(),
                stiffness_damping_s: beta,
                rms_yarn_diameters: rms,
                undamped_rms_yarn_diameters: undamped,
                evaluations,
                search_s: ts.elapsed().as_secs_f64(),
            },
        ))
    }
}

impl Stage for ValidateJob {
    type Report = ValidateReport;
    const NAME: &'static str = "validate";
    fn run(&self, observer: &mut dyn Observer) -> Result<ValidateReport, Error> {
        check_asset_ext(&self.asset)?;
        if let Some(r) = &self.report {
            io::overwrite::refuse_inputs(&[r], &[&self.asset, &self.scene])?;
        }
        if let Some(out) = &self.fit_damping {
            check_asset_ext(out)?;
            let mut inputs: Vec<&Path> = vec![&self.asset, &self.scene];
            inputs.extend(self.truth.as_deref());
            io::overwrite::refuse_inputs(&[out], &inputs)?;
        }
        let asset = io::vtkhdf::read_asset(&self.asset)?;
        // A bad damping record fails before any run.
        let recorded =
            asset
                .damping_record()
                .map_err(|e| crate::pipeline::asset::StageError::Invalid {
                    path: self.asset.clone(),
                    message: e.to_string(),
                })?;
        let vh = match &self.compare_vh {
            Some(p) => {
                check_asset_ext(p)?;
                let other = io::vtkhdf::read_asset(p)?;
                same_body(&asset, &self.asset, &other, p)?;
                Some(other)
            }
            None => None,
        };
        let record =
            asset
                .fit_record()
                .map_err(|e| crate::pipeline::asset::StageError::Invalid {
                    path: self.asset.clone(),
                    message: e.to_string(),
                })?;
        let uniform = match (&record, self.uniform) {
            (Some(r), _) => Some(r.uniform),
            (None, true) => {
                return Err(crate::pipeline::asset::StageError::Invalid {
                    path: self.asset.clone(),
                    message: "--uniform: the asset records no fit (run `knitvox fit` first)".into(),
                }
                .into())
            }
            (None, false) => {
                observer.warning(&format!(
                    "{}: no fit record: no uniform-material comparison",
                    self.asset.display()
                ));
                None
            }
        };
        let text =
            crate::io::input::read_input_text(&self.scene, "scene", crate::io::max_memory())?;
        let tmp = tempfile::tempdir().map_err(|source| IoError::Write {
            path: std::env::temp_dir(),
            source,
        })?;
        let swatch_file = tmp.path().join("rest.h5");
        let (text, injected) = with_swatch(&text, &self.scene, &swatch_file)?;
        if injected {
            // The scene runs on the asset's rest yarns: their faults are
            // the asset's, not the scene's.
            crate::yarn::rods::check_rest_state(&asset.rest_yarns).map_err(|e| {
                crate::pipeline::asset::StageError::Invalid {
                    path: self.asset.clone(),
                    message: format!("rest yarns: {e}"),
                }
            })?;
            io::h5::write_file(&swatch_file, &asset.rest_yarns, None)?;
        }
        let scene = YlsScene::parse(&text, &self.scene).map_err(YlsError::from)?;
        if let Some(dt) = self.homogenized.max_dt {
            let steps = scene.duration / dt;
            if !(dt.is_finite() && dt > 0.0 && steps <= super::simulate::MAX_TOTAL_STEPS as f64) {
                return Err(Error::Usage(format!(
                    "--dt {}: {} s of scene need {} PD steps (must be > 0 s and at most {} steps)",
                    crate::geom::num(dt),
                    crate::geom::num(scene.duration),
                    crate::geom::num(steps),
                    super::simulate::MAX_TOTAL_STEPS
                )));
            }
        }
        // `--backend gpu` without a GPU fails here (exit 69), before the
        // yarn-level run, not after it.
        if self.homogenized.solver == HomogenizedSolver::Pd
            && self.homogenized.backend == BackendChoice::Gpu
        {
            crate::sim::gpu::GpuContext::new().map_err(|e| {
                super::simulate::SimulateError::Unavailable(format!(
                    "--backend gpu: no usable GPU: {e}"
                ))
            })?;
        }
        // `auto` settles its backend here as well (a probe once per process,
        // [`crate::sim::gpu::hardware_adapter_available`]): setup, like
        // reading the asset, outside the timed runs.
        if self.homogenized.solver == HomogenizedSolver::Pd
            && self.homogenized.backend == BackendChoice::Auto
        {
            crate::sim::gpu::hardware_adapter_available();
        }
        let colliders: Vec<Arc<dyn PointCollider>> =
            yls::scene_colliders(&scene.colliders, &asset.rest_yarns)?
                .into_iter()
                .map(Arc::from)
                .collect();
        let yarn_params = yls::scene_params(&scene, &self.scene)?;
        if self.homogenized.solver == HomogenizedSolver::Newton {
            if let Some(m) = newton_omissions(&colliders, yarn_params.global_damping) {
                observer.warning(&format!("{}: --solver newton {m}", self.scene.display()));
            }
        }
        let density = yarn_params.density;
        let mesh_mass_kg: f64 = asset.node_mass.iter().sum();
        let yarn_mass_kg = yarn_mass(&asset.rest_yarns, density);
        if (mesh_mass_kg - yarn_mass_kg).abs() > 0.01 * yarn_mass_kg {
            observer.warning(&format!(
                "{}: the asset's mass {mesh_mass_kg:.4e} kg differs from the yarn-level mass {yarn_mass_kg:.4e} kg: gravity and inertia differ between the runs",
                self.asset.display()
            ));
        }
        // Yarn level: run, or reused from `--truth`.
        let yarn_out = tmp.path().join("yarn_level.h5");
        let (yarn_file, yarn_level_s) = match &self.truth {
            Some(truth) => {
                let wall_s = check_truth(truth, &text, &self.scene)?;
                (truth.clone(), wall_s)
            }
            None => {
                let yr = yls::run_observed(&scene, &text, &self.scene, &yarn_out, &mut |p| {
                    observer.frame(p)
                })?;
                (yarn_out.clone(), yr.wall_s)
            }
        };
        let yd = io::read_path(&yarn_file, &Default::default())?;
        let rest = &asset.rest_yarns;
        let same_rest = yd.yarns.offsets == rest.offsets
            && yd.yarns.closed == rest.closed
            && yd
                .yarns
                .points
                .iter()
                .zip(&rest.points)
                .enumerate()
                .all(|(v, (a, b))| crate::geom::dist(*a, *b) <= rest.radius_at(v));
        if !same_rest {
            return Err(setup(
                &self.scene,
                format!(
                    "its [swatch] is not the asset's rest yarns ({}): omit [swatch] to use them",
                    self.asset.display()
                ),
            ));
        }
        let frames: YarnFrames = yd
            .frames
            .ok_or_else(|| Error::Internal("the yarn-level run wrote no frames".into()))?;
        if let Some(truth) = &self.truth {
            check_truth_times(truth, &frames.times, &scene)?;
        }
        let driver = PoseDriver::new(&rest.points, scene.pose_params())
            .map_err(|e| setup(&self.scene, format!("pose: {e}")))?;
        let yarn_forces = io::h5::read_clamp_forces(&yarn_file, frames.num_frames())?
            .filter(|f| f.first().is_some_and(|b| b.len() == driver.num_groups()));
        if yarn_forces.is_none() && driver.num_groups() > 0 {
            observer.warning(&format!(
                "{}: the yarn-level run records no clamp forces ({}): forces are not compared",
                yarn_file.display(),
                if self.truth.is_some() {
                    "a --truth file made without them; run again without --truth"
                } else {
                    "the explicit yarn model keeps none; `model = \"rods\"` does"
                }
            ));
        }
        // The damping of the homogenized runs: as given, else the asset's
        // record, else none; `fit-damping` searches it here.
        let mut how = self.homogenized;
        how.max_dt = Some(how.max_dt.unwrap_or_else(|| default_pd_step(&scene)));
        if how.stiffness_damping.is_none() {
            how.stiffness_damping = Some(recorded.as_ref().map_or(0.0, |r| r.stiffness_damping_s));
            if let Some(m) = recorded.as_ref().and_then(|r| r.superseded()) {
                observer.warning(&format!("{}: {m}", self.asset.display()));
            }
        }
        let ga = asset_materials(&asset);
        let damping_fit = match &self.fit_damping {
            Some(out) => {
                let (beta, fit) = self.fit_damping(
                    out,
                    &asset,
                    &ga,
                    how,
                    &scene,
                    &DampingScene {
                        driver: &driver,
                        damping: yarn_params.global_damping,
                        frames: &frames,
                        colliders: &colliders,
                    },
                    observer,
                )?;
                how.stiffness_damping = Some(beta);
                Some(fit)
            }
            None => None,
        };
        // Homogenized, with the asset's material, then the uniform one.
        let t = Instant::now();
        let run_with = |gamma: &MaterialFields| {
            homogenized_run(
                &how,
                &asset,
                gamma,
                &driver,
                scene.gravity,
                yarn_params.global_damping,
                &frames.times,
                &colliders,
            )
        };
        let hr = run_with(&ga).map_err(|m| setup(&self.scene, format!("homogenized run: {m}")))?;
        let homogenized_s = t.elapsed().as_secs_f64();
        let xs = &hr.frames;
        let pd = self.homogenized.solver == HomogenizedSolver::Pd;
        let pd_cap = if pd {
            self.homogenized
                .pd_iterations
                .unwrap_or(super::validate_pd::PdRunParams::default().iterations)
        } else {
            0
        };
        let mean_weight = 9.81 * mesh_mass_kg / asset.mesh.num_nodes().max(1) as f64;
        let residual_over_weight = hr.max_residual_n / mean_weight.max(f64::MIN_POSITIVE);
        if pd && hr.capped_steps > 0 {
            observer.warning(&format!(
                "{}: the homogenized PD run stopped {} of its {} steps at the {pd_cap}-iteration cap, short of the tolerance {:e} (convergence up to {:.2e}, largest residual {:.3e} N, {:.1}x the mean node weight): those steps are not converged (raise --pd-iterations)",
                self.scene.display(),
                hr.capped_steps,
                hr.steps,
                hr.tolerance,
                hr.max_convergence,
                hr.max_residual_n,
                residual_over_weight
            ));
        }
        // The same scene with one material everywhere (uniform, placeholder).
        let ne = asset.mesh.num_tets();
        let run_uniform = |m: &MaterialFields, what: &str| {
            run_with(m).map_err(|e| setup(&self.scene, format!("{what} run: {e}")))
        };
        let gu = uniform.map(|u| uniform_material(&asset, &u));
        let xu = match &gu {
            Some(g) => Some(run_uniform(g, "uniform")?.frames),
            None => None,
        };
        let gv = vh.as_ref().map(asset_materials);
        let xv = match &gv {
            Some(g) => Some(run_uniform(g, "--compare-vh")?.frames),
            None => None,
        };
        // The Y2V floor (VH Eq. 5-6) of every yarn frame.
        let e = re_embed(&asset, &self.asset)?;
        let fitter =
            ShapeFitter::from_embedded(rest, &e, &ShapeFitParams::default()).map_err(|source| {
                crate::pipeline::asset::StageError::Fit {
                    path: self.asset.clone(),
                    source,
                }
            })?;
        let placeholder = (asset.gamma_s.iter().any(|g| *g != DEFAULT_GAMMA_S)
            || asset.gamma_v.iter().any(|g| *g != DEFAULT_GAMMA_V))
        .then(|| {
            run_uniform(
                &MaterialFields::uniform(ne, DEFAULT_GAMMA_S, DEFAULT_GAMMA_V),
                "placeholder",
            )
        })
        .transpose()?;
        let nf = frames.num_frames();
        let mut floor = Vec::new();
        let mut floor_rms = Vec::with_capacity(nf);
        for k in 1..nf {
            let (x_hat, _) = fitter
                .fit(frames.frame(k))
                .map_err(|e| setup(&self.scene, format!("frame {k}: Y2V: {e}")))?;
            let d = yarn_distances(&asset, &x_hat, frames.frame(k));
            floor_rms.push(rms_max(&d).0);
            floor.extend(d);
        }
        let (mut all, mut all_u) = (Vec::new(), Vec::new());
        let mut per_frame = Vec::with_capacity(nf.saturating_sub(1));
        for k in 1..nf {
            let d = yarn_distances(&asset, &xs[k], frames.frame(k));
            let (rms, max) = rms_max(&d);
            all.extend(d);
            let uniform_rms = xu.as_ref().map(|xu| {
                let du = yarn_distances(&asset, &xu[k], frames.frame(k));
                let r = rms_max(&du).0;
                all_u.extend(du);
                r
            });
            per_frame.push(FrameError {
                frame: k,
                time: frames.times[k],
                rms,
                max,
                uniform_rms,
                y2v_floor_rms: floor_rms[k - 1],
                clamp_force_n: None,
                asset_clamp_force_n: None,
            });
        }
        let (rms, max) = rms_max(&all);
        let (urms, umax) = rms_max(&all_u);
        let (frms, fmax) = rms_max(&floor);
        let vh_rms_max = xv.as_ref().map(|xv| {
            let d: Vec<f64> = (1..nf)
                .flat_map(|k| yarn_distances(&asset, &xv[k], frames.frame(k)))
                .collect();
            rms_max(&d)
        });
        let placeholder_rms = placeholder.map(|p| {
            let d: Vec<f64> = (1..nf)
                .flat_map(|k| yarn_distances(&asset, &p.frames[k], frames.frame(k)))
                .collect();
            rms_max(&d).0
        });
        // Clamp forces of every homogenized run against the yarn level's.
        let node_group = super::clamp_drive::node_groups(&asset, &driver);
        let forces_of = |g: &MaterialFields, x: &[Vec<Vec3>]| {
            validate_forces::mesh_band_forces(&asset.mesh, g, &node_group, driver.num_groups(), x)
                .map_err(|e| setup(&self.scene, format!("clamp forces: {e}")))
        };
        let force_peak = yarn_forces.as_deref().and_then(validate_forces::peak);
        let (mut clamp_force, mut uniform_clamp_force, mut vh_clamp_force) = (None, None, None);
        if let (Some(yf), Some(at)) = (&yarn_forces, force_peak) {
            let fa = forces_of(&ga, xs)?;
            clamp_force = validate_forces::compare(yf, &fa, at);
            let (ya, ma) = (
                validate_forces::along_peak(yf, at),
                validate_forces::along_peak(&fa, at),
            );
            for e in per_frame.iter_mut() {
                e.clamp_force_n = ya.get(e.frame).copied();
                e.asset_clamp_force_n = ma.get(e.frame).copied();
            }
            if let (Some(g), Some(x)) = (&gu, &xu) {
                uniform_clamp_force = validate_forces::compare(yf, &forces_of(g, x)?, at);
            }
            if let (Some(g), Some(x)) = (&gv, &xv) {
                vh_clamp_force = validate_forces::compare(yf, &forces_of(g, x)?, at);
            }
        }
        // The motion of both levels, measured the same way on the yarns.
        let masses = crate::yarn::fabric::lumped_masses(rest, density);
        let radii: Vec<f64> = (0..rest.num_points()).map(|v| rest.radius_at(v)).collect();
        let motion_scene = MotionScene {
            masses: &masses,
            radii: &radii,
            gravity: scene.gravity,
            mass_damping: yarn_params.global_damping,
            colliders: &colliders,
        };
        let v2y = |x: &[Vec<Vec3>]| -> Vec<Vec<Vec3>> {
            x.iter()
                .map(|f| asset.embedding.v2y(&asset.mesh, f))
                .collect()
        };
        let motion_of = |y: &[Vec<Vec3>]| {
            let refs: Vec<&[Vec3]> = y.iter().map(|f| f.as_slice()).collect();
            validate_motion::measure(&motion_scene, &frames.times, &refs)
        };
        let yarn_refs: Vec<&[Vec3]> = (0..nf).map(|k| frames.frame(k)).collect();
        let yarn_motion = validate_motion::measure(&motion_scene, &frames.times, &yarn_refs);
        // The asset's run as yarns: for its motion and the report's PLY.
        let ys = v2y(xs);
        let homogenized_motion = motion_of(&ys);
        let uniform_motion = xu.as_deref().map(|x| motion_of(&v2y(x)));
        let motion = MotionReport {
            homogenized_match: validate_motion::compare(&yarn_motion, &homogenized_motion),
            uniform_match: uniform_motion
                .as_ref()
                .map(|u| validate_motion::compare(&yarn_motion, u)),
            yarn_level: yarn_motion,
            homogenized: homogenized_motion,
            uniform: uniform_motion,
        };
        let mut report = ValidateReport {
            frames: per_frame.len(),
            rms_yarn_diameters: rms,
            max_yarn_diameters: max,
            uniform_rms_yarn_diameters: xu.as_ref().map(|_| urms),
            uniform_max_yarn_diameters: xu.as_ref().map(|_| umax),
            vh_rms_yarn_diameters: vh_rms_max.map(|v| v.0),
            vh_max_yarn_diameters: vh_rms_max.map(|v| v.1),
            vh_asset: self.compare_vh.clone(),
            placeholder_rms_yarn_diameters: placeholder_rms,
            yarn_level_s,
            homogenized_s,
            speedup: yarn_level_s / homogenized_s.max(1e-9),
            nodes: asset.mesh.num_nodes(),
            tets: asset.mesh.num_tets(),
            yarn_vertices: rest.num_points(),
            held_nodes: xs.first().map_or(0, |_| {
                let mut h = vec![false; rest.num_points()];
                for &v in driver.pinned() {
                    h[v] = true;
                }
                held_nodes(&asset.mesh, &asset.embedding, &h).len()
            }),
            solver: self.homogenized.solver,
            solver_iterations: hr.iterations,
            solver_steps: hr.steps,
            pd_local_s: hr.local_s,
            pd_global_s: hr.global_s,
            pd_contact_cg_iterations: hr.contact_cg_iterations,
            pd_contact_refactors: hr.contact_refactors,
            pd_local_steps: hr.local_steps,
            pd_accelerations_rejected: hr.accelerations_rejected,
            pd_iteration_cap: pd_cap,
            pd_capped_steps: hr.capped_steps,
            pd_max_residual_n: hr.max_residual_n,
            pd_max_residual_over_weight: residual_over_weight,
            pd_tolerance: hr.tolerance,
            pd_convergence_max: hr.max_convergence,
            pd_backend: hr.backend,
            pd_global_solver: hr.global_solver,
            colliders: colliders.len(),
            pd_contact: match self.homogenized.solver {
                HomogenizedSolver::Pd => self.homogenized.contact.name(),
                HomogenizedSolver::Newton => "",
            },
            pd_stiffness_damping_s: match self.homogenized.solver {
                HomogenizedSolver::Pd => how.stiffness_damping.unwrap_or(0.0),
                HomogenizedSolver::Newton => 0.0,
            },
            pd_max_dt_s: match self.homogenized.solver {
                HomogenizedSolver::Pd => how.max_dt.unwrap_or(0.0),
                HomogenizedSolver::Newton => 0.0,
            },
            max_penetration_m: hr.max_penetration_m,
            max_contacts: hr.max_contacts,
            max_substeps: hr.substeps,
            mesh_mass_kg,
            yarn_mass_kg,
            y2v_floor_rms_yarn_diameters: frms,
            y2v_floor_max_yarn_diameters: fmax,
            clamp_force_n: force_peak.map(|p| crate::geom::vec3::norm(p.2)),
            clamp_force,
            uniform_clamp_force,
            vh_clamp_force,
            per_frame,
            motion,
            truth_file: self.truth.clone(),
            report_files: Vec::new(),
            damping_fit,
            verdict: String::new(),
        };
        report.verdict = verdict(&report);
        if let Some(dir) = &self.report {
            let fresh = self.truth.is_none().then_some(yarn_out.as_path());
            report.report_files = io::atomic::all_or_nothing(|| {
                write_report(dir, &asset, &frames, &ys, &report, fresh)
            })?;
        }
        Ok(report)
    }
}

/// Refuses a `--compare-vh` asset that is not the same body: the same tet
/// mesh (nodes to 1e-9 m) and the same rest yarns (to 1e-9 m).
fn same_body(a: &Asset, a_path: &Path, b: &Asset, b_path: &Path) -> Result<(), Error> {
    let close = |p: &[Vec3], q: &[Vec3]| {
        p.len() == q.len()
            && p.iter()
                .zip(q)
                .all(|(x, y)| crate::geom::dist(*x, *y) <= 1e-9)
    };
    let what = if a.mesh.tets != b.mesh.tets || !close(&a.mesh.nodes, &b.mesh.nodes) {
        Some("tet mesh")
    } else if a.rest_yarns.offsets != b.rest_yarns.offsets
        || !close(&a.rest_yarns.points, &b.rest_yarns.points)
    {
        Some("rest yarns")
    } else {
        None
    };
    match what {
        None => Ok(()),
        Some(w) => Err(crate::pipeline::asset::StageError::Invalid {
            path: b_path.to_path_buf(),
            message: format!(
                "--compare-vh: its {w} differs from {}'s: compare fits of the same embedded asset",
                a_path.display()
            ),
        }
        .into()),
    }
}

/// `validate.json`, `error.png`, `yarn_level.####.ply`, `homogenized.####.ply`,
/// and `yarn_level.h5` (the run's frames, for `--truth`) when the yarn level
/// ran here (`fresh`).
fn write_report(
    dir: &Path,
    asset: &Asset,
    frames: &YarnFrames,
    homogenized: &[Vec<Vec3>],
    r: &ValidateReport,
    fresh: Option<&Path>,
) -> Result<Vec<PathBuf>, Error> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    if let Some(src) = fresh {
        let h5 = dir.join("yarn_level.h5");
        io::atomic::write_with(&h5, |tmp| std::fs::copy(src, tmp).map(|_| ()))?;
        files.push(h5);
    }
    let json = dir.join("validate.json");
    let text = serde_json::to_vec_pretty(r).map_err(|e| Error::Internal(e.to_string()))?;
    io::atomic::write_bytes(&json, &text)?;
    files.push(json);
    let pts = |f: &dyn Fn(&FrameError) -> Option<f64>| -> Vec<[f64; 2]> {
        r.per_frame
            .iter()
            .filter_map(|e| f(e).map(|v| [e.frame as f64, v]))
            .collect()
    };
    let mut series = vec![
        plot::Series {
            label: "RMS, fitted".into(),
            points: pts(&|e| Some(e.rms)),
            color: plot::PALETTE[0],
        },
        plot::Series {
            label: "max, fitted".into(),
            points: pts(&|e| Some(e.max)),
            color: plot::PALETTE[1],
        },
    ];
    series.push(plot::Series {
        label: "RMS, Y2V floor".into(),
        points: pts(&|e| Some(e.y2v_floor_rms)),
        color: plot::PALETTE[3 % plot::PALETTE.len()],
    });
    if r.uniform_rms_yarn_diameters.is_some() {
        series.push(plot::Series {
            label: "RMS, uniform".into(),
            points: pts(&|e| e.uniform_rms),
            color: plot::PALETTE[2],
        });
    }
    let png = dir.join("error.png");
    let fig = plot::Figure {
        title: "homogenized vs yarn-level: V2Y distance per frame".into(),
        panels: vec![plot::Panel {
            x_label: "frame".into(),
            y_label: "distance (yarn diameters)".into(),
            series,
        }],
        size: (900, 500),
    };
    let bytes =
        plot::render_png(&fig).map_err(|e| Error::Internal(format!("{}: {e}", png.display())))?;
    io::atomic::write_bytes(&png, &bytes)?;
    files.push(png);
    let csv = dir.join("motion.csv");
    io::atomic::write_bytes(&csv, validate_motion::csv(&r.motion).as_bytes())?;
    files.push(csv);
    let png = dir.join("motion.png");
    let bytes = plot::render_png(&validate_motion::figure(&r.motion))
        .map_err(|e| Error::Internal(format!("{}: {e}", png.display())))?;
    io::atomic::write_bytes(&png, &bytes)?;
    files.push(png);
    let rest = &asset.rest_yarns;
    for name in ["yarn_level", "homogenized"] {
        let pattern = io::sequence::Pattern {
            dir: dir.to_path_buf(),
            prefix: format!("{name}."),
            width: 4,
            suffix: ".ply".into(),
        };
        let mut w = YarnFrameWriter::per_frame(pattern, rest, &WriteOptions::default());
        for k in 0..frames.num_frames() {
            let p = if name == "yarn_level" {
                frames.frame(k)
            } else {
                &homogenized[k]
            };
            w.push(k as i64, frames.times[k], p)?;
        }
        files.extend(w.finish()?);
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_verdict_says_better_the_same_or_worse_with_the_ratio() {
        let better = compare(0.5, 1.0, "the best uniform material");
        assert_eq!(
            better,
            "the best uniform material moves 1.000, so the asset's is 2.00x closer: better"
        );
        let worse = compare(1.0, 0.5, "the VH Eq. 7 reference");
        assert!(worse.ends_with("2.00x farther: worse"), "{worse}");
        for theirs in [0.96, 1.0, 1.04] {
            let same = compare(1.0, theirs, "u");
            assert!(same.ends_with("within 5%: the same"), "{same}");
        }
        assert!(!compare(0.0, 1.0, "u").contains("closer"));
    }

    /// The held-out scenes shipped for `validate` (examples/validate) have no
    /// `[swatch]` and parse once the asset's rest yarns are named.
    #[test]
    fn example_validate_scenes_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/validate");
        let mut scenes = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let text = std::fs::read_to_string(&path).unwrap();
                let (text, injected) = with_swatch(&text, &path, Path::new("rest.h5")).unwrap();
                assert!(injected, "{}: names its own swatch", path.display());
                YlsScene::parse(&text, &path).unwrap_or_else(|e| panic!("{e}"));
                scenes += 1;
            }
        }
        assert!(scenes >= 1, "no scene in {}", dir.display());
    }

    /// The Newton reference names what it leaves out of a scene, and says
    /// nothing when the scene has neither friction nor damping.
    #[test]
    fn newton_omissions_name_friction_and_damping() {
        use crate::yarn::sim::{PlaneCollider, SphereCollider};
        let plane = |mu: f64| -> Arc<dyn PointCollider> {
            Arc::new(PlaneCollider {
                point: [0.0; 3],
                normal: [0.0, 0.0, 1.0],
                friction: mu,
            })
        };
        let sphere: Arc<dyn PointCollider> = Arc::new(SphereCollider {
            center: [0.0; 3],
            radius: 0.04,
            velocity: [0.0; 3],
            friction: 0.5,
        });
        assert_eq!(newton_omissions(&[plane(0.0)], 0.0), None);
        assert_eq!(newton_omissions(&[], 0.0), None);
        let m = newton_omissions(&[plane(0.0), sphere], 0.0).unwrap();
        assert!(
            m.contains("friction (mu up to 0.5)") && !m.contains("damping"),
            "{m}"
        );
        let m = newton_omissions(&[plane(0.2)], 2.0).unwrap();
        assert!(
            m.contains("mu up to 0.2") && m.contains("damping (2 1/s)"),
            "{m}"
        );
    }
}
