//! Newton's method with a backtracking line search on the total potential
//! `E(q) = sum of terms`, with clamped (fixed) coordinates eliminated.
//!
//! Each iteration assembles the terms' PSD Hessians on the free coordinates,
//! factors them with faer's sparse Cholesky (the symbolic analysis is reused
//! while the sparsity pattern stays the same, so a contact set that does not
//! change costs one numeric factorization per iteration, and a changed
//! pattern reuses the last AMD ordering while its fill stays close), solves
//! `H dq = -g`, clips the step by every term's `max_step` and by a
//! per-vertex displacement cap (so no contact can be jumped over), and
//! halves it until the energy decreases enough (Armijo). A matrix that is
//! not numerically SPD gets a diagonal shift that grows until it factors.
//!
//! Converged when the largest free-coordinate force `|dE/dq_i|` (N for
//! positions, N m for twists) is at most `force_tolerance`, or at most
//! `relative_tolerance` times the largest force at the start.

use std::time::Instant;

use faer::perm::Perm;
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::Mat;

use super::assemble::LowerCsc;
use super::term::{EnergyTerm, Triplets};
use crate::linalg::cholesky::SparseCholesky;
use crate::linalg::LinalgError;

/// Controls of [`solve_static`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct YarnStaticParams {
    /// Absolute force tolerance (N): converged when every free coordinate's
    /// `|dE/dq|` is at most this. Default 1e-6 N (a millionth of the ~1 N
    /// forces of a fabric stretch test; a 1 mm yarn's weight per vertex is
    /// ~1e-6 N at HYLC density).
    pub force_tolerance: f64,
    /// Relative tolerance against the largest free force at the start.
    /// Default 1e-9.
    pub relative_tolerance: f64,
    /// Most Newton iterations. Default 200.
    pub max_iterations: usize,
    /// Largest displacement of one vertex in one iteration (m). Default
    /// infinity. Terms may lower it per vertex
    /// ([`EnergyTerm::limit_vertex_moves`]: contact keeps every yarn from
    /// passing through another).
    pub max_displacement: f64,
    /// How many leading 3-vectors of `q` are positions (m) that the
    /// displacement caps apply to; the rest (twists, rad) are not capped.
    /// Default `None`: all of `q` is positions.
    pub position_points: Option<usize>,
    /// Armijo constant. Default 1e-4.
    pub armijo: f64,
    /// Most step halvings per iteration. Default 40.
    pub max_halvings: usize,
    /// When a step would move some vertex farther than
    /// `max_displacement`, shorten only those vertices' moves (when that is
    /// still a descent direction) instead of the whole step. Default false.
    pub clip_per_vertex: bool,
}

impl Default for YarnStaticParams {
    fn default() -> Self {
        YarnStaticParams {
            force_tolerance: 1e-6,
            relative_tolerance: 1e-9,
            max_iterations: 200,
            max_displacement: f64::INFINITY,
            position_points: None,
            armijo: 1e-4,
            max_halvings: 40,
            clip_per_vertex: false,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct StaticStats {
    pub iterations: usize,
    pub converged: bool,
    /// Largest free force at the start and at the end (N).
    pub initial_residual: f64,
    pub residual: f64,
    /// Largest free force after each iteration (N).
    pub residual_history: Vec<f64>,
    /// Total energy at the end (J) and per term, by name.
    pub energy: f64,
    pub energies: Vec<(String, f64)>,
    pub halvings: usize,
    /// Iterations whose step the displacement cap (or a term's
    /// `max_step`) shortened.
    pub capped: usize,
    pub symbolic_factorizations: usize,
    /// Fill-reducing (AMD) orderings computed; the other symbolic
    /// factorizations reused the last one.
    pub orderings: usize,
    pub numeric_factorizations: usize,
    /// Iterations that needed a diagonal shift to factor.
    pub regularized: usize,
    pub assembly_ms: f64,
    pub factor_ms: f64,
    pub solve_ms: f64,
    pub line_search_ms: f64,
}

/// Why a solve failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StaticError {
    #[error("static solve: {what} is not finite at iteration {iteration} (coordinate {dof})")]
    NonFinite {
        iteration: usize,
        dof: usize,
        what: &'static str,
    },
    #[error("static solve: coordinate vector has {got} entries, the fixed mask {expected}")]
    Size { got: usize, expected: usize },
    #[error("static solve: the line search cannot decrease the energy at iteration {iteration} (largest force {residual:.3e} N at coordinate {dof})")]
    LineSearch {
        iteration: usize,
        residual: f64,
        dof: usize,
    },
    #[error("static solve: the Hessian cannot be factored at iteration {iteration}: {source}")]
    Factorization {
        iteration: usize,
        source: LinalgError,
    },
    #[error("static solve: no equilibrium after {iterations} iterations (largest force {residual:.3e} N at coordinate {dof}, tolerance {tolerance:.1e} N)")]
    NotConverged {
        iterations: usize,
        residual: f64,
        dof: usize,
        tolerance: f64,
    },
}

/// Energy and gradient (and Hessian entries) of all terms at `q`.
pub fn evaluate(
    terms: &[&mut dyn EnergyTerm],
    q: &[f64],
    grad: &mut [f64],
    mut hess: Option<&mut Triplets>,
) -> f64 {
    grad.iter_mut().for_each(|g| *g = 0.0);
    let mut e = 0.0;
    for t in terms {
        e += t.eval(q, grad, hess.as_deref_mut());
    }
    e
}

/// Largest `|g_i|` over free coordinates and where.
fn residual(grad: &[f64], fixed: &[bool]) -> (f64, usize) {
    grad.iter()
        .zip(fixed)
        .enumerate()
        .filter(|(_, (_, f))| !**f)
        .fold((0.0, 0), |(m, at), (i, (g, _))| {
            if g.abs() > m || g.is_nan() {
                (g.abs(), i)
            } else {
                (m, at)
            }
        })
}

/// Forces the clamps exert on the yarns at equilibrium: `dE/dq_i` on every
/// fixed coordinate (0 elsewhere). At equilibrium the free forces vanish, so
/// the sum over a clamp's coordinates is the force it applies (N); the yarn
/// pulls on the clamp with the opposite force.
pub fn reaction_forces(terms: &[&mut dyn EnergyTerm], q: &[f64], fixed: &[bool]) -> Vec<f64> {
    let mut g = vec![0.0; q.len()];
    evaluate(terms, q, &mut g, None);
    g.iter()
        .zip(fixed)
        .map(|(g, f)| if *f { *g } else { 0.0 })
        .collect()
}

/// How much more fill (nonzeros of the factor per nonzero of the matrix)
/// than its own AMD ordering gave a reused ordering may cost before AMD runs
/// again. On the 26x26 rib's 30% stretch the analysis with a reused
/// ordering took 21-23 ms against 52-64 ms with AMD, for 2.6% more fill and
/// a numeric factorization 5% slower (78 against 74 ms).
const ORDERING_FILL_SLACK: f64 = 1.1;

/// A symbolic analysis kept for the next solve while the pattern holds, the
/// last AMD ordering for patterns that change (a contact set changes a few
/// entries per iteration, and the ordering of the last one still fits), and
/// the factor's buffer.
#[derive(Default)]
pub struct SymbolicCache {
    key: Option<(Vec<usize>, Vec<usize>)>,
    symbolic: Option<SymbolicCholesky<usize>>,
    /// The ordering and the fill ratio `nnz(L) / nnz(lower A)` it gave on
    /// the pattern it was computed for.
    ordering: Option<(Perm<usize>, f64)>,
    values: Vec<f64>,
}

impl SymbolicCache {
    /// The analysis of `lower`'s pattern: the cached one when the pattern is
    /// the same, else one with the cached ordering while its fill stays
    /// within [`ORDERING_FILL_SLACK`], else a fresh AMD ordering.
    fn analysis(
        &mut self,
        lower: &LowerCsc,
        stats: &mut StaticStats,
    ) -> Result<SymbolicCholesky<usize>, LinalgError> {
        let same = self
            .key
            .as_ref()
            .is_some_and(|(cp, ri)| (cp.as_slice(), ri.as_slice()) == lower.pattern());
        if let (true, Some(s)) = (same, self.symbolic.take()) {
            return Ok(s);
        }
        stats.symbolic_factorizations += 1;
        let (cp, ri) = lower.pattern();
        self.key = Some((cp.to_vec(), ri.to_vec()));
        let nnz = ri.len().max(1) as f64;
        if let Some((perm, ratio)) = &self.ordering {
            if perm.len() == lower.dim() {
                let s = SparseCholesky::symbolic_ordered(lower.as_ref(), perm.as_ref())?;
                if s.len_val() as f64 / nnz <= ratio * ORDERING_FILL_SLACK {
                    return Ok(s);
                }
            }
        }
        stats.orderings += 1;
        let s = SparseCholesky::symbolic(lower.as_ref())?;
        self.ordering = Some((SparseCholesky::ordering(&s), s.len_val() as f64 / nnz));
        Ok(s)
    }
}

impl std::fmt::Debug for SymbolicCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SymbolicCache")
            .field("cached", &self.symbolic.is_some())
            .finish()
    }
}

/// Brings `q` to equilibrium: `dE/dq_i = 0` on every coordinate with
/// `fixed[i] == false`; fixed coordinates keep their values (the caller
/// places clamps and handles). `q` holds the last accepted iterate also on
/// error.
pub fn solve_static(
    terms: &mut [&mut dyn EnergyTerm],
    q: &mut [f64],
    fixed: &[bool],
    params: &YarnStaticParams,
    cache: &mut SymbolicCache,
) -> Result<StaticStats, StaticError> {
    let n = q.len();
    if fixed.len() != n {
        return Err(StaticError::Size {
            got: n,
            expected: fixed.len(),
        });
    }
    let free: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
    let mut index = vec![usize::MAX; n];
    for (k, &i) in free.iter().enumerate() {
        index[i] = k;
    }
    let nf = free.len();
    let mut stats = StaticStats::default();
    let mut grad = vec![0.0; n];
    let mut trial_grad = vec![0.0; n];
    let mut trip = Triplets::new();
    let mut trial = q.to_vec();
    let mut lower = LowerCsc::new();
    for it in 0..=params.max_iterations {
        for t in terms.iter_mut() {
            t.begin_iteration(q);
        }
        let t0 = Instant::now();
        trip.clear();
        let e = evaluate(terms, q, &mut grad, Some(&mut trip));
        stats.assembly_ms += t0.elapsed().as_secs_f64() * 1e3;
        if !e.is_finite() {
            return Err(StaticError::NonFinite {
                iteration: it,
                dof: 0,
                what: "the energy",
            });
        }
        let (res, at) = residual(&grad, fixed);
        if !res.is_finite() {
            return Err(StaticError::NonFinite {
                iteration: it,
                dof: at,
                what: "the gradient",
            });
        }
        if it == 0 {
            stats.initial_residual = res;
        }
        stats.residual = res;
        stats.energy = e;
        if res <= params.force_tolerance
            || res <= params.relative_tolerance * stats.initial_residual
            || nf == 0
        {
            stats.converged = true;
            break;
        }
        if it == params.max_iterations {
            return Err(StaticError::NotConverged {
                iterations: it,
                residual: res,
                dof: at,
                tolerance: params.force_tolerance,
            });
        }
        // Free-free lower triangle (every diagonal entry present, so
        // shifts keep the pattern).
        let t1 = Instant::now();
        let diag_sum = lower.assemble(&trip, &index, nf);
        let mean_diag = (diag_sum / nf as f64).max(f64::MIN_POSITIVE);
        let mut shift = 0.0;
        let factor = loop {
            let symbolic = cache.analysis(&lower, &mut stats).map_err(|source| {
                StaticError::Factorization {
                    iteration: it,
                    source,
                }
            })?;
            stats.numeric_factorizations += 1;
            // A failed numeric factorization consumes the analysis (rare:
            // the next try redoes it).
            let buffer = std::mem::take(&mut cache.values);
            match SparseCholesky::numeric_into(symbolic, lower.as_ref(), buffer) {
                Ok(f) => break f,
                Err(source) => {
                    cache.key = None;
                    let next = if shift == 0.0 {
                        1e-10 * mean_diag
                    } else {
                        shift * 10.0
                    };
                    if next > 1e6 * mean_diag {
                        return Err(StaticError::Factorization {
                            iteration: it,
                            source,
                        });
                    }
                    lower.shift_diagonal(next);
                    shift = next;
                }
            }
        };
        if shift > 0.0 {
            stats.regularized += 1;
        }
        stats.factor_ms += t1.elapsed().as_secs_f64() * 1e3;
        let t2 = Instant::now();
        let mut rhs = Mat::<f64>::from_fn(nf, 1, |k, _| -grad[free[k]]);
        factor.solve_in_place(rhs.as_mut());
        let (symbolic, values) = factor.into_parts();
        cache.symbolic = Some(symbolic);
        cache.values = values;
        let mut dq = vec![0.0; n];
        for (k, &i) in free.iter().enumerate() {
            dq[i] = rhs[(k, 0)];
        }
        stats.solve_ms += t2.elapsed().as_secs_f64() * 1e3;
        // Step bounds: the terms' and the displacement cap.
        let t3 = Instant::now();
        let mut alpha: f64 = 1.0;
        for t in terms.iter() {
            alpha = alpha.min(t.max_step(q, &dq));
        }
        let n_vert = params.position_points.unwrap_or(n / 3).min(n / 3);
        let mut caps = vec![params.max_displacement; n_vert];
        for t in terms.iter() {
            t.limit_vertex_moves(q, &mut caps);
        }
        if clip_moves(&mut dq, &mut alpha, &grad, &caps, params.clip_per_vertex) {
            stats.capped += 1;
        }
        let slope: f64 = grad.iter().zip(&dq).map(|(g, d)| g * d).sum();
        let mut accepted = false;
        for _ in 0..=params.max_halvings {
            for i in 0..n {
                trial[i] = q[i] + alpha * dq[i];
            }
            let et = evaluate(terms, &trial, &mut trial_grad, None);
            let (rt, _) = residual(&trial_grad, fixed);
            let armijo = et <= e + params.armijo * alpha * slope;
            // Near convergence energy differences drown in rounding: accept a
            // step that keeps the energy (to rounding) and lowers the force.
            let flat = et <= e + 1e-12 * e.abs().max(f64::MIN_POSITIVE) && rt < res;
            if et.is_finite() && (armijo || flat) {
                accepted = true;
                break;
            }
            alpha *= 0.5;
            stats.halvings += 1;
        }
        stats.line_search_ms += t3.elapsed().as_secs_f64() * 1e3;
        if !accepted {
            return Err(StaticError::LineSearch {
                iteration: it,
                residual: res,
                dof: at,
            });
        }
        q.copy_from_slice(&trial);
        for t in terms.iter_mut() {
            t.accept(q);
        }
        stats.iterations = it + 1;
        let (r_new, _) = residual(&trial_grad, fixed);
        stats.residual_history.push(r_new);
    }
    stats.energies = terms
        .iter()
        .map(|t| {
            let mut g = vec![0.0; n];
            (t.name().to_string(), t.eval(q, &mut g, None))
        })
        .collect();
    Ok(stats)
}

/// Applies the per-vertex displacement caps to the step `alpha dq`: with
/// `per_vertex`, only the vertices that would move too far are shortened
/// (kept when that is still a descent direction); otherwise, or when it is
/// not, `alpha` shrinks until every vertex is within its cap. Returns
/// whether the step was shortened.
fn clip_moves(
    dq: &mut [f64],
    alpha: &mut f64,
    grad: &[f64],
    caps: &[f64],
    per_vertex: bool,
) -> bool {
    let moves: Vec<f64> = (0..caps.len())
        .map(|v| (dq[3 * v].powi(2) + dq[3 * v + 1].powi(2) + dq[3 * v + 2].powi(2)).sqrt())
        .collect();
    let over = |v: usize| moves[v] * *alpha > caps[v];
    if !(0..caps.len()).any(over) {
        return false;
    }
    if per_vertex {
        let mut clipped = dq.to_vec();
        for v in (0..caps.len()).filter(|&v| over(v)) {
            let f = caps[v] / (moves[v] * *alpha);
            clipped[3 * v..3 * v + 3].iter_mut().for_each(|d| *d *= f);
        }
        let slope: f64 = grad.iter().zip(&clipped).map(|(g, d)| g * d).sum();
        if slope < 0.0 {
            dq.copy_from_slice(&clipped);
            return true;
        }
    }
    let limit = (0..caps.len())
        .filter(|&v| moves[v] > 0.0)
        .map(|v| caps[v] / moves[v])
        .fold(f64::INFINITY, f64::min);
    *alpha = alpha.min(limit);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An SPD path-graph Laplacian plus identity over `n` coordinates, the
    /// path visiting them in the order `path`, with extra couplings `extra`.
    fn path_matrix(path: &[usize], extra: &[(usize, usize)]) -> LowerCsc {
        let n = path.len();
        let mut trip = Triplets::new();
        for i in 0..n {
            trip.push(i, i, 1.0);
        }
        let mut spring = |a: usize, b: usize| {
            trip.push_block(&[a, b], &[1.0, -1.0, -1.0, 1.0]);
        };
        for w in path.windows(2) {
            spring(w[0], w[1]);
        }
        for &(a, b) in extra {
            spring(a, b);
        }
        let mut m = LowerCsc::new();
        m.assemble(&trip, &(0..n).collect::<Vec<_>>(), n);
        m
    }

    fn solve(s: SymbolicCholesky<usize>, m: &LowerCsc) -> Vec<f64> {
        let f = SparseCholesky::numeric(s, m.as_ref()).unwrap();
        let mut rhs = Mat::<f64>::from_fn(m.dim(), 1, |i, _| (i as f64 * 0.37).sin());
        f.solve_in_place(rhs.as_mut());
        (0..m.dim()).map(|i| rhs[(i, 0)]).collect()
    }

    #[test]
    fn a_changed_pattern_reuses_the_ordering_while_its_fill_stays_close() {
        let n = 400;
        let chain: Vec<usize> = (0..n).collect();
        let mut cache = SymbolicCache::default();
        let mut stats = StaticStats::default();
        let a = path_matrix(&chain, &[]);
        let s = cache.analysis(&a, &mut stats).unwrap();
        assert_eq!((stats.symbolic_factorizations, stats.orderings), (1, 1));
        cache.symbolic = Some(s);
        // Same pattern: the analysis itself is kept.
        let _ = cache.analysis(&a, &mut stats).unwrap();
        assert_eq!((stats.symbolic_factorizations, stats.orderings), (1, 1));
        // A few new couplings (a contact set that changed): new analysis,
        // old ordering, and the same solution as a fresh AMD analysis.
        let b = path_matrix(&chain, &[(10, 12), (200, 203)]);
        let reused = cache.analysis(&b, &mut stats).unwrap();
        assert_eq!((stats.symbolic_factorizations, stats.orderings), (2, 1));
        let fresh = SparseCholesky::symbolic(b.as_ref()).unwrap();
        let (x, y) = (solve(reused, &b), solve(fresh, &b));
        let err = x
            .iter()
            .zip(&y)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        let size = y.iter().fold(0.0f64, |m, p| m.max(p.abs()));
        assert!(err <= 1e-12 * size, "reused ordering: {err:e} of {size:e}");
        // The same path through scrambled labels: the old ordering would
        // fill in, so AMD runs again.
        let scrambled: Vec<usize> = (0..n).map(|i| (i * 163) % n).collect();
        let c = path_matrix(&scrambled, &[]);
        let s = cache.analysis(&c, &mut stats).unwrap();
        assert_eq!((stats.symbolic_factorizations, stats.orderings), (3, 2));
        assert!(
            s.len_val() as f64 <= 1.1 * c.pattern().1.len() as f64,
            "a path needs no fill: {} for {}",
            s.len_val(),
            c.pattern().1.len()
        );
    }
}
