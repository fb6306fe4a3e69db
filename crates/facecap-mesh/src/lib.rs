//! Dense face mesh front end: MediaPipe's face detector (BlazeFace short range) and
//! 478-point face landmark model (v2, with irises), run in pure Rust.
//!
//! * [`tflite`]: a bounds-checked TFLite flatbuffer reader and a small float32
//!   interpreter for the ten operators these models use.
//!
//! The models come from MediaPipe's `face_landmarker.task` bundle (Apache-2.0), fetched
//! by `scripts/setup.sh` into the model cache ([`FACE_DETECTOR_MODEL`],
//! [`FACE_LANDMARKS_MODEL`]).

pub mod error;
pub mod tflite;

pub use error::{Error, Result};

/// File name of the BlazeFace short-range detector in the model cache.
pub const FACE_DETECTOR_MODEL: &str = "face_detector.tflite";
/// File name of the 478-point face landmark model in the model cache.
pub const FACE_LANDMARKS_MODEL: &str = "face_landmarks_detector.tflite";
