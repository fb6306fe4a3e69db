#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
//! Tracks a synthetic ground-truth sequence and prints the thesis' error measure for both
//! solvers at several noise levels: `cargo run --release -p facecap-muscle --example synthetic_track`.

use std::f64::consts::FRAC_PI_4;
use std::time::Instant;

use facecap_muscle::defaults::{default_muscle_set, landmark_positions};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::synthetic::{make_sequence, SyntheticFace};
use facecap_muscle::track::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    let face = SyntheticFace::new(61, 67);
    let lm = landmark_positions(&face.map, &face.positions);
    let set = default_muscle_set(&lm, &face.positions).unwrap();
    let rig = MuscleRig::from_mesh(&set, &face.mesh()).unwrap();
    println!("| noise (px) | solver | points/muscle | thesis error | contraction MAE | jaw MAE (rad) | mean rms (px) | mean solve (ms) |");
    println!("|---|---|---|---|---|---|---|---|");
    for noise in [0.0, 0.5, 1.0, 2.0] {
        for (mode, ppm) in [
            (SolveMode::Global, 1),
            (SolveMode::PointByPoint, 1),
            (SolveMode::PointByPoint, 4),
        ] {
            let model = TrackModel::from_landmarks(&rig, &face.map, &[], ppm).unwrap();
            let (mut err, mut cerr, mut jerr, mut rms, mut time, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            for seed in 0..5u64 {
                let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
                let seq = make_sequence(&rig, model.vertices(), 90, noise, &mut || rng.random::<f64>()).unwrap();
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
                for (f, obs) in seq.observations.iter().enumerate() {
                    let t0 = Instant::now();
                    let rep = tracker
                        .solve_into(
                            &TrackInput {
                                points: obs,
                                weights: None,
                            },
                            &mut ws,
                            &mut st,
                            &mut out,
                        )
                        .unwrap();
                    time += t0.elapsed().as_secs_f64();
                    rms += rep.rms_px;
                    let mut e = 0.0;
                    for (a, b) in out.contractions.iter().zip(&seq.contractions[f]) {
                        e += (a - b).abs();
                        cerr += (a - b).abs() / out.contractions.len() as f64;
                    }
                    e += (out.jaw - seq.jaw[f]).abs() / FRAC_PI_4;
                    jerr += (out.jaw - seq.jaw[f]).abs();
                    err += e / (out.contractions.len() + 1) as f64;
                    n += 1.0;
                }
            }
            println!(
                "| {noise} | {mode:?} | {ppm} | {:.4} | {:.4} | {:.4} | {:.3} | {:.3} |",
                err / n,
                cerr / n,
                jerr / n,
                rms / n,
                1e3 * time / n
            );
        }
    }
}
