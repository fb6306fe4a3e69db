//! The one error type of `facecap-tensor`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Failures of tensor building, model files, fitting and Poisson cloning.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An error from `facecap-core` (I/O, mesh formats, cameras).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
    /// An operating-system I/O failure on a named path.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A model file (or mesh database file) is malformed, truncated or of an unsupported version.
    #[error("bad {what} file {path}: {reason}")]
    Format {
        /// Which format ("tensor model", "OBJ", ...).
        what: &'static str,
        /// The file (may be empty for in-memory data).
        path: PathBuf,
        /// What is wrong, with a byte offset or line where known.
        reason: String,
    },
    /// The corresponded database has a hole: no mesh for this identity/expression pair.
    #[error("database has no mesh for identity {identity:?} with expression {expression:?}")]
    MissingCell {
        /// Identity name.
        identity: String,
        /// Expression name.
        expression: String,
    },
    /// A parameter is out of range or not finite.
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: String,
        /// Allowed range.
        expected: String,
    },
    /// Input sizes disagree.
    #[error("dimension mismatch for {what}: expected {expected}, got {got}")]
    DimensionMismatch {
        /// What was compared.
        what: String,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// The caller's feature-point tracker failed (see [`crate::video_fit::FeatureTracker`]).
    #[error("feature point tracking failed: {reason}")]
    FeatureTracking {
        /// Why.
        reason: String,
    },
    /// A numerical routine could not produce a result (degenerate input).
    #[error("numerical failure in {operation}: {reason}")]
    Numerical {
        /// The routine.
        operation: &'static str,
        /// Why.
        reason: String,
    },
}

impl Error {
    pub(crate) fn invalid(name: &'static str, value: impl ToString, expected: impl Into<String>) -> Self {
        Error::InvalidParameter {
            name,
            value: value.to_string(),
            expected: expected.into(),
        }
    }

    pub(crate) fn dim(what: impl Into<String>, expected: usize, got: usize) -> Self {
        Error::DimensionMismatch {
            what: what.into(),
            expected,
            got,
        }
    }
}
