//! The shot stage's error, shared by its setup and its time loop.

use std::path::{Path, PathBuf};

use super::sim_scene::SceneError;
use crate::io::IoError;
use crate::pipeline::ErrorClass;
use crate::sim::SimError;

/// Errors of the shot stage.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Inputs that do not fit together (the message names the key or option).
    #[error("{path}: {message}", path = path.display())]
    Invalid { path: PathBuf, message: String },
    /// A requested backend or solver this build cannot run.
    #[error("{0}")]
    Unavailable(String),
    /// A request knitvox refuses (the message names the option).
    #[error("{0}")]
    Usage(String),
    /// A run that continues a shot found no checkpoint to continue from.
    #[error("{message}")]
    NoCheckpoint { dir: PathBuf, message: String },
    /// The checkpoint given does not fit the shot or the request.
    #[error("{path}: {message}", path = path.display())]
    CheckpointMismatch { path: PathBuf, message: String },
    /// Stopped on request (SIGTERM) after a step; the checkpoint holds the
    /// state, `--resume` continues.
    #[error("interrupted after step {step} (shot time {time:.6} s); the shot's state is saved in {checkpoint}; run the same command with --resume to continue", checkpoint = checkpoint.display())]
    Interrupted {
        checkpoint: PathBuf,
        step: usize,
        time: f64,
    },
    /// The simulation diverged.
    #[error("{path}: {source} (shot time {time:.6} s, before frame {frame})", path = path.display())]
    Diverged {
        path: PathBuf,
        frame: i64,
        time: f64,
        #[source]
        source: SimError,
    },
}

impl SimulateError {
    /// How the caller should react: a backend this machine cannot run is
    /// `Unavailable` (the inputs are fine; retry on a GPU node); everything
    /// else but i/o is bad input (retrying the same inputs fails the same
    /// way, divergence included).
    pub fn class(&self) -> ErrorClass {
        match self {
            SimulateError::Io(e) => e.class().into(),
            SimulateError::Unavailable(_) => ErrorClass::Unavailable,
            SimulateError::Usage(_) | SimulateError::CheckpointMismatch { .. } => ErrorClass::Usage,
            SimulateError::NoCheckpoint { .. } => ErrorClass::Missing,
            SimulateError::Interrupted { .. } => ErrorClass::Transient,
            _ => ErrorClass::BadInput,
        }
    }
    /// The file the error is about, where it names one.
    pub fn file(&self) -> Option<PathBuf> {
        match self {
            SimulateError::Io(e) => Some(e.path().to_path_buf()),
            SimulateError::Invalid { path, .. }
            | SimulateError::Diverged { path, .. }
            | SimulateError::CheckpointMismatch { path, .. } => Some(path.clone()),
            SimulateError::NoCheckpoint { dir, .. } => Some(dir.clone()),
            SimulateError::Interrupted { checkpoint, .. } => Some(checkpoint.clone()),
            SimulateError::Scene(e) => Some(e.path.clone()),
            SimulateError::Usage(_) | SimulateError::Unavailable(_) => None,
        }
    }
    /// The PD step that diverged (1-based), if that is what happened.
    pub fn diverged_step(&self) -> Option<u64> {
        match self {
            SimulateError::Diverged {
                source: SimError::Diverged { step, .. },
                ..
            } => Some(*step),
            _ => None,
        }
    }
}

/// An [`SimulateError::Invalid`] about `path`.
pub(super) fn invalid(path: &Path, message: impl Into<String>) -> SimulateError {
    SimulateError::Invalid {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

impl crate::pipeline::error::StageFailure for SimulateError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        SimulateError::class(self)
    }
    fn file(&self) -> Option<std::path::PathBuf> {
        SimulateError::file(self)
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<SimulateError> for crate::pipeline::Error {
    fn from(e: SimulateError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}
