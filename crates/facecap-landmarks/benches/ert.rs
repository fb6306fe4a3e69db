//! One ERT landmark prediction (dlib's 68- and 5-point models) on a 640x480 face.
//!
//! Input: frame 0 of the shared clip `videos/liveportrait_d9.mp4` (512x480, decoded
//! to grey by the ffmpeg CLI) edge-padded to 640x480 like the dlib anchor script,
//! with the face box dlib's HOG detector found on it (from the agreement fixture);
//! without the data a seeded synthetic 640x480 image and a 260 px box. Workspaces
//! are built outside the timed loop.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_core::landmarks::Rect;
use facecap_core::paths::{model_file_or_skip, shared_data_file, DLIB_5_MODEL, DLIB_68_MODEL};
use facecap_landmarks::ert::{ErtParams, ErtPrecision, ShapePredictor};
use image::GrayImage;
use nalgebra::Point2;

const PAD: u32 = 64;

fn face_640x480() -> (GrayImage, Rect, &'static str) {
    let synthetic = || {
        let mut img = GrayImage::new(640, 480);
        for (x, y, p) in img.enumerate_pixels_mut() {
            let v = (x * 7 + y * 13) ^ (x * y);
            p.0[0] = (v % 251) as u8;
        }
        (img, Rect::from_dlib(190, 110, 449, 369), "synthetic")
    };
    let Some(path) = shared_data_file("bench ert", "videos/liveportrait_d9.mp4") else {
        return synthetic();
    };
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output();
    let Ok(out) = out else { return synthetic() };
    if out.stdout.len() != 512 * 480 {
        return synthetic();
    }
    let src = GrayImage::from_raw(512, 480, out.stdout).unwrap();
    let img = GrayImage::from_fn(640, 480, |x, y| {
        let sx = x.saturating_sub(PAD).min(511);
        *src.get_pixel(sx, y)
    });
    // dlib HOG box of frame 0 (testdata/dlib_ert/fixture.json), shifted by the padding
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_ert/fixture.json");
    let text = std::fs::read_to_string(fixture).unwrap_or_default();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or(serde_json::Value::Null);
    let item = v["items"].as_array().and_then(|items| {
        items
            .iter()
            .find(|i| i["file"] == "videos/liveportrait_d9.mp4" && i["frame"] == 0)
            .cloned()
    });
    let Some(item) = item else { return synthetic() };
    let b: Vec<i64> = item["box"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_i64().unwrap())
        .collect();
    let p = i64::from(PAD);
    (
        img,
        Rect::from_dlib(b[0] + p, b[1], b[2] + p, b[3]),
        "liveportrait_d9 frame 0 padded",
    )
}

/// The first 200 frames of `videos/liveportrait_d9.mp4` (grey, 512x480) with dlib's
/// HOG box of each from the agreement fixture, like the dlib anchor script's cycle of
/// frames (different faces read different leaves, so the leaf table is not all cached).
fn frames_d9() -> Vec<(GrayImage, Rect)> {
    let Some(path) = shared_data_file("bench ert", "videos/liveportrait_d9.mp4") else {
        return Vec::new();
    };
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/dlib_ert/fixture.json");
    let text = std::fs::read_to_string(fixture).unwrap_or_default();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or(serde_json::Value::Null);
    let Some(items) = v["items"].as_array() else {
        return Vec::new();
    };
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-frames:v", "200", "-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output();
    let Ok(out) = out else { return Vec::new() };
    let frames: Vec<&[u8]> = out.stdout.chunks_exact(512 * 480).collect();
    items
        .iter()
        .filter(|i| i["file"] == "videos/liveportrait_d9.mp4")
        .filter_map(|i| {
            let f = frames.get(i["frame"].as_u64()? as usize)?;
            let b: Vec<i64> = i["box"]
                .as_array()?
                .iter()
                .filter_map(serde_json::Value::as_i64)
                .collect();
            let img = GrayImage::from_raw(512, 480, f.to_vec())?;
            Some((img, Rect::from_dlib(b[0], b[1], b[2], b[3])))
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let (img, rect, what) = face_640x480();
    eprintln!("ert bench input: {what}, box {:?}", rect.to_dlib());
    let clip = frames_d9();
    eprintln!(
        "ert bench clip: {} frames of liveportrait_d9 with a dlib box",
        clip.len()
    );
    let mut g = c.benchmark_group("ert");
    g.sample_size(30).measurement_time(std::time::Duration::from_secs(4));
    for (name, label) in [
        (DLIB_68_MODEL, "predict_68pt_640x480"),
        (DLIB_5_MODEL, "predict_5pt_640x480"),
    ] {
        let Some(path) = model_file_or_skip("bench ert", name) else {
            continue;
        };
        let exact = ShapePredictor::from_file(&path).unwrap();
        let fast = exact.clone().with_params(ErtParams {
            precision: ErtPrecision::Fast,
            ..Default::default()
        });
        let mut ws = exact.new_workspace();
        let mut out = vec![Point2::origin(); exact.num_parts()];
        for (sp, suffix) in [(&exact, ""), (&fast, "_fast")] {
            g.bench_function(format!("{label}{suffix}"), |b| {
                b.iter(|| {
                    sp.predict_into(std::hint::black_box(&img), &rect, &mut ws, &mut out)
                        .unwrap();
                })
            });
        }
        if !clip.is_empty() {
            let cycle = label.replace("640x480", "d9_200_frames");
            for (sp, suffix) in [(&exact, ""), (&fast, "_fast")] {
                let mut next = 0usize;
                g.bench_function(format!("{cycle}{suffix}"), |b| {
                    b.iter(|| {
                        let (img, rect) = &clip[next % clip.len()];
                        next += 1;
                        sp.predict_into(std::hint::black_box(img), rect, &mut ws, &mut out)
                            .unwrap();
                    })
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
