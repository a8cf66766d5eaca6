//! The one error of the pipeline stages and its classes.
//!
//! Every stage fails with [`Error`] (a stage's own typed error inside
//! [`Error::Stage`]); its [`Error::class`] is the single
//! place that decides the process exit code ([`ErrorClass::exit_code`],
//! sysexits.h values) and whether a scheduler may retry
//! ([`ErrorClass::retry`]), for the CLI, a daemon and a farm alike.

use std::path::PathBuf;

use crate::io::{self, IoError};

/// What kind of failure an error is: decides the exit code and the retry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorClass {
    /// The request is wrong (flags, or a selection the inputs do not
    /// hold): exit 2.
    Usage,
    /// An input is malformed, inconsistent or unsupported, or asks for
    /// something the solvers cannot do stably (divergence): exit 65.
    BadInput,
    /// An input file is missing or unreadable: exit 66.
    Missing,
    /// This machine cannot run the request (`--backend gpu` without a
    /// usable GPU): exit 69.
    Unavailable,
    /// A bug in knitvox: exit 70.
    Internal,
    /// An output could not be written (missing folder, permissions, disk
    /// full): exit 74.
    Output,
    /// Temporary trouble (an input still being written by another
    /// process): exit 75.
    Transient,
}

/// Whether (and where) the same request may be run again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Retry {
    /// Retrying the same request fails the same way.
    No,
    /// Only after a person fixes something (a path, an output folder).
    AfterFix,
    /// Later, on any machine: the trouble passes by itself.
    Later,
    /// On another machine (a GPU node) or with other resources.
    Elsewhere,
}

impl ErrorClass {
    /// Every class, in exit-code order.
    pub const ALL: [ErrorClass; 7] = [
        ErrorClass::Usage,
        ErrorClass::BadInput,
        ErrorClass::Missing,
        ErrorClass::Unavailable,
        ErrorClass::Internal,
        ErrorClass::Output,
        ErrorClass::Transient,
    ];

    /// The documented process exit code (docs/guides/cli.md, "Exit codes").
    pub fn exit_code(self) -> u8 {
        match self {
            ErrorClass::Usage => 2,
            ErrorClass::BadInput => 65,
            ErrorClass::Missing => 66,
            ErrorClass::Unavailable => 69,
            ErrorClass::Internal => 70,
            ErrorClass::Output => 74,
            ErrorClass::Transient => 75,
        }
    }

    /// The retry decision of the exit-code table (docs/guides/cli.md).
    pub fn retry(self) -> Retry {
        match self {
            ErrorClass::Usage | ErrorClass::BadInput | ErrorClass::Internal => Retry::No,
            ErrorClass::Missing | ErrorClass::Output => Retry::AfterFix,
            ErrorClass::Unavailable => Retry::Elsewhere,
            ErrorClass::Transient => Retry::Later,
        }
    }

    /// Whether a scheduler may simply run the same job again (requeue):
    /// only transient failures.
    pub fn retryable(self) -> bool {
        self.retry() == Retry::Later
    }
}

impl From<io::ErrorClass> for ErrorClass {
    fn from(c: io::ErrorClass) -> Self {
        match c {
            io::ErrorClass::BadInput => ErrorClass::BadInput,
            io::ErrorClass::MissingInput => ErrorClass::Missing,
            io::ErrorClass::Output => ErrorClass::Output,
            io::ErrorClass::Transient => ErrorClass::Transient,
            io::ErrorClass::Usage => ErrorClass::Usage,
        }
    }
}

/// A stage's own typed error, as [`Error`] carries it: each stage file
/// implements this for its error and converts it into [`Error`] with
/// [`Error::stage`], so this file names no stage.
pub trait StageFailure: std::error::Error + Send + Sync + 'static {
    /// Exit code and retry decision of this failure.
    fn class(&self) -> ErrorClass;
    /// The file the error is about, where it names one.
    fn file(&self) -> Option<PathBuf> {
        None
    }
    /// The error as `dyn Error`, for a cause chain.
    fn as_error(&self) -> &(dyn std::error::Error + 'static);
}

/// The error of every pipeline stage. A stage's own typed error (with its
/// file and place) is kept whole in [`Error::Stage`]; [`Error::class`]
/// classifies them all.
#[derive(Debug)]
pub enum Error {
    /// Reading or writing a file.
    Io(IoError),
    /// A stage's own error: the asset stages (embed, shapefit, export), the
    /// shot, a pattern, a yarn-level scene run, a fabric test (Sperl 2022
    /// §4), a farm submission.
    Stage(Box<dyn StageFailure>),
    /// Embedding outside a stage (benchmarks).
    Embed(crate::embed::EmbedError),
    /// Shape fitting outside a stage (benchmarks).
    Fit(crate::fit::FitError),
    /// Geometry that does not hold together.
    Geom(crate::geom::GeomError),
    /// The request asks for what the inputs do not hold, or for something
    /// knitvox refuses (the message names the option or key).
    Usage(String),
    /// A bug: an invariant did not hold.
    Internal(String),
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The wrapped errors are transparent: their own message.
        match self {
            Error::Io(e) => e.fmt(f),
            Error::Stage(e) => e.fmt(f),
            Error::Embed(e) => e.fmt(f),
            Error::Fit(e) => e.fmt(f),
            Error::Geom(e) => e.fmt(f),
            Error::Usage(m) => f.write_str(m),
            Error::Internal(m) => write!(f, "internal error: {m}"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        // Transparent: the wrapped error's own cause.
        match self {
            Error::Io(e) => e.source(),
            Error::Stage(e) => e.as_error().source(),
            Error::Embed(e) => e.source(),
            Error::Fit(e) => e.source(),
            Error::Geom(e) => e.source(),
            Error::Usage(_) | Error::Internal(_) => None,
        }
    }
}

impl From<IoError> for Error {
    fn from(e: IoError) -> Self {
        Error::Io(e)
    }
}

impl From<crate::embed::EmbedError> for Error {
    fn from(e: crate::embed::EmbedError) -> Self {
        Error::Embed(e)
    }
}

impl From<crate::fit::FitError> for Error {
    fn from(e: crate::fit::FitError) -> Self {
        Error::Fit(e)
    }
}

impl From<crate::geom::GeomError> for Error {
    fn from(e: crate::geom::GeomError) -> Self {
        Error::Geom(e)
    }
}

impl Error {
    /// Wraps a stage's own error.
    pub fn stage(e: impl StageFailure) -> Self {
        Error::Stage(Box::new(e))
    }

    /// The class of this error: exit code and retry decision.
    pub fn class(&self) -> ErrorClass {
        match self {
            Error::Io(e) => e.class().into(),
            Error::Stage(e) => e.class(),
            Error::Embed(_) | Error::Fit(_) | Error::Geom(_) => ErrorClass::BadInput,
            Error::Usage(_) => ErrorClass::Usage,
            Error::Internal(_) => ErrorClass::Internal,
        }
    }

    /// The file the error is about, where it names one.
    pub fn file(&self) -> Option<PathBuf> {
        match self {
            Error::Io(e) => Some(e.path().to_path_buf()),
            Error::Stage(e) => e.file(),
            _ => None,
        }
    }

    /// The stage error inside, if it is one of type `E`.
    pub fn downcast_stage<E: StageFailure>(&self) -> Option<&E> {
        match self {
            Error::Stage(e) => e.as_error().downcast_ref::<E>(),
            _ => None,
        }
    }
}

/// A stage's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    /// The exit-code table of docs/guides/cli.md, row by row: code and retry column.
    #[test]
    fn classes_give_the_documented_exit_codes_and_retries() {
        let table = [
            (ErrorClass::Usage, 2, Retry::No),
            (ErrorClass::BadInput, 65, Retry::No),
            (ErrorClass::Missing, 66, Retry::AfterFix),
            (ErrorClass::Unavailable, 69, Retry::Elsewhere),
            (ErrorClass::Internal, 70, Retry::No),
            (ErrorClass::Output, 74, Retry::AfterFix),
            (ErrorClass::Transient, 75, Retry::Later),
        ];
        assert_eq!(table.len(), ErrorClass::ALL.len());
        for (c, code, retry) in table {
            assert_eq!(c.exit_code(), code, "{c:?}");
            assert_eq!(c.retry(), retry, "{c:?}");
            assert_eq!(c.retryable(), c == ErrorClass::Transient, "{c:?}");
        }
    }

    #[test]
    fn io_classes_map_one_to_one() {
        let read = |kind| IoError::Read {
            path: "a.bcc".into(),
            source: std::io::Error::from(kind),
        };
        let e = Error::from(read(std::io::ErrorKind::NotFound));
        assert_eq!(e.class(), ErrorClass::Missing);
        assert_eq!(e.file(), Some(PathBuf::from("a.bcc")));
        let e = Error::from(IoError::Write {
            path: "o.ply".into(),
            source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
        });
        assert_eq!(e.class(), ErrorClass::Output);
        assert_eq!(e.class().exit_code(), 74);
    }
}
