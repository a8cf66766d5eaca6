//! A baked character: one triangle mesh and its world-space vertex positions
//! at a list of times, as any DCC can export them (Alembic-style point
//! caches; schemas/character-hdf5.md). A shot takes it like a skinned glTF
//! character: the rest mesh places the garment and its pins, and the body
//! at time `t` is the linear interpolation of the two frames around `t`.
//!
//! Pure: no files, no printing, no environment.

use super::{AnimError, Character, TriangleMesh};
use crate::geom::Vec3;

/// Triangles plus per-frame positions (metres, +Y up, world space).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BodyCache {
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Vertices per frame.
    pub num_vertices: usize,
    /// Time of each frame (s), strictly increasing.
    pub times: Vec<f64>,
    /// Frame-major positions: frame `f` is `points[f * V .. (f + 1) * V]`.
    pub points: Vec<Vec3>,
    /// The pose the garment is placed on and pinned to (the bind pose of
    /// the character it was baked from); `None` = the first frame.
    pub rest: Option<Vec<Vec3>>,
}

impl BodyCache {
    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.times.len()
    }

    /// Positions of frame `f` (0-based).
    pub fn frame(&self, f: usize) -> &[Vec3] {
        &self.points[f * self.num_vertices..(f + 1) * self.num_vertices]
    }

    /// Checks sizes, finiteness, time order and triangle indices; errors name
    /// the place as a path inside the cache's layout.
    pub fn validate(&self) -> Result<(), AnimError> {
        let (v, f) = (self.num_vertices, self.times.len());
        let fail = |path: &str, message: String| Err(super::err(path, message));
        if f == 0 {
            return fail("/character/times", "the cache has no frames".into());
        }
        if v == 0 || self.triangles.is_empty() {
            return fail(
                "/character/triangles",
                format!(
                    "the cache has {v} vertices and {} triangles",
                    self.triangles.len()
                ),
            );
        }
        if Some(self.points.len()) != f.checked_mul(v) {
            return fail(
                "/character/points",
                format!(
                    "{} positions for {f} frames x {v} vertices",
                    self.points.len()
                ),
            );
        }
        if let Some(i) = self.times.iter().position(|t| !t.is_finite()) {
            return fail(
                &format!("/character/times/{i}"),
                "time is not finite".into(),
            );
        }
        if let Some(i) = (1..f).find(|&i| self.times[i] <= self.times[i - 1]) {
            return fail(
                &format!("/character/times/{i}"),
                format!(
                    "times must increase: {} after {}",
                    self.times[i],
                    self.times[i - 1]
                ),
            );
        }
        if let Some(i) = self
            .points
            .iter()
            .position(|p| !p.iter().all(|x| x.is_finite()))
        {
            return fail(
                &format!("/character/points/{}/{}", i / v, i % v),
                "coordinate is not finite".into(),
            );
        }
        if let Some((t, tri)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, tri)| tri.iter().any(|&k| k as usize >= v))
        {
            return fail(
                &format!("/character/triangles/{t}"),
                format!("vertex index out of range in {tri:?} ({v} vertices)"),
            );
        }
        if let Some(rest) = &self.rest {
            if rest.len() != v {
                return fail(
                    "/character/rest_points",
                    format!("{} rest positions for {v} vertices", rest.len()),
                );
            }
            if let Some(i) = rest.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
                return fail(
                    &format!("/character/rest_points/{i}"),
                    "coordinate is not finite".into(),
                );
            }
        }
        Ok(())
    }

    /// Length of the cached motion (s): last time minus first.
    pub fn duration(&self) -> f64 {
        match (self.times.first(), self.times.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }

    /// The rest pose (see [`BodyCache::rest`]).
    pub fn rest_positions(&self) -> &[Vec3] {
        match &self.rest {
            Some(r) => r,
            None => self.frame(0),
        }
    }

    /// Positions at time `t` (s): linear between the two frames around `t`,
    /// held at the first/last frame outside the cached range (a shot may
    /// pre-roll before the cache starts or run past its end).
    pub fn positions_at(&self, t: f64) -> Vec<Vec3> {
        let n = self.times.len();
        if n == 0 {
            return Vec::new();
        }
        if !(t > self.times[0]) {
            return self.frame(0).to_vec();
        }
        if t >= self.times[n - 1] {
            return self.frame(n - 1).to_vec();
        }
        // First frame later than t: 1..n-1 by the checks above.
        let hi = self.times.partition_point(|&x| x <= t);
        let lo = hi - 1;
        let w = (t - self.times[lo]) / (self.times[hi] - self.times[lo]);
        self.frame(lo)
            .iter()
            .zip(self.frame(hi))
            .map(|(a, b)| std::array::from_fn(|k| a[k] + w * (b[k] - a[k])))
            .collect()
    }

    /// The world-space body at time `t`.
    pub fn body_mesh(&self, t: f64) -> TriangleMesh {
        TriangleMesh {
            positions: self.positions_at(t),
            triangles: self.triangles.clone(),
        }
    }

    /// The rest body (where the garment is placed and pinned).
    pub fn rest_mesh(&self) -> TriangleMesh {
        TriangleMesh {
            positions: self.rest_positions().to_vec(),
            triangles: self.triangles.clone(),
        }
    }

    /// Bakes a skinned character's animation `anim` at `times` (s), with the
    /// bind pose as rest.
    pub fn bake(character: &Character, anim: Option<usize>, times: &[f64]) -> BodyCache {
        let rest = character.body_mesh(None, 0.0);
        let mut points = Vec::with_capacity(times.len() * rest.positions.len());
        for &t in times {
            points.extend(character.skinned_positions(anim, t));
        }
        BodyCache {
            triangles: rest.triangles,
            num_vertices: rest.positions.len(),
            times: times.to_vec(),
            points,
            rest: Some(rest.positions),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_frames() -> BodyCache {
        BodyCache {
            triangles: vec![[0, 1, 2]],
            num_vertices: 3,
            times: vec![1.0, 3.0],
            points: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 2.0, 0.0],
                [1.0, 2.0, 0.0],
                [0.0, 3.0, 4.0],
            ],
            rest: None,
        }
    }

    #[test]
    fn interpolates_between_frames_and_holds_outside() {
        let c = two_frames();
        c.validate().unwrap();
        assert_eq!(c.positions_at(0.0), c.frame(0));
        assert_eq!(c.positions_at(1.0), c.frame(0));
        assert_eq!(c.positions_at(9.0), c.frame(1));
        let mid = c.positions_at(1.5);
        assert_eq!(mid[0], [0.0, 0.5, 0.0]);
        assert_eq!(mid[2], [0.0, 1.5, 1.0]);
        assert_eq!(c.duration(), 2.0);
        assert_eq!(c.rest_mesh().positions, c.frame(0));
    }

    #[test]
    fn validation_names_the_place() {
        let mut c = two_frames();
        c.times[1] = 1.0;
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("/character/times/1"));
        let mut c = two_frames();
        c.triangles.push([0, 1, 3]);
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("/character/triangles/1"));
        let mut c = two_frames();
        c.points[4][1] = f64::NAN;
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("/character/points/1/1"));
        let mut c = two_frames();
        c.points.pop();
        assert!(c.validate().is_err());
        let mut c = two_frames();
        c.rest = Some(vec![[0.0; 3]; 2]);
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("rest_points"));
    }

    #[test]
    fn bake_matches_skinning() {
        // One unskinned triangle on a node translated by an animation would
        // need a full character; the bind pose alone (no animation) must
        // reproduce the body mesh at every time.
        let ch = Character {
            meshes: vec![super::super::CharacterMesh {
                node: 0,
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                triangles: vec![[0, 1, 2]],
                ..Default::default()
            }],
            skeleton: vec![super::super::Node::default()],
            ..Default::default()
        };
        let c = BodyCache::bake(&ch, None, &[0.0, 0.5]);
        c.validate().unwrap();
        assert_eq!(c.num_frames(), 2);
        assert_eq!(c.positions_at(0.25), ch.body_mesh(None, 0.25).positions);
    }
}
