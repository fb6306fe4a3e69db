#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Property-based fuzzing of the muscle-set JSON parser: every mutated file parses or is
//! an error, never a panic. Inputs tried: the case count below.

#[path = "../../facecap-io/tests/fuzz_common/mod.rs"]
mod fuzz_common;

use facecap_muscle::set::MuscleSet;
use fuzz_common::{config, mutated};
use proptest::prelude::*;

/// Inputs tried.
const CASES: u32 = 3000;

const SEED: &str = r#"{
  "format": "facecap-muscle-set", "version": 1, "units": "cm",
  "muscles": [
    { "name": "cheek_L", "type": "linear", "origin": [6.1, 1.0, 2.0], "insertion": [2.4, -3.2, 4.9],
      "rs": 5.0, "rf": 7.5, "k": 1.2, "zone": 3.14159, "wrinkle": { "height": 0.05, "count": 3 },
      "vertex_group": "jaw" },
    { "name": "lips", "type": "sphincter", "centre": [0, -3, 5], "upper": [0, -2, 5], "corner": [2, -3, 5],
      "radius": 1.6, "height": 0.4, "k": 0.3 }
  ],
  "vertex_groups": { "jaw": { "indices": [10, 11, 12], "weights": [1.0, 0.5, 0.2] } },
  "jaw": { "pivot": [0.0, -1.0, -6.0], "max_angle": 0.35, "vertex_group": "jaw" }
}"#;

#[test]
fn seed_is_valid() {
    MuscleSet::from_json_str(SEED).unwrap();
}

proptest! {
    #![proptest_config(config(CASES))]
    #[test]
    fn fuzz_muscle_json(b in mutated(SEED.as_bytes().to_vec())) {
        let _ = MuscleSet::from_json_str(&String::from_utf8_lossy(&b));
    }
}
