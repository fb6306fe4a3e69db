#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Prints the evidence tables of `docs/solvers.md`:
//! 1. synthetic ground truth (ICT rig if the shared data is present, else a synthetic rig):
//!    random sparse weights, yaw +-30 / pitch +-20 / roll +-10 deg, default camera 640x480,
//!    0 / 0.5 / 2 px noise; per method weight RMSE, reprojection error, time per frame;
//! 2. real video (dlib landmark fixtures in testdata/solve): mean reprojection error per method
//!    and weight jitter on the stillest stretch with and without the temporal term.
//!
//! `cargo run --release -p facecap-solve --example evaluate [-- FRAMES]`

use std::time::Instant;

use facecap_core::camera::Intrinsics;
use facecap_core::landmarks::Landmarks68;
use facecap_solve::synth::{generate, rmse, SynthParams};
use facecap_solve::{
    AnySolver, BlendshapeRig, Exact3dParams, Exact3dSolver, ExpressionSolver, Method, ObjectiveParams, Solution,
    SolveState,
};

fn load_rig() -> (BlendshapeRig, String) {
    let g = facecap_core::paths::shared_data_file("evaluate", "models3d/ict_facekit/ict_face_arkit53.glb");
    let m = facecap_core::paths::shared_data_file("evaluate", "models3d/ict_facekit/ict_landmarks68.json");
    match (g, m) {
        (Some(g), Some(m)) => (
            BlendshapeRig::from_gltf(&g, &m).unwrap(),
            "ICT FaceKit ARKit-53 (MIT)".into(),
        ),
        _ => (BlendshapeRig::synthetic(16, 1), "synthetic 16-shape rig".into()),
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn solve_seq(s: &AnySolver, frames: &[Landmarks68]) -> (Vec<Solution>, Vec<f64>, Vec<f64>) {
    let n = s.num_shapes();
    let mut ws = s.workspace();
    let mut st = SolveState::new(n);
    let mut out = Solution::new(n);
    let (mut sols, mut times, mut costs) = (Vec::new(), Vec::new(), Vec::new());
    for lm in frames {
        let t = Instant::now();
        let r = s.solve_into(lm, &mut ws, &mut st, &mut out).unwrap();
        times.push(t.elapsed().as_secs_f64() * 1e6);
        costs.push(r.cost);
        sols.push(out.clone());
    }
    (sols, times, costs)
}

fn synthetic(rig: &BlendshapeRig, rig_name: &str, count: usize, pose: SynthParams) {
    let cam = Intrinsics::default_for_frame(640, 480).unwrap();
    println!(
        "### Synthetic ground truth: {rig_name}, {} shapes, {count} frames per noise level\n",
        rig.num_shapes()
    );
    println!("Each frame is solved independently (fresh state: cold start, no temporal term).\n");
    println!("| noise (px) | method | weight RMSE | reprojection error (px) | time/frame median (us) |");
    println!("|---|---|---|---|---|");
    let s3 = Exact3dSolver::new(rig, Exact3dParams::new(cam)).unwrap();
    for noise in [0.0, 0.5, 2.0] {
        let frames = generate(
            rig,
            &cam,
            640.0,
            &SynthParams {
                noise_px: noise,
                ..pose
            },
            count,
            42,
        );
        let mut bob_w: Vec<Vec<f64>> = Vec::new();
        let mut ex3_cost = Vec::new();
        for m in [
            Method::Bobyqa,
            Method::Region,
            Method::Pca,
            Method::Exact,
            Method::Exact3d,
        ] {
            let s = AnySolver::new(m, rig, cam, ObjectiveParams::default()).unwrap();
            let (mut e_rmse, mut e_rep, mut times) = (0.0, 0.0, Vec::new());
            for f in &frames {
                // independent frames: fresh state each
                let (sols, t, c) = solve_seq(&s, std::slice::from_ref(&f.landmarks));
                e_rmse += rmse(&sols[0].weights, &f.weights);
                e_rep += sols[0].reprojection_error(&f.landmarks);
                times.push(t[0]);
                if m == Method::Bobyqa {
                    bob_w.push(sols[0].weights.clone());
                }
                if m == Method::Exact3d {
                    ex3_cost.push(c[0]);
                }
            }
            let k = frames.len() as f64;
            println!(
                "| {noise} | {} | {:.4} | {:.2} | {:.0} |",
                m.name(),
                e_rmse / k,
                e_rep / k,
                median(&mut times)
            );
        }
        // exact3d objective vs BOBYQA's weights scored under the 3D model (best pose)
        let mut wins = 0;
        for ((f, w), c) in frames.iter().zip(&bob_w).zip(&ex3_cost) {
            let (_, fb) = s3.fit_pose(&f.landmarks, w).unwrap();
            if *c <= fb + 1e-9 * fb {
                wins += 1;
            }
        }
        println!(
            "| {noise} | (exact3d objective <= BOBYQA's, 3D-scored) | {wins}/{} frames | | |",
            frames.len()
        );
    }
    println!();
}

fn still_stretch(frames: &[Landmarks68], len: usize) -> usize {
    let motion =
        |a: &Landmarks68, b: &Landmarks68| a.points.iter().zip(&b.points).map(|(p, q)| (p - q).norm()).sum::<f64>();
    let mut best = (f64::INFINITY, 0);
    for s in 0..frames.len().saturating_sub(len) {
        let m: f64 = (s..s + len - 1).map(|i| motion(&frames[i], &frames[i + 1])).sum();
        if m < best.0 {
            best = (m, s);
        }
    }
    best.1
}

fn jitter(sols: &[Solution]) -> f64 {
    // mean over consecutive pairs of the RMS weight change
    let mut s = 0.0;
    for w in sols.windows(2) {
        s += rmse(&w[0].weights, &w[1].weights);
    }
    s / (sols.len() - 1).max(1) as f64
}

fn real(rig: &BlendshapeRig, rig_name: &str, methods: &[Method]) {
    println!("### Real video: {rig_name}, dlib 68-point landmark fixtures (every 2nd frame of the first 120)\n");
    println!("| clip | method | mean reprojection error (px) | time/frame median (us) | jitter on still stretch, mu = 0 | jitter, mu = 200 px^2 |");
    println!("|---|---|---|---|---|---|");
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../testdata/solve");
    for (clip, w, h) in [("liveportrait_d3", 512, 512), ("liveportrait_d9", 512, 480)] {
        let recs = facecap_io::csv::read_landmarks_csv(format!("{dir}/landmarks_{clip}.csv")).unwrap();
        let frames: Vec<Landmarks68> = recs.iter().filter_map(|r| r.landmarks.clone()).collect();
        let cam = Intrinsics::default_for_frame(w, h).unwrap();
        let still = still_stretch(&frames, 10);
        if methods.len() > 2 {
            println!("<!-- {clip}: still stretch = rows {still}..{} -->", still + 10);
        }
        for m in [
            Method::Bobyqa,
            Method::Region,
            Method::Pca,
            Method::Exact,
            Method::Exact3d,
        ] {
            let s = AnySolver::new(m, rig, cam, ObjectiveParams::default()).unwrap();
            let (sols, mut t, _) = solve_seq(&s, &frames);
            let err: f64 = sols
                .iter()
                .zip(&frames)
                .map(|(s, f)| s.reprojection_error(f))
                .sum::<f64>()
                / frames.len() as f64;
            let j0 = jitter(&sols[still..still + 10]);
            let st = AnySolver::new(
                m,
                rig,
                cam,
                ObjectiveParams {
                    l1: 1.0,
                    temporal: 200.0,
                },
            )
            .unwrap();
            let (sols_t, _, _) = solve_seq(&st, &frames);
            let j1 = jitter(&sols_t[still..still + 10]);
            println!(
                "| {clip} | {} | {err:.2} | {:.0} | {j0:.4} | {j1:.4} |",
                m.name(),
                median(&mut t)
            );
        }
    }
    println!();
}

/// The seed's own setting: observations made by the 2D model itself (frontal orthographic view
/// of the rig under a random similarity) plus noise.
fn consistent_2d(rig: &BlendshapeRig, rig_name: &str, count: usize) {
    use rand::{Rng, SeedableRng};
    println!(
        "### 2D-consistent data: {rig_name}, orthographic frontal view under a random similarity, {count} frames\n"
    );
    println!("| noise (px) | method | weight RMSE | reprojection error (px) |");
    println!("|---|---|---|---|");
    let cam = Intrinsics::default_for_frame(640, 480).unwrap();
    let n = rig.num_shapes();
    for noise in [0.0, 0.5, 2.0] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut frames = Vec::new();
        for _ in 0..count {
            let mut w = vec![0.0; n];
            for _ in 0..rng.random_range(2..=5) {
                w[rng.random_range(0..n)] = rng.random_range(0.2..1.0);
            }
            let (a, sc) = (rng.random_range(-0.3..0.3f64), rng.random_range(12.0..18.0));
            let (tx, ty) = (rng.random_range(250.0..390.0), rng.random_range(190.0..290.0));
            let mut nz =
                || noise * (rng.random_range(-1.0..1.0f64) + rng.random_range(-1.0..1.0) + rng.random_range(-1.0..1.0));
            let lm = Landmarks68::from_fn(|l| {
                let p = rig.landmark(l, &w);
                let (x, y) = (p.x, -p.y);
                (
                    tx + sc * (a.cos() * x - a.sin() * y) + nz(),
                    ty + sc * (a.sin() * x + a.cos() * y) + nz(),
                )
            });
            frames.push((w, lm));
        }
        for m in [Method::Bobyqa, Method::Region, Method::Pca, Method::Exact] {
            let s = AnySolver::new(m, rig, cam, ObjectiveParams::default()).unwrap();
            let (mut e, mut r) = (0.0, 0.0);
            for (w, lm) in &frames {
                let (sols, _, _) = solve_seq(&s, std::slice::from_ref(lm));
                e += rmse(&sols[0].weights, w);
                r += sols[0].reprojection_error(lm);
            }
            let k = frames.len() as f64;
            println!("| {noise} | {} | {:.4} | {:.2} |", m.name(), e / k, r / k);
        }
    }
    println!("\n(noise: sum of three U(-1, 1) draws times the level, std = level.)\n");
}

fn main() {
    let count: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(30);
    let (rig, name) = load_rig();
    if std::env::args().nth(2).as_deref() == Some("2d") {
        let sub = if rig.num_shapes() > 16 {
            rig.select(&SUBSET16).unwrap()
        } else {
            rig.clone()
        };
        consistent_2d(&sub, &format!("{name}, 16-shape subset"), count);
        return;
    }
    let sub = if rig.num_shapes() > 16 {
        let names: Vec<&str> = SUBSET16.to_vec();
        rig.select(&names).unwrap()
    } else {
        rig.clone()
    };
    let sub_name = format!("{name}, 16-shape subset");
    let wide = SynthParams::default();
    let frontal = SynthParams {
        max_yaw_deg: 3.0,
        max_pitch_deg: 3.0,
        max_roll_deg: 3.0,
        ..Default::default()
    };
    synthetic(&sub, &sub_name, count, wide);
    synthetic(&sub, &sub_name, count, frontal);
    if rig.num_shapes() > 16 {
        synthetic(&rig, &name, (count / 3).max(3), wide);
    }
    real(&sub, &sub_name, &Method::ALL);
    if rig.num_shapes() > 16 {
        real(&rig, &name, &[Method::Exact, Method::Exact3d]);
    }
}

const SUBSET16: [&str; 16] = [
    "browDown_L",
    "browInnerUp_L",
    "browOuterUp_L",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeWide_L",
    "jawOpen",
    "jawLeft",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthFunnel",
    "mouthPucker",
    "mouthStretch_L",
    "mouthUpperUp_L",
    "mouthLowerDown_R",
    "mouthFrown_L",
];
