//! `facecap info` through the built binary.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;
use std::process::{Command, Output, Stdio};

use image::{GrayImage, Luma};

fn facecap(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_facecap"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap()
}

fn make_y4m(dir: &Path) -> std::path::PathBuf {
    let frames: Vec<GrayImage> = (0..5u8)
        .map(|k| GrayImage::from_fn(33, 17, |x, y| Luma([16 + k * 10 + (x + y) as u8])))
        .collect();
    let mut bytes = Vec::new();
    facecap_io::video::y4m::write_gray_y4m(&mut bytes, &frames, 25, 1, false).unwrap();
    let p = dir.join("clip.y4m");
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn info_text_on_a_y4m() {
    let dir = tempfile::tempdir().unwrap();
    let p = make_y4m(dir.path());
    let out = facecap(&["info".as_ref(), p.as_os_str()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("frames decoded:     5"), "{stdout}");
    assert!(stdout.contains("resolution:         33x17"), "{stdout}");
    assert!(stdout.contains("fps:                25"), "{stdout}");
    assert!(stdout.contains("duration:           0.200 s"), "{stdout}");
    assert!(stdout.contains("codec:              y4m 420jpeg"), "{stdout}");
}

#[test]
fn info_json_on_a_y4m() {
    let dir = tempfile::tempdir().unwrap();
    let p = make_y4m(dir.path());
    let out = facecap(&["info".as_ref(), "--json".as_ref(), p.as_os_str()]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["frames_decoded"], 5);
    assert_eq!(v["width"], 33);
    assert_eq!(v["height"], 17);
    assert_eq!(v["fps"], 25.0);
    assert_eq!(v["source"], "y4m");
    assert!((v["duration_s"].as_f64().unwrap() - 0.2).abs() < 1e-9);
}

#[test]
fn info_on_shared_clip_matches_ffprobe_numbers() {
    let Some(p) = facecap_core::paths::shared_data_file("info_on_shared_clip", "videos/liveportrait_d9.mp4") else {
        return;
    };
    if let Err(e) = facecap_io::video::ffmpeg::locate_ffmpeg(None) {
        facecap_core::paths::skip(&format!("info_on_shared_clip: {e}"));
        return;
    }
    let out = facecap(&["info".as_ref(), "--json".as_ref(), p.as_os_str()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["frames_decoded"], 587);
    assert_eq!((v["width"].as_u64(), v["height"].as_u64()), (Some(512), Some(480)));
    assert_eq!(v["codec"], "h264");
    assert_eq!(v["fps"], 30.0);
    // ffprobe: stream duration 19.566667 s.
    assert!((v["duration_s"].as_f64().unwrap() - 19.566667).abs() < 1e-5, "{v}");
}

#[test]
fn info_errors_name_the_file_and_fail() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.mp4");
    let out = facecap(&["info".as_ref(), missing.as_os_str()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope.mp4"), "{err}");

    let empty = dir.path().join("empty_folder");
    std::fs::create_dir(&empty).unwrap();
    let out = facecap(&["info".as_ref(), empty.as_os_str()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("empty_folder") && err.contains("no images"), "{err}");
}
