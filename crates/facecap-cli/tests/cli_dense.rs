//! The dense solve (`--landmarks mesh --mesh-points all`) on a short shared clip with the
//! ICT-FaceKit rig: summary.json reports the dense points and the frames solved with them,
//! and the weights and poses are finite. Reads the clip, the rig and the face mesh models
//! from the shared data and the model cache (`SKIP:` when absent).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn data() -> Option<PathBuf> {
    let p = std::env::var_os("FACECAP_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let ok = p.join("videos/liveportrait_d18.mp4").is_file()
        && p.join("models3d/ict_facekit/ict_face_arkit53.glb").is_file()
        && ["face_detector.tflite", "face_landmarks_detector.tflite"]
            .iter()
            .all(|m| facecap_core::paths::model_file(m).is_some());
    ok.then_some(p)
}

/// Rows of a frame CSV after the header: (success, values from column `first`).
fn rows(path: &Path, first: usize) -> Vec<(bool, Vec<f64>)> {
    let text = std::fs::read_to_string(path).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let success = header.iter().position(|h| *h == "success").unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            (
                v[success].trim() == "1",
                v[first..]
                    .iter()
                    .map(|x| x.trim().parse::<f64>().unwrap_or(f64::NAN))
                    .collect(),
            )
        })
        .collect()
}

#[test]
fn dense_mesh_solve_with_the_ict_rig() {
    let Some(data) = data() else {
        facecap_core::paths::skip_missing_data(
            "dense_mesh_solve: the clip, the ICT rig or the face mesh models absent",
        );
        return;
    };
    let ict = data.join("models3d/ict_facekit");
    let dir = tempfile::tempdir().unwrap();
    let run = |points: &str, out: &Path| {
        let st = Command::new(env!("CARGO_BIN_EXE_facecap"))
            .args([
                "capture",
                "--quiet",
                "--no-preview",
                "--landmarks",
                "mesh",
                "--mesh-points",
                points,
            ])
            .arg("--rig")
            .arg(ict.join("ict_face_arkit53.glb"))
            .arg("--landmark-map")
            .arg(ict.join("ict_landmarks68.json"))
            .arg("--out")
            .arg(out)
            .arg(data.join("videos/liveportrait_d18.mp4"))
            .output()
            .unwrap();
        assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("liveportrait_d18/summary.json")).unwrap()).unwrap();
        s
    };
    let out = dir.path().join("all");
    let s = run("all", &out);
    let sp = &s["solve_points"];
    eprintln!("solve_points: {sp}");
    assert_eq!(sp["landmarks"], 68);
    let dense = sp["dense"].as_u64().unwrap();
    assert!(dense >= 300, "{dense} dense points");
    let success = s["success_frames"].as_u64().unwrap();
    assert!(success > 150, "{success} frames solved");
    assert_eq!(sp["dense_frames"].as_u64().unwrap(), success);
    let w = rows(&out.join("liveportrait_d18/weights.csv"), 4);
    let p = rows(&out.join("liveportrait_d18/pose.csv"), 4);
    for (i, ((ok, v), (pok, pv))) in w.iter().zip(&p).enumerate() {
        if *ok {
            assert!(
                v.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x)),
                "frame {i}: {v:?}"
            );
        }
        if *pok {
            assert!(pv.iter().all(|x| x.is_finite()), "frame {i}: pose {pv:?}");
        }
    }
    // landmarks.csv keeps the 68 points
    let header = std::fs::read_to_string(out.join("liveportrait_d18/landmarks.csv")).unwrap();
    let cols = header.lines().next().unwrap().split(',').count();
    assert!(cols < 4 + 3 * 68 + 10, "{cols} columns in landmarks.csv");
    // --mesh-points 68: no dense points
    let s68 = run("68", &dir.path().join("p68"));
    assert_eq!(s68["solve_points"]["dense"], 0);
    assert_eq!(s68["solve_points"]["dense_frames"], 0);
}
