#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Model plausibility: a damaged model (one flipped exponent bit makes a value thousands
//! of times too large) is rejected when loaded, whether or not setup knows its checksum,
//! and dlib's own models sit well inside the bounds.

mod ert_common;

use facecap_landmarks::ert::{ErtModel, ShapePredictor};
use facecap_landmarks::ert::{MAX_DELTA_ABS, MAX_LEAF_ABS, MEAN_SHAPE_RANGE};

fn rejected(m: &ErtModel, what: &str) {
    let e = m.validate().expect_err(what).to_string();
    assert!(e.contains("implausible"), "{what}: {e}");
    // Also through the dlib serialisation, as a file would be read.
    assert!(ShapePredictor::from_bytes(&m.to_dlib_bytes()).is_err(), "{what}");
}

#[test]
fn damaged_values_are_rejected() {
    let good = ert_common::synthetic_model(3, 68, 2, 3, 3, 20);
    good.validate().unwrap();
    let mut m = good.clone();
    m.initial_shape[5] *= 65536.0; // a flipped exponent bit
    rejected(&m, "mean shape value x 2^16");
    let mut m = good.clone();
    let v = m.initial_shape[0];
    m.initial_shape.iter_mut().for_each(|x| *x = v);
    rejected(&m, "68 identical mean-shape points");
    let mut m = good.clone();
    m.forests[1][2].leaf_values[3][7] = 4.0;
    rejected(&m, "leaf value 4");
    let mut m = good.clone();
    m.deltas[0][4] = [0.1, -30.0];
    rejected(&m, "feature offset -30");
}

#[test]
fn dlib_models_are_well_inside_the_bounds() {
    for name in [facecap_core::paths::DLIB_68_MODEL, facecap_core::paths::DLIB_5_MODEL] {
        let Some(p) = facecap_core::paths::model_file_or_skip("dlib_models_are_well_inside_the_bounds", name) else {
            return;
        };
        let m = ErtModel::from_file(&p).unwrap();
        let (lo, hi) = m
            .initial_shape
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        let leaf = m
            .forests
            .iter()
            .flatten()
            .flat_map(|t| t.leaf_values.iter().flatten())
            .fold(0.0f32, |a, &x| a.max(x.abs()));
        let delta = m
            .deltas
            .iter()
            .flatten()
            .fold(0.0f32, |a, d| a.max(d[0].abs()).max(d[1].abs()));
        eprintln!("{name}: mean shape in [{lo:.3}, {hi:.3}], max |leaf| {leaf:.3}, max |offset| {delta:.3}");
        // Measured (68 / 5 points): mean shape in [0.029, 1.070] / [0.227, 0.776], |leaf| <=
        // 0.061 / 0.030, |offset| <= 0.187 / 0.501: every bound is at least 3x away.
        assert!(
            lo > MEAN_SHAPE_RANGE.0 / 3.0 && hi < MEAN_SHAPE_RANGE.1 / 1.8,
            "{lo} {hi}"
        );
        assert!(leaf < MAX_LEAF_ABS / 3.0, "{leaf}");
        assert!(delta < MAX_DELTA_ABS / 3.0, "{delta}");
    }
}
