#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Property-based fuzzing of facecap-core's parsers (see `fuzz_common`): every mutated
//! input is an `Ok` or an `Err`, never a panic or an abort. Inputs tried per target are
//! the case counts below (docs/reliability.md); the whole file runs in a few seconds.

mod fuzz_common;

use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::mesh::{Mesh, MorphMesh, MorphTarget};
use facecap_io::csv::{landmark_columns, parse_frame_csv, FrameCsvWriter, FrameRow};
use facecap_io::formats::dlib_xml::parse_dlib_xml;
use facecap_io::formats::ljson::{ljson_to_string, parse_ljson, Ljson};
use facecap_io::formats::pts::{parse_pts, pts_to_string};
use facecap_io::gltf_io::{read_morph_file_from_slice, write_glb, MorphAnimation};
use facecap_io::obj::{obj_to_string, parse_obj};
use facecap_io::video::{open_source, Frame, SourceOptions};
use fuzz_common::{config, mutated};
use nalgebra::{Point2, Point3, Vector3};
use proptest::prelude::*;

/// Inputs tried per target.
const TEXT_CASES: u32 = 3000;
const GLTF_CASES: u32 = 1500;
const Y4M_CASES: u32 = 400;

fn face() -> Landmarks68 {
    Landmarks68::from_fn(|i| (100.0 + (i % 17) as f64 * 7.5, 80.0 + (i / 17) as f64 * 20.0))
}

fn tri_mesh() -> MorphMesh {
    let positions = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
        Point3::new(1.0, 1.0, 0.2),
    ];
    MorphMesh {
        base: Mesh {
            positions,
            triangles: vec![[0, 1, 2], [2, 1, 3]],
            normals: Vec::new(),
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
        },
        targets: vec![MorphTarget {
            name: "jawOpen".into(),
            deltas: vec![Vector3::new(0.0, -0.1, 0.0); 4],
        }],
    }
}

fn pts_seed() -> Vec<u8> {
    pts_to_string(&face().points).unwrap().into_bytes()
}

fn ljson_seed() -> Vec<u8> {
    ljson_to_string(&Ljson::from_landmarks68("PTS", &face()))
        .unwrap()
        .into_bytes()
}

fn obj_seed() -> Vec<u8> {
    obj_to_string(&tri_mesh().base).unwrap().into_bytes()
}

fn xml_seed() -> Vec<u8> {
    br#"<?xml version='1.0' encoding='ISO-8859-1'?>
<dataset><name>faces</name><comment>c</comment><images>
<image file='a.png' width='640' height='480'>
  <box top='10' left='20' width='100' height='120' ignore='0'>
    <label>face</label><part name='00' x='30' y='40'/><part name='01' x='50' y='60'/>
  </box>
</image></images></dataset>
"#
    .to_vec()
}

fn csv_seed() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("l.csv");
    let mut w = FrameCsvWriter::create(&p, &landmark_columns()).unwrap();
    let mut values = [0.0; 136];
    facecap_io::csv::landmark_values(Some(&face()), &mut values);
    for frame in 0..3u64 {
        w.write_row(&FrameRow {
            frame,
            timestamp: frame as f64 / 30.0,
            success: frame != 1,
            confidence: 0.9,
            values: &values,
        })
        .unwrap();
    }
    w.finish().unwrap();
    std::fs::read(&p).unwrap()
}

fn glb_seed() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("r.glb");
    let anim = MorphAnimation {
        times_s: vec![0.0, 0.5, 1.0],
        weights: vec![vec![0.0], vec![0.5], vec![1.0]],
    };
    write_glb(&p, &tri_mesh(), Some(&anim)).unwrap();
    std::fs::read(&p).unwrap()
}

fn map_seed() -> Vec<u8> {
    let ids: Vec<String> = (0..68).map(|i| (i * 3).to_string()).collect();
    format!("[{}]", ids.join(",")).into_bytes()
}

fn y4m_seed() -> Vec<u8> {
    let frames: Vec<image::GrayImage> = (0..3)
        .map(|k| image::GrayImage::from_pixel(8, 6, image::Luma([40 * k])))
        .collect();
    let mut out = Vec::new();
    facecap_io::video::y4m::write_gray_y4m(&mut out, &frames, 25, 1, false).unwrap();
    out
}

#[test]
fn seeds_are_valid() {
    assert_eq!(parse_pts(&String::from_utf8(pts_seed()).unwrap()).unwrap().len(), 68);
    parse_ljson(&ljson_seed()).unwrap();
    parse_obj(&String::from_utf8(obj_seed()).unwrap()).unwrap();
    parse_dlib_xml(&String::from_utf8(xml_seed()).unwrap()).unwrap();
    assert_eq!(parse_frame_csv(&csv_seed()).unwrap().rows.len(), 3);
    let (_, anim) = read_morph_file_from_slice(&glb_seed(), None).unwrap();
    assert!(anim.is_some());
    LandmarkMap::from_json_str(&String::from_utf8(map_seed()).unwrap()).unwrap();
    let _ = Point2::<f64>::origin();
}

proptest! {
    #![proptest_config(config(TEXT_CASES))]
    #[test]
    fn fuzz_pts(b in mutated(pts_seed())) {
        let _ = parse_pts(&String::from_utf8_lossy(&b));
    }
    #[test]
    fn fuzz_ljson(b in mutated(ljson_seed())) {
        let _ = parse_ljson(&b);
    }
    #[test]
    fn fuzz_obj(b in mutated(obj_seed())) {
        let _ = parse_obj(&String::from_utf8_lossy(&b));
    }
    #[test]
    fn fuzz_dlib_xml(b in mutated(xml_seed())) {
        let _ = parse_dlib_xml(&String::from_utf8_lossy(&b));
    }
    #[test]
    fn fuzz_frame_csv(b in mutated(csv_seed())) {
        if let Ok(t) = parse_frame_csv(&b) {
            let _ = facecap_io::csv::landmarks_from_table(&t);
        }
    }
    #[test]
    fn fuzz_landmark_map(b in mutated(map_seed())) {
        let _ = LandmarkMap::from_json_str(&String::from_utf8_lossy(&b));
    }
}

proptest! {
    #![proptest_config(config(GLTF_CASES))]
    #[test]
    fn fuzz_glb(b in mutated(glb_seed())) {
        let _ = read_morph_file_from_slice(&b, None);
    }
}

proptest! {
    #![proptest_config(config(Y4M_CASES))]
    #[test]
    fn fuzz_y4m(b in mutated(y4m_seed())) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.y4m");
        std::fs::write(&p, &b).unwrap();
        if let Ok(mut src) = open_source(&p, &SourceOptions::default()) {
            let mut f = Frame::default();
            for _ in 0..16 {
                match src.read_into(&mut f) {
                    Ok(true) => {}
                    _ => break,
                }
            }
        }
    }
}
