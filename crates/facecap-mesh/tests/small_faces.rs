//! The small-face search (`FaceDetector::detect_small_into`, `MeshParams::small_faces`)
//! against the hand-made face boxes of dlib's face landmark data set and the 68-point
//! annotations of the shared annotated photos (research-only data, read from
//! `../shared/data/annotated`; the test skips without it).
//!
//! BlazeFace short range on the whole image (MediaPipe's FaceLandmarker) finds no face in
//! group photos whose faces are 30-155 px wide; the search must find them, and nothing
//! that is not an annotated face.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use facecap_mesh::{Detection, FaceMesh, MeshParams, RgbView};

/// `(left, top, width, height)` pixel boxes of one image in dlib's XML.
fn xml_boxes(xml: &str, file: &str) -> Vec<[f32; 4]> {
    let start = xml
        .find(&format!("<image file='{file}'"))
        .unwrap_or_else(|| panic!("{file} not in the XML"));
    let block = &xml[start..start + xml[start..].find("</image>").unwrap()];
    let attr = |tag: &str, name: &str| -> f32 {
        let k = tag.find(&format!("{name}='")).unwrap() + name.len() + 2;
        tag[k..k + tag[k..].find('\'').unwrap()].parse().unwrap()
    };
    block
        .split("<box ")
        .skip(1)
        .map(|t| [attr(t, "left"), attr(t, "top"), attr(t, "width"), attr(t, "height")])
        .collect()
}

/// The detection's box centre in pixels.
fn centre(d: &Detection, w: u32, h: u32) -> (f32, f32) {
    (
        (d.xmin + d.width / 2.0) * w as f32,
        (d.ymin + d.height / 2.0) * h as f32,
    )
}

#[test]
fn small_faces_of_group_photos_are_found_and_nothing_else() {
    let test = "small_faces_of_group_photos_are_found_and_nothing_else";
    let Some(tracker) = tracker(test, MeshParams::default()) else {
        return;
    };
    let detector = tracker.detector();
    let Some(xml_path) =
        facecap_core::paths::shared_data_file(test, "annotated/dlib_faces/training_with_face_landmarks.xml")
    else {
        return;
    };
    let Some(test_xml) = facecap_core::paths::shared_data_file(
        test,
        "annotated/dlib_faces/testing_subset_shared_with_face_landmarks.xml",
    ) else {
        return;
    };
    let xml = std::fs::read_to_string(xml_path).unwrap() + &std::fs::read_to_string(test_xml).unwrap();
    let mut ws = detector.workspace();
    let mut dets = Vec::new();
    // (image, faces the search must find)
    let cases = [("2007_007763.jpg", 6), ("2008_002470.jpg", 4)];
    for (file, want) in cases {
        let Some(path) = facecap_core::paths::shared_data_file(test, &format!("annotated/dlib_faces/{file}")) else {
            return;
        };
        let img = image::open(&path).unwrap().to_rgb8();
        let view = RgbView::from_image(&img).unwrap();
        let boxes = xml_boxes(&xml, file);
        let inside = |d: &Detection| {
            let (x, y) = centre(d, img.width(), img.height());
            boxes
                .iter()
                .position(|b| x >= b[0] && x <= b[0] + b[2] && y >= b[1] && y <= b[1] + b[3])
        };
        let faces_hit = |dets: &[Detection]| {
            let mut hit: Vec<usize> = dets.iter().filter_map(inside).collect();
            hit.sort_unstable();
            hit.dedup();
            hit.len()
        };
        detector.detect_into(&view, &mut ws, &mut dets).unwrap();
        let whole = faces_hit(&dets);
        detector.detect_small_into(&view, &mut ws, &mut dets).unwrap();
        let hit = faces_hit(&dets);
        eprintln!(
            "{file}: {} annotated faces; whole image finds {whole}, the small-face search {hit} ({} detections)",
            boxes.len(),
            dets.len()
        );
        // MediaPipe's FaceLandmarker finds none of these faces
        assert!(
            whole < 2,
            "{file}: the whole-image pass finds {whole} faces; update the test"
        );
        assert!(hit >= want, "{file}: {hit} of {} faces found", boxes.len());
        for d in &dets {
            assert!(
                inside(d).is_some(),
                "{file}: detection at {:?} is no annotated face",
                centre(d, img.width(), img.height())
            );
        }
    }
}

#[test]
fn the_tracker_finds_a_small_annotated_face_in_a_large_photo() {
    let test = "the_tracker_finds_a_small_annotated_face_in_a_large_photo";
    let Some(tracker) = tracker(test, MeshParams::default()) else {
        return;
    };
    // a 1864 x 1529 group photo; the annotated face is 142 px wide (8 % of the long side)
    let Some(path) = facecap_core::paths::shared_data_file(test, "annotated/helen/2086996835_5.jpg") else {
        return;
    };
    let want = facecap_io::formats::pts::read_pts(path.with_extension("pts")).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    let view = RgbView::from_image(&img).unwrap();
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    let off = common::tracker(
        test,
        MeshParams {
            small_faces: false,
            ..MeshParams::default()
        },
    )
    .unwrap();
    let report = off
        .track_into(&view, 0.0, &mut off.workspace(), &mut off.state(), &mut mesh)
        .unwrap();
    assert!(
        !report.has_face(),
        "without the search (MediaPipe's behaviour) no face: {report:?}"
    );
    let report = tracker
        .track_into(&view, 0.0, &mut ws, &mut tracker.state(), &mut mesh)
        .unwrap();
    assert!(report.has_face(), "{report:?}");
    let got = facecap_mesh::ibug68::ibug68(&mesh.points).unwrap();
    let nme = facecap_core::landmarks::Landmarks68::from_slice(&got)
        .unwrap()
        .normalised_mean_error(&want);
    eprintln!("2086996835_5.jpg: found the annotated face, NME {nme:.4} (inter-ocular)");
    // the mesh's 68 points against the hand annotation (the other annotated faces the mesh
    // finds: mean 0.045); a face elsewhere would be > 1
    assert!(nme < 0.1, "NME {nme}");
}

#[test]
fn tiles_cover_the_image_and_overlap_by_a_third() {
    for (w, h) in [(480, 480), (1920, 1080), (817, 1024), (64, 2000), (1, 1)] {
        let tiles: Vec<_> = facecap_mesh::Window::tiles(w, h).collect();
        let side = w.max(h) as f32 / 3.0;
        assert!(!tiles.is_empty());
        for axis in [0, 1] {
            let len = [w, h][axis] as f32;
            let mut c: Vec<f32> = tiles.iter().map(|t| [t.cx, t.cy][axis]).collect();
            c.sort_by(f32::total_cmp);
            c.dedup();
            if len > side {
                assert!((c[0] - side / 2.0).abs() < 1e-3, "{w}x{h}: first window flush");
                assert!(
                    (c[c.len() - 1] - (len - side / 2.0)).abs() < 1e-2,
                    "{w}x{h}: last window flush"
                );
                for p in c.windows(2) {
                    assert!(
                        p[1] - p[0] <= side * 2.0 / 3.0 + 1e-3,
                        "{w}x{h}: windows overlap by a third"
                    );
                }
            } else {
                assert_eq!(c, vec![len / 2.0], "{w}x{h}: one centred window");
            }
        }
        assert!(tiles.iter().all(|t| t.side == side));
    }
    assert_eq!(facecap_mesh::Window::tiles(480, 480).count(), 16);
    assert_eq!(facecap_mesh::Window::tiles(1920, 1080).count(), 12);
}

/// `MeshTracker::faces_in_image` (the images mode of `facecap landmarks --landmarks mesh`)
/// gives every annotated face of the group photos, once each, largest first.
#[test]
fn every_face_of_a_group_photo_gets_its_mesh_once() {
    let test = "every_face_of_a_group_photo_gets_its_mesh_once";
    let Some(tracker) = tracker(test, MeshParams::default()) else {
        return;
    };
    let mut xml = String::new();
    for name in [
        "training_with_face_landmarks.xml",
        "testing_subset_shared_with_face_landmarks.xml",
    ] {
        let Some(p) = facecap_core::paths::shared_data_file(test, &format!("annotated/dlib_faces/{name}")) else {
            return;
        };
        xml += &std::fs::read_to_string(p).unwrap();
    }
    let mut ws = tracker.workspace();
    for file in ["2007_007763.jpg", "2008_002470.jpg"] {
        let Some(path) = facecap_core::paths::shared_data_file(test, &format!("annotated/dlib_faces/{file}")) else {
            return;
        };
        let img = image::open(&path).unwrap().to_rgb8();
        let faces = tracker
            .faces_in_image(&RgbView::from_image(&img).unwrap(), &mut ws)
            .unwrap();
        let boxes = xml_boxes(&xml, file);
        // each face's nose tip (mesh point 1) in its own annotated box
        let mut hit: Vec<usize> = faces
            .iter()
            .map(|f| {
                let p = f.mesh.points[1];
                boxes
                    .iter()
                    .position(|b| p[0] >= b[0] && p[0] <= b[0] + b[2] && p[1] >= b[1] && p[1] <= b[1] + b[3])
                    .unwrap_or_else(|| panic!("{file}: a face at {p:?} is no annotated face"))
            })
            .collect();
        eprintln!("{file}: {} faces of {} annotated", faces.len(), boxes.len());
        let n = hit.len();
        hit.sort_unstable();
        hit.dedup();
        assert_eq!(hit.len(), n, "{file}: a face found twice");
        assert_eq!(n, boxes.len(), "{file}: {n} of {} faces", boxes.len());
        let areas: Vec<f32> = faces
            .iter()
            .map(|f| {
                let b = f.bounds();
                (b[2] - b[0]) * (b[3] - b[1])
            })
            .collect();
        assert!(
            areas.windows(2).all(|a| a[0] >= a[1]),
            "{file}: not largest first: {areas:?}"
        );
        assert!(faces.iter().all(|f| f.mesh.presence >= 0.5));
    }
}
