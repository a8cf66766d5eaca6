//! `validate`'s homogenized run by projective dynamics: contacts
//! keep the carried yarns their radius outside a collider, friction holds a
//! swatch on a slope that a frictionless one slides down, and PD settles a
//! hang where the backward-Euler Newton reference does.
mod common;

use knitvox::fit::elastic::MaterialFields;
use std::sync::Arc;

use knitvox::embed::EmbedParams;
use knitvox::geom::{Asset, Vec3};
use knitvox::io::{self, ReadOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::pipeline::validate::{homogenized_run, HomogenizedRunParams, HomogenizedSolver};
use knitvox::yarn::poses::{PoseDriver, PoseKind, PoseParams};
use knitvox::yarn::sim::{PlaneCollider, PointCollider};

/// A 4 x 4 stockinette laid flat in XZ (normal +Y), embedded.
fn flat_asset() -> Asset {
    let dir = tempfile::tempdir().unwrap();
    let mut y = common::flat_swatch("stockinette", 4, 4);
    y.map_points(|p| [p[0], p[2], -p[1]]);
    let yarns = dir.path().join("flat.h5");
    io::h5::write_file(&yarns, &y, None).unwrap();
    build_asset(
        &yarns,
        &ReadOptions::default(),
        &EmbedParams::default(),
        "test",
    )
    .unwrap()
    .0
}

fn lowest_yarn(asset: &Asset) -> f64 {
    asset
        .rest_yarns
        .points
        .iter()
        .map(|p| p[1])
        .fold(f64::INFINITY, f64::min)
}

/// Mean V2Y yarn-vertex displacement (m) from node positions `from` to `to`.
fn mean_displacement(asset: &Asset, from: &[Vec3], to: &[Vec3]) -> Vec3 {
    let (a, b) = (
        asset.embedding.v2y(&asset.mesh, from),
        asset.embedding.v2y(&asset.mesh, to),
    );
    let n = a.len() as f64;
    std::array::from_fn(|k| a.iter().zip(&b).map(|(p, q)| q[k] - p[k]).sum::<f64>() / n)
}

fn free(asset: &Asset) -> PoseDriver {
    PoseDriver::new(
        &asset.rest_yarns.points,
        PoseParams::new(PoseKind::Free, 0.0),
    )
    .unwrap()
}

#[test]
fn pd_contacts_keep_every_yarn_vertex_its_radius_above_a_plane() {
    let asset = flat_asset();
    let r = asset.rest_yarns.radius_at(0);
    // The floor touches the lowest yarn surface at rest; the swatch falls
    // onto it and is pressed by gravity for 0.2 s.
    let floor: Arc<dyn PointCollider> = Arc::new(PlaneCollider {
        point: [0.0, lowest_yarn(&asset) - r, 0.0],
        normal: [0.0, 1.0, 0.0],
        friction: 0.0,
    });
    let ne = asset.mesh.num_tets();
    let times: Vec<f64> = (0..=6).map(|k| k as f64 / 30.0).collect();
    let run = homogenized_run(
        &HomogenizedRunParams::default(),
        &asset,
        &MaterialFields::uniform(ne, 1e3, 1e3),
        &free(&asset),
        [0.0, -9.81, 0.0],
        2.0,
        &times,
        &[floor],
    )
    .unwrap();
    eprintln!(
        "contacts {} penetration {:e} m, {} PD iterations",
        run.max_contacts, run.max_penetration_m, run.iterations
    );
    // Exact for a plane (validate_pd module doc): yarns touch, none sinks.
    assert!(run.max_contacts > 0, "no yarn vertex reached the floor");
    assert!(
        run.max_penetration_m < 0.02 * r,
        "{}",
        run.max_penetration_m
    );
    // Some nodes sit below the yarns they carry and must have gone below
    // the yarns' contact level: the constraint is on the yarns, not nodes.
    let last = run.frames.last().unwrap();
    let node_low = last.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    assert!(node_low < lowest_yarn(&asset) - r, "{node_low}");
}

/// Mean slide (m) down a 20° slope with friction coefficient `mu` from
/// 0.1 s (the swatch has landed) to 0.3 s.
fn slide(asset: &Asset, mu: f64) -> f64 {
    let r = asset.rest_yarns.radius_at(0);
    let th = 20f64.to_radians();
    // The slope rises along +X; it touches the lowest yarn surface under
    // the swatch's centre (the swatch starts on it, tilted relative to it).
    let n: Vec3 = [-th.sin(), th.cos(), 0.0];
    let pts = &asset.rest_yarns.points;
    let c: Vec3 = std::array::from_fn(|k| pts.iter().map(|p| p[k]).sum::<f64>() / pts.len() as f64);
    let lowest = pts
        .iter()
        .map(|p| (0..3).map(|k| (p[k] - c[k]) * n[k]).sum::<f64>())
        .fold(f64::INFINITY, f64::min);
    let point: Vec3 = std::array::from_fn(|k| c[k] + (lowest - r) * n[k]);
    let slope: Arc<dyn PointCollider> = Arc::new(PlaneCollider {
        point,
        normal: n,
        friction: mu,
    });
    let ne = asset.mesh.num_tets();
    let times: Vec<f64> = (0..=9).map(|k| k as f64 / 30.0).collect();
    let run = homogenized_run(
        // Converged PD steps: at the default 8 iterations PD's slow
        // convergence on this soft, large motion acts as damping that
        // rounding alone moves (the mu 0 slide: 64-81% of the free one at 8
        // or 16 iterations, depending on the contact solve's last digits;
        // 89-91% at 60).
        &HomogenizedRunParams {
            pd_iterations: Some(60),
            ..Default::default()
        },
        asset,
        &MaterialFields::uniform(ne, 1e4, 1e4),
        &free(asset),
        [0.0, -9.81, 0.0],
        0.0,
        &times,
        &[slope],
    )
    .unwrap();
    let d = mean_displacement(asset, &run.frames[3], &run.frames[9]);
    // Down the slope: along -(cos θ, sin θ, 0).
    -(d[0] * th.cos() + d[1] * th.sin())
}

#[test]
fn friction_holds_the_mesh_on_a_slope_a_frictionless_one_slides_down() {
    let asset = flat_asset();
    let free_slide = 0.5 * 9.81 * 20f64.to_radians().sin() * (0.3f64.powi(2) - 0.1f64.powi(2));
    let (slip, stick) = (slide(&asset, 0.0), slide(&asset, 0.6));
    eprintln!("slide 0.1-0.3 s: mu 0 {slip:.4e} m, mu 0.6 {stick:.4e} m, free {free_slide:.4e} m");
    // tan 20° = 0.36 < 0.6: static friction holds it.
    assert!(slip > 0.85 * free_slide, "{slip} vs {free_slide}");
    assert!(stick.abs() < 0.05 * free_slide, "{stick} vs {free_slide}");
}

/// Mean downward displacement (m) of a hang of `asset` (an edge held,
/// gravity, global damping 5 1/s) after 2 s with material `m`, by `solver`.
fn hang_sag(asset: &Asset, m: &MaterialFields, solver: HomogenizedSolver) -> f64 {
    let driver = PoseDriver::new(
        &asset.rest_yarns.points,
        PoseParams::new(PoseKind::Hang, 0.0),
    )
    .unwrap();
    let times: Vec<f64> = (0..=20).map(|k| k as f64 * 0.1).collect();
    let run = homogenized_run(
        &HomogenizedRunParams {
            solver,
            ..Default::default()
        },
        asset,
        m,
        &driver,
        [0.0, -9.81, 0.0],
        5.0,
        &times,
        &[],
    )
    .unwrap();
    -mean_displacement(asset, &run.frames[0], run.frames.last().unwrap())[1]
}

#[test]
fn pd_settles_a_hang_where_the_newton_reference_does() {
    let asset = flat_asset();
    let m = MaterialFields::uniform(asset.mesh.num_tets(), 1e4, 1e4);
    let (pd, newton) = (
        hang_sag(&asset, &m, HomogenizedSolver::Pd),
        hang_sag(&asset, &m, HomogenizedSolver::Newton),
    );
    eprintln!("mean sag after 2 s: PD {pd:.8e} m, Newton {newton:.8e} m");
    assert!(newton > 0.0 && pd > 0.0);
    assert!((pd - newton).abs() < 0.01 * newton, "{pd} vs {newton}");
}

/// Fibres in the homogenized runs (`fit --fibres` assets): a soft swatch
/// hung by an edge sags less with taut course and wale fibres, and PD
/// settles where the Newton reference does, fibres included.
#[test]
fn fibres_hold_up_a_hang_alike_in_pd_and_newton() {
    use knitvox::embed::orientation::{course_and_wale, OrientationParams};
    use knitvox::sim::fibre::FibreFamily;
    let asset = flat_asset();
    let ne = asset.mesh.num_tets();
    let cw = course_and_wale(
        &asset.rest_yarns,
        &asset.grid,
        &asset.tet_voxel,
        &OrientationParams::default(),
    )
    .unwrap();
    let soft = MaterialFields::uniform(ne, 1e3, 1e3);
    let mut fibred = soft.clone();
    fibred.fibres = [cw.course, cw.wale]
        .into_iter()
        .map(|directions| FibreFamily {
            directions,
            beta: Vec::new(),
            gamma: vec![3e4; ne],
        })
        .collect();
    let sag = |m: &MaterialFields, solver| hang_sag(&asset, m, solver);
    let plain = sag(&soft, HomogenizedSolver::Pd);
    let (pd, newton) = (
        sag(&fibred, HomogenizedSolver::Pd),
        sag(&fibred, HomogenizedSolver::Newton),
    );
    eprintln!(
        "mean sag after 2 s: soft {plain:.6e} m; with fibres PD {pd:.6e}, Newton {newton:.6e}"
    );
    assert!(pd < 0.9 * plain, "{pd} vs {plain}");
    assert!((pd - newton).abs() < 0.01 * newton, "{pd} vs {newton}");
}
