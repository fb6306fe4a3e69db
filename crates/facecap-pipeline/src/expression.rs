//! The expression solve: blendshape weights and head pose per frame, `weights.csv` and
//! `pose.csv`, the same for `capture` (tracked video) and `solve` (a landmarks CSV).
//!
//! The solver set-up, including the per-subject neutral calibration, is behind one
//! function, [`build_expression_solve`]: the sink calls it once per video (after the
//! last frame when a calibration needs the whole clip).
//!
//! Head pose: `exact3d` solves it with the weights. For the 2D solvers (`exact`,
//! `bobyqa`, `region`, `pca`), a perspective PnP pose ([`facecap_geom::pnp::solve_pnp`],
//! warm-started from the previous frame) of the rig's landmarks *posed with the solved
//! weights* is fitted to the tracked landmarks beside them, so `pose.csv` has a pose with
//! every solver.

use std::path::Path;
use std::sync::Arc;

use facecap_core::camera::{pose_row, Intrinsics, ModelToCamera};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_geom::pnp::{solve_pnp, PnpParams};
use facecap_io::csv::{FrameCsvWriter, FrameRow, POSE_COLUMNS};
use facecap_landmarks::gaze::{GazeGains, GazeRest, HeadTurn, IrisFrame};
use facecap_solve::{
    AnySolver, BlendshapeRig, DensePoints, ExpressionSolver, Method, ObjectiveParams, ShapePriors, Solution, SolveState,
};
use image::GrayImage;
use nalgebra::{Point2, Point3};

use crate::error::{BoxError, Error, Result};
use crate::sink::{FrameImages, Sink, TrackedFace};

/// What the expression solve is built from (shared by all videos of a run).
#[derive(Debug, Clone)]
pub struct ExpressionSetup {
    /// The rig at the 68 landmarks (with its mesh for meshes and glTF).
    pub rig: BlendshapeRig,
    /// The solver.
    pub method: Method,
    /// Objective weights (L1, temporal).
    pub objective: ObjectiveParams,
    /// Per-shape priors of the 3D solver (`None`: none).
    pub priors: Option<ShapePriors>,
    /// Dense points of the 3D solver, observed as the face mesh's points of each frame
    /// ([`TrackedFace::mesh`]; `None`: the 68 landmarks only). Their neutral follows the
    /// rig's neutral calibration ([`facecap_solve::dense::calibrate_points`]).
    pub dense: Option<DensePoints>,
}

/// A calibrated rig and what was done (for `summary.json`).
#[derive(Debug, Clone)]
pub struct Calibrated {
    /// The rig with the subject's neutral.
    pub rig: BlendshapeRig,
    /// JSON report of the calibration.
    pub report: serde_json::Value,
}

/// A per-subject neutral calibration that needs every tracked frame first.
pub trait NeutralCalibration: Send + Sync {
    /// Calibrates `rig` on `frames` (frame index, tracked landmarks); `solver` is the
    /// generic rig's solver, built with `camera`.
    ///
    /// # Errors
    /// Whatever the calibration fails with.
    fn calibrate(
        &self,
        solver: &AnySolver,
        rig: &BlendshapeRig,
        camera: Intrinsics,
        frames: &[(u64, Landmarks68)],
    ) -> std::result::Result<Calibrated, BoxError>;
}

/// A calibration hook and the clip's tracked frames (frame index, landmarks).
pub type CalibrationInput<'a> = (&'a dyn NeutralCalibration, &'a [(u64, Landmarks68)]);

/// The one place the expression solver is set up: the generic rig's solver, or, with a
/// calibration and the clip's tracked frames, the solver of the calibrated rig.
/// Returns the solver and the calibration's report (`null` without one).
///
/// # Errors
/// Invalid solver parameters or a failed calibration.
pub fn build_expression_solve(
    setup: &ExpressionSetup,
    camera: Intrinsics,
    calibration: Option<CalibrationInput<'_>>,
) -> Result<(AnySolver, serde_json::Value)> {
    let with_priors = |s: AnySolver| -> Result<AnySolver> {
        Ok(match &setup.priors {
            Some(p) => s.with_priors(p.clone())?,
            None => s,
        })
    };
    let with_dense = |s: AnySolver, rig: &BlendshapeRig| -> Result<AnySolver> {
        Ok(match &setup.dense {
            Some(d) => s.with_dense(facecap_solve::dense::calibrate_points(d, &setup.rig, rig))?,
            None => s,
        })
    };
    let solver = with_dense(
        with_priors(AnySolver::new(setup.method, &setup.rig, camera, setup.objective)?)?,
        &setup.rig,
    )?;
    let Some((cal, frames)) = calibration else {
        return Ok((solver, serde_json::Value::Null));
    };
    if frames.is_empty() {
        // No face anywhere: nothing to calibrate on; every frame is written as failed.
        return Ok((
            solver,
            serde_json::json!({"mode": "skipped", "reason": "no tracked frame"}),
        ));
    }
    let c = cal
        .calibrate(&solver, &setup.rig, camera, frames)
        .map_err(Error::Calibration)?;
    let calibrated = with_dense(
        with_priors(AnySolver::new(setup.method, &c.rig, camera, setup.objective)?)?,
        &c.rig,
    )?;
    Ok((calibrated, c.report))
}

/// One solved frame (kept for the animation, meshes and the report).
#[derive(Debug, Clone, PartialEq)]
pub struct SolvedFrame {
    /// Frame index.
    pub index: u64,
    /// Seconds.
    pub timestamp: f64,
    /// Whether the weights were solved (else they repeat the previous frame's).
    pub success: bool,
    /// Tracking confidence.
    pub confidence: f64,
    /// Tracked landmarks.
    pub landmarks: Option<Landmarks68>,
    /// Weights (the previous solved frame's when `success` is false; zeros before any).
    pub weights: Vec<f64>,
    /// Head pose (model to camera), from `exact3d` or the PnP beside a 2D solver.
    pub pose: Option<ModelToCamera>,
    /// Mean landmark reprojection error of the solve, px.
    pub reprojection_px: f64,
}

/// What the sink leaves when finished.
#[derive(Debug, Clone)]
pub struct ExpressionResult {
    /// Blendshape names (rig order).
    pub names: Vec<String>,
    /// One entry per frame.
    pub frames: Vec<SolvedFrame>,
    /// Frames kept for a contact sheet: (index into `frames`, grey image).
    pub sheet: Vec<(usize, Arc<GrayImage>)>,
    /// Frames with a face.
    pub faces_found: u64,
    /// The calibration report (`null` without calibration).
    pub neutral_report: serde_json::Value,
    /// Per-frame solver failures (frame, message); those frames are written unsolved.
    pub failures: Vec<(u64, String)>,
    /// Frames solved with the dense points ([`ExpressionSetup::dense`]) observed.
    pub dense_frames: u64,
    /// What the companion rig did, or why it was skipped (`null` without one,
    /// [`ExpressionSink::with_companion`]).
    pub companion: serde_json::Value,
}

/// Largest plausible mean reprojection error of a solve, as a fraction of the tracked
/// face's size (the diagonal of the landmarks' bounding box). Measured solves are around
/// 1-2 % of it; a solve off by a quarter of the face has fitted nothing.
pub const MAX_REPROJECTION_FACE_FRACTION: f64 = 0.25;
/// Largest plausible head distance from the camera, rig units.
pub const MAX_HEAD_DISTANCE: f64 = 1e5;

/// `Ok` when a solve is plausible, else why not: a reprojection error above
/// [`MAX_REPROJECTION_FACE_FRACTION`] of the face, or a non-finite or absurdly distant
/// pose ([`MAX_HEAD_DISTANCE`]). Such frames are written as failed, not as solved.
///
/// # Errors
/// The reason, as text.
pub fn implausible_solve(
    l: &Landmarks68,
    reprojection_px: f64,
    pose: Option<&ModelToCamera>,
) -> std::result::Result<(), String> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in &l.points {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    let face = (x1 - x0).hypot(y1 - y0);
    let limit = MAX_REPROJECTION_FACE_FRACTION * face;
    if !(reprojection_px.is_finite() && reprojection_px <= limit) {
        return Err(format!(
            "implausible solve: mean reprojection error {reprojection_px:.1} px on a face of {face:.1} px \
             (limit {limit:.1} px)"
        ));
    }
    if let Some(p) = pose {
        let t = p.tvec();
        let d = t.norm();
        if !(d.is_finite() && d <= MAX_HEAD_DISTANCE) {
            return Err(format!(
                "implausible solve: head at distance {d:e} rig units (limit {MAX_HEAD_DISTANCE:e})"
            ));
        }
    }
    Ok(())
}

/// Solves every frame and writes `weights.csv` (`frame,timestamp,success,confidence,`
/// then one column per rig shape) and `pose.csv` (`frame,timestamp,success,confidence,
/// pose_Tx..pose_Rz`, [`facecap_core::camera::pose_row`]).
pub struct ExpressionSink<'a> {
    setup: &'a ExpressionSetup,
    camera: Option<Intrinsics>,
    calibration: Option<&'a dyn NeutralCalibration>,
    sheet_policy: FrameImages,
    solving: Option<Solving>,
    buffered: Vec<TrackedFace>,
    /// `pose.csv` and `weights.csv` (`None`: a companion's sink, which writes nothing).
    pose_csv: Option<FrameCsvWriter>,
    w_csv: Option<FrameCsvWriter>,
    result: ExpressionResult,
    pnp_model: Vec<Point3<f64>>,
    pnp_image: Vec<Point2<f64>>,
    /// The solver's weights of the last solved frame (without the gaze shapes' values).
    prev_solver_weights: Vec<f64>,
    /// The last frame's head pose (the PnP's warm start beside a 2D solver).
    prev_pose: Option<ModelToCamera>,
    gaze: Gaze,
    /// The rig's `eyeBlink*` shapes, their sides and the shapes a closing lid drives
    /// (see [`blink_weight`], [`closed_eye_weights`]).
    blink_idx: Vec<BlinkShape>,
    /// The rig's `(mouthShrugLower, mouthRollLower)`, when it has both (see
    /// [`rolled_lip_shrug`]).
    shrug_idx: Option<(usize, usize)>,
    /// The lips' red and the chin's rise ([`crate::lips`]).
    lips: crate::lips::Lips,
    /// Neutral calibration on the fly (live input), see [`ExpressionSink::with_live_neutral`].
    live: Option<LiveNeutralState>,
    /// A second rig solved on the same frames, see [`ExpressionSink::with_companion`].
    companion: Option<Companion<'a>>,
}

/// The companion of [`ExpressionSink::with_companion`]: its sink (which writes nothing)
/// and the shapes averaged, `(index in this rig, index in the companion)`.
struct Companion<'a> {
    sink: Box<ExpressionSink<'a>>,
    /// The companion's whole-clip neutral calibration.
    calibration: &'a dyn NeutralCalibration,
    pairs: Vec<(usize, usize)>,
    /// The companion rig's name (for `summary.json`).
    label: String,
}

/// The shapes two rigs both solve, matched by ARKit name (`eyeBlinkLeft` = `eyeBlink_L`,
/// [`facecap_solve::observability::split_side`]; a sided shape of `a` with an unsided one
/// of `b`), as `(index in a, index in b)`: a shape either rig's priors hold at 0 is not
/// paired (its value comes from one rig alone).
pub fn shared_solved_shapes(a: &ExpressionSetup, b: &ExpressionSetup) -> Vec<(usize, usize)> {
    use facecap_solve::observability::split_side;
    let free = |s: &ExpressionSetup, k: usize| match &s.priors {
        Some(p) => !p.fixed.get(k).copied().unwrap_or(true),
        None => true,
    };
    let mut out = Vec::new();
    for (i, n) in a.rig.names.iter().enumerate() {
        if !free(a, i) {
            continue;
        }
        let key = split_side(n);
        // a sided shape also pairs with the other rig's unsided one (ARKit's
        // `browInnerUp` against ICT's `browInnerUp_L` / `_R`)
        let j = b.rig.names.iter().position(|m| split_side(m) == key).or_else(|| {
            b.rig
                .names
                .iter()
                .position(|m| key.1.is_some() && split_side(m) == (key.0, None))
        });
        if let Some(j) = j {
            if free(b, j) {
                out.push((i, j));
            }
        }
    }
    out
}

/// Fewest shared shapes ([`shared_solved_shapes`]) for [`ExpressionSink::with_companion`].
pub const MIN_COMPANION_SHAPES: usize = 10;

/// When a live run takes the subject's neutral: the `window` seconds of tracked frames
/// that start `after` seconds into the stream, and again (the next `window` seconds)
/// whenever `redo` is set.
#[derive(Debug, Clone)]
pub struct LiveNeutral {
    /// Seconds from the first tracked face to the start of the window (>= 0).
    pub after: f64,
    /// Length of the resting window in seconds (> 0).
    pub window: f64,
    /// Set to take the neutral again from the next frames (cleared when taken up).
    pub redo: Arc<std::sync::atomic::AtomicBool>,
}

/// Fewest tracked frames a live neutral window needs.
pub const LIVE_NEUTRAL_MIN_FRAMES: usize = 5;

/// A neutral fit running on its own thread: (calibration number, first and last frame,
/// frames) and the channel its solver comes back on.
type PendingNeutral = (
    (u32, u64, u64, usize),
    std::sync::mpsc::Receiver<Result<(AnySolver, serde_json::Value)>>,
);

struct LiveNeutralState {
    cal: Arc<dyn NeutralCalibration>,
    params: LiveNeutral,
    /// Stream time of the first tracked face of the current attempt.
    start: Option<f64>,
    frames: Vec<(u64, Landmarks68)>,
    /// A calibration is being collected.
    collecting: bool,
    /// Calibrations started so far.
    taken: u32,
    /// The fit in progress.
    pending: Option<PendingNeutral>,
}

/// The gaze shapes (`eyeLook*`) from the iris centres against the subject's resting
/// gaze: the solver holds them at 0 and their weights come from
/// [`facecap_landmarks::gaze::gaze_weights`] on every solved frame with an iris estimate.
#[derive(Debug, Clone, Default)]
struct Gaze {
    /// The gaze shapes' indices in the rig, in `GAZE_WEIGHT_NAMES` order.
    idx: [Option<usize>; 8],
    /// The subject's resting gaze (`GazeRest::towards_straight_ahead` of the whole clip when
    /// every frame is known first).
    rest: Option<GazeRest>,
    /// Whether `rest` comes from the whole clip (else from the frames so far).
    rest_from_clip: bool,
    /// Iris estimates so far (the running rest when frames stream).
    seen: Vec<IrisFrame>,
    /// The subject's resting head rotation `(pitch, yaw)` (`pose.csv`'s `Rx`, `Ry`), the
    /// same median as `rest`; the gaze is the eyes' turn in the head from it.
    rest_head: Option<(f64, f64)>,
    /// Head rotations so far (the running rest when frames stream).
    seen_head: Vec<(f64, f64)>,
}

/// Gain on the solved `eyeBlink*` weights. dlib's 68 points never close an eye: on the
/// shared clips a visibly closed eye keeps 30-55 % of its resting eye aspect ratio (d9:
/// 0.08-0.15 against 0.28 at rest), so the solve reaches about 0.55 of a rig's full
/// closure there. The gain maps that to 1 (docs/expressions.md, "Eyes").
pub const BLINK_GAIN: f64 = 1.8;

/// How much a plainly visible iris damps `eyeBlink*`: the weight is multiplied by
/// `1 - BLINK_IRIS_DAMPING * clamp((c - BLINK_IRIS_FROM) / (1 - BLINK_IRIS_FROM), 0, 1)`,
/// with `c` the eye's iris confidence in [0, 1]
/// ([`facecap_landmarks::gaze::EyeEstimate::confidence`]: 1 for an open eye whose dark
/// iris stands out, 0 for a closed eye or no estimate). A downward glance lowers the
/// upper lid by about a quarter of the eye's opening and the solve reads it as half a
/// blink, but the iris stays in plain view (confidence 1 on liveportrait_d6's glances);
/// in a blink it fades (0.4-0.7 at the peak of d9's blinks, 0 when the lids meet).
/// docs/expressions.md, "Eyes".
pub const BLINK_IRIS_DAMPING: f64 = 0.8;

/// Iris confidence below which `eyeBlink*` is not damped (see [`BLINK_IRIS_DAMPING`]).
pub const BLINK_IRIS_FROM: f64 = 0.5;

/// `eyeBlink*` after the gain and the iris damping (see [`BLINK_GAIN`],
/// [`BLINK_IRIS_DAMPING`]); an `iris_confidence` that is NaN counts as 0 (no estimate).
pub fn blink_weight(solved: f64, iris_confidence: f64) -> f64 {
    let c = if iris_confidence.is_finite() {
        iris_confidence
    } else {
        0.0
    };
    let visible = ((c - BLINK_IRIS_FROM) / (1.0 - BLINK_IRIS_FROM)).clamp(0.0, 1.0);
    let w = solved * BLINK_GAIN * (1.0 - BLINK_IRIS_DAMPING * visible);
    if w.is_finite() {
        w.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// How far a closing lid drives `eyeLookDown*`: the weight becomes
/// `max(eyeLookDown, CLOSED_EYE_LOOK_DOWN * eyeBlink)` on the same side. Under a closing
/// lid the iris disappears, so the gaze estimate has nothing to go on; meanwhile the eye
/// itself turns down (and in) during a blink (blink-associated eye movements, Collewijn,
/// van der Steen & Steinman 1985; Riggs, Kelly, Manning & Moore 1987), and ARKit's scores
/// carry it: MediaPipe's `eyeLookDown` follows its own `eyeBlink` with r 0.74-0.90 on the
/// shared clips. Measured (docs/expressions.md, "The closed eye"): mean r +0.014 (dlib68)
/// and +0.033 (mesh, whose iris gaze stays level through a blink). 0.4 until the gaze
/// became the eyes' turn in the head (docs/gaze.md, "Head turns"), which reads more of
/// the downward look itself; then 0.3 gave mean r 0.7915 -> 0.7924 (built-in) and 0.8003
/// -> 0.8007 (ICT), and the synthetic RMSE 0.0827 -> 0.0812 (0.2: 0.7924 / 0.7999 /
/// 0.0801; 0.5: 0.7905 / 0.7995 / 0.0845).
pub const CLOSED_EYE_LOOK_DOWN: f64 = 0.3;

/// How much of `eyeBlink*` is added to `eyeSquint*` on the same side (clamped to 1). A
/// blink is the palpebral part of orbicularis oculi, the muscle whose contraction is the
/// squint (FACS AU7 lid tightener, with AU6 the orbital part), and the lower lid rises with
/// it; ARKit's scores carry it (MediaPipe's `eyeSquint` follows its `eyeBlink` with r
/// 0.76-0.83 on four of the shared clips). The 68 points cannot tell the lower lid's rise in
/// a blink from the upper lid's fall, so the solve gives all of it to `eyeBlink`.
/// Measured (docs/expressions.md, "The closed eye"): mean r +0.017 (dlib68), +0.013 (mesh).
pub const CLOSED_EYE_SQUINT: f64 = 0.3;

/// One `eyeBlink*` shape of a rig and the shapes of its side that a closing lid drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct BlinkShape {
    blink: usize,
    side: Option<char>,
    look_down: Option<usize>,
    squint: Option<usize>,
    /// `eyeLookIn*` and `eyeLookOut*`: faded by [`closed_eye_sideways`].
    sideways: [Option<usize>; 2],
}

impl BlinkShape {
    /// Every `eyeBlink*` of `names`, with the `eyeLookDown*`, `eyeSquint*`, `eyeLookIn*`
    /// and `eyeLookOut*` of its side.
    fn of_rig(names: &[String]) -> Vec<Self> {
        let find = |base: &str, side: Option<char>| shape_index(names, base, side);
        names
            .iter()
            .enumerate()
            .filter_map(|(k, n)| {
                let (base, side) = facecap_solve::observability::split_side(n);
                (base == "eyeBlink").then(|| BlinkShape {
                    blink: k,
                    side,
                    look_down: find("eyeLookDown", side),
                    squint: find("eyeSquint", side),
                    sideways: [find("eyeLookIn", side), find("eyeLookOut", side)],
                })
            })
            .collect()
    }

    /// Applies [`closed_eye_weights`] and [`closed_eye_sideways`] to this side's shapes in
    /// `weights`.
    fn drive_closed_eye(&self, weights: &mut [f64]) {
        let blink = weights[self.blink];
        let value = |k: Option<usize>| k.map_or(0.0, |k| weights[k]);
        let (d, s) = closed_eye_weights(blink, value(self.look_down), value(self.squint));
        if let Some(k) = self.look_down {
            weights[k] = d;
        }
        if let Some(k) = self.squint {
            weights[k] = s;
        }
        for k in self.sideways.into_iter().flatten() {
            weights[k] = closed_eye_sideways(blink, weights[k]);
        }
    }
}

/// A sideways gaze weight (`eyeLookIn*` / `eyeLookOut*`) of an eye whose final `eyeBlink`
/// is `blink`: `look * (1 - blink)`. A closing lid covers the iris, and the image's iris
/// centre (the dark region's mode, `facecap_landmarks::gaze`) then follows the lid's edge,
/// not the eye. Measured (docs/expressions.md, "The closed eye"): mean r +0.005 with dlib's
/// points (the image's iris), -0.0003 with the mesh's (the model's iris). Non-finite
/// inputs count as 0.
pub fn closed_eye_sideways(blink: f64, look: f64) -> f64 {
    unit(look) * (1.0 - unit(blink))
}

/// A weight clamped to [0, 1]; non-finite counts as 0.
pub(crate) fn unit(x: f64) -> f64 {
    if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The index in `names` of the shape named `base` on `side` (ARKit or ICT spelling).
fn shape_index(names: &[String], base: &str, side: Option<char>) -> Option<usize> {
    use facecap_solve::observability::split_side;
    names.iter().position(|n| split_side(n) == (base, side))
}

/// `(eyeLookDown, eyeSquint)` of one eye given its final `eyeBlink` (after
/// [`blink_weight`]) and the gaze's `eyeLookDown` and the solved `eyeSquint`: see
/// [`CLOSED_EYE_LOOK_DOWN`] and [`CLOSED_EYE_SQUINT`]. Non-finite inputs count as 0; both
/// results are in [0, 1].
pub fn closed_eye_weights(blink: f64, look_down: f64, squint: f64) -> (f64, f64) {
    let (b, d, s) = (unit(blink), unit(look_down), unit(squint));
    (d.max(CLOSED_EYE_LOOK_DOWN * b), (s + CLOSED_EYE_SQUINT * b).min(1.0))
}

/// How much of `mouthRollLower` is added to `mouthShrugLower` (clamped to 1). Both raise
/// the lower lip's outer edge towards the upper lip; the 68 points cannot tell them
/// apart (the built-in rig's two shapes move them along directions with cosine 0.80 in
/// the image plane; what separates them, the lip's depth and the chin's small rise, a
/// camera in front hardly sees), so the solve's priors give the motion to `mouthRollLower`
/// and `mouthShrugLower` kept 0.13-0.23x of MediaPipe's spread. The chin raiser (FACS AU17,
/// the mentalis) is what pushes the lower lip up and in: ARKit's scores carry both, and
/// MediaPipe's `mouthShrugLower` follows its own `mouthRollLower` with r 0.83 on
/// liveportrait_d18 and 0.72 on liveportrait_d6. Measured (docs/expressions.md, "The
/// chin raiser with the rolled lip"): `mouthShrugLower` r 0.545 -> 0.70 (built-in) and
/// 0.44 -> 0.67 (ICT), flat for shares 0.5-1.
pub const ROLLED_LIP_SHRUG: f64 = 0.5;

/// `(mouthShrugLower, mouthRollLower)` of a rig's `names` (ARKit's or ICT's spelling),
/// when it has both.
fn rolled_lip_shapes(names: &[String]) -> Option<(usize, usize)> {
    shape_index(names, "mouthShrugLower", None).zip(shape_index(names, "mouthRollLower", None))
}

/// `mouthShrugLower` given the solved `mouthShrugLower` and `mouthRollLower` (see
/// [`ROLLED_LIP_SHRUG`]). Non-finite inputs count as 0; the result is in [0, 1].
pub fn rolled_lip_shrug(shrug: f64, roll: f64) -> f64 {
    (unit(shrug) + ROLLED_LIP_SHRUG * unit(roll)).min(1.0)
}

/// Zero-lag smoothing of a whole clip's solved weights (capture and `solve`, where every
/// frame is solved before any is written; live input is not smoothed, it cannot wait for
/// the next frames). Per shape, over each run of consecutive solved frames (a failed frame
/// splits the runs): a centred 3-frame median, then a centred `[1, 2, 1] / 4` average
/// (renormalised at a run's ends). The median removes single-frame outliers of the landmark
/// track: an eye that reads open for one frame inside a blink (liveportrait_d9 frames 299,
/// 382: dlib's points jump back to an open eye for one frame) and one-frame spikes at rest;
/// a blink of two frames or more keeps its peak. Both filters are symmetric, so a blink's
/// onset is not delayed. Measured on the five shared clips (docs/expressions.md,
/// "Temporal"): eyeBlink r 0.894 -> 0.912 (built-in) and 0.892 -> 0.908 (ICT).
pub fn smooth_weights(frames: &mut [SolvedFrame]) {
    let mut start = 0;
    while start < frames.len() {
        if !frames[start].success {
            start += 1;
            continue;
        }
        let mut end = start;
        while end < frames.len() && frames[end].success {
            end += 1;
        }
        smooth_run(&mut frames[start..end]);
        start = end;
    }
}

/// [`smooth_weights`] on one run of solved frames.
fn smooth_run(run: &mut [SolvedFrame]) {
    let len = run.len();
    if len < 3 {
        return;
    }
    let n = run[0].weights.len();
    let mut med = vec![0.0; len];
    for k in 0..n {
        if run.iter().any(|f| f.weights.len() != n || !f.weights[k].is_finite()) {
            continue;
        }
        for (i, m) in med.iter_mut().enumerate() {
            *m = if i == 0 || i + 1 == len {
                run[i].weights[k]
            } else {
                let (a, b, c) = (run[i - 1].weights[k], run[i].weights[k], run[i + 1].weights[k]);
                a.max(b).min(a.min(b).max(c))
            };
        }
        for i in 0..len {
            let (mut sum, mut w) = (2.0 * med[i], 2.0);
            if i > 0 {
                sum += med[i - 1];
                w += 1.0;
            }
            if i + 1 < len {
                sum += med[i + 1];
                w += 1.0;
            }
            run[i].weights[k] = sum / w;
        }
    }
}

/// Per axis the median of finite head rotations `(pitch, yaw)` (the resting gaze's
/// median); `None` without one.
fn median_head(heads: &[(f64, f64)]) -> Option<(f64, f64)> {
    let med = |pick: fn(&(f64, f64)) -> f64| {
        let mut v: Vec<f64> = heads.iter().map(pick).filter(|x| x.is_finite()).collect();
        facecap_landmarks::gaze::median(&mut v)
    };
    Some((med(|h| h.0)?, med(|h| h.1)?))
}

/// A pose's head rotation `(pitch, yaw)` against the line of sight to the camera:
/// `pose.csv`'s `Rx` (positive chin down) and `Ry` (positive towards the subject's right),
/// which are against the optical axis, plus the angle of the head's position off that
/// axis. A head below the axis looks up to the camera as a head pitched chin down does;
/// a head right of it (image right) looks left to it, as a head turned to the image's
/// right does (`Ry < 0`). Measured against the rotation alone (docs/gaze.md, "Head
/// turns"): mean r 0.7900 -> 0.7915 (built-in), 0.7993 -> 0.8003 (ICT).
fn head_of(pose: Option<&ModelToCamera>) -> Option<(f64, f64)> {
    let [tx, ty, tz, rx, ry, _] = pose_row(pose);
    if tz.is_nan() || tz <= 0.0 {
        return None;
    }
    let (pitch, yaw) = (rx + ty.atan2(tz), ry - tx.atan2(tz));
    (pitch.is_finite() && yaw.is_finite()).then_some((pitch, yaw))
}

/// Frames' measures kept for a running rest of live input (the resting gaze, the lips'
/// rest), at most.
pub(crate) const RUNNING_REST_SEEN_MAX: usize = 100_000;
/// Frames between updates of a running rest (and before the first).
pub(crate) const RUNNING_REST_EVERY: usize = 15;

/// Whether a running rest is due for an update now that `seen` frames have been kept:
/// every [`RUNNING_REST_EVERY`] frames, and at the first chance while there is none.
pub(crate) fn running_rest_due(seen: usize, has_rest: bool) -> bool {
    seen >= RUNNING_REST_EVERY && (seen % RUNNING_REST_EVERY == 0 || !has_rest)
}

impl Gaze {
    fn new(names: &[String]) -> Self {
        let mut idx = [None; 8];
        for (slot, want) in idx.iter_mut().zip(facecap_landmarks::gaze::GAZE_WEIGHT_NAMES) {
            let (base, side) = facecap_solve::observability::split_side(want);
            *slot = shape_index(names, base, side);
        }
        Gaze { idx, ..Gaze::default() }
    }

    fn active(&self) -> bool {
        self.idx.iter().any(Option::is_some)
    }

    /// Writes this frame's gaze weights into `weights`; `head` is the frame's head
    /// rotation `(pitch, yaw)` when it has a pose.
    fn apply(&mut self, iris: Option<&IrisFrame>, head: Option<(f64, f64)>, weights: &mut [f64]) {
        if !self.active() {
            return;
        }
        let Some(iris) = iris else { return };
        if !self.rest_from_clip && self.seen.len() < RUNNING_REST_SEEN_MAX {
            // streaming: the running median of the frames so far stands in for the clip's
            self.seen.push(*iris);
            if let Some(h) = head {
                self.seen_head.push(h);
            }
            if running_rest_due(self.seen.len(), self.rest.is_some()) {
                self.rest = GazeRest::towards_straight_ahead(&self.seen);
                self.rest_head = median_head(&self.seen_head);
            }
        }
        let Some(rest) = self.rest else { return };
        let turn = match (head, self.rest_head) {
            (Some(h), Some(r)) => HeadTurn {
                pitch: h.0 - r.0,
                yaw: h.1 - r.1,
            },
            _ => HeadTurn::default(),
        };
        let g = facecap_landmarks::gaze::gaze_weights_in_head(iris, &rest, &GazeGains::default(), turn);
        for (slot, v) in self.idx.iter().zip(g) {
            if let Some(k) = slot {
                weights[*k] = v;
            }
        }
    }
}

impl std::fmt::Debug for ExpressionSink<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExpressionSink")
            .field("method", &self.setup.method)
            .field("camera", &self.camera)
            .field("calibration", &self.calibration.is_some())
            .field("frames", &self.result.frames.len())
            .finish()
    }
}

impl<'a> ExpressionSink<'a> {
    /// Starts `weights.csv` and `pose.csv` in `out_dir`. `camera` is needed by `exact3d`
    /// and by the PnP pose beside the 2D solvers (without one, their pose is NaN).
    /// With `calibration`, frames are buffered and solved after the last one.
    /// `sheet` says which frames' images to keep for a contact sheet.
    ///
    /// # Errors
    /// `exact3d` without a camera, invalid solver parameters, or file creation.
    pub fn create(
        out_dir: &Path,
        setup: &'a ExpressionSetup,
        camera: Option<Intrinsics>,
        calibration: Option<&'a dyn NeutralCalibration>,
        sheet: FrameImages,
    ) -> Result<Self> {
        Self::create_inner(Some(out_dir), setup, camera, calibration, sheet)
    }

    fn create_inner(
        out_dir: Option<&Path>,
        setup: &'a ExpressionSetup,
        camera: Option<Intrinsics>,
        calibration: Option<&'a dyn NeutralCalibration>,
        sheet: FrameImages,
    ) -> Result<Self> {
        if setup.method == Method::Exact3d && camera.is_none() {
            return Err(Error::invalid(
                "camera",
                "none",
                "a camera for the exact3d solver (frame size or fx,fy,cx,cy)",
            ));
        }
        let solving = match calibration {
            None => Some(Solving::new(
                build_expression_solve(setup, solver_camera(camera)?, None)?.0,
            )),
            Some(_) => None,
        };
        let names = setup.rig.names.clone();
        Ok(ExpressionSink {
            setup,
            camera,
            calibration,
            sheet_policy: sheet,
            solving,
            buffered: Vec::new(),
            pose_csv: match out_dir {
                Some(d) => Some(FrameCsvWriter::create(d.join("pose.csv"), &POSE_COLUMNS)?),
                None => None,
            },
            w_csv: match out_dir {
                Some(d) => Some(FrameCsvWriter::create(d.join("weights.csv"), &names)?),
                None => None,
            },
            result: ExpressionResult {
                names,
                frames: Vec::new(),
                sheet: Vec::new(),
                faces_found: 0,
                neutral_report: serde_json::Value::Null,
                failures: Vec::new(),
                dense_frames: 0,
                companion: serde_json::Value::Null,
            },
            pnp_model: Vec::with_capacity(NUM_LANDMARKS),
            pnp_image: Vec::with_capacity(NUM_LANDMARKS),
            prev_solver_weights: vec![0.0; setup.rig.names.len()],
            prev_pose: None,
            gaze: Gaze::new(&setup.rig.names),
            blink_idx: BlinkShape::of_rig(&setup.rig.names),
            shrug_idx: rolled_lip_shapes(&setup.rig.names),
            lips: crate::lips::Lips::new(
                ["mouthRollLower", "mouthRollUpper", "mouthShrugLower"].map(|n| shape_index(&setup.rig.names, n, None)),
            ),
            live: None,
            companion: None,
        })
    }

    /// Also solves every frame with a second rig (`setup`, named `label`, calibrated by `calibration`)
    /// and writes, for each shape both rigs solve ([`shared_solved_shapes`]), the mean of
    /// the two rigs' weights; the pose, the reprojection error and every other shape are
    /// this rig's. Two rigs with ARKit's names are two models of how the same expressions
    /// move the landmarks; where one rig's shapes are nearly collinear on the landmarks
    /// (ICT's `jawOpen` and `mouthShrugLower`, cos -0.97) the other's are not, and their
    /// errors are partly independent: on the shared clips the ICT rig with the built-in
    /// rig as companion follows MediaPipe's scores better than either alone
    /// (docs/expressions.md, "The built-in rig as a companion"). Used where the whole clip
    /// is solved before it is written (with a whole-clip `calibration` in [`Self::create`]).
    /// Without one, or with fewer than [`MIN_COMPANION_SHAPES`] shared shapes, the
    /// companion is skipped and [`ExpressionResult::companion`] says why.
    ///
    /// # Errors
    /// What [`Self::create`] fails with.
    pub fn with_companion(
        mut self,
        label: &str,
        setup: &'a ExpressionSetup,
        calibration: &'a dyn NeutralCalibration,
    ) -> Result<Self> {
        let pairs = shared_solved_shapes(self.setup, setup);
        let skipped = if self.calibration.is_none() {
            Some("no whole-clip neutral calibration (--neutral none)".to_string())
        } else if pairs.len() < MIN_COMPANION_SHAPES {
            Some(format!(
                "the rig shares {} solved shapes with the {label} (by ARKit name); at least \
                 {MIN_COMPANION_SHAPES} are needed",
                pairs.len()
            ))
        } else {
            None
        };
        if let Some(why) = skipped {
            self.result.companion = serde_json::json!({ "skipped": why });
            return Ok(self);
        }
        let sink = Self::create_inner(None, setup, self.camera, Some(calibration), FrameImages::None)?;
        self.companion = Some(Companion {
            sink: Box::new(sink),
            calibration,
            pairs,
            label: label.to_string(),
        });
        Ok(self)
    }

    /// Calibrates the subject's neutral while frames stream (live input): frames are
    /// solved at once with the generic rig; once the window of [`LiveNeutral`] is full,
    /// `cal` fits the neutral on it and the following frames are solved with the
    /// calibrated rig; setting [`LiveNeutral::redo`] takes it again. The fit runs on its
    /// own thread, so no frame waits for it: frames are solved with the previous rig
    /// until it is done. Use with a sink created without a `calibration` (which would
    /// wait for the whole clip).
    ///
    /// # Errors
    /// A negative or non-finite `after`, a `window` that is not > 0, or a sink created
    /// with a whole-clip calibration.
    pub fn with_live_neutral(mut self, cal: Arc<dyn NeutralCalibration>, params: LiveNeutral) -> Result<Self> {
        if !(params.after.is_finite() && params.after >= 0.0) {
            return Err(Error::invalid(
                "neutral after (s)",
                params.after,
                "a finite number >= 0",
            ));
        }
        if !(params.window.is_finite() && params.window > 0.0) {
            return Err(Error::invalid(
                "neutral window (s)",
                params.window,
                "a finite number > 0",
            ));
        }
        if self.calibration.is_some() {
            return Err(Error::invalid(
                "calibration",
                "whole clip",
                "no whole-clip calibration together with a live one",
            ));
        }
        self.live = Some(LiveNeutralState {
            cal,
            params,
            start: None,
            frames: Vec::new(),
            collecting: true,
            taken: 0,
            pending: None,
        });
        Ok(self)
    }

    /// The last frame solved (each call of [`Sink::frame`] solves its frame at once
    /// unless a whole-clip calibration buffers them).
    pub fn last_frame(&self) -> Option<&SolvedFrame> {
        self.result.frames.last()
    }

    /// The blendshape names (rig order).
    pub fn names(&self) -> &[String] {
        &self.result.names
    }

    /// The neutral calibrations so far (`null`, or a list for live calibrations).
    pub fn neutral_report(&self) -> &serde_json::Value {
        &self.result.neutral_report
    }

    /// How many live neutral calibrations were applied so far.
    pub fn live_neutrals_taken(&self) -> u32 {
        match &self.result.neutral_report {
            serde_json::Value::Array(a) => a.iter().filter(|e| e.get("report").is_some()).count() as u32,
            _ => 0,
        }
    }

    /// Collects the live neutral window, starts the fit when it is full, and returns the
    /// calibrated solver once the fit is done. A failed fit is reported in
    /// `neutral_report` and the run goes on with the rig it had.
    fn live_neutral(&mut self, face: &TrackedFace) -> Result<Option<Solving>> {
        let camera = solver_camera(self.camera)?;
        let Some(live) = self.live.as_mut() else {
            return Ok(None);
        };
        if let Some(((taken, first, last, n), rx)) = &live.pending {
            let outcome = match rx.try_recv() {
                Err(std::sync::mpsc::TryRecvError::Empty) => return Ok(None),
                Err(std::sync::mpsc::TryRecvError::Disconnected) => Err("the calibration thread stopped".to_string()),
                Ok(r) => r.map_err(|e| e.to_string()),
            };
            let mut entry = serde_json::json!({
                "calibration": taken, "first_frame": first, "last_frame": last, "frames": n,
                "applied_from_frame": face.index,
            });
            let solver = match outcome {
                Ok((solver, report)) => {
                    entry["report"] = report;
                    Some(Solving::new(solver))
                }
                Err(e) => {
                    entry["error"] = serde_json::json!(e);
                    None
                }
            };
            live.pending = None;
            match &mut self.result.neutral_report {
                serde_json::Value::Array(a) => a.push(entry),
                other => *other = serde_json::Value::Array(vec![entry]),
            }
            return Ok(solver);
        }
        if live.params.redo.swap(false, std::sync::atomic::Ordering::SeqCst) {
            live.collecting = true;
            live.start = Some(face.timestamp - live.params.after);
            live.frames.clear();
        }
        if !live.collecting {
            return Ok(None);
        }
        let Some(l) = &face.landmarks else { return Ok(None) };
        let start = *live.start.get_or_insert(face.timestamp);
        let t = face.timestamp - start;
        if t < live.params.after {
            return Ok(None);
        }
        live.frames.push((face.index, l.clone()));
        if t < live.params.after + live.params.window || live.frames.len() < LIVE_NEUTRAL_MIN_FRAMES {
            return Ok(None);
        }
        let frames = std::mem::take(&mut live.frames);
        live.collecting = false;
        live.taken += 1;
        let key = (
            live.taken,
            frames.first().map_or(0, |f| f.0),
            frames.last().map_or(0, |f| f.0),
            frames.len(),
        );
        let (tx, rx) = std::sync::mpsc::channel();
        let (cal, setup) = (live.cal.clone(), self.setup.clone());
        std::thread::Builder::new()
            .name("facecap-live-neutral".into())
            .spawn(move || {
                let _ = tx.send(build_expression_solve(&setup, camera, Some((cal.as_ref(), &frames))));
            })
            .map_err(|e| Error::invalid("neutral calibration thread", e, "a thread the system can start"))?;
        live.pending = Some((key, rx));
        Ok(None)
    }

    /// Commits both CSVs and returns the solved frames.
    ///
    /// # Errors
    /// When a file cannot be written or renamed.
    pub fn finish(self) -> Result<ExpressionResult> {
        if let Some(c) = self.pose_csv {
            c.finish()?;
        }
        if let Some(c) = self.w_csv {
            c.finish()?;
        }
        Ok(self.result)
    }

    fn solve_one(&mut self, sv: &mut Solving, face: &TrackedFace) -> Result<()> {
        let mut out = self.solve_frame(sv, face);
        if out.success {
            self.conventions(&mut out, face.iris.as_ref());
        }
        self.write_frame(out, face)
    }

    /// The weights of a solved frame that are not the solve's alone: the gaze shapes from
    /// the irises (the eyes' turn in the head), then `eyeBlink*` after the gain and the
    /// iris damping, what a closing lid drives, the lips' lost red on their roll shapes
    /// ([`crate::lips`]), the chin raiser with the rolled lower lip ([`rolled_lip_shrug`])
    /// and the chin's rise.
    fn conventions(&mut self, out: &mut SolvedFrame, iris: Option<&IrisFrame>) {
        let chin = self.lips.add_rolls(out.landmarks.as_ref(), &mut out.weights);
        self.gaze.apply(iris, head_of(out.pose.as_ref()), &mut out.weights);
        for b in &self.blink_idx {
            let c = iris.map_or(0.0, |i| match b.side {
                Some('L') => i.left.confidence,
                Some('R') => i.right.confidence,
                _ => 0.5 * (i.left.confidence + i.right.confidence),
            });
            out.weights[b.blink] = blink_weight(out.weights[b.blink], c);
            b.drive_closed_eye(&mut out.weights);
        }
        if let Some((shrug, roll)) = self.shrug_idx {
            out.weights[shrug] = rolled_lip_shrug(out.weights[shrug], out.weights[roll]);
        }
        self.lips.add_chin(chin, &mut out.weights);
    }

    /// Solves one frame (weights, pose; failures recorded), writing nothing. The gaze, eye and lip
    /// weights are the caller's ([`ExpressionSink::conventions`]).
    fn solve_frame(&mut self, sv: &mut Solving, face: &TrackedFace) -> SolvedFrame {
        let Solving {
            solver,
            ws,
            state,
            solution,
        } = sv;
        let prev_pose = self.prev_pose;
        let prev_weights = self.prev_solver_weights.clone();
        let mut out = SolvedFrame {
            index: face.index,
            timestamp: face.timestamp,
            success: false,
            confidence: face.confidence,
            landmarks: face.landmarks.clone(),
            weights: prev_weights,
            pose: None,
            reprojection_px: f64::NAN,
        };
        if let Some(l) = &face.landmarks {
            self.result.faces_found += 1;
            let solved = solver
                .solve_dense_into(l, face.mesh.as_deref(), ws, state, &mut *solution)
                .map_err(|e| e.to_string())
                .and_then(|_| implausible_solve(l, solution.reprojection_error(l), solution.pose.as_ref()));
            match solved {
                Ok(()) => {
                    out.success = true;
                    if self.setup.dense.is_some() && face.mesh.is_some() {
                        self.result.dense_frames += 1;
                    }
                    out.weights.copy_from_slice(&solution.weights);
                    out.pose = match solution.pose {
                        Some(p) => Some(p),
                        None => self.pnp_pose(&solution.weights, l, prev_pose),
                    };
                    self.prev_solver_weights.copy_from_slice(&solution.weights);
                    out.reprojection_px = solution.reprojection_error(l);
                }
                Err(e) => {
                    self.result.failures.push((face.index, e));
                    state.reset();
                }
            }
        } else {
            state.reset();
        }
        self.prev_pose = out.pose;
        out
    }

    /// Writes a solved frame's `pose.csv` and `weights.csv` rows and keeps it.
    fn write_frame(&mut self, out: SolvedFrame, face: &TrackedFace) -> Result<()> {
        let n = out.weights.len();
        let pose_values = pose_row(out.pose.as_ref());
        let (Some(pose_csv), Some(w_csv)) = (self.pose_csv.as_mut(), self.w_csv.as_mut()) else {
            self.result.frames.push(out);
            return Ok(());
        };
        pose_csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success: out.success && out.pose.is_some(),
            confidence: face.confidence,
            values: &pose_values,
        })?;
        let nan = [f64::NAN];
        let values: Vec<f64> = if out.success {
            out.weights.clone()
        } else {
            nan.iter().copied().cycle().take(n).collect()
        };
        w_csv.write_row(&FrameRow {
            frame: face.index,
            timestamp: face.timestamp,
            success: out.success,
            confidence: face.confidence,
            values: &values,
        })?;
        if let Some(g) = &face.gray {
            self.result.sheet.push((self.result.frames.len(), g.clone()));
        }
        self.result.frames.push(out);
        Ok(())
    }

    /// PnP pose of the rig's landmarks posed with `weights` (2D solvers).
    fn pnp_pose(&mut self, weights: &[f64], l: &Landmarks68, prev: Option<ModelToCamera>) -> Option<ModelToCamera> {
        let camera = self.camera?;
        let rig = &self.setup.rig;
        self.pnp_model.clear();
        self.pnp_image.clear();
        for i in 0..NUM_LANDMARKS {
            if !rig.mapped[i] {
                continue;
            }
            let mut p = [rig.neutral[[i, 0]], rig.neutral[[i, 1]], rig.neutral[[i, 2]]];
            for (k, w) in weights.iter().enumerate() {
                for (c, v) in p.iter_mut().enumerate() {
                    *v += w * rig.deltas[[k, i, c]];
                }
            }
            self.pnp_model.push(Point3::new(p[0], p[1], p[2]));
            self.pnp_image.push(l.points[i]);
        }
        solve_pnp(&self.pnp_model, &self.pnp_image, &camera, prev, &PnpParams::default())
            .ok()
            .map(|(p, _)| p)
    }
}

/// A solver with its workspace and warm-start state.
#[derive(Debug)]
struct Solving {
    solver: AnySolver,
    ws: <AnySolver as ExpressionSolver>::Workspace,
    state: SolveState,
    solution: Solution,
}

impl Solving {
    fn new(solver: AnySolver) -> Self {
        let n = solver.num_shapes();
        Solving {
            ws: solver.workspace(),
            state: SolveState::new(n),
            solution: Solution::new(n),
            solver,
        }
    }
}

/// Fewest frames [`calibrate_dense`] takes the dense points' neutral from.
pub const DENSE_NEUTRAL_MIN_FRAMES: usize = 5;

/// The subject's neutral at the dense points of a calibrated 3D solver: each frame of
/// `faces` with landmarks and a mesh is solved on the landmarks alone (warm-started), and
/// each dense point's model-space offset onto its observation
/// ([`facecap_solve::Exact3dSolver::dense_offsets`]) is collected; the per-coordinate
/// median over the clip is added to the point's neutral. The 68 landmarks get the
/// subject's neutral from the calibration; this gives it to the dense points, which the
/// generic map onto the rig cannot (the median keeps what stays put over the clip: the
/// subject's shape, not the expressions). Returns a JSON report (`null` without dense
/// points).
pub fn calibrate_dense(solver: &mut AnySolver, faces: &[TrackedFace]) -> serde_json::Value {
    let AnySolver::Exact3d(s) = solver else {
        return serde_json::Value::Null;
    };
    let m = s.num_dense();
    if m == 0 {
        return serde_json::Value::Null;
    }
    let n = s.num_shapes();
    let mut ws = s.workspace();
    let mut state = SolveState::new(n);
    let mut sol = Solution::new(n);
    let mut per_point: Vec<[Vec<f64>; 3]> = vec![Default::default(); m];
    let mut used = 0usize;
    for f in faces {
        let (Some(l), Some(mesh)) = (&f.landmarks, &f.mesh) else {
            state.reset();
            continue;
        };
        if s.solve_into(l, &mut ws, &mut state, &mut sol).is_err() {
            state.reset();
            continue;
        }
        let Some(pose) = sol.pose else { continue };
        if let Some(off) = s.dense_offsets(mesh, &sol.weights, &pose) {
            for (acc, o) in per_point.iter_mut().zip(&off) {
                for c in 0..3 {
                    acc[c].push(o[c]);
                }
            }
            used += 1;
        }
    }
    if used < DENSE_NEUTRAL_MIN_FRAMES {
        return serde_json::json!({"mode": "skipped", "frames": used});
    }
    let median = |v: &mut Vec<f64>| -> f64 {
        v.sort_by(f64::total_cmp);
        let k = v.len() / 2;
        if v.len() % 2 == 1 {
            v[k]
        } else {
            0.5 * (v[k - 1] + v[k])
        }
    };
    let offsets: Vec<nalgebra::Vector3<f64>> = per_point
        .iter_mut()
        .map(|[x, y, z]| nalgebra::Vector3::new(median(x), median(y), median(z)))
        .collect();
    s.shift_dense(&offsets);
    let mean = offsets.iter().map(|o| o.norm()).sum::<f64>() / m as f64;
    serde_json::json!({
        "mode": "median offset over the clip after the landmarks' solve",
        "points": m,
        "frames": used,
        "mean_offset_rig_units": mean,
    })
}

/// The camera handed to the solver: the real one, or (2D solvers only, which do not
/// use it) a unit camera.
fn solver_camera(camera: Option<Intrinsics>) -> Result<Intrinsics> {
    match camera {
        Some(c) => Ok(c),
        None => Ok(Intrinsics::new(1.0, 1.0, 0.0, 0.0)?),
    }
}

impl ExpressionSink<'_> {
    /// Calibrates on every tracked frame of `faces`, then solves each (not smoothed).
    fn solve_clip(
        &mut self,
        cal: &dyn NeutralCalibration,
        faces: &[TrackedFace],
    ) -> Result<(Vec<SolvedFrame>, Solving)> {
        let tracked: Vec<(u64, Landmarks68)> = faces
            .iter()
            .filter_map(|t| t.landmarks.clone().map(|l| (t.index, l)))
            .collect();
        let (mut solver, mut report) =
            build_expression_solve(self.setup, solver_camera(self.camera)?, Some((cal, &tracked)))?;
        let dense = calibrate_dense(&mut solver, faces);
        if let (serde_json::Value::Object(o), false) = (&mut report, dense.is_null()) {
            o.insert("dense".into(), dense);
        }
        self.result.neutral_report = report;
        let irises: Vec<IrisFrame> = faces.iter().filter_map(|t| t.iris).collect();
        self.gaze.rest = GazeRest::towards_straight_ahead(&irises);
        self.gaze.rest_from_clip = self.gaze.rest.is_some();
        self.lips.rest_from(tracked.iter().map(|(_, l)| l));
        let mut sv = Solving::new(solver);
        // every frame's pose first: the resting head is the clip's median, as the gaze's
        let mut solved: Vec<SolvedFrame> = faces.iter().map(|face| self.solve_frame(&mut sv, face)).collect();
        let heads: Vec<(f64, f64)> = solved
            .iter()
            .filter(|f| f.success)
            .filter_map(|f| head_of(f.pose.as_ref()))
            .collect();
        self.gaze.rest_head = median_head(&heads);
        for (out, face) in solved.iter_mut().zip(faces) {
            if out.success {
                self.conventions(out, face.iris.as_ref());
            }
        }
        Ok((solved, sv))
    }
}

/// Replaces each paired shape's weight of `frames` by the mean of it and `other`'s
/// (`pairs`: index in `frames`, index in `other`), on the frames both solved. Returns how
/// many frames were averaged.
pub(crate) fn average_shared(frames: &mut [SolvedFrame], other: &[SolvedFrame], pairs: &[(usize, usize)]) -> u64 {
    let mut n = 0;
    for (f, o) in frames.iter_mut().zip(other) {
        if !(f.success && o.success && f.index == o.index) {
            continue;
        }
        n += 1;
        for &(i, j) in pairs {
            if let (Some(a), Some(&b)) = (f.weights.get(i).copied(), o.weights.get(j)) {
                f.weights[i] = 0.5 * (a + b);
            }
        }
    }
    n
}

impl Sink for ExpressionSink<'_> {
    fn name(&self) -> &str {
        "solve"
    }

    fn images(&self) -> FrameImages {
        self.sheet_policy
    }

    fn wants_iris(&self) -> bool {
        // the gaze shapes, and the iris damping of eyeBlink
        self.gaze.active() || !self.blink_idx.is_empty()
    }

    fn wants_mesh(&self) -> bool {
        self.setup.dense.is_some()
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        match self.solving.take() {
            Some(mut sv) => {
                let r = self.solve_one(&mut sv, face);
                let calibrated = match r {
                    Ok(()) => self.live_neutral(face),
                    Err(e) => Err(e),
                };
                self.solving = Some(sv);
                if let Some(new) = calibrated? {
                    self.solving = Some(new);
                }
                Ok(())
            }
            None => {
                self.buffered.push(face.clone());
                Ok(())
            }
        }
    }

    fn end(&mut self) -> Result<()> {
        let Some(cal) = self.calibration else { return Ok(()) };
        if self.solving.is_some() {
            return Ok(());
        }
        let faces = std::mem::take(&mut self.buffered);
        let (mut solved, sv) = self.solve_clip(cal, &faces)?;
        if let Some(c) = self.companion.as_mut() {
            let (other, _) = c.sink.solve_clip(c.calibration, &faces)?;
            let averaged = average_shared(&mut solved, &other, &c.pairs);
            let names: Vec<&str> = c.pairs.iter().map(|&(i, _)| self.result.names[i].as_str()).collect();
            self.result.companion = serde_json::json!({
                "rig": c.label,
                "shapes_averaged": names,
                "frames_averaged": averaged,
                "neutral_calibration": c.sink.result.neutral_report,
            });
        }
        // the whole clip is known: every frame is solved first, then smoothed without lag
        smooth_weights(&mut solved);
        for (out, face) in solved.into_iter().zip(&faces) {
            self.write_frame(out, face)?;
        }
        self.solving = Some(sv);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames_of(values: &[f64], failed: &[usize]) -> Vec<SolvedFrame> {
        values
            .iter()
            .enumerate()
            .map(|(i, &v)| SolvedFrame {
                index: i as u64,
                timestamp: i as f64 / 30.0,
                success: !failed.contains(&i),
                confidence: 1.0,
                landmarks: None,
                weights: vec![v, 0.5],
                pose: None,
                reprojection_px: 0.0,
            })
            .collect()
    }

    #[test]
    fn smoothing_drops_one_frame_outliers_keeps_blinks_and_does_not_delay_them() {
        // a blink (frames 5-9) whose eye reads open for one frame (7), and a one-frame spike
        // at rest (frame 14)
        let v = [
            0.0, 0.0, 0.0, 0.0, 0.0, 0.9, 1.0, 0.0, 1.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.6, 0.0, 0.0,
        ];
        let mut f = frames_of(&v, &[]);
        smooth_weights(&mut f);
        let w: Vec<f64> = f.iter().map(|x| x.weights[0]).collect();
        assert!(w[7] > 0.7, "the dip inside the blink is gone: {w:?}");
        assert!(w[14] < 0.01, "the spike at rest is gone: {w:?}");
        // symmetric: the blink's half-height crossings stay where they were (5 and 9)
        assert!(w[4] < 0.5 && w[5] >= 0.5 && w[9] >= 0.5 && w[10] < 0.5, "{w:?}");
        // a constant shape stays constant, to the last bit
        assert!(f.iter().all(|x| x.weights[1] == 0.5));
        // a two-frame blink keeps its peak above 0.5
        let mut f = frames_of(&[0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0], &[]);
        smooth_weights(&mut f);
        assert!(f[3].weights[0] >= 0.5 && f[4].weights[0] >= 0.5, "{:?}", f);
    }

    #[test]
    fn smoothing_never_crosses_a_failed_frame_nor_reads_one() {
        // frame 3 failed (it repeats the previous weights); frames 0-2 and 4-6 are runs
        let mut f = frames_of(&[0.0, 0.0, 0.0, 9.0, 1.0, 1.0, 1.0], &[3]);
        smooth_weights(&mut f);
        let w: Vec<f64> = f.iter().map(|x| x.weights[0]).collect();
        assert_eq!(w, vec![0.0, 0.0, 0.0, 9.0, 1.0, 1.0, 1.0]);
        // runs shorter than three frames are left alone; non-finite columns too
        let mut f = frames_of(&[0.2, 0.8, 0.0, 0.3], &[2]);
        f[0].weights[1] = f64::NAN;
        smooth_weights(&mut f);
        assert_eq!(f[1].weights[0], 0.8);
        assert!(f[0].weights[1].is_nan() && f[1].weights[1] == 0.5);
        smooth_weights(&mut []);
    }

    #[test]
    fn blink_weight_is_damped_only_where_the_iris_is_plainly_visible() {
        // no estimate or a closed eye: the gain alone
        assert!((blink_weight(0.3, 0.0) - 0.3 * BLINK_GAIN).abs() < 1e-12);
        assert_eq!(blink_weight(0.3, BLINK_IRIS_FROM), blink_weight(0.3, 0.0));
        assert_eq!(blink_weight(0.3, f64::NAN), blink_weight(0.3, 0.0));
        // a glance: half a blink in the solve, iris in full view -> well below 0.5
        assert!(blink_weight(0.3, 1.0) < 0.2);
        // a closed eye stays closed, and the result is a weight
        assert_eq!(blink_weight(0.9, 0.0), 1.0);
        assert_eq!(blink_weight(-0.1, 0.0), 0.0);
        assert_eq!(blink_weight(f64::NAN, 0.2), 0.0);
        // more iris, less blink
        assert!(blink_weight(0.4, 0.9) < blink_weight(0.4, 0.7));
    }

    #[test]
    fn a_rolled_lower_lip_raises_the_chin_raiser() {
        // half the roll is added, clamped to a weight
        assert!((rolled_lip_shrug(0.1, 0.6) - (0.1 + ROLLED_LIP_SHRUG * 0.6)).abs() < 1e-12);
        assert_eq!(rolled_lip_shrug(0.2, 0.0), 0.2);
        assert_eq!(rolled_lip_shrug(0.9, 1.0), 1.0);
        assert_eq!(rolled_lip_shrug(-0.2, -0.5), 0.0);
        assert_eq!(rolled_lip_shrug(f64::NAN, 0.4), ROLLED_LIP_SHRUG * 0.4);
        assert_eq!(rolled_lip_shrug(0.3, f64::INFINITY), 0.3);
        // found by name in ARKit's and ICT's spelling (neither has a side)
        for names in [
            ["jawOpen", "mouthRollLower", "mouthShrugLower"],
            ["mouthShrugLower", "eyeBlink_L", "mouthRollLower"],
        ] {
            let names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
            let (shrug, roll) = rolled_lip_shapes(&names).unwrap();
            assert!(names[shrug] == "mouthShrugLower" && names[roll] == "mouthRollLower");
        }
        let no_roll: Vec<String> = ["mouthShrugLower", "jawOpen"].iter().map(|s| s.to_string()).collect();
        assert_eq!(rolled_lip_shapes(&no_roll), None);
    }

    #[test]
    fn a_closing_lid_drives_look_down_and_squint_of_its_own_side_only() {
        let names: Vec<String> = [
            "eyeBlinkLeft",
            "eyeBlinkRight",
            "eyeLookDownLeft",
            "eyeLookDownRight",
            "eyeSquintLeft",
            "eyeSquintRight",
            "jawOpen",
            "eyeLookInLeft",
            "eyeLookOutRight",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let sides = BlinkShape::of_rig(&names);
        assert_eq!(sides.len(), 2);
        // left eye closed, right eye open and looking down and out
        let mut w = vec![1.0, 0.0, 0.0, 0.6, 0.1, 0.2, 0.7, 0.5, 0.5];
        for b in &sides {
            b.drive_closed_eye(&mut w);
        }
        let want = [
            1.0,
            0.0,
            CLOSED_EYE_LOOK_DOWN,
            0.6,
            0.1 + CLOSED_EYE_SQUINT,
            0.2,
            0.7,
            0.0,
            0.5,
        ];
        for (got, want) in w.iter().zip(want) {
            assert!((got - want).abs() < 1e-12, "{w:?}");
        }
        // ICT's names, and a rig without the driven shapes
        let ict: Vec<String> = ["eyeBlink_L", "eyeSquint_L"].iter().map(|s| s.to_string()).collect();
        let s = BlinkShape::of_rig(&ict);
        assert_eq!((s[0].look_down, s[0].squint), (None, Some(1)));
        // weights stay weights
        assert_eq!(closed_eye_weights(1.0, f64::NAN, 0.95), (CLOSED_EYE_LOOK_DOWN, 1.0));
        assert_eq!(closed_eye_weights(f64::INFINITY, 0.2, -1.0), (0.2, 0.0));
        assert!((closed_eye_sideways(0.25, 0.4) - 0.3).abs() < 1e-12);
        assert_eq!(closed_eye_sideways(f64::NAN, 0.4), 0.4);
        assert_eq!(closed_eye_sideways(0.5, f64::NAN), 0.0);
    }

    fn setup_named(names: &[&str], fixed: &[usize]) -> ExpressionSetup {
        let mut rig = BlendshapeRig::synthetic(names.len(), 3);
        rig.names = names.iter().map(|n| n.to_string()).collect();
        let mut priors = ShapePriors::neutral(names.len());
        for &k in fixed {
            priors.fixed[k] = true;
        }
        ExpressionSetup {
            rig,
            method: Method::Exact3d,
            objective: ObjectiveParams::default(),
            priors: Some(priors),
            dense: None,
        }
    }

    #[test]
    fn companion_shapes_match_by_arkit_name_and_only_where_both_rigs_solve_them() {
        // ICT-style and ARKit-style names; cheekSquint held at 0 by the companion,
        // eyeLookUp by both; mouthLeft is a direction, not a side
        let a = setup_named(
            &[
                "eyeBlink_L",
                "eyeBlink_R",
                "cheekSquint_L",
                "mouthLeft",
                "eyeLookUp_L",
                "tongueOut",
                "browInnerUp_R",
            ],
            &[4],
        );
        let b = setup_named(
            &[
                "mouthLeft",
                "eyeBlinkRight",
                "eyeBlinkLeft",
                "cheekSquintLeft",
                "eyeLookUpLeft",
                "browInnerUp",
            ],
            &[3, 4],
        );
        assert_eq!(shared_solved_shapes(&a, &b), vec![(0, 2), (1, 1), (3, 0), (6, 5)]);
    }

    #[test]
    fn a_companion_averages_paired_shapes_on_frames_both_rigs_solved() {
        let mut a = frames_of(&[0.2, 0.4, 0.6], &[]);
        let mut b = frames_of(&[0.6, 0.0, 1.0], &[1]);
        for f in &mut b {
            f.weights.swap(0, 1); // the companion's order differs: shape 0 is its index 1
        }
        let n = average_shared(&mut a, &b, &[(0, 1)]);
        assert_eq!(n, 2);
        let got: Vec<f64> = a.iter().map(|f| f.weights[0]).collect();
        // frame 1: the companion failed, this rig's weight stays
        assert!((got[0] - 0.4).abs() < 1e-12 && (got[1] - 0.4).abs() < 1e-12 && (got[2] - 0.8).abs() < 1e-12);
        // the unpaired shape stays this rig's
        assert!(a.iter().all(|f| f.weights[1] == 0.5));
        // a failed frame of this rig stays failed and untouched
        let mut c = frames_of(&[0.2], &[0]);
        assert_eq!(average_shared(&mut c, &frames_of(&[1.0], &[]), &[(0, 0)]), 0);
        assert_eq!(c[0].weights[0], 0.2);
    }
}
