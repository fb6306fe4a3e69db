//! The muscle sink: contractions and jaw angle per frame (`contractions.csv`), for
//! `capture --muscles` and `muscle track`.

use std::path::Path;

use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::mesh::MorphMesh;
use facecap_io::csv::{FrameCsvWriter, FrameRow};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::set::MuscleSet;
use facecap_muscle::track::{
    MuscleTracker, SolveMode, TrackInput, TrackModel, TrackOutput, TrackParams, TrackState, TrackWorkspace,
};
use nalgebra::{Point2, Point3, Rotation3};

use crate::error::Result;
use crate::sink::{Sink, TrackedFace};

/// Tracking points per muscle.
const POINTS_PER_MUSCLE: usize = 4;

/// The muscle set-up shared by all videos: the rig and the tracking model over its
/// mapped landmarks.
#[derive(Debug, Clone)]
pub struct MuscleSetup {
    /// The muscle rig on the mesh.
    pub rig: MuscleRig,
    model: TrackModel,
    mode: SolveMode,
    names: Vec<String>,
}

impl MuscleSetup {
    /// The muscle set `set` (`None`: the default 11 muscles placed from the mesh's 68
    /// landmarks) on `mesh` with its landmark map.
    ///
    /// # Errors
    /// An unplaceable set or a map that does not fit the mesh.
    pub fn new(set: Option<&MuscleSet>, mesh: &MorphMesh, map: &LandmarkMap, mode: SolveMode) -> Result<Self> {
        map.validate(mesh.base.num_vertices())?;
        let positions: Vec<Point3<f64>> = mesh.base.positions.iter().map(|p| p.cast::<f64>()).collect();
        let owned;
        let set = match set {
            Some(s) => s,
            None => {
                let lm = facecap_muscle::defaults::landmark_positions(map, &positions);
                owned = facecap_muscle::defaults::default_muscle_set(&lm, &positions)?;
                &owned
            }
        };
        let rig = MuscleRig::from_mesh(set, &mesh.base)?;
        Self::from_rig(rig, map, mode)
    }

    /// A set-up over an existing muscle rig.
    ///
    /// # Errors
    /// A map that does not fit the rig.
    pub fn from_rig(rig: MuscleRig, map: &LandmarkMap, mode: SolveMode) -> Result<Self> {
        let model = TrackModel::from_landmarks(&rig, map, &[], POINTS_PER_MUSCLE)?;
        let mut names: Vec<String> = rig.names().to_vec();
        names.push("jaw".to_string());
        Ok(MuscleSetup {
            rig,
            model,
            mode,
            names,
        })
    }

    /// `contractions.csv`'s value columns: one per muscle, then `jaw`.
    pub fn columns(&self) -> &[String] {
        &self.names
    }
}

/// One frame's muscle result (kept with [`MuscleSink::keep_history`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MuscleFrame {
    /// Frame index.
    pub index: u64,
    /// Seconds.
    pub timestamp: f64,
    /// Whether the contractions were solved.
    pub success: bool,
    /// Contractions solved on this frame (the previous ones when not solved).
    pub contractions: Vec<f64>,
    /// Jaw angle (radians).
    pub jaw: f64,
    /// Head rotation (model to camera).
    pub rotation: Rotation3<f64>,
}

/// Writes `contractions.csv`: `frame,timestamp,success,confidence,` one column per
/// muscle in `[0, 1]`, then `jaw` in radians.
#[derive(Debug)]
pub struct MuscleSink {
    tracker: MuscleTracker,
    ws: TrackWorkspace,
    state: TrackState,
    out: TrackOutput,
    points: Vec<Point2<f64>>,
    values: Vec<f64>,
    csv: FrameCsvWriter,
    history: Option<Vec<MuscleFrame>>,
}

impl MuscleSink {
    /// Starts `contractions.csv` in `out_dir` for a video seen through `camera`.
    ///
    /// # Errors
    /// Invalid tracking parameters or file creation.
    pub fn create(out_dir: &Path, setup: &MuscleSetup, camera: Intrinsics) -> Result<Self> {
        let tracker = MuscleTracker::new(
            setup.model.clone(),
            camera,
            TrackParams {
                mode: setup.mode,
                ..TrackParams::default()
            },
        )?;
        Ok(MuscleSink {
            ws: TrackWorkspace::new(&setup.model),
            state: TrackState::new(&setup.model),
            out: TrackOutput::new(&setup.model),
            tracker,
            points: vec![Point2::origin(); setup.model.num_points()],
            values: vec![f64::NAN; setup.names.len()],
            csv: FrameCsvWriter::create(out_dir.join("contractions.csv"), &setup.names)?,
            history: None,
        })
    }

    /// Also keeps every frame's result in memory (returned by `finish`).
    pub fn keep_history(mut self) -> Self {
        self.history = Some(Vec::new());
        self
    }

    /// Commits `contractions.csv`; returns the kept frames (empty without
    /// [`MuscleSink::keep_history`]).
    ///
    /// # Errors
    /// When the file cannot be written or renamed.
    pub fn finish(self) -> Result<Vec<MuscleFrame>> {
        self.csv.finish()?;
        Ok(self.history.unwrap_or_default())
    }
}

impl Sink for MuscleSink {
    fn name(&self) -> &str {
        "muscles"
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        let mut success = false;
        self.values.fill(f64::NAN);
        if let Some(l) = &face.landmarks {
            for (slot, lm) in self.tracker.model().landmark_of_point().iter().enumerate() {
                if let Some(i) = lm {
                    self.points[slot] = l.points[*i];
                }
            }
            let input = TrackInput {
                points: &self.points,
                weights: None,
            };
            if let Ok(rep) = self
                .tracker
                .solve_into(&input, &mut self.ws, &mut self.state, &mut self.out)
            {
                if rep.rms_px.is_finite() {
                    let m = self.out.contractions.len();
                    self.values[..m].copy_from_slice(&self.out.contractions);
                    self.values[m] = self.out.jaw;
                    success = true;
                }
            }
        }
        self.csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success,
            confidence: face.confidence,
            values: &self.values,
        })?;
        if let Some(h) = self.history.as_mut() {
            h.push(MuscleFrame {
                index: face.index,
                timestamp: face.timestamp,
                success,
                contractions: self.state.contractions.clone(),
                jaw: self.state.jaw,
                rotation: self.out.pose.0.rotation.to_rotation_matrix(),
            });
        }
        Ok(())
    }
}
