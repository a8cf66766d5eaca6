//! The quasi-static Newton solver (yarn::statics) on discrete elastic rods:
//! analytic axial stretch, a cantilever under gravity against Euler-Bernoulli,
//! reaction forces balancing the load, determinism.

use knitvox::geom::Yarns;
use knitvox::yarn::rods::{RodEnergy, RodParams, RodRest, RodTopology};
use knitvox::yarn::statics::{
    reaction_forces, solve_static, EnergyTerm, GravityTerm, SymbolicCache, YarnStaticParams,
};

const R: f64 = 1e-3;

fn straight_rod(n: usize, len: f64) -> Yarns {
    let pts: Vec<[f64; 3]> = (0..n)
        .map(|i| [len * i as f64 / (n - 1) as f64, 0.0, 0.0])
        .collect();
    let mut y = Yarns::new();
    y.push_curve(&pts, false, R);
    y
}

/// Rods of `y` at rest with `params`, and the clamp mask of the first two and
/// (optionally) last two vertices with their edges' twists.
fn setup(y: &Yarns, params: &RodParams, clamp_end: bool) -> (RodEnergy, Vec<f64>, Vec<bool>) {
    let topo = RodTopology::new(y).unwrap();
    let rest = RodRest::from_positions(&topo, &y.points).unwrap();
    let q = topo.q_from_points(&y.points);
    let n = y.num_points();
    let mut fixed = vec![false; q.len()];
    let ne = topo.num_edges();
    let mut clamp = |v: usize| fixed[3 * v..3 * v + 3].iter_mut().for_each(|f| *f = true);
    clamp(0);
    clamp(1);
    if clamp_end {
        clamp(n - 2);
        clamp(n - 1);
    }
    fixed[topo.twist_dof(0)] = true;
    if clamp_end {
        fixed[topo.twist_dof(ne - 1)] = true;
    }
    let rods = RodEnergy::new(topo, rest, params, &q).unwrap();
    (rods, q, fixed)
}

#[test]
fn axial_stretch_matches_ea_strain() {
    let (n, len, delta) = (21, 0.1, 0.01);
    let y = straight_rod(n, len);
    let params = RodParams::default();
    let (mut rods, mut q, fixed) = setup(&y, &params, true);
    for v in [n - 2, n - 1] {
        q[3 * v] += delta;
    }
    let sp = YarnStaticParams {
        force_tolerance: 1e-10,
        ..YarnStaticParams::default()
    };
    let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods];
    let stats = solve_static(
        &mut terms,
        &mut q,
        &fixed,
        &sp,
        &mut SymbolicCache::default(),
    )
    .unwrap();
    assert!(stats.converged && stats.residual <= 1e-10, "{stats:?}");
    // Only the free span stretches: its rest length is len - 2h.
    let h = len / (n - 1) as f64;
    let ea = params.young_modulus * std::f64::consts::PI * R * R;
    let expect = ea * delta / (len - 2.0 * h);
    let react = reaction_forces(&terms, &q, &fixed);
    let right: f64 = (n - 2..n).map(|v| react[3 * v]).sum();
    let left: f64 = (0..2).map(|v| react[3 * v]).sum();
    assert!(
        (right - expect).abs() <= 1e-6 * expect,
        "{right} vs {expect}"
    );
    assert!((left + expect).abs() <= 1e-6 * expect, "{left} vs {expect}");
    // Straight stays straight.
    for v in 0..n {
        assert!(q[3 * v + 1].abs() < 1e-12 && q[3 * v + 2].abs() < 1e-12);
    }
}

fn cantilever(n: usize) -> (Vec<f64>, Vec<bool>, f64, f64, RodParams) {
    let len = 0.02;
    let y = straight_rod(n, len);
    // A stiff rod (bend scale 1) so the deflection stays small (~1% of L).
    let params = RodParams {
        bend_scale: 1.0,
        ..RodParams::default()
    };
    let (mut rods, mut q, fixed) = setup(&y, &params, false);
    let h = len / (n - 1) as f64;
    let mu = 120.0 * std::f64::consts::PI * R * R;
    let mass: Vec<f64> = (0..n)
        .map(|v| {
            if v == 0 || v == n - 1 {
                0.5 * mu * h
            } else {
                mu * h
            }
        })
        .collect();
    let total_weight: f64 = mass.iter().sum::<f64>() * 9.81;
    let mut gravity = GravityTerm {
        mass,
        g: [0.0, -9.81, 0.0],
    };
    let sp = YarnStaticParams {
        force_tolerance: 1e-12,
        ..YarnStaticParams::default()
    };
    let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut gravity];
    let stats = solve_static(
        &mut terms,
        &mut q,
        &fixed,
        &sp,
        &mut SymbolicCache::default(),
    )
    .unwrap();
    assert!(stats.converged, "{stats:?}");
    let react = reaction_forces(&terms, &q, &fixed);
    let support: f64 = (0..2).map(|v| react[3 * v + 1]).sum();
    (q, fixed, support, total_weight, params)
}

#[test]
fn cantilever_under_gravity_matches_euler_bernoulli_and_balances() {
    let n = 41;
    let (q, _, support, weight, params) = cantilever(n);
    // The clamp holds the whole weight (its own vertices' too): reactions +
    // weight = 0 up to the free forces left (<= 1e-12 N on 39 vertices).
    assert!(
        (support - weight).abs() <= 1e-6 * weight,
        "{support} vs {weight}"
    );
    // Euler-Bernoulli tip deflection w = q L^4 / (8 EI), uniform load
    // q = mu g, of the span from the middle of the clamped edge (the first
    // hinge's Voronoi region starts there: length L - h/2).
    let len = 0.02;
    let h = len / (n - 1) as f64;
    let span = len - 0.5 * h;
    let ei = params.bend_stiffness(R);
    let load = 120.0 * std::f64::consts::PI * R * R * 9.81;
    let expect = load * span.powi(4) / (8.0 * ei);
    let tip = -q[3 * (n - 1) + 1];
    assert!(expect < 0.02 * len, "small-deflection regime: {expect}");
    assert!(
        (tip - expect).abs() <= 0.01 * expect,
        "tip {tip} vs Euler-Bernoulli {expect}"
    );
}

#[test]
fn solves_are_deterministic() {
    let (a, ..) = cantilever(31);
    let (b, ..) = cantilever(31);
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

/// Yarn A along x at z = 0, yarn B along z... crossing above it at height
/// `h` (centre distance), both 2 cm long with 41 vertices.
fn crossing(h: f64) -> Yarns {
    let n = 41;
    let a: Vec<[f64; 3]> = (0..n)
        .map(|i| [-0.01 + 0.02 * i as f64 / (n - 1) as f64, 0.0, 0.0])
        .collect();
    let b: Vec<[f64; 3]> = (0..n)
        .map(|i| [0.0, h, -0.01 + 0.02 * i as f64 / (n - 1) as f64])
        .collect();
    let mut y = Yarns::new();
    y.push_curve(&a, false, R);
    y.push_curve(&b, false, R);
    y
}

#[test]
fn contact_gradient_matches_finite_differences() {
    use knitvox::yarn::sim::YarnSimParams;
    use knitvox::yarn::statics::ContactTerm;
    let y = crossing(1.5 * R);
    let term = ContactTerm::new(&y, &YarnSimParams::default(), 0.5 * R).unwrap();
    let mut q: Vec<f64> = y.points.iter().flatten().copied().collect();
    // Tilt yarn B a little so the pair is not symmetric.
    for v in 41..82 {
        q[3 * v] += 0.05 * (q[3 * v + 2]);
    }
    let mut g = vec![0.0; q.len()];
    let e0 = term.eval(&q, &mut g, None);
    assert!(e0 > 0.0);
    let mut checked = 0;
    for i in 0..q.len() {
        if g[i].abs() < 1e-9 {
            continue;
        }
        let eps = 1e-9;
        let (mut qp, mut qm) = (q.clone(), q.clone());
        qp[i] += eps;
        qm[i] -= eps;
        let mut s = vec![0.0; q.len()];
        let fd = (term.eval(&qp, &mut s, None) - term.eval(&qm, &mut s, None)) / (2.0 * eps);
        assert!(
            (fd - g[i]).abs() <= 1e-5 * g[i].abs().max(1e-6),
            "{i}: fd {fd} vs {}",
            g[i]
        );
        checked += 1;
    }
    assert!(checked >= 12, "{checked} coordinates checked");
}

/// Rods of a [`crossing`] at rest in its positions, with the two end
/// vertices and end twists of both yarns clamped: topology, rest state,
/// coordinates and the fixed mask.
fn clamped_crossing(y: &Yarns) -> (RodTopology, RodRest, Vec<f64>, Vec<bool>) {
    let topo = RodTopology::new(y).unwrap();
    let rest = RodRest::from_positions(&topo, &y.points).unwrap();
    let q = topo.q_from_points(&y.points);
    let mut fixed = vec![false; q.len()];
    for v in [0, 1, 39, 40, 41, 42, 80, 81] {
        fixed[3 * v..3 * v + 3].iter_mut().for_each(|f| *f = true);
    }
    for e in [0, 39, 40, 79] {
        fixed[topo.twist_dof(e)] = true;
    }
    (topo, rest, q, fixed)
}

#[test]
fn pressed_crossing_reaches_equilibrium_with_balanced_contact() {
    use knitvox::yarn::sim::YarnSimParams;
    use knitvox::yarn::statics::ContactTerm;
    // Centre distance 1.6 r: deep in contact (ratio 0.8); the clamped ends
    // hold both yarns, so they bend apart until contact balances bending.
    let y = crossing(1.6 * R);
    let params = RodParams {
        bend_scale: 1.0,
        ..RodParams::default()
    };
    let (topo, rest, mut q, fixed) = clamped_crossing(&y);
    let mut rods = RodEnergy::new(topo, rest, &params, &q).unwrap();
    let mut contact = ContactTerm::new(&y, &YarnSimParams::default(), 0.5 * R).unwrap();
    let sp = YarnStaticParams {
        force_tolerance: 1e-9,
        max_displacement: 0.25 * R,
        ..YarnStaticParams::default()
    };
    let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact];
    let stats = solve_static(
        &mut terms,
        &mut q,
        &fixed,
        &sp,
        &mut SymbolicCache::default(),
    )
    .unwrap();
    assert!(stats.converged, "{stats:?}");
    let react = reaction_forces(&terms, &q, &fixed);
    let fa: f64 = [0, 1, 39, 40].iter().map(|v| react[3 * v + 1]).sum();
    let fb: f64 = [41, 42, 80, 81].iter().map(|v| react[3 * v + 1]).sum();
    // Contact pushes A (below) down and B up; their clamps hold them with
    // equal and opposite forces.
    assert!(fa > 1e-6 && fb < -1e-6, "{fa} {fb}");
    assert!((fa + fb).abs() <= 1e-6 * fa, "{fa} {fb}");
    let st = contact.stats(&q);
    assert!(
        st.active_pairs > 0 && st.min_distance_ratio > 0.75,
        "{st:?}"
    );
    // They separated from the initial 0.8.
    assert!(st.min_distance_ratio > 0.8, "{st:?}");
}

#[test]
fn yarn_pulled_through_another_stops_on_it_with_large_steps_allowed() {
    use knitvox::yarn::sim::YarnSimParams;
    use knitvox::yarn::statics::ContactTerm;
    // B's middle starts 3 r above A (no contact); its clamped ends are 4 r
    // below A,
    // so its unconstrained equilibrium lies on the far side of A. Steps of
    // up to 10 r per vertex are allowed: only the contact's own move limits
    // (0.45 of each candidate pair's distance) keep B from jumping through.
    let y = crossing(3.0 * R);
    let params = RodParams {
        bend_scale: 1.0,
        ..RodParams::default()
    };
    let (topo, rest, mut q, fixed) = clamped_crossing(&y);
    // A smooth arch: the ends down by 7 r, the middle in place.
    for v in 41..82 {
        let z = q[3 * v + 2] / 0.01;
        q[3 * v + 1] -= 7.0 * R * z * z;
    }
    let mut rods = RodEnergy::new(topo, rest, &params, &q).unwrap();
    let mut contact = ContactTerm::new(&y, &YarnSimParams::default(), 10.0 * R).unwrap();
    let sp = YarnStaticParams {
        force_tolerance: 1e-8,
        max_displacement: 10.0 * R,
        clip_per_vertex: true,
        ..YarnStaticParams::default()
    };
    let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact];
    let stats = solve_static(
        &mut terms,
        &mut q,
        &fixed,
        &sp,
        &mut SymbolicCache::default(),
    )
    .unwrap();
    assert!(stats.converged, "{stats:?}");
    // B's middle (vertex 61) rests on A's middle (vertex 20), not below it.
    let gap = q[3 * 61 + 1] - q[3 * 20 + 1];
    assert!(gap > 1.5 * R, "B is {gap} m above A");
    let st = contact.stats(&q);
    assert!(
        st.active_pairs > 0 && st.min_distance_ratio > 0.75,
        "{st:?}"
    );
}

#[test]
fn contact_limits_the_moves_of_nearby_vertices_only() {
    use knitvox::yarn::sim::YarnSimParams;
    use knitvox::yarn::statics::ContactTerm;
    // Yarns crossing 3 r apart (centre distance): A's and B's middle
    // vertices may move at most 0.45 of the pair distance, 1.35 r; far
    // vertices are not limited by the crossing.
    let y = crossing(3.0 * R);
    let contact = ContactTerm::new(&y, &YarnSimParams::default(), 2.0 * R).unwrap();
    let q: Vec<f64> = y.points.iter().flatten().copied().collect();
    let mut caps = vec![1.0; y.num_points()];
    contact.limit_vertex_moves(&q, &mut caps);
    for v in [20, 61] {
        assert!(
            (caps[v] - 0.45 * 3.0 * R).abs() < 1e-12,
            "vertex {v}: cap {}",
            caps[v]
        );
    }
    // Far from the crossing only the yarn's own distant segments (beyond
    // the excluded neighbours, 4-4.5 mm along it) limit a vertex.
    for v in [0, 40, 41, 81] {
        assert!(caps[v] >= 1.75 * R, "vertex {v}: cap {}", caps[v]);
    }
}

/// Friction lagged on a [`crossing`] pressed at centre distance `h`, at
/// the given positions (also the start positions).
fn lagged_friction(
    y: &Yarns,
    q: &[f64],
    mu: f64,
    eps: f64,
) -> (
    knitvox::yarn::statics::ContactTerm,
    knitvox::yarn::statics::FrictionTerm,
) {
    use knitvox::yarn::sim::YarnSimParams;
    use knitvox::yarn::statics::{ContactTerm, FrictionParams, FrictionTerm};
    let mut contact = ContactTerm::new(y, &YarnSimParams::default(), 0.5 * R).unwrap();
    contact.begin_iteration(q);
    let mut friction = FrictionTerm::new(&FrictionParams {
        mu,
        stick_distance: eps,
        lag_updates: 1,
    });
    friction.lag(&contact, q, q);
    (contact, friction)
}

#[test]
fn friction_gradient_and_hessian_match_finite_differences_and_hessian_is_psd() {
    let y = crossing(1.6 * R);
    let q0: Vec<f64> = y.points.iter().flatten().copied().collect();
    let eps = 1e-5;
    let (_, friction) = lagged_friction(&y, &q0, 0.3, eps);
    assert!(friction.contacts().len() >= 2, "{:?}", friction.contacts());
    // Yarn B moved tangentially (x, z) by a small (stick) and a large
    // (slide) amount, plus a vertex-wise wobble so no two contacts agree.
    for (shift, label) in [(3e-6, "stick"), (4e-5, "slide")] {
        let mut q = q0.clone();
        for v in 41..82 {
            let w = (v as f64 * 0.7).sin();
            q[3 * v] += shift * (1.0 + 0.2 * w);
            q[3 * v + 1] += 1e-7 * w;
            q[3 * v + 2] -= 0.5 * shift * (1.0 - 0.3 * w);
        }
        let slips = friction.slips(&q);
        let regime = |s: &f64| if label == "stick" { *s < eps } else { *s > eps };
        assert!(slips.iter().all(regime), "{label}: slips {slips:?}");
        let n = q.len();
        let mut g = vec![0.0; n];
        let mut trip = knitvox::yarn::statics::Triplets::new();
        let e = friction.eval(&q, &mut g, Some(&mut trip));
        assert!(e > 0.0);
        let mut h = vec![0.0; n * n];
        for ((&r, &c), &v) in trip.rows.iter().zip(&trip.cols).zip(&trip.vals) {
            h[r as usize * n + c as usize] += v;
        }
        let gmax = g.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let hmax = h.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(gmax > 0.0 && hmax > 0.0);
        let dofs: Vec<usize> = (0..n).filter(|&i| g[i].abs() > 1e-6 * gmax).collect();
        assert!(dofs.len() >= 12, "{label}: {} coordinates", dofs.len());
        let step = 1e-3 * eps;
        for &i in &dofs {
            let (mut qp, mut qm) = (q.clone(), q.clone());
            qp[i] += step;
            qm[i] -= step;
            let (mut gp, mut gm) = (vec![0.0; n], vec![0.0; n]);
            let ep = friction.eval(&qp, &mut gp, None);
            let em = friction.eval(&qm, &mut gm, None);
            let fd = (ep - em) / (2.0 * step);
            assert!(
                (fd - g[i]).abs() <= 1e-5 * gmax,
                "{label} gradient {i}: fd {fd} vs {}",
                g[i]
            );
            for &j in &dofs {
                let fdh = (gp[j] - gm[j]) / (2.0 * step);
                assert!(
                    (fdh - h[j * n + i]).abs() <= 1e-4 * hmax,
                    "{label} Hessian ({j}, {i}): fd {fdh} vs {}",
                    h[j * n + i]
                );
            }
        }
        // PSD: x^T H x >= 0 for pseudo-random x.
        for k in 0..20 {
            let x: Vec<f64> = (0..n).map(|i| ((i * 7 + k * 13) as f64).sin()).collect();
            let xhx: f64 = (0..n)
                .map(|r| x[r] * (0..n).map(|c| h[r * n + c] * x[c]).sum::<f64>())
                .sum();
            assert!(xhx >= -1e-9 * hmax, "{label}: x^T H x = {xhx}");
        }
    }
    // Sliding (B shifted 1 mm along A), every contact pulls with exactly
    // its Coulomb force mu lambda (the force on segment A's vertices), and
    // the whole pull along the shift is at most sum(mu lambda).
    let mut q = q0.clone();
    for v in 41..82 {
        q[3 * v] += 1e-3;
    }
    let mut fx = 0.0;
    for c in friction.contacts() {
        let mut one = friction.clone();
        one.set_contacts(vec![*c]);
        let mut g = vec![0.0; q.len()];
        one.eval(&q, &mut g, None);
        let fa: Vec<f64> = (0..3)
            .map(|k| g[3 * c.vertices[0] + k] + g[3 * c.vertices[1] + k])
            .collect();
        let mag = (fa[0] * fa[0] + fa[1] * fa[1] + fa[2] * fa[2]).sqrt();
        let cap = 0.3 * c.normal_force;
        assert!((mag - cap).abs() <= 1e-9 * cap, "{mag} N vs {cap} N");
        fx += c.vertices[2..].iter().map(|&v| g[3 * v]).sum::<f64>();
    }
    let cap = friction.total_capacity();
    assert!(
        fx > 0.5 * cap && fx <= cap * (1.0 + 1e-12),
        "{fx} N vs {cap} N"
    );
}

#[test]
fn pressed_crossing_sticks_below_and_slides_at_coulomb_force_above() {
    use knitvox::yarn::statics::FrictionTerm;
    // B pressed onto A (centre distance 1.6 r, as above), then B's clamps
    // moved sideways along A (x) by delta in one load step: friction on the
    // crossing holds B's middle while B's lateral bending force is below
    // mu N, and B slides along A at the constant force mu N above it.
    let (mu, eps) = (0.25, 1e-5);
    let y = crossing(1.6 * R);
    let params = RodParams {
        bend_scale: 1.0,
        ..RodParams::default()
    };
    let (topo, rest, mut q0, fixed) = clamped_crossing(&y);
    let mut rods = RodEnergy::new(topo, rest, &params, &q0).unwrap();
    let (mut contact, _) = lagged_friction(&y, &q0, mu, eps);
    let sp = YarnStaticParams {
        force_tolerance: 1e-9,
        max_displacement: 0.25 * R,
        clip_per_vertex: true,
        ..YarnStaticParams::default()
    };
    let mut cache = SymbolicCache::default();
    {
        let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact];
        solve_static(&mut terms, &mut q0, &fixed, &sp, &mut cache).unwrap();
    }
    let b_clamp = [41, 42, 80, 81];
    let mut ratios = Vec::new();
    for delta in [2e-6, 5e-6, 2e-5, 1e-4, 5e-4, 1e-3, 2e-3] {
        let mut q = q0.clone();
        contact.begin_iteration(&q0);
        let mut friction = FrictionTerm::new(&knitvox::yarn::statics::FrictionParams {
            mu,
            stick_distance: eps,
            lag_updates: 2,
        });
        friction.lag(&contact, &q0, &q0);
        for v in b_clamp {
            q[3 * v] += delta;
        }
        // One solve and two lag refreshes (normal forces and contacts at
        // the new equilibrium, start positions kept).
        for refresh in 0..3 {
            if refresh > 0 {
                contact.begin_iteration(&q);
                friction.lag(&contact, &q, &q0);
            }
            let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact, &mut friction];
            let st = solve_static(&mut terms, &mut q, &fixed, &sp, &mut cache).unwrap();
            assert!(st.converged, "delta {delta}: {st:?}");
        }
        let slip = friction.slips(&q).into_iter().fold(0.0, f64::max);
        let terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact, &mut friction];
        let react = reaction_forces(&terms, &q, &fixed);
        let fx: f64 = b_clamp.iter().map(|&v| react[3 * v]).sum();
        let normal: f64 = b_clamp.iter().map(|&v| react[3 * v + 1]).sum::<f64>().abs();
        // The clamps hold B against friction: the force pulling it along.
        let ratio = fx.abs() / (mu * normal);
        // The friction force itself against its Coulomb bound mu sum(lambda)
        // (each segment pair is its own contact; the lagged sum of their
        // force magnitudes is a little above the net N where their forces
        // are not parallel).
        let mut g = vec![0.0; q.len()];
        friction.eval(&q, &mut g, None);
        let fric: f64 = (41..82).map(|v| g[3 * v]).sum();
        let of_capacity = fric.abs() / friction.total_capacity();
        eprintln!(
            "delta {delta:.1e} m: tangential {fx:.4e} N, normal {normal:.4e} N, F/(mu N) {ratio:.4}, \
             F/(mu sum lambda) {of_capacity:.4}, slip {slip:.3e} m"
        );
        ratios.push((delta, ratio, slip, of_capacity));
    }
    // Stick: well below mu N the closest points move less than eps_u.
    for &(delta, ratio, slip, _) in &ratios[..2] {
        assert!(ratio < 0.9 && slip < eps, "delta {delta}: {ratio} {slip}");
    }
    // The clamp force never exceeds mu N by more than 5%.
    assert!(ratios.iter().all(|r| r.1 <= 1.05), "{ratios:?}");
    // Slide: above, B slid along A, the friction force saturates at its
    // Coulomb bound (1%) and the clamps pull with mu N (5%).
    for &(delta, ratio, slip, of_capacity) in &ratios[ratios.len() - 4..] {
        assert!(
            of_capacity >= 0.99 && (ratio - 1.0).abs() <= 0.05 && slip > eps,
            "delta {delta}: F/(mu N) {ratio}, F/(mu sum lambda) {of_capacity}, slip {slip}"
        );
    }
}

#[test]
fn carried_offsets_keep_the_friction_force_across_a_new_lag() {
    // B shifted 3 um along A (sticking, eps_u 10 um): re-lagging there with
    // the carried offsets keeps the friction force on B; plain IPC lagging
    // (no carry) starts from zero force.
    let y = crossing(1.6 * R);
    let q0: Vec<f64> = y.points.iter().flatten().copied().collect();
    let (mut contact, friction) = lagged_friction(&y, &q0, 0.3, 1e-5);
    let mut q = q0.clone();
    for v in 41..82 {
        q[3 * v] += 3e-6;
    }
    let pull = |f: &knitvox::yarn::statics::FrictionTerm| -> f64 {
        let mut g = vec![0.0; q.len()];
        f.eval(&q, &mut g, None);
        (41..82).map(|v| g[3 * v]).sum()
    };
    let before = pull(&friction);
    assert!(before > 0.1 * friction.total_capacity(), "{before}");
    contact.begin_iteration(&q);
    let mut carried = friction.clone();
    carried.lag_carrying(&contact, &q, &q, &friction.carry(&q));
    let mut plain = friction.clone();
    plain.lag(&contact, &q, &q);
    let (after, reset) = (pull(&carried), pull(&plain));
    assert!(
        (after - before).abs() <= 0.01 * before,
        "{after} N after vs {before} N before"
    );
    assert!(reset.abs() <= 1e-12, "{reset}");
}
