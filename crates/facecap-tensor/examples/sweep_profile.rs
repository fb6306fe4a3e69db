#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Runs the 500-point fitting sweep of the criterion bench `tensor_fit_sweep_500pts` in a
//! loop, for profilers (`perf record`, `valgrind --tool=callgrind`): same synthetic model,
//! points, pose and warm start as the bench.
//!
//! `cargo run -j 1 --release -p facecap-tensor --example sweep_profile -- [Regularised|NonNegative] [full|fixed] [sweeps] [warm-up sweeps]`
//!
//! Callgrind instruction count of the sweeps only (the model build excluded):
//! `valgrind --tool=callgrind --toggle-collect='*Fitter*solve_into*' target/release/examples/sweep_profile Regularised full 20`
//!
//! The bench iterates thousands of sweeps from one warm start, so it mostly measures
//! the converged state. The same state in callgrind, without counting the warm-up
//! sweeps: `--toggle-collect='*sweep_profile*timed_sweeps*' ... Regularised full 20 1000`.

use std::time::Instant;

use facecap_tensor::fit::{FitInput, FitParams, FitReport, FitState, FitWorkspace, Fitter, Method};

#[path = "../benches/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let method = match args.get(1).map(String::as_str) {
        Some("NonNegative") => Method::NonNegative,
        _ => Method::Regularised,
    };
    let update_identity = args.get(2).map(String::as_str) != Some("fixed");
    let sweeps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let warm_up: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(0);
    let problem = common::SweepProblem::new();
    let (model, vertices, input) = (&problem.model, &problem.vertices, problem.input());
    let params = FitParams {
        method,
        max_sweeps: 1,
        tol: 0.0,
        update_identity,
        ..Default::default()
    };
    let fitter = Fitter::new(model, vertices, params).unwrap();
    let mut ws = fitter.workspace();
    let mut st = fitter.initial_state();
    fitter.solve_into(&input, &mut ws, &mut st).unwrap();
    for _ in 0..warm_up {
        fitter.solve_into(&input, &mut ws, &mut st).unwrap();
    }
    let t = Instant::now();
    let last = timed_sweeps(&fitter, &input, &mut ws, &mut st, sweeps);
    let el = t.elapsed().as_secs_f64();
    println!(
        "{method:?} update_identity={update_identity}: {sweeps} sweeps, {:.1} us per sweep, last {:?}",
        el / sweeps as f64 * 1e6,
        last
    );
}

/// The measured sweeps (a separate function for callgrind's `--toggle-collect`).
#[inline(never)]
fn timed_sweeps(
    fitter: &Fitter,
    input: &FitInput,
    ws: &mut FitWorkspace,
    st: &mut FitState,
    sweeps: usize,
) -> Option<FitReport> {
    let mut last = None;
    for _ in 0..sweeps {
        last = Some(fitter.solve_into(input, ws, st).unwrap());
    }
    last
}
