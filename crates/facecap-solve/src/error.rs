//! The one error type of `facecap-solve`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Failures of rig loading, parameter validation and solving.
///
/// Numerical outcomes (iteration cap reached, BOBYQA stopped early) are not errors:
/// they are reported in [`crate::Report::stop`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An error from `facecap-core` (I/O, mesh and landmark-map formats).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
    /// A parameter is out of range or not finite.
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name as the user knows it.
        name: &'static str,
        /// Offending value, printed.
        value: String,
        /// Allowed range or form.
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
    /// A rig (meshes, names, landmark map) is inconsistent.
    #[error("invalid rig {source_name}: {reason}")]
    Rig {
        /// The file or description of the rig.
        source_name: String,
        /// What is wrong.
        reason: String,
    },
    /// A file in one of this crate's formats (e.g. `Shapes2d` JSON) is malformed.
    #[error("malformed {format} file {path}: {reason}")]
    Parse {
        /// Format name.
        format: &'static str,
        /// The file (empty for in-memory text).
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The input landmarks cannot be solved (e.g. non-finite or degenerate points).
    #[error("invalid input landmarks: {reason}")]
    Input {
        /// Why.
        reason: String,
    },
    /// A numerical routine failed (degenerate geometry, singular system).
    #[error("numerical failure in {operation}: {reason}")]
    Numerical {
        /// The routine.
        operation: &'static str,
        /// Why.
        reason: String,
    },
}

impl Error {
    /// Builds an [`Error::InvalidParameter`].
    pub fn invalid(name: &'static str, value: impl ToString, expected: impl Into<String>) -> Self {
        Error::InvalidParameter {
            name,
            value: value.to_string(),
            expected: expected.into(),
        }
    }

    /// Builds an [`Error::Rig`].
    pub fn rig(source_name: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::Rig {
            source_name: source_name.into(),
            reason: reason.into(),
        }
    }
}

/// Rejects NaN/inf and values outside `[lo, hi]`, naming the parameter.
pub(crate) fn check_range(name: &'static str, value: f64, lo: f64, hi: f64) -> Result<f64> {
    if !value.is_finite() || value < lo || value > hi {
        return Err(Error::invalid(name, value, format!("a finite number in [{lo}, {hi}]")));
    }
    Ok(value)
}

/// Rejects integers outside `[lo, hi]`.
pub(crate) fn check_count(name: &'static str, value: usize, lo: usize, hi: usize) -> Result<usize> {
    if value < lo || value > hi {
        return Err(Error::invalid(name, value, format!("an integer in [{lo}, {hi}]")));
    }
    Ok(value)
}
