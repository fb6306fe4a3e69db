//! The shared clips against MediaPipe FaceLandmarker's iris centres and `eyeLook*` scores
//! (fixture `testdata/gaze/mediapipe_iris.csv`, made by `testdata/gaze/make_fixture.py`):
//! decode with `open_source`, track with the CLI's tracker set-up, estimate the irises,
//! and the agreement statistics. Used by `tests/gaze_mediapipe.rs` and
//! `examples/gaze_eval.rs`.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;

use facecap_core::landmarks::Landmarks68;
use facecap_io::video::{open_source, Frame, SourceOptions};
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::gaze::{EyeEstimate, IrisEstimator, IrisFrame};
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};

/// Clip order of the fixture.
pub const CLIPS: [&str; 5] = [
    "liveportrait_d18",
    "liveportrait_d3",
    "liveportrait_d6",
    "liveportrait_d9",
    "sadtalker_WDA_KatieHill_000",
];

/// A clip's MediaPipe signal counts for a correlation only where it moves (std >= this),
/// as in the expression evaluation.
pub const MIN_REFERENCE_STD: f64 = 0.05;

/// One fixture row.
#[derive(Clone, Copy, Debug)]
pub struct MpRow {
    /// MediaPipe found a face.
    pub face: bool,
    /// Iris centre of the subject's right eye (image left), pixels.
    pub right: [f64; 2],
    /// Subject's left eye.
    pub left: [f64; 2],
    /// eyeLook{In,Out,Up,Down}Left, then the same Right.
    pub scores: [f64; 8],
}

/// The fixture, per clip.
pub fn read_fixture() -> BTreeMap<String, Vec<MpRow>> {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/gaze/mediapipe_iris.csv"
    ))
    .expect("testdata/gaze/mediapipe_iris.csv");
    let mut out: BTreeMap<String, Vec<MpRow>> = BTreeMap::new();
    for line in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 15, "fixture row {line}");
        let face = f[2] == "1";
        let num = |k: usize| {
            if face {
                f[k].parse::<f64>().expect("number")
            } else {
                f64::NAN
            }
        };
        let row = MpRow {
            face,
            right: [num(3), num(4)],
            left: [num(5), num(6)],
            scores: std::array::from_fn(|k| num(7 + k)),
        };
        let rows = out.entry(f[0].to_string()).or_default();
        assert_eq!(
            rows.len(),
            f[1].parse::<usize>().expect("frame"),
            "fixture frames in order"
        );
        rows.push(row);
    }
    out
}

/// The CLI's tracker (HOG detector, 68-point ERT with sub-pixel output, default tracker
/// parameters), or `None` with a `SKIP:` line when a model is missing.
pub fn tracker(test: &str) -> Option<LandmarkTracker<FaceDetector, ShapePredictor>> {
    let sp_path = facecap_core::paths::model_file_or_skip(test, facecap_core::paths::DLIB_68_MODEL)?;
    let Ok(det) = FaceDetector::default_model() else {
        facecap_core::paths::skip_missing_data(&format!("{test}: face detector model missing"));
        return None;
    };
    let sp = ShapePredictor::from_file_cached(&sp_path)
        .ok()?
        .0
        .with_params(ErtParams {
            output: OutputPrecision::SubPixel,
            ..Default::default()
        });
    LandmarkTracker::new(det, sp, TrackerParams::default()).ok()
}

/// Per frame of a clip: the tracked frame's success and, per estimator, both eyes.
pub struct ClipRun {
    /// Frame size.
    pub width: u32,
    /// Frame size.
    pub height: u32,
    /// Tracked landmarks per frame (`None` when the tracker had no face).
    pub landmarks: Vec<Option<Landmarks68>>,
    /// `estimates[e][frame]` for estimator `e`.
    pub estimates: Vec<Vec<IrisFrame>>,
}

/// Decodes and tracks a clip and runs every estimator on every tracked frame.
pub fn run_clip(
    path: &Path,
    tracker: &LandmarkTracker<FaceDetector, ShapePredictor>,
    estimators: &[IrisEstimator],
) -> facecap_landmarks::Result<ClipRun> {
    let mut src = open_source(path, &SourceOptions::default())?;
    let (width, height) = (src.info().width, src.info().height);
    let mut frame = Frame::default();
    let mut ws = tracker.new_workspace();
    let mut state = TrackerState::new();
    let mut tracked = TrackedFrame::default();
    let mut iws: Vec<_> = estimators.iter().map(|e| e.new_workspace()).collect();
    let mut run = ClipRun {
        width,
        height,
        landmarks: Vec::new(),
        estimates: vec![Vec::new(); estimators.len()],
    };
    while src.read_into(&mut frame)? {
        tracker.track_into(&frame.gray, frame.timestamp_s, &mut ws, &mut state, &mut tracked)?;
        run.landmarks.push(tracked.success.then(|| tracked.landmarks.clone()));
        for (k, est) in estimators.iter().enumerate() {
            let mut out = IrisFrame::default();
            if tracked.success {
                est.estimate_into(&frame.gray, &tracked.landmarks, &mut iws[k], &mut out)?;
            }
            run.estimates[k].push(out);
        }
    }
    Ok(run)
}

/// Pearson correlation (0 when either side is constant).
pub fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    if x.len() < 3 {
        return 0.0;
    }
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx <= 0.0 || syy <= 0.0 {
        0.0
    } else {
        sxy / (sxx * syy).sqrt()
    }
}

/// Median (NaN for an empty slice).
pub fn median(x: &[f64]) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn std_dev(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (x.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / n).sqrt()
}

/// Agreement of one eye on one clip.
#[derive(Clone, Debug, Default)]
pub struct EyeStats {
    /// Frames with a valid estimate and a MediaPipe face.
    pub frames: usize,
    /// Frames where the tracker had a face.
    pub tracked: usize,
    /// Per frame |ours - MediaPipe| in px.
    pub dist_px: Vec<f64>,
    /// Per frame |ours - MediaPipe| / eye width.
    pub dist_rel: Vec<f64>,
    /// Pearson r of -(u - median u) with MediaPipe's eyeLookOut - eyeLookIn, if that moves.
    pub r_h: Option<f64>,
    /// Pearson r of v - median v with MediaPipe's eyeLookDown - eyeLookUp, if that moves.
    pub r_v: Option<f64>,
    /// The same correlations for MediaPipe's own iris centre in our eye frame (what an
    /// exact iris would reach with our landmarks).
    pub r_h_mp_iris: Option<f64>,
    /// See `r_h_mp_iris`.
    pub r_v_mp_iris: Option<f64>,
    /// Pearson r of our u / v with MediaPipe's iris u / v in the same eye frame.
    pub r_u_iris: f64,
    /// See `r_u_iris`.
    pub r_v_iris: f64,
    /// Median of our u - MediaPipe's iris u, and the same for v (eye widths).
    pub bias_uv: [f64; 2],
    /// (Δu, Δv) per frame relative to the clip median, with MediaPipe's four scores of
    /// that eye (In, Out, Up, Down) minus their clip medians, for the gain fit.
    pub samples: Vec<([f64; 2], [f64; 4])>,
}

/// Statistics of one eye (`right` = subject's right) of one clip.
pub fn eye_stats(est: &[IrisFrame], lms: &[Option<Landmarks68>], mp: &[MpRow], right: bool) -> EyeStats {
    let mut s = EyeStats::default();
    let score_base = if right { 4 } else { 0 };
    let (io, ii) = if right { (36, 39) } else { (45, 42) };
    // (our u v, MediaPipe's iris u v in our eye frame, MediaPipe's 4 scores of this eye)
    let mut rows: Vec<([f64; 2], [f64; 2], [f64; 4])> = Vec::new();
    for (k, f) in est.iter().enumerate() {
        let Some(lm) = lms.get(k).and_then(|l| l.as_ref()) else {
            continue;
        };
        s.tracked += 1;
        let e: EyeEstimate = if right { f.right } else { f.left };
        let Some(m) = mp.get(k).filter(|m| m.face) else {
            continue;
        };
        if !e.valid() {
            continue;
        }
        let c = if right { m.right } else { m.left };
        let d = ((e.centre.x - c[0]).powi(2) + (e.centre.y - c[1]).powi(2)).sqrt();
        s.dist_px.push(d);
        s.dist_rel.push(d / e.width_px);
        let (o, i) = (lm.points[io], lm.points[ii]);
        let uv_mp = uv_in_frame([o.x, o.y], [i.x, i.y], right, c);
        rows.push(([e.u, e.v], uv_mp, std::array::from_fn(|j| m.scores[score_base + j])));
    }
    s.frames = rows.len();
    if rows.len() < 3 {
        return s;
    }
    let col = |j: usize, q: usize| -> Vec<f64> {
        rows.iter()
            .map(|r| match j {
                0 => r.0[q],
                1 => r.1[q],
                _ => r.2[q],
            })
            .collect()
    };
    let (u, v, u_mp, v_mp) = (col(0, 0), col(0, 1), col(1, 0), col(1, 1));
    let (mu, mv) = (median(&u), median(&v));
    let h: Vec<f64> = u.iter().map(|x| -(x - mu)).collect();
    let h_mp: Vec<f64> = u_mp.iter().map(|x| -x).collect();
    let ref_h: Vec<f64> = rows.iter().map(|r| r.2[1] - r.2[0]).collect();
    let ref_v: Vec<f64> = rows.iter().map(|r| r.2[3] - r.2[2]).collect();
    if std_dev(&ref_h) >= MIN_REFERENCE_STD {
        s.r_h = Some(pearson(&h, &ref_h));
        s.r_h_mp_iris = Some(pearson(&h_mp, &ref_h));
    }
    if std_dev(&ref_v) >= MIN_REFERENCE_STD {
        s.r_v = Some(pearson(&v, &ref_v));
        s.r_v_mp_iris = Some(pearson(&v_mp, &ref_v));
    }
    s.bias_uv = [
        median(&u.iter().zip(&u_mp).map(|(a, b)| a - b).collect::<Vec<_>>()),
        median(&v.iter().zip(&v_mp).map(|(a, b)| a - b).collect::<Vec<_>>()),
    ];
    s.r_u_iris = pearson(&u, &u_mp);
    s.r_v_iris = pearson(&v, &v_mp);
    let med_sc: [f64; 4] = std::array::from_fn(|j| median(&col(2, j)));
    s.samples = rows
        .iter()
        .map(|r| ([r.0[0] - mu, r.0[1] - mv], std::array::from_fn(|j| r.2[j] - med_sc[j])))
        .collect();
    s
}

/// MediaPipe's iris `c` (pixels) in the eye frame of the corners `outer`, `inner`.
pub fn uv_in_frame(outer: [f64; 2], inner: [f64; 2], right: bool, c: [f64; 2]) -> [f64; 2] {
    let (dx, dy) = (inner[0] - outer[0], inner[1] - outer[1]);
    let l = (dx * dx + dy * dy).sqrt();
    let (ax, ay) = (dx / l, dy / l);
    let (nx, ny) = if right { (-ay, ax) } else { (ay, -ax) };
    let (px, py) = (c[0] - outer[0], c[1] - outer[1]);
    [(px * ax + py * ay) / l, (px * nx + py * ny) / l]
}

/// The gain `g` minimising `Σ (clamp(g x, 0, 1) - clamp(y, 0, 1))²` on a grid of
/// 0.25 .. 60 (step 0.25), and the fit's RMS.
pub fn fit_gain(xy: &[(f64, f64)]) -> (f64, f64) {
    let mut best = (0.0, f64::INFINITY);
    for k in 1..=240 {
        let g = 0.25 * k as f64;
        let e: f64 = xy
            .iter()
            .map(|&(x, y)| ((g * x).clamp(0.0, 1.0) - y.clamp(0.0, 1.0)).powi(2))
            .sum();
        if e < best.1 {
            best = (g, e);
        }
    }
    (best.0, (best.1 / xy.len().max(1) as f64).sqrt())
}
