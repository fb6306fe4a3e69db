//! The landmark sinks: `landmarks.csv`, and an in-memory recorder.

use std::path::Path;
use std::sync::Arc;

use facecap_core::landmarks::NUM_LANDMARKS;
use facecap_io::csv::{landmark_columns, landmark_values, FrameCsvWriter, FrameRow, LandmarkRecord};
use image::GrayImage;

use crate::error::Result;
use crate::sink::{FrameImages, Sink, TrackedFace};

/// Writes `landmarks.csv`: `frame,timestamp,success,confidence,x_0..x_67,y_0..y_67`
/// (0-based pixels, `nan` where `success` is 0). The same file from every command.
#[derive(Debug)]
pub struct LandmarkCsvSink {
    csv: FrameCsvWriter,
    values: [f64; 2 * NUM_LANDMARKS],
}

impl LandmarkCsvSink {
    /// Starts the file (committed by [`LandmarkCsvSink::finish`]).
    ///
    /// # Errors
    /// When the temporary file cannot be created.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        Ok(LandmarkCsvSink {
            csv: FrameCsvWriter::create(path, &landmark_columns())?,
            values: [0.0; 2 * NUM_LANDMARKS],
        })
    }

    /// Commits the file.
    ///
    /// # Errors
    /// When it cannot be written or renamed.
    pub fn finish(self) -> Result<()> {
        self.csv.finish()?;
        Ok(())
    }
}

impl Sink for LandmarkCsvSink {
    fn name(&self) -> &str {
        "landmarks"
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        landmark_values(face.landmarks.as_ref(), &mut self.values);
        self.csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success: face.landmarks.is_some(),
            confidence: face.confidence,
            values: &self.values,
        })?;
        Ok(())
    }
}

/// Keeps every frame's landmarks in memory (and, when asked, the grey frames up to a
/// byte budget), for algorithms that need the whole clip before they start (the tensor
/// model's identity fit).
#[derive(Debug, Default)]
pub struct LandmarkRecorder {
    /// One record per frame.
    pub records: Vec<LandmarkRecord>,
    /// The grey frames, while they fit in the budget (`None` once it was exceeded or
    /// when none were asked for).
    pub images: Option<Vec<Arc<GrayImage>>>,
    budget: usize,
    bytes: usize,
}

impl LandmarkRecorder {
    /// Records landmarks only.
    pub fn new() -> Self {
        LandmarkRecorder::default()
    }

    /// Records landmarks and grey frames while they take at most `budget_bytes`; past
    /// that the frames are dropped and [`LandmarkRecorder::images`] is `None` (the
    /// caller decodes the video again).
    pub fn with_images(budget_bytes: usize) -> Self {
        LandmarkRecorder {
            images: Some(Vec::new()),
            budget: budget_bytes,
            ..LandmarkRecorder::default()
        }
    }
}

impl Sink for LandmarkRecorder {
    fn name(&self) -> &str {
        "record"
    }

    fn images(&self) -> FrameImages {
        if self.images.is_some() {
            FrameImages::Every
        } else {
            FrameImages::None
        }
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        self.records.push(LandmarkRecord {
            frame: face.index,
            timestamp: face.timestamp,
            success: face.landmarks.is_some(),
            confidence: face.confidence,
            landmarks: face.landmarks.clone(),
        });
        if let Some(images) = self.images.as_mut() {
            match &face.gray {
                Some(g) if self.bytes + g.as_raw().len() <= self.budget => {
                    self.bytes += g.as_raw().len();
                    images.push(g.clone());
                }
                _ => self.images = None,
            }
        }
        Ok(())
    }
}
