#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Per-solve time of our two-pass BOBYQA on the 12 problems of
//! `testdata/solve/bobyqa_dlib_fixture.json` (the problems `testdata/solve/time_dlib_bobyqa.py`
//! times dlib's `find_min_bobyqa` on; the same as the criterion id `solve/bobyqa/16`), cold start
//! as dlib's driver. Prints wall time per solve (mean, median, min) and the process CPU time per
//! solve (from /proc/self/stat over the whole loop), plus evaluations.
//!
//! `cargo run --release -p facecap-solve --example bobyqa_timing [-- REPS]`

use std::time::Instant;

use facecap_core::landmarks::Landmarks68;
use facecap_solve::{Basis2d, BobyqaParams, BobyqaSolver, ExpressionSolver, Solution, SolveState};

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

fn cpu_seconds() -> f64 {
    // utime + stime of this process, clock ticks (USER_HZ = 100 on Linux)
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let reps: usize = std::env::args().nth(1).map_or(20, |s| s.parse().unwrap());
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
    let mut stable = [false; 68];
    for i in facecap_solve::basis::DEFAULT_STABLE {
        stable[i] = true;
    }
    let basis = Basis2d {
        names: (0..k).map(|i| format!("s{i}")).collect(),
        neutral: fx.neutral.clone(),
        deltas: d,
        mapped: [true; 68],
        stable,
    };
    let frames: Vec<Landmarks68> = fx
        .problems
        .iter()
        .map(|p| Landmarks68::from_fn(|l| (p.obs[2 * l], p.obs[2 * l + 1])))
        .collect();
    let s = BobyqaSolver::new(&basis, BobyqaParams::default()).unwrap();
    let mut ws = s.workspace();
    let mut st = SolveState::new(k);
    let mut out = Solution::new(k);
    // warm-up pass (as dlib's driver)
    for f in &frames {
        st.reset();
        s.solve_into(f, &mut ws, &mut st, &mut out).unwrap();
    }
    let mut t = Vec::new();
    let mut evals = Vec::new();
    let c0 = cpu_seconds();
    for _ in 0..reps {
        for f in &frames {
            st.reset();
            let t0 = Instant::now();
            let r = s.solve_into(f, &mut ws, &mut st, &mut out).unwrap();
            t.push(t0.elapsed().as_secs_f64() * 1e6);
            evals.push(r.evaluations);
        }
    }
    let cpu = (cpu_seconds() - c0) * 1e6 / t.len() as f64;
    let mean = t.iter().sum::<f64>() / t.len() as f64;
    t.sort_by(f64::total_cmp);
    evals.sort_unstable();
    println!(
        "our BOBYQA (bobyqa_solver, two passes), {} fixture problems x {reps} reps (after one warm-up pass):",
        frames.len()
    );
    println!(
        "  wall per solve: mean {mean:.0} us, median {:.0} us, min {:.0} us; process CPU per solve (mean) {cpu:.0} us",
        t[t.len() / 2],
        t[0]
    );
    println!(
        "  evaluations per solve: median {} (range {}-{})",
        evals[evals.len() / 2],
        evals[0],
        evals[evals.len() - 1]
    );
}
