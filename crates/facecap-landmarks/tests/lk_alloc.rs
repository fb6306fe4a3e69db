#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![allow(unsafe_code)] // the counting global allocator needs `unsafe impl GlobalAlloc`
//! No allocation per frame after warm-up: `push_frame` + `track_into` (sequential)
//! under a counting global allocator.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_landmarks::lk::{LkParams, LkWorkspace, PyramidLk, TrackStatus};
use image::GrayImage;
use nalgebra::Point2;

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn no_allocation_per_frame_after_warm_up() {
    let frames: Vec<GrayImage> = (0..6)
        .map(|k| {
            GrayImage::from_fn(320, 240, |x, y| {
                let (x, y) = (x as f64 - k as f64 * 0.7, y as f64 + k as f64 * 0.3);
                image::Luma([
                    (128.0 + 50.0 * (x / 6.0).sin() * (y / 8.0).cos() + 40.0 * ((x + 2.0 * y) / 11.0).sin()) as u8,
                ])
            })
        })
        .collect();
    for fb in [None, Some(1.0)] {
        let lk = PyramidLk::new(LkParams {
            forward_backward: fb,
            ..LkParams::default()
        })
        .unwrap();
        let mut ws = LkWorkspace::new(&lk);
        let pts: Vec<Point2<f64>> = (0..68)
            .map(|i| Point2::new(40.0 + (i % 17) as f64 * 14.0, 50.0 + (i / 17) as f64 * 35.0))
            .collect();
        let mut next = vec![Point2::origin(); pts.len()];
        let mut st = vec![TrackStatus::Tracked; pts.len()];
        let mut err = vec![0.0; pts.len()];
        // Warm-up: both pyramids once, one track call (thread-local window buffer).
        ws.push_frame(&frames[0]).unwrap();
        ws.push_frame(&frames[1]).unwrap();
        lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap();
        let before = ALLOCS.load(Ordering::SeqCst);
        for f in &frames[2..] {
            ws.push_frame(f).unwrap();
            let rep = lk.track_into(&ws, &pts, &mut next, &mut st, &mut err).unwrap();
            assert!(rep.tracked > 60, "{rep:?}");
        }
        let after = ALLOCS.load(Ordering::SeqCst);
        assert_eq!(after - before, 0, "allocations after warm-up (fb {fb:?})");
    }
}
