//! `knitvox yls SCENE.toml -o frames.h5`: runs a yarn-level scene
//! (schemas/yls-scene.md) and streams the frames into a knitvox HDF5 file
//! (rest yarns + frames + times) with the scene text and every simulator
//! parameter stored beside them (`/metadata/scene_toml`,
//! `/metadata/parameters_json`).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use crate::anim::Character;
use crate::geom::bvh::{MeshCollider, MeshTopology};
use crate::geom::{Vec3, Yarns};
use crate::io::{self, h5::FrameWriter, IoError};
use crate::pipeline::pattern::{generate, PatternJob, PatternSource, PatternStageError};
use crate::pipeline::util::median;
use crate::pipeline::yls_scene::{ColliderSpec, SceneError, YarnModel, YlsScene};
use crate::pipeline::{Error, ErrorClass, FrameProgress, Observer, Stage};
use crate::yarn::fabric::{FabricError, FabricParams, RelaxParams, RodDynamics, RodDynamicsParams};
use crate::yarn::pattern::{Layout, PatternParams};
use crate::yarn::poses::{PoseDriver, PoseError};
use crate::yarn::sim::{
    Handle, HandleMotion, PlaneCollider, PointCollider, SphereCollider, YarnSim, YarnSimError,
    YarnSimParams,
};

/// Errors of a yarn-level scene run; each names the scene file.
#[derive(Debug, thiserror::Error)]
pub enum YlsError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("{}: swatch: {source}", file.display())]
    Pattern {
        file: PathBuf,
        source: PatternStageError,
    },
    #[error("{}: the pose does not fit the swatch: {source}", file.display())]
    Pose { file: PathBuf, source: PoseError },
    #[error("{}: {message}", file.display())]
    Setup { file: PathBuf, message: String },
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{}: {source}", file.display())]
    Sim { file: PathBuf, source: YarnSimError },
    #[error("{}: rods model: {source}", file.display())]
    Rods { file: PathBuf, source: FabricError },
}

impl YlsError {
    /// The exit-code class. Divergence counts as bad input (the scene asks
    /// for something the simulator cannot do stably), like `simulate`.
    pub fn class(&self) -> ErrorClass {
        match self {
            YlsError::Io(e) => e.class().into(),
            YlsError::Pattern {
                source: PatternStageError::Read { .. },
                ..
            } => ErrorClass::Missing,
            _ => ErrorClass::BadInput,
        }
    }

    /// The file the error is about: the scene, or the file an I/O error
    /// names.
    pub fn file(&self) -> PathBuf {
        match self {
            YlsError::Scene(e) => e.file.clone(),
            YlsError::Io(e) => e.path().to_path_buf(),
            YlsError::Pattern { file, .. }
            | YlsError::Pose { file, .. }
            | YlsError::Setup { file, .. }
            | YlsError::Sim { file, .. }
            | YlsError::Rods { file, .. } => file.clone(),
        }
    }
}

/// What a run did (`--json` prints it).
#[derive(Debug, Clone, serde::Serialize)]
pub struct YlsReport {
    pub scene: String,
    pub output: PathBuf,
    pub vertices: usize,
    pub curves: usize,
    /// Output frames after the rest frame.
    pub frames: usize,
    pub steps: u64,
    /// Clamped (scripted) vertices.
    pub handled_vertices: usize,
    /// Minimum over every step of non-adjacent segment distance / 2r.
    pub min_distance_ratio: f64,
    /// Largest one-step vertex displacement / r.
    pub max_displacement_ratio: f64,
    /// Median wall time of one output frame (ms).
    pub ms_per_frame_median: f64,
    /// Wall time of the generated swatch's relaxation (ms; 0 without).
    pub relax_ms: f64,
    pub wall_s: f64,
    /// The yarn mechanics that ran (`explicit` or `rods`).
    pub model: YarnModel,
    /// `rods`: Newton iterations over all steps, the largest final force
    /// residual of a step (N), yarn-yarn contacts per vertex at the end and
    /// the deepest collider penetration (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub newton_iterations: Option<usize>,
    /// `rods`: steps retried as two half steps after Newton failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub split_steps: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_residual_n: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contacts_per_vertex: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_penetration_m: Option<f64>,
}

/// The yarn mechanics of a run.
enum Runner {
    Explicit(Box<YarnSim>),
    Rods(Box<RodDynamics>),
}

/// What one output frame's advance did.
#[derive(Default)]
struct FrameStats {
    steps: u64,
    min_ratio: f64,
    max_disp: f64,
    newton: usize,
    splits: u64,
    residual: f64,
    contacts_per_vertex: f64,
    penetration: f64,
}

impl FrameStats {
    /// What both models report: steps, minimum distance ratio, largest
    /// one-step displacement ratio.
    fn common(steps: u64, min_ratio: f64, max_disp: f64) -> FrameStats {
        FrameStats {
            steps,
            min_ratio,
            max_disp,
            ..FrameStats::default()
        }
    }
}

impl Runner {
    fn advance(&mut self, dt: f64, file: &Path) -> Result<FrameStats, YlsError> {
        match self {
            Runner::Explicit(sim) => {
                let st = sim.advance(dt).map_err(|source| YlsError::Sim {
                    file: file.into(),
                    source,
                })?;
                Ok(FrameStats::common(
                    st.steps,
                    st.min_distance_ratio,
                    st.max_displacement_ratio,
                ))
            }
            Runner::Rods(d) => {
                let st = d.advance(dt).map_err(|source| YlsError::Rods {
                    file: file.into(),
                    source,
                })?;
                Ok(FrameStats {
                    newton: st.newton_iterations,
                    splits: st.split_steps,
                    residual: st.max_residual_n,
                    contacts_per_vertex: st.contacts_per_vertex,
                    penetration: st.max_penetration_m,
                    ..FrameStats::common(st.steps, st.min_distance_ratio, st.max_displacement_ratio)
                })
            }
        }
    }

    fn time(&self) -> f64 {
        match self {
            Runner::Explicit(sim) => sim.time(),
            Runner::Rods(d) => d.time(),
        }
    }

    fn positions(&self) -> Vec<Vec3> {
        match self {
            Runner::Explicit(sim) => sim.positions().to_vec(),
            Runner::Rods(d) => d.points(),
        }
    }

    /// `rods`: the clamp force on each band ([`RodDynamics::band_forces`]);
    /// None for the explicit simulator, which keeps no internal-force
    /// split of its handles.
    fn band_forces(&mut self) -> Option<Vec<Vec3>> {
        match self {
            Runner::Explicit(_) => None,
            Runner::Rods(d) => Some(d.band_forces()),
        }
    }
}

/// The rods model's parameters for `scene`: `knitvox train`'s yarn model
/// (friction from `[rods]`), the scene's gravity, and the density and
/// global damping the explicit simulator would use (`[sim]`), so both
/// models and `validate`'s mesh see the same mass and damping; the yarn
/// material that `rest`'s rest shape was relaxed under, when recorded.
pub fn rods_params(
    scene: &YlsScene,
    sim: &YarnSimParams,
    rest: &Yarns,
) -> (FabricParams, RodDynamicsParams) {
    let spec = scene.rods.clone().unwrap_or_default();
    let (mut fabric, _) = FabricParams {
        density: sim.density,
        ..FabricParams::default()
    }
    .for_yarns(rest, &Default::default());
    if let Some(mu) = spec.friction {
        fabric.friction.mu = mu;
    }
    let d = RodDynamicsParams::default();
    let dynamics = RodDynamicsParams {
        max_dt: spec.max_dt.unwrap_or(d.max_dt),
        gravity: scene.gravity,
        global_damping: sim.global_damping,
        collider_stiffness: spec.collider_stiffness.unwrap_or(d.collider_stiffness),
        force_tolerance: spec.force_tolerance,
        ..d
    };
    (fabric, dynamics)
}

/// The rest yarns of a scene: a generated (and by default relaxed)
/// pattern, lying in the fabric frame as `knitvox pattern` writes it, or a
/// yarn file as it is.
pub fn scene_swatch(scene: &YlsScene, file: &Path) -> Result<(Yarns, f64), YlsError> {
    let s = &scene.swatch;
    if let Some(path) = &s.file {
        let d = io::read_path(path, &Default::default())?;
        // A fault of the swatch file's rest shape is the file's, not the scene's.
        crate::yarn::rods::check_rest_state(&d.yarns).map_err(|e| YlsError::Setup {
            file: path.clone(),
            message: e.to_string(),
        })?;
        return Ok((d.yarns, 0.0));
    }
    let source = match (&s.pattern, &s.grid) {
        (Some(name), _) => PatternSource::Builtin(name.clone()),
        (None, Some(grid)) => PatternSource::GridFile(grid.clone()),
        (None, None) => {
            return Err(YlsError::Setup {
                file: file.into(),
                message: "table `swatch` names no source".into(),
            })
        }
    };
    let mut params = PatternParams::default();
    if let Some(r) = s.yarn_radius {
        params.yarn_radius = r;
    }
    let job = PatternJob {
        source,
        layout: Layout {
            courses: s.courses.unwrap_or(12) as usize,
            wales: s.wales.unwrap_or(12) as usize,
            tube_radius: s.tube_radius,
            helix: false,
            separate_courses: false,
        },
        params,
        relax: s.relax.unwrap_or(true).then(RelaxParams::default),
        material: crate::yarn::fabric::FabricParams::default().material(),
    };
    let t = Instant::now();
    let (yarns, _) = generate(&job).map_err(|source| YlsError::Pattern {
        file: file.into(),
        source,
    })?;
    let relax_ms = t.elapsed().as_secs_f64() * 1e3;
    Ok((yarns, relax_ms))
}

/// Simulator parameters: defaults, the scene's gravity, then `[sim]`
/// overrides by field name (unknown names are errors naming the key).
pub fn scene_params(scene: &YlsScene, file: &Path) -> Result<YarnSimParams, YlsError> {
    let mut table = scene.sim.clone();
    if !table.contains_key("gravity") {
        table.insert(
            "gravity".into(),
            toml::Value::Array(
                scene
                    .gravity
                    .iter()
                    .map(|g| toml::Value::Float(*g))
                    .collect(),
            ),
        );
    }
    let p: YarnSimParams = toml::Value::Table(table)
        .try_into()
        .map_err(|e: toml::de::Error| YlsError::Setup {
            file: file.into(),
            message: format!("table `sim`: {}", e.to_string().trim_end()),
        })?;
    p.validate().map_err(|source| YlsError::Sim {
        file: file.into(),
        source,
    })?;
    Ok(p)
}

/// Why a character cannot be made into a yarn collider.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CharacterColliderError {
    /// The file has no animation of this name.
    #[error("no animation {name:?}; the file has {known:?}")]
    UnknownAnimation { name: String, known: Vec<String> },
    /// The character has no skinned triangles to collide with.
    #[error("the character has no skinned triangles")]
    NoSkinnedTriangles,
}

/// A skinned glTF body as a yarn collider: the body is posed at the query
/// time (re-posed when the time moves by more than `repose_s`) and the
/// signed distance comes from the mesh's BVH and pseudo-normals.
#[derive(Debug)]
pub struct CharacterCollider {
    character: Character,
    animation: Option<usize>,
    scale: f64,
    offset: Vec3,
    topology: MeshTopology,
    repose_s: f64,
    posed: Mutex<Option<(f64, Arc<MeshCollider>)>>,
}

impl CharacterCollider {
    /// `animation` by name (`None`: bind pose). Errors name the animation.
    pub fn new(
        character: Character,
        animation: Option<&str>,
        scale: f64,
        offset: Vec3,
    ) -> Result<CharacterCollider, CharacterColliderError> {
        let animation = match animation {
            None => None,
            Some(name) => Some(character.animation_index(name).ok_or_else(|| {
                CharacterColliderError::UnknownAnimation {
                    name: name.to_string(),
                    known: character.animation_names(),
                }
            })?),
        };
        let rest = character.body_mesh(None, 0.0);
        if rest.triangles.is_empty() {
            return Err(CharacterColliderError::NoSkinnedTriangles);
        }
        let (topology, _) = MeshTopology::welded(&rest.triangles, &rest.positions);
        Ok(CharacterCollider {
            character,
            animation,
            scale,
            offset,
            topology,
            repose_s: 1.0 / 600.0,
            posed: Mutex::new(None),
        })
    }

    fn mesh_at(&self, t: f64) -> Option<Arc<MeshCollider>> {
        let mut g = self.posed.lock().ok()?;
        if let Some((t0, m)) = g.as_ref() {
            if (t - t0).abs() <= self.repose_s {
                return Some(m.clone());
            }
        }
        let body = self.character.body_mesh(self.animation, t);
        let pos: Vec<Vec3> = body
            .positions
            .iter()
            .map(|p| std::array::from_fn(|k| self.scale * p[k] + self.offset[k]))
            .collect();
        let m = Arc::new(MeshCollider::new(&self.topology, &pos).ok()?);
        *g = Some((t, m.clone()));
        Some(m)
    }
}

impl PointCollider for CharacterCollider {
    fn signed_distance(&self, p: Vec3, t: f64) -> (f64, Vec3) {
        match self.mesh_at(t).and_then(|m| m.closest(p)) {
            Some(hit) => (hit.signed_distance, hit.outward),
            None => (f64::INFINITY, [0.0, 1.0, 0.0]),
        }
    }
}

/// Runs `scene` (read from `file`, text `text`) and writes `out`.
/// `progress(done, total)` after every frame.
pub fn run(
    scene: &YlsScene,
    text: &str,
    file: &Path,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<YlsReport, YlsError> {
    run_observed(scene, text, file, out, &mut |p| progress(p.done, p.total))
}

/// [`run`], reporting each frame (number from 1, wall time) to `on_frame`.
pub fn run_observed(
    scene: &YlsScene,
    text: &str,
    file: &Path,
    out: &Path,
    on_frame: &mut dyn FnMut(&FrameProgress),
) -> Result<YlsReport, YlsError> {
    let t0 = Instant::now();
    // The files the scene names are inputs too (exit 2 if `out` is one).
    let characters = scene.colliders.iter().filter_map(|c| match c {
        ColliderSpec::Character { file, .. } => Some(file.as_path()),
        _ => None,
    });
    let inputs: Vec<&Path> = [Some(file), scene.swatch.file.as_deref()]
        .into_iter()
        .chain([scene.swatch.grid.as_deref()])
        .flatten()
        .chain(characters)
        .collect();
    io::overwrite::refuse_inputs(&[out], &inputs)?;
    // The pose's counts are refused before a swatch is built or relaxed.
    scene
        .pose_params()
        .check()
        .map_err(|source| YlsError::Pose {
            file: file.into(),
            source,
        })?;
    let (rest, relax_ms) = scene_swatch(scene, file)?;
    let params = scene_params(scene, file)?;
    let sim_err = |source| YlsError::Sim {
        file: file.into(),
        source,
    };
    let driver = Arc::new(PoseDriver::new(&rest.points, scene.pose_params()).map_err(
        |source| YlsError::Pose {
            file: file.into(),
            source,
        },
    )?);
    let colliders = scene_colliders(&scene.colliders, &rest)?;
    let (mut runner, model_record) = match scene.model {
        YarnModel::Explicit => {
            let mut sim = YarnSim::new(&rest, params.clone()).map_err(sim_err)?;
            for g in 0..driver.num_groups() {
                sim.add_handle(Handle {
                    vertices: driver.group_vertices(g).to_vec(),
                    motion: HandleMotion::Pose {
                        driver: driver.clone(),
                        group: g,
                    },
                    start_time: 0.0,
                })
                .map_err(sim_err)?;
            }
            for collider in colliders {
                sim.add_collider(collider);
            }
            (Runner::Explicit(Box::new(sim)), format!("{params:?}"))
        }
        YarnModel::Rods => {
            let (fabric, dynamics) = rods_params(scene, &params, &rest);
            let record = format!("{fabric:?} {dynamics:?}");
            let d = RodDynamics::new(
                &rest,
                &fabric,
                &dynamics,
                Some(driver.clone()),
                colliders.into_iter().map(Arc::from).collect(),
            )
            .map_err(|source| YlsError::Rods {
                file: file.into(),
                source,
            })?;
            (Runner::Rods(Box::new(d)), record)
        }
    };

    let mut writer = FrameWriter::create(out, &rest)?;
    writer.add_text("scene_toml", text)?;
    let record = serde_json::json!({
        "generator": format!("knitvox {}", env!("CARGO_PKG_VERSION")),
        "scene_file": file.display().to_string(),
        "model": scene.model,
        "yarn_sim_parameters": model_record,
        "pose": format!("{:?}", scene.pose_params()),
        "handled_vertices": driver.pinned().len(),
    });
    writer.add_text("parameters_json", &record.to_string())?;
    writer.push(0.0, &rest.points)?;
    // Clamp forces per frame and band, from the rest frame on.
    let mut band_forces: Option<Vec<Vec<Vec3>>> = runner.band_forces().map(|f| vec![f]);
    let frames = scene.num_frames();
    let frame_dt = 1.0 / scene.frame_rate;
    let mut total = FrameStats {
        min_ratio: f64::INFINITY,
        ..FrameStats::default()
    };
    let mut ms = Vec::with_capacity(frames);
    for f in 1..=frames {
        let tf = Instant::now();
        let st = runner.advance(frame_dt, file)?;
        ms.push(tf.elapsed().as_secs_f64() * 1e3);
        total.steps += st.steps;
        total.min_ratio = total.min_ratio.min(st.min_ratio);
        total.max_disp = total.max_disp.max(st.max_disp);
        total.newton += st.newton;
        total.splits += st.splits;
        total.residual = total.residual.max(st.residual);
        total.contacts_per_vertex = st.contacts_per_vertex;
        total.penetration = total.penetration.max(st.penetration);
        writer.push(runner.time(), &runner.positions())?;
        if let (Some(all), Some(f)) = (band_forces.as_mut(), runner.band_forces()) {
            all.push(f);
        }
        on_frame(&FrameProgress {
            frame: f as i64,
            done: f,
            total: frames,
            ms: ms[ms.len() - 1],
            residual: None,
            penetration_m: None,
        });
    }
    // The run's wall time travels with the frames: `validate --truth`
    // reuses them and reports this time as the yarn level's.
    let wall_s = t0.elapsed().as_secs_f64();
    if let Some(all) = band_forces
        .as_ref()
        .filter(|a| a.iter().all(|f| !f.is_empty()))
    {
        writer.add_clamp_forces(all)?;
    }
    writer.add_text(
        "run_json",
        &serde_json::json!({ "wall_s": wall_s, "steps": total.steps }).to_string(),
    )?;
    let output = writer.finish()?;
    let rods = scene.model == YarnModel::Rods;
    Ok(YlsReport {
        scene: scene.name.clone(),
        output,
        vertices: rest.num_points(),
        curves: rest.num_curves(),
        frames,
        steps: total.steps,
        handled_vertices: driver.pinned().len(),
        min_distance_ratio: total.min_ratio,
        max_displacement_ratio: total.max_disp,
        ms_per_frame_median: median(ms),
        relax_ms,
        wall_s,
        model: scene.model,
        newton_iterations: rods.then_some(total.newton),
        split_steps: rods.then_some(total.splits),
        max_residual_n: rods.then_some(total.residual),
        contacts_per_vertex: rods.then_some(total.contacts_per_vertex),
        max_penetration_m: rods.then_some(total.penetration),
    })
}

/// The yarn-level scene stage: a scene file -> knitvox HDF5 frames.
#[derive(Debug, Clone)]
pub struct YlsJob {
    /// Scene file (schemas/yls-scene.md).
    pub scene: PathBuf,
    /// Output knitvox HDF5 file (.h5 or .hdf5).
    pub output: PathBuf,
}

impl Stage for YlsJob {
    type Report = YlsReport;
    const NAME: &'static str = "yls";
    fn run(&self, observer: &mut dyn Observer) -> Result<YlsReport, Error> {
        let ext = self
            .output
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("");
        if !matches!(ext.to_ascii_lowercase().as_str(), "h5" | "hdf5") {
            return Err(IoError::Unsupported {
                path: self.output.clone(),
                message: "yls writes knitvox HDF5 frames; name the output .h5 or .hdf5".into(),
            }
            .into());
        }
        let text =
            crate::io::input::read_input_text(&self.scene, "scene", crate::io::max_memory())?;
        let scene = YlsScene::parse(&text, &self.scene).map_err(YlsError::from)?;
        Ok(run_observed(
            &scene,
            &text,
            &self.scene,
            &self.output,
            &mut |p| observer.frame(p),
        )?)
    }
}

/// A point of the plane with `normal` that passes under `c` (the centre of
/// `rest`'s bounds) one yarn diameter (`2 r_max`) below its lowest yarn
/// point along the normal.
fn plane_under(rest: &crate::geom::Yarns, c: Vec3, normal: Vec3, r_max: f64) -> Vec3 {
    let len = crate::geom::vec3::norm(normal);
    let n = normal.map(|c| c / len);
    let lowest = rest
        .points
        .iter()
        .map(|p| crate::geom::vec3::dot(crate::geom::vec3::sub(*p, c), n))
        .fold(0.0, f64::min);
    std::array::from_fn(|i| c[i] + (lowest - 2.0 * r_max) * n[i])
}

/// The colliders of a yls scene, as both the yarn-level run and `validate`
/// use them: a sphere without `center` sits under the centre of `rest`,
/// its top one yarn diameter below the lowest yarn point.
pub fn scene_colliders(
    specs: &[ColliderSpec],
    rest: &crate::geom::Yarns,
) -> Result<Vec<Box<dyn PointCollider>>, YlsError> {
    let (lo, hi) = rest
        .bounds()
        .map_or(([0.0; 3], [0.0; 3]), |b| (b.min, b.max));
    let r_max = (0..rest.num_points())
        .map(|v| rest.radius_at(v))
        .fold(0.0, f64::max);
    let centre: Vec3 = std::array::from_fn(|i| 0.5 * (lo[i] + hi[i]));
    let mut out: Vec<Box<dyn PointCollider>> = Vec::with_capacity(specs.len());
    for c in specs {
        out.push(match c {
            ColliderSpec::Plane {
                point,
                normal,
                friction,
            } => Box::new(PlaneCollider {
                point: point.unwrap_or_else(|| plane_under(rest, centre, *normal, r_max)),
                normal: *normal,
                friction: *friction,
            }),
            ColliderSpec::Sphere {
                center,
                offset,
                radius,
                friction,
                velocity,
            } => Box::new(SphereCollider {
                center: center.unwrap_or_else(|| {
                    let o = offset.unwrap_or([0.0; 3]);
                    [
                        centre[0] + o[0],
                        lo[1] - 2.0 * r_max - radius + o[1],
                        centre[2] + o[2],
                    ]
                }),
                radius: *radius,
                velocity: velocity.unwrap_or([0.0; 3]),
                friction: *friction,
            }),
            ColliderSpec::Character {
                file,
                animation,
                scale,
                offset,
            } => {
                let ch = io::gltf_skin::read_character(file)?;
                Box::new(
                    CharacterCollider::new(
                        ch,
                        animation.as_deref(),
                        scale.unwrap_or(1.0),
                        offset.unwrap_or([0.0; 3]),
                    )
                    .map_err(|e| YlsError::Setup {
                        file: file.clone(),
                        message: e.to_string(),
                    })?,
                )
            }
        });
    }
    Ok(out)
}

impl crate::pipeline::error::StageFailure for YlsError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        YlsError::class(self)
    }
    fn file(&self) -> Option<std::path::PathBuf> {
        Some(YlsError::file(self))
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<YlsError> for crate::pipeline::Error {
    fn from(e: YlsError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{RestShape, YarnMaterial};

    /// A plane without `point` lies one yarn diameter below the swatch's
    /// lowest point along its normal, however it is tilted; a sphere's
    /// `offset` shifts its default placement.
    #[test]
    fn default_colliders_sit_a_yarn_diameter_below_the_swatch() {
        let mut y = Yarns::new();
        y.push_curve(
            &[[0.0, 0.0, 0.0], [0.02, 0.003, 0.0], [0.04, 0.0, 0.01]],
            false,
            0.001,
        );
        let tilt = [0.342_020_143_325_668_7, 0.939_692_620_785_908_4, 0.0];
        let text = format!(
            "duration = 0.1\nframe_rate = 30\n[swatch]\npattern = \"rib1x1\"\n[pose]\nkind = \"free\"\namount = 0.0\n\
             [[colliders]]\ntype = \"plane\"\nnormal = {tilt:?}\n\
             [[colliders]]\ntype = \"sphere\"\nradius = 0.03\n\
             [[colliders]]\ntype = \"sphere\"\nradius = 0.03\noffset = [0.01, 0.0, -0.005]\n"
        );
        let scene = YlsScene::parse(&text, Path::new("s.toml")).unwrap();
        let c = scene_colliders(&scene.colliders, &y).unwrap();
        let lowest = y
            .points
            .iter()
            .map(|p| c[0].signed_distance(*p, 0.0).0)
            .fold(f64::INFINITY, f64::min);
        assert!((lowest - 0.002).abs() < 1e-12, "{lowest}");
        // The sphere's top under the centre (0.02, 0.005): one diameter
        // below the lowest point (y = 0), then shifted.
        let top = |k: usize, x: f64, z: f64| c[k].signed_distance([x, 0.0, z], 0.0).0;
        assert!((top(1, 0.02, 0.005) - 0.002).abs() < 1e-12);
        assert!((top(2, 0.03, 0.0) - 0.002).abs() < 1e-12);
        let both = text.replace("offset = [", "center = [0.0, 0.0, 0.0]\noffset = [");
        let e = YlsScene::parse(&both, Path::new("s.toml")).unwrap_err();
        assert!(e.to_string().contains("give one"), "{e}");
    }

    #[test]
    fn the_rods_model_runs_under_the_rest_shapes_material() {
        let text =
            "model = \"rods\"\nduration = 0.1\nframe_rate = 30\n[swatch]\npattern = \"rib1x1\"\n\
                    [pose]\nkind = \"stretch_courses\"\namount = 0.1\n";
        let scene = YlsScene::parse(text, Path::new("s.toml")).unwrap();
        let sim = YarnSimParams {
            density: 60.0,
            ..YarnSimParams::default()
        };
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1e-3, 0.0, 0.0]], false, 1e-3);
        let (f, _) = rods_params(&scene, &sim, &y);
        assert_eq!(f.material(), FabricParams::default().material());
        let m = YarnMaterial::from_values([5e6, 2e6, 0.1, 30.0]);
        y.rest = Some(RestShape {
            material: Some(m),
            ..Default::default()
        });
        let (f, _) = rods_params(&scene, &sim, &y);
        assert_eq!((f.material(), f.density), (m, 60.0));
    }
}
