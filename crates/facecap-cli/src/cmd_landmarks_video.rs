//! Video mode of `facecap landmarks` (tracker): `facecap landmarks VIDEO --out DIR [--draw]`.
//!
//! Runs [`facecap_landmarks::tracker::LandmarkTracker`] (dlib-compatible HOG
//! detector + ERT shape predictor + pyramidal LK, unfiltered) over every
//! frame and writes, in `DIR`:
//!
//! * `landmarks.csv` — one row per frame, OpenFace-style columns
//!   `frame,timestamp,success,confidence,x_0..x_67,y_0..y_67` (0-based pixels,
//!   centre of the top-left pixel = (0, 0); `nan` where `success` is 0), written
//!   atomically (the file appears only when the run completes);
//! * with `--draw`, `frames/frame_NNNNNN.png`: each frame in grey with the points
//!   (red when successful, yellow when not) and the ERT box (green).
//!
//! A progress bar is shown only when stderr is a terminal.

use std::io::IsTerminal as _;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use facecap_core::csv::{landmark_columns, landmark_values, FrameCsvWriter, FrameRow};
use facecap_core::landmarks::{Rect, NUM_LANDMARKS};
use facecap_core::video::{open_source, Frame, SourceOptions};
use facecap_landmarks::detect::FaceDetector;
use facecap_landmarks::ert::{ErtParams, OutputPrecision, ShapePredictor};
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
use image::{GrayImage, Rgb, RgbImage};

use crate::cmd_landmarks::{resolve_model, VideoJob};

/// Runs the video mode.
pub fn run(job: &VideoJob) -> anyhow::Result<ExitCode> {
    let model_path = resolve_model(job.model.as_deref())?;
    let sp = ShapePredictor::from_file_cached(&model_path)
        .map(|(sp, _)| sp)
        .with_context(|| format!("loading {}", model_path.display()))?
        .with_params(ErtParams {
            output: OutputPrecision::SubPixel,
        });
    let det = FaceDetector::default_model()
        .and_then(|d| d.with_upsample(job.upsample))
        .context("loading the face detector")?;
    // Unfiltered (the configuration checked against dlib on the shared clips); the One
    // Euro filter (`TrackerParams::filter`) trades accuracy on fast expressions for less jitter.
    let params = TrackerParams::default();
    let tracker = LandmarkTracker::new(det, sp, params)?;
    let mut ws = tracker.new_workspace();
    let mut state = TrackerState::new();
    let mut out = TrackedFrame::default();

    let mut src = open_source(&job.input, &SourceOptions::default())
        .with_context(|| format!("opening {}", job.input.display()))?;
    std::fs::create_dir_all(&job.out_dir).with_context(|| format!("creating {}", job.out_dir.display()))?;
    let frames_dir = job.out_dir.join("frames");
    if job.draw {
        std::fs::create_dir_all(&frames_dir).with_context(|| format!("creating {}", frames_dir.display()))?;
    }
    let csv_path = job.out_dir.join("landmarks.csv");
    let mut csv = FrameCsvWriter::create(&csv_path, &landmark_columns())?;

    let bar = if std::io::stderr().is_terminal() {
        let b = src
            .info()
            .frame_count
            .map_or_else(indicatif::ProgressBar::no_length, indicatif::ProgressBar::new);
        if let Ok(style) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames {per_sec} {eta}") {
            b.set_style(style);
        }
        Some(b)
    } else {
        None
    };

    let mut frame = Frame::default();
    let mut values = [0.0; 2 * NUM_LANDMARKS];
    let (mut n, mut ok) = (0u64, 0u64);
    let mut track_time = 0.0;
    let mut canvas = RgbImage::new(0, 0);
    while src.read_into(&mut frame)? {
        let t0 = Instant::now();
        tracker
            .track_into(&frame.gray, frame.timestamp_s, &mut ws, &mut state, &mut out)
            .with_context(|| format!("frame {}", frame.index))?;
        track_time += t0.elapsed().as_secs_f64();
        landmark_values(out.success.then_some(&out.landmarks), &mut values);
        csv.write_row(&FrameRow {
            frame: frame.index,
            timestamp: frame.timestamp_s.max(0.0),
            success: out.success,
            confidence: out.confidence,
            values: &values,
        })?;
        if job.draw {
            draw(&frame.gray, &out, &mut canvas);
            let p = frames_dir.join(format!("frame_{:06}.png", frame.index));
            canvas.save(&p).with_context(|| format!("writing {}", p.display()))?;
        }
        n += 1;
        ok += u64::from(out.success);
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    csv.finish()?;
    eprintln!(
        "{}: {n} frames, face on {ok} ({:.1} %), tracker {:.0} frames/s (decode excluded); wrote {}",
        job.input.display(),
        if n > 0 { 100.0 * ok as f64 / n as f64 } else { 0.0 },
        if track_time > 0.0 { n as f64 / track_time } else { 0.0 },
        display_rel(&csv_path)
    );
    Ok(ExitCode::SUCCESS)
}

fn display_rel(p: &Path) -> String {
    p.display().to_string()
}

/// Grey frame with the landmarks and box drawn.
fn draw(gray: &GrayImage, f: &TrackedFrame, canvas: &mut RgbImage) {
    let (w, h) = gray.dimensions();
    if canvas.dimensions() != (w, h) {
        *canvas = RgbImage::new(w, h);
    }
    for (d, s) in canvas.pixels_mut().zip(gray.pixels()) {
        *d = Rgb([s[0], s[0], s[0]]);
    }
    let mut put = |x: i64, y: i64, c: Rgb<u8>| {
        if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
            canvas.put_pixel(x as u32, y as u32, c);
        }
    };
    if let Some(Rect {
        left,
        top,
        width,
        height,
    }) = f.rect
    {
        let (l, t) = (left.round() as i64, top.round() as i64);
        let (r, b) = ((left + width - 1.0).round() as i64, (top + height - 1.0).round() as i64);
        for x in l..=r {
            put(x, t, Rgb([0, 255, 0]));
            put(x, b, Rgb([0, 255, 0]));
        }
        for y in t..=b {
            put(l, y, Rgb([0, 255, 0]));
            put(r, y, Rgb([0, 255, 0]));
        }
    }
    if f.confidence > 0.0 {
        let c = if f.success {
            Rgb([255, 0, 0])
        } else {
            Rgb([255, 255, 0])
        };
        for p in f.landmarks.points.iter() {
            let (x, y) = (p.x.round() as i64, p.y.round() as i64);
            for (dx, dy) in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)] {
                put(x + dx, y + dy, c);
            }
        }
    }
}
