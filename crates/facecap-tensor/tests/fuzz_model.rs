#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Property-based fuzzing of the tensor model file: every mutated file loads or is a
//! format error, never a panic or an abort (counts are checked against the bytes present
//! before anything is reserved). Inputs tried: the case count below.

#[path = "../../facecap-io/tests/fuzz_common/mod.rs"]
mod fuzz_common;

use facecap_tensor::model::{HosvdParams, TensorModel};
use facecap_tensor::synth;
use fuzz_common::{config, mutated};
use proptest::prelude::*;

/// Inputs tried.
const CASES: u32 = 2000;

fn seed() -> Vec<u8> {
    let d = synth::database(12, 3, 2, 5).unwrap();
    TensorModel::build(&d, &HosvdParams::default())
        .unwrap()
        .0
        .to_bytes(true)
}

proptest! {
    #![proptest_config(config(CASES))]
    #[test]
    fn fuzz_tensor_model(b in mutated(seed())) {
        let _ = TensorModel::from_bytes(&b);
    }
}
