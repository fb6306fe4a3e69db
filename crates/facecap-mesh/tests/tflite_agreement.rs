//! Our interpreter against Google's TFLite runtime on MediaPipe's face models
//! (fixtures: `testdata/mesh/make_tflite_fixtures.py`).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use facecap_mesh::tflite::Interpreter;
use facecap_mesh::{FACE_DETECTOR_MODEL, FACE_LANDMARKS_MODEL};

/// `|ours - theirs| <= ABS + REL * |theirs|` (TFLite's own XNNPACK and reference kernels
/// differ by up to 2.5e-4 on these outputs; see `max_abs_diff_xnnpack_vs_reference`).
const ABS: f32 = 1e-3;
const REL: f32 = 1e-3;

fn check(what: &str, ours: &[f32], theirs: &[f32]) -> f32 {
    assert_eq!(ours.len(), theirs.len(), "{what}: length");
    let mut worst = 0.0f32;
    for (i, (&a, &b)) in ours.iter().zip(theirs).enumerate() {
        let d = (a - b).abs();
        assert!(d <= ABS + REL * b.abs(), "{what}[{i}]: ours {a}, TFLite {b}");
        worst = worst.max(d);
    }
    worst
}

#[test]
fn landmark_model_matches_tflite() {
    let test = "landmark_model_matches_tflite";
    let Some(path) = model(test, FACE_LANDMARKS_MODEL) else {
        return;
    };
    let it = Interpreter::from_file(&path).unwrap();
    assert_eq!(it.input_shape(0), Some(&[1usize, 256, 256, 3][..]));
    let mut ws = it.workspace();
    let fx = fixture("landmarks_tflite.json");
    let mut ran = 0;
    for case in fx["cases"].as_array().unwrap() {
        let Some(img) = case_input(test, case, 256) else {
            continue;
        };
        for (d, &s) in it.input_mut(&mut ws, 0).unwrap().iter_mut().zip(&img) {
            *d = s as f32 / 255.0;
        }
        it.run(&mut ws).unwrap();
        let name = case["name"].as_str().unwrap();
        let w = check(
            &format!("{name} landmarks"),
            it.output(&ws, 0).unwrap(),
            &floats(&case["landmarks"]),
        );
        check(
            &format!("{name} face flag"),
            it.output(&ws, 1).unwrap(),
            &floats(&case["face_flag"]),
        );
        check(
            &format!("{name} score"),
            it.output(&ws, 2).unwrap(),
            &floats(&case["score"]),
        );
        eprintln!("{name}: max landmark difference {w:.2e}");
        ran += 1;
    }
    assert!(ran >= 1);
}

#[test]
fn detector_model_matches_tflite() {
    let test = "detector_model_matches_tflite";
    let Some(path) = model(test, FACE_DETECTOR_MODEL) else {
        return;
    };
    let it = Interpreter::from_file(&path).unwrap();
    assert_eq!(it.input_shape(0), Some(&[1usize, 128, 128, 3][..]));
    let mut ws = it.workspace();
    let fx = fixture("detector_tflite.json");
    for case in fx["cases"].as_array().unwrap() {
        let Some(img) = case_input(test, case, 128) else {
            continue;
        };
        for (d, &s) in it.input_mut(&mut ws, 0).unwrap().iter_mut().zip(&img) {
            *d = s as f32 / 127.5 - 1.0;
        }
        it.run(&mut ws).unwrap();
        let name = case["name"].as_str().unwrap();
        let reg = it.output(&ws, 0).unwrap();
        let cls = it.output(&ws, 1).unwrap();
        check(&format!("{name} scores"), cls, &floats(&case["scores"]));
        for top in case["top"].as_array().unwrap() {
            let a = top["anchor"].as_u64().unwrap() as usize;
            check(
                &format!("{name} regressors of anchor {a}"),
                &reg[a * 16..(a + 1) * 16],
                &floats(&top["regressors"]),
            );
        }
        let sum: f64 = reg.iter().map(|v| v.abs() as f64).sum();
        let want = case["regressors_abs_sum"].as_f64().unwrap();
        assert!(
            (sum - want).abs() <= 1e-4 * want,
            "{name}: regressor |sum| {sum} vs {want}"
        );
    }
}

#[test]
fn models_use_only_the_supported_ops() {
    let test = "models_use_only_the_supported_ops";
    for name in [FACE_DETECTOR_MODEL, FACE_LANDMARKS_MODEL] {
        let Some(path) = model(test, name) else { return };
        let it = Interpreter::from_file(&path).unwrap();
        eprintln!(
            "{name}: {:?}, workspace {} floats",
            it.op_counts(),
            it.workspace_floats()
        );
        let total: usize = it.op_counts().iter().map(|c| c.1).sum();
        assert!(total > 50, "{name}: only {total} operators");
    }
}

/// Every truncation and a sweep of single-byte corruptions of a real model file must
/// give an error or a model, never a panic.
#[test]
fn damaged_model_files_never_panic() {
    let test = "damaged_model_files_never_panic";
    let Some(path) = model(test, FACE_DETECTOR_MODEL) else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let step = bytes.len() / 400;
    for n in (0..bytes.len()).step_by(step.max(1)) {
        assert!(
            Interpreter::from_bytes(&bytes[..n]).is_err(),
            "truncation to {n} bytes accepted"
        );
    }
    // Corrupt bytes in the flatbuffer's tables (the first and last few KiB hold the
    // vtables, shapes and options; the middle is weight data).
    let mut damaged = bytes.clone();
    let positions: Vec<usize> = (0..4096)
        .chain(bytes.len().saturating_sub(8192)..bytes.len())
        .step_by(13)
        .collect();
    for &p in &positions {
        for v in [0x00u8, 0xff, 0x7f] {
            let old = damaged[p];
            damaged[p] = v;
            if let Ok(it) = Interpreter::from_bytes(&damaged) {
                // A model that still loads must also run without panicking.
                let mut ws = it.workspace();
                it.run(&mut ws).unwrap();
            }
            damaged[p] = old;
        }
    }
}
