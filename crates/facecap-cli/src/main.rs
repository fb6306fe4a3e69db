//! `facecap` command-line tool: composes the facecap crates.
//!
//! Each subcommand lives in its own module with its `clap::Args` struct and a
//! `run` function; `main` only dispatches.

use clap::{Parser, Subcommand};

/// `println!` that never panics on a closed stdout (see [`out`]).
macro_rules! outln {
    () => {
        $crate::out::println("")
    };
    ($($arg:tt)*) => {
        $crate::out::println(&format!($($arg)*))
    };
}

mod cmd_batch;
mod cmd_capture;
mod cmd_info;
mod cmd_landmarks;
mod cmd_landmarks_mesh;
mod cmd_landmarks_video;
mod cmd_live;
mod cmd_muscle;
mod cmd_rig;
mod cmd_solve;
mod cmd_synth;
mod cmd_tensor;
mod cmd_tensor_fit;
mod cmd_transfer;
mod default_rig;
mod ert_flag;
mod eyelid;
mod live_window;
mod neutral;
mod out;
mod progress;
mod report;
mod truth;
mod upsample_flag;
mod warp;

/// Markerless facial performance capture from monocular video.
#[derive(Debug, Parser)]
#[command(name = "facecap", version, about, long_about = None)]
struct Cli {
    /// No progress output (errors are still printed on stderr).
    #[arg(short, long, global = true)]
    quiet: bool,
    /// More detail on stderr (per-stage notes and timings).
    #[arg(short, long, global = true, conflicts_with = "quiet")]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Decode a whole video and print frames decoded, resolution, fps, duration and codec.
    Info(cmd_info::Args),
    /// 68 landmarks for images (one .pts per face) or a video (landmarks.csv).
    Landmarks(cmd_landmarks::Args),
    /// Solve blendshape weights from a landmarks CSV against a rig.
    Solve(cmd_solve::Args),
    /// Muscle model: track contractions from video, bake muscle blendshapes.
    #[command(subcommand)]
    Muscle(cmd_muscle::Command),
    /// Tensor face model: build, generate, fit.
    #[command(subcommand)]
    Tensor(cmd_tensor::Command),
    /// Transfer expressions from a source video onto a target.
    Transfer(cmd_tensor::TransferArgs),
    /// One command from video to landmarks, pose, weights, meshes and a report.
    Capture(cmd_capture::Args),
    /// A manifest of videos captured in resumable shards, locally or as a Slurm job array.
    Batch(cmd_batch::Args),
    /// Live capture: a camera, stream or Y4M on stdin in; OSC/VMC, Live Link Face, JSON out in real time.
    Live(cmd_live::Args),
    /// Make a synthetic ground-truth video from a real face photo.
    Synth(cmd_synth::Args),
    /// What the 68 landmarks see of a rig's shapes, and the priors capture solves with.
    Rig(cmd_rig::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    out::set(cli.quiet, cli.verbose);
    let result = match cli.command {
        Command::Info(a) => cmd_info::run(a),
        Command::Landmarks(a) => cmd_landmarks::run(a),
        Command::Solve(a) => cmd_solve::run(a),
        Command::Muscle(c) => cmd_muscle::run(c),
        Command::Tensor(c) => cmd_tensor::run(c),
        Command::Transfer(a) => cmd_tensor::run_transfer(a),
        Command::Capture(a) => cmd_capture::run(a),
        Command::Batch(a) => cmd_batch::run(a),
        Command::Synth(a) => cmd_synth::run(a),
        Command::Live(a) => cmd_live::run(a),
        Command::Rig(a) => cmd_rig::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// An error and its causes on one line, each cause once: a cause whose text its
/// parent's message already contains is not repeated.
pub(crate) fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let msg = cause.to_string();
        if text.contains(&msg) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&msg);
    }
    text
}

/// Worker threads for `--jobs`: the request, or the number of cores, capped at the
/// cores the machine has and at the number of `items` (one per video); a larger
/// request is capped with a note on stderr (a pool of 100,000 threads only thrashes).
pub(crate) fn capped_jobs(requested: Option<usize>, items: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let cap = cores.min(items.max(1));
    match requested {
        Some(n) if n > cores => {
            out::info(&format!("--jobs {n}: this machine has {cores} cores; using {cap}"));
            cap
        }
        Some(n) => n.clamp(1, cap),
        None => cap,
    }
}

/// Writes an RGB image as PNG atomically (temporary file + rename: a kill leaves no
/// partial PNG under its final name).
pub(crate) fn save_png_atomic(img: &image::RgbImage, path: &std::path::Path) -> anyhow::Result<()> {
    let bytes = report::png_bytes_fast(img)?;
    facecap_core::atomic::write_atomic(path, |w| std::io::Write::write_all(w, &bytes))?;
    Ok(())
}

/// Prints on stderr (also with `--quiet`) what salvage mode did with a damaged input:
/// how many frames could not be decoded, and the first reason. Returns whether any
/// frame was decoded.
pub(crate) fn report_undecodable(input: &std::path::Path, run: &facecap_pipeline::RunReport) -> bool {
    let bad = run.undecodable.len() as u64;
    if let Some((first, why)) = run.undecodable.first() {
        eprintln!(
            "warning: {}: {bad} of {} frames could not be decoded (success = 0); first at frame {first}: {why}",
            input.display(),
            run.frames
        );
    }
    run.frames > bad
}
