//! `knitvox yls`: yarn-level scenes end to end (generated swatch, scripted
//! pose, colliders, HDF5 frames with the scene and parameters stored), the
//! contact bound during stretches and a drape, and error reporting.

mod common;

use std::path::Path;
use std::process::Command;

use knitvox::io::h5;

fn run(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(common::knitvox_bin())
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A tiny scene: 3 x 3 stitches of `pattern`, `duration` s at 100 frames/s.
fn scene(pattern: &str, kind: &str, amount: f64, duration: f64, extra: &str) -> String {
    format!(
        r#"name = "{kind} test"
duration = {duration}
frame_rate = 100
gravity = [0.0, 0.0, 0.0]
{extra}
[swatch]
pattern = "{pattern}"
courses = 3
wales = 3

[pose]
kind = "{kind}"
amount = {amount}
ramp = {duration}
"#
    )
}

fn x_extent(points: &[[f64; 3]]) -> f64 {
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p[0]), h.max(p[0]))
        });
    hi - lo
}

fn first_and_last_frames(out: &Path) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let first = h5::read_frame(out, 0).unwrap();
    let last = h5::read_frame(out, h5::frame_count(out).unwrap() - 1).unwrap();
    (first, last)
}

/// The largest fall (m, along -Y) of any vertex between two frames.
fn largest_drop(first: &[[f64; 3]], last: &[[f64; 3]]) -> f64 {
    first
        .iter()
        .zip(last)
        .map(|(a, b)| a[1] - b[1])
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Runs a scene through the CLI and returns the JSON report.
fn run_scene(dir: &Path, name: &str, text: &str) -> (serde_json::Value, std::path::PathBuf) {
    let s = dir.join(format!("{name}.toml"));
    std::fs::write(&s, text).unwrap();
    let out = dir.join(format!("{name}.h5"));
    let (code, stdout, err) = run(&[
        "yls",
        s.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    // The report is the last line, after one JSON line per frame.
    let last = stdout.lines().last().unwrap_or("");
    (serde_json::from_str(last).unwrap(), out)
}

#[test]
fn stretch_scenes_keep_the_contact_bound_and_store_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    for pattern in ["rib1x1", "stockinette"] {
        let text = scene(pattern, "stretch_courses", 0.3, 0.03, "");
        let (r, out) = run_scene(dir.path(), pattern, &text);
        let ratio = r["min_distance_ratio"].as_f64().unwrap();
        eprintln!(
            "{pattern}: 30% stretch, {} vertices, {} steps, min distance / 2r {ratio:.3}",
            r["vertices"], r["steps"]
        );
        // The contact bound: never below 2r x 0.75, measured every step.
        assert!(ratio >= 0.75, "{pattern}: {ratio}");
        assert!(r["max_displacement_ratio"].as_f64().unwrap() <= 0.1 + 1e-9);
        // Rest frame + 3 frames; the clamped edge moved by 30% of the width.
        assert_eq!(h5::frame_count(&out).unwrap(), 4);
        let first = h5::read_frame(&out, 0).unwrap();
        let last = h5::read_frame(&out, 3).unwrap();
        let strain = x_extent(&last) / x_extent(&first) - 1.0;
        assert!((strain - 0.3).abs() < 0.02, "{pattern}: strain {strain}");
        // The scene and the parameters travel with the frames.
        assert_eq!(
            h5::read_text(&out, "scene_toml").unwrap().as_deref(),
            Some(text.as_str())
        );
        let params = h5::read_text(&out, "parameters_json").unwrap().unwrap();
        assert!(params.contains("youngs_modulus"), "{params}");
    }
}

#[test]
fn drape_over_a_sphere_keeps_the_contact_bound() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "{}\n[[colliders]]\ntype = \"sphere\"\nradius = 0.01\n",
        scene("stockinette", "free", 0.0, 0.05, "")
    )
    .replace("gravity = [0.0, 0.0, 0.0]", "gravity = [0.0, -9.81, 0.0]");
    let (r, out) = run_scene(dir.path(), "drape", &text);
    let ratio = r["min_distance_ratio"].as_f64().unwrap();
    eprintln!("drape: min distance / 2r {ratio:.3}");
    assert!(ratio >= 0.75, "{ratio}");
    // It fell, and nothing went through the sphere (centre under the
    // swatch, top one yarn diameter below its lowest point).
    let (first, last) = first_and_last_frames(&out);
    let drop = largest_drop(&first, &last);
    assert!(drop > 1e-3, "the swatch did not fall ({drop} m)");
    let (lo, hi) = first
        .iter()
        .fold(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]), |(l, h), p| {
            (
                std::array::from_fn(|k| l[k].min(p[k])),
                std::array::from_fn(|k| h[k].max(p[k])),
            )
        });
    let r_yarn = 0.001; // the generator's default radius
    let c = [
        0.5 * (lo[0] + hi[0]),
        lo[1] - 2.0 * r_yarn - 0.01,
        0.5 * (lo[2] + hi[2]),
    ];
    for p in &last {
        let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
        assert!(
            d >= 0.01 + 0.5 * r_yarn,
            "a vertex is {d} m from the centre"
        );
    }
}

#[test]
fn the_rods_model_follows_the_handles_and_drapes_without_passing_through() {
    let dir = tempfile::tempdir().unwrap();
    let text = scene("rib1x1", "stretch_courses", 0.3, 0.03, "model = \"rods\"");
    let (r, out) = run_scene(dir.path(), "rods_stretch", &text);
    assert_eq!(r["model"], "rods", "{r}");
    assert!(r["newton_iterations"].as_u64().unwrap() >= r["steps"].as_u64().unwrap());
    let ratio = r["min_distance_ratio"].as_f64().unwrap();
    assert!(ratio >= 0.75, "{ratio}");
    let first = h5::read_frame(&out, 0).unwrap();
    let last = h5::read_frame(&out, 3).unwrap();
    let strain = x_extent(&last) / x_extent(&first) - 1.0;
    assert!((strain - 0.3).abs() < 0.02, "strain {strain}");
    let params = h5::read_text(&out, "parameters_json").unwrap().unwrap();
    assert!(params.contains("\"model\":\"rods\""), "{params}");
    assert!(params.contains("collider_stiffness"), "{params}");
    // Dropped on a frictional sphere under gravity: it falls, stays out of
    // the sphere by its radius (less the penalty's give) and keeps the
    // contact bound.
    let text = format!(
        "{}\n[[colliders]]\ntype = \"sphere\"\nradius = 0.01\nfriction = 0.5\n",
        scene("stockinette", "free", 0.0, 0.05, "model = \"rods\"")
    )
    .replace("gravity = [0.0, 0.0, 0.0]", "gravity = [0.0, -9.81, 0.0]");
    let (r, out) = run_scene(dir.path(), "rods_drape", &text);
    assert!(r["min_distance_ratio"].as_f64().unwrap() >= 0.75, "{r}");
    let pen = r["max_penetration_m"].as_f64().unwrap();
    assert!(pen < 1e-4, "penetration {pen} m");
    let (first, last) = first_and_last_frames(&out);
    let drop = largest_drop(&first, &last);
    assert!(drop > 1e-3, "the swatch did not fall ({drop} m)");
    // `[rods]` settings are checked and need the rods model.
    for (text, key) in [
        (
            format!(
                "{}\n[rods]\nmax_dt = 0.001\n",
                scene("rib1x1", "shear", 0.1, 0.01, "")
            ),
            "model = \"rods\"",
        ),
        (
            format!(
                "{}\n[rods]\nmax_dt = -1.0\n",
                scene("rib1x1", "shear", 0.1, 0.01, "model = \"rods\"")
            ),
            "rods.max_dt",
        ),
        (
            format!(
                "{}\n[rods]\nfriction = 0.2\nstiffnes = 3.0\n",
                scene("rib1x1", "shear", 0.1, 0.01, "model = \"rods\"")
            ),
            "stiffnes",
        ),
    ] {
        let s = dir.path().join("bad_rods.toml");
        std::fs::write(&s, &text).unwrap();
        let o = dir.path().join("bad_rods.h5");
        let (code, _, err) = run(&["yls", s.to_str().unwrap(), "-o", o.to_str().unwrap()]);
        assert_eq!(code, 65, "{key}: {err}");
        assert!(err.contains(key), "{key} not in {err}");
    }
}

#[test]
fn every_pose_kind_runs() {
    let dir = tempfile::tempdir().unwrap();
    for (kind, amount) in [
        ("stretch_wales", 0.1),
        ("biaxial", 0.1),
        ("shear", 0.1),
        ("bend_central", 0.5),
        ("bend_diagonal", 0.5),
        ("fan", 0.1),
        ("twist", 0.5),
        ("multi_fold", 0.1),
        ("hang", 0.0),
    ] {
        let text = scene("plain", kind, amount, 0.01, "");
        let (r, _) = run_scene(dir.path(), kind, &text);
        assert!(r["handled_vertices"].as_u64().unwrap() > 0, "{kind}");
        assert!(r["min_distance_ratio"].as_f64().unwrap() >= 0.75, "{kind}");
    }
}

#[test]
fn scene_errors_name_the_key_and_exit_codes_are_distinct() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.h5");
    let o = out.to_str().unwrap();
    let cases = [
        (
            scene("rib1x1", "stretch_courses", 0.3, 0.01, "").replace("amount", "amout"),
            "amout",
        ),
        (
            format!(
                "{}\n[sim]\nyoungs_modulu = 1.0\n",
                scene("rib1x1", "shear", 0.1, 0.01, "")
            ),
            "youngs_modulu",
        ),
        (scene("rib1x1", "stretchy", 0.3, 0.01, ""), "stretchy"),
        (scene("nosuch", "shear", 0.1, 0.01, ""), "nosuch"),
        // A pose the swatch cannot take (fold height / length >= 0.5).
        (scene("plain", "multi_fold", 0.5, 0.01, ""), "multi_fold"),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let s = dir.path().join(format!("bad{i}.toml"));
        std::fs::write(&s, text).unwrap();
        let (code, stdout, err) = run(&["yls", s.to_str().unwrap(), "-o", o, "--json"]);
        assert_eq!(code, 65, "{key}: {err}");
        assert!(err.contains(key), "{key} not in {err}");
        assert!(err.contains(&format!("bad{i}.toml")), "{err}");
        // The JSON error names the scene as its file, for farm scripts.
        let v: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
        assert_eq!(v["file"], s.to_str().unwrap(), "{key}: {v}");
    }
    assert!(!out.exists(), "no output after a failed run");
    let (code, _, err) = run(&["yls", "/nonexistent/scene.toml", "-o", o]);
    assert_eq!(code, 66, "{err}");
    let s = dir.path().join("good.toml");
    std::fs::write(&s, scene("plain", "shear", 0.1, 0.01, "")).unwrap();
    let (code, _, err) = run(&["yls", s.to_str().unwrap(), "-o", "x.ply"]);
    assert_eq!(code, 65, "{err}");
}

#[test]
fn a_diverging_run_names_the_step_and_the_vertex() {
    let dir = tempfile::tempdir().unwrap();
    // A speed guard far below the handle speed trips on the first steps.
    let text = format!(
        "{}\n[sim]\nmax_speed = 1e-9\n",
        scene("plain", "stretch_courses", 0.3, 0.01, "")
    );
    let s = dir.path().join("div.toml");
    std::fs::write(&s, text).unwrap();
    let out = dir.path().join("div.h5");
    let (code, _, err) = run(&["yls", s.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_ne!(code, 0);
    assert!(err.contains("diverged at step"), "{err}");
    assert!(err.contains("vertex"), "{err}");
    assert!(!out.exists(), "a diverged run leaves no frame file");
}

#[test]
fn bench_yls_prints_its_figures_and_refuses_unknown_patterns() {
    let (code, stdout, err) = run(&[
        "bench",
        "yls",
        "--vertices",
        "600",
        "--steps",
        "5",
        "--warmup",
        "0",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    for key in [
        "vertices",
        "us_per_vertex_step",
        "ms_per_frame",
        "steps_per_frame",
        "contact_pairs",
        "contacts_per_vertex",
        "min_distance_ratio",
    ] {
        assert!(v.get(key).is_some(), "{key} missing in {stdout}");
    }
    // Relaxed into contact first, the timed steps run with the yarns
    // touching (the loose generated swatch has almost no contacts).
    let loose_cpv = v["contacts_per_vertex"].as_f64().unwrap();
    let (code, stdout, err) = run(&[
        "bench",
        "yls",
        "--vertices",
        "600",
        "--steps",
        "5",
        "--warmup",
        "0",
        "--relax",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let cpv = r["contacts_per_vertex"].as_f64().unwrap();
    assert!(
        cpv > 0.3 && cpv > 3.0 * loose_cpv,
        "relaxed {cpv}, loose {loose_cpv}"
    );
    assert!(r["min_distance_ratio"].as_f64().unwrap() >= 0.75);
    let n = v["vertices"].as_f64().unwrap();
    assert!(
        (300.0..1200.0).contains(&n),
        "{n} vertices for a target of 600"
    );
    assert!(v["us_per_vertex_step"].as_f64().unwrap() > 0.0);
    assert!(v["min_distance_ratio"].as_f64().unwrap() >= 0.75);
    let (code, _, err) = run(&["bench", "yls", "--pattern", "nosuch", "--json"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("rib1x1"), "lists the known patterns: {err}");
}

#[test]
fn bench_yls_times_a_relaxed_file_stretched_into_contact() {
    let dir = tempfile::tempdir().unwrap();
    let swatch = dir.path().join("rib.h5");
    let swatch = swatch.to_str().unwrap();
    let (code, _, err) = run(&[
        "pattern",
        "rib1x1",
        "--courses",
        "4",
        "--wales",
        "4",
        "-o",
        swatch,
    ]);
    assert_eq!(code, 0, "{err}");
    let bench = |extra: &[&str]| {
        let mut args = vec![
            "bench", "yls", "--input", swatch, "--steps", "3", "--warmup", "0", "--json",
        ];
        args.extend_from_slice(extra);
        let (code, stdout, err) = run(&args);
        assert_eq!(code, 0, "{err}");
        serde_json::from_str::<serde_json::Value>(&stdout).unwrap()
    };
    let rest = bench(&[]);
    assert_eq!(rest["relaxed"], true, "{rest}");
    assert!(rest["prestretch"].is_null(), "{rest}");
    let pulled = bench(&["--prestretch", "0.3", "--prestretch-steps", "3"]);
    let pre = &pulled["prestretch"];
    assert_eq!(pre["stretch"].as_f64(), Some(0.3), "{pulled}");
    assert!(pre["force_n"].as_f64().unwrap() > 0.0, "{pulled}");
    assert!(pre["newton_iterations"].as_u64().unwrap() > 0, "{pulled}");
    // The stretch presses the yarns together: more contacts per vertex in
    // the timed steps than at rest, and no pull-through.
    let (c0, c1) = (
        rest["contacts_per_vertex"].as_f64().unwrap(),
        pulled["contacts_per_vertex"].as_f64().unwrap(),
    );
    assert!(c1 > c0, "stretched {c1} vs rest {c0} contacts per vertex");
    assert!(pulled["min_distance_ratio"].as_f64().unwrap() >= 0.75);
    assert_eq!(pulled["vertices"], rest["vertices"]);
    // A loose swatch has no rest shape to stretch from.
    let (code, _, err) = run(&[
        "bench",
        "yls",
        "--vertices",
        "600",
        "--prestretch",
        "0.3",
        "--json",
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("rest shape"), "{err}");
}
