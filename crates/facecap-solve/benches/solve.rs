#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Per-frame cost of the solvers on 68 landmarks, 16 and 53 shapes (workspaces built outside the
//! timed loop; state reset before every call = cold start, as dlib's anchor timing).
//!
//! 16 shapes: the 12 problems of `testdata/solve/bobyqa_dlib_fixture.json` (ICT shapes, the
//! anchor's recipe), so the BOBYQA time compares with dlib's on the same problems.
//! 53 shapes: the ICT ARKit-53 rig (synthetic rig if the shared data is absent), frontal frames.
//!
//! Warm ids (`*_warm*`): a smooth 60-frame synthetic trajectory (4 active shapes, head turning
//! +-20 deg yaw / +-8 deg pitch, 0.5 px noise), the state carried from frame to frame as in
//! tracking; every call solves the next frame (changing landmarks), wrapping around.
//!
//! Goals of issue 5 (docs/bench/solve.md): `solve/exact_warm/16` <= 20 us, `solve/exact_warm/53`
//! <= 60 us; `solve/bobyqa/16` <= 0.5x dlib's `find_min_bobyqa` on the same 12 problems
//! (`testdata/solve/time_dlib_bobyqa.py`).
//!
//! `cargo bench -j 1 -p facecap-solve --bench solve -- 'exact|bobyqa/16'`

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::Landmarks68;
use facecap_solve::synth::{generate, SynthParams};
use facecap_solve::{
    AnySolver, Basis2d, BlendshapeRig, ExpressionSolver, Method, ObjectiveParams, Solution, SolveState,
};

#[derive(serde::Deserialize)]
struct Problem {
    obs: Vec<f64>,
}
#[derive(serde::Deserialize)]
struct Fixture {
    neutral: Vec<f64>,
    deltas: Vec<Vec<f64>>,
    problems: Vec<Problem>,
}

fn fixture_basis() -> (Basis2d, Vec<Landmarks68>) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/solve/bobyqa_dlib_fixture.json"
    );
    let fx: Fixture = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let k = fx.deltas.len();
    let mut d = ndarray::Array2::zeros((k, 136));
    for (i, row) in fx.deltas.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            d[[i, j]] = *v;
        }
    }
    let basis = Basis2d {
        names: (0..k).map(|i| format!("s{i}")).collect(),
        neutral: fx.neutral.clone(),
        deltas: d,
        mapped: [true; 68],
        stable: {
            let mut s = [false; 68];
            for i in facecap_solve::basis::DEFAULT_STABLE {
                s[i] = true;
            }
            s
        },
    };
    let frames = fx
        .problems
        .iter()
        .map(|p| Landmarks68::from_fn(|l| (p.obs[2 * l], p.obs[2 * l + 1])))
        .collect();
    (basis, frames)
}

fn ict_rig() -> BlendshapeRig {
    let g = facecap_core::paths::shared_data_file("bench", "models3d/ict_facekit/ict_face_arkit53.glb");
    let m = facecap_core::paths::shared_data_file("bench", "models3d/ict_facekit/ict_landmarks68.json");
    match (g, m) {
        (Some(g), Some(m)) => BlendshapeRig::from_gltf(&g, &m).unwrap(),
        _ => BlendshapeRig::synthetic(53, 1),
    }
}

fn bench_one<S: ExpressionSolver>(
    c: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    id: BenchmarkId,
    s: &S,
    frames: &[Landmarks68],
    cold: bool,
) {
    let n = s.num_shapes();
    let mut ws = s.workspace();
    let mut st = SolveState::new(n);
    let mut out = Solution::new(n);
    let mut i = 0;
    c.bench_function(id, |b| {
        b.iter(|| {
            if cold {
                st.reset();
            }
            i = (i + 1) % frames.len();
            s.solve_into(&frames[i], &mut ws, &mut st, &mut out).unwrap()
        })
    });
}

fn solvers(c: &mut Criterion) {
    let mut g = c.benchmark_group("solve");
    g.sample_size(20)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1));
    let obj = ObjectiveParams::default();
    let obj_temporal = ObjectiveParams { temporal: 200.0, ..obj };

    // 16 shapes, fixture problems (2D methods)
    let (basis16, frames16) = fixture_basis();
    let exact16 = facecap_solve::ExactSolver::new(
        &basis16,
        facecap_solve::ExactParams {
            alignments: 1,
            ..Default::default()
        },
    )
    .unwrap();
    bench_one(&mut g, BenchmarkId::new("exact", 16), &exact16, &frames16, true);
    let bob16 = facecap_solve::BobyqaSolver::new(&basis16, facecap_solve::BobyqaParams::default()).unwrap();
    bench_one(&mut g, BenchmarkId::new("bobyqa", 16), &bob16, &frames16, true);

    // 53 shapes (ICT), and the ICT 16-shape subset for the 3D solver
    let rig = ict_rig();
    let cam = Intrinsics::default_for_frame(640, 480).unwrap();
    let frames = generate(
        &rig,
        &cam,
        640.0,
        &SynthParams {
            noise_px: 0.5,
            ..Default::default()
        },
        12,
        3,
    );
    let lms: Vec<Landmarks68> = frames.iter().map(|f| f.landmarks.clone()).collect();
    let n = rig.num_shapes();
    for m in [
        Method::Exact,
        Method::Bobyqa,
        Method::Region,
        Method::Pca,
        Method::Exact3d,
    ] {
        let s = AnySolver::new(m, &rig, cam, obj).unwrap();
        bench_one(&mut g, BenchmarkId::new(m.name(), n), &s, &lms, true);
    }
    // warm-started tracking: a smooth 60-frame trajectory, state carried between frames
    let traj = facecap_solve::synth::trajectory(&rig, &cam, 640.0, 0.5, 60, 5);
    let tl: Vec<Landmarks68> = traj.iter().map(|f| f.landmarks.clone()).collect();
    for m in [Method::Exact, Method::Exact3d] {
        let s = AnySolver::new(m, &rig, cam, obj).unwrap();
        bench_one(
            &mut g,
            BenchmarkId::new(format!("{}_warm", m.name()), n),
            &s,
            &tl,
            false,
        );
    }
    // with the temporal term (mu > 0 changes the Hessian's diagonal shift every frame, so the
    // QP factor is recomputed instead of reused)
    let s = AnySolver::new(Method::Exact, &rig, cam, obj_temporal).unwrap();
    bench_one(&mut g, BenchmarkId::new("exact_warm_temporal", n), &s, &tl, false);
    if n > 16 {
        let sub = rig
            .select(&rig.names.iter().take(16).map(String::as_str).collect::<Vec<_>>())
            .unwrap();
        let frames = generate(
            &sub,
            &cam,
            640.0,
            &SynthParams {
                noise_px: 0.5,
                ..Default::default()
            },
            12,
            3,
        );
        let lms: Vec<Landmarks68> = frames.iter().map(|f| f.landmarks.clone()).collect();
        let s = AnySolver::new(Method::Exact3d, &sub, cam, obj).unwrap();
        bench_one(&mut g, BenchmarkId::new("exact3d", 16), &s, &lms, true);
        let traj = facecap_solve::synth::trajectory(&sub, &cam, 640.0, 0.5, 60, 5);
        let tl: Vec<Landmarks68> = traj.iter().map(|f| f.landmarks.clone()).collect();
        for m in [Method::Exact, Method::Exact3d] {
            let s = AnySolver::new(m, &sub, cam, obj).unwrap();
            bench_one(
                &mut g,
                BenchmarkId::new(format!("{}_warm", m.name()), 16),
                &s,
                &tl,
                false,
            );
        }
        let s = AnySolver::new(Method::Exact, &sub, cam, obj_temporal).unwrap();
        bench_one(&mut g, BenchmarkId::new("exact_warm_temporal", 16), &s, &tl, false);
    }
    g.finish();
}

criterion_group!(benches, solvers);
criterion_main!(benches);
