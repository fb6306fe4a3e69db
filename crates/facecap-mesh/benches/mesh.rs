//! Steady per-call cost of the mesh front end (workspaces built outside the timed loop).
//! Needs the model cache (`scripts/setup.sh`) and, for the frame benches, the shared
//! clips; prints `SKIP:` without them.
//!
//!     nice -n 10 cargo bench -p facecap-mesh --bench mesh
#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_io::video::{open_source, Frame, SourceOptions};
use facecap_mesh::tflite::Interpreter;
use facecap_mesh::{FaceMesh, MeshModels, MeshParams, MeshTracker, RgbView};
use facecap_mesh::{FACE_DETECTOR_MODEL, FACE_LANDMARKS_MODEL};

fn models(c: &mut Criterion) {
    for (name, label) in [
        (FACE_LANDMARKS_MODEL, "landmarks_256"),
        (FACE_DETECTOR_MODEL, "detector_128"),
    ] {
        let Some(path) = facecap_core::paths::model_file_or_skip("bench models", name) else {
            return;
        };
        let it = Interpreter::from_file(&path).unwrap();
        let mut ws = it.workspace();
        for (i, v) in it.input_mut(&mut ws, 0).unwrap().iter_mut().enumerate() {
            *v = ((i * 7919) % 251) as f32 / 251.0;
        }
        c.bench_function(&format!("model/{label}"), |b| b.iter(|| it.run(&mut ws).unwrap()));
    }
}

/// The first RGB frame of a shared clip.
fn first_frame(clip: &str) -> Option<image::RgbImage> {
    let path = facecap_core::paths::shared_data_file("bench frames", clip)?;
    let opts = SourceOptions {
        rgb: true,
        ..SourceOptions::default()
    };
    let mut src = open_source(&path, &opts).ok()?;
    let mut f = Frame::default();
    src.read_into(&mut f).ok()?;
    f.rgb
}

fn frames(c: &mut Criterion) {
    let Ok(models) = MeshModels::from_cache() else {
        eprintln!("SKIP: bench frames: models not in the model cache (run scripts/setup.sh)");
        return;
    };
    let Some(face) = first_frame("videos/liveportrait_d9.mp4") else {
        return;
    };
    let tracker = MeshTracker::new(models, MeshParams::default()).unwrap();
    let mut ws = tracker.workspace();
    let mut mesh = FaceMesh::default();
    // 640x480 frame: the 480x480 clip frame centred on a grey canvas.
    let mut vga = image::RgbImage::from_pixel(640, 480, image::Rgb([90, 90, 90]));
    image::imageops::replace(&mut vga, &face, 80, 0);
    let vga_view = RgbView::from_image(&vga).unwrap();
    let mut dets = Vec::new();
    let mut dws = tracker.detector().workspace();
    c.bench_function("frame/detector_640x480", |b| {
        b.iter(|| tracker.detector().detect_into(&vga_view, &mut dws, &mut dets).unwrap())
    });
    // The small-face search (run only where the whole-image pass finds no face): 15
    // windows of a third of the long side on a 640x480 frame.
    c.bench_function("frame/detector_small_faces_640x480", |b| {
        b.iter(|| {
            tracker
                .detector()
                .detect_small_into(&vga_view, &mut dws, &mut dets)
                .unwrap()
        })
    });
    let view = RgbView::from_image(&face).unwrap();
    let mut state = tracker.state();
    tracker.track_into(&view, 0.0, &mut ws, &mut state, &mut mesh).unwrap();
    c.bench_function("frame/track_480x480", |b| {
        b.iter(|| {
            // Same frame every time: the tracked region converges; detector not run.
            tracker.track_into(&view, 0.0, &mut ws, &mut state, &mut mesh).unwrap()
        })
    });
    c.bench_function("frame/detect_and_landmarks_480x480", |b| {
        b.iter(|| {
            let mut fresh = tracker.state();
            tracker.track_into(&view, 0.0, &mut ws, &mut fresh, &mut mesh).unwrap()
        })
    });
    // The landmark model's input: the tracked face region sampled to 256 x 256.
    use facecap_mesh::roi::{warp_to_tensor, Affine, BilinearTable, Border, ValueMap};
    let (table, n) = (BilinearTable::new(), facecap_mesh::tracker::LANDMARK_INPUT);
    let map = Affine::for_rect(&mesh.rect, view.width, view.height, n);
    let mut tensor = vec![0.0f32; n * n * 3];
    c.bench_function("frame/warp_256", |b| {
        b.iter(|| warp_to_tensor(&view, &map, n, Border::Replicate, ValueMap::UNIT, &table, &mut tensor))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(4));
    targets = models, frames
}
criterion_main!(benches);
