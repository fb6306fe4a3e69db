//! `facecap solve`: blendshape weights and head pose from a landmarks CSV against a rig,
//! through the same expression sink and output writers as `facecap capture`, so the
//! files mean the same (docs/capture.md).
//!
//! ```text
//! facecap solve LANDMARKS.csv [--rig RIG.glb --landmark-map MAP.json] [--width W --height H]
//!     [--camera fx,fy,cx,cy] [--method exact3d|exact|bobyqa|region|pca] [--l1 1] [--temporal 100]
//!     [--shapes NAME,NAME,...] [--neutral auto|none|FRAME] [--fps F] [--obj]
//!     [--obj-space camera|model] [--still-head] --out DIR
//! ```
//!
//! Input: facecap's `landmarks.csv` (`frame,timestamp,success,confidence,x_0..x_67,y_0..y_67`,
//! 0-based pixels) or an OpenFace 2.x FeatureExtraction CSV (columns found by name, spaces
//! after commas allowed, extra columns ignored; OpenFace's 1-based frames become 0-based).
//! Rows with `success = 0` get `nan` weights and reset the warm start. The solver set-up
//! (priors, neutral calibration) is `capture`'s, with the same defaults, so `solve` on
//! `capture`'s `landmarks.csv` reproduces its `pose.csv` and `weights.csv`.
//!
//! Outputs in `DIR` (each written atomically; the same files as `capture`):
//! `weights.csv`, `pose.csv`, `openface.csv`, `livelink.csv` (ARKit-named rigs),
//! `animation.glb` (morph weights and head motion) and, with `--obj`, `obj/frame_NNNNNN.obj`.
//!
//! Camera: `--camera fx,fy,cx,cy` in pixels, else the default camera `fx = fy = max(W, H)`,
//! principal point `((W - 1) / 2, (H - 1) / 2)` from `--width/--height`. `exact3d` needs one;
//! the 2D methods use it for the PnP head pose beside them (without one their pose is NaN).

use std::path::PathBuf;

use anyhow::{bail, Context};
use facecap_core::camera::Intrinsics;
use facecap_core::landmark_map::LandmarkMap;
use facecap_pipeline::outputs::{ObjSpace, SolveOutputs};
use facecap_pipeline::{ExpressionSetup, ExpressionSink, FrameImages};
use facecap_solve::{BlendshapeRig, Method, ObjectiveParams};

/// Arguments of `facecap solve`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  facecap solve out/clip/landmarks.csv --width 512 --height 512 --out solved/\n  \
    facecap solve openface_output.csv --rig ict.glb --landmark-map ict_landmarks68.json --camera 800,800,319.5,239.5 --out solved/"
)]
pub struct Args {
    /// Landmarks CSV (facecap's landmarks.csv or an OpenFace FeatureExtraction CSV).
    #[arg(value_name = "LANDMARKS.csv")]
    pub landmarks: PathBuf,
    /// Rig: glTF/GLB with morph targets (default: the built-in rig, as `capture`).
    #[arg(long, value_name = "RIG.glb", requires = "landmark_map")]
    pub rig: Option<PathBuf>,
    /// Landmark-to-vertex map JSON of `--rig` (`vertex_by_ibug_0based` object or a list of 68 ids).
    #[arg(long, value_name = "MAP.json")]
    pub landmark_map: Option<PathBuf>,
    /// Frame width in pixels (for the default camera).
    #[arg(long, requires = "height")]
    pub width: Option<u32>,
    /// Frame height in pixels (for the default camera).
    #[arg(long, requires = "width")]
    pub height: Option<u32>,
    /// Camera intrinsics `fx,fy,cx,cy` in pixels (overrides the default camera).
    #[arg(long, value_name = "fx,fy,cx,cy")]
    pub camera: Option<String>,
    /// Solver: exact3d (pose + weights, needs a camera), exact, bobyqa, region or pca.
    #[arg(long, default_value = "exact3d")]
    pub method: String,
    /// L1 weight lambda (px^2 per unit weight).
    #[arg(long, default_value_t = 1.0)]
    pub l1: f64,
    /// Temporal weight mu on ||e_t - e_{t-1}||^2 (px^2), as `capture --temporal`.
    #[arg(long, default_value_t = 100.0)]
    pub temporal: f64,
    /// Per-subject neutral calibration, as `capture --neutral`: `auto` (default), `none`
    /// or a frame index where the face is at rest.
    #[arg(long, default_value = "auto")]
    pub neutral: String,
    /// Frame rate for keyframe times and Live Link timecodes (default: from the CSV's timestamps).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Output folder (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Also write one mesh per frame, `DIR/obj/frame_NNNNNN.obj` (rig space; see --obj-space).
    #[arg(long)]
    pub obj: bool,
    /// Frame of the OBJs: `model` or `camera` (posed by the head pose). Implies --obj.
    #[arg(long, value_name = "camera|model", value_parser = ["camera", "model"])]
    pub obj_space: Option<String>,
    /// Keep the head still in `animation.glb`.
    #[arg(long)]
    pub still_head: bool,
    /// Solve for these blendshapes only (comma-separated rig names, in this order; default: all).
    #[arg(long, value_name = "NAME,NAME,...")]
    pub shapes: Option<String>,
    /// With `--rig`, as `capture --companion`: `builtin` also solves the built-in rig on the
    /// same landmarks and writes, for each shape both rigs solve (matched by ARKit name), the
    /// mean of the two rigs' weights; `none`: the rig's own weights alone. Used with a
    /// whole-clip neutral calibration (`--neutral auto` or a frame, the default).
    #[arg(long, value_name = "builtin|none", default_value = "builtin", value_parser = ["builtin", "none"])]
    pub companion: String,
}

/// Frame rate from the records' frame numbers and timestamps (`None` when they do not say).
fn fps_of(records: &[facecap_io::csv::LandmarkRecord]) -> Option<f64> {
    let (a, b) = (records.first()?, records.last()?);
    let (df, dt) = (b.frame.checked_sub(a.frame)? as f64, b.timestamp - a.timestamp);
    (df > 0.0 && dt > 0.0).then(|| df / dt)
}

/// The solve of `rig` with its default priors, and its neutral calibration hook.
fn solve_setup(
    rig: BlendshapeRig,
    choice: crate::neutral::NeutralChoice,
    method: Method,
    objective: ObjectiveParams,
) -> (ExpressionSetup, crate::cmd_capture::NeutralHook) {
    let priors = crate::cmd_capture::rig_priors(&rig);
    let hook = crate::cmd_capture::NeutralHook {
        choice,
        method,
        objective,
        priors: priors.clone(),
    };
    let setup = ExpressionSetup {
        rig,
        method,
        objective,
        priors,
        dense: None,
    };
    (setup, hook)
}

/// Runs `facecap solve`.
pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let method: Method = args.method.parse()?;
    let neutral: crate::neutral::NeutralChoice = args.neutral.parse()?;
    let camera = match (&args.camera, args.width, args.height) {
        (Some(c), _, _) => Some(crate::cmd_capture::parse_camera(c)?),
        (None, Some(w), Some(h)) => Some(Intrinsics::default_for_frame(w, h)?),
        _ => None,
    };
    if method == Method::Exact3d && camera.is_none() {
        bail!("method exact3d needs a camera: pass --width W --height H (default camera) or --camera fx,fy,cx,cy, or choose --method exact");
    }
    let obj = match (&args.obj_space, args.obj) {
        (Some(s), _) => Some(s.parse::<ObjSpace>()?),
        (None, true) => Some(ObjSpace::Model),
        (None, false) => None,
    };
    let (mesh, map, name) = match (&args.rig, &args.landmark_map) {
        (Some(r), Some(m)) => (
            facecap_io::gltf_io::read_morph_mesh(r).with_context(|| format!("loading rig {}", r.display()))?,
            LandmarkMap::from_json_file(m)?,
            r.display().to_string(),
        ),
        (Some(_), None) => bail!("--rig needs --landmark-map (68 iBUG landmarks -> vertex ids)"),
        (None, Some(m)) => bail!(
            "--landmark-map {} is the map of a --rig; without --rig the built-in rig (with its own map) is used",
            m.display()
        ),
        (None, None) => {
            let (mesh, map) = crate::default_rig::default_rig()?;
            (mesh, map, "built-in default rig".to_string())
        }
    };
    let rig = BlendshapeRig::from_morph_mesh(mesh, &map, &name)?;
    let rig = match &args.shapes {
        Some(list) => {
            let names: Vec<&str> = list.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
            if names.is_empty() {
                bail!("--shapes {list:?}: no blendshape names given");
            }
            let mut seen = std::collections::HashSet::new();
            if let Some(d) = names.iter().find(|n| !seen.insert(**n)) {
                bail!("--shapes {list:?}: {d} is listed twice");
            }
            rig.select(&names).with_context(|| format!("--shapes {list:?}"))?
        }
        None => rig,
    };
    let mut records = facecap_pipeline::openface::read_landmarks(&args.landmarks)
        .with_context(|| format!("reading {}", args.landmarks.display()))?;
    if records.is_empty() {
        bail!("{} has no frames", args.landmarks.display());
    }
    // Rows are solved in frame order (the temporal term and the animation need it),
    // whatever order the file lists them in; a frame listed twice is an error.
    if records.windows(2).any(|w| w[1].frame <= w[0].frame) {
        records.sort_by_key(|r| r.frame);
        if let Some(w) = records.windows(2).find(|w| w[1].frame == w[0].frame) {
            bail!("{}: frame {} is listed twice", args.landmarks.display(), w[0].frame);
        }
        crate::out::info(&format!(
            "{}: rows are not in frame order; solved in frame order",
            args.landmarks.display()
        ));
    }
    let fps = match args.fps {
        Some(f) if f.is_finite() && f > 0.0 => f,
        Some(f) => bail!("--fps {f}: expected a finite number > 0"),
        None => fps_of(&records).unwrap_or(facecap_io::livelink::FALLBACK_FPS),
    };
    let objective = ObjectiveParams {
        l1: args.l1,
        temporal: args.temporal,
    };
    objective.validate()?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let (setup, hook) = solve_setup(rig, neutral, method, objective);
    let t0 = std::time::Instant::now();
    let mut sink = ExpressionSink::create(
        &args.out,
        &setup,
        camera,
        hook.active()
            .then_some(&hook as &dyn facecap_pipeline::NeutralCalibration),
        FrameImages::None,
    )?;
    // the built-in rig beside `--rig` (`--companion builtin`), with its own priors and
    // neutral calibration, as `capture`
    let companion = match (&args.rig, args.companion.as_str()) {
        (Some(_), "builtin") => {
            let (mesh, map) = crate::default_rig::default_rig()?;
            let rig = BlendshapeRig::from_morph_mesh(mesh, &map, "built-in default rig")?;
            Some(solve_setup(rig, neutral, method, objective))
        }
        _ => None,
    };
    if let Some((c, h)) = &companion {
        sink = sink.with_companion(
            "built-in default rig",
            c,
            h as &dyn facecap_pipeline::NeutralCalibration,
        )?;
    }
    let replayed = facecap_pipeline::replay(&records, &mut [&mut sink])?;
    let solve_seconds = t0.elapsed().as_secs_f64();
    let result = sink.finish()?;
    for (frame, e) in &replayed.rejected {
        crate::out::info(&format!("frame {frame}: {e}"));
    }
    for (frame, e) in &result.failures {
        crate::out::info(&format!("frame {frame}: solver failed: {e}"));
    }
    if let Some(mesh) = setup.rig.mesh.as_ref() {
        facecap_pipeline::outputs::write_solve_outputs(
            &args.out,
            &setup.rig,
            mesh,
            &result,
            &SolveOutputs {
                obj,
                still_head: args.still_head,
                fps,
                rig_unit_mm: facecap_pipeline::openface::RIG_UNIT_MM,
            },
        )?;
    }
    if let Some(n) = result.companion["shapes_averaged"].as_array() {
        crate::out::info(&format!(
            "solve: {} shapes averaged with the built-in rig's on {} frames (--companion builtin)",
            n.len(),
            result.companion["frames_averaged"]
        ));
    }
    let solved: Vec<&facecap_pipeline::SolvedFrame> = result.frames.iter().filter(|f| f.success).collect();
    let err = solved.iter().map(|f| f.reprojection_px).sum::<f64>() / solved.len().max(1) as f64;
    crate::out::info(&format!(
        "solve: method {}, {} shapes, {}/{} frames solved, mean landmark error {:.2} px, {:.1} us/frame; wrote {}",
        method.name(),
        result.names.len(),
        solved.len(),
        records.len(),
        err,
        1e6 * solve_seconds / records.len() as f64,
        args.out.display()
    ));
    Ok(std::process::ExitCode::SUCCESS)
}
