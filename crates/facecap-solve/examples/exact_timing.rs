#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Per-call timing of the exact 2D solver on the bench's warm-started trajectory (quick check
//! outside criterion; also a small, repeatable workload for `valgrind --tool=callgrind`).
//!
//! `cargo run --release -p facecap-solve --example exact_timing [-- REPS]`

use std::time::Instant;

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::Landmarks68;
use facecap_solve::{AnySolver, BlendshapeRig, ExpressionSolver, Method, ObjectiveParams, Solution, SolveState};

fn main() {
    let reps: usize = std::env::args().nth(1).map_or(200, |s| s.parse().unwrap());
    // optional filter on the printed label, e.g. "53 shapes temporal 0 warm"
    let filter = std::env::args().nth(2).unwrap_or_default();
    let g = facecap_core::paths::shared_data_file("exact_timing", "models3d/ict_facekit/ict_face_arkit53.glb");
    let m = facecap_core::paths::shared_data_file("exact_timing", "models3d/ict_facekit/ict_landmarks68.json");
    let rig = match (g, m) {
        (Some(g), Some(m)) => BlendshapeRig::from_gltf(&g, &m).unwrap(),
        _ => BlendshapeRig::synthetic(53, 1),
    };
    let sub = rig
        .select(&rig.names.iter().take(16).map(String::as_str).collect::<Vec<_>>())
        .unwrap();
    let cam = Intrinsics::default_for_frame(640, 480).unwrap();
    for (name, r) in [("16", &sub), ("53", &rig)] {
        let traj = facecap_solve::synth::trajectory(r, &cam, 640.0, 0.5, 60, 5);
        let tl: Vec<Landmarks68> = traj.iter().map(|f| f.landmarks.clone()).collect();
        for temporal in [0.0, 1.0] {
            let obj = ObjectiveParams { l1: 1.0, temporal };
            let s = AnySolver::new(Method::Exact, r, cam, obj).unwrap();
            let n = s.num_shapes();
            for cold in [false, true] {
                let label = format!(
                    "exact {name} shapes temporal {temporal} {}",
                    if cold { "cold" } else { "warm" }
                );
                if !label.contains(&filter) {
                    continue;
                }
                let mut ws = s.workspace();
                let mut st = SolveState::new(n);
                let mut out = Solution::new(n);
                let mut times = Vec::with_capacity(reps * tl.len());
                let (mut inner, mut calls) = (0usize, 0usize);
                for _ in 0..reps {
                    for lm in &tl {
                        if cold {
                            st.reset();
                        }
                        let t = Instant::now();
                        let rep = s.solve_into(lm, &mut ws, &mut st, &mut out).unwrap();
                        times.push(t.elapsed().as_nanos() as f64 * 1e-3);
                        inner += rep.evaluations;
                        calls += 1;
                    }
                }
                times.sort_by(|a, b| a.total_cmp(b));
                let mean = times.iter().sum::<f64>() / times.len() as f64;
                println!(
                    "{label}: median {:.2} us, mean {:.2} us, p10 {:.2}, p90 {:.2}; working-set changes/call {:.2}",
                    times[times.len() / 2],
                    mean,
                    times[times.len() / 10],
                    times[times.len() * 9 / 10],
                    inner as f64 / calls as f64
                );
            }
        }
    }
}
