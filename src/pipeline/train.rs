//! `knitvox train ASSET.vtkhdf --pose KIND -o POSE.h5`: one training pose
//! (VH 2024 §8.6) run quasi-statically at yarn level on the asset's own
//! rest yarns (`yarn::fabric::pose`), written as knitvox HDF5 frames with
//! their mechanics (elastic energy, clamp reactions, external forces) and
//! a record of the pose and the asset (`/metadata/pose_json`,
//! `/metadata/parameters_json`; schemas/yarns-hdf5.md). Each pose is its own
//! process, so a farm runs a pose set in parallel; `knitvox fit` takes the
//! files.

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::geom::{MaterialOverrides, Vec3};
use crate::io::{self, h5::FrameWriter, IoError};
use crate::pipeline::asset::{check_asset_ext, StageError};
use crate::pipeline::util::sha256_file;
use crate::pipeline::{Error, FrameProgress, Observer, Stage};
use crate::yarn::fabric::pose::{
    kind_name, run_pose, FabricPlane, PoseRunError, PoseRunParams, PoseStep,
};
use crate::yarn::fabric::{FabricParams, MaterialChoice, RigFrame};

/// The training-pose stage: an asset -> one pose's equilibrium frames.
#[derive(Debug, Clone)]
pub struct TrainJob {
    /// The homogenized asset (.vtkhdf) whose rest yarns are posed.
    pub asset: PathBuf,
    /// Output knitvox HDF5 file (.h5 or .hdf5).
    pub output: PathBuf,
    /// The pose and its load steps.
    pub pose: PoseRunParams,
    /// Yarn model (rods, contact, friction, Newton controls); its material
    /// applies where the rest yarns record none.
    pub fabric: FabricParams,
    /// Material fields that replace the rest yarns' recorded ones.
    pub material: MaterialOverrides,
}

/// What a run did (`--json` prints it).
#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    pub asset: PathBuf,
    pub asset_sha256: String,
    pub output: PathBuf,
    /// The pose's schema name (`stretch_courses`, ...).
    pub pose: String,
    pub amount: f64,
    /// The amplitudes the load path stopped at (`[amount]` without a list)
    /// and their frames (from 0).
    pub amounts: Vec<f64>,
    pub stop_frames: Vec<usize>,
    pub mirror: bool,
    /// Gravity along the fabric's normal (m/s²; 0: none).
    pub gravity_m_s2: f64,
    /// Equilibrium frames written (one per step).
    pub frames: usize,
    pub vertices: usize,
    pub curves: usize,
    pub clamped_vertices: usize,
    /// The coordinate plane the swatch lies in (turned into the pose
    /// frame, fabric in XZ, for the run).
    pub fabric_plane: FabricPlane,
    /// The yarn material the pose ran under and where it came from.
    pub material: MaterialChoice,
    /// `stored` (the asset's rest yarns carry rest lengths and curvatures)
    /// or `positions` (rest state taken from the positions).
    pub rest_shape: &'static str,
    /// Largest clamp force at the last step (N) and every clamp's force
    /// there (N, per clamped group).
    pub final_force_n: f64,
    pub final_clamp_forces_n: Vec<Vec3>,
    /// Smallest contact distance / (rA + rB) over every step.
    pub min_distance_ratio: f64,
    pub steps: Vec<PoseStep>,
    pub minutes: f64,
    /// The warnings also given to the observer.
    pub warnings: Vec<String>,
}

impl TrainJob {
    fn invalid(&self, message: String) -> Error {
        Error::from(StageError::Invalid {
            path: self.asset.clone(),
            message,
        })
    }

    /// Refuses what is wrong with the request before any reading.
    fn check_request(&self) -> Result<(), Error> {
        io::overwrite::refuse_inputs(&[&self.output], &[&self.asset])?;
        check_asset_ext(&self.asset)?;
        let ext = self
            .output
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        if !matches!(ext.as_str(), "h5" | "hdf5") {
            return Err(IoError::Unsupported {
                path: self.output.clone(),
                message: "train writes knitvox HDF5 frames; name the output .h5 or .hdf5".into(),
            }
            .into());
        }
        self.pose
            .check()
            .map_err(|e| Error::Usage(format!("--pose {}: {e}", kind_name(self.pose.pose.kind))))
    }
}

/// What to do about rest yarns that pass through each other: the radius
/// they were embedded with, and where a smaller one is given.
fn radius_hint(rest: &crate::geom::Yarns) -> String {
    let radii: Vec<f64> = match &rest.vertex_radius {
        Some(v) => v.clone(),
        None => rest.radius.clone(),
    };
    let lo = radii.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = radii.iter().copied().fold(0.0, f64::max);
    let used = if lo < hi {
        format!("{lo:.3e} to {hi:.3e} m")
    } else {
        format!("{hi:.3e} m")
    };
    format!(
        "; the asset's yarns were read with a radius of {used}: embed the yarn file again with a \
         smaller `--radius` (and `--override-radius` where the file gives radii; in a job, \
         `[garment] radius`), or check its `--units`"
    )
}

/// The JSON record of the pose and the asset stored as `/metadata/pose_json`.
fn pose_record(job: &TrainJob, sha: &str, plane: FabricPlane, rest_shape: &str) -> String {
    let p = &job.pose.pose;
    serde_json::json!({
        "kind": kind_name(p.kind),
        "amount": p.amount,
        "mirror": p.mirror,
        "folds": p.folds,
        "band": p.band,
        "steps": job.pose.steps,
        "amounts": job.pose.stops(),
        "frame_amounts": job.pose.load_path(),
        "stop_frames": job.pose.stop_frames(),
        "gravity_m_s2": job.pose.gravity,
        "quasi_static": true,
        "fabric_plane": plane,
        "rest_shape": rest_shape,
        "asset": { "path": job.asset.display().to_string(), "sha256": sha },
    })
    .to_string()
}

impl Stage for TrainJob {
    type Report = TrainReport;
    const NAME: &'static str = "train";

    fn run(&self, observer: &mut dyn Observer) -> Result<TrainReport, Error> {
        let t0 = Instant::now();
        self.check_request()?;
        let sha = sha256_file(&self.asset)?;
        let asset = io::vtkhdf::read_asset(&self.asset)?;
        let rest = &asset.rest_yarns;
        let mut warnings = Vec::new();
        let rest_shape = if rest.rest.is_some() {
            "stored"
        } else {
            warnings.push(format!(
                "{}: the rest yarns carry no rest shape (rest lengths, curvatures): the rods take \
                 the relaxed positions as rest, so the swatch is not held by contact as knitted \
                 (embed the HDF5 output of `knitvox pattern` to keep it)",
                self.asset.display()
            ));
            "positions"
        };
        let (fabric, material) = self.fabric.for_yarns(rest, &self.material);
        warnings.extend(material.warning(&self.asset.display().to_string()));
        warnings.iter().for_each(|w| observer.warning(w));
        let plane = FabricPlane::of(&rest.points);
        let mut writer = FrameWriter::create(&self.output, rest)?;
        writer.add_text("pose_json", &pose_record(self, &sha, plane, rest_shape))?;
        let parameters = serde_json::json!({
            "generator": format!("knitvox {}", env!("CARGO_PKG_VERSION")),
            "fabric": fabric,
            "settle": self.pose.settle,
        });
        writer.add_text("parameters_json", &parameters.to_string())?;
        let total = self.pose.load_path().len();
        let mut last_frame = Instant::now();
        let mut on_frame = |f: &RigFrame| -> Result<(), IoError> {
            let r = writer
                .push(f.parameter, f.points)
                .and_then(|_| writer.push_mechanics(f.energy, &f.reactions, &f.external));
            observer.frame(&FrameProgress::of_rig(f.index, total, &mut last_frame));
            r
        };
        let run = run_pose(rest, &fabric, &self.pose, &mut on_frame).map_err(|e| match e {
            PoseRunError::Frame { error, .. } => Error::from(error),
            e => {
                let mut what = format!("pose {}: {e}", kind_name(self.pose.pose.kind));
                if let PoseRunError::Crossing { .. } = e {
                    what.push_str(&radius_hint(rest));
                }
                if e.is_usage() {
                    Error::Usage(what)
                } else {
                    self.invalid(what)
                }
            }
        })?;
        let output = writer.finish()?;
        if run.min_distance_ratio < 0.75 {
            let w = format!(
                "yarns came to {:.3} x 2r of each other (below 0.75: a yarn may have pulled through another)",
                run.min_distance_ratio
            );
            observer.warning(&w);
            warnings.push(w);
        }
        let last = run
            .steps
            .last()
            .ok_or_else(|| Error::Internal("a pose run returned no step".into()))?;
        Ok(TrainReport {
            asset: self.asset.clone(),
            asset_sha256: sha,
            output,
            pose: kind_name(self.pose.pose.kind),
            amount: self.pose.pose.amount,
            amounts: self.pose.stops(),
            stop_frames: self.pose.stop_frames(),
            mirror: self.pose.pose.mirror,
            gravity_m_s2: self.pose.gravity,
            frames: run.steps.len(),
            vertices: rest.num_points(),
            curves: rest.num_curves(),
            clamped_vertices: run.clamped_vertices,
            fabric_plane: run.plane,
            material,
            rest_shape,
            final_force_n: last.force_n,
            final_clamp_forces_n: last.clamp_forces_n.clone(),
            min_distance_ratio: run.min_distance_ratio,
            steps: run.steps.clone(),
            minutes: t0.elapsed().as_secs_f64() / 60.0,
            warnings,
        })
    }
}
