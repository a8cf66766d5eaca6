//! The real binary on temporary folders: commands, outputs, exit codes.
mod common;

use std::path::Path;
use std::process::{Command, Output};

fn knitvox(args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .expect("run knitvox")
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn help_on_every_subcommand() {
    for args in [
        &["--help"][..],
        &["inspect", "--help"],
        &["convert", "--help"],
        &["bench", "--help"],
        &["bench", "io", "--help"],
        &["demo", "--help"],
        &["completions", "--help"],
        &["run", "--help"],
        &["watch", "--help"],
        &["train", "--help"],
        &["fit", "--help"],
        &["validate", "--help"],
    ] {
        let o = knitvox(args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(
            String::from_utf8_lossy(&o.stdout).contains("Usage"),
            "{args:?}"
        );
    }
}

#[test]
fn completions_for_bash() {
    let o = knitvox(&["completions", "bash"]);
    assert!(o.status.success());
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("knitvox") && s.contains("convert"));
}

#[test]
fn usage_errors_exit_2() {
    assert_eq!(knitvox(&["convert"]).status.code(), Some(2));
    assert_eq!(
        knitvox(&["inspect", "x.bcc", "--tile", "0x0"])
            .status
            .code(),
        Some(2)
    );
    assert_eq!(
        knitvox(&["inspect", "x.bcc", "--units", "parsec"])
            .status
            .code(),
        Some(2)
    );
}

#[test]
fn demo_then_inspect_and_convert_everything() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = knitvox(&["demo", "--out", p(&out), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let outputs = report["outputs"].as_array().unwrap();
    // Every writable format, once as a single file and once as frames.
    for ext in ["bcc", "obj", "ply", "gltf", "glb", "h5"] {
        assert!(
            outputs
                .iter()
                .any(|v| v.as_str().unwrap().ends_with(&format!("swatch.{ext}"))),
            "{ext}"
        );
    }
    for f in outputs {
        let f = f.as_str().unwrap();
        assert!(Path::new(f).is_file(), "{f}");
    }
    // Homogenization: the fit lowers the loss below the uniform material's
    // on its two poses and the held-out line is measured.
    let fit = &report["fit"];
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    assert!(
        num(&fit["fit"]["loss_fitted"]) < num(&fit["fit"]["loss_before"]),
        "{fit}"
    );
    assert_eq!(fit["fit"]["poses"].as_array().unwrap().len(), 2);
    let v = &fit["validate"];
    for k in [
        "rms_yarn_diameters",
        "uniform_rms_yarn_diameters",
        "speedup",
    ] {
        assert!(num(&v[k]).is_finite() && num(&v[k]) > 0.0, "{k}: {v}");
    }
    assert!(Path::new(fit["fitted"].as_str().unwrap()).is_file());
    let input = out.join("example_swatch.bcc");
    let o = knitvox(&[
        "inspect",
        "--json",
        p(&input),
        p(&out.join("swatch.glb")),
        p(&out.join("swatch_frames.####.ply")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let reports = v.as_array().unwrap();
    assert_eq!(reports.len(), 3);
    assert_eq!(reports[0]["curves"], 9);
    assert_eq!(reports[0]["closed_curves"], 1);
    assert_eq!(reports[0]["units_source"], "assumed");
    assert_eq!(reports[1]["units_source"], "file");
    assert_eq!(reports[2]["frames"], 5);
    assert_eq!(reports[0]["points"], reports[1]["points"]);

    // Convert BCC (say it is in cm, Z up) to OBJ in mm: coordinates scale by 10.
    let obj = dir.path().join("x.obj");
    let o = knitvox(&[
        "convert",
        p(&input),
        p(&obj),
        "--units",
        "cm",
        "--up-axis",
        "z",
        "--out-units",
        "mm",
        "--out-up-axis",
        "z",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = knitvox::io::read_path(&input, &Default::default()).unwrap();
    let b = knitvox::io::read_path(&obj, &Default::default()).unwrap();
    let (pa, pb) = (a.yarns.points[5], b.yarns.points[5]);
    // a was read as m +Y up; in the file it is (x, y, z) = cm +Z up -> written as mm +Z up
    // -> read back as m +Y up: x scales by 10, and file (y, z) -> internal (z, -y).
    assert!((pb[0] - 10.0 * pa[0]).abs() < 1e-9 * pa[0].abs().max(1.0));
}

#[test]
fn bad_input_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.bcc");
    std::fs::write(&empty, b"").unwrap();
    let o = knitvox(&["inspect", p(&empty)]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
    assert!(stderr(&o).contains("empty.bcc"), "{}", stderr(&o));

    let unknown = dir.path().join("curves.xyz");
    std::fs::write(&unknown, b"1 2 3").unwrap();
    let o = knitvox(&["inspect", p(&unknown)]);
    assert_eq!(o.status.code(), Some(65));
    assert!(stderr(&o).contains("unknown file type"), "{}", stderr(&o));

    let o = knitvox(&["inspect", p(&dir.path().join("missing.ply"))]);
    assert_eq!(o.status.code(), Some(66), "{}", stderr(&o));

    let garbage = dir.path().join("garbage.glb");
    std::fs::write(&garbage, [0xffu8; 100]).unwrap();
    let o = knitvox(&["convert", p(&garbage), p(&dir.path().join("o.ply"))]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
    assert!(!dir.path().join("o.ply").exists());

    // Output into a folder that does not exist: an output failure.
    knitvox(&["demo", "--out", p(&dir.path().join("d"))]);
    let o = knitvox(&[
        "convert",
        p(&dir.path().join("d/example_swatch.bcc")),
        "/nonexistent-knitvox/out.ply",
    ]);
    assert_eq!(o.status.code(), Some(74), "{}", stderr(&o));
    // Writing a read-only format.
    let o = knitvox(&[
        "convert",
        p(&dir.path().join("d/example_swatch.bcc")),
        p(&dir.path().join("o.pyp")),
    ]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
}

#[test]
fn bench_io_json_shape() {
    let o = knitvox(&["bench", "io", "--points", "2000", "--runs", "3", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["bench"], "io");
    for f in ["bcc", "obj", "ply", "gltf", "glb", "hdf5"] {
        let t = &v["formats"][f];
        assert!(t["write_ms"].as_f64().unwrap() > 0.0, "{f}");
        assert!(t["read_ms"].as_f64().unwrap() > 0.0, "{f}");
        assert!(t["bytes"].as_u64().unwrap() > 0, "{f}");
    }
}

#[test]
fn inspect_foreign_and_busy_hdf5() {
    let Some(dir) = common::external_data("hdf5") else {
        return;
    };
    let o = knitvox(&["inspect", "--json", p(&dir.join("pyfive_chunked.hdf5"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v[0]["knitvox_yarns"], false);
    assert_eq!(v[0]["datasets"][0]["path"], "/dataset1");
    // Its "open for write" flag is set: transient (75) with the h5clear advice, not a crash.
    let o = knitvox(&[
        "inspect",
        p(&dir.join("jhdf_test_byteshuffle_compressed_datasets_latest.hdf5")),
    ]);
    assert_eq!(o.status.code(), Some(75), "{}", stderr(&o));
    assert!(stderr(&o).contains("h5clear"), "{}", stderr(&o));
}

/// A missing input's OS error is printed once (library
/// errors embed their cause and also return it as `source()`), and the code
/// is 66.
#[test]
fn missing_input_prints_its_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.bcc");
    for args in [
        vec!["inspect", p(&missing)],
        vec!["convert", p(&missing), "out.ply"],
        vec!["embed", p(&missing), "-o", "out.vtkhdf"],
    ] {
        let o = knitvox(&args);
        assert_eq!(o.status.code(), Some(66), "{args:?}: {}", stderr(&o));
        let err = stderr(&o);
        let cause = std::io::Error::from_raw_os_error(2).to_string(); // ENOENT
        assert_eq!(err.matches(&cause).count(), 1, "{args:?}: {err}");
        assert!(err.contains("nope.bcc"), "{err}");
    }
}

/// Four parallel polylines 30 units long: a garment of 30 cm read in cm, or
/// of 30 m when the unitless OBJ is read as metres (the assumed unit).
fn wide_obj(dir: &Path) -> std::path::PathBuf {
    let mut text = String::new();
    for c in 0..4 {
        for i in 0..31 {
            text += &format!("v {i} {} 0\n", c as f64 * 0.5);
        }
        let ids: Vec<String> = (1..=31).map(|i| (c * 31 + i).to_string()).collect();
        text += &format!("l {}\n", ids.join(" "));
    }
    let path = dir.join("wide.obj");
    std::fs::write(&path, text).unwrap();
    path
}

fn json_of(o: &Output) -> serde_json::Value {
    // One document, or (simulate, yls, run) JSON lines with the report last.
    let text = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(&text)
        .or_else(|_| serde_json::from_str(text.lines().last().unwrap_or("")))
        .unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// Option values checked after clap (ranges, names inside
/// files, frame numbers) are usage errors (exit 2) that name the option.
#[test]
fn bad_option_values_are_usage_errors_naming_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let obj = wide_obj(dir.path());
    let asset = dir.path().join("a.vtkhdf");
    let o = knitvox(&["embed", p(&obj), "-o", p(&asset), "--units", "cm"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = dir.path().join("f.####.obj");
    let o = knitvox(&["convert", p(&obj), p(&frames), "--units", "cm"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let fox = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/Fox.glb");
    let out = dir.path().join("o.vtkhdf");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["embed", p(&obj), "-o", p(&out), "--voxel-size", "nan"],
            "--voxel-size",
        ),
        (
            vec!["embed", p(&obj), "-o", p(&out), "--max-voxels", "0"],
            "--max-voxels",
        ),
        (
            vec!["embed", p(&obj), "-o", p(&out), "--density", "inf"],
            "--density",
        ),
        (
            vec!["inspect", p(&obj), "--spline-samples", "0"],
            "--spline-samples",
        ),
        (vec!["inspect", p(&obj), "--radius", "nan"], "--radius"),
        (
            vec![
                "shapefit",
                p(&asset),
                p(&frames),
                "-o",
                p(&out),
                "--alpha",
                "0",
            ],
            "--alpha",
        ),
        (
            vec![
                "shapefit",
                p(&asset),
                p(&frames),
                "-o",
                p(&out),
                "--frames",
                "5",
            ],
            "--frames 5",
        ),
        (
            vec![
                "simulate",
                p(&asset),
                "--character",
                fox,
                "--animation",
                "Dance",
                "--frames",
                "1-2",
                "-o",
                p(&out),
            ],
            "--animation 'Dance'",
        ),
        (
            vec![
                "simulate",
                p(&asset),
                "--character",
                fox,
                "--fit-joint",
                "b_Wing",
                "--frames",
                "1-2",
                "-o",
                p(&out),
            ],
            "--fit-joint 'b_Wing'",
        ),
    ];
    for (args, option) in cases {
        let o = knitvox(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(e.contains(option), "{args:?}: {e}");
    }
    // The names are right: the same run gets past the check.
    assert!(!out.exists());
}

/// `--backend gpu` without a GPU adapter is its own class,
/// exit 69 (EX_UNAVAILABLE), not bad input (65). The Vulkan loader is
/// pointed at no driver, so no adapter exists on any machine.
#[test]
fn no_gpu_adapter_exits_69() {
    let dir = tempfile::tempdir().unwrap();
    let obj = wide_obj(dir.path());
    let asset = dir.path().join("a.vtkhdf");
    let o = knitvox(&["embed", p(&obj), "-o", p(&asset), "--units", "cm"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = dir.path().join("s.toml");
    std::fs::write(&scene, "[simulation]\nfps = 24\n").unwrap();
    let out = dir.path().join("o.vtkhdf");
    let o = Command::new(common::knitvox_bin())
        .args([
            "simulate",
            p(&asset),
            "--scene",
            p(&scene),
            "--frames",
            "1-1",
        ])
        .args(["--backend", "gpu", "-o", p(&out)])
        .env("VK_ICD_FILENAMES", "/nonexistent")
        .env("VK_DRIVER_FILES", "/nonexistent")
        .output()
        .unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(69), "{e}");
    assert!(e.contains("--backend gpu") && e.contains("no GPU"), "{e}");
    assert!(!out.exists());
}

/// A garment 30 m across read with an assumed unit warns
/// (stderr, and `warnings` in --json) in convert, embed and simulate, with
/// the unit that would make it clothing; declared units do not warn.
#[test]
fn implausible_size_with_an_assumed_unit_warns() {
    let dir = tempfile::tempdir().unwrap();
    let obj = wide_obj(dir.path());
    let ply = dir.path().join("w.ply");
    let o = knitvox(&["convert", p(&obj), p(&ply), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let w = json_of(&o)["warnings"].as_array().unwrap().clone();
    assert_eq!(w.len(), 1, "{w:?}");
    let w = w[0].as_str().unwrap();
    assert!(
        w.contains("30.0") && w.contains("--units cm") && w.contains("assumed"),
        "{w}"
    );
    assert!(stderr(&o).contains("warning:") && stderr(&o).contains("--units cm"));
    // Given units (and axis): no assumption, no warning, even at 30 m.
    for extra in [&["--units", "cm"][..], &["--units", "m", "--up-axis", "y"]] {
        let mut args = vec!["convert", p(&obj), p(&ply), "--json"];
        args.extend(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(json_of(&o)["warnings"], serde_json::json!([]), "{extra:?}");
        assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    }
    let asset = dir.path().join("a.vtkhdf");
    let o = knitvox(&["embed", p(&obj), "-o", p(&asset), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let w = json_of(&o)["warnings"].clone();
    assert!(w[0].as_str().unwrap().contains("--units cm"), "{w}");
    let scene = dir.path().join("s.toml");
    std::fs::write(&scene, "[simulation]\nfps = 24\n").unwrap();
    let out = dir.path().join("o.vtkhdf");
    let o = knitvox(&[
        "simulate",
        p(&asset),
        "--scene",
        p(&scene),
        "--frames",
        "1-1",
        "--backend",
        "cpu",
        "-o",
        p(&out),
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let w = json_of(&o)["warnings"].clone();
    assert!(
        w[0].as_str().unwrap().contains("implausible for clothing"),
        "{w}"
    );
}

/// `inspect CHAR.glb` reports joints, skins, animations
/// with durations, the bind-pose box and a --character-scale that makes the
/// body 1.7 m tall (Fox.glb: about 79 units high -> 0.022).
#[test]
fn inspect_character_reports_rig_and_scale() {
    let fox = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/Fox.glb");
    let o = knitvox(&["inspect", fox, "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = &json_of(&o)[0];
    assert_eq!(v["format"], "gltf character");
    assert_eq!(v["joints"].as_array().unwrap().len(), 24);
    assert_eq!(v["skins"].as_array().unwrap().len(), 1);
    let names: Vec<&str> = v["animations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["Survey", "Walk", "Run"]);
    for a in v["animations"].as_array().unwrap() {
        assert!(a["duration_s"].as_f64().unwrap() > 0.1, "{a}");
    }
    let height = v["height"].as_f64().unwrap();
    assert!((70.0..90.0).contains(&height), "{height}");
    let scale = v["suggested_character_scale"].as_f64().unwrap();
    assert!((scale * height - 1.7).abs() < 0.05, "{scale} x {height}");
    assert!(v["bind_bbox_min"][1].as_f64().unwrap() < v["bind_bbox_max"][1].as_f64().unwrap());
    let o = knitvox(&["inspect", fox]);
    let text = String::from_utf8_lossy(&o.stdout);
    for want in [
        "b_Spine02_03",
        "Walk (0.7",
        "--character-scale 0.022",
        "bind bbox",
    ] {
        assert!(text.contains(want), "{want}: {text}");
    }
}

/// `inspect CHAR.glb --animation A --time T` places every joint in that
/// pose: bones keep their lengths (the fox's limbs are rigid), joints move,
/// the arm chain is in order; an unknown animation is bad input naming the
/// ones the file has.
#[test]
fn inspect_character_places_joints_in_a_chosen_pose() {
    let fox = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/Fox.glb");
    let places = |extra: &[&str]| {
        let o = knitvox(&[&["inspect", fox, "--json"], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
        json_of(&o)[0]["joint_places"].as_array().unwrap().clone()
    };
    let bind = places(&[]);
    let walk = places(&["--animation", "Walk", "--time", "0.3"]);
    assert_eq!(bind.len(), 24);
    assert_eq!(walk.len(), 24);
    let mut moved = 0;
    for (b, w) in bind.iter().zip(&walk) {
        assert_eq!(b["name"], w["name"]);
        assert_eq!(b["parent"], w["parent"]);
        // The hip rides on the root with the walk's root motion; every
        // other bone is rigid.
        let rooted = b["parent"].as_str().is_some_and(|p| p.contains("Root"));
        if let (Some(lb), Some(lw), false) =
            (b["bone_length"].as_f64(), w["bone_length"].as_f64(), rooted)
        {
            assert!((lb - lw).abs() < 1e-3 * lb.max(1.0), "{b} / {w}");
        }
        let d: f64 = (0..3)
            .map(|k| {
                (b["position"][k].as_f64().unwrap() - w["position"][k].as_f64().unwrap()).powi(2)
            })
            .sum::<f64>()
            .sqrt();
        moved += usize::from(d > 1.0);
    }
    assert!(moved > 10, "{moved} joints moved");
    let hand = walk.iter().find(|j| j["name"] == "b_LeftHand_011").unwrap();
    assert_eq!(hand["parent"], "b_LeftForeArm_010");
    assert!(hand["bone_length"].as_f64().unwrap() > 10.0, "{hand}");
    let o = knitvox(&["inspect", fox, "--animation", "Jump"]);
    assert_eq!(o.status.code(), Some(65));
    let e = stderr(&o);
    assert!(e.contains("Jump") && e.contains("Survey, Walk, Run"), "{e}");
}

/// Completion scripts and --help offer the values of
/// --backend, --solver and --format.
#[test]
fn completion_offers_backend_solver_and_format_values() {
    let o = knitvox(&["completions", "bash"]);
    let s = String::from_utf8_lossy(&o.stdout);
    for values in ["cpu gpu auto", "direct dd", "ply bcc obj gltf glb h5"] {
        assert!(s.contains(values), "bash completion lacks '{values}'");
    }
    let o = knitvox(&["completions", "fish"]);
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("-l backend") && s.contains("cpu\\t"),
        "fish: backend"
    );
    let help = String::from_utf8_lossy(&knitvox(&["simulate", "--help"]).stdout).into_owned();
    for v in ["cpu", "gpu", "auto", "direct", "dd"] {
        assert!(
            help.contains(&format!("- {v}:")),
            "simulate --help lacks {v}"
        );
    }
}

/// A headless farm node (no Wayland session): probing for a GPU must not
/// print error lines from the Vulkan drivers' layers. Mesa's device-select
/// layer, where installed (CI installs mesa-vulkan-drivers), connects to a
/// Wayland display and prints "error: XDG_RUNTIME_DIR is invalid or not set"
/// twice unless knitvox switches it off (`main`).
#[test]
fn gpu_probe_on_a_headless_node_prints_no_driver_errors() {
    let o = Command::new(common::knitvox_bin())
        .args(["bench", "sim", "--tets", "200", "--steps", "1"])
        .args(["--backend", "auto", "--json"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("NODEVICE_SELECT")
        .output()
        .expect("run knitvox");
    let err = stderr(&o);
    assert!(o.status.success(), "bench sim failed: {err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "driver noise: {err}");
}

/// `bench sim` measures its own accuracy: the default tolerance stays
/// within 1% of the converged reference run of the drape, while a fixed two
/// iterations per step is flagged as capped, warned about and further off.
#[test]
fn bench_sim_reports_the_deviation_from_its_converged_reference() {
    let bench = |extra: &[&str]| {
        let o = Command::new(common::knitvox_bin())
            .args(["bench", "sim", "--tets", "1500", "--steps", "10"])
            .args(["--backend", "cpu", "--json"])
            .args(extra)
            .output()
            .expect("run knitvox");
        assert!(o.status.success(), "bench sim failed: {}", stderr(&o));
        (json_of(&o), stderr(&o))
    };
    let num = |v: &serde_json::Value, k: &str| {
        v[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {v}"))
    };
    let (d, err) = bench(&[]);
    assert!(d["scene"].as_str().unwrap().starts_with("drape"), "{d}");
    assert_eq!(d["capped_steps"], 0, "{d}");
    assert_eq!(d["reference_capped_steps"], 0, "{d}");
    assert!(num(&d, "convergence") <= num(&d, "tolerance"), "{d}");
    assert!(num(&d, "displacement_m") > 0.02, "{d}");
    assert!(num(&d, "deviation") <= 0.01, "{d}");
    assert!(
        num(&d, "reference_iterations") > num(&d, "pd_iterations"),
        "{d}"
    );
    assert!(!err.contains("warning"), "{err}");
    let (few, err) = bench(&["--pd-iterations", "2", "--tolerance", "0"]);
    assert_eq!(few["capped_steps"], 10, "{few}");
    assert_eq!(few["pd_iterations"], 2.0, "{few}");
    assert!(
        num(&few, "deviation") > 2.0 * num(&d, "deviation"),
        "{few} vs {d}"
    );
    assert!(err.contains("warning") && err.contains("cap"), "{err}");
    let (none, _) = bench(&["--no-reference", "--scene", "stretch"]);
    assert!(none["deviation"].is_null(), "{none}");
    assert!(
        none["scene"].as_str().unwrap().starts_with("stretch"),
        "{none}"
    );
}

/// A small swatch with points 5 and 17 of every curve written twice (the
/// repeats real BCC files carry), and its curves without the repeats.
fn swatch_with_repeats() -> (knitvox::geom::Yarns, knitvox::geom::Yarns) {
    use knitvox::yarn::analytic::{knit_swatch, SwatchParams};
    let clean = knit_swatch(&SwatchParams {
        courses: 3,
        wales: 3,
        with_ring: false,
        points_per_loop: 12,
        ..SwatchParams::default()
    });
    let mut dup = knitvox::geom::Yarns::new();
    for c in 0..clean.num_curves() {
        let mut pts = Vec::new();
        for (i, q) in clean.curve(c).iter().enumerate() {
            pts.push(*q);
            if i == 5 || i == 17 {
                pts.push(*q);
            }
        }
        dup.push_curve(&pts, clean.closed[c], clean.radius[c]);
    }
    (dup, clean)
}

/// Repeated points are welded on read: `inspect` says how many (text and
/// JSON), `embed` warns and reports it, and a frame sequence of the same
/// garment whose later frame moved the repeats apart is welded by its
/// first frame's map, so it still matches the asset (`shapefit`).
#[test]
fn repeated_points_are_welded_reported_and_frames_still_match() {
    let dir = tempfile::tempdir().unwrap();
    let (dup, clean) = swatch_with_repeats();
    let welded = 2 * clean.num_curves();
    assert_eq!(dup.num_points(), clean.num_points() + welded);
    let w = knitvox::io::WriteOptions::default();
    let rest = dir.path().join("dup.bcc");
    knitvox::io::write_path(&rest, &dup, None, &w).unwrap();
    let o = knitvox(&["inspect", p(&rest), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = &json_of(&o)[0];
    assert_eq!(r["welded_points"], welded, "{r}");
    assert_eq!(r["points"], clean.num_points(), "{r}");
    assert!(r["segment_length_m"]["min"].as_f64().unwrap() > 1e-6, "{r}");
    let o = knitvox(&["inspect", p(&rest)]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains(&format!("welded {welded} repeated point")),
        "{text}"
    );
    let asset = dir.path().join("dup.vtkhdf");
    let o = knitvox(&["embed", p(&rest), "-o", p(&asset), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_of(&o)["welded_points"], welded);
    assert!(
        stderr(&o).contains(&format!(
            "warning: {}: welded {welded} repeated point",
            p(&rest)
        )),
        "{}",
        stderr(&o)
    );
    // Frame 1 as the rest; frame 2 moved, its repeats pulled apart
    // halfway along their next segment.
    let seq = dir.path().join("seq.####.bcc");
    knitvox::io::write_path(&dir.path().join("seq.0001.bcc"), &dup, None, &w).unwrap();
    let mut moved = dup.clone();
    for c in 0..moved.num_curves() {
        let r = moved.curve_range(c);
        for i in [6, 19] {
            let (a, b) = (moved.points[r.start + i], moved.points[r.start + i + 1]);
            moved.points[r.start + i] = std::array::from_fn(|k| 0.5 * (a[k] + b[k]));
        }
    }
    moved.map_points(|q| [q[0] + 1e-4, q[1], q[2]]);
    knitvox::io::write_path(&dir.path().join("seq.0002.bcc"), &moved, None, &w).unwrap();
    let fitted = dir.path().join("fitted.vtkhdf");
    let o = knitvox(&["shapefit", p(&asset), p(&seq), "-o", p(&fitted), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_of(&o)["frames"], 2);
}
