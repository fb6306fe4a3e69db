//! The preview video (`preview.mp4`): per frame, the colour video frame with the tracked
//! landmarks and the rig drawn over the face in the solved head pose, beside the rig
//! rendered with the solved weights and head rotation, and a bar chart of the weights.
//!
//! ```text
//! +----------------------------+--------------+----------------+
//! | video frame                | rig, solved  | jawOpen  ##### |
//! | + mesh overlay (camera)    | weights and  | mouthSmile ##  |
//! | + 68 landmarks             | head rotation| ...            |
//! +----------------------------+--------------+----------------+
//! ```
//!
//! It is a second pass over the video, after the solve: the weights of a frame are final
//! only once the whole clip was seen (the neutral calibration fits the subject's resting
//! face over many frames first), so the preview cannot be a per-frame [`crate::Sink`] of
//! the tracking pass without holding every colour frame in memory. The video is decoded
//! again in colour (ffmpeg decodes in its own process), batches of frames are rendered in
//! parallel with rayon (one [`RenderWorkspace`] per thread) and written in order to an
//! [`FfmpegEncoder`] (H.264, yuv420p, MP4, written atomically).

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use facecap_core::camera::Intrinsics;
use facecap_io::video::encode::{EncoderParams, FfmpegEncoder};
use facecap_io::video::{open_source, Frame, SourceOptions};
use image::{Rgb, RgbImage};
use nalgebra::Point2;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::expression::SolvedFrame;
use crate::render::{draw_landmarks, draw_text, draw_weight_bars, RenderWorkspace, RigRenderer, View, BAR_ROW};

/// Width of the weight bar chart, pixels.
pub const BARS_WIDTH: u32 = 264;
/// Opacity of the mesh drawn over the video frame.
pub const OVERLAY_ALPHA: f32 = 0.45;
/// Landmark colour on the frames.
pub const LANDMARK_COLOUR: [u8; 3] = [60, 230, 90];

/// Settings of [`write_preview`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `max_height` | 360 | frames taller than this are scaled down to it (pixels) | 64..=2160 |
/// | `max_fps` | 15 | frame-rate cap: a faster video shows every k-th frame, k = ceil(fps / max_fps), at fps / k | 1..=240 |
/// | `decode_threads` | 1 | ffmpeg decoder threads for the second pass | any (0 = ffmpeg's choice) |
/// | `encoder` | [`EncoderParams::default`] with preset `ultrafast` (`fps` is set from the video) | x264 settings | |
#[derive(Debug, Clone, PartialEq)]
pub struct PreviewParams {
    /// Largest frame height in the preview.
    pub max_height: u32,
    /// Largest frame rate of the preview (rendering and encoding dominate its cost).
    pub max_fps: f64,
    /// ffmpeg decoder threads.
    pub decode_threads: u32,
    /// Encoder settings (its `fps` is replaced by the video's when that is known).
    pub encoder: EncoderParams,
}

impl Default for PreviewParams {
    fn default() -> Self {
        PreviewParams {
            max_height: 360,
            max_fps: 15.0,
            decode_threads: 1,
            // the preview is for looking at: x264's cheapest preset (no trellis, no
            // B-frames) costs a third of `veryfast` at a larger file
            encoder: EncoderParams {
                preset: "ultrafast".into(),
                ..EncoderParams::default()
            },
        }
    }
}

/// What [`write_preview`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct PreviewReport {
    /// Frames written.
    pub frames: u64,
    /// Size of the video.
    pub width: u32,
    /// Size of the video.
    pub height: u32,
    /// Frame rate written.
    pub fps: f64,
    /// Busy seconds decoding (this process's side).
    pub decode_seconds: f64,
    /// Wall seconds rendering (parallel).
    pub render_seconds: f64,
    /// Seconds spent handing frames to ffmpeg (its encoding overlaps the rendering).
    pub encode_seconds: f64,
}

/// Where the parts of a preview frame go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewLayout {
    /// Scale from video pixels to preview pixels (<= 1).
    pub scale: f64,
    /// Size of the scaled video frame.
    pub frame: (u32, u32),
    /// Side of the square rig panel (= the frame height).
    pub panel: u32,
    /// Width and height of the whole preview frame (even).
    pub size: (u32, u32),
}

impl PreviewLayout {
    /// The layout for a `width` x `height` video scaled to at most `max_height`.
    pub fn new(width: u32, height: u32, max_height: u32) -> Self {
        let scale = if height > max_height {
            f64::from(max_height) / f64::from(height)
        } else {
            1.0
        };
        let fw = ((f64::from(width) * scale).round() as u32).max(1);
        let fh = ((f64::from(height) * scale).round() as u32).max(1);
        let total_w = fw + fh + BARS_WIDTH;
        PreviewLayout {
            scale,
            frame: (fw, fh),
            panel: fh,
            size: (total_w + total_w % 2, fh + fh % 2),
        }
    }
}

/// The shapes the bar chart shows: the `rows` with the largest weight over the solved
/// frames, in rig order.
pub fn shapes_to_show(frames: &[SolvedFrame], num_shapes: usize, rows: usize) -> Vec<usize> {
    let mut peak = vec![f64::NEG_INFINITY; num_shapes];
    for f in frames.iter().filter(|f| f.success) {
        for (p, w) in peak.iter_mut().zip(&f.weights) {
            if w.is_finite() {
                *p = p.max(*w);
            }
        }
    }
    let mut order: Vec<usize> = (0..num_shapes).collect();
    order.sort_by(|&a, &b| peak[b].total_cmp(&peak[a]).then(a.cmp(&b)));
    order.truncate(rows);
    order.sort_unstable();
    order
}

/// Draws the mesh overlay and the landmarks (discs of `landmark_radius` px) of `f` onto
/// `img` (the video frame scaled by `scale`), with `camera` the video's camera.
///
/// # Errors
/// A weight count that is not the rig's.
pub fn draw_overlay(
    img: &mut RgbImage,
    renderer: &RigRenderer,
    f: &SolvedFrame,
    camera: &Intrinsics,
    scale: f64,
    landmark_radius: f64,
    ws: &mut RenderWorkspace,
) -> Result<()> {
    if !f.success {
        return Ok(());
    }
    let k = Intrinsics::new(
        camera.fx * scale,
        camera.fy * scale,
        (camera.cx + 0.5) * scale - 0.5,
        (camera.cy + 0.5) * scale - 0.5,
    )?;
    if let Some(pose) = &f.pose {
        renderer.draw(
            img,
            &f.weights,
            Some(pose),
            View::Camera { camera: &k, pose },
            OVERLAY_ALPHA,
            ws,
        )?;
    }
    if let Some(l) = &f.landmarks {
        let pts: Vec<Point2<f64>> = l
            .points
            .iter()
            .map(|p| Point2::new((p.x + 0.5) * scale - 0.5, (p.y + 0.5) * scale - 0.5))
            .collect();
        draw_landmarks(img, &pts, landmark_radius, LANDMARK_COLOUR);
    }
    Ok(())
}

/// One preview frame from the colour frame `rgb` and its solved frame.
///
/// # Errors
/// A weight count that is not the rig's.
#[allow(clippy::too_many_arguments)]
pub fn compose_frame(
    rgb: &RgbImage,
    f: &SolvedFrame,
    renderer: &RigRenderer,
    camera: &Intrinsics,
    names: &[String],
    shown: &[usize],
    layout: &PreviewLayout,
    ws: &mut RenderWorkspace,
) -> Result<RgbImage> {
    let mut out = RgbImage::from_pixel(layout.size.0, layout.size.1, Rgb([255, 255, 255]));
    let mut frame = if layout.scale < 1.0 {
        crate::render::scale_bilinear(rgb, layout.frame.0, layout.frame.1)
    } else {
        rgb.clone()
    };
    let radius = (f64::from(layout.frame.1) / 220.0).max(1.6);
    draw_overlay(&mut frame, renderer, f, camera, layout.scale, radius, ws)?;
    let stamp = format!("frame {}  {:.2} s", f.index, f.timestamp);
    draw_text(&mut frame, &stamp, 7, 7, 1, [0, 0, 0]);
    draw_text(&mut frame, &stamp, 6, 6, 1, [255, 255, 255]);
    if !f.success {
        let msg = "no face: tracking lost";
        draw_text(&mut frame, msg, 7, 21, 2, [0, 0, 0]);
        draw_text(&mut frame, msg, 6, 20, 2, [255, 80, 80]);
    }
    image::imageops::overlay(&mut out, &frame, 0, 0);
    let mut panel = RgbImage::from_pixel(layout.panel, layout.panel, Rgb(crate::render::BACKGROUND));
    renderer.draw(
        &mut panel,
        &f.weights,
        f.pose.as_ref(),
        View::Portrait { size: layout.panel },
        1.0,
        ws,
    )?;
    let caption = if f.success {
        "rig: solved weights + head"
    } else {
        "rig: last solved frame"
    };
    draw_text(&mut panel, caption, 6, 6, 1, [60, 60, 60]);
    image::imageops::overlay(&mut out, &panel, i64::from(layout.frame.0), 0);
    let bx = layout.frame.0 + layout.panel + 8;
    draw_text(&mut out, "blendshape weights", i64::from(bx), 6, 1, [20, 20, 20]);
    draw_weight_bars(
        &mut out,
        (bx, 22, BARS_WIDTH - 12, layout.size.1.saturating_sub(24)),
        names,
        &f.weights,
        shown,
    );
    Ok(out)
}

/// Writes the preview of `frames` (the solve of `video`) to `out` (module docs), and
/// returns the colour frames whose indices are in `keep` (for a report's stills).
/// `interrupted` stops it at the next batch with [`Error::Interrupted`] (nothing is
/// left under `out`).
///
/// # Errors
/// Decoding, rendering or encoding failures; a video whose frames do not match
/// `frames`.
#[allow(clippy::too_many_arguments)]
pub fn write_preview(
    video: &Path,
    frames: &[SolvedFrame],
    names: &[String],
    renderer: &RigRenderer,
    camera: &Intrinsics,
    out: &Path,
    params: &PreviewParams,
    keep: &[u64],
    interrupted: Option<&AtomicBool>,
) -> Result<(PreviewReport, Vec<(u64, RgbImage)>)> {
    if !(64..=2160).contains(&params.max_height) {
        return Err(Error::invalid(
            "preview max_height",
            params.max_height,
            "64..=2160 pixels",
        ));
    }
    let mut source = open_source(
        video,
        &SourceOptions {
            rgb: true,
            threads: params.decode_threads,
            ..SourceOptions::default()
        },
    )?;
    let info = source.info().clone();
    let layout = PreviewLayout::new(info.width, info.height, params.max_height);
    if !(params.max_fps.is_finite() && (1.0..=240.0).contains(&params.max_fps)) {
        return Err(Error::invalid("preview max_fps", params.max_fps, "1..=240"));
    }
    let video_fps = if info.fps.is_finite() && info.fps > 0.0 {
        info.fps
    } else {
        params.encoder.fps
    };
    // every `stride`-th frame, at the rate that keeps the clip's duration
    let stride = ((video_fps / params.max_fps).ceil() as usize).clamp(1, 240);
    let fps = video_fps / stride as f64;
    let mut encoder = FfmpegEncoder::create(
        out,
        layout.size.0,
        layout.size.1,
        &EncoderParams {
            fps,
            ..params.encoder.clone()
        },
    )?;
    let rows = (layout.size.1.saturating_sub(24) / BAR_ROW) as usize;
    let shown = shapes_to_show(frames, renderer.num_shapes(), rows);
    let batch = (2 * rayon::current_num_threads()).max(4);
    let (mut decode_s, mut render_s) = (0.0, 0.0);
    let mut next = 0usize;
    let (mut next_index, mut consecutive) = (0u64, 0u32);
    let mut kept = Vec::new();
    // Frames go to ffmpeg from their own thread, so encoding overlaps decoding and
    // rendering the next batch.
    let (tx, rx) = std::sync::mpsc::sync_channel::<RgbImage>(batch);
    let abort = AtomicBool::new(false);
    let abort_ref = &abort;
    let (loop_result, written) = std::thread::scope(|scope| {
        let writer = scope.spawn(move || -> Result<(u64, f64)> {
            let mut busy = 0.0;
            for img in rx {
                let t = Instant::now();
                encoder.write_frame(&img)?;
                busy += t.elapsed().as_secs_f64();
            }
            if abort_ref.load(Ordering::SeqCst) {
                // dropped unfinished: ffmpeg is stopped and nothing is published
                return Ok((0, busy));
            }
            let t = Instant::now();
            let n = encoder.finish()?;
            Ok((n, busy + t.elapsed().as_secs_f64()))
        });
        let loop_result = (|| -> Result<()> {
            loop {
                if interrupted.is_some_and(|f| f.load(Ordering::SeqCst)) {
                    return Err(Error::Interrupted { frame: next as u64 });
                }
                let t = Instant::now();
                let mut decoded = Vec::with_capacity(batch);
                for _ in 0..batch {
                    let mut fr = Frame::default();
                    match source.read_into(&mut fr) {
                        Ok(false) => break,
                        Ok(true) => {
                            next_index = fr.index + 1;
                            consecutive = 0;
                        }
                        // A frame the tracking pass could not decode either (salvage, as
                        // in the tracker): shown as a dark frame marked lost.
                        Err(e) => {
                            let index = match &e {
                                facecap_core::Error::Decode { frame: Some(k), .. } => (*k).max(next_index),
                                _ => next_index,
                            };
                            next_index = index + 1;
                            consecutive += 1;
                            if consecutive > crate::tracker::MAX_CONSECUTIVE_DECODE_ERRORS {
                                break;
                            }
                            fr.index = index;
                            fr.rgb = Some(RgbImage::from_pixel(
                                info.width.max(1),
                                info.height.max(1),
                                Rgb([40, 40, 40]),
                            ));
                        }
                    }
                    decoded.push(fr);
                }
                decode_s += t.elapsed().as_secs_f64();
                if decoded.is_empty() {
                    break;
                }
                for (k, fr) in decoded.iter().enumerate() {
                    if keep.contains(&fr.index) {
                        if let Some(rgb) = &fr.rgb {
                            kept.push((fr.index, rgb.clone()));
                        }
                    }
                    let solved = frames.get(next + k);
                    if solved.map(|s| s.index) != Some(fr.index) {
                        return Err(Error::invalid(
                            "preview frames",
                            format!("video frame {} has no solved frame", fr.index),
                            format!("the {} frames of the solve, in order", frames.len()),
                        ));
                    }
                }
                let t = Instant::now();
                let rendered: Vec<Result<RgbImage>> = decoded
                    .par_iter()
                    .enumerate()
                    .filter(|(k, _)| (next + k) % stride == 0)
                    .map_init(RenderWorkspace::default, |ws, (k, fr)| {
                        let rgb = fr.rgb.as_ref().ok_or_else(|| {
                            Error::invalid("preview source", "no colour frames", "a source that decodes RGB")
                        })?;
                        compose_frame(rgb, &frames[next + k], renderer, camera, names, &shown, &layout, ws)
                    })
                    .collect();
                render_s += t.elapsed().as_secs_f64();
                for img in rendered {
                    if tx.send(img?).is_err() {
                        // the writer stopped: its error is reported below
                        return Ok(());
                    }
                }
                next += decoded.len();
            }
            if next != frames.len() {
                return Err(Error::invalid(
                    "preview frames",
                    format!("{next} frames decoded"),
                    format!("the {} frames of the solve", frames.len()),
                ));
            }
            Ok(())
        })();
        let finished = if loop_result.is_ok() {
            drop(tx);
            writer.join().unwrap_or(Err(Error::StagePanicked {
                stage: "preview encoding",
            }))
        } else {
            abort.store(true, Ordering::SeqCst);
            drop(tx);
            let _ = writer.join();
            Ok((0, 0.0))
        };
        (loop_result, finished)
    });
    loop_result?;
    let (written, encode_s) = written?;
    let report = PreviewReport {
        frames: written,
        width: layout.size.0,
        height: layout.size.1,
        fps,
        decode_seconds: decode_s,
        render_seconds: render_s,
        encode_seconds: encode_s,
    };
    Ok((report, kept))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_is_even_and_scales_tall_frames() {
        let l = PreviewLayout::new(1281, 721, 480);
        assert_eq!(l.size.1 % 2, 0);
        assert_eq!(l.size.0 % 2, 0);
        assert!(l.frame.1 <= 480 && l.scale < 1.0);
        let s = PreviewLayout::new(512, 512, 480);
        assert_eq!(s.frame, (480, 480));
        let small = PreviewLayout::new(320, 240, 480);
        assert_eq!((small.scale, small.frame, small.panel), (1.0, (320, 240), 240));
    }

    #[test]
    fn bar_chart_shows_the_most_active_shapes_in_rig_order() {
        let f = |w: Vec<f64>, success| SolvedFrame {
            index: 0,
            timestamp: 0.0,
            success,
            confidence: 1.0,
            landmarks: None,
            weights: w,
            pose: None,
            reprojection_px: 0.0,
        };
        let frames = vec![f(vec![0.1, 0.9, 0.0, 0.5], true), f(vec![1.0, 0.0, 1.0, 0.0], false)];
        assert_eq!(shapes_to_show(&frames, 4, 2), vec![1, 3]);
        assert_eq!(shapes_to_show(&frames, 4, 10), vec![0, 1, 2, 3]);
    }
}
