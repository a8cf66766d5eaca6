//! The terminal side of long commands: progress (a bar on a terminal, a
//! line per step otherwise, JSON events with `--json`), warnings on stderr,
//! the final JSON report, and SIGTERM relayed to a stage that can stop
//! cleanly.

/// Prints warnings on stderr (`warning: ...`) and returns them for a
/// `--json` report's `warnings` array.
pub(crate) fn warn_all(warnings: Vec<String>) -> Vec<String> {
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    warnings
}

/// How a [`Console`] shows frame progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ProgressMode {
    /// Nothing.
    Off,
    /// A progress bar on stderr (a terminal).
    Bar,
    /// A plain line per frame on stderr (no terminal: farm logs).
    Lines,
    /// A JSON line per frame on stdout (`--json`).
    Json,
}

impl ProgressMode {
    /// `--progress` / `--no-progress` of a command whose stdout holds only
    /// its report (`--json` or not): a bar on a terminal (or with
    /// `--progress`), else a plain line per frame on stderr (farm logs),
    /// nothing with `--no-progress`.
    pub fn on_stderr(progress: bool, no_progress: bool) -> ProgressMode {
        use std::io::IsTerminal;
        if no_progress {
            ProgressMode::Off
        } else if progress || std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        }
    }

    /// `--json`: JSON lines; else a bar on a terminal, plain lines without.
    pub fn of(json: bool) -> ProgressMode {
        use std::io::IsTerminal;
        if json {
            ProgressMode::Json
        } else if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        }
    }
}

/// The CLI's [`crate::pipeline::Observer`]: warnings on stderr
/// (`warning: ...`, kept for a `--json` report's `warnings` array) and
/// frame progress ([`ProgressMode`]).
pub(crate) struct Console {
    pub warnings: Vec<String>,
    bar: Option<indicatif::ProgressBar>,
    mode: ProgressMode,
    label: String,
}

impl Console {
    /// A console; with `show`, a progress bar of `frames` frames labelled
    /// `label` (`label {bar} pos/len frames [elapsed < eta]`).
    pub fn new(show: bool, frames: usize, label: &str) -> Console {
        let mode = if show {
            ProgressMode::Bar
        } else {
            ProgressMode::Off
        };
        Console::with_mode(mode, frames, label)
    }

    /// A console showing progress as `mode` says.
    /// Runs `stage` with this console as its observer; returns its result
    /// and the warnings, with the progress bar finished (so a report can be
    /// printed after it).
    pub fn run<S: crate::pipeline::Stage>(
        mut self,
        stage: &S,
    ) -> (Result<S::Report, crate::pipeline::Error>, Vec<String>) {
        let result = stage.run(&mut self);
        (result, std::mem::take(&mut self.warnings))
    }

    pub fn with_mode(mode: ProgressMode, frames: usize, label: &str) -> Console {
        Console {
            warnings: Vec::new(),
            bar: (mode == ProgressMode::Bar).then(|| frame_bar(frames, label)),
            mode,
            label: label.to_string(),
        }
    }
}

impl Drop for Console {
    fn drop(&mut self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

impl crate::pipeline::Observer for Console {
    fn warning(&mut self, message: &str) {
        eprintln!("warning: {message}");
        self.warnings.push(message.to_string());
    }
    fn frames(&mut self, done: usize, total: usize) {
        if let Some(b) = &self.bar {
            b.set_length(total as u64);
            b.set_position(done as u64);
        }
    }
    fn frame(&mut self, p: &crate::pipeline::FrameProgress) {
        match self.mode {
            ProgressMode::Off => {}
            ProgressMode::Bar => self.frames(p.done, p.total),
            ProgressMode::Json => print_event("frame", p),
            ProgressMode::Lines => {
                // Statistics a stage does not have are left out.
                let opt = |x: Option<f64>, what: &str, unit: &str| {
                    x.map_or(String::new(), |x| format!(", {what} {x:.3e} {unit}"))
                };
                eprintln!(
                    "{}: frame {} ({}/{}) {:.0} ms{}{}",
                    self.label,
                    p.frame,
                    p.done,
                    p.total,
                    p.ms,
                    opt(p.residual, "residual", "N"),
                    opt(p.penetration_m, "penetration", "m")
                );
            }
        }
    }
    fn step(&mut self, message: &str) {
        match self.mode {
            ProgressMode::Off => {}
            ProgressMode::Json => print_event("step", &serde_json::json!({ "step": message })),
            ProgressMode::Bar => match &self.bar {
                Some(b) => b.println(format!("{}: {message}", self.label)),
                None => eprintln!("{}: {message}", self.label),
            },
            ProgressMode::Lines => eprintln!("{}: {message}", self.label),
        }
    }
    fn iteration(&mut self, p: &crate::fit::elastic::FitProgress) {
        match self.mode {
            ProgressMode::Off | ProgressMode::Bar => {}
            ProgressMode::Json => print_event("iteration", p),
            // The damping search's loss is an RMS in yarn diameters.
            ProgressMode::Lines if p.stage == "damping" => eprintln!(
                "{}: {} damping evaluation {} ({}) RMS {:.4} yarn diameters, {:.0} ms",
                self.label, p.sample, p.iteration, p.method, p.loss, p.ms
            ),
            // The stiffening stage's loss is the relative clamp-force misfit.
            ProgressMode::Lines if p.stage == "stiffening" => eprintln!(
                "{}: {} {} evaluation {} ({}) force misfit {:.4}, {:.0} ms",
                self.label, p.sample, p.stage, p.iteration, p.method, p.loss, p.ms
            ),
            ProgressMode::Lines => eprintln!(
                "{}: {} {} iteration {} ({}) loss {:.4e} m^3, {:.0} ms",
                self.label, p.sample, p.stage, p.iteration, p.method, p.loss, p.ms
            ),
        }
    }
}

/// One progress object as a JSON line on stdout with its `event` name.
fn print_event(event: &str, p: &impl serde::Serialize) {
    use std::io::Write;
    let mut v = serde_json::to_value(p).unwrap_or_default();
    if let Some(o) = v.as_object_mut() {
        o.insert("event".into(), event.into());
    }
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{v}");
    let _ = out.flush();
}

/// SIGTERM while `run` or `simulate` works: see [`relay_sigterm`].
static INTERRUPT: crate::pipeline::Interrupt = crate::pipeline::Interrupt::new();

extern "C" fn on_sigterm(_: libc::c_int) {
    if !INTERRUPT.request() {
        // No stage can stop cleanly: die of SIGTERM as without a handler.
        // SAFETY: signal and raise are async-signal-safe.
        unsafe {
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
            libc::raise(libc::SIGTERM);
        }
    }
}

/// From here on SIGTERM makes a running (armed) shot checkpoint and stop
/// (exit 75, resumed by the next run); otherwise it ends the process.
pub(crate) fn relay_sigterm() -> &'static crate::pipeline::Interrupt {
    #[cfg(unix)]
    // SAFETY: installs an async-signal-safe handler (atomics, signal, raise).
    unsafe {
        libc::signal(
            libc::SIGTERM,
            on_sigterm as extern "C" fn(libc::c_int) as libc::sighandler_t,
        );
    }
    &INTERRUPT
}

/// Prints a `--json` report as the last line of stdout (after any
/// progress lines), with `"event": "report"` and `extra` fields.
pub(crate) fn print_json_report(
    report: &impl serde::Serialize,
    extra: &[(&str, serde_json::Value)],
) -> anyhow::Result<()> {
    let mut v = serde_json::to_value(report)?;
    if let Some(o) = v.as_object_mut() {
        o.insert("event".into(), "report".into());
        for (k, x) in extra {
            o.insert((*k).into(), x.clone());
        }
    }
    println!("{}", serde_json::to_string(&v)?);
    Ok(())
}

/// Whether a raw command line asks for `--json` (before any `--`): errors
/// are then a JSON object on stdout, for every command, parse errors too.
pub fn wants_json(args: impl IntoIterator<Item = std::ffi::OsString>) -> bool {
    args.into_iter()
        .skip(1)
        .take_while(|a| a != "--")
        .any(|a| a == "--json")
}

fn frame_bar(frames: usize, label: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new(frames as u64);
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{label} {{bar:40}} {{pos}}/{{len}} frames [{{elapsed_precise}} < {{eta}}]"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    b
}
