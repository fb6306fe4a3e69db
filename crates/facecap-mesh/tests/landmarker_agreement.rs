//! The whole front end (detector, region, landmarks, projection) against MediaPipe's
//! FaceLandmarker in IMAGE mode on frames of the shared clips
//! (fixture: `testdata/mesh/make_landmarker_fixture.py`).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use facecap_mesh::tracker::IRIS_CENTERS;
use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshState, MeshTracker, RgbView};

/// Per-frame goals of the issue (480x480 clips): mean and max distance, iris centres.
const MEAN_PX: f32 = 0.5;
const MAX_PX: f32 = 2.0;
const IRIS_PX: f32 = 0.5;
/// Regression bound: measured 0.001-0.003 px mean on every fixture frame (the warp
/// reproduces OpenCV's fixed-point bilinear sampling, so inputs match bit for bit or
/// nearly).
const MEAN_REGRESSION_PX: f32 = 0.05;

#[test]
fn landmarks_match_mediapipe_face_landmarker() {
    let test = "landmarks_match_mediapipe_face_landmarker";
    let (Some(det), Some(lm)) = (
        model(test, facecap_mesh::FACE_DETECTOR_MODEL),
        model(test, facecap_mesh::FACE_LANDMARKS_MODEL),
    ) else {
        return;
    };
    let tracker = MeshTracker::new(MeshModels::load(&det, &lm).unwrap(), MeshParams::default()).unwrap();
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    let fx = fixture("landmarker_mediapipe.json");
    let mut checked = 0;
    for f in fx["frames"].as_array().unwrap() {
        let clip = f["clip"].as_str().unwrap();
        let index = f["frame"].as_u64().unwrap();
        let Some(img) = clip_frame(test, clip, index) else {
            return;
        };
        let mut state = MeshState::default();
        let report = tracker
            .track_into(&RgbView::from_image(&img).unwrap(), 0.0, &mut ws, &mut state, &mut mesh)
            .unwrap();
        let Some(want) = f["points"].as_array() else {
            assert!(!report.has_face(), "{clip}#{index}: MediaPipe found no face, we did");
            continue;
        };
        assert!(report.has_face(), "{clip}#{index}: no face ({report:?})");
        let d: Vec<f32> = want
            .iter()
            .zip(&mesh.points)
            .map(|(w, p)| {
                let w = floats(w);
                ((p[0] - w[0]).powi(2) + (p[1] - w[1]).powi(2)).sqrt()
            })
            .collect();
        let mean = d.iter().sum::<f32>() / d.len() as f32;
        let max = d.iter().copied().fold(0.0, f32::max);
        let iris = IRIS_CENTERS.map(|i| d[i]);
        eprintln!(
            "{clip}#{index}: mean {mean:.3} px, max {max:.3} px, iris {:.3} / {:.3} px (detection {:.3}, presence {:.3})",
            iris[0], iris[1], report.detection_score, report.presence
        );
        let w = f["width"].as_f64().unwrap() as f32;
        // Goals are stated for 480-px clips; scale them for other sizes.
        let k = w / 480.0;
        assert!(mean <= MEAN_PX * k, "{clip}#{index}: mean {mean} px");
        assert!(
            mean <= MEAN_REGRESSION_PX,
            "{clip}#{index}: mean {mean} px, was 0.003 px at most"
        );
        assert!(max <= MAX_PX * k, "{clip}#{index}: max {max} px");
        assert!(
            iris.iter().all(|&e| e <= IRIS_PX * k),
            "{clip}#{index}: iris {iris:?} px"
        );
        checked += 1;
    }
    assert!(checked > 0);
}

/// VIDEO mode: tracking from the previous frame's landmarks and one-euro smoothing,
/// against FaceLandmarker's video mode over the first frames of two clips.
#[test]
fn tracked_smoothed_landmarks_match_mediapipe_video_mode() {
    let test = "tracked_smoothed_landmarks_match_mediapipe_video_mode";
    let (Some(det), Some(lm)) = (
        model(test, facecap_mesh::FACE_DETECTOR_MODEL),
        model(test, facecap_mesh::FACE_LANDMARKS_MODEL),
    ) else {
        return;
    };
    let params = MeshParams {
        smoothing: Some(facecap_mesh::SmoothingParams::default()),
        ..MeshParams::default()
    };
    let tracker = MeshTracker::new(MeshModels::load(&det, &lm).unwrap(), params).unwrap();
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    let fx = fixture("landmarker_mediapipe.json");
    for v in fx["videos"].as_array().unwrap() {
        let clip = v["clip"].as_str().unwrap();
        let n = v["frames"].as_u64().unwrap();
        let ms = v["frame_ms"].as_f64().unwrap();
        let Some(frames) = clip_frames(test, clip, n) else {
            return;
        };
        let mut state = tracker.state();
        let stored = v["stored"].as_array().unwrap();
        let mut next = 0;
        for (i, img) in frames.iter().enumerate() {
            let report = tracker
                .track_into(
                    &RgbView::from_image(img).unwrap(),
                    i as f64 * ms * 1e-3,
                    &mut ws,
                    &mut state,
                    &mut mesh,
                )
                .unwrap();
            let Some(s) = stored.get(next) else { break };
            if s["frame"].as_u64() != Some(i as u64) {
                continue;
            }
            next += 1;
            let want = s["points"].as_array().unwrap();
            assert!(report.has_face(), "{clip}#{i}: {report:?}");
            let d: Vec<f32> = want
                .iter()
                .zip(&mesh.points)
                .map(|(w, p)| {
                    let w = floats(w);
                    ((p[0] - w[0]).powi(2) + (p[1] - w[1]).powi(2)).sqrt()
                })
                .collect();
            let mean = d.iter().sum::<f32>() / d.len() as f32;
            let max = d.iter().copied().fold(0.0, f32::max);
            let iris = IRIS_CENTERS.map(|i| d[i]);
            eprintln!(
                "{clip}#{i} ({:?}): mean {mean:.3} px, max {max:.3} px, iris {:.3} / {:.3} px",
                report.status, iris[0], iris[1]
            );
            let k = v["width"].as_f64().unwrap() as f32 / 480.0;
            assert!(mean <= MEAN_PX * k, "{clip}#{i}: mean {mean} px");
            assert!(max <= MAX_PX * k, "{clip}#{i}: max {max} px");
            assert!(iris.iter().all(|&e| e <= IRIS_PX * k), "{clip}#{i}: iris {iris:?} px");
        }
        assert_eq!(next, stored.len(), "{clip}: not every stored frame was compared");
    }
}
