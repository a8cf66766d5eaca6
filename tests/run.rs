//! `knitvox run JOB.toml`: job manifests and cached stages.

mod common;

use std::path::Path;
use std::process::Output;

use common::job::{job_dir, manifest, write_garment};

fn run(job: &Path, extra: &[&str]) -> Output {
    std::process::Command::new(common::knitvox_bin())
        .arg("run")
        .arg(job)
        .args(extra)
        .output()
        .unwrap()
}

/// The report of a `--json` run: the last line, after one JSON line per
/// computed frame.
fn report(out: &Output) -> serde_json::Value {
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.lines().last().unwrap()).unwrap()
}

/// `(name, status)` of each stage of a `--json` run.
fn statuses(out: &Output) -> Vec<(String, String)> {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    report(out)["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["name"].as_str().unwrap().to_string(),
                s["status"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn pairs(v: &[(&str, &str)]) -> Vec<(String, String)> {
    v.iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect()
}

#[test]
fn second_run_does_nothing_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let first = run(&job, &["--json"]);
    assert_eq!(
        statuses(&first),
        pairs(&[("embed", "ran"), ("shot", "ran"), ("export", "ran")])
    );
    let out = dir.path().join("job.out");
    for f in [
        "garment.vtkhdf",
        "shot.vtkhdf",
        // Numbered by farm frame, as the shot's frames 1-2.
        "export/garment.0001.ply",
        "export/garment.0002.ply",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    for s in ["embed", "shot", "export"] {
        assert!(out.join(".knitvox").join(format!("{s}.json")).is_file());
    }
    let second = run(&job, &[]);
    assert!(second.status.success());
    let text = String::from_utf8_lossy(&second.stdout);
    assert!(text.contains("embed: cached (key "), "{text}");
    assert!(text.contains("export: cached (key "), "{text}");
    assert!(text.contains("nothing to do"), "{text}");
    assert!(!text.contains("ran in"), "{text}");
    // The keys do not depend on the folder `run` starts in.
    let parent = dir.path().parent().unwrap();
    let relative = job.strip_prefix(parent).unwrap();
    let elsewhere = std::process::Command::new(common::knitvox_bin())
        .current_dir(parent)
        .arg("run")
        .arg(relative)
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(
        statuses(&elsewhere),
        pairs(&[
            ("embed", "cached"),
            ("shot", "cached"),
            ("export", "cached")
        ])
    );
    // A deleted output reruns its stage (and nothing whose key is unchanged).
    std::fs::remove_file(out.join("export/garment.0001.ply")).unwrap();
    assert_eq!(
        statuses(&run(&job, &["--json"])),
        pairs(&[("embed", "cached"), ("shot", "cached"), ("export", "ran")])
    );
}

#[test]
fn changed_garment_content_reruns_every_stage() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    statuses(&run(&job, &["--json"]));
    write_garment(&dir.path().join("swatch.bcc"), 4);
    let second = run(&job, &["--json"]);
    assert_eq!(
        statuses(&second),
        pairs(&[("embed", "ran"), ("shot", "ran"), ("export", "ran")])
    );
    assert_eq!(report(&second)["ran"], 3);
}

#[test]
fn changed_export_parameter_reruns_only_export() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let first = run(&job, &["--json"]);
    statuses(&first);
    std::fs::write(&job, manifest("cm")).unwrap();
    let second = run(&job, &["--json"]);
    assert_eq!(
        statuses(&second),
        pairs(&[("embed", "cached"), ("shot", "cached"), ("export", "ran")])
    );
    let key = |o: &Output, i: usize| report(o)["stages"][i]["key"].as_str().unwrap().to_string();
    assert_eq!(key(&first, 1), key(&second, 1));
    assert_ne!(key(&first, 2), key(&second, 2));
    // Another format replaces the previous export's files.
    std::fs::write(&job, manifest("m").replace("\"ply\"", "\"obj\"")).unwrap();
    let third = run(&job, &["--json"]);
    assert_eq!(
        statuses(&third),
        pairs(&[("embed", "cached"), ("shot", "cached"), ("export", "ran")])
    );
    let export = dir.path().join("job.out/export");
    let mut files: Vec<String> = std::fs::read_dir(&export)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(files, ["garment.0001.obj", "garment.0002.obj"]);
}

#[test]
fn stage_option_runs_that_stage_and_what_it_needs() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    assert_eq!(
        statuses(&run(&job, &["--stage", "embed", "--json"])),
        pairs(&[("embed", "ran")])
    );
    assert!(!dir.path().join("job.out/shot.vtkhdf").exists());
    let bad = run(&job, &["--stage", "fit"]);
    assert_eq!(bad.status.code(), Some(2));
}

/// `[garment]`'s read options reach the embedding, and a changed radius
/// changes the embed key, so the stage runs again.
#[test]
fn garment_read_options_reach_the_asset_and_rerun_embed() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    let with = |extra: &str| manifest("m").replace("[garment]\n", &format!("[garment]\n{extra}\n"));
    let radius_of = || {
        let a =
            knitvox::io::vtkhdf::read_asset(&dir.path().join("job.out/garment.vtkhdf")).unwrap();
        a.rest_yarns.radius[0]
    };
    std::fs::write(&job, with("radius = 0.0004")).unwrap();
    let first = run(&job, &["--stage", "embed", "--json"]);
    assert_eq!(statuses(&first), pairs(&[("embed", "ran")]));
    assert_eq!(radius_of(), 0.0004);
    // Unchanged: cached; the tile written either way is the same key.
    std::fs::write(&job, with("radius = 0.0004\ntile = \"1x1\"")).unwrap();
    let tiled = run(&job, &["--stage", "embed", "--json"]);
    std::fs::write(&job, with("radius = 0.0004\ntile = [1, 1]")).unwrap();
    let pair = run(&job, &["--stage", "embed", "--json"]);
    assert_eq!(statuses(&pair), pairs(&[("embed", "cached")]));
    let key = |o: &Output| report(o)["stages"][0]["key"].as_str().unwrap().to_string();
    assert_eq!(key(&tiled), key(&pair));
    std::fs::write(&job, with("radius = 0.0003")).unwrap();
    let second = run(&job, &["--stage", "embed", "--json"]);
    assert_eq!(statuses(&second), pairs(&[("embed", "ran")]));
    assert_ne!(key(&first), key(&second));
    assert_eq!(radius_of(), 0.0003);
    for (extra, key) in [
        ("radius = -1.0", "garment.radius"),
        ("spline_samples = 0", "garment.spline_samples"),
        ("tile = \"3\"", "garment.tile"),
        ("tile = [1, 2, 3]", "garment.tile"),
        ("tile = [0, 2]", "garment.tile"),
    ] {
        std::fs::write(&job, with(extra)).unwrap();
        let out = run(&job, &[]);
        assert_eq!(out.status.code(), Some(65), "{extra}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("job.toml") && err.contains(key),
            "{extra}: {err}"
        );
    }
}

#[test]
fn unknown_key_exits_65_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    std::fs::write(
        &job,
        manifest("m").replace("[export]", "[export]\nspeed = 3"),
    )
    .unwrap();
    let out = run(&job, &[]);
    assert_eq!(out.status.code(), Some(65));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("job.toml"), "{err}");
    assert!(err.contains("speed"), "{err}");
    assert!(!dir.path().join("job.out").exists());
}

#[test]
fn missing_garment_file_exits_66_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let job = job_dir(dir.path());
    std::fs::remove_file(dir.path().join("swatch.bcc")).unwrap();
    let out = run(&job, &[]);
    assert_eq!(out.status.code(), Some(66));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("swatch.bcc"), "{err}");
}

/// Every property of schemas/job.schema.json is a manifest key and back:
/// a manifest naming every schema property parses, and a key the schema
/// lacks is refused by the struct as well.
#[test]
fn json_schema_properties_match_the_manifest() {
    use knitvox::pipeline::job::Manifest;
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("schemas/job.schema.json"),
    )
    .unwrap();
    let schema: serde_json::Value = serde_json::from_str(&text).unwrap();
    let names = |v: &serde_json::Value| -> Vec<String> {
        let mut n: Vec<String> = v["properties"]
            .as_object()
            .unwrap()
            .keys()
            .cloned()
            .collect();
        n.sort();
        n
    };
    // The struct's keys, from a full manifest serialized back.
    let full: Manifest = toml::from_str(
        r#"
output = "o"
frames = "1"
[garment]
yarns = "y.bcc"
units = "mm"
up_axis = "z"
radius = 0.0005
override_radius = true
spline_samples = 4
tile = "2x3"
[character]
file = "c.glb"
animation = "Walk"
scale = 1.0
pin_distance = 0.01
fit_joint = "j"
[embed]
voxel_size = 0.001
max_voxels = 10
density = 1000.0
cards = ["st.toml", "rib.toml@curves=0-3"]
[[train]]
kind = "shear"
amount = 0.1
mirror = true
steps = 3
friction = 0.2
gravity = 9.81
band = 0.1
[fit]
samples = 2
harmonic = [1, 10]
joint = true
fibres = false
model = "vh"
[shot]
scene = "s.toml"
dt = 0.01
fps = 24.0
preroll = 0.1
backend = "cpu"
solver = "direct"
garment_rotate = [0.0, 0.0, 0.0]
garment_offset = [0.0, 0.0, 0.0]
checkpoint_every = 5
[export]
format = "ply"
steps = "0"
units = "m"
up_axis = "y"
name = "n"
"#,
    )
    .unwrap();
    let v = serde_json::to_value(&full).unwrap();
    let keys = |v: &serde_json::Value| -> Vec<String> {
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    assert_eq!(names(&schema), keys(&v), "top level");
    assert_eq!(
        names(&schema["properties"]["train"]["items"]),
        keys(&v["train"][0]),
        "[[train]]"
    );
    for section in ["garment", "character", "embed", "fit", "shot", "export"] {
        assert_eq!(
            names(&schema["properties"][section]),
            keys(&v[section]),
            "[{section}]"
        );
        assert_eq!(
            schema["properties"][section]["additionalProperties"],
            serde_json::Value::Bool(false),
            "[{section}]"
        );
    }
    assert_eq!(
        schema["additionalProperties"],
        serde_json::Value::Bool(false)
    );
}

#[test]
fn character_job_runs_on_the_repository_fox_and_caches() {
    // The [character] form (as `simulate --character`), on examples/Fox.glb.
    let dir = tempfile::tempdir().unwrap();
    write_garment(&dir.path().join("swatch.bcc"), 3);
    let fox = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb");
    let text = format!(
        r#"
frames = "1-2"
[garment]
yarns = "swatch.bcc"
[character]
file = "{}"
animation = "Walk"
scale = 0.0025
fit_joint = "b_Spine02_03"
[shot]
backend = "cpu"
garment_rotate = [-90.0, 0.0, 0.0]
[export]
format = "obj"
"#,
        fox.display()
    );
    let job = dir.path().join("fox.toml");
    std::fs::write(&job, &text).unwrap();
    // The character lies outside the job's folder: allowed by name.
    let examples = fox.parent().unwrap().to_str().unwrap();
    let allowed = ["--json", "--allow-root", examples];
    let refused = run(&job, &["--json"]);
    assert_eq!(refused.status.code(), Some(65));
    assert_eq!(
        statuses(&run(&job, &allowed)),
        pairs(&[("embed", "ran"), ("shot", "ran"), ("export", "ran")])
    );
    assert!(dir.path().join("fox.out/export/garment.0001.obj").is_file());
    assert_eq!(
        statuses(&run(&job, &allowed)),
        pairs(&[
            ("embed", "cached"),
            ("shot", "cached"),
            ("export", "cached")
        ])
    );
    // A character parameter reruns the shot and what follows, not embed.
    std::fs::write(&job, text.replace("scale = 0.0025", "scale = 0.003")).unwrap();
    assert_eq!(
        statuses(&run(&job, &allowed)),
        pairs(&[("embed", "cached"), ("shot", "ran"), ("export", "ran")])
    );
}

#[test]
fn training_poses_are_tasks_and_the_fit_follows_them() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::job::training_job_dir(dir.path());
    // One farm array task: embed, then pose 1 alone.
    let one = run(&job, &["--stage", "train", "--task", "1", "--json"]);
    assert_eq!(
        statuses(&one),
        pairs(&[("embed", "ran"), ("train.1", "ran")])
    );
    let out = dir.path().join("job.out");
    assert!(out.join("train/01-bend_central.h5").is_file());
    assert!(!out.join("train/00-stretch_courses.h5").exists());
    // A task past the last is a usage error naming the stage.
    let bad = run(&job, &["--stage", "train", "--task", "2"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("2 task(s)"));
    // The whole job: pose 0 runs, pose 1 is cached, the fit follows.
    let all = run(&job, &["--json"]);
    assert_eq!(
        statuses(&all),
        pairs(&[
            ("embed", "cached"),
            ("train.0", "ran"),
            ("train.1", "cached"),
            ("fit", "ran")
        ])
    );
    assert!(out.join("fitted.vtkhdf").is_file());
    // A changed pose reruns that pose and the fit, not the other pose.
    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("amount = 0.3", "amount = 0.2");
    std::fs::write(&job, text).unwrap();
    assert_eq!(
        statuses(&run(&job, &["--json"])),
        pairs(&[
            ("embed", "cached"),
            ("train.0", "cached"),
            ("train.1", "ran"),
            ("fit", "ran")
        ])
    );
    // The farm plan: train is an array of two tasks, the fit after it.
    let plan = run(&job, &["--plan", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&plan.stdout).unwrap();
    assert_eq!(v["stages"][1]["name"], "train");
    assert_eq!(v["stages"][1]["tasks"], 2);
    assert_eq!(v["stages"][2]["after"][0], "train");
}

#[test]
fn a_bad_training_pose_is_refused_naming_its_key() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    write_garment(&dir.path().join("swatch.bcc"), 3);
    for (body, key) in [
        ("[[train]]\nkind = \"wiggle\"\n", "train[0].kind"),
        ("[[train]]\nkind = \"shear\"\nsteps = 0\n", "train[0].steps"),
        ("[[train]]\nkind = \"shear\"\nband = 0.6\n", "band is 0.6"),
        ("[fit]\n", "[fit] needs at least one [[train]]"),
    ] {
        std::fs::write(&job, format!("[garment]\nyarns = \"swatch.bcc\"\n{body}")).unwrap();
        let out = run(&job, &[]);
        assert_eq!(out.status.code(), Some(65), "{body}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(key), "{body}: {err}");
    }
}

/// A job whose shot takes 24 frames, run on one thread (bitwise results).
fn long_shot_job(dir: &Path) -> std::path::PathBuf {
    let job = job_dir(dir);
    let text = manifest("m").replace("frames = \"1-2\"", "frames = \"1-24\"");
    std::fs::write(&job, text).unwrap();
    job
}

/// SIGTERM during `run`'s shot: the shot checkpoints and the run exits 75;
/// the next run resumes from the checkpoint (it computes only the frames
/// after it) and leaves the same bytes as an uninterrupted run, with the
/// checkpoint gone.
#[test]
fn sigterm_checkpoints_the_shot_and_the_next_run_resumes_it() {
    use std::io::BufRead;
    // Both runs in one folder with one command line: the assets record
    // their inputs' paths and the command.
    let dir = tempfile::tempdir().unwrap();
    let job = long_shot_job(dir.path());
    let clean = std::process::Command::new(common::knitvox_bin())
        .env("RAYON_NUM_THREADS", "1")
        .args(["run", "--json"])
        .arg(&job)
        .output()
        .unwrap();
    assert!(
        clean.status.success(),
        "{}",
        String::from_utf8_lossy(&clean.stderr)
    );
    let out = dir.path().join("job.out");
    let reference = common::files_under(&out);
    assert!(!reference.keys().any(|p| p.starts_with("checkpoints")));
    std::fs::remove_dir_all(&out).unwrap();

    let mut child = std::process::Command::new(common::knitvox_bin())
        .env("RAYON_NUM_THREADS", "1")
        .args(["run", "--json"])
        .arg(&job)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // SIGTERM once the shot has computed frame 3.
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    for line in lines.by_ref() {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        if v["event"] == "frame" && v["frame"] == 3 {
            break;
        }
    }
    // SAFETY: signalling our own child process.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let rest: Vec<String> = lines.map(Result::unwrap).collect();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(75), "{err}");
    let last: serde_json::Value = serde_json::from_str(rest.last().unwrap()).unwrap();
    assert_eq!(last["event"], "error", "{last}");
    assert_eq!(last["class"], "transient", "{last}");
    assert!(!out.join("shot.vtkhdf").exists());
    assert!(!out.join(".knitvox/shot.json").exists());
    let ckpts: Vec<_> = std::fs::read_dir(out.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ckpt"))
        .collect();
    assert_eq!(ckpts.len(), 1, "{ckpts:?}");
    // A run stopped before its first step leaves a step-0 checkpoint beside
    // later ones (a daemon killed as the shot began, then restarted): the
    // finished run removes every checkpoint of the job, not only the one it
    // resumed from.
    let name = ckpts[0].file_name().unwrap().to_string_lossy().into_owned();
    let (stem, _) = name.rsplit_once(".ckpt").unwrap();
    let (prefix, _) = stem.rsplit_once('.').unwrap();
    std::fs::copy(
        &ckpts[0],
        out.join(format!("checkpoints/{prefix}.0000000000.ckpt")),
    )
    .unwrap();

    let again = std::process::Command::new(common::knitvox_bin())
        .env("RAYON_NUM_THREADS", "1")
        .args(["run", "--json"])
        .arg(&job)
        .output()
        .unwrap();
    assert_eq!(
        statuses(&again),
        pairs(&[("embed", "cached"), ("shot", "ran"), ("export", "ran")])
    );
    let text = String::from_utf8_lossy(&again.stdout);
    let frames: Vec<i64> = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["event"] == "frame")
        .map(|v| v["frame"].as_i64().unwrap())
        .collect();
    assert!(
        frames.first().is_some_and(|&f| f > 3),
        "did not resume: {frames:?}"
    );
    assert_eq!(frames.last(), Some(&24));
    let after = common::files_under(&out);
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        reference.keys().collect::<Vec<_>>()
    );
    for (p, bytes) in &reference {
        assert!(
            &after[p] == bytes,
            "{} differs from the clean run",
            p.display()
        );
    }
}

/// A second `run` of a job while the first runs its shot waits for it: exit
/// 75 (transient, retry later) naming the lock and its holder; the first
/// finishes undisturbed and the second, run again, finds everything cached.
#[test]
fn a_concurrent_run_of_the_same_job_is_refused_as_busy() {
    use std::io::BufRead;
    let dir = tempfile::tempdir().unwrap();
    let job = long_shot_job(dir.path());
    let mut first = std::process::Command::new(common::knitvox_bin())
        .args(["run", "--json"])
        .arg(&job)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(first.stdout.take().unwrap()).lines();
    for line in lines.by_ref() {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        if v["event"] == "frame" && v["frame"] == 2 {
            break;
        }
    }
    let second = run(&job, &[]);
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(75), "{err}");
    assert!(err.contains("shot.lock"), "{err}");
    assert!(err.contains(&first.id().to_string()), "{err}");
    let rest: Vec<String> = lines.map(Result::unwrap).collect();
    assert!(first.wait().unwrap().success());
    let last: serde_json::Value = serde_json::from_str(rest.last().unwrap()).unwrap();
    assert_eq!(last["ran"], 3, "{last}");
    let third = run(&job, &["--json"]);
    assert_eq!(
        statuses(&third),
        pairs(&[
            ("embed", "cached"),
            ("shot", "cached"),
            ("export", "cached")
        ])
    );
    assert!(!dir.path().join("job.out/.knitvox/shot.lock").exists());
}
