#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Our tracker + iris estimator on every shared clip against MediaPipe FaceLandmarker's
//! iris centres and `eyeLook*` scores (fixture `testdata/gaze/mediapipe_iris.csv`, made by
//! `testdata/gaze/make_fixture.py`). Bounds measured in `docs/gaze.md`. Skips without the
//! shared data or the models.

#[path = "gaze_common/clips.rs"]
mod clips;

use clips::{eye_stats, median, read_fixture, run_clip, tracker, CLIPS};
use facecap_landmarks::gaze::{IrisEstimator, IrisParams};

/// Median iris-centre distance to MediaPipe over the 480x480 clips (d18, d6), px
/// (measured 2.06).
const MAX_MEDIAN_PX_480: f64 = 2.4;
/// The same over every clip, in eye widths (measured 0.046).
const MAX_MEDIAN_REL: f64 = 0.055;
/// Mean over clip-eyes (where MediaPipe's signal moves) of the horizontal Pearson r
/// (measured 0.647; MediaPipe's own iris in our eye frame: 0.631).
const MIN_MEAN_R_H: f64 = 0.58;
/// Mean vertical Pearson r (measured 0.649; MediaPipe's own iris: 0.450).
const MIN_MEAN_R_V: f64 = 0.58;
/// Share of tracked eyes with a valid estimate (measured 0.945: the rest are blinks and
/// d3's winks).
const MIN_VALID_SHARE: f64 = 0.9;

#[test]
fn iris_centres_and_gaze_agree_with_mediapipe_on_shared_clips() {
    let Some(tracker) = tracker("gaze_mediapipe") else {
        return;
    };
    let est = IrisEstimator::new(IrisParams::default()).unwrap();
    let fx = read_fixture();
    let (mut px480, mut rel, mut rh, mut rv) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut valid, mut tracked) = (0usize, 0usize);
    for clip in CLIPS {
        let Some(path) = facecap_core::paths::shared_data_file("gaze_mediapipe", &format!("videos/{clip}.mp4")) else {
            continue;
        };
        let run = run_clip(&path, &tracker, std::slice::from_ref(&est)).unwrap();
        let mp = &fx[clip];
        assert_eq!(mp.len(), run.landmarks.len(), "{clip}: frame count");
        for (eye, right) in [("right", true), ("left", false)] {
            let s = eye_stats(&run.estimates[0], &run.landmarks, mp, right);
            eprintln!(
                "{clip} {eye}: {} valid / {} tracked, median {:.2} px ({:.1} % eye width), r_h {:?}, r_v {:?}",
                s.frames,
                s.tracked,
                median(&s.dist_px),
                100.0 * median(&s.dist_rel),
                s.r_h,
                s.r_v
            );
            valid += s.frames;
            tracked += s.tracked;
            if run.width == 480 && run.height == 480 {
                px480.extend(&s.dist_px);
            }
            rel.extend(&s.dist_rel);
            rh.extend(s.r_h);
            rv.extend(s.r_v);
        }
    }
    if tracked == 0 {
        facecap_core::paths::skip_missing_data("gaze_mediapipe: no shared clip found");
        return;
    }
    let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
    let share = valid as f64 / tracked as f64;
    eprintln!(
        "valid {:.1} %, median {:.2} px on 480x480, {:.1} % eye width on all; mean r_h {:.3} ({} clip-eyes), r_v {:.3} ({})",
        100.0 * share,
        median(&px480),
        100.0 * median(&rel),
        mean(&rh),
        rh.len(),
        mean(&rv),
        rv.len()
    );
    assert!(share >= MIN_VALID_SHARE, "valid share {share}");
    if !px480.is_empty() {
        assert!(median(&px480) <= MAX_MEDIAN_PX_480, "median {} px", median(&px480));
    }
    assert!(median(&rel) <= MAX_MEDIAN_REL, "median {} eye widths", median(&rel));
    if !rh.is_empty() {
        assert!(mean(&rh) >= MIN_MEAN_R_H, "mean r_h {}", mean(&rh));
    }
    if !rv.is_empty() {
        assert!(mean(&rv) >= MIN_MEAN_R_V, "mean r_v {}", mean(&rv));
    }
}
