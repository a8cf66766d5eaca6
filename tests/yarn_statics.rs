//! The quasi-static Newton solver (yarn::statics) on discrete elastic rods:
//! analytic axial stretch, a cantilever under gravity against Euler-Bernoulli,
//! reaction forces balancing the load, determinism.

use knitvox::geom::Yarns;
use knitvox::yarn::rods::{RodEnergy, RodParams, RodRest, RodTopology};
use knitvox::yarn::statics::{
    reaction_forces, solve_static, EnergyTerm, GravityTerm, StaticParams, SymbolicCache,
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
    let sp = StaticParams {
        force_tolerance: 1e-10,
        ..StaticParams::default()
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
    let sp = StaticParams {
        force_tolerance: 1e-12,
        ..StaticParams::default()
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
    let sp = StaticParams {
        force_tolerance: 1e-9,
        max_displacement: 0.25 * R,
        ..StaticParams::default()
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
    let sp = StaticParams {
        force_tolerance: 1e-8,
        max_displacement: 10.0 * R,
        clip_per_vertex: true,
        ..StaticParams::default()
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
