//! The benchmarks behind `knitvox bench io|embed|sim|yls`: each builds its
//! scene, times the work with the physics engaged and returns what it
//! measured (the CLI prints it, `--json`: schemas/cli-json.md). Timings are
//! medians of the runs or steps.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::geom::Vec3;
use crate::io::{self, Format, IoError, ReadOptions, WriteOptions};
use crate::pipeline::sim_scene::{BackendChoice, SolverChoice};
use crate::pipeline::util::median;
use crate::yarn::analytic::knit_swatch_with_points;

/// Why a benchmark could not run. Each variant keeps the error it wraps as
/// its cause, so the exit code is that cause's class (`pipeline::class_of`
/// looks through the chain); the message is the cause's own.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{0}")]
    Io(#[from] IoError),
    #[error("{0}")]
    Embed(#[from] crate::embed::EmbedError),
    #[error("{0}")]
    ShapeFit(#[from] crate::fit::FitError),
    #[error("{0}")]
    Sim(#[from] crate::sim::SimError),
    #[error("{0}")]
    YarnSim(#[from] crate::yarn::sim::YarnSimError),
    #[error("{0}")]
    Fabric(#[from] crate::yarn::fabric::FabricError),
    #[error("{0}")]
    Pattern(#[from] crate::pipeline::pattern::PatternStageError),
    #[error("{0}")]
    Shot(#[from] crate::pipeline::simulate::SimulateError),
    /// A request the benchmark refuses (the message names the option).
    #[error("{0}")]
    Usage(String),
    /// A broken invariant of the benchmark itself.
    #[error("internal error: {0}")]
    Internal(String),
}

/// `bench io`: the input (or the built-in analytic swatch of `points`
/// points) written and read back in every writable format, `runs` times.
#[derive(Debug, Clone)]
pub struct IoRequest {
    pub input: Option<PathBuf>,
    pub read: ReadOptions,
    pub points: usize,
    pub runs: usize,
}

/// `bench embed`: the input (or the analytic swatch) embedded `runs` times
/// at `voxel_size` (m; default: the embedding's), then `frames` frames
/// shape-fitted.
#[derive(Debug, Clone)]
pub struct EmbedRequest {
    pub input: Option<PathBuf>,
    pub read: ReadOptions,
    pub points: usize,
    pub voxel_size: Option<f64>,
    pub frames: usize,
    pub runs: usize,
}

/// The scene of `bench sim`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SimScene {
    /// The swatch (in the xy plane) pinned along its low-x edge and left to
    /// fall under gravity along -z, normal to the fabric: a flap draping
    /// from a rail, the large soft bending motion PD converges slowest on.
    #[default]
    Drape,
    /// Both x edges pinned, one pulled 20% of the width over the run, under
    /// gravity along -y.
    Stretch,
}

/// `bench sim`: `steps` PD steps of `dt` (s) of `scene` on about `tets`
/// tets, and (unless `reference` is off) the same steps run again to
/// `reference_tolerance`, untimed, for the deviation.
#[derive(Debug, Clone)]
pub struct SimRequest {
    pub tets: usize,
    pub steps: usize,
    pub dt: f64,
    pub scene: SimScene,
    pub backend: BackendChoice,
    pub solver: SolverChoice,
    /// Most PD iterations per step (default: `PdParams`'s).
    pub pd_iterations: Option<u32>,
    /// PD convergence tolerance (`PdParams::tolerance`; 0 runs
    /// `pd_iterations`; default: `PdParams`'s).
    pub tolerance: Option<f64>,
    /// Run the converged reference and report the deviation from it.
    pub reference: bool,
    /// Tolerance of the reference run (default [`REFERENCE_TOLERANCE`]).
    pub reference_tolerance: Option<f64>,
    /// Domain-decomposed solver only: Jacobi tolerance and interior model.
    pub dd_tolerance: Option<f64>,
    pub dd_interiors: Option<crate::sim::dd::Interiors>,
    /// Anderson window (default: `PdParams`'s).
    pub anderson: Option<usize>,
}

/// Default PD tolerance of `bench sim`'s converged reference run: its
/// deviation from a run to 1e-7 is below 0.01% of the displacement on the
/// drape (docs/performance.md "Converged steps").
pub const REFERENCE_TOLERANCE: f64 = 1e-5;

/// Iteration cap of the reference run.
pub const REFERENCE_MAX_ITERATIONS: u32 = 3000;

/// `bench yls`: the yarn-level simulator on a built-in `pattern` swatch of
/// about `vertices` vertices or on `input`.
#[derive(Debug, Clone)]
pub struct YlsRequest {
    pub vertices: usize,
    pub pattern: String,
    pub steps: usize,
    pub warmup: usize,
    pub frames: usize,
    pub relax: bool,
    pub input: Option<PathBuf>,
    /// Quasi-static stretch along x before the timed run (0: none), in
    /// `prestretch_steps` load steps.
    pub prestretch: f64,
    pub prestretch_steps: usize,
}

/// What `bench yls` measured: the `--json` object and the simulator's report.
#[derive(Debug, Clone)]
pub struct YlsBench {
    pub json: serde_json::Value,
    pub report: crate::yarn::sim::BenchReport,
}

fn time_ms<T>(
    runs: usize,
    mut f: impl FnMut() -> Result<T, BenchError>,
) -> Result<f64, BenchError> {
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let s = Instant::now();
        std::hint::black_box(f()?);
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(t))
}

/// One format's times in `bench io`.
#[derive(Debug, Clone, Serialize)]
pub struct FormatTimes {
    pub write_ms: f64,
    pub read_ms: f64,
    pub bytes: u64,
}

/// What `bench io` measured (`--json`: schemas/cli-json.md).
#[derive(Debug, Clone, Serialize)]
pub struct IoBench {
    pub bench: &'static str,
    pub input: String,
    pub curves: usize,
    pub points: usize,
    pub runs: usize,
    pub threads: usize,
    pub input_read_ms: Option<f64>,
    pub formats: BTreeMap<&'static str, FormatTimes>,
}

/// `bench io`: write and read times of every writable format.
pub fn io(a: &IoRequest) -> Result<IoBench, BenchError> {
    let opts = a.read.clone();
    let (yarns, input, input_read_ms) = match &a.input {
        Some(p) => {
            let d = io::read_path(p, &opts)?;
            let ms = time_ms(a.runs, || Ok(io::read_path(p, &opts)?))?;
            (d.yarns, p.display().to_string(), Some(ms))
        }
        None => (
            knit_swatch_with_points(a.points),
            format!("built-in analytic swatch ({} points)", a.points),
            None,
        ),
    };
    let dir = tempfile::tempdir().map_err(|source| IoError::Write {
        path: std::env::temp_dir(),
        source,
    })?;
    let mut formats = BTreeMap::new();
    let read_back = ReadOptions {
        radius: opts.radius,
        ..ReadOptions::default()
    };
    for format in Format::ALL.into_iter().filter(|f| f.is_writable()) {
        let path = dir.path().join(format!("bench.{}", format.extensions()[0]));
        let write_ms = time_ms(a.runs, || {
            Ok(io::write_path(
                &path,
                &yarns,
                None,
                &WriteOptions::default(),
            )?)
        })?;
        let read_ms = time_ms(a.runs, || Ok(io::read_path(&path, &read_back)?))?;
        let bytes = std::fs::metadata(&path)
            .map_err(|source| IoError::Read {
                path: path.clone(),
                source,
            })?
            .len();
        formats.insert(
            format.name(),
            FormatTimes {
                write_ms,
                read_ms,
                bytes,
            },
        );
    }
    let r = IoBench {
        bench: "io",
        input,
        curves: yarns.num_curves(),
        points: yarns.num_points(),
        runs: a.runs,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        input_read_ms,
        formats,
    };
    Ok(r)
}

/// Peak resident memory of this process (MB), from /proc (Linux); None elsewhere.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// What `bench embed` measured (`--json`: schemas/cli-json.md).
#[derive(Debug, Clone, Serialize)]
pub struct EmbedBench {
    pub bench: &'static str,
    pub input: String,
    pub yarn_points: usize,
    pub voxel_size: f64,
    pub voxels: usize,
    pub nodes: usize,
    pub tets: usize,
    pub nodes_per_yarn_point: f64,
    pub runs: usize,
    pub threads: usize,
    pub embed_ms: f64,
    pub shapefit_prepare_ms: f64,
    pub shapefit_frames: usize,
    pub shapefit_ms_per_frame: f64,
    pub shapefit_rms_error_max_m: f64,
    pub peak_rss_mb: Option<f64>,
}

/// `bench embed`: embedding and Y2V shape-fit times and the mesh size.
pub fn embed(a: &EmbedRequest) -> Result<EmbedBench, BenchError> {
    use crate::embed::{embed as run_embed, EmbedParams};
    use crate::fit::{ShapeFitParams, ShapeFitter};
    let (yarns, input) = match &a.input {
        Some(p) => (
            io::read_path(p, &a.read.clone())?.yarns,
            p.display().to_string(),
        ),
        None => (
            knit_swatch_with_points(a.points),
            format!("built-in analytic swatch ({} points)", a.points),
        ),
    };
    let params = EmbedParams {
        voxel_size: a.voxel_size,
        ..EmbedParams::default()
    };
    let e = run_embed(&yarns, &params)?;
    let embed_ms = time_ms(a.runs, || Ok(run_embed(&yarns, &params)?))?;
    let t = Instant::now();
    let fitter = ShapeFitter::from_embedded(&yarns, &e, &ShapeFitParams::default())?;
    let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
    let frames = crate::pipeline::demo::demo_frames(&yarns, a.frames.max(1));
    let mut per_frame = Vec::new();
    let mut worst: f64 = 0.0;
    for f in 0..frames.num_frames() {
        let t = Instant::now();
        let (_, st) = fitter.fit(frames.frame(f))?;
        per_frame.push(t.elapsed().as_secs_f64() * 1e3);
        worst = worst.max(st.rms_error);
    }
    let r = EmbedBench {
        bench: "embed",
        input,
        yarn_points: yarns.num_points(),
        voxel_size: e.stats.voxel_size,
        voxels: e.stats.voxels,
        nodes: e.mesh.num_nodes(),
        tets: e.mesh.num_tets(),
        nodes_per_yarn_point: e.mesh.num_nodes() as f64 / yarns.num_points().max(1) as f64,
        runs: a.runs,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        embed_ms,
        shapefit_prepare_ms: prepare_ms,
        shapefit_frames: per_frame.len(),
        shapefit_ms_per_frame: median(per_frame),
        shapefit_rms_error_max_m: worst,
        peak_rss_mb: peak_rss_mb(),
    };
    Ok(r)
}

/// What `bench sim` measured (`--json`: schemas/cli-json.md).
#[derive(Debug, Clone, Serialize)]
pub struct SimBench {
    pub bench: &'static str,
    pub input: String,
    pub scene: &'static str,
    pub yarn_points: usize,
    pub voxel_size: f64,
    pub tets: usize,
    pub nodes: usize,
    pub pinned: usize,
    pub steps: usize,
    pub dt: f64,
    pub threads: usize,
    pub solver: &'static str,
    pub backend: &'static str,
    /// One-off assembly and factorization (ms).
    pub prepare_ms: f64,
    /// Median wall time of one time step (ms).
    pub ms_per_step: f64,
    /// Mean PD iterations (local + global) per step.
    pub pd_iterations: f64,
    pub pd_iterations_max: u32,
    /// The PD tolerance and iteration cap the timed run used.
    pub tolerance: f64,
    pub max_iterations: u32,
    /// Steps that stopped at the cap short of the tolerance.
    pub capped_steps: usize,
    /// Largest convergence measure at the end of a step
    /// (`StepStats::convergence`; dimensionless).
    pub convergence: f64,
    /// Largest implicit-Euler residual over the steps (N).
    pub residual: f64,
    /// Largest node distance from the converged reference run, over all
    /// steps, divided by the reference's largest node displacement from
    /// the start (dimensionless); null without a reference.
    pub deviation: Option<f64>,
    /// The reference's largest node displacement from the start (m).
    pub displacement_m: Option<f64>,
    /// The reference run: its tolerance, mean and largest PD iterations per
    /// step, capped steps and largest residual (N).
    pub reference_tolerance: Option<f64>,
    pub reference_iterations: Option<f64>,
    pub reference_iterations_max: Option<u32>,
    pub reference_capped_steps: Option<usize>,
    pub reference_residual: Option<f64>,
    /// Median time of the step's local steps (ms).
    pub local_ms_per_step: f64,
    /// Median time of the step's global solves (ms).
    pub global_ms_per_step: f64,
    /// Mean iterations of the iterative global solves per step (Jacobi for
    /// dd; 0 for direct without contacts).
    pub global_iterations: f64,
    /// Largest relative residual of the iterative global solves.
    pub global_residual: f64,
    /// Mean local steps per step (PD iterations + 1 + rejected Anderson
    /// iterates).
    pub local_steps: f64,
    pub peak_rss_mb: Option<f64>,
}

/// One run of the bench scene: the positions after every step and the
/// step statistics.
struct SimRun {
    frames: Vec<Vec<Vec3>>,
    stats: Vec<crate::sim::pd::StepStats>,
    prepare_ms: f64,
    backend: &'static str,
}

/// `bench sim`: an analytic knit swatch of about `--tets` tets in the scene
/// of [`SimScene`], timed at the asked PD settings and compared with the
/// same scene converged to the reference tolerance.
pub fn sim(a: &SimRequest) -> Result<SimBench, BenchError> {
    use crate::embed::{embed as run_embed, EmbedParams};
    use crate::geom::{DEFAULT_GAMMA_S, DEFAULT_GAMMA_V};
    use crate::pipeline::simulate::{attach_backend, global_solver};
    use crate::sim::pd::{PdParams, PdSolver, STANDARD_GRAVITY};
    let mut global = global_solver(a.solver);
    if let crate::sim::pd::GlobalSolver::DomainDecomposed(dp) = &mut global {
        if let Some(t) = a.dd_tolerance {
            dp.tolerance = t;
        }
        if let Some(i) = a.dd_interiors {
            dp.interiors = i;
        }
    }
    let solver_name = global.name();
    // About 1.7 tets per yarn point at the default voxel size (the
    // embedding table of docs/performance.md); one correction from the first embedding's ratio.
    let mut points = (a.tets as f64 / 1.7).max(800.0) as usize;
    let mut yarns = knit_swatch_with_points(points);
    let mut e = run_embed(&yarns, &EmbedParams::default())?;
    let ratio = a.tets as f64 / e.mesh.num_tets().max(1) as f64;
    if !(0.85..=1.15).contains(&ratio) {
        points = ((points as f64) * ratio).max(800.0) as usize;
        yarns = knit_swatch_with_points(points);
        e = run_embed(&yarns, &EmbedParams::default())?;
    }
    let mesh = &e.mesh;
    let nt = mesh.num_tets();
    let h = e.stats.voxel_size;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in &mesh.nodes {
        lo = lo.min(p[0]);
        hi = hi.max(p[0]);
    }
    let left: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][0] <= lo + 0.5 * h)
        .collect();
    let right: Vec<usize> = match a.scene {
        SimScene::Drape => Vec::new(),
        SimScene::Stretch => (0..mesh.num_nodes())
            .filter(|&i| mesh.nodes[i][0] >= hi - 0.5 * h)
            .collect(),
    };
    let pinned: Vec<usize> = left.iter().chain(&right).copied().collect();
    let steps = a.steps.max(1);
    let speed = 0.2 * (hi - lo) / (steps as f64 * a.dt);
    let gravity = match a.scene {
        SimScene::Drape => [0.0, 0.0, -STANDARD_GRAVITY],
        SimScene::Stretch => [0.0, -STANDARD_GRAVITY, 0.0],
    };
    let defaults = PdParams::default();
    let params = PdParams {
        dt: a.dt,
        gravity,
        mass_damping: 2.0,
        global,
        max_iterations: a.pd_iterations.unwrap_or(defaults.max_iterations),
        tolerance: a.tolerance.unwrap_or(defaults.tolerance),
        anderson_window: a.anderson.unwrap_or(defaults.anderson_window),
        ..defaults
    };
    let run = |params: PdParams, backend: BackendChoice| -> Result<SimRun, BenchError> {
        let t = Instant::now();
        let mut solver = PdSolver::new(
            mesh,
            &e.node_mass,
            &vec![DEFAULT_GAMMA_S; nt],
            &vec![DEFAULT_GAMMA_V; nt],
            &pinned,
            params,
        )?;
        let backend = attach_backend(&mut solver, backend)?;
        let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut x = mesh.nodes.clone();
        let mut v = vec![[0.0; 3]; x.len()];
        let (mut frames, mut stats) = (Vec::with_capacity(steps), Vec::with_capacity(steps));
        for s in 1..=steps {
            let dx = speed * a.dt * s as f64;
            let pins: Vec<[f64; 3]> = left
                .iter()
                .map(|&i| mesh.nodes[i])
                .chain(right.iter().map(|&i| {
                    let p = mesh.nodes[i];
                    [p[0] + dx, p[1], p[2]]
                }))
                .collect();
            stats.push(solver.step(&mut x, &mut v, &pins)?);
            frames.push(x.clone());
        }
        Ok(SimRun {
            frames,
            stats,
            prepare_ms,
            backend,
        })
    };
    let timed = run(params, a.backend)?;
    // The reference: the same scene on the CPU, converged.
    let reference = if a.reference {
        let tolerance = a.reference_tolerance.unwrap_or(REFERENCE_TOLERANCE);
        let r = run(
            PdParams {
                tolerance,
                max_iterations: REFERENCE_MAX_ITERATIONS,
                ..params
            },
            BackendChoice::Cpu,
        )?;
        Some((tolerance, r))
    } else {
        None
    };
    use crate::geom::dist;
    let (deviation, displacement) = match &reference {
        Some((_, r)) => {
            let mut far = 0.0f64;
            let mut moved = 0.0f64;
            for (f, g) in timed.frames.iter().zip(&r.frames) {
                for i in 0..f.len() {
                    far = far.max(dist(f[i], g[i]));
                    moved = moved.max(dist(g[i], mesh.nodes[i]));
                }
            }
            (Some(far / moved.max(f64::MIN_POSITIVE)), Some(moved))
        }
        None => (None, None),
    };
    let totals = |stats: &[crate::sim::pd::StepStats]| {
        let mut t = crate::sim::shot::LoopStats::default();
        stats.iter().for_each(|st| t.add(st));
        t
    };
    let st = &timed.stats;
    let timed_totals = totals(st);
    let reference_totals = reference.as_ref().map(|(_, r)| totals(&r.stats));
    let mean = |f: &dyn Fn(&crate::sim::pd::StepStats) -> f64| {
        st.iter().map(f).sum::<f64>() / steps as f64
    };
    let r = SimBench {
        bench: "sim",
        input: format!(
            "built-in analytic knit swatch ({} points)",
            yarns.num_points()
        ),
        scene: match a.scene {
            SimScene::Drape => {
                "drape: the low-x edge pinned, gravity along -z (normal to the swatch)"
            }
            SimScene::Stretch => {
                "stretch: both x edges pinned, one pulled 20% of the width over the run, gravity"
            }
        },
        yarn_points: yarns.num_points(),
        voxel_size: h,
        tets: nt,
        nodes: mesh.num_nodes(),
        pinned: pinned.len(),
        steps,
        dt: a.dt,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        solver: solver_name,
        backend: timed.backend,
        prepare_ms: timed.prepare_ms,
        ms_per_step: median(timed_totals.step_ms.clone()),
        pd_iterations: timed_totals.iterations_mean(),
        pd_iterations_max: timed_totals.iterations_max,
        tolerance: params.tolerance,
        max_iterations: params.max_iterations,
        capped_steps: timed_totals.capped_steps,
        convergence: timed_totals.convergence_max,
        residual: timed_totals.residual_max,
        deviation,
        displacement_m: displacement,
        reference_tolerance: reference.as_ref().map(|r| r.0),
        reference_iterations: reference_totals.as_ref().map(|t| t.iterations_mean()),
        reference_iterations_max: reference_totals.as_ref().map(|t| t.iterations_max),
        reference_capped_steps: reference_totals.as_ref().map(|t| t.capped_steps),
        reference_residual: reference_totals.as_ref().map(|t| t.residual_max),
        local_ms_per_step: median(st.iter().map(|s| s.local_ms).collect()),
        global_ms_per_step: median(st.iter().map(|s| s.global_ms).collect()),
        global_iterations: mean(&|s| f64::from(s.global_iterations)),
        global_residual: st.iter().map(|s| s.global_residual).fold(0.0, f64::max),
        local_steps: mean(&|s| f64::from(s.local_steps())),
        peak_rss_mb: peak_rss_mb(),
    };
    Ok(r)
}

/// `bench yls`: the yarn-level simulator on a generated swatch of about
/// `--vertices` vertices (courses along x) or on `--input`, optionally
/// relaxed into contact and stretched quasi-statically first, then both x
/// ends clamped and pulled 30% further apart over 1 s
/// ([`crate::yarn::sim::stretch_scene`]).
pub fn yls(a: &YlsRequest) -> Result<YlsBench, BenchError> {
    let (mut yarns, input) = match &a.input {
        Some(path) => {
            let d = io::read_path(path, &ReadOptions::default())?;
            (d.yarns, path.display().to_string())
        }
        None => generated_swatch(a)?,
    };
    if a.relax && yarns.rest.is_none() {
        let (relaxed, _) = crate::yarn::fabric::relax_into_contact(
            &yarns,
            &Default::default(),
            &Default::default(),
        )?;
        yarns = relaxed;
    }
    let prestretch = if a.prestretch > 0.0 {
        Some(prestretch(&mut yarns, a.prestretch, a.prestretch_steps)?)
    } else {
        None
    };
    let opts = crate::yarn::sim::BenchOptions {
        vertices: yarns.num_points(),
        steps: a.steps.max(1),
        warmup: a.warmup,
        frames: a.frames,
        ..Default::default()
    };
    let r = crate::yarn::sim::bench_yarns(&yarns, false, &opts)?;
    let json = serde_json::json!({
        "bench": "yls",
        "input": input,
        "scene": "stretch: both x ends clamped, pulled 30% apart over 1 s, no gravity",
        "frame_s": crate::yarn::sim::BENCH_FRAME,
        "vertices": r.vertices,
        "us_per_vertex_step": r.us_per_vertex_step,
        "ms_per_frame": r.ms_per_frame,
        "steps_per_frame": r.steps_per_frame,
        "dt_median": r.dt_median,
        "relaxed": yarns.rest.is_some(),
        "prestretch": prestretch,
        "contact_pairs": r.contact_pairs,
        "contacts_per_vertex": r.contacts_per_vertex,
        "candidate_pairs": r.candidate_pairs,
        "min_distance_ratio": r.min_distance_ratio,
        "rebuilds": r.rebuilds,
        "rebuild_ms": r.rebuild_ms,
        "forces_us_per_vertex_step": r.forces_us_per_vertex_step,
        "ms_per_frame_measured": r.ms_per_frame_measured,
        "frames_min_distance_ratio": r.frames_min_distance_ratio,
        "threads": r.threads,
        "steps": r.steps,
    });
    Ok(YlsBench { json, report: r })
}

/// The built-in pattern swatch of about `--vertices` vertices and its name.
fn generated_swatch(a: &YlsRequest) -> Result<(crate::geom::Yarns, String), BenchError> {
    use crate::pipeline::pattern::{generate, PatternJob, PatternSource};
    use crate::yarn::pattern::{Layout, PatternParams};
    let job = |n: usize| PatternJob {
        source: PatternSource::Builtin(a.pattern.clone()),
        layout: Layout {
            courses: n,
            wales: n,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
        params: PatternParams::default(),
        relax: None,
        material: crate::yarn::fabric::FabricParams::default().material(),
    };
    // About 32 vertices per stitch for the knits; one correction from the
    // first swatch's count.
    let mut n = ((a.vertices.max(64) as f64 / 32.0).sqrt().round() as usize).max(2);
    let (mut yarns, mut report) = generate(&job(n))?;
    let ratio = a.vertices as f64 / yarns.num_points().max(1) as f64;
    if !(0.9..=1.1).contains(&ratio) {
        n = ((n as f64) * ratio.sqrt()).round().max(2.0) as usize;
        (yarns, report) = generate(&job(n))?;
    }
    let name = format!(
        "built-in {} swatch, {n} courses x {n} wales ({} curves)",
        a.pattern, report.curves
    );
    Ok((yarns, name))
}

/// What the quasi-static pre-stretch did (the bench's JSON `prestretch`).
#[derive(Debug, Clone, Serialize)]
pub struct PrestretchReport {
    pub stretch: f64,
    pub steps: usize,
    pub force_n: f64,
    pub contacts_per_vertex: f64,
    pub newton_iterations: usize,
    pub seconds: f64,
}

/// Stretches `yarns` (which carry a rest shape) quasi-statically along x by
/// `stretch` in `steps` load steps (the weft stretch test without its
/// hold) and leaves them at the last equilibrium, rest shape kept.
fn prestretch(
    yarns: &mut crate::geom::Yarns,
    stretch: f64,
    steps: usize,
) -> Result<PrestretchReport, BenchError> {
    use crate::yarn::fabric::{stretch_test, Direction, StretchParams};
    if yarns.rest.is_none() {
        return Err(BenchError::Usage(
            "--prestretch needs a swatch with a rest shape (--relax, or a relaxed --input)".into(),
        ));
    }
    let params = StretchParams {
        direction: Direction::Weft,
        max_stretch: stretch,
        steps,
        hold_steps: 0,
        ..StretchParams::default()
    };
    let mut last = None;
    let r = stretch_test(yarns, &Default::default(), &params, &mut |f| {
        last = Some(f.points.to_vec());
        Ok(())
    })?;
    yarns.points =
        last.ok_or_else(|| BenchError::Internal("the pre-stretch gave no frame".into()))?;
    let end = r.points.last().expect("at least the rest point");
    Ok(PrestretchReport {
        stretch,
        steps,
        force_n: end.force_n,
        contacts_per_vertex: end.contacts_per_vertex,
        newton_iterations: r.points.iter().map(|p| p.newton_iterations).sum(),
        seconds: r.seconds,
    })
}

/// What [`bench_slab`] measured.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct SlabBench {
    /// Global solver ("direct", "dd").
    pub solver: &'static str,
    /// Slab size in voxels (x, y, z).
    pub voxels: [usize; 3],
    /// Tets of the slab.
    pub tets: usize,
    /// Nodes of the slab.
    pub nodes: usize,
    /// rayon threads.
    pub threads: usize,
    /// Solver construction (assembly, factor or DD precomputation) (ms).
    pub setup_ms: f64,
    /// Median wall time per step (ms).
    pub ms_per_step: f64,
    /// Mean PD iterations per step.
    pub pd_iterations: f64,
    /// Mean iterative global-solver iterations per step.
    pub global_iterations: f64,
    /// Largest relative residual of the iterative global solves.
    pub global_residual: f64,
    /// Domains (domain-decomposed solver; 0 for direct).
    pub domains: usize,
    /// Size of the reduced system per coordinate (domain-decomposed solver).
    pub reduced_size: usize,
}

/// Benchmark of the time loop on a horizontal slab of about `tets` tets
/// (3 voxels thick, square, 1 cm voxels, 200 kg/m³, γs = γv = 1e4 Pa, the
/// asset defaults) pinned along the x = 0 edge, falling under gravity at
/// Δt = 1/150 s with the default PD parameters and `global` as the solver:
/// `steps` steps (at least 5), median time per step.
pub fn bench_slab(
    tets: usize,
    global: crate::sim::pd::GlobalSolver,
    steps: usize,
) -> Result<SlabBench, crate::sim::SimError> {
    let params = crate::sim::pd::PdParams {
        global,
        report_residual: false,
        ..Default::default()
    };
    bench_slab_thick(tets, 3, params, steps)
}

/// [`bench_slab`] with a slab `thick` voxels thick (at least 1; a 2-voxel
/// slab is closer to a rib swatch's cross-section) and the given parameters
/// (`params.global` is the solver).
pub fn bench_slab_thick(
    tets: usize,
    thick: usize,
    params: crate::sim::pd::PdParams,
    steps: usize,
) -> Result<SlabBench, crate::sim::SimError> {
    let thick = thick.max(1);
    let global = params.global;
    let side = ((tets as f64 / (6.0 * thick as f64)).sqrt().round() as usize).max(1);
    let vox = [side, thick, side];
    let (mesh, mass) = crate::embed::box_mesh(vox, 0.01, 200.0);
    let nt = mesh.num_tets();
    let pins: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][0] < 1e-9)
        .collect();
    let pin_pos: Vec<Vec3> = pins.iter().map(|&i| mesh.nodes[i]).collect();
    let t0 = Instant::now();
    let g = vec![crate::geom::DEFAULT_GAMMA_S; nt];
    let mut solver = crate::sim::pd::PdSolver::new(&mesh, &mass, &g, &g, &pins, params)?;
    let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
    let (mut x, mut v) = (mesh.nodes.clone(), vec![[0.0; 3]; mesh.num_nodes()]);
    let steps = steps.max(5);
    let mut times = Vec::with_capacity(steps);
    let (mut its, mut gits, mut gres) = (0u64, 0u64, 0.0f64);
    for _ in 0..steps {
        let st = solver.step(&mut x, &mut v, &pin_pos)?;
        times.push(st.ms);
        its += st.iterations as u64;
        gits += st.global_iterations as u64;
        gres = gres.max(st.global_residual);
    }
    times.sort_by(f64::total_cmp);
    let dd = solver.dd_stats().unwrap_or_default();
    Ok(SlabBench {
        solver: global.name(),
        voxels: vox,
        tets: nt,
        nodes: mesh.num_nodes(),
        threads: rayon::current_num_threads(),
        setup_ms,
        ms_per_step: times[times.len() / 2],
        pd_iterations: its as f64 / steps as f64,
        global_iterations: gits as f64 / steps as f64,
        global_residual: gres,
        domains: dd.domains,
        reduced_size: dd.reduced_size,
    })
}
