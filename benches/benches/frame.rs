//! Per-frame budget of the whole tracking pipeline: `VideoTracker::run` (decode, detect or
//! track, landmarks, plausibility checks) over a 30-frame clip of a real face, for each
//! landmark front end. Criterion reports time per frame (throughput in frames).
//!
//! `cargo bench -p facecap-benches --bench frame` (skips, with a `SKIP:` line, when the
//! model cache has no dlib or face mesh models).
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

criterion_group!(benches, frame);
criterion_main!(benches);
