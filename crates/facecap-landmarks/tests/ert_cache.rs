//! `ShapePredictor::from_file_cached`: first call writes the cache, later calls hit
//! it, and stale, damaged or truncated caches are replaced, always giving the same
//! predictor as parsing the model file.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod ert_common;

use facecap_core::landmarks::Rect;
use facecap_landmarks::ert::{CacheStatus, ShapePredictor};
use nalgebra::Point2;

fn predict(sp: &ShapePredictor) -> Vec<Point2<f64>> {
    let img = ert_common::synthetic_image(5, 160, 120);
    let mut ws = sp.new_workspace();
    let mut all = Vec::new();
    for (l, t) in [(10, 10), (40, 20), (-5, 30)] {
        let mut out = vec![Point2::origin(); sp.num_parts()];
        sp.predict_into(&img, &Rect::from_dlib(l, t, l + 90, t + 80), &mut ws, &mut out)
            .unwrap();
        all.extend(out);
    }
    all
}

#[test]
fn cache_is_written_hit_and_replaced_when_stale_or_damaged() {
    let dir = std::env::temp_dir().join(format!("facecap_ert_cache_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let model = dir.join("sp.dat");
    let m = ert_common::synthetic_model(3, 12, 4, 20, 3, 40);
    std::fs::write(&model, m.to_dlib_bytes()).unwrap();
    let want = predict(&ShapePredictor::from_file(&model).unwrap());

    let (sp, status) = ShapePredictor::from_file_cached(&model).unwrap();
    assert_eq!(status, CacheStatus::Written);
    assert_eq!(predict(&sp), want);
    let cache = dir.join("sp.dat.facecap-cache");
    assert!(cache.is_file());

    let (sp, status) = ShapePredictor::from_file_cached(&model).unwrap();
    assert_eq!(status, CacheStatus::Hit);
    assert_eq!(predict(&sp), want);

    // a damaged byte, a truncation, garbage: parsed again, cache rewritten
    let good = std::fs::read(&cache).unwrap();
    let mut bad = good.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0x10;
    for broken in [
        bad,
        good[..good.len() / 3].to_vec(),
        b"not a cache".to_vec(),
        Vec::new(),
    ] {
        std::fs::write(&cache, &broken).unwrap();
        let (sp, status) = ShapePredictor::from_file_cached(&model).unwrap();
        assert_eq!(status, CacheStatus::Written);
        assert_eq!(predict(&sp), want);
        assert_eq!(std::fs::read(&cache).unwrap(), good);
    }

    // another model under the same name (size changes): the stale cache is not used
    let m2 = ert_common::synthetic_model(4, 12, 3, 10, 2, 40);
    std::fs::write(&model, m2.to_dlib_bytes()).unwrap();
    let want2 = predict(&ShapePredictor::from_file(&model).unwrap());
    let (sp, status) = ShapePredictor::from_file_cached(&model).unwrap();
    assert_eq!(status, CacheStatus::Written);
    assert_eq!(predict(&sp), want2);

    // a malformed model is still an error, cache or not
    std::fs::write(&model, b"garbage").unwrap();
    assert!(ShapePredictor::from_file_cached(&model).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
