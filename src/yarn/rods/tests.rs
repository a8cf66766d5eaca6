use super::*;
use crate::geom::Yarns;
use std::f64::consts::PI;

const R: f64 = 0.5e-3;

/// Deterministic pseudo-random numbers in [-1, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

fn helix(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let s = i as f64 * 0.35;
            [4e-3 * s.cos(), 4e-3 * s.sin(), 1.2e-3 * s]
        })
        .collect()
}

/// A loop like a knit stitch's: rises, turns over and comes back down,
/// weaving in depth.
fn knit_loop(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let s = i as f64 / (n - 1) as f64 * 2.0 * PI;
            [
                3e-3 * (s - 1.6 * s.sin()),
                5e-3 * (1.0 - s.cos()),
                1.5e-3 * (2.0 * s).sin(),
            ]
        })
        .collect()
}

/// A non-planar closed ring (its Bishop transport has holonomy).
fn ring(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let p = i as f64 / n as f64 * 2.0 * PI;
            // No mirror symmetry (a symmetric ring has zero total torsion).
            let r = 5e-3 * (1.0 + 0.15 * (p + 0.3).cos());
            [
                r * p.cos(),
                r * p.sin(),
                2e-3 * (3.0 * p).sin() + 1e-3 * (2.0 * p + 0.7).sin(),
            ]
        })
        .collect()
}

fn straight(n: usize, l: f64) -> Vec<Vec3> {
    (0..n).map(|i| [i as f64 * l, 0.0, 0.0]).collect()
}

/// Rod parameters with the bend/twist scale at 1 (the fabric's default; the
/// rods' own default 1e-3 would leave bending drowned by stretch).
fn full_bend() -> RodParams {
    RodParams {
        bend_scale: 1.0,
        ..RodParams::default()
    }
}

fn rods(points: &[Vec3], closed: bool, params: &RodParams) -> (RodEnergy, Vec<f64>) {
    let mut y = Yarns::new();
    y.push_curve(points, closed, R);
    let topo = RodTopology::new(&y).unwrap();
    let rest = RodRest::from_positions(&topo, &y.points).unwrap();
    let q = topo.q_from_points(&y.points);
    (RodEnergy::new(topo, rest, params, &q).unwrap(), q)
}

/// Keeps only the chosen parts (the stiffnesses differ by orders of
/// magnitude, so each part is checked on its own).
fn only(mut en: RodEnergy, stretch: bool, bend: bool, twist: bool) -> RodEnergy {
    if !stretch {
        en.ks.iter_mut().for_each(|k| *k = 0.0);
    }
    for k in en.hinge_k.iter_mut() {
        if !bend {
            k[0] = 0.0;
        }
        if !twist {
            k[1] = 0.0;
        }
    }
    en
}

fn perturb(q: &[f64], n_pos: usize, amp: f64, twist_amp: f64, seed: u64) -> Vec<f64> {
    let mut rng = Lcg(seed);
    q.iter()
        .enumerate()
        .map(|(i, &x)| x + if i < n_pos { amp } else { twist_amp } * rng.next())
        .collect()
}

fn grad(en: &RodEnergy, q: &[f64]) -> (f64, Vec<f64>) {
    let mut g = vec![0.0; q.len()];
    let e = en.eval(q, &mut g, None);
    (e, g)
}

fn dense_hessian(en: &RodEnergy, q: &[f64]) -> Vec<Vec<f64>> {
    let n = q.len();
    let mut g = vec![0.0; n];
    let mut t = Triplets::new();
    en.eval(q, &mut g, Some(&mut t));
    let mut h = vec![vec![0.0; n]; n];
    for k in 0..t.len() {
        h[t.rows[k] as usize][t.cols[k] as usize] += t.vals[k];
    }
    h
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// Max-norm relative error of the gradient against central differences.
fn fd_gradient_error(en: &RodEnergy, q: &[f64], n_pos: usize) -> f64 {
    let (_, g) = grad(en, q);
    let mut fd = vec![0.0; q.len()];
    for i in 0..q.len() {
        let h = if i < n_pos { 1e-9 } else { 1e-6 };
        let (mut qp, mut qm) = (q.to_vec(), q.to_vec());
        qp[i] += h;
        qm[i] -= h;
        let mut scratch = vec![0.0; q.len()];
        let ep = en.eval(&qp, &mut scratch, None);
        let em = en.eval(&qm, &mut scratch, None);
        fd[i] = (ep - em) / (2.0 * h);
    }
    let diff: Vec<f64> = g.iter().zip(&fd).map(|(a, b)| a - b).collect();
    max_abs(&diff) / max_abs(&fd)
}

fn cases() -> Vec<(&'static str, Vec<Vec3>, bool)> {
    vec![
        ("helix", helix(14), false),
        ("knit loop", knit_loop(16), false),
        ("ring", ring(12), true),
    ]
}

#[test]
fn gradient_matches_finite_differences() {
    let params = full_bend();
    for (name, pts, closed) in cases() {
        let n_pos = 3 * pts.len();
        for (part, s, b, t) in [
            ("stretch", true, false, false),
            ("bend", false, true, false),
            ("twist", false, false, true),
        ] {
            let (en, q0) = rods(&pts, closed, &params);
            let en = only(en, s, b, t);
            // Perturbed positions and twists (at rest the gradient is zero
            // and a relative error means nothing; see the rest test).
            for seed in [1, 2] {
                let q = perturb(&q0, n_pos, 3e-4, 0.3, seed);
                let err = fd_gradient_error(&en, &q, n_pos);
                assert!(
                    err < 1e-5,
                    "{name} {part} seed {seed}: relative error {err:e}"
                );
            }
        }
    }
}

#[test]
fn gradient_matches_finite_differences_after_frame_updates() {
    // The reference frames move by time-parallel transport; the gradient
    // must still be that of the evaluated energy.
    let params = full_bend();
    let pts = knit_loop(12);
    let n_pos = 3 * pts.len();
    let (en, q0) = rods(&pts, false, &params);
    let mut en = only(en, false, true, true);
    let q1 = perturb(&q0, n_pos, 5e-4, 0.5, 7);
    en.accept(&q1);
    let q2 = perturb(&q1, n_pos, 2e-4, 0.2, 8);
    let err = fd_gradient_error(&en, &q2, n_pos);
    assert!(err < 1e-5, "relative error {err:e}");
}

#[test]
fn exact_hessian_matches_finite_differences_of_gradient() {
    let params = full_bend();
    for (name, pts, closed) in cases() {
        let n_pos = 3 * pts.len();
        for (part, s, b, t) in [
            ("stretch", true, false, false),
            ("bend", false, true, false),
            ("twist", false, false, true),
        ] {
            let (en, q0) = rods(&pts, closed, &params);
            let mut en = only(en, s, b, t);
            en.hessian = HingeHessian::Exact;
            let q = perturb(&q0, n_pos, 3e-4, 0.3, 3);
            let h = dense_hessian(&en, &q);
            let v = perturb(&vec![0.0; q.len()], n_pos, 1.0, 1.0, 4);
            let hv: Vec<f64> = h
                .iter()
                .map(|row| row.iter().zip(&v).map(|(a, b)| a * b).sum())
                .collect();
            // Positions step 1e-9 m, twists 1e-6 rad along v.
            let step: Vec<f64> = v
                .iter()
                .enumerate()
                .map(|(i, x)| x * if i < n_pos { 1e-9 } else { 1e-6 })
                .collect();
            let qp: Vec<f64> = q.iter().zip(&step).map(|(a, b)| a + b).collect();
            let qm: Vec<f64> = q.iter().zip(&step).map(|(a, b)| a - b).collect();
            let (_, gp) = grad(&en, &qp);
            let (_, gm) = grad(&en, &qm);
            // H (D v) with D the per-coordinate step scale.
            let hdv: Vec<f64> = h
                .iter()
                .map(|row| row.iter().zip(&step).map(|(a, b)| a * b).sum())
                .collect();
            let fd: Vec<f64> = gp.iter().zip(&gm).map(|(a, b)| (a - b) / 2.0).collect();
            let diff: Vec<f64> = hdv.iter().zip(&fd).map(|(a, b)| a - b).collect();
            let err = max_abs(&diff) / max_abs(&fd);
            assert!(err < 1e-5, "{name} {part}: relative error {err:e}");
            // Symmetric.
            let n = q.len();
            for i in 0..n {
                for j in 0..n {
                    assert!((h[i][j] - h[j][i]).abs() <= 1e-9 * max_abs(&hv).max(1e-300));
                }
            }
        }
    }
}

/// Smallest eigenvalue of a dense symmetric matrix.
fn min_eigenvalue(h: &[Vec<f64>]) -> (f64, f64) {
    let n = h.len();
    let m = nalgebra::DMatrix::from_fn(n, n, |i, j| h[i][j]);
    let e = m.symmetric_eigen().eigenvalues;
    (e.min(), e.iter().fold(0.0f64, |a, b| a.max(b.abs())))
}

#[test]
fn pushed_hessian_is_positive_semidefinite() {
    let params = full_bend();
    for (name, pts, closed) in cases() {
        let n_pos = 3 * pts.len();
        let (en, q0) = rods(&pts, closed, &params);
        // Compressed edges and strongly bent/twisted hinges make the exact
        // Hessian indefinite.
        let q = perturb(&q0, n_pos, 5e-4, 1.5, 5);
        let mut exact = en.clone();
        exact.hessian = HingeHessian::Exact;
        let (lo_exact, _) = min_eigenvalue(&dense_hessian(&exact, &q));
        for model in [HingeHessian::Projected, HingeHessian::GaussNewton] {
            let mut en = en.clone();
            en.set_hinge_hessian(model);
            let (lo, scale) = min_eigenvalue(&dense_hessian(&en, &q));
            assert!(
                lo_exact < -1e-6 * scale,
                "{name}: test should start indefinite"
            );
            assert!(
                lo >= -1e-10 * scale,
                "{name} {model:?}: min eigenvalue {lo:e} (scale {scale:e})"
            );
        }
    }
}

/// Every hinge's strains `d` (`frame::hinge_strains`) at `q` in the frames
/// of the rods' current state, and their weights.
fn strains(en: &RodEnergy, q: &[f64]) -> Vec<([f64; 5], [f64; 5])> {
    (0..en.topo.num_hinges())
        .map(|k| {
            let c = en.hinge_const(k);
            let (e, th) = en.hinge_vars(q, k);
            let f0 = edge_frame(e[0], th[0], c.tp[0], c.up[0]);
            let f1 = edge_frame(e[1], th[1], c.tp[1], c.up[1]);
            (hinge_strains(&f0, &f1, &c).0, c.strain_weights())
        })
        .collect()
}

/// The Gauss-Newton hinge Hessian is `2 sum_k w_k grad d_k grad d_k^T`:
/// its quadratic form along a direction `v` equals `2 sum w_k (D d_k[v])^2`
/// with the strains' directional derivatives taken by central differences.
/// At a rest configuration (all strains zero) it is the exact Hessian.
#[test]
fn gauss_newton_hessian_is_the_strain_jacobian_product() {
    let params = full_bend();
    for (name, pts, closed) in cases() {
        let n_pos = 3 * pts.len();
        let (en, q0) = rods(&pts, closed, &params);
        let mut gn = only(en, false, true, true);
        gn.set_hinge_hessian(HingeHessian::GaussNewton);
        let mut exact = gn.clone();
        exact.hessian = HingeHessian::Exact;
        let (h_rest, h_exact) = (dense_hessian(&gn, &q0), dense_hessian(&exact, &q0));
        let scale = max_abs(&h_exact.concat());
        let diff = h_rest
            .iter()
            .flatten()
            .zip(h_exact.iter().flatten())
            .fold(0.0, |m: f64, (a, b)| m.max((a - b).abs()));
        assert!(
            diff <= 1e-9 * scale,
            "{name}: at rest GN - exact {diff:e} (scale {scale:e})"
        );
        let q = perturb(&q0, n_pos, 3e-4, 0.3, 7);
        let h = dense_hessian(&gn, &q);
        for seed in [11, 12] {
            let v = perturb(&vec![0.0; q.len()], n_pos, 1.0, 1.0, seed);
            let vhv: f64 = h
                .iter()
                .zip(&v)
                .map(|(row, vi)| vi * row.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>())
                .sum();
            let step = 1e-7;
            let at = |t: f64| -> Vec<([f64; 5], [f64; 5])> {
                let qt: Vec<f64> = q.iter().zip(&v).map(|(a, b)| a + t * b).collect();
                strains(&gn, &qt)
            };
            let (plus, minus) = (at(step), at(-step));
            let mut fd = 0.0;
            for ((dp, w), (dm, _)) in plus.iter().zip(&minus) {
                for k in 0..5 {
                    let dd = (dp[k] - dm[k]) / (2.0 * step);
                    fd += 2.0 * w[k] * dd * dd;
                }
            }
            assert!(
                (vhv - fd).abs() <= 1e-6 * fd.abs(),
                "{name} v{seed}: v^T H v {vhv:e} against {fd:e}"
            );
            assert!(vhv > 0.0, "{name}: no bend/twist along v");
        }
    }
}

#[test]
fn rest_configuration_has_zero_energy_and_gradient() {
    let params = full_bend();
    for (name, pts, closed) in cases() {
        let (en, q) = rods(&pts, closed, &params);
        let (e, g) = grad(&en, &q);
        let ks = params.stretch_stiffness(R);
        assert!(e.abs() < 1e-20, "{name}: rest energy {e:e}");
        assert!(
            max_abs(&g) < 1e-10 * ks,
            "{name}: rest gradient {:e}",
            max_abs(&g)
        );
        let n_open = en.rest().m_bar.len() - usize::from(closed);
        assert!(
            en.rest().m_bar[..n_open].iter().all(|m| m.abs() < 1e-12),
            "{name}: Bishop frames have no rest twist at open hinges"
        );
        if closed {
            // The wavy ring's transport does not close up: its holonomy sits
            // in the closing hinge's rest twist.
            let hol = *en.rest().m_bar.last().unwrap();
            assert!(hol.abs() > 1e-3, "{name}: holonomy {hol}");
        }
        // And the same after a frame update at rest.
        let mut en2 = en.clone();
        en2.begin_iteration(&q);
        let (e2, g2) = grad(&en2, &q);
        assert!(
            e2.abs() < 1e-20 && max_abs(&g2) < 1e-10 * ks,
            "{name}: after update"
        );
    }
}

/// Rotation matrix about unit axis `a` by angle `t` (Rodrigues).
fn rotation(a: Vec3, t: f64) -> [[f64; 3]; 3] {
    let (s, c) = t.sin_cos();
    let mut m = [[0.0; 3]; 3];
    let k = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]];
    for i in 0..3 {
        for j in 0..3 {
            let id = if i == j { 1.0 } else { 0.0 };
            m[i][j] = c * id + s * k[i][j] + (1.0 - c) * a[i] * a[j];
        }
    }
    m
}

fn rot(m: &[[f64; 3]; 3], v: Vec3) -> Vec3 {
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

#[test]
fn rigid_motions_cost_nothing() {
    let params = full_bend();
    let m = rotation([0.48, -0.6, 0.64], 2.1);
    let shift = [0.3, -0.1, 0.25];
    for (name, pts, closed) in cases() {
        let nv = pts.len();
        let (mut en, q0) = rods(&pts, closed, &params);
        let q = perturb(&q0, 3 * nv, 5e-4, 0.4, 9);
        en.accept(&q);
        let (e, g) = grad(&en, &q);
        // The same rods moved rigidly: positions and frames rotate, twist
        // angles stay.
        let mut moved = en.clone();
        for e in 0..moved.state.t.len() {
            moved.state.t[e] = rot(&m, moved.state.t[e]);
            moved.state.u[e] = rot(&m, moved.state.u[e]);
        }
        let mut qr = q.clone();
        for v in 0..nv {
            let p = rot(&m, [q[3 * v], q[3 * v + 1], q[3 * v + 2]]);
            for i in 0..3 {
                qr[3 * v + i] = p[i] + shift[i];
            }
        }
        let (er, gr) = grad(&moved, &qr);
        assert!((er - e).abs() <= 1e-9 * e, "{name}: {e} vs {er}");
        let mut expect = g.clone();
        for v in 0..nv {
            let p = rot(&m, [g[3 * v], g[3 * v + 1], g[3 * v + 2]]);
            expect[3 * v..3 * v + 3].copy_from_slice(&p);
        }
        let diff: Vec<f64> = gr.iter().zip(&expect).map(|(a, b)| a - b).collect();
        assert!(
            max_abs(&diff) <= 1e-8 * max_abs(&g),
            "{name}: gradient not rotated"
        );
        // Infinitesimally: a rotation w x x of the positions with material
        // frames turning along (twist change w . t_e per edge, since the
        // reference directors follow by parallel transport) and any
        // translation are zero directions of the gradient.
        let w = [0.3, -0.5, 0.8];
        let mut d = vec![0.0; q.len()];
        for v in 0..nv {
            let x = [q[3 * v], q[3 * v + 1], q[3 * v + 2]];
            let r = crate::geom::vec3::cross(w, x);
            for i in 0..3 {
                d[3 * v + i] = r[i] + shift[i];
            }
        }
        for e in 0..en.topology().num_edges() {
            d[en.topology().twist_dof(e)] = dot(w, en.state.t[e]);
        }
        let dir: f64 = g.iter().zip(&d).map(|(a, b)| a * b).sum();
        let scale: f64 = g.iter().zip(&d).map(|(a, b)| (a * b).abs()).sum();
        assert!(dir.abs() <= 1e-9 * scale, "{name}: {dir:e} vs {scale:e}");
    }
}

#[test]
fn twist_of_a_straight_rod() {
    let params = RodParams::default();
    let (n, l) = (11, 1e-3);
    let pts = straight(n, l);
    let (en, q0) = rods(&pts, false, &params);
    // Twist-free frames: no twist energy, and a rigid spin of all material
    // frames (a constant twist angle) costs nothing either.
    let mut q = q0.clone();
    assert_eq!(en.energies(&q).twist, 0.0);
    for e in 0..n - 1 {
        q[en.topology().twist_dof(e)] = 0.7;
    }
    assert!(en.energies(&q).twist.abs() < 1e-30);
    // Twisting one end by theta relative to the other, uniformly:
    // E = beta theta^2 / (2 L), L the distance between the end edges'
    // midpoints (the length the discrete twist lives on).
    let theta = 1.3;
    for e in 0..n - 1 {
        q[en.topology().twist_dof(e)] = theta * e as f64 / (n - 2) as f64;
    }
    let beta = params.twist_stiffness(R);
    let expect = beta * theta * theta / (2.0 * (n - 2) as f64 * l);
    let got = en.energies(&q);
    assert!(
        (got.twist - expect).abs() < 1e-12 * expect,
        "{} vs {expect}",
        got.twist
    );
    assert!(got.bend.abs() < 1e-30 && got.stretch.abs() < 1e-30);
}

#[test]
fn rest_curvature_is_signed() {
    // A planar arc: turning angle phi per hinge.
    let (n, rad) = (12, 6e-3);
    let phi: f64 = 0.25;
    let pts: Vec<Vec3> = (0..n)
        .map(|i| {
            let a = i as f64 * phi;
            [rad * a.sin(), rad * (1.0 - a.cos()), 0.0]
        })
        .collect();
    let params = RodParams::default();
    let (en, q0) = rods(&pts, false, &params);
    assert!(en.energies(&q0).total().abs() < 1e-24);
    // Same shape, material frames turned by pi: the arc now bends the other
    // way in its material frame, kappa -> -kappa, per hinge
    // E = 1/(2 lbar) * 2 * 1/2 B |2 kappa|^2 = 2 B kappa^2 / lbar with
    // kappa = 2 tan(phi / 2).
    let mut q = q0.clone();
    for e in 0..n - 1 {
        q[en.topology().twist_dof(e)] = PI;
    }
    let l = 2.0 * rad * (phi / 2.0).sin();
    let kappa = 2.0 * (phi / 2.0).tan();
    let b = params.bend_stiffness(R);
    let expect = (n - 2) as f64 * 2.0 * b * kappa * kappa / l;
    let got = en.energies(&q);
    assert!(
        (got.bend - expect).abs() < 1e-9 * expect,
        "{} vs {expect}",
        got.bend
    );
    assert!(got.twist.abs() < 1e-24);
    // The mirror image (same |curvature|) with the frames the rest state
    // starts it with is not at rest either (an unsigned model says 0).
    let mirror: Vec<f64> = q0
        .iter()
        .enumerate()
        .map(|(i, &x)| if i < 3 * n && i % 3 == 1 { -x } else { x })
        .collect();
    let fresh = RodEnergy::new(en.topology().clone(), en.rest().clone(), &params, &mirror).unwrap();
    let e_mirror = fresh.energies(&mirror).bend;
    assert!(
        e_mirror > 0.1 * expect,
        "mirror energy {e_mirror:e} vs {expect:e}"
    );
}

#[test]
fn reference_twist_is_continuous_over_many_steps() {
    // Two edges along x, the third on a cone of half-angle alpha about x,
    // swept round 5 times: each turn the reference twist at the last hinge
    // gains the swept solid angle 2 pi (1 - cos alpha) (parallel-transport
    // holonomy), so after 5 turns it is far outside (-pi, pi].
    let (l, alpha, turns, steps) = (1e-3, PI / 3.0, 5, 200);
    let at = |p: f64| -> Vec<Vec3> {
        vec![
            [0.0, 0.0, 0.0],
            [l, 0.0, 0.0],
            [2.0 * l, 0.0, 0.0],
            [
                2.0 * l + l * alpha.cos(),
                l * alpha.sin() * p.cos(),
                l * alpha.sin() * p.sin(),
            ],
        ]
    };
    let (mut en, _) = rods(&at(0.0), false, &RodParams::default());
    let start = en.state().ref_twist[1];
    let mut prev = start;
    for k in 1..=turns * steps {
        let q = en
            .topology()
            .q_from_points(&at(k as f64 * 2.0 * PI / steps as f64));
        en.begin_iteration(&q);
        en.accept(&q);
        let r = en.state().ref_twist[1];
        assert!((r - prev).abs() < 0.1, "jump {prev} -> {r} at step {k}");
        prev = r;
    }
    let expect = turns as f64 * 2.0 * PI * (1.0 - alpha.cos());
    let got = (prev - start).abs();
    assert!((got - expect).abs() < 1e-2 * expect, "{got} vs {expect}");
    // The twist energy follows the accumulated reference twist.
    let q = en.topology().q_from_points(&at(0.0));
    let twist = en.energies(&q).twist;
    let [_, beta, lbar] = en.hinge_k[1];
    let m = prev - start;
    assert!((twist - beta * m * m / (2.0 * lbar)).abs() < 1e-9 * twist);
}

#[test]
fn same_result_for_any_thread_count() {
    let pts = helix(2000);
    let (en, q0) = rods(&pts, false, &RodParams::default());
    let q = perturb(&q0, 3 * pts.len(), 3e-4, 0.3, 11);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut g = vec![0.0; q.len()];
            let mut t = Triplets::new();
            let e = en.eval(&q, &mut g, Some(&mut t));
            (e, g, t.vals)
        })
    };
    let (e1, g1, h1) = run(1);
    let (e2, g2, h2) = run(3);
    assert_eq!(e1.to_bits(), e2.to_bits());
    assert_eq!(g1, g2);
    assert_eq!(h1, h2);
}

#[test]
fn rest_length_scaling_and_bad_input() {
    let pts = straight(5, 1e-3);
    let mut y = Yarns::new();
    y.push_curve(&pts, false, R);
    let topo = RodTopology::new(&y).unwrap();
    assert_eq!(topo.num_dofs(), 3 * 5 + 4);
    assert_eq!(topo.twist_dof(2), 17);
    let mut rest = RodRest::from_positions(&topo, &pts).unwrap();
    rest.scale_lengths(&[0.9; 4]).unwrap();
    let q = topo.q_from_points(&pts);
    let params = RodParams::default();
    let en = RodEnergy::new(topo.clone(), rest.clone(), &params, &q).unwrap();
    // 4 edges of rest length 0.9 mm stretched to 1 mm.
    let k = params.stretch_stiffness(R);
    let l0 = 0.9e-3;
    let expect = 4.0 * 0.5 * k * l0 * (1e-3 / l0 - 1.0f64).powi(2);
    let got = en.energies(&q);
    assert!((got.stretch - expect).abs() < 1e-12 * expect);
    assert!(matches!(
        rest.scale_lengths(&[1.0; 3]),
        Err(RodError::Length { .. })
    ));
    assert!(matches!(
        rest.scale_lengths(&[1.0, -1.0, 1.0, 1.0]),
        Err(RodError::BadParameter { .. })
    ));
    // Coincident points, wrong lengths.
    let mut bad = pts.clone();
    bad[2] = bad[1];
    assert!(matches!(
        RodRest::from_positions(&topo, &bad),
        Err(RodError::DegenerateEdge { edge: 1, .. })
    ));
    assert!(matches!(
        RodEnergy::new(topo.clone(), rest.clone(), &params, &q[1..]),
        Err(RodError::Length { .. })
    ));
    let mut short = rest.clone();
    short.m_bar.pop();
    assert!(RodEnergy::new(topo, short, &params, &q).is_err());
}

#[test]
fn topology_of_open_and_closed_curves() {
    let mut y = Yarns::new();
    y.push_curve(&straight(4, 1e-3), false, R);
    y.push_curve(&ring(5), true, 2.0 * R);
    let t = RodTopology::new(&y).unwrap();
    assert_eq!(t.num_edges(), 3 + 5);
    assert_eq!(t.num_hinges(), 2 + 5);
    assert_eq!(t.edges[7], [8, 4]);
    // The closing hinge at the ring's first vertex joins its last and first
    // edges.
    assert_eq!(t.hinges[6].vertices, [8, 4, 5]);
    assert_eq!(t.hinges[6].edges, [7, 3]);
    assert_eq!(t.edge_radius[0], R);
    assert_eq!(t.edge_radius[5], 2.0 * R);
}

/// Timing of one energy + gradient + Hessian evaluation (run with
/// `--release --ignored --nocapture`).
#[test]
#[ignore]
fn bench_eval_22k_vertices() {
    let n = 22_000;
    let pts: Vec<Vec3> = (0..n)
        .map(|i| {
            let s = i as f64 * 0.35;
            [4e-3 * s.cos(), 4e-3 * s.sin(), 2e-4 * s]
        })
        .collect();
    let (en, q0) = rods(&pts, false, &RodParams::default());
    let q = perturb(&q0, 3 * n, 2e-4, 0.2, 3);
    let time = |en: &RodEnergy, with_h: bool| {
        let mut ts: Vec<f64> = (0..5)
            .map(|_| {
                let mut g = vec![0.0; q.len()];
                let mut t = Triplets::new();
                let t0 = std::time::Instant::now();
                std::hint::black_box(en.eval(&q, &mut g, with_h.then_some(&mut t)));
                t0.elapsed().as_secs_f64()
            })
            .collect();
        ts.sort_by(f64::total_cmp);
        ts[2] * 1e3
    };
    let mut exact = en.clone();
    exact.hessian = HingeHessian::Exact;
    println!(
        "rods eval {n} vertices, {} threads (median of 5): E+g+H {:.1} ms, E+g {:.1} ms, \
         E+g+H without PSD projection {:.1} ms",
        rayon::current_num_threads(),
        time(&en, true),
        time(&en, false),
        time(&exact, true),
    );
}

#[test]
fn max_step_keeps_edges_from_turning_round() {
    let pts = straight(4, 1e-3);
    let (mut en, q) = rods(&pts, false, &RodParams::default());
    en.begin_iteration(&q);
    // Moving the last vertex back by 3 mm would reverse the last edge
    // (through zero length).
    let mut dq = vec![0.0; q.len()];
    dq[9] = -3e-3;
    let alpha = en.max_step(&q, &dq);
    // t . e goes 1 mm -> 1 mm - alpha 3 mm, kept >= 0.1 mm.
    assert!((alpha - 0.3).abs() < 1e-12, "{alpha}");
    let qa: Vec<f64> = q.iter().zip(&dq).map(|(a, b)| a + alpha * b).collect();
    let (e, g) = grad(&en, &qa);
    assert!(e.is_finite() && g.iter().all(|x| x.is_finite()));
    // Small and sideways steps are not limited.
    dq[9] = 0.0;
    dq[10] = 5e-3;
    assert_eq!(en.max_step(&q, &dq), 1.0);
}

#[test]
fn set_rest_matches_a_fresh_build() {
    let pts = knit_loop(10);
    let (mut en, q0) = rods(&pts, false, &RodParams::default());
    let q = perturb(&q0, 3 * pts.len(), 2e-4, 0.2, 12);
    let mut rest = en.rest().clone();
    let factors: Vec<f64> = (0..rest.l0.len()).map(|e| 0.9 + 0.01 * e as f64).collect();
    rest.scale_lengths(&factors).unwrap();
    let fresh = RodEnergy::new(
        en.topology().clone(),
        rest.clone(),
        &RodParams::default(),
        &q0,
    )
    .unwrap();
    let before = en.energies(&q);
    en.set_rest(rest).unwrap();
    let (a, b) = (en.energies(&q), fresh.energies(&q));
    assert_eq!(a, b);
    assert!(a.stretch > before.stretch);
}
