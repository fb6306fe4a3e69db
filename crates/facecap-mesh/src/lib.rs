//! Dense face mesh front end: MediaPipe's face detector (BlazeFace short range) and
//! 478-point face landmark model (v2, with irises), run in pure Rust.
//!
//! * [`tflite`]: the `facecap-tflite` crate, re-exported: a bounds-checked TFLite
//!   flatbuffer reader and a small float32 interpreter for the ten operators these
//!   models use.
//! * [`detector`]: BlazeFace decoding (anchors, scores, boxes, weighted NMS).
//! * [`roi`]: rotated regions and the image-to-tensor warp.
//! * [`tracker`]: [`MeshTracker`], detection + landmarks + tracking per frame.
//! * [`smoothing`]: MediaPipe's video-mode one-euro smoothing.
//! * [`ibug68`], [`eyes`]: the mesh read as the 68 iBUG points; the eye outlines and iris
//!   centres (gaze).
//!
//! ```no_run
//! use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshTracker, RgbView};
//! # fn main() -> facecap_mesh::Result<()> {
//! let tracker = MeshTracker::new(MeshModels::from_cache()?, MeshParams::default())?;
//! let (mut ws, mut state, mut mesh) = (tracker.workspace(), tracker.state(), FaceMesh::default());
//! let img = image::RgbImage::new(640, 480); // a video frame
//! let report = tracker.track_into(&RgbView::from_image(&img)?, 0.0, &mut ws, &mut state, &mut mesh)?;
//! if report.has_face() {
//!     println!("nose tip at {:?}", mesh.points[1]);
//! }
//! # Ok(())
//! # }
//! ```
//!
//! The models come from MediaPipe's `face_landmarker.task` bundle (Apache-2.0), fetched
//! by `scripts/setup.sh` into the model cache ([`FACE_DETECTOR_MODEL`],
//! [`FACE_LANDMARKS_MODEL`]).

pub mod canonical;
pub mod detector;
pub mod error;
pub mod eyes;
pub mod ibug68;
pub mod roi;
pub mod smoothing;
pub mod tracker;

pub use facecap_tflite as tflite;

pub use detector::{Detection, DetectorParams, FaceDetector, Window};
pub use error::{Error, Result};
pub use roi::{NormRect, RgbView};
pub use smoothing::{LandmarkSmoother, SmoothingParams};
pub use tracker::{
    FaceMesh, ImageFace, MeshModels, MeshParams, MeshReport, MeshState, MeshStatus, MeshTracker, MeshWorkspace,
    MAX_IMAGE_DETECTIONS, SAME_FACE_IOU, SMALL_FACE_INTERVAL,
};

/// File name of the BlazeFace short-range detector in the model cache.
pub const FACE_DETECTOR_MODEL: &str = "face_detector.tflite";
/// File name of the 478-point face landmark model in the model cache.
pub const FACE_LANDMARKS_MODEL: &str = "face_landmarks_detector.tflite";
