#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![allow(unsafe_code)] // a counting global allocator needs `unsafe impl GlobalAlloc`
//! The per-frame fit does not allocate after warm-up.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_tensor::fit::{FitInput, FitParams, Fitter, Method};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use nalgebra::{Point3, Vector3};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Only the measuring thread counts: the test harness's own threads may allocate
    /// at any time (seen on a loaded CI machine), the fit runs on this thread alone.
    static COUNTING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn count() {
    if COUNTING.with(std::cell::Cell::get) {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_frame_fit_does_not_allocate() {
    let d = synth::database(400, 6, 4, 1).unwrap();
    let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let vertices: Vec<u32> = (0..68).map(|k| k * 5).collect();
    let k = Intrinsics::new(800.0, 800.0, 320.0, 240.0).unwrap();
    for method in [Method::Regularised, Method::NonNegative] {
        let fitter = Fitter::new(
            &model,
            &vertices,
            FitParams {
                method,
                ..Default::default()
            },
        )
        .unwrap();
        let mut ws = fitter.workspace();
        let mut st = fitter.initial_state();
        let weights = vec![1.0; 68];
        let mut frames = Vec::new();
        for f in 0..4 {
            let pose =
                ModelToCamera::from_rvec_tvec(Vector3::new(0.0, 0.05 * f as f64, 0.0), Vector3::new(0.0, 0.0, 60.0));
            let fpts = model.generate(&[0.2; 6], &[0.25; 4]).unwrap();
            frames.push(
                vertices
                    .iter()
                    .map(|&v| {
                        let v = v as usize;
                        pose.project(&k, &Point3::new(fpts[3 * v], fpts[3 * v + 1], fpts[3 * v + 2]))
                            .unwrap()
                    })
                    .collect::<Vec<_>>(),
            );
        }
        let input = |f: usize| FitInput {
            image: &frames[f],
            weights: &weights,
            intrinsics: k,
        };
        fitter.solve_into(&input(0), &mut ws, &mut st).unwrap(); // warm-up
        let before = ALLOCS.load(Ordering::SeqCst);
        COUNTING.with(|c| c.set(true));
        for f in 1..4 {
            fitter.solve_into(&input(f), &mut ws, &mut st).unwrap();
        }
        COUNTING.with(|c| c.set(false));
        let after = ALLOCS.load(Ordering::SeqCst);
        assert_eq!(
            after - before,
            0,
            "{method:?}: {} allocations in 3 frames",
            after - before
        );
    }
}
