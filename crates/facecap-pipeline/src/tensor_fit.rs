//! The driver of the tensor model's video fit (Papanek 2010, sec. 4.2; the steps are in
//! [`facecap_tensor::video_fit`]): landmarks from the one tracking pass, identity from
//! the whole clip, then the per-frame pass with LK-tracked feature points on the grey
//! frames the tracking pass kept (or, past the memory budget or with landmarks from a
//! CSV, on one decoding of the video).

use std::path::Path;
use std::sync::Arc;

use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_io::csv::LandmarkRecord;
use facecap_io::video::{Frame, FrameSource};
use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use facecap_tensor::fit::{FitParams, FitState};
use facecap_tensor::model::TensorModel;
use facecap_tensor::video_fit::{fit_identity, FeatureTracker, FramePass, FramePassParams, FrameStep, IdentityFit};
use image::GrayImage;
use nalgebra::Point2;

use crate::error::{Error, Result};

/// Grey frames kept in memory by the tracking pass for the feature points (bytes).
/// Longer clips are decoded a second time instead.
pub const FRAME_BUDGET_BYTES: usize = 1 << 30;

/// Options of the video fit.
///
/// | name | default | meaning |
/// |---|---|---|
/// | `params` | [`FitParams::default`] | fitter (priors, constraint, projection) |
/// | `pass` | [`FramePassParams::default`] | per-frame pass and feature points |
/// | `identity_frames` | 40 | evenly spaced frames for the shared identity (>= 1) |
/// | `use_jaw` | false | also fit the jaw contour landmarks 0-16 (they slide along the face) |
/// | `focal` | max(width, height) | focal length in pixels |
/// | `lk_fb_px` | 1 | LK forward-backward threshold for the feature points (px; 0 = off) |
#[derive(Debug, Clone, PartialEq)]
pub struct VideoFitOptions {
    /// Fitter parameters.
    pub params: FitParams,
    /// Per-frame pass parameters.
    pub pass: FramePassParams,
    /// Frames for the identity.
    pub identity_frames: usize,
    /// Fit landmarks 0-16 too.
    pub use_jaw: bool,
    /// Focal length (pixels).
    pub focal: Option<f64>,
    /// LK forward-backward threshold (pixels).
    pub lk_fb_px: f64,
}

impl Default for VideoFitOptions {
    fn default() -> Self {
        VideoFitOptions {
            params: FitParams::default(),
            pass: FramePassParams::default(),
            identity_frames: 40,
            use_jaw: false,
            focal: None,
            lk_fb_px: 1.0,
        }
    }
}

/// Where the per-frame pass gets its grey frames.
pub enum FrameSupply {
    /// Frames kept by the tracking pass.
    Kept(Vec<Arc<GrayImage>>),
    /// Decode them (once) from this source.
    Decode(Box<dyn FrameSource>),
}

impl std::fmt::Debug for FrameSupply {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameSupply::Kept(v) => write!(f, "Kept({} frames)", v.len()),
            FrameSupply::Decode(_) => f.write_str("Decode"),
        }
    }
}

/// A fitted clip.
#[derive(Debug, Clone)]
pub struct VideoFit {
    /// Per-frame landmarks.
    pub records: Vec<LandmarkRecord>,
    /// Per-frame fit (`None`: no landmarks or the fit failed).
    pub states: Vec<Option<FitState>>,
    /// Per-frame RMS reprojection error of the landmarks, px (NaN = not fitted).
    pub rms_landmarks: Vec<f64>,
    /// Per-frame RMS reprojection error of the live feature points, px.
    pub rms_features: Vec<f64>,
    /// Per-frame RMS reprojection error of all fitted points, px.
    pub rms_all: Vec<f64>,
    /// Live feature points per frame.
    pub live_features: Vec<usize>,
    /// Feature points seeded in total.
    pub seeded_features: usize,
    /// Seedings.
    pub seedings: usize,
    /// Camera used.
    pub intrinsics: Intrinsics,
    /// Steps 1 and 2.
    pub identity: IdentityFit,
    /// Per-frame fit failures (frame position, message).
    pub failures: Vec<(usize, String)>,
}

/// LK on consecutive grey frames as the feature-point tracker.
struct LkPoints {
    lk: PyramidLk,
    ws: LkWorkspace,
    next: Vec<Point2<f64>>,
    status: Vec<TrackStatus>,
    err: Vec<f64>,
}

impl FeatureTracker for LkPoints {
    fn track(&mut self, points: &mut [Point2<f64>], alive: &mut [bool]) -> facecap_tensor::Result<()> {
        if self.ws.frames_pushed() < 2 {
            return Ok(());
        }
        let n = points.len();
        self.next.resize(n, Point2::origin());
        self.status.resize(n, TrackStatus::Tracked);
        self.err.resize(n, 0.0);
        self.lk
            .track_into(&self.ws, points, &mut self.next, &mut self.status, &mut self.err)
            .map_err(|e| facecap_tensor::Error::FeatureTracking { reason: e.to_string() })?;
        for j in 0..n {
            if alive[j] && self.status[j].is_tracked() {
                points[j] = self.next[j];
            } else {
                alive[j] = false;
            }
        }
        Ok(())
    }
}

/// Fits `model` to a clip (module docs): `records` are the frames' landmarks, `frames`
/// their grey images (needed only with feature points), `width x height` the frame size.
///
/// # Errors
/// A map with fewer than 6 usable landmarks, no frame with landmarks, invalid options,
/// decoding or fitting errors.
pub fn fit_tensor_video(
    model: &TensorModel,
    map: &LandmarkMap,
    records: Vec<LandmarkRecord>,
    frames: FrameSupply,
    (width, height): (u32, u32),
    o: &VideoFitOptions,
) -> Result<VideoFit> {
    map.validate(model.num_vertices())?;
    let pairs: Vec<(usize, u32)> = map.mapped().filter(|(i, _)| o.use_jaw || *i > 16).collect();
    if pairs.len() < 6 {
        return Err(Error::invalid("landmark map", pairs.len(), ">= 6 usable landmarks"));
    }
    if !(o.lk_fb_px.is_finite() && o.lk_fb_px >= 0.0) {
        return Err(Error::invalid("lk_fb_px", o.lk_fb_px, "a finite number >= 0"));
    }
    let lm_vertices: Vec<u32> = pairs.iter().map(|p| p.1).collect();
    let k = match o.focal {
        Some(f) => Intrinsics::new(f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0)?,
        None => Intrinsics::default_for_frame(width, height)?,
    };
    let lm_points: Vec<Option<Vec<Point2<f64>>>> = records
        .iter()
        .map(|r| {
            r.landmarks
                .as_ref()
                .filter(|_| r.success)
                .map(|lm| pairs.iter().map(|(i, _)| lm.points[*i]).collect())
        })
        .collect();
    let identity = fit_identity(model, &lm_vertices, &o.params, k, &lm_points, o.identity_frames)?;
    let mut pass = FramePass::new(
        model,
        &lm_vertices,
        &o.params,
        o.pass,
        k,
        identity.w_id.clone(),
        identity.w_exp.clone(),
    )?;
    let lk = PyramidLk::new(LkParams {
        forward_backward: (o.lk_fb_px > 0.0).then_some(o.lk_fb_px),
        ..LkParams::default()
    })?;
    let mut tracker = LkPoints {
        ws: LkWorkspace::new(&lk),
        lk,
        next: Vec::new(),
        status: Vec::new(),
        err: Vec::new(),
    };
    let use_images = pass.uses_features();
    let mut frames = frames;
    let mut decoded = Frame::default();
    let n = records.len();
    let mut out = VideoFit {
        states: Vec::with_capacity(n),
        rms_landmarks: Vec::with_capacity(n),
        rms_features: Vec::with_capacity(n),
        rms_all: Vec::with_capacity(n),
        live_features: Vec::with_capacity(n),
        seeded_features: 0,
        seedings: 0,
        intrinsics: k,
        identity,
        failures: Vec::new(),
        records: Vec::new(),
    };
    for f in 0..n {
        let mut have_image = false;
        if use_images {
            let img: Option<&GrayImage> = match &mut frames {
                FrameSupply::Kept(v) => v.get(f).map(|a| a.as_ref()),
                FrameSupply::Decode(src) => src.read_into(&mut decoded)?.then_some(&decoded.gray),
            };
            if let Some(img) = img {
                tracker.ws.push_frame(img)?;
                have_image = true;
            }
        }
        let fit = pass.step(
            FrameStep {
                landmark_points: lm_points[f].as_deref(),
                landmarks: records[f].landmarks.as_ref().filter(|_| records[f].success),
                have_image,
            },
            &mut tracker,
        )?;
        if let Some(why) = fit.failure {
            out.failures.push((f, why));
        }
        out.states.push(fit.state);
        out.rms_landmarks.push(fit.rms_landmarks);
        out.rms_features.push(fit.rms_features);
        out.rms_all.push(fit.rms_all);
        out.live_features.push(fit.live_features);
    }
    let rep = pass.report();
    out.seeded_features = rep.seeded_features;
    out.seedings = rep.seedings;
    out.records = records;
    Ok(out)
}

/// The frame size of a video without decoding it.
///
/// # Errors
/// When the video cannot be opened.
pub fn frame_size(video: &Path) -> Result<(u32, u32)> {
    let src = crate::tracker::open_video(video, 1)?;
    Ok((src.info().width, src.info().height))
}
