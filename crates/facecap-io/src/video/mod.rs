//! Frame sources: video files (through an `ffmpeg` child process), Y4M files (native
//! parser) and folders of images, all behind one [`FrameSource`] trait.
//!
//! Every source yields [`Frame`]s in presentation order with a 0-based `index` and a
//! presentation timestamp in seconds, a grey image always and an RGB image when
//! [`SourceOptions::rgb`] is set. [`open_source`] picks the source from the path:
//!
//! | path | source | timestamps |
//! |---|---|---|
//! | a directory | [`folder::ImageFolderSource`]: files with an image extension (`png jpg jpeg pgm ppm pbm pnm`), sorted by file name (byte order: zero-pad numbers) | `index / folder_fps` |
//! | a single image file | the same source with one frame | 0 |
//! | extension `.y4m` or content starting with `YUV4MPEG2 ` | [`y4m::Y4mSource`] | `index * F_den / F_num` |
//! | anything else | [`ffmpeg::FfmpegSource`] | the frame's pts (`pts * time_base`), exactly what `ffprobe -show_entries frame=pts_time` reports |
//!
//! ## Grey levels
//! Decoded video is Y'CbCr; the grey image is the decoder's **luma plane** (never
//! ffmpeg's `-pix_fmt gray` conversion). [`Luma`] chooses whether those codes are
//! expanded from the limited video range 16..235 to 0..255 (`Luma::Full`, the default: the
//! grey levels an OpenCV `BGR2GRAY` pipeline sees, and the range of still images and
//! of the models trained on them) or left as stored (`Luma::AsStored`). See
//! `docs/video.md` for the measurements behind this choice.
//!
//! ## Example
//! ```
//! use facecap_io::video::{open_source, Frame, SourceOptions};
//! # fn main() -> facecap_core::Result<()> {
//! let dir = tempfile::tempdir().map_err(|e| facecap_core::Error::io("tempdir", e))?;
//! let path = dir.path().join("clip.y4m");
//! // A 4x2, two-frame 4:2:0 Y4M file.
//! let mut bytes = b"YUV4MPEG2 W4 H2 F25:1 C420jpeg\n".to_vec();
//! for v in [16u8, 235] {
//!     bytes.extend_from_slice(b"FRAME\n");
//!     bytes.extend(std::iter::repeat(v).take(8));
//!     bytes.extend([128u8; 4]);
//! }
//! std::fs::write(&path, &bytes).map_err(|e| facecap_core::Error::io(&path, e))?;
//! let mut src = open_source(&path, &SourceOptions::default())?;
//! assert_eq!(src.info().frame_count, Some(2));
//! let mut frame = Frame::default();
//! let mut times = Vec::new();
//! while src.read_into(&mut frame)? {
//!     times.push((frame.index, frame.timestamp_s, frame.gray.get_pixel(0, 0)[0]));
//! }
//! assert_eq!(times, vec![(0, 0.0, 0), (1, 0.04, 255)]);
//! # Ok(()) }
//! ```

use std::fmt::Debug;
use std::path::{Path, PathBuf};

use image::{GrayImage, RgbImage};

use facecap_core::error::{Error, Result};

pub mod encode;
pub mod ffmpeg;
pub mod folder;
pub mod mp4;
pub mod small;
pub mod y4m;
pub mod yuv;

/// Frames per second used for image folders when the caller gives none.
pub const DEFAULT_FOLDER_FPS: f64 = 30.0;

/// One decoded frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// 0-based position in presentation order.
    pub index: u64,
    /// Presentation timestamp in seconds (from the container for video files).
    pub timestamp_s: f64,
    /// 8-bit grey image (see the module docs for the grey levels).
    pub gray: GrayImage,
    /// 8-bit RGB image, present when [`SourceOptions::rgb`] was set.
    pub rgb: Option<RgbImage>,
    /// A small colour copy, present on the frames a [`small::ColourTap`] selects
    /// ([`FrameSource::tap_colour`]). Its buffer is reused when the frame is.
    pub small: Option<small::SmallFrame>,
}

impl Default for Frame {
    fn default() -> Self {
        Frame {
            index: 0,
            timestamp_s: 0.0,
            gray: GrayImage::new(0, 0),
            rgb: None,
            small: None,
        }
    }
}

/// What kind of source a [`FrameSource`] reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// A video file decoded by ffmpeg.
    Video,
    /// A YUV4MPEG2 file.
    Y4m,
    /// A folder of images.
    ImageFolder,
    /// A single image file.
    Image,
}

/// Stream properties known when a source is opened.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoInfo {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Nominal frame rate (frames per second).
    pub fps: f64,
    /// Number of frames if the container states it (video) or it is known (Y4M, folders).
    pub frame_count: Option<u64>,
    /// Duration in seconds if known.
    pub duration_s: Option<f64>,
    /// Codec name (ffmpeg's short name, e.g. `h264`, `mpeg4`; `y4m 420jpeg`; `images`).
    pub codec: String,
    /// Which source reads it.
    pub kind: SourceKind,
}

/// How grey levels of Y'CbCr sources are delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Luma {
    /// Limited-range luma (16..235) expanded to 0..255 with `round((Y-16)*255/219)`;
    /// full-range sources are left as they are. Default.
    #[default]
    Full,
    /// The luma codes exactly as stored in the stream.
    AsStored,
}

/// Options of [`open_source`].
///
/// | field | default | meaning | range |
/// |---|---|---|---|
/// | `rgb` | `false` | also produce [`Frame::rgb`] | |
/// | `folder_fps` | 30 | frame rate of image folders (timestamps `index / fps`) | finite, > 0 |
/// | `luma` | [`Luma::Full`] | grey levels of Y'CbCr sources | |
/// | `ffmpeg` | `None` | ffmpeg binary; `None` = [`ffmpeg::locate_ffmpeg`] | existing file |
/// | `strict` | `true` | stop with an error at the first decode error instead of letting ffmpeg conceal it (never hands out a damaged frame) | |
/// | `threads` | 0 | ffmpeg decoder threads (0 = ffmpeg's choice) | 0..=64 |
/// | `scale` | `None` | video files only: ffmpeg scales every frame to this width x height (bilinear) before it reaches the pipe, so a caller that wants small frames neither moves nor converts full ones; Y4M files and images keep their size | 1..=8192 each |
/// | `select` | `None` | video files only: deliver only the frames a [`FrameSelect`] names (ffmpeg drops the others before scaling, converting and piping them); delivered frames keep their indices and timestamps, so indices jump over the dropped ones; Y4M files and images deliver every frame | see [`FrameSelect`] |
/// | `probe_frame_count` | `true` | video files only: run `ffprobe` for [`VideoInfo::frame_count`] (a caller that knows it already can save the process) | |
#[derive(Debug, Clone, PartialEq)]
pub struct SourceOptions {
    /// Also produce RGB frames.
    pub rgb: bool,
    /// Frame rate of image folders.
    pub folder_fps: f64,
    /// Grey levels of Y'CbCr sources.
    pub luma: Luma,
    /// Explicit ffmpeg binary.
    pub ffmpeg: Option<PathBuf>,
    /// Stop at the first decode error (see the table).
    pub strict: bool,
    /// ffmpeg decoder threads (0 = automatic).
    pub threads: u32,
    /// Frame size ffmpeg scales video files to (see the table).
    pub scale: Option<(u32, u32)>,
    /// Frames of video files to deliver (see the table).
    pub select: Option<FrameSelect>,
    /// Ask ffprobe for the frame count of video files.
    pub probe_frame_count: bool,
}

/// Which frames of a video file [`SourceOptions::select`] delivers: frame `k` (0-based,
/// in decoding order, as [`Frame::index`]) when `k % stride == 0` or `k` is in `extra`.
///
/// | field | meaning | range |
/// |---|---|---|
/// | `stride` | every `stride`-th frame, from frame 0 | 1..=[`MAX_SELECT_STRIDE`] |
/// | `extra` | further frames | at most [`MAX_SELECT_EXTRA`] |
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameSelect {
    /// Every `stride`-th frame.
    pub stride: u64,
    /// Further frame indices.
    pub extra: Vec<u64>,
}

/// Largest [`FrameSelect::stride`].
pub const MAX_SELECT_STRIDE: u64 = 1000;
/// Most [`FrameSelect::extra`] indices.
pub const MAX_SELECT_EXTRA: usize = 256;

impl FrameSelect {
    /// Whether frame `k` is delivered.
    pub fn contains(&self, k: u64) -> bool {
        (self.stride > 0 && k % self.stride == 0) || self.extra.contains(&k)
    }

    /// Checks the fields (see the table).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the field.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_SELECT_STRIDE).contains(&self.stride) {
            return Err(Error::invalid(
                "select stride",
                self.stride,
                format!("1..={MAX_SELECT_STRIDE}"),
            ));
        }
        if self.extra.len() > MAX_SELECT_EXTRA {
            return Err(Error::invalid(
                "select extra",
                format!("{} frames", self.extra.len()),
                format!("at most {MAX_SELECT_EXTRA}"),
            ));
        }
        Ok(())
    }

    /// The expression of ffmpeg's `select` filter for these frames (commas escaped for a
    /// filter graph), on the frame number `n` the filter counts.
    pub fn ffmpeg_expr(&self) -> String {
        let mut e = format!("not(mod(n\\,{}))", self.stride);
        let mut extra = self.extra.clone();
        extra.sort_unstable();
        extra.dedup();
        for k in extra.iter().filter(|&&k| k % self.stride != 0) {
            e.push_str(&format!("+eq(n\\,{k})"));
        }
        e
    }
}

impl Default for SourceOptions {
    fn default() -> Self {
        SourceOptions {
            rgb: false,
            folder_fps: DEFAULT_FOLDER_FPS,
            luma: Luma::Full,
            ffmpeg: None,
            strict: true,
            threads: 0,
            scale: None,
            select: None,
            probe_frame_count: true,
        }
    }
}

/// Largest accepted `threads`.
pub const MAX_THREADS: u32 = 64;

impl SourceOptions {
    /// Checks the parameters (see the table on [`SourceOptions`]).
    pub fn validate(&self) -> Result<()> {
        if !(self.folder_fps.is_finite() && self.folder_fps > 0.0) {
            return Err(Error::invalid("folder_fps", self.folder_fps, "a finite number > 0"));
        }
        if self.threads > MAX_THREADS {
            return Err(Error::invalid("threads", self.threads, format!("0..={MAX_THREADS}")));
        }
        if let Some((w, h)) = self.scale {
            if !((1..=8192).contains(&w) && (1..=8192).contains(&h)) {
                return Err(Error::invalid("scale", format!("{w}x{h}"), "1..=8192 pixels each"));
            }
        }
        if let Some(s) = &self.select {
            s.validate()?;
        }
        Ok(())
    }
}

/// A stream of frames. Implementations end a stream cleanly (`Ok(false)` / `Ok(None)`)
/// only when every frame was delivered; damaged input gives an [`Error::Decode`] naming
/// the file and the frame index.
pub trait FrameSource: Send + Debug {
    /// Stream properties.
    fn info(&self) -> &VideoInfo;

    /// The file or folder being read.
    fn path(&self) -> &Path;

    /// Decodes the next frame into `frame`, reusing its buffers when they have the
    /// right size (no allocation per frame after the first). Returns `Ok(false)` at the
    /// end of the stream, leaving `frame` unspecified.
    ///
    /// # Errors
    /// [`Error::Decode`] (with the frame index) for damaged or inconsistent data,
    /// [`Error::Io`] for read failures, [`Error::Tool`] when ffmpeg fails to run.
    fn read_into(&mut self, frame: &mut Frame) -> Result<bool>;

    /// Keeps a small colour copy ([`Frame::small`]) of the frames `tap` selects from
    /// now on. Returns whether this source can (video files through ffmpeg can; the
    /// others return `false` and deliver no copies).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when the tap does not fit the video
    /// ([`small::ColourTap::validate`]).
    fn tap_colour(&mut self, tap: small::ColourTap) -> Result<bool> {
        tap.validate(self.info().width, self.info().height)?;
        Ok(false)
    }

    /// Allocating convenience form of [`FrameSource::read_into`].
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let mut f = Frame::default();
        Ok(self.read_into(&mut f)?.then_some(f))
    }
}

/// Opens `path` as a frame source (see the module docs for how the source is chosen).
///
/// # Errors
/// [`Error::InvalidParameter`] for bad options, [`Error::Io`] when the path does not
/// exist, [`Error::Decode`] when it is not a readable video / Y4M / image folder,
/// [`Error::Tool`] when a video needs ffmpeg and none is found.
pub fn open_source(path: impl AsRef<Path>, opts: &SourceOptions) -> Result<Box<dyn FrameSource>> {
    let path = path.as_ref();
    opts.validate()?;
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Ok(Box::new(folder::ImageFolderSource::open_dir(path, opts)?));
    }
    if meta.len() == 0 {
        return Err(Error::Decode {
            path: path.to_path_buf(),
            frame: None,
            reason: "empty file (0 bytes)".into(),
        });
    }
    let ext_is = |e: &str| path.extension().is_some_and(|x| x.eq_ignore_ascii_case(e));
    if ext_is("y4m") || y4m::is_y4m(path)? {
        return Ok(Box::new(y4m::Y4mSource::open(path, opts)?));
    }
    if crate::image_io::has_image_extension(path) {
        return Ok(Box::new(folder::ImageFolderSource::open_image(path, opts)?));
    }
    Ok(Box::new(ffmpeg::FfmpegSource::open(path, opts)?))
}

/// Makes `img` `width x height`, reallocating only when the size differs.
pub(crate) fn ensure_gray(img: &mut GrayImage, width: u32, height: u32) {
    if img.dimensions() != (width, height) {
        *img = GrayImage::new(width, height);
    }
}

/// Makes `frame.rgb` hold a `width x height` image when `want`, else `None`.
pub(crate) fn ensure_rgb(rgb: &mut Option<RgbImage>, want: bool, width: u32, height: u32) {
    if !want {
        *rgb = None;
        return;
    }
    match rgb {
        Some(img) if img.dimensions() == (width, height) => {}
        _ => *rgb = Some(RgbImage::new(width, height)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_select_expression_and_membership() {
        let s = FrameSelect {
            stride: 2,
            extra: vec![9, 4, 9, 3],
        };
        assert_eq!(s.ffmpeg_expr(), "not(mod(n\\,2))+eq(n\\,3)+eq(n\\,9)");
        let got: Vec<u64> = (0..10).filter(|&k| s.contains(k)).collect();
        assert_eq!(got, vec![0, 2, 3, 4, 6, 8, 9]);
        assert!(s.validate().is_ok());
        assert!(FrameSelect {
            stride: 0,
            extra: vec![]
        }
        .validate()
        .is_err());
    }
}
