//! A `knitvox watch` process for the watch tests, its JSON log collected.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use knitvox::io::{self, WriteOptions};
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};
use serde_json::Value;

/// A small knit swatch (courses x 4 wales) in the format of `ext`.
pub fn swatch_bytes(courses: usize, ext: &str) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(format!("s.{ext}"));
    let yarns = knit_swatch(&SwatchParams {
        courses,
        wales: 4,
        with_ring: false,
        points_per_loop: 12,
        ..SwatchParams::default()
    });
    io::write_path(&p, &yarns, None, &WriteOptions::default()).unwrap();
    std::fs::read(p).unwrap()
}

/// Names of a folder's entries, sorted.
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// The jobs in a `done/` folder, without the records of their warnings
/// (`NAME.warnings.json`, e.g. a shot's unconverged PD steps).
pub fn done_jobs(done: &Path) -> Vec<String> {
    names(done)
        .into_iter()
        .filter(|n| !n.ends_with(".warnings.json"))
        .collect()
}

/// A running daemon whose JSON log lines are collected; killed on drop.
pub struct Daemon {
    pub child: Child,
    log: Arc<Mutex<Vec<Value>>>,
}

impl Daemon {
    /// `knitvox watch ROOT ARGS...`.
    pub fn spawn(root: &Path, args: &[&str]) -> Daemon {
        let mut child = Command::new(super::knitvox_bin())
            .arg("watch")
            .arg(root)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let out = child.stdout.take().unwrap();
        let log = Arc::new(Mutex::new(Vec::new()));
        let sink = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { break };
                let v: Value = serde_json::from_str(&line)
                    .unwrap_or_else(|e| panic!("log line is not JSON ({e}): {line}"));
                sink.lock().unwrap().push(v);
            }
        });
        Daemon { child, log }
    }

    /// The log events of one kind.
    pub fn events(&self, kind: &str) -> Vec<Value> {
        let log = self.log.lock().unwrap();
        log.iter().filter(|v| v["event"] == kind).cloned().collect()
    }

    /// The jobs of the events of one kind, sorted.
    pub fn jobs(&self, kind: &str) -> Vec<String> {
        let mut v: Vec<String> = self
            .events(kind)
            .iter()
            .map(|e| e["job"].as_str().unwrap().to_string())
            .collect();
        v.sort();
        v
    }

    /// Waits until `done` holds (checked every 20 ms); false on timeout.
    pub fn wait_for(&self, timeout: Duration, done: impl Fn(&Daemon) -> bool) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if done(self) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }

    /// The whole log, a line per event.
    pub fn dump(&self) -> String {
        let log = self.log.lock().unwrap();
        log.iter().map(|v| format!("{v}\n")).collect()
    }

    pub fn signal(&self, sig: libc::c_int) {
        // SAFETY: signalling our own child process.
        unsafe { libc::kill(self.child.id() as libc::pid_t, sig) };
    }

    /// Waits for the process to exit; its exit code.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<i32> {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Some(s) = self.child.try_wait().unwrap() {
                // Let the reader thread drain the pipe.
                std::thread::sleep(Duration::from_millis(100));
                return s.code();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
