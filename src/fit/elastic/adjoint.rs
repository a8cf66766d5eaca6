//! Equilibrium per frame (VH Eq. 14) and the adjoint gradient of the loss
//! (VH Eq. 15-17).
//!
//! With `g(x, γ) = ∂E/∂x - f_ext` on the free DOFs (pinned nodes are
//! Dirichlet: fixed, so the unknowns are the free coordinates),
//! `K = ∂g/∂x` the exact force Jacobian ([`crate::sim::hessian::element_hessian`]
//! without projection: the adjoint needs the true linearization) and
//! `C = ∂g/∂γ` ([`crate::sim::hessian::element_gamma_derivatives`]):
//! `Kᵀ λ = ∂ε/∂xᵀ` (Eq. 17) and `∂ε/∂γ = -λᵀ C` (Eq. 16). `K` is
//! symmetric except where the 0.01 singular-value floor is active, and need
//! not be definite away from a stable equilibrium: [`super::jacobian`]
//! factors it by sparse Cholesky where it is symmetric positive definite,
//! else by sparse LU, which solves with `Kᵀ` exactly.

use faer::linalg::solvers::SolveCore;
use faer::{Conj, Mat};
use nalgebra::DMatrix;
use rayon::prelude::*;

use super::error::SolveError;
use super::force_loss::{wrench_coefficients, ForceTarget};
use super::jacobian::{KFactor, KPatternCache, SYMMETRY_TOLERANCE};
use super::loss::FrameTarget;
use super::types::{Frame, MaterialFields};
use crate::geom::{TetMesh, Vec3};
use crate::linalg::lu::sparse_lu;
use crate::sim::element::Vec12;
use crate::sim::energy::ElasticModel;
use crate::sim::fibre::fibre_gamma_derivative;
use crate::sim::hessian::element_gamma_derivatives;
use crate::sim::statics::{StaticAnalysis, StaticParams, StaticSolver, StaticStats};

/// Free DOFs of a frame: 3 per unpinned node, in node order.
#[derive(Debug, Clone, PartialEq)]
pub struct FreeDofs {
    /// First DOF of each node, None when pinned.
    pub index: Vec<Option<usize>>,
    /// Number of free DOFs.
    pub ndof: usize,
}

impl FreeDofs {
    /// Free DOFs of `n` nodes with `pinned` fixed (indices checked by the caller).
    pub fn new(n: usize, pinned: &[usize]) -> FreeDofs {
        let mut is_pinned = vec![false; n];
        for &p in pinned {
            if p < n {
                is_pinned[p] = true;
            }
        }
        let mut index = vec![None; n];
        let mut ndof = 0;
        for i in 0..n {
            if !is_pinned[i] {
                index[i] = Some(ndof);
                ndof += 3;
            }
        }
        FreeDofs { index, ndof }
    }
}

/// Newton tolerance of the projected-Hessian solve before polishing: the
/// energy line search of [`StaticSolver`] stalls near 1e-8 (energy changes
/// reach rounding), so tighter residuals come from exact Newton steps.
const COARSE_TOLERANCE: f64 = 1e-6;

/// The coarse tolerance of a second try when the projected-Hessian Newton
/// stalls above [`COARSE_TOLERANCE`] (measured: a cantilever frame under
/// gravity stuck at 1.03e-6 after 100 iterations); the exact Newton steps of
/// the polish then go on from there.
const STALLED_TOLERANCE: f64 = 1e-4;

/// Equilibrium of `frame` under `model` (VH Eq. 14, quasi-static) from
/// `start` (pinned nodes are put at the frame's own start positions):
/// [`StaticSolver`] to `max(tolerance, 1e-6)`, then, as VH §8 does after PD,
/// a few full Newton steps with the exact force Jacobian (sparse LU) until
/// the relative residual (as [`crate::sim::statics`] defines it) is at most
/// `params.tolerance`.
pub fn equilibrium(
    model: &ElasticModel,
    mass: &[f64],
    frame: &Frame,
    start: &[Vec3],
    params: &StaticParams,
) -> Result<(Vec<Vec3>, StaticStats), SolveError> {
    equilibrium_with(model, mass, frame, start, params, &FrameCache::default())
}

/// What the solves of one frame keep from one material to the next: the
/// statics' pattern analysis and the force Jacobian's Cholesky analysis
/// (both fixed by the mesh and the frame's pins).
#[derive(Default)]
pub struct FrameCache {
    statics: std::sync::Mutex<StaticAnalysis>,
    pub(super) jacobian: KPatternCache,
}

/// [`equilibrium`] with the frame's `cache`.
pub fn equilibrium_with(
    model: &ElasticModel,
    mass: &[f64],
    frame: &Frame,
    start: &[Vec3],
    params: &StaticParams,
    cache: &FrameCache,
) -> Result<(Vec<Vec3>, StaticStats), SolveError> {
    let analysis = std::mem::take(&mut *cache.statics.lock().unwrap_or_else(|e| e.into_inner()));
    let mut solver = StaticSolver::new(model.clone(), mass, &frame.pinned)?.with_analysis(analysis);
    let result = equilibrium_of(&mut solver, model, frame, start, params);
    *cache.statics.lock().unwrap_or_else(|e| e.into_inner()) = solver.into_analysis();
    result
}

fn equilibrium_of(
    solver: &mut StaticSolver,
    model: &ElasticModel,
    frame: &Frame,
    start: &[Vec3],
    params: &StaticParams,
) -> Result<(Vec<Vec3>, StaticStats), SolveError> {
    let mut x0 = start.to_vec();
    for &p in &frame.pinned {
        x0[p] = frame.start[p];
    }
    let coarse = StaticParams {
        tolerance: params.tolerance.max(COARSE_TOLERANCE),
        ..*params
    };
    let (mut x, mut stats) = match solver.solve(&x0, &frame.f_ext, None, &coarse) {
        Ok(r) => r,
        Err(first @ crate::sim::SimError::Diverged { .. })
            if coarse.tolerance < STALLED_TOLERANCE =>
        {
            let looser = StaticParams {
                tolerance: STALLED_TOLERANCE,
                ..coarse
            };
            solver
                .solve(&x0, &frame.f_ext, None, &looser)
                .map_err(|second| SolveError::Stalled {
                    first,
                    tolerance: STALLED_TOLERANCE,
                    second,
                })?
        }
        Err(e) => return Err(SolveError::NoEquilibrium(e)),
    };
    let free = FreeDofs::new(model.num_nodes(), &frame.pinned);
    let (mut g, mut rel) = residual(model, frame, &x, &free)?;
    let mut polish = 0;
    while rel > params.tolerance && polish < 8 {
        polish += 1;
        let k = assemble_k(model, &x, &free)?;
        let lu = sparse_lu(free.ndof, &k)?;
        let mut rhs = Mat::<f64>::from_fn(free.ndof, 1, |i, _| -g[i]);
        lu.solve_in_place_with_conj(Conj::No, rhs.as_mut());
        let mut step = 1.0;
        let mut improved = false;
        for _ in 0..4 {
            let trial: Vec<Vec3> = x
                .iter()
                .enumerate()
                .map(|(i, p)| match free.index[i] {
                    Some(d) => std::array::from_fn(|c| p[c] + step * rhs[(d + c, 0)]),
                    None => *p,
                })
                .collect();
            let (gt, rt) = residual(model, frame, &trial, &free)?;
            if rt < rel {
                (x, g, rel, improved) = (trial, gt, rt, true);
                break;
            }
            step *= 0.5;
        }
        stats.iterations += 1;
        stats.residuals.push(rel);
        if !improved {
            break;
        }
    }
    if !(rel <= params.tolerance) || !x.iter().flatten().all(|v| v.is_finite()) {
        return Err(SolveError::NotConverged {
            residual: rel,
            tolerance: params.tolerance,
        });
    }
    Ok((x, stats))
}

/// A known equilibrium: one frame's positions under a material (stacked
/// `[γs; γv]`, Pa), from which [`equilibrium_continued`] reaches another.
#[derive(Debug, Clone, PartialEq)]
pub struct Anchor {
    pub gamma: std::sync::Arc<Vec<f64>>,
    pub x: Vec<Vec3>,
}

/// Halvings of the material step in [`equilibrium_continued`] before it
/// gives up: the path is walked in steps no shorter than 1/2^8 of it.
const CONTINUATION_HALVINGS: u32 = 8;

/// Equilibrium of `frame` under the material `gamma` (stacked `[γs; γv]`,
/// Pa, all > 0), reached by continuation from `anchor`: the material walks
/// the geometric path `γ(t) = γ_a^(1-t) γ^t` (t from 0 to 1; positive all
/// along, and scale-uniform in ln γ like the fit's log-space steps), each
/// [`equilibrium`] warm-started from the last. A step whose solve fails is
/// halved, a step that succeeds doubles the next. Needed where Newton from
/// the frame's own start does not converge for a fitted material of high
/// contrast (γ spanning ten decades) although the fit reached that material
/// through equilibria it warm-started all the way. Returns the positions and
/// the number of solves.
pub fn equilibrium_continued(
    mesh: &TetMesh,
    mass: &[f64],
    frame: &Frame,
    fields: &MaterialFields,
    anchor: &Anchor,
    params: &StaticParams,
) -> Result<(Vec<Vec3>, u32), SolveError> {
    let gamma = &fields.stacked();
    let len = fields.num_fields() * mesh.num_tets();
    if gamma.len() != len || anchor.gamma.len() != len || anchor.x.len() != mesh.num_nodes() {
        return Err(SolveError::AnchorMismatch);
    }
    let (mut t, mut h, mut solves) = (0.0f64, 1.0f64, 0u32);
    let mut x = anchor.x.clone();
    while t < 1.0 {
        let tt = (t + h).min(1.0);
        let g: Vec<f64> = anchor
            .gamma
            .iter()
            .zip(gamma)
            .map(|(a, b)| {
                if tt >= 1.0 {
                    *b
                } else {
                    a.powf(1.0 - tt) * b.powf(tt)
                }
            })
            .collect();
        let m = fields.with_stacked(&g).model(mesh)?;
        solves += 1;
        match equilibrium(&m, mass, frame, &x, params) {
            Ok((xn, _)) => {
                x = xn;
                t = tt;
                h = (2.0 * h).min(1.0);
            }
            Err(e) => {
                h *= 0.5;
                if h < 0.5f64.powi(CONTINUATION_HALVINGS as i32) {
                    return Err(SolveError::Continuation {
                        error: Box::new(e),
                        fraction: t,
                    });
                }
            }
        }
    }
    Ok((x, solves))
}

/// `g = ∂E/∂x - f_ext` on the free DOFs and its relative size: largest free
/// node residual over the largest free-node external or elastic force (the
/// pinned nodes' too when no free node is loaded).
fn residual(
    model: &ElasticModel,
    frame: &Frame,
    x: &[Vec3],
    free: &FreeDofs,
) -> Result<(Vec<f64>, f64), SolveError> {
    let grad = model.gradient(x)?;
    let mut g = vec![0.0; free.ndof];
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let loaded =
        (0..free.index.len()).any(|i| free.index[i].is_some() && norm(frame.f_ext[i]) > 0.0);
    for (i, fi) in free.index.iter().enumerate() {
        let f = frame.f_ext[i];
        // As crate::sim::statics: pinned nodes' elastic forces (reactions)
        // count only when no free node is loaded.
        if fi.is_some() || !loaded {
            scale = scale.max(norm(f)).max(norm(grad[i]));
        }
        if let Some(d) = fi {
            let r = [grad[i][0] - f[0], grad[i][1] - f[1], grad[i][2] - f[2]];
            g[*d..*d + 3].copy_from_slice(&r);
            worst = worst.max(norm(r));
        }
    }
    let rel = if scale > 0.0 { worst / scale } else { worst };
    if !rel.is_finite() {
        return Err(SolveError::NonFiniteResidual);
    }
    Ok((g, rel))
}

/// Exact `K = ∂g/∂x` on the free DOFs (entries, duplicates summed).
fn assemble_k(
    model: &ElasticModel,
    x: &[Vec3],
    free: &FreeDofs,
) -> Result<Vec<(usize, usize, f64)>, SolveError> {
    Ok(assemble_k_checked(model, x, free)?.0)
}

/// Sparse matrix entries (row, col, value), duplicates summed.
type Entries = Vec<(usize, usize, f64)>;

/// [`assemble_k`], and whether every element block is symmetric to
/// [`SYMMETRY_TOLERANCE`] of its largest entry (then so is `K`).
fn assemble_k_checked(
    model: &ElasticModel,
    x: &[Vec3],
    free: &FreeDofs,
) -> Result<(Entries, bool), SolveError> {
    let f = model.deformation_gradients(x)?;
    let rest = model.rest();
    let blocks: Vec<_> = (0..rest.len())
        .into_par_iter()
        .map(|e| model.tet_hessian(e, &f[e], false))
        .collect();
    let symmetric = blocks.par_iter().all(|h| {
        let asymmetry = (h - h.transpose()).amax();
        asymmetry <= SYMMETRY_TOLERANCE * h.amax()
    });
    let mut k = Vec::with_capacity(rest.len() * 144);
    for (r, h) in rest.iter().zip(&blocks) {
        for b in 0..4 {
            let Some(ib) = free.index[r.nodes[b]] else {
                continue;
            };
            for a in 0..4 {
                let Some(ia) = free.index[r.nodes[a]] else {
                    continue;
                };
                for kk in 0..3 {
                    for cc in 0..3 {
                        k.push((ib + kk, ia + cc, h[(3 * b + kk, 3 * a + cc)]));
                    }
                }
            }
        }
    }
    Ok((k, symmetric))
}

/// Everything Eq. 16-21 need from one frame at its equilibrium.
pub struct FrameLinearization {
    pub free: FreeDofs,
    /// `K = ∂g/∂x` on free DOFs, entries (row, col, value), duplicates summed.
    pub k: Vec<(usize, usize, f64)>,
    /// `C = ∂g/∂γ`: (free DOF, index in the stacked `γ` of length n_F n_E
    /// for n_F fields, value).
    pub c: Vec<(usize, usize, f64)>,
    /// `G = ∂²ε/∂x²` on free DOFs (row, col, value).
    pub g: Vec<(usize, usize, f64)>,
    /// `∂ε/∂x` on free DOFs.
    pub de_dx: Vec<f64>,
    /// The adjoint state `λ` (Eq. 17).
    pub lambda: Vec<f64>,
    /// `∂ε/∂γ` (Eq. 16), stacked `[γs; γv; γ_fibres...]`.
    pub grad: Vec<f64>,
    /// The factor of `K` (the adjoint's), reused by the Gauss-Newton
    /// solves that need `K⁻¹`.
    pub k_factor: KFactor,
    /// The clamp-force term's linearization, where the frame has one.
    pub force: Option<ForceLinearization>,
}

/// The clamp-force term of a frame linearized at its equilibrium
/// ([`super::force_loss`]): `ε_F ≈ w |r + J_F dγ|²`.
pub struct ForceLinearization {
    /// `J_F = dW/dγ = A (C_h - K_hf K⁻¹ C_f)`: one row per band and wrench
    /// component (N/Pa, N per unit β), one column per stacked parameter.
    pub jacobian: DMatrix<f64>,
    /// The residuals `W - R` (N), stacked like the rows.
    pub residual: Vec<f64>,
    /// `2 w` (m³/N²): the term's Gauss-Newton matrix is `2 w J_Fᵀ J_F`.
    pub weight2: f64,
}

/// Linearizes `frame` at its equilibrium `x` under `model`: `K`, `C`, `G`,
/// and the adjoint gradient. `cache` keeps the frame's Cholesky analysis
/// from one linearization to the next ([`KFactor`]).
pub fn linearize(
    model: &ElasticModel,
    frame: &Frame,
    x: &[Vec3],
    cache: &FrameCache,
) -> Result<FrameLinearization, SolveError> {
    let free = FreeDofs::new(model.num_nodes(), &frame.pinned);
    let f = model.deformation_gradients(x)?;
    let rest = model.rest();
    let ne = rest.len();
    let (k, symmetric) = assemble_k_checked(model, x, &free)?;
    // Fields: γs, γv, each family's γ, then each stiffening family's β
    // ([`super::types::MaterialFields::stacked`]).
    let fams = model.fibres();
    let stiff: Vec<usize> = (0..fams.len()).filter(|&k| fams[k].stiffening()).collect();
    let nf = 2 + fams.len() + stiff.len();
    let mut c = Vec::with_capacity(ne * 12 * nf);
    // The held band of each node the clamp-force term reads, and the rows
    // `A C_h` of the wrench's direct dependence on γ.
    let mut force_rows = frame
        .forces
        .as_ref()
        .filter(|t| t.weight > 0.0 && !t.bands.is_empty())
        .map(|t| ForceRows::new(t, x, model.num_nodes(), nf * ne));
    for (e, r) in rest.iter().enumerate() {
        let (ds, dv) = element_gamma_derivatives(&f[e], r);
        let fibre: Vec<_> = fams
            .iter()
            .map(|fam| {
                if fam.stiffening() {
                    fam.param_derivatives(e, &f[e], r)
                } else {
                    let dk = fibre_gamma_derivative(&f[e], r, &fam.directions[e]);
                    (dk, dk * 0.0)
                }
            })
            .collect();
        if let Some(rows) = force_rows.as_mut() {
            let mut per_field: Vec<(usize, &Vec12)> = vec![(e, &ds), (ne + e, &dv)];
            for (k, (dk, _)) in fibre.iter().enumerate() {
                per_field.push(((2 + k) * ne + e, dk));
            }
            for (j, &k) in stiff.iter().enumerate() {
                per_field.push(((2 + fams.len() + j) * ne + e, &fibre[k].1));
            }
            rows.add_parameters(&r.nodes, &per_field);
        }
        for b in 0..4 {
            let Some(ib) = free.index[r.nodes[b]] else {
                continue;
            };
            for kk in 0..3 {
                c.push((ib + kk, e, ds[3 * b + kk]));
                c.push((ib + kk, ne + e, dv[3 * b + kk]));
                for (k, (dk, _)) in fibre.iter().enumerate() {
                    c.push((ib + kk, (2 + k) * ne + e, dk[3 * b + kk]));
                }
                for (j, &k) in stiff.iter().enumerate() {
                    let db = fibre[k].1[3 * b + kk];
                    c.push((ib + kk, (2 + fams.len() + j) * ne + e, db));
                }
            }
        }
    }
    let g = free_hessian(&frame.target, model, &free);
    let dfull = frame.target.gradient(model, x);
    let mut de_dx = vec![0.0; free.ndof];
    for (i, fi) in free.index.iter().enumerate() {
        if let Some(d) = fi {
            de_dx[*d..*d + 3].copy_from_slice(&dfull[i]);
        }
    }
    let factor = KFactor::new(free.ndof, &k, symmetric, &cache.jacobian)?;
    let mut rhs = Mat::<f64>::from_fn(free.ndof, 1, |i, _| de_dx[i]);
    factor.solve_transpose_in_place(rhs.as_mut());
    let lambda: Vec<f64> = (0..free.ndof).map(|i| rhs[(i, 0)]).collect();
    if !lambda.iter().all(|v| v.is_finite()) {
        return Err(SolveError::SingularAdjoint);
    }
    let mut grad = vec![0.0; nf * ne];
    for &(row, j, v) in &c {
        grad[j] -= lambda[row] * v;
    }
    let force = match (force_rows, &frame.forces) {
        (Some(rows), Some(t)) => {
            let lin = rows.finish(model, &f, x, frame, t, &free, &factor, &c)?;
            let r = nalgebra::DVector::from_column_slice(&lin.residual);
            let jr = lin.jacobian.tr_mul(&r);
            for (gj, v) in grad.iter_mut().zip(jr.iter()) {
                *gj += lin.weight2 * v;
            }
            Some(lin)
        }
        _ => None,
    };
    Ok(FrameLinearization {
        free,
        k,
        c,
        g,
        de_dx,
        lambda,
        grad,
        k_factor: factor,
        force,
    })
}

/// The clamp-force term's rows while [`linearize`] assembles `C`: which
/// band (and place in it) each held node has, its wrench coefficients, and
/// `A C_h` (one row per band and wrench component).
struct ForceRows {
    /// Per node: (band, index in the band) where the term reads it.
    place: Vec<Option<(usize, usize)>>,
    /// Per band, `A_i` of its nodes ([`wrench_coefficients`]).
    coeffs: Vec<Vec<[[f64; 3]; 6]>>,
    /// `A C_h`.
    direct: DMatrix<f64>,
}

impl ForceRows {
    fn new(t: &ForceTarget, x: &[Vec3], n: usize, params: usize) -> ForceRows {
        let mut place = vec![None; n];
        for (b, band) in t.bands.iter().enumerate() {
            for (k, &i) in band.nodes.iter().enumerate() {
                if i < n {
                    place[i] = Some((b, k));
                }
            }
        }
        ForceRows {
            place,
            coeffs: t
                .bands
                .iter()
                .map(|b| wrench_coefficients(&b.nodes, x, t.length))
                .collect(),
            direct: DMatrix::zeros(6 * t.bands.len(), params),
        }
    }

    /// Adds one tet's `∂g/∂γ_j` (12 entries per parameter `j`) on the held
    /// nodes the term reads.
    fn add_parameters(&mut self, nodes: &[usize; 4], per_field: &[(usize, &Vec12)]) {
        for (a, &node) in nodes.iter().enumerate() {
            let Some((b, k)) = self.place[node] else {
                continue;
            };
            let coeff = &self.coeffs[b][k];
            for &(j, d) in per_field {
                for (w, cw) in coeff.iter().enumerate() {
                    let v: f64 = (0..3).map(|kk| cw[kk] * d[3 * a + kk]).sum();
                    self.direct[(6 * b + w, j)] += v;
                }
            }
        }
    }

    /// `J_F = A C_h - (A K_hf) K⁻¹ C_f` and the residuals.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        self,
        model: &ElasticModel,
        f: &[nalgebra::Matrix3<f64>],
        x: &[Vec3],
        frame: &Frame,
        t: &ForceTarget,
        free: &FreeDofs,
        factor: &KFactor,
        c: &[(usize, usize, f64)],
    ) -> Result<ForceLinearization, SolveError> {
        let rows = self.direct.nrows();
        // (A K_hf)ᵀ: one column per wrench row, over the free DOFs.
        let mut lam = Mat::<f64>::zeros(free.ndof, rows);
        for (e, r) in model.rest().iter().enumerate() {
            if !r.nodes.iter().any(|&i| self.place[i].is_some()) {
                continue;
            }
            let h = model.tet_hessian(e, &f[e], false);
            for (a, &na) in r.nodes.iter().enumerate() {
                let Some((b, k)) = self.place[na] else {
                    continue;
                };
                let coeff = &self.coeffs[b][k];
                for (bb, &nb) in r.nodes.iter().enumerate() {
                    let Some(ib) = free.index[nb] else {
                        continue;
                    };
                    for cc in 0..3 {
                        for w in 0..6 {
                            let v: f64 = (0..3)
                                .map(|kk| coeff[w][kk] * h[(3 * a + kk, 3 * bb + cc)])
                                .sum();
                            lam[(ib + cc, 6 * b + w)] += v;
                        }
                    }
                }
            }
        }
        // Λ = K⁻ᵀ (A K_hf)ᵀ, so (A K_hf) K⁻¹ C_f = Λᵀ C_f.
        factor.solve_transpose_in_place(lam.as_mut());
        let mut jacobian = self.direct;
        for &(row, j, v) in c {
            for w in 0..rows {
                jacobian[(w, j)] -= lam[(row, w)] * v;
            }
        }
        if !jacobian.iter().all(|v| v.is_finite()) {
            return Err(SolveError::SingularAdjoint);
        }
        let grad = model.gradient(x)?;
        let residual: Vec<f64> = t
            .residuals(x, &grad, &frame.f_ext)
            .into_iter()
            .flatten()
            .collect();
        Ok(ForceLinearization {
            jacobian,
            residual,
            weight2: 2.0 * t.weight,
        })
    }
}

/// `G` of the frame's loss on the free DOFs (3 coordinates expanded).
fn free_hessian(
    target: &FrameTarget,
    model: &ElasticModel,
    free: &FreeDofs,
) -> Vec<(usize, usize, f64)> {
    let mut g = Vec::new();
    for (i, j, v) in target.hessian_entries(model) {
        if let (Some(a), Some(b)) = (free.index[i], free.index[j]) {
            for c in 0..3 {
                g.push((a + c, b + c, v));
            }
        }
    }
    g
}
