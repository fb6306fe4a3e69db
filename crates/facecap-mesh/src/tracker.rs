//! The 478-point face mesh per frame: detection, region of interest, landmark model,
//! projection back to the image, and tracking from the previous frame's landmarks, as
//! MediaPipe's FaceLandmarker does in video mode (`face_landmarker_graph.cc`,
//! `face_landmarks_detector_graph.cc`):
//!
//! * no face tracked: run the detector, take the best detection, region =
//!   [`Detection::to_rect`] with scale 1.5; where it finds none, facecap (not MediaPipe)
//!   looks again for small faces on windows of the image ([`MeshParams::small_faces`],
//!   [`FaceDetector::detect_small_into`]);
//! * landmarks: the region sampled to 256 x 256 (values in [0, 1], edge pixels
//!   replicated), the model's 478 (x, y, z) in tensor pixels mapped back with
//!   `p = c + R(theta) (l / 256 - 0.5) * size` (MediaPipe's `LandmarkProjectionCalculator`,
//!   which rotates in normalised units); face presence = `sigmoid(output 1)`;
//! * presence >= `min_presence`: the next frame's region is the axis-aligned bounding box
//!   of all landmarks, rotated so that landmarks 33 and 263 (the outer eye corners) are
//!   level, made square on its long side (in pixels) and scaled by 1.5; otherwise the face
//!   is lost and the next frame runs the detector again.
//!
//! MediaPipe also smooths the landmarks in video mode (a one-euro filter, see
//! [`crate::smoothing`]) before it returns them, while the next frame's region comes from
//! the raw landmarks. [`MeshTracker`] does the same when [`MeshParams::smoothing`] is set
//! (default: off, raw landmarks).
//!
//! Output coordinates: pixels, centre of the top-left pixel = (0, 0); `z` is MediaPipe's
//! relative depth scaled by the image width like x (smaller = closer to the camera).

use crate::detector::{check_unit, Detection, DetectorParams, DetectorWorkspace, FaceDetector};
use crate::roi::{Affine, BilinearTable, Border, NormRect, RgbView, ValueMap};
use crate::smoothing::{LandmarkSmoother, SmoothingParams};
use crate::tflite::{Interpreter, Workspace};
use crate::{Error, Result};

/// Landmark model input size.
pub const LANDMARK_INPUT: usize = 256;
/// Number of mesh landmarks (468 face points and 10 iris points).
pub const NUM_LANDMARKS: usize = 478;
/// Landmarks whose line sets the tracking rotation (outer corners of the eyes).
pub const ROTATION_LANDMARKS: [usize; 2] = [33, 263];
/// Centre landmarks of the two irises (468 = right iris of the subject, 473 = left).
pub const IRIS_CENTERS: [usize; 2] = [468, 473];

/// Tracker settings.
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `detector` | see [`DetectorParams`] | face detector settings | |
/// | `min_presence` | 0.5 | minimum face presence to keep tracking (`min_face_presence_confidence`) | [0, 1] |
/// | `roi_scale` | 1.5 | region size over the face box (MediaPipe's `scale_x/scale_y`) | [1, 4] |
/// | `smoothing` | `None` | one-euro smoothing of the output as FaceLandmarker's video mode | see [`SmoothingParams`] |
/// | `small_faces` | `true` | where the detector finds no face, look again for small faces ([`FaceDetector::detect_small_into`]; in a video at most every [`SMALL_FACE_INTERVAL`] frames) | |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshParams {
    /// Face detector settings.
    pub detector: DetectorParams,
    /// Minimum face presence score to accept landmarks and keep tracking.
    pub min_presence: f32,
    /// Region-of-interest scale.
    pub roi_scale: f32,
    /// Output smoothing (`None` = raw landmarks).
    pub smoothing: Option<SmoothingParams>,
    /// Look again for small faces where the whole-image detection finds none (MediaPipe
    /// does not: `false` is FaceLandmarker's behaviour).
    pub small_faces: bool,
}

/// Frames between two small-face searches while a video shows no face: the search costs
/// one detector run per window ([`FaceDetector::detect_small_into`]), so a long stretch
/// without a face is searched on every tenth frame (a third of a second at 30 frames/s).
pub const SMALL_FACE_INTERVAL: u32 = 10;

impl Default for MeshParams {
    fn default() -> Self {
        MeshParams {
            detector: DetectorParams::default(),
            min_presence: 0.5,
            roi_scale: 1.5,
            smoothing: None,
            small_faces: true,
        }
    }
}

impl MeshParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        self.detector.validate()?;
        check_unit("min_presence", self.min_presence)?;
        if !(1.0..=4.0).contains(&self.roi_scale) {
            return Err(Error::InvalidParameter {
                name: "roi_scale",
                value: self.roi_scale.to_string(),
                expected: "a number in [1, 4]".into(),
            });
        }
        if let Some(p) = self.smoothing {
            LandmarkSmoother::new(p)?;
        }
        Ok(())
    }
}

/// The two models: BlazeFace short range and the 478-point landmark model.
#[derive(Debug, Clone)]
pub struct MeshModels {
    /// Face detector model.
    pub detector: Interpreter,
    /// Landmark model.
    pub landmarks: Interpreter,
}

impl MeshModels {
    /// Loads both `.tflite` files.
    ///
    /// # Errors
    /// [`Error::Io`] or [`Error::Model`] naming the file.
    pub fn load(detector: &std::path::Path, landmarks: &std::path::Path) -> Result<Self> {
        Ok(MeshModels {
            detector: Interpreter::from_file(detector)?,
            landmarks: Interpreter::from_file(landmarks)?,
        })
    }

    /// Loads both models from the model cache (`scripts/setup.sh` puts them there).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] when a model is not in the cache, else as [`MeshModels::load`].
    pub fn from_cache() -> Result<Self> {
        let find = |name: &str| {
            facecap_core::paths::model_file(name).ok_or_else(|| Error::InvalidInput {
                what: format!("model {name} not in the model cache (run scripts/setup.sh)"),
            })
        };
        MeshModels::load(&find(crate::FACE_DETECTOR_MODEL)?, &find(crate::FACE_LANDMARKS_MODEL)?)
    }
}

/// The 478 landmarks of one face in one frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaceMesh {
    /// `(x, y, z)` in pixels (see the module docs), [`NUM_LANDMARKS`] entries.
    pub points: Vec<[f32; 3]>,
    /// Face presence score in [0, 1].
    pub presence: f32,
    /// The region the landmarks were computed in.
    pub rect: NormRect,
}

/// One face of a still image ([`MeshTracker::faces_in_image`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ImageFace {
    /// The face's 478 landmarks.
    pub mesh: FaceMesh,
    /// Score of the detection the landmarks were computed from.
    pub detection_score: f32,
}

impl ImageFace {
    /// Pixel bounding box `(left, top, right, bottom)` of the landmarks.
    pub fn bounds(&self) -> [f32; 4] {
        bounds(&self.mesh.points)
    }
}

/// Pixel bounding box `(left, top, right, bottom)` of points (`[inf, inf, -inf, -inf]`
/// for none).
fn bounds(points: &[[f32; 3]]) -> [f32; 4] {
    points.iter().fold(
        [f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY],
        |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])],
    )
}

/// Area of a `(left, top, right, bottom)` box (0 when empty).
fn area(b: &[f32; 4]) -> f32 {
    (b[2] - b[0]).max(0.0) * (b[3] - b[1]).max(0.0)
}

/// Intersection over union of two boxes.
fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let inter = area(&[a[0].max(b[0]), a[1].max(b[1]), a[2].min(b[2]), a[3].min(b[3])]);
    let union = area(a) + area(b) - inter;
    if union > 0.0 {
        inter / union
    } else {
        0.0
    }
}

/// At most this many detections of one image get the landmark model
/// ([`MeshTracker::faces_in_image`]).
pub const MAX_IMAGE_DETECTIONS: usize = 64;

/// Faces of a still image whose landmark boxes overlap more than this (intersection over
/// union) are one face found twice ([`MeshTracker::faces_in_image`]).
pub const SAME_FACE_IOU: f32 = 0.3;

/// What carries between frames (make one per video with [`MeshTracker::state`]).
#[derive(Debug, Clone, Default)]
pub struct MeshState {
    /// Region for the next frame (from the last landmarks); `None` = run the detector.
    pub next_rect: Option<NormRect>,
    /// Smoothing filters, when [`MeshParams::smoothing`] is set.
    pub smoother: Option<LandmarkSmoother>,
    /// Frames to go before the next small-face search (0 = search on the next frame
    /// without a face; see [`SMALL_FACE_INTERVAL`]).
    pub small_face_wait: u32,
}

/// How a frame went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshStatus {
    /// Landmarks computed in the region tracked from the previous frame.
    Tracked,
    /// The detector found the face and landmarks were computed in its region.
    Detected,
    /// The detector found no face.
    NoFace,
    /// The landmark model's presence score was below `min_presence` (face lost; the
    /// next frame runs the detector).
    Lost,
}

/// Per-frame report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshReport {
    /// Outcome.
    pub status: MeshStatus,
    /// Whether the detector ran on this frame.
    pub detector_ran: bool,
    /// Score of the detection used (0 when none).
    pub detection_score: f32,
    /// Face presence score of the landmark model (0 when it did not run).
    pub presence: f32,
}

impl MeshReport {
    /// Whether `out` holds landmarks for this frame.
    pub fn has_face(&self) -> bool {
        matches!(self.status, MeshStatus::Tracked | MeshStatus::Detected)
    }
}

/// Per-thread buffers.
#[derive(Debug, Clone)]
pub struct MeshWorkspace {
    detector: DetectorWorkspace,
    landmarks: Workspace,
    detections: Vec<Detection>,
    norm: Vec<[f32; 3]>,
}

/// Face mesh tracker: immutable, `Send + Sync`; one [`MeshWorkspace`] per thread and one
/// [`MeshState`] per video.
#[derive(Debug, Clone)]
pub struct MeshTracker {
    detector: FaceDetector,
    landmarks: Interpreter,
    params: MeshParams,
    table: BilinearTable,
}

impl MeshTracker {
    /// Builds the tracker.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for bad settings, [`Error::Model`] when a model does
    /// not have the expected inputs and outputs.
    pub fn new(models: MeshModels, params: MeshParams) -> Result<Self> {
        params.validate()?;
        let lm = models.landmarks;
        let ok = lm.input_shape(0) == Some(&[1, LANDMARK_INPUT, LANDMARK_INPUT, 3][..])
            && lm.output_shape(0).map(|s| s.iter().product::<usize>()) == Some(NUM_LANDMARKS * 3)
            && lm.output_shape(1).map(|s| s.iter().product::<usize>()) == Some(1);
        if !ok {
            return Err(Error::Model {
                reason:
                    "not a 478-point face landmark model (expected [1,256,256,3] -> 1434 values and a presence score)"
                        .into(),
            });
        }
        Ok(MeshTracker {
            detector: FaceDetector::new(models.detector, params.detector)?,
            landmarks: lm,
            params,
            table: BilinearTable::new(),
        })
    }

    /// The settings.
    pub fn params(&self) -> &MeshParams {
        &self.params
    }

    /// The face detector.
    pub fn detector(&self) -> &FaceDetector {
        &self.detector
    }

    /// A fresh per-video state.
    pub fn state(&self) -> MeshState {
        MeshState {
            next_rect: None,
            smoother: self.params.smoothing.and_then(|p| LandmarkSmoother::new(p).ok()),
            small_face_wait: 0,
        }
    }

    /// Buffers for one thread.
    pub fn workspace(&self) -> MeshWorkspace {
        MeshWorkspace {
            detector: self.detector.workspace(),
            landmarks: self.landmarks.workspace(),
            detections: Vec::with_capacity(16),
            norm: Vec::with_capacity(NUM_LANDMARKS),
        }
    }

    /// Runs the landmark model in `rect`; fills `out` and `ws.norm` (normalised image
    /// coordinates); returns the presence score.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another tracker.
    pub fn landmarks_in(
        &self,
        img: &RgbView<'_>,
        rect: &NormRect,
        ws: &mut MeshWorkspace,
        out: &mut FaceMesh,
    ) -> Result<f32> {
        let (w, h) = (img.width, img.height);
        let map = Affine::for_rect(rect, w, h, LANDMARK_INPUT);
        let input = self.landmarks.input_mut(&mut ws.landmarks, 0)?;
        crate::roi::warp_to_tensor(
            img,
            &map,
            LANDMARK_INPUT,
            Border::Replicate,
            ValueMap::UNIT,
            &self.table,
            input,
        );
        self.landmarks.run(&mut ws.landmarks)?;
        let raw = self.landmarks.output(&ws.landmarks, 0)?;
        let logit = self
            .landmarks
            .output(&ws.landmarks, 1)?
            .first()
            .copied()
            .unwrap_or(f32::NEG_INFINITY);
        let presence = 1.0 / (1.0 + (-logit).exp());
        let n = LANDMARK_INPUT as f32;
        let (s, c) = rect.rotation.sin_cos();
        ws.norm.clear();
        out.points.clear();
        for p in raw.chunks_exact(3) {
            let (x, y) = (p[0] / n - 0.5, p[1] / n - 0.5);
            let nx = (c * x - s * y) * rect.width + rect.x_center;
            let ny = (s * x + c * y) * rect.height + rect.y_center;
            let nz = p[2] / n * rect.width;
            ws.norm.push([nx, ny, nz]);
            // `nx * w` is the coordinate the warp sampled at (OpenCV's, centre of the
            // top-left pixel = 0), i.e. the project's pixel convention, and equals
            // MediaPipe's normalised output times the image size.
            out.points.push([nx * w as f32, ny * h as f32, nz * w as f32]);
        }
        out.presence = presence;
        out.rect = *rect;
        Ok(presence)
    }

    /// The next frame's region from normalised landmarks (see the module docs).
    pub fn rect_from_landmarks(&self, norm: &[[f32; 3]], w: usize, h: usize) -> Option<NormRect> {
        let (mut x0, mut y0, mut x1, mut y1) = (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        for p in norm {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        let (a, b) = (norm.get(ROTATION_LANDMARKS[0])?, norm.get(ROTATION_LANDMARKS[1])?);
        if !(x1 > x0 && y1 > y0) {
            return None;
        }
        let rotation =
            crate::roi::rotation_from([a[0] * w as f32, a[1] * h as f32], [b[0] * w as f32, b[1] * h as f32]);
        let long = ((x1 - x0) * w as f32).max((y1 - y0) * h as f32);
        Some(NormRect {
            x_center: (x0 + x1) / 2.0,
            y_center: (y0 + y1) / 2.0,
            width: long / w as f32 * self.params.roi_scale,
            height: long / h as f32 * self.params.roi_scale,
            rotation,
        })
    }

    /// Every face of a still image, largest first (FaceLandmarker's IMAGE mode with
    /// `num_faces` unbounded, plus facecap's small-face search):
    ///
    /// * the detector runs on the whole image and, unless [`MeshParams::small_faces`] is
    ///   off, on the small-face windows as well ([`FaceDetector::detect_small_into`]), so a
    ///   group photo's far faces are found next to its near ones;
    /// * each detection (the whole image's first, each list best first; at most
    ///   [`MAX_IMAGE_DETECTIONS`]) gets the landmark model in its region, unless its box
    ///   centre lies inside a face already found;
    /// * a face is kept when its presence is at least `min_presence`, its landmarks are
    ///   finite, and its landmark box overlaps no kept face's by more than
    ///   [`SAME_FACE_IOU`] (the same face found by both passes).
    ///
    /// Allocates its result; for video use [`MeshTracker::track_into`].
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another tracker.
    pub fn faces_in_image(&self, img: &RgbView<'_>, ws: &mut MeshWorkspace) -> Result<Vec<ImageFace>> {
        let (w, h) = (img.width, img.height);
        self.detector.detect_into(img, &mut ws.detector, &mut ws.detections)?;
        let mut detections = ws.detections.clone();
        if self.params.small_faces {
            self.detector
                .detect_small_into(img, &mut ws.detector, &mut ws.detections)?;
            detections.extend_from_slice(&ws.detections);
        }
        detections.truncate(MAX_IMAGE_DETECTIONS);
        let mut faces: Vec<ImageFace> = Vec::new();
        let mut boxes: Vec<[f32; 4]> = Vec::new();
        let mut mesh = FaceMesh::default();
        for d in &detections {
            let (cx, cy) = (
                (d.xmin + d.width / 2.0) * w as f32,
                (d.ymin + d.height / 2.0) * h as f32,
            );
            if boxes
                .iter()
                .any(|b| cx >= b[0] && cx <= b[2] && cy >= b[1] && cy <= b[3])
            {
                continue;
            }
            let rect = d.to_rect(w, h, self.params.roi_scale);
            let presence = self.landmarks_in(img, &rect, ws, &mut mesh)?;
            let finite = mesh.points.iter().flatten().all(|v| v.is_finite());
            if !(presence >= self.params.min_presence && finite && mesh.points.len() == NUM_LANDMARKS) {
                continue;
            }
            let b = bounds(&mesh.points);
            if boxes.iter().any(|k| iou(k, &b) > SAME_FACE_IOU) {
                continue;
            }
            boxes.push(b);
            faces.push(ImageFace {
                mesh: mesh.clone(),
                detection_score: d.score,
            });
        }
        faces.sort_by(|a, b| area(&b.bounds()).total_cmp(&area(&a.bounds())));
        Ok(faces)
    }

    /// The small-face search of a frame without a face ([`MeshParams::small_faces`]):
    /// runs [`FaceDetector::detect_small_into`] into the workspace's detections unless it
    /// is off or waiting ([`SMALL_FACE_INTERVAL`]); returns whether it ran.
    fn search_small(&self, img: &RgbView<'_>, ws: &mut MeshWorkspace, state: &mut MeshState) -> Result<bool> {
        if !self.params.small_faces {
            return Ok(false);
        }
        if state.small_face_wait > 0 {
            state.small_face_wait -= 1;
            return Ok(false);
        }
        self.detector
            .detect_small_into(img, &mut ws.detector, &mut ws.detections)?;
        if ws.detections.is_empty() {
            state.small_face_wait = SMALL_FACE_INTERVAL;
        }
        Ok(true)
    }

    /// Processes one frame taken at `timestamp_s` seconds (used by smoothing only).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a workspace of another tracker.
    pub fn track_into(
        &self,
        img: &RgbView<'_>,
        timestamp_s: f64,
        ws: &mut MeshWorkspace,
        state: &mut MeshState,
        out: &mut FaceMesh,
    ) -> Result<MeshReport> {
        let (w, h) = (img.width, img.height);
        let mut report = MeshReport {
            status: MeshStatus::Tracked,
            detector_ran: false,
            detection_score: 0.0,
            presence: 0.0,
        };
        let mut small_searched = false;
        let rect = match state.next_rect {
            Some(r) => r,
            None => {
                report.detector_ran = true;
                self.detector.detect_into(img, &mut ws.detector, &mut ws.detections)?;
                if ws.detections.is_empty() {
                    small_searched = self.search_small(img, ws, state)?;
                }
                let Some(d) = ws.detections.first() else {
                    report.status = MeshStatus::NoFace;
                    if let Some(s) = &mut state.smoother {
                        s.reset();
                    }
                    return Ok(report);
                };
                report.status = MeshStatus::Detected;
                report.detection_score = d.score;
                d.to_rect(w, h, self.params.roi_scale)
            }
        };
        report.presence = self.landmarks_in(img, &rect, ws, out)?;
        if report.presence < self.params.min_presence
            && report.detector_ran
            && !small_searched
            && self.search_small(img, ws, state)?
        {
            // the whole image's detection was no face the landmark model accepts (a
            // group photo's far faces, a pattern): the small faces' best, if any
            if let Some(d) = ws.detections.first().copied() {
                report.detection_score = d.score;
                let rect = d.to_rect(w, h, self.params.roi_scale);
                report.presence = self.landmarks_in(img, &rect, ws, out)?;
            }
        }
        if report.presence < self.params.min_presence {
            report.status = MeshStatus::Lost;
            state.next_rect = None;
            if let Some(s) = &mut state.smoother {
                s.reset();
            }
            return Ok(report);
        }
        state.next_rect = self.rect_from_landmarks(&ws.norm, w, h);
        state.small_face_wait = 0;
        if let Some(s) = &mut state.smoother {
            s.apply(timestamp_s, out);
        }
        Ok(report)
    }
}
