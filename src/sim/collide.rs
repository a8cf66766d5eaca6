//! Colliders for the PD time loop: planes, spheres and (animated) triangle
//! meshes, each with a thickness, posed at one time and used as projection
//! constraints through [`NodeProjector`] (VH §8.5 follows vanilla PD,
//! Bouaziz et al. 2014 §5: a node that is not admissible is moved to the
//! closest admissible position).
//!
//! * Signed distances: plane `(p - o)·n̂`; sphere `|p - c| - r`; triangle
//!   mesh `±|p - q|` with `q` the closest surface point (found with a
//!   bounding-volume hierarchy) and the sign from the angle-weighted
//!   pseudo-normal of the closest feature (face, edge or vertex; Bærentzen &
//!   Aanæs 2005, "Signed distance computation using the angle weighted
//!   pseudonormal"), which is exact for closed, consistently oriented
//!   meshes. On an open mesh a point is outside when it is on the front side
//!   of the closest feature (for a boundary edge: of its one triangle).
//! * Admissible: signed distance >= thickness (m). Projection moves a node
//!   along the outward direction at the closest feature to distance
//!   `thickness`.
//! * Friction ([`ColliderSet::friction`], the rule in `sim::contact`) acts
//!   on the motion relative to the surface: a mesh given its vertex
//!   positions at the start of the step ([`MeshCollider::with_previous`])
//!   reports how the closest surface point moved over the step; planes and
//!   spheres rest.
//!
//! Pure math: no files, no printing.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Small fixed-size loops over x, y, z read better indexed.
#![allow(clippy::needless_range_loop)]

use super::contact::{Contact, NodeProjector, PointProjector};
use crate::geom::bvh::{normalized, MeshCollider};
use crate::geom::vec3::{add, dot, norm, scale, sub};
use crate::geom::Vec3;

/// The geometry of a collider.
#[derive(Debug, Clone)]
pub enum Shape {
    /// Half-space `(p - point)·normal >= 0` is outside (`normal` need not be unit).
    Plane { point: Vec3, normal: Vec3 },
    /// Ball of `radius` (m) about `center`.
    Sphere { center: Vec3, radius: f64 },
    /// A posed triangle mesh (e.g. a character's body).
    Mesh(Box<MeshCollider>),
}

/// A collider: a shape and the distance (m) nodes keep from it.
#[derive(Debug, Clone)]
pub struct Collider {
    pub shape: Shape,
    /// Distance (m, >= 0) a node must keep from the surface; the tet nodes
    /// sit at the voxel corners around the yarns, so a small positive value
    /// keeps the yarns off the body. Default in scenes: 1 mm.
    pub thickness: f64,
}

/// Signed distance of a point to one collider and the outward direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distance {
    /// Signed distance (m), negative inside.
    pub signed: f64,
    /// Unit outward direction (along which the projection moves the point).
    pub outward: Vec3,
}

impl Collider {
    /// Signed distance of `p` to the surface (m) and the outward direction;
    /// None for an empty mesh or a degenerate plane normal.
    pub fn distance(&self, p: Vec3) -> Option<Distance> {
        self.probe(p, false).map(|(d, _)| d)
    }

    /// [`Self::distance`] and, when `motion` is set, the displacement (m) of
    /// the closest surface point over the time step.
    fn probe(&self, p: Vec3, motion: bool) -> Option<(Distance, Vec3)> {
        self.probe_within(p, motion, self.thickness)
    }

    /// [`Self::probe`] with the surface motion read only within `thickness`.
    fn probe_within(&self, p: Vec3, motion: bool, thickness: f64) -> Option<(Distance, Vec3)> {
        let still = |d: Distance| (d, [0.0; 3]);
        match &self.shape {
            Shape::Plane { point, normal } => {
                let n = normalized(*normal)?;
                Some(still(Distance {
                    signed: dot(sub(p, *point), n),
                    outward: n,
                }))
            }
            Shape::Sphere { center, radius } => {
                let d = sub(p, *center);
                let l = norm(d);
                let outward = if l > 0.0 {
                    scale(d, 1.0 / l)
                } else {
                    [0.0, 1.0, 0.0]
                };
                Some(still(Distance {
                    signed: l - radius,
                    outward,
                }))
            }
            Shape::Mesh(m) => m.closest(p).map(|h| {
                // Only contacts need the motion.
                let u = if motion && h.signed_distance < thickness {
                    m.surface_motion(&h)
                } else {
                    [0.0; 3]
                };
                let d = Distance {
                    signed: h.signed_distance,
                    outward: h.outward,
                };
                (d, u)
            }),
        }
    }

    /// The closest admissible position to `p` (distance >= thickness), or
    /// None when `p` is admissible.
    pub fn project(&self, p: Vec3) -> Option<Vec3> {
        self.project_moving(p).map(|(q, _)| q)
    }

    /// [`Self::project`] and the displacement (m) of the surface there over
    /// the time step.
    pub fn project_moving(&self, p: Vec3) -> Option<(Vec3, Vec3)> {
        self.project_moving_by(p, self.thickness)
    }

    /// [`Self::project_moving`] keeping `thickness` (m) instead of the
    /// collider's own.
    fn project_moving_by(&self, p: Vec3, thickness: f64) -> Option<(Vec3, Vec3)> {
        let (d, u) = self.probe_within(p, true, thickness)?;
        if d.signed >= thickness || !d.signed.is_finite() {
            return None;
        }
        // Onto the surface first, then out by the thickness: exact for a
        // plane through the origin (fewer roundings than one combined step).
        let on = add(p, scale(d.outward, -d.signed));
        Some((add(on, scale(d.outward, thickness)), u))
    }
}

/// Colliders posed at one time; the free nodes' [`NodeProjector`].
#[derive(Debug, Clone, Default)]
pub struct ColliderSet {
    pub colliders: Vec<Collider>,
    /// Coulomb friction coefficient (static = kinetic, >= 0) of contacts
    /// with any of the colliders (`sim::contact`). Default 0.
    pub friction: f64,
}

/// Passes over the colliders in [`ColliderSet::project`]: a node pushed out
/// of one collider into another is corrected by the next pass.
const PROJECTION_PASSES: usize = 3;

impl ColliderSet {
    /// The smallest signed distance (m) of `p` over the colliders and that
    /// collider's index, or None without colliders.
    pub fn min_signed_distance(&self, p: Vec3) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        for (i, c) in self.colliders.iter().enumerate() {
            if let Some(d) = c.distance(p) {
                if best.is_none_or(|b| d.signed < b.1) {
                    best = Some((i, d.signed));
                }
            }
        }
        best
    }

    /// Penetration depth (m, >= 0) of `p` into the colliders: the largest
    /// `max(0, -signed distance)`.
    pub fn penetration(&self, p: Vec3) -> f64 {
        self.min_signed_distance(p)
            .map_or(0.0, |(_, d)| (-d).max(0.0))
    }

    /// The largest [`Self::penetration`] (m) of `points` (e.g. the yarn
    /// vertices embedded in the tets), 0 for none.
    pub fn max_penetration(&self, points: &[Vec3]) -> f64 {
        use rayon::prelude::*;
        points
            .par_iter()
            .map(|p| self.penetration(*p))
            .reduce(|| 0.0, f64::max)
    }
}

impl ColliderSet {
    /// The closest admissible position of `p` over the projection passes
    /// and the surface motion of the last collider that moved it.
    fn resolve(&self, p: Vec3) -> Option<(Vec3, Vec3)> {
        self.resolve_with(p, 0.0)
    }

    /// [`Self::resolve`] for a point that keeps `extra` (m) beyond each
    /// collider's thickness.
    fn resolve_with(&self, p: Vec3, extra: f64) -> Option<(Vec3, Vec3)> {
        let mut q = p;
        let mut motion = None;
        for _ in 0..PROJECTION_PASSES {
            let mut any = false;
            for c in &self.colliders {
                if let Some((r, u)) = c.project_moving_by(q, c.thickness + extra) {
                    q = r;
                    motion = Some(u);
                    any = true;
                }
            }
            if !any {
                break;
            }
        }
        motion.map(|u| (q, u))
    }
}

impl NodeProjector for ColliderSet {
    fn project(&self, _node: usize, p: Vec3) -> Option<Vec3> {
        self.resolve(p).map(|(q, _)| q)
    }
    fn contact(&self, _node: usize, p: Vec3) -> Option<Contact> {
        self.resolve(p).map(|(target, surface_motion)| Contact {
            target,
            surface_motion,
            friction: self.friction,
        })
    }
}

/// Colliders acting on embedded points (yarn vertices): point `j` keeps
/// `radius[j]` beyond each collider's thickness.
#[derive(Debug, Clone, Copy)]
pub struct PointColliders<'a> {
    pub set: &'a ColliderSet,
    /// Per point (m, >= 0).
    pub radius: &'a [f64],
}

impl PointProjector for PointColliders<'_> {
    fn contact(&self, point: usize, p: Vec3) -> Option<Contact> {
        let r = self.radius.get(point).copied().unwrap_or(0.0);
        self.set
            .resolve_with(p, r)
            .map(|(target, surface_motion)| Contact {
                target,
                surface_motion,
                friction: self.set.friction,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_and_sphere_projection_exact() {
        let plane = Collider {
            shape: Shape::Plane {
                point: [0.0, 1.0, 0.0],
                normal: [0.0, 2.0, 0.0],
            },
            thickness: 0.01,
        };
        assert_eq!(plane.project([0.3, 1.5, 0.0]), None);
        let q = plane.project([0.3, 0.5, -0.2]).unwrap();
        assert!((q[1] - 1.01).abs() < 1e-15 && q[0] == 0.3 && q[2] == -0.2);
        let sphere = Collider {
            shape: Shape::Sphere {
                center: [1.0, 0.0, 0.0],
                radius: 0.5,
            },
            thickness: 0.0,
        };
        let q = sphere.project([1.0, 0.15, 0.2]).unwrap();
        assert!((norm(sub(q, [1.0, 0.0, 0.0])) - 0.5).abs() < 1e-15);
        assert!((q[1] / q[2] - 0.75).abs() < 1e-12);
        assert_eq!(sphere.project([2.0, 0.0, 0.0]), None);
    }
}
