//! The watch-folder daemon (`knitvox watch ROOT`; schemas/watch.md).
//!
//! Sources -> debounced batches -> workers, as watchexec splits it: the
//! main loop scans `inbox/` (every `poll`, or early when inotify hints at a
//! change), takes drops whose files held still across two scans, claims
//! each in `work/` ([`claims`]) and hands it to a worker thread, which runs
//! it as a `knitvox run` child process ([`worker`]) so that a crash inside
//! libhdf5 on an untrusted file kills only the child. A bad job is logged
//! and filed under `failed/`; only a broken ROOT stops the daemon.

pub mod claims;
mod paths;
pub mod scan;
pub mod status;
pub mod worker;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;

use self::claims::{Claim, Owner};
pub use self::paths::Paths;
use self::scan::{Drop, Readiness, Signature, Stability};
use self::worker::{Outcome, RunResult};
use crate::io::IoError;
use crate::pipeline::{Error, ErrorClass};

/// The daemon's settings (`knitvox watch` flags).
#[derive(Debug, Clone)]
pub struct Config {
    /// The watched folder (holds inbox/, work/, done/, failed/, out/).
    pub root: PathBuf,
    /// The knitvox binary the jobs run with (`run JOB.toml --json`).
    pub exe: PathBuf,
    /// Rescan interval (s) [default 2]: the truth, inotify only hints.
    pub poll: Duration,
    /// A drop is taken when its files' sizes and mtimes held across two
    /// scans at least this far apart (s) [default 2; the CLI makes it 60 on
    /// a network filesystem, whose attribute cache hides changes].
    pub settle: Duration,
    /// Jobs run at once [default 1].
    pub workers: usize,
    /// Process what is there, then exit.
    pub once: bool,
    /// Claim heartbeat period (s) [default 2].
    pub heartbeat: Duration,
    /// A claim without heartbeat for this long is taken over (s) [default 3 heartbeats].
    pub stale_after: Duration,
    /// Extra runs of a job that failed transiently (exit 75) [default 2].
    pub retries: u32,
    /// Wait before retry n is n times this (s) [default 2].
    pub retry_delay: Duration,
    /// After SIGTERM, running jobs may finish for this long before they are
    /// sent SIGTERM (checkpoint and stop) (s) [default 30].
    pub grace: Duration,
    /// Use inotify as a hint (off on network filesystems) [default true].
    pub inotify: bool,
    /// Folders outside ROOT that jobs may read (each child gets them as
    /// `--allow-root DIR`; absolute paths).
    pub allow_roots: Vec<PathBuf>,
    /// The memory budget of the whole daemon (bytes): each child gets
    /// `--max-memory` of this divided by `workers` [default: none given,
    /// each child takes its own default].
    pub max_memory: Option<u64>,
}

impl Config {
    /// The defaults for `root`, running jobs with `exe`.
    pub fn new(root: PathBuf, exe: PathBuf) -> Config {
        let heartbeat = Duration::from_secs(2);
        Config {
            root,
            exe,
            poll: Duration::from_secs(2),
            settle: Duration::from_secs(2),
            workers: 1,
            once: false,
            heartbeat,
            stale_after: heartbeat * 3,
            retries: 2,
            retry_delay: Duration::from_secs(2),
            grace: Duration::from_secs(30),
            inotify: true,
            allow_roots: Vec::new(),
            max_memory: None,
        }
    }

    /// The memory budget of one child: the daemon's over its workers.
    pub fn child_max_memory(&self) -> Option<u64> {
        self.max_memory
            .map(|m| (m / self.workers.max(1) as u64).max(1))
    }
}

/// One log line (JSON with an `event` field; schemas/watch.md, "Log").
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    Started {
        root: PathBuf,
        host: String,
        pid: u32,
        workers: usize,
        poll_s: f64,
        settle_s: f64,
        stale_after_s: f64,
        inotify: bool,
        /// Each child's `--max-memory` (bytes), where the daemon has a budget.
        child_max_memory: Option<u64>,
        allow_roots: Vec<PathBuf>,
    },
    /// A new drop was claimed.
    Claimed {
        job: String,
        entries: Vec<String>,
    },
    /// A job left in work/ by a dead, stopped or lost daemon was taken over.
    Takeover {
        job: String,
        generation: u64,
        previous_host: Option<String>,
        previous_pid: Option<u32>,
        heartbeat_age_s: Option<f64>,
        released: bool,
    },
    JobStarted {
        job: String,
        attempt: u32,
        pid: u32,
    },
    /// A stage of the child's report.
    Stage {
        job: String,
        name: String,
        status: String,
        ms: f64,
    },
    Retry {
        job: String,
        attempt: u32,
        class: ErrorClass,
        message: String,
        delay_s: f64,
    },
    Done {
        job: String,
        ms: f64,
        output: PathBuf,
    },
    Failed {
        job: String,
        class: ErrorClass,
        exit_code: u8,
        message: String,
        file: Option<String>,
        place: Option<String>,
    },
    /// Stopped by this daemon (stop, lost claim): left in work/ for the next owner.
    Interrupted {
        job: String,
    },
    /// Another daemon took the job over (this one missed its heartbeats).
    Lost {
        job: String,
    },
    /// Something the daemon works around (an inotify error: full rescan),
    /// or a warning of a job's run (`job` set).
    Warning {
        #[serde(skip_serializing_if = "Option::is_none")]
        job: Option<String>,
        message: String,
    },
    /// A run failed as bad input while the drop's files were still
    /// changing (or younger than the settle time): not filed; run again
    /// once they held still.
    NotReady {
        job: String,
        attempt: u32,
        message: String,
    },
    /// The job could not be filed away, persistently: left in work/NAME
    /// with `parked.json`, not taken again until that file is removed.
    Parked {
        job: String,
        message: String,
    },
    Stopping {
        running: Vec<String>,
    },
    Stopped {
        done: usize,
        failed: usize,
    },
}

/// What a daemon run did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Summary {
    pub done: usize,
    pub failed: usize,
    pub interrupted: usize,
    pub parked: usize,
}

/// A job handed to a worker.
struct Task {
    name: String,
    claim: Claim,
    /// The drop, for a new claim; `None` for a takeover (read from work/).
    drop: Option<Drop>,
    /// The signature of each of the drop's entries when it was claimed.
    signature: Option<BTreeMap<String, Signature>>,
}

/// A running job as the main loop and the worker share it.
#[derive(Default)]
struct Running {
    child: Option<u32>,
    /// This daemon signalled the child (stop or lost claim).
    signalled: bool,
}

enum Msg {
    /// inotify saw something: scan now.
    Wake,
    Finished(String, JobEnd),
}

enum JobEnd {
    Done,
    Failed,
    Interrupted,
    Parked,
}

struct Shared<'a> {
    cfg: &'a Config,
    paths: Paths,
    running: Mutex<HashMap<String, Running>>,
    stop: &'a AtomicUsize,
    log: &'a (dyn Fn(&Event) + Sync),
}

fn identity() -> Owner {
    Owner {
        host: claims::host_name(),
        pid: std::process::id(),
        started: claims::unix_now(),
        claimed: 0.0,
        generation: 0,
        released: false,
    }
}

/// Runs the daemon until `stop` counts a signal and the running jobs are
/// over (or, with `once`, until the inbox holds nothing more to take).
/// The first stop stops taking work and lets jobs finish for `grace`; a
/// second (or the end of the grace) sends the children SIGTERM. Errors
/// only for a ROOT that cannot be used.
pub fn run(
    cfg: &Config,
    stop: &AtomicUsize,
    log: &(dyn Fn(&Event) + Sync),
) -> Result<Summary, Error> {
    let paths = Paths::new(&cfg.root);
    paths.create()?;
    let me = identity();
    let (tx, rx) = mpsc::channel::<Msg>();
    let watcher = if cfg.inotify {
        hint_watcher(&paths.inbox, tx.clone(), log)
    } else {
        None
    };
    log(&Event::Started {
        root: cfg.root.clone(),
        host: me.host.clone(),
        pid: me.pid,
        workers: cfg.workers,
        poll_s: cfg.poll.as_secs_f64(),
        settle_s: cfg.settle.as_secs_f64(),
        stale_after_s: cfg.stale_after.as_secs_f64(),
        inotify: watcher.is_some(),
        child_max_memory: cfg.child_max_memory(),
        allow_roots: cfg.allow_roots.clone(),
    });
    let shared = Shared {
        cfg,
        paths,
        running: Mutex::new(HashMap::new()),
        stop,
        log,
    };
    let (task_tx, task_rx) = mpsc::channel::<Task>();
    let task_rx = Arc::new(Mutex::new(task_rx));
    let summary = std::thread::scope(|s| {
        for _ in 0..cfg.workers.max(1) {
            let (rx, tx, shared) = (task_rx.clone(), tx.clone(), &shared);
            s.spawn(move || loop {
                let task = rx.lock().map(|r| r.recv());
                let Ok(Ok(task)) = task else { break };
                let name = task.name.clone();
                let end = process(shared, task);
                if tx.send(Msg::Finished(name, end)).is_err() {
                    break;
                }
            });
        }
        let r = main_loop(&shared, &me, &rx, &task_tx);
        drop(task_tx); // workers end when the queue closes
        r
    });
    drop(watcher);
    log(&Event::Stopped {
        done: summary.done,
        failed: summary.failed,
    });
    Ok(summary)
}

/// inotify on the inbox, as a hint only: any event, error or overflow
/// means "scan now" (every scan is a full scan).
fn hint_watcher(
    inbox: &Path,
    tx: mpsc::Sender<Msg>,
    log: &(dyn Fn(&Event) + Sync),
) -> Option<notify::RecommendedWatcher> {
    use notify::Watcher;
    let tx = Mutex::new(tx);
    let handler = move |e: notify::Result<notify::Event>| {
        // Our own scans open files and folders (access events): no news.
        if matches!(&e, Ok(ev) if ev.kind.is_access() && !ev.need_rescan()) {
            return;
        }
        if let Ok(tx) = tx.lock() {
            let _ = tx.send(Msg::Wake);
        }
    };
    let mut w = match notify::recommended_watcher(handler) {
        Ok(w) => w,
        Err(e) => {
            log(&Event::Warning {
                job: None,
                message: format!("inotify unavailable ({e}): polling only"),
            });
            return None;
        }
    };
    match w.watch(inbox, notify::RecursiveMode::Recursive) {
        Ok(()) => Some(w),
        Err(e) => {
            log(&Event::Warning {
                job: None,
                message: format!("cannot watch {} ({e}): polling only", inbox.display()),
            });
            None
        }
    }
}

fn main_loop(
    sh: &Shared,
    me: &Owner,
    rx: &mpsc::Receiver<Msg>,
    tasks: &mpsc::Sender<Task>,
) -> Summary {
    let cfg = sh.cfg;
    let mut summary = Summary::default();
    let mut stability = Stability::default();
    let mut claims: HashMap<String, Claim> = HashMap::new();
    let mut next_scan = Instant::now();
    let mut next_beat = Instant::now() + cfg.heartbeat;
    let mut stopping: Option<Instant> = None;
    let mut forwarded = false;
    loop {
        let now = Instant::now();
        let signals = sh.stop.load(Ordering::SeqCst);
        if signals > 0 && stopping.is_none() {
            stopping = Some(now + cfg.grace);
            (sh.log)(&Event::Stopping {
                running: claims.keys().cloned().collect(),
            });
        }
        if let Some(deadline) = stopping {
            if !forwarded && (signals > 1 || now >= deadline) {
                signal_children(sh, libc::SIGTERM);
                forwarded = true;
            }
            if claims.is_empty() {
                break;
            }
        }
        if now >= next_beat {
            heartbeat(sh, &claims);
            next_beat = now + cfg.heartbeat;
        }
        if stopping.is_none() && now >= next_scan {
            let pending = scan(sh, me, &mut stability, &mut claims, tasks);
            next_scan = pending.unwrap_or(now + cfg.poll).min(now + cfg.poll);
            if cfg.once && claims.is_empty() && pending.is_none() {
                break;
            }
        }
        // No scans while stopping: only heartbeats and finished jobs matter.
        let mut wake = next_beat.min(now + Duration::from_millis(250));
        if stopping.is_none() {
            wake = wake.min(next_scan);
        }
        let first = rx.recv_timeout(wake.saturating_duration_since(Instant::now()));
        // Handle everything queued: a burst of events makes one scan.
        for msg in first
            .into_iter()
            .chain(std::iter::from_fn(|| rx.try_recv().ok()))
        {
            match msg {
                Msg::Wake => next_scan = next_scan.min(Instant::now()),
                Msg::Finished(name, end) => {
                    claims.remove(&name);
                    match end {
                        JobEnd::Done => summary.done += 1,
                        JobEnd::Failed => summary.failed += 1,
                        JobEnd::Interrupted => summary.interrupted += 1,
                        JobEnd::Parked => summary.parked += 1,
                    }
                    next_scan = Instant::now(); // a worker is free
                }
            }
        }
    }
    summary
}

fn signal_children(sh: &Shared, sig: libc::c_int) {
    if let Ok(mut r) = sh.running.lock() {
        for run in r.values_mut() {
            if let Some(pid) = run.child {
                run.signalled = true;
                // SAFETY: kill has no memory effects; the pid is our own child.
                unsafe { libc::kill(pid as libc::pid_t, sig) };
            }
        }
    }
}

/// Refreshes every held claim; a lost one's child is stopped.
fn heartbeat(sh: &Shared, claims: &Claims) {
    for (name, c) in claims {
        if !matches!(c.heartbeat(), Ok(false)) {
            continue;
        }
        let Ok(mut r) = sh.running.lock() else {
            continue;
        };
        let Some(run) = r.get_mut(name).filter(|run| !run.signalled) else {
            continue; // told already
        };
        run.signalled = true;
        if let Some(pid) = run.child {
            // SAFETY: as in signal_children.
            unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
        }
        (sh.log)(&Event::Lost { job: name.clone() });
    }
}

/// Whether a claim's owner is a dead process on this host (taken over at
/// once, without waiting for its heartbeat to go stale).
fn owner_dead_here(owner: &Owner, me: &Owner) -> bool {
    if owner.host != me.host {
        return false;
    }
    if owner.pid == me.pid {
        return owner.started != me.started;
    }
    // SAFETY: signal 0 only checks that the process exists.
    let alive = unsafe { libc::kill(owner.pid as libc::pid_t, 0) } == 0
        || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
    !alive
}

/// Hands a claimed job to the workers.
fn dispatch(
    sh: &Shared,
    tasks: &mpsc::Sender<Task>,
    claims: &mut Claims,
    claim: Claim,
    drop: Option<Drop>,
    signature: Option<BTreeMap<String, Signature>>,
) {
    let name = claim
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    claims.insert(name.clone(), claim.clone());
    if let Ok(mut r) = sh.running.lock() {
        r.insert(name.clone(), Running::default());
    }
    let _ = tasks.send(Task {
        name,
        claim,
        drop,
        signature,
    });
}

type Claims = HashMap<String, Claim>;

/// One full scan: takes over abandoned jobs in work/, then claims the
/// stable drops of the inbox, while workers are free. Returns when to look
/// again for drops still settling.
fn scan(
    sh: &Shared,
    me: &Owner,
    stability: &mut Stability,
    claims: &mut Claims,
    tasks: &mpsc::Sender<Task>,
) -> Option<Instant> {
    // Abandoned jobs first: they were taken in before anything new.
    take_over_abandoned(sh, me, claims, tasks);
    take_new_drops(sh, me, stability, claims, tasks)
}

fn free(sh: &Shared, claims: &Claims) -> bool {
    claims.len() < sh.cfg.workers.max(1)
}

/// Takes over the jobs in work/ whose claim is stale, released, or held by
/// a dead process on this host.
fn take_over_abandoned(sh: &Shared, me: &Owner, claims: &mut Claims, tasks: &mpsc::Sender<Task>) {
    for (name, is_dir) in scan::list(&sh.paths.work).unwrap_or_default() {
        if !is_dir || !free(sh, claims) {
            continue;
        }
        let dir = sh.paths.work.join(&name);
        if name.starts_with('.') {
            clean_removing(&dir, sh.cfg.stale_after);
            continue;
        }
        if claims.contains_key(&name) || dir.join(worker::PARKED).exists() {
            continue; // running here, or parked for the operator
        }
        let dead = claims::current(&dir)
            .ok()
            .flatten()
            .and_then(|c| c.owner)
            .is_some_and(|o| owner_dead_here(&o, me));
        let stale = if dead {
            Duration::ZERO
        } else {
            sh.cfg.stale_after
        };
        if let Ok(Some((claim, prev))) = claims::take_over(&dir, me, stale) {
            let owner = prev.as_ref().and_then(|p| p.owner.clone());
            (sh.log)(&Event::Takeover {
                job: name.clone(),
                generation: claim.owner.generation,
                previous_host: owner.as_ref().map(|o| o.host.clone()),
                previous_pid: owner.as_ref().map(|o| o.pid),
                heartbeat_age_s: prev.as_ref().map(|p| p.age.as_secs_f64()),
                released: owner.is_some_and(|o| o.released),
            });
            dispatch(sh, tasks, claims, claim, None, None);
        }
    }
}

/// Claims the inbox's drops that held still across two scans; returns when
/// to look again at those still settling.
fn take_new_drops(
    sh: &Shared,
    me: &Owner,
    stability: &mut Stability,
    claims: &mut Claims,
    tasks: &mpsc::Sender<Task>,
) -> Option<Instant> {
    let inbox = &sh.paths.inbox;
    let entries = match scan::list(inbox) {
        Ok(e) => e,
        Err(e) => {
            (sh.log)(&Event::Warning {
                job: None,
                message: format!("cannot list {}: {e}", inbox.display()),
            });
            return None;
        }
    };
    stability.retain(&entries);
    let mut drops = scan::classify(&entries, |n| std::fs::read_to_string(inbox.join(n)).ok());
    // A drop keeps the name it was given while it waits (its namesake may
    // have left the inbox meanwhile).
    scan::unique_names(&mut drops, |first, _| stability.names.get(first).cloned());
    for d in &drops {
        if let Some(first) = d.entries().into_iter().next() {
            stability.names.insert(first, d.name.clone());
        }
    }
    let now = Instant::now();
    let mut pending: Option<Instant> = None;
    for d in drops.into_iter().filter(Drop::runnable) {
        if claims.contains_key(&d.name) || sh.paths.work.join(&d.name).exists() {
            continue; // a job of that name is in work/: after it
        }
        let mut ready = true;
        let mut signature = BTreeMap::new();
        for e in d.entries() {
            match scan::signature(&inbox.join(&e)) {
                Some(sig) => {
                    signature.insert(e.clone(), sig.clone());
                    if let Readiness::Settling(at) = stability.observe(&e, sig, now, sh.cfg.settle)
                    {
                        ready = false;
                        pending = Some(pending.map_or(at, |p: Instant| p.min(at)));
                    }
                }
                None => ready = false,
            }
        }
        if !ready || !free(sh, claims) {
            continue;
        }
        match claims::claim_new(&sh.paths.work, &d.name, me) {
            Ok(Some(claim)) => {
                (sh.log)(&Event::Claimed {
                    job: d.name.clone(),
                    entries: d.entries(),
                });
                dispatch(sh, tasks, claims, claim, Some(d), Some(signature));
            }
            Ok(None) => {}
            Err(e) => (sh.log)(&Event::Warning {
                job: None,
                message: format!("cannot claim {}: {e}", d.name),
            }),
        }
    }
    pending
}

/// Removes a hidden `.NAME.removing.PID` folder left by a daemon that died
/// while removing it.
fn clean_removing(dir: &Path, stale_after: Duration) {
    let name = dir.file_name().unwrap_or_default().to_string_lossy();
    let old = std::fs::metadata(dir)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.elapsed().ok())
        .is_some_and(|a| a > stale_after);
    if name.contains(".removing.") && old {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// A worker's whole job: take in, run (with retries), file away.
fn process(sh: &Shared, task: Task) -> JobEnd {
    let dir = worker::job_dir(&sh.paths, &task.name);
    let end = match run_job(sh, &task, &dir) {
        Ok(end) => end,
        Err(f) => {
            let outcome = Outcome::Failed(f);
            file(sh, &task, &dir, &outcome, Instant::now())
        }
    };
    if let Ok(mut r) = sh.running.lock() {
        r.remove(&task.name);
    }
    end
}

/// A job whose drop was still changing when it failed as bad input is run
/// again once the drop holds still, for as long as this after its claim
/// (a long copy over a slow share comes in bursts: measured, a PLY copied
/// in 14 pieces 3 s apart outlasted a count of 10 runs and was filed as
/// failed mid-copy), and at most [`NOT_READY_RUNS`] times; then a failure
/// is filed as it is.
const NOT_READY_WINDOW: Duration = Duration::from_secs(30 * 60);
const NOT_READY_RUNS: u32 = 1000;

fn run_job(sh: &Shared, task: &Task, dir: &Path) -> Result<JobEnd, worker::Failure> {
    let name = &task.name;
    let internal = |e: IoError| {
        let class = ErrorClass::from(e.class());
        worker::failure(name, class, e.to_string(), None)
    };
    // A previous owner died while filing: finish its filing.
    if let Some(outcome) = worker::recorded_outcome(dir) {
        return Ok(file(sh, task, dir, &outcome, Instant::now()));
    }
    let drop = match &task.drop {
        Some(d) => d.clone(),
        None => match worker::recorded_drop(dir) {
            // Entries a dead owner had not moved yet are still in the inbox.
            Some(d) => d,
            None => {
                // Died before recording the drop: nothing left the inbox.
                let _ = worker::remove_tree(dir);
                return Ok(JobEnd::Interrupted);
            }
        },
    };
    // Links are refused before anything is read; the drop still moves in
    // (a rename, never followed), so it is filed and not taken again.
    let links = worker::check_links(&sh.paths, dir, &drop);
    if !worker::take_in(&sh.paths, dir, &drop).map_err(internal)? {
        // Another daemon took the drop under another name first.
        let _ = worker::remove_tree(dir);
        return Ok(JobEnd::Interrupted);
    }
    links?;
    let stopped = || sh.stop.load(Ordering::SeqCst) > 0;
    let interrupted = || {
        let _ = task.claim.release();
        (sh.log)(&Event::Interrupted { job: name.clone() });
        Ok(JobEnd::Interrupted)
    };
    let mut claimed = task.signature.clone();
    let t = Instant::now();
    let mut attempt = 0;
    let mut not_ready = 0;
    // A bad-input failure while the drop was still changing: wait until it
    // holds still, then run it again (a bounded number of times).
    let mut still_changing = |f: &worker::Failure, attempt: u32| -> Option<bool> {
        if f.class != ErrorClass::BadInput
            || not_ready >= NOT_READY_RUNS
            || t.elapsed() > NOT_READY_WINDOW
            || !worker::still_changing(dir, &drop, claimed.as_ref(), sh.cfg.settle, stopped)
        {
            return None;
        }
        not_ready += 1;
        (sh.log)(&Event::NotReady {
            job: name.clone(),
            attempt,
            message: f.message.clone(),
        });
        claimed = Some(worker::wait_still(dir, &drop, sh.cfg.settle, stopped));
        Some(stopped())
    };
    let reads = loop {
        match worker::derive_manifest(&sh.paths, dir, &drop, &sh.cfg.allow_roots) {
            Ok(r) => break r,
            Err(f) => match still_changing(&f, 0) {
                Some(false) => continue,
                Some(true) => return interrupted(),
                None => return Err(f),
            },
        }
    };
    let args = child_args(sh, &reads);
    loop {
        attempt += 1;
        let result = run_child(sh, name, dir, attempt, &args).map_err(|e| {
            worker::failure(
                name,
                ErrorClass::Unavailable,
                format!("cannot start {}: {e}", sh.cfg.exe.display()),
                None,
            )
        })?;
        let warnings = match &result {
            RunResult::Done(_, w) => w.clone(),
            RunResult::Failed(f) => f.warnings.clone(),
            RunResult::Signalled => Vec::new(),
        };
        for w in warnings {
            (sh.log)(&Event::Warning {
                job: Some(name.clone()),
                message: w,
            });
        }
        match result {
            RunResult::Done(stages, warnings) => {
                for s in &stages {
                    (sh.log)(&Event::Stage {
                        job: name.clone(),
                        name: s.name.clone(),
                        status: s.status.clone(),
                        ms: s.ms,
                    });
                }
                let outcome = Outcome::Done { stages, warnings };
                return Ok(file(sh, task, dir, &outcome, t));
            }
            RunResult::Signalled => return interrupted(),
            RunResult::Failed(f)
                if f.class.retryable() && attempt <= sh.cfg.retries && !stopped() =>
            {
                let delay = sh.cfg.retry_delay * attempt;
                (sh.log)(&Event::Retry {
                    job: name.clone(),
                    attempt,
                    class: f.class,
                    message: f.message.clone(),
                    delay_s: delay.as_secs_f64(),
                });
                worker::sleep_unless(delay, stopped);
                if stopped() {
                    // Stopping: no new attempt; the next owner retries.
                    return interrupted();
                }
            }
            RunResult::Failed(mut f) => {
                match still_changing(&f, attempt) {
                    Some(false) => continue,
                    Some(true) => return interrupted(),
                    None => {}
                }
                f.attempts = attempt;
                if f.file.is_none() {
                    f.file = drop.entries().into_iter().next();
                }
                return Ok(file(sh, task, dir, &Outcome::Failed(f), t));
            }
        }
    }
}

/// The child's arguments after `run job.toml --json`: its share of the
/// memory budget, the operator's allowed folders, and the inbox where a
/// top-level manifest or sidecar names files there.
fn child_args(sh: &Shared, reads: &worker::Reads) -> Vec<std::ffi::OsString> {
    let mut a: Vec<std::ffi::OsString> = Vec::new();
    if let Some(m) = sh.cfg.child_max_memory() {
        a.push("--max-memory".into());
        a.push(m.to_string().into());
    }
    let inbox = reads
        .inbox
        .then(|| std::fs::canonicalize(&sh.paths.inbox).unwrap_or_else(|_| sh.paths.inbox.clone()));
    for r in sh.cfg.allow_roots.iter().chain(inbox.as_ref()) {
        a.push("--allow-root".into());
        a.push(r.clone().into_os_string());
    }
    a
}

/// Runs the child once, its pid known to the main loop while it runs.
/// Its frame progress goes to `work/NAME/progress.json` as it comes.
fn run_child(
    sh: &Shared,
    name: &str,
    dir: &Path,
    attempt: u32,
    args: &[std::ffi::OsString],
) -> std::io::Result<RunResult> {
    let mut child = worker::spawn(&sh.cfg.exe, dir, args)?;
    let pid = child.id();
    let mut signalled = false;
    if let Ok(mut r) = sh.running.lock() {
        let run = r.entry(name.to_string()).or_default();
        run.child = Some(pid);
        signalled = run.signalled;
    }
    if signalled {
        // Stopped between two attempts.
        // SAFETY: as in signal_children.
        unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
    }
    (sh.log)(&Event::JobStarted {
        job: name.into(),
        attempt,
        pid,
    });
    let stdout = child.stdout.take();
    let stderr = child.stderr.take();
    let progress = dir.join(worker::PROGRESS);
    let (out, err) = std::thread::scope(|s| {
        let err = s.spawn(move || {
            let mut v = Vec::new();
            if let Some(mut e) = stderr {
                let _ = std::io::Read::read_to_end(&mut e, &mut v);
            }
            v
        });
        let out = stdout.map_or_else(Vec::new, |o| worker::read_progress(o, &progress, attempt));
        (out, err.join().unwrap_or_default())
    });
    let status = child.wait()?;
    let _ = std::fs::remove_file(&progress);
    let out = std::process::Output {
        status,
        stdout: out,
        stderr: err,
    };
    let signalled = sh.running.lock().map_or(true, |mut r| {
        let run = r.entry(name.to_string()).or_default();
        run.child = None;
        run.signalled
    });
    Ok(worker::result_of(name, &out, signalled))
}

/// Filing attempts before a job is parked.
const FILING_TRIES: u32 = 3;

/// Files the job under done/ or failed/ (only while the claim is held). A
/// filing error is tried again twice; one that persists parks the job.
fn file(sh: &Shared, task: &Task, dir: &Path, outcome: &Outcome, t: Instant) -> JobEnd {
    let name = &task.name;
    if !task.claim.held() {
        (sh.log)(&Event::Lost { job: name.clone() });
        return JobEnd::Interrupted;
    }
    let mut tries = 0;
    loop {
        tries += 1;
        match worker::finish(&sh.paths, dir, name, outcome) {
            Ok(_) => break,
            Err(_) if tries < FILING_TRIES => {
                worker::sleep_unless(Duration::from_millis(500) * tries, || false);
            }
            Err(e) => {
                let message = format!("cannot file the job away: {e}");
                let _ = worker::park(dir, name, &message);
                (sh.log)(&Event::Parked {
                    job: name.clone(),
                    message,
                });
                let _ = task.claim.release();
                return JobEnd::Parked;
            }
        }
    }
    match outcome {
        Outcome::Done { .. } => {
            (sh.log)(&Event::Done {
                job: name.clone(),
                ms: t.elapsed().as_secs_f64() * 1e3,
                output: sh.paths.out.join(name),
            });
            JobEnd::Done
        }
        Outcome::Failed(f) => {
            (sh.log)(&Event::Failed {
                job: name.clone(),
                class: f.class,
                exit_code: f.exit_code,
                message: f.message.clone(),
                file: f.file.clone(),
                place: f.place.clone(),
            });
            JobEnd::Failed
        }
    }
}
