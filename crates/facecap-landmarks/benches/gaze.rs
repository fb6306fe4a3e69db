#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Iris-centre estimation per frame (both eyes) at 640x480 with 40-px-wide eyes (the
//! size on the 480x480 shared clips) on a drawn face (`tests/gaze_common`), with the
//! workspace built outside the timed loop.

#[path = "../tests/gaze_common/mod.rs"]
mod gaze_common;

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_landmarks::gaze::{IrisEstimator, IrisFrame, IrisParams};
use nalgebra::Point2;

fn bench(c: &mut Criterion) {
    let eyes = gaze_common::face(
        Point2::new(320.0, 220.0),
        40.0,
        0.1,
        0.2,
        (0.45, 0.02),
        (0.55, 0.02),
        0.2,
    );
    let (img, lm) = gaze_common::render(640, 480, &eyes);
    let est = IrisEstimator::new(IrisParams::default()).unwrap();
    let mut ws = est.new_workspace();
    let mut out = IrisFrame::default();
    assert_eq!(est.estimate_into(&img, &lm, &mut ws, &mut out).unwrap().valid_eyes, 2);
    let mut g = c.benchmark_group("gaze");
    g.bench_function("estimate_into_both_eyes_640x480", |b| {
        b.iter(|| {
            est.estimate_into(std::hint::black_box(&img), &lm, &mut ws, &mut out)
                .unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
