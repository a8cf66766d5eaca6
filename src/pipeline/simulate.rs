//! The shot stage: simulate a homogenized asset under a scene (gravity,
//! scripted pins, planes, spheres, an animated character it is pinned to and
//! collides with) and write the node positions of every requested frame as
//! the asset's time series plus per-frame yarn curves (V2Y).
//!
//! Time: frame `f` is at shot time `(f - first) / fps` (s); each frame
//! interval is split into `ceil(interval / dt)` equal PD steps (so the step
//! used is at most the requested `dt`); an optional pre-roll runs before
//! the first frame while the character blends from its bind pose into the
//! first frame's pose (smoothstep), so the garment, placed against the bind
//! pose, is carried into the shot instead of jumping.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Small fixed-size loops over x, y, z read better indexed.
#![allow(clippy::needless_range_loop)]

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use super::sim_scene::{BackendChoice, ColliderSection, Scene, SceneError, SolverChoice};
use crate::anim::pins::BodyPins;
use crate::anim::Character;
use crate::geom::{Asset, NodeSteps, Vec3, YarnFrames};
use crate::io::{self, IoError, WriteOptions};
use crate::sim::collide::{Collider, ColliderSet, MeshCollider, MeshTopology, Shape};
use crate::sim::contact::NodeProjector;
use crate::sim::dd::DdParams;
use crate::sim::pd::{GlobalSolver, PdParams, PdSolver, StepStats};
use crate::sim::SimError;

/// Errors of the shot stage.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Inputs that do not fit together (the message names the key or option).
    #[error("{path}: {message}", path = path.display())]
    Invalid { path: PathBuf, message: String },
    /// A requested backend or solver this build cannot run.
    #[error("{0}")]
    Unavailable(String),
    /// The simulation diverged.
    #[error("{path}: {source} (shot time {time:.6} s, before frame {frame})", path = path.display())]
    Diverged {
        path: PathBuf,
        frame: i64,
        time: f64,
        #[source]
        source: SimError,
    },
}

impl SimulateError {
    /// How the caller should react (mapped to exit codes by the binary):
    /// everything but i/o is bad input (retrying the same inputs fails the
    /// same way).
    pub fn class(&self) -> io::ErrorClass {
        match self {
            SimulateError::Io(e) => e.class(),
            _ => io::ErrorClass::BadInput,
        }
    }
    /// The PD step that diverged (1-based), if that is what happened.
    pub fn diverged_step(&self) -> Option<u64> {
        match self {
            SimulateError::Diverged {
                source: SimError::Diverged { step, .. },
                ..
            } => Some(*step),
            _ => None,
        }
    }
}

/// Penetration tolerance (m) of the written frames: 1 mm, the default
/// collider thickness. Free tet nodes end every step outside the colliders
/// (the solver projects them), but the yarn vertices are interpolated inside
/// the tets (V2Y) and cut corners where the body is concave or curved within
/// a voxel; a shot whose tet nodes or yarn vertices sit deeper than this
/// gets a warning in its notes (the figures are in the report).
pub const PENETRATION_TOLERANCE_M: f64 = 1e-3;

/// Default pre-roll (s) of a scene with a character when the scene gives
/// none: 0.2 s (30 steps of 1/150 s) to blend from the bind pose.
pub const DEFAULT_CHARACTER_PREROLL: f64 = 0.2;

/// One PD time step with contacts: [`PdSolver::step_with_contacts`], whose
/// PD iterations carry the contacts as projection constraints with Coulomb
/// friction (VH §8.5; `sim::contact`, the coefficient is the collider
/// set's) and which moves every free node still not admissible at the end
/// onto its target. Returns the step's statistics and the largest such
/// final correction (m).
pub fn pd_step(
    solver: &mut PdSolver,
    x: &mut [Vec3],
    v: &mut [Vec3],
    pinned_positions: &[Vec3],
    contacts: &dyn NodeProjector,
) -> Result<(StepStats, f64), SimError> {
    let stats = solver.step_with_contacts(x, v, pinned_positions, contacts)?;
    let correction = stats.max_projection;
    Ok((stats, correction))
}

/// The global solver of a [`SolverChoice`] (its default parameters).
pub fn global_solver(solver: SolverChoice) -> GlobalSolver {
    match solver {
        SolverChoice::Direct => GlobalSolver::Direct,
        SolverChoice::Dd => GlobalSolver::DomainDecomposed(DdParams::default()),
    }
}

/// Puts the solver on the chosen backend and returns its name ("cpu",
/// "gpu"). `Auto` takes a hardware GPU when wgpu finds one and stays on
/// the CPU otherwise (a software adapter such as lavapipe is slower than
/// the f64 CPU path); `Gpu` takes any adapter, lavapipe included, and is an
/// error without one. Call again after `refactor` / `set_time_step`, which
/// return the solver to the CPU.
pub fn attach_backend(
    solver: &mut PdSolver,
    backend: BackendChoice,
) -> Result<&'static str, SimulateError> {
    use crate::sim::gpu::{GpuContext, GpuElasticRhs, GpuError, GpuJacobi, GpuJacobiParams};
    if backend == BackendChoice::Cpu {
        return Ok("cpu");
    }
    let ctx = match GpuContext::new() {
        Ok(c) => c,
        Err(GpuError::Unavailable(why)) if backend == BackendChoice::Auto => {
            let _ = why;
            return Ok("cpu");
        }
        Err(e) => {
            return Err(SimulateError::Unavailable(format!(
                "--backend gpu: no usable GPU: {e}"
            )))
        }
    };
    if backend == BackendChoice::Auto && ctx.is_cpu_adapter() {
        return Ok("cpu");
    }
    let gpu_err = |e: GpuError| SimulateError::Unavailable(format!("GPU backend: {e}"));
    let elastic = GpuElasticRhs::new(&ctx, solver.model()).map_err(gpu_err)?;
    // Only the domain-decomposed solver iterates in full space.
    let jacobi: Option<Box<dyn crate::sim::backend::JacobiSolve>> = match solver.params().global {
        GlobalSolver::DomainDecomposed(_) => Some(Box::new(
            GpuJacobi::new(&ctx, solver.free_matrix(), GpuJacobiParams::default())
                .map_err(gpu_err)?,
        )),
        GlobalSolver::Direct => None,
    };
    solver.set_backend(Box::new(elastic), jacobi);
    Ok("gpu")
}

/// Checks that the backend and solver choices can run (without starting a
/// GPU): kept for the preflight of a shot; the names come from
/// [`attach_backend`] and [`GlobalSolver::name`].
pub fn resolve_backend(
    _backend: BackendChoice,
    solver: SolverChoice,
) -> Result<(&'static str, &'static str), SimulateError> {
    Ok(("cpu", global_solver(solver).name()))
}

/// A scripted pin group resolved to nodes.
#[derive(Debug, Clone)]
struct Handle {
    nodes: Vec<usize>,
    rest: Vec<Vec3>,
    pivot: Vec3,
    velocity: Vec3,
    omega: Vec3,
    start: f64,
    end: f64,
}

impl Handle {
    fn positions(&self, t: f64, out: &mut Vec<Vec3>) {
        let tau = if t <= self.start {
            0.0
        } else {
            t.min(self.end) - self.start
        };
        let w = Vector3::from(self.omega) * tau;
        let r = Rotation3::new(w);
        for p in &self.rest {
            let d = Vector3::new(
                p[0] - self.pivot[0],
                p[1] - self.pivot[1],
                p[2] - self.pivot[2],
            );
            let q = r * d;
            out.push(std::array::from_fn(|k| {
                self.pivot[k] + q[k] + self.velocity[k] * tau
            }));
        }
    }
}

/// The character of a shot: skin, animation, placement, topology.
struct Body {
    character: Character,
    anim: Option<usize>,
    duration: f64,
    scale: f64,
    translate: Vec3,
    looped: bool,
    time_offset: f64,
    topology: MeshTopology,
    bind: Vec<Vec3>,
    first_pose: Vec<Vec3>,
    preroll: f64,
    thickness: f64,
    collide: bool,
}

impl Body {
    fn place(&self, p: Vec<Vec3>) -> Vec<Vec3> {
        p.into_iter()
            .map(|q| std::array::from_fn(|k| q[k] * self.scale + self.translate[k]))
            .collect()
    }
    fn anim_time(&self, t: f64) -> f64 {
        let a = self.time_offset + t;
        if self.looped && self.duration > 0.0 {
            a.rem_euclid(self.duration)
        } else {
            a
        }
    }
    /// Body vertices (m) at shot time `t` (negative: pre-roll blend).
    fn positions(&self, t: f64) -> Vec<Vec3> {
        if t < 0.0 {
            let s = if self.preroll > 0.0 {
                ((t + self.preroll) / self.preroll).clamp(0.0, 1.0)
            } else {
                1.0
            };
            let s = s * s * (3.0 - 2.0 * s);
            return self
                .bind
                .iter()
                .zip(&self.first_pose)
                .map(|(a, b)| std::array::from_fn(|k| a[k] + s * (b[k] - a[k])))
                .collect();
        }
        self.place(
            self.character
                .skinned_positions(self.anim, self.anim_time(t)),
        )
    }
}

/// Colliders posed at one time, the body's vertices then, and the body
/// alone as a collider.
type Posed = (ColliderSet, Option<Vec<Vec3>>, Option<ColliderSet>);

/// What a shot did.
#[derive(Debug, Clone, Serialize)]
pub struct SimulateReport {
    pub asset: PathBuf,
    pub output: PathBuf,
    pub yarn_files: Vec<PathBuf>,
    pub frames: usize,
    pub first_frame: i64,
    pub last_frame: i64,
    pub fps: f64,
    /// Step actually used (s): the frame interval over `steps_per_frame`.
    pub dt: f64,
    pub steps_per_frame: usize,
    pub preroll_steps: usize,
    pub steps: usize,
    pub nodes: usize,
    pub tets: usize,
    pub pinned_scripted: usize,
    pub pinned_body: usize,
    pub solver: String,
    /// Domains of the domain-decomposed solver (None for "direct").
    pub dd_domains: Option<usize>,
    /// Where they come from: "asset" (its `CellData/domain`, when it names
    /// two or more domains) or "bisection" (recursive coordinate bisection).
    pub dd_partition: Option<&'static str>,
    pub backend: String,
    pub ms_per_step_median: f64,
    pub ms_total: f64,
    pub pd_iterations_mean: f64,
    pub pd_iterations_max: u32,
    /// Largest implicit-Euler residual over the steps (N).
    pub residual_max: f64,
    /// Largest penetration depth (m) of a free node into any collider over
    /// the output frames.
    pub max_penetration_m: f64,
    /// Largest penetration depth (m) of a free node into the character's
    /// body over the output frames (None without a colliding character).
    pub max_penetration_body_m: Option<f64>,
    /// Smallest signed distance (m) of a free node to a collider over the
    /// output frames (None without colliders).
    pub min_distance_m: Option<f64>,
    /// Largest penetration depth (m) of a yarn vertex (V2Y of the nodes,
    /// pinned or free) into any collider over the output frames (None
    /// without colliders).
    pub max_penetration_yarns_m: Option<f64>,
    /// The tolerance (m) the tet-node and yarn-vertex penetrations are held
    /// to ([`PENETRATION_TOLERANCE_M`]; beyond it: a warning in `notes`).
    pub penetration_tolerance_m: f64,
    /// Largest penetration depth (m) of a pinned node into the body over
    /// the output frames (pins ride on the skin, so they can dip in where
    /// the skin folds).
    pub max_penetration_pinned_m: Option<f64>,
    /// Largest contact correction of a step (m): how far the end-of-step
    /// projection moved a free node still inside a collider's thickness band
    /// after the PD iterations onto its contact target.
    pub max_contact_correction_m: f64,
    pub character: Option<CharacterReport>,
    pub notes: Vec<String>,
}

/// The character of a shot.
#[derive(Debug, Clone, Serialize)]
pub struct CharacterReport {
    pub file: PathBuf,
    pub animation: Option<String>,
    pub duration_s: f64,
    pub vertices: usize,
    pub triangles: usize,
    pub closed: bool,
    pub scale: f64,
    pub preroll_s: f64,
}

/// Inputs of a shot besides the scene.
#[derive(Debug, Clone)]
pub struct ShotRequest {
    /// Frame numbers to write (any order; sorted and de-duplicated).
    pub frames: Vec<i64>,
    /// Output asset (.vtkhdf).
    pub output: PathBuf,
    /// Yarn curves per frame: `name.####.ext` sequence or one `.h5` file.
    pub yarns_out: Option<PathBuf>,
    /// Units and axis of written yarn files.
    pub write: WriteOptions,
    /// The command line, for provenance.
    pub command: String,
}

fn invalid(path: &Path, message: impl Into<String>) -> SimulateError {
    SimulateError::Invalid {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Checks an output can be written before the (long) simulation: the asset's
/// folder exists; for yarns, the format is writable and holds frames (the
/// folder is created).
fn preflight(req: &ShotRequest) -> Result<(), SimulateError> {
    let folder_ok = |p: &Path| {
        let parent = p.parent().filter(|d| !d.as_os_str().is_empty());
        match parent {
            Some(d) if !d.is_dir() => Err(IoError::Write {
                path: p.to_path_buf(),
                source: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!("output folder {} does not exist", d.display()),
                ),
            }),
            _ => Ok(()),
        }
    };
    folder_ok(&req.output)?;
    if let Some(y) = &req.yarns_out {
        let format = io::format_of(y)?;
        if !format.is_writable() {
            return Err(invalid(y, format!("knitvox does not write {format}")));
        }
        if !format.holds_frames() && !io::sequence::is_pattern(y) {
            return Err(invalid(
                y,
                "--yarns-out needs a frame sequence name.####.ext or an .h5 file",
            ));
        }
        // The yarn frames usually get a folder of their own: make it.
        if let Some(d) = y.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d).map_err(|source| IoError::Write {
                path: d.to_path_buf(),
                source,
            })?;
        }
    }
    Ok(())
}

/// Refuses (exit 2) an output that would replace the asset or the
/// character the scene names (the command line's own files are checked by
/// the CLI; the scene's are known only here).
fn refuse_input_overwrite(
    asset_path: &Path,
    scene: &Scene,
    req: &ShotRequest,
) -> Result<(), SimulateError> {
    let character = scene.character_path();
    let mut inputs = vec![asset_path];
    inputs.extend(character.as_deref());
    let mut outputs = vec![req.output.as_path()];
    outputs.extend(req.yarns_out.as_deref());
    Ok(io::overwrite::refuse_inputs(&outputs, &inputs)?)
}

/// Rotation (degrees about x, then y, then z).
fn euler_deg(r: Vec3) -> Rotation3<f64> {
    let [a, b, c] = r.map(f64::to_radians);
    Rotation3::from_axis_angle(&Vector3::z_axis(), c)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), b)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), a)
}

fn bbox(x: &[Vec3]) -> (Vec3, Vec3) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Height (m) of the highest point of the mesh on the vertical line
/// through `(x, z)`, if the line meets it.
fn surface_height(topology: &MeshTopology, pos: &[Vec3], x: f64, z: f64) -> Option<f64> {
    let mut best: Option<f64> = None;
    for t in topology.triangles() {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        // Barycentric coordinates of (x, z) in the triangle's x-z projection.
        let det = (b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2]);
        if !(det.abs() > 0.0) {
            continue;
        }
        let u = ((x - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (z - a[2])) / det;
        let v = ((b[0] - a[0]) * (z - a[2]) - (x - a[0]) * (b[2] - a[2])) / det;
        if u < 0.0 || v < 0.0 || u + v > 1.0 {
            continue;
        }
        let y = a[1] + u * (b[1] - a[1]) + v * (c[1] - a[1]);
        best = Some(best.map_or(y, |m: f64| m.max(y)));
    }
    best
}

/// Most PD steps one shot may take (pre-roll included): hours of work at
/// the fastest step; larger requests are refused before any work starts.
pub const MAX_TOTAL_STEPS: usize = 10_000_000;

/// Simulates `asset` (read from `asset_path`) under `scene` and writes the
/// outputs of `req`. `progress(done, total)` is called after every frame.
pub fn simulate(
    asset: &Asset,
    asset_path: &Path,
    scene: &Scene,
    req: &ShotRequest,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SimulateReport, SimulateError> {
    let t_total = Instant::now();
    preflight(req)?;
    refuse_input_overwrite(asset_path, scene, req)?;
    let (_, solver_name) = resolve_backend(scene.simulation.backend, scene.simulation.solver)?;
    let mut frames = req.frames.clone();
    frames.sort_unstable();
    frames.dedup();
    let (Some(&first), Some(&last)) = (frames.first(), frames.last()) else {
        return Err(invalid(asset_path, "--frames selects no frame"));
    };
    let sim = &scene.simulation;
    let n = asset.mesh.num_nodes();
    let mut notes = Vec::new();

    // Garment placement: rotation about the bbox centre, then translation.
    let (lo, hi) = bbox(&asset.mesh.nodes);
    let centre: Vec3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let rot = euler_deg(scene.garment.rotate_deg);
    let target = scene.garment.center.unwrap_or(centre);
    let mut x: Vec<Vec3> = asset
        .mesh
        .nodes
        .iter()
        .map(|p| {
            let d = rot * Vector3::new(p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]);
            std::array::from_fn(|k| target[k] + d[k])
        })
        .collect();

    // Character.
    let frame_dt = 1.0 / sim.fps;
    let spf = ((frame_dt / sim.dt.0) * (1.0 - 1e-12)).ceil().max(1.0);
    // Bounded before any work (issue 13 item 3): dt, fps and the frame range
    // are user input; the pre-roll is added once the character is known.
    let frame_steps = spf * (last - first) as f64;
    if !(frame_steps <= MAX_TOTAL_STEPS as f64) {
        return Err(invalid(
            asset_path,
            format!(
                "frames {first}-{last} at {} fps with dt {} s need {frame_steps:.0} steps, more than the limit of {MAX_TOTAL_STEPS}",
                sim.fps, sim.dt.0
            ),
        ));
    }
    let steps_per_frame = spf as usize;
    let dt = frame_dt / steps_per_frame as f64;
    let mut body: Option<Body> = None;
    let mut char_report = None;
    if let (Some(c), Some(path)) = (&scene.character, scene.character_path()) {
        let character = io::gltf_skin::read_character(&path)?;
        let anim = match &c.animation {
            Some(name) => Some(character.animation_index(name).ok_or_else(|| {
                invalid(
                    &path,
                    format!(
                        "character.animation: no animation '{}' (the file has: {})",
                        crate::geom::excerpt(name),
                        crate::geom::excerpt(&character.animation_names().join(", "))
                    ),
                )
            })?),
            None => (!character.animations.is_empty()).then_some(0),
        };
        let duration = anim.map_or(0.0, |a| character.duration(a));
        let rest = character.body_mesh(None, 0.0);
        if rest.triangles.is_empty() {
            return Err(invalid(&path, "the character has no triangles"));
        }
        let (topology, dropped) = MeshTopology::welded(&rest.triangles, &rest.positions);
        if dropped > 0 {
            notes.push(format!(
                "character: {dropped} degenerate or out-of-range triangles ignored"
            ));
        }
        let preroll = sim.preroll.unwrap_or(DEFAULT_CHARACTER_PREROLL);
        let mut b = Body {
            character,
            anim,
            duration,
            scale: c.scale,
            translate: c.translate,
            looped: c.r#loop,
            time_offset: c.time_offset,
            topology,
            bind: Vec::new(),
            first_pose: Vec::new(),
            preroll,
            thickness: c.thickness,
            collide: c.collide,
        };
        b.bind = b.place(rest.positions);
        b.first_pose = b.place(b.character.skinned_positions(b.anim, b.anim_time(0.0)));
        if let Some(joint) = &c.fit_joint {
            let j = b
                .character
                .skeleton
                .iter()
                .position(|nd| nd.name.as_deref() == Some(joint.as_str()))
                .ok_or_else(|| {
                    invalid(
                        &path,
                        format!(
                            "character.fit_joint: no node named '{}'",
                            crate::geom::excerpt(joint)
                        ),
                    )
                })?;
            let w = b.character.node_world_matrices(None, 0.0)[j];
            let jp: Vec3 = std::array::from_fn(|k| w[(k, 3)] * b.scale + b.translate[k]);
            let (glo, ghi) = bbox(&x);
            // Centre over the joint, then lift so that the lowest clearance
            // between a garment node and the body surface straight below it
            // is `fit_gap`.
            let dx = [
                jp[0] - 0.5 * (glo[0] + ghi[0]),
                jp[2] - 0.5 * (glo[2] + ghi[2]),
            ];
            let lift = x
                .iter()
                .filter_map(|p| {
                    surface_height(&b.topology, &b.bind, p[0] + dx[0], p[2] + dx[1])
                        .map(|h| h - p[1])
                })
                .fold(f64::NEG_INFINITY, f64::max);
            if !lift.is_finite() {
                return Err(invalid(
                    &path,
                    format!(
                        "character.fit_joint: the body has no surface under the garment at joint '{}'",
                        crate::geom::excerpt(joint)
                    ),
                ));
            }
            let shift = [dx[0], lift + c.fit_gap, dx[1]];
            for p in &mut x {
                for k in 0..3 {
                    p[k] += shift[k];
                }
            }
        }
        char_report = Some(CharacterReport {
            file: path.clone(),
            animation: anim.map(|a| b.character.animation_names()[a].clone()),
            duration_s: duration,
            vertices: b.bind.len(),
            triangles: b.topology.triangles().len(),
            closed: b.topology.is_closed(),
            scale: c.scale,
            preroll_s: preroll,
        });
        body = Some(b);
    }
    for p in &mut x {
        for k in 0..3 {
            p[k] += scene.garment.translate[k];
        }
    }

    // Scripted pins.
    let mut is_pinned = vec![false; n];
    let mut handles = Vec::new();
    for (i, ps) in scene.pin.iter().enumerate() {
        let mut nodes = Vec::new();
        for &nd in &ps.nodes {
            if nd >= n {
                return Err(invalid(
                    asset_path,
                    format!("pin[{i}].nodes: node {nd} does not exist (the mesh has {n} nodes)"),
                ));
            }
            nodes.push(nd);
        }
        if let (Some(a), Some(b)) = (ps.box_min, ps.box_max) {
            nodes.extend((0..n).filter(|&j| (0..3).all(|k| x[j][k] >= a[k] && x[j][k] <= b[k])));
        }
        nodes.sort_unstable();
        nodes.dedup();
        nodes.retain(|&j| !std::mem::replace(&mut is_pinned[j], true));
        if nodes.is_empty() {
            notes.push(format!("pin[{i}] ({}) selects no free node", ps.name));
            continue;
        }
        let rest: Vec<Vec3> = nodes.iter().map(|&j| x[j]).collect();
        let pivot = ps.pivot.unwrap_or_else(|| {
            let s = rest
                .iter()
                .fold([0.0; 3], |a, p| std::array::from_fn(|k| a[k] + p[k]));
            s.map(|c| c / rest.len() as f64)
        });
        handles.push(Handle {
            nodes,
            rest,
            pivot,
            velocity: ps.velocity,
            omega: ps.angular_velocity_deg.map(f64::to_radians),
            start: ps.start,
            end: ps.end.unwrap_or(f64::INFINITY),
        });
    }

    // Body pins at the bind pose.
    let mut body_pins = BodyPins::default();
    if let (Some(b), Some(c)) = (&body, &scene.character) {
        if c.pins {
            let bind = MeshCollider::new(&b.topology, &b.bind)
                .map_err(|m| invalid(&scene.character_path().unwrap_or_default(), m))?;
            let all = BodyPins::select(&b.topology, &bind, &x, c.pin_distance);
            for (k, &nd) in all.nodes.iter().enumerate() {
                if !is_pinned[nd] {
                    is_pinned[nd] = true;
                    body_pins.nodes.push(nd);
                    body_pins.attachments.push(all.attachments[k]);
                    body_pins.distances.push(all.distances[k]);
                }
            }
            if body_pins.nodes.is_empty() {
                return Err(invalid(
                    &scene.character_path().unwrap_or_default(),
                    format!(
                        "character.pin_distance: no garment node lies within {} m of the bind-pose body; \
                         place the garment on the body (character.fit_joint / --fit-joint, garment.translate / \
                         --garment-offset, character.scale / --character-scale) or raise the pin distance",
                        c.pin_distance
                    ),
                ));
            }
        }
    }
    let pinned: Vec<usize> = handles
        .iter()
        .flat_map(|h| h.nodes.iter().copied())
        .chain(body_pins.nodes.iter().copied())
        .collect();

    let params = PdParams {
        dt,
        gravity: sim.gravity,
        mass_damping: sim.damping,
        max_iterations: sim.max_iterations,
        anderson_window: sim.anderson_window,
        tolerance: sim.tolerance,
        global: global_solver(sim.solver),
        ..PdParams::default()
    };
    let stored = stored_domains(&asset.domain);
    let mut solver = PdSolver::new_partitioned(
        &asset.mesh,
        &asset.node_mass,
        &asset.gamma_s,
        &asset.gamma_v,
        &pinned,
        params,
        stored.as_deref(),
    )
    .map_err(|e| invalid(asset_path, e.to_string()))?;
    let backend = attach_backend(&mut solver, sim.backend)?;
    let dd_domains = solver.dd_stats().map(|d| d.domains);
    let dd_partition = dd_domains.map(|_| {
        if stored.is_some() {
            "asset"
        } else {
            "bisection"
        }
    });

    // Static colliders.
    let mut statics = Vec::new();
    for c in &scene.collider {
        statics.push(match c {
            ColliderSection::Plane {
                point,
                normal,
                thickness,
            } => Collider {
                shape: Shape::Plane {
                    point: *point,
                    normal: *normal,
                },
                thickness: *thickness,
            },
            ColliderSection::Sphere {
                center,
                radius,
                thickness,
            } => Collider {
                shape: Shape::Sphere {
                    center: *center,
                    radius: *radius,
                },
                thickness: *thickness,
            },
        });
    }

    let preroll_steps = body
        .as_ref()
        .map_or(0, |b| (b.preroll / dt).ceil() as usize);
    let total_steps = preroll_steps
        .checked_add((last - first) as usize * steps_per_frame)
        .filter(|&t| t <= MAX_TOTAL_STEPS)
        .ok_or_else(|| {
            invalid(
                asset_path,
                format!(
                    "a pre-roll of {preroll_steps} steps plus {} frame steps is more than the limit of {MAX_TOTAL_STEPS} steps",
                    (last - first) as usize * steps_per_frame
                ),
            )
        })?;
    let mut v = vec![[0.0; 3]; n];
    let mut recorded: Vec<(i64, Vec<Vec3>)> = Vec::with_capacity(frames.len());
    let mut max_pen = 0.0f64;
    let mut max_pen_body: Option<f64> = None;
    let mut max_pen_yarns: Option<f64> = None;
    let mut min_dist: Option<f64> = None;
    let mut step_ms = Vec::with_capacity(total_steps);
    let mut iters_sum = 0u64;
    let mut iters_max = 0u32;
    let mut residual_max = 0.0f64;
    let mut correction_max = 0.0f64;
    let mut pen_pinned: Option<f64> = None;
    let mut next_frame = 0usize;
    let mut pin_pos = Vec::with_capacity(pinned.len());

    // Colliders (and the body alone) posed at shot time t; `previous`: the
    // body's vertices at the start of the step, for friction against its
    // motion.
    let pose = |t: f64, previous: Option<&[Vec3]>| -> Result<Posed, SimulateError> {
        let mut set = ColliderSet {
            colliders: statics.clone(),
            friction: sim.friction,
        };
        let mut body_set = None;
        let mut verts = None;
        if let Some(b) = &body {
            let pts = b.positions(t);
            if b.collide {
                let bad = |m| invalid(&scene.character_path().unwrap_or_default(), m);
                let mut m = MeshCollider::new(&b.topology, &pts).map_err(bad)?;
                if let Some(prev) = previous {
                    m = m.with_previous(prev).map_err(bad)?;
                }
                let c = Collider {
                    shape: Shape::Mesh(Box::new(m)),
                    thickness: b.thickness,
                };
                set.colliders.push(c.clone());
                body_set = Some(ColliderSet {
                    colliders: vec![c],
                    ..ColliderSet::default()
                });
            }
            verts = Some(pts);
        }
        Ok((set, verts, body_set))
    };

    let mut measure = |x: &[Vec3], set: &ColliderSet, body_set: &Option<ColliderSet>| {
        if !set.colliders.is_empty() {
            let yarns = asset.embedding.v2y(&asset.mesh, x);
            let pen = set.max_penetration(&yarns);
            max_pen_yarns = Some(max_pen_yarns.map_or(pen, |m| m.max(pen)));
        }
        for (i, p) in x.iter().enumerate() {
            if is_pinned[i] {
                if let Some(bs) = body_set {
                    let pen = bs.penetration(*p);
                    pen_pinned = Some(pen_pinned.map_or(pen, |m| m.max(pen)));
                }
                continue;
            }
            if let Some((_, d)) = set.min_signed_distance(*p) {
                min_dist = Some(min_dist.map_or(d, |m| m.min(d)));
                max_pen = max_pen.max(-d);
            }
            if let Some(bs) = body_set {
                let pen = bs.penetration(*p);
                max_pen_body = Some(max_pen_body.map_or(pen, |m| m.max(pen)));
            }
        }
    };

    let t0 = -(preroll_steps as f64) * dt;
    // Initial state: project the free nodes out of the colliders at t0.
    {
        let (set, _, _) = pose(t0, None)?;
        for (i, p) in x.iter_mut().enumerate() {
            if !is_pinned[i] {
                if let Some(q) = set.project(i, *p) {
                    *p = q;
                }
            }
        }
    }
    let record = |s: usize| -> Option<i64> {
        // Step count `s` since t0 reaches frame first + k when
        // s == preroll_steps + k * steps_per_frame.
        let k = s.checked_sub(preroll_steps)?;
        (k % steps_per_frame == 0).then(|| first + (k / steps_per_frame) as i64)
    };
    if record(0) == Some(first) {
        let (set, _, body_set) = pose(0.0, None)?;
        measure(&x, &set, &body_set);
        recorded.push((first, x.clone()));
        next_frame = 1;
        progress(1, frames.len());
    }
    let mut body_before = body.as_ref().map(|b| b.positions(t0));
    for s in 1..=total_steps {
        let t = t0 + s as f64 * dt;
        let (set, verts, body_set) = pose(t, body_before.as_deref())?;
        pin_pos.clear();
        for h in &handles {
            h.positions(t, &mut pin_pos);
        }
        if !body_pins.nodes.is_empty() {
            let (Some(b), Some(verts)) = (&body, &verts) else {
                unreachable!("body pins come from a body")
            };
            pin_pos.extend(
                body_pins
                    .positions(&b.topology, verts)
                    .ok_or_else(|| invalid(asset_path, "body pin lost its triangle"))?,
            );
        }
        let frame_of_step =
            first + ((s.saturating_sub(preroll_steps)).div_ceil(steps_per_frame)) as i64;
        let (st, correction) =
            pd_step(&mut solver, &mut x, &mut v, &pin_pos, &set).map_err(|source| {
                SimulateError::Diverged {
                    path: asset_path.to_path_buf(),
                    frame: frame_of_step,
                    time: t,
                    source,
                }
            })?;
        step_ms.push(st.ms);
        iters_sum += st.iterations as u64;
        iters_max = iters_max.max(st.iterations);
        residual_max = residual_max.max(st.residual);
        correction_max = correction_max.max(correction);
        if let Some(f) = record(s) {
            if frames.get(next_frame) == Some(&f) {
                measure(&x, &set, &body_set);
                recorded.push((f, x.clone()));
                next_frame += 1;
                progress(next_frame, frames.len());
            }
        }
        body_before = verts;
    }

    // Outputs: the asset's time series and the yarn frames.
    let mut out = asset.clone();
    let mut steps = NodeSteps::default();
    for (f, pos) in &recorded {
        steps.times.push(*f as f64 / sim.fps);
        steps.positions.extend_from_slice(pos);
    }
    out.steps = steps;
    let ms_per_step_median = median(step_ms.clone());
    let pinned_body = body_pins.nodes.len();
    let pinned_scripted = pinned.len() - pinned_body;
    for (what, pen) in [
        ("tet nodes", Some(max_pen)),
        ("yarn vertices", max_pen_yarns),
    ] {
        if let Some(p) = pen.filter(|&p| p > PENETRATION_TOLERANCE_M) {
            notes.push(format!(
                "warning: {what} sit up to {p:.3e} m inside a collider, more than the tolerance of \
                 {PENETRATION_TOLERANCE_M} m (raise the collider thickness, use smaller voxels or check the pins)"
            ));
        }
    }
    let mut report = SimulateReport {
        asset: asset_path.to_path_buf(),
        output: req.output.clone(),
        yarn_files: Vec::new(),
        frames: recorded.len(),
        first_frame: first,
        last_frame: last,
        fps: sim.fps,
        dt,
        steps_per_frame,
        preroll_steps,
        steps: total_steps,
        nodes: n,
        tets: asset.mesh.num_tets(),
        pinned_scripted,
        pinned_body,
        solver: solver_name.into(),
        dd_domains,
        dd_partition,
        backend: backend.into(),
        ms_per_step_median,
        ms_total: 0.0,
        pd_iterations_mean: iters_sum as f64 / total_steps.max(1) as f64,
        pd_iterations_max: iters_max,
        residual_max,
        max_penetration_m: max_pen.max(0.0),
        max_penetration_body_m: max_pen_body,
        max_penetration_yarns_m: max_pen_yarns,
        penetration_tolerance_m: PENETRATION_TOLERANCE_M,
        min_distance_m: min_dist,
        max_penetration_pinned_m: pen_pinned,
        max_contact_correction_m: correction_max,
        character: char_report,
        notes,
    };
    if let serde_json::Value::Object(m) = &mut out.parameters {
        m.insert(
            "simulate".into(),
            serde_json::json!({
                "scene": scene,
                "frames": [first, last],
                "dt": dt,
                "steps_per_frame": steps_per_frame,
                "preroll_steps": preroll_steps,
                "solver": solver_name,
                "backend": backend,
            }),
        );
    }
    out.provenance.command = format!("{} && {}", out.provenance.command, req.command);
    if let Some(p) = scene.character_path() {
        out.provenance.inputs.push(crate::geom::InputFile {
            path: p.display().to_string(),
            sha256: super::asset::sha256_file(&p)?,
        });
    }
    // All or nothing (issue 13 item 4): the yarn frames and the asset stay
    // temporary files until every one is written, then all get their names.
    report.yarn_files = io::atomic::all_or_nothing(|| {
        let files = match &req.yarns_out {
            Some(y) => write_yarns(&out, &recorded, y, &req.write)?,
            None => Vec::new(),
        };
        io::vtkhdf::write_asset(&req.output, &out)?;
        Ok::<_, SimulateError>(files)
    })?;
    report.ms_total = t_total.elapsed().as_secs_f64() * 1e3;
    Ok(report)
}

/// V2Y of every recorded frame, written as `name.####.ext` (numbered by
/// frame) or into one HDF5 file.
fn write_yarns(
    asset: &Asset,
    recorded: &[(i64, Vec<Vec3>)],
    path: &Path,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, SimulateError> {
    let np = asset.rest_yarns.num_points();
    let fps_times = &asset.steps.times;
    let format = io::format_of(path)?;
    if format.holds_frames() {
        let mut frames = YarnFrames::new(np);
        for (k, (_, pos)) in recorded.iter().enumerate() {
            let pts = asset.embedding.v2y(&asset.mesh, pos);
            frames
                .push_frame(fps_times[k], &pts)
                .map_err(|e| invalid(path, e.to_string()))?;
        }
        return Ok(io::write_path(
            path,
            &asset.rest_yarns,
            Some(&frames),
            opts,
        )?);
    }
    let mut written = Vec::with_capacity(recorded.len());
    for (k, (f, pos)) in recorded.iter().enumerate() {
        let pts = asset.embedding.v2y(&asset.mesh, pos);
        let mut one = YarnFrames::new(np);
        one.push_frame(fps_times[k], &pts)
            .map_err(|e| invalid(path, e.to_string()))?;
        let o = WriteOptions {
            first_frame: *f,
            ..opts.clone()
        };
        // No partial sequence: the caller stages every file (all_or_nothing).
        written.extend(io::write_path(path, &asset.rest_yarns, Some(&one), &o)?);
    }
    Ok(written)
}

/// The asset's per-tet domain ids as the domain-decomposed solver's
/// partition when they name two or more domains (equal ids form a domain;
/// the bit pattern keeps distinct i32 ids distinct). A single id, which is
/// what `embed` writes, leaves the partition to the solver's bisection.
fn stored_domains(domain: &[i32]) -> Option<Vec<u32>> {
    let first = *domain.first()?;
    domain
        .iter()
        .any(|&d| d != first)
        .then(|| domain.iter().map(|&d| d as u32).collect())
}

/// Median (NaN for none).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Reads and parses a scene file.
pub fn read_scene(path: &Path) -> Result<Scene, SimulateError> {
    let text = std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(Scene::parse(&text, path)?)
}
