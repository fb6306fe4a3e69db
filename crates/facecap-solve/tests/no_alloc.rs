#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! No heap allocation per frame after one warm-up frame, for every solver (counting allocator).
//! The workspace lint denies `unsafe`; implementing `GlobalAlloc` needs it, so this test file
//! allows it locally: it only forwards to the system allocator and counts.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_core::camera::Intrinsics;
use facecap_solve::synth::{generate, SynthParams};
use facecap_solve::{
    Basis2d, BlendshapeRig, BobyqaParams, BobyqaSolver, Exact3dParams, Exact3dSolver, ExactParams, ExactSolver,
    ExpressionSolver, ObjectiveParams, PcaParams, PcaSolver, RegionParams, RegionSolver, Solution, SolveState,
};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);
thread_local! {
    static ACTIVE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if ACTIVE.with(|a| a.get()) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if ACTIVE.with(|a| a.get()) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn count_allocs<S: ExpressionSolver>(name: &str, s: &S, frames: &[facecap_solve::synth::SynthFrame]) {
    let n = s.num_shapes();
    let mut ws = s.workspace();
    let mut st = SolveState::new(n);
    let mut out = Solution::new(n);
    s.solve_into(&frames[0].landmarks, &mut ws, &mut st, &mut out).unwrap();
    ALLOCS.store(0, Ordering::SeqCst);
    ACTIVE.with(|a| a.set(true));
    for f in &frames[1..] {
        s.solve_into(&f.landmarks, &mut ws, &mut st, &mut out).unwrap();
    }
    ACTIVE.with(|a| a.set(false));
    assert_eq!(ALLOCS.load(Ordering::SeqCst), 0, "{name} allocated per frame");
}

#[test]
fn no_allocation_per_frame() {
    let rig = BlendshapeRig::synthetic(16, 4);
    let cam = Intrinsics::default_for_frame(640, 480).unwrap();
    let frames = generate(
        &rig,
        &cam,
        640.0,
        &SynthParams {
            noise_px: 0.5,
            max_yaw_deg: 5.0,
            max_pitch_deg: 5.0,
            ..Default::default()
        },
        6,
        1,
    );
    let basis = Basis2d::frontal(&rig);
    let obj = ObjectiveParams { l1: 1.0, temporal: 2.0 };
    count_allocs(
        "exact",
        &ExactSolver::new(
            &basis,
            ExactParams {
                objective: obj,
                ..Default::default()
            },
        )
        .unwrap(),
        &frames,
    );
    // mu = 0: the QP factor is carried between passes and frames (the reuse path)
    count_allocs(
        "exact, mu = 0",
        &ExactSolver::new(&basis, ExactParams::default()).unwrap(),
        &frames,
    );
    count_allocs(
        "exact3d",
        &Exact3dSolver::new(
            &rig,
            Exact3dParams {
                objective: obj,
                ..Exact3dParams::new(cam)
            },
        )
        .unwrap(),
        &frames,
    );
    count_allocs(
        "bobyqa",
        &BobyqaSolver::new(
            &basis,
            BobyqaParams {
                objective: obj,
                ..Default::default()
            },
        )
        .unwrap(),
        &frames,
    );
    count_allocs(
        "region",
        &RegionSolver::new(
            &basis,
            RegionParams {
                objective: obj,
                ..Default::default()
            },
        )
        .unwrap(),
        &frames,
    );
    count_allocs(
        "pca",
        &PcaSolver::new(
            &basis,
            PcaParams {
                objective: obj,
                ..Default::default()
            },
        )
        .unwrap(),
        &frames,
    );
}
