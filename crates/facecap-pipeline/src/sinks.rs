//! The landmark sinks: `landmarks.csv`, and an in-memory recorder.

use std::path::Path;
use std::sync::Arc;

use facecap_core::landmarks::NUM_LANDMARKS;
use facecap_io::csv::{
    landmark_columns, landmark_values, mesh_columns, mesh_values, FrameCsvWriter, FrameRow, LandmarkRecord, MESH_POINTS,
};
use image::GrayImage;

use crate::error::Result;
use crate::sink::{FrameImages, Sink, TrackedFace};

/// Which points a landmark CSV holds (docs/formats.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LandmarkLayout {
    /// The 68 iBUG points: `x_0..x_67,y_0..y_67` (from either front end).
    #[default]
    Ibug68,
    /// The face mesh's 478 points, `x_i,y_i,z_i` point by point
    /// ([`facecap_io::csv::mesh_columns`]); needs the mesh front end (other frames are
    /// written as failed).
    Mesh478,
}

/// Writes `landmarks.csv`: `frame,timestamp,success,confidence,x_0..x_67,y_0..y_67`
/// (0-based pixels, `nan` where `success` is 0), the same file from every command; or,
/// with [`LandmarkLayout::Mesh478`], the 478 mesh points `x_0,y_0,z_0,...,z_477`.
#[derive(Debug)]
pub struct LandmarkCsvSink {
    csv: FrameCsvWriter,
    layout: LandmarkLayout,
    values: Vec<f64>,
}

impl LandmarkCsvSink {
    /// Starts the file with the 68-point layout (committed by [`LandmarkCsvSink::finish`]).
    ///
    /// # Errors
    /// When the temporary file cannot be created.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        Self::create_with(path, LandmarkLayout::Ibug68)
    }

    /// Starts the file with the given layout.
    ///
    /// # Errors
    /// When the temporary file cannot be created.
    pub fn create_with(path: impl AsRef<Path>, layout: LandmarkLayout) -> Result<Self> {
        let (columns, n) = match layout {
            LandmarkLayout::Ibug68 => (landmark_columns(), 2 * NUM_LANDMARKS),
            LandmarkLayout::Mesh478 => (mesh_columns(), 3 * MESH_POINTS),
        };
        Ok(LandmarkCsvSink {
            csv: FrameCsvWriter::create(path, &columns)?,
            layout,
            values: vec![0.0; n],
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

    fn wants_mesh(&self) -> bool {
        self.layout == LandmarkLayout::Mesh478
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        let success = match self.layout {
            LandmarkLayout::Ibug68 => {
                let n = self.values.len();
                let values: &mut [f64; 2 * NUM_LANDMARKS] = self
                    .values
                    .as_mut_slice()
                    .try_into()
                    .map_err(|_| crate::error::Error::invalid("landmark CSV values", n, "136"))?;
                landmark_values(face.landmarks.as_ref(), values);
                face.landmarks.is_some()
            }
            LandmarkLayout::Mesh478 => {
                let mesh = face.mesh.as_deref().filter(|_| face.landmarks.is_some());
                mesh_values(mesh, &mut self.values)?;
                mesh.is_some()
            }
        };
        self.csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success,
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
