//! Agreement with dlib: `testdata/dlib_ert/fixture.json` holds dlib 20.0.1's 68- and
//! 5-point landmarks for every face box of the shared annotated images and for the
//! first 200 frames of two shared videos (see `make_fixture.py` beside it). Our
//! predictor must give the same points within 0.01 px.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

use facecap_core::landmarks::Rect;
use facecap_core::paths::{model_file_or_skip, shared_data_file, DLIB_5_MODEL, DLIB_68_MODEL};
use facecap_landmarks::ert::ShapePredictor;
use image::GrayImage;
use nalgebra::Point2;
use serde_json::Value;

const TOLERANCE_PX: f64 = 0.01;
const TEST: &str = "ert_matches_dlib_fixture";

fn fnv1a64(data: &[u8]) -> String {
    let mut h: u64 = 0xCBF2_9CE4_8422_2325;
    for &b in data {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01B3);
    }
    format!("{h:016x}")
}

/// Decodes like the fixture script: ffmpeg CLI to 8-bit grey.
fn decode_grey(path: &Path, w: usize, h: usize, max_frames: Option<usize>) -> Option<Vec<Vec<u8>>> {
    let mut cmd = Command::new("ffmpeg");
    cmd.args(["-nostdin", "-loglevel", "error", "-i"]).arg(path);
    if let Some(n) = max_frames {
        cmd.args(["-frames:v", &n.to_string()]);
    }
    cmd.args(["-f", "rawvideo", "-pix_fmt", "gray", "-"]);
    let out = cmd.output().ok()?;
    if !out.status.success() {
        return None;
    }
    Some(out.stdout.chunks_exact(w * h).map(<[u8]>::to_vec).collect())
}

#[derive(Default)]
struct Stats {
    boxes: usize,
    points: usize,
    max_dev: f64,
    sum_dev: f64,
    differing_points: usize,
    subpixel_max_dev: f64,
}

#[test]
fn ert_matches_dlib_fixture() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_ert/fixture.json");
    let fixture: Value = serde_json::from_str(&std::fs::read_to_string(fixture).unwrap()).unwrap();
    let (Some(m68), Some(m5)) = (
        model_file_or_skip(TEST, DLIB_68_MODEL),
        model_file_or_skip(TEST, DLIB_5_MODEL),
    ) else {
        return;
    };
    if Command::new("ffmpeg").arg("-version").output().is_err() {
        facecap_core::paths::skip_missing_data(&format!("{TEST}: ffmpeg not found"));
        return;
    }
    let models = [
        ("68", ShapePredictor::from_file(&m68).unwrap()),
        ("5", ShapePredictor::from_file(&m5).unwrap()),
    ];
    let sub = [
        (
            "68",
            models[0].1.clone().with_params(facecap_landmarks::ert::ErtParams {
                output: facecap_landmarks::ert::OutputPrecision::SubPixel,
                ..Default::default()
            }),
        ),
        (
            "5",
            models[1].1.clone().with_params(facecap_landmarks::ert::ErtParams {
                output: facecap_landmarks::ert::OutputPrecision::SubPixel,
                ..Default::default()
            }),
        ),
    ];
    let items = fixture["items"].as_array().unwrap();
    let max_frame: usize = items
        .iter()
        .map(|i| i["frame"].as_u64().unwrap() as usize)
        .max()
        .unwrap_or(0);
    let mut frames: HashMap<String, Option<Vec<Vec<u8>>>> = HashMap::new();
    let mut stats: HashMap<(&str, &str), Stats> = HashMap::new();
    let mut skipped = 0;
    for it in items {
        let file = it["file"].as_str().unwrap().to_string();
        let (w, h) = (it["w"].as_u64().unwrap() as usize, it["h"].as_u64().unwrap() as usize);
        let decoded = frames.entry(file.clone()).or_insert_with(|| {
            let path = shared_data_file(TEST, &file)?;
            let is_video = file.starts_with("videos/");
            decode_grey(&path, w, h, is_video.then_some(max_frame + 1))
        });
        let Some(decoded) = decoded else {
            skipped += 1;
            continue;
        };
        let fi = it["frame"].as_u64().unwrap() as usize;
        let Some(raw) = decoded.get(fi) else {
            skipped += 1;
            continue;
        };
        if fnv1a64(raw) != it["hash"].as_str().unwrap() {
            eprintln!("SKIP item {file}#{fi}: this ffmpeg decodes other pixels than the fixture's");
            skipped += 1;
            continue;
        }
        let img = GrayImage::from_raw(w as u32, h as u32, raw.clone()).unwrap();
        let b: Vec<i64> = it["box"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_i64().unwrap())
            .collect();
        let rect = Rect::from_dlib(b[0], b[1], b[2], b[3]);
        let kind = it["kind"].as_str().unwrap();
        let kind: &str = match kind {
            "video" => "video",
            "dlib_xml" => "dlib_xml",
            "pts_bbox" => "pts_bbox",
            _ => "hog",
        };
        for ((name, sp), (_, sp_sub)) in models.iter().zip(&sub) {
            let want: Vec<f64> = it[*name]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let mut ws = sp.new_workspace();
            let mut got = vec![Point2::origin(); sp.num_parts()];
            sp.predict_into(&img, &rect, &mut ws, &mut got).unwrap();
            let mut got_sub = vec![Point2::origin(); sp.num_parts()];
            sp_sub.predict_into(&img, &rect, &mut ws, &mut got_sub).unwrap();
            let s = stats.entry((*name, kind)).or_default();
            s.boxes += 1;
            for (k, (p, q)) in got.iter().zip(&got_sub).enumerate() {
                let (wx, wy) = (want[2 * k], want[2 * k + 1]);
                let d = (p.x - wx).abs().max((p.y - wy).abs());
                s.points += 1;
                s.max_dev = s.max_dev.max(d);
                s.sum_dev += ((p.x - wx).powi(2) + (p.y - wy).powi(2)).sqrt();
                if d > TOLERANCE_PX {
                    s.differing_points += 1;
                    eprintln!(
                        "DIFF {name}-pt {file}#{fi} box {b:?} point {k}: ours ({}, {}) sub-pixel ({:.6}, {:.6}) dlib ({wx}, {wy})",
                        p.x, p.y, q.x, q.y
                    );
                }
                s.subpixel_max_dev = s.subpixel_max_dev.max((q.x - wx).abs().max((q.y - wy).abs()));
            }
        }
    }
    let mut keys: Vec<_> = stats.keys().copied().collect();
    keys.sort();
    eprintln!(
        "model | boxes | points | max |dev| px | mean dev px | points > {TOLERANCE_PX} px | sub-pixel max |dev| px"
    );
    let mut worst: f64 = 0.0;
    let mut total = 0;
    for k in keys {
        let s = &stats[&k];
        eprintln!(
            "{}-pt {} | {} | {} | {:.4} | {:.6} | {} | {:.4}",
            k.0,
            k.1,
            s.boxes,
            s.points,
            s.max_dev,
            s.sum_dev / s.points.max(1) as f64,
            s.differing_points,
            s.subpixel_max_dev
        );
        worst = worst.max(s.max_dev);
        total += s.boxes;
    }
    eprintln!("checked {total} model x box pairs, skipped {skipped} items");
    if total == 0 {
        facecap_core::paths::skip_missing_data(&format!("{TEST}: no fixture item could be checked"));
        return;
    }
    assert!(
        worst <= TOLERANCE_PX,
        "max deviation from dlib {worst} px > {TOLERANCE_PX} px"
    );
}
