//! Voxel embedding (VH §4-5): mesh invariants, masses, V2Y, supercover
//! connectivity, guards, determinism, the external yarn models and speed.
mod common;

use knitvox::embed::{
    compare_inertia, default_voxel_size, embed, kuhn_weights, locate, tetrahedralize, voxelize,
    EmbedError, EmbedParams, Embedded,
};
use knitvox::geom::{Vec3, VoxelGrid, Yarns};
use proptest::prelude::*;
use std::collections::{HashMap, HashSet, VecDeque};

// ---------------------------------------------------------------- helpers

fn yarns_of(curves: &[(Vec<Vec3>, bool)]) -> Yarns {
    let mut y = Yarns::new();
    for (pts, closed) in curves {
        y.push_curve(pts, *closed, 0.001);
    }
    y
}

fn params_h(h: f64) -> EmbedParams {
    EmbedParams {
        voxel_size: Some(h),
        ..EmbedParams::default()
    }
}

/// Weights of `p` in tet `tet` (general barycentric solve via the Kuhn frame).
fn weights_in(e: &Embedded, tet: u32, p: Vec3) -> [f64; 4] {
    let v = e.grid.voxels[e.tet_voxel[tet as usize] as usize];
    let g = e.grid.to_grid(p);
    kuhn_weights(
        tet as usize % 6,
        std::array::from_fn(|k| g[k] - v[k] as f64),
    )
}

/// Masses, V2Y, weights and pieces (the checks of one embedding).
fn check_masses_and_embedding(y: &Yarns, e: &Embedded) {
    // Total node mass equals total yarn mass (VH Eq. 2 with sum N_i = 1).
    let segs: Vec<[usize; 2]> = y.segments().collect();
    let yarn_mass: f64 = segs
        .iter()
        .zip(&e.segment_linear_density)
        .map(|(&[a, b], d)| d * knitvox::geom::dist(y.points[a], y.points[b]))
        .sum();
    let node_mass: f64 = e.node_mass.iter().sum();
    assert!(
        (node_mass - yarn_mass).abs() <= 1e-12 * yarn_mass,
        "node mass {node_mass} vs yarn mass {yarn_mass}"
    );
    assert!((e.stats.total_yarn_mass - yarn_mass).abs() <= 1e-12 * yarn_mass);
    assert!(e.node_mass.iter().all(|&m| m >= 0.0));
    assert_eq!(e.node_mass.len(), e.mesh.num_nodes());
    // First moment: sum_i m_i x_i = int lambda x ds, exact for linear shape
    // functions (sum_i N_i x_i = x), so it checks where the mass went.
    let diag = y.bounds().unwrap().diagonal().max(e.grid.h);
    let far = y
        .points
        .iter()
        .flatten()
        .fold(0.0f64, |m, x| m.max(x.abs()));
    for k in 0..3 {
        let yarn: f64 = segs
            .iter()
            .zip(&e.segment_linear_density)
            .map(|(&[a, b], d)| {
                d * knitvox::geom::dist(y.points[a], y.points[b])
                    * 0.5
                    * (y.points[a][k] + y.points[b][k])
            })
            .sum();
        let nodes: f64 = e
            .node_mass
            .iter()
            .zip(&e.mesh.nodes)
            .map(|(m, x)| m * x[k])
            .sum();
        assert!(
            (yarn - nodes).abs() <= 1e-11 * yarn_mass * (far + diag),
            "first moment {k}: yarn {yarn} vs nodes {nodes}"
        );
    }

    // Second moments: each yarn point's mass goes to nodes around it with
    // convex weights, so about any axis through the centre the lumped
    // inertia is at least the yarns' (Jensen), never less.
    if let Some(c) = compare_inertia(y, &e.segment_linear_density, &e.mesh.nodes, &e.node_mass) {
        for (k, r) in c.ratios().into_iter().enumerate() {
            assert!(
                r >= 1.0 - 1e-9,
                "lumped inertia {r} of the yarns' about axis {k}: {c:?}"
            );
        }
    }

    // Every vertex in its tet; V2Y of the rest nodes gives the rest yarns.
    assert_eq!(e.embedding.num_vertices(), y.num_points());
    for w in &e.embedding.weights {
        assert!(
            w.iter().all(|&x| (-1e-12..=1.0 + 1e-12).contains(&x)),
            "{w:?}"
        );
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
    let diag = y.bounds().unwrap().diagonal().max(e.grid.h);
    let back = e.embedding.v2y(&e.mesh, &e.mesh.nodes);
    for (p, q) in y.points.iter().zip(&back) {
        assert!(
            knitvox::geom::dist(*p, *q) <= 1e-12 * diag,
            "{p:?} -> {q:?}"
        );
    }
    // The sparse V2Y matrix agrees with Embedding::v2y.
    let n = e.v2y_matrix().unwrap();
    assert_eq!((n.nrows(), n.ncols()), (y.num_points(), e.mesh.num_nodes()));
    let xs = faer::Mat::<f64>::from_fn(e.mesh.num_nodes(), 1, |i, _| e.mesh.nodes[i][0]);
    let nx = &n * &xs;
    for (i, q) in back.iter().enumerate() {
        assert!((nx[(i, 0)] - q[0]).abs() <= 1e-12 * diag);
    }

    // Pieces cover [0, 1] of each segment in order, lengths add up, and each
    // midpoint lies in its tet.
    let mut by_seg: Vec<Vec<usize>> = vec![Vec::new(); segs.len()];
    for (i, p) in e.pieces.iter().enumerate() {
        by_seg[p.segment as usize].push(i);
    }
    for (s, ids) in by_seg.iter().enumerate() {
        assert!(!ids.is_empty(), "segment {s} has no piece");
        let [a, b] = segs[s];
        let len = knitvox::geom::dist(y.points[a], y.points[b]);
        let first = &e.pieces[ids[0]];
        assert_eq!(first.t0, 0.0);
        assert_eq!(e.pieces[*ids.last().unwrap()].t1, 1.0);
        let mut sum = 0.0;
        for w in ids.windows(2) {
            assert_eq!(w[1], w[0] + 1, "pieces of a segment are consecutive");
            assert_eq!(e.pieces[w[0]].t1, e.pieces[w[1]].t0, "gap or overlap");
        }
        for &i in ids {
            let p = &e.pieces[i];
            assert!(p.t1 >= p.t0);
            sum += p.length;
            let t = 0.5 * (p.t0 + p.t1);
            let mid: Vec3 =
                std::array::from_fn(|k| y.points[a][k] + t * (y.points[b][k] - y.points[a][k]));
            let w = weights_in(e, p.tet, mid);
            assert!(
                w.iter().all(|x| (-1e-9..=1.0 + 1e-9).contains(x)),
                "piece {i} midpoint outside its tet: {w:?}"
            );
        }
        assert!(
            (sum - len).abs() <= 1e-12 * len.max(1e-300),
            "{sum} vs {len}"
        );
    }
}

/// Conformity, volumes, node use and the tet-voxel map.
fn check_mesh(e: &Embedded) {
    let h = e.grid.h;
    let vol = h * h * h / 6.0;
    assert_eq!(e.mesh.num_tets(), 6 * e.grid.voxels.len());
    assert_eq!(e.tet_voxel.len(), e.mesh.num_tets());
    for t in 0..e.mesh.num_tets() {
        assert_eq!(e.tet_voxel[t] as usize, t / 6);
        let v = e.mesh.volume(t);
        assert!(
            (v - vol).abs() <= 1e-9 * vol,
            "tet {t}: volume {v}, expected {vol}"
        );
    }
    let mut faces: HashMap<[u32; 3], u32> = HashMap::new();
    let mut used = vec![false; e.mesh.num_nodes()];
    for t in &e.mesh.tets {
        for skip in 0..4 {
            let mut f = [0u32; 3];
            let mut n = 0;
            for (a, &id) in t.iter().enumerate() {
                if a != skip {
                    f[n] = id;
                    n += 1;
                }
            }
            f.sort();
            *faces.entry(f).or_default() += 1;
        }
        for &id in t {
            used[id as usize] = true;
        }
    }
    assert!(
        faces.values().all(|&c| c == 1 || c == 2),
        "a face is shared by 3+ tets"
    );
    assert!(used.iter().all(|&u| u), "a node belongs to no tet");
    // Boundary faces are exactly the triangles on voxel faces with no
    // neighbour voxel: 2 per exposed voxel face.
    let exposed: usize = e
        .grid
        .voxels
        .iter()
        .map(|v| {
            (0..3)
                .flat_map(|k| [-1, 1].map(move |s| (k, s)))
                .filter(|&(k, s)| {
                    let mut n = *v;
                    n[k] += s;
                    e.grid.find(n).is_none()
                })
                .count()
        })
        .sum();
    let boundary = faces.values().filter(|&&c| c == 1).count();
    assert_eq!(boundary, 2 * exposed, "hanging or non-matching faces");
    // Nodes are sorted unique grid corners.
    for w in e.mesh.nodes.windows(2) {
        let (a, b) = (e.grid.to_grid(w[0]), e.grid.to_grid(w[1]));
        let ka: [i64; 3] = a.map(|x| x.round() as i64);
        let kb: [i64; 3] = b.map(|x| x.round() as i64);
        assert!(ka < kb);
    }
}

/// Voxels of one curve's segments (same grid frame), face-connected (BFS).
fn assert_face_connected(voxels: &[[i32; 3]], what: &str) {
    let set: HashSet<[i32; 3]> = voxels.iter().copied().collect();
    let mut seen = HashSet::from([voxels[0]]);
    let mut queue = VecDeque::from([voxels[0]]);
    while let Some(v) = queue.pop_front() {
        for k in 0..3 {
            for s in [-1, 1] {
                let mut n = v;
                n[k] += s;
                if set.contains(&n) && seen.insert(n) {
                    queue.push_back(n);
                }
            }
        }
    }
    assert_eq!(
        seen.len(),
        set.len(),
        "{what}: voxels are not face-connected"
    );
}

fn check_curves_connected(y: &Yarns, grid: &VoxelGrid) {
    for c in 0..y.num_curves() {
        let one = yarns_of(&[(y.curve(c).to_vec(), y.closed[c])]);
        let (g, _) = voxelize(&one, grid.h, Some(grid.origin), u64::MAX).unwrap();
        assert!(g.voxels.iter().all(|v| grid.find(*v).is_some()));
        assert_face_connected(&g.voxels, &format!("curve {c}"));
    }
}

fn check_all(y: &Yarns, e: &Embedded) {
    check_masses_and_embedding(y, e);
    check_mesh(e);
    check_curves_connected(y, &e.grid);
}

// ------------------------------------------------------- hand-made cases

/// Unit grid at the origin: voxelize with h = 1 and origin 0.
fn unit_voxels(curves: &[(Vec<Vec3>, bool)]) -> (Vec<[i32; 3]>, usize) {
    let (g, extra) = voxelize(&yarns_of(curves), 1.0, Some([0.0; 3]), u64::MAX).unwrap();
    (g.voxels, extra)
}

#[test]
fn segment_along_a_face_takes_both_sides() {
    let (v, extra) = unit_voxels(&[(vec![[0.5, 1.0, 0.5], [3.5, 1.0, 0.5]], false)]);
    let want: Vec<[i32; 3]> = (0..4).flat_map(|i| [[i, 0, 0], [i, 1, 0]]).collect();
    let mut want = want;
    want.sort();
    assert_eq!(v, want);
    assert_eq!(extra, 4);
    assert_face_connected(&v, "face");
}

#[test]
fn segment_along_an_edge_takes_four_around_it() {
    let (v, extra) = unit_voxels(&[(vec![[0.5, 1.0, 2.0], [2.5, 1.0, 2.0]], false)]);
    assert_eq!(v.len(), 12);
    assert_eq!(extra, 9);
    for x in &v {
        assert!((0..3).contains(&x[0]) && (0..2).contains(&x[1]) && (1..3).contains(&x[2]));
    }
    assert_face_connected(&v, "edge");
}

#[test]
fn segment_through_corners_takes_all_eight() {
    // Passes the corners (1,1,1) and (2,2,2).
    let (v, extra) = unit_voxels(&[(vec![[0.5, 0.5, 0.5], [2.5, 2.5, 2.5]], false)]);
    assert_eq!(v.len(), 15);
    assert_eq!(extra, 12);
    for c in [[1, 1, 1], [2, 2, 2]] {
        for d in 0..8 {
            let n = [
                c[0] - 1 + (d & 1),
                c[1] - 1 + ((d >> 1) & 1),
                c[2] - 1 + ((d >> 2) & 1),
            ];
            assert!(v.contains(&n), "{n:?} missing around corner {c:?}");
        }
    }
    assert_face_connected(&v, "corner");
    // A closed zigzag through edges and corners in the plane z = 0.5.
    let zig = vec![
        [0.5, 0.5, 0.5],
        [1.5, 1.5, 0.5],
        [2.5, 0.5, 0.5],
        [3.0, 3.0, 1.0],
    ];
    let (v, extra) = unit_voxels(&[(zig, true)]);
    assert!(extra > 0);
    assert_face_connected(&v, "zigzag");
}

#[test]
fn grid_aligned_yarns_embed_with_all_invariants() {
    // The first curve fixes the bounding-box minimum at 0.5, so the default
    // origin (min - h/2) is 0 and the other curves run on faces, edges and
    // through corners of the unit grid.
    let y = yarns_of(&[
        (vec![[0.5, 0.5, 0.5], [0.75, 0.5, 0.5]], false),
        (vec![[0.5, 1.0, 0.5], [3.5, 1.0, 0.5]], false),
        (vec![[0.5, 1.0, 2.0], [2.5, 1.0, 2.0]], false),
        (
            vec![[0.5, 0.5, 0.5], [2.5, 2.5, 2.5], [3.0, 1.0, 1.0]],
            true,
        ),
    ]);
    let e = embed(&y, &params_h(1.0)).unwrap();
    assert_eq!(e.grid.origin, [0.0; 3]);
    check_all(&y, &e);
    assert!(e.stats.extra_voxels > 0);
}

// --------------------------------------------------------------- random

fn arb_yarns() -> impl Strategy<Value = Yarns> {
    let point = prop::array::uniform3(-1.0f64..1.0);
    let curve = (
        prop::collection::vec(point, 3..12),
        any::<bool>(),
        0.0005f64..0.003,
    );
    prop::collection::vec(curve, 1..4).prop_map(|cs| {
        let mut y = Yarns::new();
        for (pts, closed, r) in cs {
            y.push_curve(&pts, closed, r);
        }
        y
    })
}

/// Random yarns on a coarse lattice (multiples of 1/4), so segments often run
/// exactly along faces and edges and through corners of an h = 1/2 grid.
fn arb_lattice_yarns() -> impl Strategy<Value = Yarns> {
    let point = prop::array::uniform3(-8i32..8).prop_map(|p| p.map(|x| x as f64 * 0.25));
    let curve = (prop::collection::vec(point, 3..10), any::<bool>());
    prop::collection::vec(curve, 1..4).prop_map(|cs| {
        let mut y = Yarns::new();
        for (pts, closed) in cs {
            y.push_curve(&pts, closed, 0.001);
        }
        y
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn random_yarns_embed_with_all_invariants(y in arb_yarns(), h in 0.05f64..0.7) {
        let e = embed(&y, &params_h(h)).unwrap();
        check_all(&y, &e);
    }

    #[test]
    fn lattice_yarns_embed_with_all_invariants(y in arb_lattice_yarns()) {
        let e = embed(&y, &params_h(0.5)).unwrap();
        check_all(&y, &e);
        // With an origin on the lattice too, planes are hit exactly.
        let (g, _) = voxelize(&y, 0.5, Some([0.0; 3]), u64::MAX).unwrap();
        check_curves_connected(&y, &g);
    }

    #[test]
    fn default_voxel_size_lands_near_the_target(y in arb_yarns()) {
        let e = embed(&y, &EmbedParams::default()).unwrap();
        check_masses_and_embedding(&y, &e);
        let (h, rule) = default_voxel_size(&y, &EmbedParams::default()).unwrap();
        prop_assert_eq!(h, e.grid.h);
        prop_assert!(rule.contains("nodes"));
    }
}

/// The lumped mass of a knitted swatch at the default voxel size (about
/// half as many nodes as yarn vertices) spins with 1.01-1.05x the yarns'
/// inertia: most about the axis along the swatch (the smallest moment,
/// where a voxel is large against the thickness), least about the normal.
#[test]
fn lumped_mass_of_a_knit_swatch_keeps_the_yarns_inertia_within_eight_percent() {
    for pattern in ["stockinette", "rib"] {
        let y = common::flat_swatch(pattern, 6, 6);
        let e = embed(&y, &EmbedParams::default()).unwrap();
        let c = compare_inertia(&y, &e.segment_linear_density, &e.mesh.nodes, &e.node_mass)
            .expect("a swatch's inertia");
        let r = c.ratios();
        eprintln!("{pattern}: lumped / yarn inertia {r:?}");
        assert!(
            r.iter().all(|&x| (1.0..1.08).contains(&x)),
            "{pattern}: {r:?}"
        );
        assert!(r[0] > r[2], "{pattern}: {r:?}");
    }
}

#[test]
fn per_vertex_radius_and_linear_density_set_the_mass() {
    let mut y = yarns_of(&[(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]],
        false,
    )]);
    y.vertex_radius = Some(vec![0.001, 0.003, 0.001]);
    let p = params_h(0.3);
    let e = embed(&y, &p).unwrap();
    let area = |r: f64| 1200.0 * std::f64::consts::PI * r * r;
    let want = area(0.002) * 1.0 + area(0.002) * 2.0;
    assert!((e.stats.total_yarn_mass - want).abs() < 1e-15);
    assert!((e.linear_density[0] - want / 3.0).abs() < 1e-15);
    check_masses_and_embedding(&y, &e);
    y.linear_density = Some(vec![0.01]);
    let e = embed(&y, &p).unwrap();
    assert!((e.node_mass.iter().sum::<f64>() - 0.03).abs() < 1e-15);
}

// --------------------------------------------------------------- guards

#[test]
fn guards_give_the_right_errors() {
    let good = yarns_of(&[(vec![[0.0; 3], [1.0, 0.0, 0.0]], false)]);
    assert_eq!(
        embed(&Yarns::new(), &EmbedParams::default()),
        Err(EmbedError::Empty)
    );
    assert_eq!(
        embed(&Yarns::default(), &EmbedParams::default()),
        Err(EmbedError::Empty)
    );
    assert_eq!(
        voxelize(&Yarns::new(), 1.0, None, 100).unwrap_err(),
        EmbedError::Empty
    );
    for h in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let err = embed(&good, &params_h(h)).unwrap_err();
        assert!(
            matches!(err, EmbedError::BadVoxelSize(x) if x.to_bits() == h.to_bits()),
            "{err}"
        );
        let err = voxelize(&good, h, None, 100).unwrap_err();
        assert!(matches!(err, EmbedError::BadVoxelSize(_)), "{err}");
    }
    let nan = yarns_of(&[(vec![[0.0; 3], [f64::NAN, 0.0, 0.0]], false)]);
    assert!(matches!(
        embed(&nan, &EmbedParams::default()),
        Err(EmbedError::Yarns(_))
    ));
    assert!(matches!(
        default_voxel_size(&nan, &EmbedParams::default()),
        Err(EmbedError::Yarns(_))
    ));
    // 1e9 voxels along a 1 m yarn: refused from the bound, before allocating.
    let err = embed(&good, &params_h(1e-9)).unwrap_err();
    assert!(
        matches!(err, EmbedError::TooManyVoxels { limit: 20_000_000, estimate, .. } if estimate > 1_000_000_000),
        "{err}"
    );
    let err = embed(
        &good,
        &EmbedParams {
            voxel_size: Some(0.1),
            // The 1 m segment covers 11 voxels of 0.1 m (the limit applies
            // to the real voxels, not the 8 (C + 2) = 96 bound).
            max_voxels: 10,
            ..EmbedParams::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            EmbedError::TooManyVoxels {
                limit: 10,
                estimate: 11,
                ..
            }
        ),
        "{err}"
    );
    // Two tiny yarns ten kilometres apart at a micrometre voxel: grid too wide.
    let far = yarns_of(&[
        (vec![[0.0; 3], [1e-7, 0.0, 0.0]], false),
        (vec![[1e4, 0.0, 0.0], [1e4 + 1e-7, 0.0, 0.0]], false),
    ]);
    assert!(matches!(
        embed(&far, &params_h(1e-6)),
        Err(EmbedError::GridTooWide { .. })
    ));
    for bad in [
        EmbedParams {
            target_node_ratio: 0.0,
            ..EmbedParams::default()
        },
        EmbedParams {
            material_density: f64::NAN,
            ..EmbedParams::default()
        },
    ] {
        assert!(matches!(embed(&good, &bad), Err(EmbedError::Parameter(_))));
    }
}

// ---------------------------------------------------------- determinism

#[test]
fn embedding_is_deterministic_and_translation_equivariant() {
    // Dyadic coordinates and voxel size, so translating by 3h is exact.
    let mut rng = 0x2545f4914f6cdd1du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f64 / (1u64 << 24) as f64
    };
    let curves: Vec<(Vec<Vec3>, bool)> = (0..5)
        .map(|c| {
            (
                (0..40).map(|_| [next(), next(), next()]).collect(),
                c % 2 == 0,
            )
        })
        .collect();
    let y = yarns_of(&curves);
    let h = 0.0625;
    let a = embed(&y, &params_h(h)).unwrap();
    let b = embed(&y, &params_h(h)).unwrap();
    let strip = |e: &Embedded| {
        let mut e = e.clone();
        e.stats.voxelize_ms = 0.0;
        e.stats.tetrahedralize_ms = 0.0;
        e.stats.mass_ms = 0.0;
        e.stats.embedding_ms = 0.0;
        e
    };
    assert_eq!(strip(&a), strip(&b));
    let d = [3.0 * h, -5.0 * h, 7.0 * h];
    let mut moved = y.clone();
    for p in &mut moved.points {
        for k in 0..3 {
            p[k] += d[k];
        }
    }
    let m = embed(&moved, &params_h(h)).unwrap();
    assert_eq!(m.grid.voxels, a.grid.voxels);
    assert_eq!(m.mesh.tets, a.mesh.tets);
    assert_eq!(m.embedding, a.embedding);
    assert_eq!(m.node_mass, a.node_mass);
    assert_eq!(m.pieces, a.pieces);
    for (p, q) in m.mesh.nodes.iter().zip(&a.mesh.nodes) {
        for k in 0..3 {
            assert_eq!(p[k], q[k] + d[k]);
        }
    }
    // With a fixed origin the voxels shift by whole indices.
    let (g0, _) = voxelize(&y, h, Some([0.0; 3]), u64::MAX).unwrap();
    let (g1, _) = voxelize(&moved, h, Some([0.0; 3]), u64::MAX).unwrap();
    let shifted: Vec<[i32; 3]> = g0
        .voxels
        .iter()
        .map(|v| [v[0] + 3, v[1] - 5, v[2] + 7])
        .collect();
    assert_eq!(g1.voxels, shifted);
    let (m0, _) = tetrahedralize(&g0);
    let (m1, _) = tetrahedralize(&g1);
    assert_eq!(m0.tets, m1.tets);
    // Point location agrees after the shift too.
    for (p, q) in y.points.iter().zip(&moved.points) {
        assert_eq!(locate(&g0, *p), locate(&g1, *q));
    }
}

// -------------------------------------------------- external yarn models

fn external_models() -> Vec<(String, Yarns)> {
    use knitvox::io::{read_path, Format, ReadOptions};
    let Some(dir) = common::external_data("yarns") else {
        return Vec::new();
    };
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| Format::from_path(p).is_some())
        .collect();
    paths.sort();
    paths
        .into_iter()
        .map(|p| {
            let d = read_path(&p, &ReadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                d.yarns,
            )
        })
        .collect()
}

#[test]
fn every_external_model_embeds_with_the_default_voxel_size() {
    let models = external_models();
    if models.is_empty() {
        return;
    }
    eprintln!(
        "\n{:<38} {:>9} {:>8} {:>9} {:>7} {:>11} {:>8} {:>9}",
        "file", "yarn pts", "nodes", "tets", "nV/nY", "h (m)", "extra", "embed ms"
    );
    for (name, y) in &models {
        let t = std::time::Instant::now();
        let e = embed(y, &EmbedParams::default()).unwrap_or_else(|err| panic!("{name}: {err}"));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let ratio = e.stats.nodes as f64 / y.num_points() as f64;
        eprintln!(
            "{:<38} {:>9} {:>8} {:>9} {:>7.3} {:>11.4e} {:>8} {:>9.1}",
            name,
            y.num_points(),
            e.stats.nodes,
            e.stats.tets,
            ratio,
            e.grid.h,
            e.stats.extra_voxels,
            ms
        );
        check_masses_and_embedding(y, &e);
        check_mesh(&e);
        assert!(ratio > 0.25 && ratio < 1.0, "{name}: node ratio {ratio}");
    }
}

#[test]
fn tea_cozy_embeds_in_under_a_second() {
    let Some(y) = external_models()
        .into_iter()
        .find(|(n, _)| n == "yuksel_tea_cozy.bcc")
        .map(|(_, y)| y)
    else {
        return;
    };
    let mut times: Vec<f64> = (0..5)
        .map(|_| {
            let t = std::time::Instant::now();
            let e = embed(&y, &EmbedParams::default()).unwrap();
            let ms = t.elapsed().as_secs_f64() * 1e3;
            eprintln!(
                "tea cozy: {} points, {} nodes, {} tets, {ms:.1} ms (voxelize incl. size search {:.1}, \
                 tets {:.1}, masses {:.1}, embedding {:.1})",
                y.num_points(),
                e.stats.nodes,
                e.stats.tets,
                e.stats.voxelize_ms,
                e.stats.tetrahedralize_ms,
                e.stats.mass_ms,
                e.stats.embedding_ms
            );
            ms
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    eprintln!("tea cozy embed median {median:.1} ms");
    let (h, rule) = default_voxel_size(&y, &EmbedParams::default()).unwrap();
    eprintln!("tea cozy voxel size {h:.6e} m: {rule}");
    if !cfg!(debug_assertions) {
        assert!(
            median < 1000.0,
            "embedding the tea cozy took {median:.1} ms"
        );
    }
}

/// A dense garment whose per-segment bound (16+ voxels per
/// segment) is far above the limit but whose real voxel count is small embeds;
/// the limit still applies to the real count.
#[test]
fn dense_garment_bound_counts_real_voxels() {
    // 200K segments zig-zagging inside a 4 cm cube: bound >= 3.2M, real < 2K at 4 mm.
    let n = 200_001;
    let pts: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let t = i as f64;
            [
                0.02 + 0.019 * (t * 0.37).sin(),
                0.02 + 0.019 * (t * 0.11).cos(),
                0.02 + 0.019 * (t * 0.05).sin(),
            ]
        })
        .collect();
    let y = yarns_of(&[(pts, false)]);
    let h = 0.004;
    let (grid, _) = voxelize(&y, h, None, 1_000_000).expect("real voxels fit");
    assert!(grid.voxels.len() < 2_000, "{}", grid.voxels.len());
    assert!(grid.voxels.len() > 100, "{}", grid.voxels.len());
    let real = grid.voxels.len() as u64;
    let err = voxelize(&y, h, None, real - 1).unwrap_err();
    assert!(
        matches!(err, EmbedError::TooManyVoxels { estimate, limit, .. } if estimate > limit && limit == real - 1),
        "{err}"
    );
}
