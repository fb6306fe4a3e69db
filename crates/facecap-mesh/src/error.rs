//! The crate's error type.

use std::path::PathBuf;

/// Errors of `facecap-mesh`.
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
    /// A parameter is outside its allowed range (or NaN/inf).
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// The offending value, printed.
        value: String,
        /// The allowed range.
        expected: String,
    },
    /// An input (image, workspace, index) does not fit the call.
    #[error("invalid input: {what}")]
    InvalidInput {
        /// What was wrong.
        what: String,
    },
    /// An error from facecap-core (video decoding, paths).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The interpreter's errors keep their kind: an unusable model stays [`Error::Model`],
/// a failed read [`Error::Io`], a misfit input [`Error::InvalidInput`].
impl From<facecap_tflite::Error> for Error {
    fn from(e: facecap_tflite::Error) -> Self {
        match e {
            facecap_tflite::Error::Io { path, source } => Error::Io { path, source },
            facecap_tflite::Error::Model { reason } => Error::Model { reason },
            facecap_tflite::Error::InvalidInput { what } => Error::InvalidInput { what },
        }
    }
}
