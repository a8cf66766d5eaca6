//! `knitvox run JOB.toml --submit slurm` on a real single-node Slurm:
//! the stages as chained batch jobs, and the exit-code
//! classes on the farm (transient requeues, fix-needed holds, bad input
//! cancels the dependents).
//!
//! The cluster (slurmctld, slurmd, munged) is private to each test: its
//! config, keys, state and logs live in a temporary folder
//! (tests/support/slurm-cluster.sh). It needs root and Debian's slurm-wlm
//! and munge (`bash .ci/setup-debian test`): under CI their absence fails,
//! elsewhere the tests are skipped loudly.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::job::job_dir;

/// One cluster at a time: the tests share the host's node name.
static CLUSTER: Mutex<()> = Mutex::new(());

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/support/slurm-cluster.sh")
}

fn have_slurm() -> bool {
    let on_path = |p: &str| {
        Command::new("sh")
            .args(["-c", &format!("command -v {p}")])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    let root = unsafe { libc::geteuid() } == 0;
    common::require_tool(
        root && ["sbatch", "slurmctld", "slurmd", "munged", "scontrol"]
            .iter()
            .all(|p| on_path(p)),
        "a root shell with Debian's slurm-wlm and munge",
    )
}

/// A free TCP port on localhost.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A running private cluster; stopped on drop.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
}

impl Cluster {
    fn start() -> Cluster {
        let dir = tempfile::tempdir().unwrap();
        let out = Command::new("bash")
            .arg(script())
            .arg("start")
            .arg(dir.path())
            .arg(free_port().to_string())
            .arg(free_port().to_string())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "the test cluster did not start: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let conf = dir.path().join("slurm.conf");
        Cluster { dir, conf }
    }

    fn command(&self, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf)
            .env("RAYON_NUM_THREADS", "1");
        c
    }

    /// `scontrol show job -o ID` as key=value pairs.
    fn job(&self, id: &str) -> BTreeMap<String, String> {
        let out = self
            .command("scontrol")
            .args(["show", "job", "-o", id])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout)
            .split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    fn state(&self, id: &str) -> String {
        self.job(id).get("JobState").cloned().unwrap_or_default()
    }

    /// Waits until `done(job)` holds, for at most `secs` seconds.
    fn wait(
        &self,
        id: &str,
        secs: u64,
        what: &str,
        done: impl Fn(&BTreeMap<String, String>) -> bool,
    ) {
        let start = Instant::now();
        loop {
            let j = self.job(id);
            if done(&j) {
                return;
            }
            if start.elapsed() > Duration::from_secs(secs) {
                let logs = std::fs::read_to_string(self.dir.path().join("log/slurmctld.log"))
                    .unwrap_or_default();
                let tail: Vec<&str> = logs.lines().rev().take(15).collect();
                panic!("job {id}: {what} not reached in {secs} s: {j:?}\n{tail:?}");
            }
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    /// Makes a requeued (or released) job eligible now instead of after
    /// Slurm's requeue delay of about two minutes.
    fn hurry(&self, id: &str) {
        let s = self
            .command("scontrol")
            .args(["update", &format!("JobId={id}"), "StartTime=now"])
            .status()
            .unwrap();
        assert!(s.success());
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(script())
            .arg("stop")
            .arg(self.dir.path())
            .status();
    }
}

/// This test's private cluster, the tests taking turns; `None` (skipped
/// loudly, a failure under CI) where Slurm cannot run.
fn private_cluster() -> Option<(std::sync::MutexGuard<'static, ()>, Cluster)> {
    let one = CLUSTER.lock().unwrap_or_else(|e| e.into_inner());
    if !have_slurm() {
        return None;
    }
    Some((one, Cluster::start()))
}

/// Submits `job` and returns the job id of each stage, in order.
fn submit(cluster: &Cluster, job: &Path, extra: &[&str]) -> Vec<(String, String)> {
    let out = cluster
        .command(common::knitvox_bin())
        .arg("run")
        .arg(job)
        .args(["--submit", "slurm", "--json"])
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["stage"].as_str().unwrap().to_string(),
                s["job_id"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

/// Every file under `dir` (relative path -> bytes), skipping knitvox's own
/// records and farm logs.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.file_name().is_some_and(|n| n == ".knitvox") {
                continue;
            }
            if p.is_dir() {
                todo.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn a_job_runs_on_slurm_as_chained_stages_like_a_local_run() {
    let Some((_one, cluster)) = private_cluster() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let ids = submit(&cluster, &job, &[]);
    let names: Vec<&str> = ids.iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(names, ["embed", "shot", "export"]);
    // Each stage waits for the one before.
    let dep = cluster.job(&ids[1].1)["Dependency"].clone();
    assert!(
        dep.contains(&ids[0].1) || cluster.state(&ids[0].1) == "COMPLETED",
        "shot's dependency: {dep}"
    );
    for (stage, id) in &ids {
        cluster.wait(id, 300, &format!("{stage} COMPLETED"), |j| {
            let s = j.get("JobState").map(String::as_str).unwrap_or("");
            assert!(
                !matches!(s, "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL"),
                "{stage}: {j:?}"
            );
            s == "COMPLETED"
        });
    }
    // The farm's outputs equal a local run of the same job.
    let local = tempfile::tempdir().unwrap();
    let local_job = job_dir(local.path());
    let out = Command::new(common::knitvox_bin())
        .env("RAYON_NUM_THREADS", "1")
        .arg("run")
        .arg(&local_job)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let farm = tree(&dir.path().join("job.out"));
    let here = tree(&local.path().join("job.out"));
    assert_eq!(
        farm.keys().collect::<Vec<_>>(),
        here.keys().collect::<Vec<_>>()
    );
    for (k, v) in &farm {
        if k.extension().is_some_and(|e| e == "vtkhdf") {
            continue; // assets record their command line and paths
        }
        assert!(v == &here[k], "{} differs from the local run", k.display());
    }
    // Every stage left its log, and the job is complete: a local rerun does nothing.
    let logs = dir.path().join("job.out/.knitvox/submit/slurm");
    for (stage, id) in &ids {
        let log = logs.join(format!("{stage}-{id}.log"));
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        assert!(text.contains("\"status\""), "{}: {text}", log.display());
    }
    let again = Command::new(common::knitvox_bin())
        .arg("run")
        .arg(&job)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&again.stdout).contains("nothing to do"));
}

#[test]
fn a_job_with_quotes_and_substitutions_in_its_names_runs_on_slurm() {
    let Some((_one, cluster)) = private_cluster() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // The folder, the manifest and the output folder hold what a shell or
    // sbatch would read as code, a comment or the end of a value.
    let folder = dir
        .path()
        .join("a b 'c' \"d\" #e $(touch PWNED) `touch PWNED` 50%j");
    std::fs::create_dir_all(&folder).unwrap();
    let job = job_dir(&folder);
    let hostile = folder.join("shot #1 $(touch PWNED).toml");
    let text = std::fs::read_to_string(&job).unwrap();
    std::fs::write(&hostile, format!("output = 'out \"q\" #x'\n{text}")).unwrap();
    let ids = submit(&cluster, &hostile, &[]);
    for (stage, id) in &ids {
        cluster.wait(id, 300, &format!("{stage} COMPLETED"), |j| {
            let s = j.get("JobState").map(String::as_str).unwrap_or("");
            assert!(
                !matches!(s, "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL"),
                "{stage}: {j:?}"
            );
            s == "COMPLETED"
        });
        // The log is where --output says, in the folder as named.
        let log = folder
            .join("out \"q\" #x/.knitvox/submit/slurm")
            .join(format!("{stage}-{id}.log"));
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        assert!(text.contains("\"status\""), "{}: {text}", log.display());
        // The job name is the plain one.
        let name = cluster.job(id).get("JobName").cloned().unwrap_or_default();
        assert_eq!(name, format!("shot__1___touch_PWNED_:{stage}"));
    }
    assert!(!folder.join("PWNED").exists() && !dir.path().join("PWNED").exists());
    assert!(!Path::new("PWNED").exists());
}

/// A stand-in for knitvox on the nodes: exits with the codes listed in
/// `STAGE.codes` (one per attempt), then runs the real binary.
fn fake_knitvox(dir: &Path) -> PathBuf {
    let path = dir.join("fake-knitvox.sh");
    std::fs::write(
        &path,
        format!(
            r#"#!/bin/bash
stage=$4
n=$(cat "{d}/$stage.count" 2>/dev/null || echo 0)
echo $((n + 1)) > "{d}/$stage.count"
codes=($(cat "{d}/$stage.codes" 2>/dev/null))
[ -n "${{codes[$n]:-}}" ] && exit "${{codes[$n]}}"
exec "{real}" "$@"
"#,
            d = dir.display(),
            real = common::knitvox_bin().display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

fn attempts(dir: &Path, stage: &str) -> u32 {
    std::fs::read_to_string(dir.join(format!("{stage}.count")))
        .map(|s| s.trim().parse().unwrap())
        .unwrap_or(0)
}

#[test]
fn transient_failures_requeue_and_fix_needed_failures_hold_the_chain() {
    let Some((_one, cluster)) = private_cluster() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let fake = fake_knitvox(dir.path());
    std::fs::write(dir.path().join("embed.codes"), "75 75").unwrap();
    std::fs::write(dir.path().join("shot.codes"), "66").unwrap();
    let fake_arg = format!("--knitvox={}", fake.display());
    let ids = submit(&cluster, &job, &[&fake_arg, "--max-retries", "2"]);
    let (embed, shot, export) = (&ids[0].1, &ids[1].1, &ids[2].1);
    // Exit 75 twice: two requeues, then the real run.
    for restarts in ["1", "2"] {
        cluster.wait(embed, 120, &format!("requeue {restarts}"), |j| {
            j.get("Restarts").map(String::as_str) == Some(restarts)
                && j.get("JobState").map(String::as_str) == Some("PENDING")
        });
        cluster.hurry(embed);
    }
    cluster.wait(embed, 180, "embed COMPLETED", |j| {
        j["JobState"] == "COMPLETED"
    });
    assert_eq!(attempts(dir.path(), "embed"), 3);
    // Exit 66 (missing input): held, and export waits behind it.
    cluster.wait(shot, 180, "shot held", |j| {
        j.get("Reason")
            .is_some_and(|r| r.to_ascii_lowercase().contains("held"))
    });
    assert_eq!(cluster.state(export), "PENDING");
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(
        attempts(dir.path(), "shot"),
        1,
        "a held job must not rerun by itself"
    );
    // "The fix": release it; the chain completes.
    let s = cluster
        .command("scontrol")
        .args(["release", shot])
        .status()
        .unwrap();
    assert!(s.success());
    cluster.hurry(shot);
    for id in [shot, export] {
        cluster.wait(id, 240, "COMPLETED", |j| j["JobState"] == "COMPLETED");
    }
    assert_eq!(attempts(dir.path(), "shot"), 2);
    assert!(dir.path().join("job.out/.knitvox/export.json").is_file());
}

#[test]
fn a_bad_input_fails_its_stage_and_cancels_the_rest() {
    let Some((_one, cluster)) = private_cluster() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    // A garment that is not a yarn file: exit 65, not retryable.
    std::fs::write(dir.path().join("swatch.bcc"), b"not a bcc file").unwrap();
    let ids = submit(&cluster, &job, &[]);
    cluster.wait(&ids[0].1, 120, "embed FAILED", |j| {
        j["JobState"] == "FAILED"
    });
    assert_eq!(cluster.job(&ids[0].1)["ExitCode"], "65:0");
    for (stage, id) in &ids[1..] {
        cluster.wait(id, 120, &format!("{stage} CANCELLED"), |j| {
            j["JobState"] == "CANCELLED"
        });
    }
    let log = dir.path().join(format!(
        "job.out/.knitvox/submit/slurm/embed-{}.log",
        ids[0].1
    ));
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.contains("not retryable"), "{text}");
}

#[test]
fn a_dry_run_writes_the_scripts_and_submits_nothing() {
    // No cluster: --dry-run must not call sbatch at all.
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let out = Command::new(common::knitvox_bin())
        .env("PATH", "/nonexistent")
        .arg("run")
        .arg(&job)
        .args([
            "--submit",
            "slurm",
            "--dry-run",
            "--sbatch-arg=--partition=sim",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 3, "{text}");
    assert!(lines[1].starts_with("shot: sbatch "), "{text}");
    assert!(lines[1].contains("--dependency=afterok:<embed>"), "{text}");
    assert!(lines[2].contains("--dependency=afterok:<shot>"), "{text}");
    assert!(lines[0].contains("--partition=sim"), "{text}");
    for s in ["embed", "shot", "export"] {
        let p = dir
            .path()
            .join(format!("job.out/.knitvox/submit/slurm/{s}.sbatch"));
        let script = std::fs::read_to_string(&p).unwrap();
        assert!(script.contains(&format!("--stage' '{s}'")), "{script}");
    }
    assert!(!dir.path().join("job.out/.knitvox/embed.json").exists());
    // Without a scheduler a real submission is exit 69 (run it elsewhere).
    let out = Command::new(common::knitvox_bin())
        .env("PATH", "/nonexistent")
        .arg("run")
        .arg(&job)
        .args(["--submit", "slurm"])
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(69),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn the_plan_lists_the_stages_for_other_schedulers() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let out = Command::new(common::knitvox_bin())
        .arg("run")
        .arg(&job)
        .args(["--plan", "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let stages = v["stages"].as_array().unwrap();
    let after: Vec<Vec<String>> = stages
        .iter()
        .map(|s| serde_json::from_value(s["after"].clone()).unwrap())
        .collect();
    assert_eq!(
        after,
        [vec![], vec!["embed".to_string()], vec!["shot".to_string()]]
    );
    let argv: Vec<String> = serde_json::from_value(stages[1]["argv"].clone()).unwrap();
    assert!(Path::new(&argv[0]).is_absolute() && Path::new(&argv[2]).is_absolute());
    assert_eq!(
        &argv[1..],
        ["run", argv[2].as_str(), "--stage", "shot", "--json"]
    );
    assert!(!dir.path().join("job.out").exists(), "--plan runs nothing");
}

#[test]
fn the_deadline_and_opencue_submitters_read_the_plan() {
    if !common::require_tool(
        Command::new("python3").arg("-V").output().is_ok(),
        "python3",
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let knitvox = common::knitvox_bin();
    for farm in ["deadline", "opencue"] {
        let out = Command::new("python3")
            .arg(root.join(format!("pipelines/{farm}/submit_knitvox.py")))
            .arg(&job)
            .arg("--knitvox")
            .arg(&knitvox)
            .arg("--dry-run")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{farm}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(text.lines().count(), 3, "{farm}: {text}");
        assert!(
            text.lines().nth(2).unwrap().starts_with("export"),
            "{farm}: {text}"
        );
    }
    let info = dir.path().join("job.out/.knitvox/submit/deadline");
    let shot = std::fs::read_to_string(info.join("shot.job_info.job")).unwrap();
    assert!(shot.contains("JobDependencies=<embed>"), "{shot}");
    let plugin = std::fs::read_to_string(info.join("shot.plugin_info.job")).unwrap();
    assert!(
        plugin.contains(&format!("Executable={}", knitvox.display())),
        "{plugin}"
    );
    assert!(plugin.contains("--stage shot --json"), "{plugin}");
}

#[test]
fn training_poses_run_as_an_array_job_and_the_fit_after_them() {
    let Some((_one, cluster)) = private_cluster() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let job = common::job::training_job_dir(dir.path());
    let ids = submit(&cluster, &job, &[]);
    let names: Vec<&str> = ids.iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(names, ["embed", "train", "fit"]);
    let script = std::fs::read_to_string(
        dir.path()
            .join("job.out/.knitvox/submit/slurm/train.sbatch"),
    )
    .unwrap();
    assert!(
        script.contains("--task \"$SLURM_ARRAY_TASK_ID\""),
        "{script}"
    );
    // Every task of the array job, one line each.
    let states = |id: &str| -> Vec<String> {
        let out = cluster
            .command("scontrol")
            .args(["show", "job", "-o", id])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| {
                l.split_whitespace()
                    .find_map(|kv| kv.strip_prefix("JobState="))
                    .map(str::to_string)
            })
            .collect()
    };
    let start = Instant::now();
    loop {
        let all: Vec<String> = ids.iter().flat_map(|(_, id)| states(id)).collect();
        assert!(
            !all.iter()
                .any(|s| matches!(s.as_str(), "FAILED" | "CANCELLED" | "TIMEOUT")),
            "{all:?}"
        );
        if all.len() >= 4 && all.iter().all(|s| s == "COMPLETED") {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(600), "{all:?}");
        std::thread::sleep(Duration::from_millis(500));
    }
    let out = dir.path().join("job.out");
    for f in [
        "train/00-stretch_courses.h5",
        "train/01-bend_central.h5",
        "fitted.vtkhdf",
        ".knitvox/train.0.json",
        ".knitvox/train.1.json",
        ".knitvox/fit.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // Two array tasks ran, each with its own log.
    let logs = std::fs::read_dir(out.join(".knitvox/submit/slurm"))
        .unwrap()
        .filter(|e| {
            let n = e
                .as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .into_owned();
            n.starts_with("train-") && n.ends_with(".log")
        })
        .count();
    assert_eq!(logs, 2);
}
