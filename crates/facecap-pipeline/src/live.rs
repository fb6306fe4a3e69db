//! Live input: cameras, network streams, files played at their own rate and Y4M on
//! stdin, taken **newest first**.
//!
//! * [`Y4mStream`] reads a YUV4MPEG2 stream from any reader (stdin, a pipe from ffmpeg)
//!   with the grey levels of every other source ([`facecap_io::video::Luma::Full`]:
//!   limited-range luma expanded to 0..255), so a clip gives the same landmarks live
//!   and through `capture`.
//! * [`RawStream`] reads raw frames of a given size and layout (`gray`, `yuv420p`,
//!   `rgb24`) the same way.
//! * [`open_live`] turns a [`LiveInput`] into a source: stdin is read directly; a V4L2
//!   camera, a URL or a file (`realtime`: at its own rate, ffmpeg's `-re`) go through an
//!   `ffmpeg` child that writes Y4M to a pipe.
//! * [`LatestFrame`] wraps a source in a reader thread that keeps **only the newest
//!   frame**: when the consumer is slower than the input, the older waiting frame is
//!   dropped (counted in [`LiveStats::dropped`]), never queued, so the delay cannot grow.
//!   It logs each frame's arrival time (when its last byte was read) in an
//!   [`ArrivalLog`], which the outputs use to measure latency, arrival to packet.
//!
//! Frame indices count the frames of the stream, so dropped frames leave gaps; timestamps
//! are the stream's (`index / fps`).

use std::collections::VecDeque;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use facecap_io::video::y4m::Y4mReader;
use facecap_io::video::yuv::limited_to_full_luma_lut;
use facecap_io::video::{Frame, FrameSource, SourceKind, SourceOptions, VideoInfo};

use crate::error::{Error, Result};

/// Arrival times kept (frames); the consumer is never more than a few frames behind.
const ARRIVALS_KEPT: usize = 256;
/// How often a waiting consumer checks the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);

/// Where live frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum LiveInput {
    /// A Y4M stream on standard input (`ffmpeg ... -f yuv4mpegpipe - | facecap live -`).
    Stdin,
    /// A V4L2 camera (`/dev/video0`) through ffmpeg's `v4l2` input.
    Camera {
        /// Device path.
        device: PathBuf,
        /// Requested frame size (`None`: the camera's default).
        size: Option<(u32, u32)>,
        /// Requested frame rate (`None`: the camera's default).
        fps: Option<f64>,
    },
    /// Any URL ffmpeg reads (`rtsp://`, `udp://`, `http://`, ...), as fast as it comes.
    Url(String),
    /// A video file; `realtime` plays it at its own frame rate (ffmpeg's `-re`),
    /// otherwise frames come as fast as ffmpeg decodes them.
    File {
        /// The file.
        path: PathBuf,
        /// Play at the file's frame rate.
        realtime: bool,
    },
}

impl LiveInput {
    /// Reads a command-line input: `-` is stdin, `/dev/video*` a camera, anything with
    /// `://` a URL, else a file.
    pub fn parse(s: &str, realtime: bool, size: Option<(u32, u32)>, fps: Option<f64>) -> Self {
        if s == "-" {
            LiveInput::Stdin
        } else if s.starts_with("/dev/video") {
            LiveInput::Camera {
                device: PathBuf::from(s),
                size,
                fps,
            }
        } else if s.contains("://") {
            LiveInput::Url(s.to_string())
        } else {
            LiveInput::File {
                path: PathBuf::from(s),
                realtime,
            }
        }
    }

    /// The ffmpeg arguments before and including `-i INPUT` (`None` for stdin).
    pub fn ffmpeg_input_args(&self) -> Option<Vec<String>> {
        let mut a: Vec<String> = Vec::new();
        match self {
            LiveInput::Stdin => return None,
            LiveInput::Camera { device, size, fps } => {
                a.extend(["-f", "v4l2"].map(String::from));
                if let Some((w, h)) = size {
                    a.extend(["-video_size".to_string(), format!("{w}x{h}")]);
                }
                if let Some(f) = fps {
                    a.extend(["-framerate".to_string(), format!("{f}")]);
                }
                a.extend(["-i".to_string(), device.display().to_string()]);
            }
            LiveInput::Url(u) => {
                // ffmpeg probes a stream for up to 5 s of it by default before the first
                // frame comes out; half a second finds the codec of a live stream
                a.extend(
                    [
                        "-fflags",
                        "nobuffer",
                        "-flags",
                        "low_delay",
                        "-analyzeduration",
                        "500000",
                        "-probesize",
                        "500000",
                        "-i",
                    ]
                    .map(String::from),
                );
                a.push(u.clone());
            }
            LiveInput::File { path, realtime } => {
                if *realtime {
                    a.push("-re".into());
                }
                a.extend(["-i".to_string(), path.display().to_string()]);
            }
        }
        Some(a)
    }
}

/// Raw frames on stdin instead of Y4M: size, layout and frame rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawInput {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Pixel layout.
    pub format: RawFormat,
    /// Frames per second (timestamps).
    pub fps: f64,
}

/// Opens `input` as a frame source (module docs); `raw` reads stdin as raw frames. `ffmpeg` is the binary to run for
/// cameras, URLs and files (`None`: [`facecap_io::video::ffmpeg::locate_ffmpeg`]).
///
/// # Errors
/// A file that does not exist, ffmpeg missing or failing to start, or a stream whose
/// first bytes are not a Y4M header.
pub fn open_live(
    input: &LiveInput,
    ffmpeg: Option<&Path>,
    raw: Option<RawInput>,
    stop: &Arc<AtomicBool>,
) -> Result<(Box<dyn FrameSource>, Option<ChildGuard>)> {
    if let LiveInput::File { path, .. } = input {
        std::fs::metadata(path).map_err(|e| facecap_core::Error::io(path, e))?;
    }
    let Some(args) = input.ffmpeg_input_args() else {
        let stdin = Box::new(std::io::stdin());
        let name = PathBuf::from("<stdin>");
        let source: Box<dyn FrameSource> = match raw {
            Some(r) => Box::new(RawStream::new(stdin, name, r.width, r.height, r.format, r.fps)?),
            None => Box::new(Y4mStream::new(stdin, name, None)?),
        };
        return Ok((source, None));
    };
    let ffmpeg = facecap_io::video::ffmpeg::locate_ffmpeg(ffmpeg)?;
    let name = match input {
        LiveInput::Camera { device, .. } => device.clone(),
        LiveInput::Url(u) => PathBuf::from(u),
        LiveInput::File { path, .. } => path.clone(),
        LiveInput::Stdin => PathBuf::from("<stdin>"),
    };
    let mut child = Command::new(&ffmpeg)
        .args(["-nostdin", "-hide_banner", "-nostats", "-loglevel", "error"])
        .args(&args)
        .args(["-map", "0:V:0", "-pix_fmt", "yuv420p", "-f", "yuv4mpegpipe", "pipe:1"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| facecap_core::Error::Tool {
            tool: ffmpeg.display().to_string(),
            reason: format!("cannot start: {e}"),
        })?;
    let Some(stdout) = child.stdout.take() else {
        let _ = child.kill();
        let _ = child.wait();
        return Err(Error::invalid("ffmpeg", "no stdout pipe", "a piped child process"));
    };
    // The header comes with the first frame: a camera or a stream that sends nothing
    // would block here for ever, so a stop (Ctrl-C, SIGTERM) meanwhile kills ffmpeg.
    let guard = ChildGuard::new(child);
    let header_read = Arc::new(AtomicBool::new(false));
    let watchdog = {
        let (g, done, stop) = (guard.clone(), header_read.clone(), stop.clone());
        std::thread::Builder::new()
            .name("facecap-live-open".into())
            .spawn(move || {
                while !done.load(Ordering::SeqCst) {
                    if stop.load(Ordering::SeqCst) {
                        g.kill();
                        return;
                    }
                    std::thread::sleep(STOP_POLL);
                }
            })
            .map_err(|e| Error::invalid("live open thread", e, "a thread the system can start"))?
    };
    let opened = Y4mStream::with_guard(Box::new(stdout), name.clone(), Some(guard.clone()));
    header_read.store(true, Ordering::SeqCst);
    let _ = watchdog.join();
    if stop.load(Ordering::SeqCst) {
        guard.kill();
        return Err(Error::invalid(
            "live input",
            format!("{}: stopped before the first frame came", name.display()),
            "a stream that sends frames",
        ));
    }
    Ok((Box::new(opened?), Some(guard)))
}

/// The ffmpeg child behind a live source, shared so that it can be stopped from outside
/// the reader thread: a read blocked on a camera or network stream that sends nothing
/// never returns by itself, and the child would outlive facecap.
#[derive(Debug, Clone)]
pub struct ChildGuard(Arc<Mutex<Option<Child>>>);

impl ChildGuard {
    fn new(child: Child) -> Self {
        ChildGuard(Arc::new(Mutex::new(Some(child))))
    }

    /// Kills and reaps the child; later calls do nothing.
    pub fn kill(&self) {
        let taken = match self.0.lock() {
            Ok(mut g) => g.take(),
            Err(p) => p.into_inner().take(),
        };
        if let Some(mut c) = taken {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// A Y4M stream from any reader (module docs): `facecap-io`'s [`Y4mReader`] (grey frames,
/// [`facecap_io::video::Luma::Full`]) with the `ffmpeg` child that writes it, if any.
pub struct Y4mStream {
    inner: Y4mReader<BufReader<Box<dyn Read + Send>>>,
    child: Option<ChildGuard>,
}

impl std::fmt::Debug for Y4mStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Y4mStream").field("inner", &self.inner).finish()
    }
}

impl Y4mStream {
    /// Reads the stream header from `reader`; `name` names the stream in errors;
    /// `child` (an ffmpeg writing into `reader`) is killed when the stream is dropped.
    ///
    /// # Errors
    /// A stream that does not start with a valid Y4M header.
    pub fn new(reader: Box<dyn Read + Send>, name: PathBuf, child: Option<Child>) -> Result<Self> {
        Self::with_guard(reader, name, child.map(ChildGuard::new))
    }

    /// [`Y4mStream::new`] with the child already behind a [`ChildGuard`].
    ///
    /// # Errors
    /// A stream that does not start with a valid Y4M header.
    pub fn with_guard(reader: Box<dyn Read + Send>, name: PathBuf, child: Option<ChildGuard>) -> Result<Self> {
        let reader = BufReader::with_capacity(1 << 16, reader);
        let inner = Y4mReader::new(reader, &name, &SourceOptions::default()).map_err(|e| match e {
            facecap_core::Error::Parse { reason, .. } => facecap_core::Error::parse(
                "Y4M",
                &name,
                format!(
                    "the stream does not start with a YUV4MPEG2 header line ({reason}); \
                     send Y4M, e.g. `ffmpeg -re -i CLIP -f yuv4mpegpipe - | facecap live -`"
                ),
            ),
            other => other,
        })?;
        Ok(Y4mStream { inner, child })
    }
}

impl Drop for Y4mStream {
    fn drop(&mut self) {
        if let Some(c) = &self.child {
            c.kill();
        }
    }
}

impl FrameSource for Y4mStream {
    fn info(&self) -> &VideoInfo {
        self.inner.info()
    }

    fn path(&self) -> &Path {
        self.inner.path()
    }

    fn read_into(&mut self, frame: &mut Frame) -> facecap_core::Result<bool> {
        self.inner.read_into(frame)
    }
}

/// Pixel layout of raw frames on stdin ([`RawStream`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawFormat {
    /// 8-bit grey, `W*H` bytes per frame, full range.
    Gray,
    /// Planar 4:2:0 Y'CbCr (ffmpeg's `yuv420p`), limited range: the luma plane is used,
    /// expanded to 0..255 as every other source.
    Yuv420p,
    /// Packed 8-bit RGB (`rgb24`): grey = `(77 R + 150 G + 29 B + 128) >> 8` (ITU-R BT.601
    /// weights, as OpenCV's `RGB2GRAY`).
    Rgb24,
}

impl std::str::FromStr for RawFormat {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "gray" => Ok(RawFormat::Gray),
            "yuv420p" => Ok(RawFormat::Yuv420p),
            "rgb24" => Ok(RawFormat::Rgb24),
            _ => Err(Error::invalid("raw pixel format", s, "gray, yuv420p or rgb24")),
        }
    }
}

impl RawFormat {
    /// Bytes of one `w` x `h` frame.
    pub fn frame_len(self, w: u32, h: u32) -> usize {
        let n = w as usize * h as usize;
        match self {
            RawFormat::Gray => n,
            RawFormat::Yuv420p => n + 2 * (w.div_ceil(2) as usize * h.div_ceil(2) as usize),
            RawFormat::Rgb24 => 3 * n,
        }
    }
}

/// Raw frames of a known size and layout back to back on a reader (stdin:
/// `ffmpeg ... -f rawvideo -pix_fmt gray - | facecap live - --raw 640x480 --raw-format gray`).
pub struct RawStream {
    reader: Box<dyn Read + Send>,
    name: PathBuf,
    info: VideoInfo,
    format: RawFormat,
    buf: Vec<u8>,
    lut: [u8; 256],
    next_index: u64,
    done: bool,
}

impl std::fmt::Debug for RawStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawStream")
            .field("name", &self.name)
            .field("info", &self.info)
            .field("format", &self.format)
            .finish()
    }
}

impl RawStream {
    /// Frames of `width` x `height` in `format` at `fps` from `reader`.
    ///
    /// # Errors
    /// A zero size or a frame rate that is not finite and > 0.
    pub fn new(
        reader: Box<dyn Read + Send>,
        name: PathBuf,
        width: u32,
        height: u32,
        format: RawFormat,
        fps: f64,
    ) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::invalid(
                "raw frame size",
                format!("{width}x{height}"),
                "W and H > 0",
            ));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Error::invalid("raw frame rate", fps, "a finite number > 0"));
        }
        Ok(RawStream {
            reader,
            name,
            info: VideoInfo {
                width,
                height,
                fps,
                frame_count: None,
                duration_s: None,
                codec: format!("raw {format:?}").to_lowercase(),
                kind: SourceKind::Y4m,
            },
            format,
            buf: vec![0; format.frame_len(width, height)],
            lut: limited_to_full_luma_lut(),
            next_index: 0,
            done: false,
        })
    }
}

impl FrameSource for RawStream {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.name
    }

    fn read_into(&mut self, frame: &mut Frame) -> facecap_core::Result<bool> {
        if self.done {
            return Ok(false);
        }
        // a clean end only between frames
        let mut got = 0;
        while got < self.buf.len() {
            match self.reader.read(&mut self.buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    self.done = true;
                    return Err(facecap_core::Error::io(&self.name, e));
                }
            }
        }
        if got == 0 {
            self.done = true;
            return Ok(false);
        }
        if got < self.buf.len() {
            self.done = true;
            return Err(facecap_core::Error::Decode {
                path: self.name.clone(),
                frame: Some(self.next_index),
                reason: format!("the stream ends inside a frame ({got} of {} bytes)", self.buf.len()),
            });
        }
        let (w, h) = (self.info.width, self.info.height);
        if frame.gray.width() != w || frame.gray.height() != h {
            frame.gray = image::GrayImage::new(w, h);
        }
        frame.rgb = None;
        let n = w as usize * h as usize;
        let out: &mut [u8] = frame.gray.as_mut();
        match self.format {
            RawFormat::Gray => out.copy_from_slice(&self.buf[..n]),
            RawFormat::Yuv420p => {
                for (o, &y) in out.iter_mut().zip(&self.buf[..n]) {
                    *o = self.lut[usize::from(y)];
                }
            }
            RawFormat::Rgb24 => {
                for (o, p) in out.iter_mut().zip(self.buf.chunks_exact(3)) {
                    let v = 77 * u32::from(p[0]) + 150 * u32::from(p[1]) + 29 * u32::from(p[2]) + 128;
                    *o = (v >> 8) as u8;
                }
            }
        }
        frame.index = self.next_index;
        frame.timestamp_s = self.next_index as f64 / self.info.fps;
        self.next_index += 1;
        Ok(true)
    }
}

/// Arrival times of recent frames, by frame index (module docs).
#[derive(Debug, Clone, Default)]
pub struct ArrivalLog(Arc<Mutex<VecDeque<(u64, Instant)>>>);

impl ArrivalLog {
    fn push(&self, index: u64, at: Instant) {
        if let Ok(mut q) = self.0.lock() {
            if q.len() >= ARRIVALS_KEPT {
                q.pop_front();
            }
            q.push_back((index, at));
        }
    }

    /// When frame `index` arrived (`None` when it is too old or unknown).
    pub fn arrival(&self, index: u64) -> Option<Instant> {
        let q = self.0.lock().ok()?;
        q.iter().rev().find(|(i, _)| *i == index).map(|(_, t)| *t)
    }
}

/// Counters of a [`LatestFrame`] source, readable while it runs.
#[derive(Debug, Default)]
pub struct LiveStats {
    /// Frames read from the input.
    pub arrived: AtomicU64,
    /// Frames replaced by a newer one before the consumer took them, once it had taken
    /// its first frame.
    pub dropped: AtomicU64,
    /// Frames replaced before the consumer took its first one (start-up: a stream that
    /// began before the models were loaded, e.g. `ffmpeg -re` catching up).
    pub dropped_at_start: AtomicU64,
    /// Frames handed to the consumer.
    pub taken: AtomicU64,
}

struct Slot {
    newest: Option<Frame>,
    spare: Vec<Frame>,
    /// The input ended (`Some(Ok)`) or failed (`Some(Err)`, handed out once).
    end: Option<facecap_core::Result<()>>,
}

struct Shared {
    slot: Mutex<Slot>,
    ready: Condvar,
}

/// A source that hands out only the newest frame of `inner` (module docs).
pub struct LatestFrame {
    info: VideoInfo,
    path: PathBuf,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    stats: Arc<LiveStats>,
    arrivals: ArrivalLog,
    child: Option<ChildGuard>,
}

impl Drop for LatestFrame {
    /// Kills the source's ffmpeg child, if any: the reader thread may be blocked in a read
    /// that only the child's end can finish.
    fn drop(&mut self) {
        if let Some(c) = &self.child {
            c.kill();
        }
    }
}

impl std::fmt::Debug for LatestFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LatestFrame")
            .field("path", &self.path)
            .field("info", &self.info)
            .field("stats", &self.stats)
            .finish()
    }
}

impl LatestFrame {
    /// Starts reading `inner` on its own thread. Setting `stop` ends the stream at the
    /// consumer's next read (the way a live run is finished: Ctrl-C, SIGTERM, a key).
    ///
    /// # Errors
    /// When the reader thread cannot be started.
    pub fn spawn(mut inner: Box<dyn FrameSource>, stop: Arc<AtomicBool>) -> Result<Self> {
        let info = inner.info().clone();
        let path = inner.path().to_path_buf();
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot {
                newest: None,
                spare: Vec::new(),
                end: None,
            }),
            ready: Condvar::new(),
        });
        let stats = Arc::new(LiveStats::default());
        let arrivals = ArrivalLog::default();
        let (sh, st, ar, stop_r) = (shared.clone(), stats.clone(), arrivals.clone(), stop.clone());
        std::thread::Builder::new()
            .name("facecap-live-reader".into())
            .spawn(move || loop {
                let mut frame = sh.slot.lock().ok().and_then(|mut s| s.spare.pop()).unwrap_or_default();
                let r = inner.read_into(&mut frame);
                let now = Instant::now();
                let Ok(mut s) = sh.slot.lock() else { return };
                match r {
                    Ok(true) => {
                        st.arrived.fetch_add(1, Ordering::SeqCst);
                        ar.push(frame.index, now);
                        if let Some(old) = s.newest.replace(frame) {
                            if st.taken.load(Ordering::SeqCst) == 0 {
                                st.dropped_at_start.fetch_add(1, Ordering::SeqCst);
                            } else {
                                st.dropped.fetch_add(1, Ordering::SeqCst);
                            }
                            s.spare.push(old);
                        }
                    }
                    Ok(false) => s.end = Some(Ok(())),
                    Err(e) => s.end = Some(Err(e)),
                }
                let ended = s.end.is_some();
                drop(s);
                sh.ready.notify_all();
                if ended || stop_r.load(Ordering::SeqCst) {
                    return;
                }
            })
            .map_err(|e| Error::invalid("live reader thread", e, "a thread the system can start"))?;
        Ok(LatestFrame {
            info,
            path,
            shared,
            stop,
            stats,
            arrivals,
            child: None,
        })
    }

    /// Kills `child` (the ffmpeg behind the source, from [`open_live`]) when this is
    /// dropped, so that a run stopped while the stream is silent ends at once.
    #[must_use]
    pub fn with_child(mut self, child: Option<ChildGuard>) -> Self {
        self.child = child;
        self
    }

    /// The counters (shared; they keep counting while the source runs).
    pub fn stats(&self) -> Arc<LiveStats> {
        self.stats.clone()
    }

    /// The arrival log (shared).
    pub fn arrivals(&self) -> ArrivalLog {
        self.arrivals.clone()
    }
}

impl FrameSource for LatestFrame {
    fn info(&self) -> &VideoInfo {
        &self.info
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn read_into(&mut self, frame: &mut Frame) -> facecap_core::Result<bool> {
        let Ok(mut s) = self.shared.slot.lock() else {
            return Ok(false);
        };
        loop {
            if self.stop.load(Ordering::SeqCst) {
                return Ok(false);
            }
            if let Some(mut f) = s.newest.take() {
                self.stats.taken.fetch_add(1, Ordering::SeqCst);
                std::mem::swap(frame, &mut f);
                if f.gray.width() == frame.gray.width() && f.gray.height() == frame.gray.height() {
                    s.spare.push(f);
                }
                return Ok(true);
            }
            match s.end.take() {
                Some(Ok(())) => {
                    s.end = Some(Ok(()));
                    return Ok(false);
                }
                Some(Err(e)) => {
                    s.end = Some(Ok(()));
                    return Err(e);
                }
                None => {}
            }
            s = match self.shared.ready.wait_timeout(s, STOP_POLL) {
                Ok((g, _)) => g,
                Err(_) => return Ok(false),
            };
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A 4:2:0 Y4M stream of flat grey frames (`facecap-io`'s writer).
    fn y4m_bytes(w: u32, h: u32, frames: &[u8]) -> Vec<u8> {
        let images: Vec<_> = frames
            .iter()
            .map(|&v| image::GrayImage::from_pixel(w, h, image::Luma([v])))
            .collect();
        let mut b = Vec::new();
        facecap_io::video::y4m::write_gray_y4m(&mut b, &images, 30, 1, false).unwrap();
        b
    }

    #[test]
    fn reads_a_y4m_stream_with_full_range_grey() {
        let bytes = y4m_bytes(4, 2, &[16, 235, 126]);
        let mut s = Y4mStream::new(Box::new(std::io::Cursor::new(bytes)), "t".into(), None).unwrap();
        assert_eq!(s.info().width, 4);
        let mut f = Frame::default();
        let mut got = Vec::new();
        while s.read_into(&mut f).unwrap() {
            got.push((f.index, f.timestamp_s, f.gray.get_pixel(0, 0)[0]));
        }
        // Luma::Full: 16 -> 0, 235 -> 255, as every other source
        assert_eq!(got[0], (0, 0.0, 0));
        assert_eq!(got[1].2, 255);
        assert_eq!(got.len(), 3);
    }

    #[test]
    fn rejects_truncated_and_foreign_streams() {
        let bytes = y4m_bytes(4, 2, &[16, 235]);
        for cut in [0, 5, 20] {
            assert!(Y4mStream::new(Box::new(std::io::Cursor::new(bytes[..cut].to_vec())), "t".into(), None).is_err());
        }
        let mut s = Y4mStream::new(
            Box::new(std::io::Cursor::new(bytes[..bytes.len() - 3].to_vec())),
            "t".into(),
            None,
        )
        .unwrap();
        let mut f = Frame::default();
        assert!(s.read_into(&mut f).unwrap());
        assert!(s.read_into(&mut f).is_err());
        assert!(Y4mStream::new(Box::new(std::io::Cursor::new(b"RIFF....".to_vec())), "t".into(), None).is_err());
    }

    /// A source that yields frames as fast as asked: a slow consumer must see only the
    /// newest ones, and every frame is either taken or counted as dropped.
    #[test]
    fn latest_frame_drops_old_frames_and_counts_them() {
        let n = 40u8;
        let bytes = y4m_bytes(8, 8, &(0..n).collect::<Vec<_>>());
        let inner = Y4mStream::new(Box::new(std::io::Cursor::new(bytes)), "t".into(), None).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let mut live = LatestFrame::spawn(Box::new(inner), stop).unwrap();
        let stats = live.stats();
        let mut f = Frame::default();
        let mut taken = Vec::new();
        while live.read_into(&mut f).unwrap() {
            taken.push(f.index);
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(taken.windows(2).all(|w| w[0] < w[1]), "{taken:?}");
        let dropped = stats.dropped.load(Ordering::SeqCst) + stats.dropped_at_start.load(Ordering::SeqCst);
        assert_eq!(stats.taken.load(Ordering::SeqCst), taken.len() as u64);
        assert_eq!(stats.arrived.load(Ordering::SeqCst), u64::from(n));
        assert_eq!(taken.len() as u64 + dropped, u64::from(n));
        assert!(dropped > 0, "a slow consumer must see drops");
        assert!(live.arrivals().arrival(*taken.last().unwrap()).is_some());
    }

    #[test]
    fn stop_ends_the_stream() {
        // a reader that never delivers: the consumer still returns once stopped
        struct Never;
        impl Read for Never {
            fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
                std::thread::sleep(Duration::from_millis(20));
                Ok(0)
            }
        }
        let header = b"YUV4MPEG2 W4 H2 F30:1 C420jpeg\n".to_vec();
        let inner = Y4mStream::new(Box::new(std::io::Cursor::new(header).chain(Never)), "t".into(), None).unwrap();
        let stop = Arc::new(AtomicBool::new(true));
        let mut live = LatestFrame::spawn(Box::new(inner), stop).unwrap();
        let mut f = Frame::default();
        assert!(!live.read_into(&mut f).unwrap());
    }

    #[test]
    fn raw_streams_in_three_layouts() {
        let (w, h) = (4u32, 2u32);
        for (fmt, frame, want) in [
            (RawFormat::Gray, vec![7u8; 8], 7u8),
            (RawFormat::Yuv420p, [vec![235u8; 8], vec![128; 4]].concat(), 255),
            (RawFormat::Rgb24, [10u8, 20, 30].repeat(8), 18),
        ] {
            let bytes = [frame.clone(), frame.clone(), frame[..3].to_vec()].concat();
            let mut s = RawStream::new(Box::new(std::io::Cursor::new(bytes)), "t".into(), w, h, fmt, 25.0).unwrap();
            let mut f = Frame::default();
            assert!(s.read_into(&mut f).unwrap());
            assert_eq!(f.gray.get_pixel(3, 1)[0], want, "{fmt:?}");
            assert!(s.read_into(&mut f).unwrap());
            assert_eq!(f.timestamp_s, 0.04);
            // the third frame is cut short: an error, never a half frame
            assert!(s.read_into(&mut f).is_err(), "{fmt:?}");
        }
        assert!(RawStream::new(Box::new(std::io::empty()), "t".into(), 0, 2, RawFormat::Gray, 25.0).is_err());
        assert!(RawStream::new(Box::new(std::io::empty()), "t".into(), 2, 2, RawFormat::Gray, f64::NAN).is_err());
        assert!("bgr".parse::<RawFormat>().is_err());
    }

    #[test]
    fn parses_inputs() {
        assert_eq!(LiveInput::parse("-", false, None, None), LiveInput::Stdin);
        assert!(matches!(
            LiveInput::parse("/dev/video0", false, None, None),
            LiveInput::Camera { .. }
        ));
        assert!(matches!(
            LiveInput::parse("rtsp://h/s", false, None, None),
            LiveInput::Url(_)
        ));
        let f = LiveInput::parse("a.mp4", true, None, None);
        assert_eq!(f.ffmpeg_input_args().unwrap(), vec!["-re", "-i", "a.mp4"]);
        let c = LiveInput::parse("/dev/video2", false, Some((640, 480)), Some(30.0));
        assert_eq!(
            c.ffmpeg_input_args().unwrap(),
            vec![
                "-f",
                "v4l2",
                "-video_size",
                "640x480",
                "-framerate",
                "30",
                "-i",
                "/dev/video2"
            ]
        );
    }
}
