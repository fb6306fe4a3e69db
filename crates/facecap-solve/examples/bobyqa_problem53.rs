#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Writes a 53-shape BOBYQA problem file in the format of the anchor's dlib driver
//! (`shared/anchors/cpp/bobyqa_fit.cpp`; read back by `bobyqa_timing REPS FILE`), so that
//! dlib's `find_min_bobyqa` and our BOBYQA can be timed on the same 53-shape problems.
//!
//! Basis: the ICT ARKit-53 rig seen frontally ([`Basis2d::frontal`]; the synthetic 53-shape rig
//! if the shared data is absent), scaled to a 200 px wide face. 12 problems (seed 7):
//! `obs = neutral + D^T w + noise`, four active shapes with weights in [0.2, 0.8], uniform noise
//! of +-0.5 px. Recipe as the 16-shape fixture: lambda 1, npt `2n + 1`, rho 0.075 -> 0.01 then
//! 0.075 -> 0.005, at most 30000 evaluations per pass, cold start `w = 0`.
//!
//! `cargo run --release -p facecap-solve --example bobyqa_problem53 -- OUT.bin [REPS]`

use facecap_solve::{Basis2d, BlendshapeRig};
use rand::{Rng, SeedableRng};

fn main() {
    let out = std::env::args().nth(1).expect("usage: bobyqa_problem53 OUT.bin [REPS]");
    let reps: i32 = std::env::args().nth(2).map_or(2, |s| s.parse().unwrap());
    let g = facecap_core::paths::shared_data_file("bobyqa_problem53", "models3d/ict_facekit/ict_face_arkit53.glb");
    let m = facecap_core::paths::shared_data_file("bobyqa_problem53", "models3d/ict_facekit/ict_landmarks68.json");
    let rig = match (g, m) {
        (Some(g), Some(m)) => BlendshapeRig::from_gltf(&g, &m).unwrap(),
        _ => BlendshapeRig::synthetic(53, 1),
    };
    let basis = Basis2d::frontal(&rig);
    let k = basis.num_shapes();
    let cols = basis.neutral.len();
    let xs: Vec<f64> = basis.neutral.iter().step_by(2).copied().filter(|v| *v != 0.0).collect();
    let width = xs.iter().fold(f64::MIN, |a, v| a.max(*v)) - xs.iter().fold(f64::MAX, |a, v| a.min(*v));
    let scale = 200.0 / width;
    let neutral: Vec<f64> = basis.neutral.iter().map(|v| v * scale).collect();
    let deltas: Vec<f64> = basis.deltas.iter().map(|v| v * scale).collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let problems = 12;
    let mut obs = Vec::with_capacity(problems * cols);
    for _ in 0..problems {
        let mut w = vec![0.0; k];
        for _ in 0..4 {
            w[rng.random_range(0..k)] = rng.random_range(0.2..0.8);
        }
        for j in 0..cols {
            let clean = neutral[j] + (0..k).map(|a| w[a] * deltas[a * cols + j]).sum::<f64>();
            obs.push(if neutral[j] == 0.0 {
                0.0
            } else {
                clean + rng.random_range(-0.5..0.5)
            });
        }
    }
    let mut b: Vec<u8> = Vec::new();
    for v in [problems as i32, cols as i32, k as i32, reps, 0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for v in [1.0f64, 0.075, 0.01, 0.005] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for v in [(2 * k + 1) as i32, 30000] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    let x0 = vec![0.0; problems * k];
    for v in neutral.iter().chain(&deltas).chain(&obs).chain(&x0) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&out, b).unwrap();
    println!("wrote {out}: {problems} problems, {k} shapes, {cols} coordinates, {reps} reps");
}
