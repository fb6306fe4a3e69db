#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::needless_range_loop)]
//! Synthetic ground truth: deform a mesh with known contractions, jaw and head pose, project
//! with noise, track, and score with the thesis' error measure.

use std::f64::consts::FRAC_PI_4;

use facecap_muscle::defaults::{default_muscle_set, landmark_positions};
use facecap_muscle::rig::MuscleRig;
use facecap_muscle::synthetic::{make_sequence, SyntheticFace, SyntheticSequence};
use facecap_muscle::track::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Scores {
    thesis_error: f64,
    contraction_mae: f64,
    jaw_mae_rad: f64,
    mean_rms_px: f64,
}

fn setup() -> (MuscleRig, TrackModel) {
    let face = SyntheticFace::new(61, 67);
    let lm = landmark_positions(&face.map, &face.positions);
    let set = default_muscle_set(&lm, &face.positions).unwrap();
    let rig = MuscleRig::from_mesh(&set, &face.mesh()).unwrap();
    let model = TrackModel::from_landmarks(&rig, &face.map, &[], 1).unwrap();
    (rig, model)
}

fn run(model: &TrackModel, seq: &SyntheticSequence, params: TrackParams) -> Scores {
    let tracker = MuscleTracker::new(model.clone(), seq.intrinsics, params).unwrap();
    let mut ws = TrackWorkspace::new(model);
    let mut st = TrackState::new(model);
    let mut out = TrackOutput::new(model);
    let (mut err, mut cerr, mut jerr, mut n, mut rms) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (f, obs) in seq.observations.iter().enumerate() {
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
        rms += rep.rms_px;
        // Thesis measure: mean |x_eval - x_true| over keyframes and parameters, jaw / (pi/4).
        let mut e = 0.0;
        for (a, b) in out.contractions.iter().zip(&seq.contractions[f]) {
            e += (a - b).abs();
            cerr += (a - b).abs();
        }
        e += (out.jaw - seq.jaw[f]).abs() / FRAC_PI_4;
        jerr += (out.jaw - seq.jaw[f]).abs();
        err += e / (out.contractions.len() + 1) as f64;
        n += 1.0;
    }
    let m = model.num_muscles() as f64;
    Scores {
        thesis_error: err / n,
        contraction_mae: cerr / (n * m),
        jaw_mae_rad: jerr / n,
        mean_rms_px: rms / n,
    }
}

#[test]
fn synthetic_sequence_tracks_below_thesis_threshold() {
    let (rig, model) = setup();
    for (seed, noise) in [(1u64, 0.0), (2, 0.5), (3, 1.0)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let seq = make_sequence(&rig, model.vertices(), 90, noise, &mut || rng.random::<f64>()).unwrap();
        let g = run(&model, &seq, TrackParams::default());
        let p = run(
            &model,
            &seq,
            TrackParams {
                mode: SolveMode::PointByPoint,
                ..Default::default()
            },
        );
        for (name, s) in [("global", &g), ("point-by-point", &p)] {
            println!(
                "seed {seed} noise {noise} px {name}: thesis error {:.4}, contraction MAE {:.4}, jaw MAE {:.4} rad, mean rms {:.3} px",
                s.thesis_error, s.contraction_mae, s.jaw_mae_rad, s.mean_rms_px
            );
        }
        // measured: point-by-point thesis error 0.24-0.27, rms 10.1-10.2 px at every noise
        // level (it fits each landmark alone, so noise-free data do not help it); global
        // 0.0001 / 0.010 / 0.018
        assert!(p.thesis_error < 0.35, "point-by-point thesis error {}", p.thesis_error);
        assert!(p.mean_rms_px < 13.0, "point-by-point rms {} px", p.mean_rms_px);
        assert!(
            g.thesis_error < p.thesis_error / 5.0,
            "global no better than point-by-point"
        );
        assert!(
            g.thesis_error < 0.05,
            "global thesis error {} at noise {noise}",
            g.thesis_error
        );
    }
}
