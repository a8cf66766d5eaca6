//! Hostile job manifests: paths that leave the job's folder, outputs that
//! land on inputs, absurd numbers. Each is refused by `knitvox run` before
//! any stage runs, whatever the mode (`--plan`, `--stage`, `--submit`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::job::{write_garment, SCENE};

fn run_in(dir: &Path, args: &[&str]) -> Output {
    std::process::Command::new(common::knitvox_bin())
        .current_dir(dir)
        .arg("run")
        .args(args)
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The modes that must all refuse before doing anything.
const MODES: [&[&str]; 5] = [
    &[],
    &["--json"],
    &["--plan", "--json"],
    &["--stage", "embed"],
    &["--submit", "slurm", "--dry-run"],
];

/// A job folder `job/` and a folder beside it, `outside/`, holding a
/// garment, a scene and a (never read) character.
fn layout(root: &Path) -> (PathBuf, PathBuf) {
    let job = root.join("job");
    let outside = root.join("outside");
    std::fs::create_dir_all(&job).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    write_garment(&job.join("swatch.bcc"), 3);
    write_garment(&outside.join("x.bcc"), 3);
    std::fs::write(outside.join("s.toml"), SCENE).unwrap();
    std::fs::write(job.join("scene.toml"), SCENE).unwrap();
    std::fs::write(outside.join("c.glb"), b"glTF").unwrap();
    (job, outside)
}

/// `knitvox run` of `manifest` (written as `job/job.toml`) in every mode:
/// exit 65 naming the manifest, the key and the path as written, and
/// nothing written in the job's folder.
fn assert_refused(job: &Path, manifest: &str, key: &str, written: &str) {
    std::fs::write(job.join("job.toml"), manifest).unwrap();
    let before = names(job);
    for mode in MODES {
        let mut args = vec!["job.toml"];
        args.extend_from_slice(mode);
        let o = run_in(job, &args);
        let t = text(&o);
        assert_eq!(o.status.code(), Some(65), "{manifest} {mode:?}: {t}");
        for part in ["job.toml", key, written, "outside"] {
            assert!(t.contains(part), "{manifest} {mode:?}: no '{part}' in {t}");
        }
        assert_eq!(
            names(job),
            before,
            "{manifest} {mode:?} wrote into the job folder"
        );
    }
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn garment_yarns_outside_the_job_folder_are_refused_in_every_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let (job, outside) = layout(tmp.path());
    std::os::unix::fs::symlink(outside.join("x.bcc"), job.join("link.bcc")).unwrap();
    std::fs::create_dir(job.join("sub")).unwrap();
    let abs = outside.join("x.bcc").display().to_string();
    for yarns in [
        "../outside/x.bcc",
        abs.as_str(),
        "link.bcc",
        "sub/../../outside/x.bcc",
    ] {
        let m = format!("[garment]\nyarns = \"{yarns}\"\n[export]\n");
        assert_refused(&job, &m, "[garment] yarns", yarns);
    }
}

#[test]
fn a_scene_or_character_outside_the_job_folder_is_refused_in_every_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let (job, outside) = layout(tmp.path());
    let shot = |scene: &str| {
        format!(
            "frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"{scene}\"\n"
        )
    };
    // The scene itself.
    assert_refused(
        &job,
        &shot("../outside/s.toml"),
        "[shot] scene",
        "../outside/s.toml",
    );
    let abs_scene = outside.join("s.toml").display().to_string();
    assert_refused(&job, &shot(&abs_scene), "[shot] scene", &abs_scene);
    // The scene's own character, relative to the scene's folder.
    std::fs::create_dir_all(job.join("scenes")).unwrap();
    std::fs::write(
        job.join("scenes/fox.toml"),
        "[character]\nfile = \"../../outside/c.glb\"\nscale = 0.01\n",
    )
    .unwrap();
    assert_refused(
        &job,
        &shot("scenes/fox.toml"),
        "[character] file of the scene 'scenes/fox.toml'",
        "../../outside/c.glb",
    );
    // A symlinked character inside the job folder that leads out.
    std::os::unix::fs::symlink(outside.join("c.glb"), job.join("scenes/c.glb")).unwrap();
    std::fs::write(
        job.join("scenes/fox.toml"),
        "[character]\nfile = \"c.glb\"\n",
    )
    .unwrap();
    assert_refused(&job, &shot("scenes/fox.toml"), "[character] file", "c.glb");
    // The top-level [character].
    let abs_char = outside.join("c.glb").display().to_string();
    let m = format!(
        "frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[character]\nfile = \"{abs_char}\"\n[shot]\n"
    );
    assert_refused(&job, &m, "[character] file", &abs_char);
}

#[test]
fn allow_root_lets_a_job_read_from_another_folder_and_the_farm_nodes_too() {
    let tmp = tempfile::tempdir().unwrap();
    let (job, outside) = layout(tmp.path());
    std::fs::write(
        job.join("job.toml"),
        "frames = \"1-2\"\n[garment]\nyarns = \"../outside/x.bcc\"\n[shot]\nscene = \"../outside/s.toml\"\nbackend = \"cpu\"\n",
    )
    .unwrap();
    // Relative to the working folder, as given.
    let o = run_in(
        &job,
        &["job.toml", "--allow-root", "../outside", "--plan", "--json"],
    );
    assert!(o.status.success(), "{}", text(&o));
    let plan: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let argv: Vec<String> = plan["stages"][0]["argv"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap().to_string())
        .collect();
    let at = argv
        .iter()
        .position(|a| a == "--allow-root")
        .expect("no --allow-root in the plan");
    assert_eq!(
        Path::new(&argv[at + 1]),
        outside.canonicalize().unwrap(),
        "{argv:?}"
    );
    // The embed stage reads the outside garment.
    let o = run_in(
        &job,
        &["job.toml", "--allow-root", "../outside", "--stage", "embed"],
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(job.join("job.out/garment.vtkhdf").is_file());
    // Another folder does not allow it; a missing one is a usage error.
    let other = tmp.path().join("other");
    std::fs::create_dir(&other).unwrap();
    let o = run_in(&job, &["job.toml", "--allow-root", "../other", "--plan"]);
    assert_eq!(o.status.code(), Some(65), "{}", text(&o));
    let o = run_in(&job, &["job.toml", "--allow-root", "../nowhere", "--plan"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--allow-root"), "{}", text(&o));
}

/// Bytes no message of knitvox would hold by chance.
const SECRET: &str = "zq7Xw3Kp9Lm2Vb8Nc4Rt6Yh1Qs5Df0Gj";

/// No 6-byte piece of the secret in `t`.
fn assert_no_secret(t: &str, what: &str) {
    for w in SECRET.as_bytes().windows(6) {
        let piece = std::str::from_utf8(w).unwrap();
        assert!(
            !t.contains(piece),
            "{what}: the secret's '{piece}' leaked: {t}"
        );
    }
}

#[test]
fn an_outside_secret_named_as_scene_character_or_yarns_never_reaches_a_message() {
    let tmp = tempfile::tempdir().unwrap();
    let (job, _) = layout(tmp.path());
    let secret = tmp.path().join("secret");
    std::fs::create_dir(&secret).unwrap();
    for f in ["secret.toml", "secret.glb", "secret.bcc", "secret.obj"] {
        std::fs::write(secret.join(f), format!("{SECRET}\n{SECRET} = [\n")).unwrap();
    }
    std::os::unix::fs::symlink(secret.join("secret.toml"), job.join("linked.toml")).unwrap();
    std::fs::write(
        job.join("fox.toml"),
        "[character]\nfile = \"../secret/secret.glb\"\n",
    )
    .unwrap();
    let abs = |f: &str| secret.join(f).display().to_string();
    let shot = |scene: &str| {
        format!(
            "frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"{scene}\"\n"
        )
    };
    let manifests = [
        shot("../secret/secret.toml"),
        shot(&abs("secret.toml")),
        shot("linked.toml"),
        shot("fox.toml"),
        format!("frames = \"1\"\n[garment]\nyarns = \"swatch.bcc\"\n[character]\nfile = \"{}\"\n[shot]\n", abs("secret.glb")),
        format!("[garment]\nyarns = \"{}\"\n[export]\n", abs("secret.bcc")),
        "[garment]\nyarns = \"../secret/secret.obj\"\n[export]\n".to_string(),
    ];
    for m in manifests {
        std::fs::write(job.join("job.toml"), &m).unwrap();
        for mode in [&[][..], &["--json"], &["--plan"]] {
            let mut args = vec!["job.toml"];
            args.extend_from_slice(mode);
            let o = run_in(&job, &args);
            assert_ne!(o.status.code(), Some(0), "{m} {mode:?}");
            assert_no_secret(&text(&o), &format!("{m} {mode:?}"));
        }
    }
}

#[test]
fn an_export_over_the_garment_input_is_refused_before_any_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let job = tmp.path();
    std::fs::create_dir_all(job.join("export")).unwrap();
    std::fs::create_dir_all(job.join("job.out/export")).unwrap();
    write_garment(&job.join("export/garment.0000.ply"), 3);
    write_garment(&job.join("job.out/export/garment.0000.ply"), 3);
    write_garment(&job.join("export/mine.0003.ply"), 3);
    std::fs::write(job.join("scene.toml"), SCENE).unwrap();
    std::fs::create_dir_all(job.join("checkpoints")).unwrap();
    std::fs::write(job.join("checkpoints/s.toml"), SCENE).unwrap();
    write_garment(&job.join("swatch.bcc"), 3);
    std::fs::write(job.join("garment.vtkhdf"), b"x").unwrap();
    for (manifest, stage, input) in [
        (
            "output = \".\"\n[garment]\nyarns = \"export/garment.0000.ply\"\n[export]\nformat = \"ply\"\n",
            "export",
            "export/garment.0000.ply",
        ),
        // The default output folder.
        (
            "[garment]\nyarns = \"job.out/export/garment.0000.ply\"\n[export]\n",
            "export",
            "job.out/export/garment.0000.ply",
        ),
        (
            "output = \".\"\n[garment]\nyarns = \"export/mine.0003.ply\"\n[export]\nname = \"mine\"\nformat = \"obj\"\n",
            "export",
            "export/mine.0003.ply",
        ),
        (
            "output = \".\"\n[garment]\nyarns = \"garment.vtkhdf\"\n",
            "embed",
            "garment.vtkhdf",
        ),
        (
            "output = \".\"\nframes = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"checkpoints/s.toml\"\n",
            "shot",
            "checkpoints/s.toml",
        ),
    ] {
        std::fs::write(job.join("job.toml"), manifest).unwrap();
        let before = common::files_under(job);
        for mode in MODES {
            let mut args = vec!["job.toml"];
            args.extend_from_slice(mode);
            let o = run_in(job, &args);
            let t = text(&o);
            assert_eq!(o.status.code(), Some(2), "{manifest} {mode:?}: {t}");
            for part in ["job.toml", "never overwrites", input, stage] {
                assert!(t.contains(part), "{manifest} {mode:?}: no '{part}' in {t}");
            }
            assert!(common::files_under(job) == before, "{manifest} {mode:?} changed files");
        }
    }
}

/// A record listing a file that has since become the job's input (another
/// export name) must not make the rerun delete it as a stale output.
#[test]
fn a_stale_output_that_became_an_input_is_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let job = tmp.path();
    write_garment(&job.join("swatch.bcc"), 3);
    let manifest = job.join("job.toml");
    std::fs::write(
        &manifest,
        "output = \".\"\n[garment]\nyarns = \"swatch.bcc\"\n[export]\nname = \"a\"\n",
    )
    .unwrap();
    let o = run_in(job, &["job.toml"]);
    assert!(o.status.success(), "{}", text(&o));
    let input = job.join("export/a.0000.ply");
    let bytes = std::fs::read(&input).unwrap();
    std::fs::write(
        &manifest,
        "output = \".\"\n[garment]\nyarns = \"export/a.0000.ply\"\n[export]\nname = \"b\"\n",
    )
    .unwrap();
    let o = run_in(job, &["job.toml"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(job.join("export/b.0000.ply").is_file());
    assert_eq!(
        std::fs::read(&input).unwrap(),
        bytes,
        "the input changed or went"
    );
}

#[test]
fn absurd_manifest_numbers_are_refused_naming_key_and_value() {
    let tmp = tempfile::tempdir().unwrap();
    let job = tmp.path();
    write_garment(&job.join("swatch.bcc"), 3);
    std::fs::write(job.join("c.glb"), b"glTF").unwrap();
    std::fs::write(job.join("scene.toml"), SCENE).unwrap();
    let character = |k: &str| {
        format!("frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[character]\nfile = \"c.glb\"\n{k}\n[shot]\n")
    };
    let shot = |k: &str| {
        format!("frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"scene.toml\"\n{k}\n")
    };
    let cases = [
        (character("scale = 0"), "character.scale", "0"),
        (character("scale = nan"), "character.scale", "NaN"),
        (character("scale = 1e300"), "character.scale", "1e300"),
        (character("scale = -0.01"), "character.scale", "-0.01"),
        (
            character("pin_distance = -inf"),
            "character.pin_distance",
            "-inf",
        ),
        (shot("preroll = nan"), "shot.preroll", "NaN"),
        (shot("preroll = 1e300"), "shot.preroll", "1e300"),
        (shot("preroll = -1"), "shot.preroll", "-1"),
        (shot("dt = inf"), "shot.dt", "inf"),
        (shot("fps = 0"), "shot.fps", "0"),
        (
            shot("garment_offset = [nan, 0.0, 0.0]"),
            "shot.garment_offset",
            "NaN",
        ),
        // Valid one by one, but more steps than a shot may take.
        (shot("fps = 1e-300"), "frames", "1e-300"),
        (
            "[garment]\nyarns = \"swatch.bcc\"\n[embed]\nvoxel_size = -1e-300\n".into(),
            "embed.voxel_size",
            "-1e-300",
        ),
        (
            "[garment]\nyarns = \"swatch.bcc\"\n[[train]]\nkind = \"shear\"\ngravity = 1e300\n"
                .into(),
            "train[0].gravity",
            "1e300",
        ),
    ];
    for (manifest, key, value) in cases {
        std::fs::write(job.join("job.toml"), &manifest).unwrap();
        for mode in [&[][..], &["--plan"], &["--json"]] {
            let mut args = vec!["job.toml"];
            args.extend_from_slice(mode);
            let o = run_in(job, &args);
            let t = text(&o);
            assert_eq!(o.status.code(), Some(65), "{manifest} {mode:?}: {t}");
            for part in ["job.toml", key, value] {
                assert!(t.contains(part), "{manifest} {mode:?}: no '{part}' in {t}");
            }
            assert!(!t.contains("00000000"), "{manifest}: a long number in {t}");
            assert!(!job.join("job.out").exists(), "{manifest}: a stage ran");
        }
    }
}

#[test]
fn absurd_scene_numbers_are_refused_naming_the_scene_key_and_value() {
    let tmp = tempfile::tempdir().unwrap();
    let job = tmp.path();
    write_garment(&job.join("swatch.bcc"), 3);
    std::fs::write(job.join("c.glb"), b"glTF").unwrap();
    std::fs::write(
        job.join("job.toml"),
        "frames = \"1-2\"\n[garment]\nyarns = \"swatch.bcc\"\n[shot]\nscene = \"scene.toml\"\n",
    )
    .unwrap();
    for (scene, key, value) in [
        (
            "[character]\nfile = \"c.glb\"\nscale = 0\n",
            "character.scale",
            "0",
        ),
        (
            "[character]\nfile = \"c.glb\"\nscale = 1e-300\n",
            "character.scale",
            "1e-300",
        ),
        (
            "[character]\nfile = \"c.glb\"\nscale = nan\n",
            "character.scale",
            "NaN",
        ),
        (
            "[simulation]\npreroll = 1e300\n",
            "simulation.preroll",
            "1e300",
        ),
        ("[simulation]\npreroll = nan\n", "simulation.preroll", "NaN"),
        (
            "[simulation]\nfriction = nan\n",
            "simulation.friction",
            "NaN",
        ),
        (
            "[simulation]\ndamping = -1e300\n",
            "simulation.damping",
            "-1e300",
        ),
    ] {
        std::fs::write(job.join("scene.toml"), scene).unwrap();
        let o = run_in(job, &["job.toml", "--plan"]);
        let t = text(&o);
        assert_eq!(o.status.code(), Some(65), "{scene}: {t}");
        for part in ["scene.toml", key, value] {
            assert!(t.contains(part), "{scene}: no '{part}' in {t}");
        }
        assert!(!t.contains("00000000"), "{scene}: a long number in {t}");
    }
}
