//! Study (ignored; it takes seconds in release, minutes in debug): relax a
//! generated rib into contact with rest-length scaling (Leaf 2018 §6.1) by
//! proximal Newton solves of rods + Kaldor contact (yarn::statics), and
//! print iterations, residual and contacts per vertex.
//! `FX_SCALE=0.97 FX_ITERS=300 FX_DT=0.005 cargo test --release --test fabric_experiment -- --ignored --nocapture`
//! (measured: 6x4 rib, 814 vertices, scale 0.97: one solve of 229 Newton
//! iterations, static residual 2.6e-6 N, 0.17 contacts per vertex, min
//! distance ratio 0.988, 6.2 s).

use std::time::Instant;

use knitvox::geom::Yarns;
use knitvox::yarn::fabric::InertiaTerm;
use knitvox::yarn::pattern::{build_tile, builtin, lay_out, Layout, PatternParams};
use knitvox::yarn::rods::{RodEnergy, RodParams, RodRest, RodTopology};
use knitvox::yarn::sim::YarnSimParams;
use knitvox::yarn::statics::{
    reaction_forces, solve_static, ContactTerm, EnergyTerm, StaticParams, SymbolicCache,
};

fn env_f(name: &str, d: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

#[test]
#[ignore]
fn relax_rib_into_contact() {
    let courses = env_f("FX_COURSES", 6.0) as usize;
    let wales = env_f("FX_WALES", 4.0) as usize;
    let scale = env_f("FX_SCALE", 0.9);
    let pattern = std::env::var("FX_PATTERN").unwrap_or("rib1x1".into());
    let p = PatternParams::default();
    let r = p.yarn_radius;
    let tile = build_tile(&builtin(&pattern).unwrap(), &p).unwrap();
    let y: Yarns = lay_out(
        &tile,
        &Layout {
            courses,
            wales,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
    )
    .unwrap();
    let n = y.num_points();
    let topo = RodTopology::new(&y).unwrap();
    let mut rest = RodRest::from_positions(&topo, &y.points).unwrap();
    let factors = vec![scale; topo.num_edges()];
    rest.scale_lengths(&factors).unwrap();
    let mut q = topo.q_from_points(&y.points);
    let rp = RodParams::default();
    let mut rods = RodEnergy::new(topo.clone(), rest, &rp, &q).unwrap();
    let ysp = YarnSimParams::default();
    let mut contact = ContactTerm::new(&y, &ysp, 0.5 * r).unwrap();
    let mu = ysp.density * std::f64::consts::PI * r * r;
    let mass: Vec<f64> = vec![mu * 1.25 * r; n];
    let mut fixed = vec![false; q.len()];
    for c in &topo.curve_edges {
        fixed[topo.twist_dof(c.start)] = true;
    }
    let sp = StaticParams {
        force_tolerance: 1e-6,
        max_displacement: 0.25 * r,
        max_iterations: env_f("FX_ITERS", 100.0) as usize,
        ..StaticParams::default()
    };
    let mut cache = SymbolicCache::default();
    let t0 = Instant::now();
    let mut final_res = f64::INFINITY;
    let mut min_ratio = 0.0;
    println!("{pattern} {courses}x{wales}: {n} vertices, rest length scale {scale}");
    for round in 0..40 {
        let mut inertia = InertiaTerm::new(mass.clone(), q[..3 * n].to_vec(), env_f("FX_DT", 0.02));
        let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact, &mut inertia];
        let st = solve_static(&mut terms, &mut q, &fixed, &sp, &mut cache);
        let (it, res) = match &st {
            Ok(s) => (s.iterations, s.residual),
            Err(e) => panic!("round {round}: {e}"),
        };
        let mut terms2: Vec<&mut dyn EnergyTerm> = vec![&mut rods, &mut contact];
        let g = reaction_forces(&terms2, &q, &vec![true; q.len()]);
        let _ = &mut terms2;
        let free_res = g
            .iter()
            .zip(&fixed)
            .filter(|(_, f)| !**f)
            .map(|(g, _)| g.abs())
            .fold(0.0, f64::max);
        let cst = contact.stats(&q);
        println!(
            "round {round}: {it} its, inertia-res {res:.2e}, static residual {free_res:.3e} N, contacts/vertex {:.3}, min ratio {:.3}, {:.1} s",
            cst.contacts_per_vertex, cst.min_distance_ratio, t0.elapsed().as_secs_f64()
        );
        final_res = free_res;
        min_ratio = cst.min_distance_ratio;
        if free_res < 1e-5 {
            break;
        }
    }
    assert!(final_res < 1e-5, "not relaxed: residual {final_res} N");
    assert!(
        min_ratio > 0.75,
        "pull-through: min distance ratio {min_ratio}"
    );
}
