//! The 12 BOBYQA problems of `testdata/solve/bobyqa_dlib_fixture.json`, shared by the
//! BOBYQA examples (`bobyqa_timing`, `bobyqa_quality`).

#[derive(serde::Deserialize)]
pub struct Problem {
    pub obs: Vec<f64>,
}

#[derive(serde::Deserialize)]
pub struct Fixture {
    pub lambda: f64,
    pub neutral: Vec<f64>,
    pub deltas: Vec<Vec<f64>>,
    pub problems: Vec<Problem>,
}

/// Reads the fixture (panics with the reason: examples only).
pub fn load_fixture() -> Fixture {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/solve/bobyqa_dlib_fixture.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}
