//! Hostile names in farm scripts: a job manifest's file name, its folder and
//! its `output` key never become shell code or a `#SBATCH` directive of the
//! generated Slurm scripts, and the Deadline and OpenCue submitters refuse
//! a plan with control bytes. The scripts are checked with `bash -n`, by
//! reading their directives the way sbatch does, and by running them with
//! stand-ins for knitvox, scontrol and sleep.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The directives every stage script carries.
const DIRECTIVES: [&str; 5] = [
    "--job-name",
    "--output",
    "--open-mode",
    "--requeue",
    "--chdir",
];

/// `s` as a TOML basic string (control bytes as `\uXXXX`).
fn toml_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                out.push_str(&format!("\\u{:04X}", c as u32))
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A job folder `root/folder` with the manifest `stem.toml` whose `output`
/// key is `output`; returns the manifest path.
fn hostile_job(root: &Path, folder: &str, stem: &str, output: Option<&str>) -> PathBuf {
    let dir = root.join(folder);
    std::fs::create_dir_all(&dir).unwrap();
    common::job::write_garment(&dir.join("swatch.bcc"), 3);
    std::fs::write(dir.join("scene.toml"), common::job::SCENE).unwrap();
    let mut text = common::job::manifest("m");
    if let Some(o) = output {
        text = format!("output = {}\n{text}", toml_string(o));
    }
    let job = dir.join(format!("{stem}.toml"));
    std::fs::write(&job, text).unwrap();
    job
}

fn dry_run(job: &Path, knitvox: &Path) -> Output {
    Command::new(common::knitvox_bin())
        .env("PATH", "/nonexistent")
        .arg("run")
        .arg(job)
        .args(["--submit", "slurm", "--dry-run", "--knitvox"])
        .arg(knitvox)
        .output()
        .unwrap()
}

/// `s` escaped as a Rust string literal, without its quotes.
fn inner_escaped(s: &str) -> String {
    let e = format!("{s:?}");
    e[1..e.len() - 1].to_string()
}

/// Every path under `dir` whose name contains `PWNED`.
fn pwned(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.file_name()
                .is_some_and(|n| n.to_string_lossy() == "PWNED")
            {
                found.push(p.clone());
            }
            if p.is_dir() && !p.is_symlink() {
                todo.push(p);
            }
        }
    }
    found
}

/// Every `.sbatch` file under `dir`.
fn scripts(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "sbatch") {
                found.push(p);
            }
        }
    }
    found
}

/// The arguments of one `#SBATCH` line as sbatch reads them: split at
/// white space, `'` and `"` quote, `\` escapes, an unquoted `#` ends the
/// line; `None` for an unmatched quote (sbatch refuses the script).
fn sbatch_words(line: &str) -> Option<Vec<String>> {
    let mut words = Vec::new();
    let mut chars = line.chars().peekable();
    loop {
        while chars.peek().is_some_and(|c| c.is_whitespace()) {
            chars.next();
        }
        if chars.peek().is_none() {
            return Some(words);
        }
        let (mut word, mut quote, mut escape) = (String::new(), None, false);
        while let Some(&c) = chars.peek() {
            if quote.is_none() && c.is_whitespace() {
                break;
            }
            chars.next();
            if escape {
                escape = false;
            } else if c == '\\' {
                escape = true;
                continue;
            } else if let Some(q) = quote {
                if c == q {
                    quote = None;
                    continue;
                }
            } else if c == '"' || c == '\'' {
                quote = Some(c);
                continue;
            } else if c == '#' {
                words.push(word);
                return Some(words);
            }
            word.push(c);
        }
        if quote.is_some() {
            return None;
        }
        words.push(word);
    }
}

/// The directives of a script as sbatch collects them: `#SBATCH` lines
/// before the first line that is not a comment.
fn directives(script: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for line in script.lines().skip(1) {
        if !line.starts_with('#') {
            break;
        }
        let Some(rest) = line.strip_prefix("#SBATCH") else {
            continue;
        };
        let words =
            sbatch_words(rest).unwrap_or_else(|| panic!("sbatch refuses this line: {line:?}"));
        for w in words.into_iter().filter(|w| !w.is_empty()) {
            let (k, v) = w.split_once('=').unwrap_or((&w, ""));
            out.push((k.to_string(), v.to_string()));
        }
    }
    out
}

/// Stand-ins on PATH: `knitvox` records its arguments (NUL-separated) and
/// exits `$FAKE_RC`; `scontrol` records its arguments; `sleep` returns.
fn fake_bin(dir: &Path) -> PathBuf {
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let write = |name: &str, text: &str| {
        let p = bin.join(name);
        std::fs::write(&p, text).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    };
    write(
        "knitvox",
        "#!/bin/bash\nprintf '%s\\0' \"$@\" > \"$FAKE_LOG/argv\"\nexit \"$FAKE_RC\"\n",
    );
    write(
        "scontrol",
        "#!/bin/bash\necho \"$*\" >> \"$FAKE_LOG/scontrol\"\n",
    );
    write("sleep", "#!/bin/bash\nexit 0\n");
    bin
}

/// Runs `script` in bash from the folder `cwd` with the stand-ins, as
/// Slurm job 4242 on its first attempt; returns bash's exit code.
fn run_script(script: &Path, cwd: &Path, bin: &Path, log: &Path, rc: i32) -> i32 {
    let path = format!("{}:/usr/bin:/bin", bin.display());
    let s = Command::new("bash")
        .arg(script)
        .current_dir(cwd)
        .env("PATH", path)
        .env("FAKE_LOG", log)
        .env("FAKE_RC", rc.to_string())
        .env("SLURM_JOB_ID", "4242")
        .env("SLURM_RESTART_COUNT", "0")
        .output()
        .unwrap();
    s.status.code().unwrap_or(-1)
}

/// Names a shell or sbatch would read as code or as the end of a value.
const PRINTABLE: [&str; 8] = [
    "a $(touch PWNED) b",
    "a `touch PWNED` b",
    "a'; touch PWNED; echo '",
    "a\"; touch PWNED; echo \"",
    "a # --requeue",
    "a \\\" c",
    "50% of %j",
    " ; touch PWNED & ",
];

/// Control bytes: each would end a line of the script.
const CONTROL: [&str; 6] = [
    "o\ntouch PWNED\n#",
    "o\rtouch PWNED",
    "o\u{b}touch PWNED",
    "o\u{1b}]0;x\u{7}",
    "o\ttab",
    "o\u{7f}",
];

#[test]
fn a_control_byte_in_the_output_key_is_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let bin = fake_bin(dir.path());
    for (k, payload) in CONTROL.iter().enumerate() {
        let job = hostile_job(dir.path(), &format!("j{k}"), "job", Some(payload));
        let o = dry_run(&job, &bin.join("knitvox"));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(65), "{payload:?}: {err}");
        assert!(
            err.contains("'output' key") && err.contains(&job.display().to_string()),
            "{payload:?}: {err}"
        );
        // Shown escaped, on one line.
        assert!(err.contains(&inner_escaped(payload)), "{payload:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{payload:?}: {err}");
        assert!(scripts(dir.path()).is_empty(), "{payload:?}");
    }
    assert!(pwned(dir.path()).is_empty());
}

#[test]
fn a_newline_in_a_manifest_or_folder_name_never_starts_a_shell_line() {
    let dir = tempfile::tempdir().unwrap();
    let bin = fake_bin(dir.path());
    for (k, payload) in CONTROL.iter().enumerate() {
        for (folder, stem) in [
            (format!("f{k}"), format!("job{payload}")),
            (format!("g{k}{payload}"), "job".to_string()),
        ] {
            let job = hostile_job(dir.path(), &folder, &stem, None);
            let o = dry_run(&job, &bin.join("knitvox"));
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(65), "{payload:?}: {err}");
            assert!(err.contains("manifest's path"), "{payload:?}: {err}");
            assert!(err.contains(&inner_escaped(payload)), "{payload:?}: {err}");
        }
    }
    assert!(scripts(dir.path()).is_empty());
    // A control byte in --knitvox is a usage error.
    let job = hostile_job(dir.path(), "ok", "job", None);
    let o = dry_run(&job, Path::new("/opt/knitvox\ntouch PWNED"));
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("--knitvox"));
    assert!(pwned(dir.path()).is_empty());
}

#[test]
fn quotes_and_substitutions_in_names_stay_literal_in_the_slurm_scripts() {
    let dir = tempfile::tempdir().unwrap();
    let bin = fake_bin(dir.path());
    let combined = PRINTABLE.join(" ");
    let mut cases: Vec<(String, String, String)> = PRINTABLE
        .iter()
        .enumerate()
        .flat_map(|(k, p)| {
            [
                (format!("f{k}{p}"), "job".to_string(), "out".to_string()),
                (format!("s{k}"), format!("job{p}"), "out".to_string()),
                (format!("o{k}"), "job".to_string(), format!("out{p}")),
            ]
        })
        .collect();
    cases.push(("c".into(), combined.clone(), combined.replace('\\', "")));
    for (folder, stem, output) in &cases {
        let what = format!("folder {folder:?}, manifest {stem:?}, output {output:?}");
        let job = hostile_job(dir.path(), folder, stem, Some(output));
        let o = dry_run(&job, &bin.join("knitvox"));
        // Slurm drops backslashes from --output: such an output folder is refused.
        if dir
            .path()
            .join(folder)
            .join(output)
            .to_string_lossy()
            .contains('\\')
        {
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(65), "{what}: {err}");
            assert!(
                err.contains("backslash") && err.contains("'output'"),
                "{what}: {err}"
            );
            continue;
        }
        assert!(
            o.status.success(),
            "{what}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let job = job.canonicalize().unwrap();
        let out = job.parent().unwrap().join(output);
        let submit = out.join(".knitvox/submit/slurm");
        for stage in ["embed", "shot", "export"] {
            let script = submit.join(format!("{stage}.sbatch"));
            let text = std::fs::read_to_string(&script)
                .unwrap_or_else(|e| panic!("{what}: {}: {e}", script.display()));
            let check = Command::new("bash")
                .arg("-n")
                .arg(&script)
                .output()
                .unwrap();
            assert!(
                check.status.success(),
                "{what}: bash -n: {}\n{text}",
                String::from_utf8_lossy(&check.stderr)
            );
            // sbatch sees every directive, each value whole.
            let d = directives(&text);
            let keys: Vec<&str> = d.iter().map(|(k, _)| k.as_str()).collect();
            assert_eq!(keys, DIRECTIVES, "{what}\n{text}");
            let value = |k: &str| d.iter().find(|(key, _)| key == k).unwrap().1.clone();
            let log = format!(
                "{}/{stage}-%j.log",
                submit.display().to_string().replace('%', "%%")
            );
            assert_eq!(value("--output"), log, "{what}\n{text}");
            assert_eq!(
                value("--chdir"),
                job.parent().unwrap().display().to_string(),
                "{what}\n{text}"
            );
            let name = value("--job-name");
            assert!(
                name.ends_with(&format!(":{stage}"))
                    && name[..name.len() - stage.len() - 1]
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c)),
                "{what}: job name {name:?}"
            );
            // Run it: the stand-in gets the manifest as one argument, the
            // exit policy sees its code, nothing else runs.
            let run_dir = dir.path().join("run");
            std::fs::create_dir_all(&run_dir).unwrap();
            let log = dir.path().join("log");
            for rc in [0, 75, 66, 65] {
                let _ = std::fs::remove_dir_all(&log);
                std::fs::create_dir_all(&log).unwrap();
                let code = run_script(&script, &run_dir, &bin, &log, rc);
                assert_eq!(code, rc, "{what}: {stage} with exit {rc}\n{text}");
                let argv = std::fs::read(log.join("argv")).unwrap();
                let argv: Vec<String> = argv
                    .split(|&b| b == 0)
                    .filter(|a| !a.is_empty())
                    .map(|a| String::from_utf8_lossy(a).into_owned())
                    .collect();
                assert_eq!(
                    argv,
                    [
                        "run",
                        &job.display().to_string(),
                        "--stage",
                        stage,
                        "--json"
                    ],
                    "{what}"
                );
                let scontrol = std::fs::read_to_string(log.join("scontrol")).unwrap_or_default();
                let expected = match rc {
                    75 => "requeue 4242\n",
                    66 => "requeuehold 4242\n",
                    _ => "",
                };
                assert_eq!(scontrol, expected, "{what}: exit {rc}");
            }
        }
    }
    assert!(pwned(dir.path()).is_empty(), "{:?}", pwned(dir.path()));
}

#[test]
fn the_deadline_and_opencue_submitters_refuse_control_bytes_in_a_plan() {
    if !common::require_tool(
        Command::new("python3").arg("-V").output().is_ok(),
        "python3",
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // A knitvox that prints a plan with a newline in its output folder.
    let plan = serde_json::json!({
        "job": dir.path().join("job.toml"),
        "name": "job",
        "output": format!("{}\ntouch PWNED", out.display()),
        "stages": [{"name": "embed", "after": [], "tasks": 1,
                    "argv": ["/opt/knitvox", "run", "job.toml", "--stage", "embed", "--json"]}],
    });
    let fake = dir.path().join("knitvox");
    std::fs::write(&fake, format!("#!/bin/bash\ncat <<'EOF'\n{plan}\nEOF\n")).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for farm in ["deadline", "opencue"] {
        let o = Command::new("python3")
            .current_dir(dir.path())
            .arg(root.join(format!("pipelines/{farm}/submit_knitvox.py")))
            .arg(dir.path().join("job.toml"))
            .arg("--knitvox")
            .arg(&fake)
            .arg("--dry-run")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(65), "{farm}: {err}");
        assert!(
            err.contains("plan.output") && err.contains("\\ntouch PWNED"),
            "{farm}: {err}"
        );
        // A control byte in a flag is a usage error.
        let o = Command::new("python3")
            .arg(root.join(format!("pipelines/{farm}/submit_knitvox.py")))
            .arg(dir.path().join("job.toml"))
            .arg("--knitvox")
            .arg(format!("{}\nx", fake.display()))
            .arg("--dry-run")
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{farm}: {o:?}");
    }
    assert!(pwned(dir.path()).is_empty());
    assert!(
        !out.exists()
            && !dir
                .path()
                .join(format!("{}\ntouch PWNED", out.display()))
                .exists()
    );
}
