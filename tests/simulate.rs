//! `knitvox simulate` and the shot stage: scene errors, a drape over a
//! sphere, a swatch pinned to Fox.glb walking, exit codes, divergence.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use knitvox::embed::EmbedParams;
use knitvox::geom::Vec3;
use knitvox::io::{self, vtkhdf, ReadOptions, WriteOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::pipeline::sim_scene::Scene;
use knitvox::pipeline::simulate::{simulate, ShotRequest, SimulateError};
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};

/// A small swatch asset (4 x 4 loops, no ring, 2.5 mm voxels) in `dir`.
fn small_asset(dir: &Path) -> PathBuf {
    let yarns = knit_swatch(&SwatchParams {
        courses: 4,
        wales: 4,
        with_ring: false,
        points_per_loop: 12,
        ..SwatchParams::default()
    });
    let bcc = dir.join("swatch.bcc");
    io::write_path(&bcc, &yarns, None, &WriteOptions::default()).unwrap();
    let read = ReadOptions {
        radius: yarns.radius[0],
        ..ReadOptions::default()
    };
    let (asset, _) = build_asset(
        &bcc,
        &read,
        &EmbedParams {
            voxel_size: Some(2.5e-3),
            ..EmbedParams::default()
        },
        "test",
    )
    .unwrap();
    let path = dir.join("swatch.vtkhdf");
    vtkhdf::write_asset(&path, &asset).unwrap();
    path
}

fn fox() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb");
    assert!(
        p.is_file(),
        "examples/Fox.glb is committed with its credits"
    );
    p
}

fn run(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn request(dir: &Path, frames: Vec<i64>, yarns: Option<&str>) -> ShotRequest {
    ShotRequest {
        frames,
        output: dir.join("out.vtkhdf"),
        yarns_out: yarns.map(|y| dir.join(y)),
        write: WriteOptions::default(),
        command: "test".into(),
    }
}

fn sphere_dist(p: Vec3, c: Vec3, r: f64) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt() - r
}

#[test]
fn swatch_drapes_over_a_sphere_without_entering_it() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    // The swatch lies flat 2 mm above a 12 mm sphere and falls onto it.
    let scene = Scene::parse(
        r#"
[simulation]
dt = "1/150"
fps = 24
[garment]
rotate_deg = [-90, 0, 0]
center = [0.0, 0.016, 0.0]
[[collider]]
type = "sphere"
center = [0.0, 0.0, 0.0]
radius = 0.012
thickness = 0.001
"#,
        Path::new("scene.toml"),
    )
    .unwrap();
    let r = simulate(
        &asset,
        &asset_path,
        &scene,
        &request(dir.path(), (1..=4).collect(), Some("drape.####.ply")),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(r.frames, 4);
    let out = vtkhdf::read_asset(&dir.path().join("out.vtkhdf")).unwrap();
    assert_eq!(out.steps.num_steps(), 4);
    let n = out.mesh.num_nodes();
    let first = out.steps.step(0, n);
    let last = out.steps.step(3, n);
    let worst = last
        .iter()
        .map(|p| sphere_dist(*p, [0.0; 3], 0.012))
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "drape: min distance to the sphere {worst:.3e} m, max penetration {:.3e} m",
        r.max_penetration_m
    );
    assert!(worst >= -1e-3, "a node is {worst} m inside the sphere");
    assert!(r.max_penetration_m <= 1e-3);
    // Yarn vertices (V2Y) too, within the stated tolerance and no
    // penetration warning (the unconverged steps are noted apart).
    let yarns = r.max_penetration_yarns_m.unwrap();
    eprintln!("drape: yarn vertices up to {yarns:.3e} m inside");
    assert!(yarns <= r.penetration_tolerance_m);
    assert!(
        !r.notes.iter().any(|n| n.contains("inside a collider")),
        "{:?}",
        r.notes
    );
    assert_eq!(
        r.notes.iter().any(|n| n.contains("iteration cap")),
        r.pd_capped_steps > 0,
        "{:?}",
        r.notes
    );
    // It fell and touches the sphere (not a frozen swatch): at least 90% of
    // the gap between its lowest node and the 1 mm thickness band (with the
    // default friction 0.5 the nodes that land stick instead of sliding a
    // little further down, as they did while friction was inert).
    let drop = first
        .iter()
        .zip(last.iter())
        .map(|(a, b)| a[1] - b[1])
        .fold(f64::NEG_INFINITY, f64::max);
    let gap = first
        .iter()
        .map(|p| sphere_dist(*p, [0.0; 3], 0.012))
        .fold(f64::INFINITY, f64::min)
        - 1e-3;
    eprintln!("drape: largest drop {drop:.3e} m (gap to the thickness band {gap:.3e} m)");
    assert!(gap > 3e-4, "the scene must start with a gap ({gap} m)");
    assert!(drop > 0.9 * gap, "the swatch did not fall ({drop} m)");
    assert!(
        worst < 3e-3,
        "the swatch never reached the sphere ({worst} m)"
    );
    for f in 1..=4 {
        assert!(dir.path().join(format!("drape.{f:04}.ply")).is_file());
    }
}

/// Mean displacement (m) of the swatch down a 20° plane between the second
/// and the last of 13 frames (0.5 s) with the scene's `friction`.
fn slide_down_a_slope(dir: &Path, asset_path: &Path, friction: f64) -> f64 {
    let asset = vtkhdf::read_asset(asset_path).unwrap();
    let th = 20f64.to_radians();
    let (s, c) = (th.sin(), th.cos());
    // Laid flat, then turned -20° about z: parallel to the plane, 6 mm
    // above it along its normal.
    let scene = Scene::parse(
        &format!(
            r#"
[simulation]
friction = {friction}
[garment]
rotate_deg = [-90, 0, -20]
center = [{}, {}, 0.0]
[[collider]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [{s}, {c}, 0.0]
"#,
            0.006 * s,
            0.006 * c
        ),
        Path::new("scene.toml"),
    )
    .unwrap();
    simulate(
        &asset,
        asset_path,
        &scene,
        &request(dir, (1..=13).collect(), None),
        &mut |_, _| {},
    )
    .unwrap();
    let out = vtkhdf::read_asset(&dir.join("out.vtkhdf")).unwrap();
    let n = out.mesh.num_nodes();
    let (a, b) = (out.steps.step(1, n), out.steps.step(12, n));
    a.iter()
        .zip(b.iter())
        .map(|(p, q)| (q[0] - p[0]) * c - (q[1] - p[1]) * s)
        .sum::<f64>()
        / n as f64
}

#[test]
fn scene_friction_holds_or_lets_the_swatch_slide_down_a_slope() {
    // Friction on a slope through the shot stage: `simulation.friction`
    // reaches the contacts. tan 20° = 0.36: 0.6 holds the landed swatch, 0.1 lets it
    // slide at g (sin θ - μ cos θ) = 2.4 m/s² (0.23 m over the 0.46 s).
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let held = slide_down_a_slope(dir.path(), &asset_path, 0.6);
    let slid = slide_down_a_slope(dir.path(), &asset_path, 0.1);
    eprintln!("slope: friction 0.6 moved {held:.3e} m, 0.1 slid {slid:.3e} m");
    assert!(held.abs() < 1e-3, "friction 0.6: moved {held} m");
    assert!(slid > 0.1, "friction 0.1: slid only {slid} m");
}

#[test]
fn swatch_pinned_to_walking_fox_stays_outside_the_body() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let scene = Scene::parse(
        &format!(
            r#"
[simulation]
preroll = 0.04
[garment]
rotate_deg = [-90, 0, 0]
[character]
file = "{}"
animation = "Walk"
scale = 0.0025
fit_joint = "b_Spine02_03"
pin_distance = 0.003
"#,
            fox().display()
        ),
        Path::new("scene.toml"),
    )
    .unwrap();
    let frames = vec![1, 2, 3];
    let r = simulate(
        &asset,
        &asset_path,
        &scene,
        &request(dir.path(), frames.clone(), Some("fox.h5")),
        &mut |_, _| {},
    )
    .unwrap();
    let pen = r.max_penetration_body_m.unwrap();
    eprintln!(
        "fox: {} body pins, max penetration into the body {pen:.3e} m, min distance {:?}, {} steps",
        r.pinned_body, r.min_distance_m, r.steps
    );
    assert!(r.pinned_body > 0);
    assert!(pen <= 1e-3, "penetration {pen} m");
    let yarns = r.max_penetration_yarns_m.unwrap();
    eprintln!("fox: yarn vertices up to {yarns:.3e} m inside");
    assert!(
        yarns <= r.penetration_tolerance_m,
        "yarn vertices {yarns} m inside"
    );
    let out = vtkhdf::read_asset(&dir.path().join("out.vtkhdf")).unwrap();
    assert_eq!(out.steps.num_steps(), frames.len());
    let yarns = io::read_path(&dir.path().join("fox.h5"), &ReadOptions::default()).unwrap();
    assert_eq!(yarns.frames.unwrap().num_frames(), frames.len());
}

#[test]
fn divergence_names_the_step() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let scene = Scene::parse(
        "[simulation]\ngravity = [0.0, -1.0e7, 0.0]\n",
        Path::new("s.toml"),
    )
    .unwrap();
    let e = simulate(
        &asset,
        &asset_path,
        &scene,
        &request(dir.path(), vec![1, 2], None),
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(matches!(e, SimulateError::Diverged { .. }), "{e}");
    assert_eq!(e.diverged_step(), Some(1));
    assert!(e.to_string().contains("step 1"), "{e}");
    // The CLI maps it to bad input (65) with the step in the message.
    let scene = dir.path().join("blowup.toml");
    std::fs::write(&scene, "[simulation]\ngravity = [0.0, -1.0e7, 0.0]\n").unwrap();
    let (code, _, err) = run(&[
        "simulate",
        asset_path.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "1-2",
        "-o",
        dir.path().join("o.vtkhdf").to_str().unwrap(),
    ]);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("step 1"), "{err}");
}

#[test]
fn malformed_scenes_exit_65_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let cases = [
        (
            "unknown.toml",
            "[simulation]\ntime_step = 0.01\n",
            "time_step",
        ),
        (
            "radius.toml",
            "[[collider]]\ntype = \"sphere\"\ncenter = [0, 0, 0]\nradius = -1.0\n",
            "collider[0].radius",
        ),
        ("dt.toml", "[simulation]\ndt = \"one/150\"\n", "dt"),
        ("syntax.toml", "[simulation\n", "simulation"),
        ("kind.toml", "[[collider]]\ntype = \"cone\"\n", "cone"),
    ];
    for (name, text, key) in cases {
        let scene = dir.path().join(name);
        std::fs::write(&scene, text).unwrap();
        let (code, _, err) = run(&[
            "simulate",
            asset_path.to_str().unwrap(),
            "--scene",
            scene.to_str().unwrap(),
            "--frames",
            "1-2",
            "-o",
            dir.path().join("o.vtkhdf").to_str().unwrap(),
        ]);
        assert_eq!(code, 65, "{name}: {err}");
        assert!(
            err.contains(name),
            "{name}: the message names the file: {err}"
        );
        assert!(
            err.contains(key),
            "{name}: the message names the key {key}: {err}"
        );
    }
}

#[test]
fn cli_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let a = asset_path.to_str().unwrap();
    let o = dir.path().join("o.vtkhdf");
    let o = o.to_str().unwrap();
    let fox = fox();
    let fox = fox.to_str().unwrap();
    // Usage: neither or both drivers, bad frame spec, bad backend.
    assert_eq!(run(&["simulate", a, "--frames", "1-2", "-o", o]).0, 2);
    assert_eq!(
        run(&[
            "simulate",
            a,
            "--scene",
            "x.toml",
            "--character",
            fox,
            "--frames",
            "1",
            "-o",
            o
        ])
        .0,
        2
    );
    assert_eq!(
        run(&[
            "simulate",
            a,
            "--character",
            fox,
            "--frames",
            "x-y",
            "-o",
            o
        ])
        .0,
        2
    );
    assert_eq!(
        run(&[
            "simulate",
            a,
            "--character",
            fox,
            "--frames",
            "1",
            "--backend",
            "tpu",
            "-o",
            o
        ])
        .0,
        2
    );
    // Missing asset / scene: 66.
    let missing = dir.path().join("missing.vtkhdf");
    assert_eq!(
        run(&[
            "simulate",
            missing.to_str().unwrap(),
            "--character",
            fox,
            "--frames",
            "1",
            "-o",
            o
        ])
        .0,
        66
    );
    assert_eq!(
        run(&[
            "simulate",
            a,
            "--scene",
            "/nonexistent/s.toml",
            "--frames",
            "1",
            "-o",
            o
        ])
        .0,
        66
    );
    // GPU backend: runs where wgpu finds an adapter (lavapipe included),
    // else a clear message and exit 69 (unavailable, not bad input).
    let have_gpu = knitvox::sim::gpu::GpuContext::new().is_ok();
    let (code, _, err) = run(&[
        "simulate",
        a,
        "--character",
        fox,
        "--frames",
        "1",
        "--backend",
        "gpu",
        "-o",
        o,
    ]);
    if have_gpu {
        // The backend is accepted; this shot then fails for its placement
        // (no node near the body without --fit-joint), not for the GPU.
        assert!(!err.contains("GPU"), "{err}");
    } else {
        assert_eq!(code, 69, "{err}");
        assert!(err.contains("no usable GPU"), "{err}");
    }
    // Unknown --animation: a usage error (2) naming it and the file's.
    let (code, _, err) = run(&[
        "simulate",
        a,
        "--character",
        fox,
        "--animation",
        "Dance",
        "--frames",
        "1",
        "-o",
        o,
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("Dance") && err.contains("Walk"), "{err}");
    // Garment nowhere near the (unscaled, 80 m) fox: no pins, 65 with advice.
    let (code, _, err) = run(&["simulate", a, "--character", fox, "--frames", "1", "-o", o]);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("pin"), "{err}");
    // Output folder missing: 74, before any simulation.
    let (code, _, err) = run(&[
        "simulate",
        a,
        "--character",
        fox,
        "--frames",
        "1",
        "-o",
        "/nonexistent-dir/o.vtkhdf",
    ]);
    assert_eq!(code, 74, "{err}");
}

#[test]
fn cli_character_shot_writes_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let o = dir.path().join("shot.vtkhdf");
    let y = dir.path().join("yarns.####.bcc");
    let (code, out, err) = run(&[
        "simulate",
        asset_path.to_str().unwrap(),
        "--character",
        fox().to_str().unwrap(),
        "--animation",
        "Walk",
        "--character-scale",
        "0.0025",
        "--fit-joint",
        "b_Spine02_03",
        "--garment-rotate",
        "-90,0,0",
        "--preroll",
        "0.02",
        "--frames",
        "10,12",
        "-o",
        o.to_str().unwrap(),
        "--yarns-out",
        y.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    // The report is the last line, after one JSON line per frame.
    let v: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    assert_eq!(v["frames"], 2);
    assert!(v["max_penetration_body_m"].as_f64().unwrap() <= 1e-3);
    // The yarn vertices' figure sits next to it, with the tolerance.
    let tol = v["penetration_tolerance_m"].as_f64().unwrap();
    assert!(v["max_penetration_yarns_m"].as_f64().unwrap() <= tol);
    assert!(dir.path().join("yarns.0010.bcc").is_file());
    assert!(dir.path().join("yarns.0012.bcc").is_file());
    assert!(!dir.path().join("yarns.0011.bcc").exists());
    let s = vtkhdf::read_asset(&o).unwrap();
    assert_eq!(s.steps.times, vec![10.0 / 24.0, 12.0 / 24.0]);
}

#[test]
fn scripted_handles_follow_their_motion() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let n = asset.mesh.num_nodes();
    // Left edge fixed, right edge pulled +x at 2 cm/s, no gravity.
    let xs: Vec<f64> = asset.mesh.nodes.iter().map(|p| p[0]).collect();
    let (lo, hi) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let scene = Scene::parse(
        &format!(
            r#"
[simulation]
gravity = [0.0, 0.0, 0.0]
[[pin]]
name = "left"
box_min = [-1.0, -1.0, -1.0]
box_max = [{l}, 1.0, 1.0]
[[pin]]
name = "right"
box_min = [{r}, -1.0, -1.0]
box_max = [1.0, 1.0, 1.0]
velocity = [0.02, 0.0, 0.0]
"#,
            l = lo + 1e-4,
            r = hi - 1e-4
        ),
        Path::new("s.toml"),
    )
    .unwrap();
    let r = simulate(
        &asset,
        &asset_path,
        &scene,
        &request(dir.path(), vec![1, 3], None),
        &mut |_, _| {},
    )
    .unwrap();
    assert!(r.pinned_scripted > 0);
    let out = vtkhdf::read_asset(&dir.path().join("out.vtkhdf")).unwrap();
    let last = out.steps.step(1, n);
    let t = 2.0 / 24.0;
    for (i, p) in asset.mesh.nodes.iter().enumerate() {
        if p[0] <= lo + 1e-4 {
            assert!((last[i][0] - p[0]).abs() < 1e-12);
        }
        if p[0] >= hi - 1e-4 {
            assert!(
                (last[i][0] - (p[0] + 0.02 * t)).abs() < 1e-12,
                "{} vs {}",
                last[i][0],
                p[0] + 0.02 * t
            );
        }
    }
    // The free middle stretched along: some node moved +x.
    assert!(last
        .iter()
        .zip(&asset.mesh.nodes)
        .any(|(a, b)| a[0] - b[0] > 1e-5));
}

/// The shot measures how far its yarns (V2Y of the nodes) stretch from
/// their rest segment lengths: a free fall moves them rigidly (no stretch,
/// no warning); an edge pulled away fast stretches them past the bounds,
/// which warns naming the frame of the largest stretch.
#[test]
fn yarn_stretch_is_measured_over_the_shot_and_warned_past_its_bounds() {
    use knitvox::pipeline::simulate::{STRETCH_MAX_BOUND, STRETCH_P99_BOUND};
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let shot = |scene: &str| {
        let scene = Scene::parse(scene, Path::new("s.toml")).unwrap();
        simulate(
            &asset,
            &asset_path,
            &scene,
            &request(dir.path(), (1..=3).collect(), None),
            &mut |_, _| {},
        )
        .unwrap()
    };
    let stretch_notes = |r: &knitvox::pipeline::simulate::SimulateReport| {
        r.notes
            .iter()
            .filter(|n| n.contains("the yarns stretch"))
            .cloned()
            .collect::<Vec<_>>()
    };
    let fall = shot("[simulation]\ngravity = [0.0, -9.81, 0.0]\n");
    let (p99, max) = (
        fall.yarn_stretch_p99.unwrap(),
        fall.yarn_stretch_max.unwrap(),
    );
    assert!(p99 < 1e-6 && max < 1e-6, "{p99} {max}");
    assert!(stretch_notes(&fall).is_empty(), "{:?}", fall.notes);
    assert_eq!(fall.yarn_stretch_bound_p99, STRETCH_P99_BOUND);
    let (lo, hi) = asset
        .mesh
        .nodes
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p[0]), b.max(p[0]))
        });
    let pulled = shot(&format!(
        r#"
[simulation]
gravity = [0.0, 0.0, 0.0]
[[pin]]
name = "left"
box_min = [-1.0, -1.0, -1.0]
box_max = [{l}, 1.0, 1.0]
[[pin]]
name = "right"
box_min = [{r}, -1.0, -1.0]
box_max = [1.0, 1.0, 1.0]
velocity = [{v}, 0.0, 0.0]
"#,
        l = lo + 1e-4,
        r = hi - 1e-4,
        // Half the width over the two frame intervals.
        v = 0.5 * (hi - lo) * 12.0
    ));
    let (p99, max) = (
        pulled.yarn_stretch_p99.unwrap(),
        pulled.yarn_stretch_max.unwrap(),
    );
    assert!(max > STRETCH_MAX_BOUND && p99 <= max, "{p99} {max}");
    // Stretched more at each frame: the largest is the last frame's.
    assert_eq!(pulled.yarn_stretch_max_frame, Some(3));
    let w = stretch_notes(&pulled);
    assert_eq!(w.len(), 1, "{:?}", pulled.notes);
    assert!(
        w[0].starts_with("warning: ") && w[0].contains("(frame 3)"),
        "{w:?}"
    );
    assert!(w[0].contains("knitvox fit"), "{w:?}");
    let v = serde_json::to_value(&pulled).unwrap();
    for k in [
        "yarn_stretch_p99",
        "yarn_stretch_max",
        "yarn_stretch_max_frame",
        "yarn_stretch_bound_p99",
        "yarn_stretch_bound_max",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
}

/// Every frame or none appears under its final name: a failing
/// `--yarns-out` leaves no fresh asset and no partial frame sequence; `-o` equal to the asset is refused (exit 2).
#[test]
fn failing_yarns_out_leaves_no_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let scene = dir.path().join("s.toml");
    std::fs::write(&scene, "[simulation]\n").unwrap();
    // Frame 2's file name is taken by a folder: its rename fails.
    std::fs::create_dir_all(dir.path().join("ys/s.0002.ply")).unwrap();
    let out = dir.path().join("out.vtkhdf");
    let ys = dir.path().join("ys/s.####.ply");
    let (code, _, err) = run(&[
        "simulate",
        asset_path.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "1-2",
        "-o",
        out.to_str().unwrap(),
        "--yarns-out",
        ys.to_str().unwrap(),
    ]);
    assert_ne!(code, 0, "{err}");
    assert!(!out.exists(), "a fresh asset was left: {err}");
    assert!(
        !dir.path().join("ys/s.0001.ply").exists(),
        "a partial sequence was left"
    );
    // Output == input.
    let before = std::fs::read(&asset_path).unwrap();
    let (code, _, err) = run(&[
        "simulate",
        asset_path.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "1-2",
        "-o",
        asset_path.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("never overwrites an input"), "{err}");
    assert_eq!(std::fs::read(&asset_path).unwrap(), before);
}

/// Largest depth (m) of the yarn vertices of every frame of `yarns_h5` below
/// the plane y = 0.
fn depth_below_y0(yarns_h5: &Path) -> f64 {
    let y = io::read_path(yarns_h5, &ReadOptions::default()).unwrap();
    let frames = y.frames.unwrap();
    (0..frames.num_frames())
        .flat_map(|f| frames.frame(f).iter().map(|p| -p[1]).collect::<Vec<_>>())
        .fold(0.0, f64::max)
}

#[test]
fn yarn_vertex_penetration_is_reported_and_warned_beyond_the_tolerance() {
    // The swatch straddles the plane y = 0 and every node
    // is pinned there (pins are never projected): no free tet node is inside
    // (max_penetration_m 0), but half the yarn vertices are, which only the
    // yarn figure sees; it matches the depth recomputed from the written
    // yarn frames and exceeds the 1 mm tolerance, hence a warning.
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let scene = Scene::parse(
        r#"
[simulation]
fps = 24
[garment]
rotate_deg = [-90, 0, 0]
center = [0.0, -0.001, 0.0]
[[pin]]
name = "all"
box_min = [-1.0, -1.0, -1.0]
box_max = [1.0, 1.0, 1.0]
[[collider]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
thickness = 0.0
"#,
        Path::new("scene.toml"),
    )
    .unwrap();
    let r = simulate(
        &asset,
        &asset_path,
        &scene,
        &request(dir.path(), vec![1, 2], Some("y.h5")),
        &mut |_, _| {},
    )
    .unwrap();
    let yarns = r.max_penetration_yarns_m.unwrap();
    let expect = depth_below_y0(&dir.path().join("y.h5"));
    eprintln!(
        "straddling: tet nodes {:.3e} m, yarn vertices {yarns:.3e} m (from the frames {expect:.3e} m), notes {:?}",
        r.max_penetration_m, r.notes
    );
    assert_eq!(r.max_penetration_m, 0.0);
    assert!((yarns - expect).abs() < 1e-12, "{yarns} vs {expect}");
    assert_eq!(r.penetration_tolerance_m, 1e-3);
    assert!(yarns > r.penetration_tolerance_m);
    let warned: Vec<_> = r
        .notes
        .iter()
        .filter(|n| n.contains("yarn vertices"))
        .collect();
    assert_eq!(warned.len(), 1, "{:?}", r.notes);
    assert!(warned[0].contains("tolerance of 0.001 m"), "{}", warned[0]);
}

/// Node positions of every written frame of a flat swatch held by its
/// left edge, bending under gravity (4 frames, `solver`), and the report.
fn hang(
    dir: &Path,
    asset_path: &Path,
    solver: &str,
) -> (Vec<Vec3>, knitvox::pipeline::simulate::SimulateReport) {
    let asset = vtkhdf::read_asset(asset_path).unwrap();
    let lo = asset
        .mesh
        .nodes
        .iter()
        .map(|p| p[0])
        .fold(f64::INFINITY, f64::min);
    let scene = Scene::parse(
        &format!(
            r#"
[simulation]
solver = "{solver}"
[garment]
rotate_deg = [-90, 0, 0]
[[pin]]
name = "left"
box_min = [-1.0, -1.0, -1.0]
box_max = [{}, 1.0, 1.0]
"#,
            lo + 1e-4
        ),
        Path::new("scene.toml"),
    )
    .unwrap();
    let r = simulate(
        &asset,
        asset_path,
        &scene,
        &request(dir, (1..=4).collect(), None),
        &mut |_, _| {},
    )
    .unwrap();
    let out = vtkhdf::read_asset(&dir.join("out.vtkhdf")).unwrap();
    (out.steps.positions, r)
}

#[test]
fn dd_solver_takes_its_partition_from_the_asset_domains() {
    // `embed` writes domain 0 everywhere: the DD solver
    // bisects (one domain for this small swatch). An asset whose
    // CellData/domain names three slabs along x gets exactly those three
    // domains, and its shot matches the direct solver's.
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let (direct, rd) = hang(dir.path(), &asset_path, "direct");
    assert_eq!((rd.dd_domains, rd.dd_partition), (None, None));
    let (_, rb) = hang(dir.path(), &asset_path, "dd");
    assert_eq!(rb.dd_partition, Some("bisection"));
    assert_eq!(rb.dd_domains, Some(1));

    let mut asset = vtkhdf::read_asset(&asset_path).unwrap();
    let xs: Vec<f64> = (0..asset.mesh.num_tets())
        .map(|t| {
            let tet = asset.mesh.tets[t];
            tet.iter()
                .map(|&a| asset.mesh.nodes[a as usize][0])
                .sum::<f64>()
                / 4.0
        })
        .collect();
    let (lo, hi) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    // Ids 7, -3, 40: any int32 values name the domains.
    asset.domain = xs
        .iter()
        .map(|x| [7, -3, 40][(((x - lo) / (hi - lo) * 3.0) as usize).min(2)])
        .collect();
    let slabs = dir.path().join("slabs.vtkhdf");
    vtkhdf::write_asset(&slabs, &asset).unwrap();
    let (dd, rs) = hang(dir.path(), &slabs, "dd");
    assert_eq!(rs.dd_partition, Some("asset"));
    assert_eq!(rs.dd_domains, Some(3));
    let size = hi - lo;
    let err = direct
        .iter()
        .zip(&dd)
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    let n = asset.mesh.num_nodes();
    let sag = direct[..n]
        .iter()
        .zip(&direct[3 * n..])
        .map(|(a, b)| a[1] - b[1])
        .fold(0.0, f64::max);
    eprintln!(
        "dd with the asset's 3 domains vs direct: {:.3e} of the swatch ({size:.3e} m); sag {sag:.3e} m",
        err / size
    );
    assert!(sag > 5e-5, "the swatch hardly moved ({sag} m)");
    // DdParams::default().tolerance, relative to the swatch size.
    assert!(err < 1e-4 * size, "dd off by {err} m");
}

/// A character baked into an HDF5 cache (`knitvox bake`)
/// drives a shot as its glTF does. The swatch lies 3 mm over the walking
/// fox's back, pinned where it is within 4 mm of the body, the rest
/// colliding. Baked at 600 fps, every 1/150 s step lands on a sample, so
/// both shots see the same body (2e-10 m apart measured); between samples
/// the cache is ~5e-6 m from the skinned body (tests/character_cache.rs).
#[test]
fn baked_character_cache_drives_a_shot_like_its_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let cache = dir.path().join("fox.h5");
    let (code, out, err) = run(&[
        "bake",
        fox().to_str().unwrap(),
        "--animation",
        "Walk",
        "--fps",
        "600",
        "-o",
        cache.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["frames"], 426, "{v}"); // ceil(0.7083 s x 600) + 1
    let baked = io::character_h5::read_character_cache(&cache, 1 << 30)
        .unwrap()
        .cache;
    // The highest point of the back: the rest vertex highest within 4 and
    // 8 units (1 and 2 cm at the scale) of the body's centre in x and z.
    let rest = baked.rest_positions();
    let (lo, hi) = rest.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|k| lo[k].min(p[k])),
                std::array::from_fn(|k| hi[k].max(p[k])),
            )
        },
    );
    let c: Vec3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let top = rest
        .iter()
        .copied()
        .filter(|p| (p[0] - c[0]).abs() < 4.0 && (p[2] - c[2]).abs() < 8.0)
        .fold([0.0, f64::NEG_INFINITY, 0.0], |a, p| {
            if p[1] > a[1] {
                p
            } else {
                a
            }
        });
    let scale = 0.0025;
    // The glTF names its animation; a cache holds just the one it baked.
    let scene_for = |file: &Path, animation: &str| {
        Scene::parse(
            &format!(
                r#"
[simulation]
preroll = 0.02
[garment]
rotate_deg = [-90, 0, 0]
center = [{}, {}, {}]
[character]
file = "{}"
{animation}
scale = {scale}
pin_distance = 0.004
"#,
                top[0] * scale,
                top[1] * scale + 0.003,
                top[2] * scale,
                file.display()
            ),
            Path::new("scene.toml"),
        )
        .unwrap()
    };
    let shot = |file: &Path, animation: &str, name: &str| {
        let out = dir.path().join(name);
        std::fs::create_dir_all(&out).unwrap();
        let r = simulate(
            &asset,
            &asset_path,
            &scene_for(file, animation),
            &request(&out, vec![1, 2, 3, 4, 5, 6], Some("y.h5")),
            &mut |_, _| {},
        )
        .unwrap();
        let y = io::read_path(&out.join("y.h5"), &ReadOptions::default()).unwrap();
        (r, y.frames.unwrap())
    };
    let (rg, fg) = shot(&fox(), "animation = \"Walk\"", "gltf");
    let (rc, fc) = shot(&cache, "", "cache");
    // The swatch rides the body on its pins (so the body's motion matters).
    assert!(rg.pinned_body > 0 && rc.pinned_body == rg.pinned_body);
    let dmin = rg.min_distance_m.expect("free nodes near the body");
    assert_eq!(rc.character.as_ref().unwrap().animation, None);
    let mut worst = 0.0f64;
    for f in 0..fg.num_frames() {
        for (a, b) in fg.frame(f).iter().zip(fc.frame(f)) {
            let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            worst = worst.max(d);
        }
    }
    eprintln!(
        "baked vs glTF: largest yarn difference {worst:.3e} m, closest approach {dmin:.3e} m"
    );
    assert!(worst < 1e-6, "yarns differ by {worst} m");
    // A cache has no skeleton: --fit-joint is a usage error naming it.
    let (code, _, err) = run(&[
        "simulate",
        asset_path.to_str().unwrap(),
        "--character",
        cache.to_str().unwrap(),
        "--fit-joint",
        "b_Spine02_03",
        "--frames",
        "1",
        "-o",
        dir.path().join("x.vtkhdf").to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("character cache"), "{err}");
}

/// Heights (m) of the nodes and of the V2Y yarn vertices at the end of a
/// 0.5 s drop onto the floor y = 0 (collider thickness 1 mm) from 6 mm,
/// with `[simulation] contact = "{contact}"`, and what the report says.
fn drop_on_the_floor(dir: &Path, asset_path: &Path, contact: &str) -> (Vec<f64>, Vec<f64>, String) {
    let asset = vtkhdf::read_asset(asset_path).unwrap();
    let scene = Scene::parse(
        &format!(
            r#"
[simulation]
contact = "{contact}"
[garment]
rotate_deg = [-90, 0, 0]
center = [0.0, 0.006, 0.0]
[[collider]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
"#
        ),
        Path::new("scene.toml"),
    )
    .unwrap();
    let r = simulate(
        &asset,
        asset_path,
        &scene,
        &request(dir, (1..=13).collect(), None),
        &mut |_, _| {},
    )
    .unwrap();
    let said = serde_json::to_value(&r).unwrap()["contact"].to_string();
    let out = vtkhdf::read_asset(&dir.join("out.vtkhdf")).unwrap();
    let n = out.mesh.num_nodes();
    let last = out.steps.step(out.steps.times.len() - 1, n);
    let y = asset.embedding.v2y(&asset.mesh, last);
    (
        last.iter().map(|p| p[1]).collect(),
        y.iter().map(|p| p[1]).collect(),
        said,
    )
}

#[test]
fn yarn_contact_rests_the_yarns_their_radius_off_the_floor_where_node_contact_holds_the_nodes() {
    let dir = tempfile::tempdir().unwrap();
    let asset_path = small_asset(dir.path());
    let asset = vtkhdf::read_asset(&asset_path).unwrap();
    let r = asset.rest_yarns.radius_at(0);
    let (nodes_n, yarns_n, said_n) = drop_on_the_floor(dir.path(), &asset_path, "nodes");
    let (nodes_y, yarns_y, said_y) = drop_on_the_floor(dir.path(), &asset_path, "yarns");
    let min = |v: &[f64]| v.iter().cloned().fold(f64::INFINITY, f64::min);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    eprintln!(
        "radius {r:.2e} m; node contact: lowest node {:.3e} m, lowest yarn {:.3e} m, mean yarn {:.3e} m; \
         yarn contact: lowest node {:.3e} m, lowest yarn {:.3e} m, mean yarn {:.3e} m",
        min(&nodes_n),
        min(&yarns_n),
        mean(&yarns_n),
        min(&nodes_y),
        min(&yarns_y),
        mean(&yarns_y)
    );
    assert_eq!(said_n, "\"nodes\"");
    assert_eq!(said_y, "\"yarns\"");
    // Node contact: every node keeps the 1 mm thickness.
    assert!(min(&nodes_n) > 1e-3 - 1e-9, "{}", min(&nodes_n));
    // Yarn contact: every yarn vertex keeps its radius beyond it, the swatch
    // has landed (its lowest yarns within 0.1 mm of that), nodes under the
    // yarns go below the thickness, and the yarns rest lower than on nodes.
    let band = 1e-3 + r;
    assert!(min(&yarns_y) > band - 1e-9, "{} vs {band}", min(&yarns_y));
    assert!(min(&yarns_y) < band + 1e-4, "{} vs {band}", min(&yarns_y));
    assert!(min(&nodes_y) < 1e-3, "{}", min(&nodes_y));
    assert!(
        mean(&yarns_y) < mean(&yarns_n),
        "{} vs {}",
        mean(&yarns_y),
        mean(&yarns_n)
    );
}
