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
//! `Π = E - f_ext·x + Σ m_i |x_i - x̃_i|²/(2Δt²)`.
//!
//! Convergence: relative force residual `max_i |r_i| / scale <= tolerance`
//! (default 1e-6) over free nodes, `scale` = the largest free-node external
//! force or elastic force at the solution (whichever is larger); when no free
//! node carries an external force, the pinned nodes' elastic forces (the
//! reactions) count too.
//! Deterministic: assembly and factorization are sequential in a fixed order;
//! the energy/gradient sums are in tet order.

use std::time::Instant;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use rayon::prelude::*;

use super::cholesky::SparseCholesky;
use super::energy::ElasticModel;
use super::hessian::element_hessian;
use super::SimError;
use crate::geom::Vec3;
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
    symbolic: Option<SymbolicCholesky<usize>>,
    /// Symbolic analysis time (ms), paid once.
    pub symbolic_ms: f64,
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
        Ok(StaticSolver {
            model,
            mass: mass.to_vec(),
            free_index,
            ndof,
            symbolic: None,
            symbolic_ms: 0.0,
        })
    }

    /// The elastic model.
    pub fn model(&self) -> &ElasticModel {
        &self.model
    }

    /// Lower triangle of the projected Newton matrix on free DOFs plus
    /// `mass_scale · M`. The triplet positions depend only on the mesh and pin
    /// set, so the sparsity pattern is the same at every call.
    fn assemble(&self, x: &[Vec3], mass_scale: f64) -> Result<SparseColMat<usize, f64>, SimError> {
        let f = self.model.deformation_gradients(x)?;
        let rest = self.model.rest();
        let (gs, gv) = (self.model.gamma_s(), self.model.gamma_v());
        let blocks: Vec<_> = (0..rest.len())
            .into_par_iter()
            .map(|e| element_hessian(&f[e], &rest[e], gs[e], gv[e], true))
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
        SparseColMat::try_new_from_triplets(self.ndof, self.ndof, &trip)
            .map_err(|e| SimError::Inconsistent(format!("assembling the Newton matrix: {e:?}")))
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
        let force_scale = |g: &[Vec3]| {
            // Largest free-node external and elastic force. Without any
            // free-node external force (a pose held by its pins only) the
            // free-node elastic force is the residual itself: the pins'
            // reactions then give the problem its force scale.
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let loaded =
                (0..f_ext.len()).any(|i| self.free_index[i].is_some() && norm(f_ext[i]) > 0.0);
            let mut s = 0.0f64;
            for (i, fi) in self.free_index.iter().enumerate() {
                if fi.is_some() || !loaded {
                    let el = norm(std::array::from_fn(|c| g[i][c] + f_ext[i][c]));
                    s = s.max(norm(f_ext[i])).max(el);
                }
            }
            s
        };
        let max_res = |g: &[Vec3]| {
            let mut m = 0.0f64;
            for (i, fi) in self.free_index.iter().enumerate() {
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
            if self.symbolic.is_none() {
                let ts = Instant::now();
                self.symbolic = Some(
                    SparseCholesky::symbolic(a.as_ref())
                        .map_err(|e| SimError::Inconsistent(format!("symbolic Cholesky: {e}")))?,
                );
                self.symbolic_ms = ts.elapsed().as_secs_f64() * 1e3;
            }
            let sym = self
                .symbolic
                .take()
                .ok_or_else(|| SimError::Inconsistent("symbolic factorization missing".into()))?;
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
            self.symbolic = Some(chol.into_symbolic());
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
    use crate::sim::pd::box_mesh;

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
    use crate::sim::pd::box_mesh;

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
