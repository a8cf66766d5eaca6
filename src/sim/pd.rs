//! The global step of projective dynamics, direct (VH §7.1, Eq. 27-28) or
//! domain-decomposed (VH §7.2, Eq. 29-34), contacts as projection
//! constraints (VH §8.5), and the implicit-Euler time loop (VH Eq. 25).
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
//! # Stiffness-proportional damping
//! With [`PdParams::stiffness_damping`] `β` (s) the step also carries a
//! Rayleigh damping of the rates of deformation, co-rotated so that a rigid
//! rotation, like a translation, is not damped: the potential
//! `β / (2 Δt) Σ_e |F_e(x) - R_e F_e(x*)|²_{L_e}`, `x*` the step's start,
//! `L_e` the tet's block of the elastic part `L = Σ_e 2 V_e (γs + γv) G_eᵀ
//! G_e` of `K` (plus the fibre terms) and `R_e` the rotation that minimizes
//! it, the polar factor of `Σ_a x_a (L_e x*)_aᵀ`. Its force is `-β L v`
//! (`v = (x - x*) / Δt`) for a motion without rotation; the linear form
//! `β/(2 Δt) |x - x*|²_L` damped rotations too (a spinning or swinging
//! swatch slowed as if it deformed, a slide's landing tilt with it). It is
//! a PD constraint: the local step finds `R_e`, the global step keeps the
//! matrix, `K`'s elastic part scaled by `1 + β / Δt` and `b` gaining `(β /
//! Δt) Σ_e R_e L_e x*`; so the factorization stays once per (materials,
//! Δt, damping). It is the homogenized counterpart of the yarn-yarn
//! friction and contact damping that dissipate energy inside the fabric at
//! yarn level; the mass-proportional `c` also slows a falling or sliding
//! body.
//!
//! Pinned nodes are eliminated: their columns of `K` move to the right-hand
//! side. The free block is factored with a sparse Cholesky: the symbolic
//! factorization once per mesh and pin set, the numeric one once per
//! (materials, Δt, damping) ([`PdSolver::refactor`],
//! [`PdSolver::set_time_step`]).
//!
//! # Domain-decomposed global step (VH §7.2)
//! With [`GlobalSolver::DomainDecomposed`] the global step solves for the
//! correction `δ = x - x_k` of the current PD iterate: `K δ = b - K x_k`,
//! first in the CMS subspace ([`super::dd`]; with exact interiors, the
//! default, this solve is already exact for `K`), then by Chebyshev-Jacobi
//! iterations in full space ([`super::jacobi`], through the
//! [`JacobiSolve`] trait so a GPU backend can replace it) down to
//! [`DdParams::tolerance`] relative to `|b - K x_k|` (no iteration runs when
//! the reduced solution already meets it). The precomputation
//! (partition, per-domain factors and modes, Schur complement, spectral
//! estimate) runs once per (materials, Δt), like the direct factor.
//!
//! # Contacts (VH §8.5, Bouaziz et al. 2014 §5)
//! [`PdSolver::step_with_contacts`] adds, for every free node `i` that the
//! [`NodeProjector`] reports non-admissible at the current iterate, the
//! projection constraint `½ w_i |x_i - P(x_i)|²` with
//! `w_i = κ m_i / Δt²` ([`PdParams::contact_stiffness`] `κ`). The projections
//! `P` are re-evaluated every PD iteration (local step); the global system
//! becomes `(K + W) x = b + W P`. The constrained set only grows within a
//! step (each step starts empty, so steps depend only on their inputs): a
//! node that is admissible again keeps its weight with `P(x) = x` (the
//! projection of an admissible point), which is PD on `½ w dist(x, C)²`
//! with the same fixed point, so `W` changes only when a node joins. (Re-
//! evaluating the set every iteration made it chatter at the contact
//! boundary: 452 refactorizations in 474 PD iterations on the held-out
//! drape, 179 now; its global solves 0.51 s -> 0.24 s, median of 3.) The direct solver
//! factors `K + W` numerically (the symbolic analysis of `K` reused: `W`
//! only adds to the diagonal) for the step's first contact set, and adds
//! the nodes that join later in the step to that factor by the Woodbury
//! identity ([`crate::linalg::woodbury`], up to 64 nodes) instead of refactoring:
//! one exact solve per iteration either way. (On the held-out drape 152
//! refactorizations became 101, the figures unchanged to 10 digits.)
//! On the held-out drape of `knitvox validate` (1,568 nodes, up to 133 in
//! contact) this halved the global solves' time against the previous
//! preconditioned CG (11 iterations per solve on average). The
//! domain-decomposed solver with exact interiors solves the system by
//! conjugate gradients preconditioned with its reduced solve, an exact
//! `K⁻¹` (`W` has low rank, so few iterations; no refactorization).
//! With modal interiors it hands `W` to the Jacobi iterations as an extra
//! diagonal (its subspace is untouched: VH's point that DD is insensitive to
//! new collision constraints). Measured on the drape of
//! `examples/drape-sphere.toml` (918 nodes, 24 frames): Chebyshev-Jacobi on
//! `K + W` from the exact `K` solution cost 100 ms per step, the
//! preconditioned CG 15 ms (direct: 12 ms). After the last iteration every free node still not
//! admissible is moved to its projection (a hard guarantee: no free node ends
//! a step inside a collider); pinned nodes are never projected. Velocities
//! are then the finite differences of the final positions.
//!
//! [`PdSolver::step_with_point_contacts`] puts the same constraints on
//! points embedded in the tets (yarn vertices) instead of on the nodes:
//! each point's lumped weight and correction are added to the diagonal
//! and the right-hand side of its tet's four nodes (`super::contact`,
//! "Contacts at embedded points"), so every solver path above takes them
//! unchanged; the set of points grows within a step like the set of nodes,
//! and a node's weight grows with it (a refactorization, as for a node
//! that joins with other weights). The end-of-step guarantee moves the
//! nodes of points still inside by their lumped corrections, up to
//! 8 passes (one puts a point alone in its tet exactly on its target).
//!
//! Coulomb friction (`super::contact`): a contact with a coefficient
//! replaces `P(x_i)` by a target that also holds the node's place on the
//! surface since the start of the step (static friction) or pulls it back
//! by at most `μ` times the projection depth (kinetic), i.e. tangential
//! constraint forces bounded by `μ` times the normal one, evaluated with the
//! PD iterations like the projections, so it acts inside the implicit step
//! (the final projection uses the same targets).
//!
//! # Backends
//! The local step and the elastic right-hand side run through an
//! [`ElasticRhs`] (default [`CpuElasticRhs`]), the Jacobi iterations through
//! a [`JacobiSolve`] (default [`CpuJacobi`]); [`PdSolver::set_backend`]
//! swaps in others (the GPU backend), built from [`PdSolver::model`],
//! [`PdSolver::free_nodes`] and [`PdSolver::free_matrix`].
//!
//! # Anderson acceleration (Peng et al. 2018)
//! One PD iteration is the fixed-point map `x ← G(x) = x - K⁻¹ ∇Φ(x)`, a
//! gradient step preconditioned with the constant `K`: cheap, but linearly
//! and slowly convergent on soft, large motions (PD's artificial damping).
//! With [`PdParams::anderson_window`] `m > 0` the next iterate mixes the last
//! `m` iterates ([`crate::linalg::anderson`]): a multisecant quasi-Newton step at the
//! price of a few vector operations. An accelerated iterate is accepted only
//! if the local step at it finds `Φ` lower than at the previous iterate;
//! otherwise the plain PD iterate `G(x_k)` is taken (one more local step) and
//! the history restarts. On the soft cantilever of `tests/sim_pd.rs`
//! (`pd_iteration_study`) 5 accelerated iterations land closer to the
//! converged step than 20 plain ones (see [`PdParams::max_iterations`]).
//!
//! # Monotonicity
//! The local step minimizes the surrogate over the targets (closest rotation
//! and closest SL(3) matrix), the direct global step minimizes it over `x`
//! exactly, so `Φ` cannot increase between plain iterations (up to rounding)
//! without contacts, and the acceleration's safeguard keeps only iterates
//! that lower it. The per-iteration values of the accepted iterates are kept
//! in [`StepStats::objectives`]. The domain-decomposed step minimizes only up
//! to its tolerance, so `Φ` may rise by about that much.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::time::Instant;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use nalgebra::Vector3;
use rayon::prelude::*;

use super::backend::{ElasticRhs, IterStats, JacobiSolve};
use super::contact::{friction_target, EmbeddedPoints, NoContact, NodeProjector, PointProjector};
use super::cpu::CpuElasticRhs;
use super::dd::{DdParams, DdSolver, DdStats, Interiors};
use super::energy::ElasticModel;
use super::jacobi::CpuJacobi;
use super::partition::Partition;
use super::SimError;
use crate::geom::vec3::norm;
use crate::geom::{TetMesh, Vec3};
use crate::linalg::anderson::Anderson;
use crate::linalg::cholesky::SparseCholesky;
use crate::linalg::csr::CsrMatrix;
use crate::linalg::woodbury::LowRankUpdate;

/// Standard gravity (m/s²): the displacement floor of [`PdParams::tolerance`].
pub const STANDARD_GRAVITY: f64 = 9.81;

/// The step (s) [`PdParams::tolerance`] holds as given at (VH Table 1's
/// 1/150 s); shorter steps stop proportionally tighter.
pub const TOLERANCE_REFERENCE_STEP: f64 = 1.0 / 150.0;

/// What a step's contacts act on.
#[derive(Clone, Copy)]
pub enum Contacts<'a> {
    /// The free nodes, each projected by itself (module doc, "Contacts").
    Nodes(&'a dyn NodeProjector),
    /// Points embedded in the tets (yarn vertices), their forces reaching
    /// the nodes through the embedding weights (`super::contact`,
    /// "Contacts at embedded points").
    Points(&'a EmbeddedPoints, &'a dyn PointProjector),
}

/// Passes of the end-of-step fix-up for embedded points: each moves the
/// nodes of the points still in contact by their lumped correction.
const POINT_FIX_PASSES: usize = 8;

/// Which solver does the global step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GlobalSolver {
    /// Sparse Cholesky of the free block of `K` (VH Eq. 27-28), exact.
    Direct,
    /// CMS subspace solve plus Chebyshev-Jacobi (VH §7.2, [`super::dd`]).
    DomainDecomposed(DdParams),
}

impl GlobalSolver {
    /// A short name for statistics ("direct", "dd").
    pub fn name(&self) -> &'static str {
        match self {
            GlobalSolver::Direct => "direct",
            GlobalSolver::DomainDecomposed(_) => "dd",
        }
    }
}

impl Default for GlobalSolver {
    /// The direct solver, by a small margin on 2 CPU cores. `knitvox bench
    /// sim --tets N --steps 7 --solver direct|dd [--dd-interiors modes]
    /// --backend cpu` (knit swatch, 8 Anderson-accelerated PD iterations, 2
    /// threads), ms per step direct / DD with exact interiors / DD with 20
    /// modes per domain: 10K tets 26 / 27 / 229, 44K (12.7K nodes) 114 / 114
    /// / 791, 79K 213 / 220 / 1313, 161K 433 / 420 / 2970, 407K 1119 / 1092
    /// / 7603. The modal form needs ~3,300 Chebyshev-Jacobi iterations per
    /// step (~400 per global solve at 1e-4); with exact interiors the
    /// reduced solve is the solve and costs about one Cholesky solve. Both
    /// leave ~75% of the step to the local step.
    fn default() -> Self {
        GlobalSolver::Direct
    }
}

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
    /// Stiffness-proportional damping `β` (s, >= 0), applied implicitly
    /// and co-rotated (module doc, "Stiffness-proportional damping"): the
    /// elastic force's rate term, zero for rigid motion. Default 0.
    pub stiffness_damping: f64,
    /// Most PD iterations (local + global) per time step: the cap on
    /// [`Self::tolerance`]. Default 100; a step that reaches it is
    /// [`StepStats::capped`] (simulate and validate count and warn).
    ///
    /// Earlier a fixed count of 8 was the default; on the pinned drape of
    /// `knitvox bench sim` it leaves the nodes 5.4% (5.2K tets) and 5.1%
    /// (79.5K tets) of the largest displacement off the converged run, the
    /// extra damping of soft, large motions that slow PD convergence gives
    /// (`--pd-iterations K --tolerance 0` reports the `deviation` of any
    /// fixed count; docs/performance.md "Converged steps").
    pub max_iterations: u32,
    /// Convergence tolerance of a step (dimensionless). The PD iterations
    /// stop after the first plain PD iteration (local and global step,
    /// before acceleration) `x -> G(x) = x - A⁻¹ ∇Φ(x)` with
    ///
    /// `max_i max(|G(x)_i - x_i|, |∇Φ(x)_i| Δt² / ((1 + c Δt) max(m_i, m̄))) <= tolerance · D · s`
    ///
    /// and return `G(x)`: the residual both in the metric of the PD matrix
    /// `A` (mass, elastic and contact terms) and as the move it would give
    /// the node's mass in one step (`m̄` the mean free-node mass). Each
    /// alone misses a slow mode: the first the tangential motion under stiff
    /// contact weights (a sliding block freezes), the second the stiff
    /// elastic modes. `D = max(max_i |G(x)_i - x_i^n|, g₀ Δt²)` is the
    /// step's displacement over free nodes, at least one step of free fall
    /// from rest (`g₀ = 9.81 m/s²`). `s = min(1, Δt / Δt₀)` with `Δt₀` =
    /// [`TOLERANCE_REFERENCE_STEP`] (1/150 s): what a stop leaves undone of
    /// a step's move the next steps carry as lost velocity, a drag of up to
    /// `tolerance · s / Δt` per second, so shorter steps stop tighter and
    /// the drag per second stays about that of 1/150 s steps. Measured on a
    /// frictionless block sliding 0.5 s (`tests/sim_pd.rs`): 0.7% short of
    /// implicit Euler's travel at 1/150 s; at 1/600 s 14.2% short without
    /// the scale, 1.9% with it (0.0% with its square, at twice the
    /// iterations and many steps at the cap).
    /// [`StepStats::convergence`] is the left side over `D · s` at the last
    /// iteration.
    ///
    /// Default 0.01. The error a stop leaves accumulates over the steps, the
    /// more where it is coherent: a soft block swinging from its top face
    /// (`tests/sim_pd.rs`) ends 3.85% off its converged run after 20 steps
    /// at 0.05, 1.01% at 0.02, 0.39% at 0.01; the pinned drape of `knitvox
    /// bench sim` (5.2K tets) 0.38%, 0.13% and 0.085%, at 79.5K tets
    /// (VH's rib size) see docs/performance.md "Converged steps". 0 runs
    /// [`Self::max_iterations`].
    pub tolerance: f64,
    /// Divergence guard: largest allowed node speed after a step (m/s).
    /// Default 100 (knitwear moves far slower); `f64::INFINITY` disables it.
    pub max_speed: f64,
    /// Divergence guard: kinetic + elastic energy after a step may be at most
    /// this factor times its value before the step, or times the floor
    /// `½ M_total max_speed²` when larger (dimensionless, > 1). Default 1e6;
    /// `f64::INFINITY` disables it.
    pub energy_blowup: f64,
    /// The global solver. Default [`GlobalSolver::default`].
    pub global: GlobalSolver,
    /// Contact stiffness `κ` (dimensionless): the weight of a node's contact
    /// constraint is `κ m_i / Δt²`, i.e. `κ` times the node's inertia weight
    /// in `K` (module doc). Default 100: comparable to the elastic part of
    /// the node's row (about 10²-10³ m/Δt² for centimetre tets at VH's
    /// stiffnesses of 1e4 Pa), so a resting node sinks only ~`g Δt² / κ`
    /// (4 µm at Δt = 1/150 s) before the final projection removes even that,
    /// while `K + W` stays well conditioned: the contact CG of the
    /// domain-decomposed solver converges in a few iterations and the Jacobi
    /// spectrum bound is unchanged (see `sim::jacobi`).
    pub contact_stiffness: f64,
    /// Relative residual of the preconditioned CG solve of `(K + W) x = b +
    /// W P` in the domain-decomposed solver with exact interiors and active
    /// contacts, measured against the residual of its start `K⁻¹ (b + W P)`
    /// (dimensionless; the direct solver factors `K + W` instead). Default
    /// 1e-6.
    pub contact_tolerance: f64,
    /// Most CG iterations of that solve. Default 100.
    pub contact_max_iterations: u32,
    /// Compute [`StepStats::residual`] (one more gradient evaluation per
    /// step). Default true; benchmarks switch it off.
    pub report_residual: bool,
    /// Anderson acceleration of the PD iterations over this many past
    /// iterates ([`crate::linalg::anderson`], Peng et al. 2018), 0 for plain PD.
    /// An accelerated iterate is kept only when it lowers `Φ` below the
    /// previous iterate's value; otherwise the plain PD iterate replaces it
    /// (one more local step) and the history restarts, so `Φ` still never
    /// rises. The history also restarts when the contact set changes.
    /// Default 0.
    pub anderson_window: usize,
}

impl Default for PdParams {
    fn default() -> Self {
        PdParams {
            dt: 1.0 / 150.0,
            gravity: [0.0, -9.81, 0.0],
            mass_damping: 0.0,
            stiffness_damping: 0.0,
            max_iterations: 100,
            tolerance: 0.01,
            max_speed: 100.0,
            energy_blowup: 1e6,
            global: GlobalSolver::default(),
            contact_stiffness: 100.0,
            contact_tolerance: 1e-6,
            contact_max_iterations: 100,
            report_residual: true,
            anderson_window: 5,
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
        if !(self.stiffness_damping.is_finite() && self.stiffness_damping >= 0.0) {
            return bad(
                "stiffness_damping (must be finite and >= 0 s)",
                self.stiffness_damping,
            );
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
        if !(self.contact_stiffness.is_finite() && self.contact_stiffness >= 0.0) {
            return bad(
                "contact_stiffness (must be finite and >= 0)",
                self.contact_stiffness,
            );
        }
        if !(self.contact_tolerance.is_finite() && self.contact_tolerance > 0.0) {
            return bad(
                "contact_tolerance (must be finite and > 0)",
                self.contact_tolerance,
            );
        }
        if let GlobalSolver::DomainDecomposed(d) = &self.global {
            d.validate()?;
        }
        Ok(())
    }

    /// `(1 + c Δt) / Δt²` (1/s²): the scale of the mass term in `K`.
    fn mass_scale(&self) -> f64 {
        (1.0 + self.mass_damping * self.dt) / (self.dt * self.dt)
    }

    /// `1 + β / Δt`: the scale of the elastic part of `K`.
    fn stiffness_scale(&self) -> f64 {
        1.0 + self.stiffness_damping / self.dt
    }
}

/// What one time step did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepStats {
    /// 1-based index of this step among the solver's steps.
    pub step: u64,
    /// Global solves done (PD iterations).
    pub iterations: u32,
    /// The step used all of [`PdParams::max_iterations`] without meeting
    /// [`PdParams::tolerance`]: its end is not converged to the tolerance.
    pub capped: bool,
    /// The convergence measure of [`PdParams::tolerance`] at the last
    /// evaluated iterate (dimensionless; at most the tolerance unless
    /// [`Self::capped`]; 0 when nothing is free).
    pub convergence: f64,
    /// `Φ` (J) at the initial guess (`x* + Δt v* / (1 + c Δt)` with the pins
    /// applied), contact energy included.
    pub objective_initial: f64,
    /// `Φ` (J) at the last evaluated iterate (before the final contact
    /// projection).
    pub objective_final: f64,
    /// `Φ` (J) before the first and after every global solve
    /// (`iterations + 1` values).
    pub objectives: Vec<f64>,
    /// Largest norm over free nodes of `∇Φ` (without contacts) at the
    /// returned positions (N): how far the step is from the exact
    /// implicit-Euler solution. NaN when [`PdParams::report_residual`] is off.
    pub residual: f64,
    /// Largest node speed after the step (m/s).
    pub max_speed: f64,
    /// Most tets whose local projection hit the 0.01 singular-value floor in
    /// one local step (inverted or extremely compressed tets).
    pub clamped_tets: usize,
    /// Global solver ("direct", "dd").
    pub solver: &'static str,
    /// Backend of the local step ("cpu", "gpu").
    pub backend: &'static str,
    /// Iterations of the iterative global solves summed over the step
    /// (Chebyshev-Jacobi for "dd" with modal interiors; preconditioned CG
    /// with active contacts for "dd" with exact interiors; else 0).
    pub global_iterations: u32,
    /// Largest relative residual of the step's iterative global solves (0
    /// for direct solves; for "dd" relative to the residual of the previous
    /// iterate, for contact CG relative to that of `K⁻¹ (b + W P)`).
    pub global_residual: f64,
    /// Numeric refactorizations of `K + W` in the step (direct solver with
    /// contacts: one for the step's first contact set and one whenever the
    /// nodes added to it by the Woodbury identity would exceed 64; module
    /// doc).
    pub contact_refactors: u32,
    /// Free nodes (or embedded points, [`PdSolver::step_with_point_contacts`])
    /// with an active contact constraint in the last PD iteration.
    pub contacts: usize,
    /// Free nodes moved onto their projection (or by the points' fix-up)
    /// after the last iteration.
    pub projected: usize,
    /// Largest distance (m) one of them moved.
    pub max_projection: f64,
    /// Anderson-accelerated iterates rejected because they did not lower
    /// `Φ` (each cost one more local step; [`PdParams::anderson_window`]).
    pub accelerations_rejected: u32,
    /// Wall time of the local steps (elastic projections and right-hand
    /// side, [`ElasticRhs::evaluate`]) of the step (ms).
    pub local_ms: f64,
    /// Wall time of the global solves of the step (ms).
    pub global_ms: f64,
    /// Wall time of the step (ms).
    pub ms: f64,
}

impl StepStats {
    /// Local steps the step evaluated: one per PD iteration, one at its last
    /// iterate, one per rejected Anderson iterate.
    pub fn local_steps(&self) -> u32 {
        self.iterations + 1 + self.accelerations_rejected
    }
}

/// The PD simulator of one mesh with a fixed set of pinned nodes.
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
    /// The free block of `K`, both triangles.
    k_free: CsrMatrix,
    /// Cholesky factor of the free block of `K` (direct solver; `None` when
    /// nothing is free).
    factor: Option<SparseCholesky>,
    /// Lower triangle of the free block of `K` as factored, and the
    /// positions of its diagonal in the values (direct solver): `K + W` for
    /// a contact set is this with `W` added on the diagonal.
    k_lower: Option<(SparseColMat<usize, f64>, Vec<usize>)>,
    /// `K + W` factored for the last contact weights `W` (direct solver;
    /// module doc, "Contacts").
    contact_factor: Option<ContactFactor>,
    /// The reduced solver (domain-decomposed solver).
    dd: Option<DdSolver>,
    /// Jacobi iterations (domain-decomposed solver).
    jacobi: Option<Box<dyn JacobiSolve>>,
    /// Local step and elastic right-hand side.
    elastic: Box<dyn ElasticRhs>,
    /// Per-tet domain ids given by the caller (else automatic bisection).
    tet_domains: Option<Vec<u32>>,
    /// Per tet the block `L_e` of the elastic part of `K`, with stiffness-
    /// proportional damping (module doc), else None.
    damping_blocks: Option<std::sync::Arc<Vec<DampingBlock>>>,
    /// The pinned columns of `K`: (free row, node, value).
    k_fp: Vec<(usize, usize, f64)>,
    /// `½ M_total max_speed²` (J): floor of the energy guard.
    energy_floor: f64,
    /// Positions returned by the last step and their elastic energy (at the
    /// last PD iterate, before contact fixes), to skip re-evaluating the
    /// energy guard's "before" value.
    last: Option<(Vec<Vec3>, f64)>,
    steps: u64,
    /// Numeric refactorizations of `K + W` in the current step.
    contact_refactors: u32,
    /// Most nodes added to a factor of `K + W` by the Woodbury identity
    /// ([`MAX_LOW_RANK_NODES`]; tests set 0 to compare with refactoring).
    max_low_rank_nodes: usize,
}

impl std::fmt::Debug for PdSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PdSolver")
            .field("nodes", &self.mesh.num_nodes())
            .field("tets", &self.mesh.num_tets())
            .field("pinned", &self.pinned.len())
            .field("params", &self.params)
            .field("elastic", &self.elastic.name())
            .field("jacobi", &self.jacobi.as_ref().map(|j| j.name()))
            .field("dd", &self.dd.as_ref().map(|d| d.stats()))
            .field("steps", &self.steps)
            .finish()
    }
}

/// Solves `A X = B` in place for the three coordinate columns of `b`
/// (interleaved x, y, z per row) with the factor of `A`, or of `A` plus
/// the diagonal entries of `update` (Woodbury).
fn solve_xyz(factor: &SparseCholesky, update: Option<&LowRankUpdate>, b: &mut [f64]) {
    let n = b.len() / 3;
    let mut m = Mat::<f64>::from_fn(n, 3, |i, k| b[3 * i + k]);
    factor.solve_in_place(m.as_mut());
    if let Some(update) = update {
        update.correct(&mut m);
    }
    for i in 0..n {
        for k in 0..3 {
            b[3 * i + k] = m[(i, k)];
        }
    }
}

/// Most nodes added to a factor of `K + W` by the Woodbury identity before
/// a refactorization: each costs one column solve, and every later solve
/// `O(n)` more work, against about five solves for a refactorization.
const MAX_LOW_RANK_NODES: usize = 64;

/// `K + W` factored for one set of contact weights (direct solver), and
/// the nodes that joined the set later in the same step.
struct ContactFactor {
    /// The diagonal of `W` per free node that it solves for: as factored,
    /// plus the joined nodes' weights (`update`).
    weights: Vec<f64>,
    factor: SparseCholesky,
    /// The step ([`PdSolver::steps`]) that factored it.
    step: u64,
    /// The joined nodes.
    update: LowRankUpdate,
}

impl ContactFactor {
    /// The free rows (and weights) that joined when the weights become
    /// `w`: `Some` (maybe empty) when this factor can solve for `w` in
    /// step `step`, `None` when `w` needs a refactorization.
    fn joined(&self, w: &[f64], step: u64, most: usize) -> Option<Vec<(usize, f64)>> {
        if w.len() != self.weights.len() {
            return None;
        }
        if self.update.is_empty() && w == self.weights {
            return Some(Vec::new());
        }
        if self.step != step {
            return None;
        }
        let mut rows = Vec::new();
        for (i, (&wi, &ei)) in w.iter().zip(&self.weights).enumerate() {
            if wi == ei {
                continue;
            }
            if ei != 0.0 || !(wi > 0.0) || self.update.len() + rows.len() >= most {
                return None;
            }
            rows.push((i, wi));
        }
        Some(rows)
    }

    /// Adds the joined `rows`; false when the update failed (refactor).
    fn add(&mut self, rows: &[(usize, f64)]) -> bool {
        if !self.update.extend(&self.factor, rows) {
            return false;
        }
        for &(i, wi) in rows {
            self.weights[i] = wi;
        }
        true
    }
}

/// Positions of the diagonal entries among the values of a lower-triangular
/// CSC matrix.
fn diagonal_positions(a: &SparseColMat<usize, f64>) -> Result<Vec<usize>, SimError> {
    let (col_ptr, row) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
    (0..a.ncols())
        .map(|j| {
            (col_ptr[j]..col_ptr[j + 1])
                .find(|&e| row[e] == j)
                .ok_or_else(|| {
                    SimError::Inconsistent(format!("K has no diagonal entry in row {j}"))
                })
        })
        .collect()
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
    stiffness_scale: f64,
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
        let le = element_block(model, e);
        for a in 0..4 {
            let Some(fi) = free_index[r.nodes[a]] else {
                continue;
            };
            for b in 0..4 {
                let val = stiffness_scale * le[a][b];
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

/// One tet's block `L_e` of the elastic part of `K` (N/m per node pair,
/// the same for x, y, z): `2 V (γs + γv) ∇N_a · ∇N_b` plus each fibre's
/// `w_f c_a c_b` (its selection `F d = Σ c_a x_a`, weight 2 γ V;
/// super::fibre, a stiffening fibre's tangent at the reference strain).
/// Rows sum to zero: a translation costs nothing.
fn element_block(model: &ElasticModel, e: usize) -> [[f64; 4]; 4] {
    let r = &model.rest()[e];
    let w = 2.0 * r.volume * (model.gamma_s()[e] + model.gamma_v()[e]);
    let g = shape_gradients(&r.dm_inv);
    let fibres: Vec<(f64, [f64; 4])> = model
        .fibres()
        .iter()
        .filter(|fam| fam.gamma[e] > 0.0)
        .map(|fam| {
            let c = super::fibre::node_coefficients(r, &fam.directions[e]);
            (fam.pd_weight(e, r.volume), c)
        })
        .collect();
    std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            w * g[a].dot(&g[b]) + fibres.iter().map(|(wf, c)| wf * c[a] * c[b]).sum::<f64>()
        })
    })
}

/// The co-rotated stiffness damping of one step (module doc,
/// "Stiffness-proportional damping"): per tet its block `L_e` and
/// `y_a = (L_e x*)_a`, the elastic force of the step's start positions
/// `x*` on its nodes.
struct CorotatedDamping {
    blocks: std::sync::Arc<Vec<DampingBlock>>,
    y: Vec<[Vec3; 4]>,
    /// Per tet `x*ᵀ L_e x*` (N m): the potential's constant.
    start: Vec<f64>,
}

/// A tet's nodes and its block `L_e` ([`element_block`]).
type DampingBlock = ([usize; 4], [[f64; 4]; 4]);

impl CorotatedDamping {
    fn new(blocks: std::sync::Arc<Vec<DampingBlock>>, x: &[Vec3]) -> Self {
        let y: Vec<[Vec3; 4]> = blocks
            .par_iter()
            .with_min_len(256)
            .map(|(nodes, le)| {
                std::array::from_fn(|a| {
                    std::array::from_fn(|k| (0..4).map(|b| le[a][b] * x[nodes[b]][k]).sum())
                })
            })
            .collect();
        let start = blocks
            .iter()
            .zip(&y)
            .map(|((nodes, _), ya)| (0..4).map(|a| dot_v(x[nodes[a]], ya[a])).sum::<f64>())
            .collect();
        Self { blocks, y, start }
    }

    /// At an iterate `xk`: `Σ_e |F_e(xk) - R_e F_e(x*)|²_{L_e}` (N m)
    /// with each `R_e` the rotation that minimizes it (the polar factor of
    /// `Σ_a xk_a y_aᵀ`), the targets `Σ_e R_e y_a` on every node (N) and
    /// `L xk` (N).
    fn at(&self, xk: &[Vec3]) -> (f64, Vec<Vec3>, Vec<Vec3>) {
        let per: Vec<(f64, [Vec3; 4], [Vec3; 4])> = self
            .blocks
            .par_iter()
            .zip(self.y.par_iter())
            .with_min_len(256)
            .map(|((nodes, le), y)| {
                let xa: [Vec3; 4] = std::array::from_fn(|a| xk[nodes[a]]);
                let mut m = nalgebra::Matrix3::zeros();
                for a in 0..4 {
                    m += Vector3::from(xa[a]) * Vector3::from(y[a]).transpose();
                }
                let rot = super::projection::project_rotation(&m);
                let q: [Vec3; 4] = std::array::from_fn(|a| (rot * Vector3::from(y[a])).into());
                let lx: [Vec3; 4] = std::array::from_fn(|a| {
                    std::array::from_fn(|k| (0..4).map(|b| le[a][b] * xa[b][k]).sum())
                });
                let e = (0..4)
                    .map(|a| dot_v(xa[a], lx[a]) - 2.0 * dot_v(xa[a], q[a]))
                    .sum::<f64>();
                (e, q, lx)
            })
            .collect();
        let n = xk.len();
        let (mut targets, mut lx) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
        let mut e: f64 = self.start.iter().sum();
        for ((nodes, _), (ee, q, l)) in self.blocks.iter().zip(&per) {
            e += ee;
            for a in 0..4 {
                for k in 0..3 {
                    targets[nodes[a]][k] += q[a][k];
                    lx[nodes[a]][k] += l[a][k];
                }
            }
        }
        // Rounding can take a rigid motion's value under zero.
        (e.max(0.0), targets, lx)
    }
}

/// Both triangles of the matrix whose lower triangle is `lower`.
fn full_csr(n: usize, lower: &[Triplet<usize, usize, f64>]) -> Result<CsrMatrix, SimError> {
    let mut t = Vec::with_capacity(2 * lower.len());
    for e in lower {
        t.push((e.row, e.col, e.val));
        if e.row != e.col {
            t.push((e.col, e.row, e.val));
        }
    }
    CsrMatrix::from_triplets(n, &t).map_err(|e| SimError::Inconsistent(e.to_string()))
}

/// `y = (A + W) x` for n x 3 row-major vectors, parallel over rows.
fn mul_plus_diag(a: &CsrMatrix, w: Option<&[f64]>, x: &[f64], y: &mut [f64]) {
    y.par_chunks_mut(3)
        .enumerate()
        .with_min_len(super::jacobi::MIN_ROWS_PER_TASK)
        .for_each(|(i, yi)| {
            let mut s = [0.0; 3];
            for e in a.row_ptr[i]..a.row_ptr[i + 1] {
                let (c, v) = (a.col[e], a.val[e]);
                for k in 0..3 {
                    s[k] += v * x[3 * c + k];
                }
            }
            if let Some(w) = w {
                for k in 0..3 {
                    s[k] += w[i] * x[3 * i + k];
                }
            }
            yi.copy_from_slice(&s);
        });
}

/// Per-column dot products of two n x 3 row-major vectors.
fn dot3(a: &[f64], b: &[f64]) -> [f64; 3] {
    let mut s = [0.0; 3];
    for (p, q) in a.chunks(3).zip(b.chunks(3)) {
        for k in 0..3 {
            s[k] += p[k] * q[k];
        }
    }
    s
}

/// A PD matrix that faer could not build or factor; the reason is shown
/// in Debug form (a factorization's reason quoted, as it has always been).
fn llt_error(e: impl std::fmt::Debug) -> SimError {
    SimError::Inconsistent(format!("the PD matrix K is not positive definite: {e:?}"))
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
    /// prepares the global solver of `params.global` (factor, or the
    /// domain-decomposed precomputation with an automatic partition). Errors
    /// when the inputs do not fit together or a free node has neither mass
    /// nor stiffness (`K` singular).
    pub fn new(
        mesh: &TetMesh,
        node_mass: &[f64],
        gamma_s: &[f64],
        gamma_v: &[f64],
        pinned: &[usize],
        params: PdParams,
    ) -> Result<PdSolver, SimError> {
        Self::new_partitioned(mesh, node_mass, gamma_s, gamma_v, pinned, params, None)
    }

    /// [`Self::new`] with per-tet domain ids for the domain-decomposed
    /// solver ([`Self::set_tet_domains`]; `None`: automatic bisection), so
    /// that its precomputation runs once, with the given partition.
    pub fn new_partitioned(
        mesh: &TetMesh,
        node_mass: &[f64],
        gamma_s: &[f64],
        gamma_v: &[f64],
        pinned: &[usize],
        params: PdParams,
        tet_domains: Option<&[u32]>,
    ) -> Result<PdSolver, SimError> {
        let model = ElasticModel::new(mesh, gamma_s, gamma_v)?;
        Self::with_model(mesh, model, node_mass, pinned, params, tet_domains)
    }

    /// [`Self::new_partitioned`] with the elastic model given whole (fibre
    /// families included, [`super::fibre`]); `model` must be `mesh`'s.
    pub fn with_model(
        mesh: &TetMesh,
        model: ElasticModel,
        node_mass: &[f64],
        pinned: &[usize],
        params: PdParams,
        tet_domains: Option<&[u32]>,
    ) -> Result<PdSolver, SimError> {
        params.validate()?;
        if model.rest().len() != mesh.num_tets() || model.num_nodes() != mesh.num_nodes() {
            return Err(SimError::Inconsistent(format!(
                "a model of {} tets and {} nodes for a mesh of {} and {}",
                model.rest().len(),
                model.num_nodes(),
                mesh.num_tets(),
                mesh.num_nodes()
            )));
        }
        if let Some(ids) = tet_domains {
            if ids.len() != mesh.num_tets() {
                return Err(SimError::Inconsistent(format!(
                    "{} domain ids for {} tets",
                    ids.len(),
                    mesh.num_tets()
                )));
            }
        }
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
        let elastic = Box::new(CpuElasticRhs::new(&model));
        let mut solver = PdSolver {
            mesh: mesh.clone(),
            model,
            mass: node_mass.to_vec(),
            params,
            pinned: pinned.to_vec(),
            free_index,
            free_nodes,
            k_free: CsrMatrix::default(),
            factor: None,
            k_lower: None,
            contact_factor: None,
            dd: None,
            jacobi: None,
            elastic,
            tet_domains: tet_domains.map(<[u32]>::to_vec),
            damping_blocks: None,
            k_fp: Vec::new(),
            energy_floor,
            last: None,
            steps: 0,
            contact_refactors: 0,
            max_low_rank_nodes: MAX_LOW_RANK_NODES,
        };
        solver.factorize(true)?;
        Ok(solver)
    }

    /// Assembles `K` for the current materials and parameters and prepares
    /// the global solver; the symbolic factorization only when `symbolic` is
    /// set (or none exists yet).
    fn factorize(&mut self, symbolic: bool) -> Result<(), SimError> {
        let nf = self.free_nodes.len();
        let asm = assemble(
            &self.model,
            &self.mass,
            self.params.mass_scale(),
            self.params.stiffness_scale(),
            &self.free_index,
            nf,
        );
        self.damping_blocks = (self.params.stiffness_damping > 0.0).then(|| {
            std::sync::Arc::new(
                (0..self.model.rest().len())
                    .map(|e| (self.model.rest()[e].nodes, element_block(&self.model, e)))
                    .collect(),
            )
        });
        if let Some(fi) = asm.diag.iter().position(|d| !(*d > 0.0)) {
            return Err(SimError::Inconsistent(format!(
                "free node {} has neither mass nor stiffness (K is singular)",
                self.free_nodes[fi]
            )));
        }
        self.k_fp = asm.k_fp;
        self.k_free = full_csr(nf, &asm.lower)?;
        self.last = None;
        // K changed: a factor of K + W for the old K must not be reused.
        self.contact_factor = None;
        self.k_lower = None;
        if nf == 0 {
            self.factor = None;
            self.dd = None;
            self.jacobi = None;
            return Ok(());
        }
        match self.params.global {
            GlobalSolver::Direct => {
                let a = SparseColMat::<usize, f64>::try_new_from_triplets(nf, nf, &asm.lower)
                    .map_err(llt_error)?;
                let sym = match self.factor.take() {
                    Some(f) if !symbolic => f.into_symbolic(),
                    _ => SparseCholesky::symbolic_supernodal(a.as_ref())
                        .map_err(|e| llt_error(e.to_string()))?,
                };
                self.factor = Some(
                    SparseCholesky::numeric(sym, a.as_ref())
                        .map_err(|e| llt_error(e.to_string()))?,
                );
                let diag = diagonal_positions(&a)?;
                self.k_lower = Some((a, diag));
                self.dd = None;
                self.jacobi = None;
            }
            GlobalSolver::DomainDecomposed(dp) => {
                let tets: Vec<[usize; 4]> = self.model.rest().iter().map(|r| r.nodes).collect();
                let part = match &self.tet_domains {
                    Some(ids) => Partition::from_ids(self.mesh.num_nodes(), &tets, ids)?,
                    None => Partition::bisect(&self.mesh.nodes, &tets, dp.nodes_per_domain)?,
                };
                let (dd, jacobi) = rayon::join(
                    || DdSolver::new(&self.k_free, &tets, &part, &self.free_index, &dp),
                    || CpuJacobi::new(self.k_free.clone(), dp.jacobi),
                );
                self.dd = Some(dd?);
                self.jacobi = Some(Box::new(jacobi?));
                self.factor = None;
            }
        }
        Ok(())
    }

    /// New per-tet stiffnesses (Pa): redoes only the numeric factorization
    /// (direct) or the domain precomputation (domain-decomposed). The
    /// local-step backend takes the new materials in place (a GPU backend
    /// stays on the GPU, `ElasticRhs::update_materials`); the Jacobi backend
    /// of the domain-decomposed solver goes back to the CPU one (`K`
    /// changed): call [`Self::set_backend`] with a new one for the GPU.
    pub fn refactor(&mut self, gamma_s: &[f64], gamma_v: &[f64]) -> Result<(), SimError> {
        let model = ElasticModel::new(&self.mesh, gamma_s, gamma_v)?
            .with_fibres(self.model.fibres().to_vec())?;
        self.replace_model(model)
    }

    /// New fibre families ([`super::fibre`]; empty: none), keeping `γs`,
    /// `γv`; refactors as [`Self::refactor`].
    pub fn set_fibres(&mut self, fibres: Vec<super::fibre::FibreFamily>) -> Result<(), SimError> {
        let model = self.model.clone().with_fibres(fibres)?;
        self.replace_model(model)
    }

    fn replace_model(&mut self, model: ElasticModel) -> Result<(), SimError> {
        let old = std::mem::replace(&mut self.model, model);
        let r = self.factorize(false);
        if r.is_err() {
            // Keep the solver usable with its previous materials.
            self.model = old;
            self.factorize(false)?;
        }
        if !self.elastic.update_materials(&self.model)? {
            self.elastic = Box::new(CpuElasticRhs::new(&self.model));
        }
        self.last = None;
        r
    }

    /// New time step Δt (s) and damping (1/s): redoes only the numeric
    /// factorization (or the domain precomputation). The Jacobi backend goes
    /// back to the CPU one (`K` changed); the local-step backend is kept.
    pub fn set_time_step(&mut self, dt: f64, mass_damping: f64) -> Result<(), SimError> {
        let params = PdParams {
            dt,
            mass_damping,
            ..self.params
        };
        self.set_params(params)
    }

    /// New parameters (any field, e.g. [`PdParams::global`]): redoes the
    /// factorization or the domain precomputation. On error the previous
    /// parameters stay in force.
    pub fn set_params(&mut self, params: PdParams) -> Result<(), SimError> {
        params.validate()?;
        let old = std::mem::replace(&mut self.params, params);
        let r = self.factorize(old.global != params.global);
        if r.is_err() {
            self.params = old;
            self.factorize(true)?;
        }
        let total_mass: f64 = self.mass.iter().sum();
        self.energy_floor = 0.5 * total_mass * self.params.max_speed * self.params.max_speed;
        r
    }

    /// Per-tet domain ids for the domain-decomposed solver (e.g. the asset's
    /// `CellData/domain`; any `u32` values), or `None` for the automatic
    /// bisection. Redoes the precomputation when that solver is in use.
    pub fn set_tet_domains(&mut self, ids: Option<&[u32]>) -> Result<(), SimError> {
        if let Some(ids) = ids {
            if ids.len() != self.mesh.num_tets() {
                return Err(SimError::Inconsistent(format!(
                    "{} domain ids for {} tets",
                    ids.len(),
                    self.mesh.num_tets()
                )));
            }
        }
        let old = std::mem::replace(&mut self.tet_domains, ids.map(|i| i.to_vec()));
        if matches!(self.params.global, GlobalSolver::DomainDecomposed(_)) {
            if let Err(e) = self.factorize(false) {
                self.tet_domains = old;
                self.factorize(false)?;
                return Err(e);
            }
        }
        Ok(())
    }

    /// Replaces the local-step backend and, when given, the Jacobi backend
    /// (used by the domain-decomposed solver; `None` keeps the current one).
    /// Backends are built from [`Self::model`], [`Self::free_nodes`] and
    /// [`Self::free_matrix`].
    pub fn set_backend(
        &mut self,
        elastic: Box<dyn ElasticRhs>,
        jacobi: Option<Box<dyn JacobiSolve>>,
    ) {
        self.elastic = elastic;
        if let Some(j) = jacobi {
            self.jacobi = Some(j);
        }
        self.last = None;
    }

    /// State the elastic backend carries between steps that changes the
    /// results (the CPU SVD warm start; [`ElasticRhs::warm_start`]): with
    /// positions and velocities, all a resumed shot needs.
    pub fn warm_start(&self) -> Vec<f64> {
        self.elastic.warm_start()
    }
    /// Restores [`Self::warm_start`] (a checkpoint's).
    pub fn set_warm_start(&mut self, state: &[f64]) -> Result<(), SimError> {
        self.elastic.set_warm_start(state)
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
    /// The free (not pinned) nodes, in the order of the rows of
    /// [`Self::free_matrix`].
    pub fn free_nodes(&self) -> &[usize] {
        &self.free_nodes
    }
    /// Row of every node in [`Self::free_matrix`] (`None`: pinned).
    pub fn free_index(&self) -> &[Option<usize>] {
        &self.free_index
    }
    /// The free block of `K` (both triangles; module doc), for the current
    /// materials and Δt.
    pub fn free_matrix(&self) -> &CsrMatrix {
        &self.k_free
    }
    /// Size of the reduced system when the domain-decomposed solver is in use.
    pub fn dd_stats(&self) -> Option<DdStats> {
        self.dd.as_ref().map(|d| d.stats())
    }
    /// Names of the local-step and Jacobi backends.
    pub fn backend_names(&self) -> (&'static str, Option<&'static str>) {
        (self.elastic.name(), self.jacobi.as_ref().map(|j| j.name()))
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

    /// One implicit-Euler time step (VH Eq. 25) by PD iterations without
    /// colliders: [`Self::step_with_contacts`] with [`NoContact`].
    pub fn step(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
    ) -> Result<StepStats, SimError> {
        self.step_with_contacts(x, v, pinned_positions, &NoContact)
    }

    /// The global solve of one PD iteration: on entry `b` holds the
    /// right-hand side (n x 3, free rows, contact term included), on exit
    /// the new free positions. `xk` are the current free positions, `w` the
    /// contact weights (`None`: no active contact).
    fn global_solve(
        &mut self,
        b: &mut [f64],
        xk: &[f64],
        w: Option<&[f64]>,
    ) -> Result<IterStats, SimError> {
        let nf = self.k_free.n;
        let exact_dd = matches!(
            self.params.global,
            GlobalSolver::DomainDecomposed(dp) if dp.interiors == Interiors::Exact
        );
        if let (Some(dd), Some(jac), false) = (&self.dd, self.jacobi.as_mut(), exact_dd) {
            // Correction system K δ = b - (K + W) x_k (module doc).
            let mut r0 = vec![0.0; 3 * nf];
            mul_plus_diag(&self.k_free, w, xk, &mut r0);
            r0.iter_mut().zip(b.iter()).for_each(|(r, q)| *r = q - *r);
            let mut delta = vec![0.0; 3 * nf];
            dd.reduced_solve(&r0, &mut delta)?;
            let GlobalSolver::DomainDecomposed(dp) = self.params.global else {
                return Err(SimError::Inconsistent("solver state mismatch".into()));
            };
            let st = jac.solve(&r0, w, &mut delta, dp.tolerance, dp.max_iterations)?;
            for ((o, x0), d) in b.iter_mut().zip(xk).zip(&delta) {
                *o = x0 + d;
            }
            return Ok(st);
        }
        if let (Some(w), Some(_)) = (w, &self.factor) {
            if self.contact_solve(b, w)? {
                self.contact_refactors += 1;
            }
            return Ok(IterStats::default());
        }
        // An exact solve with K: the Cholesky factor, or the domain-
        // decomposed solve with exact interiors (a substructuring solve).
        let (factor, dd) = (&self.factor, &self.dd);
        if factor.is_none() && dd.is_none() {
            return Ok(IterStats::default());
        }
        let solve = |r: &[f64], out: &mut [f64]| -> Result<(), SimError> {
            if let Some(f) = factor {
                out.copy_from_slice(r);
                solve_xyz(f, None, out);
                Ok(())
            } else if let Some(dd) = dd {
                dd.reduced_solve(r, out)
            } else {
                Ok(())
            }
        };
        let rhs = b.to_vec();
        solve(&rhs, b)?;
        let Some(w) = w else {
            return Ok(IterStats::default());
        };
        // PCG on (K + W) x = rhs preconditioned by K⁻¹, from x = K⁻¹ rhs
        // (one CG recurrence per coordinate column).
        let x = b;
        let mut r = vec![0.0; 3 * nf];
        mul_plus_diag(&self.k_free, Some(w), x, &mut r);
        r.iter_mut().zip(&rhs).for_each(|(a, q)| *a = q - *a);
        // Relative to the residual of the unconstrained solution `K⁻¹ b`, so
        // the tolerance does not depend on where the mesh is in space.
        let bn = dot3(&r, &r).iter().sum::<f64>().sqrt();
        let mut z = vec![0.0; 3 * nf];
        solve(&r, &mut z)?;
        let mut p = z.clone();
        let mut rz = dot3(&r, &z);
        let mut q = vec![0.0; 3 * nf];
        let tol = self.params.contact_tolerance;
        let mut rel = dot3(&r, &r).iter().sum::<f64>().sqrt() / bn.max(f64::MIN_POSITIVE);
        let mut it = 0;
        while rel > tol && it < self.params.contact_max_iterations {
            it += 1;
            mul_plus_diag(&self.k_free, Some(w), &p, &mut q);
            let pq = dot3(&p, &q);
            let alpha: [f64; 3] =
                std::array::from_fn(|k| if pq[k] > 0.0 { rz[k] / pq[k] } else { 0.0 });
            for i in 0..nf {
                for k in 0..3 {
                    x[3 * i + k] += alpha[k] * p[3 * i + k];
                    r[3 * i + k] -= alpha[k] * q[3 * i + k];
                }
            }
            rel = dot3(&r, &r).iter().sum::<f64>().sqrt() / bn.max(f64::MIN_POSITIVE);
            if !rel.is_finite() {
                break;
            }
            solve(&r, &mut z)?;
            let rz_new = dot3(&r, &z);
            for k in 0..3 {
                let beta = if rz[k] > 0.0 { rz_new[k] / rz[k] } else { 0.0 };
                for i in 0..nf {
                    p[3 * i + k] = z[3 * i + k] + beta * p[3 * i + k];
                }
            }
            rz = rz_new;
        }
        Ok(IterStats {
            iterations: it,
            relative_residual: rel,
        })
    }

    /// Solves `(K + W) x = b` in place (direct solver; `w`: the diagonal of
    /// `W` per free node) with a Cholesky factor of `K + W`. Nodes that
    /// joined the contact set since the factorization in the same step
    /// (at most [`MAX_LOW_RANK_NODES`]) are added by the Woodbury identity
    /// ([`crate::linalg::woodbury`]); otherwise it refactors numerically (symbolic
    /// analysis reused). A factor of another step is reused only for
    /// exactly its weights, so a step's result does not depend on the steps
    /// before it (checkpoint resume). Returns whether it refactored.
    fn contact_solve(&mut self, b: &mut [f64], w: &[f64]) -> Result<bool, SimError> {
        let step = self.steps;
        let most = self.max_low_rank_nodes;
        let joined = self
            .contact_factor
            .as_ref()
            .and_then(|c| c.joined(w, step, most));
        let refactor = match (&mut self.contact_factor, joined) {
            (Some(c), Some(rows)) => !c.add(&rows),
            _ => true,
        };
        if refactor {
            let (lower, diag) = self.k_lower.as_ref().ok_or_else(|| {
                SimError::Inconsistent("no factor of K to add contacts to".into())
            })?;
            let mut a = lower.clone();
            let values = a.val_mut();
            for (&pos, wi) in diag.iter().zip(w) {
                values[pos] += wi;
            }
            let sym = match self.contact_factor.take() {
                Some(c) => c.factor.into_symbolic(),
                None => SparseCholesky::symbolic_supernodal(a.as_ref())
                    .map_err(|e| llt_error(e.to_string()))?,
            };
            let factor =
                SparseCholesky::numeric(sym, a.as_ref()).map_err(|e| llt_error(e.to_string()))?;
            self.contact_factor = Some(ContactFactor {
                weights: w.to_vec(),
                factor,
                step,
                update: LowRankUpdate::default(),
            });
        }
        let Some(c) = &self.contact_factor else {
            return Err(SimError::Inconsistent("contact factor missing".into()));
        };
        solve_xyz(&c.factor, Some(&c.update), b);
        Ok(refactor)
    }

    /// One implicit-Euler time step (VH Eq. 25) by PD iterations with
    /// contacts against `contacts` (module doc): advances `x` (m) and `v`
    /// (m/s) of every node; `pinned_positions` (m) are the pinned nodes'
    /// positions at the end of the step, in the order of [`Self::pinned`]
    /// (their velocities become the finite difference). On error `x` and `v`
    /// are left unchanged.
    pub fn step_with_contacts(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
        contacts: &dyn NodeProjector,
    ) -> Result<StepStats, SimError> {
        let t0 = Instant::now();
        self.step_any(x, v, pinned_positions, Contacts::Nodes(contacts), t0)
    }

    /// [`Self::step_with_contacts`] with the contacts acting on the points
    /// `points` (yarn vertices) instead of on the nodes: `contacts` is
    /// asked about each point at its embedded position, and the constraint
    /// forces reach the nodes through the embedding weights
    /// (`super::contact`, "Contacts at embedded points"). After the last
    /// iteration the nodes of points still not admissible are moved by
    /// their lumped corrections (up to 8 passes), so the points, not the
    /// nodes, end the step outside the colliders.
    pub fn step_with_point_contacts(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
        points: &EmbeddedPoints,
        contacts: &dyn PointProjector,
    ) -> Result<StepStats, SimError> {
        let t0 = Instant::now();
        if let Some(why) = points.check(self.mass.len()) {
            return Err(SimError::Inconsistent(format!("contact points: {why}")));
        }
        self.step_any(
            x,
            v,
            pinned_positions,
            Contacts::Points(points, contacts),
            t0,
        )
    }

    /// Checks the inputs of a step and runs it.
    fn step_any(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
        contacts: Contacts<'_>,
        t0: Instant,
    ) -> Result<StepStats, SimError> {
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
        let free_nodes = self.free_nodes.clone();
        self.step_inner(x, v, pinned_positions, contacts, &free_nodes, step, t0)
            .map_err(|e| match e {
                SimError::Diverged { node, reason, .. } => {
                    SimError::Diverged { step, node, reason }
                }
                other => other,
            })
    }

    #[allow(clippy::too_many_arguments)]
    fn step_inner(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        pinned_positions: &[Vec3],
        contacts: Contacts<'_>,
        free_nodes: &[usize],
        step: u64,
        t0: Instant,
    ) -> Result<StepStats, SimError> {
        let finite = |p: &Vec3| p.iter().all(|c| c.is_finite());
        let p = self.params;
        let dt = p.dt;
        let damp = 1.0 + p.mass_damping * dt;
        let n = self.mass.len();
        let nf = free_nodes.len();
        // Errors of the backends name free rows; map them to nodes.
        let row_to_node = |e: SimError| match e {
            SimError::Diverged { step, node, reason } => SimError::Diverged {
                step,
                node: free_nodes.get(node).copied().unwrap_or(node),
                reason,
            },
            other => other,
        };

        // Inertia target s (free nodes) and the initial guess.
        let mut s = x.to_vec();
        for &i in free_nodes {
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
        let elastic_before = match &self.last {
            Some((xl, e)) if xl.as_slice() == &*x => *e,
            _ => self.model.energy(x)?,
        };
        let energy_before = self.kinetic_energy(v) + elastic_before;

        // Constant part of the right-hand side: mass term minus pinned columns.
        let ms = p.mass_scale();
        let mut rhs0 = vec![0.0; 3 * nf];
        for (fi, &i) in free_nodes.iter().enumerate() {
            for k in 0..3 {
                rhs0[3 * fi + k] = ms * self.mass[i] * s[i][k];
            }
        }
        for &(fi, node, val) in &self.k_fp {
            for k in 0..3 {
                rhs0[3 * fi + k] -= val * xk[node][k];
            }
        }
        // Co-rotated stiffness-proportional damping (module doc): its
        // targets join the right-hand side at every iterate.
        let beta_dt = p.stiffness_damping / dt;
        let damping = self
            .damping_blocks
            .clone()
            .filter(|_| beta_dt > 0.0)
            .map(|b| CorotatedDamping::new(b, x));
        // Its potential at an iterate (J), the targets (β / Δt) Σ_e R_e y
        // and L x per node (the gradient is (β / Δt) L x - targets).
        let damping_at = |xk: &[Vec3]| -> (f64, Vec<Vec3>, Vec<Vec3>) {
            let Some(d) = damping.as_ref() else {
                return (0.0, Vec::new(), Vec::new());
            };
            let (e, t, lx) = d.at(xk);
            let t = t.into_iter().map(|q| q.map(|c| beta_dt * c)).collect();
            (0.5 * beta_dt * e, t, lx)
        };

        let mut objectives = Vec::with_capacity(p.max_iterations as usize + 1);
        let mut iterations = 0u32;
        let mut capped = false;
        let mut convergence = 0.0f64;
        // PdParams::tolerance: the last iterate is the plain PD iterate
        // that met it, its local step still to evaluate.
        let mut converged = false;
        let rest_displacement = STANDARD_GRAVITY * dt * dt;
        let step_scale = (dt / TOLERANCE_REFERENCE_STEP).min(1.0);
        let mean_mass = free_nodes.iter().map(|&i| self.mass[i]).sum::<f64>() / nf.max(1) as f64;
        let mut kx = vec![0.0; 3 * nf];
        let mut clamped_tets = 0usize;
        let mut global_iterations = 0u32;
        self.contact_refactors = 0;
        let mut global_residual = 0.0f64;
        let mut out = vec![[0.0; 3]; n];
        // Each step starts with an empty set: a step depends only on its
        // inputs, so a shot resumed from a checkpoint is bit for bit the
        // uninterrupted one (carrying the last step's set saved 12 of 179
        // refactorizations on the held-out drape, and broke that).
        let mut in_set = vec![false; nf];
        // The same for embedded points, and each node's free row (pinned
        // nodes: none).
        let mut in_points = match contacts {
            Contacts::Points(pts, _) => vec![false; pts.len()],
            Contacts::Nodes(_) => Vec::new(),
        };
        let mut free_index = Vec::new();
        if let Contacts::Points(..) = contacts {
            free_index = vec![usize::MAX; n];
            for (fi, &i) in free_nodes.iter().enumerate() {
                free_index[i] = fi;
            }
        }
        // The weights `w_i` of the nodes in the set (0 elsewhere), and
        // whether any node has joined.
        let mut weights = vec![0.0; nf];
        let mut constrained = false;
        let mut contacts_active: usize;
        let wscale = p.contact_stiffness / (dt * dt);
        let mut rhs = vec![0.0; 3 * nf];
        let mut xf = vec![0.0; 3 * nf];
        let (mut local_ms, mut global_ms) = (0.0, 0.0);
        let mut anderson = (p.anderson_window > 0).then(|| Anderson::new(p.anderson_window));
        // The plain PD iterate while `xk` is an accelerated one.
        let mut fallback: Option<Vec<f64>> = None;
        let mut accelerations_rejected = 0u32;
        let (elastic_after, damping_after) = loop {
            let tl = Instant::now();
            let eval = self.elastic.evaluate(&xk, &mut out)?;
            local_ms += tl.elapsed().as_secs_f64() * 1e3;
            clamped_tets = clamped_tets.max(eval.clamped_tets);
            // Contact targets and weights at the current iterate (local step).
            let stage = match contacts {
                Contacts::Nodes(c) => {
                    node_contact_stage(c, free_nodes, &xk, x, wscale, &self.mass, &in_set)
                }
                Contacts::Points(pts, c) => {
                    point_contact_stage(pts, c, free_nodes, &free_index, &xk, x, wscale, &in_points)
                }
            };
            let contact_energy = stage.energy;
            let inertia: f64 = free_nodes
                .iter()
                .map(|&i| {
                    let d = [xk[i][0] - s[i][0], xk[i][1] - s[i][1], xk[i][2] - s[i][2]];
                    0.5 * ms * self.mass[i] * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                })
                .sum();
            let (damping_energy, damping_targets, _) = damping_at(&xk);
            let phi = inertia + eval.elastic_energy + contact_energy + damping_energy;
            if let Some(plain) = fallback.take() {
                // Safeguard (Peng et al. 2018 Alg. 2): an accelerated
                // iterate must lower Φ, else the plain one replaces it.
                let prev = *objectives.last().unwrap_or(&f64::INFINITY);
                let noise = self.elastic.energy_precision() * eval.elastic_energy.abs();
                if !(phi < prev + noise) {
                    accelerations_rejected += 1;
                    if let Some(a) = anderson.as_mut() {
                        a.reset();
                    }
                    for (fi, &i) in free_nodes.iter().enumerate() {
                        xk[i] = [plain[3 * fi], plain[3 * fi + 1], plain[3 * fi + 2]];
                    }
                    continue;
                }
            }
            contacts_active = stage.active;
            // The iterate is accepted: its new contacts join the set.
            let set = match contacts {
                Contacts::Nodes(_) => &mut in_set,
                Contacts::Points(..) => &mut in_points,
            };
            for &j in &stage.joined {
                set[j] = true;
            }
            // The constrained set only grows within a step: a node (or
            // point) that met a collider keeps its weight with the
            // projection of an admissible point, itself, as target. That is
            // still PD on `½ w dist(x, C)²` (same fixed point), and the
            // weights, hence the factor of `K + W`, change only when one
            // joins; letting them leave made the set chatter at the contact
            // boundary (held-out drape: 452 refactorizations in 474
            // iterations).
            // A node (or point) joining counts even where it adds no weight
            // (a node without mass): it restarts the acceleration's history.
            let grew = !stage.joined.is_empty();
            if grew {
                weights.copy_from_slice(&stage.weights);
            }
            let proj = stage.targets;
            constrained |= grew;
            let changed = grew && iterations > 0;
            objectives.push(phi);
            if nf == 0 || converged {
                break (eval.elastic_energy, damping_targets);
            }
            if iterations >= p.max_iterations {
                capped = true;
                break (eval.elastic_energy, damping_targets);
            }
            rhs.copy_from_slice(&rhs0);
            for (fi, &i) in free_nodes.iter().enumerate() {
                for k in 0..3 {
                    rhs[3 * fi + k] += out[i][k] + damping_targets.get(i).map_or(0.0, |q| q[k]);
                    xf[3 * fi + k] = xk[i][k];
                }
            }
            for (fi, q) in proj.iter().enumerate() {
                if weights[fi] > 0.0 {
                    let q = q.unwrap_or(xk[free_nodes[fi]]);
                    for k in 0..3 {
                        rhs[3 * fi + k] += weights[fi] * q[k];
                    }
                }
            }
            // The residual force ∇Φ(x_k) = (K + W) x_k - rhs (the projections
            // minimize the surrogate at x_k) as the move it gives a node's
            // mass in one step: what the slow contact and friction modes
            // leave unbalanced (PdParams::tolerance).
            mul_plus_diag(
                &self.k_free,
                constrained.then_some(&weights[..]),
                &xf,
                &mut kx,
            );
            let unbalanced = (0..nf)
                .into_par_iter()
                .with_min_len(super::jacobi::MIN_ROWS_PER_TASK)
                .map(|fi| {
                    let r = norm(std::array::from_fn(|k| kx[3 * fi + k] - rhs[3 * fi + k]));
                    r / (ms * self.mass[free_nodes[fi]].max(mean_mass))
                })
                .reduce(|| 0.0, f64::max);
            let tg = Instant::now();
            let st = self
                .global_solve(&mut rhs, &xf, constrained.then_some(&weights[..]))
                .map_err(row_to_node)?;
            global_ms += tg.elapsed().as_secs_f64() * 1e3;
            global_iterations += st.iterations;
            global_residual = global_residual.max(st.relative_residual);
            // `rhs` now holds the plain PD iterate G(x_k) = x_k - A⁻¹ ∇Φ(x_k)
            // (A the PD matrix with the contact weights; the projections
            // minimize the surrogate at x_k, so its gradient is Φ's): the
            // plain move is the residual in the metric of A.
            // Convergence (PdParams::tolerance) compares it with the step's
            // displacement.
            let (moved, displaced) = (0..nf)
                .into_par_iter()
                .with_min_len(super::jacobi::MIN_ROWS_PER_TASK)
                .map(|fi| {
                    let i = free_nodes[fi];
                    let g = &rhs[3 * fi..3 * fi + 3];
                    let m = norm(std::array::from_fn(|k| g[k] - xf[3 * fi + k]));
                    let d = norm(std::array::from_fn(|k| g[k] - x[i][k]));
                    (m, d)
                })
                .reduce(|| (0.0, 0.0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
            convergence = moved.max(unbalanced) / (displaced.max(rest_displacement) * step_scale);
            converged = p.tolerance > 0.0 && convergence <= p.tolerance;
            // With acceleration the mixed iterate replaces the plain one and
            // that is kept as the fallback; a converged step ends on the
            // plain iterate.
            if let Some(a) = anderson.as_mut().filter(|_| !converged) {
                if changed {
                    a.reset();
                }
                let mixed = a.step(&xf, &rhs);
                if !mixed.iter().all(|v| v.is_finite()) {
                    // Overflow in the mixing: take the plain iterate.
                    a.reset();
                } else if mixed != rhs {
                    fallback = Some(std::mem::replace(&mut rhs, mixed));
                }
            }
            for (fi, &i) in free_nodes.iter().enumerate() {
                xk[i] = [rhs[3 * fi], rhs[3 * fi + 1], rhs[3 * fi + 2]];
            }
            iterations += 1;
            if let Some(fi) = (0..nf).find(|&fi| !finite(&xk[free_nodes[fi]])) {
                return Err(SimError::Diverged {
                    step,
                    node: free_nodes[fi],
                    reason: format!("position not finite after PD iteration {iterations}"),
                });
            }
        };

        // Hard guarantee: no free node (or embedded point) ends the step
        // inside a collider (and a sticking one keeps its place on the
        // surface: no creep).
        let (projected, max_projection) = match contacts {
            Contacts::Nodes(c) => {
                let fixes: Vec<(usize, Vec3)> = free_nodes
                    .par_iter()
                    .filter_map(|&i| contact_target(c, i, xk[i], x[i]).map(|q| (i, q)))
                    .collect();
                let mut max_projection = 0.0f64;
                for &(i, q) in &fixes {
                    max_projection =
                        max_projection.max(norm(std::array::from_fn(|k| q[k] - xk[i][k])));
                    xk[i] = q;
                }
                (fixes.len(), max_projection)
            }
            Contacts::Points(pts, c) => fix_points(pts, c, &free_index, &mut xk, x),
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
        let residual = if p.report_residual && projected == 0 && nf > 0 {
            // The last local step ran at these positions, and for the PD
            // energy ∇E(x) = K_el x - b_el(x) (the projections minimize it),
            // so ∇Φ = K x - rhs0 - out: one product with K instead of a
            // gradient evaluation (another SVD per tet).
            for (fi, &i) in free_nodes.iter().enumerate() {
                xf[3 * fi..3 * fi + 3].copy_from_slice(&xk[i]);
            }
            let mut kx = vec![0.0; 3 * nf];
            mul_plus_diag(&self.k_free, None, &xf, &mut kx);
            (0..nf)
                .map(|fi| {
                    let i = free_nodes[fi];
                    norm(std::array::from_fn(|k| {
                        kx[3 * fi + k]
                            - rhs0[3 * fi + k]
                            - out[i][k]
                            - damping_after.get(i).map_or(0.0, |q| q[k])
                    }))
                })
                .fold(0.0, f64::max)
        } else if p.report_residual {
            let grad = self.model.gradient(&xk)?;
            let (_, dtargets, dlx) = damping_at(&xk);
            free_nodes
                .iter()
                .map(|&i| {
                    norm(std::array::from_fn(|k| {
                        ms * self.mass[i] * (xk[i][k] - s[i][k])
                            + grad[i][k]
                            + dlx.get(i).map_or(0.0, |l| beta_dt * l[k])
                            - dtargets.get(i).map_or(0.0, |q| q[k])
                    }))
                })
                .fold(0.0, f64::max)
        } else {
            f64::NAN
        };

        x.copy_from_slice(&xk);
        v.copy_from_slice(&v_new);
        // The energy guard's "before" value for the next step: exact when no
        // contact fix moved a node after the last evaluation, else the last
        // PD iterate's, off by the fixes' small moves (the guard bounds growth
        // by `energy_blowup`, 1e6 by default). Re-evaluating it took a cold
        // SVD of every tet per step in contact, about 1/8 of the local steps.
        self.last = Some((xk, elastic_after));
        Ok(StepStats {
            step,
            iterations,
            capped,
            convergence,
            objective_initial: objectives[0],
            objective_final: *objectives.last().unwrap_or(&0.0),
            objectives,
            residual,
            max_speed,
            clamped_tets,
            solver: p.global.name(),
            backend: self.elastic.name(),
            global_iterations,
            global_residual,
            contact_refactors: self.contact_refactors,
            contacts: contacts_active,
            projected,
            max_projection,
            accelerations_rejected,
            local_ms,
            global_ms,
            ms: t0.elapsed().as_secs_f64() * 1e3,
        })
    }
}

/// The contacts of one PD iterate: per free row its target (None: the
/// node's own position) and weight (0: not constrained), the contact
/// energy (J), the active contacts (nodes or points) and those of them
/// not yet in the step's set (free rows or points), which join it once the
/// iterate is accepted.
struct ContactStage {
    targets: Vec<Option<Vec3>>,
    weights: Vec<f64>,
    energy: f64,
    active: usize,
    joined: Vec<usize>,
}

/// [`ContactStage`] of the free nodes at `xk` (started the step at `x`)
/// against node projections; `in_set` (per free row) marks the nodes that
/// have met a collider in this step.
fn node_contact_stage(
    contacts: &dyn NodeProjector,
    free_nodes: &[usize],
    xk: &[Vec3],
    x: &[Vec3],
    wscale: f64,
    mass: &[f64],
    in_set: &[bool],
) -> ContactStage {
    let targets: Vec<Option<Vec3>> = free_nodes
        .par_iter()
        .with_min_len(super::jacobi::MIN_ROWS_PER_TASK)
        .map(|&i| contact_target(contacts, i, xk[i], x[i]))
        .collect();
    let mut energy = 0.0;
    let mut active = 0;
    let mut joined = Vec::new();
    for (fi, q) in targets.iter().enumerate() {
        if let Some(q) = q {
            let i = free_nodes[fi];
            let d: Vec3 = std::array::from_fn(|k| xk[i][k] - q[k]);
            energy += 0.5 * wscale * mass[i] * dot_v(d, d);
            active += 1;
            if !in_set[fi] {
                joined.push(fi);
            }
        }
    }
    let weights = (0..free_nodes.len())
        .map(|fi| {
            if in_set[fi] || targets[fi].is_some() {
                wscale * mass[free_nodes[fi]]
            } else {
                0.0
            }
        })
        .collect();
    ContactStage {
        targets,
        weights,
        energy,
        active,
        joined,
    }
}

/// The friction target of each embedded point at node positions `xk`
/// (started the step at `x`) minus its position, None where admissible.
fn point_corrections(
    points: &EmbeddedPoints,
    contacts: &dyn PointProjector,
    xk: &[Vec3],
    x: &[Vec3],
) -> Vec<Option<Vec3>> {
    (0..points.len())
        .into_par_iter()
        .with_min_len(super::jacobi::MIN_ROWS_PER_TASK)
        .map(|j| {
            let y = points.position(j, xk);
            let c = contacts.contact(j, y)?;
            let mut t = friction_target(&c, y, points.position(j, x));
            if t != c.target {
                // As for nodes (contact_target): friction can move the
                // target back into a concave collider.
                if let Some(q) = contacts.contact(j, t) {
                    t = q.target;
                }
            }
            Some(std::array::from_fn(|k| t[k] - y[k]))
        })
        .collect()
}

/// [`ContactStage`] of the embedded points at `xk` (started the step at
/// `x`), lumped onto the free rows (`free_nodes`: each row's node; `free_index`: each node's free row,
/// `usize::MAX` when pinned; `super::contact`, "Contacts at embedded
/// points"); `in_set` (per point) as [`node_contact_stage`]'s.
#[allow(clippy::too_many_arguments)]
fn point_contact_stage(
    points: &EmbeddedPoints,
    contacts: &dyn PointProjector,
    free_nodes: &[usize],
    free_index: &[usize],
    xk: &[Vec3],
    x: &[Vec3],
    wscale: f64,
    in_set: &[bool],
) -> ContactStage {
    let nf = free_nodes.len();
    let corr = point_corrections(points, contacts, xk, x);
    let mut weights = vec![0.0; nf];
    let mut force = vec![[0.0; 3]; nf];
    let mut energy = 0.0;
    let mut active = 0;
    let mut joined = Vec::new();
    for (j, d) in corr.iter().enumerate() {
        if let Some(d) = d {
            if !in_set[j] {
                joined.push(j);
            }
            active += 1;
            energy += 0.5 * wscale * points.mass[j] * dot_v(*d, *d);
        } else if !in_set[j] {
            continue;
        }
        let wj = wscale * points.mass[j];
        for a in 0..4 {
            let fi = free_index[points.nodes[j][a] as usize];
            if fi == usize::MAX {
                continue;
            }
            let w = wj * points.weights[j][a];
            weights[fi] += w;
            if let Some(d) = d {
                for k in 0..3 {
                    force[fi][k] += w * d[k];
                }
            }
        }
    }
    let targets = (0..nf)
        .map(|fi| {
            (weights[fi] > 0.0).then(|| {
                let p = xk[free_nodes[fi]];
                std::array::from_fn(|k| p[k] + force[fi][k] / weights[fi])
            })
        })
        .collect();
    ContactStage {
        targets,
        weights,
        energy,
        active,
        joined,
    }
}

/// End-of-step fix-up for embedded points: up to [`POINT_FIX_PASSES`]
/// passes, each moving the free nodes of the points still in contact by
/// their mass-weighted lumped correction. Returns the nodes moved and the
/// largest total move (m).
fn fix_points(
    points: &EmbeddedPoints,
    contacts: &dyn PointProjector,
    free_index: &[usize],
    xk: &mut [Vec3],
    x: &[Vec3],
) -> (usize, f64) {
    let n = xk.len();
    let start = xk.to_vec();
    let mut moved = vec![false; n];
    for _ in 0..POINT_FIX_PASSES {
        let corr = point_corrections(points, contacts, xk, x);
        if corr.iter().all(|d| d.is_none()) {
            break;
        }
        let mut num = vec![[0.0; 3]; n];
        let mut den = vec![0.0; n];
        for (j, d) in corr.iter().enumerate() {
            let Some(d) = d else { continue };
            for a in 0..4 {
                let i = points.nodes[j][a] as usize;
                if free_index[i] == usize::MAX {
                    continue;
                }
                let w = points.mass[j] * points.weights[j][a];
                den[i] += w;
                for k in 0..3 {
                    num[i][k] += w * d[k];
                }
            }
        }
        for i in 0..n {
            if den[i] > 0.0 {
                for k in 0..3 {
                    xk[i][k] += num[i][k] / den[i];
                }
                moved[i] = true;
            }
        }
    }
    let most = (0..n)
        .filter(|&i| moved[i])
        .map(|i| norm(std::array::from_fn(|k| xk[i][k] - start[i][k])))
        .fold(0.0, f64::max);
    (moved.iter().filter(|&&m| m).count(), most)
}

fn dot_v(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The constraint target of free node `i` at `p` that started the step at
/// `start`: its contact's projection with Coulomb friction
/// ([`friction_target`]), None when admissible.
fn contact_target(contacts: &dyn NodeProjector, i: usize, p: Vec3, start: Vec3) -> Option<Vec3> {
    let c = contacts.contact(i, p)?;
    let t = friction_target(&c, p, start);
    if t == c.target {
        return Some(t);
    }
    // The friction moves the target along the contact's tangent plane, which
    // can enter a concave collider (a crease, a second collider) or its
    // thickness band: project it again, so the end-of-step guarantee holds.
    Some(contacts.project(i, t).unwrap_or(t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embed::box_mesh;
    use crate::sim::collide::{Collider, ColliderSet, Shape};
    use crate::sim::contact::Contact;

    /// Points must stay above y = 0 by 1 mm (frictionless).
    struct Floor;
    impl PointProjector for Floor {
        fn contact(&self, _point: usize, p: Vec3) -> Option<Contact> {
            (p[1] < 1e-3).then_some(Contact {
                target: [p[0], 1e-3, p[2]],
                surface_motion: [0.0; 3],
                friction: 0.0,
            })
        }
    }

    /// The co-rotated damping potential costs nothing for a rigid motion of
    /// the step's start (a rotation by 0.7 rad and a shift), and its
    /// gradient `L x - targets` is the potential's derivative (central
    /// differences; the optimal rotations make it exact, by the envelope
    /// theorem) at a deformed iterate.
    #[test]
    fn corotated_damping_is_free_for_rigid_motion_and_its_gradient_matches_differences() {
        let (mesh, _) = box_mesh([2, 2, 1], 0.01, 100.0);
        let nt = mesh.num_tets();
        let model = ElasticModel::new(&mesh, &vec![2.0; nt], &vec![5.0; nt]).unwrap();
        let blocks: Vec<DampingBlock> = (0..nt)
            .map(|e| (model.rest()[e].nodes, element_block(&model, e)))
            .collect();
        for (_, le) in &blocks {
            for row in le {
                assert!(row.iter().sum::<f64>().abs() < 1e-9 * row[0].abs().max(1.0));
            }
        }
        let blocks = std::sync::Arc::new(blocks);
        let start: Vec<Vec3> = mesh
            .nodes
            .iter()
            .map(|p| [p[0] * 1.05, p[1] + 0.1 * p[0], p[2] * 0.97])
            .collect();
        let rot = nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.7)
            * nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), 0.3);
        let rigid: Vec<Vec3> = start
            .iter()
            .map(|p| (rot * Vector3::from(*p) + Vector3::new(0.02, -0.01, 0.3)).into())
            .collect();
        let xk: Vec<Vec3> = rigid
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let s = (i as f64 * 0.37).sin();
                [
                    p[0] + 1e-3 * s,
                    p[1] - 2e-3 * s * s,
                    p[2] + 5e-4 * (i % 3) as f64,
                ]
            })
            .collect();
        let d = CorotatedDamping::new(blocks, &start);
        let total: f64 = d.start.iter().sum();
        {
            let (e_rigid, t, lx) = d.at(&rigid);
            let (e_start, _, _) = d.at(&start);
            let scale = start.len() as f64 * 1e-3;
            assert!(e_rigid.abs() < 1e-9 * total, "{e_rigid} (start {total})");
            assert!(e_start.abs() < 1e-9 * total, "{e_start}");
            for (l, q) in lx.iter().zip(&t) {
                for k in 0..3 {
                    assert!((l[k] - q[k]).abs() < 1e-9 * scale, "{l:?} {q:?}");
                }
            }
            let (e0, t, lx) = d.at(&xk);
            assert!(e0 > 0.0);
            let h = 1e-7;
            let mut worst = 0.0f64;
            let mut largest = 0.0f64;
            for i in 0..xk.len() {
                for k in 0..3 {
                    let mut xp = xk.clone();
                    xp[i][k] += h;
                    let mut xm = xk.clone();
                    xm[i][k] -= h;
                    // d/dx of |F - R F*|² is twice the gradient L x - targets.
                    let fd = (d.at(&xp).0 - d.at(&xm).0) / (2.0 * h) / 2.0;
                    let g = lx[i][k] - t[i][k];
                    worst = worst.max((fd - g).abs());
                    largest = largest.max(g.abs());
                }
            }
            assert!(worst < 1e-5 * largest, "worst {worst} of {largest}");
        }
    }

    /// A point alone in its tet is put on its target by one lumped pass:
    /// all four nodes move by its correction; a second point sharing no
    /// node is untouched.
    #[test]
    fn one_point_in_a_tet_lands_on_its_target_in_one_fix_pass() {
        let (mesh, _) = box_mesh([3, 1, 1], 0.01, 100.0);
        let tet = mesh.tets[0];
        let far = *mesh
            .tets
            .iter()
            .find(|t| t.iter().all(|a| !tet.contains(a)))
            .expect("a tet sharing no node");
        let pts = EmbeddedPoints {
            nodes: vec![tet, far],
            weights: vec![[0.1, 0.2, 0.3, 0.4], [0.25; 4]],
            mass: vec![1e-4, 1e-4],
        };
        // Lower the first tet's nodes so its point is 2 mm deep.
        let mut x = mesh.nodes.clone();
        let y = pts.position(0, &x)[1];
        assert!(pts.position(1, &x)[1] > 1e-3);
        for &a in &tet {
            x[a as usize][1] -= y + 2e-3;
        }
        let start = x.clone();
        let free_index: Vec<usize> = (0..x.len()).collect();
        let (moved, most) = fix_points(&pts, &Floor, &free_index, &mut x, &start);
        let after = pts.position(0, &x);
        assert!((after[1] - 1e-3).abs() < 1e-15, "{after:?}");
        assert_eq!(moved, 4);
        assert!((most - 3e-3).abs() < 1e-12, "{most}");
        for &a in &far {
            if !tet.contains(&a) {
                assert_eq!(x[a as usize], start[a as usize]);
            }
        }
    }

    #[test]
    fn contact_points_that_do_not_fit_the_mesh_are_refused() {
        let (mesh, mass) = box_mesh([1, 1, 1], 0.01, 100.0);
        let nt = mesh.num_tets();
        let mut solver = PdSolver::new(
            &mesh,
            &mass,
            &vec![1e4; nt],
            &vec![1e4; nt],
            &[],
            PdParams::default(),
        )
        .unwrap();
        let n = mesh.num_nodes();
        let (mut x, mut v) = (mesh.nodes.clone(), vec![[0.0; 3]; n]);
        let good = EmbeddedPoints {
            nodes: vec![mesh.tets[0]],
            weights: vec![[0.25; 4]],
            mass: vec![1e-4],
        };
        for bad in [
            EmbeddedPoints {
                nodes: vec![[0, 1, 2, n as u32]],
                ..good.clone()
            },
            EmbeddedPoints {
                mass: vec![0.0],
                ..good.clone()
            },
            EmbeddedPoints {
                weights: vec![[f64::NAN, 0.25, 0.25, 0.25]],
                ..good.clone()
            },
            EmbeddedPoints {
                mass: vec![],
                ..good.clone()
            },
        ] {
            let e = solver
                .step_with_point_contacts(&mut x, &mut v, &[], &bad, &Floor)
                .unwrap_err();
            assert!(e.to_string().contains("contact points"), "{e}");
        }
        assert!(solver
            .step_with_point_contacts(&mut x, &mut v, &[], &good, &Floor)
            .is_ok());
    }

    /// A step that uses every iteration without meeting the tolerance says
    /// so; one that meets it, or stops on it, does not.
    #[test]
    fn a_step_at_the_iteration_cap_is_marked_capped() {
        let (mesh, mass) = box_mesh([3, 1, 3], 0.01, 120.0);
        let nt = mesh.num_tets();
        let (gs, gv) = (vec![1e4; nt], vec![1e4; nt]);
        let pinned: Vec<usize> = (0..mesh.num_nodes())
            .filter(|&i| mesh.nodes[i][0] < 1e-9)
            .collect();
        let step = |max_iterations: u32, tolerance: f64| {
            let params = PdParams {
                max_iterations,
                tolerance,
                ..PdParams::default()
            };
            let mut pd = PdSolver::new(&mesh, &mass, &gs, &gv, &pinned, params).unwrap();
            let mut x = mesh.nodes.clone();
            let mut v = vec![[0.0; 3]; x.len()];
            let pins: Vec<Vec3> = pinned.iter().map(|&i| mesh.nodes[i]).collect();
            pd.step_with_contacts(&mut x, &mut v, &pins, &crate::sim::contact::NoContact)
                .unwrap()
        };
        let capped = step(3, 0.0);
        assert_eq!((capped.iterations, capped.capped), (3, true));
        // A tolerance any iteration meets stops after the first one, and
        // one a few iterations meet stops short of the cap.
        let at_once = step(50, 1e30);
        assert_eq!((at_once.iterations, at_once.capped), (1, false));
        let met = step(50, 1e-2);
        assert!(
            met.iterations > 1 && met.iterations < 50 && !met.capped,
            "{} iterations",
            met.iterations
        );
        assert!(met.convergence <= 1e-2, "{}", met.convergence);
        assert!(capped.convergence > 1e-2, "{}", capped.convergence);
    }

    #[test]
    fn joining_contacts_by_woodbury_match_refactoring() {
        // A 6 x 2 x 6 cm slab falling at 0.5 m/s onto a sphere: its contact
        // set grows within steps. Added by the Woodbury identity or by
        // refactoring, the steps agree to rounding.
        let (mesh, mass) = box_mesh([6, 2, 6], 0.01, 120.0);
        let nt = mesh.num_tets();
        let (gs, gv) = (vec![1e4; nt], vec![1e4; nt]);
        let sphere = ColliderSet {
            colliders: vec![Collider {
                shape: Shape::Sphere {
                    center: [0.03, -0.5 + 1e-3, 0.03],
                    radius: 0.5,
                },
                thickness: 0.0,
            }],
            friction: 0.5,
        };
        let run = |most: usize| {
            let mut pd = PdSolver::new(&mesh, &mass, &gs, &gv, &[], PdParams::default()).unwrap();
            pd.max_low_rank_nodes = most;
            let mut x = mesh.nodes.clone();
            let mut v = vec![[0.0, -0.5, 0.0]; x.len()];
            let (mut refactors, mut most_contacts) = (0, 0);
            for _ in 0..20 {
                let st = pd.step_with_contacts(&mut x, &mut v, &[], &sphere).unwrap();
                refactors += st.contact_refactors;
                most_contacts = most_contacts.max(st.contacts);
            }
            (x, refactors, most_contacts)
        };
        let (x_wb, refactors_wb, contacts) = run(MAX_LOW_RANK_NODES);
        let (x_re, refactors_re, _) = run(0);
        assert!(contacts >= 10, "too few contacts to test: {contacts}");
        assert!(
            refactors_wb < refactors_re,
            "Woodbury path not taken: {refactors_wb} against {refactors_re} refactorizations"
        );
        let worst = x_wb
            .iter()
            .zip(&x_re)
            .map(|(a, b)| norm(std::array::from_fn(|k| a[k] - b[k])))
            .fold(0.0, f64::max);
        assert!(worst < 1e-12, "positions differ by {worst} m");
    }

    #[test]
    fn friction_target_in_a_concave_corner_stays_admissible() {
        // Floor y = 0 and wall x = 0 (1 mm thickness each); a node in the
        // corner's band that slid 2.5 mm toward the wall: the kinetic
        // friction pulls its target back along the mixed contact normal,
        // which by itself would leave it 0.5 mm above the floor, inside the
        // band.
        let plane = |normal: Vec3| Collider {
            shape: Shape::Plane {
                point: [0.0; 3],
                normal,
            },
            thickness: 1e-3,
        };
        let set = ColliderSet {
            colliders: vec![plane([0.0, 1.0, 0.0]), plane([1.0, 0.0, 0.0])],
            friction: 1.0,
        };
        let (p, start) = ([5e-4, -2e-4, 0.0], [3e-3, 1e-3, 0.0]);
        let c = set.contact(0, p).unwrap();
        let raw = friction_target(&c, p, start);
        assert!(raw[1] < 0.9e-3, "the case must leave the band: {raw:?}");
        let t = contact_target(&set, 0, p, start).unwrap();
        assert!(set.project(0, t).is_none(), "{t:?} is not admissible");
        assert!(t[0] > c.target[0], "friction pulled it back: {t:?}");
    }
}
