//! `knitvox fabric-test stretch|bend|hang`: Sperl 2022 §4 tests on a yarn swatch.

use std::path::PathBuf;

use clap::{Args, Subcommand};

use super::yarn_material::YarnMaterialArgs;
use super::ExitCode;
use crate::pipeline::fabric_test::{
    run_observed, FabricTest, FabricTestJob, FabricTestReport, SwatchSource, TestFigures,
};
use crate::pipeline::pattern::PatternSource;
use crate::yarn::fabric::bend::BendParams;
use crate::yarn::fabric::{Direction, FabricParams, HangParams, RelaxParams, StretchParams};

#[derive(Debug, Subcommand)]
pub enum FabricTestKind {
    /// Clamped uniaxial stretch, quasi-static: force (N) and orthogonal
    /// compression per stretch step.
    Stretch(StretchArgs),
    /// Pear-loop bending: both clamps hold the swatch hanging down side by
    /// side and come together under gravity; loop height, width and aspect
    /// ratio h/p per clamp distance.
    Bend(BendArgs),
    /// Hung by the top edge under gravity: sag ratio and the speed left
    /// after settling.
    Hang(HangArgs),
}

/// The swatch and the outputs, common to every test.
#[derive(Debug, Args)]
pub struct SwatchArgs {
    /// Yarn file to test (relaxed into contact first unless it carries a
    /// rest shape, as `knitvox pattern` HDF5 output does).
    #[arg(value_name = "YARNS", conflicts_with_all = ["pattern", "grid"])]
    pub yarns: Option<PathBuf>,
    /// Built-in pattern, laid out to --width x --length.
    #[arg(long, value_name = "NAME", conflicts_with = "grid")]
    pub pattern: Option<String>,
    /// Stitch grid file (schemas/pattern-grid.md), laid out to --width x --length.
    #[arg(long, value_name = "FILE")]
    pub grid: Option<PathBuf>,
    /// Swatch width across the test axis (m).
    #[arg(long, value_name = "METRES", default_value_t = 0.06)]
    pub width: f64,
    /// Swatch length along the test axis (m).
    #[arg(long, value_name = "METRES", default_value_t = 0.10)]
    pub length: f64,
    /// Rest-length scale of the relaxation into contact (Leaf 2018 §6.1).
    #[arg(long, value_name = "S", default_value_t = RelaxParams::default().length_scale)]
    pub length_scale: f64,
    /// Fraction of the generated loops' curvature the yarn keeps as its rest
    /// curvature (1: the relaxed swatch lies flat, as a lab clamps it; 0.8: patterns show their
    /// character: stockinette curls, a rib draws in, garter shortens).
    #[arg(long, value_name = "F", default_value_t = RelaxParams::default().rest_curvature, value_parser = super::parse::parse_fraction)]
    pub rest_curvature: f64,
    /// Yarn-on-yarn Coulomb friction coefficient (0: frictionless; the
    /// relaxation into contact is always frictionless).
    #[arg(long, value_name = "MU", default_value_t = FabricParams::default().friction.mu, value_parser = super::parse::parse_non_negative)]
    pub friction: f64,
    /// Friction's stick distance (m): tangential slip below it is elastic
    /// sticking (the fibre bundle's tangential compliance), above it sliding.
    #[arg(long, value_name = "METRES", default_value_t = FabricParams::default().friction.stick_distance, value_parser = super::parse::parse_positive)]
    pub stick_distance: f64,
    #[command(flatten)]
    pub material: YarnMaterialArgs,
    /// Output folder: TEST.h5 (frames with energy and clamp forces) and, for
    /// stretch and bend, TEST.csv and the plot TEST.png.
    #[arg(short, long, value_name = "DIR")]
    pub output: Option<PathBuf>,
    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
    /// Show a progress bar of the test's frames (on by default when stderr is a terminal).
    #[arg(long, overrides_with = "no_progress")]
    pub progress: bool,
    /// Never show progress (without it and without a terminal: a plain line per frame on stderr).
    #[arg(long)]
    pub no_progress: bool,
}

#[derive(Debug, Args)]
pub struct StretchArgs {
    #[command(flatten)]
    pub swatch: SwatchArgs,
    /// Stretch axis: weft (along the courses), warp (along the wales), bias
    /// (45 degrees: a pattern is laid out larger and cut to the test piece;
    /// a yarn file is tested as given, so it should be a piece cut on the
    /// bias).
    #[arg(long, value_name = "weft|warp|bias", default_value = "weft")]
    pub direction: Direction,
    /// Largest stretch of the gauge section.
    #[arg(long, value_name = "S", default_value_t = 0.5)]
    pub max_stretch: f64,
    /// Load steps.
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub steps: usize,
    /// Conditioning cycles before the measured loading: each stretches to
    /// --max-stretch and back in --steps steps each way, as cyclic strip
    /// tests (EN 14704-1) condition a specimen; compression stays relative
    /// to the width before the first cycle.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub cycles: usize,
    /// Unloading steps after the measured loading and its hold, back to 0
    /// (with friction the unloading force is lower: hysteresis).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub release_steps: usize,
}

#[derive(Debug, Args)]
pub struct BendArgs {
    #[command(flatten)]
    pub swatch: SwatchArgs,
    /// Which axis runs round the loop: weft (along the courses), warp
    /// (along the wales), bias (as for stretch).
    #[arg(long, value_name = "weft|warp|bias", default_value = "weft")]
    pub direction: Direction,
    /// First (largest) distance between the clamps (m).
    #[arg(long, value_name = "METRES", default_value_t = BendParams::default().max_distance)]
    pub max_distance: f64,
    /// Last (smallest) distance between the clamps (m); above the swatch's
    /// thickness.
    #[arg(long, value_name = "METRES", default_value_t = BendParams::default().min_distance)]
    pub min_distance: f64,
    /// Intervals between the first and the last distance.
    #[arg(long, value_name = "N", default_value_t = BendParams::default().steps)]
    pub steps: usize,
}

#[derive(Debug, Args)]
pub struct HangArgs {
    #[command(flatten)]
    pub swatch: SwatchArgs,
    /// Implicit-Euler time watched after settling (s).
    #[arg(long, value_name = "SECONDS", default_value_t = 0.2)]
    pub watch: f64,
}

/// Why the swatch options do not make a fabric test.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum SwatchArgsError {
    /// A swatch width or length (m) outside `(0, 2]`.
    #[error("--width and --length must be in (0, 2] m, got {} and {}", crate::geom::num(*.width), crate::geom::num(*.length))]
    Size { width: f64, length: f64 },
    /// No yarn file, built-in pattern or grid file.
    #[error("give a yarn file, --pattern NAME or --grid FILE")]
    NoSwatch,
}

fn job(s: &SwatchArgs, test: FabricTest) -> Result<FabricTestJob, SwatchArgsError> {
    let size = [s.width, s.length];
    if !size.iter().all(|v| v.is_finite() && *v > 0.0 && *v <= 2.0) {
        return Err(SwatchArgsError::Size {
            width: s.width,
            length: s.length,
        });
    }
    let swatch = match (&s.yarns, &s.pattern, &s.grid) {
        (Some(p), _, _) => SwatchSource::Yarns(p.clone()),
        (None, Some(n), _) => SwatchSource::Pattern {
            source: PatternSource::Builtin(n.clone()),
            size,
        },
        (None, None, Some(g)) => SwatchSource::Pattern {
            source: PatternSource::GridFile(g.clone()),
            size,
        },
        (None, None, None) => return Err(SwatchArgsError::NoSwatch),
    };
    Ok(FabricTestJob {
        swatch,
        test,
        fabric: {
            let mut f = FabricParams::default();
            f.friction.mu = s.friction;
            f.friction.stick_distance = s.stick_distance;
            f
        },
        material: s.material.overrides(),
        relax: RelaxParams {
            length_scale: s.length_scale,
            rest_curvature: s.rest_curvature,
            ..RelaxParams::default()
        },
        output_dir: s.output.clone(),
    })
}

pub fn fabric_test(kind: &FabricTestKind) -> anyhow::Result<ExitCode> {
    let (swatch, test) = match kind {
        FabricTestKind::Stretch(a) => (
            &a.swatch,
            FabricTest::Stretch(StretchParams {
                direction: a.direction,
                max_stretch: a.max_stretch,
                steps: a.steps,
                conditioning_cycles: a.cycles,
                release_steps: a.release_steps,
                ..StretchParams::default()
            }),
        ),
        FabricTestKind::Bend(a) => (
            &a.swatch,
            FabricTest::Bend(BendParams {
                direction: a.direction,
                max_distance: a.max_distance,
                min_distance: a.min_distance,
                steps: a.steps,
                ..BendParams::default()
            }),
        ),
        FabricTestKind::Hang(a) => (
            &a.swatch,
            FabricTest::Hang(HangParams {
                watch_time: a.watch,
                ..HangParams::default()
            }),
        ),
    };
    let job = match job(swatch, test) {
        Ok(j) => j,
        Err(m) => {
            eprintln!("error: {m}");
            return Ok(ExitCode::Usage);
        }
    };
    // Warnings print as soon as the swatch is ready, not after the test.
    let mode = super::console::ProgressMode::on_stderr(swatch.progress, swatch.no_progress);
    let label = format!("fabric-test {}", job.test.name());
    let mut console = super::console::Console::with_mode(mode, 0, &label);
    let report = match run_observed(&job, &mut console) {
        Ok(r) => r,
        Err(e) if e.is_usage() => {
            eprintln!("error: {e}");
            return Ok(ExitCode::Usage);
        }
        Err(e) => return Err(e.into()),
    };
    if swatch.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    Ok(ExitCode::Success)
}

fn print_report(r: &FabricTestReport) {
    println!(
        "yarn material: {}",
        super::yarn_material::describe_choice(&r.material)
    );
    if let Some(x) = &r.relaxation {
        println!(
            "relaxed {} ({} vertices) into contact: rest length scale {}, {} Newton iterations, residual {:.1e} N, \
             {:.0}% of vertices touching, min distance {:.3} x 2r, size {:.4} x {:.4} m, {:.1} s",
            r.swatch,
            r.vertices,
            x.length_scale,
            x.newton_iterations,
            x.residual,
            100.0 * x.contact.near_fraction,
            x.min_distance_ratio_seen,
            x.size_after[0],
            x.size_after[1],
            x.seconds
        );
    }
    match &r.figures {
        TestFigures::Stretch(s) => {
            println!(
                "stretch ({}), {:.4} m wide, gauge {:.4} m:",
                s.direction.name(),
                s.width_m,
                s.gauge_m
            );
            println!("  stretch  force (N)  compression");
            for p in &s.points {
                println!("  {:7.3}  {:9.4}  {:11.3}", p.stretch, p.force_n, p.compression);
            }
            println!(
                "  energy change over the hold {:+.2}%, min distance {:.3} x 2r, {:.1} s",
                100.0 * s.hold_energy_change,
                s.min_distance_ratio,
                s.seconds
            );
        }
        TestFigures::Bend(b) => {
            println!(
                "pear loop ({}), {:.4} m wide, gauge {:.4} m, weight {:.4} N:",
                b.direction.name(),
                b.width_m,
                b.gauge_m,
                b.weight_n
            );
            println!("  clamps (m)  height (m)  width (m)  h/p");
            for p in &b.points {
                println!(
                    "  {:10.4}  {:10.4}  {:9.4}  {:5.3}",
                    p.clamp_distance_m, p.height_m, p.width_m, p.aspect_ratio
                );
            }
            println!(
                "  min distance {:.3} x 2r, {:.1} s",
                b.min_distance_ratio, b.seconds
            );
        }
        TestFigures::Hang(h) => println!(
            "hang: sag ratio {:.4}, max speed {:.2e} m/s after settling, weight {:.4} N, clamp force {:.4} N, {:.1} s",
            h.sag_ratio, h.max_speed_m_s, h.weight_n, h.clamp_force_n, h.seconds
        ),
    }
    for w in &r.written {
        println!("wrote {}", w.display());
    }
}
