#![no_main]
//! Fuzzes job manifests: any text loads to a job or a short error, never a
//! panic, and a loaded job's Slurm scripts have the same lines and
//! `#SBATCH` directives whatever bytes its names and keys hold.
use std::path::Path;

use knitvox::pipeline::job::Job;
use knitvox::pipeline::submit::{plan, slurm_script, SlurmOptions};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("knitvox-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let _ = std::fs::write(dir.join("y.bcc"), b"");
    let path = dir.join("m.toml");
    if std::fs::write(&path, text).is_err() {
        return;
    }
    match Job::load(&path) {
        Err(e) => assert!(format!("{e:#}").len() <= 4096),
        Ok(job) => {
            if let Ok(p) = plan(&job, Path::new("/usr/bin/knitvox")) {
                for s in &p.stages {
                    let script = slurm_script(&p, s, &SlurmOptions::default());
                    for l in script.lines() {
                        assert!(!l.contains('\r'), "a carriage return in {l:?}");
                    }
                    let directives = script.lines().filter(|l| l.starts_with("#SBATCH")).count();
                    assert!(directives >= 4, "{directives} directives left in\n{script}");
                }
            }
        }
    }
});
