//! Tension-only fibre families in the tet model (`sim::fibre`): the full
//! model's energy, gradient and Hessian, the PD local step's right-hand side,
//! the PD time loop's rest state against Newton statics, and what a fibre
//! does to a cantilever.

mod common;

use common::Rng;
use knitvox::embed::box_mesh;
use knitvox::geom::Vec3;
use knitvox::sim::backend::ElasticRhs;
use knitvox::sim::cpu::CpuElasticRhs;
use knitvox::sim::element::node_gradients;
use knitvox::sim::energy::ElasticModel;
use knitvox::sim::fibre::FibreFamily;
use knitvox::sim::pd::{PdParams, PdSolver};
use knitvox::sim::statics::{StaticParams, StaticSolver};

fn family(nt: usize, d: [f64; 3], gamma: impl Fn(usize) -> f64) -> FibreFamily {
    FibreFamily {
        directions: vec![d; nt],
        beta: Vec::new(),
        gamma: (0..nt).map(gamma).collect(),
    }
}

/// A 3x2x2 block with random Eq. 7 stiffnesses and two fibre families
/// (x and an oblique direction), stretched along x by 25% with noise.
fn stretched_block(seed: u64) -> (ElasticModel, Vec<Vec3>) {
    let (mesh, _) = box_mesh([3, 2, 2], 0.01, 120.0);
    let nt = mesh.num_tets();
    let mut rng = Rng(seed);
    let gs: Vec<f64> = (0..nt).map(|_| 100.0 * (1.0 + rng.next())).collect();
    let gv: Vec<f64> = (0..nt).map(|_| 300.0 * (1.0 + rng.next())).collect();
    let g1: Vec<f64> = (0..nt).map(|_| 2e3 * rng.next()).collect();
    let g2: Vec<f64> = (0..nt).map(|_| 1e3 * rng.next()).collect();
    let s = 1.0 / 3f64.sqrt();
    let model = ElasticModel::new(&mesh, &gs, &gv)
        .unwrap()
        .with_fibres(vec![
            family(nt, [1.0, 0.0, 0.0], |e| g1[e]),
            family(nt, [s, s, -s], |e| g2[e]),
        ])
        .unwrap();
    let x = mesh
        .nodes
        .iter()
        .map(|p| {
            [
                1.25 * p[0] + 0.002 * rng.sym(),
                p[1] + 0.1 * p[0] + 0.002 * rng.sym(),
                0.95 * p[2] + 0.002 * rng.sym(),
            ]
        })
        .collect();
    (model, x)
}

/// `steps` heavily damped PD steps of `model` from rest (the PD solver
/// built from the model's fields and fibres, which it must reproduce),
/// holding `pinned` in place: the positions and velocities reached.
fn damped_pd_rest(
    mesh: &knitvox::geom::TetMesh,
    mass: &[f64],
    model: &ElasticModel,
    pinned: &[usize],
    steps: usize,
) -> (Vec<Vec3>, Vec<Vec3>) {
    let params = PdParams {
        mass_damping: 40.0,
        max_iterations: 30,
        tolerance: 0.0,
        ..PdParams::default()
    };
    let mut pd =
        PdSolver::new(mesh, mass, model.gamma_s(), model.gamma_v(), pinned, params).unwrap();
    pd.set_fibres(model.fibres().to_vec()).unwrap();
    assert_eq!(pd.model(), model);
    let held: Vec<Vec3> = pinned.iter().map(|&i| mesh.nodes[i]).collect();
    let (mut x, mut v) = (mesh.nodes.clone(), vec![[0.0; 3]; mesh.num_nodes()]);
    for _ in 0..steps {
        pd.step(&mut x, &mut v, &held).unwrap();
    }
    (x, v)
}

/// The largest distance (m) between corresponding points.
fn largest_gap(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .fold(0.0f64, f64::max)
}

/// The model's gradient against central differences of its energy (every
/// coordinate), the element Hessians of every `stride`-th tet against
/// differences of the element stresses, and the PD right-hand side: its
/// energy is the model's, and the model's gradient is `K_el x - rhs` with
/// `K_el`'s F-space form `2 V (γs + γv) F + Σ w_k (F d_k) d_kᵀ` (`w_k` the
/// family's PD weight: `2 γ V`, or a stiffening fibre's tangent).
fn check_model_against_its_energy(model: &ElasticModel, x: &[Vec3], stride: usize) {
    let e0 = model.energy(x).unwrap();
    let g = model.gradient(x).unwrap();
    let eps = 1e-7;
    let gmax = g.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..x.len() {
        for c in 0..3 {
            let (mut p, mut q) = (x.to_vec(), x.to_vec());
            p[i][c] += eps;
            q[i][c] -= eps;
            let fd = (model.energy(&p).unwrap() - model.energy(&q).unwrap()) / (2.0 * eps);
            assert!(
                (fd - g[i][c]).abs() <= 1e-5 * gmax,
                "node {i} coord {c}: fd {fd} vs {}",
                g[i][c]
            );
        }
    }
    let fs = model.deformation_gradients(x).unwrap();
    for e in (0..model.rest().len()).step_by(stride) {
        let h = model.tet_hessian(e, &fs[e], false);
        let r = &model.rest()[e];
        for col in 0..12 {
            let (a, c) = (col / 3, col % 3);
            let mut df = nalgebra::Matrix3::zeros();
            // δF of a unit move of node a along c.
            let dsum: nalgebra::RowVector3<f64> = if a == 0 {
                -(r.dm_inv.row(0) + r.dm_inv.row(1) + r.dm_inv.row(2))
            } else {
                r.dm_inv.row(a - 1).into_owned()
            };
            df.set_row(c, &dsum);
            let step = 1e-7;
            let gp = node_gradients(&model.tet_stress(e, &(fs[e] + step * df)), &r.dm_inv);
            let gm = node_gradients(&model.tet_stress(e, &(fs[e] - step * df)), &r.dm_inv);
            for b in 0..4 {
                for k in 0..3 {
                    let fd = (gp[b][k] - gm[b][k]) / (2.0 * step);
                    let exact = h[(3 * b + k, col)];
                    assert!(
                        (fd - exact).abs() <= 1e-5 * h.norm(),
                        "tet {e} ({b},{k})/({a},{c}): fd {fd} vs {exact}"
                    );
                }
            }
        }
    }
    let mut rhs = CpuElasticRhs::new(model);
    let mut out = vec![[0.0; 3]; x.len()];
    let ev = rhs.evaluate(x, &mut out).unwrap();
    assert!(
        (ev.elastic_energy - e0).abs() <= 1e-12 * e0,
        "{} vs {e0}",
        ev.elastic_energy
    );
    let mut from_rhs = vec![[0.0; 3]; x.len()];
    let mut capped = 0;
    for (e, r) in model.rest().iter().enumerate() {
        let f = fs[e];
        let mut p = 2.0 * r.volume * (model.gamma_s()[e] + model.gamma_v()[e]) * f;
        for fam in model.fibres() {
            let d = nalgebra::Vector3::from(fam.directions[e]);
            let w = fam.pd_weight(e, r.volume);
            p += w * (f * d) * d.transpose();
            // A stiffening fibre's pull is capped at w ε (the target never
            // passes rest): the right-hand side then lacks the excess
            // (V ψ'(ε) - w ε) ŷ dᵀ of the gradient, ψ' = 2 γ ε (1 + β ε²).
            let beta = fam.beta.get(e).copied().unwrap_or(0.0);
            let y = f * d;
            let eps = y.norm() - 1.0;
            let pull = r.volume * 2.0 * fam.gamma[e] * eps * (1.0 + beta * eps * eps);
            if beta > 0.0 && eps > 0.0 && pull > w * eps {
                p += (pull - w * eps) * y.normalize() * d.transpose();
                capped += 1;
            }
        }
        for (a, gr) in node_gradients(&p, &r.dm_inv).iter().enumerate() {
            for k in 0..3 {
                from_rhs[r.nodes[a]][k] += gr[k];
            }
        }
    }
    eprintln!("fibre terms with a capped pull: {capped}");
    for (i, (fr, o)) in from_rhs.iter().zip(&out).enumerate() {
        for k in 0..3 {
            let v = fr[k] - o[k];
            assert!(
                (v - g[i][k]).abs() <= 1e-9 * gmax,
                "node {i}: {v} vs {}",
                g[i][k]
            );
        }
    }
}

#[test]
fn fibre_model_gradient_hessian_and_pd_rhs_agree_with_its_energy() {
    let (model, x) = stretched_block(1);
    let e0 = model.energy(&x).unwrap();
    let no_fibres = model.clone().with_fibres(Vec::new()).unwrap();
    let fibre_part = e0 - no_fibres.energy(&x).unwrap();
    assert!(fibre_part > 0.2 * e0, "fibres carry {fibre_part} of {e0} J");
    // The quadratic fibre's PD weight is 2 γ V (its exact local-global form).
    for fam in model.fibres() {
        for (e, r) in model.rest().iter().enumerate() {
            assert_eq!(fam.pd_weight(e, r.volume), 2.0 * r.volume * fam.gamma[e]);
        }
    }
    check_model_against_its_energy(&model, &x, 7);
}

/// A 10x2x3-voxel cantilever (x along its length, y up), clamped at x = 0,
/// under gravity: soft Eq. 7 (1 kPa, 3 kPa) with fibres of stiffness `gamma`
/// along `d`. Returns its Newton equilibrium's tip sag (m) and the model.
fn cantilever(d: [f64; 3], gamma: f64) -> (f64, ElasticModel, Vec<f64>, Vec<usize>, Vec<Vec3>) {
    let (mesh, mass) = box_mesh([10, 2, 3], 0.005, 120.0);
    let nt = mesh.num_tets();
    let model = ElasticModel::new(&mesh, &vec![1e3; nt], &vec![3e3; nt])
        .unwrap()
        .with_fibres(vec![family(nt, d, |_| gamma)])
        .unwrap();
    let pinned: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][0] < 1e-9)
        .collect();
    let f_ext: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
    let mut s = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
    let (xs, st) = s
        .solve(&mesh.nodes, &f_ext, None, &StaticParams::default())
        .unwrap();
    assert!(*st.residuals.last().unwrap() <= 1e-6, "{st:?}");
    let sag = mesh
        .nodes
        .iter()
        .zip(&xs)
        .map(|(p, q)| p[1] - q[1])
        .fold(0.0f64, f64::max);
    (sag, model, mass, pinned, xs)
}

#[test]
fn fibres_along_a_cantilever_hold_it_up_and_pd_settles_at_newtons_equilibrium() {
    let (sag_none, ..) = cantilever([1.0, 0.0, 0.0], 0.0);
    let (sag_across, ..) = cantilever([0.0, 0.0, 1.0], 3e4);
    let (sag_along, model, mass, pinned, x_newton) = cantilever([1.0, 0.0, 0.0], 3e4);
    eprintln!("tip sag: no fibres {sag_none:.5} m, across {sag_across:.5}, along {sag_along:.5}");
    // Fibres along the length carry the bending tension; across it, nothing
    // is stretched far enough to matter.
    assert!(sag_along < 0.6 * sag_none, "{sag_along} vs {sag_none}");
    assert!(sag_across > 0.9 * sag_none, "{sag_across} vs {sag_none}");

    // The PD time loop, heavily damped, comes to rest at the same shape.
    let mesh = knitvox::geom::TetMesh {
        nodes: box_mesh([10, 2, 3], 0.005, 120.0).0.nodes,
        tets: box_mesh([10, 2, 3], 0.005, 120.0).0.tets,
    };
    let (x, v) = damped_pd_rest(&mesh, &mass, &model, &pinned, 600);
    let gap = largest_gap(&x, &x_newton);
    let speed = v.iter().flatten().fold(0.0f64, |m, c| m.max(c.abs()));
    eprintln!("PD rest vs Newton: largest gap {gap:.2e} m, speed left {speed:.2e} m/s");
    assert!(gap <= 1e-5 * sag_along, "gap {gap} against sag {sag_along}");
}

/// The stiffening fibres of the knit material (`sim::knit`) in the model:
/// gradient and element Hessians against finite differences, and the PD
/// right-hand side as the quasi-Newton step `K_el x - ∇E`, with the
/// fibres' weights in `K_el` (their tangent at the reference strain).
#[test]
fn stiffening_fibre_model_gradient_hessian_and_pd_rhs_agree_with_its_energy() {
    let (quadratic, x) = stretched_block(3);
    let mut fams = quadratic.fibres().to_vec();
    let nt = quadratic.rest().len();
    fams[0].beta = (0..nt).map(|e| 40.0 + 5.0 * (e % 7) as f64).collect();
    fams[1].beta = vec![80.0; nt];
    let model = quadratic.clone().with_fibres(fams).unwrap();
    assert!(
        model.energy(&x).unwrap() > 1.05 * quadratic.energy(&x).unwrap(),
        "the stiffening adds energy at 25% stretch"
    );
    check_model_against_its_energy(&model, &x, 5);
}

/// A bar hanging from its top face under gravity, its fibres along its
/// length over a soft Eq. 7: stretched well past the PD weight's reference
/// strain at the top, the stiffening bar hangs shorter than the quadratic
/// one, and the damped PD time loop comes to rest at Newton's equilibrium.
#[test]
fn a_stiffening_bar_hangs_shorter_and_pd_settles_at_newtons_equilibrium() {
    let (mesh, mass) = box_mesh([2, 8, 2], 0.005, 120.0);
    let nt = mesh.num_tets();
    let top = mesh.nodes.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
    let pinned: Vec<usize> = (0..mesh.num_nodes())
        .filter(|&i| mesh.nodes[i][1] > top - 1e-9)
        .collect();
    let f_ext: Vec<Vec3> = mass.iter().map(|m| [0.0, -9.81 * m, 0.0]).collect();
    let hang = |beta: f64| {
        let mut fam = family(nt, [0.0, 1.0, 0.0], |_| 12.0);
        fam.beta = vec![beta; nt];
        let model = ElasticModel::new(&mesh, &vec![1.0; nt], &vec![2.0; nt])
            .unwrap()
            .with_fibres(vec![fam])
            .unwrap();
        let mut s = StaticSolver::new(model.clone(), &mass, &pinned).unwrap();
        let (xs, st) = s
            .solve(&mesh.nodes, &f_ext, None, &StaticParams::default())
            .unwrap();
        assert!(*st.residuals.last().unwrap() <= 1e-6, "{st:?}");
        let drop = mesh
            .nodes
            .iter()
            .zip(&xs)
            .map(|(p, q)| p[1] - q[1])
            .fold(0.0f64, f64::max);
        (drop, model, xs)
    };
    let (drop_quadratic, ..) = hang(0.0);
    let (drop, model, x_newton) = hang(80.0);
    let length = 8.0 * 0.005;
    eprintln!("bar of {length} m: drop {drop_quadratic:.4} m quadratic, {drop:.4} m stiffening");
    // Mean strain over the bar; the top carries twice the mean.
    assert!(drop / length > 0.12, "mean strain {}", drop / length);
    assert!(drop < 0.8 * drop_quadratic, "{drop} vs {drop_quadratic}");

    let (x, _) = damped_pd_rest(&mesh, &mass, &model, &pinned, 800);
    let gap = largest_gap(&x, &x_newton);
    eprintln!("PD rest vs Newton: largest gap {gap:.2e} m of a {drop:.4} m drop");
    assert!(gap <= 1e-4 * drop, "gap {gap} against drop {drop}");
}
