//! Scene files of the yarn-level simulator (`knitvox yls SCENE.toml`):
//! TOML text to a typed [`YlsScene`]. Layout and examples:
//! `schemas/yls-scene.md`, `examples/yls-*.toml`.
//!
//! Unknown keys are errors (a misspelt key must not silently fall back to a
//! default); every error names the file, the key and, where the TOML parser
//! knows it, the line and column.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::geom::Vec3;
use crate::yarn::poses::{PoseKind, PoseParams};

/// Where the rest yarns come from.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SwatchSpec {
    /// A built-in stitch pattern name (`knitvox pattern --list`).
    pub pattern: Option<String>,
    /// A stitch grid file (schemas/pattern-grid.md), relative to the scene.
    pub grid: Option<PathBuf>,
    /// A yarn file in any supported format, relative to the scene.
    pub file: Option<PathBuf>,
    /// Courses (rows of stitches) of a generated swatch. Default 12.
    pub courses: Option<u32>,
    /// Wales (columns of stitches) of a generated swatch. Default 12.
    pub wales: Option<u32>,
    /// Knit in the round with this tube radius (m).
    pub tube_radius: Option<f64>,
    /// Yarn radius (m) of a generated swatch; default: the generator's.
    pub yarn_radius: Option<f64>,
    /// Relax a generated swatch before the scene starts. Default true.
    pub relax: Option<bool>,
}

/// The scripted motion (see `yarn::poses`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    pub kind: PoseKind,
    /// Strain, angle (rad) or fold ratio; see `PoseKind`. Default 0.
    #[serde(default)]
    pub amount: f64,
    pub mirror: Option<bool>,
    pub folds: Option<u32>,
    pub band: Option<f64>,
    /// Ramp time (s); default: 80% of the scene duration.
    pub ramp: Option<f64>,
}

/// An external body.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ColliderSpec {
    /// Half space `(x - point) · normal >= 0`; Coulomb coefficient
    /// `friction` (>= 0, default 0) against yarn vertices and tet nodes.
    /// Without `point` the plane passes under the swatch's centre, one yarn
    /// diameter below its lowest yarn point along `normal` (a tilted plane
    /// touches no yarn at the start).
    Plane {
        point: Option<Vec3>,
        normal: Vec3,
        #[serde(default)]
        friction: f64,
    },
    /// A ball. Without `center` it sits under the swatch's centre with its
    /// top a yarn diameter below the lowest yarn point. `friction` as for
    /// the plane. `offset` (m, only without `center`) shifts that
    /// default placement (an off-centre drop). `velocity` (m/s, default
    /// 0): the centre moves at it from its placement at t = 0 (a body
    /// moving under the fabric).
    Sphere {
        center: Option<Vec3>,
        offset: Option<Vec3>,
        radius: f64,
        #[serde(default)]
        friction: f64,
        velocity: Option<Vec3>,
    },
    /// The skinned body of a glTF character, posed through one animation.
    Character {
        file: PathBuf,
        animation: Option<String>,
        /// Uniform scale from the character's units to metres. Default 1.
        scale: Option<f64>,
        /// Translation (m) after scaling. Default 0.
        offset: Option<Vec3>,
    },
}

/// Which yarn-level mechanics run the scene.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum YarnModel {
    /// The explicit simulator (`yarn::sim`: Kaldor contact, no twist,
    /// unsigned curvature, viscous contact damping).
    #[default]
    Explicit,
    /// Implicit Euler on the quasi-static rods (`yarn::fabric::dynamics`:
    /// stretch, signed bending, twist, contact, Coulomb friction): the
    /// mechanics of `knitvox train` and `fabric-test`.
    Rods,
}

/// Settings of the `rods` model (`[rods]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RodsSpec {
    /// Largest implicit-Euler step (s). Default 1/600.
    pub max_dt: Option<f64>,
    /// Yarn-on-yarn Coulomb coefficient. Default 0.25 (`knitvox train`'s).
    pub friction: Option<f64>,
    /// Collider penalty stiffness (N/m per vertex). Default 1000.
    pub collider_stiffness: Option<f64>,
    /// Newton force tolerance per step (N). Default: 1% of the heaviest
    /// vertex's weight.
    pub force_tolerance: Option<f64>,
}

/// A parsed scene, paths resolved against the scene file's folder.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YlsScene {
    /// A label stored with the output.
    #[serde(default)]
    pub name: String,
    /// Simulated time (s), > 0.
    pub duration: f64,
    /// Output frames per second. Default 60.
    #[serde(default = "default_frame_rate")]
    pub frame_rate: f64,
    /// Gravity (m/s²). Default `[0, -9.81, 0]`.
    #[serde(default = "default_gravity")]
    pub gravity: Vec3,
    pub swatch: SwatchSpec,
    pub pose: PoseSpec,
    #[serde(default)]
    pub colliders: Vec<ColliderSpec>,
    /// Overrides of the simulator parameters, by field name (checked when
    /// the simulator is built).
    #[serde(default)]
    pub sim: toml::Table,
    /// Yarn-level mechanics. Default `explicit`.
    #[serde(default)]
    pub model: YarnModel,
    /// Settings of the `rods` model.
    pub rods: Option<RodsSpec>,
}

fn default_frame_rate() -> f64 {
    60.0
}

fn default_gravity() -> Vec3 {
    [0.0, -9.81, 0.0]
}

/// Most output frames a scene may ask for (a guard against typos such as
/// `duration = 1e6`).
pub const MAX_SCENE_FRAMES: f64 = 1e6;

/// Fastest a collider may move (m/s): the yarn simulators count a vertex
/// faster than 100 m/s as diverged.
pub const MAX_COLLIDER_SPEED: f64 = 50.0;

/// A scene file that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {message}", file.display())]
pub struct SceneError {
    pub file: PathBuf,
    pub message: String,
}

impl YlsScene {
    /// Parses scene text; `file` names it in errors and anchors relative
    /// paths.
    pub fn parse(text: &str, file: &Path) -> Result<YlsScene, SceneError> {
        let err = |message: String| SceneError {
            file: file.to_path_buf(),
            message,
        };
        let mut scene: YlsScene =
            toml::from_str(text).map_err(|e| err(super::sim_scene::toml_error_line(&e, text)))?;
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(err(format!(
                    "key `{key}` is {v}; it must be finite and > 0"
                )))
            }
        };
        positive("duration", scene.duration)?;
        positive("frame_rate", scene.frame_rate)?;
        if scene.duration * scene.frame_rate > MAX_SCENE_FRAMES {
            return Err(err(format!(
                "keys `duration` x `frame_rate` ask for {} frames (at most {MAX_SCENE_FRAMES})",
                scene.duration * scene.frame_rate
            )));
        }
        if let Some(r) = &scene.rods {
            if scene.model != YarnModel::Rods {
                return Err(err(
                    "table `rods` needs `model = \"rods\"` (the explicit simulator reads `[sim]`)"
                        .into(),
                ));
            }
            for (key, v) in [
                ("rods.max_dt", r.max_dt),
                ("rods.collider_stiffness", r.collider_stiffness),
                ("rods.force_tolerance", r.force_tolerance),
            ] {
                if let Some(v) = v {
                    positive(key, v)?;
                }
            }
            if let Some(mu) = r.friction {
                if !(mu.is_finite() && (0.0..=10.0).contains(&mu)) {
                    return Err(err(format!(
                        "key `rods.friction` is {mu}; it must be in [0, 10]"
                    )));
                }
            }
            if r.max_dt.is_some_and(|dt| scene.duration / dt > 1e7) {
                return Err(err("key `rods.max_dt`: more than 1e7 steps".into()));
            }
        }
        if let Some(g) = scene.gravity.iter().find(|g| !g.is_finite()) {
            return Err(err(format!("key `gravity` has the component {g}")));
        }
        let s = &scene.swatch;
        let sources = [s.pattern.is_some(), s.grid.is_some(), s.file.is_some()];
        if sources.iter().filter(|b| **b).count() != 1 {
            return Err(err(
                "table `swatch` needs exactly one of the keys `pattern`, `grid`, `file`".into(),
            ));
        }
        for (key, v) in [("swatch.courses", s.courses), ("swatch.wales", s.wales)] {
            if v == Some(0) {
                return Err(err(format!("key `{key}` is 0; it must be >= 1")));
            }
        }
        for (key, v) in [
            ("swatch.tube_radius", s.tube_radius),
            ("swatch.yarn_radius", s.yarn_radius),
        ] {
            if let Some(v) = v {
                positive(key, v)?;
            }
        }
        for (i, c) in scene.colliders.iter().enumerate() {
            let key = |k: &str| format!("colliders[{i}].{k}");
            let finite = |k: &str, v: &Vec3| {
                if v.iter().all(|c| c.is_finite()) {
                    Ok(())
                } else {
                    Err(err(format!("key `{}` is not finite: {v:?}", key(k))))
                }
            };
            let non_negative = |k: &str, v: f64| {
                if v.is_finite() && v >= 0.0 {
                    Ok(())
                } else {
                    Err(err(format!(
                        "key `{}` is {v}; it must be finite and >= 0",
                        key(k)
                    )))
                }
            };
            match c {
                ColliderSpec::Plane {
                    point,
                    normal,
                    friction,
                } => {
                    non_negative("friction", *friction)?;
                    if let Some(p) = point {
                        finite("point", p)?;
                    }
                    finite("normal", normal)?;
                    if normal.iter().map(|c| c * c).sum::<f64>() == 0.0 {
                        return Err(err(format!("key `{}` is the zero vector", key("normal"))));
                    }
                }
                ColliderSpec::Sphere {
                    center,
                    offset,
                    radius,
                    friction,
                    velocity,
                } => {
                    non_negative("friction", *friction)?;
                    if let Some(v) = velocity {
                        finite("velocity", v)?;
                        let speed = v.iter().map(|c| c * c).sum::<f64>().sqrt();
                        if speed > MAX_COLLIDER_SPEED {
                            return Err(err(format!(
                                "key `{}` is {speed} m/s fast; at most {MAX_COLLIDER_SPEED} m/s",
                                key("velocity")
                            )));
                        }
                    }
                    if let Some(c) = center {
                        finite("center", c)?;
                    }
                    if let Some(o) = offset {
                        finite("offset", o)?;
                        if center.is_some() {
                            return Err(err(format!(
                                "keys `{}` and `{}` both given: `offset` shifts the default placement, `center` replaces it; give one",
                                key("center"),
                                key("offset")
                            )));
                        }
                    }
                    positive(&key("radius"), *radius)?;
                }
                ColliderSpec::Character { scale, offset, .. } => {
                    if let Some(s) = scale {
                        positive(&key("scale"), *s)?;
                    }
                    if let Some(o) = offset {
                        finite("offset", o)?;
                    }
                }
            }
        }
        // Resolve relative paths against the scene's folder.
        let base = file.parent().unwrap_or(Path::new("."));
        let resolve = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let Some(p) = scene.swatch.grid.as_mut() {
            resolve(p);
        }
        if let Some(p) = scene.swatch.file.as_mut() {
            resolve(p);
        }
        for c in &mut scene.colliders {
            if let ColliderSpec::Character { file, .. } = c {
                resolve(file);
            }
        }
        // Pose parameters are checked against the rest state later
        // (PoseDriver::new); the scalar ranges now, so the error names keys.
        let p = scene.pose_params();
        if !(p.band > 0.0 && p.band < 0.5) {
            return Err(err(format!(
                "key `pose.band` is {}; it must be in (0, 0.5)",
                p.band
            )));
        }
        if !(p.ramp.is_finite() && p.ramp >= 0.0) {
            return Err(err(format!(
                "key `pose.ramp` is {}; it must be >= 0 s",
                p.ramp
            )));
        }
        if !p.amount.is_finite() {
            return Err(err(format!("key `pose.amount` is {}", p.amount)));
        }
        Ok(scene)
    }

    /// Reads and parses a scene file.
    pub fn read(file: &Path) -> Result<YlsScene, SceneError> {
        let text = crate::io::input::read_input_text(file, "scene", crate::io::max_memory())
            .map_err(|e| SceneError {
                file: file.to_path_buf(),
                message: match e {
                    crate::io::IoError::Read { source, .. } => {
                        format!("cannot read the scene: {source}")
                    }
                    other => other.to_string(),
                },
            })?;
        YlsScene::parse(&text, file)
    }

    /// The pose with the defaults filled in.
    pub fn pose_params(&self) -> PoseParams {
        let mut p = PoseParams::new(self.pose.kind, self.pose.amount);
        if let Some(m) = self.pose.mirror {
            p.mirror = m;
        }
        if let Some(f) = self.pose.folds {
            p.folds = f;
        }
        if let Some(b) = self.pose.band {
            p.band = b;
        }
        p.ramp = self.pose.ramp.unwrap_or(0.8 * self.duration);
        p
    }

    /// Number of output frames (the rest state is frame 0, not counted).
    pub fn num_frames(&self) -> usize {
        (self.duration * self.frame_rate).round().max(1.0) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "rib stretch"
duration = 1.0
[swatch]
pattern = "rib1x1"
courses = 8
wales = 8
[pose]
kind = "stretch_courses"
amount = 0.3
[[colliders]]
type = "sphere"
radius = 0.05
[[colliders]]
type = "character"
file = "Fox.glb"
scale = 0.01
"#;

    #[test]
    fn parses_and_resolves() {
        let s = YlsScene::parse(GOOD, Path::new("/scenes/a.toml")).unwrap();
        assert_eq!(s.frame_rate, 60.0);
        assert_eq!(s.num_frames(), 60);
        assert_eq!(s.pose.kind, PoseKind::StretchCourses);
        assert_eq!(s.pose_params().ramp, 0.8);
        match &s.colliders[1] {
            ColliderSpec::Character { file, .. } => {
                assert_eq!(file, Path::new("/scenes/Fox.glb"))
            }
            c => panic!("{c:?}"),
        }
    }

    #[test]
    fn collider_friction_defaults_to_none_and_reaches_the_collider() {
        let mut rest = crate::geom::Yarns::new();
        rest.push_curve(&[[0.0; 3], [0.01, 0.0, 0.0]], false, 0.001);
        let mu = |text: &str| {
            let s = YlsScene::parse(text, Path::new("/scenes/a.toml")).unwrap();
            let c = crate::pipeline::yls::scene_colliders(&s.colliders[..1], &rest).unwrap();
            c[0].friction()
        };
        assert_eq!(mu(GOOD), 0.0);
        assert_eq!(
            mu(&GOOD.replace("radius = 0.05", "radius = 0.05\nfriction = 0.4")),
            0.4
        );
    }

    #[test]
    fn a_sphere_moves_at_its_velocity_and_a_runaway_one_is_refused() {
        let mut rest = crate::geom::Yarns::new();
        rest.push_curve(&[[0.0; 3], [0.01, 0.0, 0.0]], false, 0.001);
        let text = GOOD.replace("radius = 0.05", "radius = 0.05\nvelocity = [0.3, 0.0, 0.0]");
        let s = YlsScene::parse(&text, Path::new("/scenes/a.toml")).unwrap();
        let c = crate::pipeline::yls::scene_colliders(&s.colliders[..1], &rest).unwrap();
        assert_eq!(c[0].velocity([0.0; 3], 0.2), [0.3, 0.0, 0.0]);
        // The same point 0.2 s later: the centre has moved 6 cm along +X.
        let p = [0.06, 0.0, 0.0];
        let (d0, _) = c[0].signed_distance(p, 0.0);
        let (d1, _) = c[0].signed_distance(p, 0.2);
        assert!(d1 < d0 - 0.01, "{d0} -> {d1}");
        let still = crate::pipeline::yls::scene_colliders(
            &YlsScene::parse(GOOD, Path::new("/scenes/a.toml"))
                .unwrap()
                .colliders[..1],
            &rest,
        )
        .unwrap();
        assert_eq!(still[0].velocity([0.0; 3], 0.2), [0.0; 3]);
        let e = YlsScene::parse(
            &GOOD.replace("radius = 0.05", "radius = 0.05\nvelocity = [1e3, 0.0, 0.0]"),
            Path::new("/scenes/a.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("velocity") && e.contains("at most"), "{e}");
    }

    #[test]
    fn errors_name_the_key() {
        let cases = [
            (GOOD.replace("amount = 0.3", "amont = 0.3"), "amont"),
            (
                GOOD.replace("duration = 1.0", "duration = -1.0"),
                "duration",
            ),
            (GOOD.replace("stretch_courses", "stretchy"), "stretchy"),
            (
                GOOD.replace("radius = 0.05", "radius = 0.0"),
                "colliders[0].radius",
            ),
            (
                GOOD.replace("radius = 0.05", "radius = 0.05\nfriction = -0.1"),
                "colliders[0].friction",
            ),
            (GOOD.replace("courses = 8", "courses = 0"), "swatch.courses"),
            (
                GOOD.replace("pattern = \"rib1x1\"", "file = \"a.h5\"\ngrid = \"b\""),
                "swatch",
            ),
            (
                GOOD.replace("duration = 1.0", "duration = \"long\""),
                "duration",
            ),
            (GOOD.replace("duration = 1.0\n", ""), "duration"),
            (format!("{GOOD}\nband = 0.9"), "band"),
        ];
        for (text, key) in cases {
            let e = YlsScene::parse(&text, Path::new("s.toml")).unwrap_err();
            let msg = e.to_string();
            assert!(msg.starts_with("s.toml: "), "{msg}");
            assert!(msg.contains(key), "{key} not in {msg}");
        }
    }

    #[test]
    fn example_scenes_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
        let mut kinds = std::collections::BTreeSet::new();
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let s = YlsScene::read(&path).unwrap_or_else(|e| panic!("{e}"));
                kinds.insert(format!("{:?}", s.pose.kind));
            }
        }
        // Every pose kind has an example.
        assert_eq!(kinds.len(), PoseKind::ALL.len(), "{kinds:?}");
    }
}
