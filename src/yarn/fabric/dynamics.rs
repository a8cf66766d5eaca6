//! Yarn-level dynamics with the quasi-static yarn mechanics: implicit Euler
//! (Gast et al. 2015, "Optimization integrator") on the same rods, Kaldor
//! contact and lagged yarn-yarn friction that the training poses and fabric
//! tests solve to equilibrium ([`super::Fabric`]), plus gravity, Rayleigh
//! mass damping, scripted handles ([`PoseDriver`]) and colliders with
//! Coulomb friction ([`ColliderTerm`]).
//!
//! Each step of size h minimizes
//! `sum_i m_i/(2h^2)|x_i - x~_i|^2 + gamma m_i/(2h)|x_i - x_i^n|^2 + E(x)`
//! with `x~ = x^n + h v^n` and E the rods, contact, friction, gravity and
//! collider terms; then `v = (x - x^n) / h`. Handled vertices are placed on
//! their targets at the step's end time and held.
//!
//! This is the ground truth `validate` compares the homogenized mesh with
//! when a scene asks for `model = "rods"`: the explicit simulator
//! (`yarn::sim`) is a different, much softer yarn model (no twist,
//! unsigned curvature) than the one the training poses come from.
//!
//! Pure: no files, no printing, no environment.

use std::sync::Arc;
use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams};

/// Default Newton force tolerance of a step, as a fraction of the heaviest
/// vertex's weight ([`RodDynamicsParams::force_tolerance`]).
pub const STEP_TOLERANCE: f64 = 0.1;
use super::InertiaTerm;
use crate::geom::{Vec3, Yarns};
use crate::yarn::poses::PoseDriver;
use crate::yarn::sim::PointCollider;
use crate::yarn::statics::{ColliderTerm, EnergyTerm, GravityTerm};

/// Most halvings of a step whose Newton solve fails
/// ([`RodDynamics::advance`]).
pub const MAX_SPLITS: u32 = 5;

/// Controls of [`RodDynamics`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RodDynamicsParams {
    /// Largest implicit-Euler step (s). Default 1/600 s: the drape of
    /// `examples/validate` moves by under 0.1 yarn diameters RMS when it is
    /// halved (docs/guides/fitting.md, the yarn-level ground truth of `validate`).
    pub max_dt: f64,
    /// Gravity (m/s^2). Default [0, -9.81, 0].
    pub gravity: Vec3,
    /// Rayleigh mass damping gamma (1/s): force `-gamma m v`, as the
    /// explicit simulator's `global_damping`. Default 2.
    pub global_damping: f64,
    /// Collider penalty stiffness (N/m per vertex). Default 1000: a
    /// vertex's weight (~4e-6 N) sinks 4 nm, a 2 m/s impact about 0.1 mm.
    pub collider_stiffness: f64,
    /// Fastest vertex speed (m/s) before the run counts as diverged.
    /// Default 100.
    pub max_speed: f64,
    /// Newton force tolerance of a step (N). Default `None`: 10% of the
    /// heaviest vertex's weight at 1 g (3.7e-7 N for a 1 mm yarn of 120
    /// kg/m^3: the drape of `examples/validate` lies 0.03 yarn diameters
    /// RMS from a solve to 1%, in half the Newton iterations).
    pub force_tolerance: Option<f64>,
}

impl Default for RodDynamicsParams {
    fn default() -> Self {
        RodDynamicsParams {
            max_dt: 1.0 / 600.0,
            gravity: [0.0, -9.81, 0.0],
            global_damping: 2.0,
            collider_stiffness: 1e3,
            max_speed: 100.0,
            force_tolerance: None,
        }
    }
}

impl RodDynamicsParams {
    /// Checks every value's range before any work.
    pub fn check(&self) -> Result<(), FabricError> {
        let ok = self.max_dt.is_finite()
            && self.max_dt > 0.0
            && self.max_dt <= 1.0
            && self.gravity.iter().all(|g| g.is_finite() && g.abs() <= 1e3)
            && self.global_damping.is_finite()
            && self.global_damping >= 0.0
            && self.collider_stiffness.is_finite()
            && self.collider_stiffness > 0.0
            && self.max_speed.is_finite()
            && self.max_speed > 0.0
            && self
                .force_tolerance
                .is_none_or(|f| f.is_finite() && f > 0.0);
        if ok {
            Ok(())
        } else {
            Err(FabricError::Setup(format!(
                "rod dynamics parameters out of range (0 < max_dt <= 1 s, |gravity| <= 1000, damping >= 0, collider stiffness > 0, max speed > 0): {self:?}"
            )))
        }
    }
}

/// What [`RodDynamics::advance`] did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RodAdvanceStats {
    pub steps: u64,
    /// Steps whose Newton solve failed and that were retried as two half
    /// steps.
    pub split_steps: u64,
    pub newton_iterations: usize,
    /// Largest final force residual of a step (N).
    pub max_residual_n: f64,
    /// Smallest non-adjacent segment distance / (rA + rB) at a step's end.
    pub min_distance_ratio: f64,
    /// Largest one-step vertex displacement / its radius.
    pub max_displacement_ratio: f64,
    /// Yarn-yarn contacts per vertex at the end.
    pub contacts_per_vertex: f64,
    /// Vertices touching a collider at the end, and the deepest
    /// penetration over the steps (m).
    pub collider_contacts: usize,
    pub max_penetration_m: f64,
    pub seconds: f64,
}

/// A yarn set moving under implicit Euler.
pub struct RodDynamics {
    pub fabric: Fabric,
    /// Vertex velocities (m/s), 3 per vertex.
    velocity: Vec<f64>,
    time: f64,
    driver: Option<Arc<PoseDriver>>,
    fixed: Vec<bool>,
    colliders: ColliderTerm,
    gravity: GravityTerm,
    radius: Vec<f64>,
    params: RodDynamicsParams,
}

impl RodDynamics {
    /// `yarns` at rest (their stored rest shape when they carry one), with
    /// `driver`'s vertices scripted and `colliders` in the scene.
    pub fn new(
        yarns: &Yarns,
        fabric: &FabricParams,
        params: &RodDynamicsParams,
        driver: Option<Arc<PoseDriver>>,
        colliders: Vec<Arc<dyn PointCollider>>,
    ) -> Result<RodDynamics, FabricError> {
        params.check()?;
        let mut fabric = Fabric::new(yarns, fabric)?;
        let n = fabric.num_vertices();
        // Resolve 10% of the heaviest vertex's weight (at least at 1 g):
        // the default 1e-5 N would exceed a vertex's weight.
        let g_ref = crate::geom::vec3::norm(params.gravity).max(9.81);
        let weight_max = fabric.mass.iter().fold(0.0, |m: f64, &w| m.max(w)) * g_ref;
        let s = &mut fabric.params.solver;
        s.force_tolerance = params
            .force_tolerance
            .unwrap_or_else(|| s.force_tolerance.min(STEP_TOLERANCE * weight_max));
        let mut held = vec![false; n];
        if let Some(d) = &driver {
            for &v in d.pinned() {
                if v >= n {
                    return Err(FabricError::Setup(format!(
                        "handle vertex {v} out of range ({n} vertices)"
                    )));
                }
                held[v] = true;
            }
        }
        // Rotational inertia is not modelled: twists stay quasi-static, so a
        // free curve's constant twist needs its gauge.
        let fixed = fabric.clamped_and_gauged(&held);
        let radius: Vec<f64> = (0..n).map(|v| yarns.radius_at(v)).collect();
        let skin = 1.05 * fabric.params.solver.max_displacement;
        let stick = fabric.params.friction.stick_distance;
        let colliders = ColliderTerm::new(
            colliders,
            radius.clone(),
            params.collider_stiffness,
            skin,
            stick,
        );
        let gravity = GravityTerm {
            mass: fabric.mass.clone(),
            g: params.gravity,
        };
        Ok(RodDynamics {
            fabric,
            velocity: vec![0.0; 3 * n],
            time: 0.0,
            driver,
            fixed,
            colliders,
            gravity,
            radius,
            params: params.clone(),
        })
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn points(&self) -> Vec<Vec3> {
        self.fabric.points()
    }

    /// Per clamped band of the driver (its groups, in order): the resultant
    /// force (N) the clamp holds the yarns with, the sum over the band's
    /// vertices of the yarns' internal force gradient (rods, yarn-yarn
    /// contact and friction) at the current state. The band's own weight
    /// and inertia are left out, so that a homogenized mesh held by the
    /// same band can be compared force for force: within the band the pair
    /// forces cancel, and what remains is what the free fabric transmits.
    /// Empty without a driver.
    pub fn band_forces(&mut self) -> Vec<Vec3> {
        let Some(d) = self.driver.clone() else {
            return Vec::new();
        };
        let (_, g) = self.fabric.gradient(&mut []);
        (0..d.num_groups())
            .map(|k| {
                let mut f = [0.0; 3];
                for &v in d.group_vertices(k) {
                    for c in 0..3 {
                        f[c] += g[3 * v + c];
                    }
                }
                f
            })
            .collect()
    }

    /// Steps over `duration` (s) in equal steps of at most `max_dt`.
    pub fn advance(&mut self, duration: f64) -> Result<RodAdvanceStats, FabricError> {
        let t0 = Instant::now();
        let steps = (duration / self.params.max_dt).ceil().max(1.0) as u64;
        let dt = duration / steps as f64;
        let mut st = RodAdvanceStats {
            min_distance_ratio: f64::INFINITY,
            ..RodAdvanceStats::default()
        };
        for _ in 0..steps {
            self.step_or_split(dt, 0, &mut st)?;
        }
        let q = &self.fabric.q;
        st.contacts_per_vertex = self.fabric.contact.stats(q).contacts_per_vertex;
        st.collider_contacts = self.colliders.contacts().0;
        st.seconds = t0.elapsed().as_secs_f64();
        Ok(st)
    }

    /// [`Self::step`], retried as two half steps from the same state when
    /// Newton fails (its line search stalls on the non-smooth contact and
    /// friction terms, or it runs out of iterations), down to
    /// `dt / 2^MAX_SPLITS`; divergence is not retried.
    fn step_or_split(
        &mut self,
        dt: f64,
        depth: u32,
        st: &mut RodAdvanceStats,
    ) -> Result<(), FabricError> {
        let (q, v) = (self.fabric.q.clone(), self.velocity.clone());
        match self.step(dt, st) {
            Err(FabricError::Solve { .. }) if depth < MAX_SPLITS => {
                self.fabric.q = q;
                self.velocity = v;
                st.split_steps += 1;
                self.step_or_split(0.5 * dt, depth + 1, st)?;
                self.step_or_split(0.5 * dt, depth + 1, st)
            }
            other => other,
        }
    }

    /// One implicit-Euler step of `dt` (module docs).
    fn step(&mut self, dt: f64, st: &mut RodAdvanceStats) -> Result<(), FabricError> {
        let n = self.fabric.num_vertices();
        let t1 = self.time + dt;
        self.fabric.begin_step();
        let start = self.fabric.q[..3 * n].to_vec();
        self.colliders.lag_friction(&start, dt);
        self.colliders.set_time(t1);
        if let Some(d) = &self.driver {
            for (&v, p) in d.pinned().iter().zip(d.targets(t1)) {
                self.fabric.q[3 * v..3 * v + 3].copy_from_slice(&p);
            }
        }
        let target: Vec<f64> = start
            .iter()
            .zip(&self.velocity)
            .map(|(x, v)| x + dt * v)
            .collect();
        let mut inertia = InertiaTerm::new(self.fabric.mass.clone(), target, dt);
        let gamma = self.params.global_damping;
        let mut damping = (gamma > 0.0)
            .then(|| InertiaTerm::damping(self.fabric.mass.clone(), start.clone(), dt, gamma));
        let stage = format!("implicit step at t = {t1:.6} s");
        let stats = {
            let mut extra: Vec<&mut dyn EnergyTerm> =
                vec![&mut inertia, &mut self.gravity, &mut self.colliders];
            if let Some(d) = damping.as_mut() {
                extra.push(d);
            }
            self.fabric.solve(&mut extra, &self.fixed, &stage)?
        };
        st.steps += 1;
        st.newton_iterations += stats.iterations;
        st.max_residual_n = st.max_residual_n.max(stats.residual);
        let mut fastest: f64 = 0.0;
        for v in 0..n {
            let mut d2 = 0.0;
            for c in 0..3 {
                let dx = self.fabric.q[3 * v + c] - start[3 * v + c];
                self.velocity[3 * v + c] = dx / dt;
                d2 += dx * dx;
            }
            let d = d2.sqrt();
            fastest = fastest.max(d / dt);
            st.max_displacement_ratio = st.max_displacement_ratio.max(d / self.radius[v]);
        }
        if !(fastest <= self.params.max_speed) {
            return Err(FabricError::NoEquilibrium(format!(
                "{stage}: a vertex moves at {fastest:.3e} m/s (limit {} m/s): diverged",
                self.params.max_speed
            )));
        }
        let q = &self.fabric.q;
        st.min_distance_ratio = st
            .min_distance_ratio
            .min(self.fabric.contact.stats(q).min_distance_ratio);
        st.max_penetration_m = st.max_penetration_m.max(self.colliders.contacts().1);
        self.time = t1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::sim::PlaneCollider;

    const R: f64 = 5e-4;

    /// A straight yarn of 21 vertices 1 mm apart along X at height `y`.
    fn straight_yarn(y: f64) -> Yarns {
        let mut yarns = Yarns::new();
        let pts: Vec<Vec3> = (0..21).map(|i| [i as f64 * 1e-3, y, 0.0]).collect();
        yarns.push_curve(&pts, false, R);
        yarns
    }

    /// The plane y = 0, facing +Y, with Coulomb coefficient `mu`.
    fn floor(mu: f64) -> Arc<dyn PointCollider> {
        Arc::new(PlaneCollider {
            point: [0.0; 3],
            normal: [0.0, 1.0, 0.0],
            friction: mu,
        })
    }

    fn run(
        yarns: &Yarns,
        params: RodDynamicsParams,
        colliders: Vec<Arc<dyn PointCollider>>,
        duration: f64,
    ) -> (RodDynamics, RodAdvanceStats) {
        let mut d = RodDynamics::new(yarns, &FabricParams::default(), &params, None, colliders)
            .expect("set-up");
        let st = d.advance(duration).expect("advance");
        (d, st)
    }

    fn mean_y(d: &RodDynamics) -> f64 {
        let p = d.points();
        p.iter().map(|p| p[1]).sum::<f64>() / p.len() as f64
    }

    #[test]
    fn free_fall_is_implicit_euler_exactly() {
        let h = 1.0 / 600.0;
        let params = RodDynamicsParams {
            global_damping: 0.0,
            max_dt: h,
            ..RodDynamicsParams::default()
        };
        let (d, st) = run(&straight_yarn(0.0), params, Vec::new(), 10.0 * h);
        assert_eq!(st.steps, 10);
        // v_n = n h g, so y_n = -g h^2 n (n + 1) / 2.
        let expected = -9.81 * h * h * 55.0;
        for p in d.points() {
            assert!(
                (p[1] - expected).abs() <= 1e-6 * expected.abs(),
                "{} vs {expected}",
                p[1]
            );
            assert!(p[0].is_finite() && p[2].abs() < 1e-12);
        }
    }

    #[test]
    fn mass_damping_sets_the_terminal_speed() {
        let gamma = 20.0;
        let params = RodDynamicsParams {
            global_damping: gamma,
            ..RodDynamicsParams::default()
        };
        let (mut d, _) = run(&straight_yarn(0.0), params, Vec::new(), 0.5);
        let y0 = mean_y(&d);
        d.advance(0.01).expect("advance");
        let speed = (y0 - mean_y(&d)) / 0.01;
        assert!(
            (speed - 9.81 / gamma).abs() < 0.01 * 9.81 / gamma,
            "{speed} m/s vs g / gamma {}",
            9.81 / gamma
        );
    }

    #[test]
    fn a_yarn_dropped_on_a_plane_comes_to_rest_on_it() {
        let plane = floor(0.3);
        let params = RodDynamicsParams {
            global_damping: 5.0,
            ..RodDynamicsParams::default()
        };
        // Dropped from 5 mm: it lands at ~0.3 m/s after 32 ms.
        let (mut d, st) = run(&straight_yarn(R + 5e-3), params, vec![plane], 0.3);
        assert!(st.max_penetration_m < 0.1 * R, "{}", st.max_penetration_m);
        let y0 = d.points();
        let st = d.advance(0.02).expect("advance");
        assert_eq!(st.collider_contacts, 21);
        for (p, q) in d.points().iter().zip(&y0) {
            // Resting: the weight (3.8e-7 N... per vertex) sinks nanometres.
            assert!((p[1] - R).abs() < 1e-6, "height {}", p[1]);
            assert!(crate::geom::dist(*p, *q) < 1e-6, "still moving");
        }
    }

    #[test]
    fn a_step_newton_cannot_finish_is_retried_as_half_steps() {
        let plane = floor(0.0);
        // Six Newton iterations per step: enough in free fall (the energy
        // is quadratic there), not where the yarn hits the plane at the
        // full step (it takes 9-10 there with the one-radius step cap; 12-16
        // with two radii).
        let mut fabric = FabricParams::default();
        fabric.solver.max_iterations = 6;
        let params = RodDynamicsParams {
            max_dt: 1.0 / 100.0,
            ..RodDynamicsParams::default()
        };
        let yarns = straight_yarn(R + 2e-3);
        let mut d = RodDynamics::new(&yarns, &fabric, &params, None, vec![plane]).expect("set-up");
        let st = d.advance(0.05).expect("split steps finish");
        assert!(st.split_steps > 0, "{st:?}");
        assert!(st.max_penetration_m < 0.2 * R, "{st:?}");
        // Without splitting room the same run fails and names the step.
        let mut fabric = fabric.clone();
        fabric.solver.max_iterations = 4;
        let mut d =
            RodDynamics::new(&yarns, &fabric, &params, None, vec![floor(0.0)]).expect("set-up");
        let e = d.advance(0.05).expect_err("four iterations cannot land it");
        assert!(e.to_string().contains("implicit step at t ="), "{e}");
    }

    /// Slide of a yarn lying across a 20 degree slope in 0.2 s (m), and
    /// the analytic Coulomb slide `g (sin - mu cos) t^2 / 2` (0 when it
    /// holds).
    fn slide_on_slope(mu: f64) -> (f64, f64) {
        let th = 20f64.to_radians();
        let n = [0.0, th.cos(), th.sin()];
        let plane: Arc<dyn PointCollider> = Arc::new(PlaneCollider {
            point: [0.0; 3],
            normal: n,
            friction: mu,
        });
        // Along X (level), resting on the slope: centre at R along n,
        // pressed by 1 nm so friction acts from the first step.
        let mut yarns = Yarns::new();
        let c = R - 1e-9;
        let pts: Vec<Vec3> = (0..21)
            .map(|i| [i as f64 * 1e-3, c * n[1], c * n[2]])
            .collect();
        yarns.push_curve(&pts, false, R);
        let params = RodDynamicsParams {
            global_damping: 0.0,
            max_dt: 1.0 / 2400.0,
            ..RodDynamicsParams::default()
        };
        let (d, _) = run(&yarns, params, vec![plane], 0.2);
        let down = [0.0, -th.sin(), th.cos()];
        let p = d.points();
        let slide = (0..p.len())
            .map(|v| (0..3).map(|k| (p[v][k] - pts[v][k]) * down[k]).sum::<f64>())
            .sum::<f64>()
            / p.len() as f64;
        let a = (9.81 * (th.sin() - mu * th.cos())).max(0.0);
        (slide, 0.5 * a * 0.2 * 0.2)
    }

    #[test]
    fn coulomb_friction_holds_on_a_slope_below_tan_theta_and_slides_above() {
        let (held, _) = slide_on_slope(0.5);
        assert!(held.abs() < 2e-5, "slid {held} m at mu 0.5 > tan 20 deg");
        let (slid, expected) = slide_on_slope(0.2);
        assert!(
            (slid - expected).abs() < 0.03 * expected,
            "slid {slid} m, Coulomb {expected} m"
        );
    }

    /// Mean velocity along X (m/s) of a yarn along Z dropped from 5 mm
    /// onto the floor with friction 0.3 under gravity tilted so that
    /// tan = 0.5 (it slides), 30 ms after it lands; and Coulomb's answer:
    /// the landing takes `mu v_n` off the tangential speed, then the slide
    /// accelerates at `g (sin - mu cos)`.
    fn landing_speed() -> (f64, f64) {
        let (mu, g, h) = (0.3, 9.81, 5e-3);
        let th = 0.5f64.atan();
        let mut yarns = Yarns::new();
        let pts: Vec<Vec3> = (0..21).map(|i| [0.0, R + h, i as f64 * 1e-3]).collect();
        yarns.push_curve(&pts, false, R);
        let params = RodDynamicsParams {
            global_damping: 0.0,
            gravity: [g * th.sin(), -g * th.cos(), 0.0],
            ..RodDynamicsParams::default()
        };
        let t_land = (2.0 * h / (g * th.cos())).sqrt();
        let (d, st) = run(&yarns, params, vec![floor(mu)], t_land + 0.03);
        assert_eq!(st.collider_contacts, 21, "{st:?}");
        let v = (0..21).map(|i| d.velocity[3 * i]).sum::<f64>() / 21.0;
        let (vn, vt) = (g * th.cos() * t_land, g * th.sin() * t_land);
        let coulomb = vt - mu * vn + g * (th.sin() - mu * th.cos()) * 0.03;
        (v, coulomb)
    }

    #[test]
    fn a_landing_loses_mu_times_its_normal_speed_along_the_surface() {
        // The friction is lagged at a step's start, so the landing step
        // itself slides freely; but implicit Euler leaves the impact's
        // force in the penetration at its end, and the next step's
        // friction takes the impulse Coulomb asks for, one step late.
        let (v, coulomb) = landing_speed();
        assert!(
            (v - coulomb).abs() < 0.05 * coulomb,
            "{v} m/s after landing, Coulomb {coulomb} m/s"
        );
    }
}
