//! Shot setup: the garment placed in the scene, the character loaded and
//! posed, scripted and body pins resolved to nodes, the static colliders,
//! and the step schedule. Everything the time loop (`sim::shot`) needs
//! besides the solver; nothing here steps or writes.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Small fixed-size loops over x, y, z read better indexed.
#![allow(clippy::needless_range_loop)]

use std::path::Path;

use nalgebra::{Rotation3, Vector3};

use super::shot_error::{invalid, SimulateError};
use super::sim_scene::{
    CharacterSection, ColliderSection, ContactChoice, Scene, SimulationSection,
};
use crate::anim::cache::BodyCache;
use crate::anim::pins::BodyPins;
use crate::anim::{Character, TriangleMesh};
use crate::geom::bvh::{BvhError, MeshCollider, MeshTopology};
use crate::geom::{Asset, Vec3};
use crate::io;
use crate::sim::collide::{Collider, ColliderSet, Shape};
use std::sync::Arc;

use crate::sim::collide::PointColliders;
use crate::sim::contact::{Contact, EmbeddedPoints, NodeProjector, PointProjector};
use crate::sim::shot::Schedule;
use crate::sim::shot::StepContacts;

/// Default pre-roll (s) of a scene with a character when the scene gives
/// none: 0.2 s (30 steps of 1/150 s) to blend from the bind pose.
pub const DEFAULT_CHARACTER_PREROLL: f64 = 0.2;

/// Most PD steps one shot may take (pre-roll included): hours of work at
/// the fastest step; larger requests are refused before any work starts.
pub const MAX_TOTAL_STEPS: usize = 10_000_000;

/// The character of a shot.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CharacterReport {
    pub file: std::path::PathBuf,
    pub animation: Option<String>,
    pub duration_s: f64,
    pub vertices: usize,
    pub triangles: usize,
    pub closed: bool,
    pub scale: f64,
    pub preroll_s: f64,
}

/// A scripted pin group resolved to nodes.
#[derive(Debug, Clone)]
pub(super) struct Handle {
    nodes: Vec<usize>,
    rest: Vec<Vec3>,
    pivot: Vec3,
    velocity: Vec3,
    omega: Vec3,
    start: f64,
    end: f64,
}

impl Handle {
    pub(super) fn positions(&self, t: f64, out: &mut Vec<Vec3>) {
        let tau = if t <= self.start {
            0.0
        } else {
            t.min(self.end) - self.start
        };
        let w = Vector3::from(self.omega) * tau;
        let r = Rotation3::new(w);
        for p in &self.rest {
            let d = Vector3::new(
                p[0] - self.pivot[0],
                p[1] - self.pivot[1],
                p[2] - self.pivot[2],
            );
            let q = r * d;
            out.push(std::array::from_fn(|k| {
                self.pivot[k] + q[k] + self.velocity[k] * tau
            }));
        }
    }
}

/// Where a body's motion comes from.
enum Motion {
    /// A skinned glTF character and its animation (`None`: the bind pose).
    Skinned {
        character: Character,
        anim: Option<usize>,
    },
    /// A baked point cache (schemas/character-hdf5.md): animation time 0
    /// is its first frame.
    Cache(BodyCache),
}

impl Motion {
    /// Body vertices (file units, unplaced) at animation time `t` (s).
    fn positions(&self, t: f64) -> Vec<Vec3> {
        match self {
            Motion::Skinned { character, anim } => character.skinned_positions(*anim, t),
            Motion::Cache(c) => c.positions_at(c.times[0] + t),
        }
    }
}

/// The character of a shot: motion, placement, topology.
pub(super) struct Body {
    motion: Motion,
    duration: f64,
    scale: f64,
    translate: Vec3,
    looped: bool,
    time_offset: f64,
    topology: MeshTopology,
    bind: Vec<Vec3>,
    first_pose: Vec<Vec3>,
    preroll: f64,
    thickness: f64,
    collide: bool,
}

impl Body {
    fn place(&self, p: Vec<Vec3>) -> Vec<Vec3> {
        p.into_iter()
            .map(|q| std::array::from_fn(|k| q[k] * self.scale + self.translate[k]))
            .collect()
    }
    fn anim_time(&self, t: f64) -> f64 {
        let a = self.time_offset + t;
        if self.looped && self.duration > 0.0 {
            a.rem_euclid(self.duration)
        } else {
            a
        }
    }
    /// Body vertices (m) at shot time `t` (negative: pre-roll blend).
    pub(super) fn positions(&self, t: f64) -> Vec<Vec3> {
        if t < 0.0 {
            let s = if self.preroll > 0.0 {
                ((t + self.preroll) / self.preroll).clamp(0.0, 1.0)
            } else {
                1.0
            };
            let s = s * s * (3.0 - 2.0 * s);
            return self
                .bind
                .iter()
                .zip(&self.first_pose)
                .map(|(a, b)| std::array::from_fn(|k| a[k] + s * (b[k] - a[k])))
                .collect();
        }
        self.place(self.motion.positions(self.anim_time(t)))
    }
}

/// Colliders posed at one shot time: every collider, the body's vertices
/// then, and the body alone as a collider (for the penetration figures).
pub(super) struct Posed {
    pub set: ColliderSet,
    pub verts: Option<Vec<Vec3>>,
    pub body_set: Option<ColliderSet>,
    /// With `[simulation] contact = "yarns"`: the yarn vertices the
    /// colliders act on.
    pub yarn_points: Option<Arc<YarnPoints>>,
}

/// The asset's yarn vertices as contact points and their radii (m).
#[derive(Debug)]
pub(super) struct YarnPoints {
    pub points: EmbeddedPoints,
    pub radius: Vec<f64>,
}

/// Node contacts, or with yarn points the contacts of the yarn vertices.
impl StepContacts for Posed {
    fn points(&self) -> Option<(&EmbeddedPoints, &dyn PointProjector)> {
        self.yarn_points
            .as_ref()
            .map(|y| (&y.points, self as &dyn PointProjector))
    }
}

/// Each yarn vertex keeps its radius beyond every collider's thickness.
impl PointProjector for Posed {
    fn contact(&self, point: usize, p: Vec3) -> Option<Contact> {
        let radius = self.yarn_points.as_ref().map_or(&[][..], |y| &y.radius[..]);
        PointColliders {
            set: &self.set,
            radius,
        }
        .contact(point, p)
    }
}

/// The contacts of a step are those of every collider.
impl NodeProjector for Posed {
    fn project(&self, node: usize, p: Vec3) -> Option<Vec3> {
        self.set.project(node, p)
    }
    fn contact(&self, node: usize, p: Vec3) -> Option<Contact> {
        self.set.contact(node, p)
    }
}

/// A shot ready to run.
pub(super) struct ShotSetup {
    /// Node positions (m) at the start: the placed garment.
    pub x: Vec<Vec3>,
    pub body: Option<Body>,
    pub character: Option<CharacterReport>,
    pub handles: Vec<Handle>,
    pub body_pins: BodyPins,
    /// Whether each node is pinned (scripted or to the body).
    pub is_pinned: Vec<bool>,
    /// Pinned nodes: scripted groups in order, then the body pins.
    pub pinned: Vec<usize>,
    pub statics: Vec<Collider>,
    pub friction: f64,
    /// With `[simulation] contact = "yarns"`: the yarn vertices the
    /// colliders act on.
    pub yarn_points: Option<Arc<YarnPoints>>,
    pub schedule: Schedule,
    /// Remarks for the report (ignored triangles, empty pin groups).
    pub notes: Vec<String>,
}

/// Sets up the shot of frames `first..=last` of `asset` under `scene`.
pub(super) fn setup(
    asset: &Asset,
    asset_path: &Path,
    scene: &Scene,
    first: i64,
    last: i64,
) -> Result<ShotSetup, SimulateError> {
    let sim = &scene.simulation;
    let n = asset.mesh.num_nodes();
    let mut notes = Vec::new();
    let mut x = place_garment(asset, scene);
    let (steps_per_frame, dt) = frame_timing(sim, asset_path, first, last)?;
    let (body, character) = match (&scene.character, scene.character_path()) {
        (Some(c), Some(path)) => {
            let (b, r) = load_character(c, &path, sim, &mut x, &mut notes)?;
            (Some(b), Some(r))
        }
        _ => (None, None),
    };
    for p in &mut x {
        for k in 0..3 {
            p[k] += scene.garment.translate[k];
        }
    }
    let mut is_pinned = vec![false; n];
    let handles = scripted_pins(scene, asset_path, &x, &mut is_pinned, &mut notes)?;
    let body_pins = pin_to_body(scene, body.as_ref(), &x, &mut is_pinned)?;
    let pinned: Vec<usize> = handles
        .iter()
        .flat_map(|h| h.nodes.iter().copied())
        .chain(body_pins.nodes.iter().copied())
        .collect();
    let preroll_steps = body
        .as_ref()
        .map_or(0, |b| (b.preroll / dt).ceil() as usize);
    let schedule = Schedule {
        dt,
        preroll_steps,
        steps_per_frame,
        frame_intervals: (last - first) as usize,
    };
    if schedule.total_steps().is_none_or(|t| t > MAX_TOTAL_STEPS) {
        return Err(invalid(
            asset_path,
            format!(
                "a pre-roll of {preroll_steps} steps plus {} frame steps is more than the limit of {MAX_TOTAL_STEPS} steps",
                (last - first) as usize * steps_per_frame
            ),
        ));
    }
    Ok(ShotSetup {
        x,
        body,
        character,
        handles,
        body_pins,
        is_pinned,
        pinned,
        statics: static_colliders(scene),
        friction: sim.friction,
        yarn_points: (sim.contact == ContactChoice::Yarns).then(|| {
            Arc::new(YarnPoints {
                points: super::asset::yarn_contact_points(asset),
                radius: (0..asset.rest_yarns.num_points())
                    .map(|v| asset.rest_yarns.radius_at(v))
                    .collect(),
            })
        }),
        schedule,
        notes,
    })
}

/// The asset's rest nodes rotated about their bounding-box centre and
/// moved to `garment.center` (the translation comes after `fit_joint`).
fn place_garment(asset: &Asset, scene: &Scene) -> Vec<Vec3> {
    let (lo, hi) = bbox(&asset.mesh.nodes);
    let centre: Vec3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let rot = euler_deg(scene.garment.rotate_deg);
    let target = scene.garment.center.unwrap_or(centre);
    asset
        .mesh
        .nodes
        .iter()
        .map(|p| {
            let d = rot * Vector3::new(p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]);
            std::array::from_fn(|k| target[k] + d[k])
        })
        .collect()
}

/// Steps per frame interval and the step (s) used: each frame interval is
/// split into `ceil(interval / dt)` equal steps, bounded before any work
/// (dt, fps and the frame range are user input).
fn frame_timing(
    sim: &SimulationSection,
    asset_path: &Path,
    first: i64,
    last: i64,
) -> Result<(usize, f64), SimulateError> {
    let frame_dt = 1.0 / sim.fps;
    let spf = ((frame_dt / sim.dt.0) * (1.0 - 1e-12)).ceil().max(1.0);
    let frame_steps = spf * (last - first) as f64;
    if !(frame_steps <= MAX_TOTAL_STEPS as f64) {
        return Err(invalid(
        asset_path,
        format!(
            "frames {first}-{last} at {} fps with dt {} s need {} steps, more than the limit of {MAX_TOTAL_STEPS}",
            crate::geom::num(sim.fps),
            crate::geom::num(sim.dt.0),
            crate::geom::num(frame_steps)
        ),
    ));
    }
    let steps_per_frame = spf as usize;
    let dt = frame_dt / steps_per_frame as f64;
    Ok((steps_per_frame, dt))
}

/// Reads the character, poses it at the bind pose and the first frame, and
/// with `fit_joint` lays the garment `x` onto it.
fn load_character(
    c: &CharacterSection,
    path: &Path,
    sim: &SimulationSection,
    x: &mut [Vec3],
    notes: &mut Vec<String>,
) -> Result<(Body, CharacterReport), SimulateError> {
    let (motion, animation, duration, rest) = if is_cache(path) {
        read_cache(c, path)?
    } else {
        read_skinned(c, path)?
    };
    if rest.triangles.is_empty() {
        return Err(invalid(path, "the character has no triangles"));
    }
    let (topology, dropped) = MeshTopology::welded(&rest.triangles, &rest.positions);
    if dropped > 0 {
        notes.push(format!(
            "character: {dropped} degenerate or out-of-range triangles ignored"
        ));
    }
    let preroll = sim.preroll.unwrap_or(DEFAULT_CHARACTER_PREROLL);
    let mut b = Body {
        motion,
        duration,
        scale: c.scale,
        translate: c.translate,
        looped: c.r#loop,
        time_offset: c.time_offset,
        topology,
        bind: Vec::new(),
        first_pose: Vec::new(),
        preroll,
        thickness: c.thickness,
        collide: c.collide,
    };
    b.bind = b.place(rest.positions);
    b.first_pose = b.place(b.motion.positions(b.anim_time(0.0)));
    if let (Some(joint), Motion::Skinned { character, .. }) = (&c.fit_joint, &b.motion) {
        let j = character
            .skeleton
            .iter()
            .position(|nd| nd.name.as_deref() == Some(joint.as_str()))
            .ok_or_else(|| {
                invalid(
                    path,
                    format!(
                        "character.fit_joint: no node named '{}'",
                        crate::geom::excerpt(joint)
                    ),
                )
            })?;
        let w = character.node_world_matrices(None, 0.0)[j];
        let jp: Vec3 = std::array::from_fn(|k| w[(k, 3)] * b.scale + b.translate[k]);
        let (glo, ghi) = bbox(x);
        // Centre over the joint, then lift so that the lowest clearance
        // between a garment node and the body surface straight below it
        // is `fit_gap`.
        let dx = [
            jp[0] - 0.5 * (glo[0] + ghi[0]),
            jp[2] - 0.5 * (glo[2] + ghi[2]),
        ];
        let lift = x
            .iter()
            .filter_map(|p| {
                surface_height(&b.topology, &b.bind, p[0] + dx[0], p[2] + dx[1]).map(|h| h - p[1])
            })
            .fold(f64::NEG_INFINITY, f64::max);
        if !lift.is_finite() {
            return Err(invalid(
                path,
                format!(
                    "character.fit_joint: the body has no surface under the garment at joint '{}'",
                    crate::geom::excerpt(joint)
                ),
            ));
        }
        let shift = [dx[0], lift + c.fit_gap, dx[1]];
        for p in x.iter_mut() {
            for k in 0..3 {
                p[k] += shift[k];
            }
        }
    }
    let report = CharacterReport {
        file: path.to_path_buf(),
        animation,
        duration_s: duration,
        vertices: b.bind.len(),
        triangles: b.topology.triangles().len(),
        closed: b.topology.is_closed(),
        scale: c.scale,
        preroll_s: preroll,
    };
    Ok((b, report))
}

/// Whether a character file is an HDF5 point cache (by its extension; a
/// cache's content is checked when it is read).
pub(crate) fn is_cache(path: &Path) -> bool {
    io::Format::from_path(path) == Some(io::Format::Hdf5)
}

/// A glTF character: its motion, the animation's name and duration, and
/// the bind-pose body.
fn read_skinned(
    c: &CharacterSection,
    path: &Path,
) -> Result<(Motion, Option<String>, f64, TriangleMesh), SimulateError> {
    let character = io::gltf_skin::read_character(path)?;
    let anim = match &c.animation {
        Some(name) => Some(character.animation_index(name).ok_or_else(|| {
            invalid(
                path,
                format!(
                    "character.animation: no animation '{}' (the file has: {})",
                    crate::geom::excerpt(name),
                    crate::geom::excerpt(&character.animation_names().join(", "))
                ),
            )
        })?),
        None => (!character.animations.is_empty()).then_some(0),
    };
    let duration = anim.map_or(0.0, |a| character.duration(a));
    let name = anim.map(|a| character.animation_names()[a].clone());
    let rest = character.body_mesh(None, 0.0);
    Ok((Motion::Skinned { character, anim }, name, duration, rest))
}

/// An HDF5 character cache: one motion, no skeleton; its rest pose is the
/// bind pose.
fn read_cache(
    c: &CharacterSection,
    path: &Path,
) -> Result<(Motion, Option<String>, f64, TriangleMesh), SimulateError> {
    let no = |key: &str, why: &str| {
        Err(invalid(
            path,
            format!("character.{key}: {why}; this file is a character cache (schemas/character-hdf5.md)"),
        ))
    };
    if c.animation.is_some() {
        return no(
            "animation",
            "a cache holds one motion, so there is nothing to choose",
        );
    }
    if c.fit_joint.is_some() {
        return no(
            "fit_joint",
            "a cache has no skeleton; place the garment with garment.translate / --garment-offset",
        );
    }
    let read = io::character_h5::read_character_cache(path, io::max_memory())?;
    let cache = read.cache;
    let rest = cache.rest_mesh();
    let duration = cache.duration();
    Ok((Motion::Cache(cache), None, duration, rest))
}

/// The `[[pin]]` groups resolved to nodes of the placed garment `x`; a
/// node belongs to the first group that selects it.
fn scripted_pins(
    scene: &Scene,
    asset_path: &Path,
    x: &[Vec3],
    is_pinned: &mut [bool],
    notes: &mut Vec<String>,
) -> Result<Vec<Handle>, SimulateError> {
    let n = x.len();
    let mut handles = Vec::new();
    for (i, ps) in scene.pin.iter().enumerate() {
        let mut nodes = Vec::new();
        for &nd in &ps.nodes {
            if nd >= n {
                return Err(invalid(
                    asset_path,
                    format!("pin[{i}].nodes: node {nd} does not exist (the mesh has {n} nodes)"),
                ));
            }
            nodes.push(nd);
        }
        if let (Some(a), Some(b)) = (ps.box_min, ps.box_max) {
            nodes.extend((0..n).filter(|&j| (0..3).all(|k| x[j][k] >= a[k] && x[j][k] <= b[k])));
        }
        nodes.sort_unstable();
        nodes.dedup();
        nodes.retain(|&j| !std::mem::replace(&mut is_pinned[j], true));
        if nodes.is_empty() {
            notes.push(format!("pin[{i}] ({}) selects no free node", ps.name));
            continue;
        }
        let rest: Vec<Vec3> = nodes.iter().map(|&j| x[j]).collect();
        let pivot = ps.pivot.unwrap_or_else(|| {
            let s = rest
                .iter()
                .fold([0.0; 3], |a, p| std::array::from_fn(|k| a[k] + p[k]));
            s.map(|c| c / rest.len() as f64)
        });
        handles.push(Handle {
            nodes,
            rest,
            pivot,
            velocity: ps.velocity,
            omega: ps.angular_velocity_deg.map(f64::to_radians),
            start: ps.start,
            end: ps.end.unwrap_or(f64::INFINITY),
        });
    }
    Ok(handles)
}

/// Garment nodes within `character.pin_distance` of the bind-pose body,
/// pinned to it (those not pinned by a group already).
fn pin_to_body(
    scene: &Scene,
    body: Option<&Body>,
    x: &[Vec3],
    is_pinned: &mut [bool],
) -> Result<BodyPins, SimulateError> {
    let mut body_pins = BodyPins::default();
    if let (Some(b), Some(c)) = (body, &scene.character) {
        if c.pins {
            let bind = MeshCollider::new(&b.topology, &b.bind)
                .map_err(|e| invalid(&scene.character_path().unwrap_or_default(), e.to_string()))?;
            let all = BodyPins::select(&b.topology, &bind, x, c.pin_distance);
            for (k, &nd) in all.nodes.iter().enumerate() {
                if !is_pinned[nd] {
                    is_pinned[nd] = true;
                    body_pins.nodes.push(nd);
                    body_pins.attachments.push(all.attachments[k]);
                    body_pins.distances.push(all.distances[k]);
                }
            }
            if body_pins.nodes.is_empty() {
                return Err(invalid(
                &scene.character_path().unwrap_or_default(),
                format!(
                    "character.pin_distance: no garment node lies within {} m of the bind-pose body; \
                     place the garment on the body (character.fit_joint / --fit-joint, garment.translate / \
                     --garment-offset, character.scale / --character-scale) or raise the pin distance",
                    c.pin_distance
                ),
            ));
            }
        }
    }
    Ok(body_pins)
}

/// The scene's planes and spheres.
fn static_colliders(scene: &Scene) -> Vec<Collider> {
    let mut statics = Vec::new();
    for c in &scene.collider {
        statics.push(match c {
            ColliderSection::Plane {
                point,
                normal,
                thickness,
            } => Collider {
                shape: Shape::Plane {
                    point: *point,
                    normal: *normal,
                },
                thickness: *thickness,
            },
            ColliderSection::Sphere {
                center,
                radius,
                thickness,
            } => Collider {
                shape: Shape::Sphere {
                    center: *center,
                    radius: *radius,
                },
                thickness: *thickness,
            },
        });
    }
    statics
}

impl ShotSetup {
    /// Colliders (and the body alone) posed at shot time `t`; `previous`:
    /// the body's vertices at the start of the step, for friction against
    /// its motion.
    pub fn pose(
        &self,
        scene: &Scene,
        t: f64,
        previous: Option<&[Vec3]>,
    ) -> Result<Posed, SimulateError> {
        let mut set = ColliderSet {
            colliders: self.statics.clone(),
            friction: self.friction,
        };
        let mut body_set = None;
        let mut verts = None;
        if let Some(b) = &self.body {
            let pts = b.positions(t);
            if b.collide {
                let bad = |e: BvhError| {
                    invalid(&scene.character_path().unwrap_or_default(), e.to_string())
                };
                let mut m = MeshCollider::new(&b.topology, &pts).map_err(bad)?;
                if let Some(prev) = previous {
                    m = m.with_previous(prev).map_err(bad)?;
                }
                let c = Collider {
                    shape: Shape::Mesh(Box::new(m)),
                    thickness: b.thickness,
                };
                set.colliders.push(c.clone());
                body_set = Some(ColliderSet {
                    colliders: vec![c],
                    ..ColliderSet::default()
                });
            }
            verts = Some(pts);
        }
        Ok(Posed {
            set,
            verts,
            body_set,
            yarn_points: self.yarn_points.clone(),
        })
    }

    /// Positions (m) of the pinned nodes at shot time `t`, in the order of
    /// [`ShotSetup::pinned`]; `verts`: the body's vertices then.
    pub fn pin_positions(
        &self,
        asset_path: &Path,
        t: f64,
        verts: Option<&[Vec3]>,
        out: &mut Vec<Vec3>,
    ) -> Result<(), SimulateError> {
        for h in &self.handles {
            h.positions(t, out);
        }
        if !self.body_pins.nodes.is_empty() {
            let (Some(b), Some(verts)) = (&self.body, verts) else {
                unreachable!("body pins come from a body")
            };
            out.extend(
                self.body_pins
                    .positions(&b.topology, verts)
                    .ok_or_else(|| invalid(asset_path, "body pin lost its triangle"))?,
            );
        }
        Ok(())
    }

    /// Projects the free nodes out of the colliders at the start of the
    /// loop (shot time `t0`).
    pub fn project_start(&mut self, scene: &Scene) -> Result<(), SimulateError> {
        let posed = self.pose(scene, self.schedule.t0(), None)?;
        for (i, p) in self.x.iter_mut().enumerate() {
            if !self.is_pinned[i] {
                if let Some(q) = posed.set.project(i, *p) {
                    *p = q;
                }
            }
        }
        Ok(())
    }
}

/// Rotation (degrees about x, then y, then z).
fn euler_deg(r: Vec3) -> Rotation3<f64> {
    let [a, b, c] = r.map(f64::to_radians);
    Rotation3::from_axis_angle(&Vector3::z_axis(), c)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), b)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), a)
}

fn bbox(x: &[Vec3]) -> (Vec3, Vec3) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Height (m) of the highest point of the mesh on the vertical line
/// through `(x, z)`, if the line meets it.
fn surface_height(topology: &MeshTopology, pos: &[Vec3], x: f64, z: f64) -> Option<f64> {
    let mut best: Option<f64> = None;
    for t in topology.triangles() {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        // Barycentric coordinates of (x, z) in the triangle's x-z projection.
        let det = (b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2]);
        if !(det.abs() > 0.0) {
            continue;
        }
        let u = ((x - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (z - a[2])) / det;
        let v = ((b[0] - a[0]) * (z - a[2]) - (x - a[0]) * (b[2] - a[2])) / det;
        if u < 0.0 || v < 0.0 || u + v > 1.0 {
            continue;
        }
        let y = a[1] + u * (b[1] - a[1]) + v * (c[1] - a[1]);
        best = Some(best.map_or(y, |m: f64| m.max(y)));
    }
    best
}
