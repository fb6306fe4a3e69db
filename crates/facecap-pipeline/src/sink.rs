//! Per-frame sinks: what the tracker's output goes to.

use std::sync::Arc;

use facecap_core::landmarks::{Landmarks68, Rect};
use image::GrayImage;

use crate::error::Result;

/// One tracked frame as every sink sees it.
#[derive(Debug, Clone)]
pub struct TrackedFace {
    /// 0-based frame index in presentation order.
    pub index: u64,
    /// Presentation time in seconds (>= 0).
    pub timestamp: f64,
    /// The 68 landmarks (0-based pixels) when tracking succeeded.
    pub landmarks: Option<Landmarks68>,
    /// Tracking confidence in `[0, 1]`.
    pub confidence: f64,
    /// The box the shape predictor used, when there was one.
    pub rect: Option<Rect>,
    /// The grey frame, when this sink asked for this frame's image ([`Sink::images`]).
    pub gray: Option<Arc<GrayImage>>,
    /// Iris centres (when some sink asked for them, [`Sink::wants_iris`], and the face
    /// was tracked).
    pub iris: Option<facecap_landmarks::gaze::IrisFrame>,
    /// The face mesh's 478 points `[x, y, z]` (pixels, as [`facecap_mesh::FaceMesh`]),
    /// when the mesh front end tracked the face and some sink asked for them
    /// ([`Sink::wants_mesh`]).
    pub mesh: Option<Arc<[[f32; 3]]>>,
    /// A small colour copy of the frame, when the source was asked for one of this
    /// frame ([`facecap_io::video::FrameSource::tap_colour`]; the preview's frames).
    pub colour: Option<Arc<facecap_io::video::small::SmallFrame>>,
}

/// Which frames' grey images a sink needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameImages {
    /// None (most sinks: they use the landmarks).
    #[default]
    None,
    /// Every frame.
    Every,
    /// Frames whose index is a multiple of `every`, at most `max` of them (the
    /// report's contact sheet).
    Sample {
        /// Index step.
        every: u64,
        /// Largest number of frames.
        max: usize,
    },
}

impl FrameImages {
    /// Whether frame `index` is wanted when `taken` frames were taken so far.
    pub fn wants(self, index: u64, taken: usize) -> bool {
        match self {
            FrameImages::None => false,
            FrameImages::Every => true,
            FrameImages::Sample { every, max } => index % every.max(1) == 0 && taken < max,
        }
    }
}

/// A per-frame consumer of tracked faces.
///
/// The tracker calls [`Sink::frame`] once per frame in frame order from one thread,
/// then [`Sink::end`] once. Files a sink writes are committed by its own `finish`
/// method (not part of the trait, so that it can return what it computed), which the
/// caller invokes after a successful run; a sink dropped without `finish` leaves no
/// file under a final name.
pub trait Sink: Send {
    /// Short name for timings and errors (`"landmarks"`, `"solve"`, ...).
    fn name(&self) -> &str;
    /// Which frames' images this sink needs (default: none).
    fn images(&self) -> FrameImages {
        FrameImages::None
    }
    /// Whether this sink needs the iris centres (the gaze signal) of tracked frames
    /// (default: no; they are estimated on the tracking thread from the grey frame).
    fn wants_iris(&self) -> bool {
        false
    }
    /// Whether this sink needs the face mesh's 478 points of tracked frames
    /// ([`TrackedFace::mesh`]; default: no; only the mesh front end has them).
    fn wants_mesh(&self) -> bool {
        false
    }
    /// One tracked frame.
    ///
    /// # Errors
    /// Whatever the sink's writing or solving fails with; it stops the run.
    fn frame(&mut self, face: &TrackedFace) -> Result<()>;
    /// After the last frame (sinks that need the whole clip, such as a neutral
    /// calibration, do their work here).
    ///
    /// # Errors
    /// As [`Sink::frame`].
    fn end(&mut self) -> Result<()> {
        Ok(())
    }
}
