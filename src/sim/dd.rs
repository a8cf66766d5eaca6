//! The domain-decomposed (component mode synthesis) global solve of VH §7.2
//! (Eq. 29-34): a reduced solve in a subspace built per domain, then
//! Chebyshev-Jacobi iterations in full space ([`super::jacobi`], or another
//! `JacobiSolve` backend) from the reduced solution.
//!
//! # Subspace (VH Eq. 33-34)
//! The free nodes split into the interior nodes `I_d` of every domain `d`
//! (all their tets lie in `d`) and the boundary nodes `B` (touched by tets of
//! two or more domains, [`super::partition`]), kept once (not duplicated per
//! domain: VH Eq. 34). The basis `U` has, per domain, `m` modes `Φ_d`
//! (supported on `I_d`), and one column per boundary node `b`:
//! `e_b + Σ_d Ψ_d e_b` with the boundary modes `Ψ_d = -Kii_d⁻¹ Kib_d`
//! (VH Eq. 31). All three coordinates share the same scalar matrix `K`.
//!
//! Since `Kii_d Ψ_d + Kib_d = 0`, the boundary columns are `K`-orthogonal to
//! every `Φ_d`, and interiors of different domains do not couple, so the
//! reduced matrix `Kr = Uᵀ K U` is block diagonal:
//! `Kr = diag(Λ_1, ..., Λ_D, S)` with `Λ_d = Φ_dᵀ Kii_d Φ_d` (diagonal:
//! Rayleigh-Ritz vectors) and the Schur complement
//! `S = Kbb - Σ_d Kbi_d Kii_d⁻¹ Kib_d` (sparse between domains, dense within
//! a domain's boundary). `S` is assembled and factored once per (materials,
//! Δt); `Ψ_d` is never stored: `Ψ_dᵀ r = -Kbi_d Kii_d⁻¹ r_I` and
//! `Ψ_d x_B = -Kii_d⁻¹ Kib_d x_B` are one solve with the domain's Cholesky
//! factor each.
//!
//! # Modes (VH Eq. 32)
//! `Φ_d`: the `m` lowest eigenvectors of `Kii_d` (VH: ~20), by subspace
//! iteration with the factor of `Kii_d` ([`EIGEN_ITERATIONS`] rounds of
//! `Y = Kii⁻¹ X`, orthonormalization and Rayleigh-Ritz on `m + 8` vectors),
//! or a dense eigen-decomposition for interiors of at most
//! [`DENSE_EIGEN_LIMIT`] nodes. The modes only have to span the low
//! frequencies well (the Jacobi iterations correct the rest), so a few rounds
//! suffice; Rayleigh-Ritz keeps `Λ_d` exactly diagonal in the computed basis,
//! which is all the Galerkin solve needs.
//!
//! # Solve
//! `x0 = U Kr⁻¹ Uᵀ r`, i.e. per domain `p_d = Λ_d⁻¹ Φ_dᵀ r_I`, then
//! `S x_B = r_B - Σ_d Kbi_d Kii_d⁻¹ r_I`, then
//! `x_I = Φ_d p_d - Kii_d⁻¹ Kib_d x_B`.
//!
//! `x_B` is exact (the Schur complement is), so the whole error of `x0` is
//! `(Kii_d⁻¹ - Φ_d Λ_d⁻¹ Φ_dᵀ) r_I` inside the domains: the interior modes
//! above the `m` kept. With 20 modes of domains of thousands of nodes that
//! error is still smooth, and Chebyshev-Jacobi, whose rate is set by the
//! condition of `D⁻¹K` (~1000 on the knit meshes), needs hundreds of
//! iterations to remove it. [`Interiors::Exact`] keeps every interior mode:
//! `x_I = Kii_d⁻¹ (r_I - Kib_d x_B)`, one solve with the factor the boundary
//! modes need anyway, so the same cost as the modal form and no eigenvectors.
//! The reduced solve is then exact for `K` and the Jacobi iterations are
//! left with the contact weights only. Domains run in parallel (rayon) and
//! their contributions are added in domain order (deterministic).

// `!(a > b)` is deliberate: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::time::Instant;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use rayon::prelude::*;

use super::jacobi::JacobiParams;
use super::partition::{Partition, DEFAULT_NODES_PER_DOMAIN};
use super::SimError;
use crate::linalg::cholesky::SparseCholesky;
use crate::linalg::csr::CsrMatrix;
use crate::linalg::LinalgError;

/// Rounds of subspace iteration for the domain modes.
pub const EIGEN_ITERATIONS: usize = 6;
/// Interiors up to this many nodes get a dense eigen-decomposition.
pub const DENSE_EIGEN_LIMIT: usize = 64;
/// Extra vectors of the subspace iteration beyond the wanted modes (speeds
/// up convergence of the highest wanted mode).
const EXTRA_VECTORS: usize = 8;

/// How the reduced solve represents the interiors of the domains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interiors {
    /// CMS as in VH Eq. 32: the [`DdParams::modes`] lowest eigenmodes of
    /// every `Kii_d`. The reduced solution is exact on the boundary and
    /// misses the interior components above the modes (module doc), which
    /// the Chebyshev-Jacobi iterations then remove.
    Modes,
    /// Every interior mode: the limit of Eq. 32 as the mode count reaches
    /// the interior size, where `Φ_d Λ_d⁻¹ Φ_dᵀ = Kii_d⁻¹`. Applied with the
    /// domain's Cholesky factor that the boundary modes `Ψ_d` need anyway,
    /// so it costs one interior solve per domain, the same as the modal
    /// form, and no eigenvectors are computed. The reduced solve is then
    /// exact for `K` (a Schur-complement substructuring solve) and the
    /// Jacobi iterations only run when contact weights change the matrix.
    Exact,
}

/// Parameters of the domain-decomposed global solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DdParams {
    /// Target nodes per domain of the automatic partition (used when no
    /// per-tet domain ids are given). Default
    /// [`DEFAULT_NODES_PER_DOMAIN`].
    pub nodes_per_domain: usize,
    /// Eigenmodes per domain (VH §7.2: "e.g., 20") with
    /// [`Interiors::Modes`]. Default 20.
    pub modes: usize,
    /// Modal (VH Eq. 32) or exact interiors. Default [`Interiors::Exact`]:
    /// on the CPU it costs the same per solve as the modal form and leaves
    /// nothing for the Jacobi iterations (measured in `GlobalSolver`'s doc).
    pub interiors: Interiors,
    /// Relative residual at which the full-space Chebyshev-Jacobi iterations
    /// stop, measured against the residual of the previous PD iterate (the
    /// global step solves for the correction, so the tolerance does not
    /// depend on where the mesh is in space). Default 1e-4 (dimensionless).
    /// With [`Interiors::Modes`] and 20 modes per domain the knit swatches of
    /// `knitvox bench sim` need about 400 iterations per global solve to get
    /// there (docs/performance.md); with [`Interiors::Exact`] the reduced
    /// solution already meets it unless contact weights are active.
    pub tolerance: f64,
    /// Most Chebyshev-Jacobi iterations per global solve. Default 1000.
    pub max_iterations: u32,
    /// The Jacobi iteration's own parameters.
    pub jacobi: JacobiParams,
}

impl Default for DdParams {
    fn default() -> Self {
        DdParams {
            nodes_per_domain: DEFAULT_NODES_PER_DOMAIN,
            modes: 20,
            interiors: Interiors::Exact,
            tolerance: 1e-4,
            max_iterations: 1000,
            jacobi: JacobiParams::default(),
        }
    }
}

impl DdParams {
    pub(crate) fn validate(&self) -> Result<(), SimError> {
        if self.nodes_per_domain == 0
            || !(self.tolerance.is_finite() && self.tolerance > 0.0)
            || self.max_iterations == 0
        {
            return Err(SimError::Inconsistent(format!(
                "bad domain-decomposition parameters {self:?} (nodes_per_domain and \
                 max_iterations must be >= 1, tolerance finite and > 0)"
            )));
        }
        Ok(())
    }
}

/// Size of the reduced system.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DdStats {
    /// Number of domains.
    pub domains: usize,
    /// Free boundary nodes (rows of `S`).
    pub boundary_nodes: usize,
    /// Total eigenmodes over the domains.
    pub modes: usize,
    /// Size of the reduced system `Kr` per coordinate (modes + boundary nodes).
    pub reduced_size: usize,
    /// Wall time of the precomputation (ms).
    pub setup_ms: f64,
}

/// A built domain and its (negated) Schur-complement contribution.
type BuiltDomain = (Domain, Vec<Triplet<usize, usize, f64>>);

/// One domain's precomputed data.
#[derive(Debug)]
struct Domain {
    /// Interior free indices.
    interior: Vec<usize>,
    /// Boundary positions (indices into `DdSolver::boundary`) this domain
    /// touches, sorted.
    bnd: Vec<usize>,
    /// Factor of `Kii` (`None` when the interior is empty).
    factor: Option<SparseCholesky>,
    /// `Kib`: (local interior row, local boundary column, value).
    kib: Vec<(usize, usize, f64)>,
    /// Modes, `ni x m` column-major (`modes[j * ni + i]`).
    modes: Vec<f64>,
    /// `Λ_d` (one per mode).
    lambda: Vec<f64>,
}

/// The CMS reduced solver of one free block `K`.
#[derive(Debug)]
pub struct DdSolver {
    n: usize,
    /// Boundary free indices.
    boundary: Vec<usize>,
    domains: Vec<Domain>,
    /// Factor of the Schur complement `S` (`None` without boundary nodes).
    schur: Option<SparseCholesky>,
    /// [`Interiors::Exact`].
    exact: bool,
    stats: DdStats,
}

fn chol_err(what: &str) -> impl Fn(LinalgError) -> SimError + '_ {
    move |e| SimError::Inconsistent(format!("{what} is not positive definite: {e}"))
}

/// Deterministic pseudo-random value in [-1, 1).
fn hash01(i: usize, j: usize) -> f64 {
    let mut h = (i as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F));
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

impl DdSolver {
    /// Precomputes the reduced solver of `k` (the free block of the PD
    /// matrix, both triangles) with the tet partition `partition` of the mesh
    /// whose tets are `tets` (mesh node indices); `free_index` maps mesh
    /// nodes to rows of `k` (`None`: pinned).
    pub fn new(
        k: &CsrMatrix,
        tets: &[[usize; 4]],
        partition: &Partition,
        free_index: &[Option<usize>],
        params: &DdParams,
    ) -> Result<DdSolver, SimError> {
        let t0 = Instant::now();
        params.validate()?;
        let n = k.n;
        if partition.tet_domain.len() != tets.len() || partition.boundary.len() != free_index.len()
        {
            return Err(SimError::Inconsistent(
                "partition does not match the mesh".into(),
            ));
        }
        let nd = partition.num_domains.max(1);
        // Domain of every free row: usize::MAX for boundary rows; rows of
        // nodes without tets go to domain 0 (their row is diagonal).
        let mut row_domain = vec![0usize; n];
        for (node, f) in free_index.iter().enumerate() {
            if let Some(fi) = *f {
                if fi >= n {
                    return Err(SimError::Inconsistent(format!(
                        "free index {fi} outside a {n} x {n} matrix"
                    )));
                }
                if partition.boundary[node] {
                    row_domain[fi] = usize::MAX;
                }
            }
        }
        for (t, &d) in tets.iter().zip(&partition.tet_domain) {
            for &a in t {
                if let Some(fi) = free_index.get(a).copied().flatten() {
                    if row_domain[fi] != usize::MAX {
                        row_domain[fi] = d as usize;
                    }
                }
            }
        }
        let boundary: Vec<usize> = (0..n).filter(|&r| row_domain[r] == usize::MAX).collect();
        let mut local = vec![0usize; n];
        for (p, &r) in boundary.iter().enumerate() {
            local[r] = p;
        }
        let mut interiors: Vec<Vec<usize>> = vec![Vec::new(); nd];
        for r in 0..n {
            if row_domain[r] != usize::MAX {
                local[r] = interiors[row_domain[r]].len();
                interiors[row_domain[r]].push(r);
            }
        }
        // Coupling between interiors of different domains would break the
        // block structure: it cannot happen for a tet partition.
        for r in 0..n {
            let dr = row_domain[r];
            if dr == usize::MAX {
                continue;
            }
            for e in k.row_ptr[r]..k.row_ptr[r + 1] {
                let dc = row_domain[k.col[e]];
                if dc != usize::MAX && dc != dr {
                    return Err(SimError::Inconsistent(format!(
                        "rows {r} and {} of K couple interiors of domains {dr} and {dc}",
                        k.col[e]
                    )));
                }
            }
        }

        let exact = params.interiors == Interiors::Exact;
        let m_wanted = if exact { 0 } else { params.modes };
        let built: Vec<Result<BuiltDomain, SimError>> = interiors
            .into_par_iter()
            .map(|interior| build_domain(k, interior, &row_domain, &local, m_wanted))
            .collect();
        let mut domains = Vec::with_capacity(nd);
        let nb = boundary.len();
        let mut s_lower: Vec<Triplet<usize, usize, f64>> = Vec::new();
        // Kbb (lower triangle).
        for (p, &r) in boundary.iter().enumerate() {
            for e in k.row_ptr[r]..k.row_ptr[r + 1] {
                let c = k.col[e];
                if row_domain[c] == usize::MAX && local[c] <= p {
                    s_lower.push(Triplet::new(p, local[c], k.val[e]));
                }
            }
        }
        for b in built {
            let (d, t) = b?;
            s_lower.extend(t);
            domains.push(d);
        }
        let schur = if nb > 0 {
            let a = SparseColMat::<usize, f64>::try_new_from_triplets(nb, nb, &s_lower)
                .map_err(|e| SimError::Inconsistent(format!("Schur complement: {e:?}")))?;
            Some(SparseCholesky::new(a.as_ref()).map_err(chol_err("the Schur complement"))?)
        } else {
            None
        };
        let modes: usize = domains.iter().map(|d| d.lambda.len()).sum();
        let stats = DdStats {
            domains: domains.len(),
            boundary_nodes: nb,
            modes,
            reduced_size: modes + nb,
            setup_ms: t0.elapsed().as_secs_f64() * 1e3,
        };
        Ok(DdSolver {
            n,
            boundary,
            domains,
            schur,
            exact,
            stats,
        })
    }

    /// Size of the reduced system and setup time.
    pub fn stats(&self) -> DdStats {
        self.stats
    }

    /// The reduced solution `x = U Kr⁻¹ Uᵀ r` (module doc) for `r`
    /// (n x 3 row-major); `x` has the same layout.
    pub fn reduced_solve(&self, r: &[f64], x: &mut [f64]) -> Result<(), SimError> {
        let n = self.n;
        if r.len() != 3 * n || x.len() != 3 * n {
            return Err(SimError::Inconsistent(format!(
                "reduced solve of {n} rows got {} and {} values",
                r.len(),
                x.len()
            )));
        }
        // Phase 1: per domain, p_d and Kbi Kii⁻¹ r_I.
        let phase1: Vec<(Vec<f64>, Vec<f64>)> = self
            .domains
            .par_iter()
            .map(|d| {
                let ni = d.interior.len();
                let m = d.lambda.len();
                let mut p = vec![0.0; m * 3];
                for j in 0..m {
                    let phi = &d.modes[j * ni..(j + 1) * ni];
                    for k in 0..3 {
                        let s: f64 = phi
                            .iter()
                            .zip(&d.interior)
                            .map(|(v, &row)| v * r[3 * row + k])
                            .sum();
                        p[3 * j + k] = s / d.lambda[j];
                    }
                }
                let mut g = vec![0.0; d.bnd.len() * 3];
                if let Some(f) = &d.factor {
                    let mut z = Mat::<f64>::from_fn(ni, 3, |i, k| r[3 * d.interior[i] + k]);
                    f.solve_in_place(z.as_mut());
                    for &(li, lb, v) in &d.kib {
                        for k in 0..3 {
                            g[3 * lb + k] += v * z[(li, k)];
                        }
                    }
                }
                (p, g)
            })
            .collect();
        let nb = self.boundary.len();
        let mut xb = Mat::<f64>::from_fn(nb, 3, |p, k| r[3 * self.boundary[p] + k]);
        for (d, (_, g)) in self.domains.iter().zip(&phase1) {
            for (lb, &p) in d.bnd.iter().enumerate() {
                for k in 0..3 {
                    xb[(p, k)] -= g[3 * lb + k];
                }
            }
        }
        if let Some(s) = &self.schur {
            s.solve_in_place(xb.as_mut());
        }
        // Phase 2: interiors, x_I = Φ p - Kii⁻¹ Kib x_B, or with exact
        // interiors Kii⁻¹ (r_I - Kib x_B).
        let xb = &xb;
        let exact = self.exact;
        let phase2: Vec<Vec<f64>> = self
            .domains
            .par_iter()
            .zip(&phase1)
            .map(|(d, (p, _))| {
                let ni = d.interior.len();
                let mut t = if exact {
                    Mat::<f64>::from_fn(ni, 3, |i, k| -r[3 * d.interior[i] + k])
                } else {
                    Mat::<f64>::zeros(ni, 3)
                };
                for &(li, lb, v) in &d.kib {
                    for k in 0..3 {
                        t[(li, k)] += v * xb[(d.bnd[lb], k)];
                    }
                }
                if let Some(f) = &d.factor {
                    f.solve_in_place(t.as_mut());
                }
                let mut out = vec![0.0; ni * 3];
                for i in 0..ni {
                    for k in 0..3 {
                        let mut s = -t[(i, k)];
                        for j in 0..d.lambda.len() {
                            s += d.modes[j * ni + i] * p[3 * j + k];
                        }
                        out[3 * i + k] = s;
                    }
                }
                out
            })
            .collect();
        for (d, xi) in self.domains.iter().zip(&phase2) {
            for (i, &row) in d.interior.iter().enumerate() {
                x[3 * row..3 * row + 3].copy_from_slice(&xi[3 * i..3 * i + 3]);
            }
        }
        for (p, &row) in self.boundary.iter().enumerate() {
            for k in 0..3 {
                x[3 * row + k] = xb[(p, k)];
            }
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(SimError::Diverged {
                step: 0,
                node: i / 3,
                reason: "reduced (domain-decomposed) solve not finite".into(),
            });
        }
        Ok(())
    }
}

/// Builds one domain: factor of `Kii`, `Kib`, modes, and its (negated)
/// contribution `-Kbi Kii⁻¹ Kib` to the Schur complement (lower triangle, in
/// boundary positions).
fn build_domain(
    k: &CsrMatrix,
    interior: Vec<usize>,
    row_domain: &[usize],
    local: &[usize],
    m_wanted: usize,
) -> Result<BuiltDomain, SimError> {
    let ni = interior.len();
    let mut lower = Vec::new();
    let mut kii = Vec::new();
    let mut kib_global = Vec::new();
    for (li, &r) in interior.iter().enumerate() {
        for e in k.row_ptr[r]..k.row_ptr[r + 1] {
            let c = k.col[e];
            let v = k.val[e];
            if row_domain[c] == usize::MAX {
                kib_global.push((li, local[c], v));
            } else {
                let lc = local[c];
                kii.push((li, lc, v));
                if lc <= li {
                    lower.push(Triplet::new(li, lc, v));
                }
            }
        }
    }
    let mut bnd: Vec<usize> = kib_global.iter().map(|e| e.1).collect();
    bnd.sort_unstable();
    bnd.dedup();
    let kib: Vec<(usize, usize, f64)> = kib_global
        .iter()
        .map(|&(li, p, v)| (li, bnd.binary_search(&p).unwrap_or(0), v))
        .collect();
    if ni == 0 {
        return Ok((
            Domain {
                interior,
                bnd,
                factor: None,
                kib,
                modes: Vec::new(),
                lambda: Vec::new(),
            },
            Vec::new(),
        ));
    }
    let a = SparseColMat::<usize, f64>::try_new_from_triplets(ni, ni, &lower)
        .map_err(|e| SimError::Inconsistent(format!("domain block Kii: {e:?}")))?;
    let factor = SparseCholesky::new(a.as_ref()).map_err(chol_err("a domain block Kii"))?;
    // Schur contribution: Z = Kii⁻¹ Kib, S_d = Kbi Z.
    let nbd = bnd.len();
    let mut s_trip = Vec::new();
    if nbd > 0 {
        let mut z = Mat::<f64>::zeros(ni, nbd);
        for &(li, lb, v) in &kib {
            z[(li, lb)] += v;
        }
        factor.solve_in_place(z.as_mut());
        let mut sd = Mat::<f64>::zeros(nbd, nbd);
        for &(li, lb, v) in &kib {
            for q in 0..nbd {
                sd[(lb, q)] += v * z[(li, q)];
            }
        }
        for p in 0..nbd {
            for q in 0..nbd {
                if bnd[q] <= bnd[p] {
                    // Symmetrize (rounding) so the lower triangle is exact.
                    let v = 0.5 * (sd[(p, q)] + sd[(q, p)]);
                    if v != 0.0 {
                        s_trip.push(Triplet::new(bnd[p], bnd[q], -v));
                    }
                }
            }
        }
    }
    let kii_csr =
        CsrMatrix::from_triplets(ni, &kii).map_err(|e| SimError::Inconsistent(e.to_string()))?;
    let (modes, lambda) = lowest_modes(&kii_csr, &factor, m_wanted.min(ni));
    Ok((
        Domain {
            interior,
            bnd,
            factor: Some(factor),
            kib,
            modes,
            lambda,
        },
        s_trip,
    ))
}

/// The `m` lowest eigenpairs of `a` (module doc): modes column-major
/// `ni x m`, eigenvalues ascending.
fn lowest_modes(a: &CsrMatrix, factor: &SparseCholesky, m: usize) -> (Vec<f64>, Vec<f64>) {
    let n = a.n;
    if m == 0 {
        return (Vec::new(), Vec::new());
    }
    if n <= DENSE_EIGEN_LIMIT {
        let mut dense = nalgebra::DMatrix::<f64>::zeros(n, n);
        for r in 0..n {
            for e in a.row_ptr[r]..a.row_ptr[r + 1] {
                dense[(r, a.col[e])] = a.val[e];
            }
        }
        let eig = dense.symmetric_eigen();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let mut modes = Vec::with_capacity(n * m);
        let mut lambda = Vec::with_capacity(m);
        for &j in order.iter().take(m) {
            modes.extend(eig.eigenvectors.column(j).iter());
            lambda.push(eig.eigenvalues[j]);
        }
        return (modes, lambda);
    }
    let q = (m + EXTRA_VECTORS).min(n);
    let mut y = Mat::<f64>::from_fn(n, q, hash01);
    let mut evals = nalgebra::DVector::<f64>::zeros(0);
    for _ in 0..EIGEN_ITERATIONS {
        factor.solve_in_place(y.as_mut());
        // Modified Gram-Schmidt (the columns stay independent: inverse
        // iteration only sharpens them, and q << n).
        for j in 0..q {
            for i in 0..j {
                let d: f64 = (0..n).map(|r| y[(r, j)] * y[(r, i)]).sum();
                for r in 0..n {
                    y[(r, j)] -= d * y[(r, i)];
                }
            }
            let nn: f64 = (0..n).map(|r| y[(r, j)] * y[(r, j)]).sum::<f64>().sqrt();
            for r in 0..n {
                y[(r, j)] = if nn > 0.0 { y[(r, j)] / nn } else { 0.0 };
            }
        }
        // Rayleigh-Ritz: H = Yᵀ A Y.
        let mut ay = vec![0.0; n * q];
        let yrow: Vec<f64> = (0..n * q).map(|t| y[(t / q, t % q)]).collect();
        a.mul_rows(&yrow, q, &mut ay);
        let h = nalgebra::DMatrix::<f64>::from_fn(q, q, |i, j| {
            let s: f64 = (0..n).map(|r| yrow[r * q + i] * ay[r * q + j]).sum();
            let t: f64 = (0..n).map(|r| yrow[r * q + j] * ay[r * q + i]).sum();
            0.5 * (s + t)
        });
        let eig = h.symmetric_eigen();
        let mut order: Vec<usize> = (0..q).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let mut x = Mat::<f64>::zeros(n, q);
        for (jn, &jo) in order.iter().enumerate() {
            for r in 0..n {
                let mut s = 0.0;
                for i in 0..q {
                    s += yrow[r * q + i] * eig.eigenvectors[(i, jo)];
                }
                x[(r, jn)] = s;
            }
        }
        evals = nalgebra::DVector::from_iterator(q, order.iter().map(|&j| eig.eigenvalues[j]));
        y = x;
    }
    let mut modes = Vec::with_capacity(n * m);
    for j in 0..m {
        for r in 0..n {
            modes.push(y[(r, j)]);
        }
    }
    let lambda = evals.iter().take(m).cloned().collect();
    (modes, lambda)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::csr::tridiagonal_triplets;

    /// A 1D chain of `n` nodes as "tets" [i, i+1, i+1, i+1] (only the
    /// connectivity matters here) with a Laplacian-plus-mass matrix.
    #[test]
    fn reduced_solve_is_exact_when_modes_span_the_interiors() {
        let n = 40;
        let t = tridiagonal_triplets(n, 2.1);
        let k = CsrMatrix::from_triplets(n, &t).unwrap();
        let tets: Vec<[usize; 4]> = (0..n - 1).map(|i| [i, i + 1, i + 1, i + 1]).collect();
        let ids: Vec<u32> = (0..n - 1).map(|i| (i / 10) as u32).collect();
        let part = Partition::from_ids(n, &tets, &ids).unwrap();
        let free: Vec<Option<usize>> = (0..n).map(Some).collect();
        // 10 modes per domain span every interior (at most 9 nodes): the
        // reduced solve is the exact solution.
        let params = DdParams {
            modes: 10,
            interiors: Interiors::Modes,
            ..Default::default()
        };
        let dd = DdSolver::new(&k, &tets, &part, &free, &params).unwrap();
        assert_eq!(dd.stats().domains, 4);
        assert_eq!(dd.stats().boundary_nodes, 3);
        let b: Vec<f64> = (0..3 * n).map(|i| ((i * 13) % 7) as f64 - 3.0).collect();
        let mut x = vec![0.0; 3 * n];
        dd.reduced_solve(&b, &mut x).unwrap();
        let mut ax = vec![0.0; 3 * n];
        k.mul_rows(&x, 3, &mut ax);
        for (p, q) in ax.iter().zip(&b) {
            assert!((p - q).abs() < 1e-9, "{p} vs {q}");
        }
        // Fewer modes: only an approximation, but a Galerkin one (the error
        // is K-orthogonal to the subspace, so the energy norm shrinks).
        let dd2 = DdSolver::new(
            &k,
            &tets,
            &part,
            &free,
            &DdParams {
                modes: 2,
                interiors: Interiors::Modes,
                ..Default::default()
            },
        )
        .unwrap();
        let residual = |dd: &DdSolver| {
            let mut x2 = vec![0.0; 3 * n];
            dd.reduced_solve(&b, &mut x2).unwrap();
            let mut a2 = vec![0.0; 3 * n];
            k.mul_rows(&x2, 3, &mut a2);
            a2.iter()
                .zip(&b)
                .map(|(p, q)| (p - q).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let bn: f64 = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        let r = residual(&dd2);
        assert!(r < bn && r > 1e-6 * bn, "{r} {bn}");
        // Exact interiors (the default): exact with no modes at all.
        let dd3 = DdSolver::new(
            &k,
            &tets,
            &part,
            &free,
            &DdParams {
                modes: 2,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(dd3.stats().modes, 0);
        let r3 = residual(&dd3);
        assert!(r3 < 1e-12 * bn, "{r3} {bn}");
    }

    #[test]
    fn subspace_iteration_finds_the_lowest_modes() {
        let n = 200;
        let t = tridiagonal_triplets(n, 2.0);
        let a = CsrMatrix::from_triplets(n, &t).unwrap();
        let lower: Vec<Triplet<usize, usize, f64>> = t
            .iter()
            .filter(|e| e.1 <= e.0)
            .map(|e| Triplet::new(e.0, e.1, e.2))
            .collect();
        let m = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &lower).unwrap();
        let f = SparseCholesky::new(m.as_ref()).unwrap();
        let (modes, lambda) = lowest_modes(&a, &f, 5);
        for (j, l) in lambda.iter().enumerate() {
            let exact = 2.0 - 2.0 * ((j + 1) as f64 * std::f64::consts::PI / (n + 1) as f64).cos();
            assert!(
                (l - exact).abs() < 1e-6 * exact.max(1e-3),
                "{j}: {l} vs {exact}"
            );
        }
        let norm: f64 = modes[..n].iter().map(|v| v * v).sum();
        assert!((norm - 1.0).abs() < 1e-9);
    }
}
