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

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_tensor::fit::{FitInput, FitParams, Fitter, Method};
use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use nalgebra::{Point3, Vector3};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let method = match args.get(1).map(String::as_str) {
        Some("NonNegative") => Method::NonNegative,
        _ => Method::Regularised,
    };
    let update_identity = args.get(2).map(String::as_str) != Some("fixed");
    let sweeps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let d = synth::database(5090, 56, 7, 2).unwrap();
    let (model, _) = TensorModel::build(&d, &HosvdParams::default()).unwrap();
    let vertices: Vec<u32> = (0..500).map(|k| k * 10).collect();
    let k = Intrinsics::new(900.0, 900.0, 320.0, 240.0).unwrap();
    let pose = ModelToCamera::from_rvec_tvec(Vector3::new(0.1, -0.2, 0.0), Vector3::new(0.0, 0.0, 60.0));
    let f = model.generate(&[1.0 / 56.0; 56], &[1.0 / 7.0; 7]).unwrap();
    let image: Vec<_> = vertices
        .iter()
        .map(|&v| {
            let v = v as usize;
            pose.project(&k, &Point3::new(f[3 * v] + 0.1, f[3 * v + 1], f[3 * v + 2]))
                .unwrap()
        })
        .collect();
    let weights = vec![1.0; 500];
    let input = FitInput {
        image: &image,
        weights: &weights,
        intrinsics: k,
    };
    let params = FitParams {
        method,
        max_sweeps: 1,
        tol: 0.0,
        update_identity,
        ..Default::default()
    };
    let fitter = Fitter::new(&model, &vertices, params).unwrap();
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
