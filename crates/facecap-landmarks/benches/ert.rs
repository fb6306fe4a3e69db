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
use facecap_landmarks::ert::ShapePredictor;
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

fn bench(c: &mut Criterion) {
    let (img, rect, what) = face_640x480();
    eprintln!("ert bench input: {what}, box {:?}", rect.to_dlib());
    let mut g = c.benchmark_group("ert");
    g.sample_size(30).measurement_time(std::time::Duration::from_secs(4));
    for (name, label) in [
        (DLIB_68_MODEL, "predict_68pt_640x480"),
        (DLIB_5_MODEL, "predict_5pt_640x480"),
    ] {
        let Some(path) = model_file_or_skip("bench ert", name) else {
            continue;
        };
        let sp = ShapePredictor::from_file(&path).unwrap();
        let mut ws = sp.new_workspace();
        let mut out = vec![Point2::origin(); sp.num_parts()];
        g.bench_function(label, |b| {
            b.iter(|| {
                sp.predict_into(std::hint::black_box(&img), &rect, &mut ws, &mut out)
                    .unwrap();
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
