#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Gap to the exact optimum of our two-pass BOBYQA on many problems: the 12 problems of
//! `testdata/solve/bobyqa_dlib_fixture.json` and `PER - 1` seeded perturbations of each
//! (observations + uniform noise of +-`NOISE` px, seed 11), objective
//! `||neutral + D^T w - obs||^2 + lambda sum |w|` over `[0, 1]^16` (as `tests/bobyqa.rs`), exact
//! optimum from the box-QP solver. BOBYQA's result moves chaotically with rounding, so quality
//! comparisons between versions need many problems; prints the mean gap with its standard error
//! and the mean number of evaluations.
//!
//! `cargo run --release -p facecap-solve --example bobyqa_quality [-- PER NOISE]`

mod common;

use facecap_geom::qp::{qp_cost, solve_box_qp, QpOptions, QpWorkspace};
use facecap_solve::bobyqa::{Bobyqa, BobyqaRun};
use rand::{Rng, SeedableRng};

fn main() {
    let per: usize = std::env::args().nth(1).map_or(40, |s| s.parse().unwrap());
    let noise: f64 = std::env::args().nth(2).map_or(1.0, |s| s.parse().unwrap());
    let fx = common::load_fixture();
    let (k, m) = (fx.deltas.len(), fx.neutral.len());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut probs = Vec::new();
    for p in &fx.problems {
        probs.push(p.obs.clone());
        for _ in 1..per {
            probs.push(
                p.obs
                    .iter()
                    .map(|v| v + noise * rng.random_range(-1.0..1.0))
                    .collect::<Vec<f64>>(),
            );
        }
    }
    // f(w) = w^T (D D^T) w + 2 w^T D b + b^T b + lambda sum w  (b = neutral - obs, w >= 0)
    let mut h = vec![0.0; k * k];
    for a in 0..k {
        for c in 0..k {
            h[a * k + c] = 2.0 * (0..m).map(|j| fx.deltas[a][j] * fx.deltas[c][j]).sum::<f64>();
        }
    }
    let (lo, hi) = (vec![0.0; k], vec![1.0; k]);
    let mut qws = QpWorkspace::new(k);
    let mut engine = Bobyqa::new(k, 2 * k + 1).unwrap();
    let (mut gaps, mut evals) = (Vec::new(), 0usize);
    for obs in &probs {
        let b: Vec<f64> = (0..m).map(|j| fx.neutral[j] - obs[j]).collect();
        let bb: f64 = b.iter().map(|v| v * v).sum();
        let g: Vec<f64> = (0..k)
            .map(|a| -(2.0 * (0..m).map(|j| fx.deltas[a][j] * b[j]).sum::<f64>() + fx.lambda))
            .collect();
        let mut xe = vec![0.0; k];
        solve_box_qp(&h, &g, &lo, &hi, &mut xe, &QpOptions::default(), &mut qws);
        let f_exact = qp_cost(&h, &g, &xe) + bb;
        let f = |w: &[f64]| {
            let mut s = 0.0;
            for j in 0..m {
                let mut r = b[j];
                for (wk, d) in w.iter().zip(&fx.deltas) {
                    r += wk * d[j];
                }
                s += r * r;
            }
            s + fx.lambda * w.iter().map(|v| v.abs()).sum::<f64>()
        };
        let mut x = vec![0.0; k];
        let mut fv = f64::NAN;
        for rho_end in [0.01, 0.005] {
            let run = BobyqaRun {
                rho_begin: 0.075,
                rho_end,
                max_evals: 30000,
            };
            let o = engine.minimize(f, &mut x, &lo, &hi, &run).unwrap();
            evals += o.evaluations;
            fv = o.f;
        }
        gaps.push(fv - f_exact);
    }
    let np = gaps.len() as f64;
    let mean = gaps.iter().sum::<f64>() / np;
    let sd = (gaps.iter().map(|d| (d - mean) * (d - mean)).sum::<f64>() / (np - 1.0).max(1.0)).sqrt();
    println!(
        "{} problems (noise +-{noise} px): mean gap to the exact optimum {mean:.4} +- {:.4} (standard error), mean evaluations {:.1}",
        gaps.len(),
        sd / np.sqrt(),
        evals as f64 / np
    );
}
