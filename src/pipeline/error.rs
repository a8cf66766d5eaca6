//! The one error of the pipeline stages and its classes.
//!
//! Every stage fails with [`Error`]; its [`Error::class`] is the single
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

    /// The documented process exit code (README, "Exit codes").
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

    /// The retry decision of the README's exit-code table.
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

/// The error of every pipeline stage. The variants keep each stage's own
/// typed error (with its file and place); [`Error::class`] classifies them
/// all.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The asset stages: embed, shapefit, export.
    #[error(transparent)]
    Asset(#[from] super::asset::StageError),
    /// The shot stage.
    #[error(transparent)]
    Shot(#[from] super::simulate::SimulateError),
    /// The pattern stage.
    #[error(transparent)]
    Pattern(#[from] super::pattern::PatternStageError),
    /// A yarn-level scene run.
    #[error(transparent)]
    Yls(#[from] super::yls::YlsError),
    /// A fabric test (Sperl 2022 §4).
    #[error(transparent)]
    Fabric(#[from] super::fabric_test::FabricTestError),
    /// Submitting a job to a farm scheduler.
    #[error(transparent)]
    Submit(#[from] super::submit::SubmitError),
    /// Embedding outside a stage (benchmarks).
    #[error(transparent)]
    Embed(#[from] crate::embed::EmbedError),
    /// Shape fitting outside a stage (benchmarks).
    #[error(transparent)]
    Fit(#[from] crate::fit::FitError),
    /// Geometry that does not hold together.
    #[error(transparent)]
    Geom(#[from] crate::geom::GeomError),
    /// The request asks for what the inputs do not hold, or for something
    /// knitvox refuses (the message names the option or key).
    #[error("{0}")]
    Usage(String),
    /// A bug: an invariant did not hold.
    #[error("internal error: {0}")]
    Internal(String),
}

impl Error {
    /// The class of this error: exit code and retry decision.
    pub fn class(&self) -> ErrorClass {
        match self {
            Error::Io(e) => e.class().into(),
            Error::Asset(e) => e.class(),
            Error::Shot(e) => e.class(),
            Error::Pattern(e) => e.class(),
            Error::Yls(e) => e.class(),
            Error::Fabric(e) => fabric_class(e),
            Error::Submit(e) => e.class(),
            Error::Embed(_) | Error::Fit(_) | Error::Geom(_) => ErrorClass::BadInput,
            Error::Usage(_) => ErrorClass::Usage,
            Error::Internal(_) => ErrorClass::Internal,
        }
    }

    /// The file the error is about, where it names one.
    pub fn file(&self) -> Option<PathBuf> {
        match self {
            Error::Io(e) => Some(e.path().to_path_buf()),
            Error::Asset(super::asset::StageError::Io(e)) => Some(e.path().to_path_buf()),
            Error::Shot(e) => e.file(),
            Error::Yls(e) => Some(e.file()),
            Error::Asset(super::asset::StageError::Embed { path, .. })
            | Error::Asset(super::asset::StageError::Fit { path, .. })
            | Error::Asset(super::asset::StageError::Invalid { path, .. })
            | Error::Pattern(super::pattern::PatternStageError::Read { path, .. })
            | Error::Pattern(super::pattern::PatternStageError::Grid { path, .. }) => {
                Some(path.clone())
            }
            _ => None,
        }
    }

    /// The class of one cause in an error chain (`anyhow` at the binary
    /// edge, a daemon's log): a pipeline error, or one of the typed errors
    /// it wraps met on its own (an io error of `inspect` or `convert`, a
    /// stage error inside another library error). `None` for anything
    /// else. Callers take the first cause that has a class.
    pub fn class_of(cause: &(dyn std::error::Error + 'static)) -> Option<ErrorClass> {
        use super::{asset::StageError, pattern::PatternStageError};
        use super::{simulate::SimulateError, yls::YlsError};
        if let Some(e) = cause.downcast_ref::<Error>() {
            Some(e.class())
        } else if let Some(e) = cause.downcast_ref::<IoError>() {
            Some(e.class().into())
        } else if let Some(e) = cause.downcast_ref::<StageError>() {
            Some(e.class())
        } else if let Some(e) = cause.downcast_ref::<SimulateError>() {
            Some(e.class())
        } else if let Some(e) = cause.downcast_ref::<PatternStageError>() {
            Some(e.class())
        } else if let Some(e) = cause.downcast_ref::<YlsError>() {
            Some(e.class())
        } else if let Some(e) = cause.downcast_ref::<super::fabric_test::FabricTestError>() {
            Some(fabric_class(e))
        } else if let Some(e) = cause.downcast_ref::<super::submit::SubmitError>() {
            Some(e.class())
        } else if cause.is::<crate::embed::EmbedError>()
            || cause.is::<crate::fit::FitError>()
            || cause.is::<crate::geom::GeomError>()
        {
            Some(ErrorClass::BadInput)
        } else {
            None
        }
    }
}

/// A fabric test's class: its swatch's pattern errors keep theirs, its
/// parameter errors are usage errors.
fn fabric_class(e: &super::fabric_test::FabricTestError) -> ErrorClass {
    match e {
        super::fabric_test::FabricTestError::Pattern(p) => p.class(),
        _ if e.is_usage() => ErrorClass::Usage,
        _ => e.class().into(),
    }
}

/// A stage's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    /// The README's exit-code table, row by row: code and retry column.
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

    #[test]
    fn class_of_finds_a_stage_error_inside_a_chain() {
        let e = anyhow::Error::new(Error::Shot(
            super::super::simulate::SimulateError::Unavailable("no GPU".into()),
        ))
        .context("simulating");
        let class = e.chain().find_map(Error::class_of);
        assert_eq!(class, Some(ErrorClass::Unavailable));
        let e = anyhow::anyhow!("something else");
        assert_eq!(e.chain().find_map(Error::class_of), None);
        // A stage error met on its own has the class it has inside Error.
        let bare = super::super::pattern::PatternStageError::Pattern(
            crate::yarn::pattern::PatternError::BadParameter {
                name: "courses",
                value: 0.0,
                message: "must be positive".into(),
            },
        );
        let class = bare.class();
        assert_eq!(class, ErrorClass::Usage);
        assert_eq!(Error::class_of(&bare), Some(class));
        assert_eq!(Error::class_of(&Error::from(bare)), Some(class));
    }
}
