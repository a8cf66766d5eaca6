//! The files in `examples/`, used the way a user would: every grid, scene,
//! manifest and swatch there is read (and, where it is cheap, run) through
//! the CLI, and `examples/README.md` lists every file.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use knitvox::io::{self, ReadOptions};
use knitvox::pipeline::yls_scene::YlsScene;
use knitvox::yarn::pattern::{builtin, parse_grid, Pattern, Stitch};
use knitvox::yarn::poses::PoseKind;

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples")
}

fn knitvox(args: &[&str]) -> Output {
    knitvox_in(&std::env::temp_dir(), args)
}

fn knitvox_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("run knitvox")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The last line of stdout as JSON (the report of a JSON-lines command, or
/// a whole compact document).
fn last_json(o: &Output) -> serde_json::Value {
    let out = String::from_utf8_lossy(&o.stdout);
    let last = out.lines().last().unwrap_or("");
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {out}"))
}

/// Every file under `dir`, relative to it, sorted.
fn files_below(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// The clearance every generated swatch meets before relaxation: two
/// non-adjacent yarn segments at least 0.95 yarn diameters apart.
const BOUND: f64 = 0.95;

/// `examples/README.md` names every file of the folder (by its path
/// relative to it), and its relative links resolve.
#[test]
fn the_examples_readme_lists_every_example_file() {
    let dir = examples();
    let readme = std::fs::read_to_string(dir.join("README.md")).unwrap();
    let files = files_below(&dir);
    assert!(files.len() >= 30, "{files:?}");
    // `knitvox run examples/job.toml` writes its outputs under job.out/
    // (git-ignored).
    let missing: Vec<_> = files
        .iter()
        .filter(|f| f.as_path() != Path::new("README.md") && !f.starts_with("job.out"))
        .filter(|f| !readme.contains(&format!("`{}`", f.display())))
        .collect();
    assert!(
        missing.is_empty(),
        "examples/README.md does not list {missing:?}"
    );
    for link in readme.split("](").skip(1) {
        let target = &link[..link.find(')').unwrap()];
        if target.starts_with("http") {
            continue;
        }
        assert!(dir.join(target).is_file(), "dead link {target}");
    }
}

/// The one third-party file is the one `CREDITS.md` credits: its SHA-256 is
/// the one recorded there.
#[test]
fn credits_name_the_fox_by_its_sha256() {
    use sha2::{Digest, Sha256};
    let credits = std::fs::read_to_string(examples().join("CREDITS.md")).unwrap();
    let fox = std::fs::read(examples().join("Fox.glb")).unwrap();
    let hex: String = Sha256::digest(&fox)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert!(credits.contains("## Fox.glb"), "{credits}");
    assert!(
        credits.contains(&hex),
        "Fox.glb is {hex}; CREDITS.md: {credits}"
    );
}

/// `example_swatch.bcc` is the swatch `knitvox demo` writes (the analytic
/// knit swatch of the default parameters): 8 open courses and one closed
/// ring, metres, +Y up, the same points to float32 precision.
#[test]
fn example_swatch_is_the_demos_analytic_swatch() {
    let path = examples().join("example_swatch.bcc");
    let o = knitvox(&["inspect", "--json", s(&path)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let r = &v[0];
    assert_eq!(r["format"], "bcc", "{r}");
    assert_eq!(r["curves"], 9, "{r}");
    assert_eq!(r["open_curves"], 8, "{r}");
    assert_eq!(r["closed_curves"], 1, "{r}");
    assert_eq!(r["up_axis"], "y", "{r}");
    assert_eq!(r["up_axis_source"], "file", "{r}");
    let want = knitvox::yarn::analytic::knit_swatch(&Default::default());
    let got = io::read_path(&path, &ReadOptions::default()).unwrap().yarns;
    assert_eq!(got.offsets, want.offsets);
    assert_eq!(got.closed, want.closed);
    let worst = got
        .points
        .iter()
        .zip(&want.points)
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    assert!(worst < 1e-8, "points differ by up to {worst} m");
}

/// `twill.grid` is the built-in 2/2 twill, and `knitvox pattern --grid` weaves
/// it into a swatch clear of itself: the wefts one yarn turning at each
/// edge (as a loom's shuttle lays it) and one yarn per warp, or one yarn per
/// weft with `--separate-courses`.
#[test]
fn twill_grid_is_the_builtin_twill_and_weaves_wefts_and_warps() {
    let grid = examples().join("twill.grid");
    let text = std::fs::read_to_string(&grid).unwrap();
    let pattern = parse_grid(&text).unwrap();
    assert_eq!(pattern, builtin("twill").unwrap());
    assert_eq!(pattern.repeat(), [4, 4]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("twill.ply");
    // The grid knitted 6 courses x 8 wales, unrelaxed, with `extra` flags.
    let knit = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "pattern",
            "--grid",
            s(&grid),
            "--courses",
            "6",
            "--wales",
            "8",
        ];
        args.extend(["--no-relax", "--json", "-o", s(&out)]);
        args.extend(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let v = knit(&[]);
    assert_eq!(v["kind"], "woven", "{v}");
    assert_eq!(v["repeat"], serde_json::json!([4, 4]), "{v}");
    assert_eq!(v["courses"], 6, "{v}");
    assert_eq!(v["wales"], 8, "{v}");
    assert_eq!(v["curves"], 1 + 8, "one weft yarn and 8 warps: {v}");
    assert!(v["min_distance_ratio"].as_f64().unwrap() >= BOUND, "{v}");
    let yarns = io::read_path(&out, &ReadOptions::default()).unwrap().yarns;
    assert_eq!(yarns.num_curves(), 9);
    assert_eq!(yarns.num_points() as u64, v["vertices"].as_u64().unwrap());
    let v = knit(&["--separate-courses"]);
    assert_eq!(v["curves"], 6 + 8, "one yarn per weft and per warp: {v}");
    assert!(v["min_distance_ratio"].as_f64().unwrap() >= BOUND, "{v}");
}

/// `rib-band.grid`: the first five courses (the bottom lines) are a 1x1 rib,
/// the last five stockinette, and `knitvox pattern --grid` knits the 10 x 10
/// swatch of its comment as one yarn worked back and forth, clear of
/// itself, with the rib drawing in where it is relaxed.
#[test]
fn rib_band_grid_knits_a_rib_cuff_under_stockinette() {
    let grid = examples().join("rib-band.grid");
    let text = std::fs::read_to_string(&grid).unwrap();
    let Pattern::Knit(g) = parse_grid(&text).unwrap() else {
        panic!("rib-band.grid is not a knit grid")
    };
    assert_eq!(g.rows.len(), 10);
    for (j, row) in g.rows.iter().enumerate() {
        assert_eq!(row.len(), 10, "course {j}");
        for (i, st) in row.iter().enumerate() {
            let want = if j < 5 && i % 2 == 1 {
                Stitch::Purl
            } else {
                Stitch::Knit
            };
            assert_eq!(*st, want, "course {j}, wale {i}");
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mix.h5");
    let o = knitvox(&[
        "pattern",
        "--grid",
        s(&grid),
        "--courses",
        "10",
        "--wales",
        "10",
        "--json",
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["kind"], "knit", "{v}");
    assert_eq!(v["repeat"], serde_json::json!([10, 10]), "{v}");
    assert_eq!(v["curves"], 1, "{v}");
    assert!(v["min_distance_ratio"].as_f64().unwrap() >= BOUND, "{v}");
    assert_eq!(v["relaxed"], true, "{v}");
    let x = &v["relaxation"];
    assert!(
        x["min_distance_ratio_seen"].as_f64().unwrap() >= 0.75,
        "{x}"
    );
    let d = io::read_path(&out, &ReadOptions::default()).unwrap();
    assert_eq!(d.yarns.num_points() as u64, v["vertices"].as_u64().unwrap());
    assert!(d.yarns.rest.is_some(), "the h5 keeps the rest shape");
}

/// What each yarn-level example scene is: its pose family and amount, the
/// yarn model, the swatch and the colliders.
struct SceneFacts {
    file: &'static str,
    kind: PoseKind,
    amount: f64,
    rods: bool,
    pattern: &'static str,
    colliders: usize,
}

const SCENES: [SceneFacts; 15] = [
    SceneFacts {
        file: "yls-bend-central.toml",
        kind: PoseKind::BendCentral,
        amount: 2.094,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-bend-diagonal.toml",
        kind: PoseKind::BendDiagonal,
        amount: 1.571,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-biaxial.toml",
        kind: PoseKind::Biaxial,
        amount: 0.2,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-cantilever.toml",
        kind: PoseKind::Cantilever,
        amount: 0.0,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-character.toml",
        kind: PoseKind::Free,
        amount: 0.0,
        rods: false,
        pattern: "stockinette",
        colliders: 1,
    },
    SceneFacts {
        file: "yls-demo-rib-stretch.toml",
        kind: PoseKind::StretchCourses,
        amount: 0.3,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-drape.toml",
        kind: PoseKind::Free,
        amount: 0.0,
        rods: false,
        pattern: "stockinette",
        colliders: 1,
    },
    SceneFacts {
        file: "yls-drape-rods.toml",
        kind: PoseKind::Free,
        amount: 0.0,
        rods: true,
        pattern: "stockinette",
        colliders: 1,
    },
    SceneFacts {
        file: "yls-fan.toml",
        kind: PoseKind::Fan,
        amount: 0.4,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-hang.toml",
        kind: PoseKind::Hang,
        amount: 0.0,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-multi-fold.toml",
        kind: PoseKind::MultiFold,
        amount: 0.3,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-shear.toml",
        kind: PoseKind::Shear,
        amount: 0.3,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-stretch-courses.toml",
        kind: PoseKind::StretchCourses,
        amount: 0.3,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-stretch-wales.toml",
        kind: PoseKind::StretchWales,
        amount: 0.3,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
    SceneFacts {
        file: "yls-twist.toml",
        kind: PoseKind::Twist,
        amount: 3.1416,
        rods: false,
        pattern: "rib1x1",
        colliders: 0,
    },
];

/// Every scene in `examples/scenes/` reads as a yls scene (unknown keys are
/// errors) and is what its name and comment say; none is left out of
/// [`SCENES`].
#[test]
fn every_yarn_level_example_scene_reads_as_its_pose() {
    let dir = examples().join("scenes");
    let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    let mut listed: Vec<&str> = SCENES.iter().map(|f| f.file).collect();
    listed.sort();
    assert_eq!(on_disk, listed);
    for f in &SCENES {
        let scene = YlsScene::read(&dir.join(f.file)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.pose.kind, f.kind, "{}", f.file);
        assert_eq!(scene.pose.amount, f.amount, "{}", f.file);
        assert_eq!(
            scene.model == knitvox::pipeline::yls_scene::YarnModel::Rods,
            f.rods,
            "{}",
            f.file
        );
        assert_eq!(
            scene.swatch.pattern.as_deref(),
            Some(f.pattern),
            "{}",
            f.file
        );
        assert_eq!(scene.colliders.len(), f.colliders, "{}", f.file);
        assert!(
            scene.num_frames() >= 6,
            "{}: {} frames",
            f.file,
            scene.num_frames()
        );
    }
    // The character scene's glTF is the committed fox, found from the scene.
    let scene = YlsScene::read(&dir.join("yls-character.toml")).unwrap();
    match &scene.colliders[0] {
        knitvox::pipeline::yls_scene::ColliderSpec::Character { file, .. } => {
            let p = if file.is_absolute() {
                file.clone()
            } else {
                dir.join(file)
            };
            assert!(p.is_file(), "{}", p.display());
        }
        other => panic!("{other:?}"),
    }
}

/// `text` with the swatch cut to 3 x 3 stitches and the duration to `frames`
/// output frames (a ramp no longer than the run), every other key kept.
fn shrunk(text: &str, frames: f64) -> String {
    let mut t: toml::Table = text.parse().unwrap();
    let rate = t
        .get("frame_rate")
        .and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))
        .unwrap_or(60.0);
    let duration = frames / rate;
    t.insert("duration".into(), toml::Value::Float(duration));
    if let Some(sw) = t.get_mut("swatch").and_then(|v| v.as_table_mut()) {
        if sw.contains_key("pattern") {
            sw.insert("courses".into(), toml::Value::Integer(3));
            sw.insert("wales".into(), toml::Value::Integer(3));
        }
    }
    if let Some(p) = t.get_mut("pose").and_then(|v| v.as_table_mut()) {
        if p.contains_key("ramp") {
            p.insert("ramp".into(), toml::Value::Float(duration));
        }
    }
    toml::to_string(&t).unwrap()
}

/// Every yarn-level example scene runs through `knitvox yls` with its pose,
/// colliders (the fox included) and model, on a 3 x 3 swatch for one
/// frame: the report names the model and the frame, and the contact bound
/// (0.75 yarn diameters) held at every step.
#[test]
fn every_yarn_level_example_scene_runs_through_knitvox_yls() {
    let tmp = tempfile::tempdir().unwrap();
    let scenes = tmp.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    // `yls-character.toml` names `../Fox.glb`.
    std::fs::copy(examples().join("Fox.glb"), tmp.path().join("Fox.glb")).unwrap();
    for f in &SCENES {
        let text = std::fs::read_to_string(examples().join("scenes").join(f.file)).unwrap();
        let scene = scenes.join(f.file);
        std::fs::write(&scene, shrunk(&text, 1.0)).unwrap();
        let out = tmp.path().join(f.file.replace(".toml", ".h5"));
        let o = knitvox(&["yls", s(&scene), "-o", s(&out), "--json"]);
        assert!(o.status.success(), "{}: {}", f.file, stderr(&o));
        let r = last_json(&o);
        assert_eq!(r["event"], "report", "{}: {r}", f.file);
        assert_eq!(r["frames"], 1, "{}: {r}", f.file);
        assert_eq!(
            r["model"],
            if f.rods { "rods" } else { "explicit" },
            "{}",
            f.file
        );
        let ratio = r["min_distance_ratio"].as_f64().unwrap();
        assert!(ratio >= 0.75, "{}: min distance / 2r {ratio}", f.file);
        assert_eq!(io::h5::frame_count(&out).unwrap(), 2, "{}", f.file);
    }
}

/// The damping scene of `fit-damping` runs on the asset's rest yarns (no
/// `[swatch]`): a cantilever released under gravity, the rods model at 30
/// frames/s over 0.4 s, no collider.
#[test]
fn the_damping_scene_is_a_cantilever_release_on_the_assets_yarns() {
    let path = examples().join("damping/swing.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let table: toml::Table = text.parse().unwrap();
    assert!(!table.contains_key("swatch"));
    let with = format!("{text}\n[swatch]\nfile = 'rest.h5'\n");
    let scene = YlsScene::parse(&with, &path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.pose.kind, PoseKind::Cantilever);
    assert!(scene.colliders.is_empty());
    assert_eq!(scene.model, knitvox::pipeline::yls_scene::YarnModel::Rods);
    assert_eq!(scene.duration, 0.4);
    assert_eq!(scene.frame_rate, 30.0);
    assert!(scene.gravity[1] < -9.0, "{:?}", scene.gravity);
}

/// The held-out scenes of `examples/validate/`: each has no `[swatch]` (it
/// runs on the asset's rest yarns), reads as a yls scene once a swatch file
/// is named, as `validate` names it, and is the pose its name says, with
/// the rods model at 30 frames/s over 0.4 s (the posed scenes and the drape)
/// or 0.5 s (the free drops, the slide and the shoulder).
#[test]
fn every_held_out_example_scene_reads_with_the_assets_yarns() {
    let dir = examples().join("validate");
    let want = [
        ("biaxial.toml", PoseKind::Biaxial, 0.15, 0, 0.4),
        ("drape.toml", PoseKind::Free, 0.0, 1, 0.4),
        ("drop.toml", PoseKind::Free, 0.0, 1, 0.5),
        ("drop_off_centre.toml", PoseKind::Free, 0.0, 1, 0.5),
        ("fan.toml", PoseKind::Fan, 0.25, 0, 0.4),
        ("hang.toml", PoseKind::Hang, 0.0, 0, 0.4),
        ("multi_fold.toml", PoseKind::MultiFold, 0.3, 0, 0.4),
        ("shear.toml", PoseKind::Shear, 0.1, 0, 0.4),
        ("shoulder.toml", PoseKind::Free, 0.0, 1, 0.5),
        ("slide.toml", PoseKind::Free, 0.0, 1, 0.5),
        ("stretch_wales.toml", PoseKind::StretchWales, 0.3, 0, 0.4),
    ];
    let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    assert_eq!(on_disk, want.map(|w| w.0));
    for (file, kind, amount, colliders, duration) in want {
        let path = dir.join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let table: toml::Table = text.parse().unwrap();
        assert!(!table.contains_key("swatch"), "{file} names its own swatch");
        let with = format!("{text}\n[swatch]\nfile = 'rest.h5'\n");
        let scene = YlsScene::parse(&with, &path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.pose.kind, kind, "{file}");
        assert_eq!(scene.pose.amount, amount, "{file}");
        assert_eq!(scene.colliders.len(), colliders, "{file}");
        assert_eq!(
            scene.model,
            knitvox::pipeline::yls_scene::YarnModel::Rods,
            "{file}"
        );
        assert_eq!(scene.duration, duration, "{file}");
        assert_eq!(
            scene.num_frames(),
            (duration * 30.0).round() as usize,
            "{file}"
        );
    }
}

/// Each held-out scene runs through `knitvox validate` as its comment says
/// (a `knitvox pattern` swatch embedded with the defaults lies in the XZ
/// plane), cut to one frame: both levels run and the report compares that
/// frame with finite errors. The same swatch stood up (`--up-axis z`) is
/// refused before either run, naming the plane and the fix.
#[test]
fn every_held_out_example_scene_validates_an_embedded_pattern_swatch() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let yarns = d.join("swatch.ply");
    let o = knitvox(&[
        "pattern",
        "stockinette",
        "--courses",
        "4",
        "--wales",
        "4",
        "--no-relax",
        "-o",
        s(&yarns),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let asset = d.join("swatch.vtkhdf");
    let o = knitvox(&["embed", s(&yarns), "-o", s(&asset)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let standing = d.join("standing.vtkhdf");
    let o = knitvox(&["embed", s(&yarns), "--up-axis", "z", "-o", s(&standing)]);
    assert!(o.status.success(), "{}", stderr(&o));
    for file in [
        "biaxial.toml",
        "drape.toml",
        "drop.toml",
        "drop_off_centre.toml",
        "fan.toml",
        "hang.toml",
        "multi_fold.toml",
        "shear.toml",
        "slide.toml",
        "stretch_wales.toml",
    ] {
        let text = std::fs::read_to_string(examples().join("validate").join(file)).unwrap();
        let scene = d.join(file);
        std::fs::write(&scene, shrunk(&text, 1.0)).unwrap();
        let o = knitvox(&[
            "validate",
            s(&asset),
            "--scene",
            s(&scene),
            "--json",
            "--no-progress",
        ]);
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(r["frames"], 1, "{file}: {r}");
        for k in ["rms_yarn_diameters", "y2v_floor_rms_yarn_diameters"] {
            let x = r[k].as_f64().unwrap();
            assert!(x.is_finite() && x >= 0.0, "{file}: {k} {x}");
        }
        let free = [
            "drape.toml",
            "drop.toml",
            "drop_off_centre.toml",
            "slide.toml",
        ];
        assert_eq!(
            r["colliders"],
            if free.contains(&file) { 1 } else { 0 },
            "{file}"
        );
        // The motion of both levels over the frame: the yarns fall or are
        // pulled, so the centre of mass moves on both.
        for run in ["yarn_level", "homogenized"] {
            let m = &r["motion"][run];
            let travel = m["com_travel_m"].as_f64().unwrap();
            assert!(travel.is_finite() && travel > 0.0, "{file}: {run} {m}");
            assert_eq!(m["frames"].as_array().unwrap().len(), 2, "{file}: {run}");
        }
        let o = knitvox(&[
            "validate",
            s(&standing),
            "--scene",
            s(&scene),
            "--no-progress",
        ]);
        assert_eq!(o.status.code(), Some(65), "{file}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(
            e.contains("XY plane") && e.contains("--up-axis z") && !e.contains("yarn diameters"),
            "{file}: {e}"
        );
    }
}

/// `job.toml` loads as a manifest (its swatch, scene and character found
/// beside it) and plans the stages its comment names: embed, then the shot
/// on the walking fox, then the PLY export, into `examples/job.out/`,
/// without running or writing anything.
#[test]
fn job_manifest_plans_embed_shot_and_export() {
    let job = examples().join("job.toml");
    let before = files_below(&examples());
    let o = knitvox(&["run", s(&job), "--plan", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let plan = last_json(&o);
    let names: Vec<&str> = plan["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|st| st["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["embed", "shot", "export"], "{plan}");
    assert_eq!(
        plan["stages"][1]["after"],
        serde_json::json!(["embed"]),
        "{plan}"
    );
    assert_eq!(
        plan["stages"][2]["after"],
        serde_json::json!(["shot"]),
        "{plan}"
    );
    assert!(
        plan["output"].as_str().unwrap().ends_with("job.out"),
        "{plan}"
    );
    assert_eq!(
        files_below(&examples()),
        before,
        "--plan wrote into examples/"
    );
}

/// `job.toml` runs as its comment says, in a copy of the folder: the stages
/// run once, and a second run finds every stage cached.
#[test]
fn job_manifest_runs_then_every_stage_is_cached() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for f in ["job.toml", "example_swatch.bcc", "fox-walk.toml", "Fox.glb"] {
        std::fs::copy(examples().join(f), d.join(f)).unwrap();
    }
    let o = knitvox_in(d, &["run", "job.toml", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = last_json(&o);
    assert_eq!(r["event"], "report", "{r}");
    assert_eq!(r["ran"], 3, "{r}");
    let frames: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["event"] == "frame")
        .collect();
    assert_eq!(frames.len(), 2, "frames = \"1-2\"");
    let export = &r["stages"][2];
    assert_eq!(export["name"], "export", "{r}");
    let outputs = export["outputs"].as_array().unwrap();
    assert_eq!(outputs.len(), 2, "two PLY frames: {r}");
    for p in outputs {
        let p = d.join("job.out").join(p.as_str().unwrap());
        let y = io::read_path(&p, &ReadOptions::default()).unwrap().yarns;
        assert_eq!(y.num_curves(), 9, "{}", p.display());
    }
    let o = knitvox_in(d, &["run", "job.toml", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = last_json(&o);
    assert_eq!(r["ran"], 0, "{r}");
    assert!(r["stages"]
        .as_array()
        .unwrap()
        .iter()
        .all(|st| st["status"] == "cached"));
}
