//! The one error type of `facecap-muscle`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Failures of muscle-set parsing, rig building, retargeting and tracking.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An error from `facecap-core` (I/O, formats, PnP).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
    /// A parameter is out of range or not finite.
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name (for muscle parameters: `muscle "<name>": <param>`).
        name: String,
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
    /// A muscle-set JSON file is malformed.
    #[error("malformed muscle set {path}: {reason}")]
    MuscleSet {
        /// The file (empty for in-memory text).
        path: PathBuf,
        /// What is wrong (serde's message includes line and column).
        reason: String,
    },
    /// A landmark needed to place a muscle is not mapped on the mesh.
    #[error("landmark {landmark} (0-based iBUG) is needed for {purpose} but is not mapped on the mesh")]
    MissingLandmark {
        /// 0-based iBUG index.
        landmark: usize,
        /// What it was needed for.
        purpose: &'static str,
    },
    /// Degenerate geometry (e.g. coincident control points).
    #[error("degenerate geometry in {what}: {reason}")]
    Degenerate {
        /// The muscle or routine involved.
        what: String,
        /// Why.
        reason: String,
    },
}

impl Error {
    /// Builds an [`Error::InvalidParameter`].
    pub fn invalid(name: impl Into<String>, value: impl ToString, expected: impl Into<String>) -> Self {
        Error::InvalidParameter {
            name: name.into(),
            value: value.to_string(),
            expected: expected.into(),
        }
    }
}

/// `Ok(v)` when `v` is finite, else an error naming `name`.
pub(crate) fn finite(name: impl Into<String>, v: f64) -> Result<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::invalid(name, v, "a finite number"))
    }
}

/// `Ok(v)` when `v` is finite and `> 0`.
pub(crate) fn positive(name: impl Into<String> + Clone, v: f64) -> Result<f64> {
    finite(name.clone(), v)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(Error::invalid(name, v, "> 0"))
    }
}

/// `Ok(v)` when `v` is finite and `>= 0`.
pub(crate) fn non_negative(name: impl Into<String> + Clone, v: f64) -> Result<f64> {
    finite(name.clone(), v)?;
    if v >= 0.0 {
        Ok(v)
    } else {
        Err(Error::invalid(name, v, ">= 0"))
    }
}
