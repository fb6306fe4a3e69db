#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! `facecap muscle track` end to end on a shared clip (skipped without the shared data or
//! the dlib models), and its argument errors (always run).

use std::process::Command;

use facecap_core::paths::shared_data_file;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn models_present() -> bool {
    let cache = std::env::var_os("FACECAP_CACHE")
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".cache").join("facecap")));
    let Some(cache) = cache else { return false };
    let models = std::env::var_os("FACECAP_MODELS").map_or(cache.join("models"), std::path::PathBuf::from);
    models.join("shape_predictor_68_face_landmarks.dat").is_file()
        && models.join("dlib_frontal_face_detector.svm").is_file()
}

#[test]
fn track_writes_contractions_posed_mesh_and_report() {
    const T: &str = "cli_muscle::track_writes_contractions_posed_mesh_and_report";
    let (Some(video), Some(mesh), Some(map)) = (
        shared_data_file(T, "videos/liveportrait_d18.mp4"),
        shared_data_file(T, "models3d/ict_facekit/ict_face_arkit53.glb"),
        shared_data_file(T, "models3d/ict_facekit/ict_landmarks68.json"),
    ) else {
        return;
    };
    if !models_present() {
        facecap_core::paths::skip_missing_data(&format!("{T}: dlib models not in the cache (run scripts/setup.sh)"));
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = facecap()
        .args(["muscle", "track"])
        .arg(&video)
        .arg("--mesh")
        .arg(&mesh)
        .arg("--landmark-map")
        .arg(&map)
        .arg("--out")
        .arg(dir.path())
        .arg("--report")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // contractions.csv: header with the 11 default muscles and the jaw, one row per frame,
    // every frame solved, contractions in [0, 1] and the jaw within [0, max angle].
    let text = std::fs::read_to_string(dir.path().join("contractions.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').map(str::trim).collect();
    assert_eq!(&header[..4], &["frame", "timestamp", "success", "confidence"]);
    assert_eq!(header.len(), 4 + 11 + 1, "{header:?}");
    assert_eq!(*header.last().unwrap(), "jaw");
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.trim().parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 216, "one row per frame");
    let solved = rows.iter().filter(|r| r[2] == 1.0).count();
    assert!(solved >= 212, "solved {solved} of 216");
    let mut active = 0;
    for r in rows.iter().filter(|r| r[2] == 1.0) {
        for &c in &r[4..15] {
            assert!((0.0..=1.0).contains(&c), "contraction {c}");
        }
        assert!((0.0..=0.36).contains(&r[15]), "jaw {}", r[15]);
        active += usize::from(r[4..15].iter().any(|&c| c > 0.2));
    }
    assert!(
        active > 20,
        "the clip's expressions should activate muscles ({active} frames)"
    );

    // The animated rig and the report.
    let glb = facecap_io::gltf_io::read_morph_mesh(dir.path().join("posed.glb")).unwrap();
    assert_eq!(
        glb.targets.len(),
        53 + 11 + 1,
        "ICT's 53 targets + 11 muscles + jaw_open"
    );
    let report = dir.path().join("report");
    for f in ["curves_left.svg", "curves_right.svg", "curves_other.svg", "report.html"] {
        let s = std::fs::read_to_string(report.join(f)).unwrap();
        assert!(s.len() > 500, "{f} too small");
    }
    let sheet = image::open(report.join("meshes.png")).unwrap().to_rgb8();
    // 13 tiles (rest + 11 peaks + jaw) of 300 px, 4 per row.
    assert_eq!((sheet.width(), sheet.height()), (1200, 1200));
    let shaded = sheet
        .pixels()
        .filter(|p| p.0 != [245, 245, 245] && p.0 != [255, 255, 255])
        .count();
    assert!(
        shaded > 13 * 300 * 300 / 5,
        "rendered faces cover the tiles ({shaded} px)"
    );
}

#[test]
fn track_rejects_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.glb");
    let out = facecap()
        .args(["muscle", "track", "nothing.mp4", "--mesh"])
        .arg(&missing)
        .args(["--landmark-map", "nothing.json", "--solver", "sideways", "--out"])
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--solver"), "{err}");

    let out = facecap()
        .args(["muscle", "track", "nothing.mp4", "--mesh"])
        .arg(&missing)
        .args(["--landmark-map", "nothing.json", "--out"])
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("missing.glb"), "the error names the mesh file: {err}");
    assert!(!dir.path().join("o").join("contractions.csv").exists());
}
