//! `facecap synth`: a ground-truth video made from a real face photo.
//!
//! 1. The photo (by default the public-domain NASA astronaut portrait from the
//!    scikit-image wheel, fetched by `scripts/setup.sh`) gets its 68 landmarks from
//!    our detector and ERT.
//! 2. The default rig's 68 landmark points are posed by a known sequence of
//!    blendshape weights and head rotations; the pose of frame 0 is fitted to the
//!    photo by PnP (default camera). The photo's landmarks become a 3D face: each is
//!    lifted onto its camera ray at the depth of the rig's neutral point, `Y_i =
//!    X_i(0) + d_i` with `pi(pose_0, Y_i) = p_i`, so the subject's own shape (the
//!    offsets `d_i`, in model axes) turns with the head as a real face does. Each
//!    frame's target landmarks are `u_i(t) = pi(pose_0 R_t, X_i(w_t) + d_i)`.
//! 3. The photo is warped piecewise-affinely (Delaunay over the landmarks plus fixed
//!    anchors on an ellipse around the face and on the image border) so the landmarks
//!    land on the targets; the eyes close as real eyes do (the eyeball stays, the lids
//!    cover it, see [`crate::eyelid`]), and the frames are written as a 4:4:4 Y4M video.
//! 4. The truth goes beside it: `<stem>.truth.csv` (per frame: 68 landmarks, the head
//!    rotation relative to frame 0 as `rel_Rx, rel_Ry, rel_Rz` in radians with
//!    `R = Rz Ry Rx` in model axes, and the weights by name). `facecap capture` finds it
//!    next to the video and reports its errors against it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_geom::pnp::{solve_pnp, PnpParams};
use facecap_io::csv::{landmark_columns, FrameCsvWriter, FrameRow};
use image::{GrayImage, RgbImage};
use nalgebra::{Point2, Point3, Rotation3, Vector3};

use crate::default_rig::{DEFAULT_SHAPES, MEAN_FACE_68_CM};
use crate::eyelid::{close_eye, cover_eyes, eye_points, Affine, Lids, EYES};

/// Arguments of `facecap synth`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  facecap synth --out demo/ --frames 90 --seed 0")]
pub struct Args {
    /// Face photo (default: the astronaut portrait in the model cache).
    #[arg(long)]
    pub photo: Option<PathBuf>,
    /// Output folder (created).
    #[arg(long, default_value = "synth")]
    pub out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 90)]
    pub frames: u32,
    /// Frames per second.
    #[arg(long, default_value_t = 30)]
    pub fps: u32,
    /// Seed of the expression phases.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// File name of the default photo in the cache.
pub const ASTRONAUT: &str = "astronaut.png";

/// Where the default photo is looked for: `$FACECAP_CACHE/data`, then the model folder.
pub fn default_photo() -> Option<PathBuf> {
    let mut c = Vec::new();
    if let Some(d) = facecap_core::paths::cache_dir() {
        c.push(d.join("data").join(ASTRONAUT));
        c.push(d.join(ASTRONAUT));
    }
    if let Some(d) = facecap_core::paths::model_dir() {
        c.push(d.join(ASTRONAUT));
    }
    c.into_iter().find(|p| p.is_file())
}

/// Finds the largest face and its 68 landmarks in a grey image.
pub fn detect_landmarks(gray: &GrayImage) -> anyhow::Result<Option<Landmarks68>> {
    let detector = facecap_landmarks::detect::FaceDetector::default_model()?;
    let mut dws = detector.new_workspace();
    let faces = detector.detect(gray, &mut dws)?;
    let Some(face) = faces.first() else { return Ok(None) };
    let model = facecap_core::paths::model_file(facecap_core::paths::DLIB_68_MODEL).ok_or_else(|| {
        anyhow::anyhow!(
            "{} not in the model cache: run scripts/setup.sh",
            facecap_core::paths::DLIB_68_MODEL
        )
    })?;
    let ert = facecap_landmarks::ert::ShapePredictor::from_file_cached(&model)?
        .0
        .with_params(facecap_landmarks::ert::ErtParams {
            output: facecap_landmarks::ert::OutputPrecision::SubPixel,
            ..Default::default()
        });
    let mut ws = ert.new_workspace();
    let mut pts = vec![Point2::origin(); ert.num_parts()];
    ert.predict_into(gray, &face.rect, &mut ws, &mut pts)?;
    let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.x, p.y)).collect();
    Ok(Some(Landmarks68::from_slice(&xy)?))
}

/// Seconds of neutral face (all weights zero) at the start of the clip, as a
/// capture session starts (what `facecap capture --neutral auto` calibrates on).
pub const NEUTRAL_HOLD_S: f64 = 0.4;

/// The known weight sequence: a neutral hold of [`NEUTRAL_HOLD_S`], then smooth,
/// partly overlapping activations.
pub fn truth_weights(frame: u32, fps: u32, seed: u64) -> Vec<f64> {
    let t = frame as f64 / fps as f64;
    if t < NEUTRAL_HOLD_S {
        return vec![0.0; DEFAULT_SHAPES.len()];
    }
    let phase = |k: u64| ((seed.wrapping_mul(2654435761).wrapping_add(k * 40503)) % 1000) as f64 / 1000.0;
    let bump = |period: f64, k: u64, amp: f64| {
        amp * (2.0 * std::f64::consts::PI * (t / period + phase(k)))
            .sin()
            .max(0.0)
            .powf(1.5)
    };
    let mut w = vec![0.0; DEFAULT_SHAPES.len()];
    for (i, name) in DEFAULT_SHAPES.iter().enumerate() {
        w[i] = match *name {
            "jawOpen" => bump(2.6, 1, 0.8),
            "mouthSmileLeft" | "mouthSmileRight" => bump(3.1, 2, 0.7),
            "browInnerUp" => bump(2.2, 3, 0.7),
            "eyeBlinkLeft" | "eyeBlinkRight" => bump(1.7, 4, 1.0).powi(4),
            "mouthPucker" => bump(3.7, 5, 0.5),
            _ => 0.0,
        };
    }
    w
}

/// The known head rotation relative to frame 0 (model axes; radians `(rx, ry, rz)`).
pub fn truth_rotation(frame: u32, fps: u32) -> (f64, f64, f64) {
    let t = frame as f64 / fps as f64;
    let tau = 2.0 * std::f64::consts::PI;
    (
        6f64.to_radians() * (tau * t / 2.3).sin(),
        12f64.to_radians() * (tau * t / 3.0).sin(),
        4f64.to_radians() * (tau * t / 4.1).sin(),
    )
}

fn rig_points(weights: &[f64], rig: &facecap_core::mesh::MorphMesh, map: &LandmarkMap) -> Vec<Point3<f64>> {
    (0..NUM_LANDMARKS)
        .map(|i| {
            let mut p = Vector3::new(MEAN_FACE_68_CM[i][0], MEAN_FACE_68_CM[i][1], MEAN_FACE_68_CM[i][2]);
            let v = map.vertices[i].map_or(0, |v| v as usize);
            for (t, w) in rig.targets.iter().zip(weights) {
                p += t.deltas[v].cast::<f64>() * *w;
            }
            Point3::from(p)
        })
        .collect()
}

/// Runs `facecap synth`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let photo = match args.photo.clone() {
        Some(p) => p,
        None => default_photo().ok_or_else(|| {
            anyhow::anyhow!("no photo given and {ASTRONAUT} is not in the cache: run scripts/setup.sh or pass --photo")
        })?,
    };
    let paths = make_synth(&photo, &args.out, args.frames, args.fps, args.seed)?;
    outln!("wrote {} and {}", paths.0.display(), paths.1.display());
    Ok(std::process::ExitCode::SUCCESS)
}

/// Makes the video and truth; returns their paths.
pub fn make_synth(photo: &Path, out: &Path, frames: u32, fps: u32, seed: u64) -> anyhow::Result<(PathBuf, PathBuf)> {
    if !(1..=10_000).contains(&frames) {
        anyhow::bail!("--frames must be in 1..=10000, got {frames}");
    }
    if !(1..=240).contains(&fps) {
        anyhow::bail!("--fps must be in 1..=240, got {fps}");
    }
    let rgb = facecap_io::image_io::load_rgb(photo)?;
    let mut gray = GrayImage::new(rgb.width(), rgb.height());
    facecap_io::image_io::rgb_to_gray_into(&rgb, &mut gray);
    let lms = detect_landmarks(&gray)?.ok_or_else(|| anyhow::anyhow!("no face found in {}", photo.display()))?;
    let (rig, map) = crate::default_rig::default_rig()?;
    let k = Intrinsics::default_for_frame(rgb.width(), rgb.height())?;
    let neutral = rig_points(&vec![0.0; rig.targets.len()], &rig, &map);
    let (pose0, _) = solve_pnp(&neutral, &lms.points, &k, None, &PnpParams::default())?;
    let centre = neutral.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / neutral.len() as f64;
    // The subject's shape in model axes: the photo's landmark on its camera ray, at the
    // camera depth of the rig's neutral point, minus that point.
    let identity: Vec<Vector3<f64>> = neutral
        .iter()
        .zip(&lms.points)
        .map(|(x, p)| {
            let z = pose0.transform(x).z;
            let on_ray = Point3::new((p.x - k.cx) / k.fx * z, (p.y - k.cy) / k.fy * z, z);
            pose0.0.inverse_transform_point(&on_ray) - x
        })
        .collect();

    // Anchors: an ellipse around the face and the image border stay fixed.
    let bb = lms.bounding_box();
    let (cx, cy) = (bb.left + bb.width / 2.0, bb.top + bb.height / 2.0);
    let mut src_pts: Vec<(f64, f64)> = lms.points.iter().map(|p| (p.x, p.y)).collect();
    const ELLIPSE_ANCHORS: usize = 16;
    for a in 0..ELLIPSE_ANCHORS {
        let th = a as f64 / ELLIPSE_ANCHORS as f64 * std::f64::consts::TAU;
        src_pts.push((
            cx + 0.95 * bb.width * th.cos(),
            cy - 0.1 * bb.height + 1.0 * bb.height * th.sin(),
        ));
    }
    let (w, h) = (rgb.width() as f64 - 1.0, rgb.height() as f64 - 1.0);
    src_pts.extend_from_slice(&[
        (0.0, 0.0),
        (w / 2.0, 0.0),
        (w, 0.0),
        (w, h / 2.0),
        (w, h),
        (w / 2.0, h),
        (0.0, h),
        (0.0, h / 2.0),
    ]);
    let tris = facecap_geom::delaunay::delaunay(&src_pts);
    // Closing eyes: the warp stretches lid skin over the eyes (`covered`), the eyeball
    // of the photo is drawn back inside each frame's lid opening (see `crate::eyelid`).
    let photo_lids: Vec<Option<Lids>> = (0..EYES.len()).map(|e| Lids::new(&eye_points(&src_pts, e))).collect();
    let covered = cover_eyes(&rgb, &photo_lids.iter().flatten().copied().collect::<Vec<_>>());

    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let stem = "synth";
    let video_path = out.join(format!("{stem}.y4m"));
    let truth_path = out.join(format!("{stem}.truth.csv"));
    let mut columns = landmark_columns();
    columns.extend(["rel_Rx", "rel_Ry", "rel_Rz"].map(String::from));
    columns.extend(DEFAULT_SHAPES.iter().map(|s| s.to_string()));
    let mut truth = FrameCsvWriter::create(&truth_path, &columns)?;
    let mut images = Vec::with_capacity(frames as usize);
    let mut values = vec![0.0; columns.len()];
    for f in 0..frames {
        let wts = truth_weights(f, fps, seed);
        let (rx, ry, rz) = truth_rotation(f, fps);
        let r_delta = Rotation3::from_euler_angles(rx, ry, rz);
        let pts = rig_points(&wts, &rig, &map);
        let mut dst = src_pts.clone();
        // The landmarks moved by the head alone (all weights zero).
        let mut rest = src_pts.clone();
        for i in 0..NUM_LANDMARKS {
            let image_of = |x: &Point3<f64>| {
                let moved = Point3::from(r_delta * (x.coords + identity[i] - centre) + centre);
                let p = ModelToCamera::project(&pose0, &k, &moved)
                    .ok_or_else(|| anyhow::anyhow!("synthetic head left the camera's view at frame {f}"))?;
                anyhow::Ok((p.x, p.y))
            };
            dst[i] = image_of(&pts[i])?;
            rest[i] = image_of(&neutral[i])?;
            values[i] = dst[i].0;
            values[NUM_LANDMARKS + i] = dst[i].1;
        }
        values[2 * NUM_LANDMARKS] = rx;
        values[2 * NUM_LANDMARKS + 1] = ry;
        values[2 * NUM_LANDMARKS + 2] = rz;
        values[2 * NUM_LANDMARKS + 3..].copy_from_slice(&wts);
        let mut img = RgbImage::new(1, 1);
        crate::warp::warp_piecewise_affine(&covered, &src_pts, &dst, &tris, &mut img);
        for (e, photo_l) in photo_lids.iter().enumerate() {
            let (rest_e, photo_e) = (eye_points(&rest, e), eye_points(&src_pts, e));
            if let (Some(l), Some(a)) = (photo_l, Affine::fit(&rest_e, &photo_e)) {
                close_eye(&mut img, &rgb, l, &eye_points(&dst, e), &a);
            }
        }
        images.push(img);
        truth.write_row(&FrameRow {
            frame: f as u64,
            timestamp: f as f64 / fps as f64,
            success: true,
            confidence: 1.0,
            values: &values,
        })?;
    }
    facecap_core::atomic::write_atomic(&video_path, |w| facecap_io::video::y4m::write_rgb_y4m(w, &images, fps))?;
    truth.finish()?;
    Ok((video_path, truth_path))
}
