#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![allow(unsafe_code)] // the counting global allocator needs `unsafe impl GlobalAlloc`
//! No heap allocation per frame after warm-up (sequential mode), proven with a
//! counting global allocator. Only one test in this binary, so no other test thread
//! allocates while it counts.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_core::paths;
use facecap_landmarks::detect::{DetectorParams, FaceDetector, Upsample, DLIB_FRONTAL_MODEL};
use image::GrayImage;
use rand::{Rng, SeedableRng};

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
static GLOBAL: Counting = Counting;

fn noise(w: u32, h: u32, seed: u64) -> GrayImage {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    GrayImage::from_fn(w, h, |_, _| image::Luma([rng.random::<u8>()]))
}

#[test]
fn no_allocation_per_frame_after_warm_up() {
    let Some(model) = paths::model_file_or_skip("detect_alloc", DLIB_FRONTAL_MODEL) else {
        return;
    };
    // a negative threshold makes many candidates, so candidate lists are exercised
    let det = FaceDetector::from_file(&model)
        .unwrap()
        .with_params(DetectorParams {
            upsample: Upsample::Times(1),
            adjust_threshold: -1.5,
            ..Default::default()
        })
        .unwrap();
    let img = noise(200, 150, 1);
    let mut ws = det.new_workspace();
    let mut out = Vec::new();
    det.detect_into(&img, &mut ws, &mut out).unwrap();
    let n0 = out.len();
    let before = ALLOCS.load(Ordering::SeqCst);
    det.detect_into(&img, &mut ws, &mut out).unwrap();
    let after = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(out.len(), n0);
    assert_eq!(after - before, 0, "allocations in a warmed-up detect_into");
}
