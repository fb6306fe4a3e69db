//! # facecap-pipeline
//!
//! The one place that wires the algorithm crates together: a frame source feeds one
//! [`VideoTracker`] (one model lookup, one tracker policy; decoding, tracking and the
//! sinks on their own threads, frames recycled), and the tracked faces go to a list of
//! per-frame [`Sink`]s, each of which writes one kind of output and commits it
//! atomically when it finishes.
//!
//! ```text
//!  FrameSource (file, Y4M, folder, ...)   landmark CSV (replay)
//!          |                                      |
//!     VideoTracker::run  ----- TrackedFace ----> sinks: landmarks.csv, expression solve
//!     (decode | track | sinks threads)           (weights.csv + pose.csv), muscles,
//!                                                tensor, images, your own
//! ```
//!
//! Every facecap command that reads video differs only in its source and its sinks:
//! `capture` uses [`LandmarkCsvSink`], [`ExpressionSink`], [`MuscleSink`] and
//! [`TensorSink`]; `landmarks VIDEO` the landmark sink (plus a drawing sink of the
//! CLI); `muscle track` the muscle sink; `tensor fit` and `transfer` a
//! [`LandmarkRecorder`] whose records (and grey frames) feed the Papanek video fit
//! ([`tensor_fit`]); `solve` replays a landmarks CSV ([`replay`]) into the same
//! expression sink as `capture`, so both write the same `pose.csv` and `weights.csv`.
//!
//! `live` reads a camera, a stream or stdin newest-first ([`live::LatestFrame`], with
//! [`Queues::LIVE`]) into a [`LiveSink`] that solves each frame with the same
//! [`ExpressionSink`] and sends it at once (OSC/VMC, Live Link Face, JSON; [`net`]).
//!
//! **Adding a source**: implement [`facecap_io::video::FrameSource`] (a camera, a
//! stream) and pass it to [`VideoTracker::run`]. **Adding a sink**: implement
//! [`Sink`] (`frame` per tracked frame, in order; `end` after the last), and give it to
//! `run` beside the others; say in [`Sink::images`] whether it needs the grey frames.
//!
//! ```no_run
//! use facecap_pipeline::{open_video, LandmarkCsvSink, RunControl, TrackerPolicy, VideoTracker};
//! let tracker = VideoTracker::new(&TrackerPolicy::default())?;
//! let mut csv = LandmarkCsvSink::create("out/landmarks.csv")?;
//! let report = tracker.run(open_video("clip.mp4".as_ref(), 1)?, &mut [&mut csv], &mut RunControl::default())?;
//! csv.finish()?;
//! println!("{} frames, face on {}", report.frames, report.faces);
//! # Ok::<(), facecap_pipeline::Error>(())
//! ```

pub mod batch;
pub mod error;
pub mod expression;
pub mod lips;
pub mod live;
pub mod muscle;
pub mod net;
pub mod openface;
pub mod outputs;
pub mod preview;
pub mod render;
pub mod resume;
pub mod sink;
pub mod sinks;
pub mod tensor;
pub mod tensor_fit;
pub mod tracker;

pub use error::{Error, Result};
pub use expression::{
    build_expression_solve, Calibrated, ExpressionResult, ExpressionSetup, ExpressionSink, LiveNeutral,
    NeutralCalibration, SolvedFrame,
};
pub use live::{open_live, ChildGuard, LatestFrame, LiveInput};
pub use muscle::{MuscleFrame, MuscleSetup, MuscleSink};
pub use net::{LiveOutputs, LiveSink};
pub use preview::{
    write_preview, write_preview_stored, ColourFrames, PreviewParams, PreviewReport, COLOUR_FRAMES_BUDGET,
};
pub use render::{RenderWorkspace, RigRenderer, View};
pub use sink::{FrameImages, Sink, TrackedFace};
pub use sinks::{LandmarkCsvSink, LandmarkLayout, LandmarkRecorder};
pub use tensor::{TensorSetup, TensorSink};
pub use tracker::{
    open_video, open_video_rgb, open_video_with, replay, FrontEnd, Queues, RunControl, RunReport, TrackerPolicy,
    VideoTracker,
};
