//! Steady per-call cost of the mesh front end's models (workspaces built outside the
//! timed loop). Needs the model cache (`scripts/setup.sh`); prints `SKIP:` without it.
//!
//!     nice -n 10 cargo bench -p facecap-mesh --bench mesh
#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_mesh::tflite::Interpreter;
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

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(4));
    targets = models
}
criterion_main!(benches);
