//! Resumable, chunkable shots with the real
//! binary: chunks equal one run bit for bit, a chunk without its
//! checkpoint is refused, SIGTERM and kill -9 resume to the clean result,
//! `--json` progress lines and JSON errors.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use knitvox::embed::EmbedParams;
use knitvox::io::{self, checkpoint, vtkhdf, ReadOptions, WriteOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};

/// A small swatch falling onto a sphere (contacts from the second frame on).
const SCENE: &str = r#"
[simulation]
dt = "1/150"
fps = 24
[garment]
rotate_deg = [-90, 0, 0]
center = [0.0, 0.012, 0.0]
[[collider]]
type = "sphere"
center = [0.0, 0.0, 0.0]
radius = 0.01
thickness = 0.001
"#;

/// A 3 x 3 loop swatch asset (3 mm voxels) and the scene, in `dir`.
fn fixture(dir: &Path) -> (PathBuf, PathBuf) {
    let yarns = knit_swatch(&SwatchParams {
        courses: 3,
        wales: 3,
        with_ring: false,
        points_per_loop: 8,
        ..SwatchParams::default()
    });
    let bcc = dir.join("swatch.bcc");
    io::write_path(&bcc, &yarns, None, &WriteOptions::default()).unwrap();
    let read = ReadOptions {
        radius: yarns.radius[0],
        ..ReadOptions::default()
    };
    let params = EmbedParams {
        voxel_size: Some(3e-3),
        ..EmbedParams::default()
    };
    let (asset, _) = build_asset(&bcc, &read, &params, "test").unwrap();
    let path = dir.join("swatch.vtkhdf");
    vtkhdf::write_asset(&path, &asset).unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    (path, scene)
}

/// `knitvox simulate ASSET --scene SCENE --frames FRAMES -o OUT
/// --yarns-out DIR/y.####.ply EXTRA..` on one thread (bitwise comparisons).
fn shot(asset: &Path, scene: &Path, frames: &str, out: &Path, extra: &[&str]) -> Command {
    let yarns = out.parent().unwrap().join("y.####.ply");
    let mut c = Command::new(common::knitvox_bin());
    c.env("RAYON_NUM_THREADS", "1")
        .arg("simulate")
        .arg(asset)
        .arg("--scene")
        .arg(scene)
        .args(["--frames", frames, "-o"])
        .arg(out)
        .arg("--yarns-out")
        .arg(yarns)
        .args(extra);
    c
}

fn output(mut c: Command) -> (i32, String, String) {
    let o: Output = c.output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn ok(c: Command) -> String {
    let (code, out, err) = output(c);
    assert_eq!(code, 0, "{err}");
    out
}

/// The yarn frame files `y.FFFF.ply` of `dir` for `frames`, as bytes.
fn yarn_files(dir: &Path, frames: std::ops::RangeInclusive<i64>) -> Vec<Vec<u8>> {
    frames
        .map(|f| {
            let p = dir.join(format!("y.{f:04}.ply"));
            std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        })
        .collect()
}

/// Asserts the yarn frame files of `frames` are the same bytes in both folders.
fn assert_same_frames(a: &Path, b: &Path, frames: std::ops::RangeInclusive<i64>) {
    for f in frames {
        let (x, y) = (yarn_files(a, f..=f), yarn_files(b, f..=f));
        assert!(
            x == y,
            "frame {f} differs between {} and {}",
            a.display(),
            b.display()
        );
    }
}

/// Node positions and times of the time series of the assets `outs`, one
/// after the other.
fn series(outs: &[PathBuf]) -> (Vec<[f64; 3]>, Vec<f64>) {
    let (mut x, mut t) = (Vec::new(), Vec::new());
    for o in outs {
        let a = vtkhdf::read_asset(o).unwrap();
        x.extend_from_slice(&a.steps.positions);
        t.extend_from_slice(&a.steps.times);
    }
    (x, t)
}

fn checkpoints(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ckpt"))
        .collect();
    v.sort();
    v
}

/// Runs frames 1-`last` in one piece in `dir/clean` and returns the folder.
fn clean_run(dir: &Path, asset: &Path, scene: &Path, last: i64) -> PathBuf {
    let clean = dir.join("clean");
    std::fs::create_dir_all(&clean).unwrap();
    ok(shot(
        asset,
        scene,
        &format!("1-{last}"),
        &clean.join("all.vtkhdf"),
        &[],
    ));
    clean
}

/// Waits (at most two minutes) until `ready()`; panics when `child` ends first.
fn wait_for(child: &mut Child, what: &str, ready: impl Fn() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        if let Some(s) = child.try_wait().unwrap() {
            panic!("the shot ended ({s}) before {what}");
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn three_chunks_equal_one_run_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    let clean = clean_run(dir.path(), &asset, &scene, 9);
    let chunks = dir.path().join("chunks");
    std::fs::create_dir_all(&chunks).unwrap();
    let outs: Vec<PathBuf> = (1..=3)
        .map(|k| chunks.join(format!("c{k}.vtkhdf")))
        .collect();
    ok(shot(&asset, &scene, "1-3", &outs[0], &[]));
    // The second chunk finds the first's checkpoint by itself; the third
    // names the shot start.
    let r: serde_json::Value = serde_json::from_str(
        ok(shot(&asset, &scene, "4-6", &outs[1], &["--json"]))
            .lines()
            .last()
            .unwrap(),
    )
    .unwrap();
    assert_eq!(r["shot_start"], 1, "{r}");
    assert!(
        r["resumed_from"].as_str().unwrap().ends_with(".ckpt"),
        "{r}"
    );
    ok(shot(
        &asset,
        &scene,
        "7-9",
        &outs[2],
        &["--shot-start", "1"],
    ));

    assert_same_frames(&chunks, &clean, 1..=9);
    let (x, t) = series(&outs);
    let (x_clean, t_clean) = series(&[clean.join("all.vtkhdf")]);
    assert_eq!(t, t_clean);
    assert!(x == x_clean, "node positions differ");
    // Not trivially equal: the swatch moved between the frames.
    assert!(yarn_files(&clean, 1..=1) != yarn_files(&clean, 9..=9));
}

#[test]
fn a_chunk_without_its_checkpoint_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    let out = dir.path().join("c2.vtkhdf");
    let (code, _, err) = output(shot(&asset, &scene, "4-6", &out, &["--shot-start", "1"]));
    assert_eq!(code, 66, "{err}");
    assert!(
        err.contains("continue the shot that starts at frame 1") && err.contains("--checkpoint"),
        "{err}"
    );
    assert!(!out.exists());
    assert!(!dir.path().join("y.0004.ply").exists());

    // A checkpoint of another shot (other gravity) given explicitly: exit 2.
    let other = dir.path().join("other.toml");
    let text = SCENE.replace("fps = 24", "fps = 24\ngravity = [0.0, -5.0, 0.0]");
    std::fs::write(&other, text).unwrap();
    ok(shot(
        &asset,
        &other,
        "1-3",
        &dir.path().join("o.vtkhdf"),
        &[],
    ));
    let ck = checkpoints(dir.path());
    assert_eq!(ck.len(), 1, "{ck:?}");
    let (code, _, err) = output(shot(
        &asset,
        &scene,
        "4-6",
        &out,
        &["--checkpoint", ck[0].to_str().unwrap()],
    ));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("another shot"), "{err}");
    // A damaged checkpoint: bad input, naming the file.
    let mut bytes = std::fs::read(&ck[0]).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0xff;
    let bad = dir.path().join("bad.ckpt");
    std::fs::write(&bad, bytes).unwrap();
    let (code, _, err) = output(shot(
        &asset,
        &other,
        "4-6",
        &out,
        &["--checkpoint", bad.to_str().unwrap()],
    ));
    assert_eq!(code, 65, "{err}");
    assert!(err.contains("bad.ckpt") && err.contains("SHA-256"), "{err}");
    assert!(!out.exists());
}

/// SIGTERM checkpoints after the current step and exits 75; kill -9 leaves
/// only complete files under final names; `--resume` completes both to the
/// clean run's outputs.
#[test]
fn interrupted_shots_resume_to_the_clean_result() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    let last = 12;
    let clean = clean_run(dir.path(), &asset, &scene, last);
    let frames = format!("1-{last}");

    // SIGTERM once frame 2 is written (no periodic checkpoints).
    let term = dir.path().join("term");
    std::fs::create_dir_all(&term).unwrap();
    let out = term.join("all.vtkhdf");
    let args = ["--checkpoint-every", "100"];
    let mut child = shot(&asset, &scene, &frames, &out, &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for(&mut child, "frame 2", || term.join("y.0002.ply").exists());
    // SAFETY: signalling our own child process.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(75), "{err}");
    assert!(err.contains("--resume"), "{err}");
    assert_eq!(checkpoints(&term).len(), 1);
    assert!(!out.exists());
    ok(shot(
        &asset,
        &scene,
        &frames,
        &out,
        &[&args[..], &["--resume"]].concat(),
    ));
    assert_same_frames(&term, &clean, 1..=last);
    assert!(
        series(&[out]) == series(&[clean.join("all.vtkhdf")]),
        "node positions differ"
    );

    // kill -9 after the periodic checkpoint of frame 5 (every 2 frames:
    // frames 3, 5, ... from the shot start at frame 1).
    let killed = dir.path().join("killed");
    std::fs::create_dir_all(&killed).unwrap();
    let out = killed.join("all.vtkhdf");
    let args = ["--checkpoint-every", "2"];
    let mut child = shot(&asset, &scene, &frames, &out, &args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for(&mut child, "frame 6", || killed.join("y.0006.ply").exists());
    child.kill().unwrap();
    child.wait().unwrap();
    // Every file under a final name is complete.
    for e in std::fs::read_dir(&killed).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with('.') {
            continue;
        }
        if name.ends_with(".ckpt") {
            checkpoint::read(&p, 1 << 30).unwrap();
        } else {
            io::read_path(&p, &ReadOptions::default()).unwrap();
        }
    }
    assert!(!out.exists());
    // One periodic checkpoint at a time (two only when killed between
    // writing the next and removing the previous); names sort by step.
    let ck = checkpoints(&killed);
    assert!((1..=2).contains(&ck.len()), "{ck:?}");
    let latest = &ck[ck.len() - 1];
    assert!(checkpoint::read_header(latest).unwrap().step > 0);
    // Resumed from the latest periodic checkpoint, not from the start.
    let r: serde_json::Value = serde_json::from_str(
        ok(shot(
            &asset,
            &scene,
            &frames,
            &out,
            &[&args[..], &["--resume", "--json"]].concat(),
        ))
        .lines()
        .last()
        .unwrap(),
    )
    .unwrap();
    assert_eq!(r["resumed_from"].as_str(), latest.to_str(), "{r}");
    assert_same_frames(&killed, &clean, 1..=last);
    let (x, t) = series(std::slice::from_ref(&out));
    let (x_clean, t_clean) = series(&[clean.join("all.vtkhdf")]);
    assert_eq!(t, t_clean);
    let n = x.len() / t.len();
    for f in 0..t.len() {
        assert!(
            x[f * n..(f + 1) * n] == x_clean[f * n..(f + 1) * n],
            "frame {} differs ({r})",
            f + 1
        );
    }
    // Done: only the final checkpoint (for a next chunk) is left.
    let ck = checkpoints(&killed);
    assert_eq!(ck.len(), 1, "{ck:?}");
    assert_eq!(
        checkpoint::read_header(&ck[0])
            .unwrap()
            .series_frames
            .last(),
        Some(&last)
    );
    // Resuming a finished request rewrites the same outputs and keeps the
    // final checkpoint.
    ok(shot(
        &asset,
        &scene,
        &frames,
        &out,
        &[&args[..], &["--resume"]].concat(),
    ));
    assert_eq!(checkpoints(&killed), ck);
    assert_same_frames(&killed, &clean, 1..=last);
}

#[test]
fn json_progress_is_one_line_per_frame_and_the_report_last() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    let out = dir.path().join("o.vtkhdf");
    let stdout = ok(shot(&asset, &scene, "1-3", &out, &["--json"]));
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(lines.len(), 4, "{stdout}");
    for (k, v) in lines[..3].iter().enumerate() {
        assert_eq!(v["event"], "frame", "{v}");
        assert_eq!(v["frame"], k as i64 + 1, "{v}");
        assert!(v["ms"].as_f64().unwrap() >= 0.0, "{v}");
        // The first frame is the start: no step, no residual.
        assert_eq!(v["residual"].is_f64(), k > 0, "{v}");
        assert!(v["penetration_m"].as_f64().unwrap() >= 0.0, "{v}");
    }
    assert_eq!(lines[3]["event"], "report");
    assert_eq!(lines[3]["frames"], 3);
    // Without --json and without a terminal: a plain line per frame on stderr.
    let (code, _, err) = output(shot(&asset, &scene, "1-3", &out, &[]));
    assert_eq!(code, 0, "{err}");
    let frames: Vec<&str> = err.lines().filter(|l| l.contains(": frame ")).collect();
    assert_eq!(frames.len(), 3, "{err}");
    assert!(frames[2].contains("frame 3 (3/3)"), "{err}");
}

#[test]
fn errors_with_json_are_a_json_object_on_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.vtkhdf");
    let run = |args: &[&str]| {
        let mut c = Command::new(common::knitvox_bin());
        c.args(args);
        output(c)
    };
    let last_json = |out: &str| -> serde_json::Value {
        serde_json::from_str(out.lines().last().unwrap_or("")).unwrap()
    };
    let m = missing.to_str().unwrap();
    let (code, out, _) = run(&[
        "simulate",
        m,
        "--character",
        "c.glb",
        "--frames",
        "1-2",
        "-o",
        dir.path().join("o.vtkhdf").to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 66);
    let v = last_json(&out);
    assert_eq!(v["event"], "error", "{v}");
    assert_eq!(v["class"], "missing");
    assert_eq!(v["exit_code"], 66);
    assert_eq!(v["file"], m);
    assert!(v["message"].as_str().unwrap().contains("missing.vtkhdf"));
    // Every command, parse errors too.
    let bcc = dir.path().join("missing.bcc");
    let bcc = bcc.to_str().unwrap();
    let (code, out, _) = run(&["convert", bcc, "x.ply", "--json"]);
    assert_eq!(code, 66);
    assert_eq!(last_json(&out)["class"], "missing");
    let (code, out, _) = run(&["simulate", "--json", "--no-such-flag"]);
    assert_eq!(code, 2);
    let v = last_json(&out);
    assert_eq!(
        (v["class"].as_str(), v["exit_code"].as_i64()),
        (Some("usage"), Some(2))
    );
    // Without --json stdout stays empty.
    let (code, out, _) = run(&["convert", bcc, "x.ply"]);
    assert_eq!((code, out.as_str()), (66, ""));
}

/// One frame numbering: `export` of a shot's asset names its files by the
/// farm frame numbers `simulate --yarns-out` wrote (same bytes), `--frames`
/// selects by them, and `convert --first-frame` of the shot's HDF5 frames
/// gives the same files again.
#[test]
fn export_and_convert_number_frames_like_simulate() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    let shot_dir = dir.path().join("shot");
    std::fs::create_dir_all(&shot_dir).unwrap();
    let out = shot_dir.join("o.vtkhdf");
    ok(shot(&asset, &scene, "1003-1005", &out, &[]));
    let knitvox = |args: &[&str]| {
        let mut c = Command::new(common::knitvox_bin());
        c.args(args);
        output(c)
    };
    let exported = dir.path().join("exported");
    let (code, _, err) = knitvox(&[
        "export",
        out.to_str().unwrap(),
        "-o",
        exported.to_str().unwrap(),
        "--name",
        "y",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_same_frames(&exported, &shot_dir, 1003..=1005);
    assert!(!exported.join("y.0000.ply").exists());
    let one = dir.path().join("one");
    let (code, _, err) = knitvox(&[
        "export",
        out.to_str().unwrap(),
        "--frames",
        "1004",
        "-o",
        one.to_str().unwrap(),
        "--name",
        "y",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_same_frames(&one, &shot_dir, 1004..=1004);
    assert_eq!(std::fs::read_dir(&one).unwrap().count(), 1);
    let (code, _, err) = knitvox(&[
        "export",
        out.to_str().unwrap(),
        "--frames",
        "2",
        "-o",
        one.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("numbered 1003..1005"), "{err}");

    // The same shot's frames as one HDF5 file, converted to a sequence.
    let h5_dir = dir.path().join("h5");
    std::fs::create_dir_all(&h5_dir).unwrap();
    let h5 = h5_dir.join("y.h5");
    let (code, _, err) = knitvox(&[
        "simulate",
        asset.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "1003-1005",
        "-o",
        h5_dir.join("o.vtkhdf").to_str().unwrap(),
        "--yarns-out",
        h5.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let converted = dir.path().join("converted");
    std::fs::create_dir_all(&converted).unwrap();
    let (code, _, err) = knitvox(&[
        "convert",
        h5.to_str().unwrap(),
        converted.join("y.####.ply").to_str().unwrap(),
        "--first-frame",
        "1003",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_same_frames(&converted, &shot_dir, 1003..=1005);
}

/// With a walking character (pre-roll, body pins, a moving collider with
/// friction against its previous pose) two chunks equal one run bit for bit.
#[test]
fn character_shot_in_two_chunks_equals_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, _) = fixture(dir.path());
    let fox = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb");
    let character = |frames: &str, out: &Path, extra: &[&str]| {
        let mut c = Command::new(common::knitvox_bin());
        c.env("RAYON_NUM_THREADS", "1")
            .arg("simulate")
            .arg(&asset)
            .arg("--character")
            .arg(&fox)
            .args([
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
                frames,
                "-o",
            ])
            .arg(out)
            .arg("--yarns-out")
            .arg(out.parent().unwrap().join("y.####.ply"))
            .args(extra);
        c
    };
    let (one, two) = (dir.path().join("one"), dir.path().join("two"));
    for d in [&one, &two] {
        std::fs::create_dir_all(d).unwrap();
    }
    ok(character("10-13", &one.join("o.vtkhdf"), &[]));
    ok(character("10-11", &two.join("a.vtkhdf"), &[]));
    ok(character(
        "12-13",
        &two.join("b.vtkhdf"),
        &["--shot-start", "10"],
    ));
    assert_same_frames(&two, &one, 10..=13);
    let x = series(&[two.join("a.vtkhdf"), two.join("b.vtkhdf")]);
    assert!(
        x == series(&[one.join("o.vtkhdf")]),
        "node positions differ"
    );
}
