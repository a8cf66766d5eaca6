//! `knitvox watch ROOT`: the watch-folder daemon (schemas/watch.md).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use clap::Args;

use super::parse::{parse_non_negative, parse_positive};
use super::ExitCode;
use crate::daemon::{self, Config, Event};

#[derive(Debug, Args)]
pub struct WatchArgs {
    /// The watched folder: inbox/, work/, done/, failed/, out/ (created if missing).
    pub root: PathBuf,
    /// Full rescan interval in seconds (inotify, where it works, only makes scans come sooner).
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0, value_parser = parse_positive)]
    pub poll: f64,
    /// Jobs run at once (each a `knitvox run` child process).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub workers: u32,
    /// Process what is in the inbox (and abandoned jobs in work/), then exit.
    #[arg(long, conflicts_with = "status")]
    pub once: bool,
    /// Print the queue, the claims and the done/failed counts, then exit.
    #[arg(long)]
    pub status: bool,
    /// With --status: print it as JSON. (The daemon's log is always JSON lines.)
    #[arg(long)]
    pub json: bool,
    /// A drop is taken once its files' sizes and mtimes held across two scans this many seconds apart
    /// [default: 2, or 60 when ROOT is on a network filesystem (NFS attribute caches hide changes)].
    #[arg(long, value_name = "SECONDS", value_parser = parse_non_negative)]
    pub settle: Option<f64>,
    /// Claim heartbeat period in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0, value_parser = parse_positive)]
    pub heartbeat: f64,
    /// Take over a claim whose heartbeat is older than this [default: 3 heartbeats].
    #[arg(long, value_name = "SECONDS", value_parser = parse_positive)]
    pub stale_after: Option<f64>,
    /// Extra runs of a job that failed transiently (exit 75).
    #[arg(long, default_value_t = 2)]
    pub retries: u32,
    /// After SIGTERM/SIGINT, seconds running jobs may finish before they get SIGTERM (a second signal: at once).
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0, value_parser = parse_non_negative)]
    pub grace: f64,
    /// Poll only (no inotify hint); the default on network filesystems.
    #[arg(long)]
    pub no_inotify: bool,
    /// A folder outside ROOT that jobs may read (repeatable); a job reads
    /// only its own drop (and, for a top-level manifest, the inbox) otherwise.
    #[arg(long, value_name = "DIR")]
    pub allow_root: Vec<PathBuf>,
}

/// The settle time when `--settle` is not given: 2 s, or 60 s on a
/// network filesystem, whose attribute cache can hide a growing file's
/// size and mtime for up to about a minute.
pub fn default_settle(root: &std::path::Path) -> f64 {
    if daemon::scan::network_filesystem(root) {
        60.0
    } else {
        2.0
    }
}

/// SIGTERM/SIGINT received so far (the handler only counts).
static SIGNALS: AtomicUsize = AtomicUsize::new(0);

extern "C" fn count_signal(_: libc::c_int) {
    SIGNALS.fetch_add(1, Ordering::SeqCst);
}

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(s)
}

/// `max_memory`: the global `--max-memory`, the budget of the whole
/// daemon (default: an eighth of the physical memory, at most 2 GiB), shared by the workers.
pub fn watch(a: &WatchArgs, max_memory: Option<u64>) -> anyhow::Result<ExitCode> {
    let heartbeat = secs(a.heartbeat);
    let stale_after = a.stale_after.map_or(heartbeat * 3, secs);
    let settle = a.settle.unwrap_or_else(|| default_settle(&a.root));
    if a.status {
        return status(a, settle, stale_after);
    }
    // SAFETY: the handler only touches an atomic (async-signal-safe).
    unsafe {
        let h = count_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGTERM, h);
        libc::signal(libc::SIGINT, h);
    }
    let exe = std::env::current_exe()?;
    std::fs::create_dir_all(&a.root).map_err(|source| crate::io::IoError::Write {
        path: a.root.clone(),
        source,
    })?;
    let mut allow_roots = Vec::new();
    for r in &a.allow_root {
        // The children run in work/NAME: the folders go to them absolute.
        let abs = std::fs::canonicalize(r).map_err(|e| {
            crate::pipeline::Error::Usage(format!(
                "--allow-root {}: cannot resolve the folder: {e}",
                r.display()
            ))
        })?;
        if !abs.is_dir() {
            return Err(crate::pipeline::Error::Usage(format!(
                "--allow-root {}: not a folder",
                r.display()
            ))
            .into());
        }
        allow_roots.push(abs);
    }
    let cfg = Config {
        poll: secs(a.poll),
        settle: secs(settle),
        workers: a.workers as usize,
        once: a.once,
        heartbeat,
        stale_after,
        retries: a.retries,
        grace: secs(a.grace),
        inotify: !a.no_inotify && !daemon::scan::network_filesystem(&a.root),
        allow_roots,
        max_memory: Some(max_memory.unwrap_or_else(super::budget::default_max_memory)),
        ..Config::new(a.root.clone(), exe)
    };
    let log = |e: &Event| {
        use std::io::Write;
        let mut v = serde_json::to_value(e).unwrap_or_default();
        if let Some(o) = v.as_object_mut() {
            o.insert("t".into(), daemon::claims::unix_now().into());
        }
        let mut out = std::io::stdout().lock();
        // A closed log pipe must not stop the jobs.
        let _ = writeln!(out, "{v}");
        let _ = out.flush();
    };
    daemon::run(&cfg, &SIGNALS, &log)?;
    Ok(ExitCode::Success)
}

fn status(a: &WatchArgs, settle: f64, stale_after: Duration) -> anyhow::Result<ExitCode> {
    let s = daemon::status::status(&a.root, secs(settle), stale_after)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(ExitCode::Success);
    }
    println!(
        "inbox: {} ({} stable)",
        s.inbox.len(),
        s.inbox.iter().filter(|q| q.stable).count()
    );
    for q in &s.inbox {
        let kind = serde_json::to_value(&q.kind)
            .ok()
            .and_then(|v| v.as_object()?.keys().next().cloned())
            .unwrap_or_default();
        let state = if q.stable { "stable" } else { "settling" };
        println!(
            "  {:<24} {kind:<9} {state:<9} changed {:.1} s ago",
            q.job, q.age_s
        );
    }
    println!("work: {}", s.work.len());
    for w in &s.work {
        let who = match (&w.host, w.pid) {
            (Some(h), Some(p)) => format!("{h} pid {p}"),
            _ => "-".into(),
        };
        let beat = w
            .heartbeat_age_s
            .map_or("-".into(), |a| format!("{a:.1} s ago"));
        let mut at = String::new();
        if let Some(st) = &w.stage {
            at = format!(", stage {st}");
        }
        if let (Some(f), Some(d), Some(t)) = (w.frame, w.frames_done, w.frames_total) {
            at.push_str(&format!(", frame {f} ({d}/{t})"));
        }
        println!("  {:<24} {:<9} {who}, heartbeat {beat}{at}", w.job, w.state);
    }
    println!("done: {}  failed: {}", s.done, s.failed);
    Ok(ExitCode::Success)
}
