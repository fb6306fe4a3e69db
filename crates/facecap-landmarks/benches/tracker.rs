#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Tracker throughput on the shared clips, decode excluded: the frames of each clip
//! are decoded once (ffmpeg, grey) before timing, then the tracker (dlib-compatible
//! HOG detector + ERT 68-point predictor + LK, `TrackerParams::default()`, one
//! thread) runs frame after frame through the clip played forwards and backwards
//! (ping-pong, so motion stays continuous however many frames criterion asks for).
//! One criterion iteration = one frame, so the reported time is the mean cost per
//! frame in steady tracking, including the re-detections the tracker decides to
//! run; frames/s = 1 / time. `tracker/<clip>` is wall time, `tracker_cpu/<clip>`
//! the thread's CPU time (`/proc/thread-self/schedstat`) for loaded machines.
//! Skips clips or models that are missing. Research-only data (shared/data/SOURCES.md).

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use facecap_core::paths;
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
use image::GrayImage;

const CLIPS: [&str; 5] = [
    "videos/liveportrait_d18.mp4",
    "videos/liveportrait_d6.mp4",
    "videos/liveportrait_d3.mp4",
    "videos/liveportrait_d9.mp4",
    "videos/sadtalker_WDA_KatieHill_000.mp4",
];

fn decode_gray(path: &Path) -> Option<Vec<GrayImage>> {
    let probe = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height",
        ])
        .args(["-of", "csv=p=0"])
        .arg(path)
        .output()
        .ok()?;
    let dims = String::from_utf8_lossy(&probe.stdout);
    let mut it = dims.trim().split(',').map(|v| v.parse::<u32>().ok());
    let (w, h) = (it.next()??, it.next()??);
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-i"])
        .arg(path)
        .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .ok()?;
    out.status.success().then(|| {
        out.stdout
            .chunks_exact((w * h) as usize)
            .map(|c| GrayImage::from_raw(w, h, c.to_vec()).unwrap())
            .collect()
    })
}

/// CPU time of the calling thread (nanoseconds from `/proc/thread-self/schedstat`).
fn thread_cpu() -> Option<Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(Duration::from_nanos(s.split_whitespace().next()?.parse().ok()?))
}

/// Frame index `k` of the ping-pong sequence over `n` frames.
fn ping_pong(k: usize, n: usize) -> usize {
    if n < 2 {
        return 0;
    }
    let period = 2 * n - 2;
    let j = k % period;
    if j < n {
        j
    } else {
        period - j
    }
}

fn bench(c: &mut Criterion) {
    let Some(sp_path) = paths::model_file_or_skip("bench_tracker", paths::DLIB_68_MODEL) else {
        return;
    };
    let Ok(det) = FaceDetector::default_model() else {
        eprintln!("SKIP: bench_tracker: face detector model missing");
        return;
    };
    let sp = ShapePredictor::from_file(&sp_path).unwrap().with_params(ErtParams {
        output: OutputPrecision::SubPixel,
        ..Default::default()
    });
    let tracker = LandmarkTracker::new(det, sp, TrackerParams::default()).unwrap();
    let mut g = c.benchmark_group("tracker");
    g.sample_size(20)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    for clip in CLIPS {
        let Some(path) = paths::shared_data_file("bench_tracker", clip) else {
            continue;
        };
        let Some(frames) = decode_gray(&path) else {
            eprintln!("SKIP: bench_tracker: ffmpeg failed on {clip}");
            continue;
        };
        let name = Path::new(clip).file_stem().unwrap().to_string_lossy().into_owned();
        let (w, h) = frames[0].dimensions();
        let id = format!("{name}_{w}x{h}");
        for cpu in [false, true] {
            if cpu && thread_cpu().is_none() {
                continue;
            }
            let mut ws = tracker.new_workspace();
            let mut state = TrackerState::new();
            let mut out = TrackedFrame::default();
            let mut k = 0usize;
            let group = if cpu { "tracker_cpu" } else { "tracker" };
            g.bench_function(BenchmarkId::new(group, &id), |b| {
                b.iter_custom(|iters| {
                    let (t0, c0) = (Instant::now(), thread_cpu().unwrap_or_default());
                    for _ in 0..iters {
                        let f = ping_pong(k, frames.len());
                        tracker
                            .track_into(&frames[f], k as f64 / 30.0, &mut ws, &mut state, &mut out)
                            .unwrap();
                        k += 1;
                    }
                    if cpu {
                        thread_cpu().unwrap_or_default().saturating_sub(c0)
                    } else {
                        t0.elapsed()
                    }
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
