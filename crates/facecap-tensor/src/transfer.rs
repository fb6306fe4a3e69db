//! Expression transfer (Papanek 2010, ch. 5; Vlasic et al. 2005): the source
//! performance's per-frame expression weights combined with the target's identity
//! and (per-frame) pose.
//!
//! Frame `f` of the result uses `w_exp` of source frame `f`, `w_id` of the target and
//! the pose of target frame `min(f, F_target - 1)` (a single target frame, e.g. a
//! target photo or identity, gives a static head).

use facecap_core::camera::ModelToCamera;
use nalgebra::Point3;

use crate::error::{Error, Result};
use crate::fit::FitState;
use crate::model::TensorModel;

/// One transferred frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferFrame {
    /// Target identity weights.
    pub w_id: Vec<f64>,
    /// Source expression weights.
    pub w_exp: Vec<f64>,
    /// Target pose (if the target was fitted with one).
    pub pose: Option<ModelToCamera>,
}

/// Combines fitted source and target states (module docs).
///
/// # Errors
/// [`Error::InvalidParameter`] when either sequence is empty.
pub fn combine(source: &[FitState], target: &[FitState]) -> Result<Vec<TransferFrame>> {
    if source.is_empty() {
        return Err(Error::invalid("source frames", 0, ">= 1"));
    }
    if target.is_empty() {
        return Err(Error::invalid("target frames", 0, ">= 1"));
    }
    Ok(source
        .iter()
        .enumerate()
        .map(|(f, s)| {
            let t = &target[f.min(target.len() - 1)];
            TransferFrame {
                w_id: t.w_id.clone(),
                w_exp: s.w_exp.clone(),
                pose: t.pose,
            }
        })
        .collect())
}

/// The transferred mesh of each frame, in model space.
///
/// # Errors
/// As [`TensorModel::generate`].
pub fn meshes(model: &TensorModel, frames: &[TransferFrame]) -> Result<Vec<Vec<Point3<f32>>>> {
    frames
        .iter()
        .map(|f| model.generate_points(&f.w_id, &f.w_exp))
        .collect()
}
