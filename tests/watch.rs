//! `knitvox watch ROOT`: the watch-folder daemon (schemas/watch.md), run as
//! real processes on temporary folders.

mod common;

use common::daemon::{done_jobs, names, swatch_bytes, Daemon};

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use knitvox::io;
use serde_json::Value;

/// Fast timings for tests: scans every 0.5 s, heartbeats every 0.5 s.
const FAST: [&str; 4] = ["--poll", "0.5", "--heartbeat", "0.5"];

/// A daemon with [`FAST`] timings and `extra` options.
fn start(root: &Path, extra: &[&str]) -> Daemon {
    let args: Vec<&str> = FAST.iter().chain(extra).copied().collect();
    Daemon::spawn(root, &args)
}

fn per_job(events: &[Value]) -> BTreeMap<String, usize> {
    let mut m = BTreeMap::new();
    for e in events {
        *m.entry(e["job"].as_str().unwrap().to_string()).or_default() += 1;
    }
    m
}

/// Moves a prepared file or folder into the inbox in one rename.
fn drop_in(staging: &Path, root: &Path, name: &str) {
    std::fs::rename(staging.join(name), root.join("inbox").join(name)).unwrap();
}

#[test]
fn twenty_drops_at_once_are_each_done_once() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let staging = dir.path().join("staging");
    std::fs::create_dir_all(&staging).unwrap();
    let mut d = start(&root, &["--workers", "2"]);
    assert!(d.wait_for(Duration::from_secs(20), |d| !d.events("started").is_empty()));
    // 17 swatches, one of them again under another name, a corrupt file.
    let mut valid = Vec::new();
    for i in 0..17 {
        let name = format!("s{i:02}.bcc");
        std::fs::write(staging.join(&name), swatch_bytes(2 + i % 3, "bcc")).unwrap();
        valid.push(name);
    }
    std::fs::copy(staging.join("s00.bcc"), staging.join("again.bcc")).unwrap();
    valid.push("again.bcc".into());
    std::fs::write(
        staging.join("corrupt.bcc"),
        b"BCC\x01not a yarn file at all",
    )
    .unwrap();
    // The 20th grows for 5 s, as a slow copy would write it.
    let full = swatch_bytes(4, "bcc");
    let inbox = root.join("inbox");
    let growing = inbox.join("growing.bcc");
    let writer = {
        let (full, growing) = (full.clone(), growing.clone());
        std::thread::spawn(move || {
            let mut f = std::fs::File::create(&growing).unwrap();
            let chunks = 50;
            let step = full.len().div_ceil(chunks);
            for c in full.chunks(step) {
                f.write_all(c).unwrap();
                f.flush().unwrap();
                std::thread::sleep(Duration::from_millis(100));
            }
        })
    };
    for n in valid.iter().chain(["corrupt.bcc".to_string()].iter()) {
        drop_in(&staging, &root, n);
    }
    valid.push("growing.bcc".into());
    writer.join().unwrap();
    let finished = |d: &Daemon| d.events("done").len() + d.events("failed").len() >= 20;
    assert!(
        d.wait_for(Duration::from_secs(240), finished),
        "not all 20 drops finished:\n{}",
        d.dump()
    );
    // Nothing more happens after that (no second run of anything).
    std::thread::sleep(Duration::from_secs(2));
    let done = per_job(&d.events("done"));
    let failed = per_job(&d.events("failed"));
    let started = per_job(&d.events("job_started"));
    for n in &valid {
        let job = n.trim_end_matches(".bcc");
        assert_eq!(done.get(job), Some(&1), "{job} done once\n{}", d.dump());
        assert_eq!(started.get(job), Some(&1), "{job} run once");
        assert!(!failed.contains_key(job), "{job} failed\n{}", d.dump());
        let out = root.join("out").join(job);
        assert!(out.join("garment.vtkhdf").is_file(), "{job}");
        assert!(out.join(".knitvox/embed.json").is_file(), "{job}");
        assert!(root.join("done").join(n).is_file(), "{n} in done/");
    }
    assert_eq!(done.len(), 19);
    assert_eq!(std::fs::read(root.join("done/growing.bcc")).unwrap(), full);
    // The corrupt file: failed/, with its error file.
    assert_eq!(failed.get("corrupt"), Some(&1), "{}", d.dump());
    assert!(root.join("failed/corrupt.bcc").is_file());
    let err: Value =
        serde_json::from_slice(&std::fs::read(root.join("failed/corrupt.error.json")).unwrap())
            .unwrap();
    assert_eq!(err["class"], "bad_input", "{err}");
    assert_eq!(err["exit_code"], 65, "{err}");
    assert_eq!(err["file"], "corrupt.bcc", "{err}");
    assert!(
        err["message"].as_str().unwrap().contains("corrupt.bcc"),
        "{err}"
    );
    assert!(names(&inbox).is_empty(), "{:?}", names(&inbox));
    assert!(names(&root.join("work")).is_empty());
    // Alive, and a SIGTERM stops it cleanly.
    assert!(d.child.try_wait().unwrap().is_none(), "the daemon died");
    d.signal(libc::SIGTERM);
    assert_eq!(d.wait_exit(Duration::from_secs(20)), Some(0));
    assert_eq!(d.events("stopping").len(), 1);
    assert_eq!(d.events("stopped")[0]["done"], 19);
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

/// A job folder `NAME/`: swatch, scene, manifest (embed, shot, export).
fn shot_folder(parent: &Path, name: &str, frames: &str) {
    let d = parent.join(name);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("swatch.bcc"), swatch_bytes(6, "bcc")).unwrap();
    std::fs::write(d.join("sphere.toml"), SPHERE).unwrap();
    let job = format!(
        "frames = \"{frames}\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"sphere.toml\"\nbackend = \"cpu\"\n[export]\nformat = \"ply\"\n"
    );
    std::fs::write(d.join("job.toml"), job).unwrap();
}

use common::files_under as tree;

fn run_once(root: &Path) -> Daemon {
    let mut d = start(root, &["--once"]);
    assert_eq!(
        d.wait_exit(Duration::from_secs(300)),
        Some(0),
        "--once did not exit 0:\n{}",
        d.dump()
    );
    d
}

#[test]
fn kill_9_mid_shot_then_restart_completes_once_bit_for_bit() {
    const FRAMES: &str = "1-24";
    let dir = tempfile::tempdir().unwrap();
    let staging = dir.path().join("staging");
    // A clean run, for reference.
    let clean = dir.path().join("clean");
    std::fs::create_dir_all(clean.join("inbox")).unwrap();
    shot_folder(&clean.join("inbox"), "shot", FRAMES);
    let d = run_once(&clean);
    assert_eq!(
        per_job(&d.events("done")).get("shot"),
        Some(&1),
        "{}",
        d.dump()
    );
    let reference = tree(&clean.join("out/shot"));
    assert!(reference.contains_key(Path::new("shot.vtkhdf")));
    assert!(reference.contains_key(Path::new("export/garment.0011.ply")));

    // The same job, its daemon killed once the shot stage has begun.
    let root = dir.path().join("root");
    shot_folder(&staging, "shot", FRAMES);
    let d = start(&root, &[]);
    assert!(d.wait_for(Duration::from_secs(20), |d| !d.events("started").is_empty()));
    drop_in(&staging, &root, "shot");
    let out = root.join("out/shot");
    assert!(
        d.wait_for(Duration::from_secs(120), |_| out
            .join(".knitvox/embed.json")
            .is_file()),
        "{}",
        d.dump()
    );
    d.signal(libc::SIGKILL);
    let started = d.events("job_started");
    let child = started[0]["pid"].as_u64().unwrap();
    assert!(
        !out.join(".knitvox/shot.json").exists(),
        "the shot finished before the kill: make it longer"
    );
    // The child dies with the daemon (PR_SET_PDEATHSIG): nobody writes on.
    let proc_dir = PathBuf::from(format!("/proc/{child}"));
    let gone = d.wait_for(Duration::from_secs(10), |_| {
        std::fs::read_to_string(proc_dir.join("stat"))
            .map_or(true, |s| s.split_whitespace().nth(2) == Some("Z"))
    });
    assert!(gone, "child {child} outlived the daemon");
    // No partial file under a final name: whatever is there is complete.
    for (p, bytes) in tree(&out) {
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with('.') {
            continue; // temporaries are dot-prefixed
        }
        if p.extension().is_some_and(|e| e == "lock") {
            continue; // the killed run's stage lock, taken over on restart
        }
        if p.starts_with("checkpoints") {
            // The child got SIGTERM with its daemon (PR_SET_PDEATHSIG) while
            // the shot ran: a complete checkpoint to resume from.
            io::checkpoint::read(&out.join(&p), 1 << 30).unwrap();
            continue;
        }
        let r = reference
            .get(&p)
            .unwrap_or_else(|| panic!("{} is not an output", p.display()));
        assert!(
            &bytes == r, // HDF5 assets too: written without object times
            "{} differs after kill -9",
            p.display()
        );
    }
    // The kill may land after the embed's record and before its unlock;
    // make that case certain: the finished stage's lock, held by a dead
    // process of this host, must be swept by the restart.
    let embed_lock = out.join(".knitvox/embed.lock");
    if !embed_lock.exists() {
        let mut gone = Command::new("true").spawn().unwrap();
        let pid = gone.id();
        gone.wait().unwrap();
        let holder = io::lock::Holder {
            host: io::lock::host_name(),
            pid,
        };
        std::fs::write(&embed_lock, serde_json::to_string(&holder).unwrap()).unwrap();
    }
    // --status shows the orphaned claim.
    let st = Command::new(common::knitvox_bin())
        .args(["watch", "--status", "--json"])
        .arg(&root)
        .output()
        .unwrap();
    assert!(st.status.success());
    let st: Value = serde_json::from_slice(&st.stdout).unwrap();
    assert_eq!(st["work"][0]["job"], "shot", "{st}");
    assert_eq!(st["work"][0]["pid"], u64::from(d.child.id()), "{st}");
    drop(d);

    // A restart takes the job over and completes it once.
    let d = run_once(&root);
    assert_eq!(
        per_job(&d.events("takeover")).get("shot"),
        Some(&1),
        "{}",
        d.dump()
    );
    assert_eq!(
        per_job(&d.events("done")).get("shot"),
        Some(&1),
        "{}",
        d.dump()
    );
    // The embed stage that finished before the kill is not run again.
    let embed: Vec<Value> = d
        .events("stage")
        .into_iter()
        .filter(|s| s["name"] == "embed")
        .collect();
    assert_eq!(embed.len(), 1);
    assert_eq!(embed[0]["status"], "cached", "{}", d.dump());
    let after = tree(&out);
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        reference.keys().collect::<Vec<_>>()
    );
    for (p, bytes) in &reference {
        assert!(
            &after[p] == bytes,
            "{} differs from a clean run",
            p.display()
        );
    }
    assert_eq!(done_jobs(&root.join("done")), ["shot"]);
    assert!(names(&root.join("work")).is_empty());
}

#[test]
fn once_processes_the_inbox_and_exits_and_status_prints_the_queue() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let inbox = root.join("inbox");
    std::fs::create_dir_all(&inbox).unwrap();
    // A bare yarn file, a yarn file with a sidecar asking for tiny voxels
    // under a cap (so its embed fails: the sidecar was applied), a manifest with an
    // unknown key, a lone sidecar (waits for its yarn file), a hidden file.
    std::fs::write(inbox.join("plain.bcc"), swatch_bytes(2, "bcc")).unwrap();
    std::fs::write(inbox.join("capped.bcc"), swatch_bytes(2, "bcc")).unwrap();
    std::fs::write(
        inbox.join("capped.job.toml"),
        "[embed]\nvoxel_size = 0.00001\nmax_voxels = 1000\n",
    )
    .unwrap();
    std::fs::write(
        inbox.join("bad.toml"),
        "[garment]\nyarns = \"/nowhere.bcc\"\nspeed = 3\n",
    )
    .unwrap();
    std::fs::write(inbox.join("later.job.toml"), "[embed]\ndensity = 1300\n").unwrap();
    std::fs::write(inbox.join(".hidden.bcc"), b"partial").unwrap();
    let status = |json: bool| {
        let mut c = Command::new(common::knitvox_bin());
        c.args(["watch", "--status"]).arg(&root);
        if json {
            c.arg("--json");
        }
        let o = c.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let st: Value = serde_json::from_str(&status(true)).unwrap();
    let queue: Vec<(String, String)> = st["inbox"]
        .as_array()
        .unwrap()
        .iter()
        .map(|q| {
            let kind = q["kind"]
                .as_object()
                .unwrap()
                .keys()
                .next()
                .unwrap()
                .clone();
            (q["job"].as_str().unwrap().to_string(), kind)
        })
        .collect();
    let want = [
        ("bad", "manifest"),
        ("capped", "yarns"),
        ("later", "sidecar"),
        ("plain", "yarns"),
    ];
    let want: Vec<(String, String)> = want
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    assert_eq!(queue, want, "{st}");
    assert_eq!(
        st["inbox"][1]["kind"]["yarns"]["sidecar"],
        "capped.job.toml"
    );

    let d = run_once(&root);
    assert_eq!(
        per_job(&d.events("done")),
        BTreeMap::from([("plain".to_string(), 1)])
    );
    assert_eq!(
        per_job(&d.events("failed")),
        BTreeMap::from([("bad".to_string(), 1), ("capped".to_string(), 1)]),
        "{}",
        d.dump()
    );
    let err = |n: &str| -> Value {
        serde_json::from_slice(&std::fs::read(root.join("failed").join(n)).unwrap()).unwrap()
    };
    let bad = err("bad.error.json");
    assert_eq!(bad["class"], "bad_input", "{bad}");
    assert_eq!(bad["file"], "bad.toml", "{bad}");
    assert!(bad["message"].as_str().unwrap().contains("speed"), "{bad}");
    assert_eq!(bad["place"], "line 3, column 1", "{bad}");
    let capped = err("capped.error.json");
    assert!(
        capped["message"].as_str().unwrap().contains("voxels"),
        "{capped}"
    );
    assert_eq!(
        names(&root.join("failed")),
        [
            "bad.error.json",
            "bad.toml",
            "capped.bcc",
            "capped.error.json",
            "capped.job.toml"
        ]
    );
    assert_eq!(names(&root.join("done")), ["plain.bcc"]);
    // Failed jobs leave no empty output folder.
    assert_eq!(names(&root.join("out")), ["plain"]);
    assert!(root.join("out/plain/garment.vtkhdf").is_file());
    // Its default job also exports the embedded rest shape: the same yarns.
    let rest = io::read_path(
        &root.join("out/plain/export/garment.0000.ply"),
        &io::ReadOptions::default(),
    )
    .unwrap();
    let dropped = root.join("done/plain.bcc");
    let input = io::read_path(&dropped, &io::ReadOptions::default()).unwrap();
    assert_eq!(rest.yarns.num_points(), input.yarns.num_points());
    // What stays: the lone sidecar and the hidden file.
    assert_eq!(names(&inbox), [".hidden.bcc", "later.job.toml"]);
    let text = status(false);
    assert!(text.contains("inbox: 1 (1 stable)"), "{text}");
    assert!(text.contains("later") && text.contains("sidecar"), "{text}");
    assert!(text.contains("done: 1  failed: 2"), "{text}");
}

#[test]
fn sigterm_stops_a_running_job_and_the_next_start_takes_it_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let (root, staging) = (dir.path().join("root"), dir.path().join("staging"));
    shot_folder(&staging, "shot", "1-24");
    // No grace: the running child gets SIGTERM at once.
    let mut d = start(&root, &["--grace", "0", "--stale-after", "3600"]);
    assert!(d.wait_for(Duration::from_secs(20), |d| !d.events("started").is_empty()));
    drop_in(&staging, &root, "shot");
    let out = root.join("out/shot");
    assert!(
        d.wait_for(Duration::from_secs(120), |_| out
            .join(".knitvox/embed.json")
            .is_file()),
        "{}",
        d.dump()
    );
    d.signal(libc::SIGTERM);
    assert_eq!(
        d.wait_exit(Duration::from_secs(30)),
        Some(0),
        "{}",
        d.dump()
    );
    assert!(
        !out.join(".knitvox/shot.json").exists(),
        "the shot finished before SIGTERM: make it longer"
    );
    assert_eq!(
        per_job(&d.events("interrupted")).get("shot"),
        Some(&1),
        "{}",
        d.dump()
    );
    assert!(d.events("done").is_empty() && d.events("failed").is_empty());
    // The claim is released: the next daemon takes it without waiting for
    // the hour-long stale time.
    let st = Command::new(common::knitvox_bin())
        .args(["watch", "--status", "--json"])
        .arg(&root)
        .output()
        .unwrap();
    let st: Value = serde_json::from_slice(&st.stdout).unwrap();
    assert_eq!(st["work"][0]["state"], "released", "{st}");
    let mut d = start(&root, &["--once", "--stale-after", "3600"]);
    assert_eq!(
        d.wait_exit(Duration::from_secs(300)),
        Some(0),
        "{}",
        d.dump()
    );
    let takeover = d.events("takeover");
    assert_eq!(takeover.len(), 1, "{}", d.dump());
    assert_eq!(takeover[0]["released"], true);
    assert_eq!(
        per_job(&d.events("done")).get("shot"),
        Some(&1),
        "{}",
        d.dump()
    );
    assert!(out.join("shot.vtkhdf").is_file());
    assert_eq!(done_jobs(&root.join("done")), ["shot"]);
}

#[test]
fn two_daemons_share_one_folder_and_run_each_drop_once() {
    let dir = tempfile::tempdir().unwrap();
    let (root, staging) = (dir.path().join("root"), dir.path().join("staging"));
    std::fs::create_dir_all(&staging).unwrap();
    let a = start(&root, &[]);
    let b = start(&root, &[]);
    let up = |d: &Daemon| !d.events("started").is_empty();
    assert!(a.wait_for(Duration::from_secs(20), up) && b.wait_for(Duration::from_secs(20), up));
    let jobs: Vec<String> = (0..8).map(|i| format!("j{i}")).collect();
    for (i, j) in jobs.iter().enumerate() {
        std::fs::write(
            staging.join(format!("{j}.bcc")),
            swatch_bytes(2 + i % 2, "bcc"),
        )
        .unwrap();
        drop_in(&staging, &root, &format!("{j}.bcc"));
    }
    let total = |a: &Daemon, b: &Daemon| a.events("done").len() + b.events("done").len();
    assert!(
        a.wait_for(Duration::from_secs(120), |a| total(a, &b) >= 8),
        "{}\n{}",
        a.dump(),
        b.dump()
    );
    std::thread::sleep(Duration::from_secs(2));
    let mut done = per_job(&a.events("done"));
    for (j, n) in per_job(&b.events("done")) {
        *done.entry(j).or_default() += n;
    }
    let want: BTreeMap<String, usize> = jobs.iter().map(|j| (j.clone(), 1)).collect();
    assert_eq!(done, want, "{}\n{}", a.dump(), b.dump());
    assert!(a.events("failed").is_empty() && b.events("failed").is_empty());
    assert!(a.events("takeover").is_empty() && b.events("takeover").is_empty());
    assert_eq!(names(&root.join("done")).len(), 8);
}
