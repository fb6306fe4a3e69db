//! The tensor sink of `capture --tensor`: per frame, pose, identity and expression
//! weights of the tensor model fitted to the tracked landmarks (warm-started from the
//! previous frame), written to `tensor.csv`.
//!
//! `tensor.csv` is one layout for every command (`capture --tensor`, `tensor fit`,
//! `transfer`): `frame,timestamp,success,confidence,pose_Tx..pose_Rz` (the `pose.csv`
//! convention, [`facecap_core::camera::pose_row`]), then `id_<name>` per database
//! identity and `exp_<name>` per database expression; `confidence` is the tracking
//! confidence.

use std::path::Path;

use facecap_core::camera::{pose_row, Intrinsics};
use facecap_core::landmark_map::LandmarkMap;
use facecap_io::csv::{FrameCsvWriter, FrameRow, LandmarkRecord, POSE_COLUMNS};
use facecap_tensor::fit::{FitInput, FitParams, FitState, FitWorkspace, Fitter};
use facecap_tensor::model::TensorModel;
use nalgebra::Point2;

use crate::error::Result;
use crate::sink::{Sink, TrackedFace};

/// The `tensor.csv` value columns of `model`.
pub fn tensor_columns(model: &TensorModel) -> Vec<String> {
    let mut cols: Vec<String> = POSE_COLUMNS.iter().map(|s| s.to_string()).collect();
    cols.extend(model.identities.iter().map(|n| format!("id_{n}")));
    cols.extend(model.expressions.iter().map(|n| format!("exp_{n}")));
    cols
}

/// One `tensor.csv` row's values for `state` (NaN where unknown).
pub fn tensor_values(state: Option<&FitState>, values: &mut [f64]) {
    values.fill(f64::NAN);
    if let Some(s) = state {
        values[..6].copy_from_slice(&pose_row(s.pose.as_ref()));
        let ni = s.w_id.len();
        values[6..6 + ni].copy_from_slice(&s.w_id);
        values[6 + ni..6 + ni + s.w_exp.len()].copy_from_slice(&s.w_exp);
    }
}

/// Writes a `tensor.csv` for per-frame states (`None`: not fitted) beside the records
/// they were fitted to.
///
/// # Errors
/// When the file cannot be written.
pub fn write_tensor_csv(
    path: &Path,
    model: &TensorModel,
    records: &[LandmarkRecord],
    states: &[Option<FitState>],
) -> Result<()> {
    let cols = tensor_columns(model);
    let mut wr = FrameCsvWriter::create(path, &cols)?;
    let mut values = vec![f64::NAN; cols.len()];
    for (r, s) in records.iter().zip(states) {
        tensor_values(s.as_ref(), &mut values);
        wr.write_row(&FrameRow {
            frame: r.frame,
            timestamp: r.timestamp,
            success: s.is_some(),
            confidence: r.confidence,
            values: &values,
        })?;
    }
    wr.finish()?;
    Ok(())
}

/// The tensor set-up shared by all videos: the model and a fitter over its landmark
/// vertices.
#[derive(Debug, Clone)]
pub struct TensorSetup {
    fitter: Fitter,
    landmarks: Vec<usize>,
    columns: Vec<String>,
}

impl TensorSetup {
    /// A fitter of `model` on the landmarks `map` maps onto its mesh.
    ///
    /// # Errors
    /// A map that does not fit the model.
    pub fn new(model: &TensorModel, map: &LandmarkMap) -> Result<Self> {
        map.validate(model.num_vertices())?;
        let (landmarks, vertices): (Vec<usize>, Vec<u32>) = map.mapped().unzip();
        let fitter = Fitter::new(model, &vertices, FitParams::default())?;
        Ok(TensorSetup {
            fitter,
            landmarks,
            columns: tensor_columns(model),
        })
    }
}

/// Writes `tensor.csv` frame by frame (module docs).
#[derive(Debug)]
pub struct TensorSink {
    fitter: Fitter,
    landmarks: Vec<usize>,
    camera: Intrinsics,
    ws: FitWorkspace,
    state: FitState,
    image: Vec<Point2<f64>>,
    weights: Vec<f64>,
    values: Vec<f64>,
    csv: FrameCsvWriter,
}

impl TensorSink {
    /// Starts `tensor.csv` in `out_dir`.
    ///
    /// # Errors
    /// File creation.
    pub fn create(out_dir: &Path, setup: &TensorSetup, camera: Intrinsics) -> Result<Self> {
        let n = setup.landmarks.len();
        Ok(TensorSink {
            ws: setup.fitter.workspace(),
            state: setup.fitter.initial_state(),
            fitter: setup.fitter.clone(),
            landmarks: setup.landmarks.clone(),
            camera,
            image: vec![Point2::origin(); n],
            weights: vec![1.0; n],
            values: vec![f64::NAN; setup.columns.len()],
            csv: FrameCsvWriter::create(out_dir.join("tensor.csv"), &setup.columns)?,
        })
    }

    /// Commits `tensor.csv`.
    ///
    /// # Errors
    /// When the file cannot be written or renamed.
    pub fn finish(self) -> Result<()> {
        self.csv.finish()?;
        Ok(())
    }
}

impl Sink for TensorSink {
    fn name(&self) -> &str {
        "tensor"
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        let mut fitted = false;
        if let Some(l) = &face.landmarks {
            for (slot, &i) in self.landmarks.iter().enumerate() {
                self.image[slot] = l.points[i];
            }
            let input = FitInput {
                image: &self.image,
                weights: &self.weights,
                intrinsics: self.camera,
            };
            if self.fitter.solve_into(&input, &mut self.ws, &mut self.state).is_ok() {
                fitted = true;
            } else {
                self.state = self.fitter.initial_state();
            }
        }
        tensor_values(fitted.then_some(&self.state), &mut self.values);
        self.csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success: fitted,
            confidence: face.confidence,
            values: &self.values,
        })?;
        Ok(())
    }
}
