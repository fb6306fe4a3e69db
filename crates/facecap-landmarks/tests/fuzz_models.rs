#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Property-based fuzzing of the model parsers (dlib `shape_predictor` `.dat`, the ERT
//! binary cache, the HOG detector `.svm`): every mutated file loads or is an error, never
//! a panic or an abort. Inputs tried per target are the case counts below.

mod ert_common;
#[path = "../../facecap-io/tests/fuzz_common/mod.rs"]
mod fuzz_common;

use facecap_landmarks::detect::HogModel;
use facecap_landmarks::ert::{ErtModel, ShapePredictor};
use fuzz_common::{config, mutated};
use proptest::prelude::*;

/// Inputs tried per target.
const DAT_CASES: u32 = 1500;
const CACHE_CASES: u32 = 300;
const SVM_CASES: u32 = 300;

fn dat_seed() -> Vec<u8> {
    ert_common::synthetic_model(5, 8, 2, 3, 2, 10).to_dlib_bytes()
}

proptest! {
    #![proptest_config(config(DAT_CASES))]
    #[test]
    fn fuzz_dlib_dat(b in mutated(dat_seed())) {
        if let Ok(m) = ErtModel::from_bytes(&b) {
            let _ = ShapePredictor::new(&m, Default::default());
        }
    }
}

#[test]
fn fuzz_ert_cache() {
    // One model file for all cases, so the cache's stamp (size, modification time)
    // matches and the mutated cache body is what gets parsed.
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.dat");
    std::fs::write(&model, dat_seed()).unwrap();
    let cache = dir.path().join("m.dat.facecap-cache");
    ShapePredictor::from_file_cached(&model).unwrap();
    let seed = std::fs::read(&cache).unwrap();
    let reference = ShapePredictor::from_file(&model).unwrap();
    let mut runner = proptest::test_runner::TestRunner::new(config(CACHE_CASES));
    runner
        .run(&mutated(seed), |b| {
            std::fs::write(&cache, &b).unwrap();
            // A damaged cache is rebuilt from the model: the same predictor either way.
            let (sp, _) = ShapePredictor::from_file_cached(&model).unwrap();
            prop_assert_eq!(sp.num_parts(), reference.num_parts());
            prop_assert_eq!(sp.num_trees(), reference.num_trees());
            Ok(())
        })
        .unwrap();
}

#[test]
fn fuzz_hog_svm() {
    let Some(path) =
        facecap_core::paths::model_file_or_skip("fuzz_hog_svm", facecap_landmarks::detect::DLIB_FRONTAL_MODEL)
    else {
        return;
    };
    let seed = std::fs::read(&path).unwrap();
    HogModel::from_bytes(&seed, &path).unwrap();
    let mut runner = proptest::test_runner::TestRunner::new(config(SVM_CASES));
    runner
        .run(&mutated(seed), |b| {
            let _ = HogModel::from_bytes(&b, &path);
            Ok(())
        })
        .unwrap();
}
