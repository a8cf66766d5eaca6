//! The staged optimizer of one sample (VH §6.1-6.3, §6.5): gradient descent
//! then adjoint Gauss-Newton, in harmonic subspaces of growing rank and then
//! on the full per-element field, with line search and non-negativity.
//!
//! # Gauss-Newton direction (Eq. 19-21)
//! For frames `i` with `K_i = ∂g_i/∂x`, `C_i = ∂g_i/∂q` (`q` the parameters:
//! `γ` itself, or the harmonic coefficients with `C_i ← C_i diag(H, H)`,
//! Eq. 24) and `G_i = ∂²ε_i/∂x²`, the sparse system of Zehnder et al. 2021
//! (VH Eq. 21), one `(μ_i, ν_i)` pair per frame and a shared `d`:
//!
//! ```text
//! [ G_i   -K_iᵀ   0   ] [μ_i]   [ 0  ]
//! [ -K_i   0     C_i  ] [ν_i] = [ 0  ]
//! [ 0     C_iᵀ   κ I  ] [ d ]   [ ∇ε ]
//! ```
//!
//! gives `(Σ_i P_i + κ I) d = ∇ε` with `P_i = J_iᵀ G_i J_i`, `J_i = -K_i⁻¹ C_i`
//! (Eq. 19-20); the search direction is `-d`. The Levenberg-Marquardt `κ I`
//! sits on the `d` block, so the result is exactly the damped Eq. 20 (VH
//! adds `κ I` "at the l.h.s."; on the other blocks it would perturb `P`).
//! Solved by sparse LU (faer) with partial pivoting.
//!
//! # Steps and non-negativity (§6.3)
//! Line search: the first trial step is `gd_step` (GD) or `gn_step` (GN),
//! halved while the loss does not decrease (a trial whose equilibrium fails
//! counts as an increase). On the full field, components that a step would
//! take below `gamma_floor` are set to it and remembered ("clamped"); a
//! later direction that would lower a clamped component has that component
//! zeroed; if the zeroed GN direction is no longer a descent direction, the
//! clamped components it wanted to lower are pivoted: held at the floor and
//! removed from the GN system for the rest of the stage. In a harmonic
//! subspace a trial with any `γ` below the floor counts as an increase.

use std::time::Instant;

use faer::linalg::solvers::SolveCore;
use faer::{Conj, Mat};
use nalgebra::DMatrix;
use rayon::prelude::*;

use super::adjoint::{equilibrium_with, linearize, FrameCache, FrameLinearization};
use super::error::{SampleError, SolveError};
use super::regularizer::Regularizer;
use super::row_lists::RowLists;
use super::types::{
    CgParams, ElasticFitError, ElasticFitParams, Evaluated, FitProgress, MaterialFields, Sample,
};
use crate::geom::{TetMesh, Vec3};
use crate::linalg::lu::sparse_lu;
use crate::sim::energy::ElasticModel;

/// The parametrization of a stage: `γ` itself or harmonic coefficients.
#[derive(Debug, Clone)]
pub enum Basis {
    /// One parameter per tet and field (`γs_e`, `γv_e`, fibre `γ_e`).
    Full,
    /// `γ = diag(H, H, ...) q` (Eq. 23; one block per field), `H` of size
    /// `n_E x r`.
    Harmonic(DMatrix<f64>),
}

impl Basis {
    /// Number of parameters for `ne` tets and `nf` fields.
    pub fn dim(&self, ne: usize, nf: usize) -> usize {
        match self {
            Basis::Full => nf * ne,
            Basis::Harmonic(h) => nf * h.ncols(),
        }
    }
    /// `γ` (stacked) of the parameters `q`.
    pub fn expand(&self, q: &[f64], ne: usize) -> Vec<f64> {
        match self {
            Basis::Full => q.to_vec(),
            Basis::Harmonic(h) => {
                let r = h.ncols();
                let nf = q.len() / r;
                let mut g = vec![0.0; nf * ne];
                for half in 0..nf {
                    for e in 0..ne {
                        g[half * ne + e] = (0..r).map(|k| h[(e, k)] * q[half * r + k]).sum();
                    }
                }
                g
            }
        }
    }
    /// Least-squares parameters of `γ` (exact when `γ` lies in the span).
    pub fn project(&self, gamma: &[f64], ne: usize) -> Vec<f64> {
        match self {
            Basis::Full => gamma.to_vec(),
            Basis::Harmonic(_) => self.pull(gamma, ne),
        }
    }
    /// `diag(H, H, ...)ᵀ v` (the chain rule of §6.5): gradients to parameters.
    pub fn pull(&self, v: &[f64], ne: usize) -> Vec<f64> {
        match self {
            Basis::Full => v.to_vec(),
            Basis::Harmonic(h) => {
                let r = h.ncols();
                let nf = v.len() / ne;
                let mut q = vec![0.0; nf * r];
                for half in 0..nf {
                    for k in 0..r {
                        q[half * r + k] = (0..ne).map(|e| h[(e, k)] * v[half * ne + e]).sum();
                    }
                }
                q
            }
        }
    }
    /// `C diag(H, H, ...)` of a harmonic basis as a dense `ndof x m` matrix
    /// (`m = n_F r` parameters; an empty one for the full basis).
    fn dense_columns(
        &self,
        c: &[(usize, usize, f64)],
        ndof: usize,
        ne: usize,
        m: usize,
    ) -> DMatrix<f64> {
        let Basis::Harmonic(h) = self else {
            return DMatrix::zeros(0, 0);
        };
        let r = h.ncols();
        let mut dense = DMatrix::<f64>::zeros(ndof, m);
        for &(row, j, v) in c {
            let (half, e) = (j / ne, j % ne);
            for k in 0..r {
                dense[(row, half * r + k)] += v * h[(e, k)];
            }
        }
        dense
    }

    /// `C diag(H, H, ...)` of the triplets `c` (`ndof` rows, `m` parameters).
    fn columns(
        &self,
        c: &[(usize, usize, f64)],
        ndof: usize,
        ne: usize,
        m: usize,
    ) -> Vec<(usize, usize, f64)> {
        match self {
            Basis::Full => c.to_vec(),
            Basis::Harmonic(_) => {
                let dense = self.dense_columns(c, ndof, ne, m);
                let mut out = Vec::new();
                for col in 0..dense.ncols() {
                    for row in 0..ndof {
                        let v = dense[(row, col)];
                        if v != 0.0 {
                            out.push((row, col, v));
                        }
                    }
                }
                out
            }
        }
    }
}

/// The damped Gauss-Newton step `d` of Eq. 20-21: solves
/// `(Σ_i P_i + κ I) d = grad` through the sparse system of Eq. 21 (module
/// doc), by `cg` on full fields too large to factor. Parameters with
/// `fixed[j]` are removed (their `d_j` is 0). Returns `d`; the search
/// direction is `-d`.
pub fn gn_solve(
    lins: &[FrameLinearization],
    basis: &Basis,
    ne: usize,
    grad: &[f64],
    kappa: f64,
    fixed: &[bool],
    cg: &CgParams,
) -> Result<Vec<f64>, SolveError> {
    let damping = vec![kappa; grad.len()];
    gn_solve_damped(lins, basis, ne, grad, &damping, &[], fixed, cg)
}

/// [`gn_solve`] with a damping of its own per parameter and a symmetric
/// coupling between parameters (a regularizer's off-diagonal curvature,
/// entries `(a, b, v)` given both ways; full basis only): solves
/// `(Σ_i P_i + diag(damping) + coupling) d = grad`, by `cg` on full fields
/// above [`super::KKT_MAX_UNKNOWNS`].
#[allow(clippy::too_many_arguments)]
pub fn gn_solve_damped(
    lins: &[FrameLinearization],
    basis: &Basis,
    ne: usize,
    grad: &[f64],
    damping: &[f64],
    coupling: &[(usize, usize, f64)],
    fixed: &[bool],
    cg: &CgParams,
) -> Result<Vec<f64>, SolveError> {
    if let Basis::Harmonic(_) = basis {
        if !coupling.is_empty() {
            return Err(SolveError::CouplingNeedsFullBasis);
        }
        return gn_solve_subspace(lins, basis, ne, grad, damping, fixed);
    }
    let m = grad.len();
    if solved_by_cg(lins, m, cg.direct_max_unknowns) {
        return gn_solve_cg(lins, grad, damping, coupling, fixed, cg).map(|(d, _)| d);
    }
    let force_rows: usize = lins
        .iter()
        .filter_map(|l| l.force.as_ref())
        .map(|f| f.jacobian.nrows())
        .sum();
    let total: usize = lins.iter().map(|l| 2 * l.free.ndof).sum::<usize>() + force_rows + m;
    let dcol = total - m;
    let mut t = Vec::new();
    // The clamp-force terms as extra unknowns s = 2w J_F d: rows
    // [J_F, -I / 2w] and J_Fᵀ in the d rows give (P + 2w J_Fᵀ J_F) d.
    let mut srow = dcol - force_rows;
    for fl in lins.iter().filter_map(|l| l.force.as_ref()) {
        for w in 0..fl.jacobian.nrows() {
            for (j, &fx) in fixed.iter().enumerate() {
                let v = fl.jacobian[(w, j)];
                if v != 0.0 && !fx {
                    t.push((srow, dcol + j, v));
                    t.push((dcol + j, srow, v));
                }
            }
            t.push((srow, srow, -1.0 / fl.weight2));
            srow += 1;
        }
    }
    let mut off = 0;
    for l in lins {
        let n = l.free.ndof;
        t.extend(l.g.iter().map(|&(r, c, v)| (off + r, off + c, v)));
        for &(r, c, v) in &l.k {
            t.push((off + c, off + n + r, -v));
            t.push((off + n + r, off + c, -v));
        }
        for (r, j, v) in basis.columns(&l.c, n, ne, m) {
            if !fixed[j] {
                t.push((off + n + r, dcol + j, v));
                t.push((dcol + j, off + n + r, v));
            }
        }
        off += 2 * n;
    }
    for (j, &fx) in fixed.iter().enumerate() {
        t.push((dcol + j, dcol + j, if fx { 1.0 } else { damping[j] }));
    }
    for &(a, b, v) in coupling {
        if !fixed[a] && !fixed[b] {
            t.push((dcol + a, dcol + b, v));
        }
    }
    // The blocks differ by many orders of magnitude (G ~ m, K ~ Pa m,
    // C ~ m², κ tiny): equilibrate symmetrically before the LU.
    let scale = ruiz_scaling(total, &t);
    for e in t.iter_mut() {
        e.2 *= scale[e.0] * scale[e.1];
    }
    let lu = sparse_lu(total, &t).map_err(SolveError::GaussNewtonSystem)?;
    let mut rhs = Mat::<f64>::zeros(total, 1);
    for j in 0..m {
        rhs[(dcol + j, 0)] = if fixed[j] {
            0.0
        } else {
            grad[j] * scale[dcol + j]
        };
    }
    lu.solve_in_place_with_conj(Conj::No, rhs.as_mut());
    let d: Vec<f64> = (0..m)
        .map(|j| rhs[(dcol + j, 0)] * scale[dcol + j])
        .collect();
    if !d.iter().all(|v| v.is_finite()) {
        return Err(SolveError::NonFiniteDirection);
    }
    Ok(d)
}

/// The damped Gauss-Newton step in a harmonic subspace of `2r` parameters:
/// Eq. 19-20 directly. Each frame's `K` is factored once and solved for the
/// `2r` dense columns `C diag(H, H)`, giving `J = -K⁻¹ C` and `P = Jᵀ G J`
/// (`2r x 2r`). The sparse system of Eq. 21 would carry those dense columns
/// as dense rows, whose fill-in exhausts the sparse LU on a VH-size rib
/// (12.7K nodes); this costs one sparse factorization and `2r` solves per
/// frame.
fn gn_solve_subspace(
    lins: &[FrameLinearization],
    basis: &Basis,
    ne: usize,
    grad: &[f64],
    damping: &[f64],
    fixed: &[bool],
) -> Result<Vec<f64>, SolveError> {
    let m = grad.len();
    let parts: Vec<DMatrix<f64>> = lins
        .par_iter()
        .map(|l| -> Result<DMatrix<f64>, SolveError> {
            let n = l.free.ndof;
            let dense = basis.dense_columns(&l.c, n, ne, m);
            let mut j = Mat::<f64>::from_fn(n, m, |row, col| dense[(row, col)]);
            // K⁻¹ C; the sign of J cancels in Jᵀ G J.
            l.k_factor.solve_in_place(j.as_mut());
            let mut gj = Mat::<f64>::zeros(n, m);
            for &(r, c, v) in &l.g {
                for k in 0..m {
                    gj[(r, k)] += v * j[(c, k)];
                }
            }
            Ok(DMatrix::from_fn(m, m, |a, b| {
                (0..n).map(|i| j[(i, a)] * gj[(i, b)]).sum()
            }))
        })
        .collect::<Result<_, _>>()?;
    let mut p = DMatrix::<f64>::zeros(m, m);
    for part in parts {
        p += part;
    }
    for l in lins {
        if let Some(fl) = &l.force {
            // J_F diag(H, H, ...), row by row.
            let rows = fl.jacobian.nrows();
            let mut js = DMatrix::<f64>::zeros(rows, m);
            for w in 0..rows {
                let row: Vec<f64> = fl.jacobian.row(w).iter().copied().collect();
                for (k, v) in basis.pull(&row, ne).into_iter().enumerate() {
                    js[(w, k)] = v;
                }
            }
            p += js.tr_mul(&js) * fl.weight2;
        }
    }
    let mut rhs = nalgebra::DVector::<f64>::zeros(m);
    for j in 0..m {
        if fixed[j] {
            for k in 0..m {
                p[(j, k)] = 0.0;
                p[(k, j)] = 0.0;
            }
            p[(j, j)] = 1.0;
        } else {
            p[(j, j)] += damping[j];
            rhs[j] = grad[j];
        }
    }
    let d = p.lu().solve(&rhs).ok_or(SolveError::SingularSubspace)?;
    if !d.iter().all(|v| v.is_finite()) {
        return Err(SolveError::NonFiniteDirection);
    }
    Ok(d.iter().copied().collect())
}

/// Whether the full-field Gauss-Newton system of `m` parameters over
/// `lins` is solved by [`gn_solve_cg`] (its Eq. 21 form has more than
/// `direct_max` unknowns; [`super::KKT_MAX_UNKNOWNS`] by default).
fn solved_by_cg(lins: &[FrameLinearization], m: usize, direct_max: usize) -> bool {
    lins.iter().map(|l| 2 * l.free.ndof).sum::<usize>() + m > direct_max
}

/// What a CG solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct CgStats {
    pub iterations: usize,
    /// Final relative residual.
    pub residual: f64,
}

/// The damped Gauss-Newton step of Eq. 20 on the full field without forming
/// `P`: preconditioned conjugate gradients on `(Σ_i P_i + diag(damping)) d
/// = grad`, each product `P_i v = C_iᵀ K_i⁻ᵀ G_i K_i⁻¹ C_i v` two solves
/// with the adjoint's factor of `K_i` (Zehnder et al. 2021 use the same
/// products). Fixed parameters keep `d_j = 0`. The Jacobi preconditioner
/// approximates `diag(P)` with `K ≈ diag(K)`.
pub fn gn_solve_cg(
    lins: &[FrameLinearization],
    grad: &[f64],
    damping: &[f64],
    coupling: &[(usize, usize, f64)],
    fixed: &[bool],
    params: &CgParams,
) -> Result<(Vec<f64>, CgStats), SolveError> {
    let m = grad.len();
    // Per frame: C, G and Cᵀ as row lists (the products below are then
    // gathers; the same sums, bit for bit, as scattering the triplets).
    let ops: Vec<[RowLists; 3]> = lins
        .iter()
        .map(|l| {
            let n = l.free.ndof;
            Ok([
                RowLists::new(n, l.c.iter().copied())?,
                RowLists::new(n, l.g.iter().copied())?,
                RowLists::new(m, l.c.iter().map(|&(r, j, c)| (j, r, c)))?,
            ])
        })
        .collect::<Result<_, SolveError>>()?;
    let apply = |v: &[f64]| -> Vec<f64> {
        let parts: Vec<Vec<f64>> = lins
            .par_iter()
            .zip(&ops)
            .map(|(l, [c, g, ct])| {
                let n = l.free.ndof;
                let mut u = Mat::<f64>::zeros(n, 1);
                c.mul(v, u.col_as_slice_mut(0));
                l.k_factor.solve_in_place(u.as_mut());
                let mut z = Mat::<f64>::zeros(n, 1);
                g.mul(u.col_as_slice(0), z.col_as_slice_mut(0));
                l.k_factor.solve_transpose_in_place(z.as_mut());
                let mut out = vec![0.0; m];
                ct.mul(z.col_as_slice(0), &mut out);
                out
            })
            .collect();
        let mut out: Vec<f64> = (0..m).map(|j| damping[j] * v[j]).collect();
        for &(a, b, c) in coupling {
            out[a] += c * v[b];
        }
        for fl in lins.iter().filter_map(|l| l.force.as_ref()) {
            let jv = &fl.jacobian * nalgebra::DVector::from_column_slice(v);
            let back = fl.jacobian.tr_mul(&jv);
            for (o, b) in out.iter_mut().zip(back.iter()) {
                *o += fl.weight2 * b;
            }
        }
        for part in parts {
            for (o, p) in out.iter_mut().zip(part) {
                *o += p;
            }
        }
        for (o, &fx) in out.iter_mut().zip(fixed) {
            if fx {
                *o = 0.0;
            }
        }
        out
    };
    let precond = jacobi_estimate(lins, damping, m);
    let b: Vec<f64> = (0..m)
        .map(|j| if fixed[j] { 0.0 } else { grad[j] })
        .collect();
    let b_norm = dot(&b, &b).sqrt();
    let mut x = vec![0.0; m];
    if b_norm == 0.0 {
        return Ok((
            x,
            CgStats {
                iterations: 0,
                residual: 0.0,
            },
        ));
    }
    let mut r = b.clone();
    let mut z: Vec<f64> = r.iter().zip(&precond).map(|(r, p)| r / p).collect();
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let mut stats = CgStats {
        iterations: 0,
        residual: 1.0,
    };
    while stats.iterations < params.max_iterations {
        let ap = apply(&p);
        let pap = dot(&p, &ap);
        if !(pap > 0.0) || !pap.is_finite() {
            break; // lost positivity in rounding: keep the last iterate
        }
        let alpha = rz / pap;
        for j in 0..m {
            x[j] += alpha * p[j];
            r[j] -= alpha * ap[j];
        }
        stats.iterations += 1;
        stats.residual = dot(&r, &r).sqrt() / b_norm;
        if stats.residual <= params.tolerance {
            break;
        }
        z = r.iter().zip(&precond).map(|(r, p)| r / p).collect();
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        for j in 0..m {
            p[j] = z[j] + beta * p[j];
        }
    }
    if !x.iter().all(|v| v.is_finite()) || stats.iterations == 0 {
        return Err(SolveError::ConjugateGradients {
            residual: stats.residual,
        });
    }
    Ok((x, stats))
}

/// `diag(P) + damping` with `K⁻¹ ≈ diag(K)⁻¹`, floored at a millionth of
/// its mean so that no parameter the frames do not see divides by zero.
fn jacobi_estimate(lins: &[FrameLinearization], damping: &[f64], m: usize) -> Vec<f64> {
    let mut d = damping.to_vec();
    for l in lins {
        let n = l.free.ndof;
        let mut kdiag = vec![0.0; n];
        for &(r, c, v) in &l.k {
            if r == c {
                kdiag[r] += v;
            }
        }
        let mut gdiag = vec![0.0; n];
        for &(r, c, v) in &l.g {
            if r == c {
                gdiag[r] += v;
            }
        }
        for &(r, j, c) in &l.c {
            if kdiag[r] != 0.0 {
                d[j] += gdiag[r] * (c / kdiag[r]).powi(2);
            }
        }
        if let Some(fl) = &l.force {
            for (j, dj) in d.iter_mut().enumerate() {
                *dj += fl.weight2 * fl.jacobian.column(j).norm_squared();
            }
        }
    }
    let mean = d.iter().sum::<f64>() / m.max(1) as f64;
    let floor = (1e-6 * mean).max(f64::MIN_POSITIVE);
    d.iter().map(|v| v.max(floor)).collect()
}

/// Symmetric Ruiz equilibration of the matrix `t` (duplicates summed):
/// `D` with `D A D` having rows of max-norm close to 1.
fn ruiz_scaling(n: usize, t: &[(usize, usize, f64)]) -> Vec<f64> {
    let mut sum = std::collections::HashMap::with_capacity(t.len());
    for &(r, c, v) in t {
        *sum.entry((r, c)).or_insert(0.0) += v;
    }
    let mut entries: Vec<((usize, usize), f64)> = sum.into_iter().collect();
    entries.sort_unstable_by_key(|a| a.0);
    let mut d = vec![1.0; n];
    for _ in 0..8 {
        let mut rmax = vec![0.0f64; n];
        for &((r, c), v) in &entries {
            rmax[r] = rmax[r].max((v * d[r] * d[c]).abs());
        }
        for (di, m) in d.iter_mut().zip(&rmax) {
            if *m > 0.0 {
                *di /= m.sqrt();
            }
        }
    }
    d
}

/// What one stage did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct StageReport {
    /// "harmonic r=N" or "full".
    pub name: String,
    /// Number of parameters.
    pub parameters: usize,
    /// Loss (m³) at the stage start, then after each accepted iteration.
    pub losses: Vec<f64>,
    /// "gd" or "gn" per accepted iteration.
    pub methods: Vec<String>,
    /// Iterations tried (accepted or not).
    pub iterations: u32,
    /// Line-search halvings in total.
    pub halvings: u32,
    /// Components projected to the floor (full stage).
    pub clamped: usize,
    /// Components pivoted out of the GN system (full stage).
    pub pivoted: usize,
    /// Newton iterations of all equilibrium solves.
    pub newton_iterations: u64,
    /// Linearized frames whose force Jacobian was factored by Cholesky
    /// (symmetric, positive definite) and by LU (otherwise).
    pub cholesky_factors: u64,
    pub lu_factors: u64,
    /// Largest relative force residual of the frames at the stage end.
    pub final_residual: f64,
    /// Why the stage ended.
    pub stop: StageStop,
    /// Wall time (ms).
    pub ms: f64,
}

/// Why a stage ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StageStop {
    /// All its gradient-descent and Gauss-Newton iterations ran.
    #[default]
    Iterations,
    /// The sample's loss reached `loss_stop` of its start.
    LossGoal,
    /// The direction was not a descent direction.
    NoDescent,
    /// No step along the direction lowered the objective.
    LineSearch,
    /// An iteration lowered the objective by less than `min_decrease`.
    NoDecrease,
    /// Gauss-Newton stalled (`stall_decrease`).
    Stalled,
    /// Skipped: the start is not in the stage's subspace.
    Skipped,
    /// The scale stage's one-factor search ended (`scale_search`).
    SearchDone,
}

/// Levenberg-Marquardt's smallest damping factor (relative to `kappa`).
const LM_FLOOR: f64 = 1e-6;

/// Accepted Gauss-Newton iterations over which `stall_decrease` is summed.
const STALL_WINDOW: usize = 3;

/// Context of one sample's fit.
pub(super) struct SampleFit<'a> {
    mesh: &'a TetMesh,
    mass: &'a [f64],
    pub(super) sample: &'a Sample,
    pub(super) params: &'a ElasticFitParams,
    pub(super) progress: Option<&'a dyn Fn(&FitProgress)>,
    /// The initial material `[γs; γv; ...]` (Pa), the reference of
    /// `max_contrast`.
    init: Vec<f64>,
    /// The initial fields: the layout (fibre directions) of every `γ`.
    fields: &'a MaterialFields,
    /// Per frame, the pattern analyses its solves share.
    caches: Vec<FrameCache>,
}

impl SampleFit<'_> {
    fn ne(&self) -> usize {
        self.mesh.num_tets()
    }

    fn nf(&self) -> usize {
        self.fields.num_fields()
    }

    /// The elastic model of the stacked stiffnesses `gamma`.
    pub(super) fn model(&self, gamma: &[f64]) -> Result<ElasticModel, SolveError> {
        Ok(self.fields.with_stacked(gamma).model(self.mesh)?)
    }

    /// Equilibria and loss at `gamma`, warm-started from `starts`. The error
    /// carries the failing frame.
    pub(super) fn evaluate(
        &self,
        gamma: &[f64],
        starts: &[Vec<Vec3>],
    ) -> Result<Evaluated, (usize, SolveError)> {
        let model = self.model(gamma).map_err(|e| (0, e))?;
        let (mass, statics, caches) = (self.mass, self.params.statics(), &self.caches);
        let frames: Vec<Result<(Vec<Vec3>, f64, f64, u64), (usize, SolveError)>> = self
            .sample
            .frames
            .par_iter()
            .enumerate()
            .map(|(i, fr)| {
                let (x, st) = equilibrium_with(&model, mass, fr, &starts[i], &statics, &caches[i])
                    .map_err(|e| (i, e))?;
                let loss = fr.loss(&model, &x);
                if !loss.is_finite() {
                    return Err((i, SolveError::NonFiniteLoss));
                }
                let res = st.residuals.last().copied().unwrap_or(0.0);
                Ok((x, loss, res, st.iterations as u64))
            })
            .collect();
        let mut ev = Evaluated {
            gamma: gamma.to_vec(),
            model,
            xs: Vec::new(),
            loss: 0.0,
            residual: 0.0,
            newton: 0,
        };
        for f in frames {
            let (x, l, r, it) = f?;
            ev.xs.push(x);
            ev.loss += l;
            ev.residual = ev.residual.max(r);
            ev.newton += it;
        }
        Ok(ev)
    }

    /// Clamps a full field into the contrast band of the initial material
    /// ([`ElasticFitParams::max_contrast`]): every ratio `γ_j / γ0_j` within
    /// a factor `max_contrast` of their geometric mean, so the overall scale
    /// (free in a loss without external forces, set afterwards by the clamp
    /// reactions) moves freely while the contrast is bounded; then the floor.
    fn clamp_to_bounds(&self, gamma: &mut [f64]) {
        let init = &self.init;
        let mean = gamma
            .iter()
            .zip(init)
            .map(|(g, g0)| (g / g0).ln())
            .sum::<f64>()
            / gamma.len().max(1) as f64;
        let span = self.params.max_contrast.ln();
        for (g, g0) in gamma.iter_mut().zip(init) {
            let r = (*g / g0).ln().clamp(mean - span, mean + span);
            *g = (g0 * r.exp()).max(self.params.gamma_floor);
        }
    }

    /// The error of frame `frame` of this sample, with `e`'s message.
    fn error(&self, frame: usize, e: impl std::fmt::Display) -> ElasticFitError {
        ElasticFitError::Sample {
            sample: self.sample.name.clone(),
            frame,
            message: e.to_string(),
        }
    }

    /// Adjoint linearization of every frame and the total gradient `∂ε/∂γ`.
    fn linearize(
        &self,
        ev: &Evaluated,
    ) -> Result<(Vec<FrameLinearization>, Vec<f64>), ElasticFitError> {
        let caches = &self.caches;
        let lins: Vec<Result<FrameLinearization, (usize, SolveError)>> = self
            .sample
            .frames
            .par_iter()
            .enumerate()
            .map(|(i, fr)| linearize(&ev.model, fr, &ev.xs[i], &caches[i]).map_err(|e| (i, e)))
            .collect();
        let mut out = Vec::with_capacity(lins.len());
        let mut grad = vec![0.0; self.nf() * self.ne()];
        for l in lins {
            let l = l.map_err(|(i, e)| self.error(i, e))?;
            for (g, v) in grad.iter_mut().zip(&l.grad) {
                *g += v;
            }
            out.push(l);
        }
        Ok((out, grad))
    }

    /// One stage from `ev`; returns the new state and the stage report.
    fn stage(
        &self,
        basis: &Basis,
        name: String,
        mut ev: Evaluated,
        loss_goal: f64,
    ) -> Result<(Evaluated, StageReport), ElasticFitError> {
        let start = Instant::now();
        let ne = self.ne();
        let p = self.params;
        let m = basis.dim(ne, self.nf());
        let full = matches!(basis, Basis::Full);
        let mut rep = StageReport {
            name,
            parameters: m,
            ..Default::default()
        };
        let mut q = basis.project(&ev.gamma, ne);
        let back = basis.expand(&q, ne);
        let off: f64 = back
            .iter()
            .zip(&ev.gamma)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        if off > 1e-18 * ev.gamma.iter().map(|g| g * g).sum::<f64>() {
            // γ is not in the subspace (a non-uniform start): continue from
            // its projection when that is a valid material, else skip.
            if back.iter().all(|g| *g >= p.gamma_floor) {
                if let Ok(t) = self.evaluate(&back, &ev.xs) {
                    ev = t;
                }
            }
            if ev.gamma != back {
                rep.name.push_str(" (skipped: start not representable)");
                rep.stop = StageStop::Skipped;
                return Ok((ev, rep));
            }
        }
        rep.losses.push(ev.loss);
        let mut clamped = vec![false; m];
        let mut fixed = vec![false; m];
        // Levenberg-Marquardt: κ grows when the GN step had to be shortened
        // or failed, and shrinks when the full step was taken.
        let mut lm = 1.0f64;
        let mut failures = 0;
        let floor = p.gamma_floor;
        let regularizer = Regularizer::new(p, full && p.full_stage_log, self.mesh, &ev);
        // Relative decreases of the last accepted Gauss-Newton iterations.
        let mut recent = std::collections::VecDeque::with_capacity(STALL_WINDOW + 1);
        // Gradient descent that cannot go on hands over to Gauss-Newton
        // instead of ending the stage: its steps are scaled by the RMS of
        // the stacked fields, which mixes Pa with the knit material's
        // dimensionless stiffenings (measured: a knit uniform stage ended
        // after 6 descent steps at a loss 12% above VH's uniform one).
        let mut gd_over = false;
        let mut gn_done = 0;
        for it in 0..p.gd_iterations + p.gn_iterations {
            if ev.loss <= loss_goal {
                rep.stop = StageStop::LossGoal;
                break;
            }
            let gn = gd_over || it >= p.gd_iterations;
            if gn {
                if gn_done == p.gn_iterations {
                    break;
                }
                gn_done += 1;
            }
            let t_it = Instant::now();
            rep.iterations += 1;
            let hand_over = !gn && p.gn_iterations > 0;
            let (lins, grad_gamma) = self.linearize(&ev)?;
            for l in &lins {
                match l.k_factor.is_cholesky() {
                    true => rep.cholesky_factors += 1,
                    false => rep.lu_factors += 1,
                }
            }
            let mut grad = basis.pull(&grad_gamma, ne);
            regularizer.add_gradient(&ev.gamma, &mut grad);
            let gamma_rms =
                (ev.gamma.iter().map(|g| g * g).sum::<f64>() / ev.gamma.len() as f64).sqrt();
            let logmode = full && p.full_stage_log;
            let mut dir: Vec<f64> = if gn && logmode {
                let kappa = p.kappa * lm * ev.loss / (m as f64 * gamma_rms * gamma_rms);
                let mut damping: Vec<f64> = ev
                    .gamma
                    .iter()
                    .map(|g| kappa * (gamma_rms / g).powi(2))
                    .collect();
                let mut coupling = Vec::new();
                regularizer.add_hessian(&ev.gamma, &mut damping, &mut coupling);
                let d = gn_solve_damped(
                    &lins,
                    basis,
                    ne,
                    &grad,
                    &damping,
                    &coupling,
                    &fixed,
                    &p.cg(),
                )
                .map_err(|e| self.error(0, e))?;
                // In log space: dθ = dγ / γ.
                d.iter().zip(&ev.gamma).map(|(v, g)| -v / g).collect()
            } else if logmode {
                let mut d: Vec<f64> = grad.iter().zip(&ev.gamma).map(|(v, g)| -v * g).collect();
                let big = d.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                if big > 0.0 {
                    d.iter_mut().for_each(|v| *v /= big);
                }
                d
            } else if gn {
                let kappa = p.kappa * lm * ev.loss / (m as f64 * gamma_rms * gamma_rms);
                let raw = self.gn_direction(&lins, basis, &grad, kappa, &fixed)?;
                let mut d = raw.clone();
                if full {
                    zero_clamped(&mut d, &clamped);
                    if dot(&grad, &d) >= 0.0 {
                        // §6.3 pivoting: hold the clamped components the
                        // direction wanted to lower, and solve again.
                        for j in 0..m {
                            if clamped[j] && raw[j] < 0.0 && !fixed[j] {
                                fixed[j] = true;
                                rep.pivoted += 1;
                            }
                        }
                        d = self.gn_direction(&lins, basis, &grad, kappa, &fixed)?;
                        zero_clamped(&mut d, &clamped);
                    }
                }
                d
            } else {
                let mut d: Vec<f64> = grad.iter().map(|g| -g).collect();
                if full {
                    zero_clamped(&mut d, &clamped);
                }
                // Step 1 changes the most sensitive γ by the RMS of γ.
                let dg = basis.expand(&d, ne);
                let big = dg.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                if big > 0.0 {
                    d.iter_mut().for_each(|v| *v *= gamma_rms / big);
                }
                d
            };
            for j in 0..m {
                if fixed[j] {
                    dir[j] = 0.0;
                }
            }
            // In log mode `dir` is dθ (γ = e^θ): descent iff Σ g γ dθ < 0.
            let slope = if logmode {
                grad.iter()
                    .zip(&ev.gamma)
                    .zip(&dir)
                    .map(|((g, x), d)| g * x * d)
                    .sum::<f64>()
            } else {
                dot(&grad, &dir)
            };
            if !(slope < 0.0) {
                if hand_over {
                    gd_over = true;
                    continue;
                }
                rep.stop = StageStop::NoDescent;
                break;
            }
            let direction_ms = t_it.elapsed().as_secs_f64() * 1e3;
            let mut step = if gn { p.gn_step } else { p.gd_step };
            if gn && logmode && solved_by_cg(&lins, m, p.direct_max_unknowns) {
                let big = dir.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                if big * step > p.max_log_step {
                    step = p.max_log_step / big;
                }
            }
            let mut accepted = None;
            let mut halved = 0;
            let objective = regularizer.objective(&ev);
            for _ in 0..=p.max_halvings {
                let qt: Vec<f64> = if logmode {
                    q.iter()
                        .zip(&dir)
                        .map(|(a, b)| a * (step * b).clamp(-30.0, 30.0).exp())
                        .collect()
                } else {
                    q.iter().zip(&dir).map(|(a, b)| a + step * b).collect()
                };
                let mut gt = basis.expand(&qt, ne);
                let mut newly = Vec::new();
                let feasible = if full {
                    for (j, g) in gt.iter_mut().enumerate() {
                        if *g < floor || fixed[j] {
                            if !fixed[j] {
                                newly.push(j);
                            }
                            *g = floor;
                        }
                    }
                    true
                } else {
                    gt.iter().all(|g| *g >= floor)
                };
                if full {
                    self.clamp_to_bounds(&mut gt);
                }
                if feasible && gt.iter().all(|g| g.is_finite()) {
                    if let Ok(t) = self.evaluate(&gt, &ev.xs) {
                        rep.newton_iterations += t.newton;
                        if regularizer.objective(&t) < objective {
                            accepted = Some((t, newly, if full { gt.clone() } else { qt }));
                            break;
                        }
                    }
                }
                step *= 0.5;
                rep.halvings += 1;
                halved += 1;
            }
            let Some((t, newly, qn)) = accepted else {
                if gn && failures < 3 {
                    failures += 1;
                    lm *= 100.0;
                    recent.clear();
                    continue;
                }
                if hand_over {
                    gd_over = true;
                    continue;
                }
                rep.stop = StageStop::LineSearch;
                break;
            };
            failures = 0;
            if gn {
                lm = if halved == 0 {
                    (lm / 3.0).max(LM_FLOOR)
                } else {
                    lm * 4.0
                };
            }
            for j in newly {
                clamped[j] = true;
            }
            let decrease = (objective - regularizer.objective(&t)) / objective;
            q = qn;
            ev = t;
            rep.losses.push(ev.loss);
            rep.methods.push(if gn { "gn" } else { "gd" }.into());
            if let Some(report) = self.progress {
                report(&FitProgress {
                    sample: self.sample.name.clone(),
                    stage: rep.name.clone(),
                    iteration: rep.iterations,
                    method: if gn { "gn" } else { "gd" }.into(),
                    loss: ev.loss,
                    ms: t_it.elapsed().as_secs_f64() * 1e3,
                    direction_ms,
                    halvings: halved,
                });
            }
            if decrease < p.min_decrease {
                if hand_over {
                    gd_over = true;
                    continue;
                }
                rep.stop = StageStop::NoDecrease;
                break;
            }
            if gn {
                recent.push_back(decrease);
                if recent.len() > STALL_WINDOW {
                    recent.pop_front();
                }
                if stalled(&recent, lm, p.stall_decrease) {
                    rep.stop = StageStop::Stalled;
                    break;
                }
            }
        }
        rep.clamped = clamped.iter().filter(|c| **c).count();
        rep.final_residual = ev.residual;
        rep.ms = start.elapsed().as_secs_f64() * 1e3;
        Ok((ev, rep))
    }

    fn gn_direction(
        &self,
        lins: &[FrameLinearization],
        basis: &Basis,
        grad: &[f64],
        kappa: f64,
        fixed: &[bool],
    ) -> Result<Vec<f64>, ElasticFitError> {
        gn_solve(
            lins,
            basis,
            self.ne(),
            grad,
            kappa,
            fixed,
            &self.params.cg(),
        )
        .map(|d| d.iter().map(|v| -v).collect())
        .map_err(|e| self.error(0, e))
    }
}

/// Whether Gauss-Newton has stalled: undamped (`lm` at its floor) and the
/// last [`STALL_WINDOW`] accepted iterations' relative decreases sum to
/// less than `tolerance`. Small decreases while the damping still shortens
/// the steps are not a stall.
pub(super) fn stalled(recent: &std::collections::VecDeque<f64>, lm: f64, tolerance: f64) -> bool {
    lm <= LM_FLOOR && recent.len() == STALL_WINDOW && recent.iter().sum::<f64>() < tolerance
}

fn zero_clamped(d: &mut [f64], clamped: &[bool]) {
    for (v, &c) in d.iter_mut().zip(clamped) {
        if c && *v < 0.0 {
            *v = 0.0;
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Whether any frame of `sample` carries an external force: only then does
/// the loss see the material's overall scale.
pub fn loaded(sample: &Sample) -> bool {
    sample
        .frames
        .iter()
        .any(|f| f.f_ext.iter().flatten().any(|c| *c != 0.0))
}

/// Checks a sample against the mesh; the message names the frame.
fn validate(
    mesh: &TetMesh,
    mass: &[f64],
    sample: &Sample,
    model: &ElasticModel,
) -> Result<(), (usize, SampleError)> {
    let n = mesh.num_nodes();
    if sample.frames.is_empty() {
        return Err((0, SampleError::NoFrames));
    }
    if !(sample.energy > 0.0 && sample.energy.is_finite()) {
        return Err((
            0,
            SampleError::EnergyWeight {
                weight: sample.energy,
            },
        ));
    }
    if mass.len() != n {
        return Err((
            0,
            SampleError::MassCount {
                masses: mass.len(),
                nodes: n,
            },
        ));
    }
    for (i, f) in sample.frames.iter().enumerate() {
        if f.start.len() != n || f.f_ext.len() != n {
            return Err((
                i,
                SampleError::FrameLengths {
                    starts: f.start.len(),
                    forces: f.f_ext.len(),
                    nodes: n,
                },
            ));
        }
        if let Some(&p) = f.pinned.iter().find(|&&p| p >= n) {
            return Err((i, SampleError::PinnedOutOfRange { node: p, nodes: n }));
        }
        if !f
            .start
            .iter()
            .chain(&f.f_ext)
            .flatten()
            .all(|v| v.is_finite())
        {
            return Err((i, SampleError::NonFinite));
        }
        f.target.validate(model).map_err(|e| (i, e.into()))?;
    }
    Ok(())
}

/// Fits one sample from `init` (VH §6.1-6.3, §6.5): where a frame carries
/// external forces and `params.scale_search`, first the best common factor
/// of the field (stage "scale"); then for each rank of
/// `params.harmonic_ranks` (columns of `harmonic`, the basis of
/// [`super::harmonic::harmonic_basis`] with at least that many columns), a
/// stage in that subspace, then the full field when `params.full_stage`.
/// Every stage runs `gd_iterations` of gradient descent, then
/// `gn_iterations` of Gauss-Newton. Returns the fitted materials, the stage
/// reports, and the loss at `init`.
pub fn fit_sample(
    mesh: &TetMesh,
    mass: &[f64],
    sample: &Sample,
    init: &MaterialFields,
    harmonic: &DMatrix<f64>,
    params: &ElasticFitParams,
) -> Result<(MaterialFields, Vec<StageReport>, f64), ElasticFitError> {
    fit_sample_observed(mesh, mass, sample, init, harmonic, params, None)
        .map(|(gamma, stages, loss0, _)| (gamma, stages, loss0))
}

/// [`fit_sample`], calling `progress` after every iteration; also returns
/// every frame's equilibrium under the fitted material (in frame order), the
/// anchors of later solves under nearby materials
/// ([`super::adjoint::equilibrium_continued`]).
pub fn fit_sample_observed(
    mesh: &TetMesh,
    mass: &[f64],
    sample: &Sample,
    init: &MaterialFields,
    harmonic: &DMatrix<f64>,
    params: &ElasticFitParams,
    progress: Option<&dyn Fn(&FitProgress)>,
) -> Result<(MaterialFields, Vec<StageReport>, f64, Vec<Vec<Vec3>>), ElasticFitError> {
    params.check()?;
    let ne = mesh.num_tets();
    let model = init
        .model(mesh)
        .map_err(|e| ElasticFitError::Inconsistent(format!("initial material: {e}")))?;
    if init.stacked().iter().any(|g| *g < params.gamma_floor) {
        return Err(ElasticFitError::Inconsistent(format!(
            "initial material below the floor {} Pa",
            params.gamma_floor
        )));
    }
    let fit = SampleFit {
        mesh,
        mass,
        sample,
        params,
        progress,
        init: init.stacked(),
        fields: init,
        caches: sample
            .frames
            .iter()
            .map(|_| FrameCache::default())
            .collect(),
    };
    validate(mesh, mass, sample, &model).map_err(|(i, e)| fit.error(i, e))?;
    let starts: Vec<Vec<Vec3>> = sample.frames.iter().map(|f| f.start.clone()).collect();
    let mut ev = fit
        .evaluate(&init.stacked(), &starts)
        .map_err(|(i, e)| fit.error(i, e))?;
    let loss0 = ev.loss;
    let goal = params.loss_stop * loss0;
    let mut reports = Vec::new();
    if params.scale_search && loaded(sample) {
        let (e, rep) = fit.scale_stage(ev);
        ev = e;
        reports.push(rep);
    }
    for &r in &params.harmonic_ranks {
        if r == 0 || r >= ne {
            continue;
        }
        if harmonic.ncols() < r || harmonic.nrows() != ne {
            return Err(ElasticFitError::Harmonic(format!(
                "rank {r} asked but the basis is {} x {} for {ne} tets",
                harmonic.nrows(),
                harmonic.ncols()
            )));
        }
        let basis = Basis::Harmonic(harmonic.columns(0, r).into_owned());
        let (e, rep) = fit.stage(&basis, format!("harmonic r={r}"), ev, goal)?;
        ev = e;
        reports.push(rep);
    }
    if params.full_stage {
        let (e, rep) = fit.stage(&Basis::Full, "full".into(), ev, goal)?;
        ev = e;
        reports.push(rep);
    }
    if let Some(g) = ev
        .gamma
        .iter()
        .find(|g| !(g.is_finite() && **g >= params.gamma_floor))
    {
        return Err(fit.error(0, format!("fit produced gamma {g}")));
    }
    Ok((init.with_stacked(&ev.gamma), reports, loss0, ev.xs))
}
