//! The optimised predictor against the slow line-by-line port of dlib's algorithm
//! (`ert::reference`) on seeded random models, images and boxes; API errors.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod ert_common;

use facecap_core::landmarks::Rect;
use facecap_landmarks::ert::{reference, ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::Error;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn subpixel(sp: ShapePredictor) -> ShapePredictor {
    sp.with_params(ErtParams {
        output: OutputPrecision::SubPixel,
        ..Default::default()
    })
}

#[test]
fn optimised_equals_reference_on_random_models() {
    let mut rng = ChaCha8Rng::seed_from_u64(2014);
    let mut compared = 0;
    for case in 0..40u64 {
        let parts = rng.random_range(1..20);
        let depth = rng.random_range(0..5);
        let model =
            ert_common::synthetic_model(case, parts, rng.random_range(1..5), rng.random_range(1..12), depth, 30);
        let sp = subpixel(ShapePredictor::new(&model, Default::default()).unwrap());
        let (w, h) = (rng.random_range(20..200), rng.random_range(20..200));
        let img = ert_common::synthetic_image(case + 100, w, h);
        let mut ws = sp.new_workspace();
        let mut out = vec![Point2::origin(); parts];
        for _ in 0..5 {
            // boxes partly outside the image too
            let l = rng.random_range(-30..w as i64);
            let t = rng.random_range(-30..h as i64);
            let rect = Rect::from_dlib(l, t, l + rng.random_range(1..150), t + rng.random_range(1..150));
            sp.predict_into(&img, &rect, &mut ws, &mut out).unwrap();
            let want = reference::predict(&model, &img, &rect, None);
            for (p, q) in out.iter().zip(&want) {
                assert!((p - q).norm() < 1e-9, "case {case}: {p} vs {q}");
            }
            compared += 1;
        }
    }
    assert_eq!(compared, 200);
}

#[test]
fn real_models_equal_reference() {
    for name in [facecap_core::paths::DLIB_5_MODEL, facecap_core::paths::DLIB_68_MODEL] {
        let Some(path) = facecap_core::paths::model_file_or_skip("real_models_equal_reference", name) else {
            continue;
        };
        let model = facecap_landmarks::ert::ErtModel::from_file(&path).unwrap();
        let sp = subpixel(ShapePredictor::new(&model, Default::default()).unwrap());
        let img = ert_common::synthetic_image(9, 320, 240);
        let rect = Rect::from_dlib(90, 60, 230, 200);
        let mut ws = sp.new_workspace();
        let mut out = vec![Point2::origin(); sp.num_parts()];
        sp.predict_into(&img, &rect, &mut ws, &mut out).unwrap();
        let want = reference::predict(&model, &img, &rect, None);
        for (p, q) in out.iter().zip(&want) {
            assert!((p - q).norm() < 1e-9, "{name}: {p} vs {q}");
        }
    }
}

#[test]
fn starting_from_the_mean_shape_in_the_box_equals_predict_into() {
    let model = ert_common::synthetic_model(4, 12, 3, 10, 3, 40);
    let sp = subpixel(ShapePredictor::new(&model, Default::default()).unwrap());
    let img = ert_common::synthetic_image(5, 160, 120);
    let rect = Rect::from_dlib(30, 20, 130, 110);
    let start: Vec<Point2<f64>> = sp
        .mean_shape()
        .chunks_exact(2)
        .map(|p| Point2::new(30.0 + 100.0 * f64::from(p[0]), 20.0 + 90.0 * f64::from(p[1])))
        .collect();
    let mut ws = sp.new_workspace();
    let mut a = vec![Point2::origin(); 12];
    let mut b = vec![Point2::origin(); 12];
    sp.predict_into(&img, &rect, &mut ws, &mut a).unwrap();
    sp.predict_from_shape_into(&img, &rect, &start, &mut ws, &mut b)
        .unwrap();
    for (p, q) in a.iter().zip(&b) {
        assert!((p - q).norm() < 1e-3, "{p} vs {q}");
    }
    let want = reference::predict(&model, &img, &rect, Some(sp.mean_shape()));
    for (p, q) in a.iter().zip(&want) {
        assert!((p - q).norm() < 1e-9, "{p} vs {q}");
    }
}

#[test]
fn dlib_rounding_is_floor_plus_half_of_the_sub_pixel_result() {
    let model = ert_common::synthetic_model(8, 9, 2, 6, 2, 20);
    let sp = ShapePredictor::new(&model, Default::default()).unwrap();
    let img = ert_common::synthetic_image(8, 100, 100);
    let rect = Rect::from_dlib(10, 10, 80, 90);
    let mut ws = sp.new_workspace();
    let mut out = vec![Point2::origin(); 9];
    sp.predict_into(&img, &rect, &mut ws, &mut out).unwrap();
    let want = reference::predict(&model, &img, &rect, None);
    for (p, q) in out.iter().zip(&want) {
        assert_eq!((p.x, p.y), ((q.x + 0.5).floor(), (q.y + 0.5).floor()));
    }
}

#[test]
fn bad_inputs_are_errors() {
    let model = ert_common::synthetic_model(1, 5, 1, 2, 2, 8);
    let sp = ShapePredictor::new(&model, Default::default()).unwrap();
    let img = ert_common::synthetic_image(1, 50, 50);
    let mut ws = sp.new_workspace();
    let rect = Rect::from_dlib(5, 5, 40, 40);
    let mut short = vec![Point2::origin(); 4];
    assert!(matches!(
        sp.predict_into(&img, &rect, &mut ws, &mut short),
        Err(Error::DimensionMismatch {
            expected: 5,
            got: 4,
            ..
        })
    ));
    let mut out = vec![Point2::origin(); 5];
    let nan = Rect { left: f64::NAN, ..rect };
    assert!(matches!(
        sp.predict_into(&img, &nan, &mut ws, &mut out),
        Err(Error::InvalidParameter { name: "rect.left", .. })
    ));
    let empty = Rect { width: 0.0, ..rect };
    assert!(sp.predict_into(&img, &empty, &mut ws, &mut out).is_err());
    let start = vec![Point2::new(1.0, f64::INFINITY); 5];
    assert!(sp
        .predict_from_shape_into(&img, &rect, &start, &mut ws, &mut out)
        .is_err());
    assert!(sp
        .predict_from_shape_into(&img, &rect, &start[..3], &mut ws, &mut out)
        .is_err());
    // an empty image is not an error: every feature pixel reads 0
    let empty_img = image::GrayImage::new(0, 0);
    sp.predict_into(&empty_img, &rect, &mut ws, &mut out).unwrap();
    // a workspace from another predictor is resized, not an error
    let other = ShapePredictor::new(&ert_common::synthetic_model(2, 30, 2, 3, 3, 50), Default::default()).unwrap();
    let mut ws2 = other.new_workspace();
    sp.predict_into(&img, &rect, &mut ws2, &mut out).unwrap();
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<ShapePredictor>();
}
