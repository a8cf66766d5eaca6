//! The time integrator: symplectic (semi-implicit) Euler with an adaptive
//! step (Leaf §3.1, Algorithm 1):
//!
//! `v <- (v + dt M^-1 f) / (1 + c dt)`, `x <- x + dt v`
//!
//! with `dt` the smallest of
//! * `max_dt` (Leaf's default 4e-4 s),
//! * the explicit stability limit `cfl * 2 / omega_i` per vertex, with
//!   `omega_i^2` a Gershgorin bound of the stiffness row (rods, static; contact,
//!   recomputed every step from f''), and `cfl * 2 m / c` for contact damping,
//! * the displacement bound of Leaf Eq. 2 / Appendix A: no vertex moves more
//!   than `eps * r` (points of a linear segment move by a convex combination of
//!   their ends' motion, so this bounds every point of every yarn),
//! * `eps * r / v_handle` for scripted handles.
//!
//! Why explicit: the yarn model is dominated by a stiff stretch term and a
//! contact barrier that changes every step; an implicit step would need a
//! sparse factorization per step whose pattern changes with the contacts.
//! The explicit step costs one force evaluation, parallelizes perfectly
//! (per-element kernels, per-vertex gathers) and the displacement bound is a
//! hard guarantee against pull-through; the stability limit is measured, not
//! assumed, so it holds at any stiffness (at the price of small steps at
//! realistic stiffness, as in HYLC Table 2: 4e-6 to 2e-5 s).

use std::time::Instant;

use rayon::prelude::*;

use super::colliders::{resolve, PointCollider};
use super::contact::ContactSet;
use super::damping::{damped_velocity, damping_dt_limit};
use super::handles::{Handle, HandleError};
use super::model::Model;
use super::params::YarnSimParams;
use super::rod::{bend, stretch};
use super::YarnSimError;
use crate::geom::vec3::{norm, sub};
use crate::geom::{Vec3, Yarns};
use crate::yarn::PeriodicTile;

/// Energy terms (J).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct EnergyTerms {
    pub stretch: f64,
    pub bend: f64,
    pub contact: f64,
    /// Kinetic energy (J); zero where only the potential was evaluated.
    pub kinetic: f64,
}

impl EnergyTerms {
    /// Internal potential energy: stretch + bend + contact.
    pub fn internal(&self) -> f64 {
        self.stretch + self.bend + self.contact
    }
}

/// Wall-clock timings (s) of one `advance` call.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Timings {
    pub contact_build_s: f64,
    pub forces_s: f64,
    pub integrate_s: f64,
    pub total_s: f64,
}

/// Statistics of one `advance` call.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct FrameStats {
    /// Time steps taken.
    pub steps: u64,
    /// Segment pairs in contact (closest distance < rA + rB) at the end.
    pub contact_pairs: usize,
    /// Candidate pairs in the reused list at the end.
    pub candidate_pairs: usize,
    /// Minimum over every step of the frame (and the final state) of the
    /// closest distance between contact-eligible segments / (rA + rB).
    pub min_distance_ratio: f64,
    /// Largest single-step vertex displacement (m).
    pub max_displacement: f64,
    /// Largest single-step displacement divided by the vertex radius.
    pub max_displacement_ratio: f64,
    /// Energies at the end of the frame.
    pub energy: EnergyTerms,
    /// Smallest and largest step taken in the frame (s).
    pub dt_min: f64,
    pub dt_max: f64,
    /// Contact pair list rebuilds.
    pub rebuilds: u64,
    pub timings: Timings,
}

/// What one step did.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct StepInfo {
    pub dt: f64,
    pub max_disp: f64,
    pub max_disp_ratio: f64,
    pub min_ratio: f64,
    pub residual: f64,
    pub kinetic: f64,
    pub active_pairs: usize,
    pub rebuilt: bool,
    pub t_build: f64,
    pub t_force: f64,
    pub t_update: f64,
}

/// Buffers of one force evaluation.
#[derive(Debug, Clone, Default)]
pub(crate) struct Workspace {
    seg_out: Vec<(f64, [Vec3; 2])>,
    hinge_out: Vec<(f64, [Vec3; 3])>,
    pub f: Vec<Vec3>,
    pub stiff: Vec<f64>,
    pub damp: Vec<f64>,
}

pub(crate) struct EvalSummary {
    pub energy: EnergyTerms,
    pub min_ratio: f64,
    pub active_pairs: usize,
}

/// Forces `-dE/dx` (+ contact damping when `v` is given) on the real
/// vertices, stiffness and damping bounds, energies, closest distance.
pub(crate) fn evaluate(
    model: &Model,
    params: &YarnSimParams,
    x: &[Vec3],
    v: Option<&[Vec3]>,
    contacts: &mut ContactSet,
    ws: &mut Workspace,
) -> EvalSummary {
    let n = model.n_real;
    ws.seg_out.resize(model.segs.len(), (0.0, [[0.0; 3]; 2]));
    ws.hinge_out
        .resize(model.hinges.len(), (0.0, [[0.0; 3]; 3]));
    ws.seg_out
        .par_iter_mut()
        .zip(model.segs.par_iter())
        .with_min_len(1024)
        .for_each(|(o, s)| *o = stretch(s, x));
    ws.hinge_out
        .par_iter_mut()
        .zip(model.hinges.par_iter())
        .with_min_len(1024)
        .for_each(|(o, h)| *o = bend(h, x));
    contacts.eval(
        model,
        x,
        v,
        params.contact_stiffness,
        params.contact_damping_normal,
        params.contact_damping_tangent,
    );
    ws.f.resize(n, [0.0; 3]);
    ws.stiff.resize(n, 0.0);
    ws.damp.resize(n, 0.0);
    let (seg_out, hinge_out) = (&ws.seg_out, &ws.hinge_out);
    ws.f.par_iter_mut()
        .zip(ws.stiff.par_iter_mut())
        .enumerate()
        .with_min_len(1024)
        .for_each(|(i, (f, k))| {
            let mut acc = [0.0; 3];
            for &s in model.seg_inc.row(i) {
                let g = seg_out[s as usize / 2].1[s as usize % 2];
                acc[0] += g[0];
                acc[1] += g[1];
                acc[2] += g[2];
            }
            for &s in model.hinge_inc.row(i) {
                let g = hinge_out[s as usize / 3].1[s as usize % 3];
                acc[0] += g[0];
                acc[1] += g[1];
                acc[2] += g[2];
            }
            *f = acc;
            *k = model.rod_stiffness[i];
        });
    ws.damp.iter_mut().for_each(|c| *c = 0.0);
    // Contact: scatter the pairs in contact (few, in pair order: deterministic).
    let mut energy = EnergyTerms::default();
    for o in &contacts.active {
        let p = &contacts.pairs[o.pair as usize];
        let (a, b) = (&model.csegs[p.a as usize], &model.csegs[p.b as usize]);
        for (k, e) in [a.v[0], a.v[1], b.v[0], b.v[1]].into_iter().enumerate() {
            let r = model.real_of(e);
            let g = o.f[k];
            let f = &mut ws.f[r];
            f[0] += g[0];
            f[1] += g[1];
            f[2] += g[2];
            ws.stiff[r] += o.stiff[k];
            ws.damp[r] += o.damp[k];
        }
        energy.contact += o.energy;
    }
    for o in seg_out {
        energy.stretch += o.0;
    }
    for o in hinge_out {
        energy.bend += o.0;
    }
    let min_ratio = contacts.min_ratio;
    let active = contacts.active.len();
    EvalSummary {
        energy,
        min_ratio,
        active_pairs: active,
    }
}

const FREE: u32 = u32::MAX;

/// The yarn-level simulator (free yarns or one periodic tile).
#[derive(Debug)]
pub struct YarnSim {
    pub(crate) model: Model,
    pub(crate) params: YarnSimParams,
    /// Extended positions and velocities (real vertices, then ghosts).
    pub(crate) x: Vec<Vec3>,
    pub(crate) v: Vec<Vec3>,
    pub(crate) contacts: ContactSet,
    ws: Workspace,
    handles: Vec<Handle>,
    /// Handle index per real vertex (FREE if none).
    pinned_by: Vec<u32>,
    /// Position of each handled vertex when its handle was attached.
    anchor: Vec<Vec3>,
    handle_speed: f64,
    colliders: Vec<Box<dyn PointCollider>>,
    time: f64,
    steps: u64,
    rest: Option<Yarns>,
    tile: Option<PeriodicTile>,
}

impl YarnSim {
    /// A simulator of `rest` (also the initial state, at rest).
    pub fn new(rest: &Yarns, params: YarnSimParams) -> Result<YarnSim, YarnSimError> {
        YarnSim::with_rest_length_scale(rest, params, None)
    }

    /// As [`YarnSim::new`], with per-segment rest-length factors (Leaf §6.1;
    /// segments in `Yarns::segments` order).
    pub fn with_rest_length_scale(
        rest: &Yarns,
        params: YarnSimParams,
        scale: Option<&[f64]>,
    ) -> Result<YarnSim, YarnSimError> {
        let model = Model::from_yarns(rest, &params, scale)?;
        let mut sim = YarnSim::from_model(model, params, rest.points.clone());
        sim.rest = Some(rest.clone());
        Ok(sim)
    }

    /// A simulator of one periodic tile with periodic boundary conditions
    /// (Leaf §5): the state is the tile's vertices; forces are those of the
    /// infinite tiling. Per-segment rest-length factors are in tile segment
    /// order: each curve's internal segments, then its connector to the next
    /// curve.
    pub fn new_periodic(
        tile: &PeriodicTile,
        params: YarnSimParams,
        scale: Option<&[f64]>,
    ) -> Result<YarnSim, YarnSimError> {
        let model = Model::from_tile(tile, &params, scale)?;
        let mut sim = YarnSim::from_model(model, params, tile.yarns.points.clone());
        sim.tile = Some(tile.clone());
        Ok(sim)
    }

    fn from_model(model: Model, params: YarnSimParams, real: Vec<Vec3>) -> YarnSim {
        let n = model.n_real;
        let mut x = real;
        x.resize(model.n_ext(), [0.0; 3]);
        model.update_ghosts(&mut x);
        let contacts = ContactSet {
            skin: params.contact_skin * model.r_min,
            ..ContactSet::default()
        };
        YarnSim {
            v: vec![[0.0; 3]; model.n_ext()],
            x,
            contacts,
            ws: Workspace::default(),
            handles: Vec::new(),
            pinned_by: vec![FREE; n],
            anchor: vec![[0.0; 3]; n],
            handle_speed: 0.0,
            colliders: Vec::new(),
            time: 0.0,
            steps: 0,
            rest: None,
            tile: None,
            model,
            params,
        }
    }

    /// Number of (real) vertices.
    pub fn num_vertices(&self) -> usize {
        self.model.n_real
    }

    /// Current positions (m).
    pub fn positions(&self) -> &[Vec3] {
        &self.x[..self.model.n_real]
    }

    /// Current velocities (m/s).
    pub fn velocities(&self) -> &[Vec3] {
        &self.v[..self.model.n_real]
    }

    /// Lumped vertex masses (kg).
    pub fn masses(&self) -> &[f64] {
        &self.model.mass
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The parameters.
    pub fn params(&self) -> &YarnSimParams {
        &self.params
    }

    /// The current state as yarns (non-periodic simulators) or as a tile.
    pub fn yarns(&self) -> Yarns {
        let src = self
            .rest
            .as_ref()
            .or(self.tile.as_ref().map(|t| &t.yarns))
            .expect("a simulator is built from yarns or a tile");
        let mut y = src.clone();
        y.points.copy_from_slice(self.positions());
        y
    }

    /// Sets the positions (m) of all vertices (handles keep their anchors).
    pub fn set_positions(&mut self, x: &[Vec3]) -> Result<(), YarnSimError> {
        let n = self.model.n_real;
        if x.len() != n {
            return Err(YarnSimError::Param {
                name: "positions",
                message: format!("{} positions for {n} vertices", x.len()),
            });
        }
        if let Some(i) = x.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(YarnSimError::Param {
                name: "positions",
                message: format!("vertex {i} is not finite"),
            });
        }
        self.x[..n].copy_from_slice(x);
        self.model.update_ghosts(&mut self.x);
        self.contacts.valid = false;
        Ok(())
    }

    /// Sets the velocities (m/s) of all vertices.
    pub fn set_velocities(&mut self, v: &[Vec3]) -> Result<(), YarnSimError> {
        let n = self.model.n_real;
        if v.len() != n || v.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(YarnSimError::Param {
                name: "velocities",
                message: format!("need {n} finite velocities"),
            });
        }
        self.v[..n].copy_from_slice(v);
        self.model.update_ghost_velocities(&mut self.v);
        Ok(())
    }

    /// Attaches a handle (pins or scripted motion) at the vertices' current
    /// positions; returns its index. A vertex belongs to at most one handle
    /// (the later one wins).
    pub fn add_handle(&mut self, handle: Handle) -> Result<usize, YarnSimError> {
        if self.model.lattice.is_some() {
            return Err(YarnSimError::Handle(HandleError::PeriodicTile));
        }
        handle
            .validate(self.model.n_real)
            .map_err(YarnSimError::Handle)?;
        let id = self.handles.len() as u32;
        let anchors: Vec<Vec3> = handle.vertices.iter().map(|&v| self.x[v]).collect();
        for (&v, &a) in handle.vertices.iter().zip(&anchors) {
            self.pinned_by[v] = id;
            self.anchor[v] = a;
            self.v[v] = [0.0; 3];
        }
        self.handle_speed = self.handle_speed.max(handle.max_speed(&anchors));
        self.handles.push(handle);
        Ok(id as usize)
    }

    /// Pins vertices where they are now; returns the handle index.
    pub fn pin(&mut self, vertices: &[usize]) -> Result<usize, YarnSimError> {
        self.add_handle(Handle::pin(vertices.to_vec()))
    }

    /// Whether a vertex is moved by a handle.
    pub fn is_handled(&self, v: usize) -> bool {
        self.pinned_by.get(v).is_some_and(|&h| h != FREE)
    }

    /// Adds a collider.
    pub fn add_collider(&mut self, c: Box<dyn PointCollider>) {
        self.colliders.push(c);
    }

    fn fresh_eval(&self, with_velocity: bool) -> (EvalSummary, Workspace) {
        let mut cs = ContactSet {
            skin: self.contacts.skin,
            ..ContactSet::default()
        };
        cs.build(&self.model, &self.x);
        let mut ws = Workspace::default();
        let v = with_velocity.then_some(&self.v[..]);
        let s = evaluate(&self.model, &self.params, &self.x, v, &mut cs, &mut ws);
        (s, ws)
    }

    /// Internal potential energy (J): stretch + bend + contact (per tile for
    /// a periodic simulator).
    pub fn energy(&self) -> f64 {
        self.fresh_eval(false).0.energy.internal()
    }

    /// Energy terms including kinetic energy.
    pub fn energy_terms(&self) -> EnergyTerms {
        let mut e = self.fresh_eval(false).0.energy;
        e.kinetic = self.kinetic();
        e
    }

    /// Internal conservative forces `-dE/dx` (N) on every vertex (no damping,
    /// no gravity, no handles).
    pub fn forces(&self) -> Vec<Vec3> {
        self.fresh_eval(false).1.f
    }

    /// Forces including contact damping at the current velocities.
    pub fn forces_with_damping(&self) -> Vec<Vec3> {
        self.fresh_eval(true).1.f
    }

    /// Closest distance between contact-eligible segments over the sum of
    /// their radii, now.
    pub fn min_distance_ratio(&self) -> f64 {
        self.fresh_eval(false).0.min_ratio
    }

    fn kinetic(&self) -> f64 {
        let mut k = 0.0;
        for (m, v) in self.model.mass.iter().zip(&self.v) {
            k += 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        }
        k
    }

    fn diverged(&self, vertex: usize, reason: String) -> YarnSimError {
        YarnSimError::Diverged {
            step: self.steps + 1,
            time: self.time,
            vertex,
            reason,
        }
    }

    /// One time step of at most `dt_cap` seconds.
    pub(crate) fn step(&mut self, dt_cap: f64) -> Result<StepInfo, YarnSimError> {
        let t0 = Instant::now();
        let mut rebuilt = false;
        if !self.contacts.valid || self.contacts.acc_motion >= self.contacts.skin {
            self.contacts.build(&self.model, &self.x);
            rebuilt = true;
        }
        let t1 = Instant::now();
        let summary = evaluate(
            &self.model,
            &self.params,
            &self.x,
            Some(&self.v),
            &mut self.contacts,
            &mut self.ws,
        );
        let t2 = Instant::now();
        let n = self.model.n_real;
        let p = &self.params;
        let eps = p.max_step_displacement;
        let g = p.gravity;
        let (mass, radius) = (&self.model.mass, &self.model.radius);
        let (f, stiff, damp) = (&self.ws.f, &self.ws.stiff, &self.ws.damp);
        let pinned_by = &self.pinned_by;
        let v = &self.v;
        // Per-vertex step bound and residual (deterministic min/max reductions).
        let (dt_bound, worst, residual, bad) = (0..n)
            .into_par_iter()
            .with_min_len(1024)
            .map(|i| {
                if pinned_by[i] != FREE {
                    return (f64::INFINITY, i, 0.0, usize::MAX);
                }
                let m = mass[i];
                let fi = f[i];
                let fnorm = norm(fi);
                let a = [fi[0] / m + g[0], fi[1] / m + g[1], fi[2] / m + g[2]];
                let an = norm(a);
                let vn = norm(v[i]);
                if !(an.is_finite() && vn.is_finite()) {
                    return (0.0, i, f64::INFINITY, i);
                }
                let dt_cfl = p.cfl * 2.0 / (stiff[i] / m).sqrt();
                let dt_damp = p.cfl * damping_dt_limit(m, damp[i]);
                let er = eps * radius[i];
                let dt_leaf = if an > 0.0 {
                    (-vn + (vn * vn + 4.0 * er * an).sqrt()) / (2.0 * an)
                } else if vn > 0.0 {
                    er / vn
                } else {
                    f64::INFINITY
                };
                (dt_cfl.min(dt_damp).min(dt_leaf), i, fnorm, usize::MAX)
            })
            .reduce(
                || (f64::INFINITY, usize::MAX, 0.0, usize::MAX),
                |a, b| {
                    let (dt, w) = if (b.0, b.1) < (a.0, a.1) {
                        (b.0, b.1)
                    } else {
                        (a.0, a.1)
                    };
                    (dt, w, a.2.max(b.2), a.3.min(b.3))
                },
            );
        if bad != usize::MAX {
            return Err(self.diverged(bad, "non-finite force or velocity".into()));
        }
        let e_int = summary.energy.internal();
        if !e_int.is_finite() || e_int > p.max_energy_per_vertex * n as f64 {
            let w = worst_force(&self.ws.f, mass);
            return Err(self.diverged(
                w,
                format!(
                    "energy blow-up: internal energy {e_int:e} J exceeds {:e} J per vertex",
                    p.max_energy_per_vertex
                ),
            ));
        }
        let mut dt = dt_cap.min(p.max_dt).min(dt_bound);
        if self.handle_speed > 0.0 {
            dt = dt.min(eps * self.model.r_min / self.handle_speed);
        }
        if !(dt >= p.min_dt) {
            return Err(self.diverged(
                worst.min(n.saturating_sub(1)),
                format!(
                    "time step bound {dt:e} s fell below min_dt {:e} s (stiffness or speed blow-up)",
                    p.min_dt
                ),
            ));
        }
        let t_new = self.time + dt;
        let c_global = p.global_damping;
        let handles = &self.handles;
        let anchor = &self.anchor;
        let colliders = &self.colliders;
        let (xr, vr) = (&mut self.x[..n], &mut self.v[..n]);
        let (max_disp, max_ratio, worst_speed) = xr
            .par_iter_mut()
            .zip(vr.par_iter_mut())
            .enumerate()
            .with_min_len(1024)
            .map(|(i, (x, v))| {
                let old = *x;
                if pinned_by[i] != FREE {
                    let h = &handles[pinned_by[i] as usize];
                    let nx = h.position(anchor[i], t_new);
                    *v = [
                        (nx[0] - old[0]) / dt,
                        (nx[1] - old[1]) / dt,
                        (nx[2] - old[2]) / dt,
                    ];
                    *x = nx;
                } else {
                    let m = mass[i];
                    let fi = f[i];
                    let a = [fi[0] / m + g[0], fi[1] / m + g[1], fi[2] / m + g[2]];
                    *v = damped_velocity(*v, a, dt, c_global);
                    *x = [x[0] + dt * v[0], x[1] + dt * v[1], x[2] + dt * v[2]];
                    for c in colliders {
                        resolve(c.as_ref(), x, v, radius[i], t_new, dt);
                    }
                }
                let d = norm(sub(*x, old));
                let speed = norm(*v);
                let s = if speed.is_finite() && x.iter().all(|c| c.is_finite()) {
                    speed
                } else {
                    f64::INFINITY
                };
                (d, d / radius[i], (s, i))
            })
            .reduce(
                || (0.0, 0.0, (0.0, usize::MAX)),
                |a, b| {
                    let ws = if b.2 .0 > a.2 .0 || (b.2 .0 == a.2 .0 && b.2 .1 < a.2 .1) {
                        b.2
                    } else {
                        a.2
                    };
                    (a.0.max(b.0), a.1.max(b.1), ws)
                },
            );
        if !(worst_speed.0 <= p.max_speed) {
            let reason = if worst_speed.0.is_finite() {
                format!(
                    "speed {:e} m/s exceeds max_speed {:e} m/s",
                    worst_speed.0, p.max_speed
                )
            } else {
                "non-finite position or velocity".into()
            };
            return Err(self.diverged(worst_speed.1, reason));
        }
        self.model.update_ghosts(&mut self.x);
        self.model.update_ghost_velocities(&mut self.v);
        self.contacts.acc_motion += max_disp;
        self.time = t_new;
        self.steps += 1;
        let kinetic = self.kinetic();
        let t3 = Instant::now();
        Ok(StepInfo {
            dt,
            max_disp,
            max_disp_ratio: max_ratio,
            min_ratio: summary.min_ratio,
            residual,
            kinetic,
            active_pairs: summary.active_pairs,
            rebuilt,
            t_build: (t1 - t0).as_secs_f64(),
            t_force: (t2 - t1).as_secs_f64(),
            t_update: (t3 - t2).as_secs_f64(),
        })
    }

    /// Advances the simulation by `frame_dt` seconds in as many steps as the
    /// step bounds require.
    pub fn advance(&mut self, frame_dt: f64) -> Result<FrameStats, YarnSimError> {
        if !(frame_dt > 0.0 && frame_dt.is_finite()) {
            return Err(YarnSimError::Param {
                name: "frame_dt",
                message: format!("{frame_dt} is not a positive finite time"),
            });
        }
        let start = Instant::now();
        let t_end = self.time + frame_dt;
        let mut st = FrameStats {
            min_distance_ratio: f64::INFINITY,
            dt_min: f64::INFINITY,
            ..FrameStats::default()
        };
        let mut n_steps = 0u64;
        while t_end - self.time > self.params.min_dt {
            if n_steps >= self.params.max_steps_per_advance {
                return Err(self.diverged(
                    0,
                    format!(
                        "step budget of {} steps per advance exhausted at t = {} s",
                        n_steps, self.time
                    ),
                ));
            }
            let info = self.step(t_end - self.time)?;
            n_steps += 1;
            st.min_distance_ratio = st.min_distance_ratio.min(info.min_ratio);
            st.max_displacement = st.max_displacement.max(info.max_disp);
            st.max_displacement_ratio = st.max_displacement_ratio.max(info.max_disp_ratio);
            st.dt_min = st.dt_min.min(info.dt);
            st.dt_max = st.dt_max.max(info.dt);
            st.rebuilds += info.rebuilt as u64;
            st.timings.contact_build_s += info.t_build;
            st.timings.forces_s += info.t_force;
            st.timings.integrate_s += info.t_update;
        }
        self.time = self.time.max(t_end);
        // Measure the final state too.
        let t0 = Instant::now();
        if !self.contacts.valid || self.contacts.acc_motion >= self.contacts.skin {
            self.contacts.build(&self.model, &self.x);
            st.rebuilds += 1;
        }
        let s = evaluate(
            &self.model,
            &self.params,
            &self.x,
            None,
            &mut self.contacts,
            &mut self.ws,
        );
        st.timings.forces_s += t0.elapsed().as_secs_f64();
        st.min_distance_ratio = st.min_distance_ratio.min(s.min_ratio);
        st.steps = n_steps;
        st.contact_pairs = s.active_pairs;
        st.candidate_pairs = self.contacts.pairs.len();
        st.energy = s.energy;
        st.energy.kinetic = self.kinetic();
        st.timings.total_s = start.elapsed().as_secs_f64();
        Ok(st)
    }
}

fn worst_force(f: &[Vec3], m: &[f64]) -> usize {
    let mut w = 0;
    let mut best = -1.0;
    for (i, (fi, mi)) in f.iter().zip(m).enumerate() {
        let a = norm(*fi) / mi;
        if !a.is_finite() {
            return i;
        }
        if a > best {
            best = a;
            w = i;
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_respects_displacement_and_stability_bounds() {
        let y = crate::yarn::sim::plain_weave_swatch(4, 1.6e-3, 0.39e-3, 5, 4e-4);
        let mut sim = YarnSim::new(&y, YarnSimParams::default()).unwrap();
        // Contact is active at the start: it raises the stiffness bound.
        sim.step(1.0).unwrap();
        assert!((0..sim.model.n_real).any(|i| sim.ws.stiff[i] > sim.model.rod_stiffness[i]));
        let mut dt_prev = 0.0;
        for _ in 0..50 {
            let info = sim.step(1.0).unwrap();
            assert!(info.max_disp_ratio <= sim.params.max_step_displacement * (1.0 + 1e-12));
            assert!(info.dt > 0.0 && info.dt <= sim.params.max_dt);
            dt_prev = info.dt;
        }
        // The bound in force: below the rod-only explicit limit.
        let mut rod_limit = f64::INFINITY;
        for i in 0..sim.model.n_real {
            let m = sim.model.mass[i];
            rod_limit =
                rod_limit.min(sim.params.cfl * 2.0 / (sim.model.rod_stiffness[i] / m).sqrt());
        }
        assert!(
            dt_prev <= rod_limit * (1.0 + 1e-12),
            "{dt_prev} > {rod_limit}"
        );
    }

    #[test]
    fn handles_follow_their_motion_exactly() {
        let y = crate::yarn::sim::plain_weave_swatch(2, 1.6e-3, 0.5e-3, 5, 4e-4);
        let mut sim = YarnSim::new(&y, YarnSimParams::default()).unwrap();
        let p0 = y.points[0];
        sim.add_handle(Handle::translate(vec![0], [0.1, 0.0, 0.0]))
            .unwrap();
        sim.pin(&[3]).unwrap();
        sim.advance(1e-4).unwrap();
        let p = sim.positions()[0];
        assert!((p[0] - (p0[0] + 1e-5)).abs() < 1e-12);
        assert_eq!(sim.positions()[3], y.points[3]);
        assert!(sim.is_handled(0) && !sim.is_handled(1));
    }
}
