#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Times the stages of loading dlib's 68-point model: file read, parse, flat layout,
//! and the same through the binary cache (`ShapePredictor::from_file_cached`).
//! `cargo run --release -p facecap-landmarks --example ert_load_timing`
use std::time::Instant;

fn main() {
    let path = facecap_core::paths::model_file(facecap_core::paths::DLIB_68_MODEL).expect("model in the cache");
    for _ in 0..3 {
        let t = Instant::now();
        let bytes = std::fs::read(&path).unwrap();
        let t_read = t.elapsed();
        let t = Instant::now();
        let model = facecap_landmarks::ert::ErtModel::from_bytes(&bytes).unwrap();
        let t_parse = t.elapsed();
        let t = Instant::now();
        let sp = facecap_landmarks::ert::ShapePredictor::new(&model, Default::default()).unwrap();
        let t_flat = t.elapsed();
        let t = Instant::now();
        drop(model);
        drop(bytes);
        let t_drop = t.elapsed();
        let t = Instant::now();
        let det = facecap_landmarks::detect::FaceDetector::default_model().unwrap();
        let t_det = t.elapsed();
        let t = Instant::now();
        let (cached, status) = facecap_landmarks::ert::ShapePredictor::from_file_cached(&path).unwrap();
        let t_cached = t.elapsed();
        println!(
            "parse path: read {t_read:?} + parse {t_parse:?} + flat layout {t_flat:?} + drop {t_drop:?}; \
             from_file_cached {t_cached:?} ({status:?}, {} trees); HOG detector {t_det:?} ({} sub-detectors)",
            cached.num_trees(),
            det.num_sub_detectors()
        );
        assert_eq!(cached.num_trees(), sp.num_trees());
    }
}
