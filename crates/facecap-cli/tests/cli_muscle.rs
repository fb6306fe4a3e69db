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
    // The contents against an independent reference: MediaPipe FaceLandmarker's
    // blendshape scores for the same clip (testdata/expressions, see cli_expressions.rs).
    // The jaw follows jawOpen, the cheek muscles (zygomaticus) mouthSmile, the frontalis
    // the raised brows.
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../testdata/expressions/mp_blendshapes_liveportrait_d18.csv");
    let mp_text = std::fs::read_to_string(fixture).unwrap();
    let mut mp_lines = mp_text.lines();
    let mp_head: Vec<&str> = mp_lines.next().unwrap().split(',').collect();
    let mp_rows: Vec<Vec<f64>> = mp_lines
        .map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap_or(f64::NAN)).collect())
        .collect();
    assert_eq!(mp_rows.len(), rows.len());
    let mp = |names: &[&str], r: &[f64]| {
        names
            .iter()
            .map(|n| r[mp_head.iter().position(|h| h == n).unwrap()])
            .sum::<f64>()
            / names.len() as f64
    };
    let ours = |names: &[&str], r: &[f64]| {
        names
            .iter()
            .map(|n| r[header.iter().position(|h| h == n).unwrap()])
            .sum::<f64>()
            / names.len() as f64
    };
    let pairs: [(&[&str], &[&str], f64); 3] = [
        (&["jaw"], &["jawOpen"], MIN_R_JAW),
        (
            &["cheek_L", "cheek_R"],
            &["mouthSmileLeft", "mouthSmileRight"],
            MIN_R_SMILE,
        ),
        (
            &["eyebrow_forehead_L", "eyebrow_forehead_R"],
            &["browInnerUp", "browOuterUpLeft", "browOuterUpRight"],
            MIN_R_BROW,
        ),
    ];
    for (o, m, min_r) in pairs {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (r, q) in rows.iter().zip(&mp_rows) {
            if r[2] == 1.0 && q[1] == 1.0 {
                a.push(ours(o, r));
                b.push(mp(m, q));
            }
        }
        let r = pearson(&a, &b);
        eprintln!("{o:?} vs MediaPipe {m:?}: r = {r:.3} over {} frames", a.len());
        assert!(r >= min_r, "{o:?} vs {m:?}: r = {r}");
    }

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

/// Smallest Pearson r against MediaPipe's scores (measured values in docs/reliability.md).
/// Measured 2026-12-02: jaw 0.920, cheek 0.952, frontalis 0.692.
const MIN_R_JAW: f64 = 0.85;
const MIN_R_SMILE: f64 = 0.9;
const MIN_R_BROW: f64 = 0.55;

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
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

/// `facecap muscle bake` on the ICT rig, read back: the mesh and its 53 targets are kept
/// as they were, one target per muscle of the written set plus `jaw_open` is appended, and
/// each baked target moves the face the way its muscle pulls (measured at the mapped
/// landmark vertices): a linear muscle draws its insertion towards its origin and leaves
/// the other side of the face still, the sphincter draws the mouth corners in, the
/// frontalis lifts the brow, the jaw drops the chin and lower lip and leaves the eyes.
#[test]
fn bake_writes_targets_that_move_the_face_like_their_muscles() {
    const T: &str = "cli_muscle::bake_writes_targets_that_move_the_face_like_their_muscles";
    let (Some(mesh), Some(map)) = (
        shared_data_file(T, "models3d/ict_facekit/ict_face_arkit53.glb"),
        shared_data_file(T, "models3d/ict_facekit/ict_landmarks68.json"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (rig_out, set_out) = (dir.path().join("baked.glb"), dir.path().join("set.json"));
    let out = facecap()
        .args(["muscle", "bake", "--mesh"])
        .arg(&mesh)
        .arg("--landmark-map")
        .arg(&map)
        .arg("--out")
        .arg(&rig_out)
        .arg("--write-set")
        .arg(&set_out)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let input = facecap_io::gltf_io::read_morph_mesh(&mesh).unwrap();
    let baked = facecap_io::gltf_io::read_morph_mesh(&rig_out).unwrap();
    assert_eq!(
        baked.base.positions, input.base.positions,
        "the mesh itself is unchanged"
    );
    assert_eq!(baked.base.triangles, input.base.triangles);
    assert_eq!(
        &baked.targets[..input.targets.len()],
        &input.targets[..],
        "existing targets kept"
    );
    let set: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&set_out).unwrap()).unwrap();
    let muscles = set["muscles"].as_array().unwrap();
    let mut names: Vec<String> = muscles
        .iter()
        .map(|m| m["name"].as_str().unwrap().to_string())
        .collect();
    names.push("jaw_open".into());
    assert_eq!(names.len(), 12);
    let baked_names: Vec<&str> = baked.targets[input.targets.len()..]
        .iter()
        .map(|t| t.name.as_str())
        .collect();
    assert_eq!(baked_names, names);

    let lm = facecap_core::landmark_map::LandmarkMap::from_json_file(&map).unwrap();
    let v = |i: usize| lm.vertices[i].unwrap() as usize;
    let pos = |i: usize| input.base.positions[v(i)].coords.cast::<f64>();
    let target = |name: &str| baked.targets.iter().find(|t| t.name == name).unwrap();
    let delta = |name: &str, i: usize| target(name).deltas[v(i)].cast::<f64>();
    // Face scale: the outer eye corners' distance.
    let iod = (pos(36) - pos(45)).norm();
    let vec3 = |j: &serde_json::Value| {
        nalgebra::Vector3::new(j[0].as_f64().unwrap(), j[1].as_f64().unwrap(), j[2].as_f64().unwrap())
    };
    // (muscle, its insertion landmark, the mirrored landmark on the other side)
    let linear = [
        ("cheek_L", 54, 48),
        ("cheek_R", 48, 54),
        ("lips1_L", 52, 48),
        ("lips1_R", 50, 54),
        ("lips3_L", 54, 48),
        ("lips3_R", 48, 54),
        ("nose_forehead_L", 24, 17),
        ("nose_forehead_R", 19, 26),
    ];
    for (name, ins, other) in linear {
        let m = muscles.iter().find(|m| m["name"] == name).unwrap();
        let pull = (vec3(&m["origin"]) - vec3(&m["insertion"])).normalize();
        let d = delta(name, ins);
        let along = d.dot(&pull);
        let far = delta(name, other).norm();
        eprintln!(
            "{name}: insertion moves {:.3} IOD ({:.3} along the pull), mirrored landmark {:.4} IOD",
            d.norm() / iod,
            along / iod,
            far / iod
        );
        assert!(along > MIN_PULL * iod, "{name}: insertion moves {along} along its pull");
        assert!(
            along > 0.8 * d.norm(),
            "{name}: the insertion moves off the pull direction"
        );
        assert!(far < 0.1 * along, "{name}: the other side moves {far}");
    }
    // Sphincter: both corners move towards the mouth centre.
    let centre = (pos(48) + pos(51) + pos(54) + pos(57)) / 4.0;
    for i in [48, 54] {
        let inward = delta("lips", i).dot(&(centre - pos(i)).normalize());
        eprintln!("lips: corner {i} moves {:.3} IOD inward", inward / iod);
        assert!(inward > 0.5 * MIN_PULL * iod, "lips: corner {i} moves {inward} inward");
    }
    // Frontalis: the brow goes up (ICT is y-up), the mouth stays.
    for (name, brow) in [("eyebrow_forehead_L", 24), ("eyebrow_forehead_R", 19)] {
        let up = delta(name, brow).y;
        eprintln!("{name}: brow {brow} rises {:.3} IOD", up / iod);
        assert!(up > MIN_PULL * iod, "{name}: brow rises {up}");
        assert!(delta(name, 57).norm() < 1e-6 * iod, "{name} moves the lip");
    }
    // Jaw: chin and lower lip drop; eyes, brows and nose do not move.
    let (chin, lower) = (delta("jaw_open", 8), delta("jaw_open", 57));
    eprintln!(
        "jaw_open: chin drops {:.3} IOD, lower lip {:.3} IOD, upper lip {:.4} IOD",
        -chin.y / iod,
        -lower.y / iod,
        delta("jaw_open", 51).norm() / iod
    );
    assert!(-chin.y > MIN_JAW_DROP * iod && -lower.y > 0.5 * MIN_JAW_DROP * iod);
    for i in [19, 24, 36, 45, 27] {
        assert!(delta("jaw_open", i).norm() < 1e-6 * iod, "jaw_open moves landmark {i}");
    }
}

/// The smallest displacement a full contraction gives at its insertion, in inter-ocular
/// distances (measured 2026-12-02 on ICT: 0.088-0.146; sphincter corners 0.039, checked
/// against half of it).
const MIN_PULL: f64 = 0.04;
/// The smallest drop of the chin at the largest jaw angle, in inter-ocular distances
/// (measured 0.307, lower lip 0.372).
const MIN_JAW_DROP: f64 = 0.15;
