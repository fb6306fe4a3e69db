#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! One pipeline, one meaning per output: `capture`, `landmarks`, `solve`, `muscle track`
//! and `tensor fit` on one shared clip agree on their shared outputs; `animation.glb`
//! animates the head; `livelink.csv` carries the head rotation with one frame per row;
//! an OpenFace 2.x CSV solves to the same weights as facecap's own CSV.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn shared(test: &str, rel: &str) -> Option<PathBuf> {
    facecap_core::paths::shared_data_file(test, rel)
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn header(path: &Path) -> String {
    read(path).lines().next().unwrap().to_string()
}

/// The column `name` of a facecap CSV.
/// `facecap solve`'s CSV (from a landmarks CSV) against `facecap capture`'s (from the
/// video), column for column: equal, except what only the images carry. Solve has no iris:
/// its gaze shapes (`eyeLook*`, eye rotations) are 0 or NaN, except what a closing lid
/// drives (`eyeLookDown*` and the eye pitch, positive). eyeBlink (and livelink's EyeBlink,
/// OpenFace's AU45), which capture damps where the image shows the iris, is never lower in
/// solve, nor is eyeSquint, which takes a share of it; the posed model's eye and brow points
/// (OpenFace's 3D landmarks 36-47 and 17-26, which the squint lowers) move with them and are
/// skipped.
fn solve_agrees_with_capture(file: &str, solve: &str, capture: &str) {
    assert_eq!(
        solve.lines().count(),
        capture.lines().count(),
        "{file}: rows, solve vs capture"
    );
    assert_eq!(solve.lines().next(), capture.lines().next(), "{file}: header");
    let head: Vec<&str> = capture.lines().next().unwrap().split(',').map(str::trim).collect();
    for (a, b) in solve.lines().zip(capture.lines()).skip(1) {
        for ((h, x), y) in head.iter().zip(a.split(',')).zip(b.split(',')) {
            let eye_point = ["X_", "Y_", "Z_"].iter().any(|p| {
                h.strip_prefix(p)
                    .and_then(|i| i.parse::<usize>().ok())
                    .is_some_and(|i| (36..48).contains(&i) || (17..27).contains(&i))
            });
            if eye_point {
                continue;
            }
            let lower = h.to_ascii_lowercase();
            let gaze = lower.starts_with("eyelook")
                || (h.contains("Eye") && ["Yaw", "Pitch", "Roll"].iter().any(|a| h.ends_with(a)));
            if gaze {
                let v = if x == "nan" {
                    0.0
                } else {
                    x.trim().parse::<f64>().unwrap()
                };
                let from_lid = lower.starts_with("eyelookdown") || h.ends_with("Pitch");
                assert!(
                    v == 0.0 || (from_lid && v.is_finite() && v > 0.0),
                    "{file}: solve has no gaze signal: {h} = {x}"
                );
            } else if lower.contains("blink") || lower.contains("squint") || h.starts_with("AU45") {
                let (x, y) = (x.trim().parse::<f64>().unwrap(), y.trim().parse::<f64>().unwrap());
                assert!(x >= y - 1e-12, "{file} {h}: solve {x} below capture {y}");
            } else {
                assert_eq!(x, y, "{file} column {h}: solve vs capture");
            }
        }
    }
}

fn column(path: &Path, name: &str) -> Vec<f64> {
    let text = read(path);
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').map(str::trim).collect();
    let k = head
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("{name} not in {}", path.display()));
    lines
        .map(|l| l.split(',').nth(k).unwrap().trim().parse::<f64>().unwrap())
        .collect()
}

/// The first `frames` frames of a shared clip as Y4M (decoded natively by every command).
fn trimmed_clip(test: &str, dir: &Path, frames: usize) -> Option<PathBuf> {
    let src = shared(test, "videos/liveportrait_d18.mp4")?;
    facecap_core::paths::model_file_or_skip(test, facecap_core::paths::DLIB_68_MODEL)?;
    let out = dir.join("clip.y4m");
    let ok = Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-i"])
        .arg(&src)
        .args(["-frames:v", &frames.to_string(), "-pix_fmt", "yuv420p"])
        .arg(&out)
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        facecap_core::paths::skip(&format!("{test}: ffmpeg could not cut the clip"));
        return None;
    }
    Some(out)
}

#[test]
fn commands_agree_on_their_shared_outputs() {
    const T: &str = "commands_agree_on_their_shared_outputs";
    let dir = tempfile::tempdir().unwrap();
    let (Some(clip), Some(id_rig), Some(rig), Some(map)) = (
        trimmed_clip(T, dir.path(), 30),
        shared(T, "models3d/ict_facekit/ict_face_identity100.glb"),
        shared(T, "models3d/ict_facekit/ict_face_arkit53.glb"),
        shared(T, "models3d/ict_facekit/ict_landmarks68.json"),
    ) else {
        return;
    };
    let d = dir.path();
    let model = d.join("ict.fctensor");
    run_ok(
        facecap()
            .args(["tensor", "build", "--identity-rig"])
            .arg(&id_rig)
            .arg("--expression-rig")
            .arg(&rig)
            .args([
                "--identities",
                "6",
                "--seed",
                "1",
                "--expressions",
                "jawOpen,mouthSmile_L,mouthSmile_R",
                "--out",
            ])
            .arg(&model),
    );
    // capture: everything at once. `landmarks`, `tensor fit` and `muscle track` track
    // with dlib's 68 points, so capture is asked for the same front end here (its
    // default is the face mesh).
    run_ok(
        facecap()
            .args([
                "capture",
                "--quiet",
                "--landmarks",
                "dlib68",
                "--solver",
                "exact3d",
                "--muscles",
                "default",
                "--obj",
                "--rig",
            ])
            .arg(&rig)
            .arg("--landmark-map")
            .arg(&map)
            .arg("--tensor")
            .arg(&model)
            .arg("--tensor-landmark-map")
            .arg(&map)
            .arg("--out")
            .arg(d.join("cap"))
            .arg(&clip),
    );
    let cap = d.join("cap").join("clip");
    // landmarks VIDEO
    run_ok(
        facecap()
            .args(["landmarks", "--quiet"])
            .arg(&clip)
            .arg("--out")
            .arg(d.join("lm")),
    );
    // solve on capture's landmarks, same rig, camera and solver
    run_ok(
        facecap()
            .args([
                "solve", "--quiet", "--method", "exact3d", "--width", "480", "--height", "480", "--obj",
            ])
            .arg(cap.join("landmarks.csv"))
            .arg("--rig")
            .arg(&rig)
            .arg("--landmark-map")
            .arg(&map)
            .arg("--out")
            .arg(d.join("solve")),
    );
    // muscle track on the video
    run_ok(
        facecap()
            .args(["muscle", "track", "--quiet"])
            .arg(&clip)
            .arg("--mesh")
            .arg(&rig)
            .arg("--landmark-map")
            .arg(&map)
            .arg("--out")
            .arg(d.join("muscle")),
    );
    // tensor fit on the video
    run_ok(
        facecap()
            .args(["tensor", "fit", "--quiet"])
            .arg(&clip)
            .arg("--model")
            .arg(&model)
            .arg("--landmark-map")
            .arg(&map)
            .args(["--identity-frames", "5", "--write-landmarks", "--out"])
            .arg(d.join("tensor")),
    );

    // Same landmarks from every command that tracks the video.
    let lm = read(&cap.join("landmarks.csv"));
    assert_eq!(lm.lines().count(), 31, "30 frames + header");
    assert_eq!(read(&d.join("lm/landmarks.csv")), lm, "landmarks VIDEO vs capture");
    assert_eq!(read(&d.join("tensor/landmarks.csv")), lm, "tensor fit vs capture");
    // Same pose.csv numbers from solve and capture; the same weights except the gaze
    // shapes (`eyeLook*`), which capture takes from the iris in the images and a
    // landmarks CSV cannot carry.
    assert_eq!(
        read(&d.join("solve/pose.csv")),
        read(&cap.join("pose.csv")),
        "pose.csv: solve vs capture"
    );
    let (sw, cw) = (read(&d.join("solve/weights.csv")), read(&cap.join("weights.csv")));
    let head: Vec<&str> = cw.lines().next().unwrap().split(',').collect();
    assert_eq!(sw.lines().next(), cw.lines().next(), "weights.csv header");
    assert!(
        head.iter().any(|h| h.starts_with("eyeLook")),
        "the ICT rig has gaze shapes"
    );
    solve_agrees_with_capture("weights.csv", &sw, &cw);
    let rx = column(&cap.join("pose.csv"), "pose_Rx");
    assert!(
        rx.iter().all(|r| r.is_finite() && r.abs() < 1.0),
        "a near-frontal clip: {rx:?}"
    );
    // Same contractions from muscle track and capture --muscles.
    assert_eq!(
        read(&d.join("muscle/contractions.csv")),
        read(&cap.join("contractions.csv")),
        "contractions.csv: muscle track vs capture"
    );
    // One tensor.csv layout.
    assert_eq!(header(&d.join("tensor/tensor.csv")), header(&cap.join("tensor.csv")));
    assert_eq!(
        column(&d.join("tensor/tensor.csv"), "timestamp"),
        column(&cap.join("tensor.csv"), "timestamp")
    );
    // Same file names: one OBJ naming, the same CSV names.
    for f in ["obj/frame_000000.obj", "obj/frame_000029.obj"] {
        assert!(cap.join(f).is_file() && d.join("solve").join(f).is_file(), "{f}");
    }
    for f in [
        "pose.csv",
        "weights.csv",
        "openface.csv",
        "livelink.csv",
        "animation.glb",
    ] {
        assert!(d.join("solve").join(f).is_file(), "solve lacks {f}");
    }
}

/// Keyframe times, and the node paths animated, of an `animation.glb`.
fn animation_channels(path: &Path) -> (Vec<f32>, Vec<String>, Option<f64>) {
    let (doc, buffers, _) = gltf::import(path).unwrap();
    let anim = doc.animations().next().expect("an animation");
    let mut paths = Vec::new();
    let mut times = Vec::new();
    for ch in anim.channels() {
        assert_eq!(ch.target().node().index(), 0);
        paths.push(format!("{:?}", ch.target().property()));
        let reader = ch.reader(|b| Some(&buffers[b.index()]));
        times = reader.read_inputs().unwrap().collect();
    }
    let fps = anim.extras().as_ref().and_then(|e| {
        let v: serde_json::Value = serde_json::from_str(e.get()).ok()?;
        v["fps"].as_f64()
    });
    (times, paths, fps)
}

#[test]
fn animation_glb_moves_the_head_and_livelink_follows_the_pose() {
    const T: &str = "animation_glb_moves_the_head_and_livelink_follows_the_pose";
    let Some(clip) = shared(T, "videos/liveportrait_d18.mp4") else {
        return;
    };
    if facecap_core::paths::model_file_or_skip(T, facecap_core::paths::DLIB_68_MODEL).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    run_ok(
        facecap()
            .args(["capture", "--quiet", "--out"])
            .arg(dir.path().join("a"))
            .arg(&clip),
    );
    run_ok(
        facecap()
            .args(["capture", "--quiet", "--still-head", "--out"])
            .arg(dir.path().join("b"))
            .arg(&clip),
    );
    let cap = dir.path().join("a/liveportrait_d18");
    let summary: serde_json::Value = serde_json::from_str(&read(&cap.join("summary.json"))).unwrap();
    let frames = summary["frames"].as_u64().unwrap() as usize;
    let fps = summary["fps"].as_f64().unwrap();
    let (times, paths, glb_fps) = animation_channels(&cap.join("animation.glb"));
    assert_eq!(paths, ["MorphTargetWeights", "Translation", "Rotation"]);
    assert_eq!(times.len(), frames);
    assert_eq!(glb_fps, Some(fps));
    for (i, t) in times.iter().enumerate() {
        // keys on whole frames at the video's rate
        assert!((f64::from(*t) * fps - i as f64).abs() < 1e-3, "key {i} at {t} s");
    }
    // With the built-in rig (no gaze shapes) solve reproduces capture's files, except the
    // eyeBlink columns: capture damps them where the image shows the iris, solve has no
    // image (so they are compared as solve >= capture, and animation.glb, which carries
    // them, is not compared byte for byte; nor are the posed model's eye points in
    // openface.csv).
    run_ok(
        facecap()
            .args(["solve", "--quiet", "--width", "480", "--height", "480", "--out"])
            .arg(dir.path().join("s"))
            .arg(cap.join("landmarks.csv")),
    );
    for f in ["pose.csv", "weights.csv", "openface.csv", "livelink.csv"] {
        solve_agrees_with_capture(f, &read(&dir.path().join("s").join(f)), &read(&cap.join(f)));
    }
    let (_, still, _) = animation_channels(&dir.path().join("b/liveportrait_d18/animation.glb"));
    assert_eq!(still, ["MorphTargetWeights"]);
    // The default solver gives a head pose on every tracked frame.
    let yaw = column(&cap.join("pose.csv"), "pose_Ry");
    assert!(
        yaw.iter().all(|y| y.is_finite()),
        "pose.csv has NaN with the default solver"
    );

    // livelink.csv: HeadYaw follows pose.csv's yaw, timecodes advance one frame a row.
    let ll = read(&cap.join("livelink.csv"));
    let mut lines = ll.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = head.iter().position(|h| *h == "HeadYaw").unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), frames);
    let head_yaw: Vec<f64> = rows.iter().map(|r| r[k].parse().unwrap()).collect();
    let r = pearson(&head_yaw, &yaw);
    assert!(r.abs() >= 0.95, "HeadYaw vs pose_Ry: r = {r}");
    let rate = fps.round() as u64;
    let frame_of = |tc: &str| -> u64 {
        let (hms, ff) = tc.split_at(8);
        let p: Vec<u64> = hms.split(':').map(|x| x.parse().unwrap()).collect();
        let ff: u64 = ff[1..3].parse().unwrap();
        ((p[0] * 60 + p[1]) * 60 + p[2]) * rate + ff
    };
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(frame_of(row[0]), i as u64, "row {i}: {}", row[0]);
    }
    // The Khronos validator, when installed.
    let validator = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/validate_gltf.sh");
    match Command::new("bash")
        .arg(&validator)
        .arg(cap.join("animation.glb"))
        .output()
    {
        Ok(o) if o.status.code() == Some(2) => facecap_core::paths::skip(&format!("{T}: glTF validator not available")),
        Ok(o) => assert!(o.status.success(), "validator: {}", String::from_utf8_lossy(&o.stdout)),
        Err(_) => facecap_core::paths::skip(&format!("{T}: bash not available")),
    }
    blender_check(T, &cap);
    blender_check(T, &dir.path().join("b/liveportrait_d18"));
}

/// Imports the capture into Blender headless with `scripts/blender_import.py --check`
/// (scene rate and range from summary.json, keys on whole frames, head curves present).
fn blender_check(test: &str, capture: &Path) {
    if Command::new("blender").arg("--version").output().is_err() {
        facecap_core::paths::skip(&format!(
            "{test}: blender not installed (Debian: apt-get install blender)"
        ));
        return;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/blender_import.py");
    // Debian's Blender 3.4 glTF importer needs numpy < 1.24 (docs/capture.md).
    let numpy = facecap_core::paths::cache_dir().map(|d| d.join("blender-py"));
    let mut cmd = Command::new("blender");
    if let Some(p) = numpy.filter(|p| p.is_dir()) {
        cmd.env("PYTHONPATH", p);
    }
    let out = cmd
        .args(["-b", "--factory-startup", "--python"])
        .arg(&script)
        .arg("--")
        .arg(capture)
        .arg("--check")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("BLENDER IMPORT OK"),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// An OpenFace 2.x FeatureExtraction CSV (every column of a default run, spaces after
/// commas, frames from 1) holding the landmarks of facecap's `landmarks.csv`.
fn openface_csv(native: &str) -> String {
    let mut cols: Vec<String> = ["frame", "face_id", "timestamp", "confidence", "success"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    cols.extend(
        [
            "gaze_0_x",
            "gaze_0_y",
            "gaze_0_z",
            "gaze_1_x",
            "gaze_1_y",
            "gaze_1_z",
            "gaze_angle_x",
            "gaze_angle_y",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    for a in ["x", "y", "X", "Y", "Z"] {
        cols.extend((0..56).map(|i| format!("eye_lmk_{a}_{i}")));
    }
    cols.extend(
        ["pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz"]
            .iter()
            .map(|s| s.to_string()),
    );
    for a in ["x", "y", "X", "Y", "Z"] {
        cols.extend((0..68).map(|i| format!("{a}_{i}")));
    }
    cols.extend(
        ["p_scale", "p_rx", "p_ry", "p_rz", "p_tx", "p_ty"]
            .iter()
            .map(|s| s.to_string()),
    );
    cols.extend((0..34).map(|i| format!("p_{i}")));
    let aus = [
        "01", "02", "04", "05", "06", "07", "09", "10", "12", "14", "15", "17", "20", "23", "25", "26", "45",
    ];
    cols.extend(aus.iter().map(|a| format!("AU{a}_r")));
    cols.extend(aus.iter().chain(["28"].iter()).map(|a| format!("AU{a}_c")));
    let mut out = cols.join(", ");
    out.push('\n');
    let mut lines = native.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let get = |name: &str| f[head.iter().position(|h| *h == name).unwrap()];
        let frame: u64 = get("frame").parse().unwrap();
        let row: Vec<String> = cols
            .iter()
            .map(|c| match c.as_str() {
                "frame" => (frame + 1).to_string(),
                "face_id" => "0".into(),
                "timestamp" | "confidence" | "success" => get(c).to_string(),
                c if c.starts_with("x_") || c.starts_with("y_") => get(c).to_string(),
                _ => "0.5".into(),
            })
            .collect();
        out.push_str(&row.join(", "));
        out.push('\n');
    }
    out
}

#[test]
fn an_openface_csv_solves_to_the_same_weights_as_the_native_csv() {
    let native = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/solve/landmarks_liveportrait_d9.csv");
    let dir = tempfile::tempdir().unwrap();
    let of = dir.path().join("openface.csv");
    std::fs::write(&of, openface_csv(&read(&native))).unwrap();
    assert!(header(&of).starts_with("frame, face_id, timestamp, confidence, success, gaze_0_x"));
    for (input, out) in [(&native, "native"), (&of, "openface")] {
        run_ok(
            facecap()
                .args([
                    "solve", "--quiet", "--method", "exact", "--width", "512", "--height", "512", "--out",
                ])
                .arg(dir.path().join(out))
                .arg(input),
        );
    }
    let a = read(&dir.path().join("native/weights.csv"));
    let b = read(&dir.path().join("openface/weights.csv"));
    assert_eq!(a.lines().count(), 61);
    assert_eq!(a, b, "weights differ between the native and the OpenFace CSV");
    assert_eq!(
        read(&dir.path().join("native/pose.csv")),
        read(&dir.path().join("openface/pose.csv"))
    );
    // openface.csv written by solve: OpenFace's frame numbering and header.
    let written = read(&dir.path().join("native/openface.csv"));
    let mut l = written.lines();
    assert!(l
        .next()
        .unwrap()
        .starts_with("frame, face_id, timestamp, confidence, success, pose_Tx"));
    assert!(l.next().unwrap().starts_with("1, 0, 0.000, 1.00, 1, "));
}

#[test]
fn closed_stdout_and_errors_follow_the_conventions() {
    // `facecap info --json clip | head -c 1`: no panic when stdout is closed.
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<image::GrayImage> = (0..3u8)
        .map(|k| image::GrayImage::from_fn(33, 17, |x, y| image::Luma([16 + k * 10 + (x + y) as u8])))
        .collect();
    let mut bytes = Vec::new();
    facecap_io::video::y4m::write_gray_y4m(&mut bytes, &frames, 25, 1, false).unwrap();
    let clip = dir.path().join("clip.y4m");
    std::fs::write(&clip, bytes).unwrap();
    for args in [vec!["--help"], vec!["info", "--json", clip.to_str().unwrap()]] {
        // The read end of stdout is closed before the child writes: every write fails
        // with EPIPE.
        let mut child = facecap()
            .args(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(out.status.success(), "{args:?}: {:?} {err}", out.status);
    }
    // Errors once on stderr, also with --quiet; nothing on stdout.
    let out = facecap()
        .args([
            "solve",
            "--quiet",
            "--method",
            "exact",
            "/nonexistent/landmarks.csv",
            "--out",
        ])
        .arg(std::env::temp_dir().join("facecap-never-written"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("error:").count(), 1, "{err}");
    assert_eq!(err.matches("No such file").count(), 1, "{err}");
    assert!(out.stdout.is_empty());
    // --verbose exists and every subcommand's help has an example.
    assert!(facecap()
        .args(["--verbose", "--help"])
        .output()
        .unwrap()
        .status
        .success());
    for sub in [
        vec!["info"],
        vec!["landmarks"],
        vec!["solve"],
        vec!["capture"],
        vec!["synth"],
        vec!["transfer"],
        vec!["muscle", "track"],
        vec!["muscle", "bake"],
        vec!["tensor", "build"],
        vec!["tensor", "generate"],
        vec!["tensor", "fit"],
    ] {
        let out = facecap().args(&sub).arg("--help").output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("Example"), "{sub:?} --help has no example:\n{text}");
    }
}
