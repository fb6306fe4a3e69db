#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![allow(unsafe_code)] // the counting global allocator needs `unsafe impl GlobalAlloc`
//! No allocation per frame after warm-up: `IrisEstimator::estimate_into` under a counting
//! global allocator.

mod gaze_common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_landmarks::gaze::{IrisEstimator, IrisFrame, IrisParams};
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
    let frames: Vec<_> = (0..5)
        .map(|k| {
            let u = 0.4 + 0.05 * k as f64;
            let eyes = gaze_common::face(
                Point2::new(160.0, 120.0),
                30.0 + 5.0 * k as f64,
                0.1,
                0.22,
                (u, 0.0),
                (u, 0.0),
                0.12,
            );
            gaze_common::render(320, 240, &eyes)
        })
        .collect();
    let est = IrisEstimator::new(IrisParams::default()).unwrap();
    let mut ws = est.new_workspace();
    let mut out = IrisFrame::default();
    est.estimate_into(&frames[0].0, &frames[0].1, &mut ws, &mut out)
        .unwrap();
    let before = ALLOCS.load(Ordering::SeqCst);
    let mut valid = 0;
    for (img, lm) in &frames {
        valid += est.estimate_into(img, lm, &mut ws, &mut out).unwrap().valid_eyes;
    }
    let after = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(valid, 10);
    assert_eq!(after - before, 0, "allocations per frame after warm-up");
}
