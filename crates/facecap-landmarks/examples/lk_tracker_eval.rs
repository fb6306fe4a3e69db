#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Evaluates the video landmark tracker (numbers for `docs/tracking.md`):
//!
//! * throughput of the tracker alone (decode excluded, one thread) on every shared clip;
//! * face share and mean distance to dlib-per-frame landmarks (fixture
//!   `testdata/dlib_track/fixture.json`);
//! * jitter on a still segment: one shared frame repeated 150 times with seeded
//!   Gaussian sensor noise (sigma 2 grey levels);
//! * lag on a moving segment: the same frame translated by 3 px/frame (bilinear
//!   resampling) for 60 frames.
//!
//! Filter off and One Euro on. Run: `cargo run --release -p facecap-landmarks --example lk_tracker_eval`
//! (needs the shared data, the dlib models and ffmpeg).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::tracker::one_euro::OneEuroParams;
use facecap_landmarks::tracker::{ErtInit, LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
use image::GrayImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr_free::gauss;

mod rand_distr_free {
    use rand::Rng;
    /// Standard normal sample (Box-Muller), to avoid another dependency.
    pub fn gauss(rng: &mut impl Rng) -> f64 {
        let u1: f64 = rng.random_range(f64::EPSILON..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

fn decode_gray(path: &Path) -> Vec<GrayImage> {
    let probe = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height",
            "-of",
            "csv=p=0",
        ])
        .arg(path)
        .output()
        .unwrap();
    let s = String::from_utf8(probe.stdout).unwrap();
    let mut it = s.trim().split(',').map(|v| v.parse::<u32>().unwrap());
    let (w, h) = (it.next().unwrap(), it.next().unwrap());
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-i"])
        .arg(path)
        .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"])
        .output()
        .unwrap();
    out.stdout
        .chunks_exact((w * h) as usize)
        .map(|c| GrayImage::from_raw(w, h, c.to_vec()).unwrap())
        .collect()
}

#[derive(serde::Deserialize)]
struct Fixture {
    clips: Vec<Clip>,
}
#[derive(serde::Deserialize)]
struct Clip {
    clip: String,
    frames: Vec<Option<DlibFrame>>,
}
#[derive(serde::Deserialize)]
struct DlibFrame {
    pts: Vec<f64>,
}

type Tracker = LandmarkTracker<FaceDetector, ShapePredictor>;

/// Tracked frames, seconds, detector runs and LK frames.
fn run(tracker: &Tracker, frames: &[GrayImage]) -> (Vec<TrackedFrame>, f64, usize, usize) {
    let mut ws = tracker.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();
    let mut res = Vec::with_capacity(frames.len());
    let (mut dets, mut lk) = (0, 0);
    let t0 = Instant::now();
    let mut secs = 0.0;
    for (k, f) in frames.iter().enumerate() {
        let t = Instant::now();
        let rep = tracker
            .track_into(f, k as f64 / 30.0, &mut ws, &mut state, &mut out)
            .unwrap();
        secs += t.elapsed().as_secs_f64();
        dets += usize::from(rep.detector_ran);
        lk += usize::from(rep.lk_ran);
        res.push(out.clone());
    }
    let _ = t0;
    (res, secs, dets, lk)
}

fn main() {
    let sp_path = facecap_core::paths::model_file(facecap_core::paths::DLIB_68_MODEL).expect("68-point model");
    let sp = ShapePredictor::from_file(&sp_path).unwrap().with_params(ErtParams {
        output: OutputPrecision::SubPixel,
        ..Default::default()
    });
    let det = FaceDetector::default_model().unwrap();
    let variant = std::env::args().nth(1).unwrap_or_default();
    let ert_init = if variant == "previous" {
        ErtInit::PreviousShape
    } else {
        ErtInit::MeanShapeInBox
    };
    let configs = [("off", None), ("one-euro", Some(OneEuroParams::default()))];
    let fx: Fixture = serde_json::from_str(
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../testdata/dlib_track/fixture.json"
        ))
        .unwrap(),
    )
    .unwrap();
    println!("ert_init {ert_init:?}");
    println!("| clip | frames | filter | face % | detector runs | LK frames | mean dist to dlib (% IOD) | tracker frames/s (1 thread, decode excluded) |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut still_src = None;
    for clip in &fx.clips {
        let path = facecap_core::paths::shared_data_file("lk_tracker_eval", &clip.clip).expect("shared data");
        let frames = decode_gray(&path);
        if clip.clip.ends_with("liveportrait_d3.mp4") {
            still_src = Some(frames[0].clone());
        }
        for (name, filter) in configs {
            let tracker = LandmarkTracker::new(
                det.clone(),
                sp.clone(),
                TrackerParams {
                    filter,
                    ert_init,
                    ..TrackerParams::default()
                },
            )
            .unwrap();
            let (res, secs, dets, lk) = run(&tracker, &frames);
            let found = res.iter().filter(|r| r.success).count();
            let (mut sum, mut n) = (0.0, 0);
            for (r, t) in res.iter().zip(&clip.frames) {
                if let (true, Some(t)) = (r.success, t) {
                    let truth = Landmarks68::from_fn(|i| (t.pts[2 * i], t.pts[2 * i + 1]));
                    sum += r.landmarks.normalised_mean_error(&truth);
                    n += 1;
                }
            }
            println!(
                "| {} | {} | {name} | {:.1} | {dets} | {lk} | {:.2} | {:.0} |",
                clip.clip,
                frames.len(),
                100.0 * found as f64 / frames.len() as f64,
                100.0 * sum / n.max(1) as f64,
                frames.len() as f64 / secs
            );
        }
    }

    // Still segment with sensor noise.
    let base = still_src.expect("liveportrait_d3 frame");
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let still: Vec<GrayImage> = (0..150)
        .map(|_| {
            GrayImage::from_fn(base.width(), base.height(), |x, y| {
                let v = base.get_pixel(x, y)[0] as f64 + 2.0 * gauss(&mut rng);
                image::Luma([v.round().clamp(0.0, 255.0) as u8])
            })
        })
        .collect();
    // Moving segment: translate by 3 px/frame in x (bilinear).
    let speed = 3.0;
    let moving: Vec<GrayImage> = (0..60)
        .map(|k| {
            let dx = speed * k as f64 - 90.0;
            GrayImage::from_fn(base.width(), base.height(), |x, y| {
                let sx = (x as f64 - dx).clamp(0.0, base.width() as f64 - 1.001);
                let x0 = sx.floor();
                let a = sx - x0;
                let p0 = base.get_pixel(x0 as u32, y)[0] as f64;
                let p1 = base.get_pixel(x0 as u32 + 1, y)[0] as f64;
                image::Luma([((1.0 - a) * p0 + a * p1).round() as u8])
            })
        })
        .collect();
    println!();
    println!("| filter | still jitter: mean per-point std (px) | (% IOD) | moving 3 px/frame: mean lag along motion (px) | (frames) | moving: mean error (% IOD) |");
    println!("|---|---|---|---|---|---|");
    for (name, filter) in configs {
        let tracker = LandmarkTracker::new(
            det.clone(),
            sp.clone(),
            TrackerParams {
                filter,
                ert_init,
                ..TrackerParams::default()
            },
        )
        .unwrap();
        let (res, _, _, _) = run(&tracker, &still);
        let ok: Vec<&TrackedFrame> = res.iter().skip(10).filter(|r| r.success).collect();
        let mut jitter = 0.0;
        for i in 0..NUM_LANDMARKS {
            let n = ok.len() as f64;
            let (mx, my) = (
                ok.iter().map(|r| r.landmarks.points[i].x).sum::<f64>() / n,
                ok.iter().map(|r| r.landmarks.points[i].y).sum::<f64>() / n,
            );
            let var = ok
                .iter()
                .map(|r| (r.landmarks.points[i].x - mx).powi(2) + (r.landmarks.points[i].y - my).powi(2))
                .sum::<f64>()
                / n;
            jitter += var.sqrt();
        }
        jitter /= NUM_LANDMARKS as f64;
        let iod = ok[0].landmarks.interocular_distance();
        // Lag: reference = unfiltered landmarks on the unshifted frame, moved by the known shift.
        let (mres, _, _, _) = run(&tracker, &moving);
        let (r0, _, _, _) = run(
            &LandmarkTracker::new(
                det.clone(),
                sp.clone(),
                TrackerParams {
                    ert_init,
                    ..TrackerParams::default()
                },
            )
            .unwrap(),
            std::slice::from_ref(&base),
        );
        let reference = &r0[0].landmarks;
        let (mut lag, mut err, mut n) = (0.0, 0.0, 0.0);
        for (k, r) in mres.iter().enumerate().skip(10) {
            if !r.success {
                continue;
            }
            let dx = speed * k as f64 - 90.0;
            for i in 0..NUM_LANDMARKS {
                let t = reference.points[i];
                let p = r.landmarks.points[i];
                lag += (t.x + dx) - p.x;
                err += ((t.x + dx - p.x).powi(2) + (t.y - p.y).powi(2)).sqrt();
                n += 1.0;
            }
        }
        println!(
            "| {name} | {jitter:.3} | {:.2} | {:.2} | {:.2} | {:.2} |",
            100.0 * jitter / iod,
            lag / n,
            lag / n / speed,
            100.0 * err / n / iod
        );
    }
}
