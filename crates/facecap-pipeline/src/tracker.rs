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

use facecap_core::csv::LandmarkRecord;
use facecap_core::video::{open_source, Frame, FrameSource, SourceOptions, VideoInfo};
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::gaze::{IrisEstimator, IrisFrame, IrisParams};
use facecap_landmarks::tracker::one_euro::OneEuroParams;
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};

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
/// | `smooth` | false | One Euro filter on the landmarks (less jitter on still faces, lag on fast motion; docs/tracking.md) |
/// | `shape_model` | the cache's `shape_predictor_68_face_landmarks.dat` | dlib 68-point model file |
///
/// The shape predictor always returns sub-pixel landmarks (dlib rounds to whole
/// pixels, which adds jitter to tracking); the face detector is the built-in dlib HOG
/// model.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerPolicy {
    /// Smooth landmarks with the One Euro filter.
    pub smooth: bool,
    /// The 68-point model file (`None`: the model cache).
    pub shape_model: Option<PathBuf>,
    /// Detector upsampling (`Upsample::Auto`: dlib's `detector(img, 1)` recall at less cost).
    pub upsample: facecap_landmarks::detect::Upsample,
}

impl Default for TrackerPolicy {
    /// No smoothing, the cached model, automatic upsampling (what every command uses).
    fn default() -> Self {
        TrackerPolicy {
            smooth: false,
            shape_model: None,
            upsample: facecap_landmarks::detect::Upsample::Auto,
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
    tracker: LandmarkTracker<FaceDetector, ShapePredictor>,
    iris: IrisEstimator,
}

/// Per-run controls: interruption and a per-frame callback on the tracking thread.
#[derive(Default)]
pub struct RunControl<'a> {
    /// Set (e.g. by a Ctrl-C handler) to stop at the next frame with
    /// [`Error::Interrupted`].
    pub interrupted: Option<&'a AtomicBool>,
    /// Called on the calling thread after each tracked frame (progress bars).
    pub on_frame: Option<&'a mut dyn FnMut()>,
}

impl std::fmt::Debug for RunControl<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunControl")
            .field("interrupted", &self.interrupted)
            .field("on_frame", &self.on_frame.is_some())
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
/// As [`facecap_core::video::open_source`].
pub fn open_video(path: &Path, decode_threads: u32) -> Result<Box<dyn FrameSource>> {
    Ok(open_source(
        path,
        &SourceOptions {
            threads: decode_threads,
            ..SourceOptions::default()
        },
    )?)
}

impl VideoTracker {
    /// Loads the detector and the shape predictor once for `policy`.
    ///
    /// # Errors
    /// A missing or unreadable model file.
    pub fn new(policy: &TrackerPolicy) -> Result<Self> {
        let detector = FaceDetector::default_model()?.with_upsample(policy.upsample)?;
        let path = policy.shape_model_path()?;
        let ert = ShapePredictor::from_file_cached(&path)?.0.with_params(ErtParams {
            output: OutputPrecision::SubPixel,
        });
        let mut params = TrackerParams::default();
        if policy.smooth {
            params.filter = Some(OneEuroParams::default());
        }
        Ok(VideoTracker {
            tracker: LandmarkTracker::new(detector, ert, params)?,
            iris: IrisEstimator::new(IrisParams::default())?,
        })
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
        let mut iris_ws = self.iris.new_workspace();
        let mut iris_frame = IrisFrame::default();
        let iris_estimator = &self.iris;
        let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<Frame>(queues.decoded);
        let (recycle_tx, recycle_rx) = std::sync::mpsc::channel::<Frame>();
        let (track_tx, track_rx) = std::sync::mpsc::sync_channel::<Tracked>(queues.tracked);
        let tracker = &self.tracker;
        let mut ws = tracker.new_workspace();
        let mut state = TrackerState::new();
        let mut tracked = TrackedFrame::default();
        let interrupted = control.interrupted;
        let on_frame = &mut control.on_frame;
        let (decode_result, track_result, sink_result) = std::thread::scope(|scope| {
            let decoder = scope.spawn(move || -> Result<f64> {
                let mut busy = 0.0;
                loop {
                    let mut frame = recycle_rx.try_recv().unwrap_or_default();
                    let t = Instant::now();
                    if !source.read_into(&mut frame)? {
                        return Ok(busy);
                    }
                    busy += t.elapsed().as_secs_f64();
                    if frame_tx.send(frame).is_err() {
                        // the tracking stage stopped (error or interrupt)
                        return Ok(busy);
                    }
                }
            });
            let sinks_ref = &mut *sinks;
            let worker = scope.spawn(move || -> Result<Vec<f64>> { feed(sinks_ref, track_rx) });
            let track_result = (|| -> Result<(f64, u64, u64)> {
                let (mut busy, mut frames, mut faces) = (0.0, 0u64, 0u64);
                let mut taken = vec![0usize; wants.len()];
                for frame in frame_rx {
                    if interrupted.is_some_and(|f| f.load(Ordering::SeqCst)) {
                        return Err(Error::Interrupted { frame: frame.index });
                    }
                    let t = Instant::now();
                    tracker.track_into(&frame.gray, frame.timestamp_s, &mut ws, &mut state, &mut tracked)?;
                    busy += t.elapsed().as_secs_f64();
                    let mut wanted = 0u64;
                    for (k, (w, n)) in wants.iter().zip(taken.iter_mut()).enumerate() {
                        if w.wants(frame.index, *n) {
                            *n += 1;
                            wanted |= 1 << k;
                        }
                    }
                    let keep = wanted != 0;
                    let iris = if want_iris && tracked.success {
                        iris_estimator
                            .estimate_into(&frame.gray, &tracked.landmarks, &mut iris_ws, &mut iris_frame)
                            .ok()
                            .map(|_| iris_frame)
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
    let faces = records.iter().filter(|r| r.success && r.landmarks.is_some()).count() as u64;
    let busy = feed(
        sinks,
        records.iter().map(|r| Tracked {
            face: TrackedFace {
                index: r.frame,
                timestamp: r.timestamp.max(0.0),
                landmarks: r.landmarks.clone().filter(|_| r.success),
                confidence: r.confidence,
                rect: None,
                gray: None,
                iris: None,
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
    })
}
