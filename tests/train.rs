//! `knitvox train`: training poses (VH 2024 §8.6) run quasi-statically on
//! an asset's rest yarns, through the real binary, on a small relaxed 1x1
//! rib embedded once per test process.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use knitvox::io::{self, h5};

/// `(exit code, stdout, stderr)` of the binary with `args`.
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

/// A 4 x 4 rib relaxed into contact by `knitvox pattern` (rest shape
/// stored) and embedded by `knitvox embed`: `(dir, yarns.h5, asset)`.
fn asset() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static ASSET: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    ASSET.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let yarns = dir.path().join("rib.h5");
        let asset = dir.path().join("rib.vtkhdf");
        let s = |p: &Path| p.to_str().unwrap().to_string();
        let (code, _, err) = run(&[
            "pattern",
            "rib1x1",
            "--courses",
            "4",
            "--wales",
            "4",
            "-o",
            &s(&yarns),
        ]);
        assert_eq!(code, 0, "{err}");
        let (code, _, err) = run(&["embed", &s(&yarns), "-o", &s(&asset)]);
        assert_eq!(code, 0, "{err}");
        (dir, yarns, asset)
    })
}

fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs a pose with `--json` into `out`; returns the report.
fn train(out: &Path, extra: &[&str]) -> serde_json::Value {
    let (_, _, a) = asset();
    let mut args = vec!["train", path_str(a), "-o", path_str(out), "--json"];
    args.extend_from_slice(extra);
    let (code, stdout, err) = run(&args);
    assert_eq!(code, 0, "train {extra:?}: {err}");
    // One line, the report (as simulate, yls and run end theirs).
    assert_eq!(stdout.trim_end().lines().count(), 1, "{stdout}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["event"], "report");
    // No terminal here: a progress line per load step on stderr (farm
    // logs), unless switched off.
    let n = v["frames"].as_u64().unwrap();
    if extra.contains(&"--no-progress") {
        assert!(!err.contains("train: frame"), "{err}");
    } else {
        assert!(
            err.contains(&format!("train: frame 1 (1/{n}) "))
                && err.contains(&format!("train: frame {n} ({n}/{n}) ")),
            "{err}"
        );
    }
    v
}

fn dataset(path: &Path, name: &str) -> (Vec<usize>, Vec<f64>) {
    h5::read_dataset_f64(path, name).unwrap()
}

#[test]
fn stretch_courses_moves_the_band_pulls_back_harder_each_step_and_records_its_mechanics() {
    let (dir, _, asset_path) = asset();
    let out = dir.path().join("stretch.h5");
    let steps = 3;
    let amount = 0.1;
    let r = train(
        &out,
        &[
            "--pose",
            "stretch_courses",
            "--amount",
            "0.1",
            "--steps",
            "3",
        ],
    );
    assert_eq!(r["frames"], steps);
    assert_eq!(r["pose"], "stretch_courses");
    assert_eq!(r["rest_shape"], "stored", "{r}");
    // `pattern` writes the swatch lying in the fabric frame: nothing to turn.
    assert_eq!(r["fabric_plane"], "xz", "{r}");
    // The material `pattern` relaxed the yarns under came through `embed`.
    assert_eq!(r["material"]["source"], "yarn file", "{r}");
    assert_eq!(r["material"]["material"]["young_modulus"], 5e5, "{r}");

    // The frames have the asset's topology and the mechanics datasets.
    let asset = io::vtkhdf::read_asset(asset_path).unwrap();
    let rest = &asset.rest_yarns;
    let n = rest.num_points();
    let back = io::read_path(&out, &Default::default()).unwrap();
    assert_eq!(back.yarns.num_curves(), rest.num_curves());
    assert_eq!(back.yarns.num_points(), n);
    assert_eq!(back.yarns.points, rest.points);
    assert!(
        back.yarns.rest.is_some(),
        "the rest shape travels with the frames"
    );
    let (shape, points) = dataset(&out, "frames/points");
    assert_eq!(shape, vec![steps, n, 3]);
    let (shape, energy) = dataset(&out, "frames/elastic_energy");
    assert_eq!(shape, vec![steps]);
    let (shape, reactions) = dataset(&out, "frames/reaction_forces");
    assert_eq!(shape, vec![steps, n, 3]);
    let (shape, external) = dataset(&out, "frames/external_forces");
    assert_eq!(shape, vec![steps, n, 3]);
    assert!(external.iter().all(|f| *f == 0.0), "no gravity in a pose");
    let (_, times) = dataset(&out, "frames/times");
    for (k, t) in times.iter().enumerate() {
        assert!(
            (t - amount * (k + 1) as f64 / steps as f64).abs() < 1e-12,
            "{times:?}"
        );
    }

    // The right band (6% of the width) moved by amount x width along the
    // courses (+X in the pattern's frame), step by step; it pulls back
    // harder at every step and the energy rises.
    let b = rest.bounds().unwrap();
    let lx = b.max[0] - b.min[0];
    let right: Vec<usize> = (0..n)
        .filter(|&v| rest.points[v][0] >= b.max[0] - 0.06 * lx)
        .collect();
    assert!(right.len() > 5, "{} vertices in the band", right.len());
    let mut force = Vec::new();
    for k in 0..steps {
        let want = amount * lx * (k + 1) as f64 / steps as f64;
        for &v in &right {
            let i = 3 * (k * n + v);
            let d = [0, 1, 2].map(|c| points[i + c] - rest.points[v][c]);
            assert!(
                (d[0] - want).abs() < 1e-12 && d[1].abs() < 1e-12 && d[2].abs() < 1e-12,
                "step {k} vertex {v}: moved {d:?}, want {want} along x"
            );
        }
        let fx: f64 = right.iter().map(|&v| reactions[3 * (k * n + v)]).sum();
        let total: f64 = (0..n).map(|v| reactions[3 * (k * n + v)]).sum();
        assert!(
            total.abs() <= 0.01 * fx.abs() + 1e-5,
            "step {k}: clamps do not balance ({total} N of {fx} N)"
        );
        force.push(fx);
    }
    assert!(force[0] > 0.0, "{force:?}");
    assert!(force.windows(2).all(|w| w[1] > w[0]), "force {force:?}");
    assert!(energy.windows(2).all(|w| w[1] > w[0]), "energy {energy:?}");
    // The report's final force is the right clamp's (its magnitude).
    let last = r["final_force_n"].as_f64().unwrap();
    assert!(
        last >= force[2] && last <= 1.05 * force[2],
        "{last} vs {force:?}"
    );
    assert!(r["min_distance_ratio"].as_f64().unwrap() > 0.75, "{r}");

    // The pose record names the pose and the asset (path and SHA-256).
    let rec: serde_json::Value =
        serde_json::from_str(&h5::read_text(&out, "pose_json").unwrap().unwrap()).unwrap();
    assert_eq!(rec["kind"], "stretch_courses");
    assert_eq!(rec["amount"], 0.1);
    assert_eq!(rec["mirror"], false);
    assert_eq!(rec["steps"], steps);
    let sha = knitvox::pipeline::util::sha256_file(asset_path).unwrap();
    assert_eq!(rec["asset"]["sha256"], sha.as_str());
    assert_eq!(r["asset_sha256"], sha.as_str());
    assert_eq!(rec["asset"]["path"], path_str(asset_path));
}

#[test]
fn the_same_pose_twice_writes_bit_identical_frames() {
    let (dir, _, _) = asset();
    let args = ["--pose", "bend_central", "--steps", "2"];
    let (a, b) = (dir.path().join("bend-a.h5"), dir.path().join("bend-b.h5"));
    train(&a, &args);
    // Progress off or on changes nothing but stderr.
    train(&b, &[&args[..], &["--no-progress"]].concat());
    for name in [
        "frames/points",
        "frames/times",
        "frames/elastic_energy",
        "frames/reaction_forces",
        "frames/external_forces",
    ] {
        let (da, db) = (dataset(&a, name), dataset(&b, name));
        assert_eq!(da.0, db.0, "{name}");
        assert!(
            da.1.iter()
                .zip(&db.1)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "{name} differs"
        );
    }
}

#[test]
fn every_training_pose_runs_two_steps_and_stores_energy() {
    let (dir, _, _) = asset();
    let kinds = [
        "stretch_courses",
        "stretch_wales",
        "biaxial",
        "shear",
        "bend_central",
        "bend_diagonal",
        "fan",
        "twist",
        "multi_fold",
    ];
    for kind in kinds {
        for mirror in [false, true] {
            if mirror && !matches!(kind, "bend_central" | "twist") {
                continue;
            }
            let out = dir.path().join(format!("{kind}-{mirror}.h5"));
            let mut args = vec!["--pose", kind, "--steps", "2"];
            if mirror {
                args.push("--mirror");
            }
            let r = train(&out, &args);
            assert_eq!(r["frames"], 2, "{kind}");
            assert_eq!(r["mirror"], mirror, "{kind}");
            let (_, energy) = dataset(&out, "frames/elastic_energy");
            assert!(
                energy[1] > energy[0] && energy[0] > 0.0,
                "{kind} mirror {mirror}: energy {energy:?}"
            );
            assert!(r["final_force_n"].as_f64().unwrap() > 0.0, "{kind}: {r}");
        }
    }
}

#[test]
fn bad_requests_are_usage_errors_and_non_assets_are_named() {
    let (dir, yarns, asset_path) = asset();
    let out = dir.path().join("bad.h5");
    let (o, a) = (path_str(&out), path_str(asset_path));
    for args in [
        vec!["train", a, "--pose", "nosuch", "-o", o],
        vec!["train", a, "--pose", "hang", "-o", o],
        vec![
            "train",
            a,
            "--pose",
            "multi_fold",
            "--amount",
            "0.7",
            "-o",
            o,
        ],
        vec![
            "train",
            a,
            "--pose",
            "stretch_courses",
            "--amount",
            "-1.5",
            "-o",
            o,
        ],
        vec!["train", a, "--pose", "twist", "--amount", "nan", "-o", o],
        vec!["train", a, "--pose", "shear", "--steps", "0", "-o", o],
        vec!["train", a, "--pose", "shear", "--friction", "-1", "-o", o],
        vec![
            "train",
            a,
            "--pose",
            "stretch_courses",
            "--band",
            "0.6",
            "-o",
            o,
        ],
        vec![
            "train",
            a,
            "--pose",
            "cantilever",
            "--gravity",
            "9.81",
            "--band",
            "0.95",
            "-o",
            o,
        ],
        vec!["train", a, "--pose", "shear", "-o", "x.ply"],
    ] {
        let (code, _, err) = run(&args);
        assert!(code == 2 || code == 65, "{args:?}: exit {code}: {err}");
        if !args.contains(&"x.ply") {
            assert_eq!(code, 2, "{args:?}: {err}");
        }
        assert!(err.contains("error"), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} wrote its output");
    }
    // A yarn file is not an asset; nor is a text file named like one.
    let (code, _, err) = run(&["train", path_str(yarns), "--pose", "shear", "-o", o]);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("rib.h5") && err.contains(".vtkhdf"), "{err}");
    let fake = dir.path().join("fake.vtkhdf");
    std::fs::write(&fake, "not an asset\n").unwrap();
    let (code, _, err) = run(&["train", path_str(&fake), "--pose", "shear", "-o", o]);
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("fake.vtkhdf"), "{err}");
    // The output may not replace the asset.
    let (code, _, err) = run(&["train", a, "--pose", "shear", "-o", a]);
    assert_eq!(code, 2, "{err}");
    let missing = dir.path().join("missing.vtkhdf");
    let (code, _, err) = run(&["train", path_str(&missing), "--pose", "shear", "-o", o]);
    assert_eq!(code, 66, "{err}");
    assert!(!out.exists());
}

/// An asset embedded from loose generated yarns (no rest shape) still
/// trains, from its positions as rest, and says so.
#[test]
fn an_asset_without_a_rest_shape_trains_from_its_positions_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let (yarns, asset, out) = (
        dir.path().join("loose.h5"),
        dir.path().join("loose.vtkhdf"),
        dir.path().join("pose.h5"),
    );
    let (code, _, err) = run(&[
        "pattern",
        "rib1x1",
        "--courses",
        "2",
        "--wales",
        "4",
        "--no-relax",
        "-o",
        path_str(&yarns),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = run(&["embed", path_str(&yarns), "-o", path_str(&asset)]);
    assert_eq!(code, 0, "{err}");
    let (code, stdout, err) = run(&[
        "train",
        path_str(&asset),
        "--pose",
        "shear",
        "--steps",
        "1",
        "-o",
        path_str(&out),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("warning") && err.contains("no rest shape"),
        "{err}"
    );
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(r["rest_shape"], "positions");
    assert_eq!(r["warnings"].as_array().unwrap().len(), 1, "{r}");
    assert_eq!(r["frames"], 1);
    // A point moved onto another course: the yarns cross at rest, which no
    // load step can undo. Refused at once (it used to take 62 Newton
    // rounds, 41 s, on a fuzzed asset), naming the asset.
    let crossed = dir.path().join("crossed.vtkhdf");
    copy_editing_points(&asset, &crossed, "knitvox/rest_yarns/points", |p| {
        let w = p.nrows() / 2;
        let target = p.row(w).to_owned();
        p.row_mut(10).assign(&target);
    });
    let err = refused_at_once(&crossed, &dir.path().join("crossed-pose.h5"));
    assert!(
        err.contains("crossed.vtkhdf") && err.contains("pass through each other"),
        "{err}"
    );
}

/// Yarns read with a radius too large for the file overlap at rest: the
/// refusal names the radius the asset was embedded with, the closest
/// distance found and how to give a smaller one.
#[test]
fn rest_yarns_read_with_too_large_a_radius_are_refused_with_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    let (yarns, asset) = (dir.path().join("rib.bcc"), dir.path().join("thick.vtkhdf"));
    let (code, _, err) = run(&[
        "pattern",
        "rib1x1",
        "--courses",
        "2",
        "--wales",
        "4",
        "--no-relax",
        "-o",
        path_str(&yarns),
    ]);
    assert_eq!(code, 0, "{err}");
    // The pattern's yarns are about 2 mm apart (radius 1 mm): read as 3 mm.
    let (code, _, err) = run(&[
        "embed",
        path_str(&yarns),
        "--radius",
        "0.003",
        "--override-radius",
        "-o",
        path_str(&asset),
    ]);
    assert_eq!(code, 0, "{err}");
    let err = refused_at_once(&asset, &dir.path().join("pose.h5"));
    assert!(err.contains("pass through each other"), "{err}");
    assert!(err.contains("radius of 3.000e-3 m"), "{err}");
    assert!(err.contains("m apart, rA + rB = 6.000e-3 m"), "{err}");
    assert!(
        err.contains("--radius") && err.contains("[garment] radius") && err.contains("too large"),
        "{err}"
    );
}

/// Runs a one-step shear on `asset` into `out`, which must fail as bad
/// input (65) within seconds and write nothing; returns stderr.
fn refused_at_once(asset: &Path, out: &Path) -> String {
    let t = std::time::Instant::now();
    let args = ["train", path_str(asset), "--pose", "shear", "--steps", "1"];
    let (code, _, err) = run(&[&args[..], &["-o", path_str(out)]].concat());
    assert_eq!(code, 65, "{err}");
    assert!(t.elapsed().as_secs_f64() < 20.0, "{:?}: {err}", t.elapsed());
    assert!(!out.exists(), "{err}");
    err
}

/// Copies `from` to `to` with the dataset `points` (N x 3) changed by `edit`.
fn copy_editing_points(
    from: &Path,
    to: &Path,
    points: &str,
    edit: impl FnOnce(&mut ndarray::Array2<f64>),
) {
    std::fs::copy(from, to).unwrap();
    let f = common::h5_edit(to);
    let ds = f.dataset(points).unwrap();
    let mut p: ndarray::Array2<f64> = ds.read_2d().unwrap();
    edit(&mut p);
    ds.write(&p).unwrap();
    drop(ds);
    f.close().unwrap();
}

/// Copies `from` to `to` with point `v` of the dataset `points` moved 4 mm
/// along y.
fn copy_moving_a_point(from: &Path, to: &Path, points: &str, v: usize) {
    copy_editing_points(from, to, points, |p| p[[v, 1]] += 4e-3);
}

/// Yarns that are not a state of their stored rest shape (a rest point
/// moved 4 mm) are refused at once by every rods model, naming the file
/// they came from and the segment (they used to train: the first load step
/// pulled the point back and the pose recorded it as motion).
#[test]
fn rest_yarns_off_their_rest_shape_are_refused_at_once() {
    let (_, _, a) = asset();
    let dir = tempfile::tempdir().unwrap();
    let moved = dir.path().join("moved.vtkhdf");
    let v = 20;
    copy_moving_a_point(a, &moved, "knitvox/rest_yarns/points", v);
    let out = dir.path().join("pose.h5");
    let err = refused_at_once(&moved, &out);
    for word in [
        "moved.vtkhdf",
        &format!("vertices {} and {v}", v - 1),
        "not a state of the stored rest shape",
    ] {
        assert!(err.contains(word), "{word:?} not in {err}");
    }
    // `validate` runs a scene without `[swatch]` on the asset's rest yarns:
    // the fault is the asset's, and the asset is named, not the scene.
    let scene = dir.path().join("shear.toml");
    std::fs::write(
        &scene,
        "name = \"s\"\nduration = 0.1\nframe_rate = 30\nmodel = \"rods\"\n\
         [pose]\nkind = \"shear\"\namount = 0.1\n",
    )
    .unwrap();
    let (code, _, err) = run(&[
        "validate",
        path_str(&moved),
        "--scene",
        path_str(&scene),
        "--backend",
        "cpu",
    ]);
    assert_eq!(code, 65, "{err}");
    assert!(
        err.contains("moved.vtkhdf: rest yarns: segment") && !err.contains("shear.toml"),
        "{err}"
    );
    // The same fault in a yarn file: `yls` names the swatch file, not its
    // scene; `fabric-test` names it too.
    let (_, yarns, _) = asset();
    let moved_yarns = dir.path().join("moved.h5");
    copy_moving_a_point(yarns, &moved_yarns, "yarns/points", v);
    let scene = dir.path().join("drop.toml");
    std::fs::write(
        &scene,
        format!(
            "name = \"d\"\nduration = 0.1\nframe_rate = 30\nmodel = \"rods\"\n\
             [swatch]\nfile = '{}'\n[pose]\nkind = \"free\"\n",
            moved_yarns.display()
        ),
    )
    .unwrap();
    let yls_out = dir.path().join("drop.h5");
    let (code, _, err) = run(&["yls", path_str(&scene), "-o", path_str(&yls_out)]);
    assert_eq!(code, 65, "{err}");
    assert!(
        err.contains("moved.h5: segment") && !err.contains("drop.toml"),
        "{err}"
    );
    let (code, _, err) = run(&["fabric-test", "stretch", path_str(&moved_yarns)]);
    assert_eq!(code, 65, "{err}");
    assert!(
        err.contains("moved.h5") && err.contains("not a state of the stored rest shape"),
        "{err}"
    );
}

/// `--amount 0.05,0.1` loads through both amplitudes, `--steps` steps to
/// each: the frames' amounts, the record's stops, and `fit` fitting the
/// frame at each amplitude with its own training error.
#[test]
fn a_list_of_amounts_trains_each_amplitude_and_fit_reports_each() {
    let (dir, _, asset_path) = asset();
    let out = dir.path().join("stretch_list.h5");
    let r = train(
        &out,
        &[
            "--pose",
            "stretch_courses",
            "--amount",
            "0.05,0.1",
            "--steps",
            "2",
        ],
    );
    assert_eq!(r["frames"], 4, "{r}");
    assert_eq!(r["amounts"], serde_json::json!([0.05, 0.1]), "{r}");
    assert_eq!(r["stop_frames"], serde_json::json!([1, 3]), "{r}");
    let (_, times) = dataset(&out, "frames/times");
    let want = [0.025, 0.05, 0.075, 0.1];
    for (t, w) in times.iter().zip(want) {
        assert!((t - w).abs() < 1e-12, "{times:?}");
    }
    let record: serde_json::Value =
        serde_json::from_str(&h5::read_text(&out, "pose_json").unwrap().unwrap()).unwrap();
    assert_eq!(record["stop_frames"], serde_json::json!([1, 3]), "{record}");
    assert_eq!(record["frame_amounts"].as_array().unwrap().len(), 4);
    // A NaN amplitude is a usage error naming it.
    let (code, _, err) = run(&[
        "train",
        path_str(asset_path),
        "--pose",
        "shear",
        "--amount",
        "0.1,nan",
        "-o",
        path_str(&dir.path().join("bad.h5")),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("amount"), "{err}");

    let fitted = dir.path().join("listed.fit.vtkhdf");
    let (code, stdout, err) = run(&[
        "fit",
        path_str(asset_path),
        "--train",
        path_str(&out),
        "--harmonic",
        "0",
        "--gd-iterations",
        "2",
        "--gn-iterations",
        "2",
        "-o",
        path_str(&fitted),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(stdout.trim_end().lines().last().unwrap()).unwrap();
    let pose = &report["poses"][0];
    assert_eq!(pose["frames"], serde_json::json!([1, 3]), "{pose}");
    assert_eq!(pose["amounts"], serde_json::json!([0.05, 0.1]), "{pose}");
    let per = pose["training_per_frame"].as_array().unwrap();
    assert_eq!(per.len(), 2, "{pose}");
    for t in per {
        let f = t["fitted_rms_yarn_diameters"].as_f64().unwrap();
        assert!(f.is_finite() && f >= 0.0, "{t}");
    }
}

#[test]
fn a_three_dimensional_garment_is_refused_at_once_pointing_to_material_cards() {
    // A knit tube: a closed garment, no flat extent to clamp bands across.
    let dir = tempfile::tempdir().unwrap();
    let tube = dir.path().join("tube.h5");
    let asset = dir.path().join("tube.vtkhdf");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (code, _, err) = run(&[
        "pattern",
        "stockinette",
        "--courses",
        "6",
        "--wales",
        "12",
        "--tube-radius",
        "0.008",
        "--no-relax",
        "-o",
        &s(&tube),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = run(&["embed", &s(&tube), "-o", &s(&asset)]);
    assert_eq!(code, 0, "{err}");
    let err = refused_at_once(&asset, &dir.path().join("pose.h5"));
    assert!(err.contains("no flat swatch"), "{err}");
    assert!(
        err.contains("knitvox card") && err.contains("embed --card"),
        "{err}"
    );
}
