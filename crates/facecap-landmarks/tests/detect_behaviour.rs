#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Detector behaviour on synthetic frames and parameter validation.

use facecap_core::paths;
use facecap_landmarks::detect::{DetectorParams, FaceDetector, Upsample, DLIB_FRONTAL_MODEL};
use image::GrayImage;

#[test]
fn blank_and_tiny_frames_give_empty_lists() {
    let Some(model) = paths::model_file_or_skip("detect_blank", DLIB_FRONTAL_MODEL) else {
        return;
    };
    let det = FaceDetector::from_file(&model).unwrap();
    let mut ws = det.new_workspace();
    for (w, h) in [(640, 480), (1, 1), (0, 0), (7, 300), (79, 79)] {
        let img = GrayImage::from_pixel(w, h, image::Luma([128]));
        assert!(det.detect(&img, &mut ws).unwrap().is_empty(), "{w}x{h}");
    }
}

#[test]
fn invalid_parameters_are_rejected_by_name() {
    let Some(model) = paths::model_file_or_skip("detect_params", DLIB_FRONTAL_MODEL) else {
        return;
    };
    let det = FaceDetector::from_file(&model).unwrap();
    let e = det
        .clone()
        .with_params(DetectorParams {
            upsample: Upsample::Times(5),
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("upsample"), "{e}");
    let e = det
        .with_params(DetectorParams {
            adjust_threshold: f64::INFINITY,
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("adjust_threshold"), "{e}");
}
