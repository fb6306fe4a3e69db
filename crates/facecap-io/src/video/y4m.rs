//! Native YUV4MPEG2 (`.y4m`) reader.
//!
//! Format (as written by ffmpeg, x264, mjpegtools): one ASCII header line
//! `YUV4MPEG2 W<w> H<h> F<num>:<den> [I<p|t|b|m>] [A<n>:<d>] [C<space>] [X<ext>]...\n`,
//! then per frame `FRAME[ params]\n` followed by the planes Y (`w*h` bytes) and, for
//! colour spaces with chroma, Cb and Cr (`ceil(w/sx)*ceil(h/sy)` bytes each).
//!
//! | `C` tag | planes | chroma subsampling (sx, sy) |
//! |---|---|---|
//! | `420jpeg`, `420paldv`, `420mpeg2`, `420` (default when absent) | Y, Cb, Cr | (2, 2) |
//! | `422` | Y, Cb, Cr | (2, 1) |
//! | `444` | Y, Cb, Cr | (1, 1) |
//! | `444alpha` | Y, Cb, Cr, A (alpha ignored) | (1, 1) |
//! | `mono` | Y | - |
//!
//! Higher bit depths (`420p10`, `mono16`, ...) are rejected with an error naming the tag.
//! The chroma siting variants only differ in where chroma samples sit; this reader
//! samples chroma nearest for RGB output, so they are treated alike. Range: the `X`
//! extension `XCOLORRANGE=FULL|LIMITED` when present, else limited for Y'CbCr and full
//! for `mono` (what ffmpeg writes for `gray`). Matrix: BT.601 (Y4M has no field for it).
//! Timestamps are `index * den / num`.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::yuv::{expand_limited_luma, limited_to_full_luma_lut, ColorMatrix, ColorRange, YuvToRgb};
use super::{ensure_gray, ensure_rgb, Frame, FrameSource, Luma, SourceKind, SourceOptions, VideoInfo};
use facecap_core::error::{Error, Result};

/// Magic at the start of every Y4M file.
pub const MAGIC: &[u8] = b"YUV4MPEG2 ";
/// Longest accepted stream header line.
const MAX_HEADER_LEN: usize = 4096;
/// Longest accepted `FRAME` line.
const MAX_FRAME_HEADER_LEN: usize = 1024;
/// Largest accepted frame side, a guard against absurd headers.
const MAX_SIDE: u32 = 1 << 15;

/// Whether the file starts with the Y4M magic.
pub fn is_y4m(path: &Path) -> Result<bool> {
    let mut f = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut buf = [0u8; 10];
    let mut n = 0;
    while n < buf.len() {
        match f.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(Error::io(path, e)),
        }
    }
    Ok(&buf[..n] == MAGIC)
}

/// Parsed stream header.
#[derive(Debug, Clone, PartialEq)]
pub struct Y4mHeader {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Frame rate numerator.
    pub fps_num: u32,
    /// Frame rate denominator.
    pub fps_den: u32,
    /// Colour space tag without the `C` (e.g. `420jpeg`).
    pub colorspace: String,
    /// Chroma subsampling `(sx, sy)`, `None` for mono.
    pub subsampling: Option<(u32, u32)>,
    /// Whether an alpha plane follows the chroma planes.
    pub alpha: bool,
    /// Code range of the samples.
    pub range: ColorRange,
}

impl Y4mHeader {
    /// Bytes of one chroma plane.
    fn chroma_len(&self) -> usize {
        match self.subsampling {
            Some((sx, sy)) => self.width.div_ceil(sx) as usize * self.height.div_ceil(sy) as usize,
            None => 0,
        }
    }

    /// Bytes of one frame's planes.
    pub fn frame_len(&self) -> usize {
        let y = self.width as usize * self.height as usize;
        let c = if self.subsampling.is_some() {
            2 * self.chroma_len()
        } else {
            0
        };
        y + c + if self.alpha { y } else { 0 }
    }
}

/// Parses the header line (without the trailing newline).
pub fn parse_header(path: &Path, line: &[u8]) -> Result<Y4mHeader> {
    let bad = |reason: String| Error::parse("Y4M", path, reason);
    let text = std::str::from_utf8(line).map_err(|_| bad("header is not ASCII".into()))?;
    let rest = text
        .strip_prefix("YUV4MPEG2")
        .ok_or_else(|| bad("missing YUV4MPEG2 magic".into()))?;
    let (mut w, mut h, mut fps) = (None, None, None);
    let mut cs = "420jpeg".to_string();
    let mut range = None;
    for tok in rest.split_ascii_whitespace() {
        let (tag, val) = tok.split_at(1);
        match tag {
            "W" => w = Some(val.parse::<u32>().map_err(|_| bad(format!("bad width {tok:?}")))?),
            "H" => h = Some(val.parse::<u32>().map_err(|_| bad(format!("bad height {tok:?}")))?),
            "F" => {
                let (n, d) = val
                    .split_once(':')
                    .ok_or_else(|| bad(format!("bad frame rate {tok:?}")))?;
                let n = n.parse::<u32>().map_err(|_| bad(format!("bad frame rate {tok:?}")))?;
                let d = d.parse::<u32>().map_err(|_| bad(format!("bad frame rate {tok:?}")))?;
                if n == 0 || d == 0 {
                    return Err(bad(format!("frame rate {tok:?} must be positive")));
                }
                fps = Some((n, d));
            }
            "C" => cs = val.to_string(),
            "X" => {
                if let Some(r) = val.strip_prefix("COLORRANGE=") {
                    range = match r {
                        "FULL" => Some(ColorRange::Full),
                        "LIMITED" => Some(ColorRange::Limited),
                        _ => None,
                    };
                }
            }
            _ => {} // I (interlacing), A (aspect) and unknown tags do not change decoding.
        }
    }
    let width = w.ok_or_else(|| bad("header lacks W (width)".into()))?;
    let height = h.ok_or_else(|| bad("header lacks H (height)".into()))?;
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(bad(format!("frame size {width}x{height} outside 1..={MAX_SIDE}")));
    }
    let (fps_num, fps_den) = fps.ok_or_else(|| bad("header lacks F (frame rate)".into()))?;
    let (subsampling, alpha) = match cs.as_str() {
        "420jpeg" | "420paldv" | "420mpeg2" | "420" => (Some((2, 2)), false),
        "422" => (Some((2, 1)), false),
        "444" => (Some((1, 1)), false),
        "444alpha" => (Some((1, 1)), true),
        "mono" => (None, false),
        other => {
            return Err(bad(format!(
                "unsupported colour space C{other} (8-bit 420*, 422, 444, 444alpha and mono are supported)"
            )))
        }
    };
    let range = range.unwrap_or(if subsampling.is_some() {
        ColorRange::Limited
    } else {
        ColorRange::Full
    });
    Ok(Y4mHeader {
        width,
        height,
        fps_num,
        fps_den,
        colorspace: cs,
        subsampling,
        alpha,
        range,
    })
}

/// Reads a Y4M stream frame by frame from any reader: a file ([`Y4mSource`]) or a pipe
/// (the live input's stdin or ffmpeg's stdout); see the module docs.
pub struct Y4mReader<R> {
    path: PathBuf,
    info: VideoInfo,
    header: Y4mHeader,
    reader: R,
    next_index: u64,
    line: Vec<u8>,
    chroma: Vec<u8>,
    /// Bytes after the stream header (0 when unknown, e.g. a pipe).
    body_len: u64,
    lut: Option<[u8; 256]>,
    rgb: bool,
    conv: YuvToRgb,
    done: bool,
}

/// A Y4M file (seekable: [`Y4mSource::rewind`], frame count from the file size).
pub type Y4mSource = Y4mReader<BufReader<File>>;

impl<R> std::fmt::Debug for Y4mReader<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Y4mReader")
            .field("path", &self.path)
            .field("info", &self.info)
            .field("header", &self.header)
            .field("next_index", &self.next_index)
            .finish()
    }
}

/// Reads bytes up to (not including) `\n` into `line`. Returns `Ok(false)` on EOF before
/// any byte; an EOF after some bytes is reported as `Ok(true)` with `*complete = false`.
fn read_line(r: &mut impl Read, line: &mut Vec<u8>, max: usize, complete: &mut bool) -> std::io::Result<bool> {
    line.clear();
    *complete = false;
    let mut b = [0u8; 1];
    loop {
        match r.read(&mut b) {
            Ok(0) => return Ok(!line.is_empty()),
            Ok(_) => {
                if b[0] == b'\n' {
                    *complete = true;
                    return Ok(true);
                }
                line.push(b[0]);
                if line.len() > max {
                    return Ok(true);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
}

impl Y4mSource {
    /// Opens a Y4M file and parses its header.
    pub fn open(path: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        Y4mReader::with_len(BufReader::with_capacity(1 << 16, file), path, opts, Some(file_len))
    }

    /// Rewinds to the first frame.
    pub fn rewind(&mut self) -> Result<()> {
        self.reader
            .seek(SeekFrom::Start(0))
            .map_err(|e| Error::io(&self.path, e))?;
        let mut complete = false;
        read_line(&mut self.reader, &mut self.line, MAX_HEADER_LEN, &mut complete)
            .map_err(|e| Error::io(&self.path, e))?;
        self.next_index = 0;
        self.done = false;
        Ok(())
    }
}

impl<R: Read> Y4mReader<R> {
    /// Reads the stream header from `reader` (buffer it: the reader is read a line at a
    /// time); `path` names the stream in errors. The frame count is unknown.
    ///
    /// # Errors
    /// A stream that does not start with a valid header line, invalid options.
    pub fn new(reader: R, path: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        Self::with_len(reader, path, opts, None)
    }

    /// The reader of a stream of `len` bytes in all, when known.
    fn with_len(mut reader: R, path: &Path, opts: &SourceOptions, len: Option<u64>) -> Result<Self> {
        let mut line = Vec::with_capacity(128);
        let mut complete = false;
        let got = read_line(&mut reader, &mut line, MAX_HEADER_LEN, &mut complete).map_err(|e| Error::io(path, e))?;
        if !got {
            return Err(Error::parse("Y4M", path, "empty stream: no header line"));
        }
        if !complete {
            return Err(Error::parse(
                "Y4M",
                path,
                "stream header is not terminated by a newline",
            ));
        }
        let header = parse_header(path, &line)?;
        let header_len = line.len() as u64 + 1;
        let body = len.map_or(0, |l| l.saturating_sub(header_len));
        // Exact frame count when every frame header is a bare "FRAME\n".
        let per_frame = header.frame_len() as u64 + 6;
        let frame_count = len.and_then(|_| (body % per_frame == 0).then_some(body / per_frame));
        let fps = f64::from(header.fps_num) / f64::from(header.fps_den);
        let info = VideoInfo {
            width: header.width,
            height: header.height,
            fps,
            frame_count,
            duration_s: frame_count.map(|n| n as f64 / fps),
            codec: format!("y4m {}", header.colorspace),
            kind: SourceKind::Y4m,
        };
        let lut = (opts.luma == Luma::Full && header.range == ColorRange::Limited).then(limited_to_full_luma_lut);
        let conv = YuvToRgb::new(ColorMatrix::Bt601, header.range);
        Ok(Y4mReader {
            path: path.to_path_buf(),
            info,
            chroma: Vec::new(),
            body_len: body,
            header,
            reader,
            next_index: 0,
            line,
            lut,
            rgb: opts.rgb,
            conv,
            done: false,
        })
    }

    /// The parsed stream header.
    pub fn header(&self) -> &Y4mHeader {
        &self.header
    }

    fn err(&self, reason: impl Into<String>) -> Error {
        Error::Decode {
            path: self.path.clone(),
            frame: Some(self.next_index),
            reason: reason.into(),
        }
    }

    fn read_frame(&mut self, frame: &mut Frame) -> Result<bool> {
        let mut complete = false;
        let got = read_line(&mut self.reader, &mut self.line, MAX_FRAME_HEADER_LEN, &mut complete)
            .map_err(|e| Error::io(&self.path, e))?;
        if !got {
            return Ok(false);
        }
        if !complete {
            return Err(self.err("the stream ends inside the FRAME header (truncated)"));
        }
        if !(self.line.starts_with(b"FRAME") && (self.line.len() == 5 || self.line[5] == b' ')) {
            let shown: String = String::from_utf8_lossy(&self.line).chars().take(20).collect();
            return Err(self.err(format!("expected a FRAME header, found {shown:?}")));
        }
        let (w, h) = (self.header.width, self.header.height);
        // The frame size comes from the header: check it against the bytes present before
        // any frame buffer is allocated (a 32768x32768 header on a short file would
        // otherwise reserve 1.5 GB for nothing). Buffers are allocated on the first frame.
        if self.next_index == 0 && self.body_len > 0 && self.header.frame_len() as u64 > self.body_len {
            return Err(self.err(format!(
                "the stream ends inside the frame data ({} bytes per frame for {w}x{h}, {} bytes after the header; truncated)",
                self.header.frame_len(),
                self.body_len
            )));
        }
        self.chroma.resize(2 * self.header.chroma_len(), 0);
        ensure_gray(&mut frame.gray, w, h);
        let truncated = |s: &Self, e: std::io::Error| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                s.err(format!(
                    "the stream ends inside the frame data ({} bytes per frame; truncated)",
                    s.header.frame_len()
                ))
            } else {
                Error::io(&s.path, e)
            }
        };
        if let Err(e) = self.reader.read_exact(frame.gray.as_mut()) {
            return Err(truncated(self, e));
        }
        if let Err(e) = self.reader.read_exact(&mut self.chroma) {
            return Err(truncated(self, e));
        }
        if self.header.alpha {
            // Skip the alpha plane.
            let n = u64::from(w) * u64::from(h);
            let skipped = std::io::copy(&mut (&mut self.reader).take(n), &mut std::io::sink())
                .map_err(|e| Error::io(&self.path, e))?;
            if skipped != n {
                return Err(self.err("the stream ends inside the alpha plane (truncated)"));
            }
        }
        ensure_rgb(&mut frame.rgb, self.rgb, w, h);
        if let Some(rgb) = frame.rgb.as_mut() {
            match self.header.subsampling {
                Some((sx, sy)) => {
                    let (cb, cr) = self.chroma.split_at(self.chroma.len() / 2);
                    self.conv.convert_into(frame.gray.as_raw(), cb, cr, w, h, sx, sy, rgb);
                }
                None => {
                    let lut = (self.header.range == ColorRange::Limited).then(limited_to_full_luma_lut);
                    for (o, &g) in rgb.as_mut().chunks_exact_mut(3).zip(frame.gray.as_raw()) {
                        let v = lut.map_or(g, |l| l[usize::from(g)]);
                        o.copy_from_slice(&[v, v, v]);
                    }
                }
            }
        }
        if self.lut.is_some() {
            expand_limited_luma(&mut frame.gray);
        }
        frame.index = self.next_index;
        frame.timestamp_s = self.next_index as f64 * f64::from(self.header.fps_den) / f64::from(self.header.fps_num);
        self.next_index += 1;
        Ok(true)
    }
}

impl<R: Read + Send> FrameSource for Y4mReader<R> {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn read_into(&mut self, frame: &mut Frame) -> Result<bool> {
        if self.done {
            return Ok(false);
        }
        let r = self.read_frame(frame);
        if !matches!(r, Ok(true)) {
            self.done = true;
        }
        r
    }
}

/// Writes frames as a 4:2:0 (`C420jpeg`, limited range) or mono Y4M stream: used by tests
/// and demos to make small videos without external tools. `frames` are grey images
/// (luma codes as stored); chroma is neutral (128).
pub fn write_gray_y4m(
    out: &mut impl std::io::Write,
    frames: &[image::GrayImage],
    fps_num: u32,
    fps_den: u32,
    mono: bool,
) -> std::io::Result<()> {
    let (w, h) = frames.first().map_or((0, 0), |f| f.dimensions());
    let cs = if mono { "mono" } else { "420jpeg" };
    writeln!(out, "YUV4MPEG2 W{w} H{h} F{fps_num}:{fps_den} Ip A1:1 C{cs}")?;
    let chroma = vec![128u8; 2 * (w.div_ceil(2) as usize) * (h.div_ceil(2) as usize)];
    for f in frames {
        out.write_all(b"FRAME\n")?;
        out.write_all(f.as_raw())?;
        if !mono {
            out.write_all(&chroma)?;
        }
    }
    Ok(())
}

/// Writes RGB frames as a 4:4:4 limited-range BT.601 Y4M stream.
pub fn write_rgb_y4m(out: &mut dyn std::io::Write, frames: &[image::RgbImage], fps: u32) -> std::io::Result<()> {
    let (w, h) = frames.first().map_or((0, 0), |f| f.dimensions());
    writeln!(out, "YUV4MPEG2 W{w} H{h} F{fps}:1 Ip A1:1 C444")?;
    let n = (w * h) as usize;
    let mut planes = vec![0u8; 3 * n];
    for f in frames {
        for (i, p) in f.pixels().enumerate() {
            let [r, g, b] = p.0.map(f64::from);
            planes[i] = (16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0).round() as u8;
            planes[n + i] = (128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0).round() as u8;
            planes[2 * n + i] = (128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0).round() as u8;
        }
        out.write_all(b"FRAME\n")?;
        out.write_all(&planes)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;

    #[test]
    fn header_tags() {
        let p = Path::new("x.y4m");
        let h = parse_header(p, b"YUV4MPEG2 W640 H480 F30000:1001 Ip A1:1 C420mpeg2 XYSCSS=420MPEG2").unwrap();
        assert_eq!((h.width, h.height, h.fps_num, h.fps_den), (640, 480, 30000, 1001));
        assert_eq!(h.frame_len(), 640 * 480 * 3 / 2);
        let h = parse_header(p, b"YUV4MPEG2 W3 H3 F25:1 C422").unwrap();
        assert_eq!(h.frame_len(), 9 + 2 * 2 * 3);
        let h = parse_header(p, b"YUV4MPEG2 W3 H3 F25:1 Cmono XCOLORRANGE=LIMITED").unwrap();
        assert_eq!((h.frame_len(), h.range), (9, ColorRange::Limited));
        assert!(parse_header(p, b"YUV4MPEG2 W3 H3 F25:1 C420p10")
            .unwrap_err()
            .to_string()
            .contains("C420p10"));
        assert!(parse_header(p, b"YUV4MPEG2 W3 F25:1")
            .unwrap_err()
            .to_string()
            .contains("H (height)"));
        assert!(parse_header(p, b"YUV4MPEG2 W3 H3 F0:1").is_err());
        assert!(parse_header(p, b"YUV4MPEG2 W0 H3 F1:1").is_err());
    }
}
