#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Pyramidal LK per-frame cost at 640x480: pyramid build (one frame), tracking
//! 68 / 500 points with pyramids ready, and both together (the steady per-frame
//! cost of a video tracker: `push_frame_and_track_*`, wall and thread-CPU time).
//! Frames: the first 40 of liveportrait_d9 (shared data) padded to 640x480 like the
//! OpenCV anchor; a synthetic texture if absent. Points: Halton points in the face
//! area. `testdata/opencv_lk/bench_cv_lk_same_inputs.py` times OpenCV's
//! `calcOpticalFlowPyrLK` on exactly these frames and points.

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use image::GrayImage;
use nalgebra::Point2;

const W: u32 = 640;
const H: u32 = 480;

fn frames() -> Vec<GrayImage> {
    if let Some(p) = facecap_core::paths::shared_data_file("bench lk", "videos/liveportrait_d9.mp4") {
        let out = std::process::Command::new("ffmpeg")
            .args(["-nostdin", "-v", "error", "-i"])
            .arg(&p)
            .args([
                "-frames:v",
                "40",
                "-vf",
                "pad=640:480:64:0,format=gray",
                "-f",
                "rawvideo",
                "-",
            ])
            .output();
        if let Ok(o) = out {
            let f: Vec<GrayImage> = o
                .stdout
                .chunks_exact((W * H) as usize)
                .map(|c| GrayImage::from_raw(W, H, c.to_vec()).unwrap())
                .collect();
            if f.len() >= 2 {
                return f;
            }
        }
    }
    (0..40)
        .map(|k| {
            GrayImage::from_fn(W, H, |x, y| {
                let (x, y) = (x as f64 - k as f64 * 0.8, y as f64 + k as f64 * 0.4);
                image::Luma([
                    (128.0 + 50.0 * (x / 6.0).sin() * (y / 8.0).cos() + 40.0 * ((x + 2.0 * y) / 11.0).sin()) as u8,
                ])
            })
        })
        .collect()
}

/// Radical inverse of `i` in base `b` (Halton sequence).
fn halton(mut i: usize, b: usize) -> f64 {
    let (mut f, mut r) = (1.0, 0.0);
    while i > 0 {
        f /= b as f64;
        r += f * (i % b) as f64;
        i /= b;
    }
    r
}

/// The first `n` points of the 2-D Halton sequence (bases 2, 3) in the face area
/// x in [150, 490), y in [80, 420): the same points as the OpenCV timing script
/// `testdata/opencv_lk/bench_cv_lk_same_inputs.py`.
fn points(n: usize) -> Vec<Point2<f64>> {
    (1..=n)
        .map(|i| Point2::new(150.0 + 340.0 * halton(i, 2), 80.0 + 340.0 * halton(i, 3)))
        .collect()
}

/// CPU time of the calling thread (nanoseconds from `/proc/thread-self/schedstat`).
fn thread_cpu() -> Option<std::time::Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(std::time::Duration::from_nanos(
        s.split_whitespace().next()?.parse().ok()?,
    ))
}

fn bench(c: &mut Criterion) {
    let frames = frames();
    let lk = PyramidLk::new(LkParams::default()).unwrap();
    let mut g = c.benchmark_group("lk_640x480");
    g.sample_size(30)
        .measurement_time(std::time::Duration::from_secs(3))
        .warm_up_time(std::time::Duration::from_secs(1));
    let mut ws = LkWorkspace::new(&lk);
    ws.push_frame(&frames[0]).unwrap();
    ws.push_frame(&frames[1]).unwrap();
    let mut k = 0usize;
    g.bench_function("pyramid_push_frame", |b| {
        b.iter(|| {
            k = (k + 1) % frames.len();
            ws.push_frame(&frames[k]).unwrap();
        })
    });
    for n in [68usize, 500] {
        let pts = points(n);
        let mut next = vec![Point2::origin(); n];
        let mut st = vec![TrackStatus::Tracked; n];
        let mut err = vec![0.0; n];
        let mut ws = LkWorkspace::new(&lk);
        ws.push_frame(&frames[0]).unwrap();
        ws.push_frame(&frames[1]).unwrap();
        g.bench_function(format!("track_{n}pts"), |b| {
            b.iter(|| lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap())
        });
        let mut k = 1usize;
        g.bench_function(format!("push_frame_and_track_{n}pts"), |b| {
            b.iter(|| {
                k = (k + 1) % frames.len();
                ws.push_frame(&frames[k]).unwrap();
                lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap()
            })
        });
        if thread_cpu().is_some() {
            // The same work timed by the thread's CPU clock (compare with the OpenCV
            // script's thread-CPU column when the machine is loaded).
            g.bench_function(format!("push_frame_and_track_{n}pts_cpu"), |b| {
                b.iter_custom(|iters| {
                    let c0 = thread_cpu().unwrap_or_default();
                    for _ in 0..iters {
                        k = (k + 1) % frames.len();
                        ws.push_frame(&frames[k]).unwrap();
                        lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap();
                    }
                    thread_cpu().unwrap_or_default().saturating_sub(c0)
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
