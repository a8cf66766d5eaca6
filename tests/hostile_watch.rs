//! `knitvox watch` on hostile or awkward drops: files named outside ROOT,
//! symlinks, filing collisions, same-stem drops, slow copies, warnings,
//! and what `--status` shows of a running job. Real processes on
//! temporary folders, mostly in `--once` mode.

mod common;

use common::daemon::{names, swatch_bytes, Daemon};

use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use knitvox::io;
use serde_json::Value;

/// A daemon with fast heartbeats, `--poll 0.2` unless `extra` sets it.
fn start(root: &Path, extra: &[&str]) -> Daemon {
    let mut args = vec!["--heartbeat", "0.5"];
    if !extra.contains(&"--poll") {
        args.extend(["--poll", "0.2"]);
    }
    args.extend(extra);
    Daemon::spawn(root, &args)
}

/// `--once` with a short settle; waits for it to exit 0.
fn once(root: &Path, extra: &[&str]) -> Daemon {
    let mut args = vec!["--once", "--settle", "0.2"];
    args.extend(extra);
    let mut d = start(root, &args);
    let code = d.wait_exit(Duration::from_secs(120));
    assert_eq!(code, Some(0), "--once did not exit 0:\n{}", d.dump());
    d
}

fn json_file(p: &Path) -> Value {
    let bytes = std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_slice(&bytes).unwrap()
}

fn status_json(root: &Path) -> Value {
    let o = Command::new(common::knitvox_bin())
        .args(["watch", "--status", "--json"])
        .arg(root)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn job_folder(parent: &Path, name: &str, manifest: &str) -> std::path::PathBuf {
    let d = parent.join(name);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("job.toml"), manifest).unwrap();
    d
}

#[test]
fn drops_naming_files_outside_root_are_refused_without_reading_them() {
    let dir = tempfile::tempdir().unwrap();
    let (root, outside) = (dir.path().join("root"), dir.path().join("outside"));
    let inbox = root.join("inbox");
    std::fs::create_dir_all(&inbox).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    let secret = outside.join("x.bcc");
    let bytes = swatch_bytes(2, "bcc");
    std::fs::write(&secret, &bytes).unwrap();
    // A relative path up and out of a job folder (work/NAME/input/up/ is
    // five levels below the temporary folder), a top-level manifest's
    // relative path (meaning the inbox) that leaves it, an absolute path,
    // a symlink inside a job folder, a bare symlink drop.
    job_folder(
        &inbox,
        "up",
        "[garment]\nyarns = \"../../../../../outside/x.bcc\"\n",
    );
    std::fs::write(
        inbox.join("rel.toml"),
        "[garment]\nyarns = \"../../outside/x.bcc\"\n",
    )
    .unwrap();
    let abs = format!("[garment]\nyarns = \"{}\"\n", secret.display());
    std::fs::write(inbox.join("abs.toml"), &abs).unwrap();
    let linked = job_folder(&inbox, "linked", "[garment]\nyarns = \"x.bcc\"\n");
    std::os::unix::fs::symlink(&secret, linked.join("x.bcc")).unwrap();
    std::os::unix::fs::symlink(&secret, inbox.join("bare.bcc")).unwrap();
    // A symlink that stays inside its folder is fine.
    let ok = job_folder(&inbox, "ok", "[garment]\nyarns = \"alias.bcc\"\n");
    std::fs::write(ok.join("swatch.bcc"), &bytes).unwrap();
    std::os::unix::fs::symlink("swatch.bcc", ok.join("alias.bcc")).unwrap();

    let d = once(&root, &[]);
    assert_eq!(d.jobs("done"), ["ok"], "{}", d.dump());
    assert_eq!(
        d.jobs("failed"),
        ["abs", "bare", "linked", "rel", "up"],
        "{}",
        d.dump()
    );
    let written = [
        ("up", "up/job.toml", "../../../../../outside/x.bcc"),
        ("rel", "rel.toml", "../../outside/x.bcc"),
        ("abs", "abs.toml", secret.to_str().unwrap()),
    ];
    for (job, file, path) in written {
        let e = json_file(&root.join("failed").join(format!("{job}.error.json")));
        assert_eq!(e["class"], "bad_input", "{e}");
        assert_eq!(e["file"], file, "{e}");
        let m = e["message"].as_str().unwrap();
        assert!(
            m.contains("garment.yarns") && m.contains(&format!("\"{path}\"")),
            "{m}"
        );
        assert!(m.contains("outside"), "{m}");
    }
    for (job, file) in [("linked", "linked/x.bcc"), ("bare", "bare.bcc")] {
        let e = json_file(&root.join("failed").join(format!("{job}.error.json")));
        assert_eq!(e["class"], "bad_input", "{e}");
        assert_eq!(e["file"], file, "{e}");
        assert!(e["message"].as_str().unwrap().contains("symlink"), "{e}");
    }
    // Nothing of the outside file reached out/; it is where it was.
    assert_eq!(names(&root.join("out")), ["ok"]);
    assert_eq!(std::fs::read(&secret).unwrap(), bytes);
    assert!(std::fs::symlink_metadata(root.join("failed/bare.bcc"))
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(names(&inbox).is_empty(), "{:?}", names(&inbox));
}

#[test]
fn a_name_taken_in_failed_gets_a_suffix_and_never_loops() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let inbox = root.join("inbox");
    std::fs::create_dir_all(&inbox).unwrap();
    std::fs::create_dir_all(root.join("failed")).unwrap();
    // An earlier failed file `coll`, and its error file.
    std::fs::write(root.join("failed/coll"), b"earlier").unwrap();
    std::fs::write(root.join("failed/coll.error.json"), b"{}").unwrap();
    // Now a folder drop `coll/` that fails too (its yarns are missing).
    job_folder(&inbox, "coll", "[garment]\nyarns = \"nothere.bcc\"\n");
    let start = Instant::now();
    let d = once(&root, &[]);
    assert!(start.elapsed() < Duration::from_secs(60));
    assert_eq!(d.jobs("failed"), ["coll"], "{}", d.dump());
    assert!(d.events("takeover").is_empty(), "{}", d.dump());
    assert!(d.events("parked").is_empty(), "{}", d.dump());
    assert_eq!(
        names(&root.join("failed")),
        ["coll", "coll.1", "coll.1.error.json", "coll.error.json"]
    );
    assert_eq!(std::fs::read(root.join("failed/coll")).unwrap(), b"earlier");
    assert_eq!(
        std::fs::read(root.join("failed/coll.error.json")).unwrap(),
        b"{}"
    );
    assert!(root.join("failed/coll.1/job.toml").is_file());
    let e = json_file(&root.join("failed/coll.1.error.json"));
    assert_eq!(e["job"], "coll", "{e}");
    assert!(names(&root.join("work")).is_empty());
}

#[test]
fn a_job_that_cannot_be_filed_is_parked_once_not_retaken() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let inbox = root.join("inbox");
    std::fs::create_dir_all(&inbox).unwrap();
    // A 250-byte name fits a folder but not `NAME.error.json`: filing the
    // failure fails, every time.
    let long = "l".repeat(250);
    job_folder(&inbox, &long, "[garment]\nyarns = \"nothere.bcc\"\n");
    let d = once(&root, &[]);
    assert_eq!(d.jobs("parked"), [long.clone()], "{}", d.dump());
    assert!(d.events("takeover").is_empty(), "{}", d.dump());
    assert_eq!(d.events("job_started").len(), 0, "{}", d.dump());
    assert!(root.join("work").join(&long).join("parked.json").is_file());
    let st = status_json(&root);
    assert_eq!(st["work"][0]["state"], "parked", "{st}");
    assert!(
        st["work"][0]["parked"]
            .as_str()
            .unwrap()
            .contains("cannot file"),
        "{st}"
    );
    // A second daemon leaves it parked.
    let d = once(&root, &[]);
    assert!(d.events("takeover").is_empty(), "{}", d.dump());
    assert!(d.events("parked").is_empty(), "{}", d.dump());
}

#[test]
fn same_stem_drops_run_as_distinct_jobs_and_a_redrop_is_cached() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let inbox = root.join("inbox");
    std::fs::create_dir_all(&inbox).unwrap();
    std::fs::write(inbox.join("dup.bcc"), swatch_bytes(2, "bcc")).unwrap();
    std::fs::write(inbox.join("dup.obj"), swatch_bytes(3, "obj")).unwrap();
    let st = status_json(&root);
    let queued: Vec<&str> = st["inbox"]
        .as_array()
        .unwrap()
        .iter()
        .map(|q| q["job"].as_str().unwrap())
        .collect();
    assert_eq!(queued, ["dup", "dup.obj"], "{st}");
    let d = once(&root, &[]);
    assert_eq!(d.jobs("done"), ["dup", "dup.obj"], "{}", d.dump());
    assert_eq!(names(&root.join("out")), ["dup", "dup.obj"]);
    assert_eq!(names(&root.join("done")), ["dup.bcc", "dup.obj"]);
    // Each output holds its own drop: 2 and 3 courses differ.
    let a = io::read_path(
        &root.join("out/dup/export/garment.0000.ply"),
        &io::ReadOptions::default(),
    )
    .unwrap();
    let b = io::read_path(
        &root.join("out/dup.obj/export/garment.0000.ply"),
        &io::ReadOptions::default(),
    )
    .unwrap();
    assert_ne!(a.yarns.num_points(), b.yarns.num_points());
    // The same content again: the same job, cached, filed beside the first.
    std::fs::copy(root.join("done/dup.bcc"), inbox.join("dup.bcc")).unwrap();
    let d = once(&root, &[]);
    assert_eq!(d.jobs("done"), ["dup"], "{}", d.dump());
    let stages = d.events("stage");
    assert!(
        !stages.is_empty() && stages.iter().all(|s| s["status"] == "cached"),
        "{}",
        d.dump()
    );
    assert_eq!(
        names(&root.join("done")),
        ["dup.1.bcc", "dup.bcc", "dup.obj"]
    );
}

/// Writes `bytes` into `path` through one open file in `chunks` pieces,
/// `gap` apart, as a slow copy does.
/// Returns when the last piece was written (Unix seconds).
fn slow_copy(
    path: &Path,
    bytes: &[u8],
    chunks: usize,
    gap: Duration,
) -> std::thread::JoinHandle<f64> {
    let (path, bytes) = (path.to_path_buf(), bytes.to_vec());
    let mut f = std::fs::File::create(&path).unwrap();
    let step = bytes.len().div_ceil(chunks);
    let mut parts = bytes.chunks(step);
    f.write_all(parts.next().unwrap()).unwrap();
    f.flush().unwrap();
    let rest: Vec<Vec<u8>> = parts.map(|c| c.to_vec()).collect();
    std::thread::spawn(move || {
        for c in rest {
            std::thread::sleep(gap);
            f.write_all(&c).unwrap();
            f.flush().unwrap();
        }
        drop(path);
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64()
    })
}

/// A 6-stitch PLY copied into the inbox as `NAME.ply` in `pieces` pieces
/// 1 s apart while a `--once` daemon scans every second with `settle`
/// (None: the default): the daemon, after it exited 0 with the drop done,
/// never failed, byte for byte the copy; when the last piece was written
/// (Unix seconds); and the folder that holds its root.
fn copied_in_pieces(
    name: &str,
    pieces: usize,
    settle: Option<&str>,
) -> (Daemon, f64, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let full = swatch_bytes(6, "ply");
    let copy = slow_copy(
        &root.join(format!("inbox/{name}.ply")),
        &full,
        pieces,
        Duration::from_secs(1),
    );
    let mut args = vec!["--once", "--poll", "1"];
    if let Some(s) = settle {
        args.extend(["--settle", s]);
    }
    let mut d = start(&root, &args);
    assert_eq!(
        d.wait_exit(Duration::from_secs(120)),
        Some(0),
        "{}",
        d.dump()
    );
    let last_write = copy.join().unwrap();
    assert_eq!(d.jobs("done"), [name], "{}", d.dump());
    assert!(d.events("failed").is_empty(), "{}", d.dump());
    assert_eq!(
        std::fs::read(root.join(format!("done/{name}.ply"))).unwrap(),
        full
    );
    (d, last_write, dir)
}

/// The real case: a PLY written in 6 chunks 1 s apart into a folder
/// scanned every second, with the default settle time.
#[test]
fn a_ply_copied_in_six_chunks_a_second_apart_is_done_not_failed() {
    let (d, last_write, _dir) = copied_in_pieces("slow", 6, None);
    let claimed = d.events("claimed")[0]["t"].as_f64().unwrap();
    let done = d.events("done")[0]["t"].as_f64().unwrap();
    eprintln!(
        "slow copy: claimed {:.2} s and done {:.2} s after the last write",
        claimed - last_write,
        done - last_write
    );
    // Taken only once the copy was over.
    assert!(
        claimed > last_write,
        "claimed during the copy:\n{}",
        d.dump()
    );
}

/// The same copy with a settle time shorter than its pauses: the drop is
/// taken mid-copy, fails to parse, and is run again as the copy goes on,
/// until it is whole.
#[test]
fn a_ply_copied_in_six_chunks_past_a_short_settle_is_done_not_failed() {
    copied_in_pieces("slow", 6, Some("0.5"));
}

/// A long copy in many bursts (20 pieces a second apart, past a short
/// settle): run again as often as it fails while the copy goes on, not
/// filed as failed after a fixed number of runs.
#[test]
fn a_long_copy_in_many_bursts_is_retried_until_whole() {
    let (d, _, _dir) = copied_in_pieces("long", 20, Some("0.5"));
    let retries = d.events("not_ready").len();
    eprintln!("{retries} runs before the copy was whole");
    assert!(retries > 10, "{retries} runs:\n{}", d.dump());
}

/// A drop taken while its file still changes (here: an mtime in the
/// future, as a skewed NFS server gives) fails to parse, and is run again
/// once its file held still, not filed as failed.
#[test]
fn a_bad_input_failure_of_a_drop_still_changing_is_retried_not_filed() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let full = swatch_bytes(4, "ply");
    let path = root.join("inbox/late.ply");
    std::fs::write(&path, &full[..full.len() / 3]).unwrap();
    let future = std::time::SystemTime::now() + Duration::from_secs(3600);
    std::fs::File::options()
        .write(true)
        .open(&path)
        .unwrap()
        .set_modified(future)
        .unwrap();
    let mut d = start(&root, &["--once", "--settle", "0.3"]);
    assert!(
        d.wait_for(Duration::from_secs(60), |d| !d
            .events("not_ready")
            .is_empty()),
        "{}",
        d.dump()
    );
    // The copy completes (in the job's folder now, as an open file would).
    std::fs::write(root.join("work/late/input/late.ply"), &full).unwrap();
    assert_eq!(
        d.wait_exit(Duration::from_secs(60)),
        Some(0),
        "{}",
        d.dump()
    );
    assert_eq!(d.jobs("done"), ["late"], "{}", d.dump());
    assert!(d.events("failed").is_empty(), "{}", d.dump());
    assert_eq!(std::fs::read(root.join("done/late.ply")).unwrap(), full);
}

/// The same truncated file, settled and old, is a real failure.
#[test]
fn a_truncated_file_that_holds_still_is_filed_as_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let full = swatch_bytes(4, "ply");
    let path = root.join("inbox/cut.ply");
    std::fs::write(&path, &full[..full.len() / 3]).unwrap();
    let past = std::time::SystemTime::now() - Duration::from_secs(60);
    std::fs::File::options()
        .write(true)
        .open(&path)
        .unwrap()
        .set_modified(past)
        .unwrap();
    let d = once(&root, &[]);
    assert_eq!(d.jobs("failed"), ["cut"], "{}", d.dump());
    assert!(d.events("not_ready").is_empty(), "{}", d.dump());
    assert_eq!(
        json_file(&root.join("failed/cut.error.json"))["class"],
        "bad_input"
    );
}

/// A garment 30 m across from a unitless OBJ (the unit is assumed).
fn wide_obj() -> String {
    let mut text = String::new();
    for c in 0..4 {
        for i in 0..31 {
            text += &format!("v {i} {} 0\n", c as f64 * 0.5);
        }
        let ids: Vec<String> = (1..=31).map(|i| (c * 31 + i).to_string()).collect();
        text += &format!("l {}\n", ids.join(" "));
    }
    text
}

#[test]
fn a_jobs_warnings_are_kept_beside_its_drop_and_logged() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    std::fs::write(root.join("inbox/wide.obj"), wide_obj()).unwrap();
    let d = once(&root, &[]);
    assert_eq!(d.jobs("done"), ["wide"], "{}", d.dump());
    let logged: Vec<Value> = d
        .events("warning")
        .into_iter()
        .filter(|w| w["job"] == "wide")
        .collect();
    assert!(!logged.is_empty(), "{}", d.dump());
    assert!(
        logged[0]["message"]
            .as_str()
            .unwrap()
            .contains("implausible for clothing"),
        "{}",
        d.dump()
    );
    let w = json_file(&root.join("done/wide.warnings.json"));
    assert_eq!(w["job"], "wide");
    let first = w["warnings"][0].as_str().unwrap();
    assert!(
        first.contains("implausible for clothing") && first.contains("--units"),
        "{w}"
    );
    assert!(!first.contains("input/"), "{w}");
    assert_eq!(status_json(&root)["done"], 1);
}

/// A shot's stretch warning (its yarns stretched past the bounds, as a
/// swatch pulled apart fast does) is kept in the job's record beside the
/// filed drop, as every warning of the run is.
#[test]
fn a_shots_stretch_warning_is_kept_in_the_jobs_record() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let staging = dir.path().join("staging");
    let job = job_folder(
        &staging,
        "pulled",
        "frames = \"1-3\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"pull.toml\"\nbackend = \"cpu\"\n",
    );
    let bcc = job.join("swatch.bcc");
    std::fs::write(&bcc, swatch_bytes(3, "bcc")).unwrap();
    let b = io::read_path(&bcc, &Default::default())
        .unwrap()
        .yarns
        .bounds()
        .unwrap();
    let (lo, hi) = (b.min[0], b.max[0]);
    // One edge held, the other pulled half the width away over the shot.
    let scene = format!(
        "[simulation]\ngravity = [0.0, 0.0, 0.0]\n\
         [[pin]]\nname = \"left\"\nbox_min = [-1.0, -1.0, -1.0]\nbox_max = [{l}, 1.0, 1.0]\n\
         [[pin]]\nname = \"right\"\nbox_min = [{r}, -1.0, -1.0]\nbox_max = [1.0, 1.0, 1.0]\nvelocity = [{v}, 0.0, 0.0]\n",
        l = lo + 1e-4,
        r = hi - 1e-4,
        v = 0.5 * (hi - lo) * 12.0
    );
    std::fs::write(job.join("pull.toml"), scene).unwrap();
    std::fs::rename(&job, root.join("inbox/pulled")).unwrap();
    let d = once(&root, &[]);
    assert_eq!(d.jobs("done"), ["pulled"], "{}", d.dump());
    let w = json_file(&root.join("done/pulled.warnings.json"));
    let stretch: Vec<&str> = w["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|w| w.as_str())
        .filter(|w| w.contains("the yarns stretch"))
        .collect();
    assert_eq!(stretch.len(), 1, "{w}");
    assert!(
        stretch[0].contains("(frame 3)") && stretch[0].contains("knitvox fit"),
        "{w}"
    );
    assert!(
        d.events("warning").iter().any(|e| e["job"] == "pulled"
            && e["message"].as_str().unwrap().contains("the yarns stretch")),
        "{}",
        d.dump()
    );
}

/// A swatch dropped on a sphere (examples/drape-sphere.toml).
const SPHERE: &str = r#"
[simulation]
dt = "1/150"
fps = 24
gravity = [0.0, -9.81, 0.0]
damping = 2.0
max_iterations = 8
[garment]
rotate_deg = [-90.0, 0.0, 0.0]
center = [0.0, 0.03, 0.0]
[[collider]]
type = "sphere"
center = [0.0, 0.0, 0.0]
radius = 0.02
thickness = 0.001
"#;

#[test]
fn status_shows_the_running_stage_and_frame_and_children_share_the_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let staging = dir.path().join("staging");
    let shot = job_folder(
        &staging,
        "shot",
        "frames = \"1-24\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"sphere.toml\"\nbackend = \"cpu\"\n",
    );
    std::fs::write(shot.join("swatch.bcc"), swatch_bytes(6, "bcc")).unwrap();
    std::fs::write(shot.join("sphere.toml"), SPHERE).unwrap();
    std::fs::rename(&shot, root.join("inbox/shot")).unwrap();
    // 2 GiB for the daemon, two workers: 1 GiB each.
    let mut d = start(
        &root,
        &[
            "--once",
            "--settle",
            "0.2",
            "--workers",
            "2",
            "--max-memory",
            "2G",
        ],
    );
    assert!(
        d.wait_for(Duration::from_secs(60), |d| !d
            .events("job_started")
            .is_empty()),
        "{}",
        d.dump()
    );
    let pid = d.events("job_started")[0]["pid"].as_u64().unwrap();
    let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
    let args: Vec<String> = cmdline
        .split(|b| *b == 0)
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect();
    let at = args.iter().position(|a| a == "--max-memory");
    assert_eq!(
        at.map(|i| args[i + 1].as_str()),
        Some("1073741824"),
        "{args:?}"
    );
    assert_eq!(d.events("started")[0]["child_max_memory"], 1u64 << 30);
    let mut seen = None;
    let end = Instant::now() + Duration::from_secs(120);
    while Instant::now() < end && seen.is_none() && d.child.try_wait().unwrap().is_none() {
        let st = status_json(&root);
        let w = &st["work"][0];
        if w["stage"] == "shot" && w["frame"].is_i64() {
            seen = Some(w.clone());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let w = seen.unwrap_or_else(|| panic!("no stage and frame seen:\n{}", d.dump()));
    assert_eq!(w["job"], "shot");
    assert_eq!(w["state"], "running");
    assert_eq!(w["frames_total"], 24, "{w}");
    let (f, n) = (
        w["frame"].as_i64().unwrap(),
        w["frames_done"].as_u64().unwrap(),
    );
    assert!((1..=24).contains(&f) && (1..=24).contains(&n), "{w}");
    assert_eq!(
        d.wait_exit(Duration::from_secs(300)),
        Some(0),
        "{}",
        d.dump()
    );
    assert_eq!(d.jobs("done"), ["shot"], "{}", d.dump());
}
