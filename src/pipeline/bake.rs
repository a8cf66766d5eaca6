//! The bake stage: a skinned glTF character's animation sampled into an
//! HDF5 character cache (schemas/character-hdf5.md), the format any DCC can
//! write for characters whose rig knitvox cannot evaluate. A baked cache
//! drives a shot exactly as its glTF does (test: tests/character_cache.rs).

use std::path::PathBuf;

use super::{Error, Observer, Stage};
use crate::anim::cache::BodyCache;
use crate::io;

/// Most frames a bake writes (a 10-minute animation at 240 fps).
pub const MAX_BAKE_FRAMES: usize = 144_000;

/// Inputs and parameters of a bake.
#[derive(Debug, Clone)]
pub struct BakeJob {
    /// The character (glTF/GLB with a skin and animations).
    pub character: PathBuf,
    /// Animation name [default: the file's first; none: the bind pose, one frame].
    pub animation: Option<String>,
    /// Samples per second (Hz), > 0. Default 24.
    pub fps: f64,
    /// The cache to write (.h5).
    pub output: PathBuf,
}

/// What a bake wrote.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BakeReport {
    pub output: PathBuf,
    pub animation: Option<String>,
    pub frames: usize,
    pub duration_s: f64,
    pub vertices: usize,
    pub triangles: usize,
}

impl Stage for BakeJob {
    type Report = BakeReport;
    const NAME: &'static str = "bake";
    fn run(&self, _observer: &mut dyn Observer) -> Result<BakeReport, Error> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(Error::Usage(format!(
                "--fps {}: must be positive",
                self.fps
            )));
        }
        if io::Format::from_path(&self.output) != Some(io::Format::Hdf5) {
            return Err(Error::Usage(format!(
                "{}: a character cache is an HDF5 file (.h5 or .hdf5)",
                self.output.display()
            )));
        }
        io::overwrite::refuse_inputs(&[&self.output], &[&self.character])?;
        let character = io::gltf_skin::read_character(&self.character)?;
        let anim = match &self.animation {
            Some(name) => Some(character.animation_index(name).ok_or_else(|| {
                Error::Usage(format!(
                    "--animation '{}': {} has no such animation (it has: {})",
                    crate::geom::excerpt(name),
                    self.character.display(),
                    crate::geom::excerpt(&character.animation_names().join(", "))
                ))
            })?),
            None => (!character.animations.is_empty()).then_some(0),
        };
        let duration = anim.map_or(0.0, |a| character.duration(a));
        // Frames at k / fps up to the end; the last sample lands on the end.
        let intervals = (duration * self.fps - 1e-9).ceil().max(0.0);
        if intervals >= MAX_BAKE_FRAMES as f64 {
            return Err(Error::Usage(format!(
                "{:.3} s at {} fps is more than {MAX_BAKE_FRAMES} frames",
                duration, self.fps
            )));
        }
        let n = intervals as usize + 1;
        let times: Vec<f64> = (0..n)
            .map(|k| (k as f64 / self.fps).min(duration))
            .collect();
        let cache = BodyCache::bake(&character, anim, &times);
        if cache.triangles.is_empty() {
            return Err(Error::Usage(format!(
                "{}: the character has no triangles to bake",
                self.character.display()
            )));
        }
        io::character_h5::write_character_cache(&self.output, &cache)?;
        Ok(BakeReport {
            output: self.output.clone(),
            animation: anim.map(|a| character.animation_names()[a].clone()),
            frames: cache.num_frames(),
            duration_s: duration,
            vertices: cache.num_vertices,
            triangles: cache.triangles.len(),
        })
    }
}
