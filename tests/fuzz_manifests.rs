//! Mutation fuzzing of job manifests and the farm scripts made from them
//! (the cargo-fuzz target `fuzz/fuzz_targets/manifest_toml.rs` runs the same
//! checks unbounded): a hostile value in any key is refused with a short
//! message or loads within range, and no name or key, whatever its bytes,
//! adds a line or a directive to a generated Slurm script.
use std::path::{Path, PathBuf};

use knitvox::pipeline::job::Job;
use knitvox::pipeline::submit::{plan, slurm_script, SlurmOptions};
use proptest::prelude::*;

mod common;
use common::mutate::{replace_value, value_lines};

const MAX_MESSAGE: usize = 4096;

const HOSTILE: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "0",
    "-1",
    "1e300",
    "-1e300",
    "1e-300",
    "18446744073709551615",
    "-9223372036854775808",
    "\"\"",
    "\"/etc/passwd\"",
    "\"../../outside.bcc\"",
    "\"a\\nb\"",
    "\"$(touch PWNED)\"",
    "\"`touch PWNED`\"",
    "[]",
    "{}",
    "true",
];

/// A folder holding the example job and everything it names.
fn job_folder() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let ex = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    for f in ["job.toml", "example_swatch.bcc", "fox-walk.toml", "Fox.glb"] {
        std::fs::copy(ex.join(f), d.path().join(f)).unwrap();
    }
    d
}

/// Loads `text` as `name` in `dir`: `Ok(true)` refused with a short
/// message, `Ok(false)` loaded.
fn load(dir: &Path, name: &str, text: &str) -> Result<bool, String> {
    let path = dir.join(name);
    std::fs::write(&path, text).map_err(|e| e.to_string())?;
    match Job::load(&path) {
        Ok(_) => Ok(false),
        Err(e) => {
            let m = format!("{e:#}");
            if m.len() > MAX_MESSAGE {
                return Err(format!("a {}-byte message", m.len()));
            }
            if m.contains("root:x:0") {
                return Err(format!("a message quoting /etc/passwd: {m}"));
            }
            Ok(true)
        }
    }
}

#[test]
fn every_value_of_the_example_job_replaced_by_a_hostile_literal_is_refused_or_loads() {
    let d = job_folder();
    let text = std::fs::read_to_string(d.path().join("job.toml")).unwrap();
    let (mut cases, mut refused, mut failures) = (0, 0, Vec::new());
    for line in value_lines(&text) {
        for v in HOSTILE {
            cases += 1;
            match load(d.path(), "m.toml", &replace_value(&text, line, v)) {
                Ok(r) => refused += r as usize,
                Err(e) => failures.push(format!("line {line} = {v}: {e}")),
            }
        }
    }
    assert!(cases >= 100, "only {cases} cases");
    assert!(refused * 2 > cases, "only {refused} of {cases} refused");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(!d.path().join("PWNED").exists());
}

/// The lines and `#SBATCH` directives of every stage's script.
fn shape(job: &Job) -> Option<Vec<(usize, usize)>> {
    let p = plan(job, Path::new("/usr/bin/knitvox")).ok()?;
    let opts = SlurmOptions::default();
    Some(
        p.stages
            .iter()
            .map(|s| {
                let script = slurm_script(&p, s, &opts);
                let lines = script.lines().count();
                let directives = script.lines().filter(|l| l.starts_with("#SBATCH")).count();
                (lines, directives)
            })
            .collect(),
    )
}

fn benign_shape(dir: &Path) -> Vec<(usize, usize)> {
    let text = std::fs::read_to_string(dir.join("job.toml")).unwrap();
    let path = dir.join("benign.toml");
    std::fs::write(&path, format!("output = \"benign.out\"\n{text}")).unwrap();
    shape(&Job::load(&path).unwrap()).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn no_output_key_or_manifest_name_adds_a_line_or_directive_to_a_slurm_script(
        output in "[a-z\\n\\r\\t\\x00-\\x1f\\x7f $`'\"\\\\;#%()]{1,24}",
        stem in "[a-z\\n\\r\\t\\x01-\\x1f\\x7f $`'\";#%()]{1,16}",
    ) {
        let d = job_folder();
        let benign = benign_shape(d.path());
        let text = std::fs::read_to_string(d.path().join("job.toml")).unwrap();
        let quoted = toml::Value::String(output.clone()).to_string();
        let path = d.path().join(format!("{}.toml", stem.replace('/', "_")));
        if std::fs::write(&path, format!("output = {quoted}\n{text}")).is_err() {
            return Ok(()); // a name the file system refuses
        }
        if let Ok(job) = Job::load(&path) {
            if let Some(s) = shape(&job) {
                prop_assert_eq!(s, benign.clone(), "output {:?}, stem {:?}", output, stem);
            }
        }
    }
}

#[test]
fn a_newline_in_the_output_key_is_refused_when_the_plan_is_built() {
    let d = job_folder();
    let text = std::fs::read_to_string(d.path().join("job.toml")).unwrap();
    let path: PathBuf = d.path().join("m.toml");
    std::fs::write(&path, format!("output = \"o\\ntouch PWNED\\n#\"\n{text}")).unwrap();
    let job = Job::load(&path).unwrap();
    let e = plan(&job, Path::new("/usr/bin/knitvox"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("output"), "{e}");
    assert!(e.len() < 1000, "{e}");
}
