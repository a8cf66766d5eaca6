//! External bodies (planes, spheres, skinned characters: any
//! [`PointCollider`]) as an energy term of the Newton solver: a quadratic
//! penalty that keeps every yarn vertex its radius outside each surface,
//! and Coulomb friction against the surface as the lagged, smoothed IPC
//! potential of [`super::friction`] (Li et al. 2020 §5, Eq. 13-16) per
//! vertex in contact.
//!
//! The surfaces are queried at [`ColliderTerm::set_time`]'s time (the end
//! of an implicit step). Friction is lagged once per step
//! ([`ColliderTerm::lag_friction`]): the normal force is the penalty's at
//! the step's start, the slip is the vertex's motion relative to the
//! surface since then.

use std::sync::Arc;

use rayon::prelude::*;

use super::friction::{
    elastic_offset, f0, f1_over_y, onto_tangent_plane, slip_hessian_world, tangent_basis,
};
use super::term::{EnergyTerm, Triplets};
use crate::geom::vec3::dot;
use crate::geom::Vec3;
use crate::yarn::sim::PointCollider;

/// One vertex's lagged friction against one surface.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SurfaceFriction {
    vertex: usize,
    collider: usize,
    /// `mu lambda` (N).
    capacity: f64,
    /// Orthonormal tangent basis of the surface at the lag.
    basis: [Vec3; 2],
    /// Where the vertex would be at the step's end if it moved with the
    /// surface (m): the slip is measured from here.
    anchor: Vec3,
    /// Elastic tangential offset carried from the last step (m, in the
    /// tangent plane; `FrictionTerm::carry`'s role): without it a sticking
    /// vertex would creep by up to the stick distance every step.
    offset: Vec3,
}

impl SurfaceFriction {
    /// Tangential slip `u` (m) at position `x`, carried offset included.
    fn slip(&self, x: Vec3) -> [f64; 2] {
        let d: Vec3 = std::array::from_fn(|i| x[i] - self.anchor[i] + self.offset[i]);
        [dot(self.basis[0], d), dot(self.basis[1], d)]
    }
}

/// Penalty contact and lagged friction of yarn vertices against colliders.
#[derive(Debug, Clone)]
pub struct ColliderTerm {
    colliders: Vec<Arc<dyn PointCollider>>,
    /// Yarn radius per vertex (m).
    radius: Vec<f64>,
    /// Penalty stiffness (N/m per vertex).
    stiffness: f64,
    /// Candidate distance beyond the radius (m): at least the largest move
    /// of a vertex in one Newton iteration.
    skin: f64,
    /// IPC stick distance eps_u (m).
    stick_distance: f64,
    /// Query time of the surfaces (s).
    time: f64,
    /// (vertex, collider, signed distance - radius) within radius + skin
    /// at the iteration start.
    candidates: Vec<(usize, usize, f64)>,
    friction: Vec<SurfaceFriction>,
}

fn point(q: &[f64], v: usize) -> Vec3 {
    [q[3 * v], q[3 * v + 1], q[3 * v + 2]]
}

impl ColliderTerm {
    /// A term for vertices of `radius` (m) against `colliders`: penalty
    /// `stiffness` (N/m), candidates within `skin` (m) of contact, friction
    /// sticking below `stick_distance` (m).
    pub fn new(
        colliders: Vec<Arc<dyn PointCollider>>,
        radius: Vec<f64>,
        stiffness: f64,
        skin: f64,
        stick_distance: f64,
    ) -> ColliderTerm {
        ColliderTerm {
            colliders,
            radius,
            stiffness,
            skin,
            stick_distance,
            time: 0.0,
            candidates: Vec::new(),
            friction: Vec::new(),
        }
    }

    /// Queries the surfaces at time `t` (s) from now on.
    pub fn set_time(&mut self, t: f64) {
        self.time = t;
    }

    /// Every (vertex, collider, signed distance - radius, normal) with the
    /// vertex closer than `reach` (m) beyond its radius, at the current time.
    fn near(&self, q: &[f64], reach: f64) -> Vec<(usize, usize, f64, Vec3)> {
        let nv = self.radius.len();
        (0..nv)
            .into_par_iter()
            .flat_map_iter(|v| {
                let x = point(q, v);
                self.colliders
                    .iter()
                    .enumerate()
                    .filter_map(move |(c, col)| {
                        let (d, n) = col.signed_distance(x, self.time);
                        let gap = d - self.radius[v];
                        (gap < reach).then_some((v, c, gap, n))
                    })
            })
            .collect()
    }

    /// Lags the friction at `q`, the state at the step's start (time of the
    /// last [`Self::set_time`]): every vertex pressed into a surface with
    /// `mu > 0` gets its normal force, tangent basis and the point moving
    /// with the surface over the step `dt` (s). A vertex that stays on the
    /// same surface keeps the elastic part of its last slip (at most the
    /// stick distance), so sticking does not creep from step to step.
    pub fn lag_friction(&mut self, q: &[f64], dt: f64) {
        let eps = self.stick_distance;
        let carry: std::collections::HashMap<(usize, usize), Vec3> = self
            .friction
            .iter()
            .map(|f| {
                let w = elastic_offset(f.slip(point(q, f.vertex)), &f.basis, eps);
                ((f.vertex, f.collider), w)
            })
            .collect();
        let mut out = Vec::new();
        for (v, c, gap, n) in self.near(q, 0.0) {
            let col = &self.colliders[c];
            let mu = col.friction();
            let lambda = self.stiffness * (-gap);
            if !(mu > 0.0 && lambda > 0.0) {
                continue;
            }
            let x = point(q, v);
            let vc = col.velocity(x, self.time);
            let basis = tangent_basis(n);
            let offset = carry
                .get(&(v, c))
                .map_or([0.0; 3], |w| onto_tangent_plane(*w, &basis));
            out.push(SurfaceFriction {
                vertex: v,
                collider: c,
                capacity: mu * lambda,
                basis,
                anchor: std::array::from_fn(|i| x[i] + dt * vc[i]),
                offset,
            });
        }
        self.friction = out;
    }

    /// Vertices in contact (closer than their radius) and the deepest
    /// penetration (m, 0 without contact) at the last
    /// [`EnergyTerm::begin_iteration`]'s state (after a Newton solve: its
    /// final iterate), without querying the surfaces again.
    pub fn contacts(&self) -> (usize, f64) {
        let touching = self.candidates.iter().filter(|c| c.2 < 0.0);
        let deepest = touching.clone().map(|c| -c.2).fold(0.0, f64::max);
        (touching.count(), deepest)
    }
}

impl EnergyTerm for ColliderTerm {
    fn name(&self) -> &'static str {
        "collider"
    }

    fn begin_iteration(&mut self, q: &[f64]) {
        self.candidates = self
            .near(q, self.skin)
            .into_iter()
            .map(|(v, c, gap, _)| (v, c, gap))
            .collect();
    }

    fn eval(&self, q: &[f64], grad: &mut [f64], mut hess: Option<&mut Triplets>) -> f64 {
        let k = self.stiffness;
        let mut e = 0.0;
        for &(v, c, _) in &self.candidates {
            let (d, n) = self.colliders[c].signed_distance(point(q, v), self.time);
            let pen = self.radius[v] - d;
            if !(pen > 0.0) {
                continue;
            }
            e += 0.5 * k * pen * pen;
            for i in 0..3 {
                grad[3 * v + i] -= k * pen * n[i];
            }
            if let Some(h) = hess.as_deref_mut() {
                // Gauss-Newton: the surface's curvature term is dropped.
                for i in 0..3 {
                    for j in 0..3 {
                        h.push(3 * v + i, 3 * v + j, k * n[i] * n[j]);
                    }
                }
            }
        }
        let eps = self.stick_distance;
        for f in &self.friction {
            let u = f.slip(point(q, f.vertex));
            let y = (u[0] * u[0] + u[1] * u[1]).sqrt();
            e += f.capacity * f0(y, eps);
            let fy = f.capacity * f1_over_y(y, eps);
            for i in 0..3 {
                grad[3 * f.vertex + i] += fy * (u[0] * f.basis[0][i] + u[1] * f.basis[1][i]);
            }
            if let Some(h) = hess.as_deref_mut() {
                let m = slip_hessian_world(f.capacity, u, eps, &f.basis);
                for (i, row) in m.iter().enumerate() {
                    for (j, &val) in row.iter().enumerate() {
                        h.push(3 * f.vertex + i, 3 * f.vertex + j, val);
                    }
                }
            }
        }
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::sim::{PlaneCollider, SphereCollider};

    fn term(mu: f64) -> ColliderTerm {
        let sphere: Arc<dyn PointCollider> = Arc::new(SphereCollider {
            center: [0.0, -0.05, 0.0],
            radius: 0.05,
            velocity: [0.0; 3],
            friction: mu,
        });
        let plane: Arc<dyn PointCollider> = Arc::new(PlaneCollider {
            point: [0.0, 0.0, -0.01],
            normal: [0.0, 0.3, 1.0],
            friction: mu,
        });
        ColliderTerm::new(vec![sphere, plane], vec![1e-3, 2e-3], 500.0, 5e-3, 1e-5)
    }

    fn energy_and_gradient(t: &ColliderTerm, q: &[f64]) -> (f64, Vec<f64>) {
        let mut g = vec![0.0; q.len()];
        let e = t.eval(q, &mut g, None);
        (e, g)
    }

    #[test]
    fn penalty_and_friction_gradients_match_finite_differences() {
        // Vertex 0 presses into the sphere's top, vertex 1 into the tilted
        // plane; the friction is lagged at an earlier state, so with the
        // larger offset the vertices slide (slip >> eps), with the smaller
        // one they stick.
        for offset in [2e-4, 4e-6] {
            let mut t = term(0.4);
            let q0 = vec![0.0, 0.0005, 0.0, 0.01, 0.0, -0.0095];
            t.begin_iteration(&q0);
            t.lag_friction(&q0, 0.01);
            let q = vec![offset, 0.0003, -0.5 * offset, 0.01 + offset, 0.0, -0.0096];
            t.begin_iteration(&q);
            let (_, g) = energy_and_gradient(&t, &q);
            assert!(g.iter().any(|x| x.abs() > 0.0));
            for i in 0..q.len() {
                let h = 1e-9;
                let (mut qp, mut qm) = (q.clone(), q.clone());
                qp[i] += h;
                qm[i] -= h;
                let fd =
                    (energy_and_gradient(&t, &qp).0 - energy_and_gradient(&t, &qm).0) / (2.0 * h);
                assert!(
                    (fd - g[i]).abs() <= 1e-5 * g[i].abs().max(1e-3),
                    "offset {offset}, coordinate {i}: fd {fd} vs {}",
                    g[i]
                );
            }
        }
    }

    #[test]
    fn penalty_hessian_is_k_along_the_normal() {
        let mut t = term(0.0);
        let q = vec![0.0, 0.0004, 0.0, 5.0, 5.0, 5.0];
        t.begin_iteration(&q);
        let mut g = vec![0.0; 6];
        let mut h = Triplets::new();
        t.eval(&q, &mut g, Some(&mut h));
        // Sphere top: the normal is +Y, so the only entry is k at (1, 1).
        let mut yy = 0.0;
        for k in 0..h.len() {
            if h.rows[k] == 1 && h.cols[k] == 1 {
                yy += h.vals[k];
            } else {
                assert!(h.vals[k].abs() < 1e-9, "unexpected entry {k}");
            }
        }
        assert!((yy - 500.0).abs() < 1e-9, "{yy}");
        // Penetration 0.6 mm: force 0.3 N upward.
        assert!((g[1] + 500.0 * 6e-4).abs() < 1e-9, "{}", g[1]);
    }

    #[test]
    fn sliding_friction_is_mu_times_the_lagged_normal_force() {
        let q0 = vec![0.0, 0.0005, 0.0, 5.0, 5.0, 5.0];
        let q = vec![0.003, 0.0005, 0.0, 5.0, 5.0, 5.0];
        let gradient = |mu: f64| {
            let mut t = term(mu);
            t.begin_iteration(&q0);
            t.lag_friction(&q0, 0.01);
            t.begin_iteration(&q);
            energy_and_gradient(&t, &q).1
        };
        // Penetration 0.5 mm at the lag: lambda 0.25 N, mu 0.5. The
        // frictionless term gives the penalty alone; the difference is the
        // friction, tangent to the lagged normal (+Y), against the 3 mm
        // slip (>> eps: sliding).
        let (g, g0) = (gradient(0.5), gradient(0.0));
        let f = [g[0] - g0[0], g[1] - g0[1], g[2] - g0[2]];
        assert!((f[0] - 0.125).abs() < 1e-9, "{f:?}");
        assert!(f[1].abs() < 1e-12 && f[2].abs() < 1e-12, "{f:?}");
    }
}
