//! `knitvox bench io|embed|sim|yls [--json]`: the arguments of the
//! benchmarks in `pipeline::bench` and how their figures are printed
//! (docs/performance.md; `--json`: schemas/cli-json.md).

use std::path::PathBuf;

use clap::{Args, Subcommand};

use super::args::ReadArgs;
use super::exit::ExitCode;
use crate::pipeline::bench::{self, EmbedRequest, IoRequest, SimRequest, YlsRequest};

#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub target: BenchTarget,
}

#[derive(Debug, Subcommand)]
pub enum BenchTarget {
    /// Read and write times of every yarn format (median of --runs).
    Io(BenchIoArgs),
    /// Embedding and Y2V shape-fit times, mesh size and peak memory.
    Embed(BenchEmbedArgs),
    /// PD time-step cost and accuracy (deviation from a converged run) on a knit swatch of about --tets tets.
    Sim(BenchSimArgs),
    /// Yarn-level simulator step cost on a generated swatch of about --vertices vertices, 30% stretch.
    Yls(BenchYlsArgs),
}

#[derive(Debug, Args)]
pub struct BenchIoArgs {
    /// Input yarn file [default: a built-in analytic swatch of --points points].
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Points of the built-in swatch.
    #[arg(long, default_value_t = 184_000)]
    pub points: usize,
    /// Timed runs per measurement (the median is reported).
    #[arg(long, default_value_t = 7)]
    pub runs: usize,
    /// Print a JSON object.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(Debug, Args)]
pub struct BenchEmbedArgs {
    /// Input yarn file [default: a built-in analytic swatch of --points points].
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Points of the built-in swatch.
    #[arg(long, default_value_t = 50_000)]
    pub points: usize,
    /// Voxel size (m) [default: the embedding's default rule].
    #[arg(long, value_parser = super::parse::parse_positive)]
    pub voxel_size: Option<f64>,
    /// Frames to shape-fit (an analytic stretch of the rest yarns).
    #[arg(long, default_value_t = 8)]
    pub frames: usize,
    /// Timed embedding runs (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Print a JSON object.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(Debug, Args)]
pub struct BenchSimArgs {
    /// Target tet count of the swatch (the analytic knit swatch embedded at the default voxel size).
    #[arg(long, default_value_t = 20_000)]
    pub tets: usize,
    /// Timed time steps (the median is reported).
    #[arg(long, default_value_t = 20)]
    pub steps: usize,
    /// Time step (s), a number or a fraction.
    #[arg(long, default_value = "1/150", value_parser = crate::pipeline::sim_scene::parse_seconds)]
    pub dt: f64,
    /// Scene: drape (one edge pinned, the swatch falls under gravity normal to it) or stretch (both edges pinned, one pulled).
    #[arg(long, value_enum, default_value = "drape")]
    pub scene: bench::SimScene,
    /// Backend.
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: crate::pipeline::sim_scene::BackendChoice,
    /// Global solver.
    #[arg(long, value_enum, default_value = "direct")]
    pub solver: crate::pipeline::sim_scene::SolverChoice,
    /// Most PD iterations per step, the cap on --tolerance [default: the simulator's default].
    #[arg(long, alias = "iterations")]
    pub pd_iterations: Option<u32>,
    /// PD convergence tolerance (docs/guides/shots.md; 0: run --pd-iterations every step) [default: the simulator's default].
    #[arg(long, value_parser = super::parse::parse_non_negative)]
    pub tolerance: Option<f64>,
    /// Skip the converged reference run (no deviation reported; half the time or less).
    #[arg(long)]
    pub no_reference: bool,
    /// PD tolerance of the converged reference run.
    #[arg(long, value_parser = super::parse::parse_positive, default_value_t = bench::REFERENCE_TOLERANCE)]
    pub reference_tolerance: f64,
    /// Relative residual of the domain-decomposed solver's Jacobi iterations [default: its default].
    #[arg(long, value_parser = super::parse::parse_positive)]
    pub dd_tolerance: Option<f64>,
    /// Interiors of the domain-decomposed solver: exact (every interior mode, the default) or modes (VH Eq. 32's 20 lowest per domain).
    #[arg(long, value_parser = ["exact", "modes"])]
    pub dd_interiors: Option<String>,
    /// Anderson acceleration window of the PD iterations (0: plain PD) [default: the simulator's default].
    #[arg(long)]
    pub anderson: Option<usize>,
    /// Print a JSON object.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct BenchYlsArgs {
    /// Target vertex count of the swatch (VH's rib comparison: about 22K vertices, 66K DOFs).
    #[arg(long, default_value_t = 22_000)]
    pub vertices: usize,
    /// Built-in stitch pattern of the swatch.
    #[arg(long, default_value = "rib1x1")]
    pub pattern: String,
    /// Timed time steps (the median is reported).
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Untimed steps first.
    #[arg(long, default_value_t = 20)]
    pub warmup: usize,
    /// Whole 1/150 s frames to run and time after the timed steps.
    #[arg(long, default_value_t = 0)]
    pub frames: usize,
    /// Relax the swatch into contact first (as `knitvox pattern` does; the
    /// simulator then starts from the stored rest shape with its yarns
    /// touching) instead of timing the loose generated curves.
    #[arg(long)]
    pub relax: bool,
    /// Time this yarn file (e.g. a swatch relaxed by `knitvox pattern`)
    /// instead of a generated pattern (`--vertices`, `--pattern` unused).
    #[arg(long)]
    pub input: Option<std::path::PathBuf>,
    /// Stretch the relaxed swatch quasi-statically by this much along x
    /// (the weft stretch test, clamps 8 mm deep) before timing, so the
    /// contacts are engaged (a relaxed rib has ~0.6 contacts per vertex at
    /// rest, ~2 at 30%). 0: none. Needs a rest shape (`--relax` or a
    /// relaxed `--input`).
    #[arg(long, default_value_t = 0.0)]
    pub prestretch: f64,
    /// Load steps of the `--prestretch`.
    #[arg(long, default_value_t = 6)]
    pub prestretch_steps: usize,
    /// Print a JSON object.
    #[arg(long)]
    pub json: bool,
}

pub fn io(a: &BenchIoArgs) -> anyhow::Result<ExitCode> {
    let r = bench::io(&IoRequest {
        input: a.input.clone(),
        read: a.read.options(),
        points: a.points,
        runs: a.runs,
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{}: {} curves, {} points, median of {} runs",
            r.input, r.curves, r.points, r.runs
        );
        if let Some(ms) = r.input_read_ms {
            println!("  read input      {ms:9.2} ms");
        }
        for (name, t) in &r.formats {
            println!(
                "  {name:<6} write {:9.2} ms   read {:9.2} ms   {:>12} bytes",
                t.write_ms, t.read_ms, t.bytes
            );
        }
    }
    Ok(ExitCode::Success)
}

pub fn embed(a: &BenchEmbedArgs) -> anyhow::Result<ExitCode> {
    let r = bench::embed(&EmbedRequest {
        input: a.input.clone(),
        read: a.read.options(),
        points: a.points,
        voxel_size: a.voxel_size,
        frames: a.frames,
        runs: a.runs,
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{}: {} yarn points -> {} nodes, {} tets (h = {:.3e} m); embed {:.1} ms; shape fit: prepare {:.1} ms, {:.2} ms per frame; peak RSS {:.0} MB",
            r.input, r.yarn_points, r.nodes, r.tets, r.voxel_size, r.embed_ms, r.shapefit_prepare_ms, r.shapefit_ms_per_frame,
            r.peak_rss_mb.unwrap_or(f64::NAN)
        );
    }
    Ok(ExitCode::Success)
}

pub fn sim(a: &BenchSimArgs) -> anyhow::Result<ExitCode> {
    let r = bench::sim(&SimRequest {
        tets: a.tets,
        steps: a.steps,
        dt: a.dt,
        scene: a.scene,
        backend: a.backend,
        solver: a.solver,
        pd_iterations: a.pd_iterations,
        tolerance: a.tolerance,
        reference: !a.no_reference,
        reference_tolerance: Some(a.reference_tolerance),
        dd_tolerance: a.dd_tolerance,
        // clap admits only "exact" and "modes".
        dd_interiors: a.dd_interiors.as_deref().map(|i| match i {
            "modes" => crate::sim::dd::Interiors::Modes,
            _ => crate::sim::dd::Interiors::Exact,
        }),
        anderson: a.anderson,
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{} tets, {} nodes ({} pinned): prepare {:.1} ms, {:.2} ms per step (median of {}), {:.1} PD iterations per step (at most {}), residual <= {:.3e} N ({} / {})",
            r.tets, r.nodes, r.pinned, r.prepare_ms, r.ms_per_step, r.steps, r.pd_iterations, r.pd_iterations_max, r.residual, r.solver, r.backend
        );
        match (r.deviation, r.displacement_m) {
            (Some(d), Some(m)) => {
                println!(
                    "deviation from the converged run (tolerance {:e}, {:.1} iterations per step): {:.3}% of the largest displacement ({:.2} mm)",
                    r.reference_tolerance.unwrap_or(f64::NAN),
                    r.reference_iterations.unwrap_or(f64::NAN),
                    100.0 * d,
                    1e3 * m
                );
                println!(
                    "{}",
                    if d <= 0.01 {
                        "verdict: converged steps (within 1% of the motion)"
                    } else {
                        "verdict: NOT converged: the steps are more than 1% of the motion off (raise --pd-iterations or lower --tolerance)"
                    }
                );
            }
            _ => println!("deviation: not measured (--no-reference)"),
        }
    }
    // Warnings reach stderr with --json too.
    if r.capped_steps > 0 {
        eprintln!(
            "warning: {} of {} steps stopped at the cap of {} PD iterations short of the tolerance {:e} (largest convergence measure {:.3e})",
            r.capped_steps, r.steps, r.max_iterations, r.tolerance, r.convergence
        );
    }
    if r.reference_capped_steps.unwrap_or(0) > 0 {
        eprintln!(
            "warning: {} reference steps stopped at the cap short of the reference tolerance: the deviation is measured against an unconverged run",
            r.reference_capped_steps.unwrap_or(0)
        );
    }
    Ok(ExitCode::Success)
}

pub fn yls(a: &BenchYlsArgs) -> anyhow::Result<ExitCode> {
    let b = bench::yls(&YlsRequest {
        vertices: a.vertices,
        pattern: a.pattern.clone(),
        steps: a.steps,
        warmup: a.warmup,
        frames: a.frames,
        relax: a.relax,
        input: a.input.clone(),
        prestretch: a.prestretch,
        prestretch_steps: a.prestretch_steps,
    })?;
    let r = &b.report;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b.json)?);
    } else {
        println!(
            "yls: {} vertices, {:.3} us per vertex per step (median), {:.0} steps per 1/150 s frame, {:.1} ms per frame, {} contact pairs ({:.2} per vertex), min distance / 2r {:.3}",
            r.vertices, r.us_per_vertex_step, r.steps_per_frame, r.ms_per_frame, r.contact_pairs, r.contacts_per_vertex, r.min_distance_ratio
        );
    }
    Ok(ExitCode::Success)
}
