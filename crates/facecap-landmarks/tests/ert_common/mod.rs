//! Shared helpers of the ERT integration tests: seeded synthetic models and images.
#![allow(dead_code)]

use facecap_landmarks::ert::{ErtModel, RegressionTree, SplitFeature};
use image::GrayImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A random but valid model: `parts` landmarks on a jittered circle inside the unit
/// box, `cascades` x `trees` complete trees of `depth`, `features` pixels per cascade.
pub fn synthetic_model(
    seed: u64,
    parts: usize,
    cascades: usize,
    trees: usize,
    depth: u32,
    features: usize,
) -> ErtModel {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut initial_shape = Vec::with_capacity(2 * parts);
    for i in 0..parts {
        let a = i as f32 / parts as f32 * std::f32::consts::TAU;
        initial_shape.push(0.5 + 0.35 * a.cos() + rng.random_range(-0.05..0.05));
        initial_shape.push(0.55 + 0.35 * a.sin() + rng.random_range(-0.05..0.05));
    }
    let n_splits = (1usize << depth) - 1;
    let mut forests = Vec::new();
    let mut anchor_idx = Vec::new();
    let mut deltas = Vec::new();
    for _ in 0..cascades {
        let mut ts = Vec::new();
        for _ in 0..trees {
            let splits = (0..n_splits)
                .map(|_| SplitFeature {
                    idx1: rng.random_range(0..features as u64),
                    idx2: rng.random_range(0..features as u64),
                    thresh: rng.random_range(-60.0..60.0),
                })
                .collect();
            let leaf_values = (0..=n_splits)
                .map(|_| (0..2 * parts).map(|_| rng.random_range(-0.004f32..0.004)).collect())
                .collect();
            ts.push(RegressionTree { splits, leaf_values });
        }
        forests.push(ts);
        anchor_idx.push((0..features).map(|_| rng.random_range(0..parts as u64)).collect());
        deltas.push(
            (0..features)
                .map(|_| [rng.random_range(-0.15f32..0.15), rng.random_range(-0.15f32..0.15)])
                .collect(),
        );
    }
    ErtModel {
        initial_shape,
        forests,
        anchor_idx,
        deltas,
    }
}

/// A seeded smooth-ish random grey image (sum of random blobs plus noise).
pub fn synthetic_image(seed: u64, w: u32, h: u32) -> GrayImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let blobs: Vec<(f32, f32, f32, f32)> = (0..12)
        .map(|_| {
            (
                rng.random_range(0.0..w as f32),
                rng.random_range(0.0..h as f32),
                rng.random_range(10.0..80.0),
                rng.random_range(-120.0..120.0),
            )
        })
        .collect();
    let mut img = GrayImage::new(w, h);
    for (x, y, p) in img.enumerate_pixels_mut() {
        let mut v = 128.0;
        for &(bx, by, r, a) in &blobs {
            let d2 = ((x as f32 - bx).powi(2) + (y as f32 - by).powi(2)) / (r * r);
            v += a * (-d2).exp();
        }
        v += rng.random_range(-10.0..10.0);
        p.0[0] = v.clamp(0.0, 255.0) as u8;
    }
    img
}
