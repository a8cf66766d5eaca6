//! Newton equilibrium of the homogenized tet mesh (VH Eq. 13-14): the poses
//! the elasticity fit (VH §6) compares with yarn-level frames.
//!
//! Solves `∇E(x) - f_ext + M (x - x̃)/Δt² = 0` on the free nodes, where `E` is
//! VH Eq. 7 ([`super::energy`]), `f_ext` the external node forces (N; gravity
//! is `m_i g`), and the inertia term of Eq. 13 (`x̃ = 2 x_prev - x_prevprev`)
//! is present only when [`Inertia`] is given (dynamic frames); pinned nodes are
//! Dirichlet constraints (removed from the system). Each Newton step solves
//! with the PSD-projected Hessian ([`super::hessian`], plus `M/Δt²`) by a
//! sparse Cholesky whose symbolic analysis is done once per mesh and pin set
//! ([`StaticSolver::new`]); only the numeric factorization runs per iteration.
//! Backtracking line search on the total potential
//! `Π = E - f_ext·x + Σ m_i |x_i - x̃_i|²/(2Δt²) + E_c`, where `E_c` is the
//! optional collider penalty ([`ContactPenalty`]): points embedded in tets
//! (yarn vertices, through V2Y, VH Eq. 4) kept their thickness outside
//! signed-distance colliders by `k/2 · min(0, φ(p) - r)²` each. Its Newton
//! block is the Gauss-Newton `k n nᵀ` (PSD; the sphere's curvature term is
//! dropped), and every point couples only the four nodes of its own tet, so
//! the sparsity pattern, and the symbolic factorization, do not change.
//!
//! Convergence: relative force residual `max_i |r_i| / scale <= tolerance`
//! (default 1e-6) over free nodes, `scale` = the largest free-node external
//! force or elastic force at the solution (whichever is larger); when no free
//! node carries an external force, the pinned nodes' elastic forces (the
//! reactions) count too.
//! Deterministic: assembly and factorization are sequential in a fixed order;
//! the energy/gradient sums are in tet order.

use std::time::Instant;

use faer::sparse::{Argsort, Pair, SparseColMat, SymbolicSparseColMat, Triplet};
use faer::Mat;
use rayon::prelude::*;

use super::energy::ElasticModel;
use super::SimError;
use crate::geom::Vec3;
use crate::linalg::cholesky::SparseCholesky;
use faer::sparse::linalg::cholesky::SymbolicCholesky;

/// Parameters of [`StaticSolver::solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticParams {
    /// Relative force residual to reach (dimensionless). Default 1e-6.
    pub tolerance: f64,
    /// Newton iteration cap. Default 100.
    pub max_iterations: u32,
}

impl Default for StaticParams {
    fn default() -> Self {
        StaticParams {
            tolerance: 1e-6,
            max_iterations: 100,
        }
    }
}

/// The inertia term of VH Eq. 13 for dynamic frames.
#[derive(Debug, Clone, Copy)]
pub struct Inertia<'a> {
    /// Positions at the previous frame (m).
    pub x_prev: &'a [Vec3],
    /// Positions two frames back (m).
    pub x_prevprev: &'a [Vec3],
    /// Frame interval Δt (s), > 0.
    pub dt: f64,
}

/// A signed-distance collider for [`ContactPenalty`].
pub trait SignedDistance: Send + Sync {
    /// Signed distance (m, positive outside) of `p` and the outward unit
    /// normal of the closest surface point.
    fn signed_distance(&self, p: Vec3) -> (f64, Vec3);
}

/// A point embedded in one tet: `p = Σ_a w_a x_{nodes[a]}` (VH Eq. 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmbeddedPoint {
    /// The tet's four node indices.
    pub nodes: [usize; 4],
    /// Barycentric weights (sum to 1).
    pub weights: [f64; 4],
    /// Distance the point keeps from every collider (m), e.g. a yarn radius.
    pub thickness: f64,
}

/// Collider penalty `E_c = Σ_points Σ_colliders k/2 · min(0, φ(p) - r)²`.
pub struct ContactPenalty {
    pub points: Vec<EmbeddedPoint>,
    pub colliders: Vec<Box<dyn SignedDistance>>,
    /// Penalty stiffness k per point (N/m), > 0.
    pub stiffness: f64,
}

impl ContactPenalty {
    fn position(&self, pt: &EmbeddedPoint, x: &[Vec3]) -> Vec3 {
        std::array::from_fn(|k| (0..4).map(|a| pt.weights[a] * x[pt.nodes[a]][k]).sum())
    }

    /// Active contacts at `x`: (point index, gap `φ - r` < 0, normal).
    fn active(&self, x: &[Vec3]) -> Vec<(usize, f64, Vec3)> {
        let mut out = Vec::new();
        for (i, pt) in self.points.iter().enumerate() {
            let p = self.position(pt, x);
            for c in &self.colliders {
                let (d, n) = c.signed_distance(p);
                let gap = d - pt.thickness;
                if gap < 0.0 {
                    out.push((i, gap, n));
                }
            }
        }
        out
    }

    /// Adds `E_c` to `e` and its gradient to `g`.
    fn add(&self, x: &[Vec3], e: &mut f64, g: &mut [Vec3]) {
        for (i, gap, n) in self.active(x) {
            let pt = &self.points[i];
            *e += 0.5 * self.stiffness * gap * gap;
            for a in 0..4 {
                for k in 0..3 {
                    g[pt.nodes[a]][k] += pt.weights[a] * self.stiffness * gap * n[k];
                }
            }
        }
    }

    /// Points closer than their thickness to a collider at `x`, and the
    /// deepest penetration (m, >= 0).
    pub fn penetration(&self, x: &[Vec3]) -> (usize, f64) {
        let a = self.active(x);
        (a.len(), a.iter().map(|c| -c.1).fold(0.0, f64::max))
    }
}

/// What one solve did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct StaticStats {
    /// Newton iterations taken.
    pub iterations: u32,
    /// Relative force residual after each iteration (the first entry: at the start).
    pub residuals: Vec<f64>,
    /// Total line-search halvings.
    pub line_search_halvings: u32,
    /// Wall time of assembly + numeric factorization (ms).
    pub factor_ms: f64,
    /// Wall time of the whole solve (ms).
    pub total_ms: f64,
}

/// Newton statics for one mesh, pin set and mass vector.
pub struct StaticSolver {
    model: ElasticModel,
    mass: Vec<f64>,
    /// DOF index (3 per free node) of each node, None when pinned.
    free_index: Vec<Option<usize>>,
    ndof: usize,
    analysis: StaticAnalysis,
    /// Symbolic analysis time (ms), paid once per [`StaticAnalysis`].
    pub symbolic_ms: f64,
    contact: Option<ContactPenalty>,
}

/// What a [`StaticSolver`] learns about its Newton matrix's pattern, which
/// depends only on the mesh and the pin set: the symbolic Cholesky and where
/// each assembled entry lands in the compressed lower triangle. A solver
/// hands it on ([`StaticSolver::into_analysis`], [`StaticSolver::with_analysis`])
/// to the next solver of the same mesh and pins: the elasticity fit solves
/// each frame's equilibrium hundreds of times under changing materials.
#[derive(Default)]
pub struct StaticAnalysis {
    /// The tets and the free-DOF map the analysis belongs to.
    key: Option<(usize, Vec<Option<usize>>)>,
    symbolic: Option<SymbolicCholesky<usize>>,
    /// The lower triangle's pattern, the order of the elastic and mass
    /// entries into it, and their number (collider entries, whose number
    /// changes with the contacts, go through a fresh sort).
    pattern: Option<(SymbolicSparseColMat<usize>, Argsort<usize>, usize)>,
}

impl StaticSolver {
    /// Prepares statics for `model` with node masses `mass` (kg) and the
    /// pinned nodes `pinned` (their positions are given to [`Self::solve`]).
    pub fn new(model: ElasticModel, mass: &[f64], pinned: &[usize]) -> Result<Self, SimError> {
        let n = model.num_nodes();
        if mass.len() != n || mass.iter().any(|m| !(m.is_finite() && *m >= 0.0)) {
            return Err(SimError::Inconsistent(format!(
                "{} node masses (finite, >= 0) for {n} nodes",
                mass.len()
            )));
        }
        let mut is_pinned = vec![false; n];
        for &p in pinned {
            if p >= n {
                return Err(SimError::Inconsistent(format!(
                    "pinned node {p} but the mesh has {n} nodes"
                )));
            }
            is_pinned[p] = true;
        }
        let mut free_index = vec![None; n];
        let mut ndof = 0;
        for i in 0..n {
            if !is_pinned[i] {
                free_index[i] = Some(ndof);
                ndof += 3;
            }
        }
        let key = Some((model.rest().len(), free_index.clone()));
        Ok(StaticSolver {
            model,
            mass: mass.to_vec(),
            free_index,
            ndof,
            analysis: StaticAnalysis {
                key,
                ..Default::default()
            },
            symbolic_ms: 0.0,
            contact: None,
        })
    }

    /// Takes over `analysis` from an earlier solver when it was made for
    /// the same tets and pins (else keeps its own, empty one).
    pub fn with_analysis(mut self, analysis: StaticAnalysis) -> Self {
        if analysis.key == self.analysis.key {
            self.analysis = analysis;
        }
        self
    }

    /// The pattern analysis, for the next solver of this mesh and pin set.
    pub fn into_analysis(self) -> StaticAnalysis {
        self.analysis
    }

    /// Sets (or, with `None`, removes) the collider penalty. Its points must
    /// name nodes of the mesh; the stiffness must be positive and finite.
    pub fn set_contact(&mut self, contact: Option<ContactPenalty>) -> Result<(), SimError> {
        if let Some(c) = &contact {
            let n = self.model.num_nodes();
            if !(c.stiffness > 0.0 && c.stiffness.is_finite()) {
                return Err(SimError::Inconsistent(format!(
                    "contact stiffness {} N/m must be positive and finite",
                    c.stiffness
                )));
            }
            if let Some(p) = c.points.iter().find(|p| {
                p.nodes.iter().any(|&i| i >= n)
                    || !p.thickness.is_finite()
                    || p.weights.iter().any(|w| !w.is_finite())
            }) {
                return Err(SimError::Inconsistent(format!(
                    "contact point {p:?}: nodes beyond the mesh's {n} or non-finite values"
                )));
            }
        }
        self.contact = contact;
        Ok(())
    }

    /// The collider penalty, if set.
    pub fn contact(&self) -> Option<&ContactPenalty> {
        self.contact.as_ref()
    }

    /// The elastic model.
    pub fn model(&self) -> &ElasticModel {
        &self.model
    }

    /// Lower triangle of the projected Newton matrix on free DOFs plus
    /// `mass_scale · M`. The triplet positions depend only on the mesh and pin
    /// set, so the sparsity pattern is the same at every call.
    fn assemble(
        &mut self,
        x: &[Vec3],
        mass_scale: f64,
    ) -> Result<SparseColMat<usize, f64>, SimError> {
        let f = self.model.deformation_gradients(x)?;
        let rest = self.model.rest();
        let blocks: Vec<_> = (0..rest.len())
            .into_par_iter()
            .map(|e| self.model.tet_hessian(e, &f[e], true))
            .collect();
        let mut trip = Vec::with_capacity(rest.len() * 78 + self.ndof);
        for (r, h) in rest.iter().zip(&blocks) {
            for a in 0..4 {
                let Some(ia) = self.free_index[r.nodes[a]] else {
                    continue;
                };
                for b in 0..4 {
                    let Some(ib) = self.free_index[r.nodes[b]] else {
                        continue;
                    };
                    for c in 0..3 {
                        for k in 0..3 {
                            let (row, col) = (ia + c, ib + k);
                            if row >= col {
                                trip.push(Triplet::new(row, col, h[(3 * a + c, 3 * b + k)]));
                            }
                        }
                    }
                }
            }
        }
        for (i, fi) in self.free_index.iter().enumerate() {
            if let Some(d) = fi {
                for c in 0..3 {
                    trip.push(Triplet::new(d + c, d + c, mass_scale * self.mass[i]));
                }
            }
        }
        let fixed = trip.len();
        if let Some(cp) = &self.contact {
            // Gauss-Newton block k (w wᵀ) ⊗ (n nᵀ) of each active contact;
            // its node pairs share a tet, so the pattern is the elastic one.
            for (i, _, nrm) in cp.active(x) {
                let pt = &cp.points[i];
                for a in 0..4 {
                    let Some(ia) = self.free_index[pt.nodes[a]] else {
                        continue;
                    };
                    for b in 0..4 {
                        let Some(ib) = self.free_index[pt.nodes[b]] else {
                            continue;
                        };
                        let w = cp.stiffness * pt.weights[a] * pt.weights[b];
                        for c in 0..3 {
                            for k in 0..3 {
                                let (row, col) = (ia + c, ib + k);
                                if row >= col {
                                    trip.push(Triplet::new(row, col, w * nrm[c] * nrm[k]));
                                }
                            }
                        }
                    }
                }
            }
        }
        let err = |e: String| SimError::Inconsistent(format!("assembling the Newton matrix: {e}"));
        if trip.len() > fixed {
            return SparseColMat::try_new_from_triplets(self.ndof, self.ndof, &trip)
                .map_err(|e| err(format!("{e:?}")));
        }
        // No collider entries: the entries come in the same order every
        // time, so the sort into columns is done once.
        let pattern = match self.analysis.pattern.take() {
            Some(p) if p.2 == fixed => p,
            _ => {
                let pairs: Vec<Pair<usize, usize>> =
                    trip.iter().map(|t| Pair::new(t.row, t.col)).collect();
                let (sym, argsort) =
                    SymbolicSparseColMat::try_new_from_indices(self.ndof, self.ndof, &pairs)
                        .map_err(|e| err(format!("{e:?}")))?;
                (sym, argsort, fixed)
            }
        };
        let vals: Vec<f64> = trip.iter().map(|t| t.val).collect();
        let a = SparseColMat::new_from_argsort(pattern.0.clone(), &pattern.1, &vals)
            .map_err(|e| err(format!("{e:?}")));
        self.analysis.pattern = Some(pattern);
        a
    }

    /// Potential `Π` (J) and its gradient (N) at `x`.
    fn potential(
        &self,
        x: &[Vec3],
        f_ext: &[Vec3],
        inertia: Option<(&[Vec3], f64)>,
    ) -> Result<(f64, Vec<Vec3>), SimError> {
        let mut e = self.model.energy(x)?;
        let mut g = self.model.gradient(x)?;
        if let Some(c) = &self.contact {
            c.add(x, &mut e, &mut g);
        }
        for i in 0..x.len() {
            for c in 0..3 {
                e -= f_ext[i][c] * x[i][c];
                g[i][c] -= f_ext[i][c];
                if let Some((xt, k)) = inertia {
                    let d = x[i][c] - xt[i][c];
                    e += 0.5 * k * self.mass[i] * d * d;
                    g[i][c] += k * self.mass[i] * d;
                }
            }
        }
        Ok((e, g))
    }

    /// Equilibrium from the start positions `x` (m; pinned nodes are held at
    /// their values in `x`) under external node forces `f_ext` (N), with the
    /// inertia term when `inertia` is given. Returns the positions and stats.
    pub fn solve(
        &mut self,
        x: &[Vec3],
        f_ext: &[Vec3],
        inertia: Option<Inertia<'_>>,
        params: &StaticParams,
    ) -> Result<(Vec<Vec3>, StaticStats), SimError> {
        let start = Instant::now();
        let n = self.model.num_nodes();
        if x.len() != n || f_ext.len() != n {
            return Err(SimError::Inconsistent(format!(
                "{} positions and {} forces for {n} nodes",
                x.len(),
                f_ext.len()
            )));
        }
        let all_finite = |v: &[Vec3]| v.iter().all(|p| p.iter().all(|c| c.is_finite()));
        if !all_finite(x) || !all_finite(f_ext) {
            return Err(SimError::Inconsistent(
                "non-finite positions or forces".into(),
            ));
        }
        let x_tilde: Option<(Vec<Vec3>, f64)> = match inertia {
            Some(i) => {
                if i.x_prev.len() != n || i.x_prevprev.len() != n || !(i.dt > 0.0) {
                    return Err(SimError::Inconsistent(
                        "inertia: previous frames must match the mesh and dt be > 0".into(),
                    ));
                }
                let xt = (0..n)
                    .map(|k| std::array::from_fn(|c| 2.0 * i.x_prev[k][c] - i.x_prevprev[k][c]))
                    .collect();
                Some((xt, 1.0 / (i.dt * i.dt)))
            }
            None => None,
        };
        let inert = x_tilde.as_ref().map(|(xt, k)| (xt.as_slice(), *k));
        let mass_scale = inert.map(|(_, k)| k).unwrap_or(0.0);
        let free_index = self.free_index.clone();
        let force_scale = |g: &[Vec3]| {
            // Largest free-node external and elastic force. Without any
            // free-node external force (a pose held by its pins only) the
            // free-node elastic force is the residual itself: the pins'
            // reactions then give the problem its force scale.
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let loaded = (0..f_ext.len()).any(|i| free_index[i].is_some() && norm(f_ext[i]) > 0.0);
            let mut s = 0.0f64;
            for (i, fi) in free_index.iter().enumerate() {
                if fi.is_some() || !loaded {
                    let el = norm(std::array::from_fn(|c| g[i][c] + f_ext[i][c]));
                    s = s.max(norm(f_ext[i])).max(el);
                }
            }
            s
        };
        let max_res = |g: &[Vec3]| {
            let mut m = 0.0f64;
            for (i, fi) in free_index.iter().enumerate() {
                if fi.is_some() {
                    m = m.max((g[i][0].powi(2) + g[i][1].powi(2) + g[i][2].powi(2)).sqrt());
                }
            }
            m
        };
        let mut x = x.to_vec();
        let (mut pi, mut g) = self.potential(&x, f_ext, inert)?;
        let mut stats = StaticStats::default();
        let rel = |g: &[Vec3]| {
            let s = force_scale(g);
            let r = max_res(g);
            if s > 0.0 {
                r / s
            } else {
                r
            }
        };
        stats.residuals.push(rel(&g));
        while *stats.residuals.last().unwrap_or(&0.0) > params.tolerance {
            if stats.iterations >= params.max_iterations {
                return Err(SimError::Diverged {
                    step: stats.iterations as u64,
                    node: 0,
                    reason: format!(
                        "Newton did not reach relative residual {} in {} iterations (at {:e})",
                        params.tolerance,
                        params.max_iterations,
                        stats.residuals.last().unwrap_or(&f64::NAN)
                    ),
                });
            }
            stats.iterations += 1;
            let t = Instant::now();
            let a = self.assemble(&x, mass_scale)?;
            if self.analysis.symbolic.is_none() {
                let ts = Instant::now();
                self.analysis.symbolic = Some(
                    SparseCholesky::symbolic(a.as_ref())
                        .map_err(|e| SimError::Inconsistent(format!("symbolic Cholesky: {e}")))?,
                );
                self.symbolic_ms = ts.elapsed().as_secs_f64() * 1e3;
            }
            let sym =
                self.analysis.symbolic.take().ok_or_else(|| {
                    SimError::Inconsistent("symbolic factorization missing".into())
                })?;
            let chol = SparseCholesky::numeric(sym, a.as_ref()).map_err(|e| {
                SimError::Inconsistent(format!(
                    "the Newton matrix is not positive definite ({e}); pin the mesh or give inertia"
                ))
            })?;
            stats.factor_ms += t.elapsed().as_secs_f64() * 1e3;
            let mut rhs = Mat::<f64>::zeros(self.ndof, 1);
            for (i, fi) in self.free_index.iter().enumerate() {
                if let Some(d) = fi {
                    for c in 0..3 {
                        rhs[(d + c, 0)] = -g[i][c];
                    }
                }
            }
            chol.solve_in_place(rhs.as_mut());
            // Keep the symbolic analysis for the next iteration and solve.
            self.analysis.symbolic = Some(chol.into_symbolic());
            let slope: f64 = self
                .free_index
                .iter()
                .enumerate()
                .filter_map(|(i, fi)| fi.map(|d| (i, d)))
                .map(|(i, d)| (0..3).map(|c| g[i][c] * rhs[(d + c, 0)]).sum::<f64>())
                .sum();
            let mut step = 1.0;
            let r0 = max_res(&g);
            let accepted = loop {
                let trial: Vec<Vec3> = x
                    .iter()
                    .enumerate()
                    .map(|(i, p)| match self.free_index[i] {
                        Some(d) => std::array::from_fn(|c| p[c] + step * rhs[(d + c, 0)]),
                        None => *p,
                    })
                    .collect();
                let (pt, gt) = self.potential(&trial, f_ext, inert)?;
                if pt.is_finite() && (pt <= pi + 1e-4 * step * slope || max_res(&gt) < r0) {
                    break Some((trial, pt, gt));
                }
                if stats.line_search_halvings > 40 * stats.iterations {
                    break None;
                }
                step *= 0.5;
                stats.line_search_halvings += 1;
            };
            let Some((xn, pn, gn)) = accepted else {
                return Err(SimError::Diverged {
                    step: stats.iterations as u64,
                    node: 0,
                    reason: "line search found no decrease (non-finite energy or stalled)".into(),
                });
            };
            x = xn;
            pi = pn;
            g = gn;
            let r = rel(&g);
            if !r.is_finite() {
                return Err(SimError::Diverged {
                    step: stats.iterations as u64,
                    node: 0,
                    reason: "non-finite residual".into(),
                });
            }
            stats.residuals.push(r);
        }
        stats.total_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok((x, stats))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embed::box_mesh;

    /// A 6x3x3-voxel slab pinned at x = 0, its x = L face pulled by 30 %,
    /// under gravity.
    fn slab() -> (ElasticModel, Vec<f64>, Vec<usize>, Vec<Vec3>, Vec<Vec3>) {
        let h = 0.01;
        let (mesh, mass) = box_mesh([6, 3, 3], h, 120.0);
        let n = mesh.num_nodes();
        let nt = mesh.num_tets();
        let model = ElasticModel::new(&mesh, &vec![1e4; nt], &vec![3e4; nt]).unwrap();
        let lx = 6.0 * h;
        let mut pinned = Vec::new();
        let mut x = mesh.nodes.clone();
        for (i, p) in mesh.nodes.iter().enumerate() {
            if p[0] < 1e-9 {
                pinned.push(i);
            } else if p[0] > lx - 1e-9 {
                pinned.push(i);
                x[i][0] = 1.3 * lx;
            }
        }
        let f_ext: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
        assert_eq!(f_ext.len(), n);
        (model, mass, pinned, x, f_ext)
    }

    #[test]
    fn a_handed_on_analysis_gives_the_same_equilibrium() {
        let (model, mass, pinned, x, f_ext) = slab();
        let p = StaticParams::default();
        let mut fresh = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
        let (want, _) = fresh.solve(&x, &f_ext, None, &p).unwrap();
        // The analysis of the same pins, under a stiffer material: taken
        // over, and the result is the fresh solver's bit for bit.
        let (mesh, _) = box_mesh([6, 3, 3], 0.01, 120.0);
        let nt = mesh.num_tets();
        let stiff = ElasticModel::new(&mesh, &vec![2e4; nt], &vec![6e4; nt]).unwrap();
        let mut other = StaticSolver::new(stiff, &mass, &pinned).unwrap();
        other.solve(&x, &f_ext, None, &p).unwrap();
        let analysis = other.into_analysis();
        assert!(analysis.symbolic.is_some() && analysis.pattern.is_some());
        let mut s = StaticSolver::new(model.clone(), &mass, &pinned)
            .unwrap()
            .with_analysis(analysis);
        assert!(s.analysis.symbolic.is_some());
        assert_eq!(s.solve(&x, &f_ext, None, &p).unwrap().0, want);
        // Another pin set's analysis is not taken over.
        let s2 = StaticSolver::new(model, &mass, &pinned[1..])
            .unwrap()
            .with_analysis(s.into_analysis());
        assert!(s2.analysis.symbolic.is_none() && s2.analysis.pattern.is_none());
    }

    #[test]
    fn stretched_slab_reaches_equilibrium() {
        let (model, mass, pinned, x, f_ext) = slab();
        let mut s = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
        let (xs, stats) = s.solve(&x, &f_ext, None, &StaticParams::default()).unwrap();
        let last = *stats.residuals.last().unwrap();
        assert!(last <= 1e-6, "residual {last}, {stats:?}");
        assert!(stats.iterations >= 2, "{stats:?}");
        // Independent check of the residual from the model's gradient.
        let g = model.gradient(&xs).unwrap();
        let mut r = 0.0f64;
        let mut scale = 0.0f64;
        for i in 0..xs.len() {
            if !pinned.contains(&i) {
                for c in 0..3 {
                    r = r.max((g[i][c] - f_ext[i][c]).abs());
                    scale = scale.max(g[i][c].abs());
                }
            }
        }
        assert!(r <= 2e-6 * scale, "{r} vs {scale}");
        // The middle of the slab moved: it is stretched, not left at rest.
        let moved = xs
            .iter()
            .zip(&x)
            .filter(|(a, b)| (a[0] - b[0]).abs() > 1e-3)
            .count();
        assert!(moved > 10);
        // Symbolic once: a second solve with new start positions reuses it.
        let (_, st2) = s
            .solve(&xs, &f_ext, None, &StaticParams::default())
            .unwrap();
        assert!(st2.iterations <= 1, "{st2:?}");
    }

    /// Held by its pins only (no external force): the free-node elastic
    /// force is the residual itself, so the pins' reactions give the scale;
    /// the solve converges and the interior is at rest to that scale.
    #[test]
    fn a_slab_held_only_by_pins_reaches_equilibrium() {
        let (model, mass, pinned, x, f_ext) = slab();
        let zero = vec![[0.0; 3]; f_ext.len()];
        let mut s = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
        let (xs, stats) = s.solve(&x, &zero, None, &StaticParams::default()).unwrap();
        let g = model.gradient(&xs).unwrap();
        let norm = |v: Vec3| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let (mut r, mut reaction) = (0.0f64, 0.0f64);
        for (i, gi) in g.iter().enumerate() {
            if pinned.contains(&i) {
                reaction = reaction.max(norm(*gi));
            } else {
                r = r.max(norm(*gi));
            }
        }
        assert!(
            reaction > 0.0 && r <= 1e-6 * reaction,
            "{r:e} vs {reaction:e}, {stats:?}"
        );
    }

    #[test]
    fn inertia_term_gives_a_consistent_step_and_threads_do_not_matter() {
        let (model, mass, pinned, x, f_ext) = slab();
        let rest: Vec<Vec3> = x.clone();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut s = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
                let inertia = Inertia {
                    x_prev: &rest,
                    x_prevprev: &rest,
                    dt: 1.0 / 24.0,
                };
                s.solve(&x, &f_ext, Some(inertia), &StaticParams::default())
                    .unwrap()
            })
        };
        let (a, sa) = run(1);
        let (b, _) = run(2);
        assert_eq!(a, b, "thread count changed the result");
        assert!(*sa.residuals.last().unwrap() <= 1e-6);
        // The solution satisfies Eq. 13: ∇E - f_ext + M (x - x̃)/Δt² = 0.
        let g = model.gradient(&a).unwrap();
        let k = 24.0f64 * 24.0;
        let mut worst = 0.0f64;
        for i in 0..a.len() {
            if !pinned.contains(&i) {
                for c in 0..3 {
                    let r = g[i][c] - f_ext[i][c] + k * mass[i] * (a[i][c] - rest[i][c]);
                    worst = worst.max(r.abs());
                }
            }
        }
        assert!(worst < 2e-6 * g.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs())));
    }

    struct Floor(f64);
    impl SignedDistance for Floor {
        fn signed_distance(&self, p: Vec3) -> (f64, Vec3) {
            (p[1] - self.0, [0.0, 1.0, 0.0])
        }
    }
    struct Ball(Vec3, f64);
    impl SignedDistance for Ball {
        fn signed_distance(&self, p: Vec3) -> (f64, Vec3) {
            let d: Vec3 = std::array::from_fn(|k| p[k] - self.0[k]);
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (l - self.1, d.map(|c| c / l))
        }
    }

    /// Every node as an embedded point (weight 1 at that node of its first tet).
    fn node_points(mesh: &crate::geom::TetMesh, thickness: f64) -> Vec<EmbeddedPoint> {
        let mut out = vec![None; mesh.num_nodes()];
        for t in &mesh.tets {
            for a in 0..4 {
                let i = t[a] as usize;
                if out[i].is_none() {
                    let mut w = [0.0; 4];
                    w[a] = 1.0;
                    out[i] = Some(EmbeddedPoint {
                        nodes: t.map(|j| j as usize),
                        weights: w,
                        thickness,
                    });
                }
            }
        }
        out.into_iter().map(|p| p.unwrap()).collect()
    }

    #[test]
    fn contact_penalty_gradient_matches_finite_differences() {
        let (mesh, mass) = box_mesh([3, 2, 2], 0.01, 120.0);
        let nt = mesh.num_tets();
        let model = ElasticModel::new(&mesh, &vec![1e4; nt], &vec![3e4; nt]).unwrap();
        let mut s = StaticSolver::new(model, &mass, &[]).unwrap();
        // Interior points too (mixed weights), into a ball and a floor.
        let mut points = node_points(&mesh, 0.001);
        for t in mesh.tets.iter().step_by(5) {
            points.push(EmbeddedPoint {
                nodes: t.map(|j| j as usize),
                weights: [0.1, 0.2, 0.3, 0.4],
                thickness: 0.002,
            });
        }
        s.set_contact(Some(ContactPenalty {
            points,
            colliders: vec![
                Box::new(Floor(0.004)),
                Box::new(Ball([0.015, 0.0, 0.01], 0.008)),
            ],
            stiffness: 500.0,
        }))
        .unwrap();
        let x: Vec<Vec3> = mesh
            .nodes
            .iter()
            .enumerate()
            .map(|(i, p)| {
                [
                    p[0] + 1e-4 * (i % 3) as f64,
                    p[1],
                    p[2] - 1e-4 * (i % 2) as f64,
                ]
            })
            .collect();
        let zero = vec![[0.0; 3]; x.len()];
        let (_, g) = s.potential(&x, &zero, None).unwrap();
        let c = s.contact().unwrap();
        let (active, depth) = c.penetration(&x);
        assert!(active > 10 && depth > 1e-3, "{active} {depth}");
        let h = 1e-7;
        let mut worst = 0.0f64;
        for i in 0..x.len() {
            for k in 0..3 {
                let mut xp = x.clone();
                xp[i][k] += h;
                let mut xm = x.clone();
                xm[i][k] -= h;
                let fd = (s.potential(&xp, &zero, None).unwrap().0
                    - s.potential(&xm, &zero, None).unwrap().0)
                    / (2.0 * h);
                worst = worst.max((fd - g[i][k]).abs() / (1.0 + g[i][k].abs()));
            }
        }
        assert!(worst < 1e-5, "gradient vs central differences: {worst:e}");
    }

    /// A free slab released above a floor falls under gravity with inertia;
    /// with the penalty it comes to rest on the floor (within 1% of its
    /// thickness offset), without it it falls through.
    #[test]
    fn a_falling_slab_comes_to_rest_on_a_floor() {
        let (mesh, mass) = box_mesh([4, 2, 3], 0.01, 120.0);
        let nt = mesh.num_tets();
        let model = ElasticModel::new(&mesh, &vec![1e3; nt], &vec![3e3; nt]).unwrap();
        let f_ext: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
        let floor = -0.005;
        let run = |contact: bool| {
            let mut s = StaticSolver::new(model.clone(), &mass, &[]).unwrap();
            if contact {
                s.set_contact(Some(ContactPenalty {
                    points: node_points(&mesh, 0.001),
                    colliders: vec![Box::new(Floor(floor))],
                    stiffness: 100.0 * 4e3 * 0.01,
                }))
                .unwrap();
            }
            let (mut pp, mut p) = (mesh.nodes.clone(), mesh.nodes.clone());
            for _ in 0..30 {
                let inertia = Inertia {
                    x_prev: &p,
                    x_prevprev: &pp,
                    dt: 1.0 / 60.0,
                };
                let (x, st) = s
                    .solve(&p, &f_ext, Some(inertia), &StaticParams::default())
                    .unwrap();
                assert!(*st.residuals.last().unwrap() <= 1e-6);
                pp = std::mem::replace(&mut p, x);
            }
            p.iter().map(|q| q[1]).fold(f64::INFINITY, f64::min)
        };
        let with = run(true);
        let without = run(false);
        assert!(
            without < floor - 0.05,
            "no collider: lowest node at {without}"
        );
        assert!(
            (with - (floor + 0.001)).abs() < 2e-4,
            "with the floor: lowest node at {with}, floor + thickness {}",
            floor + 0.001
        );
    }

    #[test]
    fn bad_contacts_are_refused() {
        let (model, mass, pinned, _, _) = slab();
        let mut s = StaticSolver::new(model, &mass, &pinned).unwrap();
        let p = EmbeddedPoint {
            nodes: [0, 1, 2, usize::MAX],
            weights: [0.25; 4],
            thickness: 0.0,
        };
        for (points, k) in [(vec![p], 1.0), (vec![], 0.0), (vec![], f64::NAN)] {
            assert!(s
                .set_contact(Some(ContactPenalty {
                    points,
                    colliders: vec![],
                    stiffness: k,
                }))
                .is_err());
        }
    }

    #[test]
    fn bad_inputs_are_refused() {
        let (model, mass, pinned, x, f_ext) = slab();
        assert!(StaticSolver::new(model.clone(), &mass[1..], &pinned).is_err());
        assert!(StaticSolver::new(model.clone(), &mass, &[usize::MAX]).is_err());
        let mut s = StaticSolver::new(model, &mass, &pinned).unwrap();
        let mut bad = x.clone();
        bad[3][1] = f64::NAN;
        assert!(s
            .solve(&bad, &f_ext, None, &StaticParams::default())
            .is_err());
        assert!(s
            .solve(&x[1..], &f_ext, None, &StaticParams::default())
            .is_err());
    }
}

#[cfg(test)]
mod bench {
    use super::*;
    use crate::embed::box_mesh;

    /// Timing only (`cargo test --lib sim::statics::bench -- --ignored --nocapture`):
    /// a slab of `n` voxels (6 tets each), one end pinned, the other pulled 30 %.
    #[test]
    #[ignore]
    fn newton_slab_timings() {
        for n in [[24usize, 12, 6], [48, 24, 12]] {
            let h = 0.005;
            let (mesh, mass) = box_mesh(n, h, 120.0);
            let nt = mesh.num_tets();
            let model = ElasticModel::new(&mesh, &vec![1e4; nt], &vec![1e4; nt]).unwrap();
            let lx = n[0] as f64 * h;
            let mut pinned = Vec::new();
            let mut x = mesh.nodes.clone();
            for (i, p) in mesh.nodes.iter().enumerate() {
                if p[0] < 1e-9 {
                    pinned.push(i);
                } else if p[0] > lx - 1e-9 {
                    pinned.push(i);
                    x[i][0] = 1.3 * lx;
                }
            }
            let f_ext: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
            let mut s = StaticSolver::new(model, &mass, &pinned).unwrap();
            let (_, st) = s.solve(&x, &f_ext, None, &StaticParams::default()).unwrap();
            println!(
                "tets {nt}: iterations {}, residual {:e}, total {:.0} ms, factor {:.0} ms, symbolic {:.0} ms",
                st.iterations,
                st.residuals.last().unwrap(),
                st.total_ms,
                st.factor_ms,
                s.symbolic_ms
            );
        }
    }
}
