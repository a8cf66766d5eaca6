//! `knitvox pattern`: generate a stitch pattern as yarn curves.

use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::io::{self, WriteOptions};
use crate::pipeline::pattern::{generate, PatternJob, PatternSource};
use crate::yarn::fabric::{FabricParams, RelaxParams};
use crate::yarn::pattern::{Layout, PatternParams, BUILTIN_NAMES};

#[derive(Debug, Args)]
pub struct PatternArgs {
    /// Built-in pattern: stockinette, garter, rib1x1, rib2x2, seed, basketweave
    /// (knits); plain, twill, satin, basket (wovens).
    #[arg(
        value_name = "NAME",
        required_unless_present = "grid",
        conflicts_with = "grid"
    )]
    pub name: Option<String>,
    /// A stitch grid file instead of a name (K/P or 0/1 text; schemas/pattern-grid.md).
    #[arg(long, value_name = "FILE")]
    pub grid: Option<PathBuf>,
    /// Courses (knit) or wefts (woven) along +Y.
    #[arg(long, value_name = "N")]
    pub courses: usize,
    /// Wales (knit) or warps (woven) along +X (around a tube).
    #[arg(long, value_name = "M")]
    pub wales: usize,
    /// Knit in the round: a tube of this mid-surface radius (m) around +Y
    /// (--wales a multiple of the repeat); each course closes into a ring.
    #[arg(long, value_name = "METRES")]
    pub tube_radius: Option<f64>,
    /// With --tube-radius: join the courses into one helix (one yarn, as
    /// knitting in the round makes it) instead of rings.
    #[arg(long, requires = "tube_radius")]
    pub helix: bool,
    /// Flat swatches: keep each course (weft) a separate open yarn instead of
    /// one yarn knitted back and forth with a turn at each edge.
    #[arg(long, conflicts_with = "tube_radius")]
    pub separate_courses: bool,
    /// Yarn radius r (m); stitch sizes scale with it [default: 0.001, HYLC's r].
    #[arg(long, value_name = "METRES")]
    pub yarn_radius: Option<f64>,
    /// Vertex spacing along the yarn, in yarn radii.
    #[arg(long, value_name = "R", default_value_t = PatternParams::default().spacing)]
    pub spacing: f64,
    /// Skip the relaxation into contact: write the loose generated curves,
    /// without a rest shape.
    #[arg(long)]
    pub no_relax: bool,
    /// Rest-length scale of the relaxation into contact (Leaf 2018 §6.1):
    /// the yarns' rest lengths shrink to this fraction, pulling the loops
    /// onto each other.
    #[arg(long, value_name = "S", default_value_t = RelaxParams::default().length_scale)]
    pub length_scale: f64,
    /// Fraction of the generated loops' curvature the yarn keeps as its rest
    /// curvature (1: the relaxed swatch lies flat; 0.8: patterns show their
    /// character: stockinette curls, a rib draws in, garter shortens).
    #[arg(long, value_name = "F", default_value_t = RelaxParams::default().rest_curvature, value_parser = super::parse::parse_fraction)]
    pub rest_curvature: f64,
    #[command(flatten)]
    pub material: super::yarn_material::YarnMaterialArgs,
    /// Output yarn file (bcc, obj, ply, gltf, glb, h5).
    #[arg(long, short, value_name = "FILE")]
    pub output: PathBuf,
    /// Print a JSON summary (curves, vertices, size, min distance ratio).
    #[arg(long)]
    pub json: bool,
}

pub fn pattern(a: &PatternArgs) -> anyhow::Result<ExitCode> {
    let source = match (&a.name, &a.grid) {
        (_, Some(g)) => PatternSource::GridFile(g.clone()),
        (Some(n), None) => PatternSource::Builtin(n.clone()),
        (None, None) => {
            eprintln!(
                "error: give a pattern name ({}) or --grid FILE",
                BUILTIN_NAMES.join(", ")
            );
            return Ok(ExitCode::Usage);
        }
    };
    let mut params = PatternParams {
        spacing: a.spacing,
        ..PatternParams::default()
    };
    if let Some(r) = a.yarn_radius {
        params.yarn_radius = r;
    }
    let job = PatternJob {
        source,
        layout: Layout {
            courses: a.courses,
            wales: a.wales,
            tube_radius: a.tube_radius,
            helix: a.helix,
            separate_courses: a.separate_courses,
        },
        params,
        relax: (!a.no_relax).then(|| RelaxParams {
            length_scale: a.length_scale,
            rest_curvature: a.rest_curvature,
            ..RelaxParams::default()
        }),
        material: a
            .material
            .overrides()
            .apply(&FabricParams::default().material()),
    };
    if a.no_relax && !a.material.overrides().names().is_empty() {
        eprintln!(
            "error: the yarn material is recorded with the rest shape the relaxation makes; \
             --no-relax writes none"
        );
        return Ok(ExitCode::Usage);
    }
    if let Some(rp) = &job.relax {
        if !(rp.length_scale > 0.5 && rp.length_scale <= 1.0) {
            eprintln!(
                "error: --length-scale {} is out of range (0.5, 1]",
                rp.length_scale
            );
            return Ok(ExitCode::Usage);
        }
    }
    let (yarns, mut report) = generate(&job).map_err(crate::pipeline::Error::from)?;
    let written = io::write_path(&a.output, &yarns, None, &WriteOptions::default())?;
    report.written = written;
    let format = io::Format::from_path(&a.output);
    if yarns.rest.is_some() && !format.is_some_and(|f| f.holds_rest_shape()) {
        eprintln!(
            "warning: {} keeps the relaxed positions but not their rest shape (rest lengths, \
             curvatures, the yarn material they were relaxed under): a simulation from it \
             starts from positions alone; write .h5 to keep it",
            a.output.display()
        );
    }
    if report.min_distance_ratio < 0.95 {
        eprintln!(
            "warning: yarns come as close as {:.3} x 2r (shape parameters or tube radius too tight)",
            report.min_distance_ratio
        );
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} ({}, repeat {}x{}): {} courses x {} wales{} -> {} curves, {} vertices ({:.1} per stitch), \
             size {:.4} x {:.4} x {:.4} m, min distance {:.3} x 2r, {}",
            report.pattern,
            report.kind,
            report.repeat[0],
            report.repeat[1],
            report.courses,
            report.wales,
            report.tube_radius.map_or(String::new(), |r| format!(", tube R = {r} m")),
            report.curves,
            report.vertices,
            report.vertices_per_stitch,
            report.size[0],
            report.size[1],
            report.size[2],
            report.min_distance_ratio,
            if report.relaxed { "relaxed" } else { "not relaxed" },
        );
        if let Some(x) = &report.relaxation {
            println!(
                "relaxed into contact (rest lengths x {}): {:.4} x {:.4} m (generated {:.4} x {:.4}), \
                 {:.2} contacts per vertex, {:.0}% of vertices touching, min distance {:.3} x 2r, \
                 {} Newton iterations, {:.1} s",
                x.length_scale,
                x.size_after[0],
                x.size_after[1],
                x.size_before[0],
                x.size_before[1],
                x.contact.contacts_per_vertex,
                100.0 * x.contact.near_fraction,
                x.contact.min_distance_ratio,
                x.newton_iterations,
                x.seconds
            );
        }
        if let Some(m) = &report.material {
            println!("yarn material: {m}");
        }
        for p in &report.written {
            println!("{}", p.display());
        }
    }
    Ok(ExitCode::Success)
}
