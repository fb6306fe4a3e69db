//! Video landmark tracker: 68 landmarks per frame from a face detector, an ERT
//! shape regressor and pyramidal LK.
//!
//! # Per-frame logic
//!
//! 1. The previous frame is kept (one copy per frame into a reused buffer); LK
//!    pyramids are built only on frames where LK runs (step 3b), reusing the
//!    previous frame's pyramid when the previous frame ran LK too.
//! 2. **Not tracking** (first frame, or the face was lost): run the detector, take
//!    the largest face, run ERT from the mean shape in that box.
//! 3. **Tracking** (no detector):
//!    - *Cheap motion test*: one Gauss-Newton step of translation-only LK over the
//!      previous landmarks' bounding box (+10 %) on a 4-px grid, with
//!      central-difference gradients of the previous frame, `d = -G⁻¹ b`
//!      (`G = Σ ∇I ∇Iᵀ`, `b = Σ (J - I) ∇I`), plus the RMS of the grey-level
//!      change this translation leaves unexplained. About 0.4 M instructions per
//!      frame, against ~5 M for the two pyramids + LK on 21 points.
//!    - If `lk_motion_threshold < |d| <= translate_max` and the unexplained RMS is
//!      at most `lk_residual_threshold` grey levels, the previous shape moves by `d`
//!      (a small shift; no LK). If `|d| > translate_max` or the unexplained RMS
//!      exceeds `lk_residual_threshold` (not a small shift: a cut, a flat frame, a
//!      fast motion), LK carries
//!      the 21 rigid landmarks (nose 27-35, eyes 36-47) to this frame. If fewer than
//!      `min_lk_fraction` of them are tracked the face is lost and we fall back to
//!      step 2. When their median LK motion exceeds `lk_motion_threshold` px, the
//!      least-squares similarity from their previous to their LK positions moves
//!      all 68 previous landmarks ("LK carries the face"); else the previous shape
//!      is used as is. Otherwise (small motion) LK does not run and the previous
//!      shape is used as is.
//!    - The ERT box is derived from this initial shape by the **dlib-like box
//!      rule**: the square box in which the ERT mean shape best fits the shape
//!      (least squares over `l`, `t` and one scale `s` in `x ≈ l + s·u`,
//!      `y ≈ t + s·v`, `(u, v)` the mean shape in box units) — i.e. the box the
//!      detector would have had to give for the face to sit like the mean face.
//!      ERT then runs from the mean shape in that box ([`ErtInit::MeanShapeInBox`],
//!      default: dlib's initialisation with a tracked box) or from the carried
//!      shape itself ([`ErtInit::PreviousShape`], which drifts).
//! 4. **Confidence** in `[0, 1]`: `lk_fraction · exp(-d_agree / agree_scale) ·
//!    exp(-max(0, r_shape - shape_tolerance) / shape_scale)`, where `d_agree` is the
//!    mean distance between ERT's and LK's positions of the LK-tracked points
//!    (`lk_fraction = 1`, `d_agree = 0` on frames where LK did not run) and
//!    `r_shape` the RMS residual of the rigid points (nose 27-35, eyes 36-47) after
//!    similarity-aligning them to the mean shape, both divided by the inter-ocular distance. A frame from the detector
//!    has `lk_fraction = 1` and no agreement term. When the confidence is below
//!    `redetect_below`, the detector runs on the same frame and, if it finds a face,
//!    its result replaces the tracked one. `success = confidence >= min_confidence`;
//!    a failed frame stops tracking (the next frame detects).
//! 5. Optional temporal filtering of the output coordinates with the One Euro filter
//!    ([`one_euro`]); the filter restarts whenever the detector (re)starts the track.
//!
//! Coordinates are 0-based pixel centres (top-left pixel centre is `(0, 0)`).
//!
//! # Parameters ([`TrackerParams`])
//!
//! | name | default | meaning | range |
//! |---|---|---|---|
//! | `lk` | window 21, 3 levels | LK parameters | see [`crate::lk`] |
//! | `min_lk_fraction` | 0.5 | fraction of the 21 LK points LK must track to keep tracking | 0..=1 |
//! | `lk_motion_threshold` | 1.0 px | motion-test shift above which the shape is moved (by the translation or by LK), and median LK motion above which LK's similarity moves it | >= 0 |
//! | `lk_residual_threshold` | 25 grey levels | unexplained RMS change above which LK runs whatever the shift | >= 0 |
//! | `translate_max` | 3.0 px | motion-test shifts up to this (with a small residual) move the shape by the estimated translation, without LK | >= 0 |
//! | `ert_init` | `MeanShapeInBox` | how ERT is started on tracked frames | - |
//! | `agree_scale` | 0.1 | ERT/LK disagreement (÷ inter-ocular) that costs a factor e | > 0 |
//! | `shape_tolerance` | 0.05 | rigid-point shape residual (÷ inter-ocular) that costs nothing | >= 0 |
//! | `shape_scale` | 0.05 | residual beyond the tolerance that costs a factor e | > 0 |
//! | `redetect_below` | 0.35 | run the detector when confidence is below | 0..=1 |
//! | `min_confidence` | 0.2 | success threshold | 0..=1 |
//! | `redetect_interval` | 0 | also run the detector every N tracked frames (0 = never) | - |
//! | `filter` | `None` | One Euro filter parameters, `None` = off | see [`one_euro`] |
//! | `fps` | 30 | frame rate assumed when timestamps do not increase | > 0 |

pub mod backends;
pub mod one_euro;

use facecap_core::landmarks::{Landmarks68, Rect, NUM_LANDMARKS};
use facecap_geom::align::similarity2_weighted;
use image::GrayImage;
use nalgebra::Point2;

use crate::error::{Error, Result};
use crate::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use one_euro::{OneEuroParams, OneEuroState};

/// Finds faces. Implemented for [`crate::detect::FaceDetector`]; tests use mocks.
pub trait FaceFinder: Send + Sync {
    /// Reusable memory.
    type Workspace: Send + std::fmt::Debug;
    /// A fresh workspace.
    fn new_workspace(&self) -> Self::Workspace;
    /// Face boxes in `img`, written to `out` (cleared first), largest first.
    ///
    /// # Errors
    /// Whatever the detector reports.
    fn find_faces(&self, img: &GrayImage, ws: &mut Self::Workspace, out: &mut Vec<Rect>) -> Result<()>;
}

/// Regresses 68 landmarks in a face box. Implemented for [`crate::ert::ShapePredictor`].
pub trait ShapeRegressor: Send + Sync {
    /// Reusable memory.
    type Workspace: Send + std::fmt::Debug;
    /// A fresh workspace.
    fn new_workspace(&self) -> Self::Workspace;
    /// The mean shape in normalised box units, `(u, v)` per landmark, where a box
    /// `Rect { left, top, width, height }` maps `(u, v)` to
    /// `(left + (width - 1) u, top + (height - 1) v)` (dlib's convention).
    fn mean_shape(&self) -> &[f32];
    /// Landmarks from the mean shape placed in `rect`.
    ///
    /// # Errors
    /// Whatever the regressor reports.
    fn predict(&self, img: &GrayImage, rect: &Rect, ws: &mut Self::Workspace, out: &mut [Point2<f64>]) -> Result<()>;
    /// Landmarks starting from `initial` (pixels), normalised by `rect`.
    ///
    /// # Errors
    /// Whatever the regressor reports.
    fn predict_from_shape(
        &self,
        img: &GrayImage,
        rect: &Rect,
        initial: &[Point2<f64>],
        ws: &mut Self::Workspace,
        out: &mut [Point2<f64>],
    ) -> Result<()>;
}

/// How ERT starts on tracked frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ErtInit {
    /// From the previous frame's landmarks (moved by LK when motion is large).
    /// Drifts: 10 % IOD from dlib on `liveportrait_d18` (see docs/tracking.md).
    PreviousShape,
    /// From the mean shape in the box derived from the (LK-carried) previous
    /// landmarks: dlib's own initialisation with a tracked instead of a detected box.
    #[default]
    MeanShapeInBox,
}

/// Tracker parameters (see the module table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerParams {
    /// LK parameters.
    pub lk: LkParams,
    /// Minimum fraction of LK-tracked landmarks to keep tracking.
    pub min_lk_fraction: f64,
    /// Median LK motion (px) above which the shape is carried by LK.
    pub lk_motion_threshold: f64,
    /// Motion-test shifts up to this many pixels (above `lk_motion_threshold`, with
    /// a small residual) move the previous shape by the estimated translation
    /// instead of running LK; 0 = always LK above the threshold.
    pub translate_max: f64,
    /// RMS grey-level change the motion test's translation leaves unexplained above
    /// which LK runs whatever the shift (a cut, a flat frame, a motion the
    /// single linearised step cannot see). Talking faces change by 8-30 grey levels
    /// between frames without moving (mouth, eyes, compression).
    pub lk_residual_threshold: f64,
    /// ERT start on tracked frames.
    pub ert_init: ErtInit,
    /// Disagreement scale (÷ inter-ocular).
    pub agree_scale: f64,
    /// Shape residual tolerance (÷ inter-ocular).
    pub shape_tolerance: f64,
    /// Shape residual scale (÷ inter-ocular).
    pub shape_scale: f64,
    /// Re-detect below this confidence.
    pub redetect_below: f64,
    /// Success threshold.
    pub min_confidence: f64,
    /// Run the detector every N tracked frames (0 = only when needed).
    pub redetect_interval: usize,
    /// One Euro filter, `None` = off.
    pub filter: Option<OneEuroParams>,
    /// Frame rate used when timestamps do not increase.
    pub fps: f64,
}

impl Default for TrackerParams {
    fn default() -> Self {
        TrackerParams {
            lk: LkParams::default(),
            min_lk_fraction: 0.5,
            lk_motion_threshold: 1.0,
            translate_max: 3.0,
            lk_residual_threshold: 25.0,
            ert_init: ErtInit::MeanShapeInBox,
            agree_scale: 0.1,
            shape_tolerance: 0.05,
            shape_scale: 0.05,
            redetect_below: 0.35,
            min_confidence: 0.2,
            redetect_interval: 0,
            filter: None,
            fps: 30.0,
        }
    }
}

impl TrackerParams {
    /// Checks every parameter, naming the offending one.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`].
    pub fn validate(&self) -> Result<()> {
        self.lk.validate()?;
        let check = |name: &'static str, v: f64, ok: bool, expected: &str| {
            if v.is_finite() && ok {
                Ok(())
            } else {
                Err(Error::InvalidParameter {
                    name,
                    value: v.to_string(),
                    expected: expected.into(),
                })
            }
        };
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        check(
            "tracker.min_lk_fraction",
            self.min_lk_fraction,
            unit(self.min_lk_fraction),
            "0..=1",
        )?;
        check(
            "tracker.lk_motion_threshold",
            self.lk_motion_threshold,
            self.lk_motion_threshold >= 0.0,
            ">= 0",
        )?;
        check(
            "tracker.lk_residual_threshold",
            self.lk_residual_threshold,
            self.lk_residual_threshold >= 0.0,
            ">= 0",
        )?;
        check(
            "tracker.translate_max",
            self.translate_max,
            self.translate_max >= 0.0,
            ">= 0",
        )?;
        check("tracker.agree_scale", self.agree_scale, self.agree_scale > 0.0, "> 0")?;
        check(
            "tracker.shape_tolerance",
            self.shape_tolerance,
            self.shape_tolerance >= 0.0,
            ">= 0",
        )?;
        check("tracker.shape_scale", self.shape_scale, self.shape_scale > 0.0, "> 0")?;
        check(
            "tracker.redetect_below",
            self.redetect_below,
            unit(self.redetect_below),
            "0..=1",
        )?;
        check(
            "tracker.min_confidence",
            self.min_confidence,
            unit(self.min_confidence),
            "0..=1",
        )?;
        check("tracker.fps", self.fps, self.fps > 0.0, "> 0")?;
        if let Some(f) = &self.filter {
            f.validate()?;
        }
        Ok(())
    }
}

/// What the tracker did on a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameAction {
    /// No face: the detector found none.
    #[default]
    NoFace,
    /// The detector started (or restarted) the track.
    Detected,
    /// Tracked from the previous frame without the detector.
    Tracked,
    /// Tracking was doubtful; the detector ran on this frame and its face was used.
    Redetected,
}

/// One frame's result.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedFrame {
    /// The (optionally filtered) landmarks; meaningless when `success` is false.
    pub landmarks: Landmarks68,
    /// Unfiltered landmarks.
    pub raw: Landmarks68,
    /// Whether the landmarks are trusted.
    pub success: bool,
    /// Confidence in `[0, 1]` (see module docs).
    pub confidence: f64,
    /// The ERT box used.
    pub rect: Option<Rect>,
}

impl Default for TrackedFrame {
    fn default() -> Self {
        TrackedFrame {
            landmarks: Landmarks68::default(),
            raw: Landmarks68::default(),
            success: false,
            confidence: 0.0,
            rect: None,
        }
    }
}

/// Per-frame report.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TrackerReport {
    /// What happened.
    pub action: FrameAction,
    /// Whether the detector ran.
    pub detector_ran: bool,
    /// Landmarks tracked by LK (0 when LK was not used).
    pub lk_tracked: usize,
    /// Median LK motion (px), 0 when LK was not used.
    pub lk_motion: f64,
    /// Whether LK ran (pyramids built and the 68 points tracked) on this frame.
    pub lk_ran: bool,
    /// The cheap global-motion estimate (px) between the previous and this frame
    /// over the face (see the module docs); `NaN` when it was not computed.
    pub motion_estimate: f64,
    /// RMS grey-level mismatch the motion test's translation leaves unexplained;
    /// `NaN` when it was not computed.
    pub motion_residual: f64,
}

/// State carried between frames.
#[derive(Debug, Clone, Default)]
pub struct TrackerState {
    tracking: bool,
    prev: Landmarks68,
    frames_since_detect: usize,
    last_time: Option<f64>,
    last_size: (u32, u32),
    filters: Vec<OneEuroState>,
}

impl TrackerState {
    /// A state that starts with detection.
    pub fn new() -> Self {
        Self::default()
    }

    /// True when the last frame was tracked successfully.
    pub fn is_tracking(&self) -> bool {
        self.tracking
    }
}

/// Reusable memory of the tracker.
#[derive(Debug)]
pub struct TrackerWorkspace<FW, SW> {
    lk: LkWorkspace,
    finder: FW,
    regressor: SW,
    boxes: Vec<Rect>,
    lk_next: Vec<Point2<f64>>,
    lk_status: Vec<TrackStatus>,
    lk_err: Vec<f64>,
    init: Vec<Point2<f64>>,
    out: Vec<Point2<f64>>,
    scratch: Vec<f64>,
    /// The previous frame (for the motion test and for LK when it is needed).
    prev_gray: GrayImage,
    /// `prev_gray` holds the frame before the current one.
    prev_valid: bool,
    /// The LK workspace's latest pyramid is that of `prev_gray`.
    lk_has_prev: bool,
}

/// The video landmark tracker. Immutable; state lives in [`TrackerState`].
#[derive(Debug)]
pub struct LandmarkTracker<F, S> {
    finder: F,
    regressor: S,
    lk: PyramidLk,
    params: TrackerParams,
    /// Mean shape, centred, in box units (u, v).
    mean_centred: Vec<[f64; 2]>,
    mean_centroid: [f64; 2],
    mean_norm2: f64,
}

impl<F: FaceFinder, S: ShapeRegressor> LandmarkTracker<F, S> {
    /// Builds a tracker.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for bad parameters; [`Error::DimensionMismatch`]
    /// when the regressor does not produce 68 points.
    pub fn new(finder: F, regressor: S, params: TrackerParams) -> Result<Self> {
        params.validate()?;
        let ms = regressor.mean_shape();
        if ms.len() != 2 * NUM_LANDMARKS {
            return Err(Error::DimensionMismatch {
                what: "regressor mean shape values (2 x 68)".into(),
                expected: 2 * NUM_LANDMARKS,
                got: ms.len(),
            });
        }
        let pts: Vec<[f64; 2]> = ms.chunks_exact(2).map(|c| [c[0] as f64, c[1] as f64]).collect();
        let n = pts.len() as f64;
        let c = [
            pts.iter().map(|p| p[0]).sum::<f64>() / n,
            pts.iter().map(|p| p[1]).sum::<f64>() / n,
        ];
        let mean_centred: Vec<[f64; 2]> = pts.iter().map(|p| [p[0] - c[0], p[1] - c[1]]).collect();
        let mean_norm2 = mean_centred.iter().map(|p| p[0] * p[0] + p[1] * p[1]).sum();
        Ok(LandmarkTracker {
            finder,
            regressor,
            lk: PyramidLk::new(params.lk)?,
            params,
            mean_centred,
            mean_centroid: c,
            mean_norm2,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &TrackerParams {
        &self.params
    }

    /// A workspace for this tracker.
    pub fn new_workspace(&self) -> TrackerWorkspace<F::Workspace, S::Workspace> {
        TrackerWorkspace {
            lk: LkWorkspace::new(&self.lk),
            finder: self.finder.new_workspace(),
            regressor: self.regressor.new_workspace(),
            boxes: Vec::with_capacity(16),
            lk_next: vec![Point2::origin(); LK_POINTS.len()],
            lk_status: vec![TrackStatus::Tracked; LK_POINTS.len()],
            lk_err: vec![0.0; LK_POINTS.len()],
            init: vec![Point2::origin(); NUM_LANDMARKS],
            out: vec![Point2::origin(); NUM_LANDMARKS],
            scratch: Vec::with_capacity(NUM_LANDMARKS),
            prev_gray: GrayImage::new(0, 0),
            prev_valid: false,
            lk_has_prev: false,
        }
    }

    /// The dlib-like box for a shape: the square box in which the mean shape fits
    /// `pts` best (see module docs).
    pub fn box_for_shape(&self, pts: &[Point2<f64>]) -> Rect {
        let n = pts.len() as f64;
        let (mut cx, mut cy) = (0.0, 0.0);
        for p in pts {
            cx += p.x;
            cy += p.y;
        }
        cx /= n;
        cy /= n;
        let mut num = 0.0;
        for (p, m) in pts.iter().zip(&self.mean_centred) {
            num += (p.x - cx) * m[0] + (p.y - cy) * m[1];
        }
        let s = (num / self.mean_norm2).max(2.0);
        let l = cx - s * self.mean_centroid[0];
        let t = cy - s * self.mean_centroid[1];
        Rect {
            left: l,
            top: t,
            width: s + 1.0,
            height: s + 1.0,
        }
    }

    /// RMS residual of the rigid points (nose 27-35, eyes 36-47) of `pts` after
    /// similarity alignment to the mean shape, divided by the aligned inter-ocular
    /// distance. Expressions move these points little, so a large value means the
    /// shape is not a face.
    pub fn shape_residual(&self, pts: &[Point2<f64>]) -> f64 {
        let idx = RIGID_POINTS;
        let n = idx.len() as f64;
        let (mut cx, mut cy, mut mx, mut my) = (0.0, 0.0, 0.0, 0.0);
        for i in idx.clone() {
            cx += pts[i].x;
            cy += pts[i].y;
            mx += self.mean_centred[i][0];
            my += self.mean_centred[i][1];
        }
        cx /= n;
        cy /= n;
        mx /= n;
        my /= n;
        // Similarity mean -> pts: [a -b; b a].
        let (mut a, mut b, mut d) = (0.0, 0.0, 0.0);
        for i in idx.clone() {
            let (u, v) = (self.mean_centred[i][0] - mx, self.mean_centred[i][1] - my);
            let (x, y) = (pts[i].x - cx, pts[i].y - cy);
            a += u * x + v * y;
            b += u * y - v * x;
            d += u * u + v * v;
        }
        if d <= 0.0 {
            return f64::INFINITY;
        }
        a /= d;
        b /= d;
        let mut ss = 0.0;
        for i in idx {
            let (u, v) = (self.mean_centred[i][0] - mx, self.mean_centred[i][1] - my);
            let (x, y) = (pts[i].x - cx, pts[i].y - cy);
            ss += (x - (a * u - b * v)).powi(2) + (y - (b * u + a * v)).powi(2);
        }
        let rms = (ss / n).sqrt();
        let (r, l) = (self.mean_centred[36], self.mean_centred[45]);
        let iod = (a * a + b * b).sqrt() * ((l[0] - r[0]).powi(2) + (l[1] - r[1]).powi(2)).sqrt();
        if iod > 0.0 && rms.is_finite() {
            rms / iod
        } else {
            f64::INFINITY
        }
    }

    fn detect_and_fit(
        &self,
        img: &GrayImage,
        ws: &mut TrackerWorkspace<F::Workspace, S::Workspace>,
        near: Option<&Rect>,
    ) -> Result<Option<Rect>> {
        self.finder.find_faces(img, &mut ws.finder, &mut ws.boxes)?;
        let pick = match near {
            Some(r) => ws.boxes.iter().copied().max_by(|a, b| a.iou(r).total_cmp(&b.iou(r))),
            None => ws.boxes.first().copied(),
        };
        let Some(rect) = pick else { return Ok(None) };
        self.regressor.predict(img, &rect, &mut ws.regressor, &mut ws.out)?;
        Ok(Some(rect))
    }

    /// Processes one frame.
    ///
    /// `timestamp_s` is the frame time in seconds (used by the filter; when it does
    /// not increase, `1 / fps` is assumed). Writes `out`; does not allocate after
    /// warm-up unless the detector does.
    ///
    /// # Errors
    /// Errors of the detector or regressor; LK errors for frames smaller than the window.
    pub fn track_into(
        &self,
        img: &GrayImage,
        timestamp_s: f64,
        ws: &mut TrackerWorkspace<F::Workspace, S::Workspace>,
        state: &mut TrackerState,
        out: &mut TrackedFrame,
    ) -> Result<TrackerReport> {
        let p = &self.params;
        let size = img.dimensions();
        if size != state.last_size {
            ws.lk.reset();
            ws.prev_valid = false;
            ws.lk_has_prev = false;
            state.tracking = false;
            state.last_size = size;
        }
        let mut report = TrackerReport {
            motion_estimate: f64::NAN,
            motion_residual: f64::NAN,
            ..TrackerReport::default()
        };
        let lk_had_prev = std::mem::replace(&mut ws.lk_has_prev, false);
        let mut confidence = 0.0;
        let mut rect = None;
        let mut restarted = false;

        let periodic = p.redetect_interval > 0 && state.frames_since_detect >= p.redetect_interval;
        if state.tracking && ws.prev_valid && !periodic {
            let prev = &state.prev.points;
            // 3a. Cheap motion test; LK only when the face moved.
            let motion = global_motion(&ws.prev_gray, img, &state.prev.bounding_box());
            report.motion_estimate = motion.map_or(f64::INFINITY, |m| m.shift());
            report.motion_residual = motion.map_or(f64::INFINITY, |m| m.residual);
            let use_lk = match motion {
                Some(m) => {
                    m.residual > p.lk_residual_threshold || m.shift() > p.lk_motion_threshold.max(p.translate_max)
                }
                None => true,
            };
            // a small shift above the threshold: move the shape by the translation
            let translate = match motion {
                Some(m) if !use_lk && m.shift() > p.lk_motion_threshold => Some((m.dx, m.dy)),
                _ => None,
            };
            let frac = if use_lk {
                // 3b. LK carries the previous landmarks: pyramids of the previous frame
                // (reused when the last frame ran LK) and of this one.
                if !lk_had_prev {
                    ws.lk.reset();
                    ws.lk.push_frame(&ws.prev_gray)?;
                }
                ws.lk.push_frame(img)?;
                ws.lk_has_prev = true;
                report.lk_ran = true;
                let rep = self.lk.track_into(
                    &ws.lk,
                    &prev[LK_POINTS],
                    &mut ws.lk_next,
                    &mut ws.lk_status,
                    &mut ws.lk_err,
                )?;
                report.lk_tracked = rep.tracked;
                rep.tracked as f64 / LK_POINTS.len() as f64
            } else {
                1.0
            };
            if frac >= p.min_lk_fraction {
                if use_lk {
                    ws.scratch.clear();
                    for ((a, b), s) in prev[LK_POINTS].iter().zip(&ws.lk_next).zip(&ws.lk_status) {
                        if s.is_tracked() {
                            ws.scratch.push((b - a).norm());
                        }
                    }
                    ws.scratch.sort_by(f64::total_cmp);
                    report.lk_motion = ws.scratch.get(ws.scratch.len() / 2).copied().unwrap_or(0.0);
                }
                if use_lk && report.lk_motion > p.lk_motion_threshold {
                    fit_similarity_apply(&prev[LK_POINTS], &ws.lk_next, &ws.lk_status, prev, &mut ws.init);
                } else if let Some((dx, dy)) = translate {
                    for (i, q) in ws.init.iter_mut().zip(prev) {
                        *i = Point2::new(q.x + dx, q.y + dy);
                    }
                } else {
                    ws.init.copy_from_slice(prev);
                }
                let r = self.box_for_shape(&ws.init);
                match p.ert_init {
                    ErtInit::PreviousShape => {
                        self.regressor
                            .predict_from_shape(img, &r, &ws.init, &mut ws.regressor, &mut ws.out)?
                    }
                    ErtInit::MeanShapeInBox => self.regressor.predict(img, &r, &mut ws.regressor, &mut ws.out)?,
                }
                // Confidence (no agreement term when LK did not run).
                let agree = if use_lk {
                    let iod = iod_of(&ws.out).max(1.0);
                    let (mut sum, mut cnt) = (0.0, 0usize);
                    for ((o, l), s) in ws.out[LK_POINTS].iter().zip(&ws.lk_next).zip(&ws.lk_status) {
                        if s.is_tracked() {
                            sum += (o - l).norm();
                            cnt += 1;
                        }
                    }
                    if cnt > 0 {
                        sum / cnt as f64 / iod
                    } else {
                        f64::INFINITY
                    }
                } else {
                    0.0
                };
                let resid = self.shape_residual(&ws.out);
                confidence = frac
                    * (-agree / p.agree_scale).exp()
                    * (-(resid - p.shape_tolerance).max(0.0) / p.shape_scale).exp();
                if !confidence.is_finite() {
                    confidence = 0.0;
                }
                rect = Some(r);
                report.action = FrameAction::Tracked;
            }
        }
        if report.action != FrameAction::Tracked || confidence < p.redetect_below {
            let near = if state.tracking {
                Some(state.prev.bounding_box())
            } else {
                None
            };
            report.detector_ran = true;
            let found = self.detect_and_fit(img, ws, near.as_ref())?;
            if let Some(r) = found {
                let resid = self.shape_residual(&ws.out);
                confidence = (-(resid - p.shape_tolerance).max(0.0) / p.shape_scale).exp();
                rect = Some(r);
                report.action = if report.action == FrameAction::Tracked {
                    FrameAction::Redetected
                } else {
                    FrameAction::Detected
                };
                restarted = !state.tracking;
                state.frames_since_detect = 0;
            } else if report.action == FrameAction::Tracked {
                // Keep the tracked result with its (low) confidence.
            } else {
                report.action = FrameAction::NoFace;
                confidence = 0.0;
            }
        } else {
            state.frames_since_detect += 1;
        }

        let success = report.action != FrameAction::NoFace && confidence >= p.min_confidence && iod_of(&ws.out) > 0.0;
        out.success = success;
        out.confidence = confidence;
        out.rect = rect;
        if report.action != FrameAction::NoFace {
            out.raw.points.copy_from_slice(&ws.out);
        }
        // Temporal filter.
        let dt = match state.last_time {
            Some(t0) if timestamp_s.is_finite() && timestamp_s > t0 => timestamp_s - t0,
            _ => 1.0 / p.fps,
        };
        state.last_time = Some(timestamp_s);
        if let (Some(fp), true) = (&p.filter, success) {
            if state.filters.len() != 2 * NUM_LANDMARKS {
                state.filters.resize(2 * NUM_LANDMARKS, OneEuroState::default());
            }
            if restarted || !state.tracking {
                state.filters.iter_mut().for_each(OneEuroState::reset);
            }
            for (i, q) in out.raw.points.iter().enumerate() {
                let x = state.filters[2 * i].filter(fp, q.x, dt);
                let y = state.filters[2 * i + 1].filter(fp, q.y, dt);
                out.landmarks.points[i] = Point2::new(x, y);
            }
        } else {
            out.landmarks.points.copy_from_slice(&out.raw.points);
        }
        state.tracking = success;
        if success {
            state.prev.points.copy_from_slice(&ws.out);
        }
        // Keep this frame for the next one's motion test (and LK if needed).
        if ws.prev_gray.dimensions() == size {
            ws.prev_gray.copy_from_slice(img.as_raw());
        } else {
            ws.prev_gray.clone_from(img);
        }
        ws.prev_valid = true;
        Ok(report)
    }
}

/// Grid step (px) of the cheap motion test.
const MOTION_GRID_STEP: usize = 4;
/// Margin around the previous landmarks' bounding box in the motion test (fraction of its size).
const MOTION_BOX_MARGIN: f64 = 0.1;

/// Cheap global-motion test: one Gauss-Newton step of translation-only LK over the
/// face (the previous landmarks' bounding box plus a margin) on a
/// `MOTION_GRID_STEP`-px grid, with central-difference gradients of the previous
/// frame: `d = -G⁻¹ b`, `G = Σ ∇I ∇Iᵀ`, `b = Σ (J - I) ∇I`. Returns `|d|` in pixels,
/// or `None` when the region is degenerate (too small, flat). A single linearised
/// step underestimates large motions, but they still exceed the threshold, which
/// is all the test decides. The RMS of what the translation leaves unexplained
/// catches changes that are not a small shift (a cut, a flat frame, a large
/// motion the linearisation cannot see).
fn global_motion(prev: &GrayImage, cur: &GrayImage, face: &Rect) -> Option<Motion> {
    let (w, h) = (prev.width() as usize, prev.height() as usize);
    if cur.dimensions() != prev.dimensions() || w < 3 || h < 3 {
        return None;
    }
    let (mx, my) = (face.width * MOTION_BOX_MARGIN, face.height * MOTION_BOX_MARGIN);
    let clamp = |v: f64, hi: usize| -> usize { v.max(1.0).min((hi - 2) as f64) as usize };
    let (x0, x1) = (clamp(face.left - mx, w), clamp(face.left + face.width + mx, w));
    let (y0, y1) = (clamp(face.top - my, h), clamp(face.top + face.height + my, h));
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let (pi, ci) = (prev.as_raw(), cur.as_raw());
    // Integer sums of 2x the central-difference gradient (exact).
    let (mut gxx, mut gxy, mut gyy, mut bx, mut by) = (0i64, 0i64, 0i64, 0i64, 0i64);
    let (mut tt, mut n) = (0i64, 0usize);
    for y in (y0..=y1).step_by(MOTION_GRID_STEP) {
        let (r, up, dn) = (y * w, (y - 1) * w, (y + 1) * w);
        for x in (x0..=x1).step_by(MOTION_GRID_STEP) {
            let gx = pi[r + x + 1] as i64 - pi[r + x - 1] as i64;
            let gy = pi[dn + x] as i64 - pi[up + x] as i64;
            let it = ci[r + x] as i64 - pi[r + x] as i64;
            gxx += gx * gx;
            gxy += gx * gy;
            gyy += gy * gy;
            bx += it * gx;
            by += it * gy;
            tt += it * it;
            n += 1;
        }
    }
    let (a, b, c) = (gxx as f64, gxy as f64, gyy as f64);
    let det = a * c - b * b;
    if det.is_nan() || det <= 1e-9 * (a + c) * (a + c) {
        return None;
    }
    // With g = 2∇I: d = -G⁻¹ b = -2 (Σ g gᵀ)⁻¹ Σ (J - I) g.
    let dx = -2.0 * (c * bx as f64 - b * by as f64) / det;
    let dy = -2.0 * (a * by as f64 - b * bx as f64) / det;
    // Σ (J - I)² minus its part explained by the gradients (the projection bᵀ G⁻¹ b).
    let (bx, by) = (bx as f64, by as f64);
    let explained = (c * bx * bx - 2.0 * b * bx * by + a * by * by) / det;
    Some(Motion {
        dx,
        dy,
        residual: ((tt as f64 - explained).max(0.0) / n.max(1) as f64).sqrt(),
    })
}

/// Result of [`global_motion`].
#[derive(Debug, Clone, Copy)]
struct Motion {
    /// Estimated translation (px).
    dx: f64,
    dy: f64,
    /// RMS unexplained grey-level difference.
    residual: f64,
}

impl Motion {
    /// Estimated translation length (px).
    fn shift(&self) -> f64 {
        (self.dx * self.dx + self.dy * self.dy).sqrt()
    }
}

/// The landmarks LK tracks when it runs: the rigid nose and eye points, whose
/// motion says where the face went (the similarity fitted to them moves all 68).
/// A third of the 68 points, so a third of the LK cost.
const LK_POINTS: std::ops::Range<usize> = RIGID_POINTS;

/// Nose and eye points: little moved by expressions.
const RIGID_POINTS: std::ops::Range<usize> = 27..48;

fn iod_of(pts: &[Point2<f64>]) -> f64 {
    (pts[facecap_core::landmarks::OUTER_EYE_LEFT] - pts[facecap_core::landmarks::OUTER_EYE_RIGHT]).norm()
}

/// Fits the least-squares similarity `from -> to` over tracked points
/// ([`facecap_geom::align::similarity2_weighted`], lost points masked out, no allocation)
/// and writes `T(apply)` into `out` (`apply` unchanged when the fit is degenerate).
fn fit_similarity_apply(
    from: &[Point2<f64>],
    to: &[Point2<f64>],
    st: &[TrackStatus],
    apply: &[Point2<f64>],
    out: &mut [Point2<f64>],
) {
    let tracked = |i: usize| {
        if st.get(i).is_some_and(|s| s.is_tracked()) {
            1.0
        } else {
            0.0
        }
    };
    match similarity2_weighted(from, to, tracked, true) {
        Ok(t) => {
            for (o, f) in out.iter_mut().zip(apply) {
                *o = t.apply(f);
            }
        }
        Err(_) => out.copy_from_slice(apply),
    }
}
