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

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::Serialize;

use super::frames::{FrameSink, YarnFrameWriter};
use super::shot_error::invalid;
pub use super::shot_error::SimulateError;
use super::shot_setup::{self, Posed};
pub use super::shot_setup::{CharacterReport, DEFAULT_CHARACTER_PREROLL, MAX_TOTAL_STEPS};
use super::sim_scene::{BackendChoice, Scene, SimulationSection, SolverChoice};
use super::util::median;
use crate::geom::{Asset, NodeSteps, Vec3};
use crate::io::checkpoint::{self, Checkpoint, CheckpointHeader};
use crate::io::{self, IoError, WriteOptions};
use crate::pipeline::{Error, ErrorClass, FrameProgress, Observer, Stage};
use crate::sim::dd::DdParams;
use crate::sim::pd::{GlobalSolver, PdParams, PdSolver};
use crate::sim::shot::{self, LoopError};

/// Penetration tolerance (m) of the written frames: 1 mm, the default
/// collider thickness. Free tet nodes end every step outside the colliders
/// (the solver projects them), but the yarn vertices are interpolated inside
/// the tets (V2Y) and cut corners where the body is concave or curved within
/// a voxel; a shot whose tet nodes or yarn vertices sit deeper than this
/// gets a warning in its notes (the figures are in the report).
pub const PENETRATION_TOLERANCE_M: f64 = 1e-3;

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
    // `auto` runs on the CPU unless a hardware adapter is present (probed
    // once per process, no device created).
    if backend == BackendChoice::Cpu
        || (backend == BackendChoice::Auto && !crate::sim::gpu::hardware_adapter_available())
    {
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

/// What a shot did.
#[derive(Debug, Clone, Serialize)]
pub struct SimulateReport {
    pub asset: PathBuf,
    pub output: PathBuf,
    pub yarn_files: Vec<PathBuf>,
    pub frames: usize,
    pub first_frame: i64,
    pub last_frame: i64,
    /// The shot's first frame (shot time 0): `first_frame` unless this run
    /// continued an earlier chunk.
    pub shot_start: i64,
    /// The checkpoint this run continued from.
    pub resumed_from: Option<PathBuf>,
    /// The checkpoint this run left at its last frame (for the next chunk).
    pub checkpoint: Option<PathBuf>,
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
    /// Steps that stopped at the iteration cap (`max_iterations`) short of
    /// the tolerance: not converged (a note and a warning say so).
    pub pd_capped_steps: usize,
    /// The PD tolerance of the shot and the largest convergence measure at
    /// the end of a step (dimensionless, `PdParams::tolerance`: at most the
    /// tolerance unless a step was capped).
    pub pd_tolerance: f64,
    pub pd_convergence_max: f64,
    /// What the colliders acted on (`[simulation] contact`: "nodes" or
    /// "yarns").
    pub contact: super::sim_scene::ContactChoice,
    /// Stiffness-proportional damping `β` (s) of the asset's material
    /// (its damping record from `knitvox fit-damping`; 0 without one).
    pub pd_stiffness_damping_s: f64,
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
    /// Yarn-segment stretch `|l / l0 - 1|` of the output frames' yarns (V2Y
    /// of the nodes) against the rest yarns: its 99th percentile and its
    /// largest value over every segment of every frame, and the frame
    /// holding the largest (None without frames). Past
    /// [`STRETCH_P99_BOUND`] or [`STRETCH_MAX_BOUND`]: a warning.
    pub yarn_stretch_p99: Option<f64>,
    pub yarn_stretch_max: Option<f64>,
    pub yarn_stretch_max_frame: Option<i64>,
    /// The bounds the two figures above are held to.
    pub yarn_stretch_bound_p99: f64,
    pub yarn_stretch_bound_max: f64,
    pub character: Option<CharacterReport>,
    pub notes: Vec<String>,
}

/// The yarn-segment stretch that 99% of a shot's segments stay within
/// without a warning (5%), and the bound on its largest (25%). Knit yarns
/// barely stretch (a few percent at their breaking load), and a garment
/// under its weight and a character's motion strains a few percent; the
/// V2Y yarns follow the homogenized fabric, so stretch past these says the
/// material is too soft for the shot, as the placeholder material of an
/// unfitted asset is: fit it (`train`, `fit`).
pub const STRETCH_P99_BOUND: f64 = 0.05;
pub const STRETCH_MAX_BOUND: f64 = 0.25;

/// The stretch warning of a shot whose yarn stretch passes a bound.
fn stretch_warning(s: &crate::geom::StretchSummary) -> Option<String> {
    let pct = |x: f64| 100.0 * x;
    let mut past = Vec::new();
    if s.p99 > STRETCH_P99_BOUND {
        past.push(format!(
            "{}% for the 99th percentile",
            pct(STRETCH_P99_BOUND)
        ));
    }
    if s.max > STRETCH_MAX_BOUND {
        past.push(format!("{}% for the largest", pct(STRETCH_MAX_BOUND)));
    }
    (!past.is_empty()).then(|| {
        format!(
            "the yarns stretch: 99% of the yarn segments stay within {:.1}% of their rest length and the most \
             stretched is {:.1}% off (frame {}), past the bound of {}: knit yarns barely stretch, so the \
             asset's material is too soft for this shot (an asset straight from `embed` has a placeholder \
             material): give it a material card of its stitch (`knitvox card`, `knitvox embed --card`; \
             docs/guides/cards.md) or fit it to yarn-level poses (`knitvox train`, `knitvox fit`)",
            pct(s.p99),
            pct(s.max),
            s.max_frame,
            past.join(" and ")
        )
    })
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

/// How a shot is split into chunks and resumed (`knitvox simulate
/// --checkpoint-every`, `--resume`, `--shot-start`, `--checkpoint`;
/// schemas/checkpoint.md). The default is a shot that starts at its first
/// frame, writes no checkpoint and whose outputs are all or nothing.
#[derive(Debug, Clone, Default)]
pub struct ChunkOptions {
    /// Checkpoint every this many frames of the shot (counted from the shot
    /// start) and at the request's last frame. 0 (the default): no
    /// checkpoints and all-or-nothing outputs. Above 0 the shot is
    /// resumable: each yarn frame file gets its final name as soon as it is
    /// complete (a killed shot keeps its finished frames); a shot that fails
    /// for good removes the frame files it wrote.
    pub checkpoint_every: usize,
    /// Folder of the checkpoints [default: the output asset's folder].
    pub checkpoint_dir: Option<PathBuf>,
    /// Continue from this checkpoint (refused if it is not of this shot, or
    /// lies past the request's first frame, or past its last with `resume`).
    pub checkpoint: Option<PathBuf>,
    /// The shot's first frame (shot time 0; the pre-roll comes before it).
    /// `None`: the request's first frame, unless the checkpoint folder holds
    /// a checkpoint of this shot started earlier, before the request's
    /// first frame (the previous chunk's), which is then continued.
    pub shot_start: Option<i64>,
    /// Continue from the latest checkpoint of this shot up to the request's
    /// last frame (a rerun of a killed chunk); with none, start as usual.
    pub resume: bool,
    /// A checkpoint named for this shot that cannot be used (unreadable,
    /// truncated, another version or shot, a hash or header that does not
    /// match its content) is skipped with a warning naming it and why,
    /// instead of being an error (exit 65); the run then continues from an
    /// older one or starts from rest.
    pub resume_or_restart: bool,
    /// Set from outside (SIGTERM): finish the current step, checkpoint,
    /// stop with [`SimulateError::Interrupted`].
    pub stop: Option<&'static AtomicBool>,
}

/// The default checkpoint interval (frames) of `knitvox simulate`.
pub const DEFAULT_CHECKPOINT_EVERY: usize = 10;

/// Simulates `asset` (read from `asset_path`) under `scene` and writes the
/// outputs of `req`: shot setup ([`shot_setup`](super::shot_setup)), the
/// time loop ([`crate::sim::shot::run`]), and the frame writer, which gets
/// each requested frame as it is computed. Outputs are all or nothing.
/// `progress(done, total)` is called after every frame.
pub fn simulate(
    asset: &Asset,
    asset_path: &Path,
    scene: &Scene,
    req: &ShotRequest,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SimulateReport, SimulateError> {
    struct Progress<'a>(&'a mut dyn FnMut(usize, usize));
    impl Observer for Progress<'_> {
        fn frames(&mut self, done: usize, total: usize) {
            (self.0)(done, total)
        }
    }
    simulate_chunk(
        asset,
        asset_path,
        scene,
        req,
        &ChunkOptions::default(),
        &mut Progress(progress),
    )
}

/// [`simulate`] as a chunk of a longer shot: starts from rest at the shot
/// start or continues from a checkpoint ([`ChunkOptions`]), checkpoints as
/// asked, and reports each frame to `observer`.
pub fn simulate_chunk(
    asset: &Asset,
    asset_path: &Path,
    scene: &Scene,
    req: &ShotRequest,
    chunk: &ChunkOptions,
    observer: &mut dyn Observer,
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
    let mut setup = shot_setup::setup(asset, asset_path, scene, first, last)?;
    let character_sha = match scene.character_path() {
        Some(p) => Some(super::util::sha256_file(&p)?),
        None => None,
    };
    let ctx = ShotKey {
        key: shot_key(asset_path, scene, &setup.schedule, asset, &character_sha)?,
        dir: checkpoint_dir(chunk, req),
        nodes: asset.mesh.num_nodes(),
        preroll: setup.schedule.preroll_steps,
        spf: setup.schedule.steps_per_frame,
        t0: setup.schedule.t0(),
        dt: setup.schedule.dt,
        fps: sim.fps,
    };
    let resumed = resolve_start(&ctx, chunk, &frames, observer)?;
    let start = resumed.shot_start;
    setup.schedule.frame_intervals = usize::try_from(last - start).unwrap_or(usize::MAX);
    let schedule = setup.schedule;
    if schedule.total_steps().is_none_or(|t| t > MAX_TOTAL_STEPS) {
        return Err(invalid(
            asset_path,
            format!("frames {start}-{last} need more than the limit of {MAX_TOTAL_STEPS} steps"),
        ));
    }
    let (mut solver, backend, dd) = build_solver(asset, asset_path, sim, &setup)?;
    let mut out = output_asset(
        asset,
        scene,
        req,
        [start, first, last],
        &schedule,
        [solver_name, backend],
        character_sha,
    )?;
    let mut x;
    let mut v;
    let mut start_step = 0usize;
    let mut series_frames: Vec<i64> = Vec::new();
    let resumed_from = resumed.from.as_ref().map(|(p, _)| p.clone());
    match resumed.from {
        Some((path, c)) => {
            solver
                .set_warm_start(&c.warm_start)
                .map_err(|e| invalid(&path, format!("checkpoint: {e}")))?;
            start_step = c.header.step as usize;
            x = c.x;
            v = c.v;
            // Keep the frames of this request (a previous chunk's are its own).
            let n = x.len();
            for (i, &f) in c.header.series_frames.iter().enumerate() {
                if frames.binary_search(&f).is_ok() {
                    series_frames.push(f);
                    out.steps.times.push(c.series_times[i]);
                    out.steps
                        .positions
                        .extend_from_slice(&c.series[i * n..(i + 1) * n]);
                }
            }
        }
        None => {
            setup.project_start(scene)?;
            x = std::mem::take(&mut setup.x);
            v = vec![[0.0; 3]; x.len()];
        }
    }

    // A resumable shot names each frame file as it is complete; otherwise
    // all or nothing: each yarn frame stays a temporary
    // file until the asset is written too, then all get their names.
    let resumable = chunk.checkpoint_every > 0;
    let mut writer = match &req.yarns_out {
        Some(y) => Some(YarnFrameWriter::create(y, &asset.rest_yarns, &req.write)?),
        None => None,
    };
    let mut adopted = 0;
    let mut measures = Measures::default();
    let mut stretch = crate::geom::SegmentStretch::new(&asset.rest_yarns);
    // Frames a resumed run had computed count too (this request's only).
    {
        let n = x.len();
        for (i, &f) in series_frames.iter().enumerate() {
            let nodes = &out.steps.positions[i * n..(i + 1) * n];
            stretch.add_frame(f, &asset.embedding.v2y(&asset.mesh, nodes));
        }
    }
    let mut last_checkpoint = None;
    let mut periodic: Option<PathBuf> = None;
    let mut body = || -> Result<_, SimulateError> {
        // The frames a resumed run had written: their files stay when
        // complete, and come back from the checkpoint's node positions when
        // missing (one HDF5 file is always written whole).
        if let Some(w) = writer.as_mut() {
            let n = x.len();
            for (i, &f) in series_frames.iter().enumerate() {
                match w.frame_path(f).filter(|p| p.is_file()) {
                    Some(p) => {
                        w.adopt(p);
                        adopted += 1;
                    }
                    None => {
                        let nodes = &out.steps.positions[i * n..(i + 1) * n];
                        let y = asset.embedding.v2y(&asset.mesh, nodes);
                        w.push(f, out.steps.times[i], &y)?;
                    }
                }
            }
        }
        let mut body_before = setup
            .body
            .as_ref()
            .map(|b| b.positions(schedule.time(start_step)));
        let mut next_frame = series_frames.len();
        let stop = || {
            chunk
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::SeqCst))
        };
        let result = shot::run(
            &mut solver,
            &mut x,
            &mut v,
            &schedule,
            start_step,
            |_, t, pins| -> Result<Posed, SimulateError> {
                let mut posed = setup.pose(scene, t, body_before.as_deref())?;
                setup.pin_positions(asset_path, t, posed.verts.as_deref(), pins)?;
                body_before = posed.verts.take();
                Ok(posed)
            },
            |st| -> Result<(), SimulateError> {
                let f = start + st.frame as i64;
                if frames.get(next_frame) == Some(&f) {
                    let at_start;
                    let posed = match st.contacts {
                        Some(p) => p,
                        None => {
                            at_start = setup.pose(scene, schedule.time(st.step), None)?;
                            &at_start
                        }
                    };
                    let time = f as f64 / sim.fps;
                    // Every output frame's yarns: for the stretch check, the
                    // colliders and the yarn files (4 weights per vertex).
                    let yarns = asset.embedding.v2y(&asset.mesh, st.x);
                    stretch.add_frame(f, &yarns);
                    let pen = measures.add(st.x, Some(&yarns), posed, &setup.is_pinned);
                    out.steps.times.push(time);
                    out.steps.positions.extend_from_slice(st.x);
                    series_frames.push(f);
                    if let Some(w) = writer.as_mut() {
                        w.push(f, time, &yarns)?;
                    }
                    next_frame += 1;
                    observer.frame(&FrameProgress {
                        frame: f,
                        done: next_frame,
                        total: frames.len(),
                        ms: st.ms,
                        residual: Some(st.residual).filter(|r| !r.is_nan()),
                        penetration_m: pen,
                    });
                }
                let every = chunk.checkpoint_every;
                let due = every > 0 && (st.frame % every == 0 || f == last);
                if due && st.step > start_step {
                    let state = State {
                        step: st.step,
                        x: st.x,
                        v: st.v,
                        frames: &series_frames,
                        steps: &out.steps,
                        warm_start: st.solver.warm_start(),
                    };
                    let path = save_checkpoint(&ctx, start, &schedule, &state)?;
                    // Only the latest periodic checkpoint of a run is kept.
                    if let Some(old) = periodic.replace(path.clone()) {
                        if old != path {
                            let _ = std::fs::remove_file(old);
                        }
                    }
                    last_checkpoint = Some(path);
                }
                Ok(())
            },
            &stop,
        );
        let stats = match result {
            Ok(s) => s,
            Err(LoopError::Diverged {
                time,
                frame,
                source,
                ..
            }) => {
                return Err(SimulateError::Diverged {
                    path: asset_path.to_path_buf(),
                    frame: start + frame as i64,
                    time,
                    source,
                })
            }
            Err(LoopError::Callback(e)) => return Err(e),
            Err(LoopError::Stopped { step }) => {
                let state = State {
                    step,
                    x: &x,
                    v: &v,
                    frames: &series_frames,
                    steps: &out.steps,
                    warm_start: solver.warm_start(),
                };
                let path = save_checkpoint(&ctx, start, &schedule, &state)?;
                // The stop's checkpoint supersedes the run's periodic one
                // (a stop between two periodic saves would leave both).
                if let Some(old) = periodic.take().filter(|old| *old != path) {
                    let _ = std::fs::remove_file(old);
                }
                if let Some(w) = writer.take() {
                    // A per-frame sequence keeps its finished frames; one
                    // HDF5 file comes back whole from the checkpoint.
                    drop(w);
                }
                return Err(SimulateError::Interrupted {
                    checkpoint: path,
                    step,
                    time: schedule.time(step),
                });
            }
        };
        let files = match writer.take() {
            Some(w) => w.finish()?,
            None => Vec::new(),
        };
        io::vtkhdf::write_asset(&req.output, &out)?;
        Ok((files, stats))
    };
    let result = if resumable {
        body()
    } else {
        io::atomic::all_or_nothing(&mut body)
    };
    let (yarn_files, stats) = match result {
        Ok(r) => r,
        Err(e) => {
            if resumable && e.class() != ErrorClass::Transient {
                // Failed for good: the frame files this run named go too.
                if let Some(w) = &writer {
                    for p in &w.written()[adopted..] {
                        let _ = std::fs::remove_file(p);
                    }
                }
            }
            return Err(e);
        }
    };
    // A rerun of a finished request wrote no checkpoint: the one it resumed
    // from is the final one, for the next chunk.
    if last_checkpoint.is_none() && Some(start_step) == schedule.total_steps() {
        last_checkpoint = resumed_from.clone();
    }
    // Superseded: the run's own periodic checkpoint, and the one it resumed
    // from when it lies inside this request (an earlier try of it).
    let step_first = ctx.step_of(first, start);
    if let Some(p) = periodic.filter(|p| Some(p) != last_checkpoint.as_ref()) {
        let _ = std::fs::remove_file(p);
    }
    if let Some(p) = resumed_from
        .as_ref()
        .filter(|p| Some(*p) != last_checkpoint.as_ref())
    {
        if checkpoint::read_header(p).is_ok_and(|h| h.step > step_first) {
            let _ = std::fs::remove_file(p);
        }
    }

    let mut report = SimulateReport {
        asset: asset_path.to_path_buf(),
        output: req.output.clone(),
        yarn_files,
        frames: out.steps.num_steps(),
        first_frame: first,
        last_frame: last,
        shot_start: start,
        resumed_from,
        checkpoint: last_checkpoint,
        fps: sim.fps,
        dt: schedule.dt,
        steps_per_frame: schedule.steps_per_frame,
        preroll_steps: schedule.preroll_steps,
        steps: stats.steps,
        nodes: asset.mesh.num_nodes(),
        tets: asset.mesh.num_tets(),
        pinned_scripted: setup.pinned.len() - setup.body_pins.nodes.len(),
        pinned_body: setup.body_pins.nodes.len(),
        solver: solver_name.into(),
        dd_domains: dd.map(|d| d.0),
        dd_partition: dd.map(|d| d.1),
        backend: backend.into(),
        ms_per_step_median: median(stats.step_ms.clone()),
        ms_total: 0.0,
        pd_iterations_mean: stats.iterations_mean(),
        pd_iterations_max: stats.iterations_max,
        pd_capped_steps: stats.capped_steps,
        pd_tolerance: sim.tolerance,
        contact: sim.contact,
        pd_stiffness_damping_s: asset_damping(asset, asset_path)?,
        pd_convergence_max: stats.convergence_max,
        residual_max: stats.residual_max,
        max_penetration_m: 0.0,
        max_penetration_body_m: None,
        max_penetration_yarns_m: None,
        penetration_tolerance_m: PENETRATION_TOLERANCE_M,
        min_distance_m: None,
        max_penetration_pinned_m: None,
        max_contact_correction_m: stats.correction_max,
        yarn_stretch_p99: None,
        yarn_stretch_max: None,
        yarn_stretch_max_frame: None,
        yarn_stretch_bound_p99: STRETCH_P99_BOUND,
        yarn_stretch_bound_max: STRETCH_MAX_BOUND,
        character: setup.character.take(),
        notes: std::mem::take(&mut setup.notes),
    };
    measures.fill(&mut report, sim.contact);
    if let Some(st) = stretch.summary() {
        report.yarn_stretch_p99 = Some(st.p99);
        report.yarn_stretch_max = Some(st.max);
        report.yarn_stretch_max_frame = Some(st.max_frame);
        if let Some(m) = stretch_warning(&st) {
            observer.warning(&m);
            report.notes.push(format!("warning: {m}"));
        }
    }
    if report.pd_capped_steps > 0 {
        let m = format!(
            "{} of {} PD steps stopped at the {}-iteration cap short of the tolerance {:e} (convergence up to {:.2e}, largest residual {:.3e} N): \
             those steps are not converged to the tolerance (raise `max_iterations` in the scene's [simulation])",
            report.pd_capped_steps, report.steps, sim.max_iterations, report.pd_tolerance, report.pd_convergence_max, report.residual_max
        );
        observer.warning(&m);
        report.notes.push(format!("warning: {m}"));
    }
    for m in damping_warnings(asset, schedule.dt) {
        observer.warning(&m);
        report.notes.push(format!("warning: {m}"));
    }
    report.ms_total = t_total.elapsed().as_secs_f64() * 1e3;
    Ok(report)
}

/// Warnings about the asset's fitted damping for a shot stepping `dt` (s):
/// a record of the earlier linear form
/// ([`crate::geom::DampingRecord::superseded`]), and a damping found at a
/// PD step more than 1.5x longer or shorter than `dt`, where implicit
/// Euler's own dissipation differs, so it does not carry as fitted.
fn damping_warnings(asset: &Asset, dt: f64) -> Vec<String> {
    let Some(r) = asset.damping_record().ok().flatten() else {
        return Vec::new();
    };
    let mismatch = r.dt_s.and_then(|fitted| {
        let ratio = dt / fitted;
        (r.stiffness_damping_s > 0.0 && !(1.0 / 1.5..=1.5).contains(&ratio))
            .then(|| step_mismatch(r.stiffness_damping_s, fitted, dt))
    });
    r.superseded().into_iter().chain(mismatch).collect()
}

/// [`damping_warnings`]' step mismatch in words.
fn step_mismatch(beta: f64, fitted: f64, dt: f64) -> String {
    format!(
        "the asset's damping ({beta:.3e} s) was fitted with PD steps of {} s; this shot steps {} s, whose own \
         numerical dissipation differs: the motion is damped differently than fitted (set `dt` in the scene's \
         [simulation] to the fitted step, or fit the damping again at this one)",
        crate::geom::num(fitted),
        crate::geom::num(dt)
    )
}

/// What identifies a shot's checkpoints.
struct ShotKey {
    /// SHA-256 (hex) of the shot's parameters ([`shot_key`]).
    key: String,
    /// Where its checkpoints are.
    dir: PathBuf,
    nodes: usize,
    preroll: usize,
    spf: usize,
    /// Shot time (s) at step 0 and the step (s): a checkpoint's time must
    /// be its step's.
    t0: f64,
    dt: f64,
    /// Frames per second: a written frame's time is its number over it.
    fps: f64,
}

impl ShotKey {
    /// Steps from the loop start (pre-roll included) to frame `f` of the
    /// shot starting at frame `start` (`f >= start`).
    fn step_of(&self, f: i64, start: i64) -> u64 {
        self.preroll as u64 + (f - start).max(0) as u64 * self.spf as u64
    }
}

/// The hash that ties checkpoints to their shot: the asset's and the
/// character's content, the scene (every parameter), the step schedule and
/// the node count; not the frame range, so every chunk of a shot shares it.
fn shot_key(
    asset_path: &Path,
    scene: &Scene,
    schedule: &shot::Schedule,
    asset: &Asset,
    character_sha: &Option<String>,
) -> Result<String, SimulateError> {
    use sha2::{Digest, Sha256};
    let material = serde_json::json!({
        "asset_sha256": super::util::sha256_file(asset_path)?,
        "character_sha256": character_sha,
        "scene": scene,
        "dt": schedule.dt,
        "steps_per_frame": schedule.steps_per_frame,
        "preroll_steps": schedule.preroll_steps,
        "nodes": asset.mesh.num_nodes(),
    });
    let bytes = serde_json::to_vec(&material).map_err(|e| invalid(asset_path, e.to_string()))?;
    Ok(Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// The checkpoint folder of a request: the option's, else the output's.
fn checkpoint_dir(chunk: &ChunkOptions, req: &ShotRequest) -> PathBuf {
    chunk.checkpoint_dir.clone().unwrap_or_else(|| {
        req.output
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
    })
}

/// Where a run starts: the shot's first frame and, when it continues, the
/// checkpoint (its path and content).
struct Resumed {
    shot_start: i64,
    from: Option<(PathBuf, Checkpoint)>,
}

/// Why the checkpoint `h` cannot start a run of `frames` (sorted) of the
/// shot starting at `start` that may begin no later than step `bound`.
fn unusable(
    ctx: &ShotKey,
    h: &CheckpointHeader,
    start: i64,
    bound: u64,
    frames: &[i64],
) -> Option<String> {
    if h.key != ctx.key {
        return Some(format!(
            "it is of another shot: its parameters hash {}.. differs from this shot's {}.. \
             (asset, character, scene, dt, fps and pre-roll must be the same)",
            h.key.get(..12).unwrap_or(&h.key),
            &ctx.key[..12]
        ));
    }
    if h.shot_start != start {
        return Some(format!(
            "it belongs to the shot starting at frame {}, not {start}",
            h.shot_start
        ));
    }
    if h.nodes != ctx.nodes as u64 {
        return Some(format!("it has {} nodes, the asset {}", h.nodes, ctx.nodes));
    }
    if h.step > bound {
        return Some(format!(
            "it is at step {} of the shot, after step {bound}, where this run must start",
            h.step
        ));
    }
    // The frames of this request it has passed must be among its frames.
    let passed: Vec<i64> = frames
        .iter()
        .copied()
        .filter(|&f| ctx.step_of(f, start) <= h.step)
        .collect();
    let kept: Vec<i64> = h
        .series_frames
        .iter()
        .copied()
        .filter(|f| frames.binary_search(f).is_ok())
        .collect();
    (passed != kept).then(|| {
        format!(
            "it lies after frames {passed:?} of this request but holds the node positions of {kept:?}"
        )
    })
}

/// `a` and `b` equal up to the rounding of a JSON round trip.
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs().max(1.0)
}

/// Why checkpoint `c` is not a state this shot's loop wrote: another
/// shot's key or node count, a header that disagrees with the file's name
/// (`found`), a time that is not its step's, written frames out of order or
/// past its step, frame times that are not theirs. The hash covers every
/// byte; these catch a header edited and rehashed, and a renamed file.
fn inconsistent(
    ctx: &ShotKey,
    c: &Checkpoint,
    found: Option<&checkpoint::Found>,
) -> Option<String> {
    let h = &c.header;
    if h.key != ctx.key {
        return Some(format!(
            "its header is of another shot (parameters hash {}..; this shot's is {}..)",
            crate::geom::excerpt_chars(&h.key, 12),
            &ctx.key[..12]
        ));
    }
    if let Some(f) = found {
        if (f.shot_start, f.step) != (h.shot_start, h.step) {
            return Some(format!(
                "its name says shot start {} step {}, its header shot start {} step {}",
                f.shot_start, f.step, h.shot_start, h.step
            ));
        }
    }
    if h.nodes != ctx.nodes as u64 {
        return Some(format!("it has {} nodes, the asset {}", h.nodes, ctx.nodes));
    }
    let t = ctx.t0 + h.step as f64 * ctx.dt;
    if !close(h.time, t) {
        return Some(format!(
            "its time {} s is not the time {t} s of its step {}",
            h.time, h.step
        ));
    }
    let in_order = h.series_frames.windows(2).all(|w| w[0] < w[1]);
    let reached = h
        .series_frames
        .iter()
        .all(|&f| f >= h.shot_start && ctx.step_of(f, h.shot_start) <= h.step);
    if !in_order || !reached {
        return Some(format!(
            "its written frames {} are not frames the shot from frame {} reaches by step {}",
            crate::geom::excerpt(&format!("{:?}", h.series_frames)),
            h.shot_start,
            h.step
        ));
    }
    let times_ok = h
        .series_frames
        .iter()
        .zip(&c.series_times)
        .all(|(&f, &t)| close(t, f as f64 / ctx.fps));
    (!times_ok).then(|| "the times of its written frames are not those frames' times".into())
}

/// The reason in a checkpoint reader's error, without the path it starts with.
fn reason(path: &Path, e: &IoError) -> String {
    let text = e.to_string();
    let prefix = format!("{}: ", path.display());
    text.strip_prefix(&prefix).unwrap_or(&text).to_string()
}

/// Decides where the run of `frames` (sorted, deduplicated) starts
/// ([`ChunkOptions`]): from rest at the shot start, or from a checkpoint.
/// A request that starts after the shot start needs a checkpoint; none is
/// an error, never a silent restart from rest.
fn resolve_start(
    ctx: &ShotKey,
    chunk: &ChunkOptions,
    frames: &[i64],
    observer: &mut dyn Observer,
) -> Result<Resumed, SimulateError> {
    let (first, last) = (frames[0], frames[frames.len() - 1]);
    if let Some(s) = chunk.shot_start.filter(|&s| s > first) {
        return Err(SimulateError::Usage(format!(
            "--shot-start {s} is after the first frame {first} of --frames"
        )));
    }
    let bound = |start| ctx.step_of(if chunk.resume { last } else { first }, start);
    if let Some(path) = &chunk.checkpoint {
        let h = checkpoint::read_header(path)?;
        let start = chunk.shot_start.unwrap_or(h.shot_start);
        if let Some(why) = unusable(ctx, &h, start, bound(start), frames) {
            return Err(SimulateError::CheckpointMismatch {
                path: path.clone(),
                message: format!("--checkpoint cannot start frames {first}-{last}: {why}"),
            });
        }
        let c = checkpoint::read(path, io::max_memory())?;
        if let Some(why) = inconsistent(ctx, &c, None) {
            return Err(invalid(
                path,
                format!("not a usable knitvox checkpoint: {why}"),
            ));
        }
        return Ok(Resumed {
            shot_start: start,
            from: Some((path.clone(), c)),
        });
    }
    // The checkpoints named for this shot that this run may start from,
    // latest first.
    let mut candidates: Vec<checkpoint::Found> = checkpoint::list(&ctx.dir, &ctx.key)?
        .into_iter()
        .filter(|f| {
            let start = f.shot_start;
            let start_ok = match chunk.shot_start {
                Some(s) => start == s,
                None => start <= first,
            };
            // A fresh run of a shot from its start ignores older checkpoints.
            start_ok && !(start == first && !chunk.resume) && f.step <= bound(start)
        })
        .collect();
    candidates.sort_by(|a, b| (b.step, b.shot_start).cmp(&(a.step, a.shot_start)));
    for f in candidates {
        let start = f.shot_start;
        // Every candidate is read and checked whole: a damaged one is
        // never passed over in silence (a silent restart from rest).
        let why = match checkpoint::read(&f.path, io::max_memory()) {
            Err(e) => reason(&f.path, &e),
            Ok(c) => match inconsistent(ctx, &c, Some(&f)) {
                Some(why) => format!("not a usable knitvox checkpoint: {why}"),
                // Of this shot, but for other frames: not this run's.
                None if unusable(ctx, &c.header, start, bound(start), frames).is_some() => continue,
                None => {
                    return Ok(Resumed {
                        shot_start: start,
                        from: Some((f.path, c)),
                    })
                }
            },
        };
        if !chunk.resume_or_restart {
            return Err(invalid(
                &f.path,
                format!(
                    "{why}; this run would continue from it: move it away, or pass \
                     --resume-or-restart to skip it (the shot then continues from an older \
                     checkpoint or starts from rest)"
                ),
            ));
        }
        observer.warning(&format!(
            "{}: {why}; skipped (--resume-or-restart)",
            f.path.display()
        ));
    }
    let start = chunk.shot_start.unwrap_or(first);
    if start < first {
        return Err(SimulateError::NoCheckpoint {
            dir: ctx.dir.clone(),
            message: format!(
                "frames {first}-{last} continue the shot that starts at frame {start}, but {} holds no \
                 checkpoint of this shot at or before frame {first} (files {}); run the chunk before \
                 it first (same asset, scene and options, same --checkpoint-dir), or pass \
                 --checkpoint PATH",
                ctx.dir.display(),
                checkpoint::file_name(&ctx.key, start, 0).replace(".0000000000.", ".STEP.")
            ),
        });
    }
    Ok(Resumed {
        shot_start: start,
        from: None,
    })
}

/// A loop state to checkpoint.
struct State<'a> {
    step: usize,
    x: &'a [Vec3],
    v: &'a [Vec3],
    /// The written frames' numbers and node positions.
    frames: &'a [i64],
    steps: &'a NodeSteps,
    /// The solver's warm start.
    warm_start: Vec<f64>,
}

/// Writes the checkpoint of `state` into the shot's folder; returns its path.
fn save_checkpoint(
    ctx: &ShotKey,
    start: i64,
    schedule: &shot::Schedule,
    state: &State<'_>,
) -> Result<PathBuf, SimulateError> {
    let path = ctx
        .dir
        .join(checkpoint::file_name(&ctx.key, start, state.step as u64));
    let c = Checkpoint {
        header: CheckpointHeader {
            key: ctx.key.clone(),
            shot_start: start,
            step: state.step as u64,
            time: schedule.time(state.step),
            nodes: state.x.len() as u64,
            series_frames: state.frames.to_vec(),
            warm_start_len: state.warm_start.len() as u64,
            knitvox: env!("CARGO_PKG_VERSION").into(),
        },
        x: state.x.to_vec(),
        v: state.v.to_vec(),
        series_times: state.steps.times.clone(),
        series: state.steps.positions.clone(),
        warm_start: state.warm_start.clone(),
    };
    std::fs::create_dir_all(&ctx.dir).map_err(|source| IoError::Write {
        path: ctx.dir.clone(),
        source,
    })?;
    checkpoint::write(&path, &c)?;
    Ok(path)
}

/// The PD solver of a shot on its backend; with the domain-decomposed
/// solver, its domain count and where the partition comes from.
#[allow(clippy::type_complexity)]
fn build_solver(
    asset: &Asset,
    asset_path: &Path,
    sim: &SimulationSection,
    setup: &shot_setup::ShotSetup,
) -> Result<(PdSolver, &'static str, Option<(usize, &'static str)>), SimulateError> {
    let stored = stored_domains(&asset.domain);
    let model = super::asset::asset_materials(asset)
        .model(&asset.mesh)
        .map_err(|e| invalid(asset_path, e.to_string()))?;
    let mut solver = PdSolver::with_model(
        &asset.mesh,
        model,
        &asset.node_mass,
        &setup.pinned,
        PdParams {
            stiffness_damping: asset_damping(asset, asset_path)?,
            ..pd_params(sim, setup.schedule.dt)
        },
        stored.as_deref(),
    )
    .map_err(|e| invalid(asset_path, e.to_string()))?;
    let backend = attach_backend(&mut solver, sim.backend)?;
    let from = if stored.is_some() {
        "asset"
    } else {
        "bisection"
    };
    let dd = solver.dd_stats().map(|d| (d.domains, from));
    Ok((solver, backend, dd))
}

/// The output asset before its frames: a copy of `asset` with an empty time
/// series, the shot's parameters (`parameters.simulate`) and provenance
/// (the command, the character file's SHA-256).
fn output_asset(
    asset: &Asset,
    scene: &Scene,
    req: &ShotRequest,
    [start, first, last]: [i64; 3],
    schedule: &shot::Schedule,
    [solver_name, backend]: [&str; 2],
    character_sha: Option<String>,
) -> Result<Asset, SimulateError> {
    let mut out = asset.clone();
    out.steps = NodeSteps::default();
    if let serde_json::Value::Object(m) = &mut out.parameters {
        m.insert(
            "simulate".into(),
            serde_json::json!({
                "scene": scene,
                "frames": [first, last],
                "shot_start": start,
                "dt": schedule.dt,
                "steps_per_frame": schedule.steps_per_frame,
                "preroll_steps": schedule.preroll_steps,
                "solver": solver_name,
                "backend": backend,
            }),
        );
    }
    out.provenance.command = format!("{} && {}", out.provenance.command, req.command);
    if let (Some(p), Some(sha256)) = (scene.character_path(), character_sha) {
        out.provenance.inputs.push(crate::geom::InputFile {
            path: p.display().to_string(),
            sha256,
        });
    }
    Ok(out)
}

/// The stiffness-proportional damping (s) the asset records, 0 without a
/// record; a malformed record is the asset's error.
fn asset_damping(asset: &Asset, asset_path: &Path) -> Result<f64, SimulateError> {
    asset
        .damping_record()
        .map(|r| r.map_or(0.0, |r| r.stiffness_damping_s))
        .map_err(|e| invalid(asset_path, e.to_string()))
}

/// The PD parameters of a scene's `[simulation]` at step `dt` (s).
fn pd_params(sim: &SimulationSection, dt: f64) -> PdParams {
    PdParams {
        dt,
        gravity: sim.gravity,
        mass_damping: sim.damping,
        max_iterations: sim.max_iterations,
        anderson_window: sim.anderson_window,
        tolerance: sim.tolerance,
        global: global_solver(sim.solver),
        ..PdParams::default()
    }
}

/// Penetration figures over the output frames (m).
#[derive(Debug, Default)]
struct Measures {
    max_pen: f64,
    max_pen_body: Option<f64>,
    max_pen_yarns: Option<f64>,
    min_dist: Option<f64>,
    pen_pinned: Option<f64>,
}

impl Measures {
    /// Puts the figures into `report`, with a warning in its notes for
    /// tet nodes (only where the colliders act on them: with yarn contact
    /// the nodes under the yarns may enter a collider) or yarn vertices
    /// deeper than the tolerance.
    fn fill(&self, report: &mut SimulateReport, contact: super::sim_scene::ContactChoice) {
        let on_nodes = contact == super::sim_scene::ContactChoice::Nodes;
        for (what, pen) in [
            ("tet nodes", Some(self.max_pen).filter(|_| on_nodes)),
            ("yarn vertices", self.max_pen_yarns),
        ] {
            if let Some(p) = pen.filter(|&p| p > PENETRATION_TOLERANCE_M) {
                report.notes.push(format!(
                    "warning: {what} sit up to {p:.3e} m inside a collider, more than the tolerance of \
                     {PENETRATION_TOLERANCE_M} m (raise the collider thickness, use smaller voxels or check the pins)"
                ));
            }
        }
        report.max_penetration_m = self.max_pen.max(0.0);
        report.max_penetration_body_m = self.max_pen_body;
        report.max_penetration_yarns_m = self.max_pen_yarns;
        report.min_distance_m = self.min_dist;
        report.max_penetration_pinned_m = self.pen_pinned;
    }

    /// Adds one frame: node positions `x`, their yarn vertices (V2Y; given
    /// whenever there are colliders), the colliders then.
    /// Returns the frame's deepest penetration of a free node (m; None
    /// without colliders).
    fn add(
        &mut self,
        x: &[Vec3],
        yarns: Option<&[Vec3]>,
        posed: &Posed,
        is_pinned: &[bool],
    ) -> Option<f64> {
        let (set, body_set) = (&posed.set, &posed.body_set);
        let mut frame_pen: Option<f64> = None;
        if let (false, Some(y)) = (set.colliders.is_empty(), yarns) {
            let pen = set.max_penetration(y);
            self.max_pen_yarns = Some(self.max_pen_yarns.map_or(pen, |m| m.max(pen)));
        }
        for (i, p) in x.iter().enumerate() {
            if is_pinned[i] {
                if let Some(bs) = body_set {
                    let pen = bs.penetration(*p);
                    self.pen_pinned = Some(self.pen_pinned.map_or(pen, |m| m.max(pen)));
                }
                continue;
            }
            if let Some((_, d)) = set.min_signed_distance(*p) {
                self.min_dist = Some(self.min_dist.map_or(d, |m| m.min(d)));
                self.max_pen = self.max_pen.max(-d);
                frame_pen = Some(frame_pen.unwrap_or(0.0).max(-d));
            }
            if let Some(bs) = body_set {
                let pen = bs.penetration(*p);
                self.max_pen_body = Some(self.max_pen_body.map_or(pen, |m| m.max(pen)));
            }
        }
        frame_pen
    }
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

/// Reads and parses a scene file.
pub fn read_scene(path: &Path) -> Result<Scene, SimulateError> {
    let text = crate::io::input::read_input_text(path, "scene", crate::io::max_memory())?;
    Ok(Scene::parse(&text, path)?)
}

/// The shot stage: an asset under a scene -> the asset with the frames as
/// its time series, and yarn curves per frame.
#[derive(Debug, Clone)]
pub struct ShotJob {
    /// The homogenized asset (.vtkhdf); read, never modified.
    pub asset: PathBuf,
    /// The scene (a scene file's, or built from a command line).
    pub scene: Scene,
    /// Frames and outputs.
    pub request: ShotRequest,
}

impl Stage for ShotJob {
    type Report = SimulateReport;
    const NAME: &'static str = "shot";
    fn run(&self, observer: &mut dyn Observer) -> Result<SimulateReport, Error> {
        run_shot(self, &ChunkOptions::default(), observer)
    }
}

/// The shot stage as a chunk of a longer shot, with checkpoints and resume
/// ([`ChunkOptions`]).
#[derive(Debug, Clone)]
pub struct ChunkedShotJob {
    pub shot: ShotJob,
    pub chunk: ChunkOptions,
}

impl Stage for ChunkedShotJob {
    type Report = SimulateReport;
    const NAME: &'static str = "shot";
    fn run(&self, observer: &mut dyn Observer) -> Result<SimulateReport, Error> {
        run_shot(&self.shot, &self.chunk, observer)
    }
}

fn run_shot(
    job: &ShotJob,
    chunk: &ChunkOptions,
    observer: &mut dyn Observer,
) -> Result<SimulateReport, Error> {
    super::asset::check_asset_ext(&job.asset)?;
    super::asset::check_asset_ext(&job.request.output)?;
    let asset = io::vtkhdf::read_asset(&job.asset)?;
    // The asset records how its yarns were read: an assumed unit and an
    // implausible size are worth a warning before a long shot.
    if let Some(w) = super::asset::size_warning(&asset) {
        observer.warning(&format!(
            "{}: {w} (when embedding its yarns)",
            job.asset.display()
        ));
    }
    Ok(simulate_chunk(
        &asset,
        &job.asset,
        &job.scene,
        &job.request,
        chunk,
        observer,
    )?)
}
