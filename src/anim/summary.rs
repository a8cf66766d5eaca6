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
