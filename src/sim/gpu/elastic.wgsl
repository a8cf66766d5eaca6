// PD local step fused with the elastic right-hand side (VH §7.1, Eq. 26 and
// the sums of Eq. 28), f32. Mirrors src/sim/local.rs (signed SVD, closest
// rotation, Eq. 26 KKT solve with the 0.01 floor) and src/sim/energy.rs.
//
// Entry points:
//   tet_kernel    one thread per tet: F, R, V, energy, the four corner vectors
//                 2 V_e (γs R + γv V) ∇N_a (a = 0..3) with energy / clamp flag
//                 in .w of corners 0 / 1.
//   gather_kernel one thread per node: sums its corner vectors in tet order
//                 over the node -> (tet, corner) incidence (no float atomics).
//   reduce_kernel one workgroup per 256 tets: tree sum of energy and clamp
//                 flags into one partial per workgroup (summed on the CPU).

struct Params {
    num_tets: u32,
    num_nodes: u32,
    // Fibre families with data in `rest` (0-2); none read when 0.
    num_fibres: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Node indices of every tet.
@group(0) @binding(1) var<storage, read> tets: array<vec4<u32>>;
// Per tet six vec4: the columns of Dm^-1 in .xyz, .w = rest volume, γs, γv;
// then two fibre families (src/sim/fibre.rs), unit rest direction in .xyz and
// γ in .w (0 for none); then per family its stiffening β and PD weight w (J):
// (β0, w0, β1, w1).
@group(0) @binding(2) var<storage, read> rest: array<vec4<f32>>;
// Node positions, n x 3 row-major.
@group(0) @binding(3) var<storage, read> x: array<f32>;
// Per tet four corner vectors (.xyz); corner 0 .w = energy, corner 1 .w = clamped.
@group(0) @binding(4) var<storage, read_write> corners: array<vec4<f32>>;
// Incidence CSR: [0, n] node starts (offsets into the entries that follow at
// n + 1), entries 4 * tet + corner, sorted by tet within a node.
@group(0) @binding(5) var<storage, read> incidence: array<u32>;
// Result, n x 3 row-major.
@group(0) @binding(6) var<storage, read_write> out_rhs: array<f32>;
// Per workgroup of reduce_kernel: (energy sum, clamped count).
@group(0) @binding(7) var<storage, read_write> partials: array<vec2<f32>>;

const FLOOR: f32 = 0.01;
const JACOBI_SWEEPS: u32 = 8u;
const MAX_REFINE: u32 = 80u;
const SCAN_POINTS: u32 = 16u;
const EPS: f32 = 1.1920929e-7;

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>, wg_size: u32) -> u32 {
    return gid.x + gid.y * nwg.x * wg_size;
}

fn is_finite_f(v: f32) -> bool {
    // NaN fails both comparisons; inf fails the bound.
    return abs(v) <= 3.0e38;
}

// ---------------------------------------------------------------- SVD ----

struct Svd {
    u: mat3x3<f32>,
    s: vec3<f32>,
    v: mat3x3<f32>,
}

fn mat_get(m: mat3x3<f32>, r: u32, c: u32) -> f32 {
    var mm = m;
    return mm[c][r];
}

// Givens rotation (c, s) with c a + s b = sqrt(a² + b²) >= 0, -s a + c b = 0.
fn givens(a: f32, b: f32) -> vec2<f32> {
    let rho = sqrt(a * a + b * b);
    if (!(rho > 1e-30)) {
        return vec2<f32>(1.0, 0.0);
    }
    return vec2<f32>(a / rho, b / rho);
}

// Signed SVD F = U diag(s) Vᵀ with det U = det V = +1, s sorted by
// magnitude descending, s[2] < 0 exactly when det F < 0 (McAdams et al.
// 2011 style): Jacobi eigen-decomposition of FᵀF gives V, then a Givens QR
// of F V gives U and the signed singular values on the diagonal of R.
fn signed_svd(f: mat3x3<f32>) -> Svd {
    // Symmetric A = FᵀF as a flat array (row-major), V accumulates rotations.
    let ata = transpose(f) * f;
    var a: array<f32, 9>;
    var vv: array<f32, 9>;
    for (var i = 0u; i < 3u; i++) {
        for (var j = 0u; j < 3u; j++) {
            a[i * 3u + j] = ata[j][i];
            vv[i * 3u + j] = select(0.0, 1.0, i == j);
        }
    }
    for (var sweep = 0u; sweep < JACOBI_SWEEPS; sweep++) {
        for (var pair = 0u; pair < 3u; pair++) {
            let p = select(select(1u, 0u, pair == 1u), 0u, pair == 0u);
            let q = select(select(2u, 2u, pair == 1u), 1u, pair == 0u);
            let apq = a[p * 3u + q];
            let app = a[p * 3u + p];
            let aqq = a[q * 3u + q];
            if (abs(apq) <= 1e-30 * (abs(app) + abs(aqq)) || apq == 0.0) {
                continue;
            }
            let theta = (aqq - app) / (2.0 * apq);
            // Large theta: t ~ 1/(2 theta); sqrt(theta²+1) may overflow to inf,
            // which gives t = 0 (no rotation), never NaN.
            var t = 1.0 / (abs(theta) + sqrt(theta * theta + 1.0));
            if (theta < 0.0) {
                t = -t;
            }
            let c = 1.0 / sqrt(t * t + 1.0);
            let s = t * c;
            // A <- Jᵀ A J with J the rotation in the (p, q) plane.
            for (var k = 0u; k < 3u; k++) {
                let akp = a[k * 3u + p];
                let akq = a[k * 3u + q];
                a[k * 3u + p] = c * akp - s * akq;
                a[k * 3u + q] = s * akp + c * akq;
            }
            for (var k = 0u; k < 3u; k++) {
                let apk = a[p * 3u + k];
                let aqk = a[q * 3u + k];
                a[p * 3u + k] = c * apk - s * aqk;
                a[q * 3u + k] = s * apk + c * aqk;
            }
            for (var k = 0u; k < 3u; k++) {
                let vkp = vv[k * 3u + p];
                let vkq = vv[k * 3u + q];
                vv[k * 3u + p] = c * vkp - s * vkq;
                vv[k * 3u + q] = s * vkp + c * vkq;
            }
        }
    }
    // Sort eigenvalues (squared singular values) descending with V's columns.
    var ev = vec3<f32>(a[0], a[4], a[8]);
    var v = mat3x3<f32>(
        vec3<f32>(vv[0], vv[3], vv[6]),
        vec3<f32>(vv[1], vv[4], vv[7]),
        vec3<f32>(vv[2], vv[5], vv[8]),
    );
    if (ev.y > ev.x) {
        let te = ev.x; ev.x = ev.y; ev.y = te;
        let tc = v[0]; v[0] = v[1]; v[1] = tc;
    }
    if (ev.z > ev.x) {
        let te = ev.x; ev.x = ev.z; ev.z = te;
        let tc = v[0]; v[0] = v[2]; v[2] = tc;
    }
    if (ev.z > ev.y) {
        let te = ev.y; ev.y = ev.z; ev.z = te;
        let tc = v[1]; v[1] = v[2]; v[2] = tc;
    }
    // Proper rotation: a reflection in V is moved into the last column.
    if (determinant(v) < 0.0) {
        v[2] = -v[2];
    }
    // B = F V = U R; Givens QR zeroing (1,0), (2,0), (2,1).
    var b = f * v;
    var u = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
    // Rows p, q of B rotated: B <- Gᵀ B, U <- U G.
    // (1, 0) with rows 0, 1
    {
        let g = givens(b[0][0], b[0][1]);
        for (var k = 0u; k < 3u; k++) {
            let b0 = b[k][0];
            let b1 = b[k][1];
            b[k][0] = g.x * b0 + g.y * b1;
            b[k][1] = -g.y * b0 + g.x * b1;
            let u0 = u[0][k];
            let u1 = u[1][k];
            u[0][k] = g.x * u0 + g.y * u1;
            u[1][k] = -g.y * u0 + g.x * u1;
        }
    }
    // (2, 0) with rows 0, 2
    {
        let g = givens(b[0][0], b[0][2]);
        for (var k = 0u; k < 3u; k++) {
            let b0 = b[k][0];
            let b2 = b[k][2];
            b[k][0] = g.x * b0 + g.y * b2;
            b[k][2] = -g.y * b0 + g.x * b2;
            let u0 = u[0][k];
            let u2 = u[2][k];
            u[0][k] = g.x * u0 + g.y * u2;
            u[2][k] = -g.y * u0 + g.x * u2;
        }
    }
    // (2, 1) with rows 1, 2
    {
        let g = givens(b[1][1], b[1][2]);
        for (var k = 0u; k < 3u; k++) {
            let b1 = b[k][1];
            let b2 = b[k][2];
            b[k][1] = g.x * b1 + g.y * b2;
            b[k][2] = -g.y * b1 + g.x * b2;
            let u1 = u[1][k];
            let u2 = u[2][k];
            u[1][k] = g.x * u1 + g.y * u2;
            u[2][k] = -g.y * u1 + g.x * u2;
        }
    }
    var out: Svd;
    out.u = u;
    out.s = vec3<f32>(b[0][0], b[1][1], b[2][2]);
    out.v = v;
    return out;
}

// ------------------------------------------------------------ Eq. 26 ----
// Port of local.rs `solve_sorted`: the KKT system of
// min |d - s|² s.t. Π d = exp(log_target), d >= 0.01 collapses to
// φ(t) = Σ_{i<n-1} ln d_i(t) + ln t - log_target = 0 with
// λ = t (t - s_{n-1}), d_i = (s_i + sqrt(s_i² + 4λ)) / 2.

fn chain_d(s: vec3<f32>, n: u32, t: f32) -> vec3<f32> {
    var ss = s;
    let last = ss[n - 1u];
    let lambda = t * (t - last);
    var d = vec3<f32>(0.0);
    for (var i = 0u; i + 1u < n; i++) {
        let si = ss[i];
        d[i] = 0.5 * (si + sqrt(max(si * si + 4.0 * lambda, 0.0)));
    }
    d[n - 1u] = t;
    return d;
}

// (φ, φ')
fn chain_phi(s: vec3<f32>, n: u32, log_target: f32, t: f32) -> vec2<f32> {
    var ss = s;
    let last = ss[n - 1u];
    let lambda = t * (t - last);
    var phi = log(t) - log_target;
    var dphi = 1.0 / t;
    for (var i = 0u; i + 1u < n; i++) {
        let si = ss[i];
        let q = sqrt(max(si * si + 4.0 * lambda, 0.0));
        let di = 0.5 * (si + q);
        phi += log(di);
        dphi += (2.0 * t - last) / (di * max(q, 1e-30));
    }
    return vec2<f32>(phi, dphi);
}

fn chain_cost(s: vec3<f32>, n: u32, d: vec3<f32>) -> f32 {
    var c = 0.0;
    var ss = s;
    var dd = d;
    for (var i = 0u; i < n; i++) {
        let e = dd[i] - ss[i];
        c += e * e;
    }
    return c;
}

// Safeguarded Newton in the bracket [a, b] with a sign change of φ.
fn refine(s: vec3<f32>, n: u32, lt: f32, a0: f32, b0: f32) -> f32 {
    var a = a0;
    var b = b0;
    let fa = chain_phi(s, n, lt, a).x;
    if (fa == 0.0) {
        return a;
    }
    let neg_at_a = fa < 0.0;
    var t = sqrt(a * b);
    for (var it = 0u; it < MAX_REFINE; it++) {
        let fd = chain_phi(s, n, lt, t);
        let f = fd.x;
        let df = fd.y;
        if (f == 0.0) {
            return t;
        }
        if (is_finite_f(df) && abs(f / df) <= 2.0 * EPS * t) {
            return t;
        }
        if ((f < 0.0) == neg_at_a) {
            a = t;
        } else {
            b = t;
        }
        if (b - a <= 4.0 * EPS * b) {
            return t;
        }
        let newton = t - f / df;
        if (is_finite_f(df) && df != 0.0 && newton > a && newton < b) {
            t = newton;
        } else {
            t = sqrt(a * b);
        }
    }
    return t;
}

struct ChainResult {
    d: vec3<f32>,
    cost: f32,
    found: bool,
    need_floor: bool,
}

fn consider(s: vec3<f32>, n: u32, t: f32, best: ptr<function, ChainResult>) {
    let d = chain_d(s, n, t);
    var dd = d;
    for (var i = 0u; i < n; i++) {
        if (!(dd[i] >= FLOOR * (1.0 - 1e-6))) {
            return;
        }
    }
    let c = chain_cost(s, n, d);
    if (!(*best).found || c < (*best).cost) {
        (*best).d = d;
        (*best).cost = c;
        (*best).found = true;
    }
}

// The non-floor branches of local.rs `solve_sorted` for n = 2 or 3.
fn chain_solve(s: vec3<f32>, n: u32, lt: f32) -> ChainResult {
    var best: ChainResult;
    best.d = vec3<f32>(1.0);
    best.cost = 0.0;
    best.found = false;
    best.need_floor = false;
    var ss = s;
    let last = ss[n - 1u];
    // Branch t >= s_last / 2: φ increasing, at most one root.
    let ta = max(0.5 * last, FLOOR);
    if (chain_phi(s, n, lt, ta).x <= 0.0) {
        var tb = max(2.0 * ta, 1.0);
        var ok = false;
        for (var k = 0u; k < 128u; k++) {
            if (chain_phi(s, n, lt, tb).x >= 0.0) {
                ok = true;
                break;
            }
            tb *= 2.0;
            if (!is_finite_f(tb)) {
                break;
            }
        }
        if (ok) {
            consider(s, n, refine(s, n, lt, ta, tb), &best);
        }
    }
    // Branch floor <= t < s_last / 2: scan for sign changes.
    if (0.5 * last > FLOOR) {
        let lo = FLOOR;
        let hi = 0.5 * last;
        let ratio = pow(hi / lo, 1.0 / f32(SCAN_POINTS));
        var t0 = lo;
        var f0 = chain_phi(s, n, lt, t0).x;
        for (var k = 1u; k <= SCAN_POINTS; k++) {
            var t1 = t0 * ratio;
            if (k == SCAN_POINTS) {
                t1 = hi;
            }
            let f1 = chain_phi(s, n, lt, t1).x;
            if (f0 == 0.0) {
                consider(s, n, t0, &best);
            } else if ((f0 < 0.0) != (f1 < 0.0)) {
                consider(s, n, refine(s, n, lt, t0, t1), &best);
            }
            t0 = t1;
            f0 = f1;
        }
    }
    best.need_floor = chain_phi(s, n, lt, FLOOR).x > 0.0 || !best.found;
    return best;
}

struct DiagResult {
    d: vec3<f32>,
    floored: bool,
}

// local.rs `solve_sorted(s, 3, 0)` for s sorted descending, all >= FLOOR.
fn solve_sorted3(s: vec3<f32>) -> DiagResult {
    var res: DiagResult;
    let r3 = chain_solve(s, 3u, 0.0);
    res.d = r3.d;
    res.floored = false;
    if (!r3.need_floor) {
        return res;
    }
    // d3 at the floor: the same problem on (s1, s2) with target -ln(floor).
    let lt2 = -log(FLOOR);
    let r2 = chain_solve(s, 2u, lt2);
    var d2 = r2.d;
    var found2 = r2.found;
    var cost2 = r2.cost;
    if (r2.need_floor) {
        // d2 at the floor too: d1 = exp(lt2 - ln floor).
        let d0 = max(exp(lt2 - log(FLOOR)), FLOOR);
        let cand = vec3<f32>(d0, FLOOR, 0.0);
        let c = chain_cost(s, 2u, cand);
        if (!found2 || c < cost2) {
            d2 = cand;
            cost2 = c;
            found2 = true;
        }
    }
    let cand3 = vec3<f32>(d2.x, d2.y, FLOOR);
    let c3 = chain_cost(s, 3u, cand3);
    if (!r3.found || c3 < r3.cost) {
        res.d = cand3;
        res.floored = true;
    }
    return res;
}

// Eq. 26 for signed singular values in any order: clamps at the floor, sorts,
// solves, unsorts. Returns (d, clamped).
fn project_diag(s_in: vec3<f32>) -> DiagResult {
    let sc = max(s_in, vec3<f32>(FLOOR));
    // Sort descending carrying the original positions.
    var vals = sc;
    var idx = vec3<u32>(0u, 1u, 2u);
    if (vals.y > vals.x) {
        let t = vals.x; vals.x = vals.y; vals.y = t;
        let i = idx.x; idx.x = idx.y; idx.y = i;
    }
    if (vals.z > vals.x) {
        let t = vals.x; vals.x = vals.z; vals.z = t;
        let i = idx.x; idx.x = idx.z; idx.z = i;
    }
    if (vals.z > vals.y) {
        let t = vals.y; vals.y = vals.z; vals.z = t;
        let i = idx.y; idx.y = idx.z; idx.z = i;
    }
    let sol = solve_sorted3(vals);
    var d = vec3<f32>(0.0);
    d[idx.x] = sol.d.x;
    d[idx.y] = sol.d.y;
    d[idx.z] = sol.d.z;
    var res: DiagResult;
    res.d = d;
    res.floored = sol.floored || any(s_in < vec3<f32>(FLOOR));
    return res;
}

// ------------------------------------------------------------ kernels ----

fn node_pos(i: u32) -> vec3<f32> {
    return vec3<f32>(x[3u * i], x[3u * i + 1u], x[3u * i + 2u]);
}

@compute @workgroup_size(64)
fn tet_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, 64u);
    if (e >= params.num_tets) {
        return;
    }
    let ids = tets[e];
    let r0 = rest[6u * e];
    let r1 = rest[6u * e + 1u];
    let r2 = rest[6u * e + 2u];
    let dm_inv = mat3x3<f32>(r0.xyz, r1.xyz, r2.xyz);
    let vol = r0.w;
    let gs = r1.w;
    let gv = r2.w;
    let x0 = node_pos(ids.x);
    let ds = mat3x3<f32>(node_pos(ids.y) - x0, node_pos(ids.z) - x0, node_pos(ids.w) - x0);
    let f = ds * dm_inv;
    var finite = true;
    for (var c = 0u; c < 3u; c++) {
        for (var r = 0u; r < 3u; r++) {
            finite = finite && is_finite_f(mat_get(f, r, c));
        }
    }
    let ident = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
    var rot = ident;
    var vol_target = ident;
    var energy = 0.0;
    var clamped = true;
    if (finite) {
        let svd = signed_svd(f);
        let p = project_diag(svd.s);
        rot = svd.u * transpose(svd.v);
        let dm = mat3x3<f32>(vec3<f32>(p.d.x, 0.0, 0.0), vec3<f32>(0.0, p.d.y, 0.0), vec3<f32>(0.0, 0.0, p.d.z));
        vol_target = svd.u * dm * transpose(svd.v);
        // |F - R|² = Σ (s_i - 1)², |F - V|² = Σ (s_i - d_i)² (same U, V): no
        // cancellation of nearly equal matrices in f32.
        let er = svd.s - vec3<f32>(1.0);
        let ev = svd.s - p.d;
        energy = vol * (gs * dot(er, er) + gv * dot(ev, ev));
        clamped = p.floored;
    }
    var pm = 2.0 * vol * (gs * rot + gv * vol_target);
    // Tension-only fibres (src/sim/knit.rs): strain ε = |F d| - 1, energy
    // γ V (ε² + β ε⁴ / 2) in tension; target (w y - ∂E/∂y) dᵀ for the PD
    // weight w, which for β = 0 and w = 2 γ V is 2 γ V π(F d) dᵀ.
    let sw = rest[6u * e + 5u];
    for (var k = 0u; k < params.num_fibres; k++) {
        let fib = rest[6u * e + 3u + k];
        let beta = select(sw.x, sw.z, k == 1u);
        let w = select(sw.y, sw.w, k == 1u);
        if (fib.w > 0.0 && finite) {
            let y = f * fib.xyz;
            let len = length(y);
            let eps = len - 1.0;
            var t = w * y;
            if (eps > 0.0) {
                let e2 = eps * eps;
                energy += vol * fib.w * (e2 + 0.5 * beta * e2 * e2);
                let dpsi = 2.0 * fib.w * eps * (1.0 + beta * e2);
                // Capped at w ε: the target never passes rest (knit.rs).
                t -= (min(vol * dpsi, w * eps) / len) * y;
            }
            pm += mat3x3<f32>(fib.x * t, fib.y * t, fib.z * t);
        }
    }
    let h = pm * transpose(dm_inv);
    let c0 = -(h[0] + h[1] + h[2]);
    corners[4u * e] = vec4<f32>(c0, energy);
    corners[4u * e + 1u] = vec4<f32>(h[0], select(0.0, 1.0, clamped));
    corners[4u * e + 2u] = vec4<f32>(h[1], 0.0);
    corners[4u * e + 3u] = vec4<f32>(h[2], 0.0);
}

@compute @workgroup_size(64)
fn gather_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
                 @builtin(num_workgroups) nwg: vec3<u32>) {
    let a = linear_index(gid, nwg, 64u);
    let n = params.num_nodes;
    if (a >= n) {
        return;
    }
    var sum = vec3<f32>(0.0);
    let start = incidence[a];
    let end = incidence[a + 1u];
    for (var k = start; k < end; k++) {
        sum += corners[incidence[n + 1u + k]].xyz;
    }
    out_rhs[3u * a] = sum.x;
    out_rhs[3u * a + 1u] = sum.y;
    out_rhs[3u * a + 2u] = sum.z;
}

var<workgroup> red_e: array<f32, 256>;
var<workgroup> red_c: array<f32, 256>;

@compute @workgroup_size(256)
fn reduce_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32,
                 @builtin(workgroup_id) wid: vec3<u32>,
                 @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_index(gid, nwg, 256u);
    var ev = 0.0;
    var cv = 0.0;
    if (e < params.num_tets) {
        ev = corners[4u * e].w;
        cv = corners[4u * e + 1u].w;
    }
    red_e[lid] = ev;
    red_c[lid] = cv;
    workgroupBarrier();
    for (var stride = 128u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            red_e[lid] += red_e[lid + stride];
            red_c[lid] += red_c[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        partials[wid.x + wid.y * nwg.x] = vec2<f32>(red_e[0], red_c[0]);
    }
}
