#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Property-based fuzzing of the landmark CSV reader `solve` and `muscle track` use
//! (`facecap_pipeline::openface::read_landmarks`), from two seeds: an OpenFace 2.x
//! FeatureExtraction CSV (spaces after commas, `face_id`, frames from 1) and facecap's
//! own `landmarks.csv`. Every mutated file reads or is an error, never a panic, and what
//! it reads keeps the reader's promises (landmarks finite, success rows only). Inputs
//! tried: the case counts below.

#[path = "../../facecap-io/tests/fuzz_common/mod.rs"]
mod fuzz_common;

use facecap_pipeline::openface::read_landmarks;
use fuzz_common::{config, mutated};
use proptest::prelude::*;

/// Inputs tried per seed.
const CASES: u32 = 1500;

/// Two rows of an OpenFace CSV (one with a second face, which the reader skips).
fn openface_seed() -> Vec<u8> {
    let mut cols: Vec<String> = ["frame", "face_id", "timestamp", "confidence", "success", "gaze_0_x"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for a in ["x", "y"] {
        cols.extend((0..68).map(|i| format!("{a}_{i}")));
    }
    cols.push("AU01_r".into());
    let mut out = cols.join(", ");
    out.push('\n');
    for (frame, face, success) in [(1, 0, 1), (1, 1, 1), (2, 0, 0)] {
        let mut row = vec![
            frame.to_string(),
            face.to_string(),
            format!("{:.3}", f64::from(frame - 1) / 30.0),
            "0.98".into(),
            success.to_string(),
            "0.1".into(),
        ];
        row.extend((0..136).map(|i| format!("{:.1}", 100.0 + f64::from(i % 68) * 2.5 + f64::from(i / 68))));
        row.push("0.5".into());
        out.push_str(&row.join(", "));
        out.push('\n');
    }
    out.into_bytes()
}

/// The first three rows of a real facecap `landmarks.csv`.
fn native_seed() -> Vec<u8> {
    let p = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/solve/landmarks_liveportrait_d9.csv"
    );
    let text = std::fs::read_to_string(p).unwrap();
    let mut out: String = text.lines().take(4).collect::<Vec<_>>().join("\n");
    out.push('\n');
    out.into_bytes()
}

fn check(tag: &str, bytes: &[u8]) {
    // One file per target and process, written and removed for every case.
    let p = std::env::temp_dir().join(format!("facecap-fuzz-{tag}-{}.csv", std::process::id()));
    std::fs::write(&p, bytes).unwrap();
    let read = read_landmarks(&p);
    let _ = std::fs::remove_file(&p);
    if let Ok(rows) = read {
        for r in rows {
            if let Some(l) = &r.landmarks {
                assert!(r.success);
                assert!(l.points.iter().all(|q| q.x.is_finite() && q.y.is_finite()));
            }
            assert!(r.timestamp.is_finite() && r.timestamp >= 0.0);
        }
    }
}

#[test]
fn seeds_are_valid() {
    let dir = tempfile::tempdir().unwrap();
    for (seed, rows, solved) in [(openface_seed(), 2, 1), (native_seed(), 3, 3)] {
        let p = dir.path().join("seed.csv");
        std::fs::write(&p, seed).unwrap();
        let r = read_landmarks(&p).unwrap();
        assert_eq!(r.len(), rows);
        assert_eq!(r.iter().filter(|x| x.landmarks.is_some()).count(), solved);
    }
}

proptest! {
    #![proptest_config(config(CASES))]
    #[test]
    fn fuzz_openface_csv(b in mutated(openface_seed())) {
        check("openface", &b);
    }
    #[test]
    fn fuzz_native_landmark_csv(b in mutated(native_seed())) {
        check("native", &b);
    }
}
