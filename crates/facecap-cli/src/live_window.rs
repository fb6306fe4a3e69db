//! The preview window of `facecap live` (minifb, X11): the camera frame with the
//! tracked landmarks beside the rig posed with the solved weights and head rotation,
//! and a status line (frames per second, latency arrival to packets, frames dropped).
//!
//! The window runs on its own thread and takes frames newest-first (a channel of one,
//! filled with `try_send`): a slow window misses frames, it never delays the outputs.
//! Keys: N takes the neutral again, Esc or Q (or closing the window) stops the run.

use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::Duration;

use facecap_pipeline::net::PreviewFrame;
use facecap_pipeline::RigRenderer;
use image::{Rgb, RgbImage};

use crate::cmd_live::Controls;

/// Tallest camera image shown (taller frames are scaled down).
const MAX_PREVIEW_HEIGHT: u32 = 480;
/// How often the window handles its events when no frame comes.
const IDLE_POLL: Duration = Duration::from_millis(30);
/// Height of the status bar under the images (pixels).
const STATUS_HEIGHT: u32 = 24;

/// Whether a display server is there to open a window on.
pub fn display_available() -> bool {
    std::env::var_os("DISPLAY").is_some_and(|d| !d.is_empty())
        || std::env::var_os("WAYLAND_DISPLAY").is_some_and(|d| !d.is_empty())
}

/// The preview image of one frame: the camera frame (grey) with the landmarks, the rig
/// rendered beside it (the report's and the preview video's renderer), and the status
/// line below.
pub fn render_preview(frame: &PreviewFrame, renderer: &RigRenderer) -> RgbImage {
    let g = &frame.gray;
    let step = g.height().div_ceil(MAX_PREVIEW_HEIGHT).max(1);
    let (w, h) = (g.width() / step, g.height() / step);
    let mut cam = RgbImage::from_fn(w.max(1), h.max(1), |x, y| {
        let v = g
            .get_pixel((x * step).min(g.width() - 1), (y * step).min(g.height() - 1))
            .0[0];
        Rgb([v, v, v])
    });
    if let Some(l) = &frame.solved.landmarks {
        let pts: Vec<nalgebra::Point2<f64>> = l.points.iter().map(|p| p / f64::from(step)).collect();
        facecap_pipeline::render::draw_landmarks(&mut cam, &pts, 2.0, [40, 220, 60]);
    }
    let size = cam.height().max(64);
    let rig = renderer
        .render(&frame.solved.weights, frame.solved.pose.as_ref(), size)
        .unwrap_or_else(|_| RgbImage::from_pixel(size, size, Rgb([245, 245, 245])));
    let top = crate::report::side_by_side(&cam, &rig);
    let mut out = RgbImage::from_pixel(top.width(), top.height() + STATUS_HEIGHT, Rgb([20, 20, 20]));
    image::imageops::overlay(&mut out, &top, 0, 0);
    let status = format!(
        "{:.0} FPS  LATENCY {:.1} MS  DROPPED {}{}",
        frame.fps,
        frame.latency_ms,
        frame.dropped,
        if frame.solved.success { "" } else { "  NO FACE" }
    );
    draw_text(&mut out, 6, top.height() + 5, &status, 2, [255, 255, 255]);
    out
}

/// Runs the window until the channel closes, the window is closed or a stop key is hit.
///
/// # Errors
/// When the window cannot be opened or updated.
pub fn run_window(rx: Receiver<PreviewFrame>, renderer: &RigRenderer, controls: &Controls) -> Result<(), String> {
    use minifb::{Key, KeyRepeat, Window, WindowOptions};
    let mut window: Option<Window> = None;
    let mut buf: Vec<u32> = Vec::new();
    loop {
        match rx.recv_timeout(IDLE_POLL) {
            Ok(f) => {
                let img = render_preview(&f, renderer);
                let (w, h) = (img.width() as usize, img.height() as usize);
                buf.clear();
                buf.extend(
                    img.pixels()
                        .map(|p| (u32::from(p.0[0]) << 16) | (u32::from(p.0[1]) << 8) | u32::from(p.0[2])),
                );
                if !window.as_ref().is_some_and(|win| win.get_size() == (w, h)) {
                    window = Some(
                        Window::new("facecap live", w, h, WindowOptions::default())
                            .map_err(|e| format!("cannot open the window: {e}"))?,
                    );
                }
                if let Some(win) = window.as_mut() {
                    win.update_with_buffer(&buf, w, h).map_err(|e| e.to_string())?;
                }
            }
            Err(RecvTimeoutError::Timeout) => {
                if let Some(win) = window.as_mut() {
                    win.update();
                }
            }
            Err(RecvTimeoutError::Disconnected) => return Ok(()),
        }
        if let Some(win) = &window {
            if !win.is_open() || win.is_key_down(Key::Escape) || win.is_key_down(Key::Q) {
                controls.stop.store(true, Ordering::SeqCst);
                return Ok(());
            }
            if win.is_key_pressed(Key::N, KeyRepeat::No) {
                controls.redo_neutral.store(true, Ordering::SeqCst);
            }
        }
        if controls.stop.load(Ordering::SeqCst) {
            return Ok(());
        }
    }
}

/// 5x7 glyphs (rows top to bottom, 5 bits each, bit 4 = leftmost column).
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'Y' => [0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04],
        _ => [0; 7],
    }
}

/// Draws `text` (upper case, digits, `.` `-`) at (`x`, `y`) with pixel size `scale`.
fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, colour: [u8; 3]) {
    for (i, c) in text.chars().enumerate() {
        let rows = glyph(c);
        let gx = x + i as u32 * 6 * scale;
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..5u32 {
                if bits & (0x10 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (gx + col * scale + dx, y + r as u32 * scale + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, Rgb(colour));
                        }
                    }
                }
            }
        }
    }
}
