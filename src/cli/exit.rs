//! Documented process exit codes (sysexits.h values, which farm schedulers
//! and shell scripts already understand).

use crate::io::{ErrorClass, IoError};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ExitCode {
    /// Everything worked.
    Success = 0,
    /// Usage error: bad flags or arguments (clap's own code).
    Usage = 2,
    /// Bad input data: malformed, inconsistent or unsupported file. Do not retry.
    BadInput = 65,
    /// An input file is missing or unreadable.
    MissingInput = 66,
    /// The requested backend cannot run here: `--backend gpu` and no usable
    /// GPU adapter (EX_UNAVAILABLE). Retry on a GPU node or with `--backend cpu`.
    Unavailable = 69,
    /// Internal error (a bug): please report it.
    Internal = 70,
    /// Output failure: could not write (disk full, permissions, missing folder).
    Output = 74,
    /// Transient: e.g. an input is still being written by another process. Retry later.
    Transient = 75,
}

impl ExitCode {
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// The one-line message of an error and its causes, each cause printed
/// once: library errors both embed their source in their own message and
/// return it from `source()` (so `{e:#}` would print it twice), and a cause
/// whose text the message already holds adds nothing.
pub fn error_message(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let part = cause.to_string();
        if part.is_empty() || text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

/// The exit code for an error: looks through the error chain for a library
/// error that knows its class.
pub fn exit_code_for(err: &anyhow::Error) -> ExitCode {
    let of_class = |c: ErrorClass| match c {
        ErrorClass::BadInput => ExitCode::BadInput,
        ErrorClass::MissingInput => ExitCode::MissingInput,
        ErrorClass::Output => ExitCode::Output,
        ErrorClass::Transient => ExitCode::Transient,
        ErrorClass::Usage => ExitCode::Usage,
    };
    for cause in err.chain() {
        if cause.downcast_ref::<super::guard::UsageError>().is_some() {
            return ExitCode::Usage;
        }
        if let Some(e) = cause.downcast_ref::<IoError>() {
            return of_class(e.class());
        }
        if let Some(e) = cause.downcast_ref::<crate::pipeline::asset::StageError>() {
            return of_class(e.class());
        }
        if let Some(e) = cause.downcast_ref::<crate::pipeline::simulate::SimulateError>() {
            // The inputs are fine; this machine cannot run the backend.
            if matches!(e, crate::pipeline::simulate::SimulateError::Unavailable(_)) {
                return ExitCode::Unavailable;
            }
            return of_class(e.class());
        }
        if let Some(e) = cause.downcast_ref::<crate::pipeline::pattern::PatternStageError>() {
            return super::pattern::stage_exit_code(e);
        }
        if let Some(e) = cause.downcast_ref::<crate::pipeline::yls::YlsError>() {
            return of_class(e.class());
        }
        if cause.downcast_ref::<crate::embed::EmbedError>().is_some()
            || cause.downcast_ref::<crate::fit::FitError>().is_some()
        {
            return ExitCode::BadInput;
        }
        if cause.downcast_ref::<crate::geom::GeomError>().is_some() {
            return ExitCode::BadInput;
        }
    }
    ExitCode::Internal
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_cause_is_printed_once() {
        let os = std::io::Error::from(std::io::ErrorKind::NotFound);
        let os_text = os.to_string();
        let e = anyhow::Error::new(IoError::Read {
            path: "x.bcc".into(),
            source: os,
        })
        .context("converting x.bcc to y.ply");
        let m = error_message(&e);
        assert_eq!(m.matches(&os_text).count(), 1, "{m}");
        assert!(
            m.starts_with("converting x.bcc to y.ply: x.bcc: cannot read"),
            "{m}"
        );
    }
}
