//! The one error type of `facecap-core`.

use std::path::PathBuf;

/// Result alias used throughout `facecap-core`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Every failure `facecap-core` can report. Variants carry named fields so that a
/// message always says *which* file, frame, parameter or value was at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An operating-system I/O failure on a named path.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A file could be read but its content does not follow its format.
    #[error("malformed {format} file {path}: {reason}")]
    Parse {
        /// Format name, e.g. "iBUG .pts".
        format: &'static str,
        /// The file involved (may be empty for in-memory data).
        path: PathBuf,
        /// What was wrong, including a line/offset where known.
        reason: String,
    },
    /// A parameter or input value is outside its allowed range (or NaN/inf).
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name as the user knows it.
        name: &'static str,
        /// The offending value, printed.
        value: String,
        /// The allowed range or form.
        expected: String,
    },
    /// Two inputs that must agree in size do not.
    #[error("dimension mismatch for {what}: expected {expected}, got {got}")]
    DimensionMismatch {
        /// What was being compared.
        what: String,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// A video or image could not be decoded.
    #[error("cannot decode {path}{}: {reason}", frame.map(|f| format!(" at frame {f}")).unwrap_or_default())]
    Decode {
        /// The file involved.
        path: PathBuf,
        /// Frame index where decoding failed, if known.
        frame: Option<u64>,
        /// What went wrong.
        reason: String,
    },
    /// A required external program (e.g. ffmpeg) is missing or failed to start.
    #[error("external tool {tool} unavailable: {reason}")]
    Tool {
        /// Program name.
        tool: String,
        /// What went wrong, including how to install it.
        reason: String,
    },
    /// A numerical routine could not produce a result (e.g. degenerate geometry).
    #[error("numerical failure in {operation}: {reason}")]
    Numerical {
        /// The routine that failed.
        operation: &'static str,
        /// Why.
        reason: String,
    },
}

impl Error {
    /// Wraps an I/O error with the path it happened on.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// Builds a [`Error::Parse`].
    pub fn parse(format: &'static str, path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Parse {
            format,
            path: path.into(),
            reason: reason.into(),
        }
    }

    /// A [`Error::Parse`] made by a parser of in-memory text, given the path of the file
    /// the text came from; other errors are returned unchanged.
    pub fn at_path(self, path: &std::path::Path) -> Self {
        match self {
            Error::Parse { format, reason, .. } => Error::Parse {
                format,
                path: path.to_path_buf(),
                reason,
            },
            other => other,
        }
    }

    /// Builds a [`Error::InvalidParameter`].
    pub fn invalid(name: &'static str, value: impl ToString, expected: impl Into<String>) -> Self {
        Error::InvalidParameter {
            name,
            value: value.to_string(),
            expected: expected.into(),
        }
    }
}

impl Error {
    /// Builds a [`Error::DimensionMismatch`].
    pub fn dim(what: impl Into<String>, expected: usize, got: usize) -> Self {
        Error::DimensionMismatch {
            what: what.into(),
            expected,
            got,
        }
    }
}

/// Returns an error naming `name` unless `value` is finite.
pub fn ensure_finite(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::invalid(name, value, "a finite number"))
    }
}
