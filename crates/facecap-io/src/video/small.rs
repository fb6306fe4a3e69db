//! Small colour copies of chosen frames, made while a video is decoded for tracking.
//!
//! A capture decodes its video once for tracking and, for the preview, used to decode
//! it a second time in colour at the preview's size. A [`ColourTap`] set on the first
//! decode ([`FrameSource::tap_colour`](super::FrameSource::tap_colour)) keeps, for the
//! frames it selects, a [`SmallFrame`]: the decoded Y'CbCr planes scaled down to the
//! tap's size (4:2:0, a triangle filter as wide as the scale factor: ffmpeg's
//! `scale=flags=bilinear` in effect), converted to RGB only when used. [`StoredFrames`]
//! plays kept frames back as a [`FrameSource`](super::FrameSource).
//!
//! Memory: a 640x360 copy is 346 kB, so the caller bounds how many it keeps.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::RgbImage;

use super::yuv::YuvToRgb;
use super::{ensure_gray, ensure_rgb, Frame, FrameSelect, FrameSource, VideoInfo};
use facecap_core::error::{Error, Result};

/// Which frames to keep a small colour copy of, and at what size.
///
/// | field | meaning | range |
/// |---|---|---|
/// | `size` | width x height of the copies | 1..=8192 each, at most the video's size |
/// | `select` | the frames ([`FrameSelect`]) | as [`FrameSelect::validate`] |
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColourTap {
    /// Size of the copies, pixels.
    pub size: (u32, u32),
    /// The frames copied.
    pub select: FrameSelect,
}

impl ColourTap {
    /// Checks the fields against a `width` x `height` video (see the table).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the field.
    pub fn validate(&self, width: u32, height: u32) -> Result<()> {
        let (w, h) = self.size;
        if !((1..=8192).contains(&w) && (1..=8192).contains(&h)) || w > width || h > height {
            return Err(Error::invalid(
                "colour tap size",
                format!("{w}x{h}"),
                format!("1..=8192 pixels each, at most the video's {width}x{height}"),
            ));
        }
        self.select.validate()
    }
}

/// A small colour frame: Y'CbCr 4:2:0 planes and the conversion to RGB of its video.
#[derive(Debug, Clone)]
pub struct SmallFrame {
    width: u32,
    height: u32,
    /// Y (width x height), then Cb and Cr (ceil(width/2) x ceil(height/2) each).
    planes: Vec<u8>,
    conv: YuvToRgb,
}

impl SmallFrame {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.planes.len()
    }

    /// The luma plane.
    pub fn luma(&self) -> &[u8] {
        &self.planes[..self.width as usize * self.height as usize]
    }

    /// Converts to RGB into `out` (resized when its size differs).
    pub fn to_rgb_into(&self, out: &mut RgbImage) {
        let n = self.width as usize * self.height as usize;
        let c = chroma_len(self.width, self.height);
        let (y, rest) = self.planes.split_at(n);
        let (cb, cr) = rest.split_at(c);
        self.conv.convert_into(y, cb, cr, self.width, self.height, 2, 2, out);
    }

    /// Scales decoded planes down into a small frame (reusing `reuse`'s buffer):
    /// `y` is `width` x `height`; `cb`/`cr` are subsampled by `sub` (1: 4:4:4, 2: 4:2:0)
    /// with row stride `ceil(width / sub)`.
    ///
    /// # Errors
    /// Plane lengths that do not match the sizes; a target larger than the source.
    #[allow(clippy::too_many_arguments)]
    pub fn from_planes(
        y: &[u8],
        cb: &[u8],
        cr: &[u8],
        width: u32,
        height: u32,
        sub: u32,
        size: (u32, u32),
        conv: YuvToRgb,
        scaler: &mut PlaneScaler,
        reuse: Option<SmallFrame>,
    ) -> Result<SmallFrame> {
        if !(sub == 1 || sub == 2) {
            return Err(Error::invalid("chroma subsampling", sub, "1 or 2"));
        }
        let (cw, ch) = (width.div_ceil(sub), height.div_ceil(sub));
        let n = width as usize * height as usize;
        let c = cw as usize * ch as usize;
        if y.len() != n || cb.len() != c || cr.len() != c {
            return Err(Error::invalid(
                "frame planes",
                format!("{} / {} / {} bytes", y.len(), cb.len(), cr.len()),
                format!("{n} / {c} / {c} for {width}x{height}, chroma / {sub}"),
            ));
        }
        let (w, h) = size;
        if w == 0 || h == 0 || w > width || h > height {
            return Err(Error::invalid(
                "small frame size",
                format!("{w}x{h}"),
                format!("1..={width} x 1..={height}"),
            ));
        }
        let (sw, sh) = (w.div_ceil(2), h.div_ceil(2));
        let total = w as usize * h as usize + 2 * sw as usize * sh as usize;
        let mut planes = reuse.map(|r| r.planes).unwrap_or_default();
        planes.resize(total, 0);
        let (py, rest) = planes.split_at_mut(w as usize * h as usize);
        let (pcb, pcr) = rest.split_at_mut(sw as usize * sh as usize);
        scaler.scale(y, (width, height), py, (w, h));
        scaler.scale(cb, (cw, ch), pcb, (sw, sh));
        scaler.scale(cr, (cw, ch), pcr, (sw, sh));
        Ok(SmallFrame {
            width: w,
            height: h,
            planes,
            conv,
        })
    }
}

fn chroma_len(width: u32, height: u32) -> usize {
    width.div_ceil(2) as usize * height.div_ceil(2) as usize
}

/// Filter taps of one axis: for each output sample, the first input sample and its
/// weights (`taps` per output, zero-padded).
#[derive(Debug, Clone, Default, PartialEq)]
struct AxisTaps {
    from: u32,
    to: u32,
    taps: usize,
    start: Vec<usize>,
    weights: Vec<f32>,
}

impl AxisTaps {
    /// Triangle filter from `from` samples to `to` (<= `from`) samples, sample centres
    /// aligned (as ffmpeg's scaler and image-rs's `Triangle`).
    fn new(from: u32, to: u32) -> AxisTaps {
        let scale = f64::from(to) / f64::from(from);
        let support = (1.0 / scale).max(1.0);
        let taps = (2.0 * support).ceil() as usize + 1;
        let mut start = Vec::with_capacity(to as usize);
        let mut weights = vec![0.0f32; taps * to as usize];
        for i in 0..to as usize {
            let centre = (i as f64 + 0.5) / scale - 0.5;
            let first = ((centre - support).floor() + 1.0).max(0.0) as usize;
            let first = first.min(from as usize - 1);
            let ws = &mut weights[i * taps..(i + 1) * taps];
            let mut sum = 0.0;
            for (k, w) in ws.iter_mut().enumerate() {
                let j = first + k;
                if j >= from as usize {
                    break;
                }
                let v = (1.0 - (j as f64 - centre).abs() / support).max(0.0);
                *w = v as f32;
                sum += v;
            }
            if sum > 0.0 {
                for w in ws.iter_mut() {
                    *w = (f64::from(*w) / sum) as f32;
                }
            } else {
                ws[0] = 1.0;
            }
            start.push(first);
        }
        AxisTaps {
            from,
            to,
            taps,
            start,
            weights,
        }
    }
}

/// Scales 8-bit planes down (separable triangle filter), caching the taps of the last
/// sizes it was used with and a row buffer, so that scaling frame after frame
/// allocates nothing.
#[derive(Debug, Clone, Default)]
pub struct PlaneScaler {
    axes: Vec<AxisTaps>,
    rows: Vec<f32>,
}

impl PlaneScaler {
    fn axis(&mut self, from: u32, to: u32) -> usize {
        if let Some(k) = self.axes.iter().position(|a| a.from == from && a.to == to) {
            return k;
        }
        if self.axes.len() >= 8 {
            self.axes.clear();
        }
        self.axes.push(AxisTaps::new(from, to));
        self.axes.len() - 1
    }

    /// Scales `src` (`from` = width x height) into `dst` (`to`, each at most `from`'s).
    /// Sizes are the caller's to check; mismatched lengths leave `dst` unchanged.
    pub fn scale(&mut self, src: &[u8], from: (u32, u32), dst: &mut [u8], to: (u32, u32)) {
        let (sw, sh) = (from.0 as usize, from.1 as usize);
        let (dw, dh) = (to.0 as usize, to.1 as usize);
        if src.len() != sw * sh || dst.len() != dw * dh || dw == 0 || dh == 0 || dw > sw || dh > sh {
            return;
        }
        if (sw, sh) == (dw, dh) {
            dst.copy_from_slice(src);
            return;
        }
        let ky = self.axis(from.1, to.1);
        let kx = self.axis(from.0, to.0);
        let mut row = std::mem::take(&mut self.rows);
        row.clear();
        // padded so that every output reads a whole set of taps (the padding's weights
        // are 0)
        row.resize(sw + self.axes[kx].taps, 0.0);
        let (ay, ax) = (&self.axes[ky], &self.axes[kx]);
        for (oy, out) in dst.chunks_exact_mut(dw).enumerate() {
            // vertical: a weighted sum of the input rows (vectorises over the row)
            row.iter_mut().for_each(|v| *v = 0.0);
            let first = ay.start[oy];
            for (k, &w) in ay.weights[oy * ay.taps..(oy + 1) * ay.taps].iter().enumerate() {
                let j = first + k;
                if w == 0.0 || j >= sh {
                    continue;
                }
                for (acc, &s) in row.iter_mut().zip(&src[j * sw..(j + 1) * sw]) {
                    *acc += w * f32::from(s);
                }
            }
            // horizontal
            match ax.taps {
                3 => horizontal::<3>(&row, ax, out),
                4 => horizontal::<4>(&row, ax, out),
                5 => horizontal::<5>(&row, ax, out),
                6 => horizontal::<6>(&row, ax, out),
                _ => {
                    for (ox, o) in out.iter_mut().enumerate() {
                        let first = ax.start[ox];
                        let ws = &ax.weights[ox * ax.taps..(ox + 1) * ax.taps];
                        let v: f32 = row[first..first + ax.taps].iter().zip(ws).map(|(a, b)| a * b).sum();
                        *o = (v + 0.5).clamp(0.0, 255.0) as u8;
                    }
                }
            }
        }
        self.rows = row;
    }
}

/// The horizontal pass with `N` taps per output (a fixed count the compiler unrolls).
fn horizontal<const N: usize>(row: &[f32], ax: &AxisTaps, out: &mut [u8]) {
    for ((o, &first), ws) in out.iter_mut().zip(&ax.start).zip(ax.weights.chunks_exact(N)) {
        let Some(src) = row.get(first..first + N) else {
            continue;
        };
        let mut v = 0.5;
        for k in 0..N {
            v += src[k] * ws[k];
        }
        *o = v.clamp(0.0, 255.0) as u8;
    }
}

/// Frames kept in memory, played back as a [`FrameSource`] (RGB and grey at their
/// size), in the order given.
#[derive(Debug)]
pub struct StoredFrames {
    path: PathBuf,
    info: VideoInfo,
    frames: Vec<(u64, f64, Arc<SmallFrame>)>,
    next: usize,
}

impl StoredFrames {
    /// A source over `frames` (index, timestamp, copy; increasing indices, all of one
    /// size) of the video `path`; `info` is the video's, its size replaced by the
    /// copies'.
    ///
    /// # Errors
    /// Frames of different sizes or out of order.
    pub fn new(path: &Path, info: &VideoInfo, frames: Vec<(u64, f64, Arc<SmallFrame>)>) -> Result<StoredFrames> {
        let size = frames
            .first()
            .map_or((info.width, info.height), |f| (f.2.width, f.2.height));
        if let Some(w) = frames.windows(2).find(|w| w[1].0 <= w[0].0) {
            return Err(Error::invalid(
                "stored frames",
                format!("frame {} after {}", w[1].0, w[0].0),
                "increasing frame indices",
            ));
        }
        if frames.iter().any(|f| (f.2.width, f.2.height) != size) {
            return Err(Error::invalid("stored frames", "frames of different sizes", "one size"));
        }
        Ok(StoredFrames {
            path: path.to_path_buf(),
            info: VideoInfo {
                width: size.0,
                height: size.1,
                ..info.clone()
            },
            frames,
            next: 0,
        })
    }
}

impl FrameSource for StoredFrames {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn read_into(&mut self, frame: &mut Frame) -> Result<bool> {
        let Some((index, time, small)) = self.frames.get(self.next) else {
            return Ok(false);
        };
        self.next += 1;
        ensure_gray(&mut frame.gray, small.width, small.height);
        frame.gray.copy_from_slice(small.luma());
        ensure_rgb(&mut frame.rgb, true, small.width, small.height);
        if let Some(rgb) = frame.rgb.as_mut() {
            small.to_rgb_into(rgb);
        }
        frame.index = *index;
        frame.timestamp_s = *time;
        frame.small = None;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::video::yuv::{ColorMatrix, ColorRange};
    use crate::video::SourceKind;

    fn conv() -> YuvToRgb {
        YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Full)
    }

    #[test]
    fn flat_planes_stay_flat_and_weights_sum_to_one() {
        let mut s = PlaneScaler::default();
        for (from, to) in [((480, 480), (360, 360)), ((1920, 1080), (640, 360)), ((7, 5), (3, 2))] {
            let src = vec![200u8; (from.0 * from.1) as usize];
            let mut dst = vec![0u8; (to.0 * to.1) as usize];
            s.scale(&src, from, &mut dst, to);
            assert!(dst.iter().all(|&v| v == 200), "{from:?} -> {to:?}");
        }
        for (from, to) in [(480u32, 360u32), (1080, 360), (5, 1), (9, 9)] {
            let a = AxisTaps::new(from, to);
            for i in 0..to as usize {
                let sum: f32 = a.weights[i * a.taps..(i + 1) * a.taps].iter().sum();
                assert!((sum - 1.0).abs() < 1e-5, "{from}->{to} output {i}: {sum}");
                assert!(
                    a.start[i]
                        + a.weights[i * a.taps..(i + 1) * a.taps]
                            .iter()
                            .rposition(|w| *w > 0.0)
                            .unwrap()
                        < from as usize
                );
            }
        }
    }

    #[test]
    fn a_ramp_scales_to_a_ramp_with_centres_aligned() {
        // 0, 2, 4, ... over 8 columns scaled to 4: each output averages its two inputs
        let src: Vec<u8> = (0..8u8).map(|x| 20 * x).collect();
        let mut dst = vec![0u8; 4];
        PlaneScaler::default().scale(&src, (8, 1), &mut dst, (4, 1));
        // centres 0.5, 2.5, 4.5, 6.5 (interior ones are exact, the ends are clipped)
        assert_eq!(&dst[1..3], &[50, 90]);
        assert!(dst[0] <= 20 && dst[3] >= 120, "{dst:?}");
    }

    #[test]
    fn small_frame_converts_like_the_full_frame() {
        let (w, h) = (64u32, 48u32);
        let y: Vec<u8> = (0..w * h).map(|i| (60 + (i % w)) as u8).collect();
        let cb = vec![90u8; (w.div_ceil(2) * h.div_ceil(2)) as usize];
        let cr = vec![200u8; cb.len()];
        let mut sc = PlaneScaler::default();
        let f = SmallFrame::from_planes(&y, &cb, &cr, w, h, 2, (32, 24), conv(), &mut sc, None).unwrap();
        assert_eq!((f.width(), f.height()), (32, 24));
        assert_eq!(f.bytes(), 32 * 24 + 2 * 16 * 12);
        let mut rgb = RgbImage::new(1, 1);
        f.to_rgb_into(&mut rgb);
        assert_eq!(rgb.dimensions(), (32, 24));
        // middle column: luma 60 + ~2*16 + 0.5; colour of (Y, 90, 200)
        let want = conv().pixel(f.luma()[16], 90, 200);
        assert_eq!(rgb.get_pixel(16, 10).0, want);
        // 4:4:4 input gives the same chroma
        let cb4 = vec![90u8; (w * h) as usize];
        let cr4 = vec![200u8; cb4.len()];
        let g = SmallFrame::from_planes(&y, &cb4, &cr4, w, h, 1, (32, 24), conv(), &mut sc, Some(f.clone())).unwrap();
        assert_eq!(g.planes, f.planes);
    }

    #[test]
    fn bad_planes_and_sizes_are_errors() {
        let mut sc = PlaneScaler::default();
        let y = vec![0u8; 16];
        let c = vec![0u8; 4];
        assert!(SmallFrame::from_planes(&y, &c, &c, 4, 4, 2, (2, 2), conv(), &mut sc, None).is_ok());
        assert!(SmallFrame::from_planes(&y[..15], &c, &c, 4, 4, 2, (2, 2), conv(), &mut sc, None).is_err());
        assert!(SmallFrame::from_planes(&y, &c, &c, 4, 4, 2, (8, 2), conv(), &mut sc, None).is_err());
        assert!(SmallFrame::from_planes(&y, &c, &c, 4, 4, 3, (2, 2), conv(), &mut sc, None).is_err());
        let tap = ColourTap {
            size: (641, 360),
            select: FrameSelect {
                stride: 2,
                extra: vec![],
            },
        };
        assert!(tap.validate(640, 480).is_err());
        assert!(ColourTap {
            size: (640, 360),
            ..tap.clone()
        }
        .validate(640, 480)
        .is_ok());
        assert!(ColourTap {
            size: (640, 360),
            select: FrameSelect {
                stride: 0,
                extra: vec![]
            }
        }
        .validate(640, 480)
        .is_err());
    }

    #[test]
    fn stored_frames_play_back_in_order() {
        let mut sc = PlaneScaler::default();
        let y = vec![100u8; 16];
        let c = vec![128u8; 4];
        let f = Arc::new(SmallFrame::from_planes(&y, &c, &c, 4, 4, 2, (2, 2), conv(), &mut sc, None).unwrap());
        let info = VideoInfo {
            width: 4,
            height: 4,
            fps: 30.0,
            frame_count: Some(10),
            duration_s: None,
            codec: "h264".into(),
            kind: SourceKind::Video,
        };
        let mut s = StoredFrames::new(
            Path::new("v.mp4"),
            &info,
            vec![(0, 0.0, f.clone()), (4, 0.133, f.clone())],
        )
        .unwrap();
        assert_eq!((s.info().width, s.info().height, s.info().fps), (2, 2, 30.0));
        let mut fr = Frame::default();
        assert!(s.read_into(&mut fr).unwrap());
        assert_eq!(
            (fr.index, fr.rgb.as_ref().unwrap().get_pixel(1, 1).0),
            (0, [100, 100, 100])
        );
        assert!(s.read_into(&mut fr).unwrap());
        assert_eq!((fr.index, fr.timestamp_s), (4, 0.133));
        assert!(!s.read_into(&mut fr).unwrap());
        assert!(StoredFrames::new(Path::new("v"), &info, vec![(4, 0.0, f.clone()), (4, 0.0, f)]).is_err());
    }
}
