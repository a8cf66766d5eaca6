//! The two parallel kernels of a PD iteration behind traits, so the time
//! loop (`sim::pd`) runs the same algorithm on the CPU (f64, reference) and
//! on the GPU (`sim::gpu`, f32, wgpu).
//!
//! Layout of node arrays: `n x 3` row-major `f64` (`a[3 * i + k]`), the same
//! as `&[Vec3]` flattened.

use super::energy::ElasticModel;
use super::SimError;
use crate::geom::Vec3;

/// What [`ElasticRhs::evaluate`] found at the positions it was given.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LocalEval {
    /// `Σ_e V_e (γs |F_e - R_e|² + γv |F_e - V_e|²)` (J) with the targets
    /// `R_e`, `V_e` projected from these positions (VH Eq. 7-8).
    pub elastic_energy: f64,
    /// Tets whose volume projection clamped a singular value (VH Eq. 26).
    pub clamped_tets: usize,
}

/// The PD local step fused with the elastic part of the global right-hand
/// side (VH Eq. 26 and the sums of Eq. 28): for positions `x` of all nodes,
/// projects every tet's targets and writes, for every node `a`,
/// `out[a] = Σ_e 2 V_e (γs R_e + γv V_e) ∇N_a^e` (N: the factor 2 is the one
/// `sim::pd` documents).
pub trait ElasticRhs {
    /// Evaluates at `x` (m, one per mesh node); `out` has one entry per node.
    fn evaluate(&mut self, x: &[Vec3], out: &mut [Vec3]) -> Result<LocalEval, SimError>;
    /// A short name for statistics ("cpu", "gpu").
    fn name(&self) -> &'static str;
    /// Relative precision of [`LocalEval::elastic_energy`] (0: exact to
    /// f64 rounding). The PD safeguard treats an accelerated iterate whose
    /// objective rises by less than this times the elastic energy as not
    /// rising: f32 sums would otherwise reject most accelerated iterates
    /// near convergence.
    fn energy_precision(&self) -> f64 {
        0.0
    }
    /// Takes the per-tet stiffnesses of `model` (same mesh, new `γs`, `γv`)
    /// in place, so a fitted material keeps its backend. Returns false when
    /// the backend cannot (the caller then falls back to the CPU one).
    fn update_materials(&mut self, _model: &ElasticModel) -> Result<bool, SimError> {
        Ok(false)
    }
    /// State this evaluator carries from one evaluation to the next that
    /// changes its results (the CPU SVD warm start), flattened; empty when
    /// none. A shot checkpoints it so a resumed run continues bit for bit.
    fn warm_start(&self) -> Vec<f64> {
        Vec::new()
    }
    /// Restores what [`Self::warm_start`] returned; a state of the wrong
    /// length or with a non-finite value is refused.
    fn set_warm_start(&mut self, state: &[f64]) -> Result<(), SimError> {
        if state.is_empty() {
            Ok(())
        } else {
            Err(SimError::Inconsistent(format!(
                "the {} backend keeps no warm start, got {} values",
                self.name(),
                state.len()
            )))
        }
    }
}

/// Statistics of an iterative linear solve.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IterStats {
    /// Iterations run.
    pub iterations: u32,
    /// Final relative residual `|b - A x| / |b|` (Frobenius over the three
    /// columns; 0 when `b = 0`).
    pub relative_residual: f64,
}

/// Chebyshev-accelerated Jacobi iterations (Wang 2015, "A Chebyshev
/// semi-iterative approach for accelerating projective and position-based
/// dynamics") on a fixed sparse SPD matrix `A` (the free block of the PD
/// matrix `K`), optionally with a per-row extra diagonal `D` (contact
/// weights): solves `(A + D) x = b` for three right-hand sides at once.
pub trait JacobiSolve {
    /// Improves `x` (n x 3, in: initial guess, out: result) until the
    /// relative residual is at most `tolerance` or `max_iterations` ran.
    /// `extra_diag` has `n` entries (>= 0) or is `None`.
    fn solve(
        &mut self,
        b: &[f64],
        extra_diag: Option<&[f64]>,
        x: &mut [f64],
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<IterStats, SimError>;
    /// A short name for statistics ("cpu", "gpu").
    fn name(&self) -> &'static str;
}

/// The argument checks every [`JacobiSolve`] makes: `b` and `x` hold `n x 3`
/// values, `extra_diag` (if any) `n` entries, each finite and `>= 0`.
/// `who` names the solver in the message.
pub(crate) fn check_jacobi_inputs(
    who: &str,
    n: usize,
    b: &[f64],
    extra_diag: Option<&[f64]>,
    x: &[f64],
) -> Result<(), SimError> {
    if b.len() != 3 * n || x.len() != 3 * n || extra_diag.is_some_and(|w| w.len() != n) {
        return Err(SimError::Inconsistent(format!(
            "{who} of {n} rows got b of {}, x of {} and {} extra diagonal entries",
            b.len(),
            x.len(),
            extra_diag.map_or(0, |w| w.len())
        )));
    }
    if let Some((i, d)) = extra_diag
        .into_iter()
        .flatten()
        .enumerate()
        .find(|(_, d)| !(d.is_finite() && **d >= 0.0))
    {
        return Err(SimError::Inconsistent(format!(
            "{who}: extra diagonal of row {i} is {d}; it must be finite and >= 0"
        )));
    }
    Ok(())
}
