//! The one error type of `facecap-pipeline`.

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// A boxed error from a hook the caller provides (e.g. a neutral calibration).
pub type BoxError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Failures of the pipeline: the algorithm crates' errors, and the pipeline's own.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// From `facecap-core` (I/O, video, formats).
    #[error(transparent)]
    Core(#[from] facecap_core::Error),
    /// From `facecap-landmarks`.
    #[error(transparent)]
    Landmarks(#[from] facecap_landmarks::Error),
    /// From `facecap-solve`.
    #[error(transparent)]
    Solve(#[from] facecap_solve::Error),
    /// From `facecap-tensor`.
    #[error(transparent)]
    Tensor(#[from] facecap_tensor::Error),
    /// From `facecap-muscle`.
    #[error(transparent)]
    Muscle(#[from] facecap_muscle::Error),
    /// From `facecap-mesh` (the dense face mesh front end).
    #[error(transparent)]
    Mesh(#[from] facecap_mesh::Error),
    /// A model file is not in the model cache.
    #[error("{name} is not in the model cache ({cache}): run scripts/setup.sh or pass the model's path")]
    MissingModel {
        /// The model's file name.
        name: String,
        /// Where the cache was looked for.
        cache: String,
    },
    /// The run was interrupted (Ctrl-C) before this frame.
    #[error("interrupted at frame {frame}")]
    Interrupted {
        /// The frame that was not processed.
        frame: u64,
    },
    /// A pipeline stage (thread) panicked.
    #[error("the {stage} stage panicked")]
    StagePanicked {
        /// Which stage.
        stage: &'static str,
    },
    /// The neutral calibration hook failed.
    #[error("neutral calibration: {0}")]
    Calibration(BoxError),
    /// A parameter is out of range.
    #[error("invalid {name} = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: String,
        /// Allowed range.
        expected: String,
    },
    /// A batch manifest line is not valid.
    #[error("{path}:{line}: {message}")]
    Manifest {
        /// The manifest file.
        path: std::path::PathBuf,
        /// 1-based line number (0: the whole file).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A sink written by the caller failed.
    #[error("{sink}: {source}")]
    Sink {
        /// The sink's name.
        sink: String,
        /// The error.
        #[source]
        source: BoxError,
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
}
