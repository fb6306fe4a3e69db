//! The video tracker: one model lookup, one tracker policy, and the threaded
//! decode -> track -> sinks loop every command uses.
//!
//! Three stages on their own threads joined by short bounded FIFO queues (4 decoded
//! frames, 16 tracked frames), so decoding, tracking and the sinks overlap and frames
//! stay in order: **decode** reads the source into recycled [`Frame`] buffers (decoded
//! frames come back to the decoder once tracked, so the loop allocates no image memory
//! per frame); **track** (the calling thread) runs the landmark tracker; **sinks** (one
//! thread) hands every tracked frame to each sink in turn. Each stage's busy time is
//! reported. The outputs are byte-identical to running the stages one after the other.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use facecap_core::landmarks::Landmarks68;
use facecap_io::csv::LandmarkRecord;
use facecap_io::video::{open_source, Frame, FrameSource, SourceOptions, VideoInfo};
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::ErtWorkspace;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::gaze::{IrisEstimator, IrisFrame, IrisParams, IrisWorkspace};
use facecap_landmarks::tracker::backends::DetectorWs;
use facecap_landmarks::tracker::one_euro::OneEuroParams;
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState, TrackerWorkspace};

use crate::error::{Error, Result};
use crate::sink::{Sink, TrackedFace};

/// Queue length between decoding and tracking (frames).
const DECODED_QUEUE: usize = 4;
/// Queue length between tracking and the sinks (frames).
const TRACKED_QUEUE: usize = 16;
/// Queue lengths between the stages of [`VideoTracker::run_with_queues`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Queues {
    /// Decoded frames waiting for the tracker.
    pub decoded: usize,
    /// Tracked frames waiting for the sinks.
    pub tracked: usize,
}

impl Queues {
    /// Files: short FIFO queues so the stages overlap (4 decoded, 16 tracked frames).
    pub const FILE: Queues = Queues {
        decoded: DECODED_QUEUE,
        tracked: TRACKED_QUEUE,
    };
    /// Live input: no queue at all (each stage hands a frame straight to the next), so
    /// no frame waits behind another; with a source that keeps only the newest frame
    /// ([`crate::live::LatestFrame`]) the delay cannot grow.
    pub const LIVE: Queues = Queues { decoded: 0, tracked: 0 };
}

/// Largest number of sinks in one run (one bit each in [`Tracked::wanted`]).
pub const MAX_SINKS: usize = 64;

/// Consecutive decode errors after which a damaged source is given up (each error
/// consumes one frame index, so a source that keeps failing cannot loop for ever).
pub const MAX_CONSECUTIVE_DECODE_ERRORS: u32 = 10_000;

/// What the decoding stage hands to tracking: a frame, or a frame that could not be
/// decoded (salvage mode, [`RunControl::strict`] off).
enum Decoded {
    Frame(Frame),
    Failed { index: u64, timestamp: f64, reason: String },
}

/// A tracked frame on its way to the sinks, with which sinks asked for its image.
struct Tracked {
    face: TrackedFace,
    /// Bit `k`: sink `k` asked for this frame's image.
    wanted: u64,
}

/// How every command tracks landmarks.
///
/// | name | default | meaning |
/// |---|---|---|
/// | `smooth` | false | `dlib68`: One Euro filter on the landmarks (less jitter on still faces, lag on fast motion; docs/tracking.md); `mesh`: MediaPipe's video-mode one-euro smoothing of the 478 points (docs/mesh.md) |
/// | `shape_model` | the cache's `shape_predictor_68_face_landmarks.dat` | dlib 68-point model file (`dlib68` only) |
///
/// The shape predictor always returns sub-pixel landmarks (dlib rounds to whole
/// pixels, which adds jitter to tracking); the face detector is the built-in dlib HOG
/// model. `shape_model`, `upsample` and `ert_precision` are dlib's and unused by the
/// `mesh` front end, which loads none of dlib's models.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerPolicy {
    /// Smooth landmarks with the One Euro filter.
    pub smooth: bool,
    /// The 68-point model file (`None`: the model cache).
    pub shape_model: Option<PathBuf>,
    /// Detector upsampling (`Upsample::Auto`: dlib's `detector(img, 1)` recall at less cost).
    pub upsample: facecap_landmarks::detect::Upsample,
    /// ERT leaf precision (`Exact`: dlib's landmarks; `Fast`: 16-bit leaves).
    pub ert_precision: facecap_landmarks::ert::ErtPrecision,
    /// Which landmarks: dlib's 68 points, or the 478-point face mesh read as 68 points.
    pub front_end: FrontEnd,
}

/// Where the 68 landmarks come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrontEnd {
    /// dlib's HOG detector and 68-point ERT shape predictor, tracked with LK.
    #[default]
    Dlib68,
    /// MediaPipe's face detector and 478-point face mesh model (run by `facecap-mesh`),
    /// read as the 68 iBUG points ([`facecap_mesh::ibug68`]); needs colour frames.
    Mesh,
}

impl FrontEnd {
    /// The name of the front end: the value of `--landmarks`, also in `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            FrontEnd::Dlib68 => "dlib68",
            FrontEnd::Mesh => "mesh",
        }
    }
}

impl std::fmt::Display for FrontEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for FrontEnd {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        [FrontEnd::Dlib68, FrontEnd::Mesh]
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| Error::invalid("landmark front end", s, "`dlib68` or `mesh`"))
    }
}

impl Default for TrackerPolicy {
    /// No smoothing, the cached model, automatic upsampling (what every command uses).
    fn default() -> Self {
        TrackerPolicy {
            smooth: false,
            shape_model: None,
            upsample: facecap_landmarks::detect::Upsample::Auto,
            ert_precision: facecap_landmarks::ert::ErtPrecision::Exact,
            front_end: FrontEnd::Dlib68,
        }
    }
}

impl TrackerPolicy {
    /// The 68-point model's path: [`TrackerPolicy::shape_model`] or the cache's.
    ///
    /// # Errors
    /// [`Error::MissingModel`] when the cache has no model.
    pub fn shape_model_path(&self) -> Result<PathBuf> {
        if let Some(p) = &self.shape_model {
            return Ok(p.clone());
        }
        let name = facecap_core::paths::DLIB_68_MODEL;
        facecap_core::paths::model_file(name).ok_or_else(|| Error::MissingModel {
            name: name.to_string(),
            cache: facecap_core::paths::model_dir().map_or_else(|| "unknown".into(), |d| d.display().to_string()),
        })
    }
}

/// The landmark tracker every command runs (module docs).
#[derive(Debug)]
pub struct VideoTracker {
    front: Front,
}

/// The loaded landmark front end: only the models it runs.
#[derive(Debug)]
enum Front {
    /// dlib's HOG detector and ERT shape predictor; gaze from the grey frame
    /// ([`IrisEstimator`] on the six eye landmarks).
    Dlib68 {
        tracker: Box<LandmarkTracker<FaceDetector, ShapePredictor>>,
        iris: IrisEstimator,
    },
    /// MediaPipe's face detector and face mesh; gaze from the mesh's iris landmarks
    /// between its eye corners and lids ([`mesh_iris`]).
    Mesh {
        tracker: Box<facecap_mesh::MeshTracker>,
        iris: IrisParams,
    },
}

/// One run's workspaces and between-frame state of the front end.
enum FrontRun<'a> {
    Dlib68 {
        tracker: &'a LandmarkTracker<FaceDetector, ShapePredictor>,
        ws: Box<TrackerWorkspace<DetectorWs, ErtWorkspace>>,
        state: Box<TrackerState>,
        iris: &'a IrisEstimator,
        iris_ws: IrisWorkspace,
    },
    Mesh {
        tracker: &'a facecap_mesh::MeshTracker,
        ws: Box<facecap_mesh::MeshWorkspace>,
        state: facecap_mesh::MeshState,
        mesh: facecap_mesh::FaceMesh,
        iris: &'a IrisParams,
    },
}

impl<'a> FrontRun<'a> {
    fn new(front: &'a Front) -> Self {
        match front {
            Front::Dlib68 { tracker, iris } => FrontRun::Dlib68 {
                tracker,
                ws: Box::new(tracker.new_workspace()),
                state: Box::new(TrackerState::new()),
                iris,
                iris_ws: iris.new_workspace(),
            },
            Front::Mesh { tracker, iris } => FrontRun::Mesh {
                tracker,
                ws: Box::new(tracker.workspace()),
                state: tracker.state(),
                mesh: facecap_mesh::FaceMesh::default(),
                iris,
            },
        }
    }

    /// Forgets the face: the next frame starts from a fresh detection (after a frame
    /// that could not be decoded, or landmarks rejected as implausible).
    fn restart(&mut self) {
        match self {
            FrontRun::Dlib68 { state, .. } => **state = TrackerState::new(),
            FrontRun::Mesh { tracker, state, .. } => *state = tracker.state(),
        }
    }

    /// Tracks one frame into `out`.
    fn track(&mut self, frame: &Frame, out: &mut TrackedFrame) -> Result<()> {
        match self {
            FrontRun::Dlib68 { tracker, ws, state, .. } => {
                tracker.track_into(&frame.gray, frame.timestamp_s, ws, state, out)?;
                Ok(())
            }
            FrontRun::Mesh {
                tracker,
                ws,
                state,
                mesh,
                ..
            } => track_mesh(tracker, frame, ws, state, mesh, out),
        }
    }

    /// The gaze signal of the frame just tracked, whose landmarks are `landmarks`.
    fn iris(&mut self, frame: &Frame, landmarks: &Landmarks68, out: &mut IrisFrame) -> bool {
        match self {
            FrontRun::Dlib68 { iris, iris_ws, .. } => iris.estimate_into(&frame.gray, landmarks, iris_ws, out).is_ok(),
            FrontRun::Mesh { mesh, iris, .. } => mesh_iris(&mesh.points, iris, out),
        }
    }

    /// The 478 mesh points of the frame just tracked (mesh front end only).
    fn mesh_points(&self) -> Option<&[[f32; 3]]> {
        match self {
            FrontRun::Dlib68 { .. } => None,
            FrontRun::Mesh { mesh, .. } => Some(&mesh.points),
        }
    }
}

/// Both eyes' gaze from the mesh's iris centres (468, 473) in the eye frame of the mesh's
/// corners and lids ([`facecap_mesh::eyes`], [`facecap_landmarks::gaze::eye_from_centre`]):
/// the same `(u, v)` as the grey-frame estimator measures, so the resting gaze and the
/// `eyeLook*` mapping apply unchanged. `false` (and `out` untouched) for a mesh without
/// its 478 points.
pub fn mesh_iris(points: &[[f32; 3]], params: &IrisParams, out: &mut IrisFrame) -> bool {
    use facecap_landmarks::gaze::{eye_from_centre, Eye};
    use facecap_mesh::eyes;
    let p2 = |(x, y): (f64, f64)| nalgebra::Point2::new(x, y);
    let one = |outline: &[usize; 6], iris: usize, eye: Eye| {
        eyes::eye(points, outline, iris).map(|(o, c)| eye_from_centre(&o.map(p2), p2(c), eye, params))
    };
    let (Some(right), Some(left)) = (
        one(&eyes::RIGHT_EYE_OUTLINE, eyes::RIGHT_IRIS_CENTER, Eye::Right),
        one(&eyes::LEFT_EYE_OUTLINE, eyes::LEFT_IRIS_CENTER, Eye::Left),
    ) else {
        return false;
    };
    out.right = right;
    out.left = left;
    true
}

/// Per-run controls: interruption and a per-frame callback on the tracking thread.
#[derive(Default)]
pub struct RunControl<'a> {
    /// Set (e.g. by a Ctrl-C handler) to stop at the next frame with
    /// [`Error::Interrupted`].
    pub interrupted: Option<&'a AtomicBool>,
    /// Called on the calling thread after each tracked frame (progress bars).
    pub on_frame: Option<&'a mut dyn FnMut()>,
    /// Stop at the first frame that cannot be decoded (the run fails with its error).
    /// Off (the default): every decodable frame is kept, each undecodable one reaches
    /// the sinks as a frame without a face and is listed in [`RunReport::undecodable`].
    pub strict: bool,
}

impl std::fmt::Debug for RunControl<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunControl")
            .field("interrupted", &self.interrupted)
            .field("on_frame", &self.on_frame.is_some())
            .field("strict", &self.strict)
            .finish()
    }
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RunReport {
    /// The source's stream properties (`None` for a replayed landmarks CSV).
    pub info: Option<VideoInfo>,
    /// Frames processed.
    pub frames: u64,
    /// Frames with a tracked face.
    pub faces: u64,
    /// Busy seconds of the decoding stage.
    pub decode_seconds: f64,
    /// Busy seconds of the tracking stage.
    pub track_seconds: f64,
    /// Busy seconds of each sink, by [`Sink::name`], in the order given.
    pub sink_seconds: Vec<(String, f64)>,
    /// Frames whose landmarks were rejected as implausible ([`implausible_landmarks`]):
    /// (frame index, reason). They reach the sinks as frames without a face.
    pub rejected: Vec<(u64, String)>,
    /// Frames that could not be decoded (salvage mode): (frame index, reason). They
    /// reach the sinks as frames without a face.
    pub undecodable: Vec<(u64, String)>,
}

/// How far outside the image a landmark may lie, as a fraction of the image's size
/// (faces cut by the frame edge have points a little outside it).
pub const MAX_OUTSIDE_IMAGE_FRACTION: f64 = 0.5;
/// Largest plausible landmark coordinate when the image size is unknown (a replayed CSV), px.
pub const MAX_LANDMARK_COORD: f64 = 1e6;
/// Smallest plausible extent of the 68 landmarks along x and along y, px.
pub const MIN_FACE_EXTENT_PX: f64 = 1.0;

/// `Ok` when tracked landmarks are plausible, else why not: a non-finite point, a point
/// more than [`MAX_OUTSIDE_IMAGE_FRACTION`] of the image outside it (`image` = width,
/// height; without it, beyond [`MAX_LANDMARK_COORD`]), or all points within
/// [`MIN_FACE_EXTENT_PX`] of each other along x or y (68 identical points).
///
/// # Errors
/// The reason, as text.
pub fn implausible_landmarks(l: &Landmarks68, image: Option<(u32, u32)>) -> std::result::Result<(), String> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for (i, p) in l.points.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite()) {
            return Err(format!("implausible landmarks: point {i} is not finite"));
        }
        let inside = match image {
            Some((w, h)) => {
                let (w, h) = (f64::from(w), f64::from(h));
                let (mx, my) = (MAX_OUTSIDE_IMAGE_FRACTION * w, MAX_OUTSIDE_IMAGE_FRACTION * h);
                (-mx..=w + mx).contains(&p.x) && (-my..=h + my).contains(&p.y)
            }
            None => p.x.abs() <= MAX_LANDMARK_COORD && p.y.abs() <= MAX_LANDMARK_COORD,
        };
        if !inside {
            let size = image.map_or_else(String::new, |(w, h)| format!(" on a {w}x{h} image"));
            return Err(format!(
                "implausible landmarks: point {i} at ({:.1}, {:.1}){size}",
                p.x, p.y
            ));
        }
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    if x1 - x0 < MIN_FACE_EXTENT_PX || y1 - y0 < MIN_FACE_EXTENT_PX {
        return Err(format!(
            "implausible landmarks: all 68 points within {:.2} x {:.2} px (degenerate)",
            x1 - x0,
            y1 - y0
        ));
    }
    Ok(())
}

impl RunReport {
    /// Busy seconds of the sink called `name` (0 when there is none).
    pub fn sink_seconds(&self, name: &str) -> f64 {
        self.sink_seconds
            .iter()
            .filter(|(n, _)| n == name)
            .fold(0.0, |acc, (_, s)| acc + s)
    }
}

/// Opens a video file, Y4M file or image folder with `decode_threads` ffmpeg threads
/// (0 = ffmpeg's choice; one per video costs the least CPU per frame).
///
/// # Errors
/// As [`facecap_io::video::open_source`].
pub fn open_video(path: &Path, decode_threads: u32) -> Result<Box<dyn FrameSource>> {
    open_video_with(path, decode_threads, true)
}

/// [`open_video`] with ffmpeg's strictness: `strict` stops at the first decode error
/// (pair it with [`RunControl::strict`]); otherwise ffmpeg drops damaged frames and goes
/// on (the frames it delivers are intact, docs/video.md) and the source reports each
/// dropped frame as a decode error of its own, so salvage mode marks exactly those.
///
/// # Errors
/// As [`facecap_io::video::open_source`].
pub fn open_video_with(path: &Path, decode_threads: u32, strict: bool) -> Result<Box<dyn FrameSource>> {
    open_video_rgb(path, decode_threads, strict, false)
}

/// [`open_video_with`], with colour frames too when `rgb` ([`VideoTracker::needs_rgb`]).
///
/// # Errors
/// As [`facecap_io::video::open_source`].
pub fn open_video_rgb(path: &Path, decode_threads: u32, strict: bool, rgb: bool) -> Result<Box<dyn FrameSource>> {
    Ok(open_source(
        path,
        &SourceOptions {
            threads: decode_threads,
            strict,
            rgb,
            ..SourceOptions::default()
        },
    )?)
}

/// One frame through the mesh front end into `out` (as the dlib tracker fills it): the
/// 68 iBUG points of the mesh, its presence score as the confidence, the box of the
/// 68 points.
fn track_mesh(
    tracker: &facecap_mesh::MeshTracker,
    frame: &Frame,
    ws: &mut facecap_mesh::MeshWorkspace,
    state: &mut facecap_mesh::MeshState,
    mesh: &mut facecap_mesh::FaceMesh,
    out: &mut TrackedFrame,
) -> Result<()> {
    let Some(rgb) = frame.rgb.as_ref() else {
        return Err(Error::invalid(
            "frame",
            "a grey frame",
            "colour frames for the mesh front end (open the source with rgb)",
        ));
    };
    let report = tracker.track_into(
        &facecap_mesh::RgbView::from_image(rgb)?,
        frame.timestamp_s,
        ws,
        state,
        mesh,
    )?;
    out.success = false;
    out.confidence = 0.0;
    out.rect = None;
    if !report.has_face() {
        return Ok(());
    }
    let Some(points) = facecap_mesh::ibug68::ibug68(&mesh.points) else {
        return Ok(());
    };
    out.landmarks = Landmarks68::from_fn(|i| points[i]);
    out.raw = out.landmarks.clone();
    out.success = out.landmarks.is_finite();
    out.confidence = f64::from(report.presence).clamp(0.0, 1.0);
    out.rect = Some(out.landmarks.bounding_box());
    Ok(())
}

impl VideoTracker {
    /// Loads the detector and the shape predictor once for `policy`.
    ///
    /// # Errors
    /// A missing or unreadable model file.
    /// Loads the models of `policy`'s front end once: dlib's detector and shape predictor
    /// for `dlib68`, MediaPipe's detector and face mesh for `mesh` (not both).
    pub fn new(policy: &TrackerPolicy) -> Result<Self> {
        let front = match policy.front_end {
            FrontEnd::Dlib68 => {
                let detector = FaceDetector::default_model()?.with_upsample(policy.upsample)?;
                let path = policy.shape_model_path()?;
                let ert = ShapePredictor::from_file_cached(&path)?.0.with_params(ErtParams {
                    output: OutputPrecision::SubPixel,
                    precision: policy.ert_precision,
                });
                let mut params = TrackerParams::default();
                if policy.smooth {
                    params.filter = Some(OneEuroParams::default());
                }
                Front::Dlib68 {
                    tracker: Box::new(LandmarkTracker::new(detector, ert, params)?),
                    iris: IrisEstimator::new(IrisParams::default())?,
                }
            }
            FrontEnd::Mesh => {
                let params = facecap_mesh::MeshParams {
                    smoothing: policy.smooth.then(facecap_mesh::SmoothingParams::default),
                    ..facecap_mesh::MeshParams::default()
                };
                let iris = IrisParams::default();
                iris.validate()?;
                Front::Mesh {
                    tracker: Box::new(facecap_mesh::MeshTracker::new(
                        facecap_mesh::MeshModels::from_cache()?,
                        params,
                    )?),
                    iris,
                }
            }
        };
        Ok(VideoTracker { front })
    }

    /// The front end this tracker runs.
    pub fn front_end(&self) -> FrontEnd {
        match self.front {
            Front::Dlib68 { .. } => FrontEnd::Dlib68,
            Front::Mesh { .. } => FrontEnd::Mesh,
        }
    }

    /// Whether frames must come with colour ([`Frame::rgb`]): the mesh front end's
    /// models read RGB. Open the source with [`open_video_rgb`] accordingly.
    pub fn needs_rgb(&self) -> bool {
        matches!(self.front, Front::Mesh { .. })
    }

    /// Runs `source` through the tracker into `sinks` (module docs). The sinks are not
    /// finished: the caller commits them after a successful run.
    ///
    /// # Errors
    /// The first failure among tracking (including [`Error::Interrupted`]), the sinks
    /// and decoding, in that order.
    pub fn run(
        &self,
        source: Box<dyn FrameSource>,
        sinks: &mut [&mut dyn Sink],
        control: &mut RunControl<'_>,
    ) -> Result<RunReport> {
        self.run_with_queues(source, sinks, control, Queues::FILE)
    }

    /// [`VideoTracker::run`] with the given queue lengths between the stages
    /// ([`Queues::LIVE`] for live input).
    ///
    /// # Errors
    /// As [`VideoTracker::run`].
    pub fn run_with_queues(
        &self,
        mut source: Box<dyn FrameSource>,
        sinks: &mut [&mut dyn Sink],
        control: &mut RunControl<'_>,
        queues: Queues,
    ) -> Result<RunReport> {
        let info = source.info().clone();
        if sinks.len() > MAX_SINKS {
            return Err(Error::invalid("sinks", sinks.len(), format!("at most {MAX_SINKS}")));
        }
        let wants: Vec<_> = sinks.iter().map(|s| s.images()).collect();
        let names: Vec<String> = sinks.iter().map(|s| s.name().to_string()).collect();
        let want_iris = sinks.iter().any(|s| s.wants_iris());
        let want_mesh = sinks.iter().any(|s| s.wants_mesh());
        let mut iris_frame = IrisFrame::default();
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<Decoded>(queues.decoded);
        let (recycle_tx, recycle_rx) = std::sync::mpsc::channel::<Frame>();
        let (track_tx, track_rx) = std::sync::mpsc::sync_channel::<Tracked>(queues.tracked);
        let mut front = FrontRun::new(&self.front);
        let mut tracked = TrackedFrame::default();
        let interrupted = control.interrupted;
        let on_frame = &mut control.on_frame;
        let mut rejected = Vec::new();
        let mut undecodable = Vec::new();
        let (decode_result, track_result, sink_result) = std::thread::scope(|scope| {
            let strict = control.strict;
            let fps = if info.fps.is_finite() && info.fps > 0.0 {
                info.fps
            } else {
                30.0
            };
            let decoder = scope.spawn(move || -> Result<f64> {
                let mut busy = 0.0;
                let (mut next_index, mut consecutive) = (0u64, 0u32);
                loop {
                    let mut frame = recycle_rx.try_recv().unwrap_or_default();
                    let t = Instant::now();
                    let read = source.read_into(&mut frame);
                    busy += t.elapsed().as_secs_f64();
                    let msg = match read {
                        Ok(false) => return Ok(busy),
                        Ok(true) => {
                            consecutive = 0;
                            next_index = frame.index + 1;
                            Decoded::Frame(frame)
                        }
                        Err(e) if strict => return Err(e.into()),
                        Err(e) => {
                            // Salvage: this frame is lost, the others are kept.
                            let index = match &e {
                                facecap_core::Error::Decode { frame: Some(k), .. } => (*k).max(next_index),
                                _ => next_index,
                            };
                            next_index = index + 1;
                            consecutive += 1;
                            if consecutive > MAX_CONSECUTIVE_DECODE_ERRORS {
                                return Ok(busy);
                            }
                            Decoded::Failed {
                                index,
                                timestamp: index as f64 / fps,
                                reason: e.to_string(),
                            }
                        }
                    };
                    if frame_tx.send(msg).is_err() {
                        // the tracking stage stopped (error or interrupt)
                        return Ok(busy);
                    }
                }
            });
            let sinks_ref = &mut *sinks;
            let worker = scope.spawn(move || -> Result<Vec<f64>> { feed(sinks_ref, track_rx) });
            let rejected = &mut rejected;
            let undecodable = &mut undecodable;
            let track_result = (|| -> Result<(f64, u64, u64)> {
                let (mut busy, mut frames, mut faces) = (0.0, 0u64, 0u64);
                let mut taken = vec![0usize; wants.len()];
                for decoded in frame_rx {
                    let mut frame = match decoded {
                        Decoded::Frame(f) => f,
                        Decoded::Failed {
                            index,
                            timestamp,
                            reason,
                        } => {
                            undecodable.push((index, reason));
                            // the tracker starts again from a detection after the gap
                            front.restart();
                            let face = TrackedFace {
                                index,
                                timestamp: timestamp.max(0.0),
                                landmarks: None,
                                confidence: 0.0,
                                rect: None,
                                gray: None,
                                iris: None,
                                mesh: None,
                                colour: None,
                            };
                            frames += 1;
                            if track_tx.send(Tracked { face, wanted: 0 }).is_err() {
                                break;
                            }
                            continue;
                        }
                    };
                    if interrupted.is_some_and(|f| f.load(Ordering::SeqCst)) {
                        return Err(Error::Interrupted { frame: frame.index });
                    }
                    let t = Instant::now();
                    front.track(&frame, &mut tracked)?;
                    busy += t.elapsed().as_secs_f64();
                    let mut wanted = 0u64;
                    for (k, (w, n)) in wants.iter().zip(taken.iter_mut()).enumerate() {
                        if w.wants(frame.index, *n) {
                            *n += 1;
                            wanted |= 1 << k;
                        }
                    }
                    let keep = wanted != 0;
                    if tracked.success {
                        let size = (frame.gray.width(), frame.gray.height());
                        if let Err(why) = implausible_landmarks(&tracked.landmarks, Some(size)) {
                            rejected.push((frame.index, why));
                            tracked.success = false;
                            // track from a fresh detection next frame, not from these points
                            front.restart();
                        }
                    }
                    let iris =
                        (want_iris && tracked.success && front.iris(&frame, &tracked.landmarks, &mut iris_frame))
                            .then_some(iris_frame);
                    let mesh = if want_mesh && tracked.success {
                        front.mesh_points().map(Arc::<[[f32; 3]]>::from)
                    } else {
                        None
                    };
                    let face = TrackedFace {
                        index: frame.index,
                        timestamp: frame.timestamp_s.max(0.0),
                        landmarks: tracked.success.then(|| tracked.landmarks.clone()),
                        confidence: tracked.confidence,
                        rect: tracked.rect,
                        gray: keep.then(|| Arc::new(frame.gray.clone())),
                        iris,
                        mesh,
                        colour: frame.small.take().map(Arc::new),
                    };
                    let msg = Tracked { face, wanted };
                    frames += 1;
                    faces += u64::from(tracked.success);
                    if track_tx.send(msg).is_err() {
                        // the sink stage stopped: its error is reported below
                        break;
                    }
                    let _ = recycle_tx.send(frame);
                    if let Some(cb) = on_frame.as_mut() {
                        cb();
                    }
                }
                Ok((busy, frames, faces))
            })();
            // closing the queue ends the sink stage
            drop(track_tx);
            let sink_result = worker.join().unwrap_or(Err(Error::StagePanicked { stage: "sink" }));
            let decode_result = decoder
                .join()
                .unwrap_or(Err(Error::StagePanicked { stage: "decoding" }));
            (decode_result, track_result, sink_result)
        });
        let (track_seconds, frames, faces) = track_result?;
        let sink_busy = sink_result?;
        let decode_seconds = decode_result?;
        Ok(RunReport {
            info: Some(info),
            frames,
            faces,
            decode_seconds,
            track_seconds,
            sink_seconds: names.into_iter().zip(sink_busy).collect(),
            rejected,
            undecodable,
        })
    }
}

/// The sink stage: every frame to every sink in order, then `end`. A sink sees a
/// frame's image only when it asked for it.
fn feed(sinks: &mut [&mut dyn Sink], queue: impl IntoIterator<Item = Tracked>) -> Result<Vec<f64>> {
    let mut busy = vec![0.0; sinks.len()];
    for msg in queue {
        let mut without_image: Option<TrackedFace> = None;
        for (k, (s, b)) in sinks.iter_mut().zip(busy.iter_mut()).enumerate() {
            let face = if msg.face.gray.is_none() || msg.wanted & (1 << k) != 0 {
                &msg.face
            } else {
                without_image.get_or_insert_with(|| TrackedFace {
                    gray: None,
                    ..msg.face.clone()
                })
            };
            let t = Instant::now();
            s.frame(face)?;
            *b += t.elapsed().as_secs_f64();
        }
    }
    for (s, b) in sinks.iter_mut().zip(busy.iter_mut()) {
        let t = Instant::now();
        s.end()?;
        *b += t.elapsed().as_secs_f64();
    }
    Ok(busy)
}

/// Feeds landmarks read from a CSV (no video) into `sinks`, as if tracked: rows with
/// `success = 0` have no landmarks.
///
/// # Errors
/// The first sink failure.
pub fn replay(records: &[LandmarkRecord], sinks: &mut [&mut dyn Sink]) -> Result<RunReport> {
    let names: Vec<String> = sinks.iter().map(|s| s.name().to_string()).collect();
    // Implausible rows (e.g. a point at 1e300, 68 identical points) fail that frame only.
    let mut rejected = Vec::new();
    let landmarks: Vec<Option<Landmarks68>> = records
        .iter()
        .map(|r| {
            let l = r.landmarks.as_ref().filter(|_| r.success)?;
            match implausible_landmarks(l, None) {
                Ok(()) => Some(l.clone()),
                Err(why) => {
                    rejected.push((r.frame, why));
                    None
                }
            }
        })
        .collect();
    let faces = landmarks.iter().filter(|l| l.is_some()).count() as u64;
    let busy = feed(
        sinks,
        records.iter().zip(landmarks).map(|(r, landmarks)| Tracked {
            face: TrackedFace {
                index: r.frame,
                timestamp: r.timestamp.max(0.0),
                landmarks,
                confidence: r.confidence,
                rect: None,
                gray: None,
                iris: None,
                mesh: None,
                colour: None,
            },
            wanted: 0,
        }),
    )?;
    Ok(RunReport {
        info: None,
        frames: records.len() as u64,
        faces,
        decode_seconds: 0.0,
        track_seconds: 0.0,
        sink_seconds: names.into_iter().zip(busy).collect(),
        rejected,
        undecodable: Vec::new(),
    })
}
