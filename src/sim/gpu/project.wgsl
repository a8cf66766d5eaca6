// Per-node collision projection (VH §8.5 / Bouaziz et al. 2014 §5 projection
// constraints) against planes and spheres, f32: every node is pushed out of
// each collider in order (the same loop as `project_point` on the CPU).

struct Params {
    num_nodes: u32,
    num_colliders: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
// Two vec4 per collider: (point or centre, kind: 0 plane, 1 sphere) and
// (unit normal, thickness) or (radius, 0, 0, thickness).
@group(0) @binding(2) var<storage, read> colliders: array<vec4<f32>>;
// Per node: projected position, .w = 1 when it moved.
@group(0) @binding(3) var<storage, read_write> out_pos: array<vec4<f32>>;

@compute @workgroup_size(64)
fn project_kernel(@builtin(global_invocation_id) gid: vec3<u32>,
                  @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if (i >= params.num_nodes) {
        return;
    }
    var q = vec3<f32>(x[3u * i], x[3u * i + 1u], x[3u * i + 2u]);
    var moved = false;
    for (var c = 0u; c < params.num_colliders; c++) {
        let a = colliders[2u * c];
        let b = colliders[2u * c + 1u];
        if (a.w < 0.5) {
            let d = dot(q - a.xyz, b.xyz);
            if (d < b.w) {
                q = q + (b.w - d) * b.xyz;
                moved = true;
            }
        } else {
            let v = q - a.xyz;
            let l = length(v);
            let r = b.x + b.w;
            if (l < r) {
                if (l > 0.0) {
                    q = a.xyz + v * (r / l);
                } else {
                    q = a.xyz + vec3<f32>(0.0, r, 0.0);
                }
                moved = true;
            }
        }
    }
    out_pos[i] = vec4<f32>(q, select(0.0, 1.0, moved));
}
