//! Error types of the io layer. Format decoders report a [`FormatError`]
//! (what and where inside the bytes); the path-level API wraps it into an
//! [`IoError`] that also names the file.

use std::fmt;
use std::path::PathBuf;

use super::Format;
use crate::geom::GeomError;

/// Where in a file a problem was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// Nowhere in particular (the file as a whole).
    File,
    /// A byte offset from the start of the file.
    Byte(u64),
    /// A 1-based text line.
    Line(usize),
    /// A named place: a JSON pointer in a glTF, a dataset path in HDF5, a PLY element.
    Path(String),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::File => Ok(()),
            Location::Byte(b) => write!(f, "byte {b}"),
            Location::Line(l) => write!(f, "line {l}"),
            Location::Path(p) => f.write_str(p),
        }
    }
}

/// A problem inside a file's content, found by a format decoder or encoder.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct FormatError {
    pub location: Location,
    pub message: String,
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.location {
            Location::File => f.write_str(&self.message),
            _ => write!(f, "{}: {}", self.location, self.message),
        }
    }
}

impl FormatError {
    pub fn new(location: Location, message: impl Into<String>) -> FormatError {
        FormatError {
            location,
            message: message.into(),
        }
    }
    pub fn at_byte(offset: u64, message: impl Into<String>) -> FormatError {
        FormatError::new(Location::Byte(offset), message)
    }
    pub fn at_line(line: usize, message: impl Into<String>) -> FormatError {
        FormatError::new(Location::Line(line), message)
    }
    pub fn at_path(path: impl Into<String>, message: impl Into<String>) -> FormatError {
        FormatError::new(Location::Path(path.into()), message)
    }
    pub fn whole_file(message: impl Into<String>) -> FormatError {
        FormatError::new(Location::File, message)
    }
}

impl From<GeomError> for FormatError {
    fn from(e: GeomError) -> Self {
        FormatError::whole_file(e.to_string())
    }
}

/// How a caller should react to an error (mapped to exit codes by the binary).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorClass {
    /// The input is wrong: retrying will not help.
    BadInput,
    /// The input file does not exist or cannot be opened.
    MissingInput,
    /// Writing an output failed (disk full, permissions, ...).
    Output,
    /// Temporary: e.g. another process is still writing the file. Retry later.
    Transient,
    /// The command line asks for something knitvox refuses (an output that
    /// is an input): a usage error.
    Usage,
}

/// An error of the path-level io API; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {format}: {source}", path = path.display())]
    Format {
        path: PathBuf,
        format: Format,
        #[source]
        source: FormatError,
    },
    #[error("{path}: cannot read: {source}", path = path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot write: {source}", path = path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: unknown file type{ext}; known extensions: {known}", path = path.display(),
        ext = if ext.is_empty() { String::from(" (no extension)") } else { format!(" '.{ext}'") },
        known = Format::ALL.iter().flat_map(|f| f.extensions()).map(|e| format!(".{e}")).collect::<Vec<_>>().join(" "))]
    UnknownFormat { path: PathBuf, ext: String },
    #[error("{path}: {message}", path = path.display())]
    Unsupported { path: PathBuf, message: String },
    #[error("{path}: {format}: invalid content: {source}", path = path.display())]
    Invalid {
        path: PathBuf,
        format: Format,
        #[source]
        source: GeomError,
    },
    #[error("{path}: {message} (transient: retry later)", path = path.display())]
    Busy { path: PathBuf, message: String },
    /// An input that is a FIFO, device, directory or socket (see `io::input`).
    #[error("{path}: the {what} is {kind}, not a regular file; knitvox reads inputs only from regular files", path = path.display())]
    NotRegular {
        path: PathBuf,
        what: &'static str,
        kind: &'static str,
    },
    /// An input larger than the memory budget, refused before it is read.
    #[error("{path}: the {what} holds {size} bytes, more than the memory budget of {budget} bytes; it is not read (raise --max-memory if the file is genuine)", path = path.display(),
        size = if *grew { format!("at least {bytes}") } else { bytes.to_string() })]
    TooLarge {
        path: PathBuf,
        what: &'static str,
        bytes: u64,
        budget: u64,
        /// The file grew past the budget while it was read.
        grew: bool,
    },
    /// An output path that is, or resolves to, an input (see `io::overwrite`).
    #[error("output '{}' is the input '{}': knitvox never overwrites an input; choose another output path",
        output.display(), input.display())]
    OutputIsInput { output: PathBuf, input: PathBuf },
}

impl IoError {
    /// The file the error names.
    pub fn path(&self) -> &std::path::Path {
        match self {
            IoError::Format { path, .. }
            | IoError::Read { path, .. }
            | IoError::Write { path, .. }
            | IoError::Busy { path, .. }
            | IoError::Unsupported { path, .. }
            | IoError::Invalid { path, .. }
            | IoError::UnknownFormat { path, .. }
            | IoError::NotRegular { path, .. }
            | IoError::TooLarge { path, .. }
            | IoError::OutputIsInput { output: path, .. } => path,
        }
    }

    pub fn class(&self) -> ErrorClass {
        match self {
            IoError::Format { .. }
            | IoError::UnknownFormat { .. }
            | IoError::Unsupported { .. }
            | IoError::Invalid { .. }
            | IoError::NotRegular { .. }
            | IoError::TooLarge { .. } => ErrorClass::BadInput,
            IoError::Read { source, .. } => match source.kind() {
                std::io::ErrorKind::NotFound | std::io::ErrorKind::PermissionDenied => {
                    ErrorClass::MissingInput
                }
                std::io::ErrorKind::Interrupted
                | std::io::ErrorKind::WouldBlock
                | std::io::ErrorKind::TimedOut => ErrorClass::Transient,
                std::io::ErrorKind::InvalidData | std::io::ErrorKind::UnexpectedEof => {
                    ErrorClass::BadInput
                }
                _ => ErrorClass::MissingInput,
            },
            IoError::Write { .. } => ErrorClass::Output,
            IoError::Busy { .. } => ErrorClass::Transient,
            IoError::OutputIsInput { .. } => ErrorClass::Usage,
        }
    }
}
