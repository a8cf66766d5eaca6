//! The projections of the PD local step (VH §7.1): the closest
//! rotation `R(F)` and the closest volume-preserving matrix `V(F)` to the
//! deformation gradient `F` in the Frobenius norm (VH Eq. 8, Eq. 26).
//!
//! Both come from one *signed* SVD `F = U diag(s) Vᵀ` with `det U = det V = +1`:
//! a reflection is carried by the sign of the smallest singular value, so an
//! inverted tet (`det F < 0`) has `s3 < 0`.
//!
//! * `R(F) = U Vᵀ` (polar decomposition with the det fix: flipping the sign of
//!   the smallest singular value is what makes the closest *proper* rotation).
//! * `V(F) = U diag(d) Vᵀ` where `d` solves VH Eq. 26,
//!   `min |d - s|² s.t. d1 d2 d3 = 1, d >= 0.01`, the singular values first
//!   clamped to `s >= 0.01` (VH §7.1 clamps at 0.01; this keeps inverted or
//!   degenerate tets finite and gives them a proper, positive target).
//!
//! # Solving Eq. 26
//! The stationarity equations of the Lagrangian
//! `½|d - s|² - λ (d1 d2 d3 - 1)` are, using `d1 d2 d3 = 1`,
//! `d_i² - s_i d_i = λ` for every free `i`: one scalar multiplier ties the
//! three unknowns. With `s` sorted descending, the global minimizer takes the
//! `+` root `d_i = (s_i + sqrt(s_i² + 4λ)) / 2` for the two larger values, and
//! the smallest value `t = d3` may sit on either root (a strong compression
//! squeezes the thinnest direction, `t < s3 / 2`). Parametrizing by `t`,
//! `λ = t (t - s3)` and the KKT system collapses to one equation
//! `φ(t) = ln d1(t) + ln d2(t) + ln t = 0`, solved by Newton's method
//! safeguarded by a bracket (bisection in log space when a Newton step leaves
//! it), so it always converges in a bounded number of iterations. `φ` is
//! increasing for `t >= s3/2`; below that it is scanned for every sign change
//! and the root of least cost is kept. When the bound `d3 >= 0.01` is active,
//! `d3 = 0.01` is fixed and the same solve runs on the remaining two values
//! (VH: "clamp it ... and fix its value at the next iteration").

use nalgebra::{Matrix3, Vector3};

/// Lower bound on the singular values entering Eq. 26 and on the solution
/// `d` (VH §7.1).
pub const SINGULAR_VALUE_FLOOR: f64 = 0.01;

/// Iteration cap of the safeguarded Newton solve of one root (never reached
/// in practice: bisection alone halves the log-bracket each step).
const MAX_ITERATIONS: u32 = 200;

/// Number of sample points scanning `t < s3 / 2` for roots of `φ`.
const SCAN_POINTS: usize = 16;

/// `F = U diag(s) Vᵀ` with `U`, `V` proper rotations (det +1), `|s1| >= |s2| >= |s3|`,
/// `s1, s2 >= 0`; `s3 < 0` exactly when `det F < 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignedSvd {
    pub u: Matrix3<f64>,
    pub s: Vector3<f64>,
    pub v: Matrix3<f64>,
}

/// Signed SVD of `f` (see [`SignedSvd`]); `None` when `f` has a non-finite
/// entry.
///
/// The 3x3 scheme of McAdams et al. 2011 ("Computing the singular value
/// decomposition of 3x3 matrices with minimal branching and elementary
/// floating point operations") in f64, with one-sided Jacobi rotations in
/// place of the eigensolve of `FᵀF`: cyclic rotations `V` make the columns
/// of `F V` orthogonal (to rounding, relative to each column, so tiny singular
/// values stay accurate), the columns are sorted by decreasing norm, and a
/// Givens QR of `B = F V = U R` gives the
/// proper rotation `U` and the (signed) singular values `diag R`. Both `U`
/// and `V` are products of rotations, so orthogonal with det +1 to rounding,
/// and the QR keeps `U` accurate even where `Λ` is clustered or tiny (the
/// weakness of eigenvalue-only methods). About 10x faster than nalgebra's
/// general SVD, the local step's cost.
pub fn signed_svd(f: &Matrix3<f64>) -> Option<SignedSvd> {
    signed_svd_from(f, None)
}

/// [`signed_svd`] with the Jacobi rotations started from the rotation `v0`
/// (det +1) instead of the identity: `F v0` is rotated on until its columns
/// are orthogonal. With `v0` the `V` of a nearby `F` (the same tet at the
/// previous PD iteration) the columns start nearly orthogonal and the
/// quadratically convergent sweeps stop after one or two instead of four or
/// five. The result is an SVD of `F` to the same accuracy; it differs from
/// the cold one only by rounding (and by the sign/order choices where
/// singular values are equal).
pub fn signed_svd_warm(f: &Matrix3<f64>, v0: &Matrix3<f64>) -> Option<SignedSvd> {
    signed_svd_from(f, Some(v0))
}

fn signed_svd_from(f: &Matrix3<f64>, v0: Option<&Matrix3<f64>>) -> Option<SignedSvd> {
    let (mut b, mut v, scale) = match jacobi_start(f, v0)? {
        Ok(start) => start,
        Err(zero) => return Some(zero),
    };
    // One-sided (Hestenes) Jacobi: rotate column pairs of B = F V until
    // every pair is orthogonal relative to the columns' own norms (which is
    // what keeps tiny singular values accurate, unlike an eigensolve of FᵀF).
    for _sweep in 0..JACOBI_SWEEPS {
        let mut rotated = false;
        // Squared relative off-diagonal (no square root on the hot path).
        let mut max_rel2: f64 = 0.0;
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            // Summed in the order the four-lane version sums them.
            let (mut alpha, mut beta, mut gamma) = (0.0, 0.0, 0.0);
            for k in 0..3 {
                let (x, y) = (b[(k, p)], b[(k, q)]);
                alpha += x * x;
                beta += y * y;
                gamma += x * y;
            }
            let Some((c, sn, rel2)) = jacobi_rotation(alpha, beta, gamma) else {
                continue;
            };
            rotated = true;
            max_rel2 = max_rel2.max(rel2);
            for k in 0..3 {
                let (xp, xq) = (b[(k, p)], b[(k, q)]);
                b[(k, p)] = c * xp - sn * xq;
                b[(k, q)] = sn * xp + c * xq;
                let (vp, vq) = (v[(k, p)], v[(k, q)]);
                v[(k, p)] = c * vp - sn * vq;
                v[(k, q)] = sn * vp + c * vq;
            }
        }
        // Cyclic Jacobi converges quadratically: once every pair started the
        // sweep within 1e-8 of orthogonal, the sweep has brought them to
        // rounding, and a checking sweep would rotate nothing.
        if !rotated || max_rel2 <= STOP_REL2 {
            break;
        }
    }
    Some(finish_svd(b, v, scale))
}

/// The scaled `B = F V0 / max|F|`, `V0` and the scale that the sweeps start
/// from; `Err` with the SVD of a zero `F`, `None` for a non-finite one.
#[allow(clippy::type_complexity)]
fn jacobi_start(
    f: &Matrix3<f64>,
    v0: Option<&Matrix3<f64>>,
) -> Option<Result<(Matrix3<f64>, Matrix3<f64>, f64), SignedSvd>> {
    if !f.iter().all(|x| x.is_finite()) {
        return None;
    }
    // Scale to unit size so that FᵀF can neither overflow nor underflow.
    let scale = f.amax();
    if scale == 0.0 {
        return Some(Err(SignedSvd {
            u: Matrix3::identity(),
            s: Vector3::zeros(),
            v: Matrix3::identity(),
        }));
    }
    let fs = f / scale;
    Some(Ok(match v0 {
        Some(v0) if v0.iter().all(|x| x.is_finite()) => (fs * v0, *v0, scale),
        _ => (fs, Matrix3::<f64>::identity(), scale),
    }))
}

/// The Jacobi rotation `(c, s)` that makes columns of squared norms
/// `alpha`, `beta` and inner product `gamma` orthogonal, with their squared
/// relative inner product `gamma² / (alpha beta)`; `None` where they
/// already are (to rounding).
#[inline(always)]
fn jacobi_rotation(alpha: f64, beta: f64, gamma: f64) -> Option<(f64, f64, f64)> {
    let (ab, g2) = (alpha * beta, gamma * gamma);
    if gamma == 0.0 || g2 <= f64::EPSILON * f64::EPSILON * ab {
        return None;
    }
    let (c, sn) = rotation_of(alpha, beta, gamma);
    Some((c, sn, g2 / ab))
}

/// Cosine and sine of the Jacobi rotation for `gamma != 0` (Golub & Van
/// Loan §8.5.2, the smaller root `t`).
#[inline(always)]
fn rotation_of(alpha: f64, beta: f64, gamma: f64) -> (f64, f64) {
    let zeta = (beta - alpha) / (2.0 * gamma);
    // For |zeta| > 1e150 (zeta² overflows) t -> 1 / (2 zeta).
    let big = zeta.abs() > 1e150;
    let z = if big { 1.0 } else { zeta };
    let t_small = z.signum() / (z.abs() + (z * z + 1.0).sqrt());
    let t = if big { 0.5 / zeta } else { t_small };
    let c = 1.0 / (t * t + 1.0).sqrt();
    (c, t * c)
}

/// Tets per batch of [`signed_svd_warm_x4`].
pub const SVD_LANES: usize = 4;

/// [`signed_svd_warm`] of four matrices at once, into `out` (written
/// in place: returning the ~700-byte array cost a copy per call). Each
/// result is the one the single call gives (the same rotations in the same
/// order, to the sign of a zero). The Jacobi sweeps run in lockstep over
/// the four: each sweep's chain of square roots and divisions is
/// latency-bound, and four independent chains keep the divider busy where
/// one leaves it idle. A converged lane is rotated by the identity (bitwise
/// a no-op).
pub fn signed_svd_warm_x4(
    f: &[Matrix3<f64>; SVD_LANES],
    v0: &[Matrix3<f64>; SVD_LANES],
    out: &mut [Option<SignedSvd>; SVD_LANES],
) {
    let mut scale = [0.0f64; SVD_LANES];
    for l in 0..SVD_LANES {
        scale[l] = f[l].amax();
    }
    // Lanes the lockstep sweeps cannot take (non-finite or zero F, a
    // non-finite warm start): all four one by one.
    let regular = (0..SVD_LANES).all(|l| {
        scale[l] > 0.0
            && scale[l].is_finite()
            && f[l].iter().all(|x| x.is_finite())
            && v0[l].iter().all(|x| x.is_finite())
    });
    if !regular {
        for l in 0..SVD_LANES {
            out[l] = signed_svd_warm(&f[l], &v0[l]);
        }
        return;
    }
    // Lane-major B = (F / scale) V0 and V = V0: b[k][l] is entry k
    // (column-major) of lane l, as `jacobi_start` computes it.
    let mut b = [[0.0f64; SVD_LANES]; 9];
    let mut v = [[0.0f64; SVD_LANES]; 9];
    for l in 0..SVD_LANES {
        let bl = (f[l] / scale[l]) * v0[l];
        for k in 0..9 {
            b[k][l] = bl[k];
            v[k][l] = v0[l][k];
        }
    }
    let mut done = [false; SVD_LANES];
    for _sweep in 0..JACOBI_SWEEPS {
        let mut rotated = [false; SVD_LANES];
        let mut max_rel2 = [0.0f64; SVD_LANES];
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let mut c = [1.0f64; SVD_LANES];
            let mut sn = [0.0f64; SVD_LANES];
            for l in 0..SVD_LANES {
                let col = |m: usize, k: usize| b[3 * m + k][l];
                let (mut alpha, mut beta, mut gamma) = (0.0, 0.0, 0.0);
                for k in 0..3 {
                    let (x, y) = (col(p, k), col(q, k));
                    alpha += x * x;
                    beta += y * y;
                    gamma += x * y;
                }
                // Branch-free (selects, not jumps), so the four lanes'
                // divisions and square roots overlap.
                let (ab, g2) = (alpha * beta, gamma * gamma);
                let skip = done[l] | (gamma == 0.0) | (g2 <= f64::EPSILON * f64::EPSILON * ab);
                let (cl, sl) = rotation_of(alpha, beta, if skip { 1.0 } else { gamma });
                c[l] = if skip { 1.0 } else { cl };
                sn[l] = if skip { 0.0 } else { sl };
                rotated[l] |= !skip;
                let rel2 = g2 / ab;
                max_rel2[l] = if skip {
                    max_rel2[l]
                } else {
                    max_rel2[l].max(rel2)
                };
            }
            for k in 0..3 {
                let (ip, iq) = (3 * p + k, 3 * q + k);
                for l in 0..SVD_LANES {
                    let (xp, xq) = (b[ip][l], b[iq][l]);
                    b[ip][l] = c[l] * xp - sn[l] * xq;
                    b[iq][l] = sn[l] * xp + c[l] * xq;
                    let (vp, vq) = (v[ip][l], v[iq][l]);
                    v[ip][l] = c[l] * vp - sn[l] * vq;
                    v[iq][l] = sn[l] * vp + c[l] * vq;
                }
            }
        }
        for l in 0..SVD_LANES {
            done[l] |= !rotated[l] || max_rel2[l] <= STOP_REL2;
        }
        if done.iter().all(|&d| d) {
            break;
        }
    }
    // Sort per lane, then the Givens QR in lockstep (its square roots and
    // divisions are a chain like the sweeps'), then order and signs.
    let mut vs = [Matrix3::zeros(); SVD_LANES];
    for l in 0..SVD_LANES {
        let bl = Matrix3::from_fn(|r, c| b[3 * c + r][l]);
        let vl = Matrix3::from_fn(|r, c| v[3 * c + r][l]);
        let (bs, vsl) = sort_columns(bl, vl);
        vs[l] = vsl;
        for k in 0..9 {
            b[k][l] = bs[k];
        }
    }
    let mut u = [[0.0f64; SVD_LANES]; 9];
    for k in [0, 4, 8] {
        u[k] = [1.0; SVD_LANES];
    }
    for (i, j, col) in QR_ROTATIONS {
        let mut c = [1.0f64; SVD_LANES];
        let mut sn = [0.0f64; SVD_LANES];
        for l in 0..SVD_LANES {
            (c[l], sn[l]) = givens(b[3 * col + i][l], b[3 * col + j][l]);
        }
        for k in 0..3 {
            let (bi_, bj_) = (3 * k + i, 3 * k + j);
            let (ui_, uj_) = (3 * i + k, 3 * j + k);
            for l in 0..SVD_LANES {
                let (bi, bj) = (b[bi_][l], b[bj_][l]);
                b[bi_][l] = c[l] * bi + sn[l] * bj;
                b[bj_][l] = -sn[l] * bi + c[l] * bj;
                let (ui, uj) = (u[ui_][l], u[uj_][l]);
                u[ui_][l] = c[l] * ui + sn[l] * uj;
                u[uj_][l] = -sn[l] * ui + c[l] * uj;
            }
        }
    }
    for l in 0..SVD_LANES {
        let ul = Matrix3::from_fn(|r, c| u[3 * c + r][l]);
        let sv = Vector3::new(b[0][l], b[4][l], b[8][l]) * scale[l];
        out[l] = Some(order_and_sign(ul, sv, vs[l]));
    }
}

/// Sorts, fixes the signs of and QR-factors the orthogonalized `B = F V /
/// scale` into the signed SVD of `F`.
fn finish_svd(b: Matrix3<f64>, v: Matrix3<f64>, scale: f64) -> SignedSvd {
    let (mut b, vs) = sort_columns(b, v);
    let mut u = Matrix3::<f64>::identity();
    for (i, j, col) in QR_ROTATIONS {
        let (c, sn) = givens(b[(i, col)], b[(j, col)]);
        // Rows i, j of B <- G B; columns i, j of U <- U Gᵀ.
        for k in 0..3 {
            let (bi, bj) = (b[(i, k)], b[(j, k)]);
            b[(i, k)] = c * bi + sn * bj;
            b[(j, k)] = -sn * bi + c * bj;
            let (ui, uj) = (u[(k, i)], u[(k, j)]);
            u[(k, i)] = c * ui + sn * uj;
            u[(k, j)] = -sn * ui + c * uj;
        }
    }
    order_and_sign(u, Vector3::new(b[(0, 0)], b[(1, 1)], b[(2, 2)]) * scale, vs)
}

/// The Givens QR of `B = F V`: zero (1,0), (2,0), then (2,1). Each rotation
/// makes the pivot `hypot >= 0`, so R11, R22 >= 0 and R33 carries det F.
const QR_ROTATIONS: [(usize, usize, usize); 3] = [(0, 1, 0), (0, 2, 0), (1, 2, 1)];

/// Cosine and sine of the Givens rotation taking `(x, y)` to `(r, 0)`,
/// `r >= 0`; the identity for `(0, 0)`. Branch-free. F is scaled to max
/// |entry| 1: no overflow, and `hypot`'s care costs more than the rest of
/// the rotation.
#[inline(always)]
fn givens(x: f64, y: f64) -> (f64, f64) {
    let r = (x * x + y * y).sqrt();
    let zero = r == 0.0;
    let inv = 1.0 / if zero { 1.0 } else { r };
    (
        if zero { 1.0 } else { x * inv },
        if zero { 0.0 } else { y * inv },
    )
}

/// `B` and `V` with their columns sorted by decreasing norm of `B`'s, the
/// last negated where that leaves det V = -1 (a swap flips it).
#[inline(always)]
fn sort_columns(b: Matrix3<f64>, v: Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let a = Vector3::from_fn(|k, _| b.column(k).norm_squared());
    let mut order = [0usize, 1, 2];
    order.sort_by(|&x, &y| a[y].total_cmp(&a[x]));
    let mut vs = Matrix3::zeros();
    let mut bs = Matrix3::zeros();
    for (k, &o) in order.iter().enumerate() {
        vs.set_column(k, &v.column(o));
        bs.set_column(k, &b.column(o));
    }
    if vs.determinant() < 0.0 {
        vs.column_mut(2).neg_mut();
        bs.column_mut(2).neg_mut();
    }
    (bs, vs)
}

/// The signed SVD from the QR's `U`, the diagonal `sv` of `R` (scaled back)
/// and the sorted `V`: |s| in decreasing order, only `s3` negative.
/// Inlined (as is [`sort_columns`]): returned by value out of a call, the
/// 168-byte result was copied by `memmove` into the caller's `Option`
/// (inlining made the local step of a PD run about 4% faster).
#[inline(always)]
fn order_and_sign(mut u: Matrix3<f64>, mut sv: Vector3<f64>, mut vs: Matrix3<f64>) -> SignedSvd {
    // Rounding can leave |s| out of order by an ulp where values cluster:
    // swap columns of both U and V (negating one to keep det +1).
    for (i, j) in [(0usize, 1usize), (1, 2), (0, 1)] {
        if sv[i].abs() < sv[j].abs() {
            // Swapping columns i, j of U and V (and s_i, s_j) keeps
            // U diag(s) Vᵀ but flips both determinants; negating column j of
            // both restores them and keeps the product.
            u.swap_columns(i, j);
            vs.swap_columns(i, j);
            u.column_mut(j).neg_mut();
            vs.column_mut(j).neg_mut();
            sv.swap_rows(i, j);
        }
    }
    // Only the last value may be negative.
    for k in 0..2 {
        if sv[k] < 0.0 {
            u.column_mut(k).neg_mut();
            u.column_mut(2).neg_mut();
            sv[k] = -sv[k];
            sv[2] = -sv[2];
        }
    }
    SignedSvd { u, s: sv, v: vs }
}

/// Squared relative off-diagonal at a sweep's start below which that sweep
/// is the last: from 1e-8 relative, quadratic convergence reaches rounding.
/// (A looser stop, 1e-10 squared, saved a sweep but made the result jump
/// by ~1e-10 where a rounding-level change of F changed the sweep count,
/// and PD runs with the direct and the CG global solver drifted 3e-7 m
/// apart over 40 contact steps.)
const STOP_REL2: f64 = 1e-16;

/// Cap on one-sided Jacobi sweeps (f64 converges in 4-6: quadratic).
const JACOBI_SWEEPS: usize = 30;

/// Closest rotation `R(F) = argmin_{A in SO(3)} |F - A|_F` (VH Eq. 8),
/// by polar decomposition. Dimensionless. Non-finite `f` gives the identity.
pub fn project_rotation(f: &Matrix3<f64>) -> Matrix3<f64> {
    match signed_svd(f) {
        Some(svd) => svd.u * svd.v.transpose(),
        None => Matrix3::identity(),
    }
}

/// The solution of VH Eq. 26 for one set of singular values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiagProjection {
    /// The projected singular values, `d1 d2 d3 = 1`, in the order of the input.
    pub d: [f64; 3],
    /// Lagrange multiplier of `d1 d2 d3 = 1` in `½|d - s|² - λ (d1 d2 d3 - 1)`.
    pub lambda: f64,
    /// Newton/bisection iterations spent (all roots tried, summed).
    pub iterations: u32,
    /// Whether the input or the solution hit the 0.01 floor.
    pub clamped: bool,
}

impl DiagProjection {
    /// Largest absolute KKT residual of Eq. 26 for the (clamped) input `s`:
    /// the stationarity `d_i - s_i - λ Π_{j≠i} d_j` of every value not held at
    /// the floor, and the constraint `d1 d2 d3 - 1`.
    pub fn kkt_residual(&self, s: [f64; 3]) -> f64 {
        let s = s.map(clamp_floor);
        let d = self.d;
        let mut r = (d[0] * d[1] * d[2] - 1.0).abs();
        for i in 0..3 {
            let at_floor = d[i] <= SINGULAR_VALUE_FLOOR * (1.0 + 1e-12);
            if at_floor && self.clamped {
                continue;
            }
            let others = d[(i + 1) % 3] * d[(i + 2) % 3];
            r = r.max((d[i] - s[i] - self.lambda * others).abs());
        }
        r
    }
}

fn clamp_floor(x: f64) -> f64 {
    // max() also maps NaN to the floor.
    x.max(SINGULAR_VALUE_FLOOR)
}

/// Solves VH Eq. 26: the `d` with `d1 d2 d3 = 1`, `d >= 0.01` closest to
/// `max(s, 0.01)` (singular values of any order and sign; dimensionless).
pub fn project_diag_sl3(s: [f64; 3]) -> DiagProjection {
    let sc = s.map(clamp_floor);
    // Already on SL(3) (to rounding): F itself is the projection, exactly.
    if sc == s && (sc[0] * sc[1] * sc[2] - 1.0).abs() <= 4.0 * f64::EPSILON {
        let d = sc;
        return DiagProjection {
            d,
            lambda: 0.0,
            iterations: 0,
            clamped: false,
        };
    }
    if sc == s {
        if let Some(p) = near_rest_projection(s) {
            return p;
        }
    }
    general_projection(s, sc)
}

/// [`project_diag_sl3`] without the near-rest fast path (`sc`: `s` clamped
/// to the floor).
fn general_projection(s: [f64; 3], sc: [f64; 3]) -> DiagProjection {
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| sc[b].total_cmp(&sc[a]));
    let sorted = order.map(|o| sc[o]);
    let mut iterations = 0;
    let sol = solve_sorted(&sorted, 3, 0.0, &mut iterations);
    let mut d = [0.0; 3];
    for (k, &o) in order.iter().enumerate() {
        d[o] = sol.d[k];
    }
    let clamped = s.iter().any(|&x| !(x >= SINGULAR_VALUE_FLOOR)) || sol.floored;
    DiagProjection {
        d,
        lambda: sol.lambda,
        iterations,
        clamped,
    }
}

/// Newton steps of [`near_rest_projection`] before it gives up.
const NEAR_REST_NEWTON_STEPS: u32 = 8;

/// The fast path of [`project_diag_sl3`] for singular values `s >= floor`
/// (the common case: tets near their rest shape), or `None` to take the
/// general solver.
///
/// The KKT conditions of Eq. 26 give `d_i² - s_i d_i - λ = 0`, and the
/// branch with every `d_i = (s_i + sqrt(s_i² + 4λ)) / 2` is the one the
/// general solver tries first (`t >= s_last / 2`). Newton on
/// `h(λ) = d1 d2 d3 - 1` (no logarithm) from its linearization at `λ = 0`
/// converges in two or three steps near rest. The result is accepted under
/// the same tests that let the general solver skip its other branches: cost
/// `|d - s|² <= s_min² / 4` (no root with `t < s_last / 2` can do better)
/// and `<= (s_min - floor)²` (nor one on the floor), with every
/// `d_i >= floor` and `d1 d2 d3 = 1` to rounding. It is then the same root
/// as the general solver's, to rounding.
fn near_rest_projection(s: [f64; 3]) -> Option<DiagProjection> {
    let prod = s[0] * s[1] * s[2];
    let inv2: f64 = s.iter().map(|x| 1.0 / (x * x)).sum();
    let mut lambda = -(prod - 1.0) / (prod * inv2);
    let s_min = s[0].min(s[1]).min(s[2]);
    let lambda_min = -0.25 * s_min * s_min;
    for it in 1..=NEAR_REST_NEWTON_STEPS {
        if !(lambda > lambda_min) {
            return None;
        }
        let q = s.map(|x| (x * x + 4.0 * lambda).sqrt());
        let d = [
            0.5 * (s[0] + q[0]),
            0.5 * (s[1] + q[1]),
            0.5 * (s[2] + q[2]),
        ];
        let p = d[0] * d[1] * d[2];
        let h = p - 1.0;
        if h.abs() <= 4.0 * f64::EPSILON {
            let cost: f64 = (0..3).map(|k| (d[k] - s[k]).powi(2)).sum();
            let ok = d.iter().all(|&x| x >= SINGULAR_VALUE_FLOOR)
                && cost <= 0.25 * s_min * s_min
                && cost <= (s_min - SINGULAR_VALUE_FLOOR).powi(2);
            return ok.then_some(DiagProjection {
                d,
                lambda,
                iterations: it,
                clamped: false,
            });
        }
        // dh/dλ = p Σ 1 / (d_i q_i)   (d d_i / dλ = 1 / q_i).
        let dh = p * (0..3).map(|k| 1.0 / (d[k] * q[k])).sum::<f64>();
        let step = h / dh;
        if !step.is_finite() {
            return None;
        }
        lambda -= step;
    }
    None
}

/// Closest volume-preserving matrix `V(F) = argmin_{A in SL(3)} |F - A|_F`
/// (VH Eq. 8) via Eq. 26, with the 0.01 floor of VH §7.1 (so for inverted or
/// degenerate `F` it is the projection of a slightly modified `F`; always
/// finite with `det V = 1`). Dimensionless. Non-finite `f` gives the identity.
pub fn project_volume(f: &Matrix3<f64>) -> Matrix3<f64> {
    project_volume_detailed(f).0
}

/// [`project_volume`] with the solve's details.
pub fn project_volume_detailed(f: &Matrix3<f64>) -> (Matrix3<f64>, DiagProjection) {
    match signed_svd(f) {
        Some(svd) => {
            let p = project_diag_sl3([svd.s[0], svd.s[1], svd.s[2]]);
            let d = Vector3::new(p.d[0], p.d[1], p.d[2]);
            (svd.u * Matrix3::from_diagonal(&d) * svd.v.transpose(), p)
        }
        None => (
            Matrix3::identity(),
            DiagProjection {
                d: [1.0; 3],
                lambda: 0.0,
                iterations: 0,
                clamped: true,
            },
        ),
    }
}

struct Solution {
    d: [f64; 3],
    lambda: f64,
    floored: bool,
}

/// The chain of the first `n` sorted (descending, all >= floor) values with
/// `Π_{i<n} d_i = exp(log_target)`, parametrized by `t = d_{n-1}`.
struct Chain<'a> {
    s: &'a [f64; 3],
    n: usize,
    log_target: f64,
}

impl Chain<'_> {
    /// `(d, λ)` on the curve at `t`.
    fn point(&self, t: f64) -> ([f64; 3], f64) {
        let (d, lambda, _) = self.point_q(t);
        (d, lambda)
    }
    /// [`Self::point`] and the roots `q_i = sqrt(s_i² + 4λ)`.
    fn point_q(&self, t: f64) -> ([f64; 3], f64, [f64; 2]) {
        let last = self.s[self.n - 1];
        let lambda = t * (t - last);
        let mut d = [0.0; 3];
        let mut q = [0.0; 2];
        for i in 0..self.n - 1 {
            let si = self.s[i];
            q[i] = (si * si + 4.0 * lambda).max(0.0).sqrt();
            d[i] = 0.5 * (si + q[i]);
        }
        d[self.n - 1] = t;
        (d, lambda, q)
    }
    /// `φ(t)` and `φ'(t)`.
    fn phi(&self, t: f64) -> (f64, f64) {
        let last = self.s[self.n - 1];
        let (d, _, q) = self.point_q(t);
        let mut dphi = 1.0 / t;
        // One logarithm of the product instead of one per value (the local
        // step's hottest line); the sum of logs only if the product leaves
        // the normal range.
        let mut prod = t;
        for di in d.iter().take(self.n - 1) {
            prod *= di;
        }
        let phi = if prod.is_normal() {
            prod.ln()
        } else {
            t.ln() + d.iter().take(self.n - 1).map(|di| di.ln()).sum::<f64>()
        } - self.log_target;
        for i in 0..self.n - 1 {
            // d ln d_i / dλ = 1 / (d_i sqrt(s_i² + 4λ)); dλ/dt = 2t - s_last.
            dphi += (2.0 * t - last) / (d[i] * q[i].max(1e-300));
        }
        (phi, dphi)
    }
    fn cost(&self, d: &[f64; 3]) -> f64 {
        (0..self.n).map(|i| (d[i] - self.s[i]).powi(2)).sum()
    }
}

/// Safeguarded Newton on `φ` in the bracket `[a, b]` (`0 < a < b`) where
/// `φ(a)` and `φ(b)` have opposite signs (or one is zero).
/// `guess` (if inside the bracket) is the first Newton point, else the
/// log-midpoint.
/// `fa` is `φ(a)` (known to every caller).
fn refine(
    chain: &Chain,
    mut a: f64,
    mut b: f64,
    fa: f64,
    guess: Option<f64>,
    iterations: &mut u32,
) -> f64 {
    if fa == 0.0 {
        return a;
    }
    let neg_at_a = fa < 0.0;
    let mut t = match guess {
        Some(g) if g > a && g < b => g,
        _ => (a * b).sqrt(),
    };
    for _ in 0..MAX_ITERATIONS {
        *iterations += 1;
        let (f, df) = chain.phi(t);
        if f == 0.0 {
            return t;
        }
        // Converged: the Newton update is below rounding. (Checked before the
        // bracket test: at the root the step can land exactly on an end.)
        if df.is_finite() && (f / df).abs() <= 2.0 * f64::EPSILON * t {
            return t;
        }
        if (f < 0.0) == neg_at_a {
            a = t;
        } else {
            b = t;
        }
        if b - a <= 4.0 * f64::EPSILON * b {
            return t;
        }
        let newton = t - f / df;
        let next = if df.is_finite() && df != 0.0 && newton > a && newton < b {
            // Quadratic convergence: a step below 1e-9 t leaves an error of
            // order 1e-18 t after it, so the checking evaluation is skipped.
            if (f / df).abs() <= 1e-9 * t {
                return newton;
            }
            newton
        } else {
            (a * b).sqrt()
        };
        t = next;
    }
    t
}

/// Global minimizer of `Σ_{i<n} (d_i - s_i)²` subject to
/// `Π_{i<n} d_i = exp(log_target)`, `d_i >= floor`, for `s[..n]` sorted
/// descending (entries `>= n` are left zero).
fn solve_sorted(s: &[f64; 3], n: usize, log_target: f64, iterations: &mut u32) -> Solution {
    let floor = SINGULAR_VALUE_FLOOR;
    if n == 1 {
        let d0 = log_target.exp().max(floor);
        return Solution {
            d: [d0, 0.0, 0.0],
            lambda: d0 * (d0 - s[0]),
            floored: false,
        };
    }
    let chain = Chain { s, n, log_target };
    let last = s[n - 1];
    let mut best: Option<(f64, Solution)> = None;
    let consider = |t: f64, best: &mut Option<(f64, Solution)>| {
        let (d, lambda) = chain.point(t);
        if d[..n].iter().any(|&x| !(x >= floor * (1.0 - 1e-12))) {
            return;
        }
        let c = chain.cost(&d);
        if best.as_ref().is_none_or(|(bc, _)| c < *bc) {
            *best = Some((
                c,
                Solution {
                    d,
                    lambda,
                    floored: false,
                },
            ));
        }
    };

    // Branch `t >= s_last / 2`: φ increasing, at most one root.
    let ta = (0.5 * last).max(floor);
    let (fa, _) = chain.phi(ta);
    if fa <= 0.0 {
        // For t >= s_last, λ >= 0 so d_i >= s_i and
        // φ(t) >= ln(t Π_{i<n-1} s_i) - log_target: this t_b has φ >= 0
        // without evaluating it.
        let analytic = last.max((log_target - s[..n - 1].iter().product::<f64>().ln()).exp());
        // (The factor 1 + 1e-9 puts φ(t_b) >= 1e-9, clear of rounding.)
        let tb = (analytic * (1.0 + 1e-9)).max(2.0 * ta);
        let ok = tb.is_finite();
        if ok {
            // First Newton point: `s` scaled uniformly onto the constraint,
            // `d ≈ s (exp(log_target) / Π s)^(1/n)`, exact to first order
            // near rest (the common case), so Newton needs a few steps.
            let log_s = s[..n].iter().product::<f64>().ln();
            let guess = last * ((log_target - log_s) / n as f64).exp();
            let t = refine(&chain, ta, tb, fa, Some(guess), iterations);
            consider(t, &mut best);
        }
    }
    // Branch `floor <= t < s_last / 2`: scan for every sign change. Any
    // point there has `|t - s_last| > s_last / 2`, so cost above
    // `(s_last / 2)²`: when the first branch already did at least as well,
    // nothing here can win (`consider` keeps strict improvements only) and
    // the scan, most of the local step's time near rest, is skipped.
    let beaten = best
        .as_ref()
        .is_some_and(|(bc, _)| *bc <= 0.25 * last * last);
    if 0.5 * last > floor && !beaten {
        let (lo, hi) = (floor, 0.5 * last);
        let ratio = (hi / lo).powf(1.0 / SCAN_POINTS as f64);
        let mut t0 = lo;
        let mut f0 = chain.phi(t0).0;
        for k in 1..=SCAN_POINTS {
            let t1 = if k == SCAN_POINTS { hi } else { t0 * ratio };
            let f1 = chain.phi(t1).0;
            if f0 == 0.0 {
                consider(t0, &mut best);
            } else if (f0 < 0.0) != (f1 < 0.0) {
                let t = refine(&chain, t0, t1, f0, None, iterations);
                consider(t, &mut best);
            }
            t0 = t1;
            f0 = f1;
        }
    }
    // The floor active on t: fix d_{n-1} = floor, solve the rest.
    // (A candidate with d_{n-1} = floor costs at least (s_last - floor)²:
    // skip the test when the best so far already does at least as well.)
    let floor_beaten = best
        .as_ref()
        .is_some_and(|(bc, _)| *bc <= (last - floor).powi(2));
    if !floor_beaten && (chain.phi(floor).0 > 0.0 || best.is_none()) {
        let sub = solve_sorted(s, n - 1, log_target - floor.ln(), iterations);
        let mut d = sub.d;
        d[n - 1] = floor;
        let c = chain.cost(&d);
        if best.as_ref().is_none_or(|(bc, _)| c < *bc) {
            best = Some((
                c,
                Solution {
                    d,
                    lambda: sub.lambda,
                    floored: true,
                },
            ));
        }
    }
    match best {
        Some((_, sol)) => sol,
        // Unreachable: the floor branch always yields a candidate. Fall back
        // to the uniform scaling, which is feasible.
        None => {
            let x = (log_target / n as f64).exp();
            let mut d = [0.0; 3];
            d[..n].fill(x);
            Solution {
                d,
                lambda: 0.0,
                floored: false,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::sim::test_util::Rng;

    fn cost(d: [f64; 3], s: [f64; 3]) -> f64 {
        let s = s.map(clamp_floor);
        (0..3).map(|i| (d[i] - s[i]).powi(2)).sum()
    }

    /// Smallest cost over a dense grid of the feasible set
    /// `{d1 d2 d3 = 1, d >= 0.01}` (an upper bound on the true minimum).
    fn brute_force(s: [f64; 3]) -> f64 {
        let (lo, hi) = (SINGULAR_VALUE_FLOOR.ln(), 1e4f64.ln());
        let n = 500;
        let mut best = f64::INFINITY;
        for i in 0..=n {
            let d1 = (lo + (hi - lo) * i as f64 / n as f64).exp();
            for j in 0..=n {
                let d2 = (lo + (hi - lo) * j as f64 / n as f64).exp();
                let d3 = 1.0 / (d1 * d2);
                if d3 >= SINGULAR_VALUE_FLOOR {
                    best = best.min(cost([d1, d2, d3], s));
                }
            }
        }
        best
    }

    #[test]
    fn diag_solve_is_the_global_minimum() {
        let mut rng = Rng(7);
        let mut max_it = 0;
        for case in 0..300 {
            let s = match case % 3 {
                0 => [(); 3].map(|_| rng.log_uniform(0.01, 100.0)),
                1 => [(); 3].map(|_| rng.log_uniform(0.3, 3.0)),
                // Two nearly equal large values: the strong-compression branch.
                _ => {
                    let a = rng.log_uniform(1.0, 50.0);
                    [a, a * (1.0 + 0.01 * rng.next()), rng.log_uniform(0.01, 5.0)]
                }
            };
            let p = project_diag_sl3(s);
            max_it = max_it.max(p.iterations);
            let c = cost(p.d, s);
            let b = brute_force(s);
            assert!(
                c <= b * (1.0 + 1e-9) + 1e-12,
                "s {s:?}: solver {c} ({:?}) > grid {b}",
                p.d
            );
            assert!(
                ((p.d[0] * p.d[1] * p.d[2]) - 1.0).abs() < 1e-13,
                "{s:?} {p:?}"
            );
            assert!(p
                .d
                .iter()
                .all(|&x| x >= SINGULAR_VALUE_FLOOR * (1.0 - 1e-12)));
        }
        assert!(max_it <= 200, "{max_it} iterations");
    }

    #[test]
    fn near_rest_fast_path_is_the_general_root() {
        let mut rng = Rng(5);
        let mut taken = 0;
        for case in 0..2000 {
            // Near rest (most tets), moderate and large deformations.
            let spread = [0.02, 0.3, 2.0][case % 3];
            let s = [(); 3].map(|_| (spread * (2.0 * rng.next() - 1.0)).exp());
            let general = general_projection(s, s);
            if let Some(fast) = near_rest_projection(s) {
                taken += 1;
                for k in 0..3 {
                    assert!(
                        (fast.d[k] - general.d[k]).abs() < 1e-13 * general.d[k],
                        "s {s:?}: fast {fast:?} vs general {general:?}"
                    );
                }
                assert!(
                    (fast.lambda - general.lambda).abs() < 1e-12 * (1.0 + general.lambda.abs())
                );
                assert!(!fast.clamped && fast.iterations <= NEAR_REST_NEWTON_STEPS);
            } else {
                // Only large deformations may need the general solver.
                assert!(spread > 0.02, "fast path refused near-rest {s:?}");
            }
            assert_eq!(project_diag_sl3(s).d.map(|x| x > 0.0), [true; 3]);
        }
        assert!(taken > 1000, "fast path taken {taken} times of 2000");
        // Strong compression (the other branch wins) and values under the
        // floor go to the general solver.
        assert!(near_rest_projection([30.0, 30.0, 0.02]).is_none());
    }

    #[test]
    fn kkt_residual_is_tiny_and_iterations_bounded() {
        let mut rng = Rng(11);
        let mut max_it = 0;
        let mut max_res: f64 = 0.0;
        for _ in 0..20_000 {
            let s = [(); 3].map(|_| rng.log_uniform(0.005, 60.0));
            let p = project_diag_sl3(s);
            let scale = 1.0 + s.iter().fold(0.0f64, |m, &x| m.max(x));
            let res = p.kkt_residual(s) / scale;
            max_res = max_res.max(res);
            max_it = max_it.max(p.iterations);
            assert!(res < 1e-12, "s {s:?}: residual {res} ({p:?})");
        }
        // Every root is found in a handful of safeguarded Newton steps; the
        // bound covers up to three roots tried (two branches and the floor).
        eprintln!("max iterations over 20000 random solves: {max_it}");
        assert!(max_it <= 40, "max iterations {max_it}");
    }

    #[test]
    fn identity_and_det_one_are_fixed_points() {
        let p = project_diag_sl3([1.0, 1.0, 1.0]);
        assert_eq!(p.d, [1.0, 1.0, 1.0]);
        for s in [[2.0, 0.5, 1.0], [4.0, 0.5, 0.5], [0.1, 10.0, 1.0]] {
            let p = project_diag_sl3(s);
            for i in 0..3 {
                assert!((p.d[i] - s[i]).abs() < 1e-13, "{s:?} -> {:?}", p.d);
            }
        }
    }

    #[test]
    fn signed_svd_random_clustered_and_degenerate() {
        let mut rng = Rng(3);
        let rot = |rng: &mut Rng| {
            let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                rng.next() - 0.5,
                rng.next() - 0.5,
                rng.next() - 0.5,
                rng.next() - 0.5,
            ));
            *q.to_rotation_matrix().matrix()
        };
        for case in 0..3000 {
            let sv = match case % 4 {
                0 => Vector3::from_fn(|_, _| rng.log_uniform(1e-3, 1e3)),
                1 => Vector3::new(1.0, 1.0, 1.0 + 1e-14 * rng.next()),
                2 => Vector3::new(rng.next(), 0.0, 1e-20),
                _ => Vector3::new(2.0, -0.5 * rng.next(), 0.7),
            };
            let f = rot(&mut rng) * Matrix3::from_diagonal(&sv) * rot(&mut rng);
            let svd = signed_svd(&f).unwrap();
            let back = svd.u * Matrix3::from_diagonal(&svd.s) * svd.v.transpose();
            let scale = f.norm().max(1e-300);
            assert!(
                (back - f).norm() <= 1e-13 * scale,
                "case {case}: {} {svd:?}",
                (back - f).norm() / scale
            );
            for m in [svd.u, svd.v] {
                assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-13);
                assert!((m.determinant() - 1.0).abs() < 1e-13);
            }
            assert!(
                svd.s[0] >= svd.s[1] && svd.s[1] >= svd.s[2].abs(),
                "{svd:?}"
            );
            // The reflection sits on s3 (where det F is not rounding noise).
            if f.determinant().abs() > 1e-10 * scale.powi(3) {
                assert_eq!(f.determinant() < 0.0, svd.s[2] < 0.0, "{svd:?}");
            }
        }
    }

    /// F of a PD iteration: random, near identity or rank-deficient, or
    /// inverted, with the V of a nearby F as warm start.
    fn pd_like_case(rng: &mut Rng, case: usize) -> (Matrix3<f64>, Matrix3<f64>) {
        let mut f = Matrix3::from_fn(|_, _| rng.next() * 2.0 - 1.0);
        match case % 4 {
            0 => f = Matrix3::identity() + 0.3 * f,
            1 => f.set_column(2, &(0.5 * f.column(0) + 1e-9 * f.column(1))),
            2 => f.column_mut(0).neg_mut(),
            _ => {}
        }
        let near = f + Matrix3::from_fn(|_, _| 1e-3 * (rng.next() - 0.5));
        (f, signed_svd(&near).unwrap().v)
    }

    #[test]
    fn four_lane_svd_is_four_single_ones() {
        let mut rng = Rng(12);
        for batch in 0..500 {
            let cases: [_; SVD_LANES] = std::array::from_fn(|l| pd_like_case(&mut rng, batch + l));
            let mut f = cases.map(|c| c.0);
            let mut v0 = cases.map(|c| c.1);
            // Batches with a lane the lockstep sweeps cannot take: a zero
            // F, a non-finite F, a non-finite warm start.
            match batch % 10 {
                7 => f[1] = Matrix3::zeros(),
                8 => f[2][(1, 1)] = f64::NAN,
                9 => v0[3][(0, 2)] = f64::INFINITY,
                _ => {}
            }
            let mut four = [None; SVD_LANES];
            signed_svd_warm_x4(&f, &v0, &mut four);
            for l in 0..SVD_LANES {
                // `==` on floats: equal up to the sign of a zero.
                assert_eq!(
                    four[l],
                    signed_svd_warm(&f[l], &v0[l]),
                    "batch {batch} lane {l}"
                );
            }
        }
    }

    #[test]
    fn warm_started_svd_matches_the_cold_one() {
        let mut rng = Rng(7);
        for case in 0..500 {
            let f = Matrix3::from_fn(|_, _| rng.next() * 2.0 - 1.0)
                + if case % 2 == 0 {
                    Matrix3::identity()
                } else {
                    Matrix3::zeros()
                };
            // A nearby F's V (the PD use), and an unrelated rotation.
            let near = signed_svd(&(f + Matrix3::from_fn(|_, _| 1e-3 * rng.next()))).unwrap();
            let far = signed_svd(&Matrix3::from_fn(|_, _| rng.next() - 0.5)).unwrap();
            let cold = signed_svd(&f).unwrap();
            for v0 in [near.v, far.v, Matrix3::identity()] {
                let w = signed_svd_warm(&f, &v0).unwrap();
                let back = w.u * Matrix3::from_diagonal(&w.s) * w.v.transpose();
                assert!((back - f).norm() < 1e-12 * f.norm().max(1.0), "case {case}");
                assert!((w.u.determinant() - 1.0).abs() < 1e-12);
                assert!((w.v.determinant() - 1.0).abs() < 1e-12);
                assert!(
                    (w.s - cold.s).norm() < 1e-12,
                    "case {case}: {} vs {}",
                    w.s,
                    cold.s
                );
                // The polar rotation is unique where F is not singular.
                if cold.s[2].abs() > 1e-6 {
                    let (rw, rc) = (w.u * w.v.transpose(), cold.u * cold.v.transpose());
                    assert!((rw - rc).norm() < 1e-9, "case {case}");
                }
            }
        }
        // Identity warm start is the cold algorithm, bit for bit.
        let f = Matrix3::new(1.1, 0.2, -0.1, 0.0, 0.8, 0.3, 0.1, 0.0, 1.3);
        assert_eq!(signed_svd_warm(&f, &Matrix3::identity()), signed_svd(&f));
        // A non-finite warm start falls back to the cold one.
        assert_eq!(
            signed_svd_warm(&f, &Matrix3::from_element(f64::NAN)),
            signed_svd(&f)
        );
    }

    #[test]
    fn signed_svd_reconstructs_and_carries_reflection() {
        let f = Matrix3::new(1.2, 0.3, -0.1, 0.05, -0.9, 0.2, -0.3, 0.1, 1.1);
        let svd = signed_svd(&f).unwrap();
        assert!(f.determinant() < 0.0 && svd.s[2] < 0.0);
        assert!((svd.u.determinant() - 1.0).abs() < 1e-12);
        assert!((svd.v.determinant() - 1.0).abs() < 1e-12);
        let back = svd.u * Matrix3::from_diagonal(&svd.s) * svd.v.transpose();
        assert!((back - f).norm() < 1e-12);
        assert!(svd.s[0] >= svd.s[1] && svd.s[1] >= svd.s[2].abs());
        assert!(signed_svd(&Matrix3::from_element(f64::NAN)).is_none());
        assert_eq!(
            project_rotation(&Matrix3::from_element(f64::INFINITY)),
            Matrix3::identity()
        );
    }
}
