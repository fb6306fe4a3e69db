//! No allocation per prediction after warm-up (counting global allocator).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![allow(unsafe_code)] // the counting global allocator needs `unsafe impl GlobalAlloc`

mod ert_common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_core::landmarks::Rect;
use facecap_landmarks::ert::ShapePredictor;
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
static GLOBAL: Counting = Counting;

#[test]
fn prediction_does_not_allocate_after_warm_up() {
    let model = ert_common::synthetic_model(11, 68, 4, 20, 4, 100);
    let sp = ShapePredictor::new(&model, Default::default()).unwrap();
    let img = ert_common::synthetic_image(2, 320, 240);
    let rect = Rect::from_dlib(80, 50, 230, 200);
    let mut ws = sp.new_workspace();
    let mut out = vec![Point2::origin(); sp.num_parts()];
    let start = vec![Point2::new(150.0, 120.0); sp.num_parts()];
    sp.predict_into(&img, &rect, &mut ws, &mut out).unwrap();
    sp.predict_from_shape_into(&img, &rect, &start, &mut ws, &mut out)
        .unwrap();
    let before = ALLOCS.load(Ordering::SeqCst);
    for _ in 0..20 {
        sp.predict_into(&img, &rect, &mut ws, &mut out).unwrap();
        sp.predict_from_shape_into(&img, &rect, &start, &mut ws, &mut out)
            .unwrap();
    }
    assert_eq!(
        ALLOCS.load(Ordering::SeqCst) - before,
        0,
        "allocations during prediction"
    );
}
