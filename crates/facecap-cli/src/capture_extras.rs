//! Optional stages of `facecap capture`: muscle contractions (`--muscles`) and tensor
//! parameters (`--tensor`), fed per frame with the tracked landmarks.

use std::path::Path;

use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::mesh::MorphMesh;

/// Points per muscle used by the tracker's point-by-point mode.
const POINTS_PER_MUSCLE: usize = 4;

/// Muscle stage set-up (shared by all videos): the muscle set applied to the rig mesh
/// and the tracking model over the rig's mapped landmarks.
#[derive(Debug)]
pub struct MuscleSetup {
    model: facecap_muscle::track::TrackModel,
    names: Vec<String>,
}

/// Muscle stage of one video.
#[derive(Debug)]
pub struct MuscleRun {
    tracker: facecap_muscle::track::MuscleTracker,
    ws: facecap_muscle::track::TrackWorkspace,
    state: facecap_muscle::track::TrackState,
    out: facecap_muscle::track::TrackOutput,
    points: Vec<nalgebra::Point2<f64>>,
    weights: Vec<f64>,
    values: Vec<f64>,
    csv: facecap_core::csv::FrameCsvWriter,
}

impl MuscleSetup {
    /// `spec` is a muscle-set JSON path or `default` (the thesis' 11 muscles placed from
    /// the rig's 68 landmarks).
    pub fn new(spec: &str, rig: &MorphMesh, map: &LandmarkMap) -> anyhow::Result<Self> {
        let positions: Vec<nalgebra::Point3<f64>> = rig.base.positions.iter().map(|p| p.cast::<f64>()).collect();
        let set = if spec == "default" {
            let lm = facecap_muscle::defaults::landmark_positions(map, &positions);
            facecap_muscle::defaults::default_muscle_set(&lm, &positions)?
        } else {
            facecap_muscle::set::MuscleSet::from_json_file(Path::new(spec))?
        };
        let muscle_rig = facecap_muscle::rig::MuscleRig::from_mesh(&set, &rig.base)?;
        let model = facecap_muscle::track::TrackModel::from_landmarks(&muscle_rig, map, &[], POINTS_PER_MUSCLE)?;
        let mut names: Vec<String> = muscle_rig.names().to_vec();
        names.push("jaw".to_string());
        Ok(MuscleSetup { model, names })
    }

    /// Starts a video: `contractions.csv` in `out_dir`.
    pub fn start(&self, out_dir: &Path, camera: Intrinsics) -> anyhow::Result<MuscleRun> {
        use facecap_muscle::track::{MuscleTracker, TrackOutput, TrackParams, TrackState, TrackWorkspace};
        let tracker = MuscleTracker::new(self.model.clone(), camera, TrackParams::default())?;
        let k = self.model.num_points();
        Ok(MuscleRun {
            ws: TrackWorkspace::new(&self.model),
            state: TrackState::new(&self.model),
            out: TrackOutput::new(&self.model),
            tracker,
            points: vec![nalgebra::Point2::origin(); k],
            weights: vec![1.0; k],
            values: vec![f64::NAN; self.names.len()],
            csv: facecap_core::csv::FrameCsvWriter::create(out_dir.join("contractions.csv"), &self.names)?,
        })
    }
}

impl MuscleRun {
    /// One frame: contractions and jaw angle (radians) from the tracked landmarks.
    pub fn frame(&mut self, index: u64, t: f64, lms: Option<&Landmarks68>, confidence: f64) -> anyhow::Result<()> {
        let mut success = false;
        self.values.fill(f64::NAN);
        if let Some(l) = lms {
            for (slot, lm) in self.tracker.model().landmark_of_point().iter().enumerate() {
                if let Some(i) = lm {
                    self.points[slot] = l.points[*i];
                }
            }
            let input = facecap_muscle::track::TrackInput {
                points: &self.points,
                weights: Some(&self.weights),
            };
            if self
                .tracker
                .solve_into(&input, &mut self.ws, &mut self.state, &mut self.out)
                .is_ok()
            {
                let m = self.out.contractions.len();
                self.values[..m].copy_from_slice(&self.out.contractions);
                self.values[m] = self.out.jaw;
                success = true;
            }
        }
        self.csv.write_row(&facecap_core::csv::FrameRow {
            frame: index,
            timestamp: t,
            success,
            confidence,
            values: &self.values,
        })?;
        Ok(())
    }

    /// Commits `contractions.csv`.
    pub fn finish(self) -> anyhow::Result<()> {
        self.csv.finish()?;
        Ok(())
    }
}

/// Tensor stage set-up: the model and the fitter over its landmark vertices.
#[derive(Debug)]
pub struct TensorSetup {
    fitter: facecap_tensor::fit::Fitter,
    landmarks: Vec<usize>,
    columns: Vec<String>,
}

/// Tensor stage of one video.
#[derive(Debug)]
pub struct TensorRun {
    fitter: facecap_tensor::fit::Fitter,
    landmarks: Vec<usize>,
    camera: Intrinsics,
    ws: facecap_tensor::fit::FitWorkspace,
    state: facecap_tensor::fit::FitState,
    image: Vec<nalgebra::Point2<f64>>,
    weights: Vec<f64>,
    values: Vec<f64>,
    csv: facecap_core::csv::FrameCsvWriter,
}

impl TensorSetup {
    /// Loads the model file and the landmark map of its mesh (68 iBUG landmarks -> vertex).
    pub fn new(path: &Path, map_path: Option<&Path>) -> anyhow::Result<Self> {
        let model = facecap_tensor::model::TensorModel::load(path)?;
        let map_path = map_path.ok_or_else(|| {
            anyhow::anyhow!("--tensor needs --tensor-landmark-map (68 iBUG landmarks -> vertices of the tensor mesh)")
        })?;
        let map = LandmarkMap::from_json_file(map_path)?;
        map.validate(model.num_vertices())?;
        let (landmarks, vertices): (Vec<usize>, Vec<u32>) = map.mapped().unzip();
        let fitter = facecap_tensor::fit::Fitter::new(&model, &vertices, facecap_tensor::fit::FitParams::default())?;
        let mut columns: Vec<String> = facecap_core::csv::POSE_COLUMNS.iter().map(|s| s.to_string()).collect();
        columns.extend((0..model.num_identities()).map(|i| format!("id_{i}")));
        columns.extend((0..model.num_expressions()).map(|i| format!("exp_{i}")));
        Ok(TensorSetup {
            fitter,
            landmarks,
            columns,
        })
    }

    /// Starts a video: `tensor.csv` in `out_dir`.
    pub fn start(&self, out_dir: &Path, camera: Intrinsics) -> anyhow::Result<TensorRun> {
        let n = self.landmarks.len();
        Ok(TensorRun {
            ws: self.fitter.workspace(),
            state: self.fitter.initial_state(),
            fitter: self.fitter.clone(),
            landmarks: self.landmarks.clone(),
            camera,
            image: vec![nalgebra::Point2::origin(); n],
            weights: vec![1.0; n],
            values: vec![f64::NAN; self.columns.len()],
            csv: facecap_core::csv::FrameCsvWriter::create(out_dir.join("tensor.csv"), &self.columns)?,
        })
    }
}

impl TensorRun {
    /// One frame: pose, identity and expression weights fitted to the landmarks
    /// (warm-started from the previous frame).
    pub fn frame(&mut self, index: u64, t: f64, lms: Option<&Landmarks68>, confidence: f64) -> anyhow::Result<()> {
        let mut success = false;
        self.values.fill(f64::NAN);
        if let Some(l) = lms {
            for (slot, &i) in self.landmarks.iter().enumerate() {
                self.image[slot] = l.points[i];
            }
            let input = facecap_tensor::fit::FitInput {
                image: &self.image,
                weights: &self.weights,
                intrinsics: self.camera,
            };
            if self.fitter.solve_into(&input, &mut self.ws, &mut self.state).is_ok() {
                if let Some(p) = &self.state.pose {
                    // Same convention as pose.csv (rotation relative to facing the camera).
                    self.values[..6].copy_from_slice(&crate::cmd_capture::pose_row(Some(p)));
                }
                let ni = self.state.w_id.len();
                self.values[6..6 + ni].copy_from_slice(&self.state.w_id);
                self.values[6 + ni..6 + ni + self.state.w_exp.len()].copy_from_slice(&self.state.w_exp);
                success = true;
            } else {
                self.state = self.fitter.initial_state();
            }
        }
        self.csv.write_row(&facecap_core::csv::FrameRow {
            frame: index,
            timestamp: t,
            success,
            confidence,
            values: &self.values,
        })?;
        Ok(())
    }

    /// Commits `tensor.csv`.
    pub fn finish(self) -> anyhow::Result<()> {
        self.csv.finish()?;
        Ok(())
    }
}
