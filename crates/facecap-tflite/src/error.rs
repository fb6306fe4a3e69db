//! The crate's error type.

use std::path::PathBuf;

/// Errors of `facecap-tflite`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An operating-system I/O failure on a named path.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A model file is damaged or uses something this crate does not run.
    #[error("unusable TFLite model: {reason}")]
    Model {
        /// What was wrong.
        reason: String,
    },
    /// An input (tensor index, length) does not fit the call.
    #[error("invalid input: {what}")]
    InvalidInput {
        /// What was wrong.
        what: String,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
