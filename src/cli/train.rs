//! `knitvox train ASSET.vtkhdf --pose KIND -o POSE.h5`: one training pose.

use std::path::PathBuf;

use clap::Args;

use super::ExitCode;
use crate::pipeline::train::TrainJob;
use crate::pipeline::util::parse_kind;
use crate::pipeline::Stage;
use crate::yarn::fabric::pose::{default_amount, PoseRunParams};
use crate::yarn::fabric::FabricParams;
use crate::yarn::poses::PoseKind;

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Homogenized asset (.vtkhdf) whose rest yarns are posed.
    pub asset: PathBuf,
    /// Pose (schemas/yls-scene.md): stretch_courses, stretch_wales, biaxial,
    /// shear, bend_central, bend_diagonal, fan, twist, multi_fold,
    /// cantilever (needs --gravity).
    #[arg(long, value_name = "KIND", value_parser = parse_kind)]
    pub pose: PoseKind,
    /// Magnitude: strain for stretches, biaxial, shear and fan; angle (rad)
    /// for bends and twist; fold height / fold length (< 0.5) for
    /// multi_fold [default: 0.2 strain (biaxial 0.1), 0.8 rad, 0.3]. A list
    /// (`0.02,0.1,0.2,0.3`) loads through each amplitude in order, --steps
    /// load steps to each, and `fit` fits the frame at each.
    #[arg(
        long,
        value_name = "A[,A..]",
        allow_negative_numbers = true,
        value_delimiter = ',',
        num_args = 1
    )]
    pub amount: Vec<f64>,
    /// The mirrored counterpart of the pose (VH Fig. 19).
    #[arg(long)]
    pub mirror: bool,
    /// Quasi-static load steps from rest to the full amount (one frame each).
    #[arg(long, value_name = "K", default_value_t = PoseRunParams::new(PoseKind::StretchCourses).steps as u32,
          value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub steps: u32,
    /// Gravity (m/s²) along the fabric's normal, the swatch lying
    /// horizontal between its clamps: the frames then carry every vertex's
    /// weight and their sag observes the material's scale [default: 0, no
    /// external force; 9.81 for Earth].
    #[arg(long, value_name = "G", default_value_t = 0.0, value_parser = super::parse::parse_non_negative)]
    pub gravity: f64,
    /// Width of each clamped band as a fraction of the swatch extent across
    /// it, in (0, 0.5); for cantilever, the held fraction of the swatch in
    /// (0, 0.95): the overhang is the rest. A short overhang droops in the
    /// range where its droop still measures the bending stiffness
    /// [default: 0.06].
    #[arg(long, value_name = "F")]
    pub band: Option<f64>,
    /// Yarn-on-yarn Coulomb friction coefficient (0: frictionless).
    #[arg(long, value_name = "MU", default_value_t = FabricParams::default().friction.mu, value_parser = super::parse::parse_non_negative)]
    pub friction: f64,
    #[command(flatten)]
    pub material: super::yarn_material::YarnMaterialArgs,
    /// Output knitvox HDF5 file: frames with energy, clamp reactions and the pose record.
    #[arg(short, long, value_name = "POSE.h5")]
    pub output: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    /// Show a progress bar (on by default when stderr is a terminal).
    #[arg(long, overrides_with = "no_progress")]
    pub progress: bool,
    /// Never show progress (without it and without a terminal: a plain line per load step on stderr).
    #[arg(long)]
    pub no_progress: bool,
}

pub fn train(a: &TrainArgs) -> anyhow::Result<ExitCode> {
    let mut pose = PoseRunParams::new(a.pose);
    pose.pose.amount = a
        .amount
        .last()
        .copied()
        .or(default_amount(a.pose))
        .unwrap_or(0.0);
    if a.amount.len() > 1 {
        pose.amounts = a.amount.clone();
    }
    pose.pose.mirror = a.mirror;
    if let Some(b) = a.band {
        pose.pose.band = b;
    }
    pose.steps = a.steps as usize;
    pose.gravity = a.gravity;
    let mut fabric = FabricParams::default();
    fabric.friction.mu = a.friction;
    let job = TrainJob {
        asset: a.asset.clone(),
        output: a.output.clone(),
        pose,
        fabric,
        material: a.material.overrides(),
    };
    let mode = super::console::ProgressMode::on_stderr(a.progress, a.no_progress);
    let frames = job.pose.steps * job.pose.stops().len();
    let mut console = super::console::Console::with_mode(mode, frames, "train");
    let result = job.run(&mut console);
    drop(console);
    let r = result?;
    if a.json {
        // One line, as simulate/yls/run print theirs (farm logs read the last line).
        super::console::print_json_report(&r, &[])?;
    } else {
        println!(
            "{}: {}{} (amount {}) on {} ({} vertices, {} clamped, rest shape {}): {} frames, \
             final clamp force {:.4} N, min distance / 2r {:.3}, {:.2} min",
            r.output.display(),
            r.pose,
            if r.mirror { " mirrored" } else { "" },
            r.amounts
                .iter()
                .map(|a| crate::geom::num(*a).to_string())
                .collect::<Vec<_>>()
                .join(", "),
            r.asset.display(),
            r.vertices,
            r.clamped_vertices,
            r.rest_shape,
            r.frames,
            r.final_force_n,
            r.min_distance_ratio,
            r.minutes
        );
        println!("  step  amount   force (N)  energy (J)  Newton  residual (N)  contacts/v  ms");
        for s in &r.steps {
            println!(
                "  {:4}  {:6.4}  {:9.4}  {:10.3e}  {:6}  {:12.2e}  {:10.2}  {:.0}",
                s.step,
                s.amount,
                s.force_n,
                s.energy_j,
                s.newton_iterations,
                s.residual_n,
                s.contacts_per_vertex,
                s.ms
            );
        }
    }
    Ok(ExitCode::Success)
}
