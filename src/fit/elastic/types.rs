//! The elasticity fit's shared types: its parameters, errors, samples and
//! frames, the material fields it learns, the solver settings and the
//! progress records every stage reports. A leaf: it names no other file of
//! the fit.

use super::force_loss::ForceTarget;
use super::loss::FrameTarget;
use crate::geom::{TetMesh, Vec3};
use crate::sim::energy::ElasticModel;
use crate::sim::fibre::FibreFamily;
use crate::sim::statics::StaticParams;

/// Errors of elasticity fitting. Every error about a sample names it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ElasticFitError {
    /// Inputs that do not fit together (lengths, indices, parameters).
    #[error("inconsistent inputs: {0}")]
    Inconsistent(String),
    /// A sample that cannot be fitted: its frame has no equilibrium, a
    /// non-finite value or an inverted target, or the loss became non-finite.
    #[error("sample '{sample}' frame {frame}: {message}")]
    Sample {
        sample: String,
        frame: usize,
        message: String,
    },
    /// The harmonic basis could not be computed.
    #[error("harmonic basis: {0}")]
    Harmonic(String),
}

/// Per-element materials (Pa), one value per tet: VH Eq. 7's `γs`, `γv`
/// and the fibre families' stiffnesses ([`crate::sim::fibre`]; their rest
/// directions are fixed by the asset, only their `γ` are fitted).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MaterialFields {
    pub gamma_s: Vec<f64>,
    pub gamma_v: Vec<f64>,
    /// Fibre families (empty: Eq. 7 alone).
    #[serde(skip)]
    pub fibres: Vec<FibreFamily>,
}

impl MaterialFields {
    /// The same `gamma_s`, `gamma_v` (Pa) on `n` tets, no fibres.
    pub fn uniform(n: usize, gamma_s: f64, gamma_v: f64) -> Self {
        MaterialFields {
            gamma_s: vec![gamma_s; n],
            gamma_v: vec![gamma_v; n],
            fibres: Vec::new(),
        }
    }
    /// Number of fitted fields: `γs`, `γv`, one per fibre family and one
    /// more per stiffening family (its `β`).
    pub fn num_fields(&self) -> usize {
        2 + self.fibres.len() + self.fibres.iter().filter(|f| f.stiffening()).count()
    }
    /// `[γs; γv; γ_1; ...; β_1; ...]` stacked (the `γ` of VH Eq. 23, fibre
    /// families' stiffnesses appended, then the stiffening families' `β`).
    /// Every field is positive, so the fit works in its logarithm.
    pub fn stacked(&self) -> Vec<f64> {
        let mut g = self.gamma_s.clone();
        g.extend_from_slice(&self.gamma_v);
        for f in &self.fibres {
            g.extend_from_slice(&f.gamma);
        }
        for f in self.fibres.iter().filter(|f| f.stiffening()) {
            g.extend_from_slice(&f.beta);
        }
        g
    }
    /// These fields (fibre directions included) with the stiffnesses of
    /// `g`, stacked as [`Self::stacked`] gives them.
    pub fn with_stacked(&self, g: &[f64]) -> Self {
        let n = self.gamma_s.len();
        debug_assert_eq!(g.len(), n * self.num_fields());
        let nfib = self.fibres.len();
        let mut next_beta = 2 + nfib;
        MaterialFields {
            gamma_s: g[..n].to_vec(),
            gamma_v: g[n..2 * n].to_vec(),
            fibres: self
                .fibres
                .iter()
                .enumerate()
                .map(|(k, f)| FibreFamily {
                    directions: f.directions.clone(),
                    gamma: g[(2 + k) * n..(3 + k) * n].to_vec(),
                    beta: if f.stiffening() {
                        next_beta += 1;
                        g[(next_beta - 1) * n..next_beta * n].to_vec()
                    } else {
                        Vec::new()
                    },
                })
                .collect(),
        }
    }
    /// The elastic model of `mesh` with these materials.
    pub fn model(&self, mesh: &TetMesh) -> Result<ElasticModel, crate::sim::SimError> {
        ElasticModel::new(mesh, &self.gamma_s, &self.gamma_v)?.with_fibres(self.fibres.clone())
    }
}

/// One target frame of a training sample: where the mesh should be (the loss
/// targets, from Y2V) and the boundary conditions under which the mesh is
/// brought to equilibrium (quasi-static, VH Eq. 14 without inertia).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Loss targets (VH Eq. 10).
    pub target: FrameTarget,
    /// Pinned (handled) nodes: Dirichlet constraints held at `start`.
    pub pinned: Vec<usize>,
    /// Start positions of the equilibrium solve (m); the pinned nodes keep
    /// theirs. The Y2V positions of the frame are a good choice.
    pub start: Vec<Vec3>,
    /// External node forces (N): reaction forces of the yarn-level pose,
    /// gravity `m_i g`, ...
    pub f_ext: Vec<Vec3>,
    /// The clamp-force term of the loss ([`super::force_loss`]), where the
    /// frame's yarn-level run recorded the forces its clamps held; None:
    /// positions only (VH Eq. 10).
    pub forces: Option<ForceTarget>,
}

impl Frame {
    /// The frame's loss (m³) at equilibrium `x` under `model`: VH Eq. 10
    /// plus the clamp-force term where the frame has one (non-finite when
    /// the model cannot be evaluated at `x`).
    pub fn loss(&self, model: &ElasticModel, x: &[Vec3]) -> f64 {
        let positions = self.target.loss(model, x);
        match &self.forces {
            None => positions,
            Some(t) => match model.gradient(x) {
                Ok(g) => positions + t.loss(x, &g, &self.f_ext),
                Err(_) => f64::NAN,
            },
        }
    }
}

/// A training sample (VH §6.4): one or more frames fitted together.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Name used in reports and errors (e.g. the pose file).
    pub name: String,
    /// Its frames.
    pub frames: Vec<Frame>,
    /// Eq. 22 weight `w_k` (J): the elastic energy stored in the yarn-level
    /// pose; > 0 and finite.
    pub energy: f64,
}

/// Parameters of [`fit_materials`] and [`fit_sample`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ElasticFitParams {
    /// Harmonic ranks fitted before the full per-element field (VH §6.5).
    /// Default `[1, 10, 30]`; empty fits the full field directly. Ranks at or
    /// above the number of tets are skipped.
    pub harmonic_ranks: Vec<usize>,
    /// Whether the full per-element field is fitted after the harmonic
    /// stages. Default true.
    pub full_stage: bool,
    /// Whether a sample with external forces starts with a search over one
    /// common factor of the whole field (`scale_search`: doublings while the
    /// loss falls, then golden section on its logarithm). Default true.
    pub scale_search: bool,
    /// Whether the full stage works on `θ = ln γ` (multiplicative updates
    /// `γ ← γ e^{t dθ}`, gradient `γ ∂ε/∂γ`, Gauss-Newton damping scaled by
    /// `(γ_rms/γ_j)²`, i.e. Eq. 21 with Marquardt's diagonal in θ) instead
    /// of VH §6.3's additive steps with projection to the floor and
    /// pivoting. Default true: positivity without clamping, and at high
    /// contrast the additive steps drive hundreds of soft elements to the
    /// floor and stall (100x band: loss ~9e2x down, 236 elements clamped)
    /// where θ clamps none and the loss falls ~5e8x. Both recover the
    /// elements the poses determine; elsewhere (directions the Eq. 19
    /// matrix barely sees) the result follows the path, and on a 10x band
    /// the additive path stays closer to the truth (measured in `tests.rs`,
    /// synthetic recovery).
    pub full_stage_log: bool,
    /// Gradient-descent iterations at the start of every stage (VH §6.3:
    /// 10-15). Default 12.
    pub gd_iterations: u32,
    /// Gauss-Newton iterations after them, per stage (VH §6.3: 20-30).
    /// Default 50: a stage ends earlier once the loss stops falling, stalls
    /// (`stall_decrease`) or reaches `loss_stop`, and the full stage of a
    /// 100x band needs ~45
    /// (measured in `tests.rs`, synthetic recovery).
    pub gn_iterations: u32,
    /// Most conjugate-gradient iterations of a full-field Gauss-Newton
    /// direction on systems too large to factor (Eq. 21 above 60K
    /// unknowns; each iteration two solves per frame). Default 300. On the
    /// 26 x 26 rib at VH's size (12.7K nodes, stretch and bend poses, 2
    /// frames each) 100 fits in 18.4 min instead of 40.4 and reaches a 1%
    /// lower stretch loss, but a 2.2x higher bend loss (the folded field's
    /// loss 8.6% higher): the bend's directions need the longer solves.
    pub cg_iterations: usize,
    /// Largest Eq. 21 system (unknowns: twice the free DOFs of every frame
    /// plus the parameters) of a full stage solved by sparse LU;
    /// larger ones go to conjugate gradients. Default
    /// [`KKT_MAX_UNKNOWNS`] (60K): the LU's fill-in grows far
    /// beyond the matrix (a 12.7K-node rib, 2 frames: 250 s and 7 GB per
    /// step).
    pub direct_max_unknowns: usize,
    /// First trial step of gradient descent (dimensionless): the direction
    /// is scaled so that a step of 1 changes the most sensitive `γ` by the
    /// RMS of the current `γ`. Default 0.01 (VH §6.3).
    pub gd_step: f64,
    /// First trial step of Gauss-Newton (dimensionless). Default 1.0 (VH §6.3).
    pub gn_step: f64,
    /// Line-search halvings before an iteration gives up (the stage then
    /// ends). Default 10.
    pub max_halvings: u32,
    /// Levenberg-Marquardt damping, relative: `κ = kappa · ε / (m γ_rms²)`
    /// for `m` parameters at loss `ε` (the damping shrinks with the residual,
    /// as in Yamashita-Fukushima LM). Default 1e-3.
    pub kappa: f64,
    /// Floor of every `γ` (Pa): projected values (VH §6.3). Default 1e-3.
    pub gamma_floor: f64,
    /// Relative force residual of every equilibrium solve (dimensionless,
    /// [`crate::sim::statics`]); must be <= 1e-5 (VH §8: before any
    /// gradient). Default 1e-6: the force of Eq. 7 is evaluated to about
    /// 1e-8 relative (the SL(3) projection is iterative), so much tighter
    /// values may not be reachable.
    pub equilibrium_tolerance: f64,
    /// Newton iteration cap of every equilibrium solve. Default 100.
    pub equilibrium_iterations: u32,
    /// A sample's fit stops once its loss is at most this fraction of its
    /// starting loss (dimensionless). Default 1e-10.
    pub loss_stop: f64,
    /// A stage stops when an iteration lowers the loss by less than this
    /// fraction (dimensionless). Default 1e-9.
    pub min_decrease: f64,
    /// A stage stops once Gauss-Newton has stalled: its Levenberg-Marquardt
    /// damping is at its floor (the last 13 steps were taken whole, so the
    /// damping no longer shortens them) and its last 3 accepted iterations
    /// lowered the objective by less than this fraction in all
    /// (dimensionless; 0 never stops). Default 1e-4. On the 26 x 26 rib's
    /// stretch pose the full stage crept by 2e-5 per iteration for its last
    /// 35 iterations (0.07% in all, 9 of the fit's 32 min); the early damped
    /// Gauss-Newton steps, also small, are not a stall.
    pub stall_decrease: f64,
    /// Largest change of any `ln γ` in one log-space Gauss-Newton step
    /// solved by conjugate gradients (full fields above
    /// [`KKT_MAX_UNKNOWNS`] unknowns; trust region,
    /// dimensionless): the first trial step is shortened to it. Default
    /// ln 100. Without it, weakly damped steps on a 12.7K-node rib proposed
    /// materials whose trial equilibria took ~30 s each, five halvings deep
    /// (184 s per step). Directly solved (smaller) systems take the full
    /// step: capping them too made the demo's joint fit 8x slower (107 s
    /// against 13 s, release) for the same loss (1.14e-8 against 1.18e-8 m³).
    pub max_log_step: f64,
    /// Largest factor (dimensionless, >= 1) by which the full stage may
    /// move any γ, up or down, relative to the initial material of a
    /// sample's fit, up to a common factor: every `γ_j / γ0_j` stays within
    /// `max_contrast` of their geometric mean (the field is clamped into the
    /// band, then to the floor). The overall scale stays free: a loss without
    /// external forces does not see it and the clamp reactions set it after
    /// the fit. The harmonic stages, whose few parameters include that scale,
    /// are not bounded. Default 1e3: three decades either way covers
    /// the contrast of yarn-dense against empty voxels (the synthetic 100x
    /// band is recovered inside it), while the directions two poses leave
    /// unobserved otherwise drift to γs over 14 decades (0.0003 Pa to 5e10
    /// Pa on a 10 x 10 stockinette fitted to a stretch and a bend), a field
    /// whose held-out drape has no backward-Euler step.
    pub max_contrast: f64,
    /// Weight ρ (dimensionless, >= 0) of a Gaussian prior on the full
    /// stage's log-field around its start θ0 (the harmonic stages' field):
    /// the stage minimizes `L(γ) + ρ L0 mean_j (θ_j - θ0_j)²`, L0 the loss at
    /// the stage's start, so moving every γ by a factor e costs ρ L0.
    /// Directions the poses barely observe then stay at the start instead of
    /// drifting to the contrast bound for a tiny loss decrease (a MAP
    /// estimate; VH §6 has none). Log-space full stage only. Default 0.
    pub prior_weight: f64,
    /// Weight σ (dimensionless, >= 0) of a smoothness term on the full
    /// stage's log-fields over face-adjacent tets: the stage minimizes
    /// `L(γ) + σ L0 mean_(a,b) (θ_a - θ_b)²` over the adjacent pairs of the
    /// γs and of the γv field, so a jump by a factor e across every face
    /// costs σ L0. A field the poses observe only in places then varies
    /// smoothly in between instead of in patches (soft tets in series soften
    /// motions the poses never showed; docs/fidelity.md, held-out drape). Log-space
    /// full stage only. Default 0.
    pub smooth_weight: f64,
    /// Weight ρ (dimensionless, >= 0) of the clamp-force term that a knit
    /// fit adds to every frame whose yarn-level run recorded its clamp
    /// forces ([`super::force_loss`]): per sample, `w = ρ L0 / Σ |R|²`
    /// with `L0` the sample's position loss under the uniform material the
    /// field starts from, so a relative force misfit of 1 costs `ρ L0`.
    /// 0: positions only, the stiffening then set afterwards from the
    /// forces alone. Default 1.
    pub force_weight: f64,
}

impl Default for ElasticFitParams {
    fn default() -> Self {
        ElasticFitParams {
            harmonic_ranks: vec![1, 10, 30],
            full_stage: true,
            scale_search: true,
            full_stage_log: true,
            gd_iterations: 12,
            gn_iterations: 50,
            cg_iterations: 300,
            direct_max_unknowns: KKT_MAX_UNKNOWNS,
            gd_step: 0.01,
            gn_step: 1.0,
            max_halvings: 10,
            kappa: 1e-3,
            gamma_floor: 1e-3,
            equilibrium_tolerance: 1e-6,
            equilibrium_iterations: 100,
            loss_stop: 1e-10,
            min_decrease: 1e-9,
            stall_decrease: 1e-4,
            max_log_step: 2.0 * std::f64::consts::LN_10,
            max_contrast: 1e3,
            prior_weight: 0.0,
            smooth_weight: 0.0,
            force_weight: 1.0,
        }
    }
}

impl ElasticFitParams {
    /// The equilibrium solver's parameters.
    pub fn statics(&self) -> StaticParams {
        StaticParams {
            tolerance: self.equilibrium_tolerance,
            max_iterations: self.equilibrium_iterations,
        }
    }

    /// The full stage's conjugate-gradient parameters.
    pub fn cg(&self) -> CgParams {
        CgParams {
            max_iterations: self.cg_iterations,
            direct_max_unknowns: self.direct_max_unknowns,
            ..Default::default()
        }
    }

    pub(crate) fn check(&self) -> Result<(), ElasticFitError> {
        let ok = self.gd_step > 0.0
            && self.cg_iterations >= 1
            && self.gn_step > 0.0
            && self.kappa >= 0.0
            && self.kappa.is_finite()
            && self.gamma_floor > 0.0
            && self.gamma_floor.is_finite()
            && self.equilibrium_tolerance > 0.0
            && self.equilibrium_tolerance <= 1e-5
            && self.loss_stop >= 0.0
            && self.min_decrease >= 0.0
            && (0.0..1.0).contains(&self.stall_decrease)
            && self.max_log_step > 0.0
            && self.max_contrast >= 1.0
            && self.prior_weight >= 0.0
            && self.prior_weight.is_finite()
            && self.smooth_weight >= 0.0
            && self.smooth_weight.is_finite();
        if ok {
            Ok(())
        } else {
            Err(ElasticFitError::Inconsistent(format!(
                "fit parameters out of range (steps > 0, CG iterations >= 1, stall decrease in [0, 1), max log step > 0, max contrast >= 1, prior and smoothness weights >= 0, kappa >= 0, floor > 0, equilibrium tolerance in (0, 1e-5]): {self:?}"
            )))
        }
    }
}

/// Conjugate gradients on the damped Eq. 20.
#[derive(Debug, Clone, PartialEq)]
pub struct CgParams {
    /// Relative residual `|r| / |grad|` that ends the iteration. Default 1e-8.
    pub tolerance: f64,
    /// Most iterations (a truncated solve is still a descent direction:
    /// every CG iterate from zero has `gradᵀ d > 0`). Default 300
    /// ([`ElasticFitParams::cg_iterations`]).
    pub max_iterations: usize,
    /// Largest Eq. 21 system (unknowns) factored directly instead; default
    /// [`KKT_MAX_UNKNOWNS`].
    pub direct_max_unknowns: usize,
}

impl Default for CgParams {
    fn default() -> Self {
        CgParams {
            tolerance: 1e-8,
            max_iterations: 300,
            direct_max_unknowns: KKT_MAX_UNKNOWNS,
        }
    }
}

/// Largest Eq. 21 system factored directly. Its sparse LU fills in far
/// beyond the matrix (a 12.7K-node rib, 2 frames: ~250K unknowns, 250 s and
/// 7 GB per Gauss-Newton step); larger full-field systems go to
/// [`gn_solve_cg`].
pub const KKT_MAX_UNKNOWNS: usize = 60_000;

/// A material and its equilibria.
pub(crate) struct Evaluated {
    pub(crate) gamma: Vec<f64>,
    pub(crate) model: ElasticModel,
    pub(crate) xs: Vec<Vec<Vec3>>,
    pub(crate) loss: f64,
    pub(crate) residual: f64,
    pub(crate) newton: u64,
}

/// One iteration of a fit, for progress lines (`fit --json`: one JSON
/// object per iteration; the CLI adds `"event": "iteration"`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FitProgress {
    /// The sample's name (a pose file, or all of them for a joint fit).
    pub sample: String,
    /// The stage (`harmonic r=10`, `full`).
    pub stage: String,
    /// Iterations of this stage so far (1-based) and the step taken (`gd`, `gn`).
    pub iteration: u32,
    pub method: String,
    /// Loss (m³) after the iteration; for the knit material's stage
    /// `stiffening` (one line per evaluation), the relative clamp-force
    /// misfit (dimensionless).
    pub loss: f64,
    /// Wall time (ms) of the iteration, and of it the search direction
    /// (linearization and Gauss-Newton solve); the rest is the line search.
    pub ms: f64,
    pub direction_ms: f64,
    /// Line-search halvings of the accepted step.
    pub halvings: u32,
}
