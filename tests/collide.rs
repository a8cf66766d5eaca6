//! Colliders (`sim::collide`): BVH closest points against brute force,
//! inside/outside signs on closed meshes, exact plane and sphere projections.

use knitvox::geom::bvh::{closest_point_on_triangle, MeshCollider, MeshTopology};
use knitvox::geom::Vec3;
use knitvox::sim::collide::{Collider, ColliderSet, Shape};
use knitvox::sim::contact::NodeProjector;
use proptest::prelude::*;

fn dist(a: Vec3, b: Vec3) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn mesh(pos: &[Vec3], tris: &[[u32; 3]]) -> MeshCollider {
    let (t, dropped) = MeshTopology::new(tris, pos.len());
    assert_eq!(dropped, 0);
    MeshCollider::new(&t, pos).unwrap()
}

/// Closed cube [-1, 1]^3, outward-facing triangles.
fn cube() -> MeshCollider {
    let mut pos = Vec::new();
    for i in 0..8 {
        pos.push([
            if i & 1 != 0 { 1.0 } else { -1.0 },
            if i & 2 != 0 { 1.0 } else { -1.0 },
            if i & 4 != 0 { 1.0 } else { -1.0 },
        ]);
    }
    let quads = [
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
    ];
    let mut tris = Vec::new();
    for q in quads {
        tris.push([q[0], q[1], q[2]]);
        tris.push([q[0], q[2], q[3]]);
    }
    let m = mesh(&pos, &tris);
    // Orientation check: the +x face normal points along +x.
    let (t, _) = MeshTopology::new(&tris, 8);
    assert!(t.is_closed());
    m
}

/// UV sphere of radius `r`, outward-facing.
fn uv_sphere(r: f64, nu: usize, nv: usize) -> MeshCollider {
    let mut pos = vec![[0.0, r, 0.0], [0.0, -r, 0.0]];
    for i in 1..nv {
        let th = std::f64::consts::PI * i as f64 / nv as f64;
        for j in 0..nu {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / nu as f64;
            pos.push([
                r * th.sin() * ph.cos(),
                r * th.cos(),
                r * th.sin() * ph.sin(),
            ]);
        }
    }
    let ring = |i: usize, j: usize| (2 + (i - 1) * nu + j % nu) as u32;
    let mut tris = Vec::new();
    for j in 0..nu {
        tris.push([0, ring(1, j + 1), ring(1, j)]);
        tris.push([1, ring(nv - 1, j), ring(nv - 1, j + 1)]);
    }
    for i in 1..nv - 1 {
        for j in 0..nu {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            tris.push([a, b, d]);
            tris.push([a, d, c]);
        }
    }
    mesh(&pos, &tris)
}

fn brute_distance(pos: &[Vec3], tris: &[[u32; 3]], p: Vec3) -> f64 {
    tris.iter()
        .map(|t| {
            let q = closest_point_on_triangle(
                p,
                pos[t[0] as usize],
                pos[t[1] as usize],
                pos[t[2] as usize],
            )
            .0;
            dist(p, q)
        })
        .fold(f64::INFINITY, f64::min)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn bvh_closest_point_equals_brute_force(
        verts in prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 3..90),
        points in prop::collection::vec(prop::array::uniform3(-2.0f64..2.0), 1..20),
    ) {
        let nt = verts.len() / 3;
        let tris: Vec<[u32; 3]> = (0..nt as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let (topo, _) = MeshTopology::new(&tris, verts.len());
        let m = MeshCollider::new(&topo, &verts).unwrap();
        for p in points {
            let hit = m.closest(p).unwrap();
            let brute = brute_distance(&verts, &tris, p);
            prop_assert!((hit.signed_distance.abs() - brute).abs() <= 1e-12 * (1.0 + brute));
            prop_assert!((dist(p, hit.point) - brute).abs() <= 1e-12 * (1.0 + brute));
        }
    }

    #[test]
    fn cube_sign_and_distance_exact(p in prop::array::uniform3(-2.0f64..2.0)) {
        let m = cube();
        let inside = p.iter().all(|c| c.abs() < 1.0);
        let want = if inside {
            -p.iter().map(|c| 1.0 - c.abs()).fold(f64::INFINITY, f64::min)
        } else {
            p.iter().map(|c| (c.abs() - 1.0).max(0.0).powi(2)).sum::<f64>().sqrt()
        };
        let hit = m.closest(p).unwrap();
        prop_assert!((hit.signed_distance - want).abs() < 1e-12, "{p:?}: {} vs {want}", hit.signed_distance);
    }

    #[test]
    fn sphere_mesh_sign(p in prop::array::uniform3(-2.0f64..2.0)) {
        let m = uv_sphere(1.0, 24, 12);
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        // The polygon lies within 1 - cos(pi / 12) ~ 0.034 inside the sphere.
        prop_assume!((r - 1.0).abs() > 0.05);
        let hit = m.closest(p).unwrap();
        prop_assert_eq!(hit.signed_distance < 0.0, r < 1.0);
    }
}

#[test]
fn cube_corner_and_edge_regions_signed_right() {
    let m = cube();
    // Just outside a corner and an edge (vertex / edge pseudo-normals).
    for p in [[1.001, 1.001, 1.001], [1.0005, -1.0005, 0.3]] {
        assert!(m.closest(p).unwrap().signed_distance > 0.0, "{p:?}");
    }
    // Just inside, near a corner and an edge.
    for p in [[0.999, 0.999, 0.999], [0.9995, -0.9995, 0.3]] {
        assert!(m.closest(p).unwrap().signed_distance < 0.0, "{p:?}");
    }
}

#[test]
fn mesh_projection_pushes_out_to_thickness() {
    let c = Collider {
        shape: Shape::Mesh(Box::new(cube())),
        thickness: 0.01,
    };
    let q = c.project([0.5, 0.9, 0.0]).unwrap();
    assert!(dist(q, [0.5, 1.01, 0.0]) < 1e-12, "{q:?}");
    assert_eq!(c.project([0.5, 1.5, 0.0]), None);
}

#[test]
fn plane_and_sphere_projection_exact() {
    let set = ColliderSet {
        colliders: vec![
            Collider {
                shape: Shape::Plane {
                    point: [0.0, 0.0, 0.0],
                    normal: [0.0, 1.0, 0.0],
                },
                thickness: 0.001,
            },
            Collider {
                shape: Shape::Sphere {
                    center: [0.0, 1.0, 0.0],
                    radius: 0.5,
                },
                thickness: 0.001,
            },
        ],
        friction: 0.0,
    };
    let q = set.project(0, [0.2, -0.3, 0.1]).unwrap();
    assert_eq!(q, [0.2, 0.001, 0.1]);
    let q = set.project(0, [0.0, 1.2, 0.0]).unwrap();
    assert!((q[1] - 1.501).abs() < 1e-15 && q[0] == 0.0 && q[2] == 0.0);
    assert_eq!(set.project(0, [3.0, 3.0, 3.0]), None);
    assert!((set.penetration([0.0, -0.25, 0.0]) - 0.25).abs() < 1e-15);
    let (which, d) = set.min_signed_distance([0.0, 1.0, 0.0]).unwrap();
    assert_eq!((which, d), (1, -0.5));
}

#[test]
fn moving_mesh_reports_the_surface_motion_of_a_contact() {
    // The cube moved 0.1 m along +x and 0.02 m up over the step: a node just
    // inside its top face sees that displacement; without the previous pose
    // (or for a node outside) the surface rests.
    let now = cube();
    let before: Vec<Vec3> = now
        .positions()
        .iter()
        .map(|p| [p[0] - 0.1, p[1] - 0.02, p[2]])
        .collect();
    let moving = Collider {
        shape: Shape::Mesh(Box::new(now.clone().with_previous(&before).unwrap())),
        thickness: 0.0,
    };
    let (q, u) = moving.project_moving([0.3, 0.9, 0.2]).unwrap();
    assert!(dist(q, [0.3, 1.0, 0.2]) < 1e-12, "{q:?}");
    assert!(dist(u, [0.1, 0.02, 0.0]) < 1e-12, "{u:?}");
    assert_eq!(moving.project_moving([0.3, 1.5, 0.2]), None);
    let still = Collider {
        shape: Shape::Mesh(Box::new(now.clone())),
        thickness: 0.0,
    };
    assert_eq!(still.project_moving([0.3, 0.9, 0.2]).unwrap().1, [0.0; 3]);
    // The set hands the motion and its friction to the time loop.
    let set = ColliderSet {
        colliders: vec![moving],
        friction: 0.4,
    };
    let c = set.contact(7, [0.3, 0.9, 0.2]).unwrap();
    assert!(dist(c.surface_motion, [0.1, 0.02, 0.0]) < 1e-12);
    assert_eq!(c.friction, 0.4);
    // Bad previous poses are refused, not stored.
    assert!(now.clone().with_previous(&before[..3]).is_err());
    let mut nan = before.clone();
    nan[2][1] = f64::NAN;
    assert!(now.with_previous(&nan).is_err());
}
