//! Simulation scenes: the TOML file of `knitvox simulate --scene` (layout and
//! every key in schemas/sim-scene.md): time stepping, garment placement,
//! scripted pins, planes and spheres, and an animated character that the
//! garment is pinned to and collides with.
//!
//! Parsing rejects unknown keys, and every error names the file and the key
//! (`toml` reports the line, column and key path).

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::anim::pins::DEFAULT_PIN_DISTANCE;
use crate::geom::Vec3;
use crate::sim::pd::PdParams;

/// Global solver of the PD step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SolverChoice {
    /// Sparse Cholesky of the free block of K (VH Eq. 27-28).
    #[default]
    Direct,
    /// Domain-decomposed CMS subspace + Chebyshev-Jacobi (VH §7.2).
    Dd,
}

/// What a shot's colliders act on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ContactChoice {
    /// The free tet nodes, each keeping the collider's thickness.
    #[default]
    Nodes,
    /// The yarn vertices (V2Y), each keeping its yarn radius plus the
    /// collider's thickness, their forces reaching the nodes through the
    /// embedding weights (sim::contact, "Contacts at embedded points").
    Yarns,
}

/// Most PD iterations per step a scene may ask for (8 is the default; more
/// than this is a typo, not a setting).
pub const MAX_PD_ITERATIONS: u32 = 10_000;
/// Largest Anderson window (each slot holds two copies of the positions).
pub const MAX_ANDERSON_WINDOW: usize = 64;

/// Where the PD iterations run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// CPU (f64 reference).
    Cpu,
    /// wgpu (f32).
    Gpu,
    /// The GPU when one is available, else the CPU.
    #[default]
    Auto,
}

/// Why a scene value given as text could not be read; `text` is the
/// value as given (cut to an excerpt).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    /// Not one of the known choices.
    #[error("'{text}': expected {expected}")]
    UnknownChoice {
        text: String,
        expected: &'static str,
    },
    /// The numerator of a time `a/b` is not a number.
    #[error("'{text}': bad numerator")]
    Numerator { text: String },
    /// The denominator of a time `a/b` is not a number.
    #[error("'{text}': bad denominator")]
    Denominator { text: String },
    /// Neither a number of seconds nor a fraction.
    #[error("'{text}': expected seconds, e.g. 0.0066 or 1/150")]
    NotSeconds { text: String },
    /// A time that is not finite or not above 0 s.
    #[error("'{text}': must be a finite time > 0 s")]
    NotPositive { text: String },
}

impl std::str::FromStr for SolverChoice {
    type Err = ValueError;
    fn from_str(s: &str) -> Result<Self, ValueError> {
        match s {
            "direct" => Ok(SolverChoice::Direct),
            "dd" => Ok(SolverChoice::Dd),
            _ => Err(ValueError::UnknownChoice {
                text: crate::geom::excerpt(s),
                expected: "direct or dd",
            }),
        }
    }
}

impl std::str::FromStr for BackendChoice {
    type Err = ValueError;
    fn from_str(s: &str) -> Result<Self, ValueError> {
        match s {
            "cpu" => Ok(BackendChoice::Cpu),
            "gpu" => Ok(BackendChoice::Gpu),
            "auto" => Ok(BackendChoice::Auto),
            _ => Err(ValueError::UnknownChoice {
                text: crate::geom::excerpt(s),
                expected: "cpu, gpu or auto",
            }),
        }
    }
}

impl SolverChoice {
    pub fn name(self) -> &'static str {
        match self {
            SolverChoice::Direct => "direct",
            SolverChoice::Dd => "dd",
        }
    }
}

impl BackendChoice {
    pub fn name(self) -> &'static str {
        match self {
            BackendChoice::Cpu => "cpu",
            BackendChoice::Gpu => "gpu",
            BackendChoice::Auto => "auto",
        }
    }
}

/// Parses a time step: seconds as a number or a fraction `1/150`.
pub fn parse_seconds(s: &str) -> Result<f64, ValueError> {
    let text = || crate::geom::excerpt(s);
    let v = match s.split_once('/') {
        Some((a, b)) => {
            let a: f64 = a
                .trim()
                .parse()
                .map_err(|_| ValueError::Numerator { text: text() })?;
            let b: f64 = b
                .trim()
                .parse()
                .map_err(|_| ValueError::Denominator { text: text() })?;
            a / b
        }
        None => s
            .trim()
            .parse()
            .map_err(|_| ValueError::NotSeconds { text: text() })?,
    };
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(ValueError::NotPositive { text: text() })
    }
}

/// A time step in a scene: a number of seconds or a string `"1/150"`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Seconds(pub f64);

impl<'de> Deserialize<'de> for Seconds {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Num(f64),
            Int(i64),
            Text(String),
        }
        let v = match Raw::deserialize(d)? {
            Raw::Num(x) => x,
            Raw::Int(i) => i as f64,
            Raw::Text(s) => parse_seconds(&s).map_err(serde::de::Error::custom)?,
        };
        if v.is_finite() && v > 0.0 {
            Ok(Seconds(v))
        } else {
            Err(serde::de::Error::custom(format!(
                "{}: must be a finite time > 0 s",
                shown_number(v)
            )))
        }
    }
}

/// `[simulation]`: time stepping.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimulationSection {
    /// Largest time step (s); each frame interval is split into
    /// `ceil(frame interval / dt)` equal steps. Default 1/150 (VH Table 1).
    pub dt: Seconds,
    /// Frames per second of the frame numbers. Default 24.
    pub fps: f64,
    /// Gravity (m/s²). Default `[0, -9.81, 0]`.
    pub gravity: Vec3,
    /// Mass-proportional damping (1/s), implicit (sim::pd). Default 2:
    /// settles a drape within a second of shot time without visibly slowing
    /// the motion a character drives through the pins.
    pub damping: f64,
    /// Most PD iterations per step, the cap on `tolerance`. Default 100
    /// (sim::pd); a step that reaches it is counted and warned about.
    pub max_iterations: u32,
    /// Anderson acceleration window of the PD iterations, 0 for plain PD.
    /// Default 5 (sim::pd).
    pub anderson_window: usize,
    /// Coulomb friction coefficient (0..1, static = kinetic) of contacts
    /// with every collider, relative to the collider's motion
    /// (sim::contact). Default 0.5: a swatch dropped on a sphere stays on
    /// it instead of sliding off.
    pub friction: f64,
    /// PD convergence tolerance (dimensionless, sim::pd `PdParams::tolerance`):
    /// a step stops once a PD iteration moves no node by more than this
    /// fraction of the step's displacement, nor would any node's residual
    /// force move its mass by more. Default: `PdParams`'s; 0 runs
    /// `max_iterations`.
    pub tolerance: f64,
    /// Shot time (s) simulated before the first frame while the character
    /// blends from its bind pose into the first frame's pose [default: 0.2
    /// with a character (`DEFAULT_CHARACTER_PREROLL`), none without].
    pub preroll: Option<f64>,
    /// Global solver. Default direct.
    pub solver: SolverChoice,
    /// Backend. Default auto.
    pub backend: BackendChoice,
    /// What the colliders act on. Default nodes.
    pub contact: ContactChoice,
}

/// Longest pre-roll (s) a shot may ask for: an hour of shot time before the
/// first frame is a typo, not a setting.
pub const MAX_PREROLL_S: f64 = 3600.0;

/// Smallest and largest `[character] scale` (metres per character unit): a
/// micrometre to a thousand kilometres per unit covers every file unit.
pub const CHARACTER_SCALE_RANGE: (f64, f64) = (1e-6, 1e6);

/// A number as a message shows it: short (`1e300`, not 301 digits), so a
/// value out of range never makes a message long.
pub fn shown_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e6).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Frames per second of a scene without `fps`.
pub const DEFAULT_FPS: f64 = 24.0;

/// Mass-proportional damping (1/s) of a shot without `damping` (see
/// [`SimulationSection::damping`]; the simulator's own default is none).
pub const DEFAULT_SHOT_DAMPING: f64 = 2.0;

/// Coulomb friction coefficient of a shot without `friction`.
pub const DEFAULT_FRICTION: f64 = 0.5;

/// The step, gravity, iterations, Anderson window and tolerance are the
/// simulator's own defaults ([`PdParams::default`]): one source.
impl Default for SimulationSection {
    fn default() -> Self {
        let pd = PdParams::default();
        SimulationSection {
            dt: Seconds(pd.dt),
            fps: DEFAULT_FPS,
            gravity: pd.gravity,
            damping: DEFAULT_SHOT_DAMPING,
            max_iterations: pd.max_iterations,
            anderson_window: pd.anderson_window,
            friction: DEFAULT_FRICTION,
            tolerance: pd.tolerance,
            preroll: None,
            solver: SolverChoice::Direct,
            backend: BackendChoice::Auto,
            contact: ContactChoice::Nodes,
        }
    }
}

/// `[garment]`: rigid placement of the asset's rest mesh in the scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct GarmentSection {
    /// Rotation (degrees) about the x, then y, then z axis through the
    /// mesh's bounding-box centre. Default none.
    pub rotate_deg: Vec3,
    /// Where the bounding-box centre goes (m), after the rotation [default:
    /// where it is].
    pub center: Option<Vec3>,
    /// Translation (m) after the rotation (and after `[character]`
    /// `fit_joint`, as an offset). Default none.
    pub translate: Vec3,
}

/// A scripted pin group `[[pin]]`: nodes chosen by a box or by index,
/// moved rigidly over time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct PinSection {
    /// Name for reports.
    pub name: String,
    /// Box corner (m, scene coordinates after placement): nodes inside the
    /// box `[box_min, box_max]` are pinned.
    pub box_min: Option<Vec3>,
    pub box_max: Option<Vec3>,
    /// Node indices pinned (in addition to the box).
    pub nodes: Vec<usize>,
    /// Linear velocity (m/s) of the group while it moves. Default 0.
    pub velocity: Vec3,
    /// Angular velocity (degrees/s about x, y, z) about `pivot` while it
    /// moves. Default 0.
    pub angular_velocity_deg: Vec3,
    /// Rotation centre (m) [default: the centre of the group's nodes].
    pub pivot: Option<Vec3>,
    /// Shot time (s, 0 = first frame) when the motion starts. Default 0.
    pub start: f64,
    /// Shot time (s) when it stops [default: never].
    pub end: Option<f64>,
}

/// `[[collider]]`: a plane or a sphere.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, tag = "type", rename_all = "lowercase")]
pub enum ColliderSection {
    Plane {
        /// A point on the plane (m).
        point: Vec3,
        /// Outward normal (need not be unit).
        normal: Vec3,
        /// Distance nodes keep (m). Default 1 mm.
        #[serde(default = "default_thickness")]
        thickness: f64,
    },
    Sphere {
        /// Centre (m).
        center: Vec3,
        /// Radius (m).
        radius: f64,
        /// Distance nodes keep (m). Default 1 mm.
        #[serde(default = "default_thickness")]
        thickness: f64,
    },
}

/// Default collider thickness (m): 1 mm, about one voxel of the default
/// embedding, so the yarns inside the tet mesh stay off the surface.
pub const DEFAULT_THICKNESS: f64 = 1e-3;

fn default_thickness() -> f64 {
    DEFAULT_THICKNESS
}

/// `[character]`: a skinned glTF character.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharacterSection {
    /// glTF / GLB file (relative paths: from the scene file's folder).
    pub file: PathBuf,
    /// Animation name [default: the first].
    pub animation: Option<String>,
    /// Metres per character unit. Default 1 (glTF is in metres); Fox.glb is
    /// modelled in centimetre-like units 80 high: 0.01 makes it 0.8 m.
    pub scale: f64,
    /// Translation (m) of the character after scaling. Default none.
    pub translate: Vec3,
    /// Pin garment nodes within `pin_distance` of the bind-pose body. Default true.
    pub pins: bool,
    /// Pin distance (m). Default 5 mm.
    pub pin_distance: f64,
    /// Collide the free nodes with the body. Default true.
    pub collide: bool,
    /// Distance nodes keep from the body (m). Default 1 mm.
    pub thickness: f64,
    /// Loop the animation past its end (else hold the last pose). Default true.
    pub r#loop: bool,
    /// Animation time (s) at the first frame. Default 0.
    pub time_offset: f64,
    /// Lay the garment on the body over this joint (node name): after
    /// `[garment]` rotation, its bounding-box centre goes over the joint's
    /// bind-pose position (x, z) and its lowest node `fit_gap` above the
    /// highest body vertex under its footprint. Default none.
    pub fit_joint: Option<String>,
    /// Gap (m) of `fit_joint`. Default 1 mm.
    pub fit_gap: f64,
}

impl Default for CharacterSection {
    fn default() -> Self {
        CharacterSection {
            file: PathBuf::new(),
            animation: None,
            scale: 1.0,
            translate: [0.0; 3],
            pins: true,
            pin_distance: DEFAULT_PIN_DISTANCE,
            collide: true,
            thickness: DEFAULT_THICKNESS,
            r#loop: true,
            time_offset: 0.0,
            fit_joint: None,
            fit_gap: 1e-3,
        }
    }
}

/// A whole scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Scene {
    pub simulation: SimulationSection,
    pub garment: GarmentSection,
    pub pin: Vec<PinSection>,
    pub collider: Vec<ColliderSection>,
    pub character: Option<CharacterSection>,
    /// Folder relative paths are resolved against (the scene file's).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// A scene file that cannot be used; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {message}", path = path.display())]
pub struct SceneError {
    pub path: PathBuf,
    pub message: String,
}

/// A scene value out of its range: `key` names it (`simulation.fps`,
/// `pin[0].end`), `message` says what it must be.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct SceneValueError {
    /// The key of the value, with its table (`character.scale`).
    pub key: String,
    /// What the value must be, and what it was.
    pub message: String,
}

/// The error of the value at `key`.
fn invalid(key: impl Into<String>, message: impl Into<String>) -> SceneValueError {
    SceneValueError {
        key: key.into(),
        message: message.into(),
    }
}

/// A TOML error as one line, `line L, column C: message`: toml's own text
/// quotes the input line under a caret over several lines, and serde's
/// messages quote whole values.
pub(crate) fn toml_error_line(e: &toml::de::Error, text: &str) -> String {
    // Quoted values (odd pieces between '"') are cut like any input excerpt.
    let quoted_cut: Vec<String> = e
        .message()
        .trim()
        .split('"')
        .enumerate()
        .map(|(i, piece)| {
            if i % 2 == 1 {
                crate::geom::excerpt(piece)
            } else {
                piece.to_string()
            }
        })
        .collect();
    let message = crate::geom::excerpt_chars(&quoted_cut.join("\""), 200);
    let Some(at) = e.span().map(|s| s.start.min(text.len())) else {
        return message;
    };
    let before = text.as_bytes()[..at].to_vec();
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let column = at
        - before
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1)
        + 1;
    // The one input line, cut, names the key for syntax errors.
    let source = text.lines().nth(line - 1).unwrap_or("");
    format!(
        "line {line}, column {column}: {message} (in '{}')",
        crate::geom::excerpt(source.trim())
    )
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Scene {
    /// Parses scene text; `path` names the file in errors and relative
    /// paths are resolved against its folder.
    pub fn parse(text: &str, path: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = toml::from_str(text).map_err(|e| SceneError {
            path: path.to_path_buf(),
            message: toml_error_line(&e, text),
        })?;
        scene.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        scene.validate().map_err(|e| SceneError {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Ok(scene)
    }

    /// Checks values serde cannot: ranges and finiteness. Messages start with the key.
    pub fn validate(&self) -> Result<(), SceneValueError> {
        let s = &self.simulation;
        if !(s.fps.is_finite() && s.fps > 0.0) {
            return Err(invalid(
                "simulation.fps",
                format!("must be > 0 (got {})", shown_number(s.fps)),
            ));
        }
        if !finite(&s.gravity) {
            return Err(invalid("simulation.gravity", "must be finite"));
        }
        if !(s.damping.is_finite() && s.damping >= 0.0) {
            return Err(invalid(
                "simulation.damping",
                format!("must be >= 0 (got {})", shown_number(s.damping)),
            ));
        }
        if !(s.tolerance.is_finite() && s.tolerance >= 0.0) {
            return Err(invalid(
                "simulation.tolerance",
                format!("must be >= 0 (got {})", shown_number(s.tolerance)),
            ));
        }
        if let Some(p) = s
            .preroll
            .filter(|p| !(p.is_finite() && (0.0..=MAX_PREROLL_S).contains(p)))
        {
            return Err(invalid(
                "simulation.preroll",
                format!("must be 0 to {MAX_PREROLL_S} s (got {})", shown_number(p)),
            ));
        }
        if !(0.0..=1.0).contains(&s.friction) {
            return Err(invalid(
                "simulation.friction",
                format!("must be in 0..1 (got {})", shown_number(s.friction)),
            ));
        }
        if s.max_iterations == 0 {
            return Err(invalid("simulation.max_iterations", "must be >= 1"));
        }
        if s.max_iterations > MAX_PD_ITERATIONS {
            return Err(invalid(
                "simulation.max_iterations",
                format!(
                    "{} is more than the limit of {MAX_PD_ITERATIONS}",
                    s.max_iterations
                ),
            ));
        }
        if s.anderson_window > MAX_ANDERSON_WINDOW {
            return Err(invalid(
                "simulation.anderson_window",
                format!(
                    "{} is more than the limit of {MAX_ANDERSON_WINDOW}",
                    s.anderson_window
                ),
            ));
        }
        if !(s.dt.0.is_finite() && s.dt.0 > 0.0) {
            return Err(invalid(
                "simulation.dt",
                format!("must be > 0 and finite (got {})", shown_number(s.dt.0)),
            ));
        }
        if !finite(&self.garment.rotate_deg)
            || !finite(&self.garment.translate)
            || self.garment.center.is_some_and(|c| !finite(&c))
        {
            return Err(invalid(
                "garment",
                "rotate_deg, center and translate must be finite",
            ));
        }
        for (i, p) in self.pin.iter().enumerate() {
            let key = format!("pin[{i}]");
            if p.box_min.is_some() != p.box_max.is_some() {
                return Err(invalid(
                    format!("{key}.box_min/box_max"),
                    "give both or neither",
                ));
            }
            if p.box_min.is_none() && p.nodes.is_empty() {
                return Err(invalid(key.as_str(), "give box_min/box_max or nodes"));
            }
            for v in [p.box_min, p.box_max, p.pivot].into_iter().flatten() {
                if !finite(&v) {
                    return Err(invalid(key.as_str(), "box and pivot must be finite"));
                }
            }
            if !finite(&p.velocity) || !finite(&p.angular_velocity_deg) {
                return Err(invalid(
                    key.as_str(),
                    "velocity and angular_velocity_deg must be finite",
                ));
            }
            if !p.start.is_finite() || p.end.is_some_and(|e| !(e >= p.start)) {
                return Err(invalid(format!("{key}.end"), "must be >= start"));
            }
        }
        for (i, c) in self.collider.iter().enumerate() {
            let key = format!("collider[{i}]");
            match c {
                ColliderSection::Plane {
                    point,
                    normal,
                    thickness,
                } => {
                    if !finite(point) || !finite(normal) || normal.iter().all(|x| *x == 0.0) {
                        return Err(invalid(
                            format!("{key}.normal"),
                            "must be finite and non-zero",
                        ));
                    }
                    if !(thickness.is_finite() && *thickness >= 0.0) {
                        return Err(invalid(format!("{key}.thickness"), "must be >= 0"));
                    }
                }
                ColliderSection::Sphere {
                    center,
                    radius,
                    thickness,
                } => {
                    if !finite(center) {
                        return Err(invalid(format!("{key}.center"), "must be finite"));
                    }
                    if !(radius.is_finite() && *radius > 0.0) {
                        return Err(invalid(
                            format!("{key}.radius"),
                            format!("must be > 0 (got {})", shown_number(*radius)),
                        ));
                    }
                    if !(thickness.is_finite() && *thickness >= 0.0) {
                        return Err(invalid(format!("{key}.thickness"), "must be >= 0"));
                    }
                }
            }
        }
        if let Some(c) = &self.character {
            if c.file.as_os_str().is_empty() {
                return Err(invalid("character.file", "missing"));
            }
            let (lo, hi) = CHARACTER_SCALE_RANGE;
            if !(c.scale.is_finite() && (lo..=hi).contains(&c.scale)) {
                return Err(invalid(
                    "character.scale",
                    format!(
                        "must be {} to {} metres per unit (got {})",
                        shown_number(lo),
                        shown_number(hi),
                        shown_number(c.scale)
                    ),
                ));
            }
            if !finite(&c.translate) {
                return Err(invalid("character.translate", "must be finite"));
            }
            if !(c.pin_distance.is_finite() && c.pin_distance >= 0.0) {
                return Err(invalid(
                    "character.pin_distance",
                    format!("must be >= 0 (got {})", shown_number(c.pin_distance)),
                ));
            }
            if !(c.thickness.is_finite() && c.thickness >= 0.0) {
                return Err(invalid(
                    "character.thickness",
                    format!("must be >= 0 (got {})", shown_number(c.thickness)),
                ));
            }
            if !c.time_offset.is_finite() || !c.fit_gap.is_finite() {
                return Err(invalid("character.time_offset/fit_gap", "must be finite"));
            }
        }
        Ok(())
    }

    /// The character file with relative paths resolved against the scene's folder.
    pub fn character_path(&self) -> Option<PathBuf> {
        self.character.as_ref().map(|c| {
            if c.file.is_absolute() {
                c.file.clone()
            } else {
                self.base_dir.join(&c.file)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One source for each default: the scene's simulator settings are
    /// the simulator's defaults.
    #[test]
    fn scene_defaults_are_the_simulators() {
        let s = SimulationSection::default();
        let pd = PdParams::default();
        assert_eq!(s.dt.0, pd.dt);
        assert_eq!(s.gravity, pd.gravity);
        assert_eq!(s.max_iterations, pd.max_iterations);
        assert_eq!(s.anderson_window, pd.anderson_window);
        assert_eq!(s.tolerance, pd.tolerance);
        // An empty scene file gets the same.
        let parsed = Scene::parse("", Path::new("s.toml")).unwrap();
        assert_eq!(parsed.simulation, s);
    }

    #[test]
    fn parses_a_full_scene() {
        let text = r#"
[simulation]
dt = "1/150"
fps = 24
damping = 1.0
[garment]
rotate_deg = [-90, 0, 0]
[[pin]]
name = "left"
box_min = [-1, -1, -1]
box_max = [0, 1, 1]
velocity = [0.01, 0, 0]
[[collider]]
type = "sphere"
center = [0, 0, 0]
radius = 0.01
[[collider]]
type = "plane"
point = [0, -0.1, 0]
normal = [0, 1, 0]
thickness = 0.0
[character]
file = "Fox.glb"
animation = "Walk"
scale = 0.0025
"#;
        let s = Scene::parse(text, Path::new("dir/scene.toml")).unwrap();
        assert!((s.simulation.dt.0 - 1.0 / 150.0).abs() < 1e-15);
        assert_eq!(s.pin.len(), 1);
        assert_eq!(s.collider.len(), 2);
        assert_eq!(s.character_path().unwrap(), PathBuf::from("dir/Fox.glb"));
        assert_eq!(s.character.unwrap().pin_distance, DEFAULT_PIN_DISTANCE);
    }

    #[test]
    fn errors_name_the_key() {
        let e = Scene::parse("[simulation]\ndamping_x = 1\n", Path::new("s.toml")).unwrap_err();
        assert!(e.message.contains("damping_x"), "{e}");
        let e = Scene::parse(
            "[[collider]]\ntype = \"sphere\"\ncenter = [0,0,0]\nradius = -1\n",
            Path::new("s.toml"),
        )
        .unwrap_err();
        assert!(e.message.contains("collider[0].radius"), "{e}");
        let e = Scene::parse("[simulation]\ndt = \"1/0\"\n", Path::new("s.toml")).unwrap_err();
        assert!(e.message.contains("dt"), "{e}");
        assert!(e.to_string().starts_with("s.toml: "));
    }

    #[test]
    fn seconds_parse() {
        assert_eq!(parse_seconds("1/150").unwrap(), 1.0 / 150.0);
        assert_eq!(parse_seconds("0.01").unwrap(), 0.01);
        assert!(parse_seconds("-1").is_err());
        assert!(parse_seconds("1/0").is_err());
    }
}
