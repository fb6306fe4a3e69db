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
use std::sync::Arc;
use std::time::Instant;

use facecap_core::camera::Intrinsics;
use facecap_io::video::encode::{EncoderParams, FfmpegEncoder};
use facecap_io::video::small::{ColourTap, SmallFrame, StoredFrames};
use facecap_io::video::{open_source, Frame, FrameSelect, FrameSource, SourceOptions, VideoInfo, MAX_SELECT_EXTRA};
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
/// | `video_fps` | `None` | the video's frame rate if known: the decoder then skips the frames not shown (see [`SourceOptions::select`]) | finite, > 0 |
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
    /// The video's frame rate when the caller knows it (the tracking pass's): ffmpeg then
    /// drops the frames the preview does not show, and no second ffprobe runs.
    pub video_fps: Option<f64>,
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
            video_fps: None,
        }
    }
}

impl PreviewParams {
    /// The preview shows every `stride`-th frame of a `fps` video (1 when `fps` is not
    /// a positive number).
    pub fn stride(&self, fps: f64) -> u64 {
        if !(fps.is_finite() && fps > 0.0) {
            return 1;
        }
        ((fps / self.max_fps).ceil() as u64).clamp(1, 240)
    }

    /// The colour copies the tracking pass can keep for this preview of a `width` x
    /// `height`, `fps` video ([`FrameSource::tap_colour`]): the frames it shows and
    /// `extra` (the report's stills), at the preview's frame size. `None` when `extra`
    /// has more than [`MAX_SELECT_EXTRA`] frames.
    pub fn colour_tap(&self, width: u32, height: u32, fps: f64, extra: Vec<u64>) -> Option<ColourTap> {
        (extra.len() <= MAX_SELECT_EXTRA && width > 0 && height > 0).then(|| ColourTap {
            size: PreviewLayout::new(width, height, self.max_height).frame,
            select: FrameSelect {
                stride: self.stride(fps),
                extra,
            },
        })
    }
}

/// Largest memory [`ColourFrames`] holds by default (bytes): about 2,700 frames of a
/// 360x360 preview, three minutes of a 30 fps video.
pub const COLOUR_FRAMES_BUDGET: usize = 512 << 20;

/// A [`crate::Sink`] that keeps the small colour copies the tracking pass made
/// ([`crate::TrackedFace::colour`]) so that the preview need not decode the video again
/// ([`write_preview_stored`]). Past its memory budget it drops them all and the
/// preview decodes the video as before.
#[derive(Debug)]
pub struct ColourFrames {
    frames: Vec<(u64, f64, Arc<SmallFrame>)>,
    bytes: usize,
    budget: usize,
    overflow: bool,
}

impl ColourFrames {
    /// An empty store holding at most `budget` bytes.
    pub fn new(budget: usize) -> Self {
        ColourFrames {
            frames: Vec::new(),
            bytes: 0,
            budget,
            overflow: false,
        }
    }

    /// Frames kept.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether none is kept.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Whether the budget was exceeded (then nothing is kept).
    pub fn overflowed(&self) -> bool {
        self.overflow
    }

    /// The kept frames as a source for [`write_preview_stored`] (`None` when there are
    /// none or the budget was exceeded).
    pub fn into_source(self, video: &Path, info: &VideoInfo) -> Option<StoredFrames> {
        if self.overflow || self.frames.is_empty() {
            return None;
        }
        StoredFrames::new(video, info, self.frames).ok()
    }
}

impl crate::Sink for ColourFrames {
    fn name(&self) -> &str {
        "preview frames"
    }

    fn frame(&mut self, face: &crate::TrackedFace) -> Result<()> {
        if self.overflow {
            return Ok(());
        }
        if let Some(c) = &face.colour {
            self.bytes += c.bytes();
            if self.bytes > self.budget {
                self.overflow = true;
                self.frames = Vec::new();
            } else {
                self.frames.push((face.index, face.timestamp, Arc::clone(c)));
            }
        }
        Ok(())
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
    /// Scale of the preview's video part and of the kept frames to the video's frames
    /// (<= 1).
    pub scale: f64,
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

/// Scratch images of one rendering thread for [`compose_frame_into`].
#[derive(Debug, Default)]
pub struct ComposeWorkspace {
    /// The renderer's buffers.
    pub render: RenderWorkspace,
    /// The rig panel.
    panel: RgbImage,
}

/// Copies `src` into `dst` with its top-left corner at (`x0`, 0), row by row (clipped to
/// `dst`).
fn blit(dst: &mut RgbImage, src: &RgbImage, x0: u32) {
    let (dw, dh) = (dst.width() as usize, dst.height() as usize);
    let (sw, sh) = (src.width() as usize, src.height() as usize);
    let x0 = x0 as usize;
    if x0 >= dw {
        return;
    }
    let n = 3 * sw.min(dw - x0);
    let d: &mut [u8] = dst;
    let s: &[u8] = src;
    for y in 0..sh.min(dh) {
        let o = 3 * (y * dw + x0);
        d[o..o + n].copy_from_slice(&s[3 * y * sw..3 * y * sw + n]);
    }
}

/// Composes one preview frame into `out` (`layout.size`): `frame` is the colour video
/// frame at the layout's frame size (the overlay and captions are drawn onto it).
///
/// # Errors
/// A weight count that is not the rig's; images of the wrong size.
#[allow(clippy::too_many_arguments)]
pub fn compose_frame_into(
    out: &mut RgbImage,
    frame: &mut RgbImage,
    f: &SolvedFrame,
    renderer: &RigRenderer,
    camera: &Intrinsics,
    names: &[String],
    shown: &[usize],
    layout: &PreviewLayout,
    ws: &mut ComposeWorkspace,
) -> Result<()> {
    if out.dimensions() != layout.size || frame.dimensions() != layout.frame {
        return Err(Error::invalid(
            "preview frame size",
            format!("{:?} and {:?}", out.dimensions(), frame.dimensions()),
            format!("{:?} and {:?}", layout.size, layout.frame),
        ));
    }
    let radius = (f64::from(layout.frame.1) / 220.0).max(1.6);
    draw_overlay(frame, renderer, f, camera, layout.scale, radius, &mut ws.render)?;
    let stamp = format!("frame {}  {:.2} s", f.index, f.timestamp);
    draw_text(frame, &stamp, 7, 7, 1, [0, 0, 0]);
    draw_text(frame, &stamp, 6, 6, 1, [255, 255, 255]);
    if !f.success {
        let msg = "no face: tracking lost";
        draw_text(frame, msg, 7, 21, 2, [0, 0, 0]);
        draw_text(frame, msg, 6, 20, 2, [255, 80, 80]);
    }
    let raw: &mut [u8] = out;
    raw.fill(255);
    blit(out, frame, 0);
    if ws.panel.dimensions() != (layout.panel, layout.panel) {
        ws.panel = RgbImage::new(layout.panel, layout.panel);
    }
    let panel = &mut ws.panel;
    for p in panel.pixels_mut() {
        p.0 = crate::render::BACKGROUND;
    }
    renderer.draw(
        panel,
        &f.weights,
        f.pose.as_ref(),
        View::Portrait { size: layout.panel },
        1.0,
        &mut ws.render,
    )?;
    let caption = if f.success {
        "rig: solved weights + head"
    } else {
        "rig: last solved frame"
    };
    draw_text(panel, caption, 6, 6, 1, [60, 60, 60]);
    blit(out, panel, layout.frame.0);
    let bx = layout.frame.0 + layout.panel + 8;
    draw_text(out, "blendshape weights", i64::from(bx), 6, 1, [20, 20, 20]);
    draw_weight_bars(
        out,
        (bx, 22, BARS_WIDTH - 12, layout.size.1.saturating_sub(24)),
        names,
        &f.weights,
        shown,
    );
    Ok(())
}

/// One preview frame from the colour frame `rgb` (any size: scaled to the layout's)
/// and its solved frame.
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
    ws: &mut ComposeWorkspace,
) -> Result<RgbImage> {
    let mut frame = fit_to(rgb.clone(), layout.frame);
    let mut out = RgbImage::new(layout.size.0, layout.size.1);
    compose_frame_into(&mut out, &mut frame, f, renderer, camera, names, shown, layout, ws)?;
    Ok(out)
}

/// `img` scaled to `size` (bilinear) unless it has that size.
fn fit_to(img: RgbImage, size: (u32, u32)) -> RgbImage {
    if img.dimensions() == size {
        img
    } else {
        crate::render::scale_bilinear(&img, size.0, size.1)
    }
}

/// Decoded frames handed from the decoding thread to the renderer: (position in the
/// solve, colour frame at the preview's frame size).
type Batch = Vec<(usize, RgbImage)>;

/// Frames written, busy seconds of decoding, rendering and encoding, and the kept
/// frames.
type StageTotals = (u64, f64, f64, f64, Vec<(u64, RgbImage)>);

/// Writes the preview of `frames` (the solve of `video`, whose frames are `size` =
/// width x height pixels as the solve saw them) to `out` (module docs), and returns the
/// colour frames whose indices are in `keep` (for a report's stills), at the preview's
/// frame size ([`PreviewReport::scale`] of the video's). `interrupted` stops it at the
/// next batch with [`Error::Interrupted`] (nothing is left under `out`).
///
/// Three stages run at once: a thread decodes (ffmpeg scales video files to the
/// preview size itself, see [`SourceOptions::scale`]), the calling thread renders
/// batches in parallel with rayon, and a thread hands the rendered frames to the
/// encoder in order.
///
/// # Errors
/// Decoding, rendering or encoding failures; a video whose frames do not match
/// `frames` or `size`.
#[allow(clippy::too_many_arguments)]
pub fn write_preview(
    video: &Path,
    size: (u32, u32),
    frames: &[SolvedFrame],
    names: &[String],
    renderer: &RigRenderer,
    camera: &Intrinsics,
    out: &Path,
    params: &PreviewParams,
    keep: &[u64],
    interrupted: Option<&AtomicBool>,
) -> Result<(PreviewReport, Vec<(u64, RgbImage)>)> {
    write_preview_stored(
        video,
        None,
        size,
        frames,
        names,
        renderer,
        camera,
        out,
        params,
        keep,
        interrupted,
    )
}

/// [`write_preview`] from the colour copies the tracking pass kept ([`ColourFrames`])
/// when `stored` is given, instead of decoding `video` again. Frames the preview shows
/// that are not among them are shown dark, as frames the video could not give.
///
/// # Errors
/// As [`write_preview`].
#[allow(clippy::too_many_arguments)]
pub fn write_preview_stored(
    video: &Path,
    stored: Option<StoredFrames>,
    size: (u32, u32),
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
    if !(params.max_fps.is_finite() && (1.0..=240.0).contains(&params.max_fps)) {
        return Err(Error::invalid("preview max_fps", params.max_fps, "1..=240"));
    }
    if size.0 == 0 || size.1 == 0 {
        return Err(Error::invalid("preview video size", format!("{size:?}"), "non-zero"));
    }
    let layout = PreviewLayout::new(size.0, size.1, params.max_height);
    // every `stride`-th frame, at the rate that keeps the clip's duration
    let stride_of = |fps: f64| params.stride(fps) as usize;
    // With the rate known beforehand, ffmpeg drops the frames the preview does not show
    // (neither on the stride nor kept) before scaling, converting and piping them.
    let known_fps = params.video_fps.filter(|f| f.is_finite() && *f > 0.0);
    let select = known_fps
        .filter(|_| keep.len() <= MAX_SELECT_EXTRA)
        .map(|fps| FrameSelect {
            stride: stride_of(fps) as u64,
            extra: keep.to_vec(),
        })
        .filter(|s| s.stride > 1 || !s.extra.is_empty());
    let mut source: Box<dyn FrameSource> = match stored {
        Some(s) => Box::new(s),
        None => open_source(
            video,
            &SourceOptions {
                rgb: true,
                threads: params.decode_threads,
                scale: (layout.frame != size).then_some(layout.frame),
                select,
                // the tracking pass probed the video already
                probe_frame_count: known_fps.is_none(),
                ..SourceOptions::default()
            },
        )?,
    };
    let info = source.info().clone();
    if (info.width, info.height) != layout.frame && (info.width, info.height) != size {
        return Err(Error::invalid(
            "preview source",
            format!("{}x{} frames", info.width, info.height),
            format!("{}x{} (the solve's) or {:?}", size.0, size.1, layout.frame),
        ));
    }
    let video_fps = known_fps.unwrap_or(if info.fps.is_finite() && info.fps > 0.0 {
        info.fps
    } else {
        params.encoder.fps
    });
    let stride = stride_of(video_fps);
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
    let abort = AtomicBool::new(false);
    let abort_ref = &abort;
    let stop = || abort_ref.load(Ordering::SeqCst) || interrupted.is_some_and(|f| f.load(Ordering::SeqCst));
    // Finished frames go to the writer thread; the buffers come back for reuse.
    let (tx, rx) = std::sync::mpsc::sync_channel::<RgbImage>(batch);
    let (out_pool_tx, out_pool_rx) = std::sync::mpsc::channel::<RgbImage>();
    let (batch_tx, batch_rx) = std::sync::mpsc::sync_channel::<Result<Batch>>(1);
    let (frame_pool_tx, frame_pool_rx) = std::sync::mpsc::channel::<RgbImage>();
    let result = std::thread::scope(|scope| -> Result<StageTotals> {
        let writer = scope.spawn(move || -> Result<(u64, f64)> {
            let mut busy = 0.0;
            for img in rx {
                let t = Instant::now();
                encoder.write_frame(&img)?;
                busy += t.elapsed().as_secs_f64();
                let _ = out_pool_tx.send(img);
            }
            if abort_ref.load(Ordering::SeqCst) {
                // dropped unfinished: ffmpeg is stopped and nothing is published
                return Ok((0, busy));
            }
            let t = Instant::now();
            let n = encoder.finish()?;
            Ok((n, busy + t.elapsed().as_secs_f64()))
        });
        let decoder = scope.spawn(move || -> (f64, Vec<(u64, RgbImage)>) {
            let mut busy = 0.0;
            let mut kept = Vec::new();
            let r = (|| -> Result<()> {
                let (mut pos, mut next_index, mut consecutive) = (0usize, 0u64, 0u32);
                let mut fr = Frame::default();
                let dark = || RgbImage::from_pixel(layout.frame.0, layout.frame.1, Rgb([40, 40, 40]));
                let wanted = |pos: usize| frames[pos].index % stride as u64 == 0;
                let mut ended = false;
                while !ended {
                    if stop() {
                        return Err(Error::Interrupted { frame: pos as u64 });
                    }
                    let t = Instant::now();
                    let mut decoded = Batch::with_capacity(batch + 1);
                    while decoded.len() < batch {
                        if fr.rgb.is_none() {
                            fr.rgb = frame_pool_rx.try_recv().ok();
                        }
                        let rgb = match source.read_into(&mut fr) {
                            Ok(false) => {
                                ended = true;
                                break;
                            }
                            Ok(true) => {
                                next_index = fr.index + 1;
                                consecutive = 0;
                                None
                            }
                            // A frame the tracking pass could not decode either (salvage,
                            // as in the tracker): shown as a dark frame marked lost.
                            Err(e) => {
                                let index = match &e {
                                    facecap_core::Error::Decode { frame: Some(k), .. } => (*k).max(next_index),
                                    _ => next_index,
                                };
                                next_index = index + 1;
                                consecutive += 1;
                                if consecutive > crate::tracker::MAX_CONSECUTIVE_DECODE_ERRORS {
                                    ended = true;
                                    break;
                                }
                                fr.index = index;
                                Some(dark())
                            }
                        };
                        // Solved frames the source passed over: dropped by the selection
                        // (not shown), or shown dark if the preview wanted them.
                        while pos < frames.len() && frames[pos].index < fr.index {
                            if wanted(pos) {
                                decoded.push((pos, dark()));
                            }
                            pos += 1;
                        }
                        if frames.get(pos).map(|s| s.index) != Some(fr.index) {
                            return Err(Error::invalid(
                                "preview frames",
                                format!("video frame {} has no solved frame", fr.index),
                                format!("the {} frames of the solve, in order", frames.len()),
                            ));
                        }
                        let wanted_here = wanted(pos);
                        let kept_here = keep.contains(&fr.index);
                        if wanted_here || kept_here {
                            let img = match rgb {
                                Some(img) => img,
                                None => {
                                    let img = fr.rgb.take().ok_or_else(|| {
                                        Error::invalid(
                                            "preview source",
                                            "no colour frames",
                                            "a source that decodes RGB",
                                        )
                                    })?;
                                    fit_to(img, layout.frame)
                                }
                            };
                            if kept_here {
                                kept.push((fr.index, img.clone()));
                            }
                            if wanted_here {
                                decoded.push((pos, img));
                            } else {
                                fr.rgb = Some(img);
                            }
                        }
                        pos += 1;
                    }
                    if ended {
                        // Solved frames after the last one decoded: dropped by the
                        // selection, or (a video that ended early) shown dark.
                        while pos < frames.len() {
                            if wanted(pos) {
                                decoded.push((pos, dark()));
                            }
                            pos += 1;
                        }
                    }
                    busy += t.elapsed().as_secs_f64();
                    if decoded.is_empty() {
                        continue;
                    }
                    if batch_tx.send(Ok(decoded)).is_err() {
                        return Ok(());
                    }
                }
                Ok(())
            })();
            if let Err(e) = r {
                let _ = batch_tx.send(Err(e));
            }
            (busy, kept)
        });
        let mut render_s = 0.0;
        let loop_result = (|| -> Result<()> {
            for decoded in &batch_rx {
                let decoded = decoded?;
                let t = Instant::now();
                let bufs: Vec<RgbImage> = decoded
                    .iter()
                    .map(|_| {
                        out_pool_rx
                            .try_recv()
                            .unwrap_or_else(|_| RgbImage::new(layout.size.0, layout.size.1))
                    })
                    .collect();
                let rendered: Vec<Result<RgbImage>> = decoded
                    .into_par_iter()
                    .zip(bufs)
                    .map_init(ComposeWorkspace::default, |ws, ((pos, mut img), mut buf)| {
                        compose_frame_into(
                            &mut buf,
                            &mut img,
                            &frames[pos],
                            renderer,
                            camera,
                            names,
                            &shown,
                            &layout,
                            ws,
                        )?;
                        let _ = frame_pool_tx.send(img);
                        Ok(buf)
                    })
                    .collect();
                render_s += t.elapsed().as_secs_f64();
                for img in rendered {
                    if tx.send(img?).is_err() {
                        // the writer stopped: its error is reported below
                        return Ok(());
                    }
                }
            }
            Ok(())
        })();
        if loop_result.is_err() {
            abort.store(true, Ordering::SeqCst);
        }
        // unblocks a decoder waiting to hand over a batch
        drop(batch_rx);
        let (decode_s, kept) = decoder.join().map_err(|_| Error::StagePanicked {
            stage: "preview decoding",
        })?;
        drop(tx);
        let written = writer.join().unwrap_or(Err(Error::StagePanicked {
            stage: "preview encoding",
        }));
        loop_result?;
        let (n, encode_s) = written?;
        Ok((n, decode_s, render_s, encode_s, kept))
    });
    let (written, decode_s, render_s, encode_s, kept) = result?;
    let report = PreviewReport {
        frames: written,
        width: layout.size.0,
        height: layout.size.1,
        fps,
        scale: layout.scale,
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
