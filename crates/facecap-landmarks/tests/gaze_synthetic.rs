#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The iris estimator on drawn eyes with a known iris, plus the guarantees that do not
//! need real footage: closed / tiny / degenerate / out-of-image eyes are invalid without
//! a panic, parameters are validated, and the ARKit mapping follows its sign rules.

mod gaze_common;

use facecap_core::landmarks::Landmarks68;
use facecap_landmarks::gaze::{
    gaze_weights, gaze_weights_in_head, EyeEstimate, EyeRest, EyeStatus, GazeGains, GazeRest, HeadTurn, IrisEstimator,
    IrisFrame, IrisParams, GAZE_WEIGHT_NAMES, HEAD_TURN_EYE_WIDTHS, REST_MEDIAN_SHARE, STRAIGHT_AHEAD_U,
};
use gaze_common::{face, render};
use image::GrayImage;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn run(img: &GrayImage, lm: &Landmarks68) -> IrisFrame {
    let est = IrisEstimator::new(IrisParams::default()).unwrap();
    let mut ws = est.new_workspace();
    let mut out = IrisFrame::default();
    est.estimate_into(img, lm, &mut ws, &mut out).unwrap();
    out
}

#[test]
fn recovers_a_drawn_iris_within_half_a_pixel() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let mut worst = 0.0f64;
    let mut worst_uv = 0.0f64;
    for case in 0..24 {
        // eye width 30-60 px, roll up to +-25 deg, sub-pixel face centre
        let width = rng.random_range(30.0..60.0);
        let roll = rng.random_range(-0.45..0.45);
        let centre = Point2::new(160.0 + rng.random_range(-3.0..3.0), 120.0 + rng.random_range(-3.0..3.0));
        let r = 0.12;
        let iris = |rng: &mut ChaCha8Rng| (rng.random_range(0.3..0.7), rng.random_range(-0.04..0.04));
        let (ri, li) = (iris(&mut rng), iris(&mut rng));
        let eyes = face(centre, width, roll, 0.22, ri, li, r);
        let (img, lm) = render(320, 240, &eyes);
        let out = run(&img, &lm);
        for (e, spec) in [(&out.right, &eyes[0]), (&out.left, &eyes[1])] {
            assert!(e.valid(), "case {case}: {:?}", e.status);
            let err = (e.centre - spec.iris_px()).norm();
            worst = worst.max(err);
            worst_uv = worst_uv.max((e.u - spec.iris_uv.0).abs().max((e.v - spec.iris_uv.1).abs()));
            assert!(
                err <= 0.5,
                "case {case}: iris off by {err} px ({:?} vs {:?})",
                e.centre,
                spec.iris_px()
            );
            assert!(
                (e.opening - 4.0 * 0.22 * 2.0 / 9.0 * 2.0).abs() < 1e-9,
                "opening {}",
                e.opening
            );
            assert!((e.width_px - width).abs() < 1e-9);
            assert!(e.confidence > 0.0 && e.confidence <= 1.0);
        }
    }
    eprintln!("drawn iris: worst error {worst:.3} px, worst |u|/|v| error {worst_uv:.4} eye widths");
}

#[test]
fn a_lid_clipped_iris_in_the_middle_is_found_at_its_centre() {
    // a realistic iris (radius 0.22 eye widths) larger than the lid opening, centred
    let eyes = face(Point2::new(160.0, 120.0), 44.0, 0.1, 0.18, (0.5, 0.0), (0.5, 0.0), 0.22);
    let (img, lm) = render(320, 240, &eyes);
    let out = run(&img, &lm);
    for (e, spec) in [(&out.right, &eyes[0]), (&out.left, &eyes[1])] {
        assert!(e.valid(), "{:?}", e.status);
        let err = (e.centre - spec.iris_px()).norm();
        assert!(err <= 0.5, "clipped iris off by {err} px");
    }
}

#[test]
fn u_and_v_follow_the_documented_axes() {
    // both irises moved towards the image right and down: the right eye's iris goes to
    // its inner corner (u up), the left eye's to its outer corner (u down); v > 0 for both
    let eyes = face(
        Point2::new(160.0, 120.0),
        44.0,
        0.0,
        0.22,
        (0.62, 0.05),
        (0.38, 0.05),
        0.12,
    );
    let (img, lm) = render(320, 240, &eyes);
    let out = run(&img, &lm);
    assert!((out.right.u - 0.62).abs() < 0.02 && (out.left.u - 0.38).abs() < 0.02);
    assert!(out.right.v > 0.03 && out.left.v > 0.03);
    assert!(out.right.centre.x > eyes[0].at(0.5, 0.0).x && out.left.centre.x > eyes[1].at(0.5, 0.0).x);
    assert!(out.right.centre.y > 120.0 && out.left.centre.y > 120.0);
}

#[test]
fn a_closed_eye_is_invalid() {
    let eyes = face(Point2::new(160.0, 120.0), 44.0, 0.0, 0.03, (0.5, 0.0), (0.5, 0.0), 0.12);
    let (img, lm) = render(320, 240, &eyes);
    let out = run(&img, &lm);
    assert_eq!(out.right.status, EyeStatus::Closed);
    assert_eq!(out.left.status, EyeStatus::Closed);
    assert!(!out.right.valid() && out.right.confidence == 0.0);
    assert!(out.right.opening < 0.12);
}

#[test]
fn a_tiny_eye_is_invalid() {
    let eyes = face(Point2::new(160.0, 120.0), 6.0, 0.0, 0.22, (0.5, 0.0), (0.5, 0.0), 0.12);
    let (img, lm) = render(320, 240, &eyes);
    let out = run(&img, &lm);
    assert_eq!(out.right.status, EyeStatus::TooSmall);
    assert_eq!(out.left.status, EyeStatus::TooSmall);
}

#[test]
fn a_flat_eye_region_is_low_contrast() {
    let eyes = face(Point2::new(160.0, 120.0), 44.0, 0.0, 0.22, (0.5, 0.0), (0.5, 0.0), 0.12);
    let (_, lm) = render(320, 240, &eyes);
    let flat = GrayImage::from_pixel(320, 240, image::Luma([128]));
    let out = run(&flat, &lm);
    assert_eq!(out.right.status, EyeStatus::LowContrast);
    assert_eq!(out.left.status, EyeStatus::LowContrast);
}

#[test]
fn degenerate_and_out_of_image_landmarks_do_not_panic() {
    let eyes = face(Point2::new(160.0, 120.0), 44.0, 0.0, 0.22, (0.5, 0.0), (0.5, 0.0), 0.12);
    let (img, good) = render(320, 240, &eyes);
    let mut cases: Vec<(Landmarks68, Option<EyeStatus>)> = vec![(Landmarks68::default(), Some(EyeStatus::TooSmall))];
    let mut nan = good.clone();
    nan.points[37].x = f64::NAN;
    nan.points[44].y = f64::INFINITY;
    cases.push((nan, Some(EyeStatus::NotFinite)));
    let mut far = good.clone();
    for p in far.points.iter_mut() {
        p.x -= 10_000.0;
    }
    cases.push((far, Some(EyeStatus::OutOfImage)));
    let mut half = good.clone();
    for p in half.points.iter_mut() {
        p.x -= 100.0; // the right eye now straddles the left image border
    }
    cases.push((half.clone(), None));
    let mut huge = good.clone();
    for p in huge.points.iter_mut() {
        *p = Point2::new(p.x * 1e12, p.y * 1e12);
    }
    cases.push((huge, Some(EyeStatus::OutOfImage)));
    let mut collinear = good.clone();
    for p in collinear.points.iter_mut().skip(36).take(12) {
        p.y = 120.0; // lids on the corner axis: opening 0
    }
    cases.push((collinear, Some(EyeStatus::Closed)));
    // random landmarks around the image, seeded
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..200 {
        let mut lm = Landmarks68::default();
        for p in lm.points.iter_mut() {
            *p = Point2::new(rng.random_range(-50.0..370.0), rng.random_range(-50.0..290.0));
        }
        cases.push((lm, None));
    }
    for (k, (lm, expected)) in cases.iter().enumerate() {
        let out = run(&img, lm);
        if let Some(s) = expected {
            assert_eq!(out.right.status, *s, "case {k}");
        }
        for e in [&out.right, &out.left] {
            if e.valid() {
                assert!(e.centre.x.is_finite() && e.u.is_finite() && e.v.is_finite(), "case {k}");
            } else {
                assert_eq!(e.confidence, 0.0);
            }
        }
    }
    assert_eq!(run(&img, &half).right.status, EyeStatus::OutOfImage);
    // images too small for any eye, including empty ones
    for (w, h) in [(0, 0), (1, 1), (0, 5), (3, 2)] {
        let tiny = GrayImage::new(w, h);
        let out = run(&tiny, &good);
        assert!(!out.right.valid() && !out.left.valid(), "{w}x{h}");
    }
}

#[test]
fn parameters_are_validated() {
    let bad: Vec<(&str, IrisParams)> = vec![
        (
            "patch_width",
            IrisParams {
                patch_width: 8,
                ..IrisParams::default()
            },
        ),
        (
            "mask_margin",
            IrisParams {
                mask_margin: f64::NAN,
                ..IrisParams::default()
            },
        ),
        (
            "mask_margin",
            IrisParams {
                mask_margin: -0.1,
                ..IrisParams::default()
            },
        ),
        (
            "high_percentile",
            IrisParams {
                low_percentile: 0.5,
                high_percentile: 0.4,
                ..IrisParams::default()
            },
        ),
        (
            "threshold_level",
            IrisParams {
                threshold_level: 0.0,
                ..IrisParams::default()
            },
        ),
        (
            "kernel_sigma",
            IrisParams {
                kernel_sigma: f64::INFINITY,
                ..IrisParams::default()
            },
        ),
        (
            "iterations",
            IrisParams {
                iterations: 0,
                ..IrisParams::default()
            },
        ),
        (
            "min_eye_width_px",
            IrisParams {
                min_eye_width_px: 1.0,
                ..IrisParams::default()
            },
        ),
        (
            "min_opening",
            IrisParams {
                min_opening: 1.0,
                ..IrisParams::default()
            },
        ),
        (
            "min_contrast",
            IrisParams {
                min_contrast: 300.0,
                ..IrisParams::default()
            },
        ),
    ];
    for (name, p) in bad {
        match IrisEstimator::new(p) {
            Err(facecap_landmarks::Error::InvalidParameter { name: n, .. }) => assert_eq!(n, name),
            other => panic!("{name}: {other:?}"),
        }
    }
    assert!(IrisEstimator::new(IrisParams::default()).is_ok());
    let g = GazeGains {
        look_up: -1.0,
        ..GazeGains::default()
    };
    assert!(g.validate().is_err());
    assert!(GazeGains::default().validate().is_ok());
}

#[test]
fn a_workspace_of_another_size_is_an_error() {
    let a = IrisEstimator::new(IrisParams::default()).unwrap();
    let b = IrisEstimator::new(IrisParams {
        patch_width: 32,
        ..IrisParams::default()
    })
    .unwrap();
    let mut ws = b.new_workspace();
    let mut out = IrisFrame::default();
    let img = GrayImage::new(32, 32);
    assert!(matches!(
        a.estimate_into(&img, &Landmarks68::default(), &mut ws, &mut out),
        Err(facecap_landmarks::Error::DimensionMismatch { .. })
    ));
}

fn eye(u: f64, v: f64) -> EyeEstimate {
    EyeEstimate {
        u,
        v,
        status: EyeStatus::Valid,
        confidence: 1.0,
        ..EyeEstimate::default()
    }
}

/// Both eyes resting at `(0.5, 0)`, every gain 10.
fn centred_rest_and_even_gains() -> (GazeRest, GazeGains) {
    let rest = GazeRest {
        right: EyeRest { u: 0.5, v: 0.0 },
        left: EyeRest { u: 0.5, v: 0.0 },
    };
    let gains = GazeGains {
        look_in: 10.0,
        look_out: 10.0,
        look_up: 10.0,
        look_down: 10.0,
    };
    (rest, gains)
}

/// Index of a gaze weight by name.
fn idx(name: &str) -> usize {
    GAZE_WEIGHT_NAMES.iter().position(|n| *n == name).unwrap()
}

#[test]
fn gaze_weights_follow_the_arkit_sides() {
    let (rest, gains) = centred_rest_and_even_gains();
    // looking towards the subject's left (image right): the right eye's iris moves to its
    // inner corner (u up), the left eye's to its outer corner (u down); and down
    let f = IrisFrame {
        right: eye(0.55, 0.03),
        left: eye(0.45, 0.03),
    };
    let w = gaze_weights(&f, &rest, &gains);
    assert!((w[idx("eyeLookOutLeft")] - 0.5).abs() < 1e-12);
    assert!((w[idx("eyeLookInRight")] - 0.5).abs() < 1e-12);
    assert_eq!(w[idx("eyeLookInLeft")], 0.0);
    assert_eq!(w[idx("eyeLookOutRight")], 0.0);
    assert!((w[idx("eyeLookDownLeft")] - 0.3).abs() < 1e-12);
    assert!((w[idx("eyeLookDownRight")] - 0.3).abs() < 1e-12);
    assert_eq!(w[idx("eyeLookUpLeft")], 0.0);
    // clamped to 1; up
    let f = IrisFrame {
        right: eye(0.1, -0.5),
        left: eye(0.9, -0.5),
    };
    let w = gaze_weights(&f, &rest, &gains);
    assert_eq!(w[idx("eyeLookOutRight")], 1.0);
    assert_eq!(w[idx("eyeLookInLeft")], 1.0);
    assert_eq!(w[idx("eyeLookUpLeft")], 1.0);
    assert_eq!(w[idx("eyeLookUpRight")], 1.0);
    // one eye invalid: it mirrors the other
    let f = IrisFrame {
        right: eye(0.55, 0.03),
        left: EyeEstimate::default(),
    };
    let w = gaze_weights(&f, &rest, &gains);
    assert!((w[idx("eyeLookOutLeft")] - 0.5).abs() < 1e-12);
    assert!((w[idx("eyeLookDownLeft")] - 0.3).abs() < 1e-12);
    // both invalid: all zero; NaN never leaks
    assert_eq!(gaze_weights(&IrisFrame::default(), &rest, &gains), [0.0; 8]);
    let f = IrisFrame {
        right: eye(f64::NAN, 0.0),
        left: eye(0.5, f64::NAN),
    };
    assert!(gaze_weights(&f, &rest, &gains).iter().all(|w| (0.0..=1.0).contains(w)));
    // rest from a clip: per-eye medians of the valid estimates only
    let frames = [
        IrisFrame {
            right: eye(0.4, 0.0),
            left: eye(0.6, 0.1),
        },
        IrisFrame {
            right: eye(0.5, 0.2),
            left: EyeEstimate::default(),
        },
        IrisFrame {
            right: eye(0.9, 0.1),
            left: eye(0.2, 0.3),
        },
    ];
    let r = GazeRest::median_of(&frames).unwrap();
    assert_eq!((r.right.u, r.right.v), (0.5, 0.1));
    assert!((r.left.u - 0.4).abs() < 1e-12 && (r.left.v - 0.2).abs() < 1e-12);
    assert!(GazeRest::median_of(&[IrisFrame::default()]).is_none());
    // the capture's rest: u halfway between the clip's median and the straight gaze, v the
    // median; a subject who looks inwards all along then reads eyeLookIn
    let t = GazeRest::towards_straight_ahead(&frames).unwrap();
    let half = |m: f64| REST_MEDIAN_SHARE * m + (1.0 - REST_MEDIAN_SHARE) * STRAIGHT_AHEAD_U;
    assert!((t.right.u - half(0.5)).abs() < 1e-12 && (t.left.u - half(0.4)).abs() < 1e-12);
    assert_eq!((t.right.v, t.left.v), (r.right.v, r.left.v));
    let inwards = [IrisFrame {
        right: eye(0.62, 0.0),
        left: eye(0.62, 0.0),
    }];
    let t = GazeRest::towards_straight_ahead(&inwards).unwrap();
    let w = gaze_weights(&inwards[0], &t, &gains);
    assert!(w[idx("eyeLookInLeft")] > 0.1 && w[idx("eyeLookInRight")] > 0.1);
    assert_eq!(
        gaze_weights(&inwards[0], &GazeRest::median_of(&inwards).unwrap(), &gains),
        [0.0; 8]
    );
    assert!(GazeRest::towards_straight_ahead(&[IrisFrame::default()]).is_none());
}

#[test]
fn the_estimator_is_shareable_between_threads() {
    fn send_sync<T: Send + Sync>(_: &T) {}
    let est = IrisEstimator::new(IrisParams::default()).unwrap();
    send_sync(&est);
    // one estimator, one workspace per thread, identical results
    let eyes = face(
        Point2::new(160.0, 120.0),
        44.0,
        0.2,
        0.22,
        (0.45, 0.02),
        (0.55, -0.02),
        0.12,
    );
    let (img, lm) = render(320, 240, &eyes);
    let here = run(&img, &lm);
    let there = std::thread::scope(|s| {
        s.spawn(|| {
            let mut ws = est.new_workspace();
            let mut out = IrisFrame::default();
            est.estimate_into(&img, &lm, &mut ws, &mut out).unwrap();
            out
        })
        .join()
        .unwrap()
    });
    assert_eq!(here, there);
}

#[test]
fn a_head_turn_at_a_fixed_line_of_sight_turns_the_eyes_in_the_head() {
    let (rest, gains) = centred_rest_and_even_gains();
    let at_rest = IrisFrame {
        right: eye(0.5, 0.0),
        left: eye(0.5, 0.0),
    };
    let k = HEAD_TURN_EYE_WIDTHS;
    // irises where they rest in the image, head pitched chin down by 0.2: the eyes look up
    // in the head (as they must to stay on the camera)
    let w = gaze_weights_in_head(&at_rest, &rest, &gains, HeadTurn { pitch: 0.2, yaw: 0.0 });
    for side in ["Left", "Right"] {
        let up = w[idx(&format!("eyeLookUp{side}"))];
        assert!((up - 10.0 * k * 0.2).abs() < 1e-12, "eyeLookUp{side} {up}");
        assert_eq!(w[idx(&format!("eyeLookDown{side}"))], 0.0);
    }
    // head turned towards the subject's right by 0.2: the eyes turn to the subject's left
    // in the head, the left eye out and the right eye in
    let w = gaze_weights_in_head(&at_rest, &rest, &gains, HeadTurn { pitch: 0.0, yaw: 0.2 });
    assert!((w[idx("eyeLookOutLeft")] - 10.0 * k * 0.2).abs() < 1e-12);
    assert!((w[idx("eyeLookInRight")] - 10.0 * k * 0.2).abs() < 1e-12);
    assert_eq!(w[idx("eyeLookInLeft")], 0.0);
    assert_eq!(w[idx("eyeLookOutRight")], 0.0);
    // the eyes turned with the head (irises moved in the image by the same offset): no
    // turn in the head
    let with_head = IrisFrame {
        right: eye(0.5 - k * 0.2, 0.0),
        left: eye(0.5 + k * 0.2, 0.0),
    };
    let w = gaze_weights_in_head(&with_head, &rest, &gains, HeadTurn { pitch: 0.0, yaw: 0.2 });
    assert!(w.iter().all(|x| x.abs() < 1e-12), "{w:?}");
    // no turn, or a non-finite one, is `gaze_weights`
    let f = IrisFrame {
        right: eye(0.55, 0.03),
        left: eye(0.45, 0.03),
    };
    for head in [
        HeadTurn::default(),
        HeadTurn {
            pitch: f64::NAN,
            yaw: 0.1,
        },
    ] {
        assert_eq!(
            gaze_weights_in_head(&f, &rest, &gains, head),
            gaze_weights(&f, &rest, &gains)
        );
    }
}
