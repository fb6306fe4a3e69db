//! Fitting the tensor model to a video (`facecap tensor fit VIDEO`, also used by
//! `facecap transfer`): composes the landmark tracker (`facecap-landmarks`) with the
//! tensor fitter (`facecap-tensor`), following Papanek 2010, sec. 4.2:
//!
//! 1. **Landmarks**: the 68-point tracker (HOG detector + ERT + LK box carrying) runs
//!    over the video, or `--landmarks CSV` supplies them.
//! 2. **First-frame alignment** (automatic, no clicking): the first frame with landmarks
//!    is fitted on the mapped landmarks alone (pose, identity, expression).
//! 3. **Identity**: one identity from `--identity-frames` evenly spaced frames (sequence
//!    fit on the landmarks, the thesis' multi-frame fitting), started from step 2.
//! 4. **Per frame** (one streaming pass over the video): pose and expression with that
//!    identity, warm-started from the previous frame, on the landmarks plus the live
//!    extra feature points.
//! 5. **Extra feature points** (thesis sec. 4.2): after the first fitted frame, a grid of
//!    image samples (spacing `--feature-step` px) around the mouth (outer-lip polygon)
//!    and both brows (brow + upper-eyelid polygons), pushed out by `--feature-margin` px,
//!    is attached to the closest *visible* model vertex by reprojecting the fitted mesh
//!    (`features::closest_visible_vertices`, within `--feature-max-px`); each distinct
//!    vertex becomes a feature point starting at the vertex's projection. The points are
//!    tracked frame to frame by pyramidal LK (`facecap_landmarks::lk`, forward-backward
//!    check `--lk-fb-px`). A point lost by LK is dropped for good (weight 0), as is a
//!    point whose reprojection error after a frame's fit exceeds `--feature-drop-px`
//!    (the frame is then refitted once). When fewer than `--feature-reseed` of the points
//!    of the last seeding are live, new points are seeded on the current frame (a
//!    departure from the thesis, which only drops them; without it a long clip ends with
//!    almost none).
//!
//! Outputs `tensor.csv` (parameters) and `reprojection.csv` (per-frame RMS reprojection
//! error in pixels: landmarks only, feature points only, all; number of live points).

use facecap_landmarks::detect::Upsample;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use facecap_core::camera::Intrinsics;
use facecap_core::csv::{FrameCsvWriter, FrameRow, LandmarkRecord, POSE_COLUMNS};
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::video::{open_source, Frame, SourceOptions};
use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use facecap_tensor::fit::{FitInput, FitParams, FitState, Fitter, Method, Projection};
use facecap_tensor::model::TensorModel;
use nalgebra::{Point2, Point3};

/// Options shared by `tensor fit` and `transfer`.
#[derive(Debug, Clone, clap::Args)]
pub struct FitOptions {
    /// Face detector up-sampling: `auto` (default; finds what dlib's `detector(img, 1)`
    /// finds, scanning the finest levels only when needed) or N = 0..4 doublings of the
    /// image before detection, exactly dlib's `detector(img, N)` (docs/detection.md).
    #[arg(long, value_name = "auto|N", default_value = "auto")]
    pub upsample: Upsample,
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

/// Per-frame landmarks plus the video's frame size.
pub struct VideoLandmarks {
    /// One record per frame.
    pub records: Vec<LandmarkRecord>,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
}

/// A fitted sequence.
pub struct Fitted {
    /// Per-frame landmarks (tracked or read).
    pub records: Vec<LandmarkRecord>,
    /// Per-frame fit (None = no landmarks / failed).
    pub states: Vec<Option<FitState>>,
    /// Per-frame RMS reprojection error of the landmarks, px (NaN = not fitted).
    pub rms_landmarks: Vec<f64>,
    /// Per-frame RMS reprojection error of the live feature points, px.
    pub rms_features: Vec<f64>,
    /// Per-frame RMS reprojection error of all fitted points, px.
    pub rms_all: Vec<f64>,
    /// Live feature points per frame.
    pub live_features: Vec<usize>,
    /// Feature points seeded on the first frame.
    pub seeded_features: usize,
    /// Camera used.
    pub intrinsics: Intrinsics,
}

/// Parses the fitter parameters of the options.
pub fn fit_params(o: &FitOptions) -> anyhow::Result<FitParams> {
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
    for (n, v) in [
        ("--feature-step", o.feature_step),
        ("--feature-margin", o.feature_margin),
        ("--feature-max-px", o.feature_max_px),
        ("--feature-drop-px", o.feature_drop_px),
        ("--lk-fb-px", o.lk_fb_px),
        ("--feature-reseed", o.feature_reseed),
        ("--feature-weight", o.feature_weight),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{n} {v}: expected a finite number >= 0");
        }
    }
    if o.frame_sweeps == 0 {
        bail!("--frame-sweeps 0: expected >= 1");
    }
    Ok(FitParams {
        lambda_id: o.lambda_id,
        lambda_exp: o.lambda_exp,
        method,
        projection,
        ..Default::default()
    })
}

/// Runs the 68-point tracker over a video.
pub fn track_video(video: &Path, shape_model: Option<&Path>, upsample: Upsample) -> anyhow::Result<VideoLandmarks> {
    use facecap_landmarks::detect::FaceDetector;
    use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
    use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
    let model_path = crate::cmd_landmarks::resolve_model(shape_model)?;
    let sp = ShapePredictor::from_file_cached(&model_path)
        .map(|(sp, _)| sp)
        .with_context(|| format!("loading {}", model_path.display()))?
        .with_params(ErtParams {
            output: OutputPrecision::SubPixel,
        });
    let det = FaceDetector::default_model()
        .and_then(|d| d.with_upsample(upsample))
        .context("loading the face detector")?;
    let tracker = LandmarkTracker::new(det, sp, TrackerParams::default())?;
    let mut ws = tracker.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();
    let mut src =
        open_source(video, &SourceOptions::default()).with_context(|| format!("opening {}", video.display()))?;
    let (width, height) = (src.info().width, src.info().height);
    let mut frame = Frame::default();
    let mut records = Vec::new();
    while src.read_into(&mut frame)? {
        tracker
            .track_into(&frame.gray, frame.timestamp_s, &mut ws, &mut state, &mut out)
            .with_context(|| format!("{}: frame {}", video.display(), frame.index))?;
        records.push(LandmarkRecord {
            frame: frame.index,
            timestamp: frame.timestamp_s.max(0.0),
            success: out.success,
            confidence: out.confidence,
            landmarks: out.success.then(|| out.landmarks.clone()),
        });
    }
    Ok(VideoLandmarks { records, width, height })
}

/// Landmarks from a CSV, with the frame size read from the video.
fn landmarks_from_csv(video: &Path, csv: &Path) -> anyhow::Result<VideoLandmarks> {
    let records = facecap_core::csv::read_landmarks_csv(csv).with_context(|| format!("reading {}", csv.display()))?;
    let src = open_source(video, &SourceOptions::default()).with_context(|| format!("opening {}", video.display()))?;
    let info = src.info();
    Ok(VideoLandmarks {
        records,
        width: info.width,
        height: info.height,
    })
}

/// Outer-lip polygon (48-59) and brow-to-upper-eyelid polygons of both brows.
fn feature_regions(l: &Landmarks68) -> [Vec<Point2<f64>>; 3] {
    let p = &l.points;
    let pick = |ids: &[usize]| ids.iter().map(|&i| p[i]).collect::<Vec<_>>();
    [
        pick(&[48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59]),
        pick(&[17, 18, 19, 20, 21, 39, 38, 37, 36]),
        pick(&[22, 23, 24, 25, 26, 45, 44, 43, 42]),
    ]
}

/// Extra feature points of a first frame: distinct visible model vertices under image
/// samples around the mouth and brows, and where they project.
fn seed_features(
    model: &TensorModel,
    state: &FitState,
    k: &Intrinsics,
    lm: &Landmarks68,
    o: &FitOptions,
    exclude: &[u32],
) -> anyhow::Result<(Vec<u32>, Vec<Point2<f64>>)> {
    let Some(pose) = state.pose else {
        return Ok((Vec::new(), Vec::new()));
    };
    let verts: Vec<Point3<f64>> = model
        .generate_points(&state.w_id, &state.w_exp)?
        .iter()
        .map(|p| p.cast())
        .collect();
    let mut samples = Vec::new();
    for poly in feature_regions(lm) {
        samples.extend(facecap_tensor::features::grid_samples_in_polygon(
            &poly,
            o.feature_margin,
            o.feature_step,
        ));
    }
    let hits = facecap_tensor::features::closest_visible_vertices(&verts, &pose, k, &samples, o.feature_max_px)?;
    let mut seen = std::collections::HashSet::new();
    exclude.iter().for_each(|v| {
        seen.insert(*v);
    });
    let mut vs = Vec::new();
    let mut pts = Vec::new();
    for v in hits.into_iter().flatten() {
        if seen.insert(v) {
            if let Some(x) = pose.project(k, &verts[v as usize]) {
                vs.push(v);
                pts.push(x);
            }
        }
    }
    Ok((vs, pts))
}

/// Fits the model to a video (module docs).
pub fn fit_video(
    video: &Path,
    landmarks: Option<&Path>,
    o: &FitOptions,
    model: &TensorModel,
) -> anyhow::Result<Fitted> {
    let params = fit_params(o)?;
    let lms = match landmarks {
        Some(csv) => landmarks_from_csv(video, csv)?,
        None => track_video(video, o.shape_model.as_deref(), o.upsample)?,
    };
    let records = lms.records;
    let map = LandmarkMap::from_json_file(&o.landmark_map)?;
    map.validate(model.num_vertices())?;
    let pairs: Vec<(usize, u32)> = map.mapped().filter(|(i, _)| o.use_jaw || *i > 16).collect();
    if pairs.len() < 6 {
        bail!(
            "the landmark map maps only {} usable landmarks (need >= 6)",
            pairs.len()
        );
    }
    let lm_vertices: Vec<u32> = pairs.iter().map(|p| p.1).collect();
    let nl = lm_vertices.len();
    let (w, h) = (lms.width, lms.height);
    let k = match o.focal {
        Some(f) => Intrinsics::new(f, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0)?,
        None => Intrinsics::default_for_frame(w, h)?,
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
    let good: Vec<usize> = (0..lm_points.len()).filter(|&f| lm_points[f].is_some()).collect();
    let Some(&first) = good.first() else {
        bail!("{}: no frame with landmarks", video.display());
    };
    let ones = vec![1.0; nl];

    // First-frame alignment on the landmarks alone.
    let align = Fitter::new(model, &lm_vertices, params.clone())?;
    let mut aws = align.workspace();
    let mut first_state = align.initial_state();
    let first_pts = lm_points[first].as_deref().unwrap_or_default();
    let rep = align.solve_into(
        &FitInput {
            image: first_pts,
            weights: &ones,
            intrinsics: k,
        },
        &mut aws,
        &mut first_state,
    )?;
    eprintln!(
        "{}: first-frame alignment on frame {first}: {} sweeps, landmark RMS {:.2} px",
        video.display(),
        rep.sweeps,
        rep.rms_px
    );

    // Identity from evenly spaced frames, on the landmarks.
    let nsel = o.identity_frames.clamp(1, good.len());
    let sel: Vec<usize> = (0..nsel).map(|j| good[j * good.len() / nsel]).collect();
    let inputs: Vec<FitInput> = sel
        .iter()
        .filter_map(|&f| lm_points[f].as_deref())
        .map(|im| FitInput {
            image: im,
            weights: &ones,
            intrinsics: k,
        })
        .collect();
    let mut seq: Vec<FitState> = (0..inputs.len())
        .map(|_| {
            let mut s = align.initial_state();
            s.w_id.clone_from(&first_state.w_id);
            s
        })
        .collect();
    let rep = align.fit_sequence(&inputs, &mut seq, &mut aws)?;
    eprintln!(
        "{}: identity from {} frames: {} sweeps, cost {:.4} -> {:.4}, landmark RMS {:.2} px",
        video.display(),
        inputs.len(),
        rep.sweeps,
        rep.initial_cost,
        rep.final_cost,
        rep.rms_px
    );
    let per_frame_params = FitParams {
        update_identity: false,
        prior_id: None,
        max_sweeps: o.frame_sweeps,
        ..params
    };
    let mut pass = FramePass {
        model,
        o,
        k,
        params: per_frame_params,
        lm_vertices: &lm_vertices,
        w_id: seq[0].w_id.clone(),
        w_exp: first_state.w_exp.clone(),
        n: records.len(),
    };
    pass.run(video, &records, &lm_points)
}

/// The per-frame pass: decodes the video, tracks the feature points by LK, fits every
/// frame with the identity fixed, drops lost / outlying feature points and seeds new
/// ones when too few are left.
struct FramePass<'a> {
    model: &'a TensorModel,
    o: &'a FitOptions,
    k: Intrinsics,
    params: FitParams,
    lm_vertices: &'a [u32],
    w_id: Vec<f64>,
    w_exp: Vec<f64>,
    n: usize,
}

impl FramePass<'_> {
    fn run(
        &mut self,
        video: &Path,
        records: &[LandmarkRecord],
        lm_points: &[Option<Vec<Point2<f64>>>],
    ) -> anyhow::Result<Fitted> {
        let (o, k, n) = (self.o, self.k, self.n);
        let nl = self.lm_vertices.len();
        let use_features = o.feature_step > 0.0;
        let lk = PyramidLk::new(LkParams {
            forward_backward: (o.lk_fb_px > 0.0).then_some(o.lk_fb_px),
            ..LkParams::default()
        })?;
        let mut lk_ws = LkWorkspace::new(&lk);
        let mut src = if use_features {
            Some(
                open_source(video, &SourceOptions::default())
                    .with_context(|| format!("opening {}", video.display()))?,
            )
        } else {
            None
        };
        let mut frame = Frame::default();
        // Feature points: vertices, current image positions, alive flags.
        let mut fv: Vec<u32> = Vec::new();
        let mut fx: Vec<Point2<f64>> = Vec::new();
        let mut alive: Vec<bool> = Vec::new();
        let mut seeded_total = 0usize;
        let mut seeded_live = 0usize;
        let mut seeds = 0usize;
        let (mut next, mut status, mut lk_err) = (Vec::new(), Vec::new(), Vec::new());
        let mut fitter = self.fitter(&[])?;
        let mut ws = fitter.workspace();
        let mut st = self.state(&fitter);
        let mut states = Vec::with_capacity(n);
        let (mut rms_l, mut rms_f, mut rms_a, mut live) =
            (vec![f64::NAN; n], vec![f64::NAN; n], vec![f64::NAN; n], vec![0; n]);
        let mut image = Vec::new();
        let mut weights = Vec::new();
        let mut model_pts = Vec::new();
        let mut err = Vec::new();
        for f in 0..n {
            // LK: carry the live feature points into this frame.
            let mut have_frame = false;
            if let Some(src) = src.as_mut() {
                have_frame = src.read_into(&mut frame)?;
                if have_frame {
                    lk_ws.push_frame(&frame.gray)?;
                    if !fv.is_empty() && lk_ws.frames_pushed() >= 2 {
                        next.resize(fv.len(), Point2::origin());
                        status.resize(fv.len(), TrackStatus::Tracked);
                        lk_err.resize(fv.len(), 0.0);
                        lk.track_into(&lk_ws, &fx, &mut next, &mut status, &mut lk_err)?;
                        for j in 0..fv.len() {
                            if alive[j] && status[j].is_tracked() && next[j].x.is_finite() && next[j].y.is_finite() {
                                fx[j] = next[j];
                            } else {
                                alive[j] = false;
                            }
                        }
                    }
                } else {
                    // Video shorter than the landmark records: no more feature points.
                    alive.iter_mut().for_each(|a| *a = false);
                }
            }
            let Some(lp) = &lm_points[f] else {
                states.push(None);
                continue;
            };
            let nf = fv.len();
            image.clear();
            image.extend_from_slice(lp);
            image.extend_from_slice(&fx);
            weights.clear();
            weights.resize(nl, 1.0);
            let n_alive = alive.iter().filter(|&&a| a).count();
            let fw = if n_alive > 0 {
                o.feature_weight * nl as f64 / n_alive as f64
            } else {
                0.0
            };
            weights.extend(alive.iter().map(|&a| if a { fw } else { 0.0 }));
            err.resize(nl + nf, 0.0);
            let mut fitted = false;
            for attempt in 0..2 {
                let input = FitInput {
                    image: &image,
                    weights: &weights,
                    intrinsics: k,
                };
                match fitter.solve_into(&input, &mut ws, &mut st) {
                    Ok(_) => fitted = true,
                    Err(e) => {
                        eprintln!("{}: frame {f}: fit failed: {e}", video.display());
                        st.pose = None;
                        fitted = false;
                        break;
                    }
                }
                // Per-point reprojection errors; drop feature outliers and refit once.
                let Some(pose) = st.pose else { break };
                fitter.points_into(&st, &mut ws, &mut model_pts);
                for (e, (p, x)) in err.iter_mut().zip(model_pts.iter().zip(&image)) {
                    *e = pose.project(&k, p).map_or(f64::INFINITY, |q| (q - x).norm());
                }
                let mut dropped = 0;
                for j in 0..nf {
                    if alive[j] && err[nl + j] > o.feature_drop_px {
                        alive[j] = false;
                        weights[nl + j] = 0.0;
                        dropped += 1;
                    }
                }
                if dropped == 0 || attempt == 1 {
                    break;
                }
            }
            if !fitted {
                states.push(None);
                continue;
            }
            // Unweighted RMS over the used points.
            let rms = |r: std::ops::Range<usize>| -> f64 {
                let (mut s, mut c) = (0.0, 0usize);
                for i in r {
                    if weights[i] > 0.0 {
                        s += err[i] * err[i];
                        c += 1;
                    }
                }
                if c > 0 {
                    (s / c as f64).sqrt()
                } else {
                    f64::NAN
                }
            };
            rms_l[f] = rms(0..nl);
            rms_f[f] = rms(nl..nl + nf);
            rms_a[f] = rms(0..nl + nf);
            let n_live = alive.iter().filter(|&&a| a).count();
            live[f] = n_live;
            states.push(Some(st.clone()));
            // (Re-)seed feature points on this frame when too few are left.
            let want_seed =
                use_features && have_frame && (seeds == 0 || (n_live as f64) < o.feature_reseed * seeded_live as f64);
            if let (true, Some(lm)) = (want_seed, records[f].landmarks.as_ref()) {
                let (vs, start) = seed_features(self.model, &st, &k, lm, o, self.lm_vertices)?;
                if !vs.is_empty() {
                    // Keep the live points, add the new ones (skipping vertices already used).
                    let mut keep_v = Vec::new();
                    let mut keep_x = Vec::new();
                    for j in 0..nf {
                        if alive[j] {
                            keep_v.push(fv[j]);
                            keep_x.push(fx[j]);
                        }
                    }
                    let used: std::collections::HashSet<u32> = keep_v.iter().copied().collect();
                    let mut added = 0;
                    for (v, x) in vs.into_iter().zip(start) {
                        if !used.contains(&v) {
                            keep_v.push(v);
                            keep_x.push(x);
                            added += 1;
                        }
                    }
                    fv = keep_v;
                    fx = keep_x;
                    alive = vec![true; fv.len()];
                    seeded_total += added;
                    seeded_live = fv.len();
                    seeds += 1;
                    let (w_id, w_exp, pose) = (st.w_id.clone(), st.w_exp.clone(), st.pose);
                    fitter = self.fitter(&fv)?;
                    ws = fitter.workspace();
                    st = self.state(&fitter);
                    st.w_id = w_id;
                    st.w_exp = w_exp;
                    st.pose = pose;
                }
            }
        }
        eprintln!(
            "{}: {seeded_total} feature points around mouth and brows, seeded {seeds} times (re-seeded below {:.0}% live)",
            video.display(),
            100.0 * o.feature_reseed
        );
        Ok(Fitted {
            records: records.to_vec(),
            states,
            rms_landmarks: rms_l,
            rms_features: rms_f,
            rms_all: rms_a,
            live_features: live,
            seeded_features: seeded_total,
            intrinsics: k,
        })
    }

    /// A per-frame fitter for the landmarks plus the feature vertices `fv`.
    fn fitter(&self, fv: &[u32]) -> anyhow::Result<Fitter> {
        let mut vertices = self.lm_vertices.to_vec();
        vertices.extend_from_slice(fv);
        Ok(Fitter::new(self.model, &vertices, self.params.clone())?)
    }

    fn state(&self, fitter: &Fitter) -> FitState {
        let mut st = fitter.initial_state();
        st.w_id.clone_from(&self.w_id);
        st.w_exp.clone_from(&self.w_exp);
        st
    }
}

/// The `tensor.csv` value columns.
pub fn tensor_columns(model: &TensorModel) -> Vec<String> {
    let mut cols: Vec<String> = POSE_COLUMNS.iter().map(|s| s.to_string()).collect();
    cols.extend(model.identities.iter().map(|n| format!("id_{n}")));
    cols.extend(model.expressions.iter().map(|n| format!("exp_{n}")));
    cols
}

/// Confidence written to the CSV: `1 / (1 + RMS reprojection error in pixels)`.
fn confidence(rms_px: f64) -> f64 {
    if rms_px.is_finite() {
        1.0 / (1.0 + rms_px)
    } else {
        0.0
    }
}

/// Writes a parameters CSV (pose, `id_*`, `exp_*`).
pub fn write_tensor_csv(
    path: &Path,
    model: &TensorModel,
    records: &[LandmarkRecord],
    states: &[Option<FitState>],
    rms: &[f64],
) -> anyhow::Result<()> {
    let cols = tensor_columns(model);
    let mut wr = FrameCsvWriter::create(path, &cols)?;
    let mut values = vec![f64::NAN; cols.len()];
    for ((r, s), &e) in records.iter().zip(states).zip(rms) {
        values.iter_mut().for_each(|v| *v = f64::NAN);
        if let Some(s) = s {
            if let Some(p) = s.pose {
                let t = p.tvec();
                let (rx, ry, rz) = p.euler_xyz();
                values[..6].copy_from_slice(&[t.x, t.y, t.z, rx, ry, rz]);
            }
            values[6..6 + s.w_id.len()].copy_from_slice(&s.w_id);
            values[6 + s.w_id.len()..].copy_from_slice(&s.w_exp);
        }
        wr.write_row(&FrameRow {
            frame: r.frame,
            timestamp: r.timestamp,
            success: s.is_some(),
            confidence: if s.is_some() { confidence(e) } else { 0.0 },
            values: &values,
        })?;
    }
    wr.finish()?;
    Ok(())
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
    println!(
        "{}: {n} / {} frames fitted; RMS reprojection px: landmarks {}, features {}, all {}; feature points {} seeded, {last_live} live at the end",
        video.display(),
        fitted.records.len(),
        fmt(&fitted.rms_landmarks),
        fmt(&fitted.rms_features),
        fmt(&fitted.rms_all),
        fitted.seeded_features,
    );
}
