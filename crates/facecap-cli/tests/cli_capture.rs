#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! End-to-end: `facecap synth` makes a ground-truth clip, `facecap capture` runs on it and
//! on a corrupt file; the good one finishes, the bad one is reported, the exit code says
//! not all succeeded, and a rerun skips the finished capture.

use std::process::Command;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

#[test]
fn help_lists_subcommands() {
    let out = facecap().arg("--help").output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    for cmd in [
        "info",
        "landmarks",
        "solve",
        "muscle",
        "tensor",
        "transfer",
        "capture",
        "synth",
    ] {
        assert!(text.contains(cmd), "--help lacks {cmd}: {text}");
    }
}

#[test]
fn synth_then_capture_with_a_bad_video() {
    let photo = ["data/astronaut.png", "astronaut.png"]
        .iter()
        .filter_map(|r| facecap_core_cache().map(|c| c.join(r)))
        .find(|p| p.is_file());
    let (Some(photo), true) = (photo, model_present()) else {
        facecap_core::paths::skip_missing_data(
            "synth_then_capture: astronaut.png or the dlib models not in the cache (run scripts/setup.sh)",
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let synth_dir = dir.path().join("synth");
    let st = facecap()
        .args(["synth", "--frames", "12", "--out"])
        .arg(&synth_dir)
        .arg("--photo")
        .arg(&photo)
        .status()
        .unwrap();
    assert!(st.success());
    let bad = dir.path().join("broken.mp4");
    std::fs::write(&bad, b"this is not a video at all").unwrap();
    let out_dir = dir.path().join("cap");
    let out = facecap()
        .args(["capture", "--quiet", "--json", "--solver", "exact3d", "--out"])
        .arg(&out_dir)
        .arg(synth_dir.join("synth.y4m"))
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success(), "a failed video must make the exit code non-zero");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let videos = report["videos"].as_array().unwrap();
    assert_eq!(videos[0]["status"], "done");
    assert_eq!(videos[1]["status"], "failed");
    let done = out_dir.join("synth");
    for f in [
        "landmarks.csv",
        "pose.csv",
        "weights.csv",
        "livelink.csv",
        "animation.glb",
        "report.html",
        "summary.json",
    ] {
        assert!(done.join(f).is_file(), "missing {f}");
    }
    assert!(!out_dir.join("broken").join("summary.json").exists());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(done.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["frames"], 12);
    let truth = &summary["truth"];
    assert!(truth["landmark_error_px"].as_f64().unwrap() < 10.0, "{truth}");
    // No temporary files left behind.
    for e in std::fs::read_dir(&done).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.contains(".tmp-"), "left-over temporary file {name}");
    }
    // Rerun: skipped without --force.
    let out = facecap()
        .args(["capture", "--quiet", "--json", "--out"])
        .arg(&out_dir)
        .arg(synth_dir.join("synth.y4m"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["videos"][0]["status"], "skipped");

    // Real expressions (a 90-frame synthetic clip: smiles, blinks, brow raise, jaw) with
    // absolute bounds on the default capture, and the default against no calibration.
    let long = dir.path().join("synth90");
    let st = facecap()
        .args(["synth", "--frames", "90", "--out"])
        .arg(&long)
        .arg("--photo")
        .arg(&photo)
        .status()
        .unwrap();
    assert!(st.success());
    let capture = |name: &str, extra: &[&str]| -> serde_json::Value {
        let out = facecap()
            .args(["capture", "--quiet", "--out"])
            .arg(dir.path().join(name))
            .args(extra)
            .arg(long.join("synth.y4m"))
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(name).join("synth").join("summary.json")).unwrap(),
        )
        .unwrap()
    };
    // The default front end (`mesh`) and `dlib68`, each with its own measured bounds.
    // The synthetic clip moves the photo's dlib-defined 68 points, so `dlib68` reads its
    // truth more directly: measured 2026-12-06, weight RMSE 0.0815 (dlib68) and 0.0956
    // (mesh), eyeBlink 0.109 / 0.131 and 0.135 / 0.156, jawOpen 0.033 and 0.099.
    for (front, overall, blink) in [("mesh", 0.12, 0.18), ("dlib68", 0.10, 0.14)] {
        let cal = capture(&format!("cal_{front}"), &["--landmarks", front]);
        let none = capture(&format!("none_{front}"), &["--landmarks", front, "--neutral", "none"]);
        assert_eq!(cal["settings"]["landmarks"], front, "{}", cal["settings"]);
        assert!(
            cal["neutral_calibration"]["frames_used"].as_u64().unwrap() >= 60,
            "{front}: {}",
            cal["neutral_calibration"]
        );
        let (after, before) = (
            cal["truth"]["weight_rmse"].as_f64().unwrap(),
            none["truth"]["weight_rmse"].as_f64().unwrap(),
        );
        assert!(after < overall, "{front}: weight RMSE {after} (bound {overall})");
        assert!(
            after < 0.5 * before,
            "{front}: weight RMSE {after} with calibration vs {before} without"
        );
        let per = &cal["truth"]["weight_rmse_per_shape"];
        for (shape, bound) in [("jawOpen", 0.15), ("eyeBlinkLeft", blink), ("eyeBlinkRight", blink)] {
            let v = per[shape].as_f64().unwrap();
            assert!(v < bound, "{front}: {shape} RMSE {v} (bound {bound})");
        }
    }
    for bad in ["sometimes", "1.5"] {
        let out = facecap()
            .args(["capture", "--quiet", "--neutral", bad, "--out"])
            .arg(dir.path().join("bad"))
            .arg(synth_dir.join("synth.y4m"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert!(String::from_utf8_lossy(&out.stderr).contains("--neutral"), "{bad}");
    }
}

fn facecap_core_cache() -> Option<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("FACECAP_CACHE") {
        return Some(p.into());
    }
    std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".cache").join("facecap"))
}

fn model_present() -> bool {
    let Some(c) = facecap_core_cache() else { return false };
    let models = std::env::var_os("FACECAP_MODELS").map_or(c.join("models"), std::path::PathBuf::from);
    models.join("shape_predictor_68_face_landmarks.dat").is_file()
        && models.join("dlib_frontal_face_detector.svm").is_file()
}
