//! Video mode of `facecap landmarks` (tracker): `facecap landmarks VIDEO|FOLDER --out DIR
//! [--landmarks dlib68|mesh] [--draw]`.
//!
//! Runs the pipeline's [`VideoTracker`] over every frame: with `dlib68` (the default)
//! dlib-compatible HOG detector + ERT shape predictor + pyramidal LK, unfiltered; with
//! `mesh` MediaPipe's face detector and 478-point face mesh, tracked from the previous
//! frame's landmarks (FaceLandmarker's VIDEO mode; `--smooth` adds its one-euro
//! smoothing). It writes, in `DIR`:
//!
//! * `landmarks.csv` — one row per frame, OpenFace-style columns
//!   `frame,timestamp,success,confidence,x_0..x_67,y_0..y_67` (0-based pixels,
//!   centre of the top-left pixel = (0, 0); `nan` where `success` is 0), written
//!   atomically (the file appears only when the run completes); with `mesh` the 478
//!   points `x_0,y_0,z_0,...,z_477` instead (docs/formats.md), `confidence` the face
//!   presence;
//! * with `--draw`, `frames/frame_NNNNNN.png`: each frame in grey with the points
//!   (red, on frames with a face; all 478 with `mesh`) and the box (green).
//!
//! A progress bar is shown only when stderr is a terminal.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use facecap_core::landmarks::{Landmarks68, Rect};
use facecap_pipeline::{
    FrameImages, FrontEnd, LandmarkCsvSink, LandmarkLayout, RunControl, Sink, TrackedFace, TrackerPolicy, VideoTracker,
};
use image::{GrayImage, Rgb, RgbImage};

use crate::cmd_landmarks::VideoJob;

/// `--draw`: each frame in grey with the points and the box, as
/// `frames/frame_NNNNNN.png` (a sink of the pipeline).
struct DrawSink {
    dir: PathBuf,
    canvas: RgbImage,
    /// Draw the 478 mesh points instead of the 68.
    mesh: bool,
}

impl Sink for DrawSink {
    fn name(&self) -> &str {
        "draw"
    }

    fn images(&self) -> FrameImages {
        FrameImages::Every
    }

    fn wants_mesh(&self) -> bool {
        self.mesh
    }

    fn frame(&mut self, face: &TrackedFace) -> facecap_pipeline::Result<()> {
        let Some(gray) = &face.gray else { return Ok(()) };
        draw(gray, face, &mut self.canvas);
        let p = self.dir.join(format!("frame_{:06}.png", face.index));
        crate::save_png_atomic(&self.canvas, &p).map_err(|e| facecap_pipeline::Error::Sink {
            sink: format!("writing {}", p.display()),
            source: e.into(),
        })
    }
}

/// Runs the video mode.
pub fn run(job: &VideoJob) -> anyhow::Result<ExitCode> {
    // Unfiltered by default (the configuration checked against dlib on the shared
    // clips); `--smooth` trades accuracy on fast expressions for less jitter.
    let tracker = VideoTracker::new(&TrackerPolicy {
        smooth: job.smooth,
        shape_model: job.model.clone(),
        upsample: job.upsample,
        ert_precision: job.ert_precision,
        front_end: job.front_end,
    })?;
    let mesh = job.front_end == FrontEnd::Mesh;
    let source = facecap_pipeline::open_video_rgb(&job.input, 1, job.strict, tracker.needs_rgb())
        .with_context(|| format!("opening {}", job.input.display()))?;
    let frame_count = source.info().frame_count;
    std::fs::create_dir_all(&job.out_dir).with_context(|| format!("creating {}", job.out_dir.display()))?;
    let csv_path = job.out_dir.join("landmarks.csv");
    let layout = if mesh {
        LandmarkLayout::Mesh478
    } else {
        LandmarkLayout::Ibug68
    };
    let mut csv = LandmarkCsvSink::create_with(&csv_path, layout)?;
    let mut drawer = if job.draw {
        let dir = job.out_dir.join("frames");
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        Some(DrawSink {
            dir,
            canvas: RgbImage::new(0, 0),
            mesh,
        })
    } else {
        None
    };
    let progress = crate::progress::Progress::new(crate::out::quiet());
    let mut bar = progress.bar(&job.input, frame_count);
    let report = {
        let mut sinks: Vec<&mut dyn Sink> = vec![&mut csv];
        if let Some(d) = drawer.as_mut() {
            sinks.push(d);
        }
        let mut inc = || bar.inc();
        tracker.run(
            source,
            &mut sinks,
            &mut RunControl {
                interrupted: None,
                on_frame: Some(&mut inc),
                strict: job.strict,
            },
        )?
    };
    bar.finish();
    let decoded = crate::report_undecodable(&job.input, &report);
    if !decoded {
        anyhow::bail!("{}: no frame could be decoded", job.input.display());
    }
    csv.finish()?;
    let (n, ok) = (report.frames, report.faces);
    crate::out::info(&format!(
        "{}: {n} frames, face on {ok} ({:.1} %), tracker {:.0} frames/s (decode excluded); wrote {}",
        job.input.display(),
        if n > 0 { 100.0 * ok as f64 / n as f64 } else { 0.0 },
        if report.track_seconds > 0.0 {
            n as f64 / report.track_seconds
        } else {
            0.0
        },
        csv_path.display()
    ));
    Ok(ExitCode::SUCCESS)
}

/// Grey frame with the landmarks and box drawn.
fn draw(gray: &GrayImage, f: &TrackedFace, canvas: &mut RgbImage) {
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
    let c: Rgb<u8> = Rgb([255, 0, 0]);
    let mut cross = |x: f64, y: f64| {
        let (x, y) = (x.round() as i64, y.round() as i64);
        for (dx, dy) in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)] {
            put(x + dx, y + dy, c);
        }
    };
    match (f.mesh.as_deref(), f.landmarks.as_ref()) {
        (Some(mesh), Some(_)) => {
            for p in mesh {
                cross(f64::from(p[0]), f64::from(p[1]));
            }
        }
        (None, Some(l)) => {
            let l: &Landmarks68 = l;
            for p in l.points.iter() {
                cross(p.x, p.y);
            }
        }
        _ => {}
    }
}
