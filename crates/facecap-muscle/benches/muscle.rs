#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
//! Steady per-frame cost: one tracking frame (68 landmarks, 11 muscles + jaw) in both
//! solver modes, and posing a full mesh. Workspaces are built outside the timed loop.

use criterion::{criterion_group, criterion_main, Criterion};
use facecap_muscle::defaults::{default_muscle_set, landmark_positions};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::synthetic::{make_sequence, SyntheticFace};
use facecap_muscle::track::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let face = SyntheticFace::new(97, 105); // ~10k vertices, ICT face-area size
    let lm = landmark_positions(&face.map, &face.positions);
    let set = default_muscle_set(&lm, &face.positions).unwrap();
    let rig = MuscleRig::from_mesh(&set, &face.mesh()).unwrap();
    let model = TrackModel::from_landmarks(&rig, &face.map, &[], 1).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let seq = make_sequence(&rig, model.vertices(), 90, 0.5, &mut || rng.random::<f64>()).unwrap();
    let mut g = c.benchmark_group("muscle");
    g.sample_size(20)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1));
    for (name, mode) in [
        ("track_frame_global", SolveMode::Global),
        ("track_frame_point_by_point", SolveMode::PointByPoint),
    ] {
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
        // Warm up through the neutral frame; then cycle over the active frames.
        tracker
            .solve_into(
                &TrackInput {
                    points: &seq.observations[0],
                    weights: None,
                },
                &mut ws,
                &mut st,
                &mut out,
            )
            .unwrap();
        let mut f = 1;
        g.bench_function(name, |b| {
            b.iter(|| {
                let input = TrackInput {
                    points: &seq.observations[f],
                    weights: None,
                };
                let r = tracker.solve_into(&input, &mut ws, &mut st, &mut out).unwrap();
                f = if f + 1 < seq.observations.len() { f + 1 } else { 1 };
                r
            })
        });
    }
    let mut posed = rig.base().to_vec();
    let cs = vec![0.5; rig.num_muscles()];
    g.bench_function(format!("pose_full_mesh_{}v", rig.base().len()), |b| {
        b.iter(|| rig.pose_into(&cs, 0.15, &mut posed).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
