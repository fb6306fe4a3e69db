#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, missing_docs)]
//! Per-frame time of the HOG face detector on the benchmark frames, for same-sitting
//! comparisons with dlib and for instruction counts under callgrind.
//!
//! ```sh
//! cargo run --release -p facecap-landmarks --example detect_timing -- 640x480 20 [0|1|auto] [--write DIR]
//! ```
//!
//! Frames as the criterion bench makes them: the first frame of
//! `videos/liveportrait_d9.mp4` (512x480) edge-padded to 640x480, or scaled 1.5x with
//! image-rs `Triangle` (768x720) and padded to 1280x720. `--write DIR` also writes the
//! frame's raw 8-bit pixels as `DIR/frame_WxH.gray` so `testdata/dlib_hog/time_dlib_detect.py` runs dlib on
//! the same pixels. Prints the boxes and the median wall time of N calls; the
//! instruction count per frame is the difference of two callgrind runs with different N
//! divided by the difference of N.

use std::process::Command;
use std::time::Instant;

use facecap_core::paths;
use facecap_landmarks::detect::{DetectorParams, FaceDetector, Upsample, DLIB_FRONTAL_MODEL};
use image::{imageops, GrayImage};

fn first_frame() -> GrayImage {
    let path = paths::shared_data_file("detect_timing", "videos/liveportrait_d9.mp4").expect("shared data");
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .expect("ffmpeg");
    GrayImage::from_raw(512, 480, out.stdout).expect("one 512x480 frame")
}

fn pad_to(img: &GrayImage, w: u32, h: u32) -> GrayImage {
    let (iw, ih) = img.dimensions();
    let (ox, oy) = ((w.saturating_sub(iw)) / 2, (h.saturating_sub(ih)) / 2);
    GrayImage::from_fn(w, h, |x, y| {
        let sx = (x as i64 - ox as i64).clamp(0, iw as i64 - 1) as u32;
        let sy = (y as i64 - oy as i64).clamp(0, ih as i64 - 1) as u32;
        *img.get_pixel(sx, sy)
    })
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size = args.first().map_or("640x480", String::as_str);
    let n: usize = args.get(1).map_or(20, |s| s.parse().unwrap());
    let upsample: Upsample = args.get(2).map_or("0", String::as_str).parse().unwrap();
    let write = args.iter().position(|a| a == "--write").map(|i| args[i + 1].clone());
    let base = first_frame();
    let img = match size {
        "640x480" => pad_to(&base, 640, 480),
        "1280x720" => pad_to(
            &imageops::resize(&base, 768, 720, imageops::FilterType::Triangle),
            1280,
            720,
        ),
        other => panic!("size {other}: 640x480 or 1280x720"),
    };
    if let Some(dir) = write {
        let p = std::path::Path::new(&dir).join(format!("frame_{size}.gray"));
        std::fs::write(&p, img.as_raw()).unwrap();
        eprintln!("wrote {}", p.display());
    }
    let model = paths::model_file(DLIB_FRONTAL_MODEL).expect("model cache");
    let det = FaceDetector::from_file(&model)
        .unwrap()
        .with_params(DetectorParams {
            upsample,
            ..Default::default()
        })
        .unwrap();
    let mut ws = det.new_workspace();
    let mut out = Vec::new();
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        det.detect_into(&img, &mut ws, &mut out).unwrap();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let boxes: Vec<_> = out
        .iter()
        .map(|d| (d.rect.to_dlib(), (d.score * 1e4).round() / 1e4))
        .collect();
    println!(
        "{size} upsample {upsample}: {n} calls, median {:.2} ms, min {:.2} ms; boxes {boxes:?}",
        times.get(n / 2).copied().unwrap_or(f64::NAN),
        times.first().copied().unwrap_or(f64::NAN)
    );
}
