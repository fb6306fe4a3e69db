#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Synthetic ground-truth evidence for `docs/tensor.md`: random identity/expression
//! weights (non-negative, summing to 1) and poses, projected points with Gaussian
//! pixel noise; recovery error of the regularised and the NNLS fit as a function of
//! lambda and of the number of points (the bias trade-off of Papanek 2010, fig. 4.9).
//!
//! `cargo run --release -p facecap-tensor --example evidence`

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_tensor::fit::{FitInput, FitParams, Fitter, Method, Projection};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use nalgebra::{Point2, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const NV: usize = 3000;
const NI: usize = 20;
const NE: usize = 7;
/// Trials per row (override with `FACECAP_EVIDENCE_TRIALS`).
const TRIALS_DEFAULT: usize = 20;

fn trials() -> usize {
    std::env::var("FACECAP_EVIDENCE_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(TRIALS_DEFAULT)
}
const NOISE_PX: f64 = 1.0;

fn simplex(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    let v: Vec<f64> = (0..n).map(|_| -rng.random::<f64>().max(1e-12).ln()).collect();
    let s: f64 = v.iter().sum();
    v.iter().map(|x| x / s).collect()
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

struct Outcome {
    mesh_rms: f64,
    exp_disp_rms: f64,
    px_rms: f64,
    sweeps: f64,
    ms: f64,
}

fn run(model: &TensorModel, npts: usize, method: Method, lambda: f64, projection: Projection, seed: u64) -> Outcome {
    let k = Intrinsics::new(800.0, 800.0, 319.5, 239.5).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut mesh, mut disp, mut px, mut sweeps, mut ms) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let neutral = {
        let mut e = vec![0.0; NE];
        e[0] = 1.0;
        e
    };
    for _ in 0..trials() {
        let mut vs: Vec<u32> = (0..NV as u32).collect();
        for i in 0..npts {
            let j = rng.random_range(i..NV);
            vs.swap(i, j);
        }
        vs.truncate(npts);
        let w_id = simplex(&mut rng, NI);
        let w_exp = simplex(&mut rng, NE);
        let pose = ModelToCamera::from_rvec_tvec(
            Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.15..0.15),
            ),
            Vector3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(45.0..80.0),
            ),
        );
        let truth = model.generate(&w_id, &w_exp).unwrap();
        let image: Vec<Point2<f64>> = vs
            .iter()
            .map(|&v| {
                let v = v as usize;
                let p = pose
                    .project(&k, &Point3::new(truth[3 * v], truth[3 * v + 1], truth[3 * v + 2]))
                    .unwrap();
                Point2::new(p.x + NOISE_PX * gauss(&mut rng), p.y + NOISE_PX * gauss(&mut rng))
            })
            .collect();
        let params = FitParams {
            lambda_id: lambda,
            lambda_exp: lambda,
            method,
            projection,
            max_sweeps: 200,
            tol: 1e-9,
            ..Default::default()
        };
        let fitter = Fitter::new(model, &vs, params).unwrap();
        let mut ws = fitter.workspace();
        let mut st = fitter.initial_state();
        let weights = vec![1.0; npts];
        let input = FitInput {
            image: &image,
            weights: &weights,
            intrinsics: k,
        };
        let t = std::time::Instant::now();
        let rep = fitter.solve_into(&input, &mut ws, &mut st).unwrap();
        ms += t.elapsed().as_secs_f64() * 1e3;
        let fit = model.generate(&st.w_id, &st.w_exp).unwrap();
        let r = |a: &[f64], b: &[f64]| (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / NV as f64).sqrt();
        mesh += r(&fit, &truth);
        // Expression displacement relative to the same identity's neutral.
        let tn = model.generate(&w_id, &neutral).unwrap();
        let fnn = model.generate(&st.w_id, &neutral).unwrap();
        let td: Vec<f64> = truth.iter().zip(&tn).map(|(a, b)| a - b).collect();
        let fd: Vec<f64> = fit.iter().zip(&fnn).map(|(a, b)| a - b).collect();
        disp += r(&fd, &td);
        px += rep.rms_px;
        sweeps += rep.sweeps as f64;
    }
    let n = trials() as f64;
    Outcome {
        mesh_rms: mesh / n,
        exp_disp_rms: disp / n,
        px_rms: px / n,
        sweeps: sweeps / n,
        ms: ms / n,
    }
}

fn main() {
    let d = synth::database(NV, NI, NE, 42).unwrap();
    let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    // Scale of the problem: RMS distance of database faces from the mean face.
    let spread = {
        let mut s = 0.0;
        for i in 0..NI {
            for e in 0..NE {
                let c = d.data.slice(ndarray::s![.., i, e]);
                s += c
                    .iter()
                    .zip(model.mean.iter())
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    / NV as f64;
            }
        }
        (s / (NI * NE) as f64).sqrt()
    };
    println!("synthetic database: {NV} vertices, {NI} identities x {NE} expressions; RMS distance of a database face from the mean face {spread:.3} units; {} trials per row, noise {NOISE_PX} px, f = 800 px, depth 45-80 units\n", trials());
    println!("### Effect of lambda (68 points, weak perspective)\n");
    println!("| method | lambda | mesh RMS error | expression-displacement RMS error | reprojection RMS (px) | sweeps | ms per fit |");
    println!("|---|---|---|---|---|---|---|");
    for method in [Method::Regularised, Method::NonNegative] {
        for lambda in [1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0] {
            let o = run(&model, 68, method, lambda, Projection::WeakPerspective, 7);
            println!(
                "| {method:?} | {lambda:e} | {:.4} | {:.4} | {:.3} | {:.1} | {:.2} |",
                o.mesh_rms, o.exp_disp_rms, o.px_rms, o.sweeps, o.ms
            );
        }
    }
    println!("\n### Effect of the number of points (lambda = 1e-2)\n");
    println!("| method | projection | points | mesh RMS error | expression-displacement RMS error | reprojection RMS (px) | sweeps | ms per fit |");
    println!("|---|---|---|---|---|---|---|---|");
    for method in [Method::Regularised, Method::NonNegative] {
        for projection in [Projection::WeakPerspective, Projection::PerPointDepth] {
            for npts in [20, 68, 200, 500] {
                let o = run(&model, npts, method, 1e-2, projection, 11);
                println!(
                    "| {method:?} | {projection:?} | {npts} | {:.4} | {:.4} | {:.3} | {:.1} | {:.2} |",
                    o.mesh_rms, o.exp_disp_rms, o.px_rms, o.sweeps, o.ms
                );
            }
        }
    }
}
