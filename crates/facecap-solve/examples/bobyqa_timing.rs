#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Per-solve time of our two-pass BOBYQA on the 12 problems of
//! `testdata/solve/bobyqa_dlib_fixture.json` (the problems `testdata/solve/time_dlib_bobyqa.py`
//! times dlib's `find_min_bobyqa` on; the same as the criterion id `solve/bobyqa/16`), cold start
//! as dlib's driver. Prints wall time per solve (mean, median, min) and the process CPU time per
//! solve (from /proc/self/stat over the whole loop), plus evaluations.
//!
//! With a second argument, a problem file in the format of the anchor's dlib driver is solved
//! instead (the anchor's `data/bobyqa_problem.bin` written by `shared/anchors/bench_bobyqa_fit.py`,
//! or the 53-shape problems of `examples/bobyqa_problem53.rs`), by our BOBYQA
//! ([`facecap_solve::bobyqa::Bobyqa`]) with exactly the driver's objective
//! `||neutral + D^T w - obs||^2 + lambda sum |w|` (no alignment; evaluated through the Gram
//! matrix, same values) and the same two passes.
//!
//! `cargo run --release -p facecap-solve --example bobyqa_timing [-- REPS [ANCHOR_PROBLEM.bin]]`

mod common;

use std::time::Instant;

use facecap_core::landmarks::Landmarks68;
use facecap_solve::bobyqa::{Bobyqa, BobyqaRun};
use facecap_solve::{Basis2d, BobyqaParams, BobyqaSolver, ExpressionSolver, Solution, SolveState};

fn cpu_seconds() -> f64 {
    // utime + stime of this process, clock ticks (USER_HZ = 100 on Linux)
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

fn anchor_problem(reps: usize, path: &str) {
    let b = std::fs::read(path).unwrap();
    let mut off = 0usize;
    let mut i32_ = || {
        let v = i32::from_le_bytes(b[off..off + 4].try_into().unwrap());
        off += 4;
        v as usize
    };
    let (p, m, k, _r, warm) = (i32_(), i32_(), i32_(), i32_(), i32_());
    let rd = |off: &mut usize, n: usize| -> Vec<f64> {
        let v = (0..n)
            .map(|j| f64::from_le_bytes(b[*off + 8 * j..*off + 8 * j + 8].try_into().unwrap()))
            .collect();
        *off += 8 * n;
        v
    };
    let hdr = rd(&mut off, 4);
    let (lambda, rho_begin, rho_end) = (hdr[0], hdr[1], [hdr[2], hdr[3]]);
    let npt = i32::from_le_bytes(b[off..off + 4].try_into().unwrap()) as usize;
    let max_evals = i32::from_le_bytes(b[off + 4..off + 8].try_into().unwrap()) as usize;
    off += 8;
    let neutral = rd(&mut off, m);
    let d = rd(&mut off, k * m);
    let obs = rd(&mut off, p * m);
    let x0 = rd(&mut off, p * k);
    let mut gram = vec![0.0; k * k];
    for a in 0..k {
        for c in 0..k {
            gram[a * k + c] = (0..m).map(|j| d[a * m + j] * d[c * m + j]).sum();
        }
    }
    let mut engine = Bobyqa::new(k, npt).unwrap();
    let (lo, hi) = (vec![0.0; k], vec![1.0; k]);
    let (mut t, mut evals, mut fs) = (Vec::new(), Vec::new(), Vec::new());
    let mut x = vec![0.0; k];
    let mut dtb = vec![0.0; k];
    let c0 = cpu_seconds();
    for rep in 0..=reps {
        for q in 0..p {
            // b = obs - neutral; f(w) = w^T G w - 2 w^T D b + b^T b + lambda sum w
            let bq: Vec<f64> = (0..m).map(|j| obs[q * m + j] - neutral[j]).collect();
            let bb: f64 = bq.iter().map(|v| v * v).sum();
            for a in 0..k {
                dtb[a] = (0..m).map(|j| d[a * m + j] * bq[j]).sum();
            }
            if warm != 0 {
                x.copy_from_slice(&x0[q * k..(q + 1) * k]);
            } else {
                x.fill(0.0);
            }
            let t0 = Instant::now();
            let mut ev = 0;
            let mut f = 0.0;
            for re in rho_end {
                let run = BobyqaRun {
                    rho_begin,
                    rho_end: re,
                    max_evals,
                };
                let o = engine
                    .minimize(
                        |w: &[f64]| {
                            let mut s = bb;
                            for a in 0..k {
                                let gw: f64 = (0..k).map(|c| gram[a * k + c] * w[c]).sum();
                                s += w[a] * (gw - 2.0 * dtb[a]) + lambda * w[a].abs();
                            }
                            s
                        },
                        &mut x,
                        &lo,
                        &hi,
                        &run,
                    )
                    .unwrap();
                ev += o.evaluations;
                f = o.f;
            }
            if rep > 0 {
                t.push(t0.elapsed().as_secs_f64() * 1e6);
                evals.push(ev);
                fs.push(f);
            }
        }
    }
    let cpu = (cpu_seconds() - c0) * 1e6 / (t.len() + p) as f64;
    let mean = t.iter().sum::<f64>() / t.len() as f64;
    t.sort_by(f64::total_cmp);
    evals.sort_unstable();
    fs.sort_by(f64::total_cmp);
    println!(
        "our BOBYQA (two passes) on the problem file: {p} problems x {reps} reps, {} start:",
        if warm != 0 { "warm" } else { "cold" }
    );
    println!(
        "  wall per solve: mean {mean:.0} us, median {:.0} us, min {:.0} us; process CPU per solve (mean, incl. warm-up pass) {cpu:.0} us",
        t[t.len() / 2],
        t[0]
    );
    println!(
        "  evaluations per solve: median {} (range {}-{}); final objective median {:.2}",
        evals[evals.len() / 2],
        evals[0],
        evals[evals.len() - 1],
        fs[fs.len() / 2]
    );
}

fn main() {
    let reps: usize = std::env::args().nth(1).map_or(20, |s| s.parse().unwrap());
    if let Some(path) = std::env::args().nth(2) {
        anchor_problem(reps, &path);
        return;
    }
    let fx = common::load_fixture();
    // the fixture's problems were made with the solver's default L1 weight
    assert_eq!(fx.lambda, BobyqaParams::default().objective.l1, "fixture lambda");
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
