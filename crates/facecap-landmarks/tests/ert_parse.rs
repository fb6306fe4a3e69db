//! Parser tests for dlib `shape_predictor` files: round trips, exhaustive truncation,
//! seeded byte flips (never a panic), version and trailing-data errors.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod ert_common;

use facecap_core::landmarks::Rect;
use facecap_core::paths::{model_file_or_skip, DLIB_5_MODEL, DLIB_68_MODEL};
use facecap_landmarks::ert::{ErtModel, ShapePredictor};
use facecap_landmarks::Error;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn small_model_bytes() -> Vec<u8> {
    ert_common::synthetic_model(7, 5, 3, 4, 2, 10).to_dlib_bytes()
}

/// Parses and, if the model is accepted, predicts once: neither may panic.
fn parse_and_use(bytes: &[u8]) -> bool {
    match ShapePredictor::from_bytes(bytes) {
        Ok(sp) => {
            let img = ert_common::synthetic_image(1, 40, 30);
            let mut ws = sp.new_workspace();
            let mut out = vec![Point2::origin(); sp.num_parts()];
            let _ = sp.predict_into(&img, &Rect::from_dlib(5, 5, 30, 25), &mut ws, &mut out);
            true
        }
        Err(Error::Model { .. }) => false,
        Err(e) => panic!("unexpected error kind: {e}"),
    }
}

#[test]
fn synthetic_model_round_trips() {
    let m = ert_common::synthetic_model(3, 6, 2, 3, 3, 12);
    let bytes = m.to_dlib_bytes();
    let back = ErtModel::from_bytes(&bytes).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.to_dlib_bytes(), bytes);
}

#[test]
fn every_truncation_of_a_small_model_is_an_error() {
    let bytes = small_model_bytes();
    assert!(ErtModel::from_bytes(&bytes).is_ok());
    for n in 0..bytes.len() {
        match ErtModel::from_bytes(&bytes[..n]) {
            Err(Error::Model { reason, .. }) => assert!(!reason.is_empty()),
            other => panic!("truncation to {n} bytes gave {other:?}"),
        }
    }
}

#[test]
fn seeded_byte_flips_never_panic() {
    let bytes = small_model_bytes();
    let mut rng = ChaCha8Rng::seed_from_u64(0xE27);
    let mut accepted = 0;
    for _ in 0..4000 {
        let mut b = bytes.clone();
        for _ in 0..rng.random_range(1..4) {
            let i = rng.random_range(0..b.len());
            b[i] = rng.random();
        }
        accepted += usize::from(parse_and_use(&b));
    }
    eprintln!("byte flips: {accepted}/4000 mutated models were still valid");
}

#[test]
fn wrong_version_and_trailing_bytes_are_errors() {
    let mut bytes = small_model_bytes();
    // version is the first integer: [0x01, 0x01]
    assert_eq!(&bytes[..2], &[1, 1]);
    bytes[1] = 2;
    let e = ErtModel::from_bytes(&bytes).unwrap_err().to_string();
    assert!(e.contains("version 2"), "{e}");
    let mut bytes = small_model_bytes();
    bytes.push(0);
    let e = ErtModel::from_bytes(&bytes).unwrap_err().to_string();
    assert!(e.contains("trailing"), "{e}");
    assert!(ErtModel::from_bytes(b"not a model at all").is_err());
    let e = ShapePredictor::from_file(std::path::Path::new("/nonexistent/sp.dat")).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/sp.dat"), "{e}");
}

#[test]
fn invalid_indices_are_rejected() {
    let mut m = ert_common::synthetic_model(5, 4, 1, 2, 2, 8);
    m.forests[0][1].splits[0].idx2 = 8;
    assert!(ErtModel::from_bytes(&m.to_dlib_bytes()).is_err());
    let mut m = ert_common::synthetic_model(5, 4, 1, 2, 2, 8);
    m.anchor_idx[0][3] = 4;
    assert!(ErtModel::from_bytes(&m.to_dlib_bytes()).is_err());
    let mut m = ert_common::synthetic_model(5, 4, 1, 2, 2, 8);
    m.forests[0][0].leaf_values.pop();
    assert!(ErtModel::from_bytes(&m.to_dlib_bytes()).is_err());
    let mut m = ert_common::synthetic_model(5, 4, 1, 2, 2, 8);
    m.forests[0][0].leaf_values[2].push(0.0);
    assert!(ErtModel::from_bytes(&m.to_dlib_bytes()).is_err());
}

#[test]
fn real_models_parse_round_trip_and_resist_truncation() {
    for (name, parts) in [(DLIB_5_MODEL, 5), (DLIB_68_MODEL, 68)] {
        let Some(path) = model_file_or_skip("real_models_parse_round_trip_and_resist_truncation", name) else {
            continue;
        };
        let bytes = std::fs::read(&path).unwrap();
        let m = ErtModel::from_bytes(&bytes).unwrap();
        assert_eq!(m.num_parts(), parts);
        let trees: usize = m.forests.iter().map(Vec::len).sum();
        let depth = m.forests[0][0].splits.len();
        eprintln!(
            "{name}: {} cascades, {trees} trees, {depth} splits/tree, {} feature pixels/cascade",
            m.forests.len(),
            m.deltas[0].len()
        );
        // Our writer reproduces dlib's bytes exactly, so the parse lost nothing.
        assert!(
            m.to_dlib_bytes() == bytes,
            "{name}: re-serialisation differs from the file"
        );
        if parts != 5 {
            continue;
        }
        // Every truncation of the header area (version, mean shape, first trees) ...
        let head = 6000.min(bytes.len());
        for n in 0..head {
            assert!(ErtModel::from_bytes(&bytes[..n]).is_err(), "truncated at {n}");
        }
        // ... and a stride over the whole file.
        let stride = bytes.len() / 12;
        for n in (head..bytes.len()).step_by(stride) {
            assert!(ErtModel::from_bytes(&bytes[..n]).is_err(), "truncated at {n}");
        }
        // Seeded flips in the header area of the real file never panic.
        let mut rng = ChaCha8Rng::seed_from_u64(55);
        for _ in 0..30 {
            let mut b = bytes.clone();
            let i = rng.random_range(0..head);
            b[i] ^= 1 << rng.random_range(0..8);
            let _ = parse_and_use(&b);
        }
    }
}
