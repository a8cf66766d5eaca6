//! The GPU backend (`sim::gpu`, wgpu/Vulkan, f32) against the f64 CPU
//! references: the fused local step + elastic right-hand side against
//! `local_step` + the same gather, and the Chebyshev-Jacobi solver against a
//! CPU copy of the same iteration and against a direct Cholesky solve.
//!
//! Needs a Vulkan adapter (lavapipe on CI: `bash .ci/setup-debian test`).
//! Without one the tests are skipped loudly, and fail under CI.

mod common;

use common::Rng;
use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use knitvox::embed::tetrahedralize;
use knitvox::geom::{TetMesh, Vec3, VoxelGrid};
use knitvox::linalg::cholesky::SparseCholesky;
use knitvox::linalg::csr::CsrMatrix;
use knitvox::sim::backend::{ElasticRhs, JacobiSolve};
use knitvox::sim::cpu::CpuElasticRhs;
use knitvox::sim::element::node_gradients;
use knitvox::sim::energy::ElasticModel;
use knitvox::sim::fibre::FibreFamily;
use knitvox::sim::gpu::{
    chebyshev_omegas, GpuContext, GpuElasticRhs, GpuError, GpuJacobi, GpuJacobiParams,
};
use knitvox::sim::local::local_step;
use knitvox::sim::SimError;

/// Voxel edge of the test blocks (m).
const H: f64 = 0.01;

/// The GPU context, or `None` (test skipped) without a Vulkan adapter; under
/// CI a missing adapter fails the test, and a real device error always does.
fn gpu() -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(ctx) => {
            eprintln!(
                "GPU adapter: {} ({:?})",
                ctx.adapter_name(),
                ctx.adapter_info().device_type
            );
            Some(ctx)
        }
        Err(GpuError::Unavailable(reason)) => {
            common::require_tool(false, &format!("a Vulkan adapter ({reason})"));
            None
        }
        Err(e) => panic!("GPU context failed: {e}"),
    }
}

/// A block of `n` voxels, six Kuhn tets each.
fn block(n: [i32; 3]) -> TetMesh {
    let mut voxels = Vec::new();
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                voxels.push([i, j, k]);
            }
        }
    }
    voxels.sort();
    tetrahedralize(&VoxelGrid {
        origin: [0.0; 3],
        h: H,
        voxels,
    })
    .0
}

fn model(mesh: &TetMesh, rng: &mut Rng) -> ElasticModel {
    let nt = mesh.num_tets();
    let gs: Vec<f64> = (0..nt).map(|_| 100.0 * (1.0 + 50.0 * rng.next())).collect();
    let gv: Vec<f64> = (0..nt).map(|_| 1000.0 * (1.0 + 5.0 * rng.next())).collect();
    ElasticModel::new(mesh, &gs, &gv).unwrap()
}

/// CPU f64 reference of `ElasticRhs::evaluate`: `local_step`, then
/// `out[a] = Σ_e 2 V_e (γs R_e + γv V_e) ∇N_a^e` gathered in tet order.
fn cpu_rhs(m: &ElasticModel, x: &[Vec3]) -> (Vec<Vec3>, f64, usize) {
    let (targets, stats) = local_step(m, x).unwrap();
    let mut out = vec![[0.0; 3]; x.len()];
    for (e, (r, t)) in m.rest().iter().zip(&targets).enumerate() {
        let p = 2.0 * r.volume * (m.gamma_s()[e] * t.rotation + m.gamma_v()[e] * t.volume);
        for (a, g) in node_gradients(&p, &r.dm_inv).iter().enumerate() {
            for k in 0..3 {
                out[r.nodes[a]][k] += g[k];
            }
        }
    }
    (out, m.energy(x).unwrap(), stats.clamped)
}

fn rel_diff(a: &[Vec3], b: &[Vec3]) -> f64 {
    let (mut d, mut n) = (0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        for k in 0..3 {
            d += (p[k] - q[k]).powi(2);
            n += q[k].powi(2);
        }
    }
    (d / n).sqrt()
}

fn det_sign(x: &[Vec3], t: &[u32; 4]) -> f64 {
    let p = |i: usize| x[t[i] as usize];
    let e = |i: usize| [p(i)[0] - p(0)[0], p(i)[1] - p(0)[1], p(i)[2] - p(0)[2]];
    let (a, b, c) = (e(1), e(2), e(3));
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

#[test]
fn gpu_elastic_rhs_matches_cpu_reference() {
    let Some(ctx) = gpu() else { return };
    let mesh = block([3, 3, 3]);
    let mut rng = Rng(5);
    let m = model(&mesh, &mut rng);
    let mut gpu_rhs = GpuElasticRhs::new(&ctx, &m).unwrap();
    assert_eq!(gpu_rhs.name(), "gpu");
    let n = mesh.num_nodes();
    // A rotation about an oblique axis, applied to every pose: the rotation
    // part must not be mistaken for strain.
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let rot = |p: Vec3| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
    let poses: Vec<(&str, Vec<Vec3>)> = vec![
        (
            "mild noise",
            mesh.nodes
                .iter()
                .map(|p| {
                    rot([
                        p[0] + 0.2 * H * rng.sym(),
                        p[1] + 0.2 * H * rng.sym(),
                        p[2] + 0.2 * H * rng.sym(),
                    ])
                })
                .collect(),
        ),
        (
            "strong noise (inverted tets)",
            mesh.nodes
                .iter()
                .map(|p| {
                    [
                        p[0] + 0.9 * H * rng.sym(),
                        p[1] + 0.9 * H * rng.sym(),
                        p[2] + 0.9 * H * rng.sym(),
                    ]
                })
                .collect(),
        ),
        (
            "mirrored (every tet inverted)",
            mesh.nodes
                .iter()
                .map(|p| rot([-1.1 * p[0], p[1], 0.9 * p[2]]))
                .collect(),
        ),
        (
            "flattened (degenerate tets)",
            mesh.nodes
                .iter()
                .map(|p| rot([p[0] + 0.1 * H * rng.sym(), p[1] + 0.1 * H * rng.sym(), 0.0]))
                .collect(),
        ),
        (
            "crushed below the 0.01 floor and stretched",
            mesh.nodes
                .iter()
                .map(|p| rot([2.5 * p[0], 0.004 * p[1], 0.7 * p[2]]))
                .collect(),
        ),
    ];
    for (name, x) in &poses {
        let inverted = mesh.tets.iter().filter(|t| det_sign(x, t) < 0.0).count();
        let (cpu_out, cpu_e, cpu_clamped) = cpu_rhs(&m, x);
        let mut out = vec![[f64::NAN; 3]; n];
        let ev = gpu_rhs.evaluate(x, &mut out).unwrap();
        let err = rel_diff(&out, &cpu_out);
        let e_err = (ev.elastic_energy - cpu_e).abs() / cpu_e.abs().max(1e-300);
        eprintln!(
            "{name}: {inverted} of {} tets inverted, rhs rel err {err:.2e}, energy {cpu_e:.4e} rel err {e_err:.2e}, clamped gpu {} cpu {cpu_clamped}",
            mesh.num_tets(),
            ev.clamped_tets
        );
        assert!(err <= 1e-4, "{name}: rhs relative error {err}");
        assert!(
            e_err <= 1e-4,
            "{name}: energy {} vs {cpu_e}",
            ev.elastic_energy
        );
        assert_eq!(ev.clamped_tets, cpu_clamped, "{name}: clamped tets");
    }
    // The poses exercise what they claim.
    assert!(mesh.tets.iter().any(|t| det_sign(&poses[1].1, t) < 0.0));
    assert!(poses[4].1.len() == n);

    // The factor-2 convention of sim::pd: the energy gradient of
    // sim::energy is `Σ_e 2 V_e (γs + γv) F_e ∇N_a - out[a]`.
    let x = &poses[0].1;
    let mut out = vec![[0.0; 3]; n];
    gpu_rhs.evaluate(x, &mut out).unwrap();
    let grad = m.gradient(x).unwrap();
    let fs = m.deformation_gradients(x).unwrap();
    let mut from_rhs = vec![[0.0; 3]; n];
    for (e, r) in m.rest().iter().enumerate() {
        let p = 2.0 * r.volume * (m.gamma_s()[e] + m.gamma_v()[e]) * fs[e];
        for (a, g) in node_gradients(&p, &r.dm_inv).iter().enumerate() {
            for k in 0..3 {
                from_rhs[r.nodes[a]][k] += g[k];
            }
        }
    }
    for (f, o) in from_rhs.iter_mut().zip(&out) {
        for k in 0..3 {
            f[k] -= o[k];
        }
    }
    let g_err = rel_diff(&from_rhs, &grad);
    eprintln!("gradient from the GPU rhs vs sim::energy: rel err {g_err:.2e}");
    assert!(g_err <= 1e-4, "gradient relation: {g_err}");

    // At rest: zero energy and the rhs equals the elastic force-free one.
    let mut out = vec![[0.0; 3]; n];
    let ev = gpu_rhs.evaluate(&mesh.nodes, &mut out).unwrap();
    let (cpu_out, _, _) = cpu_rhs(&m, &mesh.nodes);
    assert!(
        ev.elastic_energy.abs() < 1e-9,
        "rest energy {}",
        ev.elastic_energy
    );
    assert!(rel_diff(&out, &cpu_out) < 1e-5);
}

#[test]
fn gpu_elastic_rhs_is_finite_on_collapsed_tets_and_checks_inputs() {
    let Some(ctx) = gpu() else { return };
    let mesh = block([2, 1, 1]);
    let mut rng = Rng(9);
    let m = model(&mesh, &mut rng);
    let mut gpu_rhs = GpuElasticRhs::new(&ctx, &m).unwrap();
    let n = mesh.num_nodes();
    let mut out = vec![[0.0; 3]; n];
    // Everything at one point (F = 0) and everything on a line (rank 1):
    // the projections are not unique there, but must be finite.
    let point = vec![[0.3, -0.2, 0.1]; n];
    let line: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| [p[0] + p[1] + p[2], 0.0, 0.0])
        .collect();
    for x in [&point, &line] {
        let ev = gpu_rhs.evaluate(x, &mut out).unwrap();
        assert!(ev.elastic_energy.is_finite() && ev.elastic_energy > 0.0);
        assert_eq!(ev.clamped_tets, mesh.num_tets());
        assert!(out.iter().flatten().all(|v| v.is_finite()));
        let (_, cpu_e, _) = cpu_rhs(&m, x);
        assert!(
            (ev.elastic_energy - cpu_e).abs() <= 1e-4 * cpu_e,
            "{} vs {cpu_e}",
            ev.elastic_energy
        );
    }
    // Bad inputs are errors, not panics.
    let mut bad = mesh.nodes.clone();
    bad[3][1] = f64::NAN;
    match gpu_rhs.evaluate(&bad, &mut out) {
        Err(SimError::Inconsistent(msg)) => assert!(msg.contains("node 3"), "{msg}"),
        other => panic!("expected an error, got {other:?}"),
    }
    assert!(gpu_rhs.evaluate(&mesh.nodes[1..], &mut out).is_err());
    // Deterministic: the same input gives bit-identical results.
    let x: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| [p[0] + 0.3 * H * rng.sym(), p[1], p[2]])
        .collect();
    let mut a = vec![[0.0; 3]; n];
    let mut b = vec![[0.0; 3]; n];
    let ea = gpu_rhs.evaluate(&x, &mut a).unwrap();
    let eb = gpu_rhs.evaluate(&x, &mut b).unwrap();
    assert_eq!(a, b);
    assert_eq!(ea, eb);
}

/// The free block of the PD matrix `K = M / Δt² + Σ_e 2 V_e (γs + γv) GᵀG`
/// (sim::pd module doc) of `mesh` with the nodes at y = 0 pinned, as CSR.
fn pd_matrix(mesh: &TetMesh, m: &ElasticModel) -> CsrMatrix {
    let dt = 1.0 / 150.0;
    let density = 200.0;
    let n = mesh.num_nodes();
    let mut free_index = vec![usize::MAX; n];
    let mut nf = 0;
    for (fi, p) in free_index.iter_mut().zip(&mesh.nodes) {
        if p[1] > 1e-9 {
            *fi = nf;
            nf += 1;
        }
    }
    let mut t = Vec::new();
    for (e, r) in m.rest().iter().enumerate() {
        let w = 2.0 * r.volume * (m.gamma_s()[e] + m.gamma_v()[e]);
        let d = r.dm_inv;
        let g1 = [d[(0, 0)], d[(0, 1)], d[(0, 2)]];
        let g2 = [d[(1, 0)], d[(1, 1)], d[(1, 2)]];
        let g3 = [d[(2, 0)], d[(2, 1)], d[(2, 2)]];
        let g0 = [
            -(g1[0] + g2[0] + g3[0]),
            -(g1[1] + g2[1] + g3[1]),
            -(g1[2] + g2[2] + g3[2]),
        ];
        let g = [g0, g1, g2, g3];
        for a in 0..4 {
            let fa = free_index[r.nodes[a]];
            if fa == usize::MAX {
                continue;
            }
            t.push((fa, fa, density * r.volume / 4.0 / (dt * dt)));
            for b in 0..4 {
                let fb = free_index[r.nodes[b]];
                if fb == usize::MAX {
                    continue;
                }
                let dot = g[a][0] * g[b][0] + g[a][1] * g[b][1] + g[a][2] * g[b][2];
                t.push((fa, fb, w * dot));
            }
        }
    }
    CsrMatrix::from_triplets(nf, &t).unwrap()
}

/// `(A + D) x` for three right-hand sides.
fn apply(a: &CsrMatrix, extra: Option<&[f64]>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; x.len()];
    a.mul_rows(x, 3, &mut y);
    if let Some(d) = extra {
        for r in 0..a.n {
            for k in 0..3 {
                y[3 * r + k] += d[r] * x[3 * r + k];
            }
        }
    }
    y
}

/// CPU f64 copy of the GPU iteration (Wang 2015): Jacobi step, then
/// `x_{k+1} = ω_{k+1} (y - x_{k-1}) + x_{k-1}`, for exactly `iterations`.
fn cpu_chebyshev(
    a: &CsrMatrix,
    extra: Option<&[f64]>,
    b: &[f64],
    x0: &[f64],
    rho: f64,
    iterations: usize,
) -> Vec<f64> {
    let diag = a.diagonal();
    let omegas = chebyshev_omegas(rho, iterations);
    let mut prev = x0.to_vec();
    let mut cur = x0.to_vec();
    for omega in omegas {
        let ax = apply(a, extra, &cur);
        let mut next = vec![0.0; cur.len()];
        for r in 0..a.n {
            let d = diag[r] + extra.map_or(0.0, |e| e[r]);
            for k in 0..3 {
                let i = 3 * r + k;
                let y = cur[i] + (b[i] - ax[i]) / d;
                next[i] = omega * (y - prev[i]) + prev[i];
            }
        }
        prev = cur;
        cur = next;
    }
    cur
}

fn cholesky_solve(a: &CsrMatrix, extra: Option<&[f64]>, b: &[f64]) -> Vec<f64> {
    let mut lower = Vec::new();
    for r in 0..a.n {
        for e in a.row_ptr[r]..a.row_ptr[r + 1] {
            let c = a.col[e];
            if r >= c {
                let add = if r == c {
                    extra.map_or(0.0, |d| d[r])
                } else {
                    0.0
                };
                lower.push(Triplet::new(r, c, a.val[e] + add));
            }
        }
    }
    let m = SparseColMat::<usize, f64>::try_new_from_triplets(a.n, a.n, &lower).unwrap();
    let f = SparseCholesky::new(m.as_ref()).unwrap();
    let mut rhs = Mat::<f64>::from_fn(a.n, 3, |r, k| b[3 * r + k]);
    f.solve_in_place(rhs.as_mut());
    (0..3 * a.n).map(|i| rhs[(i / 3, i % 3)]).collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn diff_rel(a: &[f64], b: &[f64]) -> f64 {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    norm(&d) / norm(b)
}

fn jacobi_problem(rng: &mut Rng) -> (CsrMatrix, Vec<f64>, Vec<f64>) {
    let mesh = block([3, 4, 3]);
    let m = model(&mesh, rng);
    let a = pd_matrix(&mesh, &m);
    let b: Vec<f64> = (0..3 * a.n).map(|_| rng.sym()).collect();
    let extra: Vec<f64> = (0..a.n)
        .map(|r| {
            if r % 5 == 0 {
                1e3 * (1.0 + rng.next())
            } else {
                0.0
            }
        })
        .collect();
    (a, b, extra)
}

#[test]
fn gpu_chebyshev_jacobi_matches_cpu_iteration() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(21);
    let (a, b, extra) = jacobi_problem(&mut rng);
    let x0: Vec<f64> = (0..3 * a.n).map(|_| 1e-3 * rng.sym()).collect();
    let rho = knitvox::sim::gpu::estimate_jacobi_radius(&a).unwrap();
    assert!(rho > 0.5 && rho < 1.0, "rho {rho}");
    // check_every 7 does not divide 40: the chunking must not change the
    // iteration.
    let mut solver = GpuJacobi::new(
        &ctx,
        &a,
        GpuJacobiParams {
            rho: Some(rho),
            check_every: 7,
        },
    )
    .unwrap();
    assert_eq!(solver.name(), "gpu");
    for extra in [None, Some(&extra[..])] {
        let mut x = x0.clone();
        let stats = solver.solve(&b, extra, &mut x, 0.0, 40).unwrap();
        assert_eq!(stats.iterations, 40);
        let reference = cpu_chebyshev(&a, extra, &b, &x0, rho, 40);
        let err = diff_rel(&x, &reference);
        let r = apply(&a, extra, &reference);
        let res: Vec<f64> = r.iter().zip(&b).map(|(p, q)| q - p).collect();
        let res = norm(&res) / norm(&b);
        eprintln!(
            "40 iterations (extra diag {}): gpu vs cpu rel err {err:.2e}, residual gpu {:.3e} cpu {res:.3e}",
            extra.is_some(),
            stats.relative_residual
        );
        assert!(err <= 1e-4, "GPU vs CPU Chebyshev: {err}");
        assert!(
            (stats.relative_residual - res).abs() <= 1e-3 * res.max(1e-3),
            "{} vs {res}",
            stats.relative_residual
        );
    }
}

#[test]
fn gpu_chebyshev_jacobi_converges_to_the_cholesky_solution() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(33);
    let (a, b, extra) = jacobi_problem(&mut rng);
    let mut solver = GpuJacobi::new(&ctx, &a, GpuJacobiParams::default()).unwrap();
    for extra in [None, Some(&extra[..])] {
        let exact = cholesky_solve(&a, extra, &b);
        let mut x = vec![0.0; 3 * a.n];
        let stats = solver.solve(&b, extra, &mut x, 1e-5, 5000).unwrap();
        let err = diff_rel(&x, &exact);
        eprintln!(
            "rho {:.5}: {} iterations, residual {:.2e}, error vs Cholesky {err:.2e}",
            solver.rho(),
            stats.iterations,
            stats.relative_residual
        );
        assert!(stats.relative_residual <= 1e-5, "{stats:?}");
        assert!(
            stats.iterations < 5000 && stats.iterations % 16 == 0,
            "{stats:?}"
        );
        assert!(err <= 1e-3, "error vs Cholesky {err}");
        // Warm start at the solution: no iterations.
        let mut again = x.clone();
        let s2 = solver.solve(&b, extra, &mut again, 1e-4, 100).unwrap();
        assert_eq!(s2.iterations, 0);
        assert_eq!(again, x);
    }
    // b = 0 gives x = 0; bad lengths and extra diagonals are errors.
    let mut x = vec![1.0; 3 * a.n];
    let s = solver
        .solve(&vec![0.0; 3 * a.n], None, &mut x, 1e-6, 10)
        .unwrap();
    assert_eq!((s.iterations, s.relative_residual), (0, 0.0));
    assert!(x.iter().all(|&v| v == 0.0));
    assert!(solver.solve(&b[1..], None, &mut x, 1e-6, 10).is_err());
    let neg = vec![-1.0; a.n];
    assert!(solver.solve(&b, Some(&neg), &mut x, 1e-6, 10).is_err());
    // A rho of 1 or more is refused.
    assert!(GpuJacobi::new(
        &ctx,
        &a,
        GpuJacobiParams {
            rho: Some(1.0),
            check_every: 4
        }
    )
    .is_err());
}

/// Timing at the size of a garment patch (~79K tets, ~15K nodes): one
/// elastic-rhs call and 100 Chebyshev-Jacobi iterations. A benchmark, not a
/// test: `cargo test --release --test sim_gpu -- --ignored --nocapture`.
#[test]
#[ignore = "benchmark; run in release with --ignored"]
fn bench_gpu_kernels_79k_tets() {
    use std::time::Instant;
    let Some(ctx) = gpu() else { return };
    let mesh = block([24, 24, 23]);
    let mut rng = Rng(77);
    let m = model(&mesh, &mut rng);
    let n = mesh.num_nodes();
    eprintln!(
        "mesh: {} tets, {n} nodes; adapter {}",
        mesh.num_tets(),
        ctx.adapter_name()
    );
    let x: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| {
            [
                p[0] + 0.2 * H * rng.sym(),
                p[1] + 0.2 * H * rng.sym(),
                p[2] + 0.2 * H * rng.sym(),
            ]
        })
        .collect();
    let t = Instant::now();
    let mut rhs = GpuElasticRhs::new(&ctx, &m).unwrap();
    eprintln!(
        "GpuElasticRhs::new: {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut out = vec![[0.0; 3]; n];
    rhs.evaluate(&x, &mut out).unwrap();
    let reps = 10;
    let t = Instant::now();
    for _ in 0..reps {
        rhs.evaluate(&x, &mut out).unwrap();
    }
    let gpu_ms = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let t = Instant::now();
    let (targets, _) = local_step(&m, &x).unwrap();
    let cpu_local_ms = t.elapsed().as_secs_f64() * 1e3;
    drop(targets);
    let (cpu_out, _, _) = cpu_rhs(&m, &x);
    eprintln!(
        "elastic rhs: gpu {gpu_ms:.1} ms/call (upload, local step, gather, energy, readback); \
         cpu local_step alone (f64, rayon) {cpu_local_ms:.1} ms; rel diff {:.1e}",
        rel_diff(&out, &cpu_out)
    );

    let a = pd_matrix(&mesh, &m);
    let t = Instant::now();
    let rho = knitvox::sim::gpu::estimate_jacobi_radius(&a).unwrap();
    eprintln!(
        "rho estimate {rho:.5} ({} rows): {:.1} ms",
        a.n,
        t.elapsed().as_secs_f64() * 1e3
    );
    let b: Vec<f64> = (0..3 * a.n).map(|_| rng.sym()).collect();
    for check_every in [16, 100] {
        let mut solver = GpuJacobi::new(
            &ctx,
            &a,
            GpuJacobiParams {
                rho: Some(rho),
                check_every,
            },
        )
        .unwrap();
        let mut xs = vec![0.0; 3 * a.n];
        solver.solve(&b, None, &mut xs, 0.0, 100).unwrap();
        let t = Instant::now();
        let mut stats = Default::default();
        for _ in 0..3 {
            xs.fill(0.0);
            stats = solver.solve(&b, None, &mut xs, 0.0, 100).unwrap();
        }
        eprintln!(
            "100 Chebyshev-Jacobi iterations (readback every {check_every}): {:.1} ms, residual {:.2e}",
            t.elapsed().as_secs_f64() * 1e3 / 3.0,
            stats.relative_residual
        );
    }
    let t = Instant::now();
    let _ = cpu_chebyshev(&a, None, &b, &vec![0.0; 3 * a.n], rho, 100);
    eprintln!(
        "cpu reference 100 iterations (sequential f64): {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
}

#[test]
fn gpu_node_projection_matches_cpu_loop() {
    use knitvox::sim::contact::NodeProjector;
    use knitvox::sim::gpu::{project_point, Collider, Colliders, GpuNodeProjector};
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(41);
    let n = 2000;
    let x: Vec<Vec3> = (0..n)
        .map(|_| [0.2 * rng.sym(), 0.2 * rng.sym(), 0.2 * rng.sym()])
        .collect();
    let colliders = vec![
        Collider::Plane {
            point: [0.0, -0.05, 0.0],
            normal: [0.1, 2.0, 0.0],
            thickness: 0.002,
        },
        Collider::Sphere {
            center: [0.05, 0.0, -0.02],
            radius: 0.08,
            thickness: 0.001,
        },
        Collider::Sphere {
            center: [-0.1, 0.1, 0.1],
            radius: 0.05,
            thickness: 0.0,
        },
    ];
    let mut proj = GpuNodeProjector::new(&ctx, n).unwrap();
    let mut out = vec![None; n];
    let count = proj.project_nodes(&x, &colliders, &mut out).unwrap();
    let cpu = Colliders(colliders.clone());
    let mut cpu_count = 0;
    let mut max_err: f64 = 0.0;
    for i in 0..n {
        let c = cpu.project(i, x[i]);
        cpu_count += c.is_some() as usize;
        match (c, out[i]) {
            (Some(a), Some(b)) => {
                for k in 0..3 {
                    max_err = max_err.max((a[k] - b[k]).abs());
                }
            }
            (None, None) => {}
            (a, b) => panic!("node {i} at {:?}: cpu {a:?} gpu {b:?}", x[i]),
        }
    }
    eprintln!("{count} of {n} nodes projected, max position difference {max_err:.1e} m");
    assert_eq!(count, cpu_count);
    assert!(
        count > n / 5 && count < n,
        "{count} projected: the test must exercise both cases"
    );
    assert!(max_err < 1e-6, "{max_err}");
    // A projected node is admissible: projecting again does not move it (up
    // to f64 rounding of the plane offset).
    let p = project_point(&colliders, [0.0, -0.1, 0.15]).unwrap();
    assert!(
        project_point(&colliders, p).is_none_or(|q| (0..3).all(|k| (q[k] - p[k]).abs() < 1e-12))
    );
    // Invalid colliders are refused.
    let bad = [Collider::Plane {
        point: [0.0; 3],
        normal: [0.0; 3],
        thickness: 0.0,
    }];
    assert!(proj.project_nodes(&x, &bad, &mut out).is_err());
}

#[test]
fn gpu_chebyshev_jacobi_reports_divergence() {
    let Some(ctx) = gpu() else { return };
    // SPD, but the Jacobi iteration matrix has the eigenvalue -1.8: the
    // iteration diverges, which must end in an error naming a node rather
    // than in NaN positions.
    let mut t = Vec::new();
    for i in 0..3 {
        for j in 0..3 {
            t.push((i, j, if i == j { 1.0 } else { 0.9 }));
        }
    }
    let a = CsrMatrix::from_triplets(3, &t).unwrap();
    assert!(knitvox::sim::gpu::estimate_jacobi_radius(&a).is_err());
    let mut solver = GpuJacobi::new(
        &ctx,
        &a,
        GpuJacobiParams {
            rho: Some(0.5),
            check_every: 8,
        },
    )
    .unwrap();
    let b = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let mut x = [0.0; 9];
    match solver.solve(&b, None, &mut x, 1e-6, 500) {
        Err(SimError::Diverged { node, reason, .. }) => {
            assert!(node < 3 && reason.contains("diverged"), "{node} {reason}");
        }
        other => panic!("expected divergence, got {other:?}"),
    }
}

/// Runs `steps` steps of a stretch scene on a small Kuhn-tet box (the x = 0
/// face held, the x = max face pulled 30% along +x over the run, gravity)
/// with the given solver, on the CPU or with the GPU backend attached.
fn stretch_run(
    ctx: Option<&GpuContext>,
    global: knitvox::sim::pd::GlobalSolver,
    steps: usize,
) -> Vec<Vec3> {
    stretch_run_to(ctx, global, steps, None).0
}

/// [`stretch_run`] with a fixed 8 iterations per step (`tolerance` None) or
/// iterating to `tolerance` (at most 100), with the step statistics.
fn stretch_run_to(
    ctx: Option<&GpuContext>,
    global: knitvox::sim::pd::GlobalSolver,
    steps: usize,
    tolerance: Option<f64>,
) -> (Vec<Vec3>, Vec<knitvox::sim::pd::StepStats>) {
    use knitvox::embed::box_mesh;
    use knitvox::sim::pd::{PdParams, PdSolver};
    let (mesh, mass) = box_mesh([8, 3, 4], 0.01, 200.0);
    let nt = mesh.num_tets();
    let xmax = 0.08;
    let left: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][0] <= 1e-9)
        .collect();
    let right: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][0] >= xmax - 1e-9)
        .collect();
    let pinned: Vec<usize> = left.iter().chain(&right).copied().collect();
    let params = PdParams {
        // A fixed iteration count: both runs do the same work per step.
        max_iterations: if tolerance.is_some() { 100 } else { 8 },
        tolerance: tolerance.unwrap_or(0.0),
        mass_damping: 2.0,
        global,
        ..PdParams::default()
    };
    let gamma_s: Vec<f64> = (0..nt)
        .map(|e| 1e4 * (1.0 + 0.5 * (e % 3) as f64))
        .collect();
    let gamma_v = vec![5e4; nt];
    let mut solver = PdSolver::new(&mesh, &mass, &gamma_s, &gamma_v, &pinned, params).unwrap();
    if let Some(ctx) = ctx {
        let elastic = GpuElasticRhs::new(ctx, solver.model()).unwrap();
        let jacobi: Option<Box<dyn JacobiSolve>> = match params.global {
            knitvox::sim::pd::GlobalSolver::Direct => None,
            _ => Some(Box::new(
                GpuJacobi::new(ctx, solver.free_matrix(), Default::default()).unwrap(),
            )),
        };
        solver.set_backend(Box::new(elastic), jacobi);
    }
    let mut x = mesh.nodes.clone();
    let mut v = vec![[0.0; 3]; x.len()];
    let mut stats = Vec::with_capacity(steps);
    for s in 1..=steps {
        let dx = 0.3 * xmax * s as f64 / steps as f64;
        let pins: Vec<Vec3> = left
            .iter()
            .map(|&i| mesh.nodes[i])
            .chain(right.iter().map(|&i| {
                let p = mesh.nodes[i];
                [p[0] + dx, p[1], p[2]]
            }))
            .collect();
        let st = solver.step(&mut x, &mut v, &pins).unwrap();
        assert_eq!(st.backend, if ctx.is_some() { "gpu" } else { "cpu" });
        stats.push(st);
    }
    (x, stats)
}

/// Largest node distance between two runs over the rest box diagonal.
fn relative_gap(a: &[Vec3], b: &[Vec3]) -> f64 {
    let diag = (0.08f64.powi(2) + 0.03f64.powi(2) + 0.04f64.powi(2)).sqrt();
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
        / diag
}

#[test]
fn gpu_and_cpu_stretch_runs_agree_after_100_steps() {
    let Some(ctx) = gpu() else { return };
    use knitvox::sim::dd::{DdParams, Interiors};
    // Modal interiors: the GPU Chebyshev-Jacobi does the full-space solve.
    let modal = DdParams {
        interiors: Interiors::Modes,
        ..Default::default()
    };
    for global in [
        knitvox::sim::pd::GlobalSolver::Direct,
        knitvox::sim::pd::GlobalSolver::DomainDecomposed(modal),
        knitvox::sim::pd::GlobalSolver::DomainDecomposed(Default::default()),
    ] {
        let cpu = stretch_run(None, global, 100);
        let gpu_run = stretch_run(Some(&ctx), global, 100);
        let gap = relative_gap(&cpu, &gpu_run);
        eprintln!(
            "{}: GPU vs CPU after 100 steps: {gap:.3e} of the box diagonal",
            global.name()
        );
        assert!(gap <= 1e-4, "{}: gap {gap:e}", global.name());
        // The scene did deform: the runs are not trivially equal.
        let rest = knitvox::embed::box_mesh([8, 3, 4], 0.01, 200.0).0.nodes;
        assert!(relative_gap(&cpu, &rest) > 0.05);
    }
}

/// The tolerance-based stop works on the GPU backend: at the default
/// tolerance both backends meet it on every step, in about as many
/// iterations, and end where the converged steps put them.
#[test]
fn gpu_and_cpu_runs_to_the_default_tolerance_agree() {
    let Some(ctx) = gpu() else { return };
    let tol = knitvox::sim::pd::PdParams::default().tolerance;
    let direct = knitvox::sim::pd::GlobalSolver::Direct;
    let (cpu, cpu_stats) = stretch_run_to(None, direct, 60, Some(tol));
    let (gpu_run, gpu_stats) = stretch_run_to(Some(&ctx), direct, 60, Some(tol));
    let its = |st: &[knitvox::sim::pd::StepStats]| -> u32 { st.iter().map(|s| s.iterations).sum() };
    let rejected = |st: &[knitvox::sim::pd::StepStats]| -> u32 {
        st.iter().map(|s| s.accelerations_rejected).sum()
    };
    eprintln!(
        "default tolerance {tol}: {} CPU and {} GPU iterations over 60 steps ({} and {} accelerated iterates rejected), gap {:.3e}",
        its(&cpu_stats),
        its(&gpu_stats),
        rejected(&cpu_stats),
        rejected(&gpu_stats),
        relative_gap(&cpu, &gpu_run)
    );
    for st in cpu_stats.iter().chain(&gpu_stats) {
        assert!(!st.capped && st.convergence <= tol, "{st:?}");
    }
    // The GPU's f32 right-hand side carries rounding of the size of the
    // forces on absolute positions, near this scene's tolerance late in the
    // stretch: it takes more iterations (1.9x on lavapipe), never the cap.
    let (a, b) = (f64::from(its(&cpu_stats)), f64::from(its(&gpu_stats)));
    assert!(b >= 0.8 * a && b <= 2.5 * a, "{a} vs {b} iterations");
    assert_eq!(
        rejected(&gpu_stats),
        0,
        "f32 energies rejected accelerated iterates"
    );
    // Both within the converged steps' own spread of each other: against
    // a run to a 100x tighter tolerance, each is as close as the other.
    let (tight, _) = stretch_run_to(None, direct, 60, Some(tol / 100.0));
    let (gc, gg) = (relative_gap(&cpu, &tight), relative_gap(&gpu_run, &tight));
    assert!(
        gg <= 2.0 * gc + 1e-5,
        "GPU {gg:e} vs CPU {gc:e} off the tight run"
    );
    assert!(relative_gap(&cpu, &gpu_run) <= 1e-3);
}

/// New materials (a fitted asset) are taken by the GPU backend in place:
/// its right-hand side then matches the CPU reference of the new model,
/// not the old one.
#[test]
fn gpu_elastic_rhs_takes_new_materials_in_place() {
    let Some(ctx) = gpu() else { return };
    let mesh = block([3, 2, 2]);
    let mut rng = Rng(11);
    let old = model(&mesh, &mut rng);
    let new = model(&mesh, &mut rng);
    let mut gpu_rhs = GpuElasticRhs::new(&ctx, &old).unwrap();
    let x: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| [1.2 * p[0] + 0.2 * H * rng.sym(), p[1], 0.9 * p[2]])
        .collect();
    let (cpu_old, ..) = cpu_rhs(&old, &x);
    let (cpu_new, ..) = cpu_rhs(&new, &x);
    assert!(
        rel_diff(&cpu_old, &cpu_new) > 0.1,
        "the two materials differ"
    );
    assert!(gpu_rhs.update_materials(&new).unwrap());
    let mut out = vec![[f64::NAN; 3]; mesh.num_nodes()];
    gpu_rhs.evaluate(&x, &mut out).unwrap();
    let err = rel_diff(&out, &cpu_new);
    assert!(err <= 1e-4, "rhs after the update vs the new model: {err}");
    // Another mesh's materials are refused (the caller falls back to the CPU).
    let other = model(&block([2, 2, 2]), &mut rng);
    assert!(!gpu_rhs.update_materials(&other).unwrap());
}

/// Fibre families (`sim::fibre`) on the GPU: the same right-hand side and
/// energy as the CPU backend, slack and stretched fibres both present, and
/// a material update that adds or drops them goes in place.
#[test]
fn gpu_elastic_rhs_with_fibres_matches_cpu_backend() {
    let Some(ctx) = gpu() else { return };
    let mesh = block([3, 3, 2]);
    let nt = mesh.num_tets();
    let mut rng = Rng(23);
    let plain = model(&mesh, &mut rng);
    let s = 0.5f64.sqrt();
    let fam = |d: [f64; 3], rng: &mut Rng| FibreFamily {
        directions: vec![d; nt],
        beta: Vec::new(),
        gamma: (0..nt).map(|_| 5e3 * rng.next()).collect(),
    };
    let fibred = plain
        .clone()
        .with_fibres(vec![
            fam([1.0, 0.0, 0.0], &mut rng),
            fam([0.0, s, s], &mut rng),
        ])
        .unwrap();
    // Stretched along x, compressed along y-z: some fibres taut, some slack.
    let x: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| {
            [
                1.3 * p[0] + 0.2 * H * rng.sym(),
                0.8 * p[1] + 0.1 * p[0] + 0.2 * H * rng.sym(),
                1.1 * p[2] + 0.2 * H * rng.sym(),
            ]
        })
        .collect();
    let cpu = |m: &ElasticModel| {
        let mut out = vec![[0.0; 3]; mesh.num_nodes()];
        let ev = CpuElasticRhs::new(m).evaluate(&x, &mut out).unwrap();
        (out, ev.elastic_energy)
    };
    let (cpu_plain, _) = cpu(&plain);
    let (cpu_fibred, e_fibred) = cpu(&fibred);
    assert!(
        rel_diff(&cpu_plain, &cpu_fibred) > 0.05,
        "the fibres matter"
    );
    let mut gpu_rhs = GpuElasticRhs::new(&ctx, &fibred).unwrap();
    let mut out = vec![[f64::NAN; 3]; mesh.num_nodes()];
    let ev = gpu_rhs.evaluate(&x, &mut out).unwrap();
    let err = rel_diff(&out, &cpu_fibred);
    let e_err = (ev.elastic_energy - e_fibred).abs() / e_fibred;
    eprintln!("fibres: rhs rel err {err:.2e}, energy rel err {e_err:.2e}");
    assert!(err <= 1e-4 && e_err <= 1e-4, "rhs {err}, energy {e_err}");
    // Dropping the fibres in place gives the plain model's rhs, and back.
    assert!(gpu_rhs.update_materials(&plain).unwrap());
    gpu_rhs.evaluate(&x, &mut out).unwrap();
    assert!(rel_diff(&out, &cpu_plain) <= 1e-4);
    assert!(gpu_rhs.update_materials(&fibred).unwrap());
    gpu_rhs.evaluate(&x, &mut out).unwrap();
    assert!(rel_diff(&out, &cpu_fibred) <= 1e-4);
    // The knit material's stiffening fibres: the quasi-Newton target with
    // their PD weights, on the same stretch.
    let mut fams = fibred.fibres().to_vec();
    fams[0].beta = (0..nt).map(|e| 40.0 + (e % 5) as f64 * 10.0).collect();
    fams[1].beta = vec![80.0; nt];
    let knit = plain.clone().with_fibres(fams).unwrap();
    let (cpu_knit, e_knit) = cpu(&knit);
    assert!(
        rel_diff(&cpu_knit, &cpu_fibred) > 0.01,
        "the stiffening matters"
    );
    assert!(gpu_rhs.update_materials(&knit).unwrap());
    let ev = gpu_rhs.evaluate(&x, &mut out).unwrap();
    let err = rel_diff(&out, &cpu_knit);
    let e_err = (ev.elastic_energy - e_knit).abs() / e_knit;
    eprintln!("stiffening fibres: rhs rel err {err:.2e}, energy rel err {e_err:.2e}");
    assert!(err <= 1e-4 && e_err <= 1e-4, "rhs {err}, energy {e_err}");
}

/// Friction lives in the time loop shared by both backends (`sim::pd`
/// contact targets, evaluated on the CPU): with the GPU local step (and the
/// GPU Jacobi of the modal domain-decomposed solver) the block on the 20°
/// slope still holds with friction 0.5 and slides with 0.2, as on the CPU.
#[test]
fn gpu_backend_keeps_coulomb_friction_on_a_slope() {
    let Some(ctx) = gpu() else { return };
    use knitvox::sim::dd::{DdParams, Interiors};
    use knitvox::sim::pd::GlobalSolver;
    let modal = DdParams {
        interiors: Interiors::Modes,
        ..Default::default()
    };
    for global in [GlobalSolver::Direct, GlobalSolver::DomainDecomposed(modal)] {
        let attach = |solver: &mut knitvox::sim::pd::PdSolver| {
            let elastic = GpuElasticRhs::new(&ctx, solver.model()).unwrap();
            let jacobi: Option<Box<dyn JacobiSolve>> = match global {
                GlobalSolver::Direct => None,
                _ => Some(Box::new(
                    GpuJacobi::new(&ctx, solver.free_matrix(), Default::default()).unwrap(),
                )),
            };
            solver.set_backend(Box::new(elastic), jacobi);
            assert_eq!(solver.backend_names().0, "gpu");
        };
        let (held, ..) = common::slide_on_incline(0.5, global, 150, &attach);
        let (_, slid, _) = common::slide_on_incline(0.2, global, 150, &attach);
        let (_, cpu_slid, _) = common::slide_on_incline(0.2, global, 150, &|_| {});
        eprintln!(
            "{} on the GPU: friction 0.5 moved {held:.3e} m, 0.2 slid {slid:.4} m (CPU {cpu_slid:.4} m)",
            global.name()
        );
        assert!(held < 1e-3, "friction 0.5 let the block move {held} m");
        assert!(slid > 0.5, "friction 0.2 slid only {slid} m");
        // f32 on the device: a few per cent over 0.7 m of sliding.
        assert!((slid - cpu_slid).abs() < 0.05 * cpu_slid);
    }
}

/// `--backend auto`'s cached probe agrees with opening a context: it reports
/// a hardware adapter exactly when `GpuContext::new` opens a non-CPU one
/// (lavapipe here and on CI: false), and asking again gives the same answer.
#[test]
fn hardware_probe_agrees_with_the_context() {
    let Some(ctx) = gpu() else { return };
    let probed = knitvox::sim::gpu::hardware_adapter_available();
    assert_eq!(
        probed,
        !ctx.is_cpu_adapter(),
        "adapter {}",
        ctx.adapter_name()
    );
    assert_eq!(knitvox::sim::gpu::hardware_adapter_available(), probed);
}
