#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Criterion benches: HOSVD build at the thesis' database size (56 identities x 7
//! expressions x 5090 vertices, synthetic) and one fitting sweep with 500 points.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use facecap_tensor::fit::{FitParams, Fitter, Method};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;

mod common;

fn hosvd(c: &mut Criterion) {
    let d = synth::database(5090, 56, 7, 1).unwrap();
    let mut g = c.benchmark_group("tensor_hosvd");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.bench_function("build_56x7x5090", |b| {
        b.iter(|| TensorModel::build(&d, &HosvdParams::default()).unwrap())
    });
    g.finish();
}

fn fit_sweep(c: &mut Criterion) {
    let problem = common::SweepProblem::new();
    let (model, vertices, input) = (&problem.model, &problem.vertices, problem.input());
    let mut g = c.benchmark_group("tensor_fit_sweep_500pts");
    g.sample_size(30).measurement_time(Duration::from_secs(4));
    // Full sweep (pose + expression + identity), and the per-frame video case
    // (identity fixed: pose + expression), as `tensor fit VIDEO` runs it.
    for (method, update_identity, name) in [
        (Method::Regularised, true, "Regularised"),
        (Method::NonNegative, true, "NonNegative"),
        (Method::Regularised, false, "Regularised_identity_fixed"),
        (Method::NonNegative, false, "NonNegative_identity_fixed"),
    ] {
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
        g.bench_with_input(BenchmarkId::from_parameter(name), &method, |b, _| {
            b.iter(|| fitter.solve_into(&input, &mut ws, &mut st).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, hosvd, fit_sweep);
criterion_main!(benches);
