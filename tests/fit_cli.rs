//! `knitvox fit` through the real binary on synthetic training poses: an
//! embedded swatch with a known stiffer band, homogenized equilibria of that
//! truth under clamps and loads (forward static solver), V2Y'd into yarn
//! frames with their mechanics (reaction and external forces, energy).
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use knitvox::embed::EmbedParams;
use knitvox::fit::elastic::adjoint::equilibrium;
use knitvox::fit::elastic::{Frame, FrameTarget};
use knitvox::fit::{ShapeFitParams, ShapeFitter};
use knitvox::geom::{Asset, Vec3};
use knitvox::io::{self, h5::FrameWriter, ReadOptions, WriteOptions};
use knitvox::pipeline::asset::{build_asset, re_embed};
use knitvox::pipeline::fit::node_forces;
use knitvox::pipeline::util::held_nodes;
use knitvox::sim::energy::ElasticModel;
use knitvox::sim::statics::StaticParams;
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};

const VOXEL: f64 = 2.5e-3;

fn swatch(courses: usize, wales: usize) -> knitvox::geom::Yarns {
    knit_swatch(&SwatchParams {
        courses,
        wales,
        points_per_loop: 12,
        with_ring: false,
        ..SwatchParams::default()
    })
}

/// Embeds a 4 x 5 swatch into `dir/a.vtkhdf`.
fn asset_in(dir: &Path) -> (PathBuf, Asset) {
    let y = swatch(4, 5);
    let yarns = dir.join("sw.ply");
    io::write_path(&yarns, &y, None, &WriteOptions::default()).unwrap();
    let params = EmbedParams {
        voxel_size: Some(VOXEL),
        ..EmbedParams::default()
    };
    let (asset, _) = build_asset(&yarns, &ReadOptions::default(), &params, "test").unwrap();
    let path = dir.join("a.vtkhdf");
    io::vtkhdf::write_asset(&path, &asset).unwrap();
    (path, asset)
}

fn centroid_x(a: &Asset, e: usize) -> f64 {
    a.mesh.tets[e]
        .iter()
        .map(|&i| a.mesh.nodes[i as usize][0])
        .sum::<f64>()
        / 4.0
}

fn x_extent(a: &Asset) -> (f64, f64) {
    a.rest_yarns
        .points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |m, p| {
            (m.0.min(p[0]), m.1.max(p[0]))
        })
}

/// The truth: 2e4 / 6e3 Pa, 5x stiffer on the middle third along x.
fn truth(a: &Asset) -> (Vec<f64>, Vec<f64>) {
    let (x0, x1) = x_extent(a);
    let (mut gs, mut gv) = (vec![2e4; a.mesh.num_tets()], vec![6e3; a.mesh.num_tets()]);
    for e in 0..a.mesh.num_tets() {
        let c = (centroid_x(a, e) - x0) / (x1 - x0);
        if (1.0 / 3.0..=2.0 / 3.0).contains(&c) {
            gs[e] *= 5.0;
            gv[e] *= 5.0;
        }
    }
    (gs, gv)
}

/// A pose file: the left band (x within 12% of the width) held, the right
/// band loaded by `load` (N in total, spread over its vertices), at 50% and
/// 100% of the load. Returns the largest yarn displacement (m).
/// The held yarn vertices (the left band) and the yarn forces (`s` times
/// `load` spread over the right band) of a synthetic pose.
fn pose_loads(a: &Asset, load: Vec3, s: f64) -> (Vec<bool>, Vec<Vec3>) {
    let (x0, x1) = x_extent(a);
    let band = 0.12 * (x1 - x0);
    let pts = &a.rest_yarns.points;
    let held: Vec<bool> = pts.iter().map(|p| p[0] < x0 + band).collect();
    let loaded: Vec<usize> = (0..pts.len()).filter(|&v| pts[v][0] > x1 - band).collect();
    let mut f_y = vec![[0.0; 3]; pts.len()];
    for &v in &loaded {
        f_y[v] = load.map(|c| s * c / loaded.len() as f64);
    }
    (held, f_y)
}

/// The mesh's equilibrium (node positions) under `model` with the loads of
/// [`pose_loads`], the held nodes where `start` has them.
fn loaded_equilibrium(
    a: &Asset,
    model: &ElasticModel,
    held: &[bool],
    f_y: &[Vec3],
    start: &[Vec3],
) -> Vec<Vec3> {
    let frame = Frame {
        target: FrameTarget {
            f_target: Vec::new(),
            alpha: 0.0,
            positions: Vec::new(),
        },
        pinned: held_nodes(&a.mesh, &a.embedding, held),
        start: start.to_vec(),
        f_ext: node_forces(&a.mesh, &a.embedding, f_y),
        forces: None,
    };
    let tight = StaticParams {
        tolerance: 1e-8,
        max_iterations: 200,
    };
    equilibrium(model, &a.node_mass, &frame, start, &tight)
        .unwrap()
        .0
}

fn write_pose(a: &Asset, gs: &[f64], gv: &[f64], load: Vec3, path: &Path) -> f64 {
    let model = ElasticModel::new(&a.mesh, gs, gv).unwrap();
    let pts = &a.rest_yarns.points;
    let mut w = FrameWriter::create(path, &a.rest_yarns).unwrap();
    let mut largest = 0.0f64;
    for (t, s) in [(0.5, 0.5), (1.0, 1.0)] {
        let (held, f_y) = pose_loads(a, load, s);
        let x = loaded_equilibrium(a, &model, &held, &f_y, &a.mesh.nodes);
        let y = a.embedding.v2y(&a.mesh, &x);
        largest = y
            .iter()
            .zip(pts)
            .map(|(p, q)| knitvox::geom::dist(*p, *q))
            .fold(largest, f64::max);
        // The clamp balances the load; only which rows are non-zero matters.
        let nh = held.iter().filter(|h| **h).count() as f64;
        let reactions: Vec<Vec3> = held
            .iter()
            .map(|&h| {
                if h {
                    load.map(|c| -s * c / nh)
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        w.push(t, &y).unwrap();
        w.push_mechanics(model.energy(&x).unwrap(), &reactions, &f_y)
            .unwrap();
    }
    w.finish().unwrap();
    largest
}

fn knitvox(args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The fixture's poses: file name and the load on the right band (N).
const POSES: [(&str, Vec3); 2] = [
    ("stretch.h5", [0.3, 0.0, 0.0]),
    ("bend.h5", [0.0, 0.0, 1.2e-2]),
];

/// Fixture: an asset and two poses (stretch along x, bend along z).
struct Case {
    _dir: tempfile::TempDir,
    dir: PathBuf,
    asset_path: PathBuf,
    asset: Asset,
    truth: (Vec<f64>, Vec<f64>),
    poses: Vec<PathBuf>,
}

fn case() -> Case {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().to_path_buf();
    let (asset_path, asset) = asset_in(&dir);
    let truth = truth(&asset);
    let mut poses = Vec::new();
    for (name, load) in POSES {
        let p = dir.join(name);
        let d = write_pose(&asset, &truth.0, &truth.1, load, &p);
        eprintln!("{name}: largest yarn displacement {d:.3e} m");
        assert!(d > 0.2 * VOXEL, "{name}: the pose hardly deforms ({d:e} m)");
        poses.push(p);
    }
    Case {
        _dir: tmp,
        dir,
        asset_path,
        asset,
        truth,
        poses,
    }
}

/// A VH Eq. 7 fit (`--model vh`) of the case's poses: the synthetic truth is
/// an Eq. 7 field, which the reference model can recover.
fn fit_args<'a>(c: &'a Case, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec!["fit", s(&c.asset_path), "--train"];
    v.extend(c.poses.iter().map(|p| s(p)));
    v.extend([
        "--model",
        "vh",
        "--samples",
        "1",
        "--harmonic",
        "1,10",
        "--gd-iterations",
        "4",
        "--gn-iterations",
        "8",
        "-o",
        s(out),
    ]);
    v.extend_from_slice(extra);
    v
}

/// Volume-weighted mean of log(gamma) over the tets `keep` selects.
fn log_mean(a: &Asset, g: &[f64], keep: impl Fn(usize) -> bool) -> f64 {
    let model = ElasticModel::new(&a.mesh, &a.gamma_s, &a.gamma_v).unwrap();
    let (mut num, mut den) = (0.0, 0.0);
    for (e, r) in model.rest().iter().enumerate().filter(|(e, _)| keep(*e)) {
        num += r.volume * g[e].ln();
        den += r.volume;
    }
    num / den
}

#[test]
fn fit_reduces_the_loss_moves_gamma_to_the_truth_and_is_deterministic() {
    let c = case();
    let out = c.dir.join("fitted.vtkhdf");
    let report = c.dir.join("report");
    // Joint fit (VH Eq. 9 over both poses), with the report.
    let o = knitvox(&fit_args(
        &c,
        &out,
        &["--joint", "--report", s(&report), "--json"],
    ));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // Full mechanics in the files: no warning.
    assert!(!stderr.contains("warning"), "{stderr}");
    // One JSON line per iteration, then the report (farm logs read them line
    // by line).
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let (r, progress) = lines.split_last().unwrap();
    assert_eq!(r["event"], "report", "{r}");
    assert!(progress.len() >= 2, "{} progress lines", progress.len());
    for p in progress {
        assert_eq!(p["event"], "iteration", "{p}");
        assert!(
            p["loss"]
                .as_f64()
                .is_some_and(|l| l.is_finite() && l >= 0.0),
            "{p}"
        );
        assert!(p["iteration"].as_u64().is_some_and(|i| i >= 1), "{p}");
        // The direction's share of the iteration, and the halvings.
        let (ms, dir) = (
            p["ms"].as_f64().unwrap(),
            p["direction_ms"].as_f64().unwrap(),
        );
        assert!(dir >= 0.0 && dir <= ms, "{p}");
        assert!(p["halvings"].as_u64().is_some(), "{p}");
    }
    let r = r.clone();
    let loss = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap();
    let (before, uniform, fitted) = (
        loss(&r, "loss_before"),
        loss(&r, "loss_uniform"),
        loss(&r, "loss_fitted"),
    );
    let a = io::vtkhdf::read_asset(&out).unwrap();
    let rec = a.fit_record().unwrap().expect("a fit record");
    assert!(a
        .gamma_s
        .iter()
        .chain(&a.gamma_v)
        .all(|g| g.is_finite() && *g > 0.0));
    // Toward the truth: the uniform material's log-mean moves toward the
    // truth's, and the fitted field makes the band stiffer than the rest.
    let all = |_: usize| true;
    let (x0, x1) = x_extent(&a);
    let in_band = |e: usize| {
        let t = (centroid_x(&a, e) - x0) / (x1 - x0);
        (1.0 / 3.0..=2.0 / 3.0).contains(&t)
    };
    let contrast = |g: &[f64]| log_mean(&a, g, in_band) - log_mean(&a, g, |e| !in_band(e));
    let truth_s = log_mean(&a, &c.truth.0, all);
    let truth_v = log_mean(&a, &c.truth.1, all);
    let (u_s, u_v) = (rec.uniform.gamma_s.ln(), rec.uniform.gamma_v.ln());
    let (p_s, p_v) = (c.asset.gamma_s[0].ln(), c.asset.gamma_v[0].ln());
    eprintln!(
        "joint: loss {before:.3e} -> uniform {uniform:.3e} -> fitted {fitted:.3e} m^3; log-mean gamma_s {p_s:.2} -> {u_s:.2} (truth {truth_s:.2}), gamma_v {p_v:.2} -> {u_v:.2} (truth {truth_v:.2}); band contrast (log) gamma_s {:.2}, gamma_v {:.2} (truth {:.2})",
        contrast(&a.gamma_s),
        contrast(&a.gamma_v),
        contrast(&c.truth.0)
    );
    assert!(
        fitted <= uniform && uniform < before,
        "{before:e} {uniform:e} {fitted:e}"
    );
    assert!(
        fitted < 0.1 * before,
        "loss fell only {:.2}x",
        before / fitted
    );
    // Distance in (log gamma_s, log gamma_v) from the truth's log-means.
    let d_uniform = (u_s - truth_s).hypot(u_v - truth_v);
    let d_placeholder = (p_s - truth_s).hypot(p_v - truth_v);
    assert!(
        d_uniform < 0.5 * d_placeholder,
        "uniform material {d_uniform:.3} from the truth, placeholder {d_placeholder:.3}"
    );
    assert!(contrast(&a.gamma_s) > 0.0 && contrast(&a.gamma_v) > 0.0);

    // The fit record: poses with their hashes, losses, the uniform material.
    assert_eq!(rec.poses.len(), 2);
    assert!(rec.joint);
    assert_eq!(
        rec.poses[0].sha256,
        knitvox::pipeline::util::sha256_file(&c.poses[0]).unwrap()
    );
    assert_eq!(rec.poses[0].frames, vec![1]);
    assert_eq!(rec.losses.len(), 2);
    assert!(rec.losses.iter().all(|l| l.fitted < l.before));
    // The asset's record keeps each pose's training fidelity, as reported.
    for (k, l) in rec.losses.iter().enumerate() {
        let t = l.training.expect("training fidelity in the record");
        assert_eq!(
            Some(t.fitted_rms_yarn_diameters),
            r["poses"][k]["training"]["fitted_rms_yarn_diameters"].as_f64()
        );
    }
    assert_eq!(a.mesh, c.asset.mesh);

    // Training fidelity, in yarn diameters: the fitted field carries the
    // training yarns closer than the uniform material, and that closer than
    // the placeholder.
    let t = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    let tr = &r["training"];
    let (t_before, t_uniform, t_fitted, t_floor) = (
        t(tr, "before_rms_yarn_diameters"),
        t(tr, "uniform_rms_yarn_diameters"),
        t(tr, "fitted_rms_yarn_diameters"),
        t(tr, "y2v_floor_rms_yarn_diameters"),
    );
    eprintln!("training RMS (yarn diameters): before {t_before:.4}, uniform {t_uniform:.4}, fitted {t_fitted:.4}, Y2V floor {t_floor:.4}");
    assert!(
        t_fitted < t_uniform && t_uniform < t_before && t_floor < t_before,
        "{tr}"
    );
    // Each pose's figures before the fit, recomputed here: the shape fit
    // of its yarns (the floor), and the equilibrium of its loads under the
    // input asset's material with the held nodes where the shape fit has
    // them, as `fit` solves it.
    let placeholder = ElasticModel::new(&c.asset.mesh, &c.asset.gamma_s, &c.asset.gamma_v).unwrap();
    let embedded = re_embed(&c.asset, &c.asset_path).unwrap();
    let fitter =
        ShapeFitter::from_embedded(&c.asset.rest_yarns, &embedded, &ShapeFitParams::default())
            .unwrap();
    let (mut pooled, mut pooled_floor) = (0.0, 0.0);
    for (k, (name, load)) in POSES.iter().enumerate() {
        let data = io::read_path(&c.poses[k], &ReadOptions::default()).unwrap();
        let frames = data.frames.unwrap();
        let yarns = frames.frame(frames.num_frames() - 1);
        let (x_hat, _) = fitter.fit(yarns).unwrap();
        let (held, f_y) = pose_loads(&c.asset, *load, 1.0);
        let x = loaded_equilibrium(&c.asset, &placeholder, &held, &f_y, &x_hat);
        let v2y = |x: &[Vec3]| c.asset.embedding.v2y(&c.asset.mesh, x);
        let rest = &c.asset.rest_yarns;
        let (before, floor) = (
            rms_diameters(rest, &v2y(&x), yarns),
            rms_diameters(rest, &v2y(&x_hat), yarns),
        );
        let pose = &r["poses"][k]["training"];
        for (what, expected) in [
            ("before_rms_yarn_diameters", before),
            ("y2v_floor_rms_yarn_diameters", floor),
        ] {
            let reported = t(pose, what);
            assert!(
                (reported - expected).abs() <= 1e-4 * expected,
                "{name} {what}: reported {reported}, recomputed {expected}"
            );
        }
        pooled += before * before / POSES.len() as f64;
        pooled_floor += floor * floor / POSES.len() as f64;
    }
    for (what, got, want) in [
        ("before", t_before, pooled.sqrt()),
        ("floor", t_floor, pooled_floor.sqrt()),
    ] {
        assert!(
            (got - want).abs() <= 1e-4 * want,
            "pooled {what}: {got} {want}"
        );
    }

    // The report: valid JSON and PNGs.
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report.join("fit.json")).unwrap()).unwrap();
    assert_eq!(json["poses"].as_array().unwrap().len(), 2);
    for png in [
        "loss.png",
        "gamma_hist.png",
        "gamma_s_slice.png",
        "gamma_v_slice.png",
    ] {
        let bytes = std::fs::read(report.join(png)).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(&bytes));
        let info = dec.read_info().unwrap().info().clone();
        assert!(info.width >= 200 && info.height >= 150, "{png}");
    }

    // The paper's pose-by-pose fit with the Eq. 22 fold (the default): the
    // loss falls too, and two runs give the same bits.
    let runs: Vec<(serde_json::Value, Asset)> = ["d1.vtkhdf", "d2.vtkhdf"]
        .iter()
        .map(|name| {
            let out = c.dir.join(name);
            let o = knitvox(&fit_args(&c, &out, &["--json"]));
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let text = String::from_utf8_lossy(&o.stdout).into_owned();
            (
                serde_json::from_str(text.lines().last().unwrap()).unwrap(),
                io::vtkhdf::read_asset(&out).unwrap(),
            )
        })
        .collect();
    let r = &runs[0].0;
    eprintln!(
        "pose by pose: loss {:.3e} -> uniform {:.3e} -> fitted {:.3e} m^3",
        loss(r, "loss_before"),
        loss(r, "loss_uniform"),
        loss(r, "loss_fitted")
    );
    assert!(loss(r, "loss_fitted") < 0.1 * loss(r, "loss_before"));
    assert_eq!(runs[0].1.gamma_s, runs[1].1.gamma_s);
    assert_eq!(runs[0].1.gamma_v, runs[1].1.gamma_v);

    // --max-contrast 1 with no harmonic stage: the full stage may only scale
    // the uniform material, so the field stays uniform.
    let flat = c.dir.join("flat.vtkhdf");
    let mut args = fit_args(&c, &flat, &["--max-contrast", "1"]);
    let h = args.iter().position(|a| *a == "1,10").unwrap();
    args[h] = "0";
    let o = knitvox(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = io::vtkhdf::read_asset(&flat).unwrap();
    for g in [&a.gamma_s, &a.gamma_v] {
        let [lo, hi] = g
            .iter()
            .fold([f64::INFINITY, 0.0f64], |r, v| [r[0].min(*v), r[1].max(*v)]);
        assert!(
            hi <= lo * (1.0 + 1e-9),
            "contrast 1 left gamma in {lo}..{hi}"
        );
    }
}

/// `fit --fibres`: course and wale directions found from the rest yarns
/// (the analytic swatch's courses run along x), stiffnesses fitted with
/// Eq. 7's, kept in the output (and refitted, directions unchanged, when
/// that output is fitted again without the flag); the before figure is the
/// earlier material's, the same as a fit without fibres reports.
#[test]
fn fit_with_fibres_finds_course_and_wale_and_keeps_them() {
    let c = case();
    let out = c.dir.join("fibres.vtkhdf");
    let o = knitvox(&fit_args(&c, &out, &["--joint", "--fibres", "--json"]));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    let r: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    let an = r["fibre_anisotropy"].as_f64().unwrap();
    assert!(an > 0.3, "chord anisotropy {an}");
    let a = io::vtkhdf::read_asset(&out).unwrap();
    let f = a.fibres.as_ref().expect("fibres in the output");
    let along = |d: &[Vec3], k: usize| {
        d.iter().filter(|v| v[k].abs() > 0.9).count() as f64 / d.len() as f64
    };
    let (cx, wy) = (along(&f.course, 0), along(&f.wale, 1));
    eprintln!(
        "fibres: anisotropy {an:.3}, course along x {cx:.3}, wale along y {wy:.3}; uniform {:?}",
        a.fit_record().unwrap().unwrap().uniform
    );
    assert!(cx > 0.8 && wy > 0.8, "course {cx}, wale {wy}");
    assert!(f
        .gamma_course
        .iter()
        .chain(&f.gamma_wale)
        .all(|g| g.is_finite() && *g > 0.0));
    let rec = a.fit_record().unwrap().unwrap();
    assert!(rec.uniform.gamma_course.is_some() && rec.uniform.gamma_wale.is_some());
    let (before, uniform, fitted) = (
        r["loss_before"].as_f64().unwrap(),
        r["loss_uniform"].as_f64().unwrap(),
        r["loss_fitted"].as_f64().unwrap(),
    );
    assert!(
        fitted <= uniform && uniform < before,
        "{before:e} {uniform:e} {fitted:e}"
    );
    // The earlier material is the placeholder, fibres or not: a fit without
    // them reports the same loss before.
    let plain = c.dir.join("plain.vtkhdf");
    let o = knitvox(&fit_args(&c, &plain, &["--joint", "--json"]));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rp: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    let bp = rp["loss_before"].as_f64().unwrap();
    assert!((bp - before).abs() <= 1e-9 * before, "{bp:e} vs {before:e}");
    assert!(io::vtkhdf::read_asset(&plain).unwrap().fibres.is_none());
    // Refitting the fibred asset keeps its directions.
    let again = c.dir.join("again.vtkhdf");
    let mut args = vec!["fit", s(&out), "--train"];
    args.extend(c.poses.iter().map(|p| s(p)));
    args.extend([
        "--samples",
        "1",
        "--harmonic",
        "1",
        "--gn-iterations",
        "2",
        "--joint",
        "-o",
        s(&again),
    ]);
    let o = knitvox(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let b = io::vtkhdf::read_asset(&again).unwrap();
    let fb = b.fibres.as_ref().expect("kept");
    assert_eq!(fb.course, f.course);
    assert_eq!(fb.wale, f.wale);
}

#[test]
fn fit_errors_name_the_file_and_exit_with_the_documented_codes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (asset_path, asset) = asset_in(d);
    let (gs, gv) = truth(&asset);
    let pose = d.join("stretch.h5");
    write_pose(&asset, &gs, &gv, [0.3, 0.0, 0.0], &pose);
    let out = d.join("out.vtkhdf");

    let fit_one = |o: &Path, extra: &[&str]| {
        let mut args = vec!["fit", s(&asset_path), "--train", s(&pose), "-o", s(o)];
        args.extend_from_slice(extra);
        knitvox(&args)
    };
    // -o equal to the input: usage, exit 2, nothing written.
    let o = fit_one(&asset_path, &[]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );

    // A contrast bound below 1: usage, exit 2, naming the option's value.
    let o = fit_one(&out, &["--max-contrast", "0.5"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("0.5") && err.contains("contrast"), "{err}");
    assert!(!out.exists());

    // A stall fraction outside [0, 1) and a CG cap of 0: usage, exit 2,
    // naming the option and the value.
    for (flag, value) in [
        ("--stall-decrease", "1"),
        ("--stall-decrease", "-0.1"),
        ("--cg-iterations", "0"),
    ] {
        let o = fit_one(&out, &[&format!("{flag}={value}")]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(flag) && err.contains(value), "{err}");
        assert!(!out.exists());
    }

    // The run failed with `code`, its stderr holds every one of `words`, and
    // nothing was written.
    let failed = |o: Output, code: i32, words: &[&str]| {
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{err}");
        assert!(
            words.iter().all(|w| err.contains(w)),
            "{words:?} not all in {err}"
        );
        assert!(!out.exists());
    };

    // A missing pose file: exit 66, named.
    let missing = d.join("nope.h5");
    let o = knitvox(&["fit", s(&asset_path), "--train", s(&missing), "-o", s(&out)]);
    failed(o, 66, &["nope.h5"]);

    // A pose of another swatch: bad input (65), naming the pose.
    let other = d.join("other.h5");
    let y = swatch(3, 5);
    let mut frames = knitvox::geom::YarnFrames::new(y.num_points());
    frames.push_frame(0.0, &y.points).unwrap();
    io::h5::write_file(&other, &y, Some(&frames)).unwrap();
    let o = knitvox(&[
        "fit",
        s(&asset_path),
        "--train",
        s(&pose),
        s(&other),
        "-o",
        s(&out),
    ]);
    failed(o, 65, &["other.h5", "topology"]);

    // An asset whose material lies below the fit's floor (a tet with γv = 0):
    // bad input (65) naming the asset, the dataset and the tet; it was an
    // internal error (70) blamed on nothing.
    let soft = d.join("soft.vtkhdf");
    let mut a = asset.clone();
    a.gamma_v[3] = 0.0;
    io::vtkhdf::write_asset(&soft, &a).unwrap();
    let o = knitvox(&["fit", s(&soft), "--train", s(&pose), "-o", s(&out)]);
    failed(
        o,
        65,
        &["soft.vtkhdf", "CellData/gamma_v of tet 3 is 0e0 Pa"],
    );

    // A pose file without mechanics is fitted under the assumed clamps with
    // warnings saying so.
    let bare = d.join("bare.h5");
    let data = io::read_path(&pose, &ReadOptions::default()).unwrap();
    io::h5::write_file(&bare, &data.yarns, data.frames.as_ref()).unwrap();
    let o = knitvox(&[
        "fit",
        s(&asset_path),
        "--train",
        s(&bare),
        "--samples",
        "1",
        "--harmonic",
        "0",
        "--gd-iterations",
        "1",
        "--gn-iterations",
        "2",
        "-o",
        s(&out),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("warning") && err.contains("reaction_forces"),
        "{err}"
    );
    assert!(out.exists());
}

/// RMS distance (yarn diameters) between two vertex sets of `y`'s topology.
fn rms_diameters(y: &knitvox::geom::Yarns, a: &[Vec3], b: &[Vec3]) -> f64 {
    let s: f64 = (0..a.len())
        .map(|v| (knitvox::geom::dist(a[v], b[v]) / (2.0 * y.radius_at(v))).powi(2))
        .sum();
    (s / a.len() as f64).sqrt()
}

const STRETCH_SCENE: &str = r#"name = "validate-stretch"
duration = 0.1
frame_rate = 50
gravity = [0.0, 0.0, 0.0]
[pose]
kind = "stretch_courses"
amount = 0.05
ramp = 0.08
"#;

#[test]
fn validate_runs_both_levels_and_reports_the_distance() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // A swatch relaxed into contact (with its rod rest shape), so that the
    // yarn-level run starts at rest.
    let asset_path = common::embedded_pattern(d, "a", "stockinette", 4, 4);
    let asset = io::vtkhdf::read_asset(&asset_path).unwrap();
    let scene = d.join("stretch.toml");
    std::fs::write(&scene, STRETCH_SCENE).unwrap();
    let report = d.join("val");

    // No fit record: --uniform cannot be honoured (bad input, 65).
    let o = knitvox(&[
        "validate",
        s(&asset_path),
        "--scene",
        s(&scene),
        "--uniform",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    assert!(err.contains("a.vtkhdf") && err.contains("fit"), "{err}");

    let o = knitvox(&[
        "validate",
        s(&asset_path),
        "--scene",
        s(&scene),
        "--report",
        s(&report),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("no fit record"), "{err}");
    // The summary as JSON, then the verdict in words.
    let stdout = String::from_utf8_lossy(&o.stdout);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 3, "{stdout}");
    let line: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
    assert!(
        lines[1].starts_with("motion: centre of mass travels ") && lines[1].contains("homogenized"),
        "{stdout}"
    );
    assert!(
        lines[2].starts_with("verdict: the asset's material moves ")
            && lines[2].contains("no uniform material to compare with"),
        "{stdout}"
    );
    assert_eq!(line["verdict"], lines[2], "{line}");
    eprintln!("{line}");
    for key in [
        "frames",
        "rms_yarn_diameters",
        "max_yarn_diameters",
        "uniform_rms_yarn_diameters",
        "yarn_level_s",
        "homogenized_s",
        "speedup",
    ] {
        assert!(line.get(key).is_some(), "{key} missing from {line}");
    }
    assert_eq!(line["frames"], 5);
    assert!(line["uniform_rms_yarn_diameters"].is_null());
    // The explicit yarn model keeps no clamp forces: said, not compared.
    assert!(line["clamp_force_n"].is_null(), "{line}");
    assert!(err.contains("records no clamp forces"), "{err}");
    let (rms, max) = (
        line["rms_yarn_diameters"].as_f64().unwrap(),
        line["max_yarn_diameters"].as_f64().unwrap(),
    );
    assert!(rms.is_finite() && rms > 0.0 && max >= rms, "{line}");
    assert!(line["speedup"].as_f64().unwrap() > 0.0);

    // The report: per-frame JSON and curve, both sequences as PLY.
    let full: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report.join("validate.json")).unwrap()).unwrap();
    let last = full["per_frame"]
        .as_array()
        .unwrap()
        .last()
        .unwrap()
        .clone();
    assert_eq!(last["frame"], 5);
    let png = std::fs::read(report.join("error.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let read = |p: PathBuf| io::read_path(&p, &ReadOptions::default()).unwrap().yarns;
    let yl = read(report.join("yarn_level.0005.ply"));
    let hm = read(report.join("homogenized.0005.ply"));
    assert!(report.join("homogenized.0000.ply").exists());
    let rest = &asset.rest_yarns;
    let tracked = rms_diameters(rest, &hm.points, &yl.points);
    assert!((tracked - last["rms"].as_f64().unwrap()).abs() < 1e-3 * tracked + 1e-6);
    // Both levels are driven by the same pose: the clamped yarn vertices
    // (V2Y of the driven tet nodes, exact for the bands' rigid maps) agree
    // with the yarn-level ones, which moved by about a yarn diameter.
    let text = format!("{STRETCH_SCENE}[swatch]\npattern = \"stockinette\"\n");
    let sc = knitvox::pipeline::yls_scene::YlsScene::parse(&text, &scene).unwrap();
    let driver = knitvox::yarn::poses::PoseDriver::new(&rest.points, sc.pose_params()).unwrap();
    let diam = |v: usize, a: &[Vec3], b: &[Vec3]| {
        knitvox::geom::dist(a[v], b[v]) / (2.0 * rest.radius_at(v))
    };
    let held = driver.pinned();
    let moved = held
        .iter()
        .map(|&v| diam(v, &rest.points, &yl.points))
        .fold(0.0, f64::max);
    let apart = held
        .iter()
        .map(|&v| diam(v, &hm.points, &yl.points))
        .fold(0.0, f64::max);
    eprintln!("last frame: {tracked:.3} yarn diameters RMS; clamped vertices moved up to {moved:.3}, differ by up to {apart:.2e}");
    assert!(moved > 0.5, "the pose hardly moved the bands: {moved}");
    assert!(
        apart < 0.02,
        "clamped vertices differ by {apart} yarn diameters"
    );

    // The report keeps the yarn-level frames; `--truth` reuses them: the
    // same errors, the recorded yarn-level time, no second yarn-level run.
    let truth = report.join("yarn_level.h5");
    // `validate --truth --json` with `extra` options: the report and stderr.
    let on_truth = |extra: &[&str]| -> (serde_json::Value, String) {
        let mut args = vec![
            "validate",
            s(&asset_path),
            "--scene",
            s(&scene),
            "--truth",
            s(&truth),
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = knitvox(&args);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        (serde_json::from_slice(&o.stdout).unwrap(), err)
    };
    let (again, _) = on_truth(&[]);
    for key in [
        "rms_yarn_diameters",
        "max_yarn_diameters",
        "y2v_floor_rms_yarn_diameters",
        "yarn_level_s",
    ] {
        assert_eq!(again[key], full[key], "{key}");
    }
    assert!(again["truth_file"]
        .as_str()
        .unwrap()
        .ends_with("yarn_level.h5"));
    // One PD iteration per step stops every step at the cap: counted,
    // with the residual it left, and warned about.
    let (one, err) = on_truth(&["--pd-iterations", "1"]);
    assert_eq!(one["pd_iteration_cap"], 1, "{one}");
    assert_eq!(one["pd_capped_steps"], one["solver_steps"], "{one}");
    let (tol, conv) = (
        one["pd_tolerance"].as_f64().unwrap(),
        one["pd_convergence_max"].as_f64().unwrap(),
    );
    assert!(tol > 0.0 && conv > tol, "{one}");
    let residual = one["pd_max_residual_n"].as_f64().unwrap();
    assert!(residual.is_finite() && residual > 0.0, "{one}");
    assert!(
        err.contains("at the 1-iteration cap") && err.contains("raise --pd-iterations"),
        "{err}"
    );
    assert!(
        again["pd_max_residual_n"].as_f64().unwrap() < residual,
        "{again}"
    );
    // Another scene (a larger stretch) is refused, naming what differs.
    let other = d.join("other.toml");
    std::fs::write(&other, STRETCH_SCENE.replace("0.05", "0.06")).unwrap();
    let o = knitvox(&[
        "validate",
        s(&asset_path),
        "--scene",
        s(&other),
        "--truth",
        s(&truth),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    assert!(err.contains("--truth") && err.contains("pose"), "{err}");

    // A yls run is a dynamic training pose: `fit` loads its frames with the
    // Eq. 13 inertia forces (the fitted frame and the two before it), or
    // takes them as equilibria with --quasi-static.
    let fit_once = |extra: &[&str]| -> serde_json::Value {
        let out = d.join(format!("dyn{}.vtkhdf", extra.len()));
        let mut args = vec![
            "fit",
            s(&asset_path),
            "--train",
            s(&truth),
            "--samples",
            "1",
            "--harmonic",
            "1",
            "--gd-iterations",
            "1",
            "--gn-iterations",
            "2",
            "-o",
            s(&out),
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        // Progress events, one per line, then the report.
        let text = String::from_utf8_lossy(&o.stdout);
        serde_json::from_str(text.lines().last().unwrap()).unwrap()
    };
    let dynamic = fit_once(&[]);
    let equilibria = fit_once(&["--quasi-static"]);
    assert_eq!(dynamic["poses"][0]["dynamic"], true, "{dynamic}");
    assert_eq!(equilibria["poses"][0]["dynamic"], false);
    let before = |r: &serde_json::Value| r["loss_before"].as_f64().unwrap();
    assert!(
        before(&dynamic) != before(&equilibria),
        "the inertia forces changed nothing: {}",
        before(&dynamic)
    );

    // Scenes with colliders: tests/validate_gravity.rs.
}

const SWING_SCENE: &str = r#"name = "damping-swing"
duration = 0.1
frame_rate = 30
model = "rods"
[pose]
kind = "cantilever"
"#;

#[test]
fn fit_damping_keeps_the_closest_damping_records_it_and_validate_runs_with_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let asset_path = common::embedded_pattern(d, "a", "stockinette", 4, 4);
    let scene = d.join("swing.toml");
    std::fs::write(&scene, SWING_SCENE).unwrap();
    let out = d.join("damped.vtkhdf");
    let rep = d.join("rep");

    // The output may not be an input; the damping is searched, not given.
    let o = knitvox(&[
        "fit-damping",
        s(&asset_path),
        "--scene",
        s(&scene),
        "-o",
        s(&asset_path),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let o = knitvox(&[
        "fit-damping",
        s(&asset_path),
        "--scene",
        s(&scene),
        "-o",
        s(&out),
        "--stiffness-damping",
        "1e-4",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--stiffness-damping"), "{err}");
    assert!(!out.exists());

    let o = knitvox(&[
        "fit-damping",
        s(&asset_path),
        "--scene",
        s(&scene),
        "-o",
        s(&out),
        "--report",
        s(&rep),
        "--json",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let fit = &r["damping_fit"];
    let beta = fit["stiffness_damping_s"].as_f64().unwrap();
    let best = fit["rms_yarn_diameters"].as_f64().unwrap();
    let undamped = fit["undamped_rms_yarn_diameters"].as_f64().unwrap();
    let evals = fit["evaluations"].as_array().unwrap();
    eprintln!(
        "damping {beta:e} s: RMS {best} (undamped {undamped}) over {} runs",
        evals.len()
    );
    // No damping first, then 14 golden-section points in [1e-6, 1e-1] s.
    assert_eq!(evals.len(), 15, "{fit}");
    assert_eq!(evals[0][0].as_f64(), Some(0.0));
    assert_eq!(evals[0][1].as_f64(), Some(undamped));
    for e in evals.iter().skip(1) {
        let b = e[0].as_f64().unwrap();
        assert!((1e-6..=1e-1).contains(&b), "{e}");
    }
    // The damping kept is the closest one tried, and the report is its run.
    let least = evals
        .iter()
        .map(|e| e[1].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    assert_eq!(best, least, "{fit}");
    assert!(evals
        .iter()
        .any(|e| e[0].as_f64() == Some(beta) && e[1].as_f64() == Some(best)));
    assert_eq!(r["pd_stiffness_damping_s"].as_f64(), Some(beta), "{r}");
    assert_eq!(r["rms_yarn_diameters"].as_f64(), Some(best), "{r}");
    // The homogenized runs step as the yarn level does (1/600 s).
    assert_eq!(r["pd_max_dt_s"].as_f64(), Some(1.0 / 600.0), "{r}");

    // The written asset records it, and the scene among its inputs.
    let damped = io::vtkhdf::read_asset(&out).unwrap();
    let record = damped.damping_record().unwrap().expect("a damping record");
    assert_eq!(record.stiffness_damping_s, beta);
    assert_eq!(record.undamped_rms_yarn_diameters, undamped);
    assert_eq!(record.evaluations.len(), 15);
    assert_eq!(record.dt_s, Some(1.0 / 600.0));
    assert!(record.corotated && record.superseded().is_none());
    assert!(damped
        .provenance
        .inputs
        .iter()
        .any(|i| i.path.ends_with("swing.toml") && i.sha256.len() == 64));

    // validate runs the damped asset with its damping (the same RMS as the
    // search's run), and --stiffness-damping 0 gives the undamped one.
    let truth = rep.join("yarn_level.h5");
    let validate = |asset: &Path, extra: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "validate",
            s(asset),
            "--scene",
            s(&scene),
            "--truth",
            s(&truth),
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let v = validate(&out, &[]);
    assert_eq!(v["pd_stiffness_damping_s"].as_f64(), Some(beta), "{v}");
    assert_eq!(v["rms_yarn_diameters"].as_f64(), Some(best), "{v}");
    let v = validate(&out, &["--stiffness-damping", "0"]);
    assert_eq!(v["rms_yarn_diameters"].as_f64(), Some(undamped), "{v}");
    let v = validate(&out, &["--dt", "1/150"]);
    assert_eq!(v["pd_max_dt_s"].as_f64(), Some(1.0 / 150.0), "{v}");
    assert_ne!(v["rms_yarn_diameters"].as_f64(), Some(best), "{v}");

    // A shot stepping 4x longer than a damping was fitted at is warned
    // about; one at the fitted step is not.
    let mut fitted = damped.clone();
    fitted.parameters["damping"]["stiffness_damping_s"] = serde_json::json!(1e-4);
    let fitted_path = d.join("fitted.vtkhdf");
    io::vtkhdf::write_asset(&fitted_path, &fitted).unwrap();
    let shot = |dt: &str| -> serde_json::Value {
        let sc = d.join(format!("shot{}.toml", dt.replace('/', "_")));
        std::fs::write(&sc, format!("[simulation]\nfps = 30\ndt = \"{dt}\"\n")).unwrap();
        let o = knitvox(&[
            "simulate",
            s(&fitted_path),
            "--scene",
            s(&sc),
            "--frames",
            "1-1",
            "--backend",
            "cpu",
            "-o",
            s(&d.join(format!("shot{}.vtkhdf", dt.replace('/', "_")))),
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text = String::from_utf8_lossy(&o.stdout);
        serde_json::from_str(text.lines().last().unwrap()).unwrap()
    };
    let warned = |r: &serde_json::Value| {
        r["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("was fitted with PD steps of"))
    };
    let r = shot("1/150");
    assert!(warned(&r), "{r}");
    let r = shot("1/600");
    assert!(!warned(&r), "{r}");
    let superseded = |r: &serde_json::Value| {
        r["warnings"].as_array().unwrap().iter().any(|w| {
            w.as_str()
                .unwrap()
                .contains("linear stiffness damping of an earlier")
        })
    };
    assert!(!superseded(&r), "{r}");
    // A record from before the co-rotated damping (no `corotated`) is
    // warned about: its β was fitted for a damping that braked rotation.
    fitted.parameters["damping"]
        .as_object_mut()
        .unwrap()
        .remove("corotated");
    io::vtkhdf::write_asset(&fitted_path, &fitted).unwrap();
    let r = shot("1/600");
    assert!(superseded(&r), "{r}");

    // A record with a negative damping is the asset's fault (65).
    let mut bad = damped.clone();
    bad.parameters["damping"]["stiffness_damping_s"] = serde_json::json!(-1.0);
    let bad_path = d.join("bad.vtkhdf");
    io::vtkhdf::write_asset(&bad_path, &bad).unwrap();
    let o = knitvox(&[
        "validate",
        s(&bad_path),
        "--scene",
        s(&scene),
        "--truth",
        s(&truth),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    assert!(
        err.contains("bad.vtkhdf") && err.contains("stiffness_damping_s"),
        "{err}"
    );
}
