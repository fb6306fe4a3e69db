#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The video tracker on every shared clip against dlib run per frame with detection
//! (fixture `testdata/dlib_track/fixture.json`, made by
//! `testdata/dlib_track/make_fixture.py`): a face on >= 98 % of frames and mean
//! landmark distance < 2 % of dlib's inter-ocular distance. Skips without the
//! shared data, the models or ffmpeg.

use std::path::Path;
use std::process::Command;

use facecap_core::landmarks::NUM_LANDMARKS;
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::tracker::one_euro::OneEuroParams;
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
use image::GrayImage;
use serde::Deserialize;

#[derive(Deserialize)]
struct Fixture {
    clips: Vec<Clip>,
}

#[derive(Deserialize)]
struct Clip {
    clip: String,
    width: u32,
    height: u32,
    frames: Vec<Option<DlibFrame>>,
}

#[derive(Deserialize)]
struct DlibFrame {
    pts: Vec<f64>,
}

fn decode_gray(path: &Path, w: u32, h: u32) -> Option<Vec<GrayImage>> {
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-i"])
        .arg(path)
        .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .ok()?;
    out.status.success().then(|| {
        out.stdout
            .chunks_exact((w * h) as usize)
            .map(|c| GrayImage::from_raw(w, h, c.to_vec()).unwrap())
            .collect()
    })
}

/// Frames per clip used by the test.
const FRAMES: usize = 240;

#[test]
fn tracker_matches_dlib_per_frame_on_shared_clips() {
    let Some(sp_path) = facecap_core::paths::model_file_or_skip("tracker_dlib", facecap_core::paths::DLIB_68_MODEL)
    else {
        return;
    };
    let Ok(det) = FaceDetector::default_model() else {
        facecap_core::paths::skip_missing_data("tracker_dlib: face detector model missing");
        return;
    };
    let sp = ShapePredictor::from_file(&sp_path).unwrap().with_params(ErtParams {
        output: OutputPrecision::SubPixel,
        ..Default::default()
    });
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/dlib_track/fixture.json"
    ))
    .unwrap();
    let fx: Fixture = serde_json::from_str(&text).unwrap();
    // The acceptance is on the unfiltered tracker (the library default); filtered numbers
    // are reported by examples/lk_tracker_eval.rs. To keep the suite fast, the first
    // FRAMES frames of each clip are used here (the example runs whole clips).
    for filter in [None::<OneEuroParams>] {
        let params = TrackerParams {
            filter,
            ..TrackerParams::default()
        };
        let tracker = LandmarkTracker::new(det.clone(), sp.clone(), params).unwrap();
        for clip in &fx.clips {
            let Some(path) = facecap_core::paths::shared_data_file("tracker_dlib", &clip.clip) else {
                continue;
            };
            let Some(frames) = decode_gray(&path, clip.width, clip.height) else {
                facecap_core::paths::skip(&format!("tracker_dlib: ffmpeg failed on {}", clip.clip));
                continue;
            };
            assert_eq!(frames.len(), clip.frames.len(), "{}", clip.clip);
            let frames = &frames[..frames.len().min(FRAMES)];
            let mut ws = tracker.new_workspace();
            let mut state = TrackerState::new();
            let mut out = TrackedFrame::default();
            let (mut found, mut nme_sum, mut nme_n, mut detections) = (0usize, 0.0, 0usize, 0usize);
            for (k, (img, truth)) in frames.iter().zip(&clip.frames).enumerate() {
                let rep = tracker
                    .track_into(img, k as f64 / 30.0, &mut ws, &mut state, &mut out)
                    .unwrap();
                detections += usize::from(rep.detector_ran);
                if out.success {
                    found += 1;
                    if let Some(t) = truth {
                        let tp = |i: usize| (t.pts[2 * i], t.pts[2 * i + 1]);
                        let iod = ((tp(45).0 - tp(36).0).powi(2) + (tp(45).1 - tp(36).1).powi(2)).sqrt();
                        let mean = (0..NUM_LANDMARKS)
                            .map(|i| {
                                let p = out.landmarks.points[i];
                                ((p.x - tp(i).0).powi(2) + (p.y - tp(i).1).powi(2)).sqrt()
                            })
                            .sum::<f64>()
                            / NUM_LANDMARKS as f64;
                        nme_sum += mean / iod;
                        nme_n += 1;
                    }
                }
            }
            let share = found as f64 / frames.len() as f64;
            let nme = nme_sum / nme_n.max(1) as f64;
            eprintln!(
                "{} filter {}: {} frames, face on {:.1} %, detector ran on {detections}, mean distance to dlib {:.2} % IOD",
                clip.clip,
                filter.is_some(),
                frames.len(),
                100.0 * share,
                100.0 * nme
            );
            assert!(share >= 0.98, "{}: face on {share}", clip.clip);
            assert!(nme < 0.02, "{}: mean distance {nme} IOD", clip.clip);
        }
    }
}
