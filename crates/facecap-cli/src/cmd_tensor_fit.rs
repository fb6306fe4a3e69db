//! Fitting the tensor model to a video (`facecap tensor fit VIDEO`, also used by
//! `facecap transfer`), Papanek 2010, sec. 4.2: the pipeline's tracker runs once over the
//! video (or `--landmarks CSV` supplies the landmarks), the identity is fitted on the
//! whole clip, then pose and expression per frame with LK-tracked feature points around
//! mouth and brows ([`facecap_tensor::video_fit`], driven by
//! [`facecap_pipeline::tensor_fit`]). The video is decoded once: the tracking pass keeps
//! the grey frames for the feature points (up to
//! [`facecap_pipeline::tensor_fit::FRAME_BUDGET_BYTES`]; longer clips are decoded a
//! second time).
//!
//! Outputs `tensor.csv` (parameters, the one `tensor.csv` layout of
//! [`facecap_pipeline::tensor`]) and `reprojection.csv` (per-frame RMS reprojection
//! error in pixels: landmarks only, feature points only, all; number of live points).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use facecap_core::landmark_map::LandmarkMap;
use facecap_io::csv::{FrameCsvWriter, FrameRow};
use facecap_pipeline::tensor_fit::{fit_tensor_video, FrameSupply, VideoFit, VideoFitOptions, FRAME_BUDGET_BYTES};
use facecap_pipeline::{LandmarkRecorder, RunControl, TrackerPolicy, VideoTracker};
use facecap_tensor::fit::{FitParams, Method, Projection};
use facecap_tensor::model::TensorModel;
use facecap_tensor::video_fit::FramePassParams;

/// Options shared by `tensor fit` and `transfer`.
#[derive(Debug, Clone, clap::Args)]
pub struct FitOptions {
    /// Model file from `facecap tensor build`.
    #[arg(long)]
    pub model: PathBuf,
    /// iBUG-68 -> model vertex map (JSON, e.g. ict_landmarks68.json).
    #[arg(long)]
    pub landmark_map: PathBuf,
    /// Weight constraint: `regularised` (closed form) or `nnls` (non-negative).
    #[arg(long, default_value = "regularised")]
    pub method: String,
    /// Identity prior weight lambda_id (model units^2).
    #[arg(long, default_value_t = 1.0)]
    pub lambda_id: f64,
    /// Expression prior weight lambda_exp (model units^2).
    #[arg(long, default_value_t = 1.0)]
    pub lambda_exp: f64,
    /// Projection of the weight steps: `weak` (thesis, z_avg) or `perspective` (per-point depth).
    #[arg(long, default_value = "perspective")]
    pub projection: String,
    /// Focal length in pixels (default: max(width, height)).
    #[arg(long)]
    pub focal: Option<f64>,
    /// Also fit the jaw contour landmarks 0-16 (off: contour points slide along the face).
    #[arg(long)]
    pub use_jaw: bool,
    /// Frames (evenly spaced successful ones) used to fit the shared identity.
    #[arg(long, default_value_t = 40)]
    pub identity_frames: usize,
    /// Maximum pose/expression sweeps per frame (warm-started).
    #[arg(long, default_value_t = 10)]
    pub frame_sweeps: usize,
    /// `--ert-precision`.
    #[command(flatten)]
    pub ert: crate::ert_flag::ErtFlag,
    /// dlib 68-point shape model for the tracker (default: the model cache).
    #[arg(long)]
    pub shape_model: Option<PathBuf>,
    /// Grid spacing (pixels) of the extra feature samples around mouth and brows; 0 = none.
    #[arg(long, default_value_t = 4.0)]
    pub feature_step: f64,
    /// Margin (pixels) by which the mouth / brow polygons are pushed out.
    #[arg(long, default_value_t = 6.0)]
    pub feature_margin: f64,
    /// Largest distance (pixels) from a sample to the projection of its model vertex.
    #[arg(long, default_value_t = 3.0)]
    pub feature_max_px: f64,
    /// Drop a feature point whose reprojection error after a frame's fit exceeds this (pixels).
    #[arg(long, default_value_t = 6.0)]
    pub feature_drop_px: f64,
    /// LK forward-backward threshold (pixels) for the feature points.
    #[arg(long, default_value_t = 1.0)]
    pub lk_fb_px: f64,
    /// Total weight of the live feature points relative to the landmarks' (each live
    /// point gets `feature_weight * landmarks / live`).
    #[arg(long, default_value_t = 0.25)]
    pub feature_weight: f64,
    /// Seed new feature points when fewer than this fraction of the last seeding is live.
    #[arg(long, default_value_t = 0.5)]
    pub feature_reseed: f64,
}

/// A fitted clip.
pub type Fitted = VideoFit;

/// Parses the fitter parameters of the options.
pub fn fit_options(o: &FitOptions) -> anyhow::Result<VideoFitOptions> {
    let method = match o.method.as_str() {
        "regularised" | "regularized" => Method::Regularised,
        "nnls" => Method::NonNegative,
        m => bail!("--method {m:?}: expected regularised or nnls"),
    };
    let projection = match o.projection.as_str() {
        "weak" => Projection::WeakPerspective,
        "perspective" => Projection::PerPointDepth,
        p => bail!("--projection {p:?}: expected weak or perspective"),
    };
    if !(o.lk_fb_px.is_finite() && o.lk_fb_px >= 0.0) {
        bail!("--lk-fb-px {}: expected a finite number >= 0", o.lk_fb_px);
    }
    let pass = FramePassParams {
        frame_sweeps: o.frame_sweeps,
        feature_step: o.feature_step,
        feature_margin: o.feature_margin,
        feature_max_px: o.feature_max_px,
        feature_drop_px: o.feature_drop_px,
        feature_weight: o.feature_weight,
        feature_reseed: o.feature_reseed,
    };
    pass.validate().context("tensor fit options")?;
    Ok(VideoFitOptions {
        params: FitParams {
            lambda_id: o.lambda_id,
            lambda_exp: o.lambda_exp,
            method,
            projection,
            ..Default::default()
        },
        pass,
        identity_frames: o.identity_frames,
        use_jaw: o.use_jaw,
        focal: o.focal,
        lk_fb_px: o.lk_fb_px,
    })
}

/// Fits the model to a video (module docs).
pub fn fit_video(
    video: &Path,
    landmarks: Option<&Path>,
    o: &FitOptions,
    model: &TensorModel,
) -> anyhow::Result<Fitted> {
    let opts = fit_options(o)?;
    let map = LandmarkMap::from_json_file(&o.landmark_map)?;
    let want_images = opts.pass.feature_step > 0.0;
    let (records, frames, size) = match landmarks {
        Some(csv) => {
            let records = facecap_pipeline::openface::read_landmarks(csv)
                .with_context(|| format!("reading {}", csv.display()))?;
            let src = facecap_pipeline::open_video(video, 1).with_context(|| format!("opening {}", video.display()))?;
            let size = (src.info().width, src.info().height);
            (records, FrameSupply::Decode(src), size)
        }
        None => {
            let tracker = VideoTracker::new(&TrackerPolicy {
                smooth: false,
                shape_model: o.shape_model.clone(),
                upsample: facecap_landmarks::detect::Upsample::Auto,
                ert_precision: o.ert.ert_precision,
                ..TrackerPolicy::default()
            })?;
            let src = facecap_pipeline::open_video(video, 1).with_context(|| format!("opening {}", video.display()))?;
            let size = (src.info().width, src.info().height);
            let mut rec = if want_images {
                LandmarkRecorder::with_images(FRAME_BUDGET_BYTES)
            } else {
                LandmarkRecorder::new()
            };
            tracker.run(src, &mut [&mut rec], &mut RunControl::default())?;
            let frames = match rec.images.take() {
                Some(v) => FrameSupply::Kept(v),
                None if want_images => {
                    crate::out::info(&format!(
                        "{}: the grey frames exceed the memory budget; decoding the video again for the feature points",
                        video.display()
                    ));
                    FrameSupply::Decode(facecap_pipeline::open_video(video, 1)?)
                }
                None => FrameSupply::Kept(Vec::new()),
            };
            (rec.records, frames, size)
        }
    };
    let fitted = fit_tensor_video(model, &map, records, frames, size, &opts)?;
    let id = &fitted.identity;
    crate::out::info(&format!(
        "{}: first-frame alignment on frame {}: {} sweeps, landmark RMS {:.2} px",
        video.display(),
        id.first_frame,
        id.first_sweeps,
        id.first_rms_px
    ));
    crate::out::info(&format!(
        "{}: identity from {} frames: {} sweeps, cost {:.4} -> {:.4}, landmark RMS {:.2} px",
        video.display(),
        id.identity_frames,
        id.identity_sweeps,
        id.identity_cost.0,
        id.identity_cost.1,
        id.identity_rms_px
    ));
    for (f, why) in &fitted.failures {
        crate::out::info(&format!("{}: frame {f}: fit failed: {why}", video.display()));
    }
    crate::out::info(&format!(
        "{}: {} feature points around mouth and brows, seeded {} times (re-seeded below {:.0}% live)",
        video.display(),
        fitted.seeded_features,
        fitted.seedings,
        100.0 * o.feature_reseed
    ));
    Ok(fitted)
}

/// Writes `tensor.csv` of a fit (see [`facecap_pipeline::tensor`]).
pub fn write_tensor_csv(path: &Path, model: &TensorModel, fitted: &Fitted) -> anyhow::Result<()> {
    facecap_pipeline::tensor::write_tensor_csv(path, model, &fitted.records, &fitted.states)?;
    Ok(())
}

/// Confidence written to `reprojection.csv`: `1 / (1 + RMS reprojection error in pixels)`.
fn confidence(rms_px: f64) -> f64 {
    if rms_px.is_finite() {
        1.0 / (1.0 + rms_px)
    } else {
        0.0
    }
}

/// Writes `reprojection.csv`: per-frame RMS reprojection errors (px) and live feature points.
pub fn write_reprojection_csv(path: &Path, fitted: &Fitted) -> anyhow::Result<()> {
    let cols = ["rms_landmarks_px", "rms_features_px", "rms_all_px", "features_live"];
    let mut wr = FrameCsvWriter::create(path, &cols)?;
    for (f, r) in fitted.records.iter().enumerate() {
        let ok = fitted.states.get(f).is_some_and(|s| s.is_some());
        let values = [
            fitted.rms_landmarks[f],
            fitted.rms_features[f],
            fitted.rms_all[f],
            fitted.live_features[f] as f64,
        ];
        wr.write_row(&FrameRow {
            frame: r.frame,
            timestamp: r.timestamp,
            success: ok,
            confidence: if ok { confidence(fitted.rms_all[f]) } else { 0.0 },
            values: &values,
        })?;
    }
    wr.finish()?;
    Ok(())
}

/// Mean and maximum of the finite values, and their count.
pub fn summary(v: &[f64]) -> (f64, f64, usize) {
    let ok: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    let mean = ok.iter().sum::<f64>() / ok.len().max(1) as f64;
    let max = ok.iter().copied().fold(f64::NAN, f64::max);
    (mean, max, ok.len())
}

/// Prints the one-line summary of a fit.
pub fn print_summary(video: &Path, fitted: &Fitted) {
    let fmt = |v: &[f64]| {
        let (m, x, n) = summary(v);
        if n > 0 {
            format!("mean {m:.2} (max {x:.2})")
        } else {
            "n/a".to_string()
        }
    };
    let n = summary(&fitted.rms_landmarks).2;
    let last_live = fitted
        .live_features
        .iter()
        .rev()
        .find(|&&x| x > 0)
        .copied()
        .unwrap_or(0);
    outln!(
        "{}: {n} / {} frames fitted; RMS reprojection px: landmarks {}, features {}, all {}; feature points {} seeded, {last_live} live at the end",
        video.display(),
        fitted.records.len(),
        fmt(&fitted.rms_landmarks),
        fmt(&fitted.rms_features),
        fmt(&fitted.rms_all),
        fitted.seeded_features,
    );
}
