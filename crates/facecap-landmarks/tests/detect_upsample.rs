#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! `Upsample::Auto` against dlib's `detector(img, 1)` (what dlib's example programs
//! call) on every shared annotated image (fixture `testdata/dlib_hog/upsample_fixture.json`,
//! made by `make_upsample_fixture.py` beside it), and `Upsample::Times(n)` equal to dlib.
//!
//! Judged per image: every box dlib finds with `detector(img, 1)` is found (IoU >= 0.5),
//! and every box we return is one dlib reports with `detector(img, 0)` or
//! `detector(img, 1)` (IoU >= 0.5), so `Auto` adds no box dlib does not report.

mod detect_common;

use std::path::PathBuf;

use detect_common::{ffmpeg_rgb, grey_sum, have_ffmpeg, to_grey};
use facecap_core::landmarks::Rect;
use facecap_core::paths;
use facecap_landmarks::detect::{DetectorParams, FaceDetector, Par, Upsample, DLIB_FRONTAL_MODEL};
use image::GrayImage;
use serde_json::Value;

/// IoU at which two boxes are taken to be the same face.
const SAME_FACE_IOU: f64 = 0.5;

struct Case {
    source: String,
    grey: GrayImage,
    /// dlib's boxes for upsample 0 and 1.
    dlib: [Vec<Rect>; 2],
}

fn rect_of(v: &Value) -> Rect {
    let l: Vec<i64> = v["ltrb"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_i64().unwrap())
        .collect();
    Rect::from_dlib(l[0], l[1], l[2], l[3])
}

/// The fixture's cases with their decoded grey images, or `None` (after a `SKIP:`
/// line) without the model, the shared data or ffmpeg.
fn cases(test: &str) -> Option<(FaceDetector, Vec<Case>)> {
    let model = paths::model_file_or_skip(test, DLIB_FRONTAL_MODEL)?;
    if paths::shared_data_dir().is_none() {
        facecap_core::paths::skip_missing_data(&format!("{test}: shared data absent"));
        return None;
    }
    if !have_ffmpeg() {
        facecap_core::paths::skip_missing_data(&format!("{test}: ffmpeg not installed"));
        return None;
    }
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_hog/upsample_fixture.json");
    let fx: Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    let mut out = Vec::new();
    for c in fx["cases"].as_array().unwrap() {
        let source = c["source"].as_str().unwrap().to_string();
        let path = paths::shared_data_file(test, &source)?;
        let (w, h) = (
            c["width"].as_u64().unwrap() as u32,
            c["height"].as_u64().unwrap() as u32,
        );
        let grey = to_grey(&ffmpeg_rgb(&path, None, w, h).unwrap().remove(0));
        assert_eq!(
            grey_sum(&grey),
            c["grey_sum"].as_u64().unwrap(),
            "{source}: grey input differs"
        );
        let runs = c["runs"].as_array().unwrap();
        let boxes = |u: u64| -> Vec<Rect> {
            let r = runs.iter().find(|r| r["upsample"].as_u64() == Some(u)).unwrap();
            r["dets"].as_array().unwrap().iter().map(rect_of).collect()
        };
        out.push(Case {
            source,
            grey,
            dlib: [boxes(0), boxes(1)],
        });
    }
    Some((FaceDetector::from_file(&model).unwrap(), out))
}

fn with(det: &FaceDetector, upsample: Upsample) -> FaceDetector {
    det.clone()
        .with_params(DetectorParams {
            upsample,
            par: Par::Rayon, // identical to Par::Seq, faster
            ..Default::default()
        })
        .unwrap()
}

fn best_iou(r: &Rect, among: &[Rect]) -> f64 {
    among.iter().map(|o| o.iou(r)).fold(0.0, f64::max)
}

#[test]
fn fixed_upsampling_equals_dlib_on_every_annotated_image() {
    let Some((det, cases)) = cases("detect_upsample_fixed") else {
        return;
    };
    let mut boxes = 0;
    for u in [0u32, 1] {
        let d = with(&det, Upsample::Times(u));
        let mut ws = d.new_workspace();
        for c in &cases {
            let mut ours: Vec<_> = d
                .detect(&c.grey, &mut ws)
                .unwrap()
                .iter()
                .map(|x| x.rect.to_dlib())
                .collect();
            let mut theirs: Vec<_> = c.dlib[u as usize].iter().map(Rect::to_dlib).collect();
            ours.sort_unstable();
            theirs.sort_unstable();
            assert_eq!(ours, theirs, "{} upsample {u}", c.source);
            boxes += theirs.len();
        }
    }
    eprintln!(
        "upsample 0 and 1: {} images, {boxes} dlib boxes, all equal",
        cases.len()
    );
}

#[test]
fn auto_finds_every_face_dlib_upsample_one_finds_and_nothing_dlib_does_not_report() {
    let Some((det, cases)) = cases("detect_upsample_auto") else {
        return;
    };
    let d = with(&det, Upsample::Auto);
    let mut ws = d.new_workspace();
    let (mut dlib1, mut found, mut exact, mut ours_total, mut beyond_up1) = (0, 0, 0, 0, 0);
    let mut min_iou = 1.0f64;
    let mut failures = Vec::new();
    for c in &cases {
        let ours: Vec<Rect> = d.detect(&c.grey, &mut ws).unwrap().iter().map(|x| x.rect).collect();
        ours_total += ours.len();
        for t in &c.dlib[1] {
            dlib1 += 1;
            let iou = best_iou(t, &ours);
            if iou >= SAME_FACE_IOU {
                found += 1;
                min_iou = min_iou.min(iou);
                exact += usize::from(ours.iter().any(|o| o.to_dlib() == t.to_dlib()));
            } else {
                failures.push(format!(
                    "{}: dlib upsample-1 box {:?} not found (best IoU {iou:.2})",
                    c.source,
                    t.to_dlib()
                ));
            }
        }
        for o in &ours {
            if best_iou(o, &c.dlib[1]) < SAME_FACE_IOU {
                beyond_up1 += 1;
                if best_iou(o, &c.dlib[0]) < SAME_FACE_IOU {
                    failures.push(format!(
                        "{}: box {:?} is reported by neither dlib call",
                        c.source,
                        o.to_dlib()
                    ));
                }
            }
        }
    }
    eprintln!(
        "auto vs dlib detector(img, 1): {} images, dlib boxes {dlib1}, found {found} (identical {exact}, min IoU {min_iou:.3}); \
         ours {ours_total}, of which {beyond_up1} only in dlib's detector(img, 0)",
        cases.len()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(dlib1 > 0);
}

#[test]
fn auto_scans_the_skipped_levels_when_nothing_else_is_found() {
    // The 37-43 px faces of a dlib example photo, placed on a larger grey canvas, are
    // smaller than the levels `Auto` scans first on a 1000 px image: the fall-back must
    // give exactly dlib's upsample-1 result.
    let Some(model) = paths::model_file_or_skip("detect_upsample_fallback", DLIB_FRONTAL_MODEL) else {
        return;
    };
    let Some(path) = paths::shared_data_file("detect_upsample_fallback", "annotated/dlib_faces/2008_002470.jpg") else {
        return;
    };
    let small = image::open(path).unwrap().to_luma8();
    let mut canvas = GrayImage::from_pixel(1000, 1000, image::Luma([128]));
    image::imageops::replace(&mut canvas, &small, 100, 200);
    let det = FaceDetector::from_file(&model).unwrap();
    let auto = with(&det, Upsample::Auto);
    let up1 = with(&det, Upsample::Times(1));
    let a = auto.detect(&canvas, &mut auto.new_workspace()).unwrap();
    let b = up1.detect(&canvas, &mut up1.new_workspace()).unwrap();
    assert!(b.len() >= 4, "{b:?}");
    assert!(b.iter().all(|x| x.rect.width < 80.0), "{b:?}");
    assert_eq!(a, b);
    // a workspace that just fell back holds candidates of the finest levels; a
    // following image where the first pass finds its face must not see them
    let Some(big) = paths::shared_data_file("detect_upsample_fallback", "annotated/lfpw/image_0004.png") else {
        return;
    };
    let big = image::open(big).unwrap().to_luma8();
    let mut ws = auto.new_workspace();
    assert_eq!(auto.detect(&canvas, &mut ws).unwrap(), b);
    let fresh = auto.detect(&big, &mut auto.new_workspace()).unwrap();
    assert!(!fresh.is_empty());
    assert_eq!(auto.detect(&big, &mut ws).unwrap(), fresh);
}
