//! Video files encoded by an `ffmpeg` child process fed raw frames through a pipe,
//! written atomically.
//!
//! Command:
//!
//! ```text
//! ffmpeg -hide_banner -nostats -loglevel error -y -f rawvideo -pix_fmt yuv420p
//!        -s WxH -framerate FPS -i pipe:0 -an -c:v libx264 -preset P -crf C
//!        -pix_fmt yuv420p -movflags +faststart -f mp4 .NAME.tmp-PID
//! ```
//!
//! * Frames are given as RGB and converted here to BT.601 limited-range 4:2:0 (the
//!   conversion ffmpeg makes of RGB by default; chroma the mean of each 2x2 block):
//!   ffmpeg's own conversion of `rgb24` input costs about three times as much CPU, and
//!   the pipe carries half the bytes.
//! * H.264 in 4:2:0 (`yuv420p`) in an MP4 with the index at the front (`+faststart`):
//!   what browsers and common players play; width and height must be even (4:2:0).
//! * The output goes to the temporary name of a [`facecap_core::atomic::AtomicFile`] in the
//!   target's folder and is renamed onto the target only after ffmpeg exited
//!   successfully ([`FfmpegEncoder::finish`]); dropping the encoder without `finish`
//!   kills and reaps ffmpeg and removes the temporary file, so a half-written video never
//!   appears under its final name.
//! * Before the rename the file's top-level MP4 boxes are checked (they must tile the
//!   file, with the index `moov` and the samples `mdat`): on a full disk ffmpeg can exit
//!   0 after failing to write the index, leaving a file no player opens.
//! * ffmpeg's stderr is read by a thread (the last lines go into error messages), so a
//!   chatty ffmpeg can never block on a full pipe.

use std::collections::VecDeque;
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use image::RgbImage;

use super::ffmpeg::{locate_ffmpeg, INSTALL_HINT};
use facecap_core::atomic::AtomicFile;
use facecap_core::error::{Error, Result};

/// Lines of ffmpeg's stderr kept for error messages.
const LOG_TAIL_LINES: usize = 8;

/// Settings of [`FfmpegEncoder`].
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `fps` | 30 | frame rate written into the stream | finite, > 0 |
/// | `crf` | 23 | x264 constant rate factor (lower: better and larger) | 0..=51 |
/// | `preset` | `veryfast` | x264 speed preset | an x264 preset name |
/// | `ffmpeg` | `None` | ffmpeg binary ([`locate_ffmpeg`] when `None`) | |
#[derive(Debug, Clone, PartialEq)]
pub struct EncoderParams {
    /// Frames per second.
    pub fps: f64,
    /// x264 constant rate factor.
    pub crf: u32,
    /// x264 preset.
    pub preset: String,
    /// The ffmpeg binary.
    pub ffmpeg: Option<PathBuf>,
}

impl Default for EncoderParams {
    fn default() -> Self {
        EncoderParams {
            fps: 30.0,
            crf: 23,
            preset: "veryfast".into(),
            ffmpeg: None,
        }
    }
}

/// x264's preset names.
const PRESETS: [&str; 10] = [
    "ultrafast",
    "superfast",
    "veryfast",
    "faster",
    "fast",
    "medium",
    "slow",
    "slower",
    "veryslow",
    "placebo",
];

impl EncoderParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the field.
    pub fn validate(&self) -> Result<()> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(Error::invalid("fps", self.fps, "a finite frame rate > 0"));
        }
        if self.crf > 51 {
            return Err(Error::invalid("crf", self.crf, "0..=51"));
        }
        if !PRESETS.contains(&self.preset.as_str()) {
            return Err(Error::invalid("preset", &self.preset, PRESETS.join(", ")));
        }
        Ok(())
    }
}

/// An H.264 MP4 being written frame by frame (module docs).
#[derive(Debug)]
pub struct FfmpegEncoder {
    target: Option<AtomicFile>,
    path: PathBuf,
    child: Child,
    stdin: Option<ChildStdin>,
    tail: Arc<Mutex<VecDeque<String>>>,
    reader: Option<JoinHandle<()>>,
    width: u32,
    height: u32,
    frames: u64,
    /// The 4:2:0 planes of the frame being written.
    yuv: Vec<u8>,
}

/// Writes the BT.601 limited-range 4:2:0 planes (Y, then Cb, then Cr) of `img` (even
/// width and height) to `out`: Y = 16 + (66 R + 129 G + 25 B) / 256, chroma from the
/// mean of each 2x2 block.
pub fn rgb_to_yuv420(img: &RgbImage, out: &mut Vec<u8>) {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (cw, ch) = (w / 2, h / 2);
    out.clear();
    out.resize(w * h + 2 * cw * ch, 0);
    let (luma, chroma) = out.split_at_mut(w * h);
    let (cb, cr) = chroma.split_at_mut(cw * ch);
    let raw = img.as_raw();
    for (src, dst) in raw.chunks_exact(3 * w).zip(luma.chunks_exact_mut(w)) {
        for (p, y) in src.chunks_exact(3).zip(dst.iter_mut()) {
            let (r, g, b) = (i32::from(p[0]), i32::from(p[1]), i32::from(p[2]));
            *y = (((66 * r + 129 * g + 25 * b + 128) >> 8) + 16) as u8;
        }
    }
    for cy in 0..ch {
        let (top, bottom) = (
            &raw[3 * w * 2 * cy..3 * w * (2 * cy + 1)],
            &raw[3 * w * (2 * cy + 1)..3 * w * (2 * cy + 2)],
        );
        let (ub, vb) = (&mut cb[cw * cy..cw * (cy + 1)], &mut cr[cw * cy..cw * (cy + 1)]);
        for (cx, (u, v)) in ub.iter_mut().zip(vb.iter_mut()).enumerate() {
            let o = 6 * cx;
            let sum = |c: usize| {
                i32::from(top[o + c])
                    + i32::from(top[o + 3 + c])
                    + i32::from(bottom[o + c])
                    + i32::from(bottom[o + 3 + c])
            };
            let (r, g, b) = (sum(0), sum(1), sum(2));
            // sums of four: a shift by 10 is the mean's shift by 8
            *u = (((-38 * r - 74 * g + 112 * b + 512) >> 10) + 128) as u8;
            *v = (((112 * r - 94 * g - 18 * b + 512) >> 10) + 128) as u8;
        }
    }
}

impl FfmpegEncoder {
    /// Starts ffmpeg writing a `width` x `height` video to (the temporary name of) `path`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for odd or zero sizes and bad [`EncoderParams`];
    /// [`Error::Tool`] when ffmpeg is missing or cannot start; [`Error::Io`] when the
    /// folder is not writable.
    pub fn create(path: impl AsRef<Path>, width: u32, height: u32, params: &EncoderParams) -> Result<Self> {
        params.validate()?;
        if width == 0 || height == 0 || width % 2 != 0 || height % 2 != 0 {
            return Err(Error::invalid(
                "video size",
                format!("{width}x{height}"),
                "even, non-zero width and height (4:2:0 chroma)",
            ));
        }
        let ffmpeg = locate_ffmpeg(params.ffmpeg.as_deref())?;
        let target = AtomicFile::create(path)?;
        let mut cmd = Command::new(&ffmpeg);
        cmd.args(["-hide_banner", "-nostats", "-loglevel", "error", "-y"])
            .args([
                "-f",
                "rawvideo",
                "-pix_fmt",
                "yuv420p",
                "-s",
                &format!("{width}x{height}"),
            ])
            .args(["-framerate", &format!("{}", params.fps), "-i", "pipe:0", "-an"])
            .args([
                "-c:v",
                "libx264",
                "-preset",
                &params.preset,
                "-crf",
                &params.crf.to_string(),
            ])
            .args(["-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4"])
            .arg(target.temp_path())
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| Error::Tool {
            tool: ffmpeg.display().to_string(),
            reason: format!("cannot start: {e}; {INSTALL_HINT}"),
        })?;
        let (Some(stdin), Some(stderr)) = (child.stdin.take(), child.stderr.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(Error::Tool {
                tool: ffmpeg.display().to_string(),
                reason: "no pipes to the child process".into(),
            });
        };
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        let tail_w = tail.clone();
        let reader = std::thread::Builder::new()
            .name("facecap-ffmpeg-encode-stderr".into())
            .spawn(move || {
                for line in std::io::BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    if let Ok(mut t) = tail_w.lock() {
                        if t.len() == LOG_TAIL_LINES {
                            t.pop_front();
                        }
                        t.push_back(line);
                    }
                }
            });
        let reader = match reader {
            Ok(r) => r,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(Error::Tool {
                    tool: "ffmpeg".into(),
                    reason: format!("cannot start the stderr reader thread: {e}"),
                });
            }
        };
        Ok(FfmpegEncoder {
            path: target.target_path().to_path_buf(),
            target: Some(target),
            child,
            stdin: Some(stdin),
            tail,
            reader: Some(reader),
            width,
            height,
            frames: 0,
            yuv: Vec::new(),
        })
    }

    /// Frames written so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    fn tail_text(&mut self) -> String {
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        let t = self
            .tail
            .lock()
            .map(|t| t.iter().cloned().collect::<Vec<_>>().join(" | "));
        match t {
            Ok(s) if !s.is_empty() => format!("ffmpeg said: {s}"),
            _ => "ffmpeg printed nothing".into(),
        }
    }

    fn tool_error(&mut self, reason: String) -> Error {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let tail = self.tail_text();
        Error::Tool {
            tool: "ffmpeg".into(),
            reason: format!("encoding {}: {reason}; {tail}", self.path.display()),
        }
    }

    /// Appends one frame.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] for a frame of another size; [`Error::Tool`] when
    /// ffmpeg stopped (with the end of its log).
    pub fn write_frame(&mut self, img: &RgbImage) -> Result<()> {
        if img.width() != self.width || img.height() != self.height {
            return Err(Error::DimensionMismatch {
                what: format!("video frame {}x{} vs the stream", img.width(), img.height()),
                expected: (self.width * self.height) as usize,
                got: (img.width() * img.height()) as usize,
            });
        }
        rgb_to_yuv420(img, &mut self.yuv);
        let Some(stdin) = self.stdin.as_mut() else {
            return Err(self.tool_error("the encoder was already closed".into()));
        };
        if let Err(e) = stdin.write_all(&self.yuv) {
            return Err(self.tool_error(format!("writing frame {}: {e}", self.frames)));
        }
        self.frames += 1;
        Ok(())
    }

    /// Closes the pipe, waits for ffmpeg and renames the finished file onto its target.
    ///
    /// # Errors
    /// [`Error::Tool`] when ffmpeg failed or no frame was written; [`Error::Io`] from the
    /// rename. The temporary file is removed on error.
    pub fn finish(mut self) -> Result<u64> {
        drop(self.stdin.take());
        let status = self.child.wait().map_err(|e| Error::Tool {
            tool: "ffmpeg".into(),
            reason: format!("cannot wait for the child process: {e}"),
        })?;
        if !status.success() {
            let tail = self.tail_text();
            return Err(Error::Tool {
                tool: "ffmpeg".into(),
                reason: format!("encoding {} failed ({status}); {tail}", self.path.display()),
            });
        }
        if self.frames == 0 {
            return Err(Error::invalid("video", "no frames", "at least one frame"));
        }
        let frames = self.frames;
        if let Some(t) = &self.target {
            // ffmpeg can exit 0 after failing to write the index (a full disk while
            // `+faststart` rewrites the file): check the boxes before publishing it.
            if let Err(why) = check_mp4_boxes(t.temp_path()) {
                let tail = self.tail_text();
                return Err(Error::Tool {
                    tool: "ffmpeg".into(),
                    reason: format!(
                        "encoding {} left an incomplete file ({why}; is the disk full?); {tail}",
                        self.path.display()
                    ),
                });
            }
        }
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        match self.target.take() {
            Some(t) => t.commit()?,
            None => return Err(Error::invalid("video", "already finished", "one finish per encoder")),
        }
        Ok(frames)
    }
}

/// Checks that `path` is a whole MP4: top-level boxes (32- or 64-bit sizes) that tile the
/// file exactly, `moov` (the index) and `mdat` (the samples) among them.
fn check_mp4_boxes(path: &Path) -> std::result::Result<(), String> {
    use super::mp4::{box_at, BadBox};
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    let mut f = std::io::BufReader::with_capacity(64, f);
    let (mut pos, mut moov, mut mdat) = (0u64, false, false);
    while pos < len {
        let b = box_at(&mut f, pos, len).map_err(|e| match e {
            BadBox::Cut => format!("box header cut at byte {pos} of {len}"),
            BadBox::Overrun { size } => format!("box at byte {pos} claims {size} bytes, {} left", len - pos),
        })?;
        moov |= &b.kind == b"moov";
        mdat |= &b.kind == b"mdat";
        pos = b.end;
    }
    match (moov, mdat) {
        (true, true) => Ok(()),
        (false, _) => Err("no moov box".into()),
        (_, false) => Err("no mdat box".into()),
    }
}

impl Drop for FfmpegEncoder {
    fn drop(&mut self) {
        drop(self.stdin.take());
        if !matches!(self.child.try_wait(), Ok(Some(_))) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mp4_box_check_wants_whole_boxes_with_moov_and_mdat() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.mp4");
        let bx = |kind: &[u8], body: usize| {
            let mut b = ((8 + body) as u32).to_be_bytes().to_vec();
            b.extend_from_slice(kind);
            b.resize(8 + body, 7);
            b
        };
        let whole = [bx(b"ftyp", 8), bx(b"moov", 40), bx(b"mdat", 100)].concat();
        std::fs::write(&p, &whole).unwrap();
        assert_eq!(check_mp4_boxes(&p), Ok(()));
        std::fs::write(&p, &whole[..whole.len() - 1]).unwrap();
        assert!(check_mp4_boxes(&p).unwrap_err().contains("claims"));
        std::fs::write(&p, [bx(b"ftyp", 8), bx(b"mdat", 100)].concat()).unwrap();
        assert_eq!(check_mp4_boxes(&p), Err("no moov box".into()));
        std::fs::write(&p, &whole[..20]).unwrap();
        assert!(check_mp4_boxes(&p).is_err());
    }

    #[test]
    fn rejects_bad_parameters_and_sizes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.mp4");
        assert!(FfmpegEncoder::create(&p, 3, 4, &EncoderParams::default()).is_err());
        let bad = EncoderParams {
            fps: f64::NAN,
            ..EncoderParams::default()
        };
        assert!(FfmpegEncoder::create(&p, 4, 4, &bad).is_err());
        let bad = EncoderParams {
            preset: "quick".into(),
            ..EncoderParams::default()
        };
        assert!(FfmpegEncoder::create(&p, 4, 4, &bad).is_err());
        assert!(!p.exists());
    }

    #[test]
    fn rgb_to_yuv420_is_bt601_limited_range() {
        let mut out = Vec::new();
        let mut img = RgbImage::from_pixel(4, 2, image::Rgb([255, 255, 255]));
        for x in 2..4 {
            for y in 0..2 {
                img.put_pixel(x, y, image::Rgb([255, 0, 0]));
            }
        }
        rgb_to_yuv420(&img, &mut out);
        assert_eq!(out.len(), 8 + 2 + 2);
        // white: (235, 128, 128); red: (82, 90, 240) (the standard's 81.5, 90, 240)
        assert_eq!(&out[..8], &[235, 235, 82, 82, 235, 235, 82, 82]);
        assert_eq!(&out[8..], &[128, 90, 128, 240]);
        rgb_to_yuv420(&RgbImage::new(2, 2), &mut out);
        assert_eq!(out, vec![16, 16, 16, 16, 128, 128]);
    }

    #[test]
    fn encodes_a_playable_mp4_atomically_or_nothing() {
        if locate_ffmpeg(None).is_err() {
            println!("SKIP: no ffmpeg");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("clip.mp4");
        let params = EncoderParams {
            fps: 25.0,
            ..EncoderParams::default()
        };
        let mut enc = FfmpegEncoder::create(&p, 64, 48, &params).unwrap();
        for k in 0..10u8 {
            enc.write_frame(&RgbImage::from_pixel(64, 48, image::Rgb([k * 20, 100, 200])))
                .unwrap();
            assert!(!p.exists(), "nothing under the final name before finish");
        }
        assert!(enc.write_frame(&RgbImage::new(32, 48)).is_err());
        assert_eq!(enc.finish().unwrap(), 10);
        // Decoded back by our own ffmpeg source: 10 frames at 25 fps.
        let mut src = super::super::open_source(&p, &super::super::SourceOptions::default()).unwrap();
        assert_eq!((src.info().width, src.info().height), (64, 48));
        assert!((src.info().fps - 25.0).abs() < 1e-6);
        let mut f = super::super::Frame::default();
        let mut n = 0;
        while src.read_into(&mut f).unwrap() {
            n += 1;
        }
        assert_eq!(n, 10);
        // Dropped without finish: no file, no temporary left.
        let q = dir.path().join("never.mp4");
        let mut enc = FfmpegEncoder::create(&q, 64, 48, &params).unwrap();
        enc.write_frame(&RgbImage::new(64, 48)).unwrap();
        drop(enc);
        assert!(!q.exists());
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(left.len(), 1, "only clip.mp4 remains");
    }
}
