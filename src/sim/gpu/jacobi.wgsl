// Chebyshev-accelerated Jacobi iterations (Wang 2015) for (A + D) x = b with
// three right-hand sides, f32. A: CSR (both triangles), D: extra diagonal.
//
//   y       = x_k + diag(A + D)^-1 (b - (A + D) x_k)        (Jacobi)
//   x_{k+1} = ω_{k+1} (y - x_{k-1}) + x_{k-1}               (Chebyshev)
//
// x_{k+1} overwrites x_{k-1} in place (each row reads only its own entry of
// x_{k-1}), so two x buffers alternate.

struct Params {
    omega: f32,
    num_rows: u32,
    // Offset (in workgroups) into `partials` for residual_kernel.
    partial_base: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// [0, n]: row starts; from n + 1: column indices.
@group(0) @binding(1) var<storage, read> idx: array<u32>;
@group(0) @binding(2) var<storage, read> val: array<f32>;
// Diagonal of A.
@group(0) @binding(3) var<storage, read> diag: array<f32>;
// Extra diagonal D (0 when none).
@group(0) @binding(4) var<storage, read> extra: array<f32>;
@group(0) @binding(5) var<storage, read> rhs: array<f32>;
@group(0) @binding(6) var<storage, read> x_cur: array<f32>;
// In: x_{k-1}; out: x_{k+1}.
@group(0) @binding(7) var<storage, read_write> x_out: array<f32>;
@group(0) @binding(8) var<storage, read_write> partials: array<f32>;

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>, wg_size: u32) -> u32 {
    return gid.x + gid.y * nwg.x * wg_size;
}

// Row r of b - (A + D) x_cur.
fn residual_row(r: u32) -> vec3<f32> {
    let n = params.num_rows;
    var ax = vec3<f32>(0.0);
    for (var k = idx[r]; k < idx[r + 1u]; k++) {
        let c = idx[n + 1u + k];
        ax += val[k] * vec3<f32>(x_cur[3u * c], x_cur[3u * c + 1u], x_cur[3u * c + 2u]);
    }
    let xr = vec3<f32>(x_cur[3u * r], x_cur[3u * r + 1u], x_cur[3u * r + 2u]);
    ax += extra[r] * xr;
    return vec3<f32>(rhs[3u * r], rhs[3u * r + 1u], rhs[3u * r + 2u]) - ax;
}

@compute @workgroup_size(64)
fn cheb_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = linear_index(gid, nwg, 64u);
    if (r >= params.num_rows) {
        return;
    }
    let res = residual_row(r);
    let xr = vec3<f32>(x_cur[3u * r], x_cur[3u * r + 1u], x_cur[3u * r + 2u]);
    let y = xr + res / (diag[r] + extra[r]);
    let prev = vec3<f32>(x_out[3u * r], x_out[3u * r + 1u], x_out[3u * r + 2u]);
    let next = params.omega * (y - prev) + prev;
    x_out[3u * r] = next.x;
    x_out[3u * r + 1u] = next.y;
    x_out[3u * r + 2u] = next.z;
}

var<workgroup> red: array<f32, 256>;

// Per workgroup of 256 rows: Σ |b - (A + D) x_cur|² (tree order, fixed).
@compute @workgroup_size(256)
fn residual_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32,
                   @builtin(workgroup_id) wid: vec3<u32>,
                   @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = linear_index(gid, nwg, 256u);
    var v = 0.0;
    if (r < params.num_rows) {
        let res = residual_row(r);
        v = dot(res, res);
    }
    red[lid] = v;
    workgroupBarrier();
    for (var stride = 128u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            red[lid] += red[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        partials[params.partial_base + wid.x + wid.y * nwg.x] = red[0];
    }
}
