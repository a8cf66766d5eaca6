//! Tests of Y2V (VH Eq. 5-6) against known deformations of analytic swatches:
//! affine maps must be reproduced exactly, smooth waves must keep their
//! amplitude, and a 30% stretch must not invert tets.

use std::f64::consts::PI;

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::shapefit::{ShapeFitParams, ShapeFitter};
use crate::embed::{embed, EmbedParams, Embedded};
use crate::geom::{TetMesh, Vec3, Yarns};
use crate::yarn::analytic::{knit_swatch, SwatchParams};

fn fixture(p: &SwatchParams) -> (Yarns, Embedded, ShapeFitter) {
    let y = knit_swatch(p);
    let e = embed(&y, &EmbedParams::default()).unwrap();
    let f = ShapeFitter::from_embedded(&y, &e, &ShapeFitParams::default()).unwrap();
    (y, e, f)
}

/// The swatch of the integration tests (tests/asset.rs): 4 x 4 loops and a ring.
fn small_swatch() -> SwatchParams {
    SwatchParams {
        courses: 4,
        wales: 4,
        points_per_loop: 16,
        ..Default::default()
    }
}

/// A wider swatch (48 x 18 mm, no ring) that holds a few 10-voxel waves.
fn wide_swatch() -> SwatchParams {
    SwatchParams {
        courses: 6,
        wales: 12,
        points_per_loop: 24,
        with_ring: false,
        ..Default::default()
    }
}

fn apply(m: &Matrix3<f64>, t: &Vector3<f64>, pts: &[Vec3]) -> Vec<Vec3> {
    pts.iter()
        .map(|p| {
            let q = m * Vector3::new(p[0], p[1], p[2]) + t;
            [q[0], q[1], q[2]]
        })
        .collect()
}

fn dist(a: Vec3, b: Vec3) -> f64 {
    crate::geom::dist(a, b)
}

/// (number of tets with det F <= 0, minimum det F) of a fitted pose.
fn det_stats(mesh: &TetMesh, nodes: &[Vec3]) -> (usize, f64) {
    let mut inverted = 0;
    let mut min = f64::INFINITY;
    for t in 0..mesh.num_tets() {
        let d = mesh.volume_with(nodes, t) / mesh.volume(t);
        if d <= 0.0 {
            inverted += 1;
        }
        min = min.min(d);
    }
    (inverted, min)
}

fn affine_cases() -> Vec<(String, Matrix3<f64>, Vector3<f64>)> {
    let rot = Rotation3::new(Vector3::new(0.3, -1.1, 0.7)).into_inner();
    let shift = Vector3::new(0.01, -0.02, 0.5);
    let maps = [
        ("uniform scale 1.2", Matrix3::identity() * 1.2),
        (
            "stretch x 1.3, contraction 0.9",
            Matrix3::from_diagonal(&Vector3::new(1.3, 0.9, 0.9)),
        ),
        (
            "shear 0.2",
            Matrix3::new(1.0, 0.2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        ),
        (
            "general",
            Matrix3::new(1.1, 0.2, 0.0, -0.1, 0.95, 0.15, 0.05, 0.0, 1.05),
        ),
    ];
    let mut out = Vec::new();
    for (name, m) in maps {
        out.push((name.to_string(), m, Vector3::zeros()));
        out.push((format!("{name}, rotated and moved"), rot * m, shift));
    }
    out
}

/// Every affine map x -> A x + b (det A > 0) of the yarns is reproduced
/// exactly: every tet node at A X + b and V2Y(Y2V(x)) = x.
#[test]
fn y2v_is_exact_for_affine_maps() {
    let mut bad = Vec::new();
    for params in [small_swatch(), wide_swatch()] {
        let (y, e, fitter) = fixture(&params);
        let size = y.bounds().unwrap().diagonal();
        for (name, a, b) in affine_cases() {
            let moved = apply(&a, &b, &y.points);
            let (nodes, stats) = fitter.fit(&moved).unwrap();
            let expect = apply(&a, &b, &e.mesh.nodes);
            let node_err = nodes
                .iter()
                .zip(&expect)
                .map(|(p, q)| dist(*p, *q))
                .fold(0.0, f64::max);
            let back = e.embedding.v2y(&e.mesh, &nodes);
            let rms = (back
                .iter()
                .zip(&moved)
                .map(|(p, q)| dist(*p, *q).powi(2))
                .sum::<f64>()
                / back.len() as f64)
                .sqrt();
            eprintln!(
                "{} points, {name}: relative V2Y RMS {:.3e}, relative max node error {:.3e}, {:.2} ms",
                y.num_points(),
                rms / size,
                node_err / size,
                stats.ms
            );
            assert!((stats.rms_error - rms).abs() <= 1e-12 * size);
            assert_eq!(stats.inverted_tets, 0);
            assert!(
                (stats.min_det_f - a.determinant()).abs() < 1e-9,
                "{stats:?}"
            );
            if !(rms < 1e-9 * size && node_err < 1e-9 * size) {
                bad.push(format!(
                    "{} points, {name}: V2Y RMS {rms:.3e} m, node error {node_err:.3e} m, size {size:.3e} m",
                    y.num_points()
                ));
            }
        }
    }
    assert!(bad.is_empty(), "not exact:\n{}", bad.join("\n"));
}

/// Fraction of a displacement field u kept by V2Y(Y2V(X + u)) - X
/// (projection on u).
fn kept(e: &Embedded, fitter: &ShapeFitter, rest: &[Vec3], u: &[Vec3]) -> f64 {
    let moved: Vec<Vec3> = rest
        .iter()
        .zip(u)
        .map(|(p, d)| std::array::from_fn(|k| p[k] + d[k]))
        .collect();
    let (nodes, _) = fitter.fit(&moved).unwrap();
    let back = e.embedding.v2y(&e.mesh, &nodes);
    let (mut num, mut den) = (0.0, 0.0);
    for ((b, p), d) in back.iter().zip(rest).zip(u) {
        for k in 0..3 {
            num += (b[k] - p[k]) * d[k];
            den += d[k] * d[k];
        }
    }
    num / den
}

/// A smooth displacement wave 10 voxels long keeps at least 90% of its
/// amplitude, whichever way it points (along x: stretch and compression;
/// along y: in-plane shear; along z: bending).
#[test]
fn y2v_keeps_a_ten_voxel_wave() {
    let (y, e, fitter) = fixture(&wide_swatch());
    let h = e.stats.voxel_size;
    let lambda = 10.0 * h;
    let amp = 0.01 * lambda;
    let mut bad = Vec::new();
    for (name, dir) in [("x (stretch)", 0), ("y (shear)", 1), ("z (bend)", 2)] {
        let mut worst: f64 = 1.0;
        for phase in [0.0, 0.5 * PI] {
            let u: Vec<Vec3> = y
                .points
                .iter()
                .map(|p| {
                    let mut d = [0.0; 3];
                    d[dir] = amp * (2.0 * PI * p[0] / lambda + phase).sin();
                    d
                })
                .collect();
            worst = worst.min(kept(&e, &fitter, &y.points, &u));
        }
        eprintln!(
            "wave along {name}, 10 voxels long (h = {h:.3e} m): keeps {:.1}%",
            100.0 * worst
        );
        if !(worst >= 0.9) {
            bad.push(format!(
                "wave along {name} keeps only {:.1}%",
                100.0 * worst
            ));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// The analytic swatch loop curve with its shape parameters exposed: loop
/// opening `a` and depth `c` (see `yarn::analytic`).
fn loops(courses: usize, wales: usize, ppl: usize, w: f64, h: f64, a: f64, c: f64) -> Vec<Vec3> {
    let n = wales * ppl;
    let b = 0.6 * h;
    let mut pts = Vec::new();
    for j in 0..courses {
        for i in 0..=n {
            let t = 2.0 * PI * wales as f64 * i as f64 / n as f64;
            pts.push([
                w * (t + a * (2.0 * t).sin()) / (2.0 * PI),
                j as f64 * h + b * t.cos(),
                c * (2.0 * t).cos(),
            ]);
        }
    }
    pts
}

/// A yarn-level 30% stretch along the courses (loops open up and flatten,
/// courses contract by 10%, plus the wiggle of the demo frames) leaves no tet
/// inverted, and the mesh takes the whole 30%.
#[test]
fn y2v_stretch_of_30_percent_inverts_no_tet() {
    let p = wide_swatch();
    let (y, e, fitter) = fixture(&p);
    let (w, h) = (p.wale_width, p.course_height);
    let rest = loops(p.courses, p.wales, p.points_per_loop, w, h, 0.8, 0.25 * w);
    assert_eq!(rest.len(), y.num_points());
    assert!(rest
        .iter()
        .zip(&y.points)
        .all(|(a, b)| dist(*a, *b) < 1e-15));
    let mut stretched = loops(
        p.courses,
        p.wales,
        p.points_per_loop,
        1.3 * w,
        0.9 * h,
        0.55,
        0.18 * w,
    );
    for q in &mut stretched {
        q[1] -= 0.0005 * (q[0] * 400.0).sin().abs();
    }
    let (nodes, stats) = fitter.fit(&stretched).unwrap();
    let (inverted, min_det) = det_stats(&e.mesh, &nodes);
    eprintln!(
        "30% stretch: {inverted} of {} tets inverted, min det F {min_det:.3}, V2Y RMS {:.3e} m",
        e.mesh.num_tets(),
        stats.rms_error
    );
    let extent = |pts: &[Vec3]| {
        let (lo, hi) = pts
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, u), q| {
                (l.min(q[0]), u.max(q[0]))
            });
        hi - lo
    };
    let back = e.embedding.v2y(&e.mesh, &nodes);
    eprintln!(
        "30% stretch: x extent ratio of the yarns {:.3}, of V2Y(Y2V) {:.3}, of the mesh {:.3}",
        extent(&stretched) / extent(&y.points),
        extent(&back) / extent(&y.points),
        extent(&nodes) / extent(&e.mesh.nodes)
    );
    assert_eq!(inverted, 0);
    assert_eq!(stats.inverted_tets, 0);
    assert!((stats.min_det_f - min_det).abs() < 1e-12);
    // The mesh carries the stretch (rotation-only normals gave 1.22).
    let ratio = extent(&nodes) / extent(&e.mesh.nodes);
    assert!((ratio - 1.3).abs() < 0.02, "mesh x extent ratio {ratio}");
}

/// Timing of Y2V per frame (test profile; `cargo test --lib
/// fit::y2v_tests::bench -- --ignored --nocapture`): the swatches of these
/// tests and of tests/asset.rs, the built-in 25k-point swatch and, when
/// ../shared/data is there, the flame ribbing, each under the demo's 30%
/// stretch (median over 5 frames, repeated on the small inputs).
#[test]
#[ignore]
fn bench_y2v_ms_per_frame() {
    let mut inputs = vec![
        (
            "tests/asset.rs swatch".to_string(),
            knit_swatch(&small_swatch()),
        ),
        ("wide swatch".to_string(), knit_swatch(&wide_swatch())),
        (
            "built-in swatch 25k".to_string(),
            crate::yarn::analytic::knit_swatch_with_points(25_000),
        ),
    ];
    let flame = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/yarns/yuksel_flame_ribbing_pattern.bcc");
    if flame.exists() {
        let y = crate::io::read_path(&flame, &crate::io::ReadOptions::default())
            .unwrap()
            .yarns;
        inputs.push(("yuksel_flame_ribbing_pattern.bcc".to_string(), y));
    }
    for (name, y) in inputs {
        let e = embed(&y, &EmbedParams::default()).unwrap();
        let t = std::time::Instant::now();
        let fitter = ShapeFitter::from_embedded(&y, &e, &ShapeFitParams::default()).unwrap();
        let prepare = t.elapsed().as_secs_f64() * 1e3;
        let frames = crate::pipeline::demo::demo_frames(&y, 5);
        let repeats = (100_000 / y.num_points()).clamp(1, 20);
        let mut ms: Vec<f64> = (0..frames.num_frames() * repeats)
            .map(|f| {
                fitter
                    .fit(frames.frame(f % frames.num_frames()))
                    .unwrap()
                    .1
                    .ms
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        let (_, last) = fitter.fit(frames.frame(frames.num_frames() - 1)).unwrap();
        eprintln!(
            "{name}: {} points, {} tets; prepare {prepare:.1} ms ({:?}); Y2V median {:.2} ms per frame ({} fits); 30% frame {last:?}",
            y.num_points(),
            e.mesh.num_tets(),
            fitter.prepare,
            ms[ms.len() / 2],
            ms.len()
        );
    }
}

/// Same fitter and same fitted nodes, bit for bit, on 1 and 3 threads.
#[test]
fn y2v_is_the_same_for_any_thread_count() {
    let p = wide_swatch();
    let y = knit_swatch(&p);
    let e = embed(&y, &EmbedParams::default()).unwrap();
    let (w, h) = (p.wale_width, p.course_height);
    let frame = loops(
        p.courses,
        p.wales,
        p.points_per_loop,
        1.2 * w,
        0.95 * h,
        0.6,
        0.2 * w,
    );
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let f = ShapeFitter::from_embedded(&y, &e, &ShapeFitParams::default()).unwrap();
                let (nodes, stats) = f.fit(&frame).unwrap();
                (
                    f.prepare.stencil_taps,
                    nodes,
                    stats.rms_error,
                    stats.min_det_f,
                )
            })
    };
    assert_eq!(run(1), run(3));
}

/// A lone planar yarn has no neighbourhood that spans 3D: every segment
/// falls back to rotation-only normals, and rigid motions stay exact.
#[test]
fn y2v_planar_yarn_falls_back_to_rotations() {
    let pts: Vec<Vec3> = (0..80)
        .map(|i| {
            let t = i as f64 * 0.25;
            [1e-3 * t, 2e-3 * t.sin(), 0.0]
        })
        .collect();
    let mut y = Yarns::new();
    y.push_curve(&pts, false, 2e-4);
    let e = embed(&y, &EmbedParams::default()).unwrap();
    let fitter = ShapeFitter::from_embedded(&y, &e, &ShapeFitParams::default()).unwrap();
    assert_eq!(fitter.prepare.segments, 79);
    assert_eq!(fitter.prepare.affine_segments, 0);
    assert_eq!(fitter.prepare.stencil_taps, 0);
    let size = y.bounds().unwrap().diagonal();
    let r = Rotation3::new(Vector3::new(0.3, -1.1, 0.7)).into_inner();
    let t = Vector3::new(0.01, -0.02, 0.5);
    let (nodes, stats) = fitter.fit(&apply(&r, &t, &y.points)).unwrap();
    let expect = apply(&r, &t, &e.mesh.nodes);
    let err = nodes
        .iter()
        .zip(&expect)
        .map(|(p, q)| dist(*p, *q))
        .fold(0.0, f64::max);
    assert!(err < 1e-9 * size, "node error {err:e}");
    assert!(stats.rms_error < 1e-9 * size);
}

/// A mirrored pose (det A < 0) has no orientation-preserving F^Y: the guard
/// falls back to rotations, the fit stays finite, and the report says how
/// many tets it had to turn inside out.
#[test]
fn y2v_mirror_is_guarded_and_reported() {
    let (y, e, fitter) = fixture(&small_swatch());
    let m = Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0));
    let (nodes, stats) = fitter
        .fit(&apply(&m, &Vector3::zeros(), &y.points))
        .unwrap();
    assert!(nodes.iter().flatten().all(|x| x.is_finite()));
    let (inverted, min_det) = det_stats(&e.mesh, &nodes);
    eprintln!("mirror: {stats:?}");
    assert_eq!(stats.inverted_tets, inverted);
    assert!((stats.min_det_f - min_det).abs() < 1e-12);
    assert!(stats.min_det_f.is_finite());
}
