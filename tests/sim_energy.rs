//! The VH Eq. 7-8 element energy, its gradient and the PD local step
//! projections (VH §7.1, Eq. 26), on random tets and a small Kuhn-split
//! voxel mesh.

mod common;

use common::Rng;
use knitvox::geom::{TetMesh, Vec3};
use knitvox::sim::energy::{element_energy, ElasticModel};
use knitvox::sim::projection::{project_volume_detailed, signed_svd, SINGULAR_VALUE_FLOOR};
use knitvox::sim::{
    gradient, local_step, project_diag_sl3, project_rotation, project_volume, total_energy,
    SimError,
};
use nalgebra::{Matrix3, Rotation3, Vector3};

fn arr(v: Vector3<f64>) -> Vec3 {
    [v[0], v[1], v[2]]
}

/// A random tet with positive volume, edge scale ~`size` (m).
fn random_tet(rng: &mut Rng, size: f64) -> TetMesh {
    loop {
        let mut nodes: Vec<Vec3> = (0..4).map(|_| arr(rng.vec() * size)).collect();
        let mesh = TetMesh {
            nodes: nodes.clone(),
            tets: vec![[0, 1, 2, 3]],
        };
        let v = mesh.volume(0);
        if v.abs() < 0.02 * size.powi(3) {
            continue;
        }
        if v < 0.0 {
            nodes.swap(1, 2);
        }
        return TetMesh {
            nodes,
            tets: vec![[0, 1, 2, 3]],
        };
    }
}

/// Voxels `nx x ny x nz` of edge `h`, six Kuhn tets each (the split along the
/// (0,0,0)-(1,1,1) diagonal: corners 0, e_a, e_a + e_b, (1,1,1) for every axis
/// permutation (a, b, c), reordered to positive volume).
fn kuhn_mesh(n: [usize; 3], h: f64) -> TetMesh {
    let id = |i: usize, j: usize, k: usize| (i + (n[0] + 1) * (j + (n[1] + 1) * k)) as u32;
    let mut nodes = Vec::new();
    for k in 0..=n[2] {
        for j in 0..=n[1] {
            for i in 0..=n[0] {
                nodes.push([i as f64 * h, j as f64 * h, k as f64 * h]);
            }
        }
    }
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                for p in perms {
                    let mut c = [0usize; 3];
                    let mut corners = vec![id(i, j, k)];
                    for &axis in &p[..2] {
                        c[axis] = 1;
                        corners.push(id(i + c[0], j + c[1], k + c[2]));
                    }
                    corners.push(id(i + 1, j + 1, k + 1));
                    let mut t = [corners[0], corners[1], corners[2], corners[3]];
                    let probe = TetMesh {
                        nodes: nodes.clone(),
                        tets: vec![t],
                    };
                    if probe.volume(0) < 0.0 {
                        t.swap(1, 2);
                    }
                    tets.push(t);
                }
            }
        }
    }
    TetMesh { nodes, tets }
}

fn gammas(rng: &mut Rng, n: usize) -> (Vec<f64>, Vec<f64>) {
    let gs = (0..n).map(|_| 1e3 + 9e3 * rng.next()).collect();
    let gv = (0..n).map(|_| 1e3 + 9e3 * rng.next()).collect();
    (gs, gv)
}

/// A random smooth-ish deformation: affine map plus a per-node jitter.
fn deform(rng: &mut Rng, mesh: &TetMesh, size: f64, amount: f64) -> Vec<Vec3> {
    let a = Matrix3::identity() + rng.mat() * amount;
    let r = rng.rotation();
    let t = rng.vec() * size;
    mesh.nodes
        .iter()
        .map(|p| {
            let p = Vector3::new(p[0], p[1], p[2]);
            arr(r * (a * p) + t + rng.vec() * (0.1 * amount * size))
        })
        .collect()
}

fn norm(g: &[Vec3]) -> f64 {
    g.iter().flatten().map(|x| x * x).sum::<f64>().sqrt()
}

/// Central differences of the energy against the analytic gradient.
fn check_gradient(mesh: &TetMesh, x: &[Vec3], gs: &[f64], gv: &[f64], size: f64) {
    let model = ElasticModel::new(mesh, gs, gv).unwrap();
    let g = model.gradient(x).unwrap();
    let step = 1e-6 * size;
    let mut fd = vec![[0.0; 3]; x.len()];
    let mut xp = x.to_vec();
    for i in 0..x.len() {
        for k in 0..3 {
            xp[i][k] = x[i][k] + step;
            let ep = model.energy(&xp).unwrap();
            xp[i][k] = x[i][k] - step;
            let em = model.energy(&xp).unwrap();
            xp[i][k] = x[i][k];
            fd[i][k] = (ep - em) / (2.0 * step);
        }
    }
    let diff: Vec<Vec3> = g
        .iter()
        .zip(&fd)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect();
    let rel = norm(&diff) / norm(&g);
    assert!(norm(&g) > 0.0);
    assert!(rel < 1e-6, "relative gradient error {rel}");
}

#[test]
fn gradient_matches_finite_differences_on_random_tets() {
    let mut rng = Rng(1);
    for _ in 0..20 {
        let size = 0.05;
        let mesh = random_tet(&mut rng, size);
        let (gs, gv) = gammas(&mut rng, 1);
        let x = deform(&mut rng, &mesh, size, 0.3);
        check_gradient(&mesh, &x, &gs, &gv, size);
    }
}

#[test]
fn gradient_matches_finite_differences_on_a_kuhn_mesh() {
    let mut rng = Rng(2);
    let h = 0.01;
    let mesh = kuhn_mesh([2, 2, 1], h);
    assert_eq!(mesh.num_tets(), 24);
    for _ in 0..5 {
        let (gs, gv) = gammas(&mut rng, mesh.num_tets());
        let x = deform(&mut rng, &mesh, h, 0.25);
        check_gradient(&mesh, &x, &gs, &gv, h);
    }
    // The free-function API agrees with the model.
    let (gs, gv) = gammas(&mut rng, mesh.num_tets());
    let x = deform(&mut rng, &mesh, h, 0.25);
    let model = ElasticModel::new(&mesh, &gs, &gv).unwrap();
    assert_eq!(
        total_energy(&mesh, &x, &gs, &gv).unwrap(),
        model.energy(&x).unwrap()
    );
    assert_eq!(
        gradient(&mesh, &x, &gs, &gv).unwrap(),
        model.gradient(&x).unwrap()
    );
}

#[test]
fn zero_energy_and_force_at_rest_and_under_rigid_motion() {
    let mut rng = Rng(3);
    let h = 0.02;
    let mesh = kuhn_mesh([2, 1, 2], h);
    let (gs, gv) = gammas(&mut rng, mesh.num_tets());
    let model = ElasticModel::new(&mesh, &gs, &gv).unwrap();
    let vol: f64 = (0..mesh.num_tets()).map(|t| mesh.volume(t)).sum();
    let gmax = 1e4;
    // Scales of one unit of strain: energy gamma V, force gamma V / h.
    let (e_scale, f_scale) = (gmax * vol, gmax * vol / h);
    let mut poses = vec![mesh.nodes.clone()];
    for _ in 0..10 {
        let r = rng.rotation();
        let t = rng.vec();
        poses.push(
            mesh.nodes
                .iter()
                .map(|p| arr(r * Vector3::new(p[0], p[1], p[2]) + t))
                .collect(),
        );
    }
    for x in &poses {
        let e = model.energy(x).unwrap();
        let g = model.gradient(x).unwrap();
        assert!(e.abs() <= 1e-10 * e_scale, "energy {e}");
        assert!(norm(&g) <= 1e-10 * f_scale, "force {}", norm(&g));
    }
    // Stretch, shear and uniform scaling all cost energy, with both terms.
    for f in [
        Matrix3::from_diagonal(&Vector3::new(1.2, 1.0, 1.0)),
        Matrix3::new(1.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        Matrix3::identity() * 1.1,
        Matrix3::identity() * 0.9,
    ] {
        let x: Vec<Vec3> = mesh
            .nodes
            .iter()
            .map(|p| arr(f * Vector3::new(p[0], p[1], p[2])))
            .collect();
        let e = model.energy(&x).unwrap();
        assert!(e > 1e-4 * e_scale, "{f}: energy {e}");
        // The shape term alone and the volume term alone are positive too
        // (the shear has det 1: no volume term there).
        let only_s = ElasticModel::new(&mesh, &gs, &vec![0.0; gs.len()]).unwrap();
        let only_v = ElasticModel::new(&mesh, &vec![0.0; gs.len()], &gv).unwrap();
        assert!(only_s.energy(&x).unwrap() > 1e-4 * e_scale);
        let ev = only_v.energy(&x).unwrap();
        if (f.determinant() - 1.0).abs() > 1e-9 {
            assert!(ev > 1e-4 * e_scale, "{f}: volume energy {ev}");
        } else {
            assert!(ev <= 1e-20 * e_scale, "{f}: volume energy {ev}");
        }
    }
}

/// Random F of the kinds the local step must survive.
fn test_matrices(rng: &mut Rng) -> Vec<Matrix3<f64>> {
    let mut out = vec![
        Matrix3::zeros(),
        Matrix3::identity(),
        -Matrix3::identity(),
        Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)),
        Matrix3::from_diagonal(&Vector3::new(1e3, 1e-3, 1e-9)),
    ];
    for _ in 0..300 {
        let u = rng.rotation();
        let v = rng.rotation();
        let kind = out.len() % 6;
        let s = match kind {
            // generic
            0 => Vector3::new(
                0.2 + 2.0 * rng.next(),
                0.2 + 2.0 * rng.next(),
                0.2 + 2.0 * rng.next(),
            ),
            // nearly singular
            1 => Vector3::new(1.0 + rng.next(), 0.5 + rng.next(), 1e-9 * rng.next()),
            // inverted
            2 => Vector3::new(0.5 + rng.next(), 0.5 + rng.next(), -(0.05 + rng.next())),
            // rank 1
            3 => Vector3::new(0.1 + 3.0 * rng.next(), 0.0, 0.0),
            // rank 2
            4 => Vector3::new(0.1 + 3.0 * rng.next(), 0.1 + rng.next(), 0.0),
            // strongly compressed / stretched
            _ => Vector3::new(
                (4.0 * rng.sym()).exp(),
                (4.0 * rng.sym()).exp(),
                (4.0 * rng.sym()).exp(),
            ),
        };
        out.push(u * Matrix3::from_diagonal(&s) * v.transpose());
    }
    out
}

#[test]
fn projections_are_exact_and_finite() {
    let mut rng = Rng(4);
    let mut max_it = 0;
    for f in test_matrices(&mut rng) {
        let r = project_rotation(&f);
        let (v, p) = project_volume_detailed(&f);
        max_it = max_it.max(p.iterations);
        assert!(r.iter().chain(v.iter()).all(|x| x.is_finite()), "{f}");
        assert!(
            (r.transpose() * r - Matrix3::identity()).norm() < 1e-12,
            "{f}"
        );
        assert!((r.determinant() - 1.0).abs() < 1e-12, "{f}");
        assert!(
            (v.determinant() - 1.0).abs() < 1e-10,
            "{f}: det V {}",
            v.determinant()
        );
        // R is the closest rotation: no nearby rotation is closer.
        for _ in 0..5 {
            let q = r * Rotation3::new(rng.vec() * 1e-3).into_inner();
            assert!((f - r).norm() <= (f - q).norm() + 1e-12, "{f}");
        }
        // V is on SL(3) and, where the floor is not active, closer than the
        // uniform scaling and than SL(3) perturbations exp(M) V, tr M = 0
        // (general, not only diagonal ones).
        if !p.clamped {
            let dv = (f - v).norm();
            let det = f.determinant();
            if det > 0.0 {
                let scaled = f / det.cbrt();
                assert!(dv <= (f - scaled).norm() + 1e-12, "{f}");
            }
            for eps in [1e-2, 1e-4] {
                for _ in 0..5 {
                    let mut m = rng.mat() * eps;
                    let tr = m.trace() / 3.0;
                    for i in 0..3 {
                        m[(i, i)] -= tr;
                    }
                    let q = m.exp() * v;
                    assert!((q.determinant() - 1.0).abs() < 1e-10);
                    assert!(
                        dv <= (f - q).norm() + 1e-12,
                        "{f}: {dv} > {}",
                        (f - q).norm()
                    );
                }
            }
            // And closer than perturbed diagonals d' = d exp(e), sum e = 0.
            let svd = signed_svd(&f).unwrap();
            for _ in 0..5 {
                let e = rng.vec() * 1e-3;
                let m = e.sum() / 3.0;
                let d: Vector3<f64> = Vector3::from_fn(|i, _| p.d[i] * (e[i] - m).exp());
                let q = svd.u * Matrix3::from_diagonal(&d) * svd.v.transpose();
                assert!(dv <= (f - q).norm() + 1e-12, "{f}");
            }
        }
    }
    eprintln!("max Newton/bisection iterations of the Eq. 26 solve: {max_it}");
    assert!(max_it <= 40, "{max_it}");
}

#[test]
fn volume_projection_fixes_det_one_matrices() {
    let mut rng = Rng(5);
    for _ in 0..100 {
        let a = Matrix3::identity() + rng.mat() * 0.4;
        let det = a.determinant();
        if det <= 0.05 {
            continue;
        }
        let f = a / det.cbrt();
        let v = project_volume(&f);
        assert!((v - f).norm() <= 1e-12 * f.norm(), "{f} -> {v}");
    }
    assert_eq!(project_volume(&Matrix3::identity()), Matrix3::identity());
}

#[test]
fn degenerate_inputs_stay_finite() {
    for s in [
        [0.0, 0.0, 0.0],
        [f64::NAN, 1.0, 1.0],
        [-1.0, -2.0, 3.0],
        [1e8, 1e8, 1e-8],
        [1e-12, 1e-12, 1e6],
    ] {
        let p = project_diag_sl3(s);
        assert!(p
            .d
            .iter()
            .all(|x| x.is_finite() && *x >= SINGULAR_VALUE_FLOOR * 0.999));
        assert!(
            (p.d[0] * p.d[1] * p.d[2] - 1.0).abs() < 1e-10,
            "{s:?} {p:?}"
        );
    }
    let nan = Matrix3::from_element(f64::NAN);
    assert_eq!(project_volume(&nan), Matrix3::identity());
}

#[test]
fn strong_volume_stiffness_preserves_volume() {
    // Uniaxial stretch 1.5 along x of one tet; minimize the energy over the
    // lateral stretch mu (F = diag(1.5, mu, mu)) by golden-section search.
    let mut rng = Rng(6);
    let mesh = random_tet(&mut rng, 0.1);
    let best_mu = |gs: f64, gv: f64| {
        let energy = |mu: f64| {
            let f = Matrix3::from_diagonal(&Vector3::new(1.5, mu, mu));
            let x: Vec<Vec3> = mesh
                .nodes
                .iter()
                .map(|p| arr(f * Vector3::new(p[0], p[1], p[2])))
                .collect();
            total_energy(&mesh, &x, &[gs], &[gv]).unwrap()
        };
        let (mut a, mut b) = (0.3, 1.3);
        let g = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..100 {
            let (c, d) = (b - g * (b - a), a + g * (b - a));
            if energy(c) < energy(d) {
                b = d;
            } else {
                a = c;
            }
        }
        0.5 * (a + b)
    };
    let soft = best_mu(1e4, 0.0);
    let stiff = best_mu(1e4, 1e7);
    let vol_err = |mu: f64| (1.5 * mu * mu - 1.0).abs();
    // Shape term only: no lateral contraction (the closest rotation is I).
    assert!((soft - 1.0).abs() < 1e-6, "{soft}");
    assert!(vol_err(stiff) < 1e-2 * vol_err(soft), "{stiff} vs {soft}");
    assert!(vol_err(stiff) < 1e-2, "{stiff}");
    // The same through element_energy directly.
    let f = Matrix3::from_diagonal(&Vector3::new(1.5, stiff, stiff));
    assert!(element_energy(&f, 1.0, 0.0, 1.0) < 1e-4);
}

#[test]
fn local_step_is_thread_count_independent() {
    let mut rng = Rng(7);
    let h = 0.01;
    let mesh = kuhn_mesh([3, 3, 2], h);
    let (gs, gv) = gammas(&mut rng, mesh.num_tets());
    let model = ElasticModel::new(&mesh, &gs, &gv).unwrap();
    // Large deformation so that some tets invert and hit the floor.
    let x = deform(&mut rng, &mesh, h, 1.5);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            (
                local_step(&model, &x).unwrap(),
                model.energy(&x).unwrap(),
                model.gradient(&x).unwrap(),
            )
        })
    };
    let one = run(1);
    let four = run(4);
    assert_eq!(one.0 .0, four.0 .0);
    assert_eq!(one.1.to_bits(), four.1.to_bits());
    assert_eq!(one.2, four.2);
    let (targets, stats) = one.0;
    assert_eq!(targets.len(), mesh.num_tets());
    for t in &targets {
        assert!((t.rotation.determinant() - 1.0).abs() < 1e-12);
        assert!((t.volume.determinant() - 1.0).abs() < 1e-10);
    }
    eprintln!("local step: {stats:?}");
    assert!(stats.max_iterations <= 40);
}

#[test]
fn inconsistent_inputs_are_errors() {
    let mesh = kuhn_mesh([1, 1, 1], 0.01);
    let n = mesh.num_tets();
    let ok = vec![1e4; n];
    let bad_len = ElasticModel::new(&mesh, &ok[1..], &ok);
    assert!(matches!(bad_len, Err(SimError::Inconsistent(m)) if m.contains("gamma")));
    let mut neg = ok.clone();
    neg[2] = -1.0;
    let e = ElasticModel::new(&mesh, &ok, &neg).unwrap_err().to_string();
    assert!(e.contains("gamma_v of tet 2"), "{e}");
    let mut bad_idx = mesh.clone();
    bad_idx.tets[1][3] = 99;
    let e = ElasticModel::new(&bad_idx, &ok, &ok)
        .unwrap_err()
        .to_string();
    assert!(e.contains("tet 1 uses node 99"), "{e}");
    let mut inverted = mesh.clone();
    inverted.tets[0].swap(1, 2);
    let e = ElasticModel::new(&inverted, &ok, &ok)
        .unwrap_err()
        .to_string();
    assert!(e.contains("tet 0 has rest volume"), "{e}");
    let model = ElasticModel::new(&mesh, &ok, &ok).unwrap();
    assert!(model.energy(&mesh.nodes[1..]).is_err());
    assert!(model.gradient(&[]).is_err());
    assert!(local_step(&model, &mesh.nodes[..3]).is_err());
}
