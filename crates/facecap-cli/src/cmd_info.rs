//! `facecap info`: decode whole videos (or Y4M files, image folders) and report what
//! was decoded.
//!
//! Text output, one block per input:
//!
//! ```text
//! file:               ../shared/data/videos/liveportrait_d9.mp4
//! source:             video (ffmpeg)
//! codec:              h264
//! resolution:         512x480
//! fps:                30
//! frames decoded:     587
//! container frames:   587
//! duration:           19.567 s
//! container duration: 19.600 s
//! decode speed:       640 frames/s (0.92 s)
//! ```
//!
//! `duration` is measured on the decoded frames: last timestamp - first timestamp + one
//! frame period (1/fps), which is what `ffprobe` calls the stream duration for a
//! constant-rate clip. With `--json` the same fields are printed as one JSON object per
//! input (an array when several inputs are given).

use std::path::PathBuf;
use std::time::Instant;

use facecap_io::video::{open_source, Frame, Luma, SourceKind, SourceOptions, DEFAULT_FOLDER_FPS};
use serde::Serialize;

/// Arguments of `facecap info`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  facecap info clip.mp4\n  facecap info --json frames_folder/")]
pub struct Args {
    /// Video files, Y4M files, image folders or images.
    #[arg(required = true, value_name = "VIDEO")]
    pub inputs: Vec<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Frame rate assumed for image folders.
    #[arg(long, default_value_t = DEFAULT_FOLDER_FPS)]
    pub folder_fps: f64,
    /// Also convert every frame to RGB (measures the RGB path's speed).
    #[arg(long)]
    pub rgb: bool,
    /// Keep decoding past damaged data (ffmpeg conceals or drops bad frames) instead of
    /// stopping with an error at the first one.
    #[arg(long)]
    pub lenient: bool,
    /// ffmpeg binary (default: $FACECAP_FFMPEG, PATH, then the cache of scripts/setup.sh).
    #[arg(long, value_name = "PATH")]
    pub ffmpeg: Option<PathBuf>,
}

/// What `facecap info` reports for one input.
#[derive(Debug, Clone, Serialize)]
pub struct InfoReport {
    /// The input path as given.
    pub path: String,
    /// `video`, `y4m`, `image_folder` or `image`.
    pub source: &'static str,
    /// Codec name.
    pub codec: String,
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Nominal frame rate.
    pub fps: f64,
    /// Frames decoded.
    pub frames_decoded: u64,
    /// Frames that could not be decoded (`--lenient`: dropped or damaged by a decode error).
    pub frames_undecodable: u64,
    /// The first such frame's error.
    pub first_undecodable: Option<String>,
    /// Frame count stated by the container, if any.
    pub container_frames: Option<u64>,
    /// Timestamp of the first decoded frame (s).
    pub first_timestamp_s: f64,
    /// Timestamp of the last decoded frame (s).
    pub last_timestamp_s: f64,
    /// Decoded duration: last - first timestamp + 1/fps (s).
    pub duration_s: f64,
    /// Duration stated by the container, if any (s).
    pub container_duration_s: Option<f64>,
    /// Wall-clock decode time (s), including opening the source.
    pub decode_seconds: f64,
    /// Frames decoded per wall-clock second.
    pub decode_fps: f64,
}

fn kind_name(k: SourceKind) -> &'static str {
    match k {
        SourceKind::Video => "video",
        SourceKind::Y4m => "y4m",
        SourceKind::ImageFolder => "image_folder",
        SourceKind::Image => "image",
    }
}

/// Decodes every frame of `path` and reports.
pub fn inspect(path: &std::path::Path, opts: &SourceOptions) -> anyhow::Result<InfoReport> {
    let start = Instant::now();
    let mut src = open_source(path, opts)?;
    let info = src.info().clone();
    let mut frame = Frame::default();
    let (mut n, mut first, mut last) = (0u64, 0.0, 0.0);
    let (mut bad, mut consecutive, mut first_bad) = (0u64, 0u32, None);
    loop {
        match src.read_into(&mut frame) {
            Ok(false) => break,
            Ok(true) => {
                if n == 0 {
                    first = frame.timestamp_s;
                }
                last = frame.timestamp_s;
                n += 1;
                consecutive = 0;
            }
            // Lenient: an undecodable frame is counted and decoding goes on (as capture's
            // salvage mode does), up to the same limit of consecutive failures.
            Err(e) if !opts.strict && consecutive < facecap_pipeline::tracker::MAX_CONSECUTIVE_DECODE_ERRORS => {
                bad += 1;
                consecutive += 1;
                first_bad.get_or_insert_with(|| e.to_string());
            }
            Err(e) => {
                return Err(anyhow::Error::new(e).context(format!("decoding {} after {n} frames", path.display())))
            }
        }
    }
    drop(src);
    let secs = start.elapsed().as_secs_f64();
    let duration_s = if n == 0 { 0.0 } else { last - first + 1.0 / info.fps };
    Ok(InfoReport {
        path: path.display().to_string(),
        source: kind_name(info.kind),
        codec: info.codec,
        width: info.width,
        height: info.height,
        fps: info.fps,
        frames_decoded: n,
        frames_undecodable: bad,
        first_undecodable: first_bad,
        container_frames: info.frame_count,
        first_timestamp_s: first,
        last_timestamp_s: last,
        duration_s,
        container_duration_s: info.duration_s,
        decode_seconds: secs,
        decode_fps: if secs > 0.0 { n as f64 / secs } else { 0.0 },
    })
}

fn print_text(r: &InfoReport) {
    let source = match r.source {
        "video" => "video (ffmpeg)",
        "y4m" => "y4m (native reader)",
        "image_folder" => "image folder",
        other => other,
    };
    outln!("file:               {}", r.path);
    outln!("source:             {source}");
    outln!("codec:              {}", r.codec);
    outln!("resolution:         {}x{}", r.width, r.height);
    outln!("fps:                {}", r.fps);
    outln!("frames decoded:     {}", r.frames_decoded);
    if r.frames_undecodable > 0 {
        outln!("frames undecodable: {}", r.frames_undecodable);
    }
    if let Some(c) = r.container_frames {
        outln!("container frames:   {c}");
    }
    outln!("duration:           {:.3} s", r.duration_s);
    if let Some(d) = r.container_duration_s {
        outln!("container duration: {d:.3} s");
    }
    outln!(
        "decode speed:       {:.0} frames/s ({:.2} s)",
        r.decode_fps,
        r.decode_seconds
    );
}

/// Runs `facecap info`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let opts = SourceOptions {
        rgb: args.rgb,
        folder_fps: args.folder_fps,
        luma: Luma::Full,
        ffmpeg: args.ffmpeg.clone(),
        strict: !args.lenient,
        threads: 0,
        scale: None,
        ..SourceOptions::default()
    };
    let mut reports = Vec::with_capacity(args.inputs.len());
    for (i, path) in args.inputs.iter().enumerate() {
        let r = inspect(path, &opts)?;
        if !args.json {
            if i > 0 {
                outln!();
            }
            print_text(&r);
        }
        reports.push(r);
    }
    if args.json {
        let text = if reports.len() == 1 {
            serde_json::to_string_pretty(&reports[0])?
        } else {
            serde_json::to_string_pretty(&reports)?
        };
        outln!("{text}");
    }
    Ok(std::process::ExitCode::SUCCESS)
}
