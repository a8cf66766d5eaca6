//! `knitvox simulate`: a shot of a homogenized asset under a scene file or a
//! character.

use std::path::PathBuf;

use clap::Args;

use super::parse::{parse_non_negative, parse_positive, ValueError};
use super::ExitCode;
use crate::anim::pins::DEFAULT_PIN_DISTANCE;
use crate::geom::{FrameSpec, Units, UpAxis, Vec3};
use crate::io::WriteOptions;
use crate::pipeline::asset::check_asset_ext;
use crate::pipeline::sim_scene::{
    parse_seconds, BackendChoice, CharacterSection, Scene, Seconds, SolverChoice,
};
use crate::pipeline::simulate::{
    self as stage, ChunkOptions, ChunkedShotJob, ShotJob, ShotRequest,
};

fn parse_vec3(s: &str) -> Result<Vec3, ValueError> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| ValueError::Vec3Syntax {
            text: s.to_string(),
        })?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(ValueError::Vec3Values {
            text: s.to_string(),
        }),
    }
}

// The choices are clap value enums here, in the CLI layer, so that --help
// and shell completion list them; the pipeline keeps its own FromStr for
// scene files.
impl clap::ValueEnum for BackendChoice {
    fn value_variants<'a>() -> &'a [Self] {
        &[BackendChoice::Cpu, BackendChoice::Gpu, BackendChoice::Auto]
    }
    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            BackendChoice::Cpu => "the CPU (f64)",
            BackendChoice::Gpu => "a wgpu adapter (f32); exit 69 without one",
            BackendChoice::Auto => "a hardware GPU when there is one, else the CPU",
        };
        Some(clap::builder::PossibleValue::new(self.name()).help(help))
    }
}

impl clap::ValueEnum for SolverChoice {
    fn value_variants<'a>() -> &'a [Self] {
        &[SolverChoice::Direct, SolverChoice::Dd]
    }
    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            SolverChoice::Direct => "sparse Cholesky of the global matrix",
            SolverChoice::Dd => "domain-decomposed subspace + Chebyshev-Jacobi",
        };
        Some(clap::builder::PossibleValue::new(self.name()).help(help))
    }
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("driver").required(true).args(["scene", "character"])))]
pub struct SimulateArgs {
    /// The homogenized asset (.vtkhdf); its materials and masses are used, it is not modified.
    pub asset: PathBuf,
    /// Scene file (TOML; schemas/sim-scene.md): time stepping, pins, colliders, character.
    #[arg(long, value_name = "SCENE.toml")]
    pub scene: Option<PathBuf>,
    /// Character (glTF/GLB with a skin, or an HDF5 character cache: schemas/character-hdf5.md):
    /// the garment is pinned to it and collides with it.
    #[arg(long, value_name = "CHAR.glb", conflicts_with = "scene")]
    pub character: Option<PathBuf>,
    /// Animation of --character [default: the file's first].
    #[arg(long, requires = "character")]
    pub animation: Option<String>,
    /// Garment nodes within this distance (m) of the bind-pose body are pinned to it.
    #[arg(long, value_name = "METRES", requires = "character", default_value_t = DEFAULT_PIN_DISTANCE, value_parser = parse_non_negative)]
    pub pin_distance: f64,
    /// Metres per unit of --character (glTF is metres; Fox.glb needs about 0.0025 for a
    /// fox of 20 cm height under the demo swatch, 0.01 for 80 cm).
    #[arg(long, value_name = "SCALE", requires = "character", default_value_t = CharacterSection::default().scale, value_parser = parse_positive)]
    pub character_scale: f64,
    /// Lay the garment flat on the body over this joint (glTF node name, e.g. b_Spine02_03).
    #[arg(long, value_name = "NODE", requires = "character")]
    pub fit_joint: Option<String>,
    /// Rotate the garment about its centre (degrees about x, then y, then z).
    #[arg(long, value_name = "RX,RY,RZ", value_parser = parse_vec3, conflicts_with = "scene", allow_hyphen_values = true)]
    pub garment_rotate: Option<Vec3>,
    /// Move the garment (m), after --fit-joint.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, conflicts_with = "scene", allow_hyphen_values = true)]
    pub garment_offset: Option<Vec3>,
    /// Frames to write: `1-24`, `1001-1100x5`, `1,5,7-20` (frame f is at (f - first)/fps s of shot time).
    #[arg(long = "frames", value_name = "SPEC")]
    pub frames: FrameSpec,
    /// Largest time step (s), a number or a fraction [default: the scene's, else 1/150].
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds)]
    pub dt: Option<f64>,
    /// Frames per second [default: the scene's, else 24].
    #[arg(long, value_parser = parse_positive)]
    pub fps: Option<f64>,
    /// Pre-roll (s) blending the character from bind pose into the first frame [default: 0.2 with a character].
    #[arg(long, value_name = "SECONDS", value_parser = parse_non_negative)]
    pub preroll: Option<f64>,
    /// Backend [default: the scene's, else auto].
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
    /// Global solver [default: the scene's, else direct].
    #[arg(long, value_enum)]
    pub solver: Option<SolverChoice>,
    /// Output asset (.vtkhdf): a copy of ASSET with the simulated frames as its time series.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Yarn curves per frame (V2Y): `name.####.ext` (ply, bcc, obj, gltf, glb) or one `.h5`.
    #[arg(long, value_name = "FILE")]
    pub yarns_out: Option<PathBuf>,
    /// Unit of written bcc, obj, ply coordinates.
    #[arg(long, value_name = "mm|cm|m|SCALE", default_value = "m")]
    pub out_units: Units,
    /// Up axis of written bcc, obj, ply coordinates.
    #[arg(long, value_name = "y|z", default_value = "y")]
    pub out_up_axis: UpAxis,
    /// Checkpoint the shot every N frames and at its last frame (schemas/checkpoint.md), so
    /// that --resume or the next chunk continues it; frame files appear as they are computed.
    /// 0: no checkpoints, and the outputs appear all at once or not at all.
    #[arg(long, value_name = "N", default_value_t = stage::DEFAULT_CHECKPOINT_EVERY)]
    pub checkpoint_every: usize,
    /// Folder of the checkpoints [default: the folder of -o].
    #[arg(long, value_name = "DIR")]
    pub checkpoint_dir: Option<PathBuf>,
    /// Continue from this checkpoint (refused when it is of another shot or lies past --frames).
    #[arg(long, value_name = "FILE")]
    pub checkpoint: Option<PathBuf>,
    /// The shot's first frame when --frames is a later chunk of it (the chunk then continues the
    /// previous chunk's checkpoint, or is refused) [default: the first of --frames, or the start
    /// of an earlier chunk whose checkpoint is in the checkpoint folder].
    #[arg(long, value_name = "FRAME", allow_hyphen_values = true)]
    pub shot_start: Option<i64>,
    /// Continue a killed or interrupted run from the latest checkpoint of this shot (none: start
    /// as usual). SIGTERM checkpoints after the current step and exits 75.
    #[arg(long)]
    pub resume: bool,
    /// As --resume, but a checkpoint of this shot that cannot be used (damaged, truncated, of
    /// another version or shot) is skipped with a warning instead of failing (exit 65): the shot
    /// then continues from an older checkpoint or starts from rest.
    #[arg(long)]
    pub resume_or_restart: bool,
    /// Print one JSON line per frame and the report as the last line (errors as JSON too).
    #[arg(long)]
    pub json: bool,
}

/// The scene of a command line: the file's, or one built from --character.
pub fn scene_of(a: &SimulateArgs) -> anyhow::Result<Scene> {
    let mut scene = match (&a.scene, &a.character) {
        (Some(p), _) => stage::read_scene(p)?,
        (None, Some(c)) => Scene {
            character: Some(CharacterSection {
                file: c.clone(),
                animation: a.animation.clone(),
                scale: a.character_scale,
                pin_distance: a.pin_distance,
                fit_joint: a.fit_joint.clone(),
                ..CharacterSection::default()
            }),
            ..Scene::default()
        },
        (None, None) => unreachable!("clap requires --scene or --character"),
    };
    if let Some(r) = a.garment_rotate {
        scene.garment.rotate_deg = r;
    }
    if let Some(t) = a.garment_offset {
        scene.garment.translate = t;
    }
    let s = &mut scene.simulation;
    if let Some(dt) = a.dt {
        s.dt = Seconds(dt);
    }
    if let Some(f) = a.fps {
        s.fps = f;
    }
    if let Some(p) = a.preroll {
        s.preroll = Some(p);
    }
    if let Some(b) = a.backend {
        s.backend = b;
    }
    if let Some(v) = a.solver {
        s.solver = v;
    }
    Ok(scene)
}

pub fn simulate(a: &SimulateArgs) -> anyhow::Result<ExitCode> {
    // Cheap checks of the command line first, before the asset is read.
    check_asset_ext(&a.asset)?;
    check_asset_ext(&a.output)?;
    let scene = scene_of(a)?;
    check_step_count(a, &scene)?;
    check_character_names(a)?;
    let shot = ShotJob {
        asset: a.asset.clone(),
        scene,
        request: ShotRequest {
            frames: a.frames.frames(),
            output: a.output.clone(),
            yarns_out: a.yarns_out.clone(),
            write: WriteOptions {
                units: a.out_units,
                up_axis: a.out_up_axis,
                first_frame: 1,
            },
            command: super::asset::command_line(),
        },
    };
    // A resumable shot checkpoints and stops on SIGTERM.
    let interrupt = (a.checkpoint_every > 0).then(super::console::relay_sigterm);
    let _armed = interrupt.map(|i| i.arm());
    let job = ChunkedShotJob {
        chunk: ChunkOptions {
            checkpoint_every: a.checkpoint_every,
            checkpoint_dir: a.checkpoint_dir.clone(),
            checkpoint: a.checkpoint.clone(),
            shot_start: a.shot_start,
            resume: a.resume || a.resume_or_restart,
            resume_or_restart: a.resume_or_restart,
            stop: interrupt.map(|i| i.flag()),
        },
        shot,
    };
    let console = super::console::Console::with_mode(
        super::console::ProgressMode::of(a.json),
        job.shot.request.frames.len(),
        "simulating",
    );
    let (result, warnings) = console.run(&job);
    let r = result?;
    if a.json {
        super::console::print_json_report(&r, &[("warnings", warnings.into())])?;
    } else {
        println!(
            "{}: {} frames ({}-{}, {} fps), {} steps of {:.5} s ({} per frame, {} pre-roll), {} nodes, {} tets, {} pinned ({} to the body); {} / {}",
            r.output.display(),
            r.frames,
            r.first_frame,
            r.last_frame,
            r.fps,
            r.steps,
            r.dt,
            r.steps_per_frame,
            r.preroll_steps,
            r.nodes,
            r.tets,
            r.pinned_scripted + r.pinned_body,
            r.pinned_body,
            r.solver,
            r.backend
        );
        println!(
            "  {:.2} ms per step (median), {:.1} PD iterations per step (max {}, tolerance {}, {} capped), residual <= {:.3e} N, total {:.0} ms",
            r.ms_per_step_median,
            r.pd_iterations_mean,
            r.pd_iterations_max,
            r.pd_tolerance,
            r.pd_capped_steps,
            r.residual_max,
            r.ms_total
        );
        if let (Some(d), Some(from)) = (r.dd_domains, r.dd_partition) {
            println!("  {d} domains ({from})");
        }
        if let Some(d) = r.min_distance_m {
            println!(
                "  max penetration {:.3e} m (body: {}; yarn vertices: {}; tolerance {:.1e} m), min distance to a collider {:.3e} m",
                r.max_penetration_m,
                r.max_penetration_body_m
                    .map_or("-".to_string(), |p| format!("{p:.3e} m")),
                r.max_penetration_yarns_m
                    .map_or("-".to_string(), |p| format!("{p:.3e} m")),
                r.penetration_tolerance_m,
                d
            );
        }
        if let Some(p) = r.max_penetration_pinned_m {
            println!("  pinned nodes: max penetration into the body {p:.3e} m");
        }
        if let (Some(p99), Some(max), Some(f)) = (
            r.yarn_stretch_p99,
            r.yarn_stretch_max,
            r.yarn_stretch_max_frame,
        ) {
            println!(
                "  yarn stretch |l/l0 - 1|: 99th percentile {:.2}%, max {:.2}% (frame {f}); bounds {}% / {}%",
                100.0 * p99,
                100.0 * max,
                100.0 * r.yarn_stretch_bound_p99,
                100.0 * r.yarn_stretch_bound_max
            );
        }
        if r.max_contact_correction_m > 0.0 {
            println!(
                "  largest contact correction of a step {:.3e} m",
                r.max_contact_correction_m
            );
        }
        for n in &r.notes {
            println!("  note: {n}");
        }
        if let Some(p) = &r.resumed_from {
            println!(
                "  continued the shot from frame {} from {}",
                r.shot_start,
                p.display()
            );
        }
        if let Some(p) = &r.checkpoint {
            println!("  checkpoint {}", p.display());
        }
        for p in &r.yarn_files {
            println!("{}", p.display());
        }
    }
    Ok(ExitCode::Success)
}

/// `--animation` and `--fit-joint` name things inside `--character`: a name
/// the file lacks is a usage error (exit 2) naming the option, found before
/// the asset is read. (The same keys in a scene file stay bad input.)
fn check_character_names(a: &SimulateArgs) -> anyhow::Result<()> {
    use crate::geom::excerpt;
    let Some(path) = &a.character else {
        return Ok(());
    };
    if a.animation.is_none() && a.fit_joint.is_none() {
        return Ok(());
    }
    let usage = |m: String| Err(crate::pipeline::Error::Usage(m).into());
    if crate::pipeline::shot_setup::is_cache(path) {
        return usage(format!(
            "--animation / --fit-joint: {} is a character cache (one motion, no skeleton); \
             drop the option and place the garment with --garment-offset",
            path.display()
        ));
    }
    let ch = crate::io::gltf_skin::read_character(path)?;
    if let Some(name) = &a.animation {
        if ch.animation_index(name).is_none() {
            let names: Vec<String> = ch.animation_names().iter().map(|n| excerpt(n)).collect();
            return usage(format!(
                "--animation '{}': {} has no such animation (it has: {})",
                excerpt(name),
                path.display(),
                if names.is_empty() {
                    "none".into()
                } else {
                    names.join(", ")
                }
            ));
        }
    }
    if let Some(joint) = &a.fit_joint {
        if !ch
            .skeleton
            .iter()
            .any(|n| n.name.as_deref() == Some(joint.as_str()))
        {
            return usage(format!(
                "--fit-joint '{}': {} has no node of that name (`knitvox inspect` lists its joints)",
                excerpt(joint),
                path.display()
            ));
        }
    }
    Ok(())
}

/// `--frames` (with `--dt`, `--fps`, `--preroll` or the scene's values) asking
/// for more PD steps than a shot may take is a usage error (exit 2), found
/// before the asset is read; the pipeline checks the same bound again.
fn check_step_count(a: &SimulateArgs, scene: &Scene) -> anyhow::Result<()> {
    use crate::geom::num;
    use crate::pipeline::simulate::MAX_TOTAL_STEPS;
    let frames = a.frames.frames();
    let (Some(first), Some(last)) = (frames.iter().min(), frames.iter().max()) else {
        return Ok(());
    };
    let s = &scene.simulation;
    let per_frame = ((1.0 / s.fps) / s.dt.0).ceil().max(1.0);
    let preroll = s.preroll.unwrap_or(0.0) / s.dt.0;
    let steps = per_frame * (last - first) as f64 + preroll.ceil();
    if !(steps <= MAX_TOTAL_STEPS as f64) {
        return Err(crate::pipeline::Error::Usage(format!(
            "--frames {} at {} fps with dt {} s (pre-roll {} s) needs {} steps, more than the limit of {MAX_TOTAL_STEPS}",
            a.frames,
            num(s.fps),
            num(s.dt.0),
            num(s.preroll.unwrap_or(0.0)),
            num(steps.round())
        ))
        .into());
    }
    Ok(())
}
