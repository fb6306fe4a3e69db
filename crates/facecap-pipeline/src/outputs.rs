//! The files made from solved frames, the same for `capture` and `solve`:
//! `animation.glb` (morph weights plus head motion), `obj/frame_NNNNNN.obj`,
//! `livelink.csv` and `openface.csv`.
//!
//! Conventions (docs/capture.md):
//! * **Keyframe times** are `frame / fps` seconds (the frame index at the video's
//!   nominal rate), so at that scene rate every key lands on a whole frame.
//! * **Head motion** in `animation.glb`: the mesh's node gets `translation` and
//!   `rotation` channels from the head pose, in glTF axes (+Y up, +Z toward the viewer;
//!   camera at the origin looking down -Z): rotation `F R F` with `R` the head rotation
//!   relative to facing the camera and `F = diag(1, -1, -1)`, translation
//!   `(tx, -ty, -tz)` in rig units. Frames without a pose hold the last one. With
//!   `still_head` (or no pose at all) the node stays at the origin.
//! * **OBJ names**: `obj/frame_NNNNNN.obj`, `NNNNNN` the 0-based frame index (six
//!   digits); `model` space is the rig's frame, `camera` space the posed head in camera
//!   axes (x right, y down, z forward, rig units).
//! * **Failed frames** (no face, or a solve rejected as implausible) never look like a
//!   neutral face: `livelink.csv` has no row for them, `animation.glb` no keyframe (it
//!   is not written when no frame was solved), `obj/` no mesh; `weights.csv`,
//!   `pose.csv` and `openface.csv` keep their row with `success = 0` and `nan` values.

use std::path::Path;

use facecap_core::camera::{head_rotation, ModelToCamera, FACING_CAMERA};
use facecap_core::mesh::MorphMesh;
use facecap_io::gltf_io::{write_glb_animated, AnimationExtras, MorphAnimation, NodeTrack};
use facecap_solve::BlendshapeRig;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};
use crate::expression::{ExpressionResult, SolvedFrame};
use facecap_io::livelink::{self, LiveLinkRow};

/// Coordinate frame of the OBJ meshes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ObjSpace {
    /// The rig's own frame (expression only).
    #[default]
    Model,
    /// Posed by the head pose into camera axes.
    Camera,
}

impl std::str::FromStr for ObjSpace {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "model" => Ok(ObjSpace::Model),
            "camera" => Ok(ObjSpace::Camera),
            _ => Err(Error::invalid("obj space", s, "camera or model")),
        }
    }
}

/// Which of the files to write and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOutputs {
    /// Write `obj/` meshes in this space.
    pub obj: Option<ObjSpace>,
    /// Leave the head out of `animation.glb`.
    pub still_head: bool,
    /// The video's nominal frame rate (keyframe times, Live Link timecodes).
    pub fps: f64,
    /// Millimetres per rig unit for `openface.csv`.
    pub rig_unit_mm: f64,
}

/// What was written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Written {
    /// `livelink.csv` when the rig's names map onto ARKit.
    pub livelink: Option<String>,
    /// Whether `animation.glb` carries head motion.
    pub head_animated: bool,
    /// OBJ files written.
    pub objs: usize,
}

/// Keyframe seconds of frame `index` at `fps`.
pub fn keyframe_time(index: u64, fps: f64) -> f64 {
    index as f64 / fps
}

/// The head pose per frame with gaps held (before the first pose: the first pose);
/// `None` when no frame has a pose.
pub fn held_poses(frames: &[SolvedFrame]) -> Option<Vec<ModelToCamera>> {
    let first = frames.iter().find_map(|f| f.pose)?;
    let mut last = first;
    Some(
        frames
            .iter()
            .map(|f| {
                if let Some(p) = f.pose {
                    last = p;
                }
                last
            })
            .collect(),
    )
}

/// The glTF node transform of a head pose (module docs): `(translation, quaternion xyzw)`.
pub fn gltf_node_transform(pose: &ModelToCamera) -> ([f32; 3], [f32; 4]) {
    let f = Matrix3::from_diagonal(&Vector3::from(FACING_CAMERA));
    let r = Rotation3::from_matrix_unchecked(f * head_rotation(pose).matrix() * f);
    let q = UnitQuaternion::from_rotation_matrix(&r);
    let t = pose.tvec();
    (
        [t.x as f32, -t.y as f32, -t.z as f32],
        [q.i as f32, q.j as f32, q.k as f32, q.w as f32],
    )
}

/// Writes the files of [`SolveOutputs`] into `out_dir` (module docs).
///
/// # Errors
/// Invalid fps, meshes that do not fit the weights, or write failures.
pub fn write_solve_outputs(
    out_dir: &Path,
    rig: &BlendshapeRig,
    mesh: &MorphMesh,
    result: &ExpressionResult,
    o: &SolveOutputs,
) -> Result<Written> {
    if !(o.fps.is_finite() && o.fps > 0.0) {
        return Err(Error::invalid("fps", o.fps, "a finite number > 0"));
    }
    let frames = &result.frames;
    let mut written = Written::default();
    let poses = held_poses(frames);
    written.livelink = livelink::write_if_arkit(
        &out_dir.join("livelink.csv"),
        &result.names,
        o.fps,
        // Frames without a solve get no row (their timecodes are missing), so a failed
        // frame never reads as a neutral face in an importer.
        frames.iter().filter(|f| f.success).map(|f| LiveLinkRow {
            index: f.index,
            weights: &f.weights,
            pose: f.pose.as_ref(),
        }),
        crate::net::eye_columns,
    )?;
    crate::openface::write_openface_csv(&out_dir.join("openface.csv"), rig, frames, o.rig_unit_mm)?;
    if frames.iter().any(|f| f.success) {
        let mut anim = MorphAnimation::default();
        let mut track = NodeTrack::default();
        for (k, f) in frames.iter().enumerate() {
            // Keys only on solved frames: glTF interpolates over failed ones instead of
            // showing a neutral face (or a held one) as if it had been measured.
            if !f.success {
                continue;
            }
            let t = keyframe_time(f.index, o.fps) as f32;
            if anim.times_s.last().is_some_and(|&l| t <= l) {
                continue;
            }
            anim.times_s.push(t);
            anim.weights.push(f.weights.iter().map(|&w| w as f32).collect());
            if let Some(p) = &poses {
                let (tr, q) = gltf_node_transform(&p[k]);
                track.translations.push(tr);
                track.rotations.push(q);
            }
        }
        written.head_animated = poses.is_some() && !o.still_head;
        write_glb_animated(
            out_dir.join("animation.glb"),
            mesh,
            &anim,
            &AnimationExtras {
                node: written.head_animated.then_some(&track),
                fps: Some(o.fps),
            },
        )?;
    }
    if let Some(space) = o.obj {
        let dir = out_dir.join("obj");
        std::fs::create_dir_all(&dir).map_err(|e| facecap_core::Error::io(&dir, e))?;
        let mut posed = Vec::new();
        let mut m = mesh.base.clone();
        for (k, f) in frames.iter().enumerate() {
            if !f.success {
                // no mesh for a frame without a solve (a neutral OBJ would look measured)
                continue;
            }
            mesh.pose_into(&f.weights, &mut posed)?;
            if let (ObjSpace::Camera, Some(p)) = (space, poses.as_ref().map(|p| p[k])) {
                for v in posed.iter_mut() {
                    *v = p.transform(&v.cast::<f64>()).cast::<f32>();
                }
            }
            m.positions.clone_from(&posed);
            m.compute_normals();
            facecap_io::obj::write_obj(obj_path(out_dir, f.index), &m)?;
            written.objs += 1;
        }
    }
    Ok(written)
}

/// `DIR/obj/frame_NNNNNN.obj` of frame `index` (the one OBJ naming).
pub fn obj_path(out_dir: &Path, index: u64) -> std::path::PathBuf {
    out_dir.join("obj").join(format!("frame_{index:06}.obj"))
}
