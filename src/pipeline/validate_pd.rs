//! `validate`'s homogenized run by projective dynamics ([`crate::sim::pd`]):
//! the integrator `simulate` uses in production (VH §7, Eq. 25-28, contacts
//! as projection constraints VH §8.5), so the fidelity and speed figures are
//! those of the shots an artist runs.
//!
//! Time: each frame interval is split into equal implicit-Euler steps of at
//! most [`PdRunParams::max_dt`] (VH Table 1: 1/150 s). Damping: the scene's
//! yarn-level global damping (mass-proportional, implicit, the same form as
//! the yarn simulator's). Pins: the four nodes of every tet holding a
//! clamped yarn vertex follow that vertex's band map at the step's time.
//!
//! Contacts ([`ContactAt`]): the scene's colliders (plane, sphere,
//! character; the yarn-level objects with their friction coefficients and
//! surface velocities) act where the yarn level applies them, on the yarn
//! vertices: each V2Y yarn vertex (VH Eq. 4) keeps its radius from the
//! collider, with its own depth, slip and Coulomb cone, and its contact
//! and friction forces reach the tet nodes through its embedding weights
//! ([`crate::sim::contact`], "Contacts at embedded points"; the vertices
//! carry the yarn mass by their segments, scaled to the nodes' total).
//!
//! With [`ContactAt::Nodes`] the colliders project the free tet nodes
//! instead, so that the yarns the nodes carry keep their radius from the
//! collider. Node `i` carries the yarn vertices embedded in its tets (its
//! star); with `o_v = y_v - x_i` their offsets at the start of the step
//! and `n` the collider's outward normal, the node keeps the directional
//! thickness `max_v (r_v - o_v · n)`. For a plane this is exact and
//! conservative: when the four nodes of a yarn vertex's tet satisfy their
//! constraints, `φ(y_v) = Σ_a w_a φ(x_a) >= Σ_a w_a (r_v - o_{v,a} · n) =
//! r_v`, since `Σ_a w_a o_{v,a} = 0`. Normal force and friction then act at
//! the nodes, up to half a voxel from the yarns, and the conservative
//! thickness holds the fabric off the collider where a node's star spans
//! yarns at several heights.

use std::sync::Arc;

use crate::geom::vec3::{dot, sub};
use crate::geom::{Asset, Vec3};
use crate::sim::contact::{Contact, EmbeddedPoints, NodeProjector, PointProjector};
use crate::sim::pd::{PdParams, PdSolver};
use crate::sim::SimError;
use crate::yarn::sim::PointCollider;

use super::sim_scene::{BackendChoice, SolverChoice};
use super::simulate::{attach_backend, global_solver, SimulateError};

/// Why a homogenized run of `validate` failed.
#[derive(Debug, thiserror::Error)]
pub enum HomogenizedRunError {
    /// The simulator refused the material, the mesh or the pins.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The PD solver could not be put on the asked backend.
    #[error(transparent)]
    Backend(#[from] SimulateError),
    /// The largest PD step (s) is not a positive finite time.
    #[error("PD step {} s must be finite and > 0", crate::geom::num(*max_dt))]
    BadStep { max_dt: f64 },
    /// The scene needs more PD steps than a run may take.
    #[error("a PD step of {} s needs {} steps over the scene, more than the limit of {limit}", crate::geom::num(*max_dt), crate::geom::num(*steps))]
    TooManySteps {
        max_dt: f64,
        steps: f64,
        limit: usize,
    },
    /// A PD step of frame `frame` (ending at `time`, s) failed.
    #[error("frame {frame} (t = {time} s): {source}")]
    PdStep {
        frame: usize,
        time: f64,
        source: SimError,
    },
    /// The Newton solves of frame `frame` (ending at `time`, s) failed even
    /// in `substeps` backward-Euler substeps.
    #[error("frame {frame} (t = {time} s, {substeps} substeps): {source}")]
    NewtonFrame {
        frame: usize,
        time: f64,
        substeps: usize,
        source: SimError,
    },
}

/// What a homogenized run of `validate` ([`super::validate::homogenized_run`])
/// computed, by Newton or by PD.
#[derive(Debug, Clone)]
pub struct HomogenizedRun {
    /// Node positions per frame (m); frame 0 is the rest state.
    pub frames: Vec<Vec<Vec3>>,
    /// Newton iterations, or PD iterations (global solves).
    pub iterations: u64,
    /// Deepest penetration of a yarn vertex into a collider (m).
    pub max_penetration_m: f64,
    /// Most contacts in one frame (Newton: yarn vertices within their
    /// radius of a collider; PD: yarn vertices, or with node contacts free
    /// tet nodes, with an active contact constraint in a step).
    pub max_contacts: usize,
    /// Most backward-Euler substeps a frame needed (1: none); for PD the
    /// implicit-Euler steps per frame.
    pub substeps: usize,
    /// Implicit-Euler steps taken in all.
    pub steps: u64,
    /// PD only (else 0): steps that ran all their iterations without
    /// meeting the tolerance, and the largest end-of-step residual over
    /// the run (N, the largest `|∇Φ|` over free nodes, [`crate::sim::pd::StepStats::residual`]).
    pub capped_steps: u64,
    pub max_residual_n: f64,
    /// PD only (else 0): the largest end-of-step convergence measure
    /// ([`crate::sim::pd::StepStats::convergence`], against the tolerance).
    pub max_convergence: f64,
    /// PD only (else 0): the PD tolerance of the steps.
    pub tolerance: f64,
    /// PD only (else 0): wall time of the local steps and of the global
    /// solves summed over the run (s), and the contact CG iterations of the
    /// global solves and the refactorizations of `K + W`.
    pub local_s: f64,
    pub global_s: f64,
    pub contact_cg_iterations: u64,
    pub contact_refactors: u64,
    /// PD only: local steps evaluated and Anderson iterates rejected
    /// ([`super::validate::ValidateReport::pd_local_steps`]).
    pub local_steps: u64,
    pub accelerations_rejected: u64,
    /// PD only: the local step's backend ("cpu", "gpu") and the global
    /// solver ("direct", "dd"); "" for Newton.
    pub backend: &'static str,
    pub global_solver: &'static str,
}

impl HomogenizedRun {
    /// A run holding only its rest frame `nodes`.
    pub fn at_rest(nodes: &[Vec3]) -> HomogenizedRun {
        HomogenizedRun {
            frames: vec![nodes.to_vec()],
            iterations: 0,
            max_penetration_m: 0.0,
            max_contacts: 0,
            substeps: 1,
            steps: 0,
            capped_steps: 0,
            max_residual_n: 0.0,
            max_convergence: 0.0,
            tolerance: 0.0,
            local_s: 0.0,
            global_s: 0.0,
            contact_cg_iterations: 0,
            contact_refactors: 0,
            local_steps: 0,
            accelerations_rejected: 0,
            backend: "",
            global_solver: "",
        }
    }
}

/// Parameters of [`pd_frames`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdRunParams {
    /// Longest implicit-Euler step (s); frame intervals are split into equal
    /// steps no longer. Default: `PdParams::default().dt` (1/150 s, VH
    /// Table 1).
    pub max_dt: f64,
    /// Mass-proportional damping `c` (1/s), as the yarn-level global
    /// damping. Default 0 (the caller passes the scene's).
    pub mass_damping: f64,
    /// PD iterations per step. Default: `PdParams::default().max_iterations`.
    pub iterations: u32,
    /// Where the local step (and the DD Jacobi iterations) run. Default
    /// `Auto`: a hardware GPU when there is one, as `simulate`.
    pub backend: BackendChoice,
    /// The global solver. Default direct (sparse Cholesky).
    pub global: SolverChoice,
    /// What the colliders act on. Default [`ContactAt::Yarns`].
    pub contact: ContactAt,
    /// Stiffness-proportional damping `β` (s) of the homogenized material
    /// ([`PdParams::stiffness_damping`]). Default 0.
    pub stiffness_damping: f64,
}

/// Where the homogenized run's colliders act (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ContactAt {
    /// At the V2Y yarn vertices, each keeping its radius, the forces
    /// reaching the nodes through the embedding weights (as the yarn level
    /// applies them).
    #[default]
    Yarns,
    /// At the free tet nodes, each keeping its directional thickness.
    Nodes,
}

impl ContactAt {
    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ContactAt::Yarns => "yarns",
            ContactAt::Nodes => "nodes",
        }
    }
}

impl Default for PdRunParams {
    fn default() -> Self {
        let d = PdParams::default();
        PdRunParams {
            max_dt: d.dt,
            mass_damping: 0.0,
            iterations: d.max_iterations,
            backend: BackendChoice::default(),
            global: SolverChoice::default(),
            contact: ContactAt::default(),
            stiffness_damping: 0.0,
        }
    }
}

/// Passes over the colliders per projection: a node pushed out of one
/// collider into another is corrected by the next pass.
const PROJECTION_PASSES: usize = 3;

/// The yarn vertices embedded in each node's tets (module doc), as CSR.
struct NodeStars {
    start: Vec<usize>,
    verts: Vec<usize>,
}

impl NodeStars {
    fn new(asset: &Asset) -> NodeStars {
        let mesh = &asset.mesh;
        let mut count = vec![0usize; mesh.num_nodes() + 1];
        for &t in &asset.embedding.tet {
            for &i in &mesh.tets[t as usize] {
                count[i as usize + 1] += 1;
            }
        }
        for i in 0..mesh.num_nodes() {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut verts = vec![0; count[mesh.num_nodes()]];
        for (v, &t) in asset.embedding.tet.iter().enumerate() {
            for &i in &mesh.tets[t as usize] {
                verts[fill[i as usize]] = v;
                fill[i as usize] += 1;
            }
        }
        NodeStars {
            start: count,
            verts,
        }
    }
    fn of(&self, node: usize) -> &[usize] {
        &self.verts[self.start[node]..self.start[node + 1]]
    }
}

/// The yarn-level colliders at one step's end time, projecting tet nodes by
/// their directional thickness (module doc).
struct YarnColliders<'a> {
    colliders: &'a [Arc<dyn PointCollider>],
    stars: &'a NodeStars,
    radius: &'a [f64],
    /// Node positions and V2Y yarn vertices at the start of the step (m).
    x0: &'a [Vec3],
    y0: &'a [Vec3],
    /// Per node, the largest yarn radius and offset length `|o_v|` over its
    /// star (m): its thickness along a normal `n` is at most `r + o |n|`, so
    /// a node at least that far outside a collider cannot touch it and its
    /// star is not walked.
    reach: &'a [[f64; 2]],
    /// End time of the step (s) and its length (s).
    t: f64,
    dt: f64,
}

/// [`YarnColliders::reach`] of every node for node positions `x0` and V2Y
/// yarn vertices `y0` (zeros for a node that carries no yarn vertex).
fn node_reach(stars: &NodeStars, radius: &[f64], x0: &[Vec3], y0: &[Vec3]) -> Vec<[f64; 2]> {
    (0..x0.len())
        .map(|i| {
            stars.of(i).iter().fold([0.0f64; 2], |[r, o], &v| {
                let d = sub(y0[v], x0[i]);
                [r.max(radius[v]), o.max(dot(d, d).sqrt())]
            })
        })
        .collect()
}

impl YarnColliders<'_> {
    /// Distance (m) node `node` keeps from a surface with outward normal `n`.
    fn thickness(&self, node: usize, n: Vec3) -> f64 {
        let x = self.x0[node];
        let star = self.stars.of(node);
        if star.is_empty() {
            return 0.0;
        }
        star.iter()
            .map(|&v| self.radius[v] - dot(sub(self.y0[v], x), n))
            .fold(f64::NEG_INFINITY, f64::max)
    }
}

impl NodeProjector for YarnColliders<'_> {
    fn project(&self, node: usize, p: Vec3) -> Option<Vec3> {
        self.contact(node, p).map(|c| c.target)
    }
    fn contact(&self, node: usize, p: Vec3) -> Option<Contact> {
        push_out(self.colliders, p, self.t, self.dt, |d, n| {
            // Far outside (the common case): the thickness cannot reach.
            // (`reach` is empty without colliders: index inside the call.)
            let [rm, om] = self.reach[node];
            if d >= rm + om * dot(n, n).sqrt() {
                return None;
            }
            let r = self.thickness(node, n);
            (d.is_finite() && r.is_finite() && d < r).then_some(r)
        })
    }
}

/// Pushes `p` out of `colliders` at time `t` (a step of `dt` s): over
/// [`PROJECTION_PASSES`] passes, every collider at signed distance `d`
/// with outward normal `n` for which `keep(d, n)` gives a distance moves
/// the point along `n` to it. The contact of the last collider that moved
/// it, None when none did.
fn push_out(
    colliders: &[Arc<dyn PointCollider>],
    p: Vec3,
    t: f64,
    dt: f64,
    keep: impl Fn(f64, Vec3) -> Option<f64>,
) -> Option<Contact> {
    let mut q = p;
    let mut hit: Option<&Arc<dyn PointCollider>> = None;
    for _ in 0..PROJECTION_PASSES {
        let mut moved = false;
        for c in colliders {
            let (d, n) = c.signed_distance(q, t);
            if let Some(r) = keep(d, n) {
                q = std::array::from_fn(|k| q[k] + (r - d) * n[k]);
                hit = Some(c);
                moved = true;
            }
        }
        if !moved {
            break;
        }
    }
    hit.map(|c| {
        let u = c.velocity(q, t);
        Contact {
            target: q,
            surface_motion: u.map(|u| u * dt),
            friction: c.friction(),
        }
    })
}

/// The yarn-level colliders at one step's end time, each V2Y yarn vertex
/// keeping its radius (module doc).
struct YarnVertexColliders<'a> {
    colliders: &'a [Arc<dyn PointCollider>],
    radius: &'a [f64],
    /// End time of the step (s) and its length (s).
    t: f64,
    dt: f64,
}

impl PointProjector for YarnVertexColliders<'_> {
    fn contact(&self, point: usize, p: Vec3) -> Option<Contact> {
        let r = self.radius[point];
        push_out(self.colliders, p, self.t, self.dt, |d, _| {
            (d.is_finite() && d < r).then_some(r)
        })
    }
}

/// Deepest penetration (m, >= 0) of a V2Y yarn vertex into its radius
/// around a collider at `t` (the Newton run's measure).
fn yarn_penetration(
    asset: &Asset,
    colliders: &[Arc<dyn PointCollider>],
    t: f64,
    x: &[Vec3],
) -> f64 {
    let y = asset.embedding.v2y(&asset.mesh, x);
    let mut depth = 0.0f64;
    for (v, p) in y.iter().enumerate() {
        let r = asset.rest_yarns.radius_at(v);
        for c in colliders {
            depth = depth.max(r - c.signed_distance(*p, t).0);
        }
    }
    depth
}

/// Puts `solver` on `backend` (see [`attach_backend`]).
fn run_backend(solver: &mut PdSolver, backend: BackendChoice) -> Result<(), SimulateError> {
    attach_backend(solver, backend).map(|_| ())
}

/// Homogenized frames at `times` (s; `times[0]` is the rest state) by PD
/// under `gravity` (m/s²) and `colliders`; the nodes in `pinned` follow
/// `target(node, t)`. Pure.
#[allow(clippy::too_many_arguments)]
pub fn pd_frames(
    asset: &Asset,
    gamma: &crate::fit::elastic::MaterialFields,
    pinned: &[usize],
    target: &dyn Fn(usize, f64) -> Vec3,
    gravity: Vec3,
    times: &[f64],
    colliders: &[Arc<dyn PointCollider>],
    params: &PdRunParams,
) -> Result<HomogenizedRun, HomogenizedRunError> {
    if !(params.max_dt > 0.0 && params.max_dt.is_finite()) {
        return Err(HomogenizedRunError::BadStep {
            max_dt: params.max_dt,
        });
    }
    let mesh = &asset.mesh;
    let steps_of = |t0: f64, t1: f64| ((t1 - t0) / params.max_dt - 1e-9).ceil().max(1.0) as usize;
    // Bounded before running, as `simulate` bounds its shots.
    let total: f64 = times.windows(2).map(|w| steps_of(w[0], w[1]) as f64).sum();
    if !(total <= super::simulate::MAX_TOTAL_STEPS as f64) {
        return Err(HomogenizedRunError::TooManySteps {
            max_dt: params.max_dt,
            steps: total,
            limit: super::simulate::MAX_TOTAL_STEPS,
        });
    }
    let first_dt = match times {
        [t0, t1, ..] => (t1 - t0) / steps_of(*t0, *t1) as f64,
        _ => params.max_dt,
    };
    let pd = PdParams {
        dt: first_dt,
        gravity,
        mass_damping: params.mass_damping,
        stiffness_damping: params.stiffness_damping,
        max_iterations: params.iterations,
        // The end-of-step residual tells how far each step is from the
        // exact implicit-Euler solution (one more gradient per step).
        report_residual: true,
        global: global_solver(params.global),
        ..PdParams::default()
    };
    let model = gamma.model(mesh)?;
    let mut solver = PdSolver::with_model(mesh, model, &asset.node_mass, pinned, pd, None)?;
    run_backend(&mut solver, params.backend)?;
    let stars = NodeStars::new(asset);
    let points = if params.contact == ContactAt::Yarns && !colliders.is_empty() {
        super::asset::yarn_contact_points(asset)
    } else {
        EmbeddedPoints::default()
    };
    let radius: Vec<f64> = (0..asset.rest_yarns.num_points())
        .map(|v| asset.rest_yarns.radius_at(v))
        .collect();
    let mut run = HomogenizedRun::at_rest(&mesh.nodes);
    run.backend = solver.backend_names().0;
    run.tolerance = pd.tolerance;
    run.global_solver = solver.params().global.name();
    let mut x = mesh.nodes.clone();
    let mut v = vec![[0.0; 3]; mesh.num_nodes()];
    let mut dt_now = first_dt;
    for k in 1..times.len() {
        let (t0, t1) = (times[k - 1], times[k]);
        let sub = steps_of(t0, t1);
        let dt = (t1 - t0) / sub as f64;
        if (dt - dt_now).abs() > 1e-12 * dt_now {
            solver.set_time_step(dt, params.mass_damping)?;
            // A new time step puts the solver back on the CPU.
            run_backend(&mut solver, params.backend)?;
            dt_now = dt;
        }
        for j in 1..=sub {
            let t = t0 + dt * j as f64;
            let pins: Vec<Vec3> = pinned.iter().map(|&i| target(i, t)).collect();
            let x0 = x.clone();
            let (y0, reach) = if colliders.is_empty() || params.contact == ContactAt::Yarns {
                (Vec::new(), Vec::new())
            } else {
                let y0 = asset.embedding.v2y(mesh, &x0);
                let reach = node_reach(&stars, &radius, &x0, &y0);
                (y0, reach)
            };
            let st = if colliders.is_empty() {
                solver.step(&mut x, &mut v, &pins)
            } else if params.contact == ContactAt::Yarns {
                let proj = YarnVertexColliders {
                    colliders,
                    radius: &radius,
                    t,
                    dt,
                };
                solver.step_with_point_contacts(&mut x, &mut v, &pins, &points, &proj)
            } else {
                let proj = YarnColliders {
                    colliders,
                    stars: &stars,
                    radius: &radius,
                    x0: &x0,
                    y0: &y0,
                    reach: &reach,
                    t,
                    dt,
                };
                solver.step_with_contacts(&mut x, &mut v, &pins, &proj)
            }
            .map_err(|source| HomogenizedRunError::PdStep {
                frame: k,
                time: t,
                source,
            })?;
            run.iterations += st.iterations as u64;
            run.steps += 1;
            run.capped_steps += u64::from(st.capped);
            run.max_convergence = run.max_convergence.max(st.convergence);
            if st.residual.is_finite() {
                run.max_residual_n = run.max_residual_n.max(st.residual);
            }
            run.local_s += st.local_ms * 1e-3;
            run.global_s += st.global_ms * 1e-3;
            run.contact_cg_iterations += st.global_iterations as u64;
            run.contact_refactors += u64::from(st.contact_refactors);
            run.local_steps += u64::from(st.local_steps());
            run.accelerations_rejected += u64::from(st.accelerations_rejected);
            run.max_contacts = run.max_contacts.max(st.contacts);
        }
        if !colliders.is_empty() {
            let depth = yarn_penetration(asset, colliders, t1, &x);
            run.max_penetration_m = run.max_penetration_m.max(depth);
        }
        run.substeps = run.substeps.max(sub);
        run.frames.push(x.clone());
    }
    Ok(run)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::sim::SphereCollider;

    /// Skipping nodes by their reach changes no contact: every node's
    /// projection equals the one with the full star walk (reach infinite),
    /// for nodes inside, near and far outside a sphere.
    #[test]
    fn culling_by_reach_changes_no_contact() {
        let sphere: Arc<dyn PointCollider> = Arc::new(SphereCollider {
            center: [0.0, 0.0, 0.0],
            radius: 0.04,
            velocity: [0.0, 0.1, 0.0],
            friction: 0.5,
        });
        let colliders = [sphere];
        // Node i sits on the x axis at 40 mm + (i - 10) mm; its star holds
        // three yarn vertices offset by up to 3 mm, radii 0.8-1.2 mm.
        let n = 40;
        let x0: Vec<Vec3> = (0..n)
            .map(|i| [0.04 + 1e-3 * (i as f64 - 10.0), 0.0, 0.0])
            .collect();
        let offsets = [[-3e-3, 0.0, 0.0], [0.0, 2e-3, 1e-3], [1e-3, -1e-3, 0.0]];
        let mut y0 = Vec::new();
        let mut radius = Vec::new();
        for x in &x0 {
            for (k, o) in offsets.iter().enumerate() {
                y0.push(std::array::from_fn(|j| x[j] + o[j]));
                radius.push(8e-4 + 2e-4 * k as f64);
            }
        }
        let stars = NodeStars {
            start: (0..=n).map(|i| 3 * i).collect(),
            verts: (0..3 * n).collect(),
        };
        let reach = node_reach(&stars, &radius, &x0, &y0);
        let unbounded = vec![[f64::INFINITY; 2]; n];
        let culled = YarnColliders {
            colliders: &colliders,
            stars: &stars,
            radius: &radius,
            x0: &x0,
            y0: &y0,
            reach: &reach,
            t: 0.0,
            dt: 1.0 / 150.0,
        };
        let full = YarnColliders {
            reach: &unbounded,
            ..culled
        };
        let mut touching = 0;
        let mut skipped = 0;
        for (i, &p) in x0.iter().enumerate() {
            let c = culled.contact(i, p);
            assert_eq!(c, full.contact(i, p), "node {i}");
            touching += usize::from(c.is_some());
            let (d, _) = colliders[0].signed_distance(p, 0.0);
            skipped += usize::from(d >= reach[i][0] + reach[i][1]);
        }
        // The case covers both sides of the bound.
        assert!(
            touching >= 10 && skipped >= 10,
            "{touching} touching, {skipped} skipped"
        );
    }
}
