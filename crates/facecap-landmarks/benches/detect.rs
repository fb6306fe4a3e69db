#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, missing_docs)]
//! Per-frame cost of the HOG face detector on 640x480 and 1280x720 grey frames.
//!
//! Frames as `/work/shared/anchors/bench_dlib_hog.py` makes them: the first frame of
//! `videos/liveportrait_d9.mp4` (512x480) edge-padded to 640x480, and scaled 1.5x
//! (768x720) then edge-padded to 1280x720. Without ffmpeg or the shared data a seeded
//! synthetic frame is used (and printed). The workspace is built outside the timed loop.

use std::process::Command;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use facecap_core::paths;
use facecap_landmarks::detect::{DetectorParams, FaceDetector, Par, Upsample, DLIB_FRONTAL_MODEL};
use image::{imageops, GrayImage};
use rand::{Rng, SeedableRng};

fn first_frame() -> Option<GrayImage> {
    let path = paths::shared_data_file("bench_detect", "videos/liveportrait_d9.mp4")?;
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .ok()?;
    GrayImage::from_raw(512, 480, out.stdout)
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

fn frames() -> Vec<(String, GrayImage)> {
    let base = first_frame().unwrap_or_else(|| {
        eprintln!("bench_detect: using a synthetic frame");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        GrayImage::from_fn(512, 480, |_, _| image::Luma([rng.random::<u8>()]))
    });
    let big = imageops::resize(&base, 768, 720, imageops::FilterType::Triangle);
    vec![
        ("640x480".into(), pad_to(&base, 640, 480)),
        ("1280x720".into(), pad_to(&big, 1280, 720)),
    ]
}

/// CPU time of the calling thread (`/proc/thread-self/schedstat`, nanoseconds), so the
/// numbers compare with the dlib anchor's CPU-time column on a loaded machine.
fn thread_cpu() -> Option<Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = s.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

fn bench(c: &mut Criterion) {
    let Some(model) = paths::model_file_or_skip("bench_detect", DLIB_FRONTAL_MODEL) else {
        return;
    };
    let det = FaceDetector::from_file(&model).unwrap();
    let mut g = c.benchmark_group("detect");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_millis(500));
    for (name, img) in frames() {
        for (pname, par, up) in [
            ("seq", Par::Seq, Upsample::Times(0)),
            ("rayon", Par::Rayon, Upsample::Times(0)),
            ("seq_up1", Par::Seq, Upsample::Times(1)),
            ("seq_auto", Par::Seq, Upsample::Auto),
        ] {
            let d = det
                .clone()
                .with_params(DetectorParams {
                    par,
                    upsample: up,
                    ..Default::default()
                })
                .unwrap();
            let mut ws = d.new_workspace();
            let mut out = Vec::new();
            d.detect_into(&img, &mut ws, &mut out).unwrap();
            eprintln!("{name} {pname}: {} faces", out.len());
            g.bench_with_input(BenchmarkId::new(pname, &name), &img, |b, img| {
                b.iter(|| d.detect_into(img, &mut ws, &mut out).unwrap())
            });
            if par == Par::Seq && thread_cpu().is_some() {
                // same work, timed by the thread's CPU clock instead of the wall clock
                g.bench_with_input(BenchmarkId::new(format!("{pname}_cpu"), &name), &img, |b, img| {
                    b.iter_custom(|iters| {
                        let t0 = thread_cpu().unwrap_or_default();
                        for _ in 0..iters {
                            d.detect_into(img, &mut ws, &mut out).unwrap();
                        }
                        thread_cpu().unwrap_or_default().saturating_sub(t0)
                    })
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
