//! Contact with external bodies as PD projection constraints (VH §8.5,
//! Bouaziz et al. 2014 §5): a node `i` at `p` that is not admissible (inside a
//! collider, or closer to it than the collider's thickness) gets the
//! constraint energy `½ w_i |x_i - P(p)|²`, where `P(p)` is its target. The
//! solver re-projects every PD iteration.
//!
//! # Coulomb friction
//! Without friction the target is the closest admissible position `q`. With
//! a coefficient `μ` the target also carries the tangential force
//! ([`friction_target`]): the constraint force is `w (P - p)`, so its normal
//! part `w δ` (`δ = |q - p|`, the depth of the projection) is the normal
//! force and, for a target at the node's start-of-step position `a`
//! (carried along by the collider's surface), `w s` is the tangential force
//! needed to stick (`s`: the tangential part of `p - a`, i.e. the slip over
//! the step relative to the collider). Static friction: if `|s| <= μ δ` the
//! target is `q - s` (no slip); kinetic friction otherwise: the tangential
//! force is clamped to `μ w δ` against the slip, target `q - μ δ s / |s|`.
//! Both forces act over the same step, so the comparison is the one of the
//! impulses. At the converged iterate the forces are the contact forces of
//! the implicit step, so friction acts inside the solve rather than on a
//! node already moved onto the surface (whose projection depth would be 0).
//!
//! # Contacts at embedded points
//! The homogenized mesh stands for yarns that lie inside its tets, up to
//! half a voxel from the nodes. Contact and friction can act where the
//! yarns are ([`EmbeddedPoints`], [`PointProjector`]): point `j` at
//! `y_j = Σ_a λ_ja x_a` (its tet's nodes `a`, barycentric weights `λ`, VH
//! Eq. 4) gets the constraint `½ w_j |y_j - P_j|²`, `w_j = κ m_j / Δt²`
//! with `m_j` the yarn mass the point stands for, and `P_j` its friction
//! target as above (depth, slip and the Coulomb cone per point). Its force
//! `w_j (P_j - y_j)` reaches node `a` as `λ_ja w_j (P_j - y_j)`, the
//! gradient through the embedding. The exact Hessian `w_j λ_j λ_jᵀ` would
//! couple the four nodes in the PD matrix; PD takes its row-sum lumping
//! `w_j diag(λ_j)` instead: the same gradient at every iterate (so the same
//! converged step), a diagonal the solver's contact path already handles,
//! and a majorizer of the exact term (`diag(λ) - λ λᵀ` is diagonally
//! dominant, since `Σ λ = 1` and `λ >= 0`), so the PD surrogate stays an
//! upper bound. Node `a` then carries the weight `W_a = Σ_j λ_ja w_j` and
//! the target `x_a + Σ_j λ_ja w_j (P_j - y_j) / W_a`; a single point in a
//! tet moves all four nodes by its own correction, which puts it on its
//! target in one iteration.
//!
//! This module holds the interface shared by the colliders (`sim::collide`)
//! and the time loop (`sim::pd`), and the friction rule.

use crate::geom::Vec3;

/// A non-admissible node's contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Closest admissible position (m): the frictionless target.
    pub target: Vec3,
    /// Displacement (m) of the collider's surface at the contact over the
    /// time step (zero for a resting collider): friction acts on the motion
    /// relative to it.
    pub surface_motion: Vec3,
    /// Coulomb coefficient (static = kinetic, >= 0; 0: frictionless).
    pub friction: f64,
}

/// Something the free nodes must stay out of during one time step (a set of
/// colliders posed at the step's end time).
pub trait NodeProjector: Sync {
    /// The closest admissible position (m) for node `node` at `p` (m), or
    /// `None` when `p` is already admissible. Must be cheap and thread-safe:
    /// the solver calls it for every free node in every PD iteration.
    fn project(&self, node: usize, p: Vec3) -> Option<Vec3>;

    /// The contact of node `node` at `p` (None when admissible). The default
    /// is [`Self::project`] without friction on a resting collider.
    fn contact(&self, node: usize, p: Vec3) -> Option<Contact> {
        self.project(node, p).map(|target| Contact {
            target,
            surface_motion: [0.0; 3],
            friction: 0.0,
        })
    }
}

/// Something the embedded points ([`EmbeddedPoints`]) must stay out of
/// during one time step: colliders posed at the step's end time, each
/// point keeping its own distance (a yarn vertex: its radius).
pub trait PointProjector: Sync {
    /// The contact of point `point` at `p` (m), None when admissible. Must
    /// be cheap and thread-safe: the solver calls it for every point in
    /// every PD iteration.
    fn contact(&self, point: usize, p: Vec3) -> Option<Contact>;
}

/// Points embedded in the tets that contacts act on (module doc,
/// "Contacts at embedded points"): yarn vertices, by their tet's nodes and
/// barycentric weights (VH Eq. 4), and the yarn mass each stands for.
#[derive(Debug, Clone, Default)]
pub struct EmbeddedPoints {
    /// The four nodes of each point's tet.
    pub nodes: Vec<[u32; 4]>,
    /// Barycentric weights of each point in its tet (>= 0, sum 1).
    pub weights: Vec<[f64; 4]>,
    /// Mass (kg, > 0) each point stands for: the scale of its contact
    /// weight `κ m / Δt²`.
    pub mass: Vec<f64>,
}

impl EmbeddedPoints {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Position (m) of point `j` for node positions `x` (V2Y, VH Eq. 4).
    pub fn position(&self, j: usize, x: &[Vec3]) -> Vec3 {
        let (ids, w) = (&self.nodes[j], &self.weights[j]);
        let mut p = [0.0; 3];
        for a in 0..4 {
            let q = x[ids[a] as usize];
            for k in 0..3 {
                p[k] += w[a] * q[k];
            }
        }
        p
    }

    /// Why these points cannot serve a mesh of `num_nodes` nodes (lengths
    /// that differ, a node out of range, weights or masses that are not
    /// finite and non-negative), or None.
    pub fn check(&self, num_nodes: usize) -> Option<String> {
        if self.weights.len() != self.len() || self.mass.len() != self.len() {
            return Some(format!(
                "{} points with {} weight rows and {} masses",
                self.len(),
                self.weights.len(),
                self.mass.len()
            ));
        }
        for j in 0..self.len() {
            if let Some(&a) = self.nodes[j].iter().find(|&&a| a as usize >= num_nodes) {
                return Some(format!("point {j} names node {a} of {num_nodes}"));
            }
            let ok = |v: f64| v.is_finite() && v >= 0.0;
            if !self.weights[j].iter().all(|&w| ok(w)) || !(ok(self.mass[j]) && self.mass[j] > 0.0)
            {
                return Some(format!("point {j} has a bad weight or mass"));
            }
        }
        None
    }
}

/// No colliders.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoContact;

impl NodeProjector for NoContact {
    fn project(&self, _node: usize, _p: Vec3) -> Option<Vec3> {
        None
    }
}

/// The constraint target (m) of a node at `p` (m) in contact `c`, with
/// Coulomb friction against its motion since `start` (m, its position at
/// the start of the step); module doc. Non-finite or negative coefficients
/// count as frictionless.
pub fn friction_target(c: &Contact, p: Vec3, start: Vec3) -> Vec3 {
    let q = c.target;
    let d: Vec3 = std::array::from_fn(|k| q[k] - p[k]);
    let depth = dot(d, d).sqrt();
    if !(c.friction > 0.0 && c.friction.is_finite() && depth > 0.0) {
        return q;
    }
    let n = d.map(|x| x / depth);
    // Slip over the step relative to the surface, tangential part.
    let r: Vec3 = std::array::from_fn(|k| p[k] - start[k] - c.surface_motion[k]);
    let rn = dot(r, n);
    let s: Vec3 = std::array::from_fn(|k| r[k] - rn * n[k]);
    let slip = dot(s, s).sqrt();
    let limit = c.friction * depth;
    // Stick: cancel the slip; slide: the largest tangential force, mu times
    // the normal one, against it.
    let keep = if slip <= limit { 1.0 } else { limit / slip };
    if !keep.is_finite() {
        return q;
    }
    std::array::from_fn(|k| q[k] - keep * s[k])
}

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contact(friction: f64) -> Contact {
        // Node 1 mm below the plane y = 0 (normal +y).
        Contact {
            target: [0.3, 0.0, 0.0],
            surface_motion: [0.0; 3],
            friction,
        }
    }

    #[test]
    fn sticks_within_the_cone_and_slides_outside() {
        let p = [0.3, -1e-3, 0.0];
        // Slipped 0.4 mm along x since the start: within 0.5 * 1 mm.
        let start = [0.2996, 0.0, 0.0];
        let t = friction_target(&contact(0.5), p, start);
        assert!((t[0] - 0.2996).abs() < 1e-15 && t[1] == 0.0, "{t:?}");
        // Friction 0.2: the force is clamped to 0.2 mm of the 0.4 mm slip.
        let t = friction_target(&contact(0.2), p, start);
        assert!((t[0] - 0.2998).abs() < 1e-12, "{t:?}");
        // Frictionless: the closest admissible point.
        assert_eq!(friction_target(&contact(0.0), p, start), [0.3, 0.0, 0.0]);
    }

    #[test]
    fn moving_surface_carries_a_sticking_node() {
        let mut c = contact(1.0);
        c.surface_motion = [0.01, 0.0, 0.0];
        // The node stayed where it was while the surface moved 1 cm (which
        // needs far more than the 1 mm cone): it is dragged 1 mm along.
        let t = friction_target(&c, [0.3, -1e-3, 0.0], [0.3, 0.0, 0.0]);
        assert!((t[0] - 0.301).abs() < 1e-12, "{t:?}");
        // Moving with the surface: no slip, target unchanged tangentially.
        c.target = [0.31, 0.0, 0.0];
        let t = friction_target(&c, [0.31, -1e-3, 0.0], [0.3, 0.0, 0.0]);
        assert!((t[0] - 0.31).abs() < 1e-12);
    }

    #[test]
    fn bad_coefficients_are_frictionless_and_never_nan() {
        for mu in [f64::NAN, -1.0, f64::INFINITY] {
            let t = friction_target(&contact(mu), [0.3, -1e-3, 0.0], [0.0; 3]);
            assert_eq!(t, [0.3, 0.0, 0.0]);
        }
        // Zero depth: nothing to base the force on.
        let t = friction_target(&contact(0.5), [0.3, 0.0, 0.0], [0.0; 3]);
        assert_eq!(t, [0.3, 0.0, 0.0]);
    }
}
