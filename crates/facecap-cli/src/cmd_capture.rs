//! `facecap capture VIDEO... --out DIR`: video in; landmarks, head pose, blendshape
//! weights, optional muscle contractions and tensor parameters, an animated rig and a
//! report out.
//!
//! Per video, in `DIR/<video-stem>/`: `landmarks.csv`, `pose.csv`, `weights.csv`
//! (named columns), `livelink.csv` (Live Link Face layout, when the rig's shape names
//! are ARKit names), `contractions.csv` (with `--muscles`), `tensor.csv` (with
//! `--tensor`), `animation.glb`, `obj/frame_NNNNNN.obj` (with `--obj`), `report.html`
//! with its images, and `summary.json`, written **last**: a folder without it is not a
//! finished capture, and reruns skip only folders that have it (unless `--force`).
//! Every file is written atomically (temporary file + rename), so an interrupt or a
//! crash never leaves a half-written file under a final name.

use facecap_landmarks::detect::Upsample;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use facecap_core::camera::{Intrinsics, ModelToCamera};
use facecap_core::csv::{landmark_columns, landmark_values, FrameCsvWriter, FrameRow, POSE_COLUMNS};
use facecap_core::gltf_io::MorphAnimation;
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::{Landmarks68, NUM_LANDMARKS};
use facecap_core::mesh::MorphMesh;
use facecap_core::video::{open_source, Frame, SourceOptions};
use facecap_landmarks::tracker::{LandmarkTracker, TrackedFrame, TrackerParams, TrackerState};
use facecap_solve::{AnySolver, BlendshapeRig, ExpressionSolver, Method, ObjectiveParams, Solution, SolveState};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde_json::json;

use crate::report;

/// Arguments of `facecap capture`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input videos (files, Y4M, or folders of images).
    #[arg(required = true)]
    pub videos: Vec<PathBuf>,
    /// Output folder; each video gets `DIR/<video-stem>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// Blendshape rig (glTF/GLB with morph targets). Default: the built-in rig.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Landmark map of `--rig` (JSON: `vertex_by_ibug_0based`, or a list of 68 ids).
    #[arg(long)]
    pub landmark_map: Option<PathBuf>,
    /// Expression solver (`exact3d`: joint head pose and weights, perspective camera).
    #[arg(long, default_value = "exact3d", value_parser = ["exact", "exact3d", "bobyqa", "region", "pca"])]
    pub solver: String,
    /// Muscle set JSON, or `default` for the built-in 11-muscle set.
    #[arg(long)]
    pub muscles: Option<String>,
    /// Tensor model file (from `facecap tensor build`).
    #[arg(long)]
    pub tensor: Option<PathBuf>,
    /// Landmark map of the `--tensor` model's mesh (68 iBUG landmarks -> vertex ids).
    #[arg(long)]
    pub tensor_landmark_map: Option<PathBuf>,
    /// Camera intrinsics `fx,fy,cx,cy` (pixels). Default: fx = fy = max(W, H), centre.
    #[arg(long)]
    pub camera: Option<String>,
    /// Also write one OBJ per frame.
    #[arg(long)]
    pub obj: bool,
    /// Temporal smoothness weight of the solver (`lambda * ||e_t - e_{t-1}||^2`, px^2).
    /// The default cuts the weights' jitter on resting stretches by a quarter with no lag at
    /// blink onset (docs/expressions.md, "Temporal"); 0 turns it off.
    #[arg(long, default_value_t = 100.0)]
    pub temporal: f64,
    /// Smooth landmarks with the One Euro filter (less jitter on still faces, some lag
    /// on fast motion; off by default, see docs/tracking.md).
    #[arg(long)]
    pub smooth: bool,
    /// Redo videos that already have a finished capture.
    #[arg(long)]
    pub force: bool,
    /// Videos processed at once (default: number of cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Per-subject neutral calibration: `auto` (default: the subject's neutral face fitted
    /// in 3D over many resting frames; with a 2D solver, the frame closest to the clip's
    /// median face shape), `none`, or
    /// a frame index where the subject's face is at rest. See docs/capture.md.
    #[arg(long, default_value = "auto")]
    pub neutral: String,
    /// ffmpeg decoder threads per video (0 = ffmpeg's choice). One thread per video
    /// costs the least CPU per frame; decoding runs beside tracking either way.
    #[arg(long, default_value_t = 1)]
    pub decode_threads: u32,
    /// Number of frames on the report's contact sheet.
    #[arg(long, default_value_t = 12)]
    pub sheet_frames: usize,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
    /// Print a JSON summary of all videos on stdout.
    #[arg(long)]
    pub json: bool,
    /// Face detector up-sampling: `auto` (default; finds what dlib's `detector(img, 1)`
    /// finds, scanning the finest levels only when needed) or N = 0..4 doublings of the
    /// image before detection, exactly dlib's `detector(img, N)` (docs/detection.md).
    #[arg(long, value_name = "auto|N", default_value = "auto")]
    pub upsample: Upsample,
}

/// The solver's time-aligned per-frame output kept for the animation and report.
#[derive(Debug, Clone)]
struct FrameOut {
    timestamp: f64,
    success: bool,
    confidence: f64,
    landmarks: Option<Landmarks68>,
    weights: Vec<f64>,
    pose: Option<ModelToCamera>,
    reprojection_px: f64,
}

/// Everything shared by all videos.
struct Setup {
    rig_mesh: MorphMesh,
    rig: BlendshapeRig,
    rig_name: String,
    method: Method,
    objective: ObjectiveParams,
    camera: Option<Intrinsics>,
    tracker: LandmarkTracker<facecap_landmarks::detect::FaceDetector, facecap_landmarks::ert::ShapePredictor>,
    /// Iris centres from the grey frames: the gaze signal of the rig's `eyeLook*` shapes.
    iris: facecap_landmarks::gaze::IrisEstimator,
    muscles: Option<crate::capture_extras::MuscleSetup>,
    tensor: Option<crate::capture_extras::TensorSetup>,
    neutral: crate::neutral::NeutralChoice,
    /// Whether the rig's measured default priors are used (3D solver).
    use_priors: bool,
    args_echo: serde_json::Value,
}

fn parse_camera(s: &str) -> anyhow::Result<Intrinsics> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--camera {s:?}: expected four numbers fx,fy,cx,cy"))?;
    if v.len() != 4 {
        anyhow::bail!("--camera {s:?}: expected four numbers fx,fy,cx,cy, got {}", v.len());
    }
    Ok(Intrinsics::new(v[0], v[1], v[2], v[3])?)
}

fn build_setup(args: &Args) -> anyhow::Result<Setup> {
    let method: Method = args.solver.parse()?;
    let neutral: crate::neutral::NeutralChoice = args.neutral.parse()?;
    if !(args.temporal.is_finite() && args.temporal >= 0.0) {
        anyhow::bail!("--temporal must be finite and >= 0, got {}", args.temporal);
    }
    let (rig_mesh, map, rig_name) = match &args.rig {
        Some(path) => {
            let map_path = args
                .landmark_map
                .as_ref()
                .ok_or_else(|| anyhow::anyhow!("--rig needs --landmark-map (68 iBUG landmarks -> vertex ids)"))?;
            let mesh = facecap_core::gltf_io::read_morph_mesh(path)?;
            let map = LandmarkMap::from_json_file(map_path)?;
            (mesh, map, path.display().to_string())
        }
        None => {
            let (mesh, map) = crate::default_rig::default_rig()?;
            (mesh, map, "built-in default rig".to_string())
        }
    };
    let rig = BlendshapeRig::from_morph_mesh(rig_mesh.clone(), &map, &rig_name)?;
    let objective = ObjectiveParams {
        temporal: args.temporal,
        ..ObjectiveParams::default()
    };
    objective.validate()?;
    let camera = args.camera.as_deref().map(parse_camera).transpose()?;
    let detector = facecap_landmarks::detect::FaceDetector::default_model()?.with_upsample(args.upsample)?;
    let ert_path = facecap_core::paths::model_file(facecap_core::paths::DLIB_68_MODEL).ok_or_else(|| {
        anyhow::anyhow!(
            "{} is not in the model cache: run scripts/setup.sh",
            facecap_core::paths::DLIB_68_MODEL
        )
    })?;
    // Sub-pixel output: dlib rounds to whole pixels, which adds jitter to tracking.
    let ert = facecap_landmarks::ert::ShapePredictor::from_file_cached(&ert_path)?
        .0
        .with_params(facecap_landmarks::ert::ErtParams {
            output: facecap_landmarks::ert::OutputPrecision::SubPixel,
        });
    let mut tracker_params = TrackerParams::default();
    if args.smooth {
        tracker_params.filter = Some(facecap_landmarks::tracker::one_euro::OneEuroParams::default());
    }
    let tracker = LandmarkTracker::new(detector, ert, tracker_params)?;
    let iris = facecap_landmarks::gaze::IrisEstimator::new(facecap_landmarks::gaze::IrisParams::default())?;
    let muscles = args
        .muscles
        .as_deref()
        .map(|m| crate::capture_extras::MuscleSetup::new(m, &rig_mesh, &map))
        .transpose()?;
    let tensor = args
        .tensor
        .as_deref()
        .map(|p| crate::capture_extras::TensorSetup::new(p, args.tensor_landmark_map.as_deref()))
        .transpose()?;
    let args_echo = json!({
        "rig": rig_name,
        "solver": method.name(),
        "temporal": args.temporal,
        "smooth": args.smooth,
        "camera": args.camera,
        "muscles": args.muscles,
        "tensor": args.tensor.as_ref().map(|p| p.display().to_string()),
        "obj": args.obj,
        "neutral": args.neutral,
        "priors": "observability defaults (facecap rig)",
    });
    Ok(Setup {
        rig_mesh,
        rig,
        rig_name,
        method,
        objective,
        camera,
        tracker,
        iris,
        muscles,
        tensor,
        neutral,
        use_priors: true,
        args_echo,
    })
}

/// Outcome of one video.
#[derive(Debug)]
enum Outcome {
    Done(serde_json::Value),
    Skipped(PathBuf),
    Failed(String),
}

/// Runs `facecap capture`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        // A second Ctrl-C exits at once; temporary files are then left under
        // `.name.tmp-PID` names, never under final names.
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    }
    let setup = build_setup(&args)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs).build()?;
    let progress = crate::progress::Progress::new(args.quiet);
    let t0 = Instant::now();
    let outcomes: Vec<(PathBuf, Outcome)> = pool.install(|| {
        args.videos
            .par_iter()
            .map(|video| {
                let out_dir = args.out.join(video_stem(video));
                let outcome = if out_dir.join("summary.json").is_file() && !args.force {
                    progress.line(&format!(
                        "skip {} (finished capture in {}; --force redoes it)",
                        video.display(),
                        out_dir.display()
                    ));
                    Outcome::Skipped(out_dir)
                } else {
                    match capture_one(video, &out_dir, &args, &setup, &interrupted, &progress) {
                        Ok(v) => Outcome::Done(v),
                        Err(e) => {
                            progress.line(&format!("FAILED {}: {e:#}", video.display()));
                            Outcome::Failed(format!("{e:#}"))
                        }
                    }
                };
                (video.clone(), outcome)
            })
            .collect()
    });
    let mut all_ok = true;
    let mut report = Vec::new();
    for (video, o) in &outcomes {
        match o {
            Outcome::Done(v) => report.push(json!({"video": video, "status": "done", "summary": v})),
            Outcome::Skipped(d) => report.push(json!({"video": video, "status": "skipped", "out": d})),
            Outcome::Failed(e) => {
                all_ok = false;
                report.push(json!({"video": video, "status": "failed", "error": e}))
            }
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({"videos": report, "seconds": t0.elapsed().as_secs_f64()}))?
        );
    } else if !args.quiet {
        for (video, o) in &outcomes {
            match o {
                Outcome::Done(v) => println!(
                    "{}: {} frames, face on {}, {:.1} frames/s -> {}",
                    video.display(),
                    v["frames"],
                    v["faces_found"],
                    v["frames_per_second"].as_f64().unwrap_or(0.0),
                    args.out.join(video_stem(video)).display()
                ),
                Outcome::Skipped(d) => println!("{}: skipped (already captured in {})", video.display(), d.display()),
                Outcome::Failed(e) => println!("{}: FAILED: {e}", video.display()),
            }
        }
    }
    if interrupted.load(Ordering::SeqCst) {
        eprintln!("interrupted: unfinished captures were discarded");
        return Ok(std::process::ExitCode::from(130));
    }
    Ok(if all_ok {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    })
}

/// One tracked frame, passed from the tracking to the solving stage.
struct Tracked {
    index: u64,
    timestamp: f64,
    /// The landmarks when tracking succeeded.
    landmarks: Option<Landmarks68>,
    confidence: f64,
    /// Iris centres (only when the rig has gaze shapes and the face was tracked).
    iris: Option<facecap_landmarks::gaze::IrisFrame>,
    /// The grey frame, for the frames shown on the report's contact sheet.
    gray: Option<GrayImage>,
}

/// The solving stage of [`capture_one`]: per tracked frame, solve for pose and
/// weights, write the CSV rows (landmarks, pose, weights, muscles, tensor) and keep
/// what the animation and report need.
struct SolveStage<'a> {
    video: &'a Path,
    progress: &'a crate::progress::Progress,
    lm_csv: &'a mut FrameCsvWriter,
    pose_csv: &'a mut FrameCsvWriter,
    w_csv: &'a mut FrameCsvWriter,
    muscle_run: Option<&'a mut crate::capture_extras::MuscleRun>,
    tensor_run: Option<&'a mut crate::capture_extras::TensorRun>,
    bar: crate::progress::Bar,
    /// Whether `run` advances the progress bar (not when tracking already did).
    count_progress: bool,
    sheet: Vec<(u64, GrayImage, FrameOut)>,
    frames: Vec<FrameOut>,
    faces_found: u64,
    timings: Timings,
    /// The gaze shapes' indices in the rig, in `GAZE_WEIGHT_NAMES` order.
    gaze_idx: [Option<usize>; 8],
    /// The subject's resting gaze (the clip median when every frame is known first).
    gaze_rest: Option<facecap_landmarks::gaze::GazeRest>,
    /// The rig's `eyeBlink*` shapes (see [`BLINK_GAIN`]).
    blink_idx: Vec<usize>,
    /// Whether `gaze_rest` is the whole clip's median (else a running one).
    gaze_rest_from_clip: bool,
    /// Iris estimates so far (the running rest when frames stream).
    iris_seen: Vec<facecap_landmarks::gaze::IrisFrame>,
}

/// Gain on the solved `eyeBlink*` weights. dlib's 68 points never close an eye: on the
/// shared clips a visibly closed eye keeps 30-55 % of its resting eye aspect ratio (d9:
/// 0.08-0.15 against 0.28 at rest), so the solve reaches about 0.55 of a rig's full closure
/// there. The gain maps that to 1 (docs/expressions.md, "Eyes").
const BLINK_GAIN: f64 = 1.8;

/// The rig's gaze shapes in [`facecap_landmarks::gaze::GAZE_WEIGHT_NAMES`] order (ARKit
/// `eyeLookInLeft` or ICT `eyeLookIn_L` names).
fn gaze_indices(names: &[String]) -> [Option<usize>; 8] {
    use facecap_solve::observability::split_side;
    let mut out = [None; 8];
    for (slot, want) in out.iter_mut().zip(facecap_landmarks::gaze::GAZE_WEIGHT_NAMES) {
        let (wb, ws) = split_side(want);
        *slot = names.iter().position(|n| split_side(n) == (wb, ws));
    }
    out
}

impl SolveStage<'_> {
    /// Writes the gaze weights of this frame into `weights` (the solve holds them at 0).
    fn apply_gaze(&mut self, iris: Option<&facecap_landmarks::gaze::IrisFrame>, weights: &mut [f64]) {
        if self.gaze_idx.iter().all(Option::is_none) {
            return;
        }
        let Some(iris) = iris else { return };
        if !self.gaze_rest_from_clip && self.iris_seen.len() < 100_000 {
            // streaming: the running median of the frames so far stands in for the clip's
            self.iris_seen.push(*iris);
            let seen = self.iris_seen.len();
            if seen >= 15 && (seen % 15 == 0 || self.gaze_rest.is_none()) {
                self.gaze_rest = facecap_landmarks::gaze::GazeRest::median_of(&self.iris_seen);
            }
        }
        let Some(rest) = self.gaze_rest else { return };
        let g = facecap_landmarks::gaze::gaze_weights(iris, &rest, &facecap_landmarks::gaze::GazeGains::default());
        for (slot, v) in self.gaze_idx.iter().zip(g) {
            if let Some(k) = slot {
                weights[*k] = v;
            }
        }
    }

    fn run(&mut self, solver: &AnySolver, queue: impl IntoIterator<Item = Tracked>) -> anyhow::Result<()> {
        let n = solver.num_shapes();
        let mut solver_ws = solver.workspace();
        let mut solve_state = SolveState::new(n);
        let mut solution = Solution::new(n);
        let mut lm_values = [0.0; 2 * NUM_LANDMARKS];
        let mut prev_weights = vec![0.0; n];
        let nan_weights = vec![f64::NAN; n];
        for msg in queue {
            let lms = msg.landmarks;
            landmark_values(lms.as_ref(), &mut lm_values);
            self.lm_csv.write_row(&FrameRow {
                frame: msg.index,
                timestamp: msg.timestamp,
                success: lms.is_some(),
                confidence: msg.confidence,
                values: &lm_values,
            })?;
            let t = Instant::now();
            let mut out = FrameOut {
                timestamp: msg.timestamp,
                success: false,
                confidence: msg.confidence,
                landmarks: lms.clone(),
                weights: prev_weights.clone(),
                pose: None,
                reprojection_px: f64::NAN,
            };
            if let Some(l) = &lms {
                self.faces_found += 1;
                match solver.solve_into(l, &mut solver_ws, &mut solve_state, &mut solution) {
                    Ok(_) => {
                        out.success = true;
                        out.weights.copy_from_slice(&solution.weights);
                        self.apply_gaze(msg.iris.as_ref(), &mut out.weights);
                        for &k in &self.blink_idx {
                            out.weights[k] = (out.weights[k] * BLINK_GAIN).min(1.0);
                        }
                        out.pose = solution.pose;
                        out.reprojection_px = solution.reprojection_error(l);
                        prev_weights.copy_from_slice(&solution.weights);
                    }
                    Err(e) => {
                        self.progress.line(&format!(
                            "{}: frame {}: solver failed: {e}",
                            self.video.display(),
                            msg.index
                        ));
                        solve_state.reset();
                    }
                }
            } else {
                solve_state.reset();
            }
            self.timings.solve += t.elapsed().as_secs_f64();
            let pose_values = pose_row(out.pose.as_ref());
            self.pose_csv.write_row(&FrameRow {
                frame: msg.index,
                timestamp: msg.timestamp,
                success: out.success && out.pose.is_some(),
                confidence: msg.confidence,
                values: &pose_values,
            })?;
            self.w_csv.write_row(&FrameRow {
                frame: msg.index,
                timestamp: msg.timestamp,
                success: out.success,
                confidence: msg.confidence,
                values: if out.success { &out.weights } else { &nan_weights },
            })?;
            if let Some(m) = self.muscle_run.as_deref_mut() {
                let t = Instant::now();
                m.frame(msg.index, msg.timestamp, lms.as_ref(), msg.confidence)?;
                self.timings.muscles += t.elapsed().as_secs_f64();
            }
            if let Some(tr) = self.tensor_run.as_deref_mut() {
                let t = Instant::now();
                tr.frame(msg.index, msg.timestamp, lms.as_ref(), msg.confidence)?;
                self.timings.tensor += t.elapsed().as_secs_f64();
            }
            if let Some(gray) = msg.gray {
                self.sheet.push((msg.index, gray, out.clone()));
            }
            self.frames.push(out);
            if self.count_progress {
                self.bar.inc();
            }
        }
        Ok(())
    }
}

fn video_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "video".into())
}

/// Per-stage wall times in seconds.
#[derive(Debug, Default, Clone, Copy)]
struct Timings {
    decode: f64,
    track: f64,
    solve: f64,
    muscles: f64,
    tensor: f64,
    write: f64,
}

fn capture_one(
    video: &Path,
    out_dir: &Path,
    args: &Args,
    setup: &Setup,
    interrupted: &AtomicBool,
    progress: &crate::progress::Progress,
) -> anyhow::Result<serde_json::Value> {
    let started = Instant::now();
    let mut timings = Timings::default();
    let mut source = open_source(
        video,
        &SourceOptions {
            threads: args.decode_threads,
            ..SourceOptions::default()
        },
    )?;
    let info = source.info().clone();
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    // A previous finished capture is being redone: remove its completion marker first.
    let _ = std::fs::remove_file(out_dir.join("summary.json"));
    let camera = match setup.camera {
        Some(c) => c,
        None => Intrinsics::default_for_frame(info.width, info.height)?,
    };
    let priors = setup
        .use_priors
        .then(|| facecap_solve::observability::default_priors(&setup.rig));
    let with_priors = |s: AnySolver| -> anyhow::Result<AnySolver> {
        Ok(match &priors {
            Some(p) => s.with_priors(p.clone())?,
            None => s,
        })
    };
    let solver = with_priors(AnySolver::new(setup.method, &setup.rig, camera, setup.objective)?)?;
    let tracker = &setup.tracker;
    let mut tracker_ws = tracker.new_workspace();
    let mut tracker_state = TrackerState::new();
    let mut tracked = TrackedFrame::default();
    let names: Vec<String> = solver.names().to_vec();

    let mut lm_csv = FrameCsvWriter::create(out_dir.join("landmarks.csv"), &landmark_columns())?;
    let mut pose_csv = FrameCsvWriter::create(out_dir.join("pose.csv"), &POSE_COLUMNS)?;
    let mut w_csv = FrameCsvWriter::create(out_dir.join("weights.csv"), &names)?;
    let mut muscle_run = setup.muscles.as_ref().map(|m| m.start(out_dir, camera)).transpose()?;
    let mut tensor_run = setup.tensor.as_ref().map(|t| t.start(out_dir, camera)).transpose()?;

    let sheet_every = info
        .frame_count
        .map(|n| (n as usize / args.sheet_frames.max(1)).max(1))
        .unwrap_or(30);
    let sheet_max = args.sheet_frames.max(1);
    let calibrate = setup.neutral != crate::neutral::NeutralChoice::None;
    // Three stages on their own threads, connected by short bounded queues:
    // decoding (reads the ffmpeg pipe into reused frames), tracking (this thread),
    // and solving + writing the per-frame outputs. Each stage's busy time is
    // reported; frames stay in order because every queue is FIFO.
    let (frame_tx, frame_rx) = std::sync::mpsc::sync_channel::<Frame>(4);
    let (recycle_tx, recycle_rx) = std::sync::mpsc::channel::<Frame>();
    let (track_tx, track_rx) = std::sync::mpsc::sync_channel::<Tracked>(16);
    let mut stage = SolveStage {
        video,
        progress,
        lm_csv: &mut lm_csv,
        pose_csv: &mut pose_csv,
        w_csv: &mut w_csv,
        muscle_run: muscle_run.as_mut(),
        tensor_run: tensor_run.as_mut(),
        bar: progress.bar(video, info.frame_count),
        count_progress: true,
        sheet: Vec::new(),
        frames: Vec::new(),
        faces_found: 0,
        timings: Timings::default(),
        gaze_idx: gaze_indices(&names),
        gaze_rest: None,
        gaze_rest_from_clip: false,
        blink_idx: names
            .iter()
            .enumerate()
            .filter(|(_, n)| facecap_solve::observability::split_side(n).0 == "eyeBlink")
            .map(|(k, _)| k)
            .collect(),
        iris_seen: Vec::new(),
    };
    let want_iris = stage.gaze_idx.iter().any(Option::is_some);
    let mut iris_ws = setup.iris.new_workspace();
    let mut iris_frame = facecap_landmarks::gaze::IrisFrame::default();
    let (decode_result, track_result, stage_result) = std::thread::scope(|scope| {
        let decoder = scope.spawn(move || -> anyhow::Result<f64> {
            let mut busy = 0.0;
            loop {
                let mut frame = recycle_rx.try_recv().unwrap_or_default();
                let t = Instant::now();
                if !source.read_into(&mut frame)? {
                    return Ok(busy);
                }
                busy += t.elapsed().as_secs_f64();
                if frame_tx.send(frame).is_err() {
                    // the tracking stage stopped (error or interrupt)
                    return Ok(busy);
                }
            }
        });
        let stage_ref = &mut stage;
        let solver_ref = &solver;
        let worker = scope.spawn(move || -> anyhow::Result<Vec<Tracked>> {
            if calibrate {
                // the neutral calibration needs every frame's landmarks first; the
                // progress bar follows tracking here, the solving pass does not move it
                stage_ref.count_progress = false;
                Ok(track_rx.into_iter().inspect(|_| stage_ref.bar.inc()).collect())
            } else {
                stage_ref.run(solver_ref, track_rx).map(|()| Vec::new())
            }
        });
        let track_result = (|| -> anyhow::Result<f64> {
            let mut busy = 0.0;
            let mut sent_sheet = 0usize;
            for frame in frame_rx {
                if interrupted.load(Ordering::SeqCst) {
                    anyhow::bail!("interrupted at frame {}", frame.index);
                }
                let t = Instant::now();
                tracker.track_into(
                    &frame.gray,
                    frame.timestamp_s,
                    &mut tracker_ws,
                    &mut tracker_state,
                    &mut tracked,
                )?;
                busy += t.elapsed().as_secs_f64();
                let keep = frame.index as usize % sheet_every == 0 && sent_sheet < sheet_max;
                sent_sheet += usize::from(keep);
                let iris = if want_iris && tracked.success {
                    setup
                        .iris
                        .estimate_into(&frame.gray, &tracked.landmarks, &mut iris_ws, &mut iris_frame)
                        .ok()
                        .map(|_| iris_frame)
                } else {
                    None
                };
                let msg = Tracked {
                    index: frame.index,
                    timestamp: frame.timestamp_s,
                    landmarks: tracked.success.then(|| tracked.landmarks.clone()),
                    confidence: tracked.confidence,
                    iris,
                    gray: keep.then(|| frame.gray.clone()),
                };
                if track_tx.send(msg).is_err() {
                    // the solving stage stopped: its error is reported below
                    break;
                }
                let _ = recycle_tx.send(frame);
            }
            Ok(busy)
        })();
        // closing the queue ends the solving stage
        drop(track_tx);
        let stage_result = worker
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the solving stage panicked")));
        let decode_result = decoder
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the decoding stage panicked")));
        (decode_result, track_result, stage_result)
    });
    // the tracking error (e.g. an interrupt) first, then the others
    timings.track = track_result?;
    let collected = stage_result?;
    // a decoding error (a corrupt or truncated video) ends the capture before any
    // calibration work
    timings.decode = decode_result?;
    let mut neutral_report = serde_json::Value::Null;
    if calibrate {
        let tracked_frames: Vec<(u64, Landmarks68)> = collected
            .iter()
            .filter_map(|t| t.landmarks.clone().map(|l| (t.index, l)))
            .collect();
        let cal = match (setup.neutral, setup.method) {
            (crate::neutral::NeutralChoice::Auto, Method::Exact3d) => crate::neutral::calibrate_subject(
                &setup.rig,
                camera,
                setup.objective,
                priors
                    .as_ref()
                    .unwrap_or(&facecap_solve::ShapePriors::neutral(setup.rig.num_shapes())),
                &tracked_frames,
            )?,
            _ => crate::neutral::calibrate(setup.neutral, &solver, &setup.rig, camera, &tracked_frames)?,
        };
        neutral_report = cal.report;
        let irises: Vec<facecap_landmarks::gaze::IrisFrame> = collected.iter().filter_map(|t| t.iris).collect();
        stage.gaze_rest = facecap_landmarks::gaze::GazeRest::median_of(&irises);
        stage.gaze_rest_from_clip = stage.gaze_rest.is_some();
        let calibrated = with_priors(AnySolver::new(setup.method, &cal.rig, camera, setup.objective)?)?;
        stage.run(&calibrated, collected)?;
    }
    let SolveStage {
        bar,
        sheet,
        frames,
        faces_found,
        timings: stage_timings,
        ..
    } = stage;
    timings.solve = stage_timings.solve;
    timings.muscles = stage_timings.muscles;
    timings.tensor = stage_timings.tensor;
    bar.finish();
    if frames.is_empty() {
        anyhow::bail!("{}: no frames decoded", video.display());
    }
    let t = Instant::now();
    lm_csv.finish()?;
    pose_csv.finish()?;
    w_csv.finish()?;
    if let Some(m) = muscle_run {
        m.finish()?;
    }
    if let Some(tr) = tensor_run {
        tr.finish()?;
    }
    let livelink = crate::livelink::write_if_arkit(
        &out_dir.join("livelink.csv"),
        &names,
        &frames_weights(&frames),
        &frame_times(&frames),
    )?;
    write_animation(out_dir, &setup.rig_mesh, &frames)?;
    if args.obj {
        write_objs(out_dir, &setup.rig_mesh, &frames)?;
    }
    let truth = crate::truth::evaluate(video, &names, &frames_for_truth(&frames))?;
    write_report(out_dir, video, setup, &names, &frames, &sheet, truth.as_ref())?;
    timings.write += t.elapsed().as_secs_f64();
    let elapsed = started.elapsed().as_secs_f64();
    let reproj: Vec<f64> = frames
        .iter()
        .map(|f| f.reprojection_px)
        .filter(|x| x.is_finite())
        .collect();
    let summary = json!({
        "video": video.display().to_string(),
        "frames": frames.len(),
        "faces_found": faces_found,
        "success_frames": frames.iter().filter(|f| f.success).count(),
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "codec": info.codec,
        "frames_per_second": frames.len() as f64 / elapsed.max(1e-9),
        "seconds": elapsed,
        "timings_seconds": {
            "decode": timings.decode, "track": timings.track, "solve": timings.solve,
            "muscles": timings.muscles, "tensor": timings.tensor, "write_outputs": timings.write,
        },
        "mean_reprojection_px": if reproj.is_empty() { f64::NAN } else { reproj.iter().sum::<f64>() / reproj.len() as f64 },
        "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy},
        "shapes": names,
        "livelink_csv": livelink,
        "truth": truth,
        "neutral_calibration": neutral_report,
        "settings": setup.args_echo,
        "versions": {"facecap": env!("CARGO_PKG_VERSION")},
    });
    let text = serde_json::to_string_pretty(&summary)?;
    facecap_core::atomic::write_atomic(out_dir.join("summary.json"), |w| w.write_all(text.as_bytes()))?;
    Ok(summary)
}

/// One `pose.csv` row: translation (model units, camera axes x right, y down, z
/// forward) and the head rotation *relative to facing the camera* as Euler angles in
/// radians (`R = Rz Ry Rx`; Rx pitch, Ry yaw, Rz roll), like OpenFace. The rig is +Y up,
/// +Z out of the face, so a face looking into the camera has model-to-camera rotation
/// `F = diag(1, -1, -1)`; the reported rotation is `R F`, which is the identity then.
pub(crate) fn pose_row(pose: Option<&ModelToCamera>) -> [f64; 6] {
    match pose {
        Some(p) => {
            let t = p.tvec();
            let flip = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, -1.0, -1.0));
            let r = nalgebra::Rotation3::from_matrix_unchecked(p.0.rotation.to_rotation_matrix().matrix() * flip);
            let (rx, ry, rz) = r.euler_angles();
            [t.x, t.y, t.z, rx, ry, rz]
        }
        None => [f64::NAN; 6],
    }
}

fn frames_weights(frames: &[FrameOut]) -> Vec<Vec<f64>> {
    frames.iter().map(|f| f.weights.clone()).collect()
}

fn frame_times(frames: &[FrameOut]) -> Vec<f64> {
    frames.iter().map(|f| f.timestamp).collect()
}

fn frames_for_truth(frames: &[FrameOut]) -> Vec<crate::truth::Estimate> {
    frames
        .iter()
        .map(|f| crate::truth::Estimate {
            landmarks: f.landmarks.clone(),
            weights: f.success.then(|| f.weights.clone()),
            pose: f.pose,
        })
        .collect()
}

/// Keyframe times must increase strictly: nudge repeated timestamps.
fn keyframe_times(frames: &[FrameOut]) -> Vec<f32> {
    let mut times: Vec<f32> = Vec::with_capacity(frames.len());
    for f in frames {
        let mut t = f.timestamp.max(0.0) as f32;
        if let Some(&last) = times.last() {
            if t <= last {
                t = last + 1e-4;
            }
        }
        times.push(t);
    }
    times
}

fn write_animation(out_dir: &Path, rig: &MorphMesh, frames: &[FrameOut]) -> anyhow::Result<()> {
    let anim = MorphAnimation {
        times_s: keyframe_times(frames),
        weights: frames
            .iter()
            .map(|f| f.weights.iter().map(|&w| w as f32).collect())
            .collect(),
    };
    facecap_core::gltf_io::write_glb(out_dir.join("animation.glb"), rig, Some(&anim))?;
    Ok(())
}

fn write_objs(out_dir: &Path, rig: &MorphMesh, frames: &[FrameOut]) -> anyhow::Result<()> {
    let dir = out_dir.join("obj");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut posed = Vec::new();
    let mut mesh = rig.base.clone();
    for (i, f) in frames.iter().enumerate() {
        rig.pose_into(&f.weights, &mut posed)?;
        mesh.positions.clone_from(&posed);
        mesh.compute_normals();
        facecap_core::obj::write_obj(dir.join(format!("frame_{i:06}.obj")), &mesh)?;
    }
    Ok(())
}

fn write_report(
    out_dir: &Path,
    video: &Path,
    setup: &Setup,
    names: &[String],
    frames: &[FrameOut],
    sheet: &[(u64, GrayImage, FrameOut)],
    truth: Option<&serde_json::Value>,
) -> anyhow::Result<()> {
    let dir = out_dir.join("report");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    // Tiles are independent: render and encode them in parallel.
    let tiles: Vec<anyhow::Result<(String, String)>> = sheet
        .par_iter()
        .map(|(idx, gray, f)| {
            let mut rgb = RgbImage::from_fn(gray.width(), gray.height(), |x, y| {
                let v = gray.get_pixel(x, y).0[0];
                image::Rgb([v, v, v])
            });
            if let Some(l) = &f.landmarks {
                let r = (gray.width().max(gray.height()) / 250).max(1) as i64;
                report::draw_points(&mut rgb, &l.points, r, [40, 220, 60]);
            }
            let size = rgb.height().clamp(64, 720);
            let mut posed = Vec::new();
            setup.rig_mesh.pose_into(&f.weights, &mut posed)?;
            // Show the head rotation as seen by the camera.
            let rot = match &f.pose {
                Some(p) => report::camera_view(&p.0.rotation.to_rotation_matrix()),
                None => nalgebra::Rotation3::identity(),
            };
            let render = report::render_mesh(&posed, &setup.rig_mesh.base.triangles, &rot, size);
            let tile = report::side_by_side(&rgb, &render);
            let name = format!("frame_{idx:06}.png");
            let bytes = report::png_bytes_fast(&tile)?;
            facecap_core::atomic::write_atomic(dir.join(&name), |w| w.write_all(&bytes))?;
            Ok((
                format!("report/{name}"),
                format!("frame {idx}, t = {:.2} s, confidence {:.2}", f.timestamp, f.confidence),
            ))
        })
        .collect();
    let sheets = tiles.into_iter().collect::<anyhow::Result<Vec<_>>>()?;
    let times = frame_times(frames);
    let mut plots = Vec::new();
    let mut svg = |file: &str, title: &str, series: Vec<(String, Vec<f64>)>| -> anyhow::Result<()> {
        let s = report::svg_line_plot(title, &times, &series, 1000, 320);
        facecap_core::atomic::write_atomic(dir.join(file), |w| w.write_all(s.as_bytes()))?;
        plots.push(format!("report/{file}"));
        Ok(())
    };
    let weight_series: Vec<(String, Vec<f64>)> = names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            (
                n.clone(),
                frames
                    .iter()
                    .map(|f| if f.success { f.weights[k] } else { f64::NAN })
                    .collect(),
            )
        })
        .collect();
    // Plot the most active shapes (at most 10 per plot to stay readable).
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by(|&a, &b| {
        let m = |k: usize| {
            weight_series[k]
                .1
                .iter()
                .filter(|x| x.is_finite())
                .fold(0.0f64, |m, &x| m.max(x))
        };
        m(b).total_cmp(&m(a))
    });
    for (chunk_i, chunk) in order.chunks(10).take(3).enumerate() {
        svg(
            &format!("weights_{chunk_i}.svg"),
            &format!("Blendshape weights ({})", chunk_i + 1),
            chunk.iter().map(|&k| weight_series[k].clone()).collect(),
        )?;
    }
    let pose_rows: Vec<[f64; 6]> = frames.iter().map(|f| pose_row(f.pose.as_ref())).collect();
    svg(
        "pose_rotation.svg",
        "Head rotation (degrees)",
        ["pitch (Rx)", "yaw (Ry)", "roll (Rz)"]
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), pose_rows.iter().map(|r| r[3 + k].to_degrees()).collect()))
            .collect(),
    )?;
    svg(
        "pose_translation.svg",
        "Head translation (model units)",
        ["Tx", "Ty", "Tz"]
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), pose_rows.iter().map(|r| r[k]).collect()))
            .collect(),
    )?;
    svg(
        "confidence.svg",
        "Tracking confidence and reprojection error",
        vec![
            ("confidence".into(), frames.iter().map(|f| f.confidence).collect()),
            (
                "reprojection px / 10".into(),
                frames.iter().map(|f| f.reprojection_px / 10.0).collect(),
            ),
        ],
    )?;
    let mut rows = vec![
        ("video".to_string(), video.display().to_string()),
        ("frames".to_string(), frames.len().to_string()),
        (
            "frames with a solved face".to_string(),
            frames.iter().filter(|f| f.success).count().to_string(),
        ),
        ("rig".to_string(), setup.rig_name.clone()),
        ("solver".to_string(), setup.method.name().to_string()),
    ];
    if let Some(t) = truth {
        rows.push(("error against ground truth".to_string(), t.to_string()));
    }
    report::write_report_html(
        out_dir,
        &format!("facecap capture: {}", video_stem(video)),
        &rows,
        "Each tile: the video frame with the tracked landmarks (green), and the rig posed with the solved weights and head rotation.",
        &sheets,
        &plots,
    )?;
    Ok(())
}
