//! `facecap capture VIDEO... --out DIR`: video in; landmarks, head pose, blendshape
//! weights, optional muscle contractions and tensor parameters, an animated rig and a
//! report out.
//!
//! Per video, in `DIR/<video-stem>/`: `landmarks.csv`, `pose.csv`, `weights.csv`
//! (named columns), `livelink.csv` (Live Link Face layout, when the rig's shape names
//! are ARKit names), `contractions.csv` (with `--muscles`), `tensor.csv` (with
//! `--tensor`), `openface.csv` (OpenFace 2.x layout), `animation.glb` (morph weights and head motion),
//! `obj/frame_NNNNNN.obj` (with `--obj`), `report.html`
//! with its images, and `summary.json`, written **last**: a folder without it is not a
//! finished capture. Reruns skip a finished folder only when its input (size, time and
//! a hash of its ends) and the settings that change the outputs are the same
//! (`facecap_pipeline::resume`); otherwise, and with `--force`, the old outputs are
//! removed and the video is captured again.
//! Every file is written atomically (temporary file + rename), so an interrupt or a
//! crash never leaves a half-written file under a final name.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use facecap_core::camera::{pose_row, Intrinsics};
use facecap_core::landmark_map::LandmarkMap;
use facecap_core::landmarks::Landmarks68;
use facecap_core::mesh::MorphMesh;
use facecap_pipeline::expression::{ExpressionResult, SolvedFrame};
use facecap_pipeline::outputs::{ObjSpace, SolveOutputs};
use facecap_pipeline::{
    Calibrated, ExpressionSetup, ExpressionSink, FrameImages, LandmarkCsvSink, MuscleSetup, MuscleSink,
    NeutralCalibration, RunControl, Sink, TensorSetup, TensorSink, TrackerPolicy, VideoTracker,
};
use facecap_solve::{AnySolver, BlendshapeRig, Method, ObjectiveParams};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde_json::json;

use crate::report;

/// Arguments of `facecap capture`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap capture clip.mp4 --out captures/\n  facecap capture a.mp4 b.mp4 --out captures/ --solver exact3d --rig ict.glb --landmark-map ict_landmarks68.json --obj-space camera"
)]
pub struct Args {
    /// Input videos (files, Y4M, or folders of images).
    #[arg(required = true)]
    pub videos: Vec<PathBuf>,
    /// Output folder; each video gets `DIR/<video-stem>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// The rig and solver flags (shared with `live`).
    #[command(flatten)]
    pub solve: SolveArgs,
    /// Muscle set JSON, or `default` for the built-in 11-muscle set.
    #[arg(long)]
    pub muscles: Option<String>,
    /// Tensor model file (from `facecap tensor build`).
    #[arg(long)]
    pub tensor: Option<PathBuf>,
    /// Landmark map of the `--tensor` model's mesh (68 iBUG landmarks -> vertex ids).
    #[arg(long)]
    pub tensor_landmark_map: Option<PathBuf>,
    /// Also write one OBJ per frame (`obj/frame_NNNNNN.obj`, rig space; see --obj-space).
    #[arg(long)]
    pub obj: bool,
    /// Frame of the OBJs: `model` (the rig's, expression only) or `camera` (posed by
    /// the head pose, camera axes). Implies --obj.
    #[arg(long, value_name = "camera|model", value_parser = ["camera", "model"])]
    pub obj_space: Option<String>,
    /// Keep the head still in `animation.glb` (morph weights only, no node motion).
    #[arg(long)]
    pub still_head: bool,
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
    /// Do not write the preview video (`preview.mp4`: each frame with the landmarks and
    /// the fitted rig over the face, beside the rig with the solved weights and a bar
    /// chart of them; written by default and shown at the top of `report.html`).
    #[arg(long)]
    pub no_preview: bool,
    /// Folder of MediaPipe blendshape references for the report, in the layout of
    /// `scripts/eval_expressions.py` (`mp_blendshapes_<video-stem>.csv`); each shape's
    /// reference is plotted beside its weight. Default: the video's own folder.
    #[arg(long, value_name = "DIR")]
    pub reference: Option<PathBuf>,
    /// Print a JSON summary of all videos on stdout.
    #[arg(long)]
    pub json: bool,
    /// Fail a video at its first undecodable frame. By default every decodable frame is
    /// kept, undecodable ones are written with `success = 0` and counted in
    /// `summary.json` (`undecodable_frames`) and on stderr, and a video fails only when
    /// no frame at all could be decoded.
    #[arg(long)]
    pub strict: bool,
    /// `--upsample`.
    #[command(flatten)]
    pub detect: crate::upsample_flag::UpsampleFlag,
    /// `--ert-precision`.
    #[command(flatten)]
    pub ert: crate::ert_flag::ErtFlag,
    /// Landmark front end: `mesh` (MediaPipe's face detector and 478-point face mesh,
    /// read as the 68 iBUG points, with the irises for gaze; docs/mesh.md) or `dlib68`
    /// (dlib's detector and 68-point model, LK tracking). `mesh` is the default: its
    /// weights follow the face more closely (docs/expressions.md); `dlib68` runs about
    /// twice as fast.
    #[arg(long, value_name = "mesh|dlib68", default_value = "mesh")]
    pub landmarks: facecap_pipeline::FrontEnd,
    /// Points of the face mesh the `exact3d` solve fits with `--landmarks mesh`: `all`
    /// (the 68 iBUG points plus every other mesh point that lies on the rig;
    /// docs/expressions.md, "Dense solve") or `68` (the 68 iBUG points only; landmarks.csv
    /// has the 68 points either way). Ignored with `dlib68` and the 2D solvers.
    #[arg(long, value_name = "all|68", default_value = "68", value_parser = ["all", "68"])]
    pub mesh_points: String,
    /// Weight of each dense mesh point's squared residual in the dense solve (the 68
    /// iBUG points weigh 1). Default: 68 / (number of dense points), so that the dense
    /// points together weigh as much as the 68.
    #[arg(long, value_name = "W")]
    pub mesh_point_weight: Option<f64>,
}

/// The dense points of `--mesh-points all` on a rig: the face mesh's points (all but its
/// 68 iBUG ones) mapped onto the rig's neutral ([`facecap_solve::dense::map_onto_rig`]).
pub(crate) fn dense_points(
    rig_mesh: &MorphMesh,
    map: &LandmarkMap,
    weight: Option<f64>,
) -> anyhow::Result<facecap_solve::DensePoints> {
    use facecap_mesh::ibug68::IBUG68_FROM_MESH;
    let params = facecap_solve::dense::DenseMapParams {
        skip: IBUG68_FROM_MESH.to_vec(),
        ..Default::default()
    };
    let canonical = facecap_mesh::canonical::canonical_face_from_cache()
        .context("reading MediaPipe's canonical face (--mesh-points all)")?;
    let m = facecap_solve::dense::map_onto_rig(&canonical, &IBUG68_FROM_MESH, &rig_mesh.base, map, &params)
        .context("mapping the face mesh's points onto the rig (--mesh-points all)")?;
    if m.targets.is_empty() {
        anyhow::bail!("--mesh-points all: no face-mesh point lies on the rig's surface");
    }
    let w = match weight {
        Some(w) if w.is_finite() && (0.0..=1e6).contains(&w) => w,
        Some(w) => anyhow::bail!("--mesh-point-weight must be in [0, 1e6], got {w}"),
        None => (68.0 / m.targets.len() as f64).min(1.0),
    };
    Ok(m.points(rig_mesh, w)?)
}

/// The rig, solver and camera flags of `capture` and `live` (the same meaning in both).
#[derive(Debug, Clone, clap::Args)]
pub struct SolveArgs {
    /// Blendshape rig (glTF/GLB with morph targets). Default: the built-in rig.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Landmark map of `--rig` (JSON: `vertex_by_ibug_0based`, or a list of 68 ids).
    #[arg(long)]
    pub landmark_map: Option<PathBuf>,
    /// Expression solver (`exact3d`: joint head pose and weights, perspective camera).
    #[arg(long, default_value = "exact3d", value_parser = ["exact", "exact3d", "bobyqa", "region", "pca"])]
    pub solver: String,
    /// Temporal smoothness weight of the solver (`lambda * ||e_t - e_{t-1}||^2`, px^2).
    /// The default cuts the weights' jitter on resting stretches by a quarter with no lag at
    /// blink onset (docs/expressions.md, "Temporal"); 0 turns it off.
    #[arg(long, default_value_t = 100.0)]
    pub temporal: f64,
    /// Camera intrinsics `fx,fy,cx,cy` (pixels). Default: fx = fy = max(W, H), centre.
    #[arg(long)]
    pub camera: Option<String>,
    /// Jaw contour correspondences of `exact3d` (iBUG 0-16): `pose` re-chooses each
    /// contour point on the rig's silhouette under the current head pose (rigs whose mesh
    /// extends behind the jaw, e.g. ICT; docs/expressions.md, "Contour correspondences"),
    /// `fixed` keeps the landmark map's vertex.
    #[arg(long, value_name = "pose|fixed", default_value = "pose", value_parser = ["pose", "fixed"])]
    pub contour: String,
    /// With `--rig`: `builtin` also solves the built-in rig on the same frames and writes,
    /// for each shape both rigs solve (matched by ARKit name, e.g. `eyeBlinkLeft` =
    /// `eyeBlink_L`), the mean of the two rigs' weights; the pose and the other shapes stay
    /// the rig's own. `none`: the rig's own weights alone. On the shared clips the ICT rig's
    /// weights follow MediaPipe's scores with mean r 0.743 alone and 0.78 with the built-in
    /// companion (docs/expressions.md, "The built-in rig as a companion"). Used where the
    /// whole clip is solved first (`capture` with a neutral calibration, the default); not
    /// by `live`, and not for rigs sharing fewer than 10 solved shapes with the built-in one.
    #[arg(long, value_name = "builtin|none", default_value = "builtin", value_parser = ["builtin", "none"])]
    pub companion: String,
}

/// Everything shared by all videos.
pub(crate) struct Setup {
    rig_mesh: MorphMesh,
    renderer: facecap_pipeline::RigRenderer,
    expression: ExpressionSetup,
    /// The built-in rig as the companion of `--rig` (`--companion builtin`).
    companion: Option<Box<(ExpressionSetup, NeutralHook)>>,
    rig_name: String,
    camera: Option<Intrinsics>,
    tracker: VideoTracker,
    muscles: Option<MuscleSetup>,
    tensor: Option<TensorSetup>,
    neutral: NeutralHook,
    obj_space: Option<ObjSpace>,
    args_echo: serde_json::Value,
    /// The settings that change the outputs (with the identity of every file they
    /// name): a finished folder is kept only when they are the same.
    output_settings: serde_json::Value,
}

/// The neutral calibration of `crate::neutral` behind the pipeline's hook: `auto` with
/// `exact3d` fits the subject's neutral in 3D over resting frames, everything else
/// calibrates on one frame.
pub(crate) struct NeutralHook {
    pub(crate) choice: crate::neutral::NeutralChoice,
    pub(crate) method: Method,
    pub(crate) objective: ObjectiveParams,
    pub(crate) priors: Option<facecap_solve::ShapePriors>,
}

impl NeutralHook {
    /// Whether a calibration was asked for.
    pub(crate) fn active(&self) -> bool {
        self.choice != crate::neutral::NeutralChoice::None
    }
}

impl NeutralCalibration for NeutralHook {
    fn calibrate(
        &self,
        solver: &AnySolver,
        rig: &BlendshapeRig,
        camera: Intrinsics,
        frames: &[(u64, Landmarks68)],
    ) -> Result<Calibrated, facecap_pipeline::error::BoxError> {
        let c = match (self.choice, self.method) {
            (crate::neutral::NeutralChoice::Auto, Method::Exact3d) => crate::neutral::calibrate_subject(
                rig,
                camera,
                self.objective,
                self.priors
                    .as_ref()
                    .unwrap_or(&facecap_solve::ShapePriors::neutral(rig.num_shapes())),
                frames,
            )?,
            _ => crate::neutral::calibrate(self.choice, solver, rig, camera, frames)?,
        };
        Ok(Calibrated {
            rig: c.rig,
            report: c.report,
        })
    }
}

/// The rig's measured default priors (docs/expressions.md).
pub(crate) fn rig_priors(rig: &BlendshapeRig) -> Option<facecap_solve::ShapePriors> {
    Some(facecap_solve::observability::default_priors(rig))
}

/// Parses `fx,fy,cx,cy`.
pub(crate) fn parse_camera(s: &str) -> anyhow::Result<Intrinsics> {
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

/// The rig, the expression solve and its neutral calibration hook, as `capture` sets
/// them up (also used by `live`): `rig` + `landmark_map` or the built-in rig, `solver`,
/// `temporal` weight, `neutral` choice.
pub(crate) struct ExpressionParts {
    pub(crate) rig_mesh: MorphMesh,
    pub(crate) map: LandmarkMap,
    pub(crate) rig_name: String,
    pub(crate) expression: ExpressionSetup,
    pub(crate) neutral: NeutralHook,
}

impl ExpressionParts {
    /// The renderer of the rig's mesh (for the preview, the report and the live window;
    /// built only where something is drawn: the companion rig never is).
    pub(crate) fn renderer(&self) -> anyhow::Result<facecap_pipeline::RigRenderer> {
        Ok(facecap_pipeline::RigRenderer::new(&self.rig_mesh, Some(&self.map))?)
    }
}

pub(crate) fn expression_parts(solve: &SolveArgs, neutral: &str) -> anyhow::Result<ExpressionParts> {
    let (rig, landmark_map, temporal) = (solve.rig.as_deref(), solve.landmark_map.as_deref(), solve.temporal);
    let method: Method = solve.solver.parse()?;
    let neutral: crate::neutral::NeutralChoice = neutral.parse()?;
    if !(temporal.is_finite() && temporal >= 0.0) {
        anyhow::bail!("--temporal must be finite and >= 0, got {temporal}");
    }
    let (rig_mesh, map, rig_name) = match rig {
        Some(path) => {
            let map_path = landmark_map
                .ok_or_else(|| anyhow::anyhow!("--rig needs --landmark-map (68 iBUG landmarks -> vertex ids)"))?;
            let mesh = facecap_io::gltf_io::read_morph_mesh(path)?;
            let map = LandmarkMap::from_json_file(map_path)?;
            (mesh, map, path.display().to_string())
        }
        None => {
            if let Some(m) = landmark_map {
                anyhow::bail!(
                    "--landmark-map {} is the map of a --rig; without --rig the built-in rig (with its own map) is used",
                    m.display()
                );
            }
            let (mesh, map) = crate::default_rig::default_rig()?;
            (mesh, map, "built-in default rig".to_string())
        }
    };
    let mut rig = BlendshapeRig::from_morph_mesh(rig_mesh.clone(), &map, &rig_name)?;
    if solve.contour == "fixed" {
        rig.contour = None;
    }
    let objective = ObjectiveParams {
        temporal,
        ..ObjectiveParams::default()
    };
    objective.validate()?;
    let priors = rig_priors(&rig);
    Ok(ExpressionParts {
        rig_mesh,
        map,
        rig_name,
        expression: ExpressionSetup {
            rig,
            method,
            objective,
            priors: priors.clone(),
            dense: None,
        },
        neutral: NeutralHook {
            choice: neutral,
            method,
            objective,
            priors,
        },
    })
}

pub(crate) fn build_setup(args: &Args) -> anyhow::Result<Setup> {
    let obj_space = match (&args.obj_space, args.obj) {
        (Some(s), _) => Some(s.parse::<ObjSpace>()?),
        (None, true) => Some(ObjSpace::Model),
        (None, false) => None,
    };
    let parts = expression_parts(&args.solve, &args.neutral)?;
    let renderer = parts.renderer()?;
    let ExpressionParts {
        rig_mesh,
        map,
        rig_name,
        mut expression,
        neutral,
    } = parts;
    // the built-in rig beside `--rig` (`--companion builtin`), set up as `capture` would
    // set it up alone
    let companion = if args.solve.rig.is_some() && args.solve.companion == "builtin" {
        let builtin = SolveArgs {
            rig: None,
            landmark_map: None,
            ..args.solve.clone()
        };
        let parts = expression_parts(&builtin, &args.neutral)?;
        Some(Box::new((parts.expression, parts.neutral)))
    } else {
        None
    };
    let method = expression.method;
    if args.mesh_points == "all" && args.landmarks == facecap_pipeline::FrontEnd::Mesh && method == Method::Exact3d {
        expression.dense = Some(dense_points(&rig_mesh, &map, args.mesh_point_weight)?);
    }
    let camera = args.solve.camera.as_deref().map(parse_camera).transpose()?;
    let tracker = VideoTracker::new(&TrackerPolicy {
        smooth: args.smooth,
        shape_model: None,
        upsample: args.detect.upsample,
        ert_precision: args.ert.ert_precision,
        front_end: args.landmarks,
    })?;
    let muscles = args
        .muscles
        .as_deref()
        .map(|m| -> anyhow::Result<MuscleSetup> {
            let set = (m != "default")
                .then(|| facecap_muscle::set::MuscleSet::from_json_file(Path::new(m)))
                .transpose()?;
            Ok(MuscleSetup::new(
                set.as_ref(),
                &rig_mesh,
                &map,
                facecap_muscle::track::SolveMode::Global,
            )?)
        })
        .transpose()?;
    let tensor = args
        .tensor
        .as_deref()
        .map(|p| -> anyhow::Result<TensorSetup> {
            let model = facecap_tensor::model::TensorModel::load(p)?;
            let map_path = args.tensor_landmark_map.as_deref().ok_or_else(|| {
                anyhow::anyhow!(
                    "--tensor needs --tensor-landmark-map (68 iBUG landmarks -> vertices of the tensor mesh)"
                )
            })?;
            Ok(TensorSetup::new(&model, &LandmarkMap::from_json_file(map_path)?)?)
        })
        .transpose()?;
    let args_echo = json!({
        "landmarks": args.landmarks.to_string(),
        "rig": rig_name,
        "solver": method.name(),
        "temporal": args.solve.temporal,
        "contour": args.solve.contour,
        "smooth": args.smooth,
        "camera": args.solve.camera,
        "muscles": args.muscles,
        "tensor": args.tensor.as_ref().map(|p| p.display().to_string()),
        "obj": obj_space.map(|s| match s { ObjSpace::Model => "model", ObjSpace::Camera => "camera" }),
        "still_head": args.still_head,
        "neutral": args.neutral,
        "priors": "observability defaults (facecap rig)",
        "companion": if args.solve.rig.is_some() { args.solve.companion.as_str() } else { "none" },
    });
    let file = |p: Option<&PathBuf>| facecap_pipeline::resume::file_identity_or_null(p.map(PathBuf::as_path));
    let output_settings = json!({
        "capture": args_echo,
        "sheet_frames": args.sheet_frames,
        "upsample": args.detect.upsample.to_string(),
        "landmarks": args.landmarks.to_string(),
        "mesh_points": args.mesh_points,
        "mesh_point_weight": args.mesh_point_weight,
        "files": {
            "rig": file(args.solve.rig.as_ref()),
            "landmark_map": file(args.solve.landmark_map.as_ref()),
            "muscles": file(args.muscles.as_ref().filter(|m| *m != "default").map(PathBuf::from).as_ref()),
            "tensor": file(args.tensor.as_ref()),
            "tensor_landmark_map": file(args.tensor_landmark_map.as_ref()),
        },
        "version": env!("CARGO_PKG_VERSION"),
    });
    Ok(Setup {
        rig_mesh,
        renderer,
        expression,
        companion,
        rig_name,
        camera,
        tracker,
        muscles,
        tensor,
        neutral,
        obj_space,
        args_echo,
        output_settings,
    })
}

/// Outcome of one video.
#[derive(Debug)]
pub(crate) enum Outcome {
    Done(serde_json::Value),
    Skipped(PathBuf),
    Failed(String),
}

/// Runs `facecap capture`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        // Ctrl-C, SIGTERM and SIGHUP stop at the next frame (unfinished captures are
        // discarded, their temporary files removed); a second one exits at once, leaving
        // temporary files under `.name.tmp-PID` names (never under final names), which
        // the next run removes.
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    }
    let setup = build_setup(&args)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let jobs = crate::capped_jobs(args.jobs, args.videos.len());
    let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs).build()?;
    let progress = crate::progress::Progress::new(crate::out::quiet());
    let t0 = Instant::now();
    // One folder per input, unique and inside --out (two cards' C0001.MP4 get C0001 and
    // C0001-2; a name like `...mp4` cannot reach the parent folder).
    let out_names = facecap_core::paths::unique_output_names(&args.videos, "video");
    for (video, name) in args.videos.iter().zip(&out_names) {
        if video.file_stem().map_or(true, |s| s.to_string_lossy() != name.as_str()) {
            crate::out::info(&format!("{} -> {}", video.display(), args.out.join(name).display()));
        }
    }
    let outcomes: Vec<(PathBuf, Outcome)> = pool.install(|| {
        args.videos
            .par_iter()
            .zip(out_names.par_iter())
            .map(|(video, out_name)| {
                let out_dir = args.out.join(out_name);
                let outcome = capture_video(video, &out_dir, &args, &setup, &interrupted, &progress);
                (video.clone(), outcome)
            })
            .collect()
    });
    let mut all_ok = true;
    let mut report = Vec::new();
    for ((video, o), name) in outcomes.iter().zip(&out_names) {
        let out = args.out.join(name);
        match o {
            Outcome::Done(v) => report.push(json!({"video": video, "status": "done", "out": out, "summary": v})),
            Outcome::Skipped(d) => report.push(json!({"video": video, "status": "skipped", "out": d})),
            Outcome::Failed(e) => {
                all_ok = false;
                // every error once, on stderr, also with --quiet
                eprintln!("error: {}: {e}", video.display());
                report.push(json!({"video": video, "status": "failed", "out": out, "error": e}))
            }
        }
    }
    if args.json {
        crate::out::println(&serde_json::to_string_pretty(
            &json!({"videos": report, "seconds": t0.elapsed().as_secs_f64()}),
        )?);
    } else if !crate::out::quiet() {
        for ((video, o), name) in outcomes.iter().zip(&out_names) {
            match o {
                Outcome::Done(v) => crate::out::println(&format!(
                    "{}: {} frames, face on {}, {:.1} frames/s -> {}",
                    video.display(),
                    v["frames"],
                    v["faces_found"],
                    v["frames_per_second"].as_f64().unwrap_or(0.0),
                    args.out.join(name).display()
                )),
                Outcome::Skipped(d) => crate::out::println(&format!(
                    "{}: skipped (already captured in {})",
                    video.display(),
                    d.display()
                )),
                Outcome::Failed(_) => {}
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

fn video_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "video".into())
}

/// Captures one video into `out_dir`, or skips it when `out_dir` holds a finished
/// capture of the same input with the same settings (and not `--force`).
pub(crate) fn capture_video(
    video: &Path,
    out_dir: &Path,
    args: &Args,
    setup: &Setup,
    interrupted: &AtomicBool,
    progress: &crate::progress::Progress,
) -> Outcome {
    use facecap_pipeline::resume::{check, Resume, Stamp};
    let mut settings = setup.output_settings.clone();
    settings["truth"] = facecap_pipeline::resume::file_identity_or_null(crate::truth::truth_path(video).as_deref());
    let stamp = match Stamp::new(video, settings) {
        Ok(s) => s,
        Err(e) => return Outcome::Failed(crate::error_text(&e.into())),
    };
    match check(out_dir, &stamp) {
        Resume::Finished if !args.force => {
            progress.line(&format!(
                "skip {} (finished capture of this input with these settings in {}; --force redoes it)",
                video.display(),
                out_dir.display()
            ));
            return Outcome::Skipped(out_dir.to_path_buf());
        }
        Resume::Redo(why) if !args.force => {
            progress.line(&format!("redo {}: {why}", video.display()));
        }
        _ => {}
    }
    match capture_one(video, out_dir, args, setup, &stamp, interrupted, progress) {
        Ok(v) => Outcome::Done(v),
        Err(e) => {
            // Interrupted (Ctrl-C, SIGTERM, SIGHUP) after some outputs were committed (the
            // CSVs are written before the preview): discard them too, so that an
            // unfinished capture leaves no outputs at all, as the run says on exit.
            if interrupted.load(Ordering::SeqCst) {
                let _ = facecap_pipeline::resume::clear_outputs(out_dir);
            }
            Outcome::Failed(crate::error_text(&e))
        }
    }
}

fn capture_one(
    video: &Path,
    out_dir: &Path,
    args: &Args,
    setup: &Setup,
    stamp: &facecap_pipeline::resume::Stamp,
    interrupted: &AtomicBool,
    progress: &crate::progress::Progress,
) -> anyhow::Result<serde_json::Value> {
    let started = Instant::now();
    // An optional truth file beside the video is checked first: a malformed one is a
    // warning (the capture goes on without it), not a failure after all the tracking.
    let use_truth = match crate::truth::validate(video) {
        Ok(()) => true,
        Err(e) => {
            eprintln!(
                "warning: {}: ignoring its truth file: {}",
                video.display(),
                crate::error_text(&e)
            );
            false
        }
    };
    let mut source =
        facecap_pipeline::open_video_rgb(video, args.decode_threads, args.strict, setup.tracker.needs_rgb())?;
    let info = source.info().clone();
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    // Temporary files of an earlier run that was killed (SIGKILL, power loss) go first.
    for d in [out_dir.to_path_buf(), out_dir.join("report"), out_dir.join("obj")] {
        let n = facecap_core::atomic::clean_stale_temps(&d);
        if n > 0 {
            crate::out::verbose(&format!("{}: removed {n} stale temporary files", d.display()));
        }
    }
    // A previous capture is being redone: remove its outputs (completion marker first),
    // so that none of them survives beside the new ones.
    facecap_pipeline::resume::clear_outputs(out_dir)?;
    let camera = match setup.camera {
        Some(c) => c,
        None => Intrinsics::default_for_frame(info.width, info.height)?,
    };
    let sheet_every = info
        .frame_count
        .map(|n| (n / args.sheet_frames.max(1) as u64).max(1))
        .unwrap_or(30);
    let preview_params = facecap_pipeline::PreviewParams {
        decode_threads: args.decode_threads,
        video_fps: Some(info.fps),
        ..facecap_pipeline::PreviewParams::default()
    };
    // The preview's frames (and the report's stills, with room for frames lost on the
    // way) are kept small and in colour as they are decoded for tracking, so that the
    // preview does not decode the video a second time.
    let mut colour = None;
    if !args.no_preview {
        let extra = (0..(args.sheet_frames.max(1) as u64 + 8).min(facecap_io::video::MAX_SELECT_EXTRA as u64))
            .map(|i| i * sheet_every)
            .collect();
        if let Some(tap) = preview_params.colour_tap(info.width, info.height, info.fps, extra) {
            if source.tap_colour(tap)? {
                colour = Some(facecap_pipeline::ColourFrames::new(
                    facecap_pipeline::COLOUR_FRAMES_BUDGET,
                ));
            }
        }
    }
    let calibrate = setup.neutral.active();
    let mut landmarks = LandmarkCsvSink::create(out_dir.join("landmarks.csv"))?;
    let mut solve = ExpressionSink::create(
        out_dir,
        &setup.expression,
        Some(camera),
        calibrate.then_some(&setup.neutral as &dyn NeutralCalibration),
        FrameImages::Sample {
            every: sheet_every,
            max: args.sheet_frames.max(1),
        },
    )?;
    if let Some(c) = setup.companion.as_deref() {
        solve = solve.with_companion("built-in default rig", &c.0, &c.1 as &dyn NeutralCalibration)?;
    }
    let mut muscles = setup
        .muscles
        .as_ref()
        .map(|m| MuscleSink::create(out_dir, m, camera))
        .transpose()?;
    let mut tensor = setup
        .tensor
        .as_ref()
        .map(|t| TensorSink::create(out_dir, t, camera))
        .transpose()?;
    let mut bar = progress.bar(video, info.frame_count);
    let run = {
        let mut sinks: Vec<&mut dyn Sink> = vec![&mut landmarks, &mut solve];
        if let Some(m) = muscles.as_mut() {
            sinks.push(m);
        }
        if let Some(t) = tensor.as_mut() {
            sinks.push(t);
        }
        if let Some(c) = colour.as_mut() {
            sinks.push(c);
        }
        let mut inc = || bar.inc();
        setup.tracker.run(
            source,
            &mut sinks,
            &mut RunControl {
                interrupted: Some(interrupted),
                on_frame: Some(&mut inc),
                strict: args.strict,
            },
        )?
    };
    bar.finish();
    if !crate::report_undecodable(video, &run) {
        anyhow::bail!("{}: no frames decoded", video.display());
    }
    let t = Instant::now();
    landmarks.finish()?;
    let result = solve.finish()?;
    for (frame, e) in &run.rejected {
        progress.line(&format!("{}: frame {frame}: {e}", video.display()));
    }
    for (frame, e) in &result.failures {
        progress.line(&format!("{}: frame {frame}: solver failed: {e}", video.display()));
    }
    if let Some(m) = muscles {
        m.finish()?;
    }
    if let Some(tr) = tensor {
        tr.finish()?;
    }
    let fps = facecap_io::livelink::rate_or_fallback(info.fps);
    let written = facecap_pipeline::outputs::write_solve_outputs(
        out_dir,
        &setup.expression.rig,
        &setup.rig_mesh,
        &result,
        &SolveOutputs {
            obj: setup.obj_space,
            still_head: args.still_head,
            fps,
            rig_unit_mm: facecap_pipeline::openface::RIG_UNIT_MM,
        },
    )?;
    let write_seconds = t.elapsed().as_secs_f64();
    let frames = &result.frames;
    let names = &result.names;
    let preview_path = out_dir.join(PREVIEW_FILE);
    let keep: Vec<u64> = result.sheet.iter().map(|(k, _)| frames[*k].index).collect();
    let t = Instant::now();
    let (preview, stills) = if args.no_preview {
        // a preview of an earlier run would no longer match
        let _ = std::fs::remove_file(&preview_path);
        (None, Vec::new())
    } else {
        let stored = colour.and_then(|c| {
            if c.overflowed() {
                crate::out::verbose(&format!(
                    "{}: the preview's frames exceed {} MiB: decoding the video again for the preview",
                    video.display(),
                    facecap_pipeline::COLOUR_FRAMES_BUDGET >> 20
                ));
            }
            c.into_source(video, &info)
        });
        let (rep, stills) = facecap_pipeline::write_preview_stored(
            video,
            stored,
            (info.width, info.height),
            frames,
            names,
            &setup.renderer,
            &camera,
            &preview_path,
            &preview_params,
            &keep,
            Some(interrupted),
        )?;
        (Some(rep), stills)
    };
    let preview_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let truth = if use_truth {
        crate::truth::evaluate(video, names, &frames_for_truth(frames))?
    } else {
        None
    };
    if let Some(n) = truth
        .as_ref()
        .and_then(|t| t["frames_other_face"].as_u64())
        .filter(|&n| n > 0)
    {
        eprintln!(
            "warning: {}: on {n} frames the tracked face is not the truth file's (landmarks more than {} inter-ocular distances away); those frames are left out of the errors against the truth",
            video.display(),
            crate::truth::OTHER_FACE_NME
        );
    }
    let reference_dir = args
        .reference
        .clone()
        .unwrap_or_else(|| video.parent().map(Path::to_path_buf).unwrap_or_default());
    let reference = reference_dir.join(format!("mp_blendshapes_{}.csv", video_stem(video)));
    write_report(
        out_dir,
        video,
        setup,
        &result,
        &ReportInputs {
            truth: truth.as_ref(),
            camera: &camera,
            preview: preview.is_some(),
            stills: &stills,
            stills_scale: preview.as_ref().map_or(1.0, |p| p.scale),
            reference: &reference,
        },
    )?;
    let report_seconds = t.elapsed().as_secs_f64();
    let elapsed = started.elapsed().as_secs_f64();
    let reproj: Vec<f64> = frames
        .iter()
        .map(|f| f.reprojection_px)
        .filter(|x| x.is_finite())
        .collect();
    let summary = json!({
        "video": video.display().to_string(),
        "frames": frames.len(),
        "faces_found": result.faces_found,
        "success_frames": frames.iter().filter(|f| f.success).count(),
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "frame_count": frames.len(),
        "codec": info.codec,
        "frames_per_second": frames.len() as f64 / elapsed.max(1e-9),
        "seconds": elapsed,
        "timings_seconds": {
            "decode": run.decode_seconds, "track": run.track_seconds, "solve": run.sink_seconds("solve"),
            "muscles": run.sink_seconds("muscles"), "tensor": run.sink_seconds("tensor"),
            "landmarks_csv": run.sink_seconds("landmarks"), "write_outputs": write_seconds,
            "preview": preview_seconds, "report": report_seconds,
        },
        "preview": preview.as_ref().map(|p| json!({
            "file": PREVIEW_FILE, "frames": p.frames, "width": p.width, "height": p.height, "fps": p.fps,
            "decode_seconds": p.decode_seconds, "render_seconds": p.render_seconds, "encode_seconds": p.encode_seconds,
        })),
        "undecodable_frames": run.undecodable.len(),
        "failed_frames": failed_frames(&run.undecodable, &run.rejected, &result.failures),
        "mean_reprojection_px": if reproj.is_empty() { f64::NAN } else { reproj.iter().sum::<f64>() / reproj.len() as f64 },
        "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy},
        "shapes": names,
        "livelink_csv": written.livelink,
        "head_animated": written.head_animated,
        "animation_fps": fps,
        "truth": truth,
        "neutral_calibration": result.neutral_report,
        "companion": result.companion,
        "solve_points": {
            "landmarks": setup.expression.rig.num_mapped(),
            "dense": setup.expression.dense.as_ref().map_or(0, |d| d.len()),
            "dense_weight": setup.expression.dense.as_ref().map(|d| d.weight()),
            "dense_frames": result.dense_frames,
        },
        "settings": setup.args_echo,
        "resume": stamp.to_json(),
        "versions": {"facecap": env!("CARGO_PKG_VERSION")},
    });
    let text = serde_json::to_string_pretty(&summary)?;
    facecap_core::atomic::write_atomic(out_dir.join("summary.json"), |w| w.write_all(text.as_bytes()))?;
    crate::out::verbose(&format!(
        "{}: busy seconds: decode {:.2}, track {:.2}, sinks {}; outputs {:.2}; preview {:.2}; report {:.2}",
        video.display(),
        run.decode_seconds,
        run.track_seconds,
        run.sink_seconds
            .iter()
            .map(|(n, s)| format!("{n} {s:.2}"))
            .collect::<Vec<_>>()
            .join(", "),
        write_seconds,
        preview_seconds,
        report_seconds
    ));
    Ok(summary)
}

/// `summary.json`'s list of frames that are `success = 0` for a reason other than "no
/// face found": `[{"frame", "reason"}]`, by frame.
pub(crate) fn failed_frames(
    undecodable: &[(u64, String)],
    rejected: &[(u64, String)],
    failures: &[(u64, String)],
) -> serde_json::Value {
    let mut all: Vec<(u64, &str)> = undecodable
        .iter()
        .chain(rejected)
        .chain(failures)
        .map(|(f, r)| (*f, r.as_str()))
        .collect();
    all.sort_by_key(|&(f, _)| f);
    serde_json::Value::Array(all.into_iter().map(|(f, r)| json!({"frame": f, "reason": r})).collect())
}

fn frames_for_truth(frames: &[SolvedFrame]) -> Vec<crate::truth::Estimate> {
    frames
        .iter()
        .map(|f| crate::truth::Estimate {
            landmarks: f.landmarks.clone(),
            weights: f.success.then(|| f.weights.clone()),
            pose: f.pose,
        })
        .collect()
}

/// File name of the preview video in a capture folder.
pub const PREVIEW_FILE: &str = "preview.mp4";

/// What the report needs beside the solve.
struct ReportInputs<'a> {
    truth: Option<&'a serde_json::Value>,
    camera: &'a Intrinsics,
    preview: bool,
    /// Colour frames of the tiles (from the preview pass; grey frames otherwise).
    stills: &'a [(u64, RgbImage)],
    /// Scale of the stills to the video's frames (the preview's).
    stills_scale: f64,
    /// Where the MediaPipe reference would be.
    reference: &'a Path,
}

fn write_report(
    out_dir: &Path,
    video: &Path,
    setup: &Setup,
    result: &ExpressionResult,
    inputs: &ReportInputs<'_>,
) -> anyhow::Result<()> {
    let frames = &result.frames;
    let names = &result.names;
    let sheet: Vec<(u64, &GrayImage, &SolvedFrame)> = result
        .sheet
        .iter()
        .map(|(k, g)| (frames[*k].index, g.as_ref(), &frames[*k]))
        .collect();
    let dir = out_dir.join("report");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    // Tiles are independent: render and encode them in parallel.
    let tiles: Vec<anyhow::Result<(String, String)>> = sheet
        .par_iter()
        .map(|(idx, gray, f)| {
            let (mut rgb, scale) = match inputs.stills.iter().find(|(i, _)| i == idx) {
                Some((_, c)) => (c.clone(), inputs.stills_scale),
                None => (
                    RgbImage::from_fn(gray.width(), gray.height(), |x, y| {
                        let v = gray.get_pixel(x, y).0[0];
                        image::Rgb([v, v, v])
                    }),
                    1.0,
                ),
            };
            // a small face is shown cropped and enlarged, not as a few pixels of the frame,
            // with its points drawn to the crop's size
            let face: Vec<(f64, f64)> = f.landmarks.as_ref().map_or_else(Vec::new, |l| {
                l.points.iter().map(|p| (p.x * scale, p.y * scale)).collect()
            });
            let square = report::face_square(rgb.width(), rgb.height(), &face);
            let mut ws = facecap_pipeline::RenderWorkspace::default();
            let radius = match square {
                Some((_, _, n)) => (f64::from(n) / 110.0).max(1.0),
                None => (f64::from(rgb.height()) / 110.0).max(2.5),
            };
            facecap_pipeline::preview::draw_overlay(
                &mut rgb,
                &setup.renderer,
                f,
                inputs.camera,
                scale,
                radius,
                &mut ws,
            )?;
            let crop_note = if square.is_some() { ", cropped to the face" } else { "" };
            let rgb = match square {
                Some(sq) => report::crop_square(&rgb, sq, rgb.height().clamp(64, 720)),
                None => rgb,
            };
            let size = rgb.height().clamp(64, 720);
            let render = setup.renderer.render(&f.weights, f.pose.as_ref(), size)?;
            let tile = report::side_by_side(&rgb, &render);
            let name = format!("frame_{idx:06}.png");
            let bytes = report::png_bytes_fast(&tile)?;
            facecap_core::atomic::write_atomic(dir.join(&name), |w| w.write_all(&bytes))?;
            let state = if f.success { "" } else { ", no face (tracking lost)" };
            Ok((
                format!("report/{name}"),
                format!(
                    "frame {idx}, t = {:.2} s, confidence {:.2}{crop_note}{state}",
                    f.timestamp, f.confidence
                ),
            ))
        })
        .collect();
    let tiles = tiles.into_iter().collect::<anyhow::Result<Vec<_>>>()?;
    let times: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
    let ok: Vec<bool> = frames.iter().map(|f| f.success).collect();
    let lost = report::lost_spans(&times, &ok);
    let n_lost = ok.iter().filter(|g| !**g).count();
    let lost_note = if n_lost == 0 {
        "A face was tracked on every frame.".to_string()
    } else {
        format!("Grey bands: the {n_lost} frames without a tracked face (no weights, no pose).")
    };
    let write_svg = |file: &str, svg: String| -> anyhow::Result<Option<String>> {
        facecap_core::atomic::write_atomic(dir.join(file), |w| w.write_all(svg.as_bytes()))?;
        Ok(Some(format!("report/{file}")))
    };
    let mut sections = Vec::new();
    // Weights: one small plot per active shape, with the reference beside it.
    let reference = if inputs.reference.is_file() {
        Some(report::read_reference(
            inputs.reference,
            names,
            &frames.iter().map(|f| f.index).collect::<Vec<_>>(),
        )?)
    } else {
        None
    };
    let series: Vec<Vec<f64>> = (0..names.len())
        .map(|k| {
            frames
                .iter()
                .map(|f| if f.success { f.weights[k] } else { f64::NAN })
                .collect()
        })
        .collect();
    let peak = |v: &[f64]| {
        v.iter()
            .filter(|x| x.is_finite())
            .fold(f64::NEG_INFINITY, |m, &x| m.max(x))
    };
    let (active, idle): (Vec<usize>, Vec<usize>) =
        (0..names.len()).partition(|&k| peak(&series[k]) > report::ACTIVE_WEIGHT);
    let curves: Vec<report::ShapeCurve> = active
        .iter()
        .map(|&k| report::ShapeCurve {
            name: names[k].clone(),
            values: series[k].clone(),
            reference: reference.as_ref().and_then(|r| r[k].clone()),
        })
        .collect();
    let y_max = active.iter().map(|&k| peak(&series[k])).fold(1.0f64, f64::max);
    let mut note = format!(
        "One plot per shape whose weight exceeds {} on some frame, all on the same weight range \
         (0 to {}) and the same time axis; blue: facecap.",
        report::ACTIVE_WEIGHT,
        report::tick(y_max)
    );
    match &reference {
        Some(r) => {
            let with = curves.iter().filter(|c| c.reference.is_some()).count();
            note.push_str(&format!(
                " Orange: MediaPipe FaceLandmarker's score for the same ARKit shape ({}; {with} of {} shapes have one), \
                 an independent model, not ground truth.",
                inputs.reference.display(),
                curves.len()
            ));
            let _ = r;
        }
        None => note.push_str(&format!(
            " No MediaPipe reference beside it: none at {} (made by scripts/eval_expressions.py; --reference DIR names its folder).",
            inputs.reference.display()
        )),
    }
    note.push(' ');
    note.push_str(&lost_note);
    if !idle.is_empty() {
        note.push_str(&format!(
            " Shapes that stay at or below {} all clip (not plotted): {}.",
            report::ACTIVE_WEIGHT,
            idle.iter().map(|&k| names[k].as_str()).collect::<Vec<_>>().join(", ")
        ));
    }
    let plot = if curves.is_empty() {
        note.push_str(if frames.iter().any(|f| f.success) {
            " No plot: no shape moved above the threshold on any solved frame."
        } else {
            " No plot: no frame had a tracked face, so no weights were solved."
        });
        None
    } else {
        write_svg(
            "weights.svg",
            report::small_multiples_svg(&times, &curves, &lost, (0.0, y_max), 4)?,
        )?
    };
    sections.push(report::Section {
        title: "Blendshape weights".into(),
        plot,
        note,
    });
    let pose_rows: Vec<[f64; 6]> = frames
        .iter()
        .map(|f| {
            if f.success {
                pose_row(f.pose.as_ref())
            } else {
                [f64::NAN; 6]
            }
        })
        .collect();
    let has_pose = pose_rows.iter().any(|r| r[3].is_finite());
    let no_pose = if frames.iter().any(|f| f.success) {
        "No head pose on any frame: the solver gave none (see pose.csv)"
    } else {
        "No head pose: no frame had a tracked face"
    };
    let pose_note = format!(
        "Rotation of the head relative to facing the camera (pose.csv: pose_Rx pitch, pose_Ry yaw, pose_Rz roll), degrees. {}",
        if has_pose { lost_note.as_str() } else { no_pose }
    );
    sections.push(report::Section {
        title: "Head rotation".into(),
        plot: write_svg(
            "pose_rotation.svg",
            report::lines_svg(
                &times,
                &["pitch (Rx)", "yaw (Ry)", "roll (Rz)"]
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (n.to_string(), pose_rows.iter().map(|r| r[3 + k].to_degrees()).collect()))
                    .collect::<Vec<_>>(),
                &lost,
                "degrees",
                no_pose,
            )?,
        )?,
        note: pose_note,
    });
    sections.push(report::Section {
        title: "Head translation".into(),
        plot: write_svg(
            "pose_translation.svg",
            report::lines_svg(
                &times,
                &["Tx (right)", "Ty (down)", "Tz (forward)"]
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (n.to_string(), pose_rows.iter().map(|r| r[k]).collect()))
                    .collect::<Vec<_>>(),
                &lost,
                "rig units (cm)",
                no_pose,
            )?,
        )?,
        note: format!(
            "Position of the rig's origin in camera axes (pose.csv pose_Tx..pose_Tz). {}",
            if has_pose { lost_note.as_str() } else { no_pose }
        ),
    });
    let conf: Vec<f64> = frames.iter().map(|f| f.confidence).collect();
    sections.push(report::Section {
        title: "Tracking confidence".into(),
        plot: write_svg(
            "confidence.svg",
            report::lines_svg(
                &times,
                &[("confidence".to_string(), conf)],
                &lost,
                "confidence",
                "No confidence values (no frames)",
            )?,
        )?,
        note: format!("The landmark tracker's confidence per frame (0 to 1). {lost_note}"),
    });
    let reproj: Vec<f64> = frames
        .iter()
        .map(|f| if f.success { f.reprojection_px } else { f64::NAN })
        .collect();
    sections.push(report::Section {
        title: "Landmark reprojection error".into(),
        plot: write_svg(
            "reprojection.svg",
            report::lines_svg(
                &times,
                &[("mean error (px)".to_string(), reproj)],
                &lost,
                "pixels",
                "No reprojection error: no frame was solved",
            )?,
        )?,
        note: format!(
            "Mean distance between the tracked landmarks and the rig's landmarks posed with the solved weights and head pose, pixels. {lost_note}"
        ),
    });
    let mut rows = vec![
        ("video".to_string(), video.display().to_string()),
        ("frames".to_string(), frames.len().to_string()),
        (
            "frames with a solved face".to_string(),
            frames.iter().filter(|f| f.success).count().to_string(),
        ),
        ("rig".to_string(), setup.rig_name.clone()),
        ("solver".to_string(), setup.expression.method.name().to_string()),
    ];
    if let Some(t) = inputs.truth {
        rows.extend(crate::truth::report_rows(t));
    }
    report::write_capture_html(
        out_dir,
        &format!("facecap capture: {}", video_stem(video)),
        inputs.preview.then_some(PREVIEW_FILE),
        "No preview video: this capture was made with --no-preview.",
        &rows,
        "Each tile: the video frame with the tracked landmarks (green) and the rig drawn over the face in the \
         solved head pose, beside the rig with the solved weights and head rotation.",
        &tiles,
        &sections,
    )?;
    Ok(())
}
