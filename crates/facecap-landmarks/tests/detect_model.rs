#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The HOG detector file parser: reads dlib's format, rejects every truncation and
//! never panics on corrupted bytes.

use std::path::Path;

use facecap_core::paths;
use facecap_landmarks::detect::{HogModel, DLIB_FRONTAL_MODEL};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// dlib's packed integer.
fn put_int(out: &mut Vec<u8>, v: i64) {
    let neg = v < 0;
    let mut m = v.unsigned_abs();
    let mut body = Vec::new();
    loop {
        body.push((m & 0xff) as u8);
        m >>= 8;
        if m == 0 {
            break;
        }
    }
    out.push(body.len() as u8 | if neg { 0x80 } else { 0 });
    out.extend(body);
}

/// dlib's float_details encoding of a double.
fn put_f64(out: &mut Vec<u8>, v: f64) {
    if v == 0.0 {
        put_int(out, 0);
        put_int(out, 0);
        return;
    }
    // v = m * 2^e with |m| < 2^53 integer
    let (mut m, mut e) = (v, 0i64);
    while m.fract() != 0.0 && m.abs() < 2f64.powi(52) {
        m *= 2.0;
        e -= 1;
    }
    put_int(out, m as i64);
    put_int(out, e);
}

/// A small valid detector: 24 x 24 window, cell 8 (3 x 3 cell filters), 2 weight
/// vectors.
fn synthetic_model_bytes(seed: u64) -> Vec<u8> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut b = Vec::new();
    put_int(&mut b, 2); // object_detector version
    put_int(&mut b, 1); // scanner version
    put_int(&mut b, 0); // feats max_size
    put_int(&mut b, 0); // feats size
    put_int(&mut b, 8); // cell size
    put_int(&mut b, 0); // padding
    put_int(&mut b, 24);
    put_int(&mut b, 24);
    put_int(&mut b, 1000);
    put_int(&mut b, 64);
    put_int(&mut b, 64);
    put_f64(&mut b, 9.0);
    let dims = 31 * 3 * 3;
    put_int(&mut b, dims);
    put_f64(&mut b, 0.25);
    put_f64(&mut b, 0.75);
    put_int(&mut b, 2);
    for _ in 0..2 {
        put_int(&mut b, -(dims + 1));
        put_int(&mut b, -1);
        for _ in 0..=dims {
            put_f64(&mut b, rng.random_range(-1.0..1.0));
        }
    }
    b
}

#[test]
fn synthetic_model_round_trips() {
    let bytes = synthetic_model_bytes(1);
    let m = HogModel::from_bytes(&bytes, Path::new("synthetic")).unwrap();
    assert_eq!((m.fhog_window_width, m.fhog_window_height), (3, 3));
    assert_eq!(m.weights.len(), 2);
    assert_eq!(m.weights[0].len(), 31 * 9 + 1);
    assert_eq!((m.overlap_iou_thresh, m.overlap_percent_covered_thresh), (0.25, 0.75));
    assert_eq!(m.nuclear_norm_regularization_strength, 9.0);
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = synthetic_model_bytes(2);
    for n in 0..bytes.len() {
        let r = HogModel::from_bytes(&bytes[..n], Path::new("t"));
        assert!(r.is_err(), "prefix of {n} bytes accepted");
    }
    // trailing garbage is rejected too
    let mut more = bytes.clone();
    more.push(0);
    assert!(HogModel::from_bytes(&more, Path::new("t")).is_err());
}

#[test]
fn corrupted_bytes_never_panic() {
    let bytes = synthetic_model_bytes(3);
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for _ in 0..3000 {
        let mut b = bytes.clone();
        for _ in 0..rng.random_range(1..4) {
            let i = rng.random_range(0..b.len());
            b[i] = rng.random();
        }
        let _ = HogModel::from_bytes(&b, Path::new("fuzz"));
    }
}

#[test]
fn wrong_versions_are_named() {
    let mut bytes = synthetic_model_bytes(5);
    bytes[1] = 3;
    let e = HogModel::from_bytes(&bytes, Path::new("v")).unwrap_err().to_string();
    assert!(e.contains("version"), "{e}");
}

#[test]
fn dlib_frontal_detector_file_parses_and_every_truncation_fails() {
    let Some(path) = paths::model_file_or_skip("detect_model", DLIB_FRONTAL_MODEL) else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let m = HogModel::from_bytes(&bytes, &path).unwrap();
    assert_eq!(m.weights.len(), 5);
    assert_eq!(
        (m.cell_size, m.padding, m.window_width, m.window_height),
        (8, 0, 80, 80)
    );
    assert_eq!((m.fhog_window_width, m.fhog_window_height), (10, 10));
    assert_eq!(
        (
            m.min_pyramid_layer_width,
            m.min_pyramid_layer_height,
            m.max_pyramid_levels
        ),
        (64, 64, 1000)
    );
    assert!((m.overlap_iou_thresh - 0.330_082_121_880_564_5).abs() < 1e-15);
    assert!((m.overlap_percent_covered_thresh - 0.788_571_428_571_428_6).abs() < 1e-15);
    assert!(m.weights.iter().all(|w| w.len() == 3101));
    // truncations: every length is checked on the small synthetic model; here a
    // stride keeps the test fast on the 155 kB file while covering every field of
    // the header and the first weights exhaustively.
    for n in (0..bytes.len()).filter(|n| *n < 400 || n % 97 == 0) {
        assert!(HogModel::from_bytes(&bytes[..n], &path).is_err(), "prefix {n}");
    }
}
