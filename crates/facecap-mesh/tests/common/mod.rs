//! Helpers shared by the integration tests: fixture inputs rebuilt exactly as
//! `testdata/mesh/make_tflite_fixtures.py` makes them.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use sha2::{Digest, Sha256};
use std::path::PathBuf;

pub fn testdata(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../testdata/mesh")
        .join(name)
}

pub fn fixture(name: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(testdata(name)).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// `v = (3x + 5y + 50c + (x*y) // 37) % 256`, HWC.
pub fn pattern(n: usize) -> Vec<u8> {
    let mut v = Vec::with_capacity(n * n * 3);
    for y in 0..n {
        for x in 0..n {
            for c in 0..3 {
                v.push(((3 * x + 5 * y + 50 * c + (x * y) / 37) % 256) as u8);
            }
        }
    }
    v
}

/// The first `n` RGB frames of a shared clip (see [`clip_frame`]).
pub fn clip_frames(test: &str, clip: &str, n: u64) -> Option<Vec<image::RgbImage>> {
    let path = facecap_core::paths::shared_data_file(test, clip)?;
    let info = facecap_io::video::open_source(&path, &Default::default())
        .unwrap()
        .info()
        .clone();
    let (w, h) = (info.width, info.height);
    let out = std::process::Command::new("ffmpeg")
        .args(["-nostdin", "-hide_banner", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-map", "0:V:0", "-frames:v", &n.to_string()])
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
        .output();
    let out = match out {
        Ok(o) if o.status.success() => o.stdout,
        _ => {
            facecap_core::paths::skip(&format!("{test}: ffmpeg not runnable"));
            return None;
        }
    };
    let size = (w * h * 3) as usize;
    Some(
        out.chunks_exact(size)
            .map(|c| image::RgbImage::from_raw(w, h, c.to_vec()).unwrap())
            .collect(),
    )
}

/// RGB frame `index` of a shared clip decoded by `ffmpeg` on PATH to rgb24 (the same
/// command as the fixture script), or `None` (with a SKIP line) when absent.
pub fn clip_frame(test: &str, clip: &str, index: u64) -> Option<image::RgbImage> {
    let path = facecap_core::paths::shared_data_file(test, clip)?;
    let info = facecap_io::video::open_source(&path, &Default::default())
        .unwrap()
        .info()
        .clone();
    let (w, h) = (info.width, info.height);
    let out = std::process::Command::new("ffmpeg")
        .args(["-nostdin", "-hide_banner", "-loglevel", "error", "-i"])
        .arg(&path)
        .args(["-map", "0:V:0", "-frames:v", &(index + 1).to_string()])
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
        .output();
    let out = match out {
        Ok(o) if o.status.success() => o.stdout,
        _ => {
            facecap_core::paths::skip(&format!("{test}: ffmpeg not runnable"));
            return None;
        }
    };
    let size = (w * h * 3) as usize;
    let bytes = out[index as usize * size..(index as usize + 1) * size].to_vec();
    image::RgbImage::from_raw(w, h, bytes)
}

/// Square crop `[x0, x0 + size)^2` resampled to `n x n` by nearest neighbour.
pub fn crop_nearest(img: &image::RgbImage, x0: usize, y0: usize, size: usize, n: usize) -> Vec<u8> {
    let idx: Vec<usize> = (0..n).map(|i| (2 * i + 1) * size / (2 * n)).collect();
    let w = img.width() as usize;
    let raw = img.as_raw();
    let mut v = Vec::with_capacity(n * n * 3);
    for &iy in &idx {
        for &ix in &idx {
            let p = ((y0 + iy) * w + x0 + ix) * 3;
            v.extend_from_slice(&raw[p..p + 3]);
        }
    }
    v
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// The u8 input of a fixture case (pattern or clip crop), `None` when data is absent.
pub fn case_input(test: &str, case: &serde_json::Value, n: usize) -> Option<Vec<u8>> {
    let img = match case["source"].as_array() {
        None => pattern(n),
        Some(s) => {
            let clip = s[0].as_str().unwrap();
            let frame = clip_frame(test, clip, s[1].as_u64().unwrap())?;
            let g = |i: usize| s[i].as_u64().unwrap() as usize;
            crop_nearest(&frame, g(2), g(3), g(4), n)
        }
    };
    let want = case["input_sha256"].as_str().unwrap();
    assert_eq!(
        sha256_hex(&img),
        want,
        "{}: rebuilt input differs from the fixture's (different ffmpeg decode?)",
        case["name"]
    );
    Some(img)
}

pub fn floats(v: &serde_json::Value) -> Vec<f32> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

/// A model from the cache, or `None` with a SKIP line.
pub fn model(test: &str, name: &str) -> Option<PathBuf> {
    facecap_core::paths::model_file_or_skip(test, name)
}

/// A tracker with `params` on the cached models, or `None` (with a SKIP line naming
/// `test`) when they are absent.
pub fn tracker(test: &str, params: facecap_mesh::MeshParams) -> Option<facecap_mesh::MeshTracker> {
    let det = model(test, facecap_mesh::FACE_DETECTOR_MODEL)?;
    let lm = model(test, facecap_mesh::FACE_LANDMARKS_MODEL)?;
    Some(facecap_mesh::MeshTracker::new(facecap_mesh::MeshModels::load(&det, &lm).unwrap(), params).unwrap())
}
