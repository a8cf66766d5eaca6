//! Resuming a shot from an unusable checkpoint: `--resume` (and a job's
//! shot stage) refuses a truncated, foreign-version, non-JSON or altered
//! checkpoint with exit 65 naming the file, never a silent restart from
//! rest; `--resume-or-restart` warns (naming the file and why) and starts
//! the shot from rest.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use knitvox::embed::EmbedParams;
use knitvox::io::{self, checkpoint, vtkhdf, ReadOptions, WriteOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};
use sha2::{Digest, Sha256};

/// A small swatch falling onto a sphere.
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

fn shot(asset: &Path, scene: &Path, frames: &str, out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(common::knitvox_bin());
    c.env("RAYON_NUM_THREADS", "1")
        .arg("simulate")
        .arg(asset)
        .arg("--scene")
        .arg(scene)
        .args(["--frames", frames, "--checkpoint-every", "3", "-o"])
        .arg(out)
        .args(extra);
    c
}

fn run(mut c: Command) -> (i32, String, String) {
    let o = c.output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
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

/// Rewrites a checkpoint's header through `edit` and, with `rehash`,
/// recomputes its SHA-256 (a forger's copy; without, a damaged one).
fn edit_header(bytes: &[u8], rehash: bool, edit: impl Fn(&mut serde_json::Value)) -> Vec<u8> {
    let hlen = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let mut h: serde_json::Value = serde_json::from_slice(&bytes[24..24 + hlen]).unwrap();
    edit(&mut h);
    let h = serde_json::to_vec(&h).unwrap();
    let mut out = bytes[..16].to_vec();
    out.extend_from_slice(&(h.len() as u64).to_le_bytes());
    out.extend_from_slice(&h);
    out.extend_from_slice(&bytes[24 + hlen..bytes.len() - 32]);
    if rehash {
        let d = Sha256::digest(&out);
        out.extend_from_slice(&d);
    } else {
        out.extend_from_slice(&bytes[bytes.len() - 32..]);
    }
    out
}

/// Flips one bit of payload value `k` from the end (1: the last value of
/// the warm start) and, with `rehash`, recomputes the SHA-256.
fn edit_tail_value(bytes: &[u8], k: usize, rehash: bool) -> Vec<u8> {
    let mut out = bytes[..bytes.len() - 32].to_vec();
    let at = out.len() - 8 * k;
    out[at] ^= 1;
    if rehash {
        let d = Sha256::digest(&out);
        out.extend_from_slice(&d);
    } else {
        out.extend_from_slice(&bytes[bytes.len() - 32..]);
    }
    out
}

/// Node positions and times of the asset at `path`.
fn series(path: &Path) -> (Vec<[f64; 3]>, Vec<f64>) {
    let a = vtkhdf::read_asset(path).unwrap();
    (a.steps.positions, a.steps.times)
}

/// The damaged copies of checkpoint `good` (of a shot of `nodes` nodes):
/// name, bytes, and the name the file gets (`None`: its own).
fn damaged(good: &[u8]) -> Vec<(&'static str, Vec<u8>)> {
    let step = |d: i64| {
        move |h: &mut serde_json::Value| {
            h["step"] = (h["step"].as_u64().unwrap() as i64 + d).into();
        }
    };
    // A valid prefix, then a header that is not JSON, hashed.
    let mut not_json = good[..16].to_vec();
    not_json.extend_from_slice(&(5u64).to_le_bytes());
    not_json.extend_from_slice(b"{oops");
    not_json.extend_from_slice(
        &good[24 + u64::from_le_bytes(good[16..24].try_into().unwrap()) as usize..good.len() - 32],
    );
    let d = Sha256::digest(&not_json);
    not_json.extend_from_slice(&d);
    vec![
        ("truncated", good[..good.len() / 2].to_vec()),
        ("truncated by its hash", good[..good.len() - 1].to_vec()),
        ("foreign version", {
            let mut b = good.to_vec();
            b[12] = 9;
            b
        }),
        ("not a checkpoint", b"{\"step\": 1}\n".to_vec()),
        ("a header that is not JSON", not_json),
        ("step altered", edit_header(good, false, step(-1))),
        (
            "step altered and rehashed",
            edit_header(good, true, step(1)),
        ),
        (
            "step altered by a frame and rehashed",
            edit_header(good, true, step(7)),
        ),
        ("warm start altered", edit_tail_value(good, 1, false)),
        ("velocity altered", edit_tail_value(good, 3000, false)),
        (
            "another shot's key, rehashed",
            edit_header(good, true, |h| {
                h["key"] = "0".repeat(64).into();
            }),
        ),
        (
            "time altered and rehashed",
            edit_header(good, true, |h| {
                h["time"] = (h["time"].as_f64().unwrap() * 0.5).into();
            }),
        ),
    ]
}

#[test]
fn resume_refuses_an_unusable_checkpoint_and_resume_or_restart_starts_from_rest() {
    let dir = tempfile::tempdir().unwrap();
    let (asset, scene) = fixture(dir.path());
    // The clean result: frames 1-6 in one run from rest.
    let clean = dir.path().join("clean.vtkhdf");
    let (c, _, e) = run(shot(&asset, &scene, "1-6", &clean, &[]));
    assert_eq!(c, 0, "{e}");
    // Frames 1-3 leave the checkpoint that `--resume` of 1-6 continues.
    let work = dir.path().join("w");
    std::fs::create_dir_all(&work).unwrap();
    let out = work.join("s.vtkhdf");
    let (c, _, e) = run(shot(&asset, &scene, "1-3", &out, &[]));
    assert_eq!(c, 0, "{e}");
    let ck = checkpoints(&work);
    assert_eq!(ck.len(), 1, "{ck:?}");
    let path = ck[0].clone();
    let good = std::fs::read(&path).unwrap();
    assert_eq!(checkpoint::read_header(&path).unwrap().step, 14);
    let reset = |bytes: &[u8]| {
        for p in checkpoints(&work) {
            std::fs::remove_file(p).unwrap();
        }
        let _ = std::fs::remove_file(&out);
        std::fs::write(&path, bytes).unwrap();
    };
    // The intact checkpoint is continued, to the clean result.
    reset(&good);
    let (c, o, e) = run(shot(&asset, &scene, "1-6", &out, &["--resume", "--json"]));
    assert_eq!(c, 0, "{e}");
    let r: serde_json::Value = serde_json::from_str(o.lines().last().unwrap()).unwrap();
    assert_eq!(r["resumed_from"].as_str(), path.to_str(), "{r}");
    assert!(series(&out) == series(&clean), "the resumed run differs");

    let name = path.file_name().unwrap().to_str().unwrap();
    for (what, bytes) in damaged(&good) {
        reset(&bytes);
        let (c, o, e) = run(shot(&asset, &scene, "1-6", &out, &["--resume", "--json"]));
        assert_eq!(c, 65, "{what}: {e}");
        let r: serde_json::Value = serde_json::from_str(o.lines().last().unwrap()).unwrap();
        assert_eq!(r["file"].as_str(), path.to_str(), "{what}: {r}");
        assert!(
            e.contains(name) && e.contains("--resume-or-restart"),
            "{what}: {e}"
        );
        assert!(!out.exists(), "{what}");
        // Skipped with a warning naming it; the shot starts from rest.
        reset(&bytes);
        let (c, o, e) = run(shot(
            &asset,
            &scene,
            "1-6",
            &out,
            &["--resume-or-restart", "--json"],
        ));
        assert_eq!(c, 0, "{what}: {e}");
        let r: serde_json::Value = serde_json::from_str(o.lines().last().unwrap()).unwrap();
        assert!(r["resumed_from"].is_null(), "{what}: {r}");
        let warnings = r["warnings"].as_array().unwrap();
        assert!(
            warnings.iter().any(|w| w.as_str().unwrap().contains(name)),
            "{what}: {r}"
        );
        assert!(e.contains("warning: ") && e.contains(name), "{what}: {e}");
        assert!(
            series(&out) == series(&clean),
            "{what}: the restarted run differs"
        );
    }

    // A checkpoint renamed to another step is refused too.
    reset(&good);
    let renamed = work.join(name.replace(".0000000014.", ".0000000015."));
    std::fs::rename(&path, &renamed).unwrap();
    let (c, _, e) = run(shot(&asset, &scene, "1-6", &out, &["--resume"]));
    assert_eq!(c, 65, "{e}");
    assert!(e.contains("its name says"), "{e}");
}

/// A job whose shot checkpoints every frame, long enough to be stopped.
const JOB: &str = r#"
frames = "1-400"
[garment]
yarns = "swatch.bcc"
[shot]
scene = "scene.toml"
backend = "cpu"
checkpoint_every = 1
"#;

#[test]
fn a_job_shot_stage_refuses_a_damaged_checkpoint_unless_told_to_restart() {
    let dir = tempfile::tempdir().unwrap();
    common::job::write_garment(&dir.path().join("swatch.bcc"), 3);
    std::fs::write(dir.path().join("scene.toml"), common::job::SCENE).unwrap();
    let job = dir.path().join("job.toml");
    std::fs::write(&job, JOB).unwrap();
    let ckdir = dir.path().join("job.out/checkpoints");
    let knitvox = |extra: &[&str]| {
        let mut c = Command::new(common::knitvox_bin());
        c.env("RAYON_NUM_THREADS", "1")
            .arg("run")
            .arg(&job)
            .args(extra);
        c
    };
    // Stopped by SIGTERM once the shot has checkpointed: exit 75, one
    // checkpoint left to resume.
    let mut child = knitvox(&[])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while !ckdir.is_dir() || checkpoints(&ckdir).is_empty() {
        assert!(child.try_wait().unwrap().is_none(), "the job ended first");
        assert!(t0.elapsed().as_secs() < 300, "no checkpoint");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: signalling our own child process.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let o = child.wait_with_output().unwrap();
    assert_eq!(
        o.status.code(),
        Some(75),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let ck = checkpoints(&ckdir);
    assert_eq!(ck.len(), 1, "{ck:?}");
    let good = std::fs::read(&ck[0]).unwrap();
    let name = ck[0].file_name().unwrap().to_str().unwrap().to_string();
    for (what, bytes) in [
        ("truncated", good[..good.len() - 100].to_vec()),
        (
            "step altered",
            edit_header(&good, true, |h| {
                h["step"] = (h["step"].as_u64().unwrap() + 1).into();
            }),
        ),
    ] {
        std::fs::write(&ck[0], &bytes).unwrap();
        let (c, _, e) = run(knitvox(&[]));
        assert_eq!(c, 65, "{what}: {e}");
        assert!(
            e.contains(&name) && e.contains("--resume-or-restart"),
            "{what}: {e}"
        );
    }
    let (c, o, e) = run(knitvox(&["--resume-or-restart", "--json"]));
    assert_eq!(c, 0, "{e}");
    let r: serde_json::Value = serde_json::from_str(o.lines().last().unwrap()).unwrap();
    let warnings = r["warnings"].as_array().unwrap();
    assert!(
        warnings.iter().any(|w| w.as_str().unwrap().contains(&name)),
        "{r}"
    );
    assert!(e.contains("warning: ") && e.contains(&name), "{e}");
}
