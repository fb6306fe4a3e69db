#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Times the parts of the HOSVD build at the thesis size (56 x 7 x 5090 vertices):
//! the symmetric eigensolver on the Gram matrices (nalgebra `SymmetricEigen`) and the
//! whole build, for `docs/tensor.md`'s backend note.
//!
//! `cargo run --release -p facecap-tensor --example backend`

use std::time::Instant;

use facecap_tensor::model::{gram_eigh, HosvdParams, TensorModel};
use facecap_tensor::synth;
use ndarray::Array2;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let d = synth::database(5090, 56, 7, 1).unwrap();
    for n in [56usize, 7] {
        let a = Array2::from_shape_fn((n, 4 * n), |(r, c)| {
            ((r * 31 + c * 17) % 23) as f64 - 11.0 + (r == c % n) as u8 as f64
        });
        let g = a.dot(&a.t());
        let mut t = Vec::new();
        for _ in 0..200 {
            let s = Instant::now();
            let _ = gram_eigh(g.view()).unwrap();
            t.push(s.elapsed().as_secs_f64());
        }
        println!("nalgebra SymmetricEigen {n}x{n}: median {:.1} us", median(t) * 1e6);
    }
    let mut t = Vec::new();
    for _ in 0..7 {
        let s = Instant::now();
        let _ = TensorModel::build(&d, &HosvdParams::default()).unwrap();
        t.push(s.elapsed().as_secs_f64());
    }
    println!(
        "TensorModel::build 56x7x5090 (3V = 15270): median {:.1} ms of 7",
        median(t) * 1e3
    );
}
