//! Optional stages of `facecap capture`: muscle contractions (`--muscles`) and tensor
//! parameters (`--tensor`), fed per frame with the tracked landmarks.

use std::path::Path;

use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::mesh::MorphMesh;

/// Muscle stage set-up (shared by all videos).
#[derive(Debug)]
pub struct MuscleSetup {}

/// Muscle stage of one video.
#[derive(Debug)]
pub struct MuscleRun {}

impl MuscleSetup {
    /// `spec` is a muscle-set JSON path or `default`.
    pub fn new(spec: &str, _rig: &MorphMesh, _map: &LandmarkMap) -> anyhow::Result<Self> {
        anyhow::bail!("--muscles {spec}: muscle capture is not wired into this build yet")
    }

    /// Starts a video.
    pub fn start(&self, _out_dir: &Path, _camera: Intrinsics) -> anyhow::Result<MuscleRun> {
        Ok(MuscleRun {})
    }
}

impl MuscleRun {
    /// One frame.
    pub fn frame(&mut self, _index: u64, _t: f64, _lms: Option<&Landmarks68>, _confidence: f64) -> anyhow::Result<()> {
        Ok(())
    }

    /// Commits `contractions.csv`.
    pub fn finish(self) -> anyhow::Result<()> {
        Ok(())
    }
}

/// Tensor stage set-up.
#[derive(Debug)]
pub struct TensorSetup {}

/// Tensor stage of one video.
#[derive(Debug)]
pub struct TensorRun {}

impl TensorSetup {
    /// Loads the model file.
    pub fn new(path: &Path) -> anyhow::Result<Self> {
        anyhow::bail!("--tensor {}: tensor capture is not wired into this build yet", path.display())
    }

    /// Starts a video.
    pub fn start(&self, _out_dir: &Path, _camera: Intrinsics) -> anyhow::Result<TensorRun> {
        Ok(TensorRun {})
    }
}

impl TensorRun {
    /// One frame.
    pub fn frame(&mut self, _index: u64, _t: f64, _lms: Option<&Landmarks68>, _confidence: f64) -> anyhow::Result<()> {
        Ok(())
    }

    /// Commits `tensor.csv`.
    pub fn finish(self) -> anyhow::Result<()> {
        Ok(())
    }
}
