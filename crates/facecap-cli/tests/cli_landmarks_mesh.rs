#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! `facecap landmarks --landmarks mesh` end to end against MediaPipe FaceLandmarker's own
//! 478 landmarks on frames of the shared clips (fixture `testdata/mesh/landmarker_mediapipe.json`,
//! made by `testdata/mesh/make_landmarker_fixture.py`): the images mode against its IMAGE
//! mode, the video mode with `--smooth` against its VIDEO mode. The points are read back
//! from the 478-point `landmarks.csv` the command writes.

use std::path::{Path, PathBuf};
use std::process::Command;

use facecap_io::csv::{read_mesh_csv, MeshRecord, MESH_POINTS};

/// Goals per frame on the 480-px clips (scaled with the width for other sizes): mean and
/// largest distance over the 478 points, and each iris centre.
const MEAN_PX: f64 = 0.5;
const MAX_PX: f64 = 2.0;
const IRIS_PX: f64 = 0.5;
/// The iris centres (subject's right, left).
const IRIS_CENTERS: [usize; 2] = [468, 473];

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn fixture() -> serde_json::Value {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/mesh/landmarker_mediapipe.json");
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn models_present(test: &str) -> bool {
    [facecap_mesh::FACE_DETECTOR_MODEL, facecap_mesh::FACE_LANDMARKS_MODEL]
        .iter()
        .all(|m| facecap_core::paths::model_file_or_skip(test, m).is_some())
}

/// The first `n` frames of `clip` as rgb24, decoded by the `ffmpeg` on PATH with the
/// fixture script's command; `None` (with a SKIP line) without ffmpeg.
fn rgb_frames(test: &str, clip: &Path, n: u64) -> Option<Vec<image::RgbImage>> {
    let info = facecap_io::video::open_source(clip, &Default::default())
        .unwrap()
        .info()
        .clone();
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-hide_banner", "-loglevel", "error", "-i"])
        .arg(clip)
        .args(["-map", "0:V:0", "-frames:v", &n.to_string()])
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
        .output();
    match out {
        Ok(o) if o.status.success() => {
            let size = (info.width * info.height * 3) as usize;
            Some(
                o.stdout
                    .chunks_exact(size)
                    .map(|c| image::RgbImage::from_raw(info.width, info.height, c.to_vec()).unwrap())
                    .collect(),
            )
        }
        _ => {
            facecap_core::paths::skip(&format!("{test}: ffmpeg not runnable"));
            None
        }
    }
}

/// Distances of our points to MediaPipe's: (mean, max, iris centres), in px.
fn distances(ours: &[[f32; 3]], want: &[serde_json::Value]) -> (f64, f64, [f64; 2]) {
    assert_eq!(ours.len(), MESH_POINTS);
    assert_eq!(want.len(), MESH_POINTS);
    let d: Vec<f64> = ours
        .iter()
        .zip(want)
        .map(|(p, w)| {
            let (wx, wy) = (w[0].as_f64().unwrap(), w[1].as_f64().unwrap());
            (f64::from(p[0]) - wx).hypot(f64::from(p[1]) - wy)
        })
        .collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let max = d.iter().copied().fold(0.0, f64::max);
    (mean, max, IRIS_CENTERS.map(|i| d[i]))
}

fn check(what: &str, rec: &MeshRecord, want: &[serde_json::Value], width: f64) {
    let pts = rec
        .points
        .as_ref()
        .unwrap_or_else(|| panic!("{what}: no face in landmarks.csv"));
    let (mean, max, iris) = distances(pts, want);
    eprintln!(
        "{what}: mean {mean:.3} px, max {max:.3} px, iris {:.3} / {:.3} px",
        iris[0], iris[1]
    );
    let k = width / 480.0;
    assert!(mean <= MEAN_PX * k, "{what}: mean {mean} px");
    assert!(max <= MAX_PX * k, "{what}: max {max} px");
    assert!(iris.iter().all(|&e| e <= IRIS_PX * k), "{what}: iris {iris:?} px");
    assert!(
        rec.confidence > 0.5 && rec.confidence <= 1.0,
        "{what}: presence {}",
        rec.confidence
    );
    // z is written (relative depth, same scale as x): finite and not all equal
    let z: Vec<f32> = pts.iter().map(|p| p[2]).collect();
    assert!(z.iter().all(|v| v.is_finite()));
    assert!(
        z.iter().copied().fold(f32::NEG_INFINITY, f32::max) - z.iter().copied().fold(f32::INFINITY, f32::min) > 1.0
    );
}

/// Images mode: every fixture frame of the IMAGE-mode part written as a PNG (lossless, so
/// the pixels are the fixture's), all given to one `facecap landmarks --landmarks mesh`
/// call; row `k` of `landmarks.csv` is image `k`.
#[test]
fn mesh_landmarks_csv_of_images_matches_mediapipe_image_mode() {
    let test = "mesh_landmarks_csv_of_images_matches_mediapipe_image_mode";
    if !models_present(test) {
        return;
    }
    let fx = fixture();
    let dir = tempfile::tempdir().unwrap();
    let mut images: Vec<(PathBuf, &serde_json::Value)> = Vec::new();
    for (k, f) in fx["frames"].as_array().unwrap().iter().enumerate() {
        let clip = f["clip"].as_str().unwrap();
        let Some(path) = facecap_core::paths::shared_data_file(test, clip) else {
            return;
        };
        let index = f["frame"].as_u64().unwrap();
        let Some(frames) = rgb_frames(test, &path, index + 1) else {
            return;
        };
        let png = dir.path().join(format!("frame_{k:02}.png"));
        frames[index as usize].save(&png).unwrap();
        images.push((png, f));
    }
    let out = dir.path().join("out");
    let st = facecap()
        .args(["landmarks", "--landmarks", "mesh", "--out"])
        .arg(&out)
        .args(images.iter().map(|(p, _)| p))
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let rows = read_mesh_csv(out.join("landmarks.csv")).unwrap();
    assert_eq!(rows.len(), images.len());
    for (k, (rec, (_, f))) in rows.iter().zip(&images).enumerate() {
        assert_eq!(rec.frame, k as u64);
        let what = format!("{}#{}", f["clip"].as_str().unwrap(), f["frame"]);
        match f["points"].as_array() {
            Some(want) => check(&what, rec, want, f["width"].as_f64().unwrap()),
            None => assert!(!rec.success, "{what}: MediaPipe found no face, we did"),
        }
    }
    // the .pts of each face holds the same 478 points (x, y)
    let pts = facecap_io::formats::pts::read_pts_points(out.join("frame_00_0.pts")).unwrap();
    assert_eq!(pts.len(), MESH_POINTS);
    let first = rows[0].points.as_ref().unwrap();
    for (a, b) in pts.iter().zip(first) {
        assert!((a.x - f64::from(b[0])).abs() < 1e-4 && (a.y - f64::from(b[1])).abs() < 1e-4);
    }
    let summary = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    assert!(
        summary.lines().nth(1).unwrap().contains(",478,frame_00_0.pts,"),
        "{summary}"
    );
}

/// Video mode with `--smooth` (tracking from the previous landmarks, one-euro smoothing)
/// against FaceLandmarker's VIDEO mode: the fixture's first 60 frames of each clip as a
/// folder of PNGs (the fixture's own rgb24 pixels; a folder runs at 30 fps, 33.3 ms
/// apart, the fixture's timestamps are 33 ms apart), compared on the stored frames.
#[test]
fn mesh_landmarks_csv_of_a_sequence_matches_mediapipe_video_mode() {
    let test = "mesh_landmarks_csv_of_a_sequence_matches_mediapipe_video_mode";
    if !models_present(test) {
        return;
    }
    let fx = fixture();
    for v in fx["videos"].as_array().unwrap() {
        let name = v["clip"].as_str().unwrap();
        let Some(clip) = facecap_core::paths::shared_data_file(test, name) else {
            return;
        };
        let n = v["frames"].as_u64().unwrap();
        let Some(frames) = rgb_frames(test, &clip, n) else {
            return;
        };
        let dir = tempfile::tempdir().unwrap();
        let seq = dir.path().join("frames");
        std::fs::create_dir(&seq).unwrap();
        for (i, f) in frames.iter().enumerate() {
            f.save(seq.join(format!("{i:04}.png"))).unwrap();
        }
        let out = dir.path().join("out");
        let st = facecap()
            .args(["landmarks", "--landmarks", "mesh", "--smooth", "--quiet", "--out"])
            .arg(&out)
            .arg(&seq)
            .output()
            .unwrap();
        assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
        let rows = read_mesh_csv(out.join("landmarks.csv")).unwrap();
        assert_eq!(rows.len() as u64, n, "{name}: one row per frame");
        assert!(rows.iter().all(|r| r.success), "{name}: a face on every frame");
        for s in v["stored"].as_array().unwrap() {
            let i = s["frame"].as_u64().unwrap() as usize;
            assert_eq!(rows[i].frame, i as u64);
            check(
                &format!("{name}#{i} (sequence)"),
                &rows[i],
                s["points"].as_array().unwrap(),
                v["width"].as_f64().unwrap(),
            );
        }
    }
}

/// The video file itself through facecap's decoder: its RGB is converted from the
/// stream's Y'CbCr by facecap (BT.709 for this clip, docs/video.md), about 1.2 grey levels
/// from ffmpeg's `rgb24` that MediaPipe was given, which moves the points by ~0.15 px mean
/// (iris centres 0.27 / 0.14 px) on the first frame (0.30 px and 0.54 / 0.43 px while
/// ffmpeg upsampled the chroma to 4:4:4). Checked: one row per frame with a face on each,
/// and the mean and largest distance goals on the stored frames.
#[test]
fn mesh_landmarks_csv_of_a_video_file_is_close_to_mediapipe() {
    let test = "mesh_landmarks_csv_of_a_video_file_is_close_to_mediapipe";
    if !models_present(test) {
        return;
    }
    let fx = fixture();
    let v = fx["videos"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["clip"] == "videos/liveportrait_d9.mp4")
        .unwrap();
    let Some(clip) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d9.mp4") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let st = facecap()
        .args(["landmarks", "--landmarks", "mesh", "--smooth", "--quiet", "--out"])
        .arg(dir.path())
        .arg(&clip)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let rows = read_mesh_csv(dir.path().join("landmarks.csv")).unwrap();
    assert_eq!(rows.len(), 587, "one row per frame");
    assert!(rows.iter().all(|r| r.success), "a face on every frame");
    let k = v["width"].as_f64().unwrap() / 480.0;
    for s in v["stored"].as_array().unwrap() {
        let i = s["frame"].as_u64().unwrap() as usize;
        let (mean, max, iris) = distances(rows[i].points.as_ref().unwrap(), s["points"].as_array().unwrap());
        eprintln!(
            "liveportrait_d9#{i} (mp4): mean {mean:.3} px, max {max:.3} px, iris {:.3} / {:.3} px",
            iris[0], iris[1]
        );
        assert!(mean <= MEAN_PX * k, "#{i}: mean {mean} px");
        assert!(max <= MAX_PX * k, "#{i}: max {max} px");
    }
}

/// The mesh front end loads only its own models: with a model folder holding nothing but
/// the two face mesh models, a folder of frames tracks (the video mode of a folder) and
/// writes one 478-point row per frame, while `dlib68` fails for want of dlib's models.
#[test]
fn mesh_front_end_runs_without_dlib_models() {
    let test = "mesh_front_end_runs_without_dlib_models";
    let (Some(det), Some(lm)) = (
        facecap_core::paths::model_file_or_skip(test, facecap_mesh::FACE_DETECTOR_MODEL),
        facecap_core::paths::model_file_or_skip(test, facecap_mesh::FACE_LANDMARKS_MODEL),
    ) else {
        return;
    };
    let Some(clip) = facecap_core::paths::shared_data_file(test, "videos/liveportrait_d9.mp4") else {
        return;
    };
    let Some(frames) = rgb_frames(test, &clip, 3) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let models = dir.path().join("models");
    std::fs::create_dir(&models).unwrap();
    std::fs::copy(&det, models.join(facecap_mesh::FACE_DETECTOR_MODEL)).unwrap();
    std::fs::copy(&lm, models.join(facecap_mesh::FACE_LANDMARKS_MODEL)).unwrap();
    let seq = dir.path().join("frames");
    std::fs::create_dir(&seq).unwrap();
    for (i, f) in frames.iter().enumerate() {
        f.save(seq.join(format!("{i:04}.png"))).unwrap();
    }
    let run = |front: &str, out: &str| {
        facecap()
            .env("FACECAP_MODELS", &models)
            .args(["landmarks", "--quiet", "--landmarks", front, "--out"])
            .arg(dir.path().join(out))
            .arg(&seq)
            .output()
            .unwrap()
    };
    let st = run("mesh", "mesh");
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let rows = read_mesh_csv(dir.path().join("mesh/landmarks.csv")).unwrap();
    assert_eq!(rows.len(), 3);
    assert!(rows
        .iter()
        .all(|r| r.success && r.points.as_ref().is_some_and(|p| p.len() == MESH_POINTS)));
    let st = run("dlib68", "dlib");
    assert!(!st.status.success(), "dlib68 ran without dlib's models");
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("model"), "{err}");
}

/// Images mode on a group photo (dlib's face data set, research-only, shared data): every
/// face gets its `.pts` and `summary.csv` row, largest first; `landmarks.csv` keeps one row
/// per image (the largest face).
#[test]
fn mesh_landmarks_of_a_group_photo_give_every_face() {
    let test = "mesh_landmarks_of_a_group_photo_give_every_face";
    if !models_present(test) {
        return;
    }
    let Some(photo) = facecap_core::paths::shared_data_file(test, "annotated/dlib_faces/2007_007763.jpg") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let st = facecap()
        .args(["landmarks", "--landmarks", "mesh", "--draw", "--out"])
        .arg(&out)
        .arg(&photo)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let summary = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let rows: Vec<Vec<&str>> = summary.lines().skip(1).map(|l| l.split(',').collect()).collect();
    // seven people, each annotated by dlib's authors (MediaPipe's FaceLandmarker finds none)
    assert_eq!(rows.len(), 7, "{summary}");
    let mut areas = Vec::new();
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r[1], k.to_string(), "{summary}");
        assert_eq!(r[8], format!("2007_007763_{k}.pts"));
        let pts = facecap_io::formats::pts::read_pts_points(out.join(r[8])).unwrap();
        assert_eq!(pts.len(), MESH_POINTS);
        let b: Vec<f64> = r[2..6].iter().map(|v| v.parse().unwrap()).collect();
        areas.push((b[2] - b[0]) * (b[3] - b[1]));
    }
    assert!(areas.windows(2).all(|a| a[0] >= a[1]), "largest first: {areas:?}");
    let csv = read_mesh_csv(out.join("landmarks.csv")).unwrap();
    assert_eq!(csv.len(), 1);
    assert!(csv[0].success);
    // the CSV row is face 0's
    let first = facecap_io::formats::pts::read_pts_points(out.join("2007_007763_0.pts")).unwrap();
    let p = csv[0].points.as_ref().unwrap();
    assert!((first[1].x - f64::from(p[1][0])).abs() < 1e-3);
    assert!(out.join("2007_007763_landmarks.png").exists());
    assert!(String::from_utf8_lossy(&st.stderr).contains("7 face(s)"));
}
