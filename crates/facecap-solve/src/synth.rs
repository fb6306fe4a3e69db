//! Seeded synthetic ground truth for tests, examples and benches.
//!
//! A frame = random sparse weights (2-5 active shapes, each `U(0.2, 1)`), a random head pose
//! (yaw `U(-30, 30)` deg, pitch `U(-20, 20)` deg, roll `U(-10, 10)` deg), the face placed so it
//! spans about 35 % of the image width, projected by a pinhole camera, plus `N(0, noise^2)` px
//! per coordinate.

use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use nalgebra::{Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::rig::BlendshapeRig;

/// One synthetic frame with its ground truth.
#[derive(Debug, Clone)]
pub struct SynthFrame {
    /// True weights.
    pub weights: Vec<f64>,
    /// True pose.
    pub pose: ModelToCamera,
    /// Noisy observed landmarks (px). Unmapped landmarks are set to the image centre.
    pub landmarks: Landmarks68,
    /// Noise-free projections (px).
    pub clean: Landmarks68,
}

/// Pose ranges and noise of [`generate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SynthParams {
    /// Max |yaw| (deg).
    pub max_yaw_deg: f64,
    /// Max |pitch| (deg).
    pub max_pitch_deg: f64,
    /// Max |roll| (deg).
    pub max_roll_deg: f64,
    /// Landmark noise standard deviation (px).
    pub noise_px: f64,
    /// Number of active shapes per frame, inclusive range.
    pub active: (usize, usize),
}

impl Default for SynthParams {
    fn default() -> Self {
        SynthParams {
            max_yaw_deg: 30.0,
            max_pitch_deg: 20.0,
            max_roll_deg: 10.0,
            noise_px: 0.0,
            active: (2, 5),
        }
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    // Box-Muller
    let u1: f64 = rng.random_range(1e-12..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Face width of the rig's mapped landmarks (model units).
fn face_width(rig: &BlendshapeRig) -> f64 {
    let xs = (0..NUM_LANDMARKS)
        .filter(|&l| rig.mapped[l])
        .map(|l| rig.neutral[[l, 0]]);
    let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    (hi - lo).max(1e-9)
}

/// Camera depth at which the face spans ~35 % of the image width, and the model centre
/// (the mapped landmarks' mean), shared by [`generate`] and [`trajectory`].
fn framing(rig: &BlendshapeRig, camera: &Intrinsics, width: f64) -> (f64, Vector3<f64>) {
    let depth = camera.fx * face_width(rig) / (0.35 * width);
    let mut centre = Vector3::zeros();
    let mut cnt = 0.0;
    for l in 0..NUM_LANDMARKS {
        if rig.mapped[l] {
            centre += Vector3::new(rig.neutral[[l, 0]], rig.neutral[[l, 1]], rig.neutral[[l, 2]]);
            cnt += 1.0;
        }
    }
    (depth, centre / cnt)
}

/// Generates `count` frames (seeded) for `rig` seen by `camera` in a `width`-pixel-wide image.
pub fn generate(
    rig: &BlendshapeRig,
    camera: &Intrinsics,
    width: f64,
    params: &SynthParams,
    count: usize,
    seed: u64,
) -> Vec<SynthFrame> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = rig.num_shapes();
    let (depth, centre) = framing(rig, camera, width);
    let mut frames = Vec::with_capacity(count);
    for _ in 0..count {
        let mut w = vec![0.0; n];
        let na = rng
            .random_range(params.active.0..=params.active.1.max(params.active.0))
            .min(n);
        for _ in 0..na {
            let k = rng.random_range(0..n);
            w[k] = rng.random_range(0.2..1.0);
        }
        let yaw = rng.random_range(-params.max_yaw_deg..=params.max_yaw_deg).to_radians();
        let pitch = rng
            .random_range(-params.max_pitch_deg..=params.max_pitch_deg)
            .to_radians();
        let roll = rng
            .random_range(-params.max_roll_deg..=params.max_roll_deg)
            .to_radians();
        // model +Y up / +Z to viewer -> camera +Y down / +Z forward: rotate pi about X first
        let flip = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let head = Rotation3::from_euler_angles(pitch, yaw, roll);
        let r = flip * head;
        let offset = Vector3::new(
            rng.random_range(-0.05..0.05) * depth,
            rng.random_range(-0.05..0.05) * depth,
            depth,
        );
        let t = offset - r * centre;
        let pose = ModelToCamera::from_rvec_tvec(r.scaled_axis(), t);
        let mut clean = Landmarks68::default();
        let mut noisy = Landmarks68::default();
        for l in 0..NUM_LANDMARKS {
            if !rig.mapped[l] {
                clean.points[l] = nalgebra::Point2::new(camera.cx, camera.cy);
                noisy.points[l] = clean.points[l];
                continue;
            }
            let p = rig.landmark(l, &w);
            let q = pose
                .project(camera, &p)
                .unwrap_or(nalgebra::Point2::new(camera.cx, camera.cy));
            clean.points[l] = q;
            noisy.points[l] = nalgebra::Point2::new(
                q.x + params.noise_px * normal(&mut rng),
                q.y + params.noise_px * normal(&mut rng),
            );
        }
        frames.push(SynthFrame {
            weights: w,
            pose,
            landmarks: noisy,
            clean,
        });
    }
    frames
}

/// Root-mean-square difference of two weight vectors.
pub fn rmse(a: &[f64], b: &[f64]) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (s / a.len().max(1) as f64).sqrt()
}

/// A smooth sequence of `count` frames (30 fps tracking-like): 4 shapes following
/// `max(0, sin(0.15 t + phase))`, head yaw `20 sin(0.05 t)` deg and pitch `8 sin(0.07 t)` deg,
/// plus `noise_px` landmark noise. For warm-start benches and jitter measurements.
pub fn trajectory(
    rig: &BlendshapeRig,
    camera: &Intrinsics,
    width: f64,
    noise_px: f64,
    count: usize,
    seed: u64,
) -> Vec<SynthFrame> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = rig.num_shapes();
    let active: Vec<(usize, f64)> = (0..4.min(n))
        .map(|_| (rng.random_range(0..n), rng.random_range(0.0..std::f64::consts::TAU)))
        .collect();
    let (depth, centre) = framing(rig, camera, width);
    let flip = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    (0..count)
        .map(|t| {
            let tf = t as f64;
            let mut w = vec![0.0; n];
            for &(k, ph) in &active {
                w[k] = (0.15 * tf + ph).sin().max(0.0);
            }
            let head = Rotation3::from_euler_angles(
                (8.0 * (0.07 * tf).sin()).to_radians(),
                (20.0 * (0.05 * tf).sin()).to_radians(),
                0.0,
            );
            let r = flip * head;
            let t_vec = Vector3::new(0.0, 0.0, depth) - r * centre;
            let pose = ModelToCamera::from_rvec_tvec(r.scaled_axis(), t_vec);
            let mut clean = Landmarks68::default();
            let mut noisy = Landmarks68::default();
            for l in 0..NUM_LANDMARKS {
                let q = if rig.mapped[l] {
                    pose.project(camera, &rig.landmark(l, &w))
                        .unwrap_or(nalgebra::Point2::new(camera.cx, camera.cy))
                } else {
                    nalgebra::Point2::new(camera.cx, camera.cy)
                };
                clean.points[l] = q;
                noisy.points[l] =
                    nalgebra::Point2::new(q.x + noise_px * normal(&mut rng), q.y + noise_px * normal(&mut rng));
            }
            SynthFrame {
                weights: w,
                pose,
                landmarks: noisy,
                clean,
            }
        })
        .collect()
}
