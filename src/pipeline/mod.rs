//! Orchestration: stages that combine io and the solvers.
//!
//! # The stage contract
//!
//! A stage (embed, shapefit, export, shot; train and fit to come) is a
//! struct of typed inputs and parameters implementing [`Stage`]:
//!
//! * **Inputs are paths and parameters.** The stage reads its own inputs
//!   (`io`), so the CLI, a job manifest and a watch-folder daemon run it the
//!   same way; the CLI only parses arguments into the job, calls
//!   [`Stage::run`] and prints the report. In-memory cores (`asset::shapefit`,
//!   `simulate::simulate`, ...) stay public for tests and benchmarks.
//! * **Outputs are atomic and carry provenance.** Every file is written to a
//!   temporary and renamed into place; a stage writing several files runs
//!   inside `io::atomic::all_or_nothing`, so either all appear or none.
//!   Assets record the command, knitvox version and SHA-256 of every input
//!   file (`geom::Provenance`) and the parameters used.
//! * **Frames stream.** A stage that produces frames hands each one, as it
//!   is computed, to the shared frame writer ([`frames::FrameSink`],
//!   [`frames::YarnFrameWriter`]): a `name.####.ext` sequence numbered by
//!   frame, or one HDF5 file. No stage keeps every frame's yarns in memory.
//!   (The shot's node positions still become the output asset's time
//!   series, which `io::vtkhdf` writes in one piece.) A resumable shot
//!   (`simulate::ChunkOptions`) gives each frame file its name as soon as
//!   it is complete and checkpoints its state (`io::checkpoint`).
//! * **Progress and warnings go to an [`Observer`]** (per frame:
//!   [`FrameProgress`]); a stage never prints.
//! * **Failures are one [`Error`].** Its [`Error::class`] ([`ErrorClass`]:
//!   usage, bad input, missing, unavailable, internal, output, transient)
//!   gives the process exit code ([`ErrorClass::exit_code`]) and the retry
//!   decision ([`ErrorClass::retry`], [`ErrorClass::retryable`]) for the CLI,
//!   a daemon and a farm alike. Each stage owns its typed error, which
//!   names the file and the place, and converts it into [`Error`]
//!   ([`Error::Stage`]); [`class_of`] classifies any cause of a chain.
//! * **Solver work is a function of typed inputs** in the math modules: the
//!   shot is its setup ([`shot_setup`]: placement, pins, colliders,
//!   schedule), the time loop `sim::shot::run` (PD stepper, per-step
//!   pin/collider update, per-frame callback, statistics), and the writer.
//! * **One source per default**: parameter structs' `Default` impls (e.g.
//!   `sim::pd::PdParams`, `embed::EmbedParams`) are the defaults; scene
//!   sections and clap arguments refer to them instead of repeating numbers.
//!
//! [`job`] runs these stages from a job manifest (`knitvox run`), skipping
//! those whose inputs, parameters and upstream stages are unchanged. A shot
//! split into frame chunks, checkpointed and resumed is
//! `simulate::ChunkedShotJob` (schemas/checkpoint.md).

pub mod asset;
pub mod bake;
pub mod bench;
pub mod card;
pub mod card_transfer;
pub mod clamp_drive;
pub mod classify;
pub mod demo;
pub mod error;
pub mod fabric_test;
pub mod fit;
pub mod frames;
pub mod inspect;
pub mod job;
pub mod pattern;
pub mod shot_error;
pub mod shot_setup;
pub mod sim_scene;
pub mod simulate;
pub mod submit;
pub mod train;
pub mod util;
pub mod validate;
pub mod validate_forces;
pub mod validate_motion;
pub mod validate_pd;
pub mod yls;
pub mod yls_scene;

pub use classify::class_of;
pub use error::{Error, ErrorClass, Retry, StageFailure};

/// One computed frame, for progress lines (`--json`: one JSON object per
/// frame; the CLI adds `"event": "frame"`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrameProgress {
    /// The frame's number (farm frame number).
    pub frame: i64,
    /// Frames computed so far by this run, and of how many.
    pub done: usize,
    pub total: usize,
    /// Wall time (ms) since the previous frame.
    pub ms: f64,
    /// Largest implicit-Euler residual (N) of the frame's steps (None where
    /// the stage has none, e.g. the yarn-level simulator).
    pub residual: Option<f64>,
    /// Deepest penetration (m) of a free node into a collider at the frame
    /// (None without colliders).
    pub penetration_m: Option<f64>,
}

impl FrameProgress {
    /// A quasi-static rig's frame `index` of `total` (a load step, a clamp
    /// distance): no residual or penetration to report; the wall time since
    /// `last`, which restarts.
    pub fn of_rig(index: usize, total: usize, last: &mut std::time::Instant) -> FrameProgress {
        let ms = last.elapsed().as_secs_f64() * 1e3;
        *last = std::time::Instant::now();
        FrameProgress {
            frame: index as i64,
            done: index,
            total,
            ms,
            residual: None,
            penetration_m: None,
        }
    }
}

/// A stop request from outside the process (SIGTERM) for the stages that
/// can honour it: a resumable shot finishes its current step, checkpoints
/// and stops with exit 75. The CLI's signal handler calls
/// [`Interrupt::request`]; outside such a stage the request is refused and
/// the handler ends the process as SIGTERM normally does (a half-done embed
/// or fit has nothing to save).
#[derive(Debug)]
pub struct Interrupt {
    requested: std::sync::atomic::AtomicBool,
    armed: std::sync::atomic::AtomicBool,
}

impl Interrupt {
    pub const fn new() -> Interrupt {
        Interrupt {
            requested: std::sync::atomic::AtomicBool::new(false),
            armed: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Asks the running stage to stop; `false` when no stage can (the
    /// caller then ends the process). Async-signal-safe (atomics only).
    pub fn request(&self) -> bool {
        use std::sync::atomic::Ordering::SeqCst;
        if self.armed.load(SeqCst) {
            self.requested.store(true, SeqCst);
            true
        } else {
            false
        }
    }

    /// The flag a resumable shot polls after every step.
    pub fn flag(&self) -> &std::sync::atomic::AtomicBool {
        &self.requested
    }

    /// Honours requests while the returned guard lives.
    pub fn arm(&self) -> InterruptArmed<'_> {
        self.armed.store(true, std::sync::atomic::Ordering::SeqCst);
        InterruptArmed(self)
    }
}

impl Default for Interrupt {
    fn default() -> Self {
        Interrupt::new()
    }
}

/// See [`Interrupt::arm`].
pub struct InterruptArmed<'a>(&'a Interrupt);

impl Drop for InterruptArmed<'_> {
    fn drop(&mut self) {
        self.0
            .armed
            .store(false, std::sync::atomic::Ordering::SeqCst);
    }
}

/// What a stage tells its caller while it runs (the CLI prints it; a
/// daemon logs it). Every method defaults to doing nothing.
pub trait Observer {
    /// A warning about the inputs (printed as `warning: ...`).
    fn warning(&mut self, _message: &str) {}
    /// `done` of `total` frames are computed.
    fn frames(&mut self, _done: usize, _total: usize) {}
    /// A frame is computed, with its statistics; defaults to
    /// [`Observer::frames`].
    fn frame(&mut self, p: &FrameProgress) {
        self.frames(p.done, p.total);
    }
    /// An iteration of a material fit is done.
    fn iteration(&mut self, _p: &crate::fit::elastic::FitProgress) {}
    /// A step of a command that runs several stages begins (`card`: the
    /// swatch, each training pose, the fit).
    fn step(&mut self, _message: &str) {}
}

/// An observer that ignores everything.
pub struct Quiet;

impl Observer for Quiet {}

/// A stage: typed inputs and parameters (the implementing struct) that
/// reads its inputs, writes its outputs atomically with their provenance,
/// and reports what it did or fails with [`Error`].
pub trait Stage {
    /// What a successful run reports (`--json` prints it).
    type Report;
    /// The stage's name in logs and manifests.
    const NAME: &'static str;
    /// Runs the stage.
    fn run(&self, observer: &mut dyn Observer) -> Result<Self::Report, Error>;
}
