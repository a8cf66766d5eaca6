//! Pins from a character's skin: garment nodes near the bind-pose body
//! surface are attached to their closest body triangle and then follow the
//! skinned body at any time (points of a character's skinned surface
//! chosen by distance at the bind pose).
//!
//! An attachment stores a point in the affine frame of its triangle
//! `(a, b, c)`: `p = a + α (b - a) + β (c - a) + γ n̂`, with `n̂` the unit
//! face normal. At the bind pose this reproduces the node exactly; at other
//! poses it follows the triangle's translation, rotation and in-plane
//! stretch, with the normal offset `γ` (m) kept.
//!
//! Pure math: no files.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geom::bvh::{MeshCollider, MeshTopology};
use crate::geom::vec3::{cross, dot, sub};
use crate::geom::Vec3;

/// Default pin distance (m): garment nodes within this unsigned distance of
/// the bind-pose body surface are pinned. 5 mm: a few voxels of the default
/// embedding of a knit with 0.4 mm yarns (VH §4 voxels are about the yarn
/// diameter), so a garment laid on the body is held along its contact line.
pub const DEFAULT_PIN_DISTANCE: f64 = 5e-3;

/// A point fixed in the frame of one body triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceAttachment {
    /// Triangle index (into [`MeshTopology::triangles`]).
    pub triangle: u32,
    /// `(α, β, γ)`: edge coordinates (dimensionless) and normal offset (m).
    pub coords: [f64; 3],
}

/// The frame `(a, e1, e2, n̂)` of triangle `t` at `positions`.
fn frame(tri: [u32; 3], positions: &[Vec3]) -> Option<(Vec3, Vec3, Vec3, Vec3)> {
    let p = |k: usize| positions.get(tri[k] as usize).copied();
    let (a, b, c) = (p(0)?, p(1)?, p(2)?);
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let n = cross(e1, e2);
    let l = dot(n, n).sqrt();
    let n = if l > 0.0 && l.is_finite() {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    };
    Some((a, e1, e2, n))
}

impl SurfaceAttachment {
    /// Attaches `p` to triangle `triangle` of `topology` posed at `positions`.
    pub fn new(
        topology: &MeshTopology,
        positions: &[Vec3],
        triangle: usize,
        p: Vec3,
    ) -> Option<SurfaceAttachment> {
        let tri = *topology.triangles().get(triangle)?;
        let (a, e1, e2, n) = frame(tri, positions)?;
        let r = sub(p, a);
        // In-plane part by the 2x2 Gram system; a degenerate triangle keeps
        // α = β = 0 (the point rides on corner a).
        let (g11, g12, g22) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
        let det = g11 * g22 - g12 * g12;
        let (r1, r2) = (dot(e1, r), dot(e2, r));
        let (alpha, beta) = if det > 1e-14 * g11 * g22 && det.is_finite() {
            ((g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det)
        } else {
            (0.0, 0.0)
        };
        let gamma = dot(n, r);
        Some(SurfaceAttachment {
            triangle: triangle as u32,
            coords: [alpha, beta, gamma],
        })
    }

    /// The attached point (m) with the body's vertices at `positions`.
    pub fn position(&self, topology: &MeshTopology, positions: &[Vec3]) -> Option<Vec3> {
        let tri = *topology.triangles().get(self.triangle as usize)?;
        let (a, e1, e2, n) = frame(tri, positions)?;
        let [al, be, ga] = self.coords;
        Some(std::array::from_fn(|k| {
            a[k] + al * e1[k] + be * e2[k] + ga * n[k]
        }))
    }
}

/// Garment nodes pinned to a body.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BodyPins {
    /// Pinned node indices, ascending.
    pub nodes: Vec<usize>,
    /// One attachment per pinned node.
    pub attachments: Vec<SurfaceAttachment>,
    /// Unsigned distance (m) of each pinned node to the bind-pose surface.
    pub distances: Vec<f64>,
}

impl BodyPins {
    /// Pins every node of `x` (m) within `pin_distance` (m) of `body` (the
    /// bind pose, built from `topology`), attached to its closest triangle.
    pub fn select(
        topology: &MeshTopology,
        body: &MeshCollider,
        x: &[Vec3],
        pin_distance: f64,
    ) -> BodyPins {
        let mut pins = BodyPins::default();
        for (i, &p) in x.iter().enumerate() {
            let Some(hit) = body.closest(p) else {
                continue;
            };
            let d = hit.signed_distance.abs();
            if !(d <= pin_distance) {
                continue;
            }
            if let Some(a) = SurfaceAttachment::new(topology, body.positions(), hit.triangle, p) {
                pins.nodes.push(i);
                pins.attachments.push(a);
                pins.distances.push(d);
            }
        }
        pins
    }

    /// Positions (m) of the pinned nodes for the body vertices `positions`
    /// (same topology), in the order of [`BodyPins::nodes`]. None when the
    /// vertex count does not fit the attachments.
    pub fn positions(&self, topology: &MeshTopology, positions: &[Vec3]) -> Option<Vec<Vec3>> {
        self.attachments
            .iter()
            .map(|a| a.position(topology, positions))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> (MeshTopology, Vec<Vec3>) {
        let pos = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        ];
        // Normals +Y.
        let (t, _) = MeshTopology::new(&[[0, 2, 1], [0, 3, 2]], 4);
        (t, pos)
    }

    #[test]
    fn attachment_reproduces_bind_pose_and_follows_rigid_motion() {
        let (topo, pos) = quad();
        let body = MeshCollider::new(&topo, &pos).unwrap();
        let x = vec![[0.3, 0.002, 0.6], [0.5, 0.5, 0.5], [0.9, -0.001, 0.2]];
        let pins = BodyPins::select(&topo, &body, &x, 0.005);
        assert_eq!(pins.nodes, vec![0, 2]);
        let back = pins.positions(&topo, &pos).unwrap();
        for (k, &n) in pins.nodes.iter().enumerate() {
            for c in 0..3 {
                assert!((back[k][c] - x[n][c]).abs() < 1e-14);
            }
        }
        // Rotate the body 90 degrees about z and shift it: the pins follow.
        let rot = |p: Vec3| [-p[1] + 2.0, p[0], p[2] + 1.0];
        let moved: Vec<Vec3> = pos.iter().map(|&p| rot(p)).collect();
        let after = pins.positions(&topo, &moved).unwrap();
        for (k, &n) in pins.nodes.iter().enumerate() {
            let want = rot(x[n]);
            for c in 0..3 {
                assert!((after[k][c] - want[c]).abs() < 1e-12, "{after:?} {want:?}");
            }
        }
    }
}
