#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! End-to-end tensor commands: `tensor build`, `tensor generate`, `tensor fit VIDEO`
//! and `transfer SOURCE TARGET` on a small synthetic database and an image-folder
//! "video" made here (always runs); the same on the shared ICT rigs and clips when
//! present (SKIP otherwise).

use std::path::{Path, PathBuf};
use std::process::Command;

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmarks::Landmarks68;
use facecap_io::csv::{landmark_columns, landmark_values, FrameCsvWriter, FrameRow};
use nalgebra::{Point2, Point3, Vector3};

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

const GRID: usize = 41;

/// A 68-landmark layout on the face plane (model units, +y up).
fn template() -> Vec<(f64, f64)> {
    let mut t = Vec::with_capacity(68);
    for i in 0..17 {
        let a = std::f64::consts::PI * (1.0 + i as f64 / 16.0);
        t.push((8.5 * a.cos(), -1.5 + 8.0 * a.sin()));
    }
    for i in 0..5 {
        t.push((
            -7.0 + 1.2 * i as f64,
            5.0 + 0.3 * (i as f64 - 2.0).abs().mul_add(-1.0, 2.0),
        ));
    }
    for i in 0..5 {
        t.push((
            2.2 + 1.2 * i as f64,
            5.0 + 0.3 * (i as f64 - 2.0).abs().mul_add(-1.0, 2.0),
        ));
    }
    for i in 0..4 {
        t.push((0.0, 2.5 - 1.0 * i as f64));
    }
    for i in 0..5 {
        t.push((-1.5 + 0.75 * i as f64, -1.2));
    }
    for cx in [-4.0, 4.0] {
        for a in [180.0f64, 120.0, 60.0, 0.0, -60.0, -120.0] {
            let r = a.to_radians();
            t.push((cx + 1.6 * r.cos(), 2.5 + 0.7 * r.sin()));
        }
    }
    for k in 0..12 {
        let r = std::f64::consts::PI - k as f64 * std::f64::consts::PI / 6.0;
        t.push((3.2 * r.cos(), -4.5 + 1.4 * r.sin()));
    }
    for k in 0..8 {
        let r = std::f64::consts::PI - k as f64 * std::f64::consts::PI / 4.0;
        t.push((2.2 * r.cos(), -4.5 + 0.6 * r.sin()));
    }
    assert_eq!(t.len(), 68);
    t
}

fn grid_xy(v: usize) -> (f64, f64) {
    let (i, j) = (v % GRID, v / GRID);
    (
        -10.0 + 20.0 * i as f64 / (GRID - 1) as f64,
        -10.0 + 20.0 * j as f64 / (GRID - 1) as f64,
    )
}

/// Face of identity `i`, expression `e`: a bulged grid, identities vary width and depth,
/// expressions open the mouth, smile and raise the brows.
fn face(i: usize, e: usize) -> Vec<Point3<f32>> {
    let (sx, bulge) = (1.0 + 0.06 * i as f64, 1.0 + 0.15 * (i as f64 - 1.5));
    (0..GRID * GRID)
        .map(|v| {
            let (x, y) = grid_xy(v);
            let mut p = Point3::new(x * sx, y, bulge * (6.0 - (x * x + y * y) / 30.0));
            let near_mouth = (-((x / 4.0).powi(2) + ((y + 4.5) / 2.0).powi(2))).exp();
            match e {
                1 if y < -4.5 => p.y -= 1.5 * near_mouth,
                2 => p.y += 0.8 * near_mouth * (x / 3.0).powi(2),
                3 if y > 3.5 => p.y += 0.8 * (-(y - 5.0).powi(2) / 4.0).exp(),
                _ => {}
            }
            p.cast()
        })
        .collect()
}

fn triangles() -> Vec<[u32; 3]> {
    let mut t = Vec::new();
    for j in 0..GRID - 1 {
        for i in 0..GRID - 1 {
            let v = (j * GRID + i) as u32;
            let g = GRID as u32;
            t.push([v, v + 1, v + g + 1]);
            t.push([v, v + g + 1, v + g]);
        }
    }
    t
}

fn nearest_vertex(x: f64, y: f64) -> u32 {
    (0..GRID * GRID)
        .min_by(|&a, &b| {
            let (ax, ay) = grid_xy(a);
            let (bx, by) = grid_xy(b);
            ((ax - x).powi(2) + (ay - y).powi(2)).total_cmp(&((bx - x).powi(2) + (by - y).powi(2)))
        })
        .unwrap() as u32
}

fn intensity(x: f64, y: f64) -> f64 {
    128.0
        + 50.0 * (0.31 * x).sin() * (0.27 * y).cos()
        + 35.0 * (0.13 * x + 0.19 * y).sin()
        + 20.0 * (0.7 * x - 0.4 * y).cos()
}

/// Writes `n` frames of a textured image translating by (1, 0.5) px per frame into
/// `dir`, and the landmarks of the model face (identity 0, a mix of expressions) moving
/// with the texture into `csv`.
fn make_clip(dir: &Path, csv: &Path, map: &[u32], n: usize, tint: [f64; 3]) {
    std::fs::create_dir_all(dir).unwrap();
    let (w, h) = (200u32, 200u32);
    let k = Intrinsics::default_for_frame(w, h).unwrap();
    let mut wr = FrameCsvWriter::create(csv, &landmark_columns()).unwrap();
    let mut values = [0.0; 136];
    for f in 0..n {
        let (dx, dy) = (f as f64, 0.5 * f as f64);
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            let v = intensity(x as f64 - dx, y as f64 - dy);
            image::Rgb(tint.map(|t| (v * t).clamp(0.0, 255.0) as u8))
        });
        img.save(dir.join(format!("frame_{f:04}.png"))).unwrap();
        // Blend expressions: neutral -> mouth open over the clip.
        let s = f as f64 / (n - 1).max(1) as f64;
        let (a, b) = (face(0, 0), face(0, 1));
        let z = 40.0;
        let pose = ModelToCamera::from_rvec_tvec(
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
            Vector3::new(dx * z / k.fx, dy * z / k.fy, z),
        );
        let mut lm = Landmarks68::default();
        for (l, &v) in map.iter().enumerate() {
            let p: Point3<f64> = (a[v as usize].coords * (1.0 - s) as f32 + b[v as usize].coords * s as f32)
                .cast()
                .into();
            lm.points[l] = pose.project(&k, &p).unwrap_or(Point2::origin());
        }
        landmark_values(Some(&lm), &mut values);
        wr.write_row(&FrameRow {
            frame: f as u64,
            timestamp: f as f64 / 30.0,
            success: true,
            confidence: 1.0,
            values: &values,
        })
        .unwrap();
    }
    wr.finish().unwrap();
}

fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines.map(|l| l.split(',').map(String::from).collect()).collect();
    (head, rows)
}

fn column(path: &Path, name: &str) -> Vec<f64> {
    let (head, rows) = read_csv(path);
    let c = head
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("{name} not in {head:?}"));
    rows.iter().map(|r| r[c].parse::<f64>().unwrap_or(f64::NAN)).collect()
}

#[test]
fn build_generate_fit_transfer_on_synthetic_data() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    // Database: 4 identities x 4 expressions on a 41x41 grid face.
    let db = root.join("db");
    std::fs::create_dir_all(&db).unwrap();
    let exps = ["neutral", "open", "smile", "brows"];
    for i in 0..4 {
        for (e, name) in exps.iter().enumerate() {
            facecap_io::obj::write_obj_positions(db.join(format!("id{i}_{name}.obj")), &face(i, e), &triangles())
                .unwrap();
        }
    }
    let model = root.join("m.fctensor");
    let out = facecap()
        .args(["tensor", "build", "--meshes"])
        .arg(&db)
        .arg("--out")
        .arg(&model)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Generate a novel face.
    let gen = root.join("novel.obj");
    let out = facecap()
        .args(["tensor", "generate", "--model"])
        .arg(&model)
        .args(["--id", "0.5,0.5,0,0", "--exp", "0,0.7,0.3,0", "--out"])
        .arg(&gen)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let geo = facecap_io::obj::read_obj_positions(&gen, None).unwrap();
    assert_eq!(geo.positions.len(), GRID * GRID);
    // Landmark map and two clips.
    let map: Vec<u32> = template().iter().map(|&(x, y)| nearest_vertex(x, y)).collect();
    let map_path = root.join("map.json");
    std::fs::write(&map_path, serde_json::to_string(&map).unwrap()).unwrap();
    let (a_dir, a_csv) = (root.join("clip_a"), root.join("a.csv"));
    let (b_dir, b_csv) = (root.join("clip_b"), root.join("b.csv"));
    make_clip(&a_dir, &a_csv, &map, 8, [1.0, 0.9, 0.8]);
    make_clip(&b_dir, &b_csv, &map, 6, [0.8, 0.9, 1.0]);
    // Fit.
    let fit = root.join("fit");
    let out = facecap()
        .args(["tensor", "fit"])
        .arg(&a_dir)
        .arg("--landmarks")
        .arg(&a_csv)
        .arg("--model")
        .arg(&model)
        .arg("--landmark-map")
        .arg(&map_path)
        .args(["--lambda-id", "1e-4", "--lambda-exp", "1e-4", "--out"])
        .arg(&fit)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("feature points around mouth and brows"), "{stderr}");
    let rms = column(&fit.join("reprojection.csv"), "rms_landmarks_px");
    assert_eq!(rms.len(), 8);
    assert!(
        rms.iter().all(|r| r.is_finite() && *r < 1.0),
        "landmark RMS {rms:?}\n{stdout}"
    );
    let tz = column(&fit.join("tensor.csv"), "pose_Tz");
    assert!(tz.iter().all(|z| (z - 40.0).abs() < 4.0), "depth {tz:?}");
    let open = column(&fit.join("tensor.csv"), "exp_open");
    assert!(open[7] > open[0] + 0.3, "mouth opening not followed: {open:?}");
    // Transfer a onto b with OBJ output and the 2D reanimation.
    let xfer = root.join("xfer");
    let out = facecap()
        .arg("transfer")
        .arg(&a_dir)
        .arg(&b_dir)
        .arg("--source-landmarks")
        .arg(&a_csv)
        .arg("--target-landmarks")
        .arg(&b_csv)
        .arg("--model")
        .arg(&model)
        .arg("--landmark-map")
        .arg(&map_path)
        .args(["--obj", "--out"])
        .arg(&xfer)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for f in [
        "transfer.glb",
        "transfer.csv",
        "source_tensor.csv",
        "target_tensor.csv",
        "source_reprojection.csv",
        "target_reprojection.csv",
        "obj/frame_000007.obj",
        "reanimation/frame_00000.png",
        "reanimation/frame_00007.png",
    ] {
        assert!(xfer.join(f).is_file(), "missing {f}");
    }
    assert!(stdout.contains("with the source mouth cloned in"), "{stdout}");
    let (head, rows) = read_csv(&xfer.join("transfer.csv"));
    assert_eq!(rows.len(), 8);
    assert!(head.iter().any(|h| h == "exp_open") && head.iter().any(|h| h == "id_id0"));
    // The reanimated frame differs from the target frame only near the mouth.
    let last_target = image::open(b_dir.join("frame_0005.png")).unwrap().to_rgb8();
    let re = image::open(xfer.join("reanimation/frame_00007.png")).unwrap().to_rgb8();
    let changed: Vec<(u32, u32)> = re
        .enumerate_pixels()
        .filter(|(x, y, p)| {
            p.0.iter()
                .zip(last_target.get_pixel(*x, *y).0)
                .any(|(a, b)| a.abs_diff(b) > 3)
        })
        .map(|(x, y, _)| (x, y))
        .collect();
    assert!(!changed.is_empty(), "nothing cloned");
    assert!(changed.len() < 200 * 200 / 4, "{} pixels changed", changed.len());
}

fn shared(rel: &str) -> Option<PathBuf> {
    facecap_core::paths::shared_data_file("cli_tensor_shared", rel)
}

#[test]
fn shared_ict_model_fit_and_transfer() {
    let (Some(id_rig), Some(ex_rig), Some(map), Some(va), Some(vb)) = (
        shared("models3d/ict_facekit/ict_face_identity100.glb"),
        shared("models3d/ict_facekit/ict_face_arkit53.glb"),
        shared("models3d/ict_facekit/ict_landmarks68.json"),
        shared("videos/liveportrait_d3.mp4"),
        shared("videos/sadtalker_WDA_KatieHill_000.mp4"),
    ) else {
        return;
    };
    if facecap_core::paths::model_file_or_skip("cli_tensor_shared", facecap_core::paths::DLIB_68_MODEL).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // The first 20 frames of each clip keep the test short (the tracker runs on them).
    let trim = |src: &Path, name: &str| -> Option<PathBuf> {
        let out = dir.path().join(name);
        let st = Command::new("ffmpeg")
            .args(["-y", "-loglevel", "error", "-i"])
            .arg(src)
            .args(["-frames:v", "20", "-c:v", "libx264", "-crf", "12"])
            .arg(&out)
            .status()
            .ok()?;
        st.success().then_some(out)
    };
    let (Some(va), Some(vb)) = (trim(&va, "a.mp4"), trim(&vb, "b.mp4")) else {
        facecap_core::paths::skip("cli_tensor_shared: ffmpeg could not trim the clips");
        return;
    };
    let model = dir.path().join("ict.fctensor");
    let out = facecap()
        .args(["tensor", "build", "--identity-rig"])
        .arg(&id_rig)
        .arg("--expression-rig")
        .arg(&ex_rig)
        .args([
            "--identities",
            "8",
            "--seed",
            "1",
            "--expressions",
            "jawOpen,mouthSmile_L,mouthSmile_R,browInnerUp_L",
            "--out",
        ])
        .arg(&model)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let xfer = dir.path().join("xfer");
    let out = facecap()
        .arg("transfer")
        .arg(&va)
        .arg(&vb)
        .arg("--model")
        .arg(&model)
        .arg("--landmark-map")
        .arg(&map)
        .args(["--identity-frames", "10", "--out"])
        .arg(&xfer)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for name in ["source", "target"] {
        let rms = column(&xfer.join(format!("{name}_reprojection.csv")), "rms_landmarks_px");
        let ok: Vec<f64> = rms.iter().copied().filter(|r| r.is_finite()).collect();
        assert!(
            ok.len() * 10 >= rms.len() * 9,
            "{name}: {} of {} frames fitted",
            ok.len(),
            rms.len()
        );
        let mean = ok.iter().sum::<f64>() / ok.len() as f64;
        assert!(mean < 10.0, "{name}: mean landmark RMS {mean} px");
    }
    assert!(xfer.join("transfer.glb").is_file() && xfer.join("reanimation/frame_00000.png").is_file());
}
