//! Per-frame budget of the whole tracking pipeline: `VideoTracker::run` (decode, detect or
//! track, landmarks, plausibility checks) over a 30-frame clip of a real face, for each
//! landmark front end. Criterion reports time per frame (throughput in frames).
//!
//! `video/yuv420_to_rgb/480x480`: the colour conversion every frame of the mesh front end
//! goes through (decoded 4:2:0 planes to interleaved RGB), one 480x480 frame.
//!
//! `cargo bench -p facecap-benches --bench frame` (the pipeline skips, with a `SKIP:` line,
//! when the model cache has no dlib or face mesh models).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use facecap_benches::{face_clip, CLIP_FRAMES};
use facecap_pipeline::{FrontEnd, LandmarkRecorder, RunControl, TrackerPolicy, VideoTracker};

fn frame(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("facecap-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let Some(clip) = face_clip(&dir) else {
        facecap_core::paths::skip_missing_data(
            "pipeline/frame: astronaut.png not in the model cache (run scripts/setup.sh)",
        );
        return;
    };
    let mut group = c.benchmark_group("pipeline/frame");
    group.throughput(Throughput::Elements(CLIP_FRAMES as u64));
    group.sample_size(10);
    for (name, front_end) in [("dlib68", FrontEnd::Dlib68), ("mesh", FrontEnd::Mesh)] {
        let tracker = match VideoTracker::new(&TrackerPolicy {
            front_end,
            ..TrackerPolicy::default()
        }) {
            Ok(t) => t,
            Err(e) => {
                facecap_core::paths::skip_missing_data(&format!("pipeline/frame/{name}: {e}"));
                continue;
            }
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                let source = facecap_pipeline::open_video_rgb(&clip, 1, true, tracker.needs_rgb()).unwrap();
                let mut rec = LandmarkRecorder::new();
                let report = tracker
                    .run(source, &mut [&mut rec], &mut RunControl::default())
                    .unwrap();
                assert_eq!(report.faces, CLIP_FRAMES as u64, "{name}: the face is lost");
                report
            });
        });
    }
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

fn yuv(c: &mut Criterion) {
    use facecap_io::video::yuv::{ColorMatrix, ColorRange, YuvToRgb};
    let (w, h) = (480usize, 480usize);
    // planes with every code and some structure (not constant, so no shortcut applies)
    let y: Vec<u8> = (0..w * h).map(|i| (i * 37 % 251) as u8).collect();
    let cb: Vec<u8> = (0..w * h / 4).map(|i| (i * 53 % 241) as u8).collect();
    let cr: Vec<u8> = (0..w * h / 4).map(|i| (i * 29 % 239) as u8).collect();
    let conv = YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Limited);
    let mut out = image::RgbImage::new(w as u32, h as u32);
    let mut group = c.benchmark_group("video/yuv420_to_rgb");
    group.throughput(Throughput::Elements(1));
    group.bench_function("480x480", |b| {
        b.iter(|| conv.convert_into(&y, &cb, &cr, w as u32, h as u32, 2, 2, &mut out));
    });
    group.finish();
}

criterion_group!(benches, frame, yuv);
criterion_main!(benches);
