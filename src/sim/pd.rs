//! The direct global step of projective dynamics (VH §7.1, Eq. 27-28) and
//! the implicit-Euler time loop (VH Eq. 25).
//!
//! One time step minimizes the incremental potential (VH Eq. 12 with the
//! `a` of Eq. 25)
//!
//! `Φ(x) = (1 + c Δt) / (2 Δt²) |x - s|²_M + Σ_e E_e(x)`,
//! `s = x* + (Δt v* + Δt² g) / (1 + c Δt)`,
//!
//! over the free nodes (pinned nodes are prescribed), where `E_e` is the
//! element energy of VH Eq. 7 ([`super::energy`]), `x*`, `v*` the state of the
//! previous step and `c` the mass-proportional damping. The damping is
//! implicit: `M (v - v*) / Δt = f + M g - c M v` with `v = (x - x*) / Δt`
//! rearranges to the potential above (the mass term scaled by `1 + c Δt`, the
//! target pulled back by `1 / (1 + c Δt)`), so it stays stable for any `c`.
//!
//! # Global step
//! With the local-step targets `R_e`, `V_e` fixed, `Φ` is quadratic in `x`
//! and, since `F_e = Σ_a x_a ∇N_aᵀ` (`∇N_a`: rest shape-function gradients),
//! decouples into one scalar system per coordinate with the same matrix
//!
//! `K = (1 + c Δt) M / Δt² + Σ_e 2 V_e (γs + γv) G_eᵀ G_e`,
//! `(G_eᵀ G_e)_ab = ∇N_a · ∇N_b`,
//!
//! and right-hand side (rows: nodes, columns: x, y, z)
//!
//! `b = (1 + c Δt) M s / Δt² + Σ_e 2 V_e G_eᵀ (γs R_e + γv V_e)ᵀ`.
//!
//! The factor 2 is not printed in VH Eq. 27-28 (which also end with a stray
//! `x`, see the errata): Eq. 7 has no ½ while Eq. 12 has `1/(2Δt²)`, so the
//! stationarity condition of Eq. 12 carries `2 V_e γ`. Using it keeps the
//! solver's fixed point the true minimizer of the energy that
//! [`super::energy`] evaluates and differentiates (the printed form
//! corresponds to stiffnesses halved).
//!
//! Pinned nodes are eliminated: their columns of `K` move to the right-hand
//! side. The free block is factored with a sparse Cholesky: the symbolic
//! factorization once per mesh and pin set, the numeric one once per
//! (materials, Δt, damping) ([`PdSolver::refactor`],
//! [`PdSolver::set_time_step`]).
//!
//! # Monotonicity
//! The local step minimizes the surrogate over the targets (closest rotation
//! and closest SL(3) matrix), the direct global step minimizes it over `x`
//! exactly, so `Φ` cannot increase between iterations (up to rounding). The
//! per-iteration values are kept in [`StepStats::objectives`].

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::time::Instant;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use nalgebra::Vector3;

use super::cholesky::SparseCholesky;
use super::energy::{node_gradients, ElasticModel};
use super::local::{local_step, TetTargets};
use super::SimError;
use crate::geom::{TetMesh, Vec3};

/// Parameters of the time loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdParams {
    /// Time step Δt (s). Default 1/150 (VH Table 1).
    pub dt: f64,
    /// Gravity acceleration (m/s²). Default `[0, -9.81, 0]` (+Y up).
    pub gravity: Vec3,
    /// Mass-proportional damping `c` (1/s), applied implicitly (module doc).
    /// Default 0.
    pub mass_damping: f64,
    /// Most PD iterations (local + global) per time step. Default 20.
    pub max_iterations: u32,
    /// Stop the PD iterations of a step when the last iteration decreased
    /// `Φ` by at most `tolerance` times the step's total decrease so far
    /// (dimensionless). Default 1e-6; 0 runs `max_iterations`.
    pub tolerance: f64,
    /// Divergence guard: largest allowed node speed after a step (m/s).
    /// Default 100 (knitwear moves far slower); `f64::INFINITY` disables it.
    pub max_speed: f64,
    /// Divergence guard: kinetic + elastic energy after a step may be at most
    /// this factor times its value before the step, or times the floor
    /// `½ M_total max_speed²` when larger (dimensionless, > 1). Default 1e6;
    /// `f64::INFINITY` disables it.
    pub energy_blowup: f64,
}

impl Default for PdParams {
    fn default() -> Self {
        PdParams {
            dt: 1.0 / 150.0,
            gravity: [0.0, -9.81, 0.0],
            mass_damping: 0.0,
            max_iterations: 20,
            tolerance: 1e-6,
            max_speed: 100.0,
            energy_blowup: 1e6,
        }
    }
}

impl PdParams {
    fn validate(&self) -> Result<(), SimError> {
        let bad = |what: &str, v: f64| {
            Err(SimError::Inconsistent(format!(
                "PD parameter {what} is {v}"
            )))
        };
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt (must be finite and > 0 s)", self.dt);
        }
        if let Some(g) = self.gravity.iter().find(|g| !g.is_finite()) {
            return bad("gravity (must be finite)", *g);
        }
        if !(self.mass_damping.is_finite() && self.mass_damping >= 0.0) {
            return bad("mass_damping (must be finite and >= 0)", self.mass_damping);
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return bad("tolerance (must be finite and >= 0)", self.tolerance);
        }
        if !(self.max_speed > 0.0) {
            return bad("max_speed (must be > 0 m/s)", self.max_speed);
        }
        if !(self.energy_blowup > 1.0) {
            return bad("energy_blowup (must be > 1)", self.energy_blowup);
        }
        Ok(())
    }

    /// `(1 + c Δt) / Δt²` (1/s²): the scale of the mass term in `K`.
    fn mass_scale(&self) -> f64 {
        (1.0 + self.mass_damping * self.dt) / (self.dt * self.dt)
    }
}

/// What one time step did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepStats {
    /// 1-based index of this step among the solver's steps.
    pub step: u64,
    /// Global solves done.
    pub iterations: u32,
    /// `Φ` (J) at the initial guess (`x* + Δt v* / (1 + c Δt)` with the pins
    /// applied).
    pub objective_initial: f64,
    /// `Φ` (J) at the returned positions.
    pub objective_final: f64,
    /// `Φ` (J) before the first and after every global solve
    /// (`iterations + 1` values).
    pub objectives: Vec<f64>,
    /// Largest norm over free nodes of `∇Φ` at the returned positions (N):
    /// how far the step is from the exact implicit-Euler solution.
    pub residual: f64,
    /// Largest node speed after the step (m/s).
    pub max_speed: f64,
    /// Most tets whose local projection hit the 0.01 singular-value floor in
    /// one local step (inverted or extremely compressed tets).
    pub clamped_tets: usize,
    /// Wall time of the step (ms).
    pub ms: f64,
}

/// The PD simulator of one mesh with a fixed set of pinned nodes.
#[derive(Debug)]
pub struct PdSolver {
    mesh: TetMesh,
    model: ElasticModel,
    mass: Vec<f64>,
    params: PdParams,
    pinned: Vec<usize>,
    /// Free-node index of every node, `None` for pinned nodes.
    free_index: Vec<Option<usize>>,
    /// Node of every free index.
    free_nodes: Vec<usize>,
    /// Cholesky factor of the free block of `K` (`None` when nothing is free).
    factor: Option<SparseCholesky>,
    /// The pinned columns of `K`: (free row, index into `pinned`, value).
    k_fp: Vec<(usize, usize, f64)>,
    /// `½ M_total max_speed²` (J): floor of the energy guard.
    energy_floor: f64,
    steps: u64,
}

/// Rest shape-function gradients `∇N_a` (1/m) of a tet from its `Dm⁻¹`.
fn shape_gradients(dm_inv: &nalgebra::Matrix3<f64>) -> [Vector3<f64>; 4] {
    let r = |i: usize| dm_inv.row(i).transpose();
    let (g1, g2, g3) = (r(0), r(1), r(2));
    [-(g1 + g2 + g3), g1, g2, g3]
}

/// The free block of `K` and its pinned columns for one set of materials
/// and time step.
struct Assembled {
    /// Lower triangle of the free block, always the same positions in the
    /// same order for a given mesh and pin set, so a numeric refactorization
    /// can reuse the symbolic one.
    lower: Vec<Triplet<usize, usize, f64>>,
    /// Pinned columns: (free row, pinned node, value).
    k_fp: Vec<(usize, usize, f64)>,
    /// Diagonal of the free block.
    diag: Vec<f64>,
}

fn assemble(
    model: &ElasticModel,
    mass: &[f64],
    mass_scale: f64,
    free_index: &[Option<usize>],
    num_free: usize,
) -> Assembled {
    let mut lower = Vec::with_capacity(model.rest().len() * 10 + num_free);
    let mut k_fp = Vec::new();
    let mut diag = vec![0.0; num_free];
    for (node, f) in free_index.iter().enumerate() {
        if let Some(fi) = *f {
            let m = mass[node] * mass_scale;
            lower.push(Triplet::new(fi, fi, m));
            diag[fi] += m;
        }
    }
    for (e, r) in model.rest().iter().enumerate() {
        let w = 2.0 * r.volume * (model.gamma_s()[e] + model.gamma_v()[e]);
        let g = shape_gradients(&r.dm_inv);
        for a in 0..4 {
            let Some(fi) = free_index[r.nodes[a]] else {
                continue;
            };
            for b in 0..4 {
                let val = w * g[a].dot(&g[b]);
                match free_index[r.nodes[b]] {
                    Some(fj) => {
                        if fi >= fj {
                            lower.push(Triplet::new(fi, fj, val));
                        }
                        if fi == fj {
                            diag[fi] += val;
                        }
                    }
                    None => k_fp.push((fi, r.nodes[b], val)),
                }
            }
        }
    }
    Assembled { lower, k_fp, diag }
}

fn llt_error(e: impl std::fmt::Debug) -> SimError {
    SimError::Inconsistent(format!("the PD matrix K is not positive definite: {e:?}"))
}

fn norm(p: Vec3) -> f64 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
}

/// Index and value of the largest entry of `it` (NaN counts as largest).
fn worst(it: impl Iterator<Item = f64>) -> (usize, f64) {
    let mut best = (0, f64::NEG_INFINITY);
    for (i, v) in it.enumerate() {
        if v.is_nan() {
            return (i, v);
        }
        if v > best.1 {
            best = (i, v);
        }
    }
    best
}

impl PdSolver {
    /// Prepares the simulator of `mesh` with lumped node masses `node_mass`
    /// (kg, finite, >= 0), per-tet stiffnesses `gamma_s`, `gamma_v` (Pa) and
    /// the nodes `pinned` (distinct, in range) whose positions every step
    /// prescribes. Assembles `K` (module doc), eliminates the pinned nodes and
    /// factors the free block. Errors when the inputs do not fit together or
    /// a free node has neither mass nor stiffness (`K` singular).
    pub fn new(
        mesh: &TetMesh,
        node_mass: &[f64],
        gamma_s: &[f64],
        gamma_v: &[f64],
        pinned: &[usize],
        params: PdParams,
    ) -> Result<PdSolver, SimError> {
        params.validate()?;
        let model = ElasticModel::new(mesh, gamma_s, gamma_v)?;
        let n = mesh.num_nodes();
        if node_mass.len() != n {
            return Err(SimError::Inconsistent(format!(
                "{} node masses for a mesh of {n} nodes",
                node_mass.len()
            )));
        }
        if let Some(i) = node_mass.iter().position(|m| !(m.is_finite() && *m >= 0.0)) {
            return Err(SimError::Inconsistent(format!(
                "mass of node {i} is {}; masses must be finite and >= 0 kg",
                node_mass[i]
            )));
        }
        let mut is_pinned = vec![false; n];
        for &p in pinned {
            if p >= n {
                return Err(SimError::Inconsistent(format!(
                    "pinned node {p} but the mesh has {n} nodes"
                )));
            }
            if std::mem::replace(&mut is_pinned[p], true) {
                return Err(SimError::Inconsistent(format!("node {p} is pinned twice")));
            }
        }
        let free_nodes: Vec<usize> = (0..n).filter(|&i| !is_pinned[i]).collect();
        let mut free_index = vec![None; n];
        for (fi, &node) in free_nodes.iter().enumerate() {
            free_index[node] = Some(fi);
        }
        let total_mass: f64 = node_mass.iter().sum();
        let energy_floor = 0.5 * total_mass * params.max_speed * params.max_speed;
        let mut solver = PdSolver {
            mesh: mesh.clone(),
            model,
            mass: node_mass.to_vec(),
            params,
            pinned: pinned.to_vec(),
            free_index,
            free_nodes,
            factor: None,
            k_fp: Vec::new(),
            energy_floor,
            steps: 0,
        };
        solver.factorize(true)?;
        Ok(solver)
    }

    /// Assembles `K` for the current materials and parameters and factors
    /// it; the symbolic factorization only when `symbolic` is set (or none
    /// exists yet).
    fn factorize(&mut self, symbolic: bool) -> Result<(), SimError> {
        let nf = self.free_nodes.len();
        let asm = assemble(
            &self.model,
            &self.mass,
            self.params.mass_scale(),
            &self.free_index,
            nf,
        );
        if let Some(fi) = asm.diag.iter().position(|d| !(*d > 0.0)) {
            return Err(SimError::Inconsistent(format!(
                "free node {} has neither mass nor stiffness (K is singular)",
                self.free_nodes[fi]
            )));
        }
        self.k_fp = asm.k_fp;
        if nf == 0 {
            self.factor = None;
            return Ok(());
        }
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(nf, nf, &asm.lower)
            .map_err(llt_error)?;
        let sym = match self.factor.take() {
            Some(f) if !symbolic => f.into_symbolic(),
            _ => SparseCholesky::symbolic(a.as_ref()).map_err(llt_error)?,
        };
        self.factor = Some(SparseCholesky::numeric(sym, a.as_ref()).map_err(llt_error)?);
        Ok(())
    }

    /// New per-tet stiffnesses (Pa): redoes only the numeric factorization.
    pub fn refactor(&mut self, gamma_s: &[f64], gamma_v: &[f64]) -> Result<(), SimError> {
        let model = ElasticModel::new(&self.mesh, gamma_s, gamma_v)?;
        let old = std::mem::replace(&mut self.model, model);
        let r = self.factorize(false);
        if r.is_err() {
            // Keep the solver usable with its previous materials.
            self.model = old;
            self.factorize(false)?;
        }
        r
    }

    /// New time step Δt (s) and damping (1/s): redoes only the numeric
    /// factorization.
    pub fn set_time_step(&mut self, dt: f64, mass_damping: f64) -> Result<(), SimError> {
        let params = PdParams {
            dt,
            mass_damping,
            ..self.params
        };
        params.validate()?;
        let old = std::mem::replace(&mut self.params, params);
        let r = self.factorize(false);
        if r.is_err() {
            self.params = old;
            self.factorize(false)?;
        }
        r
    }

    /// The parameters in use.
    pub fn params(&self) -> &PdParams {
        &self.params
    }
    /// The elastic model (rest shapes and stiffnesses).
    pub fn model(&self) -> &ElasticModel {
        &self.model
    }
    /// The pinned nodes, in the order of `pinned_positions` in [`Self::step`].
    pub fn pinned(&self) -> &[usize] {
        &self.pinned
    }
    /// Time steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// Lumped node masses (kg).
    pub fn node_mass(&self) -> &[f64] {
        &self.mass
    }

    /// Kinetic energy `½ Σ m |v|²` (J).
    pub fn kinetic_energy(&self, v: &[Vec3]) -> f64 {
        self.mass
            .iter()
            .zip(v)
            .map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
            .sum()
    }

    /// `Φ` (J) at `x` given the inertia target `s`, with the local-step
    /// targets at `x` (returned for the global step) and the elastic part.
    fn objective(
        &self,
        x: &[Vec3],
        s: &[Vec3],
    ) -> Result<(f64, f64, Vec<TetTargets>, usize), SimError> {
        let (targets, stats) = local_step(&self.model, x)?;
        let fs = self.model.deformation_gradients(x)?;
        let mut elastic = 0.0;
        for (e, (f, t)) in fs.iter().zip(&targets).enumerate() {
            let v = self.model.rest()[e].volume;
            elastic += v
                * (self.model.gamma_s()[e] * (f - t.rotation).norm_squared()
                    + self.model.gamma_v()[e] * (f - t.volume).norm_squared());
        }
        let ms = self.params.mass_scale();
        let inertia: f64 = self
            .free_nodes
            .iter()
            .map(|&i| {
                let d = [x[i][0] - s[i][0], x[i][1] - s[i][1], x[i][2] - s[i][2]];
                0.5 * ms * self.mass[i] * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            })
            .sum();
        Ok((inertia + elastic, elastic, targets, stats.clamped))
    }

    /// One implicit-Euler time step (VH Eq. 25) by PD iterations with the
    /// direct global solve: advances `x` (m) and `v` (m/s) of every node;
    /// `pinned_positions` (m) are the pinned nodes' positions at the end of
    /// the step, in the order of [`Self::pinned`] (their velocities become
    /// the finite difference). On error `x` and `v` are left unchanged.
    pub fn step(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
    ) -> Result<StepStats, SimError> {
        let t0 = Instant::now();
        let n = self.mass.len();
        if x.len() != n || v.len() != n || pinned_positions.len() != self.pinned.len() {
            return Err(SimError::Inconsistent(format!(
                "step got {} positions, {} velocities and {} pinned positions for {n} nodes \
                 with {} pinned",
                x.len(),
                v.len(),
                pinned_positions.len(),
                self.pinned.len()
            )));
        }
        let finite = |p: &Vec3| p.iter().all(|c| c.is_finite());
        for (what, arr) in [
            ("position", &*x),
            ("velocity", &*v),
            ("pinned position", pinned_positions),
        ] {
            if let Some(i) = arr.iter().position(|p| !finite(p)) {
                return Err(SimError::Inconsistent(format!("{what} {i} is not finite")));
            }
        }
        self.steps += 1;
        let step = self.steps;
        let p = self.params;
        let dt = p.dt;
        let damp = 1.0 + p.mass_damping * dt;

        // Inertia target s (free nodes) and the initial guess: s with pins.
        let mut s = x.to_vec();
        for &i in &self.free_nodes {
            for k in 0..3 {
                s[i][k] = x[i][k] + (dt * v[i][k] + dt * dt * p.gravity[k]) / damp;
            }
        }
        // Warm start at the inertial prediction without external force
        // (x* + Δt v* / (1 + c Δt)): at rest this is the previous pose, so a
        // resting state is a fixed point of the time loop even when a step
        // stops before its PD iterations converge (starting at `s` instead
        // would re-add the gravity drop every step and leave an offset that
        // depends on the iteration count).
        let mut xk: Vec<Vec3> = x
            .iter()
            .zip(v.iter())
            .map(|(p, u)| std::array::from_fn(|k| p[k] + dt * u[k] / damp))
            .collect();
        for (&i, q) in self.pinned.iter().zip(pinned_positions) {
            xk[i] = *q;
        }
        let energy_before = self.kinetic_energy(v) + self.model.energy(x)?;

        // Constant part of the right-hand side: mass term minus pinned columns.
        let ms = p.mass_scale();
        let nf = self.free_nodes.len();
        let mut rhs0 = Mat::<f64>::zeros(nf, 3);
        for (fi, &i) in self.free_nodes.iter().enumerate() {
            for k in 0..3 {
                rhs0[(fi, k)] = ms * self.mass[i] * s[i][k];
            }
        }
        for &(fi, node, val) in &self.k_fp {
            for k in 0..3 {
                rhs0[(fi, k)] -= val * xk[node][k];
            }
        }

        let mut objectives = Vec::with_capacity(p.max_iterations as usize + 1);
        let mut iterations = 0u32;
        let mut clamped_tets = 0usize;
        let elastic_after = loop {
            let (phi, elastic, targets, clamped) = self.objective(&xk, &s)?;
            clamped_tets = clamped_tets.max(clamped);
            objectives.push(phi);
            if iterations > 0 {
                let (first, prev) = (objectives[0], objectives[objectives.len() - 2]);
                if prev - phi <= p.tolerance * (first - phi) {
                    break elastic;
                }
            }
            if iterations >= p.max_iterations || nf == 0 {
                break elastic;
            }
            let mut rhs = rhs0.clone();
            for (e, (r, t)) in self.model.rest().iter().zip(&targets).enumerate() {
                let target = 2.0
                    * r.volume
                    * (self.model.gamma_s()[e] * t.rotation + self.model.gamma_v()[e] * t.volume);
                let ng = node_gradients(&target, &r.dm_inv);
                for (&node, g) in r.nodes.iter().zip(&ng) {
                    if let Some(fi) = self.free_index[node] {
                        for k in 0..3 {
                            rhs[(fi, k)] += g[k];
                        }
                    }
                }
            }
            if let Some(f) = &self.factor {
                f.solve_in_place(rhs.as_mut());
            }
            for (fi, &i) in self.free_nodes.iter().enumerate() {
                xk[i] = [rhs[(fi, 0)], rhs[(fi, 1)], rhs[(fi, 2)]];
            }
            iterations += 1;
            if let Some(fi) = (0..nf).find(|&fi| !finite(&xk[self.free_nodes[fi]])) {
                return Err(SimError::Diverged {
                    step,
                    node: self.free_nodes[fi],
                    reason: format!("position not finite after PD iteration {iterations}"),
                });
            }
        };

        let v_new: Vec<Vec3> = xk
            .iter()
            .zip(x.iter())
            .map(|(a, b)| std::array::from_fn(|k| (a[k] - b[k]) / dt))
            .collect();
        let (fastest, max_speed) = worst(v_new.iter().map(|v| norm(*v)));
        if max_speed > p.max_speed {
            return Err(SimError::Diverged {
                step,
                node: fastest,
                reason: format!(
                    "speed {max_speed:.6e} m/s exceeds the guard {} m/s",
                    p.max_speed
                ),
            });
        }
        let energy_after = self.kinetic_energy(&v_new) + elastic_after;
        let bound = p.energy_blowup * energy_before.max(self.energy_floor);
        if !(energy_after <= bound) {
            return Err(SimError::Diverged {
                step,
                node: fastest,
                reason: format!(
                    "kinetic + elastic energy grew from {energy_before:.6e} J to \
                     {energy_after:.6e} J (bound {bound:.6e} J)"
                ),
            });
        }

        // Residual of the implicit-Euler equations at the returned positions.
        let grad = self.model.gradient(&xk)?;
        let residual = self
            .free_nodes
            .iter()
            .map(|&i| {
                norm(std::array::from_fn(|k| {
                    ms * self.mass[i] * (xk[i][k] - s[i][k]) + grad[i][k]
                }))
            })
            .fold(0.0, f64::max);

        x.copy_from_slice(&xk);
        v.copy_from_slice(&v_new);
        Ok(StepStats {
            step,
            iterations,
            objective_initial: objectives[0],
            objective_final: *objectives.last().unwrap_or(&0.0),
            objectives,
            residual,
            max_speed,
            clamped_tets,
            ms: t0.elapsed().as_secs_f64() * 1e3,
        })
    }
}
