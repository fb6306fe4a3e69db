//! Video files decoded by an `ffmpeg` child process streaming raw frames through a pipe.
//!
//! Command (see `docs/video.md` for the measurements behind each choice):
//!
//! ```text
//! ffmpeg -nostdin -hide_banner -nostats -loglevel level+info [-xerror] [-threads N]
//!        -copyts -i FILE -map 0:V:0 -vf [format=pix_fmts=FORMATS,]showinfo=checksum=0
//!        [,select=EXPR][,scale=W:H:flags=bilinear] -fps_mode passthrough
//!        -f rawvideo [-pix_fmt yuv420p|yuv444p] pipe:1          (stdin = /dev/null)
//! ```
//!
//! * `-nostdin` + a null stdin: without them ffmpeg polls the terminal and decodes ~10x slower.
//! * Without scaling, `format=pix_fmts=yuv420p|yuvj420p` (grey only) or
//!   `yuv420p|yuvj420p|yuv444p|yuvj444p` (RGB requested) before `showinfo`: ffmpeg keeps
//!   a 4:2:0 source in 4:2:0 (for RGB: half the bytes of 4:4:4 through the pipe and no
//!   conversion in ffmpeg; a whole decode of a 480x480 H.264 clip took 0.77 s instead of
//!   1.34 s for 1008 frames on one core), turns other sources into the nearest listed
//!   format, keeps full-range (`yuvj`) codes as they are (`-pix_fmt yuv420p` squeezed them
//!   into 16-235 while the stream said full range), and `showinfo` reports the format of
//!   every frame (`fmt:`). With scaling, `-pix_fmt yuv420p` or `yuv444p`.
//! * The grey image is the luma plane copied straight from the pipe; RGB is converted
//!   here ([`super::yuv`]) from the same planes, so grey is identical whether or not RGB
//!   is requested. A 4:2:0 chroma sample serves the 2x2 pixels it covers, as ffmpeg's own
//!   `rgb24` conversion does: on 30 frames each of liveportrait_d6 / d18, mean |RGB -
//!   ffmpeg rgb24| 1.21 / 1.00, max 3, against 1.22 / 1.02, max 5 / 13 through ffmpeg's
//!   4:4:4 (a bilinear chroma was further off: 1.25 / 1.05, max 6 / 22).
//! * `showinfo` prints, for every frame and before its bytes reach the pipe, its index,
//!   `pts` and size on stderr; a reader thread parses those lines, so each frame gets the
//!   exact presentation timestamp `pts * time_base` (`-copyts`: no shift to zero, i.e.
//!   what `ffprobe -show_entries frame=pts_time` reports) and a size change is detected.
//! * `-fps_mode passthrough`: no frame is duplicated or dropped to fit a constant rate.
//! * `select=...` only with [`SourceOptions::select`]: the frames not selected are
//!   dropped after `showinfo` reported them (so every decoded frame still has its index
//!   and timestamp, and the source knows which reports have no bytes in the pipe) and
//!   before they are scaled, converted or piped. ffmpeg still decodes every frame (H.264
//!   frames depend on each other).
//! * `scale=...` only with [`SourceOptions::scale`]: ffmpeg's SIMD scaler shrinks the
//!   frames before they are piped and converted (`showinfo` comes first and reports the
//!   decoded size; a change of it is an error as without scaling).
//! * `-map 0:V:0`: the first video stream that is not an attached picture (cover art).
//! * Strict mode ([`SourceOptions::strict`], the default): `-xerror` makes ffmpeg 5 stop at
//!   the first decode error, and since ffmpeg 7 merely drops a damaged frame even then,
//!   the source also watches the log (`-loglevel level+info` tags each line with its
//!   level) and stops at the first `error`-level line: a damaged or truncated file yields
//!   the intact frames reported before the damage, then an [`Error::Decode`] naming the
//!   frame. Never a concealed (garbage) frame, never a silent gap. Lenient mode lets ffmpeg
//!   drop damaged frames and go on (measured: the frames it delivers are still intact).
//!
//! The child is killed and reaped when the source is dropped.

use std::collections::VecDeque;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::thread::JoinHandle;
use std::time::Duration;

use super::yuv::{expand_limited_luma, ColorMatrix, ColorRange, YuvToRgb};
use super::{ensure_gray, ensure_rgb, Frame, FrameSource, Luma, SourceKind, SourceOptions, VideoInfo};
use facecap_core::error::{Error, Result};

/// Environment variable naming the ffmpeg binary to use.
pub const FFMPEG_ENV: &str = "FACECAP_FFMPEG";
/// Longest wait for ffmpeg to produce the next frame before giving up (a hang guard).
pub const STALL_TIMEOUT: Duration = Duration::from_secs(120);
/// Lines of ffmpeg's stderr kept for error messages.
const LOG_TAIL_LINES: usize = 8;
/// Frame rate assumed when the stream states none.
const FALLBACK_FPS: f64 = 30.0;

/// How to install ffmpeg, for error messages.
pub const INSTALL_HINT: &str =
    "install it with `apt-get install ffmpeg` (Debian/Ubuntu) or run `bash scripts/setup.sh`, \
which also caches the static ffmpeg of the PyPI wheel imageio-ffmpeg; or point FACECAP_FFMPEG at an ffmpeg binary";

fn find_in_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path).map(|d| d.join(name)).find(|p| p.is_file())
}

/// The ffmpeg binary: `explicit` if given, else `$FACECAP_FFMPEG`, else `ffmpeg` on
/// `PATH`, else `<cache>/bin/ffmpeg` (placed there by `scripts/setup.sh` from the PyPI
/// wheel `imageio-ffmpeg`).
///
/// # Errors
/// [`Error::Tool`] saying where it looked and how to install ffmpeg.
pub fn locate_ffmpeg(explicit: Option<&Path>) -> Result<PathBuf> {
    let tool_err = |reason: String| Error::Tool {
        tool: "ffmpeg".into(),
        reason,
    };
    if let Some(p) = explicit {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(tool_err(format!(
                "the given ffmpeg {} does not exist; {INSTALL_HINT}",
                p.display()
            )))
        };
    }
    if let Some(p) = std::env::var_os(FFMPEG_ENV) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(tool_err(format!(
                "{FFMPEG_ENV}={} does not exist; {INSTALL_HINT}",
                p.display()
            )))
        };
    }
    if let Some(p) = find_in_path("ffmpeg") {
        return Ok(p);
    }
    let cached = facecap_core::paths::cache_dir().map(|c| c.join("bin").join("ffmpeg"));
    if let Some(p) = cached.as_ref().filter(|p| p.is_file()) {
        return Ok(p.clone());
    }
    Err(tool_err(format!(
        "not found (looked at ${FFMPEG_ENV}, PATH and {}); {INSTALL_HINT}",
        cached.map_or_else(|| "<cache>/bin/ffmpeg".to_string(), |p| p.display().to_string())
    )))
}

/// `ffprobe` beside the given ffmpeg, else on `PATH` (optional: only used for the
/// container's frame count).
pub fn locate_ffprobe(ffmpeg: &Path) -> Option<PathBuf> {
    ffmpeg
        .parent()
        .map(|d| d.join("ffprobe"))
        .filter(|p| p.is_file())
        .or_else(|| find_in_path("ffprobe"))
}

/// Protocols ffmpeg and ffprobe may open (`-protocol_whitelist`): local files and pipes.
pub const PROTOCOL_WHITELIST: &str = "file,pipe";
/// Demuxers ffmpeg and ffprobe may use on an input (`-format_whitelist`): video
/// containers and raw streams, not playlists or concatenation scripts (an HLS playlist or
/// ffconcat file saved as `.mp4` would open other files).
pub const FORMAT_WHITELIST: &str = "mov,mp4,m4a,3gp,3g2,mj2,matroska,webm,avi,mpegts,mpegtsraw,mpeg,mpegvideo,\
flv,ogg,asf,mxf,dv,gif,h264,hevc,m4v,rawvideo,yuv4mpegpipe,ivf,nut,obu,image2,png_pipe,jpeg_pipe,mjpeg";

/// A local path as an ffmpeg `file:` URL: an absolute path behind `file:`, so a name such
/// as `concat:a.mp4|b.mp4`, `http://...` or `-i` is a file name and never a protocol or an
/// option.
pub fn file_url(path: &Path) -> std::ffi::OsString {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut url = std::ffi::OsString::from("file:");
    url.push(abs.as_os_str());
    url
}

/// The input options every ffmpeg/ffprobe call on a user's file gets (see
/// [`PROTOCOL_WHITELIST`], [`FORMAT_WHITELIST`]).
pub fn safe_input_args() -> [&'static str; 4] {
    [
        "-protocol_whitelist",
        PROTOCOL_WHITELIST,
        "-format_whitelist",
        FORMAT_WHITELIST,
    ]
}

/// The container's frame count of the first video stream (`nb_frames`), via ffprobe.
pub fn probe_frame_count(ffprobe: &Path, file: &Path) -> Option<u64> {
    frame_count_of(spawn_frame_count_probe(ffprobe, file)?)
}

/// Starts ffprobe for [`probe_frame_count`] without waiting for it, so it can run
/// while ffmpeg starts.
fn spawn_frame_count_probe(ffprobe: &Path, file: &Path) -> Option<std::process::Child> {
    Command::new(ffprobe)
        .args([
            "-v",
            "error",
            "-select_streams",
            "V:0",
            "-show_entries",
            "stream=nb_frames",
        ])
        .args(["-of", "default=noprint_wrappers=1:nokey=1"])
        .args(safe_input_args())
        .arg(file_url(file))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .ok()
}

/// Stops a probe that is no longer wanted (an error while opening).
struct ProbeGuard(Option<std::process::Child>);

impl Drop for ProbeGuard {
    fn drop(&mut self) {
        if let Some(mut p) = self.0.take() {
            let _ = p.kill();
            let _ = p.wait();
        }
    }
}

/// The frame count a probe started by [`spawn_frame_count_probe`] printed.
fn frame_count_of(probe: std::process::Child) -> Option<u64> {
    let out = probe.wait_with_output().ok()?;
    if !out.status.success() {
        return None;
    }
    String::from_utf8_lossy(&out.stdout).lines().next()?.trim().parse().ok()
}

/// One `showinfo` frame line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShowinfoFrame {
    /// Frame number counted by the filter.
    pub n: u64,
    /// Presentation timestamp in time-base units (`None` for `NOPTS`).
    pub pts: Option<i64>,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Whether it is a keyframe (`iskey:1`; `false` when the line does not say).
    pub key: bool,
    /// Chroma subsampling of the frame's pixel format (`fmt:`): 2 for `yuv420p` and
    /// `yuvj420p`, 1 for `yuv444p` and `yuvj444p`, `None` for any other format or when the
    /// line does not say.
    pub chroma_sub: Option<u32>,
}

/// What the stderr reader thread reports.
#[derive(Debug)]
enum Msg {
    Frame(ShowinfoFrame),
    TimeBase {
        tb: (i64, i64),
        rate: Option<(i64, i64)>,
    },
    Line(String),
    /// A line logged at level error, fatal or panic.
    Error(String),
    Eof,
}

/// Log levels ffmpeg prints with `-loglevel level+info`, and whether they are errors.
const LEVEL_TAGS: [(&str, bool); 8] = [
    ("[info] ", false),
    ("[warning] ", false),
    ("[error] ", true),
    ("[fatal] ", true),
    ("[panic] ", true),
    ("[verbose] ", false),
    ("[debug] ", false),
    ("[trace] ", false),
];

/// Removes the level tag of a `level+` log line; says whether it was an error level.
fn strip_level(line: &str) -> (String, bool) {
    let found = LEVEL_TAGS
        .iter()
        .filter_map(|(tag, err)| line.find(tag).map(|i| (i, tag.len(), *err)))
        .min_by_key(|(i, _, _)| *i);
    match found {
        Some((i, n, err)) => (format!("{}{}", &line[..i], &line[i + n..]), err),
        None => (line.to_string(), false),
    }
}

fn field_after<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let i = line.find(key)?;
    Some(line[i + key.len()..].trim_start())
}

fn leading_token(s: &str) -> &str {
    let end = s.find(|c: char| c.is_whitespace()).unwrap_or(s.len());
    &s[..end]
}

fn parse_ratio(s: &str) -> Option<(i64, i64)> {
    let s = leading_token(s).trim_end_matches(',');
    let (a, b) = s.split_once('/')?;
    Some((a.parse().ok()?, b.parse().ok()?))
}

/// Parses a `showinfo` per-frame line (the part after `[Parsed_showinfo_0 @ 0x..] `).
pub fn parse_showinfo_frame(line: &str) -> Option<ShowinfoFrame> {
    let body = line.trim_start();
    let rest = body.strip_prefix("n:")?;
    let n = leading_token(rest.trim_start()).parse().ok()?;
    let pts_tok = leading_token(field_after(body, " pts:")?);
    let pts = if pts_tok == "NOPTS" {
        None
    } else {
        Some(pts_tok.parse().ok()?)
    };
    let (w, h) = leading_token(field_after(body, " s:")?).split_once('x')?;
    Some(ShowinfoFrame {
        n,
        pts,
        width: w.parse().ok()?,
        height: h.parse().ok()?,
        key: field_after(body, " iskey:").is_some_and(|t| leading_token(t) == "1"),
        chroma_sub: field_after(body, " fmt:").and_then(|t| match leading_token(t) {
            "yuv420p" | "yuvj420p" => Some(2),
            "yuv444p" | "yuvj444p" => Some(1),
            _ => None,
        }),
    })
}

/// Classifies one stderr line (level tag already removed).
fn classify(line: String, is_error: bool) -> Msg {
    if is_error {
        return Msg::Error(line);
    }
    if let Some(i) = line.find("Parsed_showinfo_") {
        let body = line[i..].split_once("] ").map_or("", |(_, b)| b);
        if let Some(f) = parse_showinfo_frame(body) {
            return Msg::Frame(f);
        }
        if let Some(tb) = field_after(body, "config in time_base:").and_then(parse_ratio) {
            let rate = field_after(body, "frame_rate:").and_then(parse_ratio);
            return Msg::TimeBase { tb, rate };
        }
    }
    Msg::Line(line)
}

/// What the stream header lines say about the input video stream.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamHeader {
    /// Codec short name.
    pub codec: Option<String>,
    /// Pixel format name.
    pub pix_fmt: Option<String>,
    /// Frame rate (`fps`, else `tbr`).
    pub fps: Option<f64>,
    /// Container duration.
    pub duration_s: Option<f64>,
    /// Colour matrix.
    pub matrix: ColorMatrix,
    /// Code range.
    pub range: ColorRange,
}

/// Splits at commas that are not inside parentheses or brackets.
fn split_top_level(s: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let (mut depth, mut start) = (0i32, 0usize);
    for (i, c) in s.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' if depth == 0 => {
                out.push(s[start..i].trim());
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(s[start..].trim());
    out
}

fn parse_rate(field: &str, unit: &str) -> Option<f64> {
    let v = field.strip_suffix(unit)?.trim();
    let (num, mul) = match v.strip_suffix('k') {
        Some(n) => (n, 1000.0),
        None => (v, 1.0),
    };
    num.parse::<f64>()
        .ok()
        .map(|x| x * mul)
        .filter(|x| x.is_finite() && *x > 0.0)
}

impl StreamHeader {
    /// Updates from one header line of ffmpeg's `-i` report (only the input part).
    pub fn feed(&mut self, line: &str) {
        let t = line.trim_start();
        if let Some(d) = t.strip_prefix("Duration: ") {
            let d = d.split(',').next().unwrap_or("");
            let mut secs = 0.0;
            let mut ok = true;
            for part in d.split(':') {
                match part.trim().parse::<f64>() {
                    Ok(v) => secs = secs * 60.0 + v,
                    Err(_) => ok = false,
                }
            }
            self.duration_s = ok.then_some(secs);
            return;
        }
        if self.codec.is_some() || !t.starts_with("Stream #") || t.contains("(attached pic)") {
            return;
        }
        let Some(i) = t.find(": Video: ") else { return };
        let fields = split_top_level(&t[i + ": Video: ".len()..]);
        self.codec = fields.first().map(|f| leading_token(f).to_string());
        if let Some(pf) = fields.get(1) {
            let (name, props) = pf.split_once('(').unwrap_or((pf, ""));
            self.pix_fmt = Some(name.to_string());
            if name.starts_with("yuvj") || props.split([',', ')']).any(|p| p.trim() == "pc") {
                self.range = ColorRange::Full;
            }
            if props.contains("bt709") {
                self.matrix = ColorMatrix::Bt709;
            }
        }
        self.fps = fields
            .iter()
            .find_map(|f| parse_rate(f, " fps"))
            .or_else(|| fields.iter().find_map(|f| parse_rate(f, " tbr")));
    }
}

/// A video file decoded by ffmpeg (see the module docs).
#[derive(Debug)]
pub struct FfmpegSource {
    path: PathBuf,
    info: VideoInfo,
    child: Child,
    stdout: ChildStdout,
    rx: Receiver<Msg>,
    reader: Option<JoinHandle<()>>,
    pending: Option<ShowinfoFrame>,
    time_base: Option<(i64, i64)>,
    next_index: u64,
    chroma: Vec<u8>,
    chroma_sub: u32,
    /// The chroma subsampling is ffmpeg's choice, read from each frame's report.
    negotiated: bool,
    /// Limited-range luma expanded to full range ([`expand_limited_luma`]).
    expand_luma: bool,
    conv: YuvToRgb,
    rgb: bool,
    tail: VecDeque<String>,
    strict: bool,
    /// First error-level line ffmpeg logged (strict mode stops at the next frame).
    error_line: Option<String>,
    /// Last error-level line since the last delivered frame (lenient mode).
    error_since_frame: Option<String>,
    /// Presentation time of the last delivered frame, seconds.
    last_time: Option<f64>,
    /// Frames ffmpeg dropped (lenient mode) that are still to be reported as errors.
    missing: u64,
    /// Why they were dropped (ffmpeg's error line).
    missing_reason: String,
    /// Dropped frames so far: ffmpeg's frame numbers plus this are ours.
    index_offset: u64,
    /// The error being returned concerns one dropped frame only: decoding goes on.
    skippable: bool,
    /// Lenient mode: ffmpeg logged a decode error for the frame being read (concealed);
    /// the error line.
    damaged: Option<String>,
    done: bool,
    /// Size of the decoded frames as `showinfo` reports them (before any scaling).
    decoded_size: (u32, u32),
    /// The frames ffmpeg passes on ([`SourceOptions::select`]).
    select: Option<super::FrameSelect>,
    /// Small colour copies of chosen frames ([`FrameSource::tap_colour`]).
    tap: Option<super::small::ColourTap>,
    scaler: super::small::PlaneScaler,
}

/// Largest run of dropped frames reported one by one (a timestamp jump beyond it is a
/// discontinuity, not damage).
const MAX_DROPPED_RUN: u64 = 10_000;

impl FfmpegSource {
    /// Starts ffmpeg on `path` and waits for the first frame's header.
    ///
    /// # Errors
    /// [`Error::Tool`] if ffmpeg is missing or cannot start; [`Error::Decode`] if the
    /// file is not a video, has no video stream or yields no frame.
    pub fn open(path: &Path, opts: &SourceOptions) -> Result<Self> {
        opts.validate()?;
        std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let ffmpeg = locate_ffmpeg(opts.ffmpeg.as_deref())?;
        // Without scaling, ffmpeg picks the nearest of a few planar formats: 4:2:0 sources
        // stay 4:2:0 (for colour: half the bytes through the pipe, no conversion in
        // ffmpeg; other sources become 4:4:4), and full-range (`yuvj`) sources keep their
        // codes (`-pix_fmt yuv420p` squeezed them into 16-235 while the stream's range
        // said full). `showinfo` after the format reports which (`fmt:`).
        let negotiated = opts.scale.is_none();
        let formats = if opts.rgb {
            "yuv420p|yuvj420p|yuv444p|yuvj444p"
        } else {
            "yuv420p|yuvj420p"
        };
        let pix_fmt = if opts.rgb { "yuv444p" } else { "yuv420p" };
        // showinfo first (after the lossless format choice): it reports every decoded
        // frame (so indices stay exact when `select` drops some), then the selection,
        // then the scaling of what is left
        let mut filters = if negotiated {
            format!("format=pix_fmts={formats},showinfo=checksum=0")
        } else {
            "showinfo=checksum=0".to_string()
        };
        if let Some(sel) = &opts.select {
            filters.push_str(&format!(",select={}", sel.ffmpeg_expr()));
        }
        if let Some((w, h)) = opts.scale {
            filters.push_str(&format!(",scale={w}:{h}:flags=bilinear"));
        }
        let mut cmd = Command::new(&ffmpeg);
        cmd.args(["-nostdin", "-hide_banner", "-nostats", "-loglevel", "level+info"]);
        if opts.strict {
            cmd.arg("-xerror");
        }
        if opts.threads > 0 {
            cmd.args(["-threads", &opts.threads.to_string()]);
        }
        cmd.args(safe_input_args())
            .args(["-copyts", "-i"])
            .arg(file_url(path))
            .args(["-map", "0:V:0", "-vf", &filters, "-fps_mode", "passthrough"])
            .args(["-f", "rawvideo"])
            .args(if negotiated { vec![] } else { vec!["-pix_fmt", pix_fmt] })
            .arg("pipe:1")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| Error::Tool {
            tool: ffmpeg.display().to_string(),
            reason: format!("cannot start: {e}; {INSTALL_HINT}"),
        })?;
        let (Some(stdout), Some(stderr)) = (child.stdout.take(), child.stderr.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(Error::Tool {
                tool: ffmpeg.display().to_string(),
                reason: "no pipes to the child process".into(),
            });
        };
        let (tx, rx) = mpsc::channel();
        let reader = std::thread::Builder::new()
            .name("facecap-ffmpeg-stderr".into())
            .spawn(move || {
                let mut r = std::io::BufReader::new(stderr);
                let mut buf = Vec::with_capacity(256);
                loop {
                    buf.clear();
                    match std::io::BufRead::read_until(&mut r, b'\n', &mut buf) {
                        Ok(0) | Err(_) => break,
                        Ok(_) => {
                            let (line, is_error) = strip_level(String::from_utf8_lossy(&buf).trim_end());
                            if tx.send(classify(line, is_error)).is_err() {
                                break;
                            }
                        }
                    }
                }
                let _ = tx.send(Msg::Eof);
            })
            .map_err(|e| Error::Tool {
                tool: "ffmpeg".into(),
                reason: format!("cannot start the stderr reader thread: {e}"),
            });
        let reader = match reader {
            Ok(r) => r,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        let mut src = FfmpegSource {
            path: path.to_path_buf(),
            info: VideoInfo {
                width: 0,
                height: 0,
                fps: FALLBACK_FPS,
                frame_count: None,
                duration_s: None,
                codec: String::new(),
                kind: SourceKind::Video,
            },
            child,
            stdout,
            rx,
            reader: Some(reader),
            pending: None,
            time_base: None,
            next_index: 0,
            chroma: Vec::new(),
            chroma_sub: if opts.rgb { 1 } else { 2 },
            negotiated,
            expand_luma: false,
            conv: YuvToRgb::new(ColorMatrix::Bt601, ColorRange::Limited),
            rgb: opts.rgb,
            tail: VecDeque::with_capacity(LOG_TAIL_LINES + 1),
            strict: opts.strict,
            error_line: None,
            error_since_frame: None,
            last_time: None,
            missing: 0,
            missing_reason: String::new(),
            index_offset: 0,
            skippable: false,
            damaged: None,
            done: false,
            decoded_size: (0, 0),
            select: opts.select.clone(),
            tap: None,
            scaler: super::small::PlaneScaler::default(),
        };
        // The frame count: read from an MP4/MOV file's boxes where they say it plainly
        // (the same number ffprobe reports, without a process), else from ffprobe,
        // started now so it runs while ffmpeg starts.
        let boxed_count = if opts.probe_frame_count {
            super::mp4::video_frame_count(path)
        } else {
            None
        };
        let mut probe = ProbeGuard(if opts.probe_frame_count && boxed_count.is_none() {
            locate_ffprobe(&ffmpeg).and_then(|p| spawn_frame_count_probe(&p, path))
        } else {
            None
        });
        // Header lines come before the first frame line.
        let mut header = StreamHeader::default();
        let mut rate = None;
        let mut in_output = false;
        let first = loop {
            match src.recv()? {
                Msg::Frame(f) => break Some(f),
                Msg::TimeBase { tb, rate: r } => {
                    src.time_base = Some(tb);
                    rate = r;
                }
                Msg::Line(l) => {
                    if l.starts_with("Output #") {
                        in_output = true;
                    }
                    if !in_output {
                        header.feed(&l);
                    }
                    src.push_tail(l);
                }
                Msg::Error(l) => src.note_error(l),
                Msg::Eof => break None,
            }
        };
        let Some(first) = first else {
            return Err(src.open_failure());
        };
        let frame_count = boxed_count.or_else(|| probe.0.take().and_then(frame_count_of));
        if first.width == 0 || first.height == 0 {
            return Err(src.decode_err(None, format!("ffmpeg reports a {}x{} frame", first.width, first.height)));
        }
        let fps = rate
            .filter(|(n, d)| *n > 0 && *d > 0)
            .map(|(n, d)| n as f64 / d as f64)
            .or(header.fps)
            .unwrap_or(FALLBACK_FPS);
        src.decoded_size = (first.width, first.height);
        if negotiated {
            match first.chroma_sub {
                Some(sub) => src.chroma_sub = sub,
                None => {
                    let reason = format!("ffmpeg delivers a pixel format other than {formats}");
                    return Err(src.decode_err(None, reason));
                }
            }
        }
        let (width, height) = opts.scale.unwrap_or(src.decoded_size);
        src.info = VideoInfo {
            width,
            height,
            fps,
            frame_count,
            duration_s: header.duration_s,
            codec: header.codec.clone().unwrap_or_else(|| "unknown".into()),
            kind: SourceKind::Video,
        };
        // ffmpeg converts to the requested yuv420p/yuv444p; full-range (yuvj) input keeps
        // its range tag, so the range and matrix of the input stream apply.
        let range = header.range;
        src.expand_luma = opts.luma == Luma::Full && range == ColorRange::Limited;
        src.conv = YuvToRgb::new(header.matrix, range);
        let cw = width.div_ceil(src.chroma_sub) as usize;
        let ch = height.div_ceil(src.chroma_sub) as usize;
        src.chroma = vec![0; 2 * cw * ch];
        src.pending = Some(first);
        Ok(src)
    }

    /// Keeps the last diagnostic lines (not the indented stream report or progress lines).
    /// Process id of the ffmpeg child (for diagnostics and tests).
    pub fn child_id(&self) -> u32 {
        self.child.id()
    }

    fn note_error(&mut self, line: String) {
        if self.error_line.is_none() {
            self.error_line = Some(line.clone());
        }
        self.error_since_frame = Some(line.clone());
        self.push_tail(line);
    }

    /// In strict mode, the error for frame `k` once ffmpeg has logged an error.
    fn strict_stop(&mut self, k: u64) -> Option<Error> {
        let line = self.error_line.as_ref().filter(|_| self.strict)?;
        let reason = format!(
            "ffmpeg reported a decode error, so frames from here on may be damaged (first error: {});              stopped after {k} good frames (use lenient decoding to go on); {}",
            line.trim(),
            self.tail_text()
        );
        self.done = true;
        let _ = self.child.kill();
        let _ = self.child.wait();
        Some(self.decode_err(Some(k), reason))
    }

    fn push_tail(&mut self, line: String) {
        const NOISE: [&str; 7] = [
            "frame=",
            "video:",
            "Input #",
            "Output #",
            "Stream mapping",
            "Press [q]",
            "[Parsed_showinfo_",
        ];
        if line.trim().is_empty() || line.starts_with(char::is_whitespace) || NOISE.iter().any(|n| line.starts_with(n))
        {
            return;
        }
        if self.tail.len() == LOG_TAIL_LINES {
            self.tail.pop_front();
        }
        self.tail.push_back(line);
    }

    fn tail_text(&self) -> String {
        if self.tail.is_empty() {
            "ffmpeg printed no error message".into()
        } else {
            let lines: Vec<&str> = self.tail.iter().map(|s| s.trim()).collect();
            format!("ffmpeg: {}", lines.join(" | "))
        }
    }

    fn decode_err(&self, frame: Option<u64>, reason: String) -> Error {
        Error::Decode {
            path: self.path.clone(),
            frame,
            reason,
        }
    }

    fn recv(&mut self) -> Result<Msg> {
        match self.rx.recv_timeout(STALL_TIMEOUT) {
            Ok(m) => Ok(m),
            Err(RecvTimeoutError::Disconnected) => Ok(Msg::Eof),
            Err(RecvTimeoutError::Timeout) => {
                self.done = true;
                let _ = self.child.kill();
                Err(self.decode_err(
                    Some(self.next_index),
                    format!("ffmpeg produced nothing for {} s; stopped it", STALL_TIMEOUT.as_secs()),
                ))
            }
        }
    }

    /// Error for an ffmpeg that ended before its first frame.
    fn open_failure(&mut self) -> Error {
        let status = self.child.wait().ok();
        let all: String = self.tail.iter().cloned().collect::<Vec<_>>().join("\n");
        let reason = if all.contains("does not contain any stream") || all.contains("matches no streams") {
            "contains no video stream".to_string()
        } else if all.contains("Invalid data found when processing input") || all.contains("moov atom not found") {
            format!(
                "not a readable video file (unknown format, or truncated / damaged container); {}",
                self.tail_text()
            )
        } else if status.is_some_and(|s| s.success()) {
            "the video stream has no frames".to_string()
        } else {
            format!(
                "ffmpeg failed ({}) before the first frame; {}",
                status.map_or_else(|| "unknown status".into(), |s| s.to_string()),
                self.tail_text()
            )
        };
        self.done = true;
        self.decode_err(None, reason)
    }

    /// Called when stderr closed: checks for stray output and ffmpeg's exit status.
    fn finish(&mut self) -> Result<bool> {
        self.done = true;
        let mut probe = [0u8; 1];
        let stray = matches!(self.stdout.read(&mut probe), Ok(n) if n > 0);
        let status = self.child.wait().map_err(|e| Error::Tool {
            tool: "ffmpeg".into(),
            reason: format!("cannot wait for the child process: {e}"),
        })?;
        if stray {
            return Err(self.decode_err(
                Some(self.next_index),
                "ffmpeg wrote frame data without a frame report (cannot pair frames with timestamps)".into(),
            ));
        }
        if status.success() {
            if self.next_index == 0 {
                return Err(self.decode_err(None, "no frames decoded".into()));
            }
            return Ok(false);
        }
        Err(self.decode_err(
            Some(self.next_index),
            format!(
                "decoding stopped after {} good frames ({status}; damaged or truncated file?); {}",
                self.next_index,
                self.tail_text()
            ),
        ))
    }

    fn next_report(&mut self) -> Result<Option<ShowinfoFrame>> {
        if let Some(f) = self.pending.take() {
            return Ok(Some(f));
        }
        loop {
            match self.recv()? {
                Msg::Frame(f) => return Ok(Some(f)),
                Msg::TimeBase { tb, .. } => self.time_base = Some(tb),
                Msg::Line(l) => self.push_tail(l),
                Msg::Error(l) => self.note_error(l),
                Msg::Eof => return Ok(None),
            }
        }
    }

    /// The next delivered frame (frames `select` dropped are passed over).
    fn read_frame(&mut self, frame: &mut Frame) -> Result<bool> {
        loop {
            if let Some(r) = self.read_step(frame)? {
                return Ok(r);
            }
        }
    }

    /// One frame report: `Some` as [`FrameSource::read_into`], `None` for a frame that
    /// `select` dropped (no bytes follow its report).
    fn read_step(&mut self, frame: &mut Frame) -> Result<Option<bool>> {
        if self.missing > 0 {
            // Lenient mode: one frame ffmpeg dropped as undecodable, reported on its own.
            self.missing -= 1;
            let k = self.next_index;
            self.next_index += 1;
            self.skippable = true;
            return Err(self.decode_err(
                Some(k),
                format!(
                    "ffmpeg could not decode this frame and dropped it ({})",
                    self.missing_reason
                ),
            ));
        }
        let next = self.next_report()?;
        let k = self.next_index;
        if let Some(e) = self.strict_stop(k) {
            return Err(e);
        }
        let Some(rep) = next else {
            return self.finish().map(Some);
        };
        let time = |rep: &ShowinfoFrame, tb: Option<(i64, i64)>| match (rep.pts, tb) {
            (Some(p), Some((num, den))) if den != 0 => Some(p as f64 * num as f64 / den as f64),
            _ => None,
        };
        if !self.strict {
            // Frames ffmpeg dropped after a decode error show as a gap in the timestamps.
            let err = self.error_since_frame.take();
            if let (Some(err), Some(last), Some(t)) = (&err, self.last_time, time(&rep, self.time_base)) {
                let gap = ((t - last) * self.info.fps).round() - 1.0;
                if gap >= 1.0 && gap <= MAX_DROPPED_RUN as f64 {
                    let gap = gap as u64;
                    self.index_offset += gap;
                    self.missing = gap;
                    self.missing_reason = err.trim().to_string();
                    // the frame itself follows the error: it is checked again below
                    self.error_since_frame = Some(err.clone());
                    self.pending = Some(rep);
                    return self.read_step(frame);
                }
            }
            // A frame whose decoding logged an error is concealed (partly invented by
            // ffmpeg): reported as damaged (its bytes are still read to keep the pipe in
            // step). Frames predicted from it until the next keyframe may carry some of
            // the concealment; they are kept (marking them all would throw away up to a
            // whole group of pictures over a few damaged bytes; `strict` refuses them).
            self.damaged = err.map(|e| e.trim().to_string());
        }
        if rep.n + self.index_offset != k {
            return Err(self.decode_err(
                Some(k),
                format!("ffmpeg reported frame {} where {k} was expected", rep.n),
            ));
        }
        let (dw, dh) = self.decoded_size;
        if (rep.width, rep.height) != (dw, dh) {
            return Err(self.decode_err(
                Some(k),
                format!(
                    "frame size changes from {dw}x{dh} to {}x{} (not supported; re-encode with a fixed size)",
                    rep.width, rep.height
                ),
            ));
        }
        if self.negotiated && rep.chroma_sub != Some(self.chroma_sub) {
            return Err(self.decode_err(
                Some(k),
                "the pixel format changes inside the video (not supported; re-encode it)".to_string(),
            ));
        }
        if self.select.as_ref().is_some_and(|s| !s.contains(rep.n)) {
            // dropped by ffmpeg's `select` after its report: no bytes follow
            self.last_time = time(&rep, self.time_base).or(self.last_time);
            self.error_since_frame = None;
            self.damaged = None;
            self.next_index += 1;
            return Ok(None);
        }
        let (w, h) = (self.info.width, self.info.height);
        ensure_gray(&mut frame.gray, w, h);
        let read = self
            .stdout
            .read_exact(frame.gray.as_mut())
            .and_then(|_| self.stdout.read_exact(&mut self.chroma));
        if let Err(e) = read {
            self.done = true;
            let _ = self.child.kill();
            let _ = self.child.wait();
            // Let the reader drain so the message includes ffmpeg's last words.
            while let Ok(m) = self.rx.recv_timeout(Duration::from_secs(2)) {
                match m {
                    Msg::Line(l) | Msg::Error(l) => self.push_tail(l),
                    Msg::Eof => break,
                    _ => {}
                }
            }
            return Err(self.decode_err(
                Some(k),
                format!("ffmpeg output ended inside the frame ({e}); {}", self.tail_text()),
            ));
        }
        ensure_rgb(&mut frame.rgb, self.rgb, w, h);
        if let Some(rgb) = frame.rgb.as_mut() {
            let (cb, cr) = self.chroma.split_at(self.chroma.len() / 2);
            let sub = self.chroma_sub;
            self.conv.convert_into(frame.gray.as_raw(), cb, cr, w, h, sub, sub, rgb);
        }
        // the small copy is made from the planes as decoded (before the luma table)
        let reuse = frame.small.take();
        if let Some(tap) = self.tap.as_ref().filter(|t| t.select.contains(k)) {
            let (cb, cr) = self.chroma.split_at(self.chroma.len() / 2);
            frame.small = Some(super::small::SmallFrame::from_planes(
                frame.gray.as_raw(),
                cb,
                cr,
                w,
                h,
                self.chroma_sub,
                tap.size,
                self.conv,
                &mut self.scaler,
                reuse,
            )?);
        }
        if self.expand_luma {
            expand_limited_luma(&mut frame.gray);
        }
        frame.index = k;
        frame.timestamp_s = time(&rep, self.time_base).unwrap_or(k as f64 / self.info.fps);
        self.last_time = Some(frame.timestamp_s);
        self.error_since_frame = None;
        self.next_index += 1;
        if let Some(e) = self.damaged.take() {
            self.skippable = true;
            return Err(self.decode_err(
                Some(k),
                format!("damaged: ffmpeg concealed a decode error in this frame ({e})"),
            ));
        }
        Ok(Some(true))
    }
}

impl FrameSource for FfmpegSource {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn tap_colour(&mut self, tap: super::small::ColourTap) -> Result<bool> {
        tap.validate(self.info.width, self.info.height)?;
        self.tap = Some(tap);
        Ok(true)
    }

    fn read_into(&mut self, frame: &mut Frame) -> Result<bool> {
        if self.done {
            return Ok(false);
        }
        let r = self.read_frame(frame);
        if r.is_err() && !std::mem::take(&mut self.skippable) {
            self.done = true;
        }
        r
    }
}

impl Drop for FfmpegSource {
    fn drop(&mut self) {
        if !matches!(self.child.try_wait(), Ok(Some(_))) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if let Some(h) = self.reader.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;

    #[test]
    fn showinfo_lines() {
        let f = parse_showinfo_frame(
            "n:   1 pts:   3000 pts_time:0.0333333 pos:    56313 fmt:yuv420p sar:15/16 s:512x480 i:P iskey:0 type:B",
        )
        .unwrap();
        assert_eq!(
            f,
            ShowinfoFrame {
                n: 1,
                pts: Some(3000),
                width: 512,
                height: 480,
                key: false,
                chroma_sub: Some(2),
            }
        );
        let f = parse_showinfo_frame("n:1000 pts:1038000 pts_time:11.5333 pos: 1 fmt:yuv420p sar:0/1 s:480x480 i:P")
            .unwrap();
        assert_eq!((f.n, f.pts), (1000, Some(1038000)));
        let f = parse_showinfo_frame("n:   2 pts:NOPTS pts_time:NOPTS pos: -1 fmt:gray sar:1/1 s:4x2 i:P").unwrap();
        assert_eq!((f.pts, f.chroma_sub), (None, None));
        assert!(parse_showinfo_frame("color_range:tv color_space:bt709").is_none());
        let (l, e) = strip_level("[Parsed_showinfo_0 @ 0x55] [info] config in time_base: 1/15360, frame_rate: 30/1");
        assert!(!e);
        assert_eq!(
            strip_level("[h264 @ 0x4] [error] Invalid NAL unit size"),
            ("[h264 @ 0x4] Invalid NAL unit size".into(), true)
        );
        assert_eq!(strip_level("[info]   Duration: N/A").0, "  Duration: N/A");
        match classify(l, e) {
            Msg::TimeBase { tb, rate } => assert_eq!((tb, rate), ((1, 15360), Some((30, 1)))),
            m => panic!("{m:?}"),
        }
    }

    #[test]
    fn stream_header_lines() {
        let mut h = StreamHeader::default();
        h.feed("  Duration: 00:00:19.60, start: 0.000000, bitrate: 922 kb/s");
        h.feed("  Stream #0:0[0x1](und): Video: h264 (High) (avc1 / 0x31637661), yuv420p(tv, bt709, progressive), 512x480 [SAR 15:16 DAR 1:1], 790 kb/s, 30 fps, 30 tbr, 90k tbn (default)");
        h.feed("  Stream #0:1: Video: mpeg4, yuv420p, 8x8, 29.97 fps");
        assert_eq!(h.codec.as_deref(), Some("h264"));
        assert_eq!(h.pix_fmt.as_deref(), Some("yuv420p"));
        assert_eq!(h.fps, Some(30.0));
        assert!((h.duration_s.unwrap() - 19.6).abs() < 1e-9);
        assert_eq!((h.matrix, h.range), (ColorMatrix::Bt709, ColorRange::Limited));
        let mut h = StreamHeader::default();
        h.feed("Stream #0:0: Video: mjpeg (Baseline) (MJPG / 0x47504A4D), yuvj420p(pc, bt470bg/unknown/unknown), 640x480, 23.98 tbr");
        assert_eq!(h.codec.as_deref(), Some("mjpeg"));
        assert_eq!((h.range, h.fps), (ColorRange::Full, Some(23.98)));
    }

    #[test]
    fn missing_ffmpeg_is_a_tool_error() {
        let e = locate_ffmpeg(Some(Path::new("/nonexistent/ffmpeg")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("apt-get install ffmpeg"), "{e}");
    }
}
