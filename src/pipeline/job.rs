//! Job manifests (`knitvox run JOB.toml`; schemas/job.md) and stage caching.
//!
//! A job names the garment yarns, the character, the frames and the stages
//! (`embed` -> `shot` -> `export`). Each stage's key is the SHA-256 of the
//! knitvox version, the stage name, its parameters (canonical JSON), the
//! contents of its input files and the upstream stage's key, so a changed
//! input or parameter changes that stage's key and every key downstream
//! (Houdini PDG's cook-from-cache rule). A record `OUT/.knitvox/STAGE.json`
//! is written atomically after the stage's outputs exist; a rerun skips a
//! stage whose record holds the same key and whose outputs all exist.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::asset::{EmbedJob, ExportJob};
use super::fit::FitJob;
use super::sim_scene::{shown_number, CharacterSection, Scene, Seconds};
use super::simulate::{
    read_scene, ChunkOptions, ChunkedShotJob, ShotJob, ShotRequest, DEFAULT_CHECKPOINT_EVERY,
};
use super::train::TrainJob;
use super::util::sha256_file;
use super::{Error, Observer, Stage};
use crate::embed::EmbedParams;
use crate::fit::elastic::ElasticFitParams;
use crate::geom::{FrameSpec, Units, UpAxis, Vec3};
use crate::io::confined::{resolve_inside, ConfinedError};
use crate::io::{self, IoError, ReadOptions, WriteOptions};
use crate::yarn::fabric::pose::PoseRunParams;
use crate::yarn::fabric::FabricParams;

/// The stages a job may hold, in run order.
pub const STAGES: [&str; 5] = ["embed", "train", "fit", "shot", "export"];

/// A job manifest as written (schemas/job.md, schemas/job.schema.json).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Output folder [default: `<manifest stem>.out` beside the manifest].
    pub output: Option<PathBuf>,
    /// Farm frames of the shot: `1-24`, `1001-1100x5`.
    pub frames: Option<String>,
    pub garment: Garment,
    pub character: Option<Character>,
    pub embed: Option<EmbedSection>,
    /// Training poses (`knitvox train`), one farm task each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub train: Vec<TrainSection>,
    /// Fit the asset's materials to the training poses (`knitvox fit`); the
    /// shot then simulates the fitted asset.
    pub fit: Option<FitSection>,
    pub shot: Option<ShotSection>,
    pub export: Option<ExportSection>,
}

/// `[[train]] amount`: one amplitude or a list of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Amounts {
    One(f64),
    Many(Vec<f64>),
}

impl Amounts {
    /// The listed amplitudes (one for `One`).
    pub fn values(&self) -> Vec<f64> {
        match self {
            Amounts::One(a) => vec![*a],
            Amounts::Many(v) => v.clone(),
        }
    }
}

/// `[[train]]`: one VH §8.6 training pose at yarn level (`knitvox train`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSection {
    /// Pose kind (`stretch_courses`, `bend_central`, ...; schemas/yls-scene.md).
    pub kind: String,
    /// Strain, or rad for bends and twist [default: `train`'s per kind]; a
    /// list (`[0.02, 0.1, 0.2]`) loads through each amplitude in order.
    pub amount: Option<Amounts>,
    /// The mirrored counterpart [default false].
    pub mirror: Option<bool>,
    /// Load steps [default 10].
    pub steps: Option<usize>,
    /// Yarn-on-yarn friction coefficient [default `train`'s].
    pub friction: Option<f64>,
    /// Gravity along the fabric's normal (m/s²) [default 0; `cantilever`
    /// needs it].
    pub gravity: Option<f64>,
    /// Clamped band width as a fraction of the swatch extent (`train
    /// --band`; cantilever: the held fraction) [default 0.06].
    pub band: Option<f64>,
}

/// `[fit]`: per-element materials from the training poses (`knitvox fit`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSection {
    /// Frames fitted per pose [default `fit`'s].
    pub samples: Option<usize>,
    /// Harmonic ranks before the full field [default [1, 10, 30]].
    pub harmonic: Option<Vec<usize>>,
    /// Fit every pose's frames together (VH Eq. 9) [default false].
    pub joint: Option<bool>,
    /// Also fit course and wale fibres (`fit --fibres`) [default false].
    /// Left out of the stage key when unset, so earlier jobs keep theirs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fibres: Option<bool>,
    /// Material model (`fit --model`) [default knit]. The stage key holds
    /// the model that runs, so a fit made under another default reruns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<super::fit::FitModel>,
}

impl Manifest {
    /// The default job of a bare yarn file (a watch-folder drop without a
    /// sidecar): embed, and export of the embedded rest shape (the yarns as
    /// the asset carries them, `export/garment.0000.ply`). A shot needs a
    /// scene or character, which a bare yarn file does not name.
    pub fn for_yarns(yarns: PathBuf) -> Manifest {
        Manifest {
            garment: Garment {
                yarns,
                ..Garment::default()
            },
            export: Some(ExportSection::default()),
            ..Manifest::default()
        }
    }

    /// Rewrites every path the manifest names (output, garment yarns,
    /// scene, character file) with `f`: a manifest moved to another folder
    /// (the watch daemon's `work/NAME/job.toml`) keeps naming the same files.
    pub fn map_paths(&mut self, f: impl Fn(&Path) -> PathBuf) {
        if let Some(o) = &mut self.output {
            *o = f(o);
        }
        self.garment.yarns = f(&self.garment.yarns);
        if let Some(s) = self.shot.as_mut().and_then(|s| s.scene.as_mut()) {
            *s = f(s);
        }
        if let Some(c) = &mut self.character {
            c.file = f(&c.file);
        }
    }

    /// The manifest as TOML text (what [`Job::load`] reads back).
    pub fn to_toml(&self) -> Result<String, Error> {
        toml::to_string(self).map_err(|e| Error::Internal(format!("manifest as TOML: {e}")))
    }
}

/// The garment's yarns.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Garment {
    /// Yarn file (any readable format).
    pub yarns: PathBuf,
    /// Unit of a unitless file (`mm`, `cm`, `m` or metres per unit) [default: the file's, else m].
    pub units: Option<String>,
    /// Up axis (`y` or `z`) [default: the file's, else y].
    pub up_axis: Option<String>,
    /// Yarn radius (m) for files without one, or for all with
    /// `override_radius` (`--radius`) [default 1 mm].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Use `radius` even where the file gives radii (`--override-radius`)
    /// [default false].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub override_radius: Option<bool>,
    /// Polyline samples per span of BCC spline curves, 1 to 64
    /// (`--spline-samples`) [default 1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spline_samples: Option<i64>,
    /// Repeats of a periodic `.pyp` tile along its two periods, `"NxM"`
    /// or `[N, M]` (`--tile`) [default 1x1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile: Option<Tile>,
}

/// `[garment] tile`: `"NxM"` or `[N, M]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Tile {
    Text(String),
    Pair(Vec<i64>),
}

impl Tile {
    /// The repeats, each 1 to [`io::MAX_TILE_REPEATS`], or what is wrong.
    pub fn repeats(&self) -> Result<[usize; 2], String> {
        let max = io::MAX_TILE_REPEATS;
        let each = |n: i64| {
            usize::try_from(n)
                .ok()
                .filter(|n| (1..=max).contains(n))
                .ok_or_else(|| format!("{n} repeats is out of range (each must be 1 to {max})"))
        };
        match self {
            Tile::Pair(v) => match v[..] {
                [a, b] => Ok([each(a)?, each(b)?]),
                _ => Err(format!("give two repeats, [N, M], not {}", v.len())),
            },
            Tile::Text(t) => {
                let shown = crate::geom::excerpt(t);
                let (a, b) = t
                    .to_ascii_lowercase()
                    .split_once('x')
                    .map(|(a, b)| (a.trim().to_string(), b.trim().to_string()))
                    .ok_or_else(|| format!("'{shown}' is not NxM (e.g. \"2x3\")"))?;
                match (a.parse::<i64>(), b.parse::<i64>()) {
                    (Ok(a), Ok(b)) => Ok([each(a)?, each(b)?]),
                    _ => Err(format!("'{shown}' is not NxM (e.g. \"2x3\")")),
                }
            }
        }
    }
}

/// The character driving the shot (as `simulate --character` takes it).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Character {
    /// glTF/GLB with a skin, or an HDF5 character cache.
    pub file: PathBuf,
    /// Animation name [default: the file's first].
    pub animation: Option<String>,
    /// Metres per file unit [default 1].
    pub scale: Option<f64>,
    /// Garment nodes within this distance (m) of the bind-pose body are pinned.
    pub pin_distance: Option<f64>,
    /// Lay the garment on the body over this joint.
    pub fit_joint: Option<String>,
}

/// `[embed]`: embedding parameters ([`EmbedParams`] defaults).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmbedSection {
    /// Voxel edge length (m) [default: VH §4 rule].
    pub voxel_size: Option<f64>,
    /// Refuse embeddings with more voxels than this.
    pub max_voxels: Option<u64>,
    /// Yarn material density (kg/m^3).
    pub density: Option<f64>,
    /// Material cards (`CARD.toml`, `CARD.toml@curves=..`,
    /// `CARD.toml@box=..`; paths relative to the manifest), as `embed
    /// --card` takes them [default: the placeholder material].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cards: Option<Vec<String>>,
}

/// `[shot]`: a scene file, or the top-level `[character]` with these options.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShotSection {
    /// Scene file (schemas/sim-scene.md); excludes `[character]`.
    pub scene: Option<PathBuf>,
    /// Largest time step (s).
    pub dt: Option<f64>,
    /// Frames per second.
    pub fps: Option<f64>,
    /// Pre-roll (s).
    pub preroll: Option<f64>,
    /// `cpu`, `gpu` or `auto`.
    pub backend: Option<String>,
    /// `direct` or `dd`.
    pub solver: Option<String>,
    /// Garment rotation (degrees about x, y, z).
    pub garment_rotate: Option<Vec3>,
    /// Garment translation (m).
    pub garment_offset: Option<Vec3>,
    /// Checkpoint the shot every this many frames (and on SIGTERM), so a
    /// stopped or killed run resumes instead of starting over [default 10;
    /// 0: only on SIGTERM]. Not part of the shot's key.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint_every: Option<usize>,
}

/// `[export]`: per-frame files of the shot (or of the embedded asset).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportSection {
    /// `ply`, `bcc`, `obj`, `gltf`, `glb` or `h5` [default ply].
    pub format: Option<String>,
    /// Steps to export, 0-based [default: all].
    pub steps: Option<String>,
    /// Unit of written bcc/obj/ply coordinates [default m].
    pub units: Option<String>,
    /// Up axis of written bcc/obj/ply coordinates [default y].
    pub up_axis: Option<String>,
    /// Base name of the files [default `garment`].
    pub name: Option<String>,
}

/// A manifest that cannot be used: the file and the key.
fn bad(path: &Path, message: String) -> Error {
    IoError::Unsupported {
        path: path.to_path_buf(),
        message,
    }
    .into()
}

fn parse_key<T: std::str::FromStr<Err: std::fmt::Display>>(
    path: &Path,
    key: &str,
    v: &Option<String>,
) -> Result<Option<T>, Error> {
    v.as_deref()
        .map(|s| {
            s.parse::<T>()
                .map_err(|e| bad(path, format!("key '{key}': {e}")))
        })
        .transpose()
}

/// A loaded job: the manifest with paths resolved against its folder.
#[derive(Debug, Clone)]
pub struct Job {
    pub path: PathBuf,
    pub manifest: Manifest,
    pub base: PathBuf,
    pub output: PathBuf,
    /// SIGTERM as the CLI relays it: a running shot checkpoints under
    /// `OUT/checkpoints/` and stops (exit 75); the next run resumes it.
    /// `None` [the default of `load`]: signals are not this job's business.
    pub interrupt: Option<&'static super::Interrupt>,
    /// Folders besides the manifest's own that the job may read from
    /// (`run --allow-root`), resolved.
    allowed: Vec<PathBuf>,
    /// Every file the job reads, each inside the allowed folders.
    inputs: Vec<JobInput>,
    /// The shot stage skips, with a warning, a checkpoint in
    /// `OUT/checkpoints/` it cannot use, instead of failing (exit 65)
    /// ([`ChunkOptions::resume_or_restart`]) [default of `load`: false].
    pub resume_or_restart: bool,
}

/// A file a job reads: the key that names it, the path as written, the
/// path it is read from (against the manifest's or the scene's folder) and
/// where that resolves (symlinks followed).
#[derive(Debug, Clone, PartialEq)]
pub struct JobInput {
    /// `[garment] yarns`, `[shot] scene`, `[character] file`, or `[character]
    /// file of the scene 'S'`.
    pub key: String,
    pub written: PathBuf,
    pub path: PathBuf,
    pub resolved: PathBuf,
}

/// A job that would read outside its folders or overwrite its own inputs.
/// Paths are shown as written, cut to an excerpt; no file is read to decide.
#[derive(Debug, thiserror::Error)]
pub enum JobPathError {
    /// A path resolves (symlinks followed) outside every allowed folder.
    #[error("{}: {key} '{}': {source}; `knitvox run --allow-root DIR` allows another folder", manifest.display(), excerpt_path(written))]
    Outside {
        manifest: PathBuf,
        key: String,
        written: PathBuf,
        #[source]
        source: ConfinedError,
    },
    /// A path cannot be resolved (missing, unreadable folder).
    #[error("{}: {key} '{}': cannot read: {source}", manifest.display(), excerpt_path(written))]
    Unreadable {
        manifest: PathBuf,
        key: String,
        written: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// An output of a stage is, or would replace, one of the job's inputs.
    #[error("{}: stage '{stage}' would write '{}', which is the input {key} '{}': a job never overwrites its own inputs; choose another `output` folder or `[export] name`",
        manifest.display(), output.display(), excerpt_path(written))]
    OutputIsInput {
        manifest: PathBuf,
        stage: &'static str,
        output: PathBuf,
        key: String,
        written: PathBuf,
    },
}

fn excerpt_path(p: &Path) -> String {
    crate::geom::excerpt(&p.display().to_string())
}

impl JobPathError {
    pub fn class(&self) -> super::ErrorClass {
        match self {
            JobPathError::Outside { .. } => super::ErrorClass::BadInput,
            JobPathError::Unreadable { .. } => super::ErrorClass::Missing,
            JobPathError::OutputIsInput { .. } => super::ErrorClass::Usage,
        }
    }
}

impl super::StageFailure for JobPathError {
    fn class(&self) -> super::ErrorClass {
        JobPathError::class(self)
    }
    fn file(&self) -> Option<PathBuf> {
        match self {
            JobPathError::Outside { manifest, .. }
            | JobPathError::Unreadable { manifest, .. }
            | JobPathError::OutputIsInput { manifest, .. } => Some(manifest.clone()),
        }
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<JobPathError> for Error {
    fn from(e: JobPathError) -> Self {
        Error::stage(e)
    }
}

/// A manifest number that must be finite and satisfy `ok`; `rule` says
/// what it must be. The message shows the value short.
fn number(
    path: &Path,
    key: &str,
    v: Option<f64>,
    ok: impl Fn(f64) -> bool,
    rule: &str,
) -> Result<(), Error> {
    match v {
        Some(x) if !(x.is_finite() && ok(x)) => Err(bad(
            path,
            format!(
                "key '{key}': {} is out of range (must be {rule})",
                shown_number(x)
            ),
        )),
        _ => Ok(()),
    }
}

impl Job {
    /// Reads and checks a manifest (exit 65 naming the file and key; 66 when
    /// missing): every file it names must lie inside the manifest's folder.
    pub fn load(path: &Path) -> Result<Job, Error> {
        Job::load_allowing(path, &[])
    }

    /// [`Job::load`], with the job also reading from the folders `allowed`
    /// (`run --allow-root`; relative ones against the working folder).
    /// Before any stage: numbers in range, every input (the scene's
    /// character too) resolved inside the manifest's folder or one of
    /// `allowed` (exit 65), no output of a stage on an input (exit 2).
    pub fn load_allowing(path: &Path, allowed: &[PathBuf]) -> Result<Job, Error> {
        let text = crate::io::input::read_input_text(path, "manifest", crate::io::max_memory())?;
        let manifest: Manifest = toml::from_str(&text)
            .map_err(|e| bad(path, super::sim_scene::toml_error_line(&e, &text)))?;
        let base = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .map(Path::to_path_buf)
            .unwrap_or_default();
        let stem = path.file_stem().unwrap_or_default().to_string_lossy();
        let output = match &manifest.output {
            Some(o) => base.join(o),
            None => base.join(format!("{stem}.out")),
        };
        let mut job = Job {
            path: path.to_path_buf(),
            manifest,
            base,
            output,
            interrupt: None,
            allowed: Vec::new(),
            inputs: Vec::new(),
            resume_or_restart: false,
        };
        job.check()?;
        job.allowed = allowed
            .iter()
            .map(|r| {
                std::fs::canonicalize(r).map_err(|source| {
                    Error::Usage(format!(
                        "--allow-root '{}': cannot resolve the folder: {source}",
                        excerpt_path(r)
                    ))
                })
            })
            .collect::<Result<_, _>>()?;
        job.inputs = job.check_confined(&job.allowed)?;
        job.check_outputs(&job.inputs)?;
        Ok(job)
    }

    /// The folders besides the manifest's own this job may read from.
    pub fn allowed_roots(&self) -> &[PathBuf] {
        &self.allowed
    }

    /// Every file the job reads (as checked by [`Job::load_allowing`]).
    pub fn inputs(&self) -> &[JobInput] {
        &self.inputs
    }

    /// The manifest's folder and `allowed`: where the job may read.
    fn roots(&self, allowed: &[PathBuf]) -> Vec<PathBuf> {
        let own = if self.base.as_os_str().is_empty() {
            PathBuf::from(".")
        } else {
            self.base.clone()
        };
        std::iter::once(own)
            .chain(allowed.iter().cloned())
            .collect()
    }

    /// `path` (read as `key` names it) resolved inside `roots`, or why not.
    fn confine(
        &self,
        key: &str,
        written: &Path,
        path: &Path,
        roots: &[PathBuf],
    ) -> Result<JobInput, Error> {
        let resolved = resolve_inside(path, roots).map_err(|e| match e {
            ConfinedError::Read { source, .. } => JobPathError::Unreadable {
                manifest: self.path.clone(),
                key: key.into(),
                written: written.to_path_buf(),
                source,
            },
            other => JobPathError::Outside {
                manifest: self.path.clone(),
                key: key.into(),
                written: written.to_path_buf(),
                source: other,
            },
        })?;
        Ok(JobInput {
            key: key.into(),
            written: written.to_path_buf(),
            path: path.to_path_buf(),
            resolved,
        })
    }

    /// Checks that every file the job reads (garment yarns, scene, the
    /// character, the scene's own character) resolves, symlinks followed,
    /// inside the manifest's folder or one of `allowed`, and returns them.
    /// Refused paths are errors naming the manifest, the key and the path
    /// as written; nothing outside is opened, so no file's contents reach
    /// a message. Only the scene (once inside) is read, for its character.
    pub fn check_confined(&self, allowed: &[PathBuf]) -> Result<Vec<JobInput>, Error> {
        self.check_inside(&self.roots(allowed))
    }

    /// [`Job::check_confined`] with exactly `roots` allowed (the manifest's
    /// folder only if listed): a caller that knows a narrower folder (a
    /// drop's own) confines the job to it.
    pub fn check_inside(&self, roots: &[PathBuf]) -> Result<Vec<JobInput>, Error> {
        let m = &self.manifest;
        let mut inputs = vec![self.confine(
            "[garment] yarns",
            &m.garment.yarns,
            &self.resolve(&m.garment.yarns),
            roots,
        )?];
        for spec in self.card_specs()? {
            let resolved = self.resolve(&spec.path);
            inputs.push(self.confine("[embed] cards", &spec.path, &resolved, roots)?);
        }
        if let Some(c) = &m.character {
            inputs.push(self.confine(
                "[character] file",
                &c.file,
                &self.resolve(&c.file),
                roots,
            )?);
        }
        if m.shot.is_some() {
            let (_, shot_inputs) = self.scene_within(roots)?;
            for i in shot_inputs {
                if !inputs.iter().any(|j| j.path == i.path) {
                    inputs.push(i);
                }
            }
        }
        Ok(inputs)
    }

    /// Refuses (exit 2) a stage output that is, or would replace, one of
    /// `inputs`: the assets, the pose files, the export files and what
    /// knitvox keeps in `OUT/.knitvox/` and `OUT/checkpoints/`.
    pub fn check_outputs(&self, inputs: &[JobInput]) -> Result<(), Error> {
        let stages = self.stages();
        let mut files: Vec<(&'static str, PathBuf)> = vec![("embed", self.garment_asset())];
        if stages.contains(&"train") {
            files.extend((0..self.manifest.train.len()).map(|i| ("train", self.pose_file(i))));
        }
        if stages.contains(&"fit") {
            files.push(("fit", self.fitted_asset()));
        }
        if stages.contains(&"shot") {
            files.push(("shot", self.shot_asset()));
        }
        // Folders whose every file knitvox writes or removes.
        let owned = [
            ("records", self.output.join(".knitvox")),
            ("shot", self.checkpoint_dir()),
        ];
        let export = self.manifest.export.as_ref().map(|e| {
            let name = e.name.clone().unwrap_or_else(|| "garment".into());
            (self.output.join("export"), format!("{name}."))
        });
        let refuse =
            |stage: &'static str, output: &Path, i: &JobInput| JobPathError::OutputIsInput {
                manifest: self.path.clone(),
                stage,
                output: output.to_path_buf(),
                key: i.key.clone(),
                written: i.written.clone(),
            };
        for i in inputs {
            // Where the input is named and where it resolves to: writing
            // over either changes what the job reads.
            let places: Vec<PathBuf> = [
                io::overwrite::canonical_place(&i.path),
                Some(i.resolved.clone()),
            ]
            .into_iter()
            .flatten()
            .collect();
            for (stage, f) in &files {
                if io::overwrite::overlaps(&i.path, f) || io::overwrite::overlaps(&i.resolved, f) {
                    return Err(refuse(stage, f, i).into());
                }
            }
            for (stage, dir) in &owned {
                if let Ok(d) = std::fs::canonicalize(dir) {
                    if places.iter().any(|p| p.starts_with(&d)) {
                        return Err(refuse(stage, dir, i).into());
                    }
                }
            }
            if let Some((dir, prefix)) = &export {
                if let Ok(d) = std::fs::canonicalize(dir) {
                    let hit = places.iter().any(|p| {
                        p.parent() == Some(d.as_path())
                            && p.file_name()
                                .and_then(|n| n.to_str())
                                .is_some_and(|n| n.starts_with(prefix.as_str()))
                    });
                    if hit {
                        return Err(refuse("export", &dir.join(format!("{prefix}*")), i).into());
                    }
                }
            }
        }
        Ok(())
    }

    fn check(&self) -> Result<(), Error> {
        let m = &self.manifest;
        let p = &self.path;
        parse_key::<Units>(p, "garment.units", &m.garment.units)?;
        parse_key::<UpAxis>(p, "garment.up_axis", &m.garment.up_axis)?;
        self.read_options()?;
        if m.garment.yarns.as_os_str().is_empty() {
            return Err(bad(p, "key 'garment.yarns' is required".into()));
        }
        if let Some(s) = &m.shot {
            if m.frames.is_none() {
                return Err(bad(p, "key 'frames' is required with [shot]".into()));
            }
            match (&s.scene, &m.character) {
                (Some(_), Some(_)) => {
                    return Err(bad(
                        p,
                        "key 'shot.scene' excludes [character]: the scene names its character"
                            .into(),
                    ))
                }
                (None, None) => {
                    return Err(bad(
                        p,
                        "[shot] needs key 'shot.scene' or a [character]".into(),
                    ))
                }
                _ => {}
            }
            parse_key::<super::sim_scene::BackendChoice>(p, "shot.backend", &s.backend)?;
            parse_key::<super::sim_scene::SolverChoice>(p, "shot.solver", &s.solver)?;
            for (k, v) in [("shot.dt", s.dt), ("shot.fps", s.fps)] {
                number(p, k, v, |x| x > 0.0, "a positive number")?;
            }
            let max = super::sim_scene::MAX_PREROLL_S;
            number(
                p,
                "shot.preroll",
                s.preroll,
                |x| (0.0..=max).contains(&x),
                &format!("0 to {max} s"),
            )?;
            for (k, v) in [
                ("shot.garment_rotate", s.garment_rotate),
                ("shot.garment_offset", s.garment_offset),
            ] {
                for x in v.into_iter().flatten() {
                    number(p, k, Some(x), |_| true, "finite")?;
                }
            }
        }
        if let Some(c) = &m.character {
            let (lo, hi) = super::sim_scene::CHARACTER_SCALE_RANGE;
            number(
                p,
                "character.scale",
                c.scale,
                |x| (lo..=hi).contains(&x),
                &format!(
                    "{} to {} metres per unit",
                    shown_number(lo),
                    shown_number(hi)
                ),
            )?;
            number(
                p,
                "character.pin_distance",
                c.pin_distance,
                |x| x >= 0.0,
                ">= 0 m",
            )?;
        }
        if let Some(e) = &m.embed {
            number(p, "embed.voxel_size", e.voxel_size, |x| x > 0.0, "> 0 m")?;
            number(p, "embed.density", e.density, |x| x > 0.0, "> 0 kg/m³")?;
            if e.max_voxels == Some(0) {
                return Err(bad(p, "key 'embed.max_voxels': must be at least 1".into()));
            }
        }
        if let Some(f) = &m.frames {
            parse_key::<FrameSpec>(p, "frames", &Some(f.clone()))?;
        }
        for (i, t) in m.train.iter().enumerate() {
            self.pose_params(i, t)?;
        }
        if let Some(f) = &m.fit {
            if m.train.is_empty() {
                return Err(bad(p, "[fit] needs at least one [[train]] pose".into()));
            }
            if f.samples == Some(0) {
                return Err(bad(p, "key 'fit.samples': must be at least 1".into()));
            }
            if let Some(n) = f.samples.filter(|&n| n > super::fit::MAX_SAMPLES) {
                return Err(bad(
                    p,
                    format!(
                        "key 'fit.samples': {n} is more than the maximum of {}",
                        super::fit::MAX_SAMPLES
                    ),
                ));
            }
            if f.harmonic.as_ref().is_some_and(|h| h.contains(&0)) {
                return Err(bad(
                    p,
                    "key 'fit.harmonic': ranks must be at least 1".into(),
                ));
            }
        }
        if let Some(e) = &m.export {
            parse_key::<FrameSpec>(p, "export.steps", &e.steps)?;
            parse_key::<Units>(p, "export.units", &e.units)?;
            parse_key::<UpAxis>(p, "export.up_axis", &e.up_axis)?;
            self.export_format()?;
            // Files are written inside OUT/export: a name is never a path.
            if let Some(n) = &e.name {
                if n.is_empty() || n.contains(['/', '\\', '\0']) || n.starts_with('.') {
                    return Err(bad(
                        p,
                        format!(
                            "key 'export.name': '{}' is not a plain file name (no '/', '\\', leading '.')",
                            crate::geom::excerpt(n)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    fn export_format(&self) -> Result<io::Format, Error> {
        let f = self
            .manifest
            .export
            .as_ref()
            .and_then(|e| e.format.clone())
            .unwrap_or_else(|| "ply".into());
        if !["ply", "bcc", "obj", "gltf", "glb", "h5"].contains(&f.as_str()) {
            return Err(bad(
                &self.path,
                format!(
                    "key 'export.format': '{}' is not one of ply, bcc, obj, gltf, glb, h5",
                    crate::geom::excerpt(&f)
                ),
            ));
        }
        io::Format::from_path(Path::new(&format!("x.{f}"))).ok_or_else(|| {
            bad(
                &self.path,
                format!("key 'export.format': '{f}' is not writable"),
            )
        })
    }

    fn resolve(&self, p: &Path) -> PathBuf {
        self.base.join(p)
    }

    /// `[embed] cards` parsed (paths as written; exit 65 naming the key).
    fn card_specs(&self) -> Result<Vec<crate::pipeline::card_transfer::CardSpec>, Error> {
        let cards = self
            .manifest
            .embed
            .as_ref()
            .and_then(|e| e.cards.clone())
            .unwrap_or_default();
        cards
            .iter()
            .map(|c| {
                crate::pipeline::card_transfer::CardSpec::parse(c).map_err(|e| {
                    bad(
                        &self.path,
                        format!("key 'embed.cards': {:?}: {e}", crate::geom::excerpt(c)),
                    )
                })
            })
            .collect()
    }

    /// The stages this job holds, in run order (`train` is one stage of
    /// [`Job::tasks`] independent poses).
    pub fn stages(&self) -> Vec<&'static str> {
        let m = &self.manifest;
        let mut v = vec!["embed"];
        if !m.train.is_empty() {
            v.push("train");
        }
        if m.fit.is_some() {
            v.push("fit");
        }
        if m.shot.is_some() {
            v.push("shot");
        }
        if m.export.is_some() {
            v.push("export");
        }
        v
    }

    /// Independent tasks of a stage (a farm array job): one per training
    /// pose for `train`, else 1.
    pub fn tasks(&self, stage: &str) -> usize {
        if stage == "train" {
            self.manifest.train.len().max(1)
        } else {
            1
        }
    }

    /// Pose `i` as `knitvox train` runs it (exit 65 naming the key).
    fn pose_params(
        &self,
        i: usize,
        t: &TrainSection,
    ) -> Result<(PoseRunParams, FabricParams), Error> {
        let key = |k: &str| format!("key 'train[{i}].{k}'");
        let kind = super::util::parse_kind(&t.kind)
            .map_err(|e| bad(&self.path, format!("{}: {e}", key("kind"))))?;
        let mut pose = PoseRunParams::new(kind);
        let p = &self.path;
        let k = |name: &str| format!("train[{i}].{name}");
        for (j, a) in t.amount.iter().flat_map(Amounts::values).enumerate() {
            let name = match &t.amount {
                Some(Amounts::Many(_)) => k(&format!("amount[{j}]")),
                _ => k("amount"),
            };
            number(p, &name, Some(a), |_| true, "finite")?;
        }
        number(p, &k("friction"), t.friction, |x| x >= 0.0, ">= 0")?;
        number(
            p,
            &k("gravity"),
            t.gravity,
            |x| (0.0..=1000.0).contains(&x),
            "0 to 1000 m/s²",
        )?;
        number(
            p,
            &k("band"),
            t.band,
            |x| x > 0.0 && x < 0.95,
            "in (0, 0.95)",
        )?;
        match &t.amount {
            Some(Amounts::One(a)) => pose.pose.amount = *a,
            Some(Amounts::Many(v)) => {
                let Some(last) = v.last() else {
                    return Err(bad(
                        &self.path,
                        format!("{}: the list is empty", key("amount")),
                    ));
                };
                pose.pose.amount = *last;
                pose.amounts = v.clone();
            }
            None => {}
        }
        pose.pose.mirror = t.mirror.unwrap_or(false);
        if let Some(n) = t.steps {
            if !(1..=1000).contains(&n) {
                return Err(bad(
                    &self.path,
                    format!("{}: must be 1 to 1000", key("steps")),
                ));
            }
            pose.steps = n;
        }
        let mut fabric = FabricParams::default();
        if let Some(mu) = t.friction {
            if !(mu.is_finite() && mu >= 0.0) {
                return Err(bad(
                    &self.path,
                    format!("{}: must be >= 0", key("friction")),
                ));
            }
            fabric.friction.mu = mu;
        }
        if let Some(g) = t.gravity {
            pose.gravity = g;
        }
        if let Some(b) = t.band {
            pose.pose.band = b;
        }
        pose.check()
            .map_err(|e| bad(&self.path, format!("key 'train[{i}]': {e}")))?;
        Ok((pose, fabric))
    }

    /// How the garment's yarns are read: `[garment]`'s read options as
    /// `embed`'s flags give them (exit 65 naming the key when one is bad).
    fn read_options(&self) -> Result<ReadOptions, Error> {
        let g = &self.manifest.garment;
        let p = &self.path;
        let d = ReadOptions::default();
        number(p, "garment.radius", g.radius, |x| x > 0.0, "> 0 m")?;
        let max = io::bcc::MAX_SPLINE_SAMPLES;
        let spline_samples = g
            .spline_samples
            .map(|k| {
                usize::try_from(k)
                    .ok()
                    .filter(|k| (1..=max).contains(k))
                    .ok_or_else(|| {
                        bad(
                            p,
                            format!("key 'garment.spline_samples': {k} is out of range (must be 1 to {max})"),
                        )
                    })
            })
            .transpose()?;
        let tile = match &g.tile {
            Some(t) => t
                .repeats()
                .map_err(|e| bad(p, format!("key 'garment.tile': {e}")))?,
            None => d.tile,
        };
        Ok(ReadOptions {
            units: parse_key(p, "garment.units", &g.units)?,
            up_axis: parse_key(p, "garment.up_axis", &g.up_axis)?,
            spline_samples,
            tile,
            radius: g.radius.unwrap_or(d.radius),
            override_radius: g.override_radius.unwrap_or(d.override_radius),
            ..d
        })
    }

    /// The read options beyond the unit and axis that the embed key holds,
    /// as read (a tile as `[N, M]` however written); None when none is
    /// set, so the keys of jobs without them stay what they were.
    fn read_key(&self) -> Result<Option<serde_json::Value>, Error> {
        let g = &self.manifest.garment;
        if g.radius.is_none()
            && g.override_radius.is_none()
            && g.spline_samples.is_none()
            && g.tile.is_none()
        {
            return Ok(None);
        }
        let r = self.read_options()?;
        Ok(Some(serde_json::json!({
            "radius": r.radius,
            "override_radius": r.override_radius,
            "spline_samples": r.spline_samples,
            "tile": r.tile,
        })))
    }

    /// The shot's scene (the manifest's overrides applied) and the files it
    /// reads, every one inside the job's folders.
    fn scene(&self) -> Result<(Scene, Vec<PathBuf>), Error> {
        let (scene, inputs) = self.scene_within(&self.roots(&self.allowed))?;
        Ok((scene, inputs.into_iter().map(|i| i.path).collect()))
    }

    /// [`Job::scene`] with the files confined to `roots`: the scene file is
    /// checked before it is read, its character before anything reads it.
    fn scene_within(&self, roots: &[PathBuf]) -> Result<(Scene, Vec<JobInput>), Error> {
        let s = self.manifest.shot.clone().unwrap_or_default();
        let mut inputs = Vec::new();
        let mut scene = match (&s.scene, &self.manifest.character) {
            (Some(f), _) => {
                let i = self.confine("[shot] scene", f, &self.resolve(f), roots)?;
                let scene = read_scene(&i.path)?;
                inputs.push(i);
                scene
            }
            (None, Some(c)) => {
                let d = CharacterSection::default();
                Scene {
                    character: Some(CharacterSection {
                        // As written: the key must not depend on where `run` is started.
                        file: c.file.clone(),
                        animation: c.animation.clone(),
                        scale: c.scale.unwrap_or(d.scale),
                        pin_distance: c.pin_distance.unwrap_or(d.pin_distance),
                        fit_joint: c.fit_joint.clone(),
                        ..d
                    }),
                    base_dir: self.base.clone(),
                    ..Scene::default()
                }
            }
            (None, None) => {
                return Err(bad(
                    &self.path,
                    "[shot] needs key 'shot.scene' or a [character]".into(),
                ))
            }
        };
        if let Some(c) = &scene.character {
            // A scene's own character is relative to the scene's folder.
            let key = match &s.scene {
                Some(f) => format!("[character] file of the scene '{}'", excerpt_path(f)),
                None => "[character] file".into(),
            };
            let path = scene.base_dir.join(&c.file);
            inputs.push(self.confine(&key, &c.file, &path, roots)?);
        }
        if let Some(r) = s.garment_rotate {
            scene.garment.rotate_deg = r;
        }
        if let Some(t) = s.garment_offset {
            scene.garment.translate = t;
        }
        let sim = &mut scene.simulation;
        if let Some(dt) = s.dt {
            sim.dt = Seconds(dt);
        }
        if let Some(f) = s.fps {
            sim.fps = f;
        }
        if let Some(p) = s.preroll {
            sim.preroll = Some(p);
        }
        if let Some(b) = parse_key(&self.path, "shot.backend", &s.backend)? {
            sim.backend = b;
        }
        if let Some(v) = parse_key(&self.path, "shot.solver", &s.solver)? {
            sim.solver = v;
        }
        // The manifest's values as the scene's own are checked.
        scene
            .validate()
            .map_err(|e| bad(&self.path, format!("key '{}': {}", e.key, e.message)))?;
        self.check_step_count(&scene)?;
        Ok((scene, inputs))
    }

    /// A shot asking for more PD steps than a shot may take is refused
    /// before any stage runs (the shot checks the same bound again).
    fn check_step_count(&self, scene: &Scene) -> Result<(), Error> {
        use super::shot_setup::{DEFAULT_CHARACTER_PREROLL, MAX_TOTAL_STEPS};
        let frames: Option<FrameSpec> = parse_key(&self.path, "frames", &self.manifest.frames)?;
        let frames = frames.map(|f| f.frames()).unwrap_or_default();
        let (Some(first), Some(last)) = (frames.iter().min(), frames.iter().max()) else {
            return Ok(());
        };
        let sim = &scene.simulation;
        let per_frame = ((1.0 / sim.fps) / sim.dt.0).ceil().max(1.0);
        let preroll = match &scene.character {
            Some(_) => sim.preroll.unwrap_or(DEFAULT_CHARACTER_PREROLL),
            None => 0.0,
        };
        let steps = per_frame * (last - first) as f64 + (preroll / sim.dt.0).ceil();
        if !(steps <= MAX_TOTAL_STEPS as f64) {
            return Err(bad(
                &self.path,
                format!(
                    "key 'frames': frames {first}-{last} at {} fps with dt {} s (pre-roll {} s) need {} steps, more than the limit of {MAX_TOTAL_STEPS}",
                    shown_number(sim.fps),
                    shown_number(sim.dt.0),
                    shown_number(preroll),
                    shown_number(steps)
                ),
            ));
        }
        Ok(())
    }
}

/// What happened to one stage.
#[derive(Debug, Clone, Serialize)]
pub struct StageOutcome {
    pub name: String,
    /// `ran` or `cached`.
    pub status: String,
    /// The stage key (hex SHA-256).
    pub key: String,
    /// Output files, relative to the output folder.
    pub outputs: Vec<PathBuf>,
    /// Run time (0 when cached).
    pub ms: f64,
}

/// What `knitvox run` did.
#[derive(Debug, Clone, Serialize)]
pub struct RunReport {
    pub stages: Vec<StageOutcome>,
    pub ran: usize,
}

/// The record `OUT/.knitvox/STAGE.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Record {
    stage: String,
    key: String,
    outputs: Vec<PathBuf>,
    knitvox: String,
}

fn stage_key(
    name: &str,
    params: &impl Serialize,
    inputs: &[PathBuf],
    upstream: Option<&str>,
) -> Result<String, Error> {
    let mut h = Sha256::new();
    h.update(format!(
        "knitvox {}\nstage {name}\n",
        env!("CARGO_PKG_VERSION")
    ));
    // serde_json::Value keeps object keys sorted: canonical parameters.
    let v = serde_json::to_value(params).map_err(|e| Error::Internal(e.to_string()))?;
    h.update(format!("params {v}\n"));
    for p in inputs {
        h.update(format!("input {}\n", sha256_file(p)?));
    }
    if let Some(u) = upstream {
        h.update(format!("upstream {u}\n"));
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

fn record_path(out: &Path, stage: &str) -> PathBuf {
    out.join(".knitvox").join(format!("{stage}.json"))
}

/// Whether the record holds `key` and every recorded output exists.
fn cached(out: &Path, stage: &str, key: &str) -> Option<Vec<PathBuf>> {
    let text = std::fs::read_to_string(record_path(out, stage)).ok()?;
    let r: Record = serde_json::from_str(&text).ok()?;
    (r.key == key && r.outputs.iter().all(|o| out.join(o).exists())).then_some(r.outputs)
}

/// Removes a stage's record; returns the outputs it listed.
fn invalidate(out: &Path, stage: &str) -> Result<Vec<PathBuf>, Error> {
    let path = record_path(out, stage);
    let old = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str::<Record>(&t).ok())
        .map(|r| r.outputs)
        .unwrap_or_default();
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(IoError::Write { path, source: e }.into())
        }
        _ => Ok(old),
    }
}

/// Deletes the previous run's outputs that this run did not write again
/// (another export name or format), so OUT holds one run's files. Only
/// plain relative paths inside OUT are touched, and never an input of the
/// job (a record may list a file that has since become one).
fn remove_stale(out: &Path, old: &[PathBuf], new: &[PathBuf], inputs: &[JobInput]) {
    for o in old.iter().filter(|o| !new.contains(o)) {
        let inside = o
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        let path = out.join(o);
        let an_input = inputs.iter().any(|i| {
            io::overwrite::same_file(&i.path, &path) || io::overwrite::same_file(&i.resolved, &path)
        });
        if inside && !an_input {
            // A file already gone is what we want.
            let _ = std::fs::remove_file(path);
        }
    }
}

fn write_record(out: &Path, stage: &str, key: &str, outputs: &[PathBuf]) -> Result<(), Error> {
    let dir = out.join(".knitvox");
    std::fs::create_dir_all(&dir).map_err(|source| IoError::Write {
        path: dir.clone(),
        source,
    })?;
    let r = Record {
        stage: stage.into(),
        key: key.into(),
        outputs: outputs.to_vec(),
        knitvox: env!("CARGO_PKG_VERSION").into(),
    };
    let text = serde_json::to_string_pretty(&r).map_err(|e| Error::Internal(e.to_string()))?;
    crate::io::atomic::write_bytes(&record_path(out, stage), text.as_bytes())?;
    Ok(())
}

/// A stage ready to run: returns the files it wrote.
type StageRun = Box<dyn Fn(&mut dyn Observer) -> Result<Vec<PathBuf>, Error>>;

fn relative(out: &Path, p: &Path) -> PathBuf {
    p.strip_prefix(out).unwrap_or(p).to_path_buf()
}

/// Runs the job's stages up to `until` (all when `None`), skipping those
/// whose key and outputs are unchanged. `command` goes into provenance.
pub fn run(
    job: &Job,
    until: Option<&str>,
    command: &str,
    observer: &mut dyn Observer,
) -> Result<RunReport, Error> {
    run_tasks(job, until, None, command, observer)
}

/// [`run`], and with `task` only that task of the last stage (a farm array
/// task: one training pose).
pub fn run_tasks(
    job: &Job,
    until: Option<&str>,
    task: Option<usize>,
    command: &str,
    observer: &mut dyn Observer,
) -> Result<RunReport, Error> {
    let stages = job.stages();
    let last = match until {
        None => stages.len() - 1,
        Some(n) => stages.iter().position(|s| *s == n).ok_or_else(|| {
            Error::Usage(format!(
                "--stage {}: {} has no such stage (it has: {})",
                crate::geom::excerpt(n),
                job.path.display(),
                stages.join(", ")
            ))
        })?,
    };
    if let Some(t) = task {
        let n = job.tasks(stages[last]);
        if t >= n {
            return Err(Error::Usage(format!(
                "--task {t}: stage '{}' of {} has {n} task(s), numbered from 0",
                stages[last],
                job.path.display()
            )));
        }
    }
    let out = &job.output;
    // knitvox never overwrites an input: checked at load, and again now
    // (the files may have changed since).
    let inputs = job.check_confined(&job.allowed)?;
    job.check_outputs(&inputs)?;
    let mut report = RunReport {
        stages: Vec::new(),
        ran: 0,
    };
    // Each stage's key chains its upstream's: train after embed, fit after
    // every pose, the shot after the fit (or embed), export after the shot.
    let mut keys: std::collections::HashMap<&str, String> = Default::default();
    let mut units: Vec<(String, String, StageRun)> = Vec::new();
    for (si, name) in stages[..=last].iter().enumerate() {
        units.clear();
        match *name {
            "embed" => {
                let (k, r) = job.plan_embed(command)?;
                units.push(("embed".into(), k, r));
            }
            "train" => {
                let up = keys.get("embed").cloned();
                let mut all = Sha256::new();
                for i in 0..job.manifest.train.len() {
                    let (k, r) = job.plan_train(i, up.as_deref(), command)?;
                    all.update(&k);
                    let only = task.is_none() || si != last || task == Some(i);
                    if only {
                        units.push((format!("train.{i}"), k, r));
                    }
                }
                keys.insert("train", hex(&all.finalize()));
            }
            "fit" => {
                let (k, r) = job.plan_fit(keys.get("train").map(String::as_str), command)?;
                units.push(("fit".into(), k, r));
            }
            "shot" => {
                let up = keys.get("fit").or(keys.get("embed")).cloned();
                let (k, r) = job.plan_shot(up.as_deref(), command)?;
                units.push(("shot".into(), k, r));
            }
            _ => {
                let up = keys.get("shot").or(keys.get("fit")).or(keys.get("embed"));
                let (k, r) = job.plan_export(up.map(String::as_str))?;
                units.push(("export".into(), k, r));
            }
        }
        for (unit, key, run_it) in units.drain(..) {
            if *name != "train" {
                keys.insert(name, key.clone());
            }
            report.stages.push(run_unit(
                out,
                &inputs,
                &unit,
                key,
                run_it,
                observer,
                &mut report.ran,
            )?);
        }
    }
    Ok(report)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Runs one stage (or one task of it) unless its record vouches for its
/// outputs.
fn run_unit(
    out: &Path,
    inputs: &[JobInput],
    name: &str,
    key: String,
    run_it: StageRun,
    observer: &mut dyn Observer,
    ran: &mut usize,
) -> Result<StageOutcome, Error> {
    let outcome = StageOutcome {
        name: name.to_string(),
        status: "cached".into(),
        key: key.clone(),
        outputs: Vec::new(),
        ms: 0.0,
    };
    // Look, lock, look again: another run of this job (a farm task, a
    // second shell) may be running the stage or have just finished it.
    let records = record_path(out, name);
    let records_dir = records.parent().unwrap_or(out);
    let lock_path = records_dir.join(format!("{name}.lock"));
    let lock = match cached(out, name, &key) {
        Some(_) => {
            // A run killed after its record but before its unlock.
            io::lock::remove_if_orphaned(&lock_path);
            None
        }
        None => {
            std::fs::create_dir_all(records_dir).map_err(|source| IoError::Write {
                path: records_dir.to_path_buf(),
                source,
            })?;
            Some(io::lock::Lock::acquire(&lock_path)?)
        }
    };
    let result = run_locked(out, inputs, name, key, run_it, observer, outcome);
    match &result {
        Ok(o) if o.status == "ran" => *ran += 1,
        Ok(_) => {}
        Err(_) => {
            // A first stage that failed leaves no folder behind.
            drop(lock);
            let _ = std::fs::remove_dir(records_dir);
            let _ = std::fs::remove_dir(out);
        }
    }
    result
}

/// [`run_unit`] with the stage's lock held.
fn run_locked(
    out: &Path,
    inputs: &[JobInput],
    name: &str,
    key: String,
    run_it: StageRun,
    observer: &mut dyn Observer,
    mut outcome: StageOutcome,
) -> Result<StageOutcome, Error> {
    match cached(out, name, &key) {
        Some(outputs) => outcome.outputs = outputs,
        None => {
            // Invalidate first: a run killed after writing new outputs
            // must not leave an old record vouching for them.
            let stale = invalidate(out, name)?;
            let t = Instant::now();
            let written = run_it(observer)?;
            outcome.outputs = written.iter().map(|p| relative(out, p)).collect();
            // The record only after every output exists.
            write_record(out, name, &key, &outcome.outputs)?;
            remove_stale(out, &stale, &outcome.outputs, inputs);
            outcome.status = "ran".into();
            outcome.ms = t.elapsed().as_secs_f64() * 1e3;
        }
    }
    Ok(outcome)
}

impl Job {
    fn garment_asset(&self) -> PathBuf {
        self.output.join("garment.vtkhdf")
    }

    fn shot_asset(&self) -> PathBuf {
        self.output.join("shot.vtkhdf")
    }

    /// Where a stopped shot's checkpoints wait for the next run.
    fn checkpoint_dir(&self) -> PathBuf {
        self.output.join("checkpoints")
    }

    fn fitted_asset(&self) -> PathBuf {
        self.output.join("fitted.vtkhdf")
    }

    /// Training pose `i`'s frames: `OUT/train/NN-KIND.h5`.
    fn pose_file(&self, i: usize) -> PathBuf {
        let kind = &self.manifest.train[i].kind;
        let safe: String = kind
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '_' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        self.output.join("train").join(format!("{i:02}-{safe}.h5"))
    }

    /// The asset the shot simulates: the fitted one when the job fits.
    fn shot_input(&self) -> PathBuf {
        if self.manifest.fit.is_some() {
            self.fitted_asset()
        } else {
            self.garment_asset()
        }
    }

    /// Training pose `i`'s key (its parameters and the embed key) and job.
    fn plan_train(
        &self,
        i: usize,
        upstream: Option<&str>,
        _command: &str,
    ) -> Result<(String, StageRun), Error> {
        let t = &self.manifest.train[i];
        let key = stage_key("train", &(i, t), &[], upstream)?;
        let (pose, fabric) = self.pose_params(i, t)?;
        let output = self.pose_file(i);
        let stage = TrainJob {
            asset: self.garment_asset(),
            output: output.clone(),
            pose,
            fabric,
            material: Default::default(),
        };
        let run = move |o: &mut dyn Observer| {
            if let Some(dir) = output.parent() {
                std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
                    path: dir.to_path_buf(),
                    source,
                })?;
            }
            stage.run(o)?;
            Ok(vec![output.clone()])
        };
        Ok((key, Box::new(run)))
    }

    /// The fit's key (its parameters and every pose's key) and job.
    fn plan_fit(&self, upstream: Option<&str>, command: &str) -> Result<(String, StageRun), Error> {
        let mut f = self.manifest.fit.clone().unwrap_or_default();
        f.model = Some(f.model.unwrap_or_default());
        let key = stage_key("fit", &f, &[], upstream)?;
        let mut params = ElasticFitParams::default();
        if let Some(h) = &f.harmonic {
            params.harmonic_ranks = h.clone();
        }
        let stage = FitJob {
            asset: self.garment_asset(),
            train: (0..self.manifest.train.len())
                .map(|i| self.pose_file(i))
                .collect(),
            read: ReadOptions::default(),
            samples: f.samples.unwrap_or(super::fit::DEFAULT_SAMPLES),
            params,
            output: Some(self.fitted_asset()),
            report: None,
            joint: f.joint.unwrap_or(false),
            quasi_static: false,
            fibres: f.fibres.unwrap_or(false),
            model: f.model.unwrap_or_default(),
            shape_fit_pins: false,
            command: command.into(),
        };
        Ok((key, Box::new(move |o| Ok(vec![stage.run(o)?.output]))))
    }

    /// The embed stage's key and job (keyed by the garment file's content).
    fn plan_embed(&self, command: &str) -> Result<(String, StageRun), Error> {
        let m = &self.manifest;
        let yarns = self.resolve(&m.garment.yarns);
        // The cards' contents are inputs of the stage: a refitted card
        // re-runs it.
        let cards: Vec<_> = self
            .card_specs()?
            .into_iter()
            .map(|c| crate::pipeline::card_transfer::CardSpec {
                path: self.resolve(&c.path),
                ..c
            })
            .collect();
        let inputs: Vec<PathBuf> = std::iter::once(yarns.clone())
            .chain(cards.iter().map(|c| c.path.clone()))
            .collect();
        let input = inputs.as_slice();
        let key = match self.read_key()? {
            None => stage_key(
                "embed",
                &(&m.garment.units, &m.garment.up_axis, &m.embed),
                input,
                None,
            )?,
            Some(read) => stage_key(
                "embed",
                &(&m.garment.units, &m.garment.up_axis, &m.embed, read),
                input,
                None,
            )?,
        };
        let e = m.embed.clone().unwrap_or_default();
        let d = EmbedParams::default();
        let stage = EmbedJob {
            yarns,
            read: self.read_options()?,
            params: EmbedParams {
                voxel_size: e.voxel_size,
                max_voxels: e.max_voxels.unwrap_or(d.max_voxels),
                material_density: e.density.unwrap_or(d.material_density),
                ..d
            },
            output: self.garment_asset(),
            command: command.into(),
            cards,
        };
        Ok((key, Box::new(move |o| Ok(vec![stage.run(o)?.asset]))))
    }

    /// The shot stage's key and job (scene and character files' contents).
    /// The shot checkpoints every `[shot] checkpoint_every` frames and on
    /// SIGTERM, and continues from its latest checkpoint when a run was
    /// stopped or killed; the checkpoint is removed once the asset is
    /// written.
    fn plan_shot(
        &self,
        upstream: Option<&str>,
        command: &str,
    ) -> Result<(String, StageRun), Error> {
        let m = &self.manifest;
        let (scene, inputs) = self.scene()?;
        // How often it checkpoints does not change the shot's outputs.
        let every = m.shot.as_ref().and_then(|s| s.checkpoint_every);
        let shot = m.shot.clone().map(|s| ShotSection {
            checkpoint_every: None,
            ..s
        });
        let params = (&m.frames, &shot, &m.character, &scene);
        let key = stage_key("shot", &params, &inputs, upstream)?;
        let frames: Option<FrameSpec> = parse_key(&self.path, "frames", &m.frames)?;
        let interrupt = self.interrupt;
        let stage = ChunkedShotJob {
            shot: ShotJob {
                asset: self.shot_input(),
                scene,
                request: ShotRequest {
                    frames: frames.map(|f| f.frames()).unwrap_or_default(),
                    output: self.shot_asset(),
                    yarns_out: None,
                    write: WriteOptions::default(),
                    command: command.into(),
                },
            },
            chunk: ChunkOptions {
                checkpoint_every: every.unwrap_or(DEFAULT_CHECKPOINT_EVERY),
                checkpoint_dir: Some(self.checkpoint_dir()),
                resume: true,
                resume_or_restart: self.resume_or_restart,
                stop: interrupt.map(|i| i.flag()),
                ..ChunkOptions::default()
            },
        };
        let dir = self.checkpoint_dir();
        let run = move |o: &mut dyn Observer| {
            let _armed = interrupt.map(|i| i.arm());
            let r = stage.run(o)?;
            // Done: the record vouches for the asset, nothing to resume.
            // Every checkpoint of the job goes (the run's own lies in `dir`
            // too), including one a killed run wrote at the step this run
            // resumed from.
            remove_checkpoints(&dir);
            let _ = std::fs::remove_dir(&dir); // only when empty
            Ok(vec![r.output])
        };
        Ok((key, Box::new(run)))
    }

    /// The export stage's key and job (its parameters and the shot's key):
    /// the shot's frames, or without a shot the rest shape of the fitted
    /// (or embedded) asset as step 0.
    fn plan_export(&self, upstream: Option<&str>) -> Result<(String, StageRun), Error> {
        let e = self.manifest.export.clone().unwrap_or_default();
        let key = stage_key("export", &e, &[], upstream)?;
        let d = WriteOptions::default();
        let dir = self.output.join("export");
        let asset = match (&self.manifest.shot, &self.manifest.fit) {
            (Some(_), _) => self.shot_asset(),
            (None, Some(_)) => self.fitted_asset(),
            (None, None) => self.garment_asset(),
        };
        let stage = ExportJob {
            rest_if_static: self.manifest.shot.is_none(),
            asset,
            selection: parse_key(&self.path, "export.steps", &e.steps)?,
            format: self.export_format()?,
            output: dir.clone(),
            name: Some(e.name.clone().unwrap_or_else(|| "garment".into())),
            write: WriteOptions {
                units: parse_key(&self.path, "export.units", &e.units)?.unwrap_or(d.units),
                up_axis: parse_key(&self.path, "export.up_axis", &e.up_axis)?.unwrap_or(d.up_axis),
                first_frame: 0,
            },
        };
        let run = move |o: &mut dyn Observer| {
            std::fs::create_dir_all(&dir).map_err(|source| IoError::Write {
                path: dir.clone(),
                source,
            })?;
            Ok(stage.run(o)?.written)
        };
        Ok((key, Box::new(run)))
    }
}

/// Removes the checkpoint files in a job's own checkpoint folder (nothing
/// else lives there); failures only leave files behind.
fn remove_checkpoints(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == io::checkpoint::EXT) {
            let _ = std::fs::remove_file(path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn key_follows_params_inputs_and_upstream() {
        let dir = tempfile::tempdir().unwrap();
        let a = write(dir.path(), "a.txt", "one");
        let k = |p: &str, up: Option<&str>| {
            stage_key("embed", &p, std::slice::from_ref(&a), up).unwrap()
        };
        let base = k("x", None);
        assert_eq!(base.len(), 64);
        assert_eq!(base, k("x", None));
        assert_ne!(base, k("y", None));
        assert_ne!(base, k("x", Some("u")));
        write(dir.path(), "a.txt", "two");
        assert_ne!(base, k("x", None));
    }

    #[test]
    fn paths_resolve_against_the_manifest_folder() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        // Only resolved, never read: empty files do.
        write(&sub, "y.bcc", "");
        write(&sub, "c.glb", "");
        let text =
            "frames = \"1\"\n[garment]\nyarns = \"y.bcc\"\n[character]\nfile = \"c.glb\"\n[shot]\n";
        let job = Job::load(&write(&sub, "shot.toml", text)).unwrap();
        assert_eq!(job.output, sub.join("shot.out"));
        assert_eq!(job.resolve(&job.manifest.garment.yarns), sub.join("y.bcc"));
        let (scene, inputs) = job.scene().unwrap();
        assert_eq!(inputs, vec![sub.join("c.glb")]);
        // The hashed scene holds the path as written, so the key does not
        // depend on how the manifest was named.
        let other = Job::load(&sub.join("..").join("sub").join("shot.toml")).unwrap();
        let v = |s: &Scene| serde_json::to_value(s).unwrap();
        assert_eq!(v(&scene), v(&other.scene().unwrap().0));
        let with_out =
            Job::load(&write(&sub, "o.toml", &format!("output = \"x\"\n{text}"))).unwrap();
        assert_eq!(with_out.output, sub.join("x"));
    }

    #[test]
    fn a_mapped_manifest_round_trips_through_toml() {
        let dir = tempfile::tempdir().unwrap();
        let text = "frames = \"1\"\n[garment]\nyarns = \"y.bcc\"\nunits = \"mm\"\n[character]\nfile = \"c.glb\"\n[shot]\ngarment_offset = [0.0, 1.0, 0.0]\n";
        std::fs::create_dir(dir.path().join("in")).unwrap();
        for f in ["y.bcc", "c.glb", "in/y.bcc", "in/c.glb", "a.ply"] {
            write(dir.path(), f, "");
        }
        let mut m = Job::load(&write(dir.path(), "j.toml", text))
            .unwrap()
            .manifest;
        m.map_paths(|p| Path::new("in").join(p));
        m.output = Some("../out".into());
        let back = Job::load(&write(dir.path(), "k.toml", &m.to_toml().unwrap())).unwrap();
        assert_eq!(back.manifest, m);
        assert_eq!(back.manifest.garment.yarns, Path::new("in/y.bcc"));
        assert_eq!(back.manifest.character.unwrap().file, Path::new("in/c.glb"));
        assert_eq!(back.output, dir.path().join("../out"));
        let bare = Manifest::for_yarns("a.ply".into());
        let job = Job::load(&write(dir.path(), "b.toml", &bare.to_toml().unwrap())).unwrap();
        assert_eq!(job.stages(), vec!["embed", "export"]);
    }

    #[test]
    fn check_inside_confines_to_exactly_the_roots_given() {
        let dir = tempfile::tempdir().unwrap();
        for d in ["in", "other"] {
            std::fs::create_dir(dir.path().join(d)).unwrap();
        }
        write(&dir.path().join("in"), "y.bcc", "");
        let job = Job::load(&write(
            dir.path(),
            "j.toml",
            "[garment]\nyarns = \"in/y.bcc\"\n",
        ))
        .unwrap();
        assert_eq!(job.inputs().len(), 1);
        assert_eq!(job.inputs()[0].key, "[garment] yarns");
        let inputs = job.check_inside(&[dir.path().join("in")]).unwrap();
        assert_eq!(inputs, job.inputs());
        let e = job.check_inside(&[dir.path().join("other")]).unwrap_err();
        assert_eq!(e.class(), super::super::ErrorClass::BadInput);
        assert!(e.to_string().contains("[garment] yarns 'in/y.bcc'"), "{e}");
    }

    #[test]
    fn garment_read_options_become_read_options_and_join_the_embed_key() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "y.pyp", "");
        let load = |extra: &str| {
            let text = format!("[garment]\nyarns = \"y.pyp\"\nunits = \"cm\"\n{extra}");
            Job::load(&write(dir.path(), "j.toml", &text)).unwrap()
        };
        let job =
            load("radius = 0.0003\noverride_radius = true\nspline_samples = 4\ntile = \"2X3\"\n");
        let r = job.read_options().unwrap();
        assert_eq!(r.radius, 0.0003);
        assert!(r.override_radius);
        assert_eq!(r.spline_samples, Some(4));
        assert_eq!(r.tile, [2, 3]);
        assert_eq!(r.units, Some(Units::CENTIMETRES));
        let key = |j: &Job| j.plan_embed("test").unwrap().0;
        assert_eq!(
            key(&job),
            key(&load(
                "radius = 0.0003\noverride_radius = true\nspline_samples = 4\ntile = [2, 3]\n"
            ))
        );
        assert_ne!(
            key(&job),
            key(&load(
                "radius = 0.0004\noverride_radius = true\nspline_samples = 4\ntile = [2, 3]\n"
            ))
        );
        // Without them: the key of the unit, axis and [embed] alone, as
        // before they existed, so earlier jobs stay cached.
        let plain = load("");
        assert_eq!(plain.read_options().unwrap().radius, io::DEFAULT_RADIUS_M);
        let m = &plain.manifest;
        let yarns = plain.resolve(&m.garment.yarns);
        let old = stage_key(
            "embed",
            &(&m.garment.units, &m.garment.up_axis, &m.embed),
            std::slice::from_ref(&yarns),
            None,
        )
        .unwrap();
        assert_eq!(key(&plain), old);
        assert_ne!(key(&plain), key(&load("radius = 0.001\n")));
        // The options survive the TOML the watch daemon writes.
        let back: Manifest = toml::from_str(&job.manifest.to_toml().unwrap()).unwrap();
        assert_eq!(back.garment, job.manifest.garment);
    }

    #[test]
    fn bad_manifests_name_the_key() {
        let dir = tempfile::tempdir().unwrap();
        for (text, key) in [
            (
                "[garment]\nyarns = \"y\"\nunits = \"furlong\"\n",
                "garment.units",
            ),
            (
                "[garment]\nyarns = \"y\"\n[shot]\nscene = \"s\"\n",
                "frames",
            ),
            (
                "frames = \"1\"\n[garment]\nyarns = \"y\"\n[shot]\n",
                "shot.scene",
            ),
            (
                "frames = \"1\"\n[garment]\nyarns = \"y\"\n[shot]\nscene = \"s\"\nfps = 0\n",
                "shot.fps",
            ),
            ("frames = \"x\"\n[garment]\nyarns = \"y\"\n", "frames"),
            (
                "frames = \"1\"\n[garment]\nyarns = \"y\"\n[shot]\nscene = \"s\"\n[export]\nname = \"../x\"\n",
                "export.name",
            ),
            ("[garment]\nyarns = \"y\"\nradius = 0.0\n", "garment.radius"),
            ("[garment]\nyarns = \"y\"\nradius = nan\n", "garment.radius"),
            ("[garment]\nyarns = \"y\"\nspline_samples = 65\n", "garment.spline_samples"),
            ("[garment]\nyarns = \"y\"\ntile = \"2by3\"\n", "garment.tile"),
            ("[garment]\nyarns = \"y\"\ntile = [2, 10001]\n", "garment.tile"),
        ] {
            let e = Job::load(&write(dir.path(), "j.toml", text)).unwrap_err();
            assert_eq!(e.class(), super::super::ErrorClass::BadInput, "{text}");
            let m = e.to_string();
            assert!(m.contains("j.toml") && m.contains(key), "{m}");
        }
    }
}
