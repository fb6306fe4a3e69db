#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Times the stages of loading dlib's 68-point model: file read, parse, flat layout.
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
        println!(
            "read {:?} parse {:?} flat {:?} drop {:?} detector {:?} ({} trees, {:?})",
            t_read,
            t_parse,
            t_flat,
            t_drop,
            t_det,
            sp.num_trees(),
            std::mem::size_of_val(&det)
        );
    }
}
