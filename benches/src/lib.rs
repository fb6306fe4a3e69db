//! Inputs of the workspace benchmarks (`benches/frame.rs`): a short colour clip of a real
//! face made from the model cache's astronaut photo (NASA, public domain; installed by
//! `scripts/setup.sh`), moving a little from frame to frame so that the tracker tracks.

use std::path::{Path, PathBuf};

/// Frames in the benchmark clip.
pub const CLIP_FRAMES: usize = 30;

/// Writes `CLIP_FRAMES` frames (480x480 crops of the photo sliding by up to 6 px, 30 fps,
/// Y4M 4:4:4) into `dir`, or `None` when the photo is not in the model cache.
pub fn face_clip(dir: &Path) -> Option<PathBuf> {
    let photo = facecap_core::paths::cache_dir()?.join("data/astronaut.png");
    let img = image::open(&photo).ok()?.to_rgb8();
    let frames: Vec<image::RgbImage> = (0..CLIP_FRAMES)
        .map(|i| {
            let t = i as f64 / CLIP_FRAMES as f64 * std::f64::consts::TAU;
            let dx = (3.0 + 3.0 * t.sin()).round() as u32;
            let dy = (3.0 + 3.0 * t.cos()).round() as u32;
            image::imageops::crop_imm(&img, 10 + dx, dy, 480, 480).to_image()
        })
        .collect();
    let mut bytes = Vec::new();
    facecap_io::video::y4m::write_rgb_y4m(&mut bytes, &frames, 30).ok()?;
    let path = dir.join("face.y4m");
    std::fs::write(&path, bytes).ok()?;
    Some(path)
}
