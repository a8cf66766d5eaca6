//! What `knitvox inspect CHAR.glb` reports about a character: joints, skins,
//! animations, the bind-pose bounding box and the `--character-scale` that
//! makes it a person's height. Pure: takes a [`Character`], returns numbers.

use serde::Serialize;

use super::Character;
use crate::geom::{Bounds, Vec3};

/// Height (m) the suggested `--character-scale` gives the body: an adult.
pub const TARGET_HEIGHT_M: f64 = 1.7;

/// Bind-pose heights (m, scale 1) taken as already in metres: a child to a
/// tall adult. Outside them a scale to [`TARGET_HEIGHT_M`] is suggested.
pub const PLAUSIBLE_HEIGHT_M: (f64, f64) = (0.5, 2.5);

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SkinSummary {
    /// The skin's joints (node names; `node_<i>` for unnamed nodes).
    pub joints: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AnimationSummary {
    pub name: String,
    /// Last key time (s); the timeline starts at 0.
    pub duration_s: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CharacterSummary {
    pub nodes: usize,
    pub meshes: usize,
    pub vertices: usize,
    pub triangles: usize,
    /// Every joint of every skin, once, in skin order.
    pub joints: Vec<String>,
    pub skins: Vec<SkinSummary>,
    pub animations: Vec<AnimationSummary>,
    /// Bind-pose bounding box in file units (glTF: metres, +Y up); None
    /// without vertices.
    pub bind_bbox_min: Option<Vec3>,
    pub bind_bbox_max: Option<Vec3>,
    /// Bind-pose extent along +Y (file units).
    pub height: f64,
    /// `--character-scale` for a body of plausible height: 1 when the
    /// height is already within [`PLAUSIBLE_HEIGHT_M`], else
    /// [`TARGET_HEIGHT_M`] / height (2 significant digits). None without a height.
    pub suggested_character_scale: Option<f64>,
    /// Where every joint is in the pose [`summarize`] was asked for (the
    /// bind pose by default; `inspect --animation --time`).
    pub pose: PoseChoice,
    pub joint_places: Vec<JointPlace>,
}

/// The pose joint places are given in.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PoseChoice {
    /// The animation (None: the bind pose).
    pub animation: Option<String>,
    /// Time into it (s).
    pub time_s: f64,
}

/// A joint's place in a pose: for dressing a garment onto a limb.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointPlace {
    pub name: String,
    /// The nearest ancestor that is a joint too (None: a root joint).
    pub parent: Option<String>,
    /// World position (file units, the file's axes: glTF +Y up).
    pub position: Vec3,
    /// Distance to the parent joint (file units): the bone's length.
    pub bone_length: Option<f64>,
}

fn node_name(ch: &Character, i: usize) -> String {
    ch.skeleton
        .get(i)
        .and_then(|n| n.name.clone())
        .unwrap_or_else(|| format!("node_{i}"))
}

/// `x` rounded to 2 significant digits (a scale to type, not to trust to 1e-16).
fn two_digits(x: f64) -> f64 {
    let p = 10f64.powf(x.abs().log10().floor() - 1.0);
    (x / p).round() * p
}

/// The scale suggested for a body `height` file units tall (see
/// [`CharacterSummary::suggested_character_scale`]).
pub fn suggested_scale(height: f64) -> Option<f64> {
    if !(height.is_finite() && height > 0.0) {
        return None;
    }
    let (lo, hi) = PLAUSIBLE_HEIGHT_M;
    if (lo..=hi).contains(&height) {
        return Some(1.0);
    }
    Some(two_digits(TARGET_HEIGHT_M / height))
}

/// The summary of `ch` (bind pose: no animation applied).
/// Every skin joint's world position at time `t` of animation `anim`
/// (`None`: the bind pose), with its parent joint and bone length, in skin
/// order.
pub fn joint_places(ch: &Character, anim: Option<usize>, t: f64) -> Vec<JointPlace> {
    let world = ch.node_world_matrices(anim, t);
    let mut joints: Vec<usize> = Vec::new();
    for &j in ch.skins.iter().flat_map(|s| &s.joints) {
        if !joints.contains(&j) {
            joints.push(j);
        }
    }
    let at = |i: usize| -> Option<Vec3> { world.get(i).map(|m| [m[(0, 3)], m[(1, 3)], m[(2, 3)]]) };
    joints
        .iter()
        .filter_map(|&j| {
            let position = at(j)?;
            // The nearest ancestor among the joints (bounded: a cycle ends it).
            let mut parent = ch.skeleton.get(j).and_then(|n| n.parent);
            let mut hops = 0;
            while let Some(p) = parent {
                if joints.contains(&p) || hops > ch.skeleton.len() {
                    break;
                }
                parent = ch.skeleton.get(p).and_then(|n| n.parent);
                hops += 1;
            }
            let parent = parent.filter(|p| joints.contains(p));
            Some(JointPlace {
                name: node_name(ch, j),
                parent: parent.map(|p| node_name(ch, p)),
                position,
                bone_length: parent.and_then(at).map(|q| crate::geom::dist(position, q)),
            })
        })
        .collect()
}

/// [`summarize`] with the joints placed at time `t` of animation `anim`.
pub fn summarize_at(ch: &Character, anim: Option<usize>, t: f64) -> CharacterSummary {
    let mut s = summarize(ch);
    s.pose = PoseChoice {
        animation: anim.and_then(|a| ch.animation_names().get(a).cloned()),
        time_s: t,
    };
    s.joint_places = joint_places(ch, anim, t);
    s
}

pub fn summarize(ch: &Character) -> CharacterSummary {
    let skins: Vec<SkinSummary> = ch
        .skins
        .iter()
        .map(|s| SkinSummary {
            joints: s.joints.iter().map(|&j| node_name(ch, j)).collect(),
        })
        .collect();
    let mut joints: Vec<String> = Vec::new();
    for j in skins.iter().flat_map(|s| &s.joints) {
        if !joints.contains(j) {
            joints.push(j.clone());
        }
    }
    let animations = ch
        .animation_names()
        .into_iter()
        .enumerate()
        .map(|(i, name)| AnimationSummary {
            name,
            duration_s: ch.duration(i),
        })
        .collect();
    let body = ch.body_mesh(None, 0.0);
    let bounds = crate::geom::bounds_of(&body.positions);
    let height = bounds.as_ref().map_or(0.0, |b: &Bounds| b.size()[1]);
    CharacterSummary {
        nodes: ch.skeleton.len(),
        meshes: ch.meshes.len(),
        vertices: body.positions.len(),
        triangles: body.triangles.len(),
        joints,
        skins,
        animations,
        bind_bbox_min: bounds.as_ref().map(|b| b.min),
        bind_bbox_max: bounds.as_ref().map(|b| b.max),
        height,
        suggested_character_scale: suggested_scale(height),
        pose: PoseChoice {
            animation: None,
            time_s: 0.0,
        },
        joint_places: joint_places(ch, None, 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scales_to_a_person() {
        assert_eq!(suggested_scale(1.8), Some(1.0));
        // Fox.glb's bind pose is about 80 units high (cm-like units).
        let s = suggested_scale(80.0).unwrap();
        assert!((s - 0.021).abs() < 1e-12, "{s}");
        assert_eq!(suggested_scale(170.0), Some(0.01));
        assert_eq!(suggested_scale(0.0), None);
        assert_eq!(suggested_scale(f64::NAN), None);
    }
}
