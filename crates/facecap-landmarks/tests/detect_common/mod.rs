//! Shared helpers of the detector's dlib fixture tests: decoding as the fixture scripts
//! do (ffmpeg to rgb24) and their grey rule.
#![allow(dead_code)]

use std::path::Path;
use std::process::Command;

use image::{GrayImage, RgbImage};

/// Whether the ffmpeg CLI runs.
pub fn have_ffmpeg() -> bool {
    Command::new("ffmpeg").arg("-version").output().is_ok()
}

/// Frames of `path` decoded by ffmpeg to rgb24 (`video_select = (step, n)`: every
/// `step`-th frame, at most `n`), as `testdata/dlib_hog/make_fixture.py` decodes them.
pub fn ffmpeg_rgb(path: &Path, video_select: Option<(u32, u32)>, w: u32, h: u32) -> Option<Vec<RgbImage>> {
    let mut cmd = Command::new("ffmpeg");
    cmd.args(["-nostdin", "-loglevel", "error", "-i"]).arg(path);
    if let Some((step, n)) = video_select {
        cmd.args([
            "-vf",
            &format!("select=not(mod(n\\,{step}))"),
            "-fps_mode",
            "passthrough",
            "-frames:v",
            &n.to_string(),
        ]);
    }
    cmd.args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"]);
    let out = cmd.output().ok()?;
    if !out.status.success() {
        return None;
    }
    let sz = (w * h * 3) as usize;
    out.stdout
        .chunks_exact(sz)
        .map(|c| RgbImage::from_raw(w, h, c.to_vec()))
        .collect()
}

/// The fixtures' grey rule: `(2126 R + 7152 G + 722 B) / 10000` (integer division).
pub fn to_grey(rgb: &RgbImage) -> GrayImage {
    GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let p = rgb.get_pixel(x, y).0;
        let v = (2126 * u32::from(p[0]) + 7152 * u32::from(p[1]) + 722 * u32::from(p[2])) / 10000;
        image::Luma([v as u8])
    })
}

/// Sum of the grey pixels (the fixtures store it to prove both sides saw the same input).
pub fn grey_sum(grey: &GrayImage) -> u64 {
    grey.as_raw().iter().map(|&v| u64::from(v)).sum()
}
