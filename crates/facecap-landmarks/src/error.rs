//! The one error type of `facecap-landmarks`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Failures of detection, landmark inference, optical flow and tracking.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An error from `facecap-core` (I/O, formats, video).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
    /// A model file is malformed, truncated or of an unsupported version.
    #[error("bad model file {path}: {reason}")]
    Model {
        /// The model file (may be empty for in-memory data).
        path: PathBuf,
        /// What is wrong, with a byte offset where known.
        reason: String,
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
}
