//! Embedding + Y2V + V2Y through the library and the CLI.
mod common;

use std::path::Path;
use std::process::Command;

use knitvox::embed::{embed, EmbedParams};
use knitvox::fit::{ShapeFitParams, ShapeFitter};
use knitvox::geom::{Vec3, Yarns};
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};
use nalgebra::{Matrix3, Rotation3, Vector3};

fn swatch() -> Yarns {
    knit_swatch(&SwatchParams {
        courses: 4,
        wales: 4,
        points_per_loop: 16,
        ..Default::default()
    })
}

fn fitter_for(y: &Yarns) -> (knitvox::embed::Embedded, ShapeFitter) {
    let e = embed(y, &EmbedParams::default()).unwrap();
    let f = ShapeFitter::from_embedded(y, &e, &ShapeFitParams::default()).unwrap();
    (e, f)
}

fn apply(m: &Matrix3<f64>, t: Vector3<f64>, pts: &[Vec3]) -> Vec<Vec3> {
    pts.iter()
        .map(|p| {
            let q = m * Vector3::new(p[0], p[1], p[2]) + t;
            [q[0], q[1], q[2]]
        })
        .collect()
}

fn max_dist(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| knitvox::geom::dist(*p, *q))
        .fold(0.0, f64::max)
}

#[test]
fn y2v_is_exact_for_rigid_motion() {
    let y = swatch();
    let (e, fitter) = fitter_for(&y);
    let size = y.bounds().unwrap().diagonal();
    for (axis, t) in [
        (Vector3::new(0.3, -1.1, 0.7), Vector3::new(0.01, -0.02, 0.5)),
        (Vector3::new(0.0, 2.5, 0.0), Vector3::new(-1.0, 0.0, 0.0)),
    ] {
        let r = Rotation3::new(axis).into_inner();
        let moved = apply(&r, t, &y.points);
        let (nodes, stats) = fitter.fit(&moved).unwrap();
        let expect = apply(&r, t, &e.mesh.nodes);
        let node_err = max_dist(&nodes, &expect);
        assert!(
            node_err < 1e-9 * size,
            "Y2V node error {node_err:e} for a rigid motion"
        );
        let back = e.embedding.v2y(&e.mesh, &nodes);
        let yarn_err = max_dist(&back, &moved);
        assert!(yarn_err < 1e-9 * size, "V2Y(Y2V(x)) error {yarn_err:e}");
        assert!(stats.rms_error < 1e-9 * size);
    }
}

#[test]
fn y2v_scale_and_affine_errors_are_reported_and_bounded() {
    let y = swatch();
    let (_, fitter) = fitter_for(&y);
    let size = y.bounds().unwrap().diagonal();
    let cases = [
        ("uniform scale 1.2", Matrix3::identity() * 1.2),
        (
            "stretch x 1.3",
            Matrix3::from_diagonal(&Vector3::new(1.3, 1.0, 1.0)),
        ),
        (
            "general affine",
            Matrix3::new(1.1, 0.2, 0.0, -0.1, 0.95, 0.15, 0.05, 0.0, 1.05),
        ),
    ];
    for (name, m) in cases {
        let moved = apply(&m, Vector3::new(0.001, 0.002, 0.0), &y.points);
        let displacement = max_dist(&moved, &y.points);
        let (_, stats) = fitter.fit(&moved).unwrap();
        eprintln!(
            "Y2V {name}: V2Y(Y2V(x)) RMS error {:.3e} m, max {:.3e} m (bbox diagonal {size:.3e} m, max displacement {displacement:.3e} m)",
            stats.rms_error, stats.max_error
        );
        assert!(
            stats.max_error.is_finite() && stats.max_error < 0.5 * displacement,
            "{name}: {stats:?}"
        );
    }
}

#[test]
fn y2v_is_deterministic_and_rejects_bad_frames() {
    let y = swatch();
    let (_, fitter) = fitter_for(&y);
    let moved = apply(
        &Matrix3::from_diagonal(&Vector3::new(1.1, 0.9, 1.0)),
        Vector3::zeros(),
        &y.points,
    );
    assert_eq!(fitter.fit(&moved).unwrap().0, fitter.fit(&moved).unwrap().0);
    assert!(fitter.fit(&moved[1..]).is_err());
    let mut nan = moved.clone();
    nan[3][1] = f64::NAN;
    assert!(fitter.fit(&nan).is_err());
}

fn knitvox(args: &[&str]) -> std::process::Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .unwrap()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

#[test]
fn embed_shapefit_export_cli() {
    let dir = tempfile::tempdir().unwrap();
    let y = swatch();
    let yarns = dir.path().join("swatch.h5");
    let frames = knitvox::pipeline::demo::demo_frames(&y, 4);
    knitvox::io::write_path(&yarns, &y, Some(&frames), &Default::default()).unwrap();
    let asset = dir.path().join("swatch.vtkhdf");
    let o = knitvox(&["embed", p(&yarns), "-o", p(&asset), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = knitvox(&["inspect", "--json", p(&asset)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Nothing to export yet: an error naming the asset, not an empty folder.
    let empty = dir.path().join("empty");
    let o = knitvox(&["export", p(&asset), "-o", p(&empty)]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(e.contains("no steps") && e.contains("swatch.vtkhdf"), "{e}");
    assert!(!empty.exists() || std::fs::read_dir(&empty).unwrap().next().is_none());
    let o = knitvox(&[
        "shapefit",
        p(&asset),
        p(&yarns),
        "--frames",
        "0-3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["frames"], 4);
    let out = dir.path().join("out");
    let o = knitvox(&[
        "export",
        p(&asset),
        "--frames",
        "0,2",
        "--format",
        "ply",
        "-o",
        p(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for s in [0, 2] {
        let f = out.join(format!("swatch.{s:04}.ply"));
        let d = knitvox::io::read_path(&f, &Default::default()).unwrap();
        assert!(d.yarns.same_topology(&y));
        // The exported yarns follow the frame they were fitted to.
        let err = max_dist(&d.yarns.points, frames.frame(s));
        assert!(
            err < 0.25 * y.bounds().unwrap().diagonal(),
            "step {s}: {err}"
        );
    }
    // A step the asset lacks: the option is wrong, not the file (exit 2).
    let o = knitvox(&["export", p(&asset), "--frames", "7", "-o", p(&out)]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("--frames 7"), "{e}");
}

#[test]
fn embed_bad_input_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let y = swatch();
    let yarns = dir.path().join("s.ply");
    knitvox::io::write_path(&yarns, &y, None, &Default::default()).unwrap();
    let asset = dir.path().join("a.vtkhdf");
    for (flags, what, code) in [
        // Bad option values are usage errors naming the option.
        (vec!["--voxel-size", "0"], "zero voxel size", 2),
        (vec!["--voxel-size=-1"], "negative voxel size", 2),
        (
            vec!["--voxel-size", "1e-7", "--max-voxels", "100000"],
            "too many voxels",
            2,
        ),
    ] {
        let mut args = vec!["embed", p(&yarns), "-o", p(&asset)];
        args.extend(flags);
        let o = knitvox(&args);
        assert_eq!(
            o.status.code(),
            Some(code),
            "{what}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!asset.exists(), "{what}: wrote an asset");
    }
}

#[test]
fn y2v_is_identical_for_any_thread_count() {
    let y = swatch();
    let moved = apply(
        &Matrix3::new(1.1, 0.2, 0.0, -0.1, 0.95, 0.15, 0.05, 0.0, 1.05),
        Vector3::zeros(),
        &y.points,
    );
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let (_, f) = fitter_for(&y);
                f.fit(&moved).unwrap().0
            })
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(3));
}
