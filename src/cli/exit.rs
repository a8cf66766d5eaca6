//! Documented process exit codes (sysexits.h values, which farm schedulers
//! and shell scripts already understand). The numbers and the retry
//! decisions come from [`crate::pipeline::ErrorClass`]; this module only
//! names them for the binary.

use crate::pipeline::ErrorClass;

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

/// The one mapping from error classes to exit codes
/// ([`ErrorClass::exit_code`] holds the numbers).
impl From<ErrorClass> for ExitCode {
    fn from(c: ErrorClass) -> Self {
        match c {
            ErrorClass::Usage => ExitCode::Usage,
            ErrorClass::BadInput => ExitCode::BadInput,
            ErrorClass::Missing => ExitCode::MissingInput,
            ErrorClass::Unavailable => ExitCode::Unavailable,
            ErrorClass::Internal => ExitCode::Internal,
            ErrorClass::Output => ExitCode::Output,
            ErrorClass::Transient => ExitCode::Transient,
        }
    }
}

/// The one-line message of an error and its causes, each cause printed
/// once: library errors both embed their source in their own message and
/// return it from `source()` (so `{e:#}` would print it twice), and a cause
/// whose text the message already holds adds nothing. Cut in the middle to
/// [`MAX_MESSAGE_BYTES`](crate::geom::MAX_MESSAGE_BYTES) (see [`short`]).
pub fn error_message(err: &anyhow::Error) -> String {
    short(&full_message(err))
}

/// `text` cut in the middle to [`MAX_MESSAGE_BYTES`](crate::geom::MAX_MESSAGE_BYTES):
/// every error the binary prints (stderr, `--json`, a watch folder's
/// error file) passes here, so an input that quotes a 10 MB path or line
/// still gives a short message.
pub fn short(text: &str) -> String {
    crate::geom::cap_message(text, crate::geom::MAX_MESSAGE_BYTES).into_owned()
}

fn full_message(err: &anyhow::Error) -> String {
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

/// The exit code for an error: the class of the first cause in its chain
/// that knows one ([`crate::pipeline::class_of`]); anything else is
/// an internal error.
pub fn exit_code_for(err: &anyhow::Error) -> ExitCode {
    err.chain()
        .find_map(crate::pipeline::class_of)
        .map_or(ExitCode::Internal, ExitCode::from)
}

/// The file an error is about: the first cause in its chain that names
/// one (a pipeline error, a shot error, an i/o error).
pub fn error_file(err: &anyhow::Error) -> Option<std::path::PathBuf> {
    use crate::pipeline::simulate::SimulateError;
    err.chain().find_map(|c| {
        if let Some(e) = c.downcast_ref::<crate::pipeline::Error>() {
            e.file()
        } else if let Some(e) = c.downcast_ref::<SimulateError>() {
            e.file()
        } else {
            c.downcast_ref::<crate::io::IoError>()
                .map(|e| e.path().to_path_buf())
        }
    })
}

/// The `--json` form of a failure: `{"event": "error", "class", "exit_code",
/// "message", "file"}` (`file` null where no file is named).
pub fn error_json(
    class: ErrorClass,
    message: &str,
    file: Option<&std::path::Path>,
) -> serde_json::Value {
    serde_json::json!({
        "event": "error",
        "class": class,
        "exit_code": class.exit_code(),
        "message": short(message),
        "file": file.map(|f| short(&f.display().to_string())),
    })
}

/// The class of an error (internal when no cause knows one).
pub fn class_for(err: &anyhow::Error) -> ErrorClass {
    err.chain()
        .find_map(crate::pipeline::class_of)
        .unwrap_or(ErrorClass::Internal)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::IoError;

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

    #[test]
    fn json_errors_name_class_code_and_file() {
        let e = anyhow::Error::new(crate::pipeline::Error::from(IoError::Read {
            path: "gone.vtkhdf".into(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        }));
        let class = class_for(&e);
        let v = error_json(class, &error_message(&e), error_file(&e).as_deref());
        assert_eq!(v["event"], "error");
        assert_eq!(v["class"], "missing");
        assert_eq!(v["exit_code"], 66);
        assert_eq!(v["file"], "gone.vtkhdf");
        assert!(
            v["message"].as_str().unwrap().contains("cannot read"),
            "{v}"
        );
        let v = error_json(ErrorClass::Internal, "a bug", None);
        assert!(v["file"].is_null());
    }

    #[test]
    fn exit_codes_are_the_classes_codes() {
        for c in ErrorClass::ALL {
            assert_eq!(ExitCode::from(c).code(), c.exit_code(), "{c:?}");
        }
        let e = anyhow::Error::new(crate::pipeline::Error::Usage("--frames 9".into()));
        assert_eq!(exit_code_for(&e), ExitCode::Usage);
        assert_eq!(exit_code_for(&anyhow::anyhow!("a bug")), ExitCode::Internal);
    }
}
