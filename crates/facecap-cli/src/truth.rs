//! Error of a capture against ground truth written by `facecap synth`
//! (`<video-stem>.truth.csv` beside the video).
//!
//! Measures: mean landmark error in pixels and normalised by the true inter-ocular
//! distance (outer eye corners); weight RMSE over the shapes both files name; head
//! rotation error in degrees, comparing rotations relative to the first solved frame
//! (the truth's `rel_R*` columns are relative to frame 0 in model axes).
//!
//! A frame whose tracked landmarks lie more than [`OTHER_FACE_NME`] inter-ocular distances
//! from the true ones shows another face (a photo with several people, `synth` having made
//! one of them move): it is left out of every measure and counted as
//! `frames_other_face`, so the errors describe the synthetic face or nothing.

use std::path::Path;

use facecap_core::camera::ModelToCamera;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::Rotation3;
use serde_json::json;

/// What the capture estimated for one frame.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// Tracked landmarks.
    pub landmarks: Option<Landmarks68>,
    /// Solved weights (rig order).
    pub weights: Option<Vec<f64>>,
    /// Solved pose.
    pub pose: Option<ModelToCamera>,
}

/// Mean landmark distance, in true inter-ocular distances, beyond which the tracked face
/// is taken for another face than the synthetic one. A tracker on the right face errs by
/// 0.01-0.05 (the synthetic clip: 0.036); the eyes of a neighbouring face lie at least
/// about two inter-ocular distances away.
pub const OTHER_FACE_NME: f64 = 0.5;

/// The truth file for `video`, if any.
pub fn truth_path(video: &Path) -> Option<std::path::PathBuf> {
    let stem = video.file_stem()?.to_string_lossy().into_owned();
    let p = video.with_file_name(format!("{stem}.truth.csv"));
    p.is_file().then_some(p)
}

/// Reads the truth file beside `video` (if any) without evaluating: a capture checks it
/// before tracking, so a malformed file is known before the work is done.
///
/// # Errors
/// The file cannot be read or is not a per-frame CSV with landmark columns.
pub fn validate(video: &Path) -> anyhow::Result<()> {
    if let Some(path) = truth_path(video) {
        let table = facecap_io::csv::read_frame_csv(&path)?;
        facecap_io::csv::landmarks_from_table(&table)?;
    }
    Ok(())
}

/// Errors against the truth file beside `video`; `None` when there is none.
pub fn evaluate(video: &Path, names: &[String], est: &[Estimate]) -> anyhow::Result<Option<serde_json::Value>> {
    let Some(path) = truth_path(video) else { return Ok(None) };
    let table = facecap_io::csv::read_frame_csv(&path)?;
    let truth_lms = facecap_io::csv::landmarks_from_table(&table)?;
    let (mut lm_sum, mut nme_sum, mut lm_n) = (0.0, 0.0, 0usize);
    // per estimated frame: whether it shows the synthetic face (or has no landmarks to say)
    let mut same_face = vec![true; est.len()];
    for ((t, e), same) in truth_lms.iter().zip(est).zip(&mut same_face) {
        if let (Some(tl), Some(el)) = (&t.landmarks, &e.landmarks) {
            let mean: f64 = (0..NUM_LANDMARKS)
                .map(|i| (tl.points[i] - el.points[i]).norm())
                .sum::<f64>()
                / NUM_LANDMARKS as f64;
            let nme = mean / tl.interocular_distance();
            // NaN (a degenerate inter-ocular distance) counts as another face too
            if nme.is_nan() || nme > OTHER_FACE_NME {
                *same = false;
                continue;
            }
            lm_sum += mean;
            nme_sum += nme;
            lm_n += 1;
        }
    }
    let other_face = same_face.iter().filter(|s| !**s).count();
    let (mut w_sq, mut w_n) = (0.0, 0usize);
    let mut per_shape = serde_json::Map::new();
    for (k, name) in names.iter().enumerate() {
        let Some(col) = table.column(name) else { continue };
        let (mut s, mut n) = (0.0, 0usize);
        for ((truth, e), _) in col.iter().zip(est).zip(&same_face).filter(|(_, same)| **same) {
            if let Some(w) = &e.weights {
                s += (w[k] - truth).powi(2);
                n += 1;
            }
        }
        if n > 0 {
            per_shape.insert(name.clone(), json!((s / n as f64).sqrt()));
            w_sq += s;
            w_n += n;
        }
    }
    let mut rot_errs = Vec::new();
    if let (Some(rx), Some(ry), Some(rz)) = (table.column("rel_Rx"), table.column("rel_Ry"), table.column("rel_Rz")) {
        let first = est
            .iter()
            .enumerate()
            .filter(|(i, _)| same_face[*i])
            .find_map(|(i, e)| e.pose.map(|p| (i, p)));
        if let Some((f0, p0)) = first.filter(|(f0, _)| *f0 < rx.len().min(ry.len()).min(rz.len())) {
            let r_t0 = Rotation3::from_euler_angles(rx[f0], ry[f0], rz[f0]);
            let r_e0 = p0.0.rotation.to_rotation_matrix();
            for (i, e) in est.iter().enumerate().skip(f0).filter(|(i, _)| same_face[*i]) {
                let (Some(p), Some(&x), Some(&y), Some(&z)) = (e.pose, rx.get(i), ry.get(i), rz.get(i)) else {
                    continue;
                };
                // Model-frame rotation relative to the first solved frame.
                let rel_e = r_e0.inverse() * p.0.rotation.to_rotation_matrix();
                let rel_t = r_t0.inverse() * Rotation3::from_euler_angles(x, y, z);
                // through a quaternion: `Rotation3::angle` takes acos of a trace that
                // rounding can push past 1 (NaN for a zero error)
                let err = nalgebra::UnitQuaternion::from_rotation_matrix(&(rel_e.inverse() * rel_t));
                rot_errs.push(err.angle().to_degrees());
            }
        }
    }
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    Ok(Some(json!({
        "truth_file": path.display().to_string(),
        "frames_compared": lm_n,
        "frames_other_face": other_face,
        "landmark_error_px": if lm_n > 0 { lm_sum / lm_n as f64 } else { f64::NAN },
        "landmark_nme_interocular": if lm_n > 0 { nme_sum / lm_n as f64 } else { f64::NAN },
        "weight_rmse": if w_n > 0 { (w_sq / w_n as f64).sqrt() } else { f64::NAN },
        "weight_rmse_per_shape": per_shape,
        "rotation_error_deg_mean": mean(&rot_errs),
        "rotation_error_deg_max": rot_errs.iter().copied().fold(f64::NAN, f64::max),
    })))
}

/// The truth comparison ([`evaluate`]'s value) as rows of the report's summary table:
/// figures rounded, `-` where a figure is `null` (no frame of the truth's face), the five
/// shapes with the largest error by name.
pub fn report_rows(truth: &serde_json::Value) -> Vec<(String, String)> {
    let num = |k: &str| truth[k].as_f64().filter(|v| v.is_finite());
    let fmt = |v: Option<f64>, digits: usize| v.map_or_else(|| "-".to_string(), |v| format!("{v:.digits$}"));
    let mut rows = vec![
        (
            "truth: frames compared".to_string(),
            format!(
                "{} ({} of another face left out)",
                truth["frames_compared"].as_u64().unwrap_or(0),
                truth["frames_other_face"].as_u64().unwrap_or(0)
            ),
        ),
        ("truth: weight RMSE".to_string(), fmt(num("weight_rmse"), 4)),
        (
            "truth: landmark error".to_string(),
            format!(
                "{} px mean, NME {} (inter-ocular)",
                fmt(num("landmark_error_px"), 2),
                fmt(num("landmark_nme_interocular"), 4)
            ),
        ),
        (
            "truth: head rotation error".to_string(),
            format!(
                "{} deg mean, {} deg max",
                fmt(num("rotation_error_deg_mean"), 2),
                fmt(num("rotation_error_deg_max"), 2)
            ),
        ),
    ];
    if let Some(per) = truth["weight_rmse_per_shape"].as_object() {
        let mut worst: Vec<(&String, f64)> = per
            .iter()
            .filter_map(|(k, v)| v.as_f64().filter(|v| v.is_finite()).map(|v| (k, v)))
            .collect();
        worst.sort_by(|a, b| b.1.total_cmp(&a.1));
        let text: Vec<String> = worst.iter().take(5).map(|(k, v)| format!("{k} {v:.3}")).collect();
        if !text.is_empty() {
            rows.push(("truth: largest weight errors (RMSE)".to_string(), text.join(", ")));
        }
    }
    if let Some(f) = truth["truth_file"].as_str() {
        rows.push(("truth file".to_string(), f.to_string()));
    }
    rows
}

/// The mutation strategy the parser fuzz tests share.
#[cfg(test)]
#[path = "../../facecap-io/tests/fuzz_common/mod.rs"]
mod fuzz_common;

/// Property-based fuzzing of the truth CSV as a capture reads it ([`validate`] first,
/// then [`evaluate`]): every mutated file is accepted or an error, never a panic, and an
/// accepted file never compares more frames than were estimated. Inputs tried:
/// `fuzz::CASES`.
#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic)]
mod fuzz {
    use super::fuzz_common::{config, mutated};
    use super::*;
    use proptest::prelude::*;

    /// Inputs tried.
    pub const CASES: u32 = 1500;

    /// Three frames in the layout `facecap synth` writes (landmarks, `rel_R*`, weights).
    fn seed() -> Vec<u8> {
        let mut cols: Vec<String> = ["frame", "timestamp", "success", "confidence"]
            .map(String::from)
            .to_vec();
        for a in ["x", "y"] {
            cols.extend((0..NUM_LANDMARKS).map(|i| format!("{a}_{i}")));
        }
        cols.extend(["rel_Rx", "rel_Ry", "rel_Rz", "jawOpen", "mouthSmileLeft"].map(String::from));
        let mut out = cols.join(",");
        out.push('\n');
        for f in 0..3 {
            let mut row = vec![
                f.to_string(),
                format!("{:.6}", f64::from(f) / 25.0),
                "1".into(),
                "1".into(),
            ];
            row.extend(
                (0..2 * NUM_LANDMARKS)
                    .map(|i| format!("{:.4}", 150.0 + (i % NUM_LANDMARKS) as f64 * 3.1 + i as f64 * 0.01)),
            );
            row.extend(["0.01", "-0.02", "0.003", "0.4", "0.1"].map(String::from));
            out.push_str(&row.join(","));
            out.push('\n');
        }
        out.into_bytes()
    }

    /// Estimates about 1.5 px (0.04 inter-ocular distances) from the seed's landmarks.
    fn estimates() -> Vec<Estimate> {
        (0..3)
            .map(|f| Estimate {
                landmarks: Some(Landmarks68::from_fn(|i| {
                    let t = 150.0 + i as f64 * 3.11;
                    (t + 1.0, t + 0.68 - 1.0 + f as f64 * 0.2)
                })),
                weights: Some(vec![0.3, 0.2]),
                pose: Some(ModelToCamera::identity()),
            })
            .collect()
    }

    fn check(dir: &Path, bytes: &[u8]) {
        let video = dir.join("clip.y4m");
        std::fs::write(dir.join("clip.truth.csv"), bytes).unwrap();
        if validate(&video).is_err() {
            return;
        }
        let names = ["jawOpen".to_string(), "mouthSmileLeft".to_string()];
        if let Ok(Some(v)) = evaluate(&video, &names, &estimates()) {
            let n = v["frames_compared"].as_u64().unwrap();
            assert!(n <= 3, "{n} frames compared, 3 estimated");
        }
    }

    #[test]
    fn seed_is_valid() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("clip.truth.csv"), seed()).unwrap();
        let video = dir.path().join("clip.y4m");
        validate(&video).unwrap();
        let names = ["jawOpen".to_string(), "mouthSmileLeft".to_string()];
        let v = evaluate(&video, &names, &estimates()).unwrap().unwrap();
        assert_eq!(v["frames_compared"], 3);
        assert_eq!(v["frames_other_face"], 0);
        assert!(v["landmark_nme_interocular"].as_f64().unwrap() < 0.1);
        assert!(v["weight_rmse"].as_f64().unwrap() > 0.0);
    }

    #[test]
    fn another_face_is_left_out_of_the_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("clip.truth.csv"), seed()).unwrap();
        let video = dir.path().join("clip.y4m");
        let names = ["jawOpen".to_string(), "mouthSmileLeft".to_string()];
        let all_right = evaluate(&video, &names, &estimates()).unwrap().unwrap();
        // frame 1 tracks a face 200 px away, whose weights are nothing like the truth's
        let mut est = estimates();
        est[1].landmarks = est[1]
            .landmarks
            .as_ref()
            .map(|l| Landmarks68::from_fn(|i| (l.points[i].x + 200.0, l.points[i].y)));
        est[1].weights = Some(vec![1.0, 1.0]);
        let v = evaluate(&video, &names, &est).unwrap().unwrap();
        assert_eq!(v["frames_compared"], 2);
        assert_eq!(v["frames_other_face"], 1);
        let rmse = |v: &serde_json::Value| v["weight_rmse"].as_f64().unwrap();
        assert!((rmse(&v) - rmse(&all_right)).abs() < 1e-12, "{v}");
        assert!(v["landmark_error_px"].as_f64().unwrap() < 2.0);
        // every frame another face: nothing is compared, no error is reported as a result
        for e in &mut est {
            e.landmarks = e
                .landmarks
                .as_ref()
                .map(|l| Landmarks68::from_fn(|i| (l.points[i].x + 200.0, l.points[i].y)));
        }
        let v = evaluate(&video, &names, &est).unwrap().unwrap();
        assert_eq!(v["frames_compared"], 0);
        assert_eq!(v["frames_other_face"], 3);
        assert!(v["weight_rmse"].is_null(), "{}", v["weight_rmse"]);
        // the report's rows: no figure made up for nothing compared
        let rows = report_rows(&v);
        let row = |k: &str| rows.iter().find(|r| r.0 == k).map(|r| r.1.clone()).unwrap();
        assert_eq!(row("truth: weight RMSE"), "-");
        assert_eq!(row("truth: frames compared"), "0 (3 of another face left out)");
    }

    #[test]
    fn the_report_shows_the_truth_as_rows() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("clip.truth.csv"), seed()).unwrap();
        let names = ["jawOpen".to_string(), "mouthSmileLeft".to_string()];
        let v = evaluate(&dir.path().join("clip.y4m"), &names, &estimates())
            .unwrap()
            .unwrap();
        let rows = report_rows(&v);
        let row = |k: &str| rows.iter().find(|r| r.0 == k).map(|r| r.1.clone()).unwrap();
        assert_eq!(
            row("truth: weight RMSE"),
            format!("{:.4}", v["weight_rmse"].as_f64().unwrap())
        );
        assert_eq!(row("truth: frames compared"), "3 (0 of another face left out)");
        assert!(row("truth: landmark error").ends_with("(inter-ocular)"));
        let worst = row("truth: largest weight errors (RMSE)");
        assert!(worst.contains("jawOpen") && worst.contains("mouthSmileLeft"), "{worst}");
        assert!(rows.iter().all(|r| !r.1.contains('{')), "{rows:?}");
    }

    proptest! {
        #![proptest_config(config(CASES))]
        #[test]
        fn fuzz_truth_csv(b in mutated(seed())) {
            let dir = tempfile::tempdir().unwrap();
            check(dir.path(), &b);
        }
    }
}
