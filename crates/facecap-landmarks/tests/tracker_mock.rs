#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Tracker behaviour with mock detector / regressor on synthetic moving texture:
//! detection only on the first frame and after a loss, LK carrying the face, loss
//! on a featureless frame, One Euro filter properties, parameter validation.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use facecap_core::landmarks::Rect;
use facecap_landmarks::tracker::one_euro::{OneEuroParams, OneEuroState};
use facecap_landmarks::tracker::{
    FaceFinder, FrameAction, LandmarkTracker, ShapeRegressor, TrackedFrame, TrackerParams, TrackerState,
};
use facecap_landmarks::Result;
use image::GrayImage;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Finds one fixed box unless the frame is flat (then none). Counts calls.
#[derive(Debug)]
struct MockFinder {
    rect: Rect,
    calls: Arc<AtomicUsize>,
}

impl FaceFinder for MockFinder {
    type Workspace = ();
    fn new_workspace(&self) {}
    fn find_faces(&self, img: &GrayImage, _: &mut (), out: &mut Vec<Rect>) -> Result<()> {
        self.calls.fetch_add(1, Ordering::SeqCst);
        out.clear();
        let first = img.as_raw()[0];
        if img.as_raw().iter().any(|&v| v != first) {
            out.push(self.rect);
        }
        Ok(())
    }
}

/// Mean shape: a 68-point face-like layout in box units. `predict` places it in the
/// box; `predict_from_shape` returns the initial shape (a perfect "refiner" when the
/// initial shape is right), so tracked results show what LK carried.
#[derive(Debug)]
struct MockRegressor {
    mean: Vec<f32>,
}

impl MockRegressor {
    fn new() -> Self {
        let mut mean = Vec::new();
        for i in 0..68 {
            let t = i as f32 / 68.0 * std::f32::consts::TAU;
            let r = 0.25 + 0.1 * ((i % 7) as f32 / 7.0);
            mean.push(0.5 + r * t.cos());
            mean.push(0.5 + r * t.sin());
        }
        // Eye corners (36, 45) apart horizontally, like a face.
        mean[72] = 0.25;
        mean[73] = 0.4;
        mean[90] = 0.75;
        mean[91] = 0.4;
        MockRegressor { mean }
    }
}

impl ShapeRegressor for MockRegressor {
    type Workspace = ();
    fn new_workspace(&self) {}
    fn mean_shape(&self) -> &[f32] {
        &self.mean
    }
    fn predict(&self, _: &GrayImage, r: &Rect, _: &mut (), out: &mut [Point2<f64>]) -> Result<()> {
        for (o, m) in out.iter_mut().zip(self.mean.chunks_exact(2)) {
            *o = Point2::new(
                r.left + (r.width - 1.0) * m[0] as f64,
                r.top + (r.height - 1.0) * m[1] as f64,
            );
        }
        Ok(())
    }
    fn predict_from_shape(
        &self,
        _: &GrayImage,
        _: &Rect,
        init: &[Point2<f64>],
        _: &mut (),
        out: &mut [Point2<f64>],
    ) -> Result<()> {
        out.copy_from_slice(init);
        Ok(())
    }
}

fn texture(w: u32, h: u32, dx: f64, dy: f64) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        let (x, y) = (x as f64 - dx, y as f64 - dy);
        image::Luma([(128.0
            + 45.0 * (x / 7.0).sin() * (y / 9.0).cos()
            + 35.0 * ((x + 2.0 * y) / 13.0).sin()
            + 20.0 * ((3.0 * x - y) / 17.0).cos()) as u8])
    })
}

fn tracker(params: TrackerParams) -> (LandmarkTracker<MockFinder, MockRegressor>, Arc<AtomicUsize>) {
    let calls = Arc::new(AtomicUsize::new(0));
    let finder = MockFinder {
        rect: Rect::new(100.0, 60.0, 121.0, 121.0).unwrap(),
        calls: calls.clone(),
    };
    (
        LandmarkTracker::new(finder, MockRegressor::new(), params).unwrap(),
        calls,
    )
}

#[test]
fn detects_once_then_lk_carries_the_face() {
    // LK for every shift above the threshold (no translation-only carrying)
    let (t, calls) = tracker(TrackerParams {
        translate_max: 0.0,
        ..TrackerParams::default()
    });
    let mut ws = t.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();
    let mut first = None;
    let (vx, vy) = (2.3, -1.1); // px per frame
    for k in 0..20 {
        let img = texture(320, 240, vx * k as f64, vy * k as f64);
        let rep = t
            .track_into(&img, k as f64 / 30.0, &mut ws, &mut state, &mut out)
            .unwrap();
        assert!(out.success, "frame {k}: {rep:?} conf {}", out.confidence);
        if k == 0 {
            assert_eq!(rep.action, FrameAction::Detected);
            first = Some(out.landmarks.clone());
        } else {
            assert_eq!(rep.action, FrameAction::Tracked, "frame {k}");
            let f = first.as_ref().unwrap();
            let worst = out
                .landmarks
                .points
                .iter()
                .zip(f.points.iter())
                .map(|(p, q)| ((p.x - q.x - vx * k as f64).powi(2) + (p.y - q.y - vy * k as f64).powi(2)).sqrt())
                .fold(0.0, f64::max);
            assert!(worst < 0.3, "frame {k}: drift {worst}");
        }
    }
    assert_eq!(
        calls.load(Ordering::SeqCst),
        1,
        "the detector runs on the first frame only"
    );
}

#[test]
fn flat_frame_loses_the_face_and_texture_brings_it_back() {
    let (t, _calls) = tracker(TrackerParams::default());
    let mut ws = t.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();
    let flat = GrayImage::from_pixel(320, 240, image::Luma([90]));
    let mut actions = Vec::new();
    for k in 0..8 {
        let img = if (3..5).contains(&k) {
            flat.clone()
        } else {
            texture(320, 240, k as f64, 0.0)
        };
        let rep = t
            .track_into(&img, k as f64 / 30.0, &mut ws, &mut state, &mut out)
            .unwrap();
        actions.push((rep.action, out.success));
    }
    use FrameAction::*;
    assert_eq!(
        actions,
        vec![
            (Detected, true),
            (Tracked, true),
            (Tracked, true),
            (NoFace, false),
            (NoFace, false),
            (Detected, true),
            (Tracked, true),
            (Tracked, true)
        ]
    );
}

#[test]
fn one_euro_reduces_jitter_and_follows_motion() {
    let p = OneEuroParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let dt = 1.0 / 30.0;
    // Still signal with noise: the filtered variance is much smaller.
    let mut f = OneEuroState::default();
    let (mut raw_var, mut filt_var) = (0.0, 0.0);
    for k in 0..600 {
        let n: f64 = rng.random_range(-1.0..1.0);
        let y = f.filter(&p, 100.0 + n, dt);
        if k > 60 {
            raw_var += n * n;
            filt_var += (y - 100.0) * (y - 100.0);
        }
    }
    assert!(filt_var < 0.2 * raw_var, "{filt_var} vs {raw_var}");
    // A ramp: the lag stays bounded and shrinks with beta.
    let lag = |beta: f64| {
        let p = OneEuroParams { beta, ..p };
        let mut f = OneEuroState::default();
        let mut last = 0.0;
        for k in 0..120 {
            let x = 5.0 * k as f64; // 150 px/s
            last = x - f.filter(&p, x, dt);
        }
        last
    };
    assert!(lag(0.05) < lag(0.0));
    assert!(lag(0.05) < 5.0, "lag {}", lag(0.05));
    // First sample passes through; reset restarts.
    let mut f = OneEuroState::default();
    assert_eq!(f.filter(&p, 42.0, dt), 42.0);
    f.reset();
    assert_eq!(f.filter(&p, -7.0, dt), -7.0);
}

#[test]
fn parameters_are_validated() {
    let bad = [
        TrackerParams {
            min_lk_fraction: 1.5,
            ..TrackerParams::default()
        },
        TrackerParams {
            lk_motion_threshold: -1.0,
            ..TrackerParams::default()
        },
        TrackerParams {
            translate_max: f64::NAN,
            ..TrackerParams::default()
        },
        TrackerParams {
            lk_residual_threshold: -1.0,
            ..TrackerParams::default()
        },
        TrackerParams {
            agree_scale: 0.0,
            ..TrackerParams::default()
        },
        TrackerParams {
            redetect_below: f64::NAN,
            ..TrackerParams::default()
        },
        TrackerParams {
            fps: 0.0,
            ..TrackerParams::default()
        },
        TrackerParams {
            filter: Some(OneEuroParams {
                min_cutoff: 0.0,
                ..OneEuroParams::default()
            }),
            ..TrackerParams::default()
        },
        TrackerParams {
            filter: Some(OneEuroParams {
                beta: -1.0,
                ..OneEuroParams::default()
            }),
            ..TrackerParams::default()
        },
    ];
    for p in bad {
        let finder = MockFinder {
            rect: Rect::new(0.0, 0.0, 10.0, 10.0).unwrap(),
            calls: Arc::new(AtomicUsize::new(0)),
        };
        let e = LandmarkTracker::new(finder, MockRegressor::new(), p)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("tracker.") || e.contains("one_euro.") || e.contains("lk."),
            "{e}"
        );
    }
}

/// Small shifts (above the LK threshold, up to `translate_max`) move the shape by
/// the motion test's translation without LK; each frame's step lands close to the
/// true shift (the mock regressor returns the shape it is started from, so this is
/// the carrying alone, with no ERT to correct it).
#[test]
fn small_shifts_are_carried_by_the_motion_translation() {
    let (t, calls) = tracker(TrackerParams {
        ert_init: facecap_landmarks::tracker::ErtInit::PreviousShape,
        ..TrackerParams::default()
    });
    let mut ws = t.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();
    let (vx, vy) = (1.6, -0.9); // px per frame, |v| = 1.8 px: between 1 and 3 px
    let mut prev: Option<Vec<(f64, f64)>> = None;
    for k in 0..12 {
        let img = texture(320, 240, vx * k as f64, vy * k as f64);
        let rep = t
            .track_into(&img, k as f64 / 30.0, &mut ws, &mut state, &mut out)
            .unwrap();
        assert!(out.success, "frame {k}");
        let pts: Vec<(f64, f64)> = out.landmarks.points.iter().map(|p| (p.x, p.y)).collect();
        if k > 0 {
            assert_eq!(rep.action, FrameAction::Tracked, "frame {k}");
            assert!(
                !rep.lk_ran,
                "frame {k}: LK ran for a {:.2} px shift",
                rep.motion_estimate
            );
            let p0 = prev.as_ref().unwrap();
            let (sx, sy) = (pts[30].0 - p0[30].0, pts[30].1 - p0[30].1);
            let err = ((sx - vx).powi(2) + (sy - vy).powi(2)).sqrt();
            assert!(err < 0.5, "frame {k}: step ({sx:.2}, {sy:.2}) vs ({vx}, {vy})");
        }
        prev = Some(pts);
    }
    assert_eq!(calls.load(Ordering::SeqCst), 1);
}
