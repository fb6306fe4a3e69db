#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Nothing lost, nothing silently wrong (docs/reliability.md), end to end on small clips
//! the project makes itself (`facecap synth` from the cached astronaut photo):
//!
//! * output names: two inputs of one name and a name made of dots get their own folders
//!   inside `--out`, and the JSON summary says which input went where;
//! * salvage: a Y4M with a cut last frame, an image folder with one corrupt PNG and an
//!   mp4 with 2 KB of zeros keep every decodable frame, mark the others `success = 0`
//!   with the reason, count them in `summary.json`; `--strict` fails instead;
//! * plausibility: a clip without a face gives no Live Link row and no animation (no
//!   neutral take); `solve` fails a row with 68 identical points or a point at 1e300 alone
//!   and solves rows listed in reverse order in frame order;
//! * `landmarks`: unique `.pts` names, a corrupt image fails alone, a `--box` outside the
//!   image and a bit-flipped model are errors;
//! * argument checks: `--landmark-map` without `--rig`, a shape listed twice.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use facecap_io::csv::read_landmarks_csv;
use serde_json::Value;

fn facecap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
}

fn run(cmd: &mut Command) -> Output {
    cmd.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// The cached astronaut photo and the models, or `None` after a skip line.
fn photo(test: &str) -> Option<PathBuf> {
    facecap_core::paths::model_file_or_skip(test, facecap_core::paths::DLIB_68_MODEL)?;
    facecap_core::paths::model_file_or_skip(test, "dlib_frontal_face_detector.svm")?;
    let p = facecap_core::paths::cache_dir()?.join("data").join("astronaut.png");
    if !p.is_file() {
        facecap_core::paths::skip_missing_data(&format!(
            "{test}: astronaut.png not in the cache (run scripts/setup.sh)"
        ));
        return None;
    }
    Some(p)
}

fn synth(dir: &Path, photo: &Path, frames: usize) -> PathBuf {
    let out = dir.join(format!("synth{frames}"));
    let o = run(facecap()
        .args(["synth", "--quiet", "--frames", &frames.to_string(), "--out"])
        .arg(&out)
        .arg("--photo")
        .arg(photo));
    assert!(o.status.success(), "synth: {}", stderr(&o));
    out.join("synth.y4m")
}

/// `success` per row of a facecap CSV.
fn success_column(path: &Path) -> Vec<bool> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    assert!(lines.next().unwrap().starts_with("frame,timestamp,success,"));
    lines.map(|l| l.split(',').nth(2).unwrap() == "1").collect()
}

fn data_rows(path: &Path) -> usize {
    std::fs::read_to_string(path).unwrap().lines().count() - 1
}

#[test]
fn capture_salvages_damaged_inputs_into_unique_folders() {
    const T: &str = "capture_salvages_damaged_inputs_into_unique_folders";
    let Some(photo) = photo(T) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let clip = synth(dir, &photo, 12);
    // Two cards, one clip name; a name of dots; a Y4M cut inside its last frame.
    for sub in ["a", "b"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        std::fs::copy(&clip, dir.join(sub).join("C0001.y4m")).unwrap();
    }
    std::fs::copy(&clip, dir.join("...y4m")).unwrap();
    let bytes = std::fs::read(&clip).unwrap();
    std::fs::write(dir.join("cut.y4m"), &bytes[..bytes.len() - 1000]).unwrap();
    // An image folder frame_1..frame_12 (natural order) with frame_5 corrupt.
    let frames_dir = dir.join("frames");
    std::fs::create_dir_all(&frames_dir).unwrap();
    // Colour frames: the default front end (`mesh`) reads colour, so the folder's frames
    // must hold the Y4M's colours for the landmarks to match.
    let rgb = facecap_io::video::SourceOptions {
        rgb: true,
        ..Default::default()
    };
    let mut src = facecap_io::video::open_source(&clip, &rgb).unwrap();
    let mut f = facecap_io::video::Frame::default();
    let mut k = 1;
    while facecap_io::video::FrameSource::read_into(src.as_mut(), &mut f).unwrap() {
        f.rgb
            .as_ref()
            .unwrap()
            .save(frames_dir.join(format!("frame_{k}.png")))
            .unwrap();
        k += 1;
    }
    let png = std::fs::read(frames_dir.join("frame_5.png")).unwrap();
    std::fs::write(frames_dir.join("frame_5.png"), &png[..png.len() / 3]).unwrap();

    let out_dir = dir.join("out").join("D");
    let inputs = [
        dir.join("a/C0001.y4m"),
        dir.join("b/C0001.y4m"),
        dir.join("...y4m"),
        dir.join("cut.y4m"),
        frames_dir.clone(),
    ];
    let o = run(facecap()
        .args(["capture", "--quiet", "--json", "--out"])
        .arg(&out_dir)
        .args(&inputs));
    assert!(o.status.success(), "{}", stderr(&o));
    // The damage is reported on stderr even with --quiet.
    let err = stderr(&o);
    assert!(err.contains("cut.y4m: 1 of 12 frames could not be decoded"), "{err}");
    assert!(err.contains("frames: 1 of 12 frames could not be decoded"), "{err}");
    let report: Value = serde_json::from_slice(&o.stdout).unwrap();
    let outs: Vec<String> = report["videos"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            assert_eq!(v["status"], "done", "{v}");
            v["out"].as_str().unwrap().to_string()
        })
        .collect();
    let want: Vec<String> = ["C0001", "C0001-2", "__", "cut", "frames"]
        .iter()
        .map(|n| out_dir.join(n).display().to_string())
        .collect();
    assert_eq!(outs, want);
    // Nothing outside --out: its parent holds only D.
    let parent: Vec<_> = std::fs::read_dir(dir.join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(parent, ["D"]);
    for name in ["C0001", "C0001-2", "__"] {
        let s = json(&out_dir.join(name).join("summary.json"));
        assert_eq!(s["frames"], 12, "{name}");
        assert_eq!(s["undecodable_frames"], 0, "{name}");
        assert!(s["success_frames"].as_u64().unwrap() >= 11, "{name}: {s}");
    }
    // The cut Y4M: 11 frames solved, the 12th written as failed with its reason.
    let cut = out_dir.join("cut");
    let s = json(&cut.join("summary.json"));
    assert_eq!(s["frames"], 12);
    assert_eq!(s["undecodable_frames"], 1);
    assert_eq!(s["failed_frames"][0]["frame"], 11);
    assert!(
        s["failed_frames"][0]["reason"].as_str().unwrap().contains("truncated"),
        "{s}"
    );
    let ok = success_column(&cut.join("landmarks.csv"));
    assert_eq!(ok.len(), 12);
    assert!(!ok[11] && ok[..11].iter().filter(|&&x| x).count() >= 10, "{ok:?}");
    assert!(!success_column(&cut.join("weights.csv"))[11]);
    // The folder: frame 4 (frame_5.png) failed, read in natural order (its landmarks
    // match the Y4M's frame by frame).
    let fr = out_dir.join("frames");
    let s = json(&fr.join("summary.json"));
    assert_eq!(
        (s["frames"].as_u64(), s["undecodable_frames"].as_u64()),
        (Some(12), Some(1))
    );
    assert!(
        s["failed_frames"][0]["reason"]
            .as_str()
            .unwrap()
            .contains("frame_5.png"),
        "{s}"
    );
    let a = read_landmarks_csv(out_dir.join("C0001").join("landmarks.csv")).unwrap();
    let b = read_landmarks_csv(fr.join("landmarks.csv")).unwrap();
    assert!(!b[4].success);
    // Before the corrupt frame both runs track the same images the same way; in byte
    // order index 1 would be frame_10.png (the Y4M's frame 9).
    let dist = |x: &facecap_io::csv::LandmarkRecord, y: &facecap_io::csv::LandmarkRecord| {
        let (l, m) = (x.landmarks.as_ref().unwrap(), y.landmarks.as_ref().unwrap());
        l.points
            .iter()
            .zip(&m.points)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    };
    for k in 0..4 {
        let d = dist(&a[k], &b[k]);
        assert!(d < 0.01, "frame {k}: folder and Y4M landmarks {d} px apart (order?)");
    }
    assert!(
        dist(&a[1], &a[9]) > 0.1,
        "the clip must move for the order check to mean anything"
    );
    // --strict: the cut Y4M fails.
    let o = run(facecap()
        .args(["capture", "--quiet", "--strict", "--out"])
        .arg(dir.join("strict"))
        .arg(dir.join("cut.y4m")));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));

    // solve on the capture's landmarks with three bad edits: rows in reverse order, 68
    // identical points in frame 3, a point at 1e300 in frame 7.
    let text = std::fs::read_to_string(out_dir.join("C0001").join("landmarks.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let head = lines.remove(0);
    let cols: Vec<&str> = head.split(',').collect();
    let x0 = cols.iter().position(|c| *c == "x_0").unwrap();
    for (k, line) in lines.iter_mut().enumerate() {
        let mut v: Vec<String> = line.split(',').map(str::to_string).collect();
        if k == 3 {
            for x in v.iter_mut().skip(x0) {
                *x = "100".into();
            }
            v[2] = "1".into();
        }
        if k == 7 {
            v[x0] = "1e300".into();
            v[2] = "1".into();
        }
        *line = v.join(",");
    }
    lines.reverse();
    let bad = dir.join("bad_landmarks.csv");
    std::fs::write(&bad, format!("{head}\n{}\n", lines.join("\n"))).unwrap();
    let solved = dir.join("solved");
    let o = run(facecap()
        .args(["solve", "--width", "640", "--height", "480", "--out"])
        .arg(&solved)
        .arg(&bad));
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("frame 3: implausible landmarks") && err.contains("frame 7: implausible landmarks"),
        "{err}"
    );
    let w = read_landmarks_csv(solved.join("weights.csv"));
    let frames: Vec<u64> = match &w {
        Ok(rows) => rows.iter().map(|r| r.frame).collect(),
        Err(_) => std::fs::read_to_string(solved.join("weights.csv"))
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').next().unwrap().parse().unwrap())
            .collect(),
    };
    assert_eq!(frames, (0..12).collect::<Vec<u64>>());
    let succ: Vec<bool> = std::fs::read_to_string(solved.join("weights.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap() == "1")
        .collect();
    assert!(!succ[3] && !succ[7], "{succ:?}");
    let n_ok = succ.iter().filter(|&&x| x).count();
    assert!(n_ok >= 9, "{succ:?}");
    let (_, anim) = facecap_io::gltf_io::read_morph_file(solved.join("animation.glb")).unwrap();
    assert_eq!(anim.unwrap().times_s.len(), n_ok, "one keyframe per solved frame");
}

#[test]
fn a_clip_without_a_face_is_not_a_neutral_take() {
    const T: &str = "a_clip_without_a_face_is_not_a_neutral_take";
    if photo(T).is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let clip = tmp.path().join("wall.y4m");
    let frames: Vec<image::GrayImage> = (0..6)
        .map(|k| image::GrayImage::from_pixel(320, 240, image::Luma([90 + k as u8])))
        .collect();
    let mut f = std::fs::File::create(&clip).unwrap();
    facecap_io::video::y4m::write_gray_y4m(&mut f, &frames, 25, 1, false).unwrap();
    drop(f);
    let out = tmp.path().join("out");
    let o = run(facecap().args(["capture", "--quiet", "--out"]).arg(&out).arg(&clip));
    assert!(o.status.success(), "{}", stderr(&o));
    let d = out.join("wall");
    assert_eq!(json(&d.join("summary.json"))["success_frames"], 0);
    // No row that reads as a neutral face, no animation of one.
    if d.join("livelink.csv").exists() {
        assert_eq!(data_rows(&d.join("livelink.csv")), 0);
    }
    assert!(!d.join("animation.glb").exists());
    assert_eq!(data_rows(&d.join("weights.csv")), 6);
    assert!(success_column(&d.join("landmarks.csv")).iter().all(|s| !s));
}

#[test]
fn landmarks_names_damage_boxes_and_models() {
    const T: &str = "landmarks_names_damage_boxes_and_models";
    let Some(photo) = photo(T) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    for sub in ["a", "b"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        std::fs::copy(&photo, dir.join(sub).join("img.png")).unwrap();
    }
    let png = std::fs::read(&photo).unwrap();
    std::fs::write(dir.join("bad.png"), &png[..5000]).unwrap();
    let out = dir.join("pts");
    let o = run(facecap().args(["landmarks", "--out"]).arg(&out).args([
        dir.join("a/img.png"),
        dir.join("bad.png"),
        dir.join("b/img.png"),
    ]));
    assert!(o.status.success(), "{}", stderr(&o));
    let a = facecap_io::formats::pts::read_pts(out.join("img_0.pts")).unwrap();
    let b = facecap_io::formats::pts::read_pts(out.join("img-2_0.pts")).unwrap();
    assert_eq!(a, b, "the same photo twice gives the same points under two names");
    let csv = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(
        rows[0],
        "image,face,left,top,right,bottom,score,num_points,pts_file,error"
    );
    assert!(rows[1].ends_with(",68,img_0.pts,"), "{csv}");
    assert!(
        rows[2].contains("bad.png,-1,") && rows[2].contains("cannot decode"),
        "{csv}"
    );
    assert!(rows[3].ends_with(",68,img-2_0.pts,"), "{csv}");
    // --strict: the damaged image fails the run; alone, it fails it anyway.
    let o = run(facecap()
        .args(["landmarks", "--strict", "--out"])
        .arg(dir.join("s"))
        .arg(dir.join("a/img.png"))
        .arg(dir.join("bad.png")));
    assert!(!o.status.success());
    let o = run(facecap()
        .args(["landmarks", "--out"])
        .arg(dir.join("s2"))
        .arg(dir.join("bad.png")));
    assert!(!o.status.success());
    // A box beside the 512x512 image is refused; one on it works.
    let o = run(facecap()
        .args(["landmarks", "--box", "5000,5000,6000,6000", "--out"])
        .arg(dir.join("bx"))
        .arg(&photo));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("outside the 512x512 image"), "{}", stderr(&o));
    let o = run(facecap()
        .args(["landmarks", "--box", "175,76,265,166", "--out"])
        .arg(dir.join("bx2"))
        .arg(&photo));
    assert!(o.status.success(), "{}", stderr(&o));
    // One bit flipped at byte 41 of the 68-point model: a copy under its own name fails
    // its sha256 against setup's SHA256SUMS; under another name, the plausibility check.
    let model = facecap_core::paths::model_file(facecap_core::paths::DLIB_68_MODEL).unwrap();
    let mut m = std::fs::read(&model).unwrap();
    m[41] ^= 0x10;
    std::fs::create_dir_all(dir.join("models")).unwrap();
    let same_name = dir.join("models").join(facecap_core::paths::DLIB_68_MODEL);
    let other_name = dir.join("models").join("flipped.dat");
    std::fs::write(&same_name, &m).unwrap();
    std::fs::write(&other_name, &m).unwrap();
    for (p, what) in [(&same_name, "sha256"), (&other_name, "implausible model")] {
        let o = run(facecap()
            .args(["landmarks", "--model"])
            .arg(p)
            .arg("--out")
            .arg(dir.join("fm"))
            .arg(&photo));
        assert!(!o.status.success(), "{}", p.display());
        assert!(stderr(&o).contains(what), "{}: {}", p.display(), stderr(&o));
    }
}

#[test]
fn contradictory_arguments_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("l.csv");
    std::fs::write(&csv, "frame,timestamp,success,confidence\n").unwrap();
    let map = tmp.path().join("map.json");
    std::fs::write(&map, "[]").unwrap();
    let o = run(facecap()
        .args(["capture", "--landmark-map"])
        .arg(&map)
        .arg("--out")
        .arg(tmp.path().join("o"))
        .arg("x.y4m"));
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--landmark-map") && stderr(&o).contains("without --rig"),
        "{}",
        stderr(&o)
    );
    let o = run(facecap()
        .args(["solve", "--method", "exact", "--landmark-map"])
        .arg(&map)
        .arg("--out")
        .arg(tmp.path().join("o"))
        .arg(&csv));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("without --rig"), "{}", stderr(&o));
    let o = run(facecap()
        .args(["solve", "--method", "exact", "--shapes", "jawOpen,jawOpen", "--out"])
        .arg(tmp.path().join("o"))
        .arg(&csv));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("listed twice"), "{}", stderr(&o));
}
