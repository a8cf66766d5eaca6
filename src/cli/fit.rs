//! `knitvox fit` (VH §6 elasticity fitting) and `knitvox validate`.

use std::path::PathBuf;

use clap::Args;

use super::asset::command_line;
use super::parse::ValueError;
use super::ExitCode;
use crate::fit::elastic::ElasticFitParams;
use crate::pipeline::fit::{FitJob, DEFAULT_SAMPLES, MAX_ITERATIONS, MAX_SAMPLES};
use crate::pipeline::Stage;

#[derive(Debug, Args)]
pub struct FitArgs {
    /// The asset (.vtkhdf) whose materials are fitted.
    pub asset: PathBuf,
    /// Training poses: yarn frames with the asset's rest-yarn topology (knitvox
    /// HDF5 from `knitvox train`, `yls` or `fabric-test`, or any yarn sequence).
    #[arg(long, required = true, num_args = 1.., value_name = "POSE")]
    pub train: Vec<PathBuf>,
    /// Frames fitted per pose, chosen evenly (the last frame always among them).
    #[arg(long, default_value_t = DEFAULT_SAMPLES, value_name = "N",
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_SAMPLES as u64))]
    pub samples: usize,
    /// Harmonic initialization ranks (VH §6.5), comma-separated; 0 for none.
    #[arg(long, default_value = "1,10,30", value_name = "R,R,..", value_parser = parse_ranks)]
    pub harmonic: Ranks,
    /// Gradient-descent iterations per stage (VH §6.3: 10-15).
    #[arg(long, default_value_t = ElasticFitParams::default().gd_iterations, value_name = "N",
          value_parser = clap::value_parser!(u32).range(0..=MAX_ITERATIONS as i64))]
    pub gd_iterations: u32,
    /// Gauss-Newton iterations per stage (VH §6.3: 20-30).
    #[arg(long, default_value_t = ElasticFitParams::default().gn_iterations, value_name = "N",
          value_parser = clap::value_parser!(u32).range(0..=MAX_ITERATIONS as i64))]
    pub gn_iterations: u32,
    /// Most conjugate-gradient iterations per Gauss-Newton direction of a
    /// full field too large to factor (>= 1; fewer: faster, coarser
    /// directions; docs/performance.md, fit at VH's rib size).
    #[arg(long, default_value_t = ElasticFitParams::default().cg_iterations as u64, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub cg_iterations: u64,
    /// A stage ends once Gauss-Newton, no longer damped, lowers the loss by
    /// less than this fraction over 3 iterations ([0, 1); 0: run every
    /// iteration).
    #[arg(long, default_value_t = ElasticFitParams::default().stall_decrease, value_name = "F", value_parser = parse_stall)]
    pub stall_decrease: f64,
    /// Largest contrast of the fitted field: every gamma over its initial value
    /// stays within this factor of their geometric mean (>= 1; `inf` for no
    /// bound). Poses leave most of a field unobserved; unbounded, it drifts
    /// over many decades.
    #[arg(long, default_value_t = ElasticFitParams::default().max_contrast, value_name = "F", value_parser = parse_contrast)]
    pub max_contrast: f64,
    /// Weight of a Gaussian prior on the full stage's log-field around the
    /// harmonic stages' field (>= 0; 0: none): moving every gamma by a factor
    /// e costs this fraction of the stage's starting loss, so directions the
    /// poses barely observe stay put.
    #[arg(long, default_value_t = ElasticFitParams::default().prior_weight, value_name = "RHO", value_parser = parse_prior)]
    pub prior: f64,
    /// Weight of a smoothness term on the full stage's log-fields over
    /// face-adjacent tets (>= 0; 0: none): a jump by a factor e across every
    /// face costs this fraction of the stage's starting loss, so the field
    /// varies smoothly between the places the poses observe.
    #[arg(long, default_value_t = ElasticFitParams::default().smooth_weight, value_name = "SIGMA", value_parser = parse_prior)]
    pub smooth: f64,
    /// `--model knit`: weight of the clamp forces in the loss, where the
    /// training runs recorded them (>= 0): a relative force misfit of 1
    /// costs this fraction of the uniform material's position loss. 0 fits
    /// the positions alone and sets the stiffening from the forces after.
    #[arg(long, default_value_t = ElasticFitParams::default().force_weight, value_name = "RHO", value_parser = parse_prior)]
    pub force_weight: f64,
    /// The fitted asset [default: ASSET with .fit.vtkhdf]; must differ from ASSET.
    #[arg(short, long, value_name = "OUT.vtkhdf")]
    pub output: Option<PathBuf>,
    /// Folder for fit.json and PNG plots (loss per iteration, gamma histograms, mid-plane slices).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Fit all poses' frames together (VH Eq. 9) instead of pose by pose with
    /// the energy-weighted average of Eq. 22.
    #[arg(long)]
    pub joint: bool,
    /// Fit the frames of yls runs as equilibria: without it their inertia and
    /// damping forces (VH Eq. 13-14, differenced from the shape fits of each
    /// fitted frame and the two before it) load every node.
    #[arg(long)]
    pub quasi_static: bool,
    /// Also fit tension-only fibres along the courses and wales (directions
    /// from the rest yarns), next to VH Eq. 7's isotropic gamma_s, gamma_v:
    /// knit is far stiffer along its yarn lines than in shear.
    #[arg(long)]
    pub fibres: bool,
    /// Material model: `knit` (Eq. 7 under course and wale fibres whose
    /// stiffness grows with stretch: per element gamma_s, gamma_v and per
    /// fibre a stiffness and a stiffening, fitted to the positions and the
    /// clamp forces) or `vh` (VH Eq. 7 per element, the reference; a few
    /// times faster to fit, but it holds a fraction of the knit's force
    /// once stretched).
    #[arg(long, value_enum, default_value = "knit")]
    pub model: crate::pipeline::fit::FitModel,
    /// Hold the pinned tet nodes at each frame's shape fit instead of where the pose's bands put them, where
    /// `validate` and the shots drive them.
    #[arg(long)]
    pub shape_fit_pins: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    /// Never show progress (without it: a plain line per fit stage on
    /// stderr, or a JSON line per stage on stdout with --json).
    #[arg(long)]
    pub no_progress: bool,
    #[command(flatten)]
    pub read: super::args::ReadArgs,
}

/// Harmonic ranks as parsed from `--harmonic`.
#[derive(Debug, Clone)]
pub struct Ranks(pub Vec<usize>);

fn parse_ranks(s: &str) -> Result<Ranks, ValueError> {
    let mut out = Vec::new();
    for t in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let r: usize = t.parse().map_err(|_| ValueError::Rank {
            text: t.to_string(),
        })?;
        if r > 10_000 {
            return Err(ValueError::RankTooLarge { rank: r });
        }
        if r > 0 && !out.contains(&r) {
            out.push(r);
        }
    }
    Ok(Ranks(out))
}

fn parse_prior(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(ValueError::Prior {
            text: s.to_string(),
        }),
    }
}

fn parse_stall(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..1.0).contains(&v) => Ok(v),
        _ => Err(ValueError::Stall {
            text: s.to_string(),
        }),
    }
}

fn parse_contrast(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 1.0 => Ok(v),
        _ => Err(ValueError::Contrast {
            text: s.to_string(),
        }),
    }
}

pub fn fit(a: &FitArgs) -> anyhow::Result<ExitCode> {
    let job = FitJob {
        asset: a.asset.clone(),
        train: a.train.clone(),
        read: a.read.options(),
        samples: a.samples,
        params: ElasticFitParams {
            harmonic_ranks: a.harmonic.0.clone(),
            gd_iterations: a.gd_iterations,
            gn_iterations: a.gn_iterations,
            cg_iterations: a.cg_iterations as usize,
            stall_decrease: a.stall_decrease,
            max_contrast: a.max_contrast,
            prior_weight: a.prior,
            smooth_weight: a.smooth,
            force_weight: a.force_weight,
            ..ElasticFitParams::default()
        },
        output: a.output.clone(),
        report: a.report.clone(),
        joint: a.joint,
        quasi_static: a.quasi_static,
        fibres: a.fibres,
        model: a.model,
        shape_fit_pins: a.shape_fit_pins,
        command: command_line(),
    };
    // A bar has no length to show here: plain lines without --json.
    let mode = match super::console::ProgressMode::of(a.json) {
        _ if a.no_progress => super::console::ProgressMode::Off,
        super::console::ProgressMode::Bar => super::console::ProgressMode::Lines,
        m => m,
    };
    let (result, warnings) = super::console::Console::with_mode(mode, 0, "fit").run(&job);
    let r = result?;
    if a.json {
        super::console::print_json_report(&r, &[("warnings", warnings.into())])?;
    } else {
        println!(
            "{}: fitted {} tets on {} pose(s); loss {:.3e} -> uniform {:.3e} -> fitted {:.3e} m^3; uniform gamma_s {:.4e}, gamma_v {:.4e} Pa; gamma_s {:.3e}..{:.3e}, gamma_v {:.3e}..{:.3e} Pa; {:.1} s",
            r.output.display(),
            r.tets,
            r.poses.len(),
            r.loss_before,
            r.loss_uniform,
            r.loss_fitted,
            r.uniform.gamma_s,
            r.uniform.gamma_v,
            r.gamma_s_range[0],
            r.gamma_s_range[1],
            r.gamma_v_range[0],
            r.gamma_v_range[1],
            r.wall_s
        );
        if let (Some(c), Some(w)) = (r.beta_course_range, r.beta_wale_range) {
            println!(
                "knit stiffening: uniform course {:.3}, wale {:.3}; course {:.3}..{:.3}, wale {:.3}..{:.3}",
                r.uniform.beta_course.unwrap_or(f64::NAN),
                r.uniform.beta_wale.unwrap_or(f64::NAN),
                c[0],
                c[1],
                w[0],
                w[1]
            );
        }
        if let Some(f) = &r.field_forces {
            println!(
                "clamp forces: relative misfit {:.3} under the uniform material, {:.3} fitted ({} frames, {} bands, weight {})",
                f.force_misfit_start, f.force_misfit_after, f.frames, f.bands, f.weight
            );
        }
        if let (Some(c), Some(w)) = (r.gamma_course_range, r.gamma_wale_range) {
            println!(
                "fibres: uniform course {:.4e}, wale {:.4e} Pa; course {:.3e}..{:.3e}, wale {:.3e}..{:.3e} Pa",
                r.uniform.gamma_course.unwrap_or(f64::NAN),
                r.uniform.gamma_wale.unwrap_or(f64::NAN),
                c[0],
                c[1],
                w[0],
                w[1]
            );
        }
        let t = &r.training;
        println!(
            "training poses, RMS in yarn diameters: fitted {:.3}, uniform {:.3}, before {:.3} (Y2V floor {:.3})",
            t.fitted_rms_yarn_diameters,
            t.uniform_rms_yarn_diameters,
            t.before_rms_yarn_diameters,
            t.y2v_floor_rms_yarn_diameters
        );
        for p in &r.poses {
            for ((f, a), t) in p.frames.iter().zip(&p.amounts).zip(&p.training_per_frame) {
                println!(
                    "  {} frame {f}{}: fitted {:.3}, uniform {:.3} (Y2V floor {:.3})",
                    p.path.display(),
                    a.map_or(String::new(), |a| format!(
                        " (amount {})",
                        crate::geom::num(a)
                    )),
                    t.fitted_rms_yarn_diameters,
                    t.uniform_rms_yarn_diameters,
                    t.y2v_floor_rms_yarn_diameters
                );
            }
        }
    }
    Ok(ExitCode::Success)
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// The asset (.vtkhdf), usually fitted by `knitvox fit`.
    pub asset: PathBuf,
    /// The yls scene (schemas/yls-scene.md) run at both levels; without
    /// `[swatch]` it runs on the asset's rest yarns.
    #[arg(long, value_name = "SCENE.toml")]
    pub scene: PathBuf,
    /// Require the comparison with the best uniform material (the asset's
    /// fit record); without it the comparison runs when the record exists.
    #[arg(long)]
    pub uniform: bool,
    /// Folder for validate.json, error.png and both yarn sequences (PLY).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Integrator of the homogenized runs: `pd` (projective dynamics, as
    /// `simulate` runs shots; steps as `--dt`) or `newton` (one exact
    /// backward-Euler step per frame; a slower reference).
    #[arg(long, value_enum, default_value = "pd")]
    pub solver: SolverArg,
    /// Largest PD time step (s), a number or a fraction, as `simulate --dt`
    /// [default: the yarn level's step for `model = "rods"` scenes (1/600
    /// unless `[rods] max_dt`), so that both levels step alike; else 1/150].
    #[arg(long, value_name = "SECONDS", value_parser = crate::pipeline::sim_scene::parse_seconds)]
    pub dt: Option<f64>,
    /// Most PD iterations per step (local + global; Anderson-accelerated) of
    /// the homogenized runs, the cap on the simulator's tolerance [default:
    /// 100, as `simulate`].
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub pd_iterations: Option<u32>,
    /// Where the PD runs' local step runs [default: auto, as `simulate`].
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: crate::pipeline::sim_scene::BackendChoice,
    /// Global solver of the PD runs, as `simulate --solver` [default: direct].
    #[arg(long, value_enum, default_value = "direct")]
    pub pd_solver: crate::pipeline::sim_scene::SolverChoice,
    /// What the colliders of the PD runs act on: `yarns` (each V2Y yarn
    /// vertex keeps its radius, its contact and friction forces reaching
    /// the tet nodes through the embedding weights, as the yarn level
    /// applies them) or `nodes` (each free tet node keeps the thickness of
    /// the yarns it carries).
    #[arg(long, value_enum, default_value = "yarns")]
    pub contact: ContactArg,
    /// Stiffness-proportional damping of the homogenized PD runs (s, >= 0):
    /// the implicit force -beta L v on the rates of deformation (co-rotated:
    /// rigid rotation is not damped), the
    /// homogenized stand-in for the yarns' internal friction [default: the
    /// asset's, from `knitvox fit-damping`, else 0].
    #[arg(long, value_name = "SECONDS", value_parser = non_negative_seconds)]
    pub stiffness_damping: Option<f64>,
    /// Reuse this yarn-level run of the scene instead of running it again:
    /// `yarn_level.h5` of an earlier `--report`, or `knitvox yls` output.
    /// Its scene (`[swatch]` aside), rest yarns and frame times must match;
    /// `yarn_level_s` (and the speedup) then come from the time it records.
    #[arg(long, value_name = "FRAMES.h5")]
    pub truth: Option<std::path::PathBuf>,
    /// Also run the material of this asset (the same embedded mesh with a
    /// VH Eq. 7 field fitted on the same poses: the reference to beat) and
    /// report its distance beside the asset's (`vh_rms_yarn_diameters`).
    #[arg(long, value_name = "VH_ASSET.vtkhdf")]
    pub compare_vh: Option<PathBuf>,
    /// Print the full report as JSON (per-frame errors included).
    #[arg(long)]
    pub json: bool,
    /// Show a progress bar of the yarn-level run (on by default when stderr is a terminal).
    #[arg(long, overrides_with = "no_progress")]
    pub progress: bool,
    /// Never show progress (without it and without a terminal: a plain line per yarn-level frame on stderr).
    #[arg(long)]
    pub no_progress: bool,
}

/// A finite, non-negative number of seconds.
fn non_negative_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|e| format!("{s:?} is not a number: {e}"))?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("{s} must be finite and >= 0"))
    }
}

/// `--contact` of `validate`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ContactArg {
    Yarns,
    Nodes,
}

/// `--solver` of `validate`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SolverArg {
    Pd,
    Newton,
}

#[derive(Debug, Args)]
pub struct FitDampingArgs {
    #[command(flatten)]
    pub validate: ValidateArgs,
    /// The asset to write: the input asset with the damping found recorded
    /// (parameters `damping`), which `validate` and `simulate` then use.
    #[arg(short, long, value_name = "OUT.vtkhdf")]
    pub output: PathBuf,
}

pub fn validate(a: &ValidateArgs) -> anyhow::Result<ExitCode> {
    run_validate(a, None)
}

pub fn fit_damping(a: &FitDampingArgs) -> anyhow::Result<ExitCode> {
    if a.validate.stiffness_damping.is_some() {
        return Err(crate::pipeline::Error::Usage(
            "fit-damping searches the damping: leave out --stiffness-damping".into(),
        )
        .into());
    }
    run_validate(&a.validate, Some(a.output.clone()))
}

fn run_validate(a: &ValidateArgs, fit_damping: Option<PathBuf>) -> anyhow::Result<ExitCode> {
    let label = if fit_damping.is_some() {
        "fit-damping"
    } else {
        "validate: yarn level"
    };
    let job = crate::pipeline::validate::ValidateJob {
        asset: a.asset.clone(),
        scene: a.scene.clone(),
        uniform: a.uniform,
        report: a.report.clone(),
        homogenized: crate::pipeline::validate::HomogenizedRunParams {
            solver: match a.solver {
                SolverArg::Pd => crate::pipeline::validate::HomogenizedSolver::Pd,
                SolverArg::Newton => crate::pipeline::validate::HomogenizedSolver::Newton,
            },
            max_dt: a.dt,
            pd_iterations: a.pd_iterations,
            backend: a.backend,
            global: a.pd_solver,
            contact: match a.contact {
                ContactArg::Yarns => crate::pipeline::validate_pd::ContactAt::Yarns,
                ContactArg::Nodes => crate::pipeline::validate_pd::ContactAt::Nodes,
            },
            stiffness_damping: a.stiffness_damping,
        },
        truth: a.truth.clone(),
        compare_vh: a.compare_vh.clone(),
        fit_damping,
    };
    let mode = super::console::ProgressMode::on_stderr(a.progress, a.no_progress);
    let mut console = super::console::Console::with_mode(mode, 0, label);
    let result = job.run(&mut console);
    drop(console);
    let r = result?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!("{}", r.summary());
        println!("{}", crate::pipeline::validate_motion::words(&r.motion));
        if let Some(d) = &r.damping_fit {
            println!("{}", crate::pipeline::validate::damping_words(d));
        }
        println!("{}", r.verdict);
    }
    Ok(ExitCode::Success)
}
