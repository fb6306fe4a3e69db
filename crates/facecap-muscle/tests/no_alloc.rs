#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
// A counting global allocator needs `unsafe impl GlobalAlloc`; this test file only.
#![allow(unsafe_code)]
//! Posing and tracking allocate nothing per frame after a warm-up frame.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use facecap_muscle::defaults::{default_muscle_set, landmark_positions};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::synthetic::{make_sequence, SyntheticFace};
use facecap_muscle::track::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

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
fn steady_state_frames_do_not_allocate() {
    let face = SyntheticFace::new(41, 45);
    let lm = landmark_positions(&face.map, &face.positions);
    let set = default_muscle_set(&lm, &face.positions).unwrap();
    let rig = MuscleRig::from_mesh(&set, &face.mesh()).unwrap();
    let model = TrackModel::from_landmarks(&rig, &face.map, &[], 2).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let seq = make_sequence(&rig, model.vertices(), 12, 0.5, &mut || rng.random::<f64>()).unwrap();
    let mut posed = rig.base().to_vec();
    let c = vec![0.5; rig.num_muscles()];
    for mode in [SolveMode::Global, SolveMode::PointByPoint] {
        let tracker = MuscleTracker::new(
            model.clone(),
            seq.intrinsics,
            TrackParams {
                mode,
                ..Default::default()
            },
        )
        .unwrap();
        let mut ws = TrackWorkspace::new(&model);
        let mut st = TrackState::new(&model);
        let mut out = TrackOutput::new(&model);
        let input = |f: usize| TrackInput {
            points: &seq.observations[f],
            weights: None,
        };
        tracker.solve_into(&input(0), &mut ws, &mut st, &mut out).unwrap();
        tracker.solve_into(&input(1), &mut ws, &mut st, &mut out).unwrap();
        let before = ALLOCS.load(Ordering::SeqCst);
        for f in 2..seq.observations.len() {
            tracker.solve_into(&input(f), &mut ws, &mut st, &mut out).unwrap();
        }
        rig.pose_into(&c, 0.1, &mut posed).unwrap();
        let after = ALLOCS.load(Ordering::SeqCst);
        assert_eq!(
            after - before,
            0,
            "{mode:?}: {} allocations in 10 frames",
            after - before
        );
    }
}
