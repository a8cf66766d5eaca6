//! `knitvox card`: fit a material card on a swatch of a stitch pattern.

use std::path::PathBuf;

use clap::Args;

use super::args::ReadArgs;
use super::ExitCode;
use crate::pipeline::card::{default_card_poses, CardJob, CardReport, SwatchSource};
use crate::pipeline::pattern::PatternSource;
use crate::pipeline::Stage;
use crate::yarn::fabric::FabricParams;

/// The built-in knit patterns `--library` makes cards for (the built-ins
/// list the knits first, then the wovens, which no card is made for).
pub const LIBRARY_PATTERNS: &[&str] = {
    let (knits, _wovens) = crate::yarn::pattern::BUILTIN_NAMES.split_at(6);
    knits
};

#[derive(Debug, Args)]
pub struct CardArgs {
    /// Built-in knit pattern to knit the swatch in: stockinette, garter,
    /// rib1x1, rib2x2, seed, basketweave.
    #[arg(value_name = "PATTERN", conflicts_with_all = ["grid", "swatch", "library"])]
    pub pattern: Option<String>,
    /// A stitch grid file instead of a name (K/P text; schemas/pattern-grid.md).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["swatch", "library"])]
    pub grid: Option<PathBuf>,
    /// A flat swatch's yarn file instead of a generated one (knitvox HDF5
    /// keeps the rest shape it was relaxed into).
    #[arg(long, value_name = "YARNS", conflicts_with = "library")]
    pub swatch: Option<PathBuf>,
    /// Make a card for every built-in knit pattern into this folder
    /// (`NAME.toml`, work folders `NAME.work/`).
    #[arg(long, value_name = "DIR")]
    pub library: Option<PathBuf>,
    /// Courses of a generated swatch.
    #[arg(long, value_name = "N", default_value_t = 6, value_parser = clap::value_parser!(u32).range(2..=100))]
    pub courses: u32,
    /// Wales of a generated swatch.
    #[arg(long, value_name = "M", default_value_t = 6, value_parser = clap::value_parser!(u32).range(2..=100))]
    pub wales: u32,
    /// Yarn radius (m) of a generated swatch; stitch sizes scale with it
    /// [default: 0.001].
    #[arg(long, value_name = "METRES", value_parser = super::parse::parse_positive)]
    pub yarn_radius: Option<f64>,
    /// Load steps to each training amplitude.
    #[arg(long, value_name = "K", default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub steps: u32,
    /// Gravity (m/s²) along the swatch's normal during training.
    #[arg(long, value_name = "G", default_value_t = 9.81, value_parser = super::parse::parse_non_negative)]
    pub gravity: f64,
    /// Yarn-on-yarn Coulomb friction coefficient.
    #[arg(long, value_name = "MU", default_value_t = FabricParams::default().friction.mu, value_parser = super::parse::parse_non_negative)]
    pub friction: f64,
    #[command(flatten)]
    pub material: super::yarn_material::YarnMaterialArgs,
    #[command(flatten)]
    pub read: ReadArgs,
    /// The card written (.toml).
    #[arg(
        short,
        long,
        value_name = "CARD.toml",
        required_unless_present = "library"
    )]
    pub output: Option<PathBuf>,
    /// Work folder: the swatch, its asset, the training poses and the
    /// fitted swatch [default: CARD.work beside the card].
    #[arg(long, value_name = "DIR")]
    pub work: Option<PathBuf>,
    /// The card's name [default: the pattern's, or the swatch file's stem].
    #[arg(long)]
    pub name: Option<String>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    /// Never show progress (without it: a line per step on stderr).
    #[arg(long)]
    pub no_progress: bool,
}

fn work_beside(card: &std::path::Path) -> PathBuf {
    let stem = card
        .file_stem()
        .map_or("card".into(), |s| s.to_string_lossy().into_owned());
    card.with_file_name(format!("{stem}.work"))
}

fn job(a: &CardArgs, swatch: SwatchSource, output: PathBuf, work: PathBuf) -> CardJob {
    CardJob {
        swatch,
        material: a.material.overrides(),
        friction: a.friction,
        poses: default_card_poses(),
        steps: a.steps as usize,
        gravity: a.gravity,
        output,
        work,
        name: a.name.clone(),
        command: super::asset::command_line(),
    }
}

fn generated(a: &CardArgs, source: PatternSource) -> SwatchSource {
    SwatchSource::Pattern {
        source,
        courses: a.courses as usize,
        wales: a.wales as usize,
        yarn_radius: a.yarn_radius,
    }
}

fn print(r: &CardReport) {
    println!(
        "{}: {} card: gamma_s {:.4e} Pa, gamma_v {:.4e} Pa, course {:.4e} Pa (stiffening {:.4e}), \
         wale {:.4e} Pa (stiffening {:.4e}); yarn radius {:.3e} m, {:.1} s",
        r.card.display(),
        r.name,
        r.material.gamma_s_pa,
        r.material.gamma_v_pa,
        r.material.course_pa,
        r.material.course_beta,
        r.material.wale_pa,
        r.material.wale_beta,
        r.stitch.yarn_radius_m,
        r.seconds
    );
    println!(
        "  fitted swatch (for validate): {}",
        r.fitted_swatch.display()
    );
    println!("  {}", r.verdict);
}

pub fn card(a: &CardArgs) -> anyhow::Result<ExitCode> {
    let mode = super::console::ProgressMode::on_stderr(false, a.no_progress);
    let mut jobs = Vec::new();
    if let Some(dir) = &a.library {
        for &name in LIBRARY_PATTERNS {
            let out = dir.join(format!("{name}.toml"));
            let work = dir.join(format!("{name}.work"));
            let mut j = job(
                a,
                generated(a, PatternSource::Builtin(name.into())),
                out,
                work,
            );
            j.name = Some(name.into());
            jobs.push(j);
        }
    } else {
        let Some(output) = a.output.clone() else {
            eprintln!("error: give -o CARD.toml (or --library DIR)");
            return Ok(ExitCode::Usage);
        };
        let swatch = match (&a.pattern, &a.grid, &a.swatch) {
            (Some(p), _, _) => generated(a, PatternSource::Builtin(p.clone())),
            (_, Some(g), _) => generated(a, PatternSource::GridFile(g.clone())),
            (_, _, Some(s)) => SwatchSource::Yarns {
                path: s.clone(),
                read: a.read.options(),
            },
            _ => {
                eprintln!(
                    "error: give a pattern ({}), --grid FILE, --swatch YARNS or --library DIR",
                    LIBRARY_PATTERNS.join(", ")
                );
                return Ok(ExitCode::Usage);
            }
        };
        let work = a.work.clone().unwrap_or_else(|| work_beside(&output));
        jobs.push(job(a, swatch, output, work));
    }
    if let Some(dir) = &a.library {
        std::fs::create_dir_all(dir).map_err(|source| crate::io::IoError::Write {
            path: dir.clone(),
            source,
        })?;
    }
    let mut reports = Vec::new();
    let n = jobs.len();
    for (k, j) in jobs.iter().enumerate() {
        let label = if n > 1 {
            format!("card {}/{n}", k + 1)
        } else {
            "card".to_string()
        };
        let mut console = super::console::Console::with_mode(mode, 0, &label);
        let r = j.run(&mut console)?;
        if !a.json {
            print(&r);
        }
        reports.push(r);
    }
    if a.json {
        if reports.len() == 1 {
            super::console::print_json_report(&reports[0], &[])?;
        } else {
            println!("{}", serde_json::to_string(&reports)?);
        }
    }
    Ok(ExitCode::Success)
}
