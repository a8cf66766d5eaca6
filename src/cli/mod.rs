//! Command-line interface: clap definitions and the glue from arguments to the
//! library. Only this module and `main` know about processes and terminals.

mod asset;
mod bake;
mod bench;
mod commands;
pub mod exit;
mod fabric_test;
mod fit;
pub mod guard;
mod pattern;
mod run;
mod simulate;
mod train;
mod watch;
mod yarn_material;
use yarn_material::describe_choice;
mod yls;

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use crate::geom::{Units, UpAxis};
use crate::io::{ReadOptions, WriteOptions, DEFAULT_RADIUS_M};

pub use exit::{error_message, exit_code_for, ExitCode};

/// knitvox: yarn-level knitwear to homogenized tetrahedral simulation, for render farms.
#[derive(Debug, Parser)]
#[command(name = "knitvox", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// Memory budget in bytes (suffixes K, M, G, T: 512M, 4G): the most a reader
    /// allocates for what a file declares (compressed HDF5, external glTF buffers,
    /// --tile) [default: a quarter of the physical memory].
    #[arg(long, global = true, value_name = "BYTES", value_parser = guard::parse_bytes)]
    pub max_memory: Option<u64>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Summarise yarn files: format, curves, points, length, bbox, radius, units and axes.
    Inspect(InspectArgs),
    /// Convert a yarn file (or frame sequence) into another format, unit or up axis.
    Convert(ConvertArgs),
    /// Embed yarns in a voxel tet mesh and write a homogenized asset (.vtkhdf).
    Embed(asset::EmbedArgs),
    /// Shape-fit yarn frames (Y2V, VH Eq. 5-6) into an asset's time series.
    Shapefit(asset::ShapefitArgs),
    /// Export an asset's stored steps as per-frame yarn curves (V2Y).
    Export(asset::ExportArgs),
    /// Fit per-element materials (VH §6) of an asset to yarn-level training poses.
    Fit(fit::FitArgs),
    /// Compare an asset's homogenized motion with the yarn-level run of a yls scene.
    Validate(fit::ValidateArgs),
    /// Bake a glTF character's animation into an HDF5 character cache (schemas/character-hdf5.md).
    Bake(bake::BakeArgs),
    /// Simulate a shot of an asset (scene file or character) and write frames (asset time series, yarn curves).
    Simulate(simulate::SimulateArgs),
    /// Run a job manifest's stages (embed, shot, export), skipping cached ones (schemas/job.md).
    Run(run::RunArgs),
    /// Watch a folder: run the job manifests and yarn files dropped into ROOT/inbox (schemas/watch.md).
    Watch(watch::WatchArgs),
    /// Run a yarn-level scene (schemas/yls-scene.md) and write its frames (knitvox HDF5).
    Yls(yls::YlsArgs),
    /// Run one training pose (VH §8.6) quasi-statically on an asset's rest yarns (knitvox HDF5 frames for `fit`).
    Train(train::TrainArgs),
    /// Run a benchmark and print its figures (`--json` for machine-readable output).
    Bench(BenchArgs),
    /// Generate a stitch pattern (built-in or K/P grid) as yarn curves: a flat swatch or a tube.
    Pattern(pattern::PatternArgs),
    /// Fabric tests of Sperl 2022 §4 on a yarn swatch: stretch, bend (pear loop), hang.
    #[command(subcommand)]
    FabricTest(fabric_test::FabricTestKind),
    /// Run the built-in demo job: make an example swatch, inspect it, convert it to every format.
    Demo(DemoArgs),
    /// Print a shell completion script.
    Completions {
        /// The shell: bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
}

/// How to interpret input files.
#[derive(Debug, Clone, Args)]
pub struct ReadArgs {
    /// Unit of the input: mm, cm, m or metres per unit. Overrides what the file declares
    /// [default: the file's (glTF, HDF5, pyp: m); unitless bcc, obj, poly, ply: m, reported as assumed].
    #[arg(long, value_name = "mm|cm|m|SCALE")]
    pub units: Option<Units>,
    /// Up axis of the input. Overrides what the file declares
    /// [default: the file's (BCC header, glTF and HDF5 +Y, pyp +Z); others: y, reported as assumed].
    #[arg(long, value_name = "y|z")]
    pub up_axis: Option<UpAxis>,
    /// Repeat a periodic .pyp tile N x M times along its two periods.
    #[arg(long, value_name = "NxM", default_value = "1x1", value_parser = parse_tile)]
    pub tile: [usize; 2],
    /// Polyline samples per span of BCC spline curves (C0, BS); 1 keeps the C0 control points.
    #[arg(long, value_name = "K", value_parser = guard::parse_spline_samples)]
    pub spline_samples: Option<usize>,
    /// Yarn radius in metres for files without one (or for all, with --override-radius).
    #[arg(long, value_name = "METRES", default_value_t = DEFAULT_RADIUS_M, value_parser = guard::parse_positive)]
    pub radius: f64,
    /// Use --radius even where the file gives radii.
    #[arg(long)]
    pub override_radius: bool,
}

impl ReadArgs {
    pub fn options(&self) -> ReadOptions {
        ReadOptions {
            units: self.units,
            up_axis: self.up_axis,
            spline_samples: self.spline_samples,
            tile: self.tile,
            radius: self.radius,
            override_radius: self.override_radius,
            ..ReadOptions::default()
        }
    }
}

fn parse_tile(s: &str) -> Result<[usize; 2], String> {
    let (a, b) = s
        .to_ascii_lowercase()
        .split_once('x')
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .ok_or_else(|| format!("'{s}': expected NxM, e.g. 3x3"))?;
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=10_000).contains(n))
    };
    match (parse(&a), parse(&b)) {
        (Some(n), Some(m)) => Ok([n, m]),
        _ => Err(format!(
            "'{s}': expected NxM with N and M between 1 and 10000"
        )),
    }
}

#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Yarn files (a `name.####.ext` pattern reads a frame sequence).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Print one JSON array instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(Debug, Args)]
pub struct ConvertArgs {
    /// Input yarn file or `name.####.ext` frame sequence.
    pub input: PathBuf,
    /// Output file; `name.####.ext` writes one file per frame; .h5 holds all frames.
    pub output: PathBuf,
    #[command(flatten)]
    pub read: ReadArgs,
    /// Unit of the written coordinates for bcc, obj, ply (glTF and HDF5 are always metres).
    #[arg(long, value_name = "mm|cm|m|SCALE", default_value = "m")]
    pub out_units: Units,
    /// Up axis of the written coordinates for bcc, obj, ply (glTF and HDF5 are always +Y up).
    #[arg(long, value_name = "y|z", default_value = "y")]
    pub out_up_axis: UpAxis,
    /// First frame number of a written sequence (-1e9 to 1e9).
    #[arg(long, default_value_t = WriteOptions::default().first_frame, allow_negative_numbers = true,
          value_parser = clap::value_parser!(i64).range(-crate::geom::MAX_FRAME_NUMBER..=crate::geom::MAX_FRAME_NUMBER))]
    pub first_frame: i64,
    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

impl ConvertArgs {
    pub fn write_options(&self) -> WriteOptions {
        WriteOptions {
            units: self.out_units,
            up_axis: self.out_up_axis,
            first_frame: self.first_frame,
        }
    }
}

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
    /// PD time-step cost of a stretched knit swatch of about --tets tets.
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
    #[arg(long, value_parser = guard::parse_positive)]
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
    /// Backend.
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: crate::pipeline::sim_scene::BackendChoice,
    /// Global solver.
    #[arg(long, value_enum, default_value = "direct")]
    pub solver: crate::pipeline::sim_scene::SolverChoice,
    /// Most PD iterations per step [default: the simulator's default].
    #[arg(long)]
    pub pd_iterations: Option<u32>,
    /// Relative residual of the domain-decomposed solver's Jacobi iterations [default: its default].
    #[arg(long, value_parser = guard::parse_positive)]
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

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, short, default_value = "demo-out")]
    pub out: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    crate::io::set_max_memory(cli.max_memory.unwrap_or_else(guard::default_max_memory));
    guard::check(&cli)?;
    match cli.command {
        Command::Inspect(a) => commands::inspect(&a),
        Command::Convert(a) => commands::convert(&a),
        Command::Embed(a) => asset::embed(&a),
        Command::Shapefit(a) => asset::shapefit(&a),
        Command::Export(a) => asset::export(&a),
        Command::Fit(a) => fit::fit(&a),
        Command::Validate(a) => fit::validate(&a),
        Command::Simulate(a) => simulate::simulate(&a),
        Command::Bake(a) => bake::bake(&a),
        Command::Run(a) => run::run(&a),
        Command::Watch(a) => watch::watch(&a),
        Command::Bench(a) => match a.target {
            BenchTarget::Io(b) => bench::io(&b),
            BenchTarget::Embed(b) => bench::embed(&b),
            BenchTarget::Sim(b) => bench::sim(&b),
            BenchTarget::Yls(b) => bench::yls(&b),
        },
        Command::Pattern(a) => pattern::pattern(&a),
        Command::Yls(a) => yls::yls(&a),
        Command::Train(a) => train::train(&a),
        Command::FabricTest(k) => fabric_test::fabric_test(&k),
        Command::Demo(a) => commands::demo(&a),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            clap_complete::generate(
                shell,
                &mut Cli::command(),
                "knitvox",
                &mut std::io::stdout(),
            );
            Ok(ExitCode::Success)
        }
    }
}

/// Prints warnings on stderr (`warning: ...`) and returns them for a
/// `--json` report's `warnings` array.
pub(crate) fn warn_all(warnings: Vec<String>) -> Vec<String> {
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    warnings
}

/// How a [`Console`] shows frame progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ProgressMode {
    /// Nothing.
    Off,
    /// A progress bar on stderr (a terminal).
    Bar,
    /// A plain line per frame on stderr (no terminal: farm logs).
    Lines,
    /// A JSON line per frame on stdout (`--json`).
    Json,
}

impl ProgressMode {
    /// `--progress` / `--no-progress` of a command whose stdout holds only
    /// its report (`--json` or not): a bar on a terminal (or with
    /// `--progress`), else a plain line per frame on stderr (farm logs),
    /// nothing with `--no-progress`.
    pub fn on_stderr(progress: bool, no_progress: bool) -> ProgressMode {
        use std::io::IsTerminal;
        if no_progress {
            ProgressMode::Off
        } else if progress || std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        }
    }

    /// `--json`: JSON lines; else a bar on a terminal, plain lines without.
    pub fn of(json: bool) -> ProgressMode {
        use std::io::IsTerminal;
        if json {
            ProgressMode::Json
        } else if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        }
    }
}

/// The CLI's [`crate::pipeline::Observer`]: warnings on stderr
/// (`warning: ...`, kept for a `--json` report's `warnings` array) and
/// frame progress ([`ProgressMode`]).
pub(crate) struct Console {
    pub warnings: Vec<String>,
    bar: Option<indicatif::ProgressBar>,
    mode: ProgressMode,
    label: String,
}

impl Console {
    /// A console; with `show`, a progress bar of `frames` frames labelled
    /// `label` (`label {bar} pos/len frames [elapsed < eta]`).
    pub fn new(show: bool, frames: usize, label: &str) -> Console {
        let mode = if show {
            ProgressMode::Bar
        } else {
            ProgressMode::Off
        };
        Console::with_mode(mode, frames, label)
    }

    /// A console showing progress as `mode` says.
    /// Runs `stage` with this console as its observer; returns its result
    /// and the warnings, with the progress bar finished (so a report can be
    /// printed after it).
    pub fn run<S: crate::pipeline::Stage>(
        mut self,
        stage: &S,
    ) -> (Result<S::Report, crate::pipeline::Error>, Vec<String>) {
        let result = stage.run(&mut self);
        (result, std::mem::take(&mut self.warnings))
    }

    pub fn with_mode(mode: ProgressMode, frames: usize, label: &str) -> Console {
        Console {
            warnings: Vec::new(),
            bar: (mode == ProgressMode::Bar).then(|| frame_bar(frames, label)),
            mode,
            label: label.to_string(),
        }
    }
}

impl Drop for Console {
    fn drop(&mut self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

impl crate::pipeline::Observer for Console {
    fn warning(&mut self, message: &str) {
        eprintln!("warning: {message}");
        self.warnings.push(message.to_string());
    }
    fn frames(&mut self, done: usize, total: usize) {
        if let Some(b) = &self.bar {
            b.set_length(total as u64);
            b.set_position(done as u64);
        }
    }
    fn frame(&mut self, p: &crate::pipeline::FrameProgress) {
        match self.mode {
            ProgressMode::Off => {}
            ProgressMode::Bar => self.frames(p.done, p.total),
            ProgressMode::Json => print_event("frame", p),
            ProgressMode::Lines => {
                // Statistics a stage does not have are left out.
                let opt = |x: Option<f64>, what: &str, unit: &str| {
                    x.map_or(String::new(), |x| format!(", {what} {x:.3e} {unit}"))
                };
                eprintln!(
                    "{}: frame {} ({}/{}) {:.0} ms{}{}",
                    self.label,
                    p.frame,
                    p.done,
                    p.total,
                    p.ms,
                    opt(p.residual, "residual", "N"),
                    opt(p.penetration_m, "penetration", "m")
                );
            }
        }
    }
    fn iteration(&mut self, p: &crate::fit::elastic::FitProgress) {
        match self.mode {
            ProgressMode::Off | ProgressMode::Bar => {}
            ProgressMode::Json => print_event("iteration", p),
            ProgressMode::Lines => eprintln!(
                "{}: {} {} iteration {} ({}) loss {:.4e} m^3, {:.0} ms",
                self.label, p.sample, p.stage, p.iteration, p.method, p.loss, p.ms
            ),
        }
    }
}

/// One progress object as a JSON line on stdout with its `event` name.
fn print_event(event: &str, p: &impl serde::Serialize) {
    use std::io::Write;
    let mut v = serde_json::to_value(p).unwrap_or_default();
    if let Some(o) = v.as_object_mut() {
        o.insert("event".into(), event.into());
    }
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{v}");
    let _ = out.flush();
}

/// SIGTERM while `run` or `simulate` works: see [`relay_sigterm`].
static INTERRUPT: crate::pipeline::Interrupt = crate::pipeline::Interrupt::new();

extern "C" fn on_sigterm(_: libc::c_int) {
    if !INTERRUPT.request() {
        // No stage can stop cleanly: die of SIGTERM as without a handler.
        // SAFETY: signal and raise are async-signal-safe.
        unsafe {
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
            libc::raise(libc::SIGTERM);
        }
    }
}

/// From here on SIGTERM makes a running (armed) shot checkpoint and stop
/// (exit 75, resumed by the next run); otherwise it ends the process.
pub(crate) fn relay_sigterm() -> &'static crate::pipeline::Interrupt {
    #[cfg(unix)]
    // SAFETY: installs an async-signal-safe handler (atomics, signal, raise).
    unsafe {
        libc::signal(
            libc::SIGTERM,
            on_sigterm as extern "C" fn(libc::c_int) as libc::sighandler_t,
        );
    }
    &INTERRUPT
}

/// Prints a `--json` report as the last line of stdout (after any
/// progress lines), with `"event": "report"` and `extra` fields.
pub(crate) fn print_json_report(
    report: &impl serde::Serialize,
    extra: &[(&str, serde_json::Value)],
) -> anyhow::Result<()> {
    let mut v = serde_json::to_value(report)?;
    if let Some(o) = v.as_object_mut() {
        o.insert("event".into(), "report".into());
        for (k, x) in extra {
            o.insert((*k).into(), x.clone());
        }
    }
    println!("{}", serde_json::to_string(&v)?);
    Ok(())
}

/// Whether a raw command line asks for `--json` (before any `--`): errors
/// are then a JSON object on stdout, for every command, parse errors too.
pub fn wants_json(args: impl IntoIterator<Item = std::ffi::OsString>) -> bool {
    args.into_iter()
        .skip(1)
        .take_while(|a| a != "--")
        .any(|a| a == "--json")
}

fn frame_bar(frames: usize, label: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new(frames as u64);
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{label} {{bar:40}} {{pos}}/{{len}} frames [{{elapsed_precise}} < {{eta}}]"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }

    /// Defaults written as text in clap attributes are the library's.
    #[test]
    fn textual_defaults_are_the_librarys() {
        let cli = Cli::try_parse_from(["knitvox", "bench", "sim"]).unwrap();
        let Command::Bench(BenchArgs {
            target: BenchTarget::Sim(b),
        }) = cli.command
        else {
            panic!("not bench sim")
        };
        assert_eq!(b.dt, crate::sim::pd::PdParams::default().dt);
        assert_eq!(
            b.backend,
            crate::pipeline::sim_scene::BackendChoice::default()
        );
        assert_eq!(
            b.solver,
            crate::pipeline::sim_scene::SolverChoice::default()
        );
        let cli = Cli::try_parse_from(["knitvox", "convert", "a.ply", "b.ply"]).unwrap();
        let Command::Convert(c) = cli.command else {
            panic!("not convert")
        };
        assert_eq!(c.write_options(), WriteOptions::default());
        let cli = Cli::try_parse_from(["knitvox", "export", "a.vtkhdf", "-o", "out"]).unwrap();
        let Command::Export(e) = cli.command else {
            panic!("not export")
        };
        let w = WriteOptions::default();
        assert_eq!((e.out_units, e.out_up_axis), (w.units, w.up_axis));
        let cli = Cli::try_parse_from([
            "knitvox",
            "simulate",
            "a.vtkhdf",
            "--character",
            "c.glb",
            "--frames",
            "1",
            "-o",
            "o.vtkhdf",
        ])
        .unwrap();
        let Command::Simulate(a) = cli.command else {
            panic!("not simulate")
        };
        let scene = simulate::scene_of(&a).unwrap();
        let c = scene.character.unwrap();
        let d = crate::pipeline::sim_scene::CharacterSection::default();
        assert_eq!((c.scale, c.pin_distance), (d.scale, d.pin_distance));
        assert_eq!(
            scene.simulation,
            crate::pipeline::sim_scene::SimulationSection::default()
        );
    }

    #[test]
    fn tile_parsing() {
        assert_eq!(parse_tile("3x4"), Ok([3, 4]));
        assert_eq!(parse_tile("2X2"), Ok([2, 2]));
        assert!(parse_tile("0x3").is_err());
        assert!(parse_tile("3").is_err());
        assert!(parse_tile("99999999999999999999x1").is_err());
    }
}
