#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Runs the 500-point fitting sweep of the criterion bench `tensor_fit_sweep_500pts` in a
//! loop, for profilers (`perf record`, `valgrind --tool=callgrind`): same synthetic model,
//! points, pose and warm start as the bench.
//!
//! `cargo run -j 1 --release -p facecap-tensor --example sweep_profile -- [Regularised|NonNegative] [full|fixed] [sweeps]`
//!
//! Callgrind instruction count of the sweeps only (the model build excluded):
//! `valgrind --tool=callgrind --toggle-collect='*Fitter*solve_into*' target/release/examples/sweep_profile Regularised full 20`

use std::time::Instant;

use facecap_tensor::fit::{FitParams, Fitter, Method};

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
    let t = Instant::now();
    let mut last = None;
    for _ in 0..sweeps {
        last = Some(fitter.solve_into(&input, &mut ws, &mut st).unwrap());
    }
    let el = t.elapsed().as_secs_f64();
    println!(
        "{method:?} update_identity={update_identity}: {sweeps} sweeps, {:.1} us per sweep, last {:?}",
        el / sweeps as f64 * 1e6,
        last
    );
}
