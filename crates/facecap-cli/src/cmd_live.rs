//! `facecap live INPUT`: a camera, a stream or Y4M on stdin in; blendshape weights and
//! head pose out in real time (OSC/VMC, Live Link Face, JSON lines), with a preview
//! window and, with `--out`, the files `capture` writes.
//!
//! The same tracker and expression solve as `capture` (facecap-pipeline's
//! `VideoTracker`, `ExpressionSink` built by `build_expression_solve`, the same rig,
//! priors, neutral hook, gaze and blink handling), fed newest-first
//! (`facecap_pipeline::live::LatestFrame`, `Queues::LIVE`): when the solve falls behind,
//! waiting frames are dropped and counted, never queued. The run ends at the end of the
//! stream, on Ctrl-C or SIGTERM, or when the window is closed (Esc or Q); then the
//! recording is finalised atomically. The neutral is taken from the first second of the
//! face (`--neutral-after` seconds in) and again on the N key or SIGUSR1.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use facecap_core::camera::Intrinsics;
use facecap_pipeline::live::RawInput;
use facecap_pipeline::net::{quantile, udp_to, JsonTarget, LiveReport, PreviewFrame};
use facecap_pipeline::outputs::SolveOutputs;
use facecap_pipeline::{
    open_live, ExpressionSink, FrameImages, LandmarkCsvSink, LatestFrame, LiveInput, LiveNeutral, LiveOutputs,
    LiveSink, Queues, RunControl, Sink, TrackerPolicy, VideoTracker,
};
use serde_json::json;

use crate::cmd_capture::{expression_parts, parse_camera, SolveArgs};

/// Length of the resting window the neutral is taken from (seconds).
pub const NEUTRAL_WINDOW_S: f64 = 1.0;
/// Seconds at the start and end of a run compared for a growing delay.
const DRIFT_WINDOW_S: f64 = 10.0;

/// Arguments of `facecap live`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:\n  facecap live /dev/video0 --osc 127.0.0.1:39539\n  \
    ffmpeg -re -i clip.mp4 -f yuv4mpegpipe - | facecap live - --livelink 127.0.0.1:11111 --no-window\n  \
    facecap live clip.mp4 --realtime --json --out take1/")]
pub struct Args {
    /// `-` (Y4M on stdin), a V4L2 camera (`/dev/video0`), an ffmpeg URL (`rtsp://...`,
    /// `udp://...`), or a video file (with --realtime).
    pub input: String,
    /// Play a file at its own frame rate (ffmpeg's `-re`).
    #[arg(long)]
    pub realtime: bool,
    /// Camera frame size `WxH` (V4L2 input).
    #[arg(long, value_name = "WxH")]
    pub size: Option<String>,
    /// Camera frame rate (V4L2 input), or the frame rate of `--raw` frames (default 30).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Raw frames of this size on stdin instead of Y4M (`INPUT` = `-`).
    #[arg(long, value_name = "WxH")]
    pub raw: Option<String>,
    /// Pixel layout of `--raw` frames.
    #[arg(long, default_value = "yuv420p", value_parser = ["gray", "yuv420p", "rgb24"])]
    pub raw_format: String,
    /// Send VMC-protocol OSC (VSeeFace, VTube Studio, Warudo, Blender VMC add-ons) to
    /// HOST:PORT (VMC's usual port is 39539).
    #[arg(long, value_name = "HOST:PORT")]
    pub osc: Option<String>,
    /// Send Live Link Face packets (Unreal's Apple ARKit Face Support) to HOST:PORT
    /// (Unreal listens on 11111).
    #[arg(long, value_name = "HOST:PORT")]
    pub livelink: Option<String>,
    /// JSON lines, one per frame, to stdout (`--json`) or over UDP (`--json HOST:PORT`).
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "-")]
    pub json: Option<String>,
    /// Record into DIR the files `capture` writes (landmarks.csv, pose.csv, weights.csv,
    /// livelink.csv, openface.csv, animation.glb, summary.json) and latency.csv (per
    /// frame: stream time, ms from arrival to packets), finalised at the end.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// No preview window (headless).
    #[arg(long)]
    pub no_window: bool,
    /// Neutral calibration: `auto` (default: the subject's neutral from one second of the
    /// resting face, redone on the N key or SIGUSR1) or `none`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "none"])]
    pub neutral: String,
    /// Seconds after the first face before the one-second neutral window starts.
    #[arg(long, default_value_t = 0.0, value_name = "SECONDS")]
    pub neutral_after: f64,
    /// Live Link subject name.
    #[arg(long, default_value = "facecap")]
    pub subject: String,
    /// The rig and solver flags (as `capture`).
    #[command(flatten)]
    pub solve: SolveArgs,
    /// `--upsample`.
    #[command(flatten)]
    pub detect: crate::upsample_flag::UpsampleFlag,
    /// `--ert-precision`.
    #[command(flatten)]
    pub ert: crate::ert_flag::ErtFlag,
}

fn parse_size(flag: &str, s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| anyhow::anyhow!("{flag} {s:?}: expected WxH, e.g. 640x480"))?;
    let (w, h): (u32, u32) = (
        w.trim().parse().with_context(|| format!("{flag} {s:?}: width"))?,
        h.trim().parse().with_context(|| format!("{flag} {s:?}: height"))?,
    );
    if w == 0 || h == 0 {
        anyhow::bail!("{flag} {s:?}: width and height must be > 0");
    }
    Ok((w, h))
}

/// Stop and neutral-redo flags, set by signals and the window.
#[derive(Debug, Clone)]
pub(crate) struct Controls {
    pub(crate) stop: Arc<AtomicBool>,
    pub(crate) redo_neutral: Arc<AtomicBool>,
}

fn install_signals() -> anyhow::Result<Controls> {
    use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
    let c = Controls {
        stop: Arc::new(AtomicBool::new(false)),
        redo_neutral: Arc::new(AtomicBool::new(false)),
    };
    for sig in [SIGINT, SIGTERM] {
        // a second signal exits at once (temporary files are never under final names)
        signal_hook::flag::register_conditional_shutdown(sig, 130, c.stop.clone())?;
        signal_hook::flag::register(sig, c.stop.clone())?;
    }
    signal_hook::flag::register(SIGUSR1, c.redo_neutral.clone())?;
    Ok(c)
}

/// Runs `facecap live`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let controls = install_signals()?;
    if !(args.neutral_after.is_finite() && args.neutral_after >= 0.0) {
        anyhow::bail!(
            "--neutral-after must be a finite number >= 0, got {}",
            args.neutral_after
        );
    }
    if let Some(f) = args.fps {
        if !(f.is_finite() && f > 0.0) {
            anyhow::bail!("--fps must be a finite number > 0, got {f}");
        }
    }
    let size = args.size.as_deref().map(|s| parse_size("--size", s)).transpose()?;
    let input = LiveInput::parse(&args.input, args.realtime, size, args.fps);
    if let LiveInput::File { path, realtime: false } = &input {
        anyhow::bail!(
            "{} is a file: add --realtime to play it at its own frame rate (`facecap capture` reads files as fast as it can)",
            path.display()
        );
    }
    let parts = expression_parts(&args.solve, &args.neutral)?;
    let tracker = VideoTracker::new(&TrackerPolicy {
        smooth: false,
        shape_model: None,
        upsample: args.detect.upsample,
        ert_precision: args.ert.ert_precision,
        ..TrackerPolicy::default()
    })?;
    let outputs_osc = args.osc.as_deref().map(udp_to).transpose()?;
    let outputs_ll = args.livelink.as_deref().map(udp_to).transpose()?;
    let json = match args.json.as_deref() {
        None => None,
        Some("-") => Some(JsonTarget::Stdout),
        Some(t) => Some(JsonTarget::Udp(udp_to(t)?)),
    };
    let raw = match args.raw.as_deref() {
        None => None,
        Some(_) if input != LiveInput::Stdin => anyhow::bail!("--raw reads stdin: give `-` as the input"),
        Some(r) => {
            let (width, height) = parse_size("--raw", r)?;
            Some(RawInput {
                width,
                height,
                format: args.raw_format.parse()?,
                fps: args.fps.unwrap_or(facecap_io::livelink::FALLBACK_FPS),
            })
        }
    };
    let (source, child) = open_live(&input, None, raw, &controls.stop)?;
    let info = source.info().clone();
    let camera = match args.solve.camera.as_deref() {
        Some(c) => parse_camera(c)?,
        None => Intrinsics::default_for_frame(info.width, info.height)?,
    };
    let live = LatestFrame::spawn(source, controls.stop.clone())?.with_child(child);
    let (stats, arrivals) = (live.stats(), live.arrivals());
    // Without --out the CSVs go to a temporary folder and are never committed.
    let scratch = tempfile::tempdir().context("creating a temporary folder")?;
    let rec_dir: &Path = match &args.out {
        Some(d) => {
            std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
            let _ = std::fs::remove_file(d.join("summary.json"));
            d
        }
        None => scratch.path(),
    };
    let solve = ExpressionSink::create(rec_dir, &parts.expression, Some(camera), None, FrameImages::None)?;
    let solve = if parts.neutral.active() {
        let hook = crate::cmd_capture::NeutralHook {
            choice: parts.neutral.choice,
            method: parts.neutral.method,
            objective: parts.neutral.objective,
            priors: parts.neutral.priors.clone(),
        };
        solve.with_live_neutral(
            Arc::new(hook),
            LiveNeutral {
                after: args.neutral_after,
                window: NEUTRAL_WINDOW_S,
                redo: controls.redo_neutral.clone(),
            },
        )?
    } else {
        solve
    };
    let window = !args.no_window && crate::live_window::display_available();
    let renderer = if window { Some(parts.renderer()?) } else { None };
    if !args.no_window && !window {
        crate::out::info("no display (DISPLAY and WAYLAND_DISPLAY unset): running without the preview window");
    }
    let (preview_tx, preview_rx) = std::sync::mpsc::sync_channel::<PreviewFrame>(1);
    let outputs = LiveOutputs {
        osc: outputs_osc,
        livelink: outputs_ll,
        json,
        subject: args.subject.clone(),
        device: format!("facecap-{}", std::process::id()),
        fps: info.fps,
    };
    let mut live_sink = LiveSink::new(solve, outputs, arrivals, stats.clone(), window.then_some(preview_tx))
        .on_neutral(Box::new(|e: &serde_json::Value| {
            crate::out::info(&format!(
                "live: neutral {} from frames {}..{} {} from frame {}",
                e["calibration"],
                e["first_frame"],
                e["last_frame"],
                if e.get("error").is_some() {
                    "failed, kept the previous rig"
                } else {
                    "applied"
                },
                e["applied_from_frame"]
            ))
        }));
    let mut landmarks = args
        .out
        .as_ref()
        .map(|d| LandmarkCsvSink::create(d.join("landmarks.csv")))
        .transpose()?;
    crate::out::info(&format!(
        "live: {} ({}x{}, {:.2} fps){}",
        args.input,
        info.width,
        info.height,
        info.fps,
        if window {
            "; N: neutral again, Esc/Q: stop"
        } else {
            "; Ctrl-C stops, SIGUSR1 takes the neutral again"
        }
    ));
    let started = std::time::Instant::now();
    let run = std::thread::scope(|scope| -> anyhow::Result<_> {
        let win = renderer.as_ref().map(|renderer| {
            let c = controls.clone();
            scope.spawn(move || crate::live_window::run_window(preview_rx, renderer, &c))
        });
        let result = {
            let mut sinks: Vec<&mut dyn Sink> = vec![&mut live_sink];
            if let Some(l) = landmarks.as_mut() {
                sinks.push(l);
            }
            tracker.run_with_queues(Box::new(live), &mut sinks, &mut RunControl::default(), Queues::LIVE)
        };
        // the preview channel closes with the sink; the window ends
        if let Some(w) = win {
            controls.stop.store(true, Ordering::SeqCst);
            match w.join() {
                Ok(Err(e)) => crate::out::info(&format!("preview window: {e}")),
                Err(_) => crate::out::info("preview window: the window thread panicked"),
                Ok(Ok(())) => {}
            }
        }
        Ok(result?)
    })?;
    let seconds = started.elapsed().as_secs_f64();
    let neutrals = live_sink.neutrals_taken();
    let (result, report) = live_sink.finish()?;
    let arrived = stats.arrived.load(Ordering::SeqCst);
    let dropped = stats.dropped.load(Ordering::SeqCst);
    let dropped_at_start = stats.dropped_at_start.load(Ordering::SeqCst);
    let running = arrived.saturating_sub(dropped_at_start);
    let lat = latency_summary(&report);
    let summary = json!({
        "input": args.input,
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "seconds": seconds,
        "frames_arrived": arrived,
        "frames_processed": report.frames,
        "frames_dropped": dropped,
        "frames_dropped_at_start": dropped_at_start,
        "dropped_percent": if running > 0 { 100.0 * dropped as f64 / running as f64 } else { 0.0 },
        "faces_found": result.faces_found,
        "latency_ms": lat,
        "osc_packets": report.osc_packets,
        "livelink_packets": report.livelink_packets,
        "json_lines": report.json_lines,
        "send_errors": report.send_errors,
        "neutral_calibrations": neutrals,
        "neutral_calibration": result.neutral_report,
        "timings_seconds": {"decode": run.decode_seconds, "track": run.track_seconds, "live": run.sink_seconds("live")},
        "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy},
        "shapes": result.names,
        "settings": {"rig": parts.rig_name, "solver": parts.expression.method.name(), "temporal": args.solve.temporal,
                     "neutral": args.neutral, "neutral_after": args.neutral_after},
        "versions": {"facecap": env!("CARGO_PKG_VERSION")},
    });
    crate::out::info(&format!(
        "live: {} frames arrived, {} processed, {} dropped ({:.2} %) and {} before the first, face on {}; latency arrival to packet p50 {:.1} ms, p99 {:.1} ms",
        arrived,
        report.frames,
        dropped,
        summary["dropped_percent"].as_f64().unwrap_or(0.0),
        dropped_at_start,
        result.faces_found,
        lat["p50"].as_f64().unwrap_or(f64::NAN),
        lat["p99"].as_f64().unwrap_or(f64::NAN),
    ));
    if let Some(dir) = &args.out {
        if let Some(l) = landmarks {
            l.finish()?;
        }
        let fps = facecap_io::livelink::rate_or_fallback(info.fps);
        let written = facecap_pipeline::outputs::write_solve_outputs(
            dir,
            &parts.expression.rig,
            &parts.rig_mesh,
            &result,
            &SolveOutputs {
                obj: None,
                still_head: false,
                fps,
                rig_unit_mm: facecap_pipeline::openface::RIG_UNIT_MM,
            },
        )?;
        let mut text = String::from("timestamp,latency_ms\n");
        for (t, l) in &report.latencies {
            text.push_str(&format!("{t:.6},{l:.3}\n"));
        }
        facecap_core::atomic::write_atomic(dir.join("latency.csv"), |w| w.write_all(text.as_bytes()))?;
        let mut summary = summary;
        summary["livelink_csv"] = json!(written.livelink);
        summary["head_animated"] = json!(written.head_animated);
        let text = serde_json::to_string_pretty(&summary)?;
        facecap_core::atomic::write_atomic(dir.join("summary.json"), |w| w.write_all(text.as_bytes()))?;
        crate::out::info(&format!("live: recorded into {}", dir.display()));
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// p50 / p99 / max of the latencies, and p50 / p99 over the first and the last
/// [`DRIFT_WINDOW_S`] seconds of the stream (a growing delay shows as last > first).
fn latency_summary(report: &LiveReport) -> serde_json::Value {
    let all: Vec<f64> = report.latencies.iter().map(|(_, l)| *l).collect();
    let (t0, t1) = match (report.latencies.first(), report.latencies.last()) {
        (Some(a), Some(b)) => (a.0, b.0),
        _ => (0.0, 0.0),
    };
    let part = |lo: f64, hi: f64| -> Vec<f64> {
        report
            .latencies
            .iter()
            .filter(|(t, _)| *t >= lo && *t <= hi)
            .map(|(_, l)| *l)
            .collect()
    };
    let first = part(t0, t0 + DRIFT_WINDOW_S);
    let last = part(t1 - DRIFT_WINDOW_S, t1);
    let q = |v: &[f64], p: f64| {
        let x = quantile(v, p);
        if x.is_finite() {
            json!(x)
        } else {
            serde_json::Value::Null
        }
    };
    json!({
        "frames": all.len(),
        "p50": q(&all, 0.5), "p99": q(&all, 0.99), "max": q(&all, 1.0),
        "first_10s": {"p50": q(&first, 0.5), "p99": q(&first, 0.99)},
        "last_10s": {"p50": q(&last, 0.5), "p99": q(&last, 0.99)},
    })
}
