#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
// The counting global allocator below needs `unsafe impl GlobalAlloc`.
#![allow(unsafe_code)]
//! No allocation per frame after warm-up, and tracking from the previous frame's
//! landmarks stays on the face (shared clip; needs the model cache).

mod common;

use common::*;
use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshState, MeshStatus, MeshTracker, RgbView};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct CountingAlloc;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocs() -> u64 {
    ALLOCS.with(Cell::get)
}

#[test]
fn tracking_allocates_nothing_after_warm_up_and_stays_on_the_face() {
    let test = "tracking_allocates_nothing_after_warm_up_and_stays_on_the_face";
    let (Some(det), Some(lm)) = (
        model(test, facecap_mesh::FACE_DETECTOR_MODEL),
        model(test, facecap_mesh::FACE_LANDMARKS_MODEL),
    ) else {
        return;
    };
    let clip = "videos/liveportrait_d9.mp4";
    let frames: Vec<image::RgbImage> = match (0..12).map(|i| clip_frame(test, clip, i)).collect::<Option<Vec<_>>>() {
        Some(f) => f,
        None => return,
    };
    let tracker = MeshTracker::new(MeshModels::load(&det, &lm).unwrap(), MeshParams::default()).unwrap();
    let mut ws = tracker.workspace();
    let mut state = MeshState::default();
    let mut mesh = FaceMesh::default();
    let views: Vec<RgbView<'_>> = frames.iter().map(|f| RgbView::from_image(f).unwrap()).collect();
    // Warm-up: detection then one tracked frame.
    for v in &views[..2] {
        tracker.track_into(v, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
    }
    let before = allocs();
    let mut statuses = Vec::new();
    let mut tracked = Vec::new();
    for v in &views[2..] {
        let r = tracker.track_into(v, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
        statuses.push(r.status);
        tracked.push(mesh.points.clone());
    }
    // `tracked.push(clone)` allocates once per frame by design; subtract those.
    let n = (views.len() - 2) as u64;
    let per_frame = allocs() - before;
    assert!(
        per_frame <= 2 * n,
        "{per_frame} allocations over {n} frames (clone + push only expected)"
    );
    let after_clone = allocs();
    for v in &views[2..] {
        tracker.track_into(v, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
    }
    assert_eq!(allocs() - after_clone, 0, "allocations in the per-frame path");
    assert!(statuses.iter().all(|&s| s == MeshStatus::Tracked), "{statuses:?}");
    // Tracked landmarks against landmarks from a fresh detection on the same frame.
    let mut fresh = FaceMesh::default();
    for (v, t) in views[2..].iter().zip(&tracked) {
        let mut s = MeshState::default();
        tracker.track_into(v, 0.0, &mut ws, &mut s, &mut fresh).unwrap();
        let mean = t
            .iter()
            .zip(&fresh.points)
            .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
            .sum::<f32>()
            / t.len() as f32;
        eprintln!("tracked vs fresh detection: mean {mean:.3} px");
        assert!(
            mean < 3.0,
            "tracked landmarks drifted: mean {mean} px from a fresh detection"
        );
    }
}

#[test]
fn frames_without_a_face_allocate_nothing_after_warm_up() {
    let Some(tracker) = tracker(
        "frames_without_a_face_allocate_nothing_after_warm_up",
        MeshParams::default(),
    ) else {
        return;
    };
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    // no face: the whole-image pass and the small-face search both run
    let img = image::RgbImage::from_raw(640, 480, pattern(640).into_iter().take(640 * 480 * 3).collect()).unwrap();
    let view = RgbView::from_image(&img).unwrap();
    let mut state = MeshState::default();
    let r = tracker.track_into(&view, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
    assert_eq!(r.status, MeshStatus::NoFace);
    assert_eq!(state.small_face_wait, facecap_mesh::SMALL_FACE_INTERVAL);
    let before = allocs();
    for _ in 0..3 {
        state.small_face_wait = 0;
        let r = tracker.track_into(&view, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
        assert_eq!(r.status, MeshStatus::NoFace);
    }
    assert_eq!(allocs() - before, 0, "allocations in the small-face search");
    // while waiting, the search does not run; the count goes down frame by frame
    let r = tracker.track_into(&view, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
    assert!(r.detector_ran);
    assert_eq!(state.small_face_wait, facecap_mesh::SMALL_FACE_INTERVAL - 1);
}
