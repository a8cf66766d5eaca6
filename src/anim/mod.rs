//! Skinned characters and their animations: glTF 2.0 skins and animations
//! evaluated at any time into world-space body meshes.
//!
//! Pure: no files, no printing. `io::gltf_skin` turns glTF bytes into a
//! [`Character`]; this module poses it.
//!
//! What the glTF 2.0 specification asks, and where it is done here:
//! * node transforms (spec 3.5.2): local = T * R * S (or `matrix`), world =
//!   parent world * local ([`Character::node_world_matrices`]);
//! * skins (spec 3.7.3): joint matrix j = world(joint j) * inverseBind j; a
//!   skinned vertex is sum_j w_j * jointMatrix_j * v, and the transform of the
//!   node the skinned mesh is attached to is ignored (3.7.3.3)
//!   ([`Character::skinned_positions`]);
//! * animations (spec 3.11): channels override a node's translation,
//!   rotation or scale; times before the first key clamp to the first key,
//!   after the last key to the last one;
//! * interpolation (spec Appendix C): STEP, LINEAR (slerp for rotations,
//!   shortest path), CUBICSPLINE (Hermite, tangents scaled by the key
//!   interval); rotations are normalised after interpolation.
//!
//! Morph target weights are not modelled (the reader skips `weights` channels
//! with a note): knitvox only needs the body surface for collisions.

pub mod cache;
pub mod pins;
pub mod summary;

use std::fmt;

use nalgebra::{Matrix4, Quaternion, UnitQuaternion, Vector3, Vector4};

use crate::geom::Vec3;

/// A 4x4 column-major transform (f64).
pub type Mat4 = Matrix4<f64>;

/// A triangle mesh in world space (metres).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriangleMesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// A node's rest (non-animated) local transform.
#[derive(Debug, Clone, PartialEq)]
pub enum LocalTransform {
    /// Translation, rotation quaternion `[x, y, z, w]` (glTF order), scale.
    Trs {
        translation: Vec3,
        rotation: [f64; 4],
        scale: Vec3,
    },
    /// A full matrix; the spec forbids animating such a node.
    Matrix(Mat4),
}

impl Default for LocalTransform {
    fn default() -> Self {
        LocalTransform::Trs {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [1.0; 3],
        }
    }
}

/// One node of the scene graph (joints are nodes).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Node {
    pub name: Option<String>,
    pub parent: Option<usize>,
    pub rest: LocalTransform,
}

/// A skin: the joints (node indices) and their inverse bind matrices.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Skin {
    pub joints: Vec<usize>,
    /// One per joint (identity when the file gives none).
    pub inverse_bind: Vec<Mat4>,
}

/// A triangle mesh attached to a node, in bind pose, optionally skinned.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CharacterMesh {
    /// The node the mesh hangs from (its transform is ignored when skinned).
    pub node: usize,
    /// The skin (index into [`Character::skins`]), if skinned.
    pub skin: Option<usize>,
    /// Bind-pose positions (the mesh's own coordinates).
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Influences per vertex (4 per JOINTS_n/WEIGHTS_n set); 0 when unskinned.
    pub influences: usize,
    /// `positions.len() * influences` joint indices into the skin's joint list.
    pub joints: Vec<u32>,
    /// `positions.len() * influences` weights, summing to 1 per vertex.
    pub weights: Vec<f64>,
}

/// What an animation channel drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TargetPath {
    Translation,
    Rotation,
    Scale,
}

impl TargetPath {
    /// Components per value (3, or 4 for a quaternion).
    pub fn components(self) -> usize {
        match self {
            TargetPath::Rotation => 4,
            _ => 3,
        }
    }
}

/// Keyframe interpolation (spec Appendix C).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    Linear,
    Step,
    CubicSpline,
}

/// Keyframes: strictly increasing times and flat output values
/// (CUBICSPLINE: in-tangent, value, out-tangent per key).
#[derive(Debug, Clone, PartialEq)]
pub struct Sampler {
    pub input: Vec<f64>,
    pub output: Vec<f64>,
    pub interpolation: Interpolation,
}

/// One animated property of one node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channel {
    pub node: usize,
    pub path: TargetPath,
    /// Index into [`Animation::samplers`].
    pub sampler: usize,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct Animation {
    pub name: Option<String>,
    pub channels: Vec<Channel>,
    pub samplers: Vec<Sampler>,
}

/// A skinned, animated character: meshes, the node hierarchy (skeleton),
/// skins and animations. Build it by hand or with `io::gltf_skin`, then
/// check it with [`Character::validate`]; evaluation never panics, even on an
/// unvalidated character (bad references are skipped).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Character {
    pub meshes: Vec<CharacterMesh>,
    /// Every node of the file, with its parent.
    pub skeleton: Vec<Node>,
    pub skins: Vec<Skin>,
    pub animations: Vec<Animation>,
    /// Facts of the read (skipped primitives, renormalised weights, ...).
    pub notes: Vec<String>,
}

/// A problem with a character, at a glTF-like JSON path (`/nodes/3/rotation`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AnimError {
    pub path: String,
    pub message: String,
}

impl fmt::Display for AnimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path, self.message)
    }
}

impl std::error::Error for AnimError {}

fn err(path: impl Into<String>, message: impl Into<String>) -> AnimError {
    AnimError {
        path: path.into(),
        message: message.into(),
    }
}

fn check_finite(path: &str, vals: &[f64]) -> Result<(), AnimError> {
    match vals.iter().position(|x| !x.is_finite()) {
        Some(k) => Err(err(
            format!("{path}/{k}"),
            format!("value is not finite ({})", vals[k]),
        )),
        None => Ok(()),
    }
}

impl Character {
    /// Animation names (`animation_<i>` for unnamed ones).
    pub fn animation_names(&self) -> Vec<String> {
        self.animations
            .iter()
            .enumerate()
            .map(|(i, a)| a.name.clone().unwrap_or_else(|| format!("animation_{i}")))
            .collect()
    }

    /// The index of the animation called `name`.
    pub fn animation_index(&self, name: &str) -> Option<usize> {
        self.animation_names().iter().position(|n| n == name)
    }

    /// Length of animation `anim` in seconds: its last key time (the timeline
    /// starts at 0). 0 for an unknown index or an animation without keys.
    pub fn duration(&self, anim: usize) -> f64 {
        self.animations.get(anim).map_or(0.0, |a| {
            a.samplers
                .iter()
                .filter_map(|s| s.input.last().copied())
                .fold(0.0, f64::max)
        })
    }

    /// Checks every reference, count and number; errors name the glTF path.
    pub fn validate(&self) -> Result<(), AnimError> {
        let nn = self.skeleton.len();
        // Per node: 0 not walked yet, 1 on the current walk up, 2 known to
        // reach a root. Each node is walked once, so a deep chain is linear.
        let mut state = vec![0u8; nn];
        let mut walk = Vec::new();
        for (i, node) in self.skeleton.iter().enumerate() {
            let path = format!("/nodes/{i}");
            if let Some(p) = node.parent {
                if p >= nn {
                    return Err(err(path, format!("parent {p} does not exist ({nn} nodes)")));
                }
            }
            match &node.rest {
                LocalTransform::Matrix(m) => check_finite(&format!("{path}/matrix"), m.as_slice())?,
                LocalTransform::Trs {
                    translation,
                    rotation,
                    scale,
                } => {
                    check_finite(&format!("{path}/translation"), translation)?;
                    check_finite(&format!("{path}/rotation"), rotation)?;
                    check_finite(&format!("{path}/scale"), scale)?;
                    if rotation.iter().map(|x| x * x).sum::<f64>() == 0.0 {
                        return Err(err(
                            format!("{path}/rotation"),
                            "quaternion has zero length",
                        ));
                    }
                }
            }
            // Walking up into a node of the same walk means a cycle; a
            // parent that does not exist ends the walk (reported at its node).
            walk.clear();
            let mut cur = Some(i);
            while let Some(c) = cur.filter(|&c| c < nn) {
                match state[c] {
                    2 => break,
                    1 => {
                        return Err(err(
                            path,
                            "the node is its own ancestor (cycle in the hierarchy)",
                        ))
                    }
                    _ => {
                        state[c] = 1;
                        walk.push(c);
                        cur = self.skeleton[c].parent;
                    }
                }
            }
            for &c in &walk {
                state[c] = 2;
            }
        }
        for (s, skin) in self.skins.iter().enumerate() {
            let path = format!("/skins/{s}");
            if let Some(k) = skin.joints.iter().position(|&j| j >= nn) {
                return Err(err(
                    format!("{path}/joints/{k}"),
                    format!("joint node {} does not exist ({nn} nodes)", skin.joints[k]),
                ));
            }
            if skin.inverse_bind.len() != skin.joints.len() {
                return Err(err(
                    format!("{path}/inverseBindMatrices"),
                    format!(
                        "{} inverse bind matrices for {} joints",
                        skin.inverse_bind.len(),
                        skin.joints.len()
                    ),
                ));
            }
            for (k, m) in skin.inverse_bind.iter().enumerate() {
                check_finite(&format!("{path}/inverseBindMatrices/{k}"), m.as_slice())?;
            }
        }
        for (m, mesh) in self.meshes.iter().enumerate() {
            self.validate_mesh(m, mesh)?;
        }
        for (a, anim) in self.animations.iter().enumerate() {
            self.validate_animation(a, anim)?;
        }
        Ok(())
    }

    fn validate_mesh(&self, m: usize, mesh: &CharacterMesh) -> Result<(), AnimError> {
        let path = format!("/meshes/{m}");
        if mesh.node >= self.skeleton.len() {
            return Err(err(
                path,
                format!("attached to node {} which does not exist", mesh.node),
            ));
        }
        let nv = mesh.positions.len();
        for (v, p) in mesh.positions.iter().enumerate() {
            check_finite(&format!("{path}/positions/{v}"), p)?;
        }
        if let Some(t) = mesh
            .triangles
            .iter()
            .position(|t| t.iter().any(|&i| i as usize >= nv))
        {
            return Err(err(
                format!("{path}/triangles/{t}"),
                format!(
                    "vertex index out of range in {:?} ({nv} vertices)",
                    mesh.triangles[t]
                ),
            ));
        }
        let Some(s) = mesh.skin else { return Ok(()) };
        let skin = self
            .skins
            .get(s)
            .ok_or_else(|| err(format!("{path}/skin"), format!("skin {s} does not exist")))?;
        let need = nv.checked_mul(mesh.influences);
        if mesh.influences == 0
            || need != Some(mesh.joints.len())
            || need != Some(mesh.weights.len())
        {
            return Err(err(
                path,
                format!(
                    "{nv} vertices with {} influences need {} joints and weights, found {} and {}",
                    mesh.influences,
                    need.map_or("too many".into(), |n| n.to_string()),
                    mesh.joints.len(),
                    mesh.weights.len()
                ),
            ));
        }
        let nj = skin.joints.len();
        if let Some(k) = mesh.joints.iter().position(|&j| j as usize >= nj) {
            return Err(err(
                format!("{path}/joints"),
                format!(
                    "vertex {} influence {}: joint index {} is out of range (skin {s} has {nj} joints)",
                    k / mesh.influences,
                    k % mesh.influences,
                    mesh.joints[k]
                ),
            ));
        }
        if let Some(k) = mesh
            .weights
            .iter()
            .position(|w| !(w.is_finite() && *w >= 0.0))
        {
            return Err(err(
                format!("{path}/weights"),
                format!(
                    "vertex {}: weight {} is not a finite non-negative number",
                    k / mesh.influences,
                    mesh.weights[k]
                ),
            ));
        }
        Ok(())
    }

    fn validate_animation(&self, a: usize, anim: &Animation) -> Result<(), AnimError> {
        let path = format!("/animations/{a}");
        for (s, smp) in anim.samplers.iter().enumerate() {
            let sp = format!("{path}/samplers/{s}/input");
            if smp.input.is_empty() {
                return Err(err(sp, "sampler has no keyframes"));
            }
            check_finite(&sp, &smp.input)?;
            if let Some(k) = smp.input.windows(2).position(|w| w[1] <= w[0]) {
                return Err(err(
                    sp,
                    format!(
                        "key times must be strictly increasing: key {} at {} s follows {} s",
                        k + 1,
                        smp.input[k + 1],
                        smp.input[k]
                    ),
                ));
            }
            check_finite(&format!("{path}/samplers/{s}/output"), &smp.output)?;
        }
        for (c, ch) in anim.channels.iter().enumerate() {
            let cp = format!("{path}/channels/{c}");
            let node = self.skeleton.get(ch.node).ok_or_else(|| {
                err(
                    format!("{cp}/target/node"),
                    format!("node {} does not exist", ch.node),
                )
            })?;
            if matches!(node.rest, LocalTransform::Matrix(_)) {
                return Err(err(
                    format!("{cp}/target/node"),
                    format!(
                        "node {} has a matrix; the spec forbids animating it (3.11)",
                        ch.node
                    ),
                ));
            }
            let smp = anim.samplers.get(ch.sampler).ok_or_else(|| {
                err(
                    format!("{cp}/sampler"),
                    format!("sampler {} does not exist", ch.sampler),
                )
            })?;
            let per_key = ch.path.components()
                * if smp.interpolation == Interpolation::CubicSpline {
                    3
                } else {
                    1
                };
            let want = smp.input.len().checked_mul(per_key);
            if want != Some(smp.output.len()) {
                return Err(err(
                    format!("{path}/samplers/{}/output", ch.sampler),
                    format!(
                        "{} values for {} keys: {:?} interpolation of {:?} needs {} per key",
                        smp.output.len(),
                        smp.input.len(),
                        smp.interpolation,
                        ch.path,
                        per_key
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Local transforms of every node at time `t` of animation `anim`
    /// (`None`, or an unknown index: the rest pose).
    pub fn local_matrices(&self, anim: Option<usize>, t: f64) -> Vec<Mat4> {
        let mut trs: Vec<Option<(Vec3, [f64; 4], Vec3)>> = self
            .skeleton
            .iter()
            .map(|n| match &n.rest {
                LocalTransform::Trs {
                    translation,
                    rotation,
                    scale,
                } => Some((*translation, *rotation, *scale)),
                LocalTransform::Matrix(_) => None,
            })
            .collect();
        if let Some(a) = anim.and_then(|a| self.animations.get(a)) {
            for ch in &a.channels {
                let (Some(Some(node)), Some(smp)) =
                    (trs.get_mut(ch.node), a.samplers.get(ch.sampler))
                else {
                    continue;
                };
                let mut v = [0.0; 4];
                let n = ch.path.components();
                if !sample(smp, n, ch.path == TargetPath::Rotation, t, &mut v[..n]) {
                    continue;
                }
                match ch.path {
                    TargetPath::Translation => node.0 = [v[0], v[1], v[2]],
                    TargetPath::Rotation => node.1 = v,
                    TargetPath::Scale => node.2 = [v[0], v[1], v[2]],
                }
            }
        }
        self.skeleton
            .iter()
            .zip(trs)
            .map(|(n, trs)| match (trs, &n.rest) {
                (Some((t, r, s)), _) => trs_matrix(t, r, s),
                (None, LocalTransform::Matrix(m)) => *m,
                (None, _) => Mat4::identity(),
            })
            .collect()
    }

    /// World matrices of every node at time `t` of animation `anim` (`None`:
    /// rest pose): local transforms composed down the hierarchy (spec 3.5.2).
    pub fn node_world_matrices(&self, anim: Option<usize>, t: f64) -> Vec<Mat4> {
        let local = self.local_matrices(anim, t);
        let n = local.len();
        let mut world: Vec<Option<Mat4>> = vec![None; n];
        let mut chain = Vec::new();
        for i in 0..n {
            // Collect the not-yet-computed ancestors, then compose top-down.
            chain.clear();
            let mut cur = Some(i);
            while let Some(c) = cur {
                if c >= n || world[c].is_some() || chain.len() > n {
                    break; // bad parent or cycle (validate reports it): treat as a root
                }
                chain.push(c);
                cur = self.skeleton[c].parent;
            }
            let mut acc = cur.and_then(|c| world.get(c).copied().flatten());
            for &c in chain.iter().rev() {
                let w = match acc {
                    Some(p) => p * local[c],
                    None => local[c],
                };
                world[c] = Some(w);
                acc = Some(w);
            }
        }
        world
            .into_iter()
            .map(|w| w.unwrap_or_else(Mat4::identity))
            .collect()
    }

    /// Every mesh's vertices in world space at time `t`, concatenated in mesh
    /// order (the vertices of [`Character::body_mesh`]). Skinned meshes use
    /// linear blend skinning, v' = sum_j w_j * (world(joint_j) * invBind_j) * v,
    /// on their bind-pose positions, ignoring their node's transform (spec
    /// 3.7.3.3); unskinned meshes are moved by their node's world matrix.
    pub fn skinned_positions(&self, anim: Option<usize>, t: f64) -> Vec<Vec3> {
        let world = self.node_world_matrices(anim, t);
        let mut out = Vec::with_capacity(self.meshes.iter().map(|m| m.positions.len()).sum());
        for mesh in &self.meshes {
            let skin = mesh.skin.and_then(|s| self.skins.get(s));
            let Some(skin) = skin.filter(|_| mesh.influences > 0) else {
                let m = world.get(mesh.node).copied().unwrap_or_else(Mat4::identity);
                out.extend(mesh.positions.iter().map(|p| apply(&m, p)));
                continue;
            };
            let joint_mats: Vec<Mat4> = skin
                .joints
                .iter()
                .zip(&skin.inverse_bind)
                .map(|(&j, ib)| world.get(j).copied().unwrap_or_else(Mat4::identity) * ib)
                .collect();
            let k = mesh.influences;
            for (v, p) in mesh.positions.iter().enumerate() {
                let mut m = Mat4::zeros();
                for i in v * k..(v + 1) * k {
                    let (Some(&j), Some(&w)) = (mesh.joints.get(i), mesh.weights.get(i)) else {
                        continue;
                    };
                    if w != 0.0 {
                        if let Some(jm) = joint_mats.get(j as usize) {
                            m += jm * w;
                        }
                    }
                }
                out.push(apply(&m, p));
            }
        }
        out
    }

    /// All meshes, skinned and not, as one world-space triangle mesh at time `t`.
    pub fn body_mesh(&self, anim: Option<usize>, t: f64) -> TriangleMesh {
        let positions = self.skinned_positions(anim, t);
        let mut triangles = Vec::new();
        let mut base = 0u32;
        for mesh in &self.meshes {
            triangles.extend(
                mesh.triangles
                    .iter()
                    .map(|t| t.map(|i| i.saturating_add(base))),
            );
            base = base.saturating_add(u32::try_from(mesh.positions.len()).unwrap_or(u32::MAX));
        }
        TriangleMesh {
            positions,
            triangles,
        }
    }
}

fn apply(m: &Mat4, p: &Vec3) -> Vec3 {
    let q = m * Vector4::new(p[0], p[1], p[2], 1.0);
    [q.x, q.y, q.z]
}

/// T * R * S (spec 3.5.2); the quaternion is normalised first.
pub fn trs_matrix(t: Vec3, r: [f64; 4], s: Vec3) -> Mat4 {
    let q = UnitQuaternion::from_quaternion(Quaternion::new(r[3], r[0], r[1], r[2]));
    let mut m = q.to_homogeneous() * Mat4::new_nonuniform_scaling(&Vector3::new(s[0], s[1], s[2]));
    m[(0, 3)] = t[0];
    m[(1, 3)] = t[1];
    m[(2, 3)] = t[2];
    m
}

/// Normalises a quaternion `[x, y, z, w]` in place; a zero one becomes identity.
fn normalize_quat(q: &mut [f64]) {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if n > 0.0 && n.is_finite() {
        q.iter_mut().for_each(|x| *x /= n);
    } else {
        q.copy_from_slice(&[0.0, 0.0, 0.0, 1.0]);
    }
}

/// Spherical linear interpolation along the shorter arc (spec Appendix C).
fn slerp(a: &[f64], b: &[f64], s: f64, out: &mut [f64]) {
    // Writers round their quaternions (0.707, 0.707); interpolate the unit ones.
    let (mut a4, mut b4) = ([0.0; 4], [0.0; 4]);
    a4.copy_from_slice(&a[..4]);
    b4.copy_from_slice(&b[..4]);
    normalize_quat(&mut a4);
    normalize_quat(&mut b4);
    let (a, b) = (&a4, &b4);
    let mut dot: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let sign = if dot < 0.0 { -1.0 } else { 1.0 };
    dot *= sign;
    let (wa, wb) = if dot > 0.9995 {
        (1.0 - s, s) // nearly parallel: lerp, normalised below
    } else {
        let theta = dot.min(1.0).acos();
        let st = theta.sin();
        (((1.0 - s) * theta).sin() / st, (s * theta).sin() / st)
    };
    for k in 0..4 {
        out[k] = wa * a[k] + wb * sign * b[k];
    }
    normalize_quat(out);
}

/// Evaluates `smp` (values of `n` components) at time `t` into `out`; false when
/// the sampler's arrays are inconsistent (validate reports it).
fn sample(smp: &Sampler, n: usize, is_rotation: bool, t: f64, out: &mut [f64]) -> bool {
    let keys = smp.input.len();
    let cubic = smp.interpolation == Interpolation::CubicSpline;
    let stride = if cubic { 3 * n } else { n };
    if keys == 0 || keys.checked_mul(stride) != Some(smp.output.len()) || out.len() != n {
        return false;
    }
    // The value of key k (CUBICSPLINE stores in-tangent, value, out-tangent).
    let value = |k: usize| {
        let at = k * stride + if cubic { n } else { 0 };
        &smp.output[at..at + n]
    };
    let last = keys - 1;
    // Clamp outside the keyed range (spec 3.11: before the first key, the first value).
    let t = if t.is_nan() { smp.input[0] } else { t };
    if t <= smp.input[0] || keys == 1 {
        out.copy_from_slice(value(0));
    } else if t >= smp.input[last] {
        out.copy_from_slice(value(last));
    } else {
        // Key k with input[k] <= t < input[k + 1].
        let k = smp
            .input
            .partition_point(|&x| x <= t)
            .saturating_sub(1)
            .min(last - 1);
        let (t0, t1) = (smp.input[k], smp.input[k + 1]);
        let td = t1 - t0;
        let s = ((t - t0) / td).clamp(0.0, 1.0);
        match smp.interpolation {
            Interpolation::Step => out.copy_from_slice(value(k)),
            Interpolation::Linear if is_rotation => slerp(value(k), value(k + 1), s, out),
            Interpolation::Linear => {
                for (c, o) in out.iter_mut().enumerate() {
                    *o = (1.0 - s) * value(k)[c] + s * value(k + 1)[c];
                }
            }
            Interpolation::CubicSpline => {
                // Hermite spline, spec Appendix C: p(s) = (2s^3 - 3s^2 + 1) v_k
                // + td (s^3 - 2s^2 + s) b_k + (-2s^3 + 3s^2) v_k+1 + td (s^3 - s^2) a_k+1.
                let (s2, s3) = (s * s, s * s * s);
                let out_tangent = &smp.output[k * stride + 2 * n..k * stride + 3 * n];
                let in_tangent = &smp.output[(k + 1) * stride..(k + 1) * stride + n];
                for (c, o) in out.iter_mut().enumerate() {
                    *o = (2.0 * s3 - 3.0 * s2 + 1.0) * value(k)[c]
                        + td * (s3 - 2.0 * s2 + s) * out_tangent[c]
                        + (-2.0 * s3 + 3.0 * s2) * value(k + 1)[c]
                        + td * (s3 - s2) * in_tangent[c];
                }
            }
        }
    }
    if is_rotation {
        normalize_quat(out);
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_channel(interp: Interpolation, input: Vec<f64>, output: Vec<f64>, n: usize) -> [f64; 4] {
        let smp = Sampler {
            input,
            output,
            interpolation: interp,
        };
        let mut v = [0.0; 4];
        assert!(sample(&smp, n, n == 4, 0.25, &mut v[..n]));
        v
    }

    #[test]
    fn linear_step_cubic_scalars() {
        let v = one_channel(
            Interpolation::Linear,
            vec![0.0, 1.0],
            vec![0.0, 0.0, 0.0, 4.0, 8.0, 12.0],
            3,
        );
        assert_eq!(&v[..3], &[1.0, 2.0, 3.0]);
        let v = one_channel(
            Interpolation::Step,
            vec![0.0, 1.0],
            vec![0.0, 0.0, 0.0, 4.0, 8.0, 12.0],
            3,
        );
        assert_eq!(&v[..3], &[0.0, 0.0, 0.0]);
        // Cubic with tangents 1 (slope 1 in value per second) between 0 and 1: p = s.
        let out = vec![
            1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
            1.0,
        ];
        let v = one_channel(Interpolation::CubicSpline, vec![0.0, 1.0], out, 3);
        for c in 0..3 {
            assert!((v[c] - 0.25).abs() < 1e-15, "{v:?}");
        }
    }

    #[test]
    fn clamping_outside_keys() {
        let smp = Sampler {
            input: vec![1.0, 2.0],
            output: vec![5.0, 5.0, 5.0, 7.0, 7.0, 7.0],
            interpolation: Interpolation::Linear,
        };
        let mut v = [0.0; 3];
        for (t, want) in [
            (-3.0, 5.0),
            (0.0, 5.0),
            (1.5, 6.0),
            (9.0, 7.0),
            (f64::NAN, 5.0),
        ] {
            assert!(sample(&smp, 3, false, t, &mut v));
            assert_eq!(v, [want; 3], "t = {t}");
        }
    }

    #[test]
    fn slerp_takes_the_short_way() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        // +90 deg about z and the same rotation written with negated sign.
        let a = [0.0, 0.0, 0.0, 1.0];
        let b = [0.0, 0.0, -h, -h];
        let mut o = [0.0; 4];
        slerp(&a, &b, 0.5, &mut o);
        let q = UnitQuaternion::from_quaternion(Quaternion::new(o[3], o[0], o[1], o[2]));
        assert!(
            (q.angle() - std::f64::consts::FRAC_PI_4).abs() < 1e-12,
            "{o:?}"
        );
    }

    #[test]
    fn trs_order_is_t_r_s() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let m = trs_matrix([10.0, 0.0, 0.0], [0.0, 0.0, h, h], [2.0, 2.0, 2.0]);
        let p = apply(&m, &[1.0, 0.0, 0.0]);
        assert!((p[0] - 10.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12 && p[2].abs() < 1e-12);
    }

    #[test]
    fn cycles_and_bad_refs_do_not_panic() {
        let mut c = Character {
            skeleton: vec![
                Node {
                    parent: Some(1),
                    ..Default::default()
                },
                Node {
                    parent: Some(0),
                    ..Default::default()
                },
                Node {
                    parent: Some(99),
                    ..Default::default()
                },
            ],
            ..Default::default()
        };
        assert!(c.validate().is_err());
        assert_eq!(c.node_world_matrices(Some(3), 0.0).len(), 3);
        c.skeleton[2].parent = None;
        let e = c.validate().unwrap_err();
        assert!(e.message.contains("cycle"), "{e}");
    }
}
